//! The motion-capture line format: one pose per UDP datagram, as text, so that any motion-capture
//! bridge (a VRPN or NatNet client, a ROS node, a ten-line script) can feed
//! `configurator-cli pose-relay`, which forwards each pose to the board over its link (a radio in
//! the field). The SITL speaks it too (`sitl --mocap-udp HOST:PORT`), as a motion-capture system
//! would.
//!
//! ```text
//! t_s n_m e_m d_m qw qx qy qz
//! ```
//! Eight numbers separated by white space, one line, a trailing newline allowed:
//! - `t_s`: the capture time on the sender's clock, s: informative only (the board places a
//!   pose in time with its `pose_latency_s` parameter);
//! - `n_m e_m d_m`: the centre of gravity's position, m, world north-east-down;
//! - `qw qx qy qz`: the body's attitude, Hamilton, rotating body (front-right-down) coordinates
//!   into world NED; only its heading (the yaw of the body's x axis about down) is forwarded.
//!
//! A line that is not eight finite numbers, or whose quaternion is far from unit length, is
//! refused with a [`PoseLineError`] saying why; nothing is forwarded for it.
//!
//! **ENU senders** ([`PoseFrame::Enu`]): ROS (REP 103) and most motion-capture bridges built on
//! it give `x_m y_m z_m` in world east-north-up and the attitude of a front-left-up body
//! rotating into it. [`PoseLine::parse_in`] takes such a line as the same eight numbers and
//! turns it into NED and front-right-down: north = y, east = x, down = −z, and
//! `q_ned_frd = q_ned_enu ⊗ q_enu_flu ⊗ q_flu_frd`. The first and the last factor are half
//! turns: about the axis (x + y)/√2, and about x.

use protocol::ExternalPose;

/// How far from 1 a quaternion's norm may be, so that a sender's rounding passes and a swapped
/// or missing component does not.
pub const QUATERNION_NORM_TOLERANCE: f64 = 0.01;

/// Why a line is not a pose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseLineError {
    #[error("a pose line is eight numbers `t_s n_m e_m d_m qw qx qy qz`, this one has {0}")]
    FieldCount(usize),
    #[error("field {index} (`{text}`) is not a finite number")]
    NotANumber { index: usize, text: String },
    #[error("the quaternion's norm is {norm:.3}, not 1 (order qw qx qy qz?)")]
    NotUnit { norm: f64 },
}

/// The world and body axes a sender uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum PoseFrame {
    /// World north-east-down, body front-right-down (this project's, PX4's, ArduPilot's).
    #[default]
    Ned,
    /// World east-north-up, body front-left-up (ROS REP 103, most ROS motion-capture bridges).
    Enu,
}

/// One pose as the line carries it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseLine {
    /// Capture time on the sender's clock, s.
    pub t_s: f64,
    /// Position, m, world NED.
    pub position_ned_m: [f64; 3],
    /// Attitude, body FRD → world NED, `[w, x, y, z]`.
    pub q_world_body: [f64; 4],
}

impl PoseLine {
    /// A pose whose attitude is a rotation by `heading_rad` about down.
    pub fn with_heading(t_s: f64, position_ned_m: [f64; 3], heading_rad: f64) -> Self {
        let half = 0.5 * heading_rad;
        Self { t_s, position_ned_m, q_world_body: [half.cos(), 0.0, 0.0, half.sin()] }
    }

    /// The line, newline included.
    pub fn format(&self) -> String {
        let [n, e, d] = self.position_ned_m;
        let [w, x, y, z] = self.q_world_body;
        format!("{:.6} {n:.6} {e:.6} {d:.6} {w:.9} {x:.9} {y:.9} {z:.9}\n", self.t_s)
    }

    /// Parse one line (see the module documentation).
    pub fn parse(line: &str) -> Result<Self, PoseLineError> {
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.len() != 8 {
            return Err(PoseLineError::FieldCount(fields.len()));
        }
        let mut values = [0.0f64; 8];
        for (index, (value, text)) in values.iter_mut().zip(&fields).enumerate() {
            *value = text
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| PoseLineError::NotANumber { index, text: text.to_string() })?;
        }
        let q = [values[4], values[5], values[6], values[7]];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
            return Err(PoseLineError::NotUnit { norm });
        }
        Ok(Self {
            t_s: values[0],
            position_ned_m: [values[1], values[2], values[3]],
            q_world_body: q.map(|c| c / norm),
        })
    }

    /// Parse one line written in `frame`, as a pose in NED and front-right-down.
    pub fn parse_in(line: &str, frame: PoseFrame) -> Result<Self, PoseLineError> {
        let pose = Self::parse(line)?;
        Ok(match frame {
            PoseFrame::Ned => pose,
            PoseFrame::Enu => {
                let [x, y, z] = pose.position_ned_m;
                let h = core::f64::consts::FRAC_1_SQRT_2;
                let ned_from_enu = [0.0, h, h, 0.0];
                let flu_from_frd = [0.0, 1.0, 0.0, 0.0];
                Self {
                    t_s: pose.t_s,
                    position_ned_m: [y, x, -z],
                    q_world_body: hamilton(hamilton(ned_from_enu, pose.q_world_body), flu_from_frd),
                }
            }
        })
    }

    /// The heading: the yaw of the body's x axis about world down, rad, in (−π, π].
    pub fn heading_rad(&self) -> f64 {
        let [w, x, y, z] = self.q_world_body;
        (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
    }

    /// What the board takes: position and heading.
    pub fn external_pose(&self) -> ExternalPose {
        let [n, e, d] = self.position_ned_m;
        ExternalPose {
            position_ned_m: [n as f32, e as f32, d as f32],
            heading_rad: self.heading_rad() as f32,
        }
    }
}

