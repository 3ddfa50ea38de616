//! Comparison sheets and latent maps on synthetic materials. Set `RENDER_TEST_OUT=DIR` to keep
//! the pictures for a look.

use brdf_io::{BrdfSource, Channels, Vec3};
use render::sphere::SphereOptions;
use render::{MapOptions, comparison_sheet, latent_map, path_comparison};

type Synth = brdf_synth::PreparedMaterial;

/// `a` x first + (1 - a) x second, channel by channel.
struct Mix<'a>(&'a dyn BrdfSource, &'a dyn BrdfSource, f64);

impl BrdfSource for Mix<'_> {
    fn channels(&self) -> Channels {
        self.0.channels()
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        let mut b = vec![0.0; out.len()];
        self.0.eval(wi, wo, out)?;
        self.1.eval(wi, wo, &mut b)?;
        for (o, v) in out.iter_mut().zip(b) {
            *o = self.2 * *o + (1.0 - self.2) * v;
        }
        Ok(())
    }
}

fn synth(name: &str) -> Synth {
    let wl: Vec<f64> = (360..=1000).step_by(20).map(f64::from).collect();
    brdf_synth::preset_material(name, 0).unwrap().prepare(&wl)
}

fn keep(img: &render::Image, name: &str) {
    if let Some(dir) = std::env::var_os("RENDER_TEST_OUT") {
        img.save_png(&std::path::Path::new(&dir).join(name))
            .unwrap();
    }
}

#[test]
fn comparison_sheet_reports_zero_for_identical_and_more_for_different() {
    let red = synth("carpaint_solid_red");
    let gold = synth("metal_gold");
    let near = Mix(&red, &gold, 0.9);
    let opts = SphereOptions {
        size: 40,
        ..SphereOptions::default()
    };
    let rows = vec![
        (
            "RED".to_string(),
            vec![&red as &dyn BrdfSource, &red, &near],
        ),
        (
            "GOLD".to_string(),
            vec![&gold as &dyn BrdfSource, &near, &red],
        ),
    ];
    let sheet = comparison_sheet(&["MEASURED", "EXACT", "SMOOTH"], &rows, &opts, 10.0).unwrap();
    keep(&sheet.image, "sheet.png");
    let m = &sheet.mean_delta_e;
    println!("mean dE00 per row: {m:?}");
    assert_eq!(m[0][0], 0.0, "identical renderings");
    assert!(m[0][1] > 0.5 && m[0][1] < m[1][1], "{m:?}");
    assert!(m[1][1] > 10.0, "red vs gold {m:?}");
    // The colour bar's name sits just left of it: the bar starts at the first heat map's column
    // (x = 56 + 3 x 48 = 200: labels 40 + 8 px, then cells of 40 + 8 px), the name ends 8 px
    // before it (it was at the sheet's left edge, x = 8). Text is light grey on the background.
    let img = &sheet.image;
    let name_w = render::font::text_width("CIEDE2000", 1);
    let bright: Vec<usize> = (img.height - 30..img.height)
        .flat_map(|y| (0..img.width).filter(move |&x| img.get(x, y).iter().all(|c| *c > 0.5)))
        .collect();
    assert!(!bright.is_empty());
    assert!(
        bright.iter().all(|&x| x + 8 + name_w >= 200),
        "text left of the bar's name: {:?}",
        bright.iter().min()
    );
    assert!(comparison_sheet(&["A"], &rows, &opts, 10.0).is_err());
}

