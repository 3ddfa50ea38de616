//! Data transforms applied to BRDF values before the GPLVM sees them.
//!
//! `raw` is the paper's choice (the values themselves). `log` maps f to ln(1 + f / c), which
//! tames the dynamic range of specular peaks (chrome reaches 10^3-10^4 1/sr where felt stays near
//! 0.1) while staying close to linear, f / c, for small values. Both map 0 to 0, so cells below
//! the horizon (stored as 0 for every material) contribute nothing after centring.

use std::fmt;
use std::str::FromStr;

use brdf_io::store::GramTransform;
use serde::{Deserialize, Serialize};

use crate::error::Error;

/// A pointwise, invertible transform of BRDF values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Transform {
    /// y = f (the paper).
    Raw,
    /// y = ln(1 + f / offset), inverse f = offset (e^y - 1).
    Log {
        /// The offset c > 0 (1/sr): values well below c are mapped almost linearly.
        offset: f64,
    },
}

impl Transform {
    /// The default offset of the log transform, in 1/sr.
    pub const DEFAULT_LOG_OFFSET: f64 = 0.01;

    /// Applies the transform to one value. Negative inputs are clamped to 0 first under `log`;
    /// NaN stays NaN.
    #[inline]
    pub fn forward(&self, f: f64) -> f64 {
        match *self {
            Self::Raw => f,
            Self::Log { offset } => fast_ln_1p(clamp_negative(f) / offset),
        }
    }

    /// Inverts the transform of one value.
    #[inline]
    pub fn inverse(&self, y: f64) -> f64 {
        match *self {
            Self::Raw => y,
            Self::Log { offset } => offset * fast_exp_m1(y),
        }
    }

    /// [`Transform::forward`] of a batch of stored values (vectorised; within 1e-14 of the
    /// scalar version): `out[i] = forward(input[i])`.
    ///
    /// # Panics
    /// If `input` and `out` differ in length.
    pub fn forward_batch(&self, input: &[f32], out: &mut [f64]) {
        GramTransform::to_f64(self, input, out);
    }

    /// [`Transform::inverse`] of a batch, in place (vectorised with AVX-512, or AVX2 + FMA, when
    /// the CPU has them: [`exp_m1_scaled_in_place`]; the same arithmetic as the scalar version).
    pub fn inverse_in_place(&self, values: &mut [f64]) {
        if let Self::Log { offset } = *self {
            exp_m1_scaled_in_place(values, offset);
        }
    }

    /// Checks the parameters.
    pub fn check(self) -> Result<Self, Error> {
        match self {
            Self::Log { offset } if !(offset.is_finite() && offset > 0.0) => {
                Err(Error::InvalidConfig {
                    field: "transform",
                    value: format!("log:{offset}"),
                    expected: "log:OFFSET with an offset that is finite and > 0".into(),
                })
            }
            t => Ok(t),
        }
    }
}

/// `ln(1 + x)` for finite `x >= 0`, with relative error below 1e-14 (tested against
/// [`f64::ln_1p`]), about 5x faster and free of calls, so loops over it vectorise: `u = 1 + x`
/// split as `m 2^e` with `m` in [sqrt(1/2), sqrt(2)), `ln m = 2 atanh((m - 1)/(m + 1))` by its
/// series (9 terms), and Goldberg's correction `ln(u) x / (u - 1)` for the rounding of `u`.
#[inline]
pub fn fast_ln_1p(x: f64) -> f64 {
    use std::f64::consts::{LN_2, SQRT_2};
    let u = 1.0 + x;
    let bits = u.to_bits();
    let e0 = ((bits >> 52) & 0x7ff) as i64 - 1023;
    let m0 = f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000);
    let big = m0 > SQRT_2;
    let m = if big { 0.5 * m0 } else { m0 };
    let e = (e0 + i64::from(big)) as f64;
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let p = 1.0
        + s2 * (1.0 / 3.0
            + s2 * (1.0 / 5.0
                + s2 * (1.0 / 7.0
                    + s2 * (1.0 / 9.0
                        + s2 * (1.0 / 11.0
                            + s2 * (1.0 / 13.0 + s2 * (1.0 / 15.0 + s2 * (1.0 / 17.0))))))));
    let ln_u = e * LN_2 + 2.0 * s * p;
    let d = u - 1.0;
    if d == 0.0 { x } else { ln_u * (x / d) }
}

