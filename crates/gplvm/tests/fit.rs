//! End-to-end tests of the GPLVM fit on synthetic stores.

use std::path::{Path, PathBuf};

use brdf_io::store::{Store, StoreOptions};
use brdf_io::{AngularGrid, Channels};
use brdf_synth::{preset, write_store};
use faer::{Mat, Par};
use gp_core::KernelParams;
use gplvm::{FitParams, Model, OptimizerKind, fit_store};
use test_warnings::warnings_of;

fn grid() -> AngularGrid {
    AngularGrid::new(8, 8, 16).unwrap()
}

/// Writes the preset materials selected by `pick` (indices into the 51) to a store in `dir`.
fn synth_store(dir: &Path, name: &str, pick: &[usize]) -> PathBuf {
    let all = preset(0);
    // Repeated picks are duplicates under new names (store names must be unique).
    let materials: Vec<_> = pick
        .iter()
        .enumerate()
        .map(|(k, &i)| {
            let mut m = all[i].clone();
            if pick[..k].contains(&i) {
                m.name = format!("{}_copy{k}", m.name);
            }
            m
        })
        .collect();
    let path = dir.join(name);
    let channels = Channels::parse_wavelengths("400:700:50").unwrap();
    write_store(
        &path,
        &materials,
        grid(),
        &channels,
        StoreOptions::default(),
        0,
        |_| {},
    )
    .unwrap();
    path
}

fn all_materials() -> Vec<usize> {
    (0..preset(0).len()).collect()
}

fn params(optimizer: OptimizerKind, transform: &str) -> FitParams {
    FitParams {
        optimizer,
        transform: transform.into(),
        // Keep Hooke-Jeeves affordable in a debug-profile test.
        max_evaluations: 25_000,
        min_step: 1e-4,
        ..FitParams::default()
    }
}

#[test]
fn optimisers_improve_on_pca_and_lbfgs_beats_hooke_jeeves_per_evaluation() {
    let dir = tempfile::tempdir().unwrap();
    let data = synth_store(dir.path(), "all.sbrdf", &all_materials());
    for transform in ["raw", "log"] {
        let hj = fit_store(
            &data,
            &params(OptimizerKind::HookeJeeves, transform)
                .check()
                .unwrap(),
        )
        .unwrap();
        let lb = fit_store(
            &data,
            &params(OptimizerKind::Lbfgs, transform).check().unwrap(),
        )
        .unwrap();
        for m in [&hj, &lb] {
            assert!(
                m.fit.log_likelihood > m.fit.initial_log_likelihood,
                "{transform}: {} did not improve on PCA: {} <= {}",
                m.fit.optimizer,
                m.fit.log_likelihood,
                m.fit.initial_log_likelihood
            );
        }
        let (l_hj, l_lb) = (hj.fit.log_likelihood, lb.fit.log_likelihood);
        eprintln!(
            "{transform}: HJ {l_hj:.6e} in {} evaluations, L-BFGS {l_lb:.6e} in {}",
            hj.fit.evaluations, lb.fit.evaluations
        );
        // L-BFGS at least as high (up to 1e-6 relative) in at most a tenth of the evaluations.
        assert!(
            l_lb >= l_hj - 1e-6 * l_hj.abs(),
            "{transform}: L-BFGS {l_lb} < HJ {l_hj}"
        );
        assert!(lb.fit.evaluations * 10 <= hj.fit.evaluations, "{transform}");
    }
}

/// Fits that learn the hyperparameters on a one-dimensional latent space used to stop after a
/// step that barely changed the value (or a failed line search) with a gradient of ~0.5 per
/// data value, reported as converged (an audit reached 1.4e5 more log-likelihood from there
/// with scipy). L-BFGS now drops its Hessian model at such a stall and goes on (unit tests in
/// `optim.rs`). This test held the log-likelihoods those stalled runs stopped at (-4.486554e5
/// log, 1.040703e6 raw), which belong to the presets of that time: session 40's sheen fix
/// changed the felt and satin presets, and on these presets neither fit meets a stall (the same
/// results with the stall handling switched off, as on the presets before the fix). What it
/// checks is the outcome on any data: a converged fit, with a gradient far below the stalled
/// runs' per value, well above its start.
#[test]
fn learnt_hyperparameter_fits_do_not_stop_at_a_stall() {
    let dir = tempfile::tempdir().unwrap();
    let data = synth_store(dir.path(), "all.sbrdf", &all_materials());
    for transform in ["log", "raw"] {
        let p = FitParams {
            latent_dim: 1,
            learn_hyperparameters: true,
            ..params(OptimizerKind::Lbfgs, transform)
        };
        let m = fit_store(&data, &p.check().unwrap()).unwrap();
        let per_value =
            m.fit.gradient_norm / (m.dataset.n_materials * m.dataset.d_effective) as f64;
        assert!(
            per_value < 1e-2 && !m.fit.stop_reason.contains("not converged"),
            "{transform}: |grad| {} ({per_value:e} per value): {}",
            m.fit.gradient_norm,
            m.fit.stop_reason
        );
        let start = m.fit.initial_log_likelihood;
        assert!(
            m.fit.log_likelihood > start + 0.1 * start.abs(),
            "{transform}: {} from {start}",
            m.fit.log_likelihood
        );
    }
}

