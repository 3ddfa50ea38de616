//! Comparison sheets (the paper's Figs. 4.2 and 4.4): rows of sphere renderings of several
//! sources, Delta E 2000 heat maps against a reference column, and sphere strips along paths.
//!
//! Everything is generic over [`BrdfSource`], so measured materials, exact and smooth
//! reconstructions, GP-path and linear-interpolation materials all plug in alike.

use brdf_io::BrdfSource;

use crate::colour::delta_e_2000_rgb;
use crate::error::{Error, Result};
use crate::font;
use crate::image::{Image, ramp};
use crate::sphere::{SphereOptions, render_sphere};

/// Background of sheets (linear grey).
const BACKGROUND: [f64; 3] = [0.02; 3];
/// Text colour (linear).
const TEXT: [f64; 3] = [0.85; 3];
/// Margin around cells, pixels.
const PAD: usize = 8;
/// Height of a text line at scale 1 plus spacing.
const LINE: usize = font::GLYPH_H + 4;

/// Per-pixel CIEDE2000 between two renderings of the same size: a value per pixel covered in
/// both (alpha >= 0.999), `None` elsewhere.
pub fn delta_e_map(a: &Image, b: &Image) -> Result<Vec<Option<f64>>> {
    if a.width != b.width || a.height != b.height {
        return Err(Error::InvalidArgument {
            reason: format!(
                "images differ in size: {}x{} vs {}x{}",
                a.width, a.height, b.width, b.height
            ),
        });
    }
    let clamp = |p: [f64; 3]| p.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 });
    Ok((0..a.rgb.len())
        .map(|i| {
            (a.alpha[i] >= 0.999 && b.alpha[i] >= 0.999)
                .then(|| delta_e_2000_rgb(clamp(a.rgb[i]), clamp(b.rgb[i])))
        })
        .collect())
}

/// Mean of the defined values of a Delta E map (NaN when none is defined).
pub fn mean_delta_e(map: &[Option<f64>]) -> f64 {
    let v: Vec<f64> = map.iter().flatten().copied().collect();
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// A Delta E map as a heat-map image (0 -> dark, `max` and above -> bright yellow; undefined
/// pixels transparent). `map` holds whole rows of `width` pixels (a partial row, or a width of
/// 0 with values, indexed past the image and panicked).
pub fn heat_map(map: &[Option<f64>], width: usize, max: f64) -> Result<Image> {
    if !map.len().is_multiple_of(width) {
        return Err(Error::InvalidArgument {
            reason: format!(
                "a heat map of {} values is not made of rows of {width} pixels",
                map.len()
            ),
        });
    }
    let height = map.len().checked_div(width).unwrap_or(0);
    let mut img = Image::new(width, height, [0.0; 3]);
    for (i, v) in map.iter().enumerate() {
        match v {
            Some(d) => img.rgb[i] = ramp(d / max),
            None => img.alpha[i] = 0.0,
        }
    }
    Ok(img)
}

/// [`heat_map`] with an anti-aliased rim: a pixel both renderings cover only in part (the
/// sphere's edge, where [`delta_e_map`] defines no value) takes the value of a covered pixel
/// next to it (the nearest within 2 pixels) at the smaller of their coverages (the maps' edges
/// were a hard staircase beside the anti-aliased spheres).
fn heat_map_covered(map: &[Option<f64>], a: &Image, b: &Image, max: f64) -> Result<Image> {
    let (w, h) = (a.width, a.height);
    let mut img = heat_map(map, w, max)?;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let coverage = a.alpha[i].min(b.alpha[i]);
            if map[i].is_some() || coverage <= 0.0 {
                continue;
            }
            let near = (-2i64..=2)
                .flat_map(|dy| (-2i64..=2).map(move |dx| (dx, dy)))
                .filter_map(|(dx, dy)| {
                    let (u, v) = (x as i64 + dx, y as i64 + dy);
                    if !((0..w as i64).contains(&u) && (0..h as i64).contains(&v)) {
                        return None;
                    }
                    map[v as usize * w + u as usize].map(|d| (dx * dx + dy * dy, d))
                })
                .min_by_key(|&(r2, _)| r2);
            if let Some((_, d)) = near {
                img.rgb[i] = ramp(d / max);
                img.alpha[i] = coverage.min(1.0);
            }
        }
    }
    Ok(img)
}

