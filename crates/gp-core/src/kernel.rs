//! RBF kernel with isotropic or ARD length-scales plus a white-noise (delta) term.
//!
//! For latent points `x, x'` in `R^q`:
//!
//! ```text
//! k(x, x') = s^2 exp(-1/2 sum_j (x_j - x'_j)^2 / l_j^2)        (RBF part)
//! K        = K_rbf(X) + mu I                                   (training covariance)
//! ```
//!
//! with `l_j = l` for every `j` in the isotropic case. Latent points are the rows of an `N x q`
//! matrix `X`. Gradients of any scalar `F(K)` are obtained by [`KernelParams::backprop`] from the
//! symmetric matrix `dF/dK`.

use crate::error::{
    GpError, Result, check_finite, check_finite_result, check_finite_slice, check_symmetric,
};
use faer::{Mat, MatRef, Par};
use rayon::prelude::*;

/// Length-scale of the RBF kernel: one value for every latent axis, or one per axis (ARD).
#[derive(Debug, Clone, PartialEq)]
pub enum LengthScale {
    /// `l_j = l` for every axis.
    Isotropic(f64),
    /// `l_j` given per axis; the length must equal the latent dimension `q`.
    Ard(Vec<f64>),
}

impl LengthScale {
    /// Number of free length-scale values (1 for isotropic, `q` for ARD).
    pub fn len(&self) -> usize {
        match self {
            LengthScale::Isotropic(_) => 1,
            LengthScale::Ard(v) => v.len(),
        }
    }

    /// True for an ARD length-scale with no axis (never valid after [`KernelParamsUnchecked::check`]).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The length-scale values (one for isotropic).
    pub fn values(&self) -> &[f64] {
        match self {
            LengthScale::Isotropic(l) => std::slice::from_ref(l),
            LengthScale::Ard(v) => v,
        }
    }

    /// `l_j` for latent axis `j`.
    #[inline]
    pub fn axis(&self, j: usize) -> f64 {
        match self {
            LengthScale::Isotropic(l) => *l,
            LengthScale::Ard(v) => v[j],
        }
    }

    /// True for [`LengthScale::Ard`].
    pub fn is_ard(&self) -> bool {
        matches!(self, LengthScale::Ard(_))
    }
}

/// Unvalidated kernel hyperparameters; call [`check`](Self::check) to obtain [`KernelParams`].
#[derive(Debug, Clone, PartialEq)]
pub struct KernelParamsUnchecked {
    /// RBF amplitude `s^2` (> 0).
    pub signal_variance: f64,
    /// Length-scale `l` (every value > 0).
    pub length_scale: LengthScale,
    /// White-noise variance `mu` on the diagonal (> 0).
    pub noise: f64,
}

impl KernelParamsUnchecked {
    /// Validates: every value finite and strictly positive, length-scales in 1e-150..=1e150,
    /// ARD non-empty.
    pub fn check(self) -> Result<KernelParams> {
        let bad = |name: String, value: f64| GpError::InvalidHyperparameter { name, value };
        let ok = |v: f64| v.is_finite() && v > 0.0;
        // The kernel divides squared distances by l^2: both l^2 and 1/l^2 must be normal.
        let ok_l = |l: f64| ok(l) && (1e-150..=1e150).contains(&l);
        if !ok(self.signal_variance) {
            return Err(bad("signal_variance".into(), self.signal_variance));
        }
        if !ok(self.noise) {
            return Err(bad("noise".into(), self.noise));
        }
        match &self.length_scale {
            LengthScale::Isotropic(l) => {
                if !ok_l(*l) {
                    return Err(bad("length_scale".into(), *l));
                }
            }
            LengthScale::Ard(v) => {
                if v.is_empty() {
                    return Err(GpError::Empty {
                        what: "ARD length-scale",
                    });
                }
                if let Some(j) = v.iter().position(|&l| !ok_l(l)) {
                    return Err(bad(format!("length_scale[{j}]"), v[j]));
                }
            }
        }
        Ok(KernelParams {
            signal_variance: self.signal_variance,
            length_scale: self.length_scale,
            noise: self.noise,
        })
    }
}

/// Validated hyperparameters `(s^2, l, mu)` of `K = K_rbf + mu I`; every value finite and > 0.
#[derive(Debug, Clone, PartialEq)]
pub struct KernelParams {
    signal_variance: f64,
    length_scale: LengthScale,
    noise: f64,
}

/// Gradient of a scalar with respect to the hyperparameters, in the layout of
/// [`KernelParams::to_log_vec`]: `[s^2, l (1 or q values), mu]` (either raw or log coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct HyperGradient {
    /// Derivative with respect to `s^2` (or `log s^2`).
    pub signal_variance: f64,
    /// Derivatives with respect to each `l_j` (or `log l_j`); one entry when isotropic.
    pub length_scale: Vec<f64>,
    /// Derivative with respect to `mu` (or `log mu`).
    pub noise: f64,
}

impl HyperGradient {
    /// Flattens to `[signal_variance, length_scale..., noise]`.
    pub fn to_vec(&self) -> Vec<f64> {
        let mut v = Vec::with_capacity(self.length_scale.len() + 2);
        v.push(self.signal_variance);
        v.extend_from_slice(&self.length_scale);
        v.push(self.noise);
        v
    }
}

/// Gradient of a scalar `F(K(X, theta))` with respect to `X` and the hyperparameters.
#[derive(Debug, Clone)]
pub struct KernelGradient {
    /// `dF/dX`, `N x q`.
    pub x: Mat<f64>,
    /// `dF/d(s^2)`, `dF/dl_j`, `dF/dmu`.
    pub hyper: HyperGradient,
    /// `dF/dlog s^2 = s^2 dF/ds^2`, `dF/dlog l_j = l_j dF/dl_j`, `dF/dlog mu = mu dF/dmu`.
    pub hyper_log: HyperGradient,
}

impl KernelParams {
    /// Builds and validates `(s^2, l, mu)`.
    pub fn new(signal_variance: f64, length_scale: LengthScale, noise: f64) -> Result<Self> {
        KernelParamsUnchecked {
            signal_variance,
            length_scale,
            noise,
        }
        .check()
    }

