//! DShot600 motor outputs, bidirectional: one timer DMA burst per motor timer out, one input
//! capture DMA per motor back.
//!
//! **Out.** Every control step [`BoardMotors::set_commands`] turns each motor's command into a
//! 16-bit frame (`dshot::CommandQueue::frame`: motor stop at δ ≤ 0 until the first command above zero since arming, idle (48) for δ ≤ 0 after it until disarmed, throttle 48..=2047 above; the
//! inverted checksum when the ESCs speak bidirectional DShot), the frames into compare values
//! (`dshot::compare_values`: 75 % / 37.5 % of the 1.667 µs bit), and interleaves them per timer
//! ([`interleave_burst`]) in an AXI SRAM buffer. The timer runs at the DShot600 bit period with
//! preloaded CCRs in PWM mode 1 (active low when bidirectional: the line idles high); its update
//! event requests a DMA burst (TIMx_DCR/DMAR, RM0433 §39.4.25) that writes the next bit's
//! compare values of all its motor channels at once. After 18 updates (16 bits and two idle
//! values) the stream completes. A frame takes 30 µs of the 500 µs step.
//!
//! **Back** (bidirectional DShot). About 30 µs after its frame each ESC answers on the same wire
//! with its electrical period (21 bits at 750 kbit/s, GCR). The burst stream's transfer-complete
//! interrupt ([`BurstCompletion::on_burst_complete`], a task above the control step's priority
//! in `src/main.rs`, a few register writes) switches the timer's channels to input capture of
//! both edges with the counter free-running, and starts one DMA per channel that copies each
//! captured timestamp (CCRx) into the motor's edge buffer. At the next step, before the next
//! frame, `set_commands` stops the captures, decodes each motor's edges
//! (`dshot::telemetry_from_edges`: edges → 21 line bits → GCR → checksum → eRPM → rad/s, with the
//! per-motor counters of `dshot::MotorTelemetry`) and switches the channels back to output.
//! `speeds_rad_s` then reports each motor's speed, one step old; a motor whose answers failed
//! [`crate::drivers::dshot::STALE_ANSWERS`] times in a row reads `None`.
//!
//! What runs in which task: the control task owns [`BoardMotors`] (frames, decoding, the switch
//! back); the burst task owns a [`BurstCompletion`] per timer (the switch to capture). They touch
//! the same timer at different times by construction: the completion interrupt comes 28 µs after
//! `set_commands` started the burst, and `set_commands` touches the timer again only in the next
//! step, 500 µs later, after taking the captures ([`CAPTURING`] says whether there are any).
//!
//! Not verified on hardware (no board here): this is compile-checked register code; the
//! decoding it feeds is tested on the host (`drivers::dshot`).
//!
//! Special commands (`Motors::send_command`: beep, spin direction, save, …; the protocol's
//! `EscCommand` request) are refused while armed and repeated as the specification asks
//! (`dshot::CommandQueue`, shared with the simulator's ESCs).

use super::chip::{self, cr, Dma};
use crate::app::hal::{Motors, MAX_MOTORS};
use crate::drivers::dshot::{
    bit_period_ticks, compare_values, telemetry_from_edges, CommandQueue, MotorTelemetry,
    CAPTURE_EDGES, COMPARE_BUFFER_LEN, DSHOT600_BIT_RATE_HZ, DSHOT600_TELEMETRY_BIT_RATE_HZ,
};
use crate::targets::h743::{self, tim};
use crate::targets::{interleave_burst, BoardDescription};
use core::ptr::{addr_of, addr_of_mut};
use core::sync::atomic::{AtomicBool, Ordering};
use protocol::MotorLinkHealth;

/// Most motor timers a board may use.
const MAX_TIMERS: usize = 4;
/// Words per timer buffer: 18 bit values × 4 channels.
const BURST_WORDS: usize = COMPARE_BUFFER_LEN * 4;

/// The burst buffers, in AXI SRAM (DMA1 cannot reach DTCM). NOLOAD: written before each use.
#[link_section = ".axisram.dshot"]
static mut BURSTS: core::mem::MaybeUninit<[[u32; BURST_WORDS]; MAX_TIMERS]> =
    core::mem::MaybeUninit::uninit();

