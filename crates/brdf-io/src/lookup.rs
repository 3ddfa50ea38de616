//! How a grid source combines the cells of a lookup's interpolation stencil
//! ([`AngularGrid::interpolation_stencil`](crate::AngularGrid::interpolation_stencil)).
//!
//! Stored and predicted materials hold values at the bin centres of an angular grid. Between the
//! centres the library interpolates multilinearly ([`Lookup::Multilinear`], the default of every
//! source). Near grazing angles a glossy BRDF grows like 1 / (cos theta_i cos theta_o), convex
//! in theta_d, so the chord between two centres lies above it and stored glossy materials reflect
//! more light than they were sampled from (BENCHMARKS.md "albedo": 16 of 51 synthetic presets
//! above an albedo of 1.005 on the default 16,16,32 grid, none analytically).
//! [`Lookup::LogMultilinear`] interpolates ln f instead (a weighted geometric mean), exact for a
//! Lambertian and for any value that is exponential in the grid coordinates; it is the one to
//! use for energy (`specgp albedo --lookup log`) and for exports that must not gain it.
//! [`WithLookup`] gives any grid source another lookup.

use std::fmt;
use std::str::FromStr;
use std::sync::OnceLock;

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, Channels, HalfDiff, Vec3};
use crate::source::{BrdfSource, check_output_len};

/// How a lookup between bin centres combines the stencil's cells, channel by channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Lookup {
    /// sum w_c f_c: the library's lookup (and every figure's).
    #[default]
    Multilinear,
    /// exp(sum w_c ln f_c) in each channel whose weighted cells are all positive; the
    /// multilinear sum in a channel where one is not (zero or negative values, e.g. a raw GP
    /// mean).
    LogMultilinear,
}

impl Lookup {
    /// Both lookups, in the order the command line lists them.
    pub const ALL: [Lookup; 2] = [Lookup::Multilinear, Lookup::LogMultilinear];

    /// The name the command line and configs use: `linear` or `log`.
    pub fn name(self) -> &'static str {
        match self {
            Lookup::Multilinear => "linear",
            Lookup::LogMultilinear => "log",
        }
    }
}

impl fmt::Display for Lookup {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Lookup {
    type Err = Error;

    /// `linear` or `log`.
    fn from_str(s: &str) -> Result<Self> {
        Lookup::ALL
            .into_iter()
            .find(|l| l.name() == s)
            .ok_or_else(|| Error::InvalidArgument {
                reason: format!("unknown lookup {s:?}: expected linear or log"),
            })
    }
}

/// ln v where v > 0, NaN otherwise, into `logs`: a cell's logarithms as [`cell_record`] keeps
/// them (a NaN marks a channel whose logarithmic lookup falls back to the multilinear sum).
pub fn cell_logs(values: &[f64], logs: &mut [f64]) {
    for (l, &v) in logs.iter_mut().zip(values) {
        *l = if v > 0.0 { v.ln() } else { f64::NAN };
    }
}

/// A cell as [`combine`] reads it under `lookup`: its values, then (other than multilinear
/// lookups) their logarithms (ln v where v > 0, NaN otherwise), computed once for a cell read
/// many times.
pub fn cell_record(lookup: Lookup, values: &[f64]) -> Box<[f64]> {
    let n = values.len();
    let mut record = values.to_vec();
    if lookup != Lookup::Multilinear {
        record.resize(2 * n, 0.0);
        let (v, l) = record.split_at_mut(n);
        cell_logs(v, l);
    }
    record.into_boxed_slice()
}

/// The lookup's value per channel into `out`, from the stencil's cells as (record
/// ([`cell_record`] of `out.len()` channels), weight) pairs in stencil order (callers skip
/// zero weights, which [`AngularGrid::interpolation_stencil`] gives to cells that hold no
/// value). Multilinear: sum w v, from 0 in stencil order (the arithmetic of every multilinear
/// lookup, so its bits). Logarithmic: exp(sum w ln v) in a channel whose weighted cells are all
/// positive, the multilinear sum in the others.
pub fn combine(lookup: Lookup, cells: &[(&[f64], f64)], out: &mut [f64]) {
    let m = out.len();
    // Cell by cell over all channels (a loop that vectorises); each channel's terms in stencil
    // order either way.
    let weighted_sums = |offset: usize, out: &mut [f64]| {
        out.fill(0.0);
        for &(record, w) in cells {
            let part = &record[offset..offset + m];
            out.iter_mut().zip(part).for_each(|(o, v)| *o += w * v);
        }
    };
    match lookup {
        Lookup::Multilinear => weighted_sums(0, out),
        Lookup::LogMultilinear => {
            weighted_sums(m, out);
            for (k, o) in out.iter_mut().enumerate() {
                *o = if o.is_nan() {
                    cells
                        .iter()
                        .fold(0.0, |linear, &(record, w)| linear + w * record[k])
                } else {
                    o.exp()
                };
            }
        }
    }
}

/// [`combine`] of the weighted cells of `stencil` (an interpolation stencil: at most 8 flat cell
/// index and weight pairs; zero weights skipped) whose records `record` gives (each at most once per
/// lookup; e.g. from a cache): a whole lookup, into `out`.
pub fn look_up<'r, E>(
    lookup: Lookup,
    stencil: impl IntoIterator<Item = (usize, f64)>,
    record: impl FnMut(usize) -> std::result::Result<&'r [f64], E>,
    out: &mut [f64],
) -> std::result::Result<(), E> {
    let (cells, k) = weighted_cells(stencil, record)?;
    combine(lookup, &cells[..k], out);
    Ok(())
}