/// `e^y - 1` with relative error below 1e-14 (tested against [`f64::exp_m1`]), several times
/// faster than the C library's `expm1` here and free of calls: a Taylor series for
/// |y| <= 0.35, otherwise [`gp_core::fastmath::exp_lanes`]`(y) - 1` (Cody-Waite reduction and a
/// series for `e^r`). Overflows to infinity above ln(f64::MAX).
#[inline(always)]
pub fn fast_exp_m1(y: f64) -> f64 {
    // Small |y|: y sum_{k=0}^{12} y^k / (k + 1)! (truncation below 2e-17 relative for
    // |y| <= 0.35), by Estrin's scheme so consecutive values overlap.
    // c[k] = 1 / (k + 1)!.
    let (y2, c) = (y * y, &gp_core::fastmath::FACT_INV[1..]);
    let y4 = y2 * y2;
    let y8 = y4 * y4;
    let p0 = (c[0] + y * c[1]) + y2 * (c[2] + y * c[3]);
    let p1 = (c[4] + y * c[5]) + y2 * (c[6] + y * c[7]);
    let p2 = (c[8] + y * c[9]) + y2 * (c[10] + y * c[11]);
    let small = y * ((p0 + y4 * p1) + y8 * (p2 + y4 * c[12]));
    // Large |y|: e^y - 1 (no cancellation worth the name above 0.35).
    let large = gp_core::fastmath::exp_lanes(y) - 1.0;
    if y.abs() <= 0.35 { small } else { large }
}

/// `v = scale (e^v - 1)` in place: [`fast_exp_m1`] over a slice, compiled for AVX-512 or AVX2 +
/// FMA when the CPU has them (selected at run time) so the loop runs 8 or 4 lanes wide, a short
/// slice's last values included (they run in a zero-padded block).
pub fn exp_m1_scaled_in_place(values: &mut [f64], scale: f64) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above; it implies AVX2 and FMA),
            // the only requirement of a `#[target_feature]` function.
            unsafe { exp_m1_scaled_avx512(values, scale) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above), the only requirement
            // of a `#[target_feature]` function.
            unsafe { exp_m1_scaled_avx2(values, scale) };
            return;
        }
    }
    exp_m1_scaled_portable(values, scale);
}

/// [`exp_m1_scaled_in_place`] without vector features.
fn exp_m1_scaled_portable(values: &mut [f64], scale: f64) {
    values.iter_mut().for_each(|v| *v = scale * fast_exp_m1(*v));
}

/// [`exp_m1_scaled_in_place`] compiled for AVX-512 (8 lanes; the same arithmetic, so the same
/// bits as the AVX2 version).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn exp_m1_scaled_avx512(values: &mut [f64], scale: f64) {
    // SAFETY: the caller guarantees AVX-512F, which the loop needs.
    padded_tail(values, |v| unsafe { exp_m1_scaled_loop_avx512(v, scale) });
}

/// The loop of [`exp_m1_scaled_avx512`] (not inlined: the compiler vectorises it only for a
/// length it does not know).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
#[inline(never)]
unsafe fn exp_m1_scaled_loop_avx512(values: &mut [f64], scale: f64) {
    values.iter_mut().for_each(|v| *v = scale * fast_exp_m1(*v));
}

/// [`exp_m1_scaled_in_place`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn exp_m1_scaled_avx2(values: &mut [f64], scale: f64) {
    // SAFETY: the caller guarantees AVX2 and FMA, which the loop needs.
    padded_tail(values, |v| unsafe { exp_m1_scaled_loop_avx2(v, scale) });
}

/// The loop of [`exp_m1_scaled_avx2`] (not inlined, as [`exp_m1_scaled_loop_avx512`]).
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline(never)]
unsafe fn exp_m1_scaled_loop_avx2(values: &mut [f64], scale: f64) {
    values.iter_mut().for_each(|v| *v = scale * fast_exp_m1(*v));
}

