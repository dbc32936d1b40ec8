//! A simulated magnetometer (issue 55): what an IST8310 or QMC5883L on a GNSS mast reads on a
//! craft in the simulator's world, for `flight::magnetometer`'s calibration, alignment,
//! interference compensation and heading.
//!
//! # Model
//!
//! `m = S (R_mag←imu h_imu) + b + Σ c_i u_i + n`, sampled at [`MagnetometerSpec::rate_hz`]:
//! - `h_imu`: the Earth's field in the IMU's axes, from its strength, inclination (dip, positive
//!   down) and declination (east of true north) in the north-east-down world;
//! - `R_mag←imu`: the sensor's mounting ([`MagnetometerSpec::q_mag_imu`]);
//! - `S`: soft iron and the sensor's scale and cross-axis errors (any matrix near the identity:
//!   its non-symmetric part is a rotation the alignment takes with the mounting);
//! - `b`: hard iron, µT;
//! - `c_i u_i`: motor `i`'s field at its normalised thrust `u_i ∈ [0, 1]` (currents are about
//!   proportional to thrust for a propeller at its working point);
//! - `n`: white Gaussian noise, [`MagnetometerSpec::noise_ut`] per axis.
//!
//! # The random world's ranges ([`MagnetometerSpec::random`])
//!
//! | what | range | why |
//! |---|---|---|
//! | field strength | 25–65 µT (uniform) | the Earth's surface field, 22–67 µT (IGRF-13) |
//! | inclination | −70…+70° (uniform) | where people fly; beyond, the horizontal field is too weak for a compass heading |
//! | declination | −30…+30° (uniform) | most inhabited places are within ±20° |
//! | hard iron | ±300 µT per axis (uniform) | the range: a magnetised screw, a battery strap or a buzzer near the sensor, several times the Earth's field |
//! | soft iron | scale 0.8–1.2 per axis, cross-axis ±0.2 per element (uniform) | the 20 %; sensors specify a few % of cross-axis, steel nearby the rest |
//! | mounting | any rotation (uniform on SO(3)) | a mast sensor in any orientation, 180° about any axis included |
//! | noise | 0.3–2 µT per axis (uniform) | IST8310 with 16 times averaging to QMC5883L at ±8 G, with a motor's ripple |
//! | rate | 50–100 Hz (uniform) | what the drivers configure (100 Hz) down to a slower poll |
//! | interference | each motor's field a random direction, their sum at full thrust 0–50 % of the Earth's field (uniform) | a mast 10–20 cm above the frame's power wires; the 50 % |
//!
//! A draw depends only on the generator it is given, and the noise only on the seed of
//! [`SimMagnetometer::new`], as the GNSS receiver's (`crate::gnss`). The flight simulation
//! (`fly`) does not fly with it yet: the lead wires the heading. The random world draws one on
//! request (`crate::world`, aspect `compass`), and `crate::compass_chip` puts it behind an
//! IST8310's or a QMC5883L's registers for the firmware's drivers.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::rng::Rng;

/// Field strength drawn by [`MagnetometerSpec::random`], µT.
pub const RANDOM_STRENGTH_UT: (f64, f64) = (25.0, 65.0);
/// Inclination drawn, degrees.
pub const RANDOM_INCLINATION_DEG: (f64, f64) = (-70.0, 70.0);
/// Declination drawn, degrees.
pub const RANDOM_DECLINATION_DEG: (f64, f64) = (-30.0, 30.0);
/// Hard iron drawn per axis, ± µT.
pub const RANDOM_HARD_IRON_UT: f64 = 300.0;
/// Soft iron's scale error per axis, ± (fraction).
pub const RANDOM_SOFT_IRON_SCALE: f64 = 0.2;
/// Soft iron's cross-axis term per element, ± (fraction).
pub const RANDOM_SOFT_IRON_CROSS: f64 = 0.2;
/// Noise per axis drawn, µT.
pub const RANDOM_NOISE_UT: (f64, f64) = (0.3, 2.0);
/// Output rate drawn, Hz.
pub const RANDOM_RATE_HZ: (f64, f64) = (50.0, 100.0);
/// The motors' summed field at full thrust drawn, as a fraction of the Earth's field.
pub const RANDOM_INTERFERENCE_SHARE: (f64, f64) = (0.0, 0.5);

