//! Properties of the colour pipeline: the XYZ <-> sRGB matrices, white points, linearity of
//! spectral integration and exposure, the 8-bit sRGB encoding at and beyond its ends, and
//! CIEDE2000's metric basics; CIELAB, the CIE tables' interpolation and the observer's
//! quadrature against independent values.

use proptest::prelude::*;
use render::colour::{
    ColourPipeline, Illuminant, SRGB_TO_XYZ, SpectralWeights, XYZ_TO_SRGB, cmf, coverage_warning,
    delta_e_2000, delta_e_2000_rgb, linear_srgb_to_lab, linear_srgb_to_xyz, srgb_decode,
    srgb_encode, to_srgb8, xyz_to_lab, xyz_to_linear_srgb,
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

/// CIELAB of the sRGB primaries and greys (D65, the sRGB matrices' white) are Lindbloom's
/// published values, and below the CIE's epsilon = 216/24389 the lightness is the linear
/// kappa = 24389/27 times Y (the formula's dark segment, 6/29 form), not a cube root.
#[test]
fn cielab_matches_published_values_in_both_segments() {
    for (rgb, want) in [
        ([1.0, 0.0, 0.0], [53.2408, 80.0925, 67.2032]),
        ([0.0, 1.0, 0.0], [87.7347, -86.1827, 83.1793]),
        ([0.0, 0.0, 1.0], [32.2970, 79.1875, -107.8602]),
        ([1.0, 1.0, 1.0], [100.0, 0.0, 0.0]),
        ([0.18, 0.18, 0.18], [49.4961, 0.0, 0.0]),
    ] {
        let lab = linear_srgb_to_lab(rgb);
        for c in 0..3 {
            assert!(
                (lab[c] - want[c]).abs() < 1e-4,
                "{rgb:?}: {lab:?} vs {want:?}"
            );
        }
    }
    let white = [0.9, 1.1, 1.3];
    let (epsilon, kappa) = (216.0 / 24389.0, 24389.0 / 27.0);
    for t in [0.0, 1e-6, 0.002, 0.5 * epsilon, epsilon] {
        // Equal ratios to the white: a neutral colour, a = b = 0.
        let lab = xyz_to_lab(white.map(|w| t * w), white);
        assert!((lab[0] - kappa * t).abs() < 1e-12, "{t}: {lab:?}");
        assert!(lab[1].abs() < 1e-12 && lab[2].abs() < 1e-12, "{t}: {lab:?}");
    }
    // Each of a and b follows its own ratio: X alone at 0.5 of the white's X, Y and Z at 0.25.
    let lab = xyz_to_lab([0.5 * white[0], 0.25 * white[1], 0.25 * white[2]], white);
    let (fx, fy) = (0.5f64.cbrt(), 0.25f64.cbrt());
    let want = [116.0 * fy - 16.0, 500.0 * (fx - fy), 0.0];
    for c in 0..3 {
        assert!((lab[c] - want[c]).abs() < 1e-12, "{lab:?} vs {want:?}");
    }
}

/// Illuminant names parse case-insensitively with surrounding space, print as they parse, and
/// an unknown name is an error that lists the known ones.
#[test]
fn illuminant_names_round_trip() {
    for (text, ill) in [
        ("D65", Illuminant::D65),
        (" d50 ", Illuminant::D50),
        ("a", Illuminant::A),
    ] {
        assert_eq!(text.parse::<Illuminant>().unwrap(), ill);
        assert_eq!(ill.to_string().parse::<Illuminant>().unwrap(), ill);
        assert_eq!(ill.to_string(), text.trim().to_ascii_uppercase());
    }
    let e = "F2".parse::<Illuminant>().unwrap_err().to_string();
    assert!(e.contains("\"F2\"") && e.contains("D65, D50 or A"), "{e}");
}

/// The CIE tables are interpolated linearly between their 5 nm rows and are 0 outside
/// 360-780 nm (not extrapolated from the end rows).
#[test]
fn cie_tables_interpolate_linearly_and_stop_at_their_ends() {
    let row = |nm: usize| render::cie::CMF_1931_2DEG[(nm - 360) / 5];
    for (nm, lo, t) in [(362.0, 360, 0.4), (557.5, 555, 0.5), (779.0, 775, 0.8)] {
        let (a, b) = (row(lo), row(lo + 5));
        let got = cmf(nm);
        for c in 0..3 {
            let want = (1.0 - t) * a[c] + t * b[c];
            assert!((got[c] - want).abs() <= 1e-12 * want.abs(), "{nm}: {got:?}");
        }
        let d65 = |nm: usize| render::cie::D65[(nm - 360) / 5];
        let want = (1.0 - t) * d65(lo) + t * d65(lo + 5);
        assert!(
            (Illuminant::D65.spd(nm) - want).abs() <= 1e-12 * want,
            "{nm}"
        );
    }
    assert_eq!(cmf(780.0), row(780));
    for nm in [359.9, 780.5, 785.0, 790.0, 1000.0] {
        assert_eq!(cmf(nm), [0.0; 3], "{nm}");
        assert_eq!(Illuminant::A.spd(nm), 0.0, "{nm}");
    }
}

/// The observer's weights are a 1 nm trapezoid rule over 360-780 nm of hat functions on the
/// samples: on a 1 nm sampling each weight is its own wavelength's term, halved at both ends;
/// and a spectrum linear in the wavelength, sampled unevenly over 360-780 nm, is interpolated
/// exactly, so it has the colour of its 1 nm sampling.
#[test]
fn spectral_weights_are_a_trapezoid_rule_on_hat_functions() {
    let fine: Vec<f64> = (360..=780).map(f64::from).collect();
    let w = SpectralWeights::new(&fine, Illuminant::D65).unwrap();
    assert!(!w.is_empty() && w.len() == fine.len());
    let term = |nm: f64| cmf(nm).map(|c| c * Illuminant::D65.spd(nm));
    // Y weights sum to 1 (white), so the normalisation is the sum of the Y terms.
    let q = |k: usize| {
        if k == 0 || k == fine.len() - 1 {
            0.5
        } else {
            1.0
        }
    };
    let norm: f64 = (0..fine.len()).map(|k| q(k) * term(fine[k])[1]).sum();
    for k in [0, 1, 200, fine.len() - 2, fine.len() - 1] {
        let want = term(fine[k]).map(|t| q(k) * t / norm);
        let got = [w.x[k], w.y[k], w.z[k]];
        for c in 0..3 {
            assert!(
                (got[c] - want[c]).abs() <= 1e-12 * want[c].abs(),
                "{} nm: {got:?} vs {want:?}",
                fine[k]
            );
        }
    }
    let coarse = [360.0, 420.0, 455.0, 500.0, 610.0, 700.0, 780.0];
    let line = |nm: f64| 0.2 + (nm - 360.0) / 600.0;
    let wc = SpectralWeights::new(&coarse, Illuminant::D65).unwrap();
    let a = wc.xyz(&coarse.map(line)).unwrap();
    let b = w
        .xyz(&fine.iter().map(|&nm| line(nm)).collect::<Vec<_>>())
        .unwrap();
    for c in 0..3 {
        assert!((a[c] - b[c]).abs() < 1e-12, "{a:?} vs {b:?}");
    }
}

/// A render's per-channel weights give a spectrum the pipeline's colour (`rgb = W * values`),
/// under every illuminant; RGB sources pass through unchanged.
#[test]
fn channel_weights_give_the_pipelines_colour() {
    let wl = [380.0, 430.0, 470.0, 520.0, 560.0, 610.0, 650.0, 720.0];
    let spectrum = [0.1, 0.7, 0.3, 0.9, 0.2, 0.5, 0.8, 0.4];
    for ill in [Illuminant::D65, Illuminant::D50, Illuminant::A] {
        let p = ColourPipeline::new(ill);
        let weights = p
            .channel_weights(&brdf_io::Channels::Spectral(wl.to_vec()))
            .unwrap();
        let want = p.reflectance_to_rgb(&wl, &spectrum).unwrap();
        for (c, row) in weights.iter().enumerate() {
            let got: f64 = row.iter().zip(&spectrum).map(|(w, s)| w * s).sum();
            assert!(
                (got - want[c]).abs() < 1e-13,
                "{ill} channel {c}: {got} vs {want:?}"
            );
        }
        let rgb = p.channel_weights(&brdf_io::Channels::Rgb).unwrap();
        assert_eq!(
            rgb,
            [
                vec![1.0, 0.0, 0.0],
                vec![0.0, 1.0, 0.0],
                vec![0.0, 0.0, 1.0]
            ]
        );
    }
}

/// The coverage warning names a single sample's wavelength alone and a range by its ends.
#[test]
fn coverage_warnings_name_the_span_sampled() {
    let one = coverage_warning(&[500.0], Illuminant::D65).unwrap();
    assert!(one.contains("at 500 nm,"), "{one}");
    let two = coverage_warning(&[425.0, 475.0], Illuminant::D65).unwrap();
    assert!(two.contains("at 425-475 nm,"), "{two}");
}

/// CIEDE2000 where Sharma's table has no pair: mean hues that wrap through 0 (352 and 27
/// degrees), a mean hue near 275 degrees where the rotation term peaks, and hue sums either
/// side of 360 degrees, with unequal chromas so that the rotation term counts. The references
/// come from an independent implementation, `scripts/ciede2000_reference.py` (hue difference and
/// mean hue as circular quantities via atan2 rather than the paper's case analysis; it
/// reproduces Sharma's table).
/// And a colour on the negative a axis (hue 180 degrees) is as close to its neighbours as
/// anywhere else. Between linear sRGB colours the difference is taken in CIELAB (the
/// ColorChecker test alone would pass any constant below 1.5).
#[test]
fn ciede2000_wraps_hue_means_and_differences_as_circular_quantities() {
    for (p, q, want) in [
        (
            [50.0, 19.69615506024416, -3.472963553338608],
            [50.0, 25.98076211353316, 14.999999999999998],
            12.211278701714562,
        ),
        (
            [60.0, 29.981724810572874, 1.0469849010750292],
            [60.0, -19.805361374831406, -2.7834620192013104],
            41.12802431616528,
        ),
        (
            [55.0, 1.7431148549531628, 19.92389396183491],
            [55.0, -1.0469849010750227, -29.981724810572874],
            32.648553256091496,
        ),
    ] {
        for (a, b) in [(p, q), (q, p)] {
            let d = delta_e_2000(a, b);
            assert!((d - want).abs() < 1e-9, "{a:?} {b:?}: {d} vs {want}");
        }
    }
    let d = delta_e_2000([50.0, -20.0, 0.0], [50.0, -20.0, 1e-6]);
    assert!((d - 7.251164537465866e-7).abs() < 1e-12, "{d}");
    // Between linear sRGB colours, through CIELAB (references from the same script).
    for (a, b, want) in [
        ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 52.88136527892262),
        ([0.2, 0.5, 0.1], [0.25, 0.45, 0.12], 3.9875183560497933),
    ] {
        let d = delta_e_2000_rgb(a, b);
        assert!((d - want).abs() < 1e-9, "{a:?} {b:?}: {d} vs {want}");
    }
}
