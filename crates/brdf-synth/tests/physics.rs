//! Physical checks of the 51 preset materials: energy conservation, reciprocity,
//! non-negativity, family signatures, variety, determinism.

use std::f64::consts::PI;

use brdf_io::{AngularGrid, Channels, HalfDiff};
use brdf_synth::material::directional_albedo;
use brdf_synth::microfacet::{ggx_d, smith_g2};
use brdf_synth::{
    Body, Family, Fresnel, FresnelCache, Material, Metal, N_MATERIALS, generate, preset,
    preset_material,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

const LAMBDAS: [f64; 5] = [380.0, 450.0, 550.0, 700.0, 950.0];

fn dir(theta: f64, phi: f64) -> [f64; 3] {
    [
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    ]
}

/// Directional albedo <= 1 at every incidence angle (0 to 89 degrees, where clear coats and
/// metals usually break) and wavelength, for every preset material (canonical and a perturbed seed). The quadrature's own error is checked on a Lambertian in
/// the library's unit tests (< 0.2 %), hence the 0.3 % allowance.
#[test]
fn energy_conservation_all_presets() {
    for seed in [0, 5] {
        let worst: Vec<(f64, String)> = preset(seed)
            .par_iter()
            .map(|m| {
                let p = m.prepare(&LAMBDAS);
                let mut worst = (0.0f64, String::new());
                for deg in [0.0f64, 40.0, 70.0, 85.0, 89.0] {
                    let a = directional_albedo(&p, deg.to_radians(), 96);
                    for (l, v) in LAMBDAS.iter().zip(&a) {
                        assert!(v.is_finite() && *v >= 0.0, "{} {deg} {l}: {v}", m.name);
                        if *v > worst.0 {
                            worst = (*v, format!("{} at {deg} deg, {l} nm", m.name));
                        }
                    }
                }
                worst
            })
            .collect();
        let top = worst
            .iter()
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap()
            .clone();
        println!(
            "seed {seed}: largest directional albedo {:.4} ({})",
            top.0, top.1
        );
        for (a, what) in &worst {
            assert!(*a <= 1.003, "albedo {a} > 1: {what}");
        }
        // Sanity: the near-ideal diffuser reflects nearly everything, black paint little.
        let spectralon = worst
            .iter()
            .find(|w| w.1.starts_with("spectralon"))
            .unwrap();
        assert!(spectralon.0 > 0.95, "{spectralon:?}");
    }
}

/// Felt and paper are passive but not absurdly dark; a clear-coated black is dark.
#[test]
fn albedo_levels_are_plausible() {
    let at_normal = |name: &str| {
        let m = preset_material(name, 0).unwrap().prepare(&[550.0]);
        directional_albedo(&m, 0.3, 96)[0]
    };
    let white_felt = at_normal("acrylic_felt_white");
    let black = at_normal("carpaint_solid_black");
    let spectralon = at_normal("spectralon");
    assert!(
        white_felt > 0.5 && white_felt < 0.97,
        "white felt {white_felt}"
    );
    assert!(black > 0.03 && black < 0.12, "black car paint {black}");
    assert!(
        (spectralon - 0.976).abs() < 0.005,
        "spectralon {spectralon}"
    );
}

/// f(wi, wo) = f(wo, wi) for random direction pairs, every material, several wavelengths.
#[test]
fn reciprocity_and_non_negativity() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let pairs: Vec<([f64; 3], [f64; 3])> = (0..300)
        .map(|_| {
            let a = dir(rng.random::<f64>() * 1.55, rng.random::<f64>() * 2.0 * PI);
            let b = dir(rng.random::<f64>() * 1.55, rng.random::<f64>() * 2.0 * PI);
            (a, b)
        })
        .collect();
    for m in preset(0).iter().chain(preset(9).iter()) {
        let p = m.prepare(&LAMBDAS);
        let (mut f, mut g) = ([0.0; 5], [0.0; 5]);
        for (wi, wo) in &pairs {
            p.eval(*wi, *wo, &mut f);
            p.eval(*wo, *wi, &mut g);
            for l in 0..5 {
                assert!(f[l].is_finite() && f[l] >= 0.0, "{}: {f:?}", m.name);
                let tol = 1e-12 + 1e-9 * f[l].abs();
                assert!(
                    (f[l] - g[l]).abs() <= tol,
                    "{}: {} vs {}",
                    m.name,
                    f[l],
                    g[l]
                );
            }
        }
        // Below the horizon: nothing.
        p.eval([0.3, 0.0, 0.9], [0.2, 0.1, -0.3], &mut f);
        assert_eq!(f, [0.0; 5]);
    }
}

