//! [`SimBoard`]: the simulated flight-controller board, implementing the application's hardware
//! traits [`Imu`] and [`Motors`] from the physics, so `firmware::app` runs unchanged on the host.
//!
//! # API
//! ```
//! use firmware::app::hal::{Imu, Motors};
//! use sim::{airframe::Airframe, board::{SimBoard, SimConfig}};
//!
//! let airframe = Airframe::builtin("paper-quad").unwrap();
//! let mut board = SimBoard::new(&airframe, &SimConfig::default());
//! for _ in 0..10 {
//!     board.tick(); // 500 µs of physics (4 IMU samples at 8 kHz, averaged into one)
//!     let now_us = board.now_us();
//!     let (imu, motors) = board.ports(); // disjoint borrows for `ControlLoop::step`
//!     let _sample = imu.read(); // Some(..) once per tick
//!     motors.set_commands(&[0.0; 4]); // applied from the next tick on
//!     let _ = now_us;
//! }
//! let _truth = board.physics().state(); // position, attitude, rates, rotor speeds
//! ```
//! - One [`SimBoard::tick`] advances one 2 kHz control period: the physics at
//!   `sample_rate_hz × physics_steps_per_imu_sample`, the IMU at its sample rate (8 kHz in the
//!   library), the average of the tick's samples becomes the one sample [`Imu::read`] returns
//!   (then `None` until the next tick), and the RPM telemetry is updated. The average of four
//!   8 kHz samples taken 125, 250, 375 and 500 µs into the tick is centred 187.5 µs before
//!   `now_us` (the decimation's group delay).
//! - Commands set through [`Motors::set_commands`] are held until changed (zero-order hold, as a
//!   DShot output) and act from the next tick. The steady-state speed for a command follows
//!   [`MotorParams::steady_speed_rad_s`](crate::airframe::MotorParams::steady_speed_rad_s).
//! - Arming: the `Motors` trait has no arm/disarm, so the board decides ([`Arming`]); by default
//!   the motors stay stopped until the first command above zero arrives (like an ESC that is sent
//!   DShot 0 until the craft arms), and then idle at δ = 0. [`SimMotors::disarm`] stops them.
//! - [`Motors::speeds_rad_s`] returns what bidirectional DShot would: quantised by the eRPM period
//!   encoding ([`crate::dshot`]) and delayed by the motor's `telemetry_delay_s` (whole ticks);
//!   `None` before the first report has arrived.
//! - The hand and the truth are reached through [`SimBoard::physics`] / [`SimBoard::physics_mut`].

use firmware::app::hal::{BatteryReading, Imu, ImuSample, Motors, MAX_MOTORS};
use firmware::drivers::dshot::{CommandQueue, DshotCommand};
use nalgebra::{UnitQuaternion, Vector3};

use crate::airframe::{Airframe, MotorParams, MAX_ROTORS};
use crate::battery::{PackParams, SimBattery};
use crate::dshot;
use crate::faults::{FaultInjector, FaultSchedule};
use crate::imu::{ImuModel, RawSample};
use crate::physics::Physics;
use crate::scenario::FlightApp;

/// What a simulated board reports of its hardware: the simulator's IMU model; no clock tree, no
/// DShot link (the motors are modelled behind the application's motor seam) and no receiver.
pub const SIM_BOARD_HEALTH: protocol::BoardHealth = protocol::BoardHealth {
    core_clock_hz: None,
    silicon_revision: None,
    imu: protocol::ImuDriverState::Simulated,
    motors: None,
    receiver: None,
};

/// The application's control rate, Hz, as `f64` for the simulator's arithmetic: the firmware's
/// own [`firmware::app::CONTROL_RATE_HZ`] (2 kHz), not a second definition.
pub const CONTROL_RATE_HZ: f64 = firmware::app::CONTROL_RATE_HZ as f64;
/// One control period, µs (500 µs at 2 kHz; the rate divides 1 s exactly).
pub const CONTROL_PERIOD_US: u64 = 1_000_000 / firmware::app::CONTROL_RATE_HZ as u64;
const _: () = assert!(
    1_000_000 % firmware::app::CONTROL_RATE_HZ as u64 == 0,
    "the control period must be a whole number of µs"
);
/// Longest telemetry delay the ring holds, control ticks (0.05 s, the validated maximum).
const MAX_TELEMETRY_DELAY_TICKS: usize = 100;

