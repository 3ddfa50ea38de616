//! The latent map (the paper's Figs. 4.1 and 4.3): every material as a labelled dot in the
//! first two latent axes over the predictive variance, and optionally a grid of sphere
//! thumbnails of predicted materials across the points' bounding box (marked on the map).

use brdf_io::BrdfSource;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::font;
use crate::image::Image;
use crate::sphere::{SphereOptions, render_spheres};

/// Largest side of a map's plot area and of its thumbnail panel, in pixels (as a sphere's).
pub const MAX_MAP_PIXELS: usize = 8192;
/// Most thumbnails per axis of a map's panel.
pub const MAX_THUMBNAILS: usize = 64;
/// Most variance samples per axis of a map's background ([`MapOptions::variance_samples`]): as
/// many as the largest plot has pixels.
pub const MAX_VARIANCE_SAMPLES: usize = MAX_MAP_PIXELS;

/// How to draw a latent map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapOptions {
    /// Side of the square plot area in pixels (64..=[`MAX_MAP_PIXELS`]).
    pub size: usize,
    /// Thumbnails per axis (0: none; at most [`MAX_THUMBNAILS`], 8..=1024-pixel spheres, a
    /// panel of at most [`MAX_MAP_PIXELS`]).
    pub thumbnails: usize,
    /// Sphere options of the thumbnails (their `size` is the thumbnail size).
    pub sphere: SphereOptions,
    /// Variance samples per axis of the background (bilinearly interpolated; 2..=
    /// [`MAX_VARIANCE_SAMPLES`]).
    pub variance_samples: usize,
    /// A line under the title saying what the shading is (its units; for q > 2 the slice the
    /// map shows); empty: none.
    pub caption: String,
    /// The last `predicted_points` points are predictions, not training materials: drawn as
    /// blue rings instead of red dots.
    pub predicted_points: usize,
    /// The model has one latent axis: the thumbnails are one row along X1 (at the middle of
    /// the grey box), not a square whose rows would repeat the same materials.
    pub one_axis: bool,
    /// A variance (in the units of `latent_map`'s `variance`) above which a thumbnail's point
    /// counts as far from every material: its sphere is framed in orange and a line under the
    /// panel says so (there the prediction is mostly the GP's extrapolation, which in log
    /// space can show colours no material has). `None`: no marking.
    pub far_variance: Option<f64>,
}

impl Default for MapOptions {
    /// A 640-pixel plot, no thumbnails, 48-pixel spheres, 96 x 96 variance samples.
    fn default() -> Self {
        Self {
            size: 640,
            thumbnails: 0,
            sphere: SphereOptions {
                size: 48,
                ..SphereOptions::default()
            },
            variance_samples: 96,
            caption: String::new(),
            predicted_points: 0,
            one_axis: false,
            far_variance: None,
        }
    }
}

/// A latent point with its label.
pub type LabelledPoint = (String, [f64; 2]);

/// The map caption of a model with latent dimension `q` and data transform `transform` (its
/// display form), shaded by the predictive standard deviation per transformed value (the
/// square root of model variance x `data_scale`, the units the reports use; [`latent_map`]
/// shades by the square root of its `variance`): what the colour bar means, and for q > 2
/// that the map is the slice through the origin of the other axes, for q = 1 that the vertical
/// axis is not one of the model's (every material sits at X2 = 0 and nothing varies along it).
pub fn variance_caption(transform: &str, q: usize) -> String {
    let slice = match q {
        0 | 1 => ", ONE LATENT AXIS: X2 IS NOT A MODEL AXIS".to_owned(),
        2 => String::new(),
        3 => ", SLICE X3 = 0".to_owned(),
        _ => format!(", SLICE X3..X{q} = 0"),
    };
    format!("SHADING: PREDICTIVE STD PER TRANSFORMED VALUE, {transform}{slice}")
}

/// Makes a source for a latent point (e.g. a lazily predicted material).
pub type SourceAt<'a> = dyn Fn([f64; 2]) -> Result<Box<dyn BrdfSource + 'a>> + Sync + 'a;

/// The plot extent: the points' bounding box padded by 15 % (at least 0.5, and at least
/// 1e-11 of the largest coordinate's magnitude, so that the padding is not lost to rounding far
/// from the origin and pixels stay apart in floating point), widened to a square (equal scales
/// on both axes), as (x0, x1, y0, y1).
pub fn extent(points: &[LabelledPoint]) -> [f64; 4] {
    let [x0, x1, y0, y1] = bounding_box(points);
    let pad = |a: f64, b: f64| ((b - a) * 0.15).max(0.5).max(1e-11 * a.abs().max(b.abs()));
    let (px, py) = (pad(x0, x1), pad(y0, y1));
    let (mut x0, mut x1, mut y0, mut y1) = (x0 - px, x1 + px, y0 - py, y1 + py);
    // Equal scales on both axes (distances in the latent space are what the kernel sees).
    let half = 0.5 * (x1 - x0).max(y1 - y0);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    (x0, x1, y0, y1) = (cx - half, cx + half, cy - half, cy + half);
    [x0, x1, y0, y1]
}

