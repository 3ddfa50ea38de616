//! The Gram-matrix kernel of the streaming pass: `G = Y Y^T` over the valid cells of a store,
//! transform and products in f64.
//!
//! Below-horizon cells are skipped before the arithmetic (they hold 0 and contribute nothing), so
//! the work scales with the valid fraction of the grid. Runs of valid indices are transformed
//! straight from the chunk into blocks of [`F64_BLOCK`] indices that stay in the L1 cache, and
//! each block is multiplied into the lower triangle by register tiles (AVX2 + FMA when the CPU
//! has them, selected at run time: panels of 4 rows x up to 12 columns ending at the diagonal;
//! a portable version with 4 x 8 tiles otherwise).
//!
//! (A mixed-precision variant, the transform and the products in f32, summed in f64, was
//! measured and removed: on the default synthetic store it was 1.0x (raw) to 1.2x (log) as
//! fast, and its 3e-9..1e-8 error in the centred Gram matrix moved the fitted log-likelihood by
//! 5.6e-6..5.4e-2; BENCHMARKS.md "gplvm".)

use std::ops::Range;

/// A pointwise transform applied to every stored value before it enters the Gram matrix.
pub trait GramTransform: Sync {
    /// Transformed values in f64: `out[i] = t(input[i])`; called on batches, so an
    /// implementation can vectorise. Implementations panic when the lengths differ.
    fn to_f64(&self, input: &[f32], out: &mut [f64]);
}

/// The identity transform: the Gram matrix of the stored values.
#[derive(Debug, Clone, Copy, Default)]
pub struct Identity;

impl GramTransform for Identity {
    /// Widens the values to f64 (8 lanes with AVX-512, 4 with AVX2, selected at run time).
    fn to_f64(&self, input: &[f32], out: &mut [f64]) {
        assert_eq!(input.len(), out.len(), "Identity::to_f64: lengths differ");
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F (checked just above), the only requirement
                // of a `#[target_feature]` function.
                unsafe { widen_avx512(input, out) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                unsafe { widen_avx2(input, out) };
                return;
            }
        }
        widen(input, out);
    }
}

/// `out[i] = f64::from(input[i])`, the loop every build of [`Identity`] compiles.
#[inline(always)]
fn widen(input: &[f32], out: &mut [f64]) {
    for (o, v) in out.iter_mut().zip(input) {
        *o = f64::from(*v);
    }
}

/// [`widen`] compiled for AVX-512.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn widen_avx512(input: &[f32], out: &mut [f64]) {
    widen(input, out);
}

/// [`widen`] compiled for AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn widen_avx2(input: &[f32], out: &mut [f64]) {
    widen(input, out);
}

/// Per-worker state of a Gram pass: f64 accumulators and the block being filled.
pub(crate) struct GramAccumulator<'t, T: ?Sized> {
    n: usize,
    transform: &'t T,
    /// `np x np` column-major, np = n rounded up to a multiple of 8; the lower triangle is used.
    g: Vec<f64>,
    /// Matrix order of `g` (np).
    size: usize,
    /// The block being filled: transformed values of up to [`F64_BLOCK`] valid indices,
    /// index-major (columns of n values, no padding), plus 8 zeros of slack at the end for the
    /// tiles' over-reads, which only feed the unused rows and columns n..np of g.
    wide: Vec<f64>,
    /// Indices in `wide`.
    filled: usize,
}

impl<'t, T: GramTransform + ?Sized> GramAccumulator<'t, T> {
    /// An empty accumulator for `n` materials, or `None` when its `np x np` matrix cannot be
    /// allocated (the caller names the store).
    pub(crate) fn new(n: usize, transform: &'t T) -> Option<Self> {
        let (size, [g, wide]) = Self::lengths(n);
        Some(Self {
            n,
            transform,
            g: zeroed(usize::try_from(g).ok()?)?,
            size,
            wide: zeroed(usize::try_from(wide).ok()?)?,
            filled: 0,
        })
    }

    /// Bytes one accumulator for `n` materials holds (its matrix and block).
    pub(crate) fn bytes(n: usize) -> u64 {
        let (_, [g, wide]) = Self::lengths(n);
        g.saturating_add(wide).saturating_mul(8)
    }