/// When the simulated ESCs run their motors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Arming {
    /// Stopped until the first command above zero, then armed (idle at δ = 0).
    #[default]
    OnFirstCommand,
    /// Armed from the start.
    Armed,
    /// Never spin.
    Disarmed,
}

/// How to build a [`SimBoard`].
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    /// Physics steps per raw IMU sample (1 = physics at the IMU rate, 8 kHz in the library).
    pub physics_steps_per_imu_sample: u32,
    /// Seed of the sensor noise.
    pub seed: u64,
    /// Read the IMU without errors (for tests of the physics).
    pub ideal_imu: bool,
    /// Motor arming policy.
    pub arming: Arming,
    /// Where the hand holds the vehicle at the start, world NED, m.
    pub start_position_ned_m: Vector3<f64>,
    /// Attitude at the start, `q_world_body`.
    pub start_attitude: UnitQuaternion<f64>,
    /// Faults to inject ([`crate::faults`]; empty: none).
    pub faults: FaultSchedule,
    /// What the world does beyond the airframe ([`crate::world`]); default: nothing.
    pub world: WorldEffects,
    /// The flight battery the board measures ([`crate::battery`]); default: a charged 4S pack.
    pub battery: PackParams,
}

/// Time-varying effects of the world on a board: a sagging battery, ESC answers lost, gusts, a
/// steady wind and turbulence.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WorldEffects {
    /// Fraction of every motor's thrust lost to battery sag by `battery_sag_over_s` after the
    /// start (linearly; the speed for a command falls by `√(1 − sag)`), in [0, 0.5].
    pub battery_sag: f64,
    /// Time over which the sag builds up, s.
    pub battery_sag_over_s: f64,
    /// Probability that an ESC's speed answer is lost in a control period (the application
    /// keeps the previous one), in [0, 1).
    pub telemetry_loss_probability: f64,
    /// A gust: the air moves at this velocity, world NED, m/s, ...
    pub gust_ned_mps: [f64; 3],
    /// ... from this time, s, ...
    pub gust_start_s: f64,
    /// ... for this long, s (0: no gust).
    pub gust_s: f64,
    /// More gusts, on top of that one ([`crate::world`]'s `gusts`).
    pub gusts: [Option<Gust>; 2],
    /// A steady wind, world NED, m/s, from the start of the run (the throw included), on top of
    /// the gusts ([`crate::world`]'s `wind`; zero: none).
    pub steady_wind_ned_mps: [f64; 3],
    /// Turbulence on top of the steady wind and the gusts (`None`: none).
    pub turbulence: Option<Turbulence>,
}

/// Turbulence: each world axis's air velocity a first-order Gauss–Markov process (an
/// Ornstein–Uhlenbeck process sampled at the control rate) of zero mean.
///
/// A simplified stand-in for the Dryden model of MIL-F-8785C / MIL-HDBK-1797, whose longitudinal
/// spectrum is this first-order one with a correlation time of its length scale over the mean
/// wind; its lateral and vertical spectra are second-order and their length scales differ, which
/// this one correlation time for every axis leaves out ([`crate::world`] says which ranges are
/// drawn and why).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Turbulence {
    /// Standard deviation of each world axis's velocity (north, east, down), m/s.
    pub sigma_ned_mps: [f64; 3],
    /// Correlation time of every axis, s: the autocorrelation falls as `exp(−lag / τ)`.
    pub correlation_s: f64,
    /// Seed of the process's draws.
    pub seed: u64,
}

/// The turbulence's state, advanced one step at a time ([`Turbulence`]).
///
/// The exact discretisation of the continuous process: over a step `dt`,
/// `x ← a·x + σ·√(1 − a²)·n` with `a = exp(−dt/τ)` and `n` standard normal, so the variance
/// stays σ² whatever the step. The state starts drawn from that stationary distribution: the
/// air is as turbulent at the start of a run as later.
#[derive(Clone, Debug)]
pub struct TurbulenceProcess {
    config: Turbulence,
    rng: crate::rng::Rng,
    velocity_ned_mps: Vector3<f64>,
}

impl TurbulenceProcess {
    /// The process of `config`, its state drawn from the stationary distribution.
    pub fn new(config: Turbulence) -> Self {
        let mut rng = crate::rng::Rng::new(config.seed);
        let velocity_ned_mps = Vector3::from(config.sigma_ned_mps.map(|s| s * rng.normal()));
        Self { config, rng, velocity_ned_mps }
    }

