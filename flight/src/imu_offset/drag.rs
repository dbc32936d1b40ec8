//! Optional per-throw drag model for the batch fitter ([`DragModel::VerticalQuadratic`]).
//!
//! # Model
//! A thrown craft caught at its release height flies (nearly) vertically: its velocity is
//! `v ≈ g (t − t_apex)` along the world vertical, so quadratic drag adds the specific force
//! `−(k/m) g² |τ| τ · e_z`, `τ = t − t_apex`, which in IMU axes is `R(t)ᵀ e_z` times that scalar.
//! With `R(t) = R₀ R_rel(t)` and `R_rel` integrated from the filtered gyro from the segment's first
//! sample, the drag is `s(τ) R_rel(t)ᵀ w` with one unknown 3-vector `w` per segment
//! (`w ∝ k R₀ᵀ e_z`) and the known profile `s(τ) = |τ| τ`. The apex is taken at the segment's
//! mid-time (release and catch at the same height; the trimmed edges are nearly symmetric).
//! Each row of eq. 3 becomes `y = X r + b + Z w_k`, `Z = s(τ) R_rel(t)ᵀ`.
//!
//! # Cost and memory
//! Batch only (`f64`, the configurator): per row a quaternion step and a 3 × 9 regressor; per
//! segment the 9 × 9 normal equations of `[r, b, w_k]` for the rows and for both batch lengths.
//! When a segment ends `w_k` is profiled out (eliminated at its optimum for given `[r, b]`), which
//! folds the segment into 6 × 6 quadratic forms of `θ = [r, b]`; memory stays constant whatever the
//! number of throws, and nothing is allocated.
//!
//! # What it does not model
//! Horizontal release velocity (then the drag direction turns during the flight), linear drag,
//! and anisotropic drag (a quad's body-z drag is 2–3 × its x/y drag): these remain as slowly
//! varying residuals, which the batch-means variance still sees.

use nalgebra::{Matrix3, Matrix6, SMatrix, SVector, UnitQuaternion, Vector3, Vector6};

use super::front_end::{regressor, AlignedSample};

/// How drag is treated by the fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DragModel {
    /// Ignored (the seed paper's eq. 3; the only choice on the board).
    #[default]
    Ignored,
    /// Per-throw quadratic drag along the world vertical: each row becomes
    /// `f = X r (+ b) + s(τ) R_rel(t)ᵀ w_k`, with `R_rel` the attitude change since the throw's
    /// first used sample (integrated from the filtered gyro), `s(τ) = |τ| τ`, `τ` the time from
    /// the throw's mid-time (its apex, for a catch at release height), and one unknown 3-vector
    /// `w_k` per throw (drag coefficient over mass times g², along the vertical seen in IMU axes
    /// at the first sample). 3 more unknowns per throw, profiled out when the throw ends, so the
    /// fitter's memory stays constant (4.5 KB more: 5.5 KB in all). Assumes a vertical throw
    /// caught at release height; horizontal speed, linear and anisotropic drag remain unmodelled.
    /// [`BatchFitter`](super::BatchFitter) only: the onboard estimator refuses it.
    VerticalQuadratic,
}

type Matrix9 = SMatrix<f64, 9, 9>;
type Vector9 = SVector<f64, 9>;
type Matrix3x9 = SMatrix<f64, 3, 9>;

/// Residual sum of squares as a quadratic in `θ = [r; b]`: `RSS(θ) = c − 2 gᵀθ + θᵀ Q θ`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Quadratic {
    pub(crate) q: Matrix6<f64>,
    pub(crate) g: Vector6<f64>,
    pub(crate) c: f64,
    /// Rows (samples or batches) summed.
    pub(crate) count: u32,
}

impl Quadratic {
    pub(crate) fn new() -> Self {
        Self { q: Matrix6::zeros(), g: Vector6::zeros(), c: 0.0, count: 0 }
    }

