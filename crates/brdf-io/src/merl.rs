//! MERL `.binary` BRDF files (Matusik et al. 2003): reader, writer, conversion to dataset order
//! and resampling to other grids.
//!
//! Layout: three little-endian `i32` resolutions (theta_h, theta_d, phi_d; 90, 90, 180 for MERL),
//! then 3 x n_th x n_td x n_pd little-endian f64, channel-major (all R, then G, then B), each
//! channel in MERL's angular order (the order of [`AngularGrid::index`]). Stored numbers are
//! scaled: the BRDF value in 1/sr is `stored * scale[c]` with scale = (1/1500, 1.15/1500,
//! 1.66/1500) for R, G, B ([`MERL_SCALE`]). Negative stored values mark invalid (unmeasured or
//! below-horizon) samples.
//!
//! A "full" file of resolution 90, 90, 360 ([`FULL_PHI_D_RESOLUTION`]: phi_d over [0, 2 pi))
//! is folded onto MERL's grid by reciprocity when read.
//!
//! [`read_merl`] keeps the values exactly as stored (negative markers included, times the
//! scale; a "full" file's two halves are averaged as above) and refuses NaN and infinite numbers,
//! as [`MerlBrdf::new`] does ([`write_merl`] refuses values it would store as infinities). The
//! conversions to dataset order never store a marker: on the file's own grid a marker takes the
//! mean of its measured neighbours ([`MerlBrdf::to_dataset_order`]); resampling onto another
//! grid skips markers or reads the nearest measured cell ([`Resampling`]); a marker with no
//! measured value nearby is stored as 0 and counted in the [`ImportReport`].

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, Channels, HalfDiff, Vec3};
use crate::output::write_atomic_with;
use crate::source::{BrdfSource, ImportReport};

/// Per-channel factors from stored numbers to BRDF values in 1/sr (R, G, B).
pub const MERL_SCALE: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];

/// A MERL BRDF: its grid and its values in 1/sr, channel-major (`c * grid.len() + flat`).
#[derive(Debug, Clone, PartialEq)]
pub struct MerlBrdf {
    grid: AngularGrid,
    values: Vec<f64>,
}

/// Largest half-side, in cells, of the box around a negative marker whose measured values
/// fill it on MERL's own grid ([`MerlBrdf::to_dataset_order`]).
pub const MARKER_FILL_RADIUS: usize = 3;

/// How [`MerlBrdf::resample`] maps MERL's cells onto another grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Resampling {
    /// The MERL cell containing the target bin centre ([`AngularGrid::locate`]). When that cell
    /// holds no value (a negative marker, or its own bin centre is below the horizon, where
    /// files written by specgp hold 0) while the target cell is above the horizon, the valid
    /// MERL cell of the lookup stencil ([`AngularGrid::interpolation_stencil`]) nearest to the
    /// target bin centre (largest weight) that holds a value is read instead: a valid target
    /// cell must not store a marker as 0.
    Nearest,
    /// The mean of the valid MERL cells whose bin centres fall into the target bin (negative
    /// markers and below-horizon cells excluded); a target bin that receives no MERL cell (a
    /// grid finer than MERL's along some axis) falls back to `Nearest`. The right choice for
    /// coarser grids: it averages instead of aliasing.
    #[default]
    Average,
}

