//! The portable flight-controller application: the same code on the STM32H743 and in the SITL.
//!
//! Three parts, one per RTIC task priority (docs/architecture.md, "One control period"):
//! - [`ControlLoop`] (highest priority, 2 kHz timer): IMU in, motor commands out, one compact
//!   [`LearnerSample`] per IMU sample into a lock-free queue, one [`StepRecord`] per step into
//!   the telemetry ring;
//! - [`LinkServer`] (middle priority, USB): the protocol, answering from a [`StatusView`] and
//!   streaming the step records;
//! - [`Background`] (lowest priority): drains the queue and runs what is too slow for the step;
//!   with it, the flight log's writer ([`log::Logger`]) drains the log ring to a [`log::LogSink`];
//! - below it, in the board's `idle`, the in-flight IMU-offset fit ([`offset_fit`]), fed and read
//!   back by the background task.
//!
//! The parts share nothing but small `Copy` snapshots ([`ControlSnapshot`],
//! [`BackgroundResults`]), which the board copies under a short lock: no computation ever happens
//! under a lock. The board supplies the hardware through the traits in [`hal`].

mod background;
pub mod battery;
pub mod card;
pub mod catch;
pub mod compass;
mod compass_heading;
mod control;
pub mod fix_parts;
pub mod gnss;
pub mod hal;
pub mod landing;
mod link;
pub mod log;
pub mod offset_fit;
pub mod params;
mod pilot;
mod queue;
pub mod radio;
pub mod settings;
pub mod sticks;
pub mod system;
mod telemetry;

pub use background::{
    Background, BackgroundCommand, BackgroundResults, CalibrationState, ENGAGE_WAIT_MAX_S,
    STATS_WINDOW_US,
};
pub use control::{
    ControlCommand, ControlConfig, ControlLoop, ControlSettings, ControlSnapshot, ControlState,
    ACCEL_SATURATED_MPS2, CONTROL_RATE_HZ, SPEED_REPORT_TIMEOUT_S, STUCK_GYRO_SAMPLES,
};
pub use hal::IMU_FAULT_TIMEOUT_S;
pub use link::{LinkRequest, LinkServer, TELEMETRY_SHARE_PCT, TX_CAPACITY};
pub use params::{Param, Params};
pub use pilot::{
    count_failsafe, failsafe_action, failsafe_counter, failsafe_reason, Failsafe, FailsafeCounts,
    IdentificationFailure, PilotStatus, PoseConfig, PositionFix, MAX_POSE_LATENCY_S,
};
pub use queue::{
    split_queue, LearnerSample, RingConsumer, RingProducer, SampleConsumer, SampleProducer,
    SampleQueue, SAMPLE_QUEUE_LEN,
};
pub use settings::{NoFlash, Settings};
pub use telemetry::{
    flight_telemetry, learner_telemetry, sensor_health, StepConsumer, StepProducer, StepRecord,
    StepRing, STEP_RING_LEN,
};

use protocol::{
    Capabilities, FirmwareVersion, Info, BOARD_NAME_LEN, PROTOCOL_VERSION, SCHEMA_HASH,
};

/// This firmware's version, from the crate version.
pub const FIRMWARE_VERSION: FirmwareVersion = FirmwareVersion {
    major: parse_u8(env!("CARGO_PKG_VERSION_MAJOR")),
    minor: parse_u8(env!("CARGO_PKG_VERSION_MINOR")),
    patch: parse_u8(env!("CARGO_PKG_VERSION_PATCH")),
};

/// What the board tells the host about itself.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardInfo {
    /// Board name, e.g. "STM32H743" or "SITL" (at most 32 bytes; longer is cut).
    pub board: &'static str,
    /// Unique id of this board: the MCU UID in hex, or the simulator instance (at most 32 bytes).
    pub serial: heapless::String<BOARD_NAME_LEN>,
    /// [`Capabilities`] flags.
    pub capabilities: u32,
    pub control_rate_hz: u16,
    pub motor_count: u8,
}

impl BoardInfo {
    /// The handshake/info reply for this board.
    pub fn info(&self) -> Info {
        Info {
            protocol: PROTOCOL_VERSION,
            schema_hash: SCHEMA_HASH,
            firmware: FIRMWARE_VERSION,
            board: protocol::text(self.board),
            serial: self.serial.clone(),
            capabilities: Capabilities(self.capabilities),
            control_rate_hz: self.control_rate_hz,
            motor_count: self.motor_count,
        }
    }
}

/// Everything the link reads to answer status requests and sample telemetry: copies of the
/// control and background snapshots, and the board's measurement of the step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StatusView {
    pub control: ControlSnapshot,
    pub background: BackgroundResults,
    /// The control step's execution time, when the board measures it.
    pub step_time: Option<protocol::StepTime>,
    /// The board's drivers and clocks (what [`protocol::Request::GetBoard`] answers).
    pub board: protocol::BoardHealth,
    /// The GNSS receiver, on a board with a GNSS port (what [`protocol::Request::GetGnss`]
    /// answers).
    pub gnss: Option<protocol::GnssHealth>,
    /// The compass, on a board with a compass bus (what [`protocol::Request::GetCompass`]
    /// answers).
    pub compass: Option<protocol::CompassHealth>,
}

/// Whether a pose or setpoint (position, m; heading, rad) is finite: what the link, the control
/// step and the pilot require before using one.
pub(crate) fn is_finite_pose(position_m: &[f32; 3], heading_rad: f32) -> bool {
    position_m.iter().all(|x| x.is_finite()) && heading_rad.is_finite()
}

/// Parse a decimal `u8` at compile time (crate version components).
const fn parse_u8(text: &str) -> u8 {
    let bytes = text.as_bytes();
    let mut value: u32 = 0;
    let mut i = 0;
    while i < bytes.len() {
        value = value * 10 + (bytes[i] - b'0') as u32;
        i += 1;
    }
    assert!(value <= 255, "version component exceeds 255");
    value as u8
}
