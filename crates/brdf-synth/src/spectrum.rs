//! Reflectance spectra: embedded measured tables and smooth parametric shapes.
//!
//! Every spectrum is a function of wavelength in nm. Tables are linearly interpolated and held
//! constant beyond their ends (360-1000 nm is covered by clamping).
//!
//! Embedded tables (kept coarse on purpose; derived once from the project's shared reference
//! data, never read at run time):
//! - [`colorchecker`]: the 24 ColorChecker patch reflectances of N. Ohta (380-780 nm, 5 nm),
//!   subsampled to 20 nm (`../shared/data/spectra/colorchecker/colorchecker_n_ohta_380-780_5nm.csv`).
//!   Beyond 780 nm the last value is held.
//! - [`SPECTRALON`]: the measured diffuse reflectance of a Spectralon panel (Labsphere panel 4,
//!   2023; `../shared/data/spectra/spectralon/`, MIT licence), averaged over +-10 nm windows at
//!   360:40:1000 nm.

/// Spectralon diffuse reflectance at 360:40:1000 nm (17 samples; see the module docs).
pub const SPECTRALON: [f64; 17] = [
    0.9685, 0.9730, 0.9751, 0.9759, 0.9761, 0.9763, 0.9765, 0.9768, 0.9771, 0.9778, 0.9782, 0.9786,
    0.9789, 0.9798, 0.9800, 0.9803, 0.9806,
];

