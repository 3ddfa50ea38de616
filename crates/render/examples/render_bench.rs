//! Benchmark: a 256 x 256 sphere of a predicted material, rendered lazily (the renderer
//! evaluates each cell the picture touches once with `PredictedMaterial::eval_cell`, only the
//! observer's wavelengths) against materialise-then-render (`PredictedMaterial::materialize` to
//! a `.sbrdf`, then render the stored material). Both paths use the same renderer (default
//! [`SphereOptions`]: the environment pre-integrated over the view angle, `EnvMode::Table`); the
//! per-pixel environment quadrature (`EnvMode::PerPixel`) is measured on the warm cache for
//! comparison.
//!
//! ```sh
//! specgp synth --out /tmp/b/synth.sbrdf && specgp fit /tmp/b/synth.sbrdf --out /tmp/b/model.toml
//! cargo run --release -p render --example render_bench -- /tmp/b/model.toml [SIZE] [--sidecar] [--loop N] [--lookup log]
//! cargo run --release -p render --example render_bench -- /tmp/b/model.toml [SIZE] --stored-materials
//! cargo run --release -p render --example render_bench -- /tmp/b/model.toml [SIZE] --together K
//! ```
//! `--together K` times K predictions rendered one by one against `render::render_spheres`
//! (each planned cell read once for all of them; latent-map thumbnails, sheets).
//! `--stored-materials` runs the accuracy study of the environment table instead: every stored
//! material of the model's dataset rendered with several table resolutions against a dense table
//! (the images' largest and mean linear sRGB difference and largest 8-bit code difference).
//! The latent point is the midpoint of the first two materials. `--lookup log`: every material
//! (lazy, cached and materialised) looked up logarithmically between bin centres
//! ([`brdf_io::lookup::WithLookup`]).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use brdf_io::lookup::WithLookup;
use brdf_io::{AngularGrid, BrdfSource, Channels, Lookup, Vec3};

use render::cache::predicted;
use render::{EnvMode, EnvTableSpec, SphereOptions, render_sphere};

/// A grid source (a predicted or stored material) that counts the cells evaluated (one relaxed
/// atomic add per cell); everything else, the prefetch hint included, is the material's own.
struct Counted<S>(S, AtomicUsize);

impl<S: BrdfSource> Counted<S> {
    fn new(m: S) -> Self {
        Self(m, AtomicUsize::new(0))
    }
    fn computed_cells(&self) -> usize {
        self.1.load(Ordering::Relaxed)
    }
}

