//! Page-cache benchmark of the dataset store at full scale (see BENCHMARKS.md, "dataset store").
//!
//! `cargo run --release -p brdf-io --example store_bench -- DIR [CHANNELS] [N]` (DIR is created
//! if it does not exist)
//! `cargo run --release -p brdf-io --example store_bench -- --file STORE.sbrdf` (an existing
//! store: streaming pass, Gram pass, lookups; nothing written)
//!
//! Writes a store of N materials (default 51) on MERL's 90 x 90 x 180 grid with CHANNELS smooth
//! spectral channels (default 8: 2.38 GB in f32) into DIR, then measures in one run: the
//! sequential read bandwidth of the file from the page cache (8 MiB buffered reads, best of two
//! passes after a warm-up), the full streaming Gram pass (mmap and buffered), 10^6 random
//! all-material lookups. Deletes everything it wrote.

use std::path::Path;
use std::time::Instant;

use brdf_io::store::{OpenOptions, ReadMode};
use brdf_io::{AngularGrid, Channels, Store, StoreInfo, StoreOptions, StoreWriter};
use rayon::prelude::*;

/// Smooth, BRDF-like values: a diffuse spectrum plus a specular lobe in theta_h.
fn value(m: usize, a: usize, c: usize, grid: &AngularGrid) -> f32 {
    let (ih, id, _) = grid.unindex(a);
    let th = ih as f32 / grid.n_theta_h as f32;
    let td = id as f32 / grid.n_theta_d as f32;
    let diffuse = 0.05 + 0.1 * ((m as f32 * 0.37 + c as f32 * 0.3).sin() * 0.5 + 0.5);
    let rough = 0.02 + 0.01 * (m % 7) as f32;
    diffuse + (1.0 + td) * (-(th * th) / rough).exp() * (1.0 + 0.1 * (c as f32 * 0.2).cos())
}

fn write(path: &Path, info: &StoreInfo, n: usize, options: StoreOptions) -> f64 {
    let t = Instant::now();
    let nc = info.channels.len();
    let mut w = StoreWriter::create(path, info.clone(), options).unwrap();
    let names: Vec<(String, String)> = (0..n)
        .map(|m| (format!("m{m:02}"), "synthetic".into()))
        .collect();
    w.declare_materials(&names).unwrap();
    let d = info.d();
    let step = 1 << 18;
    for start in (0..d).step_by(step) {
        let end = (start + step).min(d);
        let mut block = vec![0f32; (end - start) * n];
        block.par_chunks_mut(n).enumerate().for_each(|(i, row)| {
            let di = start + i;
            for (m, v) in row.iter_mut().enumerate() {
                *v = value(m, di / nc, di % nc, &info.grid);
            }
        });
        w.write_block(start..end, &block).unwrap();
    }
    w.finish().unwrap();
    t.elapsed().as_secs_f64()
}

fn read_bandwidth(path: &Path) -> f64 {
    let (bytes, secs) = brdf_io::store::sequential_read_seconds(path, 3).unwrap();
    bytes as f64 / secs
}

fn gram_rate(store: &Store) -> (f64, Vec<f64>) {
    let mut best = f64::INFINITY;
    let mut g = Vec::new();
    for _ in 0..2 {
        let t = Instant::now();
        g = store.gram().unwrap();
        best = best.min(t.elapsed().as_secs_f64());
    }
    (best, g)
}

/// Sum of f32 values in f64 with eight independent partial sums, so the pass measures reading,
/// not the latency of one chain of additions.
fn sum(block: &[f32]) -> f64 {
    let mut part = [0f64; 8];
    let chunks = block.chunks_exact(8);
    let rest: f64 = chunks.remainder().iter().map(|v| f64::from(*v)).sum();
    for c in chunks {
        for (p, v) in part.iter_mut().zip(c) {
            *p += f64::from(*v);
        }
    }
    part.iter().sum::<f64>() + rest
}

/// A streaming pass that touches every value (parallel sum): what the layout and reader deliver
/// without the Gram arithmetic.
fn stream_rate(store: &Store) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..2 {
        let t = Instant::now();
        let s = store
            .par_fold_chunks(|| 0.0f64, |acc, _, block| *acc += sum(block), |a, b| a + b)
            .unwrap();
        assert!(s.is_finite());
        best = best.min(t.elapsed().as_secs_f64());
    }
    best
}

