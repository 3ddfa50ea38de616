//! Colour: spectra -> CIE XYZ (1931 2-degree observer) under an illuminant -> linear sRGB ->
//! sRGB-encoded 8-bit values; CIELAB and the CIEDE2000 colour difference.
//!
//! Spectral integration ([`SpectralWeights`]): a source's spectrum, known at its wavelengths
//! `lambda_k`, is read as the piecewise-linear function through those samples (constant beyond
//! the first and last sample). Then `XYZ = sum_k w_k f(lambda_k)` with
//! `w_k = integral of cmf(lambda) S(lambda) phi_k(lambda) d lambda / integral of ybar S`, where
//! `phi_k` is the hat function of sample k and `S` the illuminant; the integral runs over
//! 360-780 nm on a 1 nm trapezoid grid with the 5 nm CIE tables linearly interpolated. The
//! weights of a constant spectrum sum to the illuminant's white, so a perfect white diffuser has
//! Y = 1 exactly, whatever the source's sampling. Channels whose three weights are all zero are
//! not needed ([`SpectralWeights::needed`]).

use crate::cie;
use crate::error::{Error, Result};

/// A CIE illuminant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Illuminant {
    /// Average daylight, 6504 K (sRGB's white).
    #[default]
    D65,
    /// Horizon daylight, 5003 K.
    D50,
    /// Incandescent tungsten, 2856 K.
    A,
}

impl Illuminant {
    /// The relative spectral power at 360, 365, ..., 780 nm.
    pub fn table(self) -> &'static [f64; cie::LEN] {
        match self {
            Self::D65 => &cie::D65,
            Self::D50 => &cie::D50,
            Self::A => &cie::A,
        }
    }

    /// Relative spectral power at `nm` (linear interpolation of the 5 nm table; 0 outside
    /// 360-780 nm).
    pub fn spd(self, nm: f64) -> f64 {
        interp_table(self.table(), nm)
    }

    /// XYZ of a perfect white diffuser under this illuminant, normalised to Y = 1.
    pub fn white_xyz(self) -> [f64; 3] {
        let w = SpectralWeights::new_raw(&[cie::START_NM], self);
        [w.x[0], w.y[0], w.z[0]]
    }
}

impl std::str::FromStr for Illuminant {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_uppercase().as_str() {
            "D65" => Ok(Self::D65),
            "D50" => Ok(Self::D50),
            "A" => Ok(Self::A),
            _ => Err(Error::InvalidArgument {
                reason: format!("unknown illuminant {s:?} (expected D65, D50 or A)"),
            }),
        }
    }
}

impl std::fmt::Display for Illuminant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::D65 => "D65",
            Self::D50 => "D50",
            Self::A => "A",
        })
    }
}

/// Linear interpolation of a 5 nm CIE table; 0 outside its range.
fn interp_table(t: &[f64; cie::LEN], nm: f64) -> f64 {
    let u = (nm - cie::START_NM) / cie::STEP_NM;
    if !(0.0..=(cie::LEN - 1) as f64).contains(&u) {
        return 0.0;
    }
    let i = (u.floor() as usize).min(cie::LEN - 2);
    let f = u - i as f64;
    t[i] * (1.0 - f) + t[i + 1] * f
}

/// The CIE 1931 2-degree colour-matching functions at `nm` (linear interpolation of the 5 nm
/// table; 0 outside 360-780 nm).
pub fn cmf(nm: f64) -> [f64; 3] {
    let col = |c: usize| {
        let mut t = [0.0; cie::LEN];
        for (o, row) in t.iter_mut().zip(cie::CMF_1931_2DEG.iter()) {
            *o = row[c];
        }
        interp_table(&t, nm)
    };
    [col(0), col(1), col(2)]
}

/// Quadrature weights taking a spectrum sampled at given wavelengths to CIE XYZ (Y = 1 for a
/// perfect white diffuser) under an illuminant; see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralWeights {
    /// Weights of X, one per source wavelength.
    pub x: Vec<f64>,
    /// Weights of Y.
    pub y: Vec<f64>,
    /// Weights of Z.
    pub z: Vec<f64>,
}