/// Every preset is isotropic: turning both directions about the normal by any angle leaves f
/// as it was (reciprocity alone cannot tell a half vector built from wi - wo across the plane
/// of incidence from wi + wo).
#[test]
fn presets_are_isotropic() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let cases: Vec<(f64, f64, f64, f64, f64)> = (0..100)
        .map(|_| {
            let mut r = |hi: f64| rng.random::<f64>() * hi;
            (r(1.5), r(1.5), r(2.0 * PI), r(2.0 * PI), r(2.0 * PI))
        })
        .collect();
    for m in preset(0) {
        let p = m.prepare(&LAMBDAS);
        let (mut f, mut g) = ([0.0; 5], [0.0; 5]);
        for &(ti, to, pi, po, turn) in &cases {
            p.eval(dir(ti, pi), dir(to, po), &mut f);
            p.eval(dir(ti, pi + turn), dir(to, po + turn), &mut g);
            for l in 0..5 {
                assert!(
                    (f[l] - g[l]).abs() <= 1e-12 + 1e-9 * f[l],
                    "{}: {} turned by {turn}: {}",
                    m.name,
                    f[l],
                    g[l]
                );
            }
        }
    }
}

/// At normal incidence and view (theta_h = theta_d = 0) a bare metal's value is
/// sum_k w_k D_k(0) G2_k(1, 1) / 4 * F(1), and F(1) must be the reflectance of the metal's
/// (n, k), ((n-1)^2 + k^2) / ((n+1)^2 + k^2), computed here from the source table (shared data).
#[test]
fn metal_fresnel_colour_at_normal_incidence() {
    let Some(source) =
        shared_data::read_to_string("spectra/metals-nk/metals_nk_360-1000_5nm_linear_interp.csv")
    else {
        return;
    };
    let lambdas = [
        400.0, 450.0, 500.0, 550.0, 600.0, 650.0, 700.0, 800.0, 900.0,
    ];
    for (name, metal) in [
        ("metal_gold", Metal::Gold),
        ("metal_silver", Metal::Silver),
        ("metal_copper", Metal::Copper),
        ("metal_aluminium", Metal::Aluminium),
        ("metal_chromium", Metal::Chromium),
    ] {
        let m = preset_material(name, 0).unwrap();
        let Body::Metal { lobes } = &m.body else {
            panic!("{name} is not a bare metal")
        };
        let shape: f64 = lobes
            .iter()
            .map(|(w, s)| {
                assert_eq!(s.fresnel, Fresnel::Conductor(metal));
                w * ggx_d(1.0, s.alpha) * smith_g2(1.0, 1.0, s.alpha) / 4.0
            })
            .sum();
        let p = m.prepare(&lambdas);
        let mut f = vec![0.0; lambdas.len()];
        p.eval([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], &mut f);
        for (l, v) in lambdas.iter().zip(&f) {
            let (n, k) = nk_from_csv(&source, metal, *l);
            let r = ((n - 1.0).powi(2) + k * k) / ((n + 1.0).powi(2) + k * k);
            let got = v / shape;
            assert!(
                (got - r).abs() < 0.01,
                "{name} at {l} nm: F = {got}, table {r}"
            );
        }
    }
    // The colours people recognise: gold and copper reflect red far more than blue; silver
    // and aluminium are nearly neutral and bright; chromium is neutral and darker.
    let r = |m: Metal, l: f64| m.normal_reflectance(l);
    assert!(r(Metal::Gold, 650.0) / r(Metal::Gold, 450.0) > 2.0);
    assert!(r(Metal::Copper, 650.0) / r(Metal::Copper, 450.0) > 1.5);
    assert!(r(Metal::Silver, 550.0) > 0.95 && r(Metal::Aluminium, 550.0) > 0.9);
    let cr = r(Metal::Chromium, 550.0);
    assert!(cr > 0.5 && cr < 0.7 && (r(Metal::Chromium, 650.0) - cr).abs() < 0.05);
}

