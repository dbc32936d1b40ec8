//! The CRSF receiver on a UART: 420 kbaud 8N1 received by a circular DMA into AXI SRAM, drained
//! by the control task at the start of every step.
//!
//! No interrupt per byte and no interrupt at all: the DMA writes the ring continuously (at most
//! 42 bytes per millisecond, 21 per 500 µs step, the ring holds 256), and [`BoardReceiver`] is
//! the [`Uart`] the application's control tick reads at its start: the bytes since the
//! previous tick go to the portable receiver policy (parser, switch mapping, failsafe), whose
//! command the tick applies before the step runs. A kill switch therefore disarms within one
//! control step of its frame's arrival.

use super::chip::{self, cr, Dma};
use crate::app::hal::Uart;
use crate::targets::h743::{self, usart};
use crate::targets::{uart_brr, ReceiverWiring};
use core::ptr::addr_of_mut;

/// CRSF serial rate, baud.
pub const CRSF_BAUD: u32 = 420_000;
/// Receive ring, bytes (a power of two is not required).
const RING_LEN: usize = 256;

#[link_section = ".axisram.crsf"]
static mut RING: core::mem::MaybeUninit<[u8; RING_LEN]> = core::mem::MaybeUninit::uninit();

/// Telemetry bytes waiting for the UART's transmit FIFO: two of the longest handset frames.
const TX_QUEUE_LEN: usize = 128;

/// The board's receiver UART: the ring the DMA writes and how far it has been read, and the
/// telemetry on its way out.
pub struct BoardReceiver {
    dma: Dma,
    read_index: usize,
    base: u32,
    /// Telemetry for the handset, fed to the 16-byte transmit FIFO at every control tick (at
    /// 420 kbaud the FIFO empties in 0.38 ms, within one 0.5 ms tick: 32 kB/s, against the
    /// 2 kB/s one telemetry frame per RC frame needs at 150 Hz).
    tx: heapless::Deque<u8, TX_QUEUE_LEN>,
}

impl BoardReceiver {
    /// Configure the UART at 420 kbaud from its kernel clock `pclk_hz` (rcc_pclk2 for USART1/6,
    /// the reset-default kernel clock) and start receiving.
    pub fn new(wiring: ReceiverWiring, pclk_hz: u32) -> Self {
        let info = h743::uart(wiring.uart);
        chip::enable_clock(info.enable);
        chip::alternate(wiring.rx, true);
        chip::alternate(wiring.tx, false);
        let dma = Dma::new(wiring.rx_dma);
        dma.route(wiring.rx_dma, info.rx_request);
        let base = info.base;
        // SAFETY: the UART and its stream belong to the receiver. The ring is in AXI SRAM and
        // only read by `read` (volatile, behind the DMA's write position).
        unsafe {
            chip::write(base + usart::CR1, 0);
            chip::write(base + usart::BRR, uart_brr(pclk_hz, CRSF_BAUD));
            chip::write(base + usart::CR3, usart::CR3_DMAR | usart::CR3_OVRDIS);
            chip::write(base + usart::ICR, usart::ICR_ALL);
            dma.start(
                base + usart::RDR,
                addr_of_mut!(RING) as u32,
                RING_LEN as u16,
                cr::PERIPHERAL_TO_MEMORY | cr::MINC | cr::CIRC | cr::PRIORITY_HIGH,
            );
            // The FIFOs are enabled while the USART is disabled (RM0433: FIFOEN is written with
            // UE = 0), then the USART.
            chip::write(base + usart::CR1, usart::CR1_FIFOEN);
            chip::write(
                base + usart::CR1,
                usart::CR1_FIFOEN | usart::CR1_UE | usart::CR1_RE | usart::CR1_TE,
            );
        }
        Self { dma, read_index: 0, base, tx: heapless::Deque::new() }
    }

    /// Move waiting telemetry bytes into the transmit FIFO while it has room. Never blocks.
    fn pump(&mut self) {
        // SAFETY: the receiver owns its UART; ISR is read-only, TDR takes one byte per write.
        unsafe {
            while !self.tx.is_empty() && chip::read(self.base + usart::ISR) & usart::ISR_TXFNF != 0
            {
                if let Some(byte) = self.tx.pop_front() {
                    chip::write(self.base + usart::TDR, u32::from(byte));
                }
            }
        }
    }
}

impl Uart for BoardReceiver {
    /// The bytes the DMA wrote since the previous call (at most `buffer.len()`; the rest next
    /// time). Never blocks.
    fn read(&mut self, buffer: &mut [u8]) -> usize {
        let write_index = RING_LEN - (self.dma.remaining() as usize).min(RING_LEN);
        let ring = addr_of_mut!(RING) as *const u8;
        let mut count = 0;
        while self.read_index != write_index && count < buffer.len() {
            // SAFETY: index < RING_LEN; a volatile byte read of the DMA's ring.
            buffer[count] = unsafe { core::ptr::read_volatile(ring.add(self.read_index)) };
            count += 1;
            self.read_index = (self.read_index + 1) % RING_LEN;
        }
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
