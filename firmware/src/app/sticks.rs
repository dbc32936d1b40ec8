//! The pilot's sticks as the pilot flies them: shaped (deadband, expo) and turned into what the
//! craft is asked to do, in angle mode or position mode.
//!
//! - **Shaping** ([`StickConfig::shape`]): a centred stick reads a few percent off centre
//!   (gimbal wear, trims), so a deadband around the centre reads zero, and the rest of the
//!   travel is stretched back to ±1; the expo `e` softens the centre,
//!   `y = (1 − e) x + e x³`, as Betaflight's and ArduPilot's expo curves do.
//! - **Angle mode**: roll and pitch tilt the learned hover thrust axis by up to
//!   [`StickConfig::max_tilt_rad`] in the frame of the heading setpoint (pitch forward: nose
//!   down, the craft accelerates forward), the yaw stick turns the heading at up to
//!   [`StickConfig::max_yaw_rate_rad_s`], and the throttle asks for a climb rate of up to
//!   [`StickConfig::max_climb_mps`] around hover (centred: hold the height). The pilot never
//!   needs the hover thrust of an airframe nobody measured: the controller finds it.
//! - **Position mode** (with a fresh pose): the sticks move the position setpoint at up to
//!   [`StickConfig::max_speed_mps`] horizontally (in the heading's frame) and the climb rate
//!   vertically; centred sticks hold where the setpoint is. The setpoint stays within
//!   [`SETPOINT_LEASH_M`] of the craft, so a craft held back by a wind does not wind up a setpoint
//!   far ahead of it.
//!
//! What it assumes of the radio: sticks normalised to −1..1 with the centre at 0 (1000–2000 µs
//! around 1500 µs, `crate::drivers::crsf::StickInput`), fresh at 50–1,000 frames per second; a
//! lost link gives no sticks at all (the craft then holds, and the radio's failsafe lands it).

use crate::drivers::crsf::StickInput;
use nalgebra::Vector3;

/// Default deadband around a centred stick, fraction of its half travel (`stick_deadband`): 5 %,
/// about 25 µs, above a worn gimbal's drift and a trim's few steps.
pub const DEFAULT_DEADBAND: f32 = 0.05;
/// Default expo (`stick_expo`): 0 linear, 1 cubic.
pub const DEFAULT_EXPO: f32 = 0.3;
/// Default largest tilt of the thrust axis in angle mode, rad (30°, `stick_max_tilt_deg`): the
/// position controller's own tilt limit (`flight::position::MAX_TILT_RAD`).
pub const DEFAULT_MAX_TILT_RAD: f32 = 30.0 * core::f32::consts::PI / 180.0;
/// Default largest yaw rate, rad/s (120 °/s, `stick_yaw_rate_dps`).
pub const DEFAULT_MAX_YAW_RATE_RAD_S: f32 = 120.0 * core::f32::consts::PI / 180.0;
/// Default largest climb or descent rate, m/s (`stick_climb_mps`).
pub const DEFAULT_MAX_CLIMB_MPS: f32 = 1.5;
/// Default largest speed of the setpoint in position mode, m/s (`stick_speed_mps`): below the
/// position loop's 2.5 m/s limit, so the craft follows its setpoint.
pub const DEFAULT_MAX_SPEED_MPS: f32 = 2.0;
/// Farthest the position setpoint may run ahead of the craft, horizontally, m (ours): 1 m is
/// 0.5 s at the default speed.
pub const SETPOINT_LEASH_M: f32 = 1.0;

/// How the sticks are flown (the `stick_*` parameters).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StickConfig {
    /// Deadband around the centre, fraction of half travel (0–0.2).
    pub deadband: f32,
    /// Expo, 0 (linear) to 1 (cubic).
    pub expo: f32,
    /// Largest tilt in angle mode, rad.
    pub max_tilt_rad: f32,
    /// Largest yaw rate, rad/s.
    pub max_yaw_rate_rad_s: f32,
    /// Largest climb or descent rate, m/s.
    pub max_climb_mps: f32,
    /// Largest speed of the position setpoint, m/s.
    pub max_speed_mps: f32,
}

