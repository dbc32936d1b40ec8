//! DShot and bidirectional DShot framing: the pure encoding and decoding a timer + DMA motor
//! driver needs, without any timer or DMA code.
//!
//! Why here: the board's motor driver only has to start a DMA transfer of compare values and
//! capture the ESC's answer; everything that can be wrong in a bit (checksums, GCR, timing
//! arithmetic) lives in this file and is tested on the host.
//!
//! # Frame (flight controller → ESC)
//!
//! Sixteen bits, most significant first, as specified by the DShot protocol (Betaflight /
//! BLHeli_32 / KISS; the widely cited description is "DShot – the missing handbook",
//! brushlesswhoop.com):
//!
//! ```text
//!  15 ............ 5   4    3 .. 0
//! [ value (11 bits) ][ T ][ checksum ]
//! ```
//!
//! - `value`: 0 = motor stop / disarmed, 1..=47 special commands ([`DshotCommand`]),
//!   48..=2047 throttle (2000 steps).
//! - `T`: telemetry request bit.
//! - `checksum` over the 12 bits `v = value << 1 | T`: `(v ^ v >> 4 ^ v >> 8) & 0xF`. For
//!   bidirectional DShot the checksum is inverted: `!(v ^ v >> 4 ^ v >> 8) & 0xF`.
//!
//! On the wire each bit is one period of a PWM at the bit rate (DShot600: 600 kbit/s, 1.667 µs per
//! bit); a 1 is high for 75 % of the period, a 0 for 37.5 %. [`compare_values`] turns a frame into
//! the 16 timer compare values plus one trailing 0 that leaves the line idle after the frame.
//! Bidirectional DShot inverts the line (idle high): the board configures the timer output with
//! inverted polarity; the compare values are the same.
//!
//! # Telemetry (ESC → flight controller, bidirectional DShot only)
//!
//! About 30 µs after a bidirectional frame the ESC answers on the same wire at 5/4 of the DShot bit
//! rate (750 kbit/s for DShot600) with 21 line bits: a start bit (low) and 20 bits where each
//! GCR `1` is a level transition. `raw ^ (raw >> 1)` undoes that, giving 20 GCR bits = four 5-bit
//! quintets, each mapped back to a nibble ([`gcr_decode`]). The 16 bits are a 12-bit value and a
//! 4-bit checksum `!(v ^ v >> 4 ^ v >> 8) & 0xF`. Without extended telemetry (EDT, off by default)
//! the 12-bit value is the electrical period `mantissa (9 bits) << exponent (3 bits)` in µs, and
//! `eRPM = 60 000 000 / period_us` ([`erpm_from_telemetry`]); `0xFFF` means stopped.
//!
//! Turning captured samples into the 21 raw bits is the driver's job; [`raw_from_samples`] (a
//! buffer of line samples at a known oversampling) and [`raw_from_edges`] (edge timestamps) are
//! two simple decoders whose assumptions are documented on each.

pub use protocol::DshotCommand;

/// DShot600 bit rate, bit/s (the protocol's name is its rate in kbit/s).
pub const DSHOT600_BIT_RATE_HZ: u32 = 600_000;
/// DShot600 bit period, ns (1 / 600 kbit/s = 1.667 µs, rounded).
pub const DSHOT600_BIT_PERIOD_NS: u32 = 1_667;
/// DShot600 frame duration (16 bits), ns (16 × 1.667 µs = 26.7 µs, rounded).
pub const DSHOT600_FRAME_NS: u32 = 26_667;
/// Bidirectional telemetry bit rate for DShot600, bit/s: 5/4 of the DShot rate (750 kbit/s).
pub const DSHOT600_TELEMETRY_BIT_RATE_HZ: u32 = DSHOT600_BIT_RATE_HZ / 4 * 5;
/// Approximate delay between the end of a bidirectional frame and the ESC's answer, µs
/// (BLHeli_32 / Bluejay answer after about 30 µs; capture should start a little before).
pub const TELEMETRY_TURNAROUND_US: u32 = 30;
/// Number of line bits in the ESC's telemetry answer (start bit + 20 GCR bits).
pub const TELEMETRY_LINE_BITS: u32 = 21;

/// Motor stop / disarmed value.
pub const VALUE_MOTOR_STOP: u16 = 0;
/// Smallest throttle value (values below are special commands).
pub const THROTTLE_MIN: u16 = 48;
/// Largest throttle value (11 bits).
pub const THROTTLE_MAX: u16 = 2047;
/// Duty of a `1` bit, numerator over [`DUTY_DENOMINATOR`] (75 %).
pub const DUTY_ONE_NUMERATOR: u32 = 6;
/// Duty of a `0` bit, numerator over [`DUTY_DENOMINATOR`] (37.5 %).
pub const DUTY_ZERO_NUMERATOR: u32 = 3;
/// Common denominator of the duties (eighths of a bit period).
pub const DUTY_DENOMINATOR: u32 = 8;
/// Length of the DMA compare buffer: 16 bits plus two trailing 0s (line idle). A burst is
/// written one bit period before it takes effect (preloaded compare registers), so the
/// stream's transfer-complete comes one period before its last value is output: with two idle
/// values it comes after the frame's last data bit, when the outputs may switch to capture the
/// bidirectional answer.
pub const COMPARE_BUFFER_LEN: usize = 18;
/// Edge timestamps captured per motor and answer: the 21 line bits of an answer have at most 21
/// level changes, plus margin for glitches.
pub const CAPTURE_EDGES: usize = 32;
/// Failed answers in a row after which a motor's speed counts as unknown (2 ms at 2 kHz): a
/// single answer lost to a bit error keeps the last speed.
pub const STALE_ANSWERS: u8 = 4;
/// Telemetry value meaning "motor stopped" (the longest period the format can carry).
pub const TELEMETRY_STOPPED: u16 = 0x0FFF;

