//! Throw-and-fly end to end: the firmware application (exactly as the board runs it) is armed,
//! thrown, identifies its actuators, and must recover to a hover and hold a position; scored
//! against the simulator's truth in metres, seconds and degrees.
//!
//! - [`fly`]: one run. The hand throws the craft on a parabola; after the excitation the
//!   firmware's controller takes over. With [`FlyConfig::mocap`] the simulator sends the true
//!   pose of the centre of gravity (position, heading) as a motion-capture system would
//!   ([`MotionCapture`]: by default 100 Hz with millimetre noise, on time; rate, jitter,
//!   latency, noise and dropouts in [`MotionCaptureConfig`]), through the same command the
//!   bridge and the protocol use.
//! - [`FlyReport`]: whether and when it hovered, the worst altitude loss below the release point,
//!   the position error over the hold, and how the run ended ([`Outcome`]).
//!
//! "Hovering" means: the body rate below [`HOVER_RATE_RAD_S`], the vertical speed below
//! [`HOVER_CLIMB_MPS`] and the thrust axis within [`HOVER_TILT_RAD`] of its equilibrium
//! direction in the current air, held for [`HOVER_HOLD_S`]. The equilibrium direction is the
//! thrust's that cancels gravity and the drag at the craft's current airspeed (the simulator's
//! truth: `VehicleModel::equilibrium_thrust_dir_ned`, its drag model and the board's wind of the
//! moment, turbulence included): straight up in still air, leaning into the wind when holding in
//! one. A craft holding in an 8 m/s wind must lean 17–27° (Monte Carlo seeds 7, 29, 40 of the
//! random world with `--wind`) and is recovered all the same; a fixed cone about up scored it as
//! never hovering.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::airframe::Airframe;
use crate::board::{SimBoard, SimConfig};
use crate::compass_feed::CompassFeed;
use crate::dynamics::State;
use crate::gnss::{GnssFeed, GnssModelConfig, GnssTruth};
use crate::hand::GrabSpec;
use crate::identification::{Scores, Throw, TrueModel};
use crate::magnetometer::MagnetometerSpec;
use crate::rng::Rng;
use crate::scenario::{with_firmware_app, FirmwareApp, FlightApp};
use firmware::app::{ControlCommand, ControlSettings, Failsafe, Param, Params, PoseConfig};
use firmware::drivers::crsf::StickInput;
use flight::learner::FlightPhase;
use protocol::{ExternalPose, LandReason};

/// Body rate below which the craft may count as hovering, rad/s (20 °/s).
pub const HOVER_RATE_RAD_S: f64 = 0.35;
/// Vertical speed below which the craft may count as hovering, m/s.
pub const HOVER_CLIMB_MPS: f64 = 0.3;
/// Angle of the true thrust axis from its equilibrium direction (up in still air, leaning into
/// a wind: module doc) below which the craft may count as hovering, rad (10°).
pub const HOVER_TILT_RAD: f64 = 0.175;
/// How long those must hold to call it a hover, s.
pub const HOVER_HOLD_S: f64 = 0.5;
/// Motion-capture rate by default, Hz (a typical optical system's; real ones run 30–500 Hz).
pub const MOCAP_RATE_HZ: f64 = 100.0;
/// Motion-capture position noise by default, one standard deviation per axis, m (optical motion
/// capture: about a millimetre; GNSS-like fixes: 0.5 m).
pub const MOCAP_NOISE_M: f64 = 0.001;
/// Motion-capture heading noise by default, one standard deviation, rad (0.1°).
pub const MOCAP_HEADING_NOISE_RAD: f64 = 0.0017;

/// What the simulated motion capture does; the default is the nominal system ([`MOCAP_RATE_HZ`],
/// [`MOCAP_NOISE_M`], [`MOCAP_HEADING_NOISE_RAD`], on time, evenly spaced, never lost), on which
/// every published figure was measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionCaptureConfig {
    /// Captures per second, Hz (1 to 2,000; above the control rate, one pose per control step
    /// at most arrives).
    pub rate_hz: f64,
    /// Each interval between captures is `1/rate_hz` plus a uniform draw in `±jitter_s`, s
    /// (0 to half the interval).
    pub jitter_s: f64,
    /// Time from a capture to its arrival at the board, s (0 to 0.1: processing and radio).
    pub latency_s: f64,
    /// Position noise, one standard deviation per axis, m (0 to 10).
    pub noise_m: f64,
    /// Heading noise, one standard deviation, rad (0 to 1).
    pub heading_noise_rad: f64,
    /// Dropouts per second of flight (Poisson; 0: never): the system loses the craft.
    pub dropouts_per_s: f64,
    /// How long each dropout lasts, s (0 to 60).
    pub dropout_s: f64,
}

impl Default for MotionCaptureConfig {
    fn default() -> Self {
        Self {
            rate_hz: MOCAP_RATE_HZ,
            jitter_s: 0.0,
            latency_s: 0.0,
            noise_m: MOCAP_NOISE_M,
            heading_noise_rad: MOCAP_HEADING_NOISE_RAD,
            dropouts_per_s: 0.0,
            dropout_s: 0.5,
        }
    }
}

impl MotionCaptureConfig {
    /// Check every field against its documented range; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        let check = |name: &str, value: f64, min: f64, max: f64| {
            if value.is_finite() && value >= min && value <= max {
                Ok(())
            } else {
                Err(format!("motion capture: {name} = {value} is outside {min}..={max}"))
            }
        };
        check("rate_hz", self.rate_hz, 1.0, 2000.0)?;
        check("jitter_s", self.jitter_s, 0.0, 0.5 / self.rate_hz)?;
        check("latency_s", self.latency_s, 0.0, 0.1)?;
        check("noise_m", self.noise_m, 0.0, 10.0)?;
        check("heading_noise_rad", self.heading_noise_rad, 0.0, 1.0)?;
        check("dropouts_per_s", self.dropouts_per_s, 0.0, 10.0)?;
        check("dropout_s", self.dropout_s, 0.0, 60.0)
    }
}

/// The motion capture on a command line (`fly`, `sitl`): the same fields as
/// [`MotionCaptureConfig`] in the units a user thinks in; the defaults are the nominal system.
#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct MotionCaptureArgs {
    /// Motion capture: poses per second, Hz (1–2000).
    #[arg(long, global = true, default_value_t = MOCAP_RATE_HZ)]
    pub mocap_rate_hz: f64,
    /// Motion capture: each interval between poses varies by up to ± this, ms (at most half
    /// the interval).
    #[arg(long, global = true, default_value_t = 0.0)]
    pub mocap_jitter_ms: f64,
    /// Motion capture: time from a capture to its arrival at the board, ms (0–100).
    #[arg(long, global = true, default_value_t = 0.0)]
    pub mocap_latency_ms: f64,
    /// Motion capture: position noise, one standard deviation per axis, mm (0–10000).
    #[arg(long, global = true, default_value_t = MOCAP_NOISE_M * 1e3)]
    pub mocap_noise_mm: f64,
    /// Motion capture: heading noise, one standard deviation, degrees.
    #[arg(long, global = true, default_value_t = 0.1)]
    pub mocap_heading_noise_deg: f64,
    /// Motion capture: dropouts per second (Poisson; 0: never), each `--mocap-dropout-s` long.
    #[arg(long, global = true, default_value_t = 0.0)]
    pub mocap_dropouts_per_s: f64,
    /// Motion capture: how long a dropout lasts, s.
    #[arg(long, global = true, default_value_t = 0.5)]
    pub mocap_dropout_s: f64,
}

