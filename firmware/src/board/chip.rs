//! Register access driven by the board description: GPIO modes, clock enables, DMA streams and
//! their DMAMUX routes, at the addresses, offsets and bits of [`crate::targets::h743`] (checked
//! against the `stm32h7` PAC by `tests/registers_match_pac.rs`; no register number is typed here).
//!
//! Why raw registers rather than the HAL's typed pins and peripherals: the pins, timers and
//! streams come from data ([`crate::targets::BoardDescription`]), so another board is a new data
//! file and no new code; the HAL's types name each pin in the type, and it has no DMA burst to
//! timer registers at all. Every access here is a volatile read or write of a documented
//! register; callers own the peripheral (each is set up once in `init` and then used by exactly
//! one task).

use crate::targets::h743::{self, dma, dmamux, exti, gpio, rcc, syscfg, RccEnable};
use crate::targets::{AltPin, DmaStream, Pin};
use core::ptr::{read_volatile, write_volatile};

/// Read a 32-bit register.
///
/// # Safety
/// `address` must be a readable peripheral register.
#[inline(always)]
pub unsafe fn read(address: u32) -> u32 {
    read_volatile(address as *const u32)
}

/// Write a 32-bit register.
///
/// # Safety
/// `address` must be a writable peripheral register the caller owns.
#[inline(always)]
pub unsafe fn write(address: u32, value: u32) {
    write_volatile(address as *mut u32, value)
}

/// Read-modify-write: clear `clear`, then set `set`.
///
/// # Safety
/// As [`write`]; not atomic (callers run in `init` or own the register).
#[inline(always)]
pub unsafe fn modify(address: u32, clear: u32, set: u32) {
    write(address, (read(address) & !clear) | set)
}

/// Enable a peripheral's clock (and read it back: RM0433 §8.5.10 asks for a delay before the
/// peripheral is accessed; the read is it).
pub fn enable_clock(enable: RccEnable) {
    let address = h743::RCC_BASE + enable.register as u32;
    // SAFETY: RCC enable registers; set once from `init` before the peripheral is used.
    unsafe {
        modify(address, 0, 1 << enable.bit);
        let _ = read(address);
    }
}

/// Enable the SYSCFG clock (RCC_APB4ENR.SYSCFGEN), for the EXTI line selection.
pub fn enable_syscfg() {
    let address = h743::RCC_BASE + rcc::APB4ENR;
    // SAFETY: RCC_APB4ENR; setting SYSCFGEN only.
    unsafe {
        modify(address, 0, rcc::APB4ENR_SYSCFGEN);
        let _ = read(address);
    }
}

#[inline(always)]
fn gpio_base(pin: Pin) -> u32 {
    h743::gpio_base(pin.port)
}

use gpio::{BSRR, IDR, MODER, OSPEEDR, PUPDR};

/// The two bits of `pin` in a 2-bit-per-pin register, set to `value`.
///
/// # Safety
/// The pin's port clock is on and the pin belongs to the caller.
unsafe fn set_field2(pin: Pin, offset: u32, value: u32) {
    let shift = gpio::field2_shift(u32::from(pin.number));
    let mask = (1 << gpio::FIELD2_BITS) - 1;
    modify(gpio_base(pin) + offset, mask << shift, (value & mask) << shift);
}

/// Connect `alt` to its peripheral: alternate-function mode, the AF number, very high speed
/// (DShot edges and 16 MHz SPI), optional pull-up (`pull_up`) or none.
pub fn alternate(alt: AltPin, pull_up: bool) {
    enable_clock(h743::gpio_enable(alt.pin.port));
    let pin = alt.pin;
    let (afr, shift) = gpio::afr_register_and_shift(u32::from(pin.number));
    let afr = gpio_base(pin) + afr;
    // SAFETY: the board description gives each pin one role (checked by `check`), so nothing
    // else configures it; these are its own fields of its port's registers.
    unsafe {
        let mask = (1 << gpio::AFR_BITS) - 1;
        modify(afr, mask << shift, (u32::from(alt.af) & mask) << shift);
        set_field2(pin, OSPEEDR, gpio::SPEED_VERY_HIGH);
        set_field2(pin, PUPDR, if pull_up { gpio::PULL_UP } else { gpio::PULL_NONE });
        set_field2(pin, MODER, gpio::MODE_ALTERNATE);
    }
}

