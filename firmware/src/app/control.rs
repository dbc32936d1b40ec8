//! The 2 kHz control step: reads the IMU, drives the motors, feeds the background task.
//!
//! Deadline: one control period (500 µs at 2 kHz). The step never blocks, never allocates and
//! never panics: a missing IMU sample is counted, a full queue drops and counts, and motor outputs
//! are always written (zero unless a throw-to-fly attempt is exciting the motors or waiting for
//! its model, or the craft flies).
//!
//! Throw-to-fly (`flight::learner::ThrowToFly`): armed by [`ControlCommand::ArmThrowToFly`], the
//! step runs the throw detector on every sample and, once the craft is thrown and falling
//! freely, the excitation schedule, whose commands it writes. Every sample goes to the background
//! task with the commands, the reported motor speeds and the phase; the background learner
//! does all the estimation there (no RLS in this step). [`ControlCommand::Disarm`] stops every
//! motor from the step it arrives in.
//!
//! Flight (`super::pilot::Pilot`): the attitude filter and position estimator run on every
//! sample; when the excitation ends the step engages the controller on the model the background
//! task published ([`ControlLoop::receive`]) and flies it until disarmed or a failsafe stops it.
//! A model still learning from the excitation (`LearnedModel::pending`, without speed
//! telemetry) is waited for, the excitation's last commands held, at most [`ENGAGE_WAIT_MAX_S`].
//!
//! **IMU checks** (before anything uses the sample; `docs/failsafes.md` has the reasoning). While
//! armed (a throw-to-fly attempt or a flight), a *bad* sample is held over: the step runs on the
//! last good sample instead, counts it by cause ([`ControlSnapshot::imu_held`]) and goes on. The
//! failsafe is for a fault that lasts: when the bad samples have gone on for
//! `imu_fault_timeout_s` ([`ControlSettings::imu_fault_timeout_s`], default
//! [`super::hal::IMU_FAULT_TIMEOUT_S`]), that step ends the attempt or disarms the flight and writes zero
//! (`ImuLost` for missing samples, [`Failsafe::ImuFault`] for the others). Bad is:
//! - **missing**: no sample for the step;
//! - **non-finite** (NaN, ±∞): the ICM-42688-P delivers 16-bit integers, so the transfer or its
//!   buffer was corrupted; one corrupted SPI transfer says nothing about the next one;
//! - **frozen**: every gyro and accelerometer value bit-identical to the previous sample's while
//!   the motors spin (exciting or flying): their vibration makes that impossible for a live
//!   sensor, so it is a stale read;
//! - **accelerometer saturated**: an axis at or beyond [`ACCEL_SATURATED_MPS2`]; here only the
//!   accelerometer is replaced (by the last unsaturated reading), the gyro is used as read.
//!
//! A **stuck gyro axis** ([`STUCK_GYRO_SAMPLES`] bit-identical readings of one axis while another
//! changed, except at the rail [`GYRO_RAIL_RAD_S`]) is a lasting fault by its detection window:
//! while flying it disarms at once. Held samples never reach the background task (the learner
//! does not learn from them; the IMU-offset estimator sees a gap) and show in the per-step
//! telemetry as steps without a fresh sample. The throw detector, the excitation schedule and the
//! pilot run on the held sample, so their clocks keep running. Disarmed, a missing or non-finite
//! sample is not used (counted in [`ControlSnapshot::imu_missing`]) and a saturated one is used
//! as read (the IMU-offset estimator judges its samples itself).
//!
//! **Motor speed reports.** A motor counts as reporting while its latest finite speed report is
//! at most [`SPEED_REPORT_TIMEOUT_S`] old ([`ControlSnapshot::speeds_reported`]). The in-flight
//! learner needs every motor's speed, so:
//! - arming for throw-to-fly is refused while a motor does not report (the link refuses the
//!   request naming the motors; the step refuses the command once it has run);
//! - armed but before the excitation (waiting, throwing, released: nothing spins), a motor
//!   without a report for the timeout since the arming ends the attempt
//!   ([`LearnerFailure::NoSpeedTelemetry`]): the motors never start;
//! - during the excitation the same ends the attempt and stops every motor in that step: the
//!   learner cannot identify a motor it does not hear, so no flyable model can come of the
//!   attempt, and spinning on would only put propellers in the air near whoever catches it;
//! - flying on the learned model, the flight goes on: INDI models each motor's speed from its
//!   commands with the learned τ (`flight::indi`) and never reads the reports. The loss is
//!   counted ([`ControlSnapshot::speed_reports_lost`]), and the in-flight refinement skips the
//!   samples without every speed (the learner's own rule).
//!
//! The exception is issue 32's identification without speed telemetry: where the user says the
//! ESCs cannot report (`motor_bidir_dshot` = 0), [`ControlSettings::arm_without_speeds`] is set,
//! none of the above applies, and the learner identifies from the commands and the body's
//! response (`flight::learner::no_speed`; every build has it, issue 56).

use super::background::{BackgroundResults, ENGAGE_WAIT_MAX_S};
use super::hal::{EscCommandError, Imu, ImuSample, Motors, MAX_MOTORS};
use super::pilot::{Failsafe, Pilot, PilotStatus};
use super::queue::{LearnerSample, SampleProducer};
use super::telemetry::{StepProducer, StepRecord};
use flight::learner::excitation::ExcitationConfig;
use flight::learner::throw_detector::{ThrowConfig, ThrowEvent};
use flight::learner::{FlightPhase, ThrowToFly};
use protocol::{
    DshotCommand, ExternalPose, ImuHeldCounters, LandReason, LearnerFailure, PositionSetpoint,
    MOTOR_TEST_KEEPALIVE_MS, MOTOR_TEST_MAX_COMMAND, SPEED_REPORT_TIMEOUT_MS,
};
use serde::{Deserialize, Serialize};

/// What the other tasks ask of the control step (from the link, the receiver, the simulator).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ControlCommand {
    /// Arm the throw detector: the next throw starts the identification (ends a motor test).
    ArmThrowToFly,
    /// Stop every motor and leave any armed state, now.
    Disarm,
    /// Stop every motor and leave any armed state, now, for this reason (the pilot's kill
    /// switch, the radio link lost): counted and reported as a failsafe when anything was armed.
    Failsafe(Failsafe),
    /// End the flight gently, for this reason: a flying craft lands (descends, disarms at the
    /// touchdown: `super::pilot::Pilot::land`); one in the air in its identification (released
    /// or exciting) lands as soon as it flies; anything else armed (waiting for a throw, a motor
    /// test) stops at once, as [`ControlCommand::Disarm`]. [`LandReason::RcLost`] also counts
    /// the radio failsafe when anything was armed.
    Land(LandReason),
    /// The pilot's sticks and mode switch from the radio, each time they change (`None`: the
    /// radio's link is lost: nothing from the pilot).
    Sticks(Option<crate::drivers::crsf::StickInput>),
    /// A pose from motion capture or a ground station.
    ExternalPose(ExternalPose),
    /// A position fix with its own accuracy and no heading: a GNSS receiver's solution
    /// (`super::gnss`).
    PositionFix(super::pilot::PositionFix),
    /// Where to hold while poses arrive (the link refuses non-finite values).
    PositionSetpoint(PositionSetpoint),
    /// A calibrated magnetic field in the IMU's axes (`super::compass`): handed to the pilot
    /// (`Pilot::magnetic_field`); one with a non-finite value or noise is ignored.
    MagneticField(super::compass::MagneticSample),
    /// The parameters changed: take these (applied when nothing is armed; kept until then).
    Configure(ControlSettings),
    /// Spin `motor` at `command` (clamped to [`MOTOR_TEST_MAX_COMMAND`]) until
    /// [`MOTOR_TEST_KEEPALIVE_MS`] after the latest such command. Ignored while armed otherwise.
    MotorTest { motor: u8, command: f32 },
    /// End a motor test (the host went away).
    StopMotorTest,
    /// Send an ESC command to `motor` (`None` = every motor) with the next stop frames. Ignored
    /// while a flight, an identification or a motor test is armed.
    EscCommand { command: DshotCommand, motor: Option<u8> },
}

