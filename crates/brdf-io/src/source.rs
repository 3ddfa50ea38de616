//! What every BRDF source offers (`specgp sample`, `render`): its channels and f(wi, wo), and the
//! import report that resampling returns.

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, Channels, HalfDiff, Vec3};
use crate::lookup::Lookup;

/// How many cells ahead a consumer that evaluates cells in order (render plans, albedo
/// tables) asks the source to prefetch ([`BrdfSource::prefetch_cell`]): with the store's
/// prefetch into L2, 2 cells ahead rendered a fast-table sphere in 3.0 ms against 3.6 ms for 1
/// (4: no better; BENCHMARKS.md "render", session 11); on a store paged on demand it keeps the
/// disk busy (BENCHMARKS.md "dataset store", session 49).
pub const PREFETCH_AHEAD: usize = 2;

/// A BRDF that can be evaluated at arbitrary direction pairs.
///
/// Directions are in the local frame (z = surface normal) and need not be normalised; the
/// argument order is Mitsuba 3's `BSDF::eval` (`wi` = `si.wi`, `wo` = the other direction), so an
/// RGL file evaluates exactly as Mitsuba's `measured` plugin (reciprocal data such as MERL does
/// not care). Grid resampling passes [`crate::HalfDiff::to_dirs`]'s pair in order. Values are
/// the BRDF f in 1/sr (no cosine factor); a pair with either direction at or below the horizon
/// gives 0 in every channel. Implementations are `Sync`, so callers may evaluate in parallel.
pub trait BrdfSource: Sync {
    /// The channel axis of [`BrdfSource::eval`]'s output.
    fn channels(&self) -> Channels;

    /// Writes f(wi, wo) for every channel into `out` (length [`Channels::len`]).
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()>;

    /// For grid sources (values at the bin centres of an angular grid, interpolated with
    /// [`AngularGrid::interpolation_stencil`], zero when a direction is at or below the horizon:
    /// stored and predicted materials), the grid; a consumer may then evaluate each cell it
    /// needs once with [`BrdfSource::eval_cell`] and interpolate itself, which equals
    /// [`BrdfSource::eval`] up to rounding. `None` (the default) for other sources.
    fn grid(&self) -> Option<AngularGrid> {
        None
    }

    /// For grid sources, how [`BrdfSource::eval`] combines the cells of a lookup's stencil; a
    /// consumer that interpolates cells itself combines them the same way
    /// ([`crate::lookup::combine`]). Multilinear by default (see [`crate::lookup`]).
    fn lookup(&self) -> Lookup {
        Lookup::Multilinear
    }

    /// Values of every channel at flat cell index `a` of [`BrdfSource::grid`] into `out`
    /// (grid sources only; the default is an error).
    fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
        let _ = (a, out);
        Err(Error::InvalidArgument {
            reason: "eval_cell: not a grid source".into(),
        })
    }

    /// A hint that [`BrdfSource::eval_cell`] of cell `a` follows soon: a source that reads
    /// stored values may start fetching them into the cache. No effect by default.
    fn prefetch_cell(&self, a: usize) {
        let _ = a;
    }

    /// A hint that [`BrdfSource::eval_cell`] of each of `cells` (in this order) follows: a
    /// source that reads its values from a disk may start reading them all (a store read with
    /// positioned reads, see [`crate::store::Store::will_need`]). Unlike
    /// [`BrdfSource::prefetch_cell`], meant for many cells at once, well ahead. No effect by
    /// default.
    fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        let _ = cells;
    }

    /// Whether [`BrdfSource::will_need_cells`] does anything for this source (its cells are
    /// read from a disk as they are needed): a consumer skips working out the cells it will
    /// read when it does not ([`will_need_pairs`]). False by default; wrappers forward it.
    fn takes_cell_hints(&self) -> bool {
        false
    }

    /// The concrete source whose [`BrdfSource::eval_cell`] this source's is, for a consumer
    /// that evaluates the cells of several sources of one kind together (a render of many
    /// predictions of one model reads each cell once for all of them: it downcasts this to
    /// the prediction). Only wrappers that evaluate cells exactly as their inner source
    /// (boxes, references, [`crate::lookup::WithLookup`]) forward it; `None` by default.
    fn cell_source(&self) -> Option<&dyn std::any::Any> {
        None
    }
}

/// Evaluates the cells of a grid source that `items` name (`cell(item)`, a flat index), in
/// this order ([`BrdfSource::eval_cell`]), hinting the source ahead: all of them at once for a
/// disk ([`BrdfSource::will_need_cells`]) and each one [`PREFETCH_AHEAD`] cells ahead for the
/// CPU's caches ([`BrdfSource::prefetch_cell`]). `visit(i, item, f)` receives each item with
/// its position and its cell's values `f` (every channel); the first error, of the source or
/// of `visit`, ends the walk.
pub fn eval_cells_in_order<T, E: From<Error>>(
    source: &dyn BrdfSource,
    items: &[T],
    cell: impl Fn(&T) -> usize,
    visit: impl FnMut(usize, &T, &[f64]) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let eval = |a: usize, f: &mut [f64]| source.eval_cell(a, f).map_err(E::from);
    eval_cells_in_order_by(source, source.channels().len(), eval, items, cell, visit)
}

/// [`eval_cells_in_order`] with each cell's `width` values computed by `eval(a, f)` instead of
/// a source's own [`BrdfSource::eval_cell`] (several sources' cells at once, say), the hints
/// going to `hints` (a source that reads the same cells).
pub fn eval_cells_in_order_by<T, E>(
    hints: &dyn BrdfSource,
    width: usize,
    mut eval: impl FnMut(usize, &mut [f64]) -> std::result::Result<(), E>,
    items: &[T],
    cell: impl Fn(&T) -> usize,
    mut visit: impl FnMut(usize, &T, &[f64]) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let mut f = vec![0.0; width];
    hints.will_need_cells(&mut items.iter().map(&cell));
    for (i, item) in items.iter().enumerate() {
        if let Some(next) = items.get(i + PREFETCH_AHEAD) {
            hints.prefetch_cell(cell(next));
        }
        eval(cell(item), &mut f)?;
        visit(i, item, &f)?;
    }
    Ok(())
}

/// A hint that [`BrdfSource::eval`] at each of `pairs` (`(wi, wo)`) follows: for a grid
/// source, passes the cells that their lookups read (the cells of their interpolation stencils
/// with a weight other than 0, ascending, each once) to [`BrdfSource::will_need_cells`]; no
/// effect for other sources, nor for those that take no hints
/// ([`BrdfSource::takes_cell_hints`]).
pub fn will_need_pairs(source: &dyn BrdfSource, pairs: &[(Vec3, Vec3)]) {
    let Some(grid) = source.grid().filter(|_| source.takes_cell_hints()) else {
        return;
    };
    let mut cells: Vec<usize> = pairs
        .iter()
        .filter(|(wi, wo)| wi[2] > 0.0 && wo[2] > 0.0)
        .filter_map(|&(wi, wo)| HalfDiff::from_dirs(wi, wo))
        .flat_map(|hd| grid.interpolation_stencil(&hd))
        .filter_map(|(a, w)| (w != 0.0).then_some(a))
        .collect();
    cells.sort_unstable();
    cells.dedup();
    source.will_need_cells(&mut cells.into_iter());
}

/// The linear blend `a f1 + (1 - a) f2` of two sources in BRDF values (the paper's linear
/// interpolation between two measured materials). A grid source when both are on the same grid.
pub struct Blend<'a> {
    first: &'a dyn BrdfSource,
    second: &'a dyn BrdfSource,
    weight: f64,
}