/// What can go wrong in DShot encoding and decoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DshotError {
    /// The 11-bit value was above 2047.
    ValueOutOfRange {
        /// The value given.
        value: u16,
    },
    /// A special command was requested while the motors are armed (refused: commands such as
    /// spin-direction changes or beeps must never reach a spinning motor).
    CommandWhileArmed {
        /// The command refused.
        command: DshotCommand,
    },
    /// A telemetry quintet was not one of the 16 GCR codes.
    GcrSymbol {
        /// The invalid 5-bit quintet.
        quintet: u8,
    },
    /// The telemetry checksum did not match.
    TelemetryCrc {
        /// The 16 decoded bits (12-bit value and 4-bit checksum).
        frame: u16,
    },
    /// No telemetry answer was found (no start bit in the capture, or too few edges).
    NoResponse,
    /// The capture ended inside the answer (fewer than 21 bits and the line not idle).
    Truncated {
        /// Bits recovered before the capture ended.
        bits: u8,
    },
    /// A timing parameter was zero or does not fit the timer (e.g. oversampling 0, period 0).
    BadTiming,
}

/// The 4-bit checksum of a 12-bit word `v` (value << 1 | telemetry bit): `(v ^ v>>4 ^ v>>8) & 0xF`,
/// inverted for bidirectional DShot.
pub const fn checksum(v12: u16, bidirectional: bool) -> u16 {
    let v = v12 & 0x0FFF;
    let crc = (v ^ (v >> 4) ^ (v >> 8)) & 0xF;
    if bidirectional {
        !crc & 0xF
    } else {
        crc
    }
}

/// Encode an 11-bit value (0 = stop, 1..=47 command, 48..=2047 throttle) into a 16-bit frame.
pub fn encode_frame(value: u16, telemetry: bool, bidirectional: bool) -> Result<u16, DshotError> {
    if value > THROTTLE_MAX {
        return Err(DshotError::ValueOutOfRange { value });
    }
    let v12 = (value << 1) | u16::from(telemetry);
    Ok((v12 << 4) | checksum(v12, bidirectional))
}

/// The motor-stop frame (value 0). Always allowed, armed or not.
pub const fn motor_stop_frame(bidirectional: bool) -> u16 {
    // v12 = 0: the checksum is 0, or 0xF when inverted.
    checksum(0, bidirectional)
}

/// Map a normalised command δ ∈ [0, 1] to a throttle value 48..=2047 (clamped; NaN gives the
/// minimum throttle 48, i.e. the motor keeps idling rather than stopping mid-air).
pub fn throttle_value(command: f32) -> u16 {
    if command.is_nan() {
        return THROTTLE_MIN;
    }
    let clamped = command.clamp(0.0, 1.0);
    let span = f32::from(THROTTLE_MAX - THROTTLE_MIN);
    // Round to nearest; the result is within 0..=span, so the cast cannot truncate.
    let steps = (clamped * span + 0.5) as u16;
    THROTTLE_MIN + steps.min(THROTTLE_MAX - THROTTLE_MIN)
}

/// Encode a throttle frame from a normalised command δ ∈ [0, 1] (see [`throttle_value`]).
pub fn throttle_frame(command: f32, telemetry: bool, bidirectional: bool) -> u16 {
    let value = throttle_value(command);
    let v12 = (value << 1) | u16::from(telemetry);
    (v12 << 4) | checksum(v12, bidirectional)
}

/// The frame a motor output sends for the application's command δ: motor stop (value 0) for
/// δ ≤ 0 (the application writes exactly 0 to every motor when nothing is armed, and ESCs only
/// arm on stop frames), otherwise [`throttle_frame`] (48..=2047; NaN idles at 48, see
/// [`throttle_value`]). Telemetry bit clear.
pub fn output_frame(command: f32, bidirectional: bool) -> u16 {
    if command <= 0.0 {
        motor_stop_frame(bidirectional)
    } else {
        throttle_frame(command, false, bidirectional)
    }
}

/// Encode a special command, refusing it while armed. Settings commands get the telemetry bit
/// set as the specification requires; the caller repeats the frame
/// [`DshotCommand::min_repeats`] times.
pub fn command_frame(
    command: DshotCommand,
    armed: bool,
    bidirectional: bool,
) -> Result<u16, DshotError> {
    if armed {
        return Err(DshotError::CommandWhileArmed { command });
    }
    encode_frame(command.value(), command.changes_settings(), bidirectional)
}

/// A special command waiting to be sent: command, motor (`None` = all), frames still to send.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PendingCommand {
    command: DshotCommand,
    motor: Option<u8>,
    repeats: u8,
}

/// The special command a motor output sends instead of its stop frames, for as many frames as
/// the specification asks ([`DshotCommand::min_repeats`]): one at a time, refused while armed
/// and dropped when the motors arm. The board's motor driver and the simulator's ESCs share it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CommandQueue {
    pending: Option<PendingCommand>,
    armed: bool,
    /// A motor was commanded above zero since the outputs were armed: from then on until they
    /// disarm, δ ≤ 0 idles a motor at the minimum throttle (value 48) instead of stopping it. A
    /// motor the allocation sets to zero in flight keeps turning: an ESC restarting a stopped
    /// motor mid-air takes tens of milliseconds and can lose sync. Before the first command
    /// (armed and waiting for the throw, in the hand) every motor stays stopped.
    spinning: bool,
}

impl CommandQueue {
    /// Tell the queue whether the motors are armed (a waiting command is dropped when they are).
    pub fn set_armed(&mut self, armed: bool) {
        self.armed = armed;
        if armed {
            self.pending = None;
        } else {
            self.spinning = false;
        }
    }

    /// The application's commands for this frame: the first one above zero while armed starts
    /// the idle-instead-of-stop rule (see [`CommandQueue::frame`]).
    pub fn note_commands(&mut self, commands: &[f32]) {
        if self.armed && commands.iter().any(|&c| c > 0.0) {
            self.spinning = true;
        }
    }

    /// Whether δ ≤ 0 idles the motors rather than stopping them (armed, and commanded above zero
    /// since).
    pub fn spinning(&self) -> bool {
        self.spinning
    }

    /// Queue `command` for `motor` (`None` = every motor), replacing any command still waiting.
    /// Refused while armed.
    pub fn queue(&mut self, command: DshotCommand, motor: Option<u8>) -> Result<(), DshotError> {
        command_frame(command, self.armed, false)?;
        self.pending = Some(PendingCommand { command, motor, repeats: command.min_repeats() });
        Ok(())
    }

    /// The command waiting and its motor (`None` = all), if any.
    pub fn pending(&self) -> Option<(DshotCommand, Option<u8>)> {
        self.pending.map(|p| (p.command, p.motor))
    }