/// The points' bounding box as (x0, x1, y0, y1).
fn bounding_box(points: &[LabelledPoint]) -> [f64; 4] {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (_, p) in points {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    [x0, x1, y0, y1]
}

/// The region the thumbnails cover: the points' bounding box, widened to at least 0.25 along
/// an axis where they (nearly) coincide, as (x0, x1, y0, y1).
pub fn thumbnail_box(points: &[LabelledPoint]) -> [f64; 4] {
    let [x0, x1, y0, y1] = bounding_box(points);
    let widen = |a: f64, b: f64| {
        let pad = (0.25 - (b - a)).max(0.0) / 2.0;
        (a - pad, b + pad)
    };
    let ((x0, x1), (y0, y1)) = (widen(x0, x1), widen(y0, y1));
    [x0, x1, y0, y1]
}

/// The first column of the plot area of a map of `points` (its top row is 40): the left margin
/// holds the axis name X2 (from column 2) and, at least 4 px after it, the y tick labels
/// (right-aligned 6 px left of the frame), and is at least 40 px wide. (On small maps the name
/// ran into the label beside it, "X2-0.5".)
pub fn plot_left(points: &[LabelledPoint]) -> usize {
    let [.., y0, y1] = extent(points);
    left_of_y_ticks(&nice_ticks(y0, y1, 5))
}

/// [`plot_left`] of a map with the y ticks `ticks`.
fn left_of_y_ticks(ticks: &[(f64, String)]) -> usize {
    let name_end = Y_NAME_X as usize + font::text_width("X2", 1);
    ticks
        .iter()
        .map(|(_, label)| name_end + 4 + font::text_width(label, 1) + 7)
        .fold(MARGIN, usize::max)
}

/// Draws the map: shading by the predictive standard deviation (the square root of `variance`:
/// white = 0, deep blue = the largest sampled; a linear variance scale drew a standard
/// deviation of half the largest, a factor of ~2 in log units, nearly white), training materials as red dots and predictions as blue rings (see
/// [`MapOptions::predicted_points`]) with labels (a training material's label that finds no
/// free spot is left out, and a note under the colour bar counts them; predictions are
/// always labelled), axis ranges, a colour bar, an optional
/// caption; with
/// `opts.thumbnails > 0` and `source_at`, a panel of spheres of the predicted materials on a
/// regular grid over the points' bounding box ([`thumbnail_box`], outlined on the map) to the
/// right.
pub fn latent_map(
    points: &[LabelledPoint],
    variance: &(dyn Fn([f64; 2]) -> Result<f64> + Sync),
    source_at: Option<&SourceAt<'_>>,
    opts: &MapOptions,
) -> Result<Image> {
    if points.is_empty()
        || !(64..=MAX_MAP_PIXELS).contains(&opts.size)
        || !(2..=MAX_VARIANCE_SAMPLES).contains(&opts.variance_samples)
    {
        return Err(Error::InvalidArgument {
            reason: format!(
                "a map needs points, a size in 64..={MAX_MAP_PIXELS} and \
                 2..={MAX_VARIANCE_SAMPLES} variance samples per axis (got {} points, size {}, \
                 {} variance samples)",
                points.len(),
                opts.size,
                opts.variance_samples
            ),
        });
    }
    if opts.thumbnails > 0 && source_at.is_some() {
        let (k, px) = (opts.thumbnails, opts.sphere.size);
        if !(1..=MAX_THUMBNAILS).contains(&k)
            || !(8..=1024).contains(&px)
            || k * px > MAX_MAP_PIXELS
        {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "thumbnails: {k} per axis of {px} px make a panel of {} px; allowed are at \
                     most {MAX_THUMBNAILS} per axis, 8..=1024 px each, a panel of at most \
                     {MAX_MAP_PIXELS} px",
                    k * px
                ),
            });
        }
    }
    if points
        .iter()
        .any(|(_, p)| !p[0].is_finite() || !p[1].is_finite())
    {
        return Err(Error::InvalidArgument {
            reason: "non-finite latent coordinates".into(),
        });
    }
    let [x0, x1, y0, y1] = extent(points);
    if ![x0, x1, y0, y1, x1 - x0, y1 - y0]
        .iter()
        .all(|v| v.is_finite())
    {
        let largest = points
            .iter()
            .flat_map(|(_, p)| p.map(f64::abs))
            .fold(0.0, f64::max);
        return Err(Error::InvalidArgument {
            reason: format!(
                "latent coordinates up to {largest:e} in magnitude are too large to plot (the \
                 map's extent overflows f64)"
            ),
        });
    }
    let size = opts.size;
    let margin = MARGIN;
    let (xt, yt) = (nice_ticks(x0, x1, 5), nice_ticks(y0, y1, 5));
    let left = left_of_y_ticks(&yt);
    let panel_title = if opts.caption.contains("SLICE") {
        "PREDICTED MATERIALS OVER THE GREY BOX, ON THE SLICE"
    } else {
        "PREDICTED MATERIALS OVER THE GREY BOX"
    };
    let with_thumbnails = opts.thumbnails > 0 && source_at.is_some();
    // X2 of each thumbnail row, top (largest) first, for the panel's right margin.
    let row_labels = if with_thumbnails && !opts.one_axis {
        let [_, _, by0, by1] = thumbnail_box(points);
        let mut labels = cell_centre_labels(by0, by1, opts.thumbnails);
        labels.reverse();
        labels
    } else {
        Vec::new()
    };
    let row_label_room = row_labels
        .iter()
        .map(|label| font::text_width(label, 1) + 8)
        .max()
        .unwrap_or(0);
    // The panel is as wide as its spheres, or as its title where that is wider (small
    // thumbnails used to cut the title to a word), plus a margin that holds the row labels.
    let panel = if with_thumbnails {
        (opts.thumbnails * opts.sphere.size).max(font::text_width(panel_title, 1))
            + margin.max(row_label_room)
    } else {
        0
    };
    let width = left + size + margin + panel;
    // Tall enough for the thumbnails too (a small plot cut them off at its own height).
    let thumb_rows = if opts.one_axis { 1 } else { opts.thumbnails };
    let panel_height = if panel > 0 {
        margin + thumb_rows * opts.sphere.size + margin
    } else {
        0
    };
    let height = (margin + size + margin + 32).max(panel_height);
    let mut img = Image::new(width, height, [1.0; 3]);
    // Variance on a coarse grid.
    let m = opts.variance_samples;
    let at = |i: usize, j: usize| {
        [
            x0 + (x1 - x0) * i as f64 / (m - 1) as f64,
            y1 - (y1 - y0) * j as f64 / (m - 1) as f64,
        ]
    };
    let grid: Vec<f64> = (0..m * m)
        .into_par_iter()
        .map(|k| checked_variance(variance, at(k % m, k / m)))
        .collect::<Result<_>>()?;
    let vmax = grid.iter().copied().fold(0.0, f64::max).max(1e-300);
    let shade = |t: f64| {
        let t = t.clamp(0.0, 1.0);
        // White -> deep blue (linear).
        [1.0 - 0.95 * t, 1.0 - 0.85 * t, 1.0 - 0.45 * t]
    };
    // Each pixel is shaded by the variance at its centre, in the coordinates `to_px` draws the
    // dots in (sampling pixel corners, from x0 at the first to x1 at the last, stretched the
    // shading by size / (size - 1) against the dots, up to half a pixel at the edges).
    for py in 0..size {
        for px in 0..size {
            let u = (px as f64 + 0.5) / size as f64 * (m - 1) as f64;
            let v = (py as f64 + 0.5) / size as f64 * (m - 1) as f64;
            let (i, j) = ((u as usize).min(m - 2), (v as usize).min(m - 2));
            let (fu, fv) = (u - i as f64, v - j as f64);
            let g = |a: usize, b: usize| grid[b * m + a];
            let val = (1.0 - fv) * ((1.0 - fu) * g(i, j) + fu * g(i + 1, j))
                + fv * ((1.0 - fu) * g(i, j + 1) + fu * g(i + 1, j + 1));
            img.set(
                (left + px) as i64,
                (margin + py) as i64,
                shade((val.max(0.0) / vmax).sqrt()),
            );
        }
    }
    let to_px = |p: [f64; 2]| {
        (
            left as f64 + (p[0] - x0) / (x1 - x0) * size as f64,
            margin as f64 + (y1 - p[1]) / (y1 - y0) * size as f64,
        )
    };
    // Frame and axis ranges.
    let black = [0.0; 3];
    let (l, t, b) = (left as i64 - 1, margin as i64 - 1, (margin + size) as i64);
    img.outline_rect(l, t, size + 2, size + 2, black);
    // Ticks at round coordinates (so a point can be read off the map, e.g. for
    // `render MODEL.toml@X1,X2,...`), with faint grid lines across the plot.
    // A label that would run into the previous one or off the image is left out (its tick
    // and grid line stay).
    let mut x_labels: Vec<(i64, i64)> = Vec::new();
    for (v, label) in &xt {
        let px = to_px([*v, y0]).0.round() as i64;
        img.blend_rect(px, t + 1, 1, size, [0.0; 3], 0.12);
        img.fill_rect(px, b + 1, 1, 4, black);
        let w = font::text_width(label, 1) as i64;
        let (a, z) = (px - w / 2, px - w / 2 + w);
        if a < 0 || z > width as i64 || x_labels.last().is_some_and(|&(_, prev)| a < prev + 6) {
            continue;
        }
        img.text(a, b + 7, label, 1, black);
        x_labels.push((a, px + w / 2));
    }
    let mut y_labels = Vec::new();
    for (v, label) in &yt {
        let py = to_px([x0, *v]).1.round() as i64;
        img.blend_rect(l + 1, py, size, 1, [0.0; 3], 0.12);
        img.fill_rect(l - 4, py, 4, 1, black);
        let w = font::text_width(label, 1) as i64;
        img.text(l - 6 - w, py - 3, label, 1, black);
        y_labels.push(py);
    }
    // Axis names midway between tick labels (or beside them when one sits at the middle).
    let mid_x = l + (size / 2) as i64;
    let x_name = if x_labels
        .iter()
        .any(|&(a, z)| a - 14 < mid_x && mid_x < z + 4)
    {
        x_labels
            .iter()
            .map(|&(_, z)| z + 6)
            .find(|&z| z > mid_x)
            .unwrap_or(mid_x)
    } else {
        mid_x - 6
    };
    img.text(x_name, b + 18, "X1", 1, black);
    // X2 centred on the y axis, or on the nearest row of the plot at least 2 px clear of every
    // y tick label (a name on a label's rows reads as part of it); where the labels leave no
    // such row (ticks under 18 px apart), centred.
    let centred = t + (size / 2) as i64 - 3;
    let glyph_h = font::GLYPH_H as i64;
    let clear = |r: i64| (y_labels.iter()).all(|&py| r + glyph_h + 2 <= py - 3 || py + 3 + 2 < r);
    let y_name = (0..size as i64)
        .flat_map(|k| [centred + k, centred - k])
        .find(|&r| t < r && r + glyph_h <= b && clear(r))
        .unwrap_or(centred);
    img.text(Y_NAME_X, y_name, "X2", 1, black);
    // The title and the colour bar end 8 px before the thumbnail panel (or 4 px before the
    // image's edge without one) on small maps, where they ran into it and off the image.
    let right_edge = if panel > 0 {
        left + size + margin - 8
    } else {
        width - 4
    };
    let text_room = right_edge.saturating_sub(l as usize);
    const TITLES: [&str; 3] = [
        "LATENT SPACE, SHADED BY PREDICTIVE STANDARD DEVIATION",
        "LATENT SPACE, SHADED BY PREDICTIVE STD",
        "LATENT SPACE",
    ];
    img.text(
        l,
        8,
        first_fitting(TITLES, text_room).unwrap_or(""),
        1,
        black,
    );
    if !opts.caption.is_empty() {
        let caption = font::fit(&opts.caption, width.saturating_sub(l as usize + 4), 1);
        img.text(l, 20, &caption, 1, NOTE_GREY);
    }
    // Colour bar: "0", a 120-pixel ramp and the largest standard deviation, from 130 px right
    // of the frame's corner; on a map too narrow for that, from the corner with a shorter
    // ramp (it ran off the image, and with thumbnails under their panel, which hid it).
    let bar_y = b + 34;
    let top = format!("{:.3}", vmax.sqrt());
    let room = right_edge as i64 - font::text_width(&top, 1) as i64 - 10;
    let (zero_x, bar_x, bar_len) = if l + 280 <= room {
        (l + 130, l + 160, 120)
    } else {
        (l, l + 10, (room - l - 10).clamp(8, 120))
    };
    for i in 0..bar_len {
        let t = i as f64 / (bar_len - 1) as f64;
        img.fill_rect(bar_x + i, bar_y, 1, 8, shade(t));
    }
    img.text(zero_x, bar_y, "0", 1, black);
    img.text(bar_x + bar_len + 10, bar_y, &top, 1, black);
    // The thumbnails' region, outlined 6 px outside the points' box (so the line passes no dot
    // at the box's edge), drawn before the labels so that none is struck through.
    let thumbs_box = (source_at.is_some() && panel > 0).then(|| thumbnail_box(points));
    if let Some([bx0, bx1, by0, by1]) = thumbs_box {
        let (px0, py0) = to_px([bx0, by1]);
        let (px1, py1) = to_px([bx1, by0]);
        // The pixels of the corners, then the rectangle through them (widths taken from the
        // unrounded corners left a corner open where the edges fell at different fractions).
        let [c0, r0, c1, r1] =
            [px0 - 6.0, py0 - 6.0, px1 + 6.0, py1 + 6.0].map(|v| v.floor() as i64);
        let (w, h) = ((c1 - c0 + 1) as usize, (r1 - r0 + 1) as usize);
        img.outline_rect(c0, r0, w, h, [0.35; 3]);
    }
    // Dots and labels: each label beside its dot where there is room, else on a ring further
    // out with a leader line; none covers another label or a dot.
    let dots: Vec<(f64, f64)> = points.iter().map(|(_, p)| to_px(*p)).collect();
    let widths: Vec<usize> = points
        .iter()
        .map(|(name, _)| font::text_width(name, 1))
        .collect();
    let plot = Rect {
        x0: left as i64,
        y0: margin as i64,
        x1: (left + size) as i64,
        y1: (margin + size) as i64,
    };
    let first_predicted = dots.len().saturating_sub(opts.predicted_points);
    let spots = place_labels(&dots, &widths, plot, first_predicted);
    for ((cx, cy), (spot, w)) in dots.iter().zip(spots.iter().zip(&widths)) {
        if let Some(spot) = spot.filter(|s| s.leader) {
            let (tx, ty) = spot.label_box(*w).nearest_point(*cx, *cy);
            img.line(*cx, *cy, tx, ty, [0.25; 3], 0.8);
        }
    }
    for (k, (cx, cy)) in dots.iter().enumerate() {
        img.disc(*cx, *cy, 4.5, [1.0; 3]);
        if k < first_predicted {
            img.disc(*cx, *cy, 3.0, [0.8, 0.05, 0.02]);
        } else {
            img.disc(*cx, *cy, 4.0, [0.05, 0.25, 0.85]);
            img.disc(*cx, *cy, 2.0, [1.0; 3]);
        }
    }
    for (((name, _), spot), w) in points.iter().zip(&spots).zip(&widths) {
        let Some(spot) = spot else { continue };
        let b = spot.label_box(*w);
        let (bw, bh) = ((b.x1 - b.x0) as usize, (b.y1 - b.y0) as usize);
        img.blend_rect(b.x0, b.y0, bw, bh, [1.0; 3], 0.6);
        img.text(spot.x, spot.y, name, 1, black);
    }
    // Say how many labels had no room (under the colour bar).
    let left_out = spots.iter().filter(|s| s.is_none()).count();
    if left_out > 0 {
        let full = format!("{left_out} OF {first_predicted} LABELS LEFT OUT");
        let note = first_fitting([format!("{full}: NO ROOM AT THIS SIZE"), full], text_room)
            .unwrap_or_else(|| format!("{left_out} LEFT OUT"));
        img.text(l, b + 50, &note, 1, NOTE_GREY);
    }
    // Thumbnails over the points' bounding box (drawn on the map), not the whole square plot:
    // the square's empty margins are far from every material, where the GP's extrapolation
    // shows colours no material has (a walkthrough took them for the model's predictions).
    if let (Some(f), Some([bx0, bx1, by0, by1])) = (source_at, thumbs_box) {
        let (g, rows) = (opts.thumbnails, thumb_rows);
        let ts = opts.sphere.size;
        let ox = (left + size + margin) as i64;
        let cells: Vec<(usize, usize)> = (0..g * rows).map(|k| (k % g, k / g)).collect();
        let points_of_cells: Vec<[f64; 2]> = cells
            .iter()
            .map(|&(i, j)| {
                [
                    bx0 + (bx1 - bx0) * (i as f64 + 0.5) / g as f64,
                    by1 - (by1 - by0) * (j as f64 + 0.5) / rows as f64,
                ]
            })
            .collect();
        // A failure names the thumbnail's latent point (a NaN in a predicted material said
        // which cell and channel, but not where on the map).
        let at = |p: [f64; 2]| {
            move |e| Error::Thumbnail {
                point: p,
                cause: Box::new(e),
            }
        };
        let sources: Vec<Box<dyn BrdfSource + '_>> = points_of_cells
            .iter()
            .map(|&p| f(p).map_err(at(p)))
            .collect::<Result<_>>()?;
        // Rendered together: predictions of one model read each cell once for all of them.
        let sources: Vec<&dyn BrdfSource> = sources.iter().map(|s| s.as_ref()).collect();
        let thumbs: Vec<Image> = render_spheres(&sources, &opts.sphere)
            .into_iter()
            .zip(&points_of_cells)
            .map(|(thumb, &p)| thumb.map_err(at(p)))
            .collect::<Result<_>>()?;
        let bg = Image::new(g * ts, rows * ts, [0.02; 3]);
        img.blit(&bg, ox, margin as i64);
        for ((i, j), th) in cells.iter().zip(&thumbs) {
            img.blit(th, ox + (i * ts) as i64, (margin + j * ts) as i64);
        }
        img.text(ox, 8, panel_title, 1, black);
        // The latent coordinates of the spheres (to type as `render MODEL.toml@X1,X2,...`):
        // X1 of each column above the panel, X2 of each row right of it; a label that would
        // run into the previous one or off the image is left out.
        let label_y = margin as i64 - 9;
        let mut end = ox - 18;
        img.text(end, label_y, "X1", 1, black);
        end += font::text_width("X1", 1) as i64;
        for (i, label) in cell_centre_labels(bx0, bx1, g).iter().enumerate() {
            let w = font::text_width(label, 1) as i64;
            let a = ox + (i * ts + ts / 2) as i64 - w / 2;
            if a >= end + 6 && a + w <= width as i64 - 2 {
                img.text(a, label_y, label, 1, black);
                end = a + w;
            }
        }
        if !row_labels.is_empty() {
            let x = ox + (g * ts) as i64 + 4;
            if end + 6 <= x {
                img.text(x, label_y, "X2", 1, black);
            }
            // Every row's label where rows are at least 10 px apart, else every k-th row.
            let every = 10usize.div_ceil(ts);
            for (j, label) in row_labels.iter().enumerate().step_by(every) {
                img.text(x, (margin + j * ts + ts / 2) as i64 - 3, label, 1, black);
            }
        }
        if let Some(limit) = opts.far_variance {
            let orange = [1.0, 0.45, 0.0];
            let mut far = 0;
            for ((i, j), p) in cells.iter().zip(&points_of_cells) {
                if checked_variance(variance, *p)? > limit {
                    far += 1;
                    // Two pixels wide, inside the thumbnail.
                    let (x, y) = (ox + (i * ts) as i64, (margin + j * ts) as i64);
                    img.outline_rect(x, y, ts, ts, orange);
                    img.outline_rect(x + 1, y + 1, ts - 2, ts - 2, orange);
                }
            }
            if far > 0 {
                let y = (margin + rows * ts + 8) as i64;
                let room = panel - margin;
                let note = first_fitting(
                    [
                        format!("ORANGE: {far} FAR FROM EVERY MATERIAL (EXTRAPOLATED)"),
                        format!("ORANGE: {far} FAR FROM EVERY MATERIAL"),
                        format!("ORANGE: {far} FAR"),
                    ],
                    room,
                );
                if let Some(note) = note {
                    img.text(ox, y, &note, 1, NOTE_GREY);
                }
            }
        }
    }
    Ok(img)
}

/// `variance` at latent point `p`, which must not be NaN or infinite: a NaN sample drew white
/// (no uncertainty), an infinite one scaled every other sample to white and labelled the
/// colour bar `inf`, without a word. Negative values (rounding below 0) are clamped where drawn.
fn checked_variance(
    variance: &(dyn Fn([f64; 2]) -> Result<f64> + Sync),
    p: [f64; 2],
) -> Result<f64> {
    let v = variance(p)?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::InvalidArgument {
            reason: format!(
                "the predictive variance at latent point ({}, {}) is {v}: a map needs finite \
                 variances",
                p[0], p[1]
            ),
        })
    }
}

