//! Scenarios: hold still, throw-and-catch, throw-and-fly — the manoeuvres a user performs with
//! the real craft, run against a flight application through [`SimBoard`].
//!
//! Each scenario is a timeline for the hand around the application's 2 kHz steps:
//! - **hold still**: the hand holds the craft level at `hold_height_m` for the whole run (sensor
//!   noise and bias, gravity on the accelerometer).
//! - **throw-and-catch**: hold for `hold_before_s`, throw (accelerate to the release velocity for
//!   an apex `throw_apex_m` above the release point while spinning up to the release body rate
//!   over `throw_duration_s`), free flight, catch when the craft falls back through the release
//!   height, hold for `after_catch_s`. The free flight is the data the IMU-offset fit uses.
//! - **throw-and-fly**: the same throw, higher (3.5 m apex) with the seed paper's body rate
//!   (400, 400, 100) °/s, no catch: the application must recover, or the craft hits the ground.
//!
//! The application is anything implementing [`FlightApp`]: [`FirmwareApp`] (the firmware's
//! application graph, exactly as the board and the SITL run it), [`AroundFirmware`] (the same
//! with a pilot's radio, or a look at each step: [`AroundStep`]), [`NoApp`] (reads the IMU,
//! commands nothing) or [`OpenLoop`] (a scenario-supplied command function of time).

use std::io::Write;

use embedded_storage::nor_flash::NorFlash;
use firmware::app::hal::{Imu, Motors, NoBattery, NoBytes};
use firmware::app::log::LogSink;
use firmware::app::radio::Receiver;
use firmware::app::system::{with_logged_system, with_system, LogTarget, System, TickHardware};
use firmware::app::{ControlCommand, NoFlash, Settings};
use firmware::drivers::compass::{DelayUs, I2cRegisterBus};
use nalgebra::Vector3;

use crate::airframe::{Airframe, AirframeError, STANDARD_GRAVITY_MPS2};
use crate::board::{SimBoard, SimConfig, SIM_BOARD_HEALTH};
use crate::hand::{HandPhase, ThrowSpec};
use crate::log::CsvLog;
use crate::radio::RcTransmitter;

/// A flight application stepped at 2 kHz on the simulated board's ports.
/// The same shape as `firmware::app::ControlLoop::step`, so the firmware's loop, the bridge and
/// the scenarios share it.
pub trait FlightApp {
    /// One control step at board time `now_us` (µs): read the IMU, set the motor commands.
    fn step<I: Imu, M: Motors>(&mut self, now_us: u64, imu: &mut I, motors: &mut M);

    /// A command from another task (a link, the bridge's external pose) at time `now_us`, before
    /// the next step. Applications without commands ignore it.
    fn command(&mut self, _command: ControlCommand, _now_us: u64) {}

    /// The compass on the board's I²C bus at `now_us`, after a step, as the board's link task
    /// services it (the bridge's magnetometer blocks reach the firmware so). Applications
    /// without a compass service ignore it.
    fn service_compass<B: I2cRegisterBus, D: DelayUs>(
        &mut self,
        _now_us: u64,
        _bus: &mut B,
        _delay: &mut D,
    ) {
    }
}

/// The firmware application as the board runs it: the application graph
/// ([`firmware::app::system::System`]: control tick, link pass, background run, and their
/// handoffs), here without a flash store. Build it with [`with_firmware_app`]; the SITL builds
/// one over its flash file with [`firmware::app::system::with_system`].
pub type FirmwareApp<'q> = System<'q, NoFlash>;

impl<F: NorFlash> FlightApp for System<'_, F> {
    /// One control tick with no pilot's radio; the background task runs to completion after
    /// it when samples wait, as the board's lowest-priority task does with time to spare.
    fn step<I: Imu, M: Motors>(&mut self, now_us: u64, imu: &mut I, motors: &mut M) {
        let hardware =
            TickHardware { imu, motors, radio_bytes: &mut NoBytes, battery: &mut NoBattery };
        self.tick(now_us, hardware);
    }

    /// Queued for the next tick, as a link pass queues what a host asked.
    fn command(&mut self, command: ControlCommand, _now_us: u64) {
        self.submit(command);
    }

    /// The firmware's compass service ([`System::service_compass`]): a reading when one is due,
    /// its calibrated field queued for the next tick.
    fn service_compass<B: I2cRegisterBus, D: DelayUs>(
        &mut self,
        now_us: u64,
        bus: &mut B,
        delay: &mut D,
    ) {
        System::service_compass(self, now_us, bus, delay);
    }
}

