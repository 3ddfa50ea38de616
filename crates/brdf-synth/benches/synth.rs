//! Throughput of the synthetic materials: preparing the preset, evaluating every material at
//! one direction pair (33 wavelengths), and generating a small dataset in memory.
//!
//! `cargo bench -p brdf-synth --bench synth`

// `criterion_group!` generates an undocumented function.
#![allow(missing_docs)]

use std::hint::black_box;

use brdf_io::{AngularGrid, Channels, HalfDiff};
use brdf_synth::{generate, preset};
use criterion::{Criterion, criterion_group, criterion_main};

fn bench(c: &mut Criterion) {
    let channels = Channels::parse_wavelengths("360:1000:20").unwrap();
    let Channels::Spectral(w) = &channels else {
        unreachable!()
    };
    let materials = preset(0);
    let mut g = c.benchmark_group("synth");
    g.sample_size(10);
    g.bench_function("prepare_51_materials_33_wavelengths", |b| {
        b.iter(|| {
            materials
                .iter()
                .map(|m| m.prepare(black_box(w)))
                .collect::<Vec<_>>()
        })
    });
    let prepared: Vec<_> = materials.iter().map(|m| m.prepare(w)).collect();
    let hd = HalfDiff {
        theta_h: 0.3,
        theta_d: 0.6,
        phi_d: 1.0,
    };
    let mut out = vec![0.0; w.len()];
    g.bench_function("eval_51_materials_one_cell_33_wavelengths", |b| {
        b.iter(|| {
            for p in &prepared {
                p.eval_half_diff(black_box(&hd), &mut out);
            }
            out[0]
        })
    });
    let grid = AngularGrid::new(16, 16, 32).unwrap();
    g.bench_function("generate_in_memory_16x16x32_33wl", |b| {
        b.iter(|| generate(&materials, black_box(grid), &channels).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
