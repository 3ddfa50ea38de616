//! `specgp synth` -> `fit` -> `export`: the model's log-likelihood equals an independent
//! recomputation from the exported data (issue 5's acceptance test), and `latent --json` reports
//! the model's coordinates; lazy renders of model points (`render MODEL@X,Y`, `map
//! --thumbnails`) read an existing forward-transformed sidecar.

use std::path::Path;
use std::process::Command;

use brdf_io::AngularGrid;
use brdf_io::npy::{NpyData, read};
use faer::{Mat, Par};
use gp_core::KernelParams;
use gplvm::Model;

/// Runs `specgp args` in `dir`.
fn run(args: &[&str], dir: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_specgp"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run specgp")
}

/// Runs `specgp args` in `dir`, which must succeed: its stdout.
fn specgp(args: &[&str], dir: &Path) -> String {
    specgp_outputs(args, dir).0
}

/// Runs `specgp args` in `dir`, which must succeed: its stdout and stderr (warnings, reports).
fn specgp_outputs(args: &[&str], dir: &Path) -> (String, String) {
    let out = run(args, dir);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "specgp {args:?} failed: {err}");
    (String::from_utf8(out.stdout).unwrap(), err)
}

/// Runs `specgp args` in `dir`, which must fail: its stderr.
fn specgp_fails(args: &[&str], dir: &Path) -> String {
    let out = run(args, dir);
    assert!(!out.status.success(), "specgp {args:?} succeeded");
    String::from_utf8(out.stderr).unwrap()
}

/// A small synthetic dataset `data.sbrdf` in `dir` (grid 8,8,16, these wavelengths).
fn synth_small(dir: &Path, wavelengths: &str) {
    specgp(
        &[
            "synth",
            "--out",
            "data.sbrdf",
            "--grid",
            "8,8,16",
            "--wavelengths",
            wavelengths,
        ],
        dir,
    );
}

/// [`synth_small`] and a fit `m.toml` of it with q = 2 (the default fit otherwise).
fn fitted_small(dir: &Path, wavelengths: &str) {
    synth_small(dir, wavelengths);
    specgp(
        &["fit", "data.sbrdf", "--out", "m.toml", "--latent-dim", "2"],
        dir,
    );
}

/// A file's kind is read from its extension in any case, by every command (`predict --out
/// P.NPY` and `sample DATA.SBRDF:MATERIAL` were refused while `fit --out M.TOML` was not).
#[test]
fn upper_case_extensions_name_the_same_kinds() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:100");
    std::fs::rename(d.join("data.sbrdf"), d.join("DATA.SBRDF")).unwrap();
    specgp(
        &["fit", "DATA.SBRDF", "--out", "M.TOML", "--latent-dim", "2"],
        d,
    );
    specgp(&["predict", "M.TOML", "--at", "0,0", "--out", "P.NPY"], d);
    specgp(&["predict", "M.TOML", "--at", "0,0", "--out", "p.npy"], d);
    assert_eq!(
        std::fs::read(d.join("P.NPY")).unwrap(),
        std::fs::read(d.join("p.npy")).unwrap()
    );
    specgp(&["predict", "M.TOML", "--at", "0,0", "--out", "P.Sbrdf"], d);
    assert_eq!(
        brdf_io::Store::open(d.join("P.Sbrdf"))
            .unwrap()
            .n_materials(),
        1
    );
    std::fs::write(d.join("dirs.csv"), "0,0,1,0,0,1\n").unwrap();
    let stored = specgp(
        &[
            "sample",
            "DATA.SBRDF:paper_white",
            "--dirs",
            "dirs.csv",
            "--out",
            "-",
        ],
        d,
    );
    assert!(stored.starts_with("400,500,600,700\n"), "{stored}");
    let predicted = specgp(
        &["sample", "M.TOML@0,0", "--dirs", "dirs.csv", "--out", "-"],
        d,
    );
    assert!(predicted.starts_with("400,500,600,700\n"), "{predicted}");
    let info = specgp(&["info", "M.TOML"], d);
    assert!(info.contains("(model)"), "{info}");
}

#[test]
fn model_log_likelihood_matches_recomputation_from_export() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    for (transform, model_name) in [("raw", "raw.toml"), ("log", "log.toml")] {
        specgp(
            &[
                "fit",
                "data.sbrdf",
                "--out",
                model_name,
                "--transform",
                transform,
                "--latent-dim",
                "3",
            ],
            d,
        );
    }
    specgp(
        &["export", "data.sbrdf", "--out", "y.npy", "--dtype", "f64"],
        d,
    );
    let y = read(d.join("y.npy")).unwrap();
    let NpyData::F64(values) = y.data else {
        panic!("expected f64 export")
    };
    let (n, cols) = (y.shape[0], y.shape[1]);

    for model_name in ["raw.toml", "log.toml"] {
        let model = Model::load(&d.join(model_name)).unwrap();
        assert_eq!(model.materials.len(), n);
        let grid: AngularGrid = model.dataset.grid.parse().unwrap();
        let nc = model.dataset.channels.len();
        let mask = grid.validity_mask();
        let keep: Vec<usize> = (0..cols).filter(|&j| mask[j / nc]).collect();
        assert_eq!(keep.len(), model.dataset.d_effective);
        // Transform (restated here with the standard library: raw, or ln(1 + max(f, 0) / c)),
        // centre over materials, and scale to unit average variance (the fit's default data
        // scaling), all recomputed from the export; the model's recorded scale must agree.
        let forward = |v: f64| match model.transform {
            gplvm::Transform::Raw => v,
            gplvm::Transform::Log { offset } => (v.max(0.0) / offset).ln_1p(),
        };
        let mut yt = Mat::<f64>::zeros(n, keep.len());
        for (c, &j) in keep.iter().enumerate() {
            let col: Vec<f64> = (0..n).map(|i| forward(values[i * cols + j])).collect();
            let mean = col.iter().sum::<f64>() / n as f64;
            for i in 0..n {
                yt[(i, c)] = col[i] - mean;
            }
        }
        let scale = yt.squared_norm_l2() / (n * keep.len()) as f64;
        assert!(
            (scale - model.data_scale).abs() <= 1e-10 * scale,
            "{model_name}: data scale {} vs recomputed {scale}",
            model.data_scale
        );
        let yt = Mat::from_fn(n, keep.len(), |i, c| yt[(i, c)] / scale.sqrt());
        let h = &model.hyperparameters;
        let params =
            KernelParams::isotropic(h.signal_variance, h.length_scale[0], h.noise).unwrap();
        let x = model.latent_matrix();
        let direct = gp_core::log_likelihood_from_data(
            yt.as_ref(),
            x.as_ref(),
            &params,
            model.prior,
            Par::Seq,
        )
        .unwrap();
        let rel = (direct - model.fit.log_likelihood).abs() / direct.abs();
        assert!(
            rel < 1e-8,
            "{model_name}: model {} vs recomputed {direct} (relative {rel:e})",
            model.fit.log_likelihood
        );
        assert!(model.fit.log_likelihood > model.fit.initial_log_likelihood);

        let json: serde_json::Value =
            serde_json::from_str(&specgp(&["latent", model_name, "--json"], d)).unwrap();
        let first = &json["materials"][0];
        assert_eq!(first["name"], model.materials[0].name.as_str());
        assert_eq!(
            first["coords"][2].as_f64().unwrap(),
            model.materials[0].coords[2]
        );

        // `info MODEL` (CLI.md: `info DATA.sbrdf|MODEL`): the fit's record, no Gram matrix.
        let info: serde_json::Value =
            serde_json::from_str(&specgp(&["info", model_name, "--json"], d)).unwrap();
        assert_eq!(info["latent_dim"], 3);
        assert_eq!(
            info["fit"]["log_likelihood"].as_f64().unwrap(),
            model.fit.log_likelihood
        );
        assert_eq!(info["dataset_status"], "present, checksum verified");
        assert_eq!(info["dataset_checksum_verified"], true);
        assert_eq!(info["dataset_intact"], true);
        assert!(info.get("gram").is_none());
        let text = specgp(&["info", model_name], d);
        assert!(
            text.contains("q = 3") && text.contains(&model.materials[0].name),
            "{text}"
        );
    }
}

#[test]
fn fit_errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_specgp"))
        .args(["fit", "missing.sbrdf", "--out", "m.toml"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("missing.sbrdf"), "{err}");
    assert!(!dir.path().join("m.toml").exists());
    std::fs::write(dir.path().join("bad.toml"), "latent_dim = 2\nwhat = 1\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_specgp"))
        .args([
            "fit",
            "missing.sbrdf",
            "--out",
            "m.toml",
            "--config",
            "bad.toml",
        ])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.toml") && err.contains("what"), "{err}");
    // A bad value (not a parse error) names the configuration file too.
    std::fs::write(dir.path().join("zero.toml"), "latent_dim = 0\n").unwrap();
    let err = specgp_fails(
        &[
            "fit",
            "missing.sbrdf",
            "--out",
            "m.toml",
            "--config",
            "zero.toml",
        ],
        dir.path(),
    );
    assert!(
        err.contains("zero.toml") && err.contains("latent_dim = 0: must be in 1..=64"),
        "{err}"
    );
    // A negative flag value is the fit's error, not clap's advice to write `-- -1e-4`.
    for (flag, value, says) in [
        (
            "--noise",
            "-1e-4",
            "noise = -0.0001: must be finite and > 0",
        ),
        (
            "--lengthscale",
            "-1",
            "lengthscale = -1: must be finite and > 0",
        ),
    ] {
        let args = ["fit", "missing.sbrdf", "--out", "m.toml", flag, value];
        let err = specgp_fails(&args, dir.path());
        assert!(err.contains(says), "{err}");
    }
    // A dataset path the model file cannot record (not UTF-8) is refused before the fit.
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let bad = std::ffi::OsStr::from_bytes(b"bad\xff.sbrdf");
        std::fs::write(dir.path().join(bad), b"not read").unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_specgp"))
            .arg("fit")
            .arg(bad)
            .args(["--out", "m.toml"])
            .current_dir(dir.path())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("not valid UTF-8"),
            "{err}"
        );
        assert!(!dir.path().join("m.toml").exists());
    }
}

