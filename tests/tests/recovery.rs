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
}