/// The weighted cells of `stencil` (an interpolation stencil: at most 8 flat cell index and
/// weight pairs) as (`cell(a)`, weight) pairs in stencil order, zero weights skipped (`cell` is
/// called once per weighted cell), and how many there are: [`look_up`]'s gathering, for
/// consumers that combine cells their own way.
pub fn weighted_cells<C: Copy + Default, E>(
    stencil: impl IntoIterator<Item = (usize, f64)>,
    mut cell: impl FnMut(usize) -> std::result::Result<C, E>,
) -> std::result::Result<([(C, f64); 8], usize), E> {
    let mut cells = [(C::default(), 0.0); 8];
    let mut k = 0;
    for (a, w) in stencil {
        if w != 0.0 {
            cells[k] = (cell(a)?, w);
            k += 1;
        }
    }
    Ok((cells, k))
}

/// A grid source looked up with another [`Lookup`]: the same cells ([`BrdfSource::eval_cell`]),
/// combined by `lookup` in [`BrdfSource::eval`] and reported by [`BrdfSource::lookup`], so that
/// consumers that interpolate cells themselves (the renderer, the RGL writer, the albedo) do
/// the same.
pub struct WithLookup<S> {
    inner: S,
    grid: AngularGrid,
    /// The inner source's channel count.
    n_channels: usize,
    lookup: Lookup,
    /// Other than multilinear lookups: each cell's [`cell_record`], made when first read (its
    /// logarithms once, not per lookup); empty under multilinear lookups.
    records: Vec<OnceLock<Box<[f64]>>>,
}

impl<S: BrdfSource> WithLookup<S> {
    /// `inner` looked up with `lookup`; an error when `inner` is not a grid source (an RGL
    /// file, a MERL file or a Neural-BRDF network has its own evaluation).
    pub fn new(inner: S, lookup: Lookup) -> Result<Self> {
        let grid = inner.grid().ok_or_else(|| Error::InvalidArgument {
            reason: format!(
                "the {lookup} lookup applies to grid sources (stored and predicted materials), \
                 not to a source with its own evaluation"
            ),
        })?;
        let cached = if lookup == Lookup::Multilinear {
            0
        } else {
            grid.len()
        };
        Ok(Self {
            n_channels: inner.channels().len(),
            inner,
            grid,
            lookup,
            records: (0..cached).map(|_| OnceLock::new()).collect(),
        })
    }

    /// The wrapped source.
    pub fn inner(&self) -> &S {
        &self.inner
    }

    /// Cell `a`'s record: cached (logarithmic lookups) or evaluated into `scratch`.
    fn record<'s>(&'s self, a: usize, scratch: &'s mut [f64]) -> Result<&'s [f64]> {
        let Some(cached) = self.records.get(a) else {
            self.inner.eval_cell(a, scratch)?;
            return Ok(scratch);
        };
        if let Some(r) = cached.get() {
            return Ok(r);
        }
        self.inner.eval_cell(a, scratch)?;
        // Another thread may have filled it meanwhile: both computed the same.
        Ok(cached.get_or_init(|| cell_record(self.lookup, scratch)))
    }
}