    /// The frame `motor` sends this step for the application's command δ: the waiting special
    /// command while its motor stops (δ ≤ 0, nothing armed); the minimum throttle (idle) for
    /// δ ≤ 0 or NaN once the motors spin (armed and commanded above zero since); otherwise
    /// [`output_frame`].
    pub fn frame(&self, motor: u8, command: f32, bidirectional: bool) -> u16 {
        match self.pending {
            Some(p) if !self.armed && command <= 0.0 && p.motor.is_none_or(|m| m == motor) => {
                command_frame(p.command, false, bidirectional)
                    .unwrap_or_else(|_| motor_stop_frame(bidirectional))
            }
            _ if self.spinning && (command <= 0.0 || command.is_nan()) => {
                throttle_frame(0.0, false, bidirectional)
            }
            _ => output_frame(command, bidirectional),
        }
    }

    /// One frame went to every motor: one repeat fewer.
    pub fn frame_sent(&mut self) {
        if let Some(pending) = &mut self.pending {
            pending.repeats = pending.repeats.saturating_sub(1);
            if pending.repeats == 0 {
                self.pending = None;
            }
        }
    }
}

/// Timer ticks per DShot bit for a timer clock and bit rate, rounded to nearest
/// (e.g. 240 MHz / 600 kbit/s = 400 ticks). Errors if the rate is 0 or the period does not fit
/// a 16-bit compare register or is too short to tell 37.5 % from 75 % (under 8 ticks).
pub fn bit_period_ticks(timer_clock_hz: u32, bit_rate_hz: u32) -> Result<u16, DshotError> {
    if bit_rate_hz == 0 {
        return Err(DshotError::BadTiming);
    }
    let ticks = (u64::from(timer_clock_hz) + u64::from(bit_rate_hz) / 2) / u64::from(bit_rate_hz);
    match u16::try_from(ticks) {
        Ok(t) if t >= 8 => Ok(t),
        _ => Err(DshotError::BadTiming),
    }
}

/// Compare value of a `1` bit (75 % of the period, rounded to nearest tick).
pub const fn duty_one_ticks(period_ticks: u16) -> u16 {
    ((period_ticks as u32 * DUTY_ONE_NUMERATOR + DUTY_DENOMINATOR / 2) / DUTY_DENOMINATOR) as u16
}

/// Compare value of a `0` bit (37.5 % of the period, rounded to nearest tick).
pub const fn duty_zero_ticks(period_ticks: u16) -> u16 {
    ((period_ticks as u32 * DUTY_ZERO_NUMERATOR + DUTY_DENOMINATOR / 2) / DUTY_DENOMINATOR) as u16
}

/// The DMA buffer for one frame: 16 compare values, most significant bit first, then a 0 that
/// keeps the line idle once the frame is out.
pub fn compare_values(frame: u16, period_ticks: u16) -> [u16; COMPARE_BUFFER_LEN] {
    let one = duty_one_ticks(period_ticks);
    let zero = duty_zero_ticks(period_ticks);
    let mut out = [0u16; COMPARE_BUFFER_LEN];
    for (i, slot) in out.iter_mut().take(16).enumerate() {
        let bit = (frame >> (15 - i)) & 1;
        *slot = if bit == 1 { one } else { zero };
    }
    out
}

/// GCR quintet → nibble, indexed by the quintet; 0xFF marks the 16 invalid quintets.
/// (Bidirectional DShot GCR table, as in Betaflight `dshot.c` / the BLHeli_32 specification.)
const GCR_DECODE: [u8; 32] = {
    let mut t = [0xFFu8; 32];
    t[0x19] = 0x0;
    t[0x1B] = 0x1;
    t[0x12] = 0x2;
    t[0x13] = 0x3;
    t[0x1D] = 0x4;
    t[0x15] = 0x5;
    t[0x16] = 0x6;
    t[0x17] = 0x7;
    t[0x1A] = 0x8;
    t[0x09] = 0x9;
    t[0x0A] = 0xA;
    t[0x0B] = 0xB;
    t[0x1E] = 0xC;
    t[0x0D] = 0xD;
    t[0x0E] = 0xE;
    t[0x0F] = 0xF;
    t
};

/// Decode the ESC's 21 raw line bits (start bit in bit 20, last bit in bit 0; either polarity)
/// into the 12-bit telemetry value, checking GCR symbols and the checksum.
///
/// Steps: `gcr = (raw ^ raw >> 1) & 0xFFFFF` (a transition is a 1), four quintets (first in
/// bits 19..15) → nibbles, 16 bits = value (12) << 4 | checksum (4), checksum
/// `!(v ^ v>>4 ^ v>>8) & 0xF`. Bits above bit 20 are ignored.
///
/// Limitation of the format (not of this decoder): GCR plus a 4-bit XOR checksum does not
/// catch every single line-bit error; a flip at a quintet boundary can turn e.g. the nibble
/// pair (8, 0) into (1, 9), which has the same checksum.
pub fn gcr_decode(raw21: u32) -> Result<u16, DshotError> {
    let raw = raw21 & 0x1F_FFFF;
    let gcr = (raw ^ (raw >> 1)) & 0xF_FFFF;
    let mut frame: u16 = 0;
    for q in 0..4 {
        let shift = 15 - 5 * q;
        // Masked to 5 bits: fits u8 and indexes the 32-entry table.
        let quintet = ((gcr >> shift) & 0x1F) as u8;
        let nibble = GCR_DECODE[usize::from(quintet)];
        if nibble > 0xF {
            return Err(DshotError::GcrSymbol { quintet });
        }
        frame = (frame << 4) | u16::from(nibble);
    }
    let value = frame >> 4;
    let v = value;
    let expected = !(v ^ (v >> 4) ^ (v >> 8)) & 0xF;
    if frame & 0xF != expected {
        return Err(DshotError::TelemetryCrc { frame });
    }
    Ok(value)
}

/// Electrical period in µs of a 12-bit telemetry value: `mantissa (bits 8..0) << exponent
/// (bits 11..9)`.
pub const fn eperiod_us(value12: u16) -> u32 {
    let mantissa = (value12 & 0x1FF) as u32;
    let exponent = ((value12 >> 9) & 0x7) as u32;
    mantissa << exponent
}