fn nk_from_csv(text: &str, metal: Metal, lambda: f64) -> (f64, f64) {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |s: &str| header.iter().position(|h| *h == s).unwrap();
    let (ni, ki) = (
        col(&format!("{}_n", metal.source_name())),
        col(&format!("{}_k", metal.source_name())),
    );
    for l in lines {
        let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
        if (v[0] - lambda).abs() < 1e-6 {
            return (v[ni], v[ki]);
        }
    }
    panic!("{lambda} nm not in the table")
}

/// Felt is brighter at grazing angles than at normal incidence (retro-reflection geometry):
/// the sheen and the rough-diffuse back-scatter; a Lambertian would be flat.
#[test]
fn felt_is_brighter_at_grazing() {
    for m in preset(0).iter().filter(|m| m.family == Family::Felt) {
        let p = m.prepare(&[550.0]);
        let f = |deg: f64| {
            let w = dir(deg.to_radians(), 0.0);
            let mut o = [0.0];
            p.eval(w, w, &mut o);
            o[0]
        };
        let ratio = f(75.0) / f(0.0);
        assert!(ratio > 1.3, "{}: retro f(75)/f(0) = {ratio}", m.name);
    }
    // The test discriminates: a Lambertian diffuser (Spectralon) is flat.
    let flat = preset_material("spectralon", 0).unwrap().prepare(&[550.0]);
    let (mut a, mut b) = ([0.0], [0.0]);
    flat.eval(dir(0.0, 0.0), dir(0.0, 0.0), &mut a);
    let w = dir(75f64.to_radians(), 0.0);
    flat.eval(w, w, &mut b);
    assert!((b[0] / a[0] - 1.0).abs() < 1e-9);
}

/// Local maxima (index) of a sampled curve.
fn local_maxima(f: &[f64]) -> Vec<usize> {
    (1..f.len() - 1)
        .filter(|&i| f[i] > f[i - 1] && f[i] >= f[i + 1])
        .collect()
}

/// The wavelength of peak reflectance of an iridescent material moves towards the blue as the
/// angle grows (thin-film interference: the optical path n d cos(theta_t) shrinks). The
/// strongest visible peak at theta_d = 10 deg is tracked to the nearest peak at 60 deg. The
/// half vector is 0.25 rad off the normal, where the flakes' lobe outshines the clear coat's.
#[test]
fn iridescent_colour_shifts_with_angle() {
    let lambdas: Vec<f64> = (0..=210).map(|i| 380.0 + 2.0 * i as f64).collect();
    let iridescent: Vec<Material> = preset(0)
        .into_iter()
        .filter(|m| m.family == Family::Iridescent)
        .collect();
    assert!(iridescent.len() >= 5);
    for m in &iridescent {
        let p = m.prepare(&lambdas);
        let spectrum = |theta_d_deg: f64| {
            let hd = HalfDiff {
                theta_h: 0.25,
                theta_d: theta_d_deg.to_radians(),
                phi_d: 0.0,
            };
            let mut f = vec![0.0; lambdas.len()];
            p.eval_half_diff(&hd, &mut f);
            f
        };
        let (near, far) = (spectrum(10.0), spectrum(60.0));
        let peaks = local_maxima(&near);
        let &p0 = peaks
            .iter()
            .filter(|&&i| lambdas[i] >= 420.0 && lambdas[i] <= 760.0)
            .max_by(|a, b| near[**a].total_cmp(&near[**b]))
            .unwrap_or_else(|| panic!("{}: no visible peak", m.name));
        let &p1 = local_maxima(&far)
            .iter()
            .min_by(|a, b| {
                (lambdas[**a] - lambdas[p0])
                    .abs()
                    .total_cmp(&(lambdas[**b] - lambdas[p0]).abs())
            })
            .unwrap();
        let (l0, l1) = (lambdas[p0], lambdas[p1]);
        println!("{}: peak {l0} nm at 10 deg -> {l1} nm at 60 deg", m.name);
        assert!(
            l1 < l0 - 10.0 && l1 > l0 - 200.0,
            "{}: peak {l0} -> {l1} nm",
            m.name
        );
        // A real colour, not a flat spectrum: the peak stands out of the mean (only slightly
        // for the pearl white, aurora_white).
        let mean = near.iter().sum::<f64>() / near.len() as f64;
        assert!(
            near[p0] > 1.05 * mean,
            "{}: peak {} mean {mean}",
            m.name,
            near[p0]
        );
    }
    // Non-iridescent paints keep their hue: a solid red's diffuse peak stays in the red.
    let red = preset_material("carpaint_solid_red", 0)
        .unwrap()
        .prepare(&lambdas);
    let mut a = vec![0.0; lambdas.len()];
    let mut b = vec![0.0; lambdas.len()];
    red.eval(dir(0.5, 0.0), dir(0.6, 2.0), &mut a);
    red.eval(dir(1.0, 0.0), dir(1.1, 2.0), &mut b);
    let argmax = |f: &[f64]| (0..f.len()).max_by(|x, y| f[*x].total_cmp(&f[*y])).unwrap();
    assert!(lambdas[argmax(&a)] > 600.0 && lambdas[argmax(&b)] > 600.0);
}

