//! The flight log: every control step on record, so a flight can be replayed through this very
//! application afterwards (`configurator-cli replay`) and read by the usual tools.
//!
//! **What is logged** (docs/flight-log.md has the byte layout):
//! - every control step's inputs, enough to replay it: the IMU sample exactly as the driver
//!   delivered it (or its absence; NaN bits kept), the motor speeds the step read, the motor
//!   count and the time; and its outputs: the commands written and the phase;
//! - every [`ControlCommand`] the tick applied (from the links' queue or the radio), with the
//!   step it was applied before;
//! - every piece of work the background task took (parameters, calibration start and stop),
//!   with the step after which it took it and the learner samples it had processed then
//!   (format 4), so a replay hands it to its background task between the same two samples;
//! - every step at which the control step adopted the background task's results (a new
//!   version of the learned model, its refinements, the in-flight offset fit), with the
//!   samples those results had been computed from (format 4): the one handoff from the
//!   background task to the control step, which the board's timing decides and nothing else
//!   records, so a replay hands the control step the same results at the same step;
//! - the parameters in force when the file begins, and a header (format version, firmware
//!   version, board, control rate, the registry's layout);
//! - in a file that begins at an arming (format 6), the control loop's whole state as it stood
//!   before the arming command ([`ArmingRecord`], [`StateChunk`]: the attitude filter, the
//!   navigation, the model in force, every detector's memory; about 9 KB, postcard) and the
//!   learner samples handed to the background task before it. The tick copies the state once,
//!   in place, into a box beside the ring ([`LogRing`]); the logger serialises it from there.
//!   So the replay runs the file's steps from the state the board ran them from;
//! - the learner's state (both G1 blocks) and the closed loop's ([`protocol::LearnerTelemetry`],
//!   [`protocol::FlightTelemetry`], exactly as the link streams them) at
//!   [`LOG_SNAPSHOT_RATE_HZ`], taken by the link pass from the snapshots it answers from. They
//!   carry their own time: the background task may not yet have written the steps before them,
//!   so a reader places them by `t_us`, not by their place in the file. A replay does not need
//!   them; a reader of the flight does (how G1 converged, the hover's errors, the failsafes).
//!
//! **Why this split of work.** The 2 kHz step must stay cheap and never block: the tick copies a
//! fixed-layout [`LogEntry`] (about 130 bytes) into a lock-free ring ([`LogRing`]) and does no
//! formatting at all; a full ring drops the whole entry and counts it. The lowest-priority task
//! ([`Logger::drain`], from `system::run_background`) serialises the entries (postcard), frames
//! them with the link protocol's framing (COBS, CRC-32C, a 0x00 delimiter: `protocol::frame`)
//! and packs the frames into fixed-size blocks ([`LOG_BLOCK_LEN`], one SD-card sector) for a
//! [`LogSink`]. A reader resynchronises at every 0x00, so a torn tail (a power cut in the middle
//! of a block) costs only the frames it cuts, and every complete block before it reads whole.
//!
//! **Files.** With the `log_always` parameter at 0 (the default), a file begins with the entry
//! that arms the craft (a throw-to-fly arming, a motor test, or a step that finds it armed) and
//! ends [`LOG_LINGER_S`] after the craft was last armed; with 1, one file runs from start-up on.
//! The parameters in force at start-up (the flash's) are the logger's from the first step, so
//! with `log_always` saved the file begins at step 1. Either file replays bit for bit whatever
//! the tasks' timing: from start-up, or from the control loop's state at the arming. (The
//! background task's state is not recorded: at an arming its learner starts afresh, and what it
//! carries over, the parameters, is in the file.)
//!
//! Assumes: one producer (the control tick) and one consumer (the lowest-priority task); the
//! sink may block its caller (an SD card's busy time), which is why only that task calls it.

use serde::{Deserialize, Serialize};

use super::control::ControlState;
use super::hal::{ImuSample, MAX_MOTORS};
use super::params::{Params, LAYOUT_HASH, PARAM_SLOTS};
use super::pilot::FAILSAFE_KINDS;
use super::queue::{
    split_queue, Mailbox, MailboxConsumer, MailboxProducer, RingConsumer, RingProducer,
};
use super::{BackgroundCommand, ControlCommand, ControlSettings};
use flight::learner::FlightPhase;
use heapless::spsc::Queue;
use protocol::{Decoder, DshotCommand, ExternalPose, LandReason, PositionSetpoint, MAX_FRAME_LEN};

/// What the link task hands the background task, and what the log records of it (defined with
/// the log, which writes every piece down, rather than with the system that routes it). The
/// parameters travel whole (about 0.5 KiB,
/// copied once per change into a static queue: no allocation, no boxing).
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(clippy::large_enum_variant)]
pub enum BackgroundWork {
    /// Start or stop a calibration.
    Command(BackgroundCommand),
    /// The parameters in force changed: take these.
    Configure(Params),
}

/// Version of the log's record layout. 2 added the learner's and the flight's snapshots
/// ([`id::LEARNER`], [`id::FLIGHT`]) to version 1's records; 3 the landing and the pilot's
/// sticks (the commands [`LoggedCommand::Land`] and [`LoggedCommand::Sticks`], the flight modes
/// `Landing` and `Angle`); 4 the adoptions of the background's results ([`id::ADOPTED`]) and
/// the learner samples each piece of work was taken at ([`id::WORK_AT`], instead of
/// [`id::WORK`]); 5 the position fixes with their own accuracy ([`LoggedCommand::PositionFix`]:
/// a GNSS receiver's); 6 the control loop's state at the head of a file that begins at an
/// arming ([`id::ARMING`], [`id::STATE`]); 7 the compass's calibrated fields
/// ([`LoggedCommand::MagneticField`]), and the pilot's latest one in that state. A reader reads
/// every earlier version, and refuses later ones.
pub const LOG_FORMAT_VERSION: u16 = 7;

/// Rate of the learner's and the flight's snapshots in a log, Hz: a G1 estimate converges over
/// tenths of a second and a hover's position error moves at a few hertz, so 25 Hz shows both;
/// the two learner blocks and a flight sample cost about 15 kB/s, a fifteenth of the steps'.
pub const LOG_SNAPSHOT_RATE_HZ: u32 = 25;

/// Bytes per block handed to the sink: one SD-card sector (SDMMC writes whole 512-byte
/// sectors), so a block is the unit a power cut tears.
pub const LOG_BLOCK_LEN: usize = 512;

/// Entries the ring between the tick and the logger holds (heapless keeps one slot free): 511
/// entries are at least 255 ms at 2 kHz (a step and at most a command or two per step), so the
/// logger rides out the longest time an SD card may stay busy on a write (SD Physical Layer
/// spec: 250 ms for SDHC/SDXC; typical cards finish within a few ms, wear levelling stalls
/// tens). A longer stall drops whole entries, counted. 78 KB on the board (AXI SRAM). At 128
/// entries (63 ms) the simulated card's test lost 373 steps to a 250 ms stall.
pub const LOG_RING_LEN: usize = 512;

/// How long a per-arming file goes on after the craft was last armed, s: the fall or catch
/// after a disarm, and the status a person checks, are part of the flight's story.
pub const LOG_LINGER_S: f32 = 2.0;

/// Parameter slots per parameters record (a record must fit one protocol frame, 256 bytes).
/// A changed parameter set is logged as the parts that changed: an identification refining in
/// flight stores its model at up to the link rate, and one G1 row (8 slots) moves at a time.
pub const PARAMS_CHUNK_SLOTS: usize = 16;

/// What one control step read and wrote, as the tick hands it to the logger.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepEntry {
    /// The step's number since start-up (the first step is 1).
    pub step: u32,
    /// Time of the step, µs since start-up.
    pub t_us: u64,
    /// The IMU sample as the driver delivered it (before any check or bias), `None`: none.
    pub imu: Option<ImuSample>,
    /// Motors the outputs reported (at most [`MAX_MOTORS`]).
    pub motor_count: u8,
    /// The speeds the step read after writing its commands, rad/s (all [`MAX_MOTORS`]).
    pub speeds_rad_s: [Option<f32>; MAX_MOTORS],
    /// The commands the step wrote (zero beyond `motor_count`).
    pub commands: [f32; MAX_MOTORS],
    pub phase: FlightPhase,
    /// The attempt ended without a result.
    pub failed: bool,
    /// Flying on the learned model.
    pub flying: bool,
    /// Anything armed (an attempt, a flight, a motor test).
    pub armed: bool,
    /// Entries the ring had dropped before this one, since start-up.
    pub ring_dropped: u32,
    /// The background's results the step adopted before it ran, if it adopted any.
    pub adopted: Option<Adoption>,
}

