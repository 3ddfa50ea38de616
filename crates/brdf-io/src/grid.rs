//! The Rusinkiewicz angular grid with MERL's index mapping, and the channel axis.
//!
//! Conventions (see `../shared/docs/DESIGN.md` section 1), kept in this one module:
//! - flat angular index `(ith * n_td + itd) * n_pd + ipd` (MERL's order: phi_d fastest);
//! - theta_h bin `i` covers `[(i/n)^2, ((i+1)/n)^2] * pi/2` (sqrt spacing);
//!   theta_d bin `j` covers `[j, j+1] / n * pi/2`; phi_d bin `k` covers `[k, k+1] / n * pi`;
//! - **values are sampled at bin centres in index space**: theta_h = ((i + 1/2)/n)^2 pi/2,
//!   theta_d = (j + 1/2)/n pi/2, phi_d = (k + 1/2)/n pi ([`AngularGrid::bin_centre`]);
//! - phi_d is folded into [0, pi) by reciprocity (swapping wi and wo adds pi to phi_d), so it is
//!   periodic with period pi;
//! - directions: local frame, z = surface normal; the half vector has azimuth 0 (isotropy).

use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;
use std::path::Path;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// A 3-vector in the local shading frame (z = normal).
pub type Vec3 = [f64; 3];

/// Rusinkiewicz half/difference angles of a direction pair, in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HalfDiff {
    /// Angle between the half vector and the normal: in [0, pi/2] for directions above the
    /// horizon ([`HalfDiff::from_dirs`] does not check that; below it, theta_h reaches pi).
    pub theta_h: f64,
    /// Angle between the incident direction and the half vector, in [0, pi/2].
    pub theta_d: f64,
    /// Azimuth of the incident direction around the half vector, folded into [0, pi).
    pub phi_d: f64,
}

fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(v: Vec3) -> Option<Vec3> {
    let n2 = dot(v, v);
    // A vector that is already unit to rounding is returned as it is (dividing by a norm within
    // 1e-15 of 1 would change it by less than an ulp).
    if (n2 - 1.0).abs() <= 1e-15 {
        return Some(v);
    }
    unit(v)
}

/// `v` divided by its norm; `None` for a zero or non-finite `v`. Any finite length works: a
/// `v` shorter than ~1e-154 or longer than ~1e154, whose squared norm underflows or
/// overflows, is divided by its largest component first.
#[inline]
pub fn unit(v: Vec3) -> Option<Vec3> {
    let n2 = dot(v, v);
    if !(n2 >= f64::MIN_POSITIVE && n2.is_finite()) {
        return unit_rescaled(v);
    }
    let n = n2.sqrt();
    Some([v[0] / n, v[1] / n, v[2] / n])
}

/// [`unit`] for a `v` whose squared norm leaves the normal range of f64.
#[cold]
fn unit_rescaled(v: Vec3) -> Option<Vec3> {
    if !v.iter().all(|x| x.is_finite()) {
        return None;
    }
    let m = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if m == 0.0 {
        return None;
    }
    let s = [v[0] / m, v[1] / m, v[2] / m];
    let n = dot(s, s).sqrt();
    Some([s[0] / n, s[1] / n, s[2] / n])
}

/// Rotates `v` about the y axis by `angle` (right-handed).
fn rotate_y(v: Vec3, angle: f64) -> Vec3 {
    let (s, c) = angle.sin_cos();
    [v[0] * c + v[2] * s, v[1], v[2] * c - v[0] * s]
}

impl HalfDiff {
    /// Half/difference angles of the direction pair (`wi`, `wo`), as in MERL's
    /// `std_coords_to_half_diff_coords`, with phi_d folded into [0, pi).
    ///
    /// Returns `None` when the half vector is undefined (wi = -wo) or a vector is zero or not
    /// finite. The inputs need not be normalised (any finite length).
    pub fn from_dirs(wi: Vec3, wo: Vec3) -> Option<Self> {
        let mut hd = Self::from_dirs_merl(wi, wo)?;
        if hd.phi_d >= PI {
            hd.phi_d -= PI;
        }
        Some(hd)
    }

    /// As [`HalfDiff::from_dirs`] with MERL's own fold (`BRDFRead.cpp`'s `phi_diff_index`):
    /// a negative phi_d gains pi, and phi_d = pi exactly (in-plane pairs, for instance, whose
    /// difference vector lies on the negative x axis) stays pi, so it lands in the last phi_d
    /// bin rather than the first. The two bins border phi_d = 0 = pi from either side and are
    /// equal for reciprocal data; MERL lookups ([`crate::merl::MerlBrdf`]) use this to read the
    /// reference reader's cell.
    pub fn from_dirs_merl(wi: Vec3, wo: Vec3) -> Option<Self> {
        let wi = normalize(wi)?;
        let wo = normalize(wo)?;
        let h = normalize([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]])?;
        let theta_h = h[2].clamp(-1.0, 1.0).acos();
        // d = R_y(-theta_h) R_z(-phi_h) wi, with the cosines and sines of phi_h and theta_h
        // read off the unit half vector (no trigonometric calls): sin theta_h = |h_xy|,
        // cos theta_h = h_z; phi_h = 0 when h is the normal.
        let rho = (h[0] * h[0] + h[1] * h[1]).sqrt();
        let (cp, sp) = if rho > 0.0 {
            (h[0] / rho, h[1] / rho)
        } else {
            (1.0, 0.0)
        };
        let v0 = wi[0] * cp + wi[1] * sp;
        let v1 = wi[1] * cp - wi[0] * sp;
        let ct = h[2].clamp(-1.0, 1.0);
        let d = [v0 * ct - wi[2] * rho, v1, wi[2] * ct + v0 * rho];
        let theta_d = d[2].clamp(-1.0, 1.0).acos();
        let mut phi_d = d[1].atan2(d[0]);
        if phi_d < 0.0 {
            phi_d += PI;
        }
        Some(Self {
            theta_h,
            theta_d,
            phi_d,
        })
    }

    /// The direction pair (wi, wo) of these angles, with the half vector at azimuth 0.
    pub fn to_dirs(&self) -> (Vec3, Vec3) {
        let (sh, ch) = self.theta_h.sin_cos();
        let (sd, cd) = self.theta_d.sin_cos();
        let (sp, cp) = self.phi_d.sin_cos();
        let h = [sh, 0.0, ch];
        let wi = rotate_y([sd * cp, sd * sp, cd], self.theta_h);
        let k = 2.0 * dot(wi, h);
        let wo = [k * h[0] - wi[0], k * h[1] - wi[1], k * h[2] - wi[2]];
        (wi, wo)
    }

    /// Whether both directions are strictly above the horizon.
    pub fn is_above_horizon(&self) -> bool {
        let (wi, wo) = self.to_dirs();
        wi[2] > 0.0 && wo[2] > 0.0
    }
}