/// What an [`AroundFirmware`] adds to the firmware's step: the pilot's radio, a look at the
/// commands and at the application after each step. Each does nothing by default.
pub trait AroundStep {
    /// The pilot's radio for the step at `now_us` (µs), advanced to that time: the control tick
    /// reads its bytes as the board's receiver UART. `None`: no receiver.
    fn radio(&mut self, _now_us: u64) -> Option<&mut RcTransmitter> {
        None
    }

    /// Sees a command before the firmware takes it.
    fn see_command(&mut self, _command: &ControlCommand) {}

    /// Sees the application after its step.
    fn after_step(&mut self, _app: &FirmwareApp<'_>) {}
}

/// The firmware application with what an [`AroundStep`] adds; commands and the compass service
/// go to the firmware unchanged, so a wrapper states only what it adds.
pub struct AroundFirmware<'a, 'q, S> {
    /// The firmware.
    pub app: &'a mut FirmwareApp<'q>,
    /// What it adds.
    pub around: S,
}

impl<S: AroundStep> FlightApp for AroundFirmware<'_, '_, S> {
    /// The firmware's step, with the radio's bytes when there is a radio (no battery either way).
    fn step<I: Imu, M: Motors>(&mut self, now_us: u64, imu: &mut I, motors: &mut M) {
        match self.around.radio(now_us) {
            Some(radio_bytes) => {
                let battery = &mut NoBattery;
                self.app.tick(now_us, TickHardware { imu, motors, radio_bytes, battery });
            }
            None => FlightApp::step(self.app, now_us, imu, motors),
        }
        self.around.after_step(self.app);
    }

    fn command(&mut self, command: ControlCommand, now_us: u64) {
        self.around.see_command(&command);
        FlightApp::command(self.app, command, now_us);
    }