/// What the control step takes from the parameters (`super::params::Params`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ControlSettings {
    pub throw: ThrowConfig,
    pub excitation: ExcitationConfig,
    /// Subtracted from every accelerometer sample, m/s², IMU axes.
    pub acc_bias_mps2: [f32; 3],
    /// What the external poses are (latency, noise).
    pub pose: super::pilot::PoseConfig,
    /// What landings and fly-aways are.
    pub land: super::landing::LandConfig,
    /// Battery voltage per cell below which a flight lands, V (`None`: never; read by the
    /// control task, which measures the battery).
    pub land_cell_v: Option<f32>,
    /// How the pilot's sticks are flown.
    pub sticks: super::sticks::StickConfig,
    /// The radio's stick channels and mode switch (read by the control task's receiver).
    pub stick_map: crate::drivers::crsf::StickMap,
    /// The mode switch's channel, 0-based.
    pub mode_channel: u8,
    /// How long, armed, bad IMU samples are held over before the IMU failsafe acts, s
    /// (`imu_fault_timeout_s`; 0: at the first bad sample).
    pub imu_fault_timeout_s: f32,
    /// Arm for throw-to-fly although the ESCs report no speed, the learner then identifying
    /// from the commands and the body's response (`flight::learner::no_speed`, issue 32): set
    /// where the user says the ESCs cannot report (`motor_bidir_dshot` = 0; 98.6 % of 1,000
    /// random worlds hovered, docs/benchmarks.md).
    pub arm_without_speeds: bool,
    /// The compass's declination, rad, east of true north positive (`compass_declination_deg`).
    pub compass_declination_rad: f32,
}

impl Default for ControlSettings {
    fn default() -> Self {
        Self {
            throw: ThrowConfig::default(),
            excitation: ExcitationConfig::default(),
            acc_bias_mps2: [0.0; 3],
            pose: super::pilot::PoseConfig::default(),
            land: super::landing::LandConfig::default(),
            land_cell_v: Some(super::battery::DEFAULT_LAND_CELL_V),
            sticks: super::sticks::StickConfig::default(),
            stick_map: crate::drivers::crsf::StickMap::AETR,
            mode_channel: crate::drivers::crsf::RcLinkConfig::default().mode.channel as u8,
            imu_fault_timeout_s: super::hal::IMU_FAULT_TIMEOUT_S,
            arm_without_speeds: false,
            compass_declination_rad: 0.0,
        }
    }
}

impl From<&super::params::Params> for ControlSettings {
    fn from(params: &super::params::Params) -> Self {
        Self {
            throw: params.throw_config(),
            excitation: params.excitation_config(),
            acc_bias_mps2: params.acc_bias_mps2(),
            pose: params.pose_config(),
            land: params.land_config(),
            land_cell_v: params.land_cell_v(),
            sticks: params.stick_config(),
            stick_map: params.stick_map(),
            mode_channel: params.mode_channel(),
            imu_fault_timeout_s: params.imu_fault_timeout_s(),
            arm_without_speeds: params.arms_without_speeds(),
            compass_declination_rad: params.compass_declination_rad(),
        }
    }
}

/// A running motor test.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
struct MotorTestState {
    motor: u8,
    command: f32,
    /// It stops by itself at this time, µs.
    until_us: u64,
}

/// Control-step rate, Hz: the published system's INDI and learner rate (docs/algorithms/indi.md).
pub const CONTROL_RATE_HZ: u16 = 2000;

/// Whether a throw-to-fly attempt is under way in `phase`, or waits for its model.
#[inline(always)]
fn attempt_under_way(phase: FlightPhase, wait: EngageWait) -> bool {
    !matches!(phase, FlightPhase::Idle | FlightPhase::Done) || wait.active()
}

/// The excitation's end waiting for a model still learning from it ([`ENGAGE_WAIT_MAX_S`]).
/// Only a learner that models the speeds publishes such models (`LearnedModel::pending`).
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct EngageWait {
    /// Steps it may still wait (0: not waiting).
    steps: u16,
}

impl EngageWait {
    /// The excitation has just ended; steps of `period_us`.
    fn start(&mut self, period_us: u32) {
        self.steps = (ENGAGE_WAIT_MAX_US / period_us.max(1)).max(1) as u16;
    }

    fn active(self) -> bool {
        self.steps > 0
    }

    /// One step of the wait: whether it goes on (the model still `pending` and time left);
    /// once it does not, it is over and the controller engages.
    fn goes_on(&mut self, pending: bool) -> bool {
        self.steps = self.steps.saturating_sub(1);
        if !pending {
            self.steps = 0;
        }
        self.steps > 0
    }

    /// The attempt ended another way (disarm, failsafe, a new arming).
    fn end(&mut self) {
        self.steps = 0;
    }
}

/// [`ENGAGE_WAIT_MAX_S`] in µs.
const ENGAGE_WAIT_MAX_US: u32 = (ENGAGE_WAIT_MAX_S * 1e6) as u32;

/// Time without a usable IMU sample after which the status calls the IMU absent, µs (10 ms).
/// Status only: while armed, `imu_fault_timeout_s` decides when a missing IMU fails safe.
const IMU_ABSENT_AFTER_US: u64 = 10_000;

/// A motor counts as reporting its speed while its latest finite report is at most this old, s
/// ([`SPEED_REPORT_TIMEOUT_MS`]). Origin: a bidirectional-DShot ESC answers every frame (2 kHz
/// here), and the board's driver already calls a motor stale after 4 failed answers in a row
/// (`drivers::dshot::STALE_ANSWERS`, 2 ms), so 0.1 s (200 frames) without a report is no run of
/// bit errors but an ESC that does not answer. It is longer than the report latency of any ESC
/// the simulator models (≤ 0.05 s; before its first report a motor reports nothing) and 2–4
/// motor time constants, so a motor silent that long during the excitation has lost its pulse.
pub const SPEED_REPORT_TIMEOUT_S: f32 = SPEED_REPORT_TIMEOUT_MS as f32 * 1e-3;

/// Consecutive bit-identical readings of one gyro axis (while another axis changes) after which
/// the axis counts as stuck (16 ms at 2 kHz). Origin: at rest on the bench, the ICM-42688-P's gyro
/// noise (2.8 mdps/√Hz, about 1 LSB at ±2000 °/s over its ~500 Hz band) makes two consecutive
/// readings equal with probability ≲ 0.3, so 32 equal readings come by chance with probability
/// ≲ 0.3³¹ ≈ 10⁻¹⁶ per step; in flight, motor vibration makes it far smaller. The simulator's
/// IMU (average of four 8 kHz samples of 16-bit codes) repeats with probability about 0.03.
pub const STUCK_GYRO_SAMPLES: u16 = 32;

/// Gyro reading at or beyond which an axis is at its rail, rad/s (1,990 °/s). Origin: the
/// ICM-42688-P at ±2,000 °/s full scale, less 10 °/s of margin for the codes next to the rail. An
/// axis held there repeats its reading because the craft turns faster than the sensor measures
/// (a violent tumble), not because the sensor froze: such repeats do not count as stuck, and the
/// attitude failsafe judges whether the flight is lost.
pub const GYRO_RAIL_RAD_S: f32 = 1990.0 * core::f32::consts::PI / 180.0;

/// Accelerometer reading at or beyond which an axis counts as saturated, m/s² (15.5 g). Origin:
/// the ICM-42688-P at ±16 g full scale (156.9 m/s²), less 0.5 g of margin so that a reading a
/// code or two below the rail counts too; no multirotor thrust comes near it (thrust-to-weight
/// 2.5–5 in the simulator's airframes, ≲ 10 for racers), so a reading there is an impact or a
/// failed sensor, and the true value is unknown.
pub const ACCEL_SATURATED_MPS2: f32 = 15.5 * 9.806_65;

/// Why a sample was not used as read (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ImuGlitch {
    Missing,
    NonFinite,
    Frozen,
    AccelSaturated,
}

/// What the IMU checks made of one step's sample.
#[derive(Clone, Copy, Debug, PartialEq)]
enum ImuVerdict {
    /// Used as read.
    Good(ImuSample),
    /// Bad, held over: the sample to use instead (raw, before the bias).
    Held(ImuSample, ImuGlitch),
    /// Bad for `imu_fault_timeout_s` (or nothing good to hold): the IMU has failed.
    Failed(ImuGlitch),
    /// Bad while disarmed: not used.
    Unused,
}

/// The IMU checks' state (see the module doc).
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct ImuGuard {
    /// The previous finite sample, as bits (gyro then accelerometer).
    previous_bits: Option<[u32; 6]>,
    /// Readings of each gyro axis equal to the previous one, consecutive.
    repeats: [u16; 3],
    /// The latest good sample (raw, before the bias).
    last_good: Option<ImuSample>,
    /// The latest accelerometer reading with no axis saturated (raw, before the bias).
    last_unsaturated_accel: Option<[f32; 3]>,
    /// Time of the first bad sample of the run in progress while armed, µs.
    bad_since_us: Option<u64>,
}

