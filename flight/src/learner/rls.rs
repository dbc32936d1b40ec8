//! Recursive least squares, one covariance shared by several outputs (docs/algorithms/learner.md).
//!
//! Model: `yₖ = xᵀ θₖ + e` for `M` outputs `k` that share the regressor vector `x` (length
//! `n ≤ N`). Because the regressors are shared, so is the covariance `P` (`n × n`): one gain
//! `K = P x / (λ + xᵀ P x)` updates every output's parameters, `θₖ += K eₖ`, and
//! `P = (P − K xᵀ P) / λ`. This is how the effectiveness rows of one kind (three specific-force
//! rows, three angular-acceleration rows) are estimated at the cost of one.
//!
//! Numerical guards of the published system, kept because the learner runs in f32 for half a
//! second on data whose excitation switches from one motor to the next:
//! - **trace-decrease limit**: one update may remove at most [`MAX_TRACE_DECREASE`] of `tr P`
//!   (a single very informative sample cannot collapse the covariance);
//! - **covariance wind-up**: directions without excitation grow by `1/λ` per step; when a diagonal
//!   of `P` exceeds `p_max`, the step uses `λ = 1 / WINDUP_SHRINK` (> 1), shrinking `P` back;
//! - **symmetry**: only the upper triangle of `P` is stored (packed by rows), so `P` is exactly
//!   symmetric by construction and needs no re-symmetrisation;
//! - **bad input**: a non-finite regressor or output is refused with [`RlsError`] and changes
//!   nothing.
//!
//! Arithmetic is `f64` inside (inputs and outputs are `f32`): the effectiveness regressions mix
//! parameters whose information differs by ten orders of magnitude (a motor's column during its
//! pulse, the Euler-term coefficients fed only by slow rate changes), and the covariance update
//! `P − a aᵀ/(λ + s)` then cancels catastrophically in single precision (estimates off by 10⁷ on
//! the simulator's octorotor). The Cortex-M7 of the H743 has a double-precision FPU
//! (`-C target-cpu=cortex-m7`), so this costs about the same instruction count as `f32`.
//!
//! Cost (the learner's budget on the Cortex-M7, docs/benchmarks.md): `update` is `O(n²)` over the
//! `n (n + 1)/2` stored entries only. `P x` reads each stored entry once and uses it twice
//! (`P_ij x_j` for `a_i`, `P_ij x_i` for `a_j`), and the rank-one downdate writes each once: the
//! dense form read all `n²` entries and wrote the lower triangle again as a mirror. With λ = 1
//! (the learner's setting) the downdate skips the division by λ. An estimator of at most
//! four regressors that uses them all (the motor model) runs an update compiled for that count,
//! its loops unrolled and inlined: on the octorotor's rotational-row sample the eight motor
//! models' updates went from about 3,700 to 2,850 instructions (`cargo xtask bench-m7`).
//!
//! `no_std`, fixed capacity (`N` regressors at most, `L = N (N + 1)/2` covariance entries), no
//! allocation.

// Index loops are kept where they mirror the matrix notation of the derivation (rows, columns,
// regressors by index), as in `thrust_axis`.
#![allow(clippy::needless_range_loop)]

/// Largest fraction of `tr P` one update may remove (published: 90 %).
pub const MAX_TRACE_DECREASE: f32 = 0.9;
/// Factor applied to `P` per step while a diagonal exceeds `p_max` (i.e. `λ = 1/0.99 > 1`).
pub const WINDUP_SHRINK: f32 = 0.99;

/// Why an update was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RlsError {
    /// A regressor or an output is NaN or infinite.
    NonFinite,
    /// The regressor vector's length is not the estimator's `n`.
    Length { expected: usize, got: usize },
}

/// Tuning of an [`Rls`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RlsConfig {
    /// Forgetting factor λ ∈ (0, 1]: 1 weighs all data equally; `exp(−Ts/T)` forgets with time
    /// constant `T`.
    pub lambda: f32,
    /// Initial covariance diagonal `P₀` (published: 100, with regressors scaled to order 1).
    pub p0: f32,
    /// Diagonal of `P` above which forgetting is suspended (see the module doc).
    pub p_max: f32,
}

impl Default for RlsConfig {
    fn default() -> Self {
        Self { lambda: 1.0, p0: 100.0, p_max: 1e4 }
    }
}

