//! Dataset store layout benchmarks: random all-material lookups and the streaming Gram pass,
//! chunked index-major (the store) against material-major rows, plus f32/zstd store variants.
//!
//! `cargo bench -p brdf-io --bench store`. The >= 2 GB page-cache run is the example
//! `store_bench` (see BENCHMARKS.md).
// criterion_group! generates an undocumented pub fn.
#![allow(missing_docs)]

use std::hint::black_box;

use brdf_io::store::{Compression, Dtype};
use brdf_io::{AngularGrid, Channels, Store, StoreInfo, StoreOptions, StoreWriter};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

const N: usize = 51;

/// Smooth, realistic-looking values for material `m` at flat index `d` (0 below the horizon is
/// applied by the writer).
fn value(m: usize, d: usize, nc: usize) -> f32 {
    let a = (d / nc) as f32;
    let c = (d % nc) as f32;
    let base = 0.05 + 0.02 * (m as f32 * 0.37).sin().abs();
    base * (1.0 + 0.3 * (c * 0.05 + m as f32).sin())
        + 2.0 * (-(a * 1e-3 * (1.0 + m as f32 * 0.1))).exp()
}

fn xorshift(s: &mut u64) -> u64 {
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    *s
}

fn write_store(path: &std::path::Path, info: &StoreInfo, options: StoreOptions) -> Store {
    let nc = info.channels.len();
    let mut w = StoreWriter::create(path, info.clone(), options).unwrap();
    let names: Vec<(String, String)> = (0..N).map(|m| (format!("m{m}"), "bench".into())).collect();
    w.declare_materials(&names).unwrap();
    let d = info.d();
    let step = 65_536;
    let mut block = Vec::new();
    for start in (0..d).step_by(step) {
        let end = (start + step).min(d);
        block.clear();
        for i in start..end {
            block.extend((0..N).map(|m| value(m, i, nc)));
        }
        w.write_block(start..end, &block).unwrap();
    }
    w.finish().unwrap();
    Store::open(path).unwrap()
}

fn layouts(c: &mut Criterion) {
    // 30 x 30 x 60 x 8 channels: D = 432,000, 51 materials, 88 MB in f32.
    let info = StoreInfo {
        grid: AngularGrid::new(30, 30, 60).unwrap(),
        channels: Channels::spectral((0..8).map(|i| 400.0 + 40.0 * i as f64).collect()).unwrap(),
    };
    let d = info.d();
    let nc = info.channels.len();
    let dir = tempfile::tempdir().unwrap();
    let store = write_store(
        &dir.path().join("f32.sbrdf"),
        &info,
        StoreOptions::default(),
    );
    let zstd = write_store(
        &dir.path().join("zstd.sbrdf"),
        &info,
        StoreOptions {
            compression: Compression::ZstdShuffle { level: 3 },
            ..Default::default()
        },
    );
    let f16 = write_store(
        &dir.path().join("f16.sbrdf"),
        &info,
        StoreOptions {
            dtype: Dtype::F16,
            ..Default::default()
        },
    );
    // Material-major rows in memory (the alternative layout, at its best: no I/O at all).
    let mask = info.grid.validity_mask();
    let rows: Vec<f32> = (0..N)
        .flat_map(|m| {
            let mask = &mask;
            (0..d).map(move |i| if mask[i / nc] { value(m, i, nc) } else { 0.0 })
        })
        .collect();
    eprintln!(
        "store sizes: f32 {} B, f16 {} B, zstd-3 {} B",
        store.file_bytes(),
        f16.file_bytes(),
        zstd.file_bytes()
    );

    let lookups = 1_000u64;
    let mut g = c.benchmark_group("lookup_all_materials");
    g.sample_size(10);
    g.throughput(Throughput::Elements(lookups));
    let mut out = vec![0f32; N];
    for (name, s) in [
        ("chunked_f32_mmap", &store),
        ("chunked_f16_mmap", &f16),
        ("chunked_zstd3_shuffle_cached", &zstd),
    ] {
        g.bench_function(name, |b| {
            let mut seed = 0x9e3779b97f4a7c15u64;
            b.iter(|| {
                for _ in 0..lookups {
                    let i = (xorshift(&mut seed) % d as u64) as usize;
                    s.values_at(i, &mut out).unwrap();
                }
                black_box(&out);
            })
        });
    }
    g.bench_function("material_major_in_memory", |b| {
        let mut seed = 0x9e3779b97f4a7c15u64;
        b.iter(|| {
            for _ in 0..lookups {
                let i = (xorshift(&mut seed) % d as u64) as usize;
                for (m, o) in out.iter_mut().enumerate() {
                    *o = rows[m * d + i];
                }
            }
            black_box(&out);
        })
    });
    g.finish();

    let mut g = c.benchmark_group("gram_pass");
    g.sample_size(10);
    g.throughput(Throughput::Bytes((N * d * 4) as u64));
    g.bench_function("chunked_f32_mmap", |b| {
        b.iter(|| black_box(store.gram().unwrap()))
    });
    g.bench_function("chunked_zstd3_shuffle", |b| {
        b.iter(|| black_box(zstd.gram().unwrap()))
    });
    g.bench_function("material_major_in_memory", |b| {
        // Same kernel on column blocks of the row-major N x D matrix.
        use faer::linalg::matmul::triangular::{BlockStructure, matmul};
        b.iter(|| {
            let block = 5140;
            let mut acc = faer::Mat::<f64>::zeros(N, N);
            let mut conv = vec![0f64; N * block];
            for start in (0..d).step_by(block) {
                let len = block.min(d - start);
                for m in 0..N {
                    for k in 0..len {
                        conv[m * len + k] = f64::from(rows[m * d + start + k]);
                    }
                }
                let a = faer::MatRef::from_row_major_slice(&conv[..N * len], N, len);
                matmul(
                    acc.as_mut(),
                    BlockStructure::TriangularLower,
                    faer::Accum::Add,
                    a,
                    BlockStructure::Rectangular,
                    a.transpose(),
                    BlockStructure::Rectangular,
                    1.0,
                    faer::Par::Seq,
                );
            }
            black_box(acc)
        })
    });
    g.finish();
}

criterion_group!(benches, layouts);
criterion_main!(benches);
