//! The default preset: 51 named materials spanning the families of the RGL isotropic catalogue
//! (felts, papers, cardboard, wall paints, vinyl wrapping films, satins, car paints, painted
//! and bare metals, iridescent paints, a leaf and a Spectralon-like diffuser).
//!
//! [`preset`]`(0)` is the canonical set; any other seed applies small deterministic
//! perturbations (roughness, reflectance level, hue shift, flake coverage, film thickness) to
//! every material, so that benchmarks and tests can draw many similar but distinct datasets.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::material::{
    Base, Body, Diffuse, Family, Flakes, Fresnel, Interface, Material, Sheen, Specular, Substrate,
};
use crate::optics::{Ior, Metal};
use crate::spectrum::{Spectrum, colorchecker as cc};

/// Number of materials in the preset.
pub const N_MATERIALS: usize = 51;

fn c(t: &'static [f64; 21]) -> Spectrum {
    Spectrum::colorchecker(t)
}

/// A pastel: `t` of a patch mixed into the white patch.
fn pastel(t: &'static [f64; 21], amount: f64) -> Spectrum {
    c(&cc::WHITE_9_5).mix(amount, c(t))
}

fn base(albedo: Spectrum, diffuse: Diffuse) -> Base {
    Base {
        albedo,
        diffuse,
        sheen: None,
        flakes: None,
    }
}

fn mat(name: &str, family: Family, body: Body, coat: Option<Interface>) -> Material {
    Material {
        name: name.to_owned(),
        family,
        body,
        coat,
    }
}

fn layered(base: Base, interface: Option<(f64, Ior)>) -> Body {
    Body::Layered {
        base,
        interface: interface.map(|(alpha, ior)| Interface { alpha, ior }),
    }
}

fn clear_coat(alpha: f64) -> Option<Interface> {
    Some(Interface {
        alpha,
        ior: Ior::CLEAR_COAT,
    })
}

/// Felt: very rough diffuse plus a fibre sheen tinted by the dye (brighter at grazing).
fn felt(name: &str, colour: Spectrum) -> Material {
    let sheen_colour = colour.clone().mix(0.35, Spectrum::Constant(0.9));
    let mut b = base(colour, Diffuse::OrenNayar { sigma: 1.0 });
    b.sheen = Some(Sheen {
        weight: 0.45,
        colour: sheen_colour,
        roughness: 0.35,
    });
    mat(name, Family::Felt, layered(b, None), None)
}

/// Paper: rough diffuse with a faint, very broad gloss.
fn paper(name: &str, colour: Spectrum) -> Material {
    mat(
        name,
        Family::Paper,
        layered(
            base(colour, Diffuse::OrenNayar { sigma: 0.45 }),
            Some((0.5, Ior::constant(1.45))),
        ),
        None,
    )
}

/// Wall / chalk paint: Oren-Nayar pigment under a rough binder surface.
fn wall_paint(name: &str, colour: Spectrum, sigma: f64, alpha: f64) -> Material {
    mat(
        name,
        Family::WallPaint,
        layered(
            base(colour, Diffuse::OrenNayar { sigma }),
            Some((alpha, Ior::BINDER)),
        ),
        None,
    )
}

fn aluminium_flakes(coverage: f64, alpha: f64) -> Flakes {
    Flakes {
        coverage,
        lobe: Specular {
            alpha,
            fresnel: Fresnel::Conductor(Metal::Aluminium),
        },
    }
}

/// Vinyl wrapping film: a pigmented plastic, optionally with metal flakes.
fn vinyl(name: &str, colour: Spectrum, alpha: f64, flakes: Option<Flakes>) -> Material {
    let mut b = base(colour, Diffuse::Lambert);
    b.flakes = flakes;
    mat(
        name,
        Family::Vinyl,
        layered(b, Some((alpha, Ior::BINDER))),
        None,
    )
}