impl MotionCaptureArgs {
    /// The configuration, checked ([`MotionCaptureConfig::validate`]). The default heading noise
    /// of 0.1° is exactly [`MOCAP_HEADING_NOISE_RAD`].
    pub fn config(&self) -> Result<MotionCaptureConfig, String> {
        let heading_noise_rad = if self.mocap_heading_noise_deg == 0.1 {
            MOCAP_HEADING_NOISE_RAD
        } else {
            self.mocap_heading_noise_deg.to_radians()
        };
        let config = MotionCaptureConfig {
            rate_hz: self.mocap_rate_hz,
            jitter_s: self.mocap_jitter_ms * 1e-3,
            latency_s: self.mocap_latency_ms * 1e-3,
            noise_m: self.mocap_noise_mm * 1e-3,
            heading_noise_rad,
            dropouts_per_s: self.mocap_dropouts_per_s,
            dropout_s: self.mocap_dropout_s,
        };
        config.validate().map(|()| config)
    }
}

/// A motion-capture system: the true pose of the centre of gravity (world NED position, heading
/// of the body frame) captured at [`MotionCaptureConfig::rate_hz`] (with jitter), with Gaussian
/// noise, delivered [`MotionCaptureConfig::latency_s`] after its capture, and lost for a while
/// now and then, as the throw-and-fly runs, the SITL's `--mocap` and the bridge tests send it.
/// Seeded: the same seed gives the same poses; the default configuration draws exactly the
/// noise it always drew (timing and dropouts have their own generator).
#[derive(Clone, Debug)]
pub struct MotionCapture {
    config: MotionCaptureConfig,
    rng: Rng,
    timing_rng: Rng,
    /// First capture, µs; the captures follow at `1/rate_hz` from it (plus jitter).
    first_us: Option<u64>,
    /// Time of the next capture, s after the first.
    next_s: f64,
    /// Captured poses on their way: (arrival time µs, pose).
    in_flight: std::collections::VecDeque<(u64, ExternalPose)>,
    /// The craft is lost until this time, µs.
    lost_until_us: u64,
}

impl MotionCapture {
    /// The nominal system ([`MotionCaptureConfig::default`]) whose noise is drawn from `seed`.
    pub fn new(seed: u64) -> Self {
        Self::with_config(MotionCaptureConfig::default(), seed)
    }

    /// A system configured by `config` (assumed valid: [`MotionCaptureConfig::validate`]).
    pub fn with_config(config: MotionCaptureConfig, seed: u64) -> Self {
        Self {
            config,
            rng: Rng::new(seed ^ 0x6d_6f63_6170),
            timing_rng: Rng::new(seed ^ 0x7469_6d69_6e67),
            first_us: None,
            next_s: 0.0,
            in_flight: std::collections::VecDeque::new(),
            lost_until_us: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &MotionCaptureConfig {
        &self.config
    }

    /// Call once per simulation tick with the true state at `now_us`: captures when one is due,
    /// and returns the pose that arrives now (the oldest due, if several).
    pub fn sample(&mut self, state: &State, now_us: u64) -> Option<ExternalPose> {
        let first_us = *self.first_us.get_or_insert(now_us);
        let since_first_s = now_us.saturating_sub(first_us) as f64 * 1e-6;
        if since_first_s + 1e-9 >= self.next_s {
            let c = self.config;
            let interval_s = 1.0 / c.rate_hz;
            let spread = if c.jitter_s > 0.0 {
                (2.0 * self.timing_rng.uniform() - 1.0) * c.jitter_s
            } else {
                0.0
            };
            // Never two captures in one tick, and never falling behind the grid.
            self.next_s = (self.next_s + interval_s + spread).max(since_first_s + 1e-6);
            if c.dropouts_per_s > 0.0
                && now_us >= self.lost_until_us
                && self.timing_rng.uniform() < 1.0 - (-c.dropouts_per_s * interval_s).exp()
            {
                self.lost_until_us = now_us + (c.dropout_s * 1e6) as u64;
            }
            if now_us >= self.lost_until_us {
                let pose = self.capture(state);
                let arrival_us = now_us + (c.latency_s * 1e6).round() as u64;
                self.in_flight.push_back((arrival_us, pose));
            }
        }
        match self.in_flight.front() {
            Some((arrival_us, _)) if *arrival_us <= now_us => {
                self.in_flight.pop_front().map(|(_, pose)| pose)
            }
            _ => None,
        }
    }

    fn capture(&mut self, state: &State) -> ExternalPose {
        let (sigma, sigma_heading) = (self.config.noise_m, self.config.heading_noise_rad);
        let p = state.position_ned_m;
        let rng = &mut self.rng;
        let mut noisy = |value: f64, sigma: f64| (value + rng.normal() * sigma) as f32;
        ExternalPose {
            position_ned_m: [noisy(p.x, sigma), noisy(p.y, sigma), noisy(p.z, sigma)],
            heading_rad: noisy(heading(&state.attitude()), sigma_heading),
        }
    }
}

/// One throw-and-fly run.
#[derive(Clone, Debug, PartialEq)]
pub struct FlyConfig {
    /// The throw.
    pub throw: Throw,
    /// Give the firmware the true IMU offset (a calibrated board).
    pub known_imu_offset: bool,
    /// Send the pose from motion capture ([`FlyConfig::motion_capture`]).
    pub mocap: bool,
    /// The motion capture (rate, jitter, latency, noise, dropouts).
    pub motion_capture: MotionCaptureConfig,
    /// The hold error is measured over the last this many seconds of the flight, s (at most
    /// 80 % of `flight_s`).
    pub hold_window_s: f64,
    /// How long to fly after the release, s.
    pub flight_s: f64,
    /// Print the flight every 100 ms on stderr (time, position, setpoint, rates, mode).
    pub trace: bool,
    /// Board (noise seed, start position).
    pub board: SimConfig,
    /// Whether the ESCs report their speeds (bidirectional DShot). `false`: the simulated ESCs
    /// answer nothing and the application is told so, as a user would set it, through
    /// `motor_bidir_dshot` = 0 (issue 32: identification without speed telemetry).
    pub speed_telemetry: bool,
    /// How the flight ends after `flight_s`: it goes on hovering (the run stops there), or it
    /// lands ([`FlightEnd`]).
    pub end: FlightEnd,
    /// The pilot's sticks, each set at a time after the release, s, as the receiver hands them
    /// to the control step ([`ControlCommand::Sticks`]); the run then records
    /// [`FlyReport::stick_trace`].
    pub sticks: Vec<(f64, StickInput)>,
    /// How the hand grabs the craft when the flight ends with [`FlightEnd::Catch`].
    pub grab: GrabSpec,
    /// A GNSS receiver instead of motion capture (`mocap` is then ignored): its NAV-PVT bytes
    /// go through the firmware's own receiver code (`firmware::app::gnss::GnssInput`), which
    /// is told the receiver's latency as a user would set it, and each solution reaches the
    /// control step as a position fix without heading.
    pub gnss: Option<GnssModelConfig>,
    /// A compass on the craft, its field, iron, mounting, noise and motor interference
    /// (`crate::magnetometer`; the random world's `compass` aspect draws it): calibrated by
    /// the user's dance before the flight and read by the firmware's compass service
    /// (`crate::compass_feed`).
    pub compass: Option<MagnetometerSpec>,
}

/// One sample of a flight flown from the sticks ([`FlyConfig::sticks`]), against the truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StickSample {
    /// Time since the first stick command, s.
    pub t_s: f64,
    /// The true hover thrust axis's tilt from up, degrees, and its direction's bearing, degrees
    /// (the way the thrust leans, clockwise from north).
    pub tilt_deg: f64,
    pub lean_bearing_deg: f64,
    /// Horizontal distance from where the craft was at the first stick command, m.
    pub distance_m: f64,
    /// Height above that point, m.
    pub climb_m: f64,
}

/// How a run's flight ends once its `flight_s` are flown.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FlightEnd {
    /// Nothing: the run stops, the craft still hovering.
    #[default]
    Hover,
    /// A landing for this reason, as the control step receives it
    /// ([`ControlCommand::Land`]): `Commanded` is a host's `land`, `RcLost` what the pilot's
    /// receiver asks for once the radio has been lost for its grace in flight
    /// (`firmware::app::radio`).
    Land(LandReason),
    /// A hand grabs the hovering craft ([`FlyConfig::grab`]) and holds it: the firmware's
    /// hand-catch detector should stop the motors (`firmware::app::catch`).
    Catch,
}

