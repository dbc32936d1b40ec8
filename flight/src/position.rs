//! Gains from the motors' time constant, and NDI position control (algorithms.md §7, §8).
//!
//! **Gains.** The slowest motor's τ limits how fast anything can be controlled, so every loop's
//! gain follows from it: `k_rate = 1/(4 ζ_rate² τ)`, and each outer loop is slower than the one
//! inside it by `4ζ²`: `k_next = k_prev / (4 ζ_next²)`, for attitude, velocity and position. A
//! cascade whose loops are 4ζ² apart behaves like a chain of critically (ζ) damped second-order
//! systems. ζ: rate 0.9, attitude 0.8, velocity 0.7, position 0.9 (published).
//!
//! **Position** (nonlinear dynamic inversion of the point mass): position error × k_pos → velocity
//! setpoint (≤ 2.5 m/s horizontal and vertical) → velocity error through a PI (k_vel, integral
//! with anti-windup) → acceleration setpoint (≤ 5 m/s² horizontal and vertical) → wanted specific
//! force `f_sp = a_sp − g` (world NED, hover (0, 0, −g)), its horizontal part limited to 30° of
//! tilt. The attitude loop turns `f_sp` into a thrust axis and a thrust.

use nalgebra::Vector3;

use crate::navigation::STANDARD_GRAVITY_MPS2;

/// Damping of the rate loop (published).
pub const ZETA_RATE: f32 = 0.9;
/// Damping of the attitude loop (published).
pub const ZETA_ATTITUDE: f32 = 0.8;
/// Damping of the velocity loop (published).
pub const ZETA_VELOCITY: f32 = 0.7;
/// Damping of the position loop (published).
pub const ZETA_POSITION: f32 = 0.9;
/// τ clamp for the gains, s (published: 0.01–0.2 s).
pub const TAU_RANGE_S: (f32, f32) = (0.01, 0.2);
/// Largest velocity setpoint per axis group (horizontal norm, vertical), m/s (published).
pub const MAX_SPEED_MPS: f32 = 2.5;
/// Largest acceleration setpoint per axis group (horizontal norm, vertical), m/s² (published).
pub const MAX_ACCEL_MPS2: f32 = 5.0;
/// Largest tilt of the wanted specific force from vertical, rad (30°, published).
pub const MAX_TILT_RAD: f32 = 30.0 * core::f32::consts::PI / 180.0;

/// The cascade's gains, all in 1/s (rate: rad/s² per rad/s; attitude: rad/s per rad; velocity:
/// m/s² per m/s; position: m/s per m); the velocity integral in 1/s².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gains {
    /// The τ the gains were made for (after the clamp), s.
    pub tau_s: f32,
    pub k_rate: f32,
    pub k_attitude: f32,
    pub k_velocity: f32,
    pub k_position: f32,
    /// Integral gain of the velocity loop: its zero at a quarter of the position loop's
    /// bandwidth, `k_vi = k_velocity · k_position / 4`, so it removes steady errors without
    /// adding overshoot to the position response.
    pub k_velocity_integral: f32,
}

impl Gains {
    /// The gains for motors whose slowest time constant is `tau_s` (clamped to
    /// [`TAU_RANGE_S`]; a non-finite τ takes the slow end).
    pub fn from_tau(tau_s: f32) -> Self {
        let tau = if tau_s.is_finite() {
            tau_s.clamp(TAU_RANGE_S.0, TAU_RANGE_S.1)
        } else {
            TAU_RANGE_S.1
        };
        let k_rate = 1.0 / (4.0 * ZETA_RATE * ZETA_RATE * tau);
        let k_attitude = k_rate / (4.0 * ZETA_ATTITUDE * ZETA_ATTITUDE);
        let k_velocity = k_attitude / (4.0 * ZETA_VELOCITY * ZETA_VELOCITY);
        let k_position = k_velocity / (4.0 * ZETA_POSITION * ZETA_POSITION);
        Self {
            tau_s: tau,
            k_rate,
            k_attitude,
            k_velocity,
            k_position,
            k_velocity_integral: 0.25 * k_velocity * k_position,
        }
    }
}

/// Where to be.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionSetpoint {
    /// World NED, m.
    pub position_ned_m: Vector3<f32>,
    /// Feed-forward velocity, world NED, m/s (zero to hold).
    pub velocity_ned_mps: Vector3<f32>,
}

/// Why a step was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PositionError {
    /// A non-finite value or a non-positive time step.
    BadInput,
}

