//! A vectorisable `exp` for kernel matrices: the RBF kernel needs N(N-1)/2 exponentials per
//! evaluation of the GPLVM objective, which the C library computes one call at a time.

/// `e^x` with relative error below 5e-16 (about two units in the last place) for
/// `-708 <= x <= 709` (tested against [`f64::exp`]), free of calls and branches so loops over
/// it vectorise: `x = k ln 2 + r` (Cody-Waite), a degree-13 Taylor polynomial for `e^r`
/// (|r| <= ln 2 / 2), and `2^k` built from its exponent bits (via the mantissa of
/// `2^52 + k + 1023`: AVX2 has no f64 -> i64 conversion). Returns 0 below -708 (where `e^x` is
/// subnormal) and infinity above 709.78.
#[inline(always)]
pub fn exp_lanes(x: f64) -> f64 {
    const LN2_HI: f64 = 6.931_471_803_691_238e-1;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    const MAX: f64 = 709.782_712_893_384;
    let xc = x.clamp(-708.0, MAX);
    let k = (xc * std::f64::consts::LOG2_E).round_ties_even();
    let r = (xc - k * LN2_HI) - k * LN2_LO;
    // sum_{j <= 13} r^j / j! by Estrin's scheme (pairs, then r^2, r^4, r^8): a dependency
    // chain of ~6 operations instead of Horner's 13 steps, so consecutive values overlap.
    let (r2, f) = (r * r, &FACT_INV);
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let a0 = 1.0 + r;
    let a1 = f[2] + r * f[3];
    let a2 = f[4] + r * f[5];
    let a3 = f[6] + r * f[7];
    let a4 = f[8] + r * f[9];
    let a5 = f[10] + r * f[11];
    let a6 = f[12] + r * f[13];
    let b0 = a0 + r2 * a1;
    let b1 = a2 + r2 * a3;
    let b2 = a4 + r2 * a5;
    let e = (b0 + r4 * b1) + r8 * (b2 + r4 * a6);
    // 2^(k - 1) times 2 (k + 1022 stays in 0..=2046 for k in -1022..=1024).
    let biased = (k + (1022.0 + TWO_52)).to_bits() & 0x000f_ffff_ffff_ffff;
    let v = (e * f64::from_bits(biased << 52)) * 2.0;
    if x < -708.0 {
        0.0
    } else if x > MAX {
        f64::INFINITY
    } else {
        v
    }
}

/// 1/k! for k = 0..=13: the Taylor coefficients of `e^r` in [`exp_lanes`] (and, from k = 1,
/// of `(e^y - 1) / y` in gplvm's transforms).
pub const FACT_INV: [f64; 14] = [
    1.0,
    1.0,
    1.0 / 2.0,
    1.0 / 6.0,
    1.0 / 24.0,
    1.0 / 120.0,
    1.0 / 720.0,
    1.0 / 5040.0,
    1.0 / 40320.0,
    1.0 / 362_880.0,
    1.0 / 3_628_800.0,
    1.0 / 39_916_800.0,
    1.0 / 479_001_600.0,
    1.0 / 6_227_020_800.0,
];

/// 1/k for k = 0..=15 (0 unused): Taylor coefficients of the polynomials here and in
/// gplvm's transforms.
pub const INV: [f64; 16] = [
    0.0,
    1.0,
    1.0 / 2.0,
    1.0 / 3.0,
    1.0 / 4.0,
    1.0 / 5.0,
    1.0 / 6.0,
    1.0 / 7.0,
    1.0 / 8.0,
    1.0 / 9.0,
    1.0 / 10.0,
    1.0 / 11.0,
    1.0 / 12.0,
    1.0 / 13.0,
    1.0 / 14.0,
    1.0 / 15.0,
];

