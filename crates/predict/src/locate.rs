//! Where a material that is not in the training set sits in a model's latent space.
//!
//! The inverse of prediction: given a new material on the model's grid and channels (a newly
//! measured file, another store's material), find the latent point whose GP prediction
//! reconstructs it best. As in leave-one-out ([`crate::evaluate`]), the transformed-space error
//! of any linear predictor follows from Gram quantities: the model's N x N Gram matrix and the
//! new material's N cross products with the training rows, `g_h[i] = y_i . y_h`, plus `|y_h|^2`.
//! One streaming pass over the training store computes those for every target at once; the
//! latent search then costs no data access ([`crate::evaluate::best_latent_point`]), and a
//! second pass measures the located prediction's errors directly, in BRDF and in transformed
//! space (Eq. 22 normalisation).

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use brdf_io::store::Store;
use brdf_io::{AngularGrid, Channels, ImportReport};
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::evaluate::{
    best_latent_point, column_runs, damaged_value, forward_columns, rmse_pass, sq_error_external,
    valid_columns,
};
use crate::predictor::{PointSupport, Predictor, PredictorKind};

/// A material to locate: a name and its D values on the model's grid and channels, in dataset
/// order (`angular_index * channels + channel`, as a store holds them; 0 below the horizon).
#[derive(Debug, Clone)]
pub struct Target {
    /// What the material is called in reports.
    pub name: String,
    /// Where it comes from (a file or store), for reports and errors.
    pub source: String,
    /// Its D values (BRDF f in 1/sr).
    pub values: Vec<f32>,
}

impl Target {
    /// Materials `indices` of `store`, read in one pass over it (for a store on the model's
    /// grid and channels; a store's payload is not re-hashed here: verify it first).
    pub fn from_store(store: &Store, indices: &[usize]) -> Result<Vec<Target>> {
        let (n, d) = (store.n_materials(), store.d());
        if let Some(&m) = indices.iter().find(|&&m| m >= n) {
            return Err(Error::InvalidArgument {
                reason: format!("material {m} of {} (it holds {n})", store.path().display()),
            });
        }
        let mut values: Vec<Vec<f32>> = indices.iter().map(|_| vec![0f32; d]).collect();
        store.for_each_chunk(|range, block| {
            for (r, i) in range.enumerate() {
                for (v, &m) in values.iter_mut().zip(indices) {
                    v[i] = block[r * n + m];
                }
            }
        })?;
        let names = store.names();
        Ok(indices
            .iter()
            .zip(values)
            .map(|(&m, values)| Target {
                name: names[m].to_owned(),
                source: store.path().display().to_string(),
                values,
            })
            .collect())
    }

    /// An RGL `.bsdf` or MERL `.binary` file resampled onto `grid` and `channels` as `specgp
    /// import` does by default (reciprocal means; MERL cells averaged), named by its file stem,
    /// and the resampling report. A file whose channels cannot give `channels` (RGB against
    /// spectral) is an error saying so.
    pub fn from_file(
        path: &Path,
        grid: &AngularGrid,
        channels: &Channels,
    ) -> Result<(Target, ImportReport)> {
        let spec = path.display().to_string();
        let name = path
            .file_stem()
            .map_or_else(|| spec.clone(), |s| s.to_string_lossy().into_owned());
        let rgb_model = *channels == Channels::Rgb;
        let mismatch = |file: &str| Error::InvalidArgument {
            reason: format!(
                "target {spec} is {file}, but the model's data are {}",
                describe_channels(channels)
            ),
        };
        let (bsdf, merl) = (
            brdf_io::has_extension(path, "bsdf"),
            brdf_io::has_extension(path, "binary"),
        );
        let (values, report) = match (bsdf, merl) {
            (true, _) => {
                let bsdf = brdf_io::rgl::RglBsdf::open(path)?;
                let rgb_file = *bsdf.native_channels() == Channels::Rgb;
                if rgb_file != rgb_model {
                    return Err(mismatch(if rgb_file {
                        "an RGB file (R,G,B)"
                    } else {
                        "a spectral file"
                    }));
                }
                let (values, report) = bsdf.resample(grid, channels)?;
                report.ensure_finite(&spec)?;
                (values, report)
            }
            (_, true) => {
                if !rgb_model {
                    return Err(mismatch("a MERL file (R,G,B)"));
                }
                let (values, report) = brdf_io::merl::read_merl(path)?
                    .resample(grid, brdf_io::merl::Resampling::Average);
                report.ensure_finite(&spec)?;
                (values, report)
            }
            _ => {
                return Err(Error::InvalidArgument {
                    reason: format!("target {spec}: expected an RGL .bsdf or a MERL .binary file"),
                });
            }
        };
        Ok((
            Target {
                name,
                source: spec,
                values,
            },
            report,
        ))
    }
}