/// Length of the packed upper triangle of a symmetric `n × n` matrix: `n (n + 1) / 2`. The third
/// parameter of [`Rls`] is `packed_len(N)` (stable Rust cannot compute an array length from `N`).
pub const fn packed_len(n: usize) -> usize {
    n * (n + 1) / 2
}

/// The estimator: `n ≤ N` shared regressors, `M` outputs, `L = packed_len(N)` covariance entries.
#[derive(Clone, Debug)]
pub struct Rls<const N: usize, const M: usize, const L: usize> {
    n: usize,
    config: RlsConfig,
    /// `theta[j][k]`: coefficient of regressor `j` in output `k`.
    theta: [[f64; M]; N],
    /// Upper triangle of `P` (`n × n`) packed by rows: row `i` holds `P[i][i..n]` and starts at
    /// [`Rls::row_start`]`(i)`; the first `packed_len(n)` entries are used.
    p: [f64; L],
    /// Exponentially weighted mean of the squared a-priori errors per output (time constant
    /// about `noise_window` updates): the noise variance used for parameter uncertainty.
    error_var: [f64; M],
    /// Updates over which `error_var` is averaged ([`NOISE_WINDOW`] unless set).
    noise_window: f32,
    updates: u32,
}

/// Most regressors of an estimator whose update is compiled for its own count (when it uses
/// all of them): the motor model's four. Larger estimators keep one copy of the update.
const UNROLLED_MAX: usize = 4;

/// Updates over which the a-priori error variance is averaged, by default (0.1 s at 2 kHz).
pub const NOISE_WINDOW: f32 = 200.0;

impl<const N: usize, const M: usize, const L: usize> Rls<N, M, L> {
    /// An estimator with `n` regressors (clamped to `1..=N`), θ = 0 and `P = P₀ I`.
    pub fn new(n: usize, config: RlsConfig) -> Self {
        let mut slot = core::mem::MaybeUninit::uninit();
        // SAFETY: a local slot, valid and aligned; `build_at` writes every field.
        unsafe {
            Self::build_at(slot.as_mut_ptr(), n, config);
            slot.assume_init()
        }
    }

    /// [`Rls::new`] in place at `this` (the covariance is up to 11 KB: never a temporary).
    ///
    /// # Safety
    /// `this` must be valid for writes and aligned.
    pub(crate) unsafe fn build_at(this: *mut Self, n: usize, config: RlsConfig) {
        const { assert!(L == packed_len(N), "Rls<N, M, L> needs L = packed_len(N)") };
        use core::ptr::addr_of_mut;
        addr_of_mut!((*this).n).write(n.clamp(1, N));
        addr_of_mut!((*this).config).write(config);
        // All-zero bytes are 0.0: the arrays are zeroed where they lie.
        addr_of_mut!((*this).theta).write_bytes(0, 1);
        addr_of_mut!((*this).p).write_bytes(0, 1);
        addr_of_mut!((*this).error_var).write_bytes(0, 1);
        addr_of_mut!((*this).noise_window).write(NOISE_WINDOW);
        addr_of_mut!((*this).updates).write(0);
        (*this).reset();
    }

    /// Average the noise variance over `updates` updates (at least one) instead of
    /// [`NOISE_WINDOW`]: the same time span for an estimator updated less often.
    pub fn set_noise_window(&mut self, updates: f32) {
        self.noise_window = if updates >= 1.0 { updates } else { 1.0 };
    }

    /// Back to θ = 0 and `P = P₀ I`.
    pub fn reset(&mut self) {
        self.theta = [[0.0; M]; N];
        self.p = [0.0; L];
        for i in 0..self.n {
            self.p[self.row_start(i)] = f64::from(self.config.p0);
        }
        self.error_var = [0.0; M];
        self.updates = 0;
    }

    /// Sets the prior variance `P[j][j]` of parameter `j` (before any update: a prior).
    pub fn set_prior_variance(&mut self, j: usize, variance: f32) {
        if j < self.n {
            let at = self.row_start(j);
            self.p[at] = f64::from(variance);
        }
    }

    /// Sets the prior covariance `P[i][j]` (= `P[j][i]`) before any update: a prior.
    pub fn set_prior_covariance(&mut self, i: usize, j: usize, value: f32) {
        let (i, j) = (i.min(j), i.max(j));
        if j < self.n {
            let at = self.row_start(i) + j - i;
            self.p[at] = f64::from(value);
        }
    }

