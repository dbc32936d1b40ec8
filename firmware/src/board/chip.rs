//! Register access driven by the board description: GPIO modes, clock enables, DMA streams and
//! their DMAMUX routes, at the addresses of [`crate::boards::h743`].
//!
//! Why raw registers rather than the HAL's typed pins and peripherals: the pins, timers and
//! streams come from data ([`crate::boards::BoardDescription`]), so another board is a new data
//! file and no new code; the HAL's types name each pin in the type, and it has no DMA burst to
//! timer registers at all. Every access here is a volatile read or write of a documented
//! register; callers own the peripheral (each is set up once in `init` and then used by exactly
//! one task).

use crate::boards::h743::{self, RccEnable};
use crate::boards::{AltPin, DmaStream, Pin};
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

/// Enable the SYSCFG clock (RCC_APB4ENR bit 1), for the EXTI line selection.
pub fn enable_syscfg() {
    // SAFETY: RCC_APB4ENR (offset 0xF4); setting SYSCFGEN only.
    unsafe {
        modify(h743::RCC_BASE + 0xF4, 0, 1 << 1);
        let _ = read(h743::RCC_BASE + 0xF4);
    }
}

fn gpio_base(pin: Pin) -> u32 {
    h743::GPIOA_BASE + 0x400 * u32::from(pin.port.index())
}

/// GPIO register offsets (RM0433 §11.4).
const MODER: u32 = 0x00;
const OSPEEDR: u32 = 0x08;
const PUPDR: u32 = 0x0C;
const IDR: u32 = 0x10;
const BSRR: u32 = 0x18;
const AFRL: u32 = 0x20;

/// The two bits of `pin` in a 2-bit-per-pin register, set to `value`.
///
/// # Safety
/// The pin's port clock is on and the pin belongs to the caller.
unsafe fn set_field2(pin: Pin, offset: u32, value: u32) {
    let shift = 2 * u32::from(pin.number);
    modify(gpio_base(pin) + offset, 0b11 << shift, (value & 0b11) << shift);
}

/// Connect `alt` to its peripheral: alternate-function mode, the AF number, very high speed
/// (DShot edges and 16 MHz SPI), optional pull-up (`pull_up`) or none.
pub fn alternate(alt: AltPin, pull_up: bool) {
    enable_clock(h743::gpio_enable(alt.pin.port));
    let pin = alt.pin;
    let afr = gpio_base(pin) + AFRL + 4 * u32::from(pin.number / 8);
    let shift = 4 * u32::from(pin.number % 8);
    // SAFETY: the board description gives each pin one role (checked by `check`), so nothing
    // else configures it; these are its own fields of its port's registers.
    unsafe {
        modify(afr, 0xF << shift, u32::from(alt.af & 0xF) << shift);
        set_field2(pin, OSPEEDR, 0b11);
        set_field2(pin, PUPDR, if pull_up { 0b01 } else { 0b00 });
        set_field2(pin, MODER, 0b10);
    }
}

/// Make `pin` a push-pull output at `high`.
pub fn output(pin: Pin, high: bool) {
    enable_clock(h743::gpio_enable(pin.port));
    set(pin, high);
    // SAFETY: as in `alternate`.
    unsafe {
        set_field2(pin, OSPEEDR, 0b10);
        set_field2(pin, MODER, 0b01);
    }
}

/// Make `pin` an input with a pull-down (a data-ready line that is not driven reads low).
pub fn input_pull_down(pin: Pin) {
    enable_clock(h743::gpio_enable(pin.port));
    // SAFETY: as in `alternate`.
    unsafe {
        set_field2(pin, PUPDR, 0b10);
        set_field2(pin, MODER, 0b00);
    }
}

/// Drive an output pin. BSRR writes are atomic: safe from any task.
#[inline(always)]
pub fn set(pin: Pin, high: bool) {
    let bit = u32::from(pin.number) + if high { 0 } else { 16 };
    // SAFETY: BSRR is write-only and atomic; only this pin's bit is written.
    unsafe { write(gpio_base(pin) + BSRR, 1 << bit) }
}

/// The input level of a pin.
pub fn level(pin: Pin) -> bool {
    // SAFETY: IDR is read-only.
    unsafe { read(gpio_base(pin) + IDR) & (1 << pin.number) != 0 }
}

