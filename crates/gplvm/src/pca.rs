//! Principal component analysis from a centred Gram matrix (no second pass over the data).
//!
//! With centred data Y = U Lambda^{1/2} V^T, S = Y Y^T = U Lambda U^T, so the PCA scores of the
//! materials on the leading q components are U_q Lambda_q^{1/2}: an eigen-decomposition of the
//! N x N matrix S is all PCA needs.

use faer::{Mat, MatRef, Side};

use crate::config::InitScaling;
use crate::error::{Error, Result};

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
        let eig = s
            .self_adjoint_eigen(Side::Lower)
            .map_err(|e| Error::InvalidData {
                reason: format!("eigen-decomposition of the Gram matrix failed: {e:?}"),
            })?;
        let vals = eig.S().column_vector();
        let u = eig.U();
        let eigenvalues: Vec<f64> = (0..n).rev().map(|i| vals[i].max(0.0)).collect();
        let mut scores = Mat::<f64>::zeros(n, q);
        for k in 0..q.min(n) {
            let col = n - 1 - k;
            let root = eigenvalues[k].sqrt();
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
}