/// Runs the element-wise `f` over `values` in whole blocks of 8 values: the last, partial block
/// is copied into a zero-padded block first, so that a short slice (a lazy lookup's 22
/// wavelengths) runs in vector lanes instead of a scalar tail. `f` treats every value alike,
/// so the results are the same bits as one call on `values`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn padded_tail(values: &mut [f64], mut f: impl FnMut(&mut [f64])) {
    let (whole, rest) = values.split_at_mut(values.len() / 8 * 8);
    if !whole.is_empty() {
        f(whole);
    }
    if !rest.is_empty() {
        let mut padded = [0.0; 8];
        padded[..rest.len()].copy_from_slice(rest);
        f(&mut padded);
        rest.copy_from_slice(&padded[..rest.len()]);
    }
}

/// `out[i] = ln(1 + max(input[i], 0) * scale)` in f64 with relative error below 2e-15 (tested
/// against [`f64::ln_1p`]); the loop vectorises (8 lanes with AVX-512, 4 with AVX2 + FMA,
/// selected at run time). `ln u = k ln 2 + 2 atanh(s)`, `s = (m - 1)/(m + 1)`, arranged so that
/// every operation stays in SIMD lanes: the reduction `u = 2^k m`, m in [sqrt(1/2), sqrt(2)),
/// is integer arithmetic on the bits, the exponent becomes a float through the 2^52 trick
/// (AVX2 has no 64-bit integer to float conversion), `m - 1` is `x` itself below sqrt(2) (so
/// the rounding of `u = 1 + x` never enters), and `2 atanh(s) / s` is a degree-6 polynomial in
/// `s^2` (`LN_SERIES`, by FMAs). About 0.7 ns per value on one core of the Zen 4 here, data in
/// cache, ~0.14 ns of it the widening and the store (the division and the FP pipes bound it;
/// BENCHMARKS.md "gplvm", session 15).
///
/// # Panics
/// If `input` and `out` differ in length.
pub fn ln_1p_scaled_f64(input: &[f32], scale: f64, out: &mut [f64]) {
    assert_eq!(input.len(), out.len());
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above; it implies AVX2 and FMA),
            // the only requirement of a `#[target_feature]` function.
            unsafe { ln_1p_scaled_f64_avx512(input, scale, out) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above), the only requirement
            // of a `#[target_feature]` function.
            unsafe { ln_1p_scaled_f64_avx2(input, scale, out) };
            return;
        }
    }
    ln_1p_scaled_f64_portable(input, scale, out);
}

/// [`ln_1p_scaled_f64`] without vector features.
fn ln_1p_scaled_f64_portable(input: &[f32], scale: f64, out: &mut [f64]) {
    for (o, v) in out.iter_mut().zip(input) {
        *o = ln_1p_lanes(f64::from(*v) * scale);
    }
}

/// [`ln_1p_scaled_f64`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn ln_1p_scaled_f64_avx2(input: &[f32], scale: f64, out: &mut [f64]) {
    for (o, v) in out.iter_mut().zip(input) {
        *o = ln_1p_lanes(f64::from(*v) * scale);
    }
}

/// [`ln_1p_scaled_f64`] compiled for AVX-512 (8 lanes; the same arithmetic, so the same bits as
/// the AVX2 version, tested).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn ln_1p_scaled_f64_avx512(input: &[f32], scale: f64, out: &mut [f64]) {
    for (o, v) in out.iter_mut().zip(input) {
        *o = ln_1p_lanes(f64::from(*v) * scale);
    }
}

/// `max(x, 0)` that keeps a NaN (`f64::max` would turn it into 0, silently hiding damaged
/// data; the transforms must pass it on so the Gram pass can refuse it).
#[inline(always)]
fn clamp_negative(x: f64) -> f64 {
    if x < 0.0 { 0.0 } else { x }
}

/// Coefficients of `p(z) ~ 2 atanh(s) / s` (`z = s^2`) for |s| <= (sqrt 2 - 1)/(sqrt 2 + 1):
/// the series `2 sum z^j / (2j + 1)` to degree 16 economised to degree 6 by shifted Chebyshev
/// polynomials on [0, 0.02944] (exact rational arithmetic; economisation error below 1.8e-16
/// of `p`).
const LN_SERIES: [f64; 7] = [
    2.000_000_000_000_000_4,
    0.666_666_666_665_523_7,
    0.400_000_000_619_624_6,
    0.285_714_159_890_576_8,
    0.222_234_366_494_193_56,
    0.181_218_709_076_424_23,
    0.168_383_798_093_369_26,
];

