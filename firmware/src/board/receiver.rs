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

/// The board's receiver UART: the ring the DMA writes and how far it has been read.
pub struct BoardReceiver {
    dma: Dma,
    read_index: usize,
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
            chip::write(base + usart::CR1, usart::CR1_UE | usart::CR1_RE | usart::CR1_TE);
        }
        Self { dma, read_index: 0 }
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
        count
    }
}
