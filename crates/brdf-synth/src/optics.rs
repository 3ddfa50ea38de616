//! Optics: complex Fresnel reflectance of dielectrics and conductors, dispersive indices and
//! thin-film (Airy) interference.
//!
//! Metal n, k tables are derived from the refractiveindex.info database (CC0), as shipped in
//! `../shared/data/spectra/metals-nk/metals_nk_360-1000_5nm_linear_interp.csv`, subsampled to
//! 360:20:1000 nm and linearly interpolated here. The test `metal_tables_match_source` checks
//! them against that file.

use std::ops::{Add, Div, Mul, Sub};

use crate::spectrum::table_lerp;

/// A minimal complex number for the Fresnel equations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Complex {
    /// Real part.
    pub re: f64,
    /// Imaginary part.
    pub im: f64,
}

impl Complex {
    /// `re + i im`.
    pub const fn new(re: f64, im: f64) -> Self {
        Self { re, im }
    }

    /// A real number.
    pub const fn real(re: f64) -> Self {
        Self { re, im: 0.0 }
    }

    /// `|z|^2`.
    pub fn norm_sqr(self) -> f64 {
        self.re * self.re + self.im * self.im
    }

    /// The principal square root (non-negative real part).
    pub fn sqrt(self) -> Self {
        let r = self.norm_sqr().sqrt();
        let re = (0.5 * (r + self.re)).max(0.0).sqrt();
        let im = (0.5 * (r - self.re)).max(0.0).sqrt();
        Self::new(re, if self.im < 0.0 { -im } else { im })
    }

    /// `exp(z)`.
    pub fn exp(self) -> Self {
        let m = self.re.exp();
        let (s, c) = self.im.sin_cos();
        Self::new(m * c, m * s)
    }
}

impl Add for Complex {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self::new(self.re + o.re, self.im + o.im)
    }
}

impl Sub for Complex {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Self::new(self.re - o.re, self.im - o.im)
    }
}

impl Mul for Complex {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        Self::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
}

impl Div for Complex {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        let d = o.norm_sqr();
        if d == 0.0 {
            return Self::real(0.0);
        }
        Self::new(
            (self.re * o.re + self.im * o.im) / d,
            (self.im * o.re - self.re * o.im) / d,
        )
    }
}

/// A real, dispersive refractive index: Cauchy's `n(lambda) = a + b / lambda^2` (lambda in nm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ior {
    /// Cauchy A.
    pub a: f64,
    /// Cauchy B in nm^2.
    pub b_nm2: f64,
}

impl Ior {
    /// An acrylic / polyurethane clear coat (n ~ 1.50 at 550 nm).
    pub const CLEAR_COAT: Self = Self {
        a: 1.485,
        b_nm2: 4_500.0,
    };
    /// A paint or plastic binder (n ~ 1.50).
    pub const BINDER: Self = Self {
        a: 1.49,
        b_nm2: 3_500.0,
    };
    /// Rutile TiO2 (ordinary ray), a Cauchy fit at 450 and 700 nm to Devore 1951
    /// (refractiveindex.info `TiO2_Devore-o`), used for interference films.
    pub const TITANIA: Self = Self {
        a: 2.366,
        b_nm2: 90_440.0,
    };
    /// Fused silica, Cauchy fit to Malitson 1965 (refractiveindex.info `SiO2_Malitson`).
    pub const SILICA: Self = Self {
        a: 1.4458,
        b_nm2: 3_540.0,
    };
    /// Muscovite mica, the usual substrate of pearlescent flakes (n ~ 1.58).
    pub const MICA: Self = Self {
        a: 1.565,
        b_nm2: 5_000.0,
    };

    /// A non-dispersive index.
    pub const fn constant(n: f64) -> Self {
        Self { a: n, b_nm2: 0.0 }
    }

    /// The index at `lambda_nm`.
    pub fn at(&self, lambda_nm: f64) -> f64 {
        self.a + self.b_nm2 / (lambda_nm * lambda_nm)
    }