/// ColorChecker patch reflectances (N. Ohta), 380:20:780 nm, 21 samples each.
pub mod colorchecker {
    /// First wavelength of every table, nm.
    pub const START_NM: f64 = 380.0;
    /// Wavelength step of every table, nm.
    pub const STEP_NM: f64 = 20.0;
    /// ColorChecker patch 1, "dark skin".
    pub const DARK_SKIN: [f64; 21] = [
        0.048, 0.065, 0.064, 0.055, 0.052, 0.054, 0.061, 0.070, 0.076, 0.087, 0.115, 0.138, 0.154,
        0.173, 0.204, 0.242, 0.282, 0.334, 0.409, 0.462, 0.421,
    ];
    /// ColorChecker patch 2, "light skin".
    pub const LIGHT_SKIN: [f64; 21] = [
        0.103, 0.182, 0.201, 0.212, 0.240, 0.282, 0.301, 0.322, 0.292, 0.295, 0.358, 0.494, 0.550,
        0.574, 0.605, 0.652, 0.713, 0.762, 0.791, 0.801, 0.734,
    ];
    /// ColorChecker patch 3, "blue sky".
    pub const BLUE_SKY: [f64; 21] = [
        0.113, 0.266, 0.336, 0.335, 0.322, 0.293, 0.260, 0.225, 0.198, 0.183, 0.163, 0.150, 0.137,
        0.123, 0.112, 0.105, 0.103, 0.102, 0.104, 0.106, 0.120,
    ];
    /// ColorChecker patch 4, "foliage".
    pub const FOLIAGE: [f64; 21] = [
        0.048, 0.050, 0.050, 0.054, 0.061, 0.067, 0.078, 0.155, 0.177, 0.137, 0.122, 0.104, 0.098,
        0.097, 0.095, 0.125, 0.247, 0.343, 0.364, 0.368, 0.341,
    ];
    /// ColorChecker patch 5, "blue flower".
    pub const BLUE_FLOWER: [f64; 21] = [
        0.123, 0.328, 0.446, 0.444, 0.421, 0.381, 0.342, 0.271, 0.211, 0.201, 0.206, 0.235, 0.243,
        0.269, 0.384, 0.490, 0.520, 0.521, 0.521, 0.517, 0.487,
    ];
    /// ColorChecker patch 6, "bluish green".
    pub const BLUISH_GREEN: [f64; 21] = [
        0.110, 0.252, 0.322, 0.353, 0.408, 0.523, 0.582, 0.569, 0.519, 0.436, 0.346, 0.260, 0.221,
        0.210, 0.211, 0.233, 0.252, 0.244, 0.260, 0.297, 0.296,
    ];
    /// ColorChecker patch 7, "orange".
    pub const ORANGE: [f64; 21] = [
        0.053, 0.054, 0.052, 0.052, 0.052, 0.055, 0.061, 0.086, 0.170, 0.297, 0.452, 0.532, 0.566,
        0.587, 0.604, 0.615, 0.628, 0.633, 0.638, 0.641, 0.582,
    ];
    /// ColorChecker patch 8, "purplish blue".
    pub const PURPLISH_BLUE: [f64; 21] = [
        0.099, 0.231, 0.324, 0.373, 0.374, 0.301, 0.202, 0.137, 0.106, 0.090, 0.083, 0.087, 0.084,
        0.098, 0.123, 0.120, 0.116, 0.128, 0.162, 0.242, 0.316,
    ];
    /// ColorChecker patch 9, "moderate red".
    pub const MODERATE_RED: [f64; 21] = [
        0.096, 0.144, 0.138, 0.131, 0.126, 0.119, 0.103, 0.094, 0.092, 0.108, 0.157, 0.415, 0.567,
        0.601, 0.607, 0.605, 0.606, 0.599, 0.593, 0.586, 0.540,
    ];
    /// ColorChecker patch 10, "purple".
    pub const PURPLE: [f64; 21] = [
        0.101, 0.177, 0.206, 0.168, 0.120, 0.086, 0.067, 0.058, 0.052, 0.055, 0.052, 0.059, 0.099,
        0.149, 0.193, 0.248, 0.319, 0.388, 0.451, 0.492, 0.467,
    ];
    /// ColorChecker patch 11, "yellow green".
    pub const YELLOW_GREEN: [f64; 21] = [
        0.056, 0.060, 0.062, 0.068, 0.085, 0.135, 0.269, 0.484, 0.545, 0.513, 0.454, 0.374, 0.331,
        0.320, 0.324, 0.354, 0.379, 0.373, 0.392, 0.433, 0.404,
    ];
    /// ColorChecker patch 12, "orange yellow".
    pub const ORANGE_YELLOW: [f64; 21] = [
        0.060, 0.065, 0.064, 0.065, 0.069, 0.092, 0.123, 0.193, 0.374, 0.512, 0.584, 0.624, 0.645,
        0.662, 0.676, 0.685, 0.696, 0.698, 0.701, 0.700, 0.639,
    ];
    /// ColorChecker patch 13, "blue".
    pub const BLUE: [f64; 21] = [
        0.069, 0.136, 0.208, 0.290, 0.338, 0.239, 0.120, 0.066, 0.048, 0.043, 0.040, 0.039, 0.040,
        0.042, 0.043, 0.044, 0.048, 0.056, 0.079, 0.138, 0.204,
    ];
    /// ColorChecker patch 14, "green".
    pub const GREEN: [f64; 21] = [
        0.055, 0.058, 0.059, 0.065, 0.078, 0.113, 0.180, 0.324, 0.355, 0.281, 0.196, 0.124, 0.089,
        0.080, 0.075, 0.078, 0.088, 0.090, 0.094, 0.110, 0.112,
    ];
    /// ColorChecker patch 15, "red".
    pub const RED: [f64; 21] = [
        0.052, 0.051, 0.049, 0.049, 0.048, 0.045, 0.044, 0.044, 0.045, 0.050, 0.072, 0.192, 0.486,
        0.654, 0.700, 0.718, 0.729, 0.727, 0.727, 0.728, 0.664,
    ];
    /// ColorChecker patch 16, "yellow".
    pub const YELLOW: [f64; 21] = [
        0.054, 0.053, 0.052, 0.053, 0.059, 0.121, 0.303, 0.475, 0.597, 0.660, 0.708, 0.737, 0.753,
        0.768, 0.780, 0.785, 0.792, 0.790, 0.787, 0.782, 0.710,
    ];
    /// ColorChecker patch 17, "magenta".
    pub const MAGENTA: [f64; 21] = [
        0.118, 0.283, 0.359, 0.327, 0.267, 0.209, 0.163, 0.124, 0.102, 0.106, 0.141, 0.279, 0.522,
        0.696, 0.766, 0.791, 0.804, 0.807, 0.813, 0.814, 0.752,
    ];
    /// ColorChecker patch 18, "cyan".
    pub const CYAN: [f64; 21] = [
        0.093, 0.195, 0.258, 0.315, 0.391, 0.458, 0.433, 0.339, 0.228, 0.141, 0.097, 0.080, 0.073,
        0.073, 0.076, 0.075, 0.072, 0.075, 0.100, 0.176, 0.214,
    ];
    /// ColorChecker patch 19, "white 9.5 (.05 D)".
    pub const WHITE_9_5: [f64; 21] = [
        0.153, 0.409, 0.840, 0.883, 0.887, 0.888, 0.887, 0.887, 0.887, 0.887, 0.887, 0.887, 0.891,
        0.890, 0.889, 0.888, 0.888, 0.886, 0.884, 0.882, 0.879,
    ];
    /// ColorChecker patch 20, "neutral 8 (.23 D)".
    pub const NEUTRAL_8: [f64; 21] = [
        0.150, 0.372, 0.580, 0.587, 0.586, 0.581, 0.580, 0.581, 0.583, 0.584, 0.588, 0.588, 0.585,
        0.580, 0.576, 0.572, 0.568, 0.564, 0.560, 0.555, 0.550,
    ];
    /// ColorChecker patch 21, "neutral 6.5 (.44 D)".
    pub const NEUTRAL_6_5: [f64; 21] = [
        0.138, 0.289, 0.357, 0.361, 0.361, 0.357, 0.356, 0.357, 0.358, 0.359, 0.361, 0.360, 0.357,
        0.353, 0.349, 0.345, 0.341, 0.337, 0.333, 0.329, 0.325,
    ];
    /// ColorChecker patch 22, "neutral 5 (.70 D)".
    pub const NEUTRAL_5: [f64; 21] = [
        0.113, 0.183, 0.202, 0.205, 0.204, 0.202, 0.202, 0.202, 0.203, 0.203, 0.205, 0.204, 0.203,
        0.200, 0.197, 0.195, 0.192, 0.190, 0.188, 0.185, 0.183,
    ];
    /// ColorChecker patch 23, "neutral 3.5 (1.05 D)".
    pub const NEUTRAL_3_5: [f64; 21] = [
        0.074, 0.091, 0.094, 0.095, 0.094, 0.093, 0.092, 0.093, 0.093, 0.093, 0.093, 0.092, 0.091,
        0.090, 0.089, 0.087, 0.086, 0.085, 0.085, 0.084, 0.083,
    ];
    /// ColorChecker patch 24, "black 2 (1.5 D)".
    pub const BLACK_2: [f64; 21] = [
        0.032, 0.035, 0.036, 0.035, 0.035, 0.034, 0.034, 0.034, 0.034, 0.033, 0.033, 0.033, 0.033,
        0.033, 0.033, 0.033, 0.032, 0.032, 0.032, 0.032, 0.032,
    ];
}

