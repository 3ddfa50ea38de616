//! Fuzz target: arbitrary bytes as a dataset store (`.sbrdf`), opened and read every way a
//! command reads one. Any panic is a bug; errors are the expected outcome.
//!
//! The prefix's xxh3 of itself and the header is recomputed for each input (when its offsets
//! point inside the input), so mutations of the header JSON, the offset table and the payload
//! reach the checks behind the hash instead of all failing at it.
#![no_main]

use std::io::Write;
use std::sync::Arc;

use brdf_io::store::{OpenOptions, Paging, ReadMode, Store, StoreMaterial};
use libfuzzer_sys::fuzz_target;
use xxhash_rust::xxh3::Xxh3;

/// Rewrites bytes 56..64 (the hash of the prefix's first 56 bytes and the header) to match.
fn fix_prefix_hash(bytes: &mut [u8]) {
    if bytes.len() < 64 {
        return;
    }
    let u64_at = |b: &[u8], i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
    let (offset, len) = (u64_at(bytes, 40), u64_at(bytes, 48));
    let Some(end) = offset.checked_add(len) else {
        return;
    };
    if end > bytes.len() as u64 {
        return;
    }
    let mut h = Xxh3::new();
    h.update(&bytes[..56]);
    h.update(&bytes[offset as usize..end as usize]);
    bytes[56..64].copy_from_slice(&h.digest().to_le_bytes());
}

fn exercise(store: Store) {
    let n = store.n_materials();
    let d = store.d();
    let mut out = vec![0.0f32; n];
    // Hints stage runs on stores read with positioned reads (direct I/O where available).
    store.will_need([0..d.min(7), d / 2..d, d.saturating_sub(1)..d + 1]);
    for i in [0, d / 2, d.saturating_sub(1), d] {
        let _ = store.values_at(i, &mut out);
    }
    let mut chunk = Vec::new();
    for c in 0..store.n_chunks().min(64) {
        let _ = store.read_chunk(c, &mut chunk);
    }
    let _ = store.verify_checksum();
    let _ = store.gram();
    let store = Arc::new(store);
    if let Ok(material) = StoreMaterial::by_index(store, 0) {
        let mut values = vec![0.0; material.n_channels()];
        let _ = material.eval([0.3, 0.1, 0.9], [-0.5, 0.2, 0.4], &mut values);
    }
}

fuzz_target!(|data: &[u8]| {
    let mut bytes = data.to_vec();
    fix_prefix_hash(&mut bytes);
    let dir = std::env::temp_dir();
    let path = dir.join(format!("specgp-fuzz-{}.sbrdf", std::process::id()));
    let mut file = std::fs::File::create(&path).expect("a temporary file");
    file.write_all(&bytes).expect("written");
    drop(file);
    for (mode, paging) in [
        (ReadMode::Mmap, Paging::ReadAround),
        (ReadMode::Mmap, Paging::OnDemand),
        (ReadMode::Buffered, Paging::Auto),
    ] {
        let options = OpenOptions {
            mode,
            paging,
            ..OpenOptions::default()
        };
        if let Ok(store) = Store::open_with(&path, options) {
            exercise(store);
        }
    }
});