    /// The turbulence's velocity now, world NED, m/s.
    pub fn velocity_ned_mps(&self) -> Vector3<f64> {
        self.velocity_ned_mps
    }

    /// Advances the process by `dt_s` and returns its new velocity, world NED, m/s.
    pub fn step(&mut self, dt_s: f64) -> Vector3<f64> {
        let a = (-dt_s / self.config.correlation_s.max(f64::MIN_POSITIVE)).exp();
        let share = (1.0 - a * a).max(0.0).sqrt();
        for (x, sigma) in self.velocity_ned_mps.iter_mut().zip(self.config.sigma_ned_mps) {
            *x = a * *x + sigma * share * self.rng.normal();
        }
        self.velocity_ned_mps
    }
}

/// The shape of a [`Gust`] in time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GustShape {
    /// The whole speed at once, for the gust's duration.
    Step,
    /// The "1 − cos" gust of the airworthiness codes (CS-25.341, MIL-F-8785C): the speed rises
    /// and falls as `(1 − cos 2πt/T)/2` over the duration `T`.
    OneMinusCosine,
}

/// A gust: the air moves at up to `peak_ned_mps` from `start_s` for `duration_s`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gust {
    pub shape: GustShape,
    /// The air's velocity at the gust's peak, world NED, m/s.
    pub peak_ned_mps: [f64; 3],
    pub start_s: f64,
    pub duration_s: f64,
}

impl Gust {
    /// The air's velocity at `now_s`, world NED, m/s.
    pub fn wind_ned_mps(&self, now_s: f64) -> Vector3<f64> {
        let t = now_s - self.start_s;
        if !(0.0..self.duration_s).contains(&t) {
            return Vector3::zeros();
        }
        let share = match self.shape {
            GustShape::Step => 1.0,
            GustShape::OneMinusCosine => {
                0.5 * (1.0 - (std::f64::consts::TAU * t / self.duration_s).cos())
            }
        };
        Vector3::from(self.peak_ned_mps) * share
    }
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            physics_steps_per_imu_sample: 1,
            seed: 1,
            ideal_imu: false,
            arming: Arming::OnFirstCommand,
            start_position_ned_m: Vector3::new(0.0, 0.0, -1.0),
            start_attitude: UnitQuaternion::identity(),
            faults: FaultSchedule::default(),
            world: WorldEffects::default(),
            battery: PackParams::default(),
        }
    }
}

/// The simulated IMU port: the newest 2 kHz sample, taken by [`Imu::read`].
#[derive(Clone, Debug, Default)]
pub struct SimImu {
    latest: Option<ImuSample>,
}

impl Imu for SimImu {
    fn read(&mut self) -> Option<ImuSample> {
        self.latest.take()
    }
}

/// The simulated motor outputs and RPM telemetry.
#[derive(Clone, Debug)]
pub struct SimMotors {
    count: u8,
    commands: [f32; MAX_MOTORS],
    arming: Arming,
    armed: bool,
    speeds_rad_s: [Option<f32>; MAX_MOTORS],
    /// Special commands waiting for the stop frames, as on the board.
    special: CommandQueue,
    /// Whether the ESCs answer with their speed (bidirectional DShot; `motor_bidir_dshot`):
    /// without, no speed is reported, as on a board with BLHeli_S ESCs.
    bidirectional: bool,
    escs: [SimEsc; MAX_MOTORS],
}

/// What a simulated ESC made of the DShot special commands on its wire: the frames are encoded
/// by the board's [`CommandQueue`] and read back here as an ESC firmware reads them (BLHeli_32,
/// Bluejay: a beep on its first frame, a settings command after six frames in a row). The
/// motor's physics does not change (a reversed direction is recorded, not flown).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SimEsc {
    /// Beeps sounded (one per beep command).
    pub beeps: u32,
    /// Spin direction reversed (`SpinDirectionReversed` or `SpinDirection2`; back to normal
    /// with `SpinDirectionNormal` or `SpinDirection1`).
    pub reversed: bool,
    /// Settings saved (`SaveSettings`).
    pub saves: u32,
    /// Settings commands refused for too few repeats (the run of frames broke before six).
    pub settings_incomplete: u32,
    /// The command of the last frame and how many frames of it in a row.
    run: Option<(DshotCommand, u8)>,
}