    /// Index of `P[i][i]` in the packed storage: rows `0..i` hold `n, n − 1, …, n − i + 1`
    /// entries.
    #[inline]
    fn row_start(&self, i: usize) -> usize {
        i * (2 * self.n + 1 - i) / 2
    }

    /// Number of regressors.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Always false (at least one regressor).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Updates accepted since the last reset.
    pub fn updates(&self) -> u32 {
        self.updates
    }

    /// Coefficient of regressor `j` in output `k`.
    #[inline]
    pub fn theta(&self, j: usize, k: usize) -> f32 {
        self.theta[j][k] as f32
    }

    /// Overwrite coefficient `j` of output `k` (e.g. to carry an earlier estimate over).
    pub fn set_theta(&mut self, j: usize, k: usize, value: f32) {
        if j < self.n && k < M && value.is_finite() {
            self.theta[j][k] = f64::from(value);
        }
    }

    /// Covariance diagonal entry `P[j][j]` (relative variance of regressor `j`'s coefficients);
    /// 0 for `j ≥ n`.
    #[inline]
    pub fn p_diag(&self, j: usize) -> f32 {
        if j < self.n {
            self.p[self.row_start(j)] as f32
        } else {
            0.0
        }
    }

    /// Covariance entry `P[i][j]` (either order; 0 outside `n × n`).
    pub fn covariance(&self, i: usize, j: usize) -> f64 {
        let (i, j) = (i.min(j), i.max(j));
        if j < self.n {
            self.p[self.row_start(i) + j - i]
        } else {
            0.0
        }
    }

    /// Mean squared a-priori error of output `k` (the noise variance estimate).
    pub fn error_var(&self, k: usize) -> f32 {
        self.error_var[k] as f32
    }

    /// The prediction `xᵀ θₖ` for each output.
    pub fn predict(&self, x: &[f32]) -> [f32; M] {
        self.predict_f64(x).map(|y| y as f32)
    }

    fn predict_f64(&self, x: &[f32]) -> [f64; M] {
        let mut y = [0.0; M];
        for (j, xj) in x.iter().enumerate().take(self.n) {
            for (k, yk) in y.iter_mut().enumerate() {
                *yk += f64::from(*xj) * self.theta[j][k];
            }
        }
        y
    }

    /// One update with regressors `x` (length `n`) and outputs `y`. Returns the a-priori errors.
    pub fn update(&mut self, x: &[f32], y: &[f32; M]) -> Result<[f32; M], RlsError> {
        // A small estimator using all its regressors (a motor model: 4 of 4) runs the update
        // with its count as a constant, so that every loop unrolls into straight-line code: on
        // the octorotor the learner makes eight such updates a sample.
        if N <= UNROLLED_MAX && self.n == N {
            self.update_with::<true>(N, x, y)
        } else {
            self.update_with::<false>(self.n, x, y)
        }
    }

