//! Writing isotropic RGL `.bsdf` files from any [`BrdfSource`], so that a stored or predicted
//! material can be rendered by Mitsuba 3 (`measured`) and pbrt-v4 (`measured`), which read this
//! format (Dupuy & Jakob 2018).
//!
//! The format stores a BRDF in a parameterisation adapted to it: for each incident elevation
//! `theta_i`, the half vectors are warped by the visible normal distribution (VNDF) of a
//! microfacet distribution D, and the values are tabulated on a regular grid of the warped unit
//! square, divided by the microfacet term D / (4 sigma) (flag `jacobian`); an evaluator inverts the
//! warp at the half vector, interpolates the table and multiplies by D / (4 sigma) again
//! (`RglBsdf`, module docs of [`super`]). Any positive D gives a valid file; a D shaped like the
//! BRDF's own lobe puts the table's samples where the BRDF varies. The writer:
//! 1. estimates D from the source's retro-reflection, `D(theta) ~ lum f(w, w) cos^2 theta` (the
//!    microfacet model's `f(w, w) = D F G / (4 cos^2 theta)` without F and G), normalised so
//!    that the integral of D cos theta_m is 1, mixed with the uniform NDF 1/pi in the share
//!    [`RglWriteOptions::broad_share`] (so the warp still puts table points where the estimate
//!    is small but the BRDF is not, and no value is divided by a vanishing D) and, when that
//!    checks better, with a narrow lobe around the mirror direction
//!    ([`RglWriteOptions::mirror_share`]), and tabulated over `u = sqrt(2 theta / pi)` as the
//!    format does;
//! 2. integrates the projected area `sigma(w_i) = int D(m) max(0, w_i . m) dm` numerically;
//! 3. tabulates per `theta_i` the warp's density over the format's half-vector coordinates:
//!    the VNDF `D(m) max(0, w_i . m)` or, when that checks better
//!    ([`RglWriteOptions::lobe_warp`]), 10 % of it and 90 % the source's own reflected
//!    luminance `lum f(w_i, w_o) cos(theta_o) 4 (w_i . m)`, both times the coordinates'
//!    Jacobian (`2 pi^2 u sin theta_m`), so that the table's points follow the BRDF at each
//!    elevation (any positive warp is valid: readers invert the stored one, and renderers'
//!    sampling pdfs come from the same tables);
//! 4. for each point of the regular grid of the warped square, finds the half vector the warp
//!    maps it to (the exact inverse of the evaluator's own warp inversion, in closed form: a
//!    binary search of the warp's CDFs and the quadratic of one cell, so a lookup of the
//!    written file at that half vector lands exactly on the grid point), reflects `w_i` about it
//!    and stores `f(w_i, w_o) cos(theta_o) 4 sigma / D` with the tables' own interpolated D and
//!    sigma: the file then reproduces the source exactly (to f32 rounding) at every stored point
//!    and interpolates between them;
//! 5. stores a luminance table (the sampling density renderers use for importance sampling,
//!    on top of the warp): the reflected luminance divided by the warp's density, so that
//!    sampling follows the BRDF;
//! 6. checks the file against the source ([`RglWriteSummary::check_rms`] at seeded direction
//!    pairs, [`RglWriteSummary::albedo_error`] at incidence 0-88 degrees) and, above
//!    [`RglWriteOptions::tolerance`], writes it again with finer tables.
//!
//! Grid sources (stored and predicted materials) are evaluated cell by cell, each cell once.
//! Negative source values (a raw-space prediction undershooting zero) are stored as 0 and
//! counted. Incident elevations are cosine-spaced from 0 to 90 degrees (denser towards grazing,
//! like the RGL database's files); the source is evaluated at most at [`MAX_EVAL_THETA_DEG`].

use std::f64::consts::PI;
use std::path::Path;

use rayon::prelude::*;

use super::{Corners, RglBsdf, Table2D, Warp, phi2u, theta2u};
use crate::albedo::{AlbedoNodes, direction};
use crate::error::{Error, Result};
use crate::grid::Channels;
use crate::lookup::{cell_record, look_up};
use crate::source::{BrdfSource, will_need_pairs};
use crate::tensor::{Field, TensorFile};

/// The default [`RglWriteOptions::broad_share`].
pub const BROAD_SHARE: f64 = 0.02;

/// The share of the narrow mirror lobe that [`RglWriteOptions::mirror_share`] `None` tries.
pub const MIRROR_SHARE: f64 = 0.1;

/// Roughness (GGX alpha) of the mirror lobe: about 9 degrees wide.
const MIRROR_ALPHA: f64 = 0.15;

/// The share of the source's lobe in the warp that [`RglWriteOptions::lobe_warp`] `None`
/// tries.
pub const WARP_LOBE_SHARE: f64 = 0.9;

/// A refinement is kept only when it brings the check error below this fraction of the
/// previous one.
const REFINE_GAIN: f64 = 0.75;

/// Largest warp-table side that refinement goes to.
const MAX_WARP: usize = 512;

/// The default [`RglWriteOptions::tolerance`]: 5 % check error (the larger of the cos-weighted
/// relative RMS error and the largest relative albedo error, [`RglWriteSummary::check`]).
pub const DEFAULT_TOLERANCE: f64 = 0.05;

/// Incident elevations (degrees) of the albedo check ([`RglWriteSummary::albedo_error`]).
pub const ALBEDO_THETAS_DEG: [f64; 8] = [0.0, 30.0, 50.0, 65.0, 75.0, 82.0, 86.0, 88.0];

/// Direction pairs of the check ([`RglWriteSummary::check_rms`]): 3/4 cosine-distributed,
/// 1/4 within ~3 degrees of the mirror direction.
pub const CHECK_PAIRS: usize = 4096;

/// The luminance table is floored at this fraction of its mean (a sampling density must be
/// positive wherever the BRDF may be).
const LUMINANCE_FLOOR: f64 = 1e-3;

/// Largest incident or retro-reflection elevation (degrees) at which the source is evaluated:
/// the 90-degree slice repeats it (a direction on the horizon has no BRDF value).
pub const MAX_EVAL_THETA_DEG: f64 = 89.5;

/// How finely a written file samples its source.
#[derive(Debug, Clone, PartialEq)]
pub struct RglWriteOptions {
    /// Incident elevations (`theta_i` samples, 0 to 90 degrees), at least 2.
    pub theta_samples: usize,
    /// Side of the `spectra` (or `rgb`) and `luminance` tables: samples of the warped unit
    /// square per incident elevation, at least 2.
    pub resolution: usize,
    /// Side of the `ndf`, `sigma` and `vndf` tables, at least 2.
    pub warp_resolution: usize,
    /// Refinement: while the written file's check error ([`RglWriteSummary::check`], the
    /// larger of [`RglWriteSummary::check_rms`] and [`RglWriteSummary::albedo_error`]) is above
    /// this, the file is written again with twice the incident elevations, twice the value
    /// tables' side (and warp tables of at least 4 times that, up to 512) or both, whichever
    /// cuts the error most, up to `max_theta_samples` and `max_resolution`, as long as a
    /// doubling cuts the error by at least a quarter (otherwise the coarser file is kept);
    /// `None` writes the sizes as they are.
    pub tolerance: Option<f64>,
    /// Most incident elevations that refinement goes to (at least `theta_samples`, at most
    /// 256).
    pub max_theta_samples: usize,
    /// Largest value-table side that refinement goes to (at least `resolution`, at most 256).
    pub max_resolution: usize,
    /// Share of the uniform NDF 1/pi in the file's NDF, in (0, 1]: the rest is the NDF
    /// estimated from the source. The table's points are placed by the NDF: a larger share
    /// puts more of them away from the estimate's peak.
    pub broad_share: f64,
    /// Share of a narrow lobe around the mirror direction (GGX, alpha 0.15) in the file's
    /// NDF, in [0, 1). The warp's density falls as sin theta_m towards the mirror direction, so
    /// for a broad estimated NDF (a diffuse or satin material) the first table column spans
    /// ~15 degrees of half vectors there, and the file ripples by a few percent around the
    /// mirror direction; the lobe puts table points there. `None` writes the file with 0 and
    /// with [`MIRROR_SHARE`] and keeps the one with the smaller check error (measured: it
    /// helps diffuse and satin materials, hurts some RGL satins).
    pub mirror_share: Option<f64>,
    /// Share of the source's own reflected lobe in each incident elevation's warp, in [0, 1]
    /// (the rest is the VNDF of the file's NDF): the table's points then follow the BRDF at
    /// that elevation, e.g. the Fresnel-brightened coat of a car paint at grazing incidence,
    /// which the VNDF alone under-samples (its albedo at 85-88 degrees came out 2-3x too high
    /// at 32^3). `None` tries the plain file, the mirror lobe and this at `WARP_LOBE_SHARE`,
    /// and keeps the best check (measured: it helps clear coats and vinyl a lot, smooth lobes
    /// not at all).
    pub lobe_warp: Option<f64>,
    /// The file's `description` text (also names the source in errors).
    pub description: String,
}

impl Default for RglWriteOptions {
    /// 32 incident elevations, 32 x 32 value tables and 128-sample warps (the RGL database's
    /// files mostly use 8, 32 and 128), refined to [`DEFAULT_TOLERANCE`] up to 64 incident
    /// elevations and 64 x 64 tables (at most ~50 MB for 33 wavelengths); the mirror lobe
    /// chosen by the check (BENCHMARKS.md "brdf-io formats", RGL writer).
    fn default() -> Self {
        Self {
            theta_samples: 32,
            resolution: 32,
            warp_resolution: 128,
            tolerance: Some(DEFAULT_TOLERANCE),
            max_theta_samples: 64,
            max_resolution: 64,
            broad_share: BROAD_SHARE,
            mirror_share: None,
            lobe_warp: None,
            description: String::new(),
        }
    }
}

impl RglWriteOptions {
    /// Checks the sizes (each at least 2, at most 1024; warp tables at most 2^28 values; the
    /// value tables, which also depend on the channels, are checked when written).
    pub fn check(&self) -> Result<()> {
        let bad = |reason: String| Err(Error::InvalidArgument { reason });
        for (name, v) in [
            ("theta samples", self.theta_samples),
            ("resolution", self.resolution),
            ("warp resolution", self.warp_resolution),
        ] {
            if !(2..=1024).contains(&v) {
                return bad(format!("RGL {name} {v} must be in 2..=1024"));
            }
        }
        if !(self.broad_share > 0.0 && self.broad_share <= 1.0) {
            return bad(format!(
                "RGL broad NDF share {} must be in (0, 1]",
                self.broad_share
            ));
        }
        if let Some(w) = self.lobe_warp
            && !(0.0..=1.0).contains(&w)
        {
            return bad(format!("RGL lobe warp share {w} must be in [0, 1]"));
        }
        if let Some(m) = self.mirror_share
            && !(0.0..1.0).contains(&m)
        {
            return bad(format!("RGL mirror lobe share {m} must be in [0, 1)"));
        }
        if let Some(t) = self.tolerance
            && !(t.is_finite() && t > 0.0)
        {
            return bad(format!("RGL tolerance {t} must be finite and > 0"));
        }
        if self.tolerance.is_some() {
            for (name, v, max) in [
                ("resolution", self.resolution, self.max_resolution),
                ("theta samples", self.theta_samples, self.max_theta_samples),
            ] {
                if !(v..=256).contains(&max) {
                    return bad(format!(
                        "RGL maximum {name} {max} must be in {v}..=256 (at least the {name})"
                    ));
                }
            }
        }
        if self.theta_samples * self.warp_resolution * self.warp_resolution > 1 << 28 {
            return bad(format!(
                "RGL tables of {} x {} x {} values are too large",
                self.theta_samples, self.warp_resolution, self.warp_resolution
            ));
        }
        Ok(())
    }
}

/// What writing a file found.
#[derive(Debug, Clone, PartialEq)]
pub struct RglWriteSummary {
    /// Table values (points x channels), including the points whose reflected direction is
    /// below the horizon (not evaluated, stored as 0).
    pub values: usize,
    /// Negative source values stored as 0.
    pub negative_clamped: usize,
    /// Table points whose reflected direction falls below the horizon (stored as 0).
    pub below_horizon: usize,
    /// The written file's error against the source at [`CHECK_PAIRS`] seeded direction pairs:
    /// relative RMS with each value weighted by cos theta_i cos theta_o (as it reaches a
    /// picture).
    pub check_rms: f64,
    /// The written file's largest relative error in directional albedo (luminance) against
    /// the source, over incident elevations [`ALBEDO_THETAS_DEG`] (up to 88 degrees, which
    /// the cos-weighted pairs of `check_rms` hardly see): what a render shows as rims.
    pub albedo_error: f64,
    /// The share of the mirror lobe in the file's NDF ([`RglWriteOptions::mirror_share`]).
    pub mirror_share: f64,
    /// The warp's share of the source's lobe ([`RglWriteOptions::lobe_warp`]).
    pub lobe_warp: f64,
    /// Incident elevations in the file (after refinement).
    pub theta_samples: usize,
    /// The value tables' side in the file (after refinement).
    pub resolution: usize,
    /// The warp tables' side in the file (after refinement).
    pub warp_resolution: usize,
}

impl RglWriteSummary {
    /// The larger of the two check errors, which refinement compares with the tolerance.
    pub fn check(&self) -> f64 {
        self.check_rms.max(self.albedo_error)
    }

