//! The message table: every type that crosses the link, in this one file.
//!
//! The schema hash ([`crate::SCHEMA_HASH`]) is computed from this file's text with comments and
//! white space removed, so any change to a wire type changes the hash. A change to the golden
//! bytes in `tests/golden.rs` is a protocol version change: bump [`crate::PROTOCOL_VERSION`].
//!
//! Frozen across all major versions, so that two sides of different majors can still tell each
//! other so: the ids of [`Request::Hello`] and [`DeviceMessage::Response`], the layout of
//! [`Hello`], the `Result` envelope of [`Response`], [`Reply::Hello`] being variant 0 with
//! [`Info::protocol`] as its first field, and [`DeviceError::IncompatibleProtocol`] being variant 0.
//!
//! Only fixed-size types go on the wire: integers of stated width, `f32`, arrays, and
//! `heapless::String` with a stated capacity. Never `usize`.

use heapless::String;
use serde::{Deserialize, Serialize};

/// Capacity of the board-name string, bytes of UTF-8.
pub const BOARD_NAME_LEN: usize = 32;
/// Capacity of a parameter or field name in an error, bytes of UTF-8.
pub const NAME_LEN: usize = 24;
/// Capacity of a unit label in an error, bytes of UTF-8.
pub const UNIT_LEN: usize = 8;
/// Maximum number of motors an airframe may have; fixes array sizes on the wire.
pub const MAX_MOTORS: usize = 8;
/// Number of telemetry topics (the variants of [`Topic`]).
pub const TOPIC_COUNT: usize = 6;
/// Highest telemetry rate a host may request for one topic, Hz: the 2 kHz control rate. The
/// per-step topics ([`Topic::is_per_step`]) reach it, every control step's sample; the others are
/// sampled by the link task, at most once per pass (1 kHz on the board and in the SITL).
pub const MAX_TELEMETRY_RATE_HZ: u16 = 2000;
/// Most elements one parameter may have (one per motor for the per-motor arrays).
pub const PARAM_MAX_LEN: usize = 8;
/// Capacity of a parameter's unit label, bytes of UTF-8 ("rad/s²/(rad/s²)" fits).
pub const PARAM_UNIT_LEN: usize = 20;
/// Capacity of a parameter's help text on the wire, bytes of UTF-8.
pub const PARAM_HELP_LEN: usize = 72;

/// A protocol version. Different majors cannot talk (both sides refuse, naming both versions);
/// a newer minor on either side degrades to what the older side knows.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Version {
    pub major: u8,
    pub minor: u8,
}

/// A firmware release version (semantic versioning).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct FirmwareVersion {
    pub major: u8,
    pub minor: u8,
    pub patch: u8,
}

/// What a board can do, as bit flags (`Capabilities::IMU | ...`).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Capabilities(pub u32);

impl Capabilities {
    /// An IMU driver is present and delivers samples.
    pub const IMU: u32 = 1 << 0;
    /// Motor outputs are driven.
    pub const MOTORS: u32 = 1 << 1;
    /// Motors report their speed (bidirectional DShot or the simulator).
    pub const MOTOR_RPM: u32 = 1 << 2;
    /// Telemetry topics can be streamed.
    pub const TELEMETRY: u32 = 1 << 3;
    /// Settings persist in flash.
    pub const PERSISTENT_STORE: u32 = 1 << 4;
    /// This is the software-in-the-loop simulator, not hardware.
    pub const SIMULATOR: u32 = 1 << 5;
    /// The board can restart into a bootloader for firmware updates (protocol 1.4).
    pub const BOOTLOADER: u32 = 1 << 6;
    /// A radio receiver is configured (protocol 1.4).
    pub const RECEIVER: u32 = 1 << 7;
    /// The motor outputs can send ESC commands ([`Request::EscCommand`], protocol 1.5).
    pub const ESC_COMMANDS: u32 = 1 << 8;
    /// The firmware identifies the motors without speed reports, from the commands and the
    /// body's response, when the ESCs cannot report (`motor_bidir_dshot` = 0): the simulators,
    /// and the board's image built for ESCs without bidirectional DShot. Without it, throw-to-fly
    /// needs every motor's speed (protocol 1.13).
    pub const IDENTIFIES_WITHOUT_SPEEDS: u32 = 1 << 9;

    /// Whether every flag in `flags` is set.
    pub fn has(self, flags: u32) -> bool {
        self.0 & flags == flags
    }
}

// ---------------------------------------------------------------------------------------------
// Host → device
// ---------------------------------------------------------------------------------------------

/// The first request on every connection. Frozen layout.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hello {
    /// The host's protocol version.
    pub protocol: Version,
    /// The host's [`crate::SCHEMA_HASH`].
    pub schema_hash: u64,
}

/// A telemetry topic.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Topic {
    /// Raw IMU samples ([`ImuTelemetry`]).
    Imu,
    /// Control-loop timing and health ([`ControlTelemetry`]).
    Control,
    /// Motor commands and speeds ([`MotorTelemetry`]).
    Motors,
    /// The in-flight learner's state and estimates ([`LearnerTelemetry`]).
    Learner,
    /// Every control step's state: IMU, attitude, motor commands and speeds, phase
    /// ([`StateTelemetry`]). Protocol 1.3.
    State,
    /// Closed-loop flight: attitude, rates, setpoints, allocation, position, failsafes
    /// ([`FlightTelemetry`]). Protocol 1.4.
    Flight,
}

impl Topic {
    /// All topics, in wire order.
    pub const ALL: [Topic; TOPIC_COUNT] =
        [Topic::Imu, Topic::Control, Topic::Motors, Topic::Learner, Topic::State, Topic::Flight];

    /// The topic's index into [`Topic::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Whether the control step writes this topic's samples (every step, into a ring the link
    /// drains), rather than the link sampling the latest state. A per-step topic at `rate_hz`
    /// sends every `round(control rate / rate_hz)`-th step, and its sequence number is the step
    /// count divided by that, so every sample lost anywhere is a gap.
    pub fn is_per_step(self) -> bool {
        matches!(self, Topic::Imu | Topic::Motors | Topic::State)
    }

    /// The longest frame one sample of this topic takes on the wire, bytes (delimiter included,
    /// every field at its longest): what a link's byte budget books per sample. Pinned by
    /// `protocol/tests/golden.rs` (`every_topic_sample_fits_its_booked_frame_length`).
    pub const fn max_frame_len(self) -> u16 {
        match self {
            Topic::Imu => 45,
            Topic::Control => 36,
            Topic::Motors => 93,
            Topic::Learner => 221,
            Topic::State => 137,
            Topic::Flight => 164,
        }
    }
}

/// Set how often a topic is streamed.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct SetTelemetryRate {
    pub topic: Topic,
    /// 0 stops the topic; 1 to [`MAX_TELEMETRY_RATE_HZ`] Hz.
    pub rate_hz: u16,
}

/// A pose from an external source (motion capture, a ground station): where the centre of
/// gravity is and which way the body points. Forwarded to the control step as it arrives.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct ExternalPose {
    /// Position of the centre of gravity, m, world NED.
    pub position_ned_m: [f32; 3],
    /// Heading: yaw of the body (thrust) frame about world z (down), rad.
    pub heading_rad: f32,
}

/// Where the craft should hold itself while flying with external poses (protocol 1.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct PositionSetpoint {
    /// Position of the centre of gravity to hold, m, world NED (the poses' world).
    pub position_ned_m: [f32; 3],
    /// Heading to hold: yaw of the thrust frame about world z (down), rad.
    pub heading_rad: f32,
}

/// Echo request for measuring round trips.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ping {
    pub nonce: u32,
}

/// The elements of one parameter's value (a scalar has one).
pub type ParamValues = heapless::Vec<f32, PARAM_MAX_LEN>;

