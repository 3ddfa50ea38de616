//! Robustness of the model-file reader ([`Model::load`]): damaged, truncated and edited model
//! files give an error that names the file and the problem, never a panic or a model that fails
//! later without the file's name.

use std::path::{Path, PathBuf};

use faer::Mat;
use gplvm::model::{DatasetRef, Hyperparameters, LatentMaterial, MODEL_FORMAT, MODEL_VERSION};
use gplvm::{FitParams, Model, fit_gram};
use proptest::prelude::*;

/// A small valid model, fitted on the Gram matrix of 6 pseudo-random materials of 40 values
/// (no store needed: [`Model::load`] does not open the dataset).
fn valid_model() -> Model {
    let (n, d) = (6, 40);
    let mut s = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let y = Mat::from_fn(n, d, |_, _| next());
    let g = &y * y.transpose();
    let config = FitParams {
        latent_dim: 2,
        max_iterations: 30,
        ..FitParams::default()
    }
    .check()
    .unwrap();
    let fit = fit_gram(g.as_ref(), d, &config).unwrap();
    Model {
        format: MODEL_FORMAT.into(),
        version: MODEL_VERSION,
        dataset: DatasetRef {
            path: PathBuf::from("data.sbrdf"),
            checksum: "xxh3-64:0123456789abcdef".into(),
            n_materials: n,
            d,
            d_effective: d,
            grid: "1,1,8".into(),
            channels: vec!["400nm".into(), "500nm".into(), "600nm".into()],
        },
        transform: config.transform,
        data_scale: fit.data_scale,
        prior: config.params.prior,
        latent_dim: config.params.latent_dim,
        hyperparameters: Hyperparameters {
            signal_variance: fit.params.signal_variance(),
            length_scale: fit.params.length_scale().values().to_vec(),
            noise: fit.params.noise(),
        },
        fit: fit.report,
        config: config.params.clone(),
        materials: (0..n)
            .map(|i| LatentMaterial {
                name: format!("mat{i}"),
                coords: (0..fit.x.ncols()).map(|k| fit.x[(i, k)]).collect(),
            })
            .collect(),
        gram: (0..n)
            .map(|i| (0..n).map(|j| g[(i, j)]).collect())
            .collect(),
    }
}

fn valid_text() -> String {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.toml");
    valid_model().save(&p).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    Model::load(&p).unwrap();
    text
}

/// The first material's `coords = [...]` (over several lines) in a model file's text.
fn first_coords(text: &str) -> &str {
    let at = text.find("coords = [").unwrap();
    let end = at + text[at..].find("\n]").unwrap() + 2;
    &text[at..end]
}

/// `Model::load` of `bytes` written to `dir/name`: the error message, which must name the file.
fn load_err(dir: &Path, name: &str, bytes: &[u8]) -> Option<String> {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    match Model::load(&p) {
        Ok(_) => None,
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains(&p.display().to_string()), "{msg}");
            Some(msg)
        }
    }
}

/// Cut at every character: an error naming the file, unless only trailing whitespace went.
#[test]
fn truncations_at_every_length_are_errors() {
    let text = valid_text();
    let dir = tempfile::tempdir().unwrap();
    for (cut, _) in text.char_indices() {
        let head = &text[..cut];
        let e = load_err(dir.path(), "cut.toml", head.as_bytes());
        if head.trim_end() != text.trim_end() {
            assert!(e.is_some(), "truncation at {cut} accepted");
        }
    }
}

/// Each top-level key and each key of a table, removed: an error naming the file and the key.
/// (Fit-configuration keys have defaults: removing one is not an error, unless the default
/// disagrees with the model, as latent_dim = 5 does with q = 2.)
#[test]
fn missing_keys_are_named() {
    let text = valid_text();
    let dir = tempfile::tempdir().unwrap();
    let mut section = String::new();
    let mut checked = 0;
    for (i, line) in text.lines().enumerate() {
        if line.starts_with('[') {
            section = line.trim_matches(['[', ']']).to_owned();
            continue;
        }
        let Some((key, _)) = line.split_once(" = ") else {
            continue;
        };
        // A value spanning lines (the Gram matrix) is removed as a whole.
        let mut lines: Vec<&str> = text.lines().collect();
        let mut end = i + 1;
        if line.ends_with('[') {
            while lines[end - 1] != "]" {
                end += 1;
            }
        }
        lines.drain(i..end);
        let edited = lines.join("\n");
        let e = load_err(dir.path(), "missing.toml", edited.as_bytes());
        if section == "config" {
            match key {
                "latent_dim" => assert!(
                    e.as_ref().is_some_and(|e| e.contains(
                        "latent_dim 2 disagrees with the fit configuration's latent_dim = 5"
                    )),
                    "{e:?}"
                ),
                _ => assert!(e.is_none(), "config key {key}: {e:?}"),
            }
            continue;
        }
        let e = e.unwrap_or_else(|| panic!("[{section}] {key} removed: accepted"));
        assert!(
            e.contains(&format!("missing field `{}`", key.trim())),
            "[{section}] {key}: {e}"
        );
        checked += 1;
    }
    assert!(checked > 30, "{checked}");
}