/// Frames in a row an ESC needs before it acts on a settings command (the DShot specification's
/// minimum; [`DshotCommand::min_repeats`]).
const SETTINGS_FRAMES: u8 = 6;

impl SimEsc {
    /// One frame on the wire (normal DShot).
    fn receive(&mut self, frame: u16) {
        let command = u8::try_from(frame >> 5).ok().and_then(DshotCommand::from_value);
        let Some(command) = command else {
            if let Some((run, frames)) = self.run.take() {
                if run.changes_settings() && frames < SETTINGS_FRAMES {
                    self.settings_incomplete += 1;
                }
            }
            return;
        };
        let frames = match self.run {
            Some((run, frames)) if run == command => frames.saturating_add(1),
            _ => 1,
        };
        self.run = Some((command, frames));
        let act_now =
            if command.changes_settings() { frames == SETTINGS_FRAMES } else { frames == 1 };
        if !act_now {
            return;
        }
        match command {
            DshotCommand::Beep1
            | DshotCommand::Beep2
            | DshotCommand::Beep3
            | DshotCommand::Beep4
            | DshotCommand::Beep5 => self.beeps += 1,
            DshotCommand::SpinDirectionReversed | DshotCommand::SpinDirection2 => {
                self.reversed = true
            }
            DshotCommand::SpinDirectionNormal | DshotCommand::SpinDirection1 => {
                self.reversed = false
            }
            DshotCommand::SaveSettings => self.saves += 1,
            _ => {}
        }
    }
}

impl SimMotors {
    /// Bidirectional DShot on or off (the SITL sets it from `motor_bidir_dshot` at each start).
    pub fn set_bidirectional(&mut self, bidirectional: bool) {
        self.bidirectional = bidirectional;
    }

    /// The simulated ESCs (first `count()` entries).
    pub fn escs(&self) -> &[SimEsc] {
        &self.escs[..self.count as usize]
    }

    /// The commands now held, δ ∈ [0, 1] (first `count()` entries).
    pub fn commands(&self) -> &[f32] {
        &self.commands[..self.count as usize]
    }

    /// Whether the ESCs run the motors.
    pub fn is_armed(&self) -> bool {
        self.armed
    }

    /// Stops the motors (until the arming policy arms them again).
    pub fn disarm(&mut self) {
        self.armed = false;
        if self.arming == Arming::OnFirstCommand {
            self.arming = Arming::Disarmed;
        }
    }

    /// Arms the motors now.
    pub fn arm(&mut self) {
        self.armed = true;
    }
}

impl Motors for SimMotors {
    fn count(&self) -> u8 {
        self.count
    }

    /// As the board's outputs: disarmed, every motor stops (with the default arming, the next
    /// command above zero spins them again).
    fn set_armed(&mut self, armed: bool) {
        if !armed && self.arming == Arming::OnFirstCommand {
            self.armed = false;
        }
    }

    fn set_commands(&mut self, commands: &[f32]) {
        for (dst, src) in self.commands.iter_mut().zip(commands).take(self.count as usize) {
            // A NaN command is treated as 0, as a DShot driver clamps before encoding.
            *dst = if src.is_nan() { 0.0 } else { src.clamp(0.0, 1.0) };
        }
        if self.arming == Arming::OnFirstCommand && self.commands().iter().any(|c| *c > 0.0) {
            self.armed = true;
        }
        // Each ESC reads the frame the board would send it; special commands only while every
        // motor is commanded to stop.
        self.special.set_armed(self.commands().iter().any(|c| *c > 0.0));
        for (i, esc) in self.escs.iter_mut().enumerate().take(usize::from(self.count)) {
            esc.receive(self.special.frame(i as u8, self.commands[i], false));
        }
        self.special.frame_sent();
    }

    fn esc_command_queue(&mut self) -> Option<&mut CommandQueue> {
        Some(&mut self.special)
    }

    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
        if self.bidirectional {
            self.speeds_rad_s
        } else {
            [None; MAX_MOTORS]
        }
    }
}

