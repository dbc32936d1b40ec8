//! The IMU model: what a MEMS gyroscope and accelerometer at an offset, rotated position read.
//!
//! Truth first: the IMU at `r` (body, from the CoG) on a rigid body measures, in its own axes
//! (`R = q_imu_body`),
//! - gyro: `R Ω`;
//! - accelerometer: the specific force at its own position,
//!   `R (f_cog + Ω̇ × r + Ω × (Ω × r))` (seed paper eq. 1–3 with ṙ = r̈ = 0).
//!
//! Then the errors, per axis, in this order: motor vibration (each rotor's imbalance as a
//! sinusoid at its rotation angle, rotating in its rotor plane, amplitude ∝ (ω/ω_max)²), constant
//! bias, white noise, range saturation, and quantisation to `bits` (full scale ±range over
//! 2^bits codes, as the ICM-42688-P's 16-bit registers). White noise per sample is
//! `σ = noise_density · √(sample rate)` (the discrete-time equivalent of a continuous white-noise
//! density, as in the Kalibr IMU noise model).

use nalgebra::{Matrix3, Vector3};

use crate::airframe::{Airframe, MAX_ROTORS};
use crate::dynamics::{Derivative, State};
use crate::rng::Rng;

/// One raw IMU sample in IMU axes (f64; the board converts to the application's f32).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RawSample {
    /// Angular rate, rad/s.
    pub gyro_rad_s: Vector3<f64>,
    /// Specific force, m/s².
    pub accel_mps2: Vector3<f64>,
}

/// Errors and limits of one three-axis sensor.
#[derive(Clone, Debug)]
struct Channel {
    /// Reading per unit of truth (scale, cross-axis, misalignment).
    sensitivity: Matrix3<f64>,
    sigma_per_sample: f64,
    bias: Vector3<f64>,
    range: f64,
    /// Quantisation step, or `None` for none.
    lsb: Option<f64>,
}

impl Channel {
    fn new(noise_density: f64, bias: [f64; 3], range: f64, bits: u32, rate_hz: f64) -> Self {
        Self {
            sensitivity: Matrix3::identity(),
            sigma_per_sample: noise_density * rate_hz.sqrt(),
            bias: Vector3::from(bias),
            range,
            lsb: (bits > 0).then(|| range / f64::from(1u32 << (bits - 1))),
        }
    }

    fn with_sensitivity(self, rows: &[[f64; 3]; 3]) -> Self {
        Self { sensitivity: Matrix3::from_fn(|i, j| rows[i][j]), ..self }
    }

    fn read(&self, truth: Vector3<f64>, rng: &mut Rng) -> Vector3<f64> {
        let mut v = self.sensitivity * truth + self.bias;
        if self.sigma_per_sample > 0.0 {
            v += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * self.sigma_per_sample;
        }
        v.map(|x| match self.lsb {
            // Codes run from −2^(b−1) to 2^(b−1) − 1: the positive end is one LSB short.
            Some(lsb) => (x / lsb).round().clamp(-self.range / lsb, self.range / lsb - 1.0) * lsb,
            None => x.clamp(-self.range, self.range),
        })
    }
}

/// The IMU of one airframe: pose on the body, sensor errors and its noise source.
#[derive(Clone, Debug)]
pub struct ImuModel {
    r_imu_m: Vector3<f64>,
    rot_imu_body: Matrix3<f64>,
    gyro: Channel,
    accel: Channel,
    vibration_accel_mps2: f64,
    vibration_gyro_rad_s: f64,
    /// Per rotor: two unit vectors `(e1, e2)` spanning its rotor plane (body axes), with
    /// `e2 = s n × e1` so that `e1 cos φ + e2 sin φ` turns the way the rotor spins.
    rotor_plane: Vec<(Vector3<f64>, Vector3<f64>)>,
    rotor_max_rad_s: Vec<f64>,
    rng: Rng,
    ideal: bool,
}

