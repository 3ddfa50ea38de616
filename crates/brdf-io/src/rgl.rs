//! Evaluation of isotropic RGL `.bsdf` files (Dupuy & Jakob 2018, "An adaptive parameterization
//! for efficient material acquisition and rendering").
//!
//! The evaluator reproduces Mitsuba 3's `measured` plugin (`src/bsdfs/measured.cpp` with the
//! `Marginal2D<Float, N, true>` interpolants of `include/mitsuba/core/distr_2d.h`) in f64 and
//! divides its result by cos(theta_o): Mitsuba returns f cos(theta_o), specgp stores the BRDF f in
//! 1/sr (`DESIGN.md` section 2). Steps for a pair (wi, wo), both above the horizon:
//! 1. half vector m = normalize(wi + wo); elevations via the stable `2 asin(|d - z| / 2)`;
//! 2. u_m = (sqrt(2 theta_m / pi), (phi_m - phi_i + pi) / 2pi mod 1) (isotropic files measure phi_m
//!    relative to phi_i), u_i = (sqrt(2 theta_i / pi), (phi_i + pi) / 2pi);
//! 3. the VNDF warp, a continuous marginal/conditional 2D distribution conditioned on
//!    (phi_i, theta_i), is inverted at u_m, giving a point of the unit square;
//! 4. the `spectra` (or `rgb`) table is bilinearly interpolated at that point and linearly in
//!    (phi_i, theta_i, wavelength);
//! 5. when the `jacobian` flag is set the result is multiplied by ndf(u_m) / (4 sigma(u_i)).
//!
//! Anisotropic files (more than two `phi_i` samples, Mitsuba's test) are rejected as not supported
//! yet. A requested wavelength outside the stored range is an error.
//!
//! Beyond the structure Mitsuba checks, [`RglBsdf::open`] refuses values that would make
//! evaluation NaN or silently wrong: `theta_i` must run from 0 to pi/2 (every incidence then
//! falls between two stored slices; the 7 RGL files and [`write_rgl`] hold 0 to pi/2 rounded to
//! f32, at most 7.5e-8 rad off) and `phi_i` must lie within [-pi, pi] (the range of the azimuth
//! it is interpolated at; isotropic files hold `[0]`); `ndf`, `vndf` and `luminance` must be
//! finite and >= 0 (`ndf` not 0 everywhere when `jacobian` is set), `sigma` > 0, the value table
//! finite, and each `vndf` slice must integrate to a positive value. Rows of a `vndf` slice
//! without density (the 90-degree slice of each of the 7 RGL files has none on the half where
//! microfacets face away from wi) invert as a uniform row instead of 0/0 (Mitsuba's inversion
//! returns NaN there), so a file that opens never evaluates to NaN (directions at or below the
//! horizon give 0).
//!
//! [`write_rgl`] writes any [`BrdfSource`] (a stored or predicted material) as an isotropic file
//! that this evaluator, Mitsuba 3 and pbrt-v4 read (`rgl/write.rs`).

use std::f64::consts::{FRAC_PI_2, PI};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, ChannelSelection, Channels, Vec3, unit};
use crate::source::{
    BrdfSource, ImportReport, PairWeights, ResampleOptions, resample_cells, resample_cells_into,
};
use crate::tensor::{DType, TensorFile};

mod write;

pub use write::{
    ALBEDO_THETAS_DEG, BROAD_SHARE, CHECK_PAIRS, DEFAULT_TOLERANCE, MAX_EVAL_THETA_DEG,
    MIRROR_SHARE, RglWriteOptions, RglWriteSummary, rgl_fields, write_rgl, write_rgl_then,
};

/// Linear interpolation weights along one conditioning axis, as Mitsuba's
/// `Distribution2D::interpolate_weights`: the interval `[v[i], v[i+1]]` with `v[i] < p`
/// (i in `0..=n-2`, 0 when none) and the clamped fraction. Axes of length 1 give `(0, 0.0)`.
fn axis_weight(values: &[f64], p: f64) -> (usize, f64) {
    let n = values.len();
    if n < 2 {
        return (0, 0.0);
    }
    // First index in 1..n-1 whose value is not below p, minus one.
    let mut i = 1;
    while i < n - 1 && values[i] < p {
        i += 1;
    }
    let i = i - 1;
    let (p0, p1) = (values[i], values[i + 1]);
    let t = ((p - p0) / (p1 - p0)).clamp(0.0, 1.0);
    (i, if t.is_nan() { 0.0 } else { t })
}

/// Up to four (slice, weight) pairs for linear interpolation over (phi_i, theta_i).
#[derive(Debug, Clone, Copy)]
struct Corners {
    slice: [usize; 4],
    weight: [f64; 4],
}

impl Corners {
    /// `stride_phi` / `stride_theta` are slice strides (0 for an axis of length 1).
    fn new(phi: (usize, f64), theta: (usize, f64), stride_phi: usize, stride_theta: usize) -> Self {
        let base = phi.0 * stride_phi + theta.0 * stride_theta;
        let (tp, tt) = (phi.1, theta.1);
        Self {
            slice: [
                base,
                base + stride_theta,
                base + stride_phi,
                base + stride_phi + stride_theta,
            ],
            weight: [
                (1.0 - tp) * (1.0 - tt),
                (1.0 - tp) * tt,
                tp * (1.0 - tt),
                tp * tt,
            ],
        }
    }

    /// Weighted sum of `table[slice * slice_len + index]` over the corners.
    #[inline]
    fn lookup(&self, table: &[f64], slice_len: usize, index: usize) -> f64 {
        let mut acc = 0.0;
        for k in 0..4 {
            if self.weight[k] != 0.0 {
                acc += self.weight[k] * table[self.slice[k] * slice_len + index];
            }
        }
        acc
    }
}

/// Bilinear position in a `w x h` table over the unit square: offsets and fractions.
#[inline]
fn patch(pos: [f64; 2], w: usize, h: usize) -> ([usize; 2], [f64; 2]) {
    let x = pos[0].clamp(0.0, 1.0) * (w - 1) as f64;
    let y = pos[1].clamp(0.0, 1.0) * (h - 1) as f64;
    let ix = (x as usize).min(w - 2);
    let iy = (y as usize).min(h - 2);
    ([ix, iy], [x - ix as f64, y - iy as f64])
}

fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

/// An unconditioned 2D table (ndf, sigma) with bilinear interpolation (Mitsuba `Marginal2D0`,
/// no normalisation).
#[derive(Debug, Clone)]
struct Table2D {
    w: usize,
    h: usize,
    data: Vec<f64>,
}