/// The captured edge timestamps of each motor's answer, in AXI SRAM (written by the capture
/// DMAs, read by the control task in the next step). NOLOAD.
#[link_section = ".axisram.dshot"]
static mut CAPTURES: core::mem::MaybeUninit<[[u32; CAPTURE_EDGES]; MAX_MOTORS]> =
    core::mem::MaybeUninit::uninit();

/// Per timer: its channels capture an answer (set by the burst task when it switched them,
/// cleared by the control task when it took the captures).
static CAPTURING: [AtomicBool; MAX_TIMERS] = [const { AtomicBool::new(false) }; MAX_TIMERS];

/// A channel's answer capture: its motor and DMA stream.
#[derive(Clone, Copy)]
struct Capture {
    motor: u8,
    dma: Dma,
}

/// Channel mode, for [`configure_channels`].
#[derive(Clone, Copy, PartialEq, Eq)]
enum ChannelMode {
    /// PWM output of the frame's bits (inverted when bidirectional).
    Output { inverted: bool },
    /// Input capture of both edges (the answer).
    Capture,
}

/// Set CCMR1/2 and CCER of `count` channels from `first` (stopped or about to be reprogrammed):
/// CCxS may only change while the channel is disabled, so CCER is cleared first.
///
/// # Safety
/// `base` is a motor timer this task owns at the moment (see the module doc).
unsafe fn configure_channels(base: u32, first: u8, count: u8, mode: ChannelMode) {
    let mut ccmr = [0u32; 2];
    let mut ccer = 0u32;
    for channel in first..first + count {
        let channel = u32::from(channel);
        let (mode_bits, enable) = match mode {
            ChannelMode::Output { inverted } => {
                (tim::CCMR_PWM1_PRELOAD, tim::CCER_E | if inverted { tim::CCER_P } else { 0 })
            }
            ChannelMode::Capture => {
                (tim::CCMR_INPUT_FILTERED, tim::CCER_E | tim::CCER_P | tim::CCER_NP)
            }
        };
        let (register, shift) = tim::ccmr_register_and_shift(channel);
        ccmr[usize::from(register == tim::CCMR2)] |= mode_bits << shift;
        ccer |= enable << tim::ccer_shift(channel);
    }
    chip::write(base + tim::CCER, 0);
    chip::write(base + tim::CCMR1, ccmr[0]);
    chip::write(base + tim::CCMR2, ccmr[1]);
    chip::write(base + tim::CCER, ccer);
}

/// The burst task's half of one motor timer: on the burst stream's transfer-complete, switch
/// the timer's channels to capture the ESCs' answers (see the module doc). `Copy` register
/// addresses only; built by [`BoardMotors::completion`].
#[derive(Clone, Copy)]
pub struct BurstCompletion {
    index: usize,
    base: u32,
    burst: Dma,
    first: u8,
    count: u8,
    captures: [Option<Capture>; 4],
}

impl BurstCompletion {
    /// The interrupt's work: acknowledge the stream; stop the bit clock; channels to input
    /// capture of both edges, the counter free-running from 0 (16-bit: 273 µs at 240 MHz, longer
    /// than the answer's window); start each channel's capture DMA. A few dozen register writes.
    pub fn on_burst_complete(&self) {
        self.burst.clear_flags();
        let base = self.base;
        // SAFETY: the control task is done with this timer until its next step (module doc);
        // the capture buffers are DMA-reachable statics only the DMA writes until then.
        unsafe {
            chip::write(base + tim::DIER, 0);
            chip::write(base + tim::CR1, 0);
            configure_channels(base, self.first, 0, ChannelMode::Capture);
            chip::write(base + tim::ARR, 0xFFFF);
            chip::write(base + tim::CNT, 0);
            let captures = addr_of_mut!(CAPTURES) as *mut [u32; CAPTURE_EDGES];
            let mut requests = 0;
            for (slot, capture) in self.captures.iter().enumerate() {
                let Some(capture) = capture else { continue };
                let channel = u32::from(self.first) + slot as u32;
                let buffer = captures.add(usize::from(capture.motor));
                capture.dma.start(
                    base + tim::ccr(channel),
                    buffer as u32,
                    CAPTURE_EDGES as u16,
                    cr::PERIPHERAL_TO_MEMORY
                        | cr::MINC
                        | cr::PSIZE_32
                        | cr::MSIZE_32
                        | cr::PRIORITY_HIGH,
                );
                requests |= tim::dier_ccde(channel);
            }
            configure_channels(base, self.first, self.count, ChannelMode::Capture);
            chip::write(base + tim::SR, 0);
            chip::write(base + tim::DIER, requests);
            chip::write(base + tim::CR1, tim::CR1_CEN);
        }
        CAPTURING[self.index].store(true, Ordering::Release);
    }
}