#[test]
fn path_comparison_and_map_draw() {
    let a = synth("acrylic_felt_white");
    let b = synth("carpaint_solid_red");
    let t = [0.0, 0.5, 1.0];
    let mixes: Vec<Mix> = t.iter().map(|&x| Mix(&b, &a, x)).collect();
    let path: Vec<&dyn BrdfSource> = mixes.iter().map(|m| m as &dyn BrdfSource).collect();
    let opts = SphereOptions {
        size: 32,
        ..SphereOptions::default()
    };
    let img = path_comparison(&path, &path, &t, &opts).unwrap();
    keep(&img, "path.png");
    // Along the path the spheres get redder: R / G at the sphere centres increases.
    // The label column: the label, at least 40 pixels, and an 8-pixel gap.
    let label_w = render::font::text_width("GP PATH", 1).max(40) + 8;
    let redness: Vec<f64> = (0..3)
        .map(|c| {
            let p = img.get(label_w + 8 + c * (32 + 8) + 16, 8 + 16);
            p[0] / p[1]
        })
        .collect();
    assert!(
        redness[0] < redness[1] && redness[1] < redness[2] && redness[0] < 1.1,
        "{redness:?}"
    );
    assert!(path_comparison(&path[..2], &path, &t, &opts).is_err());

    let points = two_points();
    // The plot's first column, right of the y tick labels.
    let plot_x = render::map::plot_left(&points);
    let var = |p: [f64; 2]| -> render::Result<f64> {
        let d = |q: [f64; 2]| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).min(4.0);
        Ok(d(points[0].1).min(d(points[1].1)))
    };
    let src = |p: [f64; 2]| -> render::Result<Box<dyn BrdfSource + '_>> {
        let x = ((p[0] + 1.0) / 2.0).clamp(0.0, 1.0);
        Ok(Box::new(Mix(&b, &a, x)))
    };
    let mopts = MapOptions {
        size: 160,
        thumbnails: 3,
        sphere: SphereOptions {
            size: 24,
            ..SphereOptions::default()
        },
        variance_samples: 16,
        caption: render::map::variance_caption("log(offset=0.01)", 5),
        predicted_points: 1,
        one_axis: false,
        far_variance: None,
    };
    // Sizes that would need a huge allocation are refused before any work.
    for bad in [
        MapOptions {
            size: 100_000,
            ..mopts.clone()
        },
        MapOptions {
            thumbnails: 100_000,
            ..mopts.clone()
        },
        MapOptions {
            thumbnails: 64,
            sphere: SphereOptions {
                size: 1024,
                ..SphereOptions::default()
            },
            ..mopts.clone()
        },
    ] {
        let err = latent_map(&points, &var, Some(&src), &bad)
            .unwrap_err()
            .to_string();
        assert!(err.contains("8192"), "{err}");
        // The thumbnail case says how large the panel would be.
        if bad.thumbnails == 64 {
            assert!(err.contains("make a panel of 65536 px"), "{err}");
        }
    }
    let map = latent_map(&points, &var, Some(&src), &mopts).unwrap();
    keep(&map, "map.png");
    // Every label found room: no note under the colour bar (rows 250..257, left of the panel).
    let note = (plot_x - 1..plot_x + 200)
        .filter(|&x| (250..257).any(|y| map.get(x, y).iter().all(|c| *c < 0.5)))
        .count();
    assert_eq!(
        note, 0,
        "a note of labels left out on a map that has room for them"
    );
    // The panel is as wide as its title (wider than 3 spheres of 24 px), not cut to a word.
    let title = "PREDICTED MATERIALS OVER THE GREY BOX, ON THE SLICE";
    let title_w = render::font::text_width(title, 1);
    assert!(title_w > 3 * 24);
    assert_eq!(map.width, plot_x + 160 + 40 + title_w + 40);
    let title_ink = (0..title_w)
        .filter(|&x| (8..15).any(|y| map.get(plot_x + 160 + 40 + x, y)[0] < 0.5))
        .count();
    assert!(
        title_ink > title_w / 2,
        "{title_ink} of {title_w} columns inked"
    );
    // Near a point the variance is low (light background), far away high (darker).
    let [x0, x1, y0, y1] = render::map::extent(&points);
    let px = |p: [f64; 2]| {
        let x = plot_x as f64 + (p[0] - x0) / (x1 - x0) * 160.0;
        let y = 40.0 + (y1 - p[1]) / (y1 - y0) * 160.0;
        map.get(x as usize, y as usize)
    };
    let near = px([-1.0, 0.1 + 0.1]);
    let far = px([0.0, y0 + 0.05]);
    assert!(near[0] > far[0] + 0.1, "near {near:?} far {far:?}");
    // The training material is a red dot, the last point (a prediction) a blue ring with a
    // white centre.
    let (dot, red_point) = (px(points[0].1), points[1].1);
    assert!(dot[0] > 0.7 && dot[1] < 0.2 && dot[2] < 0.2, "{dot:?}");
    let centre = px(red_point);
    assert!(centre.iter().all(|c| *c > 0.9), "{centre:?}");
    let ring = {
        let x = plot_x as f64 + (red_point[0] - x0) / (x1 - x0) * 160.0 + 3.0;
        let y = 40.0 + (y1 - red_point[1]) / (y1 - y0) * 160.0;
        map.get(x as usize, y as usize)
    };
    assert!(ring[2] > 0.6 && ring[0] < 0.3, "{ring:?}");
    // The caption line is drawn (grey text under the title).
    let caption_ink = (plot_x..plot_x + 160)
        .flat_map(|x| (20..27).map(move |y| (x, y)))
        .filter(|&(x, y)| map.get(x, y)[0] < 0.5)
        .count();
    assert!(caption_ink > 50, "{caption_ink}");
    // The right panel covers the points' bounding box, x in [-1, 1]: its columns sit at
    // x = -2/3, 0, 2/3, i.e. 1/6, 1/2 and 5/6 of the way to red: nearly white on the left,
    // red on the right.
    assert_eq!(render::map::thumbnail_box(&points), [-1.0, 1.0, 0.0, 0.5]);
    let row = 40 + 24 + 12;
    let left = map.get(plot_x + 160 + 40 + 12, row);
    let right = map.get(plot_x + 160 + 40 + 2 * 24 + 12, row);
    assert!(
        right[0] > 2.0 * right[2] && (left[0] - left[2]).abs() < 0.2 * left[0],
        "{left:?} {right:?}"
    );
    // With a far limit of 0.5 the middle column (x = 0, variance >= 1 there; the others 0.12 to
    // 0.29) is framed in orange (2 px inside each thumbnail), and a note under the panel counts
    // them; without one nothing is framed.
    let far_map = latent_map(
        &points,
        &var,
        Some(&src),
        &MapOptions {
            far_variance: Some(0.5),
            ..mopts.clone()
        },
    )
    .unwrap();
    keep(&far_map, "map_far.png");
    let orange = |m: &render::Image, x: usize, y: usize| {
        let p = m.get(x, y);
        p[0] > 0.9 && (0.3..0.6).contains(&p[1]) && p[2] < 0.1
    };
    let panel_x = plot_x + 160 + 40;
    for j in 0..3 {
        let y = 40 + j * 24 + 12;
        for (i, framed) in [(0, false), (1, true), (2, false)] {
            for dx in [0, 1, 22, 23] {
                let x = panel_x + i * 24 + dx;
                assert_eq!(
                    orange(&far_map, x, y),
                    framed,
                    "thumbnail {i},{j}, column {x}"
                );
                assert!(!orange(&map, x, y), "unframed map, thumbnail {i},{j}");
            }
            // The frame is 2 px wide: the third column in from either side is the sphere's
            // (a frame drawn wider would run into the neighbouring thumbnail).
            for dx in [2, 21] {
                let x = panel_x + i * 24 + dx;
                assert!(!orange(&far_map, x, y), "thumbnail {i},{j}, column {x}");
            }
            // Down the middle of the thumbnail, the same: 2 px of frame at the top and bottom.
            let x = panel_x + i * 24 + 12;
            for dy in [0, 1, 2, 21, 22, 23] {
                let y = 40 + j * 24 + dy;
                let want = framed && ![2, 21].contains(&dy);
                assert_eq!(orange(&far_map, x, y), want, "thumbnail {i},{j}, row {y}");
            }
        }
    }
    let note_ink = |m: &render::Image| {
        (panel_x..panel_x + 72)
            .flat_map(|x| (40 + 72 + 8..40 + 72 + 15).map(move |y| (x, y)))
            .filter(|&(x, y)| m.get(x, y)[0] < 0.5)
            .count()
    };
    assert!(note_ink(&far_map) > 20 && note_ink(&map) == 0);
    // The box is outlined in grey on the map, 6 px outside the points.
    let (bx, by) = (
        plot_x as f64 + (-1.0 - x0) / (x1 - x0) * 160.0 - 6.0,
        40.0 + (y1 - 0.25) / (y1 - y0) * 160.0,
    );
    let edge = map.get(bx as usize, by as usize);
    assert!(edge.iter().all(|c| (c - 0.35).abs() < 1e-9), "{edge:?}");
    // Ticks at round coordinates: a black mark under the frame at x = 0 and left of it at
    // y = 0, none halfway between two ticks.
    let ticks = render::map::nice_ticks(x0, x1, 5);
    assert!(
        ticks.iter().any(|(v, l)| *v == 0.0 && l == "0"),
        "{ticks:?}"
    );
    let (tx, ty) = (
        (plot_x as f64 + (0.0 - x0) / (x1 - x0) * 160.0).round() as usize,
        (40.0 + (y1 - 0.0) / (y1 - y0) * 160.0).round() as usize,
    );
    assert_eq!(map.get(tx, 40 + 160 + 2), [0.0; 3]);
    assert_eq!(map.get(plot_x - 3, ty), [0.0; 3]);
    let step = ticks[1].0 - ticks[0].0;
    let between = (plot_x as f64 + (0.5 * step - x0) / (x1 - x0) * 160.0).round() as usize;
    assert_eq!(map.get(between, 40 + 160 + 2), [1.0; 3]);
}

