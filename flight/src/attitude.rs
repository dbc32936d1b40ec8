//! Attitude of the IMU in the world: a complementary (Mahony-type) filter on gyro and
//! accelerometer, with an external heading when one is given (algorithms.md §9).
//!
//! ```text
//! ω  = gyro − b                                          (b: gyro-bias estimate)
//! e  = d_meas × d_est     d_meas = −f/|f|, d_est = R_bodyᵀ·down   (only when |f| ≈ g)
//!    + k_h (ψ_ext − ψ) · R_bodyᵀ·down                   (only with an external heading)
//! q ← q ⊗ exp(½ (ω + k_p e) dt),   b ← b − k_i e dt
//! ```
//!
//! The accelerometer measures gravity only when nothing else accelerates the craft, so its
//! correction is applied only while |f| is within ±20 % of g (published) and the craft turns
//! slower than 1 rad/s (ours: the excitation's pulses pass through 1 g while tumbling); in free
//! fall, in the throw and while thrusting hard the filter integrates the gyro alone, which over the second of a
//! throw-and-fly drifts by the gyro bias times a second (well under a degree). Without an
//! external heading the yaw drifts on the gyro and [`AttitudeFilter::heading_is_external`] says
//! so. The accelerometer passed in must already be moved to the centre of gravity where that
//! matters (the caller knows the offset).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::navigation::STANDARD_GRAVITY_MPS2;

/// Band of |f| around g within which the accelerometer corrects the tilt, fraction of g
/// (±20 %, algorithms.md §9).
pub const ACCEL_TRUST_BAND: f32 = 0.2;

/// Largest tilt error (sine of the angle) the gyro-bias integral learns from: 10°, above the
/// `bias/k_p` = 5.7° a 0.02 rad/s bias holds the tilt off by before it is learned.
pub const BIAS_LEARNING_MAX_ERROR: f32 = 0.17;

/// How the filter is tuned.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttitudeConfig {
    /// Proportional gain of the tilt correction, rad/s per unit of cross-product error: the
    /// tilt converges with a time constant of about `1/k_p` (5 s). It must sit well below the
    /// position loop (about 0.8 rad/s for a 25 ms motor): a horizontal acceleration tilts the
    /// specific force like a tilted craft, and a faster filter would believe it and feed the
    /// position loop a wrong "level" (measured: a 1 m, 8 s oscillation with k_p = 1).
    pub k_p: f32,
    /// Integral gain (gyro-bias learning), rad/s² per unit error: a bias settles in about
    /// `k_p/k_i` = 20 s.
    pub k_i: f32,
    /// Gain of the external-heading correction, rad/s per rad of heading error.
    pub k_heading: f32,
    /// Largest gyro bias believed, rad/s (a MEMS gyro's offset after start-up is well under it).
    pub max_bias_rad_s: f32,
    /// Largest body rate at which the accelerometer corrects the tilt, rad/s: a craft turning
    /// fast is being pushed by something other than gravity (a throw, the excitation pulses,
    /// a recovery), even when |f| happens to pass through 1 g.
    pub max_rate_for_accel_rad_s: f32,
}

impl Default for AttitudeConfig {
    fn default() -> Self {
        Self {
            k_p: 0.2,
            k_i: 0.01,
            k_heading: 1.0,
            max_bias_rad_s: 0.1,
            max_rate_for_accel_rad_s: 1.0,
        }
    }
}

/// Why a sample was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AttitudeError {
    /// A non-finite value or a non-positive time step.
    BadInput,
}

/// The attitude filter.
#[derive(Clone, Copy, Debug)]
pub struct AttitudeFilter {
    config: AttitudeConfig,
    q_world_body: UnitQuaternion<f32>,
    bias_rad_s: Vector3<f32>,
    initialised: bool,
    accel_used: bool,
    heading_external: bool,
}

impl AttitudeFilter {
    /// A filter that takes its tilt from the first accelerometer sample.
    pub fn new(config: AttitudeConfig) -> Self {
        Self {
            config,
            q_world_body: UnitQuaternion::identity(),
            bias_rad_s: Vector3::zeros(),
            initialised: false,
            accel_used: false,
            heading_external: false,
        }
    }

    /// Start from a known attitude.
    pub fn reset_to(&mut self, q_world_body: UnitQuaternion<f32>) {
        self.q_world_body = q_world_body;
        self.initialised = true;
    }

