//! End to end: `configs/quick.toml` through the whole pipeline into a temporary directory, then
//! the report's numbers checked against the model file and the data.

use std::path::Path;

use brdf_io::albedo::directional_albedo;
use xtask::{PipelineConfig, project_root};

fn load(root: &Path, rel: &str) -> PipelineConfig {
    PipelineConfig::load(&root.join(rel), root).unwrap()
}

/// The names in directory `p`, sorted.
fn entries(p: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(p)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    v.sort();
    v
}

/// A source evaluated pair by pair (its grid hidden).
struct PairByPair<'a>(&'a dyn brdf_io::BrdfSource);

impl brdf_io::BrdfSource for PairByPair<'_> {
    fn channels(&self) -> brdf_io::Channels {
        self.0.channels()
    }
    fn eval(&self, wi: brdf_io::Vec3, wo: brdf_io::Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        self.0.eval(wi, wo, out)
    }
}

#[test]
fn quick_pipeline_report_matches_the_model_and_data() {
    let root = project_root();
    let config = load(&root, "configs/quick.toml");
    let dir = tempfile::tempdir().unwrap();
    let results = xtask::run(&config, dir.path()).unwrap();

    // results.json parses and says what the returned results say.
    let text = std::fs::read_to_string(dir.path().join("results.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let ll = json["fit"]["log_likelihood"].as_f64().unwrap();
    assert!(ll.is_finite());
    assert_eq!(ll, results.fit.log_likelihood);

    // The log-likelihood is the model file's.
    let model = gplvm::Model::load(&dir.path().join("model.toml")).unwrap();
    assert_eq!(model.fit.log_likelihood, ll);
    assert!(ll > json["fit"]["initial_log_likelihood"].as_f64().unwrap());

    // Number of materials: the preset's, in the data, the model and the latent table.
    let n = brdf_synth::N_MATERIALS;
    assert_eq!(json["data"]["n_materials"].as_u64().unwrap() as usize, n);
    assert_eq!(model.materials.len(), n);
    let latent = json["latent"].as_array().unwrap();
    assert_eq!(latent.len(), n);
    for (row, m) in latent.iter().zip(&model.materials) {
        assert_eq!(row["name"].as_str().unwrap(), m.name);
        let coords: Vec<f64> = row["coords"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(coords, m.coords);
    }
    // D = cells x channels of the configured grid and wavelengths.
    assert_eq!(json["data"]["d"].as_u64().unwrap(), 8 * 8 * 16 * 7);
    assert!(json["data"]["store_bytes"].as_u64().unwrap() > (n * 8 * 8 * 16 * 7) as u64);

    // Every stage is accounted for with a finite non-negative time.
    for st in json["stages"].as_array().unwrap() {
        let s = st["seconds"].as_f64().unwrap();
        assert!(s.is_finite() && s >= 0.0, "{st}");
    }

    // Evaluation: every error finite and non-negative; the exact predictor reproduces the
    // training materials (the paper's ~0 reconstruction error).
    let eval = &json["evaluation"];
    // Paths name the published files, not the staging directory (deleted after publishing).
    assert_eq!(eval["dataset"].as_str().unwrap(), "data.sbrdf");
    let report = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    let regenerate = format!(
        "regenerate with `cargo xtask pipeline {} --out {}`",
        config.path.display(),
        dir.path().display()
    );
    assert!(report.contains(&regenerate), "{report}");
    assert!(!text.contains(".tmp/") && !report.contains(".tmp/"));
    let recon = eval["reconstruction"].as_array().unwrap();
    assert_eq!(recon.len(), n);
    let finite = |v: &serde_json::Value| {
        let x = v.as_f64().unwrap();
        assert!(x.is_finite() && x >= 0.0, "{v}");
        x
    };
    let mut smooth_max = 0.0f64;
    for row in recon {
        let exact = finite(&row["exact_rmse"]);
        assert!(exact < 1e-8, "{row}");
        assert!(finite(&row["exact_model_rmse"]) < 1e-6, "{row}");
        smooth_max = smooth_max.max(finite(&row["smooth_rmse"]));
        finite(&row["smooth_model_rmse"]);
    }
    // The smooth predictor does not interpolate: some material is visibly off.
    assert!(smooth_max > 1e-6, "{smooth_max}");
    let loo = eval["loo"].as_array().unwrap();
    assert_eq!(loo.len(), n);
    for row in loo {
        for m in row["methods"].as_array().unwrap() {
            finite(&m["brdf_rmse"]);
            finite(&m["model_rmse"]);
        }
    }
    // Predictions: the configured point and midpoint, materialised with the right size.
    let preds = json["predictions"].as_array().unwrap();
    assert_eq!(preds.len(), 2);
    let pred = predict::Predictor::open(&dir.path().join("model.toml")).unwrap();
    let mut midpoints_checked = 0;
    for p in preds {
        assert!(finite(&p["variance"]) > 0.0 || p["label"] != "point 1");
        // The variance is that of the predictor the row used, per transformed value.
        let kind = match p["predictor"].as_str().unwrap() {
            "exact" => predict::PredictorKind::Exact,
            _ => predict::PredictorKind::Smooth,
        };
        let x: Vec<f64> = p["point"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let want = pred.variance_transformed(&x, kind).unwrap();
        assert_eq!(p["variance"].as_f64().unwrap(), want, "{p}");
        // The timed lookups read every cell of this small grid once: their mean value.
        let m = pred.predict(&x, kind).unwrap();
        let (cells, nc) = (pred.grid().len(), 7);
        let mut out = vec![0.0; nc];
        let mut sum = 0.0;
        for a in 0..cells {
            m.eval_cell(a, &mut out).unwrap();
            sum += out.iter().sum::<f64>();
        }
        let mean = sum / (cells * nc) as f64;
        let shown = finite(&p["lookup_mean"]);
        assert!(
            (shown - mean).abs() <= 1e-12 * mean.abs(),
            "{shown} vs {mean}"
        );
        assert!(finite(&p["lookup_us"]) > 0.0, "{p}");
        // The largest directional albedo: the prediction's, evaluated pair by pair here (the
        // pipeline integrates each touched cell once).
        let albedo = directional_albedo(
            &PairByPair(&m),
            &brdf_io::rgl::ALBEDO_THETAS_DEG,
            brdf_io::albedo::DEFAULT_RESOLUTION,
        )
        .unwrap();
        let peak = albedo.peak().unwrap();
        let shown = &p["albedo"];
        assert!(
            (finite(&shown["value"]) - peak.value).abs() <= 1e-9 * peak.value,
            "{shown}"
        );
        assert_eq!(shown["angle_deg"].as_f64().unwrap(), peak.angle_deg);
        assert_eq!(
            shown["channel"].as_str().unwrap(),
            albedo.channels.labels()[peak.channel]
        );
        let file = dir.path().join(p["file"].as_str().unwrap());
        let bytes = std::fs::metadata(&file).unwrap().len();
        assert_eq!(bytes, p["file_bytes"].as_u64().unwrap());
        assert!(bytes >= (8 * 8 * 16 * 7 * 4) as u64);
        // The RGL file of the prediction reads back as the lazy prediction.
        let b = &p["bsdf"];
        let path = dir.path().join(b["file"].as_str().unwrap());
        assert_eq!(
            std::fs::metadata(&path).unwrap().len(),
            b["bytes"].as_u64().unwrap()
        );
        let check = finite(&b["check_rms"]);
        assert!(check > 0.0 && check < 0.05, "{b}");
        let file = brdf_io::rgl::RglBsdf::open(&path).unwrap();
        let label = p["label"].as_str().unwrap();
        assert_eq!(file.description(), format!("specgp prediction: {label}"));
        if label == "mid(metal_gold, metal_copper)" {
            // The midpoint is halfway between the two named materials' latent points.
            let at = |name: &str| {
                let m = pred.model().materials.iter().find(|m| m.name == name);
                m.unwrap().coords.clone()
            };
            let (a, b) = (at("metal_gold"), at("metal_copper"));
            let mid: Vec<f64> = a.iter().zip(&b).map(|(p, q)| 0.5 * (p + q)).collect();
            assert_eq!(x, mid);
            midpoints_checked += 1;
        }
        let lazy = pred.predict(&x, kind).unwrap();
        let (wi, wo) = ([0.3, 0.1, 0.949], [-0.5, 0.2, 0.843]);
        let (mut f, mut g) = (vec![0.0; 7], vec![0.0; 7]);
        brdf_io::BrdfSource::eval(&file, wi, wo, &mut f).unwrap();
        brdf_io::BrdfSource::eval(&lazy, wi, wo, &mut g).unwrap();
        for (a, b) in f.iter().zip(&g) {
            assert!((a - b).abs() <= 0.1 * b.abs() + 1e-9, "{f:?} {g:?}");
        }
    }
    assert_eq!(midpoints_checked, 1);
    // The stored materials' largest albedo, in store order; the report counts those above 1.
    let stored = json["stored_albedo"].as_array().unwrap();
    assert_eq!(stored.len(), n);
    let weights = brdf_io::albedo::GridAlbedo::new(
        pred.grid(),
        &brdf_io::rgl::ALBEDO_THETAS_DEG,
        brdf_io::albedo::DEFAULT_RESOLUTION,
    )
    .unwrap();
    let mut above = 0;
    for (row, m) in stored.iter().zip(&model.materials) {
        assert_eq!(row["material"].as_str().unwrap(), m.name);
        let source = brdf_io::store::StoreMaterial::open(dir.path().join("data.sbrdf"), &m.name);
        let want = weights.table(&source.unwrap()).unwrap().peak().unwrap();
        assert_eq!(row["peak"]["value"].as_f64().unwrap(), want.value, "{row}");
        above += usize::from(brdf_io::albedo::gains_energy(want.value));
    }
    let report = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(
        report.contains(&format!(
            "{above} of the {n} stored materials exceed 1 + 0.005"
        )),
        "{report}"
    );
    assert!(
        report.contains("The predictions as RGL `.bsdf` files"),
        "{report}"
    );

    // Errors by kind cover every material once, and match the per-material means.
    let kinds = json["by_kind"].as_array().unwrap();
    let total: u64 = kinds.iter().map(|k| k["n"].as_u64().unwrap()).sum();
    assert_eq!(total as usize, n);
    let weighted: f64 = kinds
        .iter()
        .map(|k| k["n"].as_f64().unwrap() * finite(&k["reconstruction_smooth"]))
        .sum();
    let direct: f64 = recon
        .iter()
        .map(|r| r["smooth_rmse"].as_f64().unwrap())
        .sum();
    assert!(
        (weighted - direct).abs() <= 1e-9 * direct.max(1.0),
        "{weighted} vs {direct}"
    );
    // The same for the leave-one-out errors of the GP (not of another method).
    let weighted: f64 = kinds
        .iter()
        .map(|k| k["n"].as_f64().unwrap() * finite(&k["loo_gp"]))
        .sum();
    let direct: f64 = loo
        .iter()
        .flat_map(|r| r["methods"].as_array().unwrap())
        .filter(|m| m["method"] == "gp")
        .map(|m| m["brdf_rmse"].as_f64().unwrap())
        .sum();
    assert!(
        (weighted - direct).abs() <= 1e-9 * direct.max(1.0),
        "{weighted} vs {direct}"
    );

    // Figures exist and the rendered errors are finite and non-negative.
    for f in json["figures"]["files"].as_array().unwrap() {
        let file = dir.path().join(f[0].as_str().unwrap());
        assert!(
            std::fs::metadata(&file).unwrap().len() > 100,
            "{}",
            file.display()
        );
    }
    let names: Vec<&str> = json["figures"]["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f[0].as_str().unwrap())
        .collect();
    for want in [
        "sheet.png",
        "comparison.png",
        "paths.png",
        "predictions.png",
        "latent.png",
    ] {
        assert!(names.contains(&want), "{want} not in {names:?}");
    }
    // The exact predictor returns a training material as stored; the smooth one is close to
    // it; a held-out prediction is further away.
    let comparison: Vec<(String, f64)> =
        serde_json::from_value(json["figures"]["comparison_delta_e"].clone()).unwrap();
    let column = |c: &str| comparison.iter().find(|(k, _)| k == c).unwrap().1;
    assert!(column("exact") < 0.01, "{comparison:?}");
    assert!(column("smooth") < column("held out"), "{comparison:?}");
    let de = json["figures"]["delta_e"].as_array().unwrap();
    assert_eq!(de.len(), 2);
    let mean: f64 = de.iter().map(|d| finite(&d["mean_delta_e"])).sum::<f64>() / 2.0;
    let shown = json["figures"]["mean_delta_e"].as_f64().unwrap();
    assert!((shown - mean).abs() <= 1e-12 * mean, "{shown} vs {mean}");
    // The comparison sheet shows the same materials and measures them the same way.
    let held: f64 = de
        .iter()
        .map(|d| finite(&d["held_out_delta_e"]))
        .sum::<f64>()
        / 2.0;
    for (c, want) in [("smooth", mean), ("held out", held)] {
        let got = column(c);
        assert!((got - want).abs() <= 1e-12 * want, "{c}: {got} vs {want}");
    }
    check_sheet(dir.path(), &pred, &results, de);
    check_paths(dir.path(), &pred);
    check_predictions(dir.path(), &pred, &results.predictions);
    check_comparison_and_latent(dir.path(), &pred, &results);

    // The markdown report quotes the numbers.
    let report = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(report.contains(&format!("| materials N | {n} |")));
    assert!(report.contains(&xtask::report::num(ll)));
    // Its sections: the config's description, the channel range (more than 4 channels), no
    // import row for synthetic data, the errors and the figures' Delta E table, and no stage
    // left out.
    assert!(report.contains("\n\nCI-sized run: 51 synthetic spectral materials"));
    assert!(
        report.contains("| channels | 7 (400 .. 700 nm) |"),
        "{report}"
    );
    assert!(!report.contains("import: outliers"));
    assert!(report.contains("\n## Errors\n") && report.contains("Streaming pass"));
    assert!(
        report.contains(
            "| material | Delta E 2000 (smooth reconstruction) | Delta E 2000 (held out) |"
        )
    );
    assert!(!report.contains("Not available in this build"));
}

/// The figures' background and text colours (figures.rs): light grey on dark grey.
const FIGURE_BG: [f64; 3] = [0.18, 0.18, 0.18];
const FIGURE_INK: [f64; 3] = [0.9, 0.9, 0.9];

/// The PNG at `path` is `want` pixel for pixel (8-bit sRGB with alpha).
fn assert_png_is(path: &Path, want: &render::Image) {
    let (w, h, png) = render::image::read_png_rgba8(path).unwrap();
    assert_eq!((w, h), (want.width, want.height), "{}", path.display());
    let want = want.to_rgba8();
    if let Some(k) = (0..w * h).find(|k| png[4 * k..4 * k + 4] != want[4 * k..4 * k + 4]) {
        panic!(
            "{} differs first at pixel ({}, {})",
            path.display(),
            k % w,
            k / w
        );
    }
}

/// The quick pipeline's leave-one-out prediction of material `name`.
fn held_out(
    pred: &predict::Predictor,
    results: &xtask::Results,
    name: &str,
) -> predict::PredictedMaterial {
    let loo = results.evaluation.as_ref().unwrap().loo.as_ref().unwrap();
    let row = loo.iter().find(|r| r.name == name).unwrap();
    pred.from_coefficients(row.gp_coefficients.clone(), name.into())
        .unwrap()
}

/// The quick pipeline's `sheet.png` (32-pixel spheres, 2 materials, leave-one-out run) is
/// exactly what its Delta E values measure: for the materials picked evenly through the dataset
/// (0 and N / 2), the stored material's sphere on top, labelled with its name, the smooth
/// reconstruction at its latent point in the middle and the held-out prediction at the bottom,
/// each labelled with its mean Delta E against the stored sphere; and the report's values are
/// those means.
fn check_sheet(
    out: &Path,
    pred: &predict::Predictor,
    results: &xtask::Results,
    delta_e: &[serde_json::Value],
) {
    use render::{Image, SphereOptions, render_sphere};
    // The sheet's cell and label sizes (figures.rs): names wrap into up to three lines of 9
    // pixels, the Delta E values are cut to one line of the sphere's width, 2 pixels under
    // the sphere.
    let (size, picked, line_h) = (32, delta_e.len(), 9);
    let (cell, label_h) = (size + 8, 3 * line_h + 3);
    let opts = SphereOptions {
        size,
        ..SphereOptions::default()
    };
    let n = pred.n_materials();
    let (w, h) = (picked * cell + 4, 3 * (cell + label_h) + 4);
    let mut want = Image::new(w, h, FIGURE_BG);
    for (col, d) in delta_e.iter().enumerate() {
        let name = d["name"].as_str().unwrap();
        let i = pred.material_index(name).unwrap();
        assert_eq!(i, col * n / picked, "{name}");
        let stored = brdf_io::store::StoreMaterial::by_index(pred.store().clone(), i).unwrap();
        let coords = &pred.model().materials[i].coords;
        let smooth = pred
            .predict(coords, predict::PredictorKind::Smooth)
            .unwrap();
        let held = held_out(pred, results, name);
        let spheres = [
            render_sphere(&stored, &opts).unwrap(),
            render_sphere(&smooth, &opts).unwrap(),
            render_sphere(&held, &opts).unwrap(),
        ];
        let de = |k: usize| xtask::figures::mean_delta_e(&spheres[0], &spheres[k]).unwrap();
        assert_eq!(d["mean_delta_e"].as_f64().unwrap(), de(1), "{name}");
        assert_eq!(d["held_out_delta_e"].as_f64().unwrap(), de(2), "{name}");
        assert!(de(1) < de(2), "{name}: {} {}", de(1), de(2));
        let labels = [
            render::font::wrap(name, size, 1, 3),
            render::font::wrap(&format!("rec dE {:.2}", de(1)), size, 1, 1),
            render::font::wrap(&format!("loo dE {:.2}", de(2)), size, 1, 1),
        ];
        assert!(labels[0].len() > 1, "{:?}", labels[0]);
        for (r, (sphere, lines)) in spheres.iter().zip(&labels).enumerate() {
            let (x0, y0) = (4 + col * cell, 4 + r * (cell + label_h));
            want.blit(sphere, x0 as i64, y0 as i64);
            for (k, text) in lines.iter().enumerate() {
                let y = y0 + size + 2 + k * line_h;
                want.text(x0 as i64, y as i64, text, 1, FIGURE_INK);
            }
        }
    }
    assert_png_is(&out.join("sheet.png"), &want);
}

/// The quick pipeline's `paths.png` (its one midpoint pair, log model) is exactly the paper's
/// Fig. 4.4 for gold to copper: under the title, three rows of 7 spheres at t = 0, 1/6, ...,
/// 1: the exact GP prediction along the straight latent line from gold to copper, the linear
/// blend in the model's (log) space, and the linear blend of the BRDF values.
fn check_paths(out: &Path, pred: &predict::Predictor) {
    use brdf_io::store::StoreMaterial;
    use render::{Image, SphereOptions};
    let (a, b) = ("metal_gold", "metal_copper");
    let (ia, ib) = (
        pred.material_index(a).unwrap(),
        pred.material_index(b).unwrap(),
    );
    let (xa, xb) = (
        &pred.model().materials[ia].coords,
        &pred.model().materials[ib].coords,
    );
    let t: Vec<f64> = (0..7).map(|k| f64::from(k) / 6.0).collect();
    let gp: Vec<_> = t
        .iter()
        .map(|&s| {
            let x: Vec<f64> = xa.iter().zip(xb).map(|(p, q)| p + s * (q - p)).collect();
            pred.predict(&x, predict::PredictorKind::Exact).unwrap()
        })
        .collect();
    let lerp: Vec<_> = t
        .iter()
        .map(|&s| pred.lerp(a, b, 1.0 - s).unwrap())
        .collect();
    let stored_a = StoreMaterial::by_index(pred.store().clone(), ia).unwrap();
    let stored_b = StoreMaterial::by_index(pred.store().clone(), ib).unwrap();
    let blends: Vec<_> = t
        .iter()
        .map(|&s| brdf_io::Blend::new(&stored_a, &stored_b, 1.0 - s).unwrap())
        .collect();
    let rows: Vec<render::sheet::SheetRow<'_>> = vec![
        ("GP PATH".into(), gp.iter().map(|m| m as _).collect()),
        (
            "LINEAR, MODEL SPACE".into(),
            lerp.iter().map(|m| m as _).collect(),
        ),
        (
            "LINEAR, BRDF VALUES".into(),
            blends.iter().map(|m| m as _).collect(),
        ),
    ];
    let captions: Vec<String> = t.iter().map(|v| format!("{v:.2}")).collect();
    let opts = SphereOptions {
        size: 32,
        ..SphereOptions::default()
    };
    let block = render::sphere_rows(&rows, &captions, &opts).unwrap();
    let mut want = Image::new(block.width + 8, block.height + 9 + 6 + 4, FIGURE_BG);
    want.text(4, 4, "METAL_GOLD TO METAL_COPPER", 1, FIGURE_INK);
    want.blit(&block, 4, 4 + 9 + 2);
    assert_png_is(&out.join("paths.png"), &want);
}

/// The quick pipeline's `predictions.png` is exactly its predictions rendered in a row: each
/// sphere (by the row's own predictor) labelled with the prediction's name and its latent
/// coordinates to two decimals, each wrapped into up to three lines of the sphere's width.
fn check_predictions(out: &Path, pred: &predict::Predictor, rows: &[xtask::stages::PredictionRow]) {
    use render::{Image, SphereOptions, render_sphere};
    // The figure's cell and label sizes (figures.rs).
    let (size, line_h) = (32, 9);
    let (cell, label_h) = (size + 8, 3 * line_h + 3);
    let opts = SphereOptions {
        size,
        ..SphereOptions::default()
    };
    assert_eq!(rows.len(), 2);
    let mut want = Image::new(rows.len() * cell + 4, cell + 2 * label_h + 4, FIGURE_BG);
    for (col, row) in rows.iter().enumerate() {
        let kind = match row.predictor.as_str() {
            "exact" => predict::PredictorKind::Exact,
            other => panic!("the quick config predicts with `exact`, not {other}"),
        };
        let sphere = render_sphere(&pred.predict(&row.point, kind).unwrap(), &opts).unwrap();
        let x = 4 + col * cell;
        want.blit(&sphere, x as i64, 4);
        let coords: Vec<String> = row.point.iter().map(|v| format!("{v:.2}")).collect();
        for (j, text) in [row.label.clone(), coords.join(", ")].iter().enumerate() {
            for (k, line) in render::font::wrap(text, size, 1, 3).iter().enumerate() {
                let y = 4 + size + 2 + j * label_h + k * line_h;
                want.text(x as i64, y as i64, line, 1, FIGURE_INK);
            }
        }
    }
    assert_png_is(&out.join("predictions.png"), &want);
}

/// The quick pipeline's `comparison.png` and `latent.png` are the render crate's figures of
/// what the run holds: the comparison sheet of the two picked materials (stored, exact,
/// smooth, held out; Delta E scale 0-10), and the latent map of the 51 materials and the two
/// predictions over the predictive standard deviation, with its caption.
fn check_comparison_and_latent(out: &Path, pred: &predict::Predictor, results: &xtask::Results) {
    use predict::PredictorKind::{Exact, Smooth};
    let opts = render::SphereOptions {
        size: 32,
        ..render::SphereOptions::default()
    };
    let model = pred.model();
    let n = model.materials.len();
    let kept: Vec<(String, Vec<Box<dyn brdf_io::BrdfSource>>)> = [0, n / 2]
        .iter()
        .map(|&i| {
            let m = &model.materials[i];
            let sources: Vec<Box<dyn brdf_io::BrdfSource>> = vec![
                Box::new(brdf_io::store::StoreMaterial::by_index(pred.store().clone(), i).unwrap()),
                Box::new(pred.predict(&m.coords, Exact).unwrap()),
                Box::new(pred.predict(&m.coords, Smooth).unwrap()),
                Box::new(held_out(pred, results, &m.name)),
            ];
            (m.name.to_uppercase(), sources)
        })
        .collect();
    let rows: Vec<render::sheet::SheetRow<'_>> = kept
        .iter()
        .map(|(name, v)| (name.clone(), v.iter().map(|b| b.as_ref()).collect()))
        .collect();
    let columns = ["STORED", "EXACT", "SMOOTH", "HELD OUT"];
    let sheet = render::comparison_sheet(&columns, &rows, &opts, 10.0).unwrap();
    assert_png_is(&out.join("comparison.png"), &sheet.image);

    let points: Vec<render::map::LabelledPoint> = model
        .materials
        .iter()
        .map(|m| (m.name.clone(), [m.coords[0], m.coords[1]]))
        .chain(
            results
                .predictions
                .iter()
                .map(|p| (p.label.clone(), [p.point[0], p.point[1]])),
        )
        .collect();
    assert_eq!((points.len(), model.latent_dim), (n + 2, 2));
    let variance = |p: [f64; 2]| Ok(pred.variance_transformed(&p, Smooth).unwrap());
    let map_opts = render::MapOptions {
        caption: render::map::variance_caption("log(offset=0.01)", 2),
        predicted_points: 2,
        ..render::MapOptions::default()
    };
    let map = render::latent_map(&points, &variance, None, &map_opts).unwrap();
    assert_png_is(&out.join("latent.png"), &map);
}

#[test]
fn configs_in_the_repository_all_validate() {
    let root = project_root();
    let mut seen = 0;
    for entry in std::fs::read_dir(root.join("configs")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml")
            && path.file_name().is_some_and(|n| n != "bench.toml")
        {
            PipelineConfig::load(&path, &root).unwrap_or_else(|e| panic!("{e}"));
            seen += 1;
        }
    }
    assert!(seen >= 2, "found {seen} configs");
}

/// Keys left out of a table take the documented defaults (`[render]` size 128, 8 sheet
/// materials, the `table` environment; `[locate]` 3 starts), and an absent table the same.
#[test]
fn left_out_keys_take_their_defaults() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(root.join("configs/quick.toml")).unwrap();
    let path = dir.path().join("defaults.toml");
    let present = base.replace("size = 32\nsheet_materials = 2", "enabled = true")
        + "\n[locate]\nfiles = [\"a.bsdf\"]\n";
    let absent = base.replace("[render]\nsize = 32\nsheet_materials = 2", "");
    for text in [present, absent] {
        std::fs::write(&path, &text).unwrap();
        let c = PipelineConfig::load(&path, &root).unwrap();
        let (r, l) = (&c.params.render, &c.params.locate);
        assert_eq!((r.enabled, r.size, r.sheet_materials), (true, 128, 8));
        assert_eq!((r.env.as_str(), l.starts), ("table", 3));
    }
}

/// Midpoints checked against a store's names once they are known (data kinds whose names are
/// read with the data): an error naming the config and the material.
#[test]
fn midpoints_are_checked_against_the_data_names() {
    let root = project_root();
    let c = load(&root, "configs/quick.toml");
    let names: Vec<String> = ["metal_gold", "metal_copper", "paper_white"]
        .map(String::from)
        .to_vec();
    c.check_midpoints(&names).unwrap();
    let err = c.check_midpoints(&names[..1]).unwrap_err().to_string();
    assert!(
        err.contains("quick.toml") && err.contains("no material named \"metal_copper\""),
        "{err}"
    );
}

/// `points = [...]` with `n` latent points.
fn points(n: usize) -> String {
    format!("points = [{}]", vec!["[0.0, 0.0]"; n].join(", "))
}

#[test]
fn unknown_keys_and_bad_values_are_named() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(root.join("configs/quick.toml")).unwrap();
    let cases = [
        (base.replace("seed = 0", "seed = 0\ncolour = 1"), "colour"),
        (
            base.replace("grid = \"8,8,16\"", "grid = \"8,0,16\""),
            "data.grid",
        ),
        (
            base.replace("kind = \"synth\"", "kind = \"mat\""),
            "data.kind",
        ),
        (
            base.replace("points = [[0.0, 0.0]]", "points = [[0.0]]"),
            "predict.points[0]",
        ),
        (
            base.replace("[fit]\nlatent_dim = 2", "[fit]\nlatent_dim = 0\n"),
            "latent_dim",
        ),
        // Checked before any data is written (they used to fail after the data and the fit).
        (
            base.replace("\"metal_copper\"]]", "\"no_such\"]]"),
            "no material named \"no_such\"",
        ),
        (
            base.replace("\"metal_copper\"]]", "\"metal_gold\"]]"),
            "names one material twice",
        ),
        (
            base.replace("\"metal_copper\"]]", "\"metal_coper\"]]"),
            "no material named \"metal_coper\"; did you mean \"metal_copper\"?",
        ),
        (
            base.replace(
                "seed = 0",
                "seed = 0\nonly = [\"metal_gold\", \"metal_gold\", \"metal_copper\", \"paper_white\"]",
            ),
            "lists \"metal_gold\" twice",
        ),
        (
            base.replace("sheet_materials = 2", "sheet_materials = 0"),
            "render.sheet_materials",
        ),
        (
            base.replace("sheet_materials = 2", "sheet_materials = 2\nenv = \"sky\""),
            "render.env \"sky\": expected `table`, `fast`, `per-pixel` or `studio`",
        ),
        (
            base.replace("grid = \"8,8,16\"", "grid = \"512,512,512\""),
            "would take 191.7 GB",
        ),
        (
            base.replace("400:700:50", "400:700:0.01"),
            "data.wavelengths",
        ),
        (
            base.replace("400:700:50", "300:700:100"),
            "data.wavelengths \"300:700:100\": ",
        ),
        (
            format!("{base}\n[locate]\nfiles = [\"a.png\"]\n"),
            "locate.files: a.png is not an RGL .bsdf or a MERL .binary file",
        ),
        (
            format!("{base}\n[locate]\nfiles = [\"a.bsdf\"]\nstarts = 0\n"),
            "locate.starts",
        ),
        // A midpoint of three names (the third used to be dropped silently) or of one.
        (
            base.replace("\"metal_copper\"]]", "\"metal_copper\", \"paper_white\"]]"),
            "predict.midpoints[0] names 3 material(s) [\"metal_gold\", \"metal_copper\", \
             \"paper_white\"]; each midpoint is a pair",
        ),
        (
            base.replace(", \"metal_copper\"]]", "]]"),
            "predict.midpoints[0] names 1 material(s)",
        ),
        // Figures too large to draw (the sheet of 51 spheres of 2048 pixels was a 10 GB image
        // that aborted the process after the fit) and a point the latent map cannot frame
        // (it failed in the render stage), before any work.
        (
            base.replace("size = 32\nsheet_materials = 2", "size = 2048\nsheet_materials = 64"),
            "render.size and render.sheet_materials ask for a sheet.png of about 106488 x 6264 \
             pixels (21.3 GB while it is drawn)",
        ),
        (
            base.replace("size = 32\nsheet_materials = 2", "size = 2048\nsheet_materials = 1"),
            "ask for a paths.png of about 14616 x 6264 pixels",
        ),
        (
            base.replace("points = [[0.0, 0.0]]", "points = [[0.0, 0.0], [0.0, -1e100]]"),
            "predict.points[1] has the coordinate -1e100, beyond +-2.5e99",
        ),
        // One sphere per point and midpoint, in cells of 1024 pixels: 64 points and the
        // midpoint are one cell more than 2^26 pixels; 63 and the midpoint, exactly 2^26, are
        // accepted below.
        (
            base.replace("size = 32", "size = 984")
                .replace("points = [[0.0, 0.0]]", &points(64)),
            "ask for a predictions.png of about 66560 x 1024 pixels",
        ),
        (base.replace("size = 32", "size = 2049"), "render.size must be in 16..=2048, got 2049"),
        (base.replace("size = 32", "size = 15"), "render.size must be in 16..=2048, got 15"),
        (
            base.replace("name = \"quick\"", "name = \"quick run\""),
            "name must be non-empty ASCII letters, digits, '-' or '_', got \"quick run\"",
        ),
        (
            base.replace("seed = 0", "seed = 0\nonly = [\"metal_gold\", \"metal_copper\"]"),
            "data.only needs at least 3 materials",
        ),
    ];
    for (i, (text, needle)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("bad{i}.toml"));
        std::fs::write(&path, text).unwrap();
        let err = PipelineConfig::load(&path, &root).unwrap_err().to_string();
        assert!(err.contains(needle), "case {i}: {err}");
        assert!(err.contains(&format!("bad{i}.toml")), "case {i}: {err}");
    }
    // The largest figures and points that are still accepted.
    for text in [
        base.replace(
            "size = 32\nsheet_materials = 2",
            "size = 1024\nsheet_materials = 8",
        ),
        base.replace("points = [[0.0, 0.0]]", "points = [[2.5e99, -2.5e99]]"),
        base.replace("size = 32", "size = 984")
            .replace("points = [[0.0, 0.0]]", &points(63)),
        base.replace("size = 32", "size = 2048\nenabled = false"),
        base.replace("size = 32", "size = 16"),
        base.replace("name = \"quick\"", "name = \"Quick-run_2\""),
        base.replace(
            "seed = 0",
            "seed = 0\nonly = [\"metal_gold\", \"metal_copper\", \"paper_white\", \"spectralon\"]",
        ),
    ] {
        let path = dir.path().join("good.toml");
        std::fs::write(&path, text).unwrap();
        PipelineConfig::load(&path, &root).unwrap();
    }
}

/// A run writes into a staging directory and publishes its files together: a failed run leaves
/// the output directory as it was; a successful one replaces the earlier run's outputs,
/// deletes the stale ones (a prediction it does not make), keeps other files, and its model
/// finds its dataset beside it. A config kept in the output directory under an output's name
/// is refused, untouched.
#[test]
fn runs_publish_their_outputs_together() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    for (name, text) in [
        ("prediction-9.npy", "old"),
        ("report.md", "old"),
        ("notes.txt", "mine"),
    ] {
        std::fs::write(out.join(name), text).unwrap();
    }
    let list = || {
        let mut v: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        v.sort();
        v
    };
    // A run that fails in its data stage (missing MERL files).
    let failing = dir.path().join("failing.toml");
    std::fs::write(
        &failing,
        "name = \"failing\"\n[data]\nkind = \"merl\"\ngrid = \"8,8,16\"\n\
         files = [\"/nonexistent/a.binary\", \"/nonexistent/b.binary\", \"/nonexistent/c.binary\"]\n",
    )
    .unwrap();
    let config = PipelineConfig::load(&failing, &root).unwrap();
    let err = xtask::run(&config, &out).unwrap_err().to_string();
    assert!(err.contains("a.binary"), "{err}");
    assert_eq!(list(), ["notes.txt", "prediction-9.npy", "report.md"]);

    let config = load(&root, "configs/quick.toml");
    xtask::run(&config, &out).unwrap();
    let files = list();
    assert!(!files.iter().any(|f| f.starts_with('.')), "{files:?}");
    assert!(!files.contains(&"prediction-9.npy".to_owned()), "{files:?}");
    assert!(
        files.contains(&"notes.txt".to_owned()) && files.contains(&"prediction-1.npy".to_owned())
    );
    assert_ne!(
        std::fs::read_to_string(out.join("report.md")).unwrap(),
        "old"
    );
    let model = gplvm::Model::load(&out.join("model.toml")).unwrap();
    assert_eq!(
        model.dataset_path(&out.join("model.toml")),
        out.join("data.sbrdf")
    );
    predict::Predictor::open(&out.join("model.toml")).unwrap();

    // A config named like an output, inside the output directory.
    let inside = out.join("model.toml");
    std::fs::copy(root.join("configs/quick.toml"), &inside).unwrap();
    let config = PipelineConfig::load(&inside, &root).unwrap();
    let err = xtask::run(&config, &out).unwrap_err().to_string();
    assert!(err.contains("would overwrite its input"), "{err}");
    assert_eq!(
        std::fs::read_to_string(&inside).unwrap(),
        std::fs::read_to_string(root.join("configs/quick.toml")).unwrap()
    );
    // An output path that cannot be looked up (a name over 255 bytes) is an error naming it,
    // not a directory to create.
    let long = dir.path().join("n".repeat(300)).join("out");
    let err = xtask::run(&load(&root, "configs/quick.toml"), &long)
        .unwrap_err()
        .to_string();
    assert!(err.contains(&format!("{}: ", long.display())), "{err}");
    assert!(!err.contains("staging"), "{err}");
    // Under another name it is the user's file: the run goes ahead and keeps it.
    let mine = out.join("mine.toml");
    std::fs::rename(&inside, &mine).unwrap();
    let config = PipelineConfig::load(&mine, &root).unwrap();
    xtask::run(&config, &out).unwrap();
    assert_eq!(
        std::fs::read_to_string(&mine).unwrap(),
        std::fs::read_to_string(root.join("configs/quick.toml")).unwrap()
    );
}

