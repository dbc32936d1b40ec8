//! Throw-and-fly end to end: the firmware application (exactly as the board runs it) is armed,
//! thrown, identifies its actuators, and must recover to a hover and hold a position; scored
//! against the simulator's truth in metres, seconds and degrees.
//!
//! - [`fly`]: one run. The hand throws the craft on a parabola; after the excitation the
//!   firmware's controller takes over. With [`FlyConfig::mocap`] the simulator sends the true
//!   pose of the centre of gravity (position, heading) at 100 Hz with millimetre noise, as a
//!   motion-capture system would, through the same command the bridge and the protocol use.
//! - [`FlyReport`]: whether and when it hovered, the worst altitude loss below the release point,
//!   the position error over the hold, and how the run ended ([`Outcome`]).
//!
//! "Hovering" means: the body rate below [`HOVER_RATE_RAD_S`], the vertical speed below
//! [`HOVER_CLIMB_MPS`] and the thrust axis within [`HOVER_TILT_RAD`] of up, held for
//! [`HOVER_HOLD_S`].

use nalgebra::{UnitQuaternion, Vector3};

use crate::airframe::Airframe;
use crate::board::{SimBoard, SimConfig};
use crate::dynamics::State;
use crate::identification::{Scores, Throw, TrueModel};
use crate::rng::Rng;
use crate::scenario::{with_firmware_app, FirmwareApp, FlightApp};
use firmware::app::{ControlCommand, Failsafe};
use flight::learner::FlightPhase;
use protocol::ExternalPose;

/// Body rate below which the craft may count as hovering, rad/s (20 °/s).
pub const HOVER_RATE_RAD_S: f64 = 0.35;
/// Vertical speed below which the craft may count as hovering, m/s.
pub const HOVER_CLIMB_MPS: f64 = 0.3;
/// Tilt of the true thrust axis from up below which the craft may count as hovering, rad (10°).
pub const HOVER_TILT_RAD: f64 = 0.175;
/// How long those must hold to call it a hover, s.
pub const HOVER_HOLD_S: f64 = 0.5;
/// Motion-capture rate, Hz.
pub const MOCAP_RATE_HZ: f64 = 100.0;
/// Motion-capture position noise, one standard deviation per axis, m.
pub const MOCAP_NOISE_M: f64 = 0.001;
/// Motion-capture heading noise, one standard deviation, rad (0.1°).
pub const MOCAP_HEADING_NOISE_RAD: f64 = 0.0017;

/// A motion-capture system: the true pose of the centre of gravity (world NED position, heading
/// of the body frame) at [`MOCAP_RATE_HZ`] with [`MOCAP_NOISE_M`] and [`MOCAP_HEADING_NOISE_RAD`]
/// of Gaussian noise, as the throw-and-fly runs and the SITL's `--mocap` send it.
#[derive(Clone, Debug)]
pub struct MotionCapture {
    rng: Rng,
    next_us: u64,
}

impl MotionCapture {
    /// A system whose noise is drawn from `seed`.
    pub fn new(seed: u64) -> Self {
        Self { rng: Rng::new(seed ^ 0x6d_6f63_6170), next_us: 0 }
    }

    /// The pose when one is due at `now_us`.
    pub fn sample(&mut self, state: &State, now_us: u64) -> Option<ExternalPose> {
        if now_us < self.next_us {
            return None;
        }
        self.next_us = now_us + (1e6 / MOCAP_RATE_HZ) as u64;
        let p = state.position_ned_m;
        let rng = &mut self.rng;
        let mut noisy = |value: f64, sigma: f64| (value + rng.normal() * sigma) as f32;
        Some(ExternalPose {
            position_ned_m: [
                noisy(p.x, MOCAP_NOISE_M),
                noisy(p.y, MOCAP_NOISE_M),
                noisy(p.z, MOCAP_NOISE_M),
            ],
            heading_rad: noisy(heading(&state.attitude()), MOCAP_HEADING_NOISE_RAD),
        })
    }
}

/// One throw-and-fly run.
#[derive(Clone, Debug, PartialEq)]
pub struct FlyConfig {
    /// The throw.
    pub throw: Throw,
    /// Give the firmware the true IMU offset (a calibrated board).
    pub known_imu_offset: bool,
    /// Send the pose at [`MOCAP_RATE_HZ`].
    pub mocap: bool,
    /// How long to fly after the release, s.
    pub flight_s: f64,
    /// Print the flight every 100 ms on stderr (time, position, setpoint, rates, mode).
    pub trace: bool,
    /// Board (noise seed, start position).
    pub board: SimConfig,
}