impl ImuGuard {
    /// Check one step's sample (`raw`, `None` if the IMU delivered none) at `now_us`: `armed`
    /// (an attempt or a flight) holds bad samples for `timeout_us`, `spinning` (the motors run)
    /// makes a frozen sample bad. Also returns whether a gyro axis is stuck.
    fn check(
        &mut self,
        raw: Option<ImuSample>,
        armed: bool,
        spinning: bool,
        now_us: u64,
        timeout_us: u64,
    ) -> (ImuVerdict, bool) {
        let mut stuck = false;
        let glitch = match raw {
            None => Some(ImuGlitch::Missing),
            Some(sample) if !is_finite_sample(&sample) => Some(ImuGlitch::NonFinite),
            Some(sample) => {
                let [gx, gy, gz] = sample.gyro_rad_s.map(f32::to_bits);
                let [ax, ay, az] = sample.accel_mps2.map(f32::to_bits);
                let bits = [gx, gy, gz, ax, ay, az];
                let frozen = spinning && self.previous_bits == Some(bits);
                // A frozen sample changes no axis, so it belongs to no run of one axis stuck while
                // the others live: the runs start afresh (else a chance repeat of one axis next
                // to a freeze would make the freeze a stuck axis).
                if frozen {
                    self.repeats = [0; 3];
                } else {
                    stuck = self.track_gyro_axes(&bits);
                }
                self.previous_bits = Some(bits);
                let saturated = sample.accel_mps2.iter().any(|a| a.abs() >= ACCEL_SATURATED_MPS2);
                if !saturated {
                    self.last_unsaturated_accel = Some(sample.accel_mps2);
                }
                if frozen {
                    Some(ImuGlitch::Frozen)
                } else if saturated && armed {
                    Some(ImuGlitch::AccelSaturated)
                } else {
                    None
                }
            }
        };
        let Some(glitch) = glitch else {
            self.last_good = raw;
            self.bad_since_us = None;
            return (raw.map_or(ImuVerdict::Unused, ImuVerdict::Good), stuck);
        };
        if !armed {
            self.bad_since_us = None;
            return (ImuVerdict::Unused, stuck);
        }
        let since_us = *self.bad_since_us.get_or_insert(now_us);
        let held = match (glitch, raw, self.last_unsaturated_accel) {
            (ImuGlitch::AccelSaturated, Some(sample), Some(accel_mps2)) => {
                Some(ImuSample { accel_mps2, ..sample })
            }
            (ImuGlitch::AccelSaturated, _, _) => None,
            _ => self.last_good,
        };
        let verdict = match held {
            Some(held) if now_us.saturating_sub(since_us) < timeout_us => {
                ImuVerdict::Held(held, glitch)
            }
            _ => ImuVerdict::Failed(glitch),
        };
        (verdict, stuck)
    }

    /// Follow each gyro axis's run of bit-identical readings: whether one axis is stuck.
    fn track_gyro_axes(&mut self, bits: &[u32; 6]) -> bool {
        match self.previous_bits {
            Some(previous) => {
                for axis in 0..3 {
                    let at_rail = f32::from_bits(bits[axis]).abs() >= GYRO_RAIL_RAD_S;
                    self.repeats[axis] = if bits[axis] == previous[axis] && !at_rail {
                        self.repeats[axis].saturating_add(1)
                    } else {
                        0
                    };
                }
            }
            None => self.repeats = [0; 3],
        }
        // N equal readings are N − 1 repeats; "another axis changed" = its run is shorter.
        let stuck_axis = |r: u16| r.saturating_add(1) >= STUCK_GYRO_SAMPLES;
        (0..3).any(|i| {
            stuck_axis(self.repeats[i]) && (0..3).any(|j| j != i && !stuck_axis(self.repeats[j]))
        })
    }
}

/// When each motor last reported its speed (see the module doc).
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct SpeedMonitor {
    /// Time of each motor's latest finite, non-negative speed report, µs.
    last_report_us: [Option<u64>; MAX_MOTORS],
}

impl SpeedMonitor {
    /// Take the reports read at `now_us`.
    fn observe(&mut self, speeds_rad_s: &[Option<f32>; MAX_MOTORS], now_us: u64) {
        for (last, speed) in self.last_report_us.iter_mut().zip(speeds_rad_s) {
            if speed.is_some_and(|s| s.is_finite() && s >= 0.0) {
                *last = Some(now_us);
            }
        }
    }

    /// Bit i set: motor i (of `count`) has reported no speed for [`SPEED_REPORT_TIMEOUT_S`] at
    /// `now_us`, counting from `since_us` at the latest (a motor gets that long from then).
    fn silent(&self, count: usize, now_us: u64, since_us: u64) -> u8 {
        let timeout_us = u64::from(SPEED_REPORT_TIMEOUT_MS) * 1000;
        let mut silent = 0u8;
        for (i, last) in self.last_report_us.iter().enumerate().take(count.min(MAX_MOTORS)) {
            let heard_us = last.map_or(since_us, |t| t.max(since_us));
            if now_us.saturating_sub(heard_us) > timeout_us {
                silent |= 1 << i;
            }
        }
        silent
    }
}

/// The bits of the first `count` motors.
fn motor_mask(count: usize) -> u8 {
    ((1u16 << count.min(MAX_MOTORS)) - 1) as u8
}

/// How the control loop is set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControlConfig {
    /// Step rate, Hz; the board's timer must call [`ControlLoop::step`] at this rate.
    pub rate_hz: u16,
}

impl Default for ControlConfig {
    fn default() -> Self {
        Self { rate_hz: CONTROL_RATE_HZ }
    }
}

/// What the control step publishes for the link and status (a small `Copy` value).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ControlSnapshot {
    /// Time of the latest step, µs since start-up.
    pub t_us: u64,
    pub steps: u32,
    /// Mean step rate over the last completed second, Hz.
    pub rate_hz: f32,
    /// Steps that began more than half a period after the previous one was due.
    pub late_steps: u32,
    /// Longest interval between consecutive steps, µs.
    pub max_interval_us: u32,
    pub samples_dropped: u32,
    pub armed: bool,
    pub imu_present: bool,
    pub imu_samples: u32,
    pub imu_missing: u32,
    /// The latest IMU sample and its time, µs.
    pub imu: ImuSample,
    pub imu_t_us: u64,
    pub motor_count: u8,
    pub commands: [f32; MAX_MOTORS],
    pub speeds_rad_s: [Option<f32>; MAX_MOTORS],
    /// Where the throw-to-fly attempt stands.
    pub phase: FlightPhase,
    /// Why the last attempt ended without a result (or was refused), if it did.
    pub failure: LearnerFailure,
    /// The motor being pulsed.
    pub exciting_motor: Option<u8>,
    /// Time since the excitation began, ms (0 before).
    pub excitation_ms: u16,
    /// Releases refused because the craft was not falling freely.
    pub releases_refused: u16,
    /// The latest external pose and its arrival time, µs.
    pub external_pose: Option<(ExternalPose, u64)>,
    /// The latest position fix with its own accuracy (a GNSS solution) and its arrival, µs.
    pub position_fix: Option<(super::pilot::PositionFix, u64)>,
    /// Flight on the learned model: attitude, position, setpoints, failsafes.
    pub pilot: PilotStatus,
    /// The motor a motor test spins now.
    pub motor_test: Option<u8>,
    /// Motor tests that stopped by themselves (no keep-alive in time).
    pub motor_test_timeouts: u16,
    /// IMU samples held over while armed (the last good one used instead), by cause.
    pub imu_held: ImuHeldCounters,
    /// Longest run of held IMU samples, µs (from the first held sample's step to the last's).
    pub imu_longest_hold_us: u32,
    /// Bit i set: motor i reported its speed within [`SPEED_REPORT_TIMEOUT_S`].
    pub speeds_reported: u8,
    /// Times a motor's speed reports stopped while the motors spun (exciting or flying).
    pub speed_reports_lost: u16,
    /// ESC commands the motor outputs took, and those they or the step refused (armed, or
    /// outputs that send none).
    pub esc_commands_sent: u16,
    pub esc_commands_refused: u16,
    /// The flight battery, as the control task's [`BatteryMonitor`](super::battery::BatteryMonitor)
    /// last saw it (`None`: the board measures none). Filled by the task, not the loop.
    pub battery: Option<protocol::BatteryStatus>,
}

/// The control loop: the highest-priority task's local resource. Its state is one value
/// ([`ControlState`]) apart from the rings out of the step, so a flight log can record the state
/// at an arming and a replay can start from it.
pub struct ControlLoop<'q> {
    state: ControlState,
    samples: SampleProducer<'q>,
    /// The telemetry ring to the link task, when the board streams per-step topics.
    telemetry: Option<StepProducer<'q>>,
}

