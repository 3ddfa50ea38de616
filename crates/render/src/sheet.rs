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
use crate::sphere::{SphereOptions, render_spheres};

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

/// Checks the top `max` of a Delta E scale: positive and finite (0 coloured every value as
/// the top, or NaN as the bottom, without a word).
fn check_delta_e_scale(max: f64) -> Result<()> {
    if max.is_finite() && max > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidArgument {
            reason: format!("Delta E scale {max} must be positive and finite"),
        })
    }
}

/// A Delta E map as a heat-map image (0 -> dark, `max` and above -> bright yellow; undefined
/// pixels transparent). `map` holds whole rows of `width` pixels (a partial row, or a width of
/// 0 with values, indexed past the image and panicked); `max` is positive and finite.
pub fn heat_map(map: &[Option<f64>], width: usize, max: f64) -> Result<Image> {
    check_delta_e_scale(max)?;
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

/// The spheres of every row's sources, row by row: all rendered in one [`render_spheres`]
/// (predictions of one model, in any row, evaluate their cells together); the first error in
/// reading order, if any.
fn render_rows(rows: &[SheetRow<'_>], opts: &SphereOptions) -> Result<Vec<Vec<Image>>> {
    let all: Vec<&dyn BrdfSource> = rows.iter().flat_map(|(_, r)| r.iter().copied()).collect();
    let mut images = render_spheres(&all, opts).into_iter();
    rows.iter()
        .map(|(_, r)| images.by_ref().take(r.len()).collect())
        .collect()
}

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
    check_delta_e_scale(de_max)?;
    let s = opts.size;
    let label_w = label_width(rows);
    // The colour bar under the heat maps spans their C - 1 cells and is at least 60 px wide:
    // small spheres get a sheet wide enough for it (it ran off the image, and its top label with
    // it). The sheet is the label, C sphere cells and the bar, so never narrower than 2 C - 1
    // cells.
    let bar_w = ((columns.len() - 1) * (s + PAD)).max(60);
    let width = label_w + PAD + columns.len() * (s + PAD) + bar_w + PAD;
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
    for (r, ((label, _), renders)) in rows.iter().zip(render_rows(rows, opts)?).enumerate() {
        let y = (header + r * row_h) as i64;
        img.text(PAD as i64, y + (s / 2) as i64 - 3, label, 1, TEXT);
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
    for (r, ((label, _), renders)) in rows.iter().zip(render_rows(rows, opts)?).enumerate() {
        let y = (PAD + r * row_h) as i64;
        img.text(PAD as i64, y + (s / 2) as i64 - 3, label, 1, TEXT);
        for (c, sphere) in renders.iter().enumerate() {
            img.blit(sphere, cell_x(c), y);
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

#[cfg(test)]
mod tests {
    use brdf_io::{Channels, Vec3};

    use super::*;
    use crate::sphere::render_sphere;

    /// A grey Lambertian reflector of albedo `rho` (RGB).
    struct Grey(f64);

    impl BrdfSource for Grey {
        fn channels(&self) -> Channels {
            Channels::Rgb
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
            let up = wi[2] > 0.0 && wo[2] > 0.0;
            out.fill(if up {
                self.0 / std::f64::consts::PI
            } else {
                0.0
            });
            Ok(())
        }
    }

    fn opts(size: usize) -> SphereOptions {
        SphereOptions {
            size,
            ..SphereOptions::default()
        }
    }

    /// An opaque image of the given colour and per-pixel coverage.
    fn covered(width: usize, rgb: [f64; 3], alpha: &[f64]) -> Image {
        let mut img = Image::new(width, alpha.len() / width, rgb);
        img.alpha = alpha.to_vec();
        img
    }

    #[test]
    fn delta_e_maps_need_equal_sizes() {
        let a = Image::new(2, 1, [0.5; 3]);
        for b in [Image::new(1, 1, [0.5; 3]), Image::new(2, 2, [0.5; 3])] {
            let err = delta_e_map(&a, &b).unwrap_err().to_string();
            let want = format!("images differ in size: 2x1 vs {}x{}", b.width, b.height);
            assert!(err.contains(&want), "{err}");
        }
    }

    #[test]
    fn delta_e_maps_compare_pixels_both_renderings_cover() {
        // Black against white: L* 0 against 100 with a* = b* = 0, where CIEDE2000's S_L is 1
        // (mean L* 50), so Delta E 00 = 100.
        let a = covered(5, [0.0; 3], &[1.0, 0.999, 0.998, 1.0, 0.0]);
        let b = covered(5, [1.0; 3], &[1.0, 1.0, 1.0, 0.5, 1.0]);
        let map = delta_e_map(&a, &b).unwrap();
        assert_eq!(map.len(), 5);
        // Pixels 0 and 1 are covered in both (alpha >= 0.999); 2 to 4 in one at most.
        assert!((map[0].unwrap() - 100.0).abs() < 1e-9, "{map:?}");
        assert!((map[1].unwrap() - 100.0).abs() < 1e-9, "{map:?}");
        assert_eq!(map[2..], [None, None, None]);
        // Negative and non-finite colours count as 0: the same as black.
        let mut bad = Image::new(3, 1, [0.0; 3]);
        bad.rgb = vec![[-1.0, 0.0, 0.0], [f64::NAN, f64::INFINITY, -0.5], [0.0; 3]];
        let map = delta_e_map(&bad, &Image::new(3, 1, [0.0; 3])).unwrap();
        assert_eq!(map, [Some(0.0); 3]);
    }

    #[test]
    fn mean_delta_e_averages_the_defined_values() {
        assert_eq!(mean_delta_e(&[Some(1.0), None, Some(4.0)]), 2.5);
        assert_eq!(mean_delta_e(&[Some(3.0)]), 3.0);
        assert!(mean_delta_e(&[None, None]).is_nan());
        assert!(mean_delta_e(&[]).is_nan());
    }

    #[test]
    fn heat_maps_colour_values_on_the_ramp_scaled_by_max() {
        let map = [
            Some(0.0),
            Some(5.0),
            Some(10.0),
            None,
            Some(20.0),
            Some(2.5),
        ];
        let img = heat_map(&map, 3, 10.0).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        // Value / max on the ramp; above max the ramp's end; undefined transparent.
        let want = [
            ramp(0.0),
            ramp(0.5),
            ramp(1.0),
            [0.0; 3],
            ramp(1.0),
            ramp(0.25),
        ];
        assert_eq!(img.rgb, want);
        assert_eq!(img.alpha, [1.0, 1.0, 1.0, 0.0, 1.0, 1.0]);
        // On the smallest positive scale every value above 0 is past the top (1 / 5e-324
        // overflows to infinity): the ramp's end, not its start.
        let img = heat_map(&[Some(0.0), Some(1.0)], 2, 5e-324).unwrap();
        assert_eq!(img.rgb, [ramp(0.0), ramp(1.0)]);
    }

    #[test]
    fn heat_maps_refuse_a_scale_that_is_not_positive_and_finite() {
        // A scale of 0 drew every value above 0 as the top and 0 itself (0 / 0 = NaN) as the
        // bottom; a negative one swapped the ends; NaN coloured everything as 0.
        let map = [Some(0.0), Some(1.0)];
        for max in [0.0, -0.0, -1.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let err = heat_map(&map, 2, max).unwrap_err().to_string();
            assert!(
                err.contains(&format!("Delta E scale {max} must be positive and finite")),
                "{max}: {err}"
            );
        }
    }

    #[test]
    fn heat_map_rims_take_the_nearest_covered_value_at_the_smaller_coverage() {
        // 4 x 3 pixels; `a` covers everything, `b` fades out to the right and bottom:
        //   b alpha   1    1    0.5   0        map  0  2  -  -
        //             1    1    0.25  0.75          4  6  -  -
        //             0    0.6  0     0             -  -  -  -
        let a = Image::new(4, 3, [0.5; 3]);
        #[rustfmt::skip]
        let b = covered(4, [0.5; 3], &[
            1.0, 1.0, 0.5, 0.0,
            1.0, 1.0, 0.25, 0.75,
            0.0, 0.6, 0.0, 0.0,
        ]);
        let n = None;
        #[rustfmt::skip]
        let map = [
            Some(0.0), Some(2.0), n, n,
            Some(4.0), Some(6.0), n, n,
            n, n, n, n,
        ];
        let img = heat_map_covered(&map, &a, &b, 8.0).unwrap();
        // Partly covered pixels, their nearest defined pixel (squared distance) and value:
        // (2, 0): (1, 0) at 1, 2; (2, 1): (1, 1) at 1, 6; (3, 1): (1, 1) at 4 (the nearest,
        // (1, 0), is at 5), 6; (1, 2): (1, 1) at 1 ((0, 1) is at 2), 6. Pixels neither covers
        // stay transparent black.
        let mut want = Image::new(4, 3, [0.0; 3]);
        want.alpha = vec![0.0; 12];
        for (i, d, alpha) in [
            (0, 0.0, 1.0),
            (1, 2.0, 1.0),
            (4, 4.0, 1.0),
            (5, 6.0, 1.0),
            (2, 2.0, 0.5),
            (6, 6.0, 0.25),
            (7, 6.0, 0.75),
            (9, 6.0, 0.6),
        ] {
            want.rgb[i] = ramp(d / 8.0);
            want.alpha[i] = alpha;
        }
        assert_eq!(img, want);
        // Defined pixels keep full coverage where the renderings cover just under 1.
        let a = covered(2, [0.5; 3], &[0.9995, 1.0]);
        let img = heat_map_covered(&[Some(4.0), Some(8.0)], &a, &a, 8.0).unwrap();
        assert_eq!(
            (img.rgb, img.alpha),
            (vec![ramp(0.5), ramp(1.0)], vec![1.0, 1.0])
        );
        // A partly covered pixel with no defined pixel within 2 stays transparent.
        let b = covered(4, [0.5; 3], &[1.0, 0.0, 0.0, 0.5]);
        let img =
            heat_map_covered(&[Some(1.0), n, n, n], &Image::new(4, 1, [0.5; 3]), &b, 8.0).unwrap();
        assert_eq!(img.alpha, [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn label_columns_fit_the_widest_label_at_least_40_pixels_plus_a_gap() {
        fn rows<'a>(g: &'a dyn BrdfSource, labels: &[&str]) -> Vec<SheetRow<'a>> {
            labels.iter().map(|l| (l.to_string(), vec![g])).collect()
        }
        let g = Grey(0.5);
        // Text is 6 px a character less the last gap: "AB" 11, 10 characters 59.
        assert_eq!(label_width(&rows(&g, &[])), 48);
        assert_eq!(label_width(&rows(&g, &["AB"])), 48);
        assert_eq!(label_width(&rows(&g, &["AB", "ABCDEFGHIJ", "X"])), 67);
    }

    /// The heat map of two identical renderings: value 0 wherever the rendering covers a pixel,
    /// at its coverage (1 where it is at least 0.999).
    fn zero_heat(render: &Image) -> Image {
        let mut heat = render.clone();
        for (p, a) in heat.rgb.iter_mut().zip(heat.alpha.iter_mut()) {
            if *a >= 0.999 {
                *a = 1.0;
            }
            *p = if *a > 0.0 { ramp(0.0) } else { [0.0; 3] };
        }
        heat
    }

    #[test]
    fn a_two_column_sheet_of_small_spheres_is_laid_out_to_the_pixel() {
        // 16 px spheres, one row labelled "R": label column max(5, 40) + 8 = 48; cells of
        // 16 + 8 from x = 56 (56, 80, 104); the colour bar (60 px: wider than one 24 px cell)
        // sets the width: 56 + 2 x 24 + 60 + 8 = 172. Header 8 + 11 = 19, a row 16 + 11 + 8 =
        // 35, the bar and its labels 2 x 11 + 2 x 8: height 19 + 35 + 38 = 92.
        let g = Grey(0.5);
        let rows = vec![("R".to_string(), vec![&g as &dyn BrdfSource, &g])];
        let sheet = comparison_sheet(&["A", "B"], &rows, &opts(16), 10.0).unwrap();
        assert_eq!(sheet.mean_delta_e, [[0.0]]);
        let sphere = render_sphere(&g, &opts(16)).unwrap();
        let mut want = Image::new(172, 92, BACKGROUND);
        want.text(56, 8, "A", 1, TEXT);
        want.text(80, 8, "B", 1, TEXT);
        // "DE00 B" cut to the 2 characters that fit 16 px.
        want.text(104, 8, "DE", 1, TEXT);
        // The label, centred on the sphere: y = 19 + 16 / 2 - 3.
        want.text(8, 24, "R", 1, TEXT);
        want.blit(&sphere, 56, 19);
        want.blit(&sphere, 80, 19);
        want.blit(&zero_heat(&sphere), 104, 19);
        // "MEAN 00.00" (59 px) does not fit 16 px: the mean alone, 2 px below the map.
        want.text(104, 37, "0.0", 1, TEXT);
        // The bar 8 px below the row (y = 62), 11 px high, from 0 to 1 over its 60 columns.
        for i in 0..60 {
            want.fill_rect(104 + i, 62, 1, 11, ramp(i as f64 / 59.0));
        }
        // Its labels 2 px below it (y = 75): "0" 12 px left of it, "10" (11 px) ending at its
        // right end (x = 104 + 60 - 11); its name (53 px) 8 px left of it, 2 px below its top.
        want.text(92, 75, "0", 1, TEXT);
        want.text(153, 75, "10", 1, TEXT);
        want.text(43, 64, "CIEDE2000", 1, TEXT);
        assert_eq!(sheet.image, want);
    }

    #[test]
    fn a_three_column_two_row_sheet_places_every_map_and_mean() {
        // 64 px spheres; labels "LONGLABEL" (53 px) and "X": label column 53 + 8 = 61. Five cells of 64 + 8 from x = 69 (69, 141, 213, 285,
        // 357); the bar spans the two map cells (144 px): width 69 + 5 x 72 + 8 = 437. Rows of
        // 64 + 11 + 8 = 83 from y = 19: height 19 + 2 x 83 + 38 = 223.
        let (dark, light) = (Grey(0.2), Grey(0.8));
        let rows = vec![
            (
                "LONGLABEL".to_string(),
                vec![&dark as &dyn BrdfSource, &dark, &light],
            ),
            (
                "X".to_string(),
                vec![&light as &dyn BrdfSource, &dark, &light],
            ),
        ];
        let sheet = comparison_sheet(&["M", "E", "S"], &rows, &opts(64), 10.0).unwrap();
        let (d, l) = (
            render_sphere(&dark, &opts(64)).unwrap(),
            render_sphere(&light, &opts(64)).unwrap(),
        );
        let dl = delta_e_map(&d, &l).unwrap();
        let ld = delta_e_map(&l, &d).unwrap();
        // Every column after the first against the first: 0 for the same material.
        let (m_dl, m_ld) = (mean_delta_e(&dl), mean_delta_e(&ld));
        assert!(m_dl > 1.0 && m_ld > 1.0, "{m_dl} {m_ld}");
        assert_eq!(sheet.mean_delta_e, [[0.0, m_dl], [m_ld, 0.0]]);

        let mut want = Image::new(437, 223, BACKGROUND);
        for (x, t) in [
            (69, "M"),
            (141, "E"),
            (213, "S"),
            (285, "DE00 E"),
            (357, "DE00 S"),
        ] {
            want.text(x, 8, t, 1, TEXT);
        }
        // Row 0 at y = 19, its label at 19 + 32 - 3; its means 2 px below the maps, in full
        // ("MEAN 00.00" is 59 px, within 64).
        want.text(8, 48, "LONGLABEL", 1, TEXT);
        want.blit(&d, 69, 19);
        want.blit(&d, 141, 19);
        want.blit(&l, 213, 19);
        want.blit(&zero_heat(&d), 285, 19);
        want.text(285, 85, "MEAN 0.00", 1, TEXT);
        want.blit(&heat_map_covered(&dl, &d, &l, 10.0).unwrap(), 357, 19);
        want.text(357, 85, &format!("MEAN {m_dl:.2}"), 1, TEXT);
        // Row 1 at y = 19 + 83 = 102.
        want.text(8, 131, "X", 1, TEXT);
        want.blit(&l, 69, 102);
        want.blit(&d, 141, 102);
        want.blit(&l, 213, 102);
        want.blit(&heat_map_covered(&ld, &l, &d, 10.0).unwrap(), 285, 102);
        want.text(285, 168, &format!("MEAN {m_ld:.2}"), 1, TEXT);
        want.blit(&zero_heat(&l), 357, 102);
        want.text(357, 168, "MEAN 0.00", 1, TEXT);
        // The bar at y = 19 + 2 x 83 + 8 = 193 under the two maps (x = 285, 144 px).
        for i in 0..144 {
            want.fill_rect(285 + i, 193, 1, 11, ramp(i as f64 / 143.0));
        }
        want.text(273, 206, "0", 1, TEXT);
        want.text(285 + 144 - 11, 206, "10", 1, TEXT);
        want.text(285 - 8 - 53, 195, "CIEDE2000", 1, TEXT);
        assert_eq!(sheet.image, want);
    }

    #[test]
    fn comparison_sheets_refuse_bad_columns_and_scales() {
        let g = Grey(0.5);
        let two = vec![("R".to_string(), vec![&g as &dyn BrdfSource, &g])];
        let three = vec![("R".to_string(), vec![&g as &dyn BrdfSource, &g, &g])];
        for (columns, rows) in [
            (&["A"][..], &two),
            (&[][..], &two),
            (&["A", "B", "C"][..], &two),
            (&["A", "B"][..], &three),
        ] {
            let err = comparison_sheet(columns, rows, &opts(8), 10.0).unwrap_err();
            assert!(
                err.to_string().contains(">= 2 columns"),
                "{columns:?}: {err}"
            );
        }
        for de_max in [0.0, -1.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let err = comparison_sheet(&["A", "B"], &two, &opts(8), de_max).unwrap_err();
            assert!(
                err.to_string().contains("must be positive"),
                "{de_max}: {err}"
            );
        }
    }

    #[test]
    fn sphere_rows_place_spheres_labels_and_centred_captions() {
        // 16 px spheres; rows "A" (2 spheres) and "B" (1): label column 48; 2 cells of
        // 16 + 8 from x = 56: width 56 + 48 + 8 = 112. Rows of 16 + 8 from y = 8, captions
        // (one line, 11 px) below: height 8 + 48 + 11 + 8 = 75.
        let (g, h) = (Grey(0.5), Grey(0.9));
        let rows = vec![
            ("A".to_string(), vec![&g as &dyn BrdfSource, &h]),
            ("B".to_string(), vec![&h as &dyn BrdfSource]),
        ];
        let (sg, sh) = (
            render_sphere(&g, &opts(16)).unwrap(),
            render_sphere(&h, &opts(16)).unwrap(),
        );
        let caps = ["1", "23", "X"].map(String::from);
        let img = sphere_rows(&rows, &caps, &opts(16)).unwrap();
        let mut want = Image::new(112, 75, BACKGROUND);
        want.text(8, 13, "A", 1, TEXT);
        want.blit(&sg, 56, 8);
        want.blit(&sh, 80, 8);
        want.text(8, 37, "B", 1, TEXT);
        want.blit(&sh, 56, 32);
        // Captions at y = 56, centred in their 16 px cells: "1" (5 px) at +5, "23" (11 px)
        // at +2; a caption past the last column is left out.
        want.text(61, 56, "1", 1, TEXT);
        want.text(82, 56, "23", 1, TEXT);
        assert_eq!(img, want);
        // Without captions no caption line.
        let img = sphere_rows(&rows, &[], &opts(16)).unwrap();
        assert_eq!((img.width, img.height), (112, 64));
        assert_eq!(img.rgb[..112 * 56], want.rgb[..112 * 56]);
        assert!(img.rgb[112 * 56..].iter().all(|&p| p == BACKGROUND));
        // Nothing to draw: an error.
        let nothing: [Vec<SheetRow<'_>>; 2] = [vec![], vec![("A".to_string(), vec![])]];
        for rows in nothing {
            let err = sphere_rows(&rows, &caps, &opts(16)).unwrap_err();
            assert!(err.to_string().contains("no spheres"), "{err}");
        }
    }

    #[test]
    fn path_comparisons_are_the_two_paths_as_rows_captioned_by_t() {
        let (g, h) = (Grey(0.3), Grey(0.7));
        let (gp, lin): (Vec<&dyn BrdfSource>, Vec<&dyn BrdfSource>) = (vec![&g, &h], vec![&h, &g]);
        let img = path_comparison(&gp, &lin, &[0.0, 0.5], &opts(32)).unwrap();
        let rows = vec![
            ("GP PATH".to_string(), gp.clone()),
            ("LINEAR".to_string(), lin.clone()),
        ];
        let want = sphere_rows(&rows, &["0.00".into(), "0.50".into()], &opts(32)).unwrap();
        assert_eq!(img, want);
        for (a, b, t) in [
            (&gp[..1], &lin[..], &[0.0, 0.5][..]),
            (&gp[..], &lin[..1], &[0.0, 0.5][..]),
            (&gp[..], &lin[..], &[0.0][..]),
        ] {
            let err = path_comparison(a, b, t, &opts(32)).unwrap_err().to_string();
            let want = format!(
                "paths of {} and {} materials with {} parameters",
                a.len(),
                b.len(),
                t.len()
            );
            assert!(err.contains(&want), "{err}");
        }
    }
}
