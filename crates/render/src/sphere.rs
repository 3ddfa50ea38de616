//! Sphere previews: an orthographic unit sphere under a directional light plus a dim uniform
//! environment, every pixel evaluated through [`BrdfSource::eval`].
//!
//! Scene (camera frame: x right, y up, z towards the viewer; the view direction is +z):
//! - a directional light from `light` (polar angle from the view axis, azimuth from +x towards
//!   +y, degrees) with irradiance [`SphereOptions::light_irradiance`] on a surface facing it;
//! - a uniform environment of radiance [`SphereOptions::env_radiance`] from every direction.
//!   A uniform environment looks the same from every surface point, so it is integrated in the
//!   local frame with a fixed, deterministic quadrature of at most [`ENV_SAMPLES`] directions
//!   per pixel that partitions the hemisphere: nested cones of half-angles [`ENV_CAP_DEGREES`]
//!   around the mirror direction of the view (the innermost cone and each ring between two
//!   cones get [`ENV_CAP`] directions, uniform in solid angle, stratified in cos theta with
//!   golden-angle azimuths; each weighs its region's solid angle / [`ENV_CAP`] x cos theta_i),
//!   and the rest of the hemisphere, covered by those of [`ENV_COSINE`] fixed cosine-weighted
//!   directions (stratified likewise) that fall outside the outer cone, sharing the rest's
//!   projected solid angle (pi minus the cones' share, estimated from the cone samples). A
//!   Lambertian gets exactly pi f; glossy lobes are resolved by the cones; the quadrature moves
//!   continuously with the view direction, so the shading is smooth (no noise, no polka dots of
//!   reflected point lights);
//! - both lights have the illuminant's spectrum (a spectral source's value at each wavelength is
//!   weighted by the illuminant and the observer, [`crate::colour::ColourPipeline`]).
//!
//! Pixel radiance = sum over lights of f(wi, wo) cos(theta_i) E (E = irradiance, or radiance x
//! solid angle for environment directions), `wi` = light direction, `wo` = view direction, both
//! in the local frame of the surface point (z = normal, a branchless orthonormal basis for the
//! tangents). The silhouette is anti-aliased: coverage is the fraction of 8 x 8 sub-pixel
//! positions inside the disc, and edge pixels are shaded once at the centroid of their covered
//! sub-positions. Pixels are shaded in parallel (rayon, by rows).

use brdf_io::{BrdfSource, Channels, Vec3};
use rayon::prelude::*;

use crate::colour::{ColourPipeline, Illuminant};
use crate::error::{Error, Result};
use crate::image::Image;

/// Cosine-weighted environment directions per pixel.
pub const ENV_COSINE: usize = 8;
/// Environment directions per cone around the mirror direction.
pub const ENV_CAP: usize = 4;
/// Half-angles (degrees) of the cones around the mirror direction.
pub const ENV_CAP_DEGREES: [f64; 3] = [2.0, 7.0, 25.0];
/// Environment directions per pixel.
pub const ENV_SAMPLES: usize = ENV_COSINE + ENV_CAP * ENV_CAP_DEGREES.len();

/// Sub-pixel grid per axis for silhouette coverage.
const COVERAGE_SUB: usize = 8;

/// How to render a sphere.
#[derive(Debug, Clone, PartialEq)]
pub struct SphereOptions {
    /// Image width and height in pixels.
    pub size: usize,
    /// Light direction (theta, phi) in degrees: theta from the view axis, phi from +x (right)
    /// towards +y (up).
    pub light: (f64, f64),
    /// Irradiance of the directional light on a surface facing it (relative units: a white
    /// diffuser facing the light renders at `light_irradiance / pi` plus the environment).
    pub light_irradiance: f64,
    /// Radiance of the uniform environment (a white diffuser receives `env_radiance` from it
    /// when facing up).
    pub env_radiance: f64,
    /// The illuminant of spectral sources.
    pub illuminant: Illuminant,
    /// Exposure in stops: colours are multiplied by 2^exposure.
    pub exposure: f64,
}

