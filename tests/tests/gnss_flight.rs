//! Outdoors without motion capture: the seed paper's quad thrown and flown (the firmware
//! application as the board runs it) on a simulated u-blox receiver, whose NAV-PVT bytes go
//! through the firmware's own driver and become position fixes with their accuracies and a
//! Doppler velocity, without heading. Scored against the simulator's truth.
//!
//! The bound: the "hold within 1 m" with a 0.3 m receiver, horizontally (a receiver's
//! vertical error is 1.5–2.5 times its horizontal), over the last 5 s of a 10 s flight. The
//! receiver's own error wanders over that time (0.3 m per axis correlated over 20 s moves by
//! about 0.2 m in 5 s): the craft follows it, as it must, and nothing more.
//!
//! The random world's receivers (`sim::world`, aspect `gnss`): each craft held within its own
//! receiver's bound, 0.3 m + 2 hAcc (`sim::gnss::GnssModelConfig::held`).
//!
//! `cargo test -p tests --release --test gnss_flight -- --nocapture` prints the figures.

use sim::airframe::Airframe;
use sim::gnss::GnssModelConfig;
use sim::recovery::{fly, FlyConfig, FlyReport, Outcome, Verdict};
use sim::world::{self, Aspect};

/// The horizontal hold bound, m (the issue's, for a 0.3 m receiver).
const HOLD_BOUND_M: f64 = 1.0;

fn run(label: &str, gnss: GnssModelConfig, seed: u64) -> FlyReport {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let mut config =
        FlyConfig { gnss: Some(gnss), flight_s: 10.0, hold_window_s: 5.0, ..FlyConfig::paper() };
    config.board.seed = seed;
    let report = fly(&airframe, &config);
    eprintln!(
        "{label}: {:?}; release → hover {:.2} s; hold error {:.3} m horizontally ({:.3} m 3-D) \
         over the last {:.0} s, in hold {:.0} % of it; {} fixes refused",
        report.outcome,
        report.release_to_hover_s.unwrap_or(f64::NAN),
        report.max_hold_error_horizontal_m.unwrap_or(f64::NAN),
        report.max_hold_error_m.unwrap_or(f64::NAN),
        report.hold_window_s,
        100.0 * report.hold_coverage,
        report.fixes_rejected,
    );
    report
}

fn assert_held(label: &str, report: &FlyReport) {
    assert_eq!(report.outcome, Outcome::Flying, "{label}: {report:?}");
    assert!(report.release_to_hover_s.is_some(), "{label}: never hovered");
    assert_eq!(report.hold_coverage, 1.0, "{label}: not in position hold throughout the window");
    let error = report.max_hold_error_horizontal_m.expect("held a position");
    assert!(error < HOLD_BOUND_M, "{label}: {error:.3} m from the setpoint horizontally");
}

/// A receiver at `rate_hz`, `latency_s` late, 0.3 m per horizontal axis.
fn receiver(rate_hz: f64, latency_s: f64) -> GnssModelConfig {
    GnssModelConfig {
        rate_hz,
        latency_s,
        horizontal_sigma_m: 0.3,
        vertical_sigma_m: 0.45,
        ..GnssModelConfig::default()
    }
}

#[test]
fn the_seed_paper_quad_holds_within_1_m_on_a_0_3_m_receiver_at_5_and_10_hz_50_to_150_ms_late() {
    for (rate_hz, latency_s) in [(10.0, 0.1), (10.0, 0.05), (5.0, 0.15)] {
        for seed in [1, 2] {
            let label = format!("{rate_hz} Hz, {:.0} ms late, seed {seed}", latency_s * 1e3);
            let report = run(&label, receiver(rate_hz, latency_s), seed);
            assert_held(&label, &report);
            // Nothing but the receiver's Gaussian error: no fix is an outlier.
            assert_eq!(report.fixes_rejected, 0, "{label}");
        }
    }
}

#[test]
fn multipath_jumps_of_metres_are_refused_and_the_craft_holds_through_them() {
    // Jumps of 3 m (one standard deviation per axis) lasting 3 s, about one every 4 s.
    let gnss = GnssModelConfig {
        multipath_per_s: 0.25,
        multipath_jump_m: 3.0,
        multipath_s: 3.0,
        ..receiver(10.0, 0.1)
    };
    let report = run("multipath", gnss, 3);
    assert!(report.fixes_rejected > 10, "{} fixes refused", report.fixes_rejected);
    assert_eq!(report.outcome, Outcome::Flying, "{report:?}");
    let error = report.max_hold_error_horizontal_m.expect("held a position");
    // Without the gate the hold would follow each jump by metres.
    assert!(error < 1.5, "{error:.3} m from the setpoint horizontally");
}

