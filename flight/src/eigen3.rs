//! Eigen-decomposition of a symmetric 3 × 3 matrix by cyclic Jacobi rotations, in `f32` or
//! `f64`.
//!
//! Used by the thrust-axis bounded search, which needs *all* eigen-pairs of the 3 × 3 force
//! matrix on every face it visits, and by the IMU-offset calibration for the axes of its 95 %
//! ellipsoid. Jacobi is unconditionally stable, accurate for small eigenvalues relative to the
//! largest, and converges quadratically: a handful of sweeps for 3 × 3. Why not nalgebra's
//! `SymmetricEigen`: it reduces to tridiagonal form with Householder reflections and then runs
//! implicit QR, general code for any size that cost the firmware about 3 KB of flash for this one
//! 3 × 3 use; this is a few hundred bytes.

use nalgebra::RealField;

/// Maximum number of sweeps (three rotations each). Quadratic convergence reaches `f64`
/// precision in 5–7 sweeps for 3 × 3; 12 is a safe cap that bounds the run time.
const MAX_SWEEPS: usize = 12;

/// Eigenvalues `values[k]` and eigenvectors (columns `vectors[..][k]`, orthonormal) of the
/// symmetric matrix `a` (only its upper triangle is read); `None` when an entry is NaN or
/// infinite. After [`MAX_SWEEPS`] the rotations stop, converged or not (a bounded run time).
pub fn symmetric_eigen3<T: RealField + Copy>(a: [[T; 3]; 3]) -> Option<([T; 3], [[T; 3]; 3])> {
    if !a.iter().flatten().all(|x| x.is_finite()) {
        return None;
    }
    let (zero, one, two) = (T::zero(), T::one(), T::one() + T::one());
    // Converged once the off-diagonal mass is below the precision's round-off.
    let tolerance = T::default_epsilon() * T::default_epsilon();
    let mut a =
        [[a[0][0], a[0][1], a[0][2]], [a[0][1], a[1][1], a[1][2]], [a[0][2], a[1][2], a[2][2]]];
    let mut v = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    for _ in 0..MAX_SWEEPS {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        let diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        if off <= tolerance * diag {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[p][q];
            if apq == zero {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (two * apq);
            // The smaller root of t² + 2θt − 1 = 0; for huge θ, θ² would overflow: t ≈ 1/(2θ).
            let t = if theta.abs() * T::default_epsilon() > one {
                one / (two * theta)
            } else {
                let sign = if theta >= zero { one } else { -one };
                sign / (theta.abs() + (theta * theta + one).sqrt())
            };
            let c = one / (t * t + one).sqrt();
            let s = t * c;
            a[p][p] -= t * apq;
            a[q][q] += t * apq;
            a[p][q] = zero;
            a[q][p] = zero;
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
    Some(([a[0][0], a[1][1], a[2][2]], v))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `V diag(values) Vᵀ` rebuilds `a` within `tolerance` (times its largest entry) and `V` is
    /// orthonormal within `orthonormal`; returns the eigenvalues, largest first.
    fn assert_decomposes<T: RealField + Copy + core::fmt::LowerExp>(
        a: [[T; 3]; 3],
        tolerance: T,
        orthonormal: T,
    ) -> [T; 3] {
        let (values, v) = symmetric_eigen3(a).unwrap();
        let scale = a.iter().flatten().fold(T::zero(), |m, x| m.max(x.abs()));
        for i in 0..3 {
            for j in 0..3 {
                let rebuilt = (0..3).fold(T::zero(), |s, k| s + v[i][k] * values[k] * v[j][k]);
                let error = (rebuilt - a[i][j]).abs();
                assert!(error <= tolerance * scale, "{i}{j}: {rebuilt:e} vs {:e}", a[i][j]);
                let gram = (0..3).fold(T::zero(), |s, k| s + v[k][i] * v[k][j]);
                let identity = if i == j { T::one() } else { T::zero() };
                assert!((gram - identity).abs() <= orthonormal, "VᵀV {i}{j}: {gram:e}");
            }
        }
        let mut sorted = values;
        sorted.sort_by(|x, y| y.partial_cmp(x).unwrap());
        sorted
    }

    #[test]
    fn reconstructs_the_matrix_in_f32() {
        assert_decomposes([[4.0f32, 1.0, -2.0], [1.0, 3.0, 0.5], [-2.0, 0.5, 1.0]], 3e-6, 1e-5);
    }

    /// In `f64` to `f64` precision, on a covariance of the IMU-offset ellipsoid's kind
    /// (millimetre-squared entries, strongly correlated axes, one repeated eigenvalue pair).
    #[test]
    fn reconstructs_a_covariance_in_f64() {
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -1.1, 2.0);
        let d = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(4e-6, 1e-6, 1e-6));
        let m = r.matrix() * d * r.matrix().transpose();
        let a: [[f64; 3]; 3] = core::array::from_fn(|i| core::array::from_fn(|j| m[(i, j)]));
        let values = assert_decomposes(a, 1e-12, 1e-14);
        for (got, want) in values.iter().zip([4e-6, 1e-6, 1e-6]) {
            assert!((got - want).abs() < 1e-18, "eigenvalue {got:e}, want {want:e}");
        }
    }

    /// A NaN or an infinity in the upper triangle (the part read) gives `None`.
    #[test]
    fn a_non_finite_entry_gives_none() {
        for bad in [f64::NAN, f64::INFINITY] {
            let a = [[1.0, bad, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]];
            assert_eq!(symmetric_eigen3(a), None);
        }
    }
}
