//! An I²C master on the H743's I2C1/I2C2, register level, polled: the compass's bus
//! (`app::compass` through `drivers::compass::I2cRegisterBus`).
//!
//! Why polled and not DMA: every DMA stream of the H743 has a job on this board already
//! (`board::gnss`), and a compass read is 7 to 9 bytes every 10 ms, about 0.2 ms on the wire at
//! 400 kHz, spent in the link pass (priority 2, under the control step, which preempts it).
//!
//! What it assumes: fast mode (400 kHz, `targets::i2c_fast_timingr` from the kernel clock, which
//! is rcc_pclk1 after reset: RCC_D2CCIP2R.I2C123SEL = 0); pull-ups on SCL and SDA (a GNSS mast
//! has them; the pins' own 40 kΩ are on as well, which alone are too weak for 400 kHz on a long
//! cable). Every wait is bounded ([`TRANSFER_TIMEOUT_US`]): a device that holds SDA low, a
//! missing pull-up or a NACK ends the transfer with an error, after which the peripheral is
//! reset (PE cleared and set, RM0433 §47.4.6 "software reset") so the next transfer starts clean.

use super::chip;
use crate::drivers::compass::I2cRegisterBus;
use crate::targets::h743::{self, i2c as reg};
use crate::targets::{i2c_fast_timingr, I2cWiring};

/// Longest one transfer may take, µs: the longest (a 1-byte register address then 9 bytes, 20
/// bytes with the address bytes and acknowledges: 11 bit times each, 0.55 ms at 400 kHz) four
/// times over, for a device stretching the clock.
pub const TRANSFER_TIMEOUT_US: u32 = 2_000;

/// Most bytes one read takes (the peripheral's NBYTES is 8 bits; the drivers read at most 7).
pub const MAX_READ_LEN: usize = 255;

/// Why a transfer failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum I2cError {
    /// The device did not acknowledge (absent, or another address).
    Nack,
    /// A wait ran past [`TRANSFER_TIMEOUT_US`] (SDA or SCL held low, no pull-ups).
    Timeout,
    /// Bus error or arbitration lost (noise on the cable, another master).
    Bus,
    /// More than [`MAX_READ_LEN`] bytes asked for.
    TooLong,
}

/// The I²C master.
pub struct BoardI2c {
    base: u32,
    timingr: u32,
    /// Polls of ISR in [`TRANSFER_TIMEOUT_US`] (a poll is a 1 µs busy wait and a register read).
    max_polls: u32,
    cycles_per_us: u32,
}

impl BoardI2c {
    /// Start `wiring`'s peripheral at 400 kHz from its kernel clock `kernel_clock_hz` (pclk1);
    /// `cycles_per_us`: the core clock in MHz, for the bounded waits.
    pub fn new(wiring: I2cWiring, kernel_clock_hz: u32, cycles_per_us: u32) -> Self {
        let info = h743::i2c(wiring.i2c);
        chip::enable_clock(info.enable);
        chip::alternate_open_drain(wiring.scl);
        chip::alternate_open_drain(wiring.sda);
        let bus = Self {
            base: info.base,
            timingr: i2c_fast_timingr(kernel_clock_hz),
            max_polls: TRANSFER_TIMEOUT_US,
            cycles_per_us: cycles_per_us.max(1),
        };
        bus.reset();
        bus
    }

    /// Disable, set the timing (TIMINGR is written with PE = 0, RM0433 §47.7.5), clear the
    /// flags, enable.
    fn reset(&self) {
        // SAFETY: this driver's own peripheral (the board description gives it one role).
        unsafe {
            chip::write(self.base + reg::CR1, 0);
            chip::write(self.base + reg::TIMINGR, self.timingr);
            chip::write(self.base + reg::ICR, reg::ICR_ALL);
            chip::write(self.base + reg::CR1, reg::CR1_PE);
        }
    }

    fn isr(&self) -> u32 {
        // SAFETY: a read of this peripheral's status register.
        unsafe { chip::read(self.base + reg::ISR) }
    }