/// Top eigenvalue of a symmetric positive semi-definite matrix by power iteration.
fn top_eigenvalue(g: &[f64], n: usize) -> f64 {
    let mut v = vec![1.0; n];
    let mut lambda = 0.0;
    for _ in 0..500 {
        let w: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| g[i * n + j] * v[j]).sum())
            .collect();
        let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        lambda = norm;
        v = w.iter().map(|x| x / norm).collect();
    }
    lambda
}

/// The 51 materials are varied: in the centred Gram matrix of the log-transformed data no
/// single direction dominates.
#[test]
fn variety_of_the_preset() {
    let grid = AngularGrid::new(8, 8, 16).unwrap();
    let channels = Channels::parse_wavelengths("400:950:50").unwrap();
    let data = generate(&preset(0), grid, &channels).unwrap();
    assert_eq!(data.n(), N_MATERIALS);
    let mask = grid.validity_mask();
    let nc = channels.len();
    let d = data.d();
    let valid: Vec<usize> = (0..d).filter(|i| mask[i / nc]).collect();
    // log(f + 1e-3), centred over materials, on valid cells only.
    let n = data.n();
    let mut y = vec![0.0; n * valid.len()];
    for i in 0..n {
        for (k, &j) in valid.iter().enumerate() {
            y[i * valid.len() + k] = (data.values[i * d + j] + 1e-3).ln();
        }
    }
    for k in 0..valid.len() {
        let mean = (0..n).map(|i| y[i * valid.len() + k]).sum::<f64>() / n as f64;
        for i in 0..n {
            y[i * valid.len() + k] -= mean;
        }
    }
    let mut g = vec![0.0; n * n];
    for a in 0..n {
        for b in 0..=a {
            let s: f64 = (0..valid.len())
                .map(|k| y[a * valid.len() + k] * y[b * valid.len() + k])
                .sum();
            g[a * n + b] = s;
            g[b * n + a] = s;
        }
    }
    let trace: f64 = (0..n).map(|i| g[i * n + i]).sum();
    let share = top_eigenvalue(&g, n) / trace;
    println!(
        "variety: top eigenvalue of the centred log Gram = {:.1} % of the trace",
        100.0 * share
    );
    assert!(share < 0.8, "top eigenvalue share {share}");
    assert!(
        share > 0.1,
        "implausibly flat spectrum of the Gram matrix: {share}"
    );
    // No two materials are identical.
    for a in 0..n {
        for b in 0..a {
            let dist = g[a * n + a] + g[b * n + b] - 2.0 * g[a * n + b];
            assert!(
                dist > 1e-3 * trace / n as f64,
                "{} ~ {}",
                data.names[a],
                data.names[b]
            );
        }
    }
}

/// Same seed, same data; another seed, different data (but the same names).
#[test]
fn datasets_are_deterministic_per_seed() {
    let grid = AngularGrid::new(4, 4, 8).unwrap();
    let channels = Channels::parse_wavelengths("450:650:100").unwrap();
    let a = brdf_synth::preset_dataset(grid, &channels, 3).unwrap();
    let b = brdf_synth::preset_dataset(grid, &channels, 3).unwrap();
    let c = brdf_synth::preset_dataset(grid, &channels, 4).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.names, c.names);
    assert_ne!(a.values, c.values);
    // Perturbations are small: the rows stay close in log space.
    let close = (0..a.values.len())
        .filter(|&i| a.values[i] > 0.0)
        .filter(|&i| ((a.values[i] + 1e-3) / (c.values[i] + 1e-3)).ln().abs() < 1.0)
        .count();
    let positive = a.values.iter().filter(|v| **v > 0.0).count();
    assert!(
        close as f64 > 0.9 * positive as f64,
        "{close} of {positive}"
    );
}