    /// Start from the tilt a specific force `f_mps2` (body axes) shows, with heading `yaw_rad`.
    pub fn reset_from_accel(
        &mut self,
        f_mps2: &Vector3<f32>,
        yaw_rad: f32,
    ) -> Result<(), AttitudeError> {
        let norm = f_mps2.norm();
        if !(norm > 0.1 && norm.is_finite() && yaw_rad.is_finite()) {
            return Err(AttitudeError::BadInput);
        }
        // Down in body axes is −f/|f|; the tilt rotates body "down" onto world down.
        let down_body = -f_mps2 / norm;
        let tilt =
            UnitQuaternion::rotation_between(&down_body, &Vector3::z()).unwrap_or_else(|| {
                UnitQuaternion::from_axis_angle(&Vector3::x_axis(), core::f32::consts::PI)
            });
        let q = tilt;
        let yaw_now = yaw_of(&q);
        self.q_world_body =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad - yaw_now) * q;
        self.initialised = true;
        Ok(())
    }

    /// One sample: gyro (rad/s) and specific force (m/s²) in body axes, an external heading
    /// (rad) if one is known now, `dt_s` since the previous sample.
    pub fn update(
        &mut self,
        gyro_rad_s: &Vector3<f32>,
        f_mps2: &Vector3<f32>,
        heading_rad: Option<f32>,
        dt_s: f32,
    ) -> Result<(), AttitudeError> {
        let finite = gyro_rad_s.iter().chain(f_mps2.iter()).all(|x| x.is_finite())
            && heading_rad.is_none_or(f32::is_finite)
            && dt_s > 0.0
            && dt_s.is_finite();
        if !finite {
            return Err(AttitudeError::BadInput);
        }
        if !self.initialised && self.reset_from_accel(f_mps2, heading_rad.unwrap_or(0.0)).is_err() {
            // No gravity to start from (free fall): start level and let the gyro run.
            self.reset_to(UnitQuaternion::identity());
        }
        let c = self.config;
        let down_est = self.q_world_body.inverse() * Vector3::z();
        let mut error = Vector3::zeros();
        let f_norm = f_mps2.norm();
        self.accel_used =
            (f_norm - STANDARD_GRAVITY_MPS2).abs() <= ACCEL_TRUST_BAND * STANDARD_GRAVITY_MPS2;
        if self.accel_used {
            error += (-f_mps2 / f_norm).cross(&down_est);
        }
        self.heading_external = heading_rad.is_some();
        let mut heading_correction = Vector3::zeros();
        if let Some(heading) = heading_rad {
            let yaw_error = wrap_pi(heading - yaw_of(&self.q_world_body));
            heading_correction = down_est * (c.k_heading * yaw_error);
        }
        // The bias is learned only from small errors: a large one is an attitude error (a start
        // or a manoeuvre), and integrating it would wind up a fake bias that takes k_p/k_i to
        // unwind.
        if error.norm() < BIAS_LEARNING_MAX_ERROR {
            let bias = self.bias_rad_s - error * (c.k_i * dt_s);
            self.bias_rad_s = bias.map(|b| b.clamp(-c.max_bias_rad_s, c.max_bias_rad_s));
        }
        let omega = gyro_rad_s - self.bias_rad_s + error * c.k_p + heading_correction;
        let half = omega * (0.5 * dt_s);
        let delta = Quaternion::new(1.0, half.x, half.y, half.z);
        self.q_world_body = UnitQuaternion::from_quaternion(self.q_world_body.into_inner() * delta);
        Ok(())
    }

    /// The attitude: body coordinates into world (NED) coordinates.
    pub fn quaternion(&self) -> UnitQuaternion<f32> {
        self.q_world_body
    }

    /// The gyro-bias estimate, rad/s, body axes.
    pub fn gyro_bias_rad_s(&self) -> Vector3<f32> {
        self.bias_rad_s
    }

    /// Whether the last sample's accelerometer corrected the tilt.
    pub fn accel_used(&self) -> bool {
        self.accel_used
    }

    /// Whether the last sample had an external heading (else the yaw drifts on the gyro).
    pub fn heading_is_external(&self) -> bool {
        self.heading_external
    }
}

/// Heading of a body: the yaw of its x axis projected on the horizontal plane, rad.
pub fn yaw_of(q_world_body: &UnitQuaternion<f32>) -> f32 {
    let x = q_world_body * Vector3::x();
    libm::atan2f(x.y, x.x)
}