impl<'a> Blend<'a> {
    /// `weight` x `first` + (1 - `weight`) x `second`; the two must have the same channels and
    /// `weight` must be finite.
    pub fn new(first: &'a dyn BrdfSource, second: &'a dyn BrdfSource, weight: f64) -> Result<Self> {
        if first.channels() != second.channels() {
            return Err(Error::InvalidArgument {
                reason: "a blend needs two sources with the same channels".into(),
            });
        }
        if !weight.is_finite() {
            return Err(Error::InvalidArgument {
                reason: format!("blend weight {weight} is not finite"),
            });
        }
        Ok(Self {
            first,
            second,
            weight,
        })
    }

    fn mix(&self, out: &mut [f64], other: &[f64]) {
        for (o, v) in out.iter_mut().zip(other) {
            *o = self.weight * *o + (1.0 - self.weight) * v;
        }
    }
}

impl BrdfSource for Blend<'_> {
    fn channels(&self) -> Channels {
        self.first.channels()
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        let mut other = vec![0.0; out.len()];
        self.first.eval(wi, wo, out)?;
        self.second.eval(wi, wo, &mut other)?;
        self.mix(out, &other);
        Ok(())
    }

    /// The sources' grid when both are on it and looked up multilinearly: a multilinear blend
    /// of cells is the blend of the lookups, a logarithmic one is not (the blend is then
    /// evaluated pair by pair).
    fn grid(&self) -> Option<AngularGrid> {
        let g = self.first.grid()?;
        let linear = [self.first.lookup(), self.second.lookup()] == [Lookup::Multilinear; 2];
        (self.second.grid() == Some(g) && linear).then_some(g)
    }

    fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
        let mut other = vec![0.0; out.len()];
        self.first.eval_cell(a, out)?;
        self.second.eval_cell(a, &mut other)?;
        self.mix(out, &other);
        Ok(())
    }

    fn prefetch_cell(&self, a: usize) {
        self.first.prefetch_cell(a);
        self.second.prefetch_cell(a);
    }

    fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        let cells: Vec<usize> = cells.collect();
        self.first.will_need_cells(&mut cells.iter().copied());
        self.second.will_need_cells(&mut cells.into_iter());
    }

    fn takes_cell_hints(&self) -> bool {
        self.first.takes_cell_hints() || self.second.takes_cell_hints()
    }
}

/// Implements [`BrdfSource`] for a pointer type by forwarding every method to the source it
/// points to.
macro_rules! forward_source {
    ($($pointer:ty),*) => {$(
        impl<S: BrdfSource + ?Sized> BrdfSource for $pointer {
            fn channels(&self) -> Channels {
                (**self).channels()
            }

            fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
                (**self).eval(wi, wo, out)
            }

            fn grid(&self) -> Option<AngularGrid> {
                (**self).grid()
            }

            fn lookup(&self) -> Lookup {
                (**self).lookup()
            }

            fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
                (**self).eval_cell(a, out)
            }

            fn prefetch_cell(&self, a: usize) {
                (**self).prefetch_cell(a);
            }

            fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
                (**self).will_need_cells(cells);
            }

            fn takes_cell_hints(&self) -> bool {
                (**self).takes_cell_hints()
            }

            fn cell_source(&self) -> Option<&dyn std::any::Any> {
                (**self).cell_source()
            }
        }
    )*};
}

// A boxed or borrowed source is the source (command lines open sources by kind at run time;
// wrappers such as `WithLookup` may borrow one).
forward_source!(Box<S>, &S);

/// The argument check every [`BrdfSource::eval`] starts with: `out` must have one slot per
/// channel (`channels`), else an [`Error::InvalidArgument`] saying so.
pub fn check_output_len(out: &[f64], channels: usize) -> Result<()> {
    if out.len() == channels {
        Ok(())
    } else {
        Err(Error::InvalidArgument {
            reason: format!(
                "output buffer has {} slots for {channels} channels",
                out.len()
            ),
        })
    }
}

/// Default outlier threshold in 1/sr: 1e4, above the specular peak of the shiniest measured
/// materials (~1e3..1e4 1/sr for chrome-like MERL samples) and far below the blow-ups of
/// Neural-BRDF networks at grazing angles (up to ~3e6 1/sr) and of RGL files divided by a tiny
/// cos(theta_o) at grazing bin centres (up to ~3e7 1/sr on the MERL grid).
pub const DEFAULT_OUTLIER_THRESHOLD: f64 = 1e4;

/// How resampling treats extreme values and sources that are not reciprocal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResampleOptions {
    /// Values above this (1/sr) are counted as outliers in the report.
    pub outlier_threshold: f64,
    /// Clamp outliers to the threshold (otherwise they are stored as computed).
    pub clamp_outliers: bool,
    /// Store the reciprocal mean `(f(wi, wo) + f(wo, wi)) / 2` of each bin centre (default;
    /// RGL files weight the two orders by the square of the cosine each divides by, see
    /// `PairWeights::CosOutgoingSquared`).
    ///
    /// The grid folds phi_d into [0, pi) by reciprocity, so every lookup of a pair and of its
    /// swapped pair reads the same cell. Measured RGL files and Neural-BRDF networks are not
    /// exactly reciprocal (the two orders differ by a few % at the median, by tens of % on some
    /// glossy materials); storing one order would show the other order's pixels, on the far side
    /// of the plane of incidence, a different material (a seam through the highlight). The mean
    /// is the least-squares reciprocal fit; the report measures the part it removes
    /// ([`ImportReport::non_reciprocity`]). `false` stores `f(wi, wo)` of the bin centre's own
    /// direction pair ([`crate::HalfDiff::to_dirs`]) and costs half the evaluations.
    pub reciprocal: bool,
}

impl ResampleOptions {
    /// Checks the options: the outlier threshold must be a finite number > 0 (a negative or zero
    /// threshold with clamping would store every value as the threshold). Called by every
    /// resampling method that takes options.
    pub fn validate(&self) -> Result<()> {
        let t = self.outlier_threshold;
        if !(t.is_finite() && t > 0.0) {
            return Err(Error::InvalidArgument {
                reason: format!("outlier threshold {t} must be a finite number > 0 (in 1/sr)"),
            });
        }
        Ok(())
    }
}

impl Default for ResampleOptions {
    /// Count values above [`DEFAULT_OUTLIER_THRESHOLD`], do not clamp, store reciprocal means.
    fn default() -> Self {
        Self {
            outlier_threshold: DEFAULT_OUTLIER_THRESHOLD,
            clamp_outliers: false,
            reciprocal: true,
        }
    }
}

/// What happened to the values while a source was resampled onto a grid.
///
/// Counts are over stored values (cells x channels) of cells above the horizon; cells below the
/// horizon are written as 0.0 and counted only in `below_horizon_cells`.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct ImportReport {
    /// Values computed (cells above the horizon x channels).
    pub values: usize,
    /// Angular cells below the horizon (written as 0.0, not evaluated).
    pub below_horizon_cells: usize,
    /// Negative values clamped to 0 (Mitsuba's RGB interpolation, and MERL's invalid markers
    /// that had no measured neighbour).
    pub negatives_clamped: usize,
    /// MERL's invalid markers (cells it did not measure) filled with the mean of measured
    /// neighbours (on MERL's own grid; [`crate::merl::MerlBrdf::to_dataset_order`]).
    #[serde(default)]
    pub markers_filled: usize,
    /// NaN or infinite values (or values beyond the f32 range), replaced by 0.
    pub non_finite: usize,
    /// Values above the source's outlier threshold (see the source's documentation).
    pub outliers: usize,
    /// Outlier values clamped to the threshold (0 unless clamping was asked for).
    pub outliers_clamped: usize,
    /// Smallest stored value (after clamping), `+inf` when nothing was stored.
    pub min: f64,
    /// Largest stored value (after clamping), `-inf` when nothing was stored.
    pub max: f64,
    /// Sum over stored values of the squared non-reciprocal part `((f(wi, wo) - f(wo, wi)) / 2)^2`,
    /// each weighted by `cos theta_i cos theta_o` of its bin centre (0 unless
    /// [`ResampleOptions::reciprocal`] resampling measured it).
    #[serde(default)]
    pub non_reciprocal_sq: f64,
    /// Sum over stored values of the squared reciprocal mean `((f(wi, wo) + f(wo, wi)) / 2)^2`,
    /// weighted as [`ImportReport::non_reciprocal_sq`] (0 unless [`ResampleOptions::reciprocal`]
    /// resampling measured it).
    #[serde(default)]
    pub reciprocal_sq: f64,
    /// Histogram of the per-value relative non-reciprocal part `|a - b| / (|a| + |b|)` of the
    /// two orders `a`, `b`: bin `k` counts values in `[10^(k/8 - 4), 10^((k+1)/8 - 4))` (bin 0
    /// also everything below 1e-4, bin 31 everything up to 1): 8 bins a decade, for a median
    /// that grazing blow-ups do not dominate ([`ImportReport::non_reciprocity_median`]).
    #[serde(default)]
    pub non_reciprocal_hist: [u64; RECIPROCITY_BINS],
}