    fn empty(theta_samples: usize, resolution: usize, warp_resolution: usize) -> Self {
        Self {
            theta_samples,
            values: 0,
            negative_clamped: 0,
            below_horizon: 0,
            check_rms: f64::NAN,
            albedo_error: f64::NAN,
            mirror_share: 0.0,
            lobe_warp: 0.0,
            resolution,
            warp_resolution,
        }
    }
}

/// Luminance weights of `channels` (summing to 1): Rec. 709 for RGB; for spectra, equal weights
/// over the visible channels (380-780 nm), or over all channels when none is visible. They only
/// shape the sampling density of the `luminance` table.
fn luminance_weights(channels: &Channels) -> Vec<f64> {
    match channels {
        Channels::Rgb => vec![0.2126, 0.7152, 0.0722],
        Channels::Spectral(w) => {
            let visible = w.iter().filter(|&&l| (380.0..=780.0).contains(&l)).count();
            w.iter()
                .map(|&l| {
                    if visible == 0 {
                        1.0 / w.len() as f64
                    } else if (380.0..=780.0).contains(&l) {
                        1.0 / visible as f64
                    } else {
                        0.0
                    }
                })
                .collect()
        }
    }
}

/// `u`'s elevation: the inverse of [`theta2u`].
fn u2theta(u: f64) -> f64 {
    u * u * (PI / 2.0)
}

/// `u`'s azimuth: the inverse of [`phi2u`].
fn u2phi(u: f64) -> f64 {
    (2.0 * u - 1.0) * PI
}

/// `wi` reflected about the unit half vector `m`, and `wi . m` (positive when `m` faces `wi`).
fn reflect(wi: [f64; 3], m: [f64; 3]) -> (f64, [f64; 3]) {
    let dot = wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2];
    (dot, [0, 1, 2].map(|k| 2.0 * dot * m[k] - wi[k]))
}

/// Incident elevation `k` of `n`: cosine-spaced, `acos(1 - k / (n - 1))`, 0 to 90 degrees.
fn theta_i_sample(k: usize, n: usize) -> f64 {
    (1.0 - k as f64 / (n - 1) as f64).clamp(0.0, 1.0).acos()
}

/// Rounds to f32 and back: what a reader of the file sees.
fn stored(v: f64) -> f64 {
    f64::from(v as f32)
}

/// Evaluates `source` at (wi, wo) into `f`, refusing non-finite values.
fn eval_finite(
    source: &dyn BrdfSource,
    name: &str,
    wi: [f64; 3],
    wo: [f64; 3],
    f: &mut [f64],
) -> Result<()> {
    source.eval(wi, wo, f)?;
    if f.iter().any(|v| !v.is_finite()) {
        return Err(Error::NonFiniteValues {
            source_name: name.to_string(),
            count: f.iter().filter(|v| !v.is_finite()).count(),
            values: f.len(),
        });
    }
    Ok(())
}

/// Cells that [`CachedCells::fill`] hints to its source at once, one window ahead of those it
/// evaluates (160 MB of stored values at the paper's 195 wavelengths and 51 materials).
const FILL_WINDOW: usize = 4096;

/// Cells per parallel task of [`CachedCells::fill`].
const FILL_TASK: usize = 64;

/// A grid source ([`BrdfSource::grid`]) whose cells are evaluated once each, when first
/// needed or hinted ([`BrdfSource::will_need_cells`] evaluates them at once, in the order of
/// the file), and interpolated with the grid's stencil (combined by the source's
/// [`BrdfSource::lookup`]): the writer evaluates the source ~10^5
/// times per file, and a lazily predicted material costs N multiply-adds per value per cell,
/// so each lookup would otherwise redo 8 cells' predictions. Equal to the source's own `eval`
/// up to rounding (the trait's contract for grid sources).
struct CachedCells<'a> {
    source: &'a dyn BrdfSource,
    grid: crate::grid::AngularGrid,
    channels: Channels,
    cells: Vec<std::sync::OnceLock<Result<Box<[f64]>>>>,
}

impl<'a> CachedCells<'a> {
    fn new(source: &'a dyn BrdfSource, grid: crate::grid::AngularGrid) -> Self {
        Self {
            source,
            grid,
            channels: source.channels(),
            cells: (0..grid.len())
                .map(|_| std::sync::OnceLock::new())
                .collect(),
        }
    }
}

impl BrdfSource for CachedCells<'_> {
    fn channels(&self) -> Channels {
        self.channels.clone()
    }

    fn eval(&self, wi: [f64; 3], wo: [f64; 3], out: &mut [f64]) -> Result<()> {
        crate::source::check_output_len(out, self.channels.len())?;
        out.fill(0.0);
        let hd = match crate::grid::HalfDiff::from_dirs(wi, wo) {
            Some(hd) if wi[2] > 0.0 && wo[2] > 0.0 => hd,
            _ => return Ok(()),
        };
        let lookup = self.source.lookup();
        let stencil = self.grid.interpolation_stencil(&hd);
        // The cells not yet evaluated, asked for together (a store read from the disk then
        // reads them at once rather than one after another).
        for &(a, w) in &stencil {
            if w != 0.0 {
                self.prefetch_cell(a);
            }
        }
        look_up(lookup, stencil, |a| self.record(a), out)
    }

    fn grid(&self) -> Option<crate::grid::AngularGrid> {
        Some(self.grid)
    }

    fn lookup(&self) -> crate::lookup::Lookup {
        self.source.lookup()
    }

    /// The cell's values, from the cache (evaluated and kept if not yet there).
    fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
        crate::source::check_output_len(out, self.channels.len())?;
        if a >= self.cells.len() {
            return Err(Error::InvalidArgument {
                reason: format!("cell {a} of a grid of {} cells", self.cells.len()),
            });
        }
        out.copy_from_slice(&self.record(a)?[..out.len()]);
        Ok(())
    }

    /// A hint for the source, if the cell is not cached yet.
    fn prefetch_cell(&self, a: usize) {
        if self.uncached(a) {
            self.source.prefetch_cell(a);
        }
    }

    /// Evaluates the cells not cached yet now, into the cache ([`CachedCells::fill`]): the
    /// writer hints each stage's cells before looking them up, so that a source reading a
    /// store from the disk reads them in the file's order rather than as the lookups come.
    fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        self.fill(cells);
    }

    /// The source's: the cache gains nothing from evaluating cells early when they are not
    /// read from a disk.
    fn takes_cell_hints(&self) -> bool {
        self.source.takes_cell_hints()
    }
}

impl CachedCells<'_> {
    /// Whether cell `a` is in the grid and not evaluated yet.
    fn uncached(&self, a: usize) -> bool {
        self.cells.get(a).is_some_and(|c| c.get().is_none())
    }

    /// Evaluates the cells of `cells` not cached yet (each once, an error kept for the lookup
    /// that reads the cell), in ascending order: in windows of [`FILL_WINDOW`] cells, each
    /// hinted to the source ([`BrdfSource::will_need_cells`]) one window ahead and evaluated
    /// in parallel. The next window's hint runs beside this window's evaluation: a store that
    /// takes a hint by reading the cells (direct I/O, see [`crate::store::Store::will_need`])
    /// reads while the cells before are computed.
    fn fill(&self, cells: &mut dyn Iterator<Item = usize>) {
        let mut cells: Vec<usize> = cells.filter(|&a| self.uncached(a)).collect();
        cells.sort_unstable();
        cells.dedup();
        let windows: Vec<&[usize]> = cells.chunks(FILL_WINDOW).collect();
        let hint = |w: usize| {
            if let Some(window) = windows.get(w) {
                self.source.will_need_cells(&mut window.iter().copied());
            }
        };
        hint(0);
        for (w, window) in windows.iter().enumerate() {
            rayon::join(
                || hint(w + 1),
                || {
                    window.par_chunks(FILL_TASK).for_each(|task| {
                        for &a in task {
                            // An error stays in the cache: the lookup of the cell returns it.
                            let _ = self.record(a);
                        }
                    })
                },
            );
        }
    }

    /// Cell `a`'s record ([`cell_record`] under the source's lookup), evaluated once.
    fn record(&self, a: usize) -> Result<&[f64]> {
        let cell = self.cells[a].get_or_init(|| {
            let mut v = vec![0.0; self.channels.len()];
            self.source
                .eval_cell(a, &mut v)
                .map(|()| cell_record(self.source.lookup(), &v))
        });
        match cell {
            Ok(record) => Ok(&record[..]),
            Err(e) => Err(Error::InvalidArgument {
                reason: format!("cell {a} of the source: {e}"),
            }),
        }
    }
}

/// The fields of an isotropic RGL file holding `source` (see the module docs), refined to
/// [`RglWriteOptions::tolerance`], and what writing found (with the check error).
pub fn rgl_fields(
    source: &dyn BrdfSource,
    options: &RglWriteOptions,
) -> Result<(Vec<Field>, RglWriteSummary)> {
    options.check()?;
    with_cached_cells(source, |source| fields_of(source, options))
}

/// `f` of `source` as the writer reads it: a grid source through a cache of its cells
/// ([`CachedCells`], each cell evaluated once), another source as it is.
fn with_cached_cells<T>(source: &dyn BrdfSource, f: impl FnOnce(&dyn BrdfSource) -> T) -> T {
    match source.grid() {
        Some(grid) => f(&CachedCells::new(source, grid)),
        None => f(source),
    }
}

/// [`rgl_fields`] of a source already cached as the writer reads it ([`with_cached_cells`]).
fn fields_of(
    source: &dyn BrdfSource,
    options: &RglWriteOptions,
) -> Result<(Vec<Field>, RglWriteSummary)> {
    // The source's side of the checks, the same for every candidate file: made once, after the
    // first candidate's tables (whose errors come first).
    let reference = std::sync::OnceLock::new();
    let build = |opts: &RglWriteOptions| -> Result<(Vec<Field>, RglWriteSummary)> {
        let (fields, mut summary) = fixed_fields(source, opts)?;
        let file = TensorFile::from_fields(fields, "written.bsdf");
        let bsdf = RglBsdf::from_tensor_file(&file)?;
        let reference = match reference.get() {
            Some(r) => r,
            None => {
                let r = SourceReference::new(source)?;
                reference.get_or_init(|| r)
            }
        };
        summary.check_rms = check_error(&bsdf, reference)?;
        summary.albedo_error = albedo_error(&bsdf, reference)?;
        tracing::info!(
            albedo_error = summary.albedo_error,
            mirror_share = opts.mirror_share,
            lobe_warp = opts.lobe_warp,
            theta_samples = opts.theta_samples,
            resolution = opts.resolution,
            warp = opts.warp_resolution,
            check_rms = summary.check_rms,
            "RGL tables of {}",
            options.description
        );
        Ok((file.into_fields(), summary))
    };
    let mut opts = options.clone();
    // The NDF's mirror lobe and the warp's share of the source's lobe: the given ones, or the
    // plain file and each of the two alone, whichever checks best.
    let shares = |m: Option<f64>, l: Option<f64>| match (m, l) {
        (Some(m), Some(l)) => vec![(m, l)],
        (Some(m), None) => vec![(m, 0.0), (m, WARP_LOBE_SHARE)],
        (None, Some(l)) => vec![(0.0, l), (MIRROR_SHARE, l)],
        (None, None) => vec![(0.0, 0.0), (MIRROR_SHARE, 0.0), (0.0, WARP_LOBE_SHARE)],
    };
    let mut chosen: Option<(RglWriteOptions, (Vec<Field>, RglWriteSummary))> = None;
    for (mirror, lobe) in shares(options.mirror_share, options.lobe_warp) {
        let o = RglWriteOptions {
            mirror_share: Some(mirror),
            lobe_warp: Some(lobe),
            ..opts.clone()
        };
        let built = build(&o)?;
        if chosen
            .as_ref()
            .is_none_or(|(_, (_, s))| built.1.check() < s.check())
        {
            chosen = Some((o, built));
        }
    }
    let (o, mut best) = chosen.expect("at least one candidate");
    opts = o;
    let Some(tolerance) = options.tolerance else {
        return Ok(best);
    };
    // Each step doubles the incident elevations, the value tables' side or both, whichever
    // cuts the error most; a step that does not cut it by a quarter is not worth its size (the
    // error is then the source's own detail), so the coarser file is kept.
    while best.1.check() > tolerance {
        let mut candidates = Vec::new();
        if 2 * opts.theta_samples <= options.max_theta_samples {
            candidates.push(RglWriteOptions {
                theta_samples: 2 * opts.theta_samples,
                ..opts.clone()
            });
        }
        if 2 * opts.resolution <= options.max_resolution {
            candidates.push(RglWriteOptions {
                resolution: 2 * opts.resolution,
                warp_resolution: opts.warp_resolution.max(8 * opts.resolution).min(MAX_WARP),
                ..opts.clone()
            });
        }
        // Some sources need both (an iridescent paint: neither doubling alone gains a quarter).
        if candidates.len() == 2 {
            candidates.push(RglWriteOptions {
                theta_samples: 2 * opts.theta_samples,
                ..candidates[1].clone()
            });
        }
        let mut next: Option<(RglWriteOptions, (Vec<Field>, RglWriteSummary))> = None;
        for c in candidates {
            let built = build(&c)?;
            if next
                .as_ref()
                .is_none_or(|(_, (_, s))| built.1.check() < s.check())
            {
                next = Some((c, built));
            }
        }
        match next {
            Some((c, built)) if built.1.check() <= REFINE_GAIN * best.1.check() => {
                opts = c;
                best = built;
            }
            _ => break,
        }
    }
    Ok(best)
}