/// Satin fabric: smooth fibres give a sheen and a soft specular sheen-tinted highlight.
fn satin(name: &str, colour: Spectrum, metal_thread: Option<Metal>) -> Material {
    let mut b = base(colour.clone(), Diffuse::OrenNayar { sigma: 0.5 });
    b.sheen = Some(Sheen {
        weight: 0.5,
        colour: colour.mix(0.5, Spectrum::Constant(0.95)),
        roughness: 0.6,
    });
    b.flakes = metal_thread.map(|m| Flakes {
        coverage: 0.25,
        lobe: Specular {
            alpha: 0.3,
            fresnel: Fresnel::Conductor(m),
        },
    });
    mat(
        name,
        Family::Satin,
        layered(b, Some((0.22, Ior::constant(1.55)))),
        None,
    )
}

/// Car paint: pigment (and optional aluminium flakes) under a smooth clear coat.
fn car_paint(name: &str, colour: Spectrum, flakes: Option<Flakes>) -> Material {
    let mut b = base(colour, Diffuse::Lambert);
    b.flakes = flakes;
    mat(name, Family::CarPaint, layered(b, None), clear_coat(0.025))
}

/// Painted metal (model-kit enamel over metal): pigment, metal showing through as flakes.
fn painted_metal(name: &str, colour: Spectrum, coverage: f64, alpha: f64) -> Material {
    let mut b = base(colour, Diffuse::OrenNayar { sigma: 0.3 });
    b.flakes = Some(aluminium_flakes(coverage, 0.35));
    mat(
        name,
        Family::PaintedMetal,
        layered(b, Some((alpha, Ior::BINDER))),
        None,
    )
}

/// A bare metal: a main lobe and a broader haze lobe.
fn metal(name: &str, m: Metal, alpha: f64) -> Material {
    let lobe = |a: f64| Specular {
        alpha: a,
        fresnel: Fresnel::Conductor(m),
    };
    mat(
        name,
        Family::Metal,
        Body::Metal {
            lobes: vec![(0.85, lobe(alpha)), (0.15, lobe((alpha * 4.0).min(0.8)))],
        },
        None,
    )
}

/// Interference flakes (a TiO2 film on a substrate) over a pigment, under a clear coat.
fn iridescent(
    name: &str,
    colour: Spectrum,
    coverage: f64,
    flake_alpha: f64,
    thickness_nm: f64,
    substrate: Substrate,
) -> Material {
    let mut b = base(colour, Diffuse::Lambert);
    b.flakes = Some(Flakes {
        coverage,
        lobe: Specular {
            alpha: flake_alpha,
            fresnel: Fresnel::ThinFilm {
                film: Ior::TITANIA,
                thickness_nm,
                substrate,
            },
        },
    });
    mat(name, Family::Iridescent, layered(b, None), clear_coat(0.03))
}