/// Which parameter: by its place in the registry (for listing them all) or by name.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq)]
pub enum ParamRef {
    /// 0 to [`ParamInfo::count`] − 1.
    Index(u16),
    Name(String<NAME_LEN>),
}

/// Give a parameter a new value: every element, validated as a whole (nothing changes when any
/// element is refused).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct SetParam {
    pub name: String<NAME_LEN>,
    pub values: ParamValues,
}

/// End the IMU-offset calibration.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct StopCalibration {
    /// Store the estimate (offset, and the accelerometer bias when fitted) in the parameters;
    /// refused with [`DeviceError::NotReady`] unless it is well determined.
    pub accept: bool,
}

/// Spin one motor for a test (propellers off!). Repeat at least every
/// [`MOTOR_TEST_KEEPALIVE_MS`] to keep it spinning.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct MotorTest {
    /// Motor index from 0.
    pub motor: u8,
    /// Command δ, 0 to [`MOTOR_TEST_MAX_COMMAND`].
    pub command: f32,
}

/// Send an ESC command (a DShot special command: [`crate::DshotCommand`]) to one motor's ESC or
/// to all of them. The motors must be stopped: refused while a flight, an identification or a
/// motor test is armed.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct EscCommand {
    /// Motor index from 0, or [`ESC_ALL_MOTORS`].
    pub motor: u8,
    /// The command's DShot number ([`crate::DshotCommand::value`]); other numbers are refused
    /// with [`DeviceError::BadValue`] (`command`).
    pub command: u8,
}

/// [`EscCommand::motor`] meaning every motor.
pub const ESC_ALL_MOTORS: u8 = 0xFF;

/// A motor test stops by itself this long after its last request, ms.
pub const MOTOR_TEST_KEEPALIVE_MS: u32 = 3000;
/// Highest command a motor test may ask for (a bench test needs no more).
pub const MOTOR_TEST_MAX_COMMAND: f32 = 0.5;

// ---------------------------------------------------------------------------------------------
// Device → host
// ---------------------------------------------------------------------------------------------

/// The answer to every request (matched by the frame's sequence number).
pub type Response = Result<Reply, DeviceError>;

/// A successful answer.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub enum Reply {
    /// Answer to [`Request::Hello`]: the board's identity. Variant 0, frozen.
    Hello(Info),
    /// Answer to [`Request::GetInfo`].
    Info(Info),
    /// Answer to [`Request::GetStatus`].
    Status(Status),
    /// The request was carried out; nothing to report.
    Done,
    /// Answer to [`Request::Ping`], echoing its nonce.
    Pong(Ping),
    /// Answer to [`Request::GetLearner`].
    Learner(LearnerTelemetry),
    /// Answer to [`Request::GetParam`] and [`Request::SetParam`] (with the value now in force).
    Param(ParamInfo),
    /// Answer to [`Request::GetConfig`], [`Request::SaveConfig`], [`Request::ResetConfig`] and
    /// an accepted [`Request::StopCalibration`].
    Config(ConfigStatus),
    /// Answer to [`Request::GetFlight`]. Protocol 1.4.
    Flight(FlightTelemetry),
    /// Answer to [`Request::GetBoard`]. Protocol 1.4.
    Board(BoardHealth),
    /// Answer to [`Request::GetHealth`]. Protocol 1.6.
    Health(SensorHealth),
    /// Answer to [`Request::GetLinkSecurity`]. Protocol 1.8.
    LinkSecurity(LinkSecurity),
    /// Answer to [`Request::ListLogs`]. Protocol 1.9.
    LogList(LogList),
    /// Answer to [`Request::ReadLog`]. Protocol 1.9.
    LogChunk(LogChunk),
    /// Answer to [`Request::SetTelemetryRate`]: the rate granted, which is the one asked, or
    /// the highest the link's byte budget leaves for the topic (0: none), or the nearest a
    /// per-step topic can send (the control rate over a whole number of steps). Protocol 1.10.
    TelemetryRate(SetTelemetryRate),
    /// Answer to [`Request::GetBattery`]. Protocol 1.11.
    Battery(BatteryStatus),
    /// Answer to [`Request::GetIdentification`]. Protocol 1.12.
    Identification(IdentificationStatus),
    /// Answer to [`Request::GetGnss`]. Protocol 1.16.
    Gnss(GnssHealth),
    /// Answer to [`Request::GetCompass`]. Protocol 1.17.
    Compass(CompassHealth),
}

/// How the latest throw-to-fly identification was made (protocol 1.12,
/// [`Request::GetIdentification`]): which path gave the motor speeds, and where the IMU offset
/// came from.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct IdentificationStatus {
    /// The motor speeds were modelled from the commands (ESCs without bidirectional DShot;
    /// docs/algorithms/learner.md, "Without speed telemetry"), not measured. Measured speeds
    /// are the better path.
    pub speeds_modelled: bool,
    /// Where the IMU offset the identification used came from.
    pub imu_offset_source: ImuOffsetSource,
    /// That offset: IMU position relative to the centre of gravity, m, IMU axes.
    pub r_imu_m: [f32; 3],
    /// Whether [`Status::imu_offset`] shows the offset fitted in this flight (its 95 %
    /// ellipsoid and verdict) rather than the onboard estimator's throws.
    pub imu_offset_status_fitted_in_flight: bool,
}

/// Where the IMU offset of an identification came from (protocol 1.12).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ImuOffsetSource {
    /// No identification since start-up.
    #[default]
    NotUsed,
    /// The stored calibration (`imu_offset_m` with `imu_offset_valid` = 1).
    Configured,
    /// The onboard estimator's throws (well determined).
    Onboard,
    /// None known and none fitted: zero (the specific-force rows are then biased at high rates).
    Zero,
    /// Fitted in this flight, jointly with the specific-force rows of G1 (no calibration
    /// throw; docs/algorithms/imu-offset.md, "In flight, with no calibration").
    FittedInFlight,
}

/// The flight battery as the board measures it (protocol 1.11, [`Request::GetBattery`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct BatteryStatus {
    /// Pack voltage, V, low-pass filtered.
    pub voltage_v: f32,
    /// Current drawn, A, low-pass filtered.
    pub current_a: f32,
    /// Charge drawn since start-up, mAh.
    pub used_mah: f32,
    /// Cells in series, estimated from the first voltage measured (0: no pack connected).
    pub cells: u8,
    /// Charge left, %, estimated from the voltage per cell (reads low under load).
    pub remaining_pct: u8,
}

/// How the link that asked is guarded ([`crate::signing`]). Protocol 1.8.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct LinkSecurity {
    /// This link is trusted (USB, the simulator's own link): unsigned requests are carried out.
    /// On an untrusted one (a radio) requests that configure, arm, spin or steer must be signed.
    pub trusted: bool,
    /// A link key is set (the board has been paired).
    pub paired: bool,
    /// The board's session for this start-up: signatures cover it, so a frame signed before a
    /// restart fails after it.
    pub session: u64,
    /// The greatest signed timestamp this link accepted since start-up (10 µs since 2015-01-01
    /// UTC; 0 when none): a signed request on it must carry a greater one.
    pub last_timestamp: u64,
    /// Requests this link refused for want of a signature, since start-up.
    pub unsigned_refused: u32,
    /// Signed requests on this link whose signature did not verify, since start-up.
    pub bad_signature: u32,
    /// Signed requests on this link refused as replays, since start-up.
    pub replayed: u32,
}

/// Set or clear the link key ([`crate::signing`]). Accepted only on a trusted link and while
/// disarmed; stored in flash at once. Protocol 1.8.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq)]
pub struct SetLinkKey {
    /// The new key ([`crate::signing::KEY_LEN`] bytes; another length is refused as
    /// [`DeviceError::Malformed`]), or `None` to unpair (every signed request then fails
    /// until the next pairing). A sequence rather than an array: serde unrolls arrays, and this
    /// saves the board 0.6 KB of flash.
    pub key: Option<heapless::Vec<u8, { crate::signing::KEY_LEN }>>,
}

