//! Evaluating one stored material at arbitrary directions (`specgp sample DATA.sbrdf:NAME`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, Channels, HalfDiff, Vec3};
use crate::source::BrdfSource;

use super::Store;

/// One material of a [`Store`], evaluated at arbitrary angles by multilinear interpolation in
/// [`crate::AngularGrid::continuous_coords`] (theta_h and theta_d clamped to the grid, phi_d
/// wrapping with period pi). Values are the stored BRDF values f (1/sr), one per channel.
///
/// Implements [`BrdfSource`], so `specgp sample DATA.sbrdf:MATERIAL` and `render` treat it like a
/// measured file. Cheap to clone (the store is shared).
#[derive(Debug, Clone)]
pub struct StoreMaterial {
    store: Arc<Store>,
    index: usize,
}

/// Splits a source spec `DATA.sbrdf:MATERIAL` into the store path and the material name
/// (`None` when `spec` does not have that form).
pub fn parse_store_spec(spec: &str) -> Option<(PathBuf, String)> {
    let (path, name) = spec.rsplit_once(':')?;
    (path.ends_with(".sbrdf") && !name.is_empty()).then(|| (PathBuf::from(path), name.to_owned()))
}

impl StoreMaterial {
    /// The material called `name`.
    pub fn new(store: Arc<Store>, name: &str) -> Result<Self> {
        Ok(Self {
            index: store.material_index(name)?,
            store,
        })
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
        Ok(Self { store, index })
    }

    /// Row index of the material.
    pub fn index(&self) -> usize {
        self.index
    }

    /// Number of channels (the length `eval` fills).
    pub fn n_channels(&self) -> usize {
        self.store.channels().len()
    }

    /// Interpolated values at half/difference angles `hd` into `out` (one per channel).
    pub fn eval_half_diff(&self, hd: &HalfDiff, out: &mut [f64]) -> Result<()> {
        let g = self.store.grid();
        let nc = self.n_channels();
        self.check_out(out)?;
        out[..nc].iter_mut().for_each(|o| *o = 0.0);
        let mut vals = vec![0f32; nc];
        for (a, w) in g.interpolation_stencil(hd) {
            if w == 0.0 {
                continue;
            }
            self.store
                .material_row(self.index, a * nc..(a + 1) * nc, &mut vals)?;
            for (o, v) in out.iter_mut().zip(&vals) {
                *o += w * f64::from(*v);
            }
        }
        Ok(())
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
        self.store.channels().clone()
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        StoreMaterial::eval(self, wi, wo, out)
    }

    fn grid(&self) -> Option<AngularGrid> {
        Some(*self.store.grid())
    }

    fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
        let nc = self.n_channels();
        self.check_out(out)?;
        let mut vals = vec![0f32; nc];
        self.store
            .material_row(self.index, a * nc..(a + 1) * nc, &mut vals)?;
        for (o, v) in out.iter_mut().zip(&vals) {
            *o = f64::from(*v);
        }
        Ok(())
    }
}