/// Channels in words, for messages: `R,G,B` or `33 wavelengths 360-1000 nm`.
pub fn describe_channels(channels: &Channels) -> String {
    match channels {
        Channels::Rgb => "RGB (R,G,B)".into(),
        Channels::Spectral(w) => format!(
            "spectral ({} wavelengths {}-{} nm)",
            w.len(),
            w.first().copied().unwrap_or(0.0),
            w.last().copied().unwrap_or(0.0)
        ),
    }
}

/// Where [`locate`] placed one target, and how well the prediction there reconstructs it.
#[derive(Debug, Clone, Serialize)]
pub struct Location {
    /// The target's name.
    pub name: String,
    /// Where the target comes from ([`Target::source`]).
    pub source: String,
    /// The latent point whose GP prediction reconstructs the target best (searched with the
    /// smooth predictor, which is continuous; a training material's own point when the
    /// exact predictor there, that material, does better).
    pub point: Vec<f64>,
    /// Eq. 22 RMSE of the exact predictor's prediction at the point (the default of
    /// `render` and `predict`) against the target, BRDF space (1/sr).
    pub brdf_rmse: f64,
    /// The same in the model's transformed space: the prediction's transformed values (before
    /// the inverse transform) against the target's (what the search minimises).
    pub model_rmse: f64,
    /// The training material closest to the target (smallest transformed-space error).
    pub nearest: String,
    /// Eq. 22 RMSE of that material against the target, BRDF space.
    pub nearest_brdf_rmse: f64,
    /// The same in the transformed space.
    pub nearest_model_rmse: f64,
    /// The training material nearest to the point in the latent space.
    pub nearest_in_latent: String,
    /// Its distance to the point in length-scales.
    pub distance: f64,
    /// The smooth predictor's variance at the point over the prior variance (near 1: far from
    /// every material, see [`crate::PointSupport`]).
    pub variance_fraction: f64,
    /// The prediction's coefficients over the N training materials (transformed space; not
    /// serialised).
    #[serde(skip)]
    pub coefficients: Vec<f64>,
}

impl Location {
    /// Whether the point found is far from every training material
    /// ([`PointSupport::is_far_fraction`]): no prediction in the space resembles the target
    /// more than the data mean does, and its location says little.
    pub fn is_far(&self) -> bool {
        PointSupport::is_far_fraction(self.variance_fraction)
    }
}

