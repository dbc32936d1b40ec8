//! The effectiveness matrices G1 and G2 from the body's response to the motors
//! (algorithms.md §5, with the two corrections of §12 that the published recipe lacked).
//!
//! # Model (IMU axes, motor speeds ω in rad/s)
//! ```text
//! f_cog = G1f ω² + f_rest                         (specific force at the centre of gravity)
//! Ω̇     = G1τ ω² + G2 ω̇ − I⁻¹ Ω × (I Ω + h)       (angular acceleration)
//! ```
//! `G1` (6 × m) is per unit squared speed, m/s² or rad/s² per (rad/s)²; `G2` (3 × m) is rad/s²
//! per rad/s² of motor acceleration (the reaction of the rotor inertia, mostly yaw); `h` is the
//! rotors' angular momentum. As published, the regression works on increments (differences of
//! samples) of signals through one 2nd-order Butterworth low-pass (20 Hz): slowly varying
//! disturbances cancel, and Ω̇ comes from differentiating the filtered gyro. The filters run on
//! every sample; the regressions on every fourth, one per sample in turn
//! ([`REGRESSION_DECIMATION`]), so the increments span four samples.
//!
//! **Specific-force rows.** The accelerometer is moved to the centre of gravity with the stored
//! IMU offset `r`: `f_cog = f_imu − Ω̇×r − Ω×(Ω×r)`. The rest `f_rest` is mostly aerodynamic drag,
//! which on a tumbling craft is fixed in the *world*, not the body: in body axes it turns at −Ω,
//! so its increment is `−w × f_rest` (`w = Ω dt`), not zero (the main error of the published
//! recipe, §12). Substituting `f_rest = f_cog − G1f ω²` gives an equation that is still linear
//! in G1f, and exact:
//! `Δf_cog + w × f_cog = G1f Δ(ω²) + w × (G1f ω²)`.
//! Its three rows have different regressors (the cross product mixes them), so the force rows
//! are one RLS over all `3m` entries of G1f with three scalar updates (one per row). A constant
//! accelerometer bias `b` is fixed in the *body* and leaves `−w × b` in the equation instead:
//! three more parameters (`b`, index `3m..3m+3`) with the regressor `−w ×`. (Estimating
//! `f_rest` from the current G1f instead is cheaper but biased: early in the excitation G1f is
//! still far off, and the rotation term is a quarter of the signal at 400 °/s; it gave 15–30 %
//! errors on the seed paper's quad.)
//!
//! **Angular-acceleration rows.** The Euler and rotor-gyroscopic terms are quadratic in the
//! rates and spoil G1τ when ignored (§12). With `h = −I G2 ω` (the definition of G2),
//! `I⁻¹ Ω × (I Ω + h) = I⁻¹ Ω × I Ω + I⁻¹ Ω × I δv` with `δv = −G2 ω`: fixed linear maps of the
//! six distinct products `Ωₐ Ω_b` and of the nine `Ωₐ δv_b`. Those fifteen join the regressors
//! (with `δv` from the current G2 estimate):
//! `ΔΩ̇ = G1τ Δ(ω²) + G2 Δω̇ + E Δ(products)`, E (3 × 15) estimated and discarded. (Writing the
//! term as nine products `Ωₐ v_b` with `v = Ω + δv` is shorter but three pairs of them are
//! identical while G2 is still zero, and that exact collinearity wrecked the f32 covariance:
//! 30–90 % errors on an octorotor.)
//!
//! The three rotational rows share their regressors, so one [`Rls`] with a shared covariance
//! serves them (`2m + 9` regressors); the force rows are one `3m + 3`-parameter RLS.
//!
//! Scaling for f32: ω² in (krad/s)², ω̇ in 100 krad/s², rate products in (10 rad/s)².

// Index loops are kept where they mirror the matrix notation of the derivation (rows, columns,
// regressors by index), as in `thrust_axis`.
#![allow(clippy::needless_range_loop)]

use super::rls::{packed_len, Rls, RlsConfig, NOISE_WINDOW};
use super::MAX_MOTORS;
use crate::filters::{BiquadCoefficients, Butterworth2, Butterworth2x3};
use nalgebra::Vector3;