/// RGBA pixels of an 8-bit PNG.
fn png_rgba(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn lazy_renders_of_model_points_read_an_existing_sidecar() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:20");
    let model = Model::load(&d.join("m.toml")).unwrap();
    assert_ne!(
        model.transform,
        gplvm::Transform::Raw,
        "the default fit is log"
    );
    let point = "m.toml@0.1,-0.2";
    // A small map with 2 x 2 thumbnails, and `extra` arguments.
    let map = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "map",
            "m.toml",
            "--thumbnails",
            "--grid",
            "2",
            "--thumbnail-size",
            "32",
            "--size",
            "160",
            "--out",
            out,
        ];
        args.extend_from_slice(extra);
        specgp(&args, d);
        png_rgba(&d.join(out))
    };
    let renders = |tag: &str| {
        let sphere = format!("sphere-{tag}.png");
        specgp(&["render", point, "--size", "40", "--out", &sphere], d);
        (
            png_rgba(&d.join(sphere)),
            map(&format!("map-{tag}.png"), &[]),
        )
    };
    let before = renders("plain");
    // Build the sidecar (stored f32 log values instead of logarithms per lookup).
    let predict_with_sidecar = [
        "predict",
        "m.toml",
        "--at",
        "0,0",
        "--sidecar",
        "--out",
        "p.npy",
    ];
    specgp(&predict_with_sidecar, d);
    let sidecar: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.starts_with("data.sbrdf.") && n.ends_with(".sbrdf"))
        .collect();
    assert_eq!(sidecar.len(), 1, "{sidecar:?}");
    let after = renders("sidecar");
    // The same pictures (to one 8-bit step: the sidecar rounds log values to f32), and real
    // ones: the sphere is covered and coloured, the map has its thumbnails.
    for ((w0, h0, a), (w1, h1, b)) in [(&before.0, &after.0), (&before.1, &after.1)] {
        assert_eq!((w0, h0), (w1, h1));
        let worst = a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
        assert!(worst <= 1, "max 8-bit difference {worst}");
    }
    // Studio thumbnails: the same panel under a sky over a dark floor, so other pixels.
    let (w, h, studio) = map("map-studio.png", &["--env", "studio"]);
    assert_eq!((w, h), (after.1.0, after.1.1));
    let changed = studio
        .chunks(4)
        .zip(after.1.2.chunks(4))
        .filter(|(a, b)| a.iter().zip(*b).any(|(x, y)| x.abs_diff(*y) > 8))
        .count();
    assert!(
        changed > 500,
        "{changed} pixels differ from the uniform environment's thumbnails"
    );
    let sphere = &after.0.2;
    let covered = sphere.chunks(4).filter(|p| p[3] == 255).count();
    assert!(
        covered > 900 && covered < 1257,
        "{covered} opaque pixels of 40 x 40"
    );
    assert!(
        sphere
            .chunks(4)
            .any(|p| p[3] == 255 && p[0].max(p[1]).max(p[2]) > 20)
    );
    // Proof the sidecar is read: a damaged one is named in a warning, for both commands,
    // which then read the dataset store (the pictures without a sidecar, exactly) ...
    std::fs::write(d.join(&sidecar[0]), b"not a store").unwrap();
    for args in [
        &[
            "render",
            point,
            "--size",
            "40",
            "--out",
            "sphere-damaged.png",
        ][..],
        &["map", "m.toml", "--thumbnails", "--out", "y.png"],
    ] {
        let (_, err) = specgp_outputs(args, d);
        assert!(
            err.contains(&sidecar[0]) && err.contains("unusable"),
            "{args:?}: {err}"
        );
    }
    assert_eq!(png_rgba(&d.join("sphere-damaged.png")), before.0);
    // ... and `predict --sidecar` rebuilds it, after which both read it again.
    let (_, err) = specgp_outputs(&predict_with_sidecar, d);
    assert!(err.contains("rebuilding"), "{err}");
    // Which sidecar a command reads is logged with -v, not printed on every run.
    let (_, err) = specgp_outputs(&["render", point, "--out", "x.png"], d);
    assert!(!err.contains("sidecar"), "{err}");
    let (_, err) = specgp_outputs(&["render", point, "--out", "x.png", "-v"], d);
    assert!(
        err.contains("reading the sidecar") && !err.contains("unusable"),
        "{err}"
    );
    // `predict --sidecar` says which sidecar it reads, as the other commands do (it said
    // nothing about an existing one) ...
    let side = d.join(&sidecar[0]).display().to_string();
    let (_, err) = specgp_outputs(&predict_with_sidecar, d);
    assert!(!err.contains("reading the sidecar"), "{err}");
    let verbose: Vec<&str> = predict_with_sidecar.iter().copied().chain(["-v"]).collect();
    let (_, err) = specgp_outputs(&verbose, d);
    assert!(
        err.contains(&format!("reading the sidecar {side}")),
        "{err}"
    );
    // ... and a sidecar that opens but holds NaN (lookups do not re-hash its payload) stops
    // every command that reads it with an error naming the file.
    let mut bytes = std::fs::read(d.join(&sidecar[0])).unwrap();
    let payload = 4096..4096 + (bytes.len() - 4096) / 2;
    bytes[payload].fill(0xff);
    std::fs::write(d.join(&sidecar[0]), bytes).unwrap();
    std::fs::write(d.join("normal.csv"), "0,0,1,0,0,1\n").unwrap();
    for args in [
        &predict_with_sidecar[..],
        &["render", point, "--out", "nan.png"],
        &["sample", point, "--dirs", "normal.csv", "--out", "nan.csv"],
    ] {
        let err = specgp_fails(args, d);
        let error = err.lines().find(|l| l.starts_with("error: ")).unwrap_or("");
        assert!(
            error.contains(&format!("{side}: material ")) && error.contains("NaN"),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn an_output_that_is_an_input_is_refused_and_the_input_kept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    let before = std::fs::read(d.join("data.sbrdf")).unwrap();
    for args in [
        &["fit", "data.sbrdf", "--out", "data.sbrdf"][..],
        &["export", "data.sbrdf", "--out", "./data.sbrdf"],
        &["render", "data.sbrdf:paper_white", "--out", "data.sbrdf"],
        &["convert", "data.sbrdf:paper_white", "--out", "data.sbrdf"],
        &[
            "sample",
            "data.sbrdf:paper_white",
            "--dirs",
            "dirs.csv",
            "--out",
            "data.sbrdf",
        ],
    ] {
        let err = specgp_fails(args, d);
        assert!(err.contains("replace the input"), "{args:?}: {err}");
    }
    assert_eq!(std::fs::read(d.join("data.sbrdf")).unwrap(), before);
    // `sample`'s directions are an input too.
    std::fs::write(d.join("dirs.csv"), "0,0,1,0,0,1\n").unwrap();
    let err = specgp_fails(
        &[
            "sample",
            "data.sbrdf:paper_white",
            "--dirs",
            "dirs.csv",
            "--out",
            "dirs.csv",
        ],
        d,
    );
    assert!(err.contains("the output is the input dirs.csv"), "{err}");
    assert_eq!(
        std::fs::read_to_string(d.join("dirs.csv")).unwrap(),
        "0,0,1,0,0,1\n"
    );
    // A model brings its dataset (and the dataset's sidecar) along: no output may replace
    // them, nor the model itself (`evaluate --json`).
    specgp(&["fit", "data.sbrdf", "--out", "m.toml"], d);
    let model = std::fs::read(d.join("m.toml")).unwrap();
    for args in [
        &["evaluate", "m.toml", "--json", "m.toml"][..],
        &["evaluate", "m.toml", "--json", "data.sbrdf"],
        &["predict", "m.toml", "--at", "0,0", "--out", "data.sbrdf"],
        &[
            "predict",
            "m.toml",
            "--at",
            "0,0",
            "--out",
            "data.sbrdf.log-0.01.sbrdf",
        ],
        &["map", "m.toml", "--out", "./data.sbrdf"],
        &["render", "m.toml@0,0", "--out", "data.sbrdf"],
    ] {
        let err = specgp_fails(args, d);
        assert!(err.contains("replace the input"), "{args:?}: {err}");
    }
    assert_eq!(std::fs::read(d.join("data.sbrdf")).unwrap(), before);
    assert_eq!(std::fs::read(d.join("m.toml")).unwrap(), model);
}

#[test]
fn sample_writes_csv_to_stdout_with_a_dash() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    std::fs::write(d.join("dirs.csv"), "0,0,1,0,0,1\n0.6,0,0.8,0,0,1\n").unwrap();
    // `specgp sample data.sbrdf:paper_white --dirs dirs.csv --out OUT [extra...]`.
    let args = |out: &'static str, extra: &[&'static str]| {
        let mut a = vec![
            "sample",
            "data.sbrdf:paper_white",
            "--dirs",
            "dirs.csv",
            "--out",
            out,
        ];
        a.extend_from_slice(extra);
        a
    };
    let stdout = specgp(&args("-", &[]), d);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 3, "{stdout}");
    assert_eq!(lines[0], "400,500,600,700");
    let white: Vec<f64> = lines[1].split(',').map(|v| v.parse().unwrap()).collect();
    // A white paper at normal incidence: a few tenths per steradian in every channel.
    assert!(white.iter().all(|v| *v > 0.05 && *v < 1.0), "{white:?}");
    assert!(!d.join("-").exists());
    // The same values as through a file.
    specgp(&args("v.csv", &[]), d);
    assert_eq!(std::fs::read_to_string(d.join("v.csv")).unwrap(), stdout);
    // Scaled vectors are read as their directions (the same values), with a warning.
    std::fs::write(d.join("long.csv"), "0,0,2,0,0,1\n1.2,0,1.6,0,0,3\n").unwrap();
    let (scaled, err) = specgp_outputs(
        &[
            "sample",
            "data.sbrdf:paper_white",
            "--dirs",
            "long.csv",
            "--out",
            "-",
        ],
        d,
    );
    let near = |a: &str, b: &str| {
        a.split(',')
            .zip(b.split(','))
            .all(|(x, y)| (x.parse::<f64>().unwrap() - y.parse::<f64>().unwrap()).abs() < 1e-9)
    };
    assert!(
        scaled
            .lines()
            .zip(stdout.lines())
            .skip(1)
            .all(|(a, b)| near(a, b)),
        "{scaled} vs {stdout}"
    );
    assert!(
        err.contains("long.csv: 2 of 2 direction pairs are not unit vectors (the first at line 1)"),
        "{err}"
    );
    assert!(
        !specgp_outputs(&args("-", &[]), d)
            .1
            .contains("unit vectors")
    );
    // At chosen wavelengths: linear interpolation between the stored ones.
    let chosen = specgp(&args("-", &["--wavelengths", "450,700"]), d);
    let lines: Vec<&str> = chosen.lines().collect();
    assert_eq!(lines[0], "450,700");
    let at: Vec<f64> = lines[1].split(',').map(|v| v.parse().unwrap()).collect();
    assert!(
        (at[0] - 0.5 * (white[0] + white[1])).abs() <= 1e-12 * white[0],
        "{at:?} {white:?}"
    );
    assert_eq!(at[1], white[3]);
    let err = specgp_fails(&args("-", &["--wavelengths", "380"]), d);
    assert!(
        err.contains("data.sbrdf") && err.contains("380 nm is outside"),
        "{err}"
    );
}

/// `SPECGP_PAGING` chooses how stores are paged in from the disk: lookups, renders, fits and
/// materialised predictions give the same bytes whichever is chosen, and a value that is not
/// one of the three is refused naming the variable and the store.
#[test]
fn store_paging_from_the_environment_changes_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:100");
    std::fs::write(d.join("dirs.csv"), "0,0,1,0,0,1\n0.6,0,0.8,0.1,0.2,0.97\n").unwrap();
    let with = |paging: &str, args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_specgp"))
            .args(args)
            .current_dir(d)
            .env("SPECGP_PAGING", paging)
            .output()
            .expect("run specgp")
    };
    let commands: [&[&str]; 4] = [
        &[
            "sample",
            "m.toml@0.1,-0.2",
            "--dirs",
            "dirs.csv",
            "--out",
            "-",
        ],
        &[
            "render",
            "m.toml@0.1,-0.2",
            "--size",
            "32",
            "--out",
            "s.png",
        ],
        &["fit", "data.sbrdf", "--out", "f.toml", "--latent-dim", "2"],
        &["predict", "m.toml", "--at", "0.1,-0.2", "--out", "p.npy"],
    ];
    let outputs = |paging: &str| -> Vec<Vec<u8>> {
        let mut all = Vec::new();
        for args in commands {
            let out = with(paging, args);
            assert!(out.status.success(), "{paging} {args:?}: {out:?}");
            all.push(out.stdout);
        }
        for file in ["s.png", "p.npy"] {
            all.push(std::fs::read(d.join(file)).unwrap());
        }
        let model = std::fs::read_to_string(d.join("f.toml")).unwrap();
        // Everything but the timings.
        let fit: Vec<&str> = model.lines().filter(|l| !l.contains("seconds")).collect();
        all.push(fit.join("\n").into_bytes());
        all
    };
    let on_demand = outputs("on-demand");
    assert_eq!(on_demand, outputs("read-around"));
    assert_eq!(on_demand, outputs("auto"));
    let out = with("random", commands[0]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("SPECGP_PAGING=\"random\"") && err.contains("data.sbrdf"),
        "{err}"
    );
}

/// A store damaged after it was written is refused by the commands that read all of it
/// (`export`, `fit`) instead of leaving as wrong numbers or a model that records the checksum
/// of other data; nothing is written.
#[test]
fn damaged_stores_are_refused_by_export_and_fit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    specgp(
        &[
            "fit",
            "data.sbrdf",
            "--latent-dim",
            "2",
            "--out",
            "good.toml",
        ],
        d,
    );
    let mut bytes = std::fs::read(d.join("data.sbrdf")).unwrap();
    bytes[4096 + 1001] ^= 0x40;
    std::fs::write(d.join("data.sbrdf"), bytes).unwrap();
    for (args, out) in [
        (&["export", "data.sbrdf", "--out", "y.npy"][..], "y.npy"),
        (&["fit", "data.sbrdf", "--out", "m.toml"], "m.toml"),
    ] {
        let e = specgp_fails(args, d);
        assert!(e.contains("data.sbrdf") && e.contains("checksum"), "{e}");
        assert!(!d.join(out).exists());
    }
    // `info MODEL` re-hashes its dataset as `info STORE` does (it compared the header's
    // recorded checksum only, and said "checksum matches"): the summary, then exit 1.
    for (args, status) in [
        (&["info", "data.sbrdf"][..], "(MISMATCH)"),
        (
            &["info", "good.toml"],
            "(present, checksum MISMATCH: its payload is damaged)",
        ),
    ] {
        let out = run(args, d);
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr),
        );
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stdout.contains(status), "{args:?}: {stdout}");
        assert!(
            stderr.contains("data.sbrdf: checksum mismatch: header says"),
            "{args:?}: {stderr}"
        );
    }
    let out = run(&["info", "good.toml", "--json"], d);
    assert_eq!(out.status.code(), Some(1));
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(info["dataset_checksum_verified"], false);
    assert_eq!(info["dataset_intact"], false);
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("the dataset of model good.toml"),
        "{out:?}"
    );
}

/// `info MODEL` on a model whose dataset was replaced (intact, other data) or removed: the
/// summary says so, the JSON's `dataset_checksum_verified` is false (it said true for a
/// replaced one, whose checksum is not the model's) and the exit status is 0 (only a damaged
/// dataset fails the command); `predict` refuses the replaced one.
#[test]
fn info_model_reports_a_replaced_or_missing_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    specgp(
        &["fit", "data.sbrdf", "--latent-dim", "2", "--out", "m.toml"],
        d,
    );
    let replaced = [
        "synth",
        "--out",
        "data.sbrdf",
        "--grid",
        "8,8,16",
        "--wavelengths",
        "400:700:100",
        "--seed",
        "3",
    ];
    specgp(&replaced, d);
    let out = run(&["info", "m.toml", "--json"], d);
    assert_eq!(out.status.code(), Some(0), "{out:?}");
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        info["dataset_status"],
        "present, DIFFERENT checksum (refitted or replaced?)"
    );
    assert_eq!(info["dataset_checksum_verified"], false);
    assert_eq!(info["dataset_intact"], true);
    let e = specgp_fails(&["predict", "m.toml", "--at", "0,0", "--out", "p.npy"], d);
    assert!(e.contains("checksum"), "{e}");
    std::fs::remove_file(d.join("data.sbrdf")).unwrap();
    let out = run(&["info", "m.toml", "--json"], d);
    assert_eq!(out.status.code(), Some(0), "{out:?}");
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        info["dataset_status"]
            .as_str()
            .unwrap()
            .starts_with("not usable: "),
        "{info}"
    );
    assert_eq!(info["dataset_checksum_verified"], false);
    assert_eq!(info["dataset_intact"], serde_json::Value::Null);
}

/// Runs the shell command `script` in `dir` with `$SPECGP` set to the binary: its status.
#[cfg(unix)]
fn shell(script: &str, dir: &Path) -> std::process::ExitStatus {
    Command::new("sh")
        .arg("-c")
        .arg(script)
        .env("SPECGP", env!("CARGO_BIN_EXE_specgp"))
        .current_dir(dir)
        .status()
        .expect("run sh")
}

