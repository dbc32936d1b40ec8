//! DShot600 motor outputs: one timer DMA burst per motor timer.
//!
//! Every control step [`BoardMotors::set_commands`] turns each motor's command into a 16-bit
//! frame (`dshot::output_frame`: motor stop at δ ≤ 0, throttle 48..=2047 above), the frames
//! into compare values (`dshot::compare_values`: 75 % / 37.5 % of the 1.667 µs bit), and
//! interleaves them per timer ([`interleave_burst`]) in an AXI SRAM buffer. The timer runs
//! continuously at the DShot600 bit period with preloaded CCRs in PWM mode 1; its update event
//! requests a DMA burst (TIMx_DCR/DMAR, RM0433 §39.4.25) that writes the next bit's compare
//! values of all its motor channels at once, so the motors of one timer switch bits on the same
//! tick. After 17 updates (16 bits and a trailing 0) the stream stops and the line stays low
//! until the next step's frame. A frame takes 28 µs of the 500 µs step; the CPU only writes
//! the buffer and restarts the streams (no interrupt).
//!
//! Not done: bidirectional DShot (the ESC's eRPM answer on the same wire). The frames are
//! normal DShot (idle low, normal checksum), so ESCs do not answer, `speeds_rad_s` is `None`
//! for every motor and the board does not announce `MOTOR_RPM`. The portable half of the
//! bidirectional path (inverted checksum, GCR decoding, eRPM → rad/s, error counters) is in
//! [`crate::drivers::dshot`] and tested; the board half (switching each channel to input
//! capture after the frame and a capture DMA per channel, or GPIO sampling) is the remaining
//! work, see `docs/board.md`.
//!
//! Special commands (`Motors::send_command`: beep, spin direction, save, …; the protocol's
//! `EscCommand` request) are refused while armed and repeated as the specification asks
//! (`dshot::CommandQueue`, shared with the simulator's ESCs).

use super::chip::{self, cr, Dma};
use crate::app::hal::{EscCommandError, Motors, MAX_MOTORS};
use crate::boards::{h743, interleave_burst, BoardDescription};
use crate::drivers::dshot::{
    bit_period_ticks, compare_values, CommandQueue, DshotCommand, COMPARE_BUFFER_LEN,
    DSHOT600_BIT_RATE_HZ,
};
use core::ptr::addr_of_mut;
use protocol::MotorLinkHealth;

/// Most motor timers a board may use.
const MAX_TIMERS: usize = 4;
/// Words per timer buffer: 17 bits × 4 channels.
const BURST_WORDS: usize = COMPARE_BUFFER_LEN * 4;

/// The burst buffers, in AXI SRAM (DMA1 cannot reach DTCM). NOLOAD: written before each use.
#[link_section = ".axisram.dshot"]
static mut BURSTS: core::mem::MaybeUninit<[[u32; BURST_WORDS]; MAX_TIMERS]> =
    core::mem::MaybeUninit::uninit();

/// Timer register offsets and bits (RM0433 §39.4, general-purpose timers TIM2–TIM5).
mod tim {
    pub const CR1: u32 = 0x00;
    pub const DIER: u32 = 0x0C;
    pub const EGR: u32 = 0x14;
    pub const CCMR1: u32 = 0x18;
    pub const CCER: u32 = 0x20;
    pub const CNT: u32 = 0x24;
    pub const PSC: u32 = 0x28;
    pub const ARR: u32 = 0x2C;
    pub const CCR1: u32 = 0x34;
    pub const DCR: u32 = 0x48;
    pub const DMAR: u32 = 0x4C;
    pub const CR1_CEN: u32 = 1 << 0;
    pub const CR1_ARPE: u32 = 1 << 7;
    pub const DIER_UDE: u32 = 1 << 8;
    pub const EGR_UG: u32 = 1 << 0;
    /// OCxM = PWM mode 1 (0b0110) with the compare preload (OCxPE), for an odd channel; an even
    /// channel's field is 8 bits higher.
    pub const CCMR_PWM1_PRELOAD: u32 = (0b110 << 4) | (1 << 3);
}

/// One motor timer and its burst.
#[derive(Clone, Copy)]
struct BurstTimer {
    base: u32,
    dma: Dma,
    /// Channels in the burst: `first`..`first + count`.
    count: u8,
    /// The motor (application index) on each burst slot, if any.
    motors: [Option<u8>; 4],
    /// Index into `BURSTS`.
    buffer: usize,
}

/// The board's motor outputs (see the module documentation).
pub struct BoardMotors {
    timers: [Option<BurstTimer>; MAX_TIMERS],
    count: u8,
    period_ticks: u16,
    frames_sent: u32,
    special: CommandQueue,
}

