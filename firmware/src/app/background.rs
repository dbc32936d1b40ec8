//! The background task's work: everything too slow for the 2 kHz step, fed by the sample queue.
//!
//! - One-second statistics of the IMU stream (mean and standard deviation per axis: at rest these
//!   are the gyro bias and the sensor noise, which the status reports and calibration flows use).
//! - The onboard IMU-offset estimator (`imu_offset`, seed paper §3.2): throws are
//!   detected as free fall, and after each accepted throw the offset, its 95 % ellipsoid and the
//!   verdict are re-estimated (a few 3 × 3 solves, once per throw). Only samples of an unpowered
//!   craft go in: none while armed (a throw-to-fly attempt), flying or with any motor commanded,
//!   nor for [`MOTORS_OFF_SETTLE_S`] after (a propeller spinning down still pushes). Its model is
//!   free fall and rest; a powered flight fits neither, and fed to it (the paper quad's
//!   throw-to-fly) it was counted as more throws and moved the estimate by 8–16 mm. The
//!   estimator is told of each such stretch as of a gap in the stream (a free fall in progress
//!   is abandoned, the rest pose in progress ends).
//!
//! - The in-flight learner (`flight::learner::Learner`): while the control step excites the
//!   motors after a throw, every sample updates the motor models, G1/G2 and the thrust axis.
//!   Its accelerometer is moved to the centre of gravity with the IMU offset: the configured one
//!   ([`Background::set_imu_offset`]), else the onboard estimate once it is well determined,
//!   else none (and the status says which). With `motor_bidir_dshot` = 0 it is built to model
//!   the speeds from the commands (`LearnerConfig::speed_telemetry`, `flight::learner::no_speed`;
//!   the published model's `speeds_modelled` says so).
//! - The IMU offset fitted in flight (`imu_offset::in_flight`, issue 32) when none is known
//!   (no calibration stored, the onboard estimate not well determined), in a task of its own
//!   below this one (`super::offset_fit`: this task hands it each sample's work and takes its
//!   estimates back a fixed time after the sample that completed them): on the learner's samples
//!   from the release, jointly with the force rows of G1, with the reported speeds or, without
//!   speed telemetry, the speeds the learner modelled for the samples it learns from (it holds
//!   the excitation's until their lag is known: `Learner::for_each_released`, the velocity
//!   carried beside each); once usable (`OffsetFitEstimate::usable`: within 5 mm), the
//!   published model carries the fitted offset and rows ([`ImuOffsetSource::FittedInFlight`])
//!   and the status shows it as the IMU offset (well determined or not by the calibration's
//!   2 mm), and the finished identification stores it as the calibration, with its ellipsoid
//!   (not one fitted on modelled speeds: `settings::Settings::service`). Measured in
//!   docs/algorithms/imu-offset.md.
//!
//! Results reach the other tasks through [`BackgroundResults`], copied under a short lock by the
//! board, never computed under it.

use super::offset_fit::{FitClient, FitWork};
use super::queue::{LearnerSample, SampleConsumer};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use flight::learner::MODELLED_SPEED_AGE_S;
use flight::learner::{FlightPhase, LearnedModel, LearnerConfig, LearnerSlot};
use flight::slot::Slot;
use imu_offset::in_flight::{OffsetFit, OffsetFitEstimate};
use imu_offset::{ImuOffsetEstimator, Verdict};
use nalgebra::Vector3;
use protocol::{ImuOffsetSource, ImuOffsetStatus, OffsetAdvice};
use tumble::TumbleInertia;

/// How long the learner keeps learning after the excitation ends, s: the last motor's speed
/// settles back to idle in about three time constants (75 ms for a 25 ms motor).
pub const LEARN_AFTER_EXCITATION_S: f32 = 0.1;

/// How long the learner goes on learning once the craft flies on the learned model, s: the
/// in-flight refinement (the pilot's controller follows at a lower gain,
/// `pilot::IN_FLIGHT_REFINEMENT_TIME_CONSTANT_S`). The recovery from the throw is a large manoeuvre the
/// model was not yet fitted to and refines it; a steady hover afterwards is closed-loop data
/// whose motor changes answer the gyro's own noise, and it biases the rotational rows: flown
/// 60 s on the simulator with no limit, racer-5in's roll and pitch rows went from 1.2 % to 20 %
/// off (hex-tilted's force rows 6.1 → 7.5 %). With 2 s: every built-in airframe ends better
/// than it engaged (racer-5in rotation block 1.15 → 0.84 % after 60 s), and on 1,000 random
/// airframes (`fly monte-carlo`) the worse G1 block goes from 3.39 % median, 13.4 % 99th
/// percentile at engagement to 2.33 % and 9.05 % (docs/benchmarks.md). Not so with rotor
/// vibration on the gyro (the random world's): after a gentle throw the hover's share of these
/// 2 s biases the rotational rows, and the 99th percentile ends at 24 % against 20 % at
/// engagement; 0.5 s would halve that tail but also cut the in-flight IMU-offset fit, which
/// shares this window (docs/benchmarks.md, "One throw, no calibration": found, not fixed).
pub const REFINE_IN_FLIGHT_S: f32 = 2.0;

/// Longest wait of the control step at the end of the excitation for a model this task is still
/// learning from samples already
/// taken (`LearnedModel::pending`: without speed telemetry the effectiveness regression learns
/// from the excitation once its lag is identified, `no_speed::RELEASE_PER_SAMPLE` samples per
/// control sample), s: about 1.7 times its longest catch-up (the lag's choice over 52 samples,
/// 26 ms, then the 1,700 samples of a 0.85 s excitation at seven net a sample, 0.12 s). The motors hold the excitation's last commands
/// (it ends at zero, where the armed ESCs idle); after it the controller is formed on what there
/// is, and refused as before when that cannot fly. Defined here, where the catch-up is, and read
/// by the control step (`super::control`).
pub const ENGAGE_WAIT_MAX_S: f32 = 0.25;