fn report_file(path: &Path) {
    let store = Store::open(path).unwrap();
    let h = store.header();
    let raw = (store.d() * store.n_materials() * 4) as f64;
    println!(
        "{}: N={} D={} {:?} {:?}: {:.1} MB on disk ({:.1} % of raw f32)",
        path.display(),
        store.n_materials(),
        store.d(),
        h.layout.dtype,
        h.layout.compression,
        store.file_bytes() as f64 / 1e6,
        100.0 * store.file_bytes() as f64 / raw
    );
    let s = stream_rate(&store);
    println!(
        "  stream pass: {s:.3} s ({:.2} GB/s of raw f32)",
        raw / s / 1e9
    );
    let (s, _) = gram_rate(&store);
    println!(
        "  gram pass: {s:.3} s ({:.2} GB/s of raw f32)",
        raw / s / 1e9
    );
    let rate = lookups(&store, 200_000);
    println!("  values_at random: {:.3} M lookups/s", rate / 1e6);
}

fn lookups(store: &Store, count: usize) -> f64 {
    let mut out = vec![0f32; store.n_materials()];
    let mut s = 0x9e3779b97f4a7c15u64;
    let d = store.d() as u64;
    let mut sink = 0.0f32;
    let t = Instant::now();
    for _ in 0..count {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        store.values_at((s % d) as usize, &mut out).unwrap();
        sink += out[0];
    }
    let rate = count as f64 / t.elapsed().as_secs_f64();
    assert!(sink.is_finite());
    rate
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("--file") {
        for f in &args[2..] {
            report_file(Path::new(f));
        }
        return;
    }
    let dir = Path::new(args.get(1).map(String::as_str).unwrap_or("."));
    if let Err(e) = std::fs::create_dir_all(dir) {
        eprintln!("store_bench: cannot create {}: {e}", dir.display());
        std::process::exit(2);
    }
    let nc: usize = args.get(2).map_or(8, |s| s.parse().unwrap());
    let n: usize = args.get(3).map_or(51, |s| s.parse().unwrap());
    let channels = Channels::spectral(
        (0..nc)
            .map(|i| 400.0 + 300.0 * i as f64 / nc as f64)
            .collect(),
    )
    .unwrap();
    let info = StoreInfo {
        grid: AngularGrid::MERL,
        channels: channels.clone(),
    };
    let gb = |b: f64| b / 1e9;
    let path = dir.join("store_bench_big.sbrdf");
    println!("threads {}", rayon::current_num_threads());
    let secs = write(&path, &info, n, StoreOptions::default());
    let bytes = std::fs::metadata(&path).unwrap().len() as f64;
    println!(
        "write  N={n} D={} f32 uncompressed: {:.2} GB in {secs:.1} s ({:.2} GB/s, block mode)",
        info.d(),
        gb(bytes),
        gb(bytes / secs)
    );
    let bw = read_bandwidth(&path);
    println!(
        "seq read bandwidth (page cache, 8 MiB reads, best of 3): {:.2} GB/s",
        gb(bw)
    );
    let store = Store::open(&path).unwrap();
    let t = Instant::now();
    store.verify_checksum().unwrap();
    println!("verify checksum: {:.2} s", t.elapsed().as_secs_f64());
    let s = stream_rate(&store);
    println!(
        "stream pass (parallel sum) mmap: {s:.2} s = {:.2} GB/s = {:.0} % of read bandwidth",
        gb(bytes / s),
        100.0 * bytes / s / bw
    );
    let (s, g) = gram_rate(&store);
    println!(
        "gram pass mmap: {s:.2} s = {:.2} GB/s = {:.0} % of read bandwidth (G[0][0] = {:.6e})",
        gb(bytes / s),
        100.0 * bytes / s / bw,
        g[0]
    );
    let buffered = Store::open_with(
        &path,
        OpenOptions {
            mode: ReadMode::Buffered,
            ..Default::default()
        },
    )
    .unwrap();
    let (s2, g2) = gram_rate(&buffered);
    assert_eq!(g, g2);
    println!(
        "gram pass buffered: {s2:.2} s = {:.2} GB/s = {:.0} % of read bandwidth",
        gb(bytes / s2),
        100.0 * bytes / s2 / bw
    );
    let rate = lookups(&store, 1_000_000);
    println!(
        "values_at (all {n} materials), mmap f32: {:.2} M lookups/s",
        rate / 1e6
    );
    let rate = lookups(&buffered, 1_000_000);
    println!(
        "values_at (all {n} materials), buffered f32: {:.2} M lookups/s",
        rate / 1e6
    );
    drop((store, buffered));
    std::fs::remove_file(&path).unwrap();
}
