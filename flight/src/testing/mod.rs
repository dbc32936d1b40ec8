//! Test support shared by `flight`'s tests and host tools' tests: synthetic sensor data with a
//! known truth. Compiled for tests and with the `std` feature only; never part of the firmware.
//!
//! Nothing here uses the estimators under test: the physics is written independently (rigid
//! body, Euler's equations, cross products), so agreement is evidence, not tautology.

extern crate std;

pub mod models;
pub mod throws;

/// A minute of flight for the motors' magnetic interference, at `t_s`: motors off for the first
/// second, then a collective thrust swinging 0.15–0.85 with ±0.1 per motor (attitude control's
/// differential thrust, drawn from `rng`), and the attitude turning at 0.2 rad/s while tilting
/// up to 0.3 rad. The motors' normalised thrusts and `q_world_imu`.
pub fn interference_flight(
    t_s: f64,
    motors: usize,
    rng: &mut crate::rng::Rng,
) -> (std::vec::Vec<f64>, nalgebra::UnitQuaternion<f64>) {
    let collective = if t_s < 1.0 { 0.0 } else { 0.5 + 0.35 * (0.3 * t_s).sin() };
    let thrust = (0..motors)
        .map(|_| if t_s < 1.0 { 0.0 } else { (collective + rng.range(-0.1, 0.1)).clamp(0.0, 1.0) })
        .collect();
    let q = nalgebra::UnitQuaternion::from_euler_angles(
        0.3 * (0.9 * t_s).sin(),
        0.3 * (0.5 * t_s).cos(),
        0.2 * t_s,
    );
    (thrust, q)
}
