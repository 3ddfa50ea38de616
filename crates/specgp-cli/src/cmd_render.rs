//! `specgp render SOURCE --out IMAGE.png`: a sphere preview of any BRDF source, and
//! `specgp map MODEL.toml --out MAP.png`: the latent space as a picture.

use std::path::PathBuf;

use anyhow::{Context, bail};
use render::{Illuminant, SphereOptions};

use crate::cmd_sample::open_source;

/// Arguments of `specgp render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// The BRDF: an RGL `.bsdf` file, a MERL `.binary` file or `DATA.sbrdf:MATERIAL` (as for
    /// `sample`).
    pub source: String,
    /// Output PNG (8-bit sRGB with alpha).
    #[arg(long)]
    pub out: PathBuf,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    /// Direction of the light THETA,PHI in degrees: THETA from the view axis, PHI from the
    /// right towards up.
    #[arg(long, default_value = "45,135")]
    pub light: String,
    /// Illuminant of spectral sources: D65, D50 or A (white-balanced to D65).
    #[arg(long, default_value = "D65")]
    pub illuminant: String,
    /// Exposure in stops (colours multiplied by 2^EV).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub exposure: f64,
    /// Background colour behind the sphere: `none` (transparent) or a grey level 0..1.
    #[arg(long, default_value = "none")]
    pub background: String,
}

/// Parses `THETA,PHI` (degrees).
pub fn parse_light(s: &str) -> anyhow::Result<(f64, f64)> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 2 {
        bail!("--light {s:?}: expected THETA,PHI in degrees");
    }
    let t: f64 = parts[0]
        .parse()
        .with_context(|| format!("--light {s:?}: THETA is not a number"))?;
    let p: f64 = parts[1]
        .parse()
        .with_context(|| format!("--light {s:?}: PHI is not a number"))?;
    if !(0.0..=180.0).contains(&t) || !p.is_finite() {
        bail!("--light {s:?}: THETA must be in [0, 180] degrees and PHI finite");
    }
    Ok((t, p))
}

/// Runs `specgp render`.
pub fn render(args: &RenderArgs) -> anyhow::Result<()> {
    let opts = SphereOptions {
        size: args.size,
        light: parse_light(&args.light)?,
        illuminant: args.illuminant.parse::<Illuminant>()?,
        exposure: args.exposure,
        ..SphereOptions::default()
    };
    let source = open_source(&args.source, None)?;
    let start = std::time::Instant::now();
    let img = render::render_sphere(source.as_ref(), &opts)
        .with_context(|| format!("rendering {}", args.source))?;
    let img = match args.background.as_str() {
        "none" => img,
        g => {
            let v: f64 = g
                .parse()
                .ok()
                .filter(|v: &f64| (0.0..=1.0).contains(v))
                .with_context(|| format!("--background {g:?}: expected `none` or 0..1"))?;
            img.over([render::colour::srgb_decode(v); 3])
        }
    };
    img.save_png(&args.out)?;
    tracing::info!(
        seconds = start.elapsed().as_secs_f64(),
        out = %args.out.display(),
        "rendered {}",
        args.source
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_light() {
        assert_eq!(parse_light("30, 90").unwrap(), (30.0, 90.0));
        assert!(parse_light("30").is_err());
        assert!(parse_light("200,0").is_err());
        assert!(parse_light("x,0").is_err());
    }
}
