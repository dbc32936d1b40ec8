//! Issue 3 × issue 4, end to end: throw-and-catch logs written by the simulator (noise, bias,
//! 16-bit quantisation, 8 kHz sampling averaged to 2 kHz, realistic quadratic drag) and fitted by
//! the configurator binary (`fit imu-offset`) recover the IMU offset of the seed paper's quad.

use nalgebra::Vector3;
use serde_json::Value;
use sim::airframe::Airframe;
use sim::log::CsvLog;
use sim::scenario::{self, ScenarioConfig, ScenarioKind};
use std::path::PathBuf;
use tests::run_cli;

/// Write one throw-and-catch log spinning at `rate_dps` (°/s, body axes) and return its path.
fn throw_log(airframe: &Airframe, rate_dps: [f64; 3], seed: u64, name: &str) -> PathBuf {
    let mut config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
    config.throw_rate_body_rad_s = Vector3::from(rate_dps).map(f64::to_radians);
    config.board.seed = seed;
    let path = std::env::temp_dir().join(format!("fc-{}-{name}.csv", std::process::id()));
    let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    let mut log = CsvLog::new(file, airframe.rotor_count()).unwrap();
    scenario::run(airframe, &config, &mut scenario::NoApp, Some(&mut log), &mut |_, _| {})
        .expect("the scenario runs");
    log.finish().unwrap();
    path
}

fn fit(args: &[&str]) -> Value {
    let output = run_cli(&[&["fit", "imu-offset", "--json"], args].concat());
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).unwrap()
}

fn vector(value: &Value) -> Vector3<f64> {
    let v: Vec<f64> = value.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    Vector3::new(v[0], v[1], v[2])
}

#[test]
fn two_spinning_throws_recover_the_paper_quads_imu_offset_within_a_millimetre() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    assert!(airframe.drag.quadratic_n_per_mps2.iter().any(|&k| k > 0.0), "drag stays on");
    // Two throws of about two revolutions per second about clearly different axes.
    let first = throw_log(&airframe, [700.0, 350.0, 180.0], 3, "spin-a");
    let second = throw_log(&airframe, [-180.0, 230.0, 700.0], 4, "spin-b");
    let paths = [first.to_str().unwrap(), second.to_str().unwrap()];
    let truth = airframe.q_imu_body() * airframe.r_imu_m();

    let offset_only = fit(&paths);
    let error_mm = (vector(&offset_only["r_imu_m"]) - truth).norm() * 1e3;
    assert!(error_mm < 1.0, "offset-only fit off by {error_mm:.3} mm");
    assert_eq!(offset_only["segments"].as_array().unwrap().len(), 2, "one throw per log");

    // Jointly with the accelerometer bias (the simulated IMU has one): closer still.
    let with_bias = fit(&[&["--bias"], &paths[..]].concat());
    let error_mm = (vector(&with_bias["r_imu_m"]) - truth).norm() * 1e3;
    assert!(error_mm < 1.0, "offset-and-bias fit off by {error_mm:.3} mm");

    // The truth lies inside the reported 95 % ellipsoid of the fit with bias.
    let semi_axes = vector(&with_bias["ci95_semi_axes_m"]);
    let axes: Vec<Vector3<f64>> =
        with_bias["ci95_axes"].as_array().unwrap().iter().map(vector).collect();
    let error = vector(&with_bias["r_imu_m"]) - truth;
    let mahalanobis: f64 = (0..3).map(|i| (axes[i].dot(&error) / semi_axes[i]).powi(2)).sum();
    assert!(mahalanobis <= 1.0, "truth outside the ellipsoid: {mahalanobis:.2}");
    for path in paths {
        let _ = std::fs::remove_file(path);
    }
}

#[test]
fn one_throw_about_the_yaw_axis_is_flagged_as_not_determining_that_axis() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let log = throw_log(&airframe, [0.0, 0.0, 720.0], 5, "yaw-only");
    let report = fit(&[log.to_str().unwrap()]);
    assert_eq!(report["well_determined"], false);
    // The spin axis (body z, seen in IMU axes) is not determined: Ω × (Ω × r) loses r's
    // component along Ω. With the bias fitted from rest poses in one attitude, the plane across
    // the spin is not either (a constant bias there looks like the constant centripetal term), so
    // the largest semi-axis may lie in either; the ellipsoid's extent along the spin axis,
    // √(χ²₃ sᵀΣs), must exceed the 2 mm of "well determined".
    let spin_axis_imu = airframe.q_imu_body() * Vector3::z();
    let c: Vec<Vec<f64>> = report["covariance_m2"]
        .as_array()
        .unwrap()
        .iter()
        .map(|row| row.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect())
        .collect();
    let covariance = nalgebra::Matrix3::from_fn(|i, j| c[i][j]);
    let extent_mm = (f64::from(imu_offset::CHI2_3DOF_95)
        * spin_axis_imu.dot(&(covariance * spin_axis_imu)))
    .sqrt()
        * 1e3;
    let largest_mm = vector(&report["ci95_semi_axes_m"]).x * 1e3;
    eprintln!("one yaw throw: 95 % extent {extent_mm:.2} mm along the spin axis, largest semi-axis {largest_mm:.2} mm");
    assert!(extent_mm > 2.0, "spin axis determined within {extent_mm:.2} mm: {report}");
    // The advice names the spin axis (the direction the throw did not excite), with that extent.
    let advice = report["advice"].as_str().unwrap();
    let named: Vec<f64> = advice
        .split_once("along (")
        .and_then(|(_, rest)| rest.split_once(')'))
        .map(|(list, _)| list.split(", ").map(|v| v.parse().unwrap()).collect())
        .unwrap_or_default();
    assert_eq!(named.len(), 3, "no direction in `{advice}`");
    let named = Vector3::new(named[0], named[1], named[2]).normalize();
    let angle_deg = named.dot(&spin_axis_imu).abs().min(1.0).acos().to_degrees();
    assert!(angle_deg < 10.0, "advice names a direction {angle_deg:.1}° from the spin axis");
    assert!(advice.contains(&format!("within {extent_mm:.2} mm along it")), "{advice}");
    assert!(report["advice"].as_str().unwrap().to_lowercase().contains("throw"));
    let _ = std::fs::remove_file(log);
}
