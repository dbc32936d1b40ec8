//! Test support shared by `flight`'s tests and host tools' tests: synthetic sensor data with a
//! known truth. Compiled for tests and with the `std` feature only; never part of the firmware.
//!
//! Nothing here uses the estimators under test: the physics is written independently (rigid
//! body, Euler's equations, cross products), so agreement is evidence, not tautology.

pub mod models;
pub mod throws;