/// Files listed per [`Request::ListLogs`] answer (a host asks again from the next number when
/// [`LogList::more`]). 16 entries of at most 11 bytes fit a frame with room to spare.
pub const LOG_LIST_LEN: usize = 16;
/// Most bytes one [`Request::ReadLog`] answer carries: the largest answer (every number at its
/// widest varint, `seq` 65,535) is 251 raw bytes, within the 253 that always fit a frame
/// (`protocol/tests/golden.rs`).
pub const LOG_CHUNK_LEN: usize = 224;

/// List the flight-log files numbered `first` or more. Protocol 1.9.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct ListLogs {
    pub first: u32,
}

/// One flight-log file (`LOG00001.BIN` is number 1). Protocol 1.9.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LogFileInfo {
    pub number: u32,
    /// Bytes in the file now (whole 512-byte blocks).
    pub size_bytes: u32,
    /// The file is still being written: it grows, and cannot be deleted yet.
    pub writing: bool,
}

/// Up to [`LOG_LIST_LEN`] files in ascending number, from [`ListLogs::first`]. Protocol 1.9.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq)]
pub struct LogList {
    pub files: heapless::Vec<LogFileInfo, LOG_LIST_LEN>,
    /// More files follow the last listed: ask again from its number + 1.
    pub more: bool,
}

/// Read `len` bytes (at most [`LOG_CHUNK_LEN`]) of log file `number` from byte `offset`.
/// Reading changes nothing, so a lost answer is simply asked for again. Protocol 1.9.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadLog {
    pub number: u32,
    pub offset: u32,
    pub len: u16,
}

/// Bytes of a log file, with where they came from so the reader can check and resume.
/// Protocol 1.9.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq)]
pub struct LogChunk {
    pub number: u32,
    /// Offset of `bytes[0]` in the file.
    pub offset: u32,
    /// The file's size now, bytes (grows while it is written).
    pub size_bytes: u32,
    /// Fewer than asked for only at the end of the file (none at the end).
    pub bytes: heapless::Vec<u8, LOG_CHUNK_LEN>,
}

/// Delete log file `number`. Refused while armed and for the file being written. Protocol 1.9.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeleteLog {
    pub number: u32,
}

/// Why a request was not carried out. Each variant's doc states what the host should do.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub enum DeviceError {
    /// Major protocol versions differ: nothing else will be answered. Update the older side.
    /// Variant 0, frozen.
    IncompatibleProtocol { device: Version, host: Version },
    /// Only [`Request::Hello`] is answered before a successful handshake: send it first.
    HandshakeRequired,
    /// The request's message id is not in the device's table (a newer host?): not carried out.
    UnknownRequest { id: u8 },
    /// The request's payload did not decode for its id: not carried out; a host bug.
    Malformed { id: u8 },
    /// A value is outside its allowed range: nothing was changed.
    BadValue { name: String<NAME_LEN>, value: f32, min: f32, max: f32, unit: String<UNIT_LEN> },
    /// The device is busy with an operation that excludes this one: retry later.
    Busy,
    /// Refused because the craft is armed: disarm first.
    RefusedWhileArmed,
    /// No parameter has this name (or index): nothing was changed. `dump` lists them.
    UnknownParam { name: String<NAME_LEN> },
    /// The parameter has `expected` elements, the request gave `got`: nothing was changed.
    WrongLength { name: String<NAME_LEN>, expected: u8, got: u8 },
    /// The parameter takes whole numbers (or 0/1 for a flag): nothing was changed.
    NotAnInteger { name: String<NAME_LEN>, value: f32 },
    /// The flash refused the configuration (`stage` says where): the configuration in force is
    /// unchanged and the previously saved one is still there.
    StorageFailed { stage: StorageStage },
    /// The operation needs something that is not there yet (a well-determined calibration, a
    /// running calibration): see the status.
    NotReady,
    /// This device cannot do that (the simulator has no bootloader): nothing was changed.
    /// Protocol 1.4.
    Unsupported,
    /// Refused to arm for throw-to-fly: bit i of `motors` set = motor i reported no speed
    /// recently ([`SensorHealth::speeds_reported`]). The in-flight learner needs every motor's
    /// speed (bidirectional DShot): check the ESCs' telemetry (ESC firmware, wiring, the
    /// `motor_bidir_dshot` parameter). Nothing was armed. Protocol 1.6.
    SpeedsNotReported { motors: u8 },
    /// This link is not trusted (a radio) and the request configures, arms, spins or steers
    /// the craft: it must be signed with the key paired over USB (`configurator-cli pair`).
    /// Nothing was changed. Protocol 1.8.
    SignatureRequired,
    /// The request's signature is not the paired key's (or no key is paired): nothing was
    /// changed. Protocol 1.8.
    BadSignature,
    /// The signature's timestamp is not greater than `last_timestamp`, the greatest this link
    /// accepted since start-up: a replayed frame, or a host clock behind (sign with a later timestamp).
    /// Nothing was changed. Protocol 1.8.
    Replayed { last_timestamp: u64 },
    /// Only a trusted link (USB) may do that (set the link key). Protocol 1.8.
    TrustedLinkOnly,
    /// No flight-log file has this number ([`Request::ListLogs`] lists them). Protocol 1.9.
    NoSuchLog { number: u32 },
    /// The read begins past the end of the file, which holds `size_bytes` bytes now (a read at
    /// exactly the end answers an empty chunk). Protocol 1.9.
    LogOffsetPastEnd { number: u32, size_bytes: u32 },
    /// The file is still being written (the craft flies, or lingers after a disarm): it cannot
    /// be deleted yet. Nothing was changed. Protocol 1.9.
    LogBeingWritten { number: u32 },
    /// The log storage failed to read or delete (a card or file-system error). Protocol 1.9.
    LogStorageFailed,
}

/// Where a configuration save or load failed.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum StorageStage {
    /// The board has no configuration store.
    NoStore,
    /// Reading the stored configuration.
    Read,
    /// Writing or erasing the flash.
    Write,
    /// The configuration did not fit the store's buffer (a firmware bug).
    TooLarge,
}

/// The board's identity and abilities (the handshake reply).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct Info {
    /// The device's protocol version. First field, frozen.
    pub protocol: Version,
    /// The device's [`crate::SCHEMA_HASH`].
    pub schema_hash: u64,
    pub firmware: FirmwareVersion,
    /// Board name, e.g. "STM32H743" or "SITL".
    pub board: String<BOARD_NAME_LEN>,
    /// Unique id of this board (the MCU's UID in hex, or the simulator's instance id).
    pub serial: String<BOARD_NAME_LEN>,
    pub capabilities: Capabilities,
    /// Rate of the control step, Hz.
    pub control_rate_hz: u16,
    /// Number of motor outputs configured.
    pub motor_count: u8,
}

/// A snapshot of the board's state.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct Status {
    /// Time since start-up, ms.
    pub uptime_ms: u32,
    pub armed: bool,
    pub control: ControlStatus,
    pub imu: ImuStatus,
    pub imu_offset: ImuOffsetStatus,
    pub link: LinkCounters,
}

/// Health of the 2 kHz control step and of the queue into the background task.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct ControlStatus {
    /// Control steps run since start-up.
    pub steps: u32,
    /// Measured mean step rate over the last second, Hz.
    pub rate_hz: f32,
    /// Steps that started more than half a period late (missed deadlines).
    pub late_steps: u32,
    /// Longest interval between two steps, µs.
    pub max_interval_us: u32,
    /// Learner samples the background task has processed.
    pub samples_processed: u32,
    /// Learner samples dropped because the queue to the background task was full.
    pub samples_dropped: u32,
    /// The step's own execution time, where the board measures it (the H743's cycle counter;
    /// `None` in the simulator, where host time says nothing about the flight controller).
    pub step_time: Option<StepTime>,
}