    /// The largest index over `wavelengths` (Cauchy indices fall with wavelength).
    pub fn max_over(&self, wavelengths: &[f64]) -> f64 {
        wavelengths
            .iter()
            .map(|&l| self.at(l))
            .fold(self.a, f64::max)
    }
}

/// Gold (Au), Johnson & Christy 1972: n at 360:20:1000 nm (refractiveindex.info `Au_Johnson`).
const GOLD_N: [f64; 33] = [
    1.492, 1.462, 1.468, 1.456, 1.417, 1.349, 1.215, 0.9711, 0.6351, 0.489, 0.3824, 0.2988, 0.2487,
    0.2048, 0.172, 0.1399, 0.1354, 0.131, 0.133, 0.1369, 0.1412, 0.1474, 0.1535, 0.1597, 0.1627,
    0.1655, 0.1683, 0.1743, 0.1852, 0.1961, 0.207, 0.2178, 0.2277,
];
/// Gold (Au), Johnson & Christy 1972: k at 360:20:1000 nm.
const GOLD_K: [f64; 33] = [
    1.878, 1.929, 1.953, 1.954, 1.932, 1.885, 1.843, 1.874, 2.072, 2.339, 2.594, 2.837, 3.074,
    3.304, 3.503, 3.702, 3.882, 4.062, 4.235, 4.406, 4.575, 4.741, 4.908, 5.074, 5.238, 5.401,
    5.565, 5.723, 5.872, 6.021, 6.171, 6.32, 6.473,
];
/// Silver (Ag), Johnson & Christy 1972: n at 360:20:1000 nm (refractiveindex.info `Ag_Johnson`).
const SILVER_N: [f64; 33] = [
    0.0873, 0.05221, 0.05, 0.0461, 0.04, 0.04444, 0.05, 0.05, 0.05, 0.0569, 0.0566, 0.05063,
    0.05516, 0.05925, 0.05457, 0.04989, 0.04544, 0.041, 0.03699, 0.03311, 0.03061, 0.03369,
    0.03676, 0.03983, 0.04, 0.04, 0.04, 0.04, 0.04, 0.04, 0.04, 0.04, 0.04,
];
/// Silver (Ag), Johnson & Christy 1972: k at 360:20:1000 nm.
const SILVER_K: [f64; 33] = [
    1.52, 1.841, 2.104, 2.348, 2.553, 2.751, 2.948, 3.131, 3.316, 3.505, 3.679, 3.841, 4.01, 4.177,
    4.332, 4.487, 4.645, 4.803, 4.96, 5.116, 5.272, 5.421, 5.57, 5.719, 5.883, 6.048, 6.213, 6.371,
    6.519, 6.667, 6.815, 6.962, 7.116,
];
/// Copper (Cu), Johnson & Christy 1972: n at 360:20:1000 nm (refractiveindex.info `Cu_Johnson`).
const COPPER_N: [f64; 33] = [
    1.366, 1.333, 1.313, 1.268, 1.245, 1.244, 1.239, 1.213, 1.181, 1.07, 0.9111, 0.7201, 0.4937,
    0.294, 0.2565, 0.2199, 0.2154, 0.211, 0.219, 0.2307, 0.2412, 0.2474, 0.2535, 0.2597, 0.2707,
    0.2819, 0.2932, 0.3017, 0.3061, 0.3104, 0.3148, 0.3191, 0.3262,
];
/// Copper (Cu), Johnson & Christy 1972: k at 360:20:1000 nm.
const COPPER_K: [f64; 33] = [
    1.941, 2.037, 2.131, 2.245, 2.348, 2.435, 2.511, 2.571, 2.606, 2.587, 2.62, 2.696, 2.962,
    3.246, 3.499, 3.752, 3.956, 4.159, 4.343, 4.522, 4.697, 4.855, 5.013, 5.171, 5.337, 5.503,
    5.668, 5.825, 5.967, 6.109, 6.251, 6.393, 6.543,
];
/// Aluminium (Al), Rakic 1995: n at 360:20:1000 nm (refractiveindex.info `Al_Rakic`).
const ALUMINIUM_N: [f64; 33] = [
    0.3886, 0.4374, 0.4879, 0.5411, 0.5997, 0.6684, 0.7393, 0.8126, 0.8878, 0.9727, 1.058, 1.158,
    1.262, 1.366, 1.494, 1.627, 1.768, 1.921, 2.085, 2.267, 2.467, 2.654, 2.767, 2.753, 2.675,
    2.502, 2.329, 2.111, 1.885, 1.674, 1.543, 1.468, 1.436,
];
/// Aluminium (Al), Rakic 1995: k at 360:20:1000 nm.
const ALUMINIUM_K: [f64; 33] = [
    4.338, 4.587, 4.836, 5.084, 5.333, 5.575, 5.815, 6.048, 6.281, 6.512, 6.743, 6.965, 7.186,
    7.406, 7.61, 7.804, 7.982, 8.142, 8.288, 8.388, 8.447, 8.465, 8.354, 8.244, 8.184, 8.153,
    8.122, 8.22, 8.394, 8.608, 8.928, 9.221, 9.495,
];
/// Chromium (Cr), Johnson & Christy 1974: n at 360:20:1000 nm (refractiveindex.info `Cr_Johnson`).
const CHROMIUM_N: [f64; 33] = [
    1.853, 1.916, 2.015, 2.123, 2.253, 2.411, 2.596, 2.78, 2.932, 3.103, 3.193, 3.218, 3.194,
    3.164, 3.126, 3.089, 3.071, 3.054, 3.059, 3.071, 3.087, 3.124, 3.161, 3.198, 3.227, 3.255,
    3.283, 3.31, 3.333, 3.357, 3.381, 3.405, 3.436,
];
/// Chromium (Cr), Johnson & Christy 1974: k at 360:20:1000 nm.
const CHROMIUM_K: [f64; 33] = [
    2.661, 2.736, 2.849, 2.973, 3.085, 3.185, 3.262, 3.305, 3.329, 3.33, 3.32, 3.302, 3.3, 3.303,
    3.322, 3.341, 3.363, 3.386, 3.399, 3.411, 3.424, 3.442, 3.461, 3.479, 3.491, 3.502, 3.513,
    3.524, 3.535, 3.546, 3.557, 3.568, 3.572,
];
/// Nickel (Ni), Johnson & Christy 1974: n at 360:20:1000 nm (refractiveindex.info `Ni_Johnson`).
const NICKEL_N: [f64; 33] = [
    1.723, 1.718, 1.716, 1.704, 1.719, 1.752, 1.794, 1.825, 1.849, 1.897, 1.933, 1.958, 1.975,
    1.99, 1.99, 1.992, 2.023, 2.054, 2.082, 2.108, 2.138, 2.178, 2.218, 2.258, 2.297, 2.337, 2.376,
    2.407, 2.424, 2.442, 2.459, 2.477, 2.506,
];
/// Nickel (Ni), Johnson & Christy 1974: k at 360:20:1000 nm.
const NICKEL_K: [f64; 33] = [
    2.354, 2.474, 2.592, 2.741, 2.878, 3.013, 3.148, 3.277, 3.413, 3.549, 3.673, 3.788, 3.913,
    4.037, 4.151, 4.265, 4.372, 4.479, 4.571, 4.659, 4.745, 4.819, 4.892, 4.966, 5.04, 5.113,
    5.186, 5.258, 5.327, 5.397, 5.467, 5.536, 5.608,
];
/// Brass (Cu70Zn30), Querry 1987: n at 360:20:1000 nm (refractiveindex.info `Cu-Zn_Querry-Cu70Zn30`).
const BRASS_N: [f64; 33] = [
    1.503, 1.487, 1.445, 1.35, 1.191, 0.994, 0.816, 0.686, 0.602, 0.549, 0.505, 0.468, 0.45, 0.449,
    0.444, 0.445, 0.444, 0.446, 0.45, 0.455, 0.458, 0.464, 0.473, 0.481, 0.486, 0.494, 0.507,
    0.523, 0.538, 0.555, 0.572, 0.588, 0.603,
];
/// Brass (Cu70Zn30), Querry 1987: k at 360:20:1000 nm.
const BRASS_K: [f64; 33] = [
    1.815, 1.818, 1.805, 1.786, 1.797, 1.883, 2.046, 2.25, 2.464, 2.668, 2.86, 3.059, 3.253, 3.434,
    3.609, 3.778, 3.943, 4.106, 4.266, 4.424, 4.579, 4.737, 4.89, 5.039, 5.192, 5.346, 5.5, 5.65,
    5.797, 5.944, 6.087, 6.228, 6.367,
];
// A tabulated n that happens to read 3.142 is data, not pi.
#[allow(clippy::approx_constant)]
/// Titanium (Ti), Johnson & Christy 1974: n at 360:20:1000 nm (refractiveindex.info `Ti_Johnson`).
const TITANIUM_N: [f64; 33] = [
    1.854, 1.983, 2.091, 2.167, 2.237, 2.292, 2.334, 2.373, 2.437, 2.508, 2.56, 2.596, 2.636,
    2.676, 2.719, 2.762, 2.807, 2.851, 2.903, 2.957, 3.013, 3.078, 3.142, 3.207, 3.231, 3.254,
    3.276, 3.295, 3.308, 3.321, 3.334, 3.347, 3.373,
];
/// Titanium (Ti), Johnson & Christy 1974: k at 360:20:1000 nm.
const TITANIUM_K: [f64; 33] = [
    2.883, 2.928, 2.956, 2.992, 3.023, 3.067, 3.132, 3.208, 3.296, 3.388, 3.48, 3.571, 3.652,
    3.729, 3.786, 3.843, 3.896, 3.949, 3.975, 3.995, 4.01, 4.01, 4.01, 4.01, 3.997, 3.983, 3.968,
    3.961, 3.963, 3.965, 3.967, 3.97, 3.978,
];

