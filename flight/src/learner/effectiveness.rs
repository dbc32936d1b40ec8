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
//! consecutive samples) of signals through one 2nd-order Butterworth low-pass (20 Hz): slowly
//! varying disturbances cancel, and Ω̇ comes from differentiating the filtered gyro.
//!
//! **Specific-force rows.** The accelerometer is moved to the centre of gravity with the stored
//! IMU offset `r`: `f_cog = f_imu − Ω̇×r − Ω×(Ω×r)`. The rest `f_rest` is mostly aerodynamic drag,
//! which on a tumbling craft is fixed in the *world*, not the body: in body axes it turns at −Ω,
//! so its increment is `−(Ω dt) × f_rest`, not zero (the main error of the published recipe,
//! §12). We add that increment back with `f_rest` from the current estimate:
//! `Δf_cog + (Ω dt) × (f_cog − Ĝ1f ω²) = G1f Δ(ω²)`.
//!
//! **Angular-acceleration rows.** The Euler and rotor-gyroscopic terms are quadratic in the
//! rates and spoil G1τ when ignored (§12). With `h = −I G2 ω` (the definition of G2),
//! `I⁻¹ Ω × (I Ω + h) = I⁻¹ Ω × I v` with `v = Ω − G2 ω`: a fixed linear map of the nine
//! products `Ωₐ v_b`. Those nine join the regressors (with `v` from the current G2 estimate):
//! `ΔΩ̇ = G1τ Δ(ω²) + G2 Δω̇ + E Δ(Ω ⊗ v)`, E (3 × 9) estimated and discarded.
//!
//! Each group of three rows shares its regressors, so one [`Rls`] with a shared covariance
//! serves it: `m` regressors for the force rows, `2m + 9` for the rotational rows.
//!
//! Scaling for f32: ω² in (krad/s)², ω̇ in 100 krad/s², rate products in (10 rad/s)².

use super::rls::{Rls, RlsConfig};
use super::MAX_MOTORS;
use crate::filters::{BiquadCoefficients, Butterworth2, Butterworth2x3};
use nalgebra::Vector3;

/// Squared-speed unit of the regression, (rad/s)².
pub const SPEED2_SCALE: f32 = 1e6;
/// Motor-acceleration unit of the regression, rad/s².
pub const SPEED_DOT_SCALE: f32 = 1e5;
/// Rate-product unit of the regression, (rad/s)².
const RATE2_SCALE: f32 = 100.0;
/// Regressors of the rotational rows besides the motors': the nine products `Ωₐ v_b`.
const RATE_PRODUCTS: usize = 9;
/// Capacity of the rotational regression: `2·8 + 9`.
pub const ROT_REGRESSORS_MAX: usize = 2 * MAX_MOTORS + RATE_PRODUCTS;

/// One centred sample of the filtered signals.
#[derive(Clone, Copy, Debug, Default)]
struct Centred {
    /// ω²/SPEED2_SCALE per motor.
    speed2: [f32; MAX_MOTORS],
    /// ω̇/SPEED_DOT_SCALE per motor.
    speed_dot: [f32; MAX_MOTORS],
    /// ω, rad/s.
    speed: [f32; MAX_MOTORS],
    rate: Vector3<f32>,
    rate_dot: Vector3<f32>,
    f_cog: Vector3<f32>,
}

/// The G1/G2 estimator.
#[derive(Clone, Debug)]
pub struct EffectivenessEstimator {
    motors: usize,
    dt_s: f32,
    half_rate_hz: f32,
    r_imu_m: Vector3<f32>,
    filter: BiquadCoefficients,
    gyro: Butterworth2x3,
    accel: Butterworth2x3,
    speed: [Butterworth2; MAX_MOTORS],
    /// Filtered (gyro, accel, speeds) of the two previous samples, newest first.
    history: [(Vector3<f32>, Vector3<f32>, [f32; MAX_MOTORS]); 2],
    seen: u8,
    previous: Option<Centred>,
    force: Rls<MAX_MOTORS, 3>,
    rotation: Rls<ROT_REGRESSORS_MAX, 3>,
}

impl EffectivenessEstimator {
    /// An estimator for `motors` motors (clamped to 1..=8) at `rate_hz`, filtering with `filter`,
    /// moving the accelerometer to the centre of gravity with `r_imu_m` (IMU axes, m).
    pub fn new(
        motors: usize,
        rate_hz: f32,
        filter: BiquadCoefficients,
        r_imu_m: [f32; 3],
        config: RlsConfig,
    ) -> Self {
        let motors = motors.clamp(1, MAX_MOTORS);
        Self {
            motors,
            dt_s: 1.0 / rate_hz,
            half_rate_hz: 0.5 * rate_hz,
            r_imu_m: Vector3::from(r_imu_m),
            filter,
            gyro: Butterworth2x3::from_coefficients(filter),
            accel: Butterworth2x3::from_coefficients(filter),
            speed: [Butterworth2::from_coefficients(filter); MAX_MOTORS],
            history: [(Vector3::zeros(), Vector3::zeros(), [0.0; MAX_MOTORS]); 2],
            seen: 0,
            previous: None,
            force: Rls::new(motors, config),
            rotation: Rls::new(2 * motors + RATE_PRODUCTS, config),
        }
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
        self.seen = 0;
        self.previous = None;
    }

