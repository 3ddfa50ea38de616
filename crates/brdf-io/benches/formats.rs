//! Bench binary (harness = false): import (resampling) of the 7 real RGL RGB files onto the MERL
//! grid (90, 90, 180), parallel with rayon, and of the 51 RGL Neural-BRDF networks onto a
//! (45, 45, 90) grid.
//!
//! Run: `cargo bench -p brdf-io --bench formats` (needs ../shared/data; skips otherwise).

use std::path::Path;
use std::time::Instant;

use brdf_io::grid::{AngularGrid, Channels};
use brdf_io::nbrdf::{GridInputs, NbrdfSet};
use brdf_io::rgl::RglBsdf;

fn main() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if !data.is_dir() {
        eprintln!("skipping: {} is absent", data.display());
        return;
    }
    let threads = rayon::current_num_threads();
    let mut files: Vec<_> = std::fs::read_dir(data.join("rgl-rgb"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "bsdf"))
        .collect();
    files.sort();
    let grid = AngularGrid::MERL;
    let start = Instant::now();
    let mut cells = 0usize;
    for f in &files {
        let t = Instant::now();
        let bsdf = RglBsdf::open(f).unwrap();
        let (values, report) = bsdf.resample(&grid, &Channels::Rgb).unwrap();
        cells += values.len() / 3;
        println!(
            "{:<28} {:>7.3} s  ({} negatives clamped, max {:.3})",
            f.file_name().unwrap().to_string_lossy(),
            t.elapsed().as_secs_f64(),
            report.negatives_clamped,
            report.max
        );
    }
    let total = start.elapsed().as_secs_f64();
    println!(
        "RGL import: {} files onto {grid} in {total:.2} s ({:.2} s/file, {:.2} M cells/s, {threads} threads)",
        files.len(),
        total / files.len() as f64,
        cells as f64 / total / 1e6
    );

    let set = NbrdfSet::open(
        data.join("nbrdf/rgl-isotropic_nbrdf_weights_675.npy"),
        data.join("nbrdf/rgl-isotropic_nbrdf_names.txt"),
    )
    .unwrap();
    let grid = AngularGrid::new(45, 45, 90).unwrap();
    let start = Instant::now();
    let (mut outliers, mut max) = (0, 0.0f64);
    for i in 0..set.len() {
        let (_, r) = set.material(i).unwrap().resample(&grid).unwrap();
        outliers += r.outliers;
        max = max.max(r.max);
    }
    let total = start.elapsed().as_secs_f64();
    println!(
        "NBRDF import: {} networks onto {grid} in {total:.2} s; {outliers} values above 1e4 1/sr, max {max:.3e}",
        set.len()
    );
    // The same networks on inputs made once for the grid (what `specgp import nbrdf` does).
    let start = Instant::now();
    let inputs = GridInputs::new(&grid);
    let made = start.elapsed().as_secs_f64();
    for i in 0..set.len() {
        let options = brdf_io::nbrdf::NbrdfOptions::default();
        set.material(i)
            .unwrap()
            .resample_on(&inputs, options)
            .unwrap();
    }
    let total = start.elapsed().as_secs_f64();
    println!(
        "NBRDF import on shared inputs: {} networks onto {grid} in {total:.2} s ({made:.3} s making the inputs)",
        set.len()
    );
}