/// The NDI position controller.
#[derive(Clone, Copy, Debug)]
pub struct PositionController {
    gains: Gains,
    /// The velocity loop's integral (an acceleration), world NED, m/s².
    integral_mps2: Vector3<f32>,
}

impl PositionController {
    /// A controller with `gains`, its integral empty.
    pub fn new(gains: Gains) -> Self {
        Self { gains, integral_mps2: Vector3::zeros() }
    }

    /// Empty the integral.
    pub fn reset(&mut self) {
        self.integral_mps2 = Vector3::zeros();
    }

    /// The integral (an acceleration), world NED, m/s².
    pub fn integral_mps2(&self) -> Vector3<f32> {
        self.integral_mps2
    }

    /// One step: position and velocity of the CoG (world NED), the setpoint, `dt_s` since the
    /// last step. Returns the wanted specific force, world NED, m/s².
    pub fn update(
        &mut self,
        position_ned_m: &Vector3<f32>,
        velocity_ned_mps: &Vector3<f32>,
        setpoint: &PositionSetpoint,
        dt_s: f32,
    ) -> Result<Vector3<f32>, PositionError> {
        let finite = [
            position_ned_m,
            velocity_ned_mps,
            &setpoint.position_ned_m,
            &setpoint.velocity_ned_mps,
        ]
        .iter()
        .all(|v| v.iter().all(|x| x.is_finite()))
            && dt_s > 0.0
            && dt_s.is_finite();
        if !finite {
            return Err(PositionError::BadInput);
        }
        let g = &self.gains;
        let velocity_sp = limit_split(
            &((setpoint.position_ned_m - position_ned_m) * g.k_position
                + setpoint.velocity_ned_mps),
            MAX_SPEED_MPS,
        );
        let velocity_error = velocity_sp - velocity_ned_mps;
        let unlimited = velocity_error * g.k_velocity + self.integral_mps2;
        let accel_sp = limit_split(&unlimited, MAX_ACCEL_MPS2);
        // Anti-windup: integrate an axis only while its output is not held at the limit in the
        // direction the error would push it further.
        for axis in 0..3 {
            let held = (unlimited[axis] - accel_sp[axis]).abs() > 1e-6;
            let pushing = velocity_error[axis] * unlimited[axis] > 0.0;
            if !(held && pushing) {
                self.integral_mps2[axis] += velocity_error[axis] * g.k_velocity_integral * dt_s;
            }
        }
        self.integral_mps2 = limit_split(&self.integral_mps2, MAX_ACCEL_MPS2);
        Ok(limit_tilt(&(accel_sp - Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2))))
    }
}

/// `v` with its horizontal part limited to a norm of `limit` and its vertical part to ±`limit`.
pub fn limit_split(v: &Vector3<f32>, limit: f32) -> Vector3<f32> {
    let horizontal = libm::sqrtf(v.x * v.x + v.y * v.y);
    let scale = if horizontal > limit { limit / horizontal } else { 1.0 };
    Vector3::new(v.x * scale, v.y * scale, v.z.clamp(-limit, limit))
}