/// One entry of the ring from the tick to the logger.
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(clippy::large_enum_variant)]
pub enum LogEntry {
    /// A command the tick applied before step `step`.
    Command { step: u32, command: ControlCommand },
    /// A step.
    Step(StepEntry),
}

/// The background task's results the control step adopted before a step (a new version of the
/// learned model): computed from the first `samples_processed` learner samples since start-up,
/// when the control step had dropped `samples_dropped` samples (its queue full). Carried in
/// the step's own entry rather than one of its own: while the learner learns, a new version
/// comes every step, and a second entry per step would halve the time the ring rides out an
/// SD card's stall.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Adoption {
    pub samples_processed: u32,
    pub samples_dropped: u32,
}

/// What goes with the control loop's state at an arming ([`LogProducer::offer_arming`]): the
/// step the arming command is applied before, and the learner samples the control step had
/// handed the background task before that step (so a replay knows which of the board's sample
/// counts its own background task's first sample is).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ArmingTag {
    pub step: u32,
    pub samples_before: u32,
}

/// The ring's storage; split it once, with the [`ArmingBox`], by [`split_log`].
pub type LogRing = Queue<LogEntry, LOG_RING_LEN>;

/// The box beside the ring for the control loop's state at an arming (9 KB, too large for a
/// ring's slot).
pub type ArmingBox = Mailbox<ArmingTag, ControlState>;

/// The tick's end and the logger's end of the ring and the box (once, at start-up).
pub fn split_log<'q>(
    ring: &'q mut LogRing,
    arming: &'q mut ArmingBox,
) -> (LogProducer<'q>, LogConsumer<'q>) {
    let (entries, entries_out) = split_queue(ring);
    let (arming, arming_out) = arming.split();
    (LogProducer { entries, arming }, LogConsumer { entries: entries_out, arming: arming_out })
}

/// The control tick's end of the ring.
pub struct LogProducer<'q> {
    entries: RingProducer<'q, LogEntry>,
    arming: MailboxProducer<'q, ArmingTag, ControlState>,
}

/// The logger's end of the ring.
pub struct LogConsumer<'q> {
    entries: RingConsumer<'q, LogEntry>,
    arming: MailboxConsumer<'q, ArmingTag, ControlState>,
}

impl LogProducer<'_> {
    /// Push an entry; a full ring drops it whole, counted. Never blocks.
    pub fn push(&mut self, entry: LogEntry) {
        self.entries.push(entry);
    }

    /// Entries dropped so far because the ring was full.
    pub fn dropped(&self) -> u32 {
        self.entries.dropped()
    }

    /// Whether entries wait for the logger.
    pub fn has_waiting(&self) -> bool {
        self.entries.has_waiting()
    }

    /// Offer the control loop's `state` as it stands before an arming command (before its
    /// entry is pushed): the logger writes it at the head of a file that begins with that
    /// command. One copy in place; refused (false) while the logger still holds an earlier one.
    pub fn offer_arming(&mut self, tag: ArmingTag, state: &ControlState) -> bool {
        self.arming.put(tag, state)
    }
}

// ---- The records, as written --------------------------------------------------------------

/// Record ids: the first byte of every frame (the protocol frame's `id`).
pub mod id {
    pub const HEADER: u8 = 0x01;
    pub const PARAMS: u8 = 0x02;
    pub const COMMAND: u8 = 0x03;
    pub const STEP: u8 = 0x04;
    pub const WORK: u8 = 0x05;
    pub const DROPPED: u8 = 0x06;
    pub const END: u8 = 0x07;
    /// A [`protocol::LearnerTelemetry`] (format 2).
    pub const LEARNER: u8 = 0x08;
    /// A [`protocol::FlightTelemetry`] (format 2).
    pub const FLIGHT: u8 = 0x09;
    /// An [`AdoptedRecord`] (format 4).
    pub const ADOPTED: u8 = 0x0A;
    /// A [`WorkRecord`] with the samples processed (format 4; formats 1–3 wrote [`WORK`]).
    pub const WORK_AT: u8 = 0x0B;
    /// An [`ArmingRecord`]: the control loop's state follows in [`STATE`] records (format 6).
    pub const ARMING: u8 = 0x0C;
    /// A [`StateChunk`] of the state an [`ARMING`] record announced (format 6).
    pub const STATE: u8 = 0x0D;
}

/// The first record of every file.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq)]
pub struct Header {
    /// [`LOG_FORMAT_VERSION`].
    pub format: u16,
    /// Firmware version, major, minor, patch.
    pub firmware: [u8; 3],
    /// The board's name ("STM32H743", "SITL").
    pub board: heapless::String<32>,
    /// Control steps per second.
    pub control_rate_hz: u16,
    /// [`LAYOUT_HASH`] of the parameter registry that wrote the parameters records.
    pub params_layout: u32,
    /// Slots of one parameter set ([`PARAM_SLOTS`]).
    pub param_slots: u16,
    /// The step the file begins with (1: start-up) and its time, µs.
    pub first_step: u32,
    pub first_t_us: u64,
    /// Written because `log_always` was set (else: an arming).
    pub always: bool,
}

/// A part of the parameter set: `values` are slots `offset..` of [`Params::slots`]. At the start
/// of a file every part is written; afterwards only the parts that changed, before the
/// [`LoggedWork::Configure`] that puts the set in force.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct ParamsRecord {
    pub offset: u16,
    pub values: heapless::Vec<f32, PARAMS_CHUNK_SLOTS>,
}

/// A control command as logged. `Configure` carries no settings: they are the ones derived from
/// the latest parameter set ([`ControlSettings::from`]), which `from_params` confirms.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub enum LoggedCommand {
    ArmThrowToFly,
    Disarm,
    ExternalPose(ExternalPose),
    PositionSetpoint(PositionSetpoint),
    Configure {
        from_params: bool,
    },
    MotorTest {
        motor: u8,
        command: f32,
    },
    StopMotorTest,
    /// The DShot special command by its value ([`DshotCommand::value`]).
    EscCommand {
        command: u8,
        motor: Option<u8>,
    },
    /// A failsafe raised outside the control step (the pilot's kill switch, the radio lost), by
    /// its index in `pilot::FAILSAFE_KINDS`.
    Failsafe {
        kind: u8,
    },
    /// End the flight gently ([`ControlCommand::Land`]), for this reason (format 2 readers see
    /// an unknown command: appended, nothing before it moved).
    Land(LandReason),
    /// The pilot's sticks ([`ControlCommand::Sticks`]).
    Sticks(Option<crate::drivers::crsf::StickInput>),
    /// A position fix with its own accuracy ([`ControlCommand::PositionFix`], format 5).
    PositionFix(super::pilot::PositionFix),
    /// A calibrated magnetic field ([`ControlCommand::MagneticField`], format 7).
    MagneticField(super::compass::MagneticSample),
}

/// A command applied before step `step`.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct CommandRecord {
    pub step: u32,
    pub command: LoggedCommand,
}

/// Flag bits of [`StepLogRecord::flags`].
pub mod flags {
    pub const FAILED: u8 = 1;
    pub const FLYING: u8 = 2;
    pub const ARMED: u8 = 4;
}

/// One control step as logged (see [`StepEntry`]).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct StepLogRecord {
    pub step: u32,
    pub t_us: u64,
    /// Gyro (rad/s) then accelerometer (m/s²), IMU axes, as delivered.
    pub imu: Option<[f32; 6]>,
    /// Every speed slot the outputs returned, rad/s.
    pub speeds_rad_s: [Option<f32>; MAX_MOTORS],
    /// The commands of the `motor_count` motors (its length is the motor count).
    pub commands: heapless::Vec<f32, MAX_MOTORS>,
    /// [`phase_code`].
    pub phase: u8,
    /// [`flags`].
    pub flags: u8,
}

/// Background work as logged; `Configure` means the parameter set written just before.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoggedWork {
    StartCalibration,
    StopCalibration,
    Configure,
}

/// Work the background task took after step `after_step` (0: before the first; the last step
/// the logger had written then, so on the board the work may have come a few steps later),
/// when it had processed `samples_processed` learner samples since start-up: that count places
/// it exactly (`None`: a format 1–3 log, whose [`id::WORK`] record did not say).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct WorkRecord {
    pub after_step: u32,
    pub work: LoggedWork,
    pub samples_processed: Option<u32>,
}

/// [`WorkRecord`] as formats 1–3 wrote it ([`id::WORK`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
struct WorkRecordV1 {
    after_step: u32,
    work: LoggedWork,
}

/// The control step adopted, before step `step`, the background task's results computed from
/// its first `samples_processed` learner samples ([`Adoption`]); written just before that
/// step's record. Every adoption is written, the first (the results at start-up, adopted by
/// the first step) included.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct AdoptedRecord {
    pub step: u32,
    pub samples_processed: u32,
    /// Learner samples the control step had dropped since start-up (its queue full): when
    /// this grows, the board's background task saw fewer samples than a replay's will.
    pub samples_dropped: u32,
}