impl<S: BrdfSource> BrdfSource for WithLookup<S> {
    fn channels(&self) -> Channels {
        self.inner.channels()
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        check_output_len(out, self.n_channels)?;
        out.fill(0.0);
        let Some(hd) = HalfDiff::from_dirs(wi, wo).filter(|_| wi[2] > 0.0 && wo[2] > 0.0) else {
            return Ok(());
        };
        // Multilinear lookups evaluate each cell into its own scratch (not cached).
        let n = out.len();
        let mut scratch = vec![0.0; 8 * n];
        let mut parts = scratch.chunks_exact_mut(n.max(1));
        let stencil = self.grid.interpolation_stencil(&hd);
        look_up(
            self.lookup,
            stencil,
            |a| self.record(a, parts.next().unwrap_or_default()),
            out,
        )
    }

    fn grid(&self) -> Option<AngularGrid> {
        Some(self.grid)
    }

    fn lookup(&self) -> Lookup {
        self.lookup
    }

    fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
        self.inner.eval_cell(a, out)
    }

    fn prefetch_cell(&self, a: usize) {
        self.inner.prefetch_cell(a);
    }

    fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        self.inner.will_need_cells(cells);
    }

    fn takes_cell_hints(&self) -> bool {
        self.inner.takes_cell_hints()
    }

    fn cell_source(&self) -> Option<&dyn std::any::Any> {
        self.inner.cell_source()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid source whose cell values are `value(theta_h, theta_d, phi_d, channel)` at the
    /// bin centres, looked up multilinearly (as stored materials are).
    struct Cells<F> {
        grid: AngularGrid,
        value: F,
    }

    impl<F: Fn(&HalfDiff, usize) -> f64 + Sync> BrdfSource for Cells<F> {
        fn channels(&self) -> Channels {
            Channels::Rgb
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
            out.fill(0.0);
            let Some(hd) = HalfDiff::from_dirs(wi, wo).filter(|_| wi[2] > 0.0 && wo[2] > 0.0)
            else {
                return Ok(());
            };
            let mut cell = [0.0; 3];
            for (a, w) in self.grid.interpolation_stencil(&hd) {
                if w != 0.0 {
                    self.eval_cell(a, &mut cell)?;
                    out.iter_mut().zip(&cell).for_each(|(o, v)| *o += w * v);
                }
            }
            Ok(())
        }
        fn grid(&self) -> Option<AngularGrid> {
            Some(self.grid)
        }
        fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
            let hd = self.grid.bin_centre_flat(a);
            for (k, o) in out.iter_mut().enumerate() {
                *o = (self.value)(&hd, k);
            }
            Ok(())
        }
    }

    fn grid() -> AngularGrid {
        AngularGrid::new(8, 8, 16).unwrap()
    }

    /// Direction pairs above the horizon at scattered angles (away from the horizon, where
    /// every stencil cell holds a value).
    fn pairs() -> Vec<(Vec3, Vec3)> {
        (0..40)
            .map(|k| {
                let t = f64::from(k);
                let (ti, to) = (0.05 + 0.031 * t, 0.9 - 0.017 * t);
                let po = 0.4 + 0.157 * t;
                (
                    [ti.sin(), 0.0, ti.cos()],
                    [to.sin() * po.cos(), to.sin() * po.sin(), to.cos()],
                )
            })
            .collect()
    }

    #[test]
    fn names_parse_and_print() {
        for l in Lookup::ALL {
            assert_eq!(l.to_string().parse::<Lookup>().unwrap(), l);
        }
        assert_eq!("log".parse::<Lookup>().unwrap(), Lookup::LogMultilinear);
        assert_eq!(Lookup::default(), Lookup::Multilinear);
        let e = "cubic".parse::<Lookup>().unwrap_err().to_string();
        assert!(
            e.contains("\"cubic\"") && e.contains("linear or log"),
            "{e}"
        );
    }

    /// The multilinear sum is the plain weighted sum (same bits); the logarithmic one is the
    /// weighted geometric mean in positive channels and falls back to the sum per channel;
    /// records hold the logarithms only for logarithmic lookups.
    #[test]
    fn lookups_combine_cells_per_channel() {
        let cells = [[2.0, 0.0, 1.5], [8.0, 3.0, -0.5], [4.0, 1.0, 2.0]];
        let weights = [0.25, 0.5, 0.25];
        let mut plain = [0.0; 3];
        for (c, w) in cells.iter().zip(weights) {
            plain.iter_mut().zip(c).for_each(|(p, v)| *p += w * v);
        }
        let combined = |lookup: Lookup| {
            let records: Vec<Box<[f64]>> = cells.iter().map(|c| cell_record(lookup, c)).collect();
            let pairs: Vec<(&[f64], f64)> = records.iter().map(|r| &r[..]).zip(weights).collect();
            let mut out = [0.0; 3];
            combine(lookup, &pairs, &mut out);
            out
        };
        assert_eq!(combined(Lookup::Multilinear), plain);
        let log = combined(Lookup::LogMultilinear);
        // 2^0.25 8^0.5 4^0.25 = 2^(0.25 + 1.5 + 0.5) = 2^2.25.
        assert!((log[0] - 2f64.powf(2.25)).abs() < 1e-14, "{log:?}");
        // A zero cell in channel 1, a negative one in channel 2: the multilinear sums.
        assert_eq!(log[1..], plain[1..]);
        assert_eq!(cell_record(Lookup::Multilinear, &cells[0])[..], cells[0]);
        let r = cell_record(Lookup::LogMultilinear, &cells[1]);
        assert_eq!(r[..4], [8.0, 3.0, -0.5, 8f64.ln()]);
        assert_eq!(r[4], 3f64.ln());
        assert!(r[5].is_nan());
        // One cell of weight 1: its values.
        let one = cell_record(Lookup::LogMultilinear, &[5.0, 6.0, 7.0]);
        let mut out = [0.0; 3];
        combine(Lookup::LogMultilinear, &[(&one, 1.0)], &mut out);
        for (o, v) in out.iter().zip([5.0, 6.0, 7.0]) {
            assert!((o - v).abs() < 1e-14 * v, "{out:?}");
        }
    }

    /// Values exponential in the grid's coordinates are looked up exactly by the logarithmic
    /// lookup (the multilinear chord overshoots their convex curve); constant values are
    /// exact under both; a multilinear `WithLookup` is its source's own lookup, bit for bit.
    #[test]
    fn log_lookups_are_exact_for_exponential_values() {
        use std::f64::consts::FRAC_PI_2;
        let g = grid();
        // Exponential in the grid's coordinates: theta_h's is sqrt(theta_h / (pi / 2)).
        let f = |u_h: f64, theta_d: f64, phi_d: f64, k: usize| {
            (1.5 * theta_d - 2.0 * u_h + 0.1 * phi_d + k as f64).exp()
        };
        let exponential = Cells {
            grid: g,
            value: |hd: &HalfDiff, k: usize| {
                f((hd.theta_h / FRAC_PI_2).sqrt(), hd.theta_d, hd.phi_d, k)
            },
        };
        let exact = |wi: Vec3, wo: Vec3, k: usize| {
            let hd = HalfDiff::from_dirs(wi, wo).unwrap();
            // Clamped like the stencil: the first and last centres bound the lookup.
            let c = |x: f64, n: usize| x.clamp(0.5 / n as f64, 1.0 - 0.5 / n as f64);
            let u_h = c((hd.theta_h / FRAC_PI_2).sqrt(), g.n_theta_h);
            let theta_d = FRAC_PI_2 * c(hd.theta_d / FRAC_PI_2, g.n_theta_d);
            f(u_h, theta_d, hd.phi_d, k)
        };
        let log = WithLookup::new(&exponential, Lookup::LogMultilinear).unwrap();
        let linear = WithLookup::new(&exponential, Lookup::Multilinear).unwrap();
        let (mut a, mut b, mut own) = ([0.0; 3], [0.0; 3], [0.0; 3]);
        let mut overshoot = 0.0f64;
        for (wi, wo) in pairs() {
            let hd = HalfDiff::from_dirs(wi, wo).unwrap();
            let step = std::f64::consts::PI / g.n_phi_d as f64;
            // phi_d wraps between its last and first centres: not exponential across the seam.
            if hd.phi_d < 0.5 * step || hd.phi_d > std::f64::consts::PI - 0.5 * step {
                continue;
            }
            log.eval(wi, wo, &mut a).unwrap();
            linear.eval(wi, wo, &mut b).unwrap();
            exponential.eval(wi, wo, &mut own).unwrap();
            assert_eq!(b, own);
            for k in 0..3 {
                let e = exact(wi, wo, k);
                assert!((a[k] - e).abs() < 1e-12 * e, "{k}: {} vs {e}", a[k]);
                assert!(b[k] >= e * (1.0 - 1e-12), "{k}: {} vs {e}", b[k]);
                overshoot = overshoot.max(b[k] / e - 1.0);
            }
        }
        assert!(overshoot > 1e-3, "{overshoot}");
        let constant = Cells {
            grid: g,
            value: |_: &HalfDiff, k: usize| 0.2 + 0.1 * k as f64,
        };
        let log = WithLookup::new(&constant, Lookup::LogMultilinear).unwrap();
        for (wi, wo) in pairs() {
            log.eval(wi, wo, &mut a).unwrap();
            for (k, v) in a.iter().enumerate() {
                assert!((v - (0.2 + 0.1 * k as f64)).abs() < 1e-15, "{a:?}");
            }
        }
        // Below the horizon, and exactly at it on either side: zero in every channel; a
        // short output is refused.
        for (wi, wo) in [
            ([0.0, 0.0, 1.0], [0.0, 0.3, -1.0]),
            ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
        ] {
            a = [1.0; 3];
            log.eval(wi, wo, &mut a).unwrap();
            assert_eq!(a, [0.0; 3], "{wi:?} {wo:?}");
        }
        assert!(
            log.eval([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], &mut [0.0; 2])
                .is_err()
        );
    }

    /// A source with its own evaluation has no cells to look up; the wrapper forwards the
    /// grid, the cells and the channels, and reports its lookup.
    #[test]
    fn the_wrapper_needs_a_grid_source_and_forwards_it() {
        struct Analytic;
        impl BrdfSource for Analytic {
            fn channels(&self) -> Channels {
                Channels::Rgb
            }
            fn eval(&self, _: Vec3, _: Vec3, out: &mut [f64]) -> Result<()> {
                out.fill(0.1);
                Ok(())
            }
        }
        let e = WithLookup::new(Analytic, Lookup::LogMultilinear)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("log lookup applies to grid sources"), "{e}");
        let cells = Cells {
            grid: grid(),
            value: |hd: &HalfDiff, k: usize| hd.theta_h + 2.0 * hd.theta_d + k as f64,
        };
        let boxed: Box<dyn BrdfSource> = Box::new(cells);
        let w = WithLookup::new(boxed, Lookup::LogMultilinear).unwrap();
        assert_eq!(w.grid(), Some(grid()));
        assert_eq!(w.lookup(), Lookup::LogMultilinear);
        assert_eq!(w.inner().lookup(), Lookup::Multilinear);
        assert_eq!(w.channels(), Channels::Rgb);
        let (mut a, mut b) = ([0.0; 3], [0.0; 3]);
        w.eval_cell(77, &mut a).unwrap();
        w.inner().eval_cell(77, &mut b).unwrap();
        assert_eq!(a, b);
        // The lookup of a wrapper of a wrapper is the outer one's.
        let twice = WithLookup::new(&w, Lookup::Multilinear).unwrap();
        assert_eq!(twice.lookup(), Lookup::Multilinear);
        // Prefetch hints (both kinds) reach the wrapped source.
        struct Hinted<S>(S, std::sync::Mutex<Vec<usize>>);
        impl<S: BrdfSource + 'static> BrdfSource for Hinted<S> {
            fn channels(&self) -> Channels {
                self.0.channels()
            }
            fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
                self.0.eval(wi, wo, out)
            }
            fn grid(&self) -> Option<AngularGrid> {
                self.0.grid()
            }
            fn prefetch_cell(&self, a: usize) {
                self.1.lock().unwrap().push(a);
            }
            fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
                self.1.lock().unwrap().extend(cells.map(|a| 1000 + a));
            }
            fn takes_cell_hints(&self) -> bool {
                true
            }
            fn cell_source(&self) -> Option<&dyn std::any::Any> {
                Some(self)
            }
        }
        assert!(!w.takes_cell_hints() && w.cell_source().is_none());
        let hinted = Hinted(w, std::sync::Mutex::new(Vec::new()));
        let outer = WithLookup::new(&hinted, Lookup::LogMultilinear).unwrap();
        assert!(outer.takes_cell_hints());
        outer.prefetch_cell(5);
        outer.prefetch_cell(9);
        outer.will_need_cells(&mut [3, 1].into_iter());
        assert_eq!(*hinted.1.lock().unwrap(), [5, 9, 1003, 1001]);
        // The concrete source behind it is the wrapped one's (it evaluates the same cells).
        let found = outer
            .cell_source()
            .and_then(|s| s.downcast_ref::<Hinted<WithLookup<_>>>());
        assert!(found.is_some_and(|s| std::ptr::eq(s, &hinted)));
    }
}