/// Corner of the first-order high-pass applied to every regressor and output of the increment
/// regressions, Hz: with the 20 Hz low-pass, the regressions see a band around 20 Hz. What
/// remains of drag after the world-frame correction (its change with airspeed and with the
/// body's anisotropy), the slow precession of a tumbling body and any error in the rotor
/// momentum term all vary at 0.2–2 Hz, while the motor pulses carry 5–40 Hz. The high-pass is a
/// linear time-invariant filter applied alike to both sides, so the linear relation between them
/// is kept. Chosen on the simulator's Monte Carlo (200 random airframes): the median worst-row G1
/// error was 16 % without it, 15 % at 4 Hz, 9.2 % at 16 Hz and 8.8 % at 20 Hz; 40 Hz low-pass
/// with 16–25 Hz high-pass was no better.
pub const HIGH_PASS_HZ: f32 = 20.0;

/// The four regressions (the three specific-force rows, the angular-acceleration rows) take
/// turns, one per sample, each on every fourth centred sample: 500 Hz at the 2 kHz control
/// rate. One sample then costs one of them, never all four (docs/benchmarks.md, issue 7: the
/// background task must finish every sample within its share of a control period on the
/// Cortex-M7). Nothing is lost that the regressions use: every signal has been through the
/// 20 Hz low-pass at the full rate first (the filter attenuates the 250 Hz Nyquist frequency of
/// 500 Hz by 44 dB, twice that far by 56 dB), and the motor pulses carry 5–40 Hz. Each
/// regression's increments span four samples; its high-pass and the rotation over an
/// increment use that step.
pub const REGRESSION_DECIMATION: u8 = 4;

/// Centred samples kept: one cycle of the regressions.
const CENTRED_RING: usize = REGRESSION_DECIMATION as usize;

/// Which regression a sample fed ([`EffectivenessEstimator::update`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regression {
    /// None (the filters are starting, or the sample was a gap).
    None,
    /// Specific-force row 0, 1 or 2 (x, y, z).
    ForceRow(u8),
    /// The angular-acceleration rows.
    Rotation,
    /// All four (no decimation).
    All,
}

/// Squared-speed unit of the regression, (rad/s)².
pub const SPEED2_SCALE: f32 = 1e6;
/// Motor-acceleration unit of the regression, rad/s².
pub const SPEED_DOT_SCALE: f32 = 1e5;
/// Rate-product unit of the regression, (rad/s)².
const RATE2_SCALE: f32 = 100.0;
/// Regressors of the rotational rows besides the motors': the nine products `Ωₐ v_b`.
const RATE_PRODUCTS: usize = 6 + 9;
/// Capacity of the rotational regression: `2·8 + 15`.
pub const ROT_REGRESSORS_MAX: usize = 2 * MAX_MOTORS + RATE_PRODUCTS;
/// Capacity of the force regression: the `3·8` entries of G1f (index `3i + axis`) and the
/// accelerometer bias (the last three).
pub const FORCE_PARAMETERS_MAX: usize = 3 * MAX_MOTORS + 3;

/// One sample of every filtered signal.
#[derive(Clone, Copy, Debug, Default)]
struct Filtered {
    gyro: Vector3<f32>,
    /// Accelerometer less the centripetal term `Ω×(Ω×r)` (formed before filtering).
    accel: Vector3<f32>,
    speed: [f32; MAX_MOTORS],
    speed2: [f32; MAX_MOTORS],
    products: [f32; RATE_PRODUCTS],
}

/// One centred sample of the filtered signals.
#[derive(Clone, Copy, Debug, Default)]
struct Centred {
    /// ω²/SPEED2_SCALE per motor.
    speed2: [f32; MAX_MOTORS],
    /// ω̇/SPEED_DOT_SCALE per motor.
    speed_dot: [f32; MAX_MOTORS],
    rate: Vector3<f32>,
    rate_dot: Vector3<f32>,
    f_cog: Vector3<f32>,
    /// Filtered rate products (see `rate_products`).
    products: [f32; RATE_PRODUCTS],
}

