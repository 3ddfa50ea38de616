//! Recognisable colours: the preset's spectra, converted to linear sRGB with the CIE 1931
//! observer under D65 (read from `../shared/data/spectra/cie`, required), have the
//! hue their names promise.

use brdf_synth::{Metal, preset};

/// (lambda, xbar, ybar, zbar, D65) at 5 nm over 380-780 nm.
fn observer() -> Option<Vec<[f64; 5]>> {
    let cmf = shared_data::read_to_string("spectra/cie/cie1931_2deg_xyz_cmf_360-830_1nm.csv")?;
    let d65 = shared_data::read_to_string("spectra/cie/cie_illuminant_D65_300-780_5nm.csv")?;
    let parse = |t: &str| -> Vec<Vec<f64>> {
        t.lines()
            .skip(1)
            .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
            .collect()
    };
    let (cmf, d65) = (parse(&cmf), parse(&d65));
    let mut out = Vec::new();
    for l in (380..=780).step_by(5) {
        let c = cmf.iter().find(|r| r[0] == l as f64)?;
        let d = d65.iter().find(|r| r[0] == l as f64)?;
        out.push([l as f64, c[1], c[2], c[3], d[1]]);
    }
    Some(out)
}

/// Linear sRGB of a reflectance spectrum under D65 (white = (1, 1, 1)).
fn srgb(obs: &[[f64; 5]], refl: impl Fn(f64) -> f64) -> [f64; 3] {
    let (mut x, mut y, mut z, mut n) = (0.0, 0.0, 0.0, 0.0);
    for [l, xb, yb, zb, e] in obs {
        let r = refl(*l);
        x += r * e * xb;
        y += r * e * yb;
        z += r * e * zb;
        n += e * yb;
    }
    let (x, y, z) = (x / n, y / n, z / n);
    [
        3.2406 * x - 1.5372 * y - 0.4986 * z,
        -0.9689 * x + 1.8758 * y + 0.0415 * z,
        0.0557 * x - 0.2040 * y + 1.0570 * z,
    ]
}

/// The sRGB transfer curve (values clamped to [0, 1]).
fn encode(v: f64) -> f64 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// The hue in degrees of a linear sRGB triple, measured on the encoded (displayed) values.
fn hue(c: [f64; 3]) -> f64 {
    let [r, g, b] = c.map(encode);
    let (max, min) = (r.max(g).max(b), r.min(g).min(b));
    let d = max - min;
    if d <= 0.0 {
        return f64::NAN;
    }
    let h = if max == r {
        60.0 * ((g - b) / d).rem_euclid(6.0)
    } else if max == g {
        60.0 * ((b - r) / d + 2.0)
    } else {
        60.0 * ((r - g) / d + 4.0)
    };
    h.rem_euclid(360.0)
}

fn in_range(h: f64, lo: f64, hi: f64) -> bool {
    if lo <= hi {
        h >= lo && h <= hi
    } else {
        h >= lo || h <= hi
    }
}

#[test]
fn metals_have_their_colours() {
    let Some(obs) = observer() else {
        return;
    };
    let gold = srgb(&obs, |l| Metal::Gold.normal_reflectance(l));
    let copper = srgb(&obs, |l| Metal::Copper.normal_reflectance(l));
    let silver = srgb(&obs, |l| Metal::Silver.normal_reflectance(l));
    let alu = srgb(&obs, |l| Metal::Aluminium.normal_reflectance(l));
    let chrome = srgb(&obs, |l| Metal::Chromium.normal_reflectance(l));
    println!("gold {gold:?} copper {copper:?} silver {silver:?} al {alu:?} cr {chrome:?}");
    // Gold: yellow-orange hue, saturated; copper: redder than gold.
    assert!(in_range(hue(gold), 38.0, 55.0), "gold hue {}", hue(gold));
    assert!(gold[2] < 0.6 * gold[0], "gold {gold:?}");
    let hc = hue(copper);
    assert!(
        hc < hue(gold) - 5.0 && in_range(hc, 5.0, 35.0),
        "copper hue {hc}"
    );
    // Silver, aluminium, chromium: near-neutral, chromium darkest.
    for (name, c) in [("silver", silver), ("aluminium", alu), ("chromium", chrome)] {
        let (max, min) = (c[0].max(c[1]).max(c[2]), c[0].min(c[1]).min(c[2]));
        assert!(max - min < 0.1 * max, "{name} {c:?}");
    }
    assert!(silver[1] > 0.9 && alu[1] > 0.85 && chrome[1] < 0.7 && chrome[1] > 0.45);
}

#[test]
fn named_colours_have_their_hues() {
    let Some(obs) = observer() else {
        return;
    };
    use brdf_synth::{Body, Material};
    let albedo = |m: &Material| match &m.body {
        Body::Layered { base, .. } => base.albedo.clone(),
        Body::Metal { .. } => unreachable!(),
    };
    // Hue ranges in degrees (encoded sRGB).
    let ranges: [(&str, f64, f64); 7] = [
        ("_red", 330.0, 20.0),
        ("_orange", 10.0, 45.0),
        ("_yellow", 35.0, 75.0),
        ("_green", 75.0, 170.0),
        ("_blue", 185.0, 260.0),
        ("_purple", 250.0, 345.0),
        ("_pink", 290.0, 20.0),
    ];
    let mut checked = 0;
    for m in preset(0)
        .iter()
        .filter(|m| !matches!(m.body, Body::Metal { .. }))
    {
        let a = albedo(m);
        let c = srgb(&obs, |l| a.eval(l));
        for (suffix, lo, hi) in ranges {
            if m.name.contains(suffix) {
                let h = hue(c);
                println!("{}: rgb {c:?} hue {h:.0}", m.name);
                assert!(
                    in_range(h, lo, hi),
                    "{}: hue {h:.0} not in {lo}-{hi}",
                    m.name
                );
                checked += 1;
            }
        }
        if m.name.contains("white") || m.name == "spectralon" {
            let (max, min) = (c[0].max(c[1]).max(c[2]), c[0].min(c[1]).min(c[2]));
            assert!(min > 0.55 && max - min < 0.15 * max, "{}: {c:?}", m.name);
            checked += 1;
        }
    }
    assert!(checked >= 20, "only {checked} materials checked");
}
