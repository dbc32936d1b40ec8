//! The monotonic microsecond time base: TIM2, a 32-bit timer counting at 1 MHz, extended to
//! 64 bits in software.
//!
//! Why TIM2: it is the other 32-bit timer besides TIM5, which drives motors on most H743 flight
//! controllers (`crate::targets::FIRMWARE_TIME_BASE`; the board check refuses a board that
//! puts motors on it). Why not the DWT cycle counter: one tick is exactly one microsecond, so `now_us` is a
//! register read and an add, with no 64-bit division by the core clock (a library call on the M7),
//! and it keeps counting while a debugger halts the core's DWT. TIM2's kernel clock is
//! 2 × pclk1 = hclk, 200 or 240 MHz depending on the silicon revision (RM0433 §8.5.7, timers on
//! APB1 run at twice the APB clock when its prescaler is not 1), an exact multiple of 1 MHz in
//! both cases, so the prescaler is exact.
//!
//! Extension: the 32-bit counter wraps every 2³² µs ≈ 71.6 minutes. Each read compares the
//! counter with the previous read and counts a wrap when it went backwards; read and update
//! happen in one short critical section (a handful of instructions) so the control task and the
//! USB task can both read the clock at their own priorities. Correct as long as the clock is read
//! at least once per 71.6 minutes, which the 2 kHz control task guarantees.

use core::cell::Cell;
use cortex_m::interrupt::Mutex;
use stm32h7xx_hal::{pac, timer::Timer};

/// (counter value at the last read, number of wraps seen so far).
static EXTENSION: Mutex<Cell<(u32, u32)>> = Mutex::new(Cell::new((0, 0)));

/// A handle to the microsecond clock. `Copy`, so each task keeps its own in `#[local]`; the only
/// way to make one is to hand over TIM2 already running at 1 MHz.
#[derive(Clone, Copy, Debug)]
pub struct MicrosClock {
    _private: (),
}

impl MicrosClock {
    /// Take TIM2, which must tick at [`crate::board::config::TIME_BASE_HZ`] and count up over
    /// its full 32-bit range (what `TimerExt::tick_timer` sets up).
    pub fn new(timer: Timer<pac::TIM2>) -> Self {
        // The timer runs on in hardware; the handle only needs its counter register from now on.
        let _ = timer;
        Self { _private: () }
    }

    /// Microseconds since TIM2 was started. Monotonic, never blocks (the critical section is a
    /// few instructions long).
    pub fn now_us(&self) -> u64 {
        cortex_m::interrupt::free(|cs| {
            // SAFETY: a read of TIM2's counter register has no side effects; TIM2 was moved into
            // `new`, so nothing else reconfigures it.
            let ticks = unsafe { (*pac::TIM2::ptr()).cnt.read().bits() };
            let cell = EXTENSION.borrow(cs);
            let (last_ticks, mut wraps) = cell.get();
            if ticks < last_ticks {
                wraps = wraps.wrapping_add(1);
            }
            cell.set((ticks, wraps));
            (u64::from(wraps) << 32) | u64::from(ticks)
        })
    }
}
