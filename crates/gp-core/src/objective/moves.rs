//! The log-likelihood after moving one latent point, in `O(N^2)` from a reference
//! factorisation, and a direct search's objective built on it.
//!
//! Moving point `n` changes row and column `n` of `K` (its diagonal, `s^2 + mu`, stays):
//! `K' = K + e_n d^T + d e_n^T` with `d = k'_n - k_n`, `d_n = 0`, a symmetric rank-2 update
//! `K' = K + U C U^T`, `U = [e_n, d]`, `C = [[0, 1], [1, 0]]`. With `M = C + U^T K^-1 U` =
//! `[[a, 1 + b], [1 + b, c]]` (`a = K^-1_nn`, `b = (K^-1 d)_n`, `c = d^T K^-1 d`), the
//! determinant lemma and Woodbury's identity give
//!
//! ```text
//! log|K'|       = log|K| + ln((1 + b)^2 - a c)
//! tr(K'^-1 S)   = tr(K^-1 S) - tr(M^-1 U^T W U),   W = K^-1 S K^-1
//! U^T W U       = [[W_nn, (W d)_n], [(W d)_n, d^T W d]]
//! ```
//!
//! so a move costs the new point's `N` kernel values and two matrix-vector products with
//! `K^-1` and `W`, both computed once per reference. For a small move every correction term is
//! small, so the difference from the reference is computed directly (to rounding relative to
//! the correction), not as the difference of two `O(N^3)` evaluations. Hooke-Jeeves, the paper's
//! optimiser, tries one coordinate at a time: all its exploratory trials are such moves.
//!
//! When the search accepts a move, the reference follows it by the same rank-2 update of `K^-1`
//! and `W` (`O(N^2)`, [`PointMoves::move_reference`]) for short moves and at most
//! [`MAX_UPDATES`] times in a row, by a new factorisation otherwise. [`MoveEvaluator`] keeps the
//! reference for a direct search (BENCHMARKS.md "gplvm", session 24: the paper's fit 16x
//! faster, its leave-one-out refits 13x).

use faer::{Mat, MatRef, Par};

use super::{FlatGplvm, GplvmObjective, Work, kinv_s_kinv_lower};
use crate::cholesky::one_norm_sym;
use crate::error::{GpError, Result};
use crate::kernel::KernelParams;

/// A move whose determinant ratio `|K'| / |K|` falls below this, or exceeds its inverse, is
/// evaluated in full: the moved point comes to (or leaves) a near-duplicate of another, and
/// the update would lose the digits the full factorisation keeps.
const MIN_DETERMINANT_RATIO: f64 = 1e-6;

/// References whose `K` has a larger 1-norm condition number take no moves (every trial is
/// evaluated in full): the update's rounding grows with `cond(K)` through `W`, ~1e3 eps |L|
/// at the paper's fits (cond ~4e5), and from a near-singular reference a move can be off
/// entirely (a test moved a point away from a duplicate at mu = 1e-10: 131 against 482).
const MAX_CONDITION: f64 = 1e7;

/// Reference moves ([`PointMoves::move_reference`]) between two full resets: each update of
/// `K^-1` and `W` adds its rounding to theirs.
pub const MAX_UPDATES: usize = 32;

/// The largest move (in length-scales, along any axis) that [`PointMoves::move_reference`]
/// makes by an update. Updates by moves up to 1 in a row drifted to 2.6e-6 relative in a test
/// (cond(K) ~ 2e5), up to 0.1 to 1.6e-10, up to 0.01 to 1.1e-12 after 32 updates: larger moves
/// reset in full (Hooke-Jeeves makes them only while its step is above 0.01).
pub const MAX_UPDATE_MOVE: f64 = 1e-2;

/// The log-likelihood of a [`GplvmObjective`] at latent points that differ from a reference in
/// one point: the reference's `X`, `K`, `K^-1`, `W = K^-1 S K^-1` and the terms of the
/// log-likelihood there (module docs).
pub struct PointMoves<'a> {
    obj: &'a GplvmObjective,
    params: KernelParams,
    x: Mat<f64>,
    /// Scaled axes of `x` (`x_ij / l_j`, one `Vec` per axis), as the kernel matrix uses them.
    z: Vec<Vec<f64>>,
    /// `K`, its factor and `K^-1` (the optimisers' plain path, [`GplvmObjective`]'s
    /// `factor_plain`), and `K^-1 S` on the way to `W`.
    work: Work,
    w: Mat<f64>,
    /// Whether the last reset succeeded (otherwise no moves are evaluated).
    ready: bool,
    /// Reference moves ([`PointMoves::move_reference`]) since the last reset.
    updates: usize,
    log_det: f64,
    trace: f64,
    sq: f64,
    value: f64,
    /// Scratch of one move: the kernel change `d`, `K^-1 d` and `W d`.
    d: Vec<f64>,
    kd: Vec<f64>,
    wd: Vec<f64>,
}

