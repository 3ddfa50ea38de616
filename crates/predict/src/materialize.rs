//! Materialising a predicted material: all its values, streamed chunk by chunk from the store
//! to a `.sbrdf` (one material), a `.npy` (1 x D) or a MERL `.binary` file.
//!
//! Only one batch of chunks (a few MB) is in memory at a time, except for MERL output, which
//! holds the RGB values of one material (3 x cells f32; 17.5 MB on MERL's grid), their f64 copy
//! on MERL's grid (35 MB) and, from another grid, the f32 values interpolated onto it (17.5 MB).

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;

use brdf_io::npy::{NpyDtype, NpyWriter};
use brdf_io::{Channels, StoreInfo, StoreOptions, StoreWriter};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::predictor::PredictedMaterial;

/// File format of a materialised prediction, chosen by the output's extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum OutputFormat {
    /// A one-material dataset store (`.sbrdf`).
    Sbrdf,
    /// A 1 x D `.npy` matrix (f32) in the store's dimension order.
    Npy,
    /// A MERL `.binary` file (RGB).
    Merl,
}

impl OutputFormat {
    /// The format of `path` from its extension (`.sbrdf`, `.npy`, `.binary`); standard output
    /// ([`brdf_io::output::STDOUT`], `-`) takes `.npy`.
    pub fn from_path(path: &Path) -> Result<Self> {
        if path == Path::new(brdf_io::output::STDOUT) {
            return Ok(Self::Npy);
        }
        [
            ("sbrdf", Self::Sbrdf),
            ("npy", Self::Npy),
            ("binary", Self::Merl),
        ]
        .into_iter()
        .find_map(|(ext, format)| brdf_io::has_extension(path, ext).then_some(format))
        .ok_or_else(|| Error::Output {
            path: path.to_owned(),
            reason: "unknown output format: expected a .sbrdf, .npy or .binary file".into(),
        })
    }
}

/// What [`PredictedMaterial::materialize`] wrote.
#[derive(Debug, Clone, serde::Serialize)]
pub struct MaterializeReport {
    /// The output file.
    pub path: PathBuf,
    /// Its format.
    pub format: OutputFormat,
    /// Values written (cells x output channels; MERL files: on MERL's grid).
    pub values: usize,
    /// Size of the file in bytes (`None` when unknown: standard output into a pipe).
    pub bytes: Option<u64>,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Predicted values below 0 (before any format clamps them: a MERL file stores 0). The GP
    /// mean is not constrained to be non-negative: under `log` it reaches down to `-offset`,
    /// under `raw` anywhere.
    pub negatives: usize,
    /// The smallest predicted value (0 when none is negative).
    pub min_value: f64,
}

/// Counts negative values and tracks the minimum of a stream of predicted values.
#[derive(Debug, Clone, Copy, Default)]
pub struct NegativeCount {
    /// Values below 0 so far.
    pub negatives: usize,
    /// The smallest value so far, or 0.
    pub min_value: f64,
}

impl NegativeCount {
    /// Adds a block of values.
    pub fn add(&mut self, values: &[f32]) {
        for &v in values {
            if v < 0.0 {
                self.negatives += 1;
                self.min_value = self.min_value.min(f64::from(v));
            }
        }
    }
}

impl PredictedMaterial {
    /// Streams all values of this material in the output dimension order
    /// (`angular_index * n_out_channels + channel`) to `sink(range, values)`, in consecutive
    /// blocks from 0 to D_out. Chunks of the store are combined in parallel batches (rayon);
    /// `progress(done, total)` counts chunks.
    pub fn stream_values(
        &self,
        mut sink: impl FnMut(Range<usize>, &[f32]) -> Result<()>,
        mut progress: impl FnMut(usize, usize),
    ) -> Result<()> {
        let (store, transformed) = self.predictor().lookup_store();
        let store = store.clone();
        let nc = store.channels().len();
        let mask = store.validity_mask();
        let sel = self.selection().clone();
        let identity = sel.is_identity(nc);
        let n_out = sel.taps().len();
        let n_chunks = store.n_chunks();
        let batch = (2 * rayon::current_num_threads()).max(1);
        let mut cell = vec![0.0f64; nc];
        let mut filled = 0usize;
        let mut cell_index = 0usize;
        let mut out_next = 0usize;
        let mut out_buf: Vec<f32> = Vec::new();
        let mut c0 = 0;
        while c0 < n_chunks {
            let c1 = (c0 + batch).min(n_chunks);
            let parts: Vec<Result<Vec<f64>>> = (c0..c1)
                .into_par_iter()
                .map(|c| {
                    let mut buf = Vec::new();
                    let (range, block) = store.chunk(c, &mut buf)?;
                    Ok(self.combine_chunk(range, block, transformed, mask, nc))
                })
                .collect();
            for part in parts {
                let part = part?;
                out_buf.clear();
                if identity {
                    out_buf.extend(part.iter().map(|v| *v as f32));
                } else {
                    for v in part {
                        cell[filled] = v;
                        filled += 1;
                        if filled == nc {
                            for &(lo, hi, t) in sel.taps() {
                                let x = if t == 0.0 {
                                    cell[lo]
                                } else {
                                    (1.0 - t) * cell[lo] + t * cell[hi]
                                };
                                out_buf.push(x as f32);
                            }
                            filled = 0;
                            cell_index += 1;
                        }
                    }
                }
                if !out_buf.is_empty() {
                    let r = out_next..out_next + out_buf.len();
                    self.check_finite(&out_buf, r.start)?;
                    out_next = r.end;
                    sink(r, &out_buf)?;
                }
            }
            progress(c1, n_chunks);
            c0 = c1;
        }
        debug_assert!(identity || cell_index * n_out == out_next);
        Ok(())
    }

