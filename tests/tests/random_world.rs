//! The firmware in a randomised world (`sim::world`): hands, motion capture, IMU errors, ESCs,
//! motors, batteries and air drawn from their documented ranges. A small version of
//! `fly monte-carlo --world random` (whose 1,000-run figures are in docs/benchmarks.md), and
//! the finding it led to: ESC speed reports older than the nominal board's.
//!
//! `cargo test -p tests --release --test random_world -- --nocapture` prints the figures.

use firmware::app::{Failsafe, IdentificationFailure};
use sim::airframe::Airframe;
use sim::recovery::{fly, FlyConfig, Outcome, Verdict};
use sim::world::{self, Aspect};

#[test]
fn thirty_random_worlds_hover_or_refuse_to_fly_and_most_hold_within_0_3_m() {
    // Issue 28's target is 99 % hovered and 97 % held over 1,000 runs; it is not met yet
    // (docs/benchmarks.md: 98.5 % and 94.2 %): the gyro's scale and cross-axis errors at high
    // spin still get some identifications refused (`NoHover`: the learned rotational block is
    // off; seed 18 here). This guards what holds today: every run either hovers or is refused
    // by the identification before it flies a model (no crash into the ground, no other
    // failsafe, no run that never settles), seeds 1-30 hover in 29 cases and hold within 0.3 m
    // in 28 (before the tumble left out the hand's last touch and the learner's filters were
    // primed in the release delay: 28 and 26).
    let results = world::monte_carlo(30, 1, 2, &Aspect::ALL, &|_| {});
    let verdicts: Vec<_> = results.iter().map(|r| (r.seed, r.verdict)).collect();
    let hovered = results
        .iter()
        .filter(|r| matches!(r.verdict, Verdict::Held | Verdict::HoveredLoose))
        .count();
    let held = results.iter().filter(|r| r.verdict == Verdict::Held).count();
    eprintln!("hovered {hovered} of 30, held {held}: {verdicts:?}");
    let refused = Verdict::Failsafe(Failsafe::Identification(IdentificationFailure::NoHover));
    for (seed, verdict) in &verdicts {
        assert!(
            matches!(verdict, Verdict::Held | Verdict::HoveredLoose) || *verdict == refused,
            "seed {seed}: {verdict:?}"
        );
    }
    assert!(hovered >= 29, "{verdicts:?}");
    assert!(held >= 28, "{verdicts:?}");
}

#[test]
fn speed_reports_2_5_ms_old_are_aligned_by_motor_speed_age_s() {
    // The seed paper's quad with ESCs whose speed reports are 2.5 ms old when read (slow
    // eRPM measurement at low speed): `fly` tells the firmware, as a user sets
    // `motor_speed_age_s`, and the learner pairs each report with the command and the IMU
    // sample of its time.
    let mut airframe = Airframe::builtin("paper-quad").unwrap();
    airframe.motor.telemetry_delay_s = 0.0025;
    for rotor in &mut airframe.rotors {
        if let Some(motor) = rotor.motor.as_mut() {
            motor.telemetry_delay_s = 0.0025;
        }
    }
    let report = fly(&airframe, &FlyConfig::paper());
    let hold_m = report.max_hold_error_m.unwrap_or(f64::INFINITY);
    eprintln!("2.5 ms old speed reports: {:?}, held within {hold_m:.3} m", report.outcome);
    assert_eq!(report.outcome, Outcome::Flying);
    assert!(hold_m <= 0.3, "held within {hold_m} m");
}
