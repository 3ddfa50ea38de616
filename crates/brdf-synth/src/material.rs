//! Layered spectral BRDF models.
//!
//! A [`Material`] is a description (plain data); [`Material::prepare`] turns it into a
//! [`PreparedMaterial`] for a set of wavelengths, which evaluates f(wi, wo, lambda) in 1/sr.
//!
//! Structure, from the bottom up:
//! - a [`Base`]: a diffuse lobe (Lambert or energy-bounded Oren-Nayar) coloured by a reflectance
//!   spectrum, optionally under a [`Sheen`] lobe (fabrics; albedo-scaled coupling), and mixed
//!   with an area fraction of oriented [`Flakes`] (metallic and pearlescent paints);
//! - optionally a dielectric [`Interface`] on the base (the binder of a paint or plastic): a GGX
//!   specular lobe with spectral Fresnel plus the base attenuated by the interface transmittance
//!   `T(mu) = 1 - E(mu)` in and out, where E is the interface's directional albedo;
//! - or, instead of both, a bare metal ([`Body::Metal`]): GGX lobes with the complex Fresnel
//!   reflectance of a real metal;
//! - optionally a clear coat (another [`Interface`]) over everything, coupled the same way.
//!
//! Every lobe is reciprocal, and every layer conserves energy: GGX single scattering with
//! height-correlated Smith masking has albedo <= F <= 1; diffuse and sheen lobes are normalised
//! numerically so that their albedo is <= their colour; a layer's albedo is
//! `E(mu_i) + T(mu_i) int T(mu_o) f_below cos <= E + (1 - E) = 1`. The tabulated E is taken at the
//! largest index over the supported range [`crate::dataset::WAVELENGTH_RANGE_NM`] (and any
//! requested wavelength outside it; Fresnel grows with the index), so `T` never over-transmits,
//! and f at a wavelength does not depend on which other wavelengths were requested.

use std::f64::consts::PI;

use brdf_io::{HalfDiff, Vec3, unit};

use crate::dataset::WAVELENGTH_RANGE_NM;
use crate::microfacet::{charlie_d, ggx_lobe, sheen_visibility, smith_g2};
use crate::optics::{Complex, Ior, Metal, fresnel, thin_film};
use crate::spectrum::Spectrum;

/// Largest diffuse reflectance a base may have (keeps every material strictly passive).
pub const MAX_ALBEDO: f64 = 0.99;

/// The family of a material (its name prefix follows the RGL catalogue's naming).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Family {
    /// Acrylic felts: rough diffuse with a strong sheen.
    Felt,
    /// Papers: rough diffuse with a faint broad gloss.
    Paper,
    /// Corrugated cardboard.
    Cardboard,
    /// Wall and ceiling paints, chalk paints: matte to eggshell.
    WallPaint,
    /// Vinyl wrapping films: matte, satin or gloss plastics, some metallic.
    Vinyl,
    /// Satin fabrics: sheen plus a soft specular.
    Satin,
    /// Car paints, solid or metallic, under a clear coat.
    CarPaint,
    /// Painted metal (model-kit paints): pigment and metal flakes over metal.
    PaintedMetal,
    /// Bare polished or brushed metals.
    Metal,
    /// Iridescent interference-flake paints and colour-change films.
    Iridescent,
    /// A leaf.
    Leaf,
    /// A near-ideal diffuser (Spectralon).
    Diffuser,
}

/// How a specular lobe reflects: its Fresnel term.
#[derive(Debug, Clone, PartialEq)]
pub enum Fresnel {
    /// A dielectric with a real, dispersive index.
    Dielectric(Ior),
    /// A real metal (complex index from the embedded tables).
    Conductor(Metal),
    /// A thin dielectric film (Airy interference) on a substrate.
    ThinFilm {
        /// Index of the film.
        film: Ior,
        /// Film thickness, nm.
        thickness_nm: f64,
        /// The material under the film.
        substrate: Substrate,
    },
}

/// The substrate under a thin film.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Substrate {
    /// A dielectric (e.g. mica).
    Dielectric(Ior),
    /// A metal (e.g. aluminium flakes).
    Conductor(Metal),
}

/// A GGX microfacet specular lobe.
#[derive(Debug, Clone, PartialEq)]
pub struct Specular {
    /// GGX roughness alpha (> 0).
    pub alpha: f64,
    /// The Fresnel term.
    pub fresnel: Fresnel,
}

/// The diffuse lobe shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Diffuse {
    /// Lambertian, 1/pi.
    Lambert,
    /// Oren-Nayar in Fujii's energy-bounded form, roughness `sigma` in [0, 1]: flatter than
    /// Lambert, with back-scattering at grazing angles.
    OrenNayar {
        /// Surface roughness (0 = Lambert).
        sigma: f64,
    },
}

/// A fabric sheen lobe (Charlie distribution, Neubelt visibility): brightest at grazing angles.
#[derive(Debug, Clone, PartialEq)]
pub struct Sheen {
    /// Strength of the sheen in [0, 1]; the diffuse lobe under it receives only what the sheen
    /// does not scatter (albedo scaling, `(1 - E_s(mu_i)) (1 - E_s(mu_o))`).
    pub weight: f64,
    /// Sheen colour (albedo of the normalised lobe), in [0, 1].
    pub colour: Spectrum,
    /// Sheen roughness in (0, 1]; small values concentrate the lobe at grazing angles.
    pub roughness: f64,
}

/// Oriented flakes embedded in a base: a fraction of the surface reflects through a GGX lobe
/// whose roughness is the spread of the flake normals.
#[derive(Debug, Clone, PartialEq)]
pub struct Flakes {
    /// Area fraction covered by flakes, in [0, 1].
    pub coverage: f64,
    /// The flakes' reflection (metal, or an interference film on mica/aluminium).
    pub lobe: Specular,
}

/// A diffuse base with optional sheen and flakes.
#[derive(Debug, Clone, PartialEq)]
pub struct Base {
    /// Diffuse reflectance spectrum (clamped to [0, [`MAX_ALBEDO`]]).
    pub albedo: Spectrum,
    /// Diffuse lobe shape.
    pub diffuse: Diffuse,
    /// Optional sheen.
    pub sheen: Option<Sheen>,
    /// Optional flakes.
    pub flakes: Option<Flakes>,
}

/// A smooth or rough dielectric interface (binder or clear coat).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interface {
    /// GGX roughness of the interface.
    pub alpha: f64,
    /// Refractive index.
    pub ior: Ior,
}

/// What lies under the optional clear coat.
#[derive(Debug, Clone, PartialEq)]
pub enum Body {
    /// A diffuse base, optionally under a dielectric interface.
    Layered {
        /// The base.
        base: Base,
        /// The interface on top of the base, if any.
        interface: Option<Interface>,
    },
    /// A bare metal: weighted GGX lobes (weights sum to <= 1).
    Metal {
        /// (weight, lobe) pairs.
        lobes: Vec<(f64, Specular)>,
    },
}

/// A named spectral material.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Name, with an RGL-like family prefix (e.g. `acrylic_felt_green`).
    pub name: String,
    /// Family.
    pub family: Family,
    /// The body.
    pub body: Body,
    /// An optional clear coat over the body.
    pub coat: Option<Interface>,
}

// ---------------------------------------------------------------------------------------------
// Preparation.

/// Nodes of the coupling tables, spaced as mu = (k / (N - 1))^2.
const E_NODES: usize = 48;
/// Stratified NDF samples per axis for the coupling tables.
const E_SAMPLES: usize = 64;
/// Relative safety margin on tabulated interface albedo (quadrature and interpolation error).
const E_MARGIN: f64 = 1.01;

