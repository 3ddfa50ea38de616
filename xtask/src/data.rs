//! The data stage: a `.sbrdf` store from the synthetic preset or imported files, through the
//! library crates (brdf-synth, brdf-io) exactly as `specgp synth` / `specgp import` do.

use std::path::Path;
use std::time::Instant;

use brdf_io::store::Compression;
use brdf_io::{Channels, ImportReport, StoreInfo, StoreOptions, StoreWriter};
use indicatif::{ProgressBar, ProgressStyle};

use crate::config::{DataConfig, DataSource};
use crate::error::{Error, Result};

/// A progress bar on stderr (hidden when stderr is not a terminal, e.g. in tests).
pub fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{what} [{{elapsed_precise}}] {{bar:40}} {{pos}}/{{len}} {{msg}}"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb
}

/// Writes the dataset of `config` to the store `out`; returns the import report (empty for
/// synthetic data) and the seconds taken.
pub fn build_store(config: &DataConfig, out: &Path) -> Result<(ImportReport, f64)> {
    let start = Instant::now();
    let options = StoreOptions {
        dtype: config.dtype,
        compression: Compression::None,
        ..StoreOptions::default()
    };
    let err = |e: &dyn std::fmt::Display| Error::stage("data", out, e);
    let report = match &config.source {
        DataSource::Synth {
            channels,
            seed,
            only,
        } => {
            let mut materials = brdf_synth::preset(*seed);
            if let Some(only) = only {
                materials.retain(|m| only.contains(&m.name));
            }
            let pb = bar(config.grid.len() as u64, "synth");
            brdf_synth::write_store(
                out,
                &materials,
                config.grid,
                channels,
                options,
                *seed,
                |done| pb.set_position(done as u64),
            )
            .map_err(|e| err(&e))?;
            pb.finish_and_clear();
            ImportReport::new()
        }
        DataSource::Nbrdf {
            weights,
            names,
            only,
        } => {
            let set = brdf_io::nbrdf::NbrdfSet::open(weights, names)
                .map_err(|e| Error::stage("data", weights, e))?;
            let rows: Vec<usize> = match only {
                Some(list) => list
                    .iter()
                    .map(|n| {
                        set.find(n.trim()).ok_or_else(|| {
                            let known = crate::config::no_material_named(n.trim(), set.names());
                            Error::stage("data", names, known)
                        })
                    })
                    .collect::<Result<_>>()?,
                None => (0..set.len()).collect(),
            };
            // The networks' inputs are the same for every network: made once.
            let inputs = brdf_io::nbrdf::GridInputs::new(&config.grid);
            import_each(out, config, Channels::Rgb, options, rows.len(), |i| {
                let net = set
                    .material(rows[i])
                    .map_err(|e| Error::stage("data", weights, e))?;
                let (values, report) = net
                    .resample_on(&inputs, brdf_io::nbrdf::NbrdfOptions::default())
                    .map_err(|e| Error::stage("data", weights, e))?;
                let source = format!("{} row {}", weights.display(), rows[i]);
                Ok((net.name().to_owned(), source, values, report))
            })?
        }
        DataSource::Merl { files } => {
            import_each(out, config, Channels::Rgb, options, files.len(), |i| {
                let file = &files[i];
                let brdf =
                    brdf_io::merl::read_merl(file).map_err(|e| Error::stage("data", file, e))?;
                let (values, report) =
                    brdf.resample(&config.grid, brdf_io::merl::Resampling::Average);
                Ok((stem(file), file.display().to_string(), values, report))
            })?
        }
        DataSource::Rgl { files, channels } => {
            use brdf_io::rgl::RglBsdf;
            let channels = match channels {
                Some(c) => c.clone(),
                None => RglBsdf::open(&files[0])
                    .map_err(|e| Error::stage("data", &files[0], e))?
                    .native_channels()
                    .clone(),
            };
            import_each(out, config, channels.clone(), options, files.len(), |i| {
                let file = &files[i];
                let (values, report) = RglBsdf::open(file)
                    .and_then(|b| b.resample(&config.grid, &channels))
                    .map_err(|e| Error::stage("data", file, e))?;
                Ok((stem(file), file.display().to_string(), values, report))
            })?
        }
    };
    Ok((report, start.elapsed().as_secs_f64()))
}

type Loaded = (String, String, Vec<f32>, ImportReport);

fn import_each(
    out: &Path,
    config: &DataConfig,
    channels: Channels,
    options: StoreOptions,
    count: usize,
    mut load: impl FnMut(usize) -> Result<Loaded>,
) -> Result<ImportReport> {
    let info = StoreInfo {
        grid: config.grid,
        channels,
    };
    let store_err = |e: brdf_io::Error| Error::stage("data", out, e);
    let mut writer = StoreWriter::create(out, info, options).map_err(store_err)?;
    let pb = bar(count as u64, "import");
    let mut total = ImportReport::new();
    // Material i is written while material i + 1 is resampled.
    writer.add_materials_overlapped(
        count,
        |i| {
            let (name, source, values, report) = load(i)?;
            report
                .ensure_finite(&format!("{name} ({source})"))
                .map_err(store_err)?;
            pb.set_message(name.clone());
            total = total.merge(&report);
            pb.inc(1);
            Ok((name, source, values))
        },
        store_err,
    )?;
    pb.finish_and_clear();
    writer.finish().map_err(store_err)?;
    Ok(total)
}

/// The material name of a merl or rgl file: its stem.
pub fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdf_io::store::{Dtype, Store};

    /// The data stage writes its store in the configured value type, uncompressed, with every
    /// material of the synthetic subset it names (in the preset's order).
    #[test]
    fn the_store_takes_the_configured_dtype() {
        let dir = tempfile::tempdir().unwrap();
        for dtype in [Dtype::F16, Dtype::F32] {
            let out = dir.path().join(format!("{dtype:?}.sbrdf"));
            let config = DataConfig {
                source: DataSource::Synth {
                    channels: Channels::parse_wavelengths("400:700:150").unwrap(),
                    seed: 0,
                    only: Some(vec!["metal_gold".into(), "paper_white".into()]),
                },
                grid: "4,4,8".parse().unwrap(),
                dtype,
            };
            build_store(&config, &out).unwrap();
            let header = Store::open(&out).unwrap().header().clone();
            assert_eq!(header.layout.dtype, dtype);
            assert_eq!(header.layout.compression, Compression::None);
            let names: Vec<&str> = header.materials.iter().map(|m| m.name.as_str()).collect();
            assert_eq!(names, ["paper_white", "metal_gold"]);
        }
    }
}
