//! The render stage: sphere sheets (measured against GP reconstruction, with Delta E 2000), the
//! comparison sheet (stored vs exact vs smooth vs held out, with Delta E heat maps), the paths
//! figure (GP path against linear blends), spheres of the predictions and the latent map,
//! through the render crate.

use std::path::Path;
use std::time::Instant;

use brdf_io::lookup::WithLookup;
use brdf_io::store::StoreMaterial;
use brdf_io::{BrdfSource, Lookup};
use predict::evaluate::LooRow;
use predict::{Predictor, PredictorKind};
use render::{Image, SphereOptions, render_spheres};
use serde::Serialize;

use crate::error::{Error, Result};
use crate::stages::PredictionRow;

/// Delta E of one material's sphere: measured against the smooth GP reconstruction.
#[derive(Debug, Clone, Serialize)]
pub struct SphereDeltaE {
    /// Material name.
    pub name: String,
    /// Mean CIE Delta E 2000 over the pixels covered by both spheres.
    pub mean_delta_e: f64,
    /// The same for the GP's prediction of the material held out (leave-one-out), when run.
    pub held_out_delta_e: Option<f64>,
}

/// What the render stage drew.
#[derive(Debug, Clone, Serialize)]
pub struct Figures {
    /// Figure files (relative to the output directory) and captions.
    pub files: Vec<(String, String)>,
    /// Per material in the sheet: Delta E of the smooth reconstruction (and of the held-out
    /// prediction, with leave-one-out results).
    pub delta_e: Vec<SphereDeltaE>,
    /// Mean of `delta_e`.
    pub mean_delta_e: f64,
    /// The comparison sheet's mean Delta E against the stored spheres, per column (`exact`,
    /// `smooth`, `held out`), over its materials.
    pub comparison_delta_e: Vec<(String, f64)>,
    /// Seconds per sphere (mean).
    pub seconds_per_sphere: f64,
}

const BG: [f64; 3] = [0.18, 0.18, 0.18];
const INK: [f64; 3] = [0.9, 0.9, 0.9];

/// Top of the Delta E scale of the comparison sheet's heat maps.
const COMPARISON_DE_MAX: f64 = 10.0;
/// Spheres per path in the paths figure (t = 0, 1/6, ..., 1).
const PATH_STEPS: usize = 7;
/// At most this many pairs in the paths figure.
const MAX_PATHS: usize = 3;

/// Mean Delta E 2000 between two renders of the same size over the pixels fully covered in
/// both, their colours clamped at 0 (as shown), NaN when they share none: the comparison
/// sheet's measure ([`render::sheet::delta_e_map`], [`render::sheet::mean_delta_e`]), so the
/// sheet and the comparison sheet agree on the same pair of spheres.
pub fn mean_delta_e(a: &Image, b: &Image) -> render::Result<f64> {
    let map = render::sheet::delta_e_map(a, b)?;
    Ok(render::sheet::mean_delta_e(&map))
}

/// Height of one label line (7-pixel glyphs plus spacing).
const LINE_H: usize = 9;
/// Height of a sphere's label: names of up to three lines (long ones wrap at '_').
const LABEL_H: usize = 3 * LINE_H + 3;

/// Draws `text` wrapped into at most `lines` lines of `width` pixels at (x, y).
fn label(img: &mut Image, x: usize, y: usize, width: usize, text: &str, lines: usize) {
    for (k, line) in render::font::wrap(text, width, 1, lines).iter().enumerate() {
        img.text(x as i64, (y + k * LINE_H) as i64, line, 1, INK);
    }
}

fn err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::stage("render", path, e)
}

/// The sources of `v` as trait objects (a row of a sphere sheet).
fn as_sources<T: BrdfSource>(v: &[T]) -> Vec<&dyn BrdfSource> {
    v.iter().map(|m| m as &dyn BrdfSource).collect()
}