    /// The value at `θ`.
    pub(crate) fn at(&self, theta: &Vector6<f64>) -> f64 {
        self.c - 2.0 * self.g.dot(theta) + theta.dot(&(self.q * theta))
    }
}

/// Normal equations of one segment's rows in `φ = [r; b; w]`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Normal9 {
    gtg: Matrix9,
    gty: Vector9,
    yty: f64,
    count: u32,
}

impl Normal9 {
    fn new() -> Self {
        Self { gtg: Matrix9::zeros(), gty: Vector9::zeros(), yty: 0.0, count: 0 }
    }

    fn add(&mut self, g: &Matrix3x9, y: &Vector3<f64>) {
        self.gtg += g.tr_mul(g);
        self.gty += g.tr_mul(y);
        self.yty += y.dot(y);
        self.count = self.count.saturating_add(1);
    }

    fn merge(&mut self, other: &Self) {
        self.gtg += other.gtg;
        self.gty += other.gty;
        self.yty += other.yty;
        self.count = self.count.saturating_add(other.count);
    }

    /// Fold into `out` with `φ = T θ + e` (`T = [I; −D]`, `e = [0; c_w]`).
    fn fold(&self, d: &SMatrix<f64, 3, 6>, c_w: &Vector3<f64>, out: &mut Quadratic) {
        let mut t = SMatrix::<f64, 9, 6>::zeros();
        t.fixed_view_mut::<6, 6>(0, 0).fill_with_identity();
        t.fixed_view_mut::<3, 6>(6, 0).copy_from(&(-d));
        let mut e = Vector9::zeros();
        e.fixed_rows_mut::<3>(6).copy_from(c_w);
        let ge = self.gtg * e;
        out.q += t.transpose() * self.gtg * t;
        out.g += t.transpose() * (self.gty - ge);
        out.c += self.yty - 2.0 * self.gty.dot(&e) + e.dot(&ge);
        out.count = out.count.saturating_add(self.count);
    }
}

/// Sums of the drag-extended problem over all segments so far, and the segment in progress.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DragSums {
    /// Rows, short batches and long batches, `w` profiled out, over finished segments.
    pub(crate) rows: Quadratic,
    pub(crate) short: Quadratic,
    pub(crate) long: Quadratic,
    /// Segments whose `w` was fitted (3 unknowns each).
    pub(crate) segments: u32,
    /// Blocks per long batch.
    group: u32,
    // The segment in progress.
    seg_rows: Normal9,
    block_rows: Normal9,
    seg_short: Normal9,
    seg_long: Normal9,
    block_g: Matrix3x9,
    block_y: Vector3<f64>,
    block_count: u32,
    long_g: Matrix3x9,
    long_y: Vector3<f64>,
    long_blocks: u32,
    attitude: UnitQuaternion<f64>,
    t_mid_s: f64,
    dt_s: f64,
}

impl DragSums {
    pub(crate) fn new(group: u32) -> Self {
        Self {
            rows: Quadratic::new(),
            short: Quadratic::new(),
            long: Quadratic::new(),
            segments: 0,
            group: group.max(1),
            seg_rows: Normal9::new(),
            block_rows: Normal9::new(),
            seg_short: Normal9::new(),
            seg_long: Normal9::new(),
            block_g: Matrix3x9::zeros(),
            block_y: Vector3::zeros(),
            block_count: 0,
            long_g: Matrix3x9::zeros(),
            long_y: Vector3::zeros(),
            long_blocks: 0,
            attitude: UnitQuaternion::identity(),
            t_mid_s: 0.0,
            dt_s: 0.0,
        }
    }