/// `--out -` writes to standard output as the shell opened it: what the shell wrote before
/// and after stays, `>>` appends (it used to follow /dev/stdout to the file and rename a new
/// file over it, losing both). Writers that seek (`export`) need `> file` at its start, and
/// refuse anything else without touching the file.
#[cfg(unix)]
#[test]
fn dash_outputs_write_into_redirected_standard_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    std::fs::write(d.join("dirs.csv"), "0,0,1,0,0,1\n").unwrap();
    specgp(
        &[
            "sample",
            "data.sbrdf:paper_white",
            "--dirs",
            "dirs.csv",
            "--out",
            "v.csv",
        ],
        d,
    );
    let csv = std::fs::read_to_string(d.join("v.csv")).unwrap();
    let sample = r#""$SPECGP" sample data.sbrdf:paper_white --dirs dirs.csv --out -"#;
    assert!(
        shell(
            &format!("{{ echo BEFORE; {sample}; echo AFTER; }} > f.txt"),
            d
        )
        .success()
    );
    assert_eq!(
        std::fs::read_to_string(d.join("f.txt")).unwrap(),
        format!("BEFORE\n{csv}AFTER\n")
    );
    std::fs::write(d.join("a.txt"), "OLD\n").unwrap();
    assert!(shell(&format!("{sample} >> a.txt"), d).success());
    assert_eq!(
        std::fs::read_to_string(d.join("a.txt")).unwrap(),
        format!("OLD\n{csv}")
    );
    // Seeking writers: `> file` gives the same bytes as a file output ...
    specgp(&["export", "data.sbrdf", "--out", "e.npy"], d);
    let npy = std::fs::read(d.join("e.npy")).unwrap();
    let export = r#""$SPECGP" export data.sbrdf --out -"#;
    assert!(shell(&format!("{export} > s.npy"), d).success());
    assert_eq!(std::fs::read(d.join("s.npy")).unwrap(), npy);
    // ... appending or writing after other output is refused, and the file is kept.
    std::fs::write(d.join("b.txt"), "OLD\n").unwrap();
    assert!(!shell(&format!("{export} >> b.txt 2> err.txt"), d).success());
    assert!(!shell(&format!("{{ echo X; {export}; }} > c.txt 2>> err.txt"), d).success());
    assert_eq!(std::fs::read_to_string(d.join("b.txt")).unwrap(), "OLD\n");
    assert_eq!(std::fs::read_to_string(d.join("c.txt")).unwrap(), "X\n");
    let err = std::fs::read_to_string(d.join("err.txt")).unwrap();
    assert_eq!(err.matches("<standard output>").count(), 2, "{err}");
    // Streaming outputs of other commands go to standard output too (no file named `-`).
    specgp(&["fit", "data.sbrdf", "--out", "m.toml"], d);
    // A predicted material's name holds commas (its latent point): export selects it whole,
    // alone or in a list.
    specgp(
        &[
            "predict",
            "m.toml",
            "--at",
            "0.1,0.2,0,0,0",
            "--out",
            "p.sbrdf",
        ],
        d,
    );
    let name = brdf_io::store::Store::open(d.join("p.sbrdf"))
        .unwrap()
        .names()[0]
        .to_owned();
    assert!(name.contains(','), "{name}");
    specgp(
        &["export", "p.sbrdf", "--materials", &name, "--out", "p.npy"],
        d,
    );
    let list = format!("{name},{name}");
    specgp(
        &["export", "p.sbrdf", "--materials", &list, "--out", "p2.npy"],
        d,
    );
    assert_eq!(read(d.join("p2.npy")).unwrap().shape[0], 2);
    // `predict --out -` writes the .npy a file output holds, and says its size.
    specgp(
        &[
            "predict",
            "m.toml",
            "--at",
            "0.1,0.2,0,0,0",
            "--out",
            "q.npy",
        ],
        d,
    );
    let predict = r#""$SPECGP" predict m.toml --at 0.1,0.2,0,0,0 --out -"#;
    assert!(shell(&format!("{predict} > q2.npy 2> perr.txt"), d).success());
    let q = std::fs::read(d.join("q.npy")).unwrap();
    assert_eq!(std::fs::read(d.join("q2.npy")).unwrap(), q);
    let perr = std::fs::read_to_string(d.join("perr.txt")).unwrap();
    assert!(perr.contains(&format!("{} bytes", q.len())), "{perr}");
    // `--variance` prints on standard error then (it went into the .npy's bytes).
    assert!(shell(&format!("{predict} --variance > q3.npy 2> perr.txt"), d).success());
    assert_eq!(std::fs::read(d.join("q3.npy")).unwrap(), q);
    let perr = std::fs::read_to_string(d.join("perr.txt")).unwrap();
    assert!(perr.starts_with("variance "), "{perr}");
    let (json, table) = specgp_outputs(&["evaluate", "m.toml", "--json", "-"], d);
    let v: serde_json::Value = serde_json::from_str(&json).expect("standard output is the JSON");
    assert_eq!(v["n_materials"], 51, "{json}");
    // The table (on standard error here) gives every material's RMSE, as the JSON does.
    let rows = v["reconstruction"].as_array().unwrap();
    assert_eq!(rows.len(), 51);
    for r in rows {
        let name = r["name"].as_str().unwrap();
        let line = (table.lines())
            .find(|l| l.split_whitespace().next() == Some(name))
            .unwrap_or_else(|| panic!("no row for {name}: {table}"));
        let field = |k: usize| -> f64 { line.split_whitespace().nth(k).unwrap().parse().unwrap() };
        for (k, key) in [(1, "exact_rmse"), (2, "smooth_rmse")] {
            let want = r[key].as_f64().unwrap();
            assert!(
                (field(k) - want).abs() <= 1e-5 * want.abs(),
                "{key}: {line}"
            );
        }
    }
    assert!(!d.join("-").exists());
}

/// A reader that closes the pipe early (`| head`) is not an error, for outputs written through
/// brdf-io as for printed ones (`sample --out -` and `convert --out -` exited 1 with "Broken
/// pipe").
#[cfg(unix)]
#[test]
fn a_closed_output_pipe_is_not_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    let rows = "0.3,0,0.954,-0.3,0,0.954\n".repeat(50_000);
    std::fs::write(d.join("dirs.csv"), rows).unwrap();
    for command in [
        r#""$SPECGP" sample data.sbrdf:paper_white --dirs dirs.csv --out -"#,
        r#""$SPECGP" convert data.sbrdf:paper_white --out -"#,
    ] {
        // The shell's exit status is the command's (`head` closes the pipe after 10 bytes).
        let script = format!("{command} 2> err.txt > fifo & head -c 10 fifo > /dev/null; wait $!");
        std::fs::remove_file(d.join("fifo")).ok();
        assert!(
            Command::new("mkfifo")
                .arg(d.join("fifo"))
                .status()
                .unwrap()
                .success()
        );
        let status = shell(&script, d);
        let err = std::fs::read_to_string(d.join("err.txt")).unwrap();
        assert!(
            status.success() && !err.contains("error"),
            "{command}: {status} {err}"
        );
    }
}

/// Where a spawned command's standard output or error goes ([`run_into`]).
#[cfg(unix)]
#[derive(Clone, Copy, Debug, PartialEq)]
enum Sink {
    /// A pipe whose reader is closed before the command starts (`| head -0`).
    Closed,
    /// `/dev/full`: every write fails with ENOSPC.
    Full,
    /// Captured, returned in the output.
    Captured,
}

#[cfg(unix)]
impl Sink {
    fn stdio(self) -> std::process::Stdio {
        match self {
            Sink::Closed => {
                let (reader, writer) = std::io::pipe().unwrap();
                drop(reader);
                writer.into()
            }
            Sink::Full => std::fs::OpenOptions::new()
                .write(true)
                .open("/dev/full")
                .unwrap()
                .into(),
            Sink::Captured => std::process::Stdio::piped(),
        }
    }
}

/// Runs `specgp args` in `dir` with standard output into `stdout` and standard error into
/// `stderr`.
#[cfg(unix)]
fn run_into(args: &[&str], dir: &Path, stdout: Sink, stderr: Sink) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_specgp"))
        .args(args)
        .current_dir(dir)
        .stdout(stdout.stdio())
        .stderr(stderr.stdio())
        .output()
        .expect("run specgp")
}

/// Printed tables, reports and warnings never panic nor cost an output file: standard output
/// closed by its reader ends the printing quietly (exit 0) after every requested file is
/// written, standard output on a full disk fails the command (exit 1, saying so) after they are
/// written, and standard error closed or full is ignored (`println!`/`eprintln!` panicked with
/// exit 101; `evaluate`/`locate --json` lost the JSON behind a closed pipe, `import` its store).
#[cfg(unix)]
#[test]
fn unwritable_standard_streams_neither_panic_nor_lose_outputs() {
    use Sink::{Captured, Closed, Full};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:100");
    let read = |name: &str| std::fs::read(d.join(name)).unwrap();
    // Reference outputs with both streams working.
    let predict = |out: &'static str| {
        [
            "predict",
            "m.toml",
            "--at",
            "0.1,-0.2",
            "--variance",
            "--out",
            out,
        ]
    };
    let variance = specgp(&predict("ref.npy"), d);
    assert!(variance.starts_with("variance "), "{variance}");
    // The share of the prior variance, in (0, 100] % between materials.
    let share: f64 = variance
        .split(" % of the prior variance")
        .next()
        .and_then(|head| head.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{variance}"));
    assert!(share > 0.0 && share <= 100.0, "{variance}");
    specgp(&["evaluate", "m.toml", "--json", "ref-ev.json"], d);
    let locate = |json: &'static str| ["locate", "m.toml", "data.sbrdf:metal_gold", "--json", json];
    specgp(&locate("ref-loc.json"), d);
    let ref_loc: serde_json::Value = serde_json::from_slice(&read("ref-loc.json")).unwrap();
    assert_eq!(ref_loc["locations"][0]["name"], "metal_gold");

    // Standard output closed or full: the files are written all the same.
    for (sink, code) in [(Closed, 0), (Full, 1)] {
        let expect = |args: &[&str], out: &std::process::Output| {
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(code), "{args:?} {sink:?}: {err}");
            if sink == Full {
                assert!(
                    err.contains("error: writing to standard output: No space left on device"),
                    "{args:?}: {err}"
                );
            } else {
                assert!(!err.contains("error"), "{args:?}: {err}");
            }
        };
        let args = ["grid", "--grid", "8,8,16"];
        expect(&args, &run_into(&args, d, sink, Captured));
        let args = predict("p.npy");
        std::fs::remove_file(d.join("p.npy")).ok();
        expect(&args, &run_into(&args, d, sink, Captured));
        assert_eq!(read("p.npy"), read("ref.npy"), "{sink:?}");
        let args = ["evaluate", "m.toml", "--json", "ev.json"];
        std::fs::remove_file(d.join("ev.json")).ok();
        expect(&args, &run_into(&args, d, sink, Captured));
        let (ev, want): (serde_json::Value, serde_json::Value) = (
            serde_json::from_slice(&read("ev.json")).unwrap(),
            serde_json::from_slice(&read("ref-ev.json")).unwrap(),
        );
        assert_eq!(ev["n_materials"], 51);
        assert_eq!(ev["summary"], want["summary"], "{sink:?}");
        let args = locate("loc.json");
        std::fs::remove_file(d.join("loc.json")).ok();
        expect(&args, &run_into(&args, d, sink, Captured));
        let loc: serde_json::Value = serde_json::from_slice(&read("loc.json")).unwrap();
        assert_eq!(loc["locations"], ref_loc["locations"], "{sink:?}");
        for args in [&["latent", "m.toml"][..], &["info", "m.toml"]] {
            expect(args, &run_into(args, d, sink, Captured));
        }
    }

    // Standard error closed or full: the work is done, the exit code is the command's.
    specgp(
        &[
            "convert",
            "data.sbrdf:paper_white",
            "--theta-samples",
            "4",
            "--resolution",
            "8",
            "--out",
            "a.bsdf",
        ],
        d,
    );
    for sink in [Closed, Full] {
        let outputs = ["r.sbrdf", "s.sbrdf", "f.toml", "q.npy", "b.bsdf", "far.png"];
        for name in outputs {
            std::fs::remove_file(d.join(name)).ok();
        }
        for args in [
            &[
                "import", "rgl", "a.bsdf", "--grid", "4,4,8", "--out", "r.sbrdf",
            ][..],
            &[
                "synth",
                "--grid",
                "4,4,8",
                "--wavelengths",
                "500,600",
                "--out",
                "s.sbrdf",
            ],
            &["fit", "data.sbrdf", "--latent-dim", "2", "--out", "f.toml"],
            &["predict", "m.toml", "--at", "0.1,-0.2", "--out", "q.npy"],
            &[
                "convert",
                "a.bsdf",
                "--theta-samples",
                "4",
                "--resolution",
                "8",
                "--out",
                "b.bsdf",
            ],
            // A tracing warning (far from every material), at -v with info logs too.
            &[
                "render",
                "m.toml@40,40",
                "--size",
                "16",
                "-v",
                "--out",
                "far.png",
            ],
        ] {
            let out = run_into(args, d, Captured, sink);
            assert_eq!(out.status.code(), Some(0), "{args:?} {sink:?}");
        }
        assert_eq!(read("q.npy"), read("ref.npy"), "{sink:?}");
        let store = brdf_io::store::Store::open(d.join("r.sbrdf")).unwrap();
        assert_eq!(store.names(), ["a"]);
        store.verify_checksum().unwrap();
        assert_eq!(Model::load(&d.join("f.toml")).unwrap().latent_dim, 2);
        for name in outputs {
            assert!(d.join(name).is_file(), "{name} {sink:?}");
        }
        // An error with its message lost still exits 1, not 101.
        let out = run_into(&["info", "nonexistent.sbrdf"], d, Captured, sink);
        assert_eq!(out.status.code(), Some(1), "{sink:?}");
    }
}

/// `specgp grid` describes a grid: its cells, those above the horizon (the mask every store
/// uses), channels, D = cells x channels and the f32 bytes of one material; RGB without
/// `--wavelengths`.
#[test]
fn grid_describes_cells_channels_and_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let grid: AngularGrid = "8,8,16".parse().unwrap();
    let valid = grid.validity_mask().iter().filter(|v| **v).count();
    assert!(valid > 0 && valid < 1024, "{valid}");
    let percent = format!("{:.1}", 100.0 * valid as f64 / 1024.0);
    for (wavelengths, channels) in [(Some("400:700:100"), 4), (None, 3)] {
        let mut args = vec!["grid", "--grid", "8,8,16"];
        args.extend(wavelengths.iter().flat_map(|w| ["--wavelengths", *w]));
        let text = specgp(&args, d);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines,
            [
                "grid           8,8,16".to_string(),
                "angular cells  1024".to_string(),
                format!("above horizon  {valid} ({percent} %)"),
                format!("channels       {channels}"),
                format!("D              {}", 1024 * channels),
                format!("bytes (f32)    {}", 4096 * channels),
            ],
            "{text}"
        );
    }
}

/// `-v` logs each command's start and end (info), `-vv` its arguments too (debug); without
/// either only warnings show.
#[test]
fn verbosity_flags_choose_the_log_level() {
    let dir = tempfile::tempdir().unwrap();
    let stderr = |flags: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_specgp"))
            .args(["grid", "--grid", "8,8,16"])
            .args(flags)
            .env_remove("SPECGP_LOG")
            .current_dir(dir.path())
            .output()
            .expect("run specgp");
        assert!(out.status.success());
        String::from_utf8(out.stderr).unwrap()
    };
    assert_eq!(stderr(&[]), "");
    let info = stderr(&["-v"]);
    assert!(
        info.contains("grid: start") && info.contains("grid: done") && !info.contains("arguments"),
        "{info}"
    );
    let debug = stderr(&["-vv"]);
    assert!(
        debug.contains("grid: start") && debug.contains("arguments"),
        "{debug}"
    );
}

/// `--help` and `--version` exit 0, also into a pipe closed by its reader; into a full disk
/// they fail (exit 1, saying so); a usage error exits 1.
#[cfg(unix)]
#[test]
fn help_into_unwritable_standard_output() {
    use Sink::{Captured, Closed, Full};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for flag in ["--help", "--version"] {
        let ok = run_into(&[flag], d, Captured, Captured);
        assert_eq!(ok.status.code(), Some(0), "{flag}");
        assert!(!ok.stdout.is_empty() && ok.stderr.is_empty(), "{flag}");
        let closed = run_into(&[flag], d, Closed, Captured);
        assert_eq!(closed.status.code(), Some(0), "{flag}");
        assert!(closed.stderr.is_empty(), "{flag}");
        let full = run_into(&[flag], d, Full, Captured);
        let err = String::from_utf8_lossy(&full.stderr);
        assert_eq!(full.status.code(), Some(1), "{flag}: {err}");
        assert!(
            err.contains("error: writing to standard output: No space left on device"),
            "{flag}: {err}"
        );
    }
    let usage = run_into(&["grid", "--nope"], d, Captured, Captured);
    assert_eq!(usage.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&usage.stderr).contains("--nope"));
}