/// How long after the craft was last powered (armed for throw-to-fly, flying, or any motor
/// commanded) samples stay away from the IMU-offset estimator, s. Origin: a motor told to stop
/// keeps turning, and pushing, for a few time constants (25–50 ms for the simulator's airframes,
/// up to about 0.1 s for large propellers); 0.5 s is five of the slowest, and a hand needs longer
/// than that to take a disarmed craft and throw it again.
pub const MOTORS_OFF_SETTLE_S: f32 = 0.5;

/// Length of one statistics window, µs (one second).
pub const STATS_WINDOW_US: u64 = 1_000_000;

/// What the background task publishes (a small `Copy` value, swapped whole).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BackgroundResults {
    /// Samples taken from the queue since start-up.
    pub samples_processed: u32,
    /// Whether a full window has completed (the statistics below are meaningful).
    pub stats_valid: bool,
    /// Gyro mean over the last completed window, rad/s.
    pub gyro_mean_rad_s: [f32; 3],
    /// Gyro standard deviation over that window, rad/s.
    pub gyro_std_rad_s: [f32; 3],
    /// Accelerometer mean over that window, m/s².
    pub accel_mean_mps2: [f32; 3],
    /// Accelerometer standard deviation over that window, m/s².
    pub accel_std_mps2: [f32; 3],
    /// The IMU-offset estimator's state and latest estimate, or the offset fitted in the
    /// latest flight when [`Self::imu_offset_fitted_in_flight`].
    pub imu_offset: ImuOffsetStatus,
    /// Whether [`Self::imu_offset`] shows the in-flight fit (until the estimator's next
    /// estimate or restart).
    pub imu_offset_fitted_in_flight: bool,
    /// What the in-flight learner has learned in the latest attempt.
    pub learned: LearnedModel,
    /// Whether the latest attempt's learning is over (the excitation, the settling after it and
    /// the in-flight refinement, [`REFINE_IN_FLIGHT_S`]): [`Self::learned`] is final until the
    /// next attempt, and the controller takes it whole (`pilot::Pilot::set_model`).
    pub learning_ended: bool,
    /// Where the IMU offset used by the latest attempt came from.
    pub learner_offset: ImuOffsetSource,
    /// That offset, IMU axes, m (the controller compensates the accelerometer with it too).
    pub learner_r_imu_m: [f32; 3],
    /// The IMU-offset calibration the host started ([`Background::start_calibration`]), if one
    /// is running.
    pub calibration: Option<CalibrationState>,
    /// The IMU offset fitted in flight with G1f (`imu_offset::in_flight`), when enabled
    /// ([`Background::set_offset_fit`]) and determined by the latest attempt's samples so far.
    pub flight_offset: Option<OffsetFitEstimate>,
}

/// What the link asks of the background task.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackgroundCommand {
    /// [`Background::start_calibration`].
    StartCalibration,
    /// [`Background::stop_calibration`].
    StopCalibration,
}

/// A running IMU-offset calibration: the estimator started afresh when it began, so
/// `imu_offset` holds this calibration's throws only.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CalibrationState {
    /// Free-fall length of the latest accepted throw, ms.
    pub last_free_fall_ms: u16,
    /// The accelerometer bias fitted with the offset, m/s², IMU axes (the residual after the
    /// configured bias was subtracted), when the model fits one.
    pub acc_bias_mps2: Option<[f32; 3]>,
}

/// The background worker.
pub struct Background<'q> {
    samples: SampleConsumer<'q>,
    gyro: [RunningStats; 3],
    accel: [RunningStats; 3],
    window_start_us: Option<u64>,
    /// Built in place (15 KB); empty only if the estimator rejected its configuration (then
    /// the status shows no throws).
    imu_offset: Slot<ImuOffsetEstimator>,
    /// The estimator's configuration (from the parameters), used from the next calibration.
    imu_offset_config: imu_offset::Config,
    /// One control period, µs: the spacing of consecutive samples when none is lost.
    period_us: u64,
    /// Time of the previous sample the IMU-offset estimator took, µs.
    previous_t_us: Option<u64>,
    /// Time of the latest sample of a powered craft (see [`MOTORS_OFF_SETTLE_S`]), µs.
    powered_at_us: Option<u64>,
    /// Whether the previous sample was kept from the IMU-offset estimator.
    offset_paused: bool,
    /// The in-flight learner, built at the first excitation (it needs the motor count).
    learner: LearnerSlot,
    /// The IMU offset to use, IMU axes, m, when configured.
    configured_offset_m: Option<[f32; 3]>,
    /// Age of the motor-speed reports (`motor_speed_age_s`), s: the learner's time alignment.
    speed_age_s: f32,
    /// The age the learner in the slot was built for, s.
    learner_speed_age_s: f32,
    /// Whether the ESCs report their speeds (`motor_bidir_dshot`): without, the learner models
    /// them from the commands (`flight::learner::no_speed`).
    speed_telemetry: bool,
    rate_hz: f32,
    previous_phase: FlightPhase,
    /// The body's inertia from its free tumble after the release: the learner's prior for it.
    tumble: TumbleInertia,
    /// Samples learned from since the excitation ended.
    samples_since_excitation: u32,
    /// How many samples after the excitation the learner still takes ([`LEARN_AFTER_EXCITATION_S`]).
    settle_samples: u32,
    /// [`ENGAGE_WAIT_MAX_S`] in samples.
    engage_wait_samples: u32,
    /// How many more while the craft flies ([`REFINE_IN_FLIGHT_S`]).
    refine_samples: u32,
    /// Whether each attempt fits the IMU offset in flight ([`Background::set_offset_fit`]).
    offset_fit_enabled: bool,
    /// The in-flight IMU-offset fit's task ([`super::offset_fit`]): this end hands it the
    /// samples and takes its estimates back.
    offset_fit: FitClient<'q>,
    /// Whether this attempt fits the offset in flight ([`Self::offset_fit`]).
    offset_fitting: bool,
    results: BackgroundResults,
}