impl MerlBrdf {
    /// A MERL BRDF from values in 1/sr, channel-major; `values.len()` must be `3 * grid.len()`.
    pub fn new(grid: AngularGrid, values: Vec<f64>) -> Result<Self> {
        if values.len() != 3 * grid.len() {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "a MERL BRDF on grid {grid} needs {} values, got {}",
                    3 * grid.len(),
                    values.len()
                ),
            });
        }
        check_finite(&values, |i| i)?;
        Ok(Self { grid, values })
    }

    /// A MERL BRDF from dataset-order values (`flat * 3 + channel`, RGB in 1/sr); cells below
    /// the horizon are written as 0. Negative values (a prediction that undershoots zero, an
    /// out-of-gamut colour converted to sRGB) become 0: in a MERL file a negative value marks
    /// the cell invalid, and readers would drop the whole cell.
    pub fn from_dataset_order(grid: AngularGrid, values: &[f32]) -> Result<Self> {
        check_dataset_order(grid, values)?;
        let n = grid.len();
        let mut out = vec![0.0; 3 * n];
        for (flat, cell) in values.chunks_exact(3).enumerate() {
            for c in 0..3 {
                out[c * n + flat] = f64::from(cell[c]).max(0.0);
            }
        }
        Ok(Self { grid, values: out })
    }

    /// A MERL BRDF on MERL's own 90 x 90 x 180 grid ([`AngularGrid::MERL`], the only one the
    /// reference reader `BRDFRead.cpp` accepts) from dataset-order RGB values on `grid`: each
    /// MERL cell holds the values interpolated at its bin centre with `grid`'s lookup
    /// interpolation ([`AngularGrid::interpolation_stencil`], what every specgp lookup of the
    /// values reads), cells below the horizon 0; negative values become 0 as in
    /// [`MerlBrdf::from_dataset_order`]. On MERL's grid this is `from_dataset_order` itself.
    pub fn on_merl_grid(grid: AngularGrid, values: &[f32]) -> Result<Self> {
        if grid == AngularGrid::MERL {
            return Self::from_dataset_order(grid, values);
        }
        check_dataset_order(grid, values)?;
        use rayon::prelude::*;
        let merl = AngularGrid::MERL;
        let mut rgb = vec![0f32; 3 * merl.len()];
        rgb.par_chunks_mut(3).enumerate().for_each(|(flat, out)| {
            let hd = merl.bin_centre_flat(flat);
            if !hd.is_above_horizon() {
                return;
            }
            let mut acc = [0.0f64; 3];
            for (a, w) in grid.interpolation_stencil(&hd) {
                if w != 0.0 {
                    (0..3).for_each(|c| acc[c] += w * f64::from(values[3 * a + c]));
                }
            }
            (0..3).for_each(|c| out[c] = acc[c] as f32);
        });
        Self::from_dataset_order(merl, &rgb)
    }

    /// The grid of the file.
    pub fn grid(&self) -> &AngularGrid {
        &self.grid
    }

    /// Values in 1/sr, channel-major; negative values are the file's invalid markers.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Value of channel `c` (0 = R) at flat angular index `flat`.
    pub fn value(&self, c: usize, flat: usize) -> f64 {
        self.values[c * self.grid.len() + flat]
    }

    /// The values in dataset order on the file's own grid (`flat * 3 + channel`), with cells
    /// below the horizon set to 0. A negative marker (a cell MERL did not measure) takes the
    /// mean of the measured values of that channel among its neighbours within
    /// [`MARKER_FILL_RADIUS`] cells along each axis (phi_d wrapping around, as phi_d = 0 = pi),
    /// the nearest ring that has any (counted in
    /// [`ImportReport::markers_filled`]): stored as 0 it was a hole the fit learnt as a black
    /// spot (resampling onto other grids already skipped markers). A marker with no measured
    /// neighbour is stored as 0 (counted in [`ImportReport::negatives_clamped`]).
    pub fn to_dataset_order(&self) -> (Vec<f32>, ImportReport) {
        let g = self.grid;
        let mask = g.validity_mask();
        let mut report = ImportReport::new();
        let mut out = vec![0f32; 3 * g.len()];
        for (flat, ok) in mask.iter().enumerate() {
            if !ok {
                report.below_horizon_cells += 1;
                continue;
            }
            for c in 0..3 {
                let mut v = self.value(c, flat);
                if v < 0.0
                    && let Some(fill) = self.neighbour_mean(&mask, c, flat)
                {
                    report.markers_filled += 1;
                    v = fill;
                }
                out[flat * 3 + c] = report.record(v, None, false) as f32;
            }
        }
        (out, report)
    }

    /// The mean of channel `c`'s measured values (valid cell, not a marker) among the cells
    /// around `flat` within the smallest box of half-side 1 to [`MARKER_FILL_RADIUS`] that
    /// holds any. The theta axes stop at their ends; phi_d wraps (its first and last bins
    /// border phi_d = 0 = pi), and a box wider than the phi_d axis takes each bin once.
    fn neighbour_mean(&self, mask: &[bool], c: usize, flat: usize) -> Option<f64> {
        let g = self.grid;
        let (i, j, k) = g.unindex(flat);
        let span = |x: usize, r: usize, n: usize| x.saturating_sub(r)..=(x + r).min(n - 1);
        let n_pd = g.n_phi_d;
        let phi_span = |r: usize| {
            let width = (2 * r + 1).min(n_pd);
            let first = if width == n_pd { 0 } else { k + n_pd - r };
            (first..first + width).map(move |d| d % n_pd)
        };
        (1..=MARKER_FILL_RADIUS).find_map(|r| {
            let (mut sum, mut count) = (0.0, 0u32);
            for a in span(i, r, g.n_theta_h) {
                for b in span(j, r, g.n_theta_d) {
                    for d in phi_span(r) {
                        let f = g.index(a, b, d);
                        let v = self.value(c, f);
                        if mask[f] && v >= 0.0 && v.is_finite() {
                            sum += v;
                            count += 1;
                        }
                    }
                }
            }
            (count > 0).then(|| sum / f64::from(count))
        })
    }

    /// The values resampled onto `grid` in dataset order (see [`Resampling`]); cells below the
    /// horizon are 0. Negative markers are skipped (`Average`) or replaced by the nearest stencil
    /// cell that holds a value (`Nearest`), and count as 0 (in
    /// [`ImportReport::negatives_clamped`]) only when no such cell exists. On the file's own grid
    /// `method` plays no part: this is [`MerlBrdf::to_dataset_order`], which fills markers from
    /// their neighbours.
    pub fn resample(&self, grid: &AngularGrid, method: Resampling) -> (Vec<f32>, ImportReport) {
        if *grid == self.grid {
            return self.to_dataset_order();
        }
        let src = self.grid;
        let n = src.len();
        let target_mask = grid.validity_mask();
        let mut sums = vec![0f64; 3 * grid.len()];
        let mut counts = vec![0u32; 3 * grid.len()];
        if method == Resampling::Average {
            for (flat, ok) in src.validity_mask().into_iter().enumerate() {
                if !ok {
                    continue;
                }
                let (i, j, k) = grid.locate(&src.bin_centre_flat(flat));
                let t = grid.index(i, j, k);
                for c in 0..3 {
                    let v = self.values[c * n + flat];
                    if v >= 0.0 && v.is_finite() {
                        sums[t * 3 + c] += v;
                        counts[t * 3 + c] += 1;
                    }
                }
            }
        }
        let mut report = ImportReport::new();
        let mut out = vec![0f32; 3 * grid.len()];
        for (t, ok) in target_mask.iter().enumerate() {
            if !ok {
                report.below_horizon_cells += 1;
                continue;
            }
            let centre = grid.bin_centre_flat(t);
            for c in 0..3 {
                let v = if counts[t * 3 + c] > 0 {
                    sums[t * 3 + c] / f64::from(counts[t * 3 + c])
                } else {
                    self.nearest_value(&centre, c)
                };
                out[t * 3 + c] = report.record(v, None, false) as f32;
            }
        }
        (out, report)
    }

    /// Channel `c` of the MERL cell containing `hd` ([`AngularGrid::locate`]) when that cell
    /// holds a value: its bin centre is above the horizon and the value is not a negative
    /// marker. Otherwise the value of the cell with the largest weight among the cells of
    /// `hd`'s lookup stencil ([`AngularGrid::interpolation_stencil`]: valid cells only) that
    /// hold one; the containing cell's value (a marker, stored as 0 and counted) when none does.
    fn nearest_value(&self, hd: &HalfDiff, c: usize) -> f64 {
        let g = self.grid;
        let (i, j, k) = g.locate(hd);
        let v = self.value(c, g.index(i, j, k));
        if v >= 0.0 && g.is_valid_cell(i, j, k) {
            return v;
        }
        g.interpolation_stencil(hd)
            .iter()
            .filter(|&&(a, w)| w > 0.0 && self.value(c, a) >= 0.0)
            .max_by(|x, y| x.1.total_cmp(&y.1))
            .map_or(v, |&(a, _)| self.value(c, a))
    }
}

impl BrdfSource for MerlBrdf {
    fn channels(&self) -> Channels {
        Channels::Rgb
    }

    /// MERL's lookup: the value of the cell containing the pair's half/difference angles
    /// (no interpolation); negative markers read as 0.
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        crate::source::check_output_len(out, 3)?;
        out.iter_mut().for_each(|v| *v = 0.0);
        if !(wi[2] > 0.0 && wo[2] > 0.0) {
            return Ok(());
        }
        let Some(hd) = HalfDiff::from_dirs_merl(wi, wo) else {
            return Ok(());
        };
        let (i, j, mut k) = self.grid.locate(&hd);
        if hd.phi_d >= std::f64::consts::PI {
            // `BRDFRead.cpp` clamps phi_d = pi into the last bin (`locate` folds it to 0).
            k = self.grid.n_phi_d - 1;
        }
        let flat = self.grid.index(i, j, k);
        for (c, o) in out.iter_mut().enumerate() {
            *o = self.value(c, flat).max(0.0);
        }
        Ok(())
    }
}

/// Checks dataset-order RGB values (`flat * 3 + channel`) on `grid`: their number, and that
/// they are finite (an error names the first bad one by its MERL index).
fn check_dataset_order(grid: AngularGrid, values: &[f32]) -> Result<()> {
    if values.len() != 3 * grid.len() {
        return Err(Error::InvalidArgument {
            reason: format!(
                "dataset-order RGB values on grid {grid} need {} values, got {}",
                3 * grid.len(),
                values.len()
            ),
        });
    }
    let n = grid.len();
    check_finite(values, |i| (i % 3) * n + i / 3)
}

/// Reads a MERL `.binary` file (values in 1/sr, negative markers kept).
pub fn read_merl(path: impl AsRef<Path>) -> Result<MerlBrdf> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_merl(&bytes, path)
}

/// The three i32 resolutions at the start of a MERL file (`bytes` holds at least 12).
pub(crate) fn header_dims(bytes: &[u8]) -> [i32; 3] {
    let dim = |k: usize| {
        i32::from_le_bytes([
            bytes[4 * k],
            bytes[4 * k + 1],
            bytes[4 * k + 2],
            bytes[4 * k + 3],
        ])
    };
    [dim(0), dim(1), dim(2)]
}