/// `predict` warns about a point far from every material, giving the distance to the nearest
/// (exponent notation from 1e6 length-scales on), and `--variance` gives the share of the prior
/// variance to three digits; `locate` warns about a target whose point is far from every
/// training material, and only about it: the data mean (the prediction at a point far away)
/// is reconstructed best far out, a training material at its own point.
#[test]
fn far_points_and_variances_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:100");
    let distance = |at: &str| {
        let (_, err) = specgp_outputs(&["predict", "m.toml", "--at", at, "--out", "p.npy"], d);
        let head = err
            .split(" length-scales away")
            .next()
            .filter(|h| h.contains(&format!("latent point {at} is far from every material")))
            .unwrap_or_else(|| panic!("{err}"));
        head.rsplit(' ').next().unwrap().to_owned()
    };
    let near = distance("50,50");
    assert!(
        !near.contains('e')
            && near.split('.').nth(1).is_some_and(|f| f.len() == 1)
            && near.parse::<f64>().is_ok_and(|v| v > 10.0),
        "{near}"
    );
    let typo = distance("1e100,0");
    assert!(
        typo.contains('e') && typo.parse::<f64>().is_ok_and(|v| v > 1e90),
        "{typo}"
    );
    // The library's numbers: per transformed value (data units) and as a share, to three
    // digits, between materials (~1 %) and next to one (below 0.1 %).
    let pred = predict::Predictor::open(&d.join("m.toml")).unwrap();
    let next_to = pred.model().materials[0]
        .coords
        .iter()
        .map(|c| c + 1e-3)
        .collect();
    for x in [vec![0.1, 0.1], next_to] {
        let at = x.iter().map(f64::to_string).collect::<Vec<_>>().join(",");
        let args = [
            "predict",
            "m.toml",
            "--at",
            &at,
            "--variance",
            "--out",
            "p.npy",
        ];
        let (variance, err) = specgp_outputs(&args, d);
        assert!(!err.contains("negative"), "{err}");
        let v = pred.variance_of(&x, predict::PredictorKind::Exact).unwrap();
        let per_value = v * pred.model().data_scale;
        assert!(
            variance.starts_with(&format!("variance {per_value:e} per transformed value")),
            "{variance}"
        );
        let share = variance
            .split(" % of the prior variance")
            .next()
            .and_then(|h| h.rsplit(' ').next())
            .unwrap_or_else(|| panic!("{variance}"));
        let digits = share.trim_start_matches(['0', '.']).replace('.', "");
        let want = 100.0 * v / pred.prior_variance();
        let shown: f64 = share.parse().unwrap();
        assert!(
            digits.len() == 3 && (shown - want).abs() <= 5e-3 * want,
            "{variance}: {want}"
        );
    }
    // A log model without a sidecar reads its dataset store, without a word.
    let (_, err) = specgp_outputs(&["render", "m.toml@0.5,0.5", "--out", "r.png"], d);
    assert_eq!(err, "");
    specgp(
        &["predict", "m.toml", "--at", "50,50", "--out", "far.sbrdf"],
        d,
    );
    let (table, err) = specgp_outputs(
        &[
            "locate",
            "m.toml",
            "far.sbrdf",
            "data.sbrdf:metal_gold",
            "--json",
            "l.json",
        ],
        d,
    );
    let json = json_file(&d.join("l.json"));
    let (far, gold) = (&json["locations"][0], &json["locations"][1]);
    assert_eq!(far["name"], "gp-exact@50,50");
    assert!(far["variance_fraction"].as_f64().unwrap() > 0.99, "{far}");
    assert_eq!(gold["name"], "metal_gold");
    assert!(gold["variance_fraction"].as_f64().unwrap() < 0.1, "{gold}");
    let warnings: Vec<&str> = err.lines().filter(|l| l.contains("warning")).collect();
    assert_eq!(warnings.len(), 1, "{err}");
    assert!(
        warnings[0].starts_with("warning: gp-exact@50,50 lies far from every training material"),
        "{err}"
    );
    assert!(table.contains("metal_gold"), "{table}");
}

/// Binary outputs (`--out -`) are refused when standard output is a terminal (run under
/// `script`, which gives the command a pseudo-terminal), before any work; CSV text is written.
#[cfg(target_os = "linux")]
#[test]
fn binary_outputs_are_refused_on_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // `script -qec CMD /dev/null` runs CMD on a new pseudo-terminal, its exit status its own.
    let on_terminal = |command: &str| {
        let out = Command::new("script")
            .args(["-qec", command, "/dev/null"])
            .env("SPECGP", env!("CARGO_BIN_EXE_specgp"))
            .current_dir(d)
            .output()
            .expect("run script (util-linux)");
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        (out.status.code(), text)
    };
    if on_terminal("true").0 != Some(0) {
        eprintln!("skipped: no pseudo-terminal for `script` here");
        return;
    }
    fitted_small(d, "400:700:100");
    for (args, what) in [
        ("convert data.sbrdf:paper_white", "an RGL tensor file"),
        ("export data.sbrdf", "an .npy array"),
        ("predict m.toml --at 0,0", "a predicted material"),
        ("render data.sbrdf:paper_white", "a PNG image"),
        ("map m.toml", "a PNG image"),
    ] {
        let (code, text) = on_terminal(&format!(r#""$SPECGP" {args} --out -"#));
        assert_eq!(code, Some(1), "{args}: {text}");
        assert!(
            text.contains(&format!(
                "refusing to write {what} (binary data) to the terminal"
            )),
            "{args}: {text}"
        );
    }
    std::fs::write(d.join("dirs.csv"), "0,0,1,0,0,1\n").unwrap();
    let (code, text) =
        on_terminal(r#""$SPECGP" sample data.sbrdf:paper_white --dirs dirs.csv --out -"#);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.starts_with("400,500,600,700"), "{text}");
}

/// `convert` writes the sizes it is given (no refinement when either is given, with a warning
/// when the check fails) and says how many negative source values it clamped: a raw-value
/// model's prediction has some, a stored material none.
#[test]
fn convert_keeps_given_sizes_and_reports_clamped_negatives() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    let sized = |source: &str, out: &str| {
        let args = ["convert", source, "--theta-samples", "8", "--out", out];
        specgp_outputs(&args, d).1
    };
    let gold = sized("data.sbrdf:metal_gold", "gold.bsdf");
    assert!(
        gold.contains("(8 incident elevations, 32 x 32 values each")
            && gold.contains(
                "warning: the check error is above --tolerance 0.05 with the sizes given"
            )
            && !gold.contains("negative"),
        "{gold}"
    );
    specgp(
        &[
            "fit",
            "data.sbrdf",
            "--out",
            "raw.toml",
            "--latent-dim",
            "2",
            "--transform",
            "raw",
        ],
        d,
    );
    // `predict` counts them too.
    let (_, err) = specgp_outputs(
        &["predict", "raw.toml", "--at", "0.5,0.5", "--out", "raw.npy"],
        d,
    );
    let count = err.lines().find_map(|l| {
        let warning = l.strip_prefix("warning: ")?;
        warning
            .split(" predicted values are negative")
            .next()?
            .parse::<u64>()
            .ok()
    });
    assert!(
        count.is_some_and(|n| n > 0)
            && err.contains("the GP mean is not constrained to be non-negative"),
        "{err}"
    );
    let raw = sized("raw.toml@0.5,0.5", "raw.bsdf");
    let negative = raw
        .lines()
        .filter_map(|l| l.strip_prefix("warning: "))
        .find(|l| l.contains("source values are negative (stored as 0"))
        .and_then(|l| l.split(' ').next())
        .and_then(|n| n.parse::<u64>().ok());
    assert!(negative.is_some_and(|n| n > 0), "{raw}");
}

/// `render`'s --exposure (stops) and --env reach the renderer, and `map` draws the space of a
/// one-dimensional model, thumbnails too.
#[test]
fn render_options_and_one_dimensional_maps() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    let sphere = |out: &str, extra: &[&str]| {
        let mut args = vec!["render", "data.sbrdf:acrylic_felt_green", "--size", "32"];
        args.extend(extra);
        args.extend(["--out", out]);
        specgp(&args, d);
        let (w, h, rgba) = png_rgba(&d.join(out));
        assert_eq!((w, h), (32, 32));
        rgba
    };
    // The mean 8-bit level of the sphere's opaque pixels.
    let mean = |rgba: &[u8]| {
        let inside: Vec<&[u8]> = rgba.chunks(4).filter(|p| p[3] == 255).collect();
        let sum: u64 = inside
            .iter()
            .flat_map(|p| &p[..3])
            .map(|&v| u64::from(v))
            .sum();
        sum as f64 / (3 * inside.len()) as f64
    };
    let plain = sphere("e0.png", &[]);
    let brighter = sphere("e1.png", &["--exposure", "1"]);
    // One stop doubles linear values: 1.37x in sRGB codes where nothing clips.
    let ratio = mean(&brighter) / mean(&plain);
    assert!(ratio > 1.25 && ratio < 1.5, "{ratio}");
    let studio = sphere("s.png", &["--env", "studio"]);
    assert_ne!(studio, plain);
    specgp(
        &[
            "fit",
            "data.sbrdf",
            "--latent-dim",
            "1",
            "--out",
            "one.toml",
        ],
        d,
    );
    let map = |extra: &[&str]| {
        let mut args = vec!["map", "one.toml", "--out", "one.png"];
        args.extend(extra);
        specgp(&args, d);
        let (w, h, _) = png_rgba(&d.join("one.png"));
        (w, h)
    };
    let (w, h) = map(&["--thumbnails"]);
    assert!(w > 640 && h > 640, "{w} x {h}");
    // --size sets the plot's side (the margins stay), --thumbnail-size the thumbnails'.
    let (w0, h0) = map(&[]);
    assert_eq!(map(&["--size", "400"]), (w0 - 240, h0 - 240));
    let (small, _) = map(&["--thumbnails", "--thumbnail-size", "16"]);
    assert!(small < w, "{small} vs {w}");
}

/// `synth --dtype --zstd` write the store as asked, with the default store's values to f16
/// precision.
#[test]
fn synth_store_options_reach_the_store() {
    use brdf_io::store::{Compression, Dtype, Store};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    let args = [
        "synth",
        "--out",
        "h.sbrdf",
        "--grid",
        "8,8,16",
        "--wavelengths",
        "400:700:100",
        "--dtype",
        "f16",
        "--zstd",
        "3",
    ];
    specgp(&args, d);
    let (plain, half) = (
        Store::open(d.join("data.sbrdf")).unwrap(),
        Store::open(d.join("h.sbrdf")).unwrap(),
    );
    let layout = &half.header().layout;
    assert_eq!(
        (layout.dtype, layout.compression),
        (Dtype::F16, Compression::Zstd { level: 3 })
    );
    assert_eq!(plain.header().layout.dtype, Dtype::F32);
    let (a, b) = (first_material(&plain), first_material(&half));
    assert!(
        a.iter()
            .zip(&b)
            .all(|(x, y)| (x - y).abs() <= 1e-3 * x.abs()),
        "{a:?} {b:?}"
    );
}

/// `import nbrdf` and `import rgl` on the real shared data; a network whose outputs overflow
/// (weights scaled by 1e30) is an error naming it, and no store is written.
#[test]
fn imports_of_real_data_and_a_broken_network() {
    let Some(shared) = shared_data::path("nbrdf").map(|_| shared_data::root()) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let weights = read(shared.join("nbrdf/merl_nbrdf_weights_675.npy")).unwrap();
    assert_eq!(weights.shape[1], 675);
    let rows: Vec<f64> = match &weights.data {
        NpyData::F32(v) => v[..2 * 675].iter().map(|&x| f64::from(x)).collect(),
        NpyData::F64(v) => v[..2 * 675].to_vec(),
    };
    let names = std::fs::read_to_string(shared.join("nbrdf/merl_nbrdf_names.txt")).unwrap();
    let names: Vec<&str> = names.lines().take(2).collect();
    std::fs::write(d.join("names.txt"), names.join("\n") + "\n").unwrap();
    let write_npy = |path: &str, values: &[f64]| {
        let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 675), }";
        let mut header = dict.to_owned();
        while !(10 + header.len() + 1).is_multiple_of(64) {
            header.push(' ');
        }
        header.push('\n');
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        values
            .iter()
            .for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
        std::fs::write(d.join(path), bytes).unwrap();
    };
    write_npy("good.npy", &rows);
    let import = |w: &'static str, out: &'static str| {
        vec![
            "import",
            "nbrdf",
            w,
            "--names",
            "names.txt",
            "--grid",
            "8,8,16",
            "--out",
            out,
        ]
    };
    specgp(&import("good.npy", "good.sbrdf"), d);
    let store = brdf_io::store::Store::open(d.join("good.sbrdf")).unwrap();
    assert_eq!(store.n_materials(), 2);
    assert_eq!(store.names()[0], names[0]);
    let mut broken = rows.clone();
    broken[675..].iter_mut().for_each(|v| *v *= 1e30);
    write_npy("broken.npy", &broken);
    let e = specgp_fails(&import("broken.npy", "broken.sbrdf"), d);
    assert!(e.contains("NaN or infinite") && e.contains(names[1]), "{e}");
    assert!(!d.join("broken.sbrdf").exists());
    // Names are checked before any network is evaluated (a control character in the last
    // name was found after all of them), and --only suggests a near name.
    std::fs::write(d.join("bad-names.txt"), format!("{}\nx\u{7}y\n", names[0])).unwrap();
    let mut bad = import("good.npy", "bad.sbrdf");
    bad[4] = "bad-names.txt";
    let e = specgp_fails(&bad, d);
    assert!(
        e.contains("bad-names.txt line 2") && e.contains("control character"),
        "{e}"
    );
    let mut only = import("good.npy", "only.sbrdf");
    let typo = &names[0][..names[0].len() - 1];
    only.extend(["--only", typo]);
    let e = specgp_fails(&only, d);
    assert!(
        e.contains(&format!(
            "no material named {typo:?}; did you mean {:?}?",
            names[0]
        )),
        "{e}"
    );
    assert!(!d.join("bad.sbrdf").exists() && !d.join("only.sbrdf").exists());
    // A real RGL file through `import rgl`.
    let bsdf = shared.join("rgl-rgb/paper_white_rgb.bsdf");
    let bsdf = bsdf.to_str().unwrap();
    // A SOURCE's extension in any case; a special file as output whatever its name.
    std::fs::copy(bsdf, d.join("PW.BSDF")).unwrap();
    std::fs::write(d.join("dirs1.csv"), "0.3,0,0.954,-0.3,0,0.954\n").unwrap();
    let sample = |source: &str, out: &str| {
        specgp(&["sample", source, "--dirs", "dirs1.csv", "--out", out], d);
    };
    sample("PW.BSDF", "pw.csv");
    sample(bsdf, "pw-lower.csv");
    assert_eq!(
        std::fs::read(d.join("pw.csv")).unwrap(),
        std::fs::read(d.join("pw-lower.csv")).unwrap()
    );
    #[cfg(unix)]
    sample("PW.BSDF", "/dev/null");
    let (_, err) = specgp_outputs(
        &[
            "import",
            "rgl",
            bsdf,
            "--grid",
            "8,8,16",
            "--out",
            "rgl.sbrdf",
        ],
        d,
    );
    let store = brdf_io::store::Store::open(d.join("rgl.sbrdf")).unwrap();
    assert_eq!(store.names(), ["paper_white_rgb"]);
    // One material is "1 material" (it was "1 materials").
    assert!(
        err.contains("wrote rgl.sbrdf: 1 material, grid 8,8,16, 3 channels, D = "),
        "{err}"
    );
    // Both file formats store the reciprocal mean of each bin by default, and report the
    // non-reciprocal part it removes; not with --no-reciprocal.
    let rgl = [
        "import", "rgl", bsdf, "--grid", "8,8,16", "--out", "nr.sbrdf",
    ];
    let nbrdf = import("good.npy", "nr.sbrdf");
    for command in [&rgl[..], &nbrdf] {
        let reports = |extra: &[&str]| {
            let args: Vec<&str> = command.iter().chain(extra).copied().collect();
            specgp_outputs(&args, d).1
        };
        let (with, without) = (reports(&[]), reports(&["--no-reciprocal"]));
        assert!(with.contains("non-reciprocal part: median"), "{with}");
        assert!(!without.contains("non-reciprocal"), "{without}");
    }
    // The store options of every import format: value type, compression, chunk length; the
    // values read back as the default store's to f16 precision.
    use brdf_io::store::{Compression, Dtype};
    for (options, dtype, compression, chunk_len) in [
        (&[][..], Dtype::F32, Compression::None, 3072),
        (
            &[
                "--dtype",
                "f16",
                "--zstd",
                "3",
                "--shuffle",
                "--chunk-len",
                "100",
            ][..],
            Dtype::F16,
            Compression::ZstdShuffle { level: 3 },
            100,
        ),
        (
            &["--zstd", "5"][..],
            Dtype::F32,
            Compression::Zstd { level: 5 },
            3072,
        ),
    ] {
        let mut args = vec![
            "import", "rgl", bsdf, "--grid", "8,8,16", "--out", "o.sbrdf",
        ];
        args.extend(options);
        specgp(&args, d);
        let other = brdf_io::store::Store::open(d.join("o.sbrdf")).unwrap();
        let layout = &other.header().layout;
        assert_eq!(
            (layout.dtype, layout.compression, layout.chunk_len),
            (dtype, compression, chunk_len),
            "{options:?}"
        );
        let (a, b) = (first_material(&store), first_material(&other));
        assert!(
            a.iter()
                .zip(&b)
                .all(|(x, y)| (x - y).abs() <= 1e-3 * x.abs() + 1e-7),
            "{options:?}"
        );
    }
}