/// A 64 px map of two points, WHITE at (-1, 0) and RED at (1, 0.5), with a variance of 0.5
/// everywhere, `g` x `g` thumbnails of `ts` px (blends of the two along X1) and the far limit
/// `far`.
fn two_point_map(g: usize, ts: usize, far: Option<f64>) -> render::Image {
    two_point_map_by(g, ts, far, &|p| ((p[0] + 1.0) / 2.0).clamp(0.0, 1.0))
}

/// [`two_point_map`] with thumbnails that blend `red(p)` of RED at the latent point `p`.
fn two_point_map_by(
    g: usize,
    ts: usize,
    far: Option<f64>,
    red: &(dyn Fn([f64; 2]) -> f64 + Sync),
) -> render::Image {
    let (a, b) = (synth("acrylic_felt_white"), synth("carpaint_solid_red"));
    let points = two_points();
    let var = |_: [f64; 2]| -> render::Result<f64> { Ok(0.5) };
    let src = |p: [f64; 2]| -> render::Result<Box<dyn BrdfSource + '_>> {
        Ok(Box::new(Mix(&b, &a, red(p))))
    };
    let opts = MapOptions {
        size: 64,
        thumbnails: g,
        sphere: SphereOptions {
            size: ts,
            ..SphereOptions::default()
        },
        variance_samples: 4,
        far_variance: far,
        ..MapOptions::default()
    };
    latent_map(&points, &var, Some(&src), &opts).unwrap()
}

