//! Per-throw drag model ([`DragModel::VerticalQuadratic`], the default, onboard and offline).
//!
//! # Model
//! A thrown craft caught at its release height flies (nearly) vertically: its velocity is
//! `v ≈ g (t − t_apex)` along the world vertical, so quadratic drag adds the specific force
//! `−(k/m) g² |τ| τ · e_z`, `τ = t − t_apex`, which in IMU axes is `R(t)ᵀ e_z` times that scalar.
//! With `R(t) = R₀ R_rel(t)` and `R_rel` integrated from the filtered gyro from the throw's first
//! used sample, the drag is `s(τ) R_rel(t)ᵀ w` with one unknown 3-vector `w` per throw
//! (`w ∝ k R₀ᵀ e_z`) and the known profile `s(τ) = |τ| τ`. The apex is taken at the throw's
//! mid-time (release and catch at the same height; the trimmed edges are nearly symmetric).
//! Each row of eq. 3 becomes `y = X r + b + Z w_k`, `Z = s(τ) R_rel(t)ᵀ`.
//!
//! # Why a throw's blocks are kept until it ends
//! `s(τ)` changes sign at the apex, and the apex is known only once the catch ends the throw, so
//! the drag columns cannot be summed as the rows arrive. Instead, per block of rows
//! ([`Config::block_s`](super::Config::block_s), 20 ms) the sums `Σ XᵀR_relᵀ`, `Σ R_relᵀ` and
//! `Σ R_rel y` are kept beside the block's `Σ X` and `Σ y` (33 numbers), and when the throw ends
//! each block's drag columns are weighted by the block's mean `s̄_b` ([`DragSums::add_throw`]).
//! `R_rel R_relᵀ = I` makes the drag–drag term exact (`Σ s²` per row). Within a 20 ms block `s`
//! changes by at most `2|τ|·20 ms`, 4 % of itself at half a second from the apex, so the
//! per-block weight changes the drag columns by a few per cent of a correction.
//!
//! # Cost and memory
//! Per row: a first-order quaternion step (renormalised), a rotation matrix and about 45
//! multiply-adds, in `f32` on the board (`f64` offline, the same code). Per throw:
//! [`MAX_THROW_BLOCKS`] blocks of 33 scalars (10.6 KB in `f32`); a free fall longer than that
//! (1.6 s, an apex above 3 m for a catch at release height) is not used. When the throw ends, its
//! 9 × 9 normal equations in `[r, b, w_k]` (rows, and both batch lengths of the batch-means
//! variance) are built in `f64`, and `w_k` is profiled out (eliminated at its optimum for given
//! `[r, b]`), which folds the throw into 6 × 6 quadratic forms of `θ = [r, b]`: memory stays
//! constant whatever the number of throws.
//!
//! # What it does not model
//! Horizontal release velocity (then the drag direction turns during the flight), linear drag,
//! and anisotropic drag (a quad's body-z drag is 2–3 × its x/y drag): these remain as slowly
//! varying residuals, which the batch-means variance still sees.

use nalgebra::{Matrix3, Matrix6, Quaternion, SMatrix, SVector, UnitQuaternion, Vector3, Vector6};

use super::moments::{spd_inverse_of, Moments};
use super::{Scalar, Segment};
use flight::math::{mul_compact, tr_mul_compact};

/// Blocks of one throw kept for the drag model: 80 × 20 ms = 1.6 s of trimmed free fall, an apex
/// of 3.1 m above a catch at release height (calibration throws climb 0.8–1.5 m, 0.8–1.1 s).
pub const MAX_THROW_BLOCKS: usize = 80;

/// How drag is treated by the fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DragModel {
    /// Ignored (the seed paper's eq. 3).
    Ignored,
    /// Per-throw quadratic drag along the world vertical (the default): each row becomes
    /// `f = X r (+ b) + s(τ) R_rel(t)ᵀ w_k`, with `R_rel` the attitude change since the throw's
    /// first used sample (integrated from the filtered gyro), `s(τ) = |τ| τ`, `τ` the time from
    /// the throw's mid-time (its apex, for a catch at release height), and one unknown 3-vector
    /// `w_k` per throw (drag coefficient over mass times g², along the vertical seen in IMU axes
    /// at the first sample). 3 more unknowns per throw, profiled out when the throw ends, so the
    /// estimator's memory stays constant. Assumes a vertical throw caught at release height;
    /// horizontal speed, linear and anisotropic drag remain unmodelled. Throws longer than
    /// [`MAX_THROW_BLOCKS`] blocks are not used.
    #[default]
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

    /// Re-express in `θ' = θ − [δ; 0]` (the reference offset moved by `δ`), exactly.
    fn recentre(&mut self, delta: &Vector3<f64>) {
        let mut e = Vector6::zeros();
        e.fixed_rows_mut::<3>(0).copy_from(delta);
        let qe = self.q * e;
        self.c += -2.0 * self.g.dot(&e) + e.dot(&qe);
        self.g -= qe;
    }
}