/// A real metal with a tabulated complex index n + i k (see the module docs for sources).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Metal {
    /// Gold (Au).
    Gold,
    /// Silver (Ag).
    Silver,
    /// Copper (Cu).
    Copper,
    /// Aluminium (Al).
    Aluminium,
    /// Chromium (Cr).
    Chromium,
    /// Nickel (Ni).
    Nickel,
    /// Brass (70 % Cu, 30 % Zn).
    Brass,
    /// Titanium (Ti).
    Titanium,
}

impl Metal {
    /// Every tabulated metal.
    pub const ALL: [Metal; 8] = [
        Metal::Gold,
        Metal::Silver,
        Metal::Copper,
        Metal::Aluminium,
        Metal::Chromium,
        Metal::Nickel,
        Metal::Brass,
        Metal::Titanium,
    ];

    /// Wavelength of the first table sample, nm.
    pub const TABLE_START_NM: f64 = 360.0;
    /// Table spacing, nm.
    pub const TABLE_STEP_NM: f64 = 20.0;

    /// The embedded (n, k) tables at 360:20:1000 nm.
    pub fn tables(self) -> (&'static [f64; 33], &'static [f64; 33]) {
        match self {
            Metal::Gold => (&GOLD_N, &GOLD_K),
            Metal::Silver => (&SILVER_N, &SILVER_K),
            Metal::Copper => (&COPPER_N, &COPPER_K),
            Metal::Aluminium => (&ALUMINIUM_N, &ALUMINIUM_K),
            Metal::Chromium => (&CHROMIUM_N, &CHROMIUM_K),
            Metal::Nickel => (&NICKEL_N, &NICKEL_K),
            Metal::Brass => (&BRASS_N, &BRASS_K),
            Metal::Titanium => (&TITANIUM_N, &TITANIUM_K),
        }
    }