impl Table2D {
    fn eval(&self, pos: [f64; 2]) -> f64 {
        let ([ix, iy], [fx, fy]) = patch(pos, self.w, self.h);
        let i = iy * self.w + ix;
        let d = &self.data;
        lerp(
            lerp(d[i], d[i + 1], fx),
            lerp(d[i + self.w], d[i + self.w + 1], fx),
            fy,
        )
    }
}

/// The VNDF warp: a continuous marginal/conditional 2D distribution per (phi_i, theta_i) slice
/// (Mitsuba `Marginal2D<Float, 2, true>` with normalisation), inverted for evaluation.
#[derive(Debug, Clone)]
struct Warp {
    w: usize,
    h: usize,
    /// Normalised density, `slices * w * h`.
    data: Vec<f64>,
    /// Conditional CDFs along x, `slices * h * (w - 1)`.
    cond: Vec<f64>,
    /// Marginal CDF along y, `slices * (h - 1)`.
    marg: Vec<f64>,
}

impl Warp {
    fn new(raw: &[f64], slices: usize, w: usize, h: usize, path: &Path) -> Result<Self> {
        let n_data = w * h;
        let (n_cond, n_marg) = ((w - 1) * h, h - 1);
        let (sx, sy) = (0.5 / (w - 1) as f64, 0.5 / (h - 1) as f64);
        let mut data = Vec::with_capacity(slices * n_data);
        let mut cond = Vec::with_capacity(slices * n_cond);
        let mut marg = Vec::with_capacity(slices * n_marg);
        let mut row_sum = vec![0.0; h];
        for s in 0..slices {
            let d = &raw[s * n_data..(s + 1) * n_data];
            let c0 = cond.len();
            for y in 0..h {
                let mut acc = 0.0;
                for x in 0..w - 1 {
                    acc += sx * (d[y * w + x] + d[y * w + x + 1]);
                    cond.push(acc);
                }
                row_sum[y] = acc;
            }
            let m0 = marg.len();
            let mut acc = 0.0;
            for y in 0..h - 1 {
                acc += sy * (row_sum[y] + row_sum[y + 1]);
                marg.push(acc);
            }
            if !(acc > 0.0 && acc.is_finite()) {
                return Err(Error::Format {
                    path: path.to_path_buf(),
                    reason: format!(
                        "field \"vndf\": slice {s} integrates to {acc}, not a positive density"
                    ),
                });
            }
            let norm = 1.0 / acc;
            cond[c0..].iter_mut().for_each(|v| *v *= norm);
            marg[m0..].iter_mut().for_each(|v| *v *= norm);
            data.extend(d.iter().map(|v| v * norm));
        }
        Ok(Self {
            w,
            h,
            data,
            cond,
            marg,
        })
    }

    /// Inverse of the warp (Mitsuba `Marginal2D::invert_continuous`): the unit-square sample
    /// that the warp maps to `u`.
    fn invert(&self, u: [f64; 2], c: &Corners) -> [f64; 2] {
        let (w, h) = (self.w, self.h);
        let ([px, py], [sx, sy]) = patch(u, w, h);
        let (n_data, n_cond, n_marg) = (w * h, (w - 1) * h, h - 1);
        let i = py * w + px;
        let v00 = c.lookup(&self.data, n_data, i);
        let v10 = c.lookup(&self.data, n_data, i + 1);
        let v01 = c.lookup(&self.data, n_data, i + w);
        let v11 = c.lookup(&self.data, n_data, i + w + 1);
        let c0 = lerp(v00, v01, sy);
        let c1 = lerp(v10, v11, sy);
        let mut x = sx * lerp(c0, c1, 0.5 * sx) / (w - 1) as f64;
        let row = py * (w - 1);
        if px > 0 {
            let a = c.lookup(&self.cond, n_cond, row + px - 1);
            let b = c.lookup(&self.cond, n_cond, row + px - 1 + (w - 1));
            x += lerp(a, b, sy);
        }
        let r0 = c.lookup(&self.cond, n_cond, row + (w - 1) - 1);
        let r1 = c.lookup(&self.cond, n_cond, row + 2 * (w - 1) - 1);
        let row_mass = lerp(r0, r1, sy);
        // A pair of rows without density (the 90-degree slice of the 7 RGL files has none on
        // the half of the square facing away from wi) is never reached by the warp, and x would be
        // 0/0 here (Mitsuba's `invert_continuous` then returns NaN): take it as a uniform row.
        // Densities are >= 0 (checked at open), so a positive mass bounds x by about 1.
        x = if row_mass > 0.0 { x / row_mass } else { u[0] };
        let mut y = sy * lerp(r0, r1, 0.5 * sy) / (h - 1) as f64;
        if py > 0 {
            y += c.lookup(&self.marg, n_marg, py - 1);
        }
        [x, y]
    }

    /// The `u.y` whose row [`Warp::invert`] maps to `s_y`: the smallest `u.y` at which the
    /// marginal part of `invert` (which depends on `u.y` only) reaches `s_y`, in closed form
    /// (a binary search of the marginal CDF, then the quadratic of its cell).
    fn forward_y(&self, s_y: f64, c: &Corners) -> f64 {
        let (w, h) = (self.w, self.h);
        let (n_cond, n_marg) = ((w - 1) * h, h - 1);
        let cell = first_reaching(h - 1, s_y, |k| c.lookup(&self.marg, n_marg, k));
        let Some(py) = cell else { return 1.0 };
        let base = if py > 0 {
            c.lookup(&self.marg, n_marg, py - 1)
        } else {
            0.0
        };
        let r0 = c.lookup(&self.cond, n_cond, py * (w - 1) + (w - 1) - 1);
        let r1 = c.lookup(&self.cond, n_cond, (py + 1) * (w - 1) + (w - 1) - 1);
        let sy = cell_root(r0, r1, (s_y - base) * (h - 1) as f64);
        (py as f64 + sy) / (h - 1) as f64
    }

    /// The `u.x` that [`Warp::invert`] maps to `s_x` on the row of `u_y` (the conditional part:
    /// the smallest such `u.x`, in closed form as [`Warp::forward_y`]); rows without density,
    /// which `invert` leaves as they are, give `s_x` back.
    fn forward_x(&self, s_x: f64, u_y: f64, c: &Corners) -> f64 {
        let (w, h) = (self.w, self.h);
        let ([_, py], [_, sy]) = patch([0.0, u_y], w, h);
        let (n_data, n_cond) = (w * h, (w - 1) * h);
        let row = py * (w - 1);
        let cdf = |k: usize| {
            lerp(
                c.lookup(&self.cond, n_cond, row + k),
                c.lookup(&self.cond, n_cond, row + k + (w - 1)),
                sy,
            )
        };
        let row_mass = cdf(w - 2);
        if row_mass.is_nan() || row_mass <= 0.0 {
            return s_x;
        }
        let target = s_x * row_mass;
        let Some(px) = first_reaching(w - 1, target, cdf) else {
            return 1.0;
        };
        let base = if px > 0 { cdf(px - 1) } else { 0.0 };
        let i = py * w + px;
        let density = |i: usize| {
            lerp(
                c.lookup(&self.data, n_data, i),
                c.lookup(&self.data, n_data, i + w),
                sy,
            )
        };
        let sx = cell_root(density(i), density(i + 1), (target - base) * (w - 1) as f64);
        (px as f64 + sx) / (w - 1) as f64
    }
}

