//! Throw-and-fly end to end against the simulator's truth: the firmware application, exactly as
//! the board runs it, is thrown, identifies its actuators, and must recover to a hover and hold
//! its position from motion capture. Physical checks: metres from the setpoint, seconds to hover.
//!
//! `cargo test -p tests --release --test recovery -- --nocapture` prints the measured figures.

use sim::airframe::Airframe;
use sim::recovery::{fly, FlyConfig, FlyReport, Outcome};

fn run(name: &str, config: &FlyConfig) -> FlyReport {
    let airframe = Airframe::builtin(name).unwrap();
    let mut config = config.clone();
    config.trace = std::env::var_os("RECOVERY_TRACE").is_some();
    config.board.ideal_imu = std::env::var_os("RECOVERY_IDEAL").is_some();
    let report = fly(&airframe, &config);
    eprintln!(
        "{name}: {:?}; release → engage {:.0} ms, → hover {:.2} s; worst drop below release {:.2} m; \
         hold error {:.3} m over {:.0} s",
        report.outcome,
        report.release_to_engage_s.unwrap_or(f64::NAN) * 1e3,
        report.release_to_hover_s.unwrap_or(f64::NAN),
        report.max_drop_below_release_m,
        report.max_hold_error_m.unwrap_or(f64::NAN),
        report.hold_window_s,
    );
    let percent = |blocks: Option<[f64; 2]>| {
        blocks.map_or("—".to_string(), |[f, r]| format!("{:.2} / {:.2} %", f * 1e2, r * 1e2))
    };
    eprintln!(
        "{name}: G1 error (force / rotation blocks) at engage {}, learner at the end {}, flown at \
         the end {}; {} models taken in flight",
        percent(report.g1_block_rel_at_engage),
        percent(report.g1_block_rel_learned_at_end),
        percent(report.g1_block_rel_flown_at_end),
        report.refinements
    );
    report
}

#[test]
fn seed_paper_quad_recovers_and_holds_its_position_within_0_3_m_for_10_s() {
    let report = run("paper-quad", &FlyConfig::paper());
    assert_eq!(report.outcome, Outcome::Flying, "{report:?}");
    assert!(report.release_to_hover_s.is_some(), "never hovered: {report:?}");
    assert!(report.hold_window_s >= 10.0);
    let error = report.max_hold_error_m.expect("held a position");
    assert!(error < 0.3, "worst distance from the setpoint over 10 s: {error} m");
    refinement_kept_the_model("paper-quad", &report);
}

/// Every other built-in airframe, thrown like the paper's quad: it must identify, recover without
/// dropping below the release point, hover within 5 s of the release, and hold its position within
/// 0.3 m for 10 s. The slow airframes (τ = 50 ms, gains 2.5 times lower than the paper quad's)
/// engage at the apex after a 0.9–1.1 s excitation and need longer to come to rest.
#[test]
fn every_builtin_airframe_recovers_hovers_and_holds() {
    for name in ["hex-flat", "hex-tilted", "octo-flat", "quad-3in", "racer-5in"] {
        let report = run(name, &FlyConfig::paper());
        assert_eq!(report.outcome, Outcome::Flying, "{name}: {report:?}");
        let hover_s = report.release_to_hover_s.expect("hovered");
        assert!(hover_s < 5.0, "{name}: release to hover {hover_s} s");
        assert!(
            report.max_drop_below_release_m < 0.5,
            "{name}: fell {} m below the release point",
            report.max_drop_below_release_m
        );
        let error = report.max_hold_error_m.expect("held a position");
        assert!(error < 0.3, "{name}: worst distance from the setpoint {error} m");
        refinement_kept_the_model(name, &report);
    }
}

/// The in-flight refinement took models from the learner and left G1 no worse than at the
/// engagement, within the refinement's own scatter: each block within 0.5 percentage points
/// (issue 28's primed learner engages closer to the truth, e.g. hex-flat's rotation block at
/// 2.12 % instead of 3.82 %, and the 2 s of closed-loop refinement then moves it by −0.31 to
/// +0.46 points over noise seeds 1–5: 2.58 % at the end on seed 1, against 3.04 % before; the
/// earlier 0.2-point margin was measured when every engagement was worse than the refinement's
/// floor). The model flown at the end is the learner's within 0.1 points.
fn refinement_kept_the_model(name: &str, report: &FlyReport) {
    assert!(report.refinements > 100, "{name}: {} models taken in flight", report.refinements);
    let engage = report.g1_block_rel_at_engage.expect("scored at engagement");
    let learned = report.g1_block_rel_learned_at_end.expect("scored at the end");
    let flown = report.g1_block_rel_flown_at_end.expect("flown at the end");
    for block in 0..2 {
        assert!(
            learned[block] < engage[block] + 0.005,
            "{name}: block {block} from {} to {}",
            engage[block],
            learned[block]
        );
        assert!((flown[block] - learned[block]).abs() < 0.001, "{name}: {flown:?} vs {learned:?}");
    }
}

