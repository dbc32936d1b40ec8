//! In-flight identification of an unknown multirotor: throw-to-arm, motor excitation, recursive
//! least squares of the motor models and of the effectiveness, and the hover thrust axis from
//! what was learned (seed paper §3.1, §3.3; docs/algorithms/learner.md).
//!
//! Two halves, split the way the firmware's tasks are:
//! - [`ThrowToFly`] runs in the 2 kHz control step: [`throw_detector`] decides that the craft has
//!   been thrown and is falling freely, then [`excitation`] pulses each motor in turn. A few dozen
//!   operations per step.
//! - [`Learner`] runs in the background task on every sample of the excitation (its filters
//!   primed on the free fall of the release delay before it, [`Learner::prime`]):
//!   [`motor_model`] per motor, [`effectiveness`] (G1, G2) and, once every motor has been pulsed,
//!   the [`crate::thrust_axis`] solver on the learned G1. It publishes a [`LearnedModel`]: the
//!   interface the controller (INDI) builds on. Every sample runs the motor models and the
//!   filters but only one of the six effectiveness regressions, and the publication is split
//!   over two samples ([`Learner::update`]), so that the worst sample stays within the
//!   background task's budget on the Cortex-M7 (docs/benchmarks.md, issue 7).
//!
//! Units of the learned effectiveness: G1 is kept per unit *squared motor speed* (m/s² or rad/s²
//! per (rad/s)²), which is what the physics says and what the regression sees. Per unit of
//! normalised thrust `u = ω²/ω_full²` (the convention of the papers and of the thrust-axis
//! problem, `u ∈ [0, 1]`), G1 is scaled by each motor's `ω_full²` from its learned model:
//! [`LearnedModel::g1_per_unit_thrust`].
//!
//! Time alignment: a motor's reported speed is paired with the command that
//! was driving it when the speed was measured, [`LearnerConfig::command_to_speed_delay_half_steps`]
//! half control steps earlier (one step of output latency, the telemetry's age, and the half
//! step by which a held command lags its samples).

pub mod effectiveness;
pub mod excitation;
pub mod inertia;
pub mod motor_model;
pub mod no_speed;
pub mod rls;
pub mod throw_detector;

use crate::filters::{BiquadCoefficients, FilterDesignError};
use crate::thrust_axis::{self, HoverProblem, ThrustAxisSolver};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use effectiveness::{EffectivenessEstimator, EffectivenessSetup, Regression};
use excitation::{Excitation, ExcitationConfig};
use motor_model::{MotorModel, MotorModelEstimator};
use no_speed::CommandSpeedModel;
use rls::RlsConfig;
use throw_detector::{ThrowConfig, ThrowDetector, ThrowEvent, ThrowState};

/// Most motors the learner handles.
pub const MAX_MOTORS: usize = 8;
/// Fewest motors the learner handles (three torque equations need at least four).
pub const MIN_MOTORS: usize = 4;

/// Low-pass cut-off of the effectiveness signals, Hz (published, docs/algorithms/learner.md).
pub const EFFECTIVENESS_CUTOFF_HZ: f32 = 20.0;
/// Low-pass cut-off of the motor-model signals, Hz (published, docs/algorithms/learner.md).
pub const MOTOR_MODEL_CUTOFF_HZ: f32 = 40.0;
/// Information needed before a motor's G1 column is used in the thrust-axis problem: its
/// covariance diagonal below this fraction of the prior (roughly: the pulse has begun and the
/// motor's speed has changed by a few hundred rad/s).
pub const AXIS_INFORMATION_FRACTION: f32 = 0.05;
/// Relative one-sigma uncertainty of a G1 column below which it counts as converged.
pub const G1_CONVERGED_RELATIVE_STD: f32 = 0.02;

/// A reported speed above which a motor counts as running (armed ESC), rad/s: far below any
/// idle speed (300 rad/s on a 3-inch quad), far above DShot's speed resolution at standstill.
pub const RUNNING_SPEED_RAD_S: f32 = 50.0;

/// The thrust-axis solver as the learner calls it, once per sample: the heuristic only. The
/// exhaustive bounded search costs up to about 1.1 million Cortex-M7 instructions at m = 8
/// (docs/benchmarks.md), far beyond one 2 kHz period of the background task, and a craft whose
/// most efficient hover needs a motor at a bound is reported as `NoHover` instead, with the axis
/// of its `u*` clamped to the bounds as the last resort (`clamp_outside_bounds`,
/// [`LearnedThrustAxis::clamped_by`]).
pub const SOLVER_CONFIG: thrust_axis::SolverConfig = thrust_axis::SolverConfig {
    max_squarings: 6,
    bounded_search: false,
    clamp_outside_bounds: true,
};

/// How the learner is set up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LearnerConfig {
    /// Sample (control) rate, Hz.
    pub rate_hz: f32,
    /// IMU position relative to the centre of gravity, IMU axes, m.
    pub r_imu_m: [f32; 3],
    /// Delay from a command to the speed report it explains, in half control steps (output +
    /// telemetry delay + the half step by which a zero-order-held command lags its samples).
    /// Default 3: the command is sent one step before it acts, the speed report is one step
    /// old, and the held command's centre is half a step earlier (odd values average two
    /// consecutive commands).
    pub command_to_speed_delay_half_steps: u8,
    /// How much older the motor-speed reports are than the IMU sample of the same step, s. The
    /// simulated board (and the H743 with its 8 kHz IMU and DShot telemetry) delivers the mean
    /// of four 8 kHz IMU samples, centred 187.5 µs before the step, and speeds one 500 µs step
    /// old: 312.5 µs.
    pub speed_report_lag_s: f32,
    /// Effectiveness RLS tuning.
    pub effectiveness_rls: RlsConfig,
    /// Motor-model RLS tuning.
    pub motor_rls: RlsConfig,
    /// Whether the ESCs report their speeds (bidirectional DShot). Without, every motor's speed
    /// is modelled from its commands and the lag identified from the body's angular response
    /// (`no_speed`); the motor models are then the nominal curve with that lag.
    pub speed_telemetry: bool,
}

/// Age of a motor-speed report when the control step reads it, s, by default: one 2 kHz step
/// (a bidirectional-DShot answer arrives within the period of the frame that asked for it,
/// and the simulated board reports speeds one step old).
pub const DEFAULT_SPEED_AGE_S: f32 = 0.0005;

/// The age the learner takes for speeds modelled from the commands (no speed telemetry,
/// `no_speed`), s: no report has an age then, and `motor_speed_age_s` (set for ESCs that do
/// report) must not move the alignment. The default's, with which every no-speed figure was
/// measured; the alignment at the IMU sample's own time (`IMU_GROUP_DELAY_S`: two half steps,
/// no report lag) flew the same 1,000 random worlds within one world of it (985 against 986
/// hovered, `fly monte-carlo --no-speed-telemetry --unknown-imu-offset`, 2026-11-29). Taking
/// the user's age instead (0.5–3 ms in the random world) had lost 7 (docs/benchmarks.md).
pub const MODELLED_SPEED_AGE_S: f32 = DEFAULT_SPEED_AGE_S;

/// Largest speed-report age the learner can align, s: 6 control steps (the command history it
/// keeps, 13 half steps).
pub const MAX_SPEED_AGE_S: f32 = 0.003;

/// Group delay of the IMU sample the control step reads, s: the mean of four 8 kHz samples,
/// centred 187.5 µs before the step.
pub const IMU_GROUP_DELAY_S: f32 = 187.5e-6;

impl LearnerConfig {
    /// The time alignment for speed reports `speed_age_s` old (clamped to
    /// [0, `MAX_SPEED_AGE_S`]) at `rate_hz`: a command acts one step after it is computed and
    /// is held for a step (its centre half a step later), so it explains the speed reported
    /// `1 + 2 · age / step` half steps later; the report is `age − IMU_GROUP_DELAY_S` older
    /// than the IMU sample of its step. A non-finite age is taken as the default. Without
    /// speed telemetry no report has an age: the modelled speeds are aligned by
    /// [`MODELLED_SPEED_AGE_S`] whatever `speed_age_s` says.
    pub fn with_speed_age(self, speed_age_s: f32) -> Self {
        let age = if !self.speed_telemetry {
            MODELLED_SPEED_AGE_S
        } else if speed_age_s.is_finite() {
            speed_age_s
        } else {
            DEFAULT_SPEED_AGE_S
        };
        let age = crate::math::clamp(age, 0.0, MAX_SPEED_AGE_S);
        let half_steps = libm::roundf(1.0 + 2.0 * age * self.rate_hz);
        Self {
            command_to_speed_delay_half_steps: crate::math::clamp(half_steps, 1.0, 13.0) as u8,
            speed_report_lag_s: age - IMU_GROUP_DELAY_S,
            ..self
        }
    }
}