/// Real measured RGL files located in the space fitted to others (`[locate]`): each lands where
/// the GP reconstructs it at least as well as the closest training material, and the report
/// says so. Skipped without the shared data.
#[test]
fn located_files_are_reported() {
    let root = project_root();
    let Some(rgl) = shared_data::path("rgl-rgb") else {
        return;
    };
    let file = |s: &str| rgl.join(format!("{s}_rgb.bsdf")).display().to_string();
    let list = |names: &[&str]| {
        names
            .iter()
            .map(|n| format!("{:?}", file(n)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("located.toml");
    let text = format!(
        "name = \"located\"\n[data]\nkind = \"rgl\"\ngrid = \"8,8,16\"\nfiles = [{}]\n\
         [fit]\nlatent_dim = 2\n[render]\nenabled = false\n[evaluate]\nloo = false\n\
         [locate]\nfiles = [{}]\nstarts = 2\n",
        list(&[
            "cc_ibiza_sunset",
            "cg_sunflower",
            "paper_white",
            "vch_golden_yellow"
        ]),
        list(&["satin_rosaline", "colodur_napoli_4f", "paper_white"])
    );
    std::fs::write(&config, text).unwrap();
    let config = PipelineConfig::load(&config, &root).unwrap();
    let out = dir.path().join("out");
    let results = xtask::run(&config, &out).unwrap();
    assert_eq!(results.located.len(), 3);
    for (l, stem) in results
        .located
        .iter()
        .zip(["satin_rosaline", "colodur_napoli_4f"])
    {
        assert_eq!(l.name, format!("{stem}_rgb"));
        assert_eq!(l.source, file(stem));
        assert!(l.brdf_rmse.is_finite() && l.brdf_rmse > 0.0, "{l:?}");
        assert!(l.model_rmse <= l.nearest_model_rmse * (1.0 + 1e-9), "{l:?}");
        assert_eq!(l.point.len(), 2);
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Located materials"), "{report}");
    assert!(report.contains("| satin_rosaline_rgb |"), "{report}");
    // A training material's own file, located, is closest to that material.
    assert_eq!(results.located[2].nearest, "paper_white_rgb");
    assert!(
        report.contains(
            "1 of the 1 files named like a training material have that material as the closest"
        ),
        "{report}"
    );
    let stage = results.stages.iter().find(|s| s.name == "locate").unwrap();
    assert_eq!(stage.status, "done");
}

/// Input files are checked before any work, naming the config and the key: a missing data file
/// (it failed in the data stage after the earlier files' import, naming no key), two files with
/// one stem (their materials' one name failed in the data stage, naming the staging store), a
/// `data.only` name repeated with spaces at its end (the data stage trims them), a midpoint of a
/// file's material.
#[test]
fn inputs_are_checked_before_any_work() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir_all(d.join("x")).unwrap();
    std::fs::create_dir_all(d.join("y")).unwrap();
    for f in ["x/a.bsdf", "y/a.bsdf", "y/b.bsdf", "c.bsdf"] {
        std::fs::write(d.join(f), "").unwrap();
    }
    let rgl = |files: &[String], extra: &str| {
        let list: Vec<String> = files.iter().map(|f| format!("{f:?}")).collect();
        format!(
            "name = \"t\"\n[data]\nkind = \"rgl\"\ngrid = \"4,4,8\"\nfiles = [{}]\n{extra}",
            list.join(", ")
        )
    };
    let p = |f: &str| d.join(f).display().to_string();
    let config = d.join("t.toml");
    let load = |text: &str| {
        std::fs::write(&config, text).unwrap();
        PipelineConfig::load(&config, &root)
    };
    let run_err = |text: &str| {
        let c = load(text).unwrap();
        let out = d.join("out");
        let e = xtask::run(&c, &out).unwrap_err().to_string();
        assert!(!out.join("data.sbrdf").exists());
        e
    };

    // Missing, relative and not a file.
    let e = run_err(&rgl(&[p("x/a.bsdf"), p("nope.bsdf"), p("c.bsdf")], ""));
    assert!(e.contains("t.toml: data.files[1]: "), "{e}");
    assert!(
        e.ends_with(&format!("{} does not exist", p("nope.bsdf"))),
        "{e}"
    );
    let e = run_err(&rgl(
        &[p("x/a.bsdf"), "no/such/b.bsdf".into(), p("c.bsdf")],
        "",
    ));
    assert!(
        e.ends_with(&format!(
            "data.files[1]: {} does not exist (a relative path in a config is relative to the \
             project root {})",
            root.join("no/such/b.bsdf").display(),
            root.display()
        )),
        "{e}"
    );
    let e = run_err(&rgl(&[p("x/a.bsdf"), p("c.bsdf"), p("y")], ""));
    assert!(
        e.ends_with(&format!("data.files[2]: {} is not a file", p("y"))),
        "{e}"
    );
    // A path through a file: neither missing nor a directory entry (ENOTDIR).
    let e = run_err(&rgl(
        &[p("x/a.bsdf"), p("c.bsdf"), p("c.bsdf/under.bsdf")],
        "",
    ));
    assert!(
        e.ends_with(&format!(
            "data.files[2]: {} cannot be read",
            p("c.bsdf/under.bsdf")
        )),
        "{e}"
    );
    let e = run_err(&rgl(
        &[p("x/a.bsdf"), p("c.bsdf"), p("y/b.bsdf")],
        &format!("[locate]\nfiles = [{:?}]\n", p("gone.bsdf")),
    ));
    assert!(
        e.ends_with(&format!(
            "locate.files[0]: {} does not exist",
            p("gone.bsdf")
        )),
        "{e}"
    );
    let nbrdf = format!(
        "name = \"t\"\n[data]\nkind = \"nbrdf\"\ngrid = \"4,4,8\"\nweights = {:?}\nnames = {:?}\n",
        p("x"),
        p("c.bsdf")
    );
    let e = run_err(&nbrdf);
    assert!(
        e.ends_with(&format!("data.weights: {} is not a file", p("x"))),
        "{e}"
    );

    // Known at load: names of files and of networks.
    let e = load(&rgl(&[p("x/a.bsdf"), p("c.bsdf"), p("y/a.bsdf")], ""))
        .unwrap_err()
        .to_string();
    assert!(
        e.ends_with(&format!(
            "data.files[2] ({}) and data.files[0] ({}) give one material name \"a\" (materials \
             are named after their files' stems)",
            p("y/a.bsdf"),
            p("x/a.bsdf")
        )),
        "{e}"
    );
    let e = load(&rgl(
        &[p("x/a.bsdf"), p("c.bsdf"), p("y/b.bsdf")],
        "[predict]\nmidpoints = [[\"a\", \"d\"]]\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.ends_with("predict.midpoints: no material named \"d\" in the data"),
        "{e}"
    );
    load(&rgl(
        &[p("x/a.bsdf"), p("c.bsdf"), p("y/b.bsdf")],
        "[predict]\nmidpoints = [[\"a\", \"b\"]]\n",
    ))
    .unwrap();
    let e = load(&format!(
        "{nbrdf}only = [\"alum-bronze\", \"alum-bronze \", \"chrome\"]\n"
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.ends_with("data.only lists \"alum-bronze \" twice (entry 2)"),
        "{e}"
    );
}

/// An output directory that does not exist is created only by a run that succeeds: a failed
/// run used to leave it (and its missing parents) behind, empty. An existing file in its place
/// is named as such (it was "File exists (os error 17)").
#[test]
fn a_failed_run_leaves_no_new_directory() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    // Fails in the data stage: a weights file that is not a NumPy file.
    std::fs::write(dir.path().join("w.npy"), "not numpy").unwrap();
    std::fs::write(dir.path().join("names.txt"), "a\nb\nc\n").unwrap();
    let failing = dir.path().join("failing.toml");
    std::fs::write(
        &failing,
        format!(
            "name = \"failing\"\n[data]\nkind = \"nbrdf\"\ngrid = \"4,4,8\"\nweights = {:?}\n\
             names = {:?}\n",
            dir.path().join("w.npy"),
            dir.path().join("names.txt")
        ),
    )
    .unwrap();
    let config = PipelineConfig::load(&failing, &root).unwrap();
    let out = dir.path().join("new").join("with space").join("out");
    let err = xtask::run(&config, &out).unwrap_err().to_string();
    assert!(err.contains("data stage"), "{err}");
    assert_eq!(
        entries(dir.path()),
        ["failing.toml", "names.txt", "w.npy"],
        "{err}"
    );

    // The same path, nested and new, with a run that succeeds.
    let config = load(&root, "configs/quick.toml");
    let results = xtask::run(&config, &out).unwrap();
    assert_eq!(results.out_dir, out.display().to_string());
    assert_eq!(
        entries(dir.path()),
        ["failing.toml", "names.txt", "new", "w.npy"]
    );
    let files = entries(&out);
    assert!(files.contains(&"report.md".to_owned()), "{files:?}");
    assert!(!files.iter().any(|f| f.starts_with('.')), "{files:?}");
    predict::Predictor::open(&out.join("model.toml")).unwrap();
    // The report's command to regenerate it quotes the path with a space.
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let command = format!("--out '{}'`", out.display());
    assert!(report.contains(&command), "{report}");

    // A file where the directory should be, or where a parent should be.
    let file = dir.path().join("names.txt");
    let err = xtask::run(&config, &file).unwrap_err().to_string();
    assert!(
        err.ends_with(
            "exists and is not a directory (--out names the directory the run writes into)"
        ),
        "{err}"
    );
    let err = xtask::run(&config, &file.join("sub"))
        .unwrap_err()
        .to_string();
    assert!(
        err.ends_with(&format!("{} is not a directory", file.display())),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "a\nb\nc\n");
    assert_eq!(
        entries(dir.path()),
        ["failing.toml", "names.txt", "new", "w.npy"]
    );
}

/// Without leave-one-out, the by-kind table says so instead of printing NaN as an error.
#[test]
fn by_kind_table_without_leave_one_out_says_it_was_not_run() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("noloo.toml");
    std::fs::write(
        &path,
        "name = \"noloo\"\n[data]\nkind = \"synth\"\ngrid = \"4,4,8\"\nwavelengths = \
         \"400:700:100\"\n[fit]\nlatent_dim = 2\nmax_iterations = 20\n[evaluate]\nloo = false\n\
         [render]\nenabled = false\n",
    )
    .unwrap();
    let config = PipelineConfig::load(&path, &root).unwrap();
    let out = dir.path().join("out");
    let results = xtask::run(&config, &out).unwrap();
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert_eq!(results.by_kind.len(), 3);
    for k in &results.by_kind {
        assert!(k.loo_gp.is_nan());
        let row = format!(
            "| {} | {} | {} | {} | - |",
            k.kind,
            k.n,
            xtask::report::num(k.reconstruction_exact),
            xtask::report::num(k.reconstruction_smooth)
        );
        assert!(report.contains(&row), "{row}\n{report}");
    }
    assert!(!report.contains("NaN"), "{report}");
    assert!(report.contains("Leave-one-out was not run (`[evaluate] loo = false`)."));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert!(json["by_kind"][0]["loo_gp"].is_null());
}

/// The by-kind table lists only the kinds the data has: two metals and a paper give two rows.
#[test]
fn by_kind_table_lists_only_the_kinds_present() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two.toml");
    std::fs::write(
        &path,
        "name = \"two\"\n[data]\nkind = \"synth\"\ngrid = \"4,4,8\"\nwavelengths = \
         \"400:700:100\"\nonly = [\"metal_gold\", \"metal_silver\", \"paper_white\"]\n\
         [fit]\nlatent_dim = 2\nmax_iterations = 20\n[evaluate]\nloo = false\n[render]\n\
         enabled = false\n",
    )
    .unwrap();
    let config = PipelineConfig::load(&path, &root).unwrap();
    let results = xtask::run(&config, &dir.path().join("out")).unwrap();
    let kinds: Vec<(&str, usize)> = results
        .by_kind
        .iter()
        .map(|k| (k.kind.as_str(), k.n))
        .collect();
    assert_eq!(kinds, [("diffuse", 1), ("metallic", 2)]);
}

/// `[render] env = "studio"` renders the figures' spheres under the studio sky: another
/// sheet than the default environment's, and the report says which.
#[test]
fn render_env_studio_lights_the_figures() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let sheet = |env: &str| {
        let path = dir.path().join(format!("{env}.toml"));
        std::fs::write(
            &path,
            format!(
                "name = \"{env}\"\n[data]\nkind = \"synth\"\ngrid = \"4,4,8\"\nwavelengths = \
                 \"400:700:100\"\nonly = [\"metal_gold\", \"metal_chromium\", \"paper_white\"]\n\
                 [fit]\nlatent_dim = 2\nmax_iterations = 20\n[evaluate]\nloo = false\n\
                 [render]\nsize = 16\nsheet_materials = 3\nenv = \"{env}\"\n"
            ),
        )
        .unwrap();
        let config = PipelineConfig::load(&path, &root).unwrap();
        let out = dir.path().join(env);
        xtask::run(&config, &out).unwrap();
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        let png = std::fs::read(out.join("sheet.png")).unwrap();
        (report, png)
    };
    let (table_report, table_png) = sheet("table");
    let (studio_report, studio_png) = sheet("studio");
    assert!(!table_report.contains("render.env"));
    assert!(
        studio_report.contains("Spheres rendered with `render.env = \"studio\"`."),
        "{studio_report}"
    );
    assert_ne!(table_png, studio_png);
}