/// Which of the background task's results the control loop adopted last: the model's
/// `LearnedModel::samples` and `pending`, and `BackgroundResults::learning_ended`. A new version
/// reaches the pilot; the same one again is not copied.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ModelVersion {
    /// Samples the model learned from.
    pub samples: u32,
    /// Whether it was still to learn from samples already taken.
    pub pending: bool,
    /// Whether the attempt's learning had ended (the model final).
    pub learning_ended: bool,
}

/// Everything the control loop remembers from one step to the next (the rings out of it
/// aside): what a flight log that begins at an arming records (`super::log`, the arming
/// state), so its replay runs the steps after it from the state the board ran them from.
#[derive(Clone, Copy, Serialize, Deserialize)]
pub struct ControlState {
    period_us: u32,
    throw_to_fly: ThrowToFly,
    /// The settings in force, and newer ones waiting for the craft to be disarmed.
    settings: ControlSettings,
    pending_settings: Option<ControlSettings>,
    motor_test: Option<MotorTestState>,
    /// An ESC command for the motor outputs, handed over in the next step.
    esc_command: Option<(DshotCommand, Option<u8>)>,
    pilot: Pilot,
    /// `LearnedModel::samples` and `pending` of the model last received, and whether its
    /// learning had ended (to copy only what changed).
    model_version: Option<ModelVersion>,
    snapshot: ControlSnapshot,
    previous_step_us: Option<u64>,
    /// Time of the latest finite IMU sample, µs.
    last_imu_us: Option<u64>,
    imu_guard: ImuGuard,
    speed_monitor: SpeedMonitor,
    /// When the throw-to-fly attempt in progress was armed, µs.
    armed_at_us: u64,
    /// Steps the excitation's end may still wait for the model ([`ENGAGE_WAIT_MAX_S`]; 0: not
    /// waiting).
    engage_wait: EngageWait,
    /// A landing asked for while the craft was in the air in its identification: it lands as
    /// soon as it flies.
    land_when_flying: Option<LandReason>,
    rate_window_start_us: u64,
    rate_window_steps: u32,
}

impl<'q> ControlLoop<'q> {
    pub fn new(config: ControlConfig, samples: SampleProducer<'q>) -> Self {
        let rate_hz = config.rate_hz.max(1);
        let state = ControlState {
            period_us: 1_000_000 / u32::from(rate_hz),
            throw_to_fly: ThrowToFly::new(
                ThrowConfig::default(),
                ExcitationConfig::default(),
                MAX_MOTORS,
            ),
            settings: ControlSettings::default(),
            pending_settings: None,
            motor_test: None,
            esc_command: None,
            pilot: Pilot::new(f32::from(rate_hz)),
            model_version: None,
            snapshot: ControlSnapshot::default(),
            previous_step_us: None,
            last_imu_us: None,
            imu_guard: ImuGuard::default(),
            speed_monitor: SpeedMonitor::default(),
            armed_at_us: 0,
            engage_wait: EngageWait::default(),
            land_when_flying: None,
            rate_window_start_us: 0,
            rate_window_steps: 0,
        };
        Self { state, samples, telemetry: None }
    }

    /// The loop's state now (a copy: what a flight log records at an arming).
    pub fn state(&self) -> &ControlState {
        &self.state
    }

    /// The version of the background's results adopted last.
    pub fn model_version(&self) -> Option<ModelVersion> {
        self.state.model_version
    }

    /// The IMU offset the step compensates the accelerometer with (IMU axes, m), as adopted
    /// with the background task's results ([`Self::receive`]; `None` before any).
    pub fn imu_offset_m(&self) -> Option<[f32; 3]> {
        self.state.pilot.imu_offset_m()
    }

    /// Learner samples handed to the background task so far (those its ring took).
    pub fn samples_handed(&self) -> u32 {
        self.samples.accepted()
    }

    /// Continue from `state` (a replay starting where a logged arming left the board).
    pub fn restore(&mut self, state: ControlState) {
        self.state = state;
    }

    /// Write one [`StepRecord`] per step into `ring` for the link's per-step telemetry.
    pub fn with_telemetry(mut self, ring: StepProducer<'q>) -> Self {
        self.set_telemetry(ring);
        self
    }

    /// Publish telemetry to `ring` from now on, where the loop lies (a board builds it in
    /// place).
    pub fn set_telemetry(&mut self, ring: StepProducer<'q>) {
        self.telemetry = Some(ring);
    }

    /// Carry out a command from another task (takes effect in this step or the next).
    pub fn command(&mut self, command: ControlCommand, now_us: u64) {
        match command {
            ControlCommand::ArmThrowToFly => {
                // Refused while a motor does not report its speed, once the step has run (before
                // the first step nothing is known; the attempt then gets the report timeout).
                let count = usize::from(self.state.snapshot.motor_count);
                if !self.state.settings.arm_without_speeds
                    && self.state.snapshot.steps > 0
                    && self.state.speed_monitor.silent(count, now_us, 0) != 0
                {
                    self.state.snapshot.failure = LearnerFailure::NoSpeedTelemetry;
                } else {
                    self.state.motor_test = None;
                    self.state.engage_wait.end();
                    self.state.land_when_flying = None;
                    self.state.throw_to_fly.arm();
                    self.state.armed_at_us = now_us;
                    self.state.snapshot.failure = LearnerFailure::None;
                }
            }
            ControlCommand::Disarm => self.disarm(),
            ControlCommand::Failsafe(failsafe) => {
                let armed = self.flight_armed() || self.state.motor_test.is_some();
                self.disarm();
                if armed {
                    self.state.pilot.raise(failsafe);
                }
            }
            ControlCommand::Land(reason) => self.land(reason),
            ControlCommand::Sticks(sticks) => self.state.pilot.set_sticks(sticks),
            ControlCommand::ExternalPose(pose) => {
                if super::is_finite_pose(&pose.position_ned_m, pose.heading_rad) {
                    self.state.snapshot.external_pose = Some((pose, now_us));
                    self.state.pilot.pose(&pose, now_us);
                }
            }
            ControlCommand::PositionFix(fix) => {
                if fix.is_valid() {
                    self.state.snapshot.position_fix = Some((fix, now_us));
                    self.state.pilot.fix(&fix, now_us);
                }
            }
            ControlCommand::PositionSetpoint(setpoint) => {
                self.state.pilot.set_position_setpoint(&setpoint);
            }
            ControlCommand::MagneticField(sample) => {
                if sample.is_valid() {
                    self.state.pilot.magnetic_field(&sample, now_us);
                }
            }
            ControlCommand::Configure(settings) => self.state.pending_settings = Some(settings),
            ControlCommand::MotorTest { motor, command } => {
                let flight_armed = self.flight_armed();
                let valid = usize::from(motor) < usize::from(self.state.snapshot.motor_count)
                    && command.is_finite();
                if valid && !flight_armed {
                    self.state.motor_test = Some(MotorTestState {
                        motor,
                        command: command.clamp(0.0, MOTOR_TEST_MAX_COMMAND),
                        until_us: now_us + u64::from(MOTOR_TEST_KEEPALIVE_MS) * 1000,
                    });
                }
            }
            ControlCommand::StopMotorTest => self.state.motor_test = None,
            ControlCommand::EscCommand { command, motor } => {
                self.state.esc_command = Some((command, motor));
            }
        }
        self.apply_pending_settings();
        self.publish_phase();
    }

    /// End the flight gently ([`ControlCommand::Land`]).
    fn land(&mut self, reason: LandReason) {
        if reason == LandReason::RcLost && (self.flight_armed() || self.state.motor_test.is_some())
        {
            self.state.pilot.note_failsafe(Failsafe::RcLost);
        }
        if self.state.pilot.land(reason) {
            return;
        }
        let in_the_air = matches!(
            self.state.throw_to_fly.phase(),
            FlightPhase::Released | FlightPhase::Exciting
        ) || self.state.engage_wait.active();
        if in_the_air {
            self.state.land_when_flying = Some(reason);
        } else {
            self.disarm();
        }
    }

    /// Stop every motor and leave any armed state; an attempt under way ends as `Disarmed`.
    fn disarm(&mut self) {
        self.state.land_when_flying = None;
        self.state.motor_test = None;
        self.state.esc_command = None;
        let attempt = self.attempt();
        self.state.throw_to_fly.disarm();
        self.state.engage_wait.end();
        self.state.pilot.disarm();
        if attempt {
            self.state.snapshot.failure = LearnerFailure::Disarmed;
        }
    }

    /// Whether a throw-to-fly attempt is under way: from the arming to the engagement,
    /// its wait for the model ([`ENGAGE_WAIT_MAX_S`]) included.
    fn attempt(&self) -> bool {
        attempt_under_way(self.state.throw_to_fly.phase(), self.state.engage_wait)
    }