    /// The matrix order np (n rounded up to a multiple of 8) and the values of the matrix
    /// (np x np) and of the block (F64_BLOCK x n plus 8 of slack), saturating.
    fn lengths(n: usize) -> (usize, [u64; 2]) {
        let size = n.div_ceil(8) * 8;
        let np = size as u64;
        let block = (F64_BLOCK as u64)
            .saturating_mul(n as u64)
            .saturating_add(8);
        (size, [np.saturating_mul(np), block])
    }

    /// Adds one index-major chunk (`block[(d - range.start) * n + m]`) of a store whose
    /// indices come `channels` to a cell: index d carries data when `cell_valid[d / channels]`.
    /// Runs of valid cells are transformed straight from the chunk into the block (one batch
    /// call per run and block); validity is looked up once per cell, not per index.
    pub(crate) fn push_chunk(
        &mut self,
        range: Range<usize>,
        block: &[f32],
        cell_valid: &[bool],
        channels: usize,
    ) {
        let n = self.n;
        let cell_end = |d: usize| ((d / channels + 1) * channels).min(range.end);
        let mut d = range.start;
        while d < range.end {
            if !cell_valid[d / channels] {
                d = cell_end(d);
                continue;
            }
            let mut end = cell_end(d);
            while end < range.end && cell_valid[end / channels] {
                end = cell_end(end);
            }
            while d < end {
                let take = (end - d).min(F64_BLOCK - self.filled);
                let (i, at) = (d - range.start, self.filled * n);
                self.transform.to_f64(
                    &block[i * n..(i + take) * n],
                    &mut self.wide[at..at + take * n],
                );
                self.filled += take;
                d += take;
                if self.filled == F64_BLOCK {
                    // The next block's input streams in while the kernel works on this one.
                    let next = (d - range.start) * n;
                    let ahead =
                        &block[next.min(block.len())..(next + F64_BLOCK * n).min(block.len())];
                    super::prefetch_lines(bytemuck::cast_slice(ahead));
                    self.flush();
                }
            }
        }
    }

    /// Adds the block to the accumulators.
    fn flush(&mut self) {
        if self.filled == 0 {
            return;
        }
        let n = self.n;
        let k = self.filled;
        // The slack after the last column must be zero (a short last block leaves old values).
        self.wide[n * k..n * k + 8].fill(0.0);
        lower_gram_f64(&self.wide, k, n, n.div_ceil(4) * 4, self.size, &mut self.g);
        self.filled = 0;
    }

    /// Merges another worker's accumulators into this one (after flushing both).
    pub(crate) fn merge(mut self, mut other: Self) -> Self {
        self.flush();
        other.flush();
        for (a, b) in self.g.iter_mut().zip(&other.g) {
            *a += b;
        }
        self
    }

    /// The full symmetric n x n matrix, row-major.
    pub(crate) fn finish(mut self) -> Vec<f64> {
        self.flush();
        let n = self.n;
        let mut out = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..=i {
                let v = self.g[j * self.size + i];
                out[i * n + j] = v;
                out[j * n + i] = v;
            }
        }
        out
    }
}

/// `len` zeros, or `None` when they cannot be allocated.
fn zeroed(len: usize) -> Option<Vec<f64>> {
    let mut v = Vec::new();
    v.try_reserve_exact(len).ok()?;
    v.resize(len, 0.0);
    Some(v)
}

/// Indices per block of the f64 kernel: 48 x 56 f64 values (21 KiB) stay in the L1 cache.
pub const F64_BLOCK: usize = 48;

