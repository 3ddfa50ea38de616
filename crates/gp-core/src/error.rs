//! The crate's single error type.

/// Every failure `gp-core` can report. Functions never panic on bad numeric input: they return one
/// of these variants instead, naming the quantity at fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GpError {
    /// A hyperparameter is non-positive or non-finite (or a length-scale whose square or
    /// inverse square is not a normal f64).
    #[error(
        "invalid hyperparameter {name} = {value:e}: must be finite and > 0{}",
        if name.starts_with("length_scale") {
            " (length-scales between 1e-150 and 1e150: the kernel divides by their square)"
        } else {
            ""
        }
    )]
    InvalidHyperparameter {
        /// Which hyperparameter (`signal_variance`, `length_scale[j]`, `noise`, ...).
        name: String,
        /// The offending value.
        value: f64,
    },
    /// Two inputs have incompatible sizes.
    #[error("dimension mismatch in {what}: expected {expected}, got {got}")]
    DimensionMismatch {
        /// What was being checked.
        what: &'static str,
        /// Expected size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// An input contains NaN or an infinity.
    #[error("non-finite value {value} in {what} at ({row}, {col})")]
    NonFinite {
        /// Which input.
        what: &'static str,
        /// Row of the first offending entry.
        row: usize,
        /// Column of the first offending entry.
        col: usize,
        /// The offending value.
        value: f64,
    },
    /// A matrix that must be symmetric is not (beyond a relative tolerance of `sqrt(eps)`).
    #[error("{what} is not symmetric: |a[{row},{col}] - a[{col},{row}]| = {diff:e}")]
    NotSymmetric {
        /// Which matrix.
        what: &'static str,
        /// Row of the worst entry.
        row: usize,
        /// Column of the worst entry.
        col: usize,
        /// Absolute asymmetry.
        diff: f64,
    },
    /// The Cholesky factorisation failed even after the maximum jitter.
    #[error(
        "{what} (n = {n}) is not positive definite: Cholesky failed after {attempts} attempts \
         (last jitter {last_jitter:e}, mean diagonal {mean_diagonal:e})"
    )]
    NotPositiveDefinite {
        /// Which matrix.
        what: &'static str,
        /// Its dimension.
        n: usize,
        /// Factorisation attempts made (the first one without jitter).
        attempts: usize,
        /// Largest jitter tried (0 if the diagonal mean was not positive).
        last_jitter: f64,
        /// Mean of the diagonal of the input.
        mean_diagonal: f64,
    },
    /// A matrix that must be positive semidefinite (a Gram matrix) fails a necessary condition:
    /// a negative diagonal entry (`row == col`), or a 2 x 2 principal minor
    /// `a_ii a_jj - a_ij^2` below zero, each beyond a tolerance of `sqrt(eps) max|a|`.
    #[error(
        "{what} is not positive semidefinite, as a Gram matrix must be: {}",
        if row == col {
            format!("diagonal entry a[{row},{row}] = {value:e} is negative")
        } else {
            format!("|a[{row},{col}]| exceeds sqrt(a[{row},{row}] a[{col},{col}]) (minor {value:e})")
        }
    )]
    NotPositiveSemidefinite {
        /// Which matrix.
        what: &'static str,
        /// Row of the offending entry or minor.
        row: usize,
        /// Column of the offending entry or minor (`== row` for a diagonal entry).
        col: usize,
        /// The negative diagonal entry, or the negative minor `a_ii a_jj - a_ij^2`.
        value: f64,
    },
    /// An input that must be non-empty is empty.
    #[error("{what} is empty")]
    Empty {
        /// Which input.
        what: &'static str,
    },
    /// An index is out of range.
    #[error("index {index} out of range for {what} of size {len}")]
    IndexOutOfRange {
        /// Which collection.
        what: &'static str,
        /// The offending index.
        index: usize,
        /// The collection's size.
        len: usize,
    },
    /// A learnt noise variance below the floor it is kept above (or not positive).
    #[error(
        "noise {noise:e} must be positive and at least the noise floor {floor:e} when the noise is learnt"
    )]
    NoiseBelowFloor {
        /// The noise variance given.
        noise: f64,
        /// The floor ([`crate::FlatGplvm::with_noise_floor`]).
        floor: f64,
    },
    /// A computation on valid inputs overflowed to a non-finite result.
    #[error("non-finite result in {what}: {value}")]
    NonFiniteResult {
        /// Which quantity.
        what: &'static str,
        /// The value obtained.
        value: f64,
    },
}