/// A long hover learns no more: 60 s after the throw racer-5in's G1 is still no worse than at
/// the engagement (without the refinement's 2 s window its roll and pitch rows drifted from
/// 1.2 % to 20 % off on closed-loop hover data).
#[test]
fn a_minute_of_hover_does_not_spoil_the_refined_model() {
    let config = FlyConfig { flight_s: 60.0, ..FlyConfig::paper() };
    let report = run("racer-5in", &config);
    assert_eq!(report.outcome, Outcome::Flying, "{report:?}");
    refinement_kept_the_model("racer-5in", &report);
}

/// A ground station moves the hold: the seed paper's quad recovers and holds where it stopped;
/// then a `SetPositionSetpoint` 1 m north, 1 m east and 0.5 m up (heading 30°) arrives through
/// the same command the protocol carries, and the craft's true centre of gravity settles within
/// 0.15 m of it and its heading within 5° (flown here step by step, as `fly` does).
#[test]
fn a_position_setpoint_from_the_ground_station_moves_the_hover() {
    use firmware::app::ControlCommand;
    use protocol::PositionSetpoint;
    use sim::board::SimBoard;
    use sim::recovery::{heading, MotionCapture};
    use sim::scenario::{with_firmware_app, FlightApp};

    let airframe = Airframe::builtin("paper-quad").unwrap();
    let config = FlyConfig::paper();
    let truth = sim::identification::TrueModel::of(&airframe);
    let q_body_thrust = airframe.q_imu_body().inverse() * truth.q_thrust_to_imu;
    let mut board = SimBoard::new(&airframe, &config.board);
    with_firmware_app(|app| {
        let r = truth.r_imu_m;
        app.background.set_imu_offset(Some([r.x as f32, r.y as f32, r.z as f32]));
        app.submit(ControlCommand::ArmThrowToFly);
        let mut mocap = MotionCapture::new(config.board.seed);
        let mut target: Option<PositionSetpoint> = None;
        let mut errors = Vec::new();
        for tick in 0..(1000 + 2000 * 14) {
            if tick == 1000 {
                board.physics_mut().throw(&config.throw.spec());
            }
            board.tick();
            let now_us = board.now_us();
            if let Some(pose) = mocap.sample(board.physics().state(), now_us) {
                app.command(ControlCommand::ExternalPose(pose), now_us);
            }
            let (imu, motors) = board.ports();
            app.step(now_us, imu, motors);
            let pilot = app.snapshot().pilot;
            let state = *board.physics().state();
            assert!(state.position_ned_m.z < 0.0, "hit the ground at {:.2} s", board.time_s());
            // Once holding where it stopped, the ground station asks for somewhere else.
            if target.is_none() && pilot.position_hold && board.time_s() > 5.0 {
                let here = state.position_ned_m;
                let setpoint = PositionSetpoint {
                    position_ned_m: [here.x as f32 + 1.0, here.y as f32 + 1.0, here.z as f32 - 0.5],
                    heading_rad: 30f32.to_radians(),
                };
                app.command(ControlCommand::PositionSetpoint(setpoint), now_us);
                target = Some(setpoint);
            }
            // The last 2 s of the flight, 6 s or more after the new setpoint.
            if let (Some(setpoint), true) = (target, board.time_s() > 13.0) {
                let goal = nalgebra::Vector3::from(setpoint.position_ned_m).cast::<f64>();
                let thrust_heading = heading(&(state.attitude() * q_body_thrust));
                let heading_error =
                    (thrust_heading - f64::from(setpoint.heading_rad)).sin().asin().abs();
                errors.push(((state.position_ned_m - goal).norm(), heading_error));
            }
        }
        let target = target.expect("the craft held a position by 5 s");
        let worst_m = errors.iter().map(|e| e.0).fold(0.0, f64::max);
        let worst_heading_deg = errors.iter().map(|e| e.1).fold(0.0, f64::max).to_degrees();
        eprintln!(
            "setpoint {:?}: worst distance {worst_m:.3} m, worst heading error {worst_heading_deg:.1}° over the last 2 s",
            target.position_ned_m
        );
        assert!(worst_m < 0.15, "worst distance from the new setpoint {worst_m:.3} m");
        assert!(worst_heading_deg < 5.0, "worst heading error {worst_heading_deg:.1}°");
    });
}