    /// Number of values of the output (cells x output channels).
    pub fn output_len(&self) -> usize {
        self.predictor().grid().len() * self.selection().taps().len()
    }

    /// Writes all values of this material to `path` (format from the extension; written to a
    /// temporary file in the same directory and renamed into place; standard output, `-`, and
    /// other special files are written in place).
    ///
    /// MERL `.binary` output needs RGB channels here (clear error for spectral data; the CLI
    /// converts spectral predictions to sRGB with `render::ColourPipeline` and
    /// [`stream_values`](Self::stream_values)); it is always on MERL's 90 x 90 x 180 grid, the
    /// only one MERL readers accept (values of another grid are interpolated onto it,
    /// [`brdf_io::merl::MerlBrdf::on_merl_grid`]), and the report counts the file's values.
    pub fn materialize(
        &self,
        path: &Path,
        progress: impl FnMut(usize, usize),
    ) -> Result<MaterializeReport> {
        self.materialize_with(path, progress, |_, _| Ok(()))
    }

    /// [`PredictedMaterial::materialize`], showing every block of values to `observe(range,
    /// values)` as it is written (as [`PredictedMaterial::stream_values`] gives them: output
    /// order, before any MERL regridding), e.g. to check the values without reading them again;
    /// an error of `observe` ends the writing (and nothing is renamed into place).
    pub fn materialize_with(
        &self,
        path: &Path,
        progress: impl FnMut(usize, usize),
        mut observe: impl FnMut(Range<usize>, &[f32]) -> Result<()>,
    ) -> Result<MaterializeReport> {
        let start = Instant::now();
        let format = OutputFormat::from_path(path)?;
        let total = self.output_len();
        let grid = *self.predictor().grid();
        let mut values = total;
        let mut count = NegativeCount::default();
        match format {
            OutputFormat::Npy => {
                let mut w = NpyWriter::create(path, NpyDtype::F32, &[1, total])?;
                self.stream_values(
                    |r, v| {
                        observe(r, v)?;
                        count.add(v);
                        Ok(w.write_f32(v)?)
                    },
                    progress,
                )?;
                w.finish()?;
            }
            OutputFormat::Sbrdf => {
                let info = StoreInfo {
                    grid,
                    channels: self.channels().clone(),
                };
                let mut w = StoreWriter::create(path, info, StoreOptions::default())?;
                let source = format!(
                    "specgp predict: {} over {} materials of {}",
                    self.label(),
                    self.coefficients().len(),
                    self.predictor().store().path().display()
                );
                w.declare_materials(&[(self.label(), source.as_str())])?;
                self.stream_values(
                    |r, v| {
                        observe(r.clone(), v)?;
                        count.add(v);
                        Ok(w.write_block(r, v)?)
                    },
                    progress,
                )?;
                w.finish()?;
            }
            OutputFormat::Merl => {
                if self.channels() != &Channels::Rgb {
                    return Err(Error::Output {
                        path: path.to_owned(),
                        reason:
                            "MERL .binary output of PredictedMaterial::materialize needs an RGB \
                                 dataset (this crate has no colour conversion; `specgp predict` \
                                 converts spectral predictions to sRGB with crates/render)"
                                .into(),
                    });
                }
                let mut all = Vec::with_capacity(total);
                self.stream_values(
                    |r, v| {
                        observe(r, v)?;
                        count.add(v);
                        all.extend_from_slice(v);
                        Ok(())
                    },
                    progress,
                )?;
                let merl = brdf_io::merl::MerlBrdf::on_merl_grid(grid, &all)?;
                brdf_io::merl::write_merl(path, &merl)?;
                values = merl.values().len();
            }
        }
        let bytes = brdf_io::output::output_len(path);
        Ok(MaterializeReport {
            path: path.to_owned(),
            format,
            values,
            bytes,
            seconds: start.elapsed().as_secs_f64(),
            negatives: count.negatives,
            min_value: count.min_value,
        })
    }
}