    /// Isotropic shorthand: `KernelParams::new(s2, LengthScale::Isotropic(l), mu)`.
    pub fn isotropic(signal_variance: f64, length_scale: f64, noise: f64) -> Result<Self> {
        Self::new(signal_variance, LengthScale::Isotropic(length_scale), noise)
    }

    /// The paper's fixed values: `s = 1`, `l = 1`, `mu = 1e-4` (isotropic).
    pub fn paper() -> Self {
        KernelParams {
            signal_variance: 1.0,
            length_scale: LengthScale::Isotropic(1.0),
            noise: 1e-4,
        }
    }

    /// RBF amplitude `s^2`.
    pub fn signal_variance(&self) -> f64 {
        self.signal_variance
    }

    /// Length-scale.
    pub fn length_scale(&self) -> &LengthScale {
        &self.length_scale
    }

    /// White-noise variance `mu`.
    pub fn noise(&self) -> f64 {
        self.noise
    }

    /// Back to the unchecked form (e.g. to edit a field and re-check).
    pub fn into_unchecked(self) -> KernelParamsUnchecked {
        KernelParamsUnchecked {
            signal_variance: self.signal_variance,
            length_scale: self.length_scale,
            noise: self.noise,
        }
    }

    /// Copy with a different noise `mu` (validated).
    pub fn with_noise(&self, noise: f64) -> Result<Self> {
        Self::new(self.signal_variance, self.length_scale.clone(), noise)
    }

    /// Number of hyperparameters: `2 + ` [`LengthScale::len`].
    pub fn n_hyper(&self) -> usize {
        2 + self.length_scale.len()
    }

    /// Log-coordinates `[log s^2, log l_1 (.. log l_q), log mu]` for positive-constrained optimisation.
    pub fn to_log_vec(&self) -> Vec<f64> {
        let mut v = Vec::with_capacity(self.n_hyper());
        v.push(self.signal_variance.ln());
        v.extend(self.length_scale.values().iter().map(|l| l.ln()));
        v.push(self.noise.ln());
        v
    }

    /// Inverse of [`to_log_vec`](Self::to_log_vec): `log_theta.len() - 2` length-scales
    /// (1 -> isotropic, else ARD). Errors if a value overflows or the slice is too short.
    pub fn from_log_slice(log_theta: &[f64]) -> Result<Self> {
        if log_theta.len() < 3 {
            return Err(GpError::DimensionMismatch {
                what: "log-hyperparameter vector (>= 3)",
                expected: 3,
                got: log_theta.len(),
            });
        }
        let k = log_theta.len() - 2;
        let ls: Vec<f64> = log_theta[1..1 + k].iter().map(|v| v.exp()).collect();
        let length_scale = if k == 1 {
            LengthScale::Isotropic(ls[0])
        } else {
            LengthScale::Ard(ls)
        };
        Self::new(log_theta[0].exp(), length_scale, log_theta[k + 1].exp())
    }

    /// Checks the length-scale matches the latent dimension `q` (ARD only).
    pub fn check_dim(&self, q: usize) -> Result<()> {
        if q == 0 {
            return Err(GpError::Empty {
                what: "latent dimension q",
            });
        }
        if let LengthScale::Ard(v) = &self.length_scale
            && v.len() != q
        {
            return Err(GpError::DimensionMismatch {
                what: "ARD length-scale vs latent dimension q",
                expected: q,
                got: v.len(),
            });
        }
        Ok(())
    }

    /// Scaled squared distance `r^2 = sum_j (a_j / l_j - b_j / l_j)^2` (no validation; slices of
    /// length q). Every kernel evaluation in this crate uses exactly this arithmetic (coordinates
    /// divided by `l_j` first, then summed over `j` in order), so `K` and cross-covariances agree
    /// bit for bit.
    #[inline]
    pub fn scaled_sq_dist(&self, a: &[f64], b: &[f64]) -> f64 {
        let mut r = 0.0;
        for (j, (x, y)) in a.iter().zip(b).enumerate() {
            let l = self.length_scale.axis(j);
            let d = x / l - y / l;
            r += d * d;
        }
        r
    }

    /// RBF value `k(a, b) = s^2 exp(-r^2/2)` (no delta term; slices of length q, unchecked).
    #[inline]
    pub fn rbf(&self, a: &[f64], b: &[f64]) -> f64 {
        self.signal_variance * (-0.5 * self.scaled_sq_dist(a, b)).exp()
    }

    /// Validates `x` (`N x q`, non-empty, finite, ARD length matches q) and returns its rows.
    pub(crate) fn rows_of(&self, x: MatRef<'_, f64>, what: &'static str) -> Result<Vec<Vec<f64>>> {
        if x.nrows() == 0 {
            return Err(GpError::Empty { what });
        }
        self.check_dim(x.ncols())?;
        check_finite(x, what)?;
        self.check_scaled(x)?;
        Ok((0..x.nrows())
            .map(|i| (0..x.ncols()).map(|j| x[(i, j)]).collect())
            .collect())
    }

    /// Errors if some `x_ij / l_j` overflows (distances would become NaN).
    fn check_scaled(&self, x: MatRef<'_, f64>) -> Result<()> {
        for j in 0..x.ncols() {
            let l = self.length_scale.axis(j);
            for i in 0..x.nrows() {
                let z = x[(i, j)] / l;
                if !z.is_finite() {
                    return Err(GpError::NonFiniteResult {
                        what: "scaled latent coordinate x / l",
                        value: z,
                    });
                }
            }
        }
        Ok(())
    }

    /// Validates `x` like `rows_of` and returns the scaled coordinates `z_ij = x_ij / l_j`
    /// stored per axis (`q` vectors of length `N`), for vectorised kernel evaluation.
    pub(crate) fn scaled_axes(
        &self,
        x: MatRef<'_, f64>,
        what: &'static str,
    ) -> Result<Vec<Vec<f64>>> {
        if x.nrows() == 0 {
            return Err(GpError::Empty { what });
        }
        self.check_dim(x.ncols())?;
        check_finite(x, what)?;
        self.check_scaled(x)?;
        Ok((0..x.ncols())
            .map(|j| {
                let l = self.length_scale.axis(j);
                (0..x.nrows()).map(|i| x[(i, j)] / l).collect()
            })
            .collect())
    }