    /// [`Rls::update`] for `n == self.n` regressors; `INLINE`: the row loops inlined (for a
    /// constant `n`).
    #[inline(always)]
    fn update_with<const INLINE: bool>(
        &mut self,
        n: usize,
        x: &[f32],
        y: &[f32; M],
    ) -> Result<[f32; M], RlsError> {
        if x.len() != n {
            return Err(RlsError::Length { expected: n, got: x.len() });
        }
        if !(x.iter().all(|v| v.is_finite()) && y.iter().all(|v| v.is_finite())) {
            return Err(RlsError::NonFinite);
        }
        let mut x_store = [0.0f64; N];
        for (d, v) in x_store.iter_mut().zip(x) {
            *d = f64::from(*v);
        }
        let x = &x_store[..n];
        // a = P x, with tr P and the largest diagonal entry on the way.
        let mut a_store = [0.0f64; N];
        let a = &mut a_store[..n];
        let (trace, max_diag) =
            symmetric_product::<INLINE>(self.p.get(..packed_len(n)).unwrap_or(&[]), x, a);
        let a = &*a;
        let lambda = if max_diag > f64::from(self.config.p_max) {
            1.0 / f64::from(WINDUP_SHRINK)
        } else {
            f64::from(self.config.lambda)
        };
        // s = xᵀ P x, ‖a‖² and the prediction xᵀ θₖ in one pass.
        let (mut s, mut norm2, mut predicted) = (0.0f64, 0.0f64, [0.0f64; M]);
        for ((aj, xj), theta) in a.iter().zip(x).zip(&self.theta) {
            s += aj * xj;
            norm2 += aj * aj;
            for (p, t) in predicted.iter_mut().zip(theta) {
                *p += xj * t;
            }
        }
        let denominator = lambda + s;
        if !(denominator.is_finite() && denominator > 0.0) {
            return Err(RlsError::NonFinite);
        }
        let inv = 1.0 / denominator;
        // A-priori errors and parameter update θₖ += K eₖ with K = P x / (λ + s).
        let mut error = [0.0f64; M];
        for ((e, y), p) in error.iter_mut().zip(y).zip(&predicted) {
            *e = f64::from(*y) - p;
        }
        for (theta, aj) in self.theta[..n].iter_mut().zip(a) {
            let kj = aj * inv;
            for (t, e) in theta.iter_mut().zip(&error) {
                *t += kj * e;
            }
        }
        // Covariance: P ← (P − α K xᵀ P)/λ with K xᵀ P = a aᵀ/(λ + s); the trace it removes is
        // ‖a‖²/(λ + s), limited to MAX_TRACE_DECREASE of tr P by α ≤ 1. Only the upper triangle
        // is stored, so P stays exactly symmetric. With λ = 1 (the usual case) no entry is
        // multiplied by 1/λ.
        let removed = norm2 * inv;
        let limit = f64::from(MAX_TRACE_DECREASE) * trace;
        let alpha = if removed > limit && removed > 0.0 { limit / removed } else { 1.0 };
        let gain = alpha * inv;
        let packed = self.p.get_mut(..packed_len(n)).unwrap_or(&mut []);
        if lambda == 1.0 {
            downdate::<INLINE>(packed, a, gain, |v| v);
        } else {
            let inv_lambda = 1.0 / lambda;
            downdate::<INLINE>(packed, a, gain, |v| v * inv_lambda);
        }
        let w = 1.0 / f64::from(self.noise_window.min(self.updates as f32 + 1.0));
        for k in 0..M {
            self.error_var[k] += w * (error[k] * error[k] - self.error_var[k]);
        }
        self.updates = self.updates.saturating_add(1);
        Ok(error.map(|e| e as f32))
    }
}

/// `a = P x` from the packed upper triangle of `P` (`x.len()` rows), and `(tr P, max P_ii)`: a
/// stored row gives its own entry of `a` its dot product with `x` and, mirrored, every later
/// entry its `P_ij x_i`. Rows go in pairs, which share the loads of `x_j` and `a_j` and halve
/// the loop set-ups (the rows are short: 23 regressors on a quad).
#[inline(always)]
fn symmetric_product<const INLINE: bool>(packed: &[f64], x: &[f64], a: &mut [f64]) -> (f64, f64) {
    let n = x.len().min(a.len());
    let (mut trace, mut max_diag) = (0.0f64, 0.0f64);
    let mut rows = packed;
    let mut i = 0;
    while i + 1 < n {
        // Rows i (P_ii, P_i,i+1, tail0) and i + 1 (P_i+1,i+1, tail1); tails over j ≥ i + 2.
        let (row0, rest) = rows.split_at(n - i);
        let (row1, rest) = rest.split_at(n - i - 1);
        rows = rest;
        let (Some(([d0, p01], tail0)), Some((&d1, tail1))) =
            (row0.split_first_chunk::<2>(), row1.split_first())
        else {
            break;
        };
        let (head, tail) = a.split_at_mut(i + 2);
        let (x0, x1) = (x[i], x[i + 1]);
        let (dot0, dot1) = if tail0.is_empty() {
            (0.0, 0.0)
        } else if x0 == 0.0 && x1 == 0.0 {
            // Nothing to mirror: regressors that are zero by construction (the effectiveness
            // balance's other-axis torques) cost only the dot products.
            if INLINE {
                dot2_inline(tail0, tail1, &x[i + 2..])
            } else {
                dot2(tail0, tail1, &x[i + 2..])
            }
        } else {
            if INLINE {
                dot_and_axpy_inline(tail0, tail1, &x[i + 2..], tail, (x0, x1))
            } else {
                dot_and_axpy(tail0, tail1, &x[i + 2..], tail, (x0, x1))
            }
        };
        head[i] += d0 * x0 + p01 * x1 + dot0;
        head[i + 1] += p01 * x0 + d1 * x1 + dot1;
        trace += d0 + d1;
        max_diag = max_diag.max(*d0).max(d1);
        i += 2;
    }
    if let (Some(&d), true) = (rows.first(), i < n) {
        // The last row of an odd n: its diagonal only.
        a[i] += d * x[i];
        trace += d;
        max_diag = max_diag.max(d);
    }
    (trace, max_diag)
}