/// The sphere options, output directory and leave-one-out results every figure of a run
/// shares; its predictor caches each cell's forward-transformed values for all of them.
struct Scene<'a> {
    pred: &'a Predictor,
    opts: SphereOptions,
    /// The lookup between bin centres of every material rendered ([`Scene::look`]).
    lookup: Lookup,
    out: &'a Path,
    loo: Option<&'a [LooRow]>,
}

impl Scene<'_> {
    /// The width of a sphere's cell in a sheet: the sphere and 8 pixels between neighbours.
    fn cell(&self) -> usize {
        self.opts.size + 8
    }

    /// `source` (a stored or predicted material) with the run's lookup; `path`: the figure, for
    /// errors.
    fn look<'s>(&self, source: impl BrdfSource + 's, path: &Path) -> Result<Looked<'s>> {
        WithLookup::new(Box::new(source) as Box<dyn BrdfSource + 's>, self.lookup)
            .map_err(|e| err(path, e))
    }

    /// The GP's prediction of material `name` held out (leave-one-out), labelled `loo-NAME`;
    /// `None` without leave-one-out results or without a row for it.
    fn held_out(&self, name: &str) -> predict::Result<Option<predict::PredictedMaterial>> {
        let Some(row) = self
            .loo
            .and_then(|rows| rows.iter().find(|r| r.name == name))
        else {
            return Ok(None);
        };
        let label = format!("loo-{name}");
        self.pred
            .from_coefficients(row.gp_coefficients.clone(), label)
            .map(Some)
    }
}

/// A material as [`Scene::look`] gives it.
type Looked<'s> = WithLookup<Box<dyn BrdfSource + 's>>;

/// A figure file (relative to the output directory) and its caption.
type Caption = (String, String);

/// A mean Delta E per column of the comparison sheet, by column name.
type ColumnDeltaE = Vec<(String, f64)>;

/// Renders the figures of a pipeline run of `config` into `out` (its `[render]` settings, its
/// midpoints' pairs as paths, its lookup).
pub fn render_figures(
    pred: &Predictor,
    predictions: &[PredictionRow],
    evaluation: Option<&predict::evaluate::Evaluation>,
    config: &crate::config::PipelineConfig,
    located: &[predict::locate::Location],
    out: &Path,
) -> Result<Figures> {
    let (render, pairs) = (&config.params.render, &config.params.predict.midpoints);
    let start = Instant::now();
    // Every figure renders predictions of this one model: each cell's logarithms once.
    let pred = &pred.with_forward_cache();
    let scene = Scene {
        pred,
        opts: SphereOptions {
            size: render.size as usize,
            env_mode: render.env_mode().map_err(|reason| err(out, reason))?,
            ..SphereOptions::default()
        },
        lookup: config.lookup,
        out,
        loo: evaluation.and_then(|e| e.loo.as_deref()),
    };
    // The sheets' materials, evenly through the dataset.
    let n = pred.model().materials.len();
    let k = render.sheet_materials.min(n).max(1);
    let picks: Vec<usize> = (0..k).map(|j| j * n / k).collect();
    let (sheet, mut spheres, delta_e) = sheet_figure(&scene, &picks, &render.env)?;
    let (comparison, s, comparison_delta_e) = comparison_figure(&scene, &picks)?;
    spheres += s;
    let mut files = vec![sheet, comparison];
    if !pairs.is_empty() {
        let (paths, s) = paths_figure(&scene, pairs)?;
        files.push(paths);
        spheres += s;
    }
    if !predictions.is_empty() {
        let (file, s) = predictions_figure(&scene, predictions)?;
        files.push(file);
        spheres += s;
    }
    if pred.model().latent_dim >= 2 {
        files.push(latent_figure(&scene, predictions, located)?);
    }
    let finite: Vec<f64> = delta_e
        .iter()
        .map(|d| d.mean_delta_e)
        .filter(|v| v.is_finite())
        .collect();
    Ok(Figures {
        files,
        mean_delta_e: finite.iter().sum::<f64>() / finite.len().max(1) as f64,
        delta_e,
        comparison_delta_e,
        seconds_per_sphere: start.elapsed().as_secs_f64() / spheres.max(1) as f64,
    })
}

