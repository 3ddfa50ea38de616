//! Accuracy and cost of writing stored materials as RGL `.bsdf` files, over the writer's
//! resolution settings (BENCHMARKS.md "brdf-io", RGL writer).
//!
//! `cargo run --release -p brdf-io --example rgl_write_study -- SOURCE...` with SOURCE a stored
//! material `DATA.sbrdf:MATERIAL` or an RGL file `FILE.bsdf` (re-encoded with specgp's own
//! parameterisation).
//!
//! For each source and setting (fixed sizes, and the default refinement): the time to build
//! the file's fields (with its check), its size, the writer's own check errors, and the errors of the written file (read back with `RglBsdf`) against the stored material at 20,000
//! seeded direction pairs (cosine-distributed, plus 2,000 near the mirror direction): relative
//! RMS weighted by cos theta_i cos theta_o (what reaches a picture), and the median and 90th
//! percentile of the per-value relative error (values above 1e-3 of the material's largest).

use std::time::Instant;

use brdf_io::rgl::{RglBsdf, RglWriteOptions, rgl_fields};
use brdf_io::store::StoreMaterial;
use brdf_io::tensor::TensorFile;
use brdf_io::{BrdfSource, Channels, Vec3};

fn next(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (*state >> 11) as f64 / (1u64 << 53) as f64
}

fn cosine_dir(state: &mut u64) -> Vec3 {
    let (r, phi) = (next(state).sqrt(), std::f64::consts::TAU * next(state));
    [r * phi.cos(), r * phi.sin(), (1.0 - r * r).max(1e-4).sqrt()]
}

fn pairs() -> Vec<(Vec3, Vec3)> {
    let mut state = 11;
    let mut out: Vec<(Vec3, Vec3)> = (0..20_000)
        .map(|_| (cosine_dir(&mut state), cosine_dir(&mut state)))
        .collect();
    while out.len() < 22_000 {
        let wi = cosine_dir(&mut state);
        let d = 0.05 * next(&mut state);
        let phi = std::f64::consts::TAU * next(&mut state);
        let wo = [-wi[0] + d * phi.cos(), -wi[1] + d * phi.sin(), wi[2]];
        let n = (wo[0] * wo[0] + wo[1] * wo[1] + wo[2] * wo[2]).sqrt();
        if wo[2] / n > 0.01 {
            out.push((wi, [wo[0] / n, wo[1] / n, wo[2] / n]));
        }
    }
    out
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.is_empty() {
        return Err("usage: rgl_write_study DATA.sbrdf:MATERIAL|FILE.bsdf...".into());
    }
    let visible = Channels::spectral(vec![450.0, 550.0, 650.0])?;
    let pairs = pairs();
    // (theta_i, table side, refine): fixed sizes, and the default refinement from 32 x 32.
    let settings = [(32, 32, false), (64, 64, false), (32, 32, true)];
    println!(
        "source | theta_i | table | warp | mirror lobe | build s | MB | check | albedo check | cos-weighted rel RMS | median | p90"
    );
    for name in &args {
        let source: Box<dyn BrdfSource> = match brdf_io::store::parse_store_spec(name) {
            Some((store, material)) => {
                Box::new(StoreMaterial::open(store, &material)?.with_wavelengths(&visible)?)
            }
            None => Box::new(RglBsdf::open(name)?),
        };
        let nc = source.channels().len();
        let label = name.rsplit('/').next().unwrap_or(name);
        let (mut f, mut g) = (vec![0.0; nc], vec![0.0; nc]);
        let reference: Vec<Vec<f64>> = pairs
            .iter()
            .map(|&(wi, wo)| {
                // The file stores negative values (out-of-gamut RGB) as 0.
                source
                    .eval(wi, wo, &mut g)
                    .map(|_| g.iter().map(|v| v.max(0.0)).collect())
            })
            .collect::<Result<_, _>>()?;
        let peak = reference.iter().flatten().copied().fold(0.0, f64::max);
        for &(theta_samples, resolution, refine) in &settings {
            let default = RglWriteOptions::default();
            let options = RglWriteOptions {
                theta_samples,
                resolution,
                warp_resolution: default.warp_resolution.max(4 * resolution),
                tolerance: default.tolerance.filter(|_| refine),
                ..default
            };
            let start = Instant::now();
            let (fields, summary) = rgl_fields(source.as_ref(), &options)?;
            let seconds = start.elapsed().as_secs_f64();
            let bytes = TensorFile::to_bytes(&fields)?;
            let bsdf = RglBsdf::from_tensor_file(&TensorFile::from_bytes(&bytes, "study.bsdf")?)?;
            let (mut num, mut den, mut rel) = (0.0, 0.0, Vec::new());
            for (&(wi, wo), r) in pairs.iter().zip(&reference) {
                bsdf.eval(wi, wo, &mut f)?;
                let w = wi[2] * wo[2];
                for c in 0..nc {
                    num += (w * (f[c] - r[c])).powi(2);
                    den += (w * r[c]).powi(2);
                    if r[c] > 1e-3 * peak {
                        rel.push((f[c] - r[c]).abs() / r[c]);
                    }
                }
            }
            rel.sort_by(f64::total_cmp);
            let q = |p: f64| rel[((rel.len() - 1) as f64 * p) as usize];
            println!(
                "{label} | {}{} | {} | {} | {} | {seconds:.2} | {:.1} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4}",
                summary.theta_samples,
                if refine { " (refined)" } else { "" },
                summary.resolution,
                summary.warp_resolution,
                summary.mirror_share,
                bytes.len() as f64 / 1e6,
                summary.check_rms,
                summary.albedo_error,
                (num / den).sqrt(),
                q(0.5),
                q(0.9)
            );
        }
    }
    Ok(())
}