/// A simulated magnetometer and the field it is in. Ranges are checked by
/// [`MagnetometerSpec::validate`].
#[derive(Clone, Debug, PartialEq)]
pub struct MagnetometerSpec {
    /// The Earth's field strength, µT (1 to 100).
    pub strength_ut: f64,
    /// Inclination, rad, positive down (−π/2 to π/2).
    pub inclination_rad: f64,
    /// Declination, rad, east of true north positive (−π to π).
    pub declination_rad: f64,
    /// Hard iron, µT per axis (±2,000).
    pub hard_iron_ut: [f64; 3],
    /// Soft iron (and scale, cross-axis), row-major; its determinant must be positive.
    pub soft_iron: [[f64; 3]; 3],
    /// The mounting, `q_mag_imu` (IMU axes into the sensor's).
    pub q_mag_imu: UnitQuaternion<f64>,
    /// Noise per axis, µT (0 to 20).
    pub noise_ut: f64,
    /// Output rate, Hz (1 to 1,000).
    pub rate_hz: f64,
    /// Each motor's field at full thrust, µT, sensor axes.
    pub motor_field_ut: Vec<[f64; 3]>,
}

impl Default for MagnetometerSpec {
    /// Zürich's field (WMM2025 near 47.4° N 8.5° E: 48 µT, dip 63.5°, declination +3°), an ideal
    /// sensor aligned with the IMU, 0.5 µT of noise at 100 Hz, no interference.
    fn default() -> Self {
        Self {
            strength_ut: 48.0,
            inclination_rad: 63.5f64.to_radians(),
            declination_rad: 3f64.to_radians(),
            hard_iron_ut: [0.0; 3],
            soft_iron: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            q_mag_imu: UnitQuaternion::identity(),
            noise_ut: 0.5,
            rate_hz: 100.0,
            motor_field_ut: Vec::new(),
        }
    }
}

fn uniform_rotation(rng: &mut Rng) -> UnitQuaternion<f64> {
    loop {
        let q = Quaternion::new(rng.normal(), rng.normal(), rng.normal(), rng.normal());
        if q.norm() > 1e-6 {
            return UnitQuaternion::from_quaternion(q);
        }
    }
}

impl MagnetometerSpec {
    /// A sensor and field drawn from the module documentation's ranges, with `motors` motors.
    pub fn random(rng: &mut Rng, motors: usize) -> Self {
        let strength_ut = rng.range(RANDOM_STRENGTH_UT.0, RANDOM_STRENGTH_UT.1);
        let inclination_rad =
            rng.range(RANDOM_INCLINATION_DEG.0, RANDOM_INCLINATION_DEG.1).to_radians();
        let declination_rad =
            rng.range(RANDOM_DECLINATION_DEG.0, RANDOM_DECLINATION_DEG.1).to_radians();
        let hard_iron_ut: [f64; 3] =
            std::array::from_fn(|_| rng.range(-RANDOM_HARD_IRON_UT, RANDOM_HARD_IRON_UT));
        let mut soft_iron = [[0.0; 3]; 3];
        for (i, row) in soft_iron.iter_mut().enumerate() {
            for (j, x) in row.iter_mut().enumerate() {
                *x = if i == j {
                    1.0 + rng.range(-RANDOM_SOFT_IRON_SCALE, RANDOM_SOFT_IRON_SCALE)
                } else {
                    rng.range(-RANDOM_SOFT_IRON_CROSS, RANDOM_SOFT_IRON_CROSS)
                };
            }
        }
        let q_mag_imu = uniform_rotation(rng);
        let noise_ut = rng.range(RANDOM_NOISE_UT.0, RANDOM_NOISE_UT.1);
        let rate_hz = rng.range(RANDOM_RATE_HZ.0, RANDOM_RATE_HZ.1);
        let share = rng.range(RANDOM_INTERFERENCE_SHARE.0, RANDOM_INTERFERENCE_SHARE.1);
        let mut motor_field: Vec<Vector3<f64>> =
            (0..motors).map(|_| Vector3::new(rng.normal(), rng.normal(), rng.normal())).collect();
        let total = motor_field.iter().sum::<Vector3<f64>>().norm();
        if total > 0.0 {
            for c in motor_field.iter_mut() {
                *c *= share * strength_ut / total;
            }
        }
        Self {
            strength_ut,
            inclination_rad,
            declination_rad,
            hard_iron_ut,
            soft_iron,
            q_mag_imu,
            noise_ut,
            rate_hz,
            motor_field_ut: motor_field.iter().map(|c| [c.x, c.y, c.z]).collect(),
        }
    }