/// Electrical RPM from a 12-bit telemetry value: `60 000 000 / period_us` rounded; 0 for the
/// "stopped" value 0xFFF and for a zero period.
pub const fn erpm_from_telemetry(value12: u16) -> u32 {
    if value12 & 0x0FFF == TELEMETRY_STOPPED {
        return 0;
    }
    let period = eperiod_us(value12);
    if period == 0 {
        return 0;
    }
    (60_000_000 + period / 2) / period
}

/// Mechanical speed in rad/s from electrical RPM: `eRPM / pole_pairs · 2π / 60`. Zero pole pairs
/// gives 0 (no division by zero).
pub fn mechanical_rad_s(erpm: u32, pole_pairs: u8) -> f32 {
    if pole_pairs == 0 {
        return 0.0;
    }
    erpm as f32 / f32::from(pole_pairs) * (2.0 * core::f32::consts::PI / 60.0)
}

/// Accumulates runs of line levels into the 21-bit raw value (first bit into bit 20).
struct RunBuilder {
    raw: u32,
    bits: u32,
}

impl RunBuilder {
    const fn new() -> Self {
        Self { raw: 0, bits: 0 }
    }

    /// Append `count` bits at `level`; extra bits past 21 are dropped.
    fn push_run(&mut self, level: bool, count: u32) {
        // One shift for the whole run (n ≤ 21, so neither shift reaches 32): a bit at a time
        // cost 90 more instructions per answer (`bench-m7`: 8 answers 4,775 → 4,052).
        let n = count.min(TELEMETRY_LINE_BITS - self.bits);
        let ones = if level { (1u32 << n) - 1 } else { 0 };
        self.raw = (self.raw << n) | ones;
        self.bits += n;
    }

    fn full(&self) -> bool {
        self.bits >= TELEMETRY_LINE_BITS
    }

    /// Finish: if the last level was high (idle), the line stays high, so pad with 1s; a frame
    /// that ends while the line is low is truncated.
    fn finish(mut self, last_level: bool) -> Result<u32, DshotError> {
        if !self.full() {
            if last_level && self.bits > 0 {
                self.push_run(true, TELEMETRY_LINE_BITS);
            } else {
                return Err(DshotError::Truncated { bits: self.bits as u8 });
            }
        }
        Ok(self.raw)
    }
}

/// Run length in samples → bits, rounded to nearest, at least one bit.
fn run_bits(run: u32, per_bit: u32) -> u32 {
    (run.saturating_add(per_bit / 2) / per_bit).max(1)
}

/// Rebuild the 21 raw line bits from a buffer of captured line samples.
///
/// Assumptions (keep the capture simple and these hold):
/// - `samples` holds one line sample per bit, packed most significant bit first into each word
///   (`samples[0]` bit 31 is the oldest sample), 1 = line high. The line idles high
///   (bidirectional DShot, pulled up), so the answer starts with the first low sample.
/// - `samples_per_bit` is the oversampling: samples per telemetry bit (e.g. 3 at 2.25 MHz for
///   DShot600's 750 kbit/s answer). It is assumed constant over the 28 µs answer; each run of
///   equal samples is rounded to the nearest whole number of bits.
/// - After the last transition the line returns to idle high, so missing trailing bits are 1s.
///
/// Returns the raw value for [`gcr_decode`], [`DshotError::NoResponse`] if no low sample is
/// found, or [`DshotError::Truncated`] if the buffer ends while the line is low.
pub fn raw_from_samples(samples: &[u32], samples_per_bit: u32) -> Result<u32, DshotError> {
    if samples_per_bit == 0 {
        return Err(DshotError::BadTiming);
    }
    let mut iter = samples.iter().flat_map(|&w| (0..32).rev().map(move |b| (w >> b) & 1 == 1));
    // Find the start bit (first low sample).
    if !iter.by_ref().any(|level| !level) {
        return Err(DshotError::NoResponse);
    }
    let mut builder = RunBuilder::new();
    let mut level = false;
    let mut run: u32 = 1;
    for sample in iter {
        if sample == level {
            run = run.saturating_add(1);
            continue;
        }
        builder.push_run(level, run_bits(run, samples_per_bit));
        if builder.full() {
            return Ok(builder.raw);
        }
        level = sample;
        run = 1;
    }
    // The buffer ended inside a run: a low run that ends with the buffer is truncated; a high run
    // is the idle tail (or its start), counted as far as it was seen and padded by `finish`.
    if level {
        builder.push_run(level, run_bits(run, samples_per_bit));
    }
    builder.finish(level)
}

/// Rebuild the 21 raw line bits from edge timestamps (e.g. input-capture values of both edges).
///
/// Assumptions: `edges_ticks[0]` is the falling edge of the start bit; the edges alternate
/// (falling, rising, falling, ...); timestamps are in timer ticks of a free-running counter that
/// may wrap (differences use wrapping arithmetic); `bit_ticks` is the telemetry bit period in
/// the same ticks. The line is high after the last edge, so missing trailing bits are 1s. A last
/// edge that is falling (line left low) gives [`DshotError::Truncated`].
pub fn raw_from_edges(edges_ticks: &[u32], bit_ticks: u32) -> Result<u32, DshotError> {
    if bit_ticks == 0 {
        return Err(DshotError::BadTiming);
    }
    if edges_ticks.len() < 2 {
        return Err(DshotError::NoResponse);
    }
    let mut builder = RunBuilder::new();
    let mut level = false;
    for pair in edges_ticks.windows(2) {
        let run = pair[1].wrapping_sub(pair[0]);
        builder.push_run(level, run_bits(run, bit_ticks));
        if builder.full() {
            return Ok(builder.raw);
        }
        level = !level;
    }
    builder.finish(level)
}

/// The 12-bit telemetry value of one answer from its edge timestamps ([`raw_from_edges`], then
/// [`gcr_decode`] with its checksum).
pub fn telemetry_from_edges(edges_ticks: &[u32], bit_ticks: u32) -> Result<u16, DshotError> {
    gcr_decode(raw_from_edges(edges_ticks, bit_ticks)?)
}