/// The points of [`two_point_map`].
fn two_points() -> Vec<(String, [f64; 2])> {
    vec![
        ("WHITE".to_string(), [-1.0, 0.0]),
        ("RED".to_string(), [1.0, 0.5]),
    ]
}

/// The first column of [`two_point_map`]'s thumbnail panel: 40 px right of its 64 px plot.
fn two_point_panel_x() -> usize {
    render::map::plot_left(&two_points()) + 64 + 40
}

/// The thumbnails are the materials at the centres of a g x g grid of cells over the points'
/// box ([-1, 1] x [0, 0.5] here), the top row at the largest X2: with materials redder with
/// X2, the top row's spheres are the redder.
#[test]
fn thumbnails_show_the_cell_centres_of_the_grey_box() {
    let points = two_points();
    assert_eq!(render::map::thumbnail_box(&points), [-1.0, 1.0, 0.0, 0.5]);
    let asked = std::sync::Mutex::new(Vec::new());
    let ts = 16;
    let map = two_point_map_by(2, ts, None, &|p| {
        asked.lock().unwrap().push(p);
        p[1] / 0.5
    });
    let mut asked = asked.into_inner().unwrap();
    asked.sort_by(|p, q| p.partial_cmp(q).unwrap());
    assert_eq!(
        asked,
        [[-0.5, 0.125], [-0.5, 0.375], [0.5, 0.125], [0.5, 0.375]]
    );
    let panel_x = two_point_panel_x();
    let redness = |j: usize| {
        let p = map.get(panel_x + ts / 2, 40 + j * ts + ts / 2);
        p[0] / p[1]
    };
    assert!(
        redness(0) > 1.2 * redness(1),
        "{} {}",
        redness(0),
        redness(1)
    );
}