impl SpectralWeights {
    /// Weights for a spectrum sampled at `wavelengths` (nm, strictly increasing) under
    /// `illuminant`.
    pub fn new(wavelengths: &[f64], illuminant: Illuminant) -> Result<Self> {
        if wavelengths.is_empty()
            || wavelengths.iter().any(|w| !w.is_finite())
            || wavelengths.windows(2).any(|w| w[1] <= w[0])
        {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "wavelengths must be finite, non-empty and strictly increasing, got {} values",
                    wavelengths.len()
                ),
            });
        }
        Ok(Self::new_raw(wavelengths, illuminant))
    }

    fn new_raw(wl: &[f64], illuminant: Illuminant) -> Self {
        let n = wl.len();
        let (mut x, mut y, mut z) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut norm = 0.0;
        // 1 nm trapezoid over 360..=780 nm.
        let steps = 420;
        for s in 0..=steps {
            let nm = cie::START_NM + s as f64;
            let q = if s == 0 || s == steps { 0.5 } else { 1.0 };
            let e = illuminant.spd(nm) * q;
            let c = cmf(nm);
            norm += c[1] * e;
            // Hat-function coefficients of the source sampling at nm.
            let (k0, k1, f) = bracket(wl, nm);
            for (k, a) in [(k0, 1.0 - f), (k1, f)] {
                if a != 0.0 {
                    x[k] += a * c[0] * e;
                    y[k] += a * c[1] * e;
                    z[k] += a * c[2] * e;
                }
            }
        }
        for v in x.iter_mut().chain(y.iter_mut()).chain(z.iter_mut()) {
            *v /= norm;
        }
        Self { x, y, z }
    }

    /// Number of wavelengths.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are no wavelengths.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Indices of the wavelengths with a non-zero weight: the only ones the observer needs.
    pub fn needed(&self) -> Vec<usize> {
        (0..self.len())
            .filter(|&k| self.x[k] != 0.0 || self.y[k] != 0.0 || self.z[k] != 0.0)
            .collect()
    }

    /// XYZ of a spectrum given at the weights' wavelengths: one value per wavelength (a shorter
    /// spectrum used to count its missing values as 0 and a longer one to lose its tail, a wrong
    /// colour without a word).
    pub fn xyz(&self, spectrum: &[f64]) -> Result<[f64; 3]> {
        if spectrum.len() != self.len() {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "a spectrum of {} values for {} wavelengths",
                    spectrum.len(),
                    self.len()
                ),
            });
        }
        let mut o = [0.0; 3];
        for (k, &v) in spectrum.iter().enumerate() {
            o[0] += self.x[k] * v;
            o[1] += self.y[k] * v;
            o[2] += self.z[k] * v;
        }
        Ok(o)
    }
}

/// The fractions of the observer's X, Y and Z responses under `illuminant` (integrals of
/// `cmf * S` over 360-780 nm) that fall between the first and last of `wavelengths` (nm,
/// increasing): beyond them a spectrum is extrapolated as constant, so colours computed from
/// samples that miss much of the visible range are guesses.
pub fn visible_coverage(wavelengths: &[f64], illuminant: Illuminant) -> [f64; 3] {
    let (Some(&lo), Some(&hi)) = (wavelengths.first(), wavelengths.last()) else {
        return [0.0; 3];
    };
    let (mut inside, mut all) = ([0.0; 3], [0.0; 3]);
    for s in 0..=420 {
        let nm = cie::START_NM + f64::from(s);
        let e = illuminant.spd(nm);
        let c = cmf(nm);
        for i in 0..3 {
            all[i] += c[i] * e;
            if (lo..=hi).contains(&nm) {
                inside[i] += c[i] * e;
            }
        }
    }
    [0, 1, 2].map(|i| inside[i] / all[i])
}

/// A warning when `wavelengths` cover less than 95 % of any of the observer's X, Y, Z
/// responses ([`visible_coverage`]): colours from them are mostly extrapolated. No wavelengths
/// at all cover nothing: a warning too.
pub fn coverage_warning(wavelengths: &[f64], illuminant: Illuminant) -> Option<String> {
    let (Some(&lo), Some(&hi)) = (wavelengths.first(), wavelengths.last()) else {
        return Some("no spectral channels: there is no colour to compute".into());
    };
    let cover = visible_coverage(wavelengths, illuminant);
    let least = cover.iter().copied().fold(f64::INFINITY, f64::min);
    (least < 0.95).then(|| {
        let span = if lo == hi {
            format!("{lo} nm")
        } else {
            format!("{lo}-{hi} nm")
        };
        format!(
            "the colour comes from spectral channels at {span}, where only {:.0} % / {:.0} % / \
             {:.0} % of the observer's X / Y / Z response under {illuminant} lies: it is \
             extrapolated from the end samples (held constant beyond them) and can be far off",
            100.0 * cover[0],
            100.0 * cover[1],
            100.0 * cover[2]
        )
    })
}