/// One motor timer and its burst.
#[derive(Clone, Copy)]
struct BurstTimer {
    base: u32,
    dma: Dma,
    /// Channels in the burst: `first`..`first + count`.
    first: u8,
    count: u8,
    /// The answer capture of each burst slot (bidirectional DShot).
    captures: [Option<Capture>; 4],
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
    /// The ESCs answer with their eRPM (inverted frames, captures).
    bidirectional: bool,
    /// Timer ticks per answer bit (240 MHz / 750 kbit/s = 320).
    answer_bit_ticks: u32,
    pole_pairs: u8,
    telemetry: [MotorTelemetry; MAX_MOTORS],
}

impl BoardMotors {
    /// Set up the board's motor timers for DShot600 at `timer_clock_hz` (the APB1/APB2 timer
    /// kernel clock) and send motor-stop frames from the first step on; bidirectional when
    /// `bidirectional` (the `motor_bidir_dshot` parameter) and the board can capture.
    pub fn new(board: &BoardDescription, timer_clock_hz: u32, bidirectional: bool) -> Self {
        let bidirectional = bidirectional && board.motor_bidirectional;
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
            let mut captures = [None; 4];
            for output in board.motors.iter().filter(|o| o.timer == motor_timer.timer) {
                // Pulled up when bidirectional: the line idles high between frame and answer.
                chip::alternate(output.pin, bidirectional);
            }
            if bidirectional {
                for (m, output) in board.driven_motors().iter().enumerate() {
                    let request = info.channel_requests[usize::from(output.channel - 1)];
                    if output.timer == motor_timer.timer && request != 0 {
                        let dma = Dma::new(output.capture_dma);
                        dma.route(output.capture_dma, request);
                        captures[usize::from(output.channel - first)] =
                            Some(Capture { motor: m as u8, dma });
                    }
                }
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
                for channel in first..first + count {
                    chip::write(base + tim::ccr(u32::from(channel)), 0);
                }
                let inverted = bidirectional;
                configure_channels(base, first, count, ChannelMode::Output { inverted });
                // Burst: DBA = CCR`first` (register index 13 + first − 1), DBL = count − 1.
                let dba = (tim::CCR1 / 4) + u32::from(first - 1);
                chip::write(base + tim::DCR, (u32::from(count - 1) << tim::DCR_DBL_SHIFT) | dba);
                chip::write(base + tim::CNT, 0);
                chip::write(base + tim::EGR, tim::EGR_UG);
                chip::write(base + tim::CR1, tim::CR1_ARPE | tim::CR1_CEN);
            }
            let dma = Dma::new(motor_timer.dma);
            dma.route(motor_timer.dma, info.update_request);
            timers[index] =
                Some(BurstTimer { base, dma, first, count, captures, motors, buffer: index });
        }
        Self {
            timers,
            count: board.motor_count.min(MAX_MOTORS as u8),
            period_ticks,
            frames_sent: 0,
            special: CommandQueue::default(),
            bidirectional,
            answer_bit_ticks: u32::from(
                bit_period_ticks(timer_clock_hz, DSHOT600_TELEMETRY_BIT_RATE_HZ).unwrap_or(320),
            ),
            pole_pairs: board.motor_pole_pairs,
            telemetry: [MotorTelemetry::default(); MAX_MOTORS],
        }
    }

    /// The burst task's half of motor timer `index` (the order of the board's motor timers), if
    /// the ESCs answer (bidirectional DShot) and the timer exists.
    pub fn completion(&self, index: usize) -> Option<BurstCompletion> {
        let timer = self.timers.get(index).copied().flatten()?;
        self.bidirectional.then_some(BurstCompletion {
            index,
            base: timer.base,
            burst: timer.dma,
            first: timer.first,
            count: timer.count,
            captures: timer.captures,
        })
    }

    /// Take timer `timer`'s captured answers (if its channels captured since the last frame),
    /// decode them into the motors' speeds, and switch its channels back to output.
    fn take_answers(&mut self, index: usize, timer: &BurstTimer) {
        if !CAPTURING[index].swap(false, Ordering::Acquire) {
            return;
        }
        let base = timer.base;
        // SAFETY: the burst task switched this timer to capture 470 µs ago and is done with it
        // until the next burst completes (module doc).
        unsafe {
            chip::write(base + tim::DIER, 0);
            chip::write(base + tim::CR1, 0);
        }
        let captures = addr_of!(CAPTURES) as *const [u32; CAPTURE_EDGES];
        for capture in timer.captures.iter().flatten() {
            capture.dma.disable();
            let edges = (CAPTURE_EDGES as u32).saturating_sub(capture.dma.remaining()) as usize;
            // SAFETY: the stream is stopped: the DMA no longer writes this motor's buffer.
            let buffer = unsafe { &*captures.add(usize::from(capture.motor)) };
            let answer =
                telemetry_from_edges(&buffer[..edges.min(CAPTURE_EDGES)], self.answer_bit_ticks);
            if let Some(motor) = self.telemetry.get_mut(usize::from(capture.motor)) {
                motor.record(answer, self.pole_pairs);
            }
        }
        // SAFETY: as above; back to the frame's bit clock and PWM output.
        unsafe {
            configure_channels(
                base,
                timer.first,
                timer.count,
                ChannelMode::Output { inverted: true },
            );
            chip::write(base + tim::ARR, u32::from(self.period_ticks) - 1);
            chip::write(base + tim::CNT, 0);
            chip::write(base + tim::CR1, tim::CR1_ARPE | tim::CR1_CEN);
        }
    }

    /// Counters for `BoardHealth.motors`: frames sent, and per motor the answers decoded and
    /// those lost (no answer, cut short, bad GCR or checksum).
    pub fn link_health(&self) -> MotorLinkHealth {
        let counters = self.telemetry.map(|t| t.counters);
        MotorLinkHealth {
            motor_count: self.count,
            frames_sent: self.frames_sent,
            reports: counters.map(|c| c.frames_ok),
            report_errors: counters.map(|c| {
                c.crc_errors
                    .saturating_add(c.gcr_symbol_errors)
                    .saturating_add(c.timeouts)
                    .saturating_add(c.other_errors)
            }),
        }
    }
}