/// A specular lobe prepared for a set of wavelengths.
#[derive(Debug, Clone)]
struct PSpec {
    alpha: f64,
    weight: f64,
    kind: PFresnel,
    /// This lobe's place in a [`FresnelCache`] of its material.
    slot: usize,
}

#[derive(Debug, Clone)]
enum PFresnel {
    /// Interface from a real medium `n1` into `n2[l]`.
    Index { n1: f64, n2: Vec<Complex> },
    /// Thin film: incident medium `n1`, film index `nf[l]`, thickness, substrate `ns[l]`.
    Film {
        n1: f64,
        nf: Vec<f64>,
        d: f64,
        ns: Vec<Complex>,
        lambda: Vec<f64>,
    },
}

impl PFresnel {
    fn new(f: &Fresnel, n1: f64, wavelengths: &[f64]) -> Self {
        match f {
            Fresnel::Dielectric(ior) => Self::Index {
                n1,
                n2: wavelengths
                    .iter()
                    .map(|&l| Complex::real(ior.at(l)))
                    .collect(),
            },
            Fresnel::Conductor(m) => Self::Index {
                n1,
                n2: wavelengths.iter().map(|&l| m.nk(l)).collect(),
            },
            Fresnel::ThinFilm {
                film,
                thickness_nm,
                substrate,
            } => Self::Film {
                n1,
                nf: wavelengths.iter().map(|&l| film.at(l)).collect(),
                d: thickness_nm.max(0.0),
                ns: wavelengths
                    .iter()
                    .map(|&l| match substrate {
                        Substrate::Dielectric(ior) => Complex::real(ior.at(l)),
                        Substrate::Conductor(m) => m.nk(l),
                    })
                    .collect(),
                lambda: wavelengths.to_vec(),
            },
        }
    }

    /// Number of wavelengths.
    fn len(&self) -> usize {
        match self {
            Self::Index { n2, .. } => n2.len(),
            Self::Film { lambda, .. } => lambda.len(),
        }
    }

    #[inline]
    fn eval(&self, l: usize, cos_d: f64) -> f64 {
        match self {
            Self::Index { n1, n2 } => fresnel(cos_d, *n1, n2[l]),
            Self::Film {
                n1,
                nf,
                d,
                ns,
                lambda,
            } => thin_film(cos_d, lambda[l], *n1, nf[l], *d, ns[l]),
        }
    }
}

impl PSpec {
    fn new(s: &Specular, weight: f64, n1: f64, wavelengths: &[f64], slot: usize) -> Self {
        Self {
            alpha: s.alpha.clamp(1e-3, 1.0),
            weight: weight.clamp(0.0, 1.0),
            kind: PFresnel::new(&s.fresnel, n1, wavelengths),
            slot,
        }
    }

    /// The lobe's Fresnel reflectance at `cos_d`, wavelength by wavelength: computed as it is
    /// read, or remembered in `cache`.
    #[inline]
    fn fresnel<'a>(&'a self, cos_d: f64, cache: Option<&'a mut FresnelCache>) -> Fresnels<'a> {
        match cache {
            None => Fresnels::Direct(&self.kind, cos_d),
            Some(c) => Fresnels::Remembered(c.get(self, cos_d)),
        }
    }
}

/// A lobe's Fresnel reflectances at one incidence cosine ([`PSpec::fresnel`]).
enum Fresnels<'a> {
    /// Computed per wavelength as they are read.
    Direct(&'a PFresnel, f64),
    /// From a [`FresnelCache`].
    Remembered(&'a [f64]),
}

impl Fresnels<'_> {
    /// The reflectance at wavelength index `l`.
    #[inline]
    fn at(&self, l: usize) -> f64 {
        match self {
            Self::Direct(kind, cos_d) => kind.eval(l, *cos_d),
            Self::Remembered(values) => values[l],
        }
    }
}

/// The Fresnel reflectances of one prepared material's lobes, remembered per incidence cosine
/// for [`PreparedMaterial::eval_cached`]. Keyed by the cosine's bits, so that a remembered
/// value is exactly what the lobe computes: the bin centres of a grid have few distinct
/// cos(theta_d) (1,339 among the 137,100 cells above the horizon of 45,45,90), so most cells of
/// a dataset reuse them, and the complex Fresnel and thin-film formulas (~40 % of a synthesis)
/// run once per distinct cosine. Holds at most [`FresnelCache::MAX_VALUES`] values; a full
/// cache starts again empty.
#[derive(Debug, Default)]
pub struct FresnelCache {
    /// Per lobe slot: cos_d bits -> reflectance per wavelength.
    slots: Vec<std::collections::HashMap<u64, Box<[f64]>>>,
    /// Values held over all slots.
    values: usize,
}

impl FresnelCache {
    /// The most values a cache holds (1 MiB of f64).
    pub const MAX_VALUES: usize = 1 << 17;

    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    /// The reflectances of `lobe` at `cos_d`, computed on the first request.
    fn get(&mut self, lobe: &PSpec, cos_d: f64) -> &[f64] {
        let n = lobe.kind.len();
        if self.slots.len() <= lobe.slot {
            self.slots
                .resize_with(lobe.slot + 1, std::collections::HashMap::new);
        }
        let key = cos_d.to_bits();
        if self.values + n > Self::MAX_VALUES && !self.slots[lobe.slot].contains_key(&key) {
            self.slots.iter_mut().for_each(|s| s.clear());
            self.values = 0;
        }
        let values = &mut self.values;
        self.slots[lobe.slot].entry(key).or_insert_with(|| {
            *values += n;
            (0..n).map(|l| lobe.kind.eval(l, cos_d)).collect()
        })
    }
}

/// A dielectric interface prepared for a set of wavelengths, with its coupling table.
#[derive(Debug, Clone)]
struct PInterface {
    spec: PSpec,
    /// Conservative interface albedo E at the nodes mu_k = (k / (N - 1))^2.
    e_table: Vec<f64>,
}

impl PInterface {
    fn new(i: &Interface, wavelengths: &[f64], slot: usize) -> Self {
        let spec = PSpec::new(
            &Specular {
                alpha: i.alpha,
                fresnel: Fresnel::Dielectric(i.ior),
            },
            1.0,
            1.0,
            wavelengths,
            slot,
        );
        // Fresnel reflectance grows with the index: tabulate E at the largest one over the
        // whole supported range, not only the requested wavelengths, so that f at a wavelength
        // is the same whatever else is requested (the maximum over the request alone made
        // values at 700 nm alone differ by up to 1.3 % from the same values prepared with
        // 360:1000:20).
        let (lo, hi) = WAVELENGTH_RANGE_NM;
        let eta = i.ior.max_over(wavelengths).max(i.ior.max_over(&[lo, hi]));
        let e_table = (0..E_NODES)
            .map(|k| {
                let t = k as f64 / (E_NODES - 1) as f64;
                let mu = (t * t).max(1e-4);
                (ggx_albedo(mu, spec.alpha, |c| fresnel(c, 1.0, Complex::real(eta))) * E_MARGIN
                    + 1e-3)
                    .min(1.0)
            })
            .collect();
        Self { spec, e_table }
    }

    /// Transmittance 1 - E(mu) into the layer below.
    #[inline]
    fn transmittance(&self, mu: f64) -> f64 {
        1.0 - table_at(&self.e_table, mu)
    }
}

