//! The CRSF receiver on a UART: 420 kbaud 8N1 received by a circular DMA into AXI SRAM, drained
//! by the control task at the start of every step.
//!
//! No interrupt per byte and no interrupt at all: the DMA writes the ring continuously (at most
//! 42 bytes per millisecond, 21 per 500 µs step, the ring holds 256), and [`BoardReceiver`] is
//! the [`Uart`] the application's control tick reads at its start: the bytes since the
//! previous tick go to the portable receiver policy (parser, switch mapping, failsafe), whose
//! command the tick applies before the step runs. A kill switch therefore disarms within one
//! control step of its frame's arrival.

use super::serial::SerialRing;
use crate::app::hal::Uart;
use crate::targets::UartWiring;
use core::ptr::addr_of_mut;

/// CRSF serial rate, baud.
pub const CRSF_BAUD: u32 = 420_000;
/// Receive ring, bytes (a power of two is not required).
const RING_LEN: usize = 256;

#[link_section = ".axisram.crsf"]
static mut RING: core::mem::MaybeUninit<[u8; RING_LEN]> = core::mem::MaybeUninit::uninit();

/// Telemetry bytes waiting for the UART's transmit FIFO: two of the longest handset frames.
const TX_QUEUE_LEN: usize = 128;

/// The board's receiver UART: its ring, and the telemetry on its way out.
pub struct BoardReceiver {
    serial: SerialRing,
    /// Telemetry for the handset, fed to the 16-byte transmit FIFO at every control tick (at
    /// 420 kbaud the FIFO empties in 0.38 ms, within one 0.5 ms tick: 32 kB/s, against the
    /// 2 kB/s one telemetry frame per RC frame needs at 150 Hz).
    tx: heapless::Deque<u8, TX_QUEUE_LEN>,
}

impl BoardReceiver {
    /// Configure the UART at 420 kbaud from its kernel clock `pclk_hz` (rcc_pclk2 for USART1/6,
    /// the reset-default kernel clock) and start receiving.
    pub fn new(wiring: UartWiring, pclk_hz: u32) -> Self {
        // SAFETY: the ring is the receiver's alone; so are its UART, pins and DMA stream.
        let serial = unsafe {
            SerialRing::start(wiring, pclk_hz, CRSF_BAUD, addr_of_mut!(RING) as *mut u8, RING_LEN)
        };
        Self { serial, tx: heapless::Deque::new() }
    }

    /// Move waiting telemetry bytes into the transmit FIFO while it has room. Never blocks.
    fn pump(&mut self) {
        while let Some(&byte) = self.tx.front() {
            if self.serial.write_fifo(&[byte]) == 0 {
                return;
            }
            self.tx.pop_front();
        }
    }
}

impl Uart for BoardReceiver {
    /// The bytes the DMA wrote since the previous call (at most `buffer.len()`; the rest next
    /// time). Never blocks.
    fn read(&mut self, buffer: &mut [u8]) -> usize {
        let count = self.serial.read(buffer);
        // The control tick reads every step: the telemetry still waiting moves on now.
        self.pump();
        count
    }

    /// Queue one telemetry frame for the handset, whole or not at all (a cut frame would only
    /// cost the handset a CRC error), and start sending it. Never blocks.
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.pump();
        if TX_QUEUE_LEN - self.tx.len() < bytes.len() {
            return 0;
        }
        for &byte in bytes {
            let _ = self.tx.push_back(byte);
        }
        self.pump();
        bytes.len()
    }
}