/// The grey box the thumbnails cover is outlined 6 px outside the points' box as a closed
/// one-pixel rectangle (its corners were left open by a pixel where the box's edges fell at
/// different fractions of a pixel), under the labels; a map without thumbnails has none.
#[test]
fn the_thumbnails_box_is_outlined_whole_and_only_with_thumbnails() {
    let points = two_points();
    let left = render::map::plot_left(&points) as f64;
    let [x0, x1, y0, y1] = render::map::extent(&points);
    let [bx0, bx1, by0, by1] = render::map::thumbnail_box(&points);
    // The outline's columns and rows on the 64 px plot.
    let col = |x: f64| (left + (x - x0) / (x1 - x0) * 64.0).floor() as usize;
    let row = |y: f64| (40.0 + (y1 - y) / (y1 - y0) * 64.0).floor() as usize;
    let (c0, c1, r0, r1) = (col(bx0) - 6, col(bx1) + 6, row(by1) - 6, row(by0) + 6);
    let outline: Vec<(usize, usize)> = (c0..=c1)
        .flat_map(|x| [(x, r0), (x, r1)])
        .chain((r0..=r1).flat_map(|y| [(c0, y), (c1, y)]))
        .collect();
    let grey = [0.35; 3];
    // Under a label's box (white at 60 %), or its text.
    let boxed = grey.map(|c| c * (1.0 - 0.6) + 0.6);
    let with = two_point_map(2, 16, None);
    for &(x, y) in &outline {
        let p = with.get(x, y);
        assert!(
            p == grey || p == boxed || p == [0.0; 3],
            "({x}, {y}) of the outline {c0}..={c1} x {r0}..={r1}: {p:?}"
        );
    }
    // The four corners are on it.
    for (x, y) in [(c0, r0), (c1, r0), (c0, r1), (c1, r1)] {
        assert_eq!(with.get(x, y), grey, "corner ({x}, {y})");
    }
    let without = two_point_map(0, 16, None);
    let grey_pixels = (0..without.height)
        .flat_map(|y| (0..without.width).map(move |x| (x, y)))
        .filter(|&(x, y)| [grey, boxed].contains(&without.get(x, y)))
        .count();
    assert_eq!(grey_pixels, 0);
}

/// A thumbnail is framed as far from every material when its variance is above the limit,
/// not at it: a variance of 0.5 everywhere frames every thumbnail under a limit one ulp below
/// 0.5, and none under 0.5 itself.
#[test]
fn thumbnails_are_framed_above_the_far_limit_only() {
    let (g, ts) = (2usize, 16usize);
    let map = |limit: f64| two_point_map(g, ts, Some(limit));
    let panel_x = two_point_panel_x();
    let framed = |m: &render::Image| {
        (0..g * g)
            .filter(|k| {
                let p = m.get(panel_x + (k % g) * ts, 40 + (k / g) * ts + ts / 2);
                p == [1.0, 0.45, 0.0]
            })
            .count()
    };
    let (all, none) = (map(f64::from_bits(0.5f64.to_bits() - 1)), map(0.5));
    assert_eq!(framed(&all), g * g);
    assert_eq!(framed(&none), 0);
    // The note under the panel (8 px under the spheres) counts the framed thumbnails, in its
    // shorter form that ends inside the panel (before the image's 40 px right margin); with
    // none framed there is no note.
    let note_ink = |m: &render::Image| -> Vec<usize> {
        (panel_x..m.width)
            .filter(|&x| (80..87).any(|y| m.get(x, y).iter().all(|c| *c < 0.5)))
            .collect()
    };
    let ink = note_ink(&all);
    let end = render::font::text_width("ORANGE: 4 FAR FROM EVERY MATERIAL", 1);
    assert!(
        ink.len() > end / 2 && *ink.last().unwrap() < panel_x + end,
        "note ink at {ink:?}"
    );
    assert!(all.width >= panel_x + end + 40);
    assert_eq!(note_ink(&none), Vec::<usize>::new());
}