/// The first of the `cells` cumulative values `cdf(0..cells)` (non-decreasing) that reaches
/// `target`, by binary search; `None` when even the last one falls short.
fn first_reaching(cells: usize, target: f64, cdf: impl Fn(usize) -> f64) -> Option<usize> {
    let (mut lo, mut hi) = (0, cells);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if cdf(mid) < target {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    (lo < cells).then_some(lo)
}

/// The smallest `s` in [0, 1] with `s (d0 + s (d1 - d0) / 2) = mass`: where the integral of a
/// density rising linearly from `d0` to `d1` (>= 0) across a cell reaches `mass` (in units of
/// the cell's width). The root in the form without cancellation, `2 mass / (d0 + sqrt(d0^2 +
/// 2 (d1 - d0) mass))`, holds for a flat density (`d1 = d0`) too.
fn cell_root(d0: f64, d1: f64, mass: f64) -> f64 {
    if mass.is_nan() || mass <= 0.0 {
        return 0.0;
    }
    let disc = (d0 * d0 + 2.0 * (d1 - d0) * mass).max(0.0);
    let denom = d0 + disc.sqrt();
    if denom.is_nan() || denom <= 0.0 {
        return 0.0;
    }
    (2.0 * mass / denom).clamp(0.0, 1.0)
}

/// An isotropic RGL `.bsdf` file (spectral `*_spec.bsdf` or RGB `*_rgb.bsdf`), ready to evaluate.
///
/// `RglBsdf` is `Sync`: evaluate from many threads at once.
#[derive(Debug, Clone)]
pub struct RglBsdf {
    path: PathBuf,
    description: String,
    native: Channels,
    selection: ChannelSelection,
    jacobian: bool,
    phi_i: Vec<f64>,
    theta_i: Vec<f64>,
    ndf: Table2D,
    sigma: Table2D,
    vndf: Warp,
    /// `spectra`/`rgb` values, `[phi_i][theta_i][channel][h][w]`.
    spectra: Vec<f32>,
    /// Stored channels.
    n_ch: usize,
    /// Resolution (w, h) of the spectra table.
    spec_w: usize,
    spec_h: usize,
}

/// Checks that every value of field `name` is finite and passes `ok` (`rule` says what it
/// requires): the first offender is an error naming the file, the field and the index.
fn check_values<T: Copy + Into<f64>>(
    path: &Path,
    name: &str,
    values: &[T],
    ok: impl Fn(f64) -> bool,
    rule: &str,
) -> Result<()> {
    match values
        .iter()
        .map(|&v| v.into())
        .enumerate()
        .find(|&(_, v)| !(v.is_finite() && ok(v)))
    {
        Some((i, v)) => Err(Error::Format {
            path: path.to_path_buf(),
            reason: format!(
                "field \"{name}\" must be {rule}; value {i} of {} is {v}",
                values.len()
            ),
        }),
        None => Ok(()),
    }
}

fn shape_error(path: &Path, reason: String) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        reason: format!("invalid RGL BSDF structure: {reason}"),
    }
}

/// Checks a field's dtype and rank and returns its shape.
fn expect<'a>(tf: &'a TensorFile, name: &str, dtype: DType, rank: usize) -> Result<&'a [usize]> {
    let f = tf.field(name)?;
    if f.dtype() != dtype || f.shape().len() != rank {
        return Err(shape_error(
            tf.path(),
            format!(
                "field {name:?} is {:?} with shape {:?}, expected {dtype:?} of rank {rank}",
                f.dtype(),
                f.shape()
            ),
        ));
    }
    Ok(f.shape())
}

/// Slack of the incident-angle checks (radians): f32 rounding of pi/2 lands 4.4e-8 above it
/// (the nearest f32) or 7.5e-8 below it (the 7 RGL files hold both), and a few ulps of the
/// arithmetic that produced the angles. 1e-6 rad is 6e-5 degrees.
const ANGLE_SLACK: f64 = 1e-6;

/// Checks the incident-angle axes: each strictly increasing, `phi_i` within [-pi, pi] (the range
/// of `atan2`, the azimuth it is interpolated at) and `theta_i` within [0, pi/2], starting at 0
/// and ending at pi/2 (evaluation clamps to the stored range, so an axis that stops short
/// would give every incidence beyond it the nearest stored slice, silently wrong; one that
/// runs past it would put slices where no incidence can reach them).
fn check_incident_axes(path: &Path, phi_i: &[f64], theta_i: &[f64]) -> Result<()> {
    for (name, v) in [("phi_i", phi_i), ("theta_i", theta_i)] {
        if let Some(k) = v.windows(2).position(|w| w[1] <= w[0]) {
            return Err(Error::Format {
                path: path.to_path_buf(),
                reason: format!(
                    "field \"{name}\" must be strictly increasing; value {} of {} is {} after {}",
                    k + 1,
                    v.len(),
                    v[k + 1],
                    v[k]
                ),
            });
        }
    }
    let lim = PI + ANGLE_SLACK;
    check_values(
        path,
        "phi_i",
        phi_i,
        |v| (-lim..=lim).contains(&v),
        "within [-pi, pi] radians",
    )?;
    let lim = FRAC_PI_2 + ANGLE_SLACK;
    check_values(
        path,
        "theta_i",
        theta_i,
        |v| (-ANGLE_SLACK..=lim).contains(&v),
        "within [0, pi/2] radians (0 to 90 degrees)",
    )?;
    let (first, last) = (theta_i[0], theta_i[theta_i.len() - 1]);
    if first > ANGLE_SLACK || last < FRAC_PI_2 - ANGLE_SLACK {
        return Err(Error::Format {
            path: path.to_path_buf(),
            reason: format!(
                "field \"theta_i\" must run from 0 to pi/2 radians (0 to 90 degrees), it holds \
                 {} values from {first} to {last} ({:.4} to {:.4} degrees): incidences outside \
                 would take the nearest stored slice",
                theta_i.len(),
                first.to_degrees(),
                last.to_degrees()
            ),
        });
    }
    Ok(())
}