    /// Fills `out[i] = r^2(x_i, x*)` from scaled axes `z` (see `scaled_axes`); same arithmetic
    /// as [`scaled_sq_dist`](Self::scaled_sq_dist).
    #[inline]
    pub(crate) fn fill_sq_dist(&self, z: &[Vec<f64>], x_star: &[f64], out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        for (j, zj) in z.iter().enumerate() {
            let zs = x_star[j] / self.length_scale.axis(j);
            for (o, &zi) in out.iter_mut().zip(zj) {
                let d = zi - zs;
                *o += d * d;
            }
        }
    }

    /// `K_rbf(X)`, `N x N`, without the noise term. `X` is `N x q` (rows are points).
    pub fn rbf_matrix(&self, x: MatRef<'_, f64>) -> Result<Mat<f64>> {
        let mut k = Mat::new();
        self.rbf_into(x, 0.0, &mut k)?;
        Ok(k)
    }

    /// [`KernelParams::kernel_matrix`] into `out` (resized to `N x N`; its old values are
    /// overwritten): the same values, without allocating.
    pub fn kernel_matrix_into(&self, x: MatRef<'_, f64>, out: &mut Mat<f64>) -> Result<()> {
        self.rbf_into(x, self.noise, out)
    }

    /// Training covariance `K = K_rbf(X) + mu I`, `N x N`, symmetric positive definite
    /// (its smallest eigenvalue is at least `mu`).
    pub fn kernel_matrix(&self, x: MatRef<'_, f64>) -> Result<Mat<f64>> {
        let mut k = Mat::new();
        self.kernel_matrix_into(x, &mut k)?;
        Ok(k)
    }