/// A reflectance-like spectrum, a function of wavelength (nm).
#[derive(Debug, Clone, PartialEq)]
pub enum Spectrum {
    /// The same value at every wavelength.
    Constant(f64),
    /// A table sampled at `start_nm + i * step_nm`, linearly interpolated, clamped at the ends.
    Table {
        /// Wavelength of the first sample, nm.
        start_nm: f64,
        /// Sample spacing, nm (> 0).
        step_nm: f64,
        /// The samples.
        values: &'static [f64],
    },
    /// A smooth Gaussian band: `lo + (hi - lo) exp(-((lambda - centre) / width)^2)`.
    Band {
        /// Peak wavelength, nm.
        centre_nm: f64,
        /// Half-width (1/e), nm.
        width_nm: f64,
        /// Value far from the band.
        lo: f64,
        /// Value at the peak.
        hi: f64,
    },
    /// A smooth logistic edge from `lo` (short wavelengths) to `hi` (long wavelengths);
    /// `hi < lo` gives a short-pass edge.
    Edge {
        /// Wavelength of the mid-point, nm.
        edge_nm: f64,
        /// Logistic scale, nm (> 0).
        width_nm: f64,
        /// Value at short wavelengths.
        lo: f64,
        /// Value at long wavelengths.
        hi: f64,
    },
    /// `factor` times a spectrum.
    Scaled(f64, Box<Spectrum>),
    /// A spectrum shifted along the wavelength axis by `shift_nm` (positive: towards the red).
    Shifted(f64, Box<Spectrum>),
    /// `(1 - t) a + t b`.
    Mix(f64, Box<Spectrum>, Box<Spectrum>),
    /// The product of two spectra (e.g. a dye's transmittance over a white base).
    Product(Box<Spectrum>, Box<Spectrum>),
}

impl Spectrum {
    /// An embedded ColorChecker table (see [`colorchecker`]).
    pub fn colorchecker(values: &'static [f64; 21]) -> Self {
        Self::Table {
            start_nm: colorchecker::START_NM,
            step_nm: colorchecker::STEP_NM,
            values,
        }
    }

    /// The Spectralon panel reflectance ([`SPECTRALON`]).
    pub fn spectralon() -> Self {
        Self::Table {
            start_nm: 360.0,
            step_nm: 40.0,
            values: &SPECTRALON,
        }
    }

    /// `factor` times this spectrum.
    pub fn scaled(self, factor: f64) -> Self {
        Self::Scaled(factor, Box::new(self))
    }

    /// This spectrum shifted by `shift_nm` towards longer wavelengths.
    pub fn shifted(self, shift_nm: f64) -> Self {
        Self::Shifted(shift_nm, Box::new(self))
    }