/// [`alternate`] as an open-drain output with the pull-up on: the lines of an I²C bus (the
/// device's own pull-ups, where fitted, are stronger than the pin's 40 kΩ).
pub fn alternate_open_drain(alt: AltPin) {
    let pin = alt.pin;
    // SAFETY: as in `alternate`: this pin's own bit of its port's OTYPER.
    unsafe {
        modify(gpio_base(pin) + gpio::OTYPER, 0, 1 << pin.number);
    }
    alternate(alt, true);
}

/// Make `pin` a push-pull output at `high`.
pub fn output(pin: Pin, high: bool) {
    enable_clock(h743::gpio_enable(pin.port));
    set(pin, high);
    // SAFETY: as in `alternate`.
    unsafe {
        set_field2(pin, OSPEEDR, gpio::SPEED_HIGH);
        set_field2(pin, MODER, gpio::MODE_OUTPUT);
    }
}

/// Make `pin` an input with a pull-down (a data-ready line that is not driven reads low).
pub fn input_pull_down(pin: Pin) {
    enable_clock(h743::gpio_enable(pin.port));
    // SAFETY: as in `alternate`.
    unsafe {
        set_field2(pin, PUPDR, gpio::PULL_DOWN);
        set_field2(pin, MODER, gpio::MODE_INPUT);
    }
}

/// Make `pin` an analog input (an ADC channel): no digital input buffer, no pull.
pub fn analog(pin: Pin) {
    enable_clock(h743::gpio_enable(pin.port));
    // SAFETY: as in `alternate`.
    unsafe {
        set_field2(pin, PUPDR, gpio::PULL_NONE);
        set_field2(pin, MODER, gpio::MODE_ANALOG);
    }
}

/// Drive an output pin. BSRR writes are atomic: safe from any task.
#[inline(always)]
pub fn set(pin: Pin, high: bool) {
    let bit = gpio::bsrr_bit(u32::from(pin.number), high);
    // SAFETY: BSRR is write-only and atomic; only this pin's bit is written.
    unsafe { write(gpio_base(pin) + BSRR, bit) }
}

/// The input level of a pin.
pub fn level(pin: Pin) -> bool {
    // SAFETY: IDR is read-only.
    unsafe { read(gpio_base(pin) + IDR) & gpio::idr_bit(u32::from(pin.number)) != 0 }
}

/// Route `pin`'s EXTI line to a rising-edge interrupt (SYSCFG_EXTICR, EXTI_RTSR1, EXTI_CPUIMR1).
pub fn exti_rising(pin: Pin) {
    enable_syscfg();
    let line = u32::from(pin.number);
    let (exticr, shift) = syscfg::exticr_register_and_shift(line);
    let exticr = h743::SYSCFG_BASE + exticr;
    // SAFETY: this line's fields only; set once in `init`.
    unsafe {
        let mask = (1 << syscfg::EXTICR_BITS) - 1;
        modify(exticr, mask << shift, u32::from(pin.port.index()) << shift);
        modify(h743::EXTI_BASE + exti::RTSR1, 0, exti::line_bit(line));
        modify(h743::EXTI_BASE + exti::CPUIMR1, 0, exti::line_bit(line));
    }
}

/// Clear a pending EXTI line (EXTI_CPUPR1, write 1 to clear).
#[inline(always)]
pub fn exti_clear(line: u8) {
    // SAFETY: write-1-to-clear of one line's bit.
    unsafe { write(h743::EXTI_BASE + exti::CPUPR1, exti::line_bit(u32::from(line))) }
}

pub use dma::{cr, flag};

/// One DMA stream, by the description's [`DmaStream`].
#[derive(Clone, Copy, Debug)]
pub struct Dma {
    base: u32,
    stream: u32,
}

