//! The user's compass calibration on the bench, simulated (issue 55): a hand turns the craft,
//! motors off, through every orientation for 30–60 s; the firmware's driver reads a simulated
//! chip ([`crate::compass_chip`]); `flight::magnetometer::EllipsoidCalibrator` fits the hard and
//! soft iron from the readings, then `AlignmentEstimator` the sensor's mounting from the
//! calibrated directions paired with the attitude the firmware's own filter
//! (`flight::attitude::AttitudeFilter`) integrates from the simulated IMU. [`calibration_dance`]
//! returns what the board would store, [`heading_error_deg`] what it is worth.
//!
//! Why: the calibration's tests in `flight` and `crate::magnetometer` draw attitudes uniformly
//! over the sphere and pair each reading with the true attitude; a real calibration gets neither.
//! A hand turns the craft along a path, so neighbouring readings are alike and some orientations
//! are never visited; the reading is quantised by the chip and paired with an attitude that is
//! some milliseconds late (the chip's conversion and the driver's poll); and the attitude is the
//! gyro's integral, drifting about the vertical with the gyro's bias (the accelerometer holds only
//! the tilt, and only while the craft turns slower than 1 rad/s).
//!
//! # The dance ([`calibration_dance`], drawn from its seed)
//!
//! | what | how, range | why |
//! |---|---|---|
//! | rest | 3 s on the bench, level, a random heading (uniform), before the hand picks it up | a board is powered before it is calibrated; its attitude filter levels from the accelerometer |
//! | path | each of the six faces of the craft turned down in turn (random order), 0–15° off (uniform), at a random heading, then a turn about the vertical, each way at random: what the rate and length leave per face after a quarter turn to reach it, kept within 90–450°, times 0.8–1.2 (uniform); the dance stops at its length wherever it is | the procedure of QGroundControl's and Mission Planner's compass calibrations: every side down, turned about the vertical |
//! | rate | 20–90 °/s (uniform), each leg ±30 % of it (uniform); the hand's angular speed follows a lag of 0.15 s | the brief's hand; a hand does not change its speed instantly |
//! | wobble | per world axis three sinusoids of 0.5–2° at 0.5–3 Hz (uniform) in angle, and the hand's position 0.5–2 cm at 0.3–2 Hz per axis | a hand's tremor and sway; they make the accelerometer read more than gravity |
//! | IMU | `crate::world`'s `imu` aspect for the seed (noise 1–3× the ICM-42688-P's, gyro bias ±0.5 °/s, accelerometer bias ±0.2 m/s², scale ±3 %, cross-axis ±2 %) on the random airframe of the seed (any IMU mounting), read at 2 kHz | the random world's IMU: the attitude drifts as the board's would |
//! | chip | IST8310 or QMC5883L (half each), polled by its firmware driver at the spec's rate | both drivers, both LSBs, single and continuous conversion |
//!
//! The spec's motor interference plays no part (the motors are off).
//!
//! # What the board is assumed to do
//!
//! Everything the firmware would, with the `flight::magnetometer` it has:
//! - the attitude filter runs with its default gains from power-up (the rest), with no heading;
//!   the gyro's offset is averaged over the last [`GYRO_REST_AVERAGE_S`] of the rest and taken
//!   out of the gyro from then on (the user is asked to hold the craft still before turning it,
//!   as compass calibrations do; without it the 95th percentile below is 3.2°, not 2.7°);
//! - the driver's reading (µT, sensor axes) goes into the calibrator as it comes, paired with the
//!   filter's quaternion at the read (the reading is up to 14 ms old then: the IST8310's
//!   measurement ends 6 ms after the read before, the QMC5883L converts every 10 ms);
//! - the calibration is solved at the end of the dance; then the pairs (kept here; a board with
//!   no room for them would turn the craft again) are calibrated and aligned **in windows** of
//!   [`ALIGNMENT_WINDOW_RAD`] of rotation (the gyro's integral of |ω|), whose mountings are
//!   averaged. One alignment over the whole dance assumes the attitude's error constant, and it
//!   is not: the gyro's scale and cross-axis errors (±3 %, ±2 %) turn the integrated attitude
//!   by up to 3 % of every turn (over a dance by 6° at the median, 26° at the 95th percentile,
//!   52° at most), and the accelerometer holds only the tilt (and only below 1 rad/s). A
//!   constant error of the attitude is harmless (it rotates the world frame, which the
//!   alignment's unknown field direction absorbs); within 360° of rotation the error changes by
//!   at most about 11°.
//!
//! # Measured (the test below: 300 random sensors, dances of 30–60 s, 2026-12-03)
//!
//! The worst heading error over 100 flying attitudes (roll and pitch within ±30°, any heading)
//! per dance: median 1.28°, 90th 2.27°, **95th 2.74°**, max 5.01° (293 dances; 7 refused for
//! coverage 0.13–0.18, too slow for their length). Aligned over the whole dance at once: median
//! 1.96°, 95th 5.08°, max 10.2°; with the true attitude instead of the filter's (the simulator's
//! knowledge): median 0.28°, 95th 1.03°, max 3.5°. The tail is the dances that covered less of the
//! sphere: coverage below 0.4 (16 dances) 95th 4.9°, 0.4–0.6 (50) 3.4°, above 0.6 (227) 2.4°
//! (refusing below 0.4 instead of `flight`'s 0.2 would leave 2.6° at the 95th percentile, 5.0°
//! at most). Per chip: IST8310 95th 2.7°, QMC5883L 2.8°; per rate (20–45, 45–70, 70–90 °/s):
//! 2.9°, 2.7°, 2.5°.

