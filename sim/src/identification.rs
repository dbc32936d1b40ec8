//! Throw-and-fly identification runs against the truth: the simulator knows the exact
//! effectiveness, motor time constants and hover thrust axis of every airframe, so the firmware's
//! learner (`flight::learner`, run by `firmware::app` exactly as on the board) can be scored in
//! physical units.
//!
//! - [`TrueModel`]: what a perfect identification would find, in the learner's own frame and
//!   units (IMU axes; G1 per unit squared motor speed; G2 per unit motor acceleration).
//! - [`identify`]: one throw-to-fly run (throw, free fall, excitation), capturing the learned
//!   model at a chosen time into the excitation and at its end, scored by [`Scores`].
//! - [`monte_carlo`]: the same over random airframes and throws, in parallel.
//!
//! How G1 errors are scored: per row, the RMS over the motors of the error divided by the RMS of
//! that row of the truth; a row whose truth is below a tenth of its block's RMS (e.g. the x row
//! of the specific force on a flat quad whose IMU is not rotated, which is zero) is divided by
//! the block's RMS instead, so an all-zero row is judged against the size of its neighbours.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::airframe::{Airframe, STANDARD_GRAVITY_MPS2};
use crate::board::{SimBoard, SimConfig};
use crate::hand::ThrowSpec;
use crate::rng::Rng;
use crate::scenario::{with_firmware_app, FirmwareApp};
use firmware::app::ControlCommand;
use flight::learner::{FlightPhase, LearnedModel, MAX_MOTORS};
use flight::thrust_axis::{HoverProblem, ThrustAxisSolver};

/// The exact model of an airframe in the learner's frame and units.
#[derive(Clone, Debug, PartialEq)]
pub struct TrueModel {
    /// Motors.
    pub motors: usize,
    /// G1 per unit squared speed, IMU axes: rows 0–2 m/s², rows 3–5 rad/s², per (rad/s)².
    pub g1_per_speed2: [[f64; MAX_MOTORS]; 6],
    /// G2, rad/s² per rad/s², IMU axes.
    pub g2: [[f64; MAX_MOTORS]; 3],
    /// Motor time constants, s.
    pub tau_s: [f64; MAX_MOTORS],
    /// Motor speed at full command, rad/s.
    pub omega_full_rad_s: [f64; MAX_MOTORS],
    /// The hover thrust axis `q_U^T` found from the exact G1 (thrust frame into IMU frame).
    pub q_thrust_to_imu: UnitQuaternion<f64>,
    /// IMU offset from the centre of gravity, IMU axes, m.
    pub r_imu_m: Vector3<f64>,
}

impl TrueModel {
    /// The exact model of `airframe` (G1 from thrust and drag-torque coefficients, rotor
    /// positions and axes, mass and inertia; G2 from the rotor inertia).
    pub fn of(airframe: &Airframe) -> Self {
        let m = airframe.rotor_count();
        let rotation: Matrix3<f64> = *airframe.q_imu_body().to_rotation_matrix().matrix();
        let inertia_inv = airframe
            .inertia_matrix()
            .try_inverse()
            .expect("a validated airframe has a positive-definite inertia");
        let wrench = airframe.wrench_per_speed_squared();
        let mut model = TrueModel {
            motors: m,
            g1_per_speed2: [[0.0; MAX_MOTORS]; 6],
            g2: [[0.0; MAX_MOTORS]; 3],
            tau_s: [0.0; MAX_MOTORS],
            omega_full_rad_s: [0.0; MAX_MOTORS],
            q_thrust_to_imu: UnitQuaternion::identity(),
            r_imu_m: airframe.q_imu_body() * airframe.r_imu_m(),
        };
        for i in 0..m {
            let motor = airframe.rotor_motor(i);
            let force = Vector3::new(wrench[(0, i)], wrench[(1, i)], wrench[(2, i)]);
            let torque = Vector3::new(wrench[(3, i)], wrench[(4, i)], wrench[(5, i)]);
            let f = rotation * force / airframe.mass_kg;
            let t = rotation * (inertia_inv * torque);
            let spin = airframe.rotors[i].spin.sign();
            let g2 = rotation
                * (inertia_inv * (-airframe.thrust_axis(i) * spin * motor.rotor_inertia_kg_m2));
            for k in 0..3 {
                model.g1_per_speed2[k][i] = f[k];
                model.g1_per_speed2[3 + k][i] = t[k];
                model.g2[k][i] = g2[k];
            }
            model.tau_s[i] = motor.tau_s;
            model.omega_full_rad_s[i] = motor.omega_max_rad_s;
        }
        model.q_thrust_to_imu = model.solve_axis().unwrap_or_else(UnitQuaternion::identity);
        model
    }

