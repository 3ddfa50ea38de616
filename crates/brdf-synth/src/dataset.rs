//! Evaluating materials on a dataset grid, in memory (small grids, tests).
//!
//! Values are f(wi, wo, lambda) in 1/sr at the bin centres of the [`AngularGrid`]
//! ([`AngularGrid::bin_centre`]), in the store's dimension order
//! `d = angular_index * n_channels + channel` (channel fastest); cells whose bin centre has a
//! direction below the horizon hold 0.

use brdf_io::{AngularGrid, Channels};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::material::{Material, PreparedMaterial};

/// The default grid of `specgp synth`: 32 x 32 x 64 (theta_h, theta_d, phi_d).
/// See BENCHMARKS.md ("synth") for the timing behind this choice.
pub const DEFAULT_GRID: AngularGrid = AngularGrid {
    n_theta_h: 32,
    n_theta_d: 32,
    n_phi_d: 64,
};

/// The default wavelengths of `specgp synth`, nm (33 samples over the RGL range).
pub const DEFAULT_WAVELENGTHS: &str = "360:1000:20";

/// The range (nm) the embedded spectra and metal n, k tables cover; synthesis refuses
/// wavelengths outside it (the tables would be extrapolated as constants).
pub const WAVELENGTH_RANGE_NM: (f64, f64) = (360.0, 1000.0);

/// The wavelengths of a spectral channel axis; synthesis is spectral only, inside
/// [`WAVELENGTH_RANGE_NM`].
pub fn wavelengths_of(channels: &Channels) -> Result<&[f64]> {
    match channels {
        Channels::Spectral(w) => {
            if w.is_empty() {
                return Err(Error::InvalidRequest {
                    reason: "the channel axis has no wavelengths".into(),
                });
            }
            let (lo, hi) = WAVELENGTH_RANGE_NM;
            if let Some(l) = w.iter().find(|l| !(lo..=hi).contains(*l)) {
                return Err(Error::InvalidRequest {
                    reason: format!(
                        "wavelength {l} nm is outside {lo}-{hi} nm, the range of the embedded \
                         spectra"
                    ),
                });
            }
            Ok(w)
        }
        Channels::Rgb => Err(Error::InvalidRequest {
            reason: "synthetic materials are spectral: give wavelengths, not RGB channels".into(),
        }),
    }
}

/// Prepares every material for the channel axis.
pub fn prepare_all(materials: &[Material], channels: &Channels) -> Result<Vec<PreparedMaterial>> {
    let w = wavelengths_of(channels)?;
    Ok(materials.par_iter().map(|m| m.prepare(w)).collect())
}

/// Evaluates one material on every cell of `grid`: `out` has `grid.len() * n_channels` values
/// in dimension order (below-horizon cells 0). Parallel over cells. A material prepared for no
/// wavelengths has nothing to write.
pub fn eval_on_grid(m: &PreparedMaterial, grid: &AngularGrid, out: &mut [f64]) {
    let nc = m.wavelengths().len();
    debug_assert_eq!(out.len(), grid.len() * nc);
    if nc == 0 {
        return;
    }
    out.par_chunks_mut(nc).enumerate().for_each(|(cell, o)| {
        let hd = grid.bin_centre_flat(cell);
        if hd.is_above_horizon() {
            m.eval_half_diff(&hd, o);
        } else {
            o.fill(0.0);
        }
    });
}

/// A dataset held in memory: N materials x D values, row-major (one row per material).
#[derive(Debug, Clone, PartialEq)]
pub struct SynthDataset {
    /// Material names, one per row.
    pub names: Vec<String>,
    /// Angular grid.
    pub grid: AngularGrid,
    /// Channel axis (spectral).
    pub channels: Channels,
    /// N x D values (f in 1/sr), row-major, in dimension order.
    pub values: Vec<f64>,
}

impl SynthDataset {
    /// Number of materials N.
    pub fn n(&self) -> usize {
        self.names.len()
    }

    /// Values per material D.
    pub fn d(&self) -> usize {
        self.grid.len() * self.channels.len()
    }

