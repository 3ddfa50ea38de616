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
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * (STOPS.len() - 1) as f64;
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
        let dir = std::env::temp_dir().join(format!("render-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
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
            std::fs::read_dir(&dir).unwrap().count() == 1,
            "no temp file left"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn png_errors_name_the_file_once_and_say_what_failed() {
        let dir = std::env::temp_dir().join(format!("render-img-err-{}", std::process::id()));
        let p = dir.join("missing/t.png");
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
}