impl RglBsdf {
    /// Reads and validates an RGL `.bsdf` file. Anisotropic files are rejected (not supported
    /// yet); every structural problem is an error naming the file and the field.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let tf = TensorFile::open(path)?;
        Self::from_tensor_file(&tf)
    }

    /// Builds the evaluator from a parsed tensor file.
    pub fn from_tensor_file(tf: &TensorFile) -> Result<Self> {
        let path = tf.path();
        let bad = |reason: String| shape_error(path, reason);
        expect(tf, "description", DType::U8, 1)?;
        let n_theta = expect(tf, "theta_i", DType::F32, 1)?[0];
        let n_phi = expect(tf, "phi_i", DType::F32, 1)?[0];
        let ndf_s = expect(tf, "ndf", DType::F32, 2)?.to_vec();
        let sigma_s = expect(tf, "sigma", DType::F32, 2)?.to_vec();
        let vndf_s = expect(tf, "vndf", DType::F32, 4)?.to_vec();
        let lum_s = expect(tf, "luminance", DType::F32, 4)?.to_vec();
        let jac_s = expect(tf, "jacobian", DType::U8, 1)?;
        if jac_s != [1] {
            return Err(bad(format!(
                "field \"jacobian\" has shape {jac_s:?}, expected [1]"
            )));
        }
        let spectral = tf.get("wavelengths").is_some();
        let (spec_name, wavelengths) = if spectral {
            expect(tf, "wavelengths", DType::F32, 1)?;
            ("spectra", Some(tf.field_f64("wavelengths")?))
        } else {
            if tf.get("rgb").is_none() && tf.get("spectra").is_some() {
                return Err(bad(
                    "a spectral file (field \"spectra\") without its field \"wavelengths\"".into(),
                ));
            }
            ("rgb", None)
        };
        let spec_s = expect(tf, spec_name, DType::F32, 5)?.to_vec();
        let n_ch = wavelengths.as_ref().map_or(3, Vec::len);
        if n_phi == 0 || n_theta == 0 {
            return Err(bad("empty phi_i or theta_i".into()));
        }
        if vndf_s[..2] != [n_phi, n_theta]
            || lum_s[..2] != [n_phi, n_theta]
            || spec_s[..3] != [n_phi, n_theta, n_ch]
        {
            return Err(bad(format!(
                "vndf {vndf_s:?}, luminance {lum_s:?} and {spec_name} {spec_s:?} do not start \
                 with (phi_i, theta_i) = ({n_phi}, {n_theta}) (and {n_ch} channels)"
            )));
        }
        if spec_s[3] != spec_s[4] || lum_s[2..] != spec_s[3..] || lum_s[2] != lum_s[3] {
            return Err(bad(format!(
                "{spec_name} {spec_s:?} and luminance {lum_s:?} need equal square tables"
            )));
        }
        for (name, s) in [
            ("ndf", &ndf_s),
            ("sigma", &sigma_s),
            ("vndf", &vndf_s[2..].to_vec()),
        ] {
            if s[0] < 2 || s[1] < 2 {
                return Err(bad(format!(
                    "field {name:?}: table {s:?} is smaller than 2 x 2"
                )));
            }
        }
        if spec_s[3] < 2 {
            return Err(bad(format!(
                "field {spec_name:?}: table {spec_s:?} is smaller than 2 x 2"
            )));
        }
        if n_phi > 2 {
            return Err(Error::Unsupported {
                path: path.to_path_buf(),
                feature: format!(
                    "anisotropic RGL BSDF ({n_phi} phi_i samples; only isotropic files with at \
                     most 2 are supported)"
                ),
            });
        }
        let phi_i = tf.field_f64("phi_i")?;
        let theta_i = tf.field_f64("theta_i")?;
        check_incident_axes(path, &phi_i, &theta_i)?;
        let native = match wavelengths {
            Some(w) => Channels::spectral(w).map_err(|e| {
                bad(format!(
                    "field \"wavelengths\" is not a valid channel axis: {e}"
                ))
            })?,
            None => Channels::Rgb,
        };
        let jacobian = tf.field("jacobian")?.bytes()[0] != 0;
        let description = tf.field("description")?.to_text().unwrap_or_default();
        let ndf = Table2D {
            w: ndf_s[1],
            h: ndf_s[0],
            data: tf.field_f64("ndf")?,
        };
        let sigma = Table2D {
            w: sigma_s[1],
            h: sigma_s[0],
            data: tf.field_f64("sigma")?,
        };
        let vndf_raw = tf.field_f64("vndf")?;
        // A density: negative values would make its CDFs decrease and the inverse garbage.
        check_values(path, "vndf", &vndf_raw, |v| v >= 0.0, "finite and >= 0")?;
        let vndf = Warp::new(&vndf_raw, n_phi * n_theta, vndf_s[3], vndf_s[2], path)?;
        // Not used by evaluation, but a renderer samples with it (a sampling density).
        let luminance = tf.field_f64("luminance")?;
        check_values(
            path,
            "luminance",
            &luminance,
            |v| v >= 0.0,
            "finite and >= 0",
        )?;
        let spectra = tf.field_f32(spec_name)?;
        check_values(path, "ndf", &ndf.data, |v| v >= 0.0, "finite and >= 0")?;
        if jacobian && !ndf.data.iter().any(|&v| v > 0.0) {
            return Err(Error::Format {
                path: path.to_path_buf(),
                reason: "field \"ndf\" is 0 everywhere (every value of the file would be 0); a \
                         microfacet distribution must be positive somewhere"
                    .into(),
            });
        }
        // sigma divides every value: zero or negative would give infinite or negative BRDFs.
        check_values(path, "sigma", &sigma.data, |v| v > 0.0, "finite and > 0")?;
        let selection = ChannelSelection::all(&native);
        Ok(Self {
            path: path.to_path_buf(),
            description,
            native,
            selection,
            jacobian,
            phi_i,
            theta_i,
            ndf,
            sigma,
            vndf,
            spectra,
            n_ch,
            spec_w: spec_s[4],
            spec_h: spec_s[3],
        })
    }

    /// The file this BSDF was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The file's `description` text.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// The incident elevations (`theta_i`, radians) the file tabulates.
    pub fn theta_i(&self) -> &[f64] {
        &self.theta_i
    }

    /// Width and height of the value tables (`spectra` or `rgb`) per incident elevation.
    pub fn table_size(&self) -> (usize, usize) {
        (self.spec_w, self.spec_h)
    }

    /// Width and height of the VNDF warp tables.
    pub fn warp_size(&self) -> (usize, usize) {
        (self.vndf.w, self.vndf.h)
    }

    /// Whether values are stored divided by the microfacet term (field `jacobian`).
    pub fn jacobian(&self) -> bool {
        self.jacobian
    }

    /// The channels stored in the file (its wavelengths, or R, G, B).
    pub fn native_channels(&self) -> &Channels {
        &self.native
    }

    /// The channels [`RglBsdf::eval`] writes (the stored ones unless changed with
    /// [`RglBsdf::with_channels`]).
    pub fn channels(&self) -> Channels {
        self.selection.channels.clone()
    }

    /// The same BSDF evaluated at other channels: wavelengths inside the stored range for a
    /// spectral file (linear interpolation between stored wavelengths, as Mitsuba), R,G,B for an
    /// RGB file.
    pub fn with_channels(mut self, channels: &Channels) -> Result<Self> {
        self.selection = ChannelSelection::new(&self.path, &self.native, channels)?;
        Ok(self)
    }

    /// f(wi, wo) in 1/sr for every selected channel, written to `out`.
    pub fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        self.eval_selection(&self.selection, wi, wo, out)
    }

    fn eval_selection(
        &self,
        sel: &ChannelSelection,
        wi: Vec3,
        wo: Vec3,
        out: &mut [f64],
    ) -> Result<()> {
        crate::source::check_output_len(out, sel.taps().len())?;
        let (Some(wi), Some(wo)) = (unit(wi), unit(wo)) else {
            return Err(Error::InvalidArgument {
                reason: format!("directions must be finite and non-zero, got {wi:?}, {wo:?}"),
            });
        };
        out.iter_mut().for_each(|v| *v = 0.0);
        if !(wi[2] > 0.0 && wo[2] > 0.0) {
            return Ok(());
        }
        let Some(m) = unit([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]) else {
            return Ok(());
        };
        let theta_i = elevation(wi);
        let phi_i = wi[1].atan2(wi[0]);
        let theta_m = elevation(m);
        let phi_m = m[1].atan2(m[0]);
        let u_wi = [theta2u(theta_i), phi2u(phi_i)];
        let mut u_m = [theta2u(theta_m), phi2u(phi_m - phi_i)];
        u_m[1] -= u_m[1].floor();

        let wp = axis_weight(&self.phi_i, phi_i);
        let wt = axis_weight(&self.theta_i, theta_i);
        let (n_phi, n_theta) = (self.phi_i.len(), self.theta_i.len());
        let vndf_corners = Corners::new(
            wp,
            wt,
            if n_phi > 1 { n_theta } else { 0 },
            if n_theta > 1 { 1 } else { 0 },
        );
        let sample = self.vndf.invert(u_m, &vndf_corners);

        let scale = if self.jacobian {
            self.ndf.eval(u_m) / (4.0 * self.sigma.eval(u_wi))
        } else {
            1.0
        };
        // The spectra table: slices [phi][theta][channel], each spec_h x spec_w.
        let (w, h) = (self.spec_w, self.spec_h);
        let ([ix, iy], [fx, fy]) = patch(sample, w, h);
        let n_slice = w * h;
        let i0 = iy * w + ix;
        let spec_corners = Corners::new(
            wp,
            wt,
            if n_phi > 1 { n_theta * self.n_ch } else { 0 },
            if n_theta > 1 { self.n_ch } else { 0 },
        );
        let bilerp = |slice: usize| -> f64 {
            let d = &self.spectra[slice * n_slice..(slice + 1) * n_slice];
            let v = |k: usize| f64::from(d[k]);
            lerp(
                lerp(v(i0), v(i0 + 1), fx),
                lerp(v(i0 + w), v(i0 + w + 1), fx),
                fy,
            )
        };
        for (o, &(k0, k1, t)) in out.iter_mut().zip(sel.taps()) {
            let mut acc = 0.0;
            for c in 0..4 {
                let wgt = spec_corners.weight[c];
                if wgt == 0.0 {
                    continue;
                }
                let base = spec_corners.slice[c];
                let mut v = bilerp(base + k0);
                if t != 0.0 {
                    v = lerp(v, bilerp(base + k1), t);
                }
                acc += wgt * v;
            }
            // RGB tables dip slightly below zero where the measured spectrum is out of gamut.
            // Mitsuba 3's `measured` (DESIGN.md's reference, and the test tables) keeps those
            // values; rgl-epfl/brdf-loader's `powitacq_rgb` clamps them at 0. `resample`
            // clamps (and counts) them.
            // Divided last: 1 / cos(theta_o) overflows for a subnormal wo[2], and a 0 value
            // times that infinity was NaN (the 7 RGL files have such zeros at wo.z = 1e-320);
            // a non-zero value over such a wo[2] is still +-inf.
            *o = acc * scale / wo[2];
        }
        Ok(())
    }

    /// Evaluates the file at every bin centre of `grid` (directions from
    /// [`crate::HalfDiff::to_dirs`]) for `channels`, in parallel, with the default
    /// [`ResampleOptions`]: each cell stores the reciprocal mean of the two direction orders,
    /// each weighted by the square of the cosine it divides by,
    /// `(c_o^2 f(wi, wo) + c_i^2 f(wo, wi)) / (c_o^2 + c_i^2)` (the non-reciprocal part is
    /// measured in the report). Values are in dataset order
    /// (`angular_index * n_channels + channel`, MERL's angular order); cells below the horizon
    /// are 0.0; a negative mean (Mitsuba's RGB tables dip slightly below zero) is clamped to 0
    /// and counted in the report; values above
    /// [`crate::source::DEFAULT_OUTLIER_THRESHOLD`] are counted, not clamped (see
    /// [`RglBsdf::resample_with`]). Such values occur at grazing bin centres, where Mitsuba's
    /// f cos(theta_o) does not vanish as fast as cos(theta_o).
    pub fn resample(
        &self,
        grid: &AngularGrid,
        channels: &Channels,
    ) -> Result<(Vec<f32>, ImportReport)> {
        self.resample_with(grid, channels, ResampleOptions::default())
    }

    /// As [`RglBsdf::resample`] with explicit outlier handling.
    pub fn resample_with(
        &self,
        grid: &AngularGrid,
        channels: &Channels,
        options: ResampleOptions,
    ) -> Result<(Vec<f32>, ImportReport)> {
        let sel = ChannelSelection::new(&self.path, &self.native, channels)?;
        let n = sel.taps().len();
        let (values, report) = resample_cells(
            grid,
            n,
            options,
            PairWeights::CosOutgoingSquared,
            |wi, wo, out| self.eval_selection(&sel, wi, wo, out),
        )?;
        tracing::info!(file = %self.path.display(), %grid, "resampled RGL BSDF: {report}");
        Ok((values, report))
    }
}