impl std::fmt::Debug for PointMoves<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PointMoves")
            .field("n", &self.x.nrows())
            .field("q", &self.x.ncols())
            .field("value", &self.value)
            .finish_non_exhaustive()
    }
}

impl<'a> PointMoves<'a> {
    /// The reference `(x, params)` of `obj`, or `None` when `K` needs jitter to factor or its
    /// condition number exceeds 1e7 (evaluate in full then: [`GplvmObjective::log_likelihood`]
    /// adds the jitter). The reference's
    /// log-likelihood ([`PointMoves::value`]) has the same bits as the optimisers' full
    /// evaluation ([`FlatGplvm::neg_log_likelihood`]).
    pub fn new(
        obj: &'a GplvmObjective,
        x: MatRef<'_, f64>,
        params: &KernelParams,
        par: Par,
    ) -> Result<Option<Self>> {
        let mut m = PointMoves {
            obj,
            params: params.clone(),
            x: Mat::new(),
            z: Vec::new(),
            work: Work::new(),
            w: Mat::new(),
            ready: false,
            updates: 0,
            log_det: 0.0,
            trace: 0.0,
            sq: 0.0,
            value: 0.0,
            d: Vec::new(),
            kd: Vec::new(),
            wd: Vec::new(),
        };
        Ok(m.reset(x, params, par)?.then_some(m))
    }

    /// Moves the reference to `(x, params)`, reusing the buffers; false when `K` needs jitter or
    /// is too ill-conditioned (as [`PointMoves::new`]). After a false or an error, moves
    /// evaluate to `None` until a reset returns true.
    pub fn reset(&mut self, x: MatRef<'_, f64>, params: &KernelParams, par: Par) -> Result<bool> {
        self.ready = false;
        self.updates = 0;
        let obj = self.obj;
        obj.check_x(x)?;
        let n = obj.n();
        self.params = params.clone();
        self.z = params.scaled_axes(x, "latent points X")?;
        self.x.resize_with(x.nrows(), x.ncols(), |_, _| 0.0);
        self.x.copy_from(x);
        // The optimisers' plain path, so the reference value has the same bits as theirs.
        let Some(log_det) = obj.factor_plain(&mut self.work, x, params, par)? else {
            return Ok(false);
        };
        let (k, kinv) = (self.work.k.as_ref(), self.work.kinv.as_ref());
        let condition = one_norm_sym(k, 0.0) * one_norm_sym(kinv, 0.0);
        // (A NaN condition, from an overflowing inverse, takes no moves either.)
        if condition.is_nan() || condition > MAX_CONDITION {
            return Ok(false);
        }
        self.log_det = log_det;
        self.trace = obj.trace_with(kinv);
        self.sq = GplvmObjective::sum_of_squares(x);
        self.value = obj.assemble_terms(self.log_det, self.trace, self.sq)?;
        // W = (K^-1 S) K^-1, symmetric: its lower triangle, then mirrored.
        let work = &mut self.work;
        kinv_s_kinv_lower(
            work.kinv.as_ref(),
            obj.s.as_ref(),
            1.0,
            &mut work.b,
            &mut self.w,
            par,
        );
        for j in 0..n {
            for i in 0..j {
                self.w[(i, j)] = self.w[(j, i)];
            }
        }
        self.ready = true;
        Ok(true)
    }

    /// The log-likelihood at the reference (after a reset that returned true).
    pub fn value(&self) -> f64 {
        self.value
    }