impl FlightEnd {
    /// `hover`, `land`, `rc-lost` or `catch`.
    pub fn parse(name: &str) -> Result<Self, String> {
        match name {
            "hover" => Ok(Self::Hover),
            "land" => Ok(Self::Land(LandReason::Commanded)),
            "rc-lost" => Ok(Self::Land(LandReason::RcLost)),
            "catch" => Ok(Self::Catch),
            other => Err(format!("unknown flight end `{other}` (hover, land, rc-lost, catch)")),
        }
    }
}

/// How long a run goes on after the hand grabbed the craft, s: ten times the detector's
/// 0.3 s, so a late detection is measured rather than cut off.
pub const CATCH_TIMEOUT_S: f64 = 3.0;

/// Longest time from the grab to the motors stopped the issue allows, s.
pub const CATCH_DETECT_MAX_S: f64 = 0.3;

/// How a hand's grab went ([`FlightEnd::Catch`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CatchReport {
    /// The grab ([`FlyConfig::grab`]).
    pub grab: GrabSpec,
    /// Time from the grab to the motors stopped by the hand-catch detector, s (`None`: not
    /// within [`CATCH_TIMEOUT_S`]).
    pub stopped_after_s: Option<f64>,
}

/// Longest a landing may take from its request to the motors stopping, s: the Monte Carlo's
/// highest hovers (about 8 m above the ground) take 16 s at the default 0.5 m/s; four times
/// that leaves room for a slow start and the touchdown's confirmation.
pub const LANDING_TIMEOUT_S: f64 = 60.0;

/// Largest vertical speed of a gentle touchdown, m/s (the 0.7 m/s).
pub const GENTLE_TOUCHDOWN_MPS: f64 = 0.7;

/// Longest time from the touchdown to the motors stopped for a gentle landing, s (the issue's
/// second).
pub const STOP_AFTER_TOUCHDOWN_S: f64 = 1.0;

/// How a landing went, against the simulator's truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LandingReport {
    /// Height of the CoG above the ground when the landing was asked for, m.
    pub requested_height_m: f64,
    /// Vertical speed at the first ground contact (a landing-gear foot reaching NED z = 0),
    /// m/s, positive down.
    pub touchdown_speed_mps: Option<f64>,
    /// Time from the first ground contact to the motors stopped (the firmware disarmed), s.
    pub stop_delay_s: Option<f64>,
    /// Height at which the motors stopped before any ground contact, m (a touchdown detected in
    /// the air: the craft then falls).
    pub stopped_in_air_m: Option<f64>,
    /// Horizontal distance from where the landing was asked for to the touchdown, m.
    pub horizontal_drift_m: Option<f64>,
}

impl LandingReport {
    /// Down within [`GENTLE_TOUCHDOWN_MPS`], motors stopped within [`STOP_AFTER_TOUCHDOWN_S`].
    pub fn gentle(&self) -> bool {
        self.touchdown_speed_mps.is_some_and(|v| v < GENTLE_TOUCHDOWN_MPS)
            && self.stop_delay_s.is_some_and(|t| t <= STOP_AFTER_TOUCHDOWN_S)
    }
}

impl FlyConfig {
    /// The seed paper's experiment: a 3.5 m parabola released at (400, 400, 100) °/s from 1.5 m,
    /// motion capture on, 13 s of flight.
    pub fn paper() -> Self {
        Self {
            throw: Throw::paper(),
            known_imu_offset: true,
            mocap: true,
            motion_capture: MotionCaptureConfig::default(),
            hold_window_s: 10.0,
            flight_s: 13.0,
            trace: false,
            board: SimConfig {
                start_position_ned_m: Vector3::new(0.0, 0.0, -1.5),
                ..SimConfig::default()
            },
            speed_telemetry: true,
            end: FlightEnd::Hover,
            sticks: Vec::new(),
            grab: GrabSpec::default(),
            gnss: None,
            compass: None,
        }
    }
}

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Still flying at the end.
    Flying,
    /// Hit the ground (NED z ≥ 0).
    Ground,
    /// The firmware stopped the motors with this failsafe.
    Failsafe(Failsafe),
    /// The throw was never detected or the excitation never ended.
    NoIdentification,
    /// Landed as asked ([`FlyConfig::end`]): the motors stopped on the ground
    /// ([`FlyReport::landing`] says how gently).
    Landed,
    /// The firmware's hand-catch detector stopped the motors (`LandReason::Caught`): after the
    /// hand's grab ([`FlyReport::catch`]) as it should, or in free flight (a false catch).
    Caught,
}