/// Bytes of the control loop's serialised state per [`StateChunk`]: a record must fit one
/// protocol frame (256 bytes with its framing).
pub const STATE_CHUNK_BYTES: usize = 192;

/// A file that begins at an arming: the control loop's state before the arming command (the
/// first command record), `len` bytes of postcard in [`StateChunk`] records right after this
/// one. With it a replay runs the file's steps from the state the board ran them from.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct ArmingRecord {
    pub tag: ArmingTag,
    pub len: u32,
}

/// Bytes `offset..` of the state an [`ArmingRecord`] announced.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq)]
pub struct StateChunk {
    pub offset: u32,
    pub bytes: heapless::Vec<u8, STATE_CHUNK_BYTES>,
}

/// The ring has dropped `entries` entries since start-up (written when the count grows).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct DroppedRecord {
    pub entries: u32,
}

/// The file's last record, written when it is closed in order.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct EndRecord {
    /// The last step logged.
    pub last_step: u32,
    /// Entries the ring had dropped since start-up.
    pub ring_dropped: u32,
}

/// A decoded record.
#[derive(Clone, Debug, PartialEq)]
pub enum LogRecord {
    Header(Header),
    Params(ParamsRecord),
    Command(CommandRecord),
    Step(StepLogRecord),
    Work(WorkRecord),
    Dropped(DroppedRecord),
    End(EndRecord),
    Learner(protocol::LearnerTelemetry),
    Flight(protocol::FlightTelemetry),
    Adopted(AdoptedRecord),
    Arming(ArmingRecord),
    State(StateChunk),
}

/// The flight phase as a byte.
pub fn phase_code(phase: FlightPhase) -> u8 {
    match phase {
        FlightPhase::Idle => 0,
        FlightPhase::WaitingForThrow => 1,
        FlightPhase::Throwing => 2,
        FlightPhase::Released => 3,
        FlightPhase::Exciting => 4,
        FlightPhase::Done => 5,
    }
}

/// The flight phase of a byte written by [`phase_code`].
pub fn phase_from_code(code: u8) -> Option<FlightPhase> {
    Some(match code {
        0 => FlightPhase::Idle,
        1 => FlightPhase::WaitingForThrow,
        2 => FlightPhase::Throwing,
        3 => FlightPhase::Released,
        4 => FlightPhase::Exciting,
        5 => FlightPhase::Done,
        _ => return None,
    })
}

impl LoggedCommand {
    /// The command as logged; `Configure` is checked against `params` (the latest set).
    pub fn from_command(command: &ControlCommand, params: &Params) -> Self {
        match *command {
            ControlCommand::ArmThrowToFly => Self::ArmThrowToFly,
            ControlCommand::Disarm => Self::Disarm,
            ControlCommand::ExternalPose(pose) => Self::ExternalPose(pose),
            ControlCommand::PositionSetpoint(setpoint) => Self::PositionSetpoint(setpoint),
            ControlCommand::Configure(settings) => {
                Self::Configure { from_params: settings == ControlSettings::from(params) }
            }
            ControlCommand::MotorTest { motor, command } => Self::MotorTest { motor, command },
            ControlCommand::StopMotorTest => Self::StopMotorTest,
            ControlCommand::EscCommand { command, motor } => {
                Self::EscCommand { command: command.value() as u8, motor }
            }
            ControlCommand::Failsafe(failsafe) => Self::Failsafe {
                kind: FAILSAFE_KINDS
                    .iter()
                    .position(|k| core::mem::discriminant(k) == core::mem::discriminant(&failsafe))
                    .unwrap_or(0) as u8,
            },
            ControlCommand::Land(reason) => Self::Land(reason),
            ControlCommand::Sticks(sticks) => Self::Sticks(sticks),
            ControlCommand::PositionFix(fix) => Self::PositionFix(fix),
            ControlCommand::MagneticField(sample) => Self::MagneticField(sample),
        }
    }

    /// The command to apply again; `Configure` takes the settings of `params`. `None`: an ESC
    /// command this firmware does not know.
    pub fn to_command(&self, params: &Params) -> Option<ControlCommand> {
        Some(match *self {
            Self::ArmThrowToFly => ControlCommand::ArmThrowToFly,
            Self::Disarm => ControlCommand::Disarm,
            Self::ExternalPose(pose) => ControlCommand::ExternalPose(pose),
            Self::PositionSetpoint(setpoint) => ControlCommand::PositionSetpoint(setpoint),
            Self::Configure { .. } => ControlCommand::Configure(ControlSettings::from(params)),
            Self::MotorTest { motor, command } => ControlCommand::MotorTest { motor, command },
            Self::StopMotorTest => ControlCommand::StopMotorTest,
            Self::EscCommand { command, motor } => {
                ControlCommand::EscCommand { command: DshotCommand::from_value(command)?, motor }
            }
            Self::Failsafe { kind } => {
                ControlCommand::Failsafe(*FAILSAFE_KINDS.get(usize::from(kind))?)
            }
            Self::Land(reason) => ControlCommand::Land(reason),
            Self::Sticks(sticks) => ControlCommand::Sticks(sticks),
            Self::PositionFix(fix) => ControlCommand::PositionFix(fix),
            Self::MagneticField(sample) => ControlCommand::MagneticField(sample),
        })
    }
}

impl StepLogRecord {
    /// The record of `entry`.
    pub fn from_entry(entry: &StepEntry) -> Self {
        let count = usize::from(entry.motor_count).min(MAX_MOTORS);
        Self {
            step: entry.step,
            t_us: entry.t_us,
            imu: entry.imu.map(|s| {
                let [gx, gy, gz] = s.gyro_rad_s;
                let [ax, ay, az] = s.accel_mps2;
                [gx, gy, gz, ax, ay, az]
            }),
            speeds_rad_s: entry.speeds_rad_s,
            commands: entry.commands[..count].iter().copied().collect(),
            phase: phase_code(entry.phase),
            flags: u8::from(entry.failed) * flags::FAILED
                + u8::from(entry.flying) * flags::FLYING
                + u8::from(entry.armed) * flags::ARMED,
        }
    }

    /// The IMU sample as the driver delivered it.
    pub fn imu_sample(&self) -> Option<ImuSample> {
        self.imu.map(|[gx, gy, gz, ax, ay, az]| ImuSample {
            gyro_rad_s: [gx, gy, gz],
            accel_mps2: [ax, ay, az],
        })
    }

    /// Motors of the step.
    pub fn motor_count(&self) -> u8 {
        self.commands.len() as u8
    }
}

// ---- The sink -----------------------------------------------------------------------------

/// Why a sink did not take a file or a block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogSinkError {
    /// No card (or no log storage on this board).
    NoCard,
    /// The storage is full.
    Full,
    /// The storage failed (a write or file-system error).
    Io,
}

/// Why a log file could not be listed, read or deleted (the link answers each with its
/// `DeviceError`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogFileError {
    /// This storage cannot list or read its files (a board without a card driver).
    Unsupported,
    /// No file has this number.
    NoSuchFile,
    /// The offset is past the file's end; it holds `size_bytes` now.
    OffsetPastEnd { size_bytes: u32 },
    /// The file is being written (it cannot be deleted yet).
    BeingWritten,
    /// The storage failed.
    Io,
}

/// The files one [`LogFiles::list`] answers: a page of [`protocol::LogList`].
pub type LogFileList = heapless::Vec<protocol::LogFileInfo, { protocol::LOG_LIST_LEN }>;

/// What one [`LogFiles::read`] read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FileRead {
    /// Bytes read into the buffer.
    pub bytes_read: usize,
    /// The file's size now, bytes.
    pub size_bytes: u32,
}

/// The files a [`LogSink`] has written, as the link task reaches them (`configurator-cli log
/// list|download|delete`). Every call does a bounded piece of work: a listing of at most
/// [`protocol::LOG_LIST_LEN`] files, a read of at most one chunk. The defaults answer
/// [`LogFileError::Unsupported`] (a sink that keeps nothing readable, [`NoCard`]).
///
/// Locking: the link task and the background task (which writes through the same sink) reach
/// the storage under one lock (`system::PassShared::logs`, taken per call), so a read sees only
/// whole blocks and never a block half appended.
pub trait LogFiles {
    /// The files numbered `first` or more, ascending, as many as `out` holds (it is cleared
    /// first); returns whether more follow.
    fn list(&mut self, first: u32, out: &mut LogFileList) -> Result<bool, LogFileError> {
        let _ = (first, out);
        Err(LogFileError::Unsupported)
    }

