//! `report.md`: the results of a pipeline run as markdown tables, readable on its own.

use std::fmt::Write as _;

use crate::pipeline::Results;

/// A number in short scientific or fixed notation.
pub fn num(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if !v.is_finite() {
        format!("{v}")
    } else if v.abs() >= 1e5 || v.abs() < 1e-3 {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

pub use brdf_io::error::quantity;

/// Bytes as KiB/MiB/GiB.
pub fn bytes(b: u64) -> String {
    let b = b as f64;
    if b >= 1024.0 * 1024.0 * 1024.0 {
        format!("{:.2} GiB", b / (1024.0 * 1024.0 * 1024.0))
    } else if b >= 1024.0 * 1024.0 {
        format!("{:.1} MiB", b / (1024.0 * 1024.0))
    } else {
        format!("{:.1} KiB", b / 1024.0)
    }
}

/// `s` as one POSIX shell word: as it is when it holds only characters the shell takes
/// literally, else in single quotes (a regenerate command with `--out out/my run` ran into
/// `out/my`).
pub fn shell_word(s: &str) -> String {
    if !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"_./:=@%+,-".contains(&b))
    {
        s.to_owned()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// The report of `r` as markdown.
pub fn markdown(r: &Results) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# specgp pipeline report: {}\n", r.name);
    if !r.description.is_empty() {
        let _ = writeln!(s, "{}\n", r.description);
    }
    let _ = writeln!(
        s,
        "Config `{}`; regenerate with `cargo xtask pipeline {} --out {}`. Every number below is \
         also in `results.json`. Total run time {:.1} s.\n",
        r.config_file,
        shell_word(&r.config_file),
        shell_word(&r.out_dir),
        r.total_seconds
    );

    let _ = writeln!(
        s,
        "## Stages\n\n| stage | status | seconds |\n|---|---|---:|"
    );
    for st in &r.stages {
        let _ = writeln!(s, "| {} | {} | {:.2} |", st.name, st.status, st.seconds);
    }

    let d = &r.data;
    let _ = writeln!(s, "\n## Data\n\n| quantity | value |\n|---|---|");
    let _ = writeln!(s, "| source | {} |", d.kind);
    let _ = writeln!(s, "| materials N | {} |", d.n_materials);
    let _ = writeln!(s, "| grid (theta_h, theta_d, phi_d) | {} |", d.grid);
    let channels = if d.n_channels <= 4 {
        d.channels.join(", ")
    } else {
        format!(
            "{} ({} .. {} nm)",
            d.n_channels,
            d.channels.first().map(String::as_str).unwrap_or(""),
            d.channels.last().map(String::as_str).unwrap_or("")
        )
    };
    let _ = writeln!(s, "| channels | {channels} |");
    let _ = writeln!(s, "| values per material D | {} |", d.d);
    let _ = writeln!(
        s,
        "| store (`{}`, {}) | {} |",
        d.store,
        d.dtype,
        bytes(d.store_bytes)
    );
    if d.kind != "synth" {
        let _ = writeln!(
            s,
            "| import: outliers / negatives clamped | {} / {}{} |",
            d.import_outliers,
            d.import_negatives_clamped,
            if d.import_negatives_clamped > 0 {
                " (values below 0, stored as 0: RGB tables of out-of-gamut colours dip below \
                 zero; see docs/CONVENTIONS.md)"
            } else {
                ""
            }
        );
    }
    let _ = writeln!(s, "| seconds | {:.2} |", d.seconds);

    let f = &r.fit;
    let _ = writeln!(s, "\n## Fit\n\n| quantity | value |\n|---|---|");
    let _ = writeln!(s, "| settings | {} |", f.config);
    let _ = writeln!(s, "| optimiser | {} |", f.optimizer);
    let _ = writeln!(s, "| transform | {} |", f.transform);
    let _ = writeln!(s, "| latent dimension q | {} |", f.latent_dim);
    let _ = writeln!(
        s,
        "| log-likelihood (PCA start -> final) | {} -> {} |",
        num(f.initial_log_likelihood),
        num(f.log_likelihood)
    );
    let _ = writeln!(
        s,
        "| iterations / evaluations | {} / {} |",
        f.iterations, f.evaluations
    );
    let _ = writeln!(s, "| stop reason | {} |", f.stop_reason);
    let ls: Vec<String> = f.length_scale.iter().map(|v| num(*v)).collect();
    let _ = writeln!(
        s,
        "| s^2, l, mu | {}, {}, {} |",
        num(f.signal_variance),
        ls.join("/"),
        num(f.noise)
    );
    let _ = writeln!(s, "| condition number of K | {} |", num(f.condition_number));
    let _ = writeln!(
        s,
        "| PCA variance explained by q components | {:.1} % |",
        100.0 * f.pca_explained
    );
    let _ = writeln!(
        s,
        "| seconds: Gram pass, optimisation, whole stage (with the PCA start and the model file) \
         | {:.2}, {:.2}, {:.2} |",
        f.gram_seconds, f.optimize_seconds, f.seconds
    );

    let _ = writeln!(s, "\n## Latent space\n");
    let q = r.latent.first().map_or(0, |l| l.coords.len());
    let _ = write!(s, "| material |");
    for k in 0..q {
        let _ = write!(s, " x{} |", k + 1);
    }
    let _ = write!(s, "\n|---|");
    for _ in 0..q {
        let _ = write!(s, "---:|");
    }
    let _ = writeln!(s);
    for l in &r.latent {
        let _ = write!(s, "| {} |", l.name);
        for c in &l.coords {
            let _ = write!(s, " {c:.4} |");
        }
        let _ = writeln!(s);
    }

    predictions(&mut s, r);
    evaluation(&mut s, r);
    located(&mut s, r);
    paper_table(&mut s, r);
    figures(&mut s, r);

    let missing: Vec<&str> = r
        .stages
        .iter()
        .filter(|st| st.status == "not available")
        .map(|st| st.name.as_str())
        .collect();
    if !missing.is_empty() {
        let _ = writeln!(
            s,
            "\n## Not available in this build\n\nStages {} are not wired in yet; no numbers are \
             reported for them.",
            missing.join(", ")
        );
    }
    s
}

fn located(s: &mut String, r: &Results) {
    if r.located.is_empty() {
        return;
    }
    let names: Vec<&str> = r.latent.iter().map(|l| l.name.as_str()).collect();
    let _ = writeln!(
        s,
        "\n## Located materials\n\nMeasured files outside the training set, resampled onto the \
         grid as the data were and placed where the GP reconstructs them best (`specgp locate`: \
         the smooth predictor's transformed-space error, searched from the {} best training \
         points; errors of the exact predictor there). Eq. 22 RMSE in BRDF space (1/sr) and in \
         the transformed space; the closest training material is the one with the smallest \
         transformed-space error; var frac is the share of the prior variance left at the \
         point.\n",
        r.config.locate.starts
    );
    let _ = writeln!(
        s,
        "| file | point | BRDF RMSE | model RMSE | closest material | its BRDF RMSE | its model \
         RMSE | var frac |\n|---|---|---:|---:|---|---:|---:|---:|"
    );
    for l in &r.located {
        let point: Vec<String> = l.point.iter().map(|v| format!("{v:.3}")).collect();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {:.3} |",
            l.name,
            point.join(", "),
            num(l.brdf_rmse),
            num(l.model_rmse),
            l.nearest,
            num(l.nearest_brdf_rmse),
            num(l.nearest_model_rmse),
            l.variance_fraction
        );
    }
    // Files named like a training material: is that material the closest one?
    let named: Vec<_> = r
        .located
        .iter()
        .filter(|l| names.contains(&l.name.as_str()))
        .collect();
    if !named.is_empty() {
        let own = named.iter().filter(|l| l.nearest == l.name).count();
        let _ = writeln!(
            s,
            "\n{own} of the {} files named like a training material have that material as the \
             closest one.",
            named.len()
        );
    }
}

fn predictions(s: &mut String, r: &Results) {
    if r.predictions.is_empty() {
        return;
    }
    let _ = writeln!(
        s,
        "\n## Predictions\n\nA prediction is N coefficients over the measured materials \
         (computed in `weights us`); a lazy lookup of one angular cell, all channels, costs N \
         multiply-adds per value (`lookup us`, mean over up to 4096 cells). Materialising writes \
         all D values. A midpoint `mid(A, B)` is the latent point halfway between two materials, \
         not a blend of them: its material is whatever the GP predicts there, which can look \
         like neither (`specgp predict --lerp A,B,0.5` is the blend). The variance is per \
         transformed value: under `log`, in squared log units, so a variance of 0.5 (standard \
         deviation 0.7) means the BRDF is uncertain by a factor of about 2.\n"
    );
    let _ = writeln!(
        s,
        "| point | latent x | predictor | variance | weights us | lookup us | mean value (1/sr) | materialised | seconds |\n|---|---|---|---:|---:|---:|---:|---|---:|"
    );
    for p in &r.predictions {
        let x: Vec<String> = p.point.iter().map(|v| format!("{v:.3}")).collect();
        let file = p.file.as_ref().map_or("-".to_string(), |f| {
            format!("[`{f}`]({f}) ({})", bytes(p.file_bytes))
        });
        let _ = writeln!(
            s,
            "| {} | ({}) | {} | {} | {:.1} | {:.2} | {} | {} | {:.3} |",
            p.label,
            x.join(", "),
            p.predictor,
            num(p.variance),
            p.weights_us,
            p.lookup_us,
            num(p.lookup_mean),
            file,
            p.materialize_seconds
        );
    }
    if r.predictions.iter().any(|p| p.bsdf.is_some()) {
        let _ = writeln!(
            s,
            "\nThe predictions as RGL `.bsdf` files, which Mitsuba 3 and pbrt-v4 render \
             (`measured` material), at the writer's starting sizes (`specgp predict --out X.bsdf` \
             also refines them while a check is above 5 %). Check: the file's cos-weighted \
             relative RMS error against the prediction at {} direction pairs, and largest relative error \
             of its directional albedo at incidence 0-88 degrees.\n\n| point | file | incident \
             elevations | table | check | albedo | seconds |\n|---|---|---:|---:|---:|---:|---:|",
            brdf_io::rgl::CHECK_PAIRS
        );
        for p in &r.predictions {
            if let Some(b) = &p.bsdf {
                let _ = writeln!(
                    s,
                    "| {} | [`{}`]({}) ({}) | {} | {} x {} | {:.2} % | {:.2} % | {:.2} |",
                    p.label,
                    b.file,
                    b.file,
                    bytes(b.bytes),
                    b.theta_samples,
                    b.resolution,
                    b.resolution,
                    100.0 * b.check_rms,
                    100.0 * b.albedo_error,
                    b.seconds
                );
            }
        }
    }
    energy(s, r);
}

/// The predictions' and the stored materials' largest directional albedo.
fn energy(s: &mut String, r: &Results) {
    use crate::stages::ALBEDO_THETAS_DEG;
    use brdf_io::albedo::{ENERGY_MARGIN, gains_energy};
    if r.predictions.is_empty() {
        return;
    }
    let mut above: Vec<_> = r
        .stored_albedo
        .iter()
        .filter(|m| gains_energy(m.peak.value))
        .collect();
    let angles: Vec<String> = ALBEDO_THETAS_DEG.iter().map(|a| a.to_string()).collect();
    let _ = write!(
        s,
        "\nEnergy: each prediction's largest directional albedo (the fraction of the light from \
         one direction that it reflects; `specgp albedo`) over incidence {} degrees and every \
         channel. Above 1 a material reflects more light than it receives in that channel, \
         which only a fluorescent one can (shifting light from other wavelengths), and a path \
         tracer turns into energy gained at every bounce. {} of the {} stored materials exceed \
         1 + {ENERGY_MARGIN} as the {} lookups between bin centres see them",
        angles.join(", "),
        above.len(),
        r.stored_albedo.len(),
        match r.config.lookup.as_deref().map(str::parse) {
            Some(Ok(brdf_io::Lookup::LogMultilinear)) => {
                "logarithmic (`lookup = \"log\"`: the figures and `.bsdf` files too)"
            }
            _ => "multilinear",
        }
    );
    if above.is_empty() {
        let _ = writeln!(s, ".\n");
    } else {
        above.sort_by(|a, b| b.peak.value.total_cmp(&a.peak.value));
        let list: Vec<String> = above
            .iter()
            .take(8)
            .map(|m| {
                format!(
                    "{} {:.3} at {} degrees",
                    m.material, m.peak.value, m.peak.angle_deg
                )
            })
            .collect();
        let _ = writeln!(
            s,
            " ({}{}): on a coarse grid glossy materials gain energy near grazing incidence \
             between the bin centres (BENCHMARKS.md \"albedo\"), fluorescent ones exceed 1 in \
             their emission band, and predictions blend them.\n",
            list.join(", "),
            if above.len() > 8 { ", ..." } else { "" }
        );
    }
    let _ = writeln!(
        s,
        "| point | largest albedo | at (degrees) | channel |\n|---|---:|---:|---|"
    );
    for p in &r.predictions {
        let _ = writeln!(
            s,
            "| {} | {:.3} | {} | {} |",
            p.label, p.albedo.value, p.albedo.angle_deg, p.albedo.channel
        );
    }
}

fn evaluation(s: &mut String, r: &Results) {
    let Some(e) = &r.evaluation else {
        return;
    };
    let _ = writeln!(
        s,
        "\n## Errors\n\nRMSE with the paper's Eq. 22 normalisation (sum over all D values, \
         divided by the {} angular cells), in BRDF space (1/sr) and in the model's transformed \
         space ({}). Reconstruction: each training material predicted at its own latent point. \
         Leave-one-out: refit without the material, place it at the latent point that best \
         reconstructs it (GP, smooth predictor) and compare with baselines chosen with knowledge \
         of it (nearest material; linear interpolation between the two materials nearest the GP \
         point or the best pair; PCA with q components). Streaming pass {:.2} s, refits {:.2} s.\n",
        e.n_angles, e.transform, e.pass_seconds, e.loo_seconds
    );
    let _ = writeln!(
        s,
        "| method | BRDF mean | BRDF median | model mean | model median | GP better on |\n|---|---:|---:|---:|---:|---:|"
    );
    for m in &e.summary {
        let better = m
            .gp_better
            .map_or("-".to_string(), |k| format!("{k}/{}", e.n_materials));
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} |",
            m.method,
            num(m.brdf_mean),
            num(m.brdf_median),
            num(m.model_mean),
            num(m.model_median),
            better
        );
    }
    let _ = writeln!(s, "\n### Per material (BRDF-space RMSE)\n");
    let _ = write!(
        s,
        "| material | reconstruction exact | reconstruction smooth |"
    );
    let methods: Vec<&str> = e
        .loo
        .as_ref()
        .and_then(|l| l.first())
        .map(|row| row.methods.iter().map(|m| m.method.name()).collect())
        .unwrap_or_default();
    for m in &methods {
        let _ = write!(s, " loo {m} |");
    }
    let _ = write!(s, "\n|---|---:|---:|");
    for _ in &methods {
        let _ = write!(s, "---:|");
    }
    let _ = writeln!(s);
    for (i, row) in e.reconstruction.iter().enumerate() {
        let _ = write!(
            s,
            "| {} | {} | {} |",
            row.name,
            num(row.exact_rmse),
            num(row.smooth_rmse)
        );
        if let Some(loo) = e.loo.as_ref().and_then(|l| l.get(i)) {
            for m in &loo.methods {
                let _ = write!(s, " {} |", num(m.brdf_rmse));
            }
        }
        let _ = writeln!(s);
    }
}