/// Normal equations of one throw's rows in `φ = [r; b; w]`.
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
        self.gtg += tr_mul_compact(g, g);
        self.gty += tr_mul_compact(g, y);
        self.yty += y.dot(y);
        self.count = self.count.saturating_add(1);
    }

    /// The drag vector profiled out: `w(θ) = D' − D θ` at its optimum, as `(D, c_w)` with
    /// `D = Q_ww⁻¹ Q_wθ`, `c_w = Q_ww⁻¹ g_w`; `None` when `Q_ww` is singular.
    fn profile(&self) -> Option<(SMatrix<f64, 3, 6>, Vector3<f64>)> {
        let q_ww: Matrix3<f64> = self.gtg.fixed_view::<3, 3>(6, 6).into_owned();
        let q_wt: SMatrix<f64, 3, 6> = self.gtg.fixed_view::<3, 6>(6, 0).into_owned();
        let g_w: Vector3<f64> = self.gty.fixed_rows::<3>(6).into_owned();
        let q_ww_inv = spd_inverse_of(&q_ww)?;
        let (d, c_w) = (q_ww_inv * q_wt, q_ww_inv * g_w);
        d.iter().chain(c_w.iter()).all(|v| v.is_finite()).then_some((d, c_w))
    }

    /// Fold into `out` with `φ = T θ + e` (`T = [I; −D]`, `e = [0; c_w]`).
    fn fold(&self, d: &SMatrix<f64, 3, 6>, c_w: &Vector3<f64>, out: &mut Quadratic) {
        let mut t = SMatrix::<f64, 9, 6>::zeros();
        t.fixed_view_mut::<6, 6>(0, 0).fill_with_identity();
        t.fixed_view_mut::<3, 6>(6, 0).copy_from(&(-d));
        let mut e = Vector9::zeros();
        e.fixed_rows_mut::<3>(6).copy_from(c_w);
        let ge = mul_compact(&self.gtg, &e);
        out.q += mul_compact(&tr_mul_compact(&t, &self.gtg), &t);
        out.g += tr_mul_compact(&t, &(self.gty - ge));
        out.c += self.yty - 2.0 * self.gty.dot(&e) + e.dot(&ge);
        out.count = out.count.saturating_add(self.count);
    }
}

/// The drag columns' sums over one block of rows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BlockDragSums<T: Scalar> {
    /// `Σ Xᵀ R_relᵀ` (offset–drag coupling).
    xtr: Matrix3<T>,
    /// `Σ R_relᵀ` (bias–drag coupling, and the block's drag column).
    rsum: Matrix3<T>,
    /// `Σ R_rel y`.
    ry: Vector3<T>,
}

impl<T: Scalar> BlockDragSums<T> {
    pub(crate) fn new() -> Self {
        Self { xtr: Matrix3::zeros(), rsum: Matrix3::zeros(), ry: Vector3::zeros() }
    }
}

/// A finished block of the throw in progress: its `Σ X`, `Σ y` and drag sums.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ThrowBlock<T: Scalar> {
    xsum: Matrix3<T>,
    ysum: Vector3<T>,
    drag: BlockDragSums<T>,
}

/// The throw in progress: the attitude since its first row, the block being summed and the
/// committed blocks (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct DragThrow<T: Scalar> {
    /// `R_rel` of the next row, as a unit quaternion.
    attitude: UnitQuaternion<T>,
    /// Half the sample interval (s).
    half_dt_s: T,
    current: BlockDragSums<T>,
    blocks: [ThrowBlock<T>; MAX_THROW_BLOCKS],
    len: usize,
    /// A block did not fit: the throw is longer than the model keeps.
    overflowed: bool,
}

impl<T: Scalar> DragThrow<T> {
    /// An empty throw for rows at `rate_hz`.
    pub(crate) fn new(rate_hz: f32) -> Self {
        let mut throw = core::mem::MaybeUninit::uninit();
        // SAFETY: a local, valid for writes and aligned; `init_in` writes every field.
        unsafe {
            Self::init_in(throw.as_mut_ptr(), rate_hz);
            throw.assume_init()
        }
    }