/// `lookup = "log"` reaches every lookup of a run: the figures change, the energy section
/// says so, the stored materials and the prediction reflect less (glossy materials gain
/// energy between bin centres under multilinear lookups) and the `.bsdf` export follows the
/// logarithmic lookups; results.json records the key only when given; other values are
/// refused with the reason.
#[test]
fn lookup_log_reaches_figures_energy_and_exports() {
    let root = project_root();
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, lookup: &str| {
        let path = dir.path().join(format!("{name}.toml"));
        std::fs::write(
            &path,
            format!(
                "name = \"{name}\"\n{lookup}[data]\nkind = \"synth\"\ngrid = \"8,8,16\"\n\
                 wavelengths = \"400:700:100\"\nonly = [\"metal_gold\", \"metal_chromium\", \
                 \"paper_white\"]\n[fit]\nlatent_dim = 2\nmax_iterations = 20\n[predict]\n\
                 midpoints = [[\"metal_gold\", \"paper_white\"]]\nbsdf = true\n\
                 [evaluate]\nloo = false\n[render]\nsize = 16\nsheet_materials = 3\n"
            ),
        )
        .unwrap();
        path
    };
    let run = |name: &str, lookup: &str| {
        let config = PipelineConfig::load(&write(name, lookup), &root).unwrap();
        let out = dir.path().join(name);
        xtask::run(&config, &out).unwrap();
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap())
                .unwrap();
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        (out, json, report)
    };
    let (linear, linear_json, linear_report) = run("linear", "");
    let (log, log_json, log_report) = run("log", "lookup = \"log\"\n");
    assert!(
        linear_report.contains("as the multilinear lookups"),
        "{linear_report}"
    );
    assert!(
        log_report.contains("as the logarithmic (`lookup = \"log\"`"),
        "{log_report}"
    );
    assert!(linear_json["config"].get("lookup").is_none());
    assert_eq!(log_json["config"]["lookup"], "log");
    for f in [
        "sheet.png",
        "comparison.png",
        "paths.png",
        "predictions.png",
    ] {
        assert_ne!(
            std::fs::read(linear.join(f)).unwrap(),
            std::fs::read(log.join(f)).unwrap(),
            "{f}"
        );
    }
    let peak = |json: &serde_json::Value, pointer: &str| {
        json.pointer(pointer).and_then(|v| v.as_f64()).unwrap()
    };
    for i in 0..3 {
        let p = format!("/stored_albedo/{i}/peak/value");
        let (a, b) = (peak(&linear_json, &p), peak(&log_json, &p));
        assert!(b < a, "{p}: {b} vs {a}");
    }
    let p = "/predictions/0/albedo/value";
    assert!(peak(&log_json, p) < peak(&linear_json, p));
    // The export holds the logarithmic lookups: its albedo, integrated from the file, is
    // the prediction's as the energy section saw it (to the writer's accuracy).
    let file = brdf_io::rgl::RglBsdf::open(log.join("prediction-1.bsdf")).unwrap();
    let table = brdf_io::albedo::directional_albedo(
        &file,
        &xtask::stages::ALBEDO_THETAS_DEG,
        brdf_io::albedo::DEFAULT_RESOLUTION,
    )
    .unwrap();
    let (got, want) = (table.peak().unwrap().value, peak(&log_json, p));
    assert!((got - want).abs() < 0.02 * want, "{got} vs {want}");
    assert!((got - peak(&linear_json, p)).abs() > 0.05 * want);

    let bad = PipelineConfig::load(&write("bad", "lookup = \"cubic\"\n"), &root)
        .err()
        .unwrap()
        .to_string();
    assert!(
        bad.contains("lookup \"cubic\": expected linear or log"),
        "{bad}"
    );
}

