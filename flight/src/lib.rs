//! The mathematics of the flight controller: estimators, solvers and controllers.
//!
//! Everything here is `no_std`, `f32` and allocation-free so that the same code runs in the 2 kHz
//! control step on the STM32H743 and in the host simulator and offline tools. No I/O, no clocks,
//! no HAL: callers pass samples and time steps in.
//!
//! **Where configuration code is compiled.** The firmware compiles this crate at opt-level 2 for
//! the control step and the learner, and the rest of the image for size ("z"; root `Cargo.toml`).
//! A function marked `#[inline]` is compiled in each crate that calls it, at that crate's
//! opt-level, and here only where this crate calls it itself. The code that runs when a model is
//! taken or refined, never in the 2 kHz step (the controller's and INDI's constructors, the
//! in-flight refinement, the attitude filter's configuration), is marked so (comment
//! "compiled by its caller"): on the board it is compiled for size, 2.1 KB less flash
//! (docs/benchmarks.md, "Firmware size"). Keep the mark off code the step or the learner's
//! sample runs: there it would be compiled at the caller's level too.
#![cfg_attr(not(feature = "std"), no_std)]

pub mod allocation;
pub mod attitude;
pub mod controller;
pub mod eigen3;
pub mod filters;
pub mod imu;
pub mod indi;
pub mod learner;
pub mod magnetometer;
pub mod math;
pub mod navigation;
pub mod position;
pub mod rng;
pub mod serde_array;
pub mod slot;
#[cfg(any(test, feature = "std"))]
pub mod testing;
pub mod thrust_axis;