/// Edits of the text that TOML accepts but no fit writes.
#[test]
fn values_no_fit_writes_are_refused() {
    let text = valid_text();
    let dir = tempfile::tempdir().unwrap();
    let coords = first_coords(&text).to_owned();
    let first = valid_model().materials[0].coords.clone();
    let cases: Vec<(&str, String, String, &str)> = vec![
        (
            "wrong type",
            "latent_dim = 2".into(),
            "latent_dim = \"two\"".into(),
            "invalid type",
        ),
        (
            "negative latent_dim",
            "latent_dim = 2".into(),
            "latent_dim = -2".into(),
            "latent_dim",
        ),
        (
            "NaN coordinate",
            coords.clone(),
            format!("coords = [nan, {:?}]", first[1]),
            "non-finite",
        ),
        (
            "infinite coordinate",
            coords.clone(),
            format!("coords = [{:?}, -inf]", first[0]),
            "non-finite",
        ),
        (
            "one coordinate for q = 2",
            coords.clone(),
            format!("coords = [{:?}]", first[0]),
            "inconsistent sizes",
        ),
        (
            "three coordinates for q = 2",
            coords.clone(),
            format!("coords = [{:?}, {:?}, 0.5]", first[0], first[1]),
            "inconsistent sizes",
        ),
        (
            "a material more than the dataset",
            "n_materials = 6".into(),
            "n_materials = 7".into(),
            "inconsistent sizes",
        ),
        (
            "zero noise",
            "\nnoise = ".into(),
            "\nnoise = 0.0 #".into(),
            "hyperparameters must be finite and > 0",
        ),
        (
            "negative signal variance",
            "signal_variance = ".into(),
            "signal_variance = -1.0 #".into(),
            "hyperparameters must be finite and > 0",
        ),
        (
            "NaN noise",
            "\nnoise = ".into(),
            "\nnoise = nan #".into(),
            "hyperparameters must be finite and > 0",
        ),
        (
            "no length-scale",
            "length_scale = [1.0]".into(),
            "length_scale = []".into(),
            "hyperparameters must be finite and > 0",
        ),
        (
            "format",
            "format = \"specgp-gplvm\"".into(),
            "format = \"specgp-gp\"".into(),
            "is not specgp-gplvm version 1",
        ),
        (
            "d_effective beyond d",
            "d_effective = 40".into(),
            "d_effective = 41".into(),
            "d_effective = 41 must be in 1..=40",
        ),
        (
            "unknown key",
            "[hyperparameters]".into(),
            "[hyperparameters]\nscale = 2.0".into(),
            "unknown field `scale`",
        ),
        (
            "duplicate key",
            "prior = true".into(),
            "prior = true\nprior = true".into(),
            "duplicate key",
        ),
    ];
    for (what, from, to, expect) in cases {
        assert!(text.contains(&from), "{what}: no {from:?} in\n{text}");
        let edited = text.replacen(&from, &to, 1);
        let e = load_err(dir.path(), "edited.toml", edited.as_bytes())
            .unwrap_or_else(|| panic!("{what}: accepted"));
        assert!(e.contains(expect), "{what}: {e}");
    }
}

