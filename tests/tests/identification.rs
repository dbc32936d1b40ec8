//! In-flight identification against the simulator's truth: the firmware application, armed for
//! throw-to-fly, is thrown on the seed paper's parabola; its learner must find each motor's time
//! constant, the effectiveness G1 and the hover thrust axis (the IMU's rotation) within the
//! issue's bounds. The craft falls afterwards: recovery is the controller's issue.

use sim::airframe::Airframe;
use sim::identification::{identify, IdentifyConfig, Scores};

fn report(name: &str, config: &IdentifyConfig) -> (Scores, sim::identification::IdentifyReport) {
    let airframe = Airframe::builtin(name).unwrap();
    let report = identify(&airframe, config);
    let learned = report.at_capture.expect("the excitation ran");
    let scores = Scores::of(&learned, &report.truth);
    eprintln!(
        "{name}: G1 rows {:?} %, τ error {:.3} ms, axis {:.3}°, euler errors {:?}°, release→excitation {:?} s, excitation→axis {:?} s",
        scores.g1_row_rel.map(|e| (e * 1000.0).round() / 10.0),
        scores.tau_error_max_s * 1e3,
        scores.axis_angle_rad.to_degrees(),
        scores.euler_error_rad.map(|e| (e.to_degrees() * 1000.0).round() / 1000.0),
        report.release_to_excitation_s,
        report.excitation_to_axis_s,
    );
    eprintln!("  axis status {:?}", learned.axis_status);
    for k in 0..6 {
        eprintln!(
            "  G1 row {k}: learned {:?}",
            (0..report.truth.motors).map(|i| learned.g1_per_speed2[k][i] * 1e6).collect::<Vec<_>>()
        );
        eprintln!(
            "            truth   {:?}",
            (0..report.truth.motors)
                .map(|i| report.truth.g1_per_speed2[k][i] * 1e6)
                .collect::<Vec<_>>()
        );
    }
    for k in 0..3 {
        eprintln!(
            "  G2 row {k}: learned {:?}",
            (0..report.truth.motors).map(|i| learned.g2[k][i] * 1e3).collect::<Vec<_>>()
        );
        eprintln!(
            "            truth   {:?}",
            (0..report.truth.motors).map(|i| report.truth.g2[k][i] * 1e3).collect::<Vec<_>>()
        );
    }
    for i in 0..report.truth.motors {
        eprintln!(
            "  motor {i}: τ {:.2} ms (true {:.2})",
            learned.motor[i].tau_s * 1e3,
            report.truth.tau_s[i] * 1e3
        );
    }
    (scores, report)
}

#[test]
fn paper_quad_identifies_within_300_ms_of_the_excitation() {
    let (scores, _) = report("paper-quad", &IdentifyConfig::paper());
    assert!(scores.axis_found);
}

#[test]
fn scratch_effects() {
    for (label, drag, ideal, rotor_inertia) in [
        ("base", true, false, true),
        ("no drag", false, false, true),
        ("ideal imu", true, true, true),
        ("no drag ideal", false, true, true),
        ("no Jr", false, true, false),
    ] {
        let mut airframe = Airframe::builtin("paper-quad").unwrap();
        if !drag {
            airframe.drag = Default::default();
        }
        if !rotor_inertia {
            airframe.motor.rotor_inertia_kg_m2 = 0.0;
        }
        let mut config = IdentifyConfig::paper();
        config.board.ideal_imu = ideal;
        let report = identify(&airframe, &config);
        let s = Scores::of(&report.at_capture.unwrap(), &report.truth);
        eprintln!(
            "{label}: rows {:?} axis {:.2}°",
            s.g1_row_rel.map(|e| (e * 1000.0).round() / 10.0),
            s.axis_angle_rad.to_degrees()
        );
    }
}