/// The 51 canonical materials (seed 0).
fn canonical() -> Vec<Material> {
    let mica = Substrate::Dielectric(Ior::MICA);
    // Colour-change films: a dielectric spacer on an absorbing chromium layer.
    let chromium = Substrate::Conductor(Metal::Chromium);
    let v = vec![
        // Felts (RGL: acrylic_felt_*).
        felt("acrylic_felt_green", c(&cc::GREEN)),
        felt("acrylic_felt_orange", c(&cc::ORANGE)),
        felt("acrylic_felt_pink", pastel(&cc::MAGENTA, 0.55)),
        felt("acrylic_felt_purple", c(&cc::PURPLE)),
        felt("acrylic_felt_white", c(&cc::WHITE_9_5).scaled(0.97)),
        felt("acrylic_felt_yellow", c(&cc::YELLOW)),
        // Papers (RGL: paper_*) and cardboard.
        paper("paper_blue", pastel(&cc::BLUE, 0.6)),
        paper("paper_green", pastel(&cc::GREEN, 0.6)),
        paper("paper_red", c(&cc::RED)),
        // White paper: optical brighteners lift the violet-blue.
        paper(
            "paper_white",
            c(&cc::WHITE_9_5).mix(
                0.5,
                Spectrum::Band {
                    centre_nm: 440.0,
                    width_nm: 40.0,
                    lo: 0.89,
                    hi: 0.98,
                },
            ),
        ),
        paper("paper_yellow", c(&cc::YELLOW)),
        mat(
            "cardboard",
            Family::Cardboard,
            layered(
                base(
                    Spectrum::Edge {
                        edge_nm: 600.0,
                        width_nm: 55.0,
                        lo: 0.08,
                        hi: 0.55,
                    },
                    Diffuse::OrenNayar { sigma: 0.8 },
                ),
                Some((0.6, Ior::constant(1.45))),
            ),
            None,
        ),
        // Wall and chalk paints (RGL: colodur_*, laika_ceiling_paint_*, chm_*).
        wall_paint("colodur_azure_4e", c(&cc::BLUE_SKY).scaled(1.6), 0.3, 0.3),
        wall_paint("colodur_connemara_4c", c(&cc::BLUISH_GREEN), 0.3, 0.3),
        wall_paint("colodur_kalahari_2a", c(&cc::LIGHT_SKIN), 0.3, 0.35),
        wall_paint(
            "colodur_napoli_4f",
            pastel(&cc::ORANGE_YELLOW, 0.5),
            0.3,
            0.3,
        ),
        wall_paint(
            "laika_ceiling_paint_18_gray",
            c(&cc::NEUTRAL_6_5),
            0.6,
            0.55,
        ),
        wall_paint("chm_mint", pastel(&cc::BLUISH_GREEN, 0.55), 0.7, 0.6),
        wall_paint("chm_orange", c(&cc::ORANGE), 0.7, 0.6),
        // Vinyl wrapping films (RGL: cm_* matte, vch_* gloss).
        vinyl("cm_military_green", c(&cc::FOLIAGE).scaled(1.3), 0.35, None),
        vinyl(
            "cm_toxic_green",
            c(&cc::YELLOW_GREEN).mix(0.4, c(&cc::GREEN)),
            0.3,
            None,
        ),
        vinyl("cm_white", c(&cc::WHITE_9_5).scaled(0.95), 0.35, None),
        vinyl(
            "vch_dragon_eye_red",
            c(&cc::RED),
            0.05,
            Some(aluminium_flakes(0.25, 0.2)),
        ),
        vinyl(
            "vch_silk_blue",
            c(&cc::PURPLISH_BLUE),
            0.12,
            Some(aluminium_flakes(0.3, 0.3)),
        ),
        vinyl("vch_ultra_pink", c(&cc::MAGENTA), 0.06, None),
        vinyl("vch_golden_yellow", c(&cc::ORANGE_YELLOW), 0.06, None),
        // Satins (RGL: satin_*).
        satin("satin_blue", c(&cc::BLUE), None),
        satin("satin_gold", c(&cc::ORANGE_YELLOW), Some(Metal::Gold)),
        satin("satin_purple", c(&cc::PURPLE), None),
        satin("satin_rosaline", pastel(&cc::MODERATE_RED, 0.6), None),
        satin("satin_white", c(&cc::WHITE_9_5).scaled(0.95), None),
        // Car paints, solid and metallic.
        car_paint("carpaint_solid_red", c(&cc::RED), None),
        car_paint("carpaint_solid_black", c(&cc::BLACK_2), None),
        car_paint(
            "carpaint_metallic_silver",
            c(&cc::NEUTRAL_6_5),
            Some(aluminium_flakes(0.55, 0.18)),
        ),
        car_paint(
            "carpaint_metallic_blue",
            c(&cc::BLUE),
            Some(aluminium_flakes(0.35, 0.15)),
        ),
        // Painted metals (RGL: ilm_* model paints).
        painted_metal(
            "ilm_l3_37_dark_green",
            c(&cc::GREEN).scaled(0.5),
            0.08,
            0.15,
        ),
        painted_metal("ilm_l3_37_matte", c(&cc::NEUTRAL_5), 0.1, 0.5),
        painted_metal("ilm_l3_37_metallic", c(&cc::NEUTRAL_5), 0.6, 0.2),
        // Bare metals.
        metal("metal_gold", Metal::Gold, 0.06),
        metal("metal_silver", Metal::Silver, 0.08),
        metal("metal_copper", Metal::Copper, 0.12),
        metal("metal_aluminium", Metal::Aluminium, 0.2),
        metal("metal_chromium", Metal::Chromium, 0.03),
        // Iridescent flake paints and colour-change films (RGL: irid_flake_paint*, cc_*,
        // aurora_white).
        iridescent("irid_flake_paint1", c(&cc::BLACK_2), 0.6, 0.2, 180.0, mica),
        iridescent(
            "irid_flake_paint1_fine",
            c(&cc::BLACK_2),
            0.75,
            0.12,
            180.0,
            mica,
        ),
        iridescent("irid_flake_paint2", c(&cc::BLACK_2), 0.6, 0.2, 150.0, mica),
        iridescent(
            "cc_ibiza_sunset",
            c(&cc::RED).scaled(0.4),
            0.5,
            0.1,
            120.0,
            chromium,
        ),
        iridescent(
            "cc_iris_purple_gem",
            c(&cc::PURPLE).scaled(0.15),
            0.5,
            0.1,
            150.0,
            chromium,
        ),
        iridescent(
            "aurora_white",
            c(&cc::WHITE_9_5).scaled(0.9),
            0.25,
            0.15,
            60.0,
            mica,
        ),
        // A leaf: chlorophyll reflectance with the red edge, a waxy cuticle.
        mat(
            "leaf_maple",
            Family::Leaf,
            layered(
                base(
                    c(&cc::FOLIAGE).mix(
                        0.5,
                        Spectrum::Edge {
                            edge_nm: 715.0,
                            width_nm: 12.0,
                            lo: 0.05,
                            hi: 0.5,
                        },
                    ),
                    Diffuse::OrenNayar { sigma: 0.3 },
                ),
                Some((0.3, Ior::constant(1.45))),
            ),
            None,
        ),
        // A near-ideal diffuser.
        mat(
            "spectralon",
            Family::Diffuser,
            layered(base(Spectrum::spectralon(), Diffuse::Lambert), None),
            None,
        ),
    ];
    debug_assert_eq!(v.len(), N_MATERIALS);
    v
}