/// `cargo xtask bench` publishes bench.json, bench.md and bench.png together: into a new nested
/// output directory that appears only when the run succeeds (no scratch or staging directory
/// left), replacing an earlier run's set and keeping the user's other files; an output path
/// under a file is refused and creates nothing. Its rows measure what their settings say: the
/// exact predictor reconstructs the training materials (to the log transform's round trip),
/// the smooth one does not, and no Delta E without spheres.
#[test]
fn bench_outputs_are_published_as_a_set() {
    let dir = tempfile::tempdir().unwrap();
    let config_path = dir.path().join("tiny.toml");
    std::fs::write(
        &config_path,
        "max_iterations = 30\nmax_evaluations = 300\ndelta_e_materials = 0\nsphere_size = 16\n\
         [base]\ngrid = \"4,4,8\"\nwavelengths = \"400:700:100\"\ndtype = \"f32\"\n\
         latent_dim = 2\ntransform = \"log\"\noptimizer = \"lbfgs\"\npredictor = \"exact\"\n\
         [sweep]\nlatent_dim = [1]\npredictor = [\"smooth\"]\n",
    )
    .unwrap();
    let config = xtask::bench::BenchConfig::load(&config_path).unwrap();
    let out = dir.path().join("new").join("bench");
    let rows = xtask::bench::run(&config, &config_path, &out).unwrap();
    assert_eq!(rows.len(), 3);
    assert_eq!(entries(dir.path()), ["new", "tiny.toml"]);
    assert_eq!(entries(&out), ["bench.json", "bench.md", "bench.png"]);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap();
    assert_eq!(json.as_array().unwrap().len(), 3);
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    for point in [
        "| base | - |",
        "| latent_dim | 1 |",
        "| predictor | smooth |",
    ] {
        assert!(md.contains(point), "{point} in {md}");
    }
    for row in &rows {
        let exact = row.settings.predictor == "exact";
        assert!(
            (row.reconstruction_rmse < 1e-9) == exact && row.reconstruction_rmse >= 0.0,
            "{} = {}: reconstruction {}",
            row.sweep,
            row.value,
            row.reconstruction_rmse
        );
        assert!(row.loo_rmse > row.reconstruction_rmse, "{}", row.loo_rmse);
        let per_channel = row.loo_rmse / (row.n_channels as f64).sqrt();
        assert_eq!(row.loo_rmse_per_channel, per_channel);
        assert!(row.delta_e.is_nan(), "{}", row.delta_e);
    }
    // Again into the existing directory, over an earlier set: replaced, nothing added, the
    // user's own file kept.
    std::fs::write(out.join("bench.md"), "an earlier run").unwrap();
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    xtask::bench::run(&config, &config_path, &out).unwrap();
    assert_eq!(
        entries(&out),
        ["bench.json", "bench.md", "bench.png", "notes.txt"]
    );
    assert_ne!(
        std::fs::read_to_string(out.join("bench.md")).unwrap(),
        "an earlier run"
    );
    // Under a file: refused, nothing created.
    let under_file = dir.path().join("tiny.toml").join("bench");
    let e = xtask::bench::run(&config, &config_path, &under_file)
        .unwrap_err()
        .to_string();
    assert!(e.contains("is not a directory"), "{e}");
    assert_eq!(entries(dir.path()), ["new", "tiny.toml"]);
}