/// `sheet.png`: the stored material (top) against the smooth GP reconstruction (middle) and,
/// with leave-one-out results, the GP's prediction of it from the other materials (bottom: a
/// reconstruction at a material's own point is nearly guaranteed, a held-out one is not), for
/// each material of `picks`; with the number of spheres rendered and each material's Delta E.
/// `env` is the config's environment (named in the caption unless it is the default).
fn sheet_figure(
    scene: &Scene<'_>,
    picks: &[usize],
    env: &str,
) -> Result<(Caption, usize, Vec<SphereDeltaE>)> {
    let (pred, opts, out, loo) = (scene.pred, &scene.opts, scene.out, scene.loo);
    let (model, store, size) = (pred.model(), pred.store().clone(), opts.size);
    let mut spheres = 0;
    let (cell, label_h, k) = (scene.cell(), LABEL_H, picks.len());
    let rows = if loo.is_some() { 3 } else { 2 };
    let mut sheet = Image::new(k * cell + 4, rows * (cell + label_h) + 4, BG);
    let mut held_out_delta_e = Vec::new();
    let mut delta_e = Vec::new();
    let sheet_path = out.join("sheet.png");
    // Every sphere in one render (the reconstructions, predictions of one model, evaluate
    // their cells together): per pick, measured, reconstructed and held out (if any).
    let mut sources = Vec::new();
    let mut has_held = Vec::new();
    for &i in picks {
        let measured =
            StoreMaterial::by_index(store.clone(), i).map_err(|e| err(&sheet_path, e))?;
        sources.push(scene.look(measured, &sheet_path)?);
        let rec = pred
            .predict(&model.materials[i].coords, PredictorKind::Smooth)
            .map_err(|e| err(&sheet_path, e))?;
        sources.push(scene.look(rec, &sheet_path)?);
        let held = scene
            .held_out(&model.materials[i].name)
            .map_err(|e| err(&sheet_path, e))?;
        has_held.push(held.is_some());
        if let Some(held) = held {
            sources.push(scene.look(held, &sheet_path)?);
        }
    }
    let mut rendered = render_spheres(&as_sources(&sources), opts).into_iter();
    let mut next = || -> Result<Image> {
        match rendered.next() {
            Some(sphere) => sphere.map_err(|e| err(&sheet_path, e)),
            None => Err(err(&sheet_path, "fewer spheres rendered than asked for")),
        }
    };
    for (col, (&i, &held)) in picks.iter().zip(&has_held).enumerate() {
        let name = &model.materials[i].name;
        let a = next()?;
        let b = next()?;
        spheres += 2;
        let de = mean_delta_e(&a, &b).map_err(|e| err(&sheet_path, e))?;
        let x = 4 + col * cell;
        sheet.blit(&a, x as i64, 4);
        label(&mut sheet, x, 4 + size + 2, size, name, 3);
        let y2 = 4 + cell + label_h;
        sheet.blit(&b, x as i64, y2 as i64);
        label(
            &mut sheet,
            x,
            y2 + size + 2,
            size,
            &format!("rec dE {de:.2}"),
            1,
        );
        delta_e.push(SphereDeltaE {
            name: name.clone(),
            mean_delta_e: de,
            held_out_delta_e: None,
        });
        if held {
            let c = next()?;
            spheres += 1;
            let de = mean_delta_e(&a, &c).map_err(|e| err(&sheet_path, e))?;
            let y3 = 4 + 2 * (cell + label_h);
            sheet.blit(&c, x as i64, y3 as i64);
            label(
                &mut sheet,
                x,
                y3 + size + 2,
                size,
                &format!("loo dE {de:.2}"),
                1,
            );
            held_out_delta_e.push(de);
            if let Some(last) = delta_e.last_mut() {
                last.held_out_delta_e = Some(de);
            }
        }
    }
    sheet
        .save_png(&sheet_path)
        .map_err(|e| err(&sheet_path, e))?;
    // Every sphere's lighting, when it is not the default directional light plus uniform
    // environment (the Delta E values depend on it).
    let env_note = match env {
        "table" => String::new(),
        env => format!(" Spheres rendered with `render.env = \"{env}\"`."),
    };
    let held_out_caption = if held_out_delta_e.is_empty() {
        String::new()
    } else {
        format!(
            "; bottom (`loo`): the GP's prediction of each material held out (leave-one-out: \
             refit without it, placed at its best latent point), mean Delta E {:.2}",
            held_out_delta_e.iter().sum::<f64>() / held_out_delta_e.len() as f64
        )
    };
    let caption = (
        "sheet.png".to_string(),
        format!(
            "Top: the dataset's materials as stored (measured, synthetic or network-approximated, \
             as the data section says); {} (`rec`): the smooth GP prediction at each material's \
             own latent point (a reconstruction), with the mean CIE Delta E 2000 over the \
             sphere{held_out_caption}.{env_note}",
            if held_out_delta_e.is_empty() {
                "bottom"
            } else {
                "middle"
            }
        ),
    );
    Ok((caption, spheres, delta_e))
}

