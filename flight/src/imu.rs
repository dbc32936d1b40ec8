//! One IMU sample as the mathematics reads it: body rate and specific force in the IMU's own
//! axes, in SI units. The IMU-offset calibration (the `imu-offset` crate) takes these, and the
//! synthetic throws of [`crate::testing::throws`] produce them.

use nalgebra::Vector3;

/// One raw IMU sample.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImuSample {
    /// Body rate (rad/s, IMU frame).
    pub gyro_radps: Vector3<f32>,
    /// Specific force (m/s², IMU frame): what the accelerometer reads (−g·ẑ when level at rest).
    pub acc_mps2: Vector3<f32>,
}