    /// `K_rbf(X) + diagonal I` into `out` (resized to `N x N`). Scaled axes z_j = x_j / l_j
    /// once; the strict lower triangle's squared distances, packed by columns, accumulated axis
    /// by axis (contiguous, vectorises), one batch of exponentials over all of them
    /// (`crate::fastmath`), then mirrored.
    fn rbf_into(&self, x: MatRef<'_, f64>, diagonal: f64, out: &mut Mat<f64>) -> Result<()> {
        let z = self.scaled_axes(x, "latent points X")?;
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F (checked just above; it implies AVX2 and
                // FMA), the only requirement of a `#[target_feature]` function.
                unsafe { self.rbf_fill_avx512(&z, diagonal, out) };
                return Ok(());
            }
        }
        self.rbf_fill(&z, diagonal, out);
        Ok(())
    }

    /// [`KernelParams::rbf_fill`] compiled for AVX-512 (the same operations, so the same bits).
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    unsafe fn rbf_fill_avx512(&self, z: &[Vec<f64>], diagonal: f64, out: &mut Mat<f64>) {
        self.rbf_fill(z, diagonal, out);
    }

    /// The body of [`KernelParams::rbf_into`] given the scaled axes `z` (one `Vec` of N values
    /// per latent axis).
    #[inline(always)]
    fn rbf_fill(&self, z: &[Vec<f64>], diagonal: f64, out: &mut Mat<f64>) {
        let n = z.first().map_or(0, Vec::len);
        let s2 = self.signal_variance;
        out.resize_with(n, n, |_, _| 0.0);
        let mut packed = vec![0.0f64; n * n.saturating_sub(1) / 2];
        let mut at = 0;
        for m in 0..n {
            let col = &mut packed[at..at + n - m - 1];
            for axis in z {
                let zm = axis[m];
                for (o, zi) in col.iter_mut().zip(&axis[m + 1..]) {
                    let d = zi - zm;
                    *o += d * d;
                }
            }
            at += n - m - 1;
        }
        crate::fastmath::rbf_from_sq_dist_in_place(&mut packed, s2);
        let mut at = 0;
        for m in 0..n {
            out.col_as_slice_mut(m)[m + 1..].copy_from_slice(&packed[at..at + n - m - 1]);
            at += n - m - 1;
        }
        for j in 0..n {
            out[(j, j)] = s2 + diagonal;
        }
        crate::gram::mirror_lower(out);
    }

    /// Cross-covariance `K_*[i, m] = k_rbf(x_i, x*_m)`, `N x M`, for training points `X` (`N x q`)
    /// and test points `X*` (`M x q`); no delta term. Columns are filled in parallel when `par`
    /// is [`Par::Rayon`].
    pub fn cross_matrix(
        &self,
        x: MatRef<'_, f64>,
        x_star: MatRef<'_, f64>,
        par: Par,
    ) -> Result<Mat<f64>> {
        let z = self.scaled_axes(x, "training latent points X")?;
        if x_star.ncols() != x.ncols() {
            return Err(GpError::DimensionMismatch {
                what: "test points X* columns vs latent dimension q",
                expected: x.ncols(),
                got: x_star.ncols(),
            });
        }
        check_finite(x_star, "test latent points X*")?;
        let n = x.nrows();
        let m = x_star.nrows();
        let q = x.ncols();
        let mut out = Mat::<f64>::zeros(n, m);
        let s2 = self.signal_variance;
        let fill = |c: usize, col: &mut [f64]| {
            let xs: Vec<f64> = (0..q).map(|j| x_star[(c, j)]).collect();
            self.fill_sq_dist(&z, &xs, col);
            crate::fastmath::rbf_from_sq_dist_in_place(col, s2);
        };
        // (`X` has rows: `scaled_axes` refuses an empty one. No test point: no column.)
        let run = |(c, col): (usize, faer::ColMut<'_, f64>)| {
            if let Some(col) = col.try_as_col_major_mut() {
                fill(c, col.as_slice_mut());
            }
        };
        match par {
            Par::Seq => out.as_mut().col_iter_mut().enumerate().for_each(run),
            _ => out.as_mut().par_col_iter_mut().enumerate().for_each(run),
        }
        Ok(out)
    }

    /// Backpropagates a symmetric `dF/dK` (`N x N`) through `K = K_rbf(X) + mu I`.
    ///
    /// With `W = dF/dK ∘ K_rbf` (elementwise) and `X` the `N x q` latent points:
    ///
    /// ```text
    /// dF/dx_nj      = -(2 / l_j^2) sum_m W_nm (x_nj - x_mj)
    /// dF/dlog s^2   = sum_nm W_nm
    /// dF/dlog l_j   = sum_nm W_nm (x_nj - x_mj)^2 / l_j^2     (summed over j when isotropic)
    /// dF/dlog mu    = mu tr(dF/dK)
    /// ```
    ///
    /// Cost `O(N^2 q)`. The raw gradients divide by the parameter (`dF/dθ = dF/dlog θ / θ`).
    pub fn backprop(&self, x: MatRef<'_, f64>, dk: MatRef<'_, f64>) -> Result<KernelGradient> {
        // rbf_matrix validates X (non-empty, finite, dimensions).
        let k_rbf = self.rbf_matrix(x)?;
        if dk.nrows() == x.nrows() && dk.ncols() == x.nrows() {
            check_finite(dk, "dF/dK")?;
            check_symmetric(dk, "dF/dK")?;
            // Symmetric to the bit, as backprop_with_rbf needs: (dk + dk^T) / 2.
            let n = dk.nrows();
            let sym = Mat::from_fn(n, n, |i, j| 0.5 * (dk[(i, j)] + dk[(j, i)]));
            return self.backprop_with_rbf(x, sym.as_ref(), k_rbf.as_ref(), true);
        }
        self.backprop_with_rbf(x, dk, k_rbf.as_ref(), true)
    }

    /// [`KernelParams::backprop`] given `K_rbf(X)` (from [`KernelParams::rbf_matrix`] or the
    /// off-diagonal of [`KernelParams::kernel_matrix`]), so no kernel value is computed twice.
    /// `dk` and `k_rbf` must be symmetric to the bit (the objective mirrors its `dF/dK`;
    /// `backprop` averages the caller's with its transpose): each pair's weight is read from
    /// whichever triangle is contiguous. Without `length_scale` the length-scale gradient (a
    /// sum over pairs per axis, ~5 % of an N = 51, q = 5 evaluation) is not computed and
    /// reported as 0 (for optimisers that keep the length-scale fixed).
    /// Compiled for AVX-512 or AVX2 + FMA when the CPU has them (selected at run time): the
    /// same operations in the same order, so the same bits, 8 or 4 lanes wide instead of the
    /// baseline's 2 (it was a quarter of a default fit's time).
    pub(crate) fn backprop_with_rbf(
        &self,
        x: MatRef<'_, f64>,
        dk: MatRef<'_, f64>,
        k_rbf: MatRef<'_, f64>,
        length_scale: bool,
    ) -> Result<KernelGradient> {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F (checked just above; it implies AVX2 and
                // FMA), the only requirement of a `#[target_feature]` function.
                return unsafe { self.backprop_avx512(x, dk, k_rbf, length_scale) };
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked just above), the only
                // requirement of a `#[target_feature]` function.
                return unsafe { self.backprop_avx2(x, dk, k_rbf, length_scale) };
            }
        }
        self.backprop_body(x, dk, k_rbf, length_scale)
    }

    /// [`KernelParams::backprop_with_rbf`] compiled for AVX-512.
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    unsafe fn backprop_avx512(
        &self,
        x: MatRef<'_, f64>,
        dk: MatRef<'_, f64>,
        k_rbf: MatRef<'_, f64>,
        length_scale: bool,
    ) -> Result<KernelGradient> {
        self.backprop_body(x, dk, k_rbf, length_scale)
    }

    /// [`KernelParams::backprop_with_rbf`] compiled for AVX2 + FMA.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn backprop_avx2(
        &self,
        x: MatRef<'_, f64>,
        dk: MatRef<'_, f64>,
        k_rbf: MatRef<'_, f64>,
        length_scale: bool,
    ) -> Result<KernelGradient> {
        self.backprop_body(x, dk, k_rbf, length_scale)
    }

    /// The arithmetic of [`KernelParams::backprop_with_rbf`] (no fused multiply-adds, so every
    /// build gives the same bits).
    #[inline(always)]
    fn backprop_body(
        &self,
        x: MatRef<'_, f64>,
        dk: MatRef<'_, f64>,
        k_rbf: MatRef<'_, f64>,
        length_scale: bool,
    ) -> Result<KernelGradient> {
        let n = x.nrows();
        let q = x.ncols();
        for (what, m) in [
            ("dF/dK vs number of latent points", dk),
            ("K_rbf vs number of latent points", k_rbf),
        ] {
            if let Some(got) = [m.nrows(), m.ncols()].into_iter().find(|&d| d != n) {
                return Err(GpError::DimensionMismatch {
                    what,
                    expected: n,
                    got,
                });
            }
        }
        let inv_l2: Vec<f64> = (0..q)
            .map(|j| {
                let l = self.length_scale.axis(j);
                1.0 / (l * l)
            })
            .collect();
        // W[n][m] = dF/dK[n][m] K_rbf[n][m] off the diagonal (dF/dK is symmetric to the bit:
        // see backprop_with_rbf). With row sums r = W 1 and
        // the points centred (the kernel part is translation-invariant), the sum over pairs of
        // the latent gradient becomes a product with W X:
        //   dF/dx_n       = -2/l^2 (r_n x_n - (W X)_n)
        // The length-scale gradient is summed over pairs with explicit differences,
        //   dF/dlog l_j   = 1/l_j^2 sum_nm W_nm (x_nj - x_mj)^2 = 2/l_j^2 sum_{n<m} W_nm d_nm^2:
        // the product form 2/l_j^2 sum_n x_nj (r_n x_nj - (W X)_nj) rounds at eps |W| |x|^2,
        // which swamps it when a (near-)duplicate pair has a huge W (~1/mu^2) and d ~ 0 (a 25 %
        // error at mu = 1e-10, the wrong sign with two such pairs).
        // W is symmetric and kept column-major in a Vec (plain slices in the hot loops), built
        // column by column (contiguous products; both triangles, so no strided mirror).
        let mut w = vec![0.0f64; n * n];
        for (m, w_m) in w.chunks_exact_mut(n.max(1)).enumerate().take(n) {
            let (dk_m, k_m) = (column(dk, m), column(k_rbf, m));
            for ((o, a), b) in w_m.iter_mut().zip(dk_m.iter()).zip(k_m.iter()) {
                *o = a * b;
            }
            w_m[m] = 0.0;
        }
        // r_n = sum_{m < n} W_nm + sum_{m > n} W_mn, each part summed in order of m (one
        // chain per row, so the bits do not depend on the vector width): the first part from
        // column m's lower triangle, the second from its upper one (W_mn = W_nm), every row's
        // chain advancing with each column.
        let mut r = vec![0.0f64; n];
        let mut below = vec![0.0f64; n];
        for (m, w_m) in w.chunks_exact(n.max(1)).enumerate().take(n) {
            for (ri, v) in r[m + 1..].iter_mut().zip(&w_m[m + 1..]) {
                *ri += v;
            }
            for (bi, v) in below[..m].iter_mut().zip(&w_m[..m]) {
                *bi += v;
            }
        }
        // Diagonal: K_rbf[n,n] = s^2 contributes only to the amplitude.
        let mut d_log_s2 = 0.0;
        for m in 0..n {
            r[m] += below[m];
            d_log_s2 += column(dk, m)[m] * self.signal_variance;
            d_log_s2 += 2.0 * below[m];
        }
        let mut gx = Mat::<f64>::zeros(n, q);
        let mut d_log_l_axis = vec![0.0f64; q];
        let mut xc = vec![0.0f64; n];
        let mut wx = vec![0.0f64; n];
        for j in 0..q {
            let xj = column(x, j);
            let mean = xj.iter().sum::<f64>() / n as f64;
            xc.iter_mut()
                .zip(xj.iter())
                .for_each(|(c, v)| *c = v - mean);
            wx.iter_mut().for_each(|v| *v = 0.0);
            for (m, wm) in w.chunks_exact(n).enumerate() {
                let a = xc[m];
                wx.iter_mut().zip(wm).for_each(|(o, v)| *o += a * v);
            }
            for i in 0..n {
                let t = r[i] * xc[i] - wx[i];
                gx[(i, j)] = -2.0 * inv_l2[j] * t;
            }
            if !length_scale {
                continue;
            }
            // Eight independent partial sums per column (one dependency chain would cost ~4
            // cycles per pair, more than the rest of the gradient).
            let mut acc = [0.0f64; 8];
            for (m, wm) in w.chunks_exact(n).enumerate() {
                let a = xj[m];
                let (wr, xr) = (&wm[m + 1..], &xj[m + 1..]);
                let mut wc = wr.chunks_exact(8);
                let mut xc8 = xr.chunks_exact(8);
                for (w8, x8) in (&mut wc).zip(&mut xc8) {
                    for k in 0..8 {
                        let d = x8[k] - a;
                        acc[k] += w8[k] * d * d;
                    }
                }
                for (k, (wv, xv)) in wc.remainder().iter().zip(xc8.remainder()).enumerate() {
                    let d = xv - a;
                    acc[k] += wv * d * d;
                }
            }
            let pairs =
                ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
            d_log_l_axis[j] = 2.0 * inv_l2[j] * pairs;
        }
        let mut trace = 0.0;
        for i in 0..n {
            trace += dk[(i, i)];
        }
        let d_log_mu = self.noise * trace;
        let d_log_l: Vec<f64> = match &self.length_scale {
            LengthScale::Isotropic(_) => vec![d_log_l_axis.iter().sum()],
            LengthScale::Ard(_) => d_log_l_axis,
        };
        let hyper_log = HyperGradient {
            signal_variance: d_log_s2,
            length_scale: d_log_l.clone(),
            noise: d_log_mu,
        };
        let hyper = HyperGradient {
            signal_variance: d_log_s2 / self.signal_variance,
            length_scale: d_log_l
                .iter()
                .zip(self.length_scale.values())
                .map(|(g, l)| g / l)
                .collect(),
            noise: trace,
        };
        Ok(KernelGradient {
            x: gx,
            hyper,
            hyper_log,
        })
    }

    /// Gradient of the cross-covariance with respect to a test point:
    /// `d k_rbf(x_i, x*) / d x*_j = k_rbf(x_i, x*) (x_ij - x*_j) / l_j^2`, returned as `N x q`
    /// (0 where `k_rbf` is 0, whatever the distance; `0 * inf` was NaN). Errors if an entry
    /// overflows.
    pub fn cross_gradient(&self, x: MatRef<'_, f64>, x_star: &[f64]) -> Result<Mat<f64>> {
        let rows = self.rows_of(x, "training latent points X")?;
        let q = x.ncols();
        if x_star.len() != q {
            return Err(GpError::DimensionMismatch {
                what: "test point x* vs latent dimension q",
                expected: q,
                got: x_star.len(),
            });
        }
        check_finite_slice(x_star, "test latent point x*")?;
        let g = Mat::from_fn(rows.len(), q, |i, j| {
            let l = self.length_scale.axis(j);
            let k = self.rbf(&rows[i], x_star);
            if k == 0.0 {
                0.0
            } else {
                k * (rows[i][j] - x_star[j]) / (l * l)
            }
        });
        check_finite_result(g.as_ref(), "cross-covariance gradient")?;
        Ok(g)
    }
}

