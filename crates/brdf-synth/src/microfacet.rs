//! The GGX (Trowbridge-Reitz) microfacet distribution with Smith height-correlated
//! masking-shadowing, and the Charlie sheen distribution.

use std::f64::consts::PI;

/// GGX normal distribution D(h) for `cos_h = h . n` and roughness `alpha` (> 0).
pub fn ggx_d(cos_h: f64, alpha: f64) -> f64 {
    if cos_h <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let c2 = cos_h * cos_h;
    let t = c2 * (a2 - 1.0) + 1.0;
    a2 / (PI * t * t)
}

/// Smith's Lambda for GGX at direction cosine `mu`.
pub fn ggx_lambda(mu: f64, alpha: f64) -> f64 {
    if mu <= 0.0 {
        return f64::INFINITY;
    }
    let mu2 = mu * mu;
    let tan2 = (1.0 - mu2).max(0.0) / mu2;
    0.5 * ((1.0 + alpha * alpha * tan2).sqrt() - 1.0)
}

/// Height-correlated Smith masking-shadowing G2 = 1 / (1 + Lambda(wi) + Lambda(wo)).
pub fn smith_g2(mu_i: f64, mu_o: f64, alpha: f64) -> f64 {
    if mu_i <= 0.0 || mu_o <= 0.0 {
        return 0.0;
    }
    1.0 / (1.0 + ggx_lambda(mu_i, alpha) + ggx_lambda(mu_o, alpha))
}

/// The Fresnel-free part of a GGX lobe, D G2 / (4 mu_i mu_o) (1/sr); multiply by F(wi . h).
pub fn ggx_lobe(cos_h: f64, mu_i: f64, mu_o: f64, alpha: f64) -> f64 {
    if mu_i <= 0.0 || mu_o <= 0.0 {
        return 0.0;
    }
    ggx_d(cos_h, alpha) * smith_g2(mu_i, mu_o, alpha) / (4.0 * mu_i * mu_o)
}

/// The "Charlie" sheen distribution of Estevez & Kulla 2017,
/// `(2 + 1/r) sin(theta_h)^(1/r) / (2 pi)`, for roughness `r` in (0, 1].
pub fn charlie_d(cos_h: f64, r: f64) -> f64 {
    let inv_r = 1.0 / r.max(1e-3);
    let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
    (2.0 + inv_r) * sin_h.powf(inv_r) / (2.0 * PI)
}

/// Neubelt & Pettineo's sheen visibility 1 / (4 (mu_i + mu_o - mu_i mu_o)) (reciprocal).
pub fn sheen_visibility(mu_i: f64, mu_o: f64) -> f64 {
    1.0 / (4.0 * (mu_i + mu_o - mu_i * mu_o)).max(1e-12)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Integral of D(h) cos(theta_h) over the hemisphere is 1 (the projected area).
    #[test]
    fn ggx_is_normalised() {
        for alpha in [0.03, 0.1, 0.3, 0.7, 1.0] {
            let n = 20_000;
            let mut sum = 0.0;
            for i in 0..n {
                // theta = u^2 pi/2 concentrates samples near the normal.
                let u = (i as f64 + 0.5) / n as f64;
                let th = u * u * PI / 2.0;
                let dth = PI * u / n as f64;
                sum += ggx_d(th.cos(), alpha) * th.cos() * th.sin() * dth * 2.0 * PI;
            }
            assert!((sum - 1.0).abs() < 1e-3, "alpha {alpha}: {sum}");
        }
    }

    #[test]
    fn smith_limits_and_symmetry() {
        assert!((smith_g2(1.0, 1.0, 0.5) - 1.0).abs() < 1e-12);
        assert!(smith_g2(0.05, 0.9, 0.5) < 0.3);
        assert_eq!(smith_g2(0.3, 0.8, 0.4), smith_g2(0.8, 0.3, 0.4));
        assert_eq!(smith_g2(0.0, 0.8, 0.4), 0.0);
    }

    #[test]
    fn charlie_is_normalised() {
        for r in [0.2, 0.5, 1.0] {
            let n = 20_000;
            let mut sum = 0.0;
            for i in 0..n {
                let th = (i as f64 + 0.5) / n as f64 * PI / 2.0;
                sum +=
                    charlie_d(th.cos(), r) * th.cos() * th.sin() * (PI / 2.0 / n as f64) * 2.0 * PI;
            }
            assert!((sum - 1.0).abs() < 1e-3, "r {r}: {sum}");
        }
    }

    /// The sheen terms' values against their formulas: Charlie's `(2 + 1/r) sin^(1/r) / (2 pi)`
    /// (its normalisation holds for any exponent, so it does not pin 1/r), roughness clamped
    /// at 1e-3; the visibility `1 / (4 (mu_i + mu_o - mu_i mu_o))`, symmetric.
    #[test]
    fn charlie_and_sheen_visibility_values() {
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-14 * b.abs();
        // cos_h 0.6: sin_h 0.8.
        for (r, expected) in [
            (1.0, 3.0 * 0.8),
            (0.5, 4.0 * 0.8f64.powi(2)),
            (0.25, 6.0 * 0.8f64.powi(4)),
        ] {
            let d = charlie_d(0.6, r);
            assert!(close(d, expected / (2.0 * PI)), "r {r}: {d}");
        }
        assert!(close(charlie_d(0.0, 0.0), 1002.0 / (2.0 * PI)));
        assert_eq!(charlie_d(1.0, 0.5), 0.0);

        for (mu_i, mu_o, expected) in [
            (1.0, 1.0, 0.25),
            (0.5, 0.5, 1.0 / 3.0),
            (0.2, 0.9, 1.0 / (4.0 * (1.1 - 0.18))),
        ] {
            let v = sheen_visibility(mu_i, mu_o);
            assert!(close(v, expected), "{mu_i} {mu_o}: {v}");
            assert_eq!(v, sheen_visibility(mu_o, mu_i));
        }
        assert_eq!(sheen_visibility(0.0, 0.0), 1e12);
    }

    /// Each term is 0 for a direction at or below the horizon, not NaN (0 / 0) or negative.
    #[test]
    fn lobes_vanish_at_and_below_the_horizon() {
        for (mu_i, mu_o) in [(0.0, 0.5), (0.5, 0.0), (-0.2, 0.5), (0.5, -0.2), (0.0, 0.0)] {
            assert_eq!(ggx_lobe(0.9, mu_i, mu_o, 0.3).to_bits(), 0, "{mu_i} {mu_o}");
            assert_eq!(smith_g2(mu_i, mu_o, 0.3).to_bits(), 0, "{mu_i} {mu_o}");
        }
        assert_eq!(ggx_d(0.0, 0.3), 0.0);
        assert_eq!(ggx_d(-0.5, 0.3), 0.0);
        assert_eq!(ggx_lambda(0.0, 0.3), f64::INFINITY);
        assert!(ggx_lobe(0.9, 0.5, 0.5, 0.3) > 0.0);
    }
}
