//! Evaluating one stored material at arbitrary directions (`specgp sample DATA.sbrdf:NAME`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, ChannelSelection, Channels, HalfDiff, Vec3};
use crate::source::BrdfSource;

use super::Store;

/// One material of a [`Store`], evaluated at arbitrary angles by multilinear interpolation in
/// [`crate::AngularGrid::continuous_coords`] (theta_h and theta_d clamped to the grid, phi_d
/// wrapping with period pi). Values are the stored BRDF values f (1/sr), one per stored channel,
/// or at chosen wavelengths ([`StoreMaterial::with_wavelengths`]).
///
/// Implements [`BrdfSource`], so `specgp sample DATA.sbrdf:MATERIAL` and `render` treat it like a
/// measured file. Cheap to clone (the store is shared).
#[derive(Debug, Clone)]
pub struct StoreMaterial {
    store: Arc<Store>,
    index: usize,
    /// The output channels: all stored ones unless chosen by [`StoreMaterial::with_wavelengths`].
    selection: Arc<ChannelSelection>,
}

/// Splits a source spec `DATA.sbrdf:MATERIAL` into the store path and the material name
/// (`None` when `spec` does not have that form).
pub fn parse_store_spec(spec: &str) -> Option<(PathBuf, String)> {
    // The first `:` after a `.sbrdf` path: the material name may contain `:` itself.
    spec.match_indices(':').find_map(|(i, _)| {
        let (path, name) = (&spec[..i], &spec[i + 1..]);
        (crate::has_extension(path, "sbrdf") && !name.is_empty())
            .then(|| (PathBuf::from(path), name.to_owned()))
    })
}

impl StoreMaterial {
    /// The material called `name`.
    pub fn new(store: Arc<Store>, name: &str) -> Result<Self> {
        let index = store.material_index(name)?;
        Self::by_index(store, index)
    }

    /// Opens the store at `path` (memory-mapped) and selects the material called `name`.
    pub fn open(path: impl AsRef<Path>, name: &str) -> Result<Self> {
        Self::new(Arc::new(Store::open(path)?), name)
    }

    /// The store this material belongs to.
    pub fn store(&self) -> &Arc<Store> {
        &self.store
    }

    /// The material at row `index` (must be < N).
    pub fn by_index(store: Arc<Store>, index: usize) -> Result<Self> {
        if index >= store.n_materials() {
            return Err(Error::StoreUsage {
                path: store.path().to_owned(),
                reason: format!(
                    "material index {index} out of range ({} materials)",
                    store.n_materials()
                ),
            });
        }
        Ok(Self {
            selection: Arc::new(ChannelSelection::all(store.channels())),
            store,
            index,
        })
    }

    /// The same material evaluated at `wavelengths`: linear interpolation between the stored
    /// wavelengths (as for RGL files and predicted materials); a wavelength outside the stored
    /// range, or wavelengths of an RGB store, are an error naming the store.
    pub fn with_wavelengths(&self, wavelengths: &Channels) -> Result<Self> {
        let selection =
            ChannelSelection::new(self.store.path(), self.store.channels(), wavelengths)?;
        Ok(Self {
            selection: Arc::new(selection),
            ..self.clone()
        })
    }

    /// Row index of the material.
    pub fn index(&self) -> usize {
        self.index
    }

    /// Number of output channels (the length `eval` fills).
    pub fn n_channels(&self) -> usize {
        self.selection.taps().len()
    }

    /// Interpolated values at half/difference angles `hd` into `out` (one per output channel).
    pub fn eval_half_diff(&self, hd: &HalfDiff, out: &mut [f64]) -> Result<()> {
        self.check_out(out)?;
        self.weighted_cells(&self.store.grid().interpolation_stencil(hd), out)
    }

    /// The sum of `w` times cell `a`'s stored channels over `cells` (only the channels the
    /// selection reads), through the selection into `out`.
    fn weighted_cells(&self, cells: &[(usize, f64)], out: &mut [f64]) -> Result<()> {
        let (first, last) = self.selection.span();
        let mut vals = vec![0f32; last + 1 - first];
        let mut sum = vec![0f64; vals.len()];
        for &(a, w) in cells {
            if w == 0.0 {
                continue;
            }
            let range = self.stored_range(a);
            let start = range.start;
            self.store.material_row(self.index, range, &mut vals)?;
            // Lookups do not re-hash the payload: a damaged value must not pass silently.
            if let Some(k) = vals.iter().position(|v| !v.is_finite()) {
                return Err(Error::DamagedValue {
                    path: self.store.path().to_owned(),
                    material: self.store.names()[self.index].to_owned(),
                    index: start + k,
                    value: vals[k],
                });
            }
            for (s, v) in sum.iter_mut().zip(&vals) {
                *s += w * f64::from(*v);
            }
        }
        self.selection.apply(&sum, first, out);
        Ok(())
    }

    /// The flat indices of cell `a`'s stored channels that the selection reads.
    fn stored_range(&self, a: usize) -> std::ops::Range<usize> {
        let nc = self.store.channels().len();
        let (first, last) = self.selection.span();
        a * nc + first..a * nc + last + 1
    }

    fn check_out(&self, out: &[f64]) -> Result<()> {
        if out.len() != self.n_channels() {
            return Err(Error::StoreUsage {
                path: self.store.path().to_owned(),
                reason: format!(
                    "output has {} slots for {} channels",
                    out.len(),
                    self.n_channels()
                ),
            });
        }
        Ok(())
    }

    /// Interpolated values for the direction pair (wi, wo) (local frame, z = normal) into `out`;
    /// 0 when either direction is at or below the horizon or the pair is degenerate.
    pub fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        let nc = self.n_channels();
        match HalfDiff::from_dirs(wi, wo) {
            Some(hd) if wi[2] > 0.0 && wo[2] > 0.0 => self.eval_half_diff(&hd, out),
            _ => {
                self.check_out(out)?;
                out[..nc].iter_mut().for_each(|o| *o = 0.0);
                Ok(())
            }
        }
    }
}

impl BrdfSource for StoreMaterial {
    fn channels(&self) -> Channels {
        self.selection.channels.clone()
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        StoreMaterial::eval(self, wi, wo, out)
    }

    fn grid(&self) -> Option<AngularGrid> {
        Some(*self.store.grid())
    }

    fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
        self.check_out(out)?;
        self.weighted_cells(&[(a, 1.0)], out)
    }

    /// Starts reading the cells' stored values (the selected channels' span, all materials:
    /// [`Store::will_need`]); cells outside the grid are skipped.
    fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        let len = self.store.grid().len();
        let ranges = cells.filter(|&a| a < len).map(|a| self.stored_range(a));
        self.store.will_need(ranges);
    }

    fn takes_cell_hints(&self) -> bool {
        self.store.takes_will_need()
    }
}