/// A run ended by SIGTERM or SIGINT removes its temporary output and exits with 128 + the
/// signal's number, as a shell reports it (SIGTERM exited with SIGINT's 130).
#[test]
fn interrupted_run_removes_its_temporary_output() {
    use std::time::{Duration, Instant};
    for (signal, code) in [("TERM", 143), ("INT", 130)] {
        let dir = tempfile::tempdir().unwrap();
        let temporaries = || -> Vec<String> {
            std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(".data.sbrdf.") && n.ends_with(".tmp"))
                .collect()
        };
        // The default grid: large enough that the run is still writing when the signal arrives.
        let mut child = Command::new(env!("CARGO_BIN_EXE_specgp"))
            .args(["synth", "--out", "data.sbrdf"])
            .current_dir(dir.path())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let start = Instant::now();
        while temporaries().is_empty() {
            assert!(
                child.try_wait().unwrap().is_none(),
                "synth ended before its output appeared"
            );
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "no temporary file"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        let killed = Command::new("kill")
            .args([&format!("-{signal}"), &child.id().to_string()])
            .status()
            .unwrap();
        assert!(killed.success());
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "SIG{signal}: {stderr}");
        assert!(
            stderr.contains("interrupted; removed 1 unfinished output file(s)"),
            "SIG{signal}: {stderr}"
        );
        assert_eq!(temporaries(), Vec::<String>::new());
        assert!(!dir.path().join("data.sbrdf").exists());
    }
}

/// `predict --out x.binary` writes a standard MERL file (90 x 90 x 180, what `BRDFRead.cpp`
/// accepts) from a model on another grid, and `sample` reads it.
#[test]
fn merl_output_of_a_coarse_model_is_on_merls_grid() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:50");
    let (_, said) = specgp_outputs(
        &["predict", "m.toml", "--at", "0,0", "--out", "x.binary"],
        d,
    );
    assert!(
        said.contains(&format!("{} values", 3 * 90 * 90 * 180)),
        "{said}"
    );
    let merl = brdf_io::merl::read_merl(d.join("x.binary")).unwrap();
    assert_eq!(merl.grid(), &AngularGrid::MERL);
    let bytes = std::fs::metadata(d.join("x.binary")).unwrap().len();
    assert_eq!(bytes, 12 + 24 * 90 * 90 * 180);
    let above: Vec<usize> = (0..AngularGrid::MERL.len())
        .filter(|&a| AngularGrid::MERL.bin_centre_flat(a).is_above_horizon())
        .collect();
    // Every MERL cell above the horizon holds a colour, except those whose interpolation reads
    // only coarse cells below the horizon (they hold 0 in the dataset). (Single channels may be
    // 0: out-of-gamut colours are clamped.)
    let coarse = AngularGrid::new(8, 8, 16).unwrap();
    let black: Vec<usize> = above
        .iter()
        .copied()
        .filter(|&a| (0..3).all(|c| merl.value(c, a) <= 0.0))
        .collect();
    let unseen: Vec<usize> = above
        .iter()
        .copied()
        .filter(|&a| {
            coarse
                .interpolation_stencil(&AngularGrid::MERL.bin_centre_flat(a))
                .iter()
                .all(|&(c, w)| w == 0.0 || !coarse.bin_centre_flat(c).is_above_horizon())
        })
        .collect();
    assert_eq!(black, unseen);
    assert!(
        black.len() * 1000 < above.len(),
        "{} black cells",
        black.len()
    );
    // Imported back; a MERL file of nothing but "not measured" (negative) samples imports as
    // a black material, with a warning (only a count said so).
    let (_, said) = specgp_outputs(
        &[
            "import", "merl", "x.binary", "--grid", "8,8,16", "--out", "x.sbrdf",
        ],
        d,
    );
    assert!(!said.contains("warning"), "{said}");
    // Bin averages by default, the nearest MERL cell with `--resampling nearest`: the
    // library's resampling of the file either way.
    specgp(
        &[
            "import",
            "merl",
            "x.binary",
            "--grid",
            "8,8,16",
            "--resampling",
            "nearest",
            "--out",
            "xn.sbrdf",
        ],
        d,
    );
    use brdf_io::merl::Resampling;
    for (store, method) in [
        ("x.sbrdf", Resampling::Average),
        ("xn.sbrdf", Resampling::Nearest),
    ] {
        let store = brdf_io::store::Store::open(d.join(store)).unwrap();
        let values = first_material(&store);
        assert!(values == merl.resample(&coarse, method).0, "{method:?}");
    }
    assert_ne!(
        merl.resample(&coarse, Resampling::Average).0,
        merl.resample(&coarse, Resampling::Nearest).0
    );
    let mut bytes = std::fs::read(d.join("x.binary")).unwrap();
    for v in bytes[12..].chunks_exact_mut(8) {
        v.copy_from_slice(&(-1.0f64).to_le_bytes());
    }
    std::fs::write(d.join("none.binary"), bytes).unwrap();
    let (_, said) = specgp_outputs(
        &[
            "import",
            "merl",
            "none.binary",
            "--grid",
            "8,8,16",
            "--out",
            "none.sbrdf",
        ],
        d,
    );
    assert!(
        said.contains("warning: none (none.binary): every stored value is 0"),
        "{said}"
    );
    std::fs::write(d.join("dirs.csv"), "0.3,0,0.954,-0.3,0,0.954\n").unwrap();
    let csv = specgp(
        &["sample", "x.binary", "--dirs", "dirs.csv", "--out", "-"],
        d,
    );
    let row: Vec<f64> = csv
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert!(row.len() == 3 && row.iter().all(|v| *v > 0.0), "{csv}");
}