/// What a run measured.
#[derive(Clone, Debug, PartialEq)]
pub struct FlyReport {
    pub outcome: Outcome,
    /// Release → the controller engaged, s.
    pub release_to_engage_s: Option<f64>,
    /// The excitation's end → the controller engaged, s: 0 but for the wait for a model still
    /// learning from the excitation (without speed telemetry: `ENGAGE_WAIT_MAX_S`).
    pub excitation_end_to_engage_s: Option<f64>,
    /// Release → hovering (see the module docs), s.
    pub release_to_hover_s: Option<f64>,
    /// Height of the release point, NED z, m.
    pub release_z_m: f64,
    /// Largest depth below the release point after it, m (positive: lower).
    pub max_drop_below_release_m: f64,
    /// The position setpoint the firmware held, NED, m.
    pub setpoint_ned_m: Option<Vector3<f64>>,
    /// Largest distance from the setpoint over the last `hold_window_s`, m.
    pub max_hold_error_m: Option<f64>,
    /// The same, horizontally (a GNSS fix's vertical error is 1.5–2.5 times its horizontal), m.
    pub max_hold_error_horizontal_m: Option<f64>,
    /// The largest horizontal error of the receiver's own solutions over the same steps, m
    /// (`None` without a receiver): the part of `max_hold_error_horizontal_m` no controller
    /// can take out.
    pub max_fix_error_horizontal_m: Option<f64>,
    /// The window over which `max_hold_error_m` was measured, s.
    pub hold_window_s: f64,
    /// Fraction of that window's steps flown in position hold (1: held throughout).
    pub hold_coverage: f64,
    /// RMS of the body rate's norm over the window's steps in position hold, rad/s: how calmly
    /// the craft holds (the attitude loops flying the estimate's noise show here first).
    pub hold_rate_rms_rad_s: Option<f64>,
    /// `PoseLost` failsafes counted over the run.
    pub pose_lost: u16,
    /// Position fixes the firmware refused as outliers (`flight::navigation::OUTLIER_SIGMAS`).
    pub fixes_rejected: u32,
    /// When the firmware first trusted a heading alignment, s after the release.
    pub heading_aligned_s: Option<f64>,
    /// The error of the firmware's heading (the yaw of its world against the true one) at the
    /// last step it flew aligned before any landing, degrees, signed.
    pub heading_error_deg: Option<f64>,
    /// Relative RMS error of the specific-force and angular-acceleration blocks of G1 against
    /// the truth ([`Scores::g1_block_rel`]): the learner's model when the controller engaged,
    /// the learner's model at the end (refined in flight) and the model flown at the end.
    pub g1_block_rel_at_engage: Option<[f64; 2]>,
    pub g1_block_rel_learned_at_end: Option<[f64; 2]>,
    pub g1_block_rel_flown_at_end: Option<[f64; 2]>,
    /// Models the flying controller moved towards (`PilotStatus::refinements`).
    pub refinements: u32,
    /// Controllers formed afresh in flight on a thrust axis that moved (`PilotStatus::reforms`).
    pub reforms: u32,
    /// The firmware's attitude (`PilotStatus::q_world_imu`) against the truth, degrees: the
    /// angle between its down and the true down (tilt) and its yaw error about the vertical
    /// (heading), when the controller engaged and when the hold window began.
    pub attitude_error_at_engage_deg: Option<[f64; 2]>,
    /// When the controller engaged, against the truth: the height of the centre of gravity
    /// above the ground (m), its vertical speed (m/s, positive down) and the angle of the true
    /// thrust axis from up (degrees): how much fall the recovery had to stop, and in what height.
    pub engaged_height_m: Option<f64>,
    pub engaged_descent_mps: Option<f64>,
    pub engaged_axis_from_up_deg: Option<f64>,
    pub attitude_error_at_window_deg: Option<[f64; 2]>,
    /// Angle between the learned and the true hover thrust direction, degrees
    /// ([`Scores::axis_angle_rad`]): the learner's model when the controller engaged and at the
    /// end of the flight (after its refinement in flight).
    pub axis_error_at_engage_deg: Option<f64>,
    pub axis_error_at_end_deg: Option<f64>,
    /// When the controller engaged on the learner's last resort, a thrust axis whose hover
    /// leaves the motor bounds (`LearnedThrustAxis::clamped_by`): by how much, normalised thrust.
    pub engaged_clamped_by: Option<f64>,
    /// The true IMU offset, IMU axes, m.
    pub r_imu_true_m: Vector3<f64>,
    /// The IMU offset fitted in flight (`imu_offset::in_flight`, run when the offset is not
    /// given: [`FlyConfig::known_imu_offset`] false) at the end of the run, with its 95 %
    /// ellipsoid's largest semi-axis, m.
    pub r_imu_fit_m: Option<Vector3<f64>>,
    pub r_imu_fit_semi_axis_m: Option<f64>,
    /// The fitted offset's covariance, m² (IMU axes).
    pub r_imu_fit_covariance_m2: Option<Matrix3<f64>>,
    /// The learner's G1 at the end ([`FlyReport::g1_block_rel_learned_at_end`]) with its force
    /// rows corrected by the fitted offset: a learner given `r₀` learns `G1f − [r − r₀]× G1τ`
    /// (`imu_offset::in_flight`), so `G1f ≈ G1f₀ + [r̂ − r₀]× G1τ`.
    pub g1_block_rel_corrected_by_fit: Option<[f64; 2]>,
    /// The same with the force rows the offset fit found jointly with the offset.
    pub g1_block_rel_fitted_jointly: Option<[f64; 2]>,
    /// The learner's model at the end of the excitation (when the controller engages or the
    /// identification fails; without speed telemetry, once it has learned from the whole
    /// excitation), per unit normalised thrust ([`thrust_scores`]): comparable with
    /// and without speed telemetry, whose speeds have an arbitrary scale, and over every run
    /// that identified, hovered or not.
    pub thrust_scores_at_excitation_end: Option<Scores>,
    /// The landing, when the run asked for one and the craft was flying then.
    pub landing: Option<LandingReport>,
    /// A landing the firmware began by itself before the run asked for one (a fly-away, the
    /// pose lost too long), and when, s after the release.
    pub landed_by_itself: Option<(LandReason, f64)>,
    /// With [`FlyConfig::sticks`]: the flight every 10 ms from the first stick command on.
    pub stick_trace: Vec<StickSample>,
    /// After the craft recovered ([`FlyReport::release_to_hover_s`]) and until a landing began
    /// or the flight ended: its fastest horizontal speed, m/s, and its horizontal distance from
    /// where it recovered at the end, m (the issue's "no craft with a fresh pose ends more than
    /// 2 m from where it recovered").
    pub max_speed_after_recovery_mps: Option<f64>,
    pub end_from_recovery_m: Option<f64>,
    /// The hand's grab, when the run ended with one ([`FlightEnd::Catch`]).
    pub catch: Option<CatchReport>,
    /// The hand-catch detector stopped the motors without a hand, s after the release.
    pub false_catch_s: Option<f64>,
}

/// Scores of `learned` per unit normalised thrust `u = ω²/ω_full²` (the papers' convention and
/// the thrust-axis problem's): its G1 per unit thrust, moved into the truth's per-squared-speed
/// units with the true full speeds, against the truth. Without speed telemetry the learner's
/// speeds are modelled in units of its own (`flight::learner::no_speed`), so only this
/// comparison means anything there; with telemetry it differs from [`Scores::of`] by the error
/// of the learned `ω_full`.
pub fn thrust_scores(learned: &flight::learner::LearnedModel, truth: &TrueModel) -> Scores {
    let mut per_true_speed2 = *learned;
    per_true_speed2.g1_per_speed2 = learned.g1_per_unit_thrust();
    for i in 0..truth.motors {
        let full2 = truth.omega_full_rad_s[i].powi(2);
        for row in per_true_speed2.g1_per_speed2.iter_mut() {
            row[i] = (f64::from(row[i]) / full2) as f32;
        }
    }
    Scores::of(&per_true_speed2, truth)
}

/// Tilt and heading error, degrees, of the firmware's `q_world_imu` (w, x, y, z) against the
/// true world ← IMU attitude `q_true`.
fn attitude_error_deg(q_world_imu: [f32; 4], q_true: &UnitQuaternion<f64>) -> [f64; 2] {
    let [w, x, y, z] = q_world_imu.map(f64::from);
    let q_filter = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    let down_true = q_true.inverse() * Vector3::z();
    let down_filter = q_filter.inverse() * Vector3::z();
    let heading_error = heading(&(q_true * q_filter.inverse()));
    [down_true.angle(&down_filter).to_degrees(), heading_error.to_degrees()]
}

/// The thrust-axis error of `scores`, degrees, when the learner found an axis.
fn axis_error_deg(scores: &Scores) -> Option<f64> {
    scores.axis_found.then(|| scores.axis_angle_rad.to_degrees())
}

/// G1 of the model `app` flies, back in the learner's terms (IMU axes, per squared speed),
/// scored against `truth`.
fn flown_scores(app: &FirmwareApp<'_>, truth: &TrueModel) -> Option<[f64; 2]> {
    let flown = app.control.control().flown_model()?;
    let mut learned = app.background.results().learned;
    for j in 0..flown.motors {
        let full2 = flown.motor[j].omega_full_rad_s().powi(2);
        for block in 0..2 {
            let column = flown.q_imu_thrust
                * nalgebra::Vector3::from_fn(|k, _| flown.g1[3 * block + k][j] / full2);
            for k in 0..3 {
                learned.g1_per_speed2[3 * block + k][j] = column[k];
            }
        }
    }
    Some(Scores::of(&learned, truth).g1_block_rel)
}