/// `sum_i a_i b_i` with four independent partial sums, so the loop vectorises instead of
/// waiting on the latency of every addition (`b` may be f32 or f64; the result does not depend
/// on the CPU: the same operations in the same order everywhere).
///
/// `a` and `b` must have the same length (checked in debug builds; in release builds the
/// longer one's extra elements would be ignored).
#[inline(always)]
pub fn dot<T: Copy + Into<f64>>(a: &[f64], b: &[T]) -> f64 {
    debug_assert_eq!(
        a.len(),
        b.len(),
        "fastmath::dot of slices of different lengths"
    );
    let mut part = [0f64; 4];
    let (ac, bc) = (a.chunks_exact(4), b.chunks_exact(4));
    let rest: f64 = ac
        .remainder()
        .iter()
        .zip(bc.remainder())
        .map(|(x, y)| x * (*y).into())
        .sum();
    for (x, y) in ac.zip(bc) {
        for k in 0..4 {
            part[k] += x[k] * y[k].into();
        }
    }
    (part[0] + part[1]) + (part[2] + part[3]) + rest
}

/// Partial sums of [`dot_wide`].
pub const WIDE_PARTS: usize = 32;

/// `sum_i a_i b_i` with [`WIDE_PARTS`] = 32 partial sums: product `i` (multiply, then add) into
/// sum `i mod 32`, in order of `i`; the sums then combined by halving, `p_k += p_(k + w)` for
/// w = 16, 8, 4, 2, 1. For dot products on a critical path: [`dot`]'s four chains wait on the
/// latency of their additions (~4 cycles each, 64 in a row at 255 values), these eight 4-lane
/// (four 8-lane) vectors do not. Plain element-wise arithmetic in a fixed order, so a build
/// with AVX2 or AVX-512 enabled (the caller's `#[target_feature]` function inlines it; the
/// compiler vectorises the loops without reordering anything) has the same bits as the
/// portable one.
///
/// `a` and `b` must have the same length (checked in debug builds; in release builds the
/// longer one's extra elements are ignored).
#[inline(always)]
pub fn dot_wide(a: &[f64], b: &[f64]) -> f64 {
    debug_assert_eq!(
        a.len(),
        b.len(),
        "fastmath::dot_wide of slices of different lengths"
    );
    let mut part = [0f64; WIDE_PARTS];
    let (mut ac, mut bc) = (a.chunks_exact(WIDE_PARTS), b.chunks_exact(WIDE_PARTS));
    for (x, y) in (&mut ac).zip(&mut bc) {
        let (x, y): (&[f64; WIDE_PARTS], &[f64; WIDE_PARTS]) =
            (x.try_into().unwrap(), y.try_into().unwrap());
        for k in 0..WIDE_PARTS {
            part[k] += x[k] * y[k];
        }
    }
    for ((p, x), y) in part.iter_mut().zip(ac.remainder()).zip(bc.remainder()) {
        *p += x * y;
    }
    halve_parts(&mut part)
}

/// `y += a x`, then [`dot_wide`]`(z, y)` of the updated `y`, in one pass (the same bits as
/// the two steps: each product is taken as the element is updated, into the same partial sum).
/// For recursions where each dot product waits on the update before it (the L-BFGS two-loop
/// recursion): `y` is read and written once instead of twice.
///
/// The three slices must have the same length (checked in debug builds; in release builds the
/// longer ones' extra elements are ignored).
#[inline(always)]
pub fn axpy_then_dot_wide(a: f64, x: &[f64], y: &mut [f64], z: &[f64]) -> f64 {
    debug_assert!(
        x.len() == y.len() && z.len() == y.len(),
        "fastmath::axpy_then_dot_wide of slices of different lengths"
    );
    let mut part = [0f64; WIDE_PARTS];
    let (mut xc, mut yc, mut zc) = (
        x.chunks_exact(WIDE_PARTS),
        y.chunks_exact_mut(WIDE_PARTS),
        z.chunks_exact(WIDE_PARTS),
    );
    for ((x, y), z) in (&mut xc).zip(&mut yc).zip(&mut zc) {
        let (x, y, z): (
            &[f64; WIDE_PARTS],
            &mut [f64; WIDE_PARTS],
            &[f64; WIDE_PARTS],
        ) = (
            x.try_into().unwrap(),
            y.try_into().unwrap(),
            z.try_into().unwrap(),
        );
        for k in 0..WIDE_PARTS {
            y[k] += a * x[k];
            part[k] += z[k] * y[k];
        }
    }
    for (((p, x), y), z) in part
        .iter_mut()
        .zip(xc.remainder())
        .zip(yc.into_remainder())
        .zip(zc.remainder())
    {
        *y += a * x;
        *p += z * *y;
    }
    halve_parts(&mut part)
}