    /// The reference latent points (`N x q`).
    pub fn x(&self) -> MatRef<'_, f64> {
        self.x.as_ref()
    }

    /// The log-likelihood at the reference with point `n` moved to `point` (`q` values), in
    /// `O(N^2)` (module docs); equal to a full evaluation up to rounding. `None` when the move
    /// brings the point so close to another, or takes it so far from one it nearly duplicated,
    /// that `|K'| / |K|` leaves [1e-6, 1e6], or after a failed [`PointMoves::reset`]: evaluate
    /// it in full then.
    pub fn value_with_point(&mut self, n: usize, point: &[f64]) -> Result<Option<f64>> {
        match self.prepare_move(n, point)? {
            Some(t) => self.obj.assemble_terms(t.log_det, t.trace, t.sq).map(Some),
            None => Ok(None),
        }
    }

    /// Makes the reference's point `n` `point`, in `O(N^2)`: `K^-1` and `W` by the same rank-2
    /// update (`K'^-1 = K^-1 - P G P^T`, `P = K^-1 U`, `G = M^-1`; `W' = W - P G Q^T - Q G P^T +
    /// P G Z G P^T`, `Q = W U`, `Z = U^T W U`). False, with the reference unchanged, when
    /// [`PointMoves::value_with_point`] would give `None`, for a move longer than
    /// [`MAX_UPDATE_MOVE`] length-scales, or after [`MAX_UPDATES`] updates since the last reset
    /// (rounding accumulates in the updated matrices): reset then.
    pub fn move_reference(&mut self, n: usize, point: &[f64]) -> Result<bool> {
        if self.updates >= MAX_UPDATES {
            return Ok(false);
        }
        let Some(t) = self.prepare_move(n, point)? else {
            return Ok(false);
        };
        let long = point.iter().enumerate().any(|(j, &p)| {
            (p - self.x[(n, j)]).abs() > MAX_UPDATE_MOVE * self.params.length_scale().axis(j)
        });
        if long {
            return Ok(false);
        }
        let value = self.obj.assemble_terms(t.log_det, t.trace, t.sq)?;
        let size = self.x.nrows();
        // G = M^-1 = [[c, -(1 + b)], [-(1 + b), a]] / det M, det M = -(|K'| / |K|).
        let det_m = -t.ratio;
        let (g11, g12, g22) = (t.c / det_m, -(1.0 + t.b) / det_m, t.a / det_m);
        // H = G Z G.
        let (z11, z12, z22) = (t.z11, t.z12, t.z22);
        let (gz11, gz12) = (g11 * z11 + g12 * z12, g11 * z12 + g12 * z22);
        let (gz21, gz22) = (g12 * z11 + g22 * z12, g12 * z12 + g22 * z22);
        let (h11, h12, h22) = (
            gz11 * g11 + gz12 * g12,
            gz11 * g12 + gz12 * g22,
            gz21 * g12 + gz22 * g22,
        );
        // P = [u, v] (u = K^-1 e_n, v = K^-1 d), Q = [w, W d] (w = W e_n): the old columns.
        let u = self.work.kinv.col_as_slice(n).to_vec();
        let w = self.w.col_as_slice(n).to_vec();
        let v = &self.kd;
        let wd = &self.wd;
        for j in 0..size {
            let (uj, vj, wj, wdj) = (u[j], v[j], w[j], wd[j]);
            // K'^-1[:, j] = K^-1[:, j] - u (G P^T)_1j - v (G P^T)_2j.
            let (p1, p2) = (g11 * uj + g12 * vj, g12 * uj + g22 * vj);
            for ((o, &ui), &vi) in self.work.kinv.col_as_slice_mut(j).iter_mut().zip(&u).zip(v) {
                *o -= ui * p1 + vi * p2;
            }
            // W'[:, j] = W[:, j] - u (G Q^T - H P^T)_1j - v (G Q^T - H P^T)_2j - w (G P^T)_1j
            //            - W d (G P^T)_2j.
            let a1 = g11 * wj + g12 * wdj - (h11 * uj + h12 * vj);
            let a2 = g12 * wj + g22 * wdj - (h12 * uj + h22 * vj);
            for ((((o, &ui), &vi), &wi), &wdi) in self
                .w
                .col_as_slice_mut(j)
                .iter_mut()
                .zip(&u)
                .zip(v)
                .zip(&w)
                .zip(wd)
            {
                *o -= ui * a1 + vi * a2 + wi * p1 + wdi * p2;
            }
        }
        // K's row and column n, the point, its scaled axes, the terms.
        for j in 0..size {
            let kj = self.work.k[(j, n)] + self.d[j];
            self.work.k[(j, n)] = kj;
            self.work.k[(n, j)] = kj;
        }
        for (axis, &p) in point.iter().enumerate() {
            self.x[(n, axis)] = p;
            self.z[axis][n] = p / self.params.length_scale().axis(axis);
        }
        self.log_det = t.log_det;
        self.trace = t.trace;
        self.sq = t.sq;
        self.value = value;
        self.updates += 1;
        Ok(true)
    }

    /// The terms of a move of point `n` to `point` (`d`, `K^-1 d` and `W d` left in the
    /// scratch vectors); `None` as [`PointMoves::value_with_point`].
    fn prepare_move(&mut self, n: usize, point: &[f64]) -> Result<Option<MoveTerms>> {
        let (size, q) = (self.x.nrows(), self.x.ncols());
        if n >= size {
            return Err(GpError::IndexOutOfRange {
                what: "moved latent point",
                index: n,
                len: size,
            });
        }
        if point.len() != q {
            return Err(GpError::DimensionMismatch {
                what: "moved latent point's coordinates vs latent dimension q",
                expected: q,
                got: point.len(),
            });
        }
        if let Some((col, &value)) = point.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(GpError::NonFinite {
                what: "moved latent point",
                row: n,
                col,
                value,
            });
        }
        if !self.ready {
            return Ok(None);
        }
        // d = k(point, x_j) - K_jn, with d_n = 0 (the diagonal does not move).
        self.d.resize(size, 0.0);
        self.params.fill_sq_dist(&self.z, point, &mut self.d);
        crate::fastmath::rbf_from_sq_dist_in_place(&mut self.d, self.params.signal_variance());
        for (j, dj) in self.d.iter_mut().enumerate() {
            *dj = if j == n {
                0.0
            } else {
                *dj - self.work.k[(j, n)]
            };
        }
        // K^-1 d and W d, column by column (both symmetric).
        for (out, m) in [(&mut self.kd, &self.work.kinv), (&mut self.wd, &self.w)] {
            out.clear();
            out.resize(size, 0.0);
            for (j, &dj) in self.d.iter().enumerate() {
                if dj != 0.0 {
                    for (o, v) in out.iter_mut().zip(m.col_as_slice(j)) {
                        *o += v * dj;
                    }
                }
            }
        }
        let a = self.work.kinv[(n, n)];
        let b = self.kd[n];
        let c = crate::fastmath::dot(&self.d, &self.kd);
        // |K'| / |K| = (1 + b)^2 - a c, as 1 + (2b + b^2 - a c) for its logarithm.
        let excess = b.mul_add(b + 2.0, -a * c);
        let ratio = 1.0 + excess;
        if !(MIN_DETERMINANT_RATIO..=1.0 / MIN_DETERMINANT_RATIO).contains(&ratio) {
            return Ok(None);
        }
        let z11 = self.w[(n, n)];
        let z12 = self.wd[n];
        let z22 = crate::fastmath::dot(&self.d, &self.wd);
        // tr(M^-1 Z) with det M = -(|K'| / |K|).
        let correction = (c * z11 - 2.0 * (1.0 + b) * z12 + a * z22) / -ratio;
        let old: f64 = (0..q).map(|j| self.x[(n, j)] * self.x[(n, j)]).sum();
        let new: f64 = point.iter().map(|v| v * v).sum();
        Ok(Some(MoveTerms {
            a,
            b,
            c,
            ratio,
            z11,
            z12,
            z22,
            log_det: self.log_det + excess.ln_1p(),
            trace: self.trace - correction,
            sq: self.sq - old + new,
        }))
    }
}

