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
    let mut img = Image::new(W, H, BG);
    let (x0, x1) = decades(rows.iter().map(|r| r.fit_seconds));
    let (y0, y1) = decades(rows.iter().map(|r| r.loo_rmse_per_channel));
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
    let mut front: Vec<&BenchRow> = rows.iter().filter(|r| r.pareto).collect();
    front.sort_by(|a, b| a.fit_seconds.total_cmp(&b.fit_seconds));
    for w in front.windows(2) {
        line(
            &mut img,
            (px(w[0].fit_seconds), py(w[0].loo_rmse_per_channel)),
            (px(w[1].fit_seconds), py(w[1].loo_rmse_per_channel)),
            1.5,
            [0.9, 0.3, 0.3],
        );
    }
    for r in rows {
        if !(r.fit_seconds > 0.0 && r.loo_rmse_per_channel > 0.0) {
            continue;
        }
        let c = (px(r.fit_seconds), py(r.loo_rmse_per_channel));
        img.disc(c.0, c.1, 4.0, colour(&r.sweep));
        if r.pareto {
            ring(&mut img, c, 8.0, [0.9, 0.3, 0.3]);
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
    ring(
        &mut img,
        (lx as f64 + 4.0, y as f64 + 3.0),
        7.0,
        [0.9, 0.3, 0.3],
    );
    img.text(lx + 14, y, "Pareto front", 1, INK);

    img.save_png(path)
        .map_err(|e| Error::stage("bench", path, e))
}
