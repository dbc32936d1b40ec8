//! The firmware in a randomised world (`sim::world`): hands, motion capture, IMU errors, ESCs,
//! motors, batteries and air drawn from their documented ranges. A small version of
//! `fly monte-carlo --world random` (whose 1,000-run figures are in docs/benchmarks.md), and
//! the findings it led to: ESC speed reports older than the nominal board's, a hover lost at
//! the end of the excitation to the gyro's sensitivity errors (flown, not refused), and a hold
//! pinned while the recovery was still braking (overshot), light frames whose drag after the
//! release hid the free fall, and a craft whose heading never aligned (nudged now) drifting on dead reckoning.
//!
//! `cargo test -p tests --release --test random_world -- --nocapture` prints the figures.

use firmware::app::{Failsafe, IdentificationFailure};
use sim::airframe::Airframe;
use sim::recovery::{fly, FlyConfig, FlyReport, Outcome, Verdict};
use sim::world::{self, Aspect};

#[test]
fn thirty_random_worlds_all_hover_and_most_hold_within_0_3_m() {
    // Issue 28's target is 99 % hovered and 97 % held over 1,000 runs (docs/benchmarks.md: 99.5 %
    // and 98.8 %). Seeds 1-30 all hover (no crash into the ground, no failsafe, no run that
    // never settles, no refused identification) and hold within 0.3 m. Before the pilot flew
    // the hover found during the excitation when the final model's hover left the motor bounds,
    // seed 18 (490 °/s, the gyro's scale and cross-axis errors) was refused (`NoHover`): 29
    // hovered, 28 held. (All 30 hold today; one is left as margin.)
    let results = world::monte_carlo(30, 1, 2, &Aspect::ALL, &|_| {});
    let verdicts: Vec<_> = results.iter().map(|r| (r.seed, r.verdict)).collect();
    let held = results.iter().filter(|r| r.verdict == Verdict::Held).count();
    eprintln!("held {held} of 30: {verdicts:?}");
    for (seed, verdict) in &verdicts {
        assert!(
            matches!(verdict, Verdict::Held | Verdict::HoveredLoose),
            "seed {seed}: {verdict:?}"
        );
    }
    assert!(held >= 29, "{verdicts:?}");
}

/// Random-world case `seed` flown once, its verdict printed.
fn fly_random_world(seed: u64) -> (FlyReport, Verdict) {
    fly_world(seed, &Aspect::ALL)
}

/// Case `seed` of the world with `aspects` drawn, flown once, its verdict printed.
fn fly_world(seed: u64, aspects: &[Aspect]) -> (FlyReport, Verdict) {
    let (airframe, config) = world::random_world_case(seed, aspects);
    let report = fly(&airframe, &config);
    let verdict = Verdict::of(&report);
    eprintln!(
        "seed {seed}: {verdict:?}, hold {:?} m over {:.0} % of the window",
        report.max_hold_error_m,
        100.0 * report.hold_coverage
    );
    (report, verdict)
}

#[test]
fn light_frames_thrown_hard_are_accepted_despite_their_drag() {
    // Random-world seeds 278 and 346: quads with terminal speeds near 10 m/s thrown at 9.4 and
    // 9.2 m/s, whose accelerometers read 0.9–1.0 g of drag after the release. Before the throw
    // detector allowed for drag against the velocity, neither throw was accepted (nothing spun,
    // `NoIdentification`); now both are within 0.7 s of the release and hold.
    for seed in [278, 346] {
        let (report, verdict) = fly_random_world(seed);
        let engaged_s = report.release_to_engage_s.unwrap_or(f64::INFINITY);
        assert!(engaged_s < 0.7, "seed {seed}: engaged {engaged_s} s after the release");
        assert_eq!(verdict, Verdict::Held, "seed {seed}");
    }
}

#[test]
fn a_hold_pinned_once_the_recovery_has_stopped_braking_is_not_overshot() {
    // Random-world seeds 70 (918 °/s) and 447 (20 °/s): the recovery carries the craft metres
    // sideways and brakes at 3-6 m/s²; when its speed fell below 0.3 m/s it was still
    // decelerating at 1-1.5 m/s², the attitude loop turning it back to level, and the hold
    // pinned there was overshot (0.83 and 0.53 m; the position loop took seconds to win it
    // back). The hold now also waits for the acceleration from the fixes to fall below 0.5 m/s²:
    // both hold within 0.3 m, in position hold for more than half of the window.
    for seed in [70, 447] {
        let (report, verdict) = fly_random_world(seed);
        assert_eq!(verdict, Verdict::Held, "seed {seed}");
        assert!(report.hold_coverage > 0.5, "seed {seed}: {}", report.hold_coverage);
    }
}