/// The binary resolves the project root at run time from `CARGO_MANIFEST_DIR` (as `cargo
/// xtask` sets it): a binary built in another checkout read that checkout's `configs/` and
/// resolved the config's relative paths there.
#[test]
fn the_binary_takes_the_project_root_of_its_environment() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("checkout");
    std::fs::create_dir_all(root.join("configs")).unwrap();
    std::fs::create_dir_all(root.join("xtask")).unwrap();
    std::fs::write(
        root.join("configs/elsewhere.toml"),
        "name = \"elsewhere\"\n[data]\nkind = \"rgl\"\ngrid = \"4,4,8\"\n\
         files = [\"a.bsdf\", \"b.bsdf\", \"c.bsdf\"]\n",
    )
    .unwrap();
    // `xtask pipeline CONFIG` run in the temporary directory, with `root` as project root.
    let pipeline = |config: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_xtask"))
            .args(["pipeline", config])
            .env("CARGO_MANIFEST_DIR", root.join("xtask"))
            .current_dir(dir.path())
            .output()
            .unwrap()
    };
    let out = pipeline("configs/elsewhere.toml");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains(&format!(
            "data.files[0]: {} does not exist (a relative path in a config is relative to the \
             project root {})",
            root.join("a.bsdf").display(),
            root.display()
        )),
        "{err}"
    );
    assert!(!root.join("out").exists());
    // A config that exists where the command runs is read from there, not looked up in the
    // root: the same data error.
    std::fs::copy(
        root.join("configs/elsewhere.toml"),
        dir.path().join("here.toml"),
    )
    .unwrap();
    let out = pipeline("here.toml");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("data.files[0]: ") && !err.contains("no such file"),
        "{err}"
    );
    // A config in neither place: the error names both (it named the root's only).
    let out = pipeline("configs/nowhere.toml");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains(&format!(
            "configs/nowhere.toml: no such file here ({}) or in the project root ({})",
            dir.path().display(),
            root.display()
        )),
        "{err}"
    );
}