use firmware::drivers::compass::{CompassError, CompassReading};
use firmware::drivers::ist8310::Ist8310;
use firmware::drivers::qmc5883l::Qmc5883l;
use flight::attitude::{AttitudeConfig, AttitudeFilter};
use flight::magnetometer::{
    tilt_compensated_heading, Alignment, AlignmentError, AlignmentEstimator, Calibration,
    CalibrationError, EllipsoidCalibrator, HeadingConfig,
};
use nalgebra::{UnitQuaternion, Vector3};

use crate::airframe::{MAX_ROTORS, STANDARD_GRAVITY_MPS2};
use crate::compass_chip::{ChipKind, CountingDelay, Nack, SharedCompassChip, SimCompassChip};
use crate::dynamics::{Derivative, State};
use crate::imu::ImuModel;
use crate::magnetometer::MagnetometerSpec;
use crate::rng::Rng;
use crate::world::{random_world_case, Aspect};

/// The hand's angular speed drawn per dance, °/s (the brief's 20–90 °/s).
pub const DANCE_RATE_DPS: (f64, f64) = (20.0, 90.0);
/// Each leg's speed as a share of the dance's, ± (30 %).
const LEG_RATE_SPREAD: f64 = 0.3;
/// The lag of the hand's angular speed, s (ours: a hand takes a few tenths of a second to speed
/// up or slow down a turn).
const HAND_LAG_S: f64 = 0.15;
/// Rest on the bench before the dance, s.
pub const REST_S: f64 = 3.0;
/// How far a face is held off straight down, rad (15°).
const FACE_TILT_MAX_RAD: f64 = 15.0 * std::f64::consts::PI / 180.0;
/// The turn about the vertical at each face, rad (90–450°).
const FACE_TURN_RAD: (f64, f64) = (0.5 * std::f64::consts::PI, 2.5 * std::f64::consts::PI);
/// A face counts as reached within this angle, rad (2°).
const FACE_REACHED_RAD: f64 = 2.0 * std::f64::consts::PI / 180.0;
/// The hand's angular wobble: amplitude per sinusoid, rad (0.5–2°), and frequency, Hz.
const WOBBLE_ANGLE_RAD: (f64, f64) =
    (0.5 * std::f64::consts::PI / 180.0, 2.0 * std::f64::consts::PI / 180.0);