/// Bins of [`ImportReport::non_reciprocal_hist`].
pub const RECIPROCITY_BINS: usize = 32;
/// Bins a decade of [`ImportReport::non_reciprocal_hist`].
const RECIPROCITY_BINS_PER_DECADE: f64 = 8.0;

/// The bin of [`ImportReport::non_reciprocal_hist`] that relative part `r` falls in, by its
/// definition: `floor((log10 r + 4) * 8)`, in `0..RECIPROCITY_BINS`.
fn reciprocity_bin_by_log(r: f64) -> usize {
    let x = (r.log10() + 4.0) * RECIPROCITY_BINS_PER_DECADE;
    // (`as` saturates: NaN and negative x land in bin 0.)
    (x as usize).min(RECIPROCITY_BINS - 1)
}

/// The bin of `r`, as [`reciprocity_bin_by_log`] gives it, without a logarithm: the number of
/// bin boundaries at or below `r` (comparisons that vectorise; a `log10` was ~10 % of a
/// Neural-BRDF import). The boundaries are the smallest values the definition puts in each
/// bin, found once by bisection over the bits of positive `f64`s, then one `+inf` to make
/// 32 lanes.
#[inline]
fn reciprocity_bin(r: f64) -> usize {
    static BOUNDARIES: std::sync::OnceLock<[f64; RECIPROCITY_BINS]> = std::sync::OnceLock::new();
    let boundaries = BOUNDARIES.get_or_init(|| {
        std::array::from_fn(|k| {
            if k + 1 == RECIPROCITY_BINS {
                return f64::INFINITY;
            }
            // The smallest positive r in bin k + 1 or above (1.0 is in the last bin).
            let (mut lo, mut hi) = (0u64, 1f64.to_bits());
            while hi - lo > 1 {
                let mid = lo + (hi - lo) / 2;
                if reciprocity_bin_by_log(f64::from_bits(mid)) > k {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            f64::from_bits(hi)
        })
    });
    let mut below = [0u64; 4];
    for four in boundaries.chunks_exact(4) {
        for (b, &t) in below.iter_mut().zip(four) {
            *b += u64::from(t <= r);
        }
    }
    // (At most 31: r = +inf is not a relative part.)
    (below.iter().sum::<u64>() as usize).min(RECIPROCITY_BINS - 1)
}

impl ImportReport {
    /// An empty report (min = +inf, max = -inf).
    pub fn new() -> Self {
        Self {
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            ..Self::default()
        }
    }

    /// Records one evaluated value and returns the value to store: NaN/inf/beyond f32 -> 0,
    /// negative -> 0,
    /// above `outlier` -> counted, and clamped to `outlier` when `clamp_outliers` is set.
    pub fn record(&mut self, v: f64, outlier: Option<f64>, clamp_outliers: bool) -> f64 {
        self.values += 1;
        let mut v = v;
        if !v.is_finite() || v.abs() > f64::from(f32::MAX) {
            self.non_finite += 1;
            v = 0.0;
        } else if v < 0.0 {
            self.negatives_clamped += 1;
            v = 0.0;
        }
        if let Some(t) = outlier
            && v > t
        {
            self.outliers += 1;
            if clamp_outliers {
                self.outliers_clamped += 1;
                v = t;
            }
        }
        self.min = self.min.min(v);
        self.max = self.max.max(v);
        v
    }

    /// An error ([`crate::Error::NonFiniteValues`], naming `source`) when any resampled value
    /// was NaN or infinite: `record` stores such values as 0, which an import must not do
    /// silently.
    pub fn ensure_finite(&self, source: &str) -> crate::Result<()> {
        if self.non_finite > 0 {
            return Err(crate::Error::NonFiniteValues {
                source_name: source.to_owned(),
                count: self.non_finite,
                values: self.values,
            });
        }
        Ok(())
    }

    /// Records the two orders `a = f(wi, wo)`, `b = f(wo, wi)` of one value, with the weight
    /// `cos_weight = cos theta_i cos theta_o` of its directions, and returns the value to store,
    /// `weight_a a + (1 - weight_a) b` (to pass to [`ImportReport::record`]; `weight_a` = 1/2:
    /// the plain mean); non-finite pairs are not measured. The report measures the plain mean
    /// and half difference.
    pub fn record_pair(&mut self, a: f64, b: f64, cos_weight: f64, weight_a: f64) -> f64 {
        let (mean, half_diff) = (0.5 * (a + b), 0.5 * (a - b));
        let stored = weight_a * a + (1.0 - weight_a) * b;
        if mean.is_finite() && half_diff.is_finite() {
            self.reciprocal_sq += cos_weight * mean * mean;
            self.non_reciprocal_sq += cos_weight * half_diff * half_diff;
            let size = a.abs() + b.abs();
            if size > 0.0 {
                let r = (a - b).abs() / size;
                self.non_reciprocal_hist[reciprocity_bin(r)] += 1;
            }
        }
        stored
    }

    /// The median over values of the relative non-reciprocal part `|a - b| / (|a| + |b|)`
    /// (unweighted; from [`ImportReport::non_reciprocal_hist`], so to within a factor
    /// `10^(1/16)`, ~15 %: the bin's geometric centre; in the first bin, which also holds
    /// everything below 1e-4, only "below 1.33e-4" is known); `None` when nothing was measured.
    pub fn non_reciprocity_median(&self) -> Option<f64> {
        let total: u64 = self.non_reciprocal_hist.iter().sum();
        if total == 0 {
            return None;
        }
        let mut seen = 0;
        let bin = self.non_reciprocal_hist.iter().position(|&c| {
            seen += c;
            2 * seen >= total
        })?;
        Some(10f64.powf((bin as f64 + 0.5) / RECIPROCITY_BINS_PER_DECADE - 4.0))
    }

    /// The relative RMS size of the source's non-reciprocal part,
    /// `sqrt(sum w h^2 / sum w m^2)` with `h`, `m` the half difference and the mean of the two
    /// orders of each value and `w = cos theta_i cos theta_o` (projected solid angle: grazing
    /// cells, where RGL files divide by a tiny cosine and networks blow up, would otherwise
    /// dominate: an audit read 68.9 % unweighted for paper_white, ~2.5 % with both angles below
    /// 80 degrees); `None` when resampling did not measure it (or every value was 0).
    pub fn non_reciprocity(&self) -> Option<f64> {
        (self.reciprocal_sq > 0.0).then(|| (self.non_reciprocal_sq / self.reciprocal_sq).sqrt())
    }

    /// Combines two reports (of disjoint parts of the same import).
    pub fn merge(mut self, other: &Self) -> Self {
        self.non_reciprocal_sq += other.non_reciprocal_sq;
        self.reciprocal_sq += other.reciprocal_sq;
        for (a, b) in self
            .non_reciprocal_hist
            .iter_mut()
            .zip(&other.non_reciprocal_hist)
        {
            *a += b;
        }
        self.values += other.values;
        self.below_horizon_cells += other.below_horizon_cells;
        self.negatives_clamped += other.negatives_clamped;
        self.markers_filled += other.markers_filled;
        self.non_finite += other.non_finite;
        self.outliers += other.outliers;
        self.outliers_clamped += other.outliers_clamped;
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
        self
    }
}

impl std::fmt::Display for ImportReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} values (min {:.4e}, max {:.4e}), {} below-horizon cells, {} negatives clamped, \
             {} non-finite, {} outliers ({} clamped)",
            self.values,
            self.min,
            self.max,
            self.below_horizon_cells,
            self.negatives_clamped,
            self.non_finite,
            self.outliers,
            self.outliers_clamped
        )?;
        if self.markers_filled > 0 {
            write!(
                f,
                ", {} unmeasured (marker) values filled from their neighbours",
                self.markers_filled
            )?;
        }
        match (self.non_reciprocity(), self.non_reciprocity_median()) {
            (Some(r), Some(m)) => write!(
                f,
                ", non-reciprocal part: median {} of values, RMS {:.2} % (cosine-weighted)",
                // The first bin (centre 1.15e-4) also holds everything below 1e-4, exact
                // zeros too: only an upper bound is known there.
                if m < 1.3e-4 {
                    "< 0.013 %".to_owned()
                } else {
                    format!("{:.2} %", 100.0 * m)
                },
                100.0 * r
            ),
            (Some(r), None) => write!(
                f,
                ", non-reciprocal part: RMS {:.2} % (cosine-weighted)",
                100.0 * r
            ),
            _ => Ok(()),
        }
    }
}