/// Directional albedo of a GGX lobe with Fresnel `f(cos_d)` at incidence cosine `mu`:
/// E = int F G2 (wi.h) / (mu cos_h) over h distributed as D(h) cos_h, by stratified quadrature.
fn ggx_albedo(mu: f64, alpha: f64, f: impl Fn(f64) -> f64) -> f64 {
    let wi = [(1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu];
    let n = E_SAMPLES;
    let cos_phi: Vec<f64> = (0..n)
        .map(|b| ((b as f64 + 0.5) / n as f64 * 2.0 * PI).cos())
        .collect();
    let mut sum = 0.0;
    for a in 0..n {
        let u = (a as f64 + 0.5) / n as f64;
        let tan2 = alpha * alpha * u / (1.0 - u);
        let cos_h = 1.0 / (1.0 + tan2).sqrt();
        let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
        for cp in &cos_phi {
            // wi lies in the xz plane: only the x component of h matters for wi . h.
            let h = [sin_h * cp, 0.0, cos_h];
            let cos_d = dot(wi, h);
            if cos_d <= 0.0 {
                continue;
            }
            let mu_o = 2.0 * cos_d * h[2] - wi[2];
            if mu_o <= 0.0 {
                continue;
            }
            sum += f(cos_d) * smith_g2(mu, mu_o, alpha) * cos_d / (mu * cos_h);
        }
    }
    sum / (n * n) as f64
}

/// Outgoing directions with their weights for [`albedo_table`]: `sum shape(wi, wo) weight`
/// approximates `int shape(wi, wo) cos(theta_o) dwo`.
type AlbedoNodes = Vec<(Vec3, f64)>;

/// Cosine-distributed outgoing directions on an `n` x `n` stratified grid: good for smooth
/// lobes (the diffuse shapes).
fn cosine_nodes(n: usize) -> AlbedoNodes {
    let mut nodes = Vec::with_capacity(n * n);
    let weight = PI / (n * n) as f64;
    for a in 0..n {
        let u = (a as f64 + 0.5) / n as f64;
        let r = u.sqrt();
        let z = (1.0 - u).sqrt();
        for b in 0..n {
            let phi = (b as f64 + 0.5) / n as f64 * 2.0 * PI;
            nodes.push(([r * phi.cos(), r * phi.sin(), z], weight));
        }
    }
    nodes
}

/// Outgoing directions uniform in solid angle, midpoints of `n` cos(theta_o) x `2 n` phi_o
/// cells, weighted by cos(theta_o). For the sheen: near grazing incidence its visibility
/// grows as 1 / cos(theta_o) towards the horizon, which cosine-distributed directions sample
/// poorly (at grazing incidence its albedo was 5 % (roughness 1) to 14 % (0.05) above what 48 x
/// 48 of them gave, so that a white sheen reflected up to 11 % more than it received);
/// here the integrand `shape cos(theta_o)` stays bounded and 48 x 96 directions are within
/// 0.5 % of a 1000 x 2000 grid at every roughness.
fn solid_angle_nodes(n: usize) -> AlbedoNodes {
    let mut nodes = Vec::with_capacity(2 * n * n);
    let cell = PI / (n * n) as f64; // d(cos theta) = 1 / n, d(phi) = pi / n.
    for a in 0..n {
        let z = (a as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        for b in 0..2 * n {
            let phi = (b as f64 + 0.5) / n as f64 * PI;
            nodes.push(([r * phi.cos(), r * phi.sin(), z], z * cell));
        }
    }
    nodes
}

/// Directional albedo of a lobe `shape(wi, wo)` (unit colour) at the coupling-table nodes
/// mu_k = (k / (N - 1))^2, by quadrature over `nodes`. Used to normalise the diffuse and sheen
/// lobes and to couple the sheen with the diffuse lobe under it.
fn albedo_table(shape: impl Fn(Vec3, Vec3) -> f64, nodes: &[(Vec3, f64)]) -> Vec<f64> {
    (0..E_NODES)
        .map(|k| {
            let t = k as f64 / (E_NODES - 1) as f64;
            let mu = (t * t).max(1e-3);
            let wi = [(1.0 - mu * mu).sqrt(), 0.0, mu];
            nodes.iter().map(|&(wo, w)| shape(wi, wo) * w).sum::<f64>()
        })
        .collect()
}

/// Linear interpolation in a coupling table at `mu`.
#[inline]
fn table_at(table: &[f64], mu: f64) -> f64 {
    let x = mu.clamp(0.0, 1.0).sqrt() * (E_NODES - 1) as f64;
    let i = (x.floor() as usize).min(E_NODES - 2);
    let f = x - i as f64;
    table[i] * (1.0 - f) + table[i + 1] * f
}

#[inline]
fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Fujii's energy-bounded Oren-Nayar shape for unit albedo (before normalisation).
#[inline]
fn oren_nayar(wi: Vec3, wo: Vec3, sigma: f64) -> f64 {
    let a = 1.0 / (PI + (PI / 2.0 - 2.0 / 3.0) * sigma);
    let b = sigma * a;
    let s = dot(wi, wo) - wi[2] * wo[2];
    let t = if s > 0.0 { wi[2].max(wo[2]) } else { 1.0 };
    (a + b * s / t.max(1e-6)).max(0.0)
}

/// The sheen shape for unit colour (before normalisation).
#[inline]
fn sheen_shape(wi: Vec3, wo: Vec3, r: f64) -> f64 {
    let h = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
    let len = dot(h, h).sqrt();
    if len <= 0.0 {
        return 0.0;
    }
    charlie_d(h[2] / len, r) * sheen_visibility(wi[2], wo[2])
}

#[derive(Debug, Clone)]
struct PBase {
    diffuse: Diffuse,
    /// Normalisation of the diffuse shape (>= 1).
    diffuse_norm: f64,
    /// Per-wavelength diffuse reflectance times the diffuse weight.
    albedo: Vec<f64>,
    /// Sheen: roughness, normalisation, per-wavelength colour times weight, and the
    /// (conservative) sheen albedo table for a white colour.
    sheen: Option<(f64, f64, Vec<f64>, Vec<f64>)>,
    /// Flakes: coverage and lobe.
    flakes: Option<(f64, PSpec)>,
}

#[derive(Debug, Clone)]
enum PBody {
    Layered {
        base: Box<PBase>,
        interface: Option<PInterface>,
    },
    Metal {
        lobes: Vec<PSpec>,
    },
}

/// A material prepared for evaluation at a fixed list of wavelengths.
#[derive(Debug, Clone)]
pub struct PreparedMaterial {
    wavelengths: Vec<f64>,
    body: PBody,
    coat: Option<PInterface>,
}

impl Material {
    /// Prepares the material for evaluation at `wavelengths` (nm): caches per-wavelength
    /// constants and the energy-coupling tables. Costs a few milliseconds.
    pub fn prepare(&self, wavelengths: &[f64]) -> PreparedMaterial {
        let covered = self.coat.is_some();
        let body = match &self.body {
            Body::Metal { lobes } => {
                let total: f64 = lobes.iter().map(|(w, _)| w.max(0.0)).sum();
                let scale = if total > 1.0 { 1.0 / total } else { 1.0 };
                PBody::Metal {
                    lobes: lobes
                        .iter()
                        .enumerate()
                        .map(|(slot, (w, s))| {
                            PSpec::new(s, w.max(0.0) * scale, 1.0, wavelengths, slot)
                        })
                        .collect(),
                }
            }
            Body::Layered { base, interface } => {
                // Flakes sit in a binder when anything covers them.
                let n1 = if covered || interface.is_some() {
                    Ior::BINDER.at(550.0)
                } else {
                    1.0
                };
                PBody::Layered {
                    base: Box::new(prepare_base(base, n1, wavelengths)),
                    interface: interface
                        .as_ref()
                        .map(|i| PInterface::new(i, wavelengths, INTERFACE_SLOT)),
                }
            }
        };
        PreparedMaterial {
            wavelengths: wavelengths.to_vec(),
            body,
            // The slot after the body's lobes.
            coat: self.coat.as_ref().map(|c| {
                let slot = match &self.body {
                    Body::Metal { lobes } => lobes.len(),
                    Body::Layered { .. } => INTERFACE_SLOT + 1,
                };
                PInterface::new(c, wavelengths, slot)
            }),
        }
    }

    /// f(wi, wo, lambda) in 1/sr (slow: prepares the material for one wavelength; use
    /// [`Material::prepare`] for many evaluations).
    pub fn eval(&self, wi: Vec3, wo: Vec3, lambda_nm: f64) -> f64 {
        let mut out = [0.0];
        self.prepare(&[lambda_nm]).eval(wi, wo, &mut out);
        out[0]
    }
}

/// [`FresnelCache`] slots of a layered body's flakes and interface (a coat takes the next).
const FLAKES_SLOT: usize = 0;
const INTERFACE_SLOT: usize = 1;

fn prepare_base(base: &Base, n1: f64, wavelengths: &[f64]) -> PBase {
    let coverage = base
        .flakes
        .as_ref()
        .map_or(0.0, |f| f.coverage.clamp(0.0, 1.0));
    let sheen_w = base
        .sheen
        .as_ref()
        .map_or(0.0, |s| s.weight.clamp(0.0, 1.0));
    let diffuse_w = 1.0 - coverage;
    let diffuse_norm = match base.diffuse {
        Diffuse::Lambert => 1.0,
        Diffuse::OrenNayar { sigma } => {
            let t = albedo_table(|wi, wo| oren_nayar(wi, wo, sigma), &cosine_nodes(48));
            t.into_iter().fold(1.0, f64::max) * 1.01
        }
    };
    let albedo = wavelengths
        .iter()
        .map(|&l| diffuse_w * base.albedo.eval(l).clamp(0.0, MAX_ALBEDO))
        .collect();
    let sheen = base.sheen.as_ref().map(|s| {
        let r = s.roughness.clamp(0.05, 1.0);
        let table = albedo_table(|wi, wo| sheen_shape(wi, wo, r), &solid_angle_nodes(48));
        let norm = table.iter().copied().fold(1.0, f64::max) * 1.02;
        // Albedo of the normalised, weighted white sheen, with a safety margin.
        let e: Vec<f64> = table
            .iter()
            .map(|a| (sheen_w * a / norm * 1.02 + 1e-3).min(1.0))
            .collect();
        let w = (1.0 - coverage) * sheen_w;
        let colour = wavelengths
            .iter()
            .map(|&l| w * s.colour.eval(l).clamp(0.0, 1.0))
            .collect();
        (r, norm, colour, e)
    });
    let flakes = base.flakes.as_ref().map(|f| {
        (
            coverage,
            PSpec::new(&f.lobe, 1.0, n1, wavelengths, FLAKES_SLOT),
        )
    });
    PBase {
        diffuse: base.diffuse,
        diffuse_norm,
        albedo,
        sheen,
        flakes,
    }
}

/// Geometry shared by every lobe of one direction pair.
struct Geom {
    wi: Vec3,
    wo: Vec3,
    mu_i: f64,
    mu_o: f64,
    cos_h: f64,
    cos_d: f64,
}

impl Geom {
    /// The geometry of directions `wi`, `wo` of any length; `None` where f is 0: a zero or
    /// non-finite vector, a direction at or below the horizon, or no half vector.
    fn of(wi: Vec3, wo: Vec3) -> Option<Self> {
        let (wi, wo) = (unit(wi)?, unit(wo)?);
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return None;
        }
        let h = unit([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]])?;
        Some(Self {
            wi,
            wo,
            mu_i: wi[2],
            mu_o: wo[2],
            cos_h: h[2],
            cos_d: dot(wi, h).clamp(0.0, 1.0),
        })
    }
}