/// The simulated board (see the module doc).
#[derive(Clone, Debug)]
pub struct SimBoard {
    physics: Physics,
    imu_model: ImuModel,
    imu: SimImu,
    motors: SimMotors,
    motor_params: Vec<MotorParams>,
    telemetry_delay_ticks: Vec<usize>,
    /// Ring of decoded telemetry speeds per tick, rad/s.
    telemetry_ring: Vec<[f32; MAX_MOTORS]>,
    samples_per_tick: u32,
    steps_per_sample: u32,
    ticks: u64,
    last_sample: ImuSample,
    last_truth_sample: RawSample,
    /// Fault injection ([`crate::faults`]).
    faults: FaultInjector,
    world: WorldEffects,
    /// Draws of the world's random effects (lost ESC answers).
    world_rng: crate::rng::Rng,
    /// The turbulence's state (`None` without turbulence).
    turbulence: Option<TurbulenceProcess>,
    battery: SimBattery,
    /// What the board's battery sensors read in the latest tick.
    battery_reading: BatteryReading,
    /// The speeds last reported per motor (kept when an answer is lost).
    reported_rad_s: [Option<f32>; MAX_MOTORS],
}

impl SimBoard {
    /// A board on `airframe` (validated), the vehicle held by the hand at the configured pose.
    pub fn new(airframe: &Airframe, config: &SimConfig) -> Self {
        let steps_per_sample = config.physics_steps_per_imu_sample.max(1);
        let sample_rate_hz = airframe.imu.sample_rate_hz;
        let physics = Physics::new(
            airframe,
            config.start_position_ned_m,
            config.start_attitude,
            sample_rate_hz * f64::from(steps_per_sample),
        );
        let m = airframe.rotor_count();
        let motor_params: Vec<MotorParams> =
            (0..m).map(|i| airframe.rotor_motor(i).clone()).collect();
        let telemetry_delay_ticks = motor_params
            .iter()
            .map(|p| {
                ((p.telemetry_delay_s * CONTROL_RATE_HZ).round() as usize)
                    .min(MAX_TELEMETRY_DELAY_TICKS)
            })
            .collect();
        Self {
            physics,
            imu_model: ImuModel::new(airframe, config.seed, config.ideal_imu),
            imu: SimImu::default(),
            motors: SimMotors {
                count: m as u8,
                commands: [0.0; MAX_MOTORS],
                arming: config.arming,
                armed: config.arming == Arming::Armed,
                speeds_rad_s: [None; MAX_MOTORS],
                special: CommandQueue::default(),
                bidirectional: true,
                escs: [SimEsc::default(); MAX_MOTORS],
            },
            motor_params,
            telemetry_delay_ticks,
            telemetry_ring: vec![[0.0; MAX_MOTORS]; MAX_TELEMETRY_DELAY_TICKS + 1],
            samples_per_tick: (sample_rate_hz / CONTROL_RATE_HZ).round() as u32,
            steps_per_sample,
            ticks: 0,
            last_sample: ImuSample::default(),
            last_truth_sample: RawSample::default(),
            faults: FaultInjector::new(&config.faults),
            world: config.world,
            world_rng: crate::rng::Rng::new(config.seed ^ 0x57_4F52_4C44),
            turbulence: config.world.turbulence.map(TurbulenceProcess::new),
            battery: SimBattery::new(config.battery, config.seed),
            battery_reading: BatteryReading::default(),
            reported_rad_s: [None; MAX_MOTORS],
        }
    }

