//! The board's motor seam.
//!
//! Bidirectional DShot (timer + DMA outputs and RPM telemetry) is a later issue. Until then the
//! board drives no motors: [`BoardMotors`] is the application's own [`NoMotors`], which reports
//! zero motors and discards commands, so nothing can spin a propeller by accident.

use crate::app::hal::NoMotors;

/// The board's motor outputs: none until the DShot driver exists.
pub type BoardMotors = NoMotors;