    fn service_compass<B: I2cRegisterBus, D: DelayUs>(
        &mut self,
        now_us: u64,
        bus: &mut B,
        delay: &mut D,
    ) {
        FlightApp::service_compass(self.app, now_us, bus, delay);
    }
}

/// Runs `f` with a fresh [`FirmwareApp`] (default control configuration and parameters, no
/// flash, no radio) whose queues live for the call.
pub fn with_firmware_app<R>(f: impl FnOnce(&mut FirmwareApp<'_>) -> R) -> R {
    with_firmware_app_and_radio(None, f)
}

/// [`with_firmware_app`] with the pilot's receiver policy `radio` in the control tick (feed it
/// bytes with [`System::tick`], e.g. from a [`crate::radio::RcTransmitter`]).
pub fn with_firmware_app_and_radio<R>(
    radio: Option<Receiver>,
    f: impl FnOnce(&mut FirmwareApp<'_>) -> R,
) -> R {
    with_system(Settings::without_store(), SIM_BOARD_HEALTH, radio, f).0
}

/// [`with_firmware_app_and_radio`] writing the flight log to `sink` (when given) as a board
/// called `board` would; `f` ends the file with [`System::finish_log`].
pub fn with_logged_firmware_app<R>(
    sink: Option<&mut dyn LogSink>,
    board: &'static str,
    radio: Option<Receiver>,
    f: impl FnOnce(&mut FirmwareApp<'_>) -> R,
) -> R {
    let log = sink.map(|sink| LogTarget { sink, board });
    with_logged_system(Settings::without_store(), SIM_BOARD_HEALTH, radio, log, f).0
}

/// Reads the IMU and commands nothing (motors stay stopped).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoApp;

impl FlightApp for NoApp {
    fn step<I: Imu, M: Motors>(&mut self, _now_us: u64, imu: &mut I, _motors: &mut M) {
        let _ = imu.read();
    }
}

/// Commands from a function of time: `f(t_s, commands)` fills the commands for the motors.
pub struct OpenLoop<F: FnMut(f64, &mut [f32])>(pub F);

impl<F: FnMut(f64, &mut [f32])> FlightApp for OpenLoop<F> {
    fn step<I: Imu, M: Motors>(&mut self, now_us: u64, imu: &mut I, motors: &mut M) {
        let _ = imu.read();
        let mut commands = [0.0f32; firmware::app::hal::MAX_MOTORS];
        let m = motors.count() as usize;
        (self.0)(now_us as f64 * 1e-6, &mut commands[..m]);
        motors.set_commands(&commands[..m]);
    }
}

/// Which manoeuvre.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScenarioKind {
    /// Held still in the hand.
    HoldStill,
    /// Thrown with spin, caught again.
    ThrowCatch,
    /// Thrown, not caught: the application flies or the craft falls.
    ThrowFly,
}

/// Parameters of a scenario. Start from [`ScenarioConfig::new`] and change fields.
#[derive(Clone, Debug, PartialEq)]
pub struct ScenarioConfig {
    /// The manoeuvre.
    pub kind: ScenarioKind,
    /// Height of the hand above the ground at the start, m.
    pub hold_height_m: f64,
    /// Time held before the throw, s.
    pub hold_before_s: f64,
    /// Apex of the throw above the release point, m (drag-free ballistic figure).
    pub throw_apex_m: f64,
    /// Horizontal release velocity (north, east), m/s.
    pub throw_horizontal_mps: [f64; 2],
    /// Body rate at release, body axes, rad/s.
    pub throw_rate_body_rad_s: Vector3<f64>,
    /// How long the hand accelerates the craft, s.
    pub throw_duration_s: f64,
    /// Catch deceleration time constant, s.
    pub catch_tau_s: f64,
    /// Time held after the catch before the run ends, s.
    pub after_catch_s: f64,
    /// Longest run, s (hold still and throw-and-fly run exactly this long).
    pub duration_s: f64,
    /// Board configuration (noise seed, physics steps per IMU sample, arming).
    pub board: SimConfig,
}

/// Why a scenario could not run.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The airframe is invalid.
    #[error(transparent)]
    Airframe(#[from] AirframeError),
    /// Writing the log failed.
    #[error("cannot write the log: {0}")]
    Io(std::io::Error),
    /// A scenario parameter is out of range.
    #[error("scenario `{field}` = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// Field name.
        field: &'static str,
        /// The value.
        value: f64,
        /// Allowed range with unit.
        allowed: &'static str,
    },
}

impl From<std::io::Error> for ScenarioError {
    fn from(error: std::io::Error) -> Self {
        Self::Io(error)
    }
}

impl ScenarioConfig {
    /// Defaults for `kind`: hold 1 m above the ground; throw-and-catch with a 1 m apex at
    /// (6, 3, 1.5) rad/s (the seed paper's ~1 m throws "with sufficient spin"); throw-and-fly
    /// with a 3.5 m apex at (400, 400, 100) °/s (seed paper §3.4).
    pub fn new(kind: ScenarioKind) -> Self {
        let fly = kind == ScenarioKind::ThrowFly;
        Self {
            kind,
            hold_height_m: 1.0,
            hold_before_s: 0.5,
            throw_apex_m: if fly { 3.5 } else { 1.0 },
            throw_horizontal_mps: [0.0, 0.0],
            throw_rate_body_rad_s: if fly {
                Vector3::new(400.0, 400.0, 100.0).map(f64::to_radians)
            } else {
                Vector3::new(6.0, 3.0, 1.5)
            },
            throw_duration_s: 0.15,
            catch_tau_s: 0.05,
            after_catch_s: 0.5,
            duration_s: match kind {
                ScenarioKind::HoldStill => 2.0,
                ScenarioKind::ThrowCatch => 10.0,
                ScenarioKind::ThrowFly => 6.0,
            },
            board: SimConfig::default(),
        }
    }

    fn validate(&self) -> Result<(), ScenarioError> {
        let checks: [(&'static str, f64, f64, f64, &'static str); 7] = [
            ("hold_height_m", self.hold_height_m, 0.05, 100.0, "[0.05, 100] m"),
            ("hold_before_s", self.hold_before_s, 0.0, 60.0, "[0, 60] s"),
            ("throw_apex_m", self.throw_apex_m, 0.0, 50.0, "[0, 50] m"),
            ("throw_duration_s", self.throw_duration_s, 0.01, 1.0, "[0.01, 1] s"),
            ("catch_tau_s", self.catch_tau_s, 0.005, 1.0, "[0.005, 1] s"),
            ("after_catch_s", self.after_catch_s, 0.0, 60.0, "[0, 60] s"),
            ("duration_s", self.duration_s, 0.001, 3600.0, "[0.001, 3600] s"),
        ];
        for (field, value, lo, hi, allowed) in checks {
            if !(value >= lo && value <= hi) {
                return Err(ScenarioError::OutOfRange { field, value, allowed });
            }
        }
        let horizontal = self.throw_horizontal_mps[0].hypot(self.throw_horizontal_mps[1]);
        if horizontal.is_nan() || horizontal > 30.0 {
            return Err(ScenarioError::OutOfRange {
                field: "throw_horizontal_mps",
                value: horizontal,
                allowed: "a speed within [0, 30] m/s",
            });
        }
        let rate = self.throw_rate_body_rad_s.norm();
        if rate.is_nan() || rate > 60.0 {
            return Err(ScenarioError::OutOfRange {
                field: "throw_rate_body_rad_s",
                value: self.throw_rate_body_rad_s.norm(),
                allowed: "a magnitude within [0, 60] rad/s",
            });
        }
        Ok(())
    }

    /// The throw as the hand performs it.
    pub fn throw_spec(&self) -> ThrowSpec {
        let mut spec = ThrowSpec::vertical(
            self.throw_apex_m,
            self.throw_rate_body_rad_s,
            self.throw_duration_s,
        );
        spec.release_velocity_ned_mps.x = self.throw_horizontal_mps[0];
        spec.release_velocity_ned_mps.y = self.throw_horizontal_mps[1];
        spec
    }
}

/// What happened in a run (truth, for checks and summaries).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Outcome {
    /// Simulated time, s.
    pub duration_s: f64,
    /// Control ticks run.
    pub ticks: u64,
    /// Release time, s.
    pub released_at_s: Option<f64>,
    /// Catch time, s.
    pub caught_at_s: Option<f64>,
    /// Highest CoG height above the ground, m.
    pub max_height_m: f64,
    /// Largest body rate magnitude, rad/s.
    pub max_rate_rad_s: f64,
    /// Whether the CoG touched the ground.
    pub touched_ground: bool,
    /// CoG position at the end, world NED, m.
    pub final_position_ned_m: [f64; 3],
}

/// Runs `config` on `airframe` with `app`, writing a CSV row per tick to `log` if given.
/// `progress(t_s, total_s)` is called every simulated 0.1 s.
pub fn run<A: FlightApp, W: Write>(
    airframe: &Airframe,
    config: &ScenarioConfig,
    app: &mut A,
    mut log: Option<&mut CsvLog<W>>,
    progress: &mut dyn FnMut(f64, f64),
) -> Result<Outcome, ScenarioError> {
    airframe.validate()?;
    config.validate()?;
    let mut board_config = config.board.clone();
    board_config.start_position_ned_m = Vector3::new(0.0, 0.0, -config.hold_height_m);
    let mut board = SimBoard::new(airframe, &board_config);
    let throws = config.kind != ScenarioKind::HoldStill;
    let total_ticks = (config.duration_s * crate::board::CONTROL_RATE_HZ).round() as u64;
    let throw_tick = (config.hold_before_s * crate::board::CONTROL_RATE_HZ).round() as u64;
    let progress_every = (0.1 * crate::board::CONTROL_RATE_HZ) as u64;
    let mut outcome = Outcome::default();
    let mut held_since_s: Option<f64> = None;
    for tick in 0..total_ticks {
        if throws && tick == throw_tick {
            let spec = config.throw_spec();
            if config.kind == ScenarioKind::ThrowCatch {
                // The hand closes where it let go: the release height.
                board.physics_mut().throw_and_catch_at_release_height(&spec, config.catch_tau_s);
            } else {
                board.physics_mut().throw(&spec);
            }
        }
        board.tick_and_step(app);
        if let Some(log) = log.as_deref_mut() {
            log.record(&board)?;
        }
        let s = board.physics().state();
        outcome.max_height_m = outcome.max_height_m.max(-s.position_ned_m.z);
        outcome.max_rate_rad_s = outcome.max_rate_rad_s.max(s.rate_body_rad_s.norm());
        outcome.touched_ground |= s.position_ned_m.z > 0.0;
        outcome.ticks = tick + 1;
        let hand = board.physics().hand();
        if config.kind == ScenarioKind::ThrowCatch
            && hand.caught_at_s().is_some()
            && hand.phase() == HandPhase::Holding
        {
            let since = *held_since_s.get_or_insert(board.time_s());
            if board.time_s() - since >= config.after_catch_s {
                break;
            }
        }
        if (tick + 1) % progress_every == 0 {
            progress(board.time_s(), config.duration_s);
        }
    }
    let hand = board.physics().hand();
    outcome.duration_s = board.time_s();
    outcome.released_at_s = hand.released_at_s();
    outcome.caught_at_s = hand.caught_at_s();
    outcome.final_position_ned_m = board.physics().state().position_ned_m.into();
    Ok(outcome)
}

/// Expected free-flight time of a throw that rises `apex_m` and is caught at release height
/// (drag-free), s: `2 √(2 h / g)`.
pub fn ballistic_flight_time_s(apex_m: f64) -> f64 {
    2.0 * (2.0 * apex_m / STANDARD_GRAVITY_MPS2).sqrt()
}
