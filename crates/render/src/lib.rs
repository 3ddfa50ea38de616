//! Colour and pictures for specgp: spectral -> CIE XYZ -> sRGB ([`colour`]), sphere previews of
//! any [`brdf_io::BrdfSource`] ([`sphere`]), latent-space maps ([`map`]) and comparison sheets
//! ([`sheet`]), written as 8-bit sRGB PNGs ([`image`]).
//!
//! Everything renders through `BrdfSource::eval`, so a lazily predicted material is rendered
//! without being materialised; several predictions of one model in one scene
//! ([`render_spheres`]: latent-map thumbnails, sheets) read each cell they touch once for all.
//!
//! ```
//! use brdf_io::store::StoreMaterial;
//! use brdf_io::{AngularGrid, Channels, StoreOptions};
//! use render::sphere::mean_colour;
//! use render::{Illuminant, SphereOptions, render_sphere};
//!
//! // Three synthetic spectral materials at 33 wavelengths, 360-1000 nm.
//! let dir = tempfile::tempdir()?;
//! let data = dir.path().join("data.sbrdf");
//! let materials: Vec<_> = ["metal_gold", "metal_copper", "spectralon"]
//!     .iter()
//!     .map(|name| brdf_synth::preset_material(name, 0).ok_or("no such preset"))
//!     .collect::<Result<_, _>>()?;
//! let grid = AngularGrid::new(16, 16, 32)?;
//! let channels = Channels::parse_wavelengths("360:1000:20")?;
//! let options = StoreOptions::default();
//! brdf_synth::write_store(&data, &materials, grid, &channels, options, 0, |_| {})?;
//!
//! // 64 x 64 spheres under D65: gold is yellow, the white diffuser neutral.
//! let opts = SphereOptions { size: 64, ..SphereOptions::default() };
//! let gold = render_sphere(&StoreMaterial::open(&data, "metal_gold")?, &opts)?;
//! let ([r, g, b], pixels) = mean_colour(&gold); // linear sRGB over the covered pixels
//! assert!(r > g && g > b && pixels > 2000);
//! let white = render_sphere(&StoreMaterial::open(&data, "spectralon")?, &opts)?;
//! let ([r, g, b], _) = mean_colour(&white);
//! assert!((r - g).abs() < 0.01 * g && (b - g).abs() < 0.01 * g);
//! gold.save_png(&dir.path().join("gold.png"))?; // 8-bit sRGB with alpha
//!
//! // A predicted material, rendered lazily: only the cells the picture touches, and only the
//! // wavelengths the observer weighs under the illuminant, are looked up.
//! let model = dir.path().join("model.toml");
//! let config = gplvm::FitParams { latent_dim: 1, ..Default::default() }.check()?;
//! gplvm::fit_store(&data, &config)?.save(&model)?;
//! let pred = predict::Predictor::open(&model)?;
//! let x = (pred.model().materials[0].coords[0] + pred.model().materials[1].coords[0]) / 2.0;
//! let mut between = pred.predict(&[x], predict::PredictorKind::Exact)?;
//! if let Some(w) = render::colour::needed_wavelengths(between.channels(), Illuminant::D65)? {
//!     between = between.with_wavelengths(&w)?; // 360-780 nm here (22 of the 33)
//! }
//! let ([r, g, b], _) = mean_colour(&render_sphere(&between, &opts)?);
//! assert!(r > g && g > b); // between gold and copper: a warm metal
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

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
    render_sphere, render_spheres, studio_irradiance, studio_radiance,
};