/// Fly `airframe` once.
pub fn fly(airframe: &Airframe, config: &FlyConfig) -> FlyReport {
    let truth = TrueModel::of(airframe);
    // The true hover thrust direction in body axes.
    let thrust_dir_body =
        airframe.q_imu_body().inverse() * (truth.q_thrust_to_imu * Vector3::new(0.0, 0.0, -1.0));
    let mut board = SimBoard::new(airframe, &config.board);
    let hold_window_s = config.hold_window_s.min(config.flight_s * 0.8);
    with_firmware_app(|app| {
        // The user's parameters, set once: how old their ESCs' speed reports are
        // (`motor_speed_age_s`; the nominal board's is the default), and for ESCs without
        // bidirectional DShot that no speed reaches the board (`motor_bidir_dshot` = 0: the
        // control step then arms without speeds, `Params::arms_without_speeds`, and the learner
        // models them from the commands, where no report's age means anything).
        let mut user_params = Params::default();
        let speed_age_s = airframe.rotor_motor(0).telemetry_delay_s as f32;
        let mut changed = user_params.set(Param::MotorSpeedAgeS as usize, &[speed_age_s]).is_ok()
            && speed_age_s != flight::learner::DEFAULT_SPEED_AGE_S;
        if !config.speed_telemetry {
            board.motors_mut().set_bidirectional(false);
            changed |= user_params.set(Param::MotorBidirDshot as usize, &[0.0]).is_ok();
        }
        // A compass: the user's calibration dance before the flight, and the local declination
        // (`crate::compass_feed`); a refused dance leaves the craft without one.
        let mut compass = config.compass.as_ref().and_then(|spec| {
            let feed = CompassFeed::new(spec, config.board.seed).ok()?;
            let declination = [feed.declination_deg()];
            changed |= user_params.set(Param::CompassDeclinationDeg as usize, &declination).is_ok();
            Some(feed)
        });
        let user_settings = ControlSettings::from(&user_params);
        if changed {
            app.background.configure(&user_params);
            app.submit(ControlCommand::Configure(user_settings));
        }
        if config.known_imu_offset {
            let r = truth.r_imu_m;
            app.background.set_imu_offset(Some([r.x as f32, r.y as f32, r.z as f32]));
        } else {
            app.background.set_offset_fit(true);
        }
        // The firmware is told what the poses are, as a user sets `pose_latency_s` and
        // `pose_noise_m` for their system (the nominal system is the parameters' default).
        let pose = PoseConfig {
            latency_s: config.motion_capture.latency_s as f32,
            noise_m: (config.motion_capture.noise_m as f32).max(1e-4),
        };
        if config.mocap && pose != PoseConfig::default() {
            let settings = ControlSettings { pose, ..user_settings };
            app.submit(ControlCommand::Configure(settings));
        }
        app.submit(ControlCommand::ArmThrowToFly);
        let mut report = FlyReport {
            outcome: Outcome::NoIdentification,
            release_to_engage_s: None,
            excitation_end_to_engage_s: None,
            release_to_hover_s: None,
            release_z_m: 0.0,
            max_drop_below_release_m: 0.0,
            setpoint_ned_m: None,
            max_hold_error_m: None,
            max_hold_error_horizontal_m: None,
            max_fix_error_horizontal_m: None,
            hold_window_s,
            hold_coverage: 0.0,
            hold_rate_rms_rad_s: None,
            pose_lost: 0,
            fixes_rejected: 0,
            heading_aligned_s: None,
            heading_error_deg: None,
            g1_block_rel_at_engage: None,
            g1_block_rel_learned_at_end: None,
            g1_block_rel_flown_at_end: None,
            refinements: 0,
            reforms: 0,
            attitude_error_at_engage_deg: None,
            engaged_height_m: None,
            engaged_descent_mps: None,
            engaged_axis_from_up_deg: None,
            attitude_error_at_window_deg: None,
            axis_error_at_engage_deg: None,
            engaged_clamped_by: None,
            axis_error_at_end_deg: None,
            r_imu_true_m: truth.r_imu_m,
            r_imu_fit_m: None,
            r_imu_fit_semi_axis_m: None,
            r_imu_fit_covariance_m2: None,
            g1_block_rel_corrected_by_fit: None,
            g1_block_rel_fitted_jointly: None,
            thrust_scores_at_excitation_end: None,
            landing: None,
            landed_by_itself: None,
            stick_trace: Vec::new(),
            max_speed_after_recovery_mps: None,
            end_from_recovery_m: None,
            catch: None,
            false_catch_s: None,
        };
        // Where the craft recovered, NED, m.
        let mut recovered_ned_m: Option<Vector3<f64>> = None;
        let mut sticks = config.sticks.iter().peekable();
        let mut sticks_from: Option<(f64, Vector3<f64>)> = None;
        let hold_ticks = 1000u64; // 0.5 s in the hand
        let spec = config.throw.spec();
        let mut mocap = (config.mocap && config.gnss.is_none())
            .then(|| MotionCapture::with_config(config.motion_capture, config.board.seed));
        let mut gnss = config.gnss.as_ref().map(|model| GnssFeed::new(model, config.board.seed));
        let (mut window_steps, mut window_hold_steps) = (0u64, 0u64);
        // The body rate's squares over the window's steps in position hold, and their count.
        let (mut window_rate_sum2, mut window_rate_steps) = (0.0f64, 0u64);
        let mut hover_since: Option<f64> = None;
        let mut release_z: Option<f64> = None;
        // When the excitation ended (the phase became `Done`), s.
        let mut excitation_end_s: Option<f64> = None;
        let mut end_s = f64::INFINITY;
        // A landing: where it was asked for, and the time of the first ground contact, s.
        let mut land_from_ned_m = Vector3::zeros();
        let mut touchdown_s: Option<f64> = None;
        let landing_s = match config.end {
            FlightEnd::Hover => 0.0,
            FlightEnd::Land(_) => LANDING_TIMEOUT_S,
            FlightEnd::Catch => CATCH_TIMEOUT_S,
        };
        let mut grab_s: Option<f64> = None;
        let max_ticks = hold_ticks + ((1.0 + config.flight_s + landing_s) * 2000.0) as u64;
        for tick in 0..max_ticks {
            if tick == hold_ticks {
                board.physics_mut().throw(&spec);
            }
            board.tick();
            let now_us = board.now_us();
            // `pose_lost`: fault injection (`SimConfig::faults`), never without faults.
            if let Some(pose) = mocap
                .as_mut()
                .and_then(|m| m.sample(board.physics().state(), now_us))
                .filter(|_| !board.pose_lost())
            {
                app.command(ControlCommand::ExternalPose(pose), now_us);
            }
            if let Some(feed) = &mut gnss {
                let state = board.physics().state();
                let truth = GnssTruth {
                    position_ned_m: state.position_ned_m,
                    velocity_ned_mps: state.velocity_ned_mps,
                };
                if let Some(fix) = feed.step(board.time_s(), &truth, now_us) {
                    app.command(ControlCommand::PositionFix(fix), now_us);
                }
            }
            if let Some(feed) = &mut compass {
                let q_world_imu =
                    board.physics().state().attitude() * airframe.q_imu_body().inverse();
                let thrust: Vec<f64> =
                    board.motors().commands().iter().map(|&u| f64::from(u)).collect();
                if let Some(sample) = feed.step(board.time_s(), &q_world_imu, &thrust, now_us) {
                    app.command(ControlCommand::MagneticField(sample), now_us);
                }
            }
            {
                let (imu, motors) = board.ports();
                app.step(now_us, imu, motors);
            }
            let t_s = board.time_s();
            let snapshot = app.snapshot();
            let state = *board.physics().state();
            if snapshot.phase == FlightPhase::Done {
                excitation_end_s.get_or_insert(t_s);
            }
            let learned = &app.background.results().learned;
            // Without speed telemetry the model is the one engaged on once it has learned from
            // the whole excitation (`LearnedModel::pending`).
            if snapshot.phase == FlightPhase::Done
                && (!learned.pending || snapshot.pilot.flying)
                && report.thrust_scores_at_excitation_end.is_none()
            {
                report.thrust_scores_at_excitation_end = Some(thrust_scores(learned, &truth));
            }
            let Some(released_s) = board.physics().hand().released_at_s() else { continue };
            let release_z_m = *release_z.get_or_insert(state.position_ned_m.z);
            report.release_z_m = release_z_m;
            let since_release = t_s - released_s;
            report.max_drop_below_release_m =
                report.max_drop_below_release_m.max(state.position_ned_m.z - report.release_z_m);
            if snapshot.pilot.heading_aligned && report.landing.is_none() {
                report.heading_aligned_s.get_or_insert(since_release);
                let q_true = state.attitude() * airframe.q_imu_body().inverse();
                let [w, x, y, z] = snapshot.pilot.q_world_imu.map(f64::from);
                let q_pilot =
                    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
                report.heading_error_deg =
                    Some(heading(&(q_true * q_pilot.inverse())).to_degrees());
            }
            if config.trace && tick % 200 == 0 {
                let p = snapshot.pilot;
                // The true yaw between the filter's world and the world.
                let q_true = state.attitude() * airframe.q_imu_body().inverse();
                let [w, x, y, z] = p.q_world_imu.map(f64::from);
                let q_filter =
                    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
                let true_alignment = heading(&(q_true * q_filter.inverse()));
                let down_true = q_true.inverse() * Vector3::z();
                let down_filter = q_filter.inverse() * Vector3::z();
                eprint!("filter tilt err {:5.2}°  ", down_true.angle(&down_filter).to_degrees());
                let up_ned = state.attitude() * thrust_dir_body;
                eprint!("axis from up {:5.1}°  ", (-up_ned.z).clamp(-1.0, 1.0).acos().to_degrees());
                eprint!(
                    "true align {:6.1}°  f_sp {:5.2} {:5.2} {:5.2}  ",
                    true_alignment.to_degrees(),
                    p.specific_force_sp_ned_mps2[0],
                    p.specific_force_sp_ned_mps2[1],
                    p.specific_force_sp_ned_mps2[2]
                );
                eprintln!(
                    "t {:6.2} s  pos {:6.2} {:6.2} {:6.2} m  vel {:5.2} {:5.2} {:5.2} m/s  rate {:6.1} °/s ({:6.1} {:6.1} {:6.1})  \
                     flying {} hold {} aligned {} {:5.1}° compass {} sp {:5.2} {:5.2} {:5.2}  est {:5.2} {:5.2} {:5.2}  tilt err {:5.1}°  sat {:04b}",
                    since_release,
                    state.position_ned_m.x, state.position_ned_m.y, state.position_ned_m.z,
                    state.velocity_ned_mps.x, state.velocity_ned_mps.y, state.velocity_ned_mps.z,
                    state.rate_body_rad_s.norm().to_degrees(),
                    state.rate_body_rad_s.x.to_degrees(),
                    state.rate_body_rad_s.y.to_degrees(),
                    state.rate_body_rad_s.z.to_degrees(),
                    p.flying, p.position_hold, p.heading_aligned, p.heading_alignment_rad.to_degrees(),
                    p.compass_heading, p.position_sp_ned_m[0], p.position_sp_ned_m[1], p.position_sp_ned_m[2],
                    p.velocity_ned_mps[0], p.velocity_ned_mps[1], p.velocity_ned_mps[2],
                    p.tilt_error_rad.to_degrees(), p.saturated,
                );
            }
            while let Some(&&(at_s, input)) = sticks.peek() {
                if since_release < at_s {
                    break;
                }
                sticks.next();
                app.command(ControlCommand::Sticks(Some(input)), now_us);
                sticks_from.get_or_insert((t_s, state.position_ned_m));
            }
            if let Some((from_s, from_ned_m)) = sticks_from {
                if tick % 20 == 0 {
                    let up = state.attitude() * thrust_dir_body;
                    let offset = state.position_ned_m - from_ned_m;
                    report.stick_trace.push(StickSample {
                        t_s: t_s - from_s,
                        tilt_deg: (-up.z).clamp(-1.0, 1.0).acos().to_degrees(),
                        lean_bearing_deg: up.y.atan2(up.x).to_degrees(),
                        distance_m: offset.xy().norm(),
                        climb_m: -offset.z,
                    });
                }
            }
            if let (Some(reason), None, None) =
                (snapshot.pilot.landing, report.landing, report.landed_by_itself)
            {
                report.landed_by_itself = Some((reason, since_release));
            }
            if snapshot.pilot.flying {
                if report.release_to_engage_s.is_none() {
                    report.excitation_end_to_engage_s = excitation_end_s.map(|end| t_s - end);
                    let learned = app.background.results().learned;
                    let scores = Scores::of(&learned, &truth);
                    report.g1_block_rel_at_engage = Some(scores.g1_block_rel);
                    report.axis_error_at_engage_deg = axis_error_deg(&scores);
                    report.engaged_clamped_by = learned
                        .thrust_axis
                        .filter(|axis| !axis.within_bounds())
                        .map(|axis| f64::from(axis.clamped_by));
                }
                let q_true = state.attitude() * airframe.q_imu_body().inverse();
                if report.engaged_height_m.is_none() {
                    let up_ned = state.attitude() * thrust_dir_body;
                    report.engaged_height_m = Some(-state.position_ned_m.z);
                    report.engaged_descent_mps = Some(state.velocity_ned_mps.z);
                    report.engaged_axis_from_up_deg =
                        Some((-up_ned.z).clamp(-1.0, 1.0).acos().to_degrees());
                }
                if report.attitude_error_at_engage_deg.is_none() {
                    report.attitude_error_at_engage_deg =
                        Some(attitude_error_deg(snapshot.pilot.q_world_imu, &q_true));
                }
                if t_s >= end_s - hold_window_s && report.attitude_error_at_window_deg.is_none() {
                    report.attitude_error_at_window_deg =
                        Some(attitude_error_deg(snapshot.pilot.q_world_imu, &q_true));
                }
                report.release_to_engage_s.get_or_insert(since_release);
                report.outcome = Outcome::Flying;
                let in_window = t_s >= end_s - hold_window_s && t_s < end_s;
                if in_window {
                    window_steps += 1;
                    window_hold_steps += u64::from(snapshot.pilot.position_hold);
                }
                if snapshot.pilot.position_hold && report.landing.is_none() {
                    let sp = Vector3::from(snapshot.pilot.position_sp_ned_m).cast::<f64>()
                        // The fixes' world: a GNSS fix's origin; motion capture's is ours.
                        + gnss.as_ref().and_then(GnssFeed::origin_ned_m).unwrap_or_else(Vector3::zeros);
                    report.setpoint_ned_m = Some(sp);
                    if in_window {
                        window_rate_sum2 += state.rate_body_rad_s.norm_squared();
                        window_rate_steps += 1;
                        let error = (state.position_ned_m - sp).norm();
                        let worst = report.max_hold_error_m.get_or_insert(0.0);
                        *worst = worst.max(error);
                        let horizontal = (state.position_ned_m - sp).xy().norm();
                        let worst = report.max_hold_error_horizontal_m.get_or_insert(0.0);
                        *worst = worst.max(horizontal);
                        if let Some(fix_error) = gnss.as_ref().and_then(GnssFeed::last_error_ned_m)
                        {
                            let worst = report.max_fix_error_horizontal_m.get_or_insert(0.0);
                            *worst = worst.max(fix_error.xy().norm());
                        }
                    }
                }
                let hovering = state.rate_body_rad_s.norm() < HOVER_RATE_RAD_S
                    && state.velocity_ned_mps.z.abs() < HOVER_CLIMB_MPS
                    && tilt_from_equilibrium_rad(board.physics().model(), &state, &thrust_dir_body)
                        < HOVER_TILT_RAD;
                if hovering {
                    let since = *hover_since.get_or_insert(since_release);
                    if since_release - since >= HOVER_HOLD_S && report.release_to_hover_s.is_none()
                    {
                        report.release_to_hover_s = Some(since);
                        recovered_ned_m = Some(state.position_ned_m);
                    }
                } else {
                    hover_since = None;
                }
                if let (Some(recovered), None) = (recovered_ned_m, &report.landing) {
                    let speed = state.velocity_ned_mps.xy().norm();
                    let fastest = report.max_speed_after_recovery_mps.get_or_insert(0.0);
                    *fastest = fastest.max(speed);
                    report.end_from_recovery_m =
                        Some((state.position_ned_m - recovered).xy().norm());
                }
            } else if snapshot.pilot.last_landing == Some(LandReason::Caught)
                && report.release_to_engage_s.is_some()
            {
                // The hand-catch detector stopped the motors: after the grab, or without one.
                report.outcome = Outcome::Caught;
                match (grab_s, &mut report.catch) {
                    (Some(at_s), Some(catch)) => catch.stopped_after_s = Some(t_s - at_s),
                    _ => report.false_catch_s = Some(since_release),
                }
                break;
            } else if let Some(landing) = &mut report.landing {
                // The landing's end: the motors stopped, on the ground or not.
                match touchdown_s {
                    Some(at_s) => {
                        landing.stop_delay_s = Some(t_s - at_s);
                        report.outcome = Outcome::Landed;
                    }
                    None => {
                        landing.stopped_in_air_m = Some(-state.position_ned_m.z);
                        report.outcome = match snapshot.pilot.last_failsafe {
                            Some(failsafe) => Outcome::Failsafe(failsafe),
                            None => Outcome::Ground,
                        };
                    }
                }
                break;
            } else if report.release_to_engage_s.is_some() {
                report.outcome = match snapshot.pilot.last_failsafe {
                    Some(failsafe) => Outcome::Failsafe(failsafe),
                    None => Outcome::Ground,
                };
                break;
            } else if let (FlightPhase::Done, Some(failsafe)) =
                (snapshot.phase, snapshot.pilot.last_failsafe)
            {
                report.outcome = Outcome::Failsafe(failsafe);
                break;
            }
            if end_s.is_infinite() {
                end_s = released_s + config.flight_s;
            }
            if let (Some(landing), None) = (&mut report.landing, touchdown_s) {
                if board.physics().model().gear_height_m(&state) <= 0.0 {
                    // The first contact of a landing: how fast, and how far from where it began.
                    touchdown_s = Some(t_s);
                    landing.touchdown_speed_mps = Some(state.velocity_ned_mps.z);
                    let drift = state.position_ned_m - land_from_ned_m;
                    landing.horizontal_drift_m = Some(drift.xy().norm());
                }
            } else if board.physics().model().gear_height_m(&state) <= 0.0
                && report.landing.is_none()
            {
                // On the ground before any landing: its gear holds the centre of gravity a few
                // centimetres up, so the gear's contact is the test, not the centre's height (a
                // recovery that slid along the ground and then "hovered" on its gear until the
                // hand-catch detector stopped it, GNSS and wind seed 220, was not counted as one).
                report.outcome = if report.release_to_engage_s.is_some() {
                    Outcome::Ground
                } else {
                    Outcome::NoIdentification
                };
                break;
            }
            if t_s >= end_s && config.end == FlightEnd::Catch {
                if !snapshot.pilot.flying || t_s >= end_s + CATCH_TIMEOUT_S {
                    break;
                }
                if grab_s.is_none() {
                    grab_s = Some(t_s);
                    report.catch = Some(CatchReport { grab: config.grab, stopped_after_s: None });
                    board.physics_mut().grab(&config.grab);
                }
                continue;
            }
            if t_s >= end_s {
                let FlightEnd::Land(reason) = config.end else { break };
                if !snapshot.pilot.flying || t_s >= end_s + LANDING_TIMEOUT_S {
                    break;
                }
                if report.landing.is_none() {
                    report.landing = Some(LandingReport {
                        requested_height_m: -state.position_ned_m.z,
                        touchdown_speed_mps: None,
                        stop_delay_s: None,
                        stopped_in_air_m: None,
                        horizontal_drift_m: None,
                    });
                    land_from_ned_m = state.position_ned_m;
                    app.command(ControlCommand::Land(reason), now_us);
                }
            }
        }
        if report.outcome == Outcome::Flying {
            let learned = app.background.results().learned;
            let scores = Scores::of(&learned, &truth);
            report.g1_block_rel_learned_at_end = Some(scores.g1_block_rel);
            report.axis_error_at_end_deg = axis_error_deg(&scores);
            report.g1_block_rel_flown_at_end = flown_scores(app, &truth);
        }
        let results = app.background.results();
        if let Some(fit) = results.flight_offset {
            report.r_imu_fit_m = Some(Vector3::from(fit.r_imu_m).cast::<f64>());
            report.r_imu_fit_semi_axis_m = Some(f64::from(fit.ci95_semi_axes_m[2]));
            report.r_imu_fit_covariance_m2 =
                Some(Matrix3::from_fn(|i, j| f64::from(fit.covariance_m2[i][j])));
            if report.outcome == Outcome::Flying {
                let delta = Vector3::from(fit.r_imu_m) - Vector3::from(results.learner_r_imu_m);
                let mut corrected = results.learned;
                let g1 = &mut corrected.g1_per_speed2;
                // Column i of the three force and the three torque rows.
                #[allow(clippy::needless_range_loop)]
                for i in 0..usize::from(corrected.motors) {
                    let torque = Vector3::new(g1[3][i], g1[4][i], g1[5][i]);
                    let correction = delta.cross(&torque);
                    for k in 0..3 {
                        g1[k][i] += correction[k];
                    }
                }
                report.g1_block_rel_corrected_by_fit =
                    Some(Scores::of(&corrected, &truth).g1_block_rel);
                let mut joint = results.learned;
                joint.g1_per_speed2[..3].copy_from_slice(&fit.g1f_per_speed2);
                report.g1_block_rel_fitted_jointly = Some(Scores::of(&joint, &truth).g1_block_rel);
            }
        }
        let pilot = app.snapshot().pilot;
        report.refinements = pilot.refinements;
        report.reforms = pilot.reforms;
        report.pose_lost = pilot.failsafes.pose_lost;
        report.fixes_rejected = pilot.fixes_rejected;
        report.hold_coverage =
            if window_steps > 0 { window_hold_steps as f64 / window_steps as f64 } else { 0.0 };
        report.hold_rate_rms_rad_s =
            (window_rate_steps > 0).then(|| (window_rate_sum2 / window_rate_steps as f64).sqrt());
        report
    })
}