/// The 51 preset materials for `seed`: seed 0 is the canonical set, any other seed perturbs
/// every material's parameters slightly and deterministically.
pub fn preset(seed: u64) -> Vec<Material> {
    let mut v = canonical();
    if seed != 0 {
        for (i, m) in v.iter_mut().enumerate() {
            let mut rng = ChaCha8Rng::seed_from_u64(
                seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (i as u64).wrapping_add(1),
            );
            perturb(m, &mut rng);
        }
    }
    v
}

/// The preset material named `name` for `seed`, if any.
pub fn preset_material(name: &str, seed: u64) -> Option<Material> {
    preset(seed).into_iter().find(|m| m.name == name)
}

/// A uniform number in [-1, 1).
fn sym(rng: &mut ChaCha8Rng) -> f64 {
    rng.random::<f64>() * 2.0 - 1.0
}

fn perturb_spectrum(s: &mut Spectrum, rng: &mut ChaCha8Rng) {
    let scale = 1.0 + 0.08 * sym(rng);
    let shift = 8.0 * sym(rng);
    let old = std::mem::replace(s, Spectrum::Constant(0.0));
    *s = old.shifted(shift).scaled(scale);
}

fn perturb_specular(s: &mut Specular, rng: &mut ChaCha8Rng) {
    s.alpha = (s.alpha * (0.15 * sym(rng)).exp()).clamp(0.005, 1.0);
    if let Fresnel::ThinFilm { thickness_nm, .. } = &mut s.fresnel {
        *thickness_nm *= 1.0 + 0.05 * sym(rng);
    }
}