    /// Read file `number` from byte `offset` into `buf` (as much as it holds and the file has);
    /// returns the bytes read and the file's size now. An offset at the end reads nothing.
    fn read(&mut self, number: u32, offset: u32, buf: &mut [u8]) -> Result<FileRead, LogFileError> {
        let _ = (number, offset, buf);
        Err(LogFileError::Unsupported)
    }

    /// Delete file `number`; refused for the file being written.
    fn delete(&mut self, number: u32) -> Result<(), LogFileError> {
        let _ = number;
        Err(LogFileError::Unsupported)
    }

    /// The link pass's snapshots at `now_us`: a logger writing a file records the learner's
    /// and the flight's state when [`LOG_SNAPSHOT_RATE_HZ`] says one is due. Storage that logs
    /// nothing keeps this default.
    fn snapshot(&mut self, now_us: u64, view: &super::StatusView) {
        let _ = (now_us, view);
    }
}

/// Where the blocks go: a file on the SD card on the board, a file in a directory on the host.
/// Called only by the lowest-priority task; it may block that task (never the others). `Send`:
/// the board hands it to that task. Its files are read back through [`LogFiles`].
pub trait LogSink: LogFiles + Send {
    /// Begin a new file; returns its number (`LOG00001.BIN` is 1).
    fn open(&mut self) -> Result<u32, LogSinkError>;
    /// Append one block to the file begun last.
    fn write_block(&mut self, block: &[u8; LOG_BLOCK_LEN]) -> Result<(), LogSinkError>;
    /// End the file (whatever the storage buffers goes out).
    fn close(&mut self) -> Result<(), LogSinkError>;
}

/// A board without log storage (or without its driver yet): every file is refused as
/// [`LogSinkError::NoCard`], so the logger drops what it drains and says so in its status.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoCard;

impl LogFiles for NoCard {}

impl LogSink for NoCard {
    fn open(&mut self) -> Result<u32, LogSinkError> {
        Err(LogSinkError::NoCard)
    }
    fn write_block(&mut self, _block: &[u8; LOG_BLOCK_LEN]) -> Result<(), LogSinkError> {
        Err(LogSinkError::NoCard)
    }
    fn close(&mut self) -> Result<(), LogSinkError> {
        Ok(())
    }
}

/// No storage: nothing to list (`None` in a graph without a log).
impl<T: LogFiles> LogFiles for Option<T> {
    fn list(&mut self, first: u32, out: &mut LogFileList) -> Result<bool, LogFileError> {
        self.as_mut().ok_or(LogFileError::Unsupported)?.list(first, out)
    }
    fn read(&mut self, number: u32, offset: u32, buf: &mut [u8]) -> Result<FileRead, LogFileError> {
        self.as_mut().ok_or(LogFileError::Unsupported)?.read(number, offset, buf)
    }
    fn delete(&mut self, number: u32) -> Result<(), LogFileError> {
        self.as_mut().ok_or(LogFileError::Unsupported)?.delete(number)
    }
    fn snapshot(&mut self, now_us: u64, view: &super::StatusView) {
        if let Some(files) = self {
            files.snapshot(now_us, view);
        }
    }
}

// ---- The writer ---------------------------------------------------------------------------

/// What the logger has done since start-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LogStatus {
    /// A file is being written, and its number.
    pub file: Option<u32>,
    /// Files begun.
    pub files: u32,
    /// Records and blocks written, and their bytes.
    pub records: u32,
    pub blocks: u32,
    /// Files the sink refused to begin, and the latest reason.
    pub open_failures: u32,
    pub last_error: Option<LogSinkError>,
    /// Blocks the sink refused (the file is given up then).
    pub write_failures: u32,
    /// Entries the ring dropped (full), since start-up.
    pub ring_dropped: u32,
    /// Records that did not encode (none expected: every record fits a frame).
    pub encode_failures: u32,
    /// Files begun at an arming without the control loop's state (the tick found the box still
    /// full, or the ring dropped the arming's entry): their replay starts from a fresh state.
    pub arming_states_missing: u32,
}

/// Whether `command` arms the craft (a file begins with it).
pub fn is_arming(command: &ControlCommand) -> bool {
    matches!(command, ControlCommand::ArmThrowToFly | ControlCommand::MotorTest { .. })
}

/// A postcard output that writes the serialised bytes as [`StateChunk`] records as they come,
/// so the state is never held whole in the logger's memory.
struct StateChunks<'l, 'q> {
    logger: &'l mut Logger<'q>,
    chunk: StateChunk,
}

impl StateChunks<'_, '_> {
    fn flush(&mut self) {
        if !self.chunk.bytes.is_empty() {
            self.logger.write(id::STATE, &self.chunk);
            self.chunk.offset += self.chunk.bytes.len() as u32;
            self.chunk.bytes.clear();
        }
    }
}

impl postcard::ser_flavors::Flavor for StateChunks<'_, '_> {
    type Output = ();

    fn try_push(&mut self, byte: u8) -> postcard::Result<()> {
        if self.chunk.bytes.is_full() {
            self.flush();
        }
        self.chunk.bytes.push(byte).map_err(|_| postcard::Error::SerializeBufferFull)
    }

    fn finalize(mut self) -> postcard::Result<()> {
        self.flush();
        Ok(())
    }
}

/// The file being written.
#[derive(Clone, Copy, Debug)]
struct OpenFile {
    /// The time the craft was last seen armed (or the file began), µs.
    last_armed_us: u64,
    /// A block was refused: nothing more goes to this file.
    broken: bool,
}

/// The lowest-priority end of the log: drains the ring, encodes the records, packs them in
/// blocks and hands the blocks to the sink, beginning and ending files.
pub struct Logger<'q> {
    entries: RingConsumer<'q, LogEntry>,
    /// The control loop's state at the latest arming (`None` only while it is being written).
    arming: Option<MailboxConsumer<'q, ArmingTag, ControlState>>,
    sink: &'q mut dyn LogSink,
    board: &'static str,
    control_rate_hz: u16,
    /// The parameters in force (the latest the background task took).
    params: Params,
    /// The parameters as the file has them (what changed since is written with the next set).
    logged_params: Params,
    file: Option<OpenFile>,
    /// A file was refused: no new try until the craft has been armed and disarmed again.
    refused: bool,
    /// The latest step found the craft armed.
    armed: bool,
    block: [u8; LOG_BLOCK_LEN],
    fill: usize,
    seq: u16,
    last_step: u32,
    last_t_us: u64,
    logged_dropped: u32,
    /// When the last snapshots were written, µs.
    last_snapshot_us: Option<u64>,
    status: LogStatus,
}

/// The files of the logger's sink (the link task reads them under the lock it shares with the
/// background task, which writes through the same sink).
impl LogFiles for Logger<'_> {
    fn list(&mut self, first: u32, out: &mut LogFileList) -> Result<bool, LogFileError> {
        self.sink.list(first, out)
    }
    fn read(&mut self, number: u32, offset: u32, buf: &mut [u8]) -> Result<FileRead, LogFileError> {
        self.sink.read(number, offset, buf)
    }
    fn delete(&mut self, number: u32) -> Result<(), LogFileError> {
        self.sink.delete(number)
    }
    fn snapshot(&mut self, now_us: u64, view: &super::StatusView) {
        if self.file.is_none() {
            self.last_snapshot_us = None;
            return;
        }
        const PERIOD_US: u64 = 1_000_000 / LOG_SNAPSHOT_RATE_HZ as u64;
        if self.last_snapshot_us.is_some_and(|t| now_us.saturating_sub(t) < PERIOD_US) {
            return;
        }
        self.last_snapshot_us = Some(now_us);
        for block in 0..2 {
            self.write(id::LEARNER, &super::learner_telemetry(view, block));
        }
        self.write(id::FLIGHT, &super::flight_telemetry(view));
    }
}

impl<'q> Logger<'q> {
    /// A logger for the entries of `entries`, writing to `sink`, for a board called `board`
    /// stepping at `control_rate_hz`. The parameters are the defaults until it is configured.
    pub fn new(
        entries: LogConsumer<'q>,
        sink: &'q mut dyn LogSink,
        board: &'static str,
        control_rate_hz: u16,
    ) -> Self {
        let LogConsumer { entries, arming } = entries;
        Self {
            entries,
            arming: Some(arming),
            sink,
            board,
            control_rate_hz,
            params: Params::default(),
            logged_params: Params::default(),
            file: None,
            refused: false,
            armed: false,
            block: [0; LOG_BLOCK_LEN],
            fill: 0,
            seq: 0,
            last_step: 0,
            last_t_us: 0,
            logged_dropped: 0,
            last_snapshot_us: None,
            status: LogStatus::default(),
        }
    }

    /// Begin with `params` in force (those loaded at start-up, before the first step), so a
    /// saved `log_always` opens the file at the first step, not at the first link pass.
    pub fn with_params(mut self, params: &Params) -> Self {
        self.params = *params;
        self
    }

