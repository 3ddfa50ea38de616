//! Study: how stored materials' lookups, multilinear between bin centres, change the
//! reflected energy and the picture, against the analytic synthetic materials they were
//! sampled from; and what interpolating the logarithm of the stored values instead (geometric
//! interpolation, `brdf_io::Lookup::LogMultilinear`, opt-in) changes.
//!
//! For every synthetic preset (canonical seed, 400-700 nm in 50 nm steps) and each grid:
//! the largest directional albedo over 0-88 degrees (`brdf_io::albedo`, 96 x 96 half
//! vectors), how many materials exceed 1.005 (the analytic ones never do), the largest relative
//! albedo error at any angle and wavelength, and the mean CIE Delta E 2000 of a 128 px sphere
//! (default scene) against the analytic material's sphere.
//!
//! ```sh
//! cargo run --release -p render --example grid_interpolation_study [-- GRID ...]
//! SHEET=docs/figures/grid-lookups.png cargo run --release -p render --example grid_interpolation_study -- 16,16,32
//! ```
//! (default grids 16,16,32 32,32,64 45,45,90; BENCHMARKS.md "albedo"). With `SHEET`, also a
//! comparison sheet on the first grid: analytic, multilinear and log-multilinear spheres of the
//! six materials whose multilinear spheres differ most, with Delta E 2000 maps (0-4).

use brdf_io::albedo::{AlbedoTable, DEFAULT_RESOLUTION, directional_albedo};
use brdf_io::lookup::WithLookup;
use brdf_io::store::StoreMaterial;
use brdf_io::{AngularGrid, BrdfSource, Channels, Lookup, StoreOptions};
use render::sheet::{delta_e_map, mean_delta_e};
use render::{SphereOptions, render_sphere};

const ANGLES: [f64; 9] = [0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0, 87.0, 88.0];

/// The largest value of a table.
fn peak(t: &AlbedoTable) -> f64 {
    t.peak().map_or(0.0, |p| p.value)
}

/// Per variant: materials above 1.005, largest relative albedo error, Delta E sum and
/// largest.
#[derive(Default, Clone, Copy)]
struct Tally {
    above: usize,
    worst_albedo: f64,
    delta_e_sum: f64,
    delta_e_max: f64,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let grids: Vec<String> = std::env::args().skip(1).collect();
    let grids = if grids.is_empty() {
        vec!["16,16,32".into(), "32,32,64".into(), "45,45,90".into()]
    } else {
        grids
    };
    let wavelengths: Vec<f64> = (0..7).map(|k| 400.0 + 50.0 * f64::from(k)).collect();
    let channels = Channels::spectral(wavelengths.clone())?;
    let materials = brdf_synth::preset(0);
    let dir = tempfile::tempdir()?;
    let opts = SphereOptions {
        size: 128,
        ..SphereOptions::default()
    };
    let mut analytic = Vec::new();
    for m in &materials {
        let p = m.prepare(&wavelengths);
        let t = directional_albedo(&p, &ANGLES, DEFAULT_RESOLUTION)?;
        analytic.push((t, render_sphere(&p, &opts)?));
    }
    let above = analytic.iter().filter(|(t, _)| peak(t) > 1.005).count();
    println!(
        "analytic: {above} of {} materials above 1.005",
        materials.len()
    );
    println!(
        "| grid | lookup | materials above 1.005 | largest relative albedo error | mean / largest sphere Delta E 2000 | sharpest (carpaint_solid_red) albedo peak |"
    );
    println!("|---|---|---|---|---|---|");
    let mut worst_spheres: Vec<(f64, usize)> = Vec::new();
    for (gi, g) in grids.iter().enumerate() {
        let grid: AngularGrid = g.parse()?;
        let path = dir.path().join(format!("{}.sbrdf", g.replace(',', "x")));
        let opt = StoreOptions::default();
        brdf_synth::write_store(&path, &materials, grid, &channels, opt, 0, |_| {})?;
        let mut tally = [Tally::default(); 2];
        let mut red = [0.0; 2];
        for (m, (exact, img)) in materials.iter().zip(&analytic) {
            let stored = StoreMaterial::open(&path, &m.name)?;
            let log = WithLookup::new(&stored, Lookup::LogMultilinear)?;
            let variants: [&dyn BrdfSource; 2] = [&stored, &log];
            for (v, src) in variants.into_iter().enumerate() {
                let t = directional_albedo(src, &ANGLES, DEFAULT_RESOLUTION)?;
                let s = &mut tally[v];
                s.above += usize::from(peak(&t) > 1.005);
                let err = t
                    .values
                    .iter()
                    .zip(&exact.values)
                    .map(|(a, b)| (a - b).abs() / b)
                    .fold(0.0, f64::max);
                s.worst_albedo = s.worst_albedo.max(err);
                let de = mean_delta_e(&delta_e_map(img, &render_sphere(src, &opts)?)?);
                if gi == 0 && v == 0 {
                    worst_spheres.push((de, worst_spheres.len()));
                }
                s.delta_e_sum += de;
                s.delta_e_max = s.delta_e_max.max(de);
                if m.name == "carpaint_solid_red" {
                    red[v] = peak(&t);
                }
            }
        }
        for (v, name) in ["multilinear (the library)", "log-multilinear"]
            .iter()
            .enumerate()
        {
            let s = tally[v];
            println!(
                "| {g} | {name} | {} | {:.1} % | {:.2} / {:.2} | {:.3} (analytic {:.3}) |",
                s.above,
                100.0 * s.worst_albedo,
                s.delta_e_sum / materials.len() as f64,
                s.delta_e_max,
                red[v],
                materials
                    .iter()
                    .zip(&analytic)
                    .find(|(m, _)| m.name == "carpaint_solid_red")
                    .map_or(0.0, |(_, (t, _))| peak(t))
            );
        }
    }
    if let Ok(out) = std::env::var("SHEET") {
        let path = dir
            .path()
            .join(format!("{}.sbrdf", grids[0].replace(',', "x")));
        worst_spheres.sort_by(|a, b| b.0.total_cmp(&a.0));
        let picked: Vec<usize> = worst_spheres.iter().take(6).map(|w| w.1).collect();
        let prepared: Vec<_> = picked
            .iter()
            .map(|&i| materials[i].prepare(&wavelengths))
            .collect();
        let stored: Vec<StoreMaterial> = picked
            .iter()
            .map(|&i| StoreMaterial::open(&path, &materials[i].name))
            .collect::<Result<_, _>>()?;
        let logs: Vec<WithLookup<&StoreMaterial>> = stored
            .iter()
            .map(|m| WithLookup::new(m, Lookup::LogMultilinear))
            .collect::<Result<_, _>>()?;
        let rows: Vec<render::sheet::SheetRow> = picked
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let sources: Vec<&dyn BrdfSource> = vec![&prepared[k], &stored[k], &logs[k]];
                (materials[i].name.clone(), sources)
            })
            .collect();
        let sheet = render::comparison_sheet(
            &["analytic", "multilinear", "log-multilinear"],
            &rows,
            &opts,
            4.0,
        )?;
        sheet.image.save_png(std::path::Path::new(&out))?;
        println!("sheet on {}: {out}", grids[0]);
    }
    Ok(())
}