/// The Hamilton product `a ⊗ b` of quaternions `[w, x, y, z]`.
fn hamilton(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    let [aw, ax, ay, az] = a;
    let [bw, bx, by, bz] = b;
    [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An ENU line (ROS) at `x y z` whose front-left-up body is yawed by `yaw_enu_rad` about up
    /// (0: facing east) and then pitched nose-up by `pitch_up_rad`.
    fn enu_line(position: [f64; 3], yaw_enu_rad: f64, pitch_up_rad: f64) -> String {
        let (y, p) = (0.5 * yaw_enu_rad, 0.5 * pitch_up_rad);
        // Nose up in FLU is a negative rotation about the body's y (left) axis.
        let q = hamilton([y.cos(), 0.0, 0.0, y.sin()], [p.cos(), 0.0, -p.sin(), 0.0]);
        let [x, yy, z] = position;
        format!("0.5 {x} {yy} {z} {} {} {} {}", q[0], q[1], q[2], q[3])
    }

    #[test]
    fn an_enu_pose_becomes_the_same_place_and_heading_in_ned() {
        // 1 m east, 2 m north, 3 m up, facing east: north 2, east 1, down −3, heading 90°.
        let pose = PoseLine::parse_in(&enu_line([1.0, 2.0, 3.0], 0.0, 0.0), PoseFrame::Enu);
        let pose = pose.unwrap();
        assert_eq!(pose.position_ned_m, [2.0, 1.0, -3.0]);
        assert!((pose.heading_rad() - 90f64.to_radians()).abs() < 1e-9, "{pose:?}");
        // Facing north (ENU yaw 90°) is heading 0; facing west (180°) is heading −90°; and a
        // nose-up pitch changes no heading.
        for (yaw_deg, heading_deg) in [(90.0, 0.0), (180.0, -90.0), (-45.0, 135.0)] {
            let line = enu_line([0.0; 3], f64::to_radians(yaw_deg), 20f64.to_radians());
            let pose = PoseLine::parse_in(&line, PoseFrame::Enu).unwrap();
            let heading = pose.heading_rad().to_degrees();
            assert!((heading - heading_deg).abs() < 1e-6, "ENU yaw {yaw_deg}°: {heading}°");
            // The nose-up pitch stays nose-up: the body's x axis points up, −down, in NED.
            let [w, x, y, z] = pose.q_world_body;
            let forward_down = 2.0 * (x * z - w * y);
            assert!((forward_down + 20f64.to_radians().sin()).abs() < 1e-9, "{pose:?}");
        }
        // NED lines pass unchanged.
        let ned = PoseLine::with_heading(1.0, [1.0, 2.0, 3.0], 0.3).format();
        assert_eq!(PoseLine::parse_in(&ned, PoseFrame::Ned), PoseLine::parse(&ned));
    }

    #[test]
    fn a_formatted_pose_parses_back_to_its_position_and_heading() {
        let pose = PoseLine::with_heading(12.5, [1.25, -3.5, -2.0], 2.5);
        let parsed = PoseLine::parse(&pose.format()).unwrap();
        assert!((parsed.heading_rad() - 2.5).abs() < 1e-6);
        assert_eq!(parsed.position_ned_m, [1.25, -3.5, -2.0]);
        let external = parsed.external_pose();
        assert_eq!(external.position_ned_m, [1.25, -3.5, -2.0]);
        assert!((external.heading_rad - 2.5).abs() < 1e-6);
    }

    #[test]
    fn the_heading_ignores_roll_and_pitch() {
        // 30° of roll after a heading of 1 rad: q = q_yaw * q_roll.
        let (h, r) = (0.5_f64, 0.5 * 30f64.to_radians());
        let q = [h.cos() * r.cos(), h.cos() * r.sin(), h.sin() * r.sin(), h.sin() * r.cos()];
        let line = format!("0 0 0 0 {} {} {} {}", q[0], q[1], q[2], q[3]);
        assert!((PoseLine::parse(&line).unwrap().heading_rad() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn malformed_lines_are_refused_saying_why() {
        assert_eq!(PoseLine::parse("1 2 3"), Err(PoseLineError::FieldCount(3)));
        assert!(matches!(
            PoseLine::parse("0 1 2 nan 1 0 0 0"),
            Err(PoseLineError::NotANumber { index: 3, .. })
        ));
        assert!(matches!(PoseLine::parse("0 1 2 3 1 0 0 1"), Err(PoseLineError::NotUnit { .. })));
    }
}