    fn solve_axis(&self) -> Option<UnitQuaternion<f64>> {
        let m = self.motors;
        let rows: Vec<Vec<f32>> = (0..6)
            .map(|k| {
                (0..m)
                    .map(|i| (self.g1_per_speed2[k][i] * self.omega_full_rad_s[i].powi(2)) as f32)
                    .collect()
            })
            .collect();
        let problem =
            HoverProblem::new([&rows[0], &rows[1], &rows[2]], [&rows[3], &rows[4], &rows[5]])
                .ok()?
                .with_gravity(STANDARD_GRAVITY_MPS2 as f32)
                .ok()?;
        let mut solver = ThrustAxisSolver::default();
        // Several calls: the warm start refines the eigenvector to full precision.
        let mut solution = solver.solve(&problem).ok()?;
        for _ in 0..4 {
            solution = solver.solve(&problem).ok()?;
        }
        Some(quaternion(solution.q_thrust_to_imu))
    }
}

fn quaternion(wxyz: [f32; 4]) -> UnitQuaternion<f64> {
    let [w, x, y, z] = wxyz.map(f64::from);
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
}

/// How a learned model compares with the truth.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Scores {
    /// Relative RMS error of each G1 row (see the module doc).
    pub g1_row_rel: [f64; 6],
    /// Relative RMS error of the specific-force block (rows 0–2) and of the angular-acceleration
    /// block (rows 3–5): RMS of all the block's errors over the RMS of its true entries.
    pub g1_block_rel: [f64; 2],
    /// Largest |τ − τ_true| over the motors, s.
    pub tau_error_max_s: f64,
    /// Angle between the learned and the true thrust direction, rad (NaN without an axis).
    pub axis_angle_rad: f64,
    /// |Δroll|, |Δpitch|, |Δyaw| of the learned `q_U^T` against the truth, rad (NaN without).
    pub euler_error_rad: [f64; 3],
    /// Whether a thrust axis was found.
    pub axis_found: bool,
}

impl Scores {
    /// Largest relative RMS error over the three specific-force rows.
    pub fn g1_force_rel(&self) -> f64 {
        self.g1_row_rel[..3].iter().copied().fold(0.0, f64::max)
    }

    /// Largest relative RMS error over the three angular-acceleration rows.
    pub fn g1_rotation_rel(&self) -> f64 {
        self.g1_row_rel[3..].iter().copied().fold(0.0, f64::max)
    }

    /// Score `learned` against `truth`.
    pub fn of(learned: &LearnedModel, truth: &TrueModel) -> Self {
        let m = truth.motors;
        let mut scores = Scores::default();
        for block in 0..2 {
            let rows = 3 * block..3 * block + 3;
            let rms = |k: usize| {
                ((0..m).map(|i| truth.g1_per_speed2[k][i].powi(2)).sum::<f64>() / m as f64).sqrt()
            };
            let block_rms =
                (rows.clone().map(|k| rms(k).powi(2)).sum::<f64>() / 3.0).sqrt().max(1e-300);
            let mut block_error2 = 0.0;
            for k in rows {
                let error = ((0..m)
                    .map(|i| {
                        (f64::from(learned.g1_per_speed2[k][i]) - truth.g1_per_speed2[k][i]).powi(2)
                    })
                    .sum::<f64>()
                    / m as f64)
                    .sqrt();
                let scale = if rms(k) < 0.1 * block_rms { block_rms } else { rms(k) };
                scores.g1_row_rel[k] = error / scale;
                block_error2 += error * error / 3.0;
            }
            scores.g1_block_rel[block] = block_error2.sqrt() / block_rms;
        }
        scores.tau_error_max_s = (0..m)
            .map(|i| (f64::from(learned.motor[i].tau_s) - truth.tau_s[i]).abs())
            .fold(0.0, f64::max);
        match &learned.thrust_axis {
            Some(axis) => {
                let q = quaternion(axis.q_thrust_to_imu);
                let down = Vector3::new(0.0, 0.0, -1.0);
                scores.axis_angle_rad = (q * down).angle(&(truth.q_thrust_to_imu * down));
                let (r, p, y) = q.euler_angles();
                let (rt, pt, yt) = truth.q_thrust_to_imu.euler_angles();
                scores.euler_error_rad = [wrap(r - rt), wrap(p - pt), wrap(y - yt)];
                scores.axis_found = true;
            }
            None => {
                scores.axis_angle_rad = f64::NAN;
                scores.euler_error_rad = [f64::NAN; 3];
            }
        }
        scores
    }
}