/// A wanted specific force with its horizontal part limited to [`MAX_TILT_RAD`] from vertical
/// (the vertical part kept, and at least a tenth of g upward so the axis is defined).
pub fn limit_tilt(f_sp: &Vector3<f32>) -> Vector3<f32> {
    let up = (-f_sp.z).max(0.1 * STANDARD_GRAVITY_MPS2);
    let horizontal_max = up * libm::tanf(MAX_TILT_RAD);
    let horizontal = libm::sqrtf(f_sp.x * f_sp.x + f_sp.y * f_sp.y);
    let scale = if horizontal > horizontal_max { horizontal_max / horizontal } else { 1.0 };
    Vector3::new(f_sp.x * scale, f_sp.y * scale, -up)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f32 = 1.0 / 500.0;

    /// A point mass driven by `f_sp + g` through a first-order lag of the attitude loop's time
    /// constant, pushed by `disturbance` (m/s²). Returns the worst speed, tilt and the final
    /// error over `seconds`, and the track of positions.
    fn simulate(
        start: Vector3<f32>,
        disturbance: Vector3<f32>,
        seconds: f32,
    ) -> (f32, f32, Vector3<f32>, f32) {
        let gains = Gains::from_tau(0.025);
        let mut controller = PositionController::new(gains);
        let setpoint = PositionSetpoint {
            position_ned_m: Vector3::zeros(),
            velocity_ned_mps: Vector3::zeros(),
        };
        let (mut p, mut v) = (start, Vector3::zeros());
        let mut accel = Vector3::zeros();
        let (mut worst_speed, mut worst_tilt, mut overshoot) = (0.0f32, 0.0f32, 0.0f32);
        let lag = DT * gains.k_attitude;
        for _ in 0..((seconds / DT) as usize) {
            let f = controller.update(&p, &v, &setpoint, DT).unwrap();
            let tilt = libm::atan2f(libm::sqrtf(f.x * f.x + f.y * f.y), -f.z);
            worst_tilt = worst_tilt.max(tilt);
            let wanted = f + Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2);
            accel += (wanted - accel) * lag;
            v += (accel + disturbance) * DT;
            p += v * DT;
            worst_speed = worst_speed.max(libm::sqrtf(v.x * v.x + v.y * v.y));
            overshoot = overshoot.max(-p.x * start.x.signum());
        }
        (worst_speed, worst_tilt, p, overshoot)
    }

    #[test]
    fn gains_for_a_25_ms_motor_follow_the_published_formula() {
        let g = Gains::from_tau(0.025);
        let k_rate = 1.0 / (4.0 * 0.81 * 0.025);
        assert!((g.k_rate - k_rate).abs() < 1e-4 * k_rate);
        assert!((g.k_attitude - k_rate / (4.0 * 0.64)).abs() < 1e-4);
        assert!((g.k_velocity - g.k_attitude / (4.0 * 0.49)).abs() < 1e-5);
        assert!((g.k_position - g.k_velocity / (4.0 * 0.81)).abs() < 1e-5);
        assert_eq!(Gains::from_tau(0.001).tau_s, 0.01);
        assert_eq!(Gains::from_tau(1.0).tau_s, 0.2);
        assert_eq!(Gains::from_tau(f32::NAN).tau_s, 0.2);
    }

    #[test]
    fn hovering_on_the_setpoint_asks_for_one_g_up() {
        let mut controller = PositionController::new(Gains::from_tau(0.025));
        let here = Vector3::new(1.0, 2.0, -3.0);
        let setpoint =
            PositionSetpoint { position_ned_m: here, velocity_ned_mps: Vector3::zeros() };
        let f = controller.update(&here, &Vector3::zeros(), &setpoint, DT).unwrap();
        assert!((f - Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2)).norm() < 1e-6);
    }

    #[test]
    fn a_2_m_offset_is_flown_out_within_limits() {
        let (speed, tilt, p, _) = simulate(Vector3::new(2.0, 0.0, 0.0), Vector3::zeros(), 15.0);
        assert!(p.norm() < 0.05, "{p:?}");
        assert!(speed <= MAX_SPEED_MPS + 0.05, "{speed}");
        assert!(tilt <= MAX_TILT_RAD + 1e-4, "{}", tilt.to_degrees());
    }

    #[test]
    fn a_steady_1_mps2_push_leaves_no_steady_error() {
        let (_, _, p, _) = simulate(Vector3::zeros(), Vector3::new(1.0, 0.0, 0.5), 40.0);
        assert!(p.norm() < 0.01, "{p:?}");
    }

    #[test]
    fn a_100_m_step_keeps_near_the_speed_limit_and_does_not_wind_up() {
        // The limit is on the velocity *setpoint*; the velocity loop (ζ = 0.7 behind the
        // attitude lag) overshoots it by under 10 %.
        let (speed, _, p, overshoot) =
            simulate(Vector3::new(-100.0, 0.0, 0.0), Vector3::zeros(), 70.0);
        assert!(speed <= 1.1 * MAX_SPEED_MPS, "{speed}");
        assert!(p.norm() < 0.05, "{p:?}");
        assert!(overshoot < 0.05, "overshoot {overshoot} m");
    }

    #[test]
    fn bad_input_changes_nothing() {
        let mut controller = PositionController::new(Gains::from_tau(0.025));
        let setpoint = PositionSetpoint {
            position_ned_m: Vector3::zeros(),
            velocity_ned_mps: Vector3::zeros(),
        };
        let far = Vector3::new(5.0, 0.0, 0.0);
        controller.update(&far, &Vector3::zeros(), &setpoint, DT).unwrap();
        let integral = controller.integral_mps2();
        let nan = Vector3::new(f32::NAN, 0.0, 0.0);
        assert_eq!(
            controller.update(&nan, &Vector3::zeros(), &setpoint, DT),
            Err(PositionError::BadInput)
        );
        assert_eq!(
            controller.update(&far, &Vector3::zeros(), &setpoint, 0.0),
            Err(PositionError::BadInput)
        );
        assert_eq!(controller.integral_mps2(), integral);
    }
}
