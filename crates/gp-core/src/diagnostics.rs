//! Length-scale diagnostic (the paper's Eq. 15 — see the caveat below).
//!
//! **Caveat (interpretation).** The text of Eq. 15 of Soler, Subr & Nowrouzezahrai (EG 2018 /
//! INRIA RR-9069) could not be retrieved while writing this crate. This module implements a
//! documented interpretation with the same purpose: the length-scale must be commensurate with
//! the spacing of the latent points, so that `K` is well conditioned *and* predictions between
//! training points are not degenerate. Replace it with the exact equation once checked.
//!
//! Let `r_ij = sqrt(sum_k (x_ik - x_jk)^2 / l_k^2)` be scaled distances, `r_min = min_{i!=j} r_ij`
//! (closest pair) and `r_nn = max_i min_{j!=i} r_ij` (the most isolated point's nearest
//! neighbour). With `rho(r) = exp(-r^2 / 2)`:
//!
//! 1. **Conditioning (upper bound on l).** The closest pair's 2x2 principal submatrix of `K`
//!    has condition number `c2 = (s^2 (1 + rho) + mu) / (s^2 (1 - rho) + mu)`, `rho = rho(r_min)`.
//!    By eigenvalue interlacing `kappa_2(K) >= c2`, so `c2 <= kappa_max` is *necessary* for a
//!    well-conditioned `K`. It holds iff `rho(r_min) <= rho_max = (kappa_max - 1)(s^2 + mu) /
//!    ((kappa_max + 1) s^2)`, i.e. `l <= d_min / sqrt(-2 ln rho_max)` (no bound if `rho_max >= 1`).
//! 2. **Non-degeneracy (lower bound on l).** Every training point must correlate with its nearest
//!    neighbour at least `rho_min`: `rho(r_nn) >= rho_min`, i.e. `l >= d_nn / sqrt(-2 ln rho_min)`.
//!    Otherwise isolated points have weights `~ 0` away from themselves and the (smooth)
//!    predictor collapses to the mean between them.
//!
//! Both bounds are reported as factors `c` by which *all* length-scales may be multiplied
//! (`l_k -> c l_k`); for an isotropic kernel `c l` is the admissible length-scale.

use crate::error::{GpError, Result};
use crate::kernel::KernelParams;
use faer::MatRef;

/// Thresholds of [`length_scale_condition`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LengthScaleThresholds {
    /// Largest acceptable condition number of the closest pair's 2x2 block (default `1e8`).
    pub kappa_max: f64,
    /// Smallest acceptable correlation of a point with its nearest neighbour (default `1e-3`).
    pub rho_min: f64,
}

impl Default for LengthScaleThresholds {
    fn default() -> Self {
        LengthScaleThresholds {
            kappa_max: 1e8,
            rho_min: 1e-3,
        }
    }
}

/// Result of [`length_scale_condition`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LengthScaleDiagnostic {
    /// Smallest scaled pairwise distance `r_min` (0 for duplicate points; `inf` if `N = 1`).
    pub r_min: f64,
    /// Largest scaled nearest-neighbour distance `r_nn` (`inf` if `N = 1`).
    pub r_nn_max: f64,
    /// Condition number `c2` of the closest pair's 2x2 block of `K` (a lower bound on `kappa_2(K)`).
    pub pair_condition: f64,
    /// Correlation `rho(r_nn)` of the most isolated point with its nearest neighbour.
    pub isolated_correlation: f64,
    /// Condition 1 holds (`c2 <= kappa_max`).
    pub well_conditioned: bool,
    /// Condition 2 holds (`rho(r_nn) >= rho_min`).
    pub non_degenerate: bool,
    /// Smallest admissible length-scale multiplier (condition 2).
    pub scale_min: f64,
    /// Largest admissible length-scale multiplier (condition 1; `inf` if unbounded, 0 if no
    /// length-scale helps, e.g. duplicate points with `2 s^2 / mu > kappa_max`).
    pub scale_max: f64,
}

impl LengthScaleDiagnostic {
    /// Both conditions hold.
    pub fn satisfied(&self) -> bool {
        self.well_conditioned && self.non_degenerate
    }
}

