//! The IMU offset fitted in flight with no calibration (issue 32;
//! `imu_offset::in_flight`): the firmware application is thrown with no offset given, and the
//! offset it fits on the release delay's tumble, the excitation and the first seconds of flight
//! is compared with the simulator's truth, in millimetres.
//!
//! `cargo test -p tests --release --test imu_offset_in_flight -- --nocapture` prints the figures.

use sim::airframe::Airframe;
use sim::recovery::{fly, FlyConfig, FlyReport, Outcome, Verdict};
use sim::world::{random_world_case, Aspect};

fn fitted_error_mm(label: &str, report: &FlyReport) -> f64 {
    let fit = report.r_imu_fit_m.unwrap_or_else(|| panic!("{label}: no offset fitted"));
    let error_mm = (fit - report.r_imu_true_m).norm() * 1e3;
    eprintln!(
        "{label}: fitted {:.1?} mm, true {:.1?} mm, error {error_mm:.2} mm; {:?}, hold error {:.3} m",
        (fit * 1e3).as_slice(),
        (report.r_imu_true_m * 1e3).as_slice(),
        report.outcome,
        report.max_hold_error_m.unwrap_or(f64::NAN)
    );
    error_mm
}

/// Random worlds 1..=`worlds` (every aspect drawn) flown with no offset given, with or without
/// speed telemetry: the fitted offsets' errors, mm, by seed and sorted.
fn random_world_fit_errors_mm(worlds: u64, speed_telemetry: bool) -> (Vec<f64>, Vec<f64>) {
    let errors: Vec<f64> = (1..=worlds)
        .map(|seed| {
            let (airframe, mut config) = random_world_case(seed, &Aspect::ALL);
            config.known_imu_offset = false;
            config.speed_telemetry = speed_telemetry;
            let label = format!("seed {seed}, speed telemetry {speed_telemetry}");
            fitted_error_mm(&label, &fly(&airframe, &config))
        })
        .collect();
    let mut sorted = errors.clone();
    sorted.sort_by(f64::total_cmp);
    (errors, sorted)
}

#[test]
fn the_seed_papers_quad_finds_its_imu_offset_in_one_throw_to_fly() {
    // The paper's quad, its IMU at about (−10, −13, 8) mm and rotated, thrown once as the paper
    // throws it, no offset given, poses at 100 Hz.
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let config = FlyConfig { known_imu_offset: false, ..FlyConfig::paper() };
    assert_eq!(config.motion_capture.rate_hz, 100.0);
    let report = fly(&airframe, &config);
    // Recovers and holds within the 0.3 m.
    assert_eq!(report.outcome, Outcome::Flying);
    let hold_m = report.max_hold_error_m.unwrap();
    assert!(hold_m < 0.3, "hold error {hold_m} m");
    // Within the 1 mm: measured 0.28 mm with the drag as full matrices on the
    // navigation's velocity in IMU axes (0.35 mm per IMU axis; 1.27 mm with the drag a polynomial
    // in time, 1.2 mm of it along the IMU's z: docs/algorithms/imu-offset.md).
    let error_mm = fitted_error_mm("paper-quad", &report);
    assert!(error_mm < 1.0, "{error_mm} mm");
    // The truth lies inside the reported 95 % ellipsoid.
    let error = report.r_imu_fit_m.unwrap() - report.r_imu_true_m;
    let inverse = report.r_imu_fit_covariance_m2.unwrap().try_inverse().unwrap();
    let mahalanobis = error.dot(&(inverse * error));
    assert!(mahalanobis <= f64::from(imu_offset::CHI2_3DOF_95), "{mahalanobis}");
    // Its force rows, fitted with it, are within 10 % (flown with no offset, 50 % typically).
    let [force, _] = report.g1_block_rel_fitted_jointly.unwrap();
    assert!(force < 0.10, "force rows {:.1} %", force * 1e2);
}