/// The G1/G2 estimator.
#[derive(Clone, Debug)]
pub struct EffectivenessEstimator {
    motors: usize,
    /// Samples between the two ends of a regression's increment: [`REGRESSION_DECIMATION`], or
    /// 1 for every regression on every sample.
    decimation: u8,
    /// Time between the two ends of an increment, s.
    increment_s: f32,
    half_rate_hz: f32,
    r_imu_m: Vector3<f32>,
    /// How much older the speed reports are than the IMU sample of the same step, s.
    speed_lag_s: f32,
    filter: BiquadCoefficients,
    gyro: Butterworth2x3,
    accel: Butterworth2x3,
    speed: [Butterworth2; MAX_MOTORS],
    /// Filters of the squared speeds (ω²/SPEED2_SCALE): the model is linear in ω², and the
    /// square of a filtered speed is not the filtered square while the speed changes fast.
    speed2: [Butterworth2; MAX_MOTORS],
    /// Filters of the rate products (formed from raw samples, then filtered: the product of
    /// filtered signals is not the filtered product at 400 °/s).
    products: [Butterworth2; RATE_PRODUCTS],
    /// The filtered signals of the last three samples: a ring, the newest at `newest`.
    history: [Filtered; 3],
    newest: usize,
    seen: u8,
    /// The last centred samples, sample `c` at `c mod CENTRED_RING`.
    centred: [Centred; CENTRED_RING],
    /// Centred samples since the filters started; modulo the decimation it chooses the
    /// regression.
    centred_count: u32,
    force: Rls<FORCE_PARAMETERS_MAX, 1, { packed_len(FORCE_PARAMETERS_MAX) }>,
    /// High-pass of each force row's regressors and output (the output last).
    force_high_pass: [HighPass<{ FORCE_PARAMETERS_MAX + 1 }>; 3],
    /// High-pass of the rotational regressors and outputs (the outputs last).
    rotation_high_pass: HighPass<{ ROT_REGRESSORS_MAX + 3 }>,
    /// Pole of the first-order high-passes at the regressions' rate, `exp(−2π f_c / f_s)`.
    high_pass_pole: f32,
    /// Sample rate, Hz (for the pole when the decimation changes).
    rate_hz: f32,
    rotation: Rls<ROT_REGRESSORS_MAX, 3, { packed_len(ROT_REGRESSORS_MAX) }>,
}

impl EffectivenessEstimator {
    /// An estimator for `motors` motors (clamped to 1..=8) at `rate_hz`, filtering with `filter`,
    /// moving the accelerometer to the centre of gravity with `r_imu_m` (IMU axes, m), with speed
    /// reports `speed_lag_s` older than the IMU samples they come with (compensated by moving
    /// the filtered squared speeds forward along their derivative).
    pub fn new(
        motors: usize,
        rate_hz: f32,
        filter: BiquadCoefficients,
        r_imu_m: [f32; 3],
        speed_lag_s: f32,
        config: RlsConfig,
    ) -> Self {
        let motors = motors.clamp(1, MAX_MOTORS);
        let mut estimator = Self {
            motors,
            decimation: 1,
            increment_s: 0.0,
            half_rate_hz: 0.5 * rate_hz,
            r_imu_m: Vector3::from(r_imu_m),
            speed_lag_s: if speed_lag_s.is_finite() { speed_lag_s } else { 0.0 },
            filter,
            gyro: Butterworth2x3::from_coefficients(filter),
            accel: Butterworth2x3::from_coefficients(filter),
            speed: [Butterworth2::from_coefficients(filter); MAX_MOTORS],
            speed2: [Butterworth2::from_coefficients(filter); MAX_MOTORS],
            products: [Butterworth2::from_coefficients(filter); RATE_PRODUCTS],
            history: [Filtered::default(); 3],
            newest: 0,
            seen: 0,
            centred: [Centred::default(); CENTRED_RING],
            centred_count: 0,
            force: Rls::new(3 * motors + 3, config),
            force_high_pass: [HighPass::default(); 3],
            rotation_high_pass: HighPass::default(),
            high_pass_pole: 0.0,
            rate_hz,
            rotation: Rls::new(2 * motors + RATE_PRODUCTS, config),
        };
        estimator.set_decimation(REGRESSION_DECIMATION);
        estimator
    }

    /// The same estimator with its regressions on every `decimation`-th centred sample: 1 (every
    /// regression on every sample, as published) or [`REGRESSION_DECIMATION`] (the default; other
    /// values are taken as that). Restarts the filters.
    pub fn with_decimation(mut self, decimation: u8) -> Self {
        self.set_decimation(decimation);
        self.restart_filters();
        self
    }