/// Locates every target in the latent space of `pred`'s model: one pass over the training
/// store for the cross products, a multi-start latent search per target (`starts` each of the
/// training points, midpoints of pairs of them, points half a length-scale off one of them
/// along an axis and quasi-random points of the region they span, those that reconstruct it
/// best; the smooth predictor's error in the transformed space, [`best_latent_point`]), and
/// one pass for the errors of the exact predictor at the point found
/// (equal to the smooth one's away from training points), which in the transformed space is
/// never worse than the closest training material (the BRDF-space error can be).
/// `progress(done, total)` counts the chunks of both passes.
///
/// Errors: no targets, a target whose length is not the store's D or that holds a NaN or an
/// infinity (named), a damaged store.
pub fn locate(
    pred: &Predictor,
    targets: &[Target],
    starts: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<Location>> {
    let store = pred.store();
    let d = store.d();
    if targets.is_empty() {
        return Err(Error::InvalidArgument {
            reason: "nothing to locate: no target materials".into(),
        });
    }
    for t in targets {
        if t.values.len() != d {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "target {:?} from {} has {} values; the model's grid and channels have D = \
                     {d}",
                    t.name,
                    t.source,
                    t.values.len()
                ),
            });
        }
        if let Some(k) = t.values.iter().position(|v| !v.is_finite()) {
            let nc = store.channels().len();
            return Err(Error::NonFiniteValue {
                what: format!(
                    "value {k} (angular cell {}, channel {}) of target {:?} from {}",
                    k / nc,
                    k % nc,
                    t.name,
                    t.source
                ),
                value: f64::from(t.values[k]),
                cause: "a target's values must be finite".into(),
            });
        }
    }
    let total = 2 * store.n_chunks();
    let first_pass = |k: usize, _: usize| progress(k, total);
    let (cross, norms) = cross_products(pred, targets, &first_pass)?;

    let model = pred.model();
    let g = model.gram_matrix();
    let n = pred.n_materials();
    let points: Vec<Vec<f64>> = model.materials.iter().map(|m| m.coords.clone()).collect();
    let placed: Vec<(Vec<f64>, Vec<f64>, usize)> = (0..targets.len())
        .into_par_iter()
        .map(|r| {
            let g_h = &cross[r * n..(r + 1) * n];
            let (point, _) =
                best_latent_point(pred.gp(), &points, g.as_ref(), g_h, norms[r], starts)?;
            let nearest = (0..n)
                .min_by(|&a, &b| {
                    let ea = g[(a, a)] - 2.0 * g_h[a];
                    let eb = g[(b, b)] - 2.0 * g_h[b];
                    ea.total_cmp(&eb)
                })
                .unwrap_or(0);
            // Report the exact predictor (what `render` and `predict` use at a point), and
            // take the closest material's own point when that material beats the search
            // (the exact predictor returns it there).
            let c = pred.coefficients(&point, PredictorKind::Exact)?;
            let e_point = sq_error_external(g.as_ref(), g_h, norms[r], &c);
            let c_near = pred.coefficients(&points[nearest], PredictorKind::Exact)?;
            let e_near = sq_error_external(g.as_ref(), g_h, norms[r], &c_near);
            let (point, c) = if e_near < e_point {
                (points[nearest].clone(), c_near)
            } else {
                (point, c)
            };
            Ok((point, c, nearest))
        })
        .collect::<Result<_>>()?;

    // Rows 2r and 2r + 1: the located prediction and the nearest material, against target r.
    let coef = Mat::from_fn(2 * targets.len(), n, |row, j| {
        let (_, c, nearest) = &placed[row / 2];
        if row % 2 == 0 {
            c[j]
        } else if j == *nearest {
            1.0
        } else {
            0.0
        }
    });
    let target_values = |d: usize, _: &[f32], out: &mut [f32]| {
        for (pair, t) in out.chunks_exact_mut(2).zip(targets) {
            pair.fill(t.values[d]);
        }
    };
    let target_name = |row: usize| {
        let t = &targets[row / 2];
        format!("target {:?} from {}", t.name, t.source)
    };
    let second_pass = |k: usize, _: usize| progress(store.n_chunks() + k, total);
    let sums = rmse_pass(
        store,
        pred.transform(),
        coef.as_ref(),
        &target_values,
        &target_name,
        true,
        &second_pass,
    )?;
    let n_angles = store.grid().len() as f64;
    let rmse = |s: f64| (s / n_angles).sqrt();
    targets
        .iter()
        .zip(placed)
        .enumerate()
        .map(|(r, (t, (point, coefficients, nearest)))| {
            let support = pred.support(&point)?;
            Ok(Location {
                name: t.name.clone(),
                source: t.source.clone(),
                brdf_rmse: rmse(sums[2 * r].0),
                model_rmse: rmse(sums[2 * r].1),
                nearest: model.materials[nearest].name.clone(),
                nearest_brdf_rmse: rmse(sums[2 * r + 1].0),
                nearest_model_rmse: rmse(sums[2 * r + 1].1),
                nearest_in_latent: support.nearest,
                distance: support.distance,
                variance_fraction: support.variance_fraction,
                point,
                coefficients,
            })
        })
        .collect()
}

