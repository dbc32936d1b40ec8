//! The flight-controller firmware as a library.
//!
//! [`app`] is the portable application: the 2 kHz control step, the link server that speaks the
//! protocol, and the background work. It builds and is tested on the host, and the simulator runs
//! exactly this code. [`drivers`] holds the portable peripheral logic (IMU register sequence,
//! DShot, CRSF) and [`targets`] the board descriptions (pins, timers, DMA streams) as data; the
//! STM32H743 board layer (`board`) that drives the registers only exists for the target.
#![cfg_attr(target_os = "none", no_std)]

pub mod app;
#[cfg(target_os = "none")]
pub mod board;
pub mod drivers;
pub mod targets;
