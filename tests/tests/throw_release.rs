//! A real hand's release and throws other than the paper's, end to end: the firmware
//! application, exactly as the board runs it, armed for throw-to-fly in the simulator.
//!
//! The simulator's hand (`sim::hand`) lets go over a taper: its push falls to zero along a
//! raised cosine, so the specific force passes through every value between the push and free
//! fall, and the board's 2 kHz samples (each the mean of four 8 kHz IMU samples) straddle the
//! release wherever it falls between them. The published detector declared the release at
//! 20 m/s², in the middle of such a taper, and refused every throw whose taper lasted 5 ms or
//! more (`flight::learner::throw_detector`).
//!
//! `cargo test -p tests --release --test throw_release -- --nocapture` prints the figures.

use nalgebra::Vector3;
use sim::airframe::Airframe;
use sim::identification::{identify, IdentifyConfig, Throw};
use sim::recovery::{fly, FlyConfig, Outcome};

/// The longest a craft may fall with its motors off after leaving the hand, s (issue 28: the
/// motors start within 300 ms of the craft leaving the hand).
const MOTORS_START_WITHIN_S: f64 = 0.3;

#[test]
fn tapering_releases_start_the_motors_within_300_ms_of_leaving_the_hand() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    for taper_ms in [5.0, 15.0, 40.0] {
        // Pushes that end on a control step and 125, 250 and 375 µs after one.
        for eighth_khz in 0..4 {
            let mut config = IdentifyConfig::paper();
            config.throw.taper_s = taper_ms * 1e-3;
            config.throw.push_s = 0.15 + f64::from(eighth_khz) / 8000.0;
            let report = identify(&airframe, &config);
            let start_s = report.release_to_excitation_s;
            eprintln!("taper {taper_ms} ms, push {:.4} s: motors start {start_s:?} s after the hand let go", config.throw.push_s);
            let start_s = start_s.unwrap_or_else(|| panic!("taper {taper_ms} ms: never thrown"));
            assert!(
                start_s <= MOTORS_START_WITHIN_S,
                "taper {taper_ms} ms: the motors started {start_s} s after the release"
            );
            // The release delay (150 ms of verified free fall) ran after the push's force fell
            // below 0.8 g, which is within the taper's last part.
            assert!(start_s >= 0.15 - taper_ms * 1e-3, "taper {taper_ms} ms: {start_s} s");
            assert!(report.at_end.is_some(), "taper {taper_ms} ms: the excitation did not end");
        }
    }
}

#[test]
fn the_paper_quad_thrown_at_1000_deg_s_about_each_axis_recovers_and_holds() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let diagonal = Vector3::new(1.0, 1.0, 1.0).normalize();
    let axes = [
        Vector3::x(),
        Vector3::y(),
        Vector3::z(),
        diagonal,
        Vector3::new(-1.0, 1.0, -1.0).normalize(),
    ];
    for axis in axes {
        let mut config = FlyConfig::paper();
        config.throw = Throw {
            rate_body_rad_s: axis * 1000f64.to_radians(),
            taper_s: 0.015,
            ..Throw::paper()
        };
        let report = fly(&airframe, &config);
        let hold_m = report.max_hold_error_m.unwrap_or(f64::INFINITY);
        eprintln!(
            "1000 °/s about {:.2?}: {:?}, hover after {:.2?} s, hold within {hold_m:.3} m, G1 at engagement {:.3?}",
            axis.as_slice(),
            report.outcome,
            report.release_to_hover_s,
            report.g1_block_rel_at_engage
        );
        assert_eq!(report.outcome, Outcome::Flying, "about {axis:?}");
        assert!(report.release_to_hover_s.is_some(), "never hovered about {axis:?}");
        assert!(hold_m <= 0.3, "about {axis:?}: held within {hold_m} m");
    }
}