/// Fields of a loaded model that other code trusts: the latent dimension q (1..=64, as a fit
/// allows, and the configuration's own), the prior (also the configuration's), and
/// length-scales the kernel accepts. These used to load, and then fail when a predictor was
/// built in an error naming no file (q = 0, length-scales beyond 1e+-150) or refit another
/// model in leave-one-out (q or prior edited without the configuration).
#[test]
fn fields_other_code_trusts_are_checked_on_load() {
    let dir = tempfile::tempdir().unwrap();
    type Edit = (&'static str, fn(&mut Model), &'static str);
    let edits: [Edit; 6] = [
        (
            "q = 0",
            |m| {
                m.latent_dim = 0;
                m.config.latent_dim = 0;
                m.materials.iter_mut().for_each(|x| x.coords.clear());
            },
            "latent_dim = 0: must be in 1..=64",
        ),
        (
            "q = 65",
            |m| {
                m.latent_dim = 65;
                m.config.latent_dim = 65;
                m.materials
                    .iter_mut()
                    .for_each(|x| x.coords.resize(65, 0.25));
            },
            "latent_dim = 65: must be in 1..=64",
        ),
        (
            "q disagrees with the configuration",
            |m| m.config.latent_dim = 3,
            "latent_dim 2 disagrees with the fit configuration's latent_dim = 3",
        ),
        (
            "prior disagrees with the configuration",
            |m| m.prior = !m.prior,
            "prior = false disagrees with the fit configuration's prior = true",
        ),
        (
            "huge length-scale",
            |m| m.hyperparameters.length_scale = vec![1e200],
            "hyperparameters: invalid hyperparameter length_scale = 1e200",
        ),
        (
            "tiny ARD length-scale",
            |m| m.hyperparameters.length_scale = vec![1.0, 1e-200],
            "hyperparameters: invalid hyperparameter length_scale[1] = 1e-200",
        ),
    ];
    let model = valid_model();
    for (what, edit, expect) in edits {
        let mut m = model.clone();
        edit(&mut m);
        let p = dir.path().join("trusted.toml");
        m.save(&p).unwrap();
        let e = Model::load(&p)
            .err()
            .unwrap_or_else(|| panic!("{what}: accepted"))
            .to_string();
        assert!(
            e.contains(&p.display().to_string()) && e.contains(expect),
            "{what}: {e}"
        );
    }
}

/// The recorded fit configuration is checked where it is used (leave-one-out refits), in an
/// error naming the model file (it used to name none); the model itself still loads, as files
/// written before a rule was added must.
#[test]
fn the_fit_configuration_is_checked_when_used() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("config.toml");
    let model = valid_model();
    let config = model.fit_config(&p).unwrap();
    assert_eq!(config.params, model.config);
    type Edit = (fn(&mut FitParams), &'static str);
    let edits: [Edit; 3] = [
        (
            |c| c.amplitude = -1.0,
            "amplitude = -1: must be finite and > 0",
        ),
        (
            |c| c.restarts = 1 << 40,
            "restarts = 1099511627776: must be at most 1000",
        ),
        (
            |c| c.min_step = 1.0,
            "min_step = 1: must be at most initial_step (0.1)",
        ),
    ];
    for (edit, expect) in edits {
        let mut m = model.clone();
        edit(&mut m.config);
        m.save(&p).unwrap();
        let m = Model::load(&p).unwrap();
        let e = m.fit_config(&p).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!(
                "{}: fit configuration: invalid configuration: ",
                p.display()
            )) && e.contains(expect),
            "{e}"
        );
    }
}

/// Deeply nested arrays and very long arrays are parse errors or size errors, not a stack
/// overflow or an allocation beyond the file's size.
#[test]
fn nested_and_huge_arrays_are_errors() {
    let text = valid_text();
    let dir = tempfile::tempdir().unwrap();
    for depth in [100, 10_000, 1_000_000] {
        let nested = format!("{}{}", "[".repeat(depth), "]".repeat(depth));
        let edited = text.replacen(
            "length_scale = [",
            &format!("length_scale = [{nested}, "),
            1,
        );
        let e = load_err(dir.path(), "deep.toml", edited.as_bytes()).expect("accepted");
        assert!(!e.is_empty());
    }
    // A latent dimension of 2^60 (with its configuration): refused before anything is sized by it.
    let edited = text.replace("latent_dim = 2", &format!("latent_dim = {}", 1u64 << 60));
    let e = load_err(dir.path(), "huge.toml", edited.as_bytes()).expect("accepted");
    assert!(e.contains("latent_dim"), "{e}");
    // 10^5 coordinates for one material: a size error.
    let long = vec!["0.5"; 100_000].join(", ");
    let edited = text.replacen(first_coords(&text), &format!("coords = [{long}]"), 1);
    let e = load_err(dir.path(), "long.toml", edited.as_bytes()).expect("accepted");
    assert!(e.contains("inconsistent sizes"), "{e}");
}