fn wrap(angle: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    (angle + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI
}

/// How long the learner keeps learning after the excitation before the "end" model is taken, s:
/// the last motor's speed settles back to idle (about three time constants).
pub const SETTLE_AFTER_EXCITATION_S: f64 = 0.08;

/// A throw of the throw-to-fly runs (identification and recovery): straight up from the hand.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Throw {
    /// Body rate at release, rad/s.
    pub rate_body_rad_s: Vector3<f64>,
    /// Apex above the release point, m.
    pub apex_m: f64,
    /// Horizontal release velocity (north, east), m/s.
    pub horizontal_mps: [f64; 2],
    /// How long the hand pushes, s, taper included.
    pub push_s: f64,
    /// How long the hand takes to let go at the end of the push, s (see [`ThrowSpec::taper_s`]).
    pub taper_s: f64,
}

/// The push of the nominal throws, s (the seed paper's hand).
pub const NOMINAL_PUSH_S: f64 = 0.15;

impl Throw {
    /// The seed paper's: a 3.5 m parabola released at (400, 400, 100) °/s.
    pub fn paper() -> Self {
        Self {
            rate_body_rad_s: Vector3::new(400.0, 400.0, 100.0).map(f64::to_radians),
            apex_m: 3.5,
            horizontal_mps: [0.0, 0.0],
            push_s: NOMINAL_PUSH_S,
            taper_s: 0.0,
        }
    }

    /// A random throw of the Monte Carlo batches: body rate 300–600 °/s about a random axis, apex
    /// 2.5–4.5 m above the release, up to 2 m/s sideways in a random direction.
    pub fn random(rng: &mut Rng) -> Self {
        let direction = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let rate_body_rad_s = direction * rng.range(300.0, 600.0).to_radians();
        let apex_m = rng.range(2.5, 4.5);
        let heading = rng.range(0.0, std::f64::consts::TAU);
        let speed = rng.range(0.0, 2.0);
        Self {
            rate_body_rad_s,
            apex_m,
            horizontal_mps: [speed * heading.cos(), speed * heading.sin()],
            push_s: NOMINAL_PUSH_S,
            taper_s: 0.0,
        }
    }

    /// What the hand does.
    pub fn spec(&self) -> ThrowSpec {
        let mut spec = ThrowSpec::vertical(self.apex_m, self.rate_body_rad_s, self.push_s)
            .with_taper(self.taper_s);
        spec.release_velocity_ned_mps.x = self.horizontal_mps[0];
        spec.release_velocity_ned_mps.y = self.horizontal_mps[1];
        spec
    }
}

/// One throw-to-fly identification run.
#[derive(Clone, Debug, PartialEq)]
pub struct IdentifyConfig {
    /// The throw.
    pub throw: Throw,
    /// Capture the learned model this long after the excitation began, s.
    pub capture_after_s: f64,
    /// Give the firmware the true IMU offset (as a calibrated board has); otherwise zero.
    pub known_imu_offset: bool,
    /// Board (noise seed and the rest).
    pub board: SimConfig,
}

impl IdentifyConfig {
    /// The seed paper's experiment: a 3.5 m parabola released at (400, 400, 100) °/s.
    pub fn paper() -> Self {
        Self {
            throw: Throw::paper(),
            capture_after_s: 0.300,
            known_imu_offset: true,
            board: SimConfig {
                start_position_ned_m: Vector3::new(0.0, 0.0, -1.5),
                ..SimConfig::default()
            },
        }
    }
}

/// What an identification run produced.
#[derive(Clone, Debug, PartialEq)]
pub struct IdentifyReport {
    /// The truth.
    pub truth: TrueModel,
    /// The learned model at `capture_after_s` into the excitation (if the excitation got there).
    pub at_capture: Option<LearnedModel>,
    /// The learned model at the end of the excitation.
    pub at_end: Option<LearnedModel>,
    /// Time from release to the start of the excitation, s.
    pub release_to_excitation_s: Option<f64>,
    /// Time from the start of the excitation to the first thrust axis, s.
    pub excitation_to_axis_s: Option<f64>,
    /// Largest motor command seen during the run (0 when nothing spun).
    pub max_command: f32,
}

