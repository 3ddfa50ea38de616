//! The latent map (the paper's Figs. 4.1 and 4.3): every material as a labelled dot in the
//! first two latent axes over the predictive variance, and optionally a grid of sphere
//! thumbnails of predicted materials across the same extent.

use brdf_io::BrdfSource;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::font;
use crate::image::Image;
use crate::sphere::{SphereOptions, render_sphere};

/// Largest side of a map's plot area and of its thumbnail panel, in pixels (as a sphere's).
pub const MAX_MAP_PIXELS: usize = 16384;
/// Most thumbnails per axis of a map's panel.
pub const MAX_THUMBNAILS: usize = 64;

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
    /// Variance samples per axis of the background (bilinearly interpolated).
    pub variance_samples: usize,
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
        }
    }
}

/// A latent point with its label.
pub type LabelledPoint = (String, [f64; 2]);

/// Makes a source for a latent point (e.g. a lazily predicted material).
pub type SourceAt<'a> = dyn Fn([f64; 2]) -> Result<Box<dyn BrdfSource + 'a>> + Sync + 'a;

/// The plot extent: the points' bounding box padded by 15 % (at least 0.5), widened to a square
/// (equal scales on both axes), as (x0, x1, y0, y1).
pub fn extent(points: &[LabelledPoint]) -> [f64; 4] {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (_, p) in points {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    let pad = |a: f64, b: f64| ((b - a) * 0.15).max(0.5);
    let (px, py) = (pad(x0, x1), pad(y0, y1));
    let (mut x0, mut x1, mut y0, mut y1) = (x0 - px, x1 + px, y0 - py, y1 + py);
    // Equal scales on both axes (distances in the latent space are what the kernel sees).
    let half = 0.5 * (x1 - x0).max(y1 - y0);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    (x0, x1, y0, y1) = (cx - half, cx + half, cy - half, cy + half);
    [x0, x1, y0, y1]
}

/// Draws the map: variance shading (white = low, deep blue = high, scaled to the largest
/// sampled variance), dots with labels, axis ranges, a colour bar; with
/// `opts.thumbnails > 0` and `source_at`, a panel of spheres of the predicted materials on a
/// regular grid over the same extent to the right.
pub fn latent_map(
    points: &[LabelledPoint],
    variance: &(dyn Fn([f64; 2]) -> Result<f64> + Sync),
    source_at: Option<&SourceAt<'_>>,
    opts: &MapOptions,
) -> Result<Image> {
    if points.is_empty() || !(64..=MAX_MAP_PIXELS).contains(&opts.size) || opts.variance_samples < 2
    {
        return Err(Error::InvalidArgument {
            reason: format!(
                "a map needs points, a size in 64..={MAX_MAP_PIXELS} and >= 2 variance samples \
                 (got {} points, size {})",
                points.len(),
                opts.size
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
                    "thumbnails: {k} per axis (at most {MAX_THUMBNAILS}) of {px} px (8..=1024), \
                     a panel of at most {MAX_MAP_PIXELS} px"
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
    let size = opts.size;
    let margin = 40usize;
    let panel = if opts.thumbnails > 0 && source_at.is_some() {
        opts.thumbnails * opts.sphere.size + margin
    } else {
        0
    };
    let width = margin + size + margin + panel;
    let height = margin + size + margin + 20;
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
        .map(|k| variance(at(k % m, k / m)))
        .collect::<Result<_>>()?;
    let vmax = grid.iter().copied().fold(0.0, f64::max).max(1e-300);
    let shade = |t: f64| {
        let t = t.clamp(0.0, 1.0);
        // White -> deep blue (linear).
        [1.0 - 0.95 * t, 1.0 - 0.85 * t, 1.0 - 0.45 * t]
    };
    for py in 0..size {
        for px in 0..size {
            let u = px as f64 / (size - 1) as f64 * (m - 1) as f64;
            let v = py as f64 / (size - 1) as f64 * (m - 1) as f64;
            let (i, j) = ((u as usize).min(m - 2), (v as usize).min(m - 2));
            let (fu, fv) = (u - i as f64, v - j as f64);
            let g = |a: usize, b: usize| grid[b * m + a];
            let val = (1.0 - fv) * ((1.0 - fu) * g(i, j) + fu * g(i + 1, j))
                + fv * ((1.0 - fu) * g(i, j + 1) + fu * g(i + 1, j + 1));
            img.set(
                (margin + px) as i64,
                (margin + py) as i64,
                shade(val / vmax),
            );
        }
    }
    let to_px = |p: [f64; 2]| {
        (
            margin as f64 + (p[0] - x0) / (x1 - x0) * size as f64,
            margin as f64 + (y1 - p[1]) / (y1 - y0) * size as f64,
        )
    };
    // Frame and axis ranges.
    let black = [0.0; 3];
    let (l, t, r, b) = (
        margin as i64 - 1,
        margin as i64 - 1,
        (margin + size) as i64,
        (margin + size) as i64,
    );
    img.fill_rect(l, t, size + 2, 1, black);
    img.fill_rect(l, b, size + 2, 1, black);
    img.fill_rect(l, t, 1, size + 2, black);
    img.fill_rect(r, t, 1, size + 2, black);
    img.text(l, b + 6, &format!("{x0:.2}"), 1, black);
    let s = format!("{x1:.2}");
    img.text(r - font::text_width(&s, 1) as i64, b + 6, &s, 1, black);
    img.text(l + (size / 2) as i64 - 12, b + 6, "X1", 1, black);
    img.text(2, t, &format!("{y1:.2}"), 1, black);
    img.text(2, b - 7, &format!("{y0:.2}"), 1, black);
    img.text(2, t + (size / 2) as i64, "X2", 1, black);
    img.text(
        l,
        8,
        "LATENT SPACE, SHADED BY PREDICTIVE VARIANCE",
        1,
        black,
    );
    // Colour bar.
    let bar_y = b + 20;
    for i in 0..120 {
        img.fill_rect(l + 160 + i, bar_y, 1, 8, shade(i as f64 / 119.0));
    }
    img.text(l + 130, bar_y, "0", 1, black);
    img.text(l + 290, bar_y, &format!("{vmax:.3}"), 1, black);
    // Dots and labels.
    for (name, p) in points {
        let (cx, cy) = to_px(*p);
        img.disc(cx, cy, 4.5, [1.0; 3]);
        img.disc(cx, cy, 3.0, [0.8, 0.05, 0.02]);
        img.text(cx as i64 + 6, cy as i64 - 3, name, 1, black);
    }
    // Thumbnails.
    if let (Some(f), true) = (source_at, panel > 0) {
        let g = opts.thumbnails;
        let ts = opts.sphere.size;
        let ox = (margin + size + margin) as i64;
        let cells: Vec<(usize, usize)> = (0..g * g).map(|k| (k % g, k / g)).collect();
        let thumbs: Vec<Image> = cells
            .iter()
            .map(|&(i, j)| {
                let p = [
                    x0 + (x1 - x0) * (i as f64 + 0.5) / g as f64,
                    y1 - (y1 - y0) * (j as f64 + 0.5) / g as f64,
                ];
                render_sphere(f(p)?.as_ref(), &opts.sphere)
            })
            .collect::<Result<_>>()?;
        let bg = Image::new(g * ts, g * ts, [0.02; 3]);
        img.blit(&bg, ox, margin as i64);
        for ((i, j), th) in cells.iter().zip(&thumbs) {
            img.blit(th, ox + (i * ts) as i64, (margin + j * ts) as i64);
        }
        let title = font::fit("PREDICTED MATERIALS (SAME EXTENT)", g * ts, 1);
        img.text(ox, 8, &title, 1, black);
    }
    Ok(img)
}