    /// What the logger has done.
    pub fn status(&self) -> LogStatus {
        self.status
    }

    /// Encode every waiting entry (beginning and ending files as the entries arm and disarm).
    pub fn drain(&mut self) {
        while self.drain_one() {}
    }

    /// Encode the oldest waiting entry; false: none waited.
    pub fn drain_one(&mut self) -> bool {
        let Some(entry) = self.entries.pop() else { return false };
        self.take(&entry);
        true
    }

    /// The background task took `work` (after the entries drained so far), having processed
    /// `samples_processed` learner samples since start-up.
    pub fn work(&mut self, work: &BackgroundWork, samples_processed: u32) {
        let logged = match work {
            BackgroundWork::Command(BackgroundCommand::StartCalibration) => {
                LoggedWork::StartCalibration
            }
            BackgroundWork::Command(BackgroundCommand::StopCalibration) => {
                LoggedWork::StopCalibration
            }
            BackgroundWork::Configure(params) => {
                self.params = *params;
                if self.file.is_some() {
                    self.write_params(false);
                }
                LoggedWork::Configure
            }
        };
        if self.file.is_some() {
            let record = WorkRecord {
                after_step: self.last_step,
                work: logged,
                samples_processed: Some(samples_processed),
            };
            self.write(id::WORK_AT, &record);
        }
    }

    /// End the file in order (the application stops: a restart, the simulator's end).
    pub fn finish(&mut self) {
        self.drain();
        self.close_file();
    }

    fn take(&mut self, entry: &LogEntry) {
        let (step, t_us, arming) = match entry {
            LogEntry::Command { step, command } => (*step, self.last_t_us, is_arming(command)),
            LogEntry::Step(s) => (s.step, s.t_us, s.armed),
        };
        let always = self.params.log_always();
        let opening = self.file.is_none() && !self.refused && (always || arming);
        if opening {
            self.open_file(step, t_us, always);
        }
        if let LogEntry::Command { command, .. } = entry {
            if is_arming(command) {
                self.arming_state(step, opening && self.file.is_some());
            }
        }
        if let LogEntry::Step(s) = entry {
            self.last_step = s.step;
            self.last_t_us = s.t_us;
            self.status.ring_dropped = s.ring_dropped;
            if self.armed && !s.armed {
                self.refused = false;
            }
            self.armed = s.armed;
        }
        let Some(file) = &mut self.file else { return };
        if arming {
            file.last_armed_us = t_us;
        }
        match entry {
            LogEntry::Command { step, command } => {
                let command = LoggedCommand::from_command(command, &self.params);
                self.write(id::COMMAND, &CommandRecord { step: *step, command });
            }
            LogEntry::Step(s) => {
                if s.ring_dropped != self.logged_dropped {
                    self.logged_dropped = s.ring_dropped;
                    self.write(id::DROPPED, &DroppedRecord { entries: s.ring_dropped });
                }
                if let Some(adoption) = s.adopted {
                    let record = AdoptedRecord {
                        step: s.step,
                        samples_processed: adoption.samples_processed,
                        samples_dropped: adoption.samples_dropped,
                    };
                    self.write(id::ADOPTED, &record);
                }
                self.write(id::STEP, &StepLogRecord::from_entry(s));
                let linger_us = (LOG_LINGER_S * 1e6) as u64;
                let last_armed_us = self.file.map_or(t_us, |f| f.last_armed_us);
                if !always && !s.armed && t_us.saturating_sub(last_armed_us) >= linger_us {
                    self.close_file();
                }
            }
        }
    }

    /// The control loop's state offered at the arming applied before `step`: written when
    /// `write` (this arming begins the file), else let go; a state of an earlier arming that
    /// found no file to begin is let go too.
    fn arming_state(&mut self, step: u32, write: bool) {
        let Some(mut arming) = self.arming.take() else { return };
        let written = match arming.waiting() {
            Some(tag) if tag.step == step && write => {
                arming.take(|tag, state| self.write_state(tag, state)).is_some()
            }
            Some(tag) if tag.step <= step => {
                arming.take(|_, _| ());
                false
            }
            _ => false,
        };
        if write && !written {
            self.status.arming_states_missing = self.status.arming_states_missing.wrapping_add(1);
        }
        self.arming = Some(arming);
    }

    /// Write `state` as an [`ArmingRecord`] and its [`StateChunk`]s (postcard, streamed).
    fn write_state(&mut self, tag: ArmingTag, state: &ControlState) {
        let Ok(len) =
            postcard::serialize_with_flavor(state, postcard::ser_flavors::Size::default())
        else {
            self.status.encode_failures = self.status.encode_failures.wrapping_add(1);
            return;
        };
        self.write(id::ARMING, &ArmingRecord { tag, len: len as u32 });
        let chunks = StateChunks {
            logger: self,
            chunk: StateChunk { offset: 0, bytes: heapless::Vec::new() },
        };
        if postcard::serialize_with_flavor(state, chunks).is_err() {
            self.status.encode_failures = self.status.encode_failures.wrapping_add(1);
        }
    }

    fn open_file(&mut self, step: u32, t_us: u64, always: bool) {
        match self.sink.open() {
            Ok(number) => {
                self.status.file = Some(number);
                self.status.files = self.status.files.wrapping_add(1);
                self.file = Some(OpenFile { last_armed_us: t_us, broken: false });
                self.fill = 0;
                self.seq = 0;
                let firmware = super::FIRMWARE_VERSION;
                let header = Header {
                    format: LOG_FORMAT_VERSION,
                    firmware: [firmware.major, firmware.minor, firmware.patch],
                    board: protocol::text(self.board),
                    control_rate_hz: self.control_rate_hz,
                    params_layout: LAYOUT_HASH,
                    param_slots: PARAM_SLOTS as u16,
                    first_step: step,
                    first_t_us: t_us,
                    always,
                };
                self.write(id::HEADER, &header);
                self.write_params(true);
                // The ring's losses so far are the file's starting point, not a loss in it.
                self.logged_dropped = self.status.ring_dropped;
            }
            Err(error) => {
                self.refused = true;
                self.status.open_failures = self.status.open_failures.wrapping_add(1);
                self.status.last_error = Some(error);
            }
        }
    }

    fn close_file(&mut self) {
        if self.file.is_none() {
            return;
        }
        let end = EndRecord { last_step: self.last_step, ring_dropped: self.status.ring_dropped };
        self.write(id::END, &end);
        if self.fill > 0 {
            // The rest of the block is zeros: empty frames to a reader.
            self.block[self.fill..].fill(0);
            self.emit_block();
        }
        if let Err(error) = self.sink.close() {
            self.status.last_error = Some(error);
        }
        self.file = None;
        self.status.file = None;
    }

    /// The parameter set's parts: all of them, or those that differ from the file's.
    fn write_params(&mut self, all: bool) {
        let slots = *self.params.slots();
        let logged = *self.logged_params.slots();
        self.logged_params = self.params;
        let parts = slots.chunks(PARAMS_CHUNK_SLOTS).zip(logged.chunks(PARAMS_CHUNK_SLOTS));
        for (i, (chunk, before)) in parts.enumerate() {
            let same = chunk.iter().zip(before).all(|(a, b)| a.to_bits() == b.to_bits());
            if same && !all {
                continue;
            }
            let record = ParamsRecord {
                offset: (i * PARAMS_CHUNK_SLOTS) as u16,
                values: chunk.iter().copied().collect(),
            };
            self.write(id::PARAMS, &record);
        }
    }

    fn write<T: Serialize>(&mut self, id: u8, record: &T) {
        let mut frame = [0u8; MAX_FRAME_LEN];
        match protocol::frame::encode(id, self.seq, record, &mut frame) {
            Ok(len) => {
                self.seq = self.seq.wrapping_add(1);
                self.status.records = self.status.records.wrapping_add(1);
                self.put(&frame[..len]);
            }
            Err(_) => self.status.encode_failures = self.status.encode_failures.wrapping_add(1),
        }
    }

    fn put(&mut self, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            let take = bytes.len().min(LOG_BLOCK_LEN - self.fill);
            self.block[self.fill..self.fill + take].copy_from_slice(&bytes[..take]);
            self.fill += take;
            bytes = &bytes[take..];
            if self.fill == LOG_BLOCK_LEN {
                self.emit_block();
            }
        }
    }

    fn emit_block(&mut self) {
        self.fill = 0;
        let Some(file) = &mut self.file else { return };
        if file.broken {
            return;
        }
        match self.sink.write_block(&self.block) {
            Ok(()) => self.status.blocks = self.status.blocks.wrapping_add(1),
            Err(error) => {
                file.broken = true;
                self.status.write_failures = self.status.write_failures.wrapping_add(1);
                self.status.last_error = Some(error);
            }
        }
    }
}

