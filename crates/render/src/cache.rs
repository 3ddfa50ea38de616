//! A per-cell cache for grid sources: a BRDF defined by values at the bin centres of an
//! [`AngularGrid`], multilinearly interpolated with [`AngularGrid::interpolation_stencil`] (as
//! stored materials and lazily predicted materials are), computed once per touched cell and
//! kept.
//!
//! One render needs no cache: the renderer evaluates each cell a picture touches once per
//! render ([`BrdfSource::eval_cell`]; rendering a `PredictedMaterial` directly is ~15 % faster
//! than through this cache, which stores every channel of every cell). Keep a material behind a
//! `CellCache` to render it several times (views, lights, exposures): later renders reuse the
//! cells. The result is the same arithmetic as the wrapped source's own interpolation (same
//! stencil, same order).

use std::sync::OnceLock;

use brdf_io::lookup::look_up;
use brdf_io::{AngularGrid, BrdfSource, Channels, HalfDiff, Lookup, Vec3};

/// A lazily predicted material behind a cell cache: each touched cell is predicted once
/// (N multiply-adds per value) over all renders, nothing else is materialised. Use it to
/// render a latent point several times; render the `PredictedMaterial` itself for one picture.
pub fn predicted(m: predict::PredictedMaterial) -> CellCache<'static> {
    let grid = *m.predictor().grid();
    let channels = m.channels().clone();
    CellCache::new(
        grid,
        channels,
        Box::new(move |a, out: &mut [f64]| {
            m.eval_cell(a, out)
                .map_err(|e| brdf_io::Error::InvalidArgument {
                    reason: e.to_string(),
                })
        }),
    )
}

/// Computes the values of every channel at one angular cell (flat index).
pub type CellFn<'a> = dyn Fn(usize, &mut [f64]) -> brdf_io::Result<()> + Sync + 'a;

/// A grid source with lazily computed, cached cell values; see the module docs.
pub struct CellCache<'a> {
    grid: AngularGrid,
    channels: Channels,
    cell: Box<CellFn<'a>>,
    cache: Vec<OnceLock<Box<[f64]>>>,
}

impl<'a> CellCache<'a> {
    /// Wraps `cell`, which fills the values of `channels` at a flat cell index of `grid`.
    pub fn new(grid: AngularGrid, channels: Channels, cell: Box<CellFn<'a>>) -> Self {
        let cache = (0..grid.len()).map(|_| OnceLock::new()).collect();
        Self {
            grid,
            channels,
            cell,
            cache,
        }
    }

    /// Number of cells computed so far.
    pub fn computed_cells(&self) -> usize {
        self.cache.iter().filter(|c| c.get().is_some()).count()
    }

    fn cell(&self, a: usize) -> brdf_io::Result<&[f64]> {
        if let Some(v) = self.cache[a].get() {
            return Ok(v);
        }
        let mut v = vec![0.0; self.channels.len()];
        (self.cell)(a, &mut v)?;
        // Another thread may have filled it meanwhile: both computed the same values.
        Ok(self.cache[a].get_or_init(|| v.into_boxed_slice()))
    }
}

impl BrdfSource for CellCache<'_> {
    fn channels(&self) -> Channels {
        self.channels.clone()
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        brdf_io::source::check_output_len(out, self.channels.len())?;
        out.fill(0.0);
        let hd = match HalfDiff::from_dirs(wi, wo) {
            Some(hd) if wi[2] > 0.0 && wo[2] > 0.0 => hd,
            _ => return Ok(()),
        };
        let stencil = self.grid.interpolation_stencil(&hd);
        look_up(Lookup::Multilinear, stencil, |a| self.cell(a), out)
    }

    fn grid(&self) -> Option<AngularGrid> {
        Some(self.grid)
    }

    fn eval_cell(&self, a: usize, out: &mut [f64]) -> brdf_io::Result<()> {
        brdf_io::source::check_output_len(out, self.channels.len())?;
        if a >= self.grid.len() {
            return Err(brdf_io::Error::InvalidArgument {
                reason: format!("cell {a} out of range ({} cells)", self.grid.len()),
            });
        }
        out.copy_from_slice(self.cell(a)?);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_cached_cells_and_computes_each_once() {
        let grid = AngularGrid::new(4, 4, 8).unwrap();
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let cache = CellCache::new(
            grid,
            Channels::Rgb,
            Box::new(|a, out: &mut [f64]| {
                calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                out.copy_from_slice(&[a as f64, 1.0, 2.0]);
                Ok(())
            }),
        );
        let mut out = [0.0; 3];
        // At a bin centre the value is the cell's own.
        let (wi, wo) = grid.bin_centre(1, 2, 3).to_dirs();
        cache.eval(wi, wo, &mut out).unwrap();
        assert!(
            (out[0] - grid.index(1, 2, 3) as f64).abs() < 1e-9,
            "{out:?}"
        );
        assert!((out[1] - 1.0).abs() < 1e-12 && (out[2] - 2.0).abs() < 1e-12);
        let first = calls.load(std::sync::atomic::Ordering::Relaxed);
        cache.eval(wi, wo, &mut out).unwrap();
        assert_eq!(calls.load(std::sync::atomic::Ordering::Relaxed), first);
        assert_eq!(cache.computed_cells(), first);
        cache
            .eval([0.0, 0.0, 1.0], [0.0, 0.5, -1.0], &mut out)
            .unwrap();
        assert_eq!(out, [0.0; 3]);
        assert!(cache.eval(wi, wo, &mut [0.0; 2]).is_err());
    }

    /// A direction exactly on the horizon (z = 0) reads 0, as for every other source, and
    /// computes no cell; the same pair lifted just above it does not.
    #[test]
    fn directions_on_the_horizon_read_zero() {
        let grid = AngularGrid::new(4, 4, 8).unwrap();
        let cache = CellCache::new(
            grid,
            Channels::Rgb,
            Box::new(|_, out: &mut [f64]| {
                out.fill(1.0);
                Ok(())
            }),
        );
        let above = [0.6, 0.0, 0.8];
        let mut out = [0.0; 3];
        for (wi, wo) in [([1.0, 0.0, 0.0], above), (above, [0.0, 1.0, 0.0])] {
            cache.eval(wi, wo, &mut out).unwrap();
            assert_eq!(out, [0.0; 3], "{wi:?} {wo:?}");
        }
        assert_eq!(cache.computed_cells(), 0);
        // Interpolation weights sum to 1 and every cell holds 1: the value is 1.
        let lifted = [0.999_95, 0.0, 0.01];
        cache.eval(lifted, above, &mut out).unwrap();
        assert!(out.iter().all(|v| (v - 1.0).abs() < 1e-12), "{out:?}");
    }
}