const WOBBLE_HZ: (f64, f64) = (0.5, 3.0);
/// The hand's sway: amplitude per axis, m, and frequency, Hz.
const SWAY_M: (f64, f64) = (0.005, 0.02);
const SWAY_HZ: (f64, f64) = (0.3, 2.0);
/// The simulation's step and the IMU's rate, s (2 kHz, the control rate: the board's samples
/// after its decimation).
const STEP_S: f64 = 0.0005;
/// The alignment's window, rad of rotation (ours, 360°): the attitude's drift within it stays
/// below about 11° (the gyro's scale error, up to 3 % of the angle turned, is the larger part),
/// and it holds a face's change and part of its turn, the two axes the mounting needs.
pub const ALIGNMENT_WINDOW_RAD: f64 = 2.0 * std::f64::consts::PI;
/// The last part of the rest over which the gyro's offset is averaged, s.
const GYRO_REST_AVERAGE_S: f64 = 2.0;

/// Why a dance gave no calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DanceError {
    /// The driver's `init` failed.
    Init(CompassError<Nack>),
    /// The ellipsoid fit refused the readings.
    Calibration(CalibrationError),
    /// The alignment refused the pairs.
    Alignment(AlignmentError),
    /// What was fitted is no calibration the board stores (a value not finite).
    NotStorable,
}

/// What a dance gave the board, and what it was.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DanceOutcome {
    /// The hard- and soft-iron calibration.
    pub calibration: Calibration,
    /// The mounting: the mean of the alignments solved over windows of
    /// [`ALIGNMENT_WINDOW_RAD`] of rotation (see the module documentation).
    pub alignment: Alignment,
    /// The mounting solved over the whole dance at once (for comparison: the attitude's drift
    /// over the dance spoils it).
    pub whole_dance_alignment: Result<Alignment, AlignmentError>,
    /// The mounting solved over the whole dance with the true attitude instead of the filter's
    /// (what the calibration and the readings alone allow; the simulator's knowledge, not the
    /// board's).
    pub true_attitude_alignment: Result<Alignment, AlignmentError>,
    /// The chip the driver read.
    pub chip: ChipKind,
    /// The hand's angular speed drawn, °/s.
    pub rate_dps: f64,
    /// Valid readings taken during the dance.
    pub readings: u32,
    /// The attitude filter's error at the end of the dance, rad: how far the integrated
    /// attitude drifted (its yaw relative to the truth's at the start included).
    pub attitude_drift_rad: f64,
}

/// A sum of sinusoids per axis: the hand's wobble (angles) or sway (positions).
struct Sinusoids {
    /// Per axis, three (amplitude, angular frequency rad/s, phase rad).
    terms: [[(f64, f64, f64); 3]; 3],
}

impl Sinusoids {
    fn random(rng: &mut Rng, amplitude: (f64, f64), hz: (f64, f64)) -> Self {
        Self {
            terms: std::array::from_fn(|_| {
                std::array::from_fn(|_| {
                    let a = rng.range(amplitude.0, amplitude.1);
                    let w = std::f64::consts::TAU * rng.range(hz.0, hz.1);
                    (a, w, rng.range(0.0, std::f64::consts::TAU))
                })
            }),
        }
    }

    /// The first derivative (`order` 1) or the second (2) at `t_s`.
    fn derivative(&self, t_s: f64, order: i32) -> Vector3<f64> {
        Vector3::from_fn(|axis, _| {
            self.terms[axis]
                .iter()
                .map(|&(a, w, p)| match order {
                    1 => a * w * (w * t_s + p).cos(),
                    _ => -a * w * w * (w * t_s + p).sin(),
                })
                .sum()
        })
    }
}

/// One leg of the path.
#[derive(Clone, Copy, Debug)]
enum Leg {
    /// Turn to this attitude (`q_world_body`).
    Face(UnitQuaternion<f64>),
    /// Turn about world down by this angle, rad (signed).
    Turn(f64),
}

