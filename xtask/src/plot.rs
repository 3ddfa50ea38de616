//! The bench plot: fit time against leave-one-out error (log-log), one colour per sweep, the
//! Pareto front joined and ringed. Drawn with the render crate's image and bitmap font (no
//! system libraries: plotters' text needs a TTF font through font-kit or an embedded font
//! file, neither of which this project has).

use std::path::Path;

use render::Image;

use crate::bench::BenchRow;
use crate::error::{Error, Result};

const W: usize = 900;
const H: usize = 600;
const LEFT: f64 = 80.0;
const RIGHT: f64 = 200.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 60.0;
const BG: [f64; 3] = [1.0, 1.0, 1.0];
const INK: [f64; 3] = [0.05, 0.05, 0.05];
const GRID: [f64; 3] = [0.85, 0.85, 0.85];
/// The Pareto front's line and rings.
const FRONT: [f64; 3] = [0.9, 0.3, 0.3];

const PALETTE: [[f64; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [0.80, 0.10, 0.10],
    [0.10, 0.40, 0.85],
    [0.10, 0.60, 0.20],
    [0.85, 0.50, 0.05],
    [0.55, 0.20, 0.70],
    [0.05, 0.65, 0.70],
    [0.60, 0.45, 0.25],
];

fn line(img: &mut Image, a: (f64, f64), b: (f64, f64), width: f64, rgb: [f64; 3]) {
    let len = (b.0 - a.0).hypot(b.1 - a.1);
    let steps = (len * 2.0).ceil().max(1.0) as usize;
    for i in 0..=steps {
        let t = i as f64 / steps as f64;
        img.disc(
            a.0 + t * (b.0 - a.0),
            a.1 + t * (b.1 - a.1),
            width / 2.0,
            rgb,
        );
    }
}

fn ring(img: &mut Image, c: (f64, f64), r: f64, rgb: [f64; 3]) {
    let steps = (r * 12.0) as usize;
    for i in 0..steps {
        let a = i as f64 / steps as f64 * std::f64::consts::TAU;
        img.disc(c.0 + r * a.cos(), c.1 + r * a.sin(), 0.8, rgb);
    }
}

/// Decade range covering `v` (log10 bounds).
fn decades(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for x in v.filter(|x| x.is_finite() && *x > 0.0) {
        lo = lo.min(x.log10());
        hi = hi.max(x.log10());
    }
    if lo > hi {
        return (0.0, 1.0);
    }
    let (lo, hi) = (lo.floor(), hi.ceil());
    if hi <= lo { (lo, lo + 1.0) } else { (lo, hi) }
}

/// Draws `rows` into the PNG `path`.
pub fn pareto_plot(rows: &[BenchRow], path: &Path) -> Result<()> {
    draw(rows)
        .save_png(path)
        .map_err(|e| Error::stage("bench", path, e))
}

/// Whether `row` has a point in the plot: a finite, positive fit time and per-channel
/// leave-one-out error (a failed evaluation's NaN has none).
fn is_plotted(row: &BenchRow) -> bool {
    let usable = |v: f64| v.is_finite() && v > 0.0;
    usable(row.fit_seconds) && usable(row.loo_rmse_per_channel)
}

/// The plot of `rows`: log-log axes over the decades the plotted rows' fit times and
/// per-channel leave-one-out errors span, a disc per plotted row in its sweep's colour, labelled
/// with its value, the Pareto front joined and ringed, and a legend of every sweep.
fn draw(rows: &[BenchRow]) -> Image {
    let mut img = Image::new(W, H, BG);
    let plotted = || rows.iter().filter(|r| is_plotted(r));
    let (x0, x1) = decades(plotted().map(|r| r.fit_seconds));
    let (y0, y1) = decades(plotted().map(|r| r.loo_rmse_per_channel));
    let pw = W as f64 - LEFT - RIGHT;
    let ph = H as f64 - TOP - BOTTOM;
    let px = |v: f64| LEFT + (v.log10() - x0) / (x1 - x0) * pw;
    let py = |v: f64| TOP + ph - (v.log10() - y0) / (y1 - y0) * ph;
    for d in x0 as i32..=x1 as i32 {
        let x = LEFT + (f64::from(d) - x0) / (x1 - x0) * pw;
        line(&mut img, (x, TOP), (x, TOP + ph), 1.0, GRID);
        let label = format!("1e{d}");
        img.text(x as i64 - 8, (TOP + ph + 8.0) as i64, &label, 1, INK);
    }
    for d in y0 as i32..=y1 as i32 {
        let y = TOP + ph - (f64::from(d) - y0) / (y1 - y0) * ph;
        line(&mut img, (LEFT, y), (LEFT + pw, y), 1.0, GRID);
        img.text(LEFT as i64 - 34, y as i64 - 3, &format!("1e{d}"), 1, INK);
    }
    line(&mut img, (LEFT, TOP + ph), (LEFT + pw, TOP + ph), 1.5, INK);
    line(&mut img, (LEFT, TOP), (LEFT, TOP + ph), 1.5, INK);
    img.text(
        LEFT as i64,
        4,
        "specgp bench: fit time against leave-one-out error (log-log)",
        2,
        INK,
    );
    img.text(
        (LEFT + pw / 2.0 - 60.0) as i64,
        (H as f64 - 24.0) as i64,
        "fit time (s)",
        2,
        INK,
    );
    img.text(
        4,
        (TOP - 14.0) as i64,
        "LOO RMSE / sqrt(channels) (1/sr)",
        1,
        INK,
    );

    // Sweeps in order of first appearance.
    let mut sweeps: Vec<&str> = Vec::new();
    for r in rows {
        if !sweeps.contains(&r.sweep.as_str()) {
            sweeps.push(&r.sweep);
        }
    }
    let colour =
        |s: &str| PALETTE[sweeps.iter().position(|x| *x == s).unwrap_or(0) % PALETTE.len()];

    // Pareto front, by fit time.
    let mut front: Vec<&BenchRow> = plotted().filter(|r| r.pareto).collect();
    front.sort_by(|a, b| a.fit_seconds.total_cmp(&b.fit_seconds));
    for w in front.windows(2) {
        line(
            &mut img,
            (px(w[0].fit_seconds), py(w[0].loo_rmse_per_channel)),
            (px(w[1].fit_seconds), py(w[1].loo_rmse_per_channel)),
            1.5,
            FRONT,
        );
    }
    for r in plotted() {
        let c = (px(r.fit_seconds), py(r.loo_rmse_per_channel));
        img.disc(c.0, c.1, 4.0, colour(&r.sweep));
        if r.pareto {
            ring(&mut img, c, 8.0, FRONT);
        }
        let label = if r.sweep == "base" {
            "base".to_string()
        } else {
            r.value.clone()
        };
        img.text(c.0 as i64 + 7, c.1 as i64 + 4, &label, 1, colour(&r.sweep));
    }

    // Legend.
    let lx = (LEFT + pw + 20.0) as i64;
    for (i, s) in sweeps.iter().enumerate() {
        let y = TOP as i64 + 10 + 18 * i as i64;
        img.disc(lx as f64 + 4.0, y as f64 + 3.0, 4.0, colour(s));
        img.text(lx + 14, y, s, 1, INK);
    }
    let y = TOP as i64 + 10 + 18 * sweeps.len() as i64 + 8;
    ring(&mut img, (lx as f64 + 4.0, y as f64 + 3.0), 7.0, FRONT);
    img.text(lx + 14, y, "Pareto front", 1, INK);
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::tests::row;

    /// A plotted row of sweep `sweep` at fit time `t` and per-channel error `e`.
    fn point(sweep: &str, value: &str, t: f64, e: f64, pareto: bool) -> BenchRow {
        BenchRow {
            sweep: sweep.into(),
            value: value.into(),
            pareto,
            ..row(t, e)
        }
    }

    /// The pixel holding image position (x, y).
    fn at(img: &Image, (x, y): (f64, f64)) -> [f64; 3] {
        img.get(x.floor() as usize, y.floor() as usize)
    }

    fn near(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        a.iter().zip(&b).all(|(u, v)| (u - v).abs() <= tol)
    }

    #[test]
    fn decades_cover_the_positive_finite_values_with_whole_powers_of_ten() {
        assert_eq!(decades([0.03, 20.0].into_iter()), (-2.0, 2.0));
        assert_eq!(decades([0.2, 5.0].into_iter()), (-1.0, 1.0));
        // One value, or an exact power of ten, still spans one decade.
        assert_eq!(decades([5.0].into_iter()), (0.0, 1.0));
        assert_eq!(decades([10.0, 10.0].into_iter()), (1.0, 2.0));
        assert_eq!(decades([0.01].into_iter()), (-2.0, -1.0));
        // Zero, negative and non-finite values are ignored; none at all gives [1, 10].
        assert_eq!(
            decades([0.0, -3.0, f64::NAN, f64::INFINITY, 0.5].into_iter()),
            (-1.0, 0.0)
        );
        assert_eq!(decades([0.0, f64::NAN].into_iter()), (0.0, 1.0));
        assert_eq!(decades(std::iter::empty()), (0.0, 1.0));
    }

    /// Points sit where their values say on log-log axes (here x over 0.1-100 s, y over
    /// 1e-3-1e-1), in their sweep's colour; the front is ringed and joined, other points not.
    #[test]
    fn points_front_axes_and_legend_are_where_the_values_put_them() {
        let rows = [
            point("base", "b", 0.2, 0.02, true),
            point("grid", "8,8,16", 2.0, 0.005, true),
            point("grid", "4,4,8", 50.0, 0.05, false),
            // Not plotted (no fit time; a NaN error): listed in the legend, and neither moves
            // the axes (0.0005 would widen y to 1e-4).
            point("dtype", "f16", 0.0, 0.0005, true),
            point("optimizer", "hj", 0.5, f64::NAN, false),
        ];
        let img = draw(&rows);
        assert_eq!((img.width, img.height), (W, H));
        let (pw, ph) = (W as f64 - LEFT - RIGHT, H as f64 - TOP - BOTTOM);
        // x: decades -1..2; y: decades -3..-1.
        let pos = |t: f64, e: f64| {
            (
                LEFT + (t.log10() + 1.0) / 3.0 * pw,
                TOP + ph - (e.log10() + 3.0) / 2.0 * ph,
            )
        };
        let (a, b, c) = (pos(0.2, 0.02), pos(2.0, 0.005), pos(50.0, 0.05));
        // Discs in the colour of their sweep, in order of first appearance.
        assert_eq!(at(&img, a), PALETTE[0]);
        assert_eq!(at(&img, b), PALETTE[1]);
        assert_eq!(at(&img, c), PALETTE[1]);
        // Front points are ringed (radius 8), the other is not.
        for p in [a, b] {
            assert!(near(at(&img, (p.0 + 8.0, p.1)), FRONT, 0.1), "{p:?}");
            assert!(near(at(&img, (p.0, p.1 - 8.0)), FRONT, 0.1), "{p:?}");
        }
        assert_eq!(at(&img, (c.0 + 8.0, c.1)), BG);
        assert_eq!(at(&img, (c.0, c.1 - 8.0)), BG);
        // The front is joined from a to b; nothing joins a to c.
        let mid = |p: (f64, f64), q: (f64, f64)| ((p.0 + q.0) / 2.0, (p.1 + q.1) / 2.0);
        assert!(near(at(&img, mid(a, b)), FRONT, 0.02));
        let ac = at(&img, mid(a, c));
        assert!(!near(ac, FRONT, 0.3), "{ac:?}");
        // The front's line is 1.5 pixels wide: across it, a quarter of the way from a to b
        // (away from the grid lines), pixels centred 1.3 or more from its axis are background.
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let (nx, ny) = (-dy / dx.hypot(dy), dx / dx.hypot(dy));
        let q = (a.0 + 0.25 * dx, a.1 + 0.25 * dy);
        let mut beside = Vec::new();
        for py in q.1 as usize - 4..=q.1 as usize + 4 {
            for px in q.0 as usize - 4..=q.0 as usize + 4 {
                let (cx, cy) = (px as f64 + 0.5 - a.0, py as f64 + 0.5 - a.1);
                let d = (cx * nx + cy * ny).abs();
                if d >= 1.3 {
                    assert_eq!(img.get(px, py), BG, "({px}, {py}), {d} from the line");
                    beside.push(d);
                }
            }
        }
        assert!(
            beside.iter().filter(|d| **d < 1.9).count() >= 2,
            "{beside:?}"
        );
        // Decade grid lines at x = 1 s and y = 1e-2, the axes along the left and bottom;
        // plain background between them.
        let grid_x = LEFT + pw / 3.0;
        let grid_y = TOP + ph / 2.0;
        for p in [(grid_x, TOP + ph * 0.8), (LEFT + pw * 0.8, grid_y)] {
            let v = at(&img, p);
            assert!(v[0] < 0.95 && v[0] > 0.5, "grid line at {p:?}: {v:?}");
        }
        assert_eq!(at(&img, (grid_x + pw / 8.0, TOP + ph * 0.8)), BG);
        // Grid lines stop at the axes, and the axes at the plot's corners.
        assert_eq!(at(&img, (LEFT + pw + 10.0, TOP + ph)), BG);
        assert_eq!(at(&img, (LEFT, H as f64 - 5.0)), BG);
        assert_eq!(at(&img, (grid_x, TOP + ph + 25.0)), BG);
        assert_eq!(at(&img, (LEFT - 40.0, grid_y)), BG);
        // Every text glyph for glyph: the title, the axis names, the tick labels under and left
        // of their grid lines, each point's label right of and below it in its sweep's colour
        // (the swept value; "base" for the base point), the legend's names.
        let mut texts = Image::new(W, H, BG);
        let mut text = |x: f64, y: f64, t: &str, scale: usize, rgb: [f64; 3]| {
            texts.text(x as i64, y as i64, t, scale, rgb);
        };
        let title = "specgp bench: fit time against leave-one-out error (log-log)";
        text(LEFT, 4.0, title, 2, INK);
        text(
            LEFT + pw / 2.0 - 60.0,
            H as f64 - 24.0,
            "fit time (s)",
            2,
            INK,
        );
        text(4.0, TOP - 14.0, "LOO RMSE / sqrt(channels) (1/sr)", 1, INK);
        for d in -1..=2 {
            let x = LEFT + f64::from(d + 1) / 3.0 * pw;
            text(x - 8.0, TOP + ph + 8.0, &format!("1e{d}"), 1, INK);
        }
        for d in -3..=-1 {
            let y = TOP + ph - f64::from(d + 3) / 2.0 * ph;
            text(LEFT - 34.0, y.trunc() - 3.0, &format!("1e{d}"), 1, INK);
        }
        for (p, label, rgb) in [(a, "base", PALETTE[0]), (b, "8,8,16", PALETTE[1])] {
            text(p.0.trunc() + 7.0, p.1.trunc() + 4.0, label, 1, rgb);
        }
        text(c.0.trunc() + 7.0, c.1.trunc() + 4.0, "4,4,8", 1, PALETTE[1]);
        let lx = LEFT + pw + 20.0;
        for (i, name) in ["base", "grid", "dtype", "optimizer", "Pareto front"]
            .iter()
            .enumerate()
        {
            let y = TOP + 10.0 + 18.0 * i as f64 + if i == 4 { 8.0 } else { 0.0 };
            text(lx + 14.0, y, name, 1, INK);
        }
        let mut glyphs = 0;
        for y in 0..H {
            for x in 0..W {
                let want = texts.get(x, y);
                if want != BG {
                    assert_eq!(img.get(x, y), want, "text pixel ({x}, {y})");
                    glyphs += 1;
                }
            }
        }
        assert!(glyphs > 1000, "{glyphs}");
        for p in [(LEFT, TOP + ph * 0.3), (LEFT + pw * 0.3, TOP + ph)] {
            let v = at(&img, p);
            assert!(v[0] < 0.3, "axis at {p:?}: {v:?}");
        }
        // Legend right of the plot: one disc per sweep (the unplotted ones too), then the
        // front's ring.
        let lx = LEFT + pw + 20.0 + 4.0;
        for (i, rgb) in PALETTE[..4].iter().enumerate() {
            let y = TOP + 10.0 + 18.0 * i as f64 + 3.0;
            assert_eq!(at(&img, (lx, y)), *rgb, "legend entry {i}");
        }
        let ring_y = TOP + 10.0 + 18.0 * 4.0 + 8.0 + 3.0;
        assert!(near(at(&img, (lx + 7.0, ring_y)), FRONT, 0.1));
        assert_eq!(at(&img, (lx, TOP + 10.0 + 18.0 * 6.0 + 3.0)), BG);
    }

    #[test]
    fn the_plot_is_written_as_png_and_a_bad_path_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let rows = [point("base", "b", 0.2, 0.02, true)];
        let path = dir.path().join("bench.png");
        pareto_plot(&rows, &path).unwrap();
        let (w, h, bytes) = render::image::read_png_rgba8(&path).unwrap();
        assert_eq!((w, h), (W, H));
        assert_eq!(bytes, draw(&rows).to_rgba8());
        let bad = dir.path().join("missing").join("bench.png");
        let e = pareto_plot(&rows, &bad).unwrap_err().to_string();
        assert!(e.contains("missing/bench.png"), "{e}");
    }
}
