//! Board constants and the clock choice: the assumptions this firmware makes about the clock
//! tree, each with its unit and where it comes from (in the manner of stabilizer's
//! `design_parameters.rs`). What differs between boards (pins, timers, DMA streams, crystal) is
//! data in [`crate::targets`]; [`BOARD`] is the one this firmware is built for.

use crate::targets::{ClockPlan, SiliconRevision};

pub use crate::targets::SELECTED as BOARD;

/// The silicon revision: DBGMCU_IDCODE.REV_ID (RM0433 rev 8 §61.5.8; 0x1003 = Y, 0x2003 = V).
pub fn silicon_revision() -> u16 {
    // SAFETY: DBGMCU_IDCODE is a read-only identity register.
    unsafe { (*stm32h7xx_hal::pac::DBGMCU::ptr()).idc.read().rev_id().bits() }
}

/// The clock plan for this chip: 480 MHz at VOS0 on revision V, 400 MHz at VOS1 otherwise
/// (revision Y is limited to 400 MHz; DS12110 table 23, errata ES0392). Read before the clocks
/// are configured; reported in `BoardHealth`.
pub fn clock_plan(revision: u16) -> ClockPlan {
    ClockPlan::for_revision(SiliconRevision::from_rev_id(revision))
}

/// Frequency of the microsecond time base ([`crate::board::time`]), Hz: 1 tick = 1 µs.
pub const TIME_BASE_HZ: u32 = 1_000_000;