#[test]
fn random_worlds_find_the_imu_offset_within_millimetres() {
    // Random airframes (IMU up to 30 mm out, any orientation) in the randomised world: hand,
    // poses, IMU errors, actuators, drag and gusts all drawn.
    let (errors, sorted) = random_world_fit_errors_mm(30, true);
    // The targets, 1 mm median and 2 mm at the 90th percentile, on these 30 worlds.
    // Measured with the quadratic drag as `|v| Q v` and the fully symmetric quartic tensor
    // (2026-11-28): median 0.92 mm, 90th (27th of 30) 1.78 mm, worst 4.87 mm (seed 7, whose
    // error every part of the world feeds: docs/algorithms/imu-offset.md). On 1,000 worlds
    // 0.98 / 2.09 / 4.87 mm (docs/benchmarks.md); with `|v| Q v` alone (to 2026-11-27) seeds 1–8
    // gave median 1.14 mm and worst 3.42 mm, 1,000 worlds 1.02 / 2.30 / 5.59 mm.
    // The median of 30 worlds moves with the worlds drawn: seeds 1–30, 31–60, 61–90 and 91–120
    // gave 0.96, 0.84, 1.07 and 0.88 mm (2026-12-05, 9c4fff4), about 0.1 mm around the 1,000
    // worlds' 0.95 mm, and any change to the flight after the engagement moves it as much
    // (1.06 mm with the rate gain kept below INDI's own mode, 0.96 mm on 1,000 worlds). The
    // issue's 1 mm is the 1,000 worlds' (docs/benchmarks.md); here it is bounded with two of
    // that spread.
    let median = 0.5 * (sorted[14] + sorted[15]);
    assert!(median < 1.2, "median {median} mm: {errors:?}");
    assert!(sorted[26] < 2.0, "90th percentile {} mm: {errors:?}", sorted[26]);
    assert!(sorted[29] < 6.0, "worst {} mm: {errors:?}", sorted[29]);
}

#[test]
fn a_learner_that_finds_no_hover_on_its_own_rows_flies_on_the_fitted_ones() {
    // Random worlds whose learner, given no offset, found no hover within the motor bounds in
    // the whole excitation, so that the craft was refused (`NoHover`) and fell from its apex,
    // while with the offset given each holds (measured 2026-11-28): seed 5036, a gentle throw
    // (20 °/s) whose fit has not determined `r` at the excitation's end (largest 95 %
    // semi-axis 124 mm), and seed 5930, whose fit had (3.5 mm). A publication whose own rows
    // find no hover is now followed by a solve on the fit's (`Learner::set_fallback_force_rows`).
    // Seed 5625's own rows find a hover in one publication of the excitation only: alternating
    // publications between the two sets of rows lost it; the fallback takes none of theirs.
    for seed in [5036, 5930, 5625] {
        let (airframe, mut config) = random_world_case(seed, &Aspect::ALL);
        config.known_imu_offset = false;
        let report = fly(&airframe, &config);
        let verdict = Verdict::of(&report);
        assert!(
            matches!(verdict, Verdict::Held | Verdict::HoveredLoose),
            "seed {seed}: {verdict:?}"
        );
        fitted_error_mm(&format!("seed {seed}"), &report);
    }
}

#[test]
fn without_speed_telemetry_the_offset_is_fitted_on_the_modelled_speeds() {
    // ESCs that report no speed (issue 32): the learner models each motor's speed from its
    // commands with the lag it identifies from the body's response, holding the excitation's
    // samples until that lag is known; the fit takes the same samples, with those speeds and
    // the velocity carried beside each, when the learner releases them. Before, it was not run
    // without speeds, and the craft flew its own rows learned with no offset (about 50 % off).
    // Over 1,000 random worlds: median 4.3 mm, 90th 16.3 mm (`fly monte-carlo --world random
    // --unknown-imu-offset --no-speed-telemetry`, 2026-12-03); with the excitation's samples
    // left out (the release delay and the flight only) 9.6 and 25.2 mm. About a third of the
    // worlds lie above 8 mm, so the median of 10 moved with a few of them (5.4 → 8.2 mm when the
    // recovery's thrust rules changed, while the 1,000 worlds' went 4.33 → 4.29 mm): 30 worlds.
    let (errors, sorted) = random_world_fit_errors_mm(30, false);
    let median = 0.5 * (sorted[14] + sorted[15]);
    assert!(median < 8.0, "median {median} mm: {errors:?}");
}

/// `cargo xtask bench-m7` checks the background task's wait for the fit in `idle` with the
/// hand-back and the sum interval restated in `xtask` (which builds none of the firmware's
/// crates): they must be the firmware's, or the check would judge another design.
#[test]
fn bench_m7s_check_of_the_fit_in_idle_uses_the_firmwares_hand_back_and_sum_interval() {
    let bench = include_str!("../../xtask/src/bench.rs");
    let restated = |name: &str| -> f32 {
        let prefix = format!("const {name}: f64 = ");
        let line = bench.lines().find_map(|l| l.strip_prefix(&prefix)).unwrap_or_else(|| {
            panic!("xtask/src/bench.rs no longer states {name}");
        });
        line.trim_end_matches(';').parse().unwrap()
    };
    assert_eq!(restated("FIT_HANDBACK_S"), firmware::app::offset_fit::OFFSET_FIT_HANDBACK_S);
    assert_eq!(restated("FIT_SUM_INTERVAL_S"), imu_offset::in_flight::SUM_INTERVAL_S);
}
