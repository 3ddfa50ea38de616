//! Linear-sRGB float images, drawing helpers (rectangles, dots, text) and atomic PNG output.

use std::path::Path;

use crate::colour::to_srgb8;
use crate::error::{Error, Result};
use crate::font;

/// A linear-sRGB image with an alpha (coverage) channel, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Linear sRGB per pixel (not clamped).
    pub rgb: Vec<[f64; 3]>,
    /// Coverage per pixel in [0, 1] (1 = opaque).
    pub alpha: Vec<f64>,
}

/// How far one image is from another ([`Image::difference`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageDifference {
    /// Largest absolute linear sRGB difference over the compared pixels and channels.
    pub max: f64,
    /// Mean absolute linear sRGB difference over the compared pixels and channels (0 when
    /// no pixel is compared).
    pub mean: f64,
    /// Largest difference of the 8-bit sRGB codes a PNG would hold.
    pub codes: u8,
}

impl Image {
    /// The difference of `other` from this image over the pixels this image covers
    /// (alpha > 0), every channel; an error when the sizes differ.
    pub fn difference(&self, other: &Image) -> Result<ImageDifference> {
        if (self.width, self.height) != (other.width, other.height) {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "comparing a {}x{} image with a {}x{} one",
                    self.width, self.height, other.width, other.height
                ),
            });
        }
        let (mut max, mut sum, mut n, mut codes) = (0.0f64, 0.0, 0usize, 0u8);
        for ((p, q), _) in self
            .rgb
            .iter()
            .zip(&other.rgb)
            .zip(&self.alpha)
            .filter(|(_, a)| **a > 0.0)
        {
            for (a, b) in p.iter().zip(q) {
                let d = (a - b).abs();
                max = max.max(d);
                sum += d;
                n += 1;
                codes = codes.max(to_srgb8(*a).abs_diff(to_srgb8(*b)));
            }
        }
        Ok(ImageDifference {
            max,
            mean: if n == 0 { 0.0 } else { sum / n as f64 },
            codes,
        })
    }

    /// A `width x height` image filled with the opaque linear colour `rgb`.
    pub fn new(width: usize, height: usize, rgb: [f64; 3]) -> Self {
        Self {
            width,
            height,
            rgb: vec![rgb; width * height],
            alpha: vec![1.0; width * height],
        }
    }

    /// The linear colour at (x, y).
    pub fn get(&self, x: usize, y: usize) -> [f64; 3] {
        self.rgb[y * self.width + x]
    }

    /// Sets an opaque pixel; coordinates outside the image are ignored.
    pub fn set(&mut self, x: i64, y: i64, rgb: [f64; 3]) {
        self.blend(x, y, rgb, 1.0);
    }

    /// Blends `rgb` over pixel (x, y) with opacity `a`; outside the image: ignored.
    pub fn blend(&mut self, x: i64, y: i64, rgb: [f64; 3], a: f64) {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return;
        }
        let i = y as usize * self.width + x as usize;
        let a = a.clamp(0.0, 1.0);
        for (c, &v) in self.rgb[i].iter_mut().zip(&rgb) {
            *c = *c * (1.0 - a) + v * a;
        }
        self.alpha[i] = self.alpha[i] * (1.0 - a) + a;
    }

    /// Fills the rectangle [x0, x0 + w) x [y0, y0 + h) (clipped).
    pub fn fill_rect(&mut self, x0: i64, y0: i64, w: usize, h: usize, rgb: [f64; 3]) {
        self.blend_rect(x0, y0, w, h, rgb, 1.0);
    }

    /// Draws the one-pixel border of the rectangle [x0, x0 + w) x [y0, y0 + h) (clipped).
    pub fn outline_rect(&mut self, x0: i64, y0: i64, w: usize, h: usize, rgb: [f64; 3]) {
        if w == 0 || h == 0 {
            return;
        }
        self.fill_rect(x0, y0, w, 1, rgb);
        self.fill_rect(x0, y0 + h as i64 - 1, w, 1, rgb);
        self.fill_rect(x0, y0, 1, h, rgb);
        self.fill_rect(x0 + w as i64 - 1, y0, 1, h, rgb);
    }

    /// Blends `rgb` with opacity `a` over the rectangle [x0, x0 + w) x [y0, y0 + h) (clipped).
    pub fn blend_rect(&mut self, x0: i64, y0: i64, w: usize, h: usize, rgb: [f64; 3], a: f64) {
        for y in y0..y0 + h as i64 {
            for x in x0..x0 + w as i64 {
                self.blend(x, y, rgb, a);
            }
        }
    }

    /// Draws a one-pixel line from (x0, y0) to (x1, y1) (pixel units), blended with opacity
    /// `a` (one pixel per step along the longer axis).
    pub fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, rgb: [f64; 3], a: f64) {
        let steps = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0) as usize;
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
            self.blend(x.floor() as i64, y.floor() as i64, rgb, a);
        }
    }

    /// Draws a filled, anti-aliased disc of radius `r` centred at (cx, cy) (pixel units, pixel
    /// centres at +0.5).
    pub fn disc(&mut self, cx: f64, cy: f64, r: f64, rgb: [f64; 3]) {
        let (x0, x1) = ((cx - r - 1.0).floor() as i64, (cx + r + 1.0).ceil() as i64);
        let (y0, y1) = ((cy - r - 1.0).floor() as i64, (cy + r + 1.0).ceil() as i64);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let d = ((x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy)) - r;
                let a = (0.5 - d).clamp(0.0, 1.0);
                if a > 0.0 {
                    self.blend(x, y, rgb, a);
                }
            }
        }
    }

    /// Draws `text` with its top-left corner at (x, y), each font pixel a `scale x scale` block.
    pub fn text(&mut self, x: i64, y: i64, text: &str, scale: usize, rgb: [f64; 3]) {
        let s = scale.max(1) as i64;
        for (k, c) in text.chars().enumerate() {
            let g = font::glyph(c);
            let gx = x + (k * font::ADVANCE) as i64 * s;
            for (row, bits) in g.iter().enumerate() {
                for col in 0..font::GLYPH_W {
                    if bits >> (font::GLYPH_W - 1 - col) & 1 == 1 {
                        let px = gx + col as i64 * s;
                        let py = y + row as i64 * s;
                        self.fill_rect(px, py, s as usize, s as usize, rgb);
                    }
                }
            }
        }
    }

    /// Copies `src` (composited over this image by its alpha) with its top-left at (x, y).
    pub fn blit(&mut self, src: &Image, x: i64, y: i64) {
        for sy in 0..src.height {
            for sx in 0..src.width {
                let i = sy * src.width + sx;
                self.blend(x + sx as i64, y + sy as i64, src.rgb[i], src.alpha[i]);
            }
        }
    }

    /// Composites the image over an opaque background colour (linear).
    pub fn over(&self, background: [f64; 3]) -> Image {
        let mut out = Image::new(self.width, self.height, background);
        out.blit(self, 0, 0);
        out
    }

    /// Multiplies every colour by `2^ev`.
    pub fn exposed(&self, ev: f64) -> Image {
        let k = 2f64.powf(ev);
        let mut out = self.clone();
        for p in &mut out.rgb {
            for c in p.iter_mut() {
                *c *= k;
            }
        }
        out
    }

    /// 8-bit sRGB-encoded RGBA bytes (colours clipped to [0, 1] per channel).
    pub fn to_rgba8(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.width * self.height * 4);
        for (p, a) in self.rgb.iter().zip(&self.alpha) {
            out.extend(p.iter().map(|&v| to_srgb8(v)));
            out.push((a.clamp(0.0, 1.0) * 255.0).round() as u8);
        }
        out
    }

    /// Writes an 8-bit sRGB PNG (RGBA) atomically ([`brdf_io::output::write_file_atomic`]: a
    /// temporary file renamed into place, or straight into a special file such as `/dev/stdout`).
    pub fn save_png(&self, path: &Path) -> Result<()> {
        // The atomic writer's errors name the file themselves: "writing P: P: ..." said it twice.
        let err = |reason: String| Error::Write {
            path: path.to_owned(),
            reason: brdf_io::error::without_path_prefix(reason, path),
        };
        if self.width == 0 || self.height == 0 {
            return Err(err("empty image".into()));
        }
        let mut bytes = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut bytes, self.width as u32, self.height as u32);
            enc.set_color(png::ColorType::Rgba);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
            let mut w = enc.write_header().map_err(|e| err(e.to_string()))?;
            w.write_image_data(&self.to_rgba8())
                .map_err(|e| err(e.to_string()))?;
            w.finish().map_err(|e| err(e.to_string()))?;
        }
        brdf_io::output::write_file_atomic(path, &bytes).map_err(|e| err(e.to_string()))
    }
}