impl Default for SphereOptions {
    /// 256 pixels, light from the upper left at 45 degrees, irradiance 2.5 (a white diffuser
    /// facing the light renders at ~0.8 linear), environment radiance 0.1, D65, exposure 0.
    fn default() -> Self {
        Self {
            size: 256,
            light: (45.0, 135.0),
            light_irradiance: 2.5,
            env_radiance: 0.1,
            illuminant: Illuminant::D65,
            exposure: 0.0,
        }
    }
}

impl SphereOptions {
    fn check(&self) -> Result<()> {
        let bad = |reason: String| Err(Error::InvalidArgument { reason });
        if self.size == 0 || self.size > 16384 {
            return bad(format!("size {} is not in 1..=16384", self.size));
        }
        let (t, p) = self.light;
        if !t.is_finite() || !p.is_finite() || !(0.0..=180.0).contains(&t) {
            return bad(format!(
                "light ({t}, {p}): theta must be in [0, 180] degrees"
            ));
        }
        for (name, v) in [
            ("light irradiance", self.light_irradiance),
            ("environment radiance", self.env_radiance),
        ] {
            if !v.is_finite() || v < 0.0 {
                return bad(format!("{name} {v} must be finite and >= 0"));
            }
        }
        if !self.exposure.is_finite() || self.exposure.abs() > 64.0 {
            return bad(format!(
                "exposure {} must be within +-64 stops",
                self.exposure
            ));
        }
        Ok(())
    }

    /// The unit direction towards the light, camera frame.
    pub fn light_dir(&self) -> Vec3 {
        let (t, p) = (self.light.0.to_radians(), self.light.1.to_radians());
        [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
    }
}

/// Stratified directions about +z: `M` points with cos(theta) = `cos_at(u)`, u = (k + 1/2) / M,
/// golden-angle azimuth.
fn stratified<const M: usize>(cos_at: impl Fn(f64) -> f64) -> [Vec3; M] {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    std::array::from_fn(|k| {
        let c = cos_at((k as f64 + 0.5) / M as f64).clamp(-1.0, 1.0);
        let r = (1.0 - c * c).max(0.0).sqrt();
        let phi = golden * k as f64;
        [r * phi.cos(), r * phi.sin(), c]
    })
}

/// The environment quadrature: sample directions for a view direction and their MIS weights.
#[derive(Debug, Clone)]
pub struct EnvQuadrature {
    cosine: [Vec3; ENV_COSINE],
    /// Per cone: cos of its half-angle and its directions about +z.
    caps: Vec<(f64, [Vec3; ENV_CAP])>,
}

impl Default for EnvQuadrature {
    fn default() -> Self {
        Self {
            cosine: stratified::<ENV_COSINE>(|u| (1.0 - u).sqrt()),
            caps: ENV_CAP_DEGREES
                .iter()
                .map(|d| {
                    let cm = d.to_radians().cos();
                    (cm, stratified::<ENV_CAP>(|u| 1.0 - u * (1.0 - cm)))
                })
                .collect(),
        }
    }
}

impl EnvQuadrature {
    /// Calls `visit(wi, weight)` for every sample direction above the horizon for the local view
    /// direction `wo` (z = normal, unit, wo.z > 0): `sum weight * f(wi, wo)` estimates the
    /// integral of f cos over the hemisphere (per unit environment radiance).
    pub fn for_each(&self, wo: Vec3, mut visit: impl FnMut(Vec3, f64)) {
        let r = [-wo[0], -wo[1], wo[2]];
        let (t, b) = basis(r);
        let to_local = |v: Vec3| {
            [
                v[0] * t[0] + v[1] * b[0] + v[2] * r[0],
                v[0] * t[1] + v[1] * b[1] + v[2] * r[1],
                v[0] * t[2] + v[1] * b[2] + v[2] * r[2],
            ]
        };
        // Cones and rings: projected solid angle they take from the hemisphere.
        let mut cone_share = 0.0;
        let mut inner = 1.0;
        for (cm, dirs) in &self.caps {
            let omega = std::f64::consts::TAU * (inner - cm) / ENV_CAP as f64;
            for &d in dirs {
                // Map the cone sample into the ring [cm, inner] in cos theta.
                let c = inner - (1.0 - d[2]) / (1.0 - cm) * (inner - cm);
                let s = (1.0 - c * c).max(0.0).sqrt();
                let h = d[0].hypot(d[1]);
                let (cx, cy) = if h > 0.0 {
                    (d[0] / h, d[1] / h)
                } else {
                    (1.0, 0.0)
                };
                let x = to_local([s * cx, s * cy, c]);
                if x[2] > 0.0 {
                    cone_share += omega * x[2];
                    visit(x, omega * x[2]);
                }
            }
            inner = *cm;
        }
        let outer = inner;
        let rest: Vec<Vec3> = self
            .cosine
            .iter()
            .copied()
            .filter(|x| dot(*x, r) < outer)
            .collect();
        if !rest.is_empty() {
            let w = (std::f64::consts::PI - cone_share).max(0.0) / rest.len() as f64;
            for x in rest {
                visit(x, w);
            }
        }
    }
}

fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Tangent and bitangent of a unit normal with n.z >= 0 (Duff et al. 2017, sign = +1).
fn basis(n: Vec3) -> (Vec3, Vec3) {
    let a = -1.0 / (1.0 + n[2]);
    let b = n[0] * n[1] * a;
    (
        [1.0 + n[0] * n[0] * a, b, -n[0]],
        [b, 1.0 + n[1] * n[1] * a, -n[1]],
    )
}

/// A shading context: the source, its linear-sRGB channel weights and the lights.
pub struct Shader<'a> {
    source: &'a dyn BrdfSource,
    /// Linear-sRGB weight rows, restricted to `needed` channels.
    weights: [Vec<f64>; 3],
    /// Channels with a non-zero weight.
    needed: Vec<usize>,
    n_channels: usize,
    /// Light directions (camera frame) and their irradiance at normal incidence.
    lights: Vec<(Vec3, f64)>,
    /// Environment radiance and its quadrature.
    env: (f64, EnvQuadrature),
    scale: f64,
}

