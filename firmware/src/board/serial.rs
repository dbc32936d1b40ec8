//! A UART as the board uses it: received by a circular DMA into a ring in AXI SRAM, sent through
//! the UART's 16-byte transmit FIFO, 8N1. No interrupt at all: whoever owns it reads the ring
//! and feeds the FIFO at its own rate (the control tick for the CRSF receiver, the link pass for
//! the telemetry radio), and nothing ever waits for the wire.
//!
//! The FIFO bounds what can leave per call: 16 bytes. Called every millisecond (the link pass)
//! that is 16 kB/s, more than a 115,200-baud radio carries (11.5 kB/s); at 230,400 baud the
//! link is FIFO-bound at 16 kB/s ([`fifo_bytes_per_s`]).

use super::chip::{self, cr, Dma};
use crate::targets::h743::{self, usart};
use crate::targets::{uart_brr, UartWiring};

/// Bytes the transmit FIFO holds (RM0433 §48.5.5: TXFIFO 16 × 9 bits).
pub const TX_FIFO_BYTES: u32 = 16;

/// What a UART fed `calls_per_s` times a second can send through its FIFO, bytes/s.
pub const fn fifo_bytes_per_s(calls_per_s: u32) -> u32 {
    TX_FIFO_BYTES * calls_per_s
}

/// A started UART and its receive ring.
pub struct SerialRing {
    dma: Dma,
    base: u32,
    ring: *const u8,
    ring_len: usize,
    read_index: usize,
}

// SAFETY: the ring is a static the DMA writes and only this owner reads; the UART's registers
// belong to it alone. Moving it to the task that owns it is sound.
unsafe impl Send for SerialRing {}

impl SerialRing {
    /// Configure `wiring`'s UART at `baud` from its kernel clock `kernel_clock_hz` (rcc_pclk2
    /// for USART1/6, the reset default) and start receiving into `ring`.
    ///
    /// # Safety
    /// `ring` must be a static buffer used by nothing else (the DMA writes it from now on), and
    /// the UART, its pins and its DMA stream must belong to the caller alone.
    pub unsafe fn start(
        wiring: UartWiring,
        kernel_clock_hz: u32,
        baud: u32,
        ring: *mut u8,
        ring_len: usize,
    ) -> Self {
        let info = h743::uart(wiring.uart);
        chip::enable_clock(info.enable);
        chip::alternate(wiring.rx, true);
        chip::alternate(wiring.tx, false);
        let dma = Dma::new(wiring.rx_dma);
        dma.route(wiring.rx_dma, info.rx_request);
        let base = info.base;
        // SAFETY: the caller's contract; the ring is only read (volatile) behind the DMA.
        unsafe {
            chip::write(base + usart::CR1, 0);
            chip::write(base + usart::BRR, uart_brr(kernel_clock_hz, baud));
            chip::write(base + usart::CR3, usart::CR3_DMAR | usart::CR3_OVRDIS);
            chip::write(base + usart::ICR, usart::ICR_ALL);
            dma.start(
                base + usart::RDR,
                ring as u32,
                ring_len as u16,
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
        Self { dma, base, ring, ring_len, read_index: 0 }
    }

    /// The bytes the DMA wrote since the previous call (at most `buffer.len()`; the rest next
    /// time). Never blocks. A ring overrun (more than its length between two calls) loses the
    /// overwritten bytes, which the frames' CRCs then reject.
    pub fn read(&mut self, buffer: &mut [u8]) -> usize {
        let len = self.ring_len;
        let write_index = len - (self.dma.remaining() as usize).min(len);
        let mut count = 0;
        while self.read_index != write_index && count < buffer.len() {
            // SAFETY: index < ring_len; a volatile byte read of the DMA's ring.
            buffer[count] = unsafe { core::ptr::read_volatile(self.ring.add(self.read_index)) };
            count += 1;
            self.read_index = (self.read_index + 1) % len;
        }
        count
    }

    /// Put as many of `bytes` into the transmit FIFO as it has room for; returns how many.
    /// Never blocks.
    pub fn write_fifo(&mut self, bytes: &[u8]) -> usize {
        // SAFETY: the owner's UART, started with its FIFOs.
        unsafe { fill_tx_fifo(self.base, bytes) }
    }
}

/// Put as many of `bytes` into the transmit FIFO of the UART at `base` as it has room for;
/// returns how many. Never blocks.
///
/// # Safety
/// `base` is a started UART with its FIFOs enabled, whose transmitter belongs to the caller.
pub unsafe fn fill_tx_fifo(base: u32, bytes: &[u8]) -> usize {
    let mut count = 0;
    // ISR is read-only; TDR takes one byte per write.
    while count < bytes.len() && chip::read(base + usart::ISR) & usart::ISR_TXFNF != 0 {
        chip::write(base + usart::TDR, u32::from(bytes[count]));
        count += 1;
    }
    count
}
