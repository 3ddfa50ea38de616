//! `specgp synth`: the embedded default dataset of synthetic spectral materials.

use std::path::PathBuf;
use std::time::Instant;

use crate::console::quantity;
use anyhow::Context as _;
use brdf_io::store::{Compression, Dtype};
use brdf_io::{AngularGrid, Channels, StoreOptions};
use brdf_synth::{DEFAULT_GRID, DEFAULT_WAVELENGTHS, preset, write_store};
use indicatif::{ProgressBar, ProgressStyle};

/// Arguments of `specgp synth`.
#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Output dataset store (`.sbrdf`).
    #[arg(long)]
    out: PathBuf,
    /// Angular resolution TH,TD,PD.
    #[arg(long, default_value_t = DEFAULT_GRID)]
    grid: AngularGrid,
    /// Wavelengths START:END:STEP or a comma list, in nm.
    #[arg(long, default_value = DEFAULT_WAVELENGTHS)]
    wavelengths: String,
    /// Seed: 0 is the canonical preset; other seeds perturb every material slightly.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Stored value type: f32 (exact) or f16 (half precision, half the size; values up to 65504,
    /// which the sharpest built-in materials exceed on 24,24,48 and finer grids: refused there,
    /// while 16,16,32 fits).
    #[arg(long, default_value = "f32")]
    dtype: Dtype,
    /// Compress chunks with zstd at this level (1..=22); uncompressed when absent.
    #[arg(long, value_name = "LEVEL", value_parser = clap::value_parser!(i32).range(1..=22))]
    zstd: Option<i32>,
}

/// Runs `specgp synth`.
pub fn synth(args: &SynthArgs) -> anyhow::Result<()> {
    crate::paths::ensure_extension(&args.out, "sbrdf", "a dataset store")?;
    crate::paths::ensure_output_directory(&args.out)?;
    let channels = Channels::parse_wavelengths(&args.wavelengths)?;
    let materials = preset(args.seed);
    let start = Instant::now();
    let pb = ProgressBar::new(args.grid.len() as u64);
    pb.set_style(
        ProgressStyle::with_template(
            "synth [{elapsed_precise}] {bar:40} {pos}/{len} cells ({eta} left)",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let options = StoreOptions {
        dtype: args.dtype,
        compression: args
            .zstd
            .map_or(Compression::None, |level| Compression::Zstd { level }),
        ..StoreOptions::default()
    };
    if let Some(bytes) =
        options.uncompressed_bytes(materials.len(), args.grid.len() * channels.len())
    {
        brdf_io::output::ensure_space(&args.out, bytes, "the dataset store")?;
    }
    tracing::info!(
        grid = %args.grid,
        channels = channels.len(),
        materials = materials.len(),
        seed = args.seed,
        "synthesising"
    );
    let header = write_store(
        &args.out,
        &materials,
        args.grid,
        &channels,
        options,
        args.seed,
        |done| pb.set_position(done as u64),
    )
    .context("synth")?;
    pb.finish_and_clear();
    let bytes = brdf_io::output::output_len(&args.out)
        .map_or_else(|| "size unknown".to_owned(), |b| format!("{b} bytes"));
    errln!(
        "wrote {}: {}, grid {}, {}, D = {}, {}, {:.1} s",
        args.out.display(),
        quantity(header.n_materials(), "material"),
        args.grid,
        quantity(channels.len(), "channel"),
        args.grid.len() * channels.len(),
        bytes,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