/// The transformed-space Gram quantities of each target against the training materials, over
/// the valid cells, in one parallel pass over `pred`'s store (f64 arithmetic, the model's
/// transform, deterministic): the cross products `g_h` (target-major, `targets x N`) and the
/// squared norms `|y_h|^2`.
pub fn cross_products(
    pred: &Predictor,
    targets: &[Target],
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(Vec<f64>, Vec<f64>)> {
    let store = pred.store();
    let transform = pred.transform();
    let n = store.n_materials();
    let m = targets.len();
    let nc = store.channels().len();
    let mask = store.validity_mask();
    let done = AtomicUsize::new(0);
    let total = store.n_chunks();
    type Acc = (Mat<f64>, Vec<f64>, Vec<usize>, Vec<f64>, Vec<f64>);
    let (cross, norms, ..) = store.par_fold_chunks(
        || -> Acc {
            (
                Mat::zeros(m, n),
                vec![0.0; m],
                Vec::new(),
                Vec::new(),
                Vec::new(),
            )
        },
        |(cross, norms, cols, t, u), range, block| {
            // Valid columns only: below-horizon cells hold 0 and carry no data.
            valid_columns(range.clone(), mask, nc, cols);
            let len = cols.len();
            if len > 0 {
                forward_columns(transform, block, n, cols, t);
                // The targets' transformed values, row-major (targets x columns).
                u.clear();
                u.resize(m * len, 0.0);
                for (r, target) in targets.iter().enumerate() {
                    let row = &mut u[r * len..(r + 1) * len];
                    for (k, e) in column_runs(cols) {
                        let (a, b) = (range.start + cols[k], range.start + cols[e - 1] + 1);
                        transform.forward_batch(&target.values[a..b], &mut row[k..e]);
                    }
                    norms[r] += row.iter().map(|v| v * v).sum::<f64>();
                }
                let tm = MatRef::from_column_major_slice(t, n, len);
                let um = MatRef::from_row_major_slice(u, m, len);
                matmul(
                    cross.as_mut(),
                    Accum::Add,
                    um,
                    tm.transpose(),
                    1.0,
                    Par::Seq,
                );
            }
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        },
        |(mut a, mut b, c, t, u), (x, y, ..)| {
            a += &x;
            b.iter_mut().zip(y).for_each(|(p, q)| *p += q);
            (a, b, c, t, u)
        },
    )?;
    let cross: Vec<f64> = (0..m)
        .flat_map(|r| (0..n).map(move |i| (r, i)))
        .map(|(r, i)| cross[(r, i)])
        .collect();
    if let Some(k) = cross.iter().chain(&norms).position(|v| !v.is_finite()) {
        return Err(match damaged_value(store)? {
            Some(e) => e,
            None => Error::NonFiniteValue {
                what: format!(
                    "a cross product of the targets with {} (entry {k})",
                    store.path().display()
                ),
                value: cross
                    .iter()
                    .chain(&norms)
                    .nth(k)
                    .copied()
                    .unwrap_or(f64::NAN),
                cause: "every stored value is finite (checked), so the sum overflowed: values \
                        too large for f64 products"
                    .into(),
            },
        });
    }
    Ok((cross, norms))
}

/// The transformed-space squared error of `coefficients` against a target from its Gram
/// quantities (`g_h`, `g_hh` as [`cross_products`] returns them): what the latent search
/// minimises, for checking a [`Location`] against the direct measurement.
///
/// # Panics
/// If `g_h` or `coefficients` is shorter than the model's N materials.
pub fn gram_sq_error(pred: &Predictor, g_h: &[f64], g_hh: f64, coefficients: &[f64]) -> f64 {
    sq_error_external(pred.model().gram_matrix().as_ref(), g_h, g_hh, coefficients)
}
