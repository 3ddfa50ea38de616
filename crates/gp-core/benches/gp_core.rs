//! Criterion benchmarks for gp-core: GPLVM likelihood + gradient and GP posterior weights.
//!
//! Run: `cargo bench -p gp-core --bench gp_core` (short measurement times; 2-core machine).

// `criterion_group!` generates an undocumented function.
#![allow(missing_docs)]

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use gp_core::{GpRegression, GplvmObjective, KernelParams, Mat, Par, Predictor, gram_from_data};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;
use std::time::Duration;

fn rand_mat(rng: &mut ChaCha8Rng, n: usize, m: usize) -> Mat<f64> {
    Mat::from_fn(n, m, |_, _| rng.random_range(-1.0..1.0))
}

fn likelihood(c: &mut Criterion) {
    let mut group = c.benchmark_group("gplvm_value_and_gradient_q2");
    let par = Par::rayon(0);
    for n in [51usize, 200, 1000] {
        let mut rng = ChaCha8Rng::seed_from_u64(n as u64);
        let y = rand_mat(&mut rng, n, 64);
        let g = gram_from_data(y.as_ref(), par).unwrap();
        let obj = GplvmObjective::from_uncentred_gram(g.as_ref(), 284_310_000)
            .unwrap()
            .with_prior(true);
        let x = rand_mat(&mut rng, n, 2);
        let p = KernelParams::paper();
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| black_box(obj.evaluate(x.as_ref(), &p, par).unwrap().value))
        });
    }
    group.finish();
    // What one L-BFGS step of the default fit evaluates: N = 51, q = 5, sequential.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let y = rand_mat(&mut rng, 51, 64);
    let g = gram_from_data(y.as_ref(), Par::Seq).unwrap();
    let obj = GplvmObjective::from_uncentred_gram(g.as_ref(), 1_500_000)
        .unwrap()
        .with_prior(true);
    let x = rand_mat(&mut rng, 51, 5);
    let p = KernelParams::paper();
    c.bench_function("gplvm_value_and_gradient_n51_q5_seq", |b| {
        b.iter(|| black_box(obj.evaluate(x.as_ref(), &p, Par::Seq).unwrap().value))
    });
    // The same through the flat interface the optimisers call (no condition estimate).
    let flat = obj.flat(5, p.clone(), gp_core::Learn::NONE).unwrap();
    let theta = flat.pack(x.as_ref(), &p).unwrap();
    c.bench_function("gplvm_flat_value_and_gradient_n51_q5_seq", |b| {
        b.iter(|| {
            black_box(
                flat.neg_log_likelihood_and_gradient(&theta, Par::Seq)
                    .unwrap()
                    .0,
            )
        })
    });
}

fn weights(c: &mut Criterion) {
    let mut group = c.benchmark_group("posterior_weights_n51_q2");
    let mut rng = ChaCha8Rng::seed_from_u64(51);
    let x = rand_mat(&mut rng, 51, 2);
    let gp = GpRegression::new(x.as_ref(), KernelParams::paper(), Par::Seq).unwrap();
    let one = [0.1, -0.2];
    group.bench_function("1_point", |b| {
        b.iter(|| black_box(gp.weights(black_box(&one), Predictor::Exact).unwrap()))
    });
    let xs = rand_mat(&mut rng, 100_000, 2);
    for (name, par) in [
        ("100k_points_rayon", Par::rayon(0)),
        ("100k_points_seq", Par::Seq),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                black_box(
                    gp.weights_batch(xs.as_ref(), Predictor::Exact, par)
                        .unwrap(),
                )
            })
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    targets = likelihood, weights
}
criterion_main!(benches);