/// Most edges an answer can have: the start bit's falling edge, one per GCR 1 (at most 20) and
/// the return to idle high.
pub const ANSWER_MAX_EDGES: usize = 22;

/// The ESC's side: the 21 raw line bits of an answer carrying `value12` (checksum added, GCR
/// encoded, each GCR 1 a level change, start bit low in bit 20), the inverse of [`gcr_decode`].
/// For host tests, the Cortex-M7 bench and simulated ESCs; the firmware only decodes.
pub fn answer_raw(value12: u16) -> u32 {
    /// Nibble → GCR quintet (the protocol's table; [`gcr_decode`] holds its inverse).
    const GCR_ENCODE: [u32; 16] = [
        0x19, 0x1B, 0x12, 0x13, 0x1D, 0x15, 0x16, 0x17, 0x1A, 0x09, 0x0A, 0x0B, 0x1E, 0x0D, 0x0E,
        0x0F,
    ];
    let v = value12 & 0xFFF;
    let frame = (v << 4) | (!(v ^ (v >> 4) ^ (v >> 8)) & 0xF);
    let gcr = (0..4)
        .fold(0u32, |gcr, k| (gcr << 5) | GCR_ENCODE[usize::from((frame >> (12 - 4 * k)) & 0xF)]);
    let mut level = 0u32; // the start bit
    let mut raw = level;
    for i in (0..20).rev() {
        level ^= (gcr >> i) & 1;
        raw = (raw << 1) | level;
    }
    raw
}

/// The edge timestamps an input capture records for the answer carrying `value12`
/// ([`answer_raw`]): the start bit's falling edge at tick `t0`, one edge per level change at the
/// bit boundaries (`bit_ticks` per bit, wrapping like a free-running timer), and the return to
/// idle high after the last bit when the line was left low. Returns the buffer and how many
/// edges it holds; [`raw_from_edges`] is its inverse.
pub fn answer_edges(value12: u16, t0: u32, bit_ticks: u32) -> ([u32; ANSWER_MAX_EDGES], usize) {
    let raw = answer_raw(value12);
    let mut edges = [0u32; ANSWER_MAX_EDGES];
    edges[0] = t0;
    let mut n = 1;
    let mut level = 0; // the start bit
    for i in (0..20).rev() {
        let bit = (raw >> i) & 1;
        if bit != level {
            edges[n] = t0.wrapping_add((20 - i) * bit_ticks);
            n += 1;
            level = bit;
        }
    }
    if level == 0 {
        // Back to idle high after the last bit.
        edges[n] = t0.wrapping_add(21 * bit_ticks);
        n += 1;
    }
    (edges, n)
}

/// One motor's speed from its bidirectional answers, with their counters.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MotorTelemetry {
    pub counters: MotorTelemetryCounters,
    speed_rad_s: f32,
    /// Failed answers since the last good one ([`STALE_ANSWERS`] or more: unknown).
    failed_in_a_row: u8,
    /// Whether any answer was good yet.
    heard: bool,
}

impl MotorTelemetry {
    /// Take one answer's outcome (a telemetry value or why there was none) for a motor with
    /// `pole_pairs` pole pairs.
    pub fn record(&mut self, answer: Result<u16, DshotError>, pole_pairs: u8) {
        self.counters.record(&answer);
        match answer {
            Ok(value) => {
                self.speed_rad_s = mechanical_rad_s(erpm_from_telemetry(value), pole_pairs);
                self.failed_in_a_row = 0;
                self.heard = true;
            }
            Err(_) => self.failed_in_a_row = self.failed_in_a_row.saturating_add(1),
        }
    }

    /// The motor's speed, rad/s: the last good answer's, unless [`STALE_ANSWERS`] answers
    /// in a row failed since (or none was good yet).
    pub fn speed_rad_s(&self) -> Option<f32> {
        (self.heard && self.failed_in_a_row < STALE_ANSWERS).then_some(self.speed_rad_s)
    }
}

/// Telemetry error and success counters for one motor.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MotorTelemetryCounters {
    /// Answers decoded with a valid checksum.
    pub frames_ok: u32,
    /// Answers with valid GCR symbols but a wrong checksum.
    pub crc_errors: u32,
    /// Answers with an invalid GCR quintet.
    pub gcr_symbol_errors: u32,
    /// No answer, or an answer cut short.
    pub timeouts: u32,
    /// Anything else (bad timing parameters).
    pub other_errors: u32,
}