/// The craft's thrust-to-weight ratio: the net force of every motor at full speed over the
/// weight (tilted rotors' sideways parts cancel in the sum).
pub fn thrust_to_weight(airframe: &Airframe) -> f64 {
    let force: Vector3<f64> = (0..airframe.rotor_count())
        .map(|i| {
            let motor = airframe.rotor_motor(i);
            airframe.thrust_axis(i)
                * motor.thrust_coefficient_n_per_rad2_s2
                * motor.omega_max_rad_s.powi(2)
        })
        .sum();
    force.norm() / (airframe.mass_kg * crate::airframe::STANDARD_GRAVITY_MPS2)
}

/// Heading of the body frame: yaw of its x axis about world z, rad.
pub fn heading(q_world_body: &UnitQuaternion<f64>) -> f64 {
    let x = q_world_body * Vector3::x();
    x.y.atan2(x.x)
}

/// Angle between the true hover thrust axis (`thrust_dir_body`, body axes) and the direction
/// that cancels gravity and the drag at the current airspeed in `model`'s air, rad (module doc).
fn tilt_from_equilibrium_rad(
    model: &crate::dynamics::VehicleModel,
    state: &State,
    thrust_dir_body: &Vector3<f64>,
) -> f64 {
    let thrust_dir_ned = state.attitude() * thrust_dir_body;
    thrust_dir_ned.angle(&model.equilibrium_thrust_dir_ned(state))
}