    /// Advances one control period (500 µs): physics, IMU, telemetry.
    pub fn tick(&mut self) {
        let mut targets = [0.0; MAX_ROTORS];
        let now_s = (self.ticks * CONTROL_PERIOD_US) as f64 * 1e-6;
        let w = self.world;
        let sag = if w.battery_sag_over_s > 0.0 {
            w.battery_sag * (now_s / w.battery_sag_over_s).min(1.0)
        } else {
            0.0
        };
        let tick_end_s = ((self.ticks + 1) * CONTROL_PERIOD_US) as f64 * 1e-6;
        if self.motors.armed {
            for (i, p) in self.motor_params.iter().enumerate() {
                // Fault injection: the output wired to this rotor (its own without faults).
                let output = self.faults.output_of_rotor(tick_end_s, i);
                let command = self.motors.commands.get(output).copied().unwrap_or(0.0);
                targets[i] = p.steady_speed_rad_s(f64::from(command)) * (1.0 - sag).max(0.0).sqrt();
            }
        }
        let steady = w.steady_wind_ned_mps != [0.0; 3];
        if w.gust_s > 0.0 || w.gusts.iter().any(Option::is_some) || steady || w.turbulence.is_some()
        {
            let gusting = (w.gust_start_s..w.gust_start_s + w.gust_s).contains(&now_s);
            let mut wind = if gusting { Vector3::from(w.gust_ned_mps) } else { Vector3::zeros() };
            for gust in w.gusts.iter().flatten() {
                wind += gust.wind_ned_mps(now_s);
            }
            // Added only when present, so that a world without them flies bit for bit as before.
            if steady {
                wind += Vector3::from(w.steady_wind_ned_mps);
            }
            if let Some(turbulence) = self.turbulence.as_mut() {
                // The state at the start of the first tick is the stationary draw; then one step
                // of a control period per tick.
                if self.ticks > 0 {
                    turbulence.step(CONTROL_PERIOD_US as f64 * 1e-6);
                }
                wind += turbulence.velocity_ned_mps();
            }
            if wind != self.physics.model().wind_ned_mps {
                self.physics.set_wind(wind);
            }
        }
        self.physics.set_rotor_targets(&targets);
        // Fault injection: a rotor's thrust scaled from this tick on (nothing without faults).
        if let Some(factors) = self.faults.thrust_factors(tick_end_s) {
            self.physics.set_rotor_thrust_factors(&factors);
        }

        let mut sum = RawSample::default();
        let mut sum_truth = RawSample::default();
        for _ in 0..self.samples_per_tick {
            for _ in 0..self.steps_per_sample {
                self.physics.step();
            }
            let (state, derivative) = (self.physics.state(), self.physics.derivative());
            let (s, t) = self.imu_model.sample(state, derivative, self.physics.rotor_angle_rad());
            sum.gyro_rad_s += s.gyro_rad_s;
            sum.accel_mps2 += s.accel_mps2;
            sum_truth.gyro_rad_s += t.gyro_rad_s;
            sum_truth.accel_mps2 += t.accel_mps2;
        }
        let n = f64::from(self.samples_per_tick);
        let to_f32 = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
        self.last_sample = ImuSample {
            gyro_rad_s: to_f32(sum.gyro_rad_s / n),
            accel_mps2: to_f32(sum.accel_mps2 / n),
        };
        // Fault injection: the sample as a failing IMU delivers it (unchanged without faults).
        let delivered = self.faults.corrupt_imu(tick_end_s, &mut self.last_sample);
        self.last_truth_sample = RawSample {
            gyro_rad_s: sum_truth.gyro_rad_s / n,
            accel_mps2: sum_truth.accel_mps2 / n,
        };
        self.imu.latest = delivered.then_some(self.last_sample);

        let rotor_speeds = self.physics.state().rotor_speed_rad_s;
        let shaft_power_w: f64 = self
            .motor_params
            .iter()
            .zip(rotor_speeds.iter())
            .map(|(p, w)| p.torque_coefficient_nm_per_rad2_s2 * w * w * w.abs())
            .sum();
        self.battery_reading = self.battery.step(CONTROL_PERIOD_US as f64 * 1e-6, shaft_power_w);

        self.ticks += 1;
        let ring_len = self.telemetry_ring.len();
        let slot = (self.ticks as usize) % ring_len;
        let speeds = self.physics.state().rotor_speed_rad_s;
        for (i, p) in self.motor_params.iter().enumerate() {
            self.telemetry_ring[slot][i] = dshot::quantise_speed(speeds[i], p.pole_pairs) as f32;
        }
        for (i, delay) in self.telemetry_delay_ticks.iter().enumerate() {
            let answer = (self.ticks as usize > *delay)
                .then(|| self.telemetry_ring[(slot + ring_len - delay) % ring_len][i]);
            let lost = w.telemetry_loss_probability > 0.0
                && self.world_rng.uniform() < w.telemetry_loss_probability;
            if self.faults.speed_report_lost(tick_end_s, i) {
                // The ESC stopped answering (fault injection): no speed at all.
                self.reported_rad_s[i] = None;
            } else if !lost {
                // A lost answer leaves the previous one in place, as the DShot driver does.
                self.reported_rad_s[i] = answer;
            }
            self.motors.speeds_rad_s[i] = self.reported_rad_s[i];
        }
    }