/// Column `j` of `m` as a slice: borrowed when the column is contiguous (every matrix faer
/// allocates), copied otherwise.
fn column(m: MatRef<'_, f64>, j: usize) -> std::borrow::Cow<'_, [f64]> {
    match m.col(j).try_as_col_major() {
        Some(c) => std::borrow::Cow::Borrowed(c.as_slice()),
        None => std::borrow::Cow::Owned((0..m.nrows()).map(|i| m[(i, j)]).collect()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The length-scale gradient with a duplicate latent pair whose dF/dK is huge (~1/mu^2,
    /// as at a tiny noise): the pair contributes nothing (d = 0), and the gradient equals the
    /// explicit sum over pairs to rounding (the product form was 25 % off at mu = 1e-10).
    #[test]
    fn length_scale_gradient_survives_duplicate_points_with_huge_weights() {
        let x = Mat::from_fn(5, 2, |i, j| {
            [
                [0.9, 0.1],
                [0.9, 0.1],
                [-0.4, 0.7],
                [0.2, -0.5],
                [0.91, 0.1],
            ][i][j]
                + 1000.0
        });
        let dk = Mat::from_fn(5, 5, |i, j| match (i.min(j), i.max(j)) {
            (0, 1) => 1e20,
            (0, 4) | (1, 4) => -3e12,
            (a, b) => 0.1 * (a + 2 * b) as f64 - 0.4,
        });
        for p in [
            KernelParams::isotropic(1.0, 1.0, 1e-10).unwrap(),
            KernelParams::new(2.0, LengthScale::Ard(vec![0.5, 2.0]), 1e-10).unwrap(),
        ] {
            let g = p.backprop(x.as_ref(), dk.as_ref()).unwrap();
            let k = p.rbf_matrix(x.as_ref()).unwrap();
            let mut want = [0.0f64; 2];
            for n in 0..5 {
                for m in 0..5 {
                    for (j, w) in want.iter_mut().enumerate() {
                        let l = p.length_scale.axis(j);
                        let d = x[(n, j)] - x[(m, j)];
                        *w += dk[(n, m)] * k[(n, m)] * d * d / (l * l);
                    }
                }
            }
            let got = &g.hyper_log.length_scale;
            let want: Vec<f64> = match p.length_scale {
                LengthScale::Isotropic(_) => vec![want[0] + want[1]],
                LengthScale::Ard(_) => want.to_vec(),
            };
            for (a, b) in got.iter().zip(&want) {
                assert!((a - b).abs() <= 1e-9 * b.abs(), "{got:?} vs {want:?}");
            }
        }
    }

    /// The vector builds of the kernel matrix and of its gradient give the portable build's
    /// bits (fits must not depend on the CPU's vector width).
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn vector_builds_of_kernel_and_gradient_agree_bitwise() {
        if !std::arch::is_x86_feature_detected!("avx512f") {
            // The AVX2 gradient build is covered where AVX-512 is missing.
            if !(std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma"))
            {
                return;
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let (n, q) = (37, 3);
        let x = Mat::from_fn(n, q, |_, _| rng.random_range(-2.0..2.0));
        let params = KernelParams::new(1.3, LengthScale::Ard(vec![0.7, 1.1, 0.9]), 1e-3).unwrap();
        let a = Mat::from_fn(n, n, |_, _| rng.random_range(-1.0..1.0));
        let dk = &a + a.transpose();
        let bits = |m: MatRef<'_, f64>| {
            (0..m.ncols())
                .flat_map(|j| (0..m.nrows()).map(move |i| m[(i, j)].to_bits()))
                .collect::<Vec<_>>()
        };
        let z = params.scaled_axes(x.as_ref(), "X").unwrap();
        let mut portable = Mat::new();
        params.rbf_fill(&z, 0.0, &mut portable);
        let dispatched = params.rbf_matrix(x.as_ref()).unwrap();
        assert_eq!(bits(dispatched.as_ref()), bits(portable.as_ref()));
        let want = params
            .backprop_body(x.as_ref(), dk.as_ref(), portable.as_ref(), true)
            .unwrap();
        let got = params
            .backprop_with_rbf(x.as_ref(), dk.as_ref(), portable.as_ref(), true)
            .unwrap();
        assert_eq!(bits(got.x.as_ref()), bits(want.x.as_ref()));
        let hyper = |h: &HyperGradient| {
            std::iter::once(h.signal_variance)
                .chain(h.length_scale.iter().copied())
                .chain(std::iter::once(h.noise))
                .map(f64::to_bits)
                .collect::<Vec<_>>()
        };
        assert_eq!(hyper(&got.hyper_log), hyper(&want.hyper_log));
        assert_eq!(hyper(&got.hyper), hyper(&want.hyper));
    }

    #[test]
    fn cross_matrix_matches_kernel_matrix_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let x = Mat::from_fn(37, 3, |_, _| rng.random_range(-2.0..2.0));
        for p in [
            KernelParams::isotropic(2.0, 0.7, 1e-3).unwrap(),
            KernelParams::new(0.5, LengthScale::Ard(vec![0.3, 1.0, 4.0]), 1e-6).unwrap(),
        ] {
            let k = p.rbf_matrix(x.as_ref()).unwrap();
            let kn = p.kernel_matrix(x.as_ref()).unwrap();
            for par in [Par::Seq, Par::rayon(2)] {
                let c = p.cross_matrix(x.as_ref(), x.as_ref(), par).unwrap();
                assert_eq!(c, k);
                // No test point: no column; no training point: an error.
                let none = p.cross_matrix(x.as_ref(), x.subrows(0, 0), par).unwrap();
                assert_eq!((none.nrows(), none.ncols()), (37, 0));
                assert!(matches!(
                    p.cross_matrix(x.subrows(0, 0), x.as_ref(), par),
                    Err(GpError::Empty { .. })
                ));
            }
            // kernel_matrix_into: the same matrix, also into a reused buffer of another size.
            let mut buf = Mat::from_fn(40, 40, |i, j| (i + j) as f64);
            p.kernel_matrix_into(x.as_ref(), &mut buf).unwrap();
            assert_eq!(buf, kn);
            let x1 = x.subrows(0, 1);
            p.kernel_matrix_into(x1, &mut buf).unwrap();
            assert_eq!(buf, p.kernel_matrix(x1).unwrap());
            for i in 0..37 {
                assert_eq!(kn[(i, i)], p.signal_variance() + p.noise());
                // Direct formula for one entry.
                let r2: f64 = (0..3)
                    .map(|j| {
                        let l = p.length_scale().axis(j);
                        ((x[(i, j)] - x[(0, j)]) / l).powi(2)
                    })
                    .sum();
                let direct = p.signal_variance() * (-0.5 * r2).exp();
                assert!((k[(i, 0)] - direct).abs() <= 1e-14 * p.signal_variance());
            }
        }
        // ARD with equal length-scales equals isotropic.
        let iso = KernelParams::isotropic(1.3, 0.9, 1e-4).unwrap();
        let ard = KernelParams::new(1.3, LengthScale::Ard(vec![0.9; 3]), 1e-4).unwrap();
        assert_eq!(
            iso.kernel_matrix(x.as_ref()).unwrap(),
            ard.kernel_matrix(x.as_ref()).unwrap()
        );
    }

    /// The length-scale's accessors: counts, emptiness, values, axes and kind.
    #[test]
    fn length_scale_accessors() {
        let iso = LengthScale::Isotropic(2.0);
        let ard = LengthScale::Ard(vec![0.5, 3.0]);
        let no_axis = LengthScale::Ard(Vec::new());
        assert_eq!((iso.len(), iso.is_empty(), iso.is_ard()), (1, false, false));
        assert_eq!((ard.len(), ard.is_empty(), ard.is_ard()), (2, false, true));
        assert_eq!(
            (no_axis.len(), no_axis.is_empty(), no_axis.is_ard()),
            (0, true, true)
        );
        assert_eq!((iso.values(), ard.values()), (&[2.0][..], &[0.5, 3.0][..]));
        assert_eq!((iso.axis(0), iso.axis(7), ard.axis(1)), (2.0, 2.0, 3.0));
    }

    #[test]
    fn log_roundtrip_and_validation() {
        let p = KernelParams::new(0.25, LengthScale::Ard(vec![0.5, 2.0]), 1e-4).unwrap();
        let lv = p.to_log_vec();
        assert_eq!(lv.len(), 4);
        let p2 = KernelParams::from_log_slice(&lv).unwrap();
        assert!((p2.signal_variance() - 0.25).abs() < 1e-15);
        assert!((p2.length_scale().values()[1] - 2.0).abs() < 1e-15);
        assert!((p2.noise() - 1e-4).abs() < 1e-19);
        assert!(KernelParams::from_log_slice(&[0.0, 0.0]).is_err());
        assert!(KernelParams::from_log_slice(&[800.0, 0.0, 0.0]).is_err());
        let e = KernelParamsUnchecked {
            signal_variance: 1.0,
            length_scale: LengthScale::Ard(vec![1.0, 0.0]),
            noise: 1.0,
        }
        .check();
        assert_eq!(
            e,
            Err(GpError::InvalidHyperparameter {
                name: "length_scale[1]".into(),
                value: 0.0
            })
        );
        assert!(p.check_dim(3).is_err());
        assert!(p.check_dim(2).is_ok());
        let x = Mat::from_fn(4, 3, |i, j| (i + j) as f64);
        assert!(matches!(
            p.kernel_matrix(x.as_ref()),
            Err(GpError::DimensionMismatch { .. })
        ));
        assert_eq!(KernelParams::paper().to_log_vec()[2], 1e-4f64.ln());
    }

    /// `dF/dK` and `K_rbf` must both be `N x N`: one wrong dimension (rows or columns, of
    /// either matrix) is a dimension error, not a gradient read from the first `N` columns of
    /// a wider matrix, nor an index panic.
    #[test]
    fn backprop_rejects_a_wrong_dimension_of_either_matrix() {
        let p = KernelParams::paper();
        let x = Mat::from_fn(4, 2, |i, j| 0.3 * (i * 2 + j) as f64);
        let k = p.rbf_matrix(x.as_ref()).unwrap();
        let dk = Mat::from_fn(4, 4, |i, j| 1.0 / (1.0 + (i + j) as f64));
        p.backprop_with_rbf(x.as_ref(), dk.as_ref(), k.as_ref(), true)
            .unwrap();
        for (r, c) in [(4, 5), (5, 4), (4, 3), (3, 4)] {
            let bad = Mat::from_fn(r, c, |i, j| 1.0 / (1.0 + (i + j) as f64));
            // The error names the wrong matrix and its wrong dimension.
            let wrong = if r != 4 { r } else { c };
            assert_eq!(
                p.backprop(x.as_ref(), bad.as_ref()).unwrap_err(),
                GpError::DimensionMismatch {
                    what: "dF/dK vs number of latent points",
                    expected: 4,
                    got: wrong
                },
                "dF/dK {r} x {c}"
            );
            for (dk, k, what) in [
                (bad.as_ref(), k.as_ref(), "dF/dK vs number of latent points"),
                (
                    dk.as_ref(),
                    bad.as_ref(),
                    "K_rbf vs number of latent points",
                ),
            ] {
                assert_eq!(
                    p.backprop_with_rbf(x.as_ref(), dk, k, true).unwrap_err(),
                    GpError::DimensionMismatch {
                        what,
                        expected: 4,
                        got: wrong
                    },
                    "{r} x {c}"
                );
            }
        }
    }

    /// `backprop` takes a caller's `dF/dK` only finite and symmetric to `sqrt(eps)` of its
    /// largest entry, and uses its symmetric part `(dF/dK + dF/dK^T) / 2`: a slightly
    /// asymmetric one gives the bits of its symmetric part, not of either triangle.
    #[test]
    fn backprop_checks_and_symmetrises_df_dk() {
        let p = KernelParams::new(1.3, LengthScale::Ard(vec![0.8, 1.7]), 1e-3).unwrap();
        let x = Mat::from_fn(5, 2, |i, j| 0.4 * i as f64 - 0.3 * (j * i % 3) as f64);
        let sym = Mat::from_fn(5, 5, |i, j| 1.0 / (1.0 + (i + j) as f64));
        let skew = |scale: f64| {
            Mat::from_fn(5, 5, |i, j| {
                sym[(i, j)] + scale * (i as f64 - j as f64) * (1.0 + (i * j) as f64)
            })
        };
        let asym = skew(1e-10);
        let half = Mat::from_fn(5, 5, |i, j| 0.5 * (asym[(i, j)] + asym[(j, i)]));
        let bits = |g: &KernelGradient| {
            let (n, q) = (g.x.nrows(), g.x.ncols());
            let mut v: Vec<u64> = (0..n * q).map(|k| g.x[(k % n, k / n)].to_bits()).collect();
            v.extend(g.hyper.to_vec().iter().map(|v| v.to_bits()));
            v
        };
        let of_half = bits(&p.backprop(x.as_ref(), half.as_ref()).unwrap());
        let of_asym = bits(&p.backprop(x.as_ref(), asym.as_ref()).unwrap());
        assert_eq!(of_asym, of_half);
        let k = p.rbf_matrix(x.as_ref()).unwrap();
        let raw = p
            .backprop_with_rbf(x.as_ref(), asym.as_ref(), k.as_ref(), true)
            .unwrap();
        assert_ne!(bits(&raw), of_half, "the triangles differ");
        assert!(matches!(
            p.backprop(x.as_ref(), skew(1e-6).as_ref()),
            Err(GpError::NotSymmetric { what: "dF/dK", .. })
        ));
        let mut nan = sym.clone();
        nan[(3, 1)] = f64::NAN;
        assert!(matches!(
            p.backprop(x.as_ref(), nan.as_ref()),
            Err(GpError::NonFinite {
                what: "dF/dK",
                row: 3,
                col: 1,
                ..
            })
        ));
    }

    /// The latent gradient is translation-invariant, and computed so: at points shifted by
    /// `2^30` (coordinates, scaled coordinates and so `K_rbf` stay exact: multiples of
    /// `2^-10`, length-scales powers of 2) it equals the unshifted gradient to rounding.
    /// Without centring the coordinates first, `r_n x_n - (W X)_n` cancels `2^30`-sized terms
    /// and keeps only ~7 digits.
    #[test]
    fn latent_gradient_is_exact_far_from_the_origin() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = 9;
        let x = Mat::from_fn(n, 2, |_, _| {
            rng.random_range(-2048i32..2048) as f64 / 1024.0
        });
        let shifted = Mat::from_fn(n, 2, |i, j| x[(i, j)] + 1073741824.0);
        let dk = Mat::from_fn(n, n, |i, j| {
            ((i * j) % 5) as f64 - 1.5 + (i + j) as f64 / 7.0
        });
        for p in [
            KernelParams::isotropic(1.5, 1.0, 1e-3).unwrap(),
            KernelParams::new(0.7, LengthScale::Ard(vec![0.5, 2.0]), 1e-2).unwrap(),
        ] {
            let g = p.backprop(x.as_ref(), dk.as_ref()).unwrap();
            let gs = p.backprop(shifted.as_ref(), dk.as_ref()).unwrap();
            let scale = g.x.norm_max();
            assert!(scale > 1e-3);
            for i in 0..n {
                for j in 0..2 {
                    let (a, b) = (g.x[(i, j)], gs.x[(i, j)]);
                    assert!((a - b).abs() <= 1e-12 * scale, "{i},{j}: {a} vs {b}");
                }
            }
        }
    }

    /// The gradients against the explicit pair sums of `backprop`'s formulas for `N = 21`,
    /// where the length-scale sum runs through its eight-lane blocks (rows with at least 8
    /// later points; the other tests have `N <= 9` and so only the remainder loop), and the
    /// summed isotropic one, the amplitude's and the noise's alongside.
    #[test]
    fn gradients_match_explicit_pair_sums_for_many_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let n = 21;
        let x = Mat::from_fn(n, 2, |_, _| rng.random_range(-1.5..1.5));
        let a = Mat::from_fn(n, n, |_, _| rng.random_range(-1.0..1.0));
        let dk = Mat::from_fn(n, n, |i, j| a[(i, j)] + a[(j, i)]);
        for p in [
            KernelParams::new(1.3, LengthScale::Ard(vec![0.8, 1.7]), 1e-2).unwrap(),
            KernelParams::isotropic(0.6, 1.1, 1e-3).unwrap(),
        ] {
            let g = p.backprop(x.as_ref(), dk.as_ref()).unwrap();
            let k = p.rbf_matrix(x.as_ref()).unwrap();
            let (mut d_l, mut d_s2, mut gx) = ([0.0f64; 2], 0.0, Mat::<f64>::zeros(n, 2));
            for r in 0..n {
                for c in 0..n {
                    let w = dk[(r, c)] * k[(r, c)];
                    d_s2 += w;
                    for j in 0..2 {
                        let l2 = p.length_scale().axis(j).powi(2);
                        let d = x[(r, j)] - x[(c, j)];
                        d_l[j] += w * d * d / l2;
                        gx[(r, j)] -= 2.0 * w * d / l2;
                    }
                }
            }
            let want_l: Vec<f64> = match p.length_scale() {
                LengthScale::Isotropic(_) => vec![d_l[0] + d_l[1]],
                LengthScale::Ard(_) => d_l.to_vec(),
            };
            let close = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-11 * scale;
            let scale_l = d_l[0].abs() + d_l[1].abs();
            for (got, want) in g.hyper_log.length_scale.iter().zip(&want_l) {
                assert!(close(*got, *want, scale_l), "{got} vs {want}");
            }
            assert!(close(
                g.hyper_log.signal_variance,
                d_s2,
                d_s2.abs().max(1.0)
            ));
            let trace: f64 = (0..n).map(|i| dk[(i, i)]).sum();
            assert!(close(
                g.hyper_log.noise,
                p.noise() * trace,
                trace.abs() * p.noise()
            ));
            let scale_x = gx.norm_max();
            for r in 0..n {
                for j in 0..2 {
                    assert!(close(g.x[(r, j)], gx[(r, j)], scale_x), "{r},{j}");
                }
            }
        }
    }
}