/// `comparison.png` (render crate): per material of `picks`, the stored sphere, the exact and
/// smooth reconstructions at its latent point (and the held-out prediction), each with a
/// CIEDE2000 heat map against the stored one; with the number of spheres rendered and the
/// mean Delta E per column.
fn comparison_figure(scene: &Scene<'_>, picks: &[usize]) -> Result<(Caption, usize, ColumnDeltaE)> {
    let (pred, opts, out, loo) = (scene.pred, &scene.opts, scene.out, scene.loo);
    let (model, store) = (pred.model(), pred.store().clone());
    let comparison_path = out.join("comparison.png");
    let e = |e: predict::Error| err(&comparison_path, e);
    let mut kept: Vec<Vec<Looked<'_>>> = Vec::new();
    for &i in picks {
        let x = &model.materials[i].coords;
        let stored =
            StoreMaterial::by_index(store.clone(), i).map_err(|e| err(&comparison_path, e))?;
        let mut row = vec![
            scene.look(stored, &comparison_path)?,
            scene.look(
                pred.predict(x, PredictorKind::Exact).map_err(e)?,
                &comparison_path,
            )?,
            scene.look(
                pred.predict(x, PredictorKind::Smooth).map_err(e)?,
                &comparison_path,
            )?,
        ];
        let name = &model.materials[i].name;
        if let Some(held) = scene.held_out(name).map_err(e)? {
            row.push(scene.look(held, &comparison_path)?);
        }
        kept.push(row);
    }
    let mut columns = vec!["STORED", "EXACT", "SMOOTH"];
    if loo.is_some() {
        columns.push("HELD OUT");
    }
    let rows: Vec<render::sheet::SheetRow<'_>> = picks
        .iter()
        .zip(&kept)
        .map(|(&i, row)| {
            let name = model.materials[i].name.to_uppercase();
            (name, as_sources(row))
        })
        .collect();
    let comparison = render::comparison_sheet(&columns, &rows, opts, COMPARISON_DE_MAX)
        .map_err(|e| err(&comparison_path, e))?;
    let spheres = rows.iter().map(|(_, r)| r.len()).sum::<usize>();
    comparison
        .image
        .save_png(&comparison_path)
        .map_err(|e| err(&comparison_path, e))?;
    let comparison_delta_e: ColumnDeltaE = (1..columns.len())
        .map(|c| {
            let v: Vec<f64> = comparison.mean_delta_e.iter().map(|r| r[c - 1]).collect();
            (
                columns[c].to_lowercase(),
                v.iter().sum::<f64>() / v.len().max(1) as f64,
            )
        })
        .collect();
    let column_means: Vec<String> = comparison_delta_e
        .iter()
        .map(|(c, v)| format!("{c} {v:.2}"))
        .collect();
    let caption = (
        "comparison.png".to_string(),
        format!(
            "The same materials as stored, reconstructed by the exact predictor (which returns a \
             training material as stored) and by the smooth one at their latent points{}, each \
             with a map of CIE Delta E 2000 against the stored sphere (scale 0 to \
             {COMPARISON_DE_MAX}). Mean Delta E per column: {}.",
            if loo.is_some() {
                ", and held out (leave-one-out)"
            } else {
                ""
            },
            column_means.join(", ")
        ),
    );
    Ok((caption, spheres, comparison_delta_e))
}