    /// What the board's battery sensors read in the latest tick, handed to the control tick as
    /// its [`BatterySensor`](firmware::app::hal::BatterySensor).
    pub fn battery_reading(&self) -> Option<BatteryReading> {
        Some(self.battery_reading)
    }

    /// The simulated pack (its truth).
    pub fn battery(&self) -> &SimBattery {
        &self.battery
    }

    /// One control period of a flight application on this board: [`SimBoard::tick`], then one
    /// step of `app` on the ports at the tick's end.
    pub fn tick_and_step<A: FlightApp>(&mut self, app: &mut A) {
        self.tick();
        let now_us = self.now_us();
        let (imu, motors) = self.ports();
        app.step(now_us, imu, motors);
    }

    /// The IMU and motor ports, borrowed together for one application step.
    pub fn ports(&mut self) -> (&mut SimImu, &mut SimMotors) {
        (&mut self.imu, &mut self.motors)
    }

    /// The motor port.
    pub fn motors(&self) -> &SimMotors {
        &self.motors
    }

    /// The motor port, mutably (arming, disarming, commands from a scenario).
    pub fn motors_mut(&mut self) -> &mut SimMotors {
        &mut self.motors
    }

    /// Board time at the end of the last tick, µs (what the application's `now_us` is).
    pub fn now_us(&self) -> u64 {
        self.ticks * CONTROL_PERIOD_US
    }

    /// Board time, s.
    pub fn time_s(&self) -> f64 {
        self.now_us() as f64 * 1e-6
    }

    /// The 2 kHz sample produced by the last tick (also after the application has read it).
    pub fn last_sample(&self) -> ImuSample {
        self.last_sample
    }

    /// The error-free counterpart of [`Self::last_sample`] (same averaging), IMU axes, f64.
    pub fn last_truth_sample(&self) -> RawSample {
        self.last_truth_sample
    }

    /// The physics (state, hand, model).
    pub fn physics(&self) -> &Physics {
        &self.physics
    }

    /// The physics, mutably (throw, catch, release, set state).
    pub fn physics_mut(&mut self) -> &mut Physics {
        &mut self.physics
    }

    /// The fault injector ([`crate::faults`]): add faults while flying.
    pub fn faults_mut(&mut self) -> &mut FaultInjector {
        &mut self.faults
    }

    /// Whether the external pose is lost now (a [`crate::faults::FaultKind::PoseLost`] is active
    /// at [`Self::now_us`]): whoever sends poses for this board skips them.
    pub fn pose_lost(&self) -> bool {
        self.faults.pose_lost(self.time_s())
    }