/// The sum of [`dot_wide`]'s partial sums, by halving.
#[inline(always)]
fn halve_parts(part: &mut [f64; WIDE_PARTS]) -> f64 {
    let mut width = WIDE_PARTS / 2;
    while width > 0 {
        for k in 0..width {
            part[k] += part[k + width];
        }
        width /= 2;
    }
    part[0]
}

/// Whether a computed sum of squares is usable as it is: finite and far enough above the
/// subnormal range that no square in it underflowed to matter (else [`norm`]'s rescaled path).
pub fn is_safe_sum_of_squares(squares: f64) -> bool {
    squares.is_finite() && squares >= f64::MIN_POSITIVE / f64::EPSILON
}

/// Euclidean norm of `v` that neither overflows nor underflows: `sqrt(dot(v, v))` (the same
/// bits) when that sum of squares is a normal number, otherwise the norm of `v` divided by its
/// largest magnitude, times that magnitude. NaN if `v` has a NaN, infinity if it has an
/// infinity.
pub fn norm(v: &[f64]) -> f64 {
    let squares = dot(v, v);
    if squares.is_nan() || is_safe_sum_of_squares(squares) {
        return squares.sqrt();
    }
    let largest = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if largest == 0.0 || largest.is_infinite() {
        return largest;
    }
    let scaled: Vec<f64> = v.iter().map(|x| x / largest).collect();
    largest * dot(&scaled, &scaled).sqrt()
}

/// [`dot`] in explicit 4-lane AVX2 vectors, with `dot`'s arithmetic exactly (lane k sums the
/// products of elements 4j + k, multiply then add; lanes and remainder combined as there), so
/// the result has the same bits. The compiler's own vectorisation of `dot` uses 2-lane halves
/// and shuffles; this is one 4-lane chain (~2.5x faster on a 255-value dot).
///
/// # Safety
/// The CPU must support AVX2 and FMA. `a` and `b` must have the same length (checked in debug
/// builds; in release builds the longer one's extra elements are ignored).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
pub unsafe fn dot_avx2<T: Lanes>(a: &[f64], b: &[T]) -> f64 {
    use std::arch::x86_64::{_mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_setzero_pd};
    debug_assert_eq!(
        a.len(),
        b.len(),
        "fastmath::dot_avx2 of slices of different lengths"
    );
    let n = a.len().min(b.len());
    let n4 = n / 4 * 4;
    let rest: f64 = a[n4..n]
        .iter()
        .zip(&b[n4..n])
        .map(|(x, y)| x * (*y).into())
        .sum();
    let mut acc = _mm256_setzero_pd();
    let mut j = 0;
    while j < n4 {
        // SAFETY: j + 4 <= n4 <= n <= both lengths, so both 4-value loads are in bounds; AVX2
        // is available (this function's contract).
        let (x, y) = unsafe {
            (
                _mm256_loadu_pd(a.as_ptr().add(j)),
                T::load4(b.as_ptr().add(j)),
            )
        };
        acc = _mm256_add_pd(acc, _mm256_mul_pd(x, y));
        j += 4;
    }
    // SAFETY: a __m256d is 4 f64.
    let p: [f64; 4] = unsafe { std::mem::transmute(acc) };
    (p[0] + p[1]) + (p[2] + p[3]) + rest
}

