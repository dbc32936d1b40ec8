//! In-flight identification against the simulator's truth: the firmware application
//! (`firmware::app`, exactly as the board runs it), armed for throw-to-fly, is thrown on the seed
//! paper's parabola; its learner must find each motor's time constant, the effectiveness G1 and
//! the hover thrust axis (the IMU's rotation) within the bounds. The craft falls
//! afterwards: recovery is the controller's issue. Also: what is not a throw never spins a motor.
//!
//! `cargo test -p tests --test identification -- --nocapture` prints the measured figures.

use firmware::app::ControlCommand;
use flight::learner::FlightPhase;
use nalgebra::Vector3;
use sim::airframe::Airframe;
use sim::board::{SimBoard, SimConfig};
use sim::identification::{identify, IdentifyConfig, IdentifyReport, Scores};
use sim::scenario::{with_firmware_app, FlightApp};

fn run(name: &str, capture_after_s: f64) -> (Scores, IdentifyReport) {
    let airframe = Airframe::builtin(name).unwrap();
    let mut config = IdentifyConfig::paper();
    config.capture_after_s = capture_after_s;
    let report = identify(&airframe, &config);
    let learned = report.at_capture.expect("the throw was detected and the excitation ran");
    let scores = Scores::of(&learned, &report.truth);
    eprintln!(
        "{name}: G1 rows (fx fy fz p q r) {:?} %, largest τ error {:.3} ms, thrust axis {:.3}° off, \
         roll/pitch/yaw errors {:?}°, release → excitation {:.1} ms, excitation → first axis \
         {:.1} ms",
        scores.g1_row_rel.map(|e| (e * 1000.0).round() / 10.0),
        scores.tau_error_max_s * 1e3,
        scores.axis_angle_rad.to_degrees(),
        scores.euler_error_rad.map(|e| (e.to_degrees() * 1000.0).round() / 1000.0),
        report.release_to_excitation_s.unwrap_or(f64::NAN) * 1e3,
        report.excitation_to_axis_s.unwrap_or(f64::NAN) * 1e3,
    );
    for i in 0..report.truth.motors {
        assert!(
            (f64::from(learned.motor[i].tau_s) - report.truth.tau_s[i]).abs() < 1e-3,
            "{name}: motor {i} τ {} s, true {} s",
            learned.motor[i].tau_s,
            report.truth.tau_s[i]
        );
    }
    (scores, report)
}

#[test]
fn seed_paper_quad_is_identified_within_300_ms_of_the_excitation() {
    let (scores, report) = run("paper-quad", 0.300);
    assert!(scores.axis_found, "a thrust axis within 300 ms");
    assert!(report.excitation_to_axis_s.unwrap() < 0.300);
    for (row, error) in scores.g1_row_rel.iter().enumerate() {
        assert!(*error <= 0.05, "G1 row {row}: relative RMS error {error}");
    }
    let [roll, pitch, yaw] = scores.euler_error_rad.map(f64::to_degrees);
    assert!(roll.abs() <= 0.5 && pitch.abs() <= 0.5, "roll {roll}°, pitch {pitch}°");
    assert!(yaw.abs() <= 1.0, "yaw {yaw}°");
    // The release delay (150 ms) passes before the excitation starts.
    assert!((report.release_to_excitation_s.unwrap() - 0.150).abs() < 0.002);
}

/// Larger airframes with slower motors (τ = 50 ms): the pulses are scaled to τ, so the
/// excitation takes 0.7–0.8 s; scored at its end. These do not reach the quad's 5 % per row
/// (hex-tilted's worst row is about 14 %, octo-flat's 9 %; see docs/benchmarks.md), but the
/// thrust axis and the time constants do.
#[test]
fn hexarotor_with_tilted_rotors_and_flat_octorotor_are_identified() {
    for name in ["hex-tilted", "octo-flat"] {
        let (scores, _) = run(name, 2.0);
        assert!(scores.axis_found, "{name}: a thrust axis");
        assert!(scores.axis_angle_rad.to_degrees() < 1.5, "{name}: axis {scores:?}");
        let worst = scores.g1_force_rel().max(scores.g1_rotation_rel());
        assert!(worst < 0.2, "{name}: worst G1 row {worst}");
    }
}

/// What the firmware did while the hand moved the craft.
#[derive(Debug, Default)]
struct Seen {
    max_command: f32,
    excited: bool,
    /// A throw began (acceleration above 20 m/s²) at least once.
    throw_started: bool,
    /// Releases refused by the free-fall check.
    releases_refused: u16,
}

/// A script for the hand at every 2 kHz tick; the firmware is armed for throw-to-fly throughout.
fn armed_through(hold_height_m: f64, ticks: u64, mut hand: impl FnMut(u64, &mut SimBoard)) -> Seen {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let config = SimConfig {
        start_position_ned_m: Vector3::new(0.0, 0.0, -hold_height_m),
        ..SimConfig::default()
    };
    let mut board = SimBoard::new(&airframe, &config);
    with_firmware_app(|app| {
        app.submit(ControlCommand::ArmThrowToFly);
        let mut seen = Seen::default();
        for tick in 0..ticks {
            hand(tick, &mut board);
            board.tick();
            let now_us = board.now_us();
            let (imu, motors) = board.ports();
            app.step(now_us, imu, motors);
            let snapshot = app.snapshot();
            seen.max_command = snapshot.commands.iter().copied().fold(seen.max_command, f32::max);
            seen.excited |= snapshot.phase == FlightPhase::Exciting;
            seen.throw_started |=
                matches!(snapshot.phase, FlightPhase::Throwing | FlightPhase::Released);
            seen.releases_refused = snapshot.releases_refused;
            assert!(snapshot.armed, "stays armed for a real throw");
        }
        eprintln!("{seen:?}");
        seen
    })
}