impl PSpec {
    /// D G2 / (4 mu_i mu_o) times the lobe weight (Fresnel excluded).
    #[inline]
    fn shape(&self, g: &Geom) -> f64 {
        self.weight * ggx_lobe(g.cos_h, g.mu_i, g.mu_o, self.alpha)
    }
}

/// A prepared material is a spectral [`brdf_io::BrdfSource`] at its prepared wavelengths
/// (renderable and sampleable like a measured file).
impl brdf_io::BrdfSource for PreparedMaterial {
    fn channels(&self) -> brdf_io::Channels {
        brdf_io::Channels::Spectral(self.wavelengths.clone())
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        brdf_io::source::check_output_len(out, self.wavelengths.len())?;
        PreparedMaterial::eval(self, wi, wo, out);
        Ok(())
    }
}

impl PreparedMaterial {
    /// The wavelengths (nm) this material was prepared for.
    pub fn wavelengths(&self) -> &[f64] {
        &self.wavelengths
    }

    /// f(wi, wo, lambda_l) in 1/sr for every prepared wavelength, written to `out` (length =
    /// number of wavelengths). Directions need not be normalised; any direction at or below the
    /// horizon gives 0.
    pub fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        self.eval_impl(wi, wo, out, None);
    }

    /// [`PreparedMaterial::eval`] with the lobes' Fresnel reflectances remembered in `cache`
    /// (one cache per material; the same values, bit for bit): for evaluating many direction
    /// pairs that share their cos(theta_d), such as a grid's bin centres.
    pub fn eval_cached(&self, wi: Vec3, wo: Vec3, out: &mut [f64], cache: &mut FresnelCache) {
        self.eval_impl(wi, wo, out, Some(cache));
    }

    fn eval_impl(&self, wi: Vec3, wo: Vec3, out: &mut [f64], mut cache: Option<&mut FresnelCache>) {
        debug_assert_eq!(out.len(), self.wavelengths.len());
        out.fill(0.0);
        let Some(g) = Geom::of(wi, wo) else {
            return;
        };
        match &self.body {
            PBody::Metal { lobes } => {
                for lobe in lobes {
                    let s = lobe.shape(&g);
                    if s > 0.0 {
                        let f = lobe.fresnel(g.cos_d, cache.as_deref_mut());
                        for (l, o) in out.iter_mut().enumerate() {
                            *o += s * f.at(l);
                        }
                    }
                }
            }
            PBody::Layered { base, interface } => {
                base.eval(&g, out, cache.as_deref_mut());
                if let Some(i) = interface {
                    i.apply(&g, out, cache.as_deref_mut());
                }
            }
        }
        if let Some(c) = &self.coat {
            c.apply(&g, out, cache);
        }
    }

    /// f at the direction pair of Rusinkiewicz angles `hd` (see [`PreparedMaterial::eval`]).
    pub fn eval_half_diff(&self, hd: &HalfDiff, out: &mut [f64]) {
        let (wi, wo) = hd.to_dirs();
        self.eval(wi, wo, out);
    }

    /// [`PreparedMaterial::eval_half_diff`] with a [`FresnelCache`]
    /// ([`PreparedMaterial::eval_cached`]).
    pub fn eval_half_diff_cached(&self, hd: &HalfDiff, out: &mut [f64], cache: &mut FresnelCache) {
        let (wi, wo) = hd.to_dirs();
        self.eval_cached(wi, wo, out, cache);
    }
}

