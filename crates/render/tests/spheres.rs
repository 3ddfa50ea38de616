//! Pixel statistics of rendered spheres: white is neutral grey, gold is yellow, real RGB files
//! render their known colours.

use render::sphere::{SphereOptions, mean_colour, render_sphere};

type Synth = brdf_synth::PreparedMaterial;

fn synth(name: &str) -> Synth {
    let wl: Vec<f64> = (360..=1000).step_by(20).map(f64::from).collect();
    let m = brdf_synth::preset_material(name, 0).unwrap_or_else(|| panic!("no preset {name}"));
    m.prepare(&wl)
}

fn small() -> SphereOptions {
    SphereOptions {
        size: 48,
        ..SphereOptions::default()
    }
}

#[test]
fn white_felt_is_neutral_grey() {
    let img = render_sphere(&synth("acrylic_felt_white"), &small()).unwrap();
    let (m, n) = mean_colour(&img);
    assert!(n > 1500, "{n}");
    let spread =
        m.iter().copied().fold(f64::MIN, f64::max) - m.iter().copied().fold(f64::MAX, f64::min);
    assert!(spread < 0.03 * m[1], "white felt mean {m:?}");
    assert!(m[1] > 0.2 && m[1] < 0.9, "{m:?}");
}

#[test]
fn gold_is_yellow() {
    for name in ["metal_gold", "satin_gold"] {
        let img = render_sphere(&synth(name), &small()).unwrap();
        let (m, _) = mean_colour(&img);
        assert!(m[0] > m[1] && m[1] > m[2], "{name}: mean {m:?}");
        assert!(m[2] < 0.6 * m[0], "{name}: {m:?}");
    }
}

fn rgl(name: &str) -> Option<brdf_io::rgl::RglBsdf> {
    let f = shared_data::path(&format!("rgl-rgb/{name}"))?;
    Some(brdf_io::rgl::RglBsdf::open(&f).unwrap())
}

#[test]
fn real_rgb_files_render_their_known_colours() {
    if let Some(src) = rgl("vch_golden_yellow_rgb.bsdf") {
        let (m, _) = mean_colour(&render_sphere(&src, &small()).unwrap());
        assert!(
            m[0] > m[1] && m[1] > m[2] && m[2] < 0.5 * m[1],
            "golden yellow {m:?}"
        );
    }
    if let Some(src) = rgl("paper_white_rgb.bsdf") {
        // Paper white is near-neutral but measurably bluish (optical brighteners: f at normal
        // incidence is R, G, B = 0.278, 0.283, 0.331): RGB passes through, so the sphere keeps
        // the file's own channel ratios.
        let (m, _) = mean_colour(&render_sphere(&src, &small()).unwrap());
        let mut f = [0.0; 3];
        src.eval([0.0, 0.0, 1.0], [0.6, 0.0, 0.8], &mut f).unwrap();
        assert!(m[1] > 0.2, "paper white {m:?}");
        assert!(
            (m[0] / m[1] - f[0] / f[1]).abs() < 0.03,
            "paper white {m:?} vs f {f:?}"
        );
        assert!(
            (m[2] / m[1] - f[2] / f[1]).abs() < 0.05,
            "paper white {m:?} vs f {f:?}"
        );
        assert!(
            (m[0] / m[1] - 1.0).abs() < 0.03 && m[2] / m[1] < 1.25,
            "{m:?}"
        );
    }
    if let Some(src) = rgl("cc_iris_purple_gem_rgb.bsdf") {
        let (m, _) = mean_colour(&render_sphere(&src, &small()).unwrap());
        // A blue-violet colour-shift paint: blue dominates.
        assert!(m[2] > 2.0 * m[1] && m[2] > 2.0 * m[0], "purple gem {m:?}");
    }
}