impl<'q> Background<'q> {
    /// The background worker for samples taken once per control step at `control_rate_hz`,
    /// with its end of the in-flight IMU-offset fit's task (`super::offset_fit`).
    pub fn new(
        samples: SampleConsumer<'q>,
        offset_fit: FitClient<'q>,
        control_rate_hz: u16,
    ) -> Self {
        let mut slot = MaybeUninit::uninit();
        Self::build_in(&mut slot, samples, offset_fit, control_rate_hz);
        // SAFETY: `build_in` wrote every field.
        unsafe { slot.assume_init() }
    }

    /// [`Background::new`] in place, field by field: the worker is about 55 KB (the learner's
    /// storage, the IMU-offset estimator), and the board keeps it in a static that `init`
    /// builds this way instead of holding it whole on its stack (docs/budget.md).
    pub fn build_in<'s>(
        slot: &'s mut MaybeUninit<Self>,
        samples: SampleConsumer<'q>,
        offset_fit: FitClient<'q>,
        control_rate_hz: u16,
    ) -> &'s mut Self {
        let rate_hz = control_rate_hz.max(1);
        let worker = slot.as_mut_ptr();
        // SAFETY: each field is written exactly once through raw field pointers before the
        // reference is formed; the learner's storage needs only its flag (`LearnerSlot`).
        unsafe {
            addr_of_mut!((*worker).samples).write(samples);
            addr_of_mut!((*worker).gyro).write(Default::default());
            addr_of_mut!((*worker).accel).write(Default::default());
            addr_of_mut!((*worker).window_start_us).write(None);
            let imu_offset = addr_of_mut!((*worker).imu_offset);
            Slot::init_empty(imu_offset);
            let _ = (*imu_offset).build_with(|slot| {
                ImuOffsetEstimator::build_in(slot, f32::from(rate_hz), imu_offset_config())
            });
            addr_of_mut!((*worker).imu_offset_config).write(imu_offset_config());
            addr_of_mut!((*worker).period_us).write(1_000_000 / u64::from(rate_hz));
            addr_of_mut!((*worker).previous_t_us).write(None);
            addr_of_mut!((*worker).powered_at_us).write(None);
            addr_of_mut!((*worker).offset_paused).write(false);
            LearnerSlot::init_empty(addr_of_mut!((*worker).learner));
            addr_of_mut!((*worker).configured_offset_m).write(None);
            addr_of_mut!((*worker).speed_age_s).write(flight::learner::DEFAULT_SPEED_AGE_S);
            addr_of_mut!((*worker).learner_speed_age_s).write(flight::learner::DEFAULT_SPEED_AGE_S);
            addr_of_mut!((*worker).speed_telemetry).write(true);
            addr_of_mut!((*worker).rate_hz).write(f32::from(rate_hz));
            addr_of_mut!((*worker).previous_phase).write(FlightPhase::Idle);
            addr_of_mut!((*worker).tumble).write(TumbleInertia::new(f32::from(rate_hz)));
            addr_of_mut!((*worker).samples_since_excitation).write(0);
            let settle = (LEARN_AFTER_EXCITATION_S * f32::from(rate_hz)) as u32;
            addr_of_mut!((*worker).settle_samples).write(settle);
            let wait = (ENGAGE_WAIT_MAX_S * f32::from(rate_hz)) as u32;
            addr_of_mut!((*worker).engage_wait_samples).write(wait);
            let refine = (REFINE_IN_FLIGHT_S * f32::from(rate_hz)) as u32;
            addr_of_mut!((*worker).refine_samples).write(refine);
            addr_of_mut!((*worker).offset_fit_enabled).write(true);
            addr_of_mut!((*worker).offset_fit).write(offset_fit);
            addr_of_mut!((*worker).offset_fitting).write(false);
            addr_of_mut!((*worker).results).write(BackgroundResults::default());
            slot.assume_init_mut()
        }
    }

    /// Use `r_imu_m` (IMU position relative to the centre of gravity, IMU axes, m) for the next
    /// identifications instead of the onboard estimate; `None` goes back to the onboard one.
    pub fn set_imu_offset(&mut self, r_imu_m: Option<[f32; 3]>) {
        self.configured_offset_m = r_imu_m.filter(|r| r.iter().all(|x| x.is_finite()));
        self.publish_offset_between_attempts();
    }

    /// Between attempts (disarmed), the offset the next one would use ([`Self::learner_offset`])
    /// is the one in use: published, so that the control step's attitude filter and
    /// navigation take the centripetal term out of the accelerometer from the start, the
    /// throw's push included. That push spins the craft up to 15 rad/s, where `ω² r` is
    /// 11 m/s² for an IMU 5 cm off, and the heading alignment learns its first yaw from the
    /// push's dead reckoning. Until the first attempt's learner started (at the release) the
    /// offset was zero even with one configured. An attempt keeps the offset it started with
    /// (`restart_learner`).
    fn publish_offset_between_attempts(&mut self) {
        if self.previous_phase == FlightPhase::Idle {
            let (r_imu_m, source) = self.learner_offset();
            self.results.learner_r_imu_m = r_imu_m;
            self.results.learner_offset = source;
        }
    }

    /// Whether attempts with no IMU offset known (no calibration stored, the onboard estimate
    /// not well determined) fit it in flight (`imu_offset::in_flight`, issue 32; on by default
    /// where it is built). The estimate is reported in [`BackgroundResults::flight_offset`];
    /// once usable, the published model carries it and the force rows fitted with it
    /// ([`ImuOffsetSource::FittedInFlight`]), the status shows it as the IMU offset, and the
    /// finished identification stores it as the calibration (`settings::Settings::service`).
    /// Off: such attempts fly with no offset, as before issue 32 (a baseline for the simulator).
    pub fn set_offset_fit(&mut self, enabled: bool) {
        self.offset_fit_enabled = enabled;
        if !enabled {
            self.stop_offset_fit();
        }
    }

    /// The attempt's in-flight fit abandoned (its estimates to come are dropped).
    fn stop_offset_fit(&mut self) {
        if self.offset_fitting {
            self.offset_fitting = false;
            self.offset_fit.stop(self.results.samples_processed);
        }
    }

    /// Take the parameters: the configured IMU offset at once, the estimator's configuration
    /// from the next calibration (or now, while it has seen no throw).
    pub fn configure(&mut self, params: &super::params::Params) {
        self.set_imu_offset(params.configured_offset_m());
        self.speed_age_s = params.motor_speed_age_s();
        self.speed_telemetry = params.bidirectional_dshot();
        let config = params.imu_offset_config();
        if config != self.imu_offset_config {
            self.imu_offset_config = config;
            if self.imu_offset.get().is_none_or(|e| e.segments().is_empty()) {
                self.restart_imu_offset();
            }
        }
    }

    /// Carry out a command from the link.
    pub fn command(&mut self, command: BackgroundCommand) {
        match command {
            BackgroundCommand::StartCalibration => self.start_calibration(),
            BackgroundCommand::StopCalibration => self.stop_calibration(),
        }
    }

    /// Start an IMU-offset calibration: the estimator forgets earlier throws, and
    /// [`BackgroundResults::calibration`] follows this calibration's throws.
    pub fn start_calibration(&mut self) {
        self.restart_imu_offset();
        self.results.calibration = Some(CalibrationState::default());
    }

    /// End the calibration (the estimate stays on show in the status).
    pub fn stop_calibration(&mut self) {
        self.results.calibration = None;
    }

    // Not inlined: a first construction builds the estimator by value, and its temporaries
    // would otherwise stay in the frame of every caller (the background task's worst path).
    #[inline(never)]
    fn restart_imu_offset(&mut self) {
        // In place: the estimator is 15 KB, too large for a temporary on this task's stack.
        let restarted = match self.imu_offset.get_mut() {
            Some(estimator) => estimator.restart(self.imu_offset_config).is_ok(),
            None => false,
        };
        if !restarted {
            let (rate_hz, config) = (self.rate_hz, self.imu_offset_config);
            let _ = self
                .imu_offset
                .build_with(|slot| ImuOffsetEstimator::build_in(slot, rate_hz, config));
        }
        self.results.imu_offset = ImuOffsetStatus::default();
        self.results.imu_offset_fitted_in_flight = false;
        self.previous_t_us = None;
    }

    /// The configured IMU offset ([`Background::set_imu_offset`]), if any.
    pub fn configured_imu_offset(&self) -> Option<[f32; 3]> {
        self.configured_offset_m
    }

    /// Process every waiting sample, unless the in-flight fit's task must catch up first
    /// ([`Self::waits_for_offset_fit`]). Returns the number processed.
    pub fn run_pending(&mut self) -> u32 {
        let mut processed = 0;
        while self.run_one() {
            processed += 1;
        }
        processed
    }

    /// Process the oldest waiting sample; false: none waited, or the in-flight fit's task must
    /// catch up first. (A replay steps the worker one sample at a time to reach the results the
    /// board's control step adopted.)
    pub fn run_one(&mut self) -> bool {
        if self.waits_for_offset_fit() {
            return false;
        }
        let Some(sample) = self.samples.pop() else { return false };
        self.process(&sample);
        true
    }

    /// Whether samples wait (processed by the next run, or held while
    /// [`Self::waits_for_offset_fit`]).
    pub fn has_waiting_samples(&self) -> bool {
        self.samples.has_waiting()
    }

    /// Whether the next sample must wait for the in-flight fit's task: its estimates are applied
    /// a fixed time after the sample that completed them (`super::offset_fit`), and that one's
    /// work is not finished yet, or its ring has no room for a sample's work.
    pub fn waits_for_offset_fit(&self) -> bool {
        !self.offset_fit.ready_for(self.results.samples_processed.wrapping_add(1))
    }

    /// The latest results.
    pub fn results(&self) -> BackgroundResults {
        self.results
    }

    /// The latest results, borrowed (no copy).
    pub fn results_ref(&self) -> &BackgroundResults {
        &self.results
    }

    fn process(&mut self, sample: &LearnerSample) {
        self.results.samples_processed = self.results.samples_processed.wrapping_add(1);
        let start = *self.window_start_us.get_or_insert(sample.t_us);
        if sample.t_us.saturating_sub(start) >= STATS_WINDOW_US {
            self.publish_window();
            self.window_start_us = Some(sample.t_us);
        }
        for axis in 0..3 {
            self.gyro[axis].add(sample.imu.gyro_rad_s[axis]);
            self.accel[axis].add(sample.imu.accel_mps2[axis]);
        }
        if self.unpowered(sample) {
            self.offset_paused = false;
            self.update_imu_offset(sample);
        } else if !self.offset_paused {
            // A free fall or rest in progress ends here; the samples left out until the craft
            // is unpowered again are told as a gap when it is (`update_imu_offset`).
            self.offset_paused = true;
            if let Some(estimator) = self.imu_offset.get_mut() {
                estimator.gap(0);
            }
            self.results.imu_offset.in_free_fall = false;
        }
        self.update_learner(sample);
        // On every sample, learning or not: the estimate of the attempt's last samples comes
        // back after them (applied as the learning path applies it), and those of an abandoned
        // attempt leave the ring.
        if self.take_offset_fit_estimates() {
            self.apply_offset_fit(sample.flying);
        }
        self.offset_fit.end_sample(self.results.samples_processed);
    }

    /// Whether the craft has been unpowered for [`MOTORS_OFF_SETTLE_S`] at `sample`: not armed
    /// for throw-to-fly, not flying, every motor command zero.
    fn unpowered(&mut self, sample: &LearnerSample) -> bool {
        let motors = usize::from(sample.motor_count).min(sample.commands.len());
        let powered = sample.flying
            || !matches!(sample.phase, FlightPhase::Idle | FlightPhase::Done)
            || sample.commands[..motors].iter().any(|&c| c != 0.0);
        if powered {
            self.powered_at_us = Some(sample.t_us);
        }
        let settle_us = (MOTORS_OFF_SETTLE_S * 1e6) as u64;
        self.powered_at_us.is_none_or(|t| sample.t_us.saturating_sub(t) >= settle_us)
    }

    fn update_learner(&mut self, sample: &LearnerSample) {
        let phase = sample.phase;
        let previous_phase = self.previous_phase;
        let starting = phase == FlightPhase::Exciting && previous_phase != FlightPhase::Exciting;
        self.previous_phase = phase;
        match phase {
            // The motors are off and the body turns freely: its inertia shows.
            FlightPhase::Released => self.tumble.update(sample.imu.gyro_rad_s),
            FlightPhase::Exciting => {}
            _ => self.tumble.reset(),
        }
        // A new identification starts at the release: the learner is restarted there and its
        // filters run on the free fall (`Learner::prime`), so that they have settled on the
        // body's own precession when the motors start. (When the release delay's samples did
        // not reach this task, it starts cold with the excitation, as before.)
        let releasing = phase == FlightPhase::Released && previous_phase != FlightPhase::Released;
        if releasing || (starting && previous_phase != FlightPhase::Released) {
            self.restart_learner(sample.motor_count);
        }
        if phase == FlightPhase::Released {
            if let Some(learner) = self.learner.get_mut() {
                let (gyro, accel) = (sample.imu.gyro_rad_s, sample.imu.accel_mps2);
                let velocity = sample.velocity_imu_mps;
                learner.prime_carrying(gyro, accel, &sample.speeds_rad_s, velocity);
            }
            self.update_offset_fit(sample);
        }
        if starting {
            if let Some(learner) = self.learner.get_mut() {
                learner.set_inertia_prior(&self.tumble.prior());
            }
        }
        // The learner runs from the start of the excitation until the motors have settled after
        // it (the last pulse's ramp still carries information), and on for the first
        // [`REFINE_IN_FLIGHT_S`] of the flight on the learned model: the in-flight refinement.
        // Not when the craft neither flies nor settles: without the controller it falls or is
        // caught, and a catch is a force no motor made.
        // While the model is still learning from the excitation (`LearnedModel::pending`), the
        // control step waits for it, at most `ENGAGE_WAIT_MAX_S`, and so does this.
        let refining = if sample.flying { self.refine_samples } else { 0 };
        let catching_up = self.results.learned.pending
            && self.samples_since_excitation < self.engage_wait_samples;
        if phase == FlightPhase::Exciting {
            self.samples_since_excitation = 0;
        } else if phase == FlightPhase::Done
            && (self.samples_since_excitation < self.settle_samples + refining || catching_up)
        {
            self.samples_since_excitation += 1;
        } else {
            self.results.learning_ended |= phase == FlightPhase::Done;
            return;
        }
        if let Some(learner) = self.learner.get_mut() {
            let (gyro, accel) = (sample.imu.gyro_rad_s, sample.imu.accel_mps2);
            // The velocity rides with each sample the learner holds without speed telemetry:
            // the in-flight offset fit takes it back with the sample (`update_offset_fit`).
            let velocity = sample.velocity_imu_mps;
            learner.update_carrying(gyro, accel, &sample.commands, &sample.speeds_rad_s, velocity);
            self.results.learned = *learner.model();
        }
        self.update_offset_fit(sample);
        self.take_offset_fit_estimates();
        self.apply_offset_fit(sample.flying);
    }

    /// Once the in-flight fit is usable (`OffsetFitEstimate::usable`: its largest 95 % semi-axis
    /// within 5 mm), the published model carries the force
    /// rows fitted with it (the learner's own, learned with the offset of the attempt's start,
    /// are off by `[r − r₀]× G1τ` and more: `imu_offset::in_flight`), and the controller
    /// compensates its accelerometer with the fitted offset, from engagement or, when the fit is
    /// determined later, from then on (`pilot::Pilot::set_model`). Once the craft flies, the
    /// learner also solves the thrust axis on the fitted rows: the axis stored for the next
    /// flights (the controller keeps the frame it engaged in). On 1,000 random worlds that
    /// axis's error went from 2.91° to 1.19° median (docs/algorithms/imu-offset.md). Not
    /// before: solved on the fitted rows from the excitation on, it found no hover in 23 of the
    /// 1,000 worlds against 1 on the learner's own.
    fn apply_offset_fit(&mut self, flying: bool) {
        let Some(fit) = self.results.flight_offset.filter(OffsetFitEstimate::usable) else {
            return;
        };
        if flying {
            if let Some(learner) = self.learner.get_mut() {
                learner.set_force_rows(Some(fit.g1f_per_speed2));
            }
        }
        self.results.learned.g1_per_speed2[..3].copy_from_slice(&fit.g1f_per_speed2);
        self.results.learner_r_imu_m = fit.r_imu_m;
        self.results.learner_offset = ImuOffsetSource::FittedInFlight;
        // Shown as the IMU offset, as a calibration's would be (its throws stay counted).
        let mut semi_axes_m = fit.ci95_semi_axes_m;
        semi_axes_m.reverse();
        self.results.imu_offset = ImuOffsetStatus {
            estimated: true,
            r_imu_m: fit.r_imu_m,
            ci95_semi_axes_m: semi_axes_m,
            well_determined: fit.well_determined,
            advice: OffsetAdvice::None,
            ..self.results.imu_offset
        };
        self.results.imu_offset_fitted_in_flight = true;
    }

    /// One sample's work for the in-flight IMU-offset fit's task (`super::offset_fit`).
    fn update_offset_fit(&mut self, sample: &LearnerSample) {
        if !self.offset_fitting {
            return;
        }
        let tag = self.results.samples_processed;
        let fit = &mut self.offset_fit;
        let mut lost = false;
        if self.speed_telemetry {
            lost |= !fit.push(
                tag,
                FitWork::Sample {
                    gyro_rad_s: sample.imu.gyro_rad_s,
                    accel_mps2: sample.imu.accel_mps2,
                    speeds_rad_s: sample.speeds_rad_s,
                    velocity_imu_mps: sample.velocity_imu_mps,
                },
            );
        } else {
            // No speed reported: the samples the learner learned from in this step, with the
            // speeds it modelled for them from the commands with the lag it identified, and the
            // velocity carried with each: the means over `no_speed::HOLD_INTERVAL_S`, the fit
            // built for their rate (`restart_learner`). It holds the excitation's samples until
            // that lag is known, then releases them, so the fit sees the same samples in the
            // same order, a little later. (Released, the motors are off: the learner's means
            // of the free fall, with zero speeds, `Learner::prime_carrying`.)
            let mut released = false;
            if let Some(learner) = self.learner.get() {
                learner.for_each_released(|gyro_rad_s, accel_mps2, speeds_rad_s, velocity| {
                    let work = FitWork::Sample {
                        gyro_rad_s,
                        accel_mps2,
                        speeds_rad_s: *speeds_rad_s,
                        velocity_imu_mps: velocity,
                    };
                    lost |= !fit.push(tag, work);
                    released = true;
                });
            }
            if !released {
                // The rows of the last held sample go into the sums on the samples between.
                lost |= !fit.push(tag, FitWork::Advance);
            }
        }
        if lost {
            // Never with `waits_for_offset_fit` kept: a fit missing samples is no fit.
            self.stop_offset_fit();
        }
    }

    /// The in-flight fit's estimates due at this sample (`super::offset_fit`: the hand-back
    /// after the sample that completed them) into the results and the learner; those of an
    /// attempt since abandoned are dropped. Whether one was taken.
    fn take_offset_fit_estimates(&mut self) -> bool {
        let tag = self.results.samples_processed;
        let results = &mut self.results;
        let learner = &mut self.learner;
        let mut taken = false;
        self.offset_fit.take_due(tag, |estimate| {
            taken = true;
            results.flight_offset = estimate;
            // Every estimate's rows, usable or not, are the learner's fallback
            // (`Learner::set_fallback_force_rows`): its own, learned with no offset, also carry
            // the tumble's rotation at the IMU (`Ω × (Ω × r)`, `Ω̇_free × r`), which no motor
            // explains and the fit models, and where they find no hover within the motor
            // bounds the craft would be refused and fall. Where `r` is still poorly determined
            // the fit's rows are uncertain only along `[δr]× G1τ`, directions a hover's torque
            // balance does not use. 1,000 random worlds (seeds 5001–6000): 3 refused for no
            // hover, none with the fallback (docs/benchmarks.md).
            if let (Some(estimate), Some(learner)) = (&estimate, learner.get_mut()) {
                learner.set_fallback_force_rows(Some(estimate.g1f_per_speed2));
            }
        });
        taken
    }

    /// A new identification for `motor_count` motors: the learner (re)built or restarted with
    /// the IMU offset of now.
    fn restart_learner(&mut self, motor_count: u8) {
        let (r_imu_m, source) = self.learner_offset();
        let reuse = self.learner.get().is_some_and(|l| {
            l.model().motors == motor_count && l.config().speed_telemetry == self.speed_telemetry
        }) && self.learner_speed_age_s == self.speed_age_s;
        if !reuse {
            let config = LearnerConfig {
                rate_hz: self.rate_hz,
                r_imu_m,
                speed_telemetry: self.speed_telemetry,
                ..LearnerConfig::default()
            }
            .with_speed_age(self.speed_age_s);
            self.learner_speed_age_s = self.speed_age_s;
            // In place: the learner is 25 KB (docs/budget.md).
            let _ = self.learner.build(usize::from(motor_count), config);
        }
        if let Some(learner) = self.learner.get_mut() {
            // Cannot fail: the offset was checked finite and the onboard one is bounded.
            let _ = learner.restart(r_imu_m);
        }
        self.results.learner_offset = source;
        self.results.learner_r_imu_m = r_imu_m;
        self.results.learning_ended = false;
        self.results.flight_offset = None;
        // Fitted only where nothing better is known, from measured speeds or, without speed
        // telemetry, from the learner's modelled ones (`update_offset_fit`).
        let fitting = self.offset_fit_enabled && source == ImuOffsetSource::Zero;
        let age_s = if self.speeds_modelled() { MODELLED_SPEED_AGE_S } else { self.speed_age_s };
        let lag_s = age_s - flight::learner::IMU_GROUP_DELAY_S;
        // Without speed telemetry the fit takes the learner's held samples, at their rate.
        let fit_rate_hz = if self.speeds_modelled() {
            flight::learner::no_speed::held_rate_hz(self.rate_hz)
        } else {
            self.rate_hz
        };
        if fitting && OffsetFit::supports_rate(fit_rate_hz) {
            // A start resets the worker's fit and drops the earlier attempt's estimates.
            self.offset_fitting = true;
            let tag = self.results.samples_processed;
            self.offset_fit.start(tag, motor_count, fit_rate_hz, lag_s);
        } else {
            self.stop_offset_fit();
        }
    }

    /// Whether the learner models the motor speeds from the commands: the ESCs report none
    /// (`motor_bidir_dshot` = 0).
    fn speeds_modelled(&self) -> bool {
        !self.speed_telemetry
    }

    /// The IMU offset for a new identification and where it came from.
    fn learner_offset(&self) -> ([f32; 3], ImuOffsetSource) {
        if let Some(r) = self.configured_offset_m {
            return (r, ImuOffsetSource::Configured);
        }
        let onboard = &self.results.imu_offset;
        if onboard.well_determined {
            (onboard.r_imu_m, ImuOffsetSource::Onboard)
        } else {
            ([0.0; 3], ImuOffsetSource::Zero)
        }
    }

    fn update_imu_offset(&mut self, sample: &LearnerSample) {
        let Some(estimator) = self.imu_offset.get_mut() else { return };
        // Samples missing from the stream (no IMU sample in a step, or dropped from a full
        // queue) would splice two stretches of data: tell the estimator about the gap.
        if let Some(previous) = self.previous_t_us.replace(sample.t_us) {
            let elapsed_us = sample.t_us.saturating_sub(previous);
            if elapsed_us > self.period_us + self.period_us / 2 {
                let missing = (elapsed_us + self.period_us / 2) / self.period_us - 1;
                estimator.gap(u32::try_from(missing).unwrap_or(u32::MAX));
            }
        }
        let imu = imu_offset::ImuSample {
            gyro_radps: Vector3::from(sample.imu.gyro_rad_s),
            acc_mps2: Vector3::from(sample.imu.accel_mps2),
        };
        // A rejected sample (corrupt values) only abandons the throw in progress.
        let rest_before = estimator.rest_progress();
        let accepted_throw = match estimator.update(&imu) {
            Ok(Some(segment)) => Some(segment),
            _ => None,
        };
        let status = &mut self.results.imu_offset;
        status.in_free_fall = estimator.in_free_fall();
        // The estimate changes with each throw and, after one, with each 50 ms of rest (the
        // craft held still after the catch tells the bias apart): the status follows both, so
        // that it is what `fit imu-offset` gives on the samples so far.
        let more_rest =
            estimator.rest_progress() != rest_before && !estimator.segments().is_empty();
        if accepted_throw.is_none() && !more_rest {
            return;
        }
        if let (Some(segment), Some(calibration)) = (accepted_throw, &mut self.results.calibration)
        {
            calibration.last_free_fall_ms =
                (u64::from(segment.len()) * self.period_us / 1000).min(65_535) as u16;
        }
        status.throws = u8::try_from(estimator.segments().len()).unwrap_or(u8::MAX);
        self.results.imu_offset_fitted_in_flight = false;
        match estimator.estimate() {
            Ok(estimate) => {
                status.estimated = true;
                status.r_imu_m = estimate.r_imu_m.into();
                status.ci95_semi_axes_m = estimate.ellipsoid.semi_axes_m;
                status.well_determined = matches!(estimate.verdict, Verdict::WellDetermined { .. });
                status.advice = advice(&estimate.verdict);
                if let Some(calibration) = &mut self.results.calibration {
                    calibration.acc_bias_mps2 = estimate.acc_bias_mps2.map(Into::into);
                }
            }
            // Never leave an earlier estimate on show as if it were current.
            Err(_) => {
                status.estimated = false;
                status.well_determined = false;
                status.advice = OffsetAdvice::None;
                status.r_imu_m = [0.0; 3];
                status.ci95_semi_axes_m = [0.0; 3];
                if let Some(calibration) = &mut self.results.calibration {
                    calibration.acc_bias_mps2 = None;
                }
            }
        }
        self.publish_offset_between_attempts();
    }

    fn publish_window(&mut self) {
        if self.gyro[0].count < 2 {
            return;
        }
        for axis in 0..3 {
            self.results.gyro_mean_rad_s[axis] = self.gyro[axis].mean;
            self.results.gyro_std_rad_s[axis] = self.gyro[axis].std();
            self.results.accel_mean_mps2[axis] = self.accel[axis].mean;
            self.results.accel_std_mps2[axis] = self.accel[axis].std();
        }
        self.results.stats_valid = true;
        self.gyro = Default::default();
        self.accel = Default::default();
    }
}