impl Default for StickConfig {
    fn default() -> Self {
        Self {
            deadband: DEFAULT_DEADBAND,
            expo: DEFAULT_EXPO,
            max_tilt_rad: DEFAULT_MAX_TILT_RAD,
            max_yaw_rate_rad_s: DEFAULT_MAX_YAW_RATE_RAD_S,
            max_climb_mps: DEFAULT_MAX_CLIMB_MPS,
            max_speed_mps: DEFAULT_MAX_SPEED_MPS,
        }
    }
}

impl StickConfig {
    /// One stick's reading shaped: zero within the deadband, the rest stretched back to ±1 and
    /// given the expo; non-finite readings are zero.
    pub fn shape(&self, x: f32) -> f32 {
        if !x.is_finite() {
            return 0.0;
        }
        let magnitude = x.abs().min(1.0);
        let deadband = self.deadband.clamp(0.0, 0.5);
        if magnitude <= deadband {
            return 0.0;
        }
        let stretched = (magnitude - deadband) / (1.0 - deadband);
        let expo = self.expo.clamp(0.0, 1.0);
        let curved = (1.0 - expo) * stretched + expo * stretched * stretched * stretched;
        curved.copysign(x)
    }

    /// What the stick frame `sticks` asks for, shaped.
    pub fn demand(&self, sticks: &StickInput) -> StickDemand {
        let (roll, pitch) = (self.shape(sticks.roll), self.shape(sticks.pitch));
        let throttle = self.shape(sticks.throttle);
        StickDemand {
            forward_rad: pitch * self.max_tilt_rad,
            right_rad: roll * self.max_tilt_rad,
            vertical_speed_mps: -throttle * self.max_climb_mps,
            yaw_rate_rad_s: self.shape(sticks.yaw) * self.max_yaw_rate_rad_s,
            forward_mps: pitch * self.max_speed_mps,
            right_mps: roll * self.max_speed_mps,
            position_mode: sticks.position_mode,
        }
    }
}

/// What one stick frame asks for, worked out once when the frame arrives (the radio's 50–1,000
/// frames a second, and only when a stick moved) rather than at each of the control step's
/// 2,000: the step reads it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StickDemand {
    /// Angle mode: the thrust axis's tilt forward (nose down) and right, rad.
    pub forward_rad: f32,
    pub right_rad: f32,
    /// The vertical speed, NED, m/s (negative: climb); both modes.
    pub vertical_speed_mps: f32,
    /// The heading's rate, rad/s (positive: to the right); both modes.
    pub yaw_rate_rad_s: f32,
    /// Position mode: the setpoint's speed forward and right in the heading's frame, m/s.
    pub forward_mps: f32,
    pub right_mps: f32,
    /// The mode switch asks for position mode.
    pub position_mode: bool,
}

impl StickDemand {
    /// Position mode's setpoint velocity, world NED, m/s, for a heading `yaw_rad`: the sticks'
    /// forward and right turned into the world, the throttle's climb.
    pub fn setpoint_velocity(&self, yaw_rad: f32) -> Vector3<f32> {
        let (sin, cos) = flight::math::sin_cos(yaw_rad);
        Vector3::new(
            cos * self.forward_mps - sin * self.right_mps,
            sin * self.forward_mps + cos * self.right_mps,
            self.vertical_speed_mps,
        )
    }
}