impl Default for LearnerConfig {
    fn default() -> Self {
        Self {
            rate_hz: 2000.0,
            r_imu_m: [0.0; 3],
            command_to_speed_delay_half_steps: 3,
            speed_report_lag_s: DEFAULT_SPEED_AGE_S - IMU_GROUP_DELAY_S,
            effectiveness_rls: RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 },
            motor_rls: RlsConfig { lambda: 1.0, p0: 1e4, p_max: 1e8 },
            speed_telemetry: true,
        }
    }
}

/// Why a learner could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LearnerError {
    /// The motor count is outside 4..=8.
    MotorCount { motors: usize },
    /// The rate does not allow the filters' cut-offs.
    Filter(FilterDesignError),
    /// The IMU offset is not finite or larger than 1 m.
    ImuOffset,
}

/// The hover thrust axis found from the learned G1.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LearnedThrustAxis {
    /// `q_U^T`: thrust-frame coordinates into IMU coordinates, `[w, x, y, z]`.
    pub q_thrust_to_imu: [f32; 4],
    /// Unit thrust direction, IMU axes.
    pub thrust_dir_imu: [f32; 3],
    /// Hover command per motor, normalised thrust u.
    pub u_hover: [f32; MAX_MOTORS],
    /// ZYX Euler angles of `q_U^T`: roll, pitch, yaw, rad.
    pub euler_zyx_rad: [f32; 3],
    /// 0 when `u_hover` is a hover of the model within the motor bounds. Otherwise the last
    /// resort of a model whose hover leaves the bounds, its `u*` clamped to them, kept only while
    /// no hover within them was found: how far `u*` was outside, normalised thrust
    /// (`thrust_axis::HoverSolution::clamped_by`).
    pub clamped_by: f32,
}

impl LearnedThrustAxis {
    /// Whether `u_hover` is a hover of the model within the motor bounds.
    pub fn within_bounds(&self) -> bool {
        self.clamped_by == 0.0
    }

    /// `q_U^T` as a rotation (thrust-frame coordinates into IMU coordinates), normalised; `None`
    /// when a component is not finite.
    pub fn rotation_thrust_to_imu(&self) -> Option<nalgebra::UnitQuaternion<f32>> {
        let [w, x, y, z] = self.q_thrust_to_imu;
        [w, x, y, z].iter().all(|v| v.is_finite()).then(|| {
            nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
        })
    }
}

/// Why the thrust axis is not (yet) known.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum AxisStatus {
    /// Not every motor has been excited enough yet.
    #[default]
    Waiting,
    /// Found.
    Found,
    /// G1τ is rank deficient: the motors cannot produce every torque.
    RankDeficient,
    /// No hover within the motor bounds along any axis (the model's thrust axis, if any, is then
    /// an earlier hover within them or the clamped last resort: [`LearnedThrustAxis::clamped_by`]).
    NoHover,
}

/// Everything learned so far: the interface to the controller.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LearnedModel {
    /// Motors identified.
    pub motors: u8,
    /// G1 per unit squared speed: rows 0–2 specific force (m/s²), rows 3–5 angular acceleration
    /// (rad/s²), per (rad/s)², IMU axes; columns are motors.
    pub g1_per_speed2: [[f32; MAX_MOTORS]; 6],
    /// G2: angular acceleration per motor acceleration, rad/s² per rad/s², IMU axes.
    pub g2: [[f32; MAX_MOTORS]; 3],
    /// The motor models.
    pub motor: [MotorModel; MAX_MOTORS],
    /// Bit i: G1 column i has converged (relative σ below [`G1_CONVERGED_RELATIVE_STD`]).
    pub g1_converged: u8,
    /// Bit i: motor i's model has converged.
    pub motors_converged: u8,
    /// The thrust axis, when found: the latest solution within the motor bounds. It stays when
    /// a later model's hover leaves the bounds (`axis_status` then `NoHover`), so the caller
    /// can tell a hover lost at the end of an excitation from one never found (`None`).
    pub thrust_axis: Option<LearnedThrustAxis>,
    /// Where the thrust-axis solution stands.
    pub axis_status: AxisStatus,
    /// Samples learned from.
    pub samples: u32,
    /// Whether the motor speeds were modelled from the commands (no speed telemetry,
    /// `no_speed`) rather than reported by the ESCs: which path identified this model.
    pub speeds_modelled: bool,
    /// Whether G1 has yet to learn from samples of the excitation already taken: without speed
    /// telemetry the effectiveness regression learns from the excitation's samples once the
    /// lag is identified at its end, a few per control sample
    /// (`no_speed::RELEASE_PER_SAMPLE`), so for up to about a tenth of a second after it this
    /// model is not the one to engage on. Always false with speed telemetry.
    pub pending: bool,
}

impl LearnedModel {
    /// G1 per unit normalised thrust `u = ω²/ω_full²`: column i scaled by motor i's `ω_full²`.
    pub fn g1_per_unit_thrust(&self) -> [[f32; MAX_MOTORS]; 6] {
        let mut g1 = self.g1_per_speed2;
        for i in 0..usize::from(self.motors).min(MAX_MOTORS) {
            let full = self.motor[i].omega_full_rad_s();
            for row in g1.iter_mut() {
                row[i] *= full * full;
            }
        }
        g1
    }

    /// How much of the attempt this model learned from, s, at the control rate `rate_hz`: its
    /// samples, each a control period, or each a held sample's interval when the speeds were
    /// modelled ([`no_speed::held_rate_hz`]).
    pub fn learned_s(&self, rate_hz: f32) -> f32 {
        let sample_rate_hz =
            if self.speeds_modelled { no_speed::held_rate_hz(rate_hz) } else { rate_hz };
        if sample_rate_hz > 0.0 {
            self.samples as f32 / sample_rate_hz
        } else {
            0.0
        }
    }

    /// Largest time constant of the motors, s (0 before any is known).
    pub fn tau_max_s(&self) -> f32 {
        self.motor[..usize::from(self.motors).min(MAX_MOTORS)]
            .iter()
            .map(|m| m.tau_s)
            .fold(0.0, f32::max)
    }
}

/// Storage for a [`Learner`] built in place ([`Learner::build_in`]): empty until the first
/// build, rebuilt in place for another motor count.
pub type LearnerSlot = crate::slot::Slot<Learner>;

impl LearnerSlot {
    /// Build a learner for `motors` motors in place, replacing any earlier one.
    pub fn build(
        &mut self,
        motors: usize,
        config: LearnerConfig,
    ) -> Result<&mut Learner, LearnerError> {
        self.build_with(|slot| Learner::build_in(slot, motors, config))
    }
}

/// The background half: every estimator of the identification.
#[derive(Clone, Debug)]
pub struct Learner {
    config: LearnerConfig,
    motors: usize,
    motor_models: [MotorModelEstimator; MAX_MOTORS],
    effectiveness: EffectivenessEstimator,
    /// Without speed telemetry: the lag and the modelled speeds (`no_speed`).
    command_speeds: CommandSpeedModel,
    /// The held samples learned from in the latest [`Learner::update_carrying`], oldest first,
    /// with their modelled speeds ([`Learner::for_each_released`]).
    released: [no_speed::ReleasedSample; no_speed::RELEASE_PER_SAMPLE],
    released_len: usize,
    solver: ThrustAxisSolver,
    /// The last commands, for the time alignment: a ring, the newest at `newest_command`.
    commands: [[f32; MAX_MOTORS]; 8],
    newest_command: usize,
    /// Whether the ESCs run the motors: since the first non-zero command of the attempt, or
    /// since a motor reported a running speed.
    armed: bool,
    /// Samples since the model was last published.
    since_publish: u8,
    /// Samples learned from.
    samples: u32,
    /// The model being published (see [`Learner::update`]).
    staging: LearnedModel,
    /// `Some(every G1 column informed)` once the first half of a publication is done.
    staged: Option<bool>,
    /// Without speed telemetry, once the catch-up's last held sample has been learned from:
    /// the force rows in effect then ([`Self::force_rows`]) for the model to engage on, which
    /// the next sample stages (unless that sample's force row x did) and publishes with its
    /// thrust axis, learning nothing beside ([`Learner::update_carrying`]).
    caught_up: Option<Option<[[f32; MAX_MOTORS]; 3]>>,
    model: LearnedModel,
    /// The specific-force rows of G1 (per unit squared speed) fitted elsewhere, published and
    /// solved for the thrust axis in place of the learner's own ([`Learner::set_force_rows`]).
    force_rows: Option<[[f32; MAX_MOTORS]; 3]>,
    /// Force rows to try the thrust axis on while the learner's own have found no hover
    /// ([`Learner::set_fallback_force_rows`]).
    fallback_rows: Option<[[f32; MAX_MOTORS]; 3]>,
    /// The last publication found no hover on the learner's own rows and none was found
    /// before: the next sample that neither publishes nor stages solves on
    /// [`Self::fallback_rows`].
    fallback_pending: bool,
    /// The solver for [`Self::fallback_rows`]: its own warm start, so that rows estimated
    /// another way (early, they may be far off) never steer the power iteration on the
    /// learner's own.
    fallback_solver: ThrustAxisSolver,
}