/// Dataset layout: flat = angular_index * n_channels + channel, below-horizon cells 0.
#[test]
fn dataset_layout_matches_direct_evaluation() {
    let grid = AngularGrid::new(5, 6, 7).unwrap();
    let channels = Channels::parse_wavelengths("400,550,700").unwrap();
    let mats = preset(0);
    let data = generate(&mats[..4], grid, &channels).unwrap();
    let mask = grid.validity_mask();
    assert!(mask.iter().any(|v| !v));
    for (mi, m) in mats[..4].iter().enumerate() {
        // Independent path: one single-wavelength preparation per wavelength.
        let single: Vec<_> = [400.0, 550.0, 700.0].map(|l| m.prepare(&[l])).into();
        for (cell, &valid) in mask.iter().enumerate() {
            let (i, j, k) = grid.unindex(cell);
            let (wi, wo) = grid.bin_centre(i, j, k).to_dirs();
            for (l, lambda) in [400.0, 550.0, 700.0].iter().enumerate() {
                let v = data.row(mi)[cell * 3 + l];
                if valid {
                    let mut direct = [0.0];
                    single[l].eval(wi, wo, &mut direct);
                    let direct = direct[0];
                    assert_eq!(single[l].wavelengths(), [*lambda]);
                    assert!((v - direct).abs() <= 1e-12 * direct.abs().max(1.0));
                    assert!(v > 0.0);
                } else {
                    assert_eq!(v, 0.0);
                }
            }
        }
    }
    assert!(generate(&mats[..1], grid, &Channels::Rgb).is_err());
}

/// f at a wavelength is the same whatever other wavelengths the material was prepared for: a
/// dataset at 400:700:100 holds the same values as the default 360:1000:20 at the wavelengths
/// they share. (The interfaces' coupling tables were taken at the largest index over the
/// requested wavelengths only, so the clear-coated and binder materials differed by up to
/// 1.3 % at 700 nm.)
#[test]
fn values_do_not_depend_on_the_other_wavelengths() {
    let grid = AngularGrid::new(4, 4, 8).unwrap();
    let full = Channels::parse_wavelengths("360:1000:20").unwrap();
    let part = Channels::parse_wavelengths("400:700:100").unwrap();
    let a = generate(&preset(0), grid, &full).unwrap();
    let b = generate(&preset(0), grid, &part).unwrap();
    let (na, nb) = (full.len(), part.len());
    let mut worst = (0.0f64, String::new());
    for m in 0..a.n() {
        for cell in 0..grid.len() {
            for (lb, la) in [(0, 2), (1, 7), (2, 12), (3, 17)] {
                let (x, y) = (a.row(m)[cell * na + la], b.row(m)[cell * nb + lb]);
                let rel = (x - y).abs() / x.abs().max(1e-300);
                if rel > worst.0 {
                    worst = (rel, format!("{} cell {cell} channel {lb}", a.names[m]));
                }
            }
        }
    }
    assert!(
        worst.0 <= 1e-12,
        "relative difference {:.3e} at {}",
        worst.0,
        worst.1
    );
    // Directly, one wavelength alone: a clear-coated paint at 700 nm.
    let m = preset_material("carpaint_solid_red", 0).unwrap();
    let wl: Vec<f64> = (0..=32).map(|i| 360.0 + 20.0 * i as f64).collect();
    let (wi, wo) = (dir(0.4, 0.0), dir(1.2, 2.5));
    let mut f = vec![0.0; wl.len()];
    m.prepare(&wl).eval(wi, wo, &mut f);
    let alone = m.eval(wi, wo, 700.0);
    assert!(
        (f[17] - alone).abs() <= 1e-12 * alone,
        "{} vs {alone}",
        f[17]
    );
}

