//! One motor's model from its command and its measured speed (docs/algorithms/learner.md):
//!
//! ```text
//! ω = a·δ + b·√δ + ω_idle − τ·ω̇
//! ```
//!
//! i.e. the first-order lag `τ ω̇ = ω_s(δ) − ω` towards the steady-state speed
//! `ω_s = a δ + b √δ + ω_idle`. Linear in `θ = (a, b, ω_idle, τ)` with the regressors
//! `(δ, √δ, A, −ω̇)` and the output ω, so an [`Rls`] finds it. `A` is 1 while the ESC runs the
//! motor and 0 while it is stopped (before the first non-zero command after a throw): a stopped
//! motor reads ω = 0, not ω_idle, and the spin-up to idle at arming is then part of the model
//! instead of a violation of it. All four signals pass through the
//! same 2nd-order Butterworth low-pass (40 Hz published), so the relation holds between the
//! filtered signals exactly (the model is linear in the regressors); ω̇ is the central difference
//! of the filtered ω, and the others are taken one sample late to line up with it.
//!
//! Scaling for f32 (regressors of order one): ω in krad/s, ω̇ in units of 100 krad/s², so the
//! parameters are `a/1000`, `b/1000`, `ω_idle/1000` (krad/s) and `100·τ` (s/100).
//!
//! Time alignment is the caller's: pair each speed with the command that was driving the motor
//! when the speed was measured (pairing it with the command of the same step biases τ by
//! about +1 ms: docs/algorithms/learner.md).

use super::rls::{packed_len, Rls, RlsConfig};
use crate::filters::{BiquadCoefficients, Butterworth2};

/// Speed unit of the regression, rad/s (krad/s keeps ω of order one).
const SPEED_SCALE_RAD_S: f32 = 1000.0;
/// Acceleration unit of the regression, rad/s² (100 krad/s²: a 2 krad/s step over 25 ms).
const ACCEL_SCALE_RAD_S2: f32 = 100_000.0;
/// τ in the regression is in units of `SPEED_SCALE / ACCEL_SCALE` = 10 ms.
const TAU_SCALE_S: f32 = SPEED_SCALE_RAD_S / ACCEL_SCALE_RAD_S2;

/// A learned motor model.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MotorModel {
    /// Linear coefficient `a`, rad/s per unit command.
    pub a_rad_s: f32,
    /// Square-root coefficient `b`, rad/s per √command.
    pub b_rad_s: f32,
    /// Speed at δ = 0 while armed, rad/s.
    pub omega_idle_rad_s: f32,
    /// First-order time constant, s.
    pub tau_s: f32,
    /// One standard deviation of `tau_s`, s (from the RLS covariance and the residuals).
    pub tau_std_s: f32,
    /// Whether the model has converged (see [`MotorModel::is_usable`]).
    pub converged: bool,
}

impl MotorModel {
    /// Speed at full command δ = 1, rad/s: `a + b + ω_idle`.
    pub fn omega_full_rad_s(&self) -> f32 {
        self.a_rad_s + self.b_rad_s + self.omega_idle_rad_s
    }

    /// Nonlinearity `κ = a/(a + b)` (1: speed linear in the command).
    pub fn kappa(&self) -> f32 {
        let sum = self.a_rad_s + self.b_rad_s;
        if sum.abs() > 1e-6 {
            self.a_rad_s / sum
        } else {
            1.0
        }
    }

    /// Steady-state speed for command δ (clamped to [0, 1]), rad/s.
    pub fn steady_speed_rad_s(&self, command: f32) -> f32 {
        let d = if command.is_finite() { command.clamp(0.0, 1.0) } else { 0.0 };
        self.a_rad_s * d + self.b_rad_s * crate::math::sqrt(d) + self.omega_idle_rad_s
    }

    /// Whether the parameters describe a motor that speeds up with its command and lags with a
    /// positive time constant.
    pub fn is_usable(&self) -> bool {
        self.tau_s > 0.0
            && self.a_rad_s + self.b_rad_s > 0.0
            && self.omega_idle_rad_s >= -0.1 * (self.a_rad_s + self.b_rad_s)
    }
}

/// The estimator of one motor's model.
#[derive(Clone, Debug)]
pub struct MotorModelEstimator {
    rls: Rls<4, 1, { packed_len(4) }>,
    filter: BiquadCoefficients,
    /// Filters of δ, √δ, A (armed) and ω (in that order).
    lowpass: [Butterworth2; 4],
    /// Filtered (δ, √δ, A, ω) of the two previous samples, newest first.
    history: [[f32; 4]; 2],
    seen: u8,
    half_rate_hz: f32,
}

impl MotorModelEstimator {
    /// An estimator for samples at `rate_hz`, filtering at `filter.cutoff` (designed by the caller).
    pub fn new(filter: BiquadCoefficients, rate_hz: f32, config: RlsConfig) -> Self {
        Self {
            rls: Rls::new(4, config),
            filter,
            lowpass: [Butterworth2::from_coefficients(filter); 4],
            history: [[0.0; 4]; 2],
            seen: 0,
            half_rate_hz: 0.5 * rate_hz,
        }
    }