/// The angular part of a dataset grid: resolution along theta_h, theta_d and phi_d.
///
/// Every axis holds 1..=[`AngularGrid::MAX_AXIS`] bins and the grid at most
/// [`AngularGrid::MAX_CELLS`] cells; deserialising (store headers, model files) checks the
/// same bounds as [`AngularGrid::new`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(try_from = "GridFields")]
pub struct AngularGrid {
    /// Number of theta_h bins (MERL: 90).
    pub n_theta_h: usize,
    /// Number of theta_d bins (MERL: 90).
    pub n_theta_d: usize,
    /// Number of phi_d bins over [0, pi) (MERL: 180).
    pub n_phi_d: usize,
}

/// The serialised fields of an [`AngularGrid`], checked by [`AngularGrid::new`] on the way in.
#[derive(Deserialize)]
struct GridFields {
    n_theta_h: usize,
    n_theta_d: usize,
    n_phi_d: usize,
}

impl TryFrom<GridFields> for AngularGrid {
    type Error = Error;

    fn try_from(f: GridFields) -> Result<Self> {
        Self::new(f.n_theta_h, f.n_theta_d, f.n_phi_d)
    }
}

impl AngularGrid {
    /// Largest number of bins along one axis (MERL uses 90, 90, 180).
    pub const MAX_AXIS: usize = 4096;

    /// Largest number of cells, 2^27 (about 134 M, 92 x MERL's 1.46 M): a grid is allocated as
    /// one array of cells x channels values, and beyond this a dataset no longer fits in memory.
    pub const MAX_CELLS: usize = 1 << 27;

    /// A grid of the given resolution; every count must be in 1..=[`Self::MAX_AXIS`] and the
    /// product at most [`Self::MAX_CELLS`].
    pub fn new(n_theta_h: usize, n_theta_d: usize, n_phi_d: usize) -> Result<Self> {
        let res = format!("resolution {n_theta_h},{n_theta_d},{n_phi_d}");
        if n_theta_h == 0 || n_theta_d == 0 || n_phi_d == 0 {
            return Err(Error::InvalidGrid {
                reason: format!("{res} has an empty axis; every count must be >= 1"),
            });
        }
        if n_theta_h.max(n_theta_d).max(n_phi_d) > Self::MAX_AXIS {
            return Err(Error::InvalidGrid {
                reason: format!(
                    "{res} has an axis longer than {} bins (the largest supported)",
                    Self::MAX_AXIS
                ),
            });
        }
        let cells = n_theta_h as u64 * n_theta_d as u64 * n_phi_d as u64; // <= 2^36
        if cells > Self::MAX_CELLS as u64 {
            return Err(Error::InvalidGrid {
                reason: format!(
                    "{res} has {cells} cells, more than the supported {} (2^27; MERL's 90,90,180 \
                     has 1458000)",
                    Self::MAX_CELLS
                ),
            });
        }
        Ok(Self {
            n_theta_h,
            n_theta_d,
            n_phi_d,
        })
    }

    /// MERL's (and the paper's) grid, 90 x 90 x 180.
    pub const MERL: Self = Self {
        n_theta_h: 90,
        n_theta_d: 90,
        n_phi_d: 180,
    };

    /// Number of angular cells, n_th * n_td * n_pd.
    pub fn len(&self) -> usize {
        self.n_theta_h * self.n_theta_d * self.n_phi_d
    }

    /// Always false: a grid has at least one cell.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Flat index of bin (ith, itd, ipd): `(ith * n_td + itd) * n_pd + ipd`.
    pub fn index(&self, ith: usize, itd: usize, ipd: usize) -> usize {
        debug_assert!(ith < self.n_theta_h && itd < self.n_theta_d && ipd < self.n_phi_d);
        (ith * self.n_theta_d + itd) * self.n_phi_d + ipd
    }

    /// Bin indices (ith, itd, ipd) of a flat index.
    pub fn unindex(&self, flat: usize) -> (usize, usize, usize) {
        let ipd = flat % self.n_phi_d;
        let rest = flat / self.n_phi_d;
        (rest / self.n_theta_d, rest % self.n_theta_d, ipd)
    }

    /// Angles at the centre (in index space) of bin (ith, itd, ipd).
    pub fn bin_centre(&self, ith: usize, itd: usize, ipd: usize) -> HalfDiff {
        let u = (ith as f64 + 0.5) / self.n_theta_h as f64;
        HalfDiff {
            theta_h: u * u * FRAC_PI_2,
            theta_d: (itd as f64 + 0.5) / self.n_theta_d as f64 * FRAC_PI_2,
            phi_d: (ipd as f64 + 0.5) / self.n_phi_d as f64 * PI,
        }
    }

    /// Angles at the centre of the bin with flat index `flat`.
    pub fn bin_centre_flat(&self, flat: usize) -> HalfDiff {
        let (i, j, k) = self.unindex(flat);
        self.bin_centre(i, j, k)
    }

    /// Continuous coordinates of `hd` in index space, with bin centres at integers:
    /// `(sqrt(theta_h / (pi/2)) n_th - 1/2, theta_d / (pi/2) n_td - 1/2, phi_d / pi n_pd - 1/2)`.
    /// Used for multilinear interpolation (theta axes clamp, phi_d wraps with period pi).
    pub fn continuous_coords(&self, hd: &HalfDiff) -> [f64; 3] {
        let th = (hd.theta_h.max(0.0) / FRAC_PI_2).sqrt() * self.n_theta_h as f64 - 0.5;
        let td = hd.theta_d.max(0.0) / FRAC_PI_2 * self.n_theta_d as f64 - 0.5;
        // phi_d folded into [0, pi) (`from_dirs` already gives that; skip the division then).
        let phi = if (0.0..PI).contains(&hd.phi_d) {
            hd.phi_d
        } else {
            hd.phi_d.rem_euclid(PI)
        };
        let pd = phi / PI * self.n_phi_d as f64 - 0.5;
        [th, td, pd]
    }

    /// The bin containing `hd` (MERL's lookup: floor, clamped to the grid; phi_d folded).
    pub fn locate(&self, hd: &HalfDiff) -> (usize, usize, usize) {
        let [th, td, pd] = self.continuous_coords(hd);
        let clamp = |x: f64, n: usize| ((x + 0.5).floor().max(0.0) as usize).min(n - 1);
        (
            clamp(th, self.n_theta_h),
            clamp(td, self.n_theta_d),
            clamp(pd, self.n_phi_d),
        )
    }