impl<'a> Shader<'a> {
    /// Prepares shading of `source` with `opts`' lights, illuminant and exposure.
    pub fn new(source: &'a dyn BrdfSource, opts: &SphereOptions) -> Result<Self> {
        opts.check()?;
        let channels = source.channels();
        let pipeline = ColourPipeline::new(opts.illuminant);
        let full = pipeline.channel_weights(&channels)?;
        let n_channels = channels.len();
        let needed: Vec<usize> = (0..n_channels)
            .filter(|&k| full.iter().any(|row| row[k] != 0.0))
            .collect();
        let weights = [0, 1, 2].map(|r| needed.iter().map(|&k| full[r][k]).collect());
        if matches!(channels, Channels::Rgb) && opts.illuminant != Illuminant::D65 {
            tracing::warn!("RGB source: the illuminant {} is ignored", opts.illuminant);
        }
        let lights = vec![(opts.light_dir(), opts.light_irradiance)];
        let env = (opts.env_radiance, EnvQuadrature::default());
        Ok(Self {
            source,
            weights,
            needed,
            n_channels,
            lights,
            env,
            scale: 2f64.powf(opts.exposure),
        })
    }

    /// Indices of the source channels that contribute to the colour.
    pub fn needed_channels(&self) -> &[usize] {
        &self.needed
    }

    /// Linear sRGB leaving a surface point with unit normal `n` (n.z >= 0) towards the viewer.
    /// `f` and `acc` are scratch buffers of the source's channel count.
    fn shade(&self, n: Vec3, f: &mut [f64], acc: &mut [f64]) -> Result<[f64; 3]> {
        let (t, b) = basis(n);
        let local = |v: Vec3| [dot(v, t), dot(v, b), dot(v, n)];
        let wo = local([0.0, 0.0, 1.0]);
        acc.fill(0.0);
        if wo[2] <= 0.0 {
            return Ok([0.0; 3]);
        }
        for &(l, e) in &self.lights {
            let wi = local(l);
            if wi[2] <= 0.0 || e == 0.0 {
                continue;
            }
            self.source.eval(wi, wo, f)?;
            let k = wi[2] * e;
            for &c in &self.needed {
                acc[c] += k * f[c];
            }
        }
        if self.env.0 > 0.0 {
            let mut err = Ok(());
            self.env.1.for_each(wo, |wi, w| {
                if err.is_ok() {
                    err = self.source.eval(wi, wo, f);
                    let k = w * self.env.0;
                    for &c in &self.needed {
                        acc[c] += k * f[c];
                    }
                }
            });
            err?;
        }
        let mut rgb = [0.0; 3];
        for (r, row) in self.weights.iter().enumerate() {
            rgb[r] = self.scale
                * row
                    .iter()
                    .zip(&self.needed)
                    .map(|(w, &c)| w * acc[c])
                    .sum::<f64>();
        }
        Ok(rgb)
    }
}