impl Learner {
    /// A learner for `motors` motors.
    pub fn new(motors: usize, config: LearnerConfig) -> Result<Self, LearnerError> {
        let mut slot = MaybeUninit::uninit();
        Self::build_in(&mut slot, motors, config)?;
        // SAFETY: `build_in` returned `Ok`: every field is written.
        Ok(unsafe { slot.assume_init() })
    }

    /// Build a learner for `motors` motors in `slot`, field by field, its effectiveness
    /// estimator and covariances too: the 25 KB learner is never a temporary on the stack. On
    /// the board the background task builds it at the first excitation,
    /// and a by-value construction took 75–100 KB of stack there, more than the task's share
    /// (docs/budget.md). On `Err` the slot is left uninitialised.
    pub fn build_in(
        slot: &mut MaybeUninit<Self>,
        motors: usize,
        config: LearnerConfig,
    ) -> Result<&mut Self, LearnerError> {
        if !(MIN_MOTORS..=MAX_MOTORS).contains(&motors) {
            return Err(LearnerError::MotorCount { motors });
        }
        check_offset(config.r_imu_m)?;
        // Without speed telemetry the effectiveness regression learns from the held samples,
        // the means over `no_speed::HOLD_INTERVAL_S`, at their rate.
        let effectiveness_rate_hz = if config.speed_telemetry {
            config.rate_hz
        } else {
            no_speed::held_rate_hz(config.rate_hz)
        };
        let slow =
            BiquadCoefficients::butterworth_lowpass(EFFECTIVENESS_CUTOFF_HZ, effectiveness_rate_hz)
                .map_err(LearnerError::Filter)?;
        let fast = BiquadCoefficients::butterworth_lowpass(MOTOR_MODEL_CUTOFF_HZ, config.rate_hz)
            .map_err(LearnerError::Filter)?;
        let motor = MotorModelEstimator::new(fast, config.rate_hz, config.motor_rls);
        let lag_lowpass = BiquadCoefficients::butterworth_lowpass(
            no_speed::LAG_LOWPASS_HZ,
            no_speed::regression_rate_hz(config.rate_hz),
        )
        .map_err(LearnerError::Filter)?;
        let empty = LearnedModel {
            motors: motors as u8,
            speeds_modelled: !config.speed_telemetry,
            pending: !config.speed_telemetry,
            ..LearnedModel::default()
        };
        let learner = slot.as_mut_ptr();
        // SAFETY: each field of the slot is written exactly once, through raw field pointers
        // (no reference to the uninitialised whole), before the reference is formed.
        unsafe {
            addr_of_mut!((*learner).config).write(config);
            addr_of_mut!((*learner).motors).write(motors);
            let models = addr_of_mut!((*learner).motor_models).cast::<MotorModelEstimator>();
            for i in 0..MAX_MOTORS {
                models.add(i).write(motor.clone());
            }
            EffectivenessEstimator::build_at(
                addr_of_mut!((*learner).effectiveness),
                EffectivenessSetup {
                    motors,
                    rate_hz: effectiveness_rate_hz,
                    filter: slow,
                    r_imu_m: config.r_imu_m,
                    speed_lag_s: config.speed_report_lag_s,
                    rls: config.effectiveness_rls,
                },
            );
            CommandSpeedModel::build_at(
                addr_of_mut!((*learner).command_speeds),
                motors,
                config.rate_hz,
                lag_lowpass,
            );
            addr_of_mut!((*learner).solver).write(ThrustAxisSolver::new(SOLVER_CONFIG));
            addr_of_mut!((*learner).commands).write([[0.0; MAX_MOTORS]; 8]);
            // Zero bytes are valid released samples (plain numbers).
            addr_of_mut!((*learner).released).write_bytes(0, 1);
            addr_of_mut!((*learner).released_len).write(0);
            addr_of_mut!((*learner).newest_command).write(0);
            addr_of_mut!((*learner).armed).write(false);
            addr_of_mut!((*learner).since_publish).write(0);
            addr_of_mut!((*learner).samples).write(0);
            addr_of_mut!((*learner).staging).write(empty);
            addr_of_mut!((*learner).staged).write(None);
            addr_of_mut!((*learner).caught_up).write(None);
            addr_of_mut!((*learner).model).write(empty);
            addr_of_mut!((*learner).force_rows).write(None);
            addr_of_mut!((*learner).fallback_rows).write(None);
            addr_of_mut!((*learner).fallback_pending).write(false);
            addr_of_mut!((*learner).fallback_solver).write(ThrustAxisSolver::new(SOLVER_CONFIG));
            Ok(slot.assume_init_mut())
        }
    }

    /// Start a new identification with the IMU offset `r_imu_m` (IMU axes, m).
    pub fn restart(&mut self, r_imu_m: [f32; 3]) -> Result<(), LearnerError> {
        check_offset(r_imu_m)?;
        self.config.r_imu_m = r_imu_m;
        for m in &mut self.motor_models {
            m.reset();
        }
        self.effectiveness.reset(r_imu_m);
        self.command_speeds.reset();
        self.released_len = 0;
        self.solver.reset();
        self.fallback_solver.reset();
        self.commands = [[0.0; MAX_MOTORS]; 8];
        self.newest_command = 0;
        self.armed = false;
        self.since_publish = 0;
        self.model = LearnedModel {
            motors: self.motors as u8,
            speeds_modelled: !self.config.speed_telemetry,
            pending: !self.config.speed_telemetry,
            ..LearnedModel::default()
        };
        self.samples = 0;
        self.staging = self.model;
        self.staged = None;
        self.caught_up = None;
        self.force_rows = None;
        self.fallback_rows = None;
        self.fallback_pending = false;
        Ok(())
    }

    /// Publish `g1f_per_speed2` (the specific-force rows of G1, m/s² per (rad/s)², IMU axes,
    /// columns are motors) instead of the learner's own from the next publication on, and solve
    /// the thrust axis with them; `None` goes back to the learner's own. For rows fitted with
    /// the IMU offset in flight (`imu_offset::in_flight`): the learner's, learned with the
    /// offset of the attempt's start, are off by `[r − r₀]× G1τ`. Until the next
    /// [`Learner::restart`]. Rows with a non-finite entry are refused (`false`).
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn set_force_rows(&mut self, g1f_per_speed2: Option<[[f32; MAX_MOTORS]; 3]>) -> bool {
        let finite = all_finite(&g1f_per_speed2);
        if finite {
            self.force_rows = g1f_per_speed2;
        }
        finite
    }

    /// Force rows (as [`Learner::set_force_rows`]'s) for the thrust axis while the learner's own
    /// have found no hover within the motor bounds in this identification: each publication
    /// whose own rows find none (and none was found before) is followed, a sample later, by a
    /// solve on these with its torque rows, published with them when it finds a hover. From
    /// then on the learner's own rows are solved again, and the axis is kept while they find
    /// none (as any earlier axis is). A craft with no axis at the excitation's end is refused
    /// and falls from its apex; rows estimated another way give it a second chance without
    /// taking the learner's own a single one. For the rows fitted with the IMU offset in flight
    /// (`imu_offset::in_flight`) when no offset is known: the learner's own then carry what
    /// the tumble's rotation does at the IMU, which no motor explains. Until the next
    /// [`Learner::restart`]. Rows with a non-finite entry are refused (`false`).
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn set_fallback_force_rows(
        &mut self,
        g1f_per_speed2: Option<[[f32; MAX_MOTORS]; 3]>,
    ) -> bool {
        let finite = all_finite(&g1f_per_speed2);
        if finite {
            self.fallback_rows = g1f_per_speed2;
        }
        finite
    }

    /// Replace the prior of the body's normalised inertia (right after [`Learner::restart`]),
    /// e.g. by the free tumble's (`tumble::TumbleInertia::prior`, in its own crate).
    pub fn set_inertia_prior(&mut self, prior: &inertia::InertiaPrior) {
        self.effectiveness.set_inertia_prior(prior);
    }

    /// The body's normalised inertia `J = I / tr I` the angular-momentum balance holds now,
    /// IMU axes (row-major).
    pub fn normalised_inertia(&self) -> [[f32; 3]; 3] {
        let j = self.effectiveness.normalised_inertia();
        core::array::from_fn(|r| core::array::from_fn(|c| j[(r, c)]))
    }

    /// The configuration in use.
    pub fn config(&self) -> &LearnerConfig {
        &self.config
    }

