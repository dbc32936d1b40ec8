//! Sufficient statistics of the IMU-offset least-squares problem (the information form of
//! recursive least squares).
//!
//! For rows `y_n = X_n r + b + e_n` (3 × 3 regressor `X_n`, measurement `y_n`, optional constant
//! bias `b`) every quantity the solver needs is a sum over rows: `Σ XᵀX`, `Σ X`, `Σ Xᵀy`, `Σ y`,
//! `Σ yᵀy` and the row count. Accumulating them is recursive least squares with forgetting factor
//! 1 and an uninformative prior: after any number of rows, a 3 × 3 solve gives exactly the batch
//! estimate over those rows, and the cost of an update does not grow with the data. The same type
//! also holds block-level sums (the rows are then `X̄_b = Σ_{n∈b} X_n`, `Ȳ_b = Σ_{n∈b} y_n`), which
//! the solver uses for the batch-means estimate of the residuals' long-run variance.
//!
//! Measurements are stored relative to a reference offset `r_ref` (`y' = y − X r_ref`), so that
//! `Σ y'ᵀy'` stays small and the residual sum of squares is not lost to cancellation in `f32`;
//! [`Moments::recentre`] moves the reference exactly.

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::Scalar;

/// Sums over rows of `X` (3 × 3) and `y` (3), generic over `f32` (board) and `f64` (host).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Moments<T: Scalar> {
    /// Upper triangle of `Σ XᵀX` (the lower triangle is not maintained: see [`Self::xtx`]).
    xtx_upper: Matrix3<T>,
    /// `Σ X`.
    pub(crate) xsum: Matrix3<T>,
    /// `Σ Xᵀ y`.
    pub(crate) xty: Vector3<T>,
    /// `Σ y`.
    pub(crate) ysum: Vector3<T>,
    /// `Σ yᵀ y`.
    pub(crate) yty: T,
    /// Number of rows (3-vectors) accumulated.
    pub(crate) count: u32,
}

impl<T: Scalar> Moments<T> {
    /// No rows.
    pub(crate) fn new() -> Self {
        Self {
            xtx_upper: Matrix3::zeros(),
            xsum: Matrix3::zeros(),
            xty: Vector3::zeros(),
            ysum: Vector3::zeros(),
            yty: T::zero(),
            count: 0,
        }
    }

    /// Add one row: the recursive update. About 45 multiply-adds, no branches, no division.
    #[inline]
    pub(crate) fn accumulate(&mut self, x: &Matrix3<T>, y: &Vector3<T>) {
        // Σ XᵀX, upper triangle only: (XᵀX)_ij = Σ_k X_ki X_kj.
        let c0 = x.column(0);
        let c1 = x.column(1);
        let c2 = x.column(2);
        let m = &mut self.xtx_upper;
        m[(0, 0)] += c0.dot(&c0);
        m[(0, 1)] += c0.dot(&c1);
        m[(0, 2)] += c0.dot(&c2);
        m[(1, 1)] += c1.dot(&c1);
        m[(1, 2)] += c1.dot(&c2);
        m[(2, 2)] += c2.dot(&c2);
        self.xsum += x;
        self.xty += x.tr_mul(y);
        self.ysum += y;
        self.yty += y.dot(y);
        self.count = self.count.saturating_add(1);
    }

    /// Add all rows of `other` (same reference offset assumed).
    pub(crate) fn merge(&mut self, other: &Self) {
        self.xtx_upper += other.xtx_upper;
        self.xsum += other.xsum;
        self.xty += other.xty;
        self.ysum += other.ysum;
        self.yty += other.yty;
        self.count = self.count.saturating_add(other.count);
    }

    /// The full symmetric `Σ XᵀX`.
    pub(crate) fn xtx(&self) -> Matrix3<T> {
        let u = &self.xtx_upper;
        Matrix3::new(
            u[(0, 0)],
            u[(0, 1)],
            u[(0, 2)],
            u[(0, 1)],
            u[(1, 1)],
            u[(1, 2)],
            u[(0, 2)],
            u[(1, 2)],
            u[(2, 2)],
        )
    }

    /// Re-express the measurements as `y − X δ` (moving the reference offset by `δ`), exactly.
    pub(crate) fn recentre(&mut self, delta: &Vector3<T>) {
        let xtx = self.xtx();
        let two = T::one() + T::one();
        self.yty = self.yty - two * delta.dot(&self.xty) + delta.dot(&(xtx * delta));
        self.xty -= xtx * delta;
        self.ysum -= self.xsum * delta;
    }

    /// `Σ |y − X d − w b|²` over the accumulated rows, for offset `d` (relative to the reference)
    /// and bias `b`, where each row's bias enters with weight `w` (1 for samples, the block length
    /// for block sums).
    pub(crate) fn sum_sq_residual(&self, d: &Vector3<T>, b: &Vector3<T>, w: T) -> T {
        let two = T::one() + T::one();
        let n: T = count_as(self.count);
        self.yty - two * d.dot(&self.xty) - two * w * b.dot(&self.ysum)
            + d.dot(&(self.xtx() * d))
            + two * w * b.dot(&(self.xsum * d))
            + n * w * w * b.dot(b)
    }
}