/// [`dot_avx2`] of `a` with each of `R` consecutive rows of `a.len()` values at the start of
/// `rows`, the rows' chains interleaved: each row's arithmetic is `dot_avx2`'s exactly, so each
/// result has the same bits, but R additions are in flight instead of one (a dot of 51 values
/// waits on 13 dependent additions).
///
/// # Safety
/// The CPU must support AVX2 and FMA. `rows` must hold at least `R * a.len()` values (checked:
/// a panic otherwise).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
pub unsafe fn dot_rows_avx2<T: Lanes, const R: usize>(a: &[f64], rows: &[T]) -> [f64; R] {
    use std::arch::x86_64::{_mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_setzero_pd};
    let n = a.len();
    let rows = &rows[..R * n];
    let n4 = n / 4 * 4;
    let mut acc = [_mm256_setzero_pd(); R];
    let mut j = 0;
    while j < n4 {
        // SAFETY: j + 4 <= n4 <= n = a.len(); AVX2 is available (this function's contract).
        let x = unsafe { _mm256_loadu_pd(a.as_ptr().add(j)) };
        for (r, acc) in acc.iter_mut().enumerate() {
            // SAFETY: r * n + j + 4 <= R * n = rows.len() (sliced above).
            let y = unsafe { T::load4(rows.as_ptr().add(r * n + j)) };
            *acc = _mm256_add_pd(*acc, _mm256_mul_pd(x, y));
        }
        j += 4;
    }
    let mut out = [0.0; R];
    for (r, (o, acc)) in out.iter_mut().zip(acc).enumerate() {
        let row = &rows[r * n..(r + 1) * n];
        let rest: f64 = a[n4..]
            .iter()
            .zip(&row[n4..])
            .map(|(x, y)| x * (*y).into())
            .sum();
        // SAFETY: a __m256d is 4 f64.
        let p: [f64; 4] = unsafe { std::mem::transmute(acc) };
        *o = (p[0] + p[1]) + (p[2] + p[3]) + rest;
    }
    out
}

/// Value types [`dot_avx2`] reads as f64 lanes (f64 itself, and f32 widened exactly).
pub trait Lanes: Copy + Into<f64> {
    /// The 4 values at `ptr`, widened to f64.
    ///
    /// # Safety
    /// `ptr` must be valid for reading 4 values, and the CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    unsafe fn load4(ptr: *const Self) -> std::arch::x86_64::__m256d;
}

impl Lanes for f32 {
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn load4(ptr: *const Self) -> std::arch::x86_64::__m256d {
        use std::arch::x86_64::{_mm_loadu_ps, _mm256_cvtps_pd};
        // SAFETY: the caller guarantees 4 readable values and AVX2.
        unsafe { _mm256_cvtps_pd(_mm_loadu_ps(ptr)) }
    }
}

impl Lanes for f64 {
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn load4(ptr: *const Self) -> std::arch::x86_64::__m256d {
        // SAFETY: the caller guarantees 4 readable values and AVX2.
        unsafe { std::arch::x86_64::_mm256_loadu_pd(ptr) }
    }
}

/// `v = s e^(-v / 2)` in place (RBF values from squared scaled distances), 8 lanes wide with
/// AVX-512 or 4 with AVX2 + FMA when the CPU has them (selected at run time), the same
/// arithmetic, so the same bits, otherwise.
pub fn rbf_from_sq_dist_in_place(values: &mut [f64], s: f64) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above; it implies AVX2 and FMA),
            // the only requirement of a `#[target_feature]` function.
            unsafe { rbf_avx512(values, s) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above), the only requirement
            // of a `#[target_feature]` function.
            unsafe { rbf_avx2(values, s) };
            return;
        }
    }
    rbf_portable(values, s);
}

/// The element-wise loop of [`rbf_from_sq_dist_in_place`]: every build's (inlined into the
/// AVX2 and AVX-512 functions, it is vectorised with their instructions).
#[inline(always)]
fn rbf_portable(values: &mut [f64], s: f64) {
    values
        .iter_mut()
        .for_each(|v| *v = s * exp_lanes(-0.5 * *v));
}

/// [`rbf_from_sq_dist_in_place`] compiled for AVX-512 (8 lanes; element-wise, so the same bits
/// as every other build: 1275 values in 1.5 us against AVX2's 2.6, BENCHMARKS.md "gp-core",
/// session 43).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn rbf_avx512(values: &mut [f64], s: f64) {
    rbf_portable(values, s);
}