    /// One control-rate sample: IMU (IMU axes), the commands applied in this step and the motor
    /// speeds reported in it (rad/s; NaN where a motor did not report).
    ///
    /// The [`LearnedModel`] is published once per cycle of the six effectiveness regressions
    /// ([`effectiveness::EffectivenessEstimator::cycle_samples`]: twelve samples at the 2 kHz
    /// control rate, six held samples without speed telemetry), and as often while the
    /// regressions do not run (filters starting, gaps), so [`Learner::model`] may be up to a
    /// cycle behind. While they run, in two halves that share a sample with the cheaper force
    /// rows' turns, never with the balance's: the last sample of force row x's turn stages the
    /// model (the copy of G1, G2 and the motor models, the convergence statistics), the last of
    /// force row y's solves the thrust axis of the staged G1 and publishes the whole at once. No
    /// sample pays for the copy, the statistics and the solve together, nor for either beside
    /// half a balance row (docs/budget.md, issue 56).
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        commands: &[f32; MAX_MOTORS],
        speeds_rad_s: &[f32; MAX_MOTORS],
    ) {
        self.update_carrying(gyro_rad_s, accel_mps2, commands, speeds_rad_s, [0.0; 3]);
    }

    /// [`Learner::update`], with `carried` held beside the sample without speed telemetry and
    /// handed back with it when it is learned from ([`Learner::for_each_released`]): the
    /// caller's own data of that instant (the background task's velocity, for the in-flight
    /// IMU-offset fit).
    pub fn update_carrying(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        commands: &[f32; MAX_MOTORS],
        speeds_rad_s: &[f32; MAX_MOTORS],
        carried: [f32; 3],
    ) {
        let ring = self.commands.len();
        self.newest_command = (self.newest_command + 1) % ring;
        self.commands[self.newest_command] = *commands;
        let half_steps = usize::from(self.config.command_to_speed_delay_half_steps).min(13);
        let back = |steps: usize| &self.commands[(self.newest_command + ring - steps) % ring];
        let (early, late) = (back(half_steps / 2), back(half_steps.div_ceil(2)));
        let driving: [f32; MAX_MOTORS] = core::array::from_fn(|i| 0.5 * (early[i] + late[i]));
        let m = self.motors;
        self.armed |= driving[..m].iter().any(|&d| d > 0.0)
            || speeds_rad_s[..m].iter().any(|&s| s > RUNNING_SPEED_RAD_S);
        if !self.config.speed_telemetry {
            // The lag regression now; the effectiveness regression on the held samples (the
            // means over `no_speed::HOLD_INTERVAL_S`), with speeds modelled with the lag
            // identified since (`no_speed::CommandSpeedModel::hold`). At most
            // `RELEASE_PER_SAMPLE` a sample: the catch-up after the excitation is spread over
            // the samples that follow it (the model says `pending` until done).
            let choosing = !self.command_speeds.chosen();
            self.command_speeds.update(gyro_rad_s, accel_mps2, &driving, self.armed, true);
            self.command_speeds.hold(gyro_rad_s, accel_mps2, &driving, self.armed, carried);
            self.released_len = 0;
            if let Some(rows) = self.caught_up.take() {
                // Caught up on the last sample: the model to engage on, staged and published
                // with its thrust axis. Nothing is learned beside it (a held sample completed
                // now waits for the next sample), so the estimates are the ones the last held
                // sample left (its row's update finished first), and the force rows are the
                // ones in effect then.
                self.effectiveness.finish_pending();
                if self.staged.is_none() {
                    let own = core::mem::replace(&mut self.force_rows, rows);
                    self.stage();
                    self.force_rows = own;
                }
                self.staging.pending = false;
                self.publish_staged();
                return;
            }
            let pending = self.model.pending;
            // The sample that chose the lag spent its share on the regressions
            // (`no_speed::SCORING_WORK_PER_MOTOR`): the catch-up starts with the next.
            let release = if choosing && self.command_speeds.chosen() {
                0
            } else {
                no_speed::RELEASE_PER_SAMPLE
            };
            // Whether the last sample learned from staged the model (its force row x).
            let mut staged_now = false;
            for _ in 0..release {
                let Some(held) = self.command_speeds.release() else { break };
                staged_now = self.learn(held.gyro_rad_s, held.accel_mps2, &held.speeds_rad_s);
                if pending {
                    // Catching up, a row a sample: its update finished in its own sample, as
                    // spreading it would only move its work into the next row's (or into the
                    // sample that publishes the model to engage on, after the last).
                    self.effectiveness.finish_pending();
                }
                self.released[self.released_len] = held;
                self.released_len += 1;
            }
            if self.released_len == 0 {
                // The row the last held sample began goes on in the samples between.
                self.effectiveness.advance();
            }
            if pending && !self.command_speeds.pending() {
                // Caught up: the model to engage on, staged and published with its thrust axis
                // on the next sample (already staged when the last held sample's force row x
                // did it, from the same estimates). This sample's regression, a staging and a
                // solve together (until 2026-12-04, the staging twice after a force row x) were
                // the catch-up's most expensive sample (docs/budget.md).
                if !staged_now {
                    self.staged = None;
                }
                self.caught_up = Some(self.force_rows);
            }
            return;
        }
        if self.config.speed_telemetry {
            for i in 0..m {
                self.motor_models[i].update(driving[i], self.armed, speeds_rad_s[i]);
            }
        }
        self.learn(gyro_rad_s, accel_mps2, speeds_rad_s);
    }

    /// The effectiveness regression on one sample, and the publication; whether the model was
    /// staged last, from the estimates this sample left (its force row x: the publication's
    /// first half, [`Learner::update`]).
    #[inline(always)]
    fn learn(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds_rad_s: &[f32; MAX_MOTORS],
    ) -> bool {
        let regression =
            self.effectiveness.update(gyro_rad_s, accel_mps2, &speeds_rad_s[..self.motors]);
        self.samples = self.samples.saturating_add(1);
        self.since_publish = self.since_publish.saturating_add(1);
        // Whether this sample already ran the thrust-axis solve its budget allows.
        let solved = match regression {
            Regression::ForceRow(0) => {
                self.stage();
                false
            }
            Regression::ForceRow(1) => {
                self.publish_staged();
                true
            }
            Regression::Begun | Regression::ForceRow(_) | Regression::RotationRow(_) => false,
            // Every sample publishes (no decimation: studies, not the firmware, with no budget a
            // sample): the fallback follows in the same sample.
            Regression::All => {
                self.stage();
                self.publish_staged();
                false
            }
            Regression::None => {
                let due = self.since_publish >= self.effectiveness.cycle_samples();
                if due {
                    self.stage();
                    self.publish_staged();
                }
                due
            }
        };
        // Never beside a staged model: its rows would be replaced before its solve.
        // Nor beside a row begun (its first sample carries the row's larger half).
        if self.fallback_pending
            && !solved
            && self.staged.is_none()
            && regression != Regression::Begun
        {
            self.solve_fallback();
        }
        regression == Regression::ForceRow(0)
    }

    /// One sample of the free fall before the excitation (motors off): the effectiveness
    /// filters run on the body's own motion, so that they have settled when the motors start
    /// ([`effectiveness::EffectivenessEstimator::prime`]); nothing is learned. Call after
    /// [`Learner::restart`], on every sample of the release delay.
    pub fn prime(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds: &[f32; MAX_MOTORS],
    ) {
        self.prime_carrying(gyro_rad_s, accel_mps2, speeds, [0.0; 3]);
    }

    /// [`Learner::prime`], with `carried` as in [`Learner::update_carrying`]: without speed
    /// telemetry the effectiveness filters run on the means over
    /// [`no_speed::HOLD_INTERVAL_S`] (at its rate, as they learn), each handed back with its
    /// zero speeds once complete ([`Learner::for_each_released`]).
    pub fn prime_carrying(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds: &[f32; MAX_MOTORS],
        carried: [f32; 3],
    ) {
        if self.config.speed_telemetry {
            self.effectiveness.prime(gyro_rad_s, accel_mps2, &speeds[..self.motors]);
            return;
        }
        // Motors off: the lag regression's filters settle on the free tumble.
        self.command_speeds.update(gyro_rad_s, accel_mps2, &[0.0; MAX_MOTORS], false, false);
        self.released_len = 0;
        if let Some(mean) = self.command_speeds.prime(gyro_rad_s, accel_mps2, carried) {
            let speeds = &mean.speeds_rad_s[..self.motors];
            self.effectiveness.prime(mean.gyro_rad_s, mean.accel_mps2, speeds);
            self.released[0] = mean;
            self.released_len = 1;
        }
    }

    /// Without speed telemetry, each held sample the latest [`Learner::update_carrying`] learned
    /// from, oldest first: its body rates (rad/s) and specific force (m/s², IMU axes), the speeds
    /// modelled for it with the lag identified (rad/s, per [`no_speed::NOMINAL_FULL_SPEED_RAD_S`])
    /// and what was carried with it: the means over [`no_speed::HOLD_INTERVAL_S`]
    /// ([`no_speed::held_rate_hz`], 250 Hz at 2 kHz). None during the excitation (the samples
    /// are held until its lag is known), up to [`no_speed::RELEASE_PER_SAMPLE`] while catching
    /// up after it, then each as it is complete; in the free fall before it
    /// ([`Learner::prime_carrying`]) each as it is complete, with zero speeds; none with speed
    /// telemetry. What the in-flight IMU-offset fit regresses on where no speed is reported
    /// (`firmware::app::background`), at that rate.
    pub fn for_each_released(
        &self,
        mut f: impl FnMut([f32; 3], [f32; 3], &[f32; MAX_MOTORS], [f32; 3]),
    ) {
        for held in &self.released[..self.released_len] {
            f(held.gyro_rad_s, held.accel_mps2, &held.speeds_rad_s, held.carried);
        }
    }

    /// The model learned so far.
    pub fn model(&self) -> &LearnedModel {
        &self.model
    }

    /// Motor `i`'s model: learned from its speeds, or without them the nominal curve with the
    /// lag identified from the body's response ([`LearnerConfig::speed_telemetry`]).
    fn motor_model(&self, i: usize) -> MotorModel {
        if !self.config.speed_telemetry {
            return self.command_speeds.motor_model();
        }
        self.motor_models[i].model()
    }

    /// First half of a publication: the estimates and their convergence into `staging`.
    fn stage(&mut self) {
        let m = self.motors;
        let model = &mut self.staging;
        model.samples = self.samples;
        model.g1_per_speed2 = self.effectiveness.g1_per_speed2();
        if let Some(rows) = &self.force_rows {
            model.g1_per_speed2[..3].copy_from_slice(rows);
        }
        model.g2 = self.effectiveness.g2();
        model.g1_converged = 0;
        model.motors_converged = 0;
        model.pending = !self.config.speed_telemetry && self.command_speeds.pending();
        let mut all_informed = true;
        for i in 0..m {
            let motor = self.motor_model(i);
            let model = &mut self.staging;
            model.motor[i] = motor;
            if model.motor[i].converged {
                model.motors_converged |= 1 << i;
            }
            let columns = self.effectiveness.column_statistics(i, self.config.effectiveness_rls.p0);
            let ((force_std, torque_std), (force_left, torque_left)) =
                (columns.relative_std, columns.information_left);
            if force_std.max(torque_std) < G1_CONVERGED_RELATIVE_STD {
                model.g1_converged |= 1 << i;
            }
            all_informed &= force_left.max(torque_left) < AXIS_INFORMATION_FRACTION;
        }
        self.staged = Some(all_informed);
    }

    /// Second half: the thrust axis of the staged G1 (once every column is informed), then the
    /// staged model is published.
    fn publish_staged(&mut self) {
        let Some(all_informed) = self.staged.take() else { return };
        self.since_publish = 0;
        let model = &mut self.staging;
        if !all_informed {
            model.axis_status = AxisStatus::Waiting;
            self.model = *model;
            return;
        }
        match hover_axis(&mut self.solver, model) {
            Ok(axis) if axis.within_bounds() => {
                model.thrust_axis = Some(axis);
                model.axis_status = AxisStatus::Found;
            }
            Err(thrust_axis::ThrustAxisError::TorqueRankDeficient { .. }) => {
                model.axis_status = AxisStatus::RankDeficient;
            }
            clamped_or_none => {
                model.axis_status = AxisStatus::NoHover;
                let none_within = !has_hover_within_bounds(model);
                // The last resort is this model's clamped axis (a hover within the bounds
                // found earlier is kept). When this model says the motors together cannot lift
                // the craft, an axis an earlier one clamped is dropped if the speeds were
                // measured: the seed paper's quad at a quarter of its thrust (0.82 of its
                // weight) flew one left by a model of the excitation and hit the ground instead
                // of being refused. Not if they were modelled from the commands: the nominal
                // curve's full speed can be tens of percent off, and 3 of 1,000 random worlds
                // without speed telemetry (323, 444, 936) said so at the end and held on the
                // earlier axis.
                match clamped_or_none {
                    Ok(axis) if none_within => model.thrust_axis = Some(axis),
                    Err(_) if none_within && !model.speeds_modelled => model.thrust_axis = None,
                    _ => {}
                }
                self.fallback_pending = none_within && self.fallback_rows.is_some();
            }
        }
        self.model = *model;
    }

    /// The thrust axis solved on [`Self::fallback_rows`] with the last publication's torque
    /// rows (a sample after it: one solve a sample at most), published with them when found.
    fn solve_fallback(&mut self) {
        self.fallback_pending = false;
        // In the staged model, which is the last published until the next is staged (which
        // overwrites its rows): no copy of the model unless an axis is found.
        let model = &mut self.staging;
        let (Some(rows), false) = (&self.fallback_rows, has_hover_within_bounds(model)) else {
            return;
        };
        model.g1_per_speed2[..3].copy_from_slice(rows);
        if let Ok(axis) = hover_axis(&mut self.fallback_solver, model) {
            if axis.within_bounds() {
                model.axis_status = AxisStatus::Found;
            }
            model.thrust_axis = Some(axis);
            self.model = *model;
        }
    }
}