/// Shorthand for `Result<T, GpError>`.
pub type Result<T> = std::result::Result<T, GpError>;

/// Checks that every entry of `m` is finite.
pub(crate) fn check_finite(m: faer::MatRef<'_, f64>, what: &'static str) -> Result<()> {
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            let v = m[(i, j)];
            if !v.is_finite() {
                return Err(GpError::NonFinite {
                    what,
                    row: i,
                    col: j,
                    value: v,
                });
            }
        }
    }
    Ok(())
}

/// Checks that every entry of `m`, computed from finite inputs, is finite:
/// [`GpError::NonFiniteResult`] naming `what` for the first that overflowed.
pub(crate) fn check_finite_result(m: faer::MatRef<'_, f64>, what: &'static str) -> Result<()> {
    check_finite(m, what).map_err(|e| match e {
        GpError::NonFinite { value, .. } => GpError::NonFiniteResult { what, value },
        e => e,
    })
}

/// Checks that every entry of `s` is finite (reported as a column vector).
pub(crate) fn check_finite_slice(s: &[f64], what: &'static str) -> Result<()> {
    match s.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(GpError::NonFinite {
            what,
            row: i,
            col: 0,
            value: s[i],
        }),
        None => Ok(()),
    }
}

/// The largest absolute entry of `m` (0 when empty).
fn max_abs(m: faer::MatRef<'_, f64>) -> f64 {
    let mut amax = 0.0f64;
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            amax = amax.max(m[(i, j)].abs());
        }
    }
    amax
}

/// Checks the necessary conditions of positive semidefiniteness that cost `O(n^2)` on a
/// symmetric `m`: no diagonal entry below `-tol` and no 2 x 2 principal minor
/// `(m_ii + tol)(m_jj + tol) - m_ij^2` below zero, `tol = sqrt(eps) max|m|`, tested as
/// `|m_ij| > sqrt(m_ii + tol) sqrt(m_jj + tol)` (the products overflow for entries near 1e154
/// and underflow near 1e-154, and the check passed any matrix there). (A full test, a
/// factorisation or an eigen-decomposition, would reject genuine centred Gram matrices, whose
/// smallest eigenvalue is 0 computed as a rounding-level +- n eps of the *uncentred* entries,
/// which this function cannot see.)
pub(crate) fn check_psd_minors(m: faer::MatRef<'_, f64>, what: &'static str) -> Result<()> {
    let n = m.nrows();
    let tol = f64::EPSILON.sqrt() * max_abs(m);
    for i in 0..n {
        if m[(i, i)] < -tol {
            return Err(GpError::NotPositiveSemidefinite {
                what,
                row: i,
                col: i,
                value: m[(i, i)],
            });
        }
    }
    // Square roots of the (tolerance-raised, non-negative) diagonal: no products that overflow.
    let root: Vec<f64> = (0..n).map(|i| (m[(i, i)] + tol).max(0.0).sqrt()).collect();
    for j in 0..n {
        for i in (j + 1)..n {
            let a = m[(i, j)].abs();
            if a > root[i] * root[j] {
                // a_ii a_jj - a_ij^2 as (g - a)(g + a), g the geometric mean of the diagonal
                // entries: -inf rather than NaN where the square overflows.
                let g = m[(i, i)].max(0.0).sqrt() * m[(j, j)].max(0.0).sqrt();
                return Err(GpError::NotPositiveSemidefinite {
                    what,
                    row: i,
                    col: j,
                    value: (g - a) * (g + a),
                });
            }
        }
    }
    Ok(())
}

/// Checks `m` is square and symmetric to a relative tolerance `sqrt(eps) * max|a|`.
pub(crate) fn check_symmetric(m: faer::MatRef<'_, f64>, what: &'static str) -> Result<()> {
    let n = m.nrows();
    if m.ncols() != n {
        return Err(GpError::DimensionMismatch {
            what,
            expected: n,
            got: m.ncols(),
        });
    }
    let tol = f64::EPSILON.sqrt() * max_abs(m);
    for j in 0..n {
        for i in (j + 1)..n {
            let diff = (m[(i, j)] - m[(j, i)]).abs();
            if diff > tol {
                return Err(GpError::NotSymmetric {
                    what,
                    row: i,
                    col: j,
                    diff,
                });
            }
        }
    }
    Ok(())
}