    /// Whether a throw-to-fly attempt or a flight is under way (a motor test aside).
    fn flight_armed(&self) -> bool {
        self.attempt() || self.state.pilot.flying()
    }

    /// Take waiting settings once nothing is armed. The throw detector is rebuilt only when
    /// its configuration changed (it would otherwise forget the last attempt's outcome).
    fn apply_pending_settings(&mut self) {
        if self.state.pending_settings.is_none()
            || self.flight_armed()
            || self.state.motor_test.is_some()
        {
            return;
        }
        let Some(settings) = self.state.pending_settings.take() else { return };
        if settings.throw != self.state.settings.throw
            || settings.excitation != self.state.settings.excitation
        {
            self.state.throw_to_fly =
                ThrowToFly::new(settings.throw, settings.excitation, MAX_MOTORS);
        }
        self.state.pilot.configure_pose(settings.pose);
        self.state.pilot.configure_landing(settings.land);
        self.state.pilot.configure_sticks(settings.sticks);
        self.state.pilot.configure_compass(settings.compass_declination_rad);
        self.state.settings = settings;
    }

    /// Take what the background task published: the learned model (copied only when it changed)
    /// and the IMU offset it was learned with. Call it with the latest results before a step.
    ///
    /// Returns whether it adopted them (a new model version or IMU offset reached the pilot):
    /// the tick logs that step, so a replay hands the control step the same results at the
    /// same step.
    pub fn receive(&mut self, results: &BackgroundResults) -> bool {
        // The samples learned from, and whether it is pending: a restarted learner's first model
        // has learned from none, as the one before the first attempt had.
        let version = ModelVersion {
            samples: results.learned.samples,
            pending: results.learned.pending,
            learning_ended: results.learning_ended,
        };
        // The offset changes alone between attempts (configured, calibrated), the model not.
        let offset_new = self.state.pilot.imu_offset_m() != Some(results.learner_r_imu_m);
        if self.state.model_version == Some(version) && !offset_new {
            return false;
        }
        self.state.model_version = Some(version);
        let model = &results.learned;
        self.state.pilot.set_model(model, results.learner_r_imu_m, results.learning_ended);
        true
    }

    /// One control step at time `now_us` (µs since start-up, monotonic). Returns whether samples
    /// are waiting for the background task (the board then schedules it).
    pub fn step<I: Imu, M: Motors>(&mut self, now_us: u64, imu: &mut I, motors: &mut M) -> bool {
        self.account_timing(now_us);
        let bias = self.state.settings.acc_bias_mps2;
        let raw = imu.read();
        let flying = self.state.pilot.flying();
        let armed = self.flight_armed();
        let spinning = flying
            || self.state.throw_to_fly.phase() == FlightPhase::Exciting
            || self.state.engage_wait.active();
        // The IMU checks (module doc): bad samples are held over while armed; a fault that
        // lasts `imu_fault_timeout_s`, or a stuck gyro axis in flight, fails.
        let timeout_us = (self.state.settings.imu_fault_timeout_s.max(0.0) * 1e6) as u64;
        let (verdict, stuck) = self.state.imu_guard.check(raw, armed, spinning, now_us, timeout_us);
        let mut imu_failed = match verdict {
            ImuVerdict::Failed(glitch) => Some(glitch),
            _ => None,
        };
        if stuck && flying {
            imu_failed = imu_failed.or(Some(ImuGlitch::Frozen));
        }
        let (sample, fresh) = match verdict {
            ImuVerdict::Good(sample) => (Some(sample), true),
            ImuVerdict::Held(sample, glitch) => {
                self.count_held(glitch, now_us);
                (Some(sample), false)
            }
            ImuVerdict::Failed(_) | ImuVerdict::Unused => (None, false),
        };
        let sample = sample.filter(|_| imu_failed.is_none()).map(|mut sample| {
            for (a, b) in sample.accel_mps2.iter_mut().zip(bias) {
                *a -= b;
            }
            sample
        });
        let snapshot = &mut self.state.snapshot;
        if raw.is_some_and(|sample| is_finite_sample(&sample)) {
            snapshot.imu_samples = snapshot.imu_samples.wrapping_add(1);
            self.state.last_imu_us = Some(now_us);
        } else {
            snapshot.imu_missing = snapshot.imu_missing.wrapping_add(1);
        }
        if let Some(sample) = sample {
            snapshot.imu = sample;
            if fresh {
                snapshot.imu_t_us = now_us;
            }
        }
        snapshot.imu_present =
            self.state.last_imu_us.is_some_and(|t| now_us.saturating_sub(t) < IMU_ABSENT_AFTER_US);

        let motor_count = usize::from(motors.count()).min(MAX_MOTORS);
        snapshot.motor_count = motor_count as u8;
        self.state.throw_to_fly.set_motors(motor_count);
        // A failed IMU during an attempt (its wait for the model included) or a flight:
        // everything stops in this step.
        let attempt = attempt_under_way(self.state.throw_to_fly.phase(), self.state.engage_wait);
        if let Some(glitch) = imu_failed.filter(|_| attempt || self.state.pilot.flying()) {
            if glitch == ImuGlitch::Missing {
                let _ = self.state.pilot.imu_lost();
            } else {
                self.state.pilot.imu_fault();
            }
            self.state.throw_to_fly.disarm();
            self.state.engage_wait.end();
            if attempt {
                snapshot.failure = LearnerFailure::ImuLost;
            }
        }
        // A motor that stopped reporting its speed ends an attempt before or during the
        // excitation (module doc); its commands are zero from this step.
        let phase = self.state.throw_to_fly.phase();
        if matches!(
            phase,
            FlightPhase::WaitingForThrow
                | FlightPhase::Throwing
                | FlightPhase::Released
                | FlightPhase::Exciting
        ) && !self.state.settings.arm_without_speeds
            && self.state.speed_monitor.silent(motor_count, now_us, self.state.armed_at_us) != 0
        {
            self.state.throw_to_fly.disarm();
            snapshot.failure = LearnerFailure::NoSpeedTelemetry;
            if phase == FlightPhase::Exciting {
                snapshot.speed_reports_lost = snapshot.speed_reports_lost.wrapping_add(1);
            }
        }
        let dt_s = self.state.period_us as f32 * 1e-6;
        let previous_commands = snapshot.commands;
        snapshot.commands = [0.0; MAX_MOTORS];
        snapshot.exciting_motor = None;
        if let Some(imu) = sample {
            let phase_before = self.state.throw_to_fly.phase();
            let disarmed = matches!(phase_before, FlightPhase::Idle | FlightPhase::WaitingForThrow)
                && !self.state.pilot.flying();
            self.state.pilot.observe(&imu, now_us, disarmed);
            // The speeds reported in the previous step (this step's come after the commands).
            let speeds = snapshot.speeds_rad_s.map(|s| s.unwrap_or(f32::NAN));
            let mut out =
                self.state.throw_to_fly.update(imu.gyro_rad_s, imu.accel_mps2, &speeds, dt_s);
            let ended = phase_before == FlightPhase::Exciting
                && self.state.throw_to_fly.phase() == FlightPhase::Done;
            if ended {
                self.state.engage_wait.start(self.state.period_us);
            }
            // The excitation is over: fly what was learned, from the last commands, once the
            // model has learned from every sample of it (at most `ENGAGE_WAIT_MAX_S`). Every
            // way out of the attempt (disarm, failsafe, a new arming) ends the wait.
            if ended || self.state.engage_wait.active() {
                if self.state.engage_wait.goes_on(self.state.pilot.model_pending()) {
                    out.commands = previous_commands;
                } else {
                    let land = self.state.land_when_flying.take();
                    match self.state.pilot.engage(&imu, &previous_commands, &speeds) {
                        Err(failsafe) => snapshot.failure = learner_failure(failsafe),
                        Ok(()) => {
                            if let Some(reason) = land {
                                self.state.pilot.land(reason);
                            }
                        }
                    }
                }
            }
            // Never a non-finite or out-of-range command (the schedule's are in [0, 1] already,
            // and so are the last step's, held while waiting for the model).
            for (dst, src) in snapshot.commands.iter_mut().zip(out.commands).take(motor_count) {
                *dst = if src.is_finite() { src.clamp(0.0, 1.0) } else { 0.0 };
            }
            snapshot.exciting_motor = out.active_motor;
            if self.state.pilot.flying() {
                match self.state.pilot.step(&imu, now_us) {
                    Ok(commands) => {
                        snapshot.commands[..motor_count].copy_from_slice(&commands[..motor_count])
                    }
                    // The pilot has stopped: motors at zero from this step.
                    Err(_) => self.state.throw_to_fly.disarm(),
                }
                // Landed (the pilot stopped without a failsafe): nothing stays armed.
                if !self.state.pilot.flying() {
                    self.state.throw_to_fly.disarm();
                }
            }
            match out.event {
                ThrowEvent::NotFreeFall => {
                    snapshot.failure = LearnerFailure::NotFreeFall;
                    snapshot.releases_refused = snapshot.releases_refused.wrapping_add(1);
                }
                ThrowEvent::TimedOut => snapshot.failure = LearnerFailure::ThrowTimedOut,
                ThrowEvent::Thrown => snapshot.failure = LearnerFailure::None,
                _ => {}
            }
        }
        self.run_motor_test(now_us, motor_count);
        if let Some((command, motor)) = self.state.esc_command.take() {
            // The link refused it while armed; an arming since then has the last word.
            let taken = if self.flight_armed() || self.state.motor_test.is_some() {
                Err(EscCommandError::Armed)
            } else {
                motors.send_command(command, motor)
            };
            let counter = match taken {
                Ok(()) => &mut self.state.snapshot.esc_commands_sent,
                Err(_) => &mut self.state.snapshot.esc_commands_refused,
            };
            *counter = counter.wrapping_add(1);
        }
        let snapshot = &mut self.state.snapshot;
        motors.set_commands(&snapshot.commands[..motor_count]);
        snapshot.speeds_rad_s = motors.speeds_rad_s();
        self.state.speed_monitor.observe(&snapshot.speeds_rad_s, now_us);
        let reported =
            motor_mask(motor_count) & !self.state.speed_monitor.silent(motor_count, now_us, 0);
        if self.state.pilot.flying() {
            // Flying on: counted once per motor that stops reporting.
            let lost = (snapshot.speeds_reported & !reported).count_ones() as u16;
            snapshot.speed_reports_lost = snapshot.speed_reports_lost.wrapping_add(lost);
        }
        snapshot.speeds_reported = reported;
        self.apply_pending_settings();
        self.publish_phase();

        // Only fresh samples go to the background task: it never learns from a held one.
        if let Some(imu) = sample.filter(|_| fresh) {
            let snapshot = &self.state.snapshot;
            self.samples.push(LearnerSample {
                t_us: now_us,
                imu,
                commands: snapshot.commands,
                speeds_rad_s: snapshot.speeds_rad_s.map(|s| s.unwrap_or(f32::NAN)),
                phase: snapshot.phase,
                flying: snapshot.pilot.flying,
                motor_count: snapshot.motor_count,
                velocity_imu_mps: self.state.pilot.velocity_imu_mps(),
            });
        }
        self.state.snapshot.samples_dropped = self.samples.dropped();
        if let Some(ring) = &mut self.telemetry {
            let snapshot = &self.state.snapshot;
            ring.push(StepRecord {
                step: snapshot.steps,
                t_us: now_us,
                imu: sample.filter(|_| fresh),
                q_world_imu: snapshot.pilot.q_world_imu,
                phase: snapshot.phase,
                failed: snapshot.failure != LearnerFailure::None,
                flying: snapshot.pilot.flying,
                motor_count: snapshot.motor_count,
                commands: snapshot.commands,
                speeds_rad_s: snapshot.speeds_rad_s,
            });
        }
        self.samples.has_waiting()
    }