    /// The IMU model (its pose on the body).
    pub fn imu_model(&self) -> &ImuModel {
        &self.imu_model
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The air velocity the physics sees in each of `ticks` ticks of a board in `world`.
    fn air_velocities(world: WorldEffects, ticks: usize) -> Vec<Vector3<f64>> {
        let airframe = Airframe::builtin("paper-quad").unwrap();
        let config = SimConfig { world, arming: Arming::Disarmed, ..SimConfig::default() };
        let mut board = SimBoard::new(&airframe, &config);
        (0..ticks)
            .map(|_| {
                board.tick();
                board.physics().model().wind_ned_mps
            })
            .collect()
    }

    fn turbulence() -> Turbulence {
        Turbulence { sigma_ned_mps: [0.6, 0.6, 0.3], correlation_s: 1.0, seed: 5 }
    }

    #[test]
    fn without_wind_the_air_is_the_gusts_alone() {
        let world = WorldEffects::default();
        assert_eq!(world.steady_wind_ned_mps, [0.0; 3]);
        assert_eq!(world.turbulence, None);
        let gust = Gust {
            shape: GustShape::OneMinusCosine,
            peak_ned_mps: [2.0, -1.0, 0.5],
            start_s: 0.1,
            duration_s: 0.2,
        };
        let gusty = WorldEffects {
            gust_ned_mps: [0.5, 0.25, 0.0],
            gust_start_s: 0.05,
            gust_s: 0.1,
            gusts: [Some(gust), None],
            ..world
        };
        for (tick, air) in air_velocities(gusty, 800).into_iter().enumerate() {
            let now_s = (tick as u64 * CONTROL_PERIOD_US) as f64 * 1e-6;
            let first = if (0.05..0.05 + 0.1).contains(&now_s) {
                Vector3::new(0.5, 0.25, 0.0)
            } else {
                Vector3::zeros()
            };
            // Exactly the sum of the gusts, with nothing added.
            assert_eq!(air, first + gust.wind_ned_mps(now_s), "tick {tick}");
        }
        assert!(air_velocities(world, 100).iter().all(|air| *air == Vector3::zeros()));
    }

    #[test]
    fn the_steady_wind_and_the_turbulence_add_to_the_gusts() {
        let steady = [3.0, -4.0, 0.0];
        let gust = Gust {
            shape: GustShape::Step,
            peak_ned_mps: [1.0, 1.0, 0.0],
            start_s: 0.1,
            duration_s: 0.1,
        };
        let world = WorldEffects {
            steady_wind_ned_mps: steady,
            turbulence: Some(turbulence()),
            gusts: [None, Some(gust)],
            ..WorldEffects::default()
        };
        let mut process = TurbulenceProcess::new(turbulence());
        for (tick, air) in air_velocities(world, 600).into_iter().enumerate() {
            let now_s = (tick as u64 * CONTROL_PERIOD_US) as f64 * 1e-6;
            if tick > 0 {
                process.step(CONTROL_PERIOD_US as f64 * 1e-6);
            }
            let expected =
                gust.wind_ned_mps(now_s) + Vector3::from(steady) + process.velocity_ned_mps();
            assert!((air - expected).norm() < 1e-12, "tick {tick}: {air} against {expected}");
        }
    }

    #[test]
    fn the_mean_air_velocity_is_the_steady_wind() {
        let steady = Vector3::new(3.0, -4.0, 0.0);
        let world = WorldEffects {
            steady_wind_ned_mps: steady.into(),
            turbulence: Some(turbulence()),
            ..WorldEffects::default()
        };
        // 60 s: the mean of a process of correlation time τ over T scatters by σ·√(2τ/T)
        // (0.11 m/s horizontally here); the tolerance is three times that.
        let air = air_velocities(world, 120_000);
        let mean = air.iter().sum::<Vector3<f64>>() / air.len() as f64;
        let tolerance = 3.0 * 0.6 * (2.0 * 1.0 / 60.0f64).sqrt();
        assert!((mean - steady).abs().max() < tolerance, "mean {mean}");
        // And the turbulence is there: the air is not the steady wind alone.
        let spread = air.iter().map(|a| (a - steady).x.powi(2)).sum::<f64>() / air.len() as f64;
        assert!(spread.sqrt() > 0.3, "{}", spread.sqrt());
    }

    #[test]
    fn the_turbulence_has_its_configured_deviation_and_correlation_time() {
        let dt_s = CONTROL_PERIOD_US as f64 * 1e-6;
        for (sigma_ned_mps, correlation_s, seed) in
            [([1.0, 1.0, 0.5], 1.0, 1), ([0.3, 0.3, 0.15], 3.0, 2)]
        {
            let mut process =
                TurbulenceProcess::new(Turbulence { sigma_ned_mps, correlation_s, seed });
            // 1,500 correlation times, kept every 10 ms.
            let every = 20;
            let series: Vec<Vector3<f64>> = (0..(1500.0 * correlation_s / dt_s) as usize)
                .map(|_| process.step(dt_s))
                .step_by(every)
                .collect();
            let lag = (correlation_s / (dt_s * every as f64)).round() as usize;
            for axis in 0..3 {
                let x: Vec<f64> = series.iter().map(|v| v[axis]).collect();
                let n = x.len() as f64;
                let mean = x.iter().sum::<f64>() / n;
                let variance = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
                let sigma = variance.sqrt();
                let configured = sigma_ned_mps[axis];
                assert!(
                    (sigma - configured).abs() < 0.2 * configured,
                    "axis {axis}: σ {sigma} against {configured}"
                );
                // The autocorrelation at a lag of τ is e⁻¹ for the configured τ.
                let covariance =
                    x.windows(lag + 1).map(|w| (w[0] - mean) * (w[lag] - mean)).sum::<f64>()
                        / (n - lag as f64);
                let rho = covariance / variance;
                let tau = -correlation_s / rho.ln();
                assert!(
                    (tau - correlation_s).abs() < 0.2 * correlation_s,
                    "axis {axis}: τ {tau} s against {correlation_s} s (ρ {rho})"
                );
            }
        }
    }
}