/// The spectral channels the observer needs under `illuminant` (non-zero weight), when they are
/// fewer than all: a source restricted to them renders the same colours with fewer lookups.
/// `None` for RGB channels or when every wavelength is needed.
pub fn needed_wavelengths(
    channels: &brdf_io::Channels,
    illuminant: Illuminant,
) -> Result<Option<brdf_io::Channels>> {
    let brdf_io::Channels::Spectral(wl) = channels else {
        return Ok(None);
    };
    let needed = SpectralWeights::new(wl, illuminant)?.needed();
    if needed.len() == wl.len() {
        return Ok(None);
    }
    Ok(Some(brdf_io::Channels::Spectral(
        needed.into_iter().map(|k| wl[k]).collect(),
    )))
}

/// The two source samples around `nm` and the interpolation fraction towards the second
/// (constant extension beyond the ends).
fn bracket(wl: &[f64], nm: f64) -> (usize, usize, f64) {
    let n = wl.len();
    if nm <= wl[0] {
        return (0, 0, 0.0);
    }
    if nm >= wl[n - 1] {
        return (n - 1, n - 1, 0.0);
    }
    let k1 = wl.partition_point(|&w| w <= nm);
    let k0 = k1 - 1;
    (k0, k1, (nm - wl[k0]) / (wl[k1] - wl[k0]))
}

/// XYZ (D65 white) -> linear sRGB: the matrix derived from the sRGB primaries and the white
/// (0.95047, 1, 1.08883), as Lindbloom tabulates it (IEC 61966-2-1's four-decimal matrix differs
/// by up to 4e-4).
pub const XYZ_TO_SRGB: [[f64; 3]; 3] = [
    [3.2404542, -1.5371385, -0.4985314],
    [-0.9692660, 1.8760108, 0.0415560],
    [0.0556434, -0.2040259, 1.0572252],
];

/// The white of [`XYZ_TO_SRGB`]: the XYZ it takes to linear sRGB (1, 1, 1), its inverse applied
/// to (1, 1, 1) (Cramer's rule): (0.95047, 1, 1.08883) to the matrix's 7 decimals. The 5 nm CIE
/// tables' D65 ([`Illuminant::white_xyz`]) is up to 2e-4 away from it, so a white diffuser
/// under D65 rendered 1.6e-4 off neutral before [`ColourPipeline`] adapted D65 as well.
pub fn srgb_white() -> [f64; 3] {
    mat_vec(&inverse(&XYZ_TO_SRGB), [1.0; 3])
}

/// The inverse of a regular 3 x 3 matrix (cofactors over the determinant).
fn inverse(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let c = |i: usize, j: usize| {
        let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
        let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
        m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    // The inverse is the transposed cofactor matrix over the determinant.
    let mut o = [[0.0; 3]; 3];
    for (i, row) in o.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = c(j, i) / det;
        }
    }
    o
}

/// Linear sRGB -> XYZ (D65 white), the inverse of [`XYZ_TO_SRGB`].
pub const SRGB_TO_XYZ: [[f64; 3]; 3] = [
    [0.4124564, 0.3575761, 0.1804375],
    [0.2126729, 0.7151522, 0.0721750],
    [0.0193339, 0.1191920, 0.9503041],
];

fn mat_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

fn mat_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut o = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            o[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    o
}

/// Bradford chromatic adaptation matrix from white `from` to white `to` (XYZ): it takes
/// `from` to `to` to rounding (the cone matrix's exact inverse, not the 7-decimal one that
/// Lindbloom tabulates, which left `to` 1e-7 off).
pub fn bradford(from: [f64; 3], to: [f64; 3]) -> [[f64; 3]; 3] {
    const M: [[f64; 3]; 3] = [
        [0.8951, 0.2664, -0.1614],
        [-0.7502, 1.7135, 0.0367],
        [0.0389, -0.0685, 1.0296],
    ];
    let s = mat_vec(&M, from);
    let d = mat_vec(&M, to);
    let diag = [
        [d[0] / s[0], 0.0, 0.0],
        [0.0, d[1] / s[1], 0.0],
        [0.0, 0.0, d[2] / s[2]],
    ];
    mat_mul(&inverse(&M), &mat_mul(&diag, &M))
}

/// XYZ -> linear sRGB.
pub fn xyz_to_linear_srgb(xyz: [f64; 3]) -> [f64; 3] {
    mat_vec(&XYZ_TO_SRGB, xyz)
}

/// Linear sRGB -> XYZ (D65).
pub fn linear_srgb_to_xyz(rgb: [f64; 3]) -> [f64; 3] {
    mat_vec(&SRGB_TO_XYZ, rgb)
}