// ---- The reader ---------------------------------------------------------------------------

/// What a reader made of a file's bytes besides the records.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReadStats {
    /// Frames that failed their COBS or CRC check or did not decode (a torn block, garbage).
    pub bad_frames: u32,
    /// Records missing by their sequence numbers (between two good frames).
    pub missing_records: u32,
    /// Bytes after the last delimiter: a frame the file ends in the middle of (a torn tail).
    pub torn_tail_bytes: u32,
}

/// Reads the records of a log file's bytes, in order, skipping what does not check out.
/// Never panics and never allocates.
pub struct LogReader<'a> {
    bytes: &'a [u8],
    pos: usize,
    decoder: Decoder,
    pending: usize,
    next_seq: Option<u16>,
    stats: ReadStats,
}

impl<'a> LogReader<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Self {
            bytes,
            pos: 0,
            decoder: Decoder::new(),
            pending: 0,
            next_seq: None,
            stats: ReadStats::default(),
        }
    }

    /// What was skipped so far (complete after the last record).
    pub fn stats(&self) -> ReadStats {
        self.stats
    }
}

impl Iterator for LogReader<'_> {
    type Item = LogRecord;

    fn next(&mut self) -> Option<LogRecord> {
        while self.pos < self.bytes.len() {
            let byte = self.bytes[self.pos];
            self.pos += 1;
            self.pending = if byte == 0 { 0 } else { self.pending + 1 };
            let Some(result) = self.decoder.push(byte) else { continue };
            let Ok(frame) = result else {
                self.stats.bad_frames += 1;
                continue;
            };
            let record = decode_record(frame.id, frame.payload);
            let Some(record) = record else {
                self.stats.bad_frames += 1;
                continue;
            };
            if let LogRecord::Header(_) = record {
                self.next_seq = None;
            }
            if let Some(expected) = self.next_seq {
                self.stats.missing_records += u32::from(frame.seq.wrapping_sub(expected));
            }
            self.next_seq = Some(frame.seq.wrapping_add(1));
            return Some(record);
        }
        self.stats.torn_tail_bytes = self.pending as u32;
        None
    }
}

fn decode_record(id: u8, payload: &[u8]) -> Option<LogRecord> {
    fn parse<'de, T: Deserialize<'de>>(payload: &'de [u8]) -> Option<T> {
        match postcard::take_from_bytes::<T>(payload) {
            Ok((value, [])) => Some(value),
            _ => None,
        }
    }
    Some(match id {
        id::HEADER => LogRecord::Header(parse(payload)?),
        id::PARAMS => LogRecord::Params(parse(payload)?),
        id::COMMAND => LogRecord::Command(parse(payload)?),
        id::STEP => LogRecord::Step(parse(payload)?),
        id::WORK => {
            let v1: WorkRecordV1 = parse(payload)?;
            LogRecord::Work(WorkRecord {
                after_step: v1.after_step,
                work: v1.work,
                samples_processed: None,
            })
        }
        id::WORK_AT => LogRecord::Work(parse(payload)?),
        id::ADOPTED => LogRecord::Adopted(parse(payload)?),
        id::ARMING => LogRecord::Arming(parse(payload)?),
        id::STATE => LogRecord::State(parse(payload)?),
        id::DROPPED => LogRecord::Dropped(parse(payload)?),
        id::END => LogRecord::End(parse(payload)?),
        id::LEARNER => LogRecord::Learner(parse(payload)?),
        id::FLIGHT => LogRecord::Flight(parse(payload)?),
        _ => return None,
    })
}

/// Follows [`ParamsRecord`]s to the parameter set they describe.
#[derive(Clone, Debug)]
pub struct ParamsAssembler {
    slots: [f32; PARAM_SLOTS],
    /// Slots written since the file began (all of them once the first set is complete).
    seen: [bool; PARAM_SLOTS],
}

impl Default for ParamsAssembler {
    fn default() -> Self {
        Self { slots: [0.0; PARAM_SLOTS], seen: [false; PARAM_SLOTS] }
    }
}

impl ParamsAssembler {
    /// Take a part; returns the set as it stands once every slot is known and the set
    /// validates (`None` before, and for a part that does not fit the set).
    pub fn push(&mut self, record: &ParamsRecord) -> Option<Params> {
        let offset = usize::from(record.offset);
        let end = offset + record.values.len();
        if end > PARAM_SLOTS {
            return None;
        }
        self.slots[offset..end].copy_from_slice(&record.values);
        self.seen[offset..end].fill(true);
        if !self.seen.iter().all(|&seen| seen) {
            return None;
        }
        Params::from_slots(&self.slots)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Files kept in memory; refuses files while `no_card`.
    #[derive(Default)]
    struct Memory {
        files: Vec<Vec<u8>>,
        open: bool,
        no_card: bool,
        opens: u32,
    }

    impl LogFiles for Memory {}

    impl LogSink for Memory {
        fn open(&mut self) -> Result<u32, LogSinkError> {
            self.opens += 1;
            if self.no_card {
                return Err(LogSinkError::NoCard);
            }
            self.files.push(Vec::new());
            self.open = true;
            Ok(self.files.len() as u32)
        }
        fn write_block(&mut self, block: &[u8; LOG_BLOCK_LEN]) -> Result<(), LogSinkError> {
            assert!(self.open, "a block outside a file");
            self.files.last_mut().unwrap().extend_from_slice(block);
            Ok(())
        }
        fn close(&mut self) -> Result<(), LogSinkError> {
            self.open = false;
            Ok(())
        }
    }

    /// A record's bytes (to compare records holding NaN bit for bit).
    fn postcard_bytes<T: Serialize>(record: &T) -> Vec<u8> {
        postcard::to_allocvec(record).unwrap()
    }

    fn step(step: u32, armed: bool) -> LogEntry {
        LogEntry::Step(StepEntry {
            step,
            t_us: u64::from(step) * 500,
            imu: Some(ImuSample {
                gyro_rad_s: [f32::NAN, step as f32, -1.0],
                accel_mps2: [0.0, 0.5, -9.81],
            }),
            motor_count: 4,
            speeds_rad_s: [Some(100.0), None, Some(f32::NAN), Some(3.0), None, None, None, None],
            commands: [0.25, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            phase: if armed { FlightPhase::WaitingForThrow } else { FlightPhase::Idle },
            armed,
            ..Default::default()
        })
    }

    /// The control loop's state at an arming goes to the head of the file that arming begins,
    /// whole and decodable; a second arming in the same file frees the box without writing;
    /// an offer while the box still holds an unwritten state is refused, and a file begun
    /// without its state is counted.
    #[test]
    fn a_file_begun_at_an_arming_carries_the_control_loops_state_there() {
        use crate::app::{ControlConfig, ControlLoop, SampleQueue};
        let mut samples = SampleQueue::new();
        let (sample_producer, _samples_out) = crate::app::split_queue(&mut samples);
        let control = ControlLoop::new(ControlConfig::default(), sample_producer);
        let state = *control.state();
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory::default();
        let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000);
        let arm = |step| LogEntry::Command { step, command: ControlCommand::ArmThrowToFly };
        for t in 1..=10 {
            producer.push(step(t, false));
        }
        let tag = ArmingTag { step: 11, samples_before: 9 };
        assert!(producer.offer_arming(tag, &state));
        assert!(!producer.offer_arming(ArmingTag { step: 12, ..tag }, &state), "the box is full");
        producer.push(arm(11));
        logger.drain();
        for t in 11..=20 {
            producer.push(step(t, true));
        }
        // A second arming while the file is open: no new file, the box is let go.
        assert!(producer.offer_arming(ArmingTag { step: 21, samples_before: 19 }, &state));
        producer.push(arm(21));
        producer.push(step(21, true));
        logger.drain();
        assert!(producer.offer_arming(ArmingTag { step: 22, samples_before: 20 }, &state));
        logger.finish();
        assert_eq!((logger.status().files, logger.status().arming_states_missing), (1, 0));
        let records: Vec<_> = LogReader::new(&sink.files[0]).collect();
        let announced: Vec<_> = records
            .iter()
            .filter_map(|r| match r {
                LogRecord::Arming(a) => Some(*a),
                _ => None,
            })
            .collect();
        assert_eq!(announced.len(), 1, "one state, at the head of the file");
        assert_eq!(announced[0].tag, tag);
        let mut bytes = Vec::new();
        for record in &records {
            if let LogRecord::State(chunk) = record {
                assert_eq!(chunk.offset as usize, bytes.len(), "chunks in order");
                bytes.extend_from_slice(&chunk.bytes);
            }
        }
        assert_eq!(bytes.len(), announced[0].len as usize);
        let decoded: ControlState = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(postcard::to_allocvec(&decoded).unwrap(), bytes, "decodes to the same state");
        let first_step = records.iter().position(|r| matches!(r, LogRecord::Step(_)));
        let last_chunk = records.iter().rposition(|r| matches!(r, LogRecord::State(_)));
        assert!(last_chunk < first_step, "the state comes before the first step");
    }

    #[test]
    fn a_file_begun_without_the_state_of_its_arming_is_counted() {
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory::default();
        let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000);
        producer.push(LogEntry::Command { step: 1, command: ControlCommand::ArmThrowToFly });
        producer.push(step(1, true));
        logger.finish();
        assert_eq!((logger.status().files, logger.status().arming_states_missing), (1, 1));
        let records: Vec<_> = LogReader::new(&sink.files[0]).collect();
        assert!(!records.iter().any(|r| matches!(r, LogRecord::Arming(_) | LogRecord::State(_))));
    }