/// Resamples `eval` over every bin centre of `grid` in dataset order
/// (`angular_index * n_channels + channel`), in parallel; cells whose bin-centre directions are
/// not both above the horizon are 0.0. `eval(wi, wo, out)` fills one cell's channels; with
/// [`ResampleOptions::reciprocal`] a cell stores the mean of `eval(wi, wo)` and `eval(wo, wi)`,
/// weighted by `weights` ([`PairWeights`]).
pub(crate) fn resample_cells<F>(
    grid: &crate::grid::AngularGrid,
    n_channels: usize,
    options: ResampleOptions,
    weights: PairWeights,
    eval: F,
) -> Result<(Vec<f32>, ImportReport)>
where
    F: Fn(Vec3, Vec3, &mut [f64]) -> Result<()> + Sync,
{
    let mut out = vec![0f32; grid.len() * n_channels];
    let report = resample_cells_into(grid, 0, &mut out, n_channels, options, weights, eval)?;
    Ok((out, report))
}

/// How the reciprocal mean of [`ResampleOptions::reciprocal`] weighs the two orders.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PairWeights {
    /// `(f(wi, wo) + f(wo, wi)) / 2` (sources evaluated directly as f: Neural-BRDF networks).
    Equal,
    /// Inverse-variance weights for sources whose f is a tabulated `f cos(theta_o)` divided by
    /// `cos(theta_o)` (RGL files, as Mitsuba returns them): the table's error is about the
    /// same everywhere, so an order's error grows like `1 / cos(theta_o)` and its weight is
    /// `cos^2(theta_o)`: `(c_o^2 f(wi, wo) + c_i^2 f(wo, wi)) / (c_o^2 + c_i^2)`. Where one
    /// direction is grazing, the order that divides by its tiny cosine (whose values near the
    /// horizon are 2-10x the other's: bright specks along the terminator of imported
    /// spheres) hardly counts. Still symmetric in the two directions, so still reciprocal.
    CosOutgoingSquared,
}

/// As [`resample_cells`] for the block of cells `first_cell..first_cell + out.len() / n_channels`,
/// written into `out` (its length must be a multiple of `n_channels` inside the grid).
pub(crate) fn resample_cells_into<F>(
    grid: &crate::grid::AngularGrid,
    first_cell: usize,
    out: &mut [f32],
    n_channels: usize,
    options: ResampleOptions,
    weights: PairWeights,
    eval: F,
) -> Result<ImportReport>
where
    F: Fn(Vec3, Vec3, &mut [f64]) -> Result<()> + Sync,
{
    resample_cells_indexed_into(
        grid,
        first_cell,
        out,
        n_channels,
        options,
        weights,
        |flat| grid.bin_centre_flat(flat).to_dirs(),
        |_, wi, wo, out| eval(wi, wo, out),
    )
}

/// Which evaluation of a cell [`resample_cells_indexed_into`] asks for: the cell's flat index
/// and whether the directions are swapped (`eval(wo, wi)`, the reciprocal order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct PairSlot {
    /// The cell's flat angular index in the grid.
    pub cell: usize,
    /// Whether this is the swapped order `(wo, wi)` of the cell's bin-centre directions.
    pub swapped: bool,
}