/// Reads an 8-bit RGB or RGBA PNG back as (width, height, RGBA bytes) — for tests and tools.
pub fn read_png_rgba8(path: &Path) -> Result<(usize, usize, Vec<u8>)> {
    let err = |reason: String| Error::Read {
        path: path.to_owned(),
        reason,
    };
    let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .map_err(|e| err(e.to_string()))?;
    let mut buf = vec![0; dec.output_buffer_size()];
    let info = dec.next_frame(&mut buf).map_err(|e| err(e.to_string()))?;
    let (w, h) = (info.width as usize, info.height as usize);
    let data = &buf[..info.buffer_size()];
    let rgba = match (info.color_type, info.bit_depth) {
        (png::ColorType::Rgba, png::BitDepth::Eight) => data.to_vec(),
        (png::ColorType::Rgb, png::BitDepth::Eight) => data
            .chunks(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect(),
        other => return Err(err(format!("unsupported PNG layout {other:?}"))),
    };
    Ok((w, h, rgba))
}

/// A perceptual colour ramp (dark blue -> teal -> yellow, viridis-like) at t in [0, 1], linear
/// sRGB.
pub fn ramp(t: f64) -> [f64; 3] {
    const STOPS: [[f64; 3]; 5] = [
        [0.267, 0.005, 0.329],
        [0.229, 0.322, 0.546],
        [0.128, 0.567, 0.551],
        [0.369, 0.789, 0.383],
        [0.993, 0.906, 0.144],
    ];
    // NaN reads as 0; beyond [0, 1], infinities included, the ends (+infinity read as 0 made
    // the largest values look like the smallest).
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * (STOPS.len() - 1) as f64;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f64;
    let enc = |c: usize| STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f;
    [
        crate::colour::srgb_decode(enc(0)),
        crate::colour::srgb_decode(enc(1)),
        crate::colour::srgb_decode(enc(2)),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn difference_over_covered_pixels_in_linear_values_and_8_bit_codes() {
        let mut a = Image::new(2, 2, [0.5; 3]);
        let mut b = a.clone();
        b.rgb[0] = [0.5, 0.52, 0.5];
        b.rgb[3] = [0.0, 0.0, 0.0];
        // Pixel 3 is not covered in `a`: not compared.
        a.alpha[3] = 0.0;
        let d = a.difference(&b).unwrap();
        assert!((d.max - 0.02).abs() < 1e-15, "{d:?}");
        assert!((d.mean - 0.02 / 9.0).abs() < 1e-15, "{d:?}");
        // sRGB codes of linear 0.5 and 0.52: 188 and 191.
        assert_eq!((to_srgb8(0.5), to_srgb8(0.52)), (188, 191));
        assert_eq!(d.codes, 3);
        // Beyond white the codes saturate at 255; the linear difference does not.
        b.rgb[0] = [3.0, 0.5, 0.5];
        let d = a.difference(&b).unwrap();
        assert_eq!((d.max, d.codes), (2.5, 67));
        assert_eq!(a.difference(&a).unwrap().codes, 0);
        let err = a.difference(&Image::new(2, 3, [0.0; 3])).unwrap_err();
        assert!(err.to_string().contains("2x2 image with a 2x3"), "{err}");
    }

    #[test]
    fn png_round_trip_and_drawing() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let mut img = Image::new(40, 20, [0.0; 3]);
        img.text(1, 1, "A1", 1, [1.0; 3]);
        img.disc(30.0, 10.0, 4.7, [1.0, 0.0, 0.0]);
        let p = dir.join("t.png");
        img.save_png(&p).unwrap();
        let (w, h, px) = read_png_rgba8(&p).unwrap();
        assert_eq!((w, h), (40, 20));
        // 'A' top row is .###. : pixel (2, 1) lit, (1, 1) dark.
        assert_eq!(px[(40 + 2) * 4], 255);
        assert_eq!(px[(40 + 1) * 4], 0);
        // Disc centre is red; a pixel on its edge is partly red.
        let at = |x: usize, y: usize| &px[(y * 40 + x) * 4..(y * 40 + x) * 4 + 3];
        assert_eq!(at(30, 10), &[255, 0, 0]);
        let edge = at(34, 10)[0];
        assert!(edge > 0 && edge < 255, "{edge}");
        assert!(
            std::fs::read_dir(dir).unwrap().count() == 1,
            "no temp file left"
        );
    }

    #[test]
    fn png_errors_name_the_file_once_and_say_what_failed() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("missing/t.png");
        let shown = p.display().to_string();
        let e = Image::new(2, 2, [0.5; 3])
            .save_png(&p)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with(&format!("writing {shown}: ")), "{e}");
        assert_eq!(e.matches(&shown).count(), 1, "{e}");
        let e = read_png_rgba8(&p).unwrap_err().to_string();
        assert!(e.starts_with(&format!("reading {shown}: ")), "{e}");
    }

    /// The pixels of `img` as `#` (the colour `on`) and `.` (anything else), one string per row.
    fn mask(img: &Image, on: [f64; 3]) -> Vec<String> {
        (0..img.height)
            .map(|y| {
                (0..img.width)
                    .map(|x| if img.get(x, y) == on { '#' } else { '.' })
                    .collect()
            })
            .collect()
    }

    const WHITE: [f64; 3] = [1.0; 3];
    const BLACK: [f64; 3] = [0.0; 3];

    #[test]
    fn get_reads_row_major_with_the_top_row_first() {
        // A 3 x 2 image whose pixel i holds [i, 10 i, 100 i]: (x, y) is pixel 3 y + x.
        let mut img = Image::new(3, 2, BLACK);
        for (i, p) in img.rgb.iter_mut().enumerate() {
            let v = i as f64;
            *p = [v, 10.0 * v, 100.0 * v];
        }
        assert_eq!(img.get(0, 0), [0.0, 0.0, 0.0]);
        assert_eq!(img.get(2, 0), [2.0, 20.0, 200.0]);
        assert_eq!(img.get(0, 1), [3.0, 30.0, 300.0]);
        assert_eq!(img.get(2, 1), [5.0, 50.0, 500.0]);
    }

    #[test]
    fn blend_mixes_colour_and_coverage_by_the_opacity() {
        // Dyadic values, so every product below is exact.
        let mut img = Image::new(1, 1, [0.25, 0.5, 1.0]);
        img.alpha[0] = 0.0;
        img.blend(0, 0, [1.0, 0.0, 0.5], 0.25);
        // c (1 - a) + v a: 0.25 x 0.75 + 0.25, 0.5 x 0.75, 0.75 + 0.5 x 0.25.
        assert_eq!(img.rgb[0], [0.4375, 0.375, 0.875]);
        // alpha (1 - a) + a: 0 x 0.75 + 0.25.
        assert_eq!(img.alpha[0], 0.25);
        img.blend(0, 0, BLACK, 0.5);
        assert_eq!(img.rgb[0], [0.21875, 0.1875, 0.4375]);
        // 0.25 x 0.5 + 0.5.
        assert_eq!(img.alpha[0], 0.625);
        // Opacities outside [0, 1] are clamped: above 1 replaces, below 0 leaves alone.
        img.blend(0, 0, [0.75, 0.5, 0.25], -3.0);
        assert_eq!(
            (img.rgb[0], img.alpha[0]),
            ([0.21875, 0.1875, 0.4375], 0.625)
        );
        img.blend(0, 0, [0.75, 0.5, 0.25], 7.0);
        assert_eq!((img.rgb[0], img.alpha[0]), ([0.75, 0.5, 0.25], 1.0));
    }

    #[test]
    fn set_paints_exactly_the_pixels_inside_and_ignores_the_rest() {
        let mut img = Image::new(3, 2, BLACK);
        // Outside on every side, including x = width on row 0 (which, read as a flat index,
        // would be the first pixel of row 1) and far outside.
        for (x, y) in [
            (-1, 0),
            (0, -1),
            (3, 0),
            (0, 2),
            (3, 1),
            (-1, -1),
            (i64::MAX, 0),
        ] {
            img.set(x, y, WHITE);
        }
        assert_eq!(img, Image::new(3, 2, BLACK));
        for (x, y) in [(0, 0), (2, 1), (1, 0)] {
            img.set(x, y, WHITE);
        }
        assert_eq!(mask(&img, WHITE), ["##.", "..#"]);
        assert!(img.alpha.iter().all(|&a| a == 1.0));
    }

    #[test]
    fn rectangles_fill_outline_and_blend_their_exact_pixels() {
        let mut img = Image::new(6, 5, BLACK);
        img.outline_rect(1, 0, 4, 5, WHITE);
        assert_eq!(
            mask(&img, WHITE),
            [".####.", ".#..#.", ".#..#.", ".#..#.", ".####."]
        );
        // Empty rectangles draw nothing.
        let mut empty = Image::new(6, 5, BLACK);
        empty.outline_rect(1, 1, 0, 3, WHITE);
        empty.outline_rect(1, 1, 3, 0, WHITE);
        empty.fill_rect(1, 1, 0, 3, WHITE);
        assert_eq!(empty, Image::new(6, 5, BLACK));
        // A rectangle half off the image is clipped.
        let mut img = Image::new(6, 5, BLACK);
        img.fill_rect(4, -1, 3, 3, WHITE);
        assert_eq!(
            mask(&img, WHITE),
            ["....##", "....##", "......", "......", "......"]
        );
        // [1, 3) x [2, 3) at half opacity over black: 0.5 in those two pixels, 0 elsewhere.
        let mut img = Image::new(6, 5, BLACK);
        img.blend_rect(1, 2, 2, 1, WHITE, 0.5);
        assert_eq!(
            mask(&img, [0.5; 3]),
            ["......", "......", ".##...", "......", "......"]
        );
        assert_eq!(
            mask(&img, BLACK),
            ["######", "######", "#..###", "######", "######"]
        );
    }

    #[test]
    fn lines_step_one_pixel_along_the_longer_axis() {
        // From (0.5, 0.5) to (3.5, 1.5): 3 steps; the points at t = 0, 1/3, 2/3, 1 are
        // (0.5, 0.5), (1.5, 0.83), (2.5, 1.17), (3.5, 1.5), in pixels (0, 0), (1, 0), (2, 1),
        // (3, 1). At opacity 0.5 over black each visited once reads 0.5.
        let mut img = Image::new(5, 3, BLACK);
        img.line(0.5, 0.5, 3.5, 1.5, WHITE, 0.5);
        assert_eq!(mask(&img, [0.5; 3]), ["##...", "..##.", "....."]);
        assert_eq!(mask(&img, BLACK), ["..###", "##..#", "#####"]);
        // Steep and backwards: from (3.2, 2.9) up to (1.2, 0.1): 3 steps (ceil 2.8) at
        // t = 0, 1/3, 2/3, 1: (3.2, 2.9), (2.53, 1.97), (1.87, 1.03), (1.2, 0.1), in pixels
        // (3, 2), (2, 1), (1, 1), (1, 0).
        let mut img = Image::new(5, 3, BLACK);
        img.line(3.2, 2.9, 1.2, 0.1, WHITE, 0.5);
        assert_eq!(mask(&img, [0.5; 3]), [".#...", ".##..", "...#."]);
        assert_eq!(mask(&img, BLACK), ["#.###", "#..##", "###.#"]);
        // Vertical, 2 long: 2 steps, pixels (1, 0), (1, 1), (1, 2), each once.
        let mut img = Image::new(3, 3, BLACK);
        img.line(1.5, 0.5, 1.5, 2.5, WHITE, 0.5);
        assert_eq!(mask(&img, [0.5; 3]), [".#.", ".#.", ".#."]);
        assert_eq!(mask(&img, BLACK), ["#.#", "#.#", "#.#"]);
    }

    #[test]
    fn discs_cover_each_pixel_by_its_centre_distance() {
        // Coverage is clamp(0.5 - (rho - r)) for a pixel centre rho from the disc's centre;
        // white over black reads the coverage. Radius 1 centred on pixel (2, 2)'s centre: the
        // centre pixel 1, its 4 neighbours (rho = 1) 0.5, the diagonals (rho = sqrt 2)
        // 1.5 - sqrt 2, the rest (rho >= 2) 0.
        let mut img = Image::new(5, 5, BLACK);
        img.disc(2.5, 2.5, 1.0, WHITE);
        let diag = 1.5 - 2f64.sqrt();
        for y in 0..5 {
            for x in 0..5 {
                let (dx, dy) = (x as i64 - 2, y as i64 - 2);
                let want = match dx * dx + dy * dy {
                    0 => 1.0,
                    1 => 0.5,
                    2 => diag,
                    _ => 0.0,
                };
                let got = img.get(x, y);
                // 1e-15: hypot and the subtraction round once or twice near 1.
                assert!(
                    got.iter().all(|c| (c - want).abs() < 1e-15),
                    "({x}, {y}): {got:?}"
                );
            }
        }
        // Radius 2 centred on pixel (5, 5)'s centre, in a 10 x 10 image: pixels 2 to the left,
        // right, above and below (rho = 2) are half covered, those 3 away not at all.
        let mut img = Image::new(10, 10, BLACK);
        img.disc(5.5, 5.5, 2.0, WHITE);
        for (x, y) in [(3, 5), (7, 5), (5, 3), (5, 7)] {
            assert_eq!(img.get(x, y), [0.5; 3], "({x}, {y})");
        }
        for (x, y) in [(2, 5), (8, 5), (5, 2), (5, 8)] {
            assert_eq!(img.get(x, y), BLACK, "({x}, {y})");
        }
        // Radius 0.5 centred on pixel (5, 5)'s centre: that pixel full (rho = 0 -> 1),
        // its neighbours (rho = 1) empty.
        let mut img = Image::new(10, 10, BLACK);
        img.disc(5.5, 5.5, 0.5, WHITE);
        assert_eq!(img.get(5, 5), WHITE);
        assert_eq!(mask(&img, BLACK).concat().matches('.').count(), 1);
        // Pixels the disc does not cover are not touched, whatever its colour: an infinite
        // colour blended at coverage 0 would make them NaN (inf x 0). The box around the
        // radius 1 disc at (2.5, 2.5) spans pixels 0 to 5; its corners are uncovered.
        let mut img = Image::new(6, 6, BLACK);
        img.disc(2.5, 2.5, 1.0, [f64::INFINITY; 3]);
        assert_eq!(img.get(2, 2), [f64::INFINITY; 3]);
        for (x, y) in [(0, 0), (5, 0), (0, 5), (5, 5), (2, 0), (0, 2)] {
            assert_eq!(img.get(x, y), BLACK, "({x}, {y})");
        }
    }

    #[test]
    fn text_draws_glyph_pixels_as_scale_blocks_one_advance_apart() {
        // "AT" at (1, 2), scale 2: font pixel (col, row) of the k-th glyph is the block
        // [1 + 12 k + 2 col, +2) x [2 + 2 row, +2) (advance 6 font pixels = 12 image pixels).
        let a = [
            ".###.", "#...#", "#...#", "#####", "#...#", "#...#", "#...#",
        ];
        let t = [
            "#####", "..#..", "..#..", "..#..", "..#..", "..#..", "..#..",
        ];
        let mut img = Image::new(26, 17, BLACK);
        img.text(1, 2, "AT", 2, WHITE);
        let mut want = vec![vec!['.'; 26]; 17];
        for (k, glyph) in [a, t].iter().enumerate() {
            for (row, bits) in glyph.iter().enumerate() {
                for (col, b) in bits.chars().enumerate() {
                    if b == '#' {
                        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                            want[2 + 2 * row + dy][1 + 12 * k + 2 * col + dx] = '#';
                        }
                    }
                }
            }
        }
        let want: Vec<String> = want.into_iter().map(|r| r.into_iter().collect()).collect();
        assert_eq!(mask(&img, WHITE), want);
        // Scale 0 draws as scale 1.
        let mut one = Image::new(6, 7, BLACK);
        one.text(0, 0, "T", 0, WHITE);
        assert_eq!(mask(&one, WHITE)[..3], ["#####.", "..#...", "..#..."]);
    }

    #[test]
    fn blit_composites_by_source_alpha_at_the_offset_and_clips() {
        // A 2 x 2 source: white opaque, white half covered; transparent, white opaque.
        let mut src = Image::new(2, 2, WHITE);
        src.alpha = vec![1.0, 0.5, 0.0, 1.0];
        let mut img = Image::new(4, 3, BLACK);
        img.blit(&src, 1, 1);
        let v = |img: &Image| -> Vec<f64> {
            (0..img.height)
                .flat_map(|y| (0..img.width).map(move |x| (x, y)))
                .map(|(x, y)| img.get(x, y)[0])
                .collect()
        };
        #[rustfmt::skip]
        assert_eq!(v(&img), [
            0.0, 0.0, 0.0, 0.0,
            0.0, 1.0, 0.5, 0.0,
            0.0, 0.0, 1.0, 0.0,
        ]);
        // Half off the top-left corner: only the source's bottom-right pixel lands, at (0, 0).
        let mut img = Image::new(4, 3, BLACK);
        img.blit(&src, -1, -1);
        assert_eq!(mask(&img, WHITE), ["#...", "....", "...."]);
        // Half off the bottom-right corner: only its top-left pixel lands, at (3, 2).
        let mut img = Image::new(4, 3, BLACK);
        img.blit(&src, 3, 2);
        assert_eq!(mask(&img, WHITE), ["....", "....", "...#"]);
    }

    #[test]
    fn over_composites_onto_an_opaque_background() {
        let mut img = Image::new(2, 1, [1.0, 0.0, 0.0]);
        img.alpha = vec![0.25, 0.0];
        let out = img.over([0.0, 0.0, 1.0]);
        // 0.25 red + 0.75 blue; the uncovered pixel is the background; both opaque.
        assert_eq!(out.rgb, [[0.25, 0.0, 0.75], [0.0, 0.0, 1.0]]);
        assert_eq!(out.alpha, [1.0, 1.0]);
    }

    #[test]
    fn exposure_multiplies_colours_by_two_to_the_ev_and_keeps_coverage() {
        let mut img = Image::new(2, 1, [0.5, 0.25, 3.0]);
        img.alpha[1] = 0.5;
        let up = img.exposed(1.0);
        assert_eq!(up.rgb, [[1.0, 0.5, 6.0]; 2]);
        assert_eq!(up.alpha, [1.0, 0.5]);
        assert_eq!(img.exposed(-2.0).rgb, [[0.125, 0.0625, 0.75]; 2]);
    }

    #[test]
    fn rgba8_bytes_encode_srgb_and_round_clamped_coverage() {
        let mut img = Image::new(4, 1, BLACK);
        // Linear 0.5 encodes to 188 (1.055 x 0.5^(1/2.4) - 0.055 = 0.7354, x 255 = 187.5
        // -> 188); 1 to 255, below 0 and above 1 clip to 0 and 255.
        img.rgb = vec![[0.0, 0.5, 1.0], [-1.0, 2.0, 0.5], BLACK, WHITE];
        // Coverage x 255 rounded: 0.5 -> 127.5 -> 128; clamped outside [0, 1].
        img.alpha = vec![1.0, 0.5, -1.0, 1.5];
        #[rustfmt::skip]
        assert_eq!(img.to_rgba8(), [
            0, 188, 255, 255,
            0, 255, 188, 128,
            0, 0, 0, 0,
            255, 255, 255, 255,
        ]);
    }

    #[test]
    fn empty_images_are_not_written() {
        let dir = tempfile::tempdir().unwrap();
        for (w, h) in [(0, 3), (3, 0), (0, 0)] {
            let p = dir.path().join(format!("{w}x{h}.png"));
            let e = Image::new(w, h, BLACK)
                .save_png(&p)
                .unwrap_err()
                .to_string();
            assert!(e.ends_with(": empty image"), "{w}x{h}: {e}");
            assert!(!p.exists(), "{w}x{h}");
        }
    }

    /// Writes a PNG of the given layout and raw data with the png crate.
    fn write_raw_png(
        path: &Path,
        w: u32,
        h: u32,
        colour: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
    ) {
        let file = std::fs::File::create(path).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
        enc.set_color(colour);
        enc.set_depth(depth);
        let mut wr = enc.write_header().unwrap();
        wr.write_image_data(data).unwrap();
        wr.finish().unwrap();
    }

    #[test]
    fn rgb_pngs_read_back_opaque_and_other_layouts_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rgb.png");
        write_raw_png(
            &p,
            2,
            1,
            png::ColorType::Rgb,
            png::BitDepth::Eight,
            &[1, 2, 3, 250, 251, 252],
        );
        let (w, h, px) = read_png_rgba8(&p).unwrap();
        assert_eq!((w, h), (2, 1));
        assert_eq!(px, [1, 2, 3, 255, 250, 251, 252, 255]);
        // RGBA comes back as stored.
        let p = dir.path().join("rgba.png");
        write_raw_png(
            &p,
            1,
            2,
            png::ColorType::Rgba,
            png::BitDepth::Eight,
            &[9, 8, 7, 6, 5, 4, 3, 2],
        );
        assert_eq!(
            read_png_rgba8(&p).unwrap(),
            (1, 2, vec![9, 8, 7, 6, 5, 4, 3, 2])
        );
        // 8-bit grey and 16-bit RGB: errors naming the file and the layout, no panic.
        let grey = dir.path().join("grey.png");
        write_raw_png(
            &grey,
            2,
            1,
            png::ColorType::Grayscale,
            png::BitDepth::Eight,
            &[0, 255],
        );
        let deep = dir.path().join("deep.png");
        write_raw_png(
            &deep,
            1,
            1,
            png::ColorType::Rgb,
            png::BitDepth::Sixteen,
            &[0; 6],
        );
        for p in [grey, deep] {
            let e = read_png_rgba8(&p).unwrap_err().to_string();
            assert!(e.starts_with(&format!("reading {}: ", p.display())), "{e}");
            assert!(e.contains("unsupported PNG layout"), "{e}");
        }
        // Not a PNG at all: an error, no panic.
        let junk = dir.path().join("junk.png");
        std::fs::write(&junk, b"not a png").unwrap();
        assert!(read_png_rgba8(&junk).is_err());
    }

    #[test]
    fn ramp_passes_through_the_viridis_colours_and_clamps() {
        // The published viridis colours at 0, 1/4, 1/2, 3/4, 1 (matplotlib: #440154, #3b528b,
        // #21918c, #5ec962, #fde725), as 8-bit sRGB codes; the ramp's stops round them to 3
        // decimals, so its codes may differ by 1.
        let viridis = [
            (0.0, [0x44, 0x01, 0x54]),
            (0.25, [0x3b, 0x52, 0x8b]),
            (0.5, [0x21, 0x91, 0x8c]),
            (0.75, [0x5e, 0xc9, 0x62]),
            (1.0, [0xfd, 0xe7, 0x25]),
        ];
        for (t, want) in viridis {
            let got = ramp(t).map(to_srgb8);
            for (g, w) in got.iter().zip(want) {
                assert!(g.abs_diff(w) <= 1, "t = {t}: {got:?} vs {want:?}");
            }
        }
        // Between stops the ramp interpolates the encoded values linearly: at 1/8, 3/8, 5/8
        // and 7/8 the encoding is the mean of its neighbours' encodings. 1e-12: one decode and
        // one encode (powf) each side.
        let enc = |t: f64| ramp(t).map(crate::colour::srgb_encode);
        for k in [1.0, 3.0, 5.0, 7.0] {
            let (lo, mid, hi) = (enc((k - 1.0) / 8.0), enc(k / 8.0), enc((k + 1.0) / 8.0));
            for c in 0..3 {
                assert!(
                    (mid[c] - (lo[c] + hi[c]) / 2.0).abs() < 1e-12,
                    "{k}/8: {mid:?}"
                );
            }
        }
        // A quarter of the way from the 3/4 stop to the 1 stop.
        let (lo, q, hi) = (enc(0.75), enc(0.8125), enc(1.0));
        for c in 0..3 {
            assert!(
                (q[c] - (0.75 * lo[c] + 0.25 * hi[c])).abs() < 1e-12,
                "{q:?}"
            );
        }
        // Outside [0, 1] the ends; NaN the start.
        assert_eq!(ramp(-2.0), ramp(0.0));
        assert_eq!(ramp(5.0), ramp(1.0));
        assert_eq!(ramp(f64::NAN), ramp(0.0));
        assert_eq!(ramp(f64::INFINITY), ramp(1.0));
        assert_eq!(ramp(f64::NEG_INFINITY), ramp(0.0));
    }
}