/// Execution time of the control step since start-up.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct StepTime {
    /// Longest step, µs.
    pub max_us: u32,
    /// Steps that ran past their deadline (one control period).
    pub overruns: u32,
}

/// The IMU as the control step sees it.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct ImuStatus {
    /// Whether samples are arriving.
    pub present: bool,
    /// Samples received since start-up.
    pub samples: u32,
    /// Control steps that found no new sample.
    pub missing: u32,
    /// Latest angular rate, rad/s, IMU axes.
    pub gyro_rad_s: [f32; 3],
    /// Latest specific force, m/s², IMU axes.
    pub accel_mps2: [f32; 3],
    /// Gyro mean over the last completed one-second window, rad/s (the bias when at rest).
    pub gyro_mean_rad_s: [f32; 3],
    /// Gyro standard deviation over that window, rad/s (the noise when at rest).
    pub gyro_std_rad_s: [f32; 3],
    /// Accelerometer standard deviation over that window, m/s².
    pub accel_std_mps2: [f32; 3],
}

/// The onboard IMU-offset estimator (seed paper §3.2), fed by every IMU sample: throws are
/// detected as free fall, and the offset is re-estimated after each one.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct ImuOffsetStatus {
    /// Throws (free-fall segments) accepted so far.
    pub throws: u8,
    /// Whether the craft is in free fall right now.
    pub in_free_fall: bool,
    /// Whether an estimate exists (at least one throw).
    pub estimated: bool,
    /// Position of the IMU relative to the centre of gravity, m, IMU axes.
    pub r_imu_m: [f32; 3],
    /// Semi-axes of the 95 % confidence ellipsoid of `r_imu_m`, m, largest first.
    pub ci95_semi_axes_m: [f32; 3],
    /// Whether every semi-axis is small enough to use the estimate.
    pub well_determined: bool,
    /// What to do next when it is not.
    pub advice: OffsetAdvice,
}

/// The IMU-offset estimator's advice to the person throwing.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub enum OffsetAdvice {
    /// Nothing to do (well determined), or no estimate yet.
    #[default]
    None,
    /// The offset is poorly determined along `direction_imu` (unit vector, IMU axes): throw
    /// again spinning about IMU axis `spin_about_axis` (0 = x, 1 = y, 2 = z).
    ThrowAgain { direction_imu: [f32; 3], spin_about_axis: u8 },
    /// Along `direction_imu` the offset cannot be told apart from an accelerometer bias: throw
    /// again at a different spin rate, about IMU axis `spin_about_axis`.
    BiasNotSeparable { direction_imu: [f32; 3], spin_about_axis: u8 },
    /// An accelerometer bias the model ignores spoils the offset: fit the bias jointly.
    FitBias,
}

/// How a parameter's elements are read.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParamKind {
    /// Any finite number in the range.
    Real,
    /// Whole numbers in the range.
    Integer,
    /// 0 (off) or 1 (on).
    Flag,
}

/// One parameter of the registry: what it is, what it may be, and what it is now.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct ParamInfo {
    /// Its place in the registry, 0 to `count` − 1.
    pub index: u16,
    /// Parameters in the registry.
    pub count: u16,
    pub name: String<NAME_LEN>,
    pub kind: ParamKind,
    /// Unit of every element ("" for pure numbers).
    pub unit: String<PARAM_UNIT_LEN>,
    /// Smallest allowed element.
    pub min: f32,
    /// Largest allowed element.
    pub max: f32,
    /// The default value (every element).
    pub default: ParamValues,
    /// The value in force now.
    pub value: ParamValues,
    /// Whether calibration or identification writes it (it is still settable by hand).
    pub learned: bool,
    pub help: String<PARAM_HELP_LEN>,
}

/// Where the configuration in force came from at start-up.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ConfigOrigin {
    /// Nothing was stored: every parameter has its default.
    #[default]
    Defaults,
    /// Loaded from flash.
    Loaded,
    /// The stored configuration has a layout this firmware does not know (a newer firmware
    /// wrote it): defaults are in force, and the stored bytes stay untouched until `save`.
    UnknownLayout { version: u16 },
    /// The stored configuration could not be read: defaults are in force; the bytes stay
    /// untouched until `save`.
    Unreadable,
    /// The board has no configuration store: changes last until power-off.
    NoStore,
}

/// The configuration store's state.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ConfigStatus {
    pub origin: ConfigOrigin,
    /// Layout version this firmware writes.
    pub layout_version: u16,
    /// Parameters in the registry.
    pub param_count: u16,
    /// Whether the configuration in force differs from the one stored (or, with nothing
    /// stored, from the defaults).
    pub unsaved_changes: bool,
    /// Stored values refused at start-up (outside their range now, or the wrong length): those
    /// parameters took their defaults.
    pub rejected_at_load: u16,
    /// Successful saves since start-up.
    pub saves: u32,
    /// Whether an IMU-offset calibration is running.
    pub calibrating: bool,
    /// Whether a motor test is spinning a motor.
    pub motor_test: bool,
}

/// One throw seen during an IMU-offset calibration, and the estimate after it.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct CalibrationThrow {
    /// Length of this throw's free fall, ms.
    pub free_fall_ms: u16,
    /// The estimate with every throw of the calibration so far (`throws` counts them).
    pub estimate: ImuOffsetStatus,
    /// The accelerometer bias fitted with the offset, m/s², IMU axes (zero when not fitted).
    pub acc_bias_mps2: [f32; 3],
}

/// Frame counters of the device's side of the link.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct LinkCounters {
    /// Valid frames received.
    pub frames_rx: u32,
    /// Frames sent (responses, telemetry, events).
    pub frames_tx: u32,
    /// Frames whose CRC did not match.
    pub bad_crc: u32,
    /// Frames with invalid COBS or too short to hold a header and CRC.
    pub bad_framing: u32,
    /// Frames longer than [`crate::MAX_FRAME_LEN`].
    pub oversize: u32,
    /// Frames with a message id the device does not know.
    pub unknown_id: u32,
    /// Frames whose payload did not decode.
    pub malformed: u32,
    /// Telemetry frames dropped for lack of transmit space.
    pub telemetry_dropped: u32,
    /// Responses dropped for lack of transmit space (the host sent requests without reading).
    pub responses_dropped: u32,
}

/// One telemetry sample; the frame's sequence number counts samples of its topic, so the host
/// sees every dropped one as a gap.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub enum Telemetry {
    Imu(ImuTelemetry),
    Control(ControlTelemetry),
    Motors(MotorTelemetry),
    Learner(LearnerTelemetry),
    State(StateTelemetry),
    Flight(FlightTelemetry),
}

/// What the closed loop is doing (protocol 1.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FlightMode {
    /// Not flying on a learned model (disarmed, waiting for a throw, or identifying).
    #[default]
    Off,
    /// Flying without a recent external pose: thrust axis up, zero vertical speed from the
    /// accelerometer; the horizontal position drifts.
    LevelHold,
    /// Flying with external poses: holding [`FlightTelemetry::position_sp_ned_m`].
    PositionHold,
    /// Descending to land, for this reason: straight down at the held position with a pose,
    /// level on the learned hover axis without; disarms at the touchdown (protocol 1.14).
    Landing(LandReason),
    /// The pilot flies it in angle mode: the sticks tilt the thrust axis, turn the heading and
    /// ask for a climb rate (protocol 1.14). In position mode the sticks move the setpoint of
    /// [`FlightMode::PositionHold`].
    Angle,
}