/// Most direction pairs that [`hint_slices`] hints at once (48 MB of them).
const HINT_PAIRS: usize = 1 << 20;

/// Hints `source` the cells of the direction pairs that `pairs(k, out)` appends to `out` for
/// each `k` of `0..n` ([`will_need_pairs`]), about [`HINT_PAIRS`] pairs at a time: the
/// writer's cached cells ([`CachedCells`]) then evaluate the cells of a stage in the file's
/// order before its lookups read them. Nothing for a source that is not on a grid or takes no
/// hints ([`BrdfSource::takes_cell_hints`]: a store in memory).
fn hint_slices(
    source: &dyn BrdfSource,
    n: usize,
    pairs: impl Fn(usize, &mut Vec<([f64; 3], [f64; 3])>),
) {
    if source.grid().is_none() || !source.takes_cell_hints() {
        return;
    }
    let mut group = Vec::new();
    for k in 0..n {
        pairs(k, &mut group);
        if group.len() >= HINT_PAIRS || k + 1 == n {
            will_need_pairs(source, &group);
            group.clear();
        }
    }
}

/// Seeded direction pairs of the check: cosine-distributed, and near the mirror direction.
fn check_pairs() -> Vec<([f64; 3], [f64; 3])> {
    let mut state = 0x5eed_u64;
    let mut next = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let cosine = |next: &mut dyn FnMut() -> f64| {
        let (r, phi) = (next().sqrt(), 2.0 * PI * next());
        [r * phi.cos(), r * phi.sin(), (1.0 - r * r).max(1e-4).sqrt()]
    };
    let mut pairs = Vec::with_capacity(CHECK_PAIRS);
    while pairs.len() < CHECK_PAIRS {
        let wi = cosine(&mut next);
        let wo = if pairs.len() % 4 == 3 {
            let (d, phi) = (0.05 * next(), 2.0 * PI * next());
            let v = [-wi[0] + d * phi.cos(), -wi[1] + d * phi.sin(), wi[2]];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            [v[0] / n, v[1] / n, v[2] / n]
        } else {
            cosine(&mut next)
        };
        if wo[2] > 0.01 {
            pairs.push((wi, wo));
        }
    }
    pairs
}

/// What the checks compare a written file with: the source at the check pairs
/// ([`check_error`]) and its directional albedo at [`ALBEDO_THETAS_DEG`] with the quadrature
/// nodes ([`albedo_error`]). The source is the same for every candidate file of a write, so
/// this is evaluated once.
struct SourceReference {
    /// Channels per value.
    nc: usize,
    /// Luminance weights of the channels.
    lum_w: Vec<f64>,
    /// The seeded direction pairs ([`check_pairs`]).
    pairs: Vec<([f64; 3], [f64; 3])>,
    /// The source at `pairs`, clamped at 0, `nc` values per pair.
    pair_values: Vec<f64>,
    /// Per elevation of [`ALBEDO_THETAS_DEG`]: the incident direction, the quadrature's
    /// outgoing directions with their weights, and the source's albedo.
    albedo: Vec<AlbedoReference>,
}

/// One elevation of [`SourceReference::albedo`].
struct AlbedoReference {
    /// The quadrature ([`crate::albedo::AlbedoNodes`] at 96 x 96).
    nodes: AlbedoNodes,
    /// The source's luminance-weighted albedo over `nodes`.
    source: f64,
}