    /// One sample: gyro (rad/s) and accelerometer (m/s²) in IMU axes, motor speeds (rad/s).
    /// Non-finite values restart the filters (the sample is a gap).
    pub fn update(&mut self, gyro_rad_s: [f32; 3], accel_mps2: [f32; 3], speeds_rad_s: &[f32]) {
        let m = self.motors;
        let finite = gyro_rad_s.iter().chain(&accel_mps2).chain(speeds_rad_s.iter().take(m));
        if speeds_rad_s.len() < m || !finite.into_iter().all(|v| v.is_finite()) {
            self.restart_filters();
            return;
        }
        let gyro = Vector3::from(gyro_rad_s);
        let accel = Vector3::from(accel_mps2);
        if self.seen == 0 {
            self.gyro.reset_to(&gyro);
            self.accel.reset_to(&accel);
            for (f, s) in self.speed.iter_mut().zip(speeds_rad_s).take(m) {
                f.reset_to(*s);
            }
        }
        let gyro_f = self.gyro.update(&gyro);
        let accel_f = self.accel.update(&accel);
        let mut speed_f = [0.0; MAX_MOTORS];
        for i in 0..m {
            speed_f[i] = self.speed[i].update(speeds_rad_s[i]);
        }
        let [previous, before] = self.history;
        self.history = [(gyro_f, accel_f, speed_f), previous];
        if self.seen < 2 {
            self.seen += 1;
            return;
        }
        // Centred on the previous sample: central differences of gyro and speeds.
        let (rate, accel_c, speed_c) = previous;
        let rate_dot = (gyro_f - before.0) * self.half_rate_hz;
        let r = self.r_imu_m;
        let f_cog = accel_c - rate_dot.cross(&r) - rate.cross(&rate.cross(&r));
        let mut now = Centred { rate, rate_dot, f_cog, ..Centred::default() };
        for i in 0..m {
            now.speed[i] = speed_c[i];
            now.speed2[i] = speed_c[i] * speed_c[i] / SPEED2_SCALE;
            now.speed_dot[i] = (speed_f[i] - before.2[i]) * self.half_rate_hz / SPEED_DOT_SCALE;
        }
        if let Some(last) = self.previous.replace(now) {
            self.regress(&last, &now);
        }
    }

    fn regress(&mut self, last: &Centred, now: &Centred) {
        let m = self.motors;
        // Force rows: Δf_cog + (Ω dt) × f_rest = G1f Δ(ω²).
        let mut x = [0.0f32; ROT_REGRESSORS_MAX];
        for i in 0..m {
            x[i] = now.speed2[i] - last.speed2[i];
        }
        let predicted = self.force.predict(&last.speed2[..m]);
        let f_rest = last.f_cog - Vector3::from(predicted);
        let y = (now.f_cog - last.f_cog) + (now.rate * self.dt_s).cross(&f_rest);
        let _ = self.force.update(&x[..m], &[y.x, y.y, y.z]);

        // Rotational rows: ΔΩ̇ = G1τ Δ(ω²) + G2 Δω̇ + E Δ(Ω ⊗ v), v = Ω − G2 ω.
        for i in 0..m {
            x[m + i] = now.speed_dot[i] - last.speed_dot[i];
        }
        let products_now = self.rate_products(now);
        let products_last = self.rate_products(last);
        for j in 0..RATE_PRODUCTS {
            x[2 * m + j] = products_now[j] - products_last[j];
        }
        let y = now.rate_dot - last.rate_dot;
        let _ = self.rotation.update(&x[..2 * m + RATE_PRODUCTS], &[y.x, y.y, y.z]);
    }

    /// The nine products `Ωₐ v_b / RATE2_SCALE` with `v = Ω − G2 ω` from the current estimate.
    fn rate_products(&self, s: &Centred) -> [f32; RATE_PRODUCTS] {
        let mut v = s.rate;
        for i in 0..self.motors {
            let g2 = self.g2_column(i);
            v -= g2 * s.speed[i];
        }
        let mut out = [0.0; RATE_PRODUCTS];
        for a in 0..3 {
            for b in 0..3 {
                out[3 * a + b] = s.rate[a] * v[b] / RATE2_SCALE;
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
                g1[k][i] = self.force.theta(i, k) / SPEED2_SCALE;
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
    pub fn information_left(&self, i: usize, p0: f32) -> (f32, f32) {
        (self.force.p_diag(i) / p0, self.rotation.p_diag(i) / p0)
    }

    /// Relative standard deviation of column `i` of G1f and of G1τ (one σ of the column's norm
    /// over the norm), from the covariance and the a-priori residuals.
    pub fn column_relative_std(&self, i: usize) -> (f32, f32) {
        let relative = |rls_p: f32, var: [f32; 3], theta: [f32; 3]| {
            let norm2 = theta.iter().map(|t| t * t).sum::<f32>();
            let var_sum = var.iter().sum::<f32>() * rls_p;
            if norm2 > 0.0 {
                libm::sqrtf(var_sum / norm2)
            } else {
                f32::INFINITY
            }
        };
        let f = relative(
            self.force.p_diag(i),
            core::array::from_fn(|k| self.force.error_var(k)),
            core::array::from_fn(|k| self.force.theta(i, k)),
        );
        let t = relative(
            self.rotation.p_diag(i),
            core::array::from_fn(|k| self.rotation.error_var(k)),
            core::array::from_fn(|k| self.rotation.theta(i, k)),
        );
        (f, t)
    }
}