    fn set_decimation(&mut self, decimation: u8) {
        self.decimation = if decimation == 1 { 1 } else { REGRESSION_DECIMATION };
        let regression_rate_hz = self.rate_hz / f32::from(self.decimation);
        self.increment_s = 1.0 / regression_rate_hz;
        self.high_pass_pole =
            libm::expf(-core::f32::consts::TAU * HIGH_PASS_HZ / regression_rate_hz);
        // The noise variance over the same time as at every sample.
        let window = NOISE_WINDOW / f32::from(self.decimation);
        self.force.set_noise_window(window);
        self.rotation.set_noise_window(window);
    }

    /// Forget everything (a new identification), with a new IMU offset.
    pub fn reset(&mut self, r_imu_m: [f32; 3]) {
        self.r_imu_m = Vector3::from(r_imu_m);
        self.force.reset();
        self.rotation.reset();
        self.restart_filters();
    }

    /// Restart the filters only (after a gap in the data), keeping the estimates.
    pub fn restart_filters(&mut self) {
        self.gyro = Butterworth2x3::from_coefficients(self.filter);
        self.accel = Butterworth2x3::from_coefficients(self.filter);
        self.speed = [Butterworth2::from_coefficients(self.filter); MAX_MOTORS];
        self.speed2 = [Butterworth2::from_coefficients(self.filter); MAX_MOTORS];
        self.products = [Butterworth2::from_coefficients(self.filter); RATE_PRODUCTS];
        self.seen = 0;
        self.centred_count = 0;
        self.force_high_pass = [HighPass::default(); 3];
        self.rotation_high_pass = HighPass::default();
    }

