//! The simulator: physics, sensors, motors, airframes, and the SITL server.

pub mod airframe;
pub mod board;
pub mod dshot;
pub mod dynamics;
pub mod hand;
pub mod imu;
pub mod physics;
pub mod rng;