/// One value of [`ln_1p_scaled_f64`] (negative inputs give 0, NaN and infinity give NaN).
#[inline(always)]
fn ln_1p_lanes(x: f64) -> f64 {
    use std::f64::consts::{FRAC_1_SQRT_2, LN_2};
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    let x = clamp_negative(x);
    let u = 1.0 + x;
    let bits = u.to_bits();
    // u = 2^k m with m in [sqrt(1/2), sqrt(2)) by integer arithmetic on the bits: subtracting
    // the bits of sqrt(1/2) carries into the exponent field exactly when the mantissa of u is
    // at least that of sqrt(1/2). (u >= 1: no sign bit, k >= 0.)
    let kq = bits.wrapping_sub(FRAC_1_SQRT_2.to_bits()) >> 52;
    let m = f64::from_bits(bits - (kq << 52));
    let k = f64::from_bits(kq | TWO_52.to_bits()) - TWO_52;
    // f = m - 1. Below sqrt(2) (k = 0) that is x itself, exact where u = 1 + x is rounded;
    // above, the rounding of u is at most 3.2e-16 of ln u.
    let f = if kq == 0 { x } else { m - 1.0 };
    let s = f / (f + 2.0);
    let z = s * s;
    // p(z) by Estrin's scheme (short dependency chains).
    let c = &LN_SERIES;
    let z2 = z * z;
    let z4 = z2 * z2;
    let p01 = z.mul_add(c[1], c[0]);
    let p23 = z.mul_add(c[3], c[2]);
    let p45 = z.mul_add(c[5], c[4]);
    let p46 = z2.mul_add(c[6], p45);
    let p03 = z2.mul_add(p23, p01);
    let p = z4.mul_add(p46, p03);
    // 0 x is 0, or NaN for a NaN or infinite x, whose bits the reduction above loses.
    k.mul_add(LN_2, s.mul_add(p, 0.0 * x))
}

impl GramTransform for Transform {
    /// Batch version of [`Transform::forward`] (vectorised; within 1e-14 of it).
    fn to_f64(&self, input: &[f32], out: &mut [f64]) {
        match *self {
            Self::Raw => brdf_io::store::Identity.to_f64(input, out),
            Self::Log { offset } => ln_1p_scaled_f64(input, 1.0 / offset, out),
        }
    }
}

impl fmt::Display for Transform {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Raw => write!(f, "raw"),
            // Plain decimals in the usual range, the exponent form outside it (an offset of
            // 1e-300 was written with 300 zeros).
            Self::Log { offset } if (1e-4..1e6).contains(offset) => {
                write!(f, "log(offset={offset})")
            }
            Self::Log { offset } => write!(f, "log(offset={offset:e})"),
        }
    }
}

impl FromStr for Transform {
    type Err = Error;