    /// Count a held IMU sample of the bad run that began at `ImuGuard::bad_since_us`.
    fn count_held(&mut self, glitch: ImuGlitch, now_us: u64) {
        let held = &mut self.state.snapshot.imu_held;
        let counter = match glitch {
            ImuGlitch::Missing => &mut held.missing,
            ImuGlitch::NonFinite => &mut held.non_finite,
            ImuGlitch::Frozen => &mut held.frozen,
            ImuGlitch::AccelSaturated => &mut held.accel_saturated,
        };
        *counter = counter.wrapping_add(1);
        let run_us = now_us.saturating_sub(self.state.imu_guard.bad_since_us.unwrap_or(now_us));
        let run_us = u32::try_from(run_us).unwrap_or(u32::MAX);
        self.state.snapshot.imu_longest_hold_us =
            self.state.snapshot.imu_longest_hold_us.max(run_us);
    }

    /// A motor test's command, or its end: by itself after the keep-alive, or when a flight
    /// begins (nothing else may drive the motors then).
    fn run_motor_test(&mut self, now_us: u64, motor_count: usize) {
        let Some(test) = self.state.motor_test else { return };
        if now_us >= test.until_us {
            self.state.motor_test = None;
            self.state.snapshot.motor_test_timeouts =
                self.state.snapshot.motor_test_timeouts.wrapping_add(1);
        } else if self.flight_armed() || usize::from(test.motor) >= motor_count {
            self.state.motor_test = None;
        } else {
            self.state.snapshot.commands[usize::from(test.motor)] = test.command;
        }
    }

    fn publish_phase(&mut self) {
        let phase = self.state.throw_to_fly.phase();
        let flight_armed = self.flight_armed();
        let snapshot = &mut self.state.snapshot;
        snapshot.phase = phase;
        snapshot.pilot = *self.state.pilot.status();
        snapshot.motor_test = self.state.motor_test.map(|test| test.motor);
        snapshot.armed = flight_armed || snapshot.motor_test.is_some();
        snapshot.excitation_ms =
            (self.state.throw_to_fly.excitation_elapsed_s() * 1000.0).clamp(0.0, 65_535.0) as u16;
    }

    /// The settings in force.
    pub fn settings(&self) -> &ControlSettings {
        &self.state.settings
    }

    /// The model the pilot flies (G1 and G2 refined in flight), while it flies.
    pub fn flown_model(&self) -> Option<&flight::indi::IndiModel> {
        self.state.pilot.flown_model()
    }

    /// Steps run since start-up.
    pub fn steps(&self) -> u32 {
        self.state.snapshot.steps
    }

    /// The latest state, for the link and the status.
    pub fn snapshot(&self) -> ControlSnapshot {
        self.state.snapshot
    }

    /// Whether anything is armed now (a flight, an attempt, a motor test), commands taken so
    /// far included: the snapshot's `armed` without copying the snapshot.
    pub fn armed(&self) -> bool {
        self.state.snapshot.armed
    }

    fn account_timing(&mut self, now_us: u64) {
        let snapshot = &mut self.state.snapshot;
        snapshot.t_us = now_us;
        snapshot.steps = snapshot.steps.wrapping_add(1);
        if let Some(previous) = self.state.previous_step_us {
            let interval_us = now_us.saturating_sub(previous).min(u64::from(u32::MAX)) as u32;
            snapshot.max_interval_us = snapshot.max_interval_us.max(interval_us);
            if interval_us > self.state.period_us + self.state.period_us / 2 {
                snapshot.late_steps = snapshot.late_steps.wrapping_add(1);
            }
        } else {
            self.state.rate_window_start_us = now_us;
        }
        self.state.previous_step_us = Some(now_us);
        self.state.rate_window_steps = self.state.rate_window_steps.wrapping_add(1);
        let window_us = now_us.saturating_sub(self.state.rate_window_start_us);
        if window_us >= 1_000_000 {
            // Steps completed in the window divided by its length.
            snapshot.rate_hz =
                self.state.rate_window_steps.saturating_sub(1) as f32 * 1e6 / window_us as f32;
            self.state.rate_window_start_us = now_us;
            self.state.rate_window_steps = 1;
        }
    }
}

/// How a failed handover shows in the learner's status.
fn learner_failure(failsafe: Failsafe) -> LearnerFailure {
    match failsafe {
        Failsafe::Identification(failure) => failure.learner_failure(),
        Failsafe::ImuLost => LearnerFailure::ImuLost,
        _ => LearnerFailure::NoHover,
    }
}

fn is_finite_sample(sample: &ImuSample) -> bool {
    sample.gyro_rad_s.iter().chain(&sample.accel_mps2).all(|x| x.is_finite())
}

#[cfg(test)]
mod tests {
    use super::super::hal::NoMotors;
    use super::super::queue::{split_queue, SampleQueue};
    use super::*;

    /// An IMU that delivers a sample on the steps the test chooses.
    struct ScriptedImu {
        deliver: fn(u32) -> bool,
        calls: u32,
    }

    impl Imu for ScriptedImu {
        fn read(&mut self) -> Option<ImuSample> {
            self.calls += 1;
            (self.deliver)(self.calls)
                .then_some(ImuSample { gyro_rad_s: [0.1, 0.2, 0.3], accel_mps2: [0.0, 0.0, -9.81] })
        }
    }

    /// Motors that remember what they were told.
    struct RecordingMotors {
        commands: Vec<f32>,
    }