/// Adds the lower triangle of `A A^T` to `g` in f64, where `A` has k columns starting every `ld`
/// values of `a` and `g` is `np x np` column-major (`np` a multiple of 8). Computed by tiles of
/// 4 or 8 rows over rows `0..rows` (`rows` a multiple of 4, <= np); a tile reads up
/// to row `max(rows, np) - 1` of a column, i.e. into the next column or the slack after the last
/// one when `ld` is smaller: those values only reach rows/columns of g beyond the caller's
/// matrix, and entries above the diagonal inside a tile are written too and are ignored.
///
/// Every build (AVX-512, AVX2 + FMA, portable) computes each entry the same way: one chain of
/// fused multiply-adds over the k columns in order, added to `g` at the end, so the result has
/// the same bits on every CPU (the fits are chaotic in the last bits of the Gram matrix).
fn lower_gram_f64(a: &[f64], k: usize, ld: usize, rows: usize, np: usize, g: &mut [f64]) {
    assert!(np.is_multiple_of(8) && rows.is_multiple_of(4) && rows <= np && g.len() >= np * np);
    assert!(k == 0 || (ld > 0 && a.len() >= (k - 1) * ld + np));
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked above; it implies AVX2 and FMA); the
            // slice lengths and shape conditions the kernel relies on are asserted above.
            unsafe { x86::lower_gram_f64_avx512(a, k, ld, rows, np, g) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked above); the slice lengths and
            // shape conditions the kernel relies on are asserted above.
            unsafe { x86::lower_gram_f64_avx2(a, k, ld, rows, np, g) };
            return;
        }
    }
    lower_gram_f64_portable(a, k, ld, rows, np, g);
}

/// Portable version of [`lower_gram_f64`] (4 x 8 tiles, scalar fused multiply-adds).
fn lower_gram_f64_portable(a: &[f64], k: usize, ld: usize, rows: usize, np: usize, g: &mut [f64]) {
    for rb in 0..rows / 4 {
        for jb in 0..(4 * rb + 4).div_ceil(8) {
            let mut acc = [[0f64; 4]; 8];
            for c in 0..k {
                let col = &a[c * ld..c * ld + np];
                let r = &col[rb * 4..rb * 4 + 4];
                for (jj, acc_j) in acc.iter_mut().enumerate() {
                    let b = col[jb * 8 + jj];
                    for (x, v) in acc_j.iter_mut().zip(r) {
                        *x = v.mul_add(b, *x);
                    }
                }
            }
            for (jj, acc_j) in acc.iter().enumerate() {
                let dst = &mut g[(jb * 8 + jj) * np + rb * 4..][..4];
                for (x, v) in dst.iter_mut().zip(acc_j) {
                    *x += v;
                }
            }
        }
    }
}