/// The Gram pass is bit-identical whatever the number of threads (a store of many small chunks,
/// so the parallel fold really splits the work).
#[test]
fn gram_pass_is_deterministic_across_thread_counts() {
    let dir = tempfile::tempdir().unwrap();
    let all = preset(0);
    let path = dir.path().join("chunky.sbrdf");
    let channels = Channels::parse_wavelengths("400:700:50").unwrap();
    let options = StoreOptions {
        chunk_len: Some(97),
        ..StoreOptions::default()
    };
    write_store(&path, &all[..20], grid(), &channels, options, 0, |_| {}).unwrap();
    let store = Store::open(&path).unwrap();
    assert!(store.n_chunks() > 40, "{} chunks", store.n_chunks());
    let transform = "log".parse().unwrap();
    {
        let grams: Vec<Vec<u64>> = [1, 2, 3, 5]
            .iter()
            .map(|&threads| {
                let pass = in_pool(threads, || gplvm::gram_pass(&store, transform)).unwrap();
                (0..20)
                    .flat_map(|i| (0..20).map(move |j| (i, j)))
                    .map(|(i, j)| pass.gram[(i, j)].to_bits())
                    .collect()
            })
            .collect();
        for g in &grams[1..] {
            assert_eq!(g, &grams[0]);
        }
    }
}

#[test]
fn fits_are_reproducible_for_a_seed() {
    let dir = tempfile::tempdir().unwrap();
    let data = synth_store(
        dir.path(),
        "some.sbrdf",
        &[0, 5, 9, 14, 20, 27, 33, 40, 45, 50],
    );
    let p = FitParams {
        restarts: 2,
        seed: 7,
        ..FitParams::default()
    }
    .check()
    .unwrap();
    let a = fit_store(&data, &p).unwrap();
    let b = fit_store(&data, &p).unwrap();
    assert_eq!(a.materials, b.materials);
    assert_eq!(a.fit.log_likelihood, b.fit.log_likelihood);
    // Restart k reuses the runs of restarts < k (same seed), so keeping the best run makes the
    // likelihood non-decreasing in the number of restarts; here the perturbed starts find
    // other optima, so the comparison has teeth.
    let with = |restarts: usize| {
        let p = FitParams {
            restarts,
            seed: 7,
            ..FitParams::default()
        };
        fit_store(&data, &p.check().unwrap())
            .unwrap()
            .fit
            .log_likelihood
    };
    let lls = [with(0), with(1), a.fit.log_likelihood];
    assert!(lls[0] <= lls[1] && lls[1] <= lls[2], "{lls:?}");
    assert!(
        lls[0] != lls[2],
        "all restarts reached the same optimum: {lls:?}"
    );
}

