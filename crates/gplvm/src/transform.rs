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
            Self::Log { offset } => (f.max(0.0) / offset).ln_1p(),
        }
    }

    /// Inverts the transform of one value.
    #[inline]
    pub fn inverse(&self, y: f64) -> f64 {
        match *self {
            Self::Raw => y,
            Self::Log { offset } => offset * y.exp_m1(),
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

    proptest! {
        #[test]
        fn inverse_round_trips(f in 0.0..1e6f64, c in 1e-4..10.0f64) {
            let t = Transform::Log { offset: c };
            let back = t.inverse(t.forward(f));
            prop_assert!((back - f).abs() <= 1e-12 * f.max(c), "{f} -> {back}");
        }
    }
}
