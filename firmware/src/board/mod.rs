//! The STM32H743 board layer: clocks, the microsecond time base, USB, and the hardware seams
//! (IMU, motors) the portable [`crate::app`] runs against.
//!
//! Only compiled for the target (`target_os = "none"`). Everything here is hardware set-up and
//! adapters; the behaviour (control step, link server, background work) lives in `app`, which the
//! simulator runs unchanged. The RTIC application that wires the two together is `src/main.rs`.

pub mod config;
pub mod identity;
pub mod imu;
pub mod motors;
pub mod time;
pub mod timing;
pub mod usb;

pub use config::{BoardConfig, BOARD};