    /// Wait for `flag` in ISR: a NACK, a bus error or the timeout end the transfer first.
    fn wait_for(&self, flag: u32) -> Result<(), I2cError> {
        for _ in 0..self.max_polls {
            let isr = self.isr();
            if isr & reg::ISR_NACKF != 0 {
                return Err(I2cError::Nack);
            }
            if isr & (reg::ISR_BERR | reg::ISR_ARLO) != 0 {
                return Err(I2cError::Bus);
            }
            if isr & flag != 0 {
                return Ok(());
            }
            cortex_m::asm::delay(self.cycles_per_us);
        }
        Err(I2cError::Timeout)
    }

    /// After a transfer: on an error the peripheral is reset (a NACK is followed by the STOP
    /// the peripheral sends by itself with AUTOEND; waited for, bounded); the flags cleared.
    fn finish(&self, result: Result<(), I2cError>) -> Result<(), I2cError> {
        if result.is_err() {
            // A NACK ends with a STOP; a timeout or a bus error leaves the bus as it is, and
            // the reset releases the lines.
            let _ = self.wait_for_stop();
            self.reset();
        } else {
            // SAFETY: clearing this peripheral's flags.
            unsafe { chip::write(self.base + reg::ICR, reg::ICR_ALL) };
        }
        result
    }

    fn wait_for_stop(&self) -> Result<(), I2cError> {
        for _ in 0..self.max_polls {
            if self.isr() & reg::ISR_STOPF != 0 {
                return Ok(());
            }
            cortex_m::asm::delay(self.cycles_per_us);
        }
        Err(I2cError::Timeout)
    }

    /// Start a transfer of `len` bytes to or from `address` (7-bit).
    fn start(&self, address: u8, len: usize, read: bool, autoend: bool) {
        let mut cr2 = (u32::from(address & 0x7F) << reg::CR2_SADD_SHIFT)
            | ((len as u32 & 0xFF) << reg::CR2_NBYTES_SHIFT)
            | reg::CR2_START;
        if read {
            cr2 |= reg::CR2_RD_WRN;
        }
        if autoend {
            cr2 |= reg::CR2_AUTOEND;
        }
        // SAFETY: this peripheral's control register; the transfer starts.
        unsafe { chip::write(self.base + reg::CR2, cr2) };
    }

    fn write_bytes(&self, address: u8, bytes: &[u8]) -> Result<(), I2cError> {
        if self.isr() & reg::ISR_BUSY != 0 {
            return Err(I2cError::Bus);
        }
        self.start(address, bytes.len(), false, true);
        for &byte in bytes {
            self.wait_for(reg::ISR_TXIS)?;
            // SAFETY: the transmit data register of this peripheral.
            unsafe { chip::write(self.base + reg::TXDR, u32::from(byte)) };
        }
        self.wait_for(reg::ISR_STOPF)
    }

    fn read_after_register(
        &self,
        address: u8,
        first_reg: u8,
        buf: &mut [u8],
    ) -> Result<(), I2cError> {
        if buf.len() > MAX_READ_LEN {
            return Err(I2cError::TooLong);
        }
        if self.isr() & reg::ISR_BUSY != 0 {
            return Err(I2cError::Bus);
        }
        // The register address, then a repeated START for the read (no STOP between).
        self.start(address, 1, false, false);
        self.wait_for(reg::ISR_TXIS)?;
        // SAFETY: the transmit data register of this peripheral.
        unsafe { chip::write(self.base + reg::TXDR, u32::from(first_reg)) };
        self.wait_for(reg::ISR_TC)?;
        self.start(address, buf.len(), true, true);
        for byte in buf.iter_mut() {
            self.wait_for(reg::ISR_RXNE)?;
            // SAFETY: the receive data register of this peripheral (reading pops the byte).
            *byte = unsafe { chip::read(self.base + reg::RXDR) } as u8;
        }
        self.wait_for(reg::ISR_STOPF)
    }
}

impl I2cRegisterBus for BoardI2c {
    type Error = I2cError;

    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), I2cError> {
        let result = self.write_bytes(address, &[reg, value]);
        self.finish(result)
    }

    fn read_registers(
        &mut self,
        address: u8,
        first_reg: u8,
        buf: &mut [u8],
    ) -> Result<(), I2cError> {
        let result = self.read_after_register(address, first_reg, buf);
        self.finish(result)
    }
}