    /// `(1 - t) self + t other`.
    pub fn mix(self, t: f64, other: Spectrum) -> Self {
        Self::Mix(t, Box::new(self), Box::new(other))
    }

    /// The product of this spectrum and `other`.
    pub fn times(self, other: Spectrum) -> Self {
        Self::Product(Box::new(self), Box::new(other))
    }

    /// The value at wavelength `lambda_nm`.
    pub fn eval(&self, lambda_nm: f64) -> f64 {
        match self {
            Self::Constant(v) => *v,
            Self::Table {
                start_nm,
                step_nm,
                values,
            } => table_lerp(*start_nm, *step_nm, values, lambda_nm),
            Self::Band {
                centre_nm,
                width_nm,
                lo,
                hi,
            } => {
                let x = (lambda_nm - centre_nm) / width_nm.max(1e-9);
                lo + (hi - lo) * (-x * x).exp()
            }
            Self::Edge {
                edge_nm,
                width_nm,
                lo,
                hi,
            } => {
                let x = (lambda_nm - edge_nm) / width_nm.max(1e-9);
                lo + (hi - lo) / (1.0 + (-x).exp())
            }
            Self::Scaled(k, s) => k * s.eval(lambda_nm),
            Self::Shifted(d, s) => s.eval(lambda_nm - d),
            Self::Mix(t, a, b) => (1.0 - t) * a.eval(lambda_nm) + t * b.eval(lambda_nm),
            Self::Product(a, b) => a.eval(lambda_nm) * b.eval(lambda_nm),
        }
    }
}

/// Linear interpolation in a table sampled at `start + i step`, clamped at both ends.
pub(crate) fn table_lerp(start: f64, step: f64, values: &[f64], x: f64) -> f64 {
    match values.len() {
        0 => 0.0,
        1 => values[0],
        n => {
            let t = ((x - start) / step).clamp(0.0, (n - 1) as f64);
            let i = (t.floor() as usize).min(n - 2);
            let f = t - i as f64;
            values[i] * (1.0 - f) + values[i + 1] * f
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_interpolates_and_clamps() {
        let s = Spectrum::colorchecker(&colorchecker::RED);
        assert_eq!(s.eval(380.0), colorchecker::RED[0]);
        assert_eq!(s.eval(300.0), colorchecker::RED[0]);
        assert_eq!(s.eval(1000.0), colorchecker::RED[20]);
        let mid = s.eval(610.0);
        assert!((mid - 0.5 * (colorchecker::RED[11] + colorchecker::RED[12])).abs() < 1e-12);
    }

    #[test]
    fn parametric_shapes() {
        let b = Spectrum::Band {
            centre_nm: 500.0,
            width_nm: 40.0,
            lo: 0.1,
            hi: 0.6,
        };
        assert!((b.eval(500.0) - 0.6).abs() < 1e-12);
        assert!((b.eval(900.0) - 0.1).abs() < 1e-6);
        // One width from the centre: 1/e of the way.
        let one_width = 0.1 + 0.5 / std::f64::consts::E;
        assert!((b.eval(540.0) - one_width).abs() < 1e-12);
        assert!((b.eval(460.0) - one_width).abs() < 1e-12);
        let e = Spectrum::Edge {
            edge_nm: 600.0,
            width_nm: 15.0,
            lo: 0.05,
            hi: 0.8,
        };
        assert!((e.eval(600.0) - 0.425).abs() < 1e-12);
        assert!(e.eval(400.0) < 0.06 && e.eval(800.0) > 0.79);
        // One width above the mid-point: the logistic 1 / (1 + 1/e).
        let above = 0.05 + 0.75 / (1.0 + (-1.0f64).exp());
        assert!((e.eval(615.0) - above).abs() < 1e-12);
        assert!((b.clone().shifted(50.0).eval(550.0) - 0.6).abs() < 1e-12);
        assert!((b.clone().scaled(0.5).eval(500.0) - 0.3).abs() < 1e-12);
        // Mixes and products, value by value.
        let mix = b.clone().mix(0.25, e.clone());
        let product = b.clone().times(e.clone());
        for l in [450.0, 540.0, 615.0, 700.0] {
            let (vb, ve) = (b.eval(l), e.eval(l));
            assert!((mix.eval(l) - (0.75 * vb + 0.25 * ve)).abs() < 1e-15, "{l}");
            assert_eq!(product.eval(l), vb * ve, "{l}");
        }
    }

    #[test]
    fn spectralon_is_near_white() {
        let s = Spectrum::spectralon();
        for l in (360..=1000).step_by(10) {
            let v = s.eval(l as f64);
            assert!(v > 0.96 && v < 0.99, "{l} nm: {v}");
        }
    }
}