/// [`rbf_from_sq_dist_in_place`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn rbf_avx2(values: &mut [f64], s: f64) {
    rbf_portable(values, s);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_matches_the_standard_library() {
        let mut worst = 0.0f64;
        let mut x = -708.0;
        while x <= 709.7 {
            let (a, b) = (exp_lanes(x), x.exp());
            worst = worst.max((a - b).abs() / b);
            x += 0.0173;
        }
        for x in [0.0, -1e-300, 1e-300, -0.3465, 0.3466, -700.0, 709.0] {
            worst = worst.max((exp_lanes(x) - x.exp()).abs() / x.exp());
        }
        // 4.3e-16 here; the sign of the degree-13 term alone moves it to 6.3e-16.
        assert!(worst < 5e-16, "worst relative error {worst:e}");
        assert_eq!(exp_lanes(0.0), 1.0);
        // The largest finite argument is computed, not infinity; just above it is.
        let max = 709.782_712_893_384;
        assert!(exp_lanes(max).is_finite());
        assert!((exp_lanes(max) - f64::exp(max)).abs() <= 5e-16 * f64::exp(max));
        assert_eq!(exp_lanes(f64::from_bits(max.to_bits() + 1)), f64::INFINITY);
        assert_eq!(exp_lanes(-800.0), 0.0);
        assert_eq!(exp_lanes(800.0), f64::INFINITY);
        let mut v: Vec<f64> = (0..1000).map(|i| f64::from(i) * 0.37).collect();
        let want: Vec<f64> = v.iter().map(|d| 2.0 * (-0.5 * d).exp()).collect();
        rbf_from_sq_dist_in_place(&mut v, 2.0);
        for (a, b) in v.iter().zip(&want) {
            assert!((a - b).abs() <= 1e-15 * b.max(f64::MIN_POSITIVE) || *b < 1e-300);
        }
    }

    /// The coefficient tables hold 1/k! and 1/k (checked by multiplying back).
    #[test]
    fn coefficient_tables_are_reciprocals() {
        let mut factorial = 1.0;
        for (k, &f) in FACT_INV.iter().enumerate() {
            factorial *= k.max(1) as f64;
            assert!((f * factorial - 1.0).abs() <= f64::EPSILON, "1/{k}!");
        }
        for (k, &inv) in INV.iter().enumerate().skip(1) {
            assert!((inv * k as f64 - 1.0).abs() <= f64::EPSILON, "1/{k}");
        }
        assert_eq!(INV[0], 0.0, "unused");
    }

    /// The RBF values have the same bits in every build (element-wise arithmetic without fused
    /// multiply-adds, whatever the vector width), over the whole range of `exp_lanes`.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn rbf_builds_agree_bitwise() {
        let dist: Vec<f64> = (0..2000).map(|i| f64::from(i) * 0.7391 - 3.0).collect();
        let portable: Vec<u64> = dist
            .iter()
            .map(|d| (1.7 * exp_lanes(-0.5 * d)).to_bits())
            .collect();
        let bits = |f: unsafe fn(&mut [f64], f64)| {
            let mut v = dist.clone();
            // SAFETY: each caller checks the CPU features of `f` first.
            unsafe { f(&mut v, 1.7) };
            v.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        };
        if std::arch::is_x86_feature_detected!("avx512f") {
            assert_eq!(bits(rbf_avx512), portable, "AVX-512");
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            assert_eq!(bits(rbf_avx2), portable, "AVX2");
        }
        assert_eq!(bits(rbf_portable), portable, "no vector extension");
        let mut v = dist.clone();
        rbf_from_sq_dist_in_place(&mut v, 1.7);
        assert_eq!(v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), portable);
    }

    /// Xorshift values of both signs over twelve decades (where the order of additions shows).
    fn mixed_values(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let u = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            u * 10f64.powi((state % 13) as i32 - 6)
        }
    }

    /// Whether this CPU runs the AVX2 + FMA kernels (the tests of their bits need it).
    #[cfg(target_arch = "x86_64")]
    fn avx2_and_fma() -> bool {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }

    /// The AVX2 dot product has `dot`'s bits for f64 and f32 values, at every length (all
    /// remainders) and with values of mixed signs and magnitudes (where the order of additions
    /// shows).
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn avx2_dot_has_the_portable_dots_bits() {
        if !avx2_and_fma() {
            return;
        }
        let mut next = mixed_values(0x9e37_79b9_7f4a_7c15);
        for len in 0..70 {
            let a: Vec<f64> = (0..len).map(|_| next()).collect();
            let b: Vec<f64> = (0..len).map(|_| next()).collect();
            let b32: Vec<f32> = b.iter().map(|&v| v as f32).collect();
            // SAFETY: AVX2 and FMA were detected above (`avx2_and_fma`).
            let (fast, fast32) = unsafe { (dot_avx2(&a, &b), dot_avx2(&a, &b32)) };
            assert_eq!(fast.to_bits(), dot(&a, &b).to_bits(), "f64, length {len}");
            assert_eq!(
                fast32.to_bits(),
                dot(&a, &b32).to_bits(),
                "f32, length {len}"
            );
        }
    }

    /// Interleaved rows ([`dot_rows_avx2`]) have each row's [`dot`] bits, at every length and
    /// for 1, 3 and 8 rows, in f64 and f32.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn avx2_dot_rows_have_each_rows_dot_bits() {
        if !avx2_and_fma() {
            return;
        }
        fn check<const R: usize>(next: &mut impl FnMut() -> f64, len: usize) {
            let a: Vec<f64> = (0..len).map(|_| next()).collect();
            // One value more than the rows need: it must be ignored.
            let b: Vec<f64> = (0..R * len + 1).map(|_| next()).collect();
            let b32: Vec<f32> = b.iter().map(|&v| v as f32).collect();
            // SAFETY: AVX2 and FMA were detected by the caller; b holds R * len values.
            let (fast, fast32) = unsafe {
                (
                    dot_rows_avx2::<_, R>(&a, &b),
                    dot_rows_avx2::<_, R>(&a, &b32),
                )
            };
            for r in 0..R {
                let (row, row32) = (&b[r * len..(r + 1) * len], &b32[r * len..(r + 1) * len]);
                assert_eq!(
                    fast[r].to_bits(),
                    dot(&a, row).to_bits(),
                    "f64 {R}x{len} row {r}"
                );
                assert_eq!(
                    fast32[r].to_bits(),
                    dot(&a, row32).to_bits(),
                    "f32 {R}x{len} row {r}"
                );
            }
        }
        let mut next = mixed_values(0x2545_f491_4f6c_dd1d);
        for len in 0..70 {
            check::<1>(&mut next, len);
            check::<3>(&mut next, len);
            check::<8>(&mut next, len);
        }
    }

    /// [`dot_wide`] compiled with AVX2 + FMA enabled (the compiler vectorises its block loop).
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn dot_wide_avx2(a: &[f64], b: &[f64]) -> f64 {
        dot_wide(a, b)
    }

    /// [`axpy_then_dot_wide`] compiled with AVX-512F enabled.
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    unsafe fn axpy_then_dot_wide_avx512(a: f64, x: &[f64], y: &mut [f64], z: &[f64]) -> f64 {
        axpy_then_dot_wide(a, x, y, z)
    }

    /// [`dot_wide`] compiled with AVX-512F enabled.
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    unsafe fn dot_wide_avx512(a: &[f64], b: &[f64]) -> f64 {
        dot_wide(a, b)
    }

    /// `dot_wide` sums as documented (product `i` into partial `i mod 32`, the partials halved
    /// 16, 8, 4, 2, 1: checked against that order written out here), is accurate to the usual
    /// bound `n eps sum |a_i b_i|`, and has the same bits when compiled for AVX2 or AVX-512, at
    /// every length (all remainders) and with mixed signs and magnitudes (where the order of
    /// the additions shows); so has `axpy_then_dot_wide` against the update and `dot_wide` in
    /// two steps.
    #[test]
    fn wide_dot_sums_in_its_documented_order_on_every_build() {
        let mut next = mixed_values(0x2545_f491_4f6c_dd1d);
        for len in (0..140).chain([255, 256, 257, 1000]) {
            let a: Vec<f64> = (0..len).map(|_| next()).collect();
            let b: Vec<f64> = (0..len).map(|_| next()).collect();
            let got = dot_wide(&a, &b);
            let mut part = [0f64; WIDE_PARTS];
            for i in 0..len {
                part[i % WIDE_PARTS] += a[i] * b[i];
            }
            for width in [16, 8, 4, 2, 1] {
                for k in 0..width {
                    part[k] += part[k + width];
                }
            }
            assert_eq!(got.to_bits(), part[0].to_bits(), "length {len}");
            // Accuracy: against the sum in 128-bit-ish precision (two-product and two-sum).
            let (mut hi, mut lo, mut abs) = (0.0f64, 0.0f64, 0.0f64);
            for (x, y) in a.iter().zip(&b) {
                let p = x * y;
                let pe = x.mul_add(*y, -p);
                let s = hi + p;
                let bb = s - hi;
                lo += (hi - (s - bb)) + (p - bb) + pe;
                hi = s;
                abs += p.abs();
            }
            let exact = hi + lo;
            assert!(
                (got - exact).abs() <= len as f64 * f64::EPSILON * abs,
                "length {len}: {got:e} against {exact:e}"
            );
            // The fused update: `y` updated as by a plain loop, and the dot product of the
            // updated `y` with the same bits as `dot_wide` (portable and AVX-512 builds).
            let scale = next();
            let updated: Vec<f64> = a.iter().zip(&b).map(|(x, y)| y + scale * x).collect();
            let z: Vec<f64> = (0..len).map(|_| next()).collect();
            let want = dot_wide(&z, &updated);
            let mut fused = b.clone();
            let got_fused = axpy_then_dot_wide(scale, &a, &mut fused, &z);
            assert_eq!(fused, updated, "fused update, length {len}");
            assert_eq!(got_fused.to_bits(), want.to_bits(), "fused, length {len}");
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: AVX2 and FMA were detected just above.
                    let fast = unsafe { dot_wide_avx2(&a, &b) };
                    assert_eq!(fast.to_bits(), got.to_bits(), "AVX2, length {len}");
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: AVX-512F was detected just above.
                    let fast = unsafe { dot_wide_avx512(&a, &b) };
                    assert_eq!(fast.to_bits(), got.to_bits(), "AVX-512, length {len}");
                    let mut fused = b.clone();
                    // SAFETY: as above.
                    let got = unsafe { axpy_then_dot_wide_avx512(scale, &a, &mut fused, &z) };
                    assert_eq!(fused, updated, "fused AVX-512 update, length {len}");
                    assert_eq!(got.to_bits(), want.to_bits(), "fused AVX-512, length {len}");
                }
            }
        }
    }

    /// `norm` is `sqrt(dot(v, v))` to the bit where that is safe, and right to rounding at
    /// magnitudes whose squares overflow or underflow.
    #[test]
    fn norm_is_safe_at_every_magnitude() {
        let v = [3.0, -4.0, 12.0, 0.5, -0.25];
        let plain = dot(&v, &v).sqrt();
        assert_eq!(norm(&v).to_bits(), plain.to_bits());
        for scale in [1e-300, 1e-200, 1e-160, 1e160, 1e200, 1e300] {
            let w: Vec<f64> = v.iter().map(|x| x * scale).collect();
            let got = norm(&w);
            assert!(
                (got / (plain * scale) - 1.0).abs() < 4.0 * f64::EPSILON,
                "{scale:e}: {got:e} against {:e}",
                plain * scale
            );
        }
        assert_eq!(norm(&[]), 0.0);
        assert_eq!(norm(&[0.0, -0.0]), 0.0);
        assert_eq!(norm(&[1.0, f64::NEG_INFINITY]), f64::INFINITY);
        assert!(norm(&[1e300, f64::NAN]).is_nan());
        let half = f64::MAX / 2.0;
        assert!((norm(&[half, -half]) / (half * 2f64.sqrt()) - 1.0).abs() < 4.0 * f64::EPSILON);
        // Safe sums start 1/eps above the smallest normal number (~1e-292), not at it.
        let safe = f64::MIN_POSITIVE / f64::EPSILON;
        assert!(is_safe_sum_of_squares(safe));
        assert!(!is_safe_sum_of_squares(f64::from_bits(safe.to_bits() - 1)));
        assert!(!is_safe_sum_of_squares(1e-300));
        assert!(is_safe_sum_of_squares(f64::MAX));
        assert!(!is_safe_sum_of_squares(f64::INFINITY) && !is_safe_sum_of_squares(f64::NAN));
    }
}
