//! The mathematics of the flight controller: estimators, solvers and controllers.
//!
//! Everything here is `no_std`, `f32` and allocation-free so that the same code runs in the 2 kHz
//! control step on the STM32H743 and in the host simulator and offline tools. No I/O, no clocks,
//! no HAL: callers pass samples and time steps in.
#![cfg_attr(not(feature = "std"), no_std)]

pub mod allocation;
pub mod attitude;
pub mod controller;
pub mod eigen3;
pub mod filters;
pub mod imu;
pub mod indi;
pub mod learner;
pub mod math;
pub mod navigation;
pub mod position;
pub mod rng;
#[cfg(any(test, feature = "std"))]
pub mod testing;
pub mod thrust_axis;