    /// Multilinear interpolation stencil at `hd`: eight (flat angular index, weight) pairs.
    /// Bin centres sit at integer [`continuous_coords`](Self::continuous_coords); theta_h and
    /// theta_d clamp at the grid's first and last centres, phi_d wraps with period pi. At a bin
    /// centre the stencil reduces to that bin with weight 1 (other weights are 0).
    ///
    /// Cells below the horizon ([`AngularGrid::is_valid_cell`]) hold no value, so they get
    /// weight 0 and the valid cells' weights are renormalised to sum to 1; when none of the
    /// eight is valid (a pair just above the horizon at large theta_h and theta_d), the
    /// nearest valid cell towards smaller theta_d (then theta_h) takes weight 1, so every
    /// lookup reads a measured value (all weights are 0 only on a grid without valid cells). A grazing lookup therefore reads only measured cells:
    /// interpolating towards the stored 0 of an invalid neighbour read grazing values ~19 %
    /// low at the median, up to 74 % (an audit against Neural-BRDF networks, lower direction
    /// within 1.1 degrees of the horizon). Away from the horizon (theta_h + theta_d of the
    /// stencil's largest corner below pi/2, where every corner is valid) this costs one
    /// comparison; nearer the horizon, each corner's validity costs the trigonometry of its
    /// bin centre (see [`AngularGrid::interpolation_stencil_with`] for hot loops).
    pub fn interpolation_stencil(&self, hd: &HalfDiff) -> [(usize, f64); 8] {
        self.interpolation_stencil_with(hd, |a| self.is_valid_flat(a))
    }

    /// [`AngularGrid::interpolation_stencil`] with each cell's validity read from `is_valid`
    /// (flat index), e.g. from a [`AngularGrid::validity_mask`] computed once: the same
    /// stencil without the trigonometry of the bin centres near the horizon. `is_valid` must
    /// agree with [`AngularGrid::is_valid_cell`].
    pub fn interpolation_stencil_with(
        &self,
        hd: &HalfDiff,
        is_valid: impl Fn(usize) -> bool,
    ) -> [(usize, f64); 8] {
        let c = self.continuous_coords(hd);
        // (`as` truncates, which is the floor for the non-negative values here: cheaper than
        // `f64::floor`, a library call without SSE4.1.)
        let clamp_axis = |x: f64, n: usize| -> (usize, usize, f64) {
            let x = x.clamp(0.0, (n - 1) as f64);
            let i0 = x as usize;
            let i1 = (i0 + 1).min(n - 1);
            (i0, i1, x - i0 as f64)
        };
        let wrap_axis = |x: f64, n: usize| -> (usize, usize, f64) {
            let f = if x >= 0.0 {
                (x as i64) as f64
            } else {
                x.floor()
            };
            let i0 = (f as i64).rem_euclid(n as i64) as usize;
            (i0, (i0 + 1) % n, x - f)
        };
        let (h0, h1, th) = clamp_axis(c[0], self.n_theta_h);
        let (d0, d1, td) = clamp_axis(c[1], self.n_theta_d);
        let (p0, p1, tp) = wrap_axis(c[2], self.n_phi_d);
        let mut out = [(0usize, 0.0f64); 8];
        let mut k = 0;
        for (hi, wh) in [(h0, 1.0 - th), (h1, th)] {
            for (di, wd) in [(d0, 1.0 - td), (d1, td)] {
                for (pi, wp) in [(p0, 1.0 - tp), (p1, tp)] {
                    out[k] = (self.index(hi, di, pi), wh * wd * wp);
                    k += 1;
                }
            }
        }
        // Both directions of a bin centre are above the horizon when theta_h + theta_d < pi/2
        // (their heights are cos theta_h cos theta_d -+ sin theta_h sin theta_d cos phi_d >=
        // cos(theta_h + theta_d)); h1 and d1 are the largest corners. The margin keeps the
        // shortcut clear of rounding in `is_above_horizon`.
        let centre = self.bin_centre(h1, d1, 0);
        if centre.theta_h + centre.theta_d < FRAC_PI_2 - 1e-9 {
            return out;
        }
        let mut total = 0.0;
        for (a, w) in &mut out {
            if is_valid(*a) {
                total += *w;
            } else {
                *w = 0.0;
            }
        }
        if total > 0.0 {
            for (_, w) in &mut out {
                *w /= total;
            }
            return out;
        }
        // No corner holds a value (a pair just above the horizon at a large theta_h and
        // theta_d): the nearest valid cell towards smaller theta_d, then smaller theta_h, at
        // the nearer theta_h and phi_d corners. Validity only grows as the angles shrink, so
        // the walk ends at the first valid cell; a grid without one gives all weights 0.
        let hc = if th < 0.5 { h0 } else { h1 };
        let pc = if tp < 0.5 { p0 } else { p1 };
        let nearest = (0..=d0)
            .rev()
            .map(|d| (hc, d))
            .chain((0..hc).rev().map(|h| (h, 0)))
            .map(|(h, d)| self.index(h, d, pc))
            .find(|&a| is_valid(a));
        if let Some(a) = nearest {
            out = [(a, 0.0); 8];
            out[0].1 = 1.0;
        }
        out
    }

    /// Whether both directions of the centre of bin (ith, itd, ipd) are above the horizon: the
    /// cell holds a value (the definition behind [`AngularGrid::validity_mask`]).
    pub fn is_valid_cell(&self, ith: usize, itd: usize, ipd: usize) -> bool {
        self.bin_centre(ith, itd, ipd).is_above_horizon()
    }

    /// [`AngularGrid::is_valid_cell`] of the bin with flat index `flat`.
    fn is_valid_flat(&self, flat: usize) -> bool {
        self.bin_centre_flat(flat).is_above_horizon()
    }

    /// Validity mask over flat indices: true where both directions of the bin centre are above
    /// the horizon. Cells outside the mask hold no measurement and never enter statistics.
    pub fn validity_mask(&self) -> Vec<bool> {
        (0..self.len()).map(|f| self.is_valid_flat(f)).collect()
    }
}

impl fmt::Display for AngularGrid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{},{},{}", self.n_theta_h, self.n_theta_d, self.n_phi_d)
    }
}

impl FromStr for AngularGrid {
    type Err = Error;

    /// Parses `TH,TD,PD`, e.g. `90,90,180`.
    fn from_str(s: &str) -> Result<Self> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let bad = || Error::InvalidGrid {
            reason: format!(
                "expected TH,TD,PD (three positive integers, e.g. 90,90,180), got {s:?}"
            ),
        };
        if parts.len() != 3 {
            return Err(bad());
        }
        let n: Vec<usize> = parts
            .iter()
            .map(|p| p.parse::<usize>().map_err(|_| bad()))
            .collect::<Result<_>>()?;
        Self::new(n[0], n[1], n[2])
    }
}

/// The channel axis of a dataset: sampled wavelengths (nm) or the three RGB channels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", content = "wavelengths_nm", rename_all = "lowercase")]
pub enum Channels {
    /// Spectral samples at these wavelengths in nm, strictly increasing.
    Spectral(Vec<f64>),
    /// Linear RGB (the colour space of the source: sRGB primaries for RGL and MERL).
    Rgb,
}