/// Why a flying craft lands (protocol 1.14).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum LandReason {
    /// [`Request::Land`] from a host.
    Commanded,
    /// The pilot's land switch.
    Switch,
    /// The pilot's radio link was lost in flight (after its grace).
    RcLost,
    /// The flight battery fell below its per-cell threshold.
    BatteryLow,
    /// The external pose stayed lost for longer than `land_pose_lost_s`.
    PoseLost,
    /// An unsigned disarm arrived over an untrusted link while flying: landed instead of
    /// dropped (counted in the link's unsigned refusals).
    UnsignedDisarm,
    /// The craft moved away from its setpoint faster than `flyaway_speed_mps` for longer than
    /// `flyaway_time_s`.
    FlyAway,
    /// A hand grabbed the hovering craft: its commanded tilt no longer turned it
    /// (`catch_detect`; protocol 1.15). Reported by [`Event::Landed`] alone: the motors stop in
    /// the step it is detected, no descent comes before.
    Caught,
}

/// Why a failsafe acted (protocol 1.4). `I` is what an identification failure carries: on the
/// wire the learner's [`LearnerFailure`]; the firmware's pilot keeps its own, narrower type in
/// this very list (`firmware::app::Failsafe`: one list of reasons, the same variants in the same
/// order, so the same bytes).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FailsafeReason<I = LearnerFailure> {
    /// A motor command was not finite or outside [0, 1]: zero was written instead.
    BadCommand,
    /// The control allocation failed for many consecutive steps.
    AllocationFailed,
    /// The identification produced no flyable model (the learner's failure says why).
    Identification(I),
    /// The thrust axis stayed far from up for too long.
    AttitudeLost,
    /// The IMU stopped delivering samples.
    ImuLost,
    /// The IMU delivers implausible samples (non-finite, a stuck axis, saturation).
    ImuFault,
    /// The external pose stopped arriving while position hold needed it.
    PoseLost,
    /// The radio link was lost (receiver failsafe or no frames).
    RcLost,
    /// The pilot's kill switch.
    Kill,
}

impl<I> FailsafeReason<I> {
    /// The same reason, an identification's failure turned by `f`.
    pub fn map_identification<J>(self, f: impl FnOnce(I) -> J) -> FailsafeReason<J> {
        match self {
            Self::BadCommand => FailsafeReason::BadCommand,
            Self::AllocationFailed => FailsafeReason::AllocationFailed,
            Self::Identification(failure) => FailsafeReason::Identification(f(failure)),
            Self::AttitudeLost => FailsafeReason::AttitudeLost,
            Self::ImuLost => FailsafeReason::ImuLost,
            Self::ImuFault => FailsafeReason::ImuFault,
            Self::PoseLost => FailsafeReason::PoseLost,
            Self::RcLost => FailsafeReason::RcLost,
            Self::Kill => FailsafeReason::Kill,
        }
    }
}

/// What a failsafe did (protocol 1.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FailsafeAction {
    /// Every motor stopped, disarmed.
    Disarmed,
    /// Flight goes on without a position: level hold.
    LevelHold,
    /// Flight goes on with the IMU sample replaced by the previous good one (a short glitch).
    HeldLastSample,
    /// The craft lands: descends, detects the touchdown, disarms (protocol 1.14).
    Land,
}

/// How often each failsafe acted since start-up (protocol 1.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct FailsafeCounters {
    pub bad_command: u16,
    pub allocation_failed: u16,
    pub identification: u16,
    pub attitude_lost: u16,
    pub imu_lost: u16,
    pub imu_fault: u16,
    pub pose_lost: u16,
    pub rc_lost: u16,
    pub kill: u16,
}

impl FailsafeCounters {
    /// Every counter with its name (the field's), in declaration order.
    pub fn named(&self) -> [(&'static str, u16); 9] {
        [
            ("bad_command", self.bad_command),
            ("allocation_failed", self.allocation_failed),
            ("identification", self.identification),
            ("attitude_lost", self.attitude_lost),
            ("imu_lost", self.imu_lost),
            ("imu_fault", self.imu_fault),
            ("pose_lost", self.pose_lost),
            ("rc_lost", self.rc_lost),
            ("kill", self.kill),
        ]
    }

    /// Failsafes of every kind since start-up.
    pub fn total(&self) -> u32 {
        self.named().iter().map(|&(_, n)| u32::from(n)).sum()
    }
}

/// The closed loop's state (protocol 1.4): what [`Topic::Flight`] streams and
/// [`Request::GetFlight`] answers. Vectors of the thrust frame are in its axes (z along minus the
/// thrust); world vectors are NED in the poses' world.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct FlightTelemetry {
    /// Device time, µs since start-up.
    pub t_us: u64,
    pub mode: FlightMode,
    /// Attitude of the thrust frame in the world, `[w, x, y, z]` (the IMU's before flight).
    pub q_world_thrust: [f32; 4],
    /// ZYX Euler angles of `q_world_thrust`: roll, pitch, yaw, rad.
    pub euler_zyx_rad: [f32; 3],
    /// Angular rate, rad/s, thrust frame.
    pub rate_rad_s: [f32; 3],
    /// Rate setpoint, rad/s, thrust frame.
    pub rate_sp_rad_s: [f32; 3],
    /// Wanted specific force, m/s², world NED.
    pub specific_force_sp_ned_mps2: [f32; 3],
    /// Angle between the thrust axis and its setpoint, rad.
    pub tilt_error_rad: f32,
    /// Position setpoint, m, world NED (while holding a position).
    pub position_sp_ned_m: Option<[f32; 3]>,
    /// Position of the centre of gravity, m, world NED (when a pose has been received).
    pub position_ned_m: Option<[f32; 3]>,
    /// Velocity of the centre of gravity, m/s, world NED (when known).
    pub velocity_ned_mps: Option<[f32; 3]>,
    /// Whether the latest pose is recent.
    pub pose_fresh: bool,
    /// Consecutive steps the allocation failed (0 when it succeeds).
    pub allocation_failures: u16,
    /// Bit i set: motor i is at a bound of its command.
    pub saturated: u8,
    /// The latest failsafe, if any.
    pub last_failsafe: Option<FailsafeReason>,
    pub failsafes: FailsafeCounters,
}

/// The board's hardware as its drivers see it (protocol 1.4, [`Request::GetBoard`]). `None`
/// where the device has no such part (the simulator has no receiver and no clock tree).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct BoardHealth {
    /// Core clock, Hz.
    pub core_clock_hz: Option<u32>,
    /// Silicon revision of the MCU (DBGMCU_IDCODE.REV_ID, e.g. 0x2003 = revision V).
    pub silicon_revision: Option<u16>,
    pub imu: ImuDriverState,
    pub motors: Option<MotorLinkHealth>,
    pub receiver: Option<ReceiverHealth>,
}

/// A u-blox GNSS receiver as its driver sees it (protocol 1.16, [`Request::GetGnss`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct GnssHealth {
    pub state: GnssState,
    /// The UART's rate now, baud (the one being tried while searching).
    pub baud: u32,
    /// Which configuration the receiver acknowledged.
    pub interface: GnssInterface,
    /// The newest solution's fix type (0 none, 2 2D, 3 3D, 4 GNSS + dead reckoning, 5 time
    /// only) and satellites used; 0 before any solution.
    pub fix_type: u8,
    pub satellites: u8,
    /// Its accuracies as the receiver states them: horizontal and vertical position, m, and
    /// speed, m/s (NaN before any solution).
    pub horizontal_accuracy_m: f32,
    pub vertical_accuracy_m: f32,
    pub speed_accuracy_mps: f32,
    /// Solutions with a 3D fix handed to the control step as position fixes, and those
    /// without a usable fix, since start-up.
    pub fixes: u32,
    pub without_fix: u32,
    /// UBX frames whose checksum failed (line noise, a wrong baud rate).
    pub checksum_errors: u32,
}

