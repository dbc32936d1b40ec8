//! The simulator: physics, sensors, motors, airframes, and the SITL server.

pub mod airframe;
pub mod battery;
pub mod board;
pub mod bridge;
pub mod calibration;
pub mod compass_calibration;
pub mod compass_chip;
pub mod compass_feed;
pub mod dshot;
pub mod dynamics;
pub mod faults;
pub mod flash;
pub mod gnss;
pub mod hand;
pub mod identification;
pub mod imu;
pub mod log;
pub mod log_dir;
pub mod magnetometer;
pub mod monte_carlo;
pub mod physics;
pub mod pose_line;
pub mod radio;
pub mod recovery;
/// The workspace's deterministic random-number generator (sensor noise, random airframes).
pub use flight::rng;
pub mod scenario;
pub mod serve;
pub mod sitl;
pub mod stats;
pub mod world;