/// `predict --out x.bsdf` and `convert SOURCE --out x.bsdf` write RGL files (the format
/// Mitsuba 3 and pbrt-v4 render) that read back as the source: a prediction written either way
/// gives the same bytes, and a stored material's file matches the stored values.
#[test]
fn rgl_files_of_predictions_and_stored_materials_read_back_as_their_source() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:50");
    let small = ["--theta-samples", "12", "--resolution", "16"];
    let (_, said) = specgp_outputs(
        &[
            &["predict", "m.toml", "--at", "0.1,-0.2", "--out", "p.bsdf"],
            &small[..],
        ]
        .concat(),
        d,
    );
    assert!(
        said.contains("as an RGL BSDF (12 incident elevations, 16 x 16 values each, 7 wavelengths")
            && said.contains("% cos-weighted RMS error at 4096 direction pairs"),
        "{said}"
    );
    specgp(
        &[
            &["convert", "m.toml@0.1,-0.2", "--out", "q.bsdf"],
            &small[..],
        ]
        .concat(),
        d,
    );
    // The description names the source as given; every other field is the same.
    let fields = |f: &str| {
        let tf = brdf_io::tensor::TensorFile::open(d.join(f)).unwrap();
        let (text, rest): (Vec<_>, Vec<_>) = tf
            .fields()
            .iter()
            .cloned()
            .partition(|f| f.name() == "description");
        (text[0].to_text().unwrap(), rest)
    };
    let ((p_text, p), (q_text, q)) = (fields("p.bsdf"), fields("q.bsdf"));
    assert_eq!(p, q);
    assert_eq!(q_text, "m.toml@0.1,-0.2");
    assert!(p_text.contains("0.1") && p_text != q_text, "{p_text}");
    let bsdf = brdf_io::rgl::RglBsdf::open(d.join("p.bsdf")).unwrap();
    assert_eq!(bsdf.channels().len(), 7);
    let (_, err) = specgp_outputs(&["convert", "data.sbrdf:metal_gold", "--out", "g.bsdf"], d);
    assert!(!err.contains("warning"), "{err}");
    // Sizes given too small: written as asked, with a warning (there was none).
    let tiny = [
        "convert",
        "data.sbrdf:metal_gold",
        "--theta-samples",
        "2",
        "--resolution",
        "2",
        "--out",
        "tiny.bsdf",
    ];
    let (_, err) = specgp_outputs(&tiny, d);
    assert!(
        err.contains(
            "warning: the check error is above --tolerance 0.05 with the sizes given \
                      (--theta-samples 2 --resolution 2)"
        ),
        "{err}"
    );
    let info = specgp(&["info", "p.bsdf"], d);
    assert!(
        info.contains("theta_i        12 (degrees: 0.0, ")
            && info.contains("value tables   16 x 16 per incident elevation")
            && info.contains("channels       7 (400,450,500,550,600,650,700)"),
        "{info}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&specgp(&["info", "g.bsdf", "--json"], d)).unwrap();
    assert_eq!(json["description"], "data.sbrdf:metal_gold");
    assert_eq!(json["theta_i_degrees"].as_array().unwrap().len(), 32);
    // Near the mirror direction, off it, and towards grazing.
    let dirs =
        "0.3,0,0.954,-0.3,0.01,0.954\n0.5,0.1,0.86,0.2,-0.6,0.775\n0.1,0,0.995,-0.8,0.3,0.52\n";
    std::fs::write(d.join("dirs.csv"), dirs).unwrap();
    let values = |source: &str| -> Vec<f64> {
        specgp(&["sample", source, "--dirs", "dirs.csv", "--out", "-"], d)
            .lines()
            .skip(1)
            .flat_map(|l| {
                l.split(',')
                    .map(|v| v.parse::<f64>().unwrap())
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let (stored, file) = (values("data.sbrdf:metal_gold"), values("g.bsdf"));
    for (k, (a, b)) in stored.iter().zip(&file).enumerate() {
        // Measured: 0.5-3 % (the file interpolates between its sample points).
        assert!((a - b).abs() <= 0.05 * a, "value {k}: stored {a}, file {b}");
    }
    for (args, says) in [
        (
            vec!["convert", "data.sbrdf:metal_gold", "--out", "g.png"],
            "must end in .bsdf",
        ),
        (
            vec![
                "convert",
                "data.sbrdf:metal_gold",
                "--out",
                "h.bsdf",
                "--resolution",
                "1",
            ],
            "resolution 1 must be in 2..=1024",
        ),
        (
            vec!["convert", "data.sbrdf", "--out", "h.bsdf"],
            "name one of its materials",
        ),
        (
            vec![
                "predict",
                "m.toml",
                "--at",
                "0,0",
                "--out",
                "h.npy",
                "--resolution",
                "16",
            ],
            "--resolution applies to a `.bsdf` output, not to h.npy",
        ),
        (
            vec![
                "convert",
                "data.sbrdf:metal_gold",
                "--out",
                "h.bsdf",
                "--resolution",
                "64",
                "--tolerance",
                "0.01",
            ],
            "cannot be used with",
        ),
    ] {
        let err = specgp_fails(&args, d);
        assert!(err.contains(says), "{args:?}: {err}");
    }
    assert!(!d.join("h.bsdf").exists());
}

/// A fit that stops at its iteration cap says so (it is not converged); a converged one does
/// not; `--max-iterations` sets the cap.
#[test]
fn fits_stopped_at_their_cap_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:50");
    let (_, said) = specgp_outputs(
        &[
            "fit",
            "data.sbrdf",
            "--out",
            "c.toml",
            "--max-iterations",
            "5",
        ],
        d,
    );
    assert!(
        said.contains("stopped at its cap (reached 5 iterations)")
            && said.contains("raise max_iterations"),
        "{said}"
    );
    assert_eq!(
        Model::load(&d.join("c.toml")).unwrap().fit.stop_reason,
        "reached 5 iterations"
    );
    let (_, said) = specgp_outputs(
        &[
            "fit",
            "data.sbrdf",
            "--out",
            "f.toml",
            "--max-iterations",
            "100000",
        ],
        d,
    );
    assert!(!said.contains("stopped at its cap"), "{said}");
    let stop = Model::load(&d.join("f.toml")).unwrap().fit.stop_reason;
    assert!(!stop.starts_with("reached"), "{stop}");
    // Leave-one-out refits at their cap say whose refit it was.
    let (table, said) = specgp_outputs(
        &[
            "evaluate",
            "f.toml",
            "--loo",
            "--cold",
            "--refit-iterations",
            "2",
            "--json",
            "loo.json",
        ],
        d,
    );
    assert!(
        said.contains("leave-one-out{held_out=paper_white}: the optimiser stopped at its cap"),
        "{said}"
    );
    // Each material's row of the table shows its own leave-one-out errors.
    let json = json_file(&d.join("loo.json"));
    let rows = json["loo"].as_array().unwrap();
    assert_eq!(rows.len(), 51);
    for row in rows {
        let name = row["name"].as_str().unwrap();
        let line = table
            .lines()
            .find(|l| l.split_whitespace().next() == Some(name))
            .unwrap_or_else(|| panic!("{name}: {table}"));
        let shown: Vec<f64> = line
            .split_whitespace()
            .skip(3)
            .map(|v| v.parse().unwrap())
            .collect();
        let methods = row["methods"].as_array().unwrap();
        assert_eq!(shown.len(), methods.len(), "{line}");
        for (v, m) in shown.iter().zip(methods) {
            let want = m["brdf_rmse"].as_f64().unwrap();
            assert!((v - want).abs() <= 1e-5 * want, "{name}: {line} vs {m}");
        }
    }
}

/// Fits that cannot make a latent space say why: a noise at least the signal variance (it
/// "converged" at once without a word), and more latent dimensions than D values span.
#[test]
fn meaningless_fits_are_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    let (_, said) = specgp_outputs(
        &["fit", "data.sbrdf", "--noise", "10", "--out", "n.toml"],
        d,
    );
    assert!(
        said.contains("noise 1e1 is at least the kernel's signal variance s^2 = 1e0"),
        "{said}"
    );
    let (_, said) = specgp_outputs(&["fit", "data.sbrdf", "--out", "ok.toml"], d);
    assert!(
        !said.contains("signal variance") && !said.contains("latent dimension"),
        "{said}"
    );
    let one = [
        "synth",
        "--grid",
        "1,1,1",
        "--wavelengths",
        "500",
        "--out",
        "one.sbrdf",
    ];
    specgp(&one, d);
    let (_, said) = specgp_outputs(
        &["fit", "one.sbrdf", "--latent-dim", "2", "--out", "one.toml"],
        d,
    );
    assert!(
        said.contains("latent dimension q = 2 for N = 51 materials of D = 1 values")
            && said.contains("min(N - 1, D) = 1 dimensions"),
        "{said}"
    );
}

/// Natural mistakes get messages that say how to fix them: a store or a model named without
/// a material or a point, a point with too few coordinates, an unknown material in --lerp.
#[test]
fn source_mistakes_say_how_to_fix_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    specgp(
        &["fit", "data.sbrdf", "--latent-dim", "3", "--out", "m.toml"],
        d,
    );
    let e = specgp_fails(&["render", "data.sbrdf", "--out", "x.png"], d);
    assert!(
        e.contains("data.sbrdf:MATERIAL") && e.contains("metal_gold"),
        "{e}"
    );
    let e = specgp_fails(&["render", "m.toml", "--out", "x.png"], d);
    assert!(e.contains("m.toml@X1,...,Xq"), "{e}");
    // Negative numbers reach the commands' own checks (clap took them for flags and suggested
    // `-- -30,0`).
    for (args, said) in [
        (
            &[
                "render",
                "data.sbrdf:paper_white",
                "--light",
                "-30,0",
                "--out",
                "x.png",
            ][..],
            "--light \"-30,0\": THETA must be in [0, 180] degrees",
        ),
        (
            &[
                "convert",
                "data.sbrdf:paper_white",
                "--tolerance",
                "-1",
                "--out",
                "x.bsdf",
            ],
            "tolerance -1 must be finite and > 0",
        ),
    ] {
        let e = specgp_fails(args, d);
        assert!(e.contains(said) && !e.contains("tip"), "{e}");
    }
    // A model whose dataset moved: each command names a remedy it has (`render`, `sample` and
    // `convert` have no --dataset, which the message used to suggest).
    let model_text = std::fs::read_to_string(d.join("m.toml")).unwrap();
    let moved: Vec<&str> = model_text
        .lines()
        .map(|l| {
            if l.starts_with("path = ") {
                "path = \"gone.sbrdf\""
            } else {
                l
            }
        })
        .collect();
    std::fs::write(d.join("moved.toml"), moved.join("\n")).unwrap();
    std::fs::write(d.join("one.csv"), "0,0,1,0,0,1\n").unwrap();
    for args in [
        &["render", "moved.toml@0,0,0", "--out", "x.png"][..],
        &[
            "sample",
            "moved.toml@0,0,0",
            "--dirs",
            "one.csv",
            "--out",
            "-",
        ],
        &["convert", "moved.toml@0,0,0", "--out", "x.bsdf"],
    ] {
        let e = specgp_fails(args, d);
        assert!(
            e.contains("gone.sbrdf is not a file")
                && e.contains("set `path` in the model file's [dataset] table")
                && !e.contains("--dataset"),
            "{args:?}: {e}"
        );
    }
    let e = specgp_fails(
        &["predict", "moved.toml", "--at", "0,0,0", "--out", "x.npy"],
        d,
    );
    assert!(e.contains("gone.sbrdf") && e.contains("`--dataset`"), "{e}");
    // An unknown output format names every accepted one (.bsdf was missing), before any work.
    let e = specgp_fails(
        &["predict", "moved.toml", "--at", "0,0,0", "--out", "x.png"],
        d,
    );
    assert!(
        e.contains("x.png: unknown output format: expected a .sbrdf, .npy, .binary or .bsdf file"),
        "{e}"
    );
    let e = specgp_fails(&["render", "m.toml@0.1,0.2", "--out", "x.png"], d);
    assert!(e.contains("give all 3 coordinates, e.g. 0,0,0"), "{e}");
    // An image size out of range is a plain range message, before the source is opened.
    for size in ["0", "8193"] {
        let e = specgp_fails(
            &["render", "nowhere.bsdf", "--size", size, "--out", "x.png"],
            d,
        );
        assert!(
            e.contains(&format!("invalid value '{size}' for '--size <SIZE>'"))
                && e.contains("not in 1..=8192")
                && !e.contains("bytes a pixel"),
            "{e}"
        );
    }
    let e = specgp_fails(&["render", "m.toml@", "--out", "x.png"], d);
    assert!(
        e.contains(
            "m.toml@: no latent point after the '@' of model m.toml: give all 3 coordinates, \
             e.g. m.toml@0,0,0"
        ),
        "{e}"
    );
    let e = specgp_fails(
        &[
            "predict",
            "m.toml",
            "--lerp",
            "metal_gol,paper_white,0.5",
            "--out",
            "x.npy",
        ],
        d,
    );
    assert!(e.contains("it holds: ") && e.contains("metal_gold"), "{e}");
    assert!(e.contains("did you mean \"metal_gold\"?"), "{e}");
    let e = specgp_fails(&["render", "data.sbrdf:metal_gol", "--out", "x.png"], d);
    assert!(e.contains("did you mean \"metal_gold\"?"), "{e}");
    // Options that would be ignored are refused.
    let e = specgp_fails(&["map", "m.toml", "--grid", "3", "--out", "x.png"], d);
    assert!(e.contains("--thumbnails"), "{e}");
    let e = specgp_fails(&["map", "m.toml", "--env", "studio", "--out", "x.png"], d);
    assert!(e.contains("--thumbnails"), "{e}");
    let e = specgp_fails(
        &[
            "map",
            "m.toml",
            "--thumbnails",
            "--env",
            "mc",
            "--out",
            "x.png",
        ],
        d,
    );
    assert!(
        e.contains("expected `table`, `fast`, `per-pixel` or `studio`"),
        "{e}"
    );
    let e = specgp_fails(
        &[
            "render",
            "data.sbrdf:metal_gold",
            "--view",
            "60",
            "--out",
            "x.png",
        ],
        d,
    );
    assert!(e.contains("--view 60 applies to --shape plane"), "{e}");
    assert!(!d.join("x.png").exists() && !d.join("x.npy").exists());
    // A latent point far from every material renders, with a warning saying so; a point
    // between materials does not warn.
    // Very far: numbers with exponents, not a hundred digits.
    let (_, err) = specgp_outputs(
        &[
            "render",
            "m.toml@1e100,-2.5e-7,0",
            "--size",
            "16",
            "--out",
            "far.png",
        ],
        d,
    );
    assert!(
        err.contains("latent point 1e100,-2.5e-7,0 is far from every material")
            && err.contains(", 1.0e100 length-scales away;"),
        "{err}"
    );
    let (_, err) = specgp_outputs(
        &[
            "render",
            "m.toml@40,40,40",
            "--size",
            "16",
            "--out",
            "far.png",
        ],
        d,
    );
    assert!(
        err.contains("latent point 40,40,40 is far from every material")
            && err.contains("close to the mean of the data"),
        "{err}"
    );
    let model = Model::load(&d.join("m.toml")).unwrap();
    let a = &model.materials[0].coords;
    let dist = |c: &Vec<f64>| -> f64 { c.iter().zip(a).map(|(u, v)| (u - v).powi(2)).sum() };
    let neighbour = model.materials[1..]
        .iter()
        .map(|m| &m.coords)
        .min_by(|u, v| dist(u).total_cmp(&dist(v)))
        .unwrap();
    let mid: Vec<String> = a
        .iter()
        .zip(neighbour)
        .map(|(u, v)| format!("{}", 0.5 * (u + v)))
        .collect();
    let at = format!("m.toml@{}", mid.join(","));
    let (_, err) = specgp_outputs(&["render", &at, "--size", "16", "--out", "near.png"], d);
    assert!(!err.contains("far from every"), "{err}");
    // At a training material's own point the exact predictor returns that material, the
    // smooth one (`--smooth`) a slightly smoothed version; `--smooth` needs a model point.
    let own = model.materials[0]
        .coords
        .iter()
        .map(|v| format!("{v}"))
        .collect::<Vec<_>>()
        .join(",");
    let name = model.materials[0].name.clone();
    std::fs::write(
        d.join("dirs.csv"),
        "0,0.6,0.8,0,-0.6,0.8\n0.3,0,0.954,0,0,1\n",
    )
    .unwrap();
    let sample = |src: &str, extra: &[&str]| {
        let mut args = vec!["sample", src, "--dirs", "dirs.csv", "--out", "-"];
        args.extend_from_slice(extra);
        let text = specgp(&args, d);
        text.lines()
            .skip(1)
            .flat_map(|l| {
                l.split(',')
                    .map(|v| v.parse::<f64>().unwrap())
                    .collect::<Vec<_>>()
            })
            .collect::<Vec<_>>()
    };
    let stored = sample(&format!("data.sbrdf:{name}"), &[]);
    let exact = sample(&format!("m.toml@{own}"), &[]);
    let smooth = sample(&format!("m.toml@{own}"), &["--smooth"]);
    let rel = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs() / y.abs().max(1e-12))
            .fold(0.0, f64::max)
    };
    assert!(rel(&exact, &stored) < 1e-5, "{exact:?} vs {stored:?}");
    let moved = rel(&smooth, &stored);
    assert!(moved > 1e-7 && moved < 0.5, "smooth moved by {moved}");
    let e = specgp_fails(
        &[
            "sample",
            &format!("data.sbrdf:{name}"),
            "--dirs",
            "dirs.csv",
            "--smooth",
            "--out",
            "-",
        ],
        d,
    );
    assert!(e.contains("--smooth applies to a model point"), "{e}");
}

/// Options that would be ignored are refused before any work (README): nothing is written.
#[test]
fn ignored_options_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:100");
    // evaluate: the leave-one-out options without --loo.
    for extra in [
        &["--starts", "5"][..],
        &["--cold"],
        &["--refit-iterations", "10"],
    ] {
        let mut args = vec!["evaluate", "m.toml", "--json", "ev.json"];
        args.extend_from_slice(extra);
        let e = specgp_fails(&args, d);
        assert!(e.contains("--loo"), "{extra:?}: {e}");
        assert!(!d.join("ev.json").exists());
    }
    // With --loo they apply (and a plain evaluate still runs with their defaults).
    specgp(
        &[
            "evaluate",
            "m.toml",
            "--loo",
            "--starts",
            "1",
            "--refit-iterations",
            "5",
            "--json",
            "ev.json",
        ],
        d,
    );
    let ev: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("ev.json")).unwrap()).unwrap();
    assert_eq!(ev["n_materials"], 51);
    specgp(&["evaluate", "m.toml"], d);
    // map --dataset without --thumbnails or --locate (the plain map reads no data), even when
    // the store does not exist.
    for dataset in ["data.sbrdf", "missing.sbrdf"] {
        let e = specgp_fails(
            &["map", "m.toml", "--dataset", dataset, "--out", "map.png"],
            d,
        );
        assert!(
            e.contains(&format!(
                "--dataset {dataset} applies to --thumbnails and --locate"
            )),
            "{e}"
        );
        assert!(!d.join("map.png").exists());
    }
    specgp(
        &[
            "map",
            "m.toml",
            "--dataset",
            "data.sbrdf",
            "--locate",
            "data.sbrdf:metal_gold",
            "--size",
            "64",
            "--out",
            "map.png",
        ],
        d,
    );
    assert!(d.join("map.png").is_file());
    // fit: a cap of the other optimiser (L-BFGS counts iterations, Hooke-Jeeves evaluations),
    // whether the optimiser comes from the default, --optimizer or a --config file.
    std::fs::write(d.join("hj.toml"), "optimizer = \"hooke-jeeves\"\n").unwrap();
    for (extra, want) in [
        (
            &["--max-evaluations", "10"][..],
            "--max-evaluations 10 caps the Hooke-Jeeves optimiser, but the fit uses lbfgs (the \
             default)",
        ),
        (
            &["--optimizer", "lbfgs", "--max-evaluations", "10"],
            "uses lbfgs (--optimizer)",
        ),
        (
            &["--optimizer", "hooke-jeeves", "--max-iterations", "5"],
            "--max-iterations 5 caps the L-BFGS optimiser, but the fit uses hooke-jeeves \
             (--optimizer)",
        ),
        (
            &["--config", "hj.toml", "--max-iterations", "5"],
            "uses hooke-jeeves (the --config file hj.toml)",
        ),
    ] {
        let mut args = vec!["fit", "data.sbrdf", "--out", "capped.toml"];
        args.extend_from_slice(extra);
        let e = specgp_fails(&args, d);
        assert!(e.contains(want), "{extra:?}: {e}");
        assert!(!d.join("capped.toml").exists());
    }
    // Each optimiser's own cap applies, and stops it.
    specgp(
        &[
            "fit",
            "data.sbrdf",
            "--out",
            "capped.toml",
            "--config",
            "hj.toml",
            "--latent-dim",
            "2",
            "--max-evaluations",
            "40",
        ],
        d,
    );
    let fit = Model::load(&d.join("capped.toml")).unwrap().fit;
    assert_eq!(fit.stop_reason, "reached 40 evaluations");
    // A seed without restarts would be silently unused: the fit runs (scripts may pass one to
    // every fit) and says so; with restarts it is used, and nothing is said.
    let seeded = |extra: &[&str]| {
        let mut args = vec![
            "fit",
            "data.sbrdf",
            "--out",
            "seeded.toml",
            "--latent-dim",
            "2",
        ];
        args.extend_from_slice(extra);
        specgp_outputs(&args, d).1
    };
    let unused = "--seed 7 has no effect without restarts";
    let e = seeded(&["--seed", "7"]);
    assert!(e.contains(unused), "{e}");
    assert!(d.join("seeded.toml").is_file());
    let e = seeded(&["--seed", "7", "--restarts", "1"]);
    assert!(!e.contains(unused), "{e}");
    assert!(d.join("seeded.toml").is_file());
}