/// The estimator's verdict as advice on the wire.
fn advice(verdict: &Verdict<f32>) -> OffsetAdvice {
    let axis_index = |axis: imu_offset::ImuAxis| match axis {
        imu_offset::ImuAxis::X => 0,
        imu_offset::ImuAxis::Y => 1,
        imu_offset::ImuAxis::Z => 2,
    };
    match *verdict {
        Verdict::WellDetermined { .. } => OffsetAdvice::None,
        Verdict::PoorlyDetermined { direction_imu, spin_next_about, .. } => {
            OffsetAdvice::ThrowAgain {
                direction_imu: direction_imu.into(),
                spin_about_axis: axis_index(spin_next_about),
            }
        }
        Verdict::BiasNotSeparable { direction_imu, spin_next_about, .. } => {
            OffsetAdvice::BiasNotSeparable {
                direction_imu: direction_imu.into(),
                spin_about_axis: axis_index(spin_next_about),
            }
        }
        Verdict::BiasSuspected { .. } => OffsetAdvice::FitBias,
    }
}

/// The onboard estimator's configuration: the library defaults, which fit the accelerometer bias
/// jointly with the help of the rest poses (a real MEMS accelerometer carries up to 0.2 m/s²,
/// which otherwise shifts `r` by millimetres; see docs/benchmarks.md), exactly as
/// `fit imu-offset` does offline.
fn imu_offset_config() -> imu_offset::Config {
    imu_offset::Config::default()
}