/// The scalars of one move ([`PointMoves::prepare_move`]; module docs).
struct MoveTerms {
    /// `K^-1_nn`, `(K^-1 d)_n`, `d^T K^-1 d`.
    a: f64,
    b: f64,
    c: f64,
    /// `|K'| / |K|`.
    ratio: f64,
    /// `Z = U^T W U`.
    z11: f64,
    z12: f64,
    z22: f64,
    /// The moved state's `log|K'|`, `tr(K'^-1 S)` and `sum |x|^2`.
    log_det: f64,
    trace: f64,
    sq: f64,
}

/// A direct search's objective, `-L(theta)` of a [`FlatGplvm`], that evaluates a `theta`
/// differing from its reference in one latent point by [`PointMoves`] (`O(N^2)`), and in two
/// points (the last accepted move and the next trial, as Hooke-Jeeves makes them) by moving the
/// reference to the first one ([`PointMoves::move_reference`], `O(N^2)`; in full every
/// [`MAX_UPDATES`] moves) and the second from there; anything else (a pattern move, a changed
/// hyperparameter, a `K` that needs jitter or is ill-conditioned) is evaluated in full and
/// becomes the reference. Values equal [`FlatGplvm::neg_log_likelihood`]'s up to rounding.
#[derive(Debug)]
pub struct MoveEvaluator<'f, 'a> {
    flat: &'f FlatGplvm<'a>,
    /// The reference's `theta` and state (`None` before the first full evaluation, or when
    /// its `K` needed jitter).
    reference: Option<(Vec<f64>, PointMoves<'a>)>,
    counts: MoveCounts,
}

/// How a `theta` differs from a [`MoveEvaluator`]'s reference.
enum Change {
    /// Not at all.
    None,
    /// In one latent point.
    One(usize),
    /// In two latent points (in index order).
    Two(usize, usize),
    /// In more, in a hyperparameter, or there is no reference.
    More,
}

/// What a [`MoveEvaluator`] has done.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MoveCounts {
    /// Evaluations in all.
    pub evaluations: u64,
    /// Evaluations without a factorisation: by a move, or of the reference itself.
    pub cheap: u64,
    /// References set up in full (each a factorisation, an inverse and `W`).
    pub references: u64,
    /// References moved to an accepted point by an update ([`PointMoves::move_reference`]).
    pub updates: u64,
}

