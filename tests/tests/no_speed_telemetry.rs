//! Identification without ESC speed telemetry (issue 32, `flight::learner::no_speed`): the
//! firmware application flown on ESCs that report no speed, told so (`motor_bidir_dshot` = 0),
//! which in a build that identifies from the commands arms without them
//! (`Params::arms_without_speeds`; what `fly --no-speed-telemetry` sets). The lag is
//! identified from the body's response (rates and specific force) and every speed modelled from
//! the commands.
//!
//! Over 1,000 random worlds it hovers 96.5 % of the airframes (docs/benchmarks.md, 100 % with
//! telemetry); the built-in quads below and random worlds 1–30 are among those it flies.
//!
//! `cargo test -p tests --release --test no_speed_telemetry -- --nocapture` prints the figures.

use firmware::app::ENGAGE_WAIT_MAX_S;
use sim::airframe::Airframe;
use sim::recovery::{fly, FlyConfig, Verdict};
use sim::world::{self, Aspect};

/// The seed paper's experiment with and without speed telemetry on `name`: (verdict, worst
/// per-motor |τ error| s, worse G1 block per unit thrust at the end of the excitation, the
/// excitation's end → engagement s) of each.
fn with_and_without(name: &str) -> [(Verdict, f64, f64, f64); 2] {
    let airframe = Airframe::builtin(name).unwrap();
    [true, false].map(|speed_telemetry| {
        let config = FlyConfig { speed_telemetry, ..FlyConfig::paper() };
        let report = fly(&airframe, &config);
        let scores = report.thrust_scores_at_excitation_end.expect("the excitation ended");
        let g1 = scores.g1_block_rel[0].max(scores.g1_block_rel[1]);
        eprintln!(
            "{name}, speed telemetry {speed_telemetry}: {:?}, τ error {:.2} ms, G1 {:.1} %, hold {:.3} m",
            Verdict::of(&report),
            1e3 * scores.tau_error_max_s,
            100.0 * g1,
            report.max_hold_error_m.unwrap_or(f64::NAN)
        );
        let wait_s = report.excitation_end_to_engage_s.expect("engaged");
        (Verdict::of(&report), scores.tau_error_max_s, g1, wait_s)
    })
}

#[test]
fn without_speed_telemetry_the_lag_is_found_from_the_rotation_and_the_craft_holds() {
    for name in ["paper-quad", "racer-5in"] {
        let [(with_verdict, with_tau, with_g1, with_wait_s), (verdict, tau_error_s, g1, wait_s)] =
            with_and_without(name);
        // Without telemetry the controller waits at the end of the excitation while the
        // effectiveness regression learns from it, a few samples a step; with, it engages in
        // the step the excitation ends.
        assert!(with_wait_s < 1e-6, "{name}: waited {with_wait_s} s with telemetry");
        assert!(
            wait_s > 5e-3 && wait_s < f64::from(ENGAGE_WAIT_MAX_S),
            "{name}: waited {wait_s} s for the model"
        );
        assert_eq!(with_verdict, Verdict::Held, "{name} with telemetry");
        // The lag from the body's response alone, within 8 ms of the truth (paper-quad 5.6 ms,
        // racer-5in 0.5 ms today; the angular-only regression this grid replaced had 0.6–1.0
        // ms on these two, and a 7.4 ms median error over 200 random worlds against 5.8 now).
        assert!(tau_error_s < 8e-3, "{name}: τ {:.2} ms off", 1e3 * tau_error_s);
        assert_eq!(verdict, Verdict::Held, "{name} without telemetry: held within 0.3 m");
        // Bidirectional DShot stays the better path: its G1 is closer to the truth (its lag is
        // within 0.1 ms; without, the racer's came out as close: 0.04 ms).
        assert!(with_tau < 1e-4, "{name}: τ {:.2} ms off with telemetry", 1e3 * with_tau);
        assert!(with_g1 < g1, "{name}: G1 {with_g1} with telemetry against {g1}");
    }
}