/// `P ← scale(P − gain · a aᵀ)` on the packed upper triangle of `P` (`a.len()` rows), rows in
/// pairs as in [`symmetric_product`].
#[inline(always)]
fn downdate<const INLINE: bool>(packed: &mut [f64], a: &[f64], gain: f64, scale: impl Scale) {
    let n = a.len();
    let mut rows = packed;
    let mut i = 0;
    while i + 1 < n {
        let (row0, rest) = core::mem::take(&mut rows).split_at_mut(n - i);
        let (row1, rest) = rest.split_at_mut(n - i - 1);
        rows = rest;
        let (Some(([d0, p01], tail0)), Some((d1, tail1))) =
            (row0.split_first_chunk_mut::<2>(), row1.split_first_mut())
        else {
            break;
        };
        let (g0, g1) = (a[i] * gain, a[i + 1] * gain);
        *d0 = scale(*d0 - g0 * a[i]);
        *p01 = scale(*p01 - g0 * a[i + 1]);
        *d1 = scale(*d1 - g1 * a[i + 1]);
        if !tail0.is_empty() {
            if INLINE {
                rows_downdate_inline(tail0, tail1, &a[i + 2..], (g0, g1), scale);
            } else {
                rows_downdate(tail0, tail1, &a[i + 2..], (g0, g1), scale);
            }
        }
        i += 2;
    }
    if let (Some(d), true) = (rows.first_mut(), i < n) {
        *d = scale(*d - a[i] * gain * a[i]);
    }
}

/// What a downdate writes each entry through: the identity, or the division by λ (as a product
/// by `1/λ`).
trait Scale: Fn(f64) -> f64 + Copy {}

impl<F: Fn(f64) -> f64 + Copy> Scale for F {}

/// A value for each of two rows (row 0's, row 1's). The Rust ABI passes a pair of scalars as
/// two scalars, so a `Pair` argument compiles as two `f64` arguments would (the same code,
/// `cargo xtask bench-m7`'s learner rows unchanged).
type Pair = (f64, f64);

/// Two rows' tails: `row0_j ← scale(row0_j − g0 a_j)` and the same for `row1` with `g1`. Not
/// inlined: a small loop of its own keeps its registers (inlined into the update, the loop
/// spilled to the stack on every entry).
#[inline(never)]
fn rows_downdate(row0: &mut [f64], row1: &mut [f64], a: &[f64], g: Pair, scale: impl Scale) {
    rows_downdate_inline(row0, row1, a, g, scale)
}

/// [`rows_downdate`] inlined (rows of a constant length, unrolled by the compiler).
#[inline(always)]
fn rows_downdate_inline(row0: &mut [f64], row1: &mut [f64], a: &[f64], g: Pair, scale: impl Scale) {
    let (g0, g1) = g;
    for ((p0, p1), aj) in row0.iter_mut().zip(row1).zip(a) {
        *p0 = scale(*p0 - g0 * aj);
        *p1 = scale(*p1 - g1 * aj);
    }
}

/// Two rows' tails: `Σ_j row0_j x_j` and `Σ_j row1_j x_j` (rows whose own regressors are zero).
#[inline(never)]
fn dot2(row0: &[f64], row1: &[f64], x: &[f64]) -> Pair {
    dot2_inline(row0, row1, x)
}

/// [`dot2`] inlined.
#[inline(always)]
fn dot2_inline(row0: &[f64], row1: &[f64], x: &[f64]) -> Pair {
    let (mut dot0, mut dot1) = (0.0, 0.0);
    for ((p0, p1), xj) in row0.iter().zip(row1).zip(x) {
        dot0 += p0 * xj;
        dot1 += p1 * xj;
    }
    (dot0, dot1)
}

/// Two rows' tails: `Σ_j row0_j x_j` and `Σ_j row1_j x_j`, and `acc_j += row0_j x0 + row1_j x1`
/// on the way (`x01`: `(x0, x1)`). Not inlined, for the same reason as [`rows_downdate`].
#[inline(never)]
fn dot_and_axpy(row0: &[f64], row1: &[f64], x: &[f64], acc: &mut [f64], x01: Pair) -> Pair {
    dot_and_axpy_inline(row0, row1, x, acc, x01)
}