impl SourceReference {
    /// The source at the check pairs and its albedo at each elevation over
    /// [`AlbedoNodes`] (half vectors on a midpoint grid in the format's coordinates).
    fn new(source: &dyn BrdfSource) -> Result<Self> {
        let channels = source.channels();
        let nc = channels.len();
        let lum_w = luminance_weights(&channels);
        let nodes: Vec<AlbedoNodes> = ALBEDO_THETAS_DEG
            .iter()
            .map(|deg| AlbedoNodes::new(deg.to_radians(), crate::albedo::DEFAULT_RESOLUTION))
            .collect();
        let pairs = check_pairs();
        // The cells of both, hinted first (the writer's cache evaluates them in file order).
        hint_slices(source, nodes.len() + 1, |k, out| match nodes.get(k) {
            Some(e) => out.extend(e.nodes().iter().map(|&(wo, _)| (e.wi(), wo))),
            None => out.extend_from_slice(&pairs),
        });
        let albedo = nodes
            .into_par_iter()
            .map(|nodes| {
                let mut g = vec![0.0; nc];
                let mut a_source = 0.0;
                for &(wo, w) in nodes.nodes() {
                    source.eval(nodes.wi(), wo, &mut g)?;
                    for (b, l) in g.iter().zip(&lum_w) {
                        a_source += w * l * b.max(0.0);
                    }
                }
                Ok(AlbedoReference {
                    nodes,
                    source: a_source,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut pair_values = vec![0.0; pairs.len() * nc];
        pair_values
            .par_chunks_mut(256 * nc)
            .zip(pairs.par_chunks(256))
            .try_for_each(|(out, chunk)| {
                for (g, &(wi, wo)) in out.chunks_exact_mut(nc).zip(chunk) {
                    source.eval(wi, wo, g)?;
                    g.iter_mut().for_each(|b| *b = b.max(0.0));
                }
                Ok::<_, Error>(())
            })?;
        Ok(Self {
            nc,
            lum_w,
            pairs,
            pair_values,
            albedo,
        })
    }
}

/// Largest relative error of `file`'s directional albedo (luminance-weighted over the
/// channels) against the source's in `reference`, over [`ALBEDO_THETAS_DEG`]. Both are
/// integrated over the same
/// nodes in half-vector space: wo = the reflection of wi about m, dwo = 4 (wi . m) dm, with m
/// on a midpoint grid in the format's coordinates (u = sqrt(2 theta_m / pi), phi_m), whose
/// nodes crowd towards the mirror direction (the first ring's m is 0.0024 degrees from the
/// normal, its wo 0.0049 degrees from the mirror direction), so a sharp
/// lobe is integrated as well as a broad one. Errors are relative to the largest albedo over
/// the elevations when an albedo is below a thousandth of it (a black material does not
/// divide by 0).
fn albedo_error(file: &RglBsdf, reference: &SourceReference) -> Result<f64> {
    let albedos = reference
        .albedo
        .par_iter()
        .map(|e| {
            let mut f = vec![0.0; reference.nc];
            let mut a_file = 0.0;
            for &(wo, w) in e.nodes.nodes() {
                file.eval(e.nodes.wi(), wo, &mut f)?;
                for (a, l) in f.iter().zip(&reference.lum_w) {
                    a_file += w * l * a;
                }
            }
            Ok((a_file, e.source))
        })
        .collect::<Result<Vec<(f64, f64)>>>()?;
    let largest = albedos.iter().map(|a| a.1).fold(0.0, f64::max);
    Ok(albedos
        .iter()
        .map(|(a, b)| {
            let scale = b.max(1e-3 * largest);
            if scale > 0.0 {
                (a - b).abs() / scale
            } else {
                0.0
            }
        })
        .fold(0.0, f64::max))
}

/// Relative RMS error of `file` against the source over the check pairs, each value weighted
/// by cos theta_i cos theta_o (0 when the source is 0 everywhere and so is the file).
fn check_error(file: &RglBsdf, reference: &SourceReference) -> Result<f64> {
    let nc = reference.nc;
    let (num, den) = reference
        .pairs
        .par_chunks(256)
        .zip(reference.pair_values.par_chunks(256 * nc))
        .map(|(chunk, values)| {
            let mut f = vec![0.0; nc];
            let (mut num, mut den) = (0.0, 0.0);
            for (&(wi, wo), g) in chunk.iter().zip(values.chunks_exact(nc)) {
                file.eval(wi, wo, &mut f)?;
                let w = wi[2] * wo[2];
                for (a, &b) in f.iter().zip(g) {
                    num += (w * (a - b)).powi(2);
                    den += (w * b).powi(2);
                }
            }
            Ok((num, den))
        })
        .collect::<Result<Vec<(f64, f64)>>>()?
        .into_iter()
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    Ok(if den > 0.0 {
        (num / den).sqrt()
    } else if num > 0.0 {
        f64::INFINITY
    } else {
        0.0
    })
}

/// [`rgl_fields`] at the options' resolutions, without the check.
fn fixed_fields(
    source: &dyn BrdfSource,
    options: &RglWriteOptions,
) -> Result<(Vec<Field>, RglWriteSummary)> {
    let name = if options.description.is_empty() {
        "source"
    } else {
        options.description.as_str()
    };
    let channels = source.channels();
    let nc = channels.len();
    let table = [
        options.theta_samples,
        nc,
        options.resolution,
        options.resolution,
    ];
    if table
        .iter()
        .try_fold(1usize, |a, &b| a.checked_mul(b))
        .is_none_or(|v| v > 1 << 28)
    {
        return Err(Error::InvalidArgument {
            reason: format!(
                "{name}: RGL value tables of {} x {} x {} x {} values are too large (at most \
                 2^28, 1 GiB of f32)",
                table[0], table[1], table[2], table[3]
            ),
        });
    }
    let lum_w = luminance_weights(&channels);
    let lum = |f: &[f64]| {
        f.iter()
            .zip(&lum_w)
            .map(|(v, w)| w * v.max(0.0))
            .sum::<f64>()
    };
    let (nw, res, nt) = (
        options.warp_resolution,
        options.resolution,
        options.theta_samples,
    );
    let max_theta = MAX_EVAL_THETA_DEG.to_radians();
    let u_at = |k: usize, n: usize| k as f64 / (n - 1) as f64;

    // 1. NDF from the retro-reflection, over u = sqrt(2 theta / pi).
    let retro = |k: usize| {
        let theta = u2theta(u_at(k, nw)).min(max_theta);
        (theta, direction(theta, 0.0))
    };
    hint_slices(source, nw, |k, pairs| {
        let w = retro(k).1;
        pairs.push((w, w));
    });
    let mut ndf = (0..nw)
        .map(|k| {
            let (theta, w) = retro(k);
            let mut f = vec![0.0; nc];
            eval_finite(source, name, w, w, &mut f)?;
            Ok(lum(&f) * theta.cos().powi(2))
        })
        .collect::<Result<Vec<f64>>>()?;
    // Normalise: 2 pi int D cos(theta) sin(theta) dtheta = 1, theta = u^2 pi / 2, dtheta = pi u du
    // (trapezoid in u over the table's nodes); then mix in the uniform NDF 1/pi.
    let integral = {
        let integrand = |k: usize| {
            let u = u_at(k, nw);
            let t = u2theta(u);
            ndf[k] * t.cos() * t.sin() * PI * u
        };
        2.0 * PI / (nw - 1) as f64
            * (0..nw - 1)
                .map(|k| 0.5 * (integrand(k) + integrand(k + 1)))
                .sum::<f64>()
    };
    // Shares: the estimate (when it is usable), the mirror lobe, the uniform NDF.
    let mirror = options.mirror_share.unwrap_or(0.0);
    let usable = integral > 0.0 && integral.is_finite();
    let w_estimate = if usable {
        (1.0 - options.broad_share) * (1.0 - mirror)
    } else {
        0.0
    };
    let w_mirror = if usable {
        (1.0 - options.broad_share) * mirror
    } else {
        0.0
    };
    let a2 = MIRROR_ALPHA * MIRROR_ALPHA;
    for (k, d) in ndf.iter_mut().enumerate() {
        // GGX, normalised: the integral of D cos theta_m is 1.
        let c = u2theta(u_at(k, nw)).cos();
        let lobe = a2 / (PI * (c * c * (a2 - 1.0) + 1.0).powi(2));
        *d = stored(
            w_estimate * *d / integral.max(f64::MIN_POSITIVE)
                + w_mirror * lobe
                + (1.0 - w_estimate - w_mirror) / PI,
        );
    }
    let ndf_table = Table2D {
        w: nw,
        h: 2,
        data: [ndf.as_slice(), ndf.as_slice()].concat(),
    };
    let d_at = |u: f64| ndf_table.eval([u, 0.0]);

    // 2. sigma(theta_i) by a midpoint rule over (u_m, phi_m), symmetric in phi_m.
    // The nodes' sines and cosines do not depend on theta_i: computed once (m = direction(tm,
    // phi) = [sin tm cos phi, sin tm sin phi, cos tm], of which wi, in the xz plane, needs x, z).
    const SIGMA_NODES: usize = 256;
    let cos_phi: Vec<f64> = (0..SIGMA_NODES / 2)
        .map(|b| ((b as f64 + 0.5) / SIGMA_NODES as f64 * 2.0 * PI - PI).cos())
        .collect();
    // Per u_m node: sin tm, cos tm, the Jacobian, D.
    let rings: Vec<[f64; 4]> = (0..SIGMA_NODES)
        .map(|a| {
            let u = (a as f64 + 0.5) / SIGMA_NODES as f64;
            let tm = u2theta(u);
            let (st, ct) = tm.sin_cos();
            [
                st,
                ct,
                2.0 * PI * PI * u * tm.sin() / SIGMA_NODES as f64,
                d_at(u),
            ]
        })
        .collect();
    let sigma: Vec<f64> = (0..nw)
        .into_par_iter()
        .map(|k| {
            let ti = u2theta(u_at(k, nw));
            let wi = direction(ti, 0.0);
            let mut acc = 0.0;
            for &[st, ct, jac, d] in &rings {
                for cp in &cos_phi {
                    let c = (wi[0] * (st * cp) + wi[2] * ct).max(0.0);
                    acc += 2.0 * d * c * jac / SIGMA_NODES as f64;
                }
            }
            stored(acc)
        })
        .collect();
    let sigma_table = Table2D {
        w: nw,
        h: 2,
        data: [sigma.as_slice(), sigma.as_slice()].concat(),
    };

    // 3. The VNDF warp's density per incident elevation (its rows are u_phi, columns u_theta).
    let theta_i: Vec<f32> = (0..nt).map(|k| theta_i_sample(k, nt) as f32).collect();
    let eval_theta = |k: usize| f64::from(theta_i[k]).min(max_theta);
    // Per slice: the table, and the sums and share that make its density
    // (1 - w) geo / sum_geo + w lobe / sum_lobe (for the luminance table below).
    let lobe_share = options.lobe_warp.unwrap_or(0.0);
    // The half vectors of the table do not depend on theta_i: computed once (as `direction`
    // does), with each column's D and Jacobian.
    let row_phi: Vec<(f64, f64)> = (0..nw)
        .map(|row| {
            let phi = u2phi(u_at(row, nw));
            (phi.cos(), phi.sin())
        })
        .collect();
    let col_theta: Vec<[f64; 4]> = (0..nw)
        .map(|col| {
            let u = u_at(col, nw);
            let tm = u2theta(u);
            let (st, ct) = tm.sin_cos();
            [st, ct, u * tm.sin(), d_at(u)]
        })
        .collect();
    // `wi` reflected about the half vector of the warp table's (row, col): (wi . m, wo).
    let warp_point = |wi: [f64; 3], row: usize, col: usize| {
        let ((cp, sp), [st, ct, ..]) = (row_phi[row], col_theta[col]);
        reflect(wi, [st * cp, st * sp, ct])
    };
    if lobe_share > 0.0 {
        hint_slices(source, nt, |k, pairs| {
            let wi = direction(eval_theta(k), 0.0);
            for (row, col) in (0..nw).flat_map(|row| (0..nw).map(move |col| (row, col))) {
                let (dot, wo) = warp_point(wi, row, col);
                if dot > 0.0 && wo[2] > 0.0 {
                    pairs.push((wi, wo));
                }
            }
        });
    }
    let warps: Vec<(Vec<f32>, [f64; 3])> = (0..nt)
        .into_par_iter()
        .map(|k| -> Result<(Vec<f32>, [f64; 3])> {
            let wi = direction(eval_theta(k), 0.0);
            let mut geo = vec![0.0f64; nw * nw];
            let mut lobe = vec![0.0f64; nw * nw];
            let mut f = vec![0.0; nc];
            for row in 0..nw {
                for (col, &[.., jac, d]) in col_theta.iter().enumerate() {
                    let (dot, wo) = warp_point(wi, row, col);
                    let c = dot.max(0.0);
                    geo[row * nw + col] = d * c * jac;
                    if lobe_share > 0.0 && c > 0.0 && wo[2] > 0.0 {
                        eval_finite(source, name, wi, wo, &mut f)?;
                        lobe[row * nw + col] = lum(&f) * wo[2] * 4.0 * c * jac;
                    }
                }
            }
            let (sg, sl) = (geo.iter().sum::<f64>(), lobe.iter().sum::<f64>());
            let wl = if sl > 0.0 && sl.is_finite() {
                lobe_share
            } else {
                0.0
            };
            let table = geo
                .iter()
                .zip(&lobe)
                .map(|(g, l)| {
                    let lobe = if wl > 0.0 { wl * l / sl } else { 0.0 };
                    ((1.0 - wl) * g / sg + lobe) as f32
                })
                .collect();
            Ok((table, [sg, sl, wl]))
        })
        .collect::<Result<Vec<_>>>()?;
    let mixture: Vec<[f64; 3]> = warps.iter().map(|w| w.1).collect();
    let vndf: Vec<f32> = warps.into_iter().flat_map(|w| w.0).collect();
    let vndf64: Vec<f64> = vndf.iter().map(|&v| f64::from(v)).collect();
    let warp = Warp::new(&vndf64, nt, nw, nw, Path::new(name))?;

    // 4. The values on the regular grid of each warped square; 5. their luminance.
    // Slice k's corners of the warp, and the point of its row's `u_y` and column `col`: the
    // warped square's coordinates u, wi reflected about their half vector (wi . m, wo), D.
    let corners = |k: usize| Corners::new((0, 0.0), (k, 0.0), 0, 1);
    let row_u = |row: usize, c: &Corners| warp.forward_y(u_at(row, res), c);
    let table_point = |wi: [f64; 3], c: &Corners, u_y: f64, col: usize| {
        let u = [warp.forward_x(u_at(col, res), u_y, c), u_y];
        let (dot, wo) = reflect(wi, direction(u2theta(u[0]), u2phi(u[1])));
        (u, dot, wo, d_at(u[0]))
    };
    hint_slices(source, nt, |k, pairs| {
        let (wi, c) = (direction(eval_theta(k), 0.0), corners(k));
        for row in 0..res {
            let u_y = row_u(row, &c);
            for col in 0..res {
                let (_, dot, wo, d) = table_point(wi, &c, u_y, col);
                if dot > 0.0 && wo[2] > 0.0 && d > 0.0 {
                    pairs.push((wi, wo));
                }
            }
        }
    });
    let slices = (0..nt)
        .into_par_iter()
        .map(|k| {
            let ti = eval_theta(k);
            let wi = direction(ti, 0.0);
            let scale = 4.0 * sigma_table.eval([theta2u(ti), phi2u(0.0)]);
            let c = corners(k);
            let [sum_geo, sum_lobe, w_lobe] = mixture[k];
            let mut values = vec![0.0f32; nc * res * res];
            let mut lum_slice = vec![0.0f64; res * res];
            let mut f = vec![0.0; nc];
            let mut summary = RglWriteSummary::empty(nt, res, nw);
            for row in 0..res {
                let u_y = row_u(row, &c);
                for col in 0..res {
                    let (u, dot, wo, d) = table_point(wi, &c, u_y, col);
                    summary.values += nc;
                    if !(dot > 0.0 && wo[2] > 0.0 && d > 0.0) {
                        summary.below_horizon += 1;
                        continue;
                    }
                    eval_finite(source, name, wi, wo, &mut f)?;
                    let k_point = wo[2] * scale / d;
                    for (ch, v) in f.iter().enumerate() {
                        if *v < 0.0 {
                            summary.negative_clamped += 1;
                        }
                        values[(ch * res + row) * res + col] = (v.max(0.0) * k_point) as f32;
                    }
                    // Sampling density wanted in the half-vector square: the reflected luminance
                    // (with the Jacobians of reflection and of the coordinates); the warp
                    // provides the density p_w, so the luminance table is their ratio.
                    let jac = u[0] * u2theta(u[0]).sin();
                    let lobe = lum(&f) * wo[2] * 4.0 * dot * jac;
                    let p_w = (1.0 - w_lobe) * d * dot * jac / sum_geo
                        + if w_lobe > 0.0 {
                            w_lobe * lobe / sum_lobe
                        } else {
                            0.0
                        };
                    lum_slice[row * res + col] = if p_w > 0.0 { lobe / p_w } else { 0.0 };
                }
            }
            let mean = lum_slice.iter().sum::<f64>() / lum_slice.len() as f64;
            let lum_slice: Vec<f32> = if mean > 0.0 && mean.is_finite() {
                lum_slice
                    .iter()
                    .map(|&l| l.max(LUMINANCE_FLOOR * mean) as f32)
                    .collect()
            } else {
                vec![1.0; res * res]
            };
            Ok((values, lum_slice, summary))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut summary = RglWriteSummary::empty(nt, res, nw);
    summary.mirror_share = mirror;
    summary.lobe_warp = lobe_share;
    let (mut values, mut luminance) = (Vec::new(), Vec::new());
    for (v, l, s) in slices {
        values.extend(v);
        luminance.extend(l);
        summary.values += s.values;
        summary.negative_clamped += s.negative_clamped;
        summary.below_horizon += s.below_horizon;
    }
    // A finite source value times 4 sigma / D can leave f32's range (a MERL file of 1e300s):
    // the file would hold infinities that renderers turn into white or NaN pixels.
    let overflow = values.iter().filter(|v| !v.is_finite()).count()
        + luminance.iter().filter(|v| !v.is_finite()).count();
    if overflow > 0 {
        return Err(Error::InvalidArgument {
            reason: format!(
                "{name}: {overflow} table values exceed the f32 range of an RGL file (above \
                 3.4e38: the source's values are too large)"
            ),
        });
    }
    let as_f32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let mut fields = vec![
        Field::from_u8(
            "description",
            vec![options.description.len()],
            options.description.as_bytes(),
        )?,
        Field::from_f32("phi_i", vec![1], &[0.0])?,
        Field::from_f32("theta_i", vec![nt], &theta_i)?,
        Field::from_f32("ndf", vec![2, nw], &as_f32(&ndf_table.data))?,
        Field::from_f32("sigma", vec![2, nw], &as_f32(&sigma_table.data))?,
        Field::from_f32("vndf", vec![1, nt, nw, nw], &vndf)?,
        Field::from_f32("luminance", vec![1, nt, res, res], &luminance)?,
        Field::from_u8("jacobian", vec![1], &[1])?,
    ];
    match &channels {
        Channels::Spectral(w) => {
            fields.push(Field::from_f32(
                "spectra",
                vec![1, nt, nc, res, res],
                &values,
            )?);
            fields.push(Field::from_f32("wavelengths", vec![nc], &as_f32(w))?);
        }
        Channels::Rgb => fields.push(Field::from_f32("rgb", vec![1, nt, 3, res, res], &values)?),
    }
    Ok((fields, summary))
}

/// Writes `source` as an isotropic RGL `.bsdf` file at `path` (see the module docs), through a
/// temporary file renamed into place.
pub fn write_rgl(
    source: &dyn BrdfSource,
    path: impl AsRef<Path>,
    options: &RglWriteOptions,
) -> Result<RglWriteSummary> {
    write_rgl_then(source, path, options, |_| ()).map(|(summary, ())| summary)
}

/// [`write_rgl`], then `after` of the source as the writer read it, with what `after`
/// returns: a grid source's cells evaluated for the file are not evaluated again (the writer
/// keeps them; e.g. the energy check of `specgp predict --out X.bsdf` reads most of the same
/// cells: at the paper's grid, a prediction read them from the disk twice); `after` sees the
/// same values, channels, grid and lookup as the source's own (a cached grid source equals
/// the source up to rounding in `eval`, and bit for bit in `eval_cell`). `after` runs only
/// once the file is written.
pub fn write_rgl_then<T>(
    source: &dyn BrdfSource,
    path: impl AsRef<Path>,
    options: &RglWriteOptions,
    after: impl FnOnce(&dyn BrdfSource) -> T,
) -> Result<(RglWriteSummary, T)> {
    options.check()?;
    with_cached_cells(source, |source| {
        let (fields, summary) = fields_of(source, options)?;
        TensorFile::write(path, &fields)?;
        Ok((summary, after(source)))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Vec3;
    use crate::lookup::Lookup;
    use crate::rgl::RglBsdf;

    /// A spectral Lambertian plus a GGX lobe (roughness `alpha`) with a colour that varies
    /// with wavelength; `offset` is added to every value (negative: an undershooting
    /// prediction).
    struct Analytic {
        channels: Channels,
        alpha: f64,
        offset: f64,
    }

    impl Analytic {
        fn new(alpha: f64) -> Self {
            Self {
                channels: Channels::spectral(vec![450.0, 550.0, 650.0, 900.0]).unwrap(),
                alpha,
                offset: 0.0,
            }
        }
    }

    impl BrdfSource for Analytic {
        fn channels(&self) -> Channels {
            self.channels.clone()
        }

        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
            out.fill(0.0);
            if wi[2] <= 0.0 || wo[2] <= 0.0 {
                return Ok(());
            }
            let h = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
            let n = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
            let c = h[2] / n;
            let a2 = self.alpha * self.alpha;
            let d = a2 / (PI * (c * c * (a2 - 1.0) + 1.0).powi(2));
            let spec = d / (4.0 * wi[2] * wo[2]);
            for (k, o) in out.iter_mut().enumerate() {
                let kd = [0.6, 0.3, 0.1, 0.5][k % 4];
                let ks = [0.04, 0.05, 0.08, 0.1][k % 4];
                *o = kd / PI + ks * spec + self.offset;
            }
            Ok(())
        }
    }

    fn written(source: &dyn BrdfSource, options: &RglWriteOptions) -> (RglBsdf, RglWriteSummary) {
        let (fields, summary) = rgl_fields(source, options).unwrap();
        let bytes = TensorFile::to_bytes(&fields).unwrap();
        let tf = TensorFile::from_bytes(&bytes, "written.bsdf").unwrap();
        (RglBsdf::from_tensor_file(&tf).unwrap(), summary)
    }

    /// The Euclidean length of `v`.
    fn norm(v: Vec3) -> f64 {
        (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
    }

    /// An RGB source with the value `f(wi, wo)` in every channel above the horizon, 0 below.
    struct Grey<F>(F);

    impl<F: Fn(Vec3, Vec3) -> f64 + Sync> BrdfSource for Grey<F> {
        fn channels(&self) -> Channels {
            Channels::Rgb
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
            out.fill(if wi[2] > 0.0 && wo[2] > 0.0 {
                (self.0)(wi, wo)
            } else {
                0.0
            });
            Ok(())
        }
    }

    /// Options that write the sizes given as they are (no refinement), with neither the
    /// mirror lobe nor the source's lobe in the warp.
    fn fixed_sizes(
        theta_samples: usize,
        resolution: usize,
        warp_resolution: usize,
    ) -> RglWriteOptions {
        RglWriteOptions {
            theta_samples,
            resolution,
            warp_resolution,
            tolerance: None,
            mirror_share: Some(0.0),
            lobe_warp: Some(0.0),
            ..RglWriteOptions::default()
        }
    }

    /// Node `k` of `n` of a table's axis in the format's coordinates, 0 to 1.
    fn node(k: usize, n: usize) -> f64 {
        k as f64 / (n - 1) as f64
    }

    /// The values of the written field `name`.
    fn values_of(fields: &[Field], name: &str) -> Vec<f64> {
        let field = fields.iter().find(|f| f.name() == name).unwrap();
        field.to_f64(Path::new(name)).unwrap()
    }

    /// A seeded direction above the horizon, cosine-distributed.
    fn random_dir(state: &mut u64) -> Vec3 {
        let mut next = || {
            *state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (*state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (r, phi) = (next().sqrt(), 2.0 * PI * next());
        [r * phi.cos(), r * phi.sin(), (1.0 - r * r).max(1e-6).sqrt()]
    }

    /// At every stored point of every slice below the evaluation limit, the written file
    /// evaluates to the source's value (f32 tables: 1e-5 relative).
    #[test]
    fn reproduces_its_source_at_the_stored_points() {
        let source = Analytic::new(0.15);
        let options = RglWriteOptions {
            theta_samples: 6,
            resolution: 12,
            warp_resolution: 64,
            tolerance: None,
            description: "analytic".into(),
            ..RglWriteOptions::default()
        };
        let (bsdf, summary) = written(&source, &options);
        assert!(
            summary.check_rms > 0.0 && summary.check_rms < 0.5,
            "{summary:?}"
        );
        assert_eq!(bsdf.description(), "analytic");
        assert_eq!(bsdf.channels(), source.channels);
        assert_eq!(summary.values, 6 * 12 * 12 * 4);
        assert_eq!(summary.negative_clamped, 0);
        let (mut f, mut g) = ([0.0; 4], [0.0; 4]);
        let mut checked = 0;
        for k in 0..options.theta_samples - 1 {
            let ti = f64::from(bsdf.theta_i[k] as f32);
            let wi = direction(ti, 0.0);
            let c = Corners::new((0, 0.0), (k, 0.0), 0, 1);
            for row in 0..options.resolution {
                for col in 0..options.resolution {
                    let n = (options.resolution - 1) as f64;
                    let u_y = bsdf.vndf.forward_y(row as f64 / n, &c);
                    let u = [bsdf.vndf.forward_x(col as f64 / n, u_y, &c), u_y];
                    let m = direction(u2theta(u[0]), u2phi(u[1]));
                    let (_, wo) = reflect(wi, m);
                    if wo[2] < 1e-3 {
                        continue;
                    }
                    bsdf.eval(wi, wo, &mut f).unwrap();
                    source.eval(wi, wo, &mut g).unwrap();
                    for ch in 0..4 {
                        let rel = (f[ch] - g[ch]).abs() / g[ch];
                        assert!(
                            rel < 1e-5,
                            "slice {k}, point ({row}, {col}), channel {ch}: file {} source {} \
                             (rel {rel:e})",
                            f[ch],
                            g[ch]
                        );
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 400, "{checked} points checked");
    }

    /// Relative RMS error of `bsdf` against `source` over seeded direction pairs (each value
    /// weighted by cos theta_i cos theta_o, as it reaches a picture).
    fn rms_error(bsdf: &RglBsdf, source: &dyn BrdfSource) -> f64 {
        let mut state = 7;
        let (mut f, mut g) = ([0.0; 4], [0.0; 4]);
        let (mut num, mut den) = (0.0, 0.0);
        for _ in 0..4000 {
            let (wi, wo) = (random_dir(&mut state), random_dir(&mut state));
            bsdf.eval(wi, wo, &mut f).unwrap();
            source.eval(wi, wo, &mut g).unwrap();
            let w = wi[2] * wo[2];
            for ch in 0..4 {
                num += w * w * (f[ch] - g[ch]).powi(2);
                den += w * w * g[ch].powi(2);
            }
        }
        (num / den).sqrt()
    }

    /// Between the stored points the file interpolates: a glossy lobe is reproduced within a
    /// few percent at the default resolution, and finer tables are more accurate.
    #[test]
    fn interpolates_its_source_and_converges_with_resolution() {
        let source = Analytic::new(0.2);
        let coarse = RglWriteOptions {
            theta_samples: 6,
            resolution: 8,
            warp_resolution: 64,
            tolerance: None,
            ..RglWriteOptions::default()
        };
        let (bsdf, coarse) = written(&source, &coarse);
        let e_coarse = rms_error(&bsdf, &source);
        let (bsdf, default) = written(&source, &RglWriteOptions::default());
        let e_default = rms_error(&bsdf, &source);
        eprintln!(
            "relative RMS error: coarse {e_coarse:.4} (check {:.4}), default {e_default:.4} \
             (check {:.4})",
            coarse.check_rms, default.check_rms
        );
        assert!(e_default < 0.02, "default tables: {e_default}");
        assert!(e_default < 0.5 * e_coarse, "{e_default} vs {e_coarse}");
        // The writer's own check tells the same story; it is stricter (a quarter of its
        // pairs are near the mirror direction, where a lobe is hardest to interpolate).
        assert!(
            coarse.check_rms > 10.0 * default.check_rms,
            "{coarse:?} {default:?}"
        );
        // (Measured: 5.1x on the coarse file, 1.4x on the default one.)
        for (check, test) in [(coarse.check_rms, e_coarse), (default.check_rms, e_default)] {
            assert!(check > test && check < 8.0 * test, "{check} vs {test}");
        }
    }

    /// The albedo check measures relative albedo errors: a file against itself scaled by 1.1
    /// is 1/11 off at every elevation, against itself 0. Where the source's albedo is below a
    /// thousandth of its largest (here 0, black at normal incidence), the error is relative
    /// to that thousandth.
    #[test]
    fn the_albedo_check_measures_relative_albedo_errors() {
        /// The file scaled by a factor that depends on the incident direction.
        struct Scaled<'a>(&'a RglBsdf, fn(Vec3) -> f64);
        impl BrdfSource for Scaled<'_> {
            fn channels(&self) -> Channels {
                self.0.channels()
            }
            fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
                self.0.eval(wi, wo, out)?;
                out.iter_mut().for_each(|v| *v *= (self.1)(wi));
                Ok(())
            }
        }
        let (bsdf, summary) = written(&Analytic::new(0.2), &RglWriteOptions::default());
        assert!(summary.albedo_error < 0.02, "{summary:?}");
        let itself = SourceReference::new(&Scaled(&bsdf, |_| 1.0)).unwrap();
        assert_eq!(albedo_error(&bsdf, &itself).unwrap(), 0.0);
        let e = albedo_error(
            &bsdf,
            &SourceReference::new(&Scaled(&bsdf, |_| 1.1)).unwrap(),
        )
        .unwrap();
        assert!((e - 0.1 / 1.1).abs() < 1e-12, "{e}");

        assert_eq!(ALBEDO_THETAS_DEG[0], 0.0);
        let albedos: Vec<f64> = itself.albedo.iter().map(|a| a.source).collect();
        let largest = albedos[1..].iter().copied().fold(0.0, f64::max);
        // Away from 1, so that a thousandth of it differs from a thousandth over it.
        assert!(largest > 0.0 && (largest - 1.0).abs() > 0.05, "{albedos:?}");
        let black_at_normal = |wi: Vec3| if wi[2] == 1.0 { 0.0 } else { 1.0 };
        let reference = SourceReference::new(&Scaled(&bsdf, black_at_normal)).unwrap();
        assert_eq!(reference.albedo[0].source, 0.0);
        let e = albedo_error(&bsdf, &reference).unwrap();
        let expected = albedos[0] / (1e-3 * largest);
        assert!((e - expected).abs() <= 1e-9 * expected, "{e} vs {expected}");
    }

    /// The check's relative error has no scale for a black source: 0 when the file is black
    /// too, infinite when it is not.
    #[test]
    fn the_check_error_of_a_black_source() {
        let black = Grey(|_: Vec3, _: Vec3| 0.0);
        let reference = SourceReference::new(&black).unwrap();
        let options = fixed_sizes(4, 8, 8);
        let (black_file, _) = written(&black, &options);
        assert_eq!(check_error(&black_file, &reference).unwrap(), 0.0);
        let (grey_file, _) = written(&Grey(|_: Vec3, _: Vec3| 0.1), &options);
        assert_eq!(check_error(&grey_file, &reference).unwrap(), f64::INFINITY);
    }

    /// A broad material's file ripples around the mirror direction unless the NDF holds the
    /// mirror lobe; the writer tries both and keeps the one that checks better.
    #[test]
    fn the_mirror_lobe_is_chosen_when_it_checks_better() {
        let mut source = Analytic::new(0.5);
        source.offset = 0.0;
        let at = |share: Option<f64>| {
            written(
                &source,
                &RglWriteOptions {
                    mirror_share: share,
                    lobe_warp: Some(0.0),
                    tolerance: None,
                    ..RglWriteOptions::default()
                },
            )
        };
        let (without, s0) = at(Some(0.0));
        let (with, s1) = at(Some(MIRROR_SHARE));
        let (_, chosen) = at(None);
        // Largest deviation along a sweep of wo through the mirror direction of wi at 22.5
        // degrees, in the plane of incidence.
        let sweep = |bsdf: &RglBsdf| {
            let ti = 22.5f64.to_radians();
            let wi = direction(ti, 0.0);
            let (mut f, mut g) = ([0.0; 4], [0.0; 4]);
            (-150..=150)
                .map(|k| {
                    let wo = direction(ti + (k as f64 * 0.1).to_radians(), PI);
                    bsdf.eval(wi, wo, &mut f).unwrap();
                    source.eval(wi, wo, &mut g).unwrap();
                    ((f[1] - g[1]) / g[1]).abs()
                })
                .fold(0.0, f64::max)
        };
        let (r0, r1) = (sweep(&without), sweep(&with));
        eprintln!(
            "ripple {r0:.4} -> {r1:.4}; check {} -> {}",
            s0.check_rms, s1.check_rms
        );
        assert!(r1 < 0.5 * r0, "{r0} {r1}");
        assert!(s1.check_rms < s0.check_rms, "{s0:?} {s1:?}");
        // The writer keeps the file with the smaller check (the larger of its two errors).
        let better = if s1.check() < s0.check() { &s1 } else { &s0 };
        assert_eq!(chosen.mirror_share, better.mirror_share);
        assert_eq!(chosen.check(), better.check());
    }

    /// A sharp lobe written at a coarse size misses the tolerance; refinement doubles the
    /// incident elevations or the tables until it is met (or stops improving) and says so.
    #[test]
    fn refinement_meets_the_tolerance_on_a_sharp_lobe() {
        let source = Analytic::new(0.03);
        let start = RglWriteOptions {
            theta_samples: 8,
            resolution: 8,
            tolerance: None,
            ..RglWriteOptions::default()
        };
        let (_, fixed) = written(&source, &start);
        let (bsdf, refined) = written(
            &source,
            &RglWriteOptions {
                tolerance: Some(0.05),
                ..start.clone()
            },
        );
        eprintln!("{fixed:?}\n{refined:?}");
        assert!(fixed.check_rms > 0.05, "{fixed:?}");
        assert!(
            refined.theta_samples * refined.resolution > 64,
            "{refined:?}"
        );
        assert!(refined.check_rms < 0.75 * fixed.check_rms, "{refined:?}");
        assert!(
            refined.check_rms <= 0.05 || refined.resolution == 128,
            "{refined:?}"
        );
        assert_eq!(bsdf.theta_i.len(), refined.theta_samples);
        assert_eq!(bsdf.spec_w, refined.resolution);
        assert!((rms_error(&bsdf, &source) - refined.check_rms).abs() < refined.check_rms);
    }

    /// The evaluator takes directions of any finite length: a wi shorter than ~1e-154 (its
    /// squared norm underflows) was refused ("directions must be finite and non-zero").
    #[test]
    fn evaluation_takes_directions_of_any_finite_length() {
        let options = RglWriteOptions {
            theta_samples: 4,
            resolution: 8,
            warp_resolution: 16,
            tolerance: None,
            ..RglWriteOptions::default()
        };
        let (bsdf, _) = written(&Analytic::new(0.3), &options);
        let (wi, wo) = ([0.0, 0.6, 0.8], [0.3, -0.4, 0.75f64.sqrt()]);
        let (mut want, mut got) = ([0.0; 4], [0.0; 4]);
        bsdf.eval(wi, wo, &mut want).unwrap();
        for s in [1e-170, 1e-300, 1e170, 1e300] {
            bsdf.eval(wi.map(|v| v * s), wo, &mut got).unwrap();
            for (a, b) in got.iter().zip(&want) {
                assert!((a - b).abs() <= 1e-12 * b, "{s:e}: {got:?} vs {want:?}");
            }
        }
        assert!(bsdf.eval([0.0; 3], wo, &mut got).is_err());
        assert!(bsdf.eval([f64::NAN, 0.0, 1.0], wo, &mut got).is_err());
    }

    /// RGB sources are written as `rgb` tables; negative values are stored as 0 and counted;
    /// bad sizes and non-finite values are errors naming the source.
    #[test]
    fn rgb_negative_and_bad_inputs() {
        struct Rgb(f64);
        impl BrdfSource for Rgb {
            fn channels(&self) -> Channels {
                Channels::Rgb
            }
            fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
                let up = wi[2] > 0.0 && wo[2] > 0.0;
                out.copy_from_slice(&[0.5, 0.25, self.0].map(|v| if up { v } else { 0.0 }));
                Ok(())
            }
        }
        let options = RglWriteOptions {
            description: "rgb test".into(),
            ..RglWriteOptions::default()
        };
        let (bsdf, summary) = written(&Rgb(-0.1), &options);
        assert_eq!(bsdf.channels(), Channels::Rgb);
        assert!(summary.negative_clamped > 0);
        let mut f = [0.0; 3];
        let wi = direction(0.4, 0.3);
        let wo = direction(0.7, 2.0);
        bsdf.eval(wi, wo, &mut f).unwrap();
        eprintln!("{f:?}");
        assert!(
            (f[0] - 0.5).abs() < 0.005 && (f[1] - 0.25).abs() < 0.0025 && f[2] == 0.0,
            "{f:?}"
        );
        let err = rgl_fields(&Rgb(f64::NAN), &options)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("rgb test") && err.contains("NaN") && err.contains(": 1 of 3 "),
            "{err}"
        );
        for bad in [
            RglWriteOptions {
                resolution: 1,
                ..options.clone()
            },
            RglWriteOptions {
                theta_samples: 2000,
                ..options.clone()
            },
        ] {
            let err = rgl_fields(&Rgb(0.1), &bad).unwrap_err().to_string();
            assert!(err.contains("must be in 2..=1024"), "{err}");
        }
        for (bad, says) in [
            (
                RglWriteOptions {
                    tolerance: Some(-1.0),
                    ..options.clone()
                },
                "tolerance -1 must be finite and > 0",
            ),
            (
                RglWriteOptions {
                    max_resolution: 16,
                    ..options.clone()
                },
                "maximum resolution 16 must be in 32..=256",
            ),
            (
                RglWriteOptions {
                    broad_share: 0.0,
                    ..options.clone()
                },
                "broad NDF share 0 must be in (0, 1]",
            ),
        ] {
            let err = rgl_fields(&Rgb(0.1), &bad).unwrap_err().to_string();
            assert!(err.contains(says), "{err}");
        }
    }

    /// The size checks: a tolerance must be above 0, and the warp tables may hold up to 2^28
    /// values (incident elevations x warp side^2), not one more.
    #[test]
    fn check_refuses_a_zero_tolerance_and_warps_over_2_pow_28_values() {
        let err = RglWriteOptions {
            tolerance: Some(0.0),
            ..RglWriteOptions::default()
        }
        .check()
        .unwrap_err()
        .to_string();
        assert!(err.contains("tolerance 0 must be finite and > 0"), "{err}");
        let sized = |theta_samples| RglWriteOptions {
            theta_samples,
            warp_resolution: 1024,
            tolerance: None,
            ..RglWriteOptions::default()
        };
        sized(256).check().unwrap();
        let err = sized(257).check().unwrap_err().to_string();
        assert!(
            err.contains("tables of 257 x 1024 x 1024 values are too large"),
            "{err}"
        );
    }

    /// Luminance weights: Rec. 709 for RGB; equal over the visible channels (380-780 nm) and
    /// 0 elsewhere; equal over all channels when none is visible.
    #[test]
    fn luminance_weights_share_the_visible_channels() {
        assert_eq!(
            luminance_weights(&Channels::Rgb),
            vec![0.2126, 0.7152, 0.0722]
        );
        let spectral = |w: &[f64]| luminance_weights(&Channels::spectral(w.to_vec()).unwrap());
        assert_eq!(
            spectral(&[360.0, 380.0, 550.0, 780.0, 900.0]),
            vec![0.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0, 0.0]
        );
        assert_eq!(spectral(&[850.0, 900.0]), vec![0.5, 0.5]);
    }

    /// The format's coordinate maps and the reflection about a half vector, for directions
    /// off the plane of incidence (the writer's `wi` always lies in it).
    #[test]
    fn coordinates_and_reflection() {
        for u in [0.0, 0.1, 0.5, 0.77, 1.0] {
            assert!((theta2u(u2theta(u)) - u).abs() < 1e-15, "{u}");
            assert!((phi2u(u2phi(u)) - u).abs() < 1e-15, "{u}");
        }
        let unit = |v: Vec3| v.map(|x| x / norm(v));
        let wi = unit([0.3, -0.4, 0.8]);
        let m = unit([0.1, 0.2, 0.9]);
        let (d, wo) = reflect(wi, m);
        let want = wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2];
        assert!((d - want).abs() < 1e-15, "{d} {want}");
        assert!((norm(wo) - 1.0).abs() < 1e-14, "{wo:?}");
        for k in 0..3 {
            // wi + wo is along m, with length 2 (wi . m).
            assert!((wi[k] + wo[k] - 2.0 * want * m[k]).abs() < 1e-15, "{k}");
        }
    }

    /// The check's pairs: [`CHECK_PAIRS`] unit directions, `wo` above 0.01; every fourth `wo`
    /// is the mirror direction of its `wi` moved by up to 0.05 (before normalising) in any
    /// direction, the others and every `wi` are spread over the hemisphere: every azimuth
    /// quadrant, elevations from near the horizon to near the normal.
    #[test]
    fn check_pairs_are_unit_directions_with_every_fourth_near_the_mirror() {
        let pairs = check_pairs();
        assert_eq!(pairs.len(), CHECK_PAIRS);
        let quadrant = |x: f64, y: f64| usize::from(x < 0.0) + 2 * usize::from(y < 0.0);
        // Per kind (wi; wo; the near-mirror offset): pairs per quadrant; lowest, highest z.
        let mut quadrants = [[0usize; 4]; 3];
        let mut z = [(1.0f64, 0.0f64); 2];
        for (k, (wi, wo)) in pairs.iter().enumerate() {
            assert!(
                (norm(*wi) - 1.0).abs() < 1e-12 && wi[2] >= 0.01,
                "{k}: {wi:?}"
            );
            assert!(
                (norm(*wo) - 1.0).abs() < 1e-12 && wo[2] > 0.01,
                "{k}: {wo:?}"
            );
            quadrants[0][quadrant(wi[0], wi[1])] += 1;
            z[0] = (z[0].0.min(wi[2]), z[0].1.max(wi[2]));
            if k % 4 == 3 {
                // wo = v / |v| with v = (-wi_x + d cos phi, -wi_y + d sin phi, wi_z): the
                // offset (d cos phi, d sin phi) is wi_z (wo_xy / wo_z + wi_xy / wi_z).
                let off = [0, 1].map(|c| wi[2] * (wo[c] / wo[2] + wi[c] / wi[2]));
                let d = off[0].hypot(off[1]);
                assert!(d <= 0.05 + 1e-9, "{k}: offset {d}");
                quadrants[2][quadrant(off[0], off[1])] += 1;
            } else {
                quadrants[1][quadrant(wo[0], wo[1])] += 1;
                z[1] = (z[1].0.min(wo[2]), z[1].1.max(wo[2]));
            }
        }
        for (kind, counts) in quadrants.iter().enumerate() {
            let total: usize = counts.iter().sum();
            assert!(counts.iter().all(|&c| 5 * c > total), "{kind}: {counts:?}");
        }
        for (lowest, highest) in z {
            assert!(lowest < 0.05 && highest > 0.999, "{z:?}");
        }
    }

    /// A grid source: each cell's values a function of its index, interpolated with the grid's
    /// stencil (as stored and predicted materials are); counts its evaluations and prefetch
    /// hints, and records its `will_need_cells` hints when it takes them.
    struct Cells {
        grid: crate::grid::AngularGrid,
        evals: std::sync::atomic::AtomicUsize,
        cell_evals: Vec<std::sync::atomic::AtomicUsize>,
        prefetches: Vec<std::sync::atomic::AtomicUsize>,
        failing: Option<usize>,
        takes_hints: bool,
        /// Each `will_need_cells` call's cells, in order.
        will_need: std::sync::Mutex<Vec<Vec<usize>>>,
        /// Per cell: how many `will_need_cells` calls there had been when it was evaluated.
        hints_before_eval: Vec<std::sync::atomic::AtomicUsize>,
    }

    impl Cells {
        fn new(failing: Option<usize>) -> Self {
            Self::on(crate::grid::AngularGrid::new(4, 4, 8).unwrap(), failing)
        }

        fn on(grid: crate::grid::AngularGrid, failing: Option<usize>) -> Self {
            let counts = || (0..grid.len()).map(|_| 0.into()).collect();
            Self {
                grid,
                evals: 0.into(),
                cell_evals: counts(),
                prefetches: counts(),
                failing,
                takes_hints: false,
                will_need: Default::default(),
                hints_before_eval: counts(),
            }
        }

        /// The same source, taking `will_need_cells` hints (as a store read from a disk).
        fn taking_hints(self) -> Self {
            Self {
                takes_hints: true,
                ..self
            }
        }

        fn will_need_calls(&self) -> Vec<Vec<usize>> {
            self.will_need.lock().unwrap().clone()
        }

        fn value(a: usize, channel: usize) -> f64 {
            0.1 + 0.05 * ((7 * a + 3 * channel) % 11) as f64
        }

        /// No cell was evaluated twice, and more than half of them once.
        fn assert_most_cells_evaluated_once(&self) {
            let counts: Vec<usize> = (self.cell_evals.iter())
                .map(|c| c.load(std::sync::atomic::Ordering::Relaxed))
                .collect();
            assert!(counts.iter().all(|&c| c <= 1), "{counts:?}");
            let evaluated = counts.iter().sum::<usize>();
            assert!(evaluated > self.grid.len() / 2, "{counts:?}");
        }
    }

    impl BrdfSource for Cells {
        fn channels(&self) -> Channels {
            Channels::Rgb
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
            use std::sync::atomic::Ordering::Relaxed;
            self.evals.fetch_add(1, Relaxed);
            out.fill(0.0);
            if let Some(hd) = crate::grid::HalfDiff::from_dirs(wi, wo)
                && wi[2] > 0.0
                && wo[2] > 0.0
            {
                for (a, w) in self.grid.interpolation_stencil(&hd) {
                    if w != 0.0 {
                        (0..3).for_each(|c| out[c] += w * Self::value(a, c));
                    }
                }
            }
            Ok(())
        }
        fn grid(&self) -> Option<crate::grid::AngularGrid> {
            Some(self.grid)
        }
        fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
            use std::sync::atomic::Ordering::Relaxed;
            self.cell_evals[a].fetch_add(1, Relaxed);
            let calls = self.will_need.lock().unwrap().len();
            self.hints_before_eval[a].store(calls, Relaxed);
            if self.failing == Some(a) {
                return Err(Error::InvalidArgument {
                    reason: "no values here".into(),
                });
            }
            (0..3).for_each(|c| out[c] = Self::value(a, c));
            Ok(())
        }
        fn prefetch_cell(&self, a: usize) {
            self.prefetches[a].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
            self.will_need.lock().unwrap().push(cells.collect());
        }
        fn takes_cell_hints(&self) -> bool {
            self.takes_hints
        }
    }

    /// Hinted cells ([`CachedCells::fill`]) are evaluated at once, each once, those not cached
    /// yet only: hinted to the source in ascending windows of [`FILL_WINDOW`], each window
    /// hinted before its cells are evaluated and the next one before them too; later lookups
    /// read the cache. The cache takes hints when its source does.
    #[test]
    fn cached_cells_evaluate_hinted_cells_in_ascending_windows() {
        use std::sync::atomic::Ordering::Relaxed;
        let source = Cells::on(crate::grid::AngularGrid::new(16, 16, 40).unwrap(), None);
        let source = source.taking_hints();
        let n = source.grid.len();
        assert!(n > 2 * FILL_WINDOW, "{n}");
        let cached = CachedCells::new(&source, source.grid);
        assert!(cached.takes_cell_hints());
        let mut got = [0.0; 3];
        cached.eval_cell(7, &mut got).unwrap();
        // Descending, with repeats, a cached cell and cells outside the grid.
        let mut hinted = (0..n).rev().chain([3, 7, n, n + 5]);
        cached.will_need_cells(&mut hinted);
        let calls = source.will_need_calls();
        let want: Vec<usize> = (0..n).filter(|&a| a != 7).collect();
        assert_eq!(calls.concat(), want);
        assert_eq!(calls.len(), want.len().div_ceil(FILL_WINDOW));
        assert!(
            calls[..calls.len() - 1]
                .iter()
                .all(|c| c.len() == FILL_WINDOW)
        );
        for a in 0..n {
            assert_eq!(source.cell_evals[a].load(Relaxed), 1, "cell {a}");
            if a == 7 {
                continue;
            }
            // Window w is call w: hinted before its cells, with the next one.
            let w = want.binary_search(&a).unwrap() / FILL_WINDOW;
            let before = source.hints_before_eval[a].load(Relaxed);
            assert_eq!(before, (w + 2).min(calls.len()), "cell {a}");
        }
        // From the cache now: no evaluation, no hint.
        for a in [0, 7, n - 1] {
            cached.eval_cell(a, &mut got).unwrap();
            assert_eq!(got, [0, 1, 2].map(|c| Cells::value(a, c)));
        }
        cached.will_need_cells(&mut (0..n));
        assert_eq!(source.will_need_calls().len(), calls.len());
        assert!((0..n).all(|a| source.cell_evals[a].load(Relaxed) == 1));
        // A failing cell's error is kept for its lookup.
        let failing = Cells::on(source.grid, Some(5)).taking_hints();
        let cached = CachedCells::new(&failing, failing.grid);
        cached.will_need_cells(&mut (0..10));
        let e = cached.eval_cell(5, &mut got).unwrap_err().to_string();
        assert!(
            e.contains("cell 5 of the source: ") && e.contains("no values here"),
            "{e}"
        );
        assert_eq!(failing.cell_evals[5].load(Relaxed), 1);
        assert!(!CachedCells::new(&Cells::new(None), failing.grid).takes_cell_hints());
    }

    /// A source that takes hints is written with each cell hinted before it is evaluated (so a
    /// store read from a disk reads them in the file's order), into the same file; a source
    /// that takes none is not hinted.
    #[test]
    fn grid_sources_are_hinted_before_their_cells_are_read() {
        use std::sync::atomic::Ordering::Relaxed;
        let plain = RglWriteOptions {
            description: "cells".into(),
            ..fixed_sizes(4, 8, 16)
        };
        // With the source's lobe in the warp, whose stage reads the most cells first.
        let lobe = RglWriteOptions {
            lobe_warp: Some(WARP_LOBE_SHARE),
            ..plain.clone()
        };
        for options in [plain, lobe] {
            let deaf = Cells::new(None);
            let (want, want_summary) = rgl_fields(&deaf, &options).unwrap();
            assert!(deaf.will_need_calls().is_empty());
            let source = Cells::new(None).taking_hints();
            let (fields, summary) = rgl_fields(&source, &options).unwrap();
            assert!(fields == want, "the files differ");
            assert_eq!(summary, want_summary);
            source.assert_most_cells_evaluated_once();
            let calls = source.will_need_calls();
            for a in 0..source.grid.len() {
                if source.cell_evals[a].load(Relaxed) == 1 {
                    let hinted = calls.iter().position(|c| c.contains(&a));
                    let before = source.hints_before_eval[a].load(Relaxed);
                    assert!(hinted.is_some_and(|h| h < before), "cell {a}: {calls:?}");
                }
            }
            // Every cell hinted once (only cells not yet evaluated are hinted).
            let mut hinted = calls.concat();
            hinted.sort_unstable();
            let evaluated: Vec<usize> = (0..source.grid.len())
                .filter(|&a| source.cell_evals[a].load(Relaxed) == 1)
                .collect();
            assert_eq!(hinted, evaluated);
        }
    }

    /// The cached cells of a grid source evaluate as the source does, to the bit (the same
    /// sums in the same order), zero at or below the horizon, each cell once, after a prefetch
    /// hint; a cell that cannot be evaluated is an error naming it.
    #[test]
    fn cached_cells_evaluate_as_their_source_each_cell_once() {
        let source = Cells::new(None);
        let cached = CachedCells::new(&source, source.grid);
        let mut state = 7u64;
        let (mut got, mut want) = ([0.0; 3], [0.0; 3]);
        let mut pairs: Vec<(Vec3, Vec3)> = (0..2000)
            .map(|_| (random_dir(&mut state), random_dir(&mut state)))
            .collect();
        let grazing = [1.0, 0.0, 0.0];
        pairs.extend([
            (grazing, [0.0, 0.0, 1.0]),
            ([0.0, 0.0, 1.0], grazing),
            ([0.3, 0.0, -0.5], [0.0, 0.2, 1.0]),
            ([0.0, 0.2, 1.0], [0.3, 0.0, -0.5]),
        ]);
        for (wi, wo) in &pairs {
            cached.eval(*wi, *wo, &mut got).unwrap();
            source.eval(*wi, *wo, &mut want).unwrap();
            assert_eq!(got, want, "{wi:?} {wo:?}");
            if wi[2] <= 0.0 || wo[2] <= 0.0 {
                assert_eq!(got, [0.0; 3]);
            } else {
                assert!(got.iter().all(|&v| v > 0.09), "{got:?}");
            }
        }
        source.assert_most_cells_evaluated_once();
        // Each cell was hinted while it was not yet evaluated: once, as it was evaluated.
        let counts = |v: &[std::sync::atomic::AtomicUsize]| {
            v.iter()
                .map(|c| c.load(std::sync::atomic::Ordering::Relaxed))
                .collect::<Vec<_>>()
        };
        assert_eq!(counts(&source.prefetches), counts(&source.cell_evals));

        let (wi, wo) = pairs[0];
        let hd = crate::grid::HalfDiff::from_dirs(wi, wo).unwrap();
        let (a, _) = source
            .grid
            .interpolation_stencil(&hd)
            .into_iter()
            .find(|&(_, w)| w != 0.0)
            .unwrap();
        let failing = Cells::new(Some(a));
        let err = CachedCells::new(&failing, failing.grid)
            .eval(wi, wo, &mut got)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&format!("cell {a} of the source: ")) && err.contains("no values here"),
            "{err}"
        );
    }

    /// A grid source is written from its cells (never through its own `eval`), each cell
    /// evaluated once, into the same file as the same source seen as a plain one.
    #[test]
    fn grid_sources_are_written_from_their_cells() {
        use std::sync::atomic::Ordering::Relaxed;
        struct Plain<'a>(&'a Cells);
        impl BrdfSource for Plain<'_> {
            fn channels(&self) -> Channels {
                self.0.channels()
            }
            fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
                self.0.eval(wi, wo, out)
            }
        }
        let options = RglWriteOptions {
            description: "cells".into(),
            ..fixed_sizes(4, 8, 16)
        };
        let source = Cells::new(None);
        let (fields, summary) = rgl_fields(&source, &options).unwrap();
        assert_eq!(source.evals.load(Relaxed), 0);
        source.assert_most_cells_evaluated_once();
        let other = Cells::new(None);
        let (plain_fields, plain_summary) = rgl_fields(&Plain(&other), &options).unwrap();
        assert!(other.evals.load(Relaxed) > CHECK_PAIRS);
        assert!(fields == plain_fields, "the files differ");
        assert_eq!(summary, plain_summary);
        assert_eq!(summary.values, 4 * 8 * 8 * 3, "{summary:?}");
    }

    /// The writer's cached cells are a grid source of their own: the source's grid and lookup,
    /// each cell's values bit for bit from `eval_cell` (evaluated once across `eval` and
    /// `eval_cell`), hints passed on only for cells not yet cached, and clear errors for a
    /// cell outside the grid or a wrong output length.
    #[test]
    fn cached_cells_are_the_sources_cells() {
        use std::sync::atomic::Ordering::Relaxed;
        let source = Cells::new(None);
        let cached = CachedCells::new(&source, source.grid);
        assert_eq!(cached.grid(), Some(source.grid));
        assert_eq!(cached.lookup(), source.lookup());
        let logarithmic = crate::lookup::WithLookup::new(&source, Lookup::LogMultilinear).unwrap();
        let cached_log = CachedCells::new(&logarithmic, source.grid);
        assert_eq!(cached_log.lookup(), Lookup::LogMultilinear);
        let (mut got, mut want) = ([0.0; 3], [0.0; 3]);
        // Half the cells through `eval` first (cached), then every cell by `eval_cell`.
        let mut state = 11u64;
        for _ in 0..200 {
            cached
                .eval(random_dir(&mut state), random_dir(&mut state), &mut got)
                .unwrap();
        }
        let before: Vec<usize> = source.cell_evals.iter().map(|c| c.load(Relaxed)).collect();
        let prefetched: Vec<usize> = source.prefetches.iter().map(|c| c.load(Relaxed)).collect();
        for a in 0..source.grid.len() {
            cached.prefetch_cell(a);
            cached.eval_cell(a, &mut got).unwrap();
            (0..3).for_each(|c| want[c] = Cells::value(a, c));
            assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "cell {a}");
            // Again: from the cache.
            cached.eval_cell(a, &mut got).unwrap();
            assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "cell {a}");
        }
        for a in 0..source.grid.len() {
            let evals = source.cell_evals[a].load(Relaxed);
            assert_eq!(evals, 1, "cell {a}");
            // A hint only for a cell that `eval` had not cached.
            let hinted = source.prefetches[a].load(Relaxed) - prefetched[a];
            assert_eq!(hinted, 1 - before[a], "cell {a}");
        }
        assert!(before.contains(&1) && before.contains(&0));
        let n = source.grid.len();
        let e = cached.eval_cell(n, &mut got).unwrap_err().to_string();
        assert!(
            e.contains(&format!("cell {n} of a grid of {n} cells")),
            "{e}"
        );
        assert!(cached.eval_cell(0, &mut [0.0; 2]).is_err());
    }

    /// `write_rgl_then` writes `write_rgl`'s file and gives `after` the source as the writer
    /// read it: a grid source's directional albedo from the cached cells equals the source's
    /// own to the bit, with no cell evaluated twice across the write and the check; other
    /// sources are passed as they are.
    #[test]
    fn writing_then_checking_reads_each_cell_once() {
        let dir = tempfile::tempdir().unwrap();
        let options = fixed_sizes(4, 8, 16);
        let (a, b) = (dir.path().join("a.bsdf"), dir.path().join("b.bsdf"));
        let source = Cells::new(None);
        let angles = [0.0, 30.0, 60.0, 85.0];
        let (summary, table) = write_rgl_then(&source, &a, &options, |s| {
            crate::albedo::directional_albedo(s, &angles, 24).unwrap()
        })
        .unwrap();
        source.assert_most_cells_evaluated_once();
        let fresh = Cells::new(None);
        assert_eq!(write_rgl(&fresh, &b, &options).unwrap(), summary);
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        let direct = crate::albedo::directional_albedo(&fresh, &angles, 24).unwrap();
        let bits = |t: &crate::albedo::AlbedoTable| {
            t.values.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        assert_eq!(bits(&table), bits(&direct));
        assert!(table.values.iter().all(|&v| v > 0.05), "{table:?}");
        // A source without a grid: `after` gets it as it is.
        let analytic = Analytic::new(0.4);
        let (_, seen) = write_rgl_then(&analytic, &a, &options, |s| s.grid().is_none()).unwrap();
        assert!(seen);
        // A failed write runs no check.
        let bad = RglWriteOptions {
            resolution: 0,
            ..options.clone()
        };
        let mut ran = false;
        assert!(write_rgl_then(&source, &a, &bad, |_| ran = true).is_err());
        assert!(!ran);
    }

    /// Refinement walks the doublings as its docs say: from the file as given, each step
    /// builds the candidates that fit the maxima (twice the incident elevations; twice the
    /// tables' side, with warps of at least 8 times the old side, up to [`MAX_WARP`]; both,
    /// when both fit), keeps the one with the smallest check, and takes it only if that cuts
    /// the check to [`REFINE_GAIN`] of the current one or less. Replayed here from files
    /// written at fixed sizes, for three sources and maxima whose walks take each kind of
    /// step and end both ways (a doubling that gains too little; no doubling left).
    #[test]
    fn refinement_takes_the_best_doubling_while_it_gains_a_quarter() {
        let mut ends = Vec::new();
        for (alpha, max_theta, max_res) in [(0.5, 32, 32), (0.3, 12, 24), (0.03, 12, 24)] {
            let source = Analytic::new(alpha);
            let base = RglWriteOptions {
                max_theta_samples: max_theta,
                max_resolution: max_res,
                ..fixed_sizes(3, 4, 16)
            };
            let fixed = |(theta_samples, resolution, warp_resolution)| {
                written(
                    &source,
                    &fixed_sizes(theta_samples, resolution, warp_resolution),
                )
                .1
            };
            let mut size = (3, 4, 16);
            let mut best = fixed(size);
            let mut steps = Vec::new();
            loop {
                let (t, r, w) = size;
                let wider = w.max(8 * r).min(MAX_WARP);
                let mut candidates = Vec::new();
                if 2 * t <= max_theta {
                    candidates.push((2 * t, r, w));
                }
                if 2 * r <= max_res {
                    candidates.push((t, 2 * r, wider));
                }
                if candidates.len() == 2 {
                    candidates.push((2 * t, 2 * r, wider));
                }
                let Some((next, summary)) = candidates
                    .into_iter()
                    .map(|c| (c, fixed(c)))
                    .min_by(|a, b| a.1.check().total_cmp(&b.1.check()))
                else {
                    ends.push("no candidate");
                    break;
                };
                if summary.check() > REFINE_GAIN * best.check() {
                    ends.push("gain too small");
                    break;
                }
                steps.push(next);
                (size, best) = (next, summary);
            }
            let (_, refined) = written(
                &source,
                &RglWriteOptions {
                    tolerance: Some(1e-9),
                    ..base.clone()
                },
            );
            let got = (
                refined.theta_samples,
                refined.resolution,
                refined.warp_resolution,
            );
            assert_eq!(got, size, "alpha {alpha}: steps {steps:?}, {ends:?}");
            assert_eq!(refined.check(), best.check(), "alpha {alpha}");
            eprintln!("alpha {alpha}: {steps:?}");
            assert!(!steps.is_empty(), "alpha {alpha}");
        }
        assert_eq!(ends, ["gain too small", "gain too small", "no candidate"]);
    }

    /// The warp's share of the source's own lobe: the writer tries the plain warp and
    /// [`WARP_LOBE_SHARE`] of the lobe and keeps the file that checks better: the lobe for a
    /// broad retro-reflective lobe (far from the mirror direction the VNDF samples), the plain
    /// warp for a GGX lobe.
    #[test]
    fn the_lobe_warp_is_chosen_when_it_checks_better() {
        let retro = Grey(|wi: Vec3, wo: Vec3| {
            let c = wi[0] * wo[0] + wi[1] * wo[1] + wi[2] * wo[2];
            0.1 / PI + 5.0 * (-(1.0 - c) / 0.3).exp()
        });
        let ggx = Analytic::new(0.2);
        for (source, lobe_is_better) in [(&retro as &dyn BrdfSource, true), (&ggx, false)] {
            let at = |lobe_warp: Option<f64>| {
                let options = RglWriteOptions {
                    lobe_warp,
                    ..fixed_sizes(8, 8, 128)
                };
                written(source, &options).1
            };
            let (plain, lobe, chosen) = (at(Some(0.0)), at(Some(WARP_LOBE_SHARE)), at(None));
            assert_eq!(
                lobe.check() < plain.check(),
                lobe_is_better,
                "{plain:?} {lobe:?}"
            );
            let better = if lobe_is_better { &lobe } else { &plain };
            assert_eq!(chosen.lobe_warp, better.lobe_warp);
            assert_eq!(chosen.check(), better.check());
        }
    }

    /// The file's NDF: the estimate from the source's retro-reflection scaled to its share
    /// (1 - `broad_share`) by the trapezoid rule in u over the table's nodes (2 pi int D cos
    /// sin dtheta, as the writer integrates), plus the uniform 1/pi; only the uniform NDF when
    /// nothing is reflected back (no estimate); only the uniform NDF with `broad_share` 1,
    /// whatever the mirror share.
    #[test]
    fn the_ndf_is_the_normalised_estimate_and_the_uniform_share() {
        // Reflects nothing back towards the incident direction: |wi - wo|^2 is 0 exactly at
        // wo = wi.
        let forward =
            Grey(|wi: Vec3, wo: Vec3| 0.1 * (0..3).map(|k| (wi[k] - wo[k]).powi(2)).sum::<f64>());
        let ndf = |source: &dyn BrdfSource, mirror_share: f64, broad_share: f64| {
            let options = RglWriteOptions {
                mirror_share: Some(mirror_share),
                broad_share,
                ..fixed_sizes(4, 8, 32)
            };
            let (fields, _) = rgl_fields(source, &options).unwrap();
            let d = values_of(&fields, "ndf");
            let nw = d.len() / 2;
            assert_eq!(d[..nw], d[nw..]);
            d[..nw].to_vec()
        };
        let trapezoid = |d: &[f64]| {
            let nw = d.len();
            let g = |k: usize| {
                let u = node(k, nw);
                let t = u2theta(u);
                d[k] * t.cos() * t.sin() * PI * u
            };
            2.0 * PI / (nw - 1) as f64 * (0..nw - 1).map(|k| 0.5 * (g(k) + g(k + 1))).sum::<f64>()
        };
        let d = ndf(&Analytic::new(0.2), 0.0, BROAD_SHARE);
        let estimate: Vec<f64> = d.iter().map(|v| v - BROAD_SHARE / PI).collect();
        // It peaks at the normal (the GGX lobe seen back along wi = wo).
        assert!(estimate[0] > 2.0 * estimate[16], "{d:?}");
        let share = trapezoid(&estimate);
        assert!((share - (1.0 - BROAD_SHARE)).abs() < 1e-6, "{share}");
        let uniform = f64::from((1.0 / PI) as f32);
        for (source, mirror, broad) in [
            (&forward as &dyn BrdfSource, 0.0, BROAD_SHARE),
            (&forward, MIRROR_SHARE, BROAD_SHARE),
            (&Analytic::new(0.2), MIRROR_SHARE, 1.0),
        ] {
            let d = ndf(source, mirror, broad);
            assert!(d.iter().all(|&v| v == uniform), "{mirror} {broad}: {d:?}");
        }
    }

    /// The file's sigma is the projected area of its NDF, int D(m) max(0, wi . m) dm: for the
    /// uniform NDF 1/pi (`broad_share` 1) (1 + cos theta_i) / 2; for any NDF 1 at normal
    /// incidence (the NDF's normalisation).
    #[test]
    fn sigma_is_the_projected_area_of_the_ndf() {
        let field = |broad_share: f64, name: &str| {
            let options = RglWriteOptions {
                broad_share,
                ..fixed_sizes(4, 8, 32)
            };
            let (fields, _) = rgl_fields(&Analytic::new(0.2), &options).unwrap();
            values_of(&fields, name)
        };
        let sigma = field(1.0, "sigma");
        let nw = sigma.len() / 2;
        for (k, s) in sigma[..nw].iter().enumerate() {
            let theta = u2theta(node(k, nw));
            let want = (1.0 + theta.cos()) / 2.0;
            assert!((s - want).abs() < 1e-4, "{k}: {s} against {want}");
        }
        let sigma = field(BROAD_SHARE, "sigma");
        assert!((sigma[0] - 1.0).abs() < 1e-3, "{}", sigma[0]);
    }

    /// The warp's lobe: with `lobe_warp` 1 each incident elevation's table is the density of
    /// the source's reflected lobe over the table's (u_theta, u_phi) points, luminance x
    /// cos theta_o x dwo / du, dwo = 4 (wi . m) dm, dm ~ u sin theta_m du dphi, summing to 1;
    /// for a black source (no lobe to follow) the plain VNDF, whatever the share.
    #[test]
    fn the_warp_follows_the_lobe_and_a_black_source_keeps_the_vndf() {
        let vndf = |source: &dyn BrdfSource, lobe_warp: f64| {
            let options = RglWriteOptions {
                lobe_warp: Some(lobe_warp),
                ..fixed_sizes(3, 8, 16)
            };
            let (fields, _) = rgl_fields(source, &options).unwrap();
            (values_of(&fields, "theta_i"), values_of(&fields, "vndf"))
        };
        let source = Analytic::new(0.2);
        let (theta_i, table) = vndf(&source, 1.0);
        let nw = 16;
        let mut f = [0.0; 4];
        for (k, &theta) in theta_i.iter().enumerate() {
            let wi = direction(theta.min(MAX_EVAL_THETA_DEG.to_radians()), 0.0);
            let mut density = vec![0.0; nw * nw];
            for row in 0..nw {
                for col in 0..nw {
                    let u = node(col, nw);
                    let tm = u2theta(u);
                    let m = direction(tm, u2phi(node(row, nw)));
                    let (c, wo) = reflect(wi, m);
                    if c > 0.0 && wo[2] > 0.0 {
                        source.eval(wi, wo, &mut f).unwrap();
                        let lum = (f[0] + f[1] + f[2]) / 3.0;
                        density[row * nw + col] = lum * wo[2] * 4.0 * c * u * tm.sin();
                    }
                }
            }
            let total: f64 = density.iter().sum();
            let slice = &table[k * nw * nw..(k + 1) * nw * nw];
            for (i, (got, d)) in slice.iter().zip(&density).enumerate() {
                let want = d / total;
                assert!(
                    (got - want).abs() <= 1e-6 * want + 1e-12,
                    "{k} {i}: {got} {want}"
                );
            }
        }
        let black = Grey(|_: Vec3, _: Vec3| 0.0);
        let (_, plain) = vndf(&black, 0.0);
        for slice in plain.chunks(nw * nw) {
            let total: f64 = slice.iter().sum();
            assert!((total - 1.0).abs() < 1e-5, "{total}");
            assert!(slice.iter().all(|&v| v >= 0.0), "{slice:?}");
        }
        assert_eq!(vndf(&black, 0.9).1, plain);
    }

    /// The table points counted below the horizon are exactly those left at 0: a source
    /// positive everywhere above the horizon stores a positive value at every other point.
    #[test]
    fn points_below_the_horizon_are_counted_and_left_at_zero() {
        let options = fixed_sizes(6, 16, 128);
        let (fields, summary) = rgl_fields(&Grey(|_: Vec3, _: Vec3| 0.3), &options).unwrap();
        let rgb = values_of(&fields, "rgb");
        let points = 16 * 16;
        let zero = rgb
            .chunks(3 * points)
            .flat_map(|slice| {
                (0..points).map(move |p| (0..3).all(|c| slice[c * points + p] == 0.0))
            })
            .filter(|&z| z)
            .count();
        assert!(zero > 0, "{summary:?}");
        assert_eq!(summary.below_horizon, zero);
        assert_eq!(summary.values, 6 * points * 3);
        assert_eq!(summary.negative_clamped, 0);
        // Zeros are not negative.
        let (fields, black) = rgl_fields(&Grey(|_: Vec3, _: Vec3| 0.0), &options).unwrap();
        assert_eq!(black.negative_clamped, 0);
        // Nothing to sample by: a uniform luminance table.
        assert!(values_of(&fields, "luminance").iter().all(|&l| l == 1.0));
    }

    /// The luminance table is the wanted sampling density (the reflected luminance) over the
    /// warp's density, floored at [`LUMINANCE_FLOOR`] of its mean. Where the two are
    /// proportional it is one constant, with the floor where the lobe is 0 (below the horizon,
    /// at theta_m = 0): for a source of constant luminance x cos theta_o under the uniform NDF,
    /// and for any source when the warp is all lobe.
    #[test]
    fn the_luminance_table_is_the_wanted_density_over_the_warps() {
        let flat = Grey(|_: Vec3, wo: Vec3| 0.3 / wo[2]);
        let glossy = Analytic::new(0.2);
        let cases = [
            (&flat as &dyn BrdfSource, 1.0, 0.0),
            (&glossy, BROAD_SHARE, 1.0),
        ];
        for (source, broad_share, lobe_warp) in cases {
            let options = RglWriteOptions {
                broad_share,
                lobe_warp: Some(lobe_warp),
                ..fixed_sizes(3, 8, 32)
            };
            let (fields, _) = rgl_fields(source, &options).unwrap();
            let luminance = values_of(&fields, "luminance");
            let points = 8 * 8;
            let mut floored = 0;
            for slice in luminance.chunks(points) {
                let top = slice.iter().copied().fold(0.0, f64::max);
                let at_top = slice
                    .iter()
                    .filter(|&&l| (l - top).abs() <= 1e-6 * top)
                    .count();
                let floor = LUMINANCE_FLOOR * top * at_top as f64 / points as f64;
                assert!(at_top >= 8, "{lobe_warp}: {slice:?}");
                for &l in slice {
                    let off = (l - top).abs().min((l - floor).abs());
                    assert!(
                        off <= 1e-6 * l,
                        "{lobe_warp}: {l} is neither {top} nor {floor}"
                    );
                }
                floored += points - at_top;
            }
            assert!(floored > 0, "{lobe_warp}");
        }
    }

    /// A source whose values leave f32's range once scaled into the tables is refused, naming
    /// it, rather than written with infinities.
    #[test]
    fn values_beyond_f32_are_refused() {
        let options = RglWriteOptions {
            description: "huge".into(),
            ..fixed_sizes(3, 8, 32)
        };
        // Huge everywhere, or only in a channel that the luminance table does not weigh.
        struct Invisible;
        impl BrdfSource for Invisible {
            fn channels(&self) -> Channels {
                Channels::spectral(vec![550.0, 900.0]).unwrap()
            }
            fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
                let up = wi[2] > 0.0 && wo[2] > 0.0;
                out.copy_from_slice(&if up { [0.3, 1e300] } else { [0.0; 2] });
                Ok(())
            }
        }
        let huge = Grey(|_: Vec3, _: Vec3| 1e300);
        for source in [&huge as &dyn BrdfSource, &Invisible] {
            let err = rgl_fields(source, &options).unwrap_err().to_string();
            assert!(
                err.starts_with("invalid argument: huge: ")
                    && err.contains("table values exceed the f32 range of an RGL file"),
                "{err}"
            );
        }
    }

    /// The value tables may hold up to 2^28 values (incident elevations x channels x side^2),
    /// not one more, and a size whose product overflows is refused as too large. A NaN source
    /// shows where the size check let a write through: its first evaluation fails.
    #[test]
    fn value_tables_over_2_pow_28_values_are_refused() {
        let mut nan = Analytic::new(0.2);
        nan.offset = f64::NAN;
        assert_eq!(nan.channels().len(), 4);
        let sized = |theta_samples| RglWriteOptions {
            description: "big".into(),
            ..fixed_sizes(theta_samples, 1024, 32)
        };
        let fits = fixed_fields(&nan, &sized(64)).unwrap_err().to_string();
        assert!(fits.contains("big") && fits.contains("NaN"), "{fits}");
        let err = fixed_fields(&nan, &sized(65)).unwrap_err().to_string();
        assert!(
            err.contains("big: RGL value tables of 65 x 4 x 1024 x 1024 values are too large"),
            "{err}"
        );
        let err = fixed_fields(&nan, &sized(usize::MAX))
            .unwrap_err()
            .to_string();
        assert!(err.contains("values are too large"), "{err}");
    }
}
