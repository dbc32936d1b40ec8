//! The board's IMU seam.
//!
//! The ICM-42688-P SPI driver is a later issue. Until then [`BoardImu`] is honest: it has no
//! driver and never returns a sample, so the application counts every tick as a missing sample
//! (visible in the status over USB) instead of flying on invented data. The real driver replaces
//! this type (same name, same trait) and its SPI/DMA buffers go in AXI SRAM (see `memory.x`).

use crate::app::hal::{Imu, ImuSample};

/// The board IMU: no driver yet, so no samples.
#[derive(Clone, Copy, Debug, Default)]
pub struct BoardImu;

impl Imu for BoardImu {
    /// Always `None`: there is no IMU driver yet. Never blocks.
    fn read(&mut self) -> Option<ImuSample> {
        None
    }
}