/// As [`resample_cells_into`], with `eval` also told which cell and order it evaluates, and
/// each cell's bin-centre directions `(wi, wo)` taken from `directions(flat)`, which must give
/// `grid.bin_centre_flat(flat).to_dirs()` (for sources that precompute per-cell work once for
/// many materials, such as the Neural-BRDF networks' inputs).
#[allow(clippy::too_many_arguments)]
pub(crate) fn resample_cells_indexed_into<D, F>(
    grid: &crate::grid::AngularGrid,
    first_cell: usize,
    out: &mut [f32],
    n_channels: usize,
    options: ResampleOptions,
    weights: PairWeights,
    directions: D,
    eval: F,
) -> Result<ImportReport>
where
    D: Fn(usize) -> (Vec3, Vec3) + Sync,
    F: Fn(PairSlot, Vec3, Vec3, &mut [f64]) -> Result<()> + Sync,
{
    use rayon::prelude::*;
    options.validate()?;
    if n_channels == 0
        || !out.len().is_multiple_of(n_channels)
        || first_cell + out.len() / n_channels > grid.len()
    {
        return Err(crate::error::Error::InvalidArgument {
            reason: format!(
                "block of {} values from cell {first_cell} does not fit grid {grid} with {n_channels} channels",
                out.len()
            ),
        });
    }
    let outlier = Some(options.outlier_threshold);
    // Chunks of whole theta_h rows keep the per-task overhead small.
    let cells_per_chunk = (grid.n_theta_d * grid.n_phi_d).max(1);
    out.par_chunks_mut(cells_per_chunk * n_channels)
        .enumerate()
        .map(|(chunk, values)| -> Result<ImportReport> {
            let mut report = ImportReport::new();
            let mut buf = vec![0f64; n_channels];
            let mut swapped = vec![0f64; n_channels];
            for (k, cell) in values.chunks_mut(n_channels).enumerate() {
                let flat = first_cell + chunk * cells_per_chunk + k;
                let (wi, wo) = directions(flat);
                if !(wi[2] > 0.0 && wo[2] > 0.0) {
                    report.below_horizon_cells += 1;
                    cell.iter_mut().for_each(|v| *v = 0.0);
                    continue;
                }
                let slot = |reversed| PairSlot {
                    cell: flat,
                    swapped: reversed,
                };
                eval(slot(false), wi, wo, &mut buf)?;
                if options.reciprocal {
                    eval(slot(true), wo, wi, &mut swapped)?;
                    let weight_a = match weights {
                        PairWeights::Equal => 0.5,
                        PairWeights::CosOutgoingSquared => {
                            let (co2, ci2) = (wo[2] * wo[2], wi[2] * wi[2]);
                            co2 / (co2 + ci2)
                        }
                    };
                    for (a, &b) in buf.iter_mut().zip(&swapped) {
                        *a = report.record_pair(*a, b, wi[2] * wo[2], weight_a);
                    }
                }
                for (o, &v) in cell.iter_mut().zip(&buf) {
                    *o = report.record(v, outlier, options.clamp_outliers) as f32;
                }
            }
            Ok(report)
        })
        .try_reduce(ImportReport::new, |a, b| Ok(a.merge(&b)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reciprocity_bins_without_a_logarithm_match_the_definition() {
        let same = |r: f64| assert_eq!(reciprocity_bin(r), reciprocity_bin_by_log(r), "r = {r:e}");
        for r in [
            0.0,
            f64::MIN_POSITIVE,
            5e-324,
            1e-300,
            1e-4,
            0.5,
            1.0,
            f64::NAN,
            // Not a relative part, but the definition still puts it in the last bin.
            f64::INFINITY,
        ] {
            same(r);
        }
        assert_eq!(reciprocity_bin(0.0), 0);
        assert_eq!(reciprocity_bin(1.0), RECIPROCITY_BINS - 1);
        // Every value within 4096 ulps of each boundary (where a logarithm's rounding
        // decides), and each bin reached.
        let mut reached = [false; RECIPROCITY_BINS];
        for k in 1..RECIPROCITY_BINS {
            let t = 10f64
                .powf(k as f64 / RECIPROCITY_BINS_PER_DECADE - 4.0)
                .to_bits();
            for bits in t - 4096..=t + 4096 {
                same(f64::from_bits(bits));
            }
            reached[reciprocity_bin(f64::from_bits(t + 4096))] = true;
        }
        assert!(reached[1..].iter().all(|&r| r), "{reached:?}");
        // Log-uniform values over [1e-6, 1].
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..200_000 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            same(10f64.powf(-6.0 * (s >> 11) as f64 / (1u64 << 53) as f64));
        }
    }

    #[test]
    fn record_clamps_and_counts() {
        let mut r = ImportReport::new();
        assert_eq!(r.record(-0.5, None, false), 0.0);
        assert_eq!(r.record(f64::NAN, None, false), 0.0);
        assert_eq!(r.record(7.0, Some(5.0), false), 7.0);
        assert_eq!(r.record(9.0, Some(5.0), true), 5.0);
        assert_eq!(r.record(2.0, Some(5.0), true), 2.0);
        assert_eq!(
            (
                r.values,
                r.negatives_clamped,
                r.non_finite,
                r.outliers,
                r.outliers_clamped
            ),
            (5, 1, 1, 2, 1)
        );
        assert_eq!((r.min, r.max), (0.0, 7.0));
        let m = r.merge(&ImportReport::new());
        assert_eq!(m, r);
        let e = r.ensure_finite("net").unwrap_err().to_string();
        assert!(e.starts_with("net: 1 of 5 resampled values are NaN"), "{e}");
        // A finite value beyond the f32 range (a MERL number of 1e300) is not called NaN or
        // infinite only.
        let mut big = ImportReport::new();
        assert_eq!(big.record(1e300, None, false), 0.0);
        assert_eq!(big.non_finite, 1);
        let e = big.ensure_finite("m.binary").unwrap_err().to_string();
        assert!(
            e.starts_with(
                "m.binary: 1 of 1 resampled values are NaN or infinite, or finite but beyond the \
                 f32 range of a store"
            ),
            "{e}"
        );
        let mut ok = ImportReport::new();
        ok.record(1.0, None, false);
        assert!(ok.ensure_finite("net").is_ok());
        // The edges are kept: the largest f32 is stored as it is, and a value equal to the
        // outlier threshold is not an outlier.
        let mut edges = ImportReport::new();
        let largest = f64::from(f32::MAX);
        assert_eq!(edges.record(largest, None, false), largest);
        assert_eq!(edges.record(5.0, Some(5.0), true), 5.0);
        assert_eq!(
            (edges.non_finite, edges.outliers, edges.outliers_clamped),
            (0, 0, 0)
        );
        assert_eq!((edges.min, edges.max), (5.0, largest));
    }

    /// `record_pair` by hand: the stored value is the weighted mean of the two orders; the sums
    /// take the plain mean and half difference times the cosine weight; the histogram bins
    /// `|a - b| / (|a| + |b|)`. A pair of zeros (no relative part) and a pair whose mean
    /// overflows are not measured.
    #[test]
    fn record_pair_measures_finite_pairs_by_hand() {
        let mut r = ImportReport::new();
        // a = 3, b = 1: stored 0.25 x 3 + 0.75 x 1 = 1.5; mean 2, half difference 1, weight
        // 0.5: sums 2 and 0.5; relative part 2 / 4 = 0.5, in bin floor((log10 0.5 + 4) x 8)
        // = floor(29.59) = 29 (2 / (3 x 1) would be bin 30).
        assert_eq!(r.record_pair(3.0, 1.0, 0.5, 0.25), 1.5);
        assert_eq!((r.reciprocal_sq, r.non_reciprocal_sq), (2.0, 0.5));
        let mut hist = [0u64; RECIPROCITY_BINS];
        hist[29] = 1;
        assert_eq!(r.non_reciprocal_hist, hist);
        assert_eq!(r.non_reciprocity(), Some(0.5));
        let median = r.non_reciprocity_median().unwrap();
        assert!(
            (median - 10f64.powf(29.5 / 8.0 - 4.0)).abs() < 1e-15,
            "{median}"
        );
        let before = r;
        assert_eq!(r.record_pair(0.0, 0.0, 1.0, 0.5), 0.0);
        // 1.5e308 + 1.5e308 overflows: the mean is infinite, the half difference 0.
        assert_eq!(r.record_pair(1.5e308, 1.5e308, 1.0, 0.5), 1.5e308);
        assert_eq!(r, before);
        assert_eq!(ImportReport::new().non_reciprocity_median(), None);
    }

    /// Merging adds every count, sum and histogram bin and keeps the extreme min and max.
    #[test]
    fn merge_adds_every_count_and_keeps_the_extremes() {
        let report = |k: usize, min: f64, max: f64| {
            let mut hist = [0u64; RECIPROCITY_BINS];
            hist[k] = k as u64;
            hist[0] = 1;
            ImportReport {
                values: 100 * k,
                below_horizon_cells: 10 * k,
                negatives_clamped: k,
                markers_filled: k + 1,
                non_finite: k + 2,
                outliers: k + 3,
                outliers_clamped: k + 4,
                min,
                max,
                non_reciprocal_sq: k as f64,
                reciprocal_sq: 10.0 * k as f64,
                non_reciprocal_hist: hist,
            }
        };
        let merged = report(3, 0.5, 2.0).merge(&report(5, 0.25, 1.0));
        let mut hist = [0u64; RECIPROCITY_BINS];
        (hist[0], hist[3], hist[5]) = (2, 3, 5);
        assert_eq!(
            merged,
            ImportReport {
                values: 800,
                below_horizon_cells: 80,
                negatives_clamped: 8,
                markers_filled: 10,
                non_finite: 12,
                outliers: 14,
                outliers_clamped: 16,
                min: 0.25,
                max: 2.0,
                non_reciprocal_sq: 8.0,
                reciprocal_sq: 80.0,
                non_reciprocal_hist: hist,
            }
        );
    }

    /// The report's one-line summary, written out: the marker count only when there is one,
    /// and the RMS alone for a report with sums but no histogram (one written before the
    /// histogram existed: `serde(default)` reads it as empty).
    #[test]
    fn display_mentions_markers_and_reciprocity_only_when_known() {
        let mut r = ImportReport {
            values: 3,
            below_horizon_cells: 1,
            min: 1.0,
            max: 2.0,
            ..ImportReport::new()
        };
        let plain = "3 values (min 1.0000e0, max 2.0000e0), 1 below-horizon cells, 0 negatives \
                     clamped, 0 non-finite, 0 outliers (0 clamped)";
        assert_eq!(r.to_string(), plain);
        (r.markers_filled, r.reciprocal_sq, r.non_reciprocal_sq) = (2, 4.0, 1.0);
        assert_eq!(
            r.to_string(),
            format!(
                "{plain}, 2 unmeasured (marker) values filled from their neighbours, \
                 non-reciprocal part: RMS 50.00 % (cosine-weighted)"
            )
        );
        let old: ImportReport = serde_json::from_str(
            r#"{"values": 3, "below_horizon_cells": 1, "negatives_clamped": 0, "non_finite": 0,
                "outliers": 0, "outliers_clamped": 0, "min": 1.0, "max": 2.0,
                "non_reciprocal_sq": 1.0, "reciprocal_sq": 4.0}"#,
        )
        .unwrap();
        assert_eq!(
            old.to_string(),
            format!("{plain}, non-reciprocal part: RMS 50.00 % (cosine-weighted)")
        );
    }

    /// A block that does not fit the grid is refused with an error, never a panic: no
    /// channels, a length that is not a whole number of cells, or cells past the grid's end.
    #[test]
    fn blocks_that_do_not_fit_the_grid_are_refused() {
        let grid = crate::grid::AngularGrid::new(2, 2, 4).unwrap();
        let eval = |_: Vec3, _: Vec3, out: &mut [f64]| {
            out.fill(0.5);
            Ok(())
        };
        let options = ResampleOptions::default();
        let refuse = |first: usize, len: usize, channels: usize| {
            let mut out = vec![0f32; len];
            let r = resample_cells_into(
                &grid,
                first,
                &mut out,
                channels,
                options,
                PairWeights::Equal,
                eval,
            );
            let e = r.unwrap_err();
            assert!(matches!(e, Error::InvalidArgument { .. }), "{e}");
            assert!(
                e.to_string().contains(&format!(
                    "block of {len} values from cell {first} does not fit grid"
                )),
                "{e}"
            );
        };
        refuse(0, 0, 0);
        refuse(0, 6, 0);
        refuse(0, 5, 2);
        refuse(10, 14, 2);
        refuse(16, 2, 2);
        // The last cells exactly: evaluated (or 0 below the horizon).
        let mut out = vec![f32::NAN; 12];
        let report =
            resample_cells_into(&grid, 10, &mut out, 2, options, PairWeights::Equal, eval).unwrap();
        assert!(out.iter().all(|&v| v == 0.5 || v == 0.0), "{out:?}");
        assert_eq!(report.values + 2 * report.below_horizon_cells, 12);
    }

    /// A source like an RGL file: a table of `f cos(theta_o)` whose error does not vanish at
    /// the horizon (here a constant 0.01 added to a white Lambertian's `cos / pi`), divided by
    /// `cos(theta_o)`. The plain reciprocal mean stores the order that divides by a grazing
    /// cosine too (values up to ~1/(2 cos) above 1/pi); the inverse-variance weights keep every
    /// cell with one direction above 10 degrees of elevation within 0.08 of 1/pi.
    #[test]
    fn cosine_weighted_reciprocal_mean_tames_grazing_divisions() {
        let grid = crate::grid::AngularGrid::new(16, 16, 32).unwrap();
        let eval = |_wi: Vec3, wo: Vec3, out: &mut [f64]| {
            out[0] = (wo[2] * std::f64::consts::FRAC_1_PI + 0.01) / wo[2];
            Ok(())
        };
        let options = ResampleOptions::default();
        let (plain, _) = resample_cells(&grid, 1, options, PairWeights::Equal, eval).unwrap();
        let (weighted, _) =
            resample_cells(&grid, 1, options, PairWeights::CosOutgoingSquared, eval).unwrap();
        let (mut worst_plain, mut worst_weighted) = (0.0f64, 0.0f64);
        for a in 0..grid.len() {
            let (wi, wo) = grid.bin_centre_flat(a).to_dirs();
            if wi[2] <= 0.0 || wo[2] <= 0.0 || wi[2].max(wo[2]) < 10f64.to_radians().sin() {
                continue;
            }
            worst_plain = worst_plain.max(f64::from(plain[a]) - std::f64::consts::FRAC_1_PI);
            worst_weighted =
                worst_weighted.max(f64::from(weighted[a]) - std::f64::consts::FRAC_1_PI);
        }
        assert!(worst_weighted < 0.08, "{worst_weighted}");
        assert!(worst_plain > 0.3, "{worst_plain}");
        // Both are reciprocal: a symmetric source is stored as it is by either.
        let sym = |wi: Vec3, wo: Vec3, out: &mut [f64]| {
            out[0] = 1.0 + wi[2] * wo[2];
            Ok(())
        };
        let (a, _) = resample_cells(&grid, 1, options, PairWeights::Equal, sym).unwrap();
        let (b, _) =
            resample_cells(&grid, 1, options, PairWeights::CosOutgoingSquared, sym).unwrap();
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 1e-6 * y));
    }

    /// A source that is not reciprocal (its value depends on which direction is incident):
    /// reciprocal resampling stores the mean of both orders and measures the removed part;
    /// one-order resampling stores f of the bin centre's own pair.
    #[test]
    fn reciprocal_resampling_stores_the_mean_of_both_orders() {
        let grid = crate::grid::AngularGrid::new(5, 6, 8).unwrap();
        let f = |wi: Vec3, wo: Vec3| [1.0 + 0.5 * wi[2] - 0.2 * wo[2], 2.0 + wi[0] * wo[1]];
        let eval = |wi: Vec3, wo: Vec3, out: &mut [f64]| {
            out.copy_from_slice(&f(wi, wo));
            Ok(())
        };
        let both = ResampleOptions::default();
        assert!(both.reciprocal);
        let one = ResampleOptions {
            reciprocal: false,
            ..both
        };
        let (mean, report) = resample_cells(&grid, 2, both, PairWeights::Equal, eval).unwrap();
        let (plain, plain_report) =
            resample_cells(&grid, 2, one, PairWeights::Equal, eval).unwrap();
        let (mut diff_sq, mut mean_sq, mut differs) = (0.0, 0.0, 0);
        let mut rel = Vec::new();
        for a in 0..grid.len() {
            let (wi, wo) = grid.bin_centre_flat(a).to_dirs();
            if !(wi[2] > 0.0 && wo[2] > 0.0) {
                assert_eq!(&mean[2 * a..2 * a + 2], [0.0, 0.0]);
                continue;
            }
            let (x, y) = (f(wi, wo), f(wo, wi));
            for c in 0..2 {
                let m = 0.5 * (x[c] + y[c]);
                assert!(
                    (f64::from(mean[2 * a + c]) - m).abs() <= 1e-6 * m.abs(),
                    "{a}"
                );
                assert!((f64::from(plain[2 * a + c]) - x[c]).abs() <= 1e-6 * x[c].abs());
                diff_sq += wi[2] * wo[2] * 0.25 * (x[c] - y[c]).powi(2);
                rel.push((x[c] - y[c]).abs() / (x[c].abs() + y[c].abs()));
                mean_sq += wi[2] * wo[2] * m * m;
                differs += usize::from((x[c] - y[c]).abs() > 1e-3);
            }
        }
        assert!(differs > 50, "the test source must not be reciprocal");
        // The histogram's median is within its bin width of the exact median.
        rel.sort_by(f64::total_cmp);
        let exact_median = rel[(rel.len() - 1) / 2];
        let median = report.non_reciprocity_median().unwrap();
        assert!(
            (median / exact_median).log10().abs() <= 1.0 / 8.0,
            "{median} vs {exact_median}"
        );
        assert_eq!(
            report.non_reciprocal_hist.iter().sum::<u64>() as usize,
            rel.len()
        );
        let r = report.non_reciprocity().unwrap();
        assert!(
            r > 0.01 && (r - (diff_sq / mean_sq).sqrt()).abs() < 1e-12 * r,
            "{r}"
        );
        assert!(
            report.to_string().contains("non-reciprocal part"),
            "{report}"
        );
        assert_eq!(plain_report.non_reciprocity(), None);
        assert_eq!(report.values, plain_report.values);
        // A reciprocal source is stored as it is.
        let sym = |wi: Vec3, wo: Vec3, out: &mut [f64]| {
            out[0] = 1.0 + wi[2] * wo[2];
            Ok(())
        };
        let (a, ra) = resample_cells(&grid, 1, both, PairWeights::Equal, sym).unwrap();
        let (b, _) = resample_cells(&grid, 1, one, PairWeights::Equal, sym).unwrap();
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 1e-6 * y));
        assert!(ra.non_reciprocity().unwrap() < 1e-12);
    }

    /// A grid source whose cell `a` holds `scale * (a + channel)`.
    struct Ramp(AngularGrid, f64);

    impl BrdfSource for Ramp {
        fn channels(&self) -> Channels {
            Channels::Rgb
        }
        fn eval(&self, wi: Vec3, _wo: Vec3, out: &mut [f64]) -> Result<()> {
            for (c, o) in out.iter_mut().enumerate() {
                *o = self.1 * (wi[2] + c as f64);
            }
            Ok(())
        }
        fn grid(&self) -> Option<AngularGrid> {
            Some(self.0)
        }
        fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
            for (c, o) in out.iter_mut().enumerate() {
                *o = self.1 * (a + c) as f64;
            }
            Ok(())
        }
    }

    /// A source without a grid (channels given) that records the prefetch hints it gets
    /// (`prefetch_cell`'s cells, then `will_need_cells`' lists).
    struct Hinted(
        Channels,
        std::sync::Mutex<Vec<usize>>,
        std::sync::Mutex<Vec<Vec<usize>>>,
    );

    impl Hinted {
        fn new(channels: Channels) -> Self {
            Self(channels, Default::default(), Default::default())
        }
        fn hints(&self) -> Vec<usize> {
            self.1.lock().unwrap().clone()
        }
        fn will_need_hints(&self) -> Vec<Vec<usize>> {
            self.2.lock().unwrap().clone()
        }
    }

    impl BrdfSource for Hinted {
        fn channels(&self) -> Channels {
            self.0.clone()
        }
        fn eval(&self, _wi: Vec3, _wo: Vec3, out: &mut [f64]) -> Result<()> {
            check_output_len(out, self.0.len())?;
            out.fill(1.0);
            Ok(())
        }
        fn prefetch_cell(&self, a: usize) {
            self.1.lock().unwrap().push(a);
        }
        fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
            self.2.lock().unwrap().push(cells.collect());
        }
    }

    /// What [`Recorder`] was asked, in order.
    #[derive(Debug, PartialEq)]
    enum Event {
        WillNeed(Vec<usize>),
        Prefetch(usize),
        Eval(usize),
    }

    /// A grid source (cell `a` holds `a + channel`, cell 13 fails) that records what it is
    /// asked.
    /// The second field: whether it takes hints (`takes_cell_hints`).
    struct Recorder(std::sync::Mutex<Vec<Event>>, bool);

    impl BrdfSource for Recorder {
        fn channels(&self) -> Channels {
            Channels::Rgb
        }
        fn eval(&self, _wi: Vec3, _wo: Vec3, _out: &mut [f64]) -> Result<()> {
            unreachable!("only cells are evaluated")
        }
        fn grid(&self) -> Option<AngularGrid> {
            Some(AngularGrid::new(2, 2, 4).unwrap())
        }
        fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
            self.0.lock().unwrap().push(Event::Eval(a));
            if a == 13 {
                return Err(Error::InvalidArgument {
                    reason: "cell 13".into(),
                });
            }
            for (c, o) in out.iter_mut().enumerate() {
                *o = (a + c) as f64;
            }
            Ok(())
        }
        fn prefetch_cell(&self, a: usize) {
            self.0.lock().unwrap().push(Event::Prefetch(a));
        }
        fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
            self.0
                .lock()
                .unwrap()
                .push(Event::WillNeed(cells.collect()));
        }
        fn takes_cell_hints(&self) -> bool {
            self.1
        }
    }

    /// `eval_cells_in_order` hints every cell at once, then evaluates them in order, each
    /// after a prefetch `PREFETCH_AHEAD` cells ahead, hands each item its position and values,
    /// and stops at the first error of the source or of the visitor.
    #[test]
    fn eval_cells_in_order_hints_ahead_and_stops_at_the_first_error() {
        use Event::{Eval, Prefetch, WillNeed};
        assert_eq!(PREFETCH_AHEAD, 2, "the expected events below assume 2");
        let source = Recorder(Default::default(), true);
        let items = [(5, 'a'), (2, 'b'), (7, 'c'), (0, 'd')];
        let mut seen = Vec::new();
        eval_cells_in_order(
            &source,
            &items,
            |(a, _)| *a,
            |i, (_, name), f| {
                seen.push((i, *name, f.to_vec()));
                Ok::<_, Error>(())
            },
        )
        .unwrap();
        let want = [(0, 'a', 5.0), (1, 'b', 2.0), (2, 'c', 7.0), (3, 'd', 0.0)];
        let want: Vec<_> = want
            .iter()
            .map(|&(i, n, v)| (i, n, vec![v, v + 1.0, v + 2.0]))
            .collect();
        assert_eq!(seen, want);
        let events = std::mem::take(&mut *source.0.lock().unwrap());
        let want = [
            WillNeed(vec![5, 2, 7, 0]),
            Prefetch(7),
            Eval(5),
            Prefetch(0),
            Eval(2),
            Eval(7),
            Eval(0),
        ];
        assert_eq!(events, want);
        // The source's error ends the walk at its cell.
        let e = eval_cells_in_order(&source, &[1, 13, 4], |a| *a, |_, _, _| Ok::<_, Error>(()))
            .unwrap_err();
        assert!(e.to_string().contains("cell 13"), "{e}");
        let events = std::mem::take(&mut *source.0.lock().unwrap());
        let want = [WillNeed(vec![1, 13, 4]), Prefetch(4), Eval(1), Eval(13)];
        assert_eq!(events, want);
        // So does the visitor's, in its own error type.
        let r: std::result::Result<(), Box<dyn std::error::Error>> = eval_cells_in_order(
            &source,
            &[3, 6, 8],
            |a| *a,
            |i, a, _| {
                if *a == 6 {
                    return Err(format!("visitor at {i}").into());
                }
                Ok(())
            },
        );
        assert_eq!(r.unwrap_err().to_string(), "visitor at 1");
        assert_eq!(source.0.lock().unwrap().last(), Some(&Eval(6)));
        // No cells: a hint of none, nothing evaluated.
        eval_cells_in_order(
            &source,
            &[] as &[usize],
            |a| *a,
            |_, _, _| Ok::<_, Error>(()),
        )
        .unwrap();
        assert_eq!(source.0.lock().unwrap().last(), Some(&WillNeed(vec![])));
    }

    /// `will_need_pairs` hints a grid source the cells of the pairs' stencils (ascending, each
    /// once; none for a pair below or on the horizon) and nothing to a source without a grid.
    #[test]
    fn will_need_pairs_hints_the_stencils_of_the_pairs_above_the_horizon() {
        let source = Recorder(Default::default(), true);
        let grid = source.grid().unwrap();
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let pairs = [
            ([0.0, 0.0, 1.0], [s, 0.0, s]),
            ([0.3, 0.1, 0.9], [-0.5, 0.2, 0.8]),
            ([0.0, 0.0, 1.0], [s, 0.0, -s]),    // below the horizon
            ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), // on it (no lookup reads a cell there)
            ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.0, 0.0, 1.0], [s, 0.0, s]), // the first again
        ];
        will_need_pairs(&source, &pairs);
        let stencils = pairs[..2].iter().flat_map(|&(wi, wo)| {
            let hd = HalfDiff::from_dirs(wi, wo).unwrap();
            grid.interpolation_stencil(&hd)
        });
        let cells = |weighted_only: bool| {
            let mut cells: Vec<usize> = (stencils.clone())
                .filter(|&(_, w)| w != 0.0 || !weighted_only)
                .map(|(a, _)| a)
                .collect();
            cells.sort_unstable();
            cells.dedup();
            cells
        };
        // Cells of a weight 0 in every stencil are read by no lookup: not hinted.
        let want = cells(true);
        assert!(
            want.len() > 2 && want.len() < cells(false).len(),
            "{want:?}"
        );
        let events = std::mem::take(&mut *source.0.lock().unwrap());
        assert_eq!(events, [Event::WillNeed(want)]);
        // Only below or on the horizon: a hint of no cells.
        will_need_pairs(&source, &pairs[2..5]);
        assert_eq!(*source.0.lock().unwrap(), [Event::WillNeed(vec![])]);
        // Not a grid source: no hint.
        let plain = Hinted::new(Channels::Rgb);
        will_need_pairs(&plain, &pairs);
        assert!(plain.will_need_hints().is_empty());
        // A grid source that takes no hints (a store in memory): none.
        let deaf = Recorder(Default::default(), false);
        will_need_pairs(&deaf, &pairs);
        assert!(deaf.0.lock().unwrap().is_empty());
        source.0.lock().unwrap().clear();
        // Boxed or borrowed, it is the source: hinted.
        will_need_pairs(&Box::new(&source), &pairs[..1]);
        assert_eq!(source.0.lock().unwrap().len(), 1);
    }

    /// A source that is not a grid source refuses cell lookups (the trait's default), so does a
    /// blend of such sources; a blend passes prefetch hints on to both of its sources; blends
    /// need equal channels; and output buffers must have one slot per channel.
    #[test]
    fn non_grid_sources_refuse_cells_and_blends_pass_hints_on() {
        let (a, b) = (Hinted::new(Channels::Rgb), Hinted::new(Channels::Rgb));
        let e = a.eval_cell(0, &mut [0.0; 3]).unwrap_err();
        assert!(matches!(e, Error::InvalidArgument { .. }), "{e}");
        assert!(
            e.to_string().contains("eval_cell: not a grid source"),
            "{e}"
        );
        let blend = Blend::new(&a, &b, 0.5).unwrap();
        assert_eq!(blend.grid(), None);
        assert!(blend.eval_cell(0, &mut [0.0; 3]).is_err());
        blend.prefetch_cell(7);
        blend.prefetch_cell(2);
        assert_eq!((a.hints(), b.hints()), (vec![7, 2], vec![7, 2]));
        blend.will_need_cells(&mut [4, 1, 9].into_iter());
        // Through a box and a reference of the blend too (the forwarding impls).
        let boxed: Box<dyn BrdfSource> = Box::new(&blend);
        boxed.will_need_cells(&mut [3].into_iter());
        let want = vec![vec![4, 1, 9], vec![3]];
        assert_eq!(
            (a.will_need_hints(), b.will_need_hints()),
            (want.clone(), want)
        );
        // A blend takes hints when either of its sources does.
        assert!(!blend.takes_cell_hints() && !boxed.takes_cell_hints());
        let recorder = Recorder(Default::default(), true);
        let (a_dyn, recorder_dyn): (&dyn BrdfSource, &dyn BrdfSource) = (&a, &recorder);
        for (first, second) in [(a_dyn, recorder_dyn), (recorder_dyn, a_dyn)] {
            assert!(Blend::new(first, second, 0.5).unwrap().takes_cell_hints());
        }
        let up = [0.0, 0.0, 1.0];
        let e = blend.eval(up, up, &mut [0.0; 4]).unwrap_err();
        assert!(e.to_string().contains("4 slots for 3 channels"), "{e}");
        let mut out = [0.0; 3];
        blend.eval(up, up, &mut out).unwrap();
        assert_eq!(out, [1.0; 3]);
        assert!(check_output_len(&[0.0; 2], 2).is_ok());
        let e = check_output_len(&[], 1).unwrap_err();
        assert!(e.to_string().contains("0 slots for 1 channels"), "{e}");
        let spectral = Hinted::new(Channels::spectral(vec![400.0, 500.0]).unwrap());
        let e = Blend::new(&a, &spectral, 0.5).err().unwrap();
        assert!(e.to_string().contains("same channels"), "{e}");
    }

    #[test]
    fn blends_mix_values_and_keep_a_shared_grid() {
        let g = AngularGrid::new(2, 2, 4).unwrap();
        let (one, ten) = (Ramp(g, 1.0), Ramp(g, 10.0));
        let b = Blend::new(&one, &ten, 0.25).unwrap();
        assert_eq!(b.grid(), Some(g));
        let mut out = [0.0; 3];
        b.eval_cell(5, &mut out).unwrap();
        // 0.25 (5 + c) + 0.75 x 10 (5 + c) = 7.75 (5 + c).
        assert_eq!(out, [38.75, 46.5, 54.25]);
        b.eval([0.0, 0.0, 0.5], [0.0, 0.0, 1.0], &mut out).unwrap();
        assert_eq!(out, [3.875, 11.625, 19.375]);
        let other_grid = Ramp(AngularGrid::new(2, 2, 8).unwrap(), 1.0);
        assert_eq!(Blend::new(&one, &other_grid, 0.5).unwrap().grid(), None);
        assert!(Blend::new(&one, &ten, f64::NAN).is_err());
        // A logarithmic lookup of blended cells is not the blend of the lookups: a blend with
        // such a source is evaluated pair by pair (no grid), with each source's own lookup.
        let log = crate::lookup::WithLookup::new(&ten, Lookup::LogMultilinear).unwrap();
        for (x, y) in [
            (&one as &dyn BrdfSource, &log as &dyn BrdfSource),
            (&log, &one),
        ] {
            let b = Blend::new(x, y, 0.25).unwrap();
            assert_eq!((b.grid(), b.lookup()), (None, Lookup::Multilinear));
        }
        let b = Blend::new(&log, &log, 0.25).unwrap();
        assert_eq!(b.grid(), None);
        let (wi, wo) = ([0.3, 0.0, 0.5], [0.0, 0.2, 1.0]);
        let (mut own, mut mixed) = ([0.0; 3], [0.0; 3]);
        log.eval(wi, wo, &mut own).unwrap();
        b.eval(wi, wo, &mut mixed).unwrap();
        for (m, o) in mixed.iter().zip(&own) {
            assert!((m - o).abs() <= 1e-15 * o, "{mixed:?} vs {own:?}");
        }
        // A boxed or borrowed source reports its source's lookup.
        let boxed: Box<dyn BrdfSource> = Box::new(log);
        let borrowed: &dyn BrdfSource = &&boxed;
        assert_eq!(borrowed.lookup(), Lookup::LogMultilinear);
        assert_eq!(boxed.grid(), Some(g));
    }
}
