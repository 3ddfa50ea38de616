//! Properties of the colour pipeline: the XYZ <-> sRGB matrices, white points, linearity of
//! spectral integration and exposure, the 8-bit sRGB encoding at and beyond its ends, and
//! CIEDE2000's metric basics.

use proptest::prelude::*;
use render::colour::{
    ColourPipeline, Illuminant, SRGB_TO_XYZ, SpectralWeights, XYZ_TO_SRGB, delta_e_2000,
    linear_srgb_to_xyz, srgb_decode, srgb_encode, to_srgb8, xyz_to_linear_srgb,
};

/// The two matrices are inverses to their 7 printed decimals, and D65's white maps to sRGB
/// white: (0.95047, 1, 1.08883) -> (1, 1, 1), and back.
#[test]
fn srgb_matrices_are_inverse_and_map_the_d65_white() {
    for i in 0..3 {
        for j in 0..3 {
            let p: f64 = (0..3).map(|k| XYZ_TO_SRGB[i][k] * SRGB_TO_XYZ[k][j]).sum();
            let q: f64 = (0..3).map(|k| SRGB_TO_XYZ[i][k] * XYZ_TO_SRGB[k][j]).sum();
            let id = if i == j { 1.0 } else { 0.0 };
            assert!(
                (p - id).abs() < 1e-6 && (q - id).abs() < 1e-6,
                "{i} {j}: {p} {q}"
            );
        }
    }
    let rgb = xyz_to_linear_srgb([0.95047, 1.0, 1.08883]);
    for c in rgb {
        assert!((c - 1.0).abs() < 1e-6, "{rgb:?}");
    }
    let white = linear_srgb_to_xyz([1.0; 3]);
    for (a, b) in white.iter().zip([0.95047, 1.0, 1.08883]) {
        assert!((a - b).abs() < 1e-6, "{white:?}");
    }
    // Y of the primaries is the sRGB luminance weights.
    assert_eq!(
        [SRGB_TO_XYZ[1][0], SRGB_TO_XYZ[1][1], SRGB_TO_XYZ[1][2]],
        [0.2126729, 0.7151522, 0.0721750]
    );
}

/// Every 8-bit code survives decode -> encode, the encoding is 0 at 0, 255 at 1, clamps
/// negative values and -infinity to 0, values above 1 and +infinity to 255, and encodes NaN
/// as 0 (documented); the curve is continuous at its linear/power joint (to the standard's own
/// 3e-8 in code value, 2.3e-9 linear: its rounded constants).
#[test]
fn srgb8_round_trips_every_code_and_clamps_out_of_range_values() {
    for code in 0u8..=255 {
        let linear = srgb_decode(f64::from(code) / 255.0);
        assert_eq!(to_srgb8(linear), code);
        assert!((0.0..=1.0).contains(&linear));
    }
    for (v, code) in [
        (0.0, 0),
        (-0.0, 0),
        (1.0, 255),
        (-1e-300, 0),
        (-5.0, 0),
        (f64::NEG_INFINITY, 0),
        (1.0 + 1e-12, 255),
        (7.5, 255),
        (f64::MAX, 255),
        (f64::INFINITY, 255),
        (f64::NAN, 0),
        (f64::MIN_POSITIVE, 0),
    ] {
        assert_eq!(to_srgb8(v), code, "{v}");
    }
    let joint = 0.003_130_8;
    let (lo, hi) = (srgb_encode(joint), srgb_encode(joint + 1e-12));
    assert!((lo - hi).abs() < 1e-7, "{lo} {hi}");
    assert!((srgb_decode(0.040_45) - srgb_decode(0.040_45 + 1e-12)).abs() < 1e-8);
}

/// Strictly increasing wavelengths from `n` positive steps starting at `start` nm.
fn wavelengths() -> impl Strategy<Value = Vec<f64>> {
    (300.0..800.0f64, prop::collection::vec(0.5..60.0f64, 0..40)).prop_map(|(start, steps)| {
        let mut wl = vec![start];
        for s in steps {
            wl.push(wl[wl.len() - 1] + s);
        }
        wl
    })
}