    /// An empty throw for rows at `rate_hz`, written in place (its blocks are 10.6 KB in
    /// `f32`: built by value and moved they were a stack frame of their own on the board).
    ///
    /// # Safety
    /// `this` must be valid for writes and aligned (a field of a value being built in place).
    pub(crate) unsafe fn init_in(this: *mut Self, rate_hz: f32) {
        let blocks = core::ptr::addr_of_mut!((*this).blocks).cast::<ThrowBlock<T>>();
        for i in 0..MAX_THROW_BLOCKS {
            blocks.add(i).write(ThrowBlock {
                xsum: Matrix3::zeros(),
                ysum: Vector3::zeros(),
                drag: BlockDragSums::new(),
            });
        }
        core::ptr::addr_of_mut!((*this).attitude).write(UnitQuaternion::identity());
        core::ptr::addr_of_mut!((*this).half_dt_s).write(T::from(0.5 / rate_hz));
        core::ptr::addr_of_mut!((*this).current).write(BlockDragSums::new());
        core::ptr::addr_of_mut!((*this).len).write(0);
        core::ptr::addr_of_mut!((*this).overflowed).write(false);
    }

    /// Forget the throw; the next row is its first.
    pub(crate) fn begin(&mut self) {
        self.attitude = UnitQuaternion::identity();
        self.current = BlockDragSums::new();
        self.len = 0;
        self.overflowed = false;
    }

    /// Add one row `y = X r + …` at body rate `gyro_radps` (the same rows as `Moments`).
    #[inline]
    pub(crate) fn add_row(&mut self, x: &Matrix3<T>, y: &Vector3<T>, gyro_radps: &Vector3<T>) {
        let r_rel = self.attitude.to_rotation_matrix().into_inner();
        let r_rel_t = r_rel.transpose();
        self.current.xtr += x.tr_mul(&r_rel_t);
        self.current.rsum += r_rel_t;
        self.current.ry += r_rel * y;
        // First-order step of q̇ = ½ q ⊗ (0, Ω), renormalised: at 600 °/s and 2 kHz a step turns
        // 5 mrad, and the neglected terms are of third order (1e-8 rad per step).
        let h = gyro_radps * self.half_dt_s;
        let step = Quaternion::new(T::one(), h.x, h.y, h.z);
        self.attitude = UnitQuaternion::new_normalize(self.attitude.into_inner() * step);
    }

    /// The block being summed is complete: its drag sums, and a fresh block.
    pub(crate) fn take_block(&mut self) -> BlockDragSums<T> {
        core::mem::replace(&mut self.current, BlockDragSums::new())
    }

    /// Commit a finished block with its `Σ X` and `Σ y`.
    pub(crate) fn commit(&mut self, xsum: &Matrix3<T>, ysum: &Vector3<T>, drag: BlockDragSums<T>) {
        match self.blocks.get_mut(self.len) {
            Some(slot) => {
                *slot = ThrowBlock { xsum: *xsum, ysum: *ysum, drag };
                self.len += 1;
            }
            None => self.overflowed = true,
        }
    }

    /// True when the throw was longer than [`MAX_THROW_BLOCKS`] blocks (it must not be used).
    pub(crate) fn overflowed(&self) -> bool {
        self.overflowed
    }

    fn blocks(&self) -> &[ThrowBlock<T>] {
        self.blocks.get(..self.len).unwrap_or(&[])
    }
}

/// Drag-profiled sums over all finished throws, `f64` (built once per throw).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DragSums {
    /// Rows, short batches and long batches, each throw's `w` profiled out.
    pub(crate) rows: Quadratic,
    pub(crate) short: Quadratic,
    pub(crate) long: Quadratic,
    /// Throws whose `w` was fitted (3 unknowns each).
    pub(crate) segments: u32,
}

impl DragSums {
    pub(crate) fn new() -> Self {
        Self {
            rows: Quadratic::new(),
            short: Quadratic::new(),
            long: Quadratic::new(),
            segments: 0,
        }
    }