/// Finite, non-negative and reciprocal at the edges of the hemisphere, for every preset at the
/// default 33 wavelengths (360:1000:20 nm): exactly grazing directions (theta = 90 deg and
/// 1e-9 rad above it), wi = wo (theta_d = 0) and wi = reflect(wo) (theta_h = 0), across azimuths.
#[test]
fn grazing_and_mirror_configurations_are_finite() {
    let wl: Vec<f64> = (0..33).map(|i| 360.0 + 20.0 * i as f64).collect();
    let h = PI / 2.0;
    let mut dirs = Vec::new();
    for t in [0.0, 0.5, 1.2, 1.5, h - 1e-4, h - 1e-9, h] {
        for ph in [0.0, 1.0, 3.0] {
            dirs.push(dir(t, ph));
        }
    }
    preset(0).par_iter().for_each(|m| {
        let p = m.prepare(&wl);
        let (mut f, mut g) = (vec![0.0; 33], vec![0.0; 33]);
        for a in &dirs {
            let mirror = [-a[0], -a[1], a[2]];
            for b in dirs.iter().chain([a, &mirror]) {
                p.eval(*a, *b, &mut f);
                p.eval(*b, *a, &mut g);
                for (x, y) in f.iter().zip(&g) {
                    assert!(x.is_finite() && *x >= 0.0, "{}: {a:?} {b:?} {x}", m.name);
                    assert!((x - y).abs() <= 1e-12 + 1e-9 * x, "{}: {x} vs {y}", m.name);
                }
            }
        }
    });
}

/// The largest relative jump of `f` (at `l`) left after bisecting the steepest of `steps`
/// steps along `path` (s in [0, 1]) down to an interval of ~1e-12: about 0 where `f` is
/// continuous, the size of the step where it is not.
fn jump_along(
    p: &brdf_synth::PreparedMaterial,
    path: impl Fn(f64) -> ([f64; 3], [f64; 3]),
    steps: usize,
) -> (f64, f64) {
    let n = p.wavelengths().len();
    let eval = |s: f64, out: &mut [f64]| {
        let (wi, wo) = path(s);
        p.eval(wi, wo, out);
    };
    let (mut f, mut prev) = (vec![0.0; n], vec![0.0; n]);
    eval(0.0, &mut prev);
    // The steepest step (relative to the larger end, with a floor) and its channel.
    let (mut worst, mut at, mut channel) = (-1.0, 1, 0);
    for k in 1..=steps {
        eval(k as f64 / steps as f64, &mut f);
        for l in 0..n {
            let rel = (f[l] - prev[l]).abs() / f[l].abs().max(prev[l].abs()).max(1e-6);
            if rel > worst {
                (worst, at, channel) = (rel, k, l);
            }
        }
        std::mem::swap(&mut f, &mut prev);
    }
    let value = |s: f64, out: &mut [f64]| {
        eval(s, out);
        out[channel]
    };
    let (mut a, mut b) = ((at - 1) as f64 / steps as f64, at as f64 / steps as f64);
    for _ in 0..40 {
        let m = 0.5 * (a + b);
        let (fa, fm, fb) = (value(a, &mut f), value(m, &mut f), value(b, &mut f));
        if (fm - fa).abs() > (fb - fm).abs() {
            b = m;
        } else {
            a = m;
        }
    }
    let (fa, fb) = (value(a, &mut f), value(b, &mut f));
    ((fa - fb).abs() / fa.abs().max(fb.abs()).max(1e-12), a)
}

/// Every preset is continuous above the horizon: along random paths of (wi, wo) (one or both
/// directions moving, theta up to 1.55 rad), the steepest step, bisected to ~1e-12, leaves no
/// jump (a discontinuity, e.g. a branch of the Fresnel or thin-film code, a clamped coupling
/// table or an Oren-Nayar case split, would stay at its size). The detector is checked on paths
/// that cross the horizon, where every preset does jump to 0.
#[test]
fn presets_are_continuous_above_the_horizon() {
    let wl: Vec<f64> = (0..33).map(|i| 360.0 + 20.0 * i as f64).collect();
    preset(0).par_iter().enumerate().for_each(|(i, m)| {
        let p = m.prepare(&wl);
        let mut rng = ChaCha8Rng::seed_from_u64(7000 + i as u64);
        let mut angle = |hi: f64| (rng.random_range(0.0..hi), rng.random_range(0.0..2.0 * PI));
        for line in 0..16 {
            let (wi0, wi1, wo0, wo1) = (angle(1.55), angle(1.55), angle(1.55), angle(1.55));
            let both = line % 2 == 1;
            let lerp = |a: (f64, f64), b: (f64, f64), s: f64| {
                dir(a.0 + (b.0 - a.0) * s, a.1 + (b.1 - a.1) * s)
            };
            let path = |s: f64| {
                (
                    lerp(wi0, if both { wi1 } else { wi0 }, s),
                    lerp(wo0, wo1, s),
                )
            };
            let (jump, s) = jump_along(&p, path, 1000);
            assert!(jump < 1e-6, "{}: jump {jump:e} at {:?}", m.name, path(s));
        }
        // Positive control: wo from 1.0 rad to 1.7 rad crosses the horizon.
        let (wi, phi) = angle(1.2);
        let (jump, _) = jump_along(&p, |s| (dir(wi, 0.0), dir(1.0 + 0.7 * s, phi)), 1000);
        assert!(jump > 0.99, "{}: horizon jump {jump}", m.name);
    });
}

