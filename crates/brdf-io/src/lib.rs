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

pub mod error;
pub mod grid;
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
pub use grid::{AngularGrid, ChannelSelection, Channels, HalfDiff, Vec3};
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