    /// Forget everything (a new identification).
    pub fn reset(&mut self) {
        self.rls.reset();
        self.restart_filters();
    }

    /// Restart the filters only (after a gap in the speed reports), keeping the estimate.
    pub fn restart_filters(&mut self) {
        self.lowpass = [Butterworth2::from_coefficients(self.filter); 4];
        self.seen = 0;
    }

    /// One sample: the command δ that drove the motor when `speed_rad_s` was measured, and
    /// whether the ESC was running the motor then (`armed`).
    pub fn update(&mut self, command: f32, armed: bool, speed_rad_s: f32) {
        if !(command.is_finite() && speed_rad_s.is_finite()) {
            self.restart_filters();
            return;
        }
        let d = command.clamp(0.0, 1.0);
        let armed = if armed { 1.0 } else { 0.0 };
        let raw = [d, crate::math::sqrt(d), armed, speed_rad_s / SPEED_SCALE_RAD_S];
        if self.seen == 0 {
            for (f, x) in self.lowpass.iter_mut().zip(raw) {
                f.reset_to(x);
            }
        }
        let filtered: [f32; 4] = core::array::from_fn(|i| self.lowpass[i].update(raw[i]));
        let [previous, before] = self.history;
        self.history = [filtered, previous];
        if self.seen < 2 {
            self.seen += 1;
            return;
        }
        // Central difference, centred on the previous sample (in speed units per ACCEL_SCALE).
        let speed_dot =
            (filtered[3] - before[3]) * self.half_rate_hz * SPEED_SCALE_RAD_S / ACCEL_SCALE_RAD_S2;
        let x = [previous[0], previous[1], previous[2], -speed_dot];
        // Refused only for non-finite values, which were excluded above.
        let _ = self.rls.update(&x, &[previous[3]]);
    }

    /// The model so far.
    pub fn model(&self) -> MotorModel {
        let theta = |j| self.rls.theta(j, 0);
        let noise = self.rls.error_var(0);
        let tau_std_s = crate::math::sqrt((self.rls.p_diag(3) * noise).max(0.0)) * TAU_SCALE_S;
        let mut model = MotorModel {
            a_rad_s: theta(0) * SPEED_SCALE_RAD_S,
            b_rad_s: theta(1) * SPEED_SCALE_RAD_S,
            omega_idle_rad_s: theta(2) * SPEED_SCALE_RAD_S,
            tau_s: theta(3) * TAU_SCALE_S,
            tau_std_s,
            converged: false,
        };
        model.converged = self.rls.updates() > 0 && model.is_usable() && tau_std_s < 0.5e-3;
        model
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A first-order motor driven by a pulse like the excitation's, sampled at 2 kHz.
    #[test]
    fn recovers_the_curve_and_time_constant_of_a_simulated_motor() {
        let (a, b, idle, tau) = (1080.0f32, 1620.0, 300.0, 0.025);
        let rate_hz = 2000.0;
        let dt = 1.0 / rate_hz;
        let filter = BiquadCoefficients::butterworth_lowpass(40.0, rate_hz).unwrap();
        let mut estimator = MotorModelEstimator::new(filter, rate_hz, RlsConfig::default());
        // Stopped until the first command (as after a throw), then armed.
        let mut omega = 0.0;
        for _ in 0..20 {
            estimator.update(0.0, false, omega);
        }
        for n in 0..400 {
            let t = n as f32 * dt;
            let command = if t < 0.03 {
                0.35
            } else if t < 0.09 {
                0.7 * (1.0 - (t - 0.03) / 0.06)
            } else {
                0.0
            };
            // Exact first-order response over one step to the held command.
            let target = a * command + b * libm::sqrtf(command) + idle;
            omega = target + (omega - target) * libm::expf(-dt / tau);
            estimator.update(command, true, omega);
        }
        let model = estimator.model();
        // The discrete zero-order hold adds half a sample of lag: τ within 0.5 ms.
        assert!((model.tau_s - tau).abs() < 0.5e-3, "τ = {} s", model.tau_s);
        assert!((model.omega_full_rad_s() - (a + b + idle)).abs() < 0.02 * (a + b + idle));
        assert!((model.omega_idle_rad_s - idle).abs() < 30.0, "{}", model.omega_idle_rad_s);
        assert!((model.kappa() - 0.4).abs() < 0.05, "κ = {}", model.kappa());
        assert!(model.is_usable());
    }

    #[test]
    fn non_finite_speeds_only_restart_the_filters() {
        let filter = BiquadCoefficients::butterworth_lowpass(40.0, 2000.0).unwrap();
        let mut estimator = MotorModelEstimator::new(filter, 2000.0, RlsConfig::default());
        estimator.update(0.5, true, f32::NAN);
        estimator.update(f32::INFINITY, true, 1000.0);
        assert_eq!(estimator.model().tau_s, 0.0);
        assert!(!estimator.model().converged);
    }
}