fn illuminant() -> impl Strategy<Value = Illuminant> {
    prop_oneof![
        Just(Illuminant::D65),
        Just(Illuminant::A),
        Just(Illuminant::D50)
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// XYZ -> linear sRGB -> XYZ returns the colour (to the matrices' 7 decimals).
    #[test]
    fn xyz_round_trips_through_linear_srgb(xyz in prop::array::uniform3(-2.0..2.0f64)) {
        let back = linear_srgb_to_xyz(xyz_to_linear_srgb(xyz));
        for c in 0..3 {
            prop_assert!((back[c] - xyz[c]).abs() < 1e-6 * (1.0 + xyz[c].abs()), "{xyz:?} {back:?}");
        }
    }

    /// A perfect white (reflectance 1 everywhere) is Y = 1 and neutral under every illuminant,
    /// whatever the sampling (the weights of a constant spectrum sum to the white): R = G = B =
    /// 1 to rounding (the pipeline adapts the white to the matrix's); a grey of reflectance k
    /// gives k times that.
    #[test]
    fn white_is_neutral_for_any_sampling(wl in wavelengths(), ill in illuminant(), k in 0.0..3.0f64) {
        let w = SpectralWeights::new(&wl, ill).unwrap();
        let xyz = w.xyz(&vec![1.0; wl.len()]).unwrap();
        prop_assert!((xyz[1] - 1.0).abs() < 1e-12, "{xyz:?}");
        for (a, b) in xyz.iter().zip(ill.white_xyz()) {
            prop_assert!((a - b).abs() < 1e-12, "{xyz:?}");
        }
        let p = ColourPipeline::new(ill);
        let rgb = p.reflectance_to_rgb(&wl, &vec![k; wl.len()]).unwrap();
        for c in rgb {
            prop_assert!((c - k).abs() <= 1e-12 * k + 1e-15, "{ill}: {rgb:?} vs {k}");
        }
    }

    /// Spectral integration is linear: rgb(a s1 + b s2) = a rgb(s1) + b rgb(s2).
    #[test]
    fn spectral_integration_is_linear(
        wl in wavelengths(),
        ill in illuminant(),
        seed in prop::collection::vec(0.0..1.0f64, 82),
        a in -2.0..2.0f64,
        b in -2.0..2.0f64,
    ) {
        let n = wl.len();
        let (s1, s2) = (&seed[..n], &seed[41..41 + n]);
        let mix: Vec<f64> = s1.iter().zip(s2).map(|(x, y)| a * x + b * y).collect();
        let p = ColourPipeline::new(ill);
        let (r1, r2, rm) = (
            p.reflectance_to_rgb(&wl, s1).unwrap(),
            p.reflectance_to_rgb(&wl, s2).unwrap(),
            p.reflectance_to_rgb(&wl, &mix).unwrap(),
        );
        for c in 0..3 {
            let want = a * r1[c] + b * r2[c];
            prop_assert!((rm[c] - want).abs() < 1e-12 * (1.0 + want.abs()), "{rm:?} vs {want}");
        }
    }

    /// The 8-bit encoding never decreases with the linear value, over every finite f64.
    #[test]
    fn srgb8_is_monotone(a in prop::num::f64::ANY, b in prop::num::f64::ANY) {
        prop_assume!(!a.is_nan() && !b.is_nan());
        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
        prop_assert!(to_srgb8(lo) <= to_srgb8(hi), "{lo} {hi}");
    }

    /// CIEDE2000 is zero for equal colours, positive otherwise, symmetric.
    #[test]
    fn delta_e_is_symmetric_and_positive(
        l1 in 0.0..100.0f64, a1 in -100.0..100.0f64, b1 in -100.0..100.0f64,
        l2 in 0.0..100.0f64, a2 in -100.0..100.0f64, b2 in -100.0..100.0f64,
    ) {
        let (p, q) = ([l1, a1, b1], [l2, a2, b2]);
        prop_assert_eq!(delta_e_2000(p, p), 0.0);
        let d = delta_e_2000(p, q);
        prop_assert!(d.is_finite() && d >= 0.0);
        prop_assert!((d - delta_e_2000(q, p)).abs() < 1e-9 * (1.0 + d));
        if p != q {
            prop_assert!(d > 0.0);
        }
    }
}

/// A spectrum with fewer or more values than wavelengths is an error (it was integrated
/// silently: missing values counted as 0, extra ones dropped).
#[test]
fn spectra_of_the_wrong_length_are_refused() {
    let wl = [450.0, 550.0, 650.0];
    let p = ColourPipeline::new(Illuminant::D65);
    for spectrum in [&[0.5, 0.5][..], &[0.5; 4][..], &[][..]] {
        let err = p.reflectance_to_rgb(&wl, spectrum).unwrap_err().to_string();
        assert!(
            err.contains(&format!("{} values for 3 wavelengths", spectrum.len())),
            "{err}"
        );
    }
    assert!(p.reflectance_to_rgb(&wl, &[0.5; 3]).is_ok());
    let w = SpectralWeights::new(&wl, Illuminant::A).unwrap();
    assert!(w.xyz(&[1.0; 2]).is_err());
}
