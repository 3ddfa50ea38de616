//! Data transforms applied to BRDF values before the GPLVM sees them.
//!
//! `raw` is the paper's choice (the values themselves). `log` maps f to ln(1 + f / c), which
//! tames the dynamic range of specular peaks (chrome reaches 10^3-10^4 1/sr where felt stays near
//! 0.1) while staying close to linear, f / c, for small values. Both map 0 to 0, so cells below
//! the horizon (stored as 0 for every material) contribute nothing after centring.

use std::fmt;
use std::str::FromStr;

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

    /// Applies the transform to one value. Negative inputs are clamped to 0 first under `log`.
    #[inline]
    pub fn forward(&self, f: f64) -> f64 {
        match *self {
            Self::Raw => f,
            Self::Log { offset } => fast_ln_1p(f.max(0.0) / offset),
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

    /// Checks the parameters.
    pub fn check(self) -> Result<Self, Error> {
        match self {
            Self::Log { offset } if !(offset.is_finite() && offset > 0.0) => {
                Err(Error::InvalidConfig {
                    reason: format!("log transform offset must be finite and > 0, got {offset}"),
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
/// |y| <= 0.35, otherwise `2^k e^r - 1` with `y = k ln 2 + r` (Cody-Waite) and a series for
/// `e^r`. Overflows to infinity above ln(f64::MAX).
#[inline]
pub fn fast_exp_m1(y: f64) -> f64 {
    const LN2_HI: f64 = 6.931_471_803_691_238e-1;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    // Small |y|: y (1 + y/2 (1 + y/3 (... (1 + y/15)))).
    let mut t = 1.0;
    for k in (2..=15).rev() {
        t = 1.0 + y * INV[k] * t;
    }
    let small = y * t;
    // Large |y|.
    const MAX: f64 = 709.782_712_893_384;
    let yc = y.clamp(-700.0, MAX);
    let k = (yc * std::f64::consts::LOG2_E).round();
    let r = (yc - k * LN2_HI) - k * LN2_LO;
    let mut e = 1.0;
    for j in (1..=13).rev() {
        e = 1.0 + r * INV[j] * e;
    }
    // 2^(k - 1) (k <= 1024 near the overflow threshold), times 2 exactly.
    let scale = f64::from_bits(((k as i64 + 1022) as u64) << 52);
    let large = (e * scale) * 2.0 - 1.0;
    if y.abs() <= 0.35 {
        small
    } else if y > MAX {
        f64::INFINITY
    } else {
        large
    }
}

/// 1/k for k = 0..=15 (0 unused).
const INV: [f64; 16] = [
    0.0,
    1.0,
    1.0 / 2.0,
    1.0 / 3.0,
    1.0 / 4.0,
    1.0 / 5.0,
    1.0 / 6.0,
    1.0 / 7.0,
    1.0 / 8.0,
    1.0 / 9.0,
    1.0 / 10.0,
    1.0 / 11.0,
    1.0 / 12.0,
    1.0 / 13.0,
    1.0 / 14.0,
    1.0 / 15.0,
];

impl fmt::Display for Transform {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Raw => write!(f, "raw"),
            Self::Log { offset } => write!(f, "log(offset={offset})"),
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
                    reason: format!("unknown transform {other:?}: expected raw, log or log:OFFSET"),
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
        assert!("sqrt".parse::<Transform>().is_err());
        assert_eq!(
            Transform::Log { offset: 0.5 }.to_string(),
            "log(offset=0.5)"
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

    proptest! {
        #[test]
        fn inverse_round_trips(f in 0.0..1e6f64, c in 1e-4..10.0f64) {
            let t = Transform::Log { offset: c };
            let back = t.inverse(t.forward(f));
            prop_assert!((back - f).abs() <= 1e-12 * f.max(c), "{f} -> {back}");
        }
    }
}