    /// One sample: gyro (rad/s) and accelerometer (m/s²) in IMU axes, motor speeds (rad/s).
    /// Non-finite values restart the filters (the sample is a gap). Returns the regression the
    /// sample fed.
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds_rad_s: &[f32],
    ) -> Regression {
        let m = self.motors;
        let finite = gyro_rad_s.iter().chain(&accel_mps2).chain(speeds_rad_s.iter().take(m));
        if speeds_rad_s.len() < m || !finite.into_iter().all(|v| v.is_finite()) {
            self.restart_filters();
            return Regression::None;
        }
        let gyro = Vector3::from(gyro_rad_s);
        let r = self.r_imu_m;
        let accel = Vector3::from(accel_mps2) - gyro.cross(&gyro.cross(&r));
        let mut speed2 = [0.0; MAX_MOTORS];
        for i in 0..m {
            speed2[i] = speeds_rad_s[i] * speeds_rad_s[i] / SPEED2_SCALE;
        }
        let products = self.rate_products(&gyro, &speeds_rad_s[..m]);
        if self.seen == 0 {
            self.gyro.reset_to(&gyro);
            self.accel.reset_to(&accel);
            for i in 0..m {
                self.speed[i].reset_to(speeds_rad_s[i]);
                self.speed2[i].reset_to(speed2[i]);
            }
            for (f, x) in self.products.iter_mut().zip(products) {
                f.reset_to(x);
            }
        }
        // Filtered in place into the ring's oldest slot.
        self.newest = (self.newest + 1) % 3;
        let filtered = &mut self.history[self.newest];
        filtered.gyro = self.gyro.update(&gyro);
        filtered.accel = self.accel.update(&accel);
        for i in 0..m {
            filtered.speed[i] = self.speed[i].update(speeds_rad_s[i]);
            filtered.speed2[i] = self.speed2[i].update(speed2[i]);
        }
        for j in 0..RATE_PRODUCTS {
            filtered.products[j] = self.products[j].update(products[j]);
        }
        if self.seen < 2 {
            self.seen += 1;
            return Regression::None;
        }
        let [filtered, previous, before] = [0, 2, 1].map(|k| &self.history[(self.newest + k) % 3]);
        // Centred on the previous sample: central differences of gyro and speeds.
        let rate_dot = (filtered.gyro - before.gyro) * self.half_rate_hz;
        let f_cog = previous.accel - rate_dot.cross(&r);
        let mut now = Centred {
            rate: previous.gyro,
            rate_dot,
            f_cog,
            products: previous.products,
            ..Centred::default()
        };
        let lead = self.speed_lag_s * self.half_rate_hz;
        for i in 0..m {
            now.speed2[i] = previous.speed2[i] + (filtered.speed2[i] - before.speed2[i]) * lead;
            let speed_dot = (filtered.speed[i] - before.speed[i]) * self.half_rate_hz;
            let speed_ddot = (filtered.speed[i] - 2.0 * previous.speed[i] + before.speed[i])
                * (4.0 * self.half_rate_hz * self.half_rate_hz);
            // The motor accelerations are moved forward by the report lag too: the rotor
            // reaction (G2) acts at once.
            now.speed_dot[i] = (speed_dot + speed_ddot * self.speed_lag_s) / SPEED_DOT_SCALE;
        }
        // This sample's regression, on the increment from `decimation` centred samples back.
        // The ring holds the centred samples of the last cycle; `now` takes the oldest's place
        // after it has been read.
        let count = self.centred_count;
        self.centred_count = count.saturating_add(1);
        let decimation = u32::from(self.decimation);
        let last = self.centred[count.wrapping_sub(decimation) as usize % CENTRED_RING];
        self.centred[count as usize % CENTRED_RING] = now;
        if count < decimation {
            return Regression::None;
        }
        if decimation == 1 {
            for k in 0..3 {
                self.regress_force_row(k, &last, &now);
            }
            self.regress_rotation(&last, &now);
            return Regression::All;
        }
        match count % decimation {
            // The last of the cycle (the first three are the force rows).
            3 => {
                self.regress_rotation(&last, &now);
                Regression::Rotation
            }
            k => {
                self.regress_force_row(k as usize, &last, &now);
                Regression::ForceRow(k as u8)
            }
        }
    }

    /// Force row `k`: (Δf_cog + w × f_cog)ₖ = (G1f Δ(ω²) + w × (G1f ω²))ₖ, parameters
    /// G1f[axis][i] at index 3i + axis; the regressor is Δ(ω²)ᵢ on (i, k) and the cross-product
    /// terms.
    fn regress_force_row(&mut self, k: usize, last: &Centred, now: &Centred) {
        let m = self.motors;
        let n = 3 * m + 3;
        let w = now.rate * self.increment_s;
        let y = (now.f_cog - last.f_cog) + w.cross(&last.f_cog);
        let mut x = [0.0f32; FORCE_PARAMETERS_MAX + 1];
        for i in 0..m {
            let (du, u) = (now.speed2[i] - last.speed2[i], last.speed2[i]);
            let column = &mut x[3 * i..3 * i + 3];
            // (w × g)ₖ = w_{k+1} g_{k+2} − w_{k+2} g_{k+1} (indices mod 3).
            column[k] = du;
            column[(k + 2) % 3] = w[(k + 1) % 3] * u;
            column[(k + 1) % 3] = -w[(k + 2) % 3] * u;
        }
        // −(w × b)ₖ = −w_{k+1} b_{k+2} + w_{k+2} b_{k+1}.
        let bias = &mut x[3 * m..3 * m + 3];
        bias[k] = 0.0;
        bias[(k + 2) % 3] = -w[(k + 1) % 3];
        bias[(k + 1) % 3] = w[(k + 2) % 3];
        x[n] = y[k];
        self.force_high_pass[k].apply(&mut x[..n + 1], self.high_pass_pole);
        let _ = self.force.update(&x[..n], &[x[n]]);
    }

    /// Rotational rows: ΔΩ̇ = G1τ Δ(ω²) + G2 Δω̇ + E Δ(Ω ⊗ v), v = Ω − G2 ω.
    fn regress_rotation(&mut self, last: &Centred, now: &Centred) {
        let m = self.motors;
        let mut x = [0.0f32; ROT_REGRESSORS_MAX + 3];
        for i in 0..m {
            x[i] = now.speed2[i] - last.speed2[i];
        }
        for i in 0..m {
            x[m + i] = now.speed_dot[i] - last.speed_dot[i];
        }
        for j in 0..RATE_PRODUCTS {
            x[2 * m + j] = now.products[j] - last.products[j];
        }
        let n = 2 * m + RATE_PRODUCTS;
        let y = now.rate_dot - last.rate_dot;
        x[n..n + 3].copy_from_slice(&[y.x, y.y, y.z]);
        self.rotation_high_pass.apply(&mut x[..n + 3], self.high_pass_pole);
        let _ = self.rotation.update(&x[..n], &[x[n], x[n + 1], x[n + 2]]);
    }

    /// The rate products `/ RATE2_SCALE`: the six distinct `Ωₐ Ω_b` (a ≤ b), then the nine
    /// `Ωₐ δv_b` with `δv = −G2 ω` from the current estimate (the rotors' momentum term).
    fn rate_products(&self, rate: &Vector3<f32>, speeds_rad_s: &[f32]) -> [f32; RATE_PRODUCTS] {
        let mut dv = Vector3::zeros();
        for (i, speed) in speeds_rad_s.iter().enumerate() {
            dv -= self.g2_column(i) * *speed;
        }
        let mut out = [0.0; RATE_PRODUCTS];
        let mut j = 0;
        for a in 0..3 {
            for b in a..3 {
                out[j] = rate[a] * rate[b] / RATE2_SCALE;
                j += 1;
            }
        }
        for a in 0..3 {
            for b in 0..3 {
                out[6 + 3 * a + b] = rate[a] * dv[b] / RATE2_SCALE;
            }
        }
        out
    }

    /// Column `i` of G2, rad/s² per rad/s².
    fn g2_column(&self, i: usize) -> Vector3<f32> {
        let j = self.motors + i;
        Vector3::new(
            self.rotation.theta(j, 0),
            self.rotation.theta(j, 1),
            self.rotation.theta(j, 2),
        ) / SPEED_DOT_SCALE
    }

    /// Number of motors.
    pub fn motors(&self) -> usize {
        self.motors
    }

    /// G1 per unit squared speed: rows 0–2 m/s², rows 3–5 rad/s², per (rad/s)², IMU axes.
    pub fn g1_per_speed2(&self) -> [[f32; MAX_MOTORS]; 6] {
        let mut g1 = [[0.0; MAX_MOTORS]; 6];
        for i in 0..self.motors {
            for k in 0..3 {
                g1[k][i] = self.force.theta(3 * i + k, 0) / SPEED2_SCALE;
                g1[3 + k][i] = self.rotation.theta(i, k) / SPEED2_SCALE;
            }
        }
        g1
    }

    /// G2, rad/s² of body angular acceleration per rad/s² of motor acceleration, IMU axes.
    pub fn g2(&self) -> [[f32; MAX_MOTORS]; 3] {
        let mut g2 = [[0.0; MAX_MOTORS]; 3];
        for i in 0..self.motors {
            let column = self.g2_column(i);
            for k in 0..3 {
                g2[k][i] = column[k];
            }
        }
        g2
    }

    /// How much has been learned about motor `i`'s columns: the covariance diagonal of its
    /// squared-speed regressor relative to the prior, for the force and the rotational rows
    /// (1: nothing yet; small: well excited).
    ///
    /// Not rescaled for the decimation: the learner's gate on it
    /// ([`super::AXIS_INFORMATION_FRACTION`]) is crossed in the first milliseconds of a pulse,
    /// while the prior still dominates `P`, and the decimated regressions cross it when the
    /// every-sample ones did (the simulator's paper quad: first thrust axis 163.5 ms into the
    /// excitation, 161.5 ms at every sample; referring `P` to one-sample increments, × 4, would
    /// delay it to 221.5 ms).
    pub fn information_left(&self, i: usize, p0: f32) -> (f32, f32) {
        let force = (0..3).map(|k| self.force.p_diag(3 * i + k)).fold(0.0, f32::max);
        (force / p0, self.rotation.p_diag(i) / p0)
    }

    /// Relative standard deviation of column `i` of G1f and of G1τ (one σ of the column's norm
    /// over the norm), from the covariance and the a-priori residuals. Referred to increments
    /// over one sample, as it was defined: the residuals of increments over `decimation`
    /// samples are about `decimation` times larger and the covariance of the same data about
    /// `decimation` times smaller, so their product is about `decimation` times larger.
    pub fn column_relative_std(&self, i: usize) -> (f32, f32) {
        let per_sample = 1.0 / f32::from(self.decimation);
        let relative = |rls_p: f32, var: [f32; 3], theta: [f32; 3]| {
            let norm2 = theta.iter().map(|t| t * t).sum::<f32>();
            let var_sum = var.iter().sum::<f32>() * rls_p * per_sample;
            if norm2 > 0.0 {
                libm::sqrtf(var_sum / norm2)
            } else {
                f32::INFINITY
            }
        };
        let f = relative(
            (0..3).map(|k| self.force.p_diag(3 * i + k)).fold(0.0, f32::max),
            [self.force.error_var(0); 3],
            core::array::from_fn(|k| self.force.theta(3 * i + k, 0)),
        );
        let t = relative(
            self.rotation.p_diag(i),
            core::array::from_fn(|k| self.rotation.error_var(k)),
            core::array::from_fn(|k| self.rotation.theta(i, k)),
        );
        (f, t)
    }
}