/// Widths, in blocks of columns, of the tiles that cover `blocks` blocks of a row panel: 3 at
/// a time (the widest tile), ending in 2 + 2 rather than 3 + 1, so only a one-block panel
/// has a one-block tile (too few accumulators to hide the FMA latency).
fn tile_widths(blocks: usize) -> impl Iterator<Item = usize> {
    let mut left = blocks;
    std::iter::from_fn(move || {
        let w = match left {
            0 => return None,
            1 | 2 => left,
            4 => 2,
            _ => 3,
        };
        left -= w;
        Some(w)
    })
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::tile_widths;

    /// AVX2 + FMA kernel of `lower_gram_f64`. Row panels of 4 rows (`i0 = 4 rb`, one ymm);
    /// each panel's columns `0..i0 + 4` go in tiles of 4, 8 or 12 columns ([`tile_widths`]:
    /// up to 12 broadcasts x 1 ymm = 12 accumulators, enough to hide the FMA latency at two
    /// FMAs per cycle, and 14 registers in all, so nothing spills). Ending each panel at its
    /// diagonal wastes only the 4 x 4 diagonal blocks' upper halves (about 9 % extra work for
    /// n = 51, against 18 % for square 4 x 8 tiles).
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA; `np % 8 == 0`, `rows % 4 == 0`, `rows <= np`,
    /// `a.len() >= (k - 1) * ld + np` (when k > 0) and `g.len() >= np * np`.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn lower_gram_f64_avx2(
        a: &[f64],
        k: usize,
        ld: usize,
        rows: usize,
        np: usize,
        g: &mut [f64],
    ) {
        let (base, g) = (a.as_ptr(), g.as_mut_ptr());
        for i0 in (0..rows).step_by(4) {
            // SAFETY: forwarded contract; i0 + 4 <= rows.
            unsafe { panel4(base, k, ld, i0, np, g) };
        }
    }

    /// AVX-512 kernel of `lower_gram_f64`: row panels of 8 rows (one zmm) whose columns
    /// `0..i0 + 8` go in tiles of 8, 16 or 24 columns (up to 24 accumulators of the 32
    /// registers; the column values are broadcast from memory by the FMAs themselves), half
    /// the instructions of the AVX2 kernel for the same arithmetic. The diagonal 8 x 8 block
    /// goes in two ymm halves ([`diagonal8`]: its lower triangle with 4 x 4 blocks, as the AVX2
    /// kernel computes it); a last panel of 4 rows (`rows % 8 == 4`) takes the AVX2 kernel's
    /// 4-row panel instead of wasting a zmm's upper half on padding.
    ///
    /// # Safety
    /// As [`lower_gram_f64_avx2`], and the CPU must support AVX-512F.
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub(super) unsafe fn lower_gram_f64_avx512(
        a: &[f64],
        k: usize,
        ld: usize,
        rows: usize,
        np: usize,
        g: &mut [f64],
    ) {
        let (base, g) = (a.as_ptr(), g.as_mut_ptr());
        let mut i0 = 0;
        while i0 < rows {
            // SAFETY: forwarded contract; an 8-row panel has i0 + 8 <= rows, a 4-row one
            // i0 + 4 <= rows (rows is a multiple of 4).
            unsafe {
                if i0 + 8 <= rows {
                    let mut j0 = 0;
                    for w in tile_widths(i0 / 8) {
                        match w {
                            1 => tile::<__m512d, 8, 1>(base, k, ld, i0, j0, np, g),
                            2 => tile::<__m512d, 8, 2>(base, k, ld, i0, j0, np, g),
                            _ => tile::<__m512d, 8, 3>(base, k, ld, i0, j0, np, g),
                        }
                        j0 += 8 * w;
                    }
                    diagonal8(base, k, ld, i0, np, g);
                    i0 += 8;
                } else {
                    panel4(base, k, ld, i0, np, g);
                    i0 += 4;
                }
            }
        }
    }

    /// The lower half of the diagonal 8 x 8 block at `i0` as two ymm row halves: rows
    /// `i0..i0 + 4` x columns `i0..i0 + 4` and rows `i0 + 4..i0 + 8` x columns `i0..i0 + 8`,
    /// 12 accumulators and 48 products per column of `a` instead of a zmm tile's 64.
    ///
    /// # Safety
    /// As [`lower_gram_f64_avx512`], and `i0 + 8 <= rows`.
    #[inline(always)]
    unsafe fn diagonal8(base: *const f64, k: usize, ld: usize, i0: usize, np: usize, g: *mut f64) {
        type V = __m256d;
        // SAFETY: the CPU supports AVX2 + FMA (caller); reads at c * ld + x with x < i0 + 8
        // <= rows, writes at columns < i0 + 8 <= np, rows < i0 + 8 <= np.
        unsafe {
            let mut top = [V::zero(); 4];
            let mut bottom = [V::zero(); 8];
            for c in 0..k {
                let col = base.add(c * ld + i0);
                let (r0, r1) = (V::load(col), V::load(col.add(4)));
                for (jj, (t, b)) in top.iter_mut().zip(&mut bottom[..4]).enumerate() {
                    let x = V::splat(col.add(jj));
                    *t = V::fma(r0, x, *t);
                    *b = V::fma(r1, x, *b);
                }
                for (jj, b) in bottom[4..].iter_mut().enumerate() {
                    *b = V::fma(r1, V::splat(col.add(4 + jj)), *b);
                }
            }
            for (jj, v) in top.iter().enumerate() {
                v.add_into(g.add((i0 + jj) * np + i0));
            }
            for (jj, v) in bottom.iter().enumerate() {
                v.add_into(g.add((i0 + jj) * np + i0 + 4));
            }
        }
    }

    /// The 4-row panel at `i0`: columns `0..i0 + 4` in tiles of 4, 8 or 12.
    ///
    /// # Safety
    /// As [`lower_gram_f64_avx2`] (AVX2 + FMA), and `i0 + 4 <= rows`.
    #[inline(always)]
    unsafe fn panel4(base: *const f64, k: usize, ld: usize, i0: usize, np: usize, g: *mut f64) {
        let mut j0 = 0;
        for w in tile_widths(i0 / 4 + 1) {
            // SAFETY: forwarded contract; j0 + 4 w <= i0 + 4 <= rows.
            unsafe {
                match w {
                    1 => tile::<__m256d, 4, 1>(base, k, ld, i0, j0, np, g),
                    2 => tile::<__m256d, 4, 2>(base, k, ld, i0, j0, np, g),
                    _ => tile::<__m256d, 4, 3>(base, k, ld, i0, j0, np, g),
                }
            }
            j0 += 4 * w;
        }
    }

    /// A vector of f64 lanes as the tiles use it: `__m256d` (AVX2 + FMA) or `__m512d`
    /// (AVX-512F). Every method is inlined into a function compiled with its feature.
    ///
    /// # Safety
    /// Every method may only run on a CPU with the vector type's features (AVX2 + FMA, or
    /// AVX-512F), i.e. inside a function compiled with them after a run-time check; `load`,
    /// `splat` and `add_into` additionally need `p` valid for `N` (`splat`: 1) `f64` reads,
    /// resp. reads and writes.
    trait Lanes: Copy {
        /// Lanes per vector: rows of a tile.
        const N: usize;
        /// All lanes zero.
        unsafe fn zero() -> Self;
        /// `N` values from `p` (unaligned).
        unsafe fn load(p: *const f64) -> Self;
        /// `*p` in every lane.
        unsafe fn splat(p: *const f64) -> Self;
        /// `a * b + c`, fused.
        unsafe fn fma(a: Self, b: Self, c: Self) -> Self;
        /// `p[..N] += self`.
        unsafe fn add_into(self, p: *mut f64);
    }

    /// Implements [`Lanes`] for one vector type from its intrinsics.
    macro_rules! lanes {
        ($t:ty, $n:expr, $zero:ident, $load:ident, $splat:ident, $fma:ident, $add:ident, $store:ident) => {
            impl Lanes for $t {
                const N: usize = $n;
                #[inline(always)]
                unsafe fn zero() -> Self {
                    // SAFETY: the caller runs with the vector's CPU features.
                    unsafe { $zero() }
                }
                #[inline(always)]
                unsafe fn load(p: *const f64) -> Self {
                    // SAFETY: as above, and `p` is valid for `N` values.
                    unsafe { $load(p) }
                }
                #[inline(always)]
                unsafe fn splat(p: *const f64) -> Self {
                    // SAFETY: as above, and `p` is valid (a broadcast from memory, which the
                    // FMA takes as its memory operand).
                    unsafe { $splat(*p) }
                }
                #[inline(always)]
                unsafe fn fma(a: Self, b: Self, c: Self) -> Self {
                    // SAFETY: the caller runs with the vector's CPU features.
                    unsafe { $fma(a, b, c) }
                }
                #[inline(always)]
                unsafe fn add_into(self, p: *mut f64) {
                    // SAFETY: as above, and `p` is valid for reading and writing `N` values.
                    unsafe { $store(p, $add($load(p), self)) }
                }
            }
        };
    }
    lanes!(
        __m256d,
        4,
        _mm256_setzero_pd,
        _mm256_loadu_pd,
        _mm256_set1_pd,
        _mm256_fmadd_pd,
        _mm256_add_pd,
        _mm256_storeu_pd
    );
    lanes!(
        __m512d,
        8,
        _mm512_setzero_pd,
        _mm512_loadu_pd,
        _mm512_set1_pd,
        _mm512_fmadd_pd,
        _mm512_add_pd,
        _mm512_storeu_pd
    );

    /// One tile: rows `i0..i0 + W`, columns `j0..j0 + W C` (W = the vector's lanes), each entry
    /// one FMA chain over the k columns of `a` in order, then added to `g`.
    ///
    /// # Safety
    /// The CPU supports `V`'s instructions; `W == V::N`; the shape contract of
    /// [`lower_gram_f64_avx2`] with `i0 + W <= rows` and `j0 + W C <= rows`, so that every read
    /// is at c * ld + x with c < k and x < rows <= np, inside a[..(k - 1) * ld + np], and every
    /// write at a column j < rows <= np, rows i0 .. i0 + W <= np of g[..np * np].
    #[inline(always)]
    unsafe fn tile<V: Lanes, const W: usize, const C: usize>(
        base: *const f64,
        k: usize,
        ld: usize,
        i0: usize,
        j0: usize,
        np: usize,
        g: *mut f64,
    ) {
        debug_assert_eq!(W, V::N);
        // SAFETY: as documented above.
        unsafe {
            let mut acc = [[V::zero(); W]; C];
            for c in 0..k {
                let col = base.add(c * ld);
                let r = V::load(col.add(i0));
                for (x, acc_x) in acc.iter_mut().enumerate() {
                    for (jj, v) in acc_x.iter_mut().enumerate() {
                        *v = V::fma(r, V::splat(col.add(j0 + W * x + jj)), *v);
                    }
                }
            }
            for (x, acc_x) in acc.iter().enumerate() {
                for (jj, v) in acc_x.iter().enumerate() {
                    v.add_into(g.add((j0 + W * x + jj) * np + i0));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pseudo_random(len: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        (0..len)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                // Values over three decades, like BRDFs.
                let u = (s >> 11) as f64 / (1u64 << 53) as f64;
                (10f64.powf(3.0 * u - 1.0)) as f32
            })
            .collect()
    }

    fn reference(n: usize, values: &[f32], valid: impl Fn(usize) -> bool) -> Vec<f64> {
        let mut g = vec![0.0; n * n];
        for (d, row) in values.chunks_exact(n).enumerate() {
            if valid(d) {
                for i in 0..n {
                    for j in 0..n {
                        g[i * n + j] += f64::from(row[i]) * f64::from(row[j]);
                    }
                }
            }
        }
        g
    }

    #[test]
    fn an_accumulator_too_large_to_allocate_is_none() {
        // 1.2e9 materials: 1.15e19 bytes, beyond any address space (refused without
        // allocating).
        let n = 1_200_000_000;
        assert!(GramAccumulator::new(n, &Identity).is_none());
        let bytes = GramAccumulator::<Identity>::bytes(n) as f64;
        assert!((1.15e19..1.16e19).contains(&bytes), "{bytes}");
        // Sizes beyond u64 saturate.
        assert_eq!(GramAccumulator::<Identity>::bytes(usize::MAX / 2), u64::MAX);
        // An ordinary one: 56 x 56 matrix, block of F64_BLOCK x 51 values and 8 of slack.
        let acc = GramAccumulator::new(51, &Identity).unwrap();
        assert_eq!((acc.g.len(), acc.wide.len()), (56 * 56, F64_BLOCK * 51 + 8));
        assert_eq!(
            GramAccumulator::<Identity>::bytes(51),
            8 * (56 * 56 + F64_BLOCK as u64 * 51 + 8)
        );
    }

    fn run(n: usize, values: &[f32], chunk: usize) -> Vec<f64> {
        // Cells of 3 indices, every seventh invalid.
        let cells: Vec<bool> = (0..values.len().div_ceil(3 * n))
            .map(|c| c % 7 != 3)
            .collect();
        let mut acc = GramAccumulator::new(n, &Identity).unwrap();
        let d = values.len() / n;
        let mut other = GramAccumulator::new(n, &Identity).unwrap();
        for start in (0..d).step_by(chunk) {
            let end = (start + chunk).min(d);
            let target = if start < d / 2 { &mut acc } else { &mut other };
            target.push_chunk(start..end, &values[start * n..end * n], &cells, 3);
        }
        acc.merge(other).finish()
    }

    fn max_rel(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs() / y.abs().max(1e-300))
            .fold(0.0, f64::max)
    }

    #[test]
    fn matches_a_direct_f64_sum() {
        for n in [1, 5, 8, 13, 51] {
            let d = 1000;
            let values = pseudo_random(n * d, n as u64);
            let want = reference(n, &values, |d| (d / 3) % 7 != 3);
            // chunks of 97 indices split between two workers, blocks of F64_BLOCK valid ones.
            let got = run(n, &values, 97);
            assert!(max_rel(&got, &want) < 1e-13, "n = {n}");
            for i in 0..n {
                for j in 0..n {
                    assert_eq!(got[i * n + j], got[j * n + i]);
                }
            }
        }
    }

    /// Every build of the kernel gives the same bits (one FMA chain per entry), for panels
    /// ending on 8- and 4-row boundaries; each vector build is checked where the CPU has it.
    #[test]
    fn simd_and_portable_f64_kernels_agree_bitwise() {
        for (np, rows, k) in [(56, 52, 48), (56, 56, 47), (8, 4, 3), (16, 16, 1)] {
            let a: Vec<f64> = pseudo_random(np * k, 5)
                .iter()
                .map(|v| f64::from(*v))
                .collect();
            let lower = |g: &[f64]| {
                let mut v = Vec::new();
                for j in 0..rows {
                    for i in j..rows {
                        v.push(g[j * np + i].to_bits());
                    }
                }
                v
            };
            let mut g = vec![0.5; np * np];
            lower_gram_f64_portable(&a, k, np, rows, np, &mut g);
            for j in 0..rows {
                for i in j..rows {
                    let want: f64 =
                        0.5 + (0..k).map(|c| a[c * np + i] * a[c * np + j]).sum::<f64>();
                    let x = g[j * np + i];
                    assert!(
                        (x - want).abs() <= 1e-13 * want,
                        "({i}, {j}): {x} vs {want}"
                    );
                }
            }
            let want = lower(&g);
            let mut builds: Vec<(&str, Vec<f64>)> = Vec::new();
            let mut g = vec![0.5; np * np];
            lower_gram_f64(&a, k, np, rows, np, &mut g);
            builds.push(("dispatched", g));
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx512f") {
                    let mut g = vec![0.5; np * np];
                    // SAFETY: the CPU supports AVX-512F; shapes as the kernel requires.
                    unsafe { x86::lower_gram_f64_avx512(&a, k, np, rows, np, &mut g) };
                    builds.push(("AVX-512", g));
                }
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    let mut g = vec![0.5; np * np];
                    // SAFETY: the CPU supports AVX2 and FMA; shapes as the kernel requires.
                    unsafe { x86::lower_gram_f64_avx2(&a, k, np, rows, np, &mut g) };
                    builds.push(("AVX2", g));
                }
            }
            for (name, g) in builds {
                assert!(
                    lower(&g) == want,
                    "{name} differs from the portable kernel ({np}, {rows}, {k})"
                );
            }
        }
    }

    #[test]
    fn tile_widths_cover_the_panel_with_wide_tiles() {
        for blocks in 0..20 {
            let w: Vec<usize> = tile_widths(blocks).collect();
            assert_eq!(w.iter().sum::<usize>(), blocks);
            assert!(w.iter().all(|&x| (1..=3).contains(&x)));
            assert!(blocks <= 1 || w.iter().all(|&x| x >= 2), "{blocks}: {w:?}");
        }
    }

    #[test]
    fn unpadded_columns_give_the_same_matrix() {
        // ld = n = 51 with 8 values of slack, as the accumulator calls it.
        let (n, np, k) = (51, 56, 48);
        let mut a: Vec<f64> = pseudo_random(n * k, 7)
            .iter()
            .map(|v| f64::from(*v))
            .collect();
        a.extend([0.0; 8]);
        let mut g1 = vec![0.0; np * np];
        let mut g2 = vec![0.0; np * np];
        lower_gram_f64(&a, k, n, 52, np, &mut g1);
        lower_gram_f64_portable(&a, k, n, 52, np, &mut g2);
        for j in 0..n {
            for i in j..n {
                let want: f64 = (0..k).map(|c| a[c * n + i] * a[c * n + j]).sum();
                for got in [g1[j * np + i], g2[j * np + i]] {
                    assert!((got - want).abs() <= 1e-13 * want, "({i}, {j})");
                }
            }
        }
    }

    #[test]
    fn transform_is_applied() {
        struct Square;
        impl GramTransform for Square {
            fn to_f64(&self, input: &[f32], out: &mut [f64]) {
                for (o, v) in out.iter_mut().zip(input) {
                    *o = f64::from(*v) * f64::from(*v);
                }
            }
        }
        let n = 9;
        let values = pseudo_random(n * 300, 9);
        let squared: Vec<f64> = values
            .iter()
            .map(|v| f64::from(*v) * f64::from(*v))
            .collect();
        let mut want = vec![0.0; n * n];
        for row in squared.chunks_exact(n) {
            for i in 0..n {
                for j in 0..n {
                    want[i * n + j] += row[i] * row[j];
                }
            }
        }
        let mut acc = GramAccumulator::new(n, &Square).unwrap();
        acc.push_chunk(0..300, &values, &[true; 300], 1);
        assert!(max_rel(&acc.finish(), &want) < 1e-13);
    }
}
