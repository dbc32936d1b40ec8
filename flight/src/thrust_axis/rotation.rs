//! Attitude helpers for the thrust axis: the shortest-arc quaternion from the thrust-frame "up"
//! direction to a measured direction, and ZYX Euler angles for display.
//!
//! Conventions (docs/architecture.md): Hamilton quaternions `[w, x, y, z]`; `q_a_b` rotates
//! b-coordinates into a-coordinates. Body FRD, so the thrust (specific force in hover) points
//! along `(0, 0, −1)` of the thrust frame, and `q_thrust_to_imu` maps thrust-frame coordinates
//! into IMU coordinates (the seed paper's `q_U^T`).

use crate::math::sqrt;

/// The thrust direction in thrust-frame coordinates: "up" in FRD.
pub const THRUST_DIR_THRUST_FRAME: [f32; 3] = [0.0, 0.0, -1.0];

/// ZYX (yaw, then pitch, then roll) Euler angles of a rotation, in radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EulerZyx {
    /// Rotation about x, applied last, in (−π, π].
    pub roll_rad: f32,
    /// Rotation about y, in [−π/2, π/2].
    pub pitch_rad: f32,
    /// Rotation about z, applied first, in (−π, π].
    pub yaw_rad: f32,
}

/// The shortest-arc rotation `q` (unit, `[w, x, y, z]`) with `q ⊗ (0, 0, −1) ⊗ q* = dir / |dir|`.
///
/// Half-way construction `w = 1 + a·b`, `v = a × b`, normalised, with `a = (0, 0, −1)`. For
/// `b_z > 0` the term `1 − b_z` is evaluated as `(b_x² + b_y²) / (1 + b_z)` to avoid
/// cancellation near the antiparallel case; exactly antiparallel (`dir` along `+z`) gives 180°
/// about x, `[0, 1, 0, 0]`. A zero or non-finite `dir` gives the identity.
pub fn shortest_arc_from_down(dir: [f32; 3]) -> [f32; 4] {
    let norm = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    if !(norm > 0.0 && norm.is_finite()) {
        return [1.0, 0.0, 0.0, 0.0];
    }
    let inv = 1.0 / norm;
    shortest_arc_from_down_unit([dir[0] * inv, dir[1] * inv, dir[2] * inv])
}

/// [`shortest_arc_from_down`] for a direction already of unit length.
pub(crate) fn shortest_arc_from_down_unit([bx, by, bz]: [f32; 3]) -> [f32; 4] {
    // a·b = −b_z; a × b = (b_y, −b_x, 0); |q|² = w² + b_x² + b_y² = 2w for unit b.
    let horizontal2 = bx * bx + by * by;
    let w = if bz > 0.0 { horizontal2 / (1.0 + bz) } else { 1.0 - bz };
    let q_norm = sqrt(w * w + horizontal2);
    if !(q_norm > 1e-30) {
        return [0.0, 1.0, 0.0, 0.0];
    }
    let inv = 1.0 / q_norm;
    [w * inv, by * inv, -bx * inv, 0.0]
}

/// Rotate a vector by a unit quaternion: `q ⊗ v ⊗ q*`.
pub fn rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
    let [w, x, y, z] = q;
    // t = 2 (q_vec × v); v' = v + w t + q_vec × t
    let t = [2.0 * (y * v[2] - z * v[1]), 2.0 * (z * v[0] - x * v[2]), 2.0 * (x * v[1] - y * v[0])];
    [
        v[0] + w * t[0] + (y * t[2] - z * t[1]),
        v[1] + w * t[1] + (z * t[0] - x * t[2]),
        v[2] + w * t[2] + (x * t[1] - y * t[0]),
    ]
}

/// ZYX Euler angles of a unit quaternion (aerospace convention: `R = Rz(yaw) Ry(pitch) Rx(roll)`).
pub fn euler_zyx(q: [f32; 4]) -> EulerZyx {
    let [w, x, y, z] = q;
    let sin_pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0);
    EulerZyx {
        roll_rad: libm::atan2f(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
        pitch_rad: libm::asinf(sin_pitch),
        yaw_rad: libm::atan2f(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn angle_between_deg(a: [f32; 3], b: [f32; 3]) -> f32 {
        let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let cross =
            [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
        let sin = libm::sqrtf(cross.iter().map(|c| c * c).sum());
        libm::atan2f(sin, dot).to_degrees()
    }

    #[test]
    fn shortest_arc_maps_down_onto_the_direction() {
        for dir in [
            [0.3, -0.2, -0.9],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, -1.0],
            [1e-4, -2e-4, 1.0],
            [0.0, 0.0, 1.0],
            [-0.5, 0.5, 0.7],
        ] {
            let q = shortest_arc_from_down(dir);
            let image = rotate(q, THRUST_DIR_THRUST_FRAME);
            assert!(angle_between_deg(image, dir) < 1e-3, "{dir:?} -> {image:?}");
            // Shortest arc: no rotation about the thrust-frame z axis.
            assert!(q[3].abs() < 1e-7);
        }
    }

    #[test]
    fn euler_of_a_pure_roll_is_that_roll() {
        let half = 0.3f32;
        let q = [libm::cosf(half), libm::sinf(half), 0.0, 0.0];
        let e = euler_zyx(q);
        assert!(
            (e.roll_rad - 0.6).abs() < 1e-6 && e.pitch_rad.abs() < 1e-6 && e.yaw_rad.abs() < 1e-6
        );
    }
}