/// Outputs whose name says another format than the one written are refused before any work
/// (as render, export, fit and predict refuse them): sample writes CSV, evaluate and locate
/// --json JSON; `-` is standard output.
#[test]
fn sample_evaluate_and_locate_outputs_must_name_their_format() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fitted_small(d, "400:700:100");
    std::fs::write(d.join("dirs.csv"), "0,0,1,0,0,1\n").unwrap();
    let cases: [(&[&str], &str, &str); 4] = [
        (
            &[
                "sample",
                "data.sbrdf:paper_white",
                "--dirs",
                "dirs.csv",
                "--out",
            ],
            "v.npy",
            "v.npy: the output is a CSV file; its name must end in .csv",
        ),
        (
            &["evaluate", "m.toml", "--json"],
            "e.txt",
            "e.txt: the output is a JSON file; its name must end in .json",
        ),
        (
            &["evaluate", "m.toml", "--json"],
            "e",
            "e: the output is a JSON file; its name must end in .json",
        ),
        (
            &["locate", "m.toml", "data.sbrdf:metal_gold", "--json"],
            "l.csv",
            "l.csv: the output is a JSON file; its name must end in .json",
        ),
    ];
    for (args, bad, want) in cases {
        let mut a = args.to_vec();
        a.push(bad);
        let e = specgp_fails(&a, d);
        assert!(e.contains(want), "{a:?}: {e}");
        assert!(!d.join(bad).exists());
        // The format's own extension, any case, and standard output are written.
        let good = if args[0] == "sample" {
            "v.CSV"
        } else {
            "r.json"
        };
        let mut a = args.to_vec();
        a.push(good);
        specgp(&a, d);
        assert!(d.join(good).is_file());
        let mut a = args.to_vec();
        a.push("-");
        assert!(!specgp(&a, d).is_empty());
    }
    let csv = std::fs::read_to_string(d.join("v.CSV")).unwrap();
    assert!(csv.starts_with("400,500,600,700\n"), "{csv}");
}

/// `predict --lerp NAME1,NAME2,A` reads material names that contain commas (`import` accepts
/// them, `predict` writes `gp-exact@X,Y`) or spaces at their ends; a split with two readings is
/// refused, and --smooth, --exact and --variance, which --lerp would ignore, before any work.
#[test]
fn lerp_reads_names_with_commas() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let names = ["a", "a,b", "b,c", "c", "gp-exact@0.1,0.2", " pad "];
    let rows = rgb_store(&d.join("data.sbrdf"), &names);
    let row = |m: usize| rows[m].clone();
    specgp(
        &[
            "fit",
            "data.sbrdf",
            "--out",
            "m.toml",
            "--transform",
            "raw",
            "--latent-dim",
            "2",
        ],
        d,
    );
    // a y1 + (1 - a) y2 of the named rows (raw values: no transform between).
    let lerp = |spec: &str, i: usize, j: usize, a: f64| {
        std::fs::remove_file(d.join("l.npy")).ok();
        specgp(&["predict", "m.toml", "--lerp", spec, "--out", "l.npy"], d);
        let NpyData::F32(got) = read(d.join("l.npy")).unwrap().data else {
            panic!("expected f32")
        };
        let (y1, y2) = (row(i), row(j));
        for (k, g) in got.iter().enumerate() {
            let want = a * f64::from(y1[k]) + (1.0 - a) * f64::from(y2[k]);
            assert!(
                (f64::from(*g) - want).abs() <= 1e-5 * want.max(1e-3),
                "{spec}: value {k}: {g} vs {want}"
            );
        }
    };
    lerp("gp-exact@0.1,0.2,c,0.25", 4, 3, 0.25);
    lerp("a,b,a,0.75", 1, 0, 0.75);
    lerp(" pad , c , 0.5", 5, 3, 0.5);
    lerp("a, c,1", 0, 3, 1.0);
    // A weight beyond [0, 1] extrapolates below zero; the warning blames the blend, not a GP.
    let (_, err) = specgp_outputs(
        &["predict", "m.toml", "--lerp", "a,c,-5", "--out", "l.npy"],
        d,
    );
    assert!(
        err.contains("values are negative")
            && err.contains("a blend with a weight outside [0, 1]")
            && !err.contains("GP mean"),
        "{err}"
    );
    let e = specgp_fails(
        &["predict", "m.toml", "--lerp", "a,b,c,0.5", "--out", "x.npy"],
        d,
    );
    assert!(
        e.contains("\"a,b,c,0.5\" is ambiguous")
            && e.contains("NAME1 \"a\" and NAME2 \"b,c\"")
            && e.contains("NAME1 \"a,b\" and NAME2 \"c\""),
        "{e}"
    );
    let e = specgp_fails(
        &["predict", "m.toml", "--lerp", "pad,c,0.5", "--out", "x.npy"],
        d,
    );
    assert!(e.contains("did you mean \" pad \"?"), "{e}");
    for flag in ["--smooth", "--exact", "--variance"] {
        let e = specgp_fails(
            &[
                "predict",
                "m.toml",
                "--lerp",
                "a,c,0.5",
                flag,
                "--sidecar",
                "--out",
                "x.npy",
            ],
            d,
        );
        assert!(
            e.contains(&format!(
                "{flag} applies to a latent point (--at), not to --lerp"
            )),
            "{e}"
        );
    }
    // Refused before any work: no output, no sidecar built.
    assert!(!d.join("x.npy").exists());
    assert_eq!(
        std::fs::read_dir(d).unwrap().count(),
        3,
        "data, model, l.npy"
    );
}

/// The JSON document in `path`.
fn json_file(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The D values of a store's first material.
fn first_material(store: &brdf_io::store::Store) -> Vec<f32> {
    let mut values = vec![0f32; store.d()];
    store.material_row(0, 0..store.d(), &mut values).unwrap();
    values
}

/// A store with RGB materials `names` on a 3 x 3 x 4 grid in `path` (values positive above
/// the horizon, different per material).
fn rgb_store(path: &Path, names: &[&str]) -> Vec<Vec<f32>> {
    let info = brdf_io::StoreInfo {
        grid: AngularGrid::new(3, 3, 4).unwrap(),
        channels: brdf_io::Channels::Rgb,
    };
    let mask = info.grid.validity_mask();
    let rows: Vec<Vec<f32>> = (0..names.len())
        .map(|m| {
            (0..info.d())
                .map(|k| {
                    if mask[k / 3] {
                        0.05 + ((m * 37 + k * 11) % 17) as f32 / 10.0
                    } else {
                        0.0
                    }
                })
                .collect()
        })
        .collect();
    let mut w = brdf_io::StoreWriter::create(path, info, brdf_io::StoreOptions::default()).unwrap();
    for (name, row) in names.iter().zip(&rows) {
        w.add_material(name, "test", row).unwrap();
    }
    w.finish().unwrap();
    rows
}

/// `import rgl` of spectral and RGB files together is refused before any file is resampled,
/// naming one file of each kind; so is --wavelengths for RGB files.
#[test]
fn import_rgl_refuses_mixed_spectral_and_rgb_files_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    rgb_store(&d.join("rgb.sbrdf"), &["grey"]);
    let small = ["--theta-samples", "4", "--resolution", "8"];
    for (source, out) in [
        ("data.sbrdf:metal_gold", "gold_spec.bsdf"),
        ("data.sbrdf:paper_white", "paper_spec.bsdf"),
        ("rgb.sbrdf:grey", "grey_rgb.bsdf"),
    ] {
        let mut args = vec!["convert", source, "--out", out];
        args.extend_from_slice(&small);
        specgp(&args, d);
    }
    let import = |files: &[&'static str], extra: &[&'static str]| {
        let mut args = vec!["import", "rgl"];
        args.extend_from_slice(files);
        args.extend_from_slice(&["--grid", "8,8,16", "--out", "mix.sbrdf"]);
        args.extend_from_slice(extra);
        args
    };
    for files in [
        &["gold_spec.bsdf", "paper_spec.bsdf", "grey_rgb.bsdf"][..],
        &["grey_rgb.bsdf", "gold_spec.bsdf"],
    ] {
        let e = specgp_fails(&import(files, &[]), d);
        assert!(
            e.contains(
                "the files mix spectral and RGB data: gold_spec.bsdf is spectral, \
                 grey_rgb.bsdf is RGB"
            ),
            "{e}"
        );
        // Nothing was resampled (no per-material report) nor written.
        assert!(!e.contains("values (min"), "{e}");
        assert!(!d.join("mix.sbrdf").exists());
    }
    let e = specgp_fails(&import(&["grey_rgb.bsdf"], &["--wavelengths", "500"]), d);
    assert!(
        e.contains("grey_rgb.bsdf: RGB data has no wavelengths; leave out --wavelengths"),
        "{e}"
    );
    // A spectral file whose range misses the channels, or a damaged file, is refused before
    // the files in front of it are resampled.
    let narrow = [
        "synth",
        "--out",
        "narrow.sbrdf",
        "--grid",
        "8,8,16",
        "--wavelengths",
        "500:600:100",
    ];
    specgp(&narrow, d);
    let mut args = vec![
        "convert",
        "narrow.sbrdf:metal_gold",
        "--out",
        "narrow_spec.bsdf",
    ];
    args.extend_from_slice(&small);
    specgp(&args, d);
    let gold = std::fs::read(d.join("gold_spec.bsdf")).unwrap();
    std::fs::write(d.join("cut_spec.bsdf"), &gold[..gold.len() / 2]).unwrap();
    for (files, want) in [
        (
            &["gold_spec.bsdf", "paper_spec.bsdf", "narrow_spec.bsdf"][..],
            "narrow_spec.bsdf",
        ),
        (&["gold_spec.bsdf", "cut_spec.bsdf"], "cut_spec.bsdf"),
    ] {
        let e = specgp_fails(&import(files, &[]), d);
        assert!(e.contains(want), "{e}");
        assert!(!e.contains("values (min"), "{e}");
        assert!(!d.join("mix.sbrdf").exists());
    }
    // One kind imports, at the first file's own channels.
    specgp(&import(&["gold_spec.bsdf", "paper_spec.bsdf"], &[]), d);
    let store = brdf_io::store::Store::open(d.join("mix.sbrdf")).unwrap();
    assert_eq!(store.names(), ["gold_spec", "paper_spec"]);
    assert_eq!(store.channels().labels(), ["400", "500", "600", "700"]);
}

/// `import nbrdf --only` with a name twice says so (it blamed a line of the names file), before
/// the network files are read.
#[test]
fn nbrdf_only_with_a_repeated_name_names_the_option() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let e = specgp_fails(
        &[
            "import",
            "nbrdf",
            "weights.npy",
            "--names",
            "names.txt",
            "--only",
            "bluebook, alum-bronze,bluebook",
            "--out",
            "n.sbrdf",
        ],
        d,
    );
    assert!(
        e.contains("--only names \"bluebook\" twice") && !e.contains("names.txt"),
        "{e}"
    );
}

/// A JSON array of numbers as the CLI prints a latent point (`X1,X2,...`, shortest form: plain
/// digits from 1e-4 to 1e6, else an exponent).
fn point_text(point: &serde_json::Value) -> String {
    point
        .as_array()
        .unwrap()
        .iter()
        .map(|v| {
            let v = v.as_f64().unwrap();
            if v == 0.0 || (1e-4..1e6).contains(&v.abs()) {
                v.to_string()
            } else {
                format!("{v:e}")
            }
        })
        .collect::<Vec<_>>()
        .join(",")
}

#[test]
fn locate_places_real_files_and_store_materials_and_explains_mismatches() {
    let Some(rgl) = shared_data::path("rgl-rgb") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let file = |stem: &str| rgl.join(format!("{stem}_rgb.bsdf")).display().to_string();
    let training = [
        "cc_ibiza_sunset",
        "cc_iris_purple_gem",
        "cg_sunflower",
        "colodur_napoli_4f",
        "paper_white",
        "vch_golden_yellow",
    ];
    let mut import = vec!["import".to_owned(), "rgl".to_owned()];
    import.extend(training.iter().map(|s| file(s)));
    import.extend(["--grid", "8,8,16", "--out", "train.sbrdf"].map(String::from));
    specgp(&import.iter().map(String::as_str).collect::<Vec<_>>(), d);
    specgp(
        &["fit", "train.sbrdf", "--out", "m.toml", "--latent-dim", "2"],
        d,
    );
    let new = file("satin_rosaline");
    specgp(
        &[
            "import",
            "rgl",
            &new,
            "--grid",
            "8,8,16",
            "--out",
            "new.sbrdf",
        ],
        d,
    );

    // The file itself and its imported copy are located at the same point with the same
    // errors (locate resamples as `import` does by default); a training material is found at
    // its own point, where the exact predictor returns it.
    let (table, _) = specgp_outputs(&["locate", "m.toml", &new, "--json", "a.json"], d);
    assert!(table.contains("satin_rosaline_rgb"), "{table}");
    // A name longer than the usual column keeps the columns aligned.
    let long = "satin_rosaline_with_a_name_longer_than_the_column_rgb.bsdf";
    std::fs::copy(&new, d.join(long)).unwrap();
    let (table, _) = specgp_outputs(&["locate", "m.toml", long, "--json", "long.json"], d);
    let nearest = serde_json::from_str::<serde_json::Value>(
        &std::fs::read_to_string(d.join("long.json")).unwrap(),
    )
    .unwrap()["locations"][0]["nearest"]
        .as_str()
        .unwrap()
        .to_owned();
    let header = table.lines().find(|l| l.starts_with("target")).unwrap();
    let row = (table.lines())
        .find(|l| l.starts_with(long.trim_end_matches(".bsdf")))
        .unwrap_or_else(|| panic!("{table}"));
    assert_eq!(
        header.find("closest material"),
        row.find(&format!("  {nearest} ")).map(|i| i + 2),
        "{table}"
    );
    specgp(
        &[
            "locate",
            "m.toml",
            "new.sbrdf:satin_rosaline_rgb",
            "train.sbrdf:paper_white_rgb",
            "--json",
            "b.json",
        ],
        d,
    );
    let read = |p: &str| json_file(&d.join(p));
    let (a, b) = (read("a.json"), read("b.json"));
    assert_eq!(a["latent_dim"], 2);
    assert_eq!(a["n_angles"], 8 * 8 * 16);
    let (la, lb) = (&a["locations"][0], &b["locations"][0]);
    assert_eq!(la["name"], "satin_rosaline_rgb");
    assert_eq!(la["source"], new.as_str());
    assert!(
        lb["source"].as_str().unwrap().ends_with("new.sbrdf"),
        "{lb}"
    );
    for key in [
        "point",
        "brdf_rmse",
        "model_rmse",
        "nearest",
        "nearest_brdf_rmse",
    ] {
        assert_eq!(la[key], lb[key], "{key}: {la} vs {lb}");
    }
    let brdf = la["brdf_rmse"].as_f64().unwrap();
    let nearest = la["nearest_model_rmse"].as_f64().unwrap();
    assert!(
        brdf > 0.0 && la["model_rmse"].as_f64().unwrap() <= nearest,
        "{la}"
    );
    assert!(
        training.iter().any(|t| la["nearest"] == format!("{t}_rgb")),
        "{la}"
    );
    let own = &b["locations"][1];
    let model = Model::load(&d.join("m.toml")).unwrap();
    let coords = &model
        .materials
        .iter()
        .find(|m| m.name == "paper_white_rgb")
        .unwrap()
        .coords;
    let point: Vec<f64> = own["point"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(&point, coords, "{own}");
    assert!(own["brdf_rmse"].as_f64().unwrap() < 1e-9, "{own}");
    assert_eq!(own["nearest"], "paper_white_rgb");

    // `map --locate` marks the same point.
    let (_, log) = specgp_outputs(&["map", "m.toml", "--out", "map.png", "--locate", &new], d);
    let shown = point_text(&la["point"]);
    assert!(
        log.contains(&format!("located satin_rosaline_rgb at {shown} ")),
        "{log}\n{shown}"
    );
    let (w, h, _) = png_rgba(&d.join("map.png"));
    assert!(w > 640 && h > 640);

    // Targets on another grid or with other channels say how to import them.
    specgp(
        &[
            "import",
            "rgl",
            &new,
            "--grid",
            "4,4,8",
            "--out",
            "coarse.sbrdf",
        ],
        d,
    );
    let e = specgp_fails(&["locate", "m.toml", "coarse.sbrdf"], d);
    assert!(
        e.contains("coarse.sbrdf") && e.contains("grid 4,4,8") && e.contains("--grid 8,8,16"),
        "{e}"
    );
    synth_small(d, "400:700:100");
    let e = specgp_fails(&["locate", "m.toml", "data.sbrdf:spectralon"], d);
    assert!(
        e.contains("channels 400:700:100") && e.contains("R,G,B"),
        "{e}"
    );
    specgp(
        &["fit", "data.sbrdf", "--out", "s.toml", "--latent-dim", "2"],
        d,
    );
    let e = specgp_fails(&["locate", "s.toml", &new], d);
    assert!(
        e.contains("is an RGB file (R,G,B), but the model's data are spectral"),
        "{e}"
    );
    // A damaged target store is refused (lookups do not re-hash; a target is read whole).
    let mut bytes = std::fs::read(d.join("new.sbrdf")).unwrap();
    bytes[5000] ^= 0x40;
    std::fs::write(d.join("bad.sbrdf"), bytes).unwrap();
    let e = specgp_fails(&["locate", "m.toml", "bad.sbrdf"], d);
    assert!(e.contains("bad.sbrdf") && e.contains("checksum"), "{e}");
    let e = specgp_fails(&["locate", "m.toml", "picture.png"], d);
    assert!(e.contains("unknown TARGET") && e.contains(".bsdf"), "{e}");
    let e = specgp_fails(&["locate", "m.toml", "new.sbrdf:satin"], d);
    assert!(e.contains("satin_rosaline_rgb"), "{e}");
    let e = specgp_fails(&["locate", "m.toml", &new, "--json", "m.toml"], d);
    assert!(e.contains("m.toml"), "{e}");
    assert!(Model::load(&d.join("m.toml")).is_ok());
}

/// Parses `specgp albedo --out` CSV text: (angle, channel values) per row.
fn albedo_rows(csv: &str) -> Vec<(f64, Vec<f64>)> {
    csv.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (v[0], v[1..].to_vec())
        })
        .collect()
}