impl<'f, 'a> MoveEvaluator<'f, 'a> {
    /// An evaluator of `flat` with no reference yet.
    pub fn new(flat: &'f FlatGplvm<'a>) -> Self {
        Self {
            flat,
            reference: None,
            counts: MoveCounts::default(),
        }
    }

    /// What it has done so far.
    pub fn counts(&self) -> MoveCounts {
        self.counts
    }

    /// `-L(theta)`, as [`FlatGplvm::neg_log_likelihood`] (its errors too).
    pub fn neg_log_likelihood(&mut self, theta: &[f64], par: Par) -> Result<f64> {
        self.counts.evaluations += 1;
        if theta.len() != self.flat.len() {
            return self.flat.neg_log_likelihood(theta, par);
        }
        let q = self.flat.q;
        let row = |i: usize| &theta[i * q..(i + 1) * q];
        match self.change_from_reference(theta) {
            Change::None => {
                if let Some((_, moves)) = &self.reference {
                    self.counts.cheap += 1;
                    return Ok(-moves.value());
                }
            }
            Change::One(i) => return self.move_value(theta, i, row(i), par),
            Change::Two(i, j) => {
                // Move the reference to the first changed point (the accepted one): by an
                // update, or in full when the update declines. Then move the second from there.
                if let Some((reference, moves)) = &mut self.reference {
                    let moved = moves.move_reference(i, row(i))?;
                    reference[i * q..(i + 1) * q].copy_from_slice(row(i));
                    if moved {
                        self.counts.updates += 1;
                    } else {
                        let base = reference.clone();
                        if !self.set_reference(&base, par)? {
                            return self.flat.neg_log_likelihood(theta, par);
                        }
                    }
                    return self.move_value(theta, j, row(j), par);
                }
            }
            Change::More => {}
        }
        if self.set_reference(theta, par)?
            && let Some((_, moves)) = &self.reference
        {
            return Ok(-moves.value());
        }
        self.flat.neg_log_likelihood(theta, par)
    }

    /// How `theta` differs from the reference: not at all, in one or two latent points (the
    /// hyperparameters bit for bit equal), or more (or there is no reference).
    fn change_from_reference(&self, theta: &[f64]) -> Change {
        let (n, q) = (self.flat.obj.n(), self.flat.q);
        let Some((reference, _)) = &self.reference else {
            return Change::More;
        };
        if theta[n * q..] != reference[n * q..] {
            return Change::More;
        }
        let mut rows =
            (0..n).filter(|&i| theta[i * q..(i + 1) * q] != reference[i * q..(i + 1) * q]);
        match (rows.next(), rows.next(), rows.next()) {
            (None, _, _) => Change::None,
            (Some(i), None, _) => Change::One(i),
            (Some(i), Some(j), None) => Change::Two(i, j),
            _ => Change::More,
        }
    }

    /// `-L` at the reference with point `i` at `point`; in full when the move declines (or
    /// there is no reference).
    fn move_value(&mut self, theta: &[f64], i: usize, point: &[f64], par: Par) -> Result<f64> {
        if let Some((_, moves)) = &mut self.reference
            && let Some(v) = moves.value_with_point(i, point)?
        {
            self.counts.cheap += 1;
            return Ok(-v);
        }
        self.flat.neg_log_likelihood(theta, par)
    }

    /// Makes `theta` the reference; false (and no reference) when its `K` needs jitter, and
    /// no reference after an error either.
    fn set_reference(&mut self, theta: &[f64], par: Par) -> Result<bool> {
        self.counts.references += 1;
        let reference = self.reference.take();
        let (x, params) = self.flat.unpack(theta)?;
        let moves = match reference {
            Some((_, mut moves)) => moves.reset(x.as_ref(), &params, par)?.then_some(moves),
            None => PointMoves::new(self.flat.obj, x.as_ref(), &params, par)?,
        };
        self.reference = moves.map(|m| (theta.to_vec(), m));
        Ok(self.reference.is_some())
    }
}
