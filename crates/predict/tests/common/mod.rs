//! Helpers shared by predict's test binaries.

/// Solves the small dense system `A x = b` (`a(i, j)` = A's entries) by Gaussian elimination
/// with partial pivoting: an independent reference for the GP's Cholesky solves.
pub fn dense_solve(a: impl Fn(usize, usize) -> f64, b: &[f64]) -> Vec<f64> {
    let n = b.len();
    let mut m: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let mut r: Vec<f64> = (0..n).map(|j| a(i, j)).collect();
            r.push(b[i]);
            r
        })
        .collect();
    for k in 0..n {
        let p = (k..n)
            .max_by(|&x, &y| m[x][k].abs().total_cmp(&m[y][k].abs()))
            .unwrap();
        m.swap(k, p);
        for i in k + 1..n {
            let f = m[i][k] / m[k][k];
            for j in k..=n {
                m[i][j] -= f * m[k][j];
            }
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|j| m[i][j] * x[j]).sum();
        x[i] = (m[i][n] - s) / m[i][i];
    }
    x
}