/// `paths.png` (the paper's Fig. 4.4), for the first [`MAX_PATHS`] of `pairs`: along the
/// straight latent line between two materials (exact predictor: the materials themselves at the
/// ends) against linear interpolation of their values, in the model's transformed space
/// (`predict --lerp`) and, for a log model, in BRDF values (the paper's blend of raw data);
/// with the number of spheres rendered.
fn paths_figure(scene: &Scene<'_>, pairs: &[[String; 2]]) -> Result<(Caption, usize)> {
    let (pred, opts, out) = (scene.pred, &scene.opts, scene.out);
    let (model, store) = (pred.model(), pred.store().clone());
    let mut spheres = 0;
    let path = out.join("paths.png");
    let e = |e: predict::Error| err(&path, e);
    let t: Vec<f64> = (0..PATH_STEPS)
        .map(|k| k as f64 / (PATH_STEPS - 1) as f64)
        .collect();
    let captions: Vec<String> = t.iter().map(|v| format!("{v:.2}")).collect();
    let mut blocks = Vec::new();
    for [a, b] in pairs.iter().take(MAX_PATHS) {
        let (ia, ib) = (
            pred.material_index(a).map_err(e)?,
            pred.material_index(b).map_err(e)?,
        );
        let (xa, xb) = (&model.materials[ia].coords, &model.materials[ib].coords);
        let gp = t
            .iter()
            .map(|&s| {
                let x: Vec<f64> = xa.iter().zip(xb).map(|(p, q)| p + s * (q - p)).collect();
                scene.look(pred.predict(&x, PredictorKind::Exact).map_err(e)?, &path)
            })
            .collect::<Result<Vec<_>>>()?;
        let lerp = t
            .iter()
            .map(|&s| scene.look(pred.lerp(a, b, 1.0 - s).map_err(e)?, &path))
            .collect::<Result<Vec<_>>>()?;
        let stored = |i| StoreMaterial::by_index(store.clone(), i).map_err(|e| err(&path, e));
        let (stored_a, stored_b) = (
            scene.look(stored(ia)?, &path)?,
            scene.look(stored(ib)?, &path)?,
        );
        let blends = t
            .iter()
            .map(|&s| brdf_io::Blend::new(&stored_a, &stored_b, 1.0 - s))
            .collect::<brdf_io::Result<Vec<_>>>()
            .map_err(|e| err(&path, e))?;
        let mut rows = vec![("GP PATH".to_string(), as_sources(&gp))];
        let raw = model.transform == gplvm::Transform::Raw;
        rows.push((
            if raw { "LINEAR" } else { "LINEAR, MODEL SPACE" }.to_string(),
            as_sources(&lerp),
        ));
        if !raw {
            rows.push(("LINEAR, BRDF VALUES".to_string(), as_sources(&blends)));
        }
        spheres += rows.iter().map(|(_, r)| r.len()).sum::<usize>();
        let img = render::sphere_rows(&rows, &captions, opts).map_err(|e| err(&path, e))?;
        blocks.push((format!("{} TO {}", a.to_uppercase(), b.to_uppercase()), img));
    }
    let width = blocks.iter().map(|(_, i)| i.width).max().unwrap_or(0) + 8;
    let height: usize = blocks
        .iter()
        .map(|(_, i)| i.height + LINE_H + 6)
        .sum::<usize>()
        + 4;
    let mut img = Image::new(width, height, BG);
    let mut y = 4usize;
    for (title, block) in &blocks {
        img.text(4, y as i64, title, 1, INK);
        y += LINE_H + 2;
        img.blit(block, 4, y as i64);
        y += block.height + 4;
    }
    img.save_png(&path).map_err(|e| err(&path, e))?;
    let caption = (
        "paths.png".to_string(),
        format!(
            "The paper's Fig. 4.4: from one material (t = 0) to another (t = 1) along the \
             straight line between their latent points (GP path, exact predictor){}; the \
             first {} pair(s) of the configured midpoints.",
            if model.transform == gplvm::Transform::Raw {
                ", against the linear interpolation of their values (t y2 + (1 - t) y1)".to_string()
            } else {
                format!(
                    ", against linear interpolation of their values in the model's transformed \
                     space ({}, as `specgp predict --lerp`) and of their BRDF values (the \
                     paper's blend)",
                    model.transform
                )
            },
            blocks.len()
        ),
    );
    Ok((caption, spheres))
}

