//! Recursive least squares with one covariance shared by several outputs (algorithms.md §3).
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
//! - **symmetry**: only the upper triangle is updated and mirrored, so `P` stays exactly
//!   symmetric;
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
//! `no_std`, fixed capacity (`N` regressors at most), no allocation; `update` is `O(n²)`.

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

/// The estimator: `n ≤ N` shared regressors, `M` outputs.
#[derive(Clone, Debug)]
pub struct Rls<const N: usize, const M: usize> {
    n: usize,
    config: RlsConfig,
    /// `theta[j][k]`: coefficient of regressor `j` in output `k`.
    theta: [[f64; M]; N],
    p: [[f64; N]; N],
    /// Exponentially weighted mean of the squared a-priori errors per output (time constant
    /// about [`NOISE_WINDOW`] updates): the noise variance used for parameter uncertainty.
    error_var: [f64; M],
    updates: u32,
}

/// Updates over which the a-priori error variance is averaged.
pub const NOISE_WINDOW: f32 = 200.0;

impl<const N: usize, const M: usize> Rls<N, M> {
    /// An estimator with `n` regressors (clamped to `1..=N`), θ = 0 and `P = P₀ I`.
    pub fn new(n: usize, config: RlsConfig) -> Self {
        let mut rls = Self {
            n: n.clamp(1, N),
            config,
            theta: [[0.0; M]; N],
            p: [[0.0; N]; N],
            error_var: [0.0; M],
            updates: 0,
        };
        rls.reset();
        rls
    }

    /// Back to θ = 0 and `P = P₀ I`.
    pub fn reset(&mut self) {
        self.theta = [[0.0; M]; N];
        self.p = [[0.0; N]; N];
        for i in 0..self.n {
            self.p[i][i] = f64::from(self.config.p0);
        }
        self.error_var = [0.0; M];
        self.updates = 0;
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

    /// Covariance diagonal entry `P[j][j]` (relative variance of regressor `j`'s coefficients).
    #[inline]
    pub fn p_diag(&self, j: usize) -> f32 {
        self.p[j][j] as f32
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
        let n = self.n;
        if x.len() != n {
            return Err(RlsError::Length { expected: n, got: x.len() });
        }
        if !(x.iter().all(|v| v.is_finite()) && y.iter().all(|v| v.is_finite())) {
            return Err(RlsError::NonFinite);
        }
        // a = P x, s = xᵀ P x. Slices of length n throughout: no bounds check in the loops.
        let mut xd = [0.0f64; N];
        for (d, v) in xd.iter_mut().zip(x) {
            *d = f64::from(*v);
        }
        let xd = &xd[..n];
        let mut px_store = [0.0f64; N];
        let px = &mut px_store[..n];
        let mut s = 0.0f64;
        let mut trace = 0.0f64;
        let mut max_diag = 0.0f64;
        for (i, (row, a)) in self.p[..n].iter().zip(px.iter_mut()).enumerate() {
            let acc: f64 = row[..n].iter().zip(xd).map(|(p, x)| p * x).sum();
            *a = acc;
            s += xd[i] * acc;
            trace += row[i];
            max_diag = max_diag.max(row[i]);
        }
        let lambda = if max_diag > f64::from(self.config.p_max) {
            1.0 / f64::from(WINDUP_SHRINK)
        } else {
            f64::from(self.config.lambda)
        };
        let denominator = lambda + s;
        if !(denominator.is_finite() && denominator > 0.0) {
            return Err(RlsError::NonFinite);
        }
        let inv = 1.0 / denominator;
        // A-priori errors and parameter update θₖ += K eₖ with K = P x / (λ + s).
        let predicted = self.predict_f64(x);
        let mut error = [0.0f64; M];
        for ((e, y), p) in error.iter_mut().zip(y).zip(&predicted) {
            *e = f64::from(*y) - p;
        }
        for (theta, a) in self.theta[..n].iter_mut().zip(px.iter()) {
            let kj = a * inv;
            for (t, e) in theta.iter_mut().zip(&error) {
                *t += kj * e;
            }
        }
        // Covariance: P ← (P − α K xᵀ P)/λ with K xᵀ P = a aᵀ/(λ + s); the trace it removes is
        // ‖a‖²/(λ + s), limited to MAX_TRACE_DECREASE of tr P by α ≤ 1. The upper triangle is
        // computed and mirrored, so P stays exactly symmetric.
        let removed = px.iter().map(|a| a * a).sum::<f64>() * inv;
        let limit = f64::from(MAX_TRACE_DECREASE) * trace;
        let alpha = if removed > limit && removed > 0.0 { limit / removed } else { 1.0 };
        let gain = alpha * inv;
        let inv_lambda = 1.0 / lambda;
        for i in 0..n {
            let ai = px[i] * gain;
            for j in i..n {
                let value = (self.p[i][j] - ai * px[j]) * inv_lambda;
                self.p[i][j] = value;
                self.p[j][i] = value;
            }
        }
        let w = 1.0 / f64::from(NOISE_WINDOW.min(self.updates as f32 + 1.0));
        for k in 0..M {
            self.error_var[k] += w * (error[k] * error[k] - self.error_var[k]);
        }
        self.updates = self.updates.saturating_add(1);
        Ok(error.map(|e| e as f32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn recovers_shared_regressor_parameters_of_three_outputs() {
        let truth = [[1.0f32, -2.0, 0.5], [0.25, 3.0, -1.0], [-0.7, 0.1, 2.0], [0.0, 0.3, -0.4]];
        let mut rls = Rls::<8, 3>::new(4, RlsConfig::default());
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
        for i in 0..4 {
            for j in 0..4 {
                assert_eq!(rls.p[i][j], rls.p[j][i], "P stays exactly symmetric");
            }
        }
    }

    #[test]
    fn bad_input_is_refused_and_changes_nothing() {
        let mut rls = Rls::<4, 1>::new(2, RlsConfig::default());
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
        let mut rls = Rls::<2, 1>::new(2, RlsConfig { p0: 1e6, ..RlsConfig::default() });
        let trace = |r: &Rls<2, 1>| r.p_diag(0) + r.p_diag(1);
        let before = trace(&rls);
        rls.update(&[10.0, 0.0], &[1.0]).unwrap();
        let after = trace(&rls);
        assert!(after >= (1.0 - MAX_TRACE_DECREASE) * before * 0.999, "{before} -> {after}");
    }

    #[test]
    fn unexcited_directions_do_not_wind_up_past_p_max() {
        let config = RlsConfig { lambda: 0.99, p0: 100.0, p_max: 1e4 };
        let mut rls = Rls::<2, 1>::new(2, config);
        // Only regressor 0 is ever excited: P[1][1] grows by 1/λ per step until the guard.
        for _ in 0..5000 {
            rls.update(&[1.0, 0.0], &[3.0]).unwrap();
        }
        assert!(rls.p_diag(1) <= 1e4 / WINDUP_SHRINK * 1.001, "{}", rls.p_diag(1));
        assert!((rls.theta(0, 0) - 3.0).abs() < 1e-4);
    }
}