impl Dma {
    /// Enable the controller's clock and take the stream.
    pub fn new(stream: DmaStream) -> Self {
        enable_clock(h743::dma_enable(stream.controller));
        let base = if stream.controller == 2 { h743::DMA2_BASE } else { h743::DMA1_BASE };
        let dma = Self { base, stream: u32::from(stream.stream) };
        dma.disable();
        dma
    }

    /// Connect DMAMUX1 request `request` to this stream (0 = none: memory to memory).
    pub fn route(&self, stream: DmaStream, request: u8) {
        let channel = u32::from(stream.dmamux_channel());
        let ccr = h743::DMAMUX1_BASE + dmamux::ccr(channel);
        // SAFETY: this stream's DMAMUX channel register, owned with the stream.
        unsafe { write(ccr, u32::from(request) & dmamux::CCR_DMAREQ_ID) }
    }

    #[inline(always)]
    fn register(&self, offset: u32) -> u32 {
        dma::stream_register(self.base, self.stream, offset)
    }

    /// (LISR or HISR, the shift of this stream's flags); LIFCR/HIFCR are `LIFCR − LISR` above.
    #[inline(always)]
    fn flag_register_and_shift(&self) -> (u32, u32) {
        let status = if self.stream >= 4 { dma::HISR } else { dma::LISR };
        (status, dma::FLAG_SHIFTS[(self.stream % 4) as usize])
    }

    /// This stream's interrupt flags ([`flag`]).
    #[inline]
    pub fn flags(&self) -> u32 {
        let (status, shift) = self.flag_register_and_shift();
        // SAFETY: LISR/HISR are read-only.
        unsafe { (read(self.base + status) >> shift) & flag::ALL }
    }

    /// Clear this stream's interrupt flags.
    #[inline]
    pub fn clear_flags(&self) {
        let (status, shift) = self.flag_register_and_shift();
        let clear = status + (dma::LIFCR - dma::LISR);
        // SAFETY: LIFCR/HIFCR are write-1-to-clear; only this stream's bits are written.
        unsafe { write(self.base + clear, flag::ALL << shift) }
    }

    /// Stop the stream and wait (a few bus cycles, bounded) until it has.
    #[inline]
    pub fn disable(&self) {
        let cr = self.register(dma::SXCR);
        // SAFETY: this stream's configuration register.
        unsafe {
            modify(cr, cr::EN, 0);
            let mut spins = 1_000u32;
            while read(cr) & cr::EN != 0 && spins > 0 {
                spins -= 1;
            }
        }
    }

    /// Whether the stream is still running.
    #[inline]
    pub fn is_enabled(&self) -> bool {
        // SAFETY: read of this stream's configuration register.
        unsafe { read(self.register(dma::SXCR)) & cr::EN != 0 }
    }

    /// Data items left to transfer (the write position of a circular receive buffer is
    /// `len − remaining`).
    #[inline]
    pub fn remaining(&self) -> u32 {
        // SAFETY: read of this stream's NDTR.
        unsafe { read(self.register(dma::SXNDTR)) & dma::SXNDTR_NDT }
    }

    /// Program and start a transfer: `peripheral` (the source in memory-to-memory mode),
    /// `memory`, `items` data items, configuration `config` (without [`cr::EN`]). FIFO on
    /// (threshold full) for memory-to-memory, direct mode otherwise.
    ///
    /// # Safety
    /// `memory` must be DMA-reachable (AXI SRAM or SRAM1–3, not DTCM) and stay valid, and not
    /// be accessed by the CPU in ways that conflict, until the transfer completes.
    #[inline]
    pub unsafe fn start(&self, peripheral: u32, memory: u32, items: u16, config: u32) {
        self.disable();
        self.clear_flags();
        write(self.register(dma::SXPAR), peripheral);
        write(self.register(dma::SXM0AR), memory);
        write(self.register(dma::SXNDTR), u32::from(items));
        let fifo = if config & cr::MEMORY_TO_MEMORY != 0 { dma::SXFCR_FIFO_FULL } else { 0 };
        write(self.register(dma::SXFCR), fifo);
        write(self.register(dma::SXCR), config);
        write(self.register(dma::SXCR), config | cr::EN);
    }
}