#[test]
fn a_hover_lost_at_the_end_of_the_excitation_to_the_gyros_sensitivity_is_flown() {
    // Random-world seeds 18 (490 °/s) and 187 (886 °/s): the gyro's scale and cross-axis errors
    // (±3 %, ±2 %) leave the learned rotational block 13-17 % off at the end of the excitation,
    // and the hover it implies needs a command outside [0, 1] (`AxisStatus::NoHover`), although
    // a hover within the bounds was found earlier in the same excitation. INDI needs the thrust
    // axis, not the exact hover commands, and a refusal drops the craft from its apex: the pilot
    // flies the last hover found. Both were refused before; both hover now and hold.
    for seed in [18, 187] {
        let (report, verdict) = fly_random_world(seed);
        assert_eq!(report.outcome, Outcome::Flying, "seed {seed}");
        assert!(report.release_to_hover_s.is_some(), "seed {seed}: never hovered");
        assert_eq!(verdict, Verdict::Held, "seed {seed}");
    }
}

#[test]
fn a_craft_that_cannot_hover_is_still_refused_before_it_flies() {
    // The seed paper's quad with a quarter of its thrust (thrust-to-weight 3.3 / 4 = 0.82): no hover
    // within the motor bounds is ever found, so there is no thrust axis to fly and the
    // identification is refused (`NoHover`) as before.
    let mut airframe = Airframe::builtin("paper-quad").unwrap();
    airframe.motor.thrust_coefficient_n_per_rad2_s2 /= 4.0;
    for rotor in &mut airframe.rotors {
        if let Some(motor) = rotor.motor.as_mut() {
            motor.thrust_coefficient_n_per_rad2_s2 /= 4.0;
        }
    }
    let report = fly(&airframe, &FlyConfig::paper());
    eprintln!("a quarter of the thrust: {:?}", report.outcome);
    assert_eq!(
        report.outcome,
        Outcome::Failsafe(Failsafe::Identification(IdentificationFailure::NoHover))
    );
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

#[test]
fn a_craft_that_recovers_without_moving_is_nudged_until_its_heading_aligns_and_then_holds() {
    // Random-world seed 421: thrown nearly straight up (0.3 m/s sideways), it recovered without
    // the horizontal motion the heading alignment learns from, and the level hold flew on dead
    // reckoning in the filter's world, where the filter's tilt error pushed it away unseen while
    // fresh poses arrived: 14 m/s and 186 m away after 25 s, never aligned. (Before the level
    // hold took the fixes' vertical speed it also sank at up to 1.2 m/s into the ground.) Nudged back and
    // forth a few tenths of a metre once steady (`firmware::app::pilot`, `nudge_velocity`), it
    // aligns and holds.
    let (report, verdict) = fly_random_world(421);
    assert_eq!(verdict, Verdict::Held);
    assert!(report.max_drop_below_release_m < 0.3, "dropped {} m", report.max_drop_below_release_m);
    let fastest = report.max_speed_after_recovery_mps.expect("it recovered");
    let away = report.end_from_recovery_m.expect("it recovered");
    assert!(fastest < 1.5, "fastest after the recovery {fastest:.2} m/s");
    assert!(away < 2.0, "ended {away:.2} m from where it recovered");
}

/// Slow motors in a turbulent wind hold within 0.3 m: in a position hold the attitude loop
/// turns at the hold's own damping (`flight::position::Gains::for_hold`). Random worlds 84, 187
/// and 627 in a 6.4–7.7 m/s wind with turbulence of σ 1.1–1.3 m/s, slowest motors 56, 52 and
/// 66 ms, strayed 0.37, 0.48 and 0.45 m from their setpoints on the published attitude gain
/// (measured: 0.13, 0.18 and 0.20 m on the hold's).
#[test]
fn slow_motors_in_a_turbulent_8_mps_wind_hold_within_0_3_m() {
    let mut windy = Aspect::ALL.to_vec();
    windy.push(Aspect::Wind);
    for seed in [84, 187, 627] {
        let (report, verdict) = fly_world(seed, &windy);
        assert_eq!(verdict, Verdict::Held, "seed {seed}: {:?} m", report.max_hold_error_m);
        assert!(report.hold_coverage > 0.5, "seed {seed}: in hold {:.2}", report.hold_coverage);
    }
}

/// A tumble's gyro sensitivity errors leave the attitude filter 10–30° off in tilt; on motion
/// capture the filter corrects it against the specific force the poses' acceleration implies
/// (`flight::attitude::AttitudeFilter::update_accelerating`), faster while it is large
/// (`AttitudeConfig::large_error_gain`), before the craft gains speed on it. Random worlds 355
/// and 389 (calm) and 639 (in wind) flew away on the uncorrected tilt, and the firmware landed
/// them as fly-aways; they hold.
#[test]
fn a_tumble_that_left_the_tilt_far_off_is_corrected_before_the_craft_flies_away() {
    let mut windy = Aspect::ALL.to_vec();
    windy.push(Aspect::Wind);
    for (seed, aspects) in [(355, &Aspect::ALL[..]), (389, &Aspect::ALL[..]), (639, &windy[..])] {
        let (report, verdict) = fly_world(seed, aspects);
        assert_eq!(verdict, Verdict::Held, "seed {seed}: {:?} m", report.max_hold_error_m);
    }
}
