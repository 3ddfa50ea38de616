//! specgp's experiment driver, run as `cargo xtask ...` (alias in `.cargo/config.toml`).
//!
//! A thin layer over the library crates: [`config`] parses and validates a pipeline config,
//! [`data`] builds the dataset store (brdf-synth / brdf-io), [`pipeline`] fits (gplvm) and runs
//! the later stages, [`report`] writes `report.md`; [`mod@bench`] sweeps settings for run time
//! against error and [`plot`] draws the result.

pub mod bench;
pub mod config;
pub mod data;
pub mod error;
pub mod figures;
pub mod pipeline;
pub mod plot;
pub mod report;
pub mod stages;

pub use config::{PipelineConfig, PipelineParams};
pub use error::{Error, Result};
pub use pipeline::{Results, project_root, run};
