//! Physically based spectral BRDF models and the embedded default dataset of specgp.
//!
//! - [`spectrum`]: reflectance spectra (embedded ColorChecker and Spectralon tables, smooth
//!   parametric shapes);
//! - [`optics`]: dispersive indices, complex Fresnel reflectance of dielectrics and real metals,
//!   thin-film interference;
//! - [`microfacet`]: GGX with Smith height-correlated masking, Charlie sheen;
//! - [`material`]: layered materials (diffuse / Oren-Nayar base, sheen, flakes, dielectric
//!   interface, clear coat, bare metals), energy-conserving and reciprocal;
//! - [`mod@preset`]: 51 named materials spanning the RGL isotropic catalogue's families,
//!   deterministic per seed;
//! - [`dataset`]: evaluation on an [`brdf_io::AngularGrid`] in memory;
//! - [`stream`]: the same streamed into a `.sbrdf` store, for any grid size.
//!
//! A small dataset with known ground truth, for tests:
//!
//! ```
//! use brdf_io::{AngularGrid, Channels};
//! let grid = AngularGrid::new(4, 4, 8)?;
//! let channels = Channels::parse_wavelengths("450:650:100")?;
//! let data = brdf_synth::preset_dataset(grid, &channels, 0)?;
//! assert_eq!((data.n(), data.d()), (51, 4 * 4 * 8 * 3));
//! // The same values as evaluating a material directly at a bin centre.
//! let gold = brdf_synth::preset_material("metal_gold", 0).unwrap();
//! let i = data.names.iter().position(|n| n == "metal_gold").unwrap();
//! let (wi, wo) = grid.bin_centre(0, 1, 2).to_dirs();
//! let f = gold.eval(wi, wo, 550.0);
//! assert!((data.row(i)[grid.index(0, 1, 2) * 3 + 1] - f).abs() < 1e-9 * f);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod dataset;
pub mod error;
pub mod material;
pub mod microfacet;
pub mod optics;
pub mod preset;
pub mod spectrum;
pub mod stream;

pub use dataset::{DEFAULT_GRID, DEFAULT_WAVELENGTHS, SynthDataset, generate, preset_dataset};
pub use error::{Error, Result};
pub use material::{
    Base, Body, Diffuse, Family, Flakes, Fresnel, FresnelCache, Interface, Material,
    PreparedMaterial, Sheen, Specular, Substrate, directional_albedo,
};
pub use optics::{Ior, Metal};
pub use preset::{N_MATERIALS, preset, preset_material};
pub use spectrum::Spectrum;
pub use stream::write_store;