/// Most wavelengths a `START:END:STEP` range may give (0.16 nm steps over 360-1000 nm): a finer
/// step is almost always a typo, and would make every store of it huge.
pub const MAX_WAVELENGTHS: usize = 4096;

/// Parses `START:END:STEP` (END included, and on the step: a range that stopped short of it
/// silently, 400:700:70 giving 400-680, hid a typo or a wrong STEP) or a comma list of numbers,
/// at most `max` values (`what` names them in that message), or says why not (the caller
/// names the option and the units around it). Shared by `--wavelengths` and `specgp albedo
/// --angles`.
pub fn parse_values(spec: &str, max: usize, what: &str) -> std::result::Result<Vec<f64>, String> {
    let num = |t: &str| {
        t.trim()
            .parse::<f64>()
            .map_err(|_| format!("{:?} is not a number", t.trim()))
    };
    if !spec.contains(':') {
        return spec.split(',').map(num).collect();
    }
    let parts: Vec<&str> = spec.split(':').collect();
    if parts.len() != 3 {
        return Err("a range needs exactly three fields".into());
    }
    let (start, end, step) = (num(parts[0])?, num(parts[1])?, num(parts[2])?);
    if ![start, end, step].iter().all(|v| v.is_finite()) || step <= 0.0 || end < start {
        return Err("need finite numbers, STEP > 0 and END >= START".into());
    }
    // Counted in f64 first: a tiny step would overflow the integer.
    let steps = ((end - start) / step + 1e-9).floor();
    if steps.is_nan() || steps >= max as f64 {
        return Err(format!(
            "more than {max} {what} (is STEP meant to be that small?)"
        ));
    }
    let last = start + steps * step;
    if (end - start) / step - steps > 1e-6 {
        return Err(format!(
            "END {end} is not START plus a whole number of STEPs (the range would stop at \
             {last}); write {start}:{last}:{step}, or choose a STEP that divides {}",
            end - start
        ));
    }
    Ok((0..=steps as usize)
        .map(|i| start + i as f64 * step)
        .collect())
}

impl Channels {
    /// Spectral channels at the given wavelengths (nm); they must be finite, positive and
    /// strictly increasing.
    pub fn spectral(wavelengths_nm: Vec<f64>) -> Result<Self> {
        if wavelengths_nm.is_empty() {
            return Err(Error::InvalidGrid {
                reason: "a spectral channel axis needs at least one wavelength".into(),
            });
        }
        if wavelengths_nm.iter().any(|w| !w.is_finite() || *w <= 0.0) {
            return Err(Error::InvalidGrid {
                reason: format!("wavelengths must be finite and positive, got {wavelengths_nm:?}"),
            });
        }
        if wavelengths_nm.windows(2).any(|w| w[1] <= w[0]) {
            return Err(Error::InvalidGrid {
                reason: format!("wavelengths must be strictly increasing, got {wavelengths_nm:?}"),
            });
        }
        Ok(Self::Spectral(wavelengths_nm))
    }

    /// Parses a wavelength specification: `START:END:STEP` in nm (END included; it must be
    /// START plus a whole number of STEPs; at most [`MAX_WAVELENGTHS`]) or a comma-separated
    /// list.
    pub fn parse_wavelengths(spec: &str) -> Result<Self> {
        let values = parse_values(spec, MAX_WAVELENGTHS, "wavelengths").map_err(|why| {
            Error::InvalidGrid {
                reason: format!(
                    "wavelengths {spec:?}: {why} (expected START:END:STEP or a comma list, in nm)"
                ),
            }
        })?;
        Self::spectral(values)
    }

    /// Number of channels.
    pub fn len(&self) -> usize {
        match self {
            Self::Spectral(w) => w.len(),
            Self::Rgb => 3,
        }
    }

    /// Always false: a channel axis has at least one channel.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Channel labels for CSV headers: wavelengths as numbers (`450`, `452.5`) or `R`, `G`, `B`.
    pub fn labels(&self) -> Vec<String> {
        match self {
            Self::Spectral(w) => w.iter().map(|x| format!("{x}")).collect(),
            Self::Rgb => vec!["R".into(), "G".into(), "B".into()],
        }
    }

    /// The name of channel `k` in messages: `600 nm`, or `R`, `G`, `B` (the index itself when
    /// there is no channel `k`).
    pub fn name(&self, k: usize) -> String {
        match self {
            Self::Spectral(wl) => wl
                .get(k)
                .map_or_else(|| format!("{k}"), |w| format!("{w} nm")),
            Self::Rgb => ["R", "G", "B"]
                .get(k)
                .map_or_else(|| format!("{k}"), |c| c.to_string()),
        }
    }
}

/// Output channels of a source and how each comes from its stored channels (an RGL file's, a
/// dataset's): all of them, or wavelengths interpolated linearly between the two neighbouring
/// stored wavelengths (as Mitsuba does; the interpolation is in BRDF values).
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSelection {
    /// The output channel axis.
    pub channels: Channels,
    /// Per output channel: stored channels `lo`, `hi` and weight `t` of `hi`
    /// (value = (1 - t) f_lo + t f_hi).
    taps: Vec<(usize, usize, f64)>,
    /// The first and last stored channel the taps read (kept: lazy lookups ask for it per
    /// cell).
    span: (usize, usize),
}

impl ChannelSelection {
    /// All stored channels, unchanged.
    pub fn all(stored: &Channels) -> Self {
        Self::from_taps(
            stored.clone(),
            (0..stored.len()).map(|c| (c, c, 0.0)).collect(),
        )
    }

    fn from_taps(channels: Channels, taps: Vec<(usize, usize, f64)>) -> Self {
        let first = taps.iter().map(|tap| tap.0).min().unwrap_or(0);
        let last = taps
            .iter()
            .map(|&(lo, hi, t)| if t == 0.0 { lo } else { hi })
            .max()
            .unwrap_or(0);
        Self {
            channels,
            taps,
            span: (first, last),
        }
    }

    /// Per output channel: stored channels `lo`, `hi` and weight `t` of `hi`
    /// (value = (1 - t) f_lo + t f_hi).
    pub fn taps(&self) -> &[(usize, usize, f64)] {
        &self.taps
    }