/// Welford's running mean and variance (numerically stable in f32 over a few thousand samples).
#[derive(Clone, Copy, Debug, Default)]
struct RunningStats {
    count: u32,
    mean: f32,
    sum_sq_dev: f32,
}

impl RunningStats {
    fn add(&mut self, x: f32) {
        if !x.is_finite() {
            return;
        }
        self.count += 1;
        let delta = x - self.mean;
        self.mean += delta / self.count as f32;
        self.sum_sq_dev += delta * (x - self.mean);
    }

    /// Sample standard deviation.
    fn std(&self) -> f32 {
        if self.count < 2 {
            return 0.0;
        }
        libm::sqrtf(self.sum_sq_dev / (self.count - 1) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::super::hal::ImuSample;
    use super::super::queue::{split_queue, SampleQueue};
    use super::*;

    #[test]
    fn one_second_windows_recover_bias_and_noise_of_a_resting_imu() {
        let (bias_rad_s, noise_rad_s, accel_noise_mps2) = ([0.01, -0.02, 0.005], 0.002, 0.03);
        let mut queue = SampleQueue::new();
        let (mut producer, consumer) = split_queue(&mut queue);
        let mut fit_handoff = super::super::offset_fit::FitHandoff::new();
        let (fit_client, _fit_ends) = fit_handoff.split(2000.0);
        let mut background = Background::new(consumer, fit_client, 2000);
        let mut rng = flight::rng::Rng::new(0x2545_f491_4f6c_dd1d);
        // 2.5 s at 2 kHz: two full windows, the second one published when the third starts.
        for step in 0..5000u64 {
            let mut imu = ImuSample::default();
            for (axis, bias) in bias_rad_s.iter().enumerate() {
                imu.gyro_rad_s[axis] = bias + noise_rad_s * rng.normal() as f32;
                imu.accel_mps2[axis] = accel_noise_mps2 * rng.normal() as f32;
            }
            imu.accel_mps2[2] -= 9.81;
            producer.push(LearnerSample { t_us: step * 500, imu, ..Default::default() });
            background.run_pending();
        }
        let results = background.results();
        assert_eq!(results.samples_processed, 5000);
        assert!(results.stats_valid);
        for (axis, bias) in bias_rad_s.iter().enumerate() {
            // 2000 samples: the mean's standard error is 0.002/√2000 ≈ 4.5e-5 rad/s.
            assert!((results.gyro_mean_rad_s[axis] - bias).abs() < 2.5e-4);
            assert!((results.gyro_std_rad_s[axis] / noise_rad_s - 1.0).abs() < 0.08);
            assert!((results.accel_std_mps2[axis] / accel_noise_mps2 - 1.0).abs() < 0.08);
        }
        assert!((results.accel_mean_mps2[2] + 9.81).abs() < 0.01);
    }

    /// Whether the IMU-offset estimator saw the craft in free fall during 0.3 s of a free fall
    /// spinning at 5 rad/s after 0.6 s held still, with the phase, flying flag and commands
    /// of `powered` during the fall (and `settle_s` of motors off before it).
    fn free_fall_seen(powered: Option<(FlightPhase, bool, f32)>) -> bool {
        let mut queue = SampleQueue::new();
        let (mut producer, consumer) = split_queue(&mut queue);
        let mut fit_handoff = super::super::offset_fit::FitHandoff::new();
        let (fit_client, _fit_ends) = fit_handoff.split(2000.0);
        let mut background = Background::new(consumer, fit_client, 2000);
        let mut rng = flight::rng::Rng::new(7);
        let mut seen = false;
        for step in 0..1800u64 {
            let falling = step >= 1200;
            let noise = |rng: &mut flight::rng::Rng| 0.02 * rng.normal() as f32;
            let imu = ImuSample {
                gyro_rad_s: if falling { [5.0, 1.0, -0.5] } else { [0.0; 3] }
                    .map(|w| w + 0.001 * rng.normal() as f32),
                accel_mps2: if falling { [0.0; 3] } else { [0.0, 0.0, -9.81] }
                    .map(|a| a + noise(&mut rng)),
            };
            let mut sample =
                LearnerSample { t_us: step * 500, imu, motor_count: 4, ..Default::default() };
            if let (true, Some((phase, flying, command))) = (falling, powered) {
                sample.phase = phase;
                sample.flying = flying;
                sample.commands[..4].fill(command);
            }
            producer.push(sample);
            background.run_pending();
            seen |= background.results().imu_offset.in_free_fall;
        }
        seen
    }

    #[test]
    fn the_imu_offset_estimator_never_sees_a_powered_craft() {
        assert!(free_fall_seen(None), "an unpowered free fall is seen");
        for powered in [
            (FlightPhase::WaitingForThrow, false, 0.0),
            (FlightPhase::Released, false, 0.0),
            (FlightPhase::Exciting, false, 0.5),
            (FlightPhase::Done, true, 0.3),
            (FlightPhase::Idle, false, 0.1),
        ] {
            assert!(!free_fall_seen(Some(powered)), "{powered:?}");
        }
    }

    #[test]
    fn non_finite_samples_do_not_poison_the_statistics() {
        let mut stats = RunningStats::default();
        for x in [1.0, f32::NAN, 3.0, f32::INFINITY] {
            stats.add(x);
        }
        assert_eq!(stats.count, 2);
        assert_eq!(stats.mean, 2.0);
    }
}
