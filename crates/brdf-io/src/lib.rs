//! Grids, BRDF file formats and the dataset store of specgp.
//!
//! - [`grid`]: the Rusinkiewicz angular grid with MERL's index mapping, the channel axis and the
//!   conversions between (theta_h, theta_d, phi_d) and (wi, wo).
//! - [`store`]: the chunked dataset store (`.sbrdf`): streaming writer, memory-mapped reader.
//! - [`tensor`]: the RGL `tensor_file` container (reader and writer); [`rgl`]: isotropic RGL
//!   `.bsdf` evaluation matching Mitsuba 3's `measured` plugin (f in 1/sr) and grid resampling;
//!   [`merl`]: MERL `.binary` files; [`nbrdf`]: Neural-BRDF networks; [`npy`]: `.npy` I/O.
//! - [`output`]: atomic output files ([`output::write_file_atomic`], [`output::AtomicOutput`]).
//! - [`source`]: the [`BrdfSource`] trait (f(wi, wo) for any source) and the [`ImportReport`].
//!
//! A store written material by material, read back memory-mapped, its Gram matrix taken in one
//! pass, and a stored material evaluated at a pair of directions:
//!
//! ```
//! use std::f64::consts::PI;
//! use brdf_io::store::StoreMaterial;
//! use brdf_io::{AngularGrid, BrdfSource, Channels, Store, StoreInfo, StoreOptions, StoreWriter};
//!
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("two.sbrdf");
//! // 8 x 8 x 16 cells (theta_h, theta_d, phi_d; MERL's index mapping) at 3 wavelengths.
//! let info = StoreInfo {
//!     grid: AngularGrid::new(8, 8, 16)?,
//!     channels: Channels::parse_wavelengths("450:650:100")?,
//! };
//! let d = info.d(); // values per material: cells x channels
//! let valid = info.grid.validity_mask().iter().filter(|v| **v).count() * 3;
//! // Two Lambertian materials, f = albedo / pi at every angle and wavelength.
//! let mut writer = StoreWriter::create(&path, info, StoreOptions::default())?;
//! for (name, albedo) in [("grey", 0.5), ("white", 0.9)] {
//!     writer.add_material(name, "example", &vec![(albedo / PI) as f32; d])?;
//! }
//! writer.finish()?; // written to a temporary file beside `path`, renamed into place here
//!
//! let store = Store::open(&path)?;
//! assert_eq!((store.n_materials(), store.d(), store.names()), (2, d, vec!["grey", "white"]));
//! // G = Y Y^T (row-major, f64 sums); cells below the horizon hold 0 and add nothing.
//! let g = store.gram()?;
//! let expected = valid as f64 * (0.5 / PI) * (0.9 / PI);
//! assert!((g[1] - expected).abs() < 1e-6 * expected && g[1] == g[2]);
//!
//! // A stored material is a `BrdfSource`: f(wi, wo) in 1/sr, one value per channel,
//! // interpolated on the grid.
//! let white = StoreMaterial::open(&path, "white")?;
//! let (wi, wo) = ([0.0, 0.6, 0.8], [0.3, -0.4, 0.75f64.sqrt()]);
//! let mut f = [0.0; 3];
//! white.eval(wi, wo, &mut f)?;
//! assert!(f.iter().all(|v| (v - 0.9 / PI).abs() < 1e-6 / PI));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod albedo;
pub mod error;
pub mod grid;
pub mod lookup;
pub mod merl;
pub mod nbrdf;
pub mod npy;
pub mod output;
pub mod rgl;
pub mod source;
pub mod store;
pub mod tensor;

pub use error::{Error, Result};

/// Whether `path` ends in `.EXT` for `ext` = `EXT`, in any ASCII case: `GOLD.BSDF` is an RGL
/// file and `P.NPY` an `.npy` output, as everywhere else a file's kind is read from its name.
pub fn has_extension(path: impl AsRef<std::path::Path>, ext: &str) -> bool {
    let name = path.as_ref().as_os_str().as_encoded_bytes();
    let n = ext.len() + 1;
    name.len() >= n
        && name[name.len() - n] == b'.'
        && name[name.len() - ext.len()..].eq_ignore_ascii_case(ext.as_bytes())
}
pub use grid::{AngularGrid, ChannelSelection, Channels, HalfDiff, Vec3, unit};
pub use lookup::Lookup;
pub use source::{Blend, BrdfSource, ImportReport};
pub use store::{Store, StoreInfo, StoreOptions, StoreWriter};

#[cfg(test)]
mod tests {
    #[test]
    fn extensions_match_in_any_case_and_only_whole() {
        use super::has_extension as has;
        assert!(has("a/GOLD.BSDF", "bsdf") && has("gold.bsdf", "bsdf") && has("x.Npy", "npy"));
        assert!(has(".sbrdf", "sbrdf"), "as `ends_with(\".sbrdf\")` read it");
        assert!(!has("gold.bsdf.tmp", "bsdf") && !has("goldbsdf", "bsdf"));
        assert!(!has("a.sbrdf", "brdf") && !has("", "npy") && !has("npy", "npy"));
        assert!(has("é.NPY", "npy") && !has("a.npé", "npy"));
    }
}