/// `predictions.png`: spheres of the predicted materials at the configured latent points,
/// labelled with their names and coordinates; with the number of spheres rendered.
fn predictions_figure(
    scene: &Scene<'_>,
    predictions: &[PredictionRow],
) -> Result<(Caption, usize)> {
    let (pred, opts, out) = (scene.pred, &scene.opts, scene.out);
    let size = opts.size;
    let mut spheres = 0;
    let path = out.join("predictions.png");
    let (cell, label_h) = (scene.cell(), LABEL_H);
    let mut img = Image::new(predictions.len() * cell + 4, cell + 2 * label_h + 4, BG);
    // All in one render: predictions of one model evaluate their cells together.
    let sources = predictions
        .iter()
        .map(|p| {
            let kind = if p.predictor == "smooth" {
                PredictorKind::Smooth
            } else {
                PredictorKind::Exact
            };
            let m = pred.predict(&p.point, kind).map_err(|e| err(&path, e))?;
            scene.look(m, &path)
        })
        .collect::<Result<Vec<_>>>()?;
    let rendered = render_spheres(&as_sources(&sources), opts);
    for (col, (p, s)) in predictions.iter().zip(rendered).enumerate() {
        let s = s.map_err(|e| err(&path, e))?;
        spheres += 1;
        let x = 4 + col * cell;
        img.blit(&s, x as i64, 4);
        label(&mut img, x, 4 + size + 2, size, &p.label, 3);
        let coords: Vec<String> = p.point.iter().map(|v| format!("{v:.2}")).collect();
        label(
            &mut img,
            x,
            4 + size + 2 + label_h,
            size,
            &coords.join(", "),
            3,
        );
    }
    img.save_png(&path).map_err(|e| err(&path, e))?;
    let caption = (
        "predictions.png".to_string(),
        "Spheres of the predicted materials at the configured latent points.".to_string(),
    );
    Ok((caption, spheres))
}