/// The legs for a dance of `length_s` at `rate_rad_s`: six faces in a random order, each
/// followed by a turn about the vertical.
fn legs(rng: &mut Rng, length_s: f64, rate_rad_s: f64) -> Vec<(Leg, f64)> {
    let mut faces: Vec<Vector3<f64>> =
        [Vector3::x(), -Vector3::x(), Vector3::y(), -Vector3::y(), Vector3::z(), -Vector3::z()]
            .to_vec();
    // Fisher–Yates.
    for i in (1..faces.len()).rev() {
        faces.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
    }
    // A face takes about a quarter turn to reach; the turns share what is left.
    let per_face_rad = (rate_rad_s * length_s / 6.0 - 0.5 * std::f64::consts::PI)
        .clamp(FACE_TURN_RAD.0, FACE_TURN_RAD.1);
    let mut legs = Vec::new();
    for down_body in faces {
        let tilt =
            UnitQuaternion::rotation_between(&down_body, &Vector3::z()).unwrap_or_else(|| {
                UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
            });
        let off_axis = rng.range(0.0, std::f64::consts::TAU);
        let off = UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(off_axis.cos(), off_axis.sin(), 0.0)),
            rng.range(0.0, FACE_TILT_MAX_RAD),
        );
        let heading = UnitQuaternion::from_axis_angle(
            &Vector3::z_axis(),
            rng.range(0.0, std::f64::consts::TAU),
        );
        let leg_rate = rate_rad_s * (1.0 + rng.range(-LEG_RATE_SPREAD, LEG_RATE_SPREAD));
        legs.push((Leg::Face(heading * off * tilt), leg_rate));
        let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
        let turn = per_face_rad * rng.range(0.8, 1.2);
        let leg_rate = rate_rad_s * (1.0 + rng.range(-LEG_RATE_SPREAD, LEG_RATE_SPREAD));
        legs.push((Leg::Turn(sign * turn), leg_rate));
    }
    legs
}

/// The firmware's driver of either chip, as one reader.
enum Driver {
    Ist8310(Ist8310<SharedCompassChip>),
    Qmc5883l(Qmc5883l<SharedCompassChip>),
}

impl Driver {
    fn read(&mut self) -> Result<CompassReading, CompassError<Nack>> {
        match self {
            Driver::Ist8310(d) => d.read(),
            Driver::Qmc5883l(d) => d.read(),
        }
    }
}

