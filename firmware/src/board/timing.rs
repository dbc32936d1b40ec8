//! Execution-time watch for the control step: how long each 2 kHz step takes, measured with the
//! Cortex-M7's DWT cycle counter (one count per core clock cycle: 2.5 ns at 400 MHz, 2.08 ns at
//! 480 MHz; the clock is detected at start-up, see `board::config`, and handed to
//! [`StepTimer::new`]).
//!
//! The control task records its own duration (two register reads and a compare, no logging: a
//! log call at the highest priority could wait on the debug probe). The longest step and the
//! number of steps over the deadline are published through atomics, and the idle task reports
//! changes over defmt, where blocking on the probe harms nobody. The portable application
//! separately counts *late* steps (start-to-start intervals) in its status snapshot.

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::{DCB, DWT};

/// Core clock cycles per microsecond at the core clock in force (set once by
/// [`StepTimer::new`]; 400 until then, never 0).
static CYCLES_PER_US: AtomicU32 = AtomicU32::new(400);

/// Core clock cycles per microsecond at the detected core clock.
pub fn cycles_per_us() -> u32 {
    CYCLES_PER_US.load(Ordering::Relaxed)
}

/// Longest control step so far, core clock cycles (written only by the control task).
static STEP_MAX_CYCLES: AtomicU32 = AtomicU32::new(0);
/// Control steps that took longer than their deadline (written only by the control task).
static STEP_OVERRUNS: AtomicU32 = AtomicU32::new(0);

/// What [`step_stats`] reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepStats {
    /// Longest control step so far, µs.
    pub max_us: u32,
    /// Steps that exceeded the deadline.
    pub overruns: u32,
}

/// The control step's stopwatch (the control task's `#[local]`).
pub struct StepTimer {
    deadline_cycles: u32,
}

impl StepTimer {
    /// Start the DWT cycle counter and time steps against `deadline_us` at the core clock
    /// `core_clock_hz`.
    pub fn new(dcb: &mut DCB, mut dwt: DWT, deadline_us: u32, core_clock_hz: u32) -> Self {
        let cycles_per_us = (core_clock_hz / 1_000_000).max(1);
        CYCLES_PER_US.store(cycles_per_us, Ordering::Relaxed);
        dcb.enable_trace();
        // The M7's DWT is software-locked after a power cycle (ARM DDI 0489, "Lock Access").
        DWT::unlock();
        dwt.enable_cycle_counter();
        Self { deadline_cycles: deadline_us.saturating_mul(cycles_per_us) }
    }

    /// A time stamp for [`StepTimer::finish`], core clock cycles.
    #[inline]
    pub fn start(&self) -> u32 {
        DWT::cycle_count()
    }

    /// Record a step that began at `started`. Never blocks, never logs.
    #[inline]
    pub fn finish(&mut self, started: u32) {
        let elapsed_cycles = DWT::cycle_count().wrapping_sub(started);
        if elapsed_cycles > STEP_MAX_CYCLES.load(Ordering::Relaxed) {
            STEP_MAX_CYCLES.store(elapsed_cycles, Ordering::Relaxed);
        }
        if elapsed_cycles > self.deadline_cycles {
            STEP_OVERRUNS
                .store(STEP_OVERRUNS.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
        }
    }
}

/// The control step's longest duration and deadline overruns so far.
pub fn step_stats() -> StepStats {
    StepStats {
        max_us: STEP_MAX_CYCLES.load(Ordering::Relaxed).div_ceil(cycles_per_us()),
        overruns: STEP_OVERRUNS.load(Ordering::Relaxed),
    }
}