#[test]
fn a_craft_shaken_in_the_hand_never_starts_the_motors() {
    // Shaken violently up and down at 2 Hz with ±60 m/s² (±6 g: enough momentum for a throw),
    // turning ±3 rad/s about x, and never let go.
    let seen = armed_through(1.0, 8000, |tick, board| {
        let t = tick as f64 / 2000.0;
        let w = std::f64::consts::TAU * 2.0;
        let accel = Vector3::new(0.0, 0.0, 60.0 * (w * t).sin());
        let spin = Vector3::new(3.0 * w * (w * t).cos(), 0.0, 0.0);
        board.physics_mut().move_with_hand(accel, spin);
    });
    // Each swing's deceleration reads free fall for a few milliseconds, too short for the
    // release delay: the detector takes it for the end of a push that goes on.
    assert!(seen.throw_started, "the shake looked like the start of a throw");
    assert!(!seen.excited && seen.max_command == 0.0, "a shake spun the motors: {seen:?}");
}

#[test]
fn a_craft_put_down_hard_never_starts_the_motors() {
    // Held 15 cm above the ground, pushed down to 2 m/s in 0.1 s and let go just above it: it
    // hits the ground hard and lies there.
    let seen = armed_through(0.15, 6000, |tick, board| {
        if tick == 1000 {
            let spec = sim::hand::ThrowSpec {
                release_velocity_ned_mps: Vector3::new(0.0, 0.0, 2.0),
                release_rate_body_rad_s: Vector3::zeros(),
                duration_s: 0.05,
                taper_s: 0.0,
            };
            board.physics_mut().throw(&spec);
        }
    });
    assert!(seen.throw_started, "the impact looked like the start of a throw");
    assert!(!seen.excited && seen.max_command == 0.0, "a hard landing spun the motors: {seen:?}");
}

#[test]
fn a_craft_dropped_from_10_cm_never_starts_the_motors() {
    let seen = armed_through(0.10, 6000, |tick, board| {
        if tick == 1000 {
            board.physics_mut().release();
        }
    });
    assert!(seen.throw_started, "the impact looked like the start of a throw");
    assert!(!seen.excited && seen.max_command == 0.0, "a drop spun the motors: {seen:?}");
}

#[test]
fn a_disarm_during_the_excitation_stops_every_motor_in_the_same_step() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let config =
        SimConfig { start_position_ned_m: Vector3::new(0.0, 0.0, -1.5), ..SimConfig::default() };
    let mut board = SimBoard::new(&airframe, &config);
    with_firmware_app(|app| {
        let disarmed = tests::disarm_during_throw_to_fly(&mut board, app, 4000, |snapshot| {
            snapshot.commands.iter().any(|c| *c > 0.3)
        });
        assert!(disarmed, "the excitation started");
    });
}

/// Issue 28: random 4–8-rotor airframes (tilted rotors, any IMU pose) thrown at 900–1,000 °/s
/// about a random axis by a hand that lets go over 15–45 ms. At these rates the body's own
/// precession is as large as the motors' torques, so the rotational rows stand or fall with
/// the normalised inertia the free tumble shows and with filters that have settled on the
/// tumble before the motors start. Scored at the end of the excitation against the truth.
/// Measured: every axis found, rotational block 0.8 % median and 1.8 % worst (before the tumble
/// left the hand's last touch out and the filters were primed: 10.1 % and 45.6 %, the thrust
/// axis up to 9.4° off).
#[test]
fn random_airframes_thrown_at_900_to_1000_dps_by_a_tapering_hand_are_identified() {
    let mut rotation = Vec::new();
    let mut lines = Vec::new();
    for seed in 1..=16u64 {
        let (airframe, mut config) = sim::identification::random_case(seed);
        let mut rng = sim::rng::Rng::new(seed ^ 0x0005_7A1E_D0C5);
        let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let spin_dps = rng.range(900.0, 1000.0);
        config.throw.rate_body_rad_s = axis * spin_dps.to_radians();
        config.throw.taper_s = rng.range(0.015, 0.045);
        config.throw.push_s = rng.range(0.15, 0.25);
        let report = identify(&airframe, &config);
        let learned = report.at_end.expect("the throw was accepted and the excitation ran");
        let scores = Scores::of(&learned, &report.truth);
        lines.push(format!(
            "seed {seed}: {} motors, {spin_dps:.0} °/s, taper {:.0} ms: G1 force {:.1} %, \
             rotation {:.1} %, axis {}",
            airframe.rotor_count(),
            config.throw.taper_s * 1e3,
            100.0 * scores.g1_block_rel[0],
            100.0 * scores.g1_block_rel[1],
            if scores.axis_found {
                format!("{:.1}° off", scores.axis_angle_rad.to_degrees())
            } else {
                "not found".into()
            }
        ));
        assert!(scores.axis_found, "{}", lines.join("\n"));
        rotation.push(scores.g1_block_rel[1]);
    }
    eprintln!("{}", lines.join("\n"));
    rotation.sort_by(f64::total_cmp);
    let (median, worst) = (rotation[rotation.len() / 2], rotation[rotation.len() - 1]);
    eprintln!("rotational block: median {:.1} %, worst {:.1} %", 100.0 * median, 100.0 * worst);
    assert!(median < 0.03 && worst < 0.06, "median {median}, worst {worst}");
}