#[test]
fn small_and_degenerate_datasets() {
    let dir = tempfile::tempdir().unwrap();
    let p = FitParams::default().check().unwrap();
    // One material: a clear error.
    let one = synth_store(dir.path(), "one.sbrdf", &[3]);
    let err = fit_store(&one, &p).unwrap_err();
    assert!(
        matches!(err, gplvm::Error::TooFewMaterials { n: 1 }),
        "{err}"
    );
    // Two materials: a finite fit that separates them.
    let two = synth_store(dir.path(), "two.sbrdf", &[3, 40]);
    let m = fit_store(&two, &p).unwrap();
    assert!(m.fit.log_likelihood.is_finite());
    assert_ne!(m.materials[0].coords, m.materials[1].coords);
    // Duplicates of one material: finite, duplicates end up (nearly) together.
    let dup = synth_store(dir.path(), "dup.sbrdf", &[3, 3, 3, 40, 12]);
    let m = fit_store(&dup, &p).unwrap();
    assert!(m.fit.log_likelihood.is_finite() && m.fit.condition_number.is_finite());
    let dist = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let spread = dist(&m.materials[0].coords, &m.materials[3].coords);
    assert!(dist(&m.materials[0].coords, &m.materials[1].coords) < 1e-3 * spread.max(1e-12));
    // The same with Hooke-Jeeves, whose trials are one-point moves from a reference `K^-1`:
    // at the paper's noise (cond(K) ~ N / mu) and at a noise so small that K needs jitter or is
    // too ill-conditioned for moves (every trial then evaluated in full).
    for noise in [1e-4, 1e-12] {
        let hj = FitParams {
            noise,
            ..params(OptimizerKind::HookeJeeves, "raw")
        }
        .check()
        .unwrap();
        let m = fit_store(&dup, &hj).unwrap();
        assert!(m.fit.log_likelihood.is_finite(), "noise {noise}");
        assert!(
            m.fit.log_likelihood > m.fit.initial_log_likelihood,
            "noise {noise}"
        );
        let spread = dist(&m.materials[0].coords, &m.materials[3].coords);
        let together = dist(&m.materials[0].coords, &m.materials[1].coords);
        assert!(
            together < 1e-3 * spread,
            "noise {noise}: {together} against {spread}"
        );
    }
    // A damaged store (a NaN where material 0's first value was; the uncompressed payload
    // starts at byte 4096, index-major, and cell 0 is valid): an error naming it and the
    // material.
    let bad = synth_store(dir.path(), "bad.sbrdf", &[3, 40, 12]);
    let mut bytes = std::fs::read(&bad).unwrap();
    bytes[4096..4100].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&bad, bytes).unwrap();
    // `fit_store` reports the payload checksum's mismatch, although the Gram pass it runs
    // alongside the hash finds the NaN too (as it does alone).
    let err = fit_store(&bad, &p).unwrap_err();
    assert!(
        matches!(
            &err,
            gplvm::Error::Store(brdf_io::Error::StoreChecksum { .. })
        ),
        "{err}"
    );
    let err = gplvm::gram_pass(&Store::open(&bad).unwrap(), p.transform).unwrap_err();
    assert!(
        matches!(&err, gplvm::Error::NonFiniteData { index: 0, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("bad.sbrdf"), "{err}");
    // Finite data that the transform takes out of range (f / offset overflows for an offset
    // of 1e-306) are not called damaged: the error names the transform and the value.
    let good = synth_store(dir.path(), "good.sbrdf", &[3, 40, 12]);
    let tiny: gplvm::Transform = "log:1e-306".parse().unwrap();
    let err = gplvm::gram_pass(&Store::open(&good).unwrap(), tiny).unwrap_err();
    match &err {
        // The value named is one the transform takes out of range (not merely the first).
        gplvm::Error::TransformOverflow { value, .. } => {
            assert!(!tiny.forward(*value).is_finite(), "{err}");
        }
        _ => panic!("{err}"),
    }
    let msg = err.to_string();
    assert!(
        msg.contains("good.sbrdf") && msg.contains("log(offset=1e-306)"),
        "{msg}"
    );
    // All materials identical: nothing to fit, a clear error, however many copies (centring
    // leaves rounding of either sign: 16 copies leave +1.2e-10 of 7.8e5, which a test for a
    // positive total variance let through to a nonsense fit).
    for copies in [3usize, 16, 33] {
        let same = synth_store(dir.path(), &format!("same{copies}.sbrdf"), &vec![7; copies]);
        let err = fit_store(&same, &p).unwrap_err();
        assert!(
            matches!(err, gplvm::Error::IdenticalMaterials { n, total_variance, uncentred_total }
                if n == copies && total_variance.abs() < 1e-12 * uncentred_total),
            "{err}"
        );
    }
}

/// The model's log-likelihood recomputed independently from the stored values: read every row,
/// transform, keep the valid cells, centre, scale, and evaluate the dense formula.
#[test]
fn reported_likelihood_matches_an_independent_recomputation() {
    let dir = tempfile::tempdir().unwrap();
    let data = synth_store(
        dir.path(),
        "some.sbrdf",
        &[1, 6, 11, 16, 21, 26, 31, 36, 41, 46],
    );
    // The last case learns the hyperparameters (saved, reloaded and recomputed like the rest);
    // on raw data the noise runs into its floor instead of towards 0 (cond(K) ~ 1e12 then).
    for (transform, learn) in [
        ("raw", false),
        ("log", false),
        ("log:0.5", false),
        ("raw", true),
    ] {
        let p = FitParams {
            transform: transform.into(),
            learn_hyperparameters: learn,
            ..FitParams::default()
        };
        let model = fit_store(&data, &p.clone().check().unwrap()).unwrap();
        let out = dir.path().join("model.toml");
        model.save(&out).unwrap();
        let model = Model::load(&out).unwrap();
        if learn {
            let h = &model.hyperparameters;
            // Amplitude and noise are learnt; the length-scale is not (redundant with the
            // latent scale; with the prior no maximum exists over it).
            assert_eq!(h.length_scale, vec![p.lengthscale], "{h:?}");
            assert!(h.noise >= p.min_noise, "{h:?}");
            assert!(h.signal_variance != p.amplitude.powi(2), "{h:?}");
            assert!(
                model.fit.condition_number < 1e10,
                "{}",
                model.fit.condition_number
            );
            assert_eq!(model.fit.jitter, 0.0);
        }
        // `fit_store` fills in the Gram pass's time (`fit_gram` leaves it 0).
        assert!(model.fit.gram_seconds > 0.0, "{:?}", model.fit);

        let store = Store::open(&data).unwrap();
        let (n, d) = (store.n_materials(), store.d());
        let nc = store.channels().len();
        let mask = store.validity_mask().to_vec();
        let cols: Vec<usize> = (0..d).filter(|&j| mask[j / nc]).collect();
        assert_eq!(cols.len(), model.dataset.d_effective);
        let mut row = vec![0f32; d];
        let mut y = Mat::<f64>::zeros(n, cols.len());
        for i in 0..n {
            store.material_row(i, 0..d, &mut row).unwrap();
            for (c, &j) in cols.iter().enumerate() {
                y[(i, c)] = model.transform.forward(f64::from(row[j]));
            }
        }
        for c in 0..cols.len() {
            let mean = (0..n).map(|i| y[(i, c)]).sum::<f64>() / n as f64;
            for i in 0..n {
                y[(i, c)] = (y[(i, c)] - mean) / model.data_scale.sqrt();
            }
        }
        let h = &model.hyperparameters;
        let params =
            KernelParams::isotropic(h.signal_variance, h.length_scale[0], h.noise).unwrap();
        let x = model.latent_matrix();
        // The reported condition number is K's exact 2-norm condition.
        let ev = params
            .kernel_matrix(x.as_ref())
            .unwrap()
            .self_adjoint_eigenvalues(faer::Side::Lower)
            .unwrap();
        let (lo, hi) = (
            ev.iter().copied().fold(f64::INFINITY, f64::min),
            ev.iter().copied().fold(0.0, f64::max),
        );
        let cond = model.fit.condition_number;
        assert!(
            ((hi / lo) - cond).abs() <= 1e-6 * cond,
            "{transform}: condition {cond} vs {}",
            hi / lo
        );
        let direct = gp_core::log_likelihood_from_data(
            y.as_ref(),
            x.as_ref(),
            &params,
            model.prior,
            Par::Seq,
        )
        .unwrap();
        let rel = (direct - model.fit.log_likelihood).abs() / direct.abs();
        assert!(
            rel < 1e-8,
            "{transform} (learn {learn}): model {} vs direct {direct} (rel {rel:e})",
            model.fit.log_likelihood
        );
    }
}

/// A model moved together with its store finds the store beside it when the recorded
/// (absolute) path is gone; the recorded path wins while it exists.
#[test]
fn a_moved_model_finds_its_store_beside_it() {
    let dir = tempfile::tempdir().unwrap();
    let before = dir.path().join("before");
    std::fs::create_dir(&before).unwrap();
    let data = synth_store(&before, "few.sbrdf", &[1, 6, 11]);
    let p = FitParams {
        latent_dim: 2,
        ..FitParams::default()
    };
    let model = fit_store(&data, &p.check().unwrap()).unwrap();
    assert!(model.dataset.path.is_absolute());
    model.save(&before.join("m.toml")).unwrap();
    let after = dir.path().join("after");
    std::fs::rename(&before, &after).unwrap();
    let moved = Model::load(&after.join("m.toml")).unwrap();
    assert_eq!(
        moved.dataset_path(&after.join("m.toml")),
        after.join("few.sbrdf")
    );
    // The recorded path is used while it exists, even with a store of that name beside.
    std::fs::create_dir(&before).unwrap();
    std::fs::copy(after.join("few.sbrdf"), &data).unwrap();
    assert_eq!(moved.dataset_path(&after.join("m.toml")), data);
    // Nothing at either place: the recorded path (the error names it).
    std::fs::remove_file(after.join("few.sbrdf")).unwrap();
    std::fs::remove_file(&data).unwrap();
    assert_eq!(moved.dataset_path(&after.join("m.toml")), data);
}

#[test]
fn bad_model_files_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.toml");
    let err = Model::load(&missing).unwrap_err().to_string();
    assert!(err.contains("nope.toml"), "{err}");
    let junk = dir.path().join("junk.toml");
    for bytes in [&b"format = 3\n[[["[..], b"SBRDF\x00\xff\xfe binary"] {
        std::fs::write(&junk, bytes).unwrap();
        let err = Model::load(&junk).unwrap_err().to_string();
        assert!(
            err.contains("junk.toml") && err.contains("not a model file"),
            "{err}"
        );
    }
    // A valid model, then values no fit writes: each is refused on load, naming the file.
    let data = synth_store(dir.path(), "few.sbrdf", &[1, 6, 11, 16, 21]);
    let p = FitParams {
        latent_dim: 2,
        transform: "log".into(),
        ..FitParams::default()
    };
    let good = dir.path().join("good.toml");
    fit_store(&data, &p.check().unwrap())
        .unwrap()
        .save(&good)
        .unwrap();
    let text = std::fs::read_to_string(&good).unwrap();
    Model::load(&good).unwrap();
    for (what, from, to, expect) in [
        ("zero offset", "offset = 0.01", "offset = 0.0", "offset"),
        (
            "negative offset",
            "offset = 0.01",
            "offset = -0.01",
            "offset",
        ),
        (
            "negative noise",
            "length_scale = [1.0]\nnoise = ",
            "length_scale = [1.0]\nnoise = -1.0 #",
            "hyperparameters",
        ),
        (
            "zero data scale",
            "data_scale = ",
            "data_scale = 0.0 #",
            "data_scale",
        ),
        (
            "unknown key",
            "latent_dim = 2",
            "latent_dim = 2\nlatent_dims = 3",
            "unknown field",
        ),
        (
            "transform edited without the configuration",
            "kind = \"log\"\noffset = 0.01",
            "kind = \"raw\"",
            "disagrees with the fit configuration",
        ),
    ] {
        assert!(
            text.contains(from),
            "{what}: the model file has no {from:?}"
        );
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, text.replacen(from, to, 1)).unwrap();
        let err = Model::load(&bad).unwrap_err().to_string();
        assert!(
            err.contains("bad.toml") && err.contains(expect),
            "{what}: {err}"
        );
    }
    // Damaged numbers that parse: a Gram matrix that cannot be one, a coordinate whose square
    // overflows. (They used to surface later, without the file's name, or as -inf.)
    let model = Model::load(&good).unwrap();
    type Edit = (&'static str, fn(&mut Model), &'static str);
    let edits: [Edit; 9] = [
        ("asymmetric Gram", |m| m.gram[0][1] *= 1.5, "not symmetric"),
        (
            "Gram scaled (its data scale not)",
            |m| m.gram.iter_mut().flatten().for_each(|v| *v *= 1e300),
            "data_scale",
        ),
        (
            "Gram zeroed",
            |m| m.gram.iter_mut().flatten().for_each(|v| *v = 0.0),
            "data_scale",
        ),
        (
            "data scale edited",
            |m| m.data_scale *= 1.0 + 1e-6,
            "data_scale",
        ),
        (
            "length-scales for 3 axes at q = 2",
            |m| m.hyperparameters.length_scale = vec![1.0, 2.0, 3.0],
            "3 length-scales for latent_dim 2",
        ),
        (
            "no informative values",
            |m| m.dataset.d_effective = 0,
            "d_effective",
        ),
        (
            "negated Gram",
            |m| m.gram.iter_mut().flatten().for_each(|v| *v = -*v),
            "negative",
        ),
        (
            "Cauchy-Schwarz violated",
            |m| {
                let v = 2.0 * (m.gram[0][0] * m.gram[1][1]).sqrt();
                (m.gram[0][1], m.gram[1][0]) = (v, v);
            },
            "exceeds",
        ),
        (
            "huge coordinate",
            |m| m.materials[0].coords[0] = 1e160,
            "beyond",
        ),
    ];
    for (what, edit, expect) in edits {
        let mut m = model.clone();
        edit(&mut m);
        let bad = dir.path().join("bad.toml");
        m.save(&bad).unwrap();
        let err = Model::load(&bad).unwrap_err().to_string();
        assert!(
            err.contains("bad.toml") && err.contains(expect),
            "{what}: {err}"
        );
    }
}

