//! Gram-matrix helpers: `G = Y Y^T`, centring `S = C G C` with `C = I - 1 1^T / N`, and subsets.
//!
//! Keeping the *uncentred* Gram `G` of the transformed data is enough for centring, for any
//! subset of materials (leave-one-out) and for errors of linear predictors (DESIGN.md section 3).

use crate::error::{GpError, Result, check_finite, check_finite_result, check_symmetric};
use faer::{Mat, MatRef, Par};

/// `G = Y Y^T` (`N x N`) from dense data `Y` (`N x D`, rows are materials). Errors on
/// non-finite data, and on products that overflow ([`GpError::NonFiniteResult`]).
pub fn gram_from_data(y: MatRef<'_, f64>, par: Par) -> Result<Mat<f64>> {
    if y.nrows() == 0 {
        return Err(GpError::Empty { what: "data Y" });
    }
    check_finite(y, "data Y")?;
    let n = y.nrows();
    let mut g = Mat::<f64>::zeros(n, n);
    faer::linalg::matmul::matmul(g.as_mut(), faer::Accum::Replace, y, y.transpose(), 1.0, par);
    symmetrise(&mut g);
    check_finite_result(g.as_ref(), "Gram matrix Y Y^T")?;
    Ok(g)
}

/// Centres a Gram matrix: `S = C G C`, `C = I - 1 1^T / N`, i.e.
/// `S_ij = G_ij - r_i - r_j + t` with row means `r` and grand mean `t`. Equals the Gram of the
/// column-centred data `Y - 1 m^T` (`m` = mean row). `G` must be square, symmetric and finite;
/// [`GpError::NonFiniteResult`] when the row sums overflow (entries near `f64::MAX / N`).
pub fn centre_gram(g: MatRef<'_, f64>) -> Result<Mat<f64>> {
    let n = g.nrows();
    if n == 0 {
        return Err(GpError::Empty {
            what: "Gram matrix",
        });
    }
    check_finite(g, "Gram matrix")?;
    check_symmetric(g, "Gram matrix")?;
    let r: Vec<f64> = (0..n)
        .map(|i| (0..n).map(|j| g[(i, j)]).sum::<f64>() / n as f64)
        .collect();
    let t = r.iter().sum::<f64>() / n as f64;
    let mut s = Mat::from_fn(n, n, |i, j| g[(i, j)] - r[i] - r[j] + t);
    symmetrise(&mut s);
    check_finite_result(s.as_ref(), "centred Gram matrix")?;
    Ok(s)
}

/// Principal submatrix `G[idx, idx]` (e.g. all materials but one for leave-one-out). Indices may
/// be in any order; errors on an out-of-range index or an empty selection.
pub fn subset_gram(g: MatRef<'_, f64>, idx: &[usize]) -> Result<Mat<f64>> {
    let n = g.nrows();
    if g.ncols() != n {
        return Err(GpError::DimensionMismatch {
            what: "Gram matrix columns vs rows",
            expected: n,
            got: g.ncols(),
        });
    }
    if idx.is_empty() {
        return Err(GpError::Empty {
            what: "subset index list",
        });
    }
    if let Some(&bad) = idx.iter().find(|&&i| i >= n) {
        return Err(GpError::IndexOutOfRange {
            what: "Gram matrix",
            index: bad,
            len: n,
        });
    }
    Ok(Mat::from_fn(idx.len(), idx.len(), |i, j| {
        g[(idx[i], idx[j])]
    }))
}

/// All indices `0..n` except `h` (leave-one-out helper for [`subset_gram`]).
pub fn all_but(n: usize, h: usize) -> Vec<usize> {
    (0..n).filter(|&i| i != h).collect()
}

/// Copies the lower triangle of square `m` into its strict upper triangle (row `j` of the
/// lower part into column `j` of the upper one).
pub(crate) fn mirror_lower(m: &mut Mat<f64>) {
    let n = m.nrows();
    for j in 1..n {
        let (left, mut right) = m.as_mut().split_at_col_mut(j);
        right
            .as_mut()
            .col_mut(0)
            .subrows_mut(0, j)
            .copy_from(left.as_ref().row(j).transpose());
    }
}