/// A small version of `fly --end land monte-carlo --world random --gnss-random` (the `gnss`
/// aspect of `sim::world`): the random world's seeds 1–20, each flown on a receiver drawn for
/// it (noise 0.02–2 m correlated over 2–60 s, velocity noise 0.02–0.2 m/s, 5–10 Hz, 50–150 ms
/// late and the firmware told so, multipath jumps, dropouts). Every craft hovers and learns its
/// heading from the receiver's velocities, and at least 17 of 20 hold within their own
/// receivers' bounds (0.3 m + 2 hAcc horizontally, `GnssModelConfig::held`). Measured: 18 (seed
/// 6 is 8.3 m off, following its receiver's multipath jumps, 3.4 m per axis for 6 s, once the
/// estimator has refused them for 5 s: 86 fixes refused; seed 14 learns its heading only 4 s
/// after the release, from a receiver whose velocity noise is 0.19 m/s per axis, and is 2.1 m
/// off, still coming back, when the window starts). The 300-run figures per noise band:
/// docs/field.md, "Outdoors: a GNSS receiver".
#[test]
fn twenty_drawn_receivers_in_the_random_world_all_hover_and_most_hold_within_their_bounds() {
    let aspects = [Aspect::ALL.as_slice(), &[Aspect::Gnss]].concat();
    let results = world::monte_carlo(20, 1, 2, &aspects, &|_| {});
    let mut held = 0;
    for r in &results {
        let receiver = world::random_world_case(r.seed, &aspects).1.gnss.expect("a receiver");
        let holds = receiver.held(&r.report);
        held += usize::from(holds);
        eprintln!(
            "seed {}: {:?}, receiver {:.2} m, {:.2} m/s; hold {:.2} m horizontally (bound {:.2} \
             m): {}; heading learned {:.2} s after the release",
            r.seed,
            r.verdict,
            receiver.horizontal_sigma_m,
            receiver.velocity_noise_mps,
            r.report.max_hold_error_horizontal_m.unwrap_or(f64::NAN),
            receiver.hold_bound_m(),
            if holds { "held" } else { "not held" },
            r.report.heading_aligned_s.unwrap_or(f64::NAN),
        );
        assert!(
            matches!(r.verdict, Verdict::Held | Verdict::HoveredLoose),
            "seed {}: {:?}",
            r.seed,
            r.verdict
        );
        assert!(r.report.heading_aligned_s.is_some(), "seed {}: heading never learned", r.seed);
    }
    assert!(held >= 17, "{held} of 20 held");
}