/// The first of `texts` (longest first) whose width fits `room` pixels: titles and notes
/// shortened at a word (a cut mid-word, "... SHADED BY PRE", read on into the thumbnail
/// panel's title beside it).
fn first_fitting<S: AsRef<str>>(texts: impl IntoIterator<Item = S>, room: usize) -> Option<S> {
    texts
        .into_iter()
        .find(|t| font::text_width(t.as_ref(), 1) <= room)
}

/// Round tick values in `[lo, hi]`: multiples of 1, 2 or 5 times a power of ten, the smallest
/// such step that gives at most 1.5 `target` ticks, each with its label (as many decimals as
/// the step needs; "0" for zero; with an exponent, as `2.5E6` or `-1E100`, when the step is
/// 1e5 or more, where plain digits ran to a hundred characters across the map).
pub fn nice_ticks(lo: f64, hi: f64, target: usize) -> Vec<(f64, String)> {
    // (A range wider than the largest f64, -1e308..1e308, gave one tick at 0 x inf = NaN.)
    if !(lo.is_finite() && hi.is_finite() && hi > lo && (hi - lo).is_finite()) {
        return Vec::new();
    }
    let raw = (hi - lo) / target.max(1) as f64;
    let exponent = raw.log10().floor() as i32;
    let power = 10f64.powi(exponent);
    let (mult, step) = [1i64, 2, 5, 10]
        .iter()
        .map(|&m| (m, m as f64 * power))
        .find(|(_, s)| (hi - lo) / s <= 1.5 * target.max(1) as f64)
        .unwrap_or((10, 10.0 * power));
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last)
        .map(|k| {
            let v = k as f64 * step;
            let label = if k == 0 {
                "0".to_owned()
            } else if step >= 1e5 {
                exponent_label(k.saturating_mul(mult), exponent)
            } else {
                format!("{v:.decimals$}")
            };
            (v, label)
        })
        .collect()
}

/// Labels of the centres of `n` equal cells across `[lo, hi]`, with two significant digits
/// of the cell width (`-1, 1, 4` -> `-0.75 -0.25 0.25 0.75`); in exponent form (`1.2E5`)
/// where plain digits would run long (values of 1e5 or more, or cells under 1e-4).
pub fn cell_centre_labels(lo: f64, hi: f64, n: usize) -> Vec<String> {
    let step = (hi - lo) / n.max(1) as f64;
    let largest = lo.abs().max(hi.abs());
    (0..n)
        .map(|i| {
            let v = lo + step * (i as f64 + 0.5);
            if step.is_nan() || step <= 0.0 || !v.is_finite() {
                format!("{v}")
            } else if largest >= 1e5 || step < 1e-4 {
                let digits = (1.0 + largest.log10().floor() - step.log10().floor()).clamp(1.0, 8.0);
                format!("{v:.*E}", digits as usize)
            } else {
                let decimals = (1.0 - step.log10().floor()).max(0.0) as usize;
                let label = format!("{v:.decimals$}");
                // No "-0.00" for a centre that rounds to zero.
                if label.trim_start_matches(['-', '0', '.']).is_empty() {
                    label.trim_start_matches('-').to_owned()
                } else {
                    label
                }
            }
        })
        .collect()
}

/// `n x 10^e` written as `D.DDDE±X` with no trailing zeros (`15, 99` -> `1.5E100`).
fn exponent_label(n: i64, e: i32) -> String {
    let sign = if n < 0 { "-" } else { "" };
    let digits = n.unsigned_abs().to_string();
    let kept = digits.trim_end_matches('0');
    let e = e as i64 + digits.len() as i64 - 1;
    let (head, tail) = kept.split_at(1);
    if tail.is_empty() {
        format!("{sign}{head}E{e}")
    } else {
        format!("{sign}{head}.{tail}E{e}")
    }
}

/// A pixel rectangle `[x0, x1) x [y0, y1)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Rect {
    x0: i64,
    y0: i64,
    x1: i64,
    y1: i64,
}

impl Rect {
    /// The square a dot at (x, y) keeps free of labels ([`DOT_CLEARANCE`]).
    fn around_dot(x: f64, y: f64) -> Self {
        Self {
            x0: (x - DOT_CLEARANCE).floor() as i64,
            y0: (y - DOT_CLEARANCE).floor() as i64,
            x1: (x + DOT_CLEARANCE).ceil() as i64,
            y1: (y + DOT_CLEARANCE).ceil() as i64,
        }
    }

    /// Area of the intersection with `o` (0 when they do not meet).
    fn overlap(&self, o: &Rect) -> i64 {
        let w = self.x1.min(o.x1) - self.x0.max(o.x0);
        let h = self.y1.min(o.y1) - self.y0.max(o.y0);
        if w > 0 && h > 0 { w * h } else { 0 }
    }

    /// Whether the rectangle lies inside `o`.
    fn inside(&self, o: &Rect) -> bool {
        self.x0 >= o.x0 && self.y0 >= o.y0 && self.x1 <= o.x1 && self.y1 <= o.y1
    }

    /// The point of the rectangle nearest to (x, y).
    fn nearest_point(&self, x: f64, y: f64) -> (f64, f64) {
        (
            x.clamp(self.x0 as f64, self.x1 as f64),
            y.clamp(self.y0 as f64, self.y1 as f64),
        )
    }
}

/// Where a label's text goes (its top-left corner) and whether it sits away from its dot
/// (then a leader line joins them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct LabelSpot {
    x: i64,
    y: i64,
    leader: bool,
}

impl LabelSpot {
    /// The box a label of `width` text pixels occupies here: the text plus a 1-pixel border.
    fn label_box(&self, width: usize) -> Rect {
        Rect {
            x0: self.x - 1,
            y0: self.y - 1,
            x1: self.x + width as i64 + 1,
            y1: self.y + font::GLYPH_H as i64 + 1,
        }
    }
}

/// Column where the y axis name (X2) starts, at the image's left edge.
const Y_NAME_X: i64 = 2;

/// The map's margins around the plot (above, right and below it; the left one is at least
/// as wide), in pixels.
const MARGIN: usize = 40;

/// Linear RGB of the map's secondary text (the caption and the notes): a dark grey, 89 of 255
/// in sRGB (0.3, 149 of 255, was hard to read on white).
const NOTE_GREY: [f64; 3] = [0.1; 3];

/// Half the side of the square a dot keeps free of labels, in pixels.
const DOT_CLEARANCE: f64 = 5.5;

/// A leader line: from a dot's centre to the nearest point of its label's box.
#[derive(Debug, Clone, Copy)]
struct Leader {
    from: (f64, f64),
    to: (f64, f64),
}

impl Leader {
    /// The line from the dot at `dot` to the box `label` (as drawn).
    fn new(dot: (f64, f64), label: &Rect) -> Self {
        Self {
            from: dot,
            to: label.nearest_point(dot.0, dot.1),
        }
    }

    /// Whether the two lines cross (touching at an end does not count).
    fn crosses(&self, o: &Leader) -> bool {
        // -1 or 1: the side of the line through a and b that c lies on; 0: on the line.
        // (`f64::signum` is 1 for 0: a line ending on the other crossed it from one side.)
        let side = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| {
            let v = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
            i8::from(v > 0.0) - i8::from(v < 0.0)
        };
        let (p, q, r, t) = (self.from, self.to, o.from, o.to);
        side(p, q, r) * side(p, q, t) < 0 && side(r, t, p) * side(r, t, q) < 0
    }

    /// Whether the line passes through the open box `[x0, x1] x [y0, y1]` (Liang-Barsky
    /// clipping; a line along an edge does not count).
    fn meets(&self, [x0, y0, x1, y1]: [f64; 4]) -> bool {
        let (dx, dy) = (self.to.0 - self.from.0, self.to.1 - self.from.1);
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for (p, q) in [
            (-dx, self.from.0 - x0),
            (dx, x1 - self.from.0),
            (-dy, self.from.1 - y0),
            (dy, y1 - self.from.1),
        ] {
            if p == 0.0 {
                if q <= 0.0 {
                    return false;
                }
            } else if p < 0.0 {
                lo = lo.max(q / p);
            } else {
                hi = hi.min(q / p);
            }
        }
        lo < hi
    }

    /// Whether the line passes through the box `r`.
    fn meets_rect(&self, r: &Rect) -> bool {
        self.meets([r.x0 as f64, r.y0 as f64, r.x1 as f64, r.y1 as f64])
    }
}

/// Radius of a drawn dot (its white ring), which leader lines of other dots avoid.
const DOT_RADIUS: f64 = 4.5;

/// Places one label per dot (`widths[i]`: the text width of dot i's label), deterministically.
///
/// Labels of dots with more neighbours go first, and each takes the best of its candidate
/// spots: beside its dot (right, left, above, below, then the four corners), then on rings of
/// growing radius around it (16 directions each; drawn with a leader line), then those ring
/// spots moved into `bounds`. Best means free (inside `bounds`, over no dot's clearance square
/// and no other label), then with the fewest tangles (leader lines crossing, a leader line
/// through another label or dot, a label over a leader line). Then
/// [`REFINE_ROUNDS`] rounds move each tangled or covered label to its best spot given all the
/// others (a label placed early cannot see the ones placed after it), a free one only to a
/// free spot.
///
/// A label with no free spot is left out (`None`: drawn over dots and other labels it hid them
/// and was unreadable itself), except the labels of dots `always..` (predictions and located
/// materials, which the user asked about): they take the spot that leaves the bounds least (a
/// label wider than them starts at their left edge), then overlaps least.
fn place_labels(
    dots: &[(f64, f64)],
    widths: &[usize],
    bounds: Rect,
    always: usize,
) -> Vec<Option<LabelSpot>> {
    let order = placing_order(dots);
    let mut layout = Layout {
        dots,
        widths,
        bounds,
        dot_boxes: dots.iter().map(|&(x, y)| Rect::around_dot(x, y)).collect(),
        labels: vec![None; dots.len()],
    };
    for &i in &order {
        let (key, spot) = layout.best_spot(i);
        if key.0 == 0 || i >= always {
            layout.labels[i] = Some(spot);
        }
    }
    for _ in 0..REFINE_ROUNDS {
        let mut moved = false;
        for &i in &order {
            let Some(now) = layout.labels[i] else {
                continue;
            };
            layout.labels[i] = None;
            let current = layout.score(i, &now);
            let (key, spot) = layout.best_spot(i);
            // Free labels stay free; one covered by a label placed after it (a prediction's)
            // may move.
            if current != (0, 0) && key < current && (key.0 == 0 || i >= always) {
                layout.labels[i] = Some(spot);
                moved = true;
            } else {
                layout.labels[i] = Some(now);
            }
        }
        if !moved {
            break;
        }
    }
    layout.labels
}

/// The order [`place_labels`] labels `dots` in: those with more dots (themselves included)
/// under 48 px away first, in index order among equals.
fn placing_order(dots: &[(f64, f64)]) -> Vec<usize> {
    let crowd = |i: usize| {
        let (x, y) = dots[i];
        dots.iter()
            .filter(|&&(u, v)| (u - x).hypot(v - y) < 48.0)
            .count()
    };
    let mut order: Vec<usize> = (0..dots.len()).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(crowd(i)), i));
    order
}

/// How many times [`place_labels`] revisits the tangled labels.
const REFINE_ROUNDS: usize = 3;

/// Labels placed so far, and what they must avoid.
struct Layout<'a> {
    dots: &'a [(f64, f64)],
    widths: &'a [usize],
    bounds: Rect,
    dot_boxes: Vec<Rect>,
    labels: Vec<Option<LabelSpot>>,
}