/// A thumbnail panel taller than a small plot makes the image taller (it was cut off at the
/// plot's height: specgp map --size 128 --thumbnails showed 3 of its 6 rows); a one-axis model's
/// panel is one row (its rows repeated the same materials).
#[test]
fn thumbnail_panels_fit_the_image_and_one_axis_maps_have_one_row() {
    let (a, b) = (synth("acrylic_felt_white"), synth("carpaint_solid_red"));
    let points = vec![
        ("WHITE".to_string(), [-1.0, 0.0]),
        ("RED".to_string(), [1.0, 0.0]),
    ];
    let var = |_: [f64; 2]| -> render::Result<f64> { Ok(0.5) };
    let src = |p: [f64; 2]| -> render::Result<Box<dyn BrdfSource + '_>> {
        let x = ((p[0] + 1.0) / 2.0).clamp(0.0, 1.0);
        Ok(Box::new(Mix(&b, &a, x)))
    };
    let opts = MapOptions {
        size: 64,
        thumbnails: 5,
        sphere: SphereOptions {
            size: 32,
            ..SphereOptions::default()
        },
        variance_samples: 4,
        ..MapOptions::default()
    };
    let square = latent_map(&points, &var, Some(&src), &opts).unwrap();
    // 5 rows of 32 px between 40 px margins: 240 px, more than the plot's 64 + 112.
    assert_eq!(square.height, 40 + 5 * 32 + 40);
    // The spheres start 40 px right of the plot (the panel is as wide as its title, wider
    // than the 5 spheres).
    let x0 = render::map::plot_left(&points) + 64 + 40;
    assert!(square.width > x0 + 5 * 32 + 40);
    // The last row is drawn: the bottom sphere's centre is lit, not the white background.
    let last = square.get(x0 + 16, 40 + 4 * 32 + 16);
    assert!(last.iter().all(|c| *c < 0.95), "{last:?}");
    // Around the spheres (transparent in the thumbnails), the panel is dark: every cell's
    // far corner, up to the last row's and column's.
    for k in 0..25 {
        let (x, y) = (x0 + (k % 5) * 32 + 31, 40 + (k / 5) * 32 + 31);
        assert_eq!(square.get(x, y), [0.02; 3], "cell {k}");
    }
    let one = latent_map(
        &points,
        &var,
        Some(&src),
        &MapOptions {
            one_axis: true,
            ..opts.clone()
        },
    )
    .unwrap();
    assert_eq!(one.height, 40 + 64 + 40 + 32);
    // One row of spheres; below it the image's white background.
    let below = one.get(x0 + 16, 40 + 32 + 8);
    assert!(below.iter().all(|c| *c > 0.99), "{below:?}");
    let sphere = one.get(x0 + 16, 40 + 16);
    assert!(sphere.iter().all(|c| *c < 0.95), "{sphere:?}");
}