    /// The row of material `i`.
    pub fn row(&self, i: usize) -> &[f64] {
        let d = self.d();
        &self.values[i * d..(i + 1) * d]
    }
}

/// Evaluates `materials` on `grid` x `channels` into memory. Use for small grids (tests);
/// [`crate::stream::write_store`] streams any size.
pub fn generate(
    materials: &[Material],
    grid: AngularGrid,
    channels: &Channels,
) -> Result<SynthDataset> {
    let d = grid.len() * channels.len();
    let total = d
        .checked_mul(materials.len())
        .filter(|t| *t <= (1usize << 31))
        .ok_or(Error::TooLarge {
            n_materials: materials.len(),
            dims: d,
        })?;
    let prepared = prepare_all(materials, channels)?;
    let mut values = vec![0.0; total];
    if d > 0 {
        for (row, m) in values.chunks_mut(d).zip(&prepared) {
            eval_on_grid(m, &grid, row);
        }
    }
    Ok(SynthDataset {
        names: materials.iter().map(|m| m.name.clone()).collect(),
        grid,
        channels: channels.clone(),
        values,
    })
}

/// The 51 preset materials of `seed` on a small grid, in memory: a ready-made dataset with
/// known ground truth for other crates' tests (e.g. grid `8,8,16` and wavelengths
/// `400:700:50` gives D = 7168).
pub fn preset_dataset(grid: AngularGrid, channels: &Channels, seed: u64) -> Result<SynthDataset> {
    generate(&crate::preset::preset(seed), grid, channels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wavelengths_outside_the_tables_are_refused() {
        let ok = Channels::parse_wavelengths("360:1000:20").unwrap();
        assert_eq!(wavelengths_of(&ok).unwrap().len(), 33);
        for bad in ["1:10:1", "5000:6000:500", "1e-300", "359.9,500"] {
            let ch = Channels::parse_wavelengths(bad).unwrap();
            let e = wavelengths_of(&ch).unwrap_err().to_string();
            assert!(e.contains("outside 360-1000 nm"), "{bad}: {e}");
        }
        assert!(wavelengths_of(&Channels::Rgb).is_err());
    }

    /// An empty spectral axis (the enum can be built without `Channels::spectral`'s checks) is
    /// an error, not a dataset of 0 values or a panic; `eval_on_grid` of a material prepared
    /// for no wavelengths writes nothing (it panicked: rayon's chunk size 0).
    #[test]
    fn an_empty_channel_axis_is_refused() {
        let empty = Channels::Spectral(Vec::new());
        let e = wavelengths_of(&empty).unwrap_err();
        assert!(matches!(e, Error::InvalidRequest { .. }), "{e}");
        assert!(e.to_string().contains("no wavelengths"), "{e}");
        let grid = AngularGrid::new(2, 2, 2).unwrap();
        let mats = crate::preset::preset(0);
        assert!(generate(&mats[..2], grid, &empty).is_err());
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.sbrdf");
        let options = brdf_io::StoreOptions::default();
        let err = crate::stream::write_store(&path, &mats[..2], grid, &empty, options, 0, |_| {});
        assert!(matches!(err, Err(Error::InvalidRequest { .. })), "{err:?}");
        let prepared = mats[0].prepare(&[]);
        let mut out: Vec<f64> = Vec::new();
        eval_on_grid(&prepared, &grid, &mut out);
        assert!(out.is_empty());
    }

    /// A grid without cells (the struct can be built without `AngularGrid::new`'s checks)
    /// gives rows of no values, not a panic (chunks of 0 values).
    #[test]
    fn a_grid_without_cells_gives_empty_rows() {
        let grid = AngularGrid {
            n_theta_h: 0,
            n_theta_d: 4,
            n_phi_d: 4,
        };
        let channels = Channels::parse_wavelengths("500,600").unwrap();
        let mats = crate::preset::preset(0);
        let set = generate(&mats[..3], grid, &channels).unwrap();
        assert_eq!((set.n(), set.d()), (3, 0));
        assert!(set.values.is_empty() && set.row(2).is_empty());
    }
}
