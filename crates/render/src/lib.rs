//! Colour and pictures for specgp: spectral -> CIE XYZ -> sRGB ([`colour`]), sphere previews of
//! any [`brdf_io::BrdfSource`] ([`sphere`]), latent-space maps ([`map`]) and comparison sheets
//! ([`sheet`]), written as 8-bit sRGB PNGs ([`image`]).
//!
//! Everything renders through `BrdfSource::eval`, so a lazily predicted material is rendered
//! without being materialised.

pub mod cache;
pub mod cie;
pub mod colour;
pub mod error;
pub mod font;
pub mod image;
pub mod map;
pub mod sheet;
pub mod sphere;

pub use cache::CellCache;
pub use colour::{ColourPipeline, Illuminant, SpectralWeights, delta_e_2000, delta_e_2000_rgb};
pub use error::{Error, Result};
pub use image::{Image, ImageDifference};
pub use map::{MapOptions, latent_map};
pub use sheet::{ComparisonSheet, comparison_sheet, path_comparison, sphere_rows};
pub use sphere::{
    ENV_MODE_NAMES, EnvMode, EnvTableSpec, PlaneOptions, SphereOptions, clear_plans, render_plane,
    render_sphere, studio_irradiance, studio_radiance,
};