/// Copies the lower triangle's average with the upper one into both (exact symmetry).
pub(crate) fn symmetrise(m: &mut Mat<f64>) {
    let n = m.nrows();
    for j in 0..n {
        for i in (j + 1)..n {
            let v = 0.5 * (m[(i, j)] + m[(j, i)]);
            m[(i, j)] = v;
            m[(j, i)] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The strict upper triangle becomes the lower one's transpose; the lower triangle and the
    /// diagonal keep their values (every order from empty to a few columns).
    #[test]
    fn mirror_lower_copies_the_lower_triangle_up() {
        for n in 0..6 {
            let lower = |i: usize, j: usize| (10 * i + j) as f64;
            let mut m = Mat::from_fn(n, n, |i, j| if i >= j { lower(i, j) } else { -1.0 });
            mirror_lower(&mut m);
            for j in 0..n {
                for i in 0..n {
                    assert_eq!(m[(i, j)], lower(i.max(j), i.min(j)), "{n}: ({i}, {j})");
                }
            }
        }
    }

    #[test]
    fn centring_matches_centred_data_and_subset() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (n, d) = (9, 14);
        let y = Mat::from_fn(n, d, |_, _| rng.random_range(-3.0..5.0));
        let g = gram_from_data(y.as_ref(), Par::Seq).unwrap();
        let s = centre_gram(g.as_ref()).unwrap();
        let mean: Vec<f64> = (0..d)
            .map(|j| (0..n).map(|i| y[(i, j)]).sum::<f64>() / n as f64)
            .collect();
        let yc = Mat::from_fn(n, d, |i, j| y[(i, j)] - mean[j]);
        let sc = gram_from_data(yc.as_ref(), Par::Seq).unwrap();
        let scale = (0..n).map(|i| g[(i, i)]).fold(0.0, f64::max);
        for j in 0..n {
            for i in 0..n {
                assert!((s[(i, j)] - sc[(i, j)]).abs() <= 1e3 * f64::EPSILON * scale);
            }
            // Rows of a centred Gram sum to zero.
            let rs: f64 = (0..n).map(|i| s[(i, j)]).sum();
            assert!(rs.abs() <= 1e3 * f64::EPSILON * scale);
        }
        // Subset of G equals the Gram of the subset of Y; centring then matches too.
        let idx = all_but(n, 4);
        let gs = subset_gram(g.as_ref(), &idx).unwrap();
        let ys = Mat::from_fn(n - 1, d, |i, j| y[(idx[i], j)]);
        let gs2 = gram_from_data(ys.as_ref(), Par::Seq).unwrap();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                assert_eq!(gs[(i, j)], gs2[(i, j)]);
            }
        }
        assert!(matches!(
            subset_gram(g.as_ref(), &[0, n]),
            Err(GpError::IndexOutOfRange { index, .. }) if index == n
        ));
        assert!(subset_gram(g.as_ref(), &[]).is_err());
        let mut bad = g.clone();
        bad[(0, 0)] = f64::NAN;
        assert!(centre_gram(bad.as_ref()).is_err());
    }

    /// With small integer data and `N = 4` every step is exact, so `Y Y^T` and its centring are
    /// the exact values (a symmetrisation that mixed the two triangles wrongly showed here);
    /// with random data both are bitwise symmetric (the centring's two triangles round
    /// differently before they are averaged).
    #[test]
    fn gram_and_centring_are_exact_and_exactly_symmetric() {
        let y = Mat::from_fn(4, 3, |i, j| ((i * 3 + j * 5) % 7) as f64 - 3.0);
        let g = gram_from_data(y.as_ref(), Par::Seq).unwrap();
        let s = centre_gram(g.as_ref()).unwrap();
        let mean: Vec<f64> = (0..3)
            .map(|j| (0..4).map(|i| y[(i, j)]).sum::<f64>() / 4.0)
            .collect();
        for i in 0..4 {
            for j in 0..4 {
                let gij: f64 = (0..3).map(|k| y[(i, k)] * y[(j, k)]).sum();
                assert_eq!(g[(i, j)], gij, "G {i},{j}");
                let sij: f64 = (0..3)
                    .map(|k| (y[(i, k)] - mean[k]) * (y[(j, k)] - mean[k]))
                    .sum();
                assert_eq!(s[(i, j)], sij, "S {i},{j}");
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let y = Mat::from_fn(13, 7, |_, _| rng.random_range(-3.0..5.0));
        let g = gram_from_data(y.as_ref(), Par::Seq).unwrap();
        let s = centre_gram(g.as_ref()).unwrap();
        for i in 0..13 {
            for j in 0..13 {
                assert_eq!(g[(i, j)].to_bits(), g[(j, i)].to_bits());
                assert_eq!(s[(i, j)].to_bits(), s[(j, i)].to_bits());
            }
        }
    }
}