impl MotorTelemetryCounters {
    /// Count the outcome of one telemetry decode.
    pub fn record(&mut self, result: &Result<u16, DshotError>) {
        let counter = match result {
            Ok(_) => &mut self.frames_ok,
            Err(DshotError::TelemetryCrc { .. }) => &mut self.crc_errors,
            Err(DshotError::GcrSymbol { .. }) => &mut self.gcr_symbol_errors,
            Err(DshotError::NoResponse | DshotError::Truncated { .. }) => &mut self.timeouts,
            Err(_) => &mut self.other_errors,
        };
        *counter = counter.saturating_add(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent reference encoder: sum of the three nibbles' XOR, written bit by bit.
    fn reference_frame(value: u16, telemetry: bool, bidirectional: bool) -> u16 {
        let mut bits = [0u8; 12];
        for (i, b) in bits.iter_mut().enumerate().take(11) {
            *b = ((value >> (10 - i)) & 1) as u8;
        }
        bits[11] = u8::from(telemetry);
        let nibble = |k: usize| -> u8 { (0..4).fold(0u8, |acc, j| (acc << 1) | bits[4 * k + j]) };
        let mut crc = nibble(0) ^ nibble(1) ^ nibble(2);
        if bidirectional {
            crc = 0xF - crc;
        }
        let mut word: u16 = 0;
        for &b in &bits {
            word = word * 2 + u16::from(b);
        }
        word * 16 + u16::from(crc)
    }

    #[test]
    fn pinned_frames() {
        assert_eq!(encode_frame(0, false, false), Ok(0x0000));
        // 48 → v = 0x060 → crc 0 ^ 6 ^ 0 = 6.
        assert_eq!(encode_frame(48, false, false), Ok(0x0606));
        // The handbook example: 1046 without telemetry = 1000001011000110.
        assert_eq!(encode_frame(1046, false, false), Ok(0b1000_0010_1100_0110));
        assert_eq!(encode_frame(1046, false, false), Ok(0x82C6));
        assert_eq!(encode_frame(2047, true, false), Ok(0xFFFF));
        assert_eq!(motor_stop_frame(false), 0x0000);
        assert_eq!(motor_stop_frame(true), 0x000F);
    }

    #[test]
    fn frames_match_reference_for_all_values() {
        for value in 0..=THROTTLE_MAX {
            for telemetry in [false, true] {
                for bidir in [false, true] {
                    assert_eq!(
                        encode_frame(value, telemetry, bidir),
                        Ok(reference_frame(value, telemetry, bidir)),
                        "value {value} tlm {telemetry} bidir {bidir}"
                    );
                }
            }
        }
        assert_eq!(
            encode_frame(2048, false, false),
            Err(DshotError::ValueOutOfRange { value: 2048 })
        );
    }

    #[test]
    fn bidirectional_checksum_is_inverted() {
        // 1046: normal crc 6, inverted 9.
        assert_eq!(encode_frame(1046, false, true), Ok(0x82C9));
        assert_eq!(encode_frame(48, false, true), Ok(0x0609));
        for value in [0u16, 1, 47, 48, 1000, 2047] {
            let n = encode_frame(value, true, false).unwrap_or(0);
            let b = encode_frame(value, true, true).unwrap_or(0);
            assert_eq!(n & 0xFFF0, b & 0xFFF0);
            assert_eq!((n ^ b) & 0xF, 0xF);
        }
    }

    #[test]
    fn throttle_mapping() {
        assert_eq!(throttle_value(0.0), 48);
        assert_eq!(throttle_value(1.0), 2047);
        assert_eq!(throttle_value(0.5), 1048); // 48 + 999.5 rounded
        assert_eq!(throttle_value(-3.0), 48);
        assert_eq!(throttle_value(7.0), 2047);
        assert_eq!(throttle_value(f32::NAN), 48);
        assert_eq!(throttle_value(f32::INFINITY), 2047);
        assert_eq!(throttle_frame(1.0, true, false), 0xFFFF);
    }

    #[test]
    fn output_frames_stop_at_zero_and_throttle_above() {
        assert_eq!(output_frame(0.0, false), 0x0000);
        assert_eq!(output_frame(-1.0, false), 0x0000);
        assert_eq!(output_frame(0.0, true), 0x000F);
        assert_eq!(output_frame(1.0, false), throttle_frame(1.0, false, false));
        assert_eq!(output_frame(1e-6, false) >> 5, THROTTLE_MIN);
        assert_eq!(output_frame(f32::NAN, false) >> 5, THROTTLE_MIN);
    }

    #[test]
    fn commands_refused_while_armed() {
        assert_eq!(
            command_frame(DshotCommand::Beep1, true, false),
            Err(DshotError::CommandWhileArmed { command: DshotCommand::Beep1 })
        );
        // Beep1 = 1, no telemetry bit: v = 2, crc 2.
        assert_eq!(command_frame(DshotCommand::Beep1, false, false), Ok(0x0022));
        // SaveSettings = 12 with telemetry bit: v = 25 = 0x019, crc = 9 ^ 1 = 8.
        assert_eq!(command_frame(DshotCommand::SaveSettings, false, false), Ok((25 << 4) | 8));
        assert_eq!(DshotCommand::SaveSettings.min_repeats(), 6);
        assert_eq!(DshotCommand::Beep3.min_repeats(), 1);
    }

    /// A beep goes to its motor alone, once; a save to every motor, six frames with the
    /// telemetry bit; the other motors keep their stop frames; nothing is queued while armed,
    /// and arming drops what waits.
    #[test]
    fn the_command_queue_sends_each_command_as_often_as_the_specification_asks() {
        let stop = motor_stop_frame(false);
        let mut queue = CommandQueue::default();
        queue.queue(DshotCommand::Beep1, Some(2)).unwrap();
        let frames: [u16; 4] = core::array::from_fn(|m| queue.frame(m as u8, 0.0, false));
        assert_eq!(frames, [stop, stop, 0x0022, stop]);
        queue.frame_sent();
        assert_eq!(queue.frame(2, 0.0, false), stop, "one beep frame only");
        queue.queue(DshotCommand::SaveSettings, None).unwrap();
        let mut saves = 0;
        while queue.frame(0, 0.0, false) == (25 << 4) | 8 {
            assert_eq!(queue.frame(3, 0.0, false), (25 << 4) | 8);
            saves += 1;
            queue.frame_sent();
        }
        assert_eq!(saves, 6);
        // A motor with a throttle command (a motor test) keeps its throttle frame.
        queue.queue(DshotCommand::Beep2, None).unwrap();
        assert_eq!(queue.frame(1, 0.5, false), throttle_frame(0.5, false, false));
        queue.set_armed(true);
        assert_eq!(queue.pending(), None);
        assert_eq!(
            queue.queue(DshotCommand::Beep1, Some(0)),
            Err(DshotError::CommandWhileArmed { command: DshotCommand::Beep1 })
        );
        assert_eq!(queue.frame(0, 0.0, false), stop);
    }

    #[test]
    fn duty_values() {
        // 240 MHz timer: 400 ticks per DShot600 bit; 1 → 300 (75 %), 0 → 150 (37.5 %).
        assert_eq!(bit_period_ticks(240_000_000, DSHOT600_BIT_RATE_HZ), Ok(400));
        assert_eq!(bit_period_ticks(200_000_000, DSHOT600_BIT_RATE_HZ), Ok(333));
        assert_eq!(bit_period_ticks(1_000, DSHOT600_BIT_RATE_HZ), Err(DshotError::BadTiming));
        assert_eq!(bit_period_ticks(240_000_000, 0), Err(DshotError::BadTiming));
        assert_eq!(bit_period_ticks(u32::MAX, 1), Err(DshotError::BadTiming));
        assert_eq!(duty_one_ticks(400), 300);
        assert_eq!(duty_zero_ticks(400), 150);
        // 333 ticks: 249.75 → 250, 124.875 → 125.
        assert_eq!(duty_one_ticks(333), 250);
        assert_eq!(duty_zero_ticks(333), 125);
        let buf = compare_values(0x82C6, 400);
        let expected_bits = [1, 0, 0, 0, 0, 0, 1, 0, 1, 1, 0, 0, 0, 1, 1, 0];
        for (i, &bit) in expected_bits.iter().enumerate() {
            assert_eq!(buf[i], if bit == 1 { 300 } else { 150 }, "bit {i}");
        }
        assert_eq!(buf[16], 0);
        assert_eq!(DSHOT600_TELEMETRY_BIT_RATE_HZ, 750_000);
        // 1 / 600 kHz = 1666.67 ns.
        assert_eq!(1_000_000_000 / DSHOT600_BIT_RATE_HZ, 1_666);
        assert_eq!(DSHOT600_BIT_PERIOD_NS, 1_667);
    }

    #[test]
    fn gcr_round_trip_all_values() {
        for value in 0..=0xFFFu16 {
            let raw = answer_raw(value);
            assert_eq!(gcr_decode(raw), Ok(value), "value {value:#x}");
            // Inverted line polarity decodes the same.
            assert_eq!(gcr_decode(!raw & 0x1F_FFFF), Ok(value));
        }
    }

    #[test]
    fn gcr_invalid_symbol_and_crc() {
        // All-ones line (idle, no transitions): quintets 00000 are invalid.
        assert_eq!(gcr_decode(0x1F_FFFF), Err(DshotError::GcrSymbol { quintet: 0 }));
        // Valid symbols but wrong checksum: flip one checksum nibble to another valid symbol.
        // Value 0x000 → frame 0x000F. Build raw with crc nibble 0xE instead.
        let gcr: u32 = (0x19 << 15) | (0x19 << 10) | (0x19 << 5) | 0x0E;
        let mut level = 0;
        let mut raw = 0u32;
        for i in (0..20).rev() {
            level ^= (gcr >> i) & 1;
            raw = (raw << 1) | level;
        }
        assert_eq!(gcr_decode(raw), Err(DshotError::TelemetryCrc { frame: 0x000E }));
    }

    /// Whether every single line-bit flip of `value`'s answer is rejected.
    fn all_flips_rejected(value: u16) -> bool {
        let raw = answer_raw(value);
        (0..21).all(|bit| gcr_decode(raw ^ (1 << bit)).is_err())
    }

    #[test]
    fn single_bit_errors_detected() {
        // Typical hover-to-full-speed periods and the stopped value.
        let values = [0xFFFu16, 0x000, 0x123, 0x2A5, 0x3FF, 0x5C3, 0x6E7, 0x7AB, 0x9D4, 0xB62];
        for value in values {
            let raw = answer_raw(value);
            for bit in 0..21 {
                let result = gcr_decode(raw ^ (1 << bit));
                assert!(
                    matches!(
                        result,
                        Err(DshotError::GcrSymbol { .. } | DshotError::TelemetryCrc { .. })
                    ),
                    "value {value:#x} bit {bit}: {result:?}"
                );
            }
        }
    }

    #[test]
    fn single_bit_error_blind_spot_is_a_format_limitation() {
        // Nibbles (8, 0) at a quintet boundary: 11010|11001. Flipping the line bit between them
        // flips GCR bits 0 of the first and 4 of the second quintet: 11011|01001 = (1, 9). Both
        // change the XOR by 9, so the checksum still matches: the format cannot see it.
        let value = 0x80A; // nibbles 8, 0, A
        assert!(!all_flips_rejected(value));
        // Most values have no blind spot.
        assert!(all_flips_rejected(0x2A5));
    }

    #[test]
    fn erpm_and_mechanical_speed() {
        // Period 1000 µs = mantissa 250, exponent 2 (250 << 2): 60 000 eRPM.
        let value = (2 << 9) | 250;
        assert_eq!(eperiod_us(value), 1000);
        assert_eq!(erpm_from_telemetry(value), 60_000);
        assert_eq!(erpm_from_telemetry(TELEMETRY_STOPPED), 0);
        assert_eq!(erpm_from_telemetry(0), 0);
        // 70 000 eRPM with 14 poles (7 pairs) = 10 000 mechanical RPM = 1047.198 rad/s.
        let w = mechanical_rad_s(70_000, 7);
        assert!((w - 1_047.197_6).abs() < 1e-2, "{w}");
        assert_eq!(mechanical_rad_s(70_000, 0), 0.0);
        // Through the whole chain: 60 000 eRPM / 7 pairs.
        let raw = answer_raw(value);
        let erpm = gcr_decode(raw).map(erpm_from_telemetry);
        assert_eq!(erpm, Ok(60_000));
        let w = mechanical_rad_s(60_000, 7);
        assert!((w - 897.597_9).abs() < 1e-2, "{w}");
    }

    /// Pack a line-level raw value into samples: `idle_before` high samples, then each of the 21
    /// bits `per_bit` times, then high idle, MSB first into words.
    fn to_samples(raw: u32, per_bit: u32, idle_before: u32, words: usize) -> [u32; 8] {
        let mut out = [u32::MAX; 8];
        let mut n = 0usize;
        let mut put = |level: bool| {
            let word = n / 32;
            let bit = 31 - (n % 32) as u32;
            if word < words {
                if level {
                    out[word] |= 1 << bit;
                } else {
                    out[word] &= !(1 << bit);
                }
            }
            n += 1;
        };
        for _ in 0..idle_before {
            put(true);
        }
        for i in (0..21).rev() {
            for _ in 0..per_bit {
                put((raw >> i) & 1 == 1);
            }
        }
        out
    }

    #[test]
    fn samples_to_raw_round_trip() {
        for value in [0x000u16, 0x123, 0x2A5, 0x5C3, 0xFFF, 0x80A] {
            let raw = answer_raw(value);
            for per_bit in [3u32, 4, 5] {
                let samples = to_samples(raw, per_bit, 7, 8);
                let rebuilt = raw_from_samples(&samples, per_bit);
                assert_eq!(rebuilt, Ok(raw), "value {value:#x} x{per_bit}");
                assert_eq!(rebuilt.and_then(gcr_decode), Ok(value));
            }
        }
    }

    #[test]
    fn samples_errors() {
        assert_eq!(raw_from_samples(&[u32::MAX; 4], 3), Err(DshotError::NoResponse));
        assert_eq!(raw_from_samples(&[], 3), Err(DshotError::NoResponse));
        assert_eq!(raw_from_samples(&[0], 0), Err(DshotError::BadTiming));
        // Start bit then the buffer ends while low.
        assert_eq!(raw_from_samples(&[0xFFFF_FFF0], 3), Err(DshotError::Truncated { bits: 0 }));
    }

    #[test]
    fn edges_to_raw_round_trip() {
        let bit_ticks = 320u32; // 240 MHz / 750 kbit/s
        for value in [0x000u16, 0x123, 0x2A5, 0x5C3, 0xFFF] {
            let raw = answer_raw(value);
            // Edges at every level change, starting with the start bit's falling edge; a timer
            // that wraps in the middle; slight jitter: +7 ticks after the first.
            let (mut edges, n) = answer_edges(value, u32::MAX - 3_000, bit_ticks);
            for edge in &mut edges[1..n] {
                *edge = edge.wrapping_add(7);
            }
            let rebuilt = raw_from_edges(&edges[..n], bit_ticks);
            assert_eq!(rebuilt, Ok(raw), "value {value:#x}");
        }
        assert_eq!(raw_from_edges(&[5], 320), Err(DshotError::NoResponse));
        // An absurdly long first run (wrapped timestamps) neither panics nor overflows: 21 low
        // bits, which then fail GCR decoding.
        assert_eq!(raw_from_edges(&[1, 0], 320), Ok(0));
        assert_eq!(gcr_decode(0), Err(DshotError::GcrSymbol { quintet: 0 }));
        assert_eq!(raw_from_edges(&[5, 10], 0), Err(DshotError::BadTiming));
        // Ends low after a falling edge: truncated.
        assert_eq!(raw_from_edges(&[0, 320, 640], 320), Err(DshotError::Truncated { bits: 2 }));
    }

    /// A motor at 21,000 eRPM on 7 pole pairs (3,000 RPM, 314 rad/s): the answer's period is
    /// 1e6/350 = 2,857 µs → mantissa 357, exponent 3 (2,856 µs); decoded through the edges to
    /// the speed; a corrupted answer is counted and keeps the last speed until
    /// [`STALE_ANSWERS`] failures in a row.
    #[test]
    fn a_captured_answer_becomes_the_motors_speed_and_failures_go_stale() {
        let bit_ticks = 320; // 240 MHz / 750 kbit/s
        let value = (3u16 << 9) | 357;
        let (edges, n) = answer_edges(value, 1_000, bit_ticks);
        assert_eq!(telemetry_from_edges(&edges[..n], bit_ticks), Ok(value));
        let mut motor = MotorTelemetry::default();
        assert_eq!(motor.speed_rad_s(), None, "nothing heard yet");
        motor.record(telemetry_from_edges(&edges[..n], bit_ticks), 7);
        let expected = 60e6 / 2856.0 / 7.0 * core::f32::consts::TAU / 60.0;
        let speed = motor.speed_rad_s().unwrap();
        assert!((speed - expected).abs() < 0.05, "{speed} rad/s vs {expected}");
        // One edge missing: the answer's bits shift and the checksum or a quintet fails.
        let mut broken = edges;
        broken.copy_within(6..n, 5);
        let failed = telemetry_from_edges(&broken[..n - 1], bit_ticks);
        assert!(failed.is_err(), "{failed:?}");
        for _ in 1..STALE_ANSWERS {
            motor.record(failed, 7);
            assert_eq!(motor.speed_rad_s(), Some(speed), "a lost answer keeps the speed");
        }
        motor.record(Err(DshotError::NoResponse), 7);
        assert_eq!(motor.speed_rad_s(), None, "stale after {STALE_ANSWERS} failures");
        let c = motor.counters;
        assert_eq!(c.frames_ok, 1);
        assert_eq!(c.crc_errors + c.gcr_symbol_errors + c.timeouts, u32::from(STALE_ANSWERS));
        // The stopped value reads 0 rad/s.
        let (stopped, n) = answer_edges(TELEMETRY_STOPPED, 0, bit_ticks);
        motor.record(telemetry_from_edges(&stopped[..n], bit_ticks), 7);
        assert_eq!(motor.speed_rad_s(), Some(0.0));
    }

    #[test]
    fn counters() {
        let mut c = MotorTelemetryCounters::default();
        c.record(&Ok(5));
        c.record(&Err(DshotError::TelemetryCrc { frame: 0 }));
        c.record(&Err(DshotError::GcrSymbol { quintet: 0 }));
        c.record(&Err(DshotError::GcrSymbol { quintet: 1 }));
        c.record(&Err(DshotError::NoResponse));
        c.record(&Err(DshotError::Truncated { bits: 3 }));
        c.record(&Err(DshotError::BadTiming));
        assert_eq!(
            c,
            MotorTelemetryCounters {
                frames_ok: 1,
                crc_errors: 1,
                gcr_symbol_errors: 2,
                timeouts: 2,
                other_errors: 1,
            }
        );
    }

    #[test]
    fn armed_motors_stay_stopped_until_commanded_then_idle_at_zero_until_disarmed() {
        let mut queue = CommandQueue::default();
        let idle = throttle_frame(0.0, false, false);
        assert_eq!(idle >> 5, THROTTLE_MIN, "idle is the minimum throttle, value 48");
        // Armed and waiting for the throw: zero commands stop every motor.
        queue.set_armed(true);
        queue.note_commands(&[0.0; 4]);
        assert_eq!(queue.frame(0, 0.0, false), motor_stop_frame(false));
        // The first command above zero (the excitation): from now on zero idles, NaN too.
        queue.note_commands(&[0.0, 0.3, 0.0, 0.0]);
        assert_eq!(queue.frame(1, 0.3, false), throttle_frame(0.3, false, false));
        assert_eq!(queue.frame(0, 0.0, false), idle);
        assert_eq!(queue.frame(2, -0.1, false), idle);
        assert_eq!(queue.frame(3, f32::NAN, false), idle);
        // Disarmed: every motor stops, and arming again starts stopped.
        queue.set_armed(false);
        assert_eq!(queue.frame(0, 0.0, false), motor_stop_frame(false));
        queue.set_armed(true);
        assert_eq!(queue.frame(0, 0.0, false), motor_stop_frame(false));
    }
}
