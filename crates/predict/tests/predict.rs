//! Accuracy and bad-input tests of the prediction service on small synthetic stores.
#![allow(clippy::needless_range_loop)]

mod common;

use common::dense_solve;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use brdf_io::store::Store;
use brdf_io::{AngularGrid, BrdfSource, Channels, StoreOptions};
use faer::{Mat, Par, Side};
use gplvm::{FitParams, Model, Transform};
use predict::evaluate::{EvalOptions, Method, Stage, evaluate, leave_one_out, sq_error};
use predict::{Error, Predictor, PredictorKind};

struct Fixture {
    _dir: tempfile::TempDir,
    store: PathBuf,
    model: PathBuf,
}

fn grid() -> AngularGrid {
    AngularGrid::new(8, 8, 16).unwrap()
}

fn channels() -> Channels {
    Channels::parse_wavelengths("400:700:50").unwrap()
}

fn write_store(path: &Path, n: usize, seed: u64, grid: AngularGrid) {
    write_store_with(path, n, seed, grid, StoreOptions::default());
}

/// As [`write_store`], with the store written with `options` (e.g. small chunks).
fn write_store_with(path: &Path, n: usize, seed: u64, grid: AngularGrid, options: StoreOptions) {
    write_store_on(path, n, seed, grid, &channels(), options);
}

/// As [`write_store_with`], on `channels` in place of [`channels`].
fn write_store_on(
    path: &Path,
    n: usize,
    seed: u64,
    grid: AngularGrid,
    channels: &Channels,
    options: StoreOptions,
) {
    let materials = brdf_synth::preset(seed);
    // Spread the picks over the preset's families.
    let step = materials.len() / n;
    let picked: Vec<_> = (0..n).map(|i| materials[i * step].clone()).collect();
    brdf_synth::write_store(path, &picked, grid, channels, options, seed, |_| {}).unwrap();
}

/// The model's material names, in order.
fn material_names(pred: &Predictor) -> Vec<String> {
    pred.model()
        .materials
        .iter()
        .map(|m| m.name.clone())
        .collect()
}

fn fixture(n: usize, transform: &str) -> Fixture {
    fixture_with(n, transform, StoreOptions::default())
}

/// As [`fixture`], with the store written with `options`.
fn fixture_with(n: usize, transform: &str, options: StoreOptions) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("data.sbrdf");
    write_store_with(&store, n, 0, grid(), options);
    // The tests use 2-D latent points (the default fit has q = 5).
    let params = FitParams {
        latent_dim: 2,
        transform: transform.into(),
        max_iterations: 300,
        ..FitParams::default()
    };
    let model = gplvm::fit_store(&store, &params.check().unwrap()).unwrap();
    let model_path = dir.path().join("model.toml");
    model.save(&model_path).unwrap();
    Fixture {
        _dir: dir,
        store,
        model: model_path,
    }
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / a.abs().max(b.abs()).max(1e-300)
}