/// `f` run in a rayon pool of `threads` threads.
fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

/// The uncentred Gram matrix of `n` pseudo-random materials with `d` values each, times
/// `scale^2`.
fn random_gram(n: usize, d: usize, seed: u64, scale: f64) -> Mat<f64> {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let y = Mat::from_fn(n, d, |_, _| scale * next());
    &y * y.transpose()
}

/// A fit with restarts has the same bits in rayon pools of 1, 2 and 3 threads, for both
/// optimisers: the objective runs sequentially, and the PCA start's and the condition number's
/// eigen-decompositions (faer's global parallelism, the current pool) must not depend on it.
#[test]
fn fits_are_identical_on_any_thread_count() {
    let g = random_gram(51, 40, 9, 1.0);
    for (optimizer, max_evaluations) in [
        (OptimizerKind::Lbfgs, 200_000),
        (OptimizerKind::HookeJeeves, 3_000),
    ] {
        let p = FitParams {
            latent_dim: 3,
            optimizer,
            max_evaluations,
            restarts: 2,
            seed: 4,
            ..FitParams::default()
        }
        .check()
        .unwrap();
        let bits: Vec<Vec<u64>> = [1, 2, 3]
            .iter()
            .map(|&threads| {
                let f = in_pool(threads, || gplvm::fit_gram(g.as_ref(), 40, &p)).unwrap();
                let mut v: Vec<u64> = (0..51)
                    .flat_map(|i| (0..3).map(move |k| (i, k)))
                    .map(|(i, k)| f.x[(i, k)].to_bits())
                    .collect();
                v.extend([f.report.log_likelihood, f.report.condition_number].map(f64::to_bits));
                v
            })
            .collect();
        assert!(bits.iter().all(|b| b == &bits[0]), "{optimizer}");
    }
}