impl ImuModel {
    /// The IMU of `airframe`, with noise drawn from `seed`. With `ideal`, the sensor reads the
    /// truth exactly (no vibration, bias, noise, saturation or quantisation) — for tests.
    pub fn new(airframe: &Airframe, seed: u64, ideal: bool) -> Self {
        let p = &airframe.imu;
        let rate = p.sample_rate_hz;
        let rotor_plane = (0..airframe.rotor_count())
            .map(|i| {
                let n = airframe.thrust_axis(i);
                // Any vector not parallel to n gives a plane basis.
                let seed_axis = if n.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
                let e1 = n.cross(&seed_axis).normalize();
                (e1, n.cross(&e1) * airframe.rotors[i].spin.sign())
            })
            .collect();
        Self {
            r_imu_m: airframe.r_imu_m(),
            rot_imu_body: *airframe.q_imu_body().to_rotation_matrix().matrix(),
            gyro: Channel::new(
                p.gyro.noise_density_rad_s_per_sqrt_hz,
                p.gyro.bias_rad_s,
                p.gyro.range_rad_s,
                p.gyro.bits,
                rate,
            )
            .with_sensitivity(&p.gyro.sensitivity),
            accel: Channel::new(
                p.accel.noise_density_mps2_per_sqrt_hz,
                p.accel.bias_mps2,
                p.accel.range_mps2,
                p.accel.bits,
                rate,
            )
            .with_sensitivity(&p.accel.sensitivity),
            vibration_accel_mps2: p.vibration.accel_mps2_at_max_speed,
            vibration_gyro_rad_s: p.vibration.gyro_rad_s_at_max_speed,
            rotor_plane,
            rotor_max_rad_s: (0..airframe.rotor_count())
                .map(|i| airframe.rotor_motor(i).omega_max_rad_s)
                .collect(),
            rng: Rng::new(seed),
            ideal,
        }
    }

    /// The error-free reading: gyro `R Ω`, accelerometer `R (f_cog + Ω̇×r + Ω×(Ω×r))`.
    pub fn truth(&self, state: &State, derivative: &Derivative) -> RawSample {
        let w = state.rate_body_rad_s;
        let w_dot = derivative.rate_dot_body_rad_s2;
        let r = self.r_imu_m;
        let f_imu_body =
            derivative.specific_force_body_mps2 + w_dot.cross(&r) + w.cross(&w.cross(&r));
        RawSample { gyro_rad_s: self.rot_imu_body * w, accel_mps2: self.rot_imu_body * f_imu_body }
    }

    /// One sample with all sensor errors, and the error-free reading it came from.
    /// `rotor_angle_rad` drives the vibration.
    pub fn sample(
        &mut self,
        state: &State,
        derivative: &Derivative,
        rotor_angle_rad: &[f64; MAX_ROTORS],
    ) -> (RawSample, RawSample) {
        let truth = self.truth(state, derivative);
        if self.ideal {
            return (truth, truth);
        }
        let (mut vib_gyro, mut vib_accel) = (Vector3::zeros(), Vector3::zeros());
        if self.vibration_accel_mps2 > 0.0 || self.vibration_gyro_rad_s > 0.0 {
            for (i, (e1, e2)) in self.rotor_plane.iter().enumerate() {
                let level = (state.rotor_speed_rad_s[i] / self.rotor_max_rad_s[i]).powi(2);
                let (s, c) = rotor_angle_rad[i].sin_cos();
                let dir = e1 * c + e2 * s;
                vib_accel += dir * (level * self.vibration_accel_mps2);
                vib_gyro += dir * (level * self.vibration_gyro_rad_s);
            }
        }
        let measured = RawSample {
            gyro_rad_s: self
                .gyro
                .read(truth.gyro_rad_s + self.rot_imu_body * vib_gyro, &mut self.rng),
            accel_mps2: self
                .accel
                .read(truth.accel_mps2 + self.rot_imu_body * vib_accel, &mut self.rng),
        };
        (measured, truth)
    }

    /// IMU position relative to the CoG, body, m.
    pub fn r_imu_m(&self) -> Vector3<f64> {
        self.r_imu_m
    }

    /// Rotation matrix taking body coordinates into IMU coordinates.
    pub fn rot_imu_body(&self) -> &Matrix3<f64> {
        &self.rot_imu_body
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantisation_and_saturation_follow_the_register_format() {
        let c = Channel::new(0.0, [0.0; 3], 34.9, 16, 8000.0);
        let lsb: f64 = 34.9 / 32768.0;
        let v = c.read(Vector3::new(1.0, 100.0, -100.0), &mut Rng::new(1));
        assert!((v.x - (1.0 / lsb).round() * lsb).abs() < 1e-15);
        assert!((v.y - 32767.0 * lsb).abs() < 1e-12, "positive saturation {}", v.y);
        assert!((v.z + 32768.0 * lsb).abs() < 1e-12, "negative saturation {}", v.z);
    }

    #[test]
    fn noise_per_sample_matches_the_density() {
        let c = Channel::new(1e-3, [0.0; 3], 1e6, 0, 8000.0);
        let mut rng = Rng::new(3);
        let n = 20_000;
        let var: f64 =
            (0..n).map(|_| c.read(Vector3::zeros(), &mut rng).x.powi(2)).sum::<f64>() / n as f64;
        let expected = 1e-3 * 8000f64.sqrt();
        assert!((var.sqrt() / expected - 1.0).abs() < 0.03, "σ {} vs {expected}", var.sqrt());
    }
}