impl RglBsdf {
    /// Block-wise resampling for streaming writers: evaluates the cells
    /// `first_cell..first_cell + out.len() / channels.len()` of `grid` (flat angular indices) into
    /// `out`, in dataset order, with the same rules as [`RglBsdf::resample_with`]. Lets a
    /// spectral import on a large grid work one block at a time instead of holding the whole
    /// material (1.1 GB in f32 for 195 wavelengths on the MERL grid).
    pub fn resample_block(
        &self,
        grid: &AngularGrid,
        channels: &Channels,
        options: ResampleOptions,
        first_cell: usize,
        out: &mut [f32],
    ) -> Result<ImportReport> {
        let sel = ChannelSelection::new(&self.path, &self.native, channels)?;
        resample_cells_into(
            grid,
            first_cell,
            out,
            sel.taps().len(),
            options,
            PairWeights::CosOutgoingSquared,
            |wi, wo, o| self.eval_selection(&sel, wi, wo, o),
        )
    }
}

impl BrdfSource for RglBsdf {
    fn channels(&self) -> Channels {
        RglBsdf::channels(self)
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        RglBsdf::eval(self, wi, wo, out)
    }
}

/// Elevation of a unit vector, stable near the pole: `2 asin(|d - (0,0,1)| / 2)`.
fn elevation(d: Vec3) -> f64 {
    let dist = (d[0] * d[0] + d[1] * d[1] + (d[2] - 1.0) * (d[2] - 1.0)).sqrt();
    2.0 * (0.5 * dist).clamp(-1.0, 1.0).asin()
}