/// The sRGB transfer curve (linear -> encoded), for values in [0, 1] (clamped: +infinity, an
/// overexposed value that overflowed, is white like any value above 1; NaN is black).
pub fn srgb_encode(v: f64) -> f64 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// The inverse sRGB transfer curve (encoded -> linear).
pub fn srgb_decode(v: f64) -> f64 {
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// A linear value in [0, 1] -> 8-bit sRGB code.
pub fn to_srgb8(v: f64) -> u8 {
    (srgb_encode(v) * 255.0).round() as u8
}

/// How spectra become linear sRGB: an illuminant, with Bradford adaptation of its white (from
/// the CIE tables, [`Illuminant::white_xyz`]) to the white of [`XYZ_TO_SRGB`] ([`srgb_white`]),
/// so a white diffuser is neutral, R = G = B = 1 to rounding, under every illuminant, D65
/// included (the tables' D65 is 2e-4 from the matrix's; the illuminant changes colour
/// rendition, not white balance).
#[derive(Debug, Clone, PartialEq)]
pub struct ColourPipeline {
    /// The illuminant.
    pub illuminant: Illuminant,
    /// XYZ under the illuminant -> linear sRGB (adaptation included).
    pub to_rgb: [[f64; 3]; 3],
}

impl ColourPipeline {
    /// The pipeline for `illuminant`.
    pub fn new(illuminant: Illuminant) -> Self {
        let adapt = bradford(illuminant.white_xyz(), srgb_white());
        Self {
            illuminant,
            to_rgb: mat_mul(&XYZ_TO_SRGB, &adapt),
        }
    }

    /// Per-channel linear-sRGB weights for a source with `channels`: `rgb = W * values`
    /// (3 rows, one column per channel). RGB sources pass through (identity).
    pub fn channel_weights(&self, channels: &brdf_io::Channels) -> Result<[Vec<f64>; 3]> {
        match channels {
            brdf_io::Channels::Rgb => Ok([
                vec![1.0, 0.0, 0.0],
                vec![0.0, 1.0, 0.0],
                vec![0.0, 0.0, 1.0],
            ]),
            brdf_io::Channels::Spectral(wl) => {
                let w = SpectralWeights::new(wl, self.illuminant)?;
                static WARNED: std::sync::atomic::AtomicBool =
                    std::sync::atomic::AtomicBool::new(false);
                // (Once said, not worked out again for every render.)
                if !WARNED.load(std::sync::atomic::Ordering::Relaxed)
                    && let Some(why) = coverage_warning(wl, self.illuminant)
                    && !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed)
                {
                    tracing::warn!("{why} (said once per run)");
                }
                let m = &self.to_rgb;
                let row = |r: usize| -> Vec<f64> {
                    (0..w.len())
                        .map(|k| m[r][0] * w.x[k] + m[r][1] * w.y[k] + m[r][2] * w.z[k])
                        .collect()
                };
                Ok([row(0), row(1), row(2)])
            }
        }
    }

    /// Linear sRGB of a reflectance spectrum sampled at `wavelengths` (one value each).
    pub fn reflectance_to_rgb(&self, wavelengths: &[f64], spectrum: &[f64]) -> Result<[f64; 3]> {
        let w = SpectralWeights::new(wavelengths, self.illuminant)?;
        Ok(mat_vec(&self.to_rgb, w.xyz(spectrum)?))
    }
}