/// The run of Monte Carlo case `seed`: [`Airframe::random`]`(seed)` (4–8 motors, tilted rotors,
/// any IMU pose) thrown at 300–600 °/s about a random axis on a 2.5–4.5 m parabola with up to
/// 2 m/s sideways, motion capture on, the IMU offset known, 13 s of flight.
pub fn random_case(seed: u64) -> (Airframe, FlyConfig) {
    let airframe = Airframe::random(seed);
    let mut rng = Rng::new(seed ^ 0x00F1_7EC0_7E57);
    let mut config = FlyConfig::paper();
    config.throw = Throw::random(&mut rng);
    config.board.seed = seed;
    (airframe, config)
}

/// How a Monte Carlo run is classified.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Hovered and held its position within [`HOLD_BOUND_M`] for the whole window.
    Held,
    /// Hovered, but strayed beyond [`HOLD_BOUND_M`] during the hold (or never started one).
    HoveredLoose,
    /// Flying at the end, never hovering.
    NeverHovered,
    /// Hit the ground after the controller engaged.
    Ground,
    /// Stopped by a failsafe.
    Failsafe(Failsafe),
    /// No throw detected or no excitation end.
    NoIdentification,
    /// The hand-catch detector stopped the motors in free flight, without a hand.
    FalseCatch,
}