/// An angle wrapped into [−π, π).
pub fn wrap_pi(angle: f32) -> f32 {
    let two_pi = 2.0 * core::f32::consts::PI;
    let wrapped = angle - two_pi * libm::floorf(angle / two_pi + 0.5);
    if wrapped.is_finite() {
        wrapped
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f32 = 1.0 / 2000.0;
    const G: f32 = STANDARD_GRAVITY_MPS2;

    fn tilt_deg(q: &UnitQuaternion<f32>) -> f32 {
        let down = q * Vector3::z();
        libm::acosf(down.z.clamp(-1.0, 1.0)).to_degrees()
    }

    #[test]
    fn a_30_degree_tilt_error_is_corrected_below_half_a_degree_in_60_s() {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        filter.reset_to(UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 30f32.to_radians()));
        let level_f = Vector3::new(0.0, 0.0, -G);
        for _ in 0..(60 * 2000) {
            filter.update(&Vector3::zeros(), &level_f, None, DT).unwrap();
        }
        assert!(tilt_deg(&filter.quaternion()) < 0.5, "{}°", tilt_deg(&filter.quaternion()));
    }

    #[test]
    fn a_gyro_bias_is_learned_while_turning_and_the_tilt_stays_within_a_degree() {
        // Level, turning about down at 0.8 rad/s, gyro biased by (0.02, −0.02, 0) rad/s.
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        let bias = Vector3::new(0.02, -0.02, 0.0);
        let gyro = Vector3::new(0.0, 0.0, 0.8) + bias;
        let level_f = Vector3::new(0.0, 0.0, -G);
        for _ in 0..(400 * 2000) {
            filter.update(&gyro, &level_f, None, DT).unwrap();
        }
        assert!(tilt_deg(&filter.quaternion()) < 1.0);
        let learned = filter.gyro_bias_rad_s();
        // Within 40 %: with the slow k_p the estimate lags the body's turn, which rotates it
        // (measured: 32 % after 400 s).
        assert!((learned - bias).norm() < 0.4 * bias.norm(), "{learned:?}");
    }

    #[test]
    fn a_3g_manoeuvre_does_not_pull_the_tilt() {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        filter.reset_to(UnitQuaternion::identity());
        // 3 g sideways and up for a second: outside the ±20 % band.
        let f = Vector3::new(2.0 * G, 0.0, -2.0 * G);
        for _ in 0..2000 {
            filter.update(&Vector3::zeros(), &f, None, DT).unwrap();
            assert!(!filter.accel_used());
        }
        assert!(tilt_deg(&filter.quaternion()) < 0.01);
    }

    #[test]
    fn an_external_heading_pulls_the_yaw() {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        filter.reset_to(UnitQuaternion::identity());
        let level_f = Vector3::new(0.0, 0.0, -G);
        for _ in 0..(6 * 2000) {
            filter.update(&Vector3::zeros(), &level_f, Some(1.0), DT).unwrap();
        }
        assert!((yaw_of(&filter.quaternion()) - 1.0).abs() < 0.01);
        assert!(filter.heading_is_external());
    }

    #[test]
    fn the_quaternion_stays_unit_over_a_million_steps_of_tumbling() {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        let gyro = Vector3::new(7.0, 7.0, 1.7);
        for _ in 0..1_000_000 {
            filter.update(&gyro, &Vector3::zeros(), None, DT).unwrap();
        }
        assert!((filter.quaternion().into_inner().norm() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn free_fall_integrates_the_gyro_exactly() {
        // 0.5 s at (400, 400, 100) °/s with no accelerometer information, as after a throw.
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        filter.reset_to(UnitQuaternion::identity());
        let rate = Vector3::new(400.0f32, 400.0, 100.0).map(f32::to_radians);
        for _ in 0..1000 {
            filter.update(&rate, &Vector3::zeros(), None, DT).unwrap();
        }
        let truth = UnitQuaternion::from_scaled_axis(rate * 0.5);
        assert!(filter.quaternion().angle_to(&truth).to_degrees() < 0.05);
    }

    #[test]
    fn bad_input_changes_nothing() {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        filter.update(&Vector3::zeros(), &Vector3::new(0.0, 0.0, -G), None, DT).unwrap();
        let before = filter.quaternion();
        let nan = Vector3::new(f32::NAN, 0.0, 0.0);
        assert_eq!(filter.update(&nan, &Vector3::zeros(), None, DT), Err(AttitudeError::BadInput));
        assert_eq!(
            filter.update(&Vector3::zeros(), &Vector3::zeros(), Some(f32::INFINITY), DT),
            Err(AttitudeError::BadInput)
        );
        assert_eq!(filter.quaternion(), before);
    }
}