/// Two and three materials, one latent dimension, and q >= N: both optimisers converge by
/// their own tests, improve on the PCA start, and a latent dimension beyond N - 1 fits exactly
/// as N - 1 does (centred data span N - 1 dimensions; the extra PCA axes start at 0 up to
/// rounding).
#[test]
fn tiny_datasets_fit_with_any_latent_dimension() {
    for n in [2usize, 3] {
        let g = random_gram(n, 20, 3, 1.0);
        for optimizer in [OptimizerKind::Lbfgs, OptimizerKind::HookeJeeves] {
            let fit = |q: usize| {
                let p = FitParams {
                    latent_dim: q,
                    optimizer,
                    ..FitParams::default()
                };
                gplvm::fit_gram(g.as_ref(), 20, &p.check().unwrap()).unwrap()
            };
            let full = fit(n - 1);
            for q in 1..=n + 2 {
                let f = fit(q);
                let r = &f.report;
                let what = format!("N {n}, q {q}, {optimizer}: {r:?}");
                assert!(r.log_likelihood.is_finite(), "{what}");
                assert!(r.log_likelihood >= r.initial_log_likelihood, "{what}");
                assert!(!r.stop_reason.contains("not converged"), "{what}");
                assert!(!r.stop_reason.contains("reached"), "{what}");
                assert!((0..q).any(|k| f.x[(0, k)] != f.x[(1, k)]), "{what}");
                if q >= n - 1 {
                    let (a, b) = (r.log_likelihood, full.report.log_likelihood);
                    assert!(
                        (a - b).abs() <= 1e-9 * b.abs(),
                        "{what}: {a} vs {b} at q = N - 1"
                    );
                }
            }
        }
    }
}