/// A rendered comparison sheet and its numbers.
#[derive(Debug, Clone)]
pub struct ComparisonSheet {
    /// The picture (opaque, linear sRGB).
    pub image: Image,
    /// Per row, per compared column (columns 1..), the mean CIEDE2000 against column 0.
    pub mean_delta_e: Vec<Vec<f64>>,
}

/// One row of a sheet: a label and its sources, one per column.
pub type SheetRow<'a> = (String, Vec<&'a dyn BrdfSource>);

/// Width of the label column of a sheet: the widest row label (at least 40 pixels) and a gap
/// before the first sphere (labels ran into it).
fn label_width(rows: &[SheetRow<'_>]) -> usize {
    rows.iter()
        .map(|(l, _)| font::text_width(l, 1))
        .max()
        .unwrap_or(0)
        .max(40)
        + PAD
}

/// Measured vs reconstructions: for every row, the spheres of all columns, then a CIEDE2000
/// heat map of every column after the first against the first (scale 0..`de_max`), with its
/// mean printed below; a colour bar at the bottom. `columns` labels the sphere columns (e.g.
/// `["measured", "exact", "smooth"]`).
pub fn comparison_sheet(
    columns: &[&str],
    rows: &[SheetRow<'_>],
    opts: &SphereOptions,
    de_max: f64,
) -> Result<ComparisonSheet> {
    if columns.len() < 2 || rows.iter().any(|(_, r)| r.len() != columns.len()) {
        return Err(Error::InvalidArgument {
            reason: format!(
                "a comparison sheet needs >= 2 columns and every row with {} sources",
                columns.len()
            ),
        });
    }
    if !(de_max.is_finite() && de_max > 0.0) {
        return Err(Error::InvalidArgument {
            reason: format!("Delta E scale {de_max} must be positive"),
        });
    }
    let s = opts.size;
    let n_cells = 2 * columns.len() - 1;
    let label_w = label_width(rows);
    // The colour bar under the heat maps is at least 60 px wide: small spheres get a sheet wide
    // enough for it (it ran off the image, and its top label with it).
    let bar_w = ((columns.len() - 1) * (s + PAD)).max(60);
    let width = (label_w + PAD + n_cells * (s + PAD) + PAD)
        .max(label_w + PAD + columns.len() * (s + PAD) + bar_w + PAD);
    let header = PAD + LINE;
    let row_h = s + LINE + PAD;
    let height = header + rows.len() * row_h + LINE * 2 + PAD * 2;
    let mut img = Image::new(width, height, BACKGROUND);
    let cell_x = |c: usize| (label_w + PAD + c * (s + PAD)) as i64;
    for (c, name) in columns.iter().enumerate() {
        img.text(cell_x(c), PAD as i64, &font::fit(name, s, 1), 1, TEXT);
    }
    for (c, name) in columns.iter().enumerate().skip(1) {
        let t = format!("DE00 {name}");
        img.text(
            cell_x(columns.len() + c - 1),
            PAD as i64,
            &font::fit(&t, s, 1),
            1,
            TEXT,
        );
    }
    let mut means = Vec::new();
    for (r, (label, sources)) in rows.iter().enumerate() {
        let y = (header + r * row_h) as i64;
        img.text(PAD as i64, y + (s / 2) as i64 - 3, label, 1, TEXT);
        let renders = sources
            .iter()
            .map(|src| render_sphere(*src, opts))
            .collect::<Result<Vec<_>>>()?;
        for (c, r_img) in renders.iter().enumerate() {
            img.blit(r_img, cell_x(c), y);
        }
        let mut row_means = Vec::new();
        for (c, r_img) in renders.iter().enumerate().skip(1) {
            let map = delta_e_map(&renders[0], r_img)?;
            let mean = mean_delta_e(&map);
            let x = cell_x(columns.len() + c - 1);
            img.blit(&heat_map_covered(&map, &renders[0], r_img, de_max)?, x, y);
            let t = if font::text_width("MEAN 00.00", 1) <= s {
                format!("MEAN {mean:.2}")
            } else {
                format!("{mean:.1}")
            };
            img.text(x, y + s as i64 + 2, &t, 1, TEXT);
            row_means.push(mean);
        }
        means.push(row_means);
    }
    // Colour bar.
    let y = (header + rows.len() * row_h + PAD) as i64;
    let x0 = cell_x(columns.len());
    for i in 0..bar_w {
        let col = ramp(i as f64 / (bar_w - 1).max(1) as f64);
        img.fill_rect(x0 + i as i64, y, 1, LINE, col);
    }
    img.text(x0 - 12, y + LINE as i64 + 2, "0", 1, TEXT);
    // The scale's top, plainly where it fits the bar (a Delta E scale of 1e300 was 301 digits
    // drawn from far left of the image across the bar's name and its "0").
    let top = [
        format!("{de_max}"),
        format!("{de_max:.3e}"),
        format!("{de_max:.0e}"),
    ]
    .into_iter()
    .find(|t| font::text_width(t, 1) <= bar_w)
    .unwrap_or_default();
    img.text(
        x0 + bar_w as i64 - font::text_width(&top, 1) as i64,
        y + LINE as i64 + 2,
        &top,
        1,
        TEXT,
    );
    // The scale's name beside it (at the sheet's left edge it sat hundreds of pixels away).
    let name_x = x0 - 8 - font::text_width("CIEDE2000", 1) as i64;
    img.text(name_x.max(PAD as i64), y + 2, "CIEDE2000", 1, TEXT);
    Ok(ComparisonSheet {
        image: img,
        mean_delta_e: means,
    })
}

/// Rows of spheres with a label per row and optional captions per column (e.g. a GP path and a
/// linear-interpolation path between two materials, captions = the path parameter).
pub fn sphere_rows(
    rows: &[SheetRow<'_>],
    captions: &[String],
    opts: &SphereOptions,
) -> Result<Image> {
    let s = opts.size;
    let n = rows.iter().map(|(_, r)| r.len()).max().unwrap_or(0);
    if n == 0 {
        return Err(Error::InvalidArgument {
            reason: "no spheres to draw".into(),
        });
    }
    let label_w = label_width(rows);
    let row_h = s + PAD;
    let cap_h = if captions.is_empty() { 0 } else { LINE };
    let width = label_w + PAD + n * (s + PAD) + PAD;
    let height = PAD + rows.len() * row_h + cap_h + PAD;
    let mut img = Image::new(width, height, BACKGROUND);
    let cell_x = |c: usize| (label_w + PAD + c * (s + PAD)) as i64;
    for (r, (label, sources)) in rows.iter().enumerate() {
        let y = (PAD + r * row_h) as i64;
        img.text(PAD as i64, y + (s / 2) as i64 - 3, label, 1, TEXT);
        for (c, src) in sources.iter().enumerate() {
            img.blit(&render_sphere(*src, opts)?, cell_x(c), y);
        }
    }
    let y = (PAD + rows.len() * row_h) as i64;
    for (c, cap) in captions.iter().enumerate().take(n) {
        let cap = font::fit(cap, s, 1);
        let w = font::text_width(&cap, 1) as i64;
        img.text(cell_x(c) + (s as i64 - w) / 2, y, &cap, 1, TEXT);
    }
    Ok(img)
}

/// The paper's Fig. 4.4: spheres along the GP path (top row) and along the linear
/// interpolation (bottom row) between two materials, captioned by the path parameter `t`.
pub fn path_comparison(
    gp_path: &[&dyn BrdfSource],
    linear_path: &[&dyn BrdfSource],
    t: &[f64],
    opts: &SphereOptions,
) -> Result<Image> {
    if gp_path.len() != linear_path.len() || t.len() != gp_path.len() {
        return Err(Error::InvalidArgument {
            reason: format!(
                "paths of {} and {} materials with {} parameters",
                gp_path.len(),
                linear_path.len(),
                t.len()
            ),
        });
    }
    let rows = vec![
        ("GP PATH".to_string(), gp_path.to_vec()),
        ("LINEAR".to_string(), linear_path.to_vec()),
    ];
    let caps: Vec<String> = t.iter().map(|v| format!("{v:.2}")).collect();
    sphere_rows(&rows, &caps, opts)
}