    /// Column prefix of this metal in the shared refractiveindex.info resampled CSV.
    pub fn source_name(self) -> &'static str {
        match self {
            Metal::Gold => "Au_Johnson",
            Metal::Silver => "Ag_Johnson",
            Metal::Copper => "Cu_Johnson",
            Metal::Aluminium => "Al_Rakic",
            Metal::Chromium => "Cr_Johnson",
            Metal::Nickel => "Ni_Johnson",
            Metal::Brass => "Cu-Zn_Querry-Cu70Zn30",
            Metal::Titanium => "Ti_Johnson",
        }
    }

    /// The complex index n + i k at `lambda_nm` (linear interpolation, clamped to 360-1000 nm).
    pub fn nk(self, lambda_nm: f64) -> Complex {
        let (n, k) = self.tables();
        Complex::new(
            table_lerp(Self::TABLE_START_NM, Self::TABLE_STEP_NM, n, lambda_nm),
            table_lerp(Self::TABLE_START_NM, Self::TABLE_STEP_NM, k, lambda_nm),
        )
    }

    /// Normal-incidence reflectance in air, ((n-1)^2 + k^2) / ((n+1)^2 + k^2).
    pub fn normal_reflectance(self, lambda_nm: f64) -> f64 {
        let z = self.nk(lambda_nm);
        ((z.re - 1.0).powi(2) + z.im * z.im) / ((z.re + 1.0).powi(2) + z.im * z.im)
    }
}