/// A first-order high-pass (DC blocker) over `N` channels: `y[n] = p·y[n−1] + x[n] − x[n−1]`.
#[derive(Clone, Copy, Debug)]
struct HighPass<const N: usize> {
    input: [f32; N],
    output: [f32; N],
    primed: bool,
}

impl<const N: usize> Default for HighPass<N> {
    fn default() -> Self {
        Self { input: [0.0; N], output: [0.0; N], primed: false }
    }
}

impl<const N: usize> HighPass<N> {
    /// Filter `x` in place (its first `x.len()` channels). The first call only primes the state
    /// with the input, so a signal that starts at a non-zero level gives no transient.
    fn apply(&mut self, x: &mut [f32], pole: f32) {
        for (j, value) in x.iter_mut().enumerate().take(N) {
            let out =
                if self.primed { pole * self.output[j] + *value - self.input[j] } else { 0.0 };
            self.input[j] = *value;
            self.output[j] = out;
            *value = out;
        }
        self.primed = true;
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use nalgebra::Matrix3;

    /// A tumbling rigid body with `m` motors whose squared speeds produce torque and force
    /// (exact model: `I Ω̇ = Σ tᵢ ωᵢ² − Ω × IΩ`, `f = Σ fᵢ ωᵢ²`), motors pulsed one after the
    /// other through first-order lags, sampled at 2 kHz (mean of four 8 kHz samples), IMU at the
    /// centre of gravity. Returns the relative RMS errors of the force and torque blocks.
    fn identify_synthetic(
        inertia: Matrix3<f64>,
        omega_max: f64,
        tau_s: f64,
        decimation: u8,
    ) -> (f64, f64, EffectivenessEstimator) {
        let m = 8;
        let arm = 0.3;
        let kf = 3e-5_f64;
        let inv = inertia.try_inverse().unwrap();
        let mass = 2.5;
        let mut torque_cols = std::vec::Vec::new();
        let mut force_cols = std::vec::Vec::new();
        for i in 0..m {
            let a = core::f64::consts::TAU * (i as f64 + 0.5) / m as f64;
            let r = nalgebra::Vector3::new(arm * a.cos(), arm * a.sin(), 0.0);
            let n = nalgebra::Vector3::new(0.0, 0.0, -1.0);
            let spin = if i % 2 == 0 { 1.0 } else { -1.0 };
            let t = r.cross(&(n * kf)) - n * (spin * kf * 0.015);
            torque_cols.push(inv * t);
            force_cols.push(n * kf / mass);
        }
        let filter = BiquadCoefficients::butterworth_lowpass(20.0, 2000.0).unwrap();
        let config = RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 };
        // Speeds sampled at the end of each 2 kHz sample, the gyro averaged over it: the speeds
        // are 187.5 µs *newer* than the IMU sample.
        let mut est = EffectivenessEstimator::new(m, 2000.0, filter, [0.0; 3], -187.5e-6, config)
            .with_decimation(decimation);
        let mut rate = nalgebra::Vector3::new(7.0, 7.0, 1.7);
        let mut speed = [0.0f64; 8];
        let dt = 1.0 / 8000.0;
        let idle = 0.1 * omega_max;
        for n in 0..2000 {
            let mut gyro = nalgebra::Vector3::zeros();
            let mut accel = nalgebra::Vector3::zeros();
            for j in 0..4 {
                let t = (4 * n + j) as f64 * dt;
                for (i, w) in speed.iter_mut().enumerate() {
                    // The default excitation for this τ: step τ, ramp 2τ, start every 2τ.
                    let local = t - 2.0 * tau_s * i as f64;
                    let command: f64 = if (0.0..tau_s).contains(&local) {
                        0.5
                    } else if (tau_s..3.0 * tau_s).contains(&local) {
                        1.0 - (local - tau_s) / (2.0 * tau_s)
                    } else {
                        0.0
                    };
                    let target = idle + (omega_max - idle) * command.sqrt();
                    *w += (target - *w) / tau_s * dt;
                }
                let mut torque = nalgebra::Vector3::zeros();
                let mut force = nalgebra::Vector3::zeros();
                for i in 0..m {
                    torque += torque_cols[i] * speed[i] * speed[i];
                    force += force_cols[i] * speed[i] * speed[i];
                }
                let euler = -inv * rate.cross(&(inertia * rate));
                rate += (torque + euler) * dt;
                gyro += rate / 4.0;
                accel += force / 4.0;
            }
            let speeds: [f32; 8] = core::array::from_fn(|i| speed[i] as f32);
            est.update(gyro.map(|x| x as f32).into(), accel.map(|x| x as f32).into(), &speeds);
        }
        let g1 = est.g1_per_speed2();
        let block = |rows: core::ops::Range<usize>, truth: &dyn Fn(usize, usize) -> f64| {
            let (mut err, mut norm) = (0.0, 0.0);
            for k in rows.clone() {
                for i in 0..m {
                    let t = truth(k - rows.start, i);
                    err += (f64::from(g1[k][i]) - t).powi(2);
                    norm += t * t;
                }
            }
            (err / norm).sqrt()
        };
        let force = block(0..3, &|k, i| force_cols[i][k]);
        let torque = block(3..6, &|k, i| torque_cols[i][k]);
        (force, torque, est)
    }