fn theta2u(theta: f64) -> f64 {
    (theta * (2.0 / PI)).max(0.0).sqrt()
}

fn phi2u(phi: f64) -> f64 {
    (phi + PI) / (2.0 * PI)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tensor::Field;

    #[test]
    fn axis_weight_matches_mitsuba_find_interval() {
        let v = [0.0, 1.0, 2.0, 4.0];
        assert_eq!(axis_weight(&v, -1.0), (0, 0.0));
        assert_eq!(axis_weight(&v, 0.5), (0, 0.5));
        assert_eq!(axis_weight(&v, 1.0), (0, 1.0));
        assert_eq!(axis_weight(&v, 3.0), (2, 0.5));
        assert_eq!(axis_weight(&v, 9.0), (2, 1.0));
        assert_eq!(axis_weight(&[3.0], 9.0), (0, 0.0));
        // Two values (a file with two phi_i samples) are one interval, not a single value.
        assert_eq!(axis_weight(&[-1.0, 1.0], 0.5), (0, 0.75));
        assert_eq!(axis_weight(&[-1.0, 1.0], 2.0), (0, 1.0));
    }

    #[test]
    fn warp_inverse_of_uniform_density_is_identity() {
        // A constant density warps nothing: invert(u) = u.
        let raw = vec![1.0; 5 * 4];
        let warp = Warp::new(&raw, 1, 5, 4, Path::new("t")).unwrap();
        let c = Corners::new((0, 0.0), (0, 0.0), 0, 0);
        for u in [[0.1, 0.2], [0.5, 0.5], [0.99, 0.01], [1.0, 1.0], [0.0, 0.0]] {
            let s = warp.invert(u, &c);
            assert!(
                (s[0] - u[0]).abs() < 1e-12 && (s[1] - u[1]).abs() < 1e-12,
                "{s:?}"
            );
        }
    }

    #[test]
    fn warp_inverse_in_rows_without_density_is_uniform() {
        // 3 x 3 density, rows 0 and 1 empty: a point in the patch between them would be 0/0.
        let raw = vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 1.0];
        let warp = Warp::new(&raw, 1, 3, 3, Path::new("t")).unwrap();
        let c = Corners::new((0, 0.0), (0, 0.0), 0, 0);
        for x in [0.0, 0.3, 0.5, 0.9, 1.0] {
            let s = warp.invert([x, 0.25], &c);
            // All the mass sits in the upper patch: y is 0 below it.
            assert_eq!(s, [x, 0.0]);
        }
        // The patch between rows 1 and 2 still inverts its density: on row 2 the x CDF of
        // 1, 2, 1 is 0.5 at the middle.
        let s = warp.invert([0.5, 1.0], &c);
        assert!(
            (s[0] - 0.5).abs() < 1e-12 && (s[1] - 1.0).abs() < 1e-12,
            "{s:?}"
        );
    }

    /// The smallest `u` in [0, 1] with `at(u) >= target`, by bisection: the reference for the
    /// closed-form forward warp.
    fn bisect(target: f64, at: impl Fn(f64) -> f64) -> f64 {
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if at(mid) < target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// `first_reaching` gives the first cell whose cumulative value reaches the target (on
    /// plateaus too) and `None` when none does: against a linear scan.
    #[test]
    fn first_reaching_matches_a_scan() {
        let cdf = [0.0, 0.5, 0.5, 0.5, 1.0, 2.0, 2.0];
        for cells in 0..=cdf.len() {
            for k in 0..=50 {
                let target = k as f64 / 20.0 - 0.25;
                let want = (0..cells).find(|&i| cdf[i] >= target);
                assert_eq!(
                    first_reaching(cells, target, |i| cdf[i]),
                    want,
                    "{cells} cells, target {target}"
                );
            }
        }
    }

    /// `cell_root` is where the integral of a linear density across a cell reaches the mass
    /// (bisection of `s (d0 + s (d1 - d0) / 2)`), 0 without mass (or NaN, or without density)
    /// and 1 past the cell's.
    #[test]
    fn cell_root_matches_bisection() {
        for d0 in [0.0, 0.25, 1.0, 3.0] {
            for d1 in [0.0, 0.5, 1.0, 4.0] {
                let cell = 0.5 * (d0 + d1);
                // Short of the cell's mass: at the full mass a density falling to 0 has a double
                // root, which bisection finds only to about 1e-8.
                for k in 1..20 {
                    let mass = cell * k as f64 / 20.0;
                    let want = bisect(mass, |s| s * (d0 + s * (d1 - d0) / 2.0));
                    let s = cell_root(d0, d1, mass);
                    assert!((s - want).abs() < 1e-12, "{d0} {d1} {mass}: {s} vs {want}");
                }
                for mass in [0.0, -0.5, f64::NAN] {
                    assert_eq!(cell_root(d0, d1, mass), 0.0, "{d0} {d1} {mass}");
                }
                if cell > 0.0 {
                    assert!((cell_root(d0, d1, cell) - 1.0).abs() < 1e-12, "{d0} {d1}");
                    assert_eq!(cell_root(d0, d1, 2.0 * cell), 1.0, "{d0} {d1}");
                } else {
                    // No density: no mass is ever reached, and 2 mass / 0 must not give 1.
                    assert_eq!(cell_root(d0, d1, 0.5), 0.0);
                }
            }
        }
    }

    #[test]
    fn forward_warp_inverts_invert_and_matches_bisection() {
        check_forward_warp(7, 6);
        // 4 cells per row: the binary search of a row's CDF must stop at its last cell (a
        // search over one cell more reads the next row there and gave 1 for s.x near 1).
        check_forward_warp(5, 4);
    }

    /// Seeded uniform numbers in [0, 1) (a 64-bit LCG's top 53 bits).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// `forward_y` / `forward_x` on random `w` x `h` tables against bisection of `invert`.
    fn check_forward_warp(w: usize, h: usize) {
        // Random densities on 3 x 2 slices, with empty cells, an empty row pair and an
        // all-empty slice's neighbour, blended between slices as lookups blend them.
        let slices = 6;
        let mut next = uniform(0x9e37_79b9_7f4a_7c15);
        let mut raw: Vec<f64> = (0..slices * w * h)
            .map(|_| {
                let v = next();
                if v < 0.25 {
                    0.0
                } else {
                    10f64.powf(4.0 * v - 2.0)
                }
            })
            .collect();
        // Slice 1: rows 0-2 empty (no density between them: `invert` keeps x there).
        raw[w * h..w * h + 3 * w].iter_mut().for_each(|v| *v = 0.0);
        let warp = Warp::new(&raw, slices, w, h, Path::new("t")).unwrap();
        let corners = [
            Corners::new((0, 0.0), (0, 0.0), 0, 1),
            Corners::new((0, 0.0), (1, 0.0), 0, 1),
            Corners::new((0, 0.0), (1, 0.3), 0, 1),
            Corners::new((0, 0.7), (1, 0.4), 3, 1),
        ];
        let (mut checked, mut exact) = (0, 0);
        for c in &corners {
            for iy in 0..=40 {
                let s_y = iy as f64 / 40.0;
                let u_y = warp.forward_y(s_y, c);
                let want_y = bisect(s_y, |y| warp.invert([0.5, y], c)[1]);
                let back_y = warp.invert([0.5, u_y], c)[1];
                assert!(
                    (back_y - s_y).abs() < 1e-13,
                    "s.y {s_y} -> {u_y} -> {back_y}"
                );
                // The same point as the bisection, or another preimage of s.y: where the
                // density vanishes the CDF is flat to rounding over a stretch.
                let flat = (warp.invert([0.5, want_y], c)[1] - s_y).abs() < 1e-13;
                assert!(
                    (u_y - want_y).abs() < 1e-12 || flat,
                    "u.y {u_y} vs bisection {want_y}"
                );
                for ix in 0..=40 {
                    let s_x = ix as f64 / 40.0;
                    let u_x = warp.forward_x(s_x, u_y, c);
                    let want_x = bisect(s_x, |x| warp.invert([x, u_y], c)[0]);
                    let flat = (warp.invert([want_x, u_y], c)[0] - s_x).abs() < 1e-13;
                    assert!(
                        (u_x - want_x).abs() < 1e-12 || flat,
                        "u.x {u_x} vs bisection {want_x} (s {s_x}, {s_y})"
                    );
                    exact += usize::from((u_x - want_x).abs() < 1e-12);
                    let back = warp.invert([u_x, u_y], c);
                    assert!(
                        (back[0] - s_x).abs() < 1e-13 && (back[1] - s_y).abs() < 1e-13,
                        "s ({s_x}, {s_y}) -> ({u_x}, {u_y}) -> {back:?}"
                    );
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 4 * 41 * 41);
        // Nearly every point is the bisection's to 1e-12; the rest sit on flat stretches.
        assert!(exact * 100 >= checked * 99, "{exact} of {checked}");
    }

    /// Slope of the `vndf` of incidence slice (`p`, `t`): density `1 + slope (x - 1/2)` along
    /// x (integral 1 per row), the same on every row.
    fn slope(p: usize, t: usize) -> f64 {
        0.25 * (p + 2 * t) as f64 - 0.75
    }

    /// `[a, b, c]` of the value table of slice (`p`, `t`), channel `ch`: `a + b x + c y`.
    fn plane(p: usize, t: usize, ch: usize) -> [f64; 3] {
        let (p, t, ch) = (p as f64, t as f64, ch as f64);
        [
            1.0 + p + 2.0 * t + 6.0 * ch,
            1.0 + 0.5 * p + 0.25 * t + 0.125 * ch,
            0.5 + 0.25 * p + 0.125 * t + 0.75 * ch,
        ]
    }

    /// An RGB file whose tables are linear, so that every step of the evaluation has a closed
    /// form: incidences `phi_i` x `theta_i`; per slice a `vndf` (2 x 3, rows x columns) with
    /// density `1 + slope(p, t) (x - 1/2)`, scaled by `1 + p + t` (normalisation removes it), and
    /// 3 x 3 rgb tables `plane(p, t, ch)`; ndf (2 x 3) `1 + x + 2y`, sigma (3 x 2)
    /// `2 + 3x + y`. Dyadic coefficients: the f32 tables hold them exactly.
    fn linear_file(phi_i: &[f32], theta_i: &[f32], jacobian: bool) -> RglBsdf {
        let (n_phi, n_theta) = (phi_i.len(), theta_i.len());
        let (mut vndf, mut rgb) = (Vec::new(), Vec::new());
        for p in 0..n_phi {
            for t in 0..n_theta {
                for _ in 0..2 {
                    for ix in 0..3 {
                        let x = ix as f64 / 2.0;
                        let d = (1 + p + t) as f64 * (1.0 + slope(p, t) * (x - 0.5));
                        vndf.push(d as f32);
                    }
                }
                for ch in 0..3 {
                    let [a, b, c] = plane(p, t, ch);
                    for iy in 0..3 {
                        for ix in 0..3 {
                            let v = a + b * ix as f64 / 2.0 + c * iy as f64 / 2.0;
                            rgb.push(v as f32);
                        }
                    }
                }
            }
        }
        let table = |h: usize, w: usize, f: &dyn Fn(f64, f64) -> f64| -> Vec<f32> {
            let at = |k: usize| {
                f(
                    (k % w) as f64 / (w - 1) as f64,
                    (k / w) as f64 / (h - 1) as f64,
                )
            };
            (0..h * w).map(|k| at(k) as f32).collect()
        };
        let fields = vec![
            Field::from_u8("description", vec![6], b"linear").unwrap(),
            Field::from_f32("phi_i", vec![n_phi], phi_i).unwrap(),
            Field::from_f32("theta_i", vec![n_theta], theta_i).unwrap(),
            Field::from_f32("ndf", vec![2, 3], &table(2, 3, &|x, y| 1.0 + x + 2.0 * y)).unwrap(),
            Field::from_f32("sigma", vec![3, 2], &table(3, 2, &|x, y| 2.0 + 3.0 * x + y)).unwrap(),
            Field::from_f32("vndf", vec![n_phi, n_theta, 2, 3], &vndf).unwrap(),
            Field::from_f32(
                "luminance",
                vec![n_phi, n_theta, 3, 3],
                &vec![1.0; n_phi * n_theta * 9],
            )
            .unwrap(),
            Field::from_f32("rgb", vec![n_phi, n_theta, 3, 3, 3], &rgb).unwrap(),
            Field::from_u8("jacobian", vec![1], &[u8::from(jacobian)]).unwrap(),
        ];
        RglBsdf::from_tensor_file(&TensorFile::from_fields(fields, "linear.bsdf")).unwrap()
    }

    /// Tent weights of the nodes of an increasing axis at `p` (clamped to its ends), by
    /// distance to the neighbours: the reference for the interval search of `axis_weight`.
    fn tent(axis: &[f64], p: f64) -> Vec<f64> {
        let n = axis.len();
        let p = p.clamp(axis[0], axis[n - 1]);
        (0..n)
            .map(|j| {
                let below = j > 0 && p <= axis[j] && p >= axis[j - 1];
                let above = j + 1 < n && p >= axis[j] && p < axis[j + 1];
                if n == 1 {
                    1.0
                } else if above {
                    (axis[j + 1] - p) / (axis[j + 1] - axis[j])
                } else if below {
                    (p - axis[j - 1]) / (axis[j] - axis[j - 1])
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// f(wi, wo) of a `linear_file`, by hand: the warp inverse of the blended density
    /// `1 + s (x - 1/2)` is its CDF `x + s (x^2 - x) / 2` at x = sqrt(2 theta_m / pi) and leaves
    /// y = (phi_m - phi_i + pi) / 2pi mod 1 as it is; the blended planes are read there; the
    /// jacobian scale is ndf(u_m) / (4 sigma(u_i)).
    fn linear_file_value(bsdf: &RglBsdf, wi: Vec3, wo: Vec3) -> [f64; 3] {
        let norm = |v: Vec3| {
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            [v[0] / n, v[1] / n, v[2] / n]
        };
        let (wi, wo) = (norm(wi), norm(wo));
        let m = norm([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]);
        let polar = |d: Vec3| d[0].hypot(d[1]).atan2(d[2]);
        let (theta_i, phi_i) = (polar(wi), wi[1].atan2(wi[0]));
        let (theta_m, phi_m) = (polar(m), m[1].atan2(m[0]));
        let x = (2.0 * theta_m / PI).sqrt();
        let y = (phi_m - phi_i + PI).rem_euclid(2.0 * PI) / (2.0 * PI);
        let wp = tent(&bsdf.phi_i, phi_i);
        let wt = tent(&bsdf.theta_i, theta_i);
        let mut s = 0.0;
        for (p, a) in wp.iter().enumerate() {
            for (t, b) in wt.iter().enumerate() {
                s += a * b * slope(p, t);
            }
        }
        let sx = x + s * (x * x - x) / 2.0;
        let scale = if bsdf.jacobian {
            let u_i = [(2.0 * theta_i / PI).sqrt(), (phi_i + PI) / (2.0 * PI)];
            (1.0 + x + 2.0 * y) / (4.0 * (2.0 + 3.0 * u_i[0] + u_i[1]))
        } else {
            1.0
        };
        let mut out = [0.0; 3];
        for (ch, o) in out.iter_mut().enumerate() {
            for (p, a) in wp.iter().enumerate() {
                for (t, b) in wt.iter().enumerate() {
                    let [pa, pb, pc] = plane(p, t, ch);
                    *o += a * b * (pa + pb * sx + pc * y);
                }
            }
            *o *= scale / wo[2];
        }
        out
    }

    /// Evaluation of files with linear tables matches the closed form: interpolation over one
    /// or two azimuths and three elevations of incidence, the half-vector coordinates, the warp
    /// inverse of blended densities, the bilinear value lookup, the jacobian scale and 1 / cos
    /// theta_o; 0 at and below the horizon.
    #[test]
    fn linear_tables_evaluate_to_their_closed_form() {
        let half_pi = std::f32::consts::FRAC_PI_2;
        let mut next = uniform(0x2545_f491_4f6c_dd1d);
        let mut dir = |max_theta: f64| {
            let (t, p) = (max_theta * next(), 2.0 * PI * next() - PI);
            [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
        };
        let mut checked = 0;
        for phi_i in [&[0.0f32][..], &[-half_pi, half_pi][..]] {
            for jacobian in [false, true] {
                let bsdf = linear_file(phi_i, &[0.0, 0.5, half_pi], jacobian);
                // What it reports: the vndf tables are 2 rows x 3 columns, rgb 3 x 3.
                assert_eq!(bsdf.jacobian(), jacobian);
                assert_eq!((bsdf.warp_size(), bsdf.table_size()), ((3, 2), (3, 3)));
                assert_eq!(bsdf.description(), "linear");
                let source: &dyn BrdfSource = &bsdf;
                let (mut out, mut via_source) = ([0.0; 3], [0.0; 3]);
                for _ in 0..400 {
                    let (wi, wo) = (dir(1.55), dir(1.55));
                    // Lengths other than 1: directions are normalised first.
                    let (wi2, wo2) = (wi.map(|v| 2.0 * v), wo.map(|v| 0.5 * v));
                    bsdf.eval(wi2, wo2, &mut out).unwrap();
                    source.eval(wi2, wo2, &mut via_source).unwrap();
                    assert_eq!(out, via_source);
                    let want = linear_file_value(&bsdf, wi, wo);
                    for c in 0..3 {
                        assert!(
                            (out[c] - want[c]).abs() <= 1e-10 * want[c].abs(),
                            "phi_i {phi_i:?}, jacobian {jacobian}, {wi:?} {wo:?}: {out:?} vs \
                             {want:?}"
                        );
                    }
                    checked += 1;
                    // At and below the horizon (either direction): 0.
                    let flat = [wo[0], wo[1], 0.0];
                    let below = [wo[0], wo[1], -wo[2]];
                    for (a, b) in [(wi, flat), (flat, wi), (wi, below), (below, wi)] {
                        bsdf.eval(a, b, &mut out).unwrap();
                        assert_eq!(out, [0.0; 3], "{a:?} {b:?}");
                    }
                }
            }
        }
        assert_eq!(checked, 1600);
    }

    #[test]
    fn warp_inverse_is_the_cdf_of_a_linear_density() {
        // Density 1 + x along x (2 columns): CDF (x + x^2/2) / 1.5.
        let raw = vec![1.0, 2.0, 1.0, 2.0];
        let warp = Warp::new(&raw, 1, 2, 2, Path::new("t")).unwrap();
        let c = Corners::new((0, 0.0), (0, 0.0), 0, 0);
        for x in [0.0, 0.25, 0.5, 0.9] {
            let s = warp.invert([x, 0.3], &c);
            let cdf = (x + x * x / 2.0) / 1.5;
            assert!(
                (s[0] - cdf).abs() < 1e-12 && (s[1] - 0.3).abs() < 1e-12,
                "{s:?}"
            );
        }
    }
}