/// Block sums for the batch-means variance at two batch lengths: `short` gets one row per block
/// (`X̄_b`, `Ȳ_b`), `long` one per `group` consecutive blocks of a segment. Short batches measure
/// the filtered sensor noise precisely (many batches); long ones also catch slowly varying
/// unmodelled forces such as drag (few batches). An unfinished long batch at the end of a segment
/// is dropped (its rows still count in the fit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BatchMeans<T: Scalar> {
    pub(crate) short: Moments<T>,
    pub(crate) long: Moments<T>,
    /// Blocks per long batch.
    pub(crate) group: u32,
    partial_xsum: Matrix3<T>,
    partial_ysum: Vector3<T>,
    partial_count: u32,
}

impl<T: Scalar> BatchMeans<T> {
    /// No batches; `group` blocks make a long batch (at least 1).
    pub(crate) fn new(group: u32) -> Self {
        Self {
            short: Moments::new(),
            long: Moments::new(),
            group: group.max(1),
            partial_xsum: Matrix3::zeros(),
            partial_ysum: Vector3::zeros(),
            partial_count: 0,
        }
    }

    /// Add a finished block of rows.
    pub(crate) fn add_block(&mut self, block: &Moments<T>) {
        self.short.accumulate(&block.xsum, &block.ysum);
        self.partial_xsum += block.xsum;
        self.partial_ysum += block.ysum;
        self.partial_count += 1;
        if self.partial_count >= self.group {
            self.long.accumulate(&self.partial_xsum, &self.partial_ysum);
            self.end_segment();
        }
    }

    /// The segment ended: drop an unfinished long batch.
    pub(crate) fn end_segment(&mut self) {
        self.partial_xsum = Matrix3::zeros();
        self.partial_ysum = Vector3::zeros();
        self.partial_count = 0;
    }

    /// Add the finished batches of `other`.
    pub(crate) fn merge(&mut self, other: &Self) {
        self.short.merge(&other.short);
        self.long.merge(&other.long);
    }

    /// See [`Moments::recentre`].
    pub(crate) fn recentre(&mut self, delta: &Vector3<T>) {
        self.short.recentre(delta);
        self.long.recentre(delta);
        self.partial_ysum -= self.partial_xsum * delta;
    }
}

/// A count as a scalar (exact below 2²⁴ for `f32`).
pub(crate) fn count_as<T: Scalar>(n: u32) -> T {
    // u32 → f64 is exact; f64 → T rounds once.
    nalgebra::convert(f64::from(n))
}

/// The inverse of a symmetric positive-definite `q` (its lower triangle is read), by
/// `flight::math::spd_inverse` in `f64`; `None` when it is not positive definite. Every size
/// and scalar shares that one body: nalgebra's Cholesky cost the firmware a copy of its
/// factorisation and solves per size and scalar (about 2.3 KB for three).
pub(crate) fn spd_inverse_of<T: Scalar, const N: usize>(
    q: &SMatrix<T, N, N>,
) -> Option<SMatrix<T, N, N>> {
    let a: [[f64; N]; N] = core::array::from_fn(|i| {
        core::array::from_fn(|j| nalgebra::try_convert::<T, f64>(q[(i, j)]).unwrap_or(f64::NAN))
    });
    let inverse = flight::math::spd_inverse(&a)?;
    Some(SMatrix::from_fn(|i, j| nalgebra::convert(inverse[i][j])))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_rows() -> [(Matrix3<f64>, Vector3<f64>); 4] {
        let x =
            |s: f64| Matrix3::new(1.0 + s, 0.5, -s * s, 0.2, 2.0 - s, 0.3, s, 0.1 * s, 1.5 + s * s);
        let y = |s: f64| Vector3::new(0.3 * s, -1.0 + s, 2.0 - 0.5 * s);
        [(x(0.0), y(0.0)), (x(0.7), y(0.7)), (x(-1.3), y(-1.3)), (x(2.1), y(2.1))]
    }

    #[test]
    fn recentre_and_residual_agree_with_direct_sums() {
        let rows = sample_rows();
        let mut m = Moments::<f64>::new();
        for (x, y) in &rows {
            m.accumulate(x, y);
        }
        let d = Vector3::new(0.01, -0.02, 0.03);
        let b = Vector3::new(0.1, 0.2, -0.3);
        let direct: f64 = rows.iter().map(|(x, y)| (y - x * d - b).norm_squared()).sum();
        assert!((m.sum_sq_residual(&d, &b, 1.0) - direct).abs() < 1e-12);

        let mut moved = m;
        moved.recentre(&d);
        let direct_moved: f64 = rows.iter().map(|(x, y)| (y - x * d).norm_squared()).sum();
        assert!((moved.yty - direct_moved).abs() < 1e-12);
        let zero = Vector3::zeros();
        assert!((moved.sum_sq_residual(&zero, &b, 1.0) - direct).abs() < 1e-12);
    }
}