/// The compass (an I²C magnetometer) as its service sees it (protocol 1.17,
/// [`Request::GetCompass`]).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct CompassHealth {
    /// Which sensor answered (`None`: none found yet).
    pub sensor: CompassSensor,
    /// Its 7-bit I²C address (0 while none is found).
    pub address: u8,
    pub state: CompassState,
    /// The `compass_enabled` parameter: samples go to the control step only when set.
    pub enabled: bool,
    /// A calibration (hard and soft iron, mounting) is stored (`compass_cal_valid`): samples go
    /// to the control step only then.
    pub calibrated: bool,
    /// Valid readings a second over the last second, Hz.
    pub rate_hz: f32,
    /// Strength of the newest valid field, µT: calibrated when a calibration is stored, raw
    /// (hard iron included) otherwise; NaN before any reading.
    pub field_ut: f32,
    /// Valid readings, failed reads (bus errors, no new data) and overflowing reads since
    /// start-up.
    pub readings: u32,
    pub failures: u32,
    pub overflows: u32,
    /// Times the sensor was declared lost, stuck or saturated since start-up.
    pub lost: u16,
    pub stuck: u16,
    pub saturated: u16,
    /// Calibrated samples handed to the control step since start-up.
    pub samples_sent: u32,
    /// The calibration procedure ([`Request::CompassCalibration`]).
    pub calibration: CompassCalibrationStatus,
}

/// Which magnetometer (protocol 1.17).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CompassSensor {
    /// Nothing answered at 0x0C, 0x0D or 0x0E.
    #[default]
    None,
    /// iSentek IST8310 (0x0C or 0x0E).
    Ist8310,
    /// QST QMC5883L (0x0D).
    Qmc5883l,
}

/// Where the compass stands (protocol 1.17).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CompassState {
    /// No sensor found: probing the bus about once a second.
    #[default]
    Absent,
    /// Found and configured, no valid reading yet.
    Starting,
    /// Valid readings arrive and change.
    Healthy,
    /// Ten reads in a row failed: unplugged or unpowered; probing again.
    Lost,
    /// 25 identical readings in a row: the sensor stopped converting.
    Stuck,
    /// Ten overflowing reads in a row: a magnet or a current next to the sensor.
    Saturated,
}

/// What the host asks of the compass calibration (protocol 1.17).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum CompassCalibrationCommand {
    /// Forget what was gathered and gather afresh: turn the craft through every orientation.
    /// Refused while armed ([`DeviceError::RefusedWhileArmed`]) and without a working sensor
    /// ([`DeviceError::NotReady`]).
    Start,
    /// Stop gathering and solve; the result (stored or refused) shows in
    /// [`CompassHealth::calibration`]. [`DeviceError::NotReady`] when nothing is gathering.
    Finish,
    /// Stop gathering; nothing is stored.
    Cancel,
}

/// The compass calibration's progress and outcome (protocol 1.17).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub enum CompassCalibrationStatus {
    /// None running since start-up (or cancelled).
    #[default]
    Idle,
    /// Gathering: samples taken and the sphere's coverage of the latest trial fit, per cent
    /// (the fit needs 20 %; a hemisphere gives 25 %, the whole sphere 100 %).
    Gathering { samples: u32, coverage_pct: u8 },
    /// Solving the samples gathered (the background task).
    Solving { samples: u32 },
    /// Solved and stored in the parameters (saved by `save`): the fit's RMS residual and field
    /// strength, µT, its coverage, per cent, and the mounting's standard deviation, degrees.
    Stored { residual_ut: f32, field_ut: f32, coverage_pct: u8, mounting_std_deg: f32 },
    /// Refused: nothing was stored.
    Refused(CompassCalibrationRefusal),
}

/// Why a compass calibration was refused (protocol 1.17). Nothing was stored.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub enum CompassCalibrationRefusal {
    /// Fewer samples than the fit needs (100): turn longer.
    TooFewSamples { samples: u32 },
    /// The samples do not lie on an ellipsoid: not one field turned through orientations.
    NotAnEllipsoid,
    /// The samples span too little of the sphere (per cent, 20 needed): turn through more
    /// orientations, both sides up, nose up and down.
    InsufficientCoverage { coverage_pct: u8 },
    /// The samples lie too far from the fitted ellipsoid (more than 10 % of the field): a
    /// motor running, steel nearby, or a broken sensor.
    ResidualTooLarge { residual_ut: f32, field_ut: f32 },
    /// Too few samples with an attitude for the mounting (50 needed).
    TooFewAttitudes { samples: u32 },
    /// The craft was turned about one axis only: the mounting cannot be told (turn about two
    /// axes: roll or pitch as well as yaw).
    NotTurnedAboutTwoAxes { observability: f32 },
    /// The fit failed numerically (non-finite sums).
    Numerical,
    /// The sensor was lost while gathering.
    SensorLost,
    /// The craft was armed while gathering (the motors' currents would be fitted as iron).
    Armed,
}

/// Where the GNSS driver stands (protocol 1.16).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum GnssState {
    /// Polling for a receiver at one baud rate after another.
    #[default]
    Searching,
    /// Found: its configuration sent, waiting for solutions at the configured rate.
    Configuring,
    /// Solutions arriving.
    Receiving,
    /// Solutions stopped (no NAV-PVT for a second): searching again soon.
    Lost,
}

/// The configuration a GNSS receiver acknowledged (protocol 1.16).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum GnssInterface {
    /// None yet (or the receiver acknowledges nothing, as some clones do).
    #[default]
    Unknown,
    /// UBX-CFG-VALSET: a u-blox M9 or M10.
    ConfigurationKeys,
    /// The legacy UBX-CFG messages: a u-blox M8 or older.
    LegacyMessages,
}

/// The IMU driver's state after its start-up checks (protocol 1.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ImuDriverState {
    /// No IMU driver on this device.
    #[default]
    NotFitted,
    /// Identified, configured and read back: delivering samples.
    Running,
    /// The identity register held `found` instead of `expected`: wrong part or no answer.
    WrongIdentity { expected: u8, found: u8 },
    /// A configuration register read back `read` after `written` was written.
    ConfigMismatch { register: u8, written: u8, read: u8 },
    /// The bus reported an error.
    BusError,
    /// The simulator's model of the IMU.
    Simulated,
}

/// The motor outputs and their speed reports (bidirectional DShot), per motor (protocol 1.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct MotorLinkHealth {
    /// Motor outputs driven.
    pub motor_count: u8,
    /// Frames sent to each motor.
    pub frames_sent: u32,
    /// Speed reports decoded per motor.
    pub reports: [u32; MAX_MOTORS],
    /// Speed reports rejected per motor (bad GCR code, CRC, or no answer).
    pub report_errors: [u32; MAX_MOTORS],
}

/// The radio receiver (CRSF) (protocol 1.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct ReceiverHealth {
    /// Channels arrived within the failsafe timeout.
    pub link_up: bool,
    /// Uplink link quality, %.
    pub link_quality_pct: u8,
    /// Uplink RSSI of the better antenna, dBm.
    pub rssi_dbm: i16,
    /// Frames accepted.
    pub frames: u32,
    /// Frames rejected (CRC, length, truncation).
    pub frame_errors: u32,
}