/// Parses the bytes of a MERL file; `path` is only used in error messages.
pub fn parse_merl(bytes: &[u8], path: impl AsRef<Path>) -> Result<MerlBrdf> {
    let path: PathBuf = path.as_ref().to_path_buf();
    let bad = |reason: String| Error::Format {
        path: path.clone(),
        reason,
    };
    if bytes.len() < 12 {
        return Err(bad(format!(
            "truncated MERL file: {} bytes, the header alone needs 12",
            bytes.len()
        )));
    }
    let dims = header_dims(bytes);
    // A file written big-endian (MERL's files are little-endian) has plausible dimensions only
    // when they are byte-swapped, and then the right size: name that instead of the numbers.
    let grid_of = |d: [i32; 3]| {
        let [a, b, c] = d.map(|x| usize::try_from(x).ok());
        AngularGrid::new(a?, b?, c?).ok()
    };
    let swapped = dims.map(i32::swap_bytes);
    let swapped_len = grid_of(swapped).and_then(|g| g.len().checked_mul(24)?.checked_add(12));
    if grid_of(dims).is_none() && swapped_len == Some(bytes.len()) {
        return Err(bad(format!(
            "the MERL header reads {dims:?}, which byte-swapped is {swapped:?} and fits the \
             file's size: the file is big-endian; MERL files are little-endian (convert it, \
             e.g. swap the bytes of the three i32 and of every f64)"
        )));
    }
    if dims.iter().any(|&d| d <= 0) {
        return Err(bad(format!(
            "bad MERL resolution {dims:?} (expected e.g. 90 90 180)"
        )));
    }
    let grid = AngularGrid::new(dims[0] as usize, dims[1] as usize, dims[2] as usize)
        .map_err(|e| bad(format!("bad MERL resolution {dims:?}: {e}")))?;
    let expected = grid
        .len()
        .checked_mul(24)
        .and_then(|n| n.checked_add(12))
        .ok_or_else(|| bad(format!("MERL resolution {dims:?} overflows")))?;
    if bytes.len() != expected {
        return Err(bad(format!(
            "MERL file of resolution {dims:?} must have {expected} bytes, it has {}",
            bytes.len()
        )));
    }
    let n = grid.len();
    let mut values = Vec::with_capacity(3 * n);
    for (i, b) in bytes[12..].chunks_exact(8).enumerate() {
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        let stored = f64::from_le_bytes(a);
        if !stored.is_finite() {
            let (c, flat) = (i / n, i % n);
            let (ith, itd, ipd) = grid.unindex(flat);
            return Err(bad(format!(
                "non-finite value {stored} at value index {i} (byte offset {}; channel {}, \
                 cell {ith},{itd},{ipd}); MERL marks invalid samples with negative numbers, \
                 not NaN or infinity",
                12 + 8 * i,
                ["R", "G", "B"][c]
            )));
        }
        values.push(stored * MERL_SCALE[i / n]);
    }
    if (grid.n_theta_h, grid.n_theta_d, grid.n_phi_d) == FULL_PHI_D_RESOLUTION {
        return Ok(fold_full_phi_d(grid, &values));
    }
    Ok(MerlBrdf { grid, values })
}

/// The resolution of "full" MERL files, whose 360 phi_d bins span [0, 2 pi) instead of MERL's
/// [0, pi): the layout of the Neural-BRDF tools' `convert_to_fullmerl` and of some renderers'
/// readers. MERL's `BRDFRead.cpp` rejects such a file; read as MERL's layout, every phi_d would
/// land in the wrong bin (40.5 degrees in the 81-degree cell).
pub const FULL_PHI_D_RESOLUTION: (usize, usize, usize) = (90, 90, 360);

/// MERL's 90 x 90 x 180 BRDF from a full file's values (`grid` = 90 x 90 x 360, phi_d over
/// [0, 2 pi)): bins k and k + 180 hold phi_d and phi_d + pi, the same pair with wi and wo
/// swapped, so each MERL cell gets their reciprocal mean (the one valid value when the other
/// is a negative marker; a negative marker when both are).
fn fold_full_phi_d(grid: AngularGrid, values: &[f64]) -> MerlBrdf {
    let merl = AngularGrid::MERL;
    let (n_full, n) = (grid.len(), merl.len());
    let half = grid.n_phi_d / 2;
    let mut out = Vec::with_capacity(3 * n);
    for c in 0..3 {
        for flat in 0..n {
            let (ith, itd, ipd) = merl.unindex(flat);
            let at = |k: usize| values[c * n_full + grid.index(ith, itd, k)];
            let (a, b) = (at(ipd), at(ipd + half));
            out.push(match (a >= 0.0, b >= 0.0) {
                (true, true) => 0.5 * (a + b),
                (true, false) => a,
                (false, true) => b,
                (false, false) => a.max(b),
            });
        }
    }
    MerlBrdf {
        grid: merl,
        values: out,
    }
}

/// The stored number whose read-back (`stored * scale`) equals `value` when such a number exists
/// within a few ulps of `value / scale` (always true for values that were read from a MERL file),
/// else the nearest one: read -> write -> read is exact.
fn stored_number(value: f64, scale: f64) -> f64 {
    let guess = value / scale;
    if !guess.is_finite() || guess * scale == value {
        return guess;
    }
    let (mut lo, mut hi) = (guess, guess);
    for _ in 0..4 {
        lo = lo.next_down();
        hi = hi.next_up();
        if lo * scale == value {
            return lo;
        }
        if hi * scale == value {
            return hi;
        }
    }
    guess
}

/// Refuses NaN and infinity (a MERL file cannot mark them, and [`read_merl`] refuses them):
/// the error names the first bad value by its channel-major MERL index (`channel_major(i)` for
/// the `i`-th value of `values`).
fn check_finite<T: Copy + Into<f64>>(
    values: &[T],
    channel_major: impl Fn(usize) -> usize,
) -> Result<()> {
    match values.iter().position(|v| !(*v).into().is_finite()) {
        None => Ok(()),
        Some(i) => Err(Error::InvalidArgument {
            reason: format!(
                "a MERL BRDF cannot hold the non-finite value {} (at MERL index {})",
                values[i].into(),
                channel_major(i)
            ),
        }),
    }
}