/// A pipeline creates no output directory (nor files) inside a directory whose mode bits say
/// read-only, even run as root (it created one there), and says which directory.
#[cfg(unix)]
#[test]
fn nothing_is_created_inside_a_read_only_directory() {
    use std::os::unix::fs::PermissionsExt;
    let root = project_root();
    let config = load(&root, "configs/quick.toml");
    let dir = tempfile::tempdir().unwrap();
    let ro = dir.path().join("ro");
    std::fs::create_dir(&ro).unwrap();
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
    for out in [ro.join("out"), ro.join("a/b"), ro.clone()] {
        let e = xtask::run(&config, &out).unwrap_err().to_string();
        // "output stage (RO): the directory ..." when RO is the output itself.
        let named = |sep| format!("{}{sep} the directory is read-only", ro.display());
        assert!(e.contains(&named(":")) || e.contains(&named("):")), "{e}");
    }
    assert!(entries(&ro).is_empty());
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// Log lines written into a pipe or a file are plain text, as specgp's: no ANSI colour codes
/// (they came out as `^[[2m...`).
#[test]
fn logs_into_a_pipe_have_no_colour_codes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Input files that exist (checked before the run) but hold no data: the run logs its data
    // stage, then fails there.
    let files: Vec<String> = ["a", "b", "c"]
        .iter()
        .map(|n| {
            let p = d.join(format!("{n}.bsdf"));
            std::fs::write(&p, "").unwrap();
            format!("{:?}", p.display().to_string())
        })
        .collect();
    let config = d.join("t.toml");
    std::fs::write(
        &config,
        format!(
            "name = \"t\"\n[data]\nkind = \"rgl\"\ngrid = \"4,4,8\"\nfiles = [{}]\n",
            files.join(", ")
        ),
    )
    .unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_xtask"))
        .arg("pipeline")
        .arg(&config)
        .arg("--out")
        .arg(d.join("out"))
        .arg("-v")
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("INFO") && err.contains("data"), "{err}");
    assert!(!err.contains('\u{1b}'), "{err:?}");
}