fn figures(s: &mut String, r: &Results) {
    let Some(f) = &r.figures else {
        return;
    };
    let _ = writeln!(
        s,
        "\n## Figures\n\nSpheres under a directional light and a dim uniform environment, {} \
         ({:.2} s per sphere). Mean CIE Delta E 2000 between the dataset's spheres (its stored \
         values) and the smooth GP reconstructions in the sheet: **{:.3}**.\n",
        if r.data.channels == ["R", "G", "B"] {
            "RGB values taken as linear sRGB"
        } else {
            "D65, spectral -> CIE XYZ -> sRGB"
        },
        f.seconds_per_sphere,
        f.mean_delta_e
    );
    for (file, caption) in &f.files {
        let _ = writeln!(s, "![{file}]({file})\n\n*{caption}*\n");
    }
    if !f.delta_e.is_empty() {
        let _ = writeln!(
            s,
            "| material | Delta E 2000 (smooth reconstruction) | Delta E 2000 (held out) |\n\
             |---|---:|---:|"
        );
        for d in &f.delta_e {
            let held = d
                .held_out_delta_e
                .map_or_else(|| "-".to_owned(), |v| format!("{v:.3}"));
            let _ = writeln!(s, "| {} | {:.3} | {held} |", d.name, d.mean_delta_e);
        }
    }
}