/// Renders `source` as a sphere filling a `size x size` image (transparent outside the
/// silhouette, linear sRGB inside); see the module docs.
pub fn render_sphere(source: &dyn BrdfSource, opts: &SphereOptions) -> Result<Image> {
    let shader = Shader::new(source, opts)?;
    let size = opts.size;
    let r = size as f64 / 2.0;
    let nc = shader.n_channels;
    let mut img = Image::new(size, size, [0.0; 3]);
    img.alpha.fill(0.0);
    /// One shaded pixel: linear sRGB and coverage.
    type Px = ([f64; 3], f64);
    let rows: Vec<Result<Vec<Px>>> = (0..size)
        .into_par_iter()
        .map(|py| {
            let mut f = vec![0.0; nc];
            let mut acc = vec![0.0; nc];
            let mut row = Vec::with_capacity(size);
            for px in 0..size {
                // Disc coordinates of the pixel centre, y up.
                let cx = (px as f64 + 0.5 - r) / r;
                let cy = (r - py as f64 - 0.5) / r;
                let half = 0.5 / r;
                let dmin = (cx.abs() - half).max(0.0).hypot((cy.abs() - half).max(0.0));
                if dmin >= 1.0 {
                    row.push(([0.0; 3], 0.0));
                    continue;
                }
                let dmax = (cx.abs() + half).hypot(cy.abs() + half);
                let (sx, sy, cov) = if dmax <= 1.0 {
                    (cx, cy, 1.0)
                } else {
                    // Edge pixel: coverage and centroid of the covered sub-positions.
                    let (mut n, mut ax, mut ay) = (0usize, 0.0, 0.0);
                    for j in 0..COVERAGE_SUB {
                        for i in 0..COVERAGE_SUB {
                            let x = cx + ((i as f64 + 0.5) / COVERAGE_SUB as f64 - 0.5) / r;
                            let y = cy + ((j as f64 + 0.5) / COVERAGE_SUB as f64 - 0.5) / r;
                            if x * x + y * y < 1.0 {
                                n += 1;
                                ax += x;
                                ay += y;
                            }
                        }
                    }
                    if n == 0 {
                        row.push(([0.0; 3], 0.0));
                        continue;
                    }
                    let k = n as f64;
                    (ax / k, ay / k, k / (COVERAGE_SUB * COVERAGE_SUB) as f64)
                };
                let nz = (1.0 - sx * sx - sy * sy).max(0.0).sqrt();
                let rgb = shader.shade([sx, sy, nz], &mut f, &mut acc)?;
                row.push((rgb, cov));
            }
            Ok(row)
        })
        .collect();
    for (py, row) in rows.into_iter().enumerate() {
        for (px, (rgb, a)) in row?.into_iter().enumerate() {
            let i = py * size + px;
            img.rgb[i] = rgb;
            img.alpha[i] = a;
        }
    }
    Ok(img)
}

