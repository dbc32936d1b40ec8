//! The compass as the pilot uses it: from the calibrated field (`super::compass`, in the IMU's
//! axes) and the attitude filter's tilt, the IMU's heading from true north, when the field can
//! be trusted.
//!
//! Why: outdoors the GNSS fixes carry no heading, and without one the craft must move before the
//! heading alignment (`flight::navigation::HeadingAlignment`) can tell which way to brake; a
//! tumble can leave the filter tilted by degrees, and the craft then drifts metres before that.
//! A compass gives the heading at rest and in a steady flight, so the pilot takes it as the
//! alignment's yaw at once and steers the filter's heading with it (`super::pilot`).
//!
//! **What it assumes of the world.**
//! - The calibration (hard and soft iron, mounting: `configurator-cli compass calibrate`) holds,
//!   and the declination (`compass_declination_deg`) is the local one: true north, the GNSS
//!   fixes' north, is magnetic north plus it.
//! - The motors' currents add a field the calibration does not know (up to half the Earth's on
//!   a mast 10–20 cm above the power wires). It is not compensated here; it is detected:
//!   [`flight::magnetometer::InterferenceMonitor`] compares the field's strength and
//!   inclination with their values with the motors off (averaged over
//!   [`REFERENCE_TIME_S`] while the craft is disarmed and still), and a disturbed field gives no
//!   heading. A disturbance that turns the field about the vertical without changing its
//!   strength or inclination is not seen; the fixes' own alignment then shows the compass's
//!   error as a yaw of its own.
//! - Without that reference (a board armed without a still moment) the compass gives no heading.
//! - The filter's tilt is good enough for the tilt compensation: the pilot asks for a heading only
//!   in a steady flight (slow, near 1 g), where a tilt error `e` turns it by about `e · tan(dip)`.

use flight::magnetometer::{
    tilt_compensated_yaw, HeadingConfig, InterferenceMonitor, MonitorConfig,
};
use nalgebra::{UnitQuaternion, Vector3};

use super::hal::elapsed_s;

/// One calibrated field for the control step (`super::ControlCommand::MagneticField`; the
/// compass service makes it, `super::compass`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MagneticSample {
    /// The calibrated field, IMU axes, µT.
    pub field_imu_ut: [f32; 3],
    /// Its noise, one standard deviation per axis, µT.
    pub noise_ut: f32,
}

impl MagneticSample {
    /// Every value finite and the noise positive (what the control step takes).
    pub fn is_valid(&self) -> bool {
        self.field_imu_ut.iter().all(|x| x.is_finite())
            && self.noise_ut.is_finite()
            && self.noise_ut > 0.0
    }
}

/// How old the latest sample may be and still give a heading, s (ours): the service reads the
/// sensor every 10 ms; five periods.
pub const FRESH_S: f32 = 0.05;

/// Time constant of the motors-off reference's average, s (ours): a hundred samples at 100 Hz,
/// which bring 2 µT of noise down to about 0.2 µT, well inside the monitor's tolerances (8 % of
/// the strength, 3° of inclination).
pub const REFERENCE_TIME_S: f32 = 1.0;

/// Largest standard deviation of a heading the pilot takes, rad (5°, ours): a field with less
/// than about 12 µT of horizontal strength at 1 µT of noise, or 1° of tilt error at a 78° dip,
/// gives none.
pub const MAX_HEADING_STD_RAD: f32 = 5.0 * core::f32::consts::PI / 180.0;

/// The latest field, the motors-off reference, and what they say of the heading.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct CompassHeading {
    /// The latest calibrated field and its arrival time, µs.
    latest: Option<(MagneticSample, u64)>,
    /// Arrival time of the latest sample taken (its heading found), µs.
    taken_us: u64,
    /// Arrival time of the latest sample the monitor saw, µs.
    monitored_us: u64,
    /// The field averaged in the filter's world while disarmed and still, µT.
    still_world_ut: Option<Vector3<f32>>,
    monitor: Option<InterferenceMonitor>,
    /// The heading of the latest sample taken, rad, when it was trusted.
    yaw_rad: Option<f32>,
    declination_rad: f32,
}