    impl Motors for RecordingMotors {
        fn count(&self) -> u8 {
            4
        }
        fn set_commands(&mut self, commands: &[f32]) {
            self.commands = commands.to_vec();
        }
        fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
            [Some(100.0), Some(101.0), Some(102.0), Some(103.0), None, None, None, None]
        }
    }

    /// `Land` on the ground stops what is armed at once (a craft waiting for a throw, a motor
    /// test): there is nothing in the air to bring down.
    #[test]
    fn a_landing_asked_for_on_the_ground_stops_what_is_armed() {
        let mut queue = SampleQueue::new();
        let (producer, mut consumer) = split_queue(&mut queue);
        let mut control = ControlLoop::new(ControlConfig::default(), producer);
        let mut imu = ScriptedImu { deliver: |_| true, calls: 0 };
        let mut motors = RecordingMotors { commands: vec![] };
        control.step(0, &mut imu, &mut motors);
        control.command(ControlCommand::ArmThrowToFly, 500);
        control.step(500, &mut imu, &mut motors);
        assert!(control.armed(), "waiting for a throw");
        control.command(ControlCommand::Land(LandReason::Commanded), 1_000);
        assert!(!control.armed(), "stopped at once");
        assert_eq!(control.snapshot().failure, LearnerFailure::Disarmed);
        control.command(ControlCommand::MotorTest { motor: 1, command: 0.05 }, 1_500);
        control.step(1_500, &mut imu, &mut motors);
        assert_eq!(motors.commands[1], 0.05);
        // The radio lost on the ground counts its failsafe too, and stops the test.
        control.command(ControlCommand::Land(LandReason::RcLost), 2_000);
        control.step(2_000, &mut imu, &mut motors);
        assert!(!control.armed());
        assert_eq!(motors.commands, vec![0.0; 4]);
        assert_eq!(control.snapshot().pilot.failsafes.rc_lost, 1);
        while consumer.pop().is_some() {}
    }

    /// The IMU offset configured (or calibrated) reaches the control step's compensation before
    /// any attempt, so that a throw's push, spinning the craft up, is compensated.
    #[test]
    fn the_configured_imu_offset_reaches_the_pilot_before_any_attempt() {
        let mut queue = SampleQueue::new();
        let (producer, consumer) = split_queue(&mut queue);
        let mut control = ControlLoop::new(ControlConfig::default(), producer);
        let mut fit_handoff = super::super::offset_fit::FitHandoff::new();
        let (fit_client, _fit_ends) = fit_handoff.split(2000.0);
        let mut background = super::super::background::Background::new(consumer, fit_client, 2000);
        assert!(control.receive(&background.results()));
        assert_eq!(control.state.pilot.imu_offset_m(), Some([0.0; 3]));
        let r_imu_m = [0.012, -0.03, 0.004];
        background.set_imu_offset(Some(r_imu_m));
        assert!(control.receive(&background.results()), "an offset alone is adopted");
        assert_eq!(control.state.pilot.imu_offset_m(), Some(r_imu_m));
        assert!(!control.receive(&background.results()), "and only once");
        background.set_imu_offset(None);
        assert!(control.receive(&background.results()));
        assert_eq!(control.state.pilot.imu_offset_m(), Some([0.0; 3]), "back to none known");
    }

    #[test]
    fn two_seconds_at_2khz_measure_2khz_with_no_late_steps() {
        let mut queue = SampleQueue::new();
        let (producer, mut consumer) = split_queue(&mut queue);
        let mut control = ControlLoop::new(ControlConfig::default(), producer);
        let mut imu = ScriptedImu { deliver: |_| true, calls: 0 };
        let mut motors = RecordingMotors { commands: vec![] };
        for step in 0..4001u64 {
            control.step(step * 500, &mut imu, &mut motors);
            while consumer.pop().is_some() {}
        }
        let snapshot = control.snapshot();
        assert_eq!(snapshot.steps, 4001);
        assert!((snapshot.rate_hz - 2000.0).abs() < 0.5, "{}", snapshot.rate_hz);
        assert_eq!(snapshot.late_steps, 0);
        assert_eq!(snapshot.max_interval_us, 500);
        assert_eq!(motors.commands, vec![0.0; 4], "disarmed: all four motors at zero");
        assert_eq!(snapshot.speeds_rad_s[3], Some(103.0));
        assert!(snapshot.imu_present);
    }

    /// Silent ESCs (no bidirectional DShot).
    struct SilentMotors;

    impl Motors for SilentMotors {
        fn count(&self) -> u8 {
            4
        }
        fn set_commands(&mut self, _commands: &[f32]) {}
        fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
            [None; MAX_MOTORS]
        }
    }

    /// Without speed reports arming is refused unless the user said the ESCs cannot report
    /// (`motor_bidir_dshot` = 0); then the attempt stays armed past the report timeout. With
    /// the parameter at its default (1) silent ESCs are refused.
    #[test]
    fn without_speed_reports_only_the_commands_only_identification_arms() {
        let mut params = super::super::params::Params::default();
        let reporting = ControlSettings::from(&params);
        assert!(!reporting.arm_without_speeds);
        params.set(super::super::params::Param::MotorBidirDshot as usize, &[0.0]).unwrap();
        let told = ControlSettings::from(&params);
        assert!(told.arm_without_speeds);
        for (settings, arms) in [
            (ControlSettings::default(), false),
            (reporting, false),
            (told, true),
            (ControlSettings { arm_without_speeds: true, ..told }, true),
        ] {
            let mut queue = SampleQueue::new();
            let (producer, _consumer) = split_queue(&mut queue);
            let mut control = ControlLoop::new(ControlConfig::default(), producer);
            let mut imu = ScriptedImu { deliver: |_| true, calls: 0 };
            control.command(ControlCommand::Configure(settings), 0);
            let timeout_us = u64::from(SPEED_REPORT_TIMEOUT_MS) * 1000;
            let mut t_us = 0;
            for _ in 0..10 {
                control.step(t_us, &mut imu, &mut SilentMotors);
                t_us += 500;
            }
            control.command(ControlCommand::ArmThrowToFly, t_us);
            while t_us < 3 * timeout_us {
                control.step(t_us, &mut imu, &mut SilentMotors);
                t_us += 500;
            }
            let snapshot = control.snapshot();
            assert_eq!(snapshot.armed, arms, "{settings:?}");
            let failure =
                if arms { LearnerFailure::None } else { LearnerFailure::NoSpeedTelemetry };
            assert_eq!(snapshot.failure, failure);
        }
    }

    #[test]
    fn a_late_step_and_missing_samples_are_counted() {
        let mut queue = SampleQueue::new();
        let (producer, _consumer) = split_queue(&mut queue);
        let mut control = ControlLoop::new(ControlConfig::default(), producer);
        // Every third read has no sample.
        let mut imu = ScriptedImu { deliver: |call| call % 3 != 0, calls: 0 };
        let times_us = [0, 500, 1000, 1800, 2300, 2800];
        for t in times_us {
            control.step(t, &mut imu, &mut NoMotors);
        }
        let snapshot = control.snapshot();
        assert_eq!(snapshot.late_steps, 1, "the 800 µs interval is late, 500 µs ones are not");
        assert_eq!(snapshot.max_interval_us, 800);
        assert_eq!(snapshot.imu_missing, 2);
        assert_eq!(snapshot.imu_samples, 4);
        assert_eq!(snapshot.motor_count, 0);
    }

    #[test]
    fn without_an_imu_the_loop_runs_and_reports_it_absent() {
        let mut queue = SampleQueue::new();
        let (producer, mut consumer) = split_queue(&mut queue);
        let mut control = ControlLoop::new(ControlConfig::default(), producer);
        let mut imu = ScriptedImu { deliver: |_| false, calls: 0 };
        let mut waiting = false;
        for step in 0..100u64 {
            waiting |= control.step(step * 500, &mut imu, &mut NoMotors);
        }
        assert!(!control.snapshot().imu_present);
        assert_eq!(control.snapshot().imu_missing, 100);
        assert!(!waiting && consumer.pop().is_none(), "nothing is queued without samples");
    }

    /// `ImuGuard::check` on a sample, disarmed and motors off: (verdict, stuck).
    fn check_disarmed(guard: &mut ImuGuard, sample: ImuSample) -> (ImuVerdict, bool) {
        guard.check(Some(sample), false, false, 0, 20_000)
    }

    #[test]
    fn a_gyro_axis_repeating_while_another_changes_counts_as_stuck_after_the_window() {
        let mut guard = ImuGuard::default();
        for i in 0..STUCK_GYRO_SAMPLES + 3 {
            let x = f32::from(i);
            let sample = ImuSample { gyro_rad_s: [0.25, x, 0.5], accel_mps2: [0.0, 0.0, -9.8] };
            let (verdict, stuck) = check_disarmed(&mut guard, sample);
            assert_eq!(stuck, i + 1 >= STUCK_GYRO_SAMPLES, "sample {i}");
            assert_eq!(verdict, ImuVerdict::Good(sample));
        }
        // Every axis constant (an ideal IMU at rest): no axis counts as stuck.
        let mut guard = ImuGuard::default();
        for _ in 0..2 * STUCK_GYRO_SAMPLES {
            let sample = ImuSample { gyro_rad_s: [0.0; 3], accel_mps2: [0.0, 0.0, -9.8] };
            assert_eq!(check_disarmed(&mut guard, sample), (ImuVerdict::Good(sample), false));
        }
        // An axis pinned at the ±2,000 °/s rail (a tumble faster than the sensor measures) while
        // another changes: saturated, not stuck, however long it lasts.
        let mut guard = ImuGuard::default();
        let rail_rad_s = 2000f32.to_radians();
        for i in 0..4 * STUCK_GYRO_SAMPLES {
            let x = f32::from(i) * 0.01;
            let sample =
                ImuSample { gyro_rad_s: [-rail_rad_s, x, -x], accel_mps2: [0.0, 0.0, -9.8] };
            assert_eq!(check_disarmed(&mut guard, sample), (ImuVerdict::Good(sample), false));
        }
    }

    #[test]
    fn armed_a_saturated_accelerometer_is_replaced_by_the_last_good_reading_until_the_timeout() {
        let mut guard = ImuGuard::default();
        let good = ImuSample { gyro_rad_s: [0.1, 0.2, 0.3], accel_mps2: [1.0, 2.0, -9.8] };
        assert_eq!(guard.check(Some(good), true, true, 0, 20_000).0, ImuVerdict::Good(good));
        let rail = ImuSample { gyro_rad_s: [0.4, 0.5, 0.6], accel_mps2: [1.0, -156.9, -9.8] };
        // Disarmed: left as read.
        assert_eq!(check_disarmed(&mut guard.clone(), rail).0, ImuVerdict::Good(rail));
        // Armed: the gyro as read, the accelerometer held, for 20 ms (the 40 steps at 0 to
        // 19.5 ms); the step at 20 ms fails.
        let held = ImuSample { accel_mps2: good.accel_mps2, ..rail };
        for step in 0..40u64 {
            let t_us = 500 + 500 * step;
            let (verdict, _) = guard.check(Some(rail), true, false, t_us, 20_000);
            assert_eq!(verdict, ImuVerdict::Held(held, ImuGlitch::AccelSaturated), "{t_us} µs");
        }
        let (verdict, _) = guard.check(Some(rail), true, false, 20_500, 20_000);
        assert_eq!(verdict, ImuVerdict::Failed(ImuGlitch::AccelSaturated));
        // A good sample ends the run: the next glitch has the whole timeout again.
        assert_eq!(guard.check(Some(good), true, false, 21_000, 20_000).0, ImuVerdict::Good(good));
        assert!(matches!(
            guard.check(Some(rail), true, false, 40_000, 20_000).0,
            ImuVerdict::Held(..)
        ));
    }

    #[test]
    fn armed_missing_non_finite_and_frozen_samples_are_held_disarmed_they_are_not_used() {
        let good = ImuSample { gyro_rad_s: [0.1, 0.2, 0.3], accel_mps2: [1.0, 2.0, -9.8] };
        let nan = ImuSample { gyro_rad_s: [f32::NAN; 3], accel_mps2: [f32::NAN; 3] };
        for (raw, glitch) in [(None, ImuGlitch::Missing), (Some(nan), ImuGlitch::NonFinite)] {
            let mut guard = ImuGuard::default();
            assert_eq!(guard.check(Some(good), true, false, 0, 20_000).0, ImuVerdict::Good(good));
            assert_eq!(
                guard.check(raw, true, false, 500, 20_000).0,
                ImuVerdict::Held(good, glitch)
            );
            assert_eq!(
                guard.check(raw, true, false, 20_000, 20_000).0,
                ImuVerdict::Held(good, glitch)
            );
            assert_eq!(guard.check(raw, true, false, 20_500, 20_000).0, ImuVerdict::Failed(glitch));
            assert_eq!(guard.check(raw, false, false, 21_000, 20_000).0, ImuVerdict::Unused);
            // A timeout of 0: the first bad sample fails; nothing good to hold: fails too.
            assert_eq!(guard.check(raw, true, false, 22_000, 0).0, ImuVerdict::Failed(glitch));
            assert_eq!(
                ImuGuard::default().check(raw, true, false, 0, 20_000).0,
                ImuVerdict::Failed(glitch)
            );
        }
        // Frozen: all six values repeated while the motors spin; the same repeat with the
        // motors off (a still craft, an ideal sensor) is a good sample.
        let mut guard = ImuGuard::default();
        assert_eq!(guard.check(Some(good), true, true, 0, 20_000).0, ImuVerdict::Good(good));
        assert_eq!(guard.check(Some(good), true, false, 500, 20_000).0, ImuVerdict::Good(good));
        let (verdict, _) = guard.check(Some(good), true, true, 1000, 20_000);
        assert_eq!(verdict, ImuVerdict::Held(good, ImuGlitch::Frozen));
        let moved = ImuSample { gyro_rad_s: [0.1, 0.2, 0.30001], ..good };
        assert_eq!(guard.check(Some(moved), true, true, 1500, 20_000).0, ImuVerdict::Good(moved));
    }

    #[test]
    fn a_motor_counts_as_silent_after_the_report_timeout_from_its_last_report_or_the_arming() {
        let mut monitor = SpeedMonitor::default();
        let timeout_us = u64::from(SPEED_REPORT_TIMEOUT_MS) * 1000;
        assert_eq!(monitor.silent(4, timeout_us, 0), 0, "a motor gets the timeout from 0");
        assert_eq!(monitor.silent(4, timeout_us + 1, 0), 0b1111);
        let mut speeds = [None; MAX_MOTORS];
        speeds[..3].copy_from_slice(&[Some(0.0), Some(100.0), Some(f32::NAN)]);
        monitor.observe(&speeds, 1_000_000);
        let later = 1_000_000 + timeout_us;
        assert_eq!(monitor.silent(4, later, 0), 0b1100, "NaN and None are no report");
        assert_eq!(monitor.silent(4, later + 1, 0), 0b1111);
        assert_eq!(monitor.silent(4, later + 1, later), 0, "armed at `later`: the timeout again");
        assert_eq!(motor_mask(4), 0b1111);
        assert_eq!(motor_mask(8), 0xFF);
    }

    #[test]
    fn non_finite_imu_samples_are_treated_as_missing() {
        struct NanImu;
        impl Imu for NanImu {
            fn read(&mut self) -> Option<ImuSample> {
                Some(ImuSample { gyro_rad_s: [f32::NAN, 0.0, 0.0], accel_mps2: [0.0; 3] })
            }
        }
        let mut queue = SampleQueue::new();
        let (producer, mut consumer) = split_queue(&mut queue);
        let mut control = ControlLoop::new(ControlConfig::default(), producer);
        control.step(0, &mut NanImu, &mut NoMotors);
        assert_eq!(control.snapshot().imu_missing, 1);
        assert!(consumer.pop().is_none());
    }

    /// A magnetic sample reaches the pilot with its time; one with a NaN, or no noise, changes
    /// nothing; a disarm forgets it.
    #[test]
    fn a_magnetic_sample_reaches_the_pilot_and_a_bad_one_changes_nothing() {
        use super::super::compass::MagneticSample;
        let mut queue = SampleQueue::new();
        let (producer, _consumer) = split_queue(&mut queue);
        let mut control = ControlLoop::new(ControlConfig::default(), producer);
        let good = MagneticSample { field_imu_ut: [20.0, -3.0, 44.0], noise_ut: 0.6 };
        control.command(ControlCommand::MagneticField(good), 1_000);
        assert_eq!(control.state.pilot.latest_magnetic_field(), Some((good, 1_000)));
        let nan = MagneticSample { field_imu_ut: [f32::NAN, 0.0, 0.0], noise_ut: 0.6 };
        control.command(ControlCommand::MagneticField(nan), 2_000);
        let silent = MagneticSample { noise_ut: 0.0, ..good };
        control.command(ControlCommand::MagneticField(silent), 3_000);
        assert_eq!(control.state.pilot.latest_magnetic_field(), Some((good, 1_000)));
        control.command(ControlCommand::Disarm, 4_000);
        assert_eq!(control.state.pilot.latest_magnetic_field(), None);
    }
}