/// The user's calibration of a compass sensing `spec`, `length_s` seconds of turning by hand
/// (30–60 s is what a user gives it), everything else drawn from `seed` (see the module
/// documentation): the calibration and the mounting the board would store, or why it refused.
pub fn calibration_dance(
    spec: &MagnetometerSpec,
    seed: u64,
    length_s: f64,
) -> Result<DanceOutcome, DanceError> {
    let mut rng = Rng::new(seed ^ 0x4441_4E43_4500_0000);
    let (mut airframe, _) = random_world_case(seed, &[Aspect::Imu]);
    airframe.imu.sample_rate_hz = 1.0 / STEP_S;
    let mut imu = ImuModel::new(&airframe, seed, false);
    let q_imu_body = UnitQuaternion::from_matrix(imu.rot_imu_body());
    let kind = if rng.uniform() < 0.5 { ChipKind::Ist8310 } else { ChipKind::Qmc5883l };
    let chip = SharedCompassChip::new(SimCompassChip::new(kind, spec.clone(), seed));
    let mut driver = match kind {
        ChipKind::Ist8310 => Driver::Ist8310(Ist8310::new(chip.clone(), kind.default_address())),
        ChipKind::Qmc5883l => Driver::Qmc5883l(Qmc5883l::new(chip.clone(), kind.default_address())),
    };
    let mut delay = CountingDelay::default();
    match &mut driver {
        Driver::Ist8310(d) => d.init(&mut delay),
        Driver::Qmc5883l(d) => d.init(&mut delay),
    }
    .map_err(DanceError::Init)?;

    let rate_rad_s = rng.range(DANCE_RATE_DPS.0, DANCE_RATE_DPS.1).to_radians();
    let legs = legs(&mut rng, length_s, rate_rad_s);
    let wobble = Sinusoids::random(&mut rng, WOBBLE_ANGLE_RAD, WOBBLE_HZ);
    let sway = Sinusoids::random(&mut rng, SWAY_M, SWAY_HZ);
    let poll_s = 1.0 / spec.rate_hz;

    let mut q_world_body =
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.range(0.0, std::f64::consts::TAU));
    let mut filter = AttitudeFilter::new(AttitudeConfig::default());
    let mut calibrator = EllipsoidCalibrator::new();
    let mut pairs: Vec<Pair> = Vec::new();
    let mut true_pairs: Vec<Pair> = Vec::new();
    let mut turned_rad = 0.0f64;
    let (mut rest_gyro_sum, mut rest_gyro_samples) = (Vector3::zeros(), 0u32);
    let mut error_at_start: Option<UnitQuaternion<f64>> = None;
    let (mut leg, mut leg_turned_rad) = (0usize, 0.0f64);
    let mut omega_hand_world = Vector3::zeros();
    let mut previous_rate_body: Option<Vector3<f64>> = None;
    let mut next_poll_s = 0.0;
    let end_s = REST_S + length_s;
    let steps = (end_s / STEP_S).round() as usize;
    for k in 0..=steps {
        let t = k as f64 * STEP_S;
        let dancing = t >= REST_S;
        // The hand's wanted angular velocity (world), lagged.
        let mut wanted = Vector3::zeros();
        if dancing {
            while leg < legs.len() {
                let (l, leg_rate) = legs[leg];
                let done = match l {
                    Leg::Face(target) => {
                        let error = target * q_world_body.inverse();
                        match error.axis_angle() {
                            Some((axis, angle)) if angle > FACE_REACHED_RAD => {
                                // Slowing into the face over the last half radian.
                                wanted = axis.into_inner() * leg_rate.min(2.0 * angle);
                                false
                            }
                            _ => true,
                        }
                    }
                    Leg::Turn(angle) => {
                        if leg_turned_rad < angle.abs() {
                            wanted = Vector3::z() * leg_rate * angle.signum();
                            false
                        } else {
                            true
                        }
                    }
                };
                if !done {
                    break;
                }
                leg += 1;
                leg_turned_rad = 0.0;
            }
        }
        omega_hand_world += (wanted - omega_hand_world) * (STEP_S / HAND_LAG_S);
        let (omega_world, accel_world) = if dancing {
            let dance_t = t - REST_S;
            // The wobble and sway start from zero as the hand picks the craft up.
            let fade = (dance_t / 1.0).min(1.0);
            (
                omega_hand_world + wobble.derivative(dance_t, 1) * fade,
                sway.derivative(dance_t, 2) * fade,
            )
        } else {
            (Vector3::zeros(), Vector3::zeros())
        };
        let rate_body = q_world_body.inverse_transform_vector(&omega_world);
        let rate_dot_body =
            previous_rate_body.map_or(Vector3::zeros(), |p| (rate_body - p) / STEP_S);
        previous_rate_body = Some(rate_body);
        let state =
            State { rate_body_rad_s: rate_body, ..State::at_rest(Vector3::zeros(), q_world_body) };
        let derivative = Derivative {
            velocity_ned_mps: Vector3::zeros(),
            accel_ned_mps2: accel_world,
            q_dot: nalgebra::Quaternion::identity(),
            rate_dot_body_rad_s2: rate_dot_body,
            rotor_accel_rad_s2: [0.0; MAX_ROTORS],
            specific_force_body_mps2: q_world_body
                .inverse_transform_vector(&(accel_world - Vector3::z() * STANDARD_GRAVITY_MPS2)),
        };
        let (sample, _) = imu.sample(&state, &derivative, &[0.0; MAX_ROTORS]);
        if dancing {
            turned_rad += sample.gyro_rad_s.norm() * STEP_S;
        }
        // The gyro's offset averaged over the rest, taken out from then on (when asked).
        if !dancing && t >= REST_S - GYRO_REST_AVERAGE_S {
            rest_gyro_sum += sample.gyro_rad_s;
            rest_gyro_samples += 1;
        }
        let gyro_offset = if dancing {
            rest_gyro_sum / f64::from(rest_gyro_samples.max(1))
        } else {
            Vector3::zeros()
        };
        // The filter is told nothing but the IMU's samples: it estimates q_world_imu.
        let _ = filter.update(
            &(sample.gyro_rad_s - gyro_offset).cast::<f32>(),
            &sample.accel_mps2.cast::<f32>(),
            None,
            STEP_S as f32,
        );
        let q_world_imu = q_world_body * q_imu_body.inverse();
        if dancing && error_at_start.is_none() {
            error_at_start = Some(filter.quaternion().cast::<f64>() * q_world_imu.inverse());
        }
        chip.update(t, &q_world_imu, &[]);
        if t >= next_poll_s {
            next_poll_s += poll_s;
            if let Ok(reading) = driver.read() {
                if dancing {
                    let raw = Vector3::from(reading.field_ut);
                    if calibrator.add_sample(&raw) {
                        let q_world_imu_f32 = q_world_imu.cast();
                        pairs.push(Pair {
                            raw_ut: raw,
                            q_world_imu: filter.quaternion(),
                            turned_rad,
                        });
                        true_pairs.push(Pair {
                            raw_ut: raw,
                            q_world_imu: q_world_imu_f32,
                            turned_rad,
                        });
                    }
                }
            }
        }
        // The true attitude turns on.
        q_world_body = UnitQuaternion::from_scaled_axis(omega_world * STEP_S) * q_world_body;
        if let Some((Leg::Turn(_), _)) = legs.get(leg) {
            leg_turned_rad += omega_hand_world.z.abs() * STEP_S;
        }
    }
    let calibration = calibrator.solve().map_err(DanceError::Calibration)?;
    let window_rad = ALIGNMENT_WINDOW_RAD;
    let alignment =
        windowed_alignment(&calibration, &pairs, window_rad).map_err(DanceError::Alignment)?;
    let whole_dance_alignment = windowed_alignment(&calibration, &pairs, f64::INFINITY);
    let true_attitude_alignment = windowed_alignment(&calibration, &true_pairs, f64::INFINITY);
    // The drift: how the filter's error against the truth changed over the dance.
    let q_true_imu = q_world_body * q_imu_body.inverse();
    let error_at_end = filter.quaternion().cast::<f64>() * q_true_imu.inverse();
    let attitude_drift_rad = error_at_start.map_or(0.0, |e| error_at_end.angle_to(&e));
    Ok(DanceOutcome {
        calibration,
        alignment,
        whole_dance_alignment,
        true_attitude_alignment,
        chip: kind,
        rate_dps: rate_rad_s.to_degrees(),
        readings: calibrator.samples(),
        attitude_drift_rad,
    })
}