/// Largest distance from the setpoint for [`Verdict::Held`], m (the 0.3 m).
pub const HOLD_BOUND_M: f64 = 0.3;

impl Verdict {
    /// The verdict of a report.
    pub fn of(report: &FlyReport) -> Self {
        match report.outcome {
            // A landing comes after the hold window: the hold is judged as a flight's.
            Outcome::Caught if report.false_catch_s.is_some() => Verdict::FalseCatch,
            Outcome::Flying | Outcome::Landed | Outcome::Caught
                if report.release_to_hover_s.is_none() =>
            {
                Verdict::NeverHovered
            }
            Outcome::Flying | Outcome::Landed | Outcome::Caught
                if report.max_hold_error_m.is_some_and(|e| e < HOLD_BOUND_M) =>
            {
                Verdict::Held
            }
            Outcome::Flying | Outcome::Landed | Outcome::Caught => Verdict::HoveredLoose,
            Outcome::Ground => Verdict::Ground,
            Outcome::Failsafe(f) => Verdict::Failsafe(f),
            Outcome::NoIdentification => Verdict::NoIdentification,
        }
    }
}

/// One Monte Carlo run's result.
#[derive(Clone, Debug, PartialEq)]
pub struct CaseResult {
    /// The seed ([`random_case`]).
    pub seed: u64,
    /// Motors.
    pub motors: usize,
    /// The slowest motor's time constant, s: every loop's gain follows from it
    /// (`flight::position::Gains::from_tau`), so what a disturbance leaves grows with it.
    pub slowest_motor_tau_s: f64,
    /// What was measured.
    pub report: FlyReport,
    /// Its classification.
    pub verdict: Verdict,
}

/// Flies the cases `case(seed)` for seeds `seed..seed + runs` on `threads` workers and
/// classifies each; `progress` is called with the number done after each.
pub fn monte_carlo(
    runs: usize,
    seed: u64,
    threads: usize,
    progress: &(dyn Fn(usize) + Sync),
    case: impl Fn(u64) -> (Airframe, FlyConfig) + Sync,
) -> Vec<CaseResult> {
    crate::stats::run_seeds(runs, seed, threads, progress, |seed| {
        let (airframe, config) = case(seed);
        let report = fly(&airframe, &config);
        let verdict = Verdict::of(&report);
        let slowest_motor_tau_s =
            (0..airframe.rotor_count()).map(|i| airframe.rotor_motor(i).tau_s).fold(0.0, f64::max);
        CaseResult { seed, motors: airframe.rotor_count(), slowest_motor_tau_s, report, verdict }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motion_capture_sends_100_poses_a_second_with_millimetre_noise() {
        let airframe = Airframe::builtin("paper-quad").unwrap();
        let board = SimBoard::new(&airframe, &SimConfig::default());
        let state = *board.physics().state();
        let mut mocap = MotionCapture::new(7);
        let mut poses = Vec::new();
        for tick in 0..20_000u64 {
            // 2 kHz for 10 s.
            if let Some(pose) = mocap.sample(&state, tick * 500) {
                poses.push(pose);
            }
        }
        assert_eq!(poses.len(), 1000);
        let truth = state.position_ned_m;
        let n = poses.len() as f64;
        let rms =
            (poses.iter().map(|p| (f64::from(p.position_ned_m[0]) - truth.x).powi(2)).sum::<f64>()
                / n)
                .sqrt();
        assert!((rms - MOCAP_NOISE_M).abs() < 0.15 * MOCAP_NOISE_M, "{rms} m");
        let heading_rms = (poses
            .iter()
            .map(|p| (f64::from(p.heading_rad) - heading(&state.attitude())).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        assert!((heading_rms - MOCAP_HEADING_NOISE_RAD).abs() < 0.15 * MOCAP_HEADING_NOISE_RAD);
    }

    #[test]
    fn motion_capture_keeps_its_rate_latency_and_dropouts() {
        // A craft falling freely from rest: its position tells the capture time.
        let airframe = Airframe::builtin("paper-quad").unwrap();
        let board = SimBoard::new(&airframe, &SimConfig::default());
        let start = *board.physics().state();
        let at = |t_s: f64| {
            let mut state = start;
            state.position_ned_m = Vector3::new(t_s, 0.0, 0.0);
            state
        };
        for (rate_hz, jitter_s, latency_s) in
            [(2000.0, 0.0, 0.0), (10.0, 0.02, 0.03), (30.0, 0.005, 0.05)]
        {
            let config = MotionCaptureConfig {
                rate_hz,
                jitter_s,
                latency_s,
                noise_m: 0.0,
                heading_noise_rad: 0.0,
                ..MotionCaptureConfig::default()
            };
            config.validate().unwrap();
            let mut mocap = MotionCapture::with_config(config, 3);
            let mut arrivals = Vec::new();
            for tick in 1..=20_000u64 {
                let now_us = tick * 500;
                let t_s = now_us as f64 * 1e-6;
                if let Some(pose) = mocap.sample(&at(t_s), now_us) {
                    arrivals.push((t_s, f64::from(pose.position_ned_m[0])));
                }
            }
            // 10 s: the rate within one pose (jitter averages out).
            let expected = 10.0 * rate_hz - latency_s * rate_hz;
            let count = arrivals.len() as f64;
            assert!(
                (count - expected).abs() <= 1.0 + 0.01 * expected,
                "{rate_hz} Hz: {count} poses"
            );
            // Each pose arrives its latency after the time it describes (to the 0.5 ms tick).
            for (arrived_s, captured_s) in &arrivals {
                assert!(
                    (arrived_s - captured_s - latency_s).abs() < 1e-4,
                    "{arrived_s} {captured_s}"
                );
            }
            // With jitter, the spacing varies within ±jitter.
            let gaps: Vec<f64> = arrivals.windows(2).map(|w| w[1].1 - w[0].1).collect();
            let spread = gaps.iter().fold(0.0f64, |m, g| m.max((g - 1.0 / rate_hz).abs()));
            assert!(spread <= 2.0 * jitter_s + 5e-4, "{rate_hz} Hz: spread {spread}");
            if jitter_s > 0.0 {
                assert!(spread > 0.5 * jitter_s, "{rate_hz} Hz: no jitter ({spread})");
            }
        }
        // Dropouts: 0.2 a second lasting 0.5 s lose about 0.1/(1 + 0.1) of 100 s.
        let config = MotionCaptureConfig {
            dropouts_per_s: 0.2,
            dropout_s: 0.5,
            ..MotionCaptureConfig::default()
        };
        let mut mocap = MotionCapture::with_config(config, 11);
        let received =
            (1..=200_000u64).filter(|tick| mocap.sample(&at(0.0), tick * 500).is_some()).count();
        let lost = 1.0 - received as f64 / 10_000.0;
        assert!((0.04..0.16).contains(&lost), "lost {lost}");
        assert!(MotionCaptureConfig { latency_s: 0.2, ..config }.validate().is_err());
    }
}