    /// Channels `wanted` from `stored`: R, G, B from RGB channels, or wavelengths inside the
    /// stored range (within 1e-9 nm) from spectral ones. Errors, naming `path` (the file or
    /// store the channels belong to), for a wavelength outside the range, a mix of RGB and
    /// spectral channels, or stored spectral channels without a wavelength.
    pub fn new(path: &Path, stored: &Channels, wanted: &Channels) -> Result<Self> {
        let (s, w) = match (stored, wanted) {
            (Channels::Rgb, Channels::Rgb) => return Ok(Self::all(stored)),
            (Channels::Spectral(s), Channels::Spectral(w)) => (s, w),
            (Channels::Rgb, Channels::Spectral(_)) => {
                return Err(Error::InvalidArgument {
                    reason: format!(
                        "{}: RGB data has no wavelengths; give none (its R, G, B channels are \
                         read as they are)",
                        path.display()
                    ),
                });
            }
            (Channels::Spectral(_), Channels::Rgb) => {
                return Err(Error::InvalidArgument {
                    reason: format!(
                        "{}: spectral data has no RGB channels; give wavelengths",
                        path.display()
                    ),
                });
            }
        };
        let (Some(&min), Some(&max)) = (s.first(), s.last()) else {
            return Err(Error::InvalidArgument {
                reason: format!("{}: the data has no wavelengths", path.display()),
            });
        };
        let taps = w
            .iter()
            .map(|&l| {
                if !(l >= min - 1e-9 && l <= max + 1e-9) {
                    return Err(Error::WavelengthOutOfRange {
                        path: path.to_owned(),
                        wavelength_nm: l,
                        min_nm: min,
                        max_nm: max,
                    });
                }
                let hi = s.partition_point(|&x| x < l).min(s.len() - 1);
                Ok(if (s[hi] - l).abs() <= 1e-9 || hi == 0 {
                    (hi, hi, 0.0)
                } else {
                    let lo = hi - 1;
                    (lo, hi, (l - s[lo]) / (s[hi] - s[lo]))
                })
            })
            .collect::<Result<_>>()?;
        Ok(Self::from_taps(wanted.clone(), taps))
    }

    /// Whether the selection is the identity on `stored` channels.
    pub fn is_identity(&self, stored: usize) -> bool {
        self.taps.len() == stored
            && self
                .taps
                .iter()
                .enumerate()
                .all(|(c, &(lo, hi, t))| lo == c && hi == c && t == 0.0)
    }

    /// The output channels' values into `out` (one slot per output channel) from stored
    /// channels `first..`: `values[k - first]` is stored channel `k` ([`Self::span`] gives the
    /// channels the taps read).
    pub fn apply(&self, values: &[f64], first: usize, out: &mut [f64]) {
        for (o, &(lo, hi, t)) in out.iter_mut().zip(&self.taps) {
            let v_lo = values[lo - first];
            *o = if t == 0.0 {
                v_lo
            } else {
                (1.0 - t) * v_lo + t * values[hi - first]
            };
        }
    }