    /// Fold a finished throw: `rows` holds exactly its committed blocks' rows (those of
    /// `segment`), `block_len` rows per block at `rate_hz`, long batches of `group` blocks (the
    /// last one counted when at least half full).
    pub(crate) fn add_throw<T: Scalar>(
        &mut self,
        throw: &DragThrow<T>,
        rows: &Moments<T>,
        segment: &Segment,
        block_len: u32,
        group: u32,
        rate_hz: f32,
    ) {
        let blocks = throw.blocks();
        if blocks.is_empty() || rows.count == 0 {
            return;
        }
        let f = |v: T| nalgebra::try_convert::<T, f64>(v).unwrap_or(f64::NAN);
        let dt_s = 1.0 / f64::from(rate_hz);
        let len = f64::from(block_len);
        // The apex: the segment's mid-time, in seconds after its first row (measured against
        // the middle of the untrimmed free fall, which the catch's slow detection moves late:
        // 2–5 % more coverage error and a longer tail on simulated and synthetic throws).
        let t_mid_s = 0.5 * f64::from(segment.len()) * dt_s;
        let identity_len = Matrix3::<f64>::identity() * len;

        let mut row_eq = Normal9::new();
        row_eq.gtg.fixed_view_mut::<3, 3>(0, 0).copy_from(&rows.xtx().map(f));
        let xsum = rows.xsum.map(f);
        row_eq.gtg.fixed_view_mut::<3, 3>(0, 3).copy_from(&xsum.transpose());
        row_eq.gtg.fixed_view_mut::<3, 3>(3, 0).copy_from(&xsum);
        let n = f64::from(rows.count);
        row_eq.gtg.fixed_view_mut::<3, 3>(3, 3).copy_from(&(Matrix3::identity() * n));
        row_eq.gty.fixed_rows_mut::<3>(0).copy_from(&rows.xty.map(f));
        row_eq.gty.fixed_rows_mut::<3>(3).copy_from(&rows.ysum.map(f));
        row_eq.yty = f(rows.yty);
        row_eq.count = rows.count;

        let (mut q_rw, mut q_bw, mut g_w) = (Matrix3::zeros(), Matrix3::zeros(), Vector3::zeros());
        let mut s2_sum = 0.0;
        let (mut short, mut long) = (Normal9::new(), Normal9::new());
        let (mut long_g, mut long_y, mut long_blocks) = (Matrix3x9::zeros(), Vector3::zeros(), 0);
        for (b, block) in blocks.iter().enumerate() {
            // The block's mean profile, and Σ s² of its rows (the exact drag–drag term).
            let first = b as f64 * len;
            let (mut s_sum, mut s2) = (0.0, 0.0);
            for k in 0..block_len {
                let tau = (first + f64::from(k)) * dt_s - t_mid_s;
                let s = tau.abs() * tau;
                s_sum += s;
                s2 += s * s;
            }
            let s_mean = s_sum / len;
            s2_sum += s2;
            let rsum = block.drag.rsum.map(f);
            q_rw += block.drag.xtr.map(f) * s_mean;
            q_bw += rsum * s_mean;
            g_w += block.drag.ry.map(f) * s_mean;
            let mut g = Matrix3x9::zeros();
            g.fixed_view_mut::<3, 3>(0, 0).copy_from(&block.xsum.map(f));
            g.fixed_view_mut::<3, 3>(0, 3).copy_from(&identity_len);
            g.fixed_view_mut::<3, 3>(0, 6).copy_from(&(rsum * s_mean));
            let y = block.ysum.map(f);
            short.add(&g, &y);
            long_g += g;
            long_y += y;
            long_blocks += 1;
            if long_blocks >= group.max(1) {
                long.add(&long_g, &long_y);
                (long_g, long_y, long_blocks) = (Matrix3x9::zeros(), Vector3::zeros(), 0);
            }
        }
        // The throw's last long batch, when at least half full, counts with its sums scaled to
        // a full batch's variance (√(group / blocks)): the drag vectors take 3 degrees of
        // freedom per throw, and a short throw would otherwise leave the long batches none.
        if 2 * long_blocks >= group.max(1) {
            let scale = libm::sqrt(f64::from(group.max(1)) / f64::from(long_blocks));
            long.add(&(long_g * scale), &(long_y * scale));
        }
        row_eq.gtg.fixed_view_mut::<3, 3>(0, 6).copy_from(&q_rw);
        row_eq.gtg.fixed_view_mut::<3, 3>(6, 0).copy_from(&q_rw.transpose());
        row_eq.gtg.fixed_view_mut::<3, 3>(3, 6).copy_from(&q_bw);
        row_eq.gtg.fixed_view_mut::<3, 3>(6, 3).copy_from(&q_bw.transpose());
        row_eq.gtg.fixed_view_mut::<3, 3>(6, 6).copy_from(&(Matrix3::identity() * s2_sum));
        row_eq.gty.fixed_rows_mut::<3>(6).copy_from(&g_w);

        // Without a drag fit (no profile at all: a degenerate throw) the rows count as they are.
        let (d, c_w) = match row_eq.profile() {
            Some(p) => {
                self.segments = self.segments.saturating_add(1);
                p
            }
            None => (SMatrix::<f64, 3, 6>::zeros(), Vector3::zeros()),
        };
        row_eq.fold(&d, &c_w, &mut self.rows);
        short.fold(&d, &c_w, &mut self.short);
        long.fold(&d, &c_w, &mut self.long);
    }

    /// Move the reference offset by `delta` (m), exactly.
    pub(crate) fn recentre(&mut self, delta: &Vector3<f64>) {
        self.rows.recentre(delta);
        self.short.recentre(delta);
        self.long.recentre(delta);
    }
}