/// CIE XYZ -> CIELAB relative to `white` (XYZ, same scale).
pub fn xyz_to_lab(xyz: [f64; 3], white: [f64; 3]) -> [f64; 3] {
    let f = |t: f64| {
        const D: f64 = 6.0 / 29.0;
        if t > D * D * D {
            t.cbrt()
        } else {
            t / (3.0 * D * D) + 4.0 / 29.0
        }
    };
    let (fx, fy, fz) = (
        f(xyz[0] / white[0]),
        f(xyz[1] / white[1]),
        f(xyz[2] / white[2]),
    );
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// Linear sRGB -> CIELAB (D65 white, sRGB white = Y 1).
pub fn linear_srgb_to_lab(rgb: [f64; 3]) -> [f64; 3] {
    xyz_to_lab(linear_srgb_to_xyz(rgb), linear_srgb_to_xyz([1.0, 1.0, 1.0]))
}

/// The CIEDE2000 colour difference between two CIELAB colours (kL = kC = kH = 1), following
/// Sharma, Wu and Dalal, "The CIEDE2000 color-difference formula: implementation notes,
/// supplementary test data, and mathematical observations", Color Res. Appl. 30 (2005).
pub fn delta_e_2000(lab1: [f64; 3], lab2: [f64; 3]) -> f64 {
    use std::f64::consts::PI;
    let [l1, a1, b1] = lab1;
    let [l2, a2, b2] = lab2;
    let c1 = a1.hypot(b1);
    let c2 = a2.hypot(b2);
    let cbar = 0.5 * (c1 + c2);
    let c7 = cbar.powi(7);
    let g = 0.5 * (1.0 - (c7 / (c7 + 25f64.powi(7))).sqrt());
    let a1p = (1.0 + g) * a1;
    let a2p = (1.0 + g) * a2;
    let c1p = a1p.hypot(b1);
    let c2p = a2p.hypot(b2);
    let hue = |b: f64, a: f64| {
        if a == 0.0 && b == 0.0 {
            0.0
        } else {
            let h = b.atan2(a);
            if h < 0.0 { h + 2.0 * PI } else { h }
        }
    };
    let h1p = hue(b1, a1p);
    let h2p = hue(b2, a2p);
    let dlp = l2 - l1;
    let dcp = c2p - c1p;
    let dhp = if c1p * c2p == 0.0 {
        0.0
    } else {
        let d = h2p - h1p;
        if d > PI {
            d - 2.0 * PI
        } else if d < -PI {
            d + 2.0 * PI
        } else {
            d
        }
    };
    let dhp_big = 2.0 * (c1p * c2p).sqrt() * (dhp / 2.0).sin();
    let lbarp = 0.5 * (l1 + l2);
    let cbarp = 0.5 * (c1p + c2p);
    let hbarp = if c1p * c2p == 0.0 {
        h1p + h2p
    } else if (h1p - h2p).abs() <= PI {
        0.5 * (h1p + h2p)
    } else if h1p + h2p < 2.0 * PI {
        0.5 * (h1p + h2p + 2.0 * PI)
    } else {
        0.5 * (h1p + h2p - 2.0 * PI)
    };
    let deg = PI / 180.0;
    let t = 1.0 - 0.17 * (hbarp - 30.0 * deg).cos()
        + 0.24 * (2.0 * hbarp).cos()
        + 0.32 * (3.0 * hbarp + 6.0 * deg).cos()
        - 0.20 * (4.0 * hbarp - 63.0 * deg).cos();
    let dtheta = 30.0 * deg * (-(((hbarp / deg) - 275.0) / 25.0).powi(2)).exp();
    let cbarp7 = cbarp.powi(7);
    let rc = 2.0 * (cbarp7 / (cbarp7 + 25f64.powi(7))).sqrt();
    let l50 = (lbarp - 50.0).powi(2);
    let sl = 1.0 + 0.015 * l50 / (20.0 + l50).sqrt();
    let sc = 1.0 + 0.045 * cbarp;
    let sh = 1.0 + 0.015 * cbarp * t;
    let rt = -(2.0 * dtheta).sin() * rc;
    let (tl, tc, th) = (dlp / sl, dcp / sc, dhp_big / sh);
    (tl * tl + tc * tc + th * th + rt * tc * th).sqrt()
}

/// CIEDE2000 between two linear sRGB colours (D65).
pub fn delta_e_2000_rgb(a: [f64; 3], b: [f64; 3]) -> f64 {
    delta_e_2000(linear_srgb_to_lab(a), linear_srgb_to_lab(b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn d65_white_point() {
        let w = Illuminant::D65.white_xyz();
        let want = [0.95047, 1.0, 1.08883];
        for c in 0..3 {
            // The 5 nm tables over 360-780 nm give Z within 2e-4 of the 1 nm value.
            assert!((w[c] - want[c]).abs() < 2e-4, "{w:?} vs {want:?}");
        }
        assert_eq!(w[1], 1.0);
    }

    /// The tabulated spectra of A and D50 give their published white points (ASTM E308, 2
    /// degrees): an illuminant read from the wrong table would move a white by 0.1 or more.
    #[test]
    fn a_and_d50_white_points() {
        for (ill, want) in [
            (Illuminant::A, [1.09850, 1.0, 0.35585]),
            (Illuminant::D50, [0.96422, 1.0, 0.82521]),
        ] {
            let w = ill.white_xyz();
            for c in 0..3 {
                assert!((w[c] - want[c]).abs() < 2e-4, "{ill:?}: {w:?} vs {want:?}");
            }
        }
    }

    /// With the published white points, `bradford` is Lindbloom's tabulated Bradford matrices
    /// (D50 -> D65 and A -> D65, 7 decimals), and the pipeline of an adapted illuminant is
    /// XYZ -> sRGB after Bradford adaptation between its own white points (a plain scaling of
    /// XYZ would move ColorChecker patches by up to 15 Delta E under A).
    #[test]
    fn bradford_matches_published_matrices_and_the_pipeline_uses_it() {
        let d65 = [0.95047, 1.0, 1.08883];
        for (from, want) in [
            (
                [0.96422, 1.0, 0.82521],
                [
                    [0.9555766, -0.0230393, 0.0631636],
                    [-0.0282895, 1.0099416, 0.0210077],
                    [0.0122982, -0.0204830, 1.3299098],
                ],
            ),
            (
                [1.09850, 1.0, 0.35585],
                [
                    [0.8446965, -0.1179225, 0.3948108],
                    [-0.1366303, 1.1041226, 0.1291718],
                    [0.0798489, -0.1348999, 3.1924009],
                ],
            ),
        ] {
            let m = bradford(from, d65);
            for i in 0..3 {
                for j in 0..3 {
                    assert!((m[i][j] - want[i][j]).abs() < 1e-6, "{m:?}");
                }
            }
        }
        for ill in [Illuminant::A, Illuminant::D50, Illuminant::D65] {
            let adapt = bradford(ill.white_xyz(), srgb_white());
            let want = mat_mul(&XYZ_TO_SRGB, &adapt);
            assert_eq!(ColourPipeline::new(ill).to_rgb, want);
            // A chromatic spectrum (a red ramp) goes through that matrix.
            let wl: Vec<f64> = (380..=780).step_by(10).map(f64::from).collect();
            let red: Vec<f64> = wl.iter().map(|w| ((w - 380.0) / 400.0).powi(3)).collect();
            let w = SpectralWeights::new(&wl, ill).unwrap();
            let rgb = ColourPipeline::new(ill)
                .reflectance_to_rgb(&wl, &red)
                .unwrap();
            let direct = mat_vec(&want, w.xyz(&red).unwrap());
            assert_eq!(rgb, direct);
            assert!(rgb[0] > 2.0 * rgb[2], "{ill:?}: {rgb:?}");
        }
    }

    /// A perfect white diffuser is neutral, R = G = B = 1 to rounding, under every illuminant
    /// and sampling: the pipeline adapts the CIE tables' white (D65's too, 2e-4 from the
    /// matrix's) to the white of the XYZ -> sRGB matrix, which is the published D65 white to
    /// the matrix's 7 decimals. Bradford takes its source white to its target to rounding.
    #[test]
    fn white_diffuser_is_neutral_to_rounding_under_every_illuminant() {
        let w = srgb_white();
        let published = [0.95047, 1.0, 1.08883];
        for c in 0..3 {
            assert!((w[c] - published[c]).abs() < 1e-6, "{w:?}");
        }
        assert!(
            (Illuminant::D65.white_xyz()[2] - published[2]).abs() > 1e-4,
            "the tables' D65 white is no longer 2e-4 from the matrix's: {:?}",
            Illuminant::D65.white_xyz()
        );
        for ill in [Illuminant::D65, Illuminant::D50, Illuminant::A] {
            let to = mat_vec(&bradford(ill.white_xyz(), w), ill.white_xyz());
            for c in 0..3 {
                assert!((to[c] - w[c]).abs() < 1e-14, "{ill}: {to:?} vs {w:?}");
            }
            for wl in [
                (360..=1000).step_by(20).map(f64::from).collect::<Vec<_>>(),
                (380..=730).step_by(10).map(f64::from).collect(),
                (400..=700).step_by(10).map(f64::from).collect(),
                vec![550.0],
            ] {
                let p = ColourPipeline::new(ill);
                let rgb = p.reflectance_to_rgb(&wl, &vec![1.0; wl.len()]).unwrap();
                for c in rgb {
                    assert!((c - 1.0).abs() < 1e-12, "{ill} {}: {rgb:?}", wl.len());
                }
            }
        }
    }

    /// A grey diffuser of reflectance r renders r in every channel (the pipeline is linear and
    /// white is neutral to rounding: see the test above), under every illuminant.
    #[test]
    fn grey_diffusers_render_their_reflectance() {
        for wl in [
            (360..=1000).step_by(20).map(f64::from).collect::<Vec<_>>(),
            (400..=700).step_by(10).map(f64::from).collect(),
            vec![550.0],
        ] {
            for ill in [Illuminant::D65, Illuminant::A, Illuminant::D50] {
                let p = ColourPipeline::new(ill);
                for r in [0.5, 0.18, 0.03] {
                    let rgb = p.reflectance_to_rgb(&wl, &vec![r; wl.len()]).unwrap();
                    for c in rgb {
                        assert!((c - r).abs() < 1e-12, "{ill} {r}: {rgb:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn needed_channels_skip_the_infrared() {
        let wl: Vec<f64> = (360..=1000).step_by(20).map(f64::from).collect();
        let w = SpectralWeights::new(&wl, Illuminant::D65).unwrap();
        let needed = w.needed();
        // 360..=780 plus the hat of 800 nm reaching down to 780 (weight 0 at one end point only
        // with the trapezoid: 800 nm's hat is zero at 780).
        assert_eq!(needed.first(), Some(&0));
        assert_eq!(wl[*needed.last().unwrap()], 780.0);
        assert!(SpectralWeights::new(&[500.0, 400.0], Illuminant::A).is_err());
        let sub = needed_wavelengths(&brdf_io::Channels::Spectral(wl.clone()), Illuminant::D65)
            .unwrap()
            .unwrap();
        assert_eq!(sub.len(), 22); // 360..=780 in 20 nm steps
        // Restricting a spectrum to the needed wavelengths keeps its colour.
        let spec: Vec<f64> = wl.iter().map(|l| (l / 300.0).sin().abs()).collect();
        let p = ColourPipeline::new(Illuminant::D65);
        let brdf_io::Channels::Spectral(sw) = &sub else {
            unreachable!()
        };
        let a = p.reflectance_to_rgb(&wl, &spec).unwrap();
        let b = p.reflectance_to_rgb(sw, &spec[..22]).unwrap();
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() < 1e-12, "{a:?} {b:?}");
        }
        assert!(
            needed_wavelengths(&brdf_io::Channels::Rgb, Illuminant::D65)
                .unwrap()
                .is_none()
        );
    }

    /// Samples that miss much of the visible range are flagged (a 500 nm store rendered gold
    /// grey, an 800-1000 nm one white, without a word); the usual samplings are not.
    #[test]
    fn samplings_that_miss_the_visible_range_are_flagged() {
        let range = |a: f64, b: f64, step: f64| -> Vec<f64> {
            (0..=((b - a) / step).round() as usize)
                .map(|i| a + i as f64 * step)
                .collect()
        };
        for ill in [Illuminant::D65, Illuminant::A] {
            for wl in [
                range(360.0, 1000.0, 20.0),
                range(400.0, 700.0, 50.0),
                range(380.0, 780.0, 5.0),
            ] {
                let c = visible_coverage(&wl, ill);
                assert!(c.iter().all(|&f| f > 0.98 && f <= 1.0), "{wl:?}: {c:?}");
                assert_eq!(coverage_warning(&wl, ill), None);
            }
            assert_eq!(visible_coverage(&range(800.0, 1000.0, 50.0), ill), [0.0; 3]);
            for wl in [vec![500.0], vec![425.0, 475.0], range(800.0, 1000.0, 50.0)] {
                let w = coverage_warning(&wl, ill).unwrap();
                assert!(
                    w.contains("extrapolated") && w.contains(&ill.to_string()),
                    "{w}"
                );
            }
        }
        // No wavelengths: a warning, not a panic (it indexed the empty slice).
        assert_eq!(visible_coverage(&[], Illuminant::D65), [0.0; 3]);
        assert!(coverage_warning(&[], Illuminant::D65).is_some_and(|w| w.contains("no spectral")));
        // Blue-poor samplings lose Z first.
        let c = visible_coverage(&range(480.0, 700.0, 20.0), Illuminant::D65);
        assert!(c[1] > 0.9 && c[2] < 0.5, "{c:?}");
        assert!(coverage_warning(&range(480.0, 700.0, 20.0), Illuminant::D65).is_some());
    }

    #[test]
    fn srgb_curve_round_trips() {
        for v in [0.0, 0.001, 0.0031308, 0.2, 0.5, 1.0] {
            assert!((srgb_decode(srgb_encode(v)) - v).abs() < 1e-12);
        }
        assert_eq!(to_srgb8(1.0), 255);
        assert_eq!(to_srgb8(0.0), 0);
        assert_eq!(to_srgb8(0.2159), 128);
    }

    /// A value that overflowed to +infinity (a bright highlight at a high exposure: 1e300 x
    /// 2^64) clips to white like any value above 1; it used to be encoded as black, a black
    /// spot in the middle of the highlight. NaN and -infinity stay black.
    #[test]
    fn overflowed_values_clip_to_white() {
        assert_eq!(srgb_encode(f64::INFINITY), srgb_encode(1.0));
        assert_eq!(to_srgb8(f64::INFINITY), 255);
        assert_eq!(to_srgb8(1e300 * 2f64.powi(64)), 255);
        assert_eq!(to_srgb8(f64::NEG_INFINITY), 0);
        assert_eq!(to_srgb8(f64::NAN), 0);
        assert_eq!(to_srgb8(2.0), 255);
    }

    /// All 34 pairs of Table 1 of Sharma, Wu and Dalal (2005), both orders (pairs 9-12 and
    /// 13-15 straddle the hue-angle boundaries the formula special-cases).
    #[test]
    fn ciede2000_matches_sharma_table() {
        let rows: [([f64; 3], [f64; 3], f64); 34] = [
            (
                [50.0000, 2.6772, -79.7751],
                [50.0000, 0.0000, -82.7485],
                2.0425,
            ),
            (
                [50.0000, 3.1571, -77.2803],
                [50.0000, 0.0000, -82.7485],
                2.8615,
            ),
            (
                [50.0000, 2.8361, -74.0200],
                [50.0000, 0.0000, -82.7485],
                3.4412,
            ),
            (
                [50.0000, -1.3802, -84.2814],
                [50.0000, 0.0000, -82.7485],
                1.0000,
            ),
            (
                [50.0000, -1.1848, -84.8006],
                [50.0000, 0.0000, -82.7485],
                1.0000,
            ),
            (
                [50.0000, -0.9009, -85.5211],
                [50.0000, 0.0000, -82.7485],
                1.0000,
            ),
            (
                [50.0000, 0.0000, 0.0000],
                [50.0000, -1.0000, 2.0000],
                2.3669,
            ),
            (
                [50.0000, -1.0000, 2.0000],
                [50.0000, 0.0000, 0.0000],
                2.3669,
            ),
            (
                [50.0000, 2.4900, -0.0010],
                [50.0000, -2.4900, 0.0009],
                7.1792,
            ),
            (
                [50.0000, 2.4900, -0.0010],
                [50.0000, -2.4900, 0.0010],
                7.1792,
            ),
            (
                [50.0000, 2.4900, -0.0010],
                [50.0000, -2.4900, 0.0011],
                7.2195,
            ),
            (
                [50.0000, 2.4900, -0.0010],
                [50.0000, -2.4900, 0.0012],
                7.2195,
            ),
            (
                [50.0000, -0.0010, 2.4900],
                [50.0000, 0.0009, -2.4900],
                4.8045,
            ),
            (
                [50.0000, -0.0010, 2.4900],
                [50.0000, 0.0010, -2.4900],
                4.8045,
            ),
            (
                [50.0000, -0.0010, 2.4900],
                [50.0000, 0.0011, -2.4900],
                4.7461,
            ),
            (
                [50.0000, 2.5000, 0.0000],
                [50.0000, 0.0000, -2.5000],
                4.3065,
            ),
            (
                [50.0000, 2.5000, 0.0000],
                [73.0000, 25.0000, -18.0000],
                27.1492,
            ),
            (
                [50.0000, 2.5000, 0.0000],
                [61.0000, -5.0000, 29.0000],
                22.8977,
            ),
            (
                [50.0000, 2.5000, 0.0000],
                [56.0000, -27.0000, -3.0000],
                31.9030,
            ),
            (
                [50.0000, 2.5000, 0.0000],
                [58.0000, 24.0000, 15.0000],
                19.4535,
            ),
            ([50.0000, 2.5000, 0.0000], [50.0000, 3.1736, 0.5854], 1.0000),
            ([50.0000, 2.5000, 0.0000], [50.0000, 3.2972, 0.0000], 1.0000),
            ([50.0000, 2.5000, 0.0000], [50.0000, 1.8634, 0.5757], 1.0000),
            ([50.0000, 2.5000, 0.0000], [50.0000, 3.2592, 0.3350], 1.0000),
            (
                [60.2574, -34.0099, 36.2677],
                [60.4626, -34.1751, 39.4387],
                1.2644,
            ),
            (
                [63.0109, -31.0961, -5.8663],
                [62.8187, -29.7946, -4.0864],
                1.2630,
            ),
            (
                [61.2901, 3.7196, -5.3901],
                [61.4292, 2.2480, -4.9620],
                1.8731,
            ),
            (
                [35.0831, -44.1164, 3.7933],
                [35.0232, -40.0716, 1.5901],
                1.8645,
            ),
            (
                [22.7233, 20.0904, -46.6940],
                [23.0331, 14.9730, -42.5619],
                2.0373,
            ),
            (
                [36.4612, 47.8580, 18.3852],
                [36.2715, 50.5065, 21.2231],
                1.4146,
            ),
            (
                [90.8027, -2.0831, 1.4410],
                [91.1528, -1.6435, 0.0447],
                1.4441,
            ),
            (
                [90.9257, -0.5406, -0.9208],
                [88.6381, -0.8985, -0.7239],
                1.5381,
            ),
            (
                [6.7747, -0.2908, -2.4247],
                [5.8714, -0.0985, -2.2286],
                0.6377,
            ),
            (
                [2.0776, 0.0795, -1.1350],
                [0.9033, -0.0636, -0.5514],
                0.9082,
            ),
        ];
        for (a, b, want) in rows {
            let d = delta_e_2000(a, b);
            assert!((d - want).abs() < 1e-4, "{a:?} {b:?}: {d} vs {want}");
            assert!((delta_e_2000(b, a) - want).abs() < 1e-4);
        }
        assert_eq!(delta_e_2000([40.0, 10.0, -3.0], [40.0, 10.0, -3.0]), 0.0);
    }
}