impl PBase {
    fn eval(&self, g: &Geom, out: &mut [f64], cache: Option<&mut FresnelCache>) {
        let d = match self.diffuse {
            Diffuse::Lambert => 1.0 / PI,
            Diffuse::OrenNayar { sigma } => oren_nayar(g.wi, g.wo, sigma) / self.diffuse_norm,
        };
        // The sheen sits on top of the diffuse lobe, which only receives what the sheen does
        // not scatter (albedo scaling, reciprocal in wi and wo).
        let (t, sheen) = match &self.sheen {
            Some((r, norm, _, e)) => (
                (1.0 - table_at(e, g.mu_i)) * (1.0 - table_at(e, g.mu_o)),
                sheen_shape(g.wi, g.wo, *r) / norm,
            ),
            None => (1.0, 0.0),
        };
        for (o, a) in out.iter_mut().zip(&self.albedo) {
            *o = t * a * d;
        }
        if let Some((_, _, colour, _)) = &self.sheen {
            for (o, c) in out.iter_mut().zip(colour) {
                *o += c * sheen;
            }
        }
        if let Some((coverage, lobe)) = &self.flakes {
            let s = coverage * lobe.shape(g);
            if s > 0.0 {
                let f = lobe.fresnel(g.cos_d, cache);
                for (l, o) in out.iter_mut().enumerate() {
                    *o += s * f.at(l);
                }
            }
        }
    }
}

impl PInterface {
    /// Replaces `below` by this interface's reflection plus the coupled layer below.
    fn apply(&self, g: &Geom, below: &mut [f64], cache: Option<&mut FresnelCache>) {
        let t = self.transmittance(g.mu_i) * self.transmittance(g.mu_o);
        let s = self.spec.shape(g);
        if s > 0.0 {
            let f = self.spec.fresnel(g.cos_d, cache);
            for (l, o) in below.iter_mut().enumerate() {
                *o = s * f.at(l) + t * *o;
            }
        } else {
            for o in below.iter_mut() {
                *o = 0.0 + t * *o;
            }
        }
    }
}