/// `specgp map --thumbnails --size 128` on 51 materials: the colour bar is drawn left of the
/// thumbnail panel (it was laid out against the whole image's width and drawn under the panel,
/// leaving a lone "0"), the title is shortened at a word before the panel's title (it was cut
/// to "... SHADED BY PRE" and read on into "PREDICTED MATERIALS ..."), and labels that find no
/// free spot stay in the plot (they were put far outside it: over the tick labels, under the
/// panel and off the image's left edge).
#[test]
fn small_maps_with_thumbnails_keep_bar_title_and_labels_in_place() {
    let (a, b) = (synth("acrylic_felt_white"), synth("carpaint_solid_red"));
    // 51 materials in a 3 x 1 patch, with names of 12 to 26 characters (up to 155 px, wider
    // than the plot).
    let points: Vec<(String, [f64; 2])> = (0..51)
        .map(|k| {
            let t = k as f64;
            let name = format!("MATERIAL_{k:02}_{}", "X".repeat(k % 15));
            (name, [-1.5 + (t * 0.37) % 3.0, -0.5 + (t * 0.61) % 1.0])
        })
        .collect();
    let var = |p: [f64; 2]| -> render::Result<f64> { Ok(0.1 + p[0].abs()) };
    let src = |p: [f64; 2]| -> render::Result<Box<dyn BrdfSource + '_>> {
        let x = ((p[0] + 1.5) / 3.0).clamp(0.0, 1.0);
        Ok(Box::new(Mix(&b, &a, x)))
    };
    let (size, g, ts) = (128usize, 6usize, 32usize);
    let opts = MapOptions {
        size,
        thumbnails: g,
        sphere: SphereOptions {
            size: ts,
            ..SphereOptions::default()
        },
        variance_samples: 8,
        caption: render::map::variance_caption("log(offset=0.01)", 5),
        ..MapOptions::default()
    };
    let map = latent_map(&points, &var, Some(&src), &opts).unwrap();
    keep(&map, "small-map.png");
    // The plot (from x = 40: the y tick labels are narrow), then 40 px before the panel.
    let left = render::map::plot_left(&points);
    assert_eq!(left, 40);
    let panel_x = left + size + 40;
    let dark = |x: usize, y: usize| map.get(x, y).iter().all(|c| *c < 0.3);
    // Colour bar: its deepest blue (shade 1 = (0.05, 0.15, 0.55)) and the largest standard
    // deviation's label are left of the panel, on the bar's rows.
    let bar_y = 40 + size + 34;
    let blue = (0..panel_x)
        .filter(|&x| {
            let c = map.get(x, bar_y + 2);
            (c[0] - 0.05).abs() < 0.02 && (c[2] - 0.55).abs() < 0.02
        })
        .count();
    assert!(
        blue >= 1,
        "no deep blue end of the colour bar left of the panel"
    );
    let bar_end = (0..panel_x)
        .rev()
        .find(|&x| map.get(x, bar_y + 2)[2] > 0.5 && map.get(x, bar_y + 2)[0] < 0.9)
        .unwrap();
    let label_ink = (bar_end + 1..panel_x)
        .filter(|&x| (bar_y..bar_y + 7).any(|y| dark(x, y)))
        .count();
    assert!(
        label_ink >= 10,
        "{label_ink} inked columns of the bar's label"
    );
    // The label ("1.449", 29 px) ends 8 px before the panel (its last column, of a "9", is
    // inked), 10 px after the ramp.
    let label_end = (bar_end + 1..panel_x)
        .rev()
        .find(|&x| (bar_y..bar_y + 7).any(|y| dark(x, y)));
    assert_eq!(label_end, Some(panel_x - 9));
    assert_eq!(bar_end, panel_x - 9 - 29 - 10);
    // Title: "LATENT SPACE" (12 characters from x 39), then nothing up to the panel's title.
    let title_end = 39 + render::font::text_width("LATENT SPACE", 1);
    let title_ink: Vec<usize> = (title_end + 1..panel_x)
        .filter(|&x| (8..15).any(|y| dark(x, y)))
        .collect();
    assert!(title_ink.is_empty(), "title ink at {title_ink:?}");
    assert!((39..title_end).any(|x| (8..15).any(|y| dark(x, y))));
    // Labels: none in the image's first columns (the axis name X2 starts at x = 2) or in the
    // panel's margin (labels wider than the plot stick out on its right, into the 40 px
    // margin), and the y tick labels' column left of the frame holds tick labels only: one run
    // of ink per tick.
    for y in 30..map.height {
        assert!(
            !dark(0, y) && !dark(1, y),
            "label ink at the left edge, row {y}"
        );
        assert!(!dark(panel_x - 2, y), "label ink before the panel, row {y}");
    }
    let tick_rows: Vec<usize> = (40..40 + size).filter(|&y| dark(left - 7, y)).collect();
    let runs = tick_rows.windows(2).filter(|w| w[1] != w[0] + 1).count() + 1;
    assert!(
        runs <= 7,
        "{runs} runs of ink in the tick label column: {tick_rows:?}"
    );
    // Most of the 51 labels find no free spot in 128 px: they are left out (drawn over each
    // other and the dots they hid them), and a grey note under the colour bar counts them.
    let note_y = 40 + size + 50;
    let grey = |x: usize, y: usize| map.get(x, y).iter().all(|c| *c < 0.5);
    let note_ink = (left - 1..panel_x)
        .filter(|&x| (note_y..note_y + 7).any(|y| grey(x, y)))
        .count();
    assert!(note_ink >= 20, "{note_ink} inked columns of the note");
    // The thumbnails' coordinates: X1 above the columns, X2 right of each row (negative ones
    // too: the panel's right margin is as wide as the widest).
    let labels_x = panel_x + g * ts + 4;
    for j in 0..g {
        let y = 40 + j * ts + ts / 2 - 3;
        let ink = (labels_x..map.width)
            .filter(|&x| (y..y + 7).any(|y| dark(x, y)))
            .count();
        assert!(ink >= 10, "row {j}: {ink} inked columns of its X2 label");
    }
    // Labels wider than a 32 px column: every other one, the others left out.
    for i in (0..g).step_by(2) {
        let x = panel_x + i * ts + ts / 2;
        let ink = (x - 8..x + 8)
            .filter(|&x| (31..38).any(|y| dark(x, y)))
            .count();
        assert!(ink >= 4, "column {i}: {ink} inked columns of its X1 label");
    }
    // The X1 row, from the axis name (18 px left of the panel) to the row labels' column:
    // runs of ink split where 5 or more columns are blank (a label has gaps of at most 3, and
    // one drawn label ends 6 px before the next). None is wider than the widest label (the
    // ones left out would run into their neighbours), and at least every other is drawn.
    let widest = widest_column_label(&points, g);
    let runs = ink_runs(&map, panel_x - 18..labels_x, 31..38);
    assert!(
        runs.len() > g / 2 && runs.iter().all(|&(a, z)| z - a < widest),
        "runs of ink {runs:?} in the X1 row, labels up to {widest} px"
    );
    // The first run is the name X1, 18 px left of the panel; each other is centred on its
    // column (to 2 px: the ink of a label's glyphs is not quite centred in its box).
    assert_eq!(runs[0].0, panel_x - 18, "{runs:?}");
    for &(a, z) in &runs[1..] {
        let off = ((a + z) / 2 - panel_x) % ts;
        assert!(off.abs_diff(ts / 2) <= 2, "run {a}..={z} in {runs:?}");
    }
    let x2 = render::font::text_width("X2", 1);
    let x2_ink = (labels_x..labels_x + x2)
        .filter(|&x| (31..38).any(|y| dark(x, y)))
        .count();
    assert!(x2_ink >= x2 / 2, "{x2_ink} inked columns of the name X2");
}

