//! Eigen-decomposition of a symmetric 3 × 3 matrix by cyclic Jacobi rotations (f32).
//!
//! Used by the bounded search, which needs *all* eigen-pairs of the 3 × 3 force matrix on every
//! face it visits. Jacobi is unconditionally stable, accurate for small eigenvalues relative to
//! the largest, and converges quadratically: a handful of sweeps for 3 × 3.

use crate::math::sqrt;

/// Maximum number of sweeps (three rotations each). Quadratic convergence reaches f32 precision
/// in 4–6 sweeps for 3 × 3; 12 is a safe cap that bounds the run time.
const MAX_SWEEPS: usize = 12;

/// Eigenvalues `values[k]` and eigenvectors (columns `vectors[..][k]`, orthonormal) of the
/// symmetric matrix `a` (only its upper triangle is read).
pub(crate) fn symmetric_eigen3(a: [[f32; 3]; 3]) -> ([f32; 3], [[f32; 3]; 3]) {
    let mut a =
        [[a[0][0], a[0][1], a[0][2]], [a[0][1], a[1][1], a[1][2]], [a[0][2], a[1][2], a[2][2]]];
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..MAX_SWEEPS {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        let diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        // Converged (or nothing finite to do) once the off-diagonal mass is below round-off.
        if !(off > 1e-14 * diag) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[p][q];
            if apq == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
            let t = if libm::fabsf(theta) > 1e15 {
                0.5 / theta
            } else {
                let sign = if theta >= 0.0 { 1.0 } else { -1.0 };
                sign / (libm::fabsf(theta) + sqrt(theta * theta + 1.0))
            };
            let c = 1.0 / sqrt(t * t + 1.0);
            let s = t * c;
            a[p][p] -= t * apq;
            a[q][q] += t * apq;
            a[p][q] = 0.0;
            a[q][p] = 0.0;
            let r = 3 - p - q; // the third index
            let (arp, arq) = (a[r][p], a[r][q]);
            a[r][p] = c * arp - s * arq;
            a[p][r] = a[r][p];
            a[r][q] = s * arp + c * arq;
            a[q][r] = a[r][q];
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reconstructs_the_matrix() {
        let a = [[4.0, 1.0, -2.0], [1.0, 3.0, 0.5], [-2.0, 0.5, 1.0]];
        let (values, v) = symmetric_eigen3(a);
        for i in 0..3 {
            for j in 0..3 {
                let rebuilt: f32 = (0..3).map(|k| v[i][k] * values[k] * v[j][k]).sum();
                assert!((rebuilt - a[i][j]).abs() < 1e-5, "{i}{j}: {rebuilt} vs {}", a[i][j]);
                let gram: f32 = (0..3).map(|k| v[k][i] * v[k][j]).sum();
                assert!((gram - if i == j { 1.0 } else { 0.0 }).abs() < 1e-5);
            }
        }
    }
}