/// Pixel statistics of a rendered sphere: mean linear sRGB over fully covered pixels, and their
/// count.
pub fn mean_colour(img: &Image) -> ([f64; 3], usize) {
    let mut s = [0.0; 3];
    let mut n = 0;
    for (p, a) in img.rgb.iter().zip(&img.alpha) {
        if *a >= 1.0 {
            for c in 0..3 {
                s[c] += p[c];
            }
            n += 1;
        }
    }
    let k = n.max(1) as f64;
    ([s[0] / k, s[1] / k, s[2] / k], n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Lambertian BRDF with a constant spectral reflectance.
    struct Lambert(Channels, f64);

    impl BrdfSource for Lambert {
        fn channels(&self) -> Channels {
            self.0.clone()
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
            let v = if wi[2] > 0.0 && wo[2] > 0.0 {
                self.1 / std::f64::consts::PI
            } else {
                0.0
            };
            out.fill(v);
            Ok(())
        }
    }

    #[test]
    fn env_quadrature_integrates_lambert_and_mirror_like_lobes() {
        let q = EnvQuadrature::default();
        let g = (1.0f64 - 0.95 * 0.95).sqrt();
        for wo in [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.95, g]] {
            // integral of cos over the hemisphere = pi.
            let mut s = 0.0;
            let mut n = 0;
            q.for_each(wo, |wi, w| {
                assert!(wi[2] > 0.0 && (dot(wi, wi) - 1.0).abs() < 1e-9);
                s += w;
                n += 1;
            });
            assert!(n <= ENV_SAMPLES);
            assert!(
                (s / std::f64::consts::PI - 1.0).abs() < 1e-12,
                "{wo:?}: {s}"
            );
            // A narrow normalised lobe around the mirror direction (Phong, exponent 2000) has
            // integral ~1 (times cos at the mirror direction).
            let e = 2000.0;
            let r = [-wo[0], -wo[1], wo[2]];
            let mut s = 0.0;
            q.for_each(wo, |wi, w| {
                let c = dot(wi, r).max(0.0);
                s += w * (e + 1.0) / std::f64::consts::TAU * c.powf(e) / wi[2];
            });
            assert!((s - 1.0).abs() < 0.25, "{wo:?}: mirror lobe {s}");
        }
        let (t, b) = basis([0.6, 0.0, 0.8]);
        assert!(dot(t, b).abs() < 1e-12 && dot(t, [0.6, 0.0, 0.8]).abs() < 1e-12);
    }

    #[test]
    fn white_diffuser_is_neutral_and_matches_the_analytic_shading() {
        let src = Lambert(Channels::parse_wavelengths("360:1000:20").unwrap(), 1.0);
        let opts = SphereOptions {
            size: 64,
            light: (0.0, 0.0),
            env_radiance: 0.0,
            ..SphereOptions::default()
        };
        let img = render_sphere(&src, &opts).unwrap();
        // Centre pixel: facing the light, radiance E / pi.
        let c = img.get(32, 32);
        let cos = {
            let x: f64 = 0.5 / 32.0;
            (1.0 - 2.0 * x * x).sqrt()
        };
        for v in c {
            assert!((v - 2.5 / std::f64::consts::PI * cos).abs() < 2e-3, "{c:?}");
        }
        let (m, n) = mean_colour(&img);
        assert!(n > 2800 && n < 3217, "{n}"); // pi 32^2 = 3217 minus edge pixels
        assert!(
            (m[0] - m[1]).abs() < 1e-3 && (m[2] - m[1]).abs() < 1e-3,
            "{m:?}"
        );
        // Corners are transparent, edge pixels partly covered.
        assert_eq!(img.alpha[0], 0.0);
        let partial = img.alpha.iter().filter(|a| **a > 0.0 && **a < 1.0).count();
        assert!(partial > 100 && partial < 400, "{partial} edge pixels");
        // Environment only: a white diffuser sees ~env_radiance on its upper half.
        let env = SphereOptions {
            size: 32,
            light_irradiance: 0.0,
            ..SphereOptions::default()
        };
        let img = render_sphere(&src, &env).unwrap();
        // A white Lambertian under a uniform environment: every covered pixel is 0.1 (within the
        // colour conversion error: the quadrature integrates a Lambertian exactly).
        for (p, a) in img.rgb.iter().zip(&img.alpha) {
            if *a > 0.0 {
                assert!((p[1] - 0.1).abs() < 1e-4, "{p:?}");
            }
        }
        let (m, _) = mean_colour(&img);
        assert!((m[1] - 0.1).abs() < 0.004, "{m:?}");
        assert!(render_sphere(&src, &SphereOptions { size: 0, ..env }).is_err());
    }
}