/// Route `pin`'s EXTI line to a rising-edge interrupt (SYSCFG_EXTICR, EXTI_RTSR1, EXTI_CPUIMR1).
pub fn exti_rising(pin: Pin) {
    enable_syscfg();
    let line = u32::from(pin.number);
    const SYSCFG_EXTICR1: u32 = 0x5800_0400 + 0x08;
    const EXTI_RTSR1: u32 = 0x5800_0000;
    const EXTI_CPUIMR1: u32 = 0x5800_0000 + 0x80;
    let exticr = SYSCFG_EXTICR1 + 4 * (line / 4);
    let shift = 4 * (line % 4);
    // SAFETY: this line's fields only; set once in `init`.
    unsafe {
        modify(exticr, 0xF << shift, u32::from(pin.port.index()) << shift);
        modify(EXTI_RTSR1, 0, 1 << line);
        modify(EXTI_CPUIMR1, 0, 1 << line);
    }
}

/// Clear a pending EXTI line (EXTI_CPUPR1, write 1 to clear).
#[inline(always)]
pub fn exti_clear(line: u8) {
    // SAFETY: write-1-to-clear of one line's bit.
    unsafe { write(0x5800_0000 + 0x88, 1 << line) }
}

/// DMA stream configuration bits (DMA_SxCR, RM0433 §15.5.5).
pub mod cr {
    pub const EN: u32 = 1 << 0;
    pub const TEIE: u32 = 1 << 2;
    pub const TCIE: u32 = 1 << 4;
    pub const PERIPHERAL_TO_MEMORY: u32 = 0b00 << 6;
    pub const MEMORY_TO_PERIPHERAL: u32 = 0b01 << 6;
    pub const MEMORY_TO_MEMORY: u32 = 0b10 << 6;
    pub const CIRC: u32 = 1 << 8;
    pub const PINC: u32 = 1 << 9;
    pub const MINC: u32 = 1 << 10;
    pub const PSIZE_32: u32 = 0b10 << 11;
    pub const MSIZE_32: u32 = 0b10 << 13;
    pub const PRIORITY_HIGH: u32 = 0b10 << 16;
    pub const PRIORITY_VERY_HIGH: u32 = 0b11 << 16;
}

/// DMA interrupt flags of one stream, after [`Dma::flags`] shifted them down (RM0433 §15.5.1).
pub mod flag {
    pub const TRANSFER_ERROR: u32 = 1 << 3;
    pub const TRANSFER_COMPLETE: u32 = 1 << 5;
    /// FIFO, direct-mode, transfer errors, half and full transfer.
    pub const ALL: u32 = 0b11_1101;
}

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
        let ccr = h743::DMAMUX1_BASE + 4 * u32::from(stream.dmamux_channel());
        // SAFETY: this stream's DMAMUX channel register, owned with the stream.
        unsafe { write(ccr, u32::from(request & 0x7F)) }
    }

    fn register(&self, offset: u32) -> u32 {
        self.base + 0x10 + 0x18 * self.stream + offset
    }

    fn flag_register_and_shift(&self) -> (u32, u32) {
        const SHIFTS: [u32; 4] = [0, 6, 16, 22];
        (if self.stream >= 4 { 4 } else { 0 }, SHIFTS[(self.stream % 4) as usize])
    }

    /// This stream's interrupt flags ([`flag`]).
    #[inline]
    pub fn flags(&self) -> u32 {
        let (high, shift) = self.flag_register_and_shift();
        // SAFETY: LISR/HISR are read-only.
        unsafe { (read(self.base + high) >> shift) & flag::ALL }
    }

    /// Clear this stream's interrupt flags.
    #[inline]
    pub fn clear_flags(&self) {
        let (high, shift) = self.flag_register_and_shift();
        // SAFETY: LIFCR/HIFCR are write-1-to-clear; only this stream's bits are written.
        unsafe { write(self.base + 0x08 + high, flag::ALL << shift) }
    }

    /// Stop the stream and wait (a few bus cycles, bounded) until it has.
    #[inline]
    pub fn disable(&self) {
        let cr = self.register(0x00);
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
        unsafe { read(self.register(0x00)) & cr::EN != 0 }
    }

    /// Data items left to transfer (the write position of a circular receive buffer is
    /// `len − remaining`).
    #[inline]
    pub fn remaining(&self) -> u32 {
        // SAFETY: read of this stream's NDTR.
        unsafe { read(self.register(0x04)) & 0xFFFF }
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
        write(self.register(0x08), peripheral);
        write(self.register(0x0C), memory);
        write(self.register(0x04), u32::from(items));
        let fifo = if config & cr::MEMORY_TO_MEMORY != 0 { 0b111 } else { 0 };
        write(self.register(0x14), fifo);
        write(self.register(0x00), config);
        write(self.register(0x00), config | cr::EN);
    }
}