#[test]
fn without_speed_telemetry_random_airframes_hover() {
    // Random worlds 1–30 (4–8 motors, every aspect randomised: throws, hands, poses, IMUs, ESC
    // curves, lags, air) without telemetry. Over 1,000 such worlds 96.5 % hover and 94.7 % hold
    // within 0.3 m (`fly monte-carlo --world random --no-speed-telemetry`, docs/benchmarks.md);
    // at those rates 30 worlds give 5 or more that never hover with probability 0.4 %, and 6 or
    // more that do not hold with 0.4 %, while a rate of 80 % fails the first bound three times
    // in four. A fixed handful of worlds, each of which must hover, tests the seeds' luck: the
    // lag regression at 250 Hz (2026-11-28) hovered as often as the 2 kHz one over 1,000 worlds
    // but lost seed 7 (τ 41 ms off) and seed 8; at 125 Hz seed 7 holds (τ 19 ms off), and
    // since the controller waits for G1 to learn from the whole excitation seed 8 does too.
    // Seed 14 was refused (`NoHover`) until the learner's clamped last-resort axis; all 30
    // hover now.
    const WORLDS: u64 = 30;
    let (mut hovered, mut held) = (0, 0);
    for seed in 1..=WORLDS {
        let (airframe, mut config) = world::random_world_case(seed, &Aspect::ALL);
        config.speed_telemetry = false;
        let report = fly(&airframe, &config);
        let verdict = Verdict::of(&report);
        let tau_ms = report.thrust_scores_at_excitation_end.map(|s| 1e3 * s.tau_error_max_s);
        eprintln!("seed {seed}: {verdict:?}, worst τ error {tau_ms:.1?} ms");
        hovered += usize::from(matches!(verdict, Verdict::Held | Verdict::HoveredLoose));
        held += usize::from(verdict == Verdict::Held);
    }
    assert!(hovered >= 26, "hovered {hovered} of {WORLDS}");
    assert!(held >= 25, "held {held} of {WORLDS}");
}

/// Random worlds without speed telemetry whose hover of the learned model leaves the motor
/// bounds (G1 and the lag far off at the excitation's end) and none within them was ever found:
/// they were refused (`NoHover`) and fell from their apex. The learner now publishes the axis of
/// u* clamped to the bounds as its last resort, and INDI, which finds the torque balance from its
/// own measurements, holds each of them within 0.3 m. Seeds 33, 70 and 89 since the held samples
/// became 4 ms means (issue 56: `fly monte-carlo --world random --no-speed-telemetry` lists u*
/// outside by 0.10, 0.23, 0.18; 14 and 84, the seeds before, now engage within the bounds).
#[test]
fn without_speed_telemetry_a_hover_outside_the_bounds_is_flown_on_its_clamped_axis() {
    for seed in [33, 70, 89] {
        let (airframe, mut config) = world::random_world_case(seed, &Aspect::ALL);
        config.speed_telemetry = false;
        let report = fly(&airframe, &config);
        let clamped_by = report.engaged_clamped_by.expect("engaged on the clamped axis");
        eprintln!("seed {seed}: u* outside by {clamped_by:.3}, {:?}", Verdict::of(&report));
        assert!(clamped_by > 0.0, "seed {seed}");
        assert_eq!(Verdict::of(&report), Verdict::Held, "seed {seed}");
    }
}

/// Without speed telemetry the control step waits at the excitation's end for the model, the
/// motors holding their last commands (the excitation ends at zero: the ESCs idle) and the
/// attempt armed: a disarm then ends it as `Disarmed` in the same step, every motor at zero and
/// the ESCs disarmed, as during the excitation (`identification.rs`), and nothing engages
/// afterwards.
#[test]
fn a_disarm_while_waiting_for_the_model_stops_every_motor_in_the_same_step() {
    use firmware::app::{ControlCommand, ControlSettings, Param, Params};
    use flight::learner::FlightPhase;
    use nalgebra::Vector3;
    use sim::board::{SimBoard, SimConfig};
    use sim::scenario::with_firmware_app;

    let airframe = Airframe::builtin("paper-quad").unwrap();
    let config =
        SimConfig { start_position_ned_m: Vector3::new(0.0, 0.0, -1.5), ..SimConfig::default() };
    let mut board = SimBoard::new(&airframe, &config);
    board.motors_mut().set_bidirectional(false);
    with_firmware_app(|app| {
        let mut params = Params::default();
        params.set(Param::MotorBidirDshot as usize, &[0.0]).unwrap();
        app.background.configure(&params);
        app.submit(ControlCommand::Configure(ControlSettings::from(&params)));
        let disarmed = tests::disarm_during_throw_to_fly(&mut board, app, 6000, |snapshot| {
            snapshot.phase == FlightPhase::Done && !snapshot.pilot.flying && snapshot.armed
        });
        assert!(disarmed, "the step waited for the model, armed");
    });
}