/// How the control step coped with its sensors (protocol 1.6, [`Request::GetHealth`]): IMU
/// glitches ridden through, and which motors report their speed.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct SensorHealth {
    /// IMU samples replaced by the last good one while armed, by cause: each was a glitch
    /// shorter than the `imu_fault_timeout_s` parameter, and the flight went on.
    pub imu_held: ImuHeldCounters,
    /// Longest run of held IMU samples since start-up, µs (board time from the first held
    /// sample of the run to its last).
    pub imu_longest_hold_us: u32,
    /// Motors connected.
    pub motor_count: u8,
    /// Bit i set: motor i reported its speed within the last [`SPEED_REPORT_TIMEOUT_MS`].
    pub speeds_reported: u8,
    /// Times a motor's speed reports stopped while the motors spun: during an identification
    /// the attempt ended ([`LearnerFailure::NoSpeedTelemetry`]); flying on a learned model the
    /// flight went on (the controller models the motor speeds from the commands).
    pub speed_reports_lost: u16,
}

/// IMU samples held over, by cause (protocol 1.6).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ImuHeldCounters {
    /// No sample arrived for the control step.
    pub missing: u32,
    /// A value was NaN or infinite (a broken data path).
    pub non_finite: u32,
    /// Every gyro and accelerometer value repeated the previous sample bit for bit while the
    /// motors spun (a frozen sensor or a stale read).
    pub frozen: u32,
    /// An accelerometer axis at the ±16 g rail: the last unsaturated accelerometer reading was
    /// used, the gyro as read.
    pub accel_saturated: u32,
}

impl ImuHeldCounters {
    /// Every held sample, whatever the cause.
    pub fn total(&self) -> u64 {
        [self.missing, self.non_finite, self.frozen, self.accel_saturated]
            .iter()
            .map(|&n| u64::from(n))
            .sum()
    }
}

/// A motor whose speed report is older than this counts as not reporting, ms (protocol 1.6).
pub const SPEED_REPORT_TIMEOUT_MS: u16 = 100;

/// Where the throw-to-fly identification stands (docs/algorithms/throw.md, learner.md).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LearnerPhase {
    /// Not armed for a throw: nothing spins.
    #[default]
    Idle,
    /// Armed: waiting for a throw (momentum above the threshold).
    WaitingForThrow,
    /// A throw is under way (acceleration high, momentum building).
    Throwing,
    /// Released: the release delay runs and free fall is being checked (motors still off).
    Released,
    /// The motors are being pulsed one after the other while the estimators learn.
    Exciting,
    /// The excitation is over; the results stand (the controller takes over from here).
    Done,
    /// Identification stopped: see [`LearnerTelemetry::failure`].
    Failed,
}

/// Why an identification attempt ended without a result.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LearnerFailure {
    /// No failure.
    #[default]
    None,
    /// Released, but the accelerometer did not read free fall (the craft was still held, or hit
    /// something): the motors never started.
    NotFreeFall,
    /// Armed for longer than the give-up time (3 s) after a throw began without a release.
    ThrowTimedOut,
    /// The torque effectiveness never reached full rank: no hover thrust axis exists.
    RankDeficient,
    /// A thrust axis was found, but hovering along it needs a motor outside [0, 1].
    NoHover,
    /// Disarmed by request during the attempt.
    Disarmed,
    /// The IMU stopped delivering samples during the attempt.
    ImuLost,
    /// A motor's speed was not reported ([`SensorHealth::speeds_reported`]): the learner needs
    /// every motor's speed. Before the excitation the motors never started; during it they
    /// stopped. Protocol 1.6.
    NoSpeedTelemetry,
    /// The excitation ended without a hover thrust axis. Protocol 1.7 (reported as `NoHover`
    /// before).
    NoThrustAxis,
    /// The model of this motor (index from 0) is unusable (its time constant or speed at full
    /// command out of range). Protocol 1.7 (`NoHover` before).
    MotorUnusable { motor: u8 },
    /// The learned model has non-finite entries or the wrong motor count. Protocol 1.7
    /// (`NoHover` before).
    InvalidModel,
}

/// The in-flight learner: phase, and the estimates so far. `g1_rows` carries three rows of the
/// 6 × m effectiveness G1 per sample, alternating between the specific-force rows and the
/// angular-acceleration rows (`g1_block`), so the whole matrix arrives every second sample.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct LearnerTelemetry {
    /// Device time, µs since start-up.
    pub t_us: u64,
    pub phase: LearnerPhase,
    pub failure: LearnerFailure,
    /// Motors the learner identifies.
    pub motor_count: u8,
    /// The motor being pulsed now (index from 0), during [`LearnerPhase::Exciting`].
    pub exciting_motor: Option<u8>,
    /// Time since the excitation began, ms (0 before).
    pub excitation_ms: u16,
    /// First-order time constant of each motor, s (0 where not yet identified).
    pub tau_s: [f32; MAX_MOTORS],
    /// Speed at full command of each motor, ω_full, rad/s (0 where not yet identified).
    pub omega_max_rad_s: [f32; MAX_MOTORS],
    /// Bit i set: motor i's model has converged.
    pub motors_converged: u8,
    /// Bit i set: column i of G1 has converged.
    pub g1_converged: u8,
    /// Whether a hover thrust axis has been found (then the next three fields hold it).
    pub thrust_axis_valid: bool,
    /// `q_U^T`: rotation taking thrust-frame coordinates into IMU coordinates, `[w, x, y, z]`.
    pub q_thrust_to_imu: [f32; 4],
    /// ZYX Euler angles of `q_U^T`: roll, pitch, yaw, rad.
    pub euler_zyx_rad: [f32; 3],
    /// Which rows `g1_rows` holds: 0 = specific force (x, y, z), 1 = angular acceleration
    /// (p, q, r).
    pub g1_block: u8,
    /// Three rows of G1 per unit normalised thrust u (u = ω²/ω_max²): m/s² (block 0) or rad/s²
    /// (block 1), IMU axes.
    pub g1_rows: [[f32; MAX_MOTORS]; 3],
}

/// The latest IMU sample.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct ImuTelemetry {
    /// Device time of the sample, µs since start-up.
    pub t_us: u64,
    pub gyro_rad_s: [f32; 3],
    pub accel_mps2: [f32; 3],
}

/// Control-loop health.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct ControlTelemetry {
    pub t_us: u64,
    pub steps: u32,
    pub late_steps: u32,
    pub samples_dropped: u32,
}

/// Motor commands and speeds.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct MotorTelemetry {
    pub t_us: u64,
    /// Commands δ ∈ [0, 1].
    pub commands: [f32; MAX_MOTORS],
    /// Speeds from RPM telemetry, rad/s; `None` where a motor has not reported.
    pub speeds_rad_s: [Option<f32>; MAX_MOTORS],
}

/// One control step's state, written by the step itself (the 2 kHz topic).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub struct StateTelemetry {
    /// Device time of the step, µs since start-up.
    pub t_us: u64,
    /// Where the throw-to-fly attempt stands.
    pub phase: LearnerPhase,
    /// Flying on the learned model (closed loop).
    pub flying: bool,
    /// Whether the step had a new IMU sample (else `gyro_rad_s` and `accel_mps2` repeat the
    /// previous one).
    pub imu_fresh: bool,
    /// Angular rate, rad/s, IMU axes.
    pub gyro_rad_s: [f32; 3],
    /// Specific force with the stored accelerometer bias removed, m/s², IMU axes.
    pub accel_mps2: [f32; 3],
    /// Attitude of the IMU in the world (NED), `[w, x, y, z]`, from the attitude filter.
    pub q_world_imu: [f32; 4],
    /// Motors connected; elements past it are zero.
    pub motor_count: u8,
    /// Commands δ ∈ [0, 1] written by this step.
    pub commands: [f32; MAX_MOTORS],
    /// Speeds from RPM telemetry, rad/s; `None` where a motor has not reported.
    pub speeds_rad_s: [Option<f32>; MAX_MOTORS],
}