#[test]
fn posterior_mean_and_variance_equal_a_dense_reference() {
    let f = fixture(10, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let model = pred.model().clone();
    let n = pred.n_materials();
    let h = &model.hyperparameters;
    let (s2, l, mu) = (h.signal_variance, h.length_scale[0], h.noise);
    let xs = model.latent_matrix();
    let k = |a: &[f64], b: &[f64]| {
        let r2: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
        s2 * (-0.5 * r2 / (l * l)).exp()
    };
    let row = |i: usize| -> Vec<f64> { (0..xs.ncols()).map(|j| xs[(i, j)]).collect() };
    let kk = Mat::from_fn(n, n, |i, j| {
        k(&row(i), &row(j)) + if i == j { mu } else { 0.0 }
    });
    // A point between materials 2 and 5.
    let x: Vec<f64> = row(2)
        .iter()
        .zip(row(5))
        .map(|(a, b)| 0.6 * a + 0.4 * b)
        .collect();
    let kstar: Vec<f64> = (0..n).map(|i| k(&row(i), &x)).collect();
    let w_ref = dense_solve(|i, j| kk[(i, j)], &kstar);
    let w = pred.gp_weights(&x, PredictorKind::Smooth).unwrap();
    for i in 0..n {
        assert!(
            (w[i] - w_ref[i]).abs() < 1e-7 * (1.0 + w_ref[i].abs()),
            "w[{i}] = {} vs {}",
            w[i],
            w_ref[i]
        );
    }
    let var_ref = s2 + mu - kstar.iter().zip(&w_ref).map(|(a, b)| a * b).sum::<f64>();
    let var = pred.variance(&x).unwrap();
    assert!(
        (var - var_ref).abs() < 1e-9 * (1.0 + var_ref),
        "{var} vs {var_ref}"
    );
    assert!(var > 0.0 && var < s2 + mu);
    assert_eq!(
        pred.variance_transformed(&x, PredictorKind::Smooth)
            .unwrap(),
        var * model.data_scale
    );
    // Away from the training points both predictors' variances agree; at training point 2
    // the exact predictor (which returns material 2 itself) has variance 0, and the smooth
    // one the dense reference's s^2 + mu - k_s^T K^-1 k_s.
    assert_eq!(pred.variance_of(&x, PredictorKind::Exact).unwrap(), var);
    assert_eq!(pred.variance_of(&x, PredictorKind::Smooth).unwrap(), var);
    let x2 = row(2);
    let exact = pred.variance_of(&x2, PredictorKind::Exact).unwrap();
    assert!(exact <= 1e-9 * (s2 + mu), "{exact}");
    let k2: Vec<f64> = (0..n).map(|i| k(&row(i), &x2)).collect();
    let w2 = dense_solve(|i, j| kk[(i, j)], &k2);
    let smooth_ref = s2 + mu - k2.iter().zip(&w2).map(|(a, b)| a * b).sum::<f64>();
    let smooth = pred.variance_of(&x2, PredictorKind::Smooth).unwrap();
    assert!(
        (smooth - smooth_ref).abs() < 1e-9 * (s2 + mu) && smooth > 0.1 * mu,
        "{smooth} vs {smooth_ref} (mu {mu})"
    );

    // Support: at a training material it is that material, 0 away, with the smooth variance's
    // share of the prior; far away the prior variance is all that is left.
    let at2 = pred.support(&x2).unwrap();
    assert_eq!(at2.nearest, model.materials[2].name);
    assert_eq!(at2.distance, 0.0);
    assert_eq!(at2.variance_fraction, smooth / (s2 + mu));
    assert!(!at2.is_far());
    let between = pred.support(&x).unwrap();
    let d2 = |i: usize| {
        row(i)
            .iter()
            .zip(&x)
            .map(|(a, b)| ((a - b) / l).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let nearest = (0..n).min_by(|&a, &b| d2(a).total_cmp(&d2(b))).unwrap();
    assert_eq!(between.nearest, model.materials[nearest].name);
    assert!(rel(between.distance, d2(nearest)) < 1e-12);
    assert_eq!(between.variance_fraction, var / (s2 + mu));
    let far: Vec<f64> = row(0).iter().map(|v| v + 10.0 * l).collect();
    let far = pred.support(&far).unwrap();
    assert!(far.is_far() && far.variance_fraction > 0.999, "{far:?}");
    assert!(far.distance > 5.0, "{far:?}");

    // Posterior mean y* = m + sum w_i (y_i - m) in the transformed space, then the inverse.
    let material = pred.predict(&x, PredictorKind::Smooth).unwrap();
    let store = Store::open(&f.store).unwrap();
    let t = model.transform;
    let mut vals = vec![0f32; n];
    let nc = store.channels().len();
    let mask = store.validity_mask().to_vec();
    let mut checked = 0;
    for d in (0..store.d()).step_by(37) {
        if !mask[d / nc] {
            continue;
        }
        store.values_at(d, &mut vals).unwrap();
        let y: Vec<f64> = vals.iter().map(|v| t.forward(f64::from(*v))).collect();
        let m = y.iter().sum::<f64>() / n as f64;
        let ystar = m + (0..n).map(|i| w_ref[i] * (y[i] - m)).sum::<f64>();
        let want = t.inverse(ystar);
        let got = material.value_at(d).unwrap();
        assert!(
            (got - want).abs() <= 1e-7 * want.abs() + 1e-12,
            "d = {d}: {got} vs {want}"
        );
        checked += 1;
    }
    assert!(checked > 50);
}

/// `materialize_with` shows the observer every value written, in order, in contiguous blocks
/// (for `.npy` and `.sbrdf` outputs); an observer's error ends the writing and leaves nothing
/// at the path.
#[test]
fn materialising_shows_every_value_written_to_the_observer() {
    let options = StoreOptions {
        chunk_len: Some(100), // several chunks, so several blocks, some splitting cells
        ..StoreOptions::default()
    };
    let f = fixture_with(6, "log", options);
    let pred = Predictor::open(&f.model).unwrap();
    assert!(pred.store().n_chunks() > 3, "{}", pred.store().n_chunks());
    let material = pred.predict(&[0.1, 0.4], PredictorKind::Exact).unwrap();
    for name in ["seen.npy", "seen.sbrdf"] {
        let out = f._dir.path().join(name);
        let mut seen: Vec<f32> = Vec::new();
        let mut blocks = 0;
        material
            .materialize_with(
                &out,
                |_, _| {},
                |range, values| {
                    assert_eq!((range.start, range.len()), (seen.len(), values.len()));
                    seen.extend_from_slice(values);
                    blocks += 1;
                    Ok(())
                },
            )
            .unwrap();
        let written = if name.ends_with(".npy") {
            brdf_io::npy::read(&out).unwrap().to_f32()
        } else {
            let store = Store::open(&out).unwrap();
            let mut row = vec![0f32; store.d()];
            store.material_row(0, 0..store.d(), &mut row).unwrap();
            row
        };
        assert_eq!(seen.len(), pred.store().d());
        assert!(blocks > 1, "{name}: {blocks}");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&seen), bits(&written), "{name}");
    }
    let out = f._dir.path().join("refused.npy");
    let mut calls = 0;
    let e = material
        .materialize_with(
            &out,
            |_, _| {},
            |_, _| {
                calls += 1;
                Err(Error::InvalidArgument {
                    reason: "observer says no".into(),
                })
            },
        )
        .unwrap_err();
    assert!(e.to_string().contains("observer says no"), "{e}");
    assert_eq!(calls, 1);
    assert!(!out.exists());
}

#[test]
fn lazy_lookups_equal_the_materialised_values() {
    let f = fixture(8, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let x = vec![0.3, -0.2];
    let material = pred.predict(&x, PredictorKind::Exact).unwrap();
    let out = f._dir.path().join("pred.npy");
    let report = material.materialize(&out, |_, _| {}).unwrap();
    let arr = brdf_io::npy::read(&out).unwrap();
    let values = arr.to_f32();
    assert_eq!(values.len(), pred.store().d());
    assert_eq!(report.values, values.len());
    let mut nonzero = 0;
    for (d, v) in values.iter().enumerate() {
        let lazy = material.value_at(d).unwrap() as f32;
        assert_eq!(lazy.to_bits(), v.to_bits(), "d = {d}");
        nonzero += usize::from(*v != 0.0);
    }
    assert!(nonzero > values.len() / 3);
    assert_eq!(report.negatives, 0);
    // An extrapolated linear interpolation (t = 3: 3 y_a - 2 y_b in log space) goes below 0
    // where y_b > 1.5 y_a; the report counts every negative value written.
    let names = material_names(&pred);
    let beyond = pred.lerp(&names[0], &names[3], 3.0).unwrap();
    let report = beyond.materialize(&out, |_, _| {}).unwrap();
    let written = brdf_io::npy::read(&out).unwrap().to_f32();
    let negatives: Vec<f32> = written.iter().copied().filter(|v| *v < 0.0).collect();
    assert!(!negatives.is_empty());
    assert_eq!(report.negatives, negatives.len());
    let min = negatives.iter().copied().fold(0f32, f32::min);
    assert_eq!(report.min_value, f64::from(min));
    // A whole cell at once (one block read, batched transforms) equals the single lookups.
    let nc = pred.channels().len();
    let mut cell_all = vec![0.0; nc];
    for a in (0..pred.grid().len()).step_by(7) {
        material.eval_cell(a, &mut cell_all).unwrap();
        for (c, v) in cell_all.iter().enumerate() {
            assert_eq!(
                v.to_bits(),
                material.value_at(a * nc + c).unwrap().to_bits()
            );
        }
    }

    // A wavelength subset (interpolated) to .sbrdf equals eval_cell.
    let sub = material
        .with_wavelengths(&Channels::parse_wavelengths("425,500,610").unwrap())
        .unwrap();
    let out = f._dir.path().join("pred.sbrdf");
    sub.materialize(&out, |_, _| {}).unwrap();
    let written = Store::open(&out).unwrap();
    assert_eq!(written.n_materials(), 1);
    assert_eq!(written.channels().len(), 3);
    let mut row = vec![0f32; written.d()];
    written.material_row(0, 0..written.d(), &mut row).unwrap();
    let mut cell = [0.0; 3];
    for a in 0..pred.grid().len() {
        sub.eval_cell(a, &mut cell).unwrap();
        for c in 0..3 {
            assert_eq!((cell[c] as f32).to_bits(), row[a * 3 + c].to_bits());
        }
        // 425 nm is halfway between the stored 400 and 450 nm.
        let (lo, hi) = (
            material.value_at(a * 7).unwrap(),
            material.value_at(a * 7 + 1).unwrap(),
        );
        assert!((cell[0] - 0.5 * (lo + hi)).abs() <= 1e-12 * (1.0 + lo.abs() + hi.abs()));
    }

    // (wi, wo) at a bin centre equals the cell; below the horizon gives 0.
    let g = pred.grid();
    let a = g.index(3, 2, 5);
    let (wi, wo) = g.bin_centre(3, 2, 5).to_dirs();
    let mut by_dirs = vec![0.0; 7];
    let mut by_cell = vec![0.0; 7];
    BrdfSource::eval(&material, wi, wo, &mut by_dirs).unwrap();
    material.eval_cell(a, &mut by_cell).unwrap();
    for c in 0..7 {
        assert!((by_dirs[c] - by_cell[c]).abs() <= 1e-9 * by_cell[c].abs().max(1e-12));
    }
    BrdfSource::eval(&material, [0.0, 0.0, 1.0], [0.0, 0.6, -0.8], &mut by_dirs).unwrap();
    assert!(by_dirs.iter().all(|v| *v == 0.0));
    // As a grid source (renderers evaluate each touched cell once through the trait).
    assert_eq!(BrdfSource::grid(&material), Some(*g));
    let mut by_trait = vec![0.0; 7];
    BrdfSource::eval_cell(&material, a, &mut by_trait).unwrap();
    assert_eq!(by_trait, by_cell);
    assert!(BrdfSource::eval_cell(&material, g.len(), &mut by_trait).is_err());
}

/// A predictor keeping each cell's forward-transformed values (`with_forward_cache`, as the
/// pipeline's figures and the map's thumbnails use) gives every lazy lookup the bits of the
/// uncached one: first reads and cached reads, several materials sharing the cache (points,
/// both predictors, a blend), a wavelength subset; under `raw` it changes nothing.
#[test]
fn forward_cache_gives_the_uncached_bits() {
    for transform in ["log", "raw"] {
        let f = fixture(6, transform);
        let pred = Predictor::open(&f.model).unwrap();
        let cached = pred.with_forward_cache();
        assert_eq!(cached.keeps_forward_values(), transform == "log");
        assert!(!pred.keeps_forward_values());
        let names = material_names(&pred);
        let nc = pred.channels().len();
        // The size cap: cells x channels x N x 8 bytes, inclusive.
        let bytes = pred.forward_cache_bytes();
        assert_eq!(bytes, (pred.grid().len() * nc * names.len() * 8) as u64);
        assert_eq!(
            pred.with_forward_cache_within(bytes).keeps_forward_values(),
            transform == "log"
        );
        assert!(
            !pred
                .with_forward_cache_within(bytes - 1)
                .keeps_forward_values()
        );
        let subset = Channels::parse_wavelengths("425,500,610").unwrap();
        let materials = |p: &Predictor| {
            vec![
                p.predict(&[0.3, -0.2], PredictorKind::Exact).unwrap(),
                p.predict(&[-0.1, 0.4], PredictorKind::Smooth).unwrap(),
                p.lerp(&names[0], &names[2], 0.3).unwrap(),
                p.predict(&[0.1, 0.1], PredictorKind::Exact)
                    .unwrap()
                    .with_wavelengths(&subset)
                    .unwrap(),
            ]
        };
        let (plain, kept) = (materials(&pred), materials(&cached));
        // Twice over the cells: the first pass fills the cache, the second reads it.
        for _ in 0..2 {
            for (a, b) in plain.iter().zip(&kept) {
                let k = a.channels().len();
                let (mut va, mut vb) = (vec![0.0; k], vec![0.0; k]);
                for cell in 0..pred.grid().len() {
                    a.eval_cell(cell, &mut va).unwrap();
                    b.eval_cell(cell, &mut vb).unwrap();
                    for (x, y) in va.iter().zip(&vb) {
                        assert_eq!(x.to_bits(), y.to_bits(), "{transform}, cell {cell}");
                    }
                }
                assert!(k == nc || k == 3);
            }
        }
    }
}

/// Predictions evaluated together (`eval_cell_each`, as renders of many thumbnails do) give
/// each one's own `eval_cell` bits, on every lookup path (the dataset under `log` and `raw`,
/// the forward cache, the sidecar), for full channels and for a wavelength subset made for
/// each material apart; materials that do not share their cells, and bad arguments, are
/// refused, and an overflow names the material that overflowed.
#[test]
fn predictions_evaluated_together_have_each_ones_bits() {
    for transform in ["log", "raw"] {
        let f = fixture(6, transform);
        let pred = Predictor::open(&f.model).unwrap();
        let names = material_names(&pred);
        let mut paths = vec![pred.clone(), pred.with_forward_cache()];
        if transform == "log" {
            let side = pred.transformed_store_path();
            pred.build_transformed_store(&side, |_, _| {}).unwrap();
            paths.push(pred.with_transformed_store(&side).unwrap());
        }
        let subset = Channels::parse_wavelengths("425,500,610").unwrap();
        for p in &paths {
            let full = vec![
                p.predict(&[0.3, -0.2], PredictorKind::Exact).unwrap(),
                p.clone()
                    .predict(&[-0.1, 0.4], PredictorKind::Smooth)
                    .unwrap(),
                p.lerp(&names[0], &names[2], 0.3).unwrap(),
                p.training(&names[4]).unwrap(),
            ];
            let sub: Vec<_> = full
                .iter()
                .map(|m| m.with_wavelengths(&subset).unwrap())
                .collect();
            for batch in [&full, &sub] {
                let refs: Vec<&predict::PredictedMaterial> = batch.iter().collect();
                let w = batch[0].channels().len();
                let mut together = vec![0.0; w * refs.len()];
                let mut alone = vec![0.0; w];
                for a in 0..p.grid().len() {
                    predict::PredictedMaterial::eval_cell_each(&refs, a, &mut together).unwrap();
                    for (k, m) in batch.iter().enumerate() {
                        m.eval_cell(a, &mut alone).unwrap();
                        let got = &together[k * w..(k + 1) * w];
                        for (x, y) in got.iter().zip(&alone) {
                            assert_eq!(x.to_bits(), y.to_bits(), "{transform}, cell {a}, {k}");
                        }
                    }
                }
            }
            assert!(full[0].shares_cells(&full[1]) && sub[0].shares_cells(&sub[3]));
            assert!(!full[0].shares_cells(&sub[0]));
            let mixed = [&full[0], &sub[1]];
            let e = predict::PredictedMaterial::eval_cell_each(&mixed, 0, &mut [0.0; 10]);
            let e = e.unwrap_err().to_string();
            assert!(e.contains("do not share their cells"), "{e}");
        }
        // Another predictor (even of the same model) reads its own cells.
        let other = Predictor::open(&f.model).unwrap();
        let (a, b) = (
            pred.training(&names[0]).unwrap(),
            other.training(&names[0]).unwrap(),
        );
        assert!(!a.shares_cells(&b));
        // A forward cache is another predictor's (under `raw` there is none: the same one).
        let cached = pred.with_forward_cache().training(&names[0]).unwrap();
        assert_eq!(a.shares_cells(&cached), transform == "raw");
        let nc = pred.channels().len();
        let each = predict::PredictedMaterial::eval_cell_each;
        assert!(each(&[&a, &b], 0, &mut vec![0.0; 2 * nc]).is_err());
        let e = each(&[], 0, &mut []).unwrap_err().to_string();
        assert!(e.contains("at least one material"), "{e}");
        let e = each(&[&a, &a], 0, &mut vec![0.0; nc])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(&format!("slots for 2 materials of {nc} channels")),
            "{e}"
        );
        let cells = pred.grid().len();
        let e = each(&[&a, &a], cells, &mut vec![0.0; 2 * nc]).unwrap_err();
        assert!(
            matches!(e, Error::CellOutOfRange { cell, .. } if cell == cells),
            "{e}"
        );
        if transform == "log" {
            // A blend far beyond its materials overflows: the error names it, not the others.
            let wild = pred.lerp(&names[0], &names[1], 1e6).unwrap();
            let mut out = vec![0.0; 2 * nc];
            let e = (0..cells)
                .find_map(|c| each(&[&a, &wild], c, &mut out).err())
                .expect("the blend overflows somewhere")
                .to_string();
            assert!(
                e.contains(&format!("of the prediction {}", wild.label()))
                    && e.contains("prediction overflowed"),
                "{e}"
            );
        }
    }
}

/// A wavelength selection whose stored span starts after the first stored channel (475 nm
/// between 450 and 500, 650 nm stored; one at 700 nm alone) reads each cell's own channels on
/// every lookup path (the dataset, the forward cache, the sidecar), with prefetch hints before
/// each cell as renders give them: its values are the interpolated single-value lookups of
/// the stored channels. (Every other selection in these tests starts at the first channel,
/// where the span's offset is 0 and any arithmetic on it reads the same values.)
#[test]
fn selections_starting_past_the_first_channel_read_their_own_channels() {
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let side = pred.transformed_store_path();
    pred.build_transformed_store(&side, |_, _| {}).unwrap();
    let nc = pred.channels().len();
    for p in [
        pred.clone(),
        pred.with_forward_cache(),
        pred.with_transformed_store(&side).unwrap(),
    ] {
        let full = p.predict(&[0.2, -0.3], PredictorKind::Smooth).unwrap();
        for (wavelengths, taps) in [
            ("475,650", vec![(1, 2, 0.5), (5, 5, 0.0)]),
            ("700", vec![(6, 6, 0.0)]),
        ] {
            let sub = full
                .with_wavelengths(&Channels::parse_wavelengths(wavelengths).unwrap())
                .unwrap();
            let mut out = vec![0.0; taps.len()];
            sub.will_need_cells(&mut (0..p.grid().len()));
            for a in 0..p.grid().len() {
                sub.prefetch_cell(a);
                sub.eval_cell(a, &mut out).unwrap();
                for (k, &(lo, hi, t)) in taps.iter().enumerate() {
                    let v_lo = full.value_at(a * nc + lo).unwrap();
                    let want = if t == 0.0 {
                        v_lo
                    } else {
                        (1.0 - t) * v_lo + t * full.value_at(a * nc + hi).unwrap()
                    };
                    assert_eq!(
                        out[k].to_bits(),
                        want.to_bits(),
                        "{wavelengths}, cell {a}, output {k}: {} vs {want}",
                        out[k]
                    );
                }
            }
        }
    }
}

#[test]
fn exact_predictor_reproduces_training_materials_and_lerp_is_linear() {
    let f = fixture(8, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let ev = evaluate(&pred, &EvalOptions::default(), &|_, _, _| {}).unwrap();
    let store = pred.store();
    let typical = (store.header().stats.sum_sq / store.d() as f64).sqrt();
    for r in &ev.reconstruction {
        assert!(
            r.exact_rmse < 1e-6 * typical,
            "{}: {} (typical value {typical})",
            r.name,
            r.exact_rmse
        );
        // The smooth predictor shrinks towards the mean: a visible but small error.
        assert!(r.smooth_rmse > r.exact_rmse, "{}", r.name);
    }
    // Direct lookups at a training point equal the stored values to f32 precision.
    let name = &pred.model().materials[3].name;
    let m = pred
        .predict(
            &pred.model().materials[3].coords.clone(),
            PredictorKind::Exact,
        )
        .unwrap();
    let mut row = vec![0f32; store.d()];
    store.material_row(3, 0..store.d(), &mut row).unwrap();
    for d in (0..store.d()).step_by(11) {
        let v = m.value_at(d).unwrap();
        assert!(
            (v - f64::from(row[d])).abs() <= 1e-5 * f64::from(row[d]).abs() + 1e-9,
            "{name} d = {d}: {v} vs {}",
            row[d]
        );
    }
    // lerp(a, b, t) in the transformed space.
    let (a, b) = (
        pred.model().materials[1].name.clone(),
        pred.model().materials[6].name.clone(),
    );
    let l = pred.lerp(&a, &b, 0.25).unwrap();
    let t = pred.transform();
    let mut vals = vec![0f32; pred.n_materials()];
    for d in (0..store.d()).step_by(53) {
        store.values_at(d, &mut vals).unwrap();
        let want =
            t.inverse(0.25 * t.forward(f64::from(vals[1])) + 0.75 * t.forward(f64::from(vals[6])));
        let got = l.value_at(d).unwrap();
        assert!(
            (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
            "{got} vs {want}"
        );
    }
}

fn dense_data(n: usize, d: usize) -> Mat<f64> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    // Materials on a low-dimensional manifold plus noise, so the methods differ.
    let basis: Vec<Vec<f64>> = (0..3)
        .map(|_| (0..d).map(|_| rng.random_range(-1.0..1.0)).collect())
        .collect();
    Mat::from_fn(n, d, |i, j| {
        let t = i as f64 / n as f64 * 3.0;
        2.0 + t.sin() * basis[0][j]
            + t.cos() * basis[1][j]
            + 0.3 * t * basis[2][j]
            + 0.05 * ((i * 31 + j * 17) % 13) as f64 / 13.0
    })
}

/// A model whose K needs jitter (two materials at one latent point, noise 1e-20): far from
/// every material the variance is the prior plus the jitter, and the support's variance
/// fraction is 1 (it was (s^2 + mu + j) / (s^2 + mu), above 1).
#[test]
fn variance_fractions_count_the_jitter_as_prior() {
    let f = fixture(6, "log");
    let mut model = gplvm::Model::load(&f.model).unwrap();
    model.materials[1].coords = model.materials[0].coords.clone();
    model.hyperparameters.noise = 1e-20;
    let path = f.model.with_file_name("jittered.toml");
    model.save(&path).unwrap();
    let pred = Predictor::open(&path).unwrap();
    let h = &model.hyperparameters;
    let far: Vec<f64> = model.materials[0].coords.iter().map(|v| v + 1e3).collect();
    let var = pred.variance(&far).unwrap();
    let jitter = var - (h.signal_variance + h.noise);
    assert_eq!(pred.prior_variance(), var);
    assert!(
        jitter > 100.0 * f64::EPSILON * h.signal_variance,
        "jitter {jitter:e}"
    );
    let support = pred.support(&far).unwrap();
    assert!(
        (support.variance_fraction - 1.0).abs() <= 4.0 * f64::EPSILON,
        "{support:?}"
    );
    let at = pred.support(&model.materials[0].coords).unwrap();
    assert!(at.variance_fraction < 1e-3, "{at:?}");
}

/// A near-exact reconstruction on data with a large offset (raw values of a bright specular
/// peak): the Gram error keeps its relative accuracy instead of drowning in the rounding of
/// `G_hh` (the expanded `G_hh - 2 c^T G_h + c^T G c` gave ~1e-16 G_hh of noise, here ~1e-3,
/// against a true error of ~1e-12).
#[test]
fn gram_error_of_a_near_exact_reconstruction_is_accurate_on_large_values() {
    let (n, d) = (9, 40);
    let y = Mat::from_fn(n, d, |i, j| 1.0e5 * dense_data(n, d)[(i, j)]);
    let g = y.as_ref() * y.as_ref().transpose();
    // A direction v summing to 0 (every method's coefficients sum to 1: affine predictors).
    let v: Vec<f64> = (0..n)
        .map(|i| [1.0, -1.0][i % 2] * (i + 1) as f64)
        .collect();
    let v_mean = v.iter().sum::<f64>() / n as f64;
    for (h, delta) in [(0, 1e-9), (4, 1e-11), (8, 1e-13)] {
        // c = e_h + delta (v - mean v).
        let c: Vec<f64> = (0..n)
            .map(|i| f64::from(u8::from(i == h)) + delta * (v[i] - v_mean))
            .collect();
        // Direct: the residual vector formed from the data, each entry computed as
        // sum_i (c_i - [i == h]) y_ij so that no large terms cancel.
        let direct: f64 = (0..d)
            .map(|j| {
                (0..n)
                    .map(|i| (c[i] - f64::from(u8::from(i == h))) * y[(i, j)])
                    .sum::<f64>()
                    .powi(2)
            })
            .sum();
        let got = sq_error(g.as_ref(), h, &c);
        assert!(direct > 0.0);
        assert!(
            rel(got, direct) < 1e-6,
            "h {h}, delta {delta:e}: Gram error {got:e} vs direct {direct:e} (G_hh {:e})",
            g[(h, h)]
        );
    }
}

#[test]
fn leave_one_out_via_the_gram_matrix_equals_brute_force() {
    let (n, d) = (9, 40);
    let y = dense_data(n, d);
    let g = gp_core::gram_from_data(y.as_ref(), Par::Seq).unwrap();
    let config = FitParams {
        transform: "raw".into(),
        max_iterations: 300,
        ..FitParams::default()
    }
    .check()
    .unwrap();
    let q = config.params.latent_dim;
    let dist2 = |a: &[f64], i: usize| -> f64 { (0..d).map(|j| (a[j] - y[(i, j)]).powi(2)).sum() };
    for h in [0, 4, 8] {
        let loo = leave_one_out(g.as_ref(), d, &config, h, 3, None).unwrap();
        let others: Vec<usize> = (0..n).filter(|&i| i != h).collect();
        let combine = |c: &[f64]| -> Vec<f64> {
            (0..d)
                .map(|j| (0..n).map(|i| c[i] * y[(i, j)]).sum())
                .collect()
        };
        for m in &loo.methods {
            assert_eq!(
                m.coefficients[h], 0.0,
                "{:?} uses the held-out row",
                m.method
            );
            let ystar = combine(&m.coefficients);
            let brute = dist2(&ystar, h);
            assert!(
                rel(brute, m.sq_error) < 1e-8,
                "{:?}: Gram {} vs dense {brute}",
                m.method,
                m.sq_error
            );
            assert!((m.sq_error - sq_error(g.as_ref(), h, &m.coefficients)).abs() < 1e-12);
        }
        let by = |k: Method| loo.methods.iter().find(|m| m.method == k).unwrap();
        // Nearest: brute-force argmin of the dense distances.
        let yh: Vec<f64> = (0..d).map(|j| y[(h, j)]).collect();
        let best_single = others
            .iter()
            .map(|&i| dist2(&yh, i))
            .fold(f64::INFINITY, f64::min);
        assert!(rel(best_single, by(Method::Nearest).sq_error) < 1e-10);
        // Best pair: dense search over pairs and a on a fine grid is never better.
        let mut grid_best = f64::INFINITY;
        for (x, &i) in others.iter().enumerate() {
            for &j in &others[x + 1..] {
                for k in 0..=200 {
                    let a = k as f64 / 200.0;
                    let ys: Vec<f64> = (0..d)
                        .map(|c| a * y[(i, c)] + (1.0 - a) * y[(j, c)])
                        .collect();
                    grid_best = grid_best.min(dist2(&ys, h));
                }
            }
        }
        let lb = by(Method::LerpBest).sq_error;
        assert!(
            lb <= grid_best + 1e-9 && grid_best <= lb * 1.01 + 1e-9,
            "{lb} vs {grid_best}"
        );
        assert!(lb <= by(Method::LerpLatent).sq_error + 1e-12);
        assert!(lb <= by(Method::Nearest).sq_error + 1e-12);
        // PCA: dense eigen-decomposition of the others' D x D covariance, projection of y_h.
        let mean: Vec<f64> = (0..d)
            .map(|j| others.iter().map(|&i| y[(i, j)]).sum::<f64>() / others.len() as f64)
            .collect();
        let yc = Mat::from_fn(others.len(), d, |r, j| y[(others[r], j)] - mean[j]);
        let cov = yc.transpose() * &yc;
        let eig = cov.self_adjoint_eigen(Side::Lower).unwrap();
        let u = eig.U();
        let mut proj = mean.clone();
        for k in 0..q {
            let col = d - 1 - k;
            let dot: f64 = (0..d).map(|j| u[(j, col)] * (yh[j] - mean[j])).sum();
            for j in 0..d {
                proj[j] += dot * u[(j, col)];
            }
        }
        let pca = combine(&by(Method::Pca).coefficients);
        for j in 0..d {
            assert!(
                (pca[j] - proj[j]).abs() < 1e-8,
                "PCA j = {j}: {} vs {}",
                pca[j],
                proj[j]
            );
        }
        // GP: the coefficients equal the dense posterior mean over the others at the GP point,
        // with the model refitted on the others' dense data.
        let y_o = Mat::from_fn(others.len(), d, |r, j| y[(others[r], j)]);
        let g_o = gp_core::gram_from_data(y_o.as_ref(), Par::Seq).unwrap();
        let fit = gplvm::fit_gram(g_o.as_ref(), d, &config).unwrap();
        let gp = gp_core::GpRegression::new(fit.x.as_ref(), fit.params, Par::Seq).unwrap();
        let w = gp
            .weights(&loo.gp_point, gp_core::Predictor::Smooth)
            .unwrap();
        let mean_o = gp_core::column_mean(y_o.as_ref());
        let dense = gp_core::posterior_mean(&w, y_o.as_ref(), &mean_o).unwrap();
        let via_c = combine(&by(Method::Gp).coefficients);
        for j in 0..d {
            assert!((dense[j] - via_c[j]).abs() < 1e-9 * (1.0 + dense[j].abs()));
        }
        // Lerp-latent: the best blend of the two others whose refitted latent points are
        // nearest to the GP's point (a = <y_h - y_j, y_i - y_j> / |y_i - y_j|^2 from the dense
        // rows, clamped to [0, 1]), with no near tie for the second place.
        let mut by_dist: Vec<(f64, usize)> = (0..others.len())
            .map(|r| {
                let d2 = (0..q).map(|k| (fit.x[(r, k)] - loo.gp_point[k]).powi(2));
                (d2.sum(), others[r])
            })
            .collect();
        by_dist.sort_by(|a, b| a.0.total_cmp(&b.0));
        assert!(by_dist[1].0 < by_dist[2].0 * (1.0 - 1e-6), "{by_dist:?}");
        let (i, j) = (by_dist[0].1, by_dist[1].1);
        let u: Vec<f64> = (0..d).map(|c| y[(i, c)] - y[(j, c)]).collect();
        let ru: f64 = (0..d).map(|c| (yh[c] - y[(j, c)]) * u[c]).sum();
        let a = (ru / u.iter().map(|v| v * v).sum::<f64>()).clamp(0.0, 1.0);
        let lat = &by(Method::LerpLatent).coefficients;
        for k in 0..n {
            let want = [(i, a), (j, 1.0 - a)]
                .iter()
                .find(|p| p.0 == k)
                .map_or(0.0, |p| p.1);
            assert!(
                (lat[k] - want).abs() < 1e-9,
                "held out {h}: lerp-latent {lat:?}, want a = {a} on {i}, 1 - a on {j}"
            );
        }
        // The GP's point is a local minimum: nudging it does not reduce the error.
        let e0 = dist2(&dense, h);
        for axis in 0..q {
            for s in [-1e-3, 1e-3] {
                let mut x = loo.gp_point.clone();
                x[axis] += s;
                let w = gp.weights(&x, gp_core::Predictor::Smooth).unwrap();
                let p = gp_core::posterior_mean(&w, y_o.as_ref(), &mean_o).unwrap();
                assert!(
                    dist2(&p, h) >= e0 * (1.0 - 1e-6),
                    "not a minimum along {axis}"
                );
            }
        }
    }
}

/// `leave_one_out` refuses fewer than 3 materials (the refit without one would keep one) and
/// a held-out index past the materials, each alone, with N and h in the message; 3 materials
/// (a refit on 2) are enough.
#[test]
fn leave_one_out_needs_three_materials_and_a_held_out_index_among_them() {
    let d = 40;
    let config = FitParams {
        transform: "raw".into(),
        latent_dim: 1,
        max_iterations: 50,
        ..FitParams::default()
    }
    .check()
    .unwrap();
    let gram = |n: usize| gp_core::gram_from_data(dense_data(n, d).as_ref(), Par::Seq).unwrap();
    for (n, h) in [(2, 0), (2, 1), (5, 5), (5, 7)] {
        let e = leave_one_out(gram(n).as_ref(), d, &config, h, 1, None).unwrap_err();
        let msg = e.to_string();
        assert!(
            matches!(e, Error::InvalidArgument { .. })
                && msg.contains("at least 3 materials")
                && msg.contains(&format!("got N = {n}, h = {h}")),
            "{msg}"
        );
    }
    let loo = leave_one_out(gram(3).as_ref(), d, &config, 2, 1, None).unwrap();
    assert_eq!(loo.held_out, 2);
    assert_eq!(loo.methods.len(), Method::ALL.len());
}

/// PCA of materials on a line (one nonzero principal component) asked for 4 components keeps
/// only the real one: the coefficients are the closed form `1/n + t_i (v . (y_h - m)) / (|v|^2
/// sum_i t_i^2)` (`t_i` the materials' centred positions along the direction `v`, `m` their
/// mean), not the rounding of the null directions divided by their rounding-level eigenvalues
/// (which moves the coefficients, though not their combination of the rows).
#[test]
fn pca_of_collinear_materials_keeps_only_their_component() {
    use predict::evaluate::pca_projection;
    let base = [0.7, 1.3, -0.4, 2.2, 0.9, -1.1];
    let v = [0.31, -0.57, 1.13, 0.29, -0.83, 0.47];
    let t = [0.3, 1.7, 2.9, 4.1, -1.3];
    let targets = [
        [1.9, -0.6, 0.8, 1.4, 2.3, 0.2],
        [-0.3, 2.1, 1.7, -0.9, 0.6, 1.2],
    ];
    // Also with the line 100 times as long: the null directions' eigenvalues are then well
    // above 1e-12 / top (and below 1e-12 top, the cut-off).
    for (scale, target) in [1.0, 100.0].into_iter().zip(targets) {
        let v = v.map(|x| scale * x);
        // Rows 0..5 on the line base + t v, row 5 the target off it.
        let y = Mat::from_fn(6, 6, |i, j| {
            if i < 5 {
                base[j] + t[i] * v[j]
            } else {
                target[j]
            }
        });
        let g = gp_core::gram_from_data(y.as_ref(), Par::Seq).unwrap();
        let c = pca_projection(g.as_ref(), &[0, 1, 2, 3, 4], 5, 4).unwrap();
        let t_mean = t.iter().sum::<f64>() / 5.0;
        let tc: Vec<f64> = t.iter().map(|x| x - t_mean).collect();
        let v_r: f64 = (0..6)
            .map(|j| v[j] * (target[j] - base[j] - t_mean * v[j]))
            .sum();
        let v2: f64 = v.iter().map(|x| x * x).sum();
        let t2: f64 = tc.iter().map(|x| x * x).sum();
        for i in 0..5 {
            let want = 0.2 + tc[i] * v_r / (v2 * t2);
            assert!((c[i] - want).abs() < 1e-9, "{i}: {c:?} vs {want}");
        }
    }
}

/// A warm leave-one-out refit (`refit_warm`) stops by the fit configuration's own L-BFGS rules,
/// not the optimiser's defaults (2000 iterations, tolerances 1e-6 and 1e-12): a gradient
/// tolerance that the start meets returns the warm start itself, and an iteration cap of 1 or a
/// cost tolerance that every step meets stops after a step or two, well short of the
/// configured run's optimum, which is a maximum of the likelihood it was given.
#[test]
fn warm_refits_stop_by_the_configured_rules() {
    let (n, d, h) = (9, 40, 4);
    let y = dense_data(n, d);
    let g = gp_core::gram_from_data(y.as_ref(), Par::Seq).unwrap();
    let params = FitParams {
        transform: "raw".into(),
        max_iterations: 300,
        ..FitParams::default()
    };
    let config = params.clone().check().unwrap();
    assert_eq!(config.params.optimizer, gplvm::OptimizerKind::Lbfgs);
    let full = gplvm::fit_gram(g.as_ref(), d, &config).unwrap();
    let others: Vec<usize> = (0..n).filter(|&i| i != h).collect();
    let g_oo = gp_core::subset_gram(g.as_ref(), &others).unwrap();
    let x0 = Mat::from_fn(n - 1, full.x.ncols(), |i, k| full.x[(others[i], k)]);
    let refit = |p: FitParams| {
        predict::evaluate::refit_warm(
            g_oo.as_ref(),
            d,
            &p.check().unwrap(),
            x0.as_ref(),
            &full.params,
        )
        .unwrap()
    };
    let configured = refit(params.clone());
    let at_start = refit(FitParams {
        gradient_tolerance: 1e10,
        ..params.clone()
    });
    assert_eq!(at_start.x, x0);
    let capped = refit(FitParams {
        max_iterations: 1,
        ..params.clone()
    });
    let by_cost = refit(FitParams {
        cost_tolerance: 1e10,
        ..params.clone()
    });
    // Each reported log-likelihood is the GPLVM objective's at the returned point, recomputed
    // from the scaled Gram matrix (not from the optimiser's per-value scale).
    let (s, _) =
        gplvm::fit::scaled_centred_gram(g_oo.as_ref(), d, config.params.data_scaling).unwrap();
    let objective = gp_core::GplvmObjective::new(s, d)
        .unwrap()
        .with_prior(config.params.prior);
    for r in [&configured, &at_start, &capped, &by_cost] {
        let (ll, _) = objective
            .log_likelihood(r.x.as_ref(), &r.params, Par::Seq)
            .unwrap();
        assert!(
            (r.log_likelihood - ll).abs() <= 1e-9 * ll.abs(),
            "{} vs {ll}",
            r.log_likelihood
        );
    }
    // The configured run ends at a maximum of the objective it was given: a further L-BFGS run
    // from its end, with the gradient-norm rule alone (1e-12), gains 7e-11 in log-likelihood.
    // A gradient shifted by 1/(N D) per component (the value per data value, its gradient not)
    // still ends near the optimum, but 3.3e-5 short of it.
    let flat =
        gplvm::fit::flat_objective(&objective, x0.ncols(), full.params.clone(), &config.params)
            .unwrap();
    let end = flat
        .pack(configured.x.as_ref(), &configured.params)
        .unwrap();
    let further = gplvm::optim::lbfgs(
        |t| Ok(flat.neg_log_likelihood_and_gradient(t, Par::Seq)?),
        &end,
        &gplvm::optim::LbfgsSettings {
            gradient_tolerance: 1e-12,
            cost_tolerance: 0.0,
            ..Default::default()
        },
    )
    .unwrap();
    let gain = -further.value - configured.log_likelihood;
    assert!(
        gain < 1e-6,
        "a further run gains {gain:.2e} over the configured refit's end"
    );
    // The configured run gains ~4 in log-likelihood over the start (53.7 to 58.0); one step
    // (or two: the cost rule retries once from steepest descent) gains under 1.1.
    for (rule, stopped) in [("1 iteration", &capped), ("cost tolerance", &by_cost)] {
        assert!(
            stopped.x != x0
                && stopped.log_likelihood > at_start.log_likelihood
                && stopped.log_likelihood < configured.log_likelihood - 1.0,
            "{rule}: {} (start {}, configured {})",
            stopped.log_likelihood,
            at_start.log_likelihood,
            configured.log_likelihood
        );
    }
}

/// `brdf_space_rmse` refuses a coefficient matrix and targets that do not fit the store, each
/// mismatch alone (a matrix of another width, a target count other than its rows, a target
/// past the materials), with an error giving the shapes, where the pass would otherwise panic
/// or score a row against no target; fitting ones give one RMSE per row (raw data: 0 for a
/// material's own row, more for another's).
#[test]
fn brdf_space_errors_refuse_shapes_that_do_not_fit_the_store() {
    use predict::evaluate::brdf_space_rmse;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("data.sbrdf");
    write_store(&path, 4, 0, grid());
    let store = Store::open(&path).unwrap();
    let identity =
        |rows: usize, cols: usize| Mat::from_fn(rows, cols, |i, j| if i == j { 1.0 } else { 0.0 });
    let run = |targets: &[usize], coef: &Mat<f64>| {
        brdf_space_rmse(&store, Transform::Raw, targets, coef.as_ref(), &|_, _| {})
    };
    assert_eq!(run(&[0, 1], &identity(2, 4)).unwrap(), vec![0.0, 0.0]);
    let swapped = run(&[1, 0], &identity(2, 4)).unwrap();
    assert!(swapped.iter().all(|&e| e > 0.0), "{swapped:?}");
    for (targets, coef) in [
        (&[0, 1][..], identity(2, 3)),
        (&[0][..], identity(2, 4)),
        (&[0, 4][..], identity(2, 4)),
    ] {
        let e = run(targets, &coef).unwrap_err().to_string();
        let want = format!(
            "coefficient matrix 2x{} and {} targets for 4 materials",
            coef.ncols(),
            targets.len()
        );
        assert!(e.contains(&want), "{e}");
    }
}

#[test]
fn brdf_space_errors_equal_model_space_errors_for_raw_data() {
    let f = fixture(6, "raw");
    let pred = Predictor::open(&f.model).unwrap();
    let ev = evaluate(
        &pred,
        &EvalOptions {
            loo: true,
            starts: 2,
            warm_start: true,
            refit_iterations: Some(50),
        },
        &|_, _, _| {},
    )
    .unwrap();
    let loo = ev.loo.as_ref().unwrap();
    assert_eq!(loo.len(), 6);
    for row in loo {
        assert_eq!(row.methods.len(), Method::ALL.len());
        for m in &row.methods {
            // Raw transform: the transformed space is BRDF space; the Gram formula and the
            // streaming pass agree up to cancellation in G_hh - 2 c^T G_h + c^T G c.
            assert!(
                (m.brdf_rmse - m.model_rmse).abs() <= 1e-5 * m.brdf_rmse.max(1e-3),
                "{} {:?}: {} vs {}",
                row.name,
                m.method,
                m.brdf_rmse,
                m.model_rmse
            );
        }
    }
    assert_eq!(ev.summary.len(), 2 + Method::ALL.len());
}

/// The BRDF-space RMSE of `coef`'s row `r` against material `targets[r]`, summed index by
/// index in the test from the stored rows with the scalar transform (a different code path
/// from the pass: no chunks, columns, batch transform or matrix product).
fn direct_brdf_rmse(
    store: &Store,
    transform: Transform,
    targets: &[usize],
    coef: &Mat<f64>,
) -> Vec<f64> {
    let (n, d) = (store.n_materials(), store.d());
    let rows: Vec<Vec<f32>> = (0..n)
        .map(|i| {
            let mut row = vec![0f32; d];
            store.material_row(i, 0..d, &mut row).unwrap();
            row
        })
        .collect();
    let n_angles = store.grid().len() as f64;
    targets
        .iter()
        .enumerate()
        .map(|(r, &t)| {
            let sum: f64 = (0..d)
                .map(|k| {
                    let y: f64 = (0..n)
                        .map(|j| coef[(r, j)] * transform.forward(f64::from(rows[j][k])))
                        .sum();
                    let diff = f64::from(rows[t][k]) - transform.inverse(y);
                    diff * diff
                })
                .sum();
            (sum / n_angles).sqrt()
        })
        .collect()
}

/// `brdf_space_rmse` equals the Eq. 22 RMSE summed index by index ([`direct_brdf_rmse`]) for
/// blends of several materials under the log and raw transforms, on a store of one chunk with
/// more valid columns than the pass multiplies at once (its 512-column blocks must line up
/// with their transformed values) and on a store of many small chunks (whose partial sums the
/// pass adds up). The two sums differ only in rounding order and in the vectorised against
/// scalar `ln_1p`/`exp_m1`: relative tolerance 1e-9, for errors of order 1e-2..1 of the values.
#[test]
fn brdf_space_errors_equal_a_direct_sum_over_every_index() {
    use predict::evaluate::brdf_space_rmse;
    let dir = tempfile::tempdir().unwrap();
    let coef = Mat::from_fn(4, 5, |r, j| {
        [
            [0.0, 0.0, 1.0, 0.0, 0.0],
            [0.0, 0.3, 0.0, 0.7, 0.0],
            [1.2, 0.0, 0.0, 0.0, -0.2],
            [0.25, 0.25, 0.0, 0.25, 0.25],
        ][r][j]
    });
    let targets = [1, 0, 3, 2];
    for (name, chunk_len) in [("one.sbrdf", None), ("many.sbrdf", Some(700))] {
        let path = dir.path().join(name);
        let options = StoreOptions {
            chunk_len,
            ..StoreOptions::default()
        };
        write_store_with(&path, 5, 0, grid(), options);
        let store = Store::open(&path).unwrap();
        let nc = store.channels().len();
        let mut buf = Vec::new();
        let (range, _) = store.chunk(0, &mut buf).unwrap();
        let valid = range.filter(|d| store.validity_mask()[d / nc]).count();
        match chunk_len {
            None => assert!(store.n_chunks() == 1 && valid > 2 * 512, "{valid}"),
            Some(_) => assert!(store.n_chunks() >= 8, "{}", store.n_chunks()),
        }
        for transform in [Transform::Log { offset: 0.01 }, Transform::Raw] {
            let got =
                brdf_space_rmse(&store, transform, &targets, coef.as_ref(), &|_, _| {}).unwrap();
            let want = direct_brdf_rmse(&store, transform, &targets, &coef);
            for (r, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    *w > 0.0 && rel(*g, *w) < 1e-9,
                    "{name} {transform:?} row {r}: {g} vs {w}"
                );
            }
        }
    }
}

/// A blend whose BRDF-space error overflows on sound data (log space, 1e6 times the
/// difference of two materials) is an error naming that row's target material, the store and
/// the infinite value, not an RMSE of infinity; the finite row before it does not stop it.
#[test]
fn overflowing_brdf_space_errors_name_the_row_and_the_store() {
    use predict::evaluate::brdf_space_rmse;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("data.sbrdf");
    write_store(&path, 4, 0, grid());
    let store = Store::open(&path).unwrap();
    let coef = Mat::from_fn(2, 4, |r, j| match (r, j) {
        (0, 0) => 1.0,
        (1, 1) => 1e6,
        (1, 2) => 1.0 - 1e6,
        _ => 0.0,
    });
    let transform = Transform::Log { offset: 0.01 };
    let e = brdf_space_rmse(&store, transform, &[0, 3], coef.as_ref(), &|_, _| {})
        .unwrap_err()
        .to_string();
    let want = format!(
        "the squared BRDF-space error of material {:?} in {} is inf: ",
        store.names()[3],
        path.display()
    );
    assert!(e.starts_with(&want) && e.contains("overflowed"), "{e}");
}

/// `evaluate` reports each leave-one-out refit once (counts 1..=N of N, in any order: the
/// refits run in parallel) and each chunk of the error pass once (1..=chunks of chunks), on a
/// store of several chunks.
#[test]
fn evaluate_reports_every_refit_and_every_chunk_once() {
    let options = StoreOptions {
        chunk_len: Some(1500),
        ..StoreOptions::default()
    };
    let f = fixture_with(5, "log", options);
    let pred = Predictor::open(&f.model).unwrap();
    let chunks = pred.store().n_chunks();
    assert!(chunks >= 4, "{chunks}");
    let seen = std::sync::Mutex::new(Vec::new());
    let options = EvalOptions {
        loo: true,
        starts: 1,
        warm_start: true,
        refit_iterations: Some(20),
    };
    evaluate(&pred, &options, &|stage, done, total| {
        seen.lock().unwrap().push((stage, done, total))
    })
    .unwrap();
    let seen = seen.into_inner().unwrap();
    for (stage, total) in [(Stage::Refits, 5), (Stage::Pass, chunks)] {
        let mut counts: Vec<usize> = seen
            .iter()
            .filter(|s| s.0 == stage)
            .map(|&(_, done, t)| {
                assert_eq!(t, total, "{stage:?}");
                done
            })
            .collect();
        counts.sort_unstable();
        assert_eq!(counts, (1..=total).collect::<Vec<_>>(), "{stage:?}");
    }
}

/// A leave-one-out refit cap of `c` iterations gives Hooke-Jeeves refits a budget of
/// `c * 2 N q` evaluations (N = 5 materials of the model, q = 2): the same leave-one-out as a
/// model whose configuration holds that budget (and at most `c` iterations) with no cap; a
/// budget of `c * (2 + N) q` instead places some held-out material elsewhere, so the
/// comparison can fail.
#[test]
fn a_refit_cap_gives_hooke_jeeves_refits_cap_times_2nq_evaluations() {
    let f = fixture(5, "log");
    let store = Arc::new(Store::open(&f.store).unwrap());
    let run = |max_evaluations: usize, max_iterations: u64, cap: Option<u64>| {
        let mut model = Model::load(&f.model).unwrap();
        model.config.optimizer = gplvm::OptimizerKind::HookeJeeves;
        model.config.max_evaluations = max_evaluations;
        model.config.max_iterations = max_iterations;
        let pred = Predictor::with_store(model, &f.model, store.clone()).unwrap();
        let options = EvalOptions {
            loo: true,
            starts: 2,
            warm_start: true,
            refit_iterations: cap,
        };
        let ev = evaluate(&pred, &options, &|_, _, _| {}).unwrap();
        ev.loo
            .unwrap()
            .into_iter()
            .map(|r| r.gp_point)
            .collect::<Vec<_>>()
    };
    let cap = 2u64;
    let (n, q) = (5, 2);
    let capped = run(3000, 1000, Some(cap));
    let exact = run(cap as usize * 2 * n * q, cap, None);
    assert_eq!(capped, exact);
    let other = run(cap as usize * (2 + n) * q, cap, None);
    assert_ne!(capped, other);
}

/// With leave-one-out, each baseline's summary counts the materials where the GP's
/// BRDF-space error is strictly lower than the baseline's (counted here from the rows), the
/// GP's own summary has no count, and every summary's mean and median are those of its
/// column of rows (written out: sum / N, and the middle of the sorted column of N = 7).
#[test]
fn leave_one_out_summaries_count_where_the_gp_is_better() {
    let f = fixture(7, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let options = EvalOptions {
        loo: true,
        starts: 2,
        warm_start: true,
        refit_iterations: Some(50),
    };
    let ev = evaluate(&pred, &options, &|_, _, _| {}).unwrap();
    let rows = ev.loo.as_ref().unwrap();
    assert_eq!(rows.len(), 7);
    let loo_summaries = &ev.summary[2..];
    assert_eq!(loo_summaries.len(), Method::ALL.len());
    let mut counts = Vec::new();
    for (mi, (method, s)) in Method::ALL.iter().zip(loo_summaries).enumerate() {
        assert_eq!(s.method, format!("loo-{}", method.name()));
        let brdf: Vec<f64> = rows.iter().map(|r| r.methods[mi].brdf_rmse).collect();
        let model: Vec<f64> = rows.iter().map(|r| r.methods[mi].model_rmse).collect();
        for (column, mean, median) in [
            (brdf, s.brdf_mean, s.brdf_median),
            (model, s.model_mean, s.model_median),
        ] {
            let mut sorted = column.clone();
            sorted.sort_by(f64::total_cmp);
            assert_eq!(median, sorted[3], "{method:?}");
            let want = column.iter().sum::<f64>() / 7.0;
            // The same 7 terms summed in the same order: equal up to rounding.
            assert!(rel(mean, want) < 1e-14, "{method:?}: {mean} vs {want}");
        }
        if *method == Method::Gp {
            assert_eq!(s.gp_better, None);
        } else {
            let better = rows
                .iter()
                .filter(|r| r.methods[0].brdf_rmse < r.methods[mi].brdf_rmse)
                .count();
            assert_eq!(s.gp_better, Some(better), "{method:?}");
            counts.push(better);
        }
    }
    assert_eq!(rows[0].methods[0].method, Method::Gp);
    // Counts strictly between 0 and N somewhere (so that "worse" or "never" would differ).
    assert!(counts.iter().any(|&c| c > 0 && c < 7), "{counts:?}");
}

/// A leave-one-out refit cap beyond any budget (`evaluate --refit-iterations` takes any u64)
/// leaves the model's own configuration in force: the Hooke-Jeeves evaluation budget derived
/// from it (`cap * 2 N q`) overflowed, a panic in debug builds and, in release builds, a wrap
/// to 0 evaluations (1 after the optimiser's floor), so the refits silently stayed at the warm
/// start.
#[test]
fn a_huge_refit_cap_leaves_the_refits_configured_budget() {
    let f = fixture(5, "log");
    let mut model = Model::load(&f.model).unwrap();
    model.config.optimizer = gplvm::OptimizerKind::HookeJeeves;
    model.config.max_evaluations = 3000;
    let store = Arc::new(Store::open(&f.store).unwrap());
    let pred = Predictor::with_store(model, &f.model, store).unwrap();
    let run = |cap: Option<u64>| {
        let options = EvalOptions {
            loo: true,
            starts: 2,
            warm_start: true,
            refit_iterations: cap,
        };
        evaluate(&pred, &options, &|_, _, _| {}).unwrap()
    };
    let own = run(None);
    let own_loo = own.loo.as_ref().unwrap();
    for cap in [1u64 << 63, u64::MAX] {
        let capped = run(Some(cap));
        for (a, b) in own_loo.iter().zip(capped.loo.as_ref().unwrap()) {
            assert_eq!(a.gp_point, b.gp_point, "cap {cap}, {}", a.name);
            for (x, y) in a.methods.iter().zip(&b.methods) {
                assert_eq!(x.model_rmse.to_bits(), y.model_rmse.to_bits(), "cap {cap}");
            }
        }
    }
    // The budget matters here (so the comparison above can fail): a starved refit (a cap of
    // 1: 2 N q = 16 evaluations) places some held-out material elsewhere.
    let starved = run(Some(1));
    assert!(
        own_loo
            .iter()
            .zip(starved.loo.as_ref().unwrap())
            .any(|(a, b)| a.gp_point != b.gp_point)
    );
}

/// A model whose recorded fit configuration a fit refuses (edited by hand, or written before a
/// rule was added) still predicts; a leave-one-out refit, which uses the configuration, is an
/// error naming the model file (it named no file).
#[test]
fn an_invalid_fit_configuration_is_an_error_naming_the_model_file() {
    let f = fixture(5, "log");
    let mut model = Model::load(&f.model).unwrap();
    model.config.min_step = 10.0;
    let store = Arc::new(Store::open(&f.store).unwrap());
    let pred = Predictor::with_store(model, &f.model, store).unwrap();
    evaluate(&pred, &EvalOptions::default(), &|_, _, _| {}).unwrap();
    let options = EvalOptions {
        loo: true,
        ..EvalOptions::default()
    };
    let e = evaluate(&pred, &options, &|_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with(&format!("{}: fit configuration: ", f.model.display()))
            && e.contains("min_step = 10: must be at most initial_step"),
        "{e}"
    );
}

/// A leave-one-out refit that cannot be done (holding out the one distinct material of
/// three leaves two identical ones: nothing to fit) is an error naming the held-out material;
/// the refit's own message ("the 2 materials are identical") counted materials the user never
/// gave and did not say which were left.
#[test]
fn a_failed_leave_one_out_refit_names_the_held_out_material() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("twins.sbrdf");
    let preset = brdf_synth::preset(0);
    let mut twin = preset[0].clone();
    twin.name = format!("{}_twin", twin.name);
    let picked = vec![preset[0].clone(), twin, preset[20].clone()];
    brdf_synth::write_store(
        &store,
        &picked,
        grid(),
        &channels(),
        StoreOptions::default(),
        0,
        |_| {},
    )
    .unwrap();
    let params = FitParams {
        latent_dim: 1,
        max_iterations: 300,
        ..FitParams::default()
    };
    let model = gplvm::fit_store(&store, &params.check().unwrap()).unwrap();
    let model_path = dir.path().join("model.toml");
    model.save(&model_path).unwrap();
    let pred = Predictor::open(&model_path).unwrap();
    // Reconstruction alone works.
    let ev = evaluate(&pred, &EvalOptions::default(), &|_, _, _| {}).unwrap();
    assert_eq!(ev.reconstruction.len(), 3);
    let options = EvalOptions {
        loo: true,
        ..EvalOptions::default()
    };
    let e = evaluate(&pred, &options, &|_, _, _| {}).unwrap_err();
    // The cause is in the message once: not also a `source`, which error chains would repeat.
    assert!(std::error::Error::source(&e).is_none(), "{e}");
    match e {
        Error::LeaveOneOut { index, name, cause } => {
            assert_eq!((index, name.as_str()), (2, picked[2].name.as_str()));
            assert!(matches!(*cause, Error::Model(_)), "{cause}");
            assert!(cause.to_string().contains("identical"), "{cause}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn bad_inputs_give_clear_errors() {
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let e = pred
        .predict(&[f64::NAN, 0.0], PredictorKind::Exact)
        .unwrap_err();
    assert!(matches!(e, Error::InvalidPoint { .. }), "{e}");
    assert!(e.to_string().contains("finite"));
    let e = pred
        .predict(&[0.0, 0.0, 1.0], PredictorKind::Exact)
        .unwrap_err();
    assert!(e.to_string().contains("2 dimensions"), "{e}");
    let m = pred.predict(&[0.0, 0.0], PredictorKind::Exact).unwrap();
    let e = m
        .with_wavelengths(&Channels::parse_wavelengths("380,500").unwrap())
        .unwrap_err();
    assert!(
        matches!(e, Error::Store(brdf_io::Error::WavelengthOutOfRange { .. })),
        "{e}"
    );
    assert!(
        e.to_string().contains("380 nm") && e.to_string().contains("400..=700"),
        "{e}"
    );
    let e = m.with_wavelengths(&Channels::Rgb).unwrap_err();
    assert!(e.to_string().contains("spectral"), "{e}");
    let e = m
        .materialize(&f._dir.path().join("x.binary"), |_, _| {})
        .unwrap_err();
    assert!(e.to_string().contains("RGB"), "{e}");
    assert!(!f._dir.path().join("x.binary").exists());
    let e = m
        .materialize(&f._dir.path().join("x.png"), |_, _| {})
        .unwrap_err();
    assert!(e.to_string().contains(".sbrdf"), "{e}");
    assert!(pred.lerp("nope", "also-nope", 0.5).is_err());

    // The dataset moved.
    let moved = f._dir.path().join("moved.sbrdf");
    std::fs::rename(&f.store, &moved).unwrap();
    let e = Predictor::open(&f.model).unwrap_err();
    assert!(matches!(e, Error::DatasetMissing { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("model.toml") && msg.contains("data.sbrdf"),
        "{msg}"
    );
    assert!(msg.contains("pass the store's new path"), "{msg}");
    // ... and can be passed explicitly; a wrong explicit path is named as given.
    Predictor::open_with_dataset(&f.model, Some(&moved)).unwrap();
    let nope = f._dir.path().join("nope.sbrdf");
    let msg = Predictor::open_with_dataset(&f.model, Some(&nope))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("nope.sbrdf given for it is not a file") && !msg.contains("pass the"),
        "{msg}"
    );

    // Same path, different content: checksum mismatch.
    write_store(&f.store, 6, 5, grid());
    let e = Predictor::open(&f.model).unwrap_err();
    assert!(matches!(e, Error::DatasetMismatch { .. }), "{e}");
    assert!(e.to_string().contains("checksum"), "{e}");

    // A store on another grid is named for that, not for its checksum.
    let other = f._dir.path().join("other.sbrdf");
    write_store(&other, 6, 0, AngularGrid::new(4, 8, 16).unwrap());
    let store = Arc::new(Store::open(&other).unwrap());
    let model = Model::load(&f.model).unwrap();
    let e = Predictor::with_store(model.clone(), &f.model, store.clone()).unwrap_err();
    assert!(
        e.to_string().contains("grid differs") && !e.to_string().contains("checksum"),
        "{e}"
    );

    // A NaN latent point inside a model.
    let store = Arc::new(Store::open(&moved).unwrap());
    let mut model = Model::load(&f.model).unwrap();
    model.materials[2].coords[0] = f64::NAN;
    let e = Predictor::with_store(model, &f.model, store).unwrap_err();
    assert!(matches!(e, Error::InvalidPoint { .. }), "{e}");
}

/// A store on the model's grid that is not the model's is named for what differs, before
/// the checksum and the material names that follow from it: channels of another spacing by the
/// first channel that differs, channels that stop early by the counts, fewer materials by the
/// sizes.
#[test]
fn stores_of_other_channels_or_sizes_are_named_for_what_differs() {
    let f = fixture(6, "log");
    let model = Model::load(&f.model).unwrap();
    let refusal = |path: &Path| {
        let store = Arc::new(Store::open(path).unwrap());
        let e = Predictor::with_store(model.clone(), &f.model, store).unwrap_err();
        assert!(matches!(e, Error::DatasetMismatch { .. }), "{e}");
        e.to_string()
    };
    let path = f._dir.path().join("other.sbrdf");
    let wide = Channels::parse_wavelengths("400:700:100").unwrap();
    for (theirs, want) in [
        (
            wide.clone(),
            format!(
                "channels differ (channel 1: model {}, store {})",
                channels().labels()[1],
                wide.labels()[1]
            ),
        ),
        (
            Channels::parse_wavelengths("400:650:50").unwrap(),
            "channels differ (model 7 channels, store 6)".to_owned(),
        ),
    ] {
        write_store_on(&path, 6, 0, grid(), &theirs, StoreOptions::default());
        let e = refusal(&path);
        assert!(e.contains(&want), "{e}");
    }
    write_store(&path, 5, 0, grid());
    let d = model.dataset.d;
    let e = refusal(&path);
    assert!(
        e.contains(&format!(
            "size differs (model 6 materials x D = {d}, store 5 x {d})"
        )),
        "{e}"
    );
}

/// Labels say how a material was made: `gp-<kind>@<point>` with each coordinate in its
/// shortest form (exponent form when long), `lerp(a,b,t)`, a training material's own name;
/// a materialised `.sbrdf` names its one material by the label.
#[test]
fn predicted_materials_are_labelled_by_how_they_were_made() {
    let f = fixture(4, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let names = material_names(&pred);
    let m = pred.predict(&[0.25, -1e-5], PredictorKind::Smooth).unwrap();
    assert_eq!(m.label(), "gp-smooth@0.25,-1e-5");
    let far = pred.predict(&[0.0, 2e6], PredictorKind::Exact).unwrap();
    assert_eq!(far.label(), "gp-exact@0,2e6");
    let lerp = pred.lerp(&names[0], &names[2], 0.3).unwrap();
    assert_eq!(lerp.label(), format!("lerp({},{},0.3)", names[0], names[2]));
    assert_eq!(pred.training(&names[1]).unwrap().label(), names[1]);
    let out = f._dir.path().join("m.sbrdf");
    m.materialize(&out, |_, _| {}).unwrap();
    assert_eq!(
        Store::open(&out).unwrap().names(),
        vec!["gp-smooth@0.25,-1e-5"]
    );
}

/// A cell index beyond the grid is an error naming it, however large: `a * n_channels`
/// overflowed (a panic in debug builds) and, in release builds, wrapped onto other cells'
/// values: with 7 channels, cell (3 * 2^64 + 1) / 7 read the flat indices 1..8 and returned
/// them as its values.
#[test]
fn cell_lookups_beyond_the_grid_are_errors() {
    let f = fixture(4, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let material = pred.predict(&[0.1, 0.2], PredictorKind::Exact).unwrap();
    let nc = pred.channels().len();
    assert_eq!(nc, 7);
    let wraps_to_index_1 = ((3u128 << 64) + 1) / 7;
    assert_eq!(wraps_to_index_1 as usize as u128, wraps_to_index_1);
    let cells = pred.grid().len();
    let mut out = vec![0.0; nc];
    for a in [cells, wraps_to_index_1 as usize, usize::MAX] {
        match material.eval_cell(a, &mut out) {
            Err(Error::CellOutOfRange { cell, cells: c }) => assert_eq!((cell, c), (a, cells)),
            other => panic!("cell {a}: {other:?} {out:?}"),
        }
        assert!(BrdfSource::eval_cell(&material, a, &mut out).is_err());
        // A prefetch hint for it does nothing (it overflowed too).
        material.prefetch_cell(a);
        BrdfSource::prefetch_cell(&material, a);
        BrdfSource::will_need_cells(&material, &mut [0, a, cells - 1].into_iter());
    }
    // The last cell still reads.
    material.eval_cell(cells - 1, &mut out).unwrap();
    for (c, v) in out.iter().enumerate() {
        assert_eq!(
            v.to_bits(),
            material.value_at((cells - 1) * nc + c).unwrap().to_bits()
        );
    }
}

/// A prediction takes cell hints (`BrdfSource::takes_cell_hints`) when its store is read with
/// positioned reads, which the hints reach, and not when the store is mapped in memory.
#[test]
fn predictions_take_cell_hints_when_their_store_reads_on_demand() {
    use brdf_io::store::{OpenOptions, Paging, ReadMode};
    let f = fixture(4, "raw");
    for (mode, paging) in [
        (ReadMode::Mmap, Paging::ReadAround),
        (ReadMode::Mmap, Paging::OnDemand),
        (ReadMode::Buffered, Paging::Auto),
    ] {
        let options = OpenOptions {
            mode,
            paging,
            ..Default::default()
        };
        let store = Arc::new(Store::open_with(&f.store, options).unwrap());
        let reads_on_demand = store.takes_will_need();
        assert_eq!(
            reads_on_demand,
            cfg!(target_os = "linux") && paging != Paging::ReadAround,
            "{mode:?} {paging:?}"
        );
        let model = Model::load(&f.model).unwrap();
        let pred = Predictor::with_store(model, &f.model, store).unwrap();
        let material = pred.predict(&[0.1, 0.2], PredictorKind::Exact).unwrap();
        assert_eq!(material.takes_cell_hints(), reads_on_demand);
        let boxed: Box<dyn BrdfSource> = Box::new(material);
        assert_eq!(boxed.takes_cell_hints(), reads_on_demand);
    }
}

/// A prediction is its own cell source (`BrdfSource::cell_source`): a consumer that evaluates
/// several predictions' cells together finds it, through a box too.
#[test]
fn a_prediction_is_its_own_cell_source() {
    let f = fixture(4, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let material = pred.predict(&[0.1, 0.2], PredictorKind::Exact).unwrap();
    let found = BrdfSource::cell_source(&material)
        .and_then(|s| s.downcast_ref::<predict::PredictedMaterial>());
    assert!(found.is_some_and(|m| std::ptr::eq(m, &material)));
    let boxed: Box<dyn BrdfSource + '_> = Box::new(&material);
    let found = boxed
        .cell_source()
        .and_then(|s| s.downcast_ref::<predict::PredictedMaterial>());
    assert!(found.is_some_and(|m| std::ptr::eq(m, &material)));
}

#[test]
fn the_transformed_sidecar_store_gives_the_same_predictions() {
    let f = fixture(8, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let side = pred.transformed_store_path();
    assert!(
        side.to_string_lossy()
            .ends_with("data.sbrdf.log-0.01.sbrdf"),
        "{side:?}"
    );
    let mut calls = 0;
    pred.build_transformed_store(&side, |_, _| calls += 1)
        .unwrap();
    assert_eq!(calls, pred.store().n_chunks());
    let fast = pred.with_transformed_store(&side).unwrap();
    assert!(fast.uses_transformed_store() && !pred.uses_transformed_store());
    let x = [0.2, 0.1];
    let (a, b) = (
        pred.predict(&x, PredictorKind::Smooth).unwrap(),
        fast.predict(&x, PredictorKind::Smooth).unwrap(),
    );
    // The sidecar rounds every transformed value t = ln(1 + f/c) to f32 (2^-24 relative), so
    // the prediction t* = sum_i c_i t_i moves by at most B = sum |c_i| max|t| 2^-24 and
    // f* = c (e^t* - 1) by (|f*| + c)(e^B - 1): a relative error that grows like c / |f*| for
    // values near 0 (an audit saw 1e-6..1e-5 relative on ordinary values of other data).
    let coef = pred.coefficients(&x, PredictorKind::Smooth).unwrap();
    let store = pred.store();
    let mut row = vec![0f32; store.d()];
    let mut t_max = 0.0f64;
    for m in 0..store.n_materials() {
        store.material_row(m, 0..store.d(), &mut row).unwrap();
        for v in &row {
            t_max = t_max.max(pred.transform().forward(f64::from(*v)).abs());
        }
    }
    let bound = coef.iter().map(|c| c.abs()).sum::<f64>() * t_max * 2f64.powi(-24);
    let Transform::Log { offset } = pred.transform() else {
        panic!("a log fixture")
    };
    let (mut worst, mut worst_relative) = (0.0f64, 0.0f64);
    for d in 0..pred.store().d() {
        let (u, v) = (a.value_at(d).unwrap(), b.value_at(d).unwrap());
        let allowed = (u.abs() + offset) * bound.exp_m1() * 1.01 + 1e-15;
        worst = worst.max((u - v).abs() / allowed);
        worst_relative = worst_relative.max((u - v).abs() / u.abs().max(1e-3));
    }
    assert!(worst <= 1.0, "{worst} of the f32 bound {bound:e}");
    // And the bound is not vacuous: the differences use a good part of it, and stay small.
    assert!(
        worst > 0.01 && worst_relative < 1e-5,
        "{worst} {worst_relative:e}"
    );
    // Lazy equals materialised with the sidecar too.
    let out = f._dir.path().join("fast.npy");
    b.materialize(&out, |_, _| {}).unwrap();
    let values = brdf_io::npy::read(&out).unwrap().to_f32();
    for (d, v) in values.iter().enumerate() {
        assert_eq!(
            (b.value_at(d).unwrap() as f32).to_bits(),
            v.to_bits(),
            "d = {d}"
        );
    }
    // A forward cache over the sidecar is a no-op: lookups keep reading the sidecar's values
    // (a cache would take the dataset's f64 logarithms instead).
    let kept = fast.with_forward_cache();
    assert!(!kept.keeps_forward_values() && kept.uses_transformed_store());
    let c = kept.predict(&x, PredictorKind::Smooth).unwrap();
    let k = pred.channels().len();
    let (mut vb, mut vc) = (vec![0.0; k], vec![0.0; k]);
    for cell in 0..pred.grid().len() {
        b.eval_cell(cell, &mut vb).unwrap();
        c.eval_cell(cell, &mut vc).unwrap();
        assert_eq!(vb, vc, "cell {cell}");
    }
    // A sidecar of another dataset is refused.
    let e = pred.with_transformed_store(&f.store).unwrap_err();
    assert!(e.to_string().contains("forward-transformed"), "{e}");
}

/// A sidecar is refused by a predictor of the same dataset under another transform (a log
/// offset of 1, raw): it holds the values of the transform it was built with, which lookups
/// would take for their own. Its source names that transform and the dataset's checksum.
#[test]
fn sidecars_of_another_transform_are_refused() {
    let f = fixture(4, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let side = pred.transformed_store_path();
    pred.build_transformed_store(&side, |_, _| {}).unwrap();
    let source = format!(
        "forward-transformed values (log(offset=0.01)) of dataset checksum {}",
        pred.store().header().checksum
    );
    let written = Store::open(&side).unwrap();
    assert!(
        written
            .header()
            .materials
            .iter()
            .all(|m| m.source == source),
        "{source}"
    );
    assert!(
        pred.with_transformed_store(&side)
            .unwrap()
            .uses_transformed_store()
    );
    for spec in ["log:1", "raw"] {
        let transform: Transform = spec.parse().unwrap();
        let mut model = pred.model().clone();
        (model.transform, model.config.transform) = (transform, spec.into());
        let other = Predictor::with_store(model, &f.model, pred.store().clone()).unwrap();
        let e = other.with_transformed_store(&side).unwrap_err();
        assert!(matches!(e, Error::DatasetMismatch { .. }), "{e}");
        assert!(
            e.to_string()
                .contains(&format!("forward-transformed values ({transform})")),
            "{e}"
        );
    }
}

/// Below-horizon indices are 0 in a sidecar and in a materialised file whatever the dataset's
/// payload holds there (here NaN for every material, a damaged payload: `StoreWriter` stores
/// 0), not an error: both mask by the index's angular cell `d / n_channels` before transforming
/// or checking a value. And the sidecar keeps the dataset's chunk length (1000 here, not the
/// writer's default), counting chunks `(1, total)` to `(total, total)` as it writes them.
#[test]
fn sidecars_and_materialised_files_are_zero_below_the_horizon() {
    let options = StoreOptions {
        chunk_len: Some(1000),
        ..StoreOptions::default()
    };
    let f = fixture_with(6, "log", options);
    let store = Store::open(&f.store).unwrap();
    let (n, nc) = (store.n_materials(), store.channels().len());
    assert_eq!(store.header().layout.chunk_len, 1000);
    let mask = store.validity_mask().to_vec();
    // A below-horizon index whose channel, read as a cell, is above the horizon (masking by
    // `d % nc` keeps it).
    let d = (0..store.d())
        .find(|&d| !mask[d / nc] && mask[d % nc])
        .unwrap();
    let patched = f.store.with_file_name("patched.sbrdf");
    let mut bytes = std::fs::read(&f.store).unwrap();
    // Uncompressed f32 payload from byte 4096, index-major: values (d, 0..n).
    for m in 0..n {
        let at = 4096 + (d * n + m) * 4;
        bytes[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    }
    std::fs::write(&patched, bytes).unwrap();
    let mut vals = vec![0f32; n];
    Store::open(&patched)
        .unwrap()
        .values_at(d, &mut vals)
        .unwrap();
    assert!(vals.iter().all(|v| v.is_nan()), "{vals:?}");

    let pred = Predictor::open_with_dataset(&f.model, Some(&patched)).unwrap();
    let side = pred.transformed_store_path();
    let mut calls = Vec::new();
    pred.build_transformed_store(&side, |done, total| calls.push((done, total)))
        .unwrap();
    let written = Store::open(&side).unwrap();
    assert_eq!(written.header().layout.chunk_len, 1000);
    let chunks = store.n_chunks();
    assert!(chunks > 2, "{chunks} chunks");
    let counted: Vec<(usize, usize)> = (1..=chunks).map(|k| (k, chunks)).collect();
    assert_eq!(calls, counted);
    written.values_at(d, &mut vals).unwrap();
    assert_eq!(vals, vec![0.0; n]);
    let fast = pred.with_transformed_store(&side).unwrap();

    let out = f._dir.path().join("pred.npy");
    for p in [&pred, &fast] {
        let m = p.predict(&[0.2, -0.3], PredictorKind::Smooth).unwrap();
        m.materialize(&out, |_, _| {}).unwrap();
        let values = brdf_io::npy::read(&out).unwrap().to_f32();
        assert_eq!(values[d], 0.0);
    }
}

/// The sidecar of a model with a tiny or huge log offset has a file name the file system
/// takes: `log-{offset}` wrote 1e-300 with 300 digits (a 330-byte name, refused with "File
/// name too long" by `predict --sidecar`). Distinct offsets keep distinct names.
#[test]
fn sidecars_of_extreme_log_offsets_have_short_names() {
    let f = fixture(4, "log:1e-300");
    let pred = Predictor::open(&f.model).unwrap();
    assert_eq!(pred.transform(), Transform::Log { offset: 1e-300 });
    let side = pred.transformed_store_path();
    assert_eq!(
        side.file_name().unwrap().to_string_lossy(),
        "data.sbrdf.log-1e-300.sbrdf"
    );
    pred.build_transformed_store(&side, |_, _| {}).unwrap();
    let fast = pred.with_transformed_store(&side).unwrap();
    // The sidecar's lookups are the dataset's: the exact predictor returns a training
    // material, through its transformed values t = ln(1 + f / 1e-300) ~ 690 rounded to f32
    // (half an ulp: |t| 2^-24), so f moves by (f + c)(e^(|t| 2^-24) - 1), ~4e-5 relative.
    let x = &pred.model().materials[2].coords;
    let (a, b) = (
        pred.predict(x, PredictorKind::Exact).unwrap(),
        fast.predict(x, PredictorKind::Exact).unwrap(),
    );
    let mut nonzero = 0;
    for d in 0..pred.store().d() {
        let (u, v) = (a.value_at(d).unwrap(), b.value_at(d).unwrap());
        let t = pred.transform().forward(u);
        let allowed = (u.abs() + 1e-300) * (t.abs() * 2f64.powi(-24)).exp_m1() * 1.01;
        assert!((u - v).abs() <= allowed, "d = {d}: {u} {v}");
        nonzero += usize::from(u != 0.0);
    }
    assert!(nonzero > pred.store().d() / 2);
    let name = |offset: f64| {
        predict::transformed_store_path(Path::new("d.sbrdf"), Transform::Log { offset })
            .to_string_lossy()
            .into_owned()
    };
    assert_eq!(name(0.01), "d.sbrdf.log-0.01.sbrdf");
    assert_eq!(name(1e300), "d.sbrdf.log-1e300.sbrdf");
    assert_ne!(name(1e-5), name(1.0000000000000002e-5));
}

/// A NaN in the stored values (a damaged payload: lookups do not re-hash it) is an error
/// naming the store or the prediction, in lookups of stored and predicted materials, in
/// materialised `.npy` files and in BRDF-space errors; never a NaN passed on silently.
#[test]
fn damaged_stored_values_are_errors_not_nans() {
    let f = fixture(6, "log");
    let store = Store::open(&f.store).unwrap();
    let (n, nc) = (store.n_materials(), store.channels().len());
    let mask = store.validity_mask().to_vec();
    let d = (0..store.d()).find(|d| mask[d / nc]).unwrap() + 3 * nc;
    assert!(mask[d / nc]);
    let damaged = f.store.with_file_name("damaged.sbrdf");
    let mut bytes = std::fs::read(&f.store).unwrap();
    // Uncompressed f32 payload from byte 4096, index-major: value (d, material 2).
    let at = 4096 + (d * n + 2) * 4;
    bytes[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&damaged, bytes).unwrap();
    let store = Arc::new(Store::open(&damaged).unwrap());
    let name = store.names()[2].to_owned();
    let stored = brdf_io::store::StoreMaterial::new(store.clone(), &name).unwrap();
    let mut out = vec![0.0; nc];
    let e = stored.eval_cell(d / nc, &mut out).unwrap_err().to_string();
    assert!(
        e.contains("damaged.sbrdf") && e.contains(&format!("{name:?}")) && e.contains("NaN"),
        "{e}"
    );
    stored.eval_cell(d / nc + 1, &mut out).unwrap();
    assert!(out.iter().all(|v| v.is_finite()));

    let pred = Predictor::open_with_dataset(&f.model, Some(&damaged)).unwrap();
    let m = pred.predict(&[0.1, -0.2], PredictorKind::Exact).unwrap();
    // The prediction meets the NaN: the error names the stored value, not the prediction.
    let e = m.eval_cell(d / nc, &mut out).unwrap_err().to_string();
    assert!(
        e.contains("damaged.sbrdf")
            && e.contains(&format!("{name:?}"))
            && e.contains(&format!("index {d}")),
        "{e}"
    );
    assert!(m.value_at(d).is_err());
    let npy = f.store.with_file_name("p.npy");
    let e = m.materialize(&npy, |_, _| {}).unwrap_err().to_string();
    assert!(
        e.contains("damaged.sbrdf") && e.contains("non-finite value NaN"),
        "{e}"
    );
    assert!(!npy.exists());
    let model = pred.model().clone();
    // Material 0's reconstruction from itself meets the NaN too (0 x NaN in the product over
    // all materials): either way the error names the stored value.
    for target in [0, 2] {
        let coef = Mat::<f64>::from_fn(1, n, |_, j| if j == target { 1.0 } else { 0.0 });
        let e = predict::evaluate::brdf_space_rmse(
            &store,
            model.transform,
            &[target],
            coef.as_ref(),
            &|_, _| {},
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("damaged.sbrdf")
                && e.contains(&format!("{name:?}"))
                && e.contains(&format!("index {d}")),
            "{e}"
        );
    }
}

/// A prediction that overflows on sound data (a log-space blend far beyond its two
/// materials) is an error that says so and clears the store, which it scanned; a cell lookup
/// names the flat index of the first overflowing value, as the single-value lookups do.
#[test]
fn overflowing_predictions_are_errors_that_clear_the_store() {
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let names: Vec<String> = pred.store().names().iter().map(|s| s.to_string()).collect();
    let nc = pred.channels().len();
    let m = pred.lerp(&names[0], &names[1], 1e6).unwrap();
    let mut out = vec![0.0; nc];
    let cells = pred.store().d() / nc;
    let failed: Vec<(usize, String)> = (0..cells)
        .filter_map(|a| m.eval_cell(a, &mut out).err().map(|e| (a, e.to_string())))
        .take(3)
        .collect();
    assert_eq!(failed.len(), 3, "a blend at 1e6 overflows in several cells");
    for (a, e) in failed {
        assert!(
            e.contains("prediction overflowed")
                && e.contains(&f.store.display().to_string())
                && e.contains("is inf"),
            "{e}"
        );
        let k = (0..nc).find(|&c| m.value_at(a * nc + c).is_err()).unwrap();
        assert!(
            e.contains(&format!("value {} of the prediction", a * nc + k)),
            "cell {a}, channel {k}: {e}"
        );
    }
}

/// The D values of material `name` of the store at `path`.
fn material_values(path: &Path, name: &str) -> Vec<f32> {
    let store = Store::open(path).unwrap();
    let m = store.material_index(name).unwrap();
    let mut v = vec![0f32; store.d()];
    store.material_row(m, 0..store.d(), &mut v).unwrap();
    v
}

/// Writes to `path` a store of one preset material between two of a 6-material fixture's picks
/// (not in its training set) and returns its name.
fn write_unseen_material(path: &Path) -> String {
    let presets = brdf_synth::preset(0);
    let step = presets.len() / 6;
    brdf_synth::write_store(
        path,
        std::slice::from_ref(&presets[step / 2]),
        grid(),
        &channels(),
        StoreOptions::default(),
        7,
        |_| {},
    )
    .unwrap();
    Store::open(path).unwrap().names()[0].to_owned()
}

#[test]
fn locating_a_new_material_agrees_with_direct_measurements() {
    use predict::locate::{Target, cross_products, gram_sq_error, locate};
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let new_store = f.store.with_file_name("new.sbrdf");
    let new_name = write_unseen_material(&new_store);
    assert!(
        pred.material_index(&new_name).is_err(),
        "{new_name} is a training material"
    );
    let training_name = pred.model().materials[3].name.clone();
    let targets = vec![
        Target {
            name: new_name.clone(),
            source: new_store.display().to_string(),
            values: material_values(&new_store, &new_name),
        },
        Target {
            name: training_name.clone(),
            source: f.store.display().to_string(),
            values: material_values(&f.store, &training_name),
        },
    ];
    let located = locate(&pred, &targets, 3, &|_, _| {}).unwrap();
    assert_eq!(located.len(), 2);

    // Cross products against a scalar recomputation from the stored values.
    let store = pred.store();
    let (n, nc) = (store.n_materials(), store.channels().len());
    let mask = store.validity_mask().to_vec();
    let t = pred.transform();
    let (cross, norms) = cross_products(&pred, &targets, &|_, _| {}).unwrap();
    let mut row = vec![0f32; n];
    let (mut want, mut want_norm) = (vec![0.0; n], 0.0);
    for d in (0..store.d()).filter(|d| mask[d / nc]) {
        store.values_at(d, &mut row).unwrap();
        let y = t.forward(f64::from(targets[0].values[d]));
        want_norm += y * y;
        for i in 0..n {
            want[i] += y * t.forward(f64::from(row[i]));
        }
    }
    assert!(rel(norms[0], want_norm) < 1e-12, "{} {want_norm}", norms[0]);
    for i in 0..n {
        assert!(
            rel(cross[i], want[i]) < 1e-12,
            "{i}: {} {}",
            cross[i],
            want[i]
        );
    }
    // The training material's cross products are its row of the model's Gram matrix.
    let g = pred.model().gram_matrix();
    for i in 0..n {
        assert!(
            rel(cross[n + i], g[(3, i)]) < 1e-12,
            "{i}: {} {}",
            cross[n + i],
            g[(3, i)]
        );
    }

    let n_angles = pred.grid().len() as f64;
    let loc = &located[0];
    // The prediction at the located point, looked up value by value, against the target.
    let m = pred.predict(&loc.point, PredictorKind::Exact).unwrap();
    let (mut brdf_sq, mut model_sq) = (0.0, 0.0);
    for d in (0..store.d()).filter(|d| mask[d / nc]) {
        let (f_new, f_pred) = (f64::from(targets[0].values[d]), m.value_at(d).unwrap());
        brdf_sq += (f_new - f_pred).powi(2);
        model_sq += (t.forward(f_new) - t.forward(f_pred)).powi(2);
    }
    assert!(
        rel(loc.brdf_rmse, (brdf_sq / n_angles).sqrt()) < 1e-9,
        "{loc:?}"
    );
    assert!(
        rel(loc.model_rmse, (model_sq / n_angles).sqrt()) < 1e-9,
        "{loc:?}"
    );
    // The Gram formula the search minimises gives the same error as the direct pass.
    let gram_rmse =
        (gram_sq_error(&pred, &cross[..n], norms[0], &loc.coefficients) / n_angles).sqrt();
    assert!(
        rel(loc.model_rmse, gram_rmse) < 1e-6,
        "{} {gram_rmse}",
        loc.model_rmse
    );
    // No training point's smooth prediction does better, and the search beats the nearest
    // material or comes close to it.
    for mat in &pred.model().materials {
        let c = pred
            .coefficients(&mat.coords, PredictorKind::Smooth)
            .unwrap();
        let e = (gram_sq_error(&pred, &cross[..n], norms[0], &c) / n_angles).sqrt();
        assert!(
            loc.model_rmse <= e * (1.0 + 1e-9),
            "{} at {}: {e}",
            loc.model_rmse,
            mat.name
        );
    }
    let nearest = pred.material_index(&loc.nearest).unwrap();
    let c = (0..n)
        .map(|j| if j == nearest { 1.0 } else { 0.0 })
        .collect::<Vec<_>>();
    let e = (gram_sq_error(&pred, &cross[..n], norms[0], &c) / n_angles).sqrt();
    assert!(
        rel(loc.nearest_model_rmse, e) < 1e-6,
        "{} {e}",
        loc.nearest_model_rmse
    );
    assert!(
        loc.model_rmse <= loc.nearest_model_rmse * (1.0 + 1e-9),
        "{loc:?}"
    );
    assert!(
        loc.variance_fraction > 0.0 && loc.variance_fraction < 1.0,
        "{loc:?}"
    );

    // A training material is found at its own point, where the exact predictor returns it.
    let own = &located[1];
    assert_eq!(own.nearest, training_name);
    assert!(
        own.nearest_brdf_rmse < 1e-12 && own.nearest_model_rmse == 0.0,
        "{own:?}"
    );
    assert_eq!(own.point, pred.model().materials[3].coords, "{own:?}");
    assert!(own.brdf_rmse < 1e-9 && own.model_rmse < 1e-9, "{own:?}");
    assert_eq!(
        (own.nearest_in_latent.as_str(), own.distance),
        (training_name.as_str(), 0.0)
    );
}

#[test]
fn locate_refuses_targets_it_cannot_compare() {
    use predict::locate::{Target, locate};
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let d = pred.store().d();
    let e = locate(&pred, &[], 3, &|_, _| {}).unwrap_err().to_string();
    assert!(e.contains("no target"), "{e}");
    let short = Target {
        name: "short".into(),
        source: "a.sbrdf".into(),
        values: vec![0.1; d - 1],
    };
    let e = locate(&pred, &[short], 3, &|_, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("\"short\" from a.sbrdf") && e.contains(&format!("D = {d}")),
        "{e}"
    );
    let mut values = vec![0.1f32; d];
    values[17] = f32::INFINITY;
    let bad = Target {
        name: "bad".into(),
        source: "b.bsdf".into(),
        values,
    };
    let e = locate(&pred, &[bad], 3, &|_, _| {})
        .unwrap_err()
        .to_string();
    let nc = pred.channels().len();
    let want = format!(
        "value 17 (angular cell {}, channel {}) of target \"bad\" from b.bsdf is inf",
        17 / nc,
        17 % nc
    );
    assert!(e.contains(&want), "{e}");

    // A file whose values resample to NaN or beyond f32 (stored as 0 by the resampler) is
    // refused as `import` refuses it, not located as a black material: a 2 x 2 x 2 MERL
    // file of 1e300 (an audit's `locate` placed it at -3 with exit 0).
    let dir = tempfile::tempdir().unwrap();
    let merl = dir.path().join("huge.binary");
    let mut bytes: Vec<u8> = [2i32, 2, 2].iter().flat_map(|v| v.to_le_bytes()).collect();
    bytes.extend((0..24).flat_map(|_| 1e300f64.to_le_bytes()));
    std::fs::write(&merl, bytes).unwrap();
    let Err(e) = Target::from_file(&merl, &grid(), &Channels::Rgb) else {
        panic!("a file of 1e300 values is accepted");
    };
    let e = e.to_string();
    assert!(
        e.contains("huge.binary") && e.contains("NaN or infinite"),
        "{e}"
    );
}

/// `Target::from_store` reads the materials asked for, in the order asked (a repeat included),
/// from a store of several chunks (a chunk holds value `d` of material `m` at
/// `(d - start) N + m`): each target is named as the material, has the store's path as its
/// source and every stored value. An index past the store's materials is an error naming it,
/// the store and how many it holds.
#[test]
fn targets_from_a_store_hold_its_materials_values() {
    use predict::locate::Target;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("chunked.sbrdf");
    let options = StoreOptions {
        chunk_len: Some(1000),
        ..StoreOptions::default()
    };
    write_store_with(&path, 5, 0, grid(), options);
    let store = Store::open(&path).unwrap();
    assert!(store.n_chunks() > 2, "{} chunks", store.n_chunks());
    let names = store.names();
    let targets = Target::from_store(&store, &[3, 0, 3]).unwrap();
    assert_eq!(targets.len(), 3);
    for (t, m) in targets.iter().zip([3, 0, 3]) {
        assert_eq!(t.name, names[m]);
        assert_eq!(t.source, path.display().to_string());
        assert_eq!(t.values, material_values(&path, names[m]), "{}", t.name);
    }
    assert_ne!(targets[0].values, targets[1].values);
    let e = Target::from_store(&store, &[1, 5]).unwrap_err().to_string();
    assert!(
        e.contains("material 5 of") && e.contains("chunked.sbrdf") && e.contains("(it holds 5)"),
        "{e}"
    );
}

/// `Target::from_file` resamples an RGL `.bsdf` file onto the model's grid and channels as the
/// file's own resampling does (values and report), named by the file's stem; a file whose
/// channels cannot give the model's (a spectral file for RGB data, a MERL file, which is RGB,
/// for spectral data) or of another kind is an error saying what the file and the model's data
/// are ([`predict::locate::describe_channels`]).
#[test]
fn target_files_are_resampled_or_refused_by_their_channels() {
    use brdf_io::rgl::{RglBsdf, RglWriteOptions, write_rgl};
    use predict::locate::{Target, describe_channels};
    assert_eq!(describe_channels(&Channels::Rgb), "RGB (R,G,B)");
    assert_eq!(
        describe_channels(&channels()),
        "spectral (7 wavelengths 400-700 nm)"
    );
    let dir = tempfile::tempdir().unwrap();
    let Channels::Spectral(wavelengths) = channels() else {
        unreachable!("the tests' channels are spectral")
    };
    let source = brdf_synth::preset(0)[0].prepare(&wavelengths);
    let bsdf = dir.path().join("paint.bsdf");
    let options = RglWriteOptions {
        theta_samples: 4,
        resolution: 8,
        warp_resolution: 16,
        tolerance: None,
        ..RglWriteOptions::default()
    };
    write_rgl(&source, &bsdf, &options).unwrap();
    let (target, report) = Target::from_file(&bsdf, &grid(), &channels()).unwrap();
    let (want, want_report) = RglBsdf::open(&bsdf)
        .unwrap()
        .resample(&grid(), &channels())
        .unwrap();
    assert_eq!(target.name, "paint");
    assert_eq!(target.source, bsdf.display().to_string());
    assert_eq!(target.values, want);
    assert!(target.values.iter().any(|&v| v > 0.0));
    assert_eq!(report, want_report);

    let e = Target::from_file(&bsdf, &grid(), &Channels::Rgb)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("paint.bsdf is a spectral file, but the model's data are RGB (R,G,B)"),
        "{e}"
    );
    // A valid 2 x 2 x 2 MERL file (RGB) for spectral data.
    let merl = dir.path().join("grey.binary");
    let mut bytes: Vec<u8> = [2i32, 2, 2].iter().flat_map(|v| v.to_le_bytes()).collect();
    bytes.extend((0..24).flat_map(|_| 0.1f64.to_le_bytes()));
    std::fs::write(&merl, bytes).unwrap();
    assert!(Target::from_file(&merl, &grid(), &Channels::Rgb).is_ok());
    let e = Target::from_file(&merl, &grid(), &channels())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(
            "grey.binary is a MERL file (R,G,B), but the model's data are spectral (7 \
             wavelengths 400-700 nm)"
        ),
        "{e}"
    );
    let e = Target::from_file(&dir.path().join("paint.csv"), &grid(), &channels())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("paint.csv: expected an RGL .bsdf or a MERL .binary file"),
        "{e}"
    );
}

/// `locate`'s progress counts the chunks of both passes over a store of several chunks: every
/// call has the total 2 x chunks, the first pass (the cross products) reports 1..=chunks and
/// the second (the errors) chunks + 1..=2 x chunks. A target located alone (one pair of rows in
/// the error pass) gets the errors measured directly: its prediction's and, from the pair's
/// second row, the nearest material's BRDF-space RMSE.
#[test]
fn locate_counts_both_passes_and_measures_the_nearest_material() {
    use predict::locate::{Target, locate};
    let f = fixture_with(
        6,
        "log",
        StoreOptions {
            chunk_len: Some(1000),
            ..StoreOptions::default()
        },
    );
    let store_path = &f.store;
    let pred = Predictor::open(&f.model).unwrap();
    let chunks = pred.store().n_chunks();
    assert!(chunks > 2, "{chunks} chunks");
    let new_store = f.store.with_file_name("new.sbrdf");
    let new_name = write_unseen_material(&new_store);
    let target = Target {
        values: material_values(&new_store, &new_name),
        name: new_name,
        source: new_store.display().to_string(),
    };
    let calls = std::sync::Mutex::new(Vec::new());
    let located = locate(&pred, std::slice::from_ref(&target), 3, &|k, total| {
        calls.lock().unwrap().push((k, total))
    })
    .unwrap();
    let mut calls = calls.into_inner().unwrap();
    assert!(
        calls.iter().all(|&(_, total)| total == 2 * chunks),
        "{calls:?}"
    );
    calls.sort_unstable();
    let done: Vec<usize> = calls.iter().map(|&(k, _)| k).collect();
    assert_eq!(done, (1..=2 * chunks).collect::<Vec<_>>());

    assert_eq!(located.len(), 1);
    let loc = &located[0];
    let store = pred.store();
    let (nc, mask) = (store.channels().len(), store.validity_mask().to_vec());
    let nearest = material_values(store_path, &loc.nearest);
    let prediction = pred.predict(&loc.point, PredictorKind::Exact).unwrap();
    let (mut nearest_sq, mut predicted_sq) = (0.0, 0.0);
    for d in (0..store.d()).filter(|d| mask[d / nc]) {
        let f = f64::from(target.values[d]);
        nearest_sq += (f - f64::from(nearest[d])).powi(2);
        predicted_sq += (f - prediction.value_at(d).unwrap()).powi(2);
    }
    let n_angles = pred.grid().len() as f64;
    let (nearest_rmse, predicted_rmse) = (
        (nearest_sq / n_angles).sqrt(),
        (predicted_sq / n_angles).sqrt(),
    );
    assert!(rel(loc.nearest_brdf_rmse, nearest_rmse) < 1e-9, "{loc:?}");
    assert!(rel(loc.brdf_rmse, predicted_rmse) < 1e-9, "{loc:?}");
    // The two rows' errors differ here, so the check above tells them apart.
    assert!(rel(nearest_rmse, predicted_rmse) > 1e-3, "{loc:?}");
}

/// Latent coordinates are bounded as model files bound them (`gplvm::model::MAX_COORDINATE`,
/// 1e100): a coordinate of exactly +-1e100 is a point (no material within reach: all weights
/// 0, the prediction is the data mean, the variance the prior's), anything beyond is an error
/// naming the bound.
#[test]
fn latent_coordinates_are_bounded_as_in_model_files() {
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let bound = gplvm::model::MAX_COORDINATE;
    assert_eq!(bound, 1e100);
    for x in [[bound, 0.0], [0.0, -bound]] {
        let w = pred.gp_weights(&x, PredictorKind::Exact).unwrap();
        assert!(w.iter().all(|v| *v == 0.0), "{w:?}");
        let c = pred.coefficients(&x, PredictorKind::Smooth).unwrap();
        assert!(c.iter().all(|v| *v == 1.0 / 6.0), "{c:?}");
        assert!(rel(pred.variance(&x).unwrap(), pred.prior_variance()) < 1e-12);
    }
    for x in [[1.5e100, 0.0], [0.0, -f64::MAX]] {
        let e = pred.predict(&x, PredictorKind::Exact).unwrap_err();
        assert!(matches!(e, Error::InvalidPoint { .. }), "{e}");
        assert!(e.to_string().contains("beyond +-1e100"), "{e}");
        assert!(pred.variance(&x).is_err() && pred.support(&x).is_err());
    }
}

/// The support of a point measures distances in length-scales, axis by axis: with ARD
/// length-scales (0.5, 4) set on the model, the nearest material and its distance are those of
/// `sqrt(sum_j ((x_j - a_j) / l_j)^2)`, and the variance fraction is the variance over the
/// prior. (The fitted model's isotropic length-scale can be 1, where dividing by it and
/// multiplying by it agree.)
#[test]
fn support_distances_are_in_per_axis_length_scales() {
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let mut model = pred.model().clone();
    let ls = [0.5, 4.0];
    model.hyperparameters.length_scale = ls.to_vec();
    let ard = Predictor::with_store(model.clone(), &f.model, pred.store().clone()).unwrap();
    let scaled = |i: usize, x: &[f64]| -> f64 {
        model.materials[i]
            .coords
            .iter()
            .zip(x)
            .zip(ls)
            .map(|((a, b), l)| ((a - b) / l).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let a0 = &model.materials[0].coords;
    for x in [
        vec![0.3, -0.2],
        vec![-0.1, 0.4],
        vec![a0[0] + 0.5 * 0.3, a0[1] + 4.0 * 0.4],
    ] {
        let s = ard.support(&x).unwrap();
        let nearest = (0..model.materials.len())
            .min_by(|&a, &b| scaled(a, &x).total_cmp(&scaled(b, &x)))
            .unwrap();
        assert_eq!(s.nearest, model.materials[nearest].name, "{x:?}");
        assert!(
            rel(s.distance, scaled(nearest, &x)) < 1e-12,
            "{x:?}: {} vs {}",
            s.distance,
            scaled(nearest, &x)
        );
        assert!(s.distance <= scaled(0, &x) * (1.0 + 1e-12));
        assert_eq!(
            s.variance_fraction,
            ard.variance(&x).unwrap() / ard.prior_variance()
        );
    }
}

/// A point is far from every material only strictly above [`PointSupport::FAR`]: a variance
/// fraction of exactly 0.9 is not far, the next float above it is.
#[test]
fn far_points_have_a_variance_fraction_strictly_above_the_threshold() {
    use predict::PointSupport;
    let at = |variance_fraction: f64| PointSupport {
        nearest: "a".into(),
        distance: 1.0,
        variance_fraction,
    };
    assert_eq!(PointSupport::FAR, 0.9);
    assert!(!at(PointSupport::FAR).is_far());
    assert!(at(PointSupport::FAR.next_up()).is_far());
    assert!(!at(0.5).is_far() && at(1.0).is_far());
    assert!(!PointSupport::is_far_fraction(PointSupport::FAR));
    assert!(PointSupport::is_far_fraction(PointSupport::FAR.next_up()));
}

/// Lookups by direction pair (`eval_dirs`, the `BrdfSource::eval` of a prediction): above the
/// horizon, the stencil's weighted sum of cell values at the pair's half/difference angles
/// (also with more than 8 output channels, which take a heap buffer instead of the stack
/// one); 0 in every channel when either direction is below or exactly at the horizon, where
/// a wrong output length is still an error.
#[test]
fn direction_lookups_interpolate_cells_above_the_horizon_and_are_zero_elsewhere() {
    let f = fixture(6, "log");
    let pred = Predictor::open(&f.model).unwrap();
    let m = pred.predict(&[0.2, -0.1], PredictorKind::Exact).unwrap();
    let wide = m
        .with_wavelengths(&Channels::parse_wavelengths("400:700:25").unwrap())
        .unwrap();
    assert_eq!((m.channels().len(), wide.channels().len()), (7, 13));
    let above = [
        ([0.0, 0.6, 0.8], [0.3, -0.4, 0.75f64.sqrt()]),
        ([0.5, 0.1, 0.3], [-0.2, 0.05, 0.9]),
        ([0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
    ];
    for mat in [&m, &wide] {
        let k = mat.channels().len();
        let (mut out, mut cell, mut src) = (vec![0.0; k], vec![0.0; k], vec![0.0; k]);
        for (wi, wo) in above {
            mat.eval_dirs(wi, wo, &mut out).unwrap();
            let hd = brdf_io::HalfDiff::from_dirs(wi, wo).unwrap();
            let mut want = vec![0.0; k];
            let mut size = 0.0f64;
            for (a, w) in pred.grid().interpolation_stencil(&hd) {
                mat.eval_cell(a, &mut cell).unwrap();
                for c in 0..k {
                    want[c] += w * cell[c];
                    size = size.max((w * cell[c]).abs());
                }
            }
            assert!(size > 0.0);
            for c in 0..k {
                assert!(
                    (out[c] - want[c]).abs() <= 1e-13 * size,
                    "{k} channels, {wi:?} {wo:?}, channel {c}: {} vs {}",
                    out[c],
                    want[c]
                );
            }
            BrdfSource::eval(mat, wi, wo, &mut src).unwrap();
            assert_eq!(src, out);
        }
        let below = [
            ([0.0, 0.6, -0.8], [0.3, -0.4, 0.75f64.sqrt()]),
            ([0.3, -0.4, 0.75f64.sqrt()], [0.0, 0.6, -0.8]),
            ([1.0, 0.0, 0.0], [0.0, 0.6, 0.8]),
            ([0.0, 0.6, 0.8], [0.0, -1.0, 0.0]),
            ([0.0, 0.0, -1.0], [0.0, 0.0, -1.0]),
        ];
        for (wi, wo) in below {
            out.fill(1.0);
            mat.eval_dirs(wi, wo, &mut out).unwrap();
            assert!(out.iter().all(|v| *v == 0.0), "{wi:?} {wo:?}: {out:?}");
            let e = mat.eval_dirs(wi, wo, &mut [0.0; 2]).unwrap_err();
            assert!(e.to_string().contains("output has 2 slots"), "{e}");
        }
    }
}
