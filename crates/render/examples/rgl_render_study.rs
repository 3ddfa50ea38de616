//! Study: how close a written RGL `.bsdf` file renders to the material it was written from, with
//! the file's incident slice chosen by the view (the renderer's order, `eval(view, light)`, as
//! Mitsuba 3's `measured` plugin reads `si.wi`) and by the light (the arguments swapped).
//! A written file is not exactly reciprocal (each incident slice is resampled on its own
//! warped table), so the two orders differ; the source material (a grid, reciprocal) does not
//! care.
//!
//! ```sh
//! specgp synth --out /tmp/rb/s.sbrdf --grid 32,32,64
//! specgp convert /tmp/rb/s.sbrdf:carpaint_solid_red --out /tmp/rb/cp.bsdf
//! cargo run --release -p render --example rgl_render_study -- /tmp/rb/cp.bsdf /tmp/rb/s.sbrdf:carpaint_solid_red [SIZE]
//! cargo run --release -p render --example rgl_render_study -- ../shared/data/rgl-rgb/paper_white_rgb.bsdf
//! ```
//! With only FILE, prints how far apart the two orders render the file itself (128 px).
//! Otherwise prints, for the default scene and the environment alone: the largest and mean linear sRGB
//! difference of each file render against the source's and the largest 8-bit code difference;
//! then the directional albedo (channel nearest 560 nm) at view angles 0-88 degrees, by a dense
//! half-vector quadrature, for the source and the file in both orders.

use brdf_io::store::{StoreMaterial, parse_store_spec};
use brdf_io::{BrdfSource, Channels, Vec3};
use render::sphere::HalfVectorQuadrature;
use render::{EnvMode, EnvTableSpec, Image, SphereOptions, render_sphere};

/// `inner` with its two directions swapped: `eval(wi, wo)` = `inner.eval(wo, wi)`.
struct Swapped<'a>(&'a dyn BrdfSource);

impl BrdfSource for Swapped<'_> {
    fn channels(&self) -> Channels {
        self.0.channels()
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        self.0.eval(wo, wi, out)
    }
}

/// The directional albedo of channel `c` of `src` at view angle `deg`:
/// the integral of f(view, light) cos(theta_light) over the light's hemisphere.
fn albedo(src: &dyn BrdfSource, c: usize, deg: f64) -> Result<f64, brdf_io::Error> {
    let q = HalfVectorQuadrature::new(1024, 64);
    let (s, co) = deg.to_radians().sin_cos();
    let view = [s, 0.0, co];
    let mut f = vec![0.0; src.channels().len()];
    let (mut acc, mut err) = (0.0, Ok(()));
    q.for_each(view, |light, w| {
        if err.is_ok() {
            match src.eval(view, light, &mut f) {
                Ok(()) => acc += w * f[c],
                Err(e) => err = Err(e),
            }
        }
    });
    err.map(|()| acc)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: rgl_render_study FILE.bsdf DATA.sbrdf:MATERIAL [SIZE]";
    let file = brdf_io::rgl::RglBsdf::open(args.get(1).ok_or(usage)?)?;
    let swapped = Swapped(&file);
    let Some(spec) = args.get(2) else {
        // No source material: how far apart the two orders render the file itself.
        for (scene, light_irradiance) in [("default scene", None), ("environment only", Some(0.0))]
        {
            let mut opts = SphereOptions {
                size: 128,
                ..SphereOptions::default()
            };
            if let Some(e) = light_irradiance {
                opts.light_irradiance = e;
            }
            let (a, b) = (
                render_sphere(&file, &opts)?,
                render_sphere(&swapped, &opts)?,
            );
            let render::ImageDifference { max, mean, codes } = a.difference(&b)?;
            // The same inside 75 degrees of view (sphere radius < sin 75), away from the rim.
            let r = 64.0 * 75f64.to_radians().sin();
            let inner = |img: &Image| {
                let mut img = img.clone();
                for (i, al) in img.alpha.iter_mut().enumerate() {
                    let (x, y) = ((i % 128) as f64 + 0.5 - 64.0, (i / 128) as f64 + 0.5 - 64.0);
                    if x * x + y * y > r * r {
                        *al = 0.0;
                    }
                }
                img
            };
            let render::ImageDifference {
                max: imax,
                mean: imean,
                codes: icodes,
            } = inner(&a).difference(&inner(&b))?;
            println!(
                "{scene}, view slice against light slice: max {max:.3e}, mean {mean:.3e}, {codes} codes; inside 75 degrees: max {imax:.3e}, mean {imean:.3e}, {icodes} codes"
            );
        }
        return Ok(());
    };
    let (store, name) = parse_store_spec(spec).ok_or(usage)?;
    let source = StoreMaterial::open(&store, &name)?;
    let size: usize = args.get(3).map_or(Ok(128), |s| s.parse())?;
    for (scene, light_irradiance) in [("default scene", None), ("environment only", Some(0.0))] {
        let mut opts = SphereOptions {
            size,
            env_mode: EnvMode::Table(EnvTableSpec::default()),
            ..SphereOptions::default()
        };
        if let Some(e) = light_irradiance {
            opts.light_irradiance = e;
        }
        let reference = render_sphere(&source, &opts)?;
        for (label, src) in [
            ("file, renderer's order", &file as &dyn BrdfSource),
            ("file, swapped", &swapped),
        ] {
            let render::ImageDifference { max, mean, codes } =
                render_sphere(src, &opts)?.difference(&reference)?;
            println!("{scene}, {label}: max {max:.3e}, mean {mean:.3e}, {codes} codes");
        }
    }
    let channels = source.channels();
    let c = match &channels {
        Channels::Spectral(w) => (0..w.len())
            .min_by(|&a, &b| (w[a] - 560.0).abs().total_cmp(&(w[b] - 560.0).abs()))
            .unwrap_or(0),
        _ => 1,
    };
    println!("albedo of channel {c} (view angle: source | file, renderer's order | swapped)");
    for deg in [0.0, 20.0, 40.0, 50.0, 60.0, 70.0, 80.0, 85.0, 88.0] {
        let a = albedo(&source, c, deg)?;
        let b = albedo(&file, c, deg)?;
        let s = albedo(&swapped, c, deg)?;
        println!(
            "{deg:>4} deg: {a:.4} | {b:.4} ({:+.1} %) | {s:.4} ({:+.1} %)",
            100.0 * (b / a - 1.0),
            100.0 * (s / a - 1.0)
        );
    }
    Ok(())
}