fn paper_table(s: &mut String, r: &Results) {
    if r.by_kind.is_empty() {
        return;
    }
    let per_prediction_us = r
        .predictions
        .iter()
        .map(|p| p.weights_us)
        .fold(f64::NAN, f64::min);
    let full_s = r
        .predictions
        .iter()
        .filter(|p| p.file.is_some())
        .map(|p| p.materialize_seconds)
        .fold(f64::NAN, f64::min);
    let timing = match (per_prediction_us.is_nan(), full_s.is_nan()) {
        (true, _) => "no prediction was configured".to_owned(),
        (false, true) => format!(
            "{per_prediction_us:.1} us for the N coefficients (lazy); nothing was materialised"
        ),
        (false, false) => format!(
            "{per_prediction_us:.1} us for the N coefficients (lazy), {full_s:.3} s to \
             materialise all D values (fastest of the configured points)"
        ),
    };
    let _ = writeln!(
        s,
        "\n## By kind of material\n\nMean Eq. 22 RMSE (BRDF space, 1/sr) per kind of synthetic \
         material (preset families: diffuse = felt, paper, cardboard, wall paint, leaf, \
         diffuser; glossy = vinyl, satin, car paint; metallic = metal, painted metal, \
         iridescent). Time per prediction: {timing}.\n"
    );
    let _ = writeln!(
        s,
        "| kind | materials | reconstruction (exact) | reconstruction (smooth) | leave-one-out (GP) |\n|---|---:|---:|---:|---:|"
    );
    for k in &r.by_kind {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} |",
            k.kind,
            k.n,
            num(k.reconstruction_exact),
            num(k.reconstruction_smooth),
            // NaN (null in results.json) when leave-one-out was not run.
            if k.loo_gp.is_nan() {
                "-".to_string()
            } else {
                num(k.loo_gp)
            }
        );
    }
    if r.by_kind.iter().any(|k| k.loo_gp.is_nan()) {
        let _ = writeln!(s, "\nLeave-one-out was not run (`[evaluate] loo = false`).");
    }
}