/// The widest of the X1 labels of `g` thumbnail columns over `points`' box.
fn widest_column_label(points: &[(String, [f64; 2])], g: usize) -> usize {
    let [bx0, bx1, ..] = render::map::thumbnail_box(points);
    render::map::cell_centre_labels(bx0, bx1, g)
        .iter()
        .map(|l| render::font::text_width(l, 1))
        .max()
        .unwrap()
}

/// The runs of dark ink (first and last column) in columns `xs` of rows `ys`, split where 5 or
/// more columns are blank (a label's glyphs leave gaps of at most 3 between them).
fn ink_runs(
    map: &render::Image,
    xs: std::ops::Range<usize>,
    ys: std::ops::Range<usize>,
) -> Vec<(usize, usize)> {
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for x in xs.filter(|&x| ys.clone().any(|y| map.get(x, y).iter().all(|c| *c < 0.3))) {
        match runs.last_mut() {
            Some(last) if x - last.1 <= 5 => last.1 = x,
            _ => runs.push((x, x)),
        }
    }
    runs
}

/// Thumbnails of 8 px, far narrower than their X1 labels: a label is drawn only 6 px clear of
/// the name X1 and of the label before it, and the name X2 only 6 px clear of the last label,
/// so every run of ink in the row is one name or one label.
#[test]
fn narrow_thumbnails_keep_their_coordinate_labels_apart() {
    let (g, ts) = (8usize, 8usize);
    let (map, points) = (two_point_map(g, ts, None), two_points());
    keep(&map, "narrow-thumbnails.png");
    let panel_x = two_point_panel_x();
    let widest = widest_column_label(&points, g);
    assert!(widest > 3 * ts, "{widest}");
    let runs = ink_runs(&map, panel_x - 18..map.width, 31..38);
    assert_eq!(runs[0].0, panel_x - 18, "{runs:?}");
    assert!(
        runs.len() >= 3 && runs.iter().all(|&(a, z)| z - a < widest),
        "runs of ink {runs:?} in the X1 row, labels up to {widest} px"
    );
}

/// The Delta E heat maps' rims are anti-aliased like the spheres beside them: a pixel the
/// sphere covers in part shows the map's colour at that coverage over the background (it was
/// left as background: a staircase edge, and the map a pixel smaller than its sphere).
#[test]
fn heat_maps_have_the_spheres_anti_aliased_rim() {
    let red = synth("carpaint_solid_red");
    let opts = SphereOptions {
        size: 40,
        ..SphereOptions::default()
    };
    let rows = vec![("RED".to_string(), vec![&red as &dyn BrdfSource, &red])];
    let sheet = comparison_sheet(&["A", "B"], &rows, &opts, 10.0).unwrap();
    keep(&sheet.image, "rim.png");
    let sphere = render::render_sphere(&red, &opts).unwrap();
    // Cells: the label column (at least 40 px) and 8 px gaps; the heat map is the third.
    let (x0, y0) = (40 + 8 + 8 + 2 * (40 + 8), 8 + render::font::GLYPH_H + 4);
    let zero = render::image::ramp(0.0);
    let mut rim = 0;
    for y in 0..40 {
        for x in 0..40 {
            let a = sphere.alpha[y * 40 + x];
            let want = if a <= 0.0 {
                [0.02; 3]
            } else {
                zero.map(|c| a * c + (1.0 - a) * 0.02)
            };
            let got = sheet.image.get(x0 + x, y0 + y);
            for k in 0..3 {
                assert!(
                    (got[k] - want[k]).abs() < 1e-9,
                    "({x}, {y}) alpha {a}: {got:?} {want:?}"
                );
            }
            rim += usize::from(a > 0.0 && a < 0.999);
        }
    }
    assert!(rim > 40, "{rim} rim pixels");
}