/// Fresnel amplitude coefficients (s, p) at the interface from a medium of real index `n1`
/// into a medium of complex index `n2`, for `cos1 = cos(theta_1)` and the (complex) cosine
/// `cos2` of the transmitted angle.
fn amplitudes(n1: Complex, cos1: Complex, n2: Complex, cos2: Complex) -> (Complex, Complex) {
    let rs = (n1 * cos1 - n2 * cos2) / (n1 * cos1 + n2 * cos2);
    let rp = (n2 * cos1 - n1 * cos2) / (n2 * cos1 + n1 * cos2);
    (rs, rp)
}

/// Cosine of the refracted angle in a medium of index `n2` for a ray with `n1 sin(theta_1)`.
fn refracted_cos(n1_sin1: f64, n2: Complex) -> Complex {
    let s = Complex::real(n1_sin1) / n2;
    (Complex::real(1.0) - s * s).sqrt()
}

/// Unpolarised Fresnel reflectance at an interface from a real medium `n1` into a medium of
/// complex index `n2` (a dielectric when `n2.im == 0`, a conductor otherwise), at incidence
/// cosine `cos1` in [0, 1]. Total internal reflection returns 1.
pub fn fresnel(cos1: f64, n1: f64, n2: Complex) -> f64 {
    let cos1 = cos1.clamp(0.0, 1.0);
    let sin1 = (1.0 - cos1 * cos1).max(0.0).sqrt();
    if n2.im == 0.0 {
        return fresnel_dielectric(cos1, n1, n2.re);
    }
    let cos2 = refracted_cos(n1 * sin1, n2);
    let (rs, rp) = amplitudes(Complex::real(n1), Complex::real(cos1), n2, cos2);
    (0.5 * (rs.norm_sqr() + rp.norm_sqr())).clamp(0.0, 1.0)
}

/// Unpolarised Fresnel reflectance between two real media (`n1` -> `n2`) at incidence cosine
/// `cos1` in [0, 1]; total internal reflection returns 1. Same as [`fresnel`] with a real `n2`,
/// in real arithmetic.
pub fn fresnel_dielectric(cos1: f64, n1: f64, n2: f64) -> f64 {
    let cos1 = cos1.clamp(0.0, 1.0);
    let sin2 = n1 / n2 * (1.0 - cos1 * cos1).max(0.0).sqrt();
    if sin2 >= 1.0 {
        return 1.0;
    }
    let cos2 = (1.0 - sin2 * sin2).sqrt();
    let rs = (n1 * cos1 - n2 * cos2) / (n1 * cos1 + n2 * cos2);
    let rp = (n2 * cos1 - n1 * cos2) / (n2 * cos1 + n1 * cos2);
    (0.5 * (rs * rs + rp * rp)).clamp(0.0, 1.0)
}

