//! Benchmark of the GPLVM fit (issue 5): the Gram pass against one plain sequential read of the
//! same store, and the two optimisers (likelihood reached, evaluations, time) per transform.
//!
//! Usage: `cargo run --release -p gplvm --example fit_bench -- DATA.sbrdf [all|lbfgs] [Q]`
//! (`lbfgs` skips Hooke-Jeeves, which takes tens of seconds; Q is the latent dimension, default
//! the default fit's)
//! (make the store with `specgp synth --out DATA.sbrdf`; it is read from the page cache: the
//! first, untimed read warms it).

use std::path::PathBuf;

use brdf_io::store::Store;
use gplvm::{FitParams, OptimizerKind, fit_gram, gram_pass};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = PathBuf::from(
        std::env::args()
            .nth(1)
            .ok_or("usage: fit_bench DATA.sbrdf")?,
    );
    let store = Store::open(&path)?;
    println!(
        "store {}: N = {}, D = {}, {:.1} MB, grid {}, {} channels",
        path.display(),
        store.n_materials(),
        store.d(),
        store.file_bytes() as f64 / 1e6,
        store.grid(),
        store.channels().len()
    );
    let mut reads = Vec::new();
    let mut grams = Vec::new();
    for _ in 0..3 {
        reads.push(brdf_io::store::sequential_read_seconds(&path, 1)?.1);
        for t in ["raw", "log"] {
            let pass = gram_pass(&store, t.parse()?)?;
            grams.push((t, pass.seconds));
        }
    }
    let best_read = reads.iter().cloned().fold(f64::INFINITY, f64::min);
    println!(
        "sequential read: {best_read:.3} s ({:.2} GB/s), best of 3",
        store.file_bytes() as f64 / best_read / 1e9
    );
    for t in ["raw", "log"] {
        let best = grams
            .iter()
            .filter(|g| g.0 == t)
            .map(|g| g.1)
            .fold(f64::INFINITY, f64::min);
        println!(
            "Gram pass ({t}): {best:.3} s = {:.2}x the sequential read, best of 3",
            best / best_read
        );
    }
    println!();
    println!("| transform | q | optimizer | log-likelihood | PCA start | evaluations | time (s) |");
    println!("|---|---|---|---|---|---|---|");
    for t in ["raw", "log"] {
        let pass = gram_pass(&store, t.parse()?)?;
        let lbfgs_only = std::env::args().nth(2).as_deref() == Some("lbfgs");
        for optimizer in [OptimizerKind::HookeJeeves, OptimizerKind::Lbfgs] {
            if lbfgs_only && optimizer == OptimizerKind::HookeJeeves {
                continue;
            }
            let defaults = FitParams::default();
            let latent_dim = match std::env::args().nth(3) {
                Some(q) => q.parse()?,
                None => defaults.latent_dim,
            };
            let config = FitParams {
                optimizer,
                latent_dim,
                transform: t.into(),
                ..defaults
            }
            .check()?;
            let fit = fit_gram(pass.gram.as_ref(), pass.d_effective, &config)?;
            println!(
                "| {t} | {} | {optimizer} | {:.6e} | {:.6e} | {} | {:.3} |",
                fit.x.ncols(),
                fit.report.log_likelihood,
                fit.report.initial_log_likelihood,
                fit.report.evaluations,
                fit.report.optimize_seconds
            );
        }
    }
    Ok(())
}