impl Motors for BoardMotors {
    fn count(&self) -> u8 {
        self.count
    }

    /// Special commands are refused while anything is armed, and a waiting one is dropped.
    fn set_armed(&mut self, armed: bool) {
        self.special.set_armed(armed);
    }

    fn health(&self) -> Option<MotorLinkHealth> {
        Some(self.link_health())
    }

    /// Send one frame to every motor output. Never blocks: the previous frame ended 470 µs ago.
    fn set_commands(&mut self, commands: &[f32]) {
        self.special.note_commands(commands);
        let period = self.period_ticks;
        let bidirectional = self.bidirectional;
        for index in 0..MAX_TIMERS {
            let Some(timer) = self.timers[index] else { continue };
            if bidirectional {
                self.take_answers(index, &timer);
            }
            let n = usize::from(timer.count);
            let mut values = [None; 4];
            for (slot, motor) in timer.motors.iter().enumerate().take(n) {
                values[slot] = motor.map(|m| {
                    let command = commands.get(usize::from(m)).copied().unwrap_or(0.0);
                    compare_values(self.special.frame(m, command, bidirectional), period)
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
                        | cr::PRIORITY_VERY_HIGH
                        // The completion switches the channels to capture the answers.
                        | if bidirectional { cr::TCIE } else { 0 },
                );
                chip::modify(timer.base + tim::DIER, 0, tim::DIER_UDE);
                // Restart the bit clock: this update requests the first burst at once.
                chip::write(timer.base + tim::EGR, tim::EGR_UG);
            }
        }
        self.frames_sent = self.frames_sent.wrapping_add(1);
        self.special.frame_sent();
    }

    fn esc_command_queue(&mut self) -> Option<&mut CommandQueue> {
        Some(&mut self.special)
    }

    /// Each motor's speed from its last answers (bidirectional DShot; `None` without, or when
    /// the answers went stale).
    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
        let mut speeds = [None; MAX_MOTORS];
        for (speed, motor) in speeds.iter_mut().zip(&self.telemetry).take(usize::from(self.count)) {
            *speed = motor.speed_rad_s();
        }
        speeds
    }
}