    /// Start a segment of raw indices `[start, end)` at `rate_hz`.
    pub(crate) fn begin_segment(&mut self, start: u32, end: u32, rate_hz: f32) {
        self.seg_rows = Normal9::new();
        self.block_rows = Normal9::new();
        self.seg_short = Normal9::new();
        self.seg_long = Normal9::new();
        self.block_g = Matrix3x9::zeros();
        self.block_y = Vector3::zeros();
        self.block_count = 0;
        self.long_g = Matrix3x9::zeros();
        self.long_y = Vector3::zeros();
        self.long_blocks = 0;
        self.attitude = UnitQuaternion::identity();
        self.dt_s = 1.0 / f64::from(rate_hz);
        self.t_mid_s = 0.5 * f64::from(end.saturating_sub(start)) * self.dt_s;
    }

    /// Add one aligned sample, `k` samples after the segment's first (relative to `r_ref = 0`).
    pub(crate) fn add_row(&mut self, s: &AlignedSample, k: u32) {
        let w = s.gyro_radps.map(f64::from);
        let w_dot = s.gyro_dot_radps2.map(f64::from);
        let tau = f64::from(k) * self.dt_s - self.t_mid_s;
        let profile = tau.abs() * tau;
        let mut g = Matrix3x9::zeros();
        g.fixed_view_mut::<3, 3>(0, 0).copy_from(&regressor(&w, &w_dot));
        g.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
        let r_rel_t = self.attitude.to_rotation_matrix().into_inner().transpose();
        g.fixed_view_mut::<3, 3>(0, 6).copy_from(&(r_rel_t * profile));
        let y = s.acc_mps2.map(f64::from);
        self.block_rows.add(&g, &y);
        self.block_g += g;
        self.block_y += y;
        self.block_count += 1;
        self.attitude *= UnitQuaternion::from_scaled_axis(w * self.dt_s);
    }

    /// A block of rows is complete (the batch fitter's block boundaries).
    pub(crate) fn end_block(&mut self) {
        if self.block_count == 0 {
            return;
        }
        self.seg_rows.merge(&self.block_rows);
        self.block_rows = Normal9::new();
        self.seg_short.add(&self.block_g, &self.block_y);
        self.long_g += self.block_g;
        self.long_y += self.block_y;
        self.long_blocks += 1;
        if self.long_blocks >= self.group {
            self.seg_long.add(&self.long_g, &self.long_y);
            self.long_g = Matrix3x9::zeros();
            self.long_y = Vector3::zeros();
            self.long_blocks = 0;
        }
        self.block_g = Matrix3x9::zeros();
        self.block_y = Vector3::zeros();
        self.block_count = 0;
    }

    /// The segment ended: profile its `w` out and fold it into the quadratics. Rows of an
    /// unfinished block are dropped, as in the batch fitter's other sums.
    pub(crate) fn end_segment(&mut self) {
        let n = &self.seg_rows;
        if n.count == 0 {
            return;
        }
        let q_ww: Matrix3<f64> = n.gtg.fixed_view::<3, 3>(6, 6).into_owned();
        let q_wt: SMatrix<f64, 3, 6> = n.gtg.fixed_view::<3, 6>(6, 0).into_owned();
        let g_w: Vector3<f64> = n.gty.fixed_rows::<3>(6).into_owned();
        let (d, c_w, fitted) = match q_ww.cholesky() {
            Some(chol) => (chol.solve(&q_wt), chol.solve(&g_w), true),
            None => (SMatrix::<f64, 3, 6>::zeros(), Vector3::zeros(), false),
        };
        let (d, c_w) = if d.iter().chain(c_w.iter()).all(|v| v.is_finite()) {
            (d, c_w)
        } else {
            (SMatrix::<f64, 3, 6>::zeros(), Vector3::zeros())
        };
        self.seg_rows.fold(&d, &c_w, &mut self.rows);
        self.seg_short.fold(&d, &c_w, &mut self.short);
        self.seg_long.fold(&d, &c_w, &mut self.long);
        if fitted {
            self.segments = self.segments.saturating_add(1);
        }
        self.begin_segment(0, 0, 1.0);
    }
}