    #[test]
    fn an_exact_tumbling_octorotor_is_identified_within_a_percent() {
        // Strong motors (ω_max 3000 rad/s) on an axisymmetric body spinning at (7, 7, 1.7) rad/s:
        // the Euler term precesses the rates, the model accounts for it.
        let axisymmetric = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.06, 0.06, 0.11));
        let (force, torque, _) =
            identify_synthetic(axisymmetric, 3000.0, 0.025, REGRESSION_DECIMATION);
        std::eprintln!(
            "axisymmetric, strong motors: force {:.2} %, torque {:.2} %",
            force * 1e2,
            torque * 1e2
        );
        assert!(force < 0.002 && torque < 0.01, "force {force}, torque {torque}");
        // Weak motors (ω_max 1100 rad/s, the library's octorotor): the pulses change the rates
        // less than the precession does, and the rows lose accuracy (measured 1.9 % and 3.8 %).
        let (force, torque, _) =
            identify_synthetic(axisymmetric, 1100.0, 0.025, REGRESSION_DECIMATION);
        std::eprintln!(
            "axisymmetric, weak motors: force {:.2} %, torque {:.2} %",
            force * 1e2,
            torque * 1e2
        );
        assert!(force < 0.03 && torque < 0.06, "force {force}, torque {torque}");
    }

    /// The regressions at every fourth sample ([`REGRESSION_DECIMATION`], one per sample in
    /// turn) learn what they learn at every sample: G1 within 0.5 % (strong motors; measured
    /// 0.26 %) and 3 % (weak motors, where the Euler term is larger than the pulses' effect;
    /// measured 2.0 %) of the every-sample result.
    #[test]
    fn decimated_regressions_learn_what_every_sample_regressions_learn() {
        let axisymmetric = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.06, 0.06, 0.11));
        for (omega_max, tolerance) in [(3000.0, 0.005), (1100.0, 0.03)] {
            let (_, _, every) = identify_synthetic(axisymmetric, omega_max, 0.025, 1);
            let (_, _, decimated) =
                identify_synthetic(axisymmetric, omega_max, 0.025, REGRESSION_DECIMATION);
            let (a, b) = (every.g1_per_speed2(), decimated.g1_per_speed2());
            let (mut difference, mut norm) = (0.0f64, 0.0f64);
            for (row_a, row_b) in a.iter().zip(&b) {
                for (x, y) in row_a.iter().zip(row_b) {
                    difference += f64::from(x - y).powi(2);
                    norm += f64::from(*x).powi(2);
                }
            }
            let relative = (difference / norm).sqrt();
            assert!(relative < tolerance, "ω_max {omega_max}: G1 differs by {relative}");
        }
    }
}