/// Evaluates the length-scale conditions (module docs) for latent points `X` (`N x q`).
/// `O(N^2 q)`.
pub fn length_scale_condition(
    x: MatRef<'_, f64>,
    params: &KernelParams,
    thresholds: LengthScaleThresholds,
) -> Result<LengthScaleDiagnostic> {
    let rows = params.rows_of(x, "latent points X")?;
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(ok(thresholds.kappa_max) && thresholds.kappa_max > 1.0) {
        return Err(GpError::InvalidHyperparameter {
            name: "kappa_max (must be > 1)".into(),
            value: thresholds.kappa_max,
        });
    }
    if !(ok(thresholds.rho_min) && thresholds.rho_min < 1.0) {
        return Err(GpError::InvalidHyperparameter {
            name: "rho_min (must be in (0, 1))".into(),
            value: thresholds.rho_min,
        });
    }
    let n = rows.len();
    let mut nn = vec![f64::INFINITY; n];
    for i in 0..n {
        for j in (i + 1)..n {
            let r2 = params.scaled_sq_dist(&rows[i], &rows[j]);
            nn[i] = nn[i].min(r2);
            nn[j] = nn[j].min(r2);
        }
    }
    let r_min = nn.iter().cloned().fold(f64::INFINITY, f64::min).sqrt();
    let r_nn_max = nn.iter().cloned().fold(0.0, f64::max).sqrt();
    let (s2, mu) = (params.signal_variance(), params.noise());
    let rho = |r: f64| (-0.5 * r * r).exp();
    let rho_pair = rho(r_min);
    let pair_condition = (s2 * (1.0 + rho_pair) + mu) / (s2 * (1.0 - rho_pair) + mu);
    let isolated_correlation = if n > 1 { rho(r_nn_max) } else { 1.0 };
    let k = thresholds.kappa_max;
    let rho_max = (k - 1.0) * (s2 + mu) / ((k + 1.0) * s2);
    let scale_max = if rho_max >= 1.0 || n < 2 {
        f64::INFINITY
    } else if r_min == 0.0 {
        0.0
    } else {
        r_min / (-2.0 * rho_max.ln()).sqrt()
    };
    let scale_min = if n < 2 {
        0.0
    } else {
        r_nn_max / (-2.0 * thresholds.rho_min.ln()).sqrt()
    };
    Ok(LengthScaleDiagnostic {
        r_min,
        r_nn_max,
        pair_condition,
        isolated_correlation,
        well_conditioned: pair_condition <= k,
        non_degenerate: isolated_correlation >= thresholds.rho_min,
        scale_min,
        scale_max,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cholesky::CholeskyFactor;
    use faer::{Mat, Par};

    /// ARD length-scales `l` times `c`, with the given signal variance and noise.
    fn ard(s2: f64, l: &[f64], c: f64, mu: f64) -> KernelParams {
        let l = l.iter().map(|v| v * c).collect();
        KernelParams::new(s2, crate::kernel::LengthScale::Ard(l), mu).unwrap()
    }

    /// Every field against its formula (module docs) at a signal variance and noise away from
    /// 1 and 0, with ARD distances; the reported multipliers put the closest pair's condition
    /// exactly at `kappa_max` and the most isolated point's correlation exactly at `rho_min`.
    #[test]
    fn fields_follow_their_formulas_and_bounds_are_exact() {
        // Three points; with l = (2, 0.5) the scaled distances are 0-1: 1.5 (dx 3), 0-2: 1.0
        // (dy 0.5) and 1-2: sqrt(2.25 + 1) = sqrt(3.25).
        let x = Mat::from_fn(3, 2, |i, j| [[0.0, 0.0], [3.0, 0.0], [0.0, 0.5]][i][j]);
        let (s2, mu, l) = (2.0, 0.1, [2.0, 0.5]);
        let th = LengthScaleThresholds {
            kappa_max: 10.0,
            rho_min: 0.4,
        };
        let d = length_scale_condition(x.as_ref(), &ard(s2, &l, 1.0, mu), th).unwrap();
        let tol = 1e-14;
        assert!((d.r_min - 1.0).abs() < tol, "{d:?}");
        assert!((d.r_nn_max - 1.5).abs() < tol, "{d:?}");
        let rho_pair = (-0.5f64).exp();
        let c2 = (s2 * (1.0 + rho_pair) + mu) / (s2 * (1.0 - rho_pair) + mu);
        assert!((d.pair_condition - c2).abs() < tol * c2, "{d:?}");
        assert!(
            (d.isolated_correlation - (-1.125f64).exp()).abs() < tol,
            "{d:?}"
        );
        // c2 = 3.27 <= 10; rho(1.5) = 0.325 < 0.4.
        assert!(
            d.well_conditioned && !d.non_degenerate && !d.satisfied(),
            "{d:?}"
        );
        // rho_max = 9 * 2.1 / (11 * 2): l may grow by 1 / sqrt(-2 ln rho_max).
        let rho_max = 9.0 * 2.1 / 22.0;
        assert!((d.scale_max - 1.0 / (-2.0 * f64::ln(rho_max)).sqrt()).abs() < tol);
        assert!((d.scale_min - 1.5 / (-2.0 * f64::ln(0.4)).sqrt()).abs() < tol);
        let at_max = length_scale_condition(x.as_ref(), &ard(s2, &l, d.scale_max, mu), th).unwrap();
        assert!((at_max.pair_condition - 10.0).abs() < 1e-12, "{at_max:?}");
        let at_min = length_scale_condition(x.as_ref(), &ard(s2, &l, d.scale_min, mu), th).unwrap();
        assert!(
            (at_min.isolated_correlation - 0.4).abs() < 1e-14,
            "{at_min:?}"
        );
        // Between the two, both conditions hold.
        let mid = 0.5 * (d.scale_min + d.scale_max);
        let both = length_scale_condition(x.as_ref(), &ard(s2, &l, mid, mu), th).unwrap();
        assert!(both.well_conditioned && both.non_degenerate && both.satisfied());
        // Two points: both bounds are finite (the closest pair is the only pair).
        let two = length_scale_condition(x.subrows(0, 2), &ard(s2, &l, 1.0, mu), th).unwrap();
        assert!((two.r_min - 1.5).abs() < tol && (two.r_nn_max - 1.5).abs() < tol);
        assert!(two.scale_max.is_finite() && two.scale_min > 0.0, "{two:?}");
    }

    /// One point has no pair: no distance, nothing to condition, no bound.
    #[test]
    fn a_single_point_has_no_bounds() {
        let x = Mat::from_fn(1, 2, |_, j| j as f64);
        let th = LengthScaleThresholds::default();
        let d = length_scale_condition(x.as_ref(), &ard(2.0, &[1.0, 3.0], 1.0, 0.1), th).unwrap();
        assert_eq!(d.r_min, f64::INFINITY);
        assert_eq!(d.r_nn_max, f64::INFINITY);
        assert_eq!(d.pair_condition, 1.0);
        assert_eq!(d.isolated_correlation, 1.0);
        assert_eq!((d.scale_min, d.scale_max), (0.0, f64::INFINITY));
        assert!(d.well_conditioned && d.non_degenerate && d.satisfied());
    }

    /// `satisfied` needs both conditions.
    #[test]
    fn satisfied_needs_both_conditions() {
        let d = LengthScaleDiagnostic {
            r_min: 1.0,
            r_nn_max: 1.0,
            pair_condition: 2.0,
            isolated_correlation: 0.5,
            well_conditioned: true,
            non_degenerate: true,
            scale_min: 0.5,
            scale_max: 2.0,
        };
        assert!(d.satisfied());
        for (well_conditioned, non_degenerate) in [(true, false), (false, true), (false, false)] {
            let d = LengthScaleDiagnostic {
                well_conditioned,
                non_degenerate,
                ..d
            };
            assert!(!d.satisfied(), "{d:?}");
        }
    }

    /// Thresholds outside `kappa_max > 1` and `0 < rho_min < 1` (or not finite) are errors
    /// naming the threshold; the nearest valid values are accepted.
    #[test]
    fn thresholds_outside_their_ranges_are_errors() {
        let x = Mat::from_fn(3, 1, |i, _| i as f64);
        let p = KernelParams::isotropic(1.0, 1.0, 0.1).unwrap();
        let check = |kappa_max: f64, rho_min: f64| {
            length_scale_condition(x.as_ref(), &p, LengthScaleThresholds { kappa_max, rho_min })
        };
        for kappa_max in [1.0, 0.5, -2.0, f64::INFINITY, f64::NAN] {
            match check(kappa_max, 1e-3) {
                Err(GpError::InvalidHyperparameter { name, .. }) => {
                    assert!(name.starts_with("kappa_max"), "{name}")
                }
                other => panic!("kappa_max {kappa_max}: {other:?}"),
            }
        }
        for rho_min in [0.0, -0.5, 1.0, 2.0, f64::INFINITY, f64::NAN] {
            match check(1e8, rho_min) {
                Err(GpError::InvalidHyperparameter { name, .. }) => {
                    assert!(name.starts_with("rho_min"), "{name}")
                }
                other => panic!("rho_min {rho_min}: {other:?}"),
            }
        }
        let above_one = 1.0 + f64::EPSILON;
        assert!(check(above_one, f64::MIN_POSITIVE).is_ok());
        assert!(check(above_one, 1.0 - f64::EPSILON / 2.0).is_ok());
    }

    #[test]
    fn bounds_are_consistent_with_conditions() {
        // Points on a line with spacing 0.5; isolated point at distance 4 from the rest.
        let x = Mat::from_fn(5, 1, |i, _| if i < 4 { 0.5 * i as f64 } else { 5.5 });
        let th = LengthScaleThresholds::default();
        let p = KernelParams::isotropic(1.0, 1.0, 1e-4).unwrap();
        let d = length_scale_condition(x.as_ref(), &p, th).unwrap();
        assert!((d.r_min - 0.5).abs() < 1e-15);
        assert!((d.r_nn_max - 4.0).abs() < 1e-15);
        assert!(!d.non_degenerate); // rho(4) = e^-8 < 1e-3
        // Rescaling l by the reported bounds flips the conditions as predicted.
        for (c, expect_nd) in [(d.scale_min * 1.01, true), (d.scale_min * 0.99, false)] {
            let p2 = KernelParams::isotropic(1.0, c, 1e-4).unwrap();
            let d2 = length_scale_condition(x.as_ref(), &p2, th).unwrap();
            assert_eq!(d2.non_degenerate, expect_nd);
        }
        // With mu = 1e-4 the pair condition is at most 2e4: no upper bound for kappa_max = 1e8.
        assert_eq!(d.scale_max, f64::INFINITY);
        assert!(d.well_conditioned);
        let th3 = LengthScaleThresholds {
            kappa_max: 1e3,
            rho_min: 1e-3,
        };
        let d = length_scale_condition(x.as_ref(), &p, th3).unwrap();
        assert!(d.scale_max.is_finite() && d.scale_max > 0.0);
        for (c, expect_wc) in [(d.scale_max * 0.99, true), (d.scale_max * 1.01, false)] {
            let p2 = KernelParams::isotropic(1.0, c, 1e-4).unwrap();
            let d2 = length_scale_condition(x.as_ref(), &p2, th3).unwrap();
            assert_eq!(d2.well_conditioned, expect_wc);
            // The pair bound is a lower bound on the true condition number.
            let k = p2.kernel_matrix(x.as_ref()).unwrap();
            let ev = k.self_adjoint_eigenvalues(faer::Side::Lower).unwrap();
            assert!(ev[4] / ev[0] >= d2.pair_condition * (1.0 - 1e-6));
            let _ = CholeskyFactor::new(k.as_ref(), Par::Seq).unwrap();
        }
        // Duplicates: no length-scale makes the pair well conditioned when 2 s^2/mu > kappa_max.
        let xd = Mat::from_fn(3, 2, |i, j| if i == 2 { 0.0 } else { (i + j) as f64 });
        let xd = Mat::from_fn(4, 2, |i, j| if i == 3 { xd[(0, j)] } else { xd[(i, j)] });
        let pd = KernelParams::isotropic(1.0, 1.0, 1e-10).unwrap();
        let dd = length_scale_condition(xd.as_ref(), &pd, th).unwrap();
        assert_eq!(dd.r_min, 0.0);
        assert_eq!(dd.scale_max, 0.0);
        assert!(!dd.well_conditioned);
        assert!(
            length_scale_condition(
                x.as_ref(),
                &p,
                LengthScaleThresholds {
                    kappa_max: 0.5,
                    rho_min: 1e-3
                }
            )
            .is_err()
        );
    }
}