/// Remembered Fresnel reflectances change nothing: every preset (seeds 0 and 3) gives the same
/// bits with a `FresnelCache` as without, on a grid's bin centres visited twice (the second
/// time from the cache), at random direction pairs, and across a cache that filled and started
/// again (more distinct cosines than `FresnelCache::MAX_VALUES` holds).
#[test]
fn fresnel_caches_give_the_same_bits() {
    let wl: Vec<f64> = (0..33).map(|k| 360.0 + 20.0 * k as f64).collect();
    let grid = AngularGrid::new(6, 8, 12).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(25);
    let random: Vec<([f64; 3], [f64; 3])> = (0..400)
        .map(|_| {
            let mut d = || dir(rng.random_range(0.0..1.6), rng.random_range(0.0..6.3));
            (d(), d())
        })
        .collect();
    let distinct = FresnelCache::MAX_VALUES / wl.len() + 500;
    for seed in [0, 3] {
        for m in preset(seed) {
            let p = m.prepare(&wl);
            let mut cache = FresnelCache::new();
            let (mut plain, mut cached) = (vec![0.0; wl.len()], vec![0.0; wl.len()]);
            let mut check = |wi: [f64; 3], wo: [f64; 3], cache: &mut FresnelCache| {
                p.eval(wi, wo, &mut plain);
                p.eval_cached(wi, wo, &mut cached, cache);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&plain), bits(&cached), "{} at {wi:?} {wo:?}", m.name);
            };
            for _ in 0..2 {
                for cell in 0..grid.len() {
                    let (wi, wo) = grid.bin_centre_flat(cell).to_dirs();
                    check(wi, wo, &mut cache);
                }
            }
            for &(wi, wo) in &random {
                check(wi, wo, &mut cache);
            }
            if m.name == "metal_gold" || m.name == "irid_flake_paint1" {
                // Specular pairs at `distinct` incidence angles fill the cache beyond its limit.
                for k in 0..distinct {
                    let theta = 1.5 * k as f64 / distinct as f64;
                    check(dir(theta, 0.0), dir(theta, PI), &mut cache);
                }
                for k in 0..50 {
                    let theta = 1.5 * k as f64 / 50.0;
                    check(dir(theta, 0.0), dir(theta, PI), &mut cache);
                }
            }
        }
    }
}

/// `brdf_io::albedo` (the renderer-facing albedo of any `BrdfSource`, 96 x 96 half vectors)
/// against this crate's own quadrature at twice the resolution, on every preset through
/// its `BrdfSource` face: sharp metals, clear coats and diffusers alike.
#[test]
fn brdf_io_albedo_matches_a_finer_quadrature() {
    let angles = [0.0, 30.0, 60.0, 80.0, 88.0];
    let worst = preset(0)
        .par_iter()
        .map(|m| {
            let p = m.prepare(&LAMBDAS);
            let table = brdf_io::albedo::directional_albedo(
                &p,
                &angles,
                brdf_io::albedo::DEFAULT_RESOLUTION,
            )
            .unwrap();
            let mut worst = (0.0f64, String::new());
            for (k, deg) in angles.iter().enumerate() {
                let fine = directional_albedo(&p, deg.to_radians(), 192);
                for ((l, a), b) in LAMBDAS.iter().zip(table.row(k)).zip(&fine) {
                    let err = (a - b).abs() / b.max(1e-3);
                    if err > worst.0 {
                        worst = (err, format!("{} at {deg} deg, {l} nm: {a} vs {b}", m.name));
                    }
                }
            }
            worst
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .unwrap();
    println!("largest relative difference {:.2e} ({})", worst.0, worst.1);
    assert!(worst.0 < 0.01, "{worst:?}");
}