/// `specgp albedo`: a stored Lambertian reflects its albedo and conserves energy; one that
/// reflects 1.5 times what it receives is reported; a model point at a training material's
/// own latent point (exact predictor, evaluated lazily) has that material's albedo; the CSV
/// goes to standard output with `--out -`; bad angles and outputs are refused before any work.
#[test]
fn albedo_reports_energy_conservation() {
    use brdf_io::{Channels, StoreInfo, StoreOptions, StoreWriter};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let info = StoreInfo {
        grid: AngularGrid::new(8, 8, 16).unwrap(),
        channels: Channels::parse_wavelengths("360:780:60").unwrap(),
    };
    let mut writer = StoreWriter::create(
        d.join("lambert.sbrdf"),
        info.clone(),
        StoreOptions::default(),
    )
    .unwrap();
    for (name, rho) in [("grey", 0.5), ("bright", 1.5)] {
        let f = (rho / std::f64::consts::PI) as f32;
        writer
            .add_material(name, "test", &vec![f; info.d()])
            .unwrap();
    }
    writer.finish().unwrap();

    let (out, err) = specgp_outputs(
        &[
            "albedo",
            "lambert.sbrdf:grey",
            "--angles",
            "0,45,85",
            "--out",
            "grey.csv",
        ],
        d,
    );
    assert!(err.is_empty(), "{err}");
    let rows = albedo_rows(&std::fs::read_to_string(d.join("grey.csv")).unwrap());
    assert_eq!(
        rows.iter().map(|r| r.0).collect::<Vec<_>>(),
        [0.0, 45.0, 85.0]
    );
    for (angle, values) in &rows {
        assert_eq!(values.len(), 8);
        for v in values {
            assert!((v - 0.5).abs() < 2e-4, "{angle}: {values:?}");
        }
    }
    // The table: Y of a grey reflectance is its albedo; the verdict.
    let y_at_45: f64 = out
        .lines()
        .nth(3)
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert!((y_at_45 - 0.5).abs() < 2e-4, "{out}");
    assert!(out.contains("energy-conserving"), "{out}");

    let (csv, err) = specgp_outputs(
        &[
            "albedo",
            "lambert.sbrdf:bright",
            "--angles",
            "30",
            "--out",
            "-",
        ],
        d,
    );
    let rows = albedo_rows(&csv);
    assert_eq!(rows.len(), 1);
    assert!((rows[0].1[3] - 1.5).abs() < 1e-3, "{csv}");
    assert!(csv.starts_with("angle_deg,360,420,"), "{csv}");
    assert!(
        err.contains("lambert.sbrdf:bright reflects more light than it receives: albedo 1.50")
            && err.contains("at 30 degrees")
            && err.contains("directional albedo of"),
        "{err}"
    );

    // `convert` and `predict` check what they write: the bright Lambertian is reported, the
    // grey one is not.
    let gain = "reflects more light than it receives: albedo 1.50";
    let (_, err) = specgp_outputs(&["convert", "lambert.sbrdf:bright", "--out", "b.bsdf"], d);
    assert!(
        err.contains(&format!("lambert.sbrdf:bright {gain}")),
        "{err}"
    );
    let (_, err) = specgp_outputs(&["convert", "lambert.sbrdf:grey", "--out", "g.bsdf"], d);
    assert!(!err.contains("reflects more light"), "{err}");
    specgp(
        &[
            "fit",
            "lambert.sbrdf",
            "--out",
            "l.toml",
            "--latent-dim",
            "1",
        ],
        d,
    );
    let lambert = Model::load(&d.join("l.toml")).unwrap();
    for m in &lambert.materials {
        let at = m.coords[0].to_string();
        let (_, err) = specgp_outputs(&["predict", "l.toml", "--at", &at, "--out", "p.npy"], d);
        assert_eq!(err.contains(gain), m.name == "bright", "{}: {err}", m.name);
        // The check summed from the values as they are written (multilinear lookups) reports
        // what `albedo` and the cell-by-cell check (logarithmic lookups) report.
        let said = |err: &str| {
            let words = "reflects more light than it receives: ";
            err.lines()
                .find_map(|l| l.split_once(words))
                .map(|(_, w)| w.to_owned())
        };
        let point = format!("l.toml@{at}");
        let (_, by_cells) = specgp_outputs(&["albedo", &point, "--out", "-"], d);
        let (_, log) = specgp_outputs(
            &[
                "predict", "l.toml", "--at", &at, "--lookup", "log", "--out", "q.npy",
            ],
            d,
        );
        assert_eq!(
            said(&err),
            said(&by_cells),
            "{}: {err} / {by_cells}",
            m.name
        );
        assert_eq!(said(&err), said(&log), "{}: {err} / {log}", m.name);
        // A `.bsdf` output checks through the cells the writer read: the same words.
        let args = ["predict", "l.toml", "--at", &at, "--out", "p.bsdf"];
        let (_, file) = specgp_outputs(&args, d);
        assert_eq!(said(&file), said(&by_cells), "{}: {file}", m.name);
    }

    // A training material at its own latent point.
    fitted_small(d, "400:700:100");
    let model = Model::load(&d.join("m.toml")).unwrap();
    let gold = model
        .materials
        .iter()
        .find(|m| m.name == "metal_gold")
        .unwrap();
    let point = format!("m.toml@{},{}", gold.coords[0], gold.coords[1]);
    let stored = specgp(&["albedo", "data.sbrdf:metal_gold", "--out", "-"], d);
    let predicted = specgp(&["albedo", &point, "--out", "-"], d);
    let (stored, predicted) = (albedo_rows(&stored), albedo_rows(&predicted));
    assert_eq!(stored.len(), 12);
    for (s, p) in stored.iter().zip(&predicted) {
        for (a, b) in s.1.iter().zip(&p.1) {
            assert!(
                (a - b).abs() < 1e-5 * a.abs().max(1e-3),
                "{}: {a} vs {b}",
                s.0
            );
        }
    }

    for (args, words) in [
        (vec!["--angles", "0:90:10"], "90 is outside [0, 90)"),
        (vec!["--out", "a.png"], "must end in .csv"),
        (vec!["--resolution", "1"], "--resolution 1"),
    ] {
        let mut all = vec!["albedo", "lambert.sbrdf:grey"];
        all.extend(args);
        let e = specgp_fails(&all, d);
        assert!(e.contains(words), "{all:?}: {e}");
    }
    assert!(!d.join("a.png").exists());
}

/// `--lookup log`: a stored glossy material looked up logarithmically reflects less than
/// multilinearly (its multilinear lookups gain energy between the coarse grid's centres) and
/// its `convert`ed file follows the logarithmic lookup; `render` and `sample` take it too;
/// files with their own evaluation refuse it, naming the file, as does an unknown lookup.
#[test]
fn log_lookups_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    synth_small(d, "400:700:100");
    let albedo = |args: &[&str]| {
        let mut all = vec!["albedo"];
        all.extend(args);
        all.extend(["--angles", "0,40,80,88", "--out", "-"]);
        albedo_rows(&specgp(&all, d))
    };
    let linear = albedo(&["data.sbrdf:metal_gold"]);
    let log = albedo(&["data.sbrdf:metal_gold", "--lookup", "log"]);
    let peak = |rows: &[(f64, Vec<f64>)]| {
        rows.iter()
            .flat_map(|r| r.1.iter().copied())
            .fold(0.0, f64::max)
    };
    // Measured on 8,8,16: 1.89 against 1.04 at 80 degrees (700 nm).
    assert!(
        peak(&linear) > 1.5 && peak(&log) < 1.1,
        "{linear:?} {log:?}"
    );
    for (l, g) in linear.iter().zip(&log) {
        for (a, b) in l.1.iter().zip(&g.1) {
            assert!(b < a, "{}: {b} vs {a}", l.0);
        }
    }
    let explicit = albedo(&["data.sbrdf:metal_gold", "--lookup", "linear"]);
    assert_eq!(explicit, linear);
    // The table's header names a lookup other than the default.
    let header = |lookup: &str| {
        let args = ["albedo", "data.sbrdf:metal_gold", "--lookup", lookup];
        specgp(&args, d)
            .lines()
            .next()
            .unwrap_or_default()
            .to_owned()
    };
    let (linear_header, log_header) = (header("linear"), header("log"));
    assert!(
        log_header.contains("; log lookups between bin centres; ")
            && !linear_header.contains("lookups"),
        "{linear_header} / {log_header}"
    );

    // The written file holds the logarithmic lookups (to the writer's accuracy).
    specgp(
        &[
            "convert",
            "data.sbrdf:metal_gold",
            "--lookup",
            "log",
            "--out",
            "gold.bsdf",
        ],
        d,
    );
    let file = albedo(&["gold.bsdf"]);
    for (f, g) in file.iter().zip(&log) {
        for (a, b) in f.1.iter().zip(&g.1) {
            assert!((a - b).abs() < 0.01 * b, "{}: {a} vs {b}", f.0);
        }
    }

    // render and sample: the glossy sphere's picture and values change.
    for lookup in ["linear", "log"] {
        let out = format!("{lookup}.png");
        let args = ["render", "data.sbrdf:metal_gold", "--size", "24"];
        specgp(
            &[&args[..], &["--lookup", lookup, "--out", &out]].concat(),
            d,
        );
    }
    assert_ne!(
        std::fs::read(d.join("linear.png")).unwrap(),
        std::fs::read(d.join("log.png")).unwrap()
    );
    std::fs::write(d.join("dirs.csv"), "0.8,0,0.6,-0.8,0,0.6\n").unwrap();
    let sample = |lookup: &str| {
        let args = ["sample", "data.sbrdf:metal_gold", "--dirs", "dirs.csv"];
        let csv = specgp(
            &[&args[..], &["--lookup", lookup, "--out", "-"]].concat(),
            d,
        );
        let row = csv.lines().nth(1).unwrap().to_owned();
        row.split(',')
            .map(|v| v.parse::<f64>().unwrap())
            .collect::<Vec<_>>()
    };
    let (a, b) = (sample("linear"), sample("log"));
    assert_eq!(a.len(), 4);
    assert!(
        a.iter().zip(&b).all(|(x, y)| y < x && *y > 0.0),
        "{a:?} {b:?}"
    );

    // predict: a `.bsdf` output holds the prediction's logarithmic lookups, as `convert` of
    // the model point does.
    specgp(
        &["fit", "data.sbrdf", "--out", "m.toml", "--latent-dim", "2"],
        d,
    );
    let model = Model::load(&d.join("m.toml")).unwrap();
    let gold = model.materials.iter().find(|m| m.name == "metal_gold");
    let c = &gold.unwrap().coords;
    let at = format!("{},{}", c[0], c[1]);
    let args = ["predict", "m.toml", "--at", &at, "--out", "p.bsdf"];
    specgp(&[&args[..], &["--lookup", "log"]].concat(), d);
    let point = format!("m.toml@{at}");
    let predicted = albedo(&[&point, "--lookup", "log"]);
    let file = albedo(&["p.bsdf"]);
    for ((f, g), s) in file.iter().zip(&predicted).zip(&log) {
        for ((a, b), c) in f.1.iter().zip(&g.1).zip(&s.1) {
            assert!((a - b).abs() < 0.01 * b, "{}: {a} vs {b}", f.0);
            // The exact predictor returns the training material at its own point.
            assert!((b - c).abs() < 1e-5 * c, "{}: {b} vs {c}", f.0);
        }
    }

    // map: thumbnails of predictions under either lookup.
    for lookup in ["linear", "log"] {
        let out = format!("map-{lookup}.png");
        let args = ["map", "m.toml", "--thumbnails", "--grid", "2"];
        let rest = ["--thumbnail-size", "16", "--lookup", lookup, "--out", &out];
        specgp(&[&args[..], &rest[..]].concat(), d);
    }
    assert_ne!(
        std::fs::read(d.join("map-linear.png")).unwrap(),
        std::fs::read(d.join("map-log.png")).unwrap()
    );

    let e = specgp_fails(&["albedo", "gold.bsdf", "--lookup", "log"], d);
    assert!(
        e.contains("--lookup log: gold.bsdf") && e.contains("applies to grid sources"),
        "{e}"
    );
    let e = specgp_fails(&["albedo", "data.sbrdf:metal_gold", "--lookup", "cubic"], d);
    assert!(e.contains("unknown lookup \"cubic\""), "{e}");
}