impl<S: BrdfSource> BrdfSource for Counted<S> {
    fn channels(&self) -> Channels {
        BrdfSource::channels(&self.0)
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        BrdfSource::eval(&self.0, wi, wo, out)
    }
    fn grid(&self) -> Option<AngularGrid> {
        BrdfSource::grid(&self.0)
    }
    fn lookup(&self) -> Lookup {
        self.0.lookup()
    }
    fn eval_cell(&self, a: usize, out: &mut [f64]) -> brdf_io::Result<()> {
        self.1.fetch_add(1, Ordering::Relaxed);
        BrdfSource::eval_cell(&self.0, a, out)
    }
    fn prefetch_cell(&self, a: usize) {
        BrdfSource::prefetch_cell(&self.0, a);
    }
    fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        BrdfSource::will_need_cells(&self.0, cells);
    }
    fn takes_cell_hints(&self) -> bool {
        self.0.takes_cell_hints()
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The dense reference table of the accuracy comparisons.
const DENSE_TABLE: EnvTableSpec = EnvTableSpec {
    nodes: 128,
    rings: 512,
    azimuths: 32,
};

/// `--stored-materials`: each stored material of `store` rendered (`size` pixels) with several
/// table resolutions, against [`DENSE_TABLE`]; one row per material, then the worst per spec.
fn stored_materials_study(
    store: std::sync::Arc<brdf_io::store::Store>,
    size: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    let spec = |nodes, rings, azimuths| EnvTableSpec {
        nodes,
        rings,
        azimuths,
    };
    let specs = [
        EnvTableSpec::FAST,
        spec(16, 64, 4),
        spec(16, 128, 8),
        EnvTableSpec::default(),
        spec(32, 256, 8),
        spec(32, 64, 2),
        spec(24, 64, 2),
        spec(12, 128, 8),
        spec(16, 128, 4),
        spec(16, 96, 4),
        spec(20, 128, 8),
        spec(24, 128, 8),
        spec(24, 96, 4),
        spec(32, 64, 4),
        spec(32, 96, 4),
        spec(32, 128, 4),
    ];
    let opts = |spec| SphereOptions {
        size,
        env_mode: EnvMode::Table(spec),
        ..SphereOptions::default()
    };
    println!(
        "{size} px, against the dense table {DENSE_TABLE:?}; per spec: max |img - dense| (linear), mean, max 8-bit code difference"
    );
    println!(
        "material | {}",
        specs
            .iter()
            .map(|s| format!("({}, {}, {})", s.nodes, s.rings, s.azimuths))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    // Cells each table touches (with the light): the scene's, the same for every grid source.
    let first = brdf_io::store::StoreMaterial::by_index(store.clone(), 0)?;
    let mut cells = Vec::with_capacity(specs.len());
    for spec in &specs {
        render::sphere::clear_plans();
        let counted = Counted::new(first.clone());
        render_sphere(&counted, &opts(*spec))?;
        cells.push(counted.computed_cells());
    }
    let mut worst = vec![(0.0f64, 0.0f64, 0u8); specs.len()];
    let names: Vec<String> = store.names().into_iter().map(String::from).collect();
    for (index, name) in names.into_iter().enumerate() {
        let m = brdf_io::store::StoreMaterial::by_index(store.clone(), index)?;
        let dense = render_sphere(&m, &opts(DENSE_TABLE))?;
        let mut line = name;
        for (spec, w) in specs.iter().zip(&mut worst) {
            let render::ImageDifference { max, mean, codes } =
                render_sphere(&m, &opts(*spec))?.difference(&dense)?;
            line += &format!(" | {max:.1e} {mean:.1e} {codes}");
            *w = (w.0.max(max), w.1.max(mean), w.2.max(codes));
        }
        println!("{line}");
    }
    for ((s, w), c) in specs.iter().zip(&worst).zip(&cells) {
        println!(
            "({}, {}, {}): worst max {:.2e}, worst mean {:.2e}, worst code difference {}, {c} cells at {size} px",
            s.nodes, s.rings, s.azimuths, w.0, w.1, w.2
        );
    }
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let model =
        std::path::PathBuf::from(args.get(1).ok_or("usage: render_bench MODEL.toml [SIZE]")?);
    let size: usize = args
        .get(2)
        .filter(|s| !s.starts_with("--"))
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(256);
    let lookup: Lookup = match args.iter().position(|a| a == "--lookup") {
        Some(at) => args.get(at + 1).ok_or("--lookup linear|log")?.parse()?,
        None => Lookup::Multilinear,
    };
    let mut pred = predict::Predictor::open(&model)?;
    if args.iter().any(|a| a == "--stored-materials") {
        return stored_materials_study(pred.store().clone(), size);
    }
    let dir = tempfile::tempdir()?;
    // `--sidecar`: read forward-transformed values (built once per dataset, not timed), so a
    // lookup under `log` costs N multiply-adds and no logarithms.
    if args.iter().any(|a| a == "--sidecar") && pred.transform() != gplvm::Transform::Raw {
        let side = dir.path().join("side.sbrdf");
        let t = Instant::now();
        pred.build_transformed_store(&side, |_, _| {})?;
        println!(
            "built the forward-transformed sidecar in {:.2} s (once per dataset, not timed below)",
            t.elapsed().as_secs_f64()
        );
        pred = pred.with_transformed_store(&side)?;
    }
    let mats = &pred.model().materials;
    let x: Vec<f64> = mats[0]
        .coords
        .iter()
        .zip(&mats[1].coords)
        .map(|(a, b)| 0.5 * (a + b))
        .collect();
    let opts = SphereOptions {
        size,
        ..SphereOptions::default()
    };
    println!(
        "model {} ({} materials, grid {}, {} channels), point {x:?}, {size}x{size}, {} rayon threads, {lookup} lookups",
        model.display(),
        mats.len(),
        pred.grid(),
        pred.channels().len(),
        rayon::current_num_threads()
    );
    let needed = render::colour::needed_wavelengths(pred.channels(), opts.illuminant)?;
    // The prediction at a latent point, at the observer's wavelengths (and under the lookup).
    let predicted_at =
        |x: &[f64]| -> Result<predict::PredictedMaterial, Box<dyn std::error::Error>> {
            let mut m = pred.predict(x, predict::PredictorKind::Exact)?;
            if let Some(w) = &needed {
                m = m.with_wavelengths(w)?;
            }
            Ok(m)
        };
    let looked_up_at = |x: &[f64]| -> Result<_, Box<dyn std::error::Error>> {
        Ok(WithLookup::new(predicted_at(x)?, lookup)?)
    };
    let predicted_material = || predicted_at(&x);
    let lazy_material = || looked_up_at(&x);
    // `--loop N`: only the mean time of N lazy renders, each of a new prediction at the same
    // point, the scene's plan cached (a steadier number than the medians of 5 below, for
    // comparing builds).
    if let Some(at) = args.iter().position(|a| a == "--loop") {
        let n: usize = args.get(at + 1).ok_or("--loop N")?.parse()?;
        render_sphere(&lazy_material()?, &opts)?;
        let t = Instant::now();
        for _ in 0..n {
            render_sphere(&lazy_material()?, &opts)?;
        }
        println!(
            "lazy, plan cached: {:.4} s per render, mean of {n}",
            t.elapsed().as_secs_f64() / n.max(1) as f64
        );
        return Ok(());
    }
    // `--together K`: K predictions on the line through the first two materials (t in
    // [-0.5, 1.5]) rendered one by one and together (`render_spheres`: each planned cell read
    // once for all), the plan cached; medians of 5; the images must be identical.
    if let Some(at) = args.iter().position(|a| a == "--together") {
        let k: usize = args.get(at + 1).ok_or("--together K")?.parse()?;
        let point = |i: usize| -> Vec<f64> {
            let t = -0.5 + 2.0 * i as f64 / (k.max(2) - 1) as f64;
            let (a, b) = (&mats[0].coords, &mats[1].coords);
            a.iter().zip(b).map(|(a, b)| a + t * (b - a)).collect()
        };
        let materials = (0..k)
            .map(|i| looked_up_at(&point(i)))
            .collect::<Result<Vec<_>, _>>()?;
        let sources: Vec<&dyn BrdfSource> = materials.iter().map(|m| m as _).collect();
        render_sphere(sources[0], &opts)?;
        let (mut alone, mut together) = (Vec::new(), Vec::new());
        let (mut solo, mut batch) = (Vec::new(), Vec::new());
        for _ in 0..5 {
            let t = Instant::now();
            solo = sources
                .iter()
                .map(|s| render_sphere(*s, &opts))
                .collect::<Result<Vec<_>, _>>()?;
            alone.push(t.elapsed().as_secs_f64());
            let t = Instant::now();
            batch = render::render_spheres(&sources, &opts)
                .into_iter()
                .collect::<Result<Vec<_>, _>>()?;
            together.push(t.elapsed().as_secs_f64());
        }
        let same = solo
            .iter()
            .zip(&batch)
            .all(|(a, b)| a.rgb == b.rgb && a.alpha == b.alpha);
        let (alone, together) = (median(alone), median(together));
        println!(
            "{k} predictions of {size} px, plan cached: one by one {alone:.4} s, together \
             {together:.4} s ({:.2}x); identical images: {same}",
            alone / together
        );
        return if same {
            Ok(())
        } else {
            Err("the spheres rendered together differ from the ones rendered alone".into())
        };
    }
    // Lazy, the scene's render plan built by this render (no earlier render of this view and
    // size in the process): median of 5.
    let cold_median = |o: &SphereOptions| -> Result<f64, Box<dyn std::error::Error>> {
        let mut times = Vec::new();
        for _ in 0..5 {
            render::clear_plans();
            let t = Instant::now();
            render_sphere(&lazy_material()?, o)?;
            times.push(t.elapsed().as_secs_f64());
        }
        Ok(median(times))
    };
    let cold = cold_median(&opts)?;
    // Lazy, plan cached (the renderer evaluates each touched cell once per render).
    let mut lazy = Vec::new();
    let mut reference = None;
    let mut cells = 0;
    for _ in 0..5 {
        let t = Instant::now();
        let src = Counted::new(lazy_material()?);
        let img = render_sphere(&src, &opts)?;
        lazy.push(t.elapsed().as_secs_f64());
        cells = src.computed_cells();
        reference = Some(img);
        if lazy.len() == 5 {
            // Renders of a material behind a persistent cell cache, once warm: the cost of the
            // lookups alone.
            let src = WithLookup::new(predicted(predicted_material()?), lookup)?;
            render_sphere(&src, &opts)?;
            let mut warm = Vec::new();
            for _ in 0..3 {
                let t = Instant::now();
                render_sphere(&src, &opts)?;
                warm.push(t.elapsed().as_secs_f64());
            }
            println!(
                "render on a warm cache (no prediction): {:.4} s median of 3",
                median(warm)
            );
            // The per-pixel environment quadrature on the same (now warmer) cache.
            let per_pixel = SphereOptions {
                env_mode: EnvMode::PerPixel,
                ..opts.clone()
            };
            let t = Instant::now();
            let pp = render_sphere(&src, &per_pixel)?;
            let t_pp = t.elapsed().as_secs_f64();
            let img = reference.as_ref().ok_or("no lazy image")?;
            let (mut max, mut sum, mut n) = (0.0f64, 0.0, 0);
            for ((a, b), al) in img.rgb.iter().zip(&pp.rgb).zip(&img.alpha) {
                if *al > 0.0 {
                    max = (0..3).map(|c| (a[c] - b[c]).abs()).fold(max, f64::max);
                    sum += (a[1] - b[1]).abs();
                    n += 1;
                }
            }
            println!(
                "per-pixel environment (20 directions per pixel) on the warm cache: {t_pp:.3} s \
                 ({} cells computed now); |table - per-pixel| linear sRGB: max {max:.2e}, mean \
                 (G) {:.2e}, mean G value {:.3}",
                src.inner().computed_cells(),
                sum / n.max(1) as f64,
                render::sphere::mean_colour(img).0[1]
            );
        }
    }
    let lazy = median(lazy);
    // What the picture needs: cells touched by the light term alone (no environment).
    let light_only = Counted::new(lazy_material()?);
    render_sphere(
        &light_only,
        &SphereOptions {
            env_radiance: 0.0,
            ..opts.clone()
        },
    )?;
    println!(
        "cells touched by the light term alone: {}",
        light_only.computed_cells()
    );
    println!(
        "lazy (each touched cell once, {} wavelengths): {lazy:.4} s median of 5 with the scene's \
         render plan cached, {cold:.4} s building it; {cells} of {} cells computed",
        needed.as_ref().map_or(pred.channels().len(), |w| w.len()),
        pred.grid().len()
    );
    // Environment-table resolution against cost: cold-cache lazy renders (cells predicted)
    // and the largest deviation from a dense table (128 nodes, 512 rings x 32 azimuths).
    let dense_src = lazy_material()?;
    let mut fast = f64::NAN;
    let dense = render_sphere(
        &dense_src,
        &SphereOptions {
            env_mode: EnvMode::Table(DENSE_TABLE),
            ..opts.clone()
        },
    )?;
    println!(
        "table (nodes, rings, azimuths) | lazy s (median of 5) | cells | max |img - dense| (linear) | mean | max 8-bit sRGB code difference"
    );
    for (nodes, rings, azimuths) in [
        (16, 32, 2),
        (16, 64, 2),
        (16, 64, 4),
        (16, 128, 8),
        (32, 64, 4),
        (32, 128, 8),
        (64, 128, 8),
    ] {
        let mode = EnvMode::Table(EnvTableSpec {
            nodes,
            rings,
            azimuths,
        });
        let o = SphereOptions {
            env_mode: mode,
            ..opts.clone()
        };
        let (mut times, mut cells, mut img) = (Vec::new(), 0, None);
        for _ in 0..5 {
            let t = Instant::now();
            let src = Counted::new(lazy_material()?);
            img = Some(render_sphere(&src, &o)?);
            times.push(t.elapsed().as_secs_f64());
            cells = src.computed_cells();
        }
        let img = img.ok_or("no image")?;
        let render::ImageDifference { max, mean, codes } = img.difference(&dense)?;
        let t = median(times);
        if mode == EnvMode::Table(EnvTableSpec::FAST) {
            fast = t;
        }
        println!(
            "({nodes}, {rings}, {azimuths}) | {t:.3} | {cells} | {max:.2e} | {mean:.2e} | {codes}"
        );
    }
    let pp = render_sphere(
        &dense_src,
        &SphereOptions {
            env_mode: EnvMode::PerPixel,
            ..opts.clone()
        },
    )?;
    let render::ImageDifference { max, mean, codes } = pp.difference(&dense)?;
    println!(
        "per-pixel quadrature: |img - dense| max {max:.2e}, mean {mean:.2e}, {codes} 8-bit codes"
    );
    // Materialise then render.
    let mut mat = Vec::new();
    for run in 0..3 {
        let t = Instant::now();
        let m = pred.predict(&x, predict::PredictorKind::Exact)?;
        let path = dir.path().join(format!("m{run}.sbrdf"));
        m.materialize(&path, |_, _| {})?;
        let t_mat = t.elapsed().as_secs_f64();
        let src = WithLookup::new(
            brdf_io::store::StoreMaterial::open(&path, m.label())?,
            lookup,
        )?;
        let img = render_sphere(&src, &opts)?;
        let total = t.elapsed().as_secs_f64();
        mat.push(total);
        if run == 0 {
            let diff = img
                .rgb
                .iter()
                .zip(&reference.as_ref().ok_or("no lazy image")?.rgb)
                .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0, f64::max))
                .fold(0.0, f64::max);
            println!(
                "materialise {t_mat:.3} s + render {:.3} s; max |lazy - materialised| = {diff:.2e} (f32 storage)",
                total - t_mat
            );
        }
    }
    let mat = median(mat);
    println!(
        "materialise-then-render: {mat:.3} s median of 3; lazy is {:.1}x faster ({:.1}x with \
         the plan built by the render)",
        mat / lazy,
        mat / cold
    );
    let fast_opts = SphereOptions {
        env_mode: EnvMode::Table(EnvTableSpec::FAST),
        ..opts.clone()
    };
    let fast_cold = cold_median(&fast_opts)?;
    println!(
        "with EnvTableSpec::FAST (`specgp render --env fast`): lazy {fast:.4} s, {:.1}x faster \
         ({fast_cold:.4} s, {:.1}x, with the plan built by the render)",
        mat / fast,
        mat / fast_cold
    );
    Ok(())
}
