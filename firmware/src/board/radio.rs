//! The telemetry radio on a UART (a SiK/RFD900-class modem, an ESP32 Wi-Fi bridge, ELRS in
//! transparent serial mode): the link protocol, exactly as on USB, through the application's
//! [`Port`]. The link pass reads the ring and feeds the transmit FIFO every millisecond.
//!
//! The radio is an untrusted link (`protocol::signing`): whoever is on its channel can read and
//! disarm, and only a request signed with the key paired over USB configures, arms, spins or
//! steers. Its byte rate is the smaller of the baud's (ten bits a byte) and what the FIFO can
//! take at the link pass's rate, so the telemetry the link grants fits ([`byte_rate`]).

use super::serial::{fifo_bytes_per_s, SerialRing};
use crate::app::hal::{Port, PortClosed};
use crate::app::system::LINK_PASS_PERIOD_US;
use crate::targets::UartWiring;
use core::ptr::addr_of_mut;

/// Receive ring, bytes: 44 ms at 115,200 baud between two link passes of 1 ms is far more than
/// needed; a save's flash erase (up to 2 s at the link's priority) overruns it, and the frames
/// it cuts fail their CRC and are asked again.
const RING_LEN: usize = 512;

#[link_section = ".axisram.radio"]
static mut RING: core::mem::MaybeUninit<[u8; RING_LEN]> = core::mem::MaybeUninit::uninit();

/// The bytes a second the radio link carries at `baud`: the baud's (8N1: ten bits a byte), or
/// less when the transmit FIFO, fed once per link pass, cannot take them.
pub const fn byte_rate(baud: u32) -> u32 {
    let wire = baud / 10;
    let fifo = fifo_bytes_per_s(1_000_000 / LINK_PASS_PERIOD_US as u32);
    if wire < fifo {
        wire
    } else {
        fifo
    }
}

/// The telemetry radio's UART as the link's port.
pub struct BoardRadio {
    serial: SerialRing,
}

impl BoardRadio {
    /// Start the radio's UART at `baud` from its kernel clock `pclk_hz`.
    pub fn new(wiring: UartWiring, pclk_hz: u32, baud: u32) -> Self {
        // SAFETY: the ring is the radio's alone; so are its UART, pins and DMA stream.
        let serial = unsafe {
            SerialRing::start(wiring, pclk_hz, baud, addr_of_mut!(RING) as *mut u8, RING_LEN)
        };
        Self { serial }
    }
}

impl Port for BoardRadio {
    fn read(&mut self, buffer: &mut [u8]) -> Result<usize, PortClosed> {
        Ok(self.serial.read(buffer))
    }

    /// What the transmit FIFO takes now (at most 16 bytes); the rest waits in the link's
    /// buffer for the next pass.
    fn write(&mut self, bytes: &[u8]) -> Result<usize, PortClosed> {
        Ok(self.serial.write_fifo(bytes))
    }
}