/// The most efficient hover of `model`'s G1 (per unit thrust), solved by `solver`.
fn hover_axis(
    solver: &mut ThrustAxisSolver,
    model: &LearnedModel,
) -> Result<LearnedThrustAxis, thrust_axis::ThrustAxisError> {
    let m = usize::from(model.motors);
    let g1 = model.g1_per_unit_thrust();
    let rows = |k: usize| &g1[k][..m];
    let problem = HoverProblem::new([rows(0), rows(1), rows(2)], [rows(3), rows(4), rows(5)]);
    // Solved in place: `?` on the problem would move (copy) it.
    let solution = match &problem {
        Ok(problem) => solver.solve(problem)?,
        Err(e) => return Err(*e),
    };
    let euler = solution.euler_zyx();
    let mut u_hover = [0.0; MAX_MOTORS];
    u_hover[..m].copy_from_slice(solution.u_hover());
    Ok(LearnedThrustAxis {
        q_thrust_to_imu: solution.q_thrust_to_imu,
        thrust_dir_imu: solution.thrust_dir_imu,
        u_hover,
        euler_zyx_rad: [euler.roll_rad, euler.pitch_rad, euler.yaw_rad],
        clamped_by: solution.clamped_by,
    })
}

/// Whether `model` has a thrust axis whose hover is within the motor bounds.
fn has_hover_within_bounds(model: &LearnedModel) -> bool {
    model.thrust_axis.is_some_and(|axis| axis.within_bounds())
}

/// Whether force rows handed in from outside are all finite (`None`, the learner's own, is).
fn all_finite(rows: &Option<[[f32; MAX_MOTORS]; 3]>) -> bool {
    rows.is_none_or(|rows| rows.iter().flatten().all(|v| v.is_finite()))
}

fn check_offset(r: [f32; 3]) -> Result<(), LearnerError> {
    if r.iter().all(|x| x.is_finite() && x.abs() <= 1.0) {
        Ok(())
    } else {
        Err(LearnerError::ImuOffset)
    }
}

/// Where a throw-to-fly attempt stands (the control step's half).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FlightPhase {
    /// Not armed: nothing spins.
    #[default]
    Idle,
    /// Armed, waiting for a throw.
    WaitingForThrow,
    /// The hand is accelerating the craft.
    Throwing,
    /// Released: the release delay and the free-fall check run, motors off.
    Released,
    /// Pulsing the motors.
    Exciting,
    /// The excitation is over.
    Done,
}

/// What a [`ThrowToFly`] step asks of the motors and reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThrowToFlyOutput {
    /// Commands δ for every motor (0 unless exciting).
    pub commands: [f32; MAX_MOTORS],
    /// The motor being pulsed.
    pub active_motor: Option<u8>,
    /// What the throw detector concluded in this step.
    pub event: ThrowEvent,
}

/// The control step's half of the identification: throw detection, then the excitation.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct ThrowToFly {
    throw_config: ThrowConfig,
    excitation_config: ExcitationConfig,
    motors: usize,
    phase: FlightPhase,
    detector: ThrowDetector,
    excitation: Excitation,
}

impl ThrowToFly {
    /// Idle, for `motors` motors.
    pub fn new(throw: ThrowConfig, excitation: ExcitationConfig, motors: usize) -> Self {
        Self {
            throw_config: throw,
            excitation_config: excitation,
            motors,
            phase: FlightPhase::Idle,
            detector: ThrowDetector::new(throw),
            excitation: Excitation::new(excitation, motors),
        }
    }

    /// Arm the throw detector (from any phase: a new attempt).
    pub fn arm(&mut self) {
        self.detector = ThrowDetector::new(self.throw_config);
        self.phase = FlightPhase::WaitingForThrow;
    }