impl Layout<'_> {
    /// The placed labels' boxes and leader lines, but dot `i`'s.
    fn others(&self, i: usize) -> Vec<(Rect, Option<Leader>)> {
        (self.labels.iter().enumerate())
            .filter(|&(k, _)| k != i)
            .filter_map(|(k, s)| {
                let s = (*s)?;
                let b = s.label_box(self.widths[k]);
                Some((b, s.leader.then(|| Leader::new(self.dots[k], &b))))
            })
            .collect()
    }

    /// Dot `i`'s label at `s`: (overlap cost, tangles).
    fn score(&self, i: usize, s: &LabelSpot) -> (i64, usize) {
        let others = self.others(i);
        let cost = self.cost(i, s, &others);
        (cost, self.tangles(i, s, &others))
    }

    /// The overlap cost of dot `i`'s label at `s` among `others`. Every pixel outside the
    /// bounds costs more than any overlap with dots and labels, one left of them twice as much
    /// (there are the y tick labels; right of the plot is a margin).
    fn cost(&self, i: usize, s: &LabelSpot, others: &[(Rect, Option<Leader>)]) -> i64 {
        let b = s.label_box(self.widths[i]);
        let out = if b.inside(&self.bounds) {
            0
        } else {
            let left = (self.bounds.x0 - b.x0).max(0) * (b.y1 - b.y0);
            ((b.x1 - b.x0) * (b.y1 - b.y0) - b.overlap(&self.bounds) + left) << 24
        };
        out + self.dot_boxes.iter().map(|d| b.overlap(d)).sum::<i64>()
            + others.iter().map(|(o, _)| b.overlap(o)).sum::<i64>()
    }

    /// The tangles of dot `i`'s label at `s` among `others`: its leader line crossing theirs
    /// or passing through their labels or (counted 3 times) other dots, its box over their
    /// leader lines.
    fn tangles(&self, i: usize, s: &LabelSpot, others: &[(Rect, Option<Leader>)]) -> usize {
        let b = s.label_box(self.widths[i]);
        let line = s.leader.then(|| Leader::new(self.dots[i], &b));
        let mut tangles = 0;
        for (o, l) in others {
            if let Some(l) = l {
                tangles += usize::from(l.meets_rect(&b));
                tangles += usize::from(line.is_some_and(|m| m.crosses(l)));
            }
            tangles += usize::from(line.is_some_and(|m| m.meets_rect(o)));
        }
        if let Some(line) = line {
            let r = DOT_RADIUS;
            tangles += 3
                * (self.dots.iter().enumerate())
                    .filter(|&(k, &(x, y))| k != i && line.meets([x - r, y - r, x + r, y + r]))
                    .count();
        }
        tangles
    }

    /// Dot `i`'s best spot given the other labels placed, with its score.
    fn best_spot(&self, i: usize) -> ((i64, usize), LabelSpot) {
        const RINGS: [f64; 7] = [16.0, 26.0, 38.0, 52.0, 68.0, 88.0, 112.0];
        const DIRECTIONS: usize = 16;
        let h = font::GLYPH_H as i64;
        let (cx, cy) = self.dots[i];
        let (x, y, w) = (cx.round() as i64, cy.round() as i64, self.widths[i] as i64);
        let beside = [
            (x + 7, y - h / 2),
            (x - 7 - w, y - h / 2),
            (x - w / 2, y - 7 - h),
            (x - w / 2, y + 7),
            (x + 7, y - 7 - h),
            (x + 7, y + 7),
            (x - 7 - w, y - 7 - h),
            (x - 7 - w, y + 7),
        ]
        .map(|(x, y)| LabelSpot {
            x,
            y,
            leader: false,
        });
        let rings = RINGS.iter().flat_map(|&r| {
            (0..DIRECTIONS).map(move |k| {
                let a = std::f64::consts::TAU * k as f64 / DIRECTIONS as f64;
                let (ax, ay) = (cx + r * a.cos(), cy + r * a.sin());
                // The box's side nearest the dot faces it.
                let left = if a.cos() >= 0.0 { ax } else { ax - w as f64 };
                LabelSpot {
                    x: left.round() as i64,
                    y: (ay - h as f64 / 2.0).round() as i64,
                    leader: true,
                }
            })
        });
        // The ring spots moved into the bounds (a label that finds no free spot takes the one
        // it overlaps least: on a small map, with the spots above alone, that was often one
        // far outside the plot, over the tick labels, under the thumbnail panel or off the
        // image).
        let bounds = self.bounds;
        let inside = move |s: LabelSpot| LabelSpot {
            x: s.x.min(bounds.x1 - 1 - w).max(bounds.x0 + 1),
            y: s.y.min(bounds.y1 - 1 - h).max(bounds.y0 + 1),
            leader: true,
        };
        let moved = rings.clone().map(inside);
        let others = self.others(i);
        let mut best = ((i64::MAX, usize::MAX), beside[0]);
        for s in beside.into_iter().chain(rings).chain(moved) {
            let cost = self.cost(i, &s, &others);
            if cost > best.0.0 {
                continue;
            }
            let key = (cost, self.tangles(i, &s, &others));
            if key < best.0 {
                best = (key, s);
            }
            if key == (0, 0) {
                break;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_centre_labels_tell_the_cells_apart() {
        assert_eq!(
            cell_centre_labels(-1.0, 1.0, 4),
            ["-0.75", "-0.25", "0.25", "0.75"]
        );
        // The default map's box: cells 0.44 wide get two decimals.
        assert_eq!(
            cell_centre_labels(-1.4, 1.24, 6),
            ["-1.18", "-0.74", "-0.30", "0.14", "0.58", "1.02"]
        );
        assert_eq!(cell_centre_labels(-1.0, 1.0, 3), ["-0.67", "0.00", "0.67"]);
        assert_eq!(cell_centre_labels(-0.3, 0.3, 1), ["0.00"]);
        assert_eq!(cell_centre_labels(0.0, 3e6, 3), ["5.0E5", "1.5E6", "2.5E6"]);
        assert_eq!(
            cell_centre_labels(1.0, 1.0 + 3e-6, 3),
            ["1.00000050E0", "1.00000150E0", "1.00000250E0"]
        );
        // Cells of exactly 1e-4 (4e-4 / 4 is exact) are still plain: five decimals.
        assert_eq!(
            cell_centre_labels(0.0, 4e-4, 4),
            ["0.00005", "0.00015", "0.00025", "0.00035"]
        );
        // Degenerate boxes (no width, reversed, NaN) print the centres as they are.
        assert_eq!(cell_centre_labels(1.0, 1.0, 3), ["1", "1", "1"]);
        assert_eq!(cell_centre_labels(2.0, 1.0, 2), ["1.75", "1.25"]);
        assert_eq!(cell_centre_labels(f64::NAN, 1.0, 1), ["NaN"]);
        for labels in [
            cell_centre_labels(-1e-300, 1e-300, 5),
            cell_centre_labels(123.0, 456.0, 7),
            cell_centre_labels(-2e5, -1e5, 10),
        ] {
            let mut unique = labels.clone();
            unique.dedup();
            assert_eq!(unique.len(), labels.len(), "{labels:?}");
        }
    }

    #[test]
    fn ticks_are_round_and_inside_the_range() {
        let labels = |t: Vec<(f64, String)>| t.into_iter().map(|(_, l)| l).collect::<Vec<_>>();
        assert_eq!(
            labels(nice_ticks(-1.82, 1.78, 5)),
            ["-1.5", "-1.0", "-0.5", "0", "0.5", "1.0", "1.5"]
        );
        assert_eq!(
            labels(nice_ticks(0.0, 10.0, 5)),
            ["0", "2", "4", "6", "8", "10"]
        );
        assert_eq!(
            labels(nice_ticks(-0.031, 0.029, 5)),
            ["-0.03", "-0.02", "-0.01", "0", "0.01", "0.02"]
        );
        assert_eq!(labels(nice_ticks(120.0, 480.0, 4)), ["200", "300", "400"]);
        for (lo, hi) in [(-3.7, 2.2), (0.001, 0.0093), (-250.0, 9.0), (5.0, 5.4)] {
            let t = nice_ticks(lo, hi, 5);
            assert!((2..=10).contains(&t.len()), "{lo}..{hi}: {t:?}");
            assert!(t.iter().all(|(v, _)| *v >= lo - 1e-12 && *v <= hi + 1e-12));
        }
        // Steps of 1e5 and more are written with an exponent (plain digits ran to a hundred
        // characters for points near the model files' 1e100 bound).
        assert_eq!(
            labels(nice_ticks(-1.0, 1.0e6, 5)),
            ["0", "2E5", "4E5", "6E5", "8E5", "1E6"]
        );
        assert_eq!(
            labels(nice_ticks(-1.3e100, 1.3e100, 5)),
            ["-1E100", "-5E99", "0", "5E99", "1E100"]
        );
        assert_eq!(
            labels(nice_ticks(2.35e7, 2.95e7, 3)),
            ["2.4E7", "2.6E7", "2.8E7"]
        );
        assert_eq!(
            labels(nice_ticks(9000.0, 41000.0, 4)),
            ["10000", "20000", "30000", "40000"]
        );
        assert!(nice_ticks(1.0, 1.0, 5).is_empty());
        assert!(nice_ticks(f64::NAN, 1.0, 5).is_empty());
    }

    /// The extent pads each axis of the bounding box by 15 % (at least 0.5) and widens the
    /// narrower axis about its centre to a square; the thumbnail box widens only an axis
    /// narrower than 0.25, to 0.25 about its centre. Values by hand; 1e-12 covers rounding.
    #[test]
    fn extents_pad_and_square_and_thumbnail_boxes_widen_thin_axes() {
        let near = |got: [f64; 4], want: [f64; 4]| {
            assert!(
                got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-12),
                "{got:?} vs {want:?}"
            );
        };
        let points = |a: [f64; 2], b: [f64; 2]| vec![("A".to_owned(), a), ("B".to_owned(), b)];
        // x: [-1, 1] and y: [0, 2], both padded by 0.5 (15 % is 0.3): x [-1.5, 1.5], y
        // [-0.5, 2.5], already square.
        near(
            extent(&points([-1.0, 0.0], [1.0, 2.0])),
            [-1.5, 1.5, -0.5, 2.5],
        );
        // x: [2, 6] padded by 0.6 to [1.4, 6.6]; y: [1, 3] padded by 0.5 to [0.5, 3.5], then
        // widened to x's 5.2 about its centre 2; and the same with the axes swapped.
        near(
            extent(&points([2.0, 1.0], [6.0, 3.0])),
            [1.4, 6.6, -0.6, 4.6],
        );
        near(
            extent(&points([1.0, 2.0], [3.0, 6.0])),
            [-0.6, 4.6, 1.4, 6.6],
        );
        // x spans 0.1: widened by 0.075 each side; y spans 3: left alone.
        near(
            thumbnail_box(&points([1.0, 2.0], [1.1, 5.0])),
            [0.925, 1.175, 2.0, 5.0],
        );
        near(
            thumbnail_box(&points([-4.0, 7.0], [-1.0, 7.0])),
            [-4.0, -1.0, 6.875, 7.125],
        );
    }

    /// Points far from the origin (model files allow coordinates up to 1e100) still get a plot
    /// of positive width around them: a padding of 0.5 vanished in rounding next to 1e100, the
    /// extent had zero width, every point mapped to NaN pixels and no dot was drawn.
    #[test]
    fn points_near_the_coordinate_bound_get_a_plot_around_them() {
        for c in [1e100, -1e100, 3e17] {
            let points = vec![("A".to_owned(), [c, c]), ("B".to_owned(), [c, c])];
            let [x0, x1, y0, y1] = extent(&points);
            assert!(
                x0 < c && c < x1 && y0 < c && c < y1,
                "{c}: {x0} {x1} {y0} {y1}"
            );
            // Wide enough for distinct pixel columns in floating point.
            assert!(
                (x1 - x0) / 8192.0 > 8.0 * c.abs() * f64::EPSILON,
                "{x0} {x1}"
            );
            let opts = MapOptions {
                size: 64,
                variance_samples: 4,
                ..MapOptions::default()
            };
            let img = latent_map(&points, &|_| Ok(1.0), None, &opts).unwrap();
            // The dots sit at the plot's centre (its right edge is 40 px from the image's):
            // red there (white ring, red core).
            let centre = img.get(img.width - 40 - 32, 40 + 32);
            assert!(centre[0] > 0.5 && centre[1] < 0.2, "{c}: {centre:?}");
        }
        // Ordinary coordinates keep the 0.5 padding.
        let [x0, x1, ..] = extent(&[("A".to_owned(), [0.3, 0.3])]);
        assert!(
            (x0 + 0.2).abs() < 1e-12 && (x1 - 0.8).abs() < 1e-12,
            "{x0} {x1}"
        );
    }

    /// Tick labels of huge coordinates stay on the image: the y labels get a left margin as
    /// wide as they need (they were right-aligned into a fixed 40-pixel margin and ran off the
    /// left edge), and x labels that would overlap are left out.
    #[test]
    fn huge_tick_labels_stay_on_the_image() {
        let points = vec![
            ("A".to_owned(), [-1e100, -1e100]),
            ("B".to_owned(), [1e100, 1e100]),
            ("C".to_owned(), [0.9e100, -3e99]),
        ];
        let opts = MapOptions {
            size: 200,
            variance_samples: 4,
            ..MapOptions::default()
        };
        let img = latent_map(&points, &|_| Ok(1.0), None, &opts).unwrap();
        let dark = |x: usize, y: usize| img.get(x, y).iter().all(|v| *v < 0.5);
        // Column 0 and the last column hold no text below the title lines (the axis name X2
        // starts at x = 2).
        for y in 30..img.height {
            assert!(
                !dark(0, y) && !dark(img.width - 1, y),
                "text at the edge, row {y}"
            );
        }
        // The labels sit in the margin, left of the frame, right of the axis name.
        let frame = (0..img.width).find(|&x| dark(x, 40 + 200)).unwrap();
        assert!(frame > 40, "the margin did not widen: frame at {frame}");
        let text_rows = 40..(40 + 200);
        let ink = (16..frame - 1).any(|x| text_rows.clone().any(|y| dark(x, y)));
        assert!(ink, "no y tick label left of the frame at {frame}");
    }

    /// A small map keeps its title and colour bar on the image (at 64 pixels the title ran
    /// 170 px and the colour bar's label 220 px beyond the right edge).
    #[test]
    fn small_maps_keep_title_and_colour_bar_on_the_image() {
        let points = vec![("A".to_owned(), [0.0, 0.0]), ("B".to_owned(), [1.0, 0.5])];
        let opts = MapOptions {
            size: 64,
            variance_samples: 4,
            ..MapOptions::default()
        };
        let variance = |p: [f64; 2]| Ok(1.0 + p[0] * p[0]);
        let img = latent_map(&points, &variance, None, &opts).unwrap();
        let dark = |x: usize, y: usize| img.get(x, y).iter().all(|v| *v < 0.5);
        for y in 0..img.height {
            for x in img.width - 3..img.width {
                assert!(!dark(x, y), "ink at ({x}, {y}) on the right edge");
            }
        }
        // The bar starts at the frame's corner (the y labels, up to "-0.5", put it at column
        // 46): "0", then the ramp, then the largest standard deviation, sqrt(1 + 1.5^2), 4 px
        // before the image's right edge (151 px wide): a ramp of 151 - 4 - 29 - 10 - 46 - 10
        // = 52 px.
        assert_eq!(img.width, 47 + 64 + 40);
        assert_colour_bar(&img, [46, 56, 52, 40 + 64 + 34], "1.803");
        // Default maps keep their layout: the 120-pixel ramp starts 160 px right of the corner.
        let big = latent_map(
            &points,
            &variance,
            None,
            &MapOptions {
                size: 400,
                variance_samples: 4,
                ..MapOptions::default()
            },
        )
        .unwrap();
        let y = 40 + 400 + 34 + 2;
        // (The y labels, up to "-0.5", put the frame's corner at column 46.)
        assert_eq!(big.get(46 + 160, y), [1.0; 3]);
        assert_ne!(big.get(46 + 161, y), [1.0; 3]);
        assert_eq!(big.get(46 + 159, y), [1.0; 3]);
    }

    /// The map's shading of a standard deviation `t` of the largest: white to deep blue.
    fn shade(t: f64) -> [f64; 3] {
        [1.0 - 0.95 * t, 1.0 - 0.85 * t, 1.0 - 0.45 * t]
    }

    /// Asserts that `img` has a colour bar at `[zero_x, bar_x, len, y]`: "0" at (zero_x, y), a
    /// ramp of `len` px from (bar_x, y), 8 px high, from shade(0) to shade(1) with white around
    /// it, and the label `top` 10 px after it.
    fn assert_colour_bar(img: &Image, [zero_x, bar_x, len, y]: [i64; 4], top: &str) {
        let white = [1.0; 3];
        let at = |x: i64, y: i64| img.get(x as usize, y as usize);
        assert!(drawn_at(img, zero_x, y, "0", [0.0; 3]), "0 at {zero_x}");
        assert!(drawn_at(img, bar_x + len + 10, y, top, [0.0; 3]), "{top}");
        for v in y..y + 8 {
            assert_eq!((at(bar_x - 1, v), at(bar_x + len, v)), (white, white));
            for i in 0..len {
                let want = shade(i as f64 / (len - 1) as f64);
                assert_eq!(at(bar_x + i, v), want, "ramp pixel {i}, row {v}");
            }
        }
        for x in bar_x..bar_x + len {
            assert_eq!((at(x, y - 1), at(x, y + 8)), (white, white));
        }
    }

    /// Whether `text` is drawn in `colour` with its top-left corner at (x, y): within the
    /// text's box and a 1-pixel border around it, exactly the text's own pixels are `colour`.
    fn drawn_at(img: &Image, x: i64, y: i64, text: &str, colour: [f64; 3]) -> bool {
        let (w, h) = (font::text_width(text, 1), font::GLYPH_H);
        let mut alone = Image::new(w + 2, h + 2, [1.0; 3]);
        alone.text(1, 1, text, 1, [0.0; 3]);
        (0..h + 2).all(|j| {
            (0..w + 2).all(|i| {
                let ink = alone.get(i, j) == [0.0; 3];
                let (u, v) = ((x - 1) as usize + i, (y - 1) as usize + j);
                (img.get(u, v) == colour) == ink
            })
        })
    }

    /// The map's furniture on a 400-pixel plot of a constant variance 2 over the square
    /// [-1.5, 1.5]^2 (ticks every 0.5, one at the middle of each axis): the frame, every grid
    /// line and tick mark, each tick label centred under (or right-aligned left of) its tick,
    /// the axis names moved past the middle tick's label, the title, the caption, the full
    /// colour bar with its two labels, a red training dot and a blue predicted ring, and a
    /// label right of each dot on a white box.
    #[test]
    fn frame_ticks_names_bar_dots_and_labels_sit_where_they_belong() {
        let points = vec![("A".to_owned(), [-1.0, -0.5]), ("B".to_owned(), [1.0, 0.5])];
        let size = 400usize;
        let opts = MapOptions {
            size,
            variance_samples: 4,
            caption: format!("STD OF LOG {}", "X".repeat(100)),
            predicted_points: 1,
            ..MapOptions::default()
        };
        let img = latent_map(&points, &|_| Ok(2.0), None, &opts).unwrap();
        assert_eq!(extent(&points), [-1.5, 1.5, -1.5, 1.5]);
        // The widest y label, "-1.5" (23 px), starts 4 px after X2 (columns 2 to 12) and ends
        // 7 px before the plot: the plot starts at column 47, 40 px from the top. The frame
        // lies around it: columns l and r, rows t and b.
        let (left, top) = (47i64, 40i64);
        assert_eq!(plot_left(&points), 47);
        let (l, t) = (left - 1, top - 1);
        let (r, b) = (left + size as i64, top + size as i64);
        assert_eq!(
            (img.width, img.height),
            (47 + size + 40, 40 + size + 40 + 32)
        );
        let (black, white) = ([0.0; 3], [1.0; 3]);
        // The constant variance is the largest.
        let base = shade(1.0);
        let grid = base.map(|c| c * (1.0 - 0.12));
        let at = |x: i64, y: i64| img.get(x as usize, y as usize);
        for k in 0..size as i64 + 2 {
            for (x, y) in [(l + k, t), (l + k, b), (l, t + k), (r, t + k)] {
                assert_eq!(at(x, y), black, "frame at ({x}, {y})");
            }
        }
        let ticks = nice_ticks(-1.5, 1.5, 5);
        let labels: Vec<&str> = ticks.iter().map(|(_, s)| s.as_str()).collect();
        assert_eq!(labels, ["-1.5", "-1.0", "-0.5", "0", "0.5", "1.0", "1.5"]);
        // Grid line k of each axis lies k sixths of the plot from its start (y runs up).
        let offsets: Vec<i64> = (0..7)
            .map(|k| (k as f64 * size as f64 / 6.0).round() as i64)
            .collect();
        assert_eq!(offsets, [0, 67, 133, 200, 267, 333, 400]);
        let columns: Vec<i64> = offsets.iter().map(|o| left + o).collect();
        let rows: Vec<i64> = offsets.iter().rev().map(|o| top + o).collect();
        // Rows and columns clear of the dots (at 114, 307 and 380, 173) and their labels.
        let clear = |v: i64, dots: [i64; 2]| dots.iter().all(|d| (v - d).abs() > 16);
        // Grid lines (the last ones lie on the frame), plain shading beside them.
        let beside = |p: i64, lines: &[i64], (start, end): (i64, i64)| {
            let next = [p - 1, p + 1].into_iter();
            next.filter(|n| start < *n && *n < end && !lines.contains(n))
                .collect::<Vec<i64>>()
        };
        for (&x, &y) in columns.iter().zip(&rows) {
            for q in t + 1..b {
                if clear(q, [173, 307]) && !rows.contains(&q) {
                    let want = if x == r { black } else { grid };
                    assert_eq!(at(x, q), want, "x grid line at ({x}, {q})");
                    for n in beside(x, &columns, (l, r)) {
                        assert_eq!(at(n, q), base, "beside the x grid line: ({n}, {q})");
                    }
                }
            }
            for q in l + 1..r {
                if clear(q, [114, 380]) && !columns.contains(&q) {
                    let want = if y == b { black } else { grid };
                    assert_eq!(at(q, y), want, "y grid line at ({q}, {y})");
                    for n in beside(y, &rows, (t, b)) {
                        assert_eq!(at(q, n), base, "beside the y grid line: ({q}, {n})");
                    }
                }
            }
        }
        for ((&x, &y), label) in columns.iter().zip(&rows).zip(&labels) {
            // Tick marks 4 px long outside the frame, then white.
            for d in 1..=4 {
                assert_eq!(at(x, b + d), black, "x tick at {x}");
                assert_eq!(at(l - d, y), black, "y tick at {y}");
            }
            for d in 5..=6 {
                assert_eq!(at(x, b + d), white, "past the x tick at {x}");
                assert_eq!(at(l - d, y), white, "past the y tick at {y}");
            }
            assert_eq!(at(x + 1, b + 1), white, "beside the x tick at {x}");
            // X labels centred under their ticks, y labels 6 px left of the frame, centred.
            let w = font::text_width(label, 1) as i64;
            assert!(drawn_at(&img, x - w / 2, b + 7, label, black), "x {label}");
            assert!(drawn_at(&img, l - 6 - w, y - 3, label, black), "y {label}");
        }
        // The middle ticks' labels hold the middles of the axes: X1 starts 6 px right of the
        // label "0" (ending at 249). X2 goes from the middle (rows 236 to 242) to the nearest
        // rows 2 px clear of every y label: 8 px up, ending 2 rows above the label "0" (rows
        // 237 to 243).
        assert!(drawn_at(&img, 255, b + 18, "X1", black));
        assert!(drawn_at(&img, 2, 228, "X2", black));
        let title = "LATENT SPACE, SHADED BY PREDICTIVE STANDARD DEVIATION";
        assert!(drawn_at(&img, l, 8, title, black));
        // The caption is cut to the 73 characters (437 px) that end 4 px before the image's
        // right edge; nothing of it is drawn further right.
        let caption = format!("STD OF LOG {}", "X".repeat(62));
        assert!(drawn_at(&img, l, 20, &caption, NOTE_GREY));
        for x in l + 438..img.width as i64 {
            assert!(
                (20..27).all(|y| at(x, y) == white),
                "caption ink in column {x}"
            );
        }
        // The colour bar: "0", then 120 px of ramp from 160 px right of the corner, then the
        // largest standard deviation, sqrt(2).
        assert_colour_bar(&img, [l + 130, l + 160, 120, b + 34], "1.414");
        // A (training): red core in a white ring; B (predicted): blue ring around white. Each
        // label sits 7 px right of its dot, vertically centred, on a white box (60 %).
        let third: f64 = 400.0 / 3.0;
        let (a, bb) = (
            (47.0 + third / 2.0, 40.0 + 2.0 * third),
            (447.0 - third / 2.0, 40.0 + third),
        );
        assert_eq!(at(113, 306), [0.8, 0.05, 0.02]);
        assert_eq!(at(107, 306), base);
        assert_eq!(at(380, 173), white);
        assert_eq!(at(383, 173), [0.05, 0.25, 0.85]);
        assert_eq!(at(374, 172), base);
        let boxed = base.map(|c| c * (1.0 - 0.6) + 0.6);
        for ((x, y), name) in [(a, "A"), (bb, "B")] {
            let (x, y) = (x.round() as i64 + 7, y.round() as i64 - 3);
            assert!(drawn_at(&img, x, y, name, black), "label {name}");
            // The box: the text and a 1-pixel border (the label is one 5 px glyph).
            assert_eq!(at(x - 1, y - 1), boxed, "label {name}'s box");
            assert_eq!(at(x + 5, y + 7), boxed, "label {name}'s box");
            assert_eq!(at(x - 2, y - 1), base, "left of label {name}'s box");
            assert_eq!(at(x + 6, y + 7), base, "right of label {name}'s box");
            assert_eq!(at(x + 5, y + 8), base, "under label {name}'s box");
        }
    }

    /// A map of `points` on a plot of `size` px over a variance of 1 everywhere.
    fn plain_map(points: &[LabelledPoint], size: usize) -> Image {
        let opts = MapOptions {
            size,
            variance_samples: 2,
            ..MapOptions::default()
        };
        latent_map(points, &|_| Ok(1.0), None, &opts).unwrap()
    }

    /// Where `latent_map` puts each x tick label over [x0, x1] on a plot of `size` px from
    /// column `left` in an image `width` px wide: centred under its tick, its first and last
    /// columns, and why it is left out: [starts left of the image, ends past its right edge,
    /// starts under 6 px after the last label kept ends] (kept when none holds).
    fn x_label_spans(
        ticks: &[(f64, String)],
        [x0, x1]: [f64; 2],
        (left, size): (i64, usize),
        width: usize,
    ) -> Vec<(i64, i64, [bool; 3])> {
        let mut last_end: Option<i64> = None;
        let mut spans = Vec::new();
        for (v, label) in ticks {
            let px = (left as f64 + (v - x0) / (x1 - x0) * size as f64).round() as i64;
            let w = font::text_width(label, 1) as i64;
            // Label widths are odd (6 n - 1 px): the label spans px - w / 2 ..= px + w / 2.
            let (a, end) = (px - w / 2, px + w / 2);
            let reasons = [
                a < 0,
                end >= width as i64,
                last_end.is_some_and(|e| a < e + 6),
            ];
            if !reasons.contains(&true) {
                last_end = Some(end);
            }
            spans.push((a, end, reasons));
        }
        spans
    }

    /// X tick labels are drawn greedily from the left, each centred under its tick: one that
    /// would start left of the image, end past its right edge or start less than 6 px after
    /// the previous drawn label ends is left out (its tick stays). Maps of every size from 64
    /// to 330 px with labels up to 101 px wide (ticks near 1e20, 5e8 apart) meet each case,
    /// including labels exactly at the image's edges and exactly 6 px apart; the row of x
    /// labels must be exactly the labels the rule keeps, at their places, and nothing else.
    #[test]
    fn x_tick_labels_that_would_overlap_or_leave_the_image_are_left_out() {
        // [off the left edge, off the right edge, too close, drawn at 0, ending at the right
        // edge, drawn exactly 6 px after the previous]
        let mut seen = [0usize; 6];
        // The left end of the first pair's plot is just left of a tick, the right end of the
        // second's just right of one.
        for shift in [1.44e9, 1.56e9] {
            let points = vec![
                ("A".to_owned(), [1e20 + shift, 0.0]),
                ("B".to_owned(), [1e20 + 5e8 + shift, 3e8]),
            ];
            let [x0, x1, ..] = extent(&points);
            let ticks = nice_ticks(x0, x1, 5);
            for size in 64..=330usize {
                let img = plain_map(&points, size);
                // The y labels (up to "-1E9", 23 px) put the plot at column 47.
                let b = 40 + size as i64;
                let mut want = Image::new(img.width, 9, [1.0; 3]);
                let mut last_end: Option<i64> = None;
                let spans = x_label_spans(&ticks, [x0, x1], (47, size), img.width);
                for ((_, label), (a, end, reasons)) in ticks.iter().zip(spans) {
                    for (n, &hit) in reasons.iter().enumerate() {
                        seen[n] += usize::from(hit);
                    }
                    if reasons.contains(&true) {
                        continue;
                    }
                    seen[3] += usize::from(a == 0);
                    seen[4] += usize::from(end + 1 == img.width as i64);
                    seen[5] += usize::from(last_end.is_some_and(|e| a == e + 6));
                    want.text(a, 1, label, 1, [0.0; 3]);
                    last_end = Some(end);
                }
                for y in 0..9 {
                    for x in 0..img.width {
                        let ink = img.get(x, (b + 6) as usize + y) == [0.0; 3];
                        assert_eq!(
                            ink,
                            want.get(x, y) == [0.0; 3],
                            "size {size}: pixel ({x}, {}) of the x labels' row",
                            b as usize + 6 + y
                        );
                    }
                }
            }
        }
        assert!(seen.iter().all(|&n| n > 0), "cases met: {seen:?}");
    }

    /// The axis names sit at the middles of their axes, moved aside where tick labels are:
    /// X1 (under the x labels) starts 6 px left of the middle unless a kept x label spans from
    /// 13 px right of the middle to 3 px left of it, when it starts 6 px after the first kept
    /// label that ends past the middle. X2 (at column 2, always 4 px or more left of the y
    /// labels) is centred on the middle or, where it would come within 2 px of a y label's
    /// rows, on the nearest rows of the plot that do not (the lower of two as near; centred
    /// if there are none). Maps of every size from 64 to 400 px over [-0.675, 2.325] x
    /// [-1.53, 1.47] meet both branches of each rule, X2 moved both ways and with a choice of
    /// two, and every boundary of the X1 rule where it decides where X1 goes.
    #[test]
    fn axis_names_sit_at_the_middles_clear_of_the_tick_labels() {
        let points = vec![
            ("A".to_owned(), [-0.175, -0.53]),
            ("B".to_owned(), [1.825, 0.47]),
        ];
        let [x0, x1, y0, y1] = extent(&points);
        let (xt, yt) = (nice_ticks(x0, x1, 5), nice_ticks(y0, y1, 5));
        let widest = yt.iter().map(|(_, s)| font::text_width(s, 1)).max();
        // The y labels, up to "-1.5" (23 px), put the plot at column 47.
        assert_eq!(widest, Some(23));
        let left = 47;
        // [X1 moved, a label starting 13 px right of the middle (alone moving X1), 14 px (X1
        // not moved), one ending 3 px left of it (alone moving X1), 4 px (X1 not moved), X1
        // moved with a label ending 6 px left of the middle, X2 moved up, X2 moved down, X2
        // centred with no clear rows, X2 moved with rows as near above as below]
        let mut seen = [0usize; 10];
        for size in 64..=400usize {
            let img = plain_map(&points, size);
            let (t, b) = (39, 40 + size as i64);
            let mid = left - 1 + (size / 2) as i64;
            let kept: Vec<(i64, i64)> = x_label_spans(&xt, [x0, x1], (left, size), img.width)
                .into_iter()
                .filter(|(_, _, reasons)| !reasons.contains(&true))
                .map(|(a, end, _)| (a, end))
                .collect();
            let near_count = (kept.iter())
                .filter(|&&(a, end)| a - 13 <= mid && mid <= end + 3)
                .count();
            let near = near_count > 0;
            let x_name = if near {
                kept.iter()
                    .map(|&(_, end)| end + 6)
                    .find(|&x| x > mid)
                    .unwrap()
            } else {
                mid - 6
            };
            assert!(
                drawn_at(&img, x_name, b + 18, "X1", [0.0; 3]),
                "size {size}: X1"
            );
            // X2: the first row of the name at the left edge, and where it would be centred.
            let y_name = (1..img.height as i64 - 8)
                .find(|&r| drawn_at(&img, 2, r, "X2", [0.0; 3]))
                .unwrap_or_else(|| panic!("size {size}: no X2"));
            let centred = 39 + (size / 2) as i64 - 3;
            let ticks = yt.iter().map(|(v, _)| (y1 - v) / (y1 - y0) * size as f64);
            let ticks: Vec<i64> = ticks.map(|y| 40 + y.round() as i64).collect();
            // Rows r..r + 7 of the name, 2 blank rows, rows y - 3..=y + 3 of a label, or back.
            let clear = |r: i64| ticks.iter().all(|&y| r + 7 + 2 <= y - 3 || y + 3 + 2 < r);
            let fits = |r: i64| t < r && r + 7 <= b;
            let nearest = (t + 1..=b - 7)
                .filter(|&r| clear(r))
                .map(|r| (r - centred).abs())
                .min();
            match nearest {
                Some(d) => {
                    assert!(fits(y_name) && clear(y_name), "size {size}: X2 at {y_name}");
                    assert_eq!((y_name - centred).abs(), d, "size {size}: X2 at {y_name}");
                    // Of two rows as near, the lower.
                    if d > 0 && fits(centred + d) && clear(centred + d) {
                        assert_eq!(y_name, centred + d, "size {size}");
                    }
                }
                None => assert_eq!(y_name, centred, "size {size}"),
            }
            let count = |f: &dyn Fn(&(i64, i64)) -> bool| kept.iter().filter(|s| f(s)).count();
            let counts = [
                usize::from(near),
                usize::from(near_count == 1) * count(&|&(a, _)| a - 13 == mid),
                usize::from(!near) * count(&|&(a, _)| a - 14 == mid),
                usize::from(near_count == 1) * count(&|&(_, end)| end + 3 == mid),
                usize::from(!near) * count(&|&(_, end)| end + 4 == mid),
                usize::from(near) * count(&|&(_, end)| end + 6 == mid),
                usize::from(y_name < centred),
                usize::from(y_name > centred),
                usize::from(nearest.is_none() && !clear(centred)),
                usize::from(
                    nearest.is_some_and(|d| d > 0 && clear(centred - d) && clear(centred + d)),
                ),
            ];
            for (s, c) in seen.iter_mut().zip(counts) {
                *s += c;
            }
        }
        assert!(seen.iter().all(|&n| n > 0), "cases met: {seen:?}");
        assert!(seen[0] < 337, "both branches: {seen:?}");
    }

    /// Every y tick label starts at least 4 px right of the axis name X2 (columns 2 to 12),
    /// however wide the labels: on small maps the two ran together ("X2-0.5").
    #[test]
    fn y_tick_labels_keep_clear_of_the_axis_name() {
        for (c, size) in [(0.2, 64), (0.2, 128), (1e7, 100), (-3e-9, 200), (1e100, 96)] {
            let points = vec![("A".to_owned(), [0.0, c]), ("B".to_owned(), [0.3, c * 1.1])];
            let img = plain_map(&points, size);
            // X2 is drawn whole, and nothing else is drawn between it and the y tick labels
            // (columns 13 to 16), from under the title to the last label.
            let b = 40 + size as i64;
            assert!(
                (1..b).any(|r| drawn_at(&img, 2, r, "X2", [0.0; 3])),
                "{c}: X2"
            );
            let dark = |x: usize, y: usize| img.get(x, y).iter().all(|v| *v < 0.5);
            for y in 30..=b as usize + 3 {
                for x in 13..17 {
                    assert!(!dark(x, y), "{c}, size {size}: ink at ({x}, {y})");
                }
            }
        }
    }

    /// The plot's shading is the bilinear interpolation of the sampled variance, drawn as
    /// `shade(sqrt(v / vmax))`, sampled at each pixel's centre in the coordinates the dots are
    /// drawn in. A variance bilinear within each cell of the sample grid (its kinks, at
    /// x = 0.5 and y = -0.5, on sample lines) is interpolated exactly, so every pixel away from
    /// the grid lines, the dots and their labels has a known colour; interpolating from another
    /// cell than the pixel's own (extrapolating) would cross a kink.
    #[test]
    fn the_shading_is_the_interpolated_standard_deviation_at_each_pixel_centre() {
        let points = vec![("A".to_owned(), [-1.0, -0.5]), ("B".to_owned(), [1.0, 0.5])];
        let variance =
            |p: [f64; 2]| 2.0 + (p[0] - 0.5).abs() + 0.5 * (p[1] + 0.5).abs() + 0.25 * p[0] * p[1];
        // The y labels, up to "-1.5" (23 px), put the plot at column 47.
        let (size, left, top, m) = (150usize, 47usize, 40usize, 7usize);
        let opts = MapOptions {
            size,
            variance_samples: m,
            ..MapOptions::default()
        };
        let img = latent_map(&points, &|p| Ok(variance(p)), None, &opts).unwrap();
        let [x0, x1, y0, y1] = extent(&points);
        // Samples every 0.5 from -1.5 to 1.5 on both axes; the shading's scale is the largest.
        assert_eq!([x0, x1, y0, y1], [-1.5, 1.5, -1.5, 1.5]);
        let at = |k: usize| -1.5 + 3.0 * k as f64 / (m - 1) as f64;
        let vmax = (0..m * m)
            .map(|k| variance([at(k % m), at(k / m)]))
            .fold(0.0, f64::max);
        // Plot pixel coordinates of a latent x (from the left) and y (from the top).
        let to_col = |x: f64| (x - x0) / (x1 - x0) * size as f64;
        let to_row = |y: f64| (y1 - y) / (y1 - y0) * size as f64;
        let grid_cols: Vec<usize> = nice_ticks(x0, x1, 5)
            .iter()
            .map(|(v, _)| to_col(*v).round() as usize)
            .collect();
        let grid_rows: Vec<usize> = nice_ticks(y0, y1, 5)
            .iter()
            .map(|(v, _)| to_row(*v).round() as usize)
            .collect();
        let dots: Vec<(f64, f64)> = points
            .iter()
            .map(|(_, p)| (to_col(p[0]), to_row(p[1])))
            .collect();
        let mut checked = 0;
        for py in 0..size {
            for px in 0..size {
                let near_dot = dots.iter().any(|&(dx, dy)| {
                    (px as f64 - dx).abs() < 60.0 && (py as f64 - dy).abs() < 20.0
                });
                if near_dot || grid_cols.contains(&px) || grid_rows.contains(&py) {
                    continue;
                }
                let p = [
                    x0 + (px as f64 + 0.5) / size as f64 * (x1 - x0),
                    y1 - (py as f64 + 0.5) / size as f64 * (y1 - y0),
                ];
                let t = (variance(p) / vmax).sqrt();
                let want = shade(t);
                let got = img.get(left + px, top + py);
                assert!(
                    (0..3).all(|c| (got[c] - want[c]).abs() < 1e-12),
                    "pixel ({px}, {py}): {got:?}, not {want:?}"
                );
                checked += 1;
            }
        }
        assert!(checked > size * size / 2, "{checked}");
    }

    /// Thumbnails asked for without a source of materials draw no panel: the image is the
    /// plain map, at the plot's height, not the height 8 rows of 64 px spheres would need.
    #[test]
    fn thumbnails_without_a_source_leave_the_plain_map() {
        let points = vec![("A".to_owned(), [0.0, 0.0]), ("B".to_owned(), [1.0, 0.5])];
        let plain = MapOptions {
            size: 64,
            variance_samples: 4,
            ..MapOptions::default()
        };
        let asked = MapOptions {
            thumbnails: 8,
            sphere: SphereOptions {
                size: 64,
                ..SphereOptions::default()
            },
            ..plain.clone()
        };
        let a = latent_map(&points, &|_| Ok(1.0), None, &plain).unwrap();
        let b = latent_map(&points, &|_| Ok(1.0), None, &asked).unwrap();
        // (The y labels, up to "-0.5", put the plot at column 47.)
        assert_eq!((a.width, a.height), (47 + 64 + 40, 40 + 64 + 40 + 32));
        assert_eq!((b.width, b.height), (a.width, a.height));
        assert!(a.rgb == b.rgb);
    }

    #[test]
    fn captions_name_the_units_and_the_slice() {
        assert_eq!(
            variance_caption("raw", 2),
            "SHADING: PREDICTIVE STD PER TRANSFORMED VALUE, raw"
        );
        assert_eq!(
            variance_caption("raw", 3),
            "SHADING: PREDICTIVE STD PER TRANSFORMED VALUE, raw, SLICE X3 = 0"
        );
        assert!(variance_caption("log(offset=0.01)", 5).ends_with(", SLICE X3..X5 = 0"));
        assert!(variance_caption("raw", 1).ends_with(", ONE LATENT AXIS: X2 IS NOT A MODEL AXIS"));
    }

    const BOUNDS: Rect = Rect {
        x0: 40,
        y0: 40,
        x1: 680,
        y1: 680,
    };

    /// The boxes of the labels placed (all of them: panics on one left out).
    fn boxes(spots: &[Option<LabelSpot>], widths: &[usize]) -> Vec<Rect> {
        spots
            .iter()
            .zip(widths)
            .enumerate()
            .map(|(i, (s, w))| {
                s.unwrap_or_else(|| panic!("label {i} left out"))
                    .label_box(*w)
            })
            .collect()
    }

    /// Asserts that the labels' boxes (with their dots' indices) lie inside `bounds` and
    /// overlap neither each other nor any dot's clearance square.
    fn assert_free(labels: &[(usize, Rect)], dots: &[(f64, f64)], bounds: &Rect) {
        for (i, (k, b)) in labels.iter().enumerate() {
            assert!(b.inside(bounds), "label {k} leaves the plot: {b:?}");
            for (j, c) in labels.iter().skip(i + 1) {
                assert_eq!(b.overlap(c), 0, "labels {k} and {j} overlap");
            }
            for (d, &(x, y)) in dots.iter().enumerate() {
                let dot = Rect::around_dot(x, y);
                assert_eq!(b.overlap(&dot), 0, "label {k} covers dot {d}");
            }
        }
    }

    #[test]
    fn sparse_labels_sit_right_of_their_dots() {
        let dots = [(100.0, 100.0), (300.0, 300.0), (500.0, 200.0)];
        let widths = [60, 90, 30];
        let spots = place_labels(&dots, &widths, BOUNDS, 3);
        for ((x, y), s) in dots.iter().zip(&spots) {
            assert_eq!(
                *s,
                Some(LabelSpot {
                    x: *x as i64 + 7,
                    y: *y as i64 - 3,
                    leader: false
                })
            );
        }
    }

    #[test]
    fn crowded_labels_overlap_neither_each_other_nor_dots() {
        // 40 dots packed in a 30 x 30 pixel patch (the metals of the default map), labels up
        // to 20 characters.
        let dots: Vec<(f64, f64)> = (0..40)
            .map(|k| {
                let t = k as f64;
                (300.0 + (t * 7.3) % 30.0, 320.0 + (t * 11.9) % 30.0)
            })
            .collect();
        let widths: Vec<usize> = (0..40).map(|k| 6 * (8 + k % 13) - 1).collect();
        let spots = place_labels(&dots, &widths, BOUNDS, 40);
        // Every one finds a free spot (none is left out).
        let b: Vec<(usize, Rect)> = boxes(&spots, &widths).into_iter().enumerate().collect();
        assert_free(&b, &dots, &BOUNDS);
        assert!(spots.iter().any(|s| s.is_some_and(|s| s.leader)));
        // Deterministic.
        assert_eq!(place_labels(&dots, &widths, BOUNDS, 40), spots);
    }

    /// On a plot too small for its labels (51 in 128 x 128 px, as `specgp map --size 128`),
    /// training materials' labels that find no free spot are left out, the others neither
    /// overlap nor cover a dot; the last 3 (predictions, always labelled) stay in the plot, one
    /// wider than the plot from its left edge (right of it is a margin, left of it the tick
    /// labels). Labels were put at ring spots up to 112 px outside the plot (over the tick
    /// labels, under the thumbnail panel, off the image), then drawn over each other.
    #[test]
    fn labels_without_a_free_spot_are_left_out_of_a_small_plot() {
        let bounds = Rect {
            x0: 40,
            y0: 40,
            x1: 168,
            y1: 168,
        };
        let dots: Vec<(f64, f64)> = (0..51)
            .map(|k| {
                let t = k as f64;
                (50.0 + (t * 13.7) % 108.0, 80.0 + (t * 7.9) % 48.0)
            })
            .collect();
        // 12 to 28 characters: 71 to 167 px.
        let widths: Vec<usize> = (0..51).map(|k| 6 * (12 + k % 17) - 1).collect();
        let spots = place_labels(&dots, &widths, bounds, 48);
        let free: Vec<(usize, Rect)> = (0..48)
            .filter_map(|k| spots[k].map(|s| (k, s.label_box(widths[k]))))
            .collect();
        let left_out = 48 - free.len();
        assert!((20..48).contains(&left_out), "{left_out} left out");
        assert_free(&free, &dots, &bounds);
        for (k, (b, w)) in boxes(&spots[48..], &widths[48..])
            .iter()
            .zip(&widths[48..])
            .enumerate()
        {
            assert!(b.y0 >= 40 && b.y1 <= 168, "label {}: {b:?}", 48 + k);
            if w + 2 <= 128 {
                assert!(b.inside(&bounds), "label {} ({w} px): {b:?}", 48 + k);
            } else {
                assert_eq!(b.x0, 40, "label {} ({w} px): {b:?}", 48 + k);
            }
        }
    }

    /// Dots with more neighbours under 48 px away are labelled first, in index order among
    /// equals; a neighbour exactly 48 px away does not count.
    #[test]
    fn crowded_dots_are_labelled_first() {
        let dots = [
            (300.0, 300.0),
            (100.0, 100.0),
            (130.0, 100.0),
            (0.0, 0.0),
            (118.0, 132.0),
            (48.0, 0.0),
            (400.0, 100.0),
            (400.0, 200.0),
        ];
        // Dots 1, 2 and 4 are 30, 34.2 and 36.7 px apart: three in each one's crowd. Dots 3
        // and 5 are 48 px apart, 6 and 7 100 px: each alone in its crowd, as is dot 0.
        assert_eq!(placing_order(&dots), [1, 2, 4, 0, 3, 5, 6, 7]);
    }

    /// The spots beside a dot, each taken when the ones before it are not free: right, left,
    /// above and below it, 7 px clear of its centre's pixel (vertically and horizontally
    /// centred), then the corners, diagonally 7 px clear (a corner 5 px clear met the dot's own
    /// clearance square, so a label never went there when every side was taken: it went onto
    /// a ring, with a leader line).
    #[test]
    fn labels_take_the_first_free_spot_beside_their_dot() {
        let (w, h) = (11i64, font::GLYPH_H as i64);
        let bounds = |x0, y0, x1, y1| Rect { x0, y0, x1, y1 };
        let spot = |x, y| LabelSpot {
            x,
            y,
            leader: false,
        };
        let alone = |b: Rect| place_labels(&[(100.0, 100.0)], &[11], b, 1)[0];
        assert_eq!(alone(bounds(0, 0, 400, 400)), Some(spot(107, 97)));
        // The right spot's box ends at 107 + 11 + 1 = 119, the left spot's starts at 81 and
        // the one above's at 85.
        assert_eq!(alone(bounds(0, 0, 118, 400)), Some(spot(100 - 7 - w, 97)));
        assert_eq!(
            alone(bounds(82, 0, 118, 400)),
            Some(spot(100 - w / 2, 100 - 7 - h))
        );
        assert_eq!(
            alone(bounds(82, 86, 118, 400)),
            Some(spot(100 - w / 2, 107))
        );
        // Every side taken by another dot 12 px away: the corners.
        let sides = [(112.0, 100.0), (88.0, 100.0), (100.0, 88.0), (100.0, 112.0)];
        let big = bounds(0, 0, 400, 400);
        let corners = [
            (spot(107, 100 - 7 - h), big),
            (spot(107, 107), bounds(0, 86, 400, 400)),
            (spot(100 - 7 - w, 100 - 7 - h), bounds(0, 0, 118, 400)),
            (spot(100 - 7 - w, 107), bounds(0, 86, 118, 400)),
        ];
        for (want, b) in corners {
            let dots: Vec<(f64, f64)> = [(100.0, 100.0)].into_iter().chain(sides).collect();
            let got = place_labels(&dots, &[11; 5], b, 5)[0];
            assert_eq!(got, Some(want), "bounds {b:?}");
        }
    }

    /// A label with no free spot beside its dot takes the first free spot on the rings around
    /// it (16 px, then 26 px, ...; from the right, turning down), vertically centred on the
    /// ring, with the side of its box nearest the dot facing it: for a dot left of the bounds,
    /// 26 px to the right; for one right of them, 26 px out at 157.5 degrees, its box's right
    /// side there.
    #[test]
    fn labels_with_no_room_beside_take_the_first_free_ring_spot() {
        let ring = |dot: (f64, f64), bounds: Rect| place_labels(&[dot], &[11], bounds, 1)[0];
        let bounds = |x0, x1| Rect {
            x0,
            y0: 0,
            x1,
            y1: 400,
        };
        let leader = |x, y| Some(LabelSpot { x, y, leader: true });
        // (100 + 26, 100 - 3.5 rounded)
        assert_eq!(ring((100.0, 100.0), bounds(120, 400)), leader(126, 97));
        // (300 - 26 cos 22.5 - 11, 100 + 26 sin 22.5 - 3.5) = (264.98, 106.45)
        assert_eq!(ring((300.0, 100.0), bounds(0, 280)), leader(265, 106));
    }

    /// A prediction's label with no free spot is moved into the bounds where it fits them (a
    /// label out of them costs more than any overlap): in bounds exactly as large as its box,
    /// it fills them, over its own dot or from a dot beyond any of their sides.
    #[test]
    fn a_label_that_just_fits_the_bounds_is_placed_inside_them() {
        let h = font::GLYPH_H as i64;
        let cases = [
            (11usize, (10.0, 6.0)),
            (23, (5.0, 2.0)),
            (5, (3.0, 7.0)),
            (11, (200.0, 6.0)),
            (11, (6.0, 250.0)),
            (11, (-200.0, 6.0)),
            (11, (6.0, -250.0)),
        ];
        for (w, (dx, dy)) in cases {
            let bounds = Rect {
                x0: 100,
                y0: 50,
                x1: 100 + w as i64 + 2,
                y1: 50 + h + 2,
            };
            let spot = place_labels(&[(100.0 + dx, 50.0 + dy)], &[w], bounds, 0)[0];
            assert_eq!(
                spot.map(|s| (s.x, s.y)),
                Some((101, 51)),
                "{w} px, {dx}, {dy}"
            );
        }
    }

    /// A label's cost: every pixel of its box (text and 1-pixel border) outside the bounds
    /// costs 2^24, one left of them twice that; overlaps with dots' clearance squares and
    /// other labels cost a pixel each.
    #[test]
    fn labels_pay_for_pixels_out_of_bounds_left_ones_twice_and_for_overlaps() {
        let dots = [(50.0, 50.0)];
        let layout = Layout {
            dots: &dots,
            widths: &[11],
            bounds: Rect {
                x0: 0,
                y0: 0,
                x1: 100,
                y1: 100,
            },
            dot_boxes: vec![Rect::around_dot(50.0, 50.0)],
            labels: vec![None],
        };
        let at = |x: i64, y: i64| LabelSpot {
            x,
            y,
            leader: false,
        };
        // The box is 13 x 9 px: x - 1..x + 12, y - 1..y + 8.
        assert_eq!(layout.cost(0, &at(20, 20), &[]), 0);
        assert_eq!(layout.cost(0, &at(1, 1), &[]), 0);
        assert_eq!(layout.cost(0, &at(88, 92), &[]), 0);
        let out = 1i64 << 24;
        assert_eq!(layout.cost(0, &at(92, 20), &[]), 4 * 9 * out);
        assert_eq!(layout.cost(0, &at(-3, 20), &[]), 2 * 4 * 9 * out);
        assert_eq!(layout.cost(0, &at(20, -3), &[]), 4 * 13 * out);
        assert_eq!(layout.cost(0, &at(20, 96), &[]), 4 * 13 * out);
        // 2 columns out at the left and 3 rows at the top: the corner's pixels count once as
        // out, then the left columns again.
        assert_eq!(
            layout.cost(0, &at(-1, -2), &[]),
            (3 * 13 + 2 * 9 - 3 * 2 + 2 * 9) * out
        );
        // The dot's clearance square is 44..56 on both axes; another label at 30..40 x 30..39.
        assert_eq!(
            Rect::around_dot(50.0, 50.0),
            Rect {
                x0: 44,
                y0: 44,
                x1: 56,
                y1: 56
            }
        );
        let other = Rect {
            x0: 30,
            y0: 30,
            x1: 40,
            y1: 39,
        };
        // Boxes 40..53 x 40..49 and 32..45 x 37..46 (1 x 2 px over the dot, 8 x 2 over the
        // other label).
        assert_eq!(layout.cost(0, &at(41, 41), &[]), 9 * 5);
        assert_eq!(layout.cost(0, &at(33, 38), &[(other, None)]), 2 + 8 * 2);
    }

    /// A leader line through another dot (within its drawn radius) counts as 3 tangles; one
    /// that passes beside, before or after a dot, none.
    #[test]
    fn a_leader_line_through_a_dot_counts_three_tangles() {
        // The label's dot, one on its leader line, one left of where it starts, one beside it.
        let dots = [
            (100.0, 100.0),
            (130.0, 100.0),
            (90.0, 100.0),
            (130.0, 110.0),
        ];
        let layout = Layout {
            dots: &dots,
            widths: &[11; 4],
            bounds: Rect {
                x0: 0,
                y0: 0,
                x1: 400,
                y1: 400,
            },
            dot_boxes: dots.iter().map(|&(x, y)| Rect::around_dot(x, y)).collect(),
            labels: vec![None; 4],
        };
        let leader = |x, y| LabelSpot { x, y, leader: true };
        // Along y = 100 to the box at x = 149, through (130, 100) only.
        assert_eq!(layout.tangles(0, &leader(150, 97), &[]), 3);
        // Up and right to (149, 48): clear of every dot.
        assert_eq!(layout.tangles(0, &leader(150, 40), &[]), 0);
        // Beside its dot, without a leader line: nothing to cross.
        let beside = LabelSpot {
            leader: false,
            ..leader(150, 97)
        };
        assert_eq!(layout.tangles(0, &beside, &[]), 0);
    }

    /// A prediction's label takes its least bad spot even where none is free; a training label
    /// it then covers moves (refinement) to a free spot. In a 60 x 24 px plot, T's label goes
    /// first (right of T) and P's 47 px label, too wide to be free anywhere, covers its top
    /// row; T's label then moves down and right on a leader line, clear of P's.
    #[test]
    fn a_label_covered_by_a_later_prediction_moves_to_a_free_spot() {
        let bounds = Rect {
            x0: 0,
            y0: 0,
            x1: 60,
            y1: 24,
        };
        let (dots, widths) = ([(10.0, 12.0), (40.0, 12.0)], [5, 47]);
        let spots = place_labels(&dots, &widths, bounds, 1);
        let [Some(t), Some(p)] = spots[..] else {
            panic!("{spots:?}")
        };
        let (tb, pb) = (t.label_box(5), p.label_box(47));
        assert!(tb.inside(&bounds) && pb.inside(&bounds), "{tb:?} {pb:?}");
        assert_eq!(tb.overlap(&pb), 0, "{tb:?} {pb:?}");
        assert!(
            dots.iter()
                .all(|&(x, y)| tb.overlap(&Rect::around_dot(x, y)) == 0)
        );
        assert!(t.leader, "{t:?}");
        // Where T's label went first (beside it, on the right), P's label covers it.
        let first = LabelSpot {
            x: 17,
            y: 9,
            leader: false,
        };
        assert!(first.label_box(5).overlap(&pb) > 0, "{pb:?}");
    }

    #[test]
    fn labels_near_the_border_stay_inside() {
        let dots = [(675.0, 45.0), (45.0, 675.0)];
        let widths = [120, 120];
        for b in boxes(&place_labels(&dots, &widths, BOUNDS, 2), &widths) {
            assert!(b.inside(&BOUNDS), "{b:?}");
        }
    }

    /// Leader lines crossing each other, leader lines through other labels, leader lines
    /// through other dots.
    fn tangles(dots: &[(f64, f64)], widths: &[usize], spots: &[Option<LabelSpot>]) -> [usize; 3] {
        let placed: Vec<(usize, Rect, bool)> = spots
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.map(|s| (i, s.label_box(widths[i]), s.leader)))
            .collect();
        let leaders: Vec<(usize, Leader)> = placed
            .iter()
            .filter(|p| p.2)
            .map(|&(i, b, _)| (i, Leader::new(dots[i], &b)))
            .collect();
        let mut t = [0; 3];
        for (a, (i, l)) in leaders.iter().enumerate() {
            t[0] += leaders[a + 1..]
                .iter()
                .filter(|(_, m)| l.crosses(m))
                .count();
            t[1] += placed
                .iter()
                .filter(|(k, b, _)| k != i && l.meets_rect(b))
                .count();
            let r = DOT_RADIUS;
            t[2] += (dots.iter().enumerate())
                .filter(|&(k, &(x, y))| k != *i && l.meets([x - r, y - r, x + r, y + r]))
                .count();
        }
        t
    }

    /// `n` dots in a 60 x 40 px patch in the middle of [`BOUNDS`], labels of 5 to 18
    /// characters (seeded).
    fn patch(n: usize, seed: u64) -> (Vec<(f64, f64)>, Vec<usize>) {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let dots = (0..n)
            .map(|_| (360.0 + 60.0 * (next() - 0.5), 360.0 + 40.0 * (next() - 0.5)))
            .collect();
        let widths = (0..n)
            .map(|_| 6 * (6 + (next() * 14.0) as usize) - 1)
            .collect();
        (dots, widths)
    }

    /// Leader lines cross neither each other nor other labels and dots where the layout
    /// allows it. The nearest free spot of each label in turn (the placement before tangles
    /// counted) gave 2-4 tangles on these patches.
    #[test]
    fn leader_lines_avoid_each_other_labels_and_dots() {
        for seed in [0, 1, 4] {
            let (dots, widths) = patch(8, seed);
            let spots = place_labels(&dots, &widths, BOUNDS, 8);
            assert!(spots.iter().all(Option::is_some));
            assert_eq!(tangles(&dots, &widths, &spots), [0; 3], "seed {seed}");
        }
    }

    /// After placement no tangled label has a spot with fewer tangles, given the others.
    #[test]
    fn no_tangled_label_has_a_better_spot() {
        for seed in 0..6 {
            let (dots, widths) = patch(12, seed);
            let spots = place_labels(&dots, &widths, BOUNDS, 12);
            let mut layout = Layout {
                dots: &dots,
                widths: &widths,
                bounds: BOUNDS,
                dot_boxes: dots.iter().map(|&(x, y)| Rect::around_dot(x, y)).collect(),
                labels: spots.clone(),
            };
            for (i, spot) in spots.iter().enumerate() {
                let spot = spot.expect("room for every label");
                layout.labels[i] = None;
                let (now, best) = (layout.score(i, &spot), layout.best_spot(i).0);
                assert!(
                    now.1 == 0 || best >= now,
                    "seed {seed}, label {i}: {now:?} -> {best:?}"
                );
                layout.labels[i] = Some(spot);
            }
        }
    }

    /// The rectangle helpers the label layout's tests also lean on, by hand: overlap areas
    /// (touching edges share nothing), containment up to equal edges, the nearest point of a
    /// box, a dot's clearance square (rounded outwards) and a label's box (text plus a
    /// 1-pixel border).
    #[test]
    fn rectangles_overlap_contain_and_clamp_by_hand() {
        let r = |x0, y0, x1, y1| Rect { x0, y0, x1, y1 };
        let a = r(0, 0, 10, 10);
        for (b, area) in [
            (r(5, 5, 15, 15), 25),
            (r(2, 3, 4, 8), 10),
            (r(-3, 4, 2, 20), 12),
            (r(10, 0, 20, 10), 0),
            (r(0, 10, 10, 20), 0),
            (r(11, 11, 12, 12), 0),
            (r(-5, -5, 0, 0), 0),
        ] {
            assert_eq!(a.overlap(&b), area, "{b:?}");
            assert_eq!(b.overlap(&a), area, "{b:?}");
        }
        assert!(a.inside(&a) && r(1, 2, 9, 8).inside(&a));
        for b in [
            r(-1, 0, 10, 10),
            r(0, -1, 10, 10),
            r(0, 0, 11, 10),
            r(0, 0, 10, 11),
        ] {
            assert!(!b.inside(&a) && a.inside(&b), "{b:?}");
        }
        assert_eq!(a.nearest_point(3.5, 4.0), (3.5, 4.0));
        assert_eq!(a.nearest_point(-2.0, 12.5), (0.0, 10.0));
        assert_eq!(a.nearest_point(14.0, -1.0), (10.0, 0.0));
        assert_eq!(Rect::around_dot(10.2, 20.7), r(4, 15, 16, 27));
        assert_eq!(Rect::around_dot(10.5, 20.5), r(5, 15, 16, 26));
        let spot = LabelSpot {
            x: 3,
            y: 4,
            leader: false,
        };
        assert_eq!(spot.label_box(10), r(2, 3, 14, 5 + font::GLYPH_H as i64));
    }

    /// Leader lines, by hand: two lines cross only through each other's interior (an X),
    /// not when one ends on the other, runs beside it or along it; a line meets a box when
    /// it passes through the box's inside (crossing it, entering it, lying in it or cutting a
    /// corner), not when it stops at an edge, runs along one or passes by (a corner too).
    #[test]
    fn leader_lines_cross_and_meet_boxes_by_hand() {
        let line = |a: (f64, f64), b: (f64, f64)| Leader { from: a, to: b };
        let x = line((0.0, 0.0), (10.0, 10.0));
        for (o, crossing) in [
            (line((0.0, 10.0), (10.0, 0.0)), true),
            (line((10.0, 0.0), (0.0, 10.0)), true),
            (line((0.0, 10.0), (5.0, 5.0)), false),
            (line((0.0, 10.0), (4.0, 6.0)), false),
            (line((1.0, 0.0), (11.0, 10.0)), false),
            (line((2.0, 2.0), (20.0, 20.0)), false),
            (line((6.0, 0.0), (6.0, 5.0)), false),
            (line((6.0, 0.0), (6.0, 7.0)), true),
            // Ending on the other line, from either side, is touching, not crossing.
            (line((10.0, 0.0), (5.0, 5.0)), false),
            (line((0.0, 10.0), (5.0, 5.0)), false),
        ] {
            assert_eq!(x.crosses(&o), crossing, "{o:?}");
            assert_eq!(o.crosses(&x), crossing, "{o:?}");
        }
        let b = [0.0, 0.0, 10.0, 10.0];
        for (l, meets) in [
            (line((-5.0, 5.0), (15.0, 5.0)), true),
            (line((5.0, -5.0), (5.0, 15.0)), true),
            (line((-5.0, -5.0), (15.0, 15.0)), true),
            (line((15.0, 15.0), (5.0, 5.0)), true),
            (line((2.0, 3.0), (4.0, 5.0)), true),
            (line((5.0, 5.0), (20.0, 8.0)), true),
            (line((-5.0, 5.0), (0.0, 5.0)), false),
            (line((15.0, 5.0), (10.0, 5.0)), false),
            (line((5.0, 15.0), (5.0, 10.0)), false),
            (line((5.0, -3.0), (5.0, 0.0)), false),
            (line((0.0, -5.0), (0.0, 15.0)), false),
            (line((-5.0, 10.0), (15.0, 10.0)), false),
            (line((-5.0, 11.0), (15.0, 11.0)), false),
            (line((-5.0, 0.0), (5.0, -10.0)), false),
            (line((11.0, -5.0), (11.0, 15.0)), false),
            (line((8.0, -5.0), (15.0, 5.0)), false),
            (line((6.0, -5.0), (12.0, 5.0)), true),
            // Touching a corner only.
            (line((5.0, 15.0), (15.0, 5.0)), false),
            (line((-5.0, 5.0), (5.0, -5.0)), false),
        ] {
            assert_eq!(l.meets(b), meets, "{l:?}");
        }
        let r = Rect {
            x0: 0,
            y0: 0,
            x1: 10,
            y1: 10,
        };
        assert!(line((-5.0, 5.0), (15.0, 5.0)).meets_rect(&r));
        assert!(!line((-5.0, 10.0), (15.0, 10.0)).meets_rect(&r));
        assert!(!line((-5.0, 5.0), (-1.0, 5.0)).meets_rect(&r));
    }
}