/// Directional albedo `int f(wi, wo) cos(theta_o) dwo` per prepared wavelength at incidence
/// angle `theta_i` (radians), by deterministic quadrature over half vectors: theta_h = u^2 pi/2
/// on `n` midpoints (dense near the normal, resolving sharp specular peaks), phi_h on `2n`
/// midpoints over [0, pi) (the integrand is symmetric in phi_h), with `dwo = 4 (wi.h) dwh`.
pub fn directional_albedo(m: &PreparedMaterial, theta_i: f64, n: usize) -> Vec<f64> {
    let nl = m.wavelengths.len();
    let mut total = vec![0.0; nl];
    let mut f = vec![0.0; nl];
    let wi = [theta_i.sin(), 0.0, theta_i.cos()];
    let n = n.max(4);
    let n_phi = 2 * n;
    let du = 1.0 / n as f64;
    let dphi = PI / n_phi as f64;
    for a in 0..n {
        let u = (a as f64 + 0.5) * du;
        let th = u * u * PI / 2.0;
        let (sh, ch) = th.sin_cos();
        let dth = PI * u * du;
        for b in 0..n_phi {
            let phi = (b as f64 + 0.5) * dphi;
            let h = [sh * phi.cos(), sh * phi.sin(), ch];
            let cd = dot(wi, h);
            if cd <= 0.0 {
                continue;
            }
            let wo = [
                2.0 * cd * h[0] - wi[0],
                2.0 * cd * h[1] - wi[1],
                2.0 * cd * h[2] - wi[2],
            ];
            if wo[2] <= 0.0 {
                continue;
            }
            m.eval(wi, wo, &mut f);
            // Both halves of phi in [0, 2 pi): factor 2.
            let w = 2.0 * wo[2] * 4.0 * cd * sh * dth * dphi;
            for (t, v) in total.iter_mut().zip(&f) {
                *t += v * w;
            }
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lambert(rho: f64) -> Material {
        Material {
            name: "lambert".into(),
            family: Family::Diffuser,
            body: Body::Layered {
                base: Base {
                    albedo: Spectrum::Constant(rho),
                    diffuse: Diffuse::Lambert,
                    sheen: None,
                    flakes: None,
                },
                interface: None,
            },
            coat: None,
        }
    }

    /// A bare metal of `lobes` (weight, lobe).
    fn metal(lobes: Vec<(f64, Specular)>) -> Material {
        Material {
            name: "metal".into(),
            family: Family::Metal,
            body: Body::Metal { lobes },
            coat: None,
        }
    }

    #[test]
    fn albedo_quadrature_is_accurate_for_lambert() {
        let m = lambert(0.9).prepare(&[550.0]);
        for deg in [0.0f64, 30.0, 60.0, 80.0, 89.0] {
            let a = directional_albedo(&m, deg.to_radians(), 96)[0];
            assert!((a - 0.9).abs() < 0.9 * 2e-3, "{deg} deg: {a}");
        }
    }

    /// A Fresnel cache returns what its lobe computes, keeps every cosine it is asked for until
    /// it holds exactly [`FresnelCache::MAX_VALUES`] values, and only then starts again empty:
    /// a known cosine never clears it, a new one beyond the bound always does, over all slots.
    #[test]
    fn the_fresnel_cache_keeps_what_fits_and_never_more() {
        let w: Vec<f64> = (0..8).map(|l| 400.0 + 40.0 * l as f64).collect();
        let lobe = |slot| {
            let s = Specular {
                alpha: 0.1,
                fresnel: Fresnel::Conductor(Metal::Gold),
            };
            PSpec::new(&s, 1.0, 1.0, &w, slot)
        };
        let (a, b) = (lobe(0), lobe(1));
        let capacity = FresnelCache::MAX_VALUES / w.len();
        assert_eq!(capacity * w.len(), FresnelCache::MAX_VALUES);
        let cosine = |k: usize| (k + 1) as f64 / (capacity + 2) as f64;
        let held = |c: &FresnelCache| c.slots.iter().map(|s| s.len()).sum::<usize>();
        let direct = |lobe: &PSpec, cos_d| -> Vec<f64> {
            (0..w.len()).map(|l| lobe.kind.eval(l, cos_d)).collect()
        };
        let mut cache = FresnelCache::new();
        for k in 0..capacity {
            let lobe = if k % 2 == 0 { &a } else { &b };
            assert_eq!(
                cache.get(lobe, cosine(k)),
                direct(lobe, cosine(k)),
                "cosine {k}"
            );
            assert_eq!(
                held(&cache),
                k + 1,
                "cosine {k}: nothing dropped before the bound"
            );
        }
        assert_eq!(cache.values, FresnelCache::MAX_VALUES);
        // Full: known cosines are read back without clearing anything.
        for k in [0, 1, capacity - 1] {
            let lobe = if k % 2 == 0 { &a } else { &b };
            assert_eq!(cache.get(lobe, cosine(k)), direct(lobe, cosine(k)));
        }
        assert_eq!(held(&cache), capacity);
        // A new cosine clears both slots and is then the only one held.
        let fresh = 0.999_999;
        assert_eq!(cache.get(&a, fresh), direct(&a, fresh));
        assert_eq!(held(&cache), 1);
        assert_eq!(cache.values, w.len());
        assert!(cache.slots[1].is_empty());
    }

    /// A metal's lobe weights are clamped at 0 and, where they sum above 1, scaled to sum 1;
    /// below 1 they are kept: f is that mix of the lobes prepared alone at weight 1.
    #[test]
    fn metal_lobe_weights_are_scaled_to_sum_at_most_one() {
        let a = Specular {
            alpha: 0.1,
            fresnel: Fresnel::Conductor(Metal::Gold),
        };
        let b = Specular {
            alpha: 0.4,
            fresnel: Fresnel::Conductor(Metal::Aluminium),
        };
        let f = |lobes: Vec<(f64, Specular)>| {
            let (t_i, t_o) = (0.5f64, 0.65f64);
            let mut out = [0.0; 2];
            metal(lobes).prepare(&[450.0, 650.0]).eval(
                [t_i.sin(), 0.0, t_i.cos()],
                [-t_o.sin(), 0.0, t_o.cos()],
                &mut out,
            );
            out
        };
        let (fa, fb) = (f(vec![(1.0, a.clone())]), f(vec![(1.0, b.clone())]));
        assert!(fa.iter().chain(&fb).all(|v| *v > 0.1), "{fa:?} {fb:?}");
        for (wa, wb, want_a, want_b) in [
            (0.3, 0.2, 0.3, 0.2),
            (0.8, 0.6, 0.8 / 1.4, 0.6 / 1.4),
            (1.5, -0.5, 1.0, 0.0),
            (-1.0, 0.5, 0.0, 0.5),
        ] {
            let got = f(vec![(wa, a.clone()), (wb, b.clone())]);
            for l in 0..2 {
                let want = want_a * fa[l] + want_b * fb[l];
                assert!(
                    (got[l] - want).abs() <= 1e-12 * want,
                    "weights {wa}, {wb}: {} against {want}",
                    got[l]
                );
            }
        }
    }

    /// An interface and a coat over it keep their own Fresnel reflectances in a cache (their own
    /// slots): a layered body under a coat of another index gives the same bits with a cache as
    /// without. No preset has both, so `fresnel_caches_give_the_same_bits` cannot tell.
    #[test]
    fn an_interface_and_a_coat_remember_their_own_fresnel() {
        let mut m = lambert(0.5);
        if let Body::Layered { interface, .. } = &mut m.body {
            *interface = Some(Interface {
                alpha: 0.2,
                ior: Ior::constant(1.3),
            });
        }
        m.coat = Some(Interface {
            alpha: 0.05,
            ior: Ior::constant(1.7),
        });
        let wl = [400.0, 550.0, 700.0];
        let p = m.prepare(&wl);
        let mut cache = FresnelCache::new();
        for k in 0..40 {
            let t = 1.4 * k as f64 / 40.0;
            let (wi, wo) = ([t.sin(), 0.0, t.cos()], [-t.sin(), 0.0, t.cos()]);
            let (mut plain, mut cached) = ([0.0; 3], [0.0; 3]);
            p.eval(wi, wo, &mut plain);
            for _ in 0..2 {
                p.eval_cached(wi, wo, &mut cached, &mut cache);
                assert_eq!(plain, cached, "theta {t}");
            }
        }
        // The same through Rusinkiewicz angles.
        let grid = brdf_io::AngularGrid::new(4, 4, 8).unwrap();
        for cell in 0..grid.len() {
            let hd = grid.bin_centre_flat(cell);
            let (mut plain, mut cached) = ([0.0; 3], [-1.0; 3]);
            p.eval_half_diff(&hd, &mut plain);
            p.eval_half_diff_cached(&hd, &mut cached, &mut cache);
            assert_eq!(plain, cached, "cell {cell}");
        }
    }

    /// As a [`brdf_io::BrdfSource`], a prepared material is spectral at its wavelengths, writes
    /// what its own `eval` writes, and refuses an output of the wrong length.
    #[test]
    fn a_prepared_material_is_a_brdf_source() {
        use brdf_io::BrdfSource;
        let p = crate::preset::preset_material("metal_gold", 0)
            .unwrap()
            .prepare(&[450.0, 650.0]);
        assert_eq!(
            BrdfSource::channels(&p),
            brdf_io::Channels::Spectral(vec![450.0, 650.0])
        );
        let (wi, wo) = ([0.3, 0.0, 0.954], [-0.3, 0.0, 0.954]);
        let (mut own, mut source) = ([0.0; 2], [-1.0; 2]);
        p.eval(wi, wo, &mut own);
        BrdfSource::eval(&p, wi, wo, &mut source).unwrap();
        assert!(own[0] > 0.1 && own[1] > own[0], "gold: {own:?}");
        assert_eq!(own, source);
        assert!(BrdfSource::eval(&p, wi, wo, &mut [0.0; 3]).is_err());
    }

    /// An interface replaces the value below by its reflection plus what it transmits,
    /// s F + t below, and by t below alone where its lobe vanishes (a direction so grazing that
    /// G2 underflows to 0; a rough interface still transmits there).
    #[test]
    fn an_interface_adds_its_reflection_to_what_it_transmits() {
        let ior = 1.5;
        let i = PInterface::new(
            &Interface {
                alpha: 1.0,
                ior: Ior::constant(ior),
            },
            &[500.0, 600.0],
            0,
        );
        let wo = [-0.3f64.sin(), 0.0, 0.3f64.cos()];
        for (wi, vanishes) in [([0.6, 0.0, 0.8], false), ([1.0, 0.0, 1e-200], true)] {
            let g = Geom::of(wi, wo).unwrap();
            let s = i.spec.shape(&g);
            let t = i.transmittance(g.mu_i) * i.transmittance(g.mu_o);
            assert_eq!(s == 0.0, vanishes, "{wi:?}: s = {s}");
            assert!(t > 0.1 && t < 1.0, "{wi:?}: t = {t}");
            let below = [0.2, 0.3];
            let mut out = below;
            i.apply(&g, &mut out, None);
            let f = fresnel(g.cos_d, 1.0, Complex::real(ior));
            for l in 0..2 {
                let want = s * f + t * below[l];
                assert!((out[l] - want).abs() <= 1e-15 * want, "{wi:?}: {out:?}");
            }
        }
    }

    /// The directional albedo of a bare metal lobe (quadrature over theta_h and phi_h) agrees
    /// with `ggx_albedo`'s (half vectors stratified as D cos_h), an independent quadrature of
    /// the same integral: to 2e-4 up to 40 degrees (9.6e-5 measured; `directional_albedo` at 96
    /// nodes is within 1.1e-5 of itself at 400), to 1 % at 70 degrees, where `ggx_albedo`'s
    /// 64 x 64 nodes are 0.65 % high (450 nm: 0.364354 at 96 nodes, 0.364364 at 1000).
    #[test]
    fn directional_albedo_of_a_metal_lobe_matches_ggx_albedo() {
        let alpha = 0.3;
        let gold = Specular {
            alpha,
            fresnel: Fresnel::Conductor(Metal::Gold),
        };
        let wl = [450.0, 650.0];
        let p = metal(vec![(1.0, gold)]).prepare(&wl);
        for (deg, tolerance) in [(0.0f64, 2e-4), (40.0, 2e-4), (70.0, 1e-2)] {
            let got = directional_albedo(&p, deg.to_radians(), 96);
            for (l, &lambda) in wl.iter().enumerate() {
                let nk = Metal::Gold.nk(lambda);
                let want = ggx_albedo(deg.to_radians().cos(), alpha, |c| fresnel(c, 1.0, nk));
                assert!(
                    (got[l] - want).abs() < tolerance * want,
                    "{deg} deg, {lambda} nm: {} against {want}",
                    got[l]
                );
            }
        }
    }

    #[test]
    fn ggx_albedo_of_white_smooth_lobe_is_near_one() {
        // F = 1, near-normal incidence on a smooth surface: almost all energy is reflected.
        let e = ggx_albedo(0.9, 0.05, |_| 1.0);
        assert!(e > 0.98 && e <= 1.0 + 1e-9, "{e}");
        // Rough GGX loses energy to (missing) multiple scattering, more at grazing.
        let e_rough = ggx_albedo(0.2, 1.0, |_| 1.0);
        assert!(e_rough < 0.8, "{e_rough}");
    }

    /// Directions need not be normalised, whatever their length: vectors whose squared length
    /// under- or overflows give the same f as unit vectors (they gave 0), and zero or
    /// non-finite vectors give 0.
    #[test]
    fn directions_of_any_length() {
        let m = crate::preset::preset_material("carpaint_metallic_silver", 0)
            .unwrap()
            .prepare(&[450.0, 650.0]);
        let wi = [0.3, -0.2, 0.9];
        let wo = [-0.5, 0.1, 0.6];
        let mut unit = [0.0; 2];
        m.eval(wi, wo, &mut unit);
        assert!(unit[0] > 0.0 && unit[1] > 0.0);
        for (a, b) in [
            (1e-200, 1e200),
            (1e-170, 1.0),
            (1.0, 1e170),
            (1e300, 1e-300),
        ] {
            let mut f = [0.0; 2];
            m.eval(wi.map(|x| x * a), wo.map(|x| x * b), &mut f);
            for (x, y) in f.iter().zip(&unit) {
                assert!(
                    (x - y).abs() <= 1e-12 * y,
                    "scales {a:e}, {b:e}: {x} vs {y}"
                );
            }
        }
        for bad in [[0.0; 3], [f64::NAN, 0.0, 1.0], [0.0, f64::INFINITY, 1.0]] {
            let mut f = [1.0; 2];
            m.eval(bad, wo, &mut f);
            assert_eq!(f, [0.0; 2]);
            m.eval(wi, bad, &mut f);
            assert_eq!(f, [0.0; 2]);
        }
    }

    /// Every interface of the presets (binders and clear coats) tabulates a conservative
    /// albedo: at every incidence (between the table's nodes too) and wavelength, its
    /// transmittance `1 - E` is below `1 - E_ref`, the same GGX lobe's albedo
    /// integrated finely at that wavelength's index (`directional_albedo` of the interface alone
    /// over a black base). It is also tight: the table holds the largest index over the range
    /// plus a 1 % and 1e-3 margin, so it withholds at most ~1 % (measured: 1.2e-3 to 1.0e-2 over
    /// 33 wavelengths at 46 angles, 2026-12-04). 360 nm (the largest index, where the table is
    /// tightest) and 1000 nm (the smallest) bound the wavelengths between.
    #[test]
    fn interface_tables_are_conservative_and_tight() {
        let wl = [360.0, 550.0, 1000.0];
        let mut interfaces: Vec<Interface> = Vec::new();
        for m in crate::preset::preset(0) {
            let mut candidates = m.coat.into_iter().collect::<Vec<_>>();
            if let Body::Layered {
                interface: Some(i), ..
            } = &m.body
            {
                candidates.push(*i);
            }
            for i in candidates {
                if !interfaces.contains(&i) {
                    interfaces.push(i);
                }
            }
        }
        assert!(interfaces.len() > 10, "{}", interfaces.len());
        let (mut tightest, mut loosest) = (f64::INFINITY, 0.0f64);
        for i in &interfaces {
            let table = PInterface::new(i, &wl, INTERFACE_SLOT);
            let alone = Material {
                name: "interface".into(),
                family: Family::Vinyl,
                body: Body::Layered {
                    base: Base {
                        albedo: Spectrum::Constant(0.0),
                        diffuse: Diffuse::Lambert,
                        sheen: None,
                        flakes: None,
                    },
                    interface: Some(*i),
                },
                coat: None,
            }
            .prepare(&wl);
            for step in 0..=20 {
                let deg = 89.0 * step as f64 / 20.0;
                let e_ref = directional_albedo(&alone, deg.to_radians(), 192);
                let t = table.transmittance(deg.to_radians().cos());
                for (e, lambda) in e_ref.iter().zip(wl) {
                    let slack = (1.0 - e) - t;
                    tightest = tightest.min(slack);
                    loosest = loosest.max(slack);
                    assert!(
                        slack > 0.0,
                        "alpha {} at {deg} deg, {lambda} nm: T {t} > 1 - E {}",
                        i.alpha,
                        1.0 - e
                    );
                }
            }
        }
        assert!(loosest < 0.015, "a table withholds {loosest}");
        eprintln!(
            "{} interfaces: slack {tightest:e} to {loosest:e}",
            interfaces.len()
        );
    }

    #[test]
    fn interface_transmittance_is_physical() {
        let i = PInterface::new(
            &Interface {
                alpha: 0.1,
                ior: Ior::constant(1.5),
            },
            &[550.0],
            INTERFACE_SLOT,
        );
        // Normal incidence: 1 - 0.04 (smooth-ish surface), with the conservative margin.
        let t0 = i.transmittance(1.0);
        assert!(t0 > 0.94 && t0 < 0.961, "{t0}");
        // Grazing: much less is transmitted.
        assert!(i.transmittance(0.05) < 0.75);
    }

    /// A base of diffuse albedo `rho` under a white sheen of roughness `r`.
    fn sheen_over(rho: f64, r: f64) -> Material {
        let mut m = lambert(rho);
        if let Body::Layered { base, .. } = &mut m.body {
            base.sheen = Some(Sheen {
                weight: 1.0,
                colour: Spectrum::Constant(1.0),
                roughness: r,
            });
        }
        m
    }

    /// A sheen alone is the Charlie distribution times the Neubelt visibility, scaled by
    /// 1 / 1.02 (a margin for the quadrature of its albedo) and, where its directional albedo
    /// would exceed 1 (small roughness: near grazing incidence), scaled down to stay passive.
    #[test]
    fn the_sheen_lobe_is_charlie_times_visibility_and_passive() {
        let dir = |theta: f64, phi: f64| {
            let (s, c) = theta.sin_cos();
            [s * phi.cos(), s * phi.sin(), c]
        };
        let pairs = [
            (dir(0.3, 0.0), dir(0.5, 2.0)),
            (dir(1.3, 0.0), dir(1.3, 0.0)),
            (dir(1.4, 0.5), dir(0.2, 3.0)),
            (dir(0.7, 1.0), dir(1.1, 1.0)),
            (dir(0.0, 0.0), dir(0.9, 0.0)),
        ];
        for r in [0.05, 0.1, 0.2, 0.3, 0.6, 1.0] {
            let sheen = sheen_over(0.0, r).prepare(&[550.0]);
            let scales: Vec<f64> = pairs
                .iter()
                .map(|&(wi, wo)| {
                    let mut f = [0.0];
                    sheen.eval(wi, wo, &mut f);
                    let h = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
                    let shape =
                        charlie_d(h[2] / dot(h, h).sqrt(), r) * sheen_visibility(wi[2], wo[2]);
                    f[0] / shape
                })
                .collect();
            for s in &scales {
                assert!(
                    (s - scales[0]).abs() <= 1e-12 * scales[0],
                    "r {r}: {scales:?}"
                );
            }
            let albedos: Vec<f64> = (0..=17)
                .map(|k| k as f64 * 5.0)
                .chain([87.0, 88.0, 89.0, 89.5, 89.9])
                .map(|deg| directional_albedo(&sheen, f64::to_radians(deg), 192)[0])
                .collect();
            let largest = albedos.iter().copied().fold(0.0, f64::max);
            assert!(largest <= 1.0, "r {r}: {albedos:?}");
            if scales[0] < 1.0 / 1.02 - 1e-12 {
                // Scaled down: the brightest incidence reflects just under all.
                assert!(largest > 0.96, "r {r}: {scales:?} {albedos:?}");
            } else {
                assert!((scales[0] - 1.0 / 1.02).abs() < 1e-15, "r {r}: {scales:?}");
            }
        }
    }

    /// Flakes cover part of the base, and the sheen (like the diffuse lobe) only the rest:
    /// flakes that reflect nothing (index 1) over half the surface halve the sheen.
    #[test]
    fn flakes_take_their_coverage_from_the_sheen() {
        let r = 0.4;
        let sheen = sheen_over(0.0, r).prepare(&[550.0]);
        let mut covered = sheen_over(0.0, r);
        if let Body::Layered { base, .. } = &mut covered.body {
            base.flakes = Some(Flakes {
                coverage: 0.5,
                lobe: Specular {
                    alpha: 0.1,
                    fresnel: Fresnel::Dielectric(Ior::constant(1.0)),
                },
            });
        }
        let covered = covered.prepare(&[550.0]);
        for (wi, wo) in [
            ([0.6, 0.0, 0.8], [0.6, 0.0, 0.8]),
            ([0.6, 0.0, 0.8], [-0.3, 0.5, 0.66f64.sqrt()]),
            ([0.0, 0.0, 1.0], [0.3, 0.4, 0.75f64.sqrt()]),
        ] {
            let (mut a, mut b) = ([0.0], [0.0]);
            sheen.eval(wi, wo, &mut a);
            covered.eval(wi, wo, &mut b);
            assert!(
                a[0] > 0.0 && b[0] == 0.5 * a[0],
                "{wi:?} {wo:?}: {} {}",
                a[0],
                b[0]
            );
        }
    }

    /// The diffuse lobe under a sheen receives what the sheen does not reflect, on the way in
    /// and on the way out: its part of f is rho / pi (1 - E(mu_i)) (1 - E(mu_o)), with E the
    /// sheen's directional albedo held with a small margin (conservative, at most 3 % off).
    #[test]
    fn the_diffuse_under_a_sheen_gets_what_the_sheen_leaves() {
        let rho = 0.5;
        for (r, ti, to) in [
            (0.3, 0.0f64, 0.0f64),
            (0.3, 0.3, 1.2),
            (0.3, 1.3, 1.3),
            (0.3, 1.45, 0.6),
            (0.1, 1.45, 0.6),
            (0.6, 1.5, 1.5),
        ] {
            let both = sheen_over(rho, r).prepare(&[550.0]);
            let sheen = sheen_over(0.0, r).prepare(&[550.0]);
            let e = |theta: f64| directional_albedo(&sheen, theta, 192)[0];
            let wi = [ti.sin(), 0.0, ti.cos()];
            let wo = [-to.sin(), 0.0, to.cos()];
            let (mut fb, mut fs) = ([0.0], [0.0]);
            both.eval(wi, wo, &mut fb);
            sheen.eval(wi, wo, &mut fs);
            let t = (fb[0] - fs[0]) / (rho / PI);
            let ideal = (1.0 - e(ti)) * (1.0 - e(to));
            assert!(
                t <= ideal && t > ideal - 0.03,
                "r {r}, {ti} {to}: {t} vs {ideal}"
            );
        }
    }

    /// Both sets of albedo nodes integrate known lobes (f cos theta_o over the hemisphere):
    /// a Lambertian 1/pi to 1 at every incidence, f = cos theta_o to 2 pi / 3 and
    /// f = (wo_x)^2 to pi / 4 (an azimuth-dependent lobe); the tables hold the
    /// integrals at every node of the table.
    #[test]
    fn albedo_nodes_integrate_known_lobes() {
        for (name, nodes, tol) in [
            ("cosine", cosine_nodes(48), 1e-3),
            ("solid angle", solid_angle_nodes(48), 1e-3),
        ] {
            let weights: f64 = nodes.iter().map(|n| n.1).sum();
            assert!((weights - PI).abs() < 1e-3, "{name}: {weights}");
            for &(wo, _) in &nodes {
                assert!(
                    (dot(wo, wo) - 1.0).abs() < 1e-12 && wo[2] > 0.0,
                    "{name}: {wo:?}"
                );
            }
            let lambert = albedo_table(|_, _| 1.0 / PI, &nodes);
            assert_eq!(lambert.len(), E_NODES);
            for a in &lambert {
                assert!((a - 1.0).abs() < 1e-12, "{name}: {a}");
            }
            for (shape, expected) in [
                (
                    &(|_: Vec3, wo: Vec3| wo[2]) as &dyn Fn(Vec3, Vec3) -> f64,
                    2.0 * PI / 3.0,
                ),
                (&|_: Vec3, wo: Vec3| wo[0] * wo[0], PI / 4.0),
                // wo_y is odd in the azimuth: 0 only over the whole circle.
                (&|_: Vec3, wo: Vec3| (1.0 + wo[1]) / PI, 1.0),
            ] {
                for a in albedo_table(shape, &nodes) {
                    assert!(
                        (a - expected).abs() < tol * expected,
                        "{name}: {a} vs {expected}"
                    );
                }
            }
        }
        // The incidence of node k is mu = (k / (N - 1))^2, from 1e-3 (near grazing) to 1.
        let mu_of_node = albedo_table(|wi, _| wi[2] / PI, &cosine_nodes(8));
        for (k, mu) in mu_of_node.iter().enumerate() {
            let t = k as f64 / (E_NODES - 1) as f64;
            assert!((mu - (t * t).max(1e-3)).abs() < 1e-12, "{k}: {mu}");
        }
    }

    /// Fujii's Oren-Nayar lobe is energy-bounded: its albedo stays at most 1 at every
    /// incidence for every roughness, so its normalisation is the 1 % margin alone, and the
    /// lobe at sigma = 0 is Lambert's (both divided by that margin).
    #[test]
    fn oren_nayar_is_energy_bounded() {
        for sigma in [0.0, 0.25, 0.5, 1.0] {
            let table = albedo_table(|wi, wo| oren_nayar(wi, wo, sigma), &cosine_nodes(48));
            let largest = table.iter().copied().fold(0.0, f64::max);
            assert!(largest <= 1.0 + 1e-9, "sigma {sigma}: {largest}");
            assert!(largest > 0.9, "sigma {sigma}: {largest}");
        }
        let wi = [0.6, 0.0, 0.8];
        let wo = unit([-0.3, 0.4, 0.7]).unwrap();
        assert!((oren_nayar(wi, wo, 0.0) - 1.0 / PI).abs() < 1e-15);
        // Fujii's A + B s / t, A = 1 / (pi + (pi / 2 - 2 / 3) sigma), B = sigma A, with
        // s = wi . wo - mu_i mu_o and t = max(mu_i, mu_o) where s > 0, else 1: by hand for
        // wi = (0.6, 0, 0.8): back-scatter s = 0.36, t = 0.8; forward s = -0.36, t = 1; towards
        // the horizon wo = (0.8, 0, 0.6): s = 0.48, t = 0.8.
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b;
        let (one, half) = (1.5 * PI - 2.0 / 3.0, 1.25 * PI - 1.0 / 3.0);
        for (wo, sigma, expected) in [
            ([0.6, 0.0, 0.8], 1.0, 1.45 / one),
            ([-0.6, 0.0, 0.8], 1.0, 0.64 / one),
            ([0.8, 0.0, 0.6], 1.0, 1.6 / one),
            ([0.6, 0.0, 0.8], 0.5, 1.225 / half),
            ([-0.6, 0.0, 0.8], 0.5, 0.82 / half),
        ] {
            let f = oren_nayar(wi, wo, sigma);
            assert!(close(f, expected), "{wo:?} {sigma}: {f} vs {expected}");
        }
        // In a material: the albedo times the shape over its 1 % margin.
        let mut rough = lambert(0.5);
        if let Body::Layered { base, .. } = &mut rough.body {
            base.diffuse = Diffuse::OrenNayar { sigma: 1.0 };
        }
        let mut f = [0.0];
        rough.prepare(&[550.0]).eval(wi, [0.6, 0.0, 0.8], &mut f);
        assert!(close(f[0], 0.5 * 1.45 / one / 1.01), "{}", f[0]);
    }
}