/// An asynchronous notice; the frame's sequence number counts events.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// Bad frames arrived since the last such event (at most one per 100 ms); totals so far.
    LinkErrors(LinkCounters),
    /// A calibration throw was accepted ([`Request::StartCalibration`]).
    CalibrationThrow(CalibrationThrow),
    /// The motor test stopped by itself: no keep-alive for [`MOTOR_TEST_KEEPALIVE_MS`].
    MotorTestTimedOut { motor: u8 },
    /// A failsafe acted (protocol 1.4); `count` is how often this reason has acted since
    /// start-up.
    Failsafe { reason: FailsafeReason, action: FailsafeAction, count: u16 },
    /// A landing began (protocol 1.14); `count`: landings begun since start-up.
    Landing { reason: LandReason, count: u16 },
    /// A landing touched down and the motors stopped (protocol 1.14): why it landed, the
    /// vertical speed at the touchdown, m/s (positive down, from the navigation estimate), and
    /// how many touchdowns since start-up.
    Landed { reason: LandReason, touchdown_speed_mps: f32, count: u16 },
}

// ---------------------------------------------------------------------------------------------
// The table: message ids. Requests go host → device; device messages go device → host.
// ---------------------------------------------------------------------------------------------

/// Id of [`Request::Hello`] (first in its table), frozen across all versions.
pub const HELLO_ID: u8 = Request::IDS[0];
/// Id of [`DeviceMessage::Response`] (first in its table), frozen across all versions.
pub const RESPONSE_ID: u8 = DeviceMessage::IDS[0];

crate::table::message_table! {
    /// Everything the host sends.
    pub enum Request {
        /// Handshake. Frozen id.
        0x01 => Hello(Hello),
        0x02 => GetInfo(()),
        0x03 => GetStatus(()),
        0x04 => SetTelemetryRate(SetTelemetryRate),
        0x05 => Ping(Ping),
        /// Arm the throw detector: the next throw starts the motor excitation. Refused with
        /// [`DeviceError::BadValue`] (`motor_count`) on a board with fewer than four motors,
        /// with [`DeviceError::SpeedsNotReported`] while a motor reports no speed, with
        /// [`DeviceError::Busy`] while the control step has not yet taken earlier commands.
        0x06 => ArmThrowToFly(()),
        /// Stop every motor now and leave any armed state. Always accepted after the handshake;
        /// commands still waiting for the control step (arm, pose) are dropped.
        0x07 => Disarm(()),
        /// A pose from motion capture or a ground station. Non-finite values are refused with
        /// [`DeviceError::BadValue`] (`pose`).
        0x08 => SetExternalPose(ExternalPose),
        /// The learner's state ([`Reply::Learner`], always with G1 block 0: the specific-force
        /// rows).
        0x09 => GetLearner(()),
        /// One parameter: its description and value ([`Reply::Param`]).
        0x0A => GetParam(ParamRef),
        /// Set a parameter (not saved until [`Request::SaveConfig`]). Refused while armed.
        0x0B => SetParam(SetParam),
        /// Write the configuration in force to flash. Refused while armed.
        0x0C => SaveConfig(()),
        /// Every parameter back to its default (not saved until [`Request::SaveConfig`]).
        /// Refused while armed.
        0x0D => ResetConfig(()),
        /// The configuration store's state ([`Reply::Config`]).
        0x0E => GetConfig(()),
        /// Start an IMU-offset calibration: the onboard estimator starts afresh, and each throw
        /// it accepts is reported as [`Event::CalibrationThrow`]. Refused while armed.
        0x0F => StartCalibration(()),
        /// End the calibration, storing the estimate when `accept`.
        0x10 => StopCalibration(StopCalibration),
        /// Spin one motor (propellers off); repeat as the keep-alive. Refused while armed
        /// (a running test is not "armed" for this: its own repeats are accepted).
        0x11 => MotorTest(MotorTest),
        /// Restart the board (the SITL restarts its application, keeping its flash file).
        /// Refused while armed. Answered before the restart.
        0x12 => Reboot(()),
        /// Where to hold while flying with external poses (protocol 1.4). Non-finite values
        /// are refused with [`DeviceError::BadValue`] (`setpoint`). Accepted any time; the
        /// setpoint in force is reported in [`FlightTelemetry::position_sp_ned_m`].
        0x13 => SetPositionSetpoint(PositionSetpoint),
        /// The closed loop's state ([`Reply::Flight`]). Protocol 1.4.
        0x14 => GetFlight(()),
        /// The board's drivers and clocks ([`Reply::Board`]). Protocol 1.4.
        0x15 => GetBoard(()),
        /// Restart into the MCU's ROM bootloader (USB DFU) for a firmware update. Refused while
        /// armed; [`DeviceError::Unsupported`] in the simulator. Answered before the restart.
        /// Protocol 1.4.
        0x16 => RebootToBootloader(()),
        /// An ESC command (beep, spin direction, save, …) → `Done` once queued for the motor
        /// outputs; refused while armed, [`DeviceError::Unsupported`] where the motor outputs
        /// cannot send them (the bridge). Protocol 1.5.
        0x17 => EscCommand(EscCommand),
        /// The sensors' health ([`Reply::Health`]): IMU samples held over, motors reporting
        /// their speed. Protocol 1.6.
        0x18 => GetHealth(()),
        /// How this link is guarded ([`Reply::LinkSecurity`]): the session a signer needs.
        /// Protocol 1.8.
        0x19 => GetLinkSecurity(()),
        /// Set or clear the link key: trusted links only, refused while armed. Protocol 1.8.
        0x1A => SetLinkKey(SetLinkKey),
        /// The flight-log files ([`Reply::LogList`]); `Unsupported` on a board without log
        /// storage. Protocol 1.9.
        0x1B => ListLogs(ListLogs),
        /// A chunk of one log file ([`Reply::LogChunk`]); `NoSuchLog`, `LogOffsetPastEnd`,
        /// `BadValue` (`len`) over [`LOG_CHUNK_LEN`]. Protocol 1.9.
        0x1C => ReadLog(ReadLog),
        /// Delete one log file → `Done`; `NoSuchLog`, `LogBeingWritten`, refused while armed.
        /// Protocol 1.9.
        0x1D => DeleteLog(DeleteLog),
        /// The flight battery ([`Reply::Battery`]); `Unsupported` on a device that measures
        /// none. Protocol 1.11.
        0x1E => GetBattery(()),
        /// How the latest identification was made ([`Reply::Identification`]). Protocol 1.12.
        0x1F => GetIdentification(()),
        /// Land: a flying craft descends at `land_descent_mps` and disarms at the touchdown
        /// (its position held with a pose, level without); a craft still waiting for a throw
        /// or on the ground stops its motors as [`Request::Disarm`] would; one in the air in
        /// its identification lands as soon as it flies. Signed over an untrusted link, like
        /// every request that steers. → `Done`. Protocol 1.14.
        0x20 => Land(()),
        /// The GNSS receiver ([`Reply::Gnss`]); `Unsupported` on a device without a GNSS port.
        /// Protocol 1.16.
        0x21 => GetGnss(()),
        /// The compass ([`Reply::Compass`]); `Unsupported` on a device without a compass bus.
        /// Protocol 1.17.
        0x22 => GetCompass(()),
        /// Start, finish or cancel the compass calibration → `Done`; refused while armed, and
        /// `NotReady` as [`CompassCalibrationCommand`] says; `Unsupported` without a compass
        /// bus. Signed over an untrusted link (it stores parameters). Protocol 1.17.
        0x23 => CompassCalibration(CompassCalibrationCommand),
    }
}

crate::table::message_table! {
    /// Everything the device sends.
    pub enum DeviceMessage {
        /// The answer to the request with the same sequence number. Frozen id.
        0x81 => Response(Response),
        /// Sequence number: per topic.
        0x82 => Telemetry(Telemetry),
        /// Sequence number: per link.
        0x83 => Event(Event),
    }
}