impl CompassHeading {
    /// Take `declination_rad` (east of true north positive); a non-finite one keeps the current.
    pub fn configure(&mut self, declination_rad: f32) {
        if declination_rad.is_finite() {
            self.declination_rad = declination_rad;
        }
    }

    /// A calibrated field that arrived at `now_us` (invalid ones ignored).
    pub fn sample(&mut self, sample: &MagneticSample, now_us: u64) {
        if sample.is_valid() {
            self.latest = Some((*sample, now_us));
        }
    }

    /// The latest field and its arrival time, µs.
    #[cfg(test)]
    pub fn latest(&self) -> Option<(MagneticSample, u64)> {
        self.latest
    }

    /// Forget the latest sample and its heading (a disarm). The motors-off reference stays: it
    /// follows the field whenever the craft is disarmed and still, and an arming for a throw
    /// (which disarms first) must not lose it.
    pub fn forget_sample(&mut self) {
        self.latest = None;
        self.yaw_rad = None;
    }

    /// The IMU's heading from true north, rad, at `now_us` with the filter's attitude
    /// `q_filter` (its yaw does not matter), when the latest sample is fresh and trusted.
    /// `still_disarmed`: the motors are off and the craft still, so the sample joins the
    /// reference.
    ///
    /// A new sample is taken in two parts, one per step, each a fraction of the control step's
    /// budget: the interference monitor (or the motors-off reference), then the heading; until
    /// the second, the previous sample's heading stands (at 100 Hz, 10 ms older). `busy`: the
    /// step carries other work (a GNSS solution's part, `super::fix_parts`), and the sample
    /// waits for a step that does not (the parts last four steps, 2 ms; a sample stays fresh
    /// for [`FRESH_S`]).
    pub fn step(
        &mut self,
        now_us: u64,
        q_filter: &UnitQuaternion<f32>,
        still_disarmed: bool,
        busy: bool,
    ) -> Option<f32> {
        let (sample, at_us) = self.latest?;
        if elapsed_s(at_us, now_us) > FRESH_S {
            self.yaw_rad = None;
            return None;
        }
        if at_us == self.taken_us || busy {
            return self.yaw_rad;
        }
        let field = Vector3::from(sample.field_imu_ut);
        if at_us != self.monitored_us {
            // Part 1: the monitor, `dt_s` after the previous sample it saw.
            let dt_s =
                if self.monitored_us == 0 { 0.01 } else { elapsed_s(self.monitored_us, at_us) };
            self.monitored_us = at_us;
            if still_disarmed {
                let world = q_filter * field;
                let a = (dt_s / REFERENCE_TIME_S).min(1.0);
                let average = self.still_world_ut.map_or(world, |mean| mean + (world - mean) * a);
                self.still_world_ut = Some(average);
                self.monitor = Some(InterferenceMonitor::new(
                    MonitorConfig::default(),
                    &average,
                    &UnitQuaternion::identity(),
                ));
            } else if let Some(monitor) = &mut self.monitor {
                monitor.update(&field, q_filter, dt_s);
            }
            return self.yaw_rad;
        }
        // Part 2: the heading.
        self.taken_us = at_us;
        let trusted = self.monitor.is_some_and(|monitor| !monitor.status().disturbed);
        let config = HeadingConfig {
            declination_rad: self.declination_rad,
            noise_ut: sample.noise_ut,
            ..HeadingConfig::default()
        };
        self.yaw_rad = trusted
            .then(|| tilt_compensated_yaw(&field, q_filter, &config).ok())
            .flatten()
            .filter(|(_, std_rad)| *std_rad <= MAX_HEADING_STD_RAD)
            .map(|(yaw_rad, _)| yaw_rad);
        self.yaw_rad
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flight::attitude::wrap_pi;

    /// A field of 48 µT at 60° of dip, magnetic north 10° east of true north, in the IMU's
    /// axes for an IMU at `yaw` (true), pitched by `pitch`, plus `extra_imu_ut`.
    fn field(
        yaw: f32,
        pitch: f32,
        extra_imu_ut: Vector3<f32>,
    ) -> (MagneticSample, UnitQuaternion<f32>) {
        let (dip, declination) = (60f32.to_radians(), 10f32.to_radians());
        let world = Vector3::new(
            48.0 * libm::cosf(dip) * libm::cosf(declination),
            48.0 * libm::cosf(dip) * libm::sinf(declination),
            48.0 * libm::sinf(dip),
        );
        let q = UnitQuaternion::from_euler_angles(0.0, pitch, yaw);
        let imu = q.inverse() * world + extra_imu_ut;
        (MagneticSample { field_imu_ut: imu.into(), noise_ut: 0.5 }, q)
    }

    /// The heading is the IMU's true one whatever the filter's own yaw, once a motors-off
    /// reference exists; none without it, none from a stale sample.
    #[test]
    fn the_heading_is_the_imus_true_one_once_a_reference_exists() {
        let mut compass = CompassHeading::default();
        compass.configure(10f32.to_radians());
        let (sample, q_true) = field(1.0, 0.2, Vector3::zeros());
        // The filter's yaw is arbitrary; its tilt is right.
        let q_filter = UnitQuaternion::from_euler_angles(0.0, 0.2, -2.0);
        compass.sample(&sample, 1_000);
        assert_eq!(compass.step(1_000, &q_filter, false, false), None, "no reference yet");
        assert_eq!(compass.step(1_500, &q_filter, false, false), None, "no reference yet");
        compass.sample(&sample, 11_000);
        // The monitor's part, then the heading's; a busy step in between does neither.
        assert_eq!(compass.step(11_000, &q_filter, true, false), None, "the monitor's part");
        assert_eq!(compass.step(11_500, &q_filter, true, true), None, "a busy step");
        let yaw = compass.step(12_000, &q_filter, true, false).expect("a heading");
        assert!(wrap_pi(yaw - flight::attitude::yaw_of(&q_true)).abs() < 0.01, "{yaw}");
        assert_eq!(compass.step(12_500, &q_filter, true, true), Some(yaw), "kept");
        assert_eq!(compass.step(11_000 + 60_000, &q_filter, false, false), None, "stale");
    }

    /// Motors' interference of a quarter of the field, off the reference: no heading, where
    /// the field alone would have turned it by degrees.
    #[test]
    fn a_field_disturbed_by_the_motors_gives_no_heading() {
        let mut compass = CompassHeading::default();
        compass.configure(10f32.to_radians());
        let q_filter = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3);
        let mut t_us = 0;
        for _ in 0..200 {
            t_us += 10_000;
            compass.sample(&field(0.3, 0.0, Vector3::zeros()).0, t_us);
            compass.step(t_us, &q_filter, true, false);
            assert!(compass.step(t_us + 500, &q_filter, true, false).is_some());
        }
        let extra = Vector3::new(0.0, 12.0, -6.0);
        let mut last = None;
        for _ in 0..200 {
            t_us += 10_000;
            compass.sample(&field(0.3, 0.0, extra).0, t_us);
            compass.step(t_us, &q_filter, false, false);
            last = compass.step(t_us + 500, &q_filter, false, false);
        }
        assert_eq!(last, None, "the disturbed field was trusted");
        // Back without the motors' field: trusted again.
        for _ in 0..300 {
            t_us += 10_000;
            compass.sample(&field(0.3, 0.0, Vector3::zeros()).0, t_us);
            compass.step(t_us, &q_filter, false, false);
            last = compass.step(t_us + 500, &q_filter, false, false);
        }
        let yaw = last.expect("a heading");
        assert!(wrap_pi(yaw - 0.3).abs() < 0.01, "{yaw}");
    }
}