/// The alignment from `pairs` (raw reading, attitude, the rotation turned so far in rad)
/// calibrated by `calibration`, solved over consecutive windows of `window_rad` of rotation
/// each (a window the estimator refuses grows into the next, and a last one shorter than half a
/// window joins the one before), the mountings averaged with weights `1/std²`; the result's
/// residual, standard deviation and field direction are those of the best window, its sample
/// count all the windows'. The last refusal when no window could be solved.
fn windowed_alignment(
    calibration: &Calibration,
    pairs: &[Pair],
    window_rad: f64,
) -> Result<Alignment, AlignmentError> {
    let mut solved = Vec::new();
    let mut last_error = AlignmentError::TooFewSamples { samples: 0 };
    let mut estimator = AlignmentEstimator::new();
    let mut window_end_rad = pairs.first().map_or(0.0, |p| p.turned_rad) + window_rad;
    let total_rad = pairs.last().map_or(0.0, |p| p.turned_rad);
    for (i, pair) in pairs.iter().enumerate() {
        estimator.add(&calibration.apply(&pair.raw_ut), &pair.q_world_imu);
        let last = i + 1 == pairs.len();
        // Close the window at its end unless less than half a window would be left over.
        let closing =
            pair.turned_rad >= window_end_rad && total_rad - pair.turned_rad >= 0.5 * window_rad;
        if closing || last {
            match estimator.solve() {
                Ok(a) => {
                    solved.push(a);
                    estimator = AlignmentEstimator::new();
                }
                Err(e) => last_error = e,
            }
            window_end_rad = pair.turned_rad + window_rad;
        }
    }
    let best = *solved.iter().min_by(|a, b| a.std_rad.total_cmp(&b.std_rad)).ok_or(last_error)?;
    // The weighted mean of the quaternions, each on the side of the best one's hemisphere.
    let reference = best.q_mag_imu.into_inner();
    let sum = solved.iter().fold(nalgebra::Quaternion::<f32>::new(0.0, 0.0, 0.0, 0.0), |sum, a| {
        let q = a.q_mag_imu.into_inner();
        let q = if q.dot(&reference) < 0.0 { -q } else { q };
        sum + q * (1.0 / a.std_rad.max(1e-6).powi(2))
    });
    Ok(Alignment {
        q_mag_imu: UnitQuaternion::from_quaternion(sum),
        samples: solved.iter().map(|a| a.samples).sum(),
        ..best
    })
}