    /// The first and last stored channel the taps read.
    pub fn span(&self) -> (usize, usize) {
        self.span
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rotates `v` about the z axis by `angle` (right-handed).
    fn rotate_z(v: Vec3, angle: f64) -> Vec3 {
        let (s, c) = angle.sin_cos();
        [v[0] * c - v[1] * s, v[0] * s + v[1] * c, v[2]]
    }
    use proptest::prelude::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    /// Wavelengths pick the stored channels at or around them (the weight of the upper one),
    /// within 1e-9 nm of the ends; every refusal names the file: a wavelength outside the
    /// range, RGB against spectral channels either way, and a spectral list without a
    /// wavelength (it used to index an empty list).
    #[test]
    fn channel_selections_interpolate_wavelengths_and_refuse_what_they_cannot() {
        let path = Path::new("a.sbrdf");
        let stored = Channels::Spectral(vec![400.0, 500.0, 700.0]);
        let sel = ChannelSelection::new(
            path,
            &stored,
            &Channels::Spectral(vec![400.0 - 1e-10, 450.0, 500.0, 650.0, 700.0 + 1e-10]),
        )
        .unwrap();
        assert_eq!(
            sel.taps(),
            &[
                (0, 0, 0.0),
                (0, 1, 0.5),
                (1, 1, 0.0),
                (1, 2, 0.75),
                (2, 2, 0.0)
            ]
        );
        assert!(!sel.is_identity(3));
        assert_eq!(sel.span(), (0, 2));
        assert!(ChannelSelection::all(&stored).is_identity(3));
        assert!(!stored.is_empty());
        // The first stored channels alone are not the identity on all of them; the taps read
        // channels up to the upper neighbour of an interpolated wavelength.
        let part =
            |w: Vec<f64>| ChannelSelection::new(path, &stored, &Channels::Spectral(w)).unwrap();
        assert!(!part(vec![400.0, 500.0]).is_identity(3));
        assert_eq!(part(vec![450.0]).span(), (0, 1));
        assert_eq!(part(vec![500.0, 600.0]).span(), (1, 2));
        assert_eq!(part(vec![500.0]).span(), (1, 1));
        let refused = |stored: &Channels, wanted: &Channels, want: &str| {
            let e = ChannelSelection::new(path, stored, wanted)
                .err()
                .unwrap_or_else(|| panic!("{stored:?} -> {wanted:?} accepted"))
                .to_string();
            assert!(e.contains("a.sbrdf") && e.contains(want), "{e}");
        };
        refused(&stored, &Channels::Spectral(vec![399.9]), "399.9");
        refused(&stored, &Channels::Spectral(vec![700.1]), "700.1");
        refused(&stored, &Channels::Rgb, "spectral data has no RGB");
        refused(
            &Channels::Rgb,
            &Channels::Spectral(vec![500.0]),
            "RGB data has no",
        );
        refused(
            &Channels::Spectral(vec![]),
            &Channels::Spectral(vec![500.0]),
            "no wavelengths",
        );
    }

    #[test]
    fn index_round_trip_and_merl_order() {
        let g = AngularGrid::MERL;
        assert_eq!(g.len(), 1_458_000);
        assert_eq!(g.index(0, 0, 1), 1);
        assert_eq!(g.index(0, 1, 0), 180);
        assert_eq!(g.index(1, 0, 0), 90 * 180);
        for flat in [0, 1, 179, 180, 16_199, 16_200, 1_457_999] {
            let (i, j, k) = g.unindex(flat);
            assert_eq!(g.index(i, j, k), flat);
        }
    }

    #[test]
    fn locate_bin_centres_on_coarse_and_merl_grids() {
        for g in [AngularGrid::new(5, 7, 9).unwrap(), AngularGrid::MERL] {
            for flat in (0..g.len()).step_by(97) {
                let (i, j, k) = g.unindex(flat);
                assert_eq!(g.locate(&g.bin_centre(i, j, k)), (i, j, k));
                let c = g.continuous_coords(&g.bin_centre(i, j, k));
                assert!(close(c[0], i as f64, 1e-9) && close(c[1], j as f64, 1e-9));
                assert!(close(c[2], k as f64, 1e-9));
            }
        }
    }

    /// Lookups at and past the grid's edges clamp to its first and last bins: theta_h and
    /// theta_d of exactly pi/2 (where the floor gives bin n, one past the end), theta_h up to
    /// pi (below the horizon) and negative angles; phi_d folds instead.
    #[test]
    fn locate_clamps_at_the_edges_of_the_grid() {
        let g = AngularGrid::new(5, 7, 9).unwrap();
        let at = |theta_h, theta_d, phi_d| {
            g.locate(&HalfDiff {
                theta_h,
                theta_d,
                phi_d,
            })
        };
        assert_eq!(at(FRAC_PI_2, FRAC_PI_2, 0.0), (4, 6, 0));
        assert_eq!(at(PI, 2.0, PI + 0.1), (4, 6, 0));
        assert_eq!(at(-0.1, -0.1, -0.1), (0, 0, 8));
    }

    #[test]
    fn interpolation_stencil_weights() {
        let g = AngularGrid::new(6, 5, 8).unwrap();
        // At a bin centre: that bin with weight 1.
        let st = g.interpolation_stencil(&g.bin_centre(2, 3, 4));
        let total: f64 = st.iter().map(|(_, w)| w).sum();
        assert!(close(total, 1.0, 1e-12));
        let at: f64 = st
            .iter()
            .filter(|(i, _)| *i == g.index(2, 3, 4))
            .map(|(_, w)| w)
            .sum();
        assert!(close(at, 1.0, 1e-9), "{st:?}");
        // Half-way in phi_d between the last and the first bin: wraps around.
        let hd = HalfDiff {
            phi_d: 0.0,
            ..g.bin_centre(2, 3, 0)
        };
        let st = g.interpolation_stencil(&hd);
        let w_first: f64 = st
            .iter()
            .filter(|(i, _)| *i == g.index(2, 3, 0))
            .map(|(_, w)| w)
            .sum();
        let w_last: f64 = st
            .iter()
            .filter(|(i, _)| *i == g.index(2, 3, 7))
            .map(|(_, w)| w)
            .sum();
        assert!(
            close(w_first, 0.5, 1e-9) && close(w_last, 0.5, 1e-9),
            "{st:?}"
        );
    }

    /// theta_h past pi/2 (below the horizon; `from_dirs` gives up to pi) clamps to the last
    /// theta_h bin, where the stencil still interpolates theta_d: half-way between the first
    /// two theta_d centres at phi_d = pi/2 (both cells valid) it reads each with weight 1/2.
    #[test]
    fn stencils_clamp_theta_h_past_the_last_bin() {
        let g = AngularGrid::new(5, 7, 9).unwrap();
        assert!(g.is_valid_cell(4, 0, 4) && g.is_valid_cell(4, 1, 4));
        for theta_h in [FRAC_PI_2 + 0.1, 2.5, PI] {
            let hd = HalfDiff {
                theta_h,
                theta_d: FRAC_PI_2 / 7.0,
                phi_d: FRAC_PI_2,
            };
            let st = g.interpolation_stencil(&hd);
            let weight = |a: usize| -> f64 { st.iter().filter(|c| c.0 == a).map(|c| c.1).sum() };
            let (a, b) = (g.index(4, 0, 4), g.index(4, 1, 4));
            assert!(close(weight(a), 0.5, 1e-12), "{theta_h}: {st:?}");
            assert!(close(weight(b), 0.5, 1e-12), "{theta_h}: {st:?}");
        }
    }

    /// Lookups over [0, pi/2]^2 x [0, pi): `n_theta` evenly spaced theta_h and theta_d from 0
    /// to pi/2 inclusive, `n_phi` phi_d from 0 in steps of pi / `n_phi`.
    fn angle_sweep(n_theta: usize, n_phi: usize) -> impl Iterator<Item = HalfDiff> {
        let theta = move |i: usize| i as f64 / (n_theta - 1) as f64 * FRAC_PI_2;
        (0..n_theta).flat_map(move |i| {
            (0..n_theta).flat_map(move |j| {
                (0..n_phi).map(move |k| HalfDiff {
                    theta_h: theta(i),
                    theta_d: theta(j),
                    phi_d: k as f64 / n_phi as f64 * PI,
                })
            })
        })
    }

    /// Whether a stencil is the nearest-valid-cell fallback: one cell, weight 1.
    fn is_fallback(st: &[(usize, f64)]) -> bool {
        st.iter().all(|&(a, _)| a == st[0].0) && st[0].1 == 1.0
    }

    /// Near the horizon the stencil reads valid cells only, with weights summing to 1; away
    /// from it (and wherever all eight corners are valid) it is the plain multilinear stencil.
    #[test]
    fn stencils_skip_cells_below_the_horizon() {
        let g = AngularGrid::new(12, 10, 16).unwrap();
        let mask = g.validity_mask();
        let (mut partial, mut plain, mut nearest) = (0, 0, 0);
        for hd in angle_sweep(40, 9) {
            let st = g.interpolation_stencil(&hd);
            let total: f64 = st.iter().map(|(_, w)| w).sum();
            let reads_invalid = st.iter().any(|&(a, w)| w > 0.0 && !mask[a]);
            assert!(!reads_invalid, "{hd:?}: {st:?}");
            assert!((total - 1.0).abs() < 1e-12, "{hd:?}: {total}");
            // The plain multilinear weights, for comparison.
            let c = g.continuous_coords(&hd);
            let all_valid = st.iter().all(|&(a, _)| mask[a]);
            if is_fallback(&st) {
                nearest += 1;
            } else if all_valid {
                plain += 1;
                let th = c[0].clamp(0.0, 11.0);
                let w_h1 = th - th.floor();
                let w: f64 = st
                    .iter()
                    .filter(|&&(a, _)| g.unindex(a).0 == (th as usize + 1).min(11))
                    .map(|(_, w)| w)
                    .sum();
                if th < 11.0 {
                    assert!((w - w_h1).abs() < 1e-12, "{hd:?}: {st:?}");
                }
            } else if total > 0.0 {
                partial += 1;
            }
        }
        // All three kinds of lookup occur in the sweep.
        assert!(
            partial > 100 && plain > 1000 && nearest > 10,
            "partial {partial}, plain {plain}, nearest {nearest}"
        );
    }

    /// When no corner of a stencil is valid, the fallback cell is at the theta_h and phi_d
    /// corners nearer to the lookup (its index-space coordinates rounded), at the largest
    /// valid theta_d up to the stencil's lower one; only a row without such a cell moves to
    /// a smaller theta_h (at theta_d bin 0). Lookups nearer either corner on both axes occur.
    #[test]
    fn stencil_fallback_reads_the_nearer_theta_h_and_phi_d_corner() {
        let g = AngularGrid::new(12, 10, 16).unwrap();
        let mask = g.validity_mask();
        let mut seen = [[0; 2]; 2];
        for hd in angle_sweep(80, 17) {
            let st = g.interpolation_stencil(&hd);
            if !is_fallback(&st) {
                continue;
            }
            let c = g.continuous_coords(&hd);
            let th = c[0].clamp(0.0, 11.0);
            let tp = c[2].rem_euclid(1.0);
            if th.fract() == 0.5 || tp == 0.5 {
                continue; // half-way: neither corner is nearer
            }
            let hn = th.round() as usize;
            let pn = c[2].rem_euclid(16.0).round() as usize % 16;
            let d0 = c[1].clamp(0.0, 9.0).floor() as usize;
            let (ci, cj, ck) = g.unindex(st[0].0);
            assert!(mask[st[0].0] && ck == pn, "{hd:?}: {st:?}");
            if ci == hn {
                assert!(cj <= d0, "{hd:?}: {st:?}");
                assert!(cj == d0 || !mask[g.index(hn, cj + 1, pn)], "{hd:?}");
            } else {
                assert!(ci < hn && cj == 0, "{hd:?}: {st:?}");
                assert!((0..=d0).all(|d| !mask[g.index(hn, d, pn)]), "{hd:?}");
            }
            // Counted between two theta_h centres only (past the last one, both corners are
            // the same cell).
            if c[0] < 11.0 {
                seen[usize::from(th.fract() > 0.5)][usize::from(tp > 0.5)] += 1;
            }
        }
        assert!(seen.iter().flatten().all(|&n| n > 0), "{seen:?}");
    }

    /// Directions of any finite length give the angles of their unit vectors: a length below
    /// ~1e-154 or above ~1e154, whose squares underflow or overflow, used to give `None`.
    #[test]
    fn directions_of_any_finite_length_are_normalised() {
        let (wi, wo) = ([0.0, 0.6, 0.8], [0.3, -0.4, 0.75f64.sqrt()]);
        let (a, b) = (
            HalfDiff::from_dirs(wi, wo).unwrap(),
            HalfDiff::from_dirs(wo, wi).unwrap(),
        );
        for s in [1e-170, 1e-300, 1e170, 1e300] {
            let scaled = wi.map(|x| x * s);
            for (hd, want) in [
                (HalfDiff::from_dirs(scaled, wo), a),
                (HalfDiff::from_dirs(wo, scaled), b),
                (HalfDiff::from_dirs_merl(scaled, wo), a),
            ] {
                let hd = hd.unwrap_or_else(|| panic!("{s:e}: None"));
                assert!(close(hd.theta_h, want.theta_h, 1e-12), "{s:e}: {hd:?}");
                assert!(close(hd.theta_d, want.theta_d, 1e-12), "{s:e}: {hd:?}");
                assert!(close(hd.phi_d, want.phi_d, 1e-12), "{s:e}: {hd:?}");
            }
        }
        for bad in [
            [0.0; 3],
            [f64::NAN, 0.0, 1.0],
            [f64::INFINITY, 0.0, 1.0],
            [1e300, 0.0, f64::NAN],
        ] {
            assert_eq!(HalfDiff::from_dirs(bad, wo), None, "{bad:?}");
        }
    }

    #[test]
    fn normal_incidence_and_mirror_direction() {
        // theta_h = 0, theta_d = 0: both directions along the normal.
        let (wi, wo) = HalfDiff {
            theta_h: 0.0,
            theta_d: 0.0,
            phi_d: 0.0,
        }
        .to_dirs();
        assert!(close(wi[2], 1.0, 1e-15) && close(wo[2], 1.0, 1e-15));
        // theta_h = 0: wo is the mirror of wi about the normal.
        let (wi, wo) = HalfDiff {
            theta_h: 0.0,
            theta_d: 0.7,
            phi_d: 0.3,
        }
        .to_dirs();
        assert!(close(wi[0], -wo[0], 1e-15) && close(wi[1], -wo[1], 1e-15));
        assert!(close(wi[2], wo[2], 1e-15) && close(wi[2], 0.7f64.cos(), 1e-15));
    }

    /// "Strictly above the horizon": a pair with one direction exactly on it (height 0.0 after
    /// rounding; these angles were searched for that) is not above it, either direction.
    #[test]
    fn a_direction_exactly_on_the_horizon_is_not_above_it() {
        let wi_on = HalfDiff {
            theta_h: 1.2787789185589873,
            theta_d: 0.2920174082359093,
            phi_d: 0.0,
        };
        let (wi, wo) = wi_on.to_dirs();
        assert!(wi[2] == 0.0 && wo[2] > 0.0, "{wi:?} {wo:?}");
        assert!(!wi_on.is_above_horizon());
        let wo_on = HalfDiff {
            theta_h: 1.1574731975160903,
            theta_d: 0.4133231292788062,
            phi_d: PI,
        };
        let (wi, wo) = wo_on.to_dirs();
        assert!(wi[2] > 0.0 && wo[2] == 0.0, "{wi:?} {wo:?}");
        assert!(!wo_on.is_above_horizon());
        // With theta_d 1e-12 smaller, both pairs are above.
        for hd in [wi_on, wo_on] {
            let inside = HalfDiff {
                theta_d: hd.theta_d - 1e-12,
                ..hd
            };
            assert!(inside.is_above_horizon(), "{inside:?}");
        }
    }

    #[test]
    fn validity_mask_excludes_grazing_cells() {
        let g = AngularGrid::new(8, 8, 16).unwrap();
        let mask = g.validity_mask();
        let valid = mask.iter().filter(|v| **v).count();
        assert!(valid > g.len() / 2 && valid < g.len(), "valid = {valid}");
        // theta_h and theta_d both near pi/2 put wo under the horizon.
        assert!(!mask[g.index(7, 7, 0)]);
        assert!(mask[g.index(0, 0, 0)]);
    }

    #[test]
    fn grid_bounds() {
        let e = "100000,100000,100000".parse::<AngularGrid>().unwrap_err();
        assert!(e.to_string().contains("longer than 4096 bins"), "{e}");
        let e = AngularGrid::new(1000, 1000, 2000).unwrap_err();
        assert!(
            e.to_string()
                .contains("2000000000 cells, more than the supported 134217728"),
            "{e}"
        );
        let g = AngularGrid::new(4096, 32, 1024).unwrap();
        assert_eq!(g.len(), AngularGrid::MAX_CELLS);
        assert!(AngularGrid::new(4096, 32, 1025).is_err());
        assert!(AngularGrid::new(4097, 1, 1).is_err());
        // Deserialising checks the same bounds.
        let ok: AngularGrid =
            serde_json::from_str(r#"{"n_theta_h":90,"n_theta_d":90,"n_phi_d":180}"#).unwrap();
        assert_eq!(ok, AngularGrid::MERL);
        let e = serde_json::from_str::<AngularGrid>(
            r#"{"n_theta_h":100000,"n_theta_d":100000,"n_phi_d":100000}"#,
        )
        .unwrap_err();
        assert!(e.to_string().contains("longer than 4096 bins"), "{e}");
        assert!(
            serde_json::from_str::<AngularGrid>(r#"{"n_theta_h":0,"n_theta_d":1,"n_phi_d":1}"#)
                .is_err()
        );
    }

    #[test]
    fn channel_names_carry_their_unit() {
        let w = Channels::parse_wavelengths("450,600.5").unwrap();
        assert_eq!(
            [w.name(0), w.name(1), w.name(2)],
            ["450 nm", "600.5 nm", "2"]
        );
        assert_eq!(
            [0, 1, 2, 3].map(|k| Channels::Rgb.name(k)),
            ["R", "G", "B", "3"]
        );
    }

    /// The shared range/list parser names a bad token and its own limit's unit.
    #[test]
    fn parse_values_names_bad_tokens_and_its_limit() {
        assert_eq!(parse_values("0:4:2", 10, "things"), Ok(vec![0.0, 2.0, 4.0]));
        assert_eq!(parse_values(" 1, 2.5", 10, "things"), Ok(vec![1.0, 2.5]));
        assert_eq!(
            parse_values("1, x", 10, "things"),
            Err("\"x\" is not a number".to_owned())
        );
        let e = parse_values("0:4:2", 2, "things").unwrap_err();
        assert!(e.starts_with("more than 2 things"), "{e}");
    }

    #[test]
    fn parse_grid_and_wavelengths() {
        assert_eq!(
            "90,90,180".parse::<AngularGrid>().unwrap(),
            AngularGrid::MERL
        );
        assert!("90,90".parse::<AngularGrid>().is_err());
        assert!("0,90,180".parse::<AngularGrid>().is_err());
        // Displayed as it is written.
        let g = AngularGrid::new(12, 10, 16).unwrap();
        assert_eq!(g.to_string(), "12,10,16");
        assert_eq!(g.to_string().parse::<AngularGrid>().unwrap(), g);
        let c = Channels::parse_wavelengths("360:1000:10").unwrap();
        assert_eq!(c.len(), 65);
        assert_eq!(c.labels()[1], "370");
        assert_eq!(
            Channels::parse_wavelengths("450, 550,650").unwrap().len(),
            3
        );
        assert!(Channels::parse_wavelengths("550,450").is_err());
        // Each rule of a range on its own, with its reason.
        for spec in ["400:300:10", "400:700:0", "400:700:-10"] {
            let e = Channels::parse_wavelengths(spec).unwrap_err().to_string();
            assert!(
                e.contains(spec) && e.contains("STEP > 0 and END >= START"),
                "{e}"
            );
        }
        assert!(Channels::parse_wavelengths("a:b").is_err());
        // Non-finite ends and steps so small that the count overflows, or just too many.
        for spec in [
            "-inf:700:50",
            "400:inf:50",
            "400:700:1e-310",
            "400:700:0.01",
            "nan:700:1",
        ] {
            let e = Channels::parse_wavelengths(spec).unwrap_err().to_string();
            assert!(e.contains(spec), "{e}");
        }
        assert_eq!(
            Channels::parse_wavelengths("360:1000:0.25").unwrap().len(),
            2561
        );
        assert_eq!(
            Channels::parse_wavelengths("400:700:2.5").unwrap().labels()[120],
            "700"
        );
        assert_eq!(Channels::parse_wavelengths("550:550:10").unwrap().len(), 1);
        // An END off the step is refused, naming where the range would stop.
        for (spec, stop) in [
            ("400:700:70", "680"),
            ("400:700:1000", "400"),
            ("400:410:3", "409"),
        ] {
            let e = Channels::parse_wavelengths(spec).unwrap_err().to_string();
            assert!(
                e.contains(spec) && e.contains(&format!("would stop at {stop})")),
                "{e}"
            );
        }
    }

    proptest! {
        /// A stencil with the validity read from a precomputed mask is the stencil (the
        /// horizon region, where the validity decides, included).
        #[test]
        fn stencil_with_a_validity_mask_is_the_stencil(
            th in 0.0..FRAC_PI_2, td in 0.0..FRAC_PI_2, pd in 0.0..PI, g in 0usize..3
        ) {
            let grid = [
                AngularGrid::new(8, 8, 16).unwrap(),
                AngularGrid::new(32, 32, 64).unwrap(),
                AngularGrid::new(5, 90, 3).unwrap(),
            ][g];
            let mask = grid.validity_mask();
            let hd = HalfDiff { theta_h: th, theta_d: td, phi_d: pd };
            prop_assert_eq!(
                grid.interpolation_stencil_with(&hd, |a| mask[a]),
                grid.interpolation_stencil(&hd)
            );
        }

        #[test]
        fn half_diff_round_trip(th in 0.0..1.5f64, td in 0.0..1.5f64, pd in 0.0..3.1f64) {
            let hd = HalfDiff { theta_h: th, theta_d: td, phi_d: pd };
            let (wi, wo) = hd.to_dirs();
            prop_assert!(close(dot(wi, wi), 1.0, 1e-12) && close(dot(wo, wo), 1.0, 1e-12));
            let back = HalfDiff::from_dirs(wi, wo).unwrap();
            prop_assert!(close(back.theta_h, th, 1e-9), "{back:?} vs {hd:?}");
            prop_assert!(close(back.theta_d, td, 1e-9), "{back:?} vs {hd:?}");
            // theta_d = 0 leaves phi_d undefined.
            if td > 1e-6 {
                let dp = (back.phi_d - pd).abs();
                prop_assert!(dp < 1e-7 || (PI - dp) < 1e-7, "{back:?} vs {hd:?}");
            }
        }

        #[test]
        fn reciprocity_folds_phi_d(th in 0.01..1.5f64, td in 0.01..1.5f64, pd in 0.0..3.1f64) {
            let (wi, wo) = HalfDiff { theta_h: th, theta_d: td, phi_d: pd }.to_dirs();
            let a = HalfDiff::from_dirs(wi, wo).unwrap();
            let b = HalfDiff::from_dirs(wo, wi).unwrap();
            prop_assert!(close(a.theta_h, b.theta_h, 1e-9) && close(a.theta_d, b.theta_d, 1e-9));
            let dp = (a.phi_d - b.phi_d).abs();
            prop_assert!(dp < 1e-7 || (PI - dp) < 1e-7);
        }

        #[test]
        fn azimuthal_rotation_invariance(th in 0.01..1.5f64, td in 0.01..1.5f64, pd in 0.0..3.1f64, rot in -3.0..3.0f64) {
            let hd = HalfDiff { theta_h: th, theta_d: td, phi_d: pd };
            let (wi, wo) = hd.to_dirs();
            let b = HalfDiff::from_dirs(rotate_z(wi, rot), rotate_z(wo, rot)).unwrap();
            prop_assert!(close(b.theta_h, th, 1e-9) && close(b.theta_d, td, 1e-9));
        }
    }
}