/// [`dot_and_axpy`] inlined.
#[inline(always)]
fn dot_and_axpy_inline(row0: &[f64], row1: &[f64], x: &[f64], acc: &mut [f64], x01: Pair) -> Pair {
    let (x0, x1) = x01;
    let (mut dot0, mut dot1) = (0.0, 0.0);
    for (((p0, p1), xj), aj) in row0.iter().zip(row1).zip(x).zip(acc) {
        dot0 += p0 * xj;
        dot1 += p1 * xj;
        // Two multiply-accumulates (`vmla.f64`), not a product sum added at the end (a
        // multiply, a multiply-accumulate and an add): one instruction less per entry pair.
        *aj += p0 * x0;
        *aj += p1 * x1;
    }
    (dot0, dot1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn recovers_shared_regressor_parameters_of_three_outputs() {
        let truth = [[1.0f32, -2.0, 0.5], [0.25, 3.0, -1.0], [-0.7, 0.1, 2.0], [0.0, 0.3, -0.4]];
        let mut rls = Rls::<8, 3, 36>::new(4, RlsConfig::default());
        let mut rng = Rng::new(7);
        for _ in 0..2000 {
            let x: [f32; 4] = core::array::from_fn(|_| rng.normal() as f32);
            let mut y = [0.0f32; 3];
            for k in 0..3 {
                for j in 0..4 {
                    y[k] += x[j] * truth[j][k];
                }
                y[k] += 0.01 * rng.normal() as f32;
            }
            rls.update(&x, &y).unwrap();
        }
        for j in 0..4 {
            for k in 0..3 {
                assert!((rls.theta(j, k) - truth[j][k]).abs() < 2e-3, "θ[{j}][{k}]");
            }
        }
        // Noise variance 1e-4 (σ = 0.01), seen through the a-priori errors.
        assert!((rls.error_var(0) / 1e-4 - 1.0).abs() < 0.3, "{}", rls.error_var(0));
    }

    /// A tight prior on one parameter holds it near its prior value where the data cannot tell
    /// it from another (two identical regressors), while the loose one takes the rest: the
    /// minimum-norm split of the data's sum without it.
    #[test]
    fn a_tight_prior_holds_a_parameter_the_data_leave_free() {
        let config = RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 };
        let mut rls = Rls::<2, 1, 3>::new(2, config);
        rls.set_theta(1, 0, 0.5);
        rls.set_prior_variance(1, 1e-4);
        for _ in 0..200 {
            // y = 3 = θ₀ + θ₁ with x = (1, 1): only the sum is observed.
            rls.update(&[1.0, 1.0], &[3.0]).unwrap();
        }
        assert!((rls.theta(1, 0) - 0.5).abs() < 1e-3, "θ₁ = {}", rls.theta(1, 0));
        assert!((rls.theta(0, 0) - 2.5).abs() < 1e-3, "θ₀ = {}", rls.theta(0, 0));
        let mut free = Rls::<2, 1, 3>::new(2, config);
        free.set_theta(1, 0, 0.5);
        for _ in 0..200 {
            free.update(&[1.0, 1.0], &[3.0]).unwrap();
        }
        // Without the prior the sum's excess is split evenly: θ₁ = 0.5 + (3 − 0.5)/2.
        assert!((free.theta(1, 0) - 1.75).abs() < 1e-3, "θ₁ = {}", free.theta(1, 0));
    }

    #[test]
    fn bad_input_is_refused_and_changes_nothing() {
        let mut rls = Rls::<4, 1, 10>::new(2, RlsConfig::default());
        rls.update(&[1.0, 0.5], &[2.0]).unwrap();
        let before = rls.clone();
        assert_eq!(rls.update(&[f32::NAN, 0.0], &[1.0]), Err(RlsError::NonFinite));
        assert_eq!(rls.update(&[1.0, 0.0], &[f32::INFINITY]), Err(RlsError::NonFinite));
        assert_eq!(rls.update(&[1.0], &[1.0]), Err(RlsError::Length { expected: 2, got: 1 }));
        assert_eq!(rls.theta, before.theta);
        assert_eq!(rls.p, before.p);
        assert_eq!(rls.updates(), 1);
    }

    #[test]
    fn one_sample_removes_at_most_ninety_percent_of_the_trace() {
        let mut rls = Rls::<2, 1, 3>::new(2, RlsConfig { p0: 1e6, ..RlsConfig::default() });
        let trace = |r: &Rls<2, 1, 3>| r.p_diag(0) + r.p_diag(1);
        let before = trace(&rls);
        rls.update(&[10.0, 0.0], &[1.0]).unwrap();
        let after = trace(&rls);
        assert!(after >= (1.0 - MAX_TRACE_DECREASE) * before * 0.999, "{before} -> {after}");
    }

    #[test]
    fn unexcited_directions_do_not_wind_up_past_p_max() {
        let config = RlsConfig { lambda: 0.99, p0: 100.0, p_max: 1e4 };
        let mut rls = Rls::<2, 1, 3>::new(2, config);
        // Only regressor 0 is ever excited: P[1][1] grows by 1/λ per step until the guard.
        for _ in 0..5000 {
            rls.update(&[1.0, 0.0], &[3.0]).unwrap();
        }
        assert!(rls.p_diag(1) <= 1e4 / WINDUP_SHRINK * 1.001, "{}", rls.p_diag(1));
        assert!((rls.theta(0, 0) - 3.0).abs() < 1e-4);
    }

    /// The dense form this estimator replaced (full `n × n` covariance, upper triangle computed
    /// and mirrored, one row per call), kept as the reference of the packed one. Counts how often
    /// the trace-decrease limit and the wind-up guard acted.
    struct DenseRls<const N: usize> {
        n: usize,
        config: RlsConfig,
        theta: [[f64; 3]; N],
        p: [[f64; N]; N],
        /// Sum `P x` in reverse order (a second rounding of the same arithmetic).
        reversed: bool,
        limited: usize,
        wound_up: usize,
    }

    impl<const N: usize> DenseRls<N> {
        fn new(n: usize, config: RlsConfig) -> Self {
            let mut p = [[0.0; N]; N];
            for (i, row) in p.iter_mut().enumerate().take(n) {
                row[i] = f64::from(config.p0);
            }
            let theta = [[0.0; 3]; N];
            Self { n, config, theta, p, reversed: false, limited: 0, wound_up: 0 }
        }

        fn update(&mut self, x: &[f32], y: &[f32; 3]) {
            let n = self.n;
            let xd: [f64; N] = core::array::from_fn(|i| x.get(i).map_or(0.0, |v| f64::from(*v)));
            let (mut px, mut s, mut trace, mut max_diag) = ([0.0f64; N], 0.0, 0.0, 0.0f64);
            for i in 0..n {
                let term = |j: usize| self.p[i][j] * xd[j];
                px[i] = if self.reversed {
                    (0..n).rev().map(term).sum()
                } else {
                    (0..n).map(term).sum()
                };
                s += xd[i] * px[i];
                trace += self.p[i][i];
                max_diag = max_diag.max(self.p[i][i]);
            }
            let lambda = if max_diag > f64::from(self.config.p_max) {
                self.wound_up += 1;
                1.0 / f64::from(WINDUP_SHRINK)
            } else {
                f64::from(self.config.lambda)
            };
            let inv = 1.0 / (lambda + s);
            for k in 0..3 {
                let e = f64::from(y[k]) - (0..n).map(|j| xd[j] * self.theta[j][k]).sum::<f64>();
                for j in 0..n {
                    self.theta[j][k] += px[j] * inv * e;
                }
            }
            let removed = px[..n].iter().map(|a| a * a).sum::<f64>() * inv;
            let limit = f64::from(MAX_TRACE_DECREASE) * trace;
            let alpha = if removed > limit && removed > 0.0 { limit / removed } else { 1.0 };
            self.limited += usize::from(alpha < 1.0);
            for i in 0..n {
                for j in i..n {
                    let value = (self.p[i][j] - px[i] * alpha * inv * px[j]) / lambda;
                    self.p[i][j] = value;
                    self.p[j][i] = value;
                }
            }
        }
    }

    /// Regressors of very different sizes (`10^(j mod 5 − 2)` times `scale`), some silent for
    /// long stretches (as one motor's columns while another is pulsed), in pairs (as the
    /// balance's other-axis torques: the product `P x` skips such pairs), and three outputs.
    fn sample(rng: &mut Rng, step: usize, scale: f64) -> ([f32; 23], [f32; 3]) {
        let mut x = [0.0f32; 23];
        for (j, v) in x.iter_mut().enumerate() {
            // Regressor 2 is silent for the first 1500 steps: its variance then holds nearly
            // all of tr P, and its first samples are limited by the trace guard.
            let active =
                if j == 2 { step >= 1500 } else { !(step / 300 + j / 2).is_multiple_of(4) };
            let size = scale * 10f64.powi(j as i32 % 5 - 2);
            *v = if active { (size * rng.normal()) as f32 } else { 0.0 };
        }
        let y = core::array::from_fn(|k| {
            (x[k] - 0.5 * x[k + 3] + 2.0 * x[22 - k]) + 0.01 * rng.normal() as f32
        });
        (x, y)
    }

    /// Largest |θ| difference over the largest |θ|, and largest |P| difference over
    /// `√(P_ii P_jj)`.
    fn deviation<const N: usize, const L: usize>(
        packed: &Rls<N, 3, L>,
        dense: &DenseRls<N>,
    ) -> (f64, f64) {
        let n = dense.n;
        let theta_scale = dense.theta.iter().flatten().fold(0.0f64, |m, t| m.max(t.abs()));
        let (mut theta, mut p) = (0.0f64, 0.0f64);
        for j in 0..n {
            for k in 0..3 {
                theta = theta.max((packed.theta[j][k] - dense.theta[j][k]).abs() / theta_scale);
            }
            for i in 0..n {
                let scale = (dense.p[i][i] * dense.p[j][j]).sqrt();
                p = p.max((packed.covariance(i, j) - dense.p[i][j]).abs() / scale);
            }
        }
        (theta, p)
    }

    /// The packed covariance gives the dense estimator's θ and P to 1e-9 relative on a quad's
    /// rotational-row size (23 regressors, three outputs), through the trace-decrease limit, the
    /// wind-up guard (forgetting with unexcited regressors) and ordinary updates.
    #[test]
    fn packed_covariance_matches_the_dense_reference() {
        // Forgetting with wind-up; no forgetting with a prior large enough for the trace limit.
        let configs = [
            RlsConfig { lambda: 0.99, p0: 100.0, p_max: 1e3 },
            RlsConfig { lambda: 1.0, p0: 1e3, p_max: 1e10 },
        ];
        let (mut limited, mut wound_up) = (0, 0);
        for config in configs {
            let mut packed = Rls::<31, 3, { packed_len(31) }>::new(23, config);
            let mut dense = DenseRls::<31>::new(23, config);
            let mut rng = Rng::new(11);
            for step in 0..3000 {
                let (x, y) = sample(&mut rng, step, 1.0);
                packed.update(&x, &y).unwrap();
                dense.update(&x, &y);
            }
            limited += dense.limited;
            wound_up += dense.wound_up;
            let (theta, p) = deviation(&packed, &dense);
            assert!(theta < 1e-9 && p < 1e-9, "{config:?}: θ {theta:e}, P {p:e}");
        }
        assert!(limited > 0 && wound_up > 0, "guards acted {limited}, {wound_up} times");
    }

    /// With the learner's prior (P₀ = 1e6, falling to 1e-7 within the run: ten orders of
    /// magnitude of cancellation) the result depends on the rounding of `P x` at a few 1e-8:
    /// the dense estimator summing in reverse order differs from itself that much. The packed
    /// one stays within three times that (measured: θ 1.7e-8, P 4.0e-8, reversed dense
    /// 3.3e-8).
    #[test]
    fn packed_covariance_is_within_rounding_of_the_dense_reference_with_a_huge_prior() {
        let config = RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 };
        let mut packed = Rls::<31, 3, { packed_len(31) }>::new(23, config);
        let mut dense = DenseRls::<31>::new(23, config);
        let mut reversed = DenseRls::<31>::new(23, config);
        reversed.reversed = true;
        let mut rng = Rng::new(11);
        for step in 0..3000 {
            let (x, y) = sample(&mut rng, step, 1.0);
            packed.update(&x, &y).unwrap();
            dense.update(&x, &y);
            reversed.update(&x, &y);
        }
        assert!(dense.limited > 0);
        let (theta, p) = deviation(&packed, &dense);
        let reversed_theta = dense
            .theta
            .iter()
            .flatten()
            .zip(reversed.theta.iter().flatten())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
            / dense.theta.iter().flatten().fold(0.0f64, |m, t| m.max(t.abs()));
        assert!(
            theta < 1e-7 && p < 1e-7,
            "θ {theta:e} (reversed dense: {reversed_theta:e}), P {p:e}"
        );
    }
}