    /// Back to idle: every motor at zero from the next step on.
    pub fn disarm(&mut self) {
        self.phase = FlightPhase::Idle;
    }

    /// Number of motors.
    pub fn motors(&self) -> usize {
        self.motors
    }

    /// Set the number of motors (a board learns it at start-up). During an excitation the
    /// attempt is abandoned (back to idle): the schedule was made for the old count.
    pub fn set_motors(&mut self, motors: usize) {
        if motors == self.motors {
            return;
        }
        self.motors = motors;
        if self.phase == FlightPhase::Exciting {
            self.phase = FlightPhase::Idle;
        }
    }

    /// The phase.
    pub fn phase(&self) -> FlightPhase {
        self.phase
    }

    /// The motor time constant measured during the spin-up of the current excitation, s.
    pub fn measured_tau_s(&self) -> Option<f32> {
        match self.phase {
            FlightPhase::Exciting | FlightPhase::Done => self.excitation.measured_tau_s(),
            _ => None,
        }
    }

    /// Time since the excitation began, s (0 before).
    pub fn excitation_elapsed_s(&self) -> f32 {
        match self.phase {
            FlightPhase::Exciting | FlightPhase::Done => self.excitation.elapsed_s(),
            _ => 0.0,
        }
    }

    /// One control step with the IMU sample (IMU axes) and the motor speeds reported (rad/s,
    /// NaN where none), `dt_s` after the previous one.
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds_rad_s: &[f32; MAX_MOTORS],
        dt_s: f32,
    ) -> ThrowToFlyOutput {
        let mut out = ThrowToFlyOutput {
            commands: [0.0; MAX_MOTORS],
            active_motor: None,
            event: ThrowEvent::None,
        };
        match self.phase {
            FlightPhase::Idle | FlightPhase::Done => {}
            FlightPhase::WaitingForThrow | FlightPhase::Throwing | FlightPhase::Released => {
                out.event = self.detector.update(accel_mps2, gyro_rad_s, dt_s);
                self.phase = match self.detector.state() {
                    ThrowState::Waiting => FlightPhase::WaitingForThrow,
                    ThrowState::Throwing { .. } => FlightPhase::Throwing,
                    ThrowState::Released { .. } => FlightPhase::Released,
                    ThrowState::Thrown => {
                        self.excitation = Excitation::new(self.excitation_config, self.motors);
                        FlightPhase::Exciting
                    }
                };
            }
            FlightPhase::Exciting => {
                let m = self.motors.min(MAX_MOTORS);
                let sum: f32 = speeds_rad_s[..m].iter().sum();
                let mean = (sum.is_finite() && m > 0).then(|| sum / m as f32);
                let excitation = self.excitation.update(gyro_rad_s, mean, dt_s);
                if excitation.finished {
                    self.phase = FlightPhase::Done;
                } else {
                    out.commands = excitation.commands;
                    out.active_motor = excitation.active_motor;
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// A quad's samples with a slowly changing spin, motors running: every estimator updates.
    fn sample(n: usize) -> ([f32; 3], [f32; 3], [f32; MAX_MOTORS], [f32; MAX_MOTORS]) {
        let t = n as f32 / 2000.0;
        let speed = |i: usize| 1000.0 + 300.0 * libm::sinf(20.0 * t + i as f32);
        let commands = core::array::from_fn(|i| if i < 4 { 0.3 } else { 0.0 });
        let speeds = core::array::from_fn(|i| if i < 4 { speed(i) } else { f32::NAN });
        ([1.0, 2.0 * t, -0.5], [0.1, -0.2, -9.0 - t], commands, speeds)
    }

    /// Without speed telemetry the excitation's samples reach the effectiveness regression
    /// once the lag is chosen after its end, as their means over `HOLD_INTERVAL_S` (one held
    /// sample in eight control samples), at most `RELEASE_PER_SAMPLE` a sample: the catch-up is
    /// spread over the samples after it, and the model says `pending` until the last held
    /// sample is learned from, and is published on the next sample.
    #[test]
    fn without_speed_telemetry_the_catch_up_is_spread_and_the_model_pending_until_done() {
        let config = LearnerConfig { speed_telemetry: false, ..LearnerConfig::default() };
        let mut slot = LearnerSlot::empty();
        let learner = slot.build(4, config).unwrap();
        learner.restart([0.0; 3]).unwrap();
        assert!(learner.model().pending);
        let no_speeds = [f32::NAN; MAX_MOTORS];
        let body = |n: usize| {
            let t = n as f32 / 2000.0;
            ([3.0 + libm::sinf(30.0 * t), -2.0, 1.0], [0.2, -0.1, -9.0 - libm::cosf(30.0 * t)])
        };
        // Each motor pulsed in turn (0.4 for the last 50 samples of its 100), the others near
        // idle: the last pulse ends with the loop.
        let pulses = 4 * 100;
        for n in 0..pulses {
            let mut commands = [0.0; MAX_MOTORS];
            for (i, c) in commands.iter_mut().enumerate().take(4) {
                *c = if n / 100 == i && n % 100 >= 50 { 0.4 } else { 0.05 };
            }
            let (gyro, accel) = body(n);
            learner.update(gyro, accel, &commands, &no_speeds);
            assert!(learner.model().pending, "pending during the excitation (sample {n})");
        }
        let before = learner.model().samples;
        let mut low = [0.0; MAX_MOTORS];
        low[..4].fill(0.05);
        let mut after = 0;
        let mut released = 0;
        while learner.model().pending {
            let (gyro, accel) = body(pulses + after);
            learner.update(gyro, accel, &low, &no_speeds);
            let mut count = 0;
            learner.for_each_released(|_, _, _, _| count += 1);
            assert!(count <= no_speed::RELEASE_PER_SAMPLE, "{count} released in one sample");
            released += count;
            after += 1;
            assert!(after < 2 * pulses, "still pending {after} samples after the excitation");
        }
        // Every held sample of the attempt learned from: one in eight control samples, one a
        // sample, one more held in every eight.
        let stride = no_speed::hold_stride(2000.0);
        let learned = (learner.model().samples - before) as usize;
        assert_eq!(learned, released);
        assert!(learned >= pulses / stride, "learned from {learned} of at least {} samples", {
            pulses / stride
        });
        // After the last pulse: the last period's pending candidates, the candidates'
        // regressions (a budget of work a sample: a quad's 52 within 110 samples, 55 ms), then
        // the catch-up, a held sample a sample (and the learner's command delay, a few samples).
        let spread = learned / no_speed::RELEASE_PER_SAMPLE;
        let scoring = no_speed::TAU_GRID_S.len() + 110;
        let most = scoring + (learned * stride).div_ceil(stride - 1) + 8;
        assert!(after >= spread && after <= most, "caught up {after} samples after the pulses");
        assert!(!learner.model().pending);
    }

    /// The slot builds a learner in place, rebuilds it for another motor count, and a refused
    /// build leaves it empty; a learner built in place equals one built by value.
    #[test]
    fn the_slot_builds_in_place_and_a_refused_build_leaves_it_empty() {
        let mut slot = LearnerSlot::empty();
        assert!(slot.get().is_none());
        let config = LearnerConfig::default();
        assert_eq!(slot.build(4, config).map(|l| l.motors), Ok(4));
        assert_eq!(slot.get().map(|l| l.model().motors), Some(4));
        assert_eq!(slot.build(8, config).map(|l| l.motors), Ok(8));
        let by_value = Learner::new(8, config).unwrap();
        let in_place = slot.get().unwrap();
        assert_eq!(in_place.effectiveness.g1_per_speed2(), by_value.effectiveness.g1_per_speed2());
        assert_eq!(
            in_place.effectiveness.normalised_inertia(),
            by_value.effectiveness.normalised_inertia()
        );
        assert_eq!(in_place.model(), by_value.model());
        assert_eq!(slot.build(9, config).err(), Some(LearnerError::MotorCount { motors: 9 }));
        assert!(slot.get().is_none(), "refused: nothing half-built is handed out");
        let far = LearnerConfig { r_imu_m: [f32::NAN, 0.0, 0.0], ..config };
        assert!(slot.build(4, far).is_err());
        assert!(slot.get_mut().is_none());
    }

    #[test]
    fn the_default_speed_age_gives_the_default_alignment_and_older_reports_shift_it() {
        let config = LearnerConfig::default();
        assert_eq!(config.with_speed_age(DEFAULT_SPEED_AGE_S), config);
        // 2.5 ms at 2 kHz: the report explains the command 1 + 2 · 5 = 11 half steps earlier,
        // and is 2.3125 ms older than the IMU sample.
        let old = config.with_speed_age(0.0025);
        assert_eq!(old.command_to_speed_delay_half_steps, 11);
        assert!((old.speed_report_lag_s - 0.0023125).abs() < 1e-7);
        // Beyond what the command history holds: clamped, never out of range.
        assert_eq!(config.with_speed_age(1.0).command_to_speed_delay_half_steps, 13);
        assert_eq!(config.with_speed_age(f32::NAN), config);
        // Without speed telemetry the speeds are modelled, not reported: no age moves them.
        let modelled = LearnerConfig { speed_telemetry: false, ..config };
        let aligned = modelled.with_speed_age(MODELLED_SPEED_AGE_S);
        for age_s in [0.0, 0.0025, 1.0, f32::NAN] {
            assert_eq!(modelled.with_speed_age(age_s), aligned, "{age_s} s");
        }
    }

    /// The model is published once per cycle of the six effectiveness regressions (staged in
    /// the last sample of force row x's turn, published with the thrust axis in the last of
    /// force row y's), and every cycle while a gap keeps the regressions from running.
    #[test]
    fn the_model_is_published_once_per_cycle_and_through_gaps() {
        let mut learner = Learner::new(4, LearnerConfig::default()).unwrap();
        assert_eq!(learner.effectiveness.cycle_samples(), 12, "2 kHz: two samples a row");
        let mut publications = std::vec::Vec::new();
        let mut last = learner.model().samples;
        for n in 0..80 {
            let (gyro, accel, commands, mut speeds) = sample(n);
            if (50..80).contains(&n) {
                speeds[0] = f32::NAN;
            }
            learner.update(gyro, accel, &commands, &speeds);
            let samples = learner.model().samples;
            if samples != last {
                publications.push((n, samples));
                last = samples;
            }
        }
        // (sample index, samples learned from). The filters take two samples, the regressions
        // twelve centred ones: they run from sample 14 (force row x's turn, 14 and 15), force row
        // x staging at 15, 27, ... what was learned from 16, 28, ... samples, and force row y
        // publishing it at 17, 29, ... Before that, and from the gap at sample 50 on (each
        // sample restarts the filters): every twelfth.
        let expected = [(11, 12), (17, 16), (29, 28), (41, 40)];
        assert_eq!(&publications[..expected.len()], &expected);
        let gap: std::vec::Vec<usize> =
            publications[expected.len()..].iter().map(|p| p.0).collect();
        assert_eq!(gap, [53, 65, 77]);
        assert!(learner.model().motor[1].a_rad_s != 0.0, "the motor models learned");
    }

    /// Force rows fitted elsewhere (the in-flight IMU-offset fit) replace the learner's own in
    /// every publication until the next restart; a non-finite set is refused and changes
    /// nothing.
    #[test]
    fn force_rows_set_from_outside_are_published_until_the_restart() {
        let mut learner = Learner::new(4, LearnerConfig::default()).unwrap();
        let run = |learner: &mut Learner, from: usize| {
            for n in from..from + 20 {
                let (gyro, accel, commands, speeds) = sample(n);
                learner.update(gyro, accel, &commands, &speeds);
            }
        };
        run(&mut learner, 0);
        let own = learner.model().g1_per_speed2;
        let mut fitted = [[0.0; MAX_MOTORS]; 3];
        fitted[2][..4].copy_from_slice(&[-1.1e-5, -0.9e-5, -1.0e-5, -1.2e-5]);
        let mut bad = fitted;
        bad[0][1] = f32::NAN;
        assert!(!learner.set_force_rows(Some(bad)));
        run(&mut learner, 20);
        assert_ne!(learner.model().g1_per_speed2[..3], fitted, "refused: still its own");
        assert!(learner.set_force_rows(Some(fitted)));
        run(&mut learner, 40);
        let published = learner.model().g1_per_speed2;
        assert_eq!(published[..3], fitted);
        assert_ne!(published[3..], own[3..], "the torque rows are still learned");
        learner.restart([0.0; 3]).unwrap();
        run(&mut learner, 0);
        assert_ne!(learner.model().g1_per_speed2[..3], fitted, "a new attempt learns its own");
    }

    /// The thrust per unit mass of each motor of [`pulse_quad`]'s quad, m/s² per (rad/s)²
    /// (6.1 m/s² at 3,000 rad/s).
    const QUAD_THRUST_PER_SPEED2: f32 = 6.1 / (3000.0 * 3000.0);

    /// [`pulse_quad`]'s force rows per squared speed: all along its −z.
    fn quad_force_rows() -> [[f32; MAX_MOTORS]; 3] {
        let mut rows = [[0.0; MAX_MOTORS]; 3];
        rows[2][..4].fill(-QUAD_THRUST_PER_SPEED2);
        rows
    }

    /// A flat X quad (arms 0.15 m, inertia 0.01 kg m², thrust [`QUAD_THRUST_PER_SPEED2`])
    /// pulsing each motor in turn, 50 ms apart, for `samples` at 2 kHz, its body rate
    /// integrated from the torques; its accelerometer reads `force_seen` times the motors'
    /// force (1: all of it; 0: nothing).
    fn pulse_quad(learner: &mut Learner, force_seen: f32, samples: core::ops::Range<usize>) {
        let thrust = QUAD_THRUST_PER_SPEED2;
        let arms = [[0.106f32, 0.106], [-0.106, 0.106], [-0.106, -0.106], [0.106, -0.106]];
        let mut rate = [5.0f32, -4.0, 1.5];
        for n in samples {
            let t_s = n as f32 / 2000.0;
            let mut commands = [0.0f32; MAX_MOTORS];
            let mut speeds = [0.0f32; MAX_MOTORS];
            let mut angular = [0.0f32; 3];
            for i in 0..4 {
                let phase = (t_s - 0.05 * i as f32).rem_euclid(0.2);
                commands[i] = if phase < 0.075 { 0.6 } else { 0.1 };
                speeds[i] = 3000.0
                    * libm::sqrtf(commands[i])
                    * (1.0 + 0.02 * libm::sinf(37.0 * t_s + i as f32));
                let force = thrust * speeds[i] * speeds[i];
                let spin = if i % 2 == 0 { 0.015 } else { -0.015 };
                angular[0] -= arms[i][1] * force / 0.01;
                angular[1] += arms[i][0] * force / 0.01;
                angular[2] += spin * force / 0.02;
            }
            let force_z = -thrust * speeds.iter().map(|w| w * w).sum::<f32>();
            let accel = [0.0, 0.0, force_seen * force_z];
            learner.update(rate, accel, &commands, &speeds);
            for k in 0..3 {
                rate[k] += angular[k] / 2000.0;
            }
        }
    }

    /// A model that says the motors together cannot lift the craft drops the last-resort axis an
    /// earlier model clamped when the speeds were measured (the craft is refused rather than
    /// flown into the ground), and keeps it when they were modelled from the commands (whose
    /// nominal full speed can be far off); a hover within the bounds found earlier is kept.
    #[test]
    fn a_too_weak_verdict_drops_an_earlier_clamped_axis_only_with_measured_speeds() {
        let mut learner = Learner::new(4, LearnerConfig::default()).unwrap();
        pulse_quad(&mut learner, 1.0, 0..1600);
        let model = *learner.model();
        let found = model.thrust_axis.expect("an axis on its own rows");
        let clamped = LearnedThrustAxis { clamped_by: 0.3, ..found };
        for (earlier, modelled, kept) in
            [(clamped, false, false), (clamped, true, true), (found, false, true)]
        {
            let mut weak = learner.clone();
            weak.staging = model;
            weak.staging.thrust_axis = Some(earlier);
            weak.staging.speeds_modelled = modelled;
            // A tenth of the thrust: every motor at full command lifts a tenth of the weight.
            for row in weak.staging.g1_per_speed2[..3].iter_mut() {
                row.iter_mut().for_each(|v| *v *= 0.1);
            }
            weak.staged = Some(true);
            weak.publish_staged();
            assert_eq!(weak.model().axis_status, AxisStatus::NoHover);
            assert_eq!(
                weak.model().thrust_axis,
                kept.then_some(earlier),
                "clamped by {}, speeds modelled: {modelled}",
                earlier.clamped_by
            );
        }
    }

    /// Where the learner's own force rows find no hover (here its accelerometer saw no motor's
    /// force), the fallback rows give it an axis a sample after a publication, and the
    /// publications after it solve on the learner's own again, keeping that axis; without
    /// fallback rows, and after a restart, there is none.
    #[test]
    fn fallback_force_rows_give_an_axis_where_the_own_rows_find_no_hover() {
        // The quad is flyable: seeing its force, the learner finds its axis on its own rows.
        let mut seeing = Learner::new(4, LearnerConfig::default()).unwrap();
        pulse_quad(&mut seeing, 1.0, 0..1600);
        let own = seeing.model().thrust_axis.expect("an axis on its own rows");
        assert!(own.thrust_dir_imu[2] < -0.99, "{:?}", own.thrust_dir_imu);

        let mut blind = Learner::new(4, LearnerConfig::default()).unwrap();
        pulse_quad(&mut blind, 0.0, 0..1600);
        assert_eq!(blind.model().axis_status, AxisStatus::NoHover);
        assert!(blind.model().thrust_axis.is_none());

        let mut learner = Learner::new(4, LearnerConfig::default()).unwrap();
        let truth = quad_force_rows();
        let mut bad = truth;
        bad[1][2] = f32::INFINITY;
        assert!(!learner.set_fallback_force_rows(Some(bad)));
        assert!(learner.set_fallback_force_rows(Some(truth)));
        pulse_quad(&mut learner, 0.0, 0..1600);
        let axis = learner.model().thrust_axis.expect("an axis on the fallback rows");
        // The quad's thrust is along its −z, which the fallback rows say and its own do not.
        assert!(axis.thrust_dir_imu[2] < -0.99, "{:?}", axis.thrust_dir_imu);
        // Its own rows are published again (they still find no hover): the axis is kept.
        assert_ne!(learner.model().g1_per_speed2[..3], truth[..]);
        assert_eq!(learner.model().axis_status, AxisStatus::NoHover);
        assert_eq!(learner.model().thrust_axis, Some(axis));

        learner.restart([0.0; 3]).unwrap();
        pulse_quad(&mut learner, 0.0, 0..1600);
        assert!(learner.model().thrust_axis.is_none(), "the restart dropped the fallback rows");
    }

    /// Where the learned hover leaves the motor bounds, the learner publishes the axis of `u*`
    /// clamped to them as a last resort (status `NoHover`), saying by how much, unless the
    /// learned motors cannot lift the craft at all; a hover within the bounds found later (here
    /// on the fallback rows) replaces it, and is never replaced by a clamped one.
    #[test]
    fn a_hover_outside_the_bounds_gives_a_clamped_axis_until_one_within_them() {
        // Seeing all of its force, the quad hovers with its busiest motor at `hover` of full
        // thrust, and every motor at full thrust gives `lift` times its weight.
        let mut seeing = Learner::new(4, LearnerConfig::default()).unwrap();
        pulse_quad(&mut seeing, 1.0, 0..1600);
        let model = seeing.model();
        let u_hover = model.thrust_axis.expect("an axis").u_hover;
        let hover = u_hover.iter().fold(0.0f32, |a, &b| a.max(b));
        let lift = -model.g1_per_unit_thrust()[2][..4].iter().sum::<f32>()
            / crate::navigation::STANDARD_GRAVITY_MPS2;
        // The accelerometer sees a quarter of the force: u* needs four times the command,
        // beyond the upper bound (1), while all four motors still lift the learned craft.
        let seen = 0.25;
        assert!(hover / seen > 1.05 && lift * seen > 1.05, "{hover} {lift}");
        let mut weak = Learner::new(4, LearnerConfig::default()).unwrap();
        pulse_quad(&mut weak, seen, 0..1600);
        let model = weak.model();
        assert_eq!(model.axis_status, AxisStatus::NoHover);
        let clamped = model.thrust_axis.expect("a clamped axis");
        assert!(!clamped.within_bounds());
        let beyond = hover / seen - 1.0;
        assert!(
            (clamped.clamped_by - beyond).abs() < 0.1 * beyond,
            "{} vs {beyond}",
            clamped.clamped_by
        );
        assert!(clamped.u_hover[..4].iter().all(|&u| (0.0..=1.0).contains(&u)));
        assert!(clamped.thrust_dir_imu[2] < -0.99, "{:?}", clamped.thrust_dir_imu);

        // Seeing a sixth, the four motors together cannot lift what the model says: refused.
        assert!(lift / 6.0 < 0.95, "{lift}");
        let mut too_weak = Learner::new(4, LearnerConfig::default()).unwrap();
        pulse_quad(&mut too_weak, 1.0 / 6.0, 0..1600);
        assert_eq!(too_weak.model().axis_status, AxisStatus::NoHover);
        assert!(too_weak.model().thrust_axis.is_none());

        let mut learner = Learner::new(4, LearnerConfig::default()).unwrap();
        assert!(learner.set_fallback_force_rows(Some(quad_force_rows())));
        pulse_quad(&mut learner, seen, 0..1600);
        let axis = learner.model().thrust_axis.expect("an axis on the fallback rows");
        assert!(axis.within_bounds(), "{}", axis.clamped_by);
        // Its own rows are published again (clamped): the hover within the bounds is kept.
        assert_eq!(learner.model().axis_status, AxisStatus::NoHover);
        assert_eq!(learner.model().thrust_axis, Some(axis));
    }

    /// Without speed telemetry the model to engage on is published on the sample after the one
    /// that learns from the catch-up's last held sample, staged there (or by that sample's
    /// force row x) and solved for its thrust axis, nothing learned beside. It is the model the
    /// caught-up sample published at once until 2026-12-04 (staged, again after a force row x,
    /// and solved in the same sample), one sample later, whichever of the six effectiveness
    /// regressions the last held sample ran (the lead-in of idle motors shifts it by held
    /// samples), and force rows handed in between the two samples do not change it.
    #[test]
    fn without_speed_telemetry_the_caught_up_model_is_published_a_sample_later_unchanged() {
        let config = LearnerConfig { speed_telemetry: false, ..LearnerConfig::default() };
        let stride = no_speed::hold_stride(2000.0);
        let thrust = QUAD_THRUST_PER_SPEED2;
        let arms = [[0.106f32, 0.106], [-0.106, 0.106], [-0.106, -0.106], [0.106, -0.106]];
        let no_speeds = [f32::NAN; MAX_MOTORS];
        // Samples learned since the last publication when the catch-up ended: which of the six
        // regressions its last held sample ran (0: force row y, which publishes; 5: force row
        // x, which stages).
        let mut last_rows = std::collections::BTreeSet::new();
        let cycle = Learner::new(4, config).unwrap().effectiveness.cycle_samples();
        assert_eq!(cycle, 6, "one held sample a row");
        for lead in 0..4 * usize::from(cycle) {
            let lead_in = lead * stride;
            let mut learner = Learner::new(4, config).unwrap();
            let mut rate = [5.0f32, -4.0, 1.5];
            let mut at_once: Option<Learner> = None;
            for n in 0..4000usize {
                // Motors near idle for the lead-in, then each pulsed once in turn, 50 ms apart.
                let t_s = n.saturating_sub(lead_in) as f32 / 2000.0;
                let mut commands = [0.0f32; MAX_MOTORS];
                let mut angular = [0.0f32; 3];
                for i in 0..4 {
                    let phase = t_s - 0.05 * i as f32;
                    let pulsed = n >= lead_in && (0.0..0.075).contains(&phase);
                    commands[i] = if pulsed { 0.6 } else { 0.1 };
                    let speed = 3000.0 * libm::sqrtf(commands[i]);
                    let force = thrust * speed * speed;
                    let spin = if i % 2 == 0 { 0.015 } else { -0.015 };
                    angular[0] -= arms[i][1] * force / 0.01;
                    angular[1] += arms[i][0] * force / 0.01;
                    angular[2] += spin * force / 0.02;
                }
                let force_z = -thrust * commands[..4].iter().map(|c| 9e6 * c).sum::<f32>();
                learner.update(rate, [0.0, 0.0, force_z], &commands, &no_speeds);
                for k in 0..3 {
                    rate[k] += angular[k] / 2000.0 + 0.3 * libm::sinf(0.01 * n as f32) / 2000.0;
                }
                if let Some(reference) = at_once.take() {
                    assert!(learner.caught_up.is_none());
                    assert!(!learner.model().pending, "published a sample after the catch-up");
                    assert_eq!(learner.model(), reference.model(), "lead-in {lead}");
                    assert_eq!(learner.released_len, 0, "nothing learned beside the solve");
                    // Every column informed: the publication solved for the thrust axis (this
                    // crude excitation's model finds no hover within the motor bounds).
                    assert_ne!(learner.model().axis_status, AxisStatus::Waiting);
                    break;
                }
                if learner.caught_up.is_some() {
                    assert!(learner.model().pending, "not yet published");
                    last_rows.insert(learner.since_publish);
                    // The path until 2026-12-04: staged (again) and published at once, from
                    // the estimates the last held sample left (its row's update finished).
                    let mut reference = learner.clone();
                    reference.effectiveness.finish_pending();
                    reference.stage();
                    reference.publish_staged();
                    assert!(!reference.model().pending);
                    at_once = Some(reference);
                    // Force rows handed in after the catch-up's last sample wait for the next
                    // publication.
                    let mut rows = quad_force_rows();
                    rows[0][lead % 4] = 1e-7;
                    assert!(learner.set_force_rows(Some(rows)));
                }
            }
            assert!(!learner.model().pending, "lead-in {lead}: never caught up");
        }
        assert!(last_rows.into_iter().eq(0..cycle), "every regression last");
    }
}