#[cfg(test)]
mod tests {
    use super::{bytes, num, shell_word};

    /// Fixed notation with 4 decimals from 1e-3 up to (not including) 1e5, scientific with 3
    /// outside, plain 0 and non-finite values as Rust writes them.
    #[test]
    fn numbers_switch_notation_at_1e_3_and_1e5() {
        for (v, want) in [
            (0.0, "0"),
            (-0.0, "0"),
            (1.5, "1.5000"),
            (-2.25, "-2.2500"),
            (1e-3, "0.0010"),
            (9.99e-4, "9.990e-4"),
            (99_999.5, "99999.5000"),
            (1e5, "1.000e5"),
            (-3.925557e6, "-3.926e6"),
            (f64::NAN, "NaN"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
        ] {
            assert_eq!(num(v), want, "{v}");
        }
    }

    /// KiB below 1 MiB, MiB below 1 GiB, GiB from there.
    #[test]
    fn byte_counts_in_binary_units() {
        for (b, want) in [
            (0, "0.0 KiB"),
            (1536, "1.5 KiB"),
            ((1 << 20) - 1, "1024.0 KiB"),
            (1 << 20, "1.0 MiB"),
            (55_174_064, "52.6 MiB"),
            ((1 << 30) - 1, "1024.0 MiB"),
            (1 << 30, "1.00 GiB"),
            (1_230_000_000, "1.15 GiB"),
        ] {
            assert_eq!(bytes(b), want, "{b}");
        }
    }

    #[test]
    fn shell_words_quote_what_the_shell_would_split_or_expand() {
        assert_eq!(shell_word("configs/quick.toml"), "configs/quick.toml");
        assert_eq!(shell_word("/tmp/a-b_c/out.1"), "/tmp/a-b_c/out.1");
        assert_eq!(shell_word("out/my run"), "'out/my run'");
        assert_eq!(shell_word("it's"), "'it'\\''s'");
        assert_eq!(shell_word("$HOME/*"), "'$HOME/*'");
        assert_eq!(shell_word(""), "''");
    }
}