/// Unpolarised reflectance of a thin film (index `n_film`, thickness `thickness_nm`) between an
/// incident medium `n1` and a substrate `n_sub` (complex: dielectric or metal), at incidence
/// cosine `cos1` and wavelength `lambda_nm`: the Airy sum of all internal reflections,
/// `r = (r12 + r23 e^{2i delta}) / (1 + r12 r23 e^{2i delta})`, `delta = 2 pi n d cos / lambda`,
/// per polarisation.
pub fn thin_film(
    cos1: f64,
    lambda_nm: f64,
    n1: f64,
    n_film: f64,
    thickness_nm: f64,
    n_sub: Complex,
) -> f64 {
    let cos1 = cos1.clamp(0.0, 1.0);
    let sin1 = (1.0 - cos1 * cos1).max(0.0).sqrt();
    let nf = Complex::real(n_film);
    let cos_f = refracted_cos(n1 * sin1, nf);
    let cos_s = refracted_cos(n1 * sin1, n_sub);
    let (r12s, r12p) = amplitudes(Complex::real(n1), Complex::real(cos1), nf, cos_f);
    let (r23s, r23p) = amplitudes(nf, cos_f, n_sub, cos_s);
    // Phase of one round trip through the film (complex if the film is evanescent).
    let delta =
        Complex::real(2.0 * std::f64::consts::PI * n_film * thickness_nm / lambda_nm) * cos_f;
    let phase = (Complex::new(0.0, 2.0) * delta).exp();
    let one = Complex::real(1.0);
    let rs = (r12s + r23s * phase) / (one + r12s * r23s * phase);
    let rp = (r12p + r23p * phase) / (one + r12p * r23p * phase);
    (0.5 * (rs.norm_sqr() + rp.norm_sqr())).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_fresnel_known_values() {
        // Normal incidence, n = 1.5: ((1.5-1)/(1.5+1))^2 = 0.04.
        assert!((fresnel(1.0, 1.0, Complex::real(1.5)) - 0.04).abs() < 1e-12);
        // Grazing incidence reflects everything.
        assert!((fresnel(0.0, 1.0, Complex::real(1.5)) - 1.0).abs() < 1e-9);
        // Brewster's angle: p vanishes, R = Rs / 2.
        let tb = 1.5f64.atan();
        let r = fresnel(tb.cos(), 1.0, Complex::real(1.5));
        let ct = (1.0 - (tb.sin() / 1.5).powi(2)).sqrt();
        let rs = ((tb.cos() - 1.5 * ct) / (tb.cos() + 1.5 * ct)).powi(2);
        assert!((r - 0.5 * rs).abs() < 1e-12);
        // Monotone in the index (used for the conservative coupling tables).
        for c in [0.1, 0.5, 0.9] {
            assert!(fresnel(c, 1.0, Complex::real(1.6)) > fresnel(c, 1.0, Complex::real(1.5)));
        }
    }

    #[test]
    fn real_and_complex_dielectric_paths_agree() {
        for n2 in [1.33, 1.5, 2.4] {
            for i in 0..=20 {
                let c = i as f64 / 20.0;
                let sin1 = (1.0 - c * c).sqrt();
                let cos2 = refracted_cos(sin1, Complex::real(n2));
                let (rs, rp) = amplitudes(
                    Complex::real(1.0),
                    Complex::real(c),
                    Complex::real(n2),
                    cos2,
                );
                let complex = 0.5 * (rs.norm_sqr() + rp.norm_sqr());
                let real = fresnel_dielectric(c, 1.0, n2);
                assert!((complex - real).abs() < 1e-12, "n {n2} cos {c}");
            }
        }
        // Total internal reflection from the dense side.
        assert_eq!(fresnel_dielectric(0.3, 1.5, 1.0), 1.0);
    }

    #[test]
    fn conductor_normal_incidence_formula() {
        for m in Metal::ALL {
            for l in [380.0, 550.0, 700.0, 950.0] {
                let r = fresnel(1.0, 1.0, m.nk(l));
                assert!((r - m.normal_reflectance(l)).abs() < 1e-12, "{m:?} {l}");
            }
        }
        // Gold is yellow: reflects red far better than blue.
        assert!(Metal::Gold.normal_reflectance(650.0) > 0.9);
        assert!(Metal::Gold.normal_reflectance(450.0) < 0.45);
    }

    /// At oblique incidence the complex-amplitude path (principal square roots) agrees with the
    /// real-arithmetic conductor formulas of Born & Wolf (sec. 14.4.1) for every metal, and both
    /// polarisations stay physical (Rp dips below Rs, and R reaches 1 at grazing).
    #[test]
    fn conductor_fresnel_matches_born_and_wolf() {
        let born_wolf = |cos1: f64, n: f64, k: f64| {
            let sin2 = 1.0 - cos1 * cos1;
            let t = n * n - k * k - sin2;
            let root = (t * t + 4.0 * n * n * k * k).sqrt();
            let (a2, b2) = (0.5 * (root + t), 0.5 * (root - t));
            let a = a2.sqrt();
            let rs =
                (a2 + b2 - 2.0 * a * cos1 + cos1 * cos1) / (a2 + b2 + 2.0 * a * cos1 + cos1 * cos1);
            let st = sin2 / cos1; // sin(theta) tan(theta)
            let rp = rs * (a2 + b2 - 2.0 * a * st + st * st) / (a2 + b2 + 2.0 * a * st + st * st);
            (rs, rp)
        };
        for m in Metal::ALL {
            for l in [380.0, 550.0, 700.0, 950.0] {
                let z = m.nk(l);
                for deg in [5.0f64, 30.0, 60.0, 75.0, 85.0, 89.5] {
                    let c = deg.to_radians().cos();
                    let (rs, rp) = born_wolf(c, z.re, z.im);
                    let r = fresnel(c, 1.0, z);
                    assert!(
                        (r - 0.5 * (rs + rp)).abs() < 1e-12,
                        "{m:?} {l} nm {deg} deg: {r}"
                    );
                    assert!(rp < rs && rs < 1.0, "{m:?} {l} nm {deg} deg: {rs} {rp}");
                }
                assert!((fresnel(0.0, 1.0, z) - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn thin_film_limits() {
        // Zero thickness: the bare substrate.
        let sub = Complex::real(1.5);
        for c in [1.0, 0.6, 0.2] {
            let a = thin_film(c, 550.0, 1.0, 2.4, 0.0, sub);
            assert!((a - fresnel(c, 1.0, sub)).abs() < 1e-12);
        }
        // Quarter-wave film of index sqrt(n_sub) on glass: anti-reflection (R ~ 0).
        let nf = 1.5f64.sqrt();
        let r = thin_film(1.0, 550.0, 1.0, nf, 550.0 / (4.0 * nf), sub);
        assert!(r < 1e-12, "{r}");
        // Quarter-wave high-index film: the classic (n1 n_s - n_f^2)^2 / (n1 n_s + n_f^2)^2.
        let nf = 2.4;
        let r = thin_film(1.0, 550.0, 1.0, nf, 550.0 / (4.0 * nf), sub);
        let expect = ((1.5 - nf * nf) / (1.5 + nf * nf)).powi(2);
        assert!((r - expect).abs() < 1e-12, "{r} vs {expect}");
    }

    /// The Airy sum agrees with the characteristic-matrix method (Macleod, Thin-Film Optical
    /// Filters, ch. 2, with its n - i k convention conjugated) for a film on a metal, whose
    /// complex amplitudes make the phase's sign matter (on real amplitudes, a film's phase and
    /// its conjugate give the same reflectance), at several incidences and thicknesses, both
    /// polarisations.
    #[test]
    fn thin_film_matches_the_characteristic_matrix() {
        let matrix = |cos1: f64, lambda: f64, nf: f64, d: f64, ns: Complex| {
            let sin1 = (1.0 - cos1 * cos1).sqrt();
            let cos_f = (1.0 - (sin1 / nf).powi(2)).sqrt();
            let s = Complex::real(sin1) / ns;
            let cos_s = (Complex::real(1.0) - s * s).sqrt();
            let delta = 2.0 * std::f64::consts::PI * nf * d * cos_f / lambda;
            // With indices n + i k (this module's sign) the matrix carries -i sin(delta).
            let (sd, cd) = ((-delta).sin(), delta.cos());
            // Tilted admittances: n cos (s) and n / cos (p).
            let mut r = 0.0;
            for (eta0, etaf, etas) in [
                (Complex::real(cos1), nf * cos_f, ns * cos_s),
                (Complex::real(1.0 / cos1), nf / cos_f, ns / cos_s),
            ] {
                let b = Complex::real(cd) + Complex::new(0.0, sd / etaf) * etas;
                let c = Complex::new(0.0, etaf * sd) + Complex::real(cd) * etas;
                r += 0.5 * ((eta0 * b - c) / (eta0 * b + c)).norm_sqr();
            }
            r
        };
        for metal in [Metal::Gold, Metal::Aluminium] {
            for lambda in [450.0, 550.0, 700.0] {
                let ns = metal.nk(lambda);
                for d in [40.0, 130.0, 310.0] {
                    for cos1 in [1.0, 0.7, 0.3] {
                        let airy = thin_film(cos1, lambda, 1.0, 1.38, d, ns);
                        let tmm = matrix(cos1, lambda, 1.38, d, ns);
                        assert!(
                            (airy - tmm).abs() < 1e-12,
                            "{metal:?} {lambda} nm, {d} nm, cos {cos1}: {airy} vs {tmm}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn complex_sqrt_and_exp() {
        let z = Complex::new(-3.0, 4.0);
        let s = z.sqrt();
        let back = s * s;
        assert!((back.re + 3.0).abs() < 1e-12 && (back.im - 4.0).abs() < 1e-12);
        // The principal root below the real axis too: (1 - 2i)^2 = -3 - 4i.
        let s = Complex::new(-3.0, -4.0).sqrt();
        assert!(
            (s.re - 1.0).abs() < 1e-12 && (s.im + 2.0).abs() < 1e-12,
            "{s:?}"
        );
        assert_eq!(Complex::new(4.0, 0.0).sqrt(), Complex::new(2.0, 0.0));
        let e = Complex::new(0.0, std::f64::consts::PI).exp();
        assert!((e.re + 1.0).abs() < 1e-12 && e.im.abs() < 1e-12);
    }

    #[test]
    fn metal_tables_match_source() {
        let Some(text) = shared_data::read_to_string(
            "spectra/metals-nk/metals_nk_360-1000_5nm_linear_interp.csv",
        ) else {
            return;
        };
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        for m in Metal::ALL {
            let ni = header
                .iter()
                .position(|h| *h == format!("{}_n", m.source_name()));
            let ki = header
                .iter()
                .position(|h| *h == format!("{}_k", m.source_name()));
            let (ni, ki) = (ni.unwrap(), ki.unwrap());
            let mut worst: f64 = 0.0;
            for r in &rows {
                let (n, k) = (r[ni], r[ki]);
                let r_src = ((n - 1.0).powi(2) + k * k) / ((n + 1.0).powi(2) + k * k);
                worst = worst.max((r_src - m.normal_reflectance(r[0])).abs());
                // Exact at the embedded nodes.
                if (r[0] - 360.0) % 20.0 == 0.0 {
                    let z = m.nk(r[0]);
                    assert!((z.re - n).abs() <= 1e-3 * n.max(0.1), "{m:?} n at {}", r[0]);
                    assert!((z.im - k).abs() <= 1e-3 * k.max(0.1), "{m:?} k at {}", r[0]);
                }
            }
            // Between nodes the coarse table stays within 0.02 in reflectance.
            assert!(
                worst < 0.02,
                "{m:?}: worst normal-reflectance error {worst}"
            );
        }
    }
}