/// The load checks at their bounds: a coordinate of exactly +-1e100 loads and one an ulp
/// beyond does not; a Gram entry may exceed sqrt(G_ii G_jj) by 1e-9 relative (rounding) and
/// no more; a Gram matrix with N rows, one of them short, is a size error; a data scale of 0,
/// infinity or NaN is named as such (not as a disagreement with the Gram matrix).
#[test]
fn load_checks_hold_at_their_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.toml");
    let load = |m: &Model| {
        m.save(&p).unwrap();
        Model::load(&p).map_err(|e| e.to_string())
    };
    let model = valid_model();
    for v in [1e100, -1e100] {
        let mut m = model.clone();
        m.materials[2].coords[1] = v;
        assert!(load(&m).is_ok(), "{v:e}");
        m.materials[2].coords[1] = v * (1.0 + f64::EPSILON);
        let e = load(&m).unwrap_err();
        assert!(e.contains("is beyond +-1e100"), "{e}");
    }

    // Cauchy-Schwarz at the bound; the data scale follows the edited Gram matrix (its centred
    // trace per value), so only the bound decides.
    let at_bound = |factor: f64| {
        let mut m = model.clone();
        let v = (m.gram[0][0] * m.gram[3][3]).sqrt() * factor;
        (m.gram[0][3], m.gram[3][0]) = (v, v);
        let g = Mat::from_fn(6, 6, |i, j| m.gram[i][j]);
        m.data_scale = gplvm::fit::scaled_centred_gram(g.as_ref(), 40, m.config.data_scaling)
            .unwrap()
            .1;
        load(&m)
    };
    assert!(at_bound(1.0).is_ok());
    assert!(at_bound(1.0 + 5e-10).is_ok());
    let e = at_bound(1.0 + 2e-9).unwrap_err();
    assert!(
        e.contains("Gram entry (3, 0)") && e.contains("exceeds"),
        "{e}"
    );

    let mut m = model.clone();
    m.gram[4].pop();
    let e = load(&m).unwrap_err();
    assert!(e.contains("the Gram matrix is not 6 x 6"), "{e}");

    // The recorded data scale may differ from the recomputed one by 1e-9 relative, plus the
    // rounding of centring, 64 N eps of the uncentred trace per value; no more.
    let recorded_as = |m: &Model, factor: f64| {
        let mut m = m.clone();
        m.data_scale *= factor;
        load(&m)
    };
    assert!(recorded_as(&model, 1.0 + 5e-10).is_ok());
    let e = recorded_as(&model, 1.0 + 2e-9).unwrap_err();
    assert!(e.contains("disagrees with the Gram matrix"), "{e}");
    // A common component of 1e6 added to the Gram matrix (materials 1e3 from the origin, a
    // centred variance of 0.07 per value): the rounding term dominates (3e-8 relative).
    let offset = {
        let mut m = model.clone();
        let c = 1e6;
        m.gram.iter_mut().flatten().for_each(|v| *v += c);
        let g = Mat::from_fn(6, 6, |i, j| m.gram[i][j]);
        m.data_scale = gplvm::fit::scaled_centred_gram(g.as_ref(), 40, m.config.data_scaling)
            .unwrap()
            .1;
        m
    };
    let uncentred: f64 = (0..6).map(|i| offset.gram[i][i]).sum::<f64>() / 240.0;
    let rounding = 64.0 * 6.0 * f64::EPSILON * uncentred / offset.data_scale;
    assert!(rounding > 1e-9, "{rounding:e}");
    assert!(recorded_as(&offset, 1.0 + 0.9 * rounding).is_ok());
    assert!(recorded_as(&offset, 1.0 + 1.2 * rounding + 1e-9).is_err());

    for bad in [0.0, f64::INFINITY, f64::NAN] {
        let mut m = model.clone();
        m.data_scale = bad;
        // TOML writes these; the check, not the parser, refuses them.
        let e = load(&m).unwrap_err();
        assert!(
            e.contains("data_scale must be finite and > 0"),
            "{bad}: {e}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Random byte changes: an error naming the file, or a model whose checked invariants hold.
    #[test]
    fn byte_changes_never_panic(
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
    ) {
        let text = valid_text();
        let dir = tempfile::tempdir().unwrap();
        let mut bytes = text.into_bytes();
        for (at, v) in edits {
            let i = at.index(bytes.len());
            bytes[i] = v;
        }
        let p = dir.path().join("flipped.toml");
        std::fs::write(&p, &bytes).unwrap();
        match Model::load(&p) {
            Err(e) => prop_assert!(e.to_string().contains(&p.display().to_string()), "{}", e),
            Ok(m) => {
                prop_assert!((1..=64).contains(&m.latent_dim));
                prop_assert!(m.materials.iter().all(|x| x.coords.len() == m.latent_dim
                    && x.coords.iter().all(|v| v.is_finite())));
                prop_assert_eq!(m.gram.len(), m.materials.len());
            }
        }
    }

    /// Random text after a valid start: an error naming the file.
    #[test]
    fn random_tails_are_errors(tail in proptest::collection::vec(any::<u8>(), 0..256), cut in 0usize..2000) {
        let text = valid_text();
        let dir = tempfile::tempdir().unwrap();
        let mut bytes = text.as_bytes()[..cut.min(text.len() - 1)].to_vec();
        bytes.extend_from_slice(&tail);
        let p = dir.path().join("tail.toml");
        std::fs::write(&p, &bytes).unwrap();
        let e = Model::load(&p).err();
        prop_assert!(e.is_some_and(|e| e.to_string().contains(&p.display().to_string())));
    }
}