    /// Check every field against its documented range; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        let check = |name: &str, value: f64, min: f64, max: f64| {
            if value.is_finite() && value >= min && value <= max {
                Ok(())
            } else {
                Err(format!("magnetometer: {name} = {value} is outside {min}..={max}"))
            }
        };
        check("strength_ut", self.strength_ut, 1.0, 100.0)?;
        let half_pi = std::f64::consts::FRAC_PI_2;
        check("inclination_rad", self.inclination_rad, -half_pi, half_pi)?;
        let pi = std::f64::consts::PI;
        check("declination_rad", self.declination_rad, -pi, pi)?;
        for b in self.hard_iron_ut {
            check("hard_iron_ut", b, -2_000.0, 2_000.0)?;
        }
        check("soft_iron determinant", self.soft_iron_matrix().determinant(), 1e-3, 1e3)?;
        check("noise_ut", self.noise_ut, 0.0, 20.0)?;
        check("rate_hz", self.rate_hz, 1.0, 1_000.0)?;
        for c in self.motor_field_ut.iter().flatten() {
            check("motor_field_ut", *c, -1_000.0, 1_000.0)?;
        }
        Ok(())
    }

    /// The soft-iron matrix.
    pub fn soft_iron_matrix(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|i, j| self.soft_iron[i][j])
    }

    /// The Earth's field in the world (north, east, down), µT.
    pub fn field_world_ut(&self) -> Vector3<f64> {
        let horizontal = self.strength_ut * self.inclination_rad.cos();
        Vector3::new(
            horizontal * self.declination_rad.cos(),
            horizontal * self.declination_rad.sin(),
            self.strength_ut * self.inclination_rad.sin(),
        )
    }

    /// The motors' field at these normalised thrusts (missing motors at 0), µT, sensor axes.
    pub fn interference_ut(&self, thrust: &[f64]) -> Vector3<f64> {
        self.motor_field_ut
            .iter()
            .zip(thrust)
            .map(|(c, u)| Vector3::new(c[0], c[1], c[2]) * *u)
            .sum()
    }

    /// The reading without noise at the attitude `q_world_imu` and these thrusts, µT.
    pub fn clean_reading_ut(
        &self,
        q_world_imu: &UnitQuaternion<f64>,
        thrust: &[f64],
    ) -> Vector3<f64> {
        let h_imu = q_world_imu.inverse_transform_vector(&self.field_world_ut());
        self.soft_iron_matrix() * (self.q_mag_imu * h_imu)
            + Vector3::from(self.hard_iron_ut)
            + self.interference_ut(thrust)
    }
}

/// The simulated sensor: samples on its own clock with its own noise.
#[derive(Clone, Debug)]
pub struct SimMagnetometer {
    spec: MagnetometerSpec,
    rng: Rng,
    next_sample_s: f64,
}

impl SimMagnetometer {
    /// A sensor whose noise is fixed by `seed`; its first sample is due at time 0.
    pub fn new(spec: MagnetometerSpec, seed: u64) -> Self {
        Self { spec, rng: Rng::new(seed ^ 0x4D41_474E_0000_0000), next_sample_s: 0.0 }
    }