/// With unit-variance scaling the fit does not depend on the data's units: the same
/// likelihood and the same latent configuration (pairwise distances: the objective is
/// invariant under rotations of the latent space, so rounding may turn the points) for data
/// scaled by 1e-150 and 1e150.
#[test]
fn unit_variance_fits_do_not_depend_on_the_data_scale() {
    let p = FitParams {
        latent_dim: 2,
        ..FitParams::default()
    }
    .check()
    .unwrap();
    let fit = |scale: f64| gplvm::fit_gram(random_gram(10, 20, 5, scale).as_ref(), 20, &p).unwrap();
    let dists = |x: &Mat<f64>| -> Vec<f64> {
        (0..10)
            .flat_map(|i| (0..i).map(move |j| (i, j)))
            .map(|(i, j)| {
                (0..2)
                    .map(|k| (x[(i, k)] - x[(j, k)]).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .collect()
    };
    let one = fit(1.0);
    let d1 = dists(&one.x);
    for scale in [1e-150, 1e-30, 1e30, 1e150] {
        let f = fit(scale);
        let (a, b) = (f.report.log_likelihood, one.report.log_likelihood);
        assert!((a - b).abs() <= 1e-9 * b.abs(), "{scale:e}: {a} vs {b}");
        let worst = dists(&f.x)
            .iter()
            .zip(&d1)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-5, "{scale:e}: a distance changed by {worst}");
        assert!((f.data_scale / one.data_scale / (scale * scale) - 1.0).abs() < 1e-12);
    }
}

/// A q = 2 fit with `data_scaling = none` of 10 random materials (20 values each) scaled by
/// `scale`.
fn unscaled_fit(scale: f64) -> gplvm::Fit {
    let p = FitParams {
        latent_dim: 2,
        data_scaling: gplvm::DataScaling::None,
        ..FitParams::default()
    }
    .check()
    .unwrap();
    gplvm::fit_gram(random_gram(10, 20, 5, scale).as_ref(), 20, &p).unwrap()
}

/// Unscaled data with a Gram matrix near 1e200 (gradients near 1e204, whose squares
/// overflow): L-BFGS still optimises. Against such data the log-determinant term is
/// negligible and the points spread without bound, the same way as for the same data at 1e100
/// (a Gram matrix near 1e100, no overflow): both fits improve on their start by the same
/// relative amount. (Before the gradient norm was computed safely, the 1e200 fit stopped at its
/// start with an infinite norm.)
#[test]
fn unscaled_fits_survive_gradients_whose_squares_overflow() {
    let (huge, big) = (unscaled_fit(1e100), unscaled_fit(1e50));
    for f in [&huge, &big] {
        let r = &f.report;
        assert!(r.gradient_norm.is_finite() && r.gradient_norm > 0.0);
        assert!(
            r.log_likelihood > r.initial_log_likelihood * (1.0 - 1e-3),
            "{}: {:e} from {:e}",
            r.stop_reason,
            r.log_likelihood,
            r.initial_log_likelihood
        );
    }
    let ratio = huge.report.log_likelihood / big.report.log_likelihood;
    assert!((ratio / 1e100 - 1.0).abs() < 1e-6, "ratio {ratio:e}");
}

/// Unscaled data near 1e-155 (a Gram matrix near the subnormal range, 1e-309) fit like the
/// same data near 1e-150: their PCA start used to fail ("eigen-decomposition of the Gram
/// matrix failed: NoConvergence"). Against a noise of 1e-4 such data are nothing, so both
/// fits are the prior's (the same likelihood).
#[test]
fn unscaled_fits_of_data_near_the_subnormal_range() {
    let (tiny, small) = (unscaled_fit(1e-155), unscaled_fit(1e-150));
    let (a, b) = (tiny.report.log_likelihood, small.report.log_likelihood);
    assert!(
        a.is_finite() && (a - b).abs() <= 1e-9 * b.abs(),
        "{a} vs {b}"
    );
}

/// Hooke-Jeeves with exploratory trials evaluated as one-point moves (`MoveEvaluator`, O(N^2)
/// each, the fits' and refits' objective) converges where it does with every trial a full
/// O(N^3) evaluation: rounding tips some near-ties the other way (the runs took 72,239 and
/// 74,399 evaluations for seed 3), and both end at the same value to 1e-10, most trials
/// evaluated without a factorisation.
#[test]
fn hooke_jeeves_by_point_moves_matches_full_evaluations() {
    use gp_core::{GplvmObjective, Learn};
    use gplvm::optim::{HookeJeevesSettings, hooke_jeeves};
    let (n, d, q) = (20, 400, 2);
    for seed in [3u64, 4] {
        let g = random_gram(n, d, seed, 1.0);
        let obj = GplvmObjective::from_uncentred_gram(g.as_ref(), d)
            .unwrap()
            .with_prior(true);
        let params = KernelParams::paper();
        let flat = obj.flat(q, params.clone(), Learn::NONE).unwrap();
        let x0 = Mat::from_fn(n, q, |i, j| ((i * q + j) as f64 * 0.37).sin());
        let theta0 = flat.pack(x0.as_ref(), &params).unwrap();
        let settings = HookeJeevesSettings {
            max_evaluations: 1_000_000,
            min_step: 1e-7,
            ..HookeJeevesSettings::default()
        };
        let full = hooke_jeeves(
            |t| {
                flat.neg_log_likelihood(t, Par::Seq)
                    .unwrap_or(f64::INFINITY)
            },
            &theta0,
            &settings,
        )
        .unwrap();
        let mut evaluator = flat.move_evaluator();
        let by_moves = hooke_jeeves(
            |t| {
                evaluator
                    .neg_log_likelihood(t, Par::Seq)
                    .unwrap_or(f64::INFINITY)
            },
            &theta0,
            &settings,
        )
        .unwrap();
        let c = evaluator.counts();
        eprintln!(
            "seed {seed}: full {:.12e} in {} evaluations; by moves {:.12e} in {} ({c:?})",
            full.value, full.evaluations, by_moves.value, by_moves.evaluations
        );
        assert!(!full.at_limit && !by_moves.at_limit);
        assert!((by_moves.value - full.value).abs() <= 1e-10 * full.value.abs());
        assert_eq!(c.evaluations, by_moves.evaluations);
        assert!(c.cheap * 2 > c.evaluations, "{c:?}");
    }
}

/// A fit of `random_gram(n, d, 3, 1.0)` with `p`, and what it warned.
fn fit_warnings(n: usize, d: usize, p: FitParams) -> (gplvm::Fit, String) {
    let g = random_gram(n, d, 3, 1.0);
    let config = p.check().unwrap();
    let (fit, said) = warnings_of(|| gplvm::fit_gram(g.as_ref(), d, &config));
    (fit.unwrap(), said)
}

/// `fit_gram` warns exactly when a setting makes no sense for the data, each warning at its
/// threshold: q beyond the centred data's span min(N - 1, D); a noise of at least the signal
/// variance (fixed hyperparameters only); a noise below the rounding of `s^2 + mu`; a nearly
/// singular K (condition above 1e12); most materials isolated in the latent space. A sensible
/// fit warns of nothing.
#[test]
fn fits_warn_of_settings_that_make_no_sense() {
    let base = || FitParams {
        latent_dim: 2,
        ..FitParams::default()
    };
    let (fit, said) = fit_warnings(10, 20, base());
    assert_eq!(said, "", "a sensible fit");
    assert!(fit.report.condition_number < 1e12);

    // The span: N - 1 = 3 for 4 materials, D = 2 for 2 values each.
    for (n, d, q, warns) in [
        (4, 20, 3, false),
        (4, 20, 4, true),
        (10, 2, 2, false),
        (10, 2, 3, true),
    ] {
        let p = FitParams {
            latent_dim: q,
            ..base()
        };
        let (_, said) = fit_warnings(n, d, p);
        let expected = format!("latent dimension q = {q} for N = {n} materials of D = {d} values");
        assert_eq!(
            said.contains(&expected),
            warns,
            "N {n}, D {d}, q {q}: {said}"
        );
    }

    // Noise against the signal variance s^2 = amplitude^2 = 9 (not 2 amplitude: 2 x 2 = 2 + 2).
    for (noise, learn, warns) in [(9.0, false, true), (8.99, false, false), (9.0, true, false)] {
        let p = FitParams {
            amplitude: 3.0,
            noise,
            learn_hyperparameters: learn,
            ..base()
        };
        let (_, said) = fit_warnings(10, 20, p);
        assert_eq!(
            said.contains("is at least the kernel's signal variance s^2 = 9e0"),
            warns,
            "{noise} {learn}: {said}"
        );
    }

    // Noise under the rounding of s^2 + mu = 1 + mu (half an ulp above 1 is 1.1e-16; 8e-17
    // would survive 1 - mu, whose half ulp is 5.6e-17).
    for (noise, warns) in [(1e-17, true), (8e-17, true), (1e-15, false)] {
        let p = FitParams { noise, ..base() };
        let (_, said) = fit_warnings(10, 20, p);
        assert_eq!(
            said.contains("is below the rounding of the kernel's diagonal"),
            warns,
            "{noise:e}: {said}"
        );
    }

    // Two duplicate materials and almost no noise: K is nearly singular at the optimum.
    let mut g = random_gram(10, 20, 3, 1.0);
    for j in 0..10 {
        g[(9, j)] = g[(8, j)];
        g[(j, 9)] = g[(j, 8)];
    }
    g[(9, 9)] = g[(8, 8)];
    let config = FitParams {
        noise: 1e-14,
        ..base()
    }
    .check()
    .unwrap();
    let (fit, said) = warnings_of(|| gplvm::fit_gram(g.as_ref(), 20, &config));
    let fit = fit.unwrap();
    assert!(fit.report.condition_number > 1e12, "{:?}", fit.report);
    assert!(
        said.contains("K is nearly singular at the optimum"),
        "{said}"
    );

    // A length-scale of 1e-3 from a unit-variance PCA start, one iteration: every material is
    // hundreds of length-scales from the next.
    let p = FitParams {
        lengthscale: 1e-3,
        init_scaling: gplvm::InitScaling::Isotropic,
        max_iterations: 1,
        ..base()
    };
    let (_, said) = fit_warnings(10, 20, p);
    assert!(
        said.contains("10 of 10 materials correlate less than 1e-3"),
        "{said}"
    );
}

/// The fit configuration reaches the optimiser and the kernel: L-BFGS's iteration cap, gradient
/// tolerance and value-change tolerance each decide where it stops; iterations and evaluations
/// are summed over restarts; a fixed amplitude a gives the signal variance a^2.
#[test]
fn fit_settings_reach_the_optimiser_and_the_kernel() {
    let g = random_gram(10, 20, 3, 1.0);
    let fit = |p: FitParams| gplvm::fit_gram(g.as_ref(), 20, &p.check().unwrap()).unwrap();
    let base = || FitParams {
        latent_dim: 2,
        ..FitParams::default()
    };

    let capped = fit(FitParams {
        max_iterations: 3,
        ..base()
    });
    assert_eq!(capped.report.stop_reason, "reached 3 iterations");
    assert_eq!(capped.report.iterations, 3);
    // Three capped runs: three times the iterations, and more evaluations than one.
    let thrice = fit(FitParams {
        max_iterations: 3,
        restarts: 2,
        ..base()
    });
    assert_eq!(thrice.report.iterations, 9);
    assert!(
        thrice.report.evaluations >= 3 * 3 + 3,
        "{:?}",
        thrice.report
    );
    assert!(thrice.report.evaluations > capped.report.evaluations);

    let loose = fit(FitParams {
        gradient_tolerance: 1e6,
        ..base()
    });
    assert!(
        loose.report.stop_reason.ends_with("below tolerance"),
        "{:?}",
        loose.report
    );
    assert_eq!(loose.report.iterations, 0);

    let coarse = fit(FitParams {
        cost_tolerance: 1e6,
        ..base()
    });
    assert!(
        coarse.report.stop_reason.contains("< 1.0e6 in one step"),
        "{:?}",
        coarse.report
    );

    let amplified = fit(FitParams {
        amplitude: 3.0,
        noise: 1e-3,
        ..base()
    });
    assert_eq!(amplified.params.signal_variance(), 9.0);
    assert_eq!(amplified.params.noise(), 1e-3);
}
