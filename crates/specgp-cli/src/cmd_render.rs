//! `specgp render SOURCE --out IMAGE.png`: a sphere (or grazing-view plane) preview of any BRDF
//! source, and
//! `specgp map MODEL.toml --out MAP.png`: the latent space as a picture.

use std::path::PathBuf;

use anyhow::{Context, bail};
use render::{Illuminant, SphereOptions};

use crate::cmd_sample::open_source;

/// Arguments of `specgp render`.
#[derive(Debug, Clone, clap::Args)]
pub struct RenderArgs {
    /// The BRDF: an RGL `.bsdf` file, a MERL `.binary` file, `DATA.sbrdf:MATERIAL` or
    /// `MODEL.toml@X1,...,Xq` (all q latent coordinates: a predicted material, by the exact
    /// predictor unless --smooth, rendered lazily: only the cells the picture touches are
    /// predicted), as for `sample`.
    pub source: String,
    /// Output PNG (8-bit sRGB with alpha).
    #[arg(long)]
    pub out: PathBuf,
    /// Image width and height in pixels (1..=8192).
    #[arg(long, default_value_t = 256, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=render::map::MAX_MAP_PIXELS as u64))]
    pub size: usize,
    /// Direction of the light THETA,PHI in degrees: THETA from the view axis, PHI from the
    /// right towards up. Default: 45,135 (upper left) for a sphere; for a plane, behind the
    /// sample 26 degrees short of the mirror direction of the view at its centre (130,90 at
    /// --view 78), so that glossy samples show their sheen.
    #[arg(long, allow_hyphen_values = true)]
    pub light: Option<String>,
    /// Illuminant of spectral sources: D65, D50 or A. Colours are white-balanced to D65
    /// (Bradford), as a camera would: a white material looks white under each; coloured ones
    /// shift. RGB sources are shown as stored, so D50 and A are refused for them.
    #[arg(long, default_value = "D65")]
    pub illuminant: String,
    /// Exposure in stops (colours multiplied by 2^EV).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub exposure: f64,
    /// Background colour behind the sphere: `none` (transparent) or a grey level 0..1.
    #[arg(long, default_value = "none")]
    pub background: String,
    /// What to render: `sphere`, or `plane` (a flat square sample seen at a grazing angle,
    /// see --view).
    #[arg(long, default_value = "sphere")]
    pub shape: String,
    /// With `--shape plane`: angle in degrees between the sample's normal and the view
    /// direction at its centre (0..89; default 78).
    #[arg(long, allow_negative_numbers = true)]
    pub view: Option<f64>,
    /// The environment: the dim uniform one integrated as `table` (pre-integrated over the
    /// view angle once per render through the half vector, accurate on the sharpest lobes;
    /// isotropic BRDFs, i.e. every specgp source), `fast` (a coarser table: a quarter of the
    /// lookups, a few 8-bit steps off at grazing views of sharp materials) or `per-pixel` (20
    /// directions per pixel, coarse on sharp lobes); or `studio`, a bright sky over a dark floor
    /// (per pixel, slower), in which metals and mirrors show a horizon instead of looking like
    /// black plastic.
    #[arg(long, default_value = "table")]
    pub env: String,
    /// With a model point: the smooth predictor (the noise-free posterior mean, continuous in
    /// the latent point) instead of the exact one.
    #[arg(long)]
    pub smooth: bool,
    #[command(flatten)]
    pub lookup: crate::cmd_sample::LookupArg,
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

/// Parses `--env`: `table`, `fast`, `per-pixel` or `studio`.
pub fn parse_env(s: &str) -> anyhow::Result<render::EnvMode> {
    s.parse()
        .map_err(|_| anyhow::anyhow!("--env {s:?}: expected {}", render::ENV_MODE_NAMES))
}

/// Runs `specgp render`.
pub fn render(args: &RenderArgs) -> anyhow::Result<()> {
    let source = crate::paths::source_file(&args.source);
    crate::paths::ensure_output_is_not_an_input(&args.out, &[&source])?;
    crate::paths::ensure_extension(&args.out, "png", "a PNG image")?;
    crate::paths::refuse_binary_on_terminal(&args.out, "a PNG image")?;
    let env_mode = parse_env(&args.env)?;
    let plane = match args.shape.as_str() {
        "sphere" => {
            if let Some(v) = args.view {
                bail!("--view {v} applies to --shape plane (a sphere shows every view angle)");
            }
            None
        }
        "plane" => Some(render::PlaneOptions {
            view: args.view.unwrap_or(render::PlaneOptions::default().view),
            ..render::PlaneOptions::default()
        }),
        s => bail!("--shape {s:?}: expected `sphere` or `plane`"),
    };
    let opts = SphereOptions {
        size: args.size,
        light: match (&args.light, &plane) {
            (Some(light), _) => parse_light(light)?,
            (None, Some(plane)) => plane.sheen_light(),
            (None, None) => SphereOptions::default().light,
        },
        illuminant: args.illuminant.parse::<Illuminant>()?,
        exposure: args.exposure,
        env_mode,
        ..SphereOptions::default()
    };
    let start = std::time::Instant::now();
    let source = open_render_source(
        &args.source,
        opts.illuminant,
        crate::cmd_sample::predictor_kind(args.smooth),
    )?;
    let source = args.lookup.apply(source, &args.source)?;
    if opts.illuminant != Illuminant::D65 && source.channels() == brdf_io::Channels::Rgb {
        bail!(
            "--illuminant {}: {} is RGB, shown as stored (linear sRGB); an illuminant applies \
             to spectral sources",
            args.illuminant,
            args.source
        );
    }
    // The studio and per-pixel environments integrate hundreds of directions per pixel (a
    // 256 px studio sphere takes ~1 s, 1024 px ~17 s): a spinner on a terminal.
    let slow = matches!(
        env_mode,
        render::EnvMode::Studio | render::EnvMode::PerPixel
    ) || args.size > 1024;
    let spinner = indicatif::ProgressBar::new_spinner();
    if slow {
        spinner.set_message(format!("rendering {} ({} px)", args.source, args.size));
        spinner.enable_steady_tick(std::time::Duration::from_millis(120));
    }
    let img = match &plane {
        None => render::render_sphere(source.as_ref(), &opts),
        Some(p) => render::render_plane(source.as_ref(), &opts, p),
    };
    spinner.finish_and_clear();
    let img = img.with_context(|| format!("rendering {}", args.source))?;
    finish(args, img, start)
}

/// Opens SOURCE for rendering: only the wavelengths the observer needs are looked up where the
/// source can select them; model points (`MODEL.toml@X,Y`) are predicted lazily, cell by cell
/// (the renderer evaluates each cell a picture touches once).
pub fn open_render_source(
    spec: &str,
    illuminant: Illuminant,
    kind: predict::PredictorKind,
) -> anyhow::Result<Box<dyn brdf_io::BrdfSource>> {
    // Ask the source only for the wavelengths the observer needs, where it can select them
    // (spectral .bsdf files, stored materials, model points); others return all their channels.
    if let Some(m) = crate::cmd_predict::open_model_source(spec, None, kind) {
        let mut m = m?;
        if let Some(w) = render::colour::needed_wavelengths(m.channels(), illuminant)? {
            m = m.with_wavelengths(&w)?;
        }
        return Ok(Box::new(m));
    }
    let mut source = open_source(spec, None, kind)?;
    let needed = render::colour::needed_wavelengths(&source.channels(), illuminant)?;
    if let Some(sub) = needed {
        match open_source(spec, Some(&sub), kind) {
            Ok(s) => {
                tracing::info!(
                    wavelengths = sub.len(),
                    "looking up only the wavelengths the observer needs"
                );
                source = s;
            }
            Err(e) => tracing::debug!("source keeps all its channels: {e:#}"),
        }
    }
    Ok(source)
}

/// Composites over the background and writes the PNG.
fn finish(args: &RenderArgs, img: render::Image, start: std::time::Instant) -> anyhow::Result<()> {
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

/// Arguments of `specgp map`.
#[derive(Debug, clap::Args)]
pub struct MapArgs {
    /// The model file (TOML) written by `specgp fit`.
    pub model: PathBuf,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
    /// Add a panel of rendered spheres of predicted materials across the latent space.
    #[arg(long)]
    pub thumbnails: bool,
    /// Thumbnails per axis (with --thumbnails; 1..=64, a panel of at most 8192 pixels).
    #[arg(long, default_value_t = 6, requires = "thumbnails", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=64))]
    pub grid: usize,
    /// Side of the plot area in pixels (64..=8192). Labels that find no room are left out (the
    /// map counts them); a larger size shows more.
    #[arg(long, default_value_t = 640, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(64..=8192))]
    pub size: usize,
    /// Thumbnail sphere size in pixels (with --thumbnails; 8..=1024).
    #[arg(long, default_value_t = 64, requires = "thumbnails", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(8..=1024))]
    pub thumbnail_size: usize,
    /// The thumbnails' environment, as `render --env`: `table`, `fast`, `per-pixel`, or
    /// `studio` (a sky over a dark floor, in which metals show what they reflect; slower: 36
    /// thumbnails of 64 px take about 2 s instead of 0.4 s).
    #[arg(long, default_value = "table", requires = "thumbnails")]
    pub env: String,
    /// The thumbnails' lookup between the grid's bin centres, as `render --lookup`: `linear`
    /// or `log`.
    #[arg(long, default_value = "linear", requires = "thumbnails")]
    pub lookup: brdf_io::Lookup,
    /// With --thumbnails or --locate (the only parts of a map that read the data): the dataset
    /// store, when it moved since fitting (default: the path in the model).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Also mark where these materials outside the training set sit (as `specgp locate` finds
    /// them; drawn as labelled rings): DATA.sbrdf, DATA.sbrdf:MATERIAL, .bsdf or .binary files.
    #[arg(long, num_args = 1..)]
    pub locate: Vec<String>,
}

/// Runs `specgp map`: latent points of the first two axes (other axes at 0 for the shading and
/// thumbnails), predictive variance of the GP (`predict::Predictor::variance`), thumbnails of
/// the exact predictor's materials (lazy, only the observer's wavelengths looked up).
pub fn map(args: &MapArgs) -> anyhow::Result<()> {
    if let Some(dataset) = &args.dataset
        && !args.thumbnails
        && args.locate.is_empty()
    {
        bail!(
            "--dataset {} applies to --thumbnails and --locate, which read the data (the map \
             itself needs only the model file)",
            dataset.display()
        );
    }
    let mut inputs = crate::paths::model_inputs(&args.model, args.dataset.as_deref());
    let located_files: Vec<PathBuf> = args
        .locate
        .iter()
        .map(|t| crate::paths::source_file(t))
        .collect();
    inputs.extend(located_files.iter().map(PathBuf::as_path));
    crate::paths::ensure_output_is_not_an_input(&args.out, &inputs)?;
    crate::paths::ensure_extension(&args.out, "png", "a PNG image")?;
    crate::paths::refuse_binary_on_terminal(&args.out, "a PNG image")?;
    let env_mode = parse_env(&args.env)?;
    let start = std::time::Instant::now();
    let model = gplvm::Model::load(&args.model)?;
    if model.latent_dim < 1 {
        bail!("{}: the model has no latent axes", args.model.display());
    }
    let q = model.latent_dim;
    let full = |p: [f64; 2]| {
        let mut x = vec![0.0; q];
        x[0] = p[0];
        if q > 1 {
            x[1] = p[1];
        }
        x
    };
    let on_map = |x: &[f64]| [x[0], x.get(1).copied().unwrap_or(0.0)];
    let mut points: Vec<(String, [f64; 2])> = model
        .materials
        .iter()
        .map(|m| (m.name.clone(), on_map(&m.coords)))
        .collect();
    // The model with its data, for thumbnails and located materials (once for both).
    let pred = if args.thumbnails || !args.locate.is_empty() {
        Some(
            predict::Predictor::open_with_dataset(&args.model, args.dataset.as_deref())
                .with_context(|| format!("opening model {}", args.model.display()))?,
        )
    } else {
        None
    };
    let located = match &pred {
        Some(pred) if !args.locate.is_empty() => {
            crate::cmd_locate::locate_targets(pred, &args.locate, 3)?
        }
        _ => Vec::new(),
    };
    for l in &located {
        errln!(
            "located {} at {} (Eq. 22 RMSE {:.4e} in BRDF space)",
            l.name,
            crate::cmd_predict::format_point(&l.point),
            l.brdf_rmse
        );
        // A located variant of a training material keeps its name: say which is which.
        let label = if model.materials.iter().any(|m| m.name == l.name) {
            format!("{} (located)", l.name)
        } else {
            l.name.clone()
        };
        points.push((label, on_map(&l.point)));
    }
    let opts = render::MapOptions {
        predicted_points: located.len(),
        size: args.size,
        thumbnails: if args.thumbnails { args.grid } else { 0 },
        sphere: SphereOptions {
            size: args.thumbnail_size,
            env_mode,
            ..SphereOptions::default()
        },
        caption: render::map::variance_caption(&model.transform.to_string(), q),
        one_axis: q == 1,
        ..render::MapOptions::default()
    };
    // Variance per transformed value, as `predict --variance` and the reports give it.
    let scale = model.data_scale;
    let img = if let Some(pred) = pred.filter(|_| args.thumbnails) {
        // Thumbnails are lazy predictions: read an existing sidecar like `render` does, else
        // keep each cell's logarithms for the next thumbnail.
        let pred = crate::cmd_predict::with_existing_sidecar(pred)?.with_forward_cache();
        let needed = render::colour::needed_wavelengths(pred.channels(), opts.sphere.illuminant)?;
        // Thumbnails where the materials explain less than a tenth of the prior variance are
        // framed as far from every material (as `predict` warns about such points).
        let opts = render::MapOptions {
            far_variance: Some(predict::PointSupport::FAR * pred.prior_variance() * scale),
            ..opts
        };
        let variance = |p: [f64; 2]| -> render::Result<f64> {
            pred.variance(&full(p))
                .map(|v| v * scale)
                .map_err(|e| render::Error::InvalidArgument {
                    reason: e.to_string(),
                })
        };
        let source_at = |p: [f64; 2]| -> render::Result<Box<dyn brdf_io::BrdfSource + '_>> {
            let err = |e: predict::Error| render::Error::InvalidArgument {
                reason: e.to_string(),
            };
            let mut m = pred
                .predict(&full(p), predict::PredictorKind::Exact)
                .map_err(err)?;
            if let Some(w) = &needed {
                m = m.with_wavelengths(w).map_err(err)?;
            }
            Ok(Box::new(brdf_io::lookup::WithLookup::new(m, args.lookup)?))
        };
        // Studio and per-pixel thumbnails take seconds (36 of 64 px: ~2 s): a spinner.
        let spinner = indicatif::ProgressBar::new_spinner();
        if matches!(
            env_mode,
            render::EnvMode::Studio | render::EnvMode::PerPixel
        ) {
            spinner.set_message(format!("rendering {} thumbnails", args.grid * args.grid));
            spinner.enable_steady_tick(std::time::Duration::from_millis(120));
        }
        let img = render::latent_map(&points, &variance, Some(&source_at), &opts);
        spinner.finish_and_clear();
        img?
    } else {
        // The variance needs only the latent points and hyperparameters, not the data.
        let params = predict::kernel_params(&model)?;
        let gp =
            gp_core::GpRegression::new(model.latent_matrix().as_ref(), params, faer::Par::Seq)?;
        let variance = |p: [f64; 2]| -> render::Result<f64> {
            gp.variance(&full(p))
                .map(|v| v * scale)
                .map_err(|e| render::Error::InvalidArgument {
                    reason: e.to_string(),
                })
        };
        render::latent_map(&points, &variance, None, &opts)?
    };
    img.save_png(&args.out)?;
    tracing::info!(
        seconds = start.elapsed().as_secs_f64(),
        out = %args.out.display(),
        "latent map of {}",
        args.model.display()
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

    #[test]
    fn renders_a_real_rgl_file_to_png() {
        let Some(file) = shared_data::path("rgl-rgb/vch_golden_yellow_rgb.bsdf") else {
            return;
        };
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("s.png");
        let args = RenderArgs {
            source: file.to_str().unwrap().into(),
            out: out.clone(),
            size: 32,
            light: None,
            illuminant: "D65".into(),
            exposure: 0.0,
            background: "0.5".into(),
            shape: "sphere".into(),
            view: None,
            env: "table".into(),
            smooth: false,
            lookup: Default::default(),
        };
        render(&args).unwrap();
        let (w, h, px) = render::image::read_png_rgba8(&out).unwrap();
        assert_eq!((w, h), (32, 32));
        // Corner: the grey background; the sphere's lower right: yellow (R > G > B).
        assert_eq!(&px[..4], &[128, 128, 128, 255]);
        let i = (22 * 32 + 20) * 4;
        assert!(
            px[i] > px[i + 1] && px[i + 1] > px[i + 2],
            "{:?}",
            &px[i..i + 4]
        );
        // The grazing-view plane: a yellow band across the middle, background above and below.
        let plane = RenderArgs {
            shape: "plane".into(),
            view: Some(78.0),
            ..args.clone()
        };
        render(&plane).unwrap();
        let (_, _, px) = render::image::read_png_rgba8(&out).unwrap();
        assert_eq!(&px[..4], &[128, 128, 128, 255]);
        let i = (16 * 32 + 16) * 4;
        assert!(
            px[i] > px[i + 1] && px[i + 1] > px[i + 2],
            "{:?}",
            &px[i..i + 4]
        );
        // The plane's default light is its sheen light, not the sphere's (45,135) in front
        // of the sample: the glossy paint's centre is brighter under it.
        let sum = |p: &[u8]| p[..3].iter().map(|&c| c as u32).sum::<u32>();
        let sheen = sum(&px[i..i + 4]);
        render(&RenderArgs {
            light: Some("45,135".into()),
            ..plane.clone()
        })
        .unwrap();
        let (_, _, front) = render::image::read_png_rgba8(&out).unwrap();
        assert!(
            sheen > sum(&front[i..i + 4]) + 30,
            "{sheen} vs {:?}",
            &front[i..i + 4]
        );
        for (field, bad) in [
            (
                "illuminant",
                RenderArgs {
                    illuminant: "F2".into(),
                    ..plane.clone()
                },
            ),
            (
                "shape",
                RenderArgs {
                    shape: "cube".into(),
                    ..plane.clone()
                },
            ),
            (
                "view",
                RenderArgs {
                    view: Some(90.0),
                    ..plane.clone()
                },
            ),
            (
                "env",
                RenderArgs {
                    env: "mc".into(),
                    ..plane.clone()
                },
            ),
            (
                "view of a sphere",
                RenderArgs {
                    view: Some(60.0),
                    ..args.clone()
                },
            ),
        ] {
            assert!(render(&bad).is_err(), "bad {field} accepted");
        }
        // An illuminant other than D65 would be ignored by an RGB source: refused, by name.
        let e = render(&RenderArgs {
            illuminant: "A".into(),
            ..args.clone()
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("--illuminant A") && e.contains("vch_golden_yellow_rgb.bsdf is RGB"),
            "{e}"
        );
        render(&RenderArgs {
            illuminant: "d65".into(),
            ..args.clone()
        })
        .unwrap();
        // An output that is a directory is refused before rendering.
        let e = render(&RenderArgs {
            out: dir.path().to_owned(),
            ..args.clone()
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("it is a directory"), "{e}");
        // An output directory that does not exist is refused before rendering, by name.
        let missing = dir.path().join("no-such-dir").join("s.png");
        let e = render(&RenderArgs {
            out: missing,
            ..args
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("no-such-dir does not exist") && !e.contains(".s.png."),
            "{e}"
        );
    }
}