    /// Parses `raw`, `log` (default offset) or `log:C`.
    fn from_str(s: &str) -> Result<Self, Error> {
        match s.trim() {
            "raw" => Ok(Self::Raw),
            "log" => Ok(Self::Log {
                offset: Self::DEFAULT_LOG_OFFSET,
            }),
            other => match other.strip_prefix("log:").map(str::parse::<f64>) {
                Some(Ok(offset)) => Self::Log { offset }.check(),
                _ => Err(Error::InvalidConfig {
                    field: "transform",
                    value: format!("{other:?}"),
                    expected: "raw, log or log:OFFSET".into(),
                }),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn parse_and_display() {
        assert_eq!("raw".parse::<Transform>().unwrap(), Transform::Raw);
        assert_eq!(
            "log:0.5".parse::<Transform>().unwrap(),
            Transform::Log { offset: 0.5 }
        );
        assert!("log:-1".parse::<Transform>().is_err());
        // The offset must be finite and > 0 (at 0 the log of a zero value is -inf).
        for bad in [0.0, -0.0, f64::INFINITY, f64::NAN] {
            let e = Transform::Log { offset: bad }
                .check()
                .unwrap_err()
                .to_string();
            assert!(e.contains("finite and > 0"), "{bad}: {e}");
        }
        assert!(Transform::Log { offset: 1e-300 }.check().is_ok());
        assert!("sqrt".parse::<Transform>().is_err());
        assert_eq!(
            Transform::Log { offset: 0.5 }.to_string(),
            "log(offset=0.5)"
        );
        assert_eq!(
            Transform::Log { offset: 1e-300 }.to_string(),
            "log(offset=1e-300)"
        );
        assert_eq!(
            Transform::Log { offset: 2.5e7 }.to_string(),
            "log(offset=2.5e7)"
        );
    }

    #[test]
    fn zero_maps_to_zero_and_log_compresses_peaks() {
        let t = Transform::Log { offset: 0.01 };
        assert_eq!(t.forward(0.0), 0.0);
        assert_eq!(t.forward(-0.5), 0.0);
        // A 10^4 dynamic range between felt (0.1) and a chrome peak (1000) becomes ~4.
        let ratio = t.forward(1000.0) / t.forward(0.1);
        assert!(ratio > 4.0 && ratio < 5.0, "ratio = {ratio}");
    }

    #[test]
    fn fast_ln_1p_and_exp_m1_match_the_standard_library() {
        let mut worst = 0.0f64;
        let mut x = 1e-30;
        while x < 1e12 {
            for k in [1.0, 1.37, 2.9, 7.3] {
                let v = x * k;
                let (a, b) = (fast_ln_1p(v), v.ln_1p());
                worst = worst.max((a - b).abs() / b);
            }
            x *= 1.7;
        }
        assert!(worst < 1e-14, "worst relative error {worst:e}");
        assert_eq!(fast_ln_1p(0.0), 0.0);
        let mut worst = 0.0f64;
        let mut y = -720.0;
        while y < 720.0 {
            let (a, b) = (fast_exp_m1(y), y.exp_m1());
            if b.is_finite() {
                worst = worst.max((a - b).abs() / b.abs().max(f64::MIN_POSITIVE));
            } else {
                assert_eq!(a, f64::INFINITY, "y = {y}");
            }
            y += 0.0137;
        }
        for y in [1e-300, -1e-300, 1e-12, -1e-12, 0.349, -0.349, 0.351, -0.351] {
            worst = worst.max((fast_exp_m1(y) - y.exp_m1()).abs() / y.exp_m1().abs());
        }
        assert!(worst < 1e-14, "exp_m1 worst relative error {worst:e}");
        assert_eq!(fast_exp_m1(0.0), 0.0);
        // Around sqrt(2) - 1, where the mantissa range switches.
        for k in -50..50 {
            let v = std::f64::consts::SQRT_2 - 1.0 + f64::from(k) * 1e-12;
            assert!((fast_ln_1p(v) - v.ln_1p()).abs() < 1e-15);
        }
    }

    /// The AVX-512, AVX2 and portable builds of the batch transforms give the same bits
    /// (fits are chaotic in the last bits of the Gram matrix, so they must not depend on the
    /// CPU's vector width); each build is checked where the CPU has it.
    #[test]
    fn vector_builds_of_the_batch_transforms_agree_bitwise() {
        let xs: Vec<f32> = (0..4099)
            .map(|i| 1e-6 * 1.0071f64.powi(i) as f32 * if i % 17 == 0 { -1.0 } else { 1.0 })
            .collect();
        let scale = 1.0 / 0.01;
        let want: Vec<u64> = xs
            .iter()
            .map(|v| ln_1p_lanes(f64::from(*v) * scale).to_bits())
            .collect();
        let ys: Vec<f64> = (0..4099).map(|i| f64::from(i) * 0.003 - 2.0).collect();
        let want_inv: Vec<u64> = ys
            .iter()
            .map(|y| (0.01 * fast_exp_m1(*y)).to_bits())
            .collect();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        type Ln = unsafe fn(&[f32], f64, &mut [f64]);
        type Exp = unsafe fn(&mut [f64], f64);
        let mut builds: Vec<(&str, Ln, Exp)> = vec![(
            "portable",
            ln_1p_scaled_f64_portable,
            exp_m1_scaled_portable,
        )];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                builds.push(("AVX-512", ln_1p_scaled_f64_avx512, exp_m1_scaled_avx512));
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                builds.push(("AVX2", ln_1p_scaled_f64_avx2, exp_m1_scaled_avx2));
            }
        }
        for (name, ln, exp) in &builds {
            let mut out = vec![0.0; xs.len()];
            // SAFETY: each build is listed only when the CPU has its features (checked above).
            unsafe { ln(&xs, scale, &mut out) };
            assert_eq!(bits(&out), want, "ln, {name}");
            let mut inv = ys.clone();
            // SAFETY: as above.
            unsafe { exp(&mut inv, 0.01) };
            assert_eq!(bits(&inv), want_inv, "exp_m1, {name}");
            // Short slices (a lazy lookup's wavelengths) run through a zero-padded last block.
            for len in 0..=25 {
                let at = 37 * len;
                let mut short = ys[at..at + len].to_vec();
                // SAFETY: as above.
                unsafe { exp(&mut short, 0.01) };
                assert_eq!(
                    bits(&short),
                    want_inv[at..at + len],
                    "exp_m1, {name}, {len}"
                );
            }
        }
        let mut out = vec![0.0; xs.len()];
        ln_1p_scaled_f64(&xs, scale, &mut out);
        assert_eq!(bits(&out), want, "ln, dispatched");
        let mut inv = ys.clone();
        exp_m1_scaled_in_place(&mut inv, 0.01);
        assert_eq!(bits(&inv), want_inv, "exp_m1, dispatched");
        eprintln!(
            "{} vector builds checked besides the dispatched one",
            builds.len()
        );
    }

    #[test]
    fn batch_f64_ln_1p_matches_the_standard_library() {
        let mut xs = vec![
            0.0f32, -3.0, 1e-30, 1e-8, 5.9e-8, 1e-4, 0.4142, 0.4143, 1.0, 3.0,
        ];
        let mut x = 1e-30f64;
        while x < 1e30 {
            for k in [1.0, 1.37, 2.9, 7.3] {
                xs.push((x * k) as f32);
            }
            x *= 1.13;
        }
        for scale in [1.0, 100.0, 1.0 / 3.0] {
            let mut out = vec![0.0; xs.len()];
            ln_1p_scaled_f64(&xs, scale, &mut out);
            for (v, y) in xs.iter().zip(&out) {
                let want = (f64::from(*v).max(0.0) * scale).ln_1p();
                let err = (y - want).abs() / want.max(f64::MIN_POSITIVE);
                assert!(
                    err < 2e-15 || (want == 0.0 && *y == 0.0),
                    "x = {v}: {y} vs {want}"
                );
            }
        }
        // and the Gram transform agrees with the scalar forward transform.
        let t = Transform::Log { offset: 0.01 };
        let mut out = vec![0.0; xs.len()];
        t.to_f64(&xs, &mut out);
        for (v, y) in xs.iter().zip(&out) {
            let want = t.forward(f64::from(*v));
            assert!((y - want).abs() <= 1e-14 * want.abs(), "x = {v}");
        }
    }

    #[test]
    fn non_finite_values_are_not_hidden() {
        let t = Transform::Log { offset: 0.01 };
        assert!(t.forward(f64::NAN).is_nan());
        let input = [1.0f32, f32::NAN, f32::INFINITY, -2.0, 0.5];
        let mut out = [0.0; 5];
        t.forward_batch(&input, &mut out);
        assert!(out[1].is_nan() && !out[2].is_finite(), "{out:?}");
        assert_eq!(out[3], 0.0);
        assert!((out[0] - 100f64.ln_1p()).abs() < 1e-13 && out[4] > 0.0);
    }

    #[test]
    fn batch_inverse_equals_the_scalar_inverse() {
        let t = Transform::Log { offset: 0.01 };
        let ys: Vec<f64> = (0..20_000)
            .map(|i| -720.0 + 0.0731 * f64::from(i))
            .collect();
        let mut batch = ys.clone();
        t.inverse_in_place(&mut batch);
        for (y, b) in ys.iter().zip(&batch) {
            let want = 0.01 * y.exp_m1();
            if want.is_finite() {
                assert!(
                    (b - want).abs() <= 1e-14 * want.abs(),
                    "y = {y}: {b} vs {want}"
                );
            } else {
                assert_eq!(*b, f64::INFINITY);
            }
            assert!((b - t.inverse(*y)).abs() <= 1e-15 * b.abs() || b == &t.inverse(*y));
        }
        let mut raw = ys.clone();
        Transform::Raw.inverse_in_place(&mut raw);
        assert_eq!(raw, ys);
    }

    proptest! {
        #[test]
        fn inverse_round_trips(f in 0.0..1e6f64, c in 1e-4..10.0f64) {
            let t = Transform::Log { offset: c };
            let back = t.inverse(t.forward(f));
            prop_assert!((back - f).abs() <= 1e-12 * f.max(c), "{f} -> {back}");
        }
    }
}