/// Writes a MERL `.binary` file (temporary file + rename). Values are in 1/sr; the per-channel
/// scale is inverted so that [`read_merl`] gives the same values back (except on a grid of
/// [`FULL_PHI_D_RESOLUTION`], which [`read_merl`] folds onto MERL's grid).
///
/// A value whose stored number (value / scale) is beyond the f64 range (above ~1.2e305 1/sr
/// in R, ~2e305 in B) is an error naming `path`: the file would hold an infinity, which
/// [`read_merl`] refuses.
pub fn write_merl(path: impl AsRef<Path>, brdf: &MerlBrdf) -> Result<()> {
    let path = path.as_ref();
    let g = brdf.grid;
    let dims = [g.n_theta_h, g.n_theta_d, g.n_phi_d].map(i32::try_from);
    let [Ok(a), Ok(b), Ok(c)] = dims else {
        return Err(Error::InvalidArgument {
            reason: format!("grid {g} does not fit MERL's i32 header"),
        });
    };
    let n = g.len();
    // A finite value beyond f64::MAX times the scale has no finite stored number: the file
    // would hold an infinity that `read_merl` refuses.
    if let Some(i) = (0..brdf.values.len())
        .find(|&i| !stored_number(brdf.values[i], MERL_SCALE[i / n]).is_finite())
    {
        return Err(Error::InvalidArgument {
            reason: format!(
                "{}: value {:e} (channel {}, MERL index {}) is too large for a MERL file: its \
                 stored number (value / {:e}) is beyond the f64 range",
                path.display(),
                brdf.values[i],
                ["R", "G", "B"][i / n],
                i % n,
                MERL_SCALE[i / n]
            ),
        });
    }
    write_atomic_with(path, |w| {
        for d in [a, b, c] {
            w.write_all(&d.to_le_bytes())?;
        }
        for (i, v) in brdf.values.iter().enumerate() {
            w.write_all(&stored_number(*v, MERL_SCALE[i / n]).to_le_bytes())?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn non_finite_values_are_refused_with_their_merl_index() {
        let grid = AngularGrid::new(2, 2, 4).unwrap();
        let n = grid.len();
        let mut values = vec![0.5; 3 * n];
        values[n + 5] = f64::NAN;
        let err = MerlBrdf::new(grid, values).unwrap_err().to_string();
        assert!(
            err.contains("non-finite value NaN") && err.contains(&format!("MERL index {}", n + 5)),
            "{err}"
        );
        // Dataset order is cell-major (flat * 3 + channel): value 3 * 7 + 2 is channel 2, cell 7.
        let mut dataset = vec![0.5f32; 3 * n];
        dataset[3 * 7 + 2] = f32::INFINITY;
        let err = MerlBrdf::from_dataset_order(grid, &dataset)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("non-finite value inf")
                && err.contains(&format!("MERL index {}", 2 * n + 7)),
            "{err}"
        );
        assert!(
            MerlBrdf::new(grid, vec![-1.0; 3 * n]).is_ok(),
            "negative markers stay allowed"
        );
    }

    fn synthetic(grid: AngularGrid) -> MerlBrdf {
        // Smooth positive values with a few negative markers, as a MERL file would hold them.
        let n = grid.len();
        let values = (0..3 * n)
            .map(|i| {
                let (c, flat) = (i / n, i % n);
                let hd = grid.bin_centre_flat(flat);
                let raw = if flat % 17 == 3 {
                    -1.0
                } else {
                    100.0 * (-3.0 * hd.theta_h).exp() + 10.0 * (c as f64 + 1.0) + hd.phi_d
                };
                raw * MERL_SCALE[c]
            })
            .collect();
        MerlBrdf::new(grid, values).unwrap()
    }

    /// `BRDFRead.cpp` reads phi_d = pi (in-plane pairs whose difference vector points along
    /// -x; normal incidence) from the last phi_d bin, and phi_d just above 0 from the first.
    #[test]
    fn lookups_at_phi_d_pi_read_the_reference_readers_last_bin() {
        let grid = AngularGrid::new(9, 9, 18).unwrap();
        // Each cell's value is its flat index (channel 0).
        let n = grid.len();
        let values = (0..3 * n).map(|i| (i % n) as f64).collect();
        let brdf = MerlBrdf::new(grid, values).unwrap();
        let read = |wi: Vec3, wo: Vec3| {
            let mut out = [0.0; 3];
            brdf.eval(wi, wo, &mut out).unwrap();
            out[0].round() as usize
        };
        // In-plane directions (y = 0 exactly) at signed polar angles.
        let dir = |t: f64| [t.sin(), 0.0, t.cos()];
        let mut at_pi = 0;
        for (a, b) in [
            (0.3, -0.7),
            (-0.5, 0.1),
            (0.0, 0.4),
            (0.0, -0.4),
            (0.6, 0.2),
            (-0.6, -0.2),
        ] {
            let (wi, wo) = (dir(a), dir(b));
            let hd = HalfDiff::from_dirs_merl(wi, wo).unwrap();
            let folded = HalfDiff::from_dirs(wi, wo).unwrap();
            let (i, j, k) = grid.locate(&folded);
            let want = if hd.phi_d == PI {
                at_pi += 1;
                assert_eq!(
                    (folded.phi_d, k),
                    (0.0, 0),
                    "folded, it sits in the first bin"
                );
                grid.index(i, j, grid.n_phi_d - 1)
            } else {
                grid.index(i, j, k)
            };
            assert_eq!(read(wi, wo), want, "{wi:?} {wo:?}: {hd:?}");
        }
        assert!(at_pi >= 1, "none of the in-plane pairs has phi_d = pi");
    }

    /// Values on another grid reach MERL's grid through the lookup interpolation: a constant
    /// (in the valid cells, 0 in the others, as stored) stays constant above the horizon
    /// wherever a valid coarse cell is near, and every MERL cell equals the coarse grid's
    /// interpolation at its bin centre.
    #[test]
    fn values_on_another_grid_are_interpolated_onto_merls_grid() {
        let coarse = AngularGrid::new(4, 5, 6).unwrap();
        let coarse_mask = coarse.validity_mask();
        let constant: Vec<f32> = (0..3 * coarse.len())
            .map(|i| {
                if coarse_mask[i / 3] {
                    [0.5, 1.0, 2.0][i % 3]
                } else {
                    0.0
                }
            })
            .collect();
        let m = MerlBrdf::on_merl_grid(coarse, &constant).unwrap();
        let merl = AngularGrid::MERL;
        assert_eq!(m.grid(), &merl);
        let mut grazing_constant = 0;
        for flat in (0..merl.len()).step_by(101) {
            let hd = merl.bin_centre_flat(flat);
            let near_valid = coarse
                .interpolation_stencil(&hd)
                .iter()
                .any(|&(_, w)| w > 0.0);
            let want = if hd.is_above_horizon() && near_valid {
                // Cells next to invalid coarse cells read the constant too (the stencil skips
                // the stored 0s).
                if coarse
                    .interpolation_stencil(&hd)
                    .iter()
                    .any(|&(a, _)| !coarse_mask[a])
                {
                    grazing_constant += 1;
                }
                [0.5, 1.0, 2.0]
            } else {
                [0.0; 3]
            };
            for (c, w) in want.iter().enumerate() {
                assert!((m.value(c, flat) - w).abs() < 1e-6, "{flat} {c}");
            }
        }
        assert!(grazing_constant > 100, "{grazing_constant}");
        let varied: Vec<f32> = (0..3 * coarse.len())
            .map(|i| (i * 37 % 101) as f32 / 10.0)
            .collect();
        let m = MerlBrdf::on_merl_grid(coarse, &varied).unwrap();
        for flat in (0..merl.len()).step_by(997) {
            let hd = merl.bin_centre_flat(flat);
            if !hd.is_above_horizon() {
                continue;
            }
            for c in 0..3 {
                let want: f64 = coarse
                    .interpolation_stencil(&hd)
                    .iter()
                    .map(|&(a, w)| w * f64::from(varied[3 * a + c]))
                    .sum();
                assert!(
                    (m.value(c, flat) - want).abs() <= 1e-5 * want.max(1.0),
                    "{flat}"
                );
            }
        }
        // On MERL's grid the values are kept as they are.
        let small: Vec<f32> = vec![0.25; 3 * merl.len()];
        let same = MerlBrdf::on_merl_grid(merl, &small).unwrap();
        assert_eq!(same, MerlBrdf::from_dataset_order(merl, &small).unwrap());
        assert!(MerlBrdf::on_merl_grid(coarse, &varied[1..]).is_err());
    }

    #[test]
    fn write_read_round_trip_is_exact() {
        let grid = AngularGrid::new(9, 9, 18).unwrap();
        let brdf = synthetic(grid);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.binary");
        write_merl(&p, &brdf).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(bytes.len(), 12 + 24 * grid.len());
        assert_eq!(&bytes[..4], &9i32.to_le_bytes());
        let back = read_merl(&p).unwrap();
        assert_eq!(back, brdf, "read(write(x)) must equal x bit for bit");
        // And the file bytes round-trip as well.
        write_merl(&p, &back).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), bytes);
    }

    /// A full 90 x 90 x 360 file (phi_d over [0, 2 pi)) reads as MERL's grid: each cell is the
    /// reciprocal mean of bins k and k + 180, a lookup at phi_d = 40.5 degrees reads the 40.5
    /// degree cell (not the 81-degree one, as reading it with MERL's layout did), and negative
    /// markers drop out of the mean.
    #[test]
    fn full_phi_d_files_are_folded_onto_merls_grid() {
        let full = AngularGrid::new(90, 90, 360).unwrap();
        let stored = |c: usize, ith: usize, itd: usize, k: usize| -> f64 {
            // Smooth in the angles, different in the two halves, one negative marker.
            if (c, ith, itd, k) == (1, 10, 20, 200) {
                return -1.0;
            }
            (1 + c) as f64
                + ith as f64 * 0.01
                + itd as f64 * 0.001
                + (k % 180) as f64 * 1e-4
                + if k >= 180 { 0.5 } else { 0.0 }
        };
        let mut values = Vec::with_capacity(3 * full.len());
        for c in 0..3 {
            for flat in 0..full.len() {
                let (i, j, k) = full.unindex(flat);
                values.push(stored(c, i, j, k));
            }
        }
        let bytes = merl_bytes([90, 90, 360], &values);
        let brdf = parse_merl(&bytes, "full.binary").unwrap();
        assert_eq!(brdf.grid(), &AngularGrid::MERL);
        let merl = AngularGrid::MERL;
        for (c, i, j, k) in [
            (0, 3, 4, 5),
            (2, 89, 0, 179),
            (1, 45, 45, 90),
            (1, 10, 20, 20),
        ] {
            let want = if (c, i, j, k) == (1, 10, 20, 20) {
                stored(c, i, j, k)
            } else {
                0.5 * (stored(c, i, j, k) + stored(c, i, j, k + 180))
            } * MERL_SCALE[c];
            let got = brdf.value(c, merl.index(i, j, k));
            assert!(
                (got - want).abs() <= 1e-15 * want,
                "{c} {i} {j} {k}: {got} vs {want}"
            );
        }
        // In-plane-free pair at phi_d = 40.5 degrees reads bin 40 of MERL's grid.
        let hd = HalfDiff {
            theta_h: merl.bin_centre(30, 30, 0).theta_h,
            theta_d: merl.bin_centre(30, 30, 0).theta_d,
            phi_d: 40.5f64.to_radians(),
        };
        let (wi, wo) = hd.to_dirs();
        let mut out = [0.0; 3];
        brdf.eval(wi, wo, &mut out).unwrap();
        let want = 0.5 * (stored(0, 30, 30, 40) + stored(0, 30, 30, 220)) * MERL_SCALE[0];
        assert!(
            (out[0] - want).abs() <= 1e-12 * want,
            "{} vs {want}",
            out[0]
        );
    }

    /// NaN and +-infinity are refused with the file and the first bad index; finite negative
    /// markers (-1) are kept as they are.
    #[test]
    fn non_finite_values_are_refused_negative_markers_kept() {
        let grid = AngularGrid::new(2, 2, 4).unwrap();
        let n = grid.len();
        let values: Vec<f64> = (0..3 * n)
            .map(|i| if i == 5 { -1.0 } else { 0.5 * i as f64 })
            .collect();
        let bytes = merl_bytes([2, 2, 4], &values);
        let ok = parse_merl(&bytes, "ok.binary").unwrap();
        assert_eq!(ok.value(0, 5), -MERL_SCALE[0]);
        assert_eq!(ok.value(1, 3), 0.5 * (n + 3) as f64 * MERL_SCALE[1]);
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut b = bytes.clone();
            let i = n + 3; // channel G, flat 3
            b[12 + 8 * i..20 + 8 * i].copy_from_slice(&bad.to_le_bytes());
            // A second bad value later: the first one is reported.
            b[12 + 8 * (2 * n)..20 + 8 * (2 * n)].copy_from_slice(&bad.to_le_bytes());
            let e = parse_merl(&b, "bad.binary").unwrap_err();
            let msg = e.to_string();
            assert!(msg.starts_with("bad.binary: non-finite value"), "{msg}");
            assert!(msg.contains(&format!("value index {i} ")), "{msg}");
            assert!(msg.contains("channel G, cell 0,0,3"), "{msg}");
        }
    }

    #[test]
    fn dataset_order_counts_markers_and_masks_horizon() {
        let grid = AngularGrid::new(6, 6, 12).unwrap();
        let brdf = synthetic(grid);
        let (v, r) = brdf.to_dataset_order();
        let mask = grid.validity_mask();
        let valid = mask.iter().filter(|m| **m).count();
        assert_eq!(r.values, 3 * valid);
        let markers: Vec<usize> = (0..grid.len())
            .filter(|f| f % 17 == 3 && mask[*f])
            .collect();
        assert_eq!(r.markers_filled, 3 * markers.len());
        assert_eq!(r.negatives_clamped, 0);
        // A marker holds the mean of its measured neighbours in the 3 x 3 x 3 box around it
        // (other markers there left out).
        for &m in &markers {
            let (i, j, k) = grid.unindex(m);
            for c in 0..3 {
                let (mut sum, mut count) = (0.0, 0.0);
                for a in i.saturating_sub(1)..=(i + 1).min(5) {
                    for b in j.saturating_sub(1)..=(j + 1).min(5) {
                        // phi_d wraps: bins 11 and 0 border phi_d = pi = 0.
                        for d in [(k + 11) % 12, k, (k + 1) % 12] {
                            let f = grid.index(a, b, d);
                            if mask[f] && brdf.value(c, f) >= 0.0 {
                                sum += brdf.value(c, f);
                                count += 1.0;
                            }
                        }
                    }
                }
                assert!(count > 0.0);
                assert_eq!(
                    v[m * 3 + c],
                    (sum / count) as f32,
                    "marker {m}, channel {c}"
                );
                assert!(v[m * 3 + c] > 0.0);
            }
        }
        let f = mask.iter().position(|m| *m).unwrap();
        assert_eq!(v[f * 3 + 1], brdf.value(1, f) as f32);
        let bad = mask.iter().position(|m| !*m).unwrap();
        assert_eq!(&v[bad * 3..bad * 3 + 3], &[0.0, 0.0, 0.0]);
        // Resampling onto the same grid is the identity conversion.
        assert_eq!(brdf.resample(&grid, Resampling::Average).0, v);
        // Back from dataset order: valid cells survive exactly.
        let again = MerlBrdf::from_dataset_order(grid, &v).unwrap();
        assert_eq!(again.value(2, f) as f32, v[f * 3 + 2]);
        // A negative value (an out-of-gamut colour) is written as 0, not as an invalid marker
        // that would drop the cell's other channels too.
        let mut w = v.clone();
        w[f * 3 + 1] = -0.25;
        let clamped = MerlBrdf::from_dataset_order(grid, &w).unwrap();
        assert_eq!(clamped.value(1, f), 0.0);
        assert_eq!(clamped.value(2, f) as f32, v[f * 3 + 2]);
        assert_eq!(clamped.to_dataset_order().1.negatives_clamped, 0);
    }

    /// The box around a marker wraps along phi_d: the first and last phi_d bins border
    /// phi_d = 0 = pi, so a marker in one is filled from the other. A box wider than the phi_d
    /// axis counts each bin once.
    #[test]
    fn marker_boxes_wrap_around_phi_d() {
        // Measured cells only in the last phi_d bin (value 4) and, two bins in, in bin 2
        // (value 10); markers everywhere else.
        let grid = AngularGrid::new(4, 4, 8).unwrap();
        let n = grid.len();
        let mut values = vec![-1.0; 3 * n];
        for c in 0..3 {
            values[c * n + grid.index(1, 1, 7)] = 4.0;
            values[c * n + grid.index(1, 1, 2)] = 10.0;
        }
        let (v, _) = MerlBrdf::new(grid, values).unwrap().to_dataset_order();
        let at = |k: usize| v[grid.index(1, 1, k) * 3];
        // Bin 0's ring 1 reaches bin 7 across phi_d = 0 (and bin 1, a marker): only 4 counts.
        assert_eq!(at(0), 4.0);
        // Bin 1 sees bin 2 at ring 1; bin 7 is two bins away, so it does not count.
        assert_eq!(at(1), 10.0);
        // Bin 6 sees bin 7 at ring 1, but bin 2 only at ring 4 (across the wrap).
        assert_eq!(at(6), 4.0);
        // Bin 4 is two bins from bin 2 and three from bin 7: ring 2 holds bin 2 only.
        assert_eq!(at(4), 10.0);
        // Bin 5 is two bins from bin 7 and three from bin 2.
        assert_eq!(at(5), 4.0);

        // On a 2-bin phi_d axis every box spans it; each measured bin counts once, so a
        // marker is the mean of its neighbours, not weighted by how often the box wraps.
        let grid = AngularGrid::new(3, 3, 2).unwrap();
        let n = grid.len();
        let mut values = vec![-1.0; 3 * n];
        for c in 0..3 {
            values[c * n + grid.index(1, 1, 0)] = 2.0;
            values[c * n + grid.index(1, 0, 1)] = 8.0;
        }
        let (v, _) = MerlBrdf::new(grid, values).unwrap().to_dataset_order();
        assert_eq!(v[grid.index(1, 1, 1) * 3 + 2], 5.0);
    }

    /// Markers take the measured values of the nearest ring that has any, up to
    /// `MARKER_FILL_RADIUS` cells away; beyond that they are stored as 0 and counted.
    #[test]
    fn markers_are_filled_from_the_nearest_measured_ring() {
        let grid = AngularGrid::new(8, 8, 16).unwrap();
        let mask = grid.validity_mask();
        // One measured cell, (1, 1, 8); every other cell a marker.
        let measured = grid.index(1, 1, 8);
        assert!(mask[measured]);
        let mut values = vec![-1.0; 3 * grid.len()];
        for c in 0..3 {
            values[c * grid.len() + measured] = 0.5 + c as f64;
        }
        let (v, r) = MerlBrdf::new(grid, values).unwrap().to_dataset_order();
        let (mut filled, mut zeros) = (0, 0);
        for (f, ok) in mask.iter().enumerate() {
            if !ok || f == measured {
                continue;
            }
            let (i, j, k) = grid.unindex(f);
            let ring = i.abs_diff(1).max(j.abs_diff(1)).max(k.abs_diff(8));
            if ring <= MARKER_FILL_RADIUS {
                assert_eq!(&v[f * 3..f * 3 + 3], &[0.5, 1.5, 2.5], "cell {f}");
                filled += 3;
            } else {
                assert_eq!(&v[f * 3..f * 3 + 3], &[0.0; 3], "cell {f}");
                zeros += 3;
            }
        }
        assert!(filled > 0 && zeros > 0);
        assert_eq!((r.markers_filled, r.negatives_clamped), (filled, zeros));
        assert!(
            r.to_string()
                .contains(&format!("{filled} unmeasured (marker) values filled"))
        );
    }

    #[test]
    fn coarse_resampling_averages_a_constant_exactly() {
        let fine = AngularGrid::new(12, 12, 24).unwrap();
        let coarse = AngularGrid::new(4, 4, 8).unwrap();
        let brdf = MerlBrdf::new(fine, vec![0.25; 3 * fine.len()]).unwrap();
        for m in [Resampling::Nearest, Resampling::Average] {
            let (v, r) = brdf.resample(&coarse, m);
            assert_eq!(r.negatives_clamped, 0);
            for (t, ok) in coarse.validity_mask().iter().enumerate() {
                let want = if *ok { 0.25 } else { 0.0 };
                assert_eq!(v[t * 3], want, "cell {t} with {m:?}");
            }
        }
    }

    /// A valid (above-horizon) target cell whose MERL cell holds no value (its centre is below
    /// the horizon: a negative marker in MERL's files, 0 in files specgp writes) reads the
    /// nearest MERL cell that holds one: every valid target cell of a constant material is that
    /// constant, with either method, on coarser and finer grids. Both used to store 0 there
    /// (e.g. 1789 valid cells of MERL's grid on 45,45,90 with `Nearest`, 3506 on 100,100,200
    /// with `Average`), zeros the store counts as data.
    #[test]
    fn valid_target_cells_never_read_cells_without_a_value() {
        let src = AngularGrid::new(18, 18, 36).unwrap();
        let (n, mask) = (src.len(), src.validity_mask());
        for below in [-1.0 / 1500.0, 0.0] {
            let values = (0..3 * n)
                .map(|i| if mask[i % n] { 0.5 } else { below })
                .collect();
            let brdf = MerlBrdf::new(src, values).unwrap();
            for (g, method) in [
                ((9, 9, 18), Resampling::Nearest),
                ((12, 12, 24), Resampling::Nearest),
                ((20, 20, 40), Resampling::Average),
                ((18, 18, 72), Resampling::Average),
                ((20, 20, 40), Resampling::Nearest),
            ] {
                let grid = AngularGrid::new(g.0, g.1, g.2).unwrap();
                let (v, report) = brdf.resample(&grid, method);
                for (t, ok) in grid.validity_mask().into_iter().enumerate() {
                    let want = if ok { [0.5; 3] } else { [0.0; 3] };
                    assert_eq!(v[3 * t..3 * t + 3], want, "{g:?} {method:?} cell {t}");
                }
                assert_eq!(report.negatives_clamped, 0, "{g:?} {method:?}");
            }
        }
        // Where the containing MERL cell holds a value, it is read as before.
        let ramp = (0..3 * n).map(|i| (i % n) as f64).collect();
        let brdf = MerlBrdf::new(src, ramp).unwrap();
        let grid = AngularGrid::new(9, 9, 18).unwrap();
        let (v, _) = brdf.resample(&grid, Resampling::Nearest);
        let t = grid.index(2, 3, 4);
        let (i, j, k) = src.locate(&grid.bin_centre(2, 3, 4));
        assert_eq!(f64::from(v[3 * t]), src.index(i, j, k) as f64);
    }

    /// A big-endian MERL file is named as such (its header read little-endian gave dimensions
    /// like 1509949440 and a message about the grid's size limit).
    #[test]
    fn big_endian_files_are_named_big_endian() {
        let mut bytes = Vec::new();
        for d in [9i32, 9, 18] {
            bytes.extend_from_slice(&d.to_be_bytes());
        }
        for _ in 0..3 * 9 * 9 * 18 {
            bytes.extend_from_slice(&1500f64.to_be_bytes());
        }
        let e = parse_merl(&bytes, "be.binary").unwrap_err();
        assert!(matches!(e, Error::Format { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.starts_with("be.binary: the MERL header reads [150994944, 150994944, 301989888]")
                && msg.contains("byte-swapped is [9, 9, 18]")
                && msg.contains("the file is big-endian"),
            "{msg}"
        );
        // 180 byte-swapped (0xb4000000) is a negative i32, as in MERL's own 90 x 90 x 180.
        let mut bytes = Vec::new();
        for d in [9i32, 9, 180] {
            bytes.extend_from_slice(&d.to_be_bytes());
        }
        bytes.resize(12 + 24 * 9 * 9 * 180, 0);
        let e = parse_merl(&bytes, "be.binary").unwrap_err().to_string();
        assert!(e.contains("byte-swapped is [9, 9, 180]"), "{e}");
        // Big-endian dimensions that do not fit the size stay a plain resolution error.
        let e = parse_merl(&bytes[..bytes.len() - 8], "be.binary")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bad MERL resolution") && !e.contains("big-endian"),
            "{e}"
        );
    }

    /// A value whose stored number overflows f64 (1e306 x 1500) is refused by the writer,
    /// naming the file and the value: it used to be written as an infinity that `read_merl`
    /// then refused. Large values that fit still round-trip exactly; so do lookups with
    /// directions of any finite length (a wi shorter than ~1e-154 used to read 0).
    #[test]
    fn values_beyond_the_stored_range_are_refused_by_the_writer() {
        let grid = AngularGrid::new(2, 2, 4).unwrap();
        let n = grid.len();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.binary");
        let mut values = vec![1e300; 3 * n];
        values[n + 5] = 1e306;
        let e = write_merl(&p, &MerlBrdf::new(grid, values.clone()).unwrap())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("h.binary: value 1e306 (channel G, MERL index 5)")
                && e.contains("too large for a MERL file"),
            "{e}"
        );
        assert!(!p.exists(), "nothing is written");
        values[n + 5] = 1e300;
        let brdf = MerlBrdf::new(grid, values).unwrap();
        write_merl(&p, &brdf).unwrap();
        assert_eq!(read_merl(&p).unwrap(), brdf);
        let constant = MerlBrdf::new(grid, vec![0.5; 3 * n]).unwrap();
        let wo = [0.3, -0.4, 0.75f64.sqrt()];
        for s in [1.0, 1e-170, 1e170] {
            let mut out = [0.0; 3];
            constant
                .eval([0.0, 0.6 * s, 0.8 * s], wo, &mut out)
                .unwrap();
            assert_eq!(out, [0.5; 3], "{s:e}");
        }
    }

    #[test]
    fn rejects_bad_sizes() {
        let e = parse_merl(&[0u8; 5], "m.binary").unwrap_err().to_string();
        assert!(e.contains("m.binary") && e.contains("truncated"), "{e}");
        // Far fewer values than the resolutions in the header call for.
        let b = merl_bytes([2, 2, 2], &[0.0; 2]);
        assert!(
            parse_merl(&b, "m.binary")
                .unwrap_err()
                .to_string()
                .contains("must have")
        );
    }

    /// A MERL file's bytes: the three resolutions, then `stored` (stored numbers, channel-major).
    fn merl_bytes(dims: [i32; 3], stored: &[f64]) -> Vec<u8> {
        let mut b: Vec<u8> = dims.iter().flat_map(|d| d.to_le_bytes()).collect();
        b.extend(stored.iter().flat_map(|v| v.to_le_bytes()));
        b
    }

    /// For every stored number s of a sweep (fractions and integers, 1e-5 to 1e5), and each
    /// channel's scale, the writer's stored number for the value s * scale reads back as
    /// s * scale exactly, negative markers as well; it is within 4 ulps of the quotient
    /// (s * scale) / scale (not always s itself: the product rounds). A stored number beyond
    /// the f64 range stays infinite, for `write_merl` to refuse.
    #[test]
    fn stored_numbers_read_back_exactly() {
        for scale in MERL_SCALE {
            for e in -5..=5 {
                for i in 1..400 {
                    let s = (i as f64 * 0.0137 + (i % 7) as f64) * 10f64.powi(e);
                    let value = s * scale;
                    let got = stored_number(value, scale);
                    assert_eq!(got * scale, value, "s = {s}, scale = {scale}");
                    let quotient = value / scale;
                    let ulps = (got.to_bits() as i64 - quotient.to_bits() as i64).abs();
                    assert!(ulps <= 4, "{ulps} ulps from {quotient}");
                    assert_eq!(stored_number(-value, scale) * scale, -value);
                }
            }
        }
        assert_eq!(stored_number(0.0, MERL_SCALE[0]), 0.0);
        assert!(stored_number(1e306, MERL_SCALE[0]).is_infinite());
    }

    /// Files too short for the header, or of a resolution with an empty axis (zero or
    /// negative), or the wrong size for their resolution, are errors naming the file and the
    /// numbers (12 bytes are a whole header, judged by its size).
    #[test]
    fn bad_headers_and_sizes_are_named() {
        let e = |b: &[u8]| parse_merl(b, "m.binary").unwrap_err().to_string();
        assert_eq!(
            e(&[0; 11]),
            "m.binary: truncated MERL file: 11 bytes, the header alone needs 12"
        );
        assert_eq!(
            e(&merl_bytes([1, 1, 1], &[])),
            "m.binary: MERL file of resolution [1, 1, 1] must have 36 bytes, it has 12"
        );
        for dims in [[0, 2, 2], [2, -1, 2], [2, 2, 0]] {
            assert_eq!(
                e(&merl_bytes(dims, &[0.0; 24])),
                format!("m.binary: bad MERL resolution {dims:?} (expected e.g. 90 90 180)")
            );
        }
        let big = e(&merl_bytes([1 << 20, 2, 2], &[]));
        assert!(
            big.starts_with("m.binary: bad MERL resolution [1048576, 2, 2]: invalid grid"),
            "{big}"
        );
        let m = parse_merl(&merl_bytes([1, 1, 1], &[1500.0, 1500.0, -3.0]), "m.binary").unwrap();
        assert_eq!(m.values(), [1.0, 1.15, -3.0 * MERL_SCALE[2]]);
        assert_eq!(m.grid(), &AngularGrid::new(1, 1, 1).unwrap());
        // A NaN's message gives its byte offset: 12 + 8 * index.
        let e = e(&merl_bytes([1, 1, 2], &[0.0, 0.0, 0.0, f64::NAN, 0.0, 0.0]));
        assert!(
            e.contains("value index 3 (byte offset 36; channel G, cell 0,0,1)"),
            "{e}"
        );
    }

    /// Folding a full file: each MERL cell is the mean of bins k and k + 180 when both are
    /// measured, the measured one when the other is a marker, and the larger marker when both
    /// are markers.
    #[test]
    fn full_files_fold_each_pair_of_phi_d_bins() {
        let full = AngularGrid::new(90, 90, 360).unwrap();
        let merl = AngularGrid::MERL;
        let n = full.len();
        let mut values = vec![0.25; 3 * n];
        let mut set = |c: usize, i: usize, j: usize, k: usize, a: f64, b: f64| {
            values[c * n + full.index(i, j, k)] = a;
            values[c * n + full.index(i, j, k + 180)] = b;
        };
        set(0, 1, 2, 3, 1.0, 3.0);
        set(1, 4, 5, 6, 2.0, -1.0);
        set(2, 7, 8, 9, -1.0, 5.0);
        set(2, 10, 11, 179, -3.0, -2.0);
        set(0, 12, 13, 0, -2.0, -3.0);
        let m = fold_full_phi_d(full, &values);
        assert_eq!(m.grid(), &merl);
        assert_eq!(m.values().len(), 3 * merl.len());
        for (c, i, j, k, want) in [
            (0, 1, 2, 3, 2.0),
            (1, 4, 5, 6, 2.0),
            (2, 7, 8, 9, 5.0),
            (2, 10, 11, 179, -2.0),
            (0, 12, 13, 0, -2.0),
            (1, 89, 89, 179, 0.25),
        ] {
            assert_eq!(m.value(c, merl.index(i, j, k)), want, "{c} {i} {j} {k}");
        }
    }

    /// A BRDF needs exactly 3 values per cell; `values` gives them back as given, channel-major,
    /// and dataset order (`flat * 3 + c`) lands at `c * n + flat`.
    #[test]
    fn values_are_channel_major() {
        let grid = AngularGrid::new(2, 2, 4).unwrap();
        let n = grid.len();
        let e = MerlBrdf::new(grid, vec![0.0; 3 * n - 1])
            .unwrap_err()
            .to_string();
        assert!(e.contains("needs 48 values, got 47"), "{e}");
        let e = MerlBrdf::from_dataset_order(grid, &[0.0; 49])
            .unwrap_err()
            .to_string();
        assert!(e.contains("need 48 values, got 49"), "{e}");
        let values: Vec<f64> = (0..3 * n).map(|i| i as f64).collect();
        assert_eq!(
            MerlBrdf::new(grid, values.clone()).unwrap().values(),
            values
        );
        let dataset: Vec<f32> = (0..3 * n).map(|i| i as f32).collect();
        let m = MerlBrdf::from_dataset_order(grid, &dataset).unwrap();
        for flat in 0..n {
            for c in 0..3 {
                assert_eq!(m.value(c, flat), (flat * 3 + c) as f64);
            }
        }
    }

    /// On the file's own grid: cells below the horizon are counted and stored as 0; a measured
    /// 0 is a value, not a marker (kept as 0, and counted in a marker's mean: the marker
    /// between a 0 and a 4 is 2).
    #[test]
    fn measured_zeros_are_values_not_markers() {
        let grid = AngularGrid::new(4, 4, 8).unwrap();
        let n = grid.len();
        let mask = grid.validity_mask();
        let below = mask.iter().filter(|ok| !**ok).count();
        assert!(below > 0);
        // Channel 0 is 4 everywhere but a marker at (0, 0, 4) and a measured 0 at each of the
        // other cells of its ring-1 box.
        let mut values = vec![4.0; 3 * n];
        let marker = grid.index(0, 0, 4);
        for a in 0..2 {
            for b in 0..2 {
                for d in 3..6 {
                    values[grid.index(a, b, d)] = 0.0;
                }
            }
        }
        values[marker] = -1.0;
        // Its 11 neighbours are all 0: the mean is 0, and the cell counts as filled.
        let (v, r) = MerlBrdf::new(grid, values.clone())
            .unwrap()
            .to_dataset_order();
        assert_eq!(r.below_horizon_cells, below);
        assert_eq!((r.markers_filled, r.negatives_clamped), (1, 0));
        assert_eq!(v[marker * 3], 0.0);
        assert_eq!(v[grid.index(1, 1, 4) * 3], 0.0, "a measured 0 stays 0");
        // One neighbour 4 more, and the rest 0: 4 / 11.
        values[grid.index(1, 1, 5)] = 4.0;
        let (v, _) = MerlBrdf::new(grid, values).unwrap().to_dataset_order();
        assert_eq!(v[marker * 3], (4.0f64 / 11.0) as f32);
    }

    /// `Average` resampling averages every measured value that falls in a target bin, zeros
    /// included: fine phi_d bins 3K, 3K + 1, 3K + 2 (values 0, 2, 4) land in coarse bin K,
    /// whose mean is 2 (3 if zeros were left out); near the pole every cell is above the
    /// horizon, so each bin gets whole triples.
    #[test]
    fn average_resampling_counts_measured_zeros() {
        let fine = AngularGrid::new(12, 12, 24).unwrap();
        let coarse = AngularGrid::new(4, 4, 8).unwrap();
        let n = fine.len();
        let values = (0..3 * n)
            .map(|i| 2.0 * (fine.unindex(i % n).2 % 3) as f64)
            .collect();
        let (v, r) = MerlBrdf::new(fine, values)
            .unwrap()
            .resample(&coarse, Resampling::Average);
        for k in 0..8 {
            let t = coarse.index(0, 0, k);
            assert_eq!(&v[3 * t..3 * t + 3], &[2.0; 3], "bin {k}");
        }
        let below = coarse.validity_mask().iter().filter(|ok| !**ok).count();
        assert_eq!(r.below_horizon_cells, below);
        assert_eq!(r.values, 3 * (coarse.len() - below));
    }

    /// A lookup is 0 when either direction is at or below the horizon, a negative marker
    /// reads as 0, the output needs exactly 3 slots, and the channels are RGB.
    #[test]
    fn lookups_below_the_horizon_or_at_markers_read_zero() {
        let grid = AngularGrid::new(2, 2, 4).unwrap();
        let n = grid.len();
        let up = [0.0, 0.0, 1.0];
        let down = [0.6, 0.0, -0.8];
        let brdf = MerlBrdf::new(grid, vec![0.5; 3 * n]).unwrap();
        assert_eq!(brdf.channels(), Channels::Rgb);
        let read = |b: &MerlBrdf, wi: Vec3, wo: Vec3| {
            let mut out = [9.0; 3];
            b.eval(wi, wo, &mut out).unwrap();
            out
        };
        assert_eq!(read(&brdf, up, up), [0.5; 3]);
        assert_eq!(read(&brdf, up, down), [0.0; 3]);
        assert_eq!(read(&brdf, down, up), [0.0; 3]);
        assert_eq!(read(&brdf, [1.0, 0.0, 0.0], up), [0.0; 3]);
        let markers = MerlBrdf::new(grid, vec![-0.5; 3 * n]).unwrap();
        assert_eq!(read(&markers, up, up), [0.0; 3]);
        let mut short = [0.0; 2];
        assert!(brdf.eval(up, up, &mut short).is_err());
    }
}