/// The position setpoint moved by `velocity_ned_mps` over `dt_s`, kept within
/// [`SETPOINT_LEASH_M`] of `position_ned_m` horizontally.
pub fn move_setpoint(
    setpoint_ned_m: &Vector3<f32>,
    velocity_ned_mps: &Vector3<f32>,
    position_ned_m: &Vector3<f32>,
    dt_s: f32,
) -> Vector3<f32> {
    let moved = setpoint_ned_m + velocity_ned_mps * dt_s;
    let ahead = moved - position_ned_m;
    // Within the leash (every step but those a held-back craft spends at its end): no root.
    let ahead2 = ahead.x * ahead.x + ahead.y * ahead.y;
    if ahead2 <= SETPOINT_LEASH_M * SETPOINT_LEASH_M {
        return moved;
    }
    let scale = SETPOINT_LEASH_M / libm::sqrtf(ahead2);
    Vector3::new(position_ned_m.x + ahead.x * scale, position_ned_m.y + ahead.y * scale, moved.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_centred_stick_reads_zero_and_full_travel_reads_one_whatever_the_expo() {
        for expo in [0.0, 0.3, 1.0] {
            let config = StickConfig { expo, ..StickConfig::default() };
            for x in [0.0, 0.03, -0.049, f32::NAN] {
                assert_eq!(config.shape(x), 0.0, "{x} with expo {expo}");
            }
            assert!((config.shape(1.0) - 1.0).abs() < 1e-6);
            assert!((config.shape(-1.0) + 1.0).abs() < 1e-6);
            assert!((config.shape(1.3) - 1.0).abs() < 1e-6, "beyond the travel: full");
            // Monotonic and odd.
            let mut previous = 0.0;
            for i in 6..=100 {
                let x = i as f32 / 100.0;
                let y = config.shape(x);
                assert!(y > previous, "{x}: {y} after {previous}");
                assert_eq!(config.shape(-x), -y);
                previous = y;
            }
        }
        // The expo softens the middle: half travel gives less than half.
        let linear = StickConfig { expo: 0.0, ..StickConfig::default() };
        let soft = StickConfig { expo: 0.5, ..StickConfig::default() };
        assert!(soft.shape(0.5) < linear.shape(0.5));
    }

    #[test]
    fn angle_mode_tilts_forward_for_pitch_and_climbs_for_throttle() {
        let config = StickConfig { deadband: 0.0, expo: 0.0, ..StickConfig::default() };
        let demand = config.demand(&StickInput {
            roll: -0.5,
            pitch: 1.0,
            throttle: 0.5,
            yaw: 0.25,
            position_mode: false,
        });
        assert!((demand.forward_rad - DEFAULT_MAX_TILT_RAD).abs() < 1e-6);
        assert!((demand.right_rad + 0.5 * DEFAULT_MAX_TILT_RAD).abs() < 1e-6);
        let vertical = demand.vertical_speed_mps;
        assert!((vertical + 0.5 * DEFAULT_MAX_CLIMB_MPS).abs() < 1e-6, "up is negative in NED");
        assert!((demand.yaw_rate_rad_s - 0.25 * DEFAULT_MAX_YAW_RATE_RAD_S).abs() < 1e-6);
    }

    #[test]
    fn position_mode_moves_the_setpoint_in_the_headings_frame_on_a_leash() {
        let config = StickConfig { deadband: 0.0, expo: 0.0, ..StickConfig::default() };
        let forward = config.demand(&StickInput {
            roll: 0.0,
            pitch: 1.0,
            throttle: 0.0,
            yaw: 0.0,
            position_mode: true,
        });
        // Heading east: forward is +y.
        let v = forward.setpoint_velocity(core::f32::consts::FRAC_PI_2);
        assert!((v - Vector3::new(0.0, DEFAULT_MAX_SPEED_MPS, 0.0)).norm() < 1e-5, "{v:?}");
        // A craft that stays put: the setpoint runs ahead only up to the leash.
        let here = Vector3::new(1.0, 2.0, -3.0);
        let mut setpoint = here;
        for _ in 0..4000 {
            setpoint = move_setpoint(&setpoint, &v, &here, 0.0005);
        }
        assert!(((setpoint - here).xy().norm() - SETPOINT_LEASH_M).abs() < 1e-4, "{setpoint:?}");
        // Vertically the setpoint moves with the throttle, unleashed.
        let climb = Vector3::new(0.0, 0.0, -1.0);
        let moved = move_setpoint(&here, &climb, &here, 1.0);
        assert!((moved.z - (here.z - 1.0)).abs() < 1e-6);
    }
}