/// Throw `airframe` as `config` says with the firmware armed for throw-to-fly, and record what
/// its learner learned (the craft is not caught: the run ends at the end of the excitation, or
/// 1.5 s after release without one).
pub fn identify(airframe: &Airframe, config: &IdentifyConfig) -> IdentifyReport {
    let truth = TrueModel::of(airframe);
    with_firmware_app(|app| run(app, airframe, config, truth))
}

fn run(
    app: &mut FirmwareApp<'_>,
    airframe: &Airframe,
    config: &IdentifyConfig,
    truth: TrueModel,
) -> IdentifyReport {
    let mut board = SimBoard::new(airframe, &config.board);
    if config.known_imu_offset {
        let r = truth.r_imu_m;
        app.background.set_imu_offset(Some([r.x as f32, r.y as f32, r.z as f32]));
    }
    app.submit(ControlCommand::ArmThrowToFly);
    let mut report = IdentifyReport {
        truth,
        at_capture: None,
        at_end: None,
        release_to_excitation_s: None,
        excitation_to_axis_s: None,
        max_command: 0.0,
    };
    let hold_ticks = 1000; // 0.5 s in the hand
    let mut excitation_start_s: Option<f64> = None;
    let mut excitation_end_s: Option<f64> = None;
    let spec = config.throw.spec();
    for tick in 0..10_000u64 {
        if tick == hold_ticks {
            board.physics_mut().throw(&spec);
        }
        board.tick_and_step(app);
        let t_s = board.time_s();
        let snapshot = app.snapshot();
        report.max_command = snapshot.commands.iter().copied().fold(report.max_command, f32::max);
        let learned = app.background.results().learned;
        match snapshot.phase {
            FlightPhase::Exciting => {
                let start = *excitation_start_s.get_or_insert(t_s);
                if report.release_to_excitation_s.is_none() {
                    let released = board.physics().hand().released_at_s();
                    report.release_to_excitation_s = released.map(|r| t_s - r);
                }
                if report.excitation_to_axis_s.is_none() && learned.thrust_axis.is_some() {
                    report.excitation_to_axis_s = Some(t_s - start);
                }
                if report.at_capture.is_none() && t_s - start >= config.capture_after_s - 1e-9 {
                    report.at_capture = Some(learned);
                }
            }
            FlightPhase::Done => {
                let start = excitation_start_s.unwrap_or(t_s);
                let end = *excitation_end_s.get_or_insert(t_s);
                if report.at_capture.is_none() && t_s - start >= config.capture_after_s - 1e-9 {
                    report.at_capture = Some(learned);
                }
                if t_s - end >= SETTLE_AFTER_EXCITATION_S {
                    report.at_end = Some(learned);
                    report.at_capture.get_or_insert(learned);
                    break;
                }
            }
            _ => {}
        }
        let released = board.physics().hand().released_at_s();
        if released.is_some_and(|r| t_s - r > 1.5) || board.physics().state().position_ned_m.z > 0.0
        {
            break;
        }
    }
    report
}

/// One Monte Carlo case: a random airframe and a random throw ([`Throw::random`]).
pub fn random_case(seed: u64) -> (Airframe, IdentifyConfig) {
    let airframe = Airframe::random(seed);
    let mut rng = Rng::new(seed ^ 0x1D_E471_F1CA_7104);
    let mut config = IdentifyConfig::paper();
    config.throw = Throw::random(&mut rng);
    config.capture_after_s = 10.0; // the end of the excitation
    config.board.seed = seed;
    (airframe, config)
}

/// Result of one Monte Carlo case.
#[derive(Clone, Debug, PartialEq)]
pub struct CaseResult {
    /// The seed.
    pub seed: u64,
    /// Motors.
    pub motors: usize,
    /// Scores at the end of the excitation (None when it never ran).
    pub scores: Option<Scores>,
}

/// Runs `runs` random cases (seeds `seed..seed + runs`) on `threads` workers.
pub fn monte_carlo(
    runs: usize,
    seed: u64,
    threads: usize,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<CaseResult> {
    crate::stats::run_seeds(runs, seed, threads, progress, |seed| {
        let (airframe, config) = random_case(seed);
        let report = identify(&airframe, &config);
        let scores = report.at_end.as_ref().map(|m| Scores::of(m, &report.truth));
        CaseResult { seed, motors: airframe.rotor_count(), scores }
    })
}