    /// The spec.
    pub fn spec(&self) -> &MagnetometerSpec {
        &self.spec
    }

    /// One reading (µT, sensor axes) when a sample is due at `time_s`, else `None`; the truth
    /// is the attitude and thrusts at the call (call it at least at the sensor's rate).
    pub fn update(
        &mut self,
        time_s: f64,
        q_world_imu: &UnitQuaternion<f64>,
        thrust: &[f64],
    ) -> Option<Vector3<f64>> {
        if time_s < self.next_sample_s {
            return None;
        }
        let period = 1.0 / self.spec.rate_hz;
        // On the sensor's grid; a caller that fell behind gets one sample, not a burst.
        self.next_sample_s += period * ((time_s - self.next_sample_s) / period).floor() + period;
        Some(self.sample(q_world_imu, thrust))
    }

    /// One reading now, whatever the clock.
    pub fn sample(&mut self, q_world_imu: &UnitQuaternion<f64>, thrust: &[f64]) -> Vector3<f64> {
        let noise = self.spec.noise_ut;
        let rng = &mut self.rng;
        self.spec.clean_reading_ut(q_world_imu, thrust)
            + Vector3::new(rng.normal() * noise, rng.normal() * noise, rng.normal() * noise)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flight::magnetometer::{
        tilt_compensated_heading, Alignment, AlignmentEstimator, Calibration, EllipsoidCalibrator,
        HeadingConfig, InterferenceConfig, InterferenceEstimator,
    };

    #[test]
    fn random_sensors_are_within_their_ranges() {
        let mut rng = Rng::new(55);
        for _ in 0..1_000 {
            let spec = MagnetometerSpec::random(&mut rng, 4);
            spec.validate().unwrap();
            assert!((25.0..=65.0).contains(&spec.strength_ut));
            assert!(spec.inclination_rad.abs() <= 70f64.to_radians());
            assert!((50.0..=100.0).contains(&spec.rate_hz));
            assert!(spec.hard_iron_ut.iter().all(|b| b.abs() <= 300.0));
            let share = spec.interference_ut(&[1.0; 4]).norm() / spec.strength_ut;
            assert!(share <= 0.5 + 1e-12, "interference {share}");
        }
        let bad = MagnetometerSpec { rate_hz: 0.0, ..MagnetometerSpec::default() };
        assert_eq!(
            bad.validate(),
            Err("magnetometer: rate_hz = 0 is outside 1..=1000".to_string())
        );
    }

    /// 20,000 samples at rest: the mean is the clean reading within 4 standard errors, each
    /// axis's standard deviation the drawn noise within 3 %, the rate the drawn rate, and the
    /// same seed gives the same samples.
    #[test]
    fn output_has_the_statistics_it_claims() {
        let mut rng = Rng::new(9);
        let spec = MagnetometerSpec::random(&mut rng, 4);
        let q = UnitQuaternion::from_euler_angles(0.2, -0.4, 2.0);
        let thrust = [0.5; 4];
        let clean = spec.clean_reading_ut(&q, &thrust);
        let mut sensor = SimMagnetometer::new(spec.clone(), 1);
        let n = 20_000;
        let mut samples = Vec::new();
        let dt = 0.001;
        let mut t = 0.0;
        while samples.len() < n {
            if let Some(m) = sensor.update(t, &q, &thrust) {
                samples.push(m);
            }
            t += dt;
        }
        let rate = (n - 1) as f64 / (t - dt);
        assert!((rate / spec.rate_hz - 1.0).abs() < 0.01, "rate {rate} vs {}", spec.rate_hz);
        let mean = samples.iter().sum::<Vector3<f64>>() / n as f64;
        let standard_error = spec.noise_ut / (n as f64).sqrt();
        for axis in 0..3 {
            assert!((mean[axis] - clean[axis]).abs() < 4.0 * standard_error, "axis {axis}");
            let var = samples.iter().map(|m| (m[axis] - mean[axis]).powi(2)).sum::<f64>()
                / (n - 1) as f64;
            assert!((var.sqrt() / spec.noise_ut - 1.0).abs() < 0.03, "axis {axis}");
        }
        // Interference proportional to thrust: full thrust minus none is the motors' sum.
        let difference =
            spec.clean_reading_ut(&q, &[1.0; 4]) - spec.clean_reading_ut(&q, &[0.0; 4]);
        assert!((difference - spec.interference_ut(&[1.0; 4])).norm() < 1e-9);
        // Deterministic from the seed.
        let mut again = SimMagnetometer::new(spec.clone(), 1);
        let mut other = SimMagnetometer::new(spec, 2);
        let first = again.sample(&q, &thrust);
        assert_eq!(first, samples[0]);
        assert_ne!(other.sample(&q, &thrust), first);
    }

    fn wrap(a: f64) -> f64 {
        (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
    }

    /// A minute of hand turning at the sensor's rate, motors off: the calibration; then 20 s
    /// more: the alignment.
    fn calibrate_and_align(
        rng: &mut Rng,
        sensor: &mut SimMagnetometer,
    ) -> (Calibration, Alignment) {
        let rate_hz = sensor.spec().rate_hz;
        let mut calibrator = EllipsoidCalibrator::new();
        for _ in 0..(60.0 * rate_hz) as usize {
            let q = uniform_rotation(rng);
            calibrator.add_sample(&sensor.sample(&q, &[]).cast());
        }
        let calibration = calibrator.solve().unwrap();
        let mut estimator = AlignmentEstimator::new();
        for _ in 0..(20.0 * rate_hz) as usize {
            let q = uniform_rotation(rng);
            let m = calibration.apply(&sensor.sample(&q, &[]).cast());
            estimator.add(&m, &q.cast());
        }
        (calibration, estimator.solve().unwrap())
    }

    /// The heading error of a noise-free reading at `q` and `thrust`, degrees, after the
    /// calibration, the alignment and (when given) the interference compensation.
    fn heading_error_deg(
        spec: &MagnetometerSpec,
        q: &UnitQuaternion<f64>,
        thrust: &[f64],
        (calibration, alignment): &(Calibration, Alignment),
        interference: Option<&InterferenceEstimator>,
    ) -> f64 {
        let config = HeadingConfig {
            declination_rad: spec.declination_rad as f32,
            ..HeadingConfig::default()
        };
        let raw = spec.clean_reading_ut(q, thrust).cast::<f32>();
        let mut field = calibration.apply(&raw);
        if let Some(estimator) = interference {
            let thrust: Vec<f32> = thrust.iter().map(|&u| u as f32).collect();
            field = estimator.compensate(&field, &thrust);
        }
        let heading =
            tilt_compensated_heading(&alignment.to_imu(&field), &q.cast(), &config).unwrap();
        wrap(f64::from(heading.yaw_rad) - q.euler_angles().2).abs().to_degrees()
    }

    /// `flight::magnetometer` recovers what the random world drew: over 20 sensors, a minute of
    /// hand turning at the sensor's rate gives the hard iron within 1 µT, the soft iron up to a
    /// rotation and a scale within 2 %, and with the alignment learned from 20 s of turning the
    /// heading within 2° over every attitude tried.
    #[test]
    fn calibration_recovers_what_was_drawn() {
        let mut rng = Rng::new(2026);
        let (mut worst_offset, mut worst_shape, mut worst_heading) = (0.0f64, 0.0f64, 0.0f64);
        for case in 0..20 {
            let spec = MagnetometerSpec::random(&mut rng, 4);
            let mut sensor = SimMagnetometer::new(spec.clone(), case);
            let fit = calibrate_and_align(&mut rng, &mut sensor);
            let calibration = &fit.0;
            let offset =
                (calibration.offset_ut.cast::<f64>() - Vector3::from(spec.hard_iron_ut)).norm();
            worst_offset = worst_offset.max(offset);
            assert!(offset < 1.0, "case {case}: hard iron off by {offset} µT");
            // W S = k U: (W S)ᵀ (W S) / k² is the identity.
            let ws = calibration.soft_iron.cast::<f64>() * spec.soft_iron_matrix();
            let gram = ws.transpose() * ws;
            let k2 = gram.trace() / 3.0;
            let shape = (gram / k2 - Matrix3::identity()).abs().max();
            worst_shape = worst_shape.max(shape);
            assert!(shape < 0.02, "case {case}: soft iron off by {shape}");
            for _ in 0..200 {
                let q = UnitQuaternion::from_euler_angles(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-std::f64::consts::PI, std::f64::consts::PI),
                );
                let error = heading_error_deg(&spec, &q, &[], &fit, None);
                worst_heading = worst_heading.max(error);
                assert!(error < 2.0, "case {case}: heading off by {error}°");
            }
        }
        println!(
            "worst hard iron {worst_offset:.3} µT, soft iron {worst_shape:.4}, heading {worst_heading:.2}°"
        );
    }

    /// The motors' fields the world drew (their sum up to 50 % of the Earth's at full thrust)
    /// learned by `flight::magnetometer::InterferenceEstimator` from a spool-up and a minute of
    /// turning flight: the summed field at full thrust within 5 % of the Earth's, and the
    /// compensated heading within 2° at every thrust (without: up to tens of degrees).
    #[test]
    fn interference_estimator_recovers_the_drawn_motors() {
        let mut rng = Rng::new(4242);
        let (mut worst_sum, mut worst_heading, mut worst_raw) = (0.0f64, 0.0f64, 0.0f64);
        for case in 0..8 {
            let spec = MagnetometerSpec::random(&mut rng, 4);
            let mut sensor = SimMagnetometer::new(spec.clone(), 100 + case);
            let fit = calibrate_and_align(&mut rng, &mut sensor);
            let (calibration, alignment) = &fit;
            let mut estimator = InterferenceEstimator::new(
                4,
                InterferenceConfig { noise_ut: calibration.residual_ut, ..Default::default() },
            );
            let dt = 1.0 / spec.rate_hz;
            let mut t = 0.0f64;
            while t < 61.0 {
                let (thrust, q) = flight::testing::interference_flight(t, 4, &mut rng);
                if let Some(m) = sensor.update(t, &q, &thrust) {
                    let thrust: Vec<f32> = thrust.iter().map(|&u| u as f32).collect();
                    let field = calibration.apply(&m.cast());
                    assert!(estimator.update(&field, &q.cast(), &alignment.q_mag_imu, &thrust));
                }
                t += dt;
            }
            let truth = calibration.soft_iron.cast::<f64>() * spec.interference_ut(&[1.0; 4]);
            let learned = estimator.interference_ut(&[1.0; 4]).0.cast::<f64>();
            let sum_error = (learned - truth).norm() / spec.strength_ut;
            worst_sum = worst_sum.max(sum_error);
            assert!(sum_error < 0.05, "case {case}: full-thrust field off by {sum_error}");
            for collective in [0.0, 0.25, 0.5, 0.75, 1.0] {
                for _ in 0..40 {
                    let q = UnitQuaternion::from_euler_angles(
                        rng.range(-0.5, 0.5),
                        rng.range(-0.5, 0.5),
                        rng.range(-std::f64::consts::PI, std::f64::consts::PI),
                    );
                    let thrust = [collective; 4];
                    let error = heading_error_deg(&spec, &q, &thrust, &fit, Some(&estimator));
                    worst_heading = worst_heading.max(error);
                    assert!(error < 2.0, "case {case} thrust {collective}: {error}°");
                    worst_raw = worst_raw.max(heading_error_deg(&spec, &q, &thrust, &fit, None));
                }
            }
        }
        println!(
            "full-thrust field off by {:.1} % of the Earth's at worst; heading {worst_heading:.2}° \
             compensated, {worst_raw:.1}° not",
            100.0 * worst_sum
        );
    }
}
