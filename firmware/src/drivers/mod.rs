//! Portable driver logic for the board's peripherals: the pure encoding, decoding and register
//! sequences that the H743 board layer drives through SPI, timers, DMA and UARTs.
//!
//! Everything here is plain `no_std` Rust without the HAL, so it is tested on the host against
//! known frames and mock buses; the board layer (`crate::board`) only moves the bytes.

pub mod compass;
pub mod crsf;
pub mod dshot;
pub mod icm42688;
pub mod ist8310;
pub mod qmc5883l;
pub mod ubx;
