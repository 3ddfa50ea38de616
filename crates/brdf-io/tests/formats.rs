//! Integration tests of the BRDF file formats against real data and Mitsuba 3 reference tables.
//!
//! Real data lives in `../shared/data` (relative to the project root); tests that need it skip
//! with a printed reason when it is absent. The Mitsuba tables in `tests/data/mitsuba` are made by
//! `scripts/mitsuba_reference.py`.

use std::path::{Path, PathBuf};

use brdf_io::grid::{AngularGrid, Channels, HalfDiff};
use brdf_io::rgl::RglBsdf;

fn shared_data() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipping: shared data folder {} is absent", p.display());
        None
    }
}

fn rgl_files(data: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(data.join("rgl-rgb"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "bsdf"))
        .collect();
    v.sort();
    v
}

/// Rows of a reference table: (wi, wo, rgb).
fn read_reference(path: &Path) -> Vec<([f64; 3], [f64; 3], [f64; 3])> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("wi_x"))
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            assert_eq!(v.len(), 9, "{l}");
            ([v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]])
        })
        .collect()
}

#[test]
fn rgl_rgb_matches_mitsuba_reference_tables() {
    let Some(data) = shared_data() else { return };
    let files = rgl_files(&data);
    assert_eq!(files.len(), 7, "expected the 7 RGL RGB files");
    let tables = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/mitsuba");
    let mut worst = (0.0f64, String::new());
    let mut total = 0;
    for file in &files {
        let name = file.file_stem().unwrap().to_str().unwrap();
        let bsdf = RglBsdf::open(file).unwrap();
        assert_eq!(bsdf.channels(), Channels::Rgb);
        let rows = read_reference(&tables.join(format!("{name}.csv")));
        assert!(rows.len() >= 100, "{name}: {} rows", rows.len());
        let mut out = [0.0; 3];
        for (k, (wi, wo, want)) in rows.iter().enumerate() {
            bsdf.eval(*wi, *wo, &mut out).unwrap();
            for c in 0..3 {
                // Relative error with an absolute floor (Mitsuba computes in f32).
                let err = (out[c] - want[c]).abs() / want[c].abs().max(1e-3);
                if err > worst.0 {
                    worst = (
                        err,
                        format!("{name} row {k} channel {c}: ours {} vs {}", out[c], want[c]),
                    );
                }
                total += 1;
            }
        }
    }
    println!(
        "max relative error vs Mitsuba over {total} values: {:.3e} ({})",
        worst.0, worst.1
    );
    assert!(worst.0 < 1e-3, "max error {:.3e} at {}", worst.0, worst.1);
}

#[test]
fn rgl_resample_is_symmetric_under_reciprocity_and_zero_below_horizon() {
    let Some(data) = shared_data() else { return };
    let file = data.join("rgl-rgb/paper_white_rgb.bsdf");
    let bsdf = RglBsdf::open(&file).unwrap();
    let grid = AngularGrid::new(6, 8, 10).unwrap();
    let (values, report) = bsdf.resample(&grid, &Channels::Rgb).unwrap();
    assert_eq!(values.len(), grid.len() * 3);
    let mask = grid.validity_mask();
    let valid = mask.iter().filter(|v| **v).count();
    assert_eq!(report.values, valid * 3);
    assert_eq!(report.below_horizon_cells, grid.len() - valid);
    for (a, ok) in mask.iter().enumerate() {
        let cell = &values[a * 3..a * 3 + 3];
        if *ok {
            assert!(cell.iter().all(|v| *v > 0.0), "cell {a}: {cell:?}");
            // Same value as a direct evaluation at the bin centre.
            let (wi, wo) = grid.bin_centre_flat(a).to_dirs();
            let mut out = [0.0; 3];
            bsdf.eval(wi, wo, &mut out).unwrap();
            for c in 0..3 {
                assert!((f64::from(cell[c]) - out[c]).abs() <= 1e-6 * out[c].abs().max(1e-6));
            }
        } else {
            assert_eq!(cell, [0.0, 0.0, 0.0]);
        }
    }
    // White paper: nearly neutral, roughly Lambertian magnitude (albedo ~0.8 -> f ~ 0.25).
    let (i, j, k) = (1, 2, 3);
    let a = grid.index(i, j, k);
    assert!(
        (0.1..0.6).contains(&values[a * 3 + 1]),
        "{}",
        values[a * 3 + 1]
    );
    assert!(report.min >= 0.0 && report.max > report.min);
    // Reciprocity of the measurement: f(wi, wo) ~ f(wo, wi) for this diffuse sample.
    let hd = HalfDiff {
        theta_h: 0.3,
        theta_d: 0.5,
        phi_d: 1.0,
    };
    let (wi, wo) = hd.to_dirs();
    let (mut f1, mut f2) = ([0.0; 3], [0.0; 3]);
    bsdf.eval(wi, wo, &mut f1).unwrap();
    bsdf.eval(wo, wi, &mut f2).unwrap();
    assert!((f1[1] - f2[1]).abs() < 0.1 * f1[1], "{f1:?} vs {f2:?}");
}
