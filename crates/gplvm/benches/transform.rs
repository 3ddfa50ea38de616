//! Criterion benchmarks of the data transforms on the sizes the hot loops use: one Gram-pass
//! block (48 indices x 51 materials of stored f32 values) forward-transformed to f64, and one
//! block of predicted values inverse-transformed in place.
//!
//! Run: `cargo bench -p gplvm --bench transform` (throughput in values per second; one thread).

// `criterion_group!` generates an undocumented function.
#![allow(missing_docs)]

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use gplvm::Transform;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// BRDF-like values over six decades, 1e-4 .. 1e2 1/sr.
fn values(len: usize) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    (0..len)
        .map(|_| 10f64.powf(rng.random_range(-4.0..2.0)) as f32)
        .collect()
}

fn transforms(c: &mut Criterion) {
    let len = 48 * 51;
    let input = values(len);
    let mut out = vec![0.0; len];
    let mut group = c.benchmark_group("transform_block_48x51");
    group.throughput(Throughput::Elements(len as u64));
    for t in ["raw", "log"] {
        let t: Transform = t.parse().unwrap();
        group.bench_function(format!("forward_batch_{t}"), |b| {
            b.iter(|| t.forward_batch(black_box(&input), &mut out))
        });
    }
    let log: Transform = "log".parse().unwrap();
    let mut forward = vec![0.0; len];
    log.forward_batch(&input, &mut forward);
    group.bench_function("inverse_in_place_log", |b| {
        b.iter(|| {
            out.copy_from_slice(black_box(&forward));
            log.inverse_in_place(&mut out);
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    targets = transforms
}
criterion_main!(benches);
