//! The GNSS receiver's UART: received by interrupt into a lock-free byte queue, sent through the
//! UART's 16-byte transmit FIFO, 8N1 at the rate the driver asks for (`app::gnss`: it searches
//! 9,600–921,600 baud for the receiver, then moves both to `gnss_baud`).
//!
//! Why an interrupt and not a DMA ring like the other UARTs (`super::serial`): every one of the
//! H743's 16 DMA streams already has a job on this board (IMU, motor bursts, the ESCs' answers,
//! the receiver, the telemetry radio, the flash). The receive FIFO interrupt
//! ([`GnssRx::on_interrupt`]) moves each byte into [`GNSS_QUEUE_LEN`] bytes of queue; the link
//! pass reads it every millisecond ([`BoardGnss`], the application's `GnssPort`). At 115,200
//! baud that is 11,520 interrupts a second of a few dozen cycles each (well under 1 % of the
//! core); the FIFO gives the interrupt 16 bytes of slack (174 µs at 921,600 baud, the fastest
//! rate searched), more than the control step at the same priority takes.

use super::chip;
use crate::app::hal::{GnssPort, Uart};
use crate::targets::h743::{self, usart};
use crate::targets::{uart_brr, GnssWiring};
use heapless::spsc::{Consumer, Producer, Queue};

/// Bytes between the interrupt and the link pass: 89 ms at 115,200 baud, far more than the 1 ms
/// between passes; a configuration save's flash erase (up to 2 s at the link's priority, only
/// while disarmed) overruns it, and the frames it cuts fail their checksum.
pub const GNSS_QUEUE_LEN: usize = 1024;

/// The queue's storage (DTCM; the interrupt and the link task each own one end).
pub type GnssQueue = Queue<u8, GNSS_QUEUE_LEN>;

/// The interrupt's end: empties the receive FIFO into the queue.
pub struct GnssRx {
    base: u32,
    bytes: Producer<'static, u8>,
    /// Bytes lost because the queue was full.
    dropped: u32,
}

/// The link task's end: the application's GNSS port.
pub struct BoardGnss {
    base: u32,
    kernel_clock_hz: u32,
    baud: u32,
    bytes: Consumer<'static, u8>,
}

/// Start `wiring`'s UART at `baud` from its kernel clock `kernel_clock_hz` (rcc_pclk1 for
/// USART2, the reset default), receiving into `queue` by interrupt (the caller binds the
/// UART's interrupt to [`GnssRx::on_interrupt`]).
pub fn start(
    wiring: GnssWiring,
    kernel_clock_hz: u32,
    baud: u32,
    queue: &'static mut GnssQueue,
) -> (GnssRx, BoardGnss) {
    let info = h743::uart(wiring.uart);
    chip::enable_clock(info.enable);
    // A receiver's TX idles high; the pull-up keeps an unconnected pad from reading noise.
    chip::alternate(wiring.rx, true);
    chip::alternate(wiring.tx, false);
    let base = info.base;
    // SAFETY: the UART and its pins belong to this driver alone (the board description gives
    // each one role).
    unsafe {
        chip::write(base + usart::CR1, 0);
        chip::write(base + usart::BRR, uart_brr(kernel_clock_hz, baud));
        chip::write(base + usart::CR3, usart::CR3_OVRDIS);
        chip::write(base + usart::ICR, usart::ICR_ALL);
        enable(base);
    }
    let (bytes_in, bytes_out) = queue.split();
    (
        GnssRx { base, bytes: bytes_in, dropped: 0 },
        BoardGnss { base, kernel_clock_hz, baud, bytes: bytes_out },
    )
}

/// FIFOs on (written with UE = 0, RM0433 §48.5.4), then the UART with its receive interrupt.
///
/// # Safety
/// `base` is the caller's UART.
unsafe fn enable(base: u32) {
    chip::write(base + usart::CR1, usart::CR1_FIFOEN);
    chip::write(
        base + usart::CR1,
        usart::CR1_FIFOEN | usart::CR1_RXFNEIE | usart::CR1_UE | usart::CR1_RE | usart::CR1_TE,
    );
}

impl GnssRx {
    /// The UART's interrupt: every byte waiting in the receive FIFO into the queue (a full
    /// queue drops it, counted). Never blocks; at most 16 bytes per call.
    pub fn on_interrupt(&mut self) {
        // SAFETY: this UART's status and data registers; reading RDR pops the FIFO.
        unsafe {
            while chip::read(self.base + usart::ISR) & usart::ISR_RXFNE != 0 {
                let byte = chip::read(self.base + usart::RDR) as u8;
                if self.bytes.enqueue(byte).is_err() {
                    self.dropped = self.dropped.wrapping_add(1);
                }
            }
            // Framing and noise errors (a wrong rate while searching) are the parser's to find.
            chip::write(self.base + usart::ICR, usart::ICR_ALL);
        }
    }

    /// Bytes lost because the queue was full, since start-up.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }
}

impl Uart for BoardGnss {
    /// The bytes received since the last call (at most `buffer.len()`; the rest next time).
    fn read(&mut self, buffer: &mut [u8]) -> usize {
        let mut count = 0;
        while count < buffer.len() {
            let Some(byte) = self.bytes.dequeue() else { break };
            buffer[count] = byte;
            count += 1;
        }
        count
    }

    /// What the transmit FIFO takes now (at most 16 bytes); the driver offers the rest again.
    fn write(&mut self, bytes: &[u8]) -> usize {
        // SAFETY: this driver's UART, started with its FIFOs by `start`.
        unsafe { super::serial::fill_tx_fifo(self.base, bytes) }
    }
}

impl GnssPort for BoardGnss {
    /// A new rate: the UART stopped, its divider written, started again (a byte in flight is
    /// lost; the driver expects that of a rate change).
    fn set_baud(&mut self, baud: u32) {
        if baud == self.baud || baud == 0 {
            return;
        }
        self.baud = baud;
        // SAFETY: this UART's registers; BRR is written with UE = 0 (RM0433 §48.8.1).
        unsafe {
            chip::write(self.base + usart::CR1, 0);
            chip::write(self.base + usart::BRR, uart_brr(self.kernel_clock_hz, baud));
            chip::write(self.base + usart::ICR, usart::ICR_ALL);
            enable(self.base);
        }
    }
}
