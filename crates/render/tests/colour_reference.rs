//! Colour reference values: the 24 ColorChecker patches (spectra from ../shared/data) against
//! their published sRGB values.

use render::colour::{ColourPipeline, Illuminant, delta_e_2000_rgb, srgb_decode};

/// Published sRGB (8-bit, D65) of the ColorChecker Classic (BabelColor / X-Rite values as
/// tabulated on Wikipedia's "ColorChecker" page), in patch order.
const PUBLISHED_SRGB: [[u8; 3]; 24] = [
    [115, 82, 68],
    [194, 150, 130],
    [98, 122, 157],
    [87, 108, 67],
    [133, 128, 177],
    [103, 189, 170],
    [214, 126, 44],
    [80, 91, 166],
    [193, 90, 99],
    [94, 60, 108],
    [157, 188, 64],
    [224, 163, 46],
    [56, 61, 150],
    [70, 148, 73],
    [175, 54, 60],
    [231, 199, 31],
    [187, 86, 149],
    [8, 133, 161],
    [243, 243, 242],
    [200, 200, 200],
    [160, 160, 160],
    [122, 122, 121],
    [85, 85, 85],
    [52, 52, 52],
];

#[test]
fn colorchecker_patches_match_published_srgb() {
    let Some(text) = shared_data::read_to_string(
        "spectra/colorchecker/colorchecker_babelcolor_average_380-730_10nm.csv",
    ) else {
        return;
    };
    let mut wl = Vec::new();
    let mut patches = vec![Vec::new(); 24];
    for line in text.lines().skip(1).filter(|l| !l.trim().is_empty()) {
        let v: Vec<f64> = line.split(',').map(|f| f.trim().parse().unwrap()).collect();
        assert_eq!(v.len(), 25, "{line}");
        wl.push(v[0]);
        for (p, x) in patches.iter_mut().zip(&v[1..]) {
            p.push(*x);
        }
    }
    let pipe = ColourPipeline::new(Illuminant::D65);
    let mut des = Vec::new();
    for (k, spectrum) in patches.iter().enumerate() {
        let rgb = pipe.reflectance_to_rgb(&wl, spectrum).unwrap();
        let want = PUBLISHED_SRGB[k].map(|c| srgb_decode(f64::from(c) / 255.0));
        let de = delta_e_2000_rgb(rgb, want);
        println!(
            "patch {:2}: sRGB {:?} published {:?} dE00 {de:.2}",
            k + 1,
            rgb.map(render::colour::to_srgb8),
            PUBLISHED_SRGB[k]
        );
        des.push(de);
    }
    let mean = des.iter().sum::<f64>() / des.len() as f64;
    let max = des.iter().copied().fold(0.0, f64::max);
    println!("ColorChecker (BabelColor average, D65): mean dE00 {mean:.3}, max {max:.3}");
    // Today 1.28 / 2.71 (an independent pure-Python reference gets 1.28 / 2.67: the rest is the
    // data against the published numbers). Swapped interpolation weights add ~0.35 to the mean.
    assert!(mean < 1.5, "mean dE00 {mean}");
    assert!(max < 3.0, "max dE00 {max}");
    // The neutral row (neutral 8 to black; white 9.5 is measurably warm) is neutral.
    for (k, patch) in patches.iter().enumerate().skip(19) {
        let rgb = pipe.reflectance_to_rgb(&wl, patch).unwrap();
        let spread = rgb.iter().copied().fold(f64::MIN, f64::max)
            - rgb.iter().copied().fold(f64::MAX, f64::min);
        assert!(spread < 0.02 * rgb[1] + 0.003, "patch {} {rgb:?}", k + 1);
    }
}

#[test]
fn d65_white_point_from_the_embedded_tables_matches_the_shared_csv() {
    // The embedded 5 nm tables against a 1 nm integration of the shared CSV files.
    let (Some(cmf), Some(d65)) = (
        shared_data::read_to_string("spectra/cie/cie1931_2deg_xyz_cmf_360-830_1nm.csv"),
        shared_data::read_to_string("spectra/cie/CIE_std_illum_D65.csv"),
    ) else {
        return;
    };
    let parse = |t: &str| -> Vec<Vec<f64>> {
        t.lines()
            .skip(1)
            .filter(|l| !l.trim().is_empty())
            .map(|l| l.split(',').map(|f| f.trim().parse().unwrap()).collect())
            .collect()
    };
    let (cmf, d65) = (parse(&cmf), parse(&d65));
    let spd = |nm: f64| {
        d65.iter()
            .find(|r| (r[0] - nm).abs() < 1e-9)
            .map(|r| r[1])
            .unwrap()
    };
    let mut xyz = [0.0; 3];
    for r in &cmf {
        let e = spd(r[0]);
        for c in 0..3 {
            xyz[c] += r[c + 1] * e;
        }
    }
    let full = [xyz[0] / xyz[1], 1.0, xyz[2] / xyz[1]];
    assert!(
        (full[0] - 0.95047).abs() < 1e-4 && (full[2] - 1.08883).abs() < 1e-4,
        "{full:?}"
    );
    let emb = Illuminant::D65.white_xyz();
    for c in 0..3 {
        assert!((emb[c] - full[c]).abs() < 2e-4, "{emb:?} vs {full:?}");
    }
}
