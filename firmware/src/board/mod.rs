//! The STM32H743 board layer: clocks, the microsecond time base, USB, the flash store, the
//! bootloader hand-over and the drivers behind the hardware seams (IMU, motors, receiver) the
//! portable [`crate::app`] runs against.
//!
//! Only compiled for the target (`target_os = "none"`). Everything here is hardware set-up and
//! adapters, driven by the board description in [`crate::targets`] (pins, timers, DMA streams);
//! the behaviour (control step, link server, background work, CRSF and DShot framing, the IMU's
//! register sequence) lives in portable code the simulator and the host tests run. The RTIC
//! application that wires the two together is `src/main.rs`.

pub mod battery;
pub mod bootloader;
pub mod chip;
pub mod config;
pub mod flash;
pub mod gnss;
pub mod i2c;
pub mod identity;
pub mod imu;
pub mod motors;
pub mod radio;
pub mod receiver;
pub mod sdcard;
pub mod serial;
pub mod time;
pub mod timing;
pub mod usb;

pub use config::BOARD;