/// The SITL on a GNSS receiver and no motion capture, in a steady 4 m/s wind: `identify` over
/// TCP arms it, the simulated hand throws it, and it recovers and holds a position from the
/// receiver's fixes. Measured on the board's own estimate (the SITL's truth stays inside it;
/// the truth's figures are the Monte Carlo's: docs/benchmarks.md, "GNSS"): in position hold,
/// within 1 m of its setpoint at every look over 4 s.
#[test]
fn the_sitl_on_gnss_in_a_4_mps_wind_recovers_from_identify_and_holds_within_1_m() {
    use sim::sitl::{Sitl, SitlConfig};
    let config = SitlConfig {
        pty: false,
        tcp_port: Some(0),
        speed: 4.0,
        hand_throws_to_fly: true,
        gnss: Some(receiver(10.0, 0.1)),
        wind_ned_mps: [0.0, 4.0, 0.0],
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let tcp = sitl.tcp_addr.unwrap().to_string();
    let identified = tests::run_cli(&["identify", "--tcp", &tcp, "--yes", "--json"]);
    assert!(identified.status.success(), "{}", String::from_utf8_lossy(&identified.stderr));
    // 6 s of flight for the recovery, the heading's alignment and the hold to start.
    std::thread::sleep(std::time::Duration::from_secs_f64(6.0 / config.speed));
    for _ in 0..4 {
        let status = tests::run_cli(&["--tcp", &tcp, "--json", "status"]);
        assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
        let status: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
        let flight = &status["flight"];
        assert_eq!(flight["mode"], "PositionHold", "{flight}");
        let error_m = tests::estimate_from_setpoint_m(flight);
        assert!(error_m < HOLD_BOUND_M, "{error_m:.3} m from the setpoint: {flight}");
        std::thread::sleep(std::time::Duration::from_secs_f64(1.0 / config.speed));
    }
    // The receiver as the board's link task sees it (protocol 1.16's `GetGnss`): configured,
    // a 3D fix, 10 a second taken.
    let info = tests::run_cli(&["--tcp", &tcp, "--json", "info"]);
    assert!(info.status.success(), "{}", String::from_utf8_lossy(&info.stderr));
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let gnss = &info["gnss"];
    assert_eq!((gnss["state"].as_str(), gnss["fix_type"].as_u64()), (Some("Receiving"), Some(3)));
    assert!(gnss["fixes"].as_u64().unwrap() > 50, "{gnss}");
}

/// Crafts a tumble left with the attitude filter tilted by about 8° (gyro scale errors in tumbles
/// of 370–470 °/s), on receivers of 0.1–0.3 m with 0.12–0.19 m/s of velocity noise (the random
/// receiver world's seeds 131 and 160). Before the heading is known nothing corrects that
/// tilt: the level hold flies the filter's level, the craft accelerates at `g · sin e`
/// (1.2–1.4 m/s²) where the dead reckoning sees nothing, and only the heading alignment, once
/// the nudge's motion outweighs that drift, lets the fixes brake it. They flew 49 and 98 m away
/// (`fly --gnss --end land case --world random --gnss-random --seed 131`) until the alignment
/// took the velocity fixes the estimator refused, its centred sums needed a quarter of the
/// evidence, the nudge went to 2 m/s² and the velocity restarted from the fixes; each now
/// learns its heading within 5 s of the release and ends within 12 m of where it recovered
/// (measured: 3.7 and 3.6 s, 8.6 m each). Not solved: seed 315, 12° after an 845 °/s tumble,
/// learns it in 5.3 s and ends 28 m away.
#[test]
fn a_craft_left_tilted_by_its_tumble_learns_its_heading_and_brakes_before_it_flies_away() {
    let aspects = [Aspect::ALL.as_slice(), &[Aspect::Gnss]].concat();
    for seed in [131, 160] {
        let (airframe, config) = world::random_world_case(seed, &aspects);
        let report = fly(&airframe, &config);
        let aligned_s = report.heading_aligned_s.unwrap_or(f64::NAN);
        let from_recovery_m = report.end_from_recovery_m.unwrap_or(f64::NAN);
        eprintln!(
            "seed {seed}: heading learned {aligned_s:.2} s after the release; ended \
             {from_recovery_m:.2} m from where it recovered"
        );
        assert!(aligned_s < 5.0, "seed {seed}: heading learned after {aligned_s:.2} s");
        assert!(from_recovery_m < 12.0, "seed {seed}: {from_recovery_m:.2} m from the recovery");
    }
}

/// The same tumbles with a compass on the GNSS mast (the random world's `compass` aspect: its
/// iron, mounting, noise and motors' interference drawn; calibrated by the user's dance before
/// the flight, `sim::compass_feed`). The heading is known before the throw, so the hold starts
/// as soon as the craft has recovered, and nothing drifts while a heading is waited for; the
/// tumble's yaw error (the gyro's scale errors, as the tilt's) is flown until the fixes'
/// evidence replaces the compass's yaw, the motors' field keeping the compass out of the flight.
/// Measured, seeds 131, 160 and 315: 8.6, 8.6 and 28 m from the recovery without the compass;
/// with it 0.26, 0.45 and 0.25 m.
#[test]
fn with_a_compass_the_tumbled_crafts_hold_where_they_recovered() {
    let aspects = [Aspect::ALL.as_slice(), &[Aspect::Gnss, Aspect::Compass]].concat();
    for seed in [131, 160, 315] {
        let (airframe, config) = world::random_world_case(seed, &aspects);
        assert!(config.compass.is_some(), "seed {seed}: no compass drawn");
        let report = fly(&airframe, &config);
        let from_recovery_m = report.end_from_recovery_m.unwrap_or(f64::NAN);
        eprintln!(
            "seed {seed}: heading learned {:.2} s after the release; ended {from_recovery_m:.2} m \
             from where it recovered",
            report.heading_aligned_s.unwrap_or(f64::NAN)
        );
        assert!(from_recovery_m < 2.0, "seed {seed}: {from_recovery_m:.2} m from the recovery");
    }
}

/// A receiver's noisy velocity is not flown as tilt: seed 157 of the random receiver world (a
/// 15 ms motor, whose velocity loop the motors alone would set at 4 m/s² per m/s, on a receiver
/// with 0.15 m/s of velocity noise per axis) held at 34 °/s RMS of body rate before the hold's
/// velocity gain was bounded by the estimate's noise
/// (`flight::controller::HOLD_VELOCITY_NOISE_ACCEL_MPS2`); the same craft on motion capture holds
/// at 1.5 °/s. Measured now: 17 °/s, and it hovers by the simulator's test (body rate below
/// 20 °/s for a second), which it did not before.
#[test]
fn a_noisy_receivers_velocity_is_not_flown_as_tilt() {
    let aspects = [Aspect::ALL.as_slice(), &[Aspect::Gnss]].concat();
    let (airframe, config) = world::random_world_case(157, &aspects);
    let receiver = config.gnss.clone().expect("a receiver");
    assert!(receiver.velocity_noise_mps > 0.14, "{} m/s", receiver.velocity_noise_mps);
    let report = fly(&airframe, &config);
    let rate_deg_s = report.hold_rate_rms_rad_s.unwrap_or(f64::NAN).to_degrees();
    eprintln!(
        "seed 157: body rate in the hold {rate_deg_s:.1} °/s RMS; hold {:.2} m horizontally",
        report.max_hold_error_horizontal_m.unwrap_or(f64::NAN)
    );
    assert!(report.release_to_hover_s.is_some(), "never hovered");
    assert!(rate_deg_s < 25.0, "{rate_deg_s:.1} °/s RMS in the hold");
}