/// `latent.png` (render crate): the training materials, `predictions` and `located`
/// materials over the predictive standard deviation, in the first two latent axes (other
/// coordinates 0, the prior mean).
fn latent_figure(
    scene: &Scene<'_>,
    predictions: &[PredictionRow],
    located: &[predict::locate::Location],
) -> Result<Caption> {
    let (pred, out) = (scene.pred, scene.out);
    let model = pred.model();
    let path = out.join("latent.png");
    let q = model.latent_dim;
    let points: Vec<render::map::LabelledPoint> = model
        .materials
        .iter()
        .map(|m| (m.name.clone(), [m.coords[0], m.coords[1]]))
        .chain(
            predictions
                .iter()
                .map(|p| (p.label.clone(), [p.point[0], p.point[1]])),
        )
        .chain(
            located
                .iter()
                .map(|l| (format!("{} (located)", l.name), [l.point[0], l.point[1]])),
        )
        .collect();
    let variance = |p: [f64; 2]| -> render::Result<f64> {
        let mut x = vec![0.0; q];
        x[0] = p[0];
        x[1] = p[1];
        pred.variance_transformed(&x, PredictorKind::Smooth)
            .map_err(|e| render::Error::InvalidArgument {
                reason: e.to_string(),
            })
    };
    let opts = render::MapOptions {
        caption: render::map::variance_caption(&model.transform.to_string(), q),
        predicted_points: predictions.len() + located.len(),
        ..render::MapOptions::default()
    };
    let img = render::latent_map(&points, &variance, None, &opts).map_err(|e| err(&path, e))?;
    img.save_png(&path).map_err(|e| err(&path, e))?;
    Ok((
        "latent.png".to_string(),
        "The training materials (red dots) and the predicted points and located materials \
         (blue rings) in the first two latent coordinates (equal scales), shaded by the GP's predictive standard \
         deviation per transformed value (the square root of the predictions table's \
         variance; for q > 2, on the slice through 0 of the other coordinates, so points off \
         that slice can sit in a lighter or darker area than their own variance says)."
            .to_string(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Delta E averages over the pixels both images cover fully (alpha >= 0.999), pixel by
    /// pixel, colours clamped at 0; nothing in common is NaN, not 0; sizes must agree.
    #[test]
    fn mean_delta_e_averages_over_the_pixels_both_cover() {
        use render::delta_e_2000_rgb;
        let (grey, red, blue) = ([0.2, 0.2, 0.2], [0.5, 0.1, 0.1], [0.1, 0.1, 0.6]);
        let mut a = Image::new(5, 1, grey);
        let mut b = Image::new(5, 1, grey);
        a.rgb[1] = red;
        b.rgb[1] = blue;
        a.rgb[2] = blue;
        b.rgb[2] = grey;
        // Pixel 3 differs but is not covered by b (an edge pixel of a sphere).
        a.rgb[3] = red;
        b.alpha[3] = 0.99;
        // Pixel 4 differs only below 0, which is shown as 0.
        a.rgb[4] = [-0.3, 0.0, 0.2];
        b.rgb[4] = [0.0, 0.0, 0.2];
        let want = (delta_e_2000_rgb(red, blue) + delta_e_2000_rgb(blue, grey)) / 4.0;
        assert!(want > 10.0);
        let got = mean_delta_e(&a, &b).unwrap();
        assert!((got - want).abs() < 1e-12 * want, "{got} vs {want}");
        // Symmetric in the coverage test: uncovered in a only also leaves the pixel out.
        let (mut a2, mut b2) = (a.clone(), b.clone());
        a2.alpha[3] = 0.99;
        b2.alpha[3] = 1.0;
        let got = mean_delta_e(&a2, &b2).unwrap();
        assert!((got - want).abs() < 1e-12 * want, "{got} vs {want}");
        assert_eq!(mean_delta_e(&a, &a).unwrap(), 0.0);
        // Nothing covered by both.
        let mut none = Image::new(5, 1, grey);
        none.alpha.iter_mut().for_each(|v| *v = 0.99);
        assert!(mean_delta_e(&a, &none).unwrap().is_nan());
        // Images of different sizes are not compared.
        let e = mean_delta_e(&a, &Image::new(4, 1, grey)).unwrap_err();
        assert!(e.to_string().contains("5x1 vs 4x1"), "{e}");
    }
}