fn perturb_interface(i: &mut Interface, rng: &mut ChaCha8Rng) {
    i.alpha = (i.alpha * (0.15 * sym(rng)).exp()).clamp(0.005, 1.0);
}

fn perturb(m: &mut Material, rng: &mut ChaCha8Rng) {
    match &mut m.body {
        Body::Metal { lobes } => {
            for (_, s) in lobes {
                perturb_specular(s, rng);
            }
        }
        Body::Layered { base, interface } => {
            perturb_spectrum(&mut base.albedo, rng);
            if let Diffuse::OrenNayar { sigma } = &mut base.diffuse {
                *sigma = (*sigma + 0.1 * sym(rng)).clamp(0.0, 1.0);
            }
            if let Some(s) = &mut base.sheen {
                s.weight = (s.weight + 0.05 * sym(rng)).clamp(0.0, 1.0);
                s.roughness = (s.roughness * (0.1 * sym(rng)).exp()).clamp(0.05, 1.0);
            }
            if let Some(f) = &mut base.flakes {
                f.coverage = (f.coverage + 0.05 * sym(rng)).clamp(0.0, 1.0);
                perturb_specular(&mut f.lobe, rng);
            }
            if let Some(i) = interface {
                perturb_interface(i, rng);
            }
        }
    }
    if let Some(cc) = &mut m.coat {
        perturb_interface(cc, rng);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn preset_has_51_unique_names_with_family_prefixes() {
        let p = preset(0);
        assert_eq!(p.len(), N_MATERIALS);
        let mut names: Vec<&str> = p.iter().map(|m| m.name.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), N_MATERIALS);
        for fam in [
            Family::Felt,
            Family::Paper,
            Family::Cardboard,
            Family::WallPaint,
            Family::Vinyl,
            Family::Satin,
            Family::CarPaint,
            Family::PaintedMetal,
            Family::Metal,
            Family::Iridescent,
            Family::Leaf,
            Family::Diffuser,
        ] {
            assert!(p.iter().any(|m| m.family == fam), "{fam:?} missing");
        }
        for m in &p {
            assert!(
                m.name
                    .chars()
                    .all(|ch| ch.is_ascii_lowercase() || ch.is_ascii_digit() || ch == '_'),
                "{}",
                m.name
            );
        }
    }

    /// Relative deviations `v / bound` of one perturbed parameter over many materials and seeds:
    /// all within [-1, 1], and both halves reached beyond 1/2 (a uniform draw in [-1, 1) per
    /// value, so hundreds of values miss that only with negligible probability).
    fn assert_spread(what: &str, deviations: &[f64]) {
        assert!(
            deviations.len() >= 40,
            "{what}: {} values",
            deviations.len()
        );
        for v in deviations {
            assert!(v.abs() <= 1.0 + 1e-12, "{what}: {v} of its bound");
        }
        let lo = deviations.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = deviations.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert!(
            lo < -0.5 && hi > 0.5,
            "{what}: from {lo} to {hi} of its bound"
        );
    }

    fn log_ratio(a: f64, b: f64) -> f64 {
        (b / a).ln()
    }

    /// Deviations of a perturbed GGX lobe: roughness and film thickness.
    fn specular_deviations(a: &Specular, b: &Specular, push: &mut impl FnMut(&'static str, f64)) {
        // Clamped to [0.005, 1]: skip values the clamp cut.
        if b.alpha > 0.005 && b.alpha < 1.0 {
            push("alpha", log_ratio(a.alpha, b.alpha) / 0.15);
        }
        if let (
            Fresnel::ThinFilm {
                thickness_nm: t0, ..
            },
            Fresnel::ThinFilm {
                thickness_nm: t1, ..
            },
        ) = (&a.fresnel, &b.fresnel)
        {
            push("thickness", (t1 / t0 - 1.0) / 0.05);
        }
    }

    /// Every seed but 0 perturbs each material within these bounds, both ways: the
    /// albedo scaled by 1 +- 8 % and shifted by +- 8 nm (wrapping the canonical spectrum), GGX
    /// roughness (lobes, flakes, interfaces, coats) by a factor exp(+-0.15), Oren-Nayar sigma
    /// by +- 0.1, sheen weight and flake coverage by +- 0.05, sheen roughness by exp(+-0.1),
    /// film thickness by 1 +- 5 %, each value clamped to its range.
    #[test]
    fn perturbations_stay_within_their_bounds_both_ways() {
        let canonical = preset(0);
        let mut d: std::collections::BTreeMap<&str, Vec<f64>> = Default::default();
        let mut push = |what, v: f64| d.entry(what).or_default().push(v);
        for seed in 1..=12 {
            for (c, m) in canonical.iter().zip(preset(seed)) {
                match (&c.body, &m.body) {
                    (Body::Metal { lobes: a }, Body::Metal { lobes: b }) => {
                        for ((wa, sa), (wb, sb)) in a.iter().zip(b) {
                            assert_eq!(wa, wb, "{}: lobe weights are not perturbed", m.name);
                            specular_deviations(sa, sb, &mut push);
                        }
                    }
                    (
                        Body::Layered {
                            base: a,
                            interface: ia,
                        },
                        Body::Layered {
                            base: b,
                            interface: ib,
                        },
                    ) => {
                        let Spectrum::Scaled(scale, inner) = &b.albedo else {
                            panic!("{}: albedo {:?}", m.name, b.albedo);
                        };
                        let Spectrum::Shifted(shift, original) = inner.as_ref() else {
                            panic!("{}: albedo {:?}", m.name, b.albedo);
                        };
                        assert_eq!(**original, a.albedo, "{}", m.name);
                        push("albedo scale", (scale - 1.0) / 0.08);
                        push("albedo shift", shift / 8.0);
                        if let (Diffuse::OrenNayar { sigma: s0 }, Diffuse::OrenNayar { sigma: s1 }) =
                            (&a.diffuse, &b.diffuse)
                            && *s1 > 0.0
                            && *s1 < 1.0
                        {
                            // Clamped to [0, 1]: skip values the clamp cut.
                            push("sigma", (s1 - s0) / 0.1);
                        }
                        if let (Some(s0), Some(s1)) = (&a.sheen, &b.sheen) {
                            push("sheen weight", (s1.weight - s0.weight) / 0.05);
                            push(
                                "sheen roughness",
                                log_ratio(s0.roughness, s1.roughness) / 0.1,
                            );
                        }
                        if let (Some(f0), Some(f1)) = (&a.flakes, &b.flakes) {
                            push("flake coverage", (f1.coverage - f0.coverage) / 0.05);
                            specular_deviations(&f0.lobe, &f1.lobe, &mut push);
                        }
                        if let (Some(i0), Some(i1)) = (ia, ib) {
                            push("interface alpha", log_ratio(i0.alpha, i1.alpha) / 0.15);
                        }
                    }
                    _ => panic!("{}: the body changed kind", m.name),
                }
                if let (Some(c0), Some(c1)) = (&c.coat, &m.coat) {
                    push("coat alpha", log_ratio(c0.alpha, c1.alpha) / 0.15);
                }
            }
        }
        assert_eq!(d.len(), 10, "{:?}", d.keys().collect::<Vec<_>>());
        for (what, deviations) in &d {
            assert_spread(what, deviations);
        }
    }

    #[test]
    fn seeds_are_deterministic_and_distinct() {
        assert_eq!(preset(0), preset(0));
        assert_eq!(preset(7), preset(7));
        assert_ne!(preset(7), preset(8));
        assert_ne!(preset(0), preset(1));
        // Same names and families whatever the seed.
        let a: Vec<_> = preset(0).into_iter().map(|m| (m.name, m.family)).collect();
        let b: Vec<_> = preset(3).into_iter().map(|m| (m.name, m.family)).collect();
        assert_eq!(a, b);
    }
}
