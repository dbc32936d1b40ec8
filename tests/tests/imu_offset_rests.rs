//! Issues 28 and 32: what two equal-rate throws and their rests can and cannot settle onboard.
//! The configurator binary runs the guided calibration (`calibrate imu-offset`) against the SITL
//! over its pseudo-terminal, as a user does with a board; the SITL's hand throws the craft at one
//! spin rate (550 °/s, as the seed paper throws) about two different body axes, with an
//! accelerometer bias of 0.1 m/s², and holds it still between and after the throws.
//!
//! The first throw spins about the yaw axis, so the catch leaves the craft level and the rests
//! before and after it are one attitude. At the second catch the board's estimate cannot tell a
//! bias from the offset along the cross product of the two spin axes (equal rates give the same
//! centripetal term in both throws). Issue 28 let the rest after that catch measure the bias
//! there and conclude; but a rest pose reads the accelerometer's scale errors too (`g uᵀ S u`,
//! up to 0.3 m/s² for the ±3 % the estimator assumes, `imu_offset::rest`), so three attitudes
//! cannot pin a bias of 0.1 m/s², and concluding on them was overconfident on real IMUs (the
//! truth inside the ellipsoid in 34 of 200 random airframes). Now the board asks for a throw at
//! another spin rate, and the third throw, at 350 °/s about the pitch axis, concludes.

use nalgebra::Vector3;
use serde_json::Value;
use sim::airframe::Airframe;
use sim::sitl::{Sitl, SitlConfig};
use tests::run_cli;

/// The accelerometer bias of the simulated IMU, m/s², IMU axes: 0.1 m/s² (10 mg, half the
/// ICM-42688-P's specified zero-g offset), on every axis.
const ACC_BIAS_MPS2: [f64; 3] = [0.0577, -0.0577, 0.0577];

#[test]
fn two_equal_rate_throws_ask_for_another_rate_and_a_third_throw_concludes() {
    // Built before the SITL starts throwing, so that the calibration sees every throw.
    tests::cli_binary();
    let flash = std::env::temp_dir().join(format!("fc-rests-{}.bin", std::process::id()));
    let _ = std::fs::remove_file(&flash);
    let config = SitlConfig {
        speed: 2.0,
        auto_throw_every_s: Some(3.0),
        auto_throw_count: Some(3),
        auto_throw_rates_dps: Some(vec![[0.0, 0.0, 550.0], [550.0, 0.0, 0.0], [0.0, 350.0, 0.0]]),
        acc_bias_mps2: Some(ACC_BIAS_MPS2),
        flash_file: Some(flash.clone()),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let port = sitl.pty_path.clone().unwrap().display().to_string();
    let args = [
        "--port",
        port.as_str(),
        "--json",
        "calibrate",
        "imu-offset",
        "--yes",
        "--max-throws",
        "3",
        "--timeout-s",
        "20",
    ];
    let output = run_cli(&args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    eprintln!("{stderr}");
    assert!(output.status.success(), "calibrate did not conclude after three throws: {stderr}");
    // After the second throw and its rest the board asked for another spin rate; the third
    // throw concluded.
    let after_two = stderr.split("throw 3:").next().unwrap_or_default();
    assert!(after_two.contains("different spin rate"), "{stderr}");
    assert!(stderr.contains("throw 3:"), "{stderr}");
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["stored"], true);
    assert_eq!(report["throws"].as_u64(), Some(3));
    let vector = |v: &Value| {
        let v: Vec<f64> = v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        Vector3::new(v[0], v[1], v[2])
    };
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let truth_mm = airframe.q_imu_body() * airframe.r_imu_m() * 1e3;
    let error_mm = (vector(&report["r_imu_mm"]) - truth_mm).norm();
    let semi_axes_mm = vector(&report["ci95_semi_axes_mm"]);
    eprintln!(
        "offset {:.2?} mm, truth {:.2?} mm: {error_mm:.2} mm off; 95 % semi-axes {:.2?} mm",
        vector(&report["r_imu_mm"]).as_slice(),
        truth_mm.as_slice(),
        semi_axes_mm.as_slice()
    );
    assert!(error_mm < 1.0, "offset {error_mm:.2} mm from the truth");
    assert!(semi_axes_mm.max() <= 2.0, "not well determined: {semi_axes_mm:?} mm");
    // The bias stored with it removes most of the simulated one. Not all: with two of the three
    // rest attitudes level, the bias along "up" is known only as well as local gravity is
    // (`gravity_sigma_mps2`, 0.01 m/s²) and what the free fall adds (0.034 m/s² off, measured).
    let bias = Vector3::from(ACC_BIAS_MPS2);
    let bias_error = (vector(&report["acc_bias_mps2"]) - bias).norm();
    assert!(
        bias_error < 0.5 * bias.norm(),
        "bias {:?} m/s², off by {bias_error:.3}",
        report["acc_bias_mps2"]
    );
    drop(sitl);
    let _ = std::fs::remove_file(&flash);
}