    #[test]
    fn an_entry_is_a_small_copy_and_a_step_record_under_100_bytes() {
        // What the 2 kHz tick copies per step, and what a step costs in the file.
        // 176: the landing's and the sticks' settings (issue 53) ride in `ControlSettings`.
        assert!(core::mem::size_of::<LogEntry>() <= 176, "{}", core::mem::size_of::<LogEntry>());
        let LogEntry::Step(entry) = step(u32::MAX, true) else { unreachable!() };
        let entry = StepEntry { t_us: 3_600_000_000, ..entry };
        let mut frame = [0u8; MAX_FRAME_LEN];
        let record = StepLogRecord::from_entry(&entry);
        let len = protocol::frame::encode(id::STEP, u16::MAX, &record, &mut frame).unwrap();
        assert!(len <= 100, "{len} bytes");
    }

    #[test]
    fn a_file_per_arming_from_the_arming_to_the_linger_after_the_disarm_reads_back_exactly() {
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory::default();
        let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000);
        let linger_steps = (LOG_LINGER_S * 2000.0) as u32;
        let mut expected = Vec::new();
        let mut t = 1;
        // 10 steps disarmed (not logged), an arming, 50 armed steps, the disarm, the linger.
        for _ in 0..10 {
            producer.push(step(t, false));
            t += 1;
            logger.drain();
        }
        let arm = LogEntry::Command { step: t, command: ControlCommand::ArmThrowToFly };
        producer.push(arm);
        logger.drain();
        expected.push(arm);
        for i in 0..50 + 1 + linger_steps + 10 {
            let entry = step(t, i < 50);
            producer.push(entry);
            logger.drain();
            // Closed at the step 2 s after the last armed one (i = 49).
            if i <= 49 + linger_steps {
                expected.push(entry);
            }
            t += 1;
        }
        logger.work(&BackgroundWork::Command(BackgroundCommand::StartCalibration), 0);
        logger.finish();
        assert_eq!(logger.status().files, 1);
        assert_eq!(sink.files.len(), 1, "one arming, one file");
        let bytes = &sink.files[0];
        assert_eq!(bytes.len() % LOG_BLOCK_LEN, 0);
        let mut reader = LogReader::new(bytes);
        let Some(LogRecord::Header(header)) = reader.next() else { panic!("no header") };
        assert_eq!((header.first_step, header.always, header.board.as_str()), (11, false, "TEST"));
        let mut params = ParamsAssembler::default();
        let mut read = Vec::new();
        let mut end = None;
        for record in reader.by_ref() {
            match record {
                LogRecord::Params(part) => {
                    if let Some(p) = params.push(&part) {
                        assert_eq!(p, Params::default());
                    }
                }
                LogRecord::Command(c) => read.push(LogEntry::Command {
                    step: c.step,
                    command: c.command.to_command(&Params::default()).unwrap(),
                }),
                LogRecord::Step(s) => {
                    let LogEntry::Step(original) = expected[read.len()] else {
                        panic!("a step where a command was logged")
                    };
                    assert_eq!(
                        postcard_bytes(&StepLogRecord::from_entry(&original)),
                        postcard_bytes(&s)
                    );
                    // NaN and None survive bit for bit.
                    assert_eq!(s.imu.unwrap()[0].to_bits(), f32::NAN.to_bits());
                    assert_eq!(s.speeds_rad_s[1], None);
                    read.push(LogEntry::Step(original));
                }
                LogRecord::End(e) => end = Some(e),
                other => panic!("unexpected {other:?}"),
            }
        }
        // Every entry in order (steps compared bit for bit above; NaN != NaN for `==`).
        assert_eq!(read.len(), expected.len());
        assert_eq!(read[0], arm);
        assert_eq!(
            end.map(|e| e.last_step),
            Some(11 + 49 + linger_steps),
            "closed after the linger"
        );
        assert_eq!(reader.stats(), ReadStats::default(), "nothing damaged, nothing torn");
    }

    /// An adoption rides in its step's entry and is written just before that step's record; a
    /// format 1–3 work record (no sample count) still reads, as work with none.
    #[test]
    fn an_adoption_is_written_before_its_step_and_old_work_records_still_read() {
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory::default();
        let mut always = Params::default();
        always.set(super::super::params::find(b"log_always").unwrap(), &[1.0]).unwrap();
        let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000).with_params(&always);
        let adoption = Adoption { samples_processed: 41, samples_dropped: 2 };
        for t in 1..=3 {
            let LogEntry::Step(entry) = step(t, false) else { unreachable!() };
            let adopted = (t == 2).then_some(adoption);
            producer.push(LogEntry::Step(StepEntry { adopted, ..entry }));
        }
        logger.finish();
        let records: Vec<_> = LogReader::new(&sink.files[0]).collect();
        let LogRecord::Header(header) = &records[0] else { panic!() };
        assert_eq!(header.first_step, 1, "log_always from the start-up parameters: step 1");
        let order: Vec<String> = records
            .iter()
            .filter_map(|r| match r {
                LogRecord::Step(s) => Some(format!("step {}", s.step)),
                LogRecord::Adopted(a) => {
                    Some(format!("adopted {} {}", a.step, a.samples_processed))
                }
                _ => None,
            })
            .collect();
        assert_eq!(order, ["step 1", "adopted 2 41", "step 2", "step 3"]);
        assert!(records.contains(&LogRecord::Adopted(AdoptedRecord {
            step: 2,
            samples_processed: 41,
            samples_dropped: 2
        })));

        let old = WorkRecordV1 { after_step: 7, work: LoggedWork::Configure };
        let mut frame = [0u8; MAX_FRAME_LEN];
        let len = protocol::frame::encode(id::WORK, 0, &old, &mut frame).unwrap();
        let read: Vec<_> = LogReader::new(&frame[..len]).collect();
        let expected =
            WorkRecord { after_step: 7, work: LoggedWork::Configure, samples_processed: None };
        assert_eq!(read, [LogRecord::Work(expected)]);
    }

    #[test]
    fn with_log_always_one_file_runs_from_the_first_step_and_work_is_logged_after_its_step() {
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory::default();
        let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000);
        let mut always = Params::default();
        always.set(super::super::params::find(b"log_always").unwrap(), &[1.0]).unwrap();
        logger.work(&BackgroundWork::Configure(always), 0);
        for t in 1..=10_000 {
            producer.push(step(t, false));
            logger.drain();
            if t == 5 {
                logger.work(&BackgroundWork::Command(BackgroundCommand::StopCalibration), 4);
            }
        }
        // A changed set is written as the part that changed.
        let mut changed = always;
        changed.set(super::super::params::find(b"motor_tau_s").unwrap(), &[0.03; 8]).unwrap();
        logger.work(&BackgroundWork::Configure(changed), 9_000);
        logger.finish();
        assert_eq!(sink.files.len(), 1);
        let records: Vec<_> = LogReader::new(&sink.files[0]).collect();
        let LogRecord::Header(header) = &records[0] else { panic!() };
        assert!(header.always && header.first_step == 1);
        let steps = records.iter().filter(|r| matches!(r, LogRecord::Step(_))).count();
        assert_eq!(steps, 10_000);
        let work = records.iter().find_map(|r| match r {
            LogRecord::Work(w) => Some(*w),
            _ => None,
        });
        let expected = WorkRecord {
            after_step: 5,
            work: LoggedWork::StopCalibration,
            samples_processed: Some(4),
        };
        assert_eq!(work, Some(expected));
        let parts = records.iter().filter(|r| matches!(r, LogRecord::Params(_))).count();
        let whole_set = PARAM_SLOTS.div_ceil(PARAMS_CHUNK_SLOTS);
        assert!(
            parts < whole_set + 3,
            "{parts} parts: the whole set at the start, then the change"
        );
        let mut assembler = ParamsAssembler::default();
        let last = records.iter().filter_map(|r| match r {
            LogRecord::Params(part) => assembler.push(part),
            _ => None,
        });
        assert_eq!(last.last(), Some(changed));
    }

    #[test]
    fn without_a_card_an_arming_is_refused_once_and_counted_and_nothing_is_written() {
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory { no_card: true, ..Default::default() };
        let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000);
        for t in 1..=2000 {
            producer.push(step(t, (100..1000).contains(&t)));
            logger.drain();
        }
        for t in 2001..=3000 {
            producer.push(step(t, true));
            logger.drain();
        }
        let status = logger.status();
        assert_eq!(status.open_failures, 2, "one try per arming");
        assert_eq!(status.last_error, Some(LogSinkError::NoCard));
        assert_eq!((status.files, status.blocks), (0, 0));
        assert_eq!(sink.opens, 2);
    }

    #[test]
    fn a_full_ring_drops_whole_entries_counted_and_the_file_says_so() {
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory::default();
        let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000);
        producer.push(LogEntry::Command { step: 1, command: ControlCommand::ArmThrowToFly });
        let mut t = 1;
        // The logger stalls (an SD card busy) for 200 steps more than the ring holds.
        let stalled = LOG_RING_LEN as u32 + 200;
        for _ in 0..stalled {
            let LogEntry::Step(entry) = step(t, true) else { unreachable!() };
            producer.push(LogEntry::Step(StepEntry { ring_dropped: producer.dropped(), ..entry }));
            t += 1;
        }
        let held = LOG_RING_LEN as u32 - 1;
        assert_eq!(producer.dropped(), stalled + 1 - held);
        logger.drain();
        let LogEntry::Step(entry) = step(t, true) else { unreachable!() };
        producer.push(LogEntry::Step(StepEntry { ring_dropped: producer.dropped(), ..entry }));
        logger.finish();
        let records: Vec<_> = LogReader::new(&sink.files[0]).collect();
        let steps: Vec<u32> = records
            .iter()
            .filter_map(|r| match r {
                LogRecord::Step(s) => Some(s.step),
                _ => None,
            })
            .collect();
        // The ring kept the arming and `held - 1` steps, then the next step.
        assert_eq!(steps[..steps.len() - 1], (1..held).collect::<Vec<_>>()[..]);
        assert_eq!(*steps.last().unwrap(), stalled + 1, "the gap is visible in the step numbers");
        let dropped = DroppedRecord { entries: stalled + 1 - held };
        assert!(records.contains(&LogRecord::Dropped(dropped)));
    }

    /// A microSD card's write time, as the simulated card below takes it: every single-block
    /// write (CMD24 at 25 MHz, 4-bit, with the card's programming) takes a time drawn uniformly
    /// from `write_us`, and every `stall_every_blocks` blocks one write takes `stall_us` instead
    /// (wear levelling, an allocation unit erased).
    #[derive(Clone, Copy, Debug)]
    struct CardTiming {
        write_us: (f64, f64),
        stall_every_blocks: u64,
        stall_us: f64,
    }

    /// What logging through a timed card left: entries the ring dropped, blocks written, the
    /// card's share of the time, and the file.
    struct TimedRun {
        dropped: u32,
        blocks: u64,
        card_busy_fraction: f64,
        file: Vec<u8>,
    }

    /// `seconds` of armed 2 kHz steps logged by the background task through a card timed as
    /// `timing`, in virtual time: the tick pushes one entry every 0.5 ms whatever the card does;
    /// the background drains while it is free and is held for each block's write time (the
    /// board's writes are polled: the lowest-priority task waits, nothing else does).
    fn log_through_a_timed_card(timing: CardTiming, seconds: f64) -> TimedRun {
        let step_us = 500u64;
        let (mut ring, mut arming) = (LogRing::new(), ArmingBox::new());
        let (mut producer, consumer) = split_log(&mut ring, &mut arming);
        let mut sink = Memory::default();
        let mut rng = flight::rng::Rng::new(11);
        let mut busy_total_us = 0.0;
        let mut bg_free_us = 0u64;
        let blocks;
        {
            let mut logger = Logger::new(consumer, &mut sink, "TEST", 2000);
            producer.push(LogEntry::Command { step: 1, command: ControlCommand::ArmThrowToFly });
            let steps = (seconds * 1e6 / step_us as f64) as u32;
            let mut seen_blocks = 0u64;
            for k in 1..=steps {
                let t_us = u64::from(k) * step_us;
                let LogEntry::Step(entry) = step(k, true) else { unreachable!() };
                producer
                    .push(LogEntry::Step(StepEntry { ring_dropped: producer.dropped(), ..entry }));
                let mut now_us = bg_free_us.max(t_us);
                while now_us < t_us + step_us && logger.drain_one() {
                    // The writer's own work per entry (encoding, CRC): a few µs on the M7.
                    now_us += 5;
                    let written = u64::from(logger.status().blocks);
                    for block in seen_blocks..written {
                        let write_us = if (block + 1) % timing.stall_every_blocks == 0 {
                            timing.stall_us
                        } else {
                            let (low, high) = timing.write_us;
                            low + (high - low) * rng.uniform()
                        };
                        busy_total_us += write_us;
                        now_us += write_us as u64;
                    }
                    seen_blocks = written;
                }
                bg_free_us = now_us;
            }
            blocks = seen_blocks;
            logger.finish();
        }
        let elapsed_us = bg_free_us.max((seconds * 1e6) as u64) as f64;
        TimedRun {
            dropped: producer.dropped(),
            blocks,
            card_busy_fraction: busy_total_us / elapsed_us,
            file: sink.files.swap_remove(0),
        }
    }

    /// Typical cards of speed class 10 and up: single-block writes of 0.25–1.5 ms and a 40 ms
    /// stall every 1,024 blocks (about 3 s of log). The ring rides every stall out: nothing is
    /// dropped, and the card is busy a fraction of the time, so the background catches up after
    /// each stall.
    #[test]
    fn a_card_at_typical_write_times_loses_no_entry() {
        let timing =
            CardTiming { write_us: (250.0, 1500.0), stall_every_blocks: 1024, stall_us: 40e3 };
        let run = log_through_a_timed_card(timing, 20.0);
        let blocks_per_s = run.blocks as f64 / 20.0;
        std::eprintln!(
            "typical card: {} blocks ({blocks_per_s:.0} a second, {:.0} kB/s), card busy {:.0} % \
             of the time, {} entries dropped",
            run.blocks,
            blocks_per_s * LOG_BLOCK_LEN as f64 / 1e3,
            run.card_busy_fraction * 100.0,
            run.dropped
        );
        assert_eq!(run.dropped, 0);
        // The log's rate at 2 kHz (steps of at most 100 bytes): 150–400 blocks a second.
        assert!((150.0..400.0).contains(&blocks_per_s), "{blocks_per_s} blocks/s");
        assert!(run.card_busy_fraction < 0.6, "{}", run.card_busy_fraction);
        let steps = LogReader::new(&run.file).filter(|r| matches!(r, LogRecord::Step(_))).count();
        assert_eq!(steps, 40_000, "every step in the file");
    }

    /// The SD specification's worst case, a write busy for 250 ms, is ridden out (the ring holds
    /// 255 ms at 2 kHz); a card stalled for 400 ms, beyond any card within the specification,
    /// loses the steps of the ~145 ms the ring cannot hold, whole, counted by the tick, and the
    /// file says how many where they were lost and reads back on both sides of the gap.
    #[test]
    fn a_stall_the_ring_cannot_hold_drops_whole_entries_counted_in_the_file() {
        let spec =
            CardTiming { write_us: (250.0, 1500.0), stall_every_blocks: 1024, stall_us: 250e3 };
        let run = log_through_a_timed_card(spec, 5.0);
        std::eprintln!("250 ms stall: {} blocks, {} entries dropped", run.blocks, run.dropped);
        assert_eq!(run.dropped, 0, "the specification's worst case is ridden out");
        let beyond = CardTiming { stall_us: 400e3, ..spec };
        let run = log_through_a_timed_card(beyond, 5.0);
        let records: Vec<_> = LogReader::new(&run.file).collect();
        let dropped_in_file: u32 = records
            .iter()
            .map(|r| match r {
                LogRecord::Dropped(d) => d.entries,
                _ => 0,
            })
            .sum();
        let steps = records.iter().filter(|r| matches!(r, LogRecord::Step(_))).count() as u32;
        std::eprintln!(
            "400 ms stall: {} blocks, {} entries dropped ({} in the file), {steps} steps kept",
            run.blocks,
            run.dropped,
            dropped_in_file
        );
        // One stall in 5 s (about 1,700 blocks): 400 ms less the ring's 255 ms, at 2 kHz.
        assert!((250..=330).contains(&run.dropped), "{} dropped", run.dropped);
        assert_eq!(dropped_in_file, run.dropped, "every drop is in the file");
        assert_eq!(steps + run.dropped, 10_000, "kept and dropped steps account for all");
    }
}
