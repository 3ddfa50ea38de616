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

/// ln v where v > 0, NaN otherwise: a cell's logarithms for [`StencilSum::add_with_logs`] (a NaN
/// marks a channel whose lookup falls back to the multilinear sum).
pub fn cell_logs(values: &[f64], logs: &mut [f64]) {
    for (l, &v) in logs.iter_mut().zip(values) {
        *l = if v > 0.0 { v.ln() } else { f64::NAN };
    }
}

/// One channel's logarithmic lookup from its two sums over the weighted cells: `log`, the sum
/// of w ln v (NaN when a cell is not positive), gives exp(log); a NaN gives the multilinear sum
/// `linear`. What [`StencilSum::finish`] writes per channel, for callers that sum themselves.
pub fn finish_channel(linear: f64, log: f64) -> f64 {
    if log.is_nan() { linear } else { log.exp() }
}

/// The running combination of a stencil's cells under a [`Lookup`], one value per channel: add
/// each weighted cell in stencil order, then [`StencilSum::finish`]. The multilinear sum is the
/// arithmetic every multilinear lookup does (zero, then `+= w * v` per cell), so its bits are
/// theirs.
#[derive(Debug, Clone)]
pub struct StencilSum {
    linear: Vec<f64>,
    /// sum w ln v per channel (log lookups only); NaN once a weighted cell is not positive.
    log: Vec<f64>,
}

impl StencilSum {
    /// An empty sum of `channels` channels.
    pub fn new(lookup: Lookup, channels: usize) -> Self {
        let log_len = if lookup == Lookup::LogMultilinear {
            channels
        } else {
            0
        };
        Self {
            linear: vec![0.0; channels],
            log: vec![0.0; log_len],
        }
    }

    /// Adds a cell's `values` with weight `weight` (callers skip zero weights, which
    /// [`AngularGrid::interpolation_stencil`] gives to cells that hold no value).
    pub fn add(&mut self, weight: f64, values: &[f64]) {
        for (s, v) in self.linear.iter_mut().zip(values) {
            *s += weight * v;
        }
        for (l, &v) in self.log.iter_mut().zip(values) {
            *l += weight * if v > 0.0 { v.ln() } else { f64::NAN };
        }
    }

    /// [`StencilSum::add`] with the cell's logarithms computed beforehand ([`cell_logs`]), for
    /// callers that read a cell many times (the renderer's plans): the same bits.
    pub fn add_with_logs(&mut self, weight: f64, values: &[f64], logs: &[f64]) {
        for (s, v) in self.linear.iter_mut().zip(values) {
            *s += weight * v;
        }
        for (l, g) in self.log.iter_mut().zip(logs) {
            *l += weight * g;
        }
    }

    /// Writes the lookup's value per channel into `out` (as long as the channels) and empties
    /// the sum for the next lookup.
    pub fn finish(&mut self, out: &mut [f64]) {
        out.copy_from_slice(&self.linear);
        for (o, l) in out.iter_mut().zip(&self.log) {
            *o = finish_channel(*o, *l);
        }
        self.linear.fill(0.0);
        self.log.fill(0.0);
    }
}

/// A grid source looked up with another [`Lookup`]: the same cells ([`BrdfSource::eval_cell`]),
/// combined by `lookup` in [`BrdfSource::eval`] and reported by [`BrdfSource::lookup`], so that
/// consumers that interpolate cells themselves (the renderer, the RGL writer, the albedo) do
/// the same.
pub struct WithLookup<S> {
    inner: S,
    grid: AngularGrid,
    lookup: Lookup,
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
        Ok(Self {
            inner,
            grid,
            lookup,
        })
    }

    /// The wrapped source.
    pub fn inner(&self) -> &S {
        &self.inner
    }
}

impl<S: BrdfSource> BrdfSource for WithLookup<S> {
    fn channels(&self) -> Channels {
        self.inner.channels()
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        check_output_len(out, self.inner.channels().len())?;
        out.fill(0.0);
        let Some(hd) = HalfDiff::from_dirs(wi, wo).filter(|_| wi[2] > 0.0 && wo[2] > 0.0) else {
            return Ok(());
        };
        let mut sum = StencilSum::new(self.lookup, out.len());
        let mut cell = vec![0.0; out.len()];
        for (a, w) in self.grid.interpolation_stencil(&hd) {
            if w == 0.0 {
                continue;
            }
            self.inner.eval_cell(a, &mut cell)?;
            sum.add(w, &cell);
        }
        sum.finish(out);
        Ok(())
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
    /// weighted geometric mean in positive channels and falls back to the sum per channel.
    #[test]
    fn sums_combine_cells_per_channel() {
        let cells = [[2.0, 0.0, 1.5], [8.0, 3.0, -0.5], [4.0, 1.0, 2.0]];
        let weights = [0.25, 0.5, 0.25];
        let mut plain = [0.0; 3];
        for (c, w) in cells.iter().zip(weights) {
            plain.iter_mut().zip(c).for_each(|(p, v)| *p += w * v);
        }
        let mut linear = StencilSum::new(Lookup::Multilinear, 3);
        let mut log = StencilSum::new(Lookup::LogMultilinear, 3);
        let mut with_logs = StencilSum::new(Lookup::LogMultilinear, 3);
        for (c, w) in cells.iter().zip(weights) {
            linear.add(w, c);
            log.add(w, c);
            let mut l = [0.0; 3];
            cell_logs(c, &mut l);
            with_logs.add_with_logs(w, c, &l);
        }
        let mut out = [0.0; 3];
        linear.finish(&mut out);
        assert_eq!(out, plain);
        log.finish(&mut out);
        // 2^0.25 8^0.5 4^0.25 = 2^(0.25 + 1.5 + 0.5) = 2^2.25.
        assert!((out[0] - 2f64.powf(2.25)).abs() < 1e-14, "{out:?}");
        // A zero cell in channel 1, a negative one in channel 2: the multilinear sums.
        assert_eq!(out[1..], plain[1..]);
        let mut again = [0.0; 3];
        with_logs.finish(&mut again);
        assert_eq!(again, out);
        assert_eq!(finish_channel(0.7, f64::NAN), 0.7);
        assert_eq!(finish_channel(0.7, 2f64.ln()), 2f64.ln().exp());
        // `finish` empties the sums.
        linear.add(1.0, &[5.0, 6.0, 7.0]);
        linear.finish(&mut out);
        assert_eq!(out, [5.0, 6.0, 7.0]);
        log.add(1.0, &[5.0, 6.0, 7.0]);
        log.finish(&mut out);
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
        // Below the horizon: zero in every channel; a short output is refused.
        a = [1.0; 3];
        log.eval([0.0, 0.0, 1.0], [0.0, 0.3, -1.0], &mut a).unwrap();
        assert_eq!(a, [0.0; 3]);
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
    }
}
