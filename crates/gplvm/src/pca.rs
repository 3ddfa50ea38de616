//! Principal component analysis from a centred Gram matrix (no second pass over the data).
//!
//! With centred data Y = U Lambda^{1/2} V^T, S = Y Y^T = U Lambda U^T, so the PCA scores of the
//! materials on the leading q components are U_q Lambda_q^{1/2}: an eigen-decomposition of the
//! N x N matrix S is all PCA needs.

use faer::{Mat, MatRef, Side};

use crate::config::InitScaling;
use crate::error::{Error, Result};

/// Below this largest entry, S is decomposed in units of a power of two near it (the squares
/// of its entries underflow).
const TINY: f64 = 1e-150;

/// PCA of the materials: leading eigenvalues of S (descending) and scores (N x q).
#[derive(Debug, Clone)]
pub struct Pca {
    /// All eigenvalues of S in descending order (clamped at 0).
    pub eigenvalues: Vec<f64>,
    /// Scores of the materials on the leading `q` components, N x q.
    pub scores: Mat<f64>,
}

impl Pca {
    /// PCA with `q` components of the centred Gram matrix `s`.
    ///
    /// Each component's sign is fixed so that its largest-magnitude score is positive, which
    /// makes the result deterministic. Components past N get zero scores; those beyond the rank
    /// of S but below N get scores of the size of S's rounding (~sqrt(eps) of the leading
    /// ones; exactly 0 where the eigenvalue rounds below 0 and is clamped).
    pub fn from_centred_gram(s: MatRef<'_, f64>, q: usize) -> Result<Self> {
        let n = s.nrows();
        if n == 0 || s.ncols() != n {
            return Err(Error::InvalidData {
                reason: format!(
                    "PCA needs a square, non-empty Gram matrix, got {}x{}",
                    n,
                    s.ncols()
                ),
            });
        }
        // faer's eigen-decomposition does not converge on entries near the subnormal range
        // (unscaled data near 1e-155, S ~ 1e-309): S is then decomposed in units of 4^k, a
        // power of two near its largest entry (exact, and sqrt(4^k) = 2^k is too).
        let amax = (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .fold(0.0f64, |m, (i, j)| m.max(s[(i, j)].abs()));
        // (2^k and 2^-k are normal numbers; 4^k and 4^-k need not be.)
        let root_unit = if amax > 0.0 && amax < TINY {
            2f64.powi((amax.log2() / 2.0).ceil() as i32)
        } else {
            1.0
        };
        let scaled;
        let s = if root_unit == 1.0 {
            s
        } else {
            let inv = 1.0 / root_unit;
            scaled = Mat::from_fn(n, n, |i, j| s[(i, j)] * inv * inv);
            scaled.as_ref()
        };
        let eig = s
            .self_adjoint_eigen(Side::Lower)
            .map_err(|e| Error::InvalidData {
                reason: format!("eigen-decomposition of the Gram matrix failed: {e:?}"),
            })?;
        let vals = eig.S().column_vector();
        let u = eig.U();
        let scaled_eigenvalues: Vec<f64> = (0..n).rev().map(|i| vals[i].max(0.0)).collect();
        let eigenvalues: Vec<f64> = scaled_eigenvalues
            .iter()
            .map(|v| v * root_unit * root_unit)
            .collect();
        let mut scores = Mat::<f64>::zeros(n, q);
        for k in 0..q.min(n) {
            let col = n - 1 - k;
            let root = scaled_eigenvalues[k].sqrt() * root_unit;
            let mut biggest = 0.0f64;
            for i in 0..n {
                if u[(i, col)].abs() > biggest.abs() {
                    biggest = u[(i, col)];
                }
            }
            let sign = if biggest < 0.0 { -1.0 } else { 1.0 };
            for i in 0..n {
                scores[(i, k)] = sign * u[(i, col)] * root;
            }
        }
        Ok(Self {
            eigenvalues,
            scores,
        })
    }

    /// Share of the total variance carried by the leading `q` components.
    pub fn explained(&self, q: usize) -> f64 {
        let total: f64 = self.eigenvalues.iter().sum();
        if total > 0.0 {
            self.eigenvalues.iter().take(q).sum::<f64>() / total
        } else {
            0.0
        }
    }

    /// The scores scaled for use as a latent start.
    pub fn latent_start(&self, scaling: InitScaling) -> Mat<f64> {
        let (n, q) = (self.scores.nrows(), self.scores.ncols());
        let std = |k: usize| {
            let mean = (0..n).map(|i| self.scores[(i, k)]).sum::<f64>() / n as f64;
            ((0..n)
                .map(|i| (self.scores[(i, k)] - mean).powi(2))
                .sum::<f64>()
                / n as f64)
                .sqrt()
        };
        let factors: Vec<f64> = match scaling {
            InitScaling::None => vec![1.0; q],
            InitScaling::Isotropic | InitScaling::Likelihood => {
                let s0 = if q > 0 { std(0) } else { 0.0 };
                vec![if s0 > 0.0 { 1.0 / s0 } else { 1.0 }; q]
            }
            InitScaling::PerAxis => (0..q)
                .map(|k| {
                    let s = std(k);
                    if s > 0.0 { 1.0 / s } else { 1.0 }
                })
                .collect(),
        };
        Mat::from_fn(n, q, |i, k| self.scores[(i, k)] * factors[k])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pca_scores_reproduce_the_gram_matrix_of_rank_two_data() {
        // Centred rank-2 data: S = Y Y^T must equal scores scores^T.
        let y = Mat::from_fn(6, 5, |i, j| {
            let a = i as f64 - 2.5;
            let b = ((i * 7) % 5) as f64 - 2.0;
            a * (j as f64 + 1.0) + b * ((j * j) as f64 - 3.0)
        });
        // Centre the rows' mean (over materials).
        let mut yc = y.clone();
        for j in 0..5 {
            let m = (0..6).map(|i| y[(i, j)]).sum::<f64>() / 6.0;
            for i in 0..6 {
                yc[(i, j)] -= m;
            }
        }
        let s = &yc * yc.transpose();
        let pca = Pca::from_centred_gram(s.as_ref(), 2).unwrap();
        let back = &pca.scores * pca.scores.transpose();
        for i in 0..6 {
            for j in 0..6 {
                assert!((back[(i, j)] - s[(i, j)]).abs() < 1e-9 * s[(0, 0)].abs().max(1.0));
            }
        }
        assert!((pca.explained(2) - 1.0).abs() < 1e-12);
        assert!(pca.eigenvalues[0] >= pca.eigenvalues[1]);
        let x = pca.latent_start(InitScaling::Isotropic);
        let std0 = (0..6).map(|i| x[(i, 0)].powi(2)).sum::<f64>() / 6.0;
        assert!((std0.sqrt() - 1.0).abs() < 1e-12);
    }

    /// A Gram matrix near the subnormal range (unscaled data near 1e-155) has the PCA of the
    /// same data at unit scale, scaled (faer's eigen-decomposition did not converge on it:
    /// "NoConvergence", and an unscaled fit of such data failed).
    #[test]
    fn pca_of_a_tiny_gram_matrix_is_the_scaled_pca() {
        let s = Mat::from_fn(5, 5, |i, j| {
            let (a, b) = (i as f64 - 2.0, j as f64 - 2.0);
            a * b + if i == j { 0.5 - 0.1 * i as f64 } else { 0.0 }
        });
        let base = Pca::from_centred_gram(s.as_ref(), 2).unwrap();
        for c in [1e-155, 1e-150, 1e-120] {
            let tiny = Mat::from_fn(5, 5, |i, j| s[(i, j)] * c * c);
            let pca = Pca::from_centred_gram(tiny.as_ref(), 2).unwrap();
            for (a, b) in pca.eigenvalues.iter().zip(&base.eigenvalues) {
                assert!(
                    (a / (c * c) - b).abs() <= 1e-9 * base.eigenvalues[0],
                    "{c:e}"
                );
            }
            for i in 0..5 {
                for k in 0..2 {
                    let want = base.scores[(i, k)];
                    assert!((pca.scores[(i, k)] / c - want).abs() <= 1e-9, "{c:e}");
                }
            }
        }
    }

    /// Identical materials give a zero centred Gram matrix: zero eigenvalues, zero scores and
    /// nothing explained, all finite (the tiny-matrix rescaling must not take log2(0)).
    #[test]
    fn pca_of_a_zero_gram_matrix_is_zero() {
        let pca = Pca::from_centred_gram(Mat::<f64>::zeros(4, 4).as_ref(), 3).unwrap();
        assert_eq!(pca.eigenvalues, vec![0.0; 4]);
        assert_eq!((pca.scores.nrows(), pca.scores.ncols()), (4, 3));
        for i in 0..4 {
            for k in 0..3 {
                assert_eq!(pca.scores[(i, k)], 0.0);
            }
        }
        assert_eq!(pca.explained(2), 0.0);
        for scaling in [InitScaling::PerAxis, InitScaling::Isotropic] {
            let x = pca.latent_start(scaling);
            assert!((0..4).all(|i| (0..3).all(|k| x[(i, k)] == 0.0)));
        }
    }

    /// The latent starts' scalings, on scores given directly (with a non-zero mean, so the
    /// standard deviation must be taken about it): `None` keeps them, `Isotropic` (and
    /// `Likelihood`, whose search starts there) divides both axes by the first one's standard
    /// deviation, `PerAxis` each axis by its own; a constant axis is left as it is.
    #[test]
    fn latent_start_scalings_standardise_as_documented() {
        // Axis 0: 1, 3, 5, 7 (mean 4, std sqrt(5)); axis 1: 10, 10, 14, 14 (std 2); axis 2: 3s.
        let scores = Mat::from_fn(4, 3, |i, k| match k {
            0 => 1.0 + 2.0 * i as f64,
            1 => 10.0 + 4.0 * (i / 2) as f64,
            _ => 3.0,
        });
        let pca = Pca {
            eigenvalues: vec![3.0, 2.0, 1.0, 0.0],
            scores: scores.clone(),
        };
        let factors = |scaling| {
            let x = pca.latent_start(scaling);
            (0..3)
                .map(|k| {
                    let f = x[(0, k)] / scores[(0, k)];
                    for i in 1..4 {
                        assert!((x[(i, k)] - f * scores[(i, k)]).abs() < 1e-14);
                    }
                    f
                })
                .collect::<Vec<f64>>()
        };
        let close = |got: Vec<f64>, want: [f64; 3]| {
            for (g, w) in got.iter().zip(want) {
                assert!((g - w).abs() < 1e-14, "{got:?} against {want:?}");
            }
        };
        let s0 = 5f64.sqrt();
        close(factors(InitScaling::None), [1.0; 3]);
        close(factors(InitScaling::Isotropic), [1.0 / s0; 3]);
        close(factors(InitScaling::Likelihood), [1.0 / s0; 3]);
        close(factors(InitScaling::PerAxis), [1.0 / s0, 0.5, 1.0]);
        // No components (q = 0): an empty start under every scaling.
        let none = Pca::from_centred_gram(Mat::<f64>::identity(4, 4).as_ref(), 0).unwrap();
        for scaling in [InitScaling::Isotropic, InitScaling::PerAxis] {
            let x = none.latent_start(scaling);
            assert_eq!((x.nrows(), x.ncols()), (4, 0));
        }
    }

    /// Each component's sign is fixed as documented: its largest-magnitude score is positive,
    /// whatever sign the eigen-solver returned (checked over matrices whose components come out
    /// of the solver with both signs).
    #[test]
    fn pca_components_have_a_positive_largest_score() {
        for seed in 0..8u64 {
            let y = Mat::from_fn(7, 4, |i, j| {
                let h = (i as u64 * 31 + j as u64 * 17 + seed * 101) % 23;
                h as f64 - 11.0
            });
            let s = &y * y.transpose();
            let pca = Pca::from_centred_gram(s.as_ref(), 3).unwrap();
            for k in 0..3 {
                let largest = (0..7)
                    .map(|i| pca.scores[(i, k)])
                    .fold(0.0f64, |m, v| if v.abs() > m.abs() { v } else { m });
                assert!(largest > 0.0, "seed {seed}, component {k}: {largest}");
            }
        }
    }

    /// A non-square or empty matrix is refused with an error that says what it got.
    #[test]
    fn pca_refuses_a_non_square_or_empty_gram_matrix() {
        for (r, c) in [(3, 2), (2, 3), (0, 0), (0, 3)] {
            let err = Pca::from_centred_gram(Mat::<f64>::zeros(r, c).as_ref(), 1).unwrap_err();
            let msg = err.to_string();
            assert!(msg.contains(&format!("got {r}x{c}")), "{msg}");
        }
    }
}