/// A reading and what the board knew when it took it.
#[derive(Clone, Copy, Debug)]
struct Pair {
    /// The driver's reading, µT, sensor axes.
    raw_ut: Vector3<f32>,
    /// The attitude the pair is given with.
    q_world_imu: UnitQuaternion<f32>,
    /// The rotation the gyro measured since the dance began (the integral of |ω|), rad.
    turned_rad: f64,
}

/// The heading error of the board's compass after `outcome` at the attitude `q_world_imu`
/// (with the motors off), degrees: the noise-free reading through the calibration and the
/// mounting, the tilt-compensated heading (the true roll and pitch, the spec's declination)
/// against the true yaw.
pub fn heading_error_deg(
    spec: &MagnetometerSpec,
    outcome: &DanceOutcome,
    q_world_imu: &UnitQuaternion<f64>,
) -> f64 {
    let config =
        HeadingConfig { declination_rad: spec.declination_rad as f32, ..HeadingConfig::default() };
    let raw = spec.clean_reading_ut(q_world_imu, &[]).cast::<f32>();
    let field_imu = outcome.alignment.to_imu(&outcome.calibration.apply(&raw));
    match tilt_compensated_heading(&field_imu, &q_world_imu.cast(), &config) {
        Ok(heading) => {
            let error = f64::from(heading.yaw_rad) - q_world_imu.euler_angles().2;
            (error + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU).to_degrees() - 180.0
        }
        Err(_) => f64::INFINITY,
    }
    .abs()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::quantile;

    /// Largest tilt the heading is checked at, rad (30°: a craft flying).
    const CHECK_TILT_RAD: f64 = 30.0 * std::f64::consts::PI / 180.0;

    /// The worst heading error over 100 attitudes (roll and pitch within ±30°, any yaw).
    fn worst_heading_error_deg(spec: &MagnetometerSpec, outcome: &DanceOutcome, seed: u64) -> f64 {
        let mut rng = Rng::new(seed);
        (0..100)
            .map(|_| {
                let q = UnitQuaternion::from_euler_angles(
                    rng.range(-CHECK_TILT_RAD, CHECK_TILT_RAD),
                    rng.range(-CHECK_TILT_RAD, CHECK_TILT_RAD),
                    rng.range(-std::f64::consts::PI, std::f64::consts::PI),
                );
                heading_error_deg(spec, outcome, &q)
            })
            .fold(0.0, f64::max)
    }

    /// Dances in the test: 300, about 15 s (the 95th percentile of a hundred moves by half a
    /// degree from one set of seeds to the next).
    const DANCES: u64 = 300;

    /// `median, 90th, 95th, max` of `values`, degrees.
    fn distribution(values: &[f64]) -> String {
        format!(
            "median {:.2}°, 90th {:.2}°, 95th {:.2}°, max {:.2}°",
            quantile(values, 0.5),
            quantile(values, 0.9),
            quantile(values, 0.95),
            values.iter().cloned().fold(0.0, f64::max)
        )
    }

    /// Over 300 random sensors (the random world's ranges: field, dip, declination, hard and
    /// soft iron, any mounting, noise, rate), each calibrated by a dance of 30–60 s at 20–90 °/s
    /// through the firmware's driver with the attitude the firmware's filter integrates from a
    /// random IMU: the worst heading error over flying attitudes is within 3° at the 95th
    /// percentile; a dance is refused only for its coverage (too slow for its length), at most
    /// 5 % of them; and the windowed alignment beats one over the whole dance, which the
    /// attitude's drift spoils (its 95th percentile is larger).
    #[test]
    fn a_dance_by_hand_calibrates_random_sensors_within_three_degrees() {
        let (mut worst, mut whole, mut truth) = (Vec::new(), Vec::new(), Vec::new());
        let mut refused = Vec::new();
        let mut spec_rng = Rng::new(0x00DA_4CE5);
        for seed in 0..DANCES {
            let spec = MagnetometerSpec::random(&mut spec_rng, 4);
            let length_s = spec_rng.range(30.0, 60.0);
            let outcome = match calibration_dance(&spec, seed, length_s) {
                Ok(outcome) => outcome,
                // The board says to turn on: a fair answer to a dance too slow for its length.
                Err(DanceError::Calibration(CalibrationError::InsufficientCoverage {
                    coverage,
                })) => {
                    println!("seed {seed}: {length_s:.0} s, refused: coverage {coverage:.2}");
                    refused.push(seed);
                    continue;
                }
                Err(e) => panic!("seed {seed}: {e:?}"),
            };
            let error = worst_heading_error_deg(&spec, &outcome, seed);
            let other = |alignment: Result<Alignment, AlignmentError>| {
                alignment.map_or(f64::INFINITY, |alignment| {
                    worst_heading_error_deg(&spec, &DanceOutcome { alignment, ..outcome }, seed)
                })
            };
            whole.push(other(outcome.whole_dance_alignment));
            truth.push(other(outcome.true_attitude_alignment));
            println!(
                "seed {seed}: {:?} {length_s:.0} s at {:.0} °/s, {} readings, coverage {:.2}, \
                 drift {:.1}°, worst heading {error:.2}° (whole dance {:.2}°, true attitude \
                 {:.2}°)",
                outcome.chip,
                outcome.rate_dps,
                outcome.readings,
                outcome.calibration.coverage,
                outcome.attitude_drift_rad.to_degrees(),
                whole[whole.len() - 1],
                truth[truth.len() - 1],
            );
            worst.push(error);
        }
        println!("worst heading error per dance: {}", distribution(&worst));
        println!("  aligned over the whole dance at once: {}", distribution(&whole));
        println!("  aligned with the true attitude: {}", distribution(&truth));
        println!("  refused (coverage): {} of {DANCES}", refused.len());
        let p95 = quantile(&worst, 0.95);
        assert!(p95 <= 3.0, "95th percentile {p95:.2}°");
        assert!(refused.len() as u64 * 20 <= DANCES, "{} refused", refused.len());
        assert!(quantile(&whole, 0.95) > p95, "the windows gain nothing");
    }
}