impl FlyConfig {
    /// The seed paper's experiment: a 3.5 m parabola released at (400, 400, 100) °/s from 1.5 m,
    /// motion capture on, 13 s of flight.
    pub fn paper() -> Self {
        Self {
            throw: Throw::paper(),
            known_imu_offset: true,
            mocap: true,
            flight_s: 13.0,
            trace: false,
            board: SimConfig {
                start_position_ned_m: Vector3::new(0.0, 0.0, -1.5),
                ..SimConfig::default()
            },
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
}

/// What a run measured.
#[derive(Clone, Debug, PartialEq)]
pub struct FlyReport {
    pub outcome: Outcome,
    /// Release → the controller engaged, s.
    pub release_to_engage_s: Option<f64>,
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
    /// The window over which `max_hold_error_m` was measured, s.
    pub hold_window_s: f64,
    /// Relative RMS error of the specific-force and angular-acceleration blocks of G1 against
    /// the truth ([`Scores::g1_block_rel`]): the learner's model when the controller engaged,
    /// the learner's model at the end (refined in flight) and the model flown at the end.
    pub g1_block_rel_at_engage: Option<[f64; 2]>,
    pub g1_block_rel_learned_at_end: Option<[f64; 2]>,
    pub g1_block_rel_flown_at_end: Option<[f64; 2]>,
    /// Models the flying controller moved towards (`PilotStatus::refinements`).
    pub refinements: u32,
}

/// G1 of the model `app` flies, back in the learner's terms (IMU axes, per squared speed),
/// scored against `truth`.
fn flown_scores(app: &FirmwareApp<'_>, truth: &TrueModel) -> Option<[f64; 2]> {
    let flown = app.control.flown_model()?;
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
    let hold_window_s = 10.0f64.min(config.flight_s * 0.8);
    with_firmware_app(|app| {
        if config.known_imu_offset {
            let r = truth.r_imu_m;
            app.background.set_imu_offset(Some([r.x as f32, r.y as f32, r.z as f32]));
        }
        app.control.command(ControlCommand::ArmThrowToFly, 0);
        let mut report = FlyReport {
            outcome: Outcome::NoIdentification,
            release_to_engage_s: None,
            release_to_hover_s: None,
            release_z_m: 0.0,
            max_drop_below_release_m: 0.0,
            setpoint_ned_m: None,
            max_hold_error_m: None,
            hold_window_s,
            g1_block_rel_at_engage: None,
            g1_block_rel_learned_at_end: None,
            g1_block_rel_flown_at_end: None,
            refinements: 0,
        };
        let hold_ticks = 1000u64; // 0.5 s in the hand
        let spec = config.throw.spec();
        let mut mocap = config.mocap.then(|| MotionCapture::new(config.board.seed));
        let mut hover_since: Option<f64> = None;
        let mut release_z: Option<f64> = None;
        let mut end_s = f64::INFINITY;
        let max_ticks = hold_ticks + ((1.0 + config.flight_s) * 2000.0) as u64;
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
            {
                let (imu, motors) = board.ports();
                app.step(now_us, imu, motors);
            }
            let t_s = board.time_s();
            let snapshot = app.control.snapshot();
            let state = *board.physics().state();
            let Some(released_s) = board.physics().hand().released_at_s() else { continue };
            let release_z_m = *release_z.get_or_insert(state.position_ned_m.z);
            report.release_z_m = release_z_m;
            let since_release = t_s - released_s;
            report.max_drop_below_release_m =
                report.max_drop_below_release_m.max(state.position_ned_m.z - report.release_z_m);
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
                eprint!(
                    "true align {:6.1}°  f_sp {:5.2} {:5.2} {:5.2}  ",
                    true_alignment.to_degrees(),
                    p.specific_force_sp_ned_mps2[0],
                    p.specific_force_sp_ned_mps2[1],
                    p.specific_force_sp_ned_mps2[2]
                );
                eprintln!(
                    "t {:6.2} s  pos {:6.2} {:6.2} {:6.2} m  vel {:5.2} {:5.2} {:5.2} m/s  rate {:6.1} °/s  \
                     flying {} hold {} aligned {} {:5.1}° sp {:5.2} {:5.2} {:5.2}  est {:5.2} {:5.2} {:5.2}  tilt err {:5.1}°  sat {:04b}",
                    since_release,
                    state.position_ned_m.x, state.position_ned_m.y, state.position_ned_m.z,
                    state.velocity_ned_mps.x, state.velocity_ned_mps.y, state.velocity_ned_mps.z,
                    state.rate_body_rad_s.norm().to_degrees(),
                    p.flying, p.position_hold, p.heading_aligned, p.heading_alignment_rad.to_degrees(),
                    p.position_sp_ned_m[0], p.position_sp_ned_m[1], p.position_sp_ned_m[2],
                    p.velocity_ned_mps[0], p.velocity_ned_mps[1], p.velocity_ned_mps[2],
                    p.tilt_error_rad.to_degrees(), p.saturated,
                );
            }
            if snapshot.pilot.flying {
                if report.release_to_engage_s.is_none() {
                    let learned = app.background.results().learned;
                    report.g1_block_rel_at_engage = Some(Scores::of(&learned, &truth).g1_block_rel);
                }
                report.release_to_engage_s.get_or_insert(since_release);
                report.outcome = Outcome::Flying;
                if snapshot.pilot.position_hold {
                    let sp = Vector3::from(snapshot.pilot.position_sp_ned_m).cast::<f64>();
                    report.setpoint_ned_m = Some(sp);
                    if t_s >= end_s - hold_window_s {
                        let error = (state.position_ned_m - sp).norm();
                        let worst = report.max_hold_error_m.get_or_insert(0.0);
                        *worst = worst.max(error);
                    }
                }
                let hovering = state.rate_body_rad_s.norm() < HOVER_RATE_RAD_S
                    && state.velocity_ned_mps.z.abs() < HOVER_CLIMB_MPS
                    && thrust_tilt_rad(&state.attitude(), &thrust_dir_body) < HOVER_TILT_RAD;
                if hovering {
                    let since = *hover_since.get_or_insert(since_release);
                    if since_release - since >= HOVER_HOLD_S && report.release_to_hover_s.is_none()
                    {
                        report.release_to_hover_s = Some(since);
                    }
                } else {
                    hover_since = None;
                }
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
            if state.position_ned_m.z >= 0.0 {
                report.outcome = if report.release_to_engage_s.is_some() {
                    Outcome::Ground
                } else {
                    Outcome::NoIdentification
                };
                break;
            }
            if t_s >= end_s {
                break;
            }
        }
        if report.outcome == Outcome::Flying {
            let learned = app.background.results().learned;
            report.g1_block_rel_learned_at_end = Some(Scores::of(&learned, &truth).g1_block_rel);
            report.g1_block_rel_flown_at_end = flown_scores(app, &truth);
        }
        report.refinements = app.control.snapshot().pilot.refinements;
        report
    })
}

/// Heading of the body frame: yaw of its x axis about world z, rad.
pub fn heading(q_world_body: &UnitQuaternion<f64>) -> f64 {
    let x = q_world_body * Vector3::x();
    x.y.atan2(x.x)
}

/// Angle between the true hover thrust axis (`thrust_dir_body`, body axes) and up, rad.
fn thrust_tilt_rad(q_world_body: &UnitQuaternion<f64>, thrust_dir_body: &Vector3<f64>) -> f64 {
    let up = q_world_body * thrust_dir_body;
    (-up.z).clamp(-1.0, 1.0).acos()
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
}

/// Largest distance from the setpoint for [`Verdict::Held`], m (the 0.3 m).
pub const HOLD_BOUND_M: f64 = 0.3;

impl Verdict {
    /// The verdict of a report.
    pub fn of(report: &FlyReport) -> Self {
        match report.outcome {
            Outcome::Flying if report.release_to_hover_s.is_none() => Verdict::NeverHovered,
            Outcome::Flying if report.max_hold_error_m.is_some_and(|e| e < HOLD_BOUND_M) => {
                Verdict::Held
            }
            Outcome::Flying => Verdict::HoveredLoose,
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
    /// What was measured.
    pub report: FlyReport,
    /// Its classification.
    pub verdict: Verdict,
}

/// Runs `runs` random cases (seeds `seed..seed + runs`) on `threads` workers; `progress` is
/// called with the number done after each.
pub fn monte_carlo(
    runs: usize,
    seed: u64,
    threads: usize,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<CaseResult> {
    crate::stats::run_seeds(runs, seed, threads, progress, |seed| {
        let (airframe, config) = random_case(seed);
        let report = fly(&airframe, &config);
        let verdict = Verdict::of(&report);
        CaseResult { seed, motors: airframe.rotor_count(), report, verdict }
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
}