impl BoardMotors {
    /// Set up the board's motor timers for DShot600 at `timer_clock_hz` (the APB1/APB2 timer
    /// kernel clock) and send motor-stop frames from the first step on.
    pub fn new(board: &BoardDescription, timer_clock_hz: u32) -> Self {
        // 240 MHz / 600 kbit/s = 400 ticks; 200 MHz → 333. Both fit; the fallback never runs.
        let period_ticks = bit_period_ticks(timer_clock_hz, DSHOT600_BIT_RATE_HZ).unwrap_or(333);
        let mut timers = [None; MAX_TIMERS];
        for (index, motor_timer) in board.motor_timers.iter().take(MAX_TIMERS).enumerate() {
            let Some(info) = h743::timer(motor_timer.timer) else { continue };
            let (first, count) = board.burst_channels(motor_timer.timer);
            let mut motors = [None; 4];
            for (m, output) in board.driven_motors().iter().enumerate() {
                if output.timer == motor_timer.timer {
                    motors[usize::from(output.channel - first)] = Some(m as u8);
                }
            }
            for output in board.motors.iter().filter(|o| o.timer == motor_timer.timer) {
                chip::alternate(output.pin, false);
            }
            chip::enable_clock(info.enable);
            let base = info.base;
            // SAFETY: the timer belongs to the motor outputs (the description gives it no other
            // role; `check` refuses the time base's and the control tick's timers). Configured
            // while stopped.
            unsafe {
                chip::write(base + tim::CR1, 0);
                chip::write(base + tim::DIER, 0);
                chip::write(base + tim::PSC, 0);
                chip::write(base + tim::ARR, u32::from(period_ticks) - 1);
                let mut ccmr = [0u32; 2];
                let mut ccer = 0u32;
                for channel in first..first + count {
                    let c = u32::from(channel - 1);
                    ccmr[(c / 2) as usize] |= tim::CCMR_PWM1_PRELOAD << (8 * (c % 2));
                    ccer |= 1 << (4 * c);
                    chip::write(base + tim::CCR1 + 4 * c, 0);
                }
                chip::write(base + tim::CCMR1, ccmr[0]);
                chip::write(base + tim::CCMR1 + 4, ccmr[1]);
                chip::write(base + tim::CCER, ccer);
                // Burst: DBA = CCR`first` (register index 13 + first − 1), DBL = count − 1.
                let dba = (tim::CCR1 / 4) + u32::from(first - 1);
                chip::write(base + tim::DCR, (u32::from(count - 1) << 8) | dba);
                chip::write(base + tim::CNT, 0);
                chip::write(base + tim::EGR, tim::EGR_UG);
                chip::write(base + tim::CR1, tim::CR1_ARPE | tim::CR1_CEN);
            }
            let dma = Dma::new(motor_timer.dma);
            dma.route(motor_timer.dma, info.update_request);
            timers[index] = Some(BurstTimer { base, dma, count, motors, buffer: index });
        }
        Self {
            timers,
            count: board.motor_count.min(MAX_MOTORS as u8),
            period_ticks,
            frames_sent: 0,
            special: CommandQueue::default(),
        }
    }

    /// Tell the outputs whether anything is armed (special commands are refused while it is, and
    /// a waiting one is dropped).
    pub fn set_armed(&mut self, armed: bool) {
        self.special.set_armed(armed);
    }

    /// Counters for `BoardHealth.motors`. No speed reports: see the module documentation.
    pub fn health(&self) -> MotorLinkHealth {
        MotorLinkHealth {
            motor_count: self.count,
            frames_sent: self.frames_sent,
            reports: [0; MAX_MOTORS],
            report_errors: [0; MAX_MOTORS],
        }
    }
}

impl Motors for BoardMotors {
    fn count(&self) -> u8 {
        self.count
    }

    /// Send one frame to every motor output. Never blocks: the previous frame ended 470 µs ago.
    fn set_commands(&mut self, commands: &[f32]) {
        let period = self.period_ticks;
        for timer in self.timers.iter().flatten() {
            let n = usize::from(timer.count);
            let mut values = [None; 4];
            for (slot, motor) in timer.motors.iter().enumerate().take(n) {
                values[slot] = motor.map(|m| {
                    let command = commands.get(usize::from(m)).copied().unwrap_or(0.0);
                    compare_values(self.special.frame(m, command, false), period)
                });
            }
            // SAFETY: the stream of this timer is stopped before its buffer is rewritten (the
            // previous burst ended long ago; `disable` makes sure), and only this task writes it.
            unsafe {
                chip::modify(timer.base + tim::DIER, tim::DIER_UDE, 0);
                timer.dma.disable();
                let bursts = addr_of_mut!(BURSTS) as *mut [u32; BURST_WORDS];
                let buffer = &mut *bursts.add(timer.buffer);
                interleave_burst(&values[..n], buffer);
                timer.dma.start(
                    timer.base + tim::DMAR,
                    buffer.as_ptr() as u32,
                    (COMPARE_BUFFER_LEN * n) as u16,
                    cr::MEMORY_TO_PERIPHERAL
                        | cr::MINC
                        | cr::PSIZE_32
                        | cr::MSIZE_32
                        | cr::PRIORITY_VERY_HIGH,
                );
                chip::modify(timer.base + tim::DIER, 0, tim::DIER_UDE);
                // Restart the bit clock: this update requests the first burst at once.
                chip::write(timer.base + tim::EGR, tim::EGR_UG);
            }
        }
        self.frames_sent = self.frames_sent.wrapping_add(1);
        self.special.frame_sent();
    }

    /// Queue a special command for `motor` (`None` = every motor), sent instead of the stop
    /// frame on the following steps as often as the specification asks. Refused while armed.
    fn send_command(
        &mut self,
        command: DshotCommand,
        motor: Option<u8>,
    ) -> Result<(), EscCommandError> {
        self.special.queue(command, motor).map_err(|_| EscCommandError::Armed)
    }

    /// `None` for every motor: no bidirectional DShot capture yet.
    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
        [None; MAX_MOTORS]
    }
}
