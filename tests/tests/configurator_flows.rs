//! End to end: the configurator binary against the SITL over its pseudo-terminal, as a user
//! works with a board: calibrate, save, restart and find it again; `diff` → `defaults` → apply
//! the diff → the same `dump`; a bad line in an applied file changes nothing; everything that
//! must wait for a disarm is refused while armed; a motor test stops by itself.

use configurator_cli::connect::{connect, Target};
use configurator_cli::plot::{CLIP_ONLY_BEYOND, CONVERGED_MARGIN};
use protocol::{Event, MotorTest, Reply, Request, SetTelemetryRate, Telemetry, Topic};
use serde_json::Value;
use sim::sitl::{Sitl, SitlConfig};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tests::run_cli;

/// A flash file of its own for each test, removed first.
fn flash_file(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("fc-flows-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{test}.bin"));
    let _ = std::fs::remove_file(&path);
    path
}

fn start(flash: &Path, config: SitlConfig) -> (Sitl, String) {
    let config = SitlConfig { flash_file: Some(flash.to_path_buf()), ..config };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let port = sitl.pty_path.clone().unwrap().display().to_string();
    (sitl, port)
}

/// Run the configurator on `port`; returns (exit code, stdout, stderr).
fn cli(port: &str, args: &[&str]) -> (i32, String, String) {
    let mut all = vec!["--port", port];
    all.extend_from_slice(args);
    let output = run_cli(&all);
    (
        output.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

fn ok(port: &str, args: &[&str]) -> String {
    let (code, stdout, stderr) = cli(port, args);
    assert_eq!(code, 0, "{args:?} failed: {stderr}");
    stdout
}

fn values(json: &Value) -> Vec<f64> {
    json["value"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
}

#[test]
fn two_throws_calibrate_the_offset_which_survives_a_restart_of_the_sitl() {
    let flash = flash_file("calibration");
    let throwing = SitlConfig {
        speed: 4.0,
        auto_throw_every_s: Some(2.0),
        auto_throw_count: Some(4),
        ..SitlConfig::default()
    };
    let (sitl, port) = start(&flash, throwing);
    let report: Value = serde_json::from_str(&ok(
        &port,
        &["--json", "calibrate", "imu-offset", "--yes", "--max-throws", "2", "--timeout-s", "20"],
    ))
    .unwrap();
    assert_eq!(report["stored"], true);
    let throws = report["throws"].as_u64().unwrap();
    assert!((1..=2).contains(&throws), "{throws} throws");
    // The estimate is the airframe's offset: compare lengths (the IMU axes are rotated).
    let truth_mm = sim::airframe::Airframe::load("paper-quad").unwrap().r_imu_m().norm() * 1e3;
    let r_mm: Vec<f64> =
        report["r_imu_mm"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let norm_mm = r_mm.iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!((norm_mm - truth_mm).abs() < 1.5, "|r| {norm_mm:.2} mm, truth {truth_mm:.2} mm");
    let stored: Value =
        serde_json::from_str(&ok(&port, &["--json", "get", "imu_offset_m"])).unwrap();
    let stored_m = values(&stored);
    for (m, mm) in stored_m.iter().zip(&r_mm) {
        assert!((m * 1e3 - mm).abs() < 1e-3, "stored {stored_m:?} m, reported {r_mm:?} mm");
    }
    assert!(ok(&port, &["status"]).contains("unsaved changes"));
    ok(&port, &["save"]);
    drop(sitl);

    // The SITL restarted on the same flash file: the offset is still there, to the bit.
    let (_sitl, port) = start(&flash, SitlConfig::default());
    let again: Value =
        serde_json::from_str(&ok(&port, &["--json", "get", "imu_offset_m"])).unwrap();
    assert_eq!(values(&again), stored_m);
    let valid: Value =
        serde_json::from_str(&ok(&port, &["--json", "get", "imu_offset_valid"])).unwrap();
    assert_eq!(values(&valid), vec![1.0]);
    let status: Value = serde_json::from_str(&ok(&port, &["--json", "status"])).unwrap();
    assert_eq!(status["config"]["origin"], "loaded from flash");
    assert_eq!(status["config"]["unsaved_changes"], false);
}

#[test]
fn a_diff_applied_after_defaults_gives_back_the_same_dump_and_a_bad_line_changes_nothing() {
    let flash = flash_file("diff");
    let (_sitl, port) = start(&flash, SitlConfig::default());
    ok(&port, &["set", "imu_offset_m", "=", "0.0125,-0.003,0.0301"]);
    ok(&port, &["set", "throw_momentum_mps=5.25"]);
    ok(&port, &["set", "motor_tau_s", "=", "0.021,0.022,0.023,0.024,0,0,0,0"]);
    let dump = ok(&port, &["dump"]);
    let diff = ok(&port, &["diff"]);
    assert_eq!(diff.lines().filter(|l| l.starts_with("set ")).count(), 3, "{diff}");
    let diff_file = flash.with_extension("diff.txt");
    std::fs::write(&diff_file, &diff).unwrap();

    ok(&port, &["defaults"]);
    assert_eq!(ok(&port, &["diff"]).lines().filter(|l| l.starts_with("set ")).count(), 0);
    let applied = ok(&port, &["apply", diff_file.to_str().unwrap()]);
    assert!(applied.contains("applied 3 lines"), "{applied}");
    assert_eq!(ok(&port, &["dump"]), dump, "the dump after defaults and the diff is identical");

    // A file whose third `set` is out of range: refused with its line number, nothing applied.
    let bad = "# a pasted diff\nset throw_momentum_mps = 3\n\nset imu_offset_m = 0,0,0\nset gravity_mps2 = 12\nset excitation_step_cmd = 0.6\n";
    let bad_file = flash.with_extension("bad.txt");
    std::fs::write(&bad_file, bad).unwrap();
    let (code, stdout, stderr) = cli(&port, &["apply", bad_file.to_str().unwrap()]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stdout.is_empty());
    assert!(stderr.contains("line 5") && stderr.contains("gravity_mps2"), "{stderr}");
    assert_eq!(ok(&port, &["dump"]), dump, "nothing changed");
    // A refused `set` changes nothing either, and is bad input (exit code 2).
    let (code, _, stderr) = cli(&port, &["set", "imu_offset_m", "=", "0,0,0.9"]);
    assert_eq!(code, 2);
    assert!(stderr.contains("outside the allowed range -0.5 to 0.5 m"), "{stderr}");
    let (code, _, _) = cli(&port, &["set", "no_such_thing", "=", "1"]);
    assert_eq!(code, 2);
    assert_eq!(ok(&port, &["dump"]), dump);
}

#[test]
fn everything_that_changes_the_board_is_refused_while_armed() {
    let flash = flash_file("armed");
    let (_sitl, port) = start(&flash, SitlConfig { throw_to_fly: true, ..SitlConfig::default() });
    let dump = ok(&port, &["dump"]);
    let refused: [&[&str]; 6] = [
        &["set", "throw_momentum_mps", "=", "5"],
        &["save"],
        &["defaults"],
        &["calibrate", "imu-offset", "--yes", "--timeout-s", "2"],
        &["motor-test", "--motor", "0", "--yes", "--duration-s", "0.5"],
        &["reboot"],
    ];
    for args in refused {
        let (code, _, stderr) = cli(&port, args);
        assert_eq!(code, 1, "{args:?}: {stderr}");
        assert!(stderr.contains("refused while armed"), "{args:?}: {stderr}");
    }
    assert_eq!(ok(&port, &["dump"]), dump, "nothing changed");
    ok(&port, &["disarm"]);
    ok(&port, &["set", "throw_momentum_mps", "=", "5"]);
    ok(&port, &["save"]);
}

/// The motor command the SITL reports for `motor`, from one motors-topic sample.
fn motor_command(client: &mut configurator_cli::link::Client, motor: usize) -> f32 {
    client.telemetry.clear();
    let deadline = Instant::now() + Duration::from_secs(2);
    while Instant::now() < deadline {
        client.listen(Duration::from_millis(20)).unwrap();
        if let Some(sample) = client.telemetry.drain(..).next_back() {
            if let Telemetry::Motors(motors) = sample.data {
                return motors.commands[motor];
            }
        }
    }
    panic!("no motor telemetry");
}

#[test]
fn a_motor_test_stops_by_itself_without_keep_alive_and_at_once_on_disconnect() {
    let config = SitlConfig { pty: false, tcp_port: Some(0), ..SitlConfig::default() };
    let sitl = Sitl::start(&config).unwrap();
    let target = Target::Tcp(sitl.tcp_addr.unwrap().to_string());
    let mut client = connect(&target).unwrap();
    let rate = SetTelemetryRate { topic: Topic::Motors, rate_hz: 100 };
    client.request(&Request::SetTelemetryRate(rate), "rate").unwrap();
    let test = Request::MotorTest(MotorTest { motor: 2, command: 0.15 });
    assert_eq!(client.request(&test, "motor test").unwrap(), Reply::Done);
    assert_eq!(motor_command(&mut client, 2), 0.15);
    assert_eq!(motor_command(&mut client, 1), 0.0, "only the motor asked for");
    // No keep-alive: stopped 3 s after the request, with an event saying so.
    let started = Instant::now();
    while motor_command(&mut client, 2) > 0.0 {
        assert!(started.elapsed() < Duration::from_secs(4), "still spinning after 4 s");
    }
    let stopped_after = started.elapsed();
    assert!(stopped_after > Duration::from_millis(2700), "stopped after {stopped_after:?}");
    client.listen(Duration::from_millis(50)).unwrap();
    assert!(
        client.events.iter().any(|e| matches!(e, Event::MotorTestTimedOut { motor: 2 })),
        "{:?}",
        client.events
    );
    // Spinning again, then the host goes away: it stops at once.
    assert_eq!(client.request(&test, "motor test").unwrap(), Reply::Done);
    assert_eq!(motor_command(&mut client, 2), 0.15);
    drop(client);
    let mut watcher = connect(&target).unwrap();
    watcher.request(&Request::SetTelemetryRate(rate), "rate").unwrap();
    let dropped = Instant::now();
    while motor_command(&mut watcher, 2) > 0.0 {
        assert!(
            dropped.elapsed() < Duration::from_millis(500),
            "still spinning after the disconnect"
        );
    }
    // A bad motor index or command is refused.
    let bad = Request::MotorTest(MotorTest { motor: 4, command: 0.1 });
    assert!(watcher.request(&bad, "motor test").is_err());
    let bad = Request::MotorTest(MotorTest { motor: 0, command: 0.9 });
    assert!(watcher.request(&bad, "motor test").is_err());
}

#[test]
fn a_recording_holds_every_control_step_and_its_attitude_agrees_with_its_accelerometer() {
    let flash = flash_file("record");
    let (_sitl, port) = start(&flash, SitlConfig::default());
    let csv_path = flash.with_extension("csv");
    let report: Value = serde_json::from_str(&ok(
        &port,
        &[
            "--json",
            "record",
            "--topic",
            "state,learner",
            "--duration-s",
            "3",
            csv_path.to_str().unwrap(),
        ],
    ))
    .unwrap();
    assert_eq!(report["gaps"], 0, "{report}");
    let rows = report["rows"].as_u64().unwrap();
    let span_s = report["span_s"].as_f64().unwrap();
    assert!(span_s > 2.5, "{report}");
    assert_eq!(rows, (span_s * 2000.0).round() as u64 + 1, "one row per 500 µs step: {report}");
    let learner = report["topics"].as_array().unwrap().iter().find(|t| t["topic"] == "learner");
    assert!(learner.unwrap()["received"].as_u64().unwrap() > 200, "100 Hz learner samples");

    let text = std::fs::read_to_string(&csv_path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let number = |row: &[&str], name: &str| row[column(name)].parse::<f64>().unwrap();
    for pair in rows.windows(2) {
        let dt_s = number(&pair[1], "t") - number(&pair[0], "t");
        assert!((dt_s - 0.0005).abs() < 2e-6, "consecutive rows 500 µs apart, got {dt_s} s");
    }
    // Held still: the specific force is gravity seen through the recorded attitude,
    // f = −g (−sin θ, sin φ cos θ, cos φ cos θ), once the attitude filter has settled.
    let g = 9.81;
    for row in &rows[rows.len() - 1000..] {
        let (roll, pitch) =
            (number(row, "roll_deg").to_radians(), number(row, "pitch_deg").to_radians());
        let expected =
            [g * pitch.sin(), -g * roll.sin() * pitch.cos(), -g * roll.cos() * pitch.cos()];
        for (axis, want) in ["acc_x", "acc_y", "acc_z"].iter().zip(expected) {
            let got = number(row, axis);
            assert!((got - want).abs() < 0.4, "{axis}: {got:.3} m/s², attitude says {want:.3}");
        }
    }
    assert_eq!(rows.last().unwrap()[column("phase")], "idle");
    let _ = std::fs::remove_file(&csv_path);
}

#[test]
fn identify_learns_the_motors_and_the_thrust_axis_flies_and_stores_the_model() {
    let flash = flash_file("identify");
    let (_sitl, port) =
        start(&flash, SitlConfig { hand_throws_to_fly: true, ..SitlConfig::default() });
    let (code, stdout, stderr) =
        cli(&port, &["--json", "identify", "--yes", "--timeout-s", "20", "--disarm-after-s", "3"]);
    assert_eq!(code, 0, "identify failed: {stderr}");
    for step in ["armed", "throw detected", "pulsing motor 4", "identified", "flying", "disarmed"] {
        assert!(stderr.contains(step), "no `{step}` in the progress: {stderr}");
    }
    let report: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!((report["phase"].as_str(), report["flew"].as_bool()), (Some("Done"), Some(true)));
    assert_eq!(report["stored_in_parameters"], true, "{report}");
    // The flight summary of `--disarm-after-s`, as the text prints it: a hover reached within
    // a few seconds of the release, the thrust axis near its setpoint meanwhile.
    let flight = &report["flight"];
    let hover_after_s = flight["hover_after_s"].as_f64().unwrap_or(f64::NAN);
    assert!((0.5..5.0).contains(&hover_after_s), "{flight}");
    assert!(flight["worst_tilt_deg"].as_f64().is_some_and(|deg| deg < 30.0), "{flight}");
    assert_eq!(flight["worst_position_m"], Value::Null, "no external pose: {flight}");
    let airframe = sim::airframe::Airframe::load("paper-quad").unwrap();
    let truth = sim::identification::TrueModel::of(&airframe);
    // The thrust axis: the learned −z of the thrust frame against the truth, in IMU axes.
    let q: Vec<f64> = report["thrust_axis"]["q_thrust_to_imu"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let learned = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        q[0], q[1], q[2], q[3],
    ));
    let down = nalgebra::Vector3::new(0.0, 0.0, -1.0);
    let angle_deg = (learned * down).angle(&(truth.q_thrust_to_imu * down)).to_degrees();
    // A flow test: the model the configurator reports and stores is the firmware's. The
    // accuracy of the identification itself is asserted in tests/identification.rs (0.5° on the
    // paper's throw). Here the SITL's hand throw is followed by the controller at full thrust
    // during the learner's settling window, which moves the axis: 3.45° measured (1.0–2.5° with
    // the controller's earlier thrust projection). Known weakness, in the issue note.
    assert!(angle_deg < 5.0, "thrust axis {angle_deg:.2}° from the truth");
    // The motor time constants, in the report and in the parameters now in force.
    let tau: Value = serde_json::from_str(&ok(&port, &["--json", "get", "motor_tau_s"])).unwrap();
    for (i, tau_s) in values(&tau).iter().enumerate() {
        assert!(
            (tau_s - truth.tau_s[i]).abs() < 0.003,
            "motor {i}: τ {tau_s} s vs {}",
            truth.tau_s[i]
        );
    }
    let diff = ok(&port, &["diff"]);
    assert!(diff.contains("set thrust_axis_q") && diff.contains("set g1_fz"), "{diff}");
    // No calibration was stored and no throw made one: the IMU offset was fitted in this
    // flight (issue 32). The status shows it as a calibration's, the identification says so,
    // and it is in force as the calibration (to be saved with the rest).
    let status: Value = serde_json::from_str(&ok(&port, &["--json", "status"])).unwrap();
    let identification = &status["identification"];
    assert_eq!(identification["speeds"], "measured", "{identification}");
    assert_eq!(identification["imu_offset_source"], "fitted_in_flight", "{identification}");
    let offset = &status["imu_offset"];
    assert_eq!(offset["source"], "fitted_in_flight", "{offset}");
    let r: Vec<f64> =
        offset["r_imu_m"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let r_error_m = (nalgebra::Vector3::from_column_slice(&r) - truth.r_imu_m).norm();
    // The paper quad's IMU sits 18 mm from its centre of gravity: an offset taken as zero would
    // be that far off. (A flow test: 1.4 mm measured; the fit's accuracy is asserted in
    // tests/imu_offset_in_flight.rs.)
    assert!(
        truth.r_imu_m.norm() > 0.015 && r_error_m < 0.005,
        "r {r:?} m, truth {:?}, {:.2} mm off",
        truth.r_imu_m,
        r_error_m * 1e3
    );
    let valid: Value =
        serde_json::from_str(&ok(&port, &["--json", "get", "imu_offset_valid"])).unwrap();
    assert_eq!(values(&valid), [1.0]);
    let stored: Value =
        serde_json::from_str(&ok(&port, &["--json", "get", "imu_offset_m"])).unwrap();
    let stored = values(&stored);
    assert!(
        stored.iter().zip(&r).all(|(a, b)| (a - b).abs() < 1e-6),
        "stored {stored:?}, shown {r:?}"
    );
    let ci95: Value =
        serde_json::from_str(&ok(&port, &["--json", "get", "imu_offset_ci95_m"])).unwrap();
    // Flown (and stored) once usable: its largest 95 % semi-axis within 5 mm.
    assert!(values(&ci95).iter().all(|&axis_m| axis_m > 0.0 && axis_m <= 0.005), "{ci95}");
}

/// `plot` of a real recording: an octorotor's throw-and-fly from the SITL (8 motors, so 24 G1
/// columns a panel). The G1 panels' axes fit what the learner converged to, not its first
/// transients; their legends are one row per motor and per G1 row; the attitude, which this
/// airframe's upside-down IMU records wrapping at ±180°, is drawn continuous.
#[test]
fn plot_of_an_octorotor_throw_and_fly_is_readable() {
    let flash = flash_file("plot");
    let config = SitlConfig {
        airframe: "octo-flat".into(),
        hand_throws_to_fly: true,
        ..SitlConfig::default()
    };
    let (_sitl, port) = start(&flash, config);
    let csv = flash.with_extension("csv");
    let csv_arg = csv.to_str().unwrap();
    // Recorded 4 s past the excitation: the in-flight IMU-offset fit replaces the force rows
    // about 0.8 s after it (the earlier plateau is a transient the axis may clip), and the
    // converged axis fits the recording's second half, which then starts after that.
    let args = ["identify", "--yes", "--timeout-s", "20", "--disarm-after-s", "4"];
    ok(&port, &[&args[..], &["--record", csv_arg]].concat());
    let png = flash.with_extension("png");
    let report: Value =
        serde_json::from_str(&ok(&port, &["--json", "plot", csv_arg, "-o", png.to_str().unwrap()]))
            .unwrap();
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");

    let text = std::fs::read_to_string(&csv).unwrap();
    let rec = configurator_cli::plot::parse_recording(&text, "octo.csv").unwrap();
    let column = |name: &str| &rec.columns.iter().find(|c| c.name == name).unwrap().values;
    let axis = |panel: &str| {
        let axes = report["axes"].as_array().unwrap();
        let a = axes.iter().find(|a| a["panel"] == panel).unwrap_or_else(|| panic!("{report}"));
        (a["y_min"].as_f64().unwrap(), a["y_max"].as_f64().unwrap(), a.clone())
    };
    for (panel, rows) in [
        ("G1 convergence: specific force", ["fx", "fy", "fz"]),
        ("G1 convergence: angular acceleration", ["p", "q", "r"]),
    ] {
        let (lo, hi, a) = axis(panel);
        // What the learner ended with: every value on the axis, and spread over a good part of
        // it (a transient-scaled axis squashes them into 4 to 12 % of the height here).
        let last: Vec<f64> = rows
            .iter()
            .flat_map(|row| (0..8).map(move |m| format!("g1_{row}_{m}")))
            .map(|name| column(&name).iter().rev().find_map(|v| *v).unwrap())
            .collect();
        let (min, max) = last.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(lo < min && max < hi, "{panel}: learned {min}..{max} beyond the axis {lo}..{hi}");
        // The axis promises them at least 1 / (2 × 1.5) of its height: it clips the transients
        // only where that gains a factor CLIP_ONLY_BEYOND, around the converged spread widened
        // by CONVERGED_MARGIN each side (10 % allowed for the tail's settling).
        let promised = 1.0 / (CLIP_ONLY_BEYOND * (1.0 + 2.0 * CONVERGED_MARGIN));
        let share = (max - min) / (hi - lo);
        assert!(
            share > 0.9 * promised,
            "{panel}: the learned values use {:.0} % of the axis",
            share * 100.0
        );
        // 8 motors + 3 line styles (+ the marker of clipped samples), not 24 columns.
        let clipped = a["clipped_samples"].as_u64().unwrap() > 0;
        assert_eq!(a["legend_entries"], 8 + 3 + u64::from(clipped), "{a}");
    }
    // The recorded roll and yaw wrap at ±180° (jumps of nearly 360° between two rows); drawn
    // unwrapped, no step between two rows is more than a quarter turn, and the axis runs past
    // 180°. A quarter turn, not the 10° of the rows' usual spacing: the rows come as the
    // telemetry reaches the recorder (their times are its arrivals), further apart on a loaded
    // machine (a step of 11.8° under `cargo xtask test`, in a tumble of 1,000 °/s), while a wrap
    // left in, or one unwrapped the wrong way, is 360° in one row.
    let wrapped = |name: &str| {
        let v: Vec<f64> = column(name).iter().flatten().copied().collect();
        v.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max)
    };
    assert!(wrapped("roll_deg") > 300.0, "the flight wraps the roll: the premise of this check");
    for name in ["roll_deg", "pitch_deg", "yaw_deg"] {
        let drawn = configurator_cli::plot::unwrap_deg(column(name));
        let steps = drawn.windows(2).filter_map(|w| Some((w[1]? - w[0]?).abs()));
        let largest = steps.fold(0.0, f64::max);
        assert!(largest < 90.0, "{name}: a step of {largest:.1}° between two rows");
    }
    let (lo, hi, _) = axis("attitude");
    assert!(lo < -180.0 || hi > 180.0, "attitude axis {lo}..{hi}: not unwrapped");
    for path in [csv, png] {
        let _ = std::fs::remove_file(path);
    }
}

#[test]
fn the_shell_reconnects_by_itself_after_a_reboot_and_finds_the_saved_value() {
    use std::io::Write as _;
    let flash = flash_file("reconnect");
    let (_sitl, port) = start(&flash, SitlConfig::default());
    let mut child = std::process::Command::new(tests::cli_binary())
        .args(["--port", &port, "shell"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let script = "set gravity_mps2 = 9.79\nsave\nreboot\nget gravity_mps2\nstatus\n";
    child.stdin.take().unwrap().write_all(script.as_bytes()).unwrap();
    let output = child.wait_with_output().unwrap();
    let (stdout, stderr) =
        (String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("reconnected to SITL"), "the shell says it reconnected: {stderr}");
    assert!(!stderr.contains("error"), "every command after the reboot worked: {stderr}");
    let restarted = format!(
        "the board restarted; configuration: {} parameters, loaded from flash",
        firmware::app::params::PARAM_COUNT
    );
    assert!(stdout.contains(&restarted), "{stdout}");
    let after = stdout.split("the board restarted").nth(1).unwrap();
    assert!(after.contains("gravity_mps2 = 9.79\n"), "the saved value after the reboot: {after}");
}

/// `motor_bidir_dshot = 0` (ESCs without bidirectional DShot) takes effect at the next start:
/// the SITL's ESCs then report no speed, as BLHeli_S ESCs would, and throw-to-fly arms to
/// identify from the commands; with the default (1) a stopped motor reads 0 rad/s.
#[test]
fn the_bidirectional_dshot_parameter_decides_after_a_restart_whether_speeds_are_reported() {
    let flash = flash_file("bidir");
    let (_sitl, port) = start(&flash, SitlConfig::default());
    let dir = flash.parent().unwrap();
    let record = |name: &str| {
        let csv = dir.join(name);
        ok(&port, &["record", "--topic", "motors", "--duration-s", "0.1", csv.to_str().unwrap()]);
        let text = std::fs::read_to_string(&csv).unwrap();
        let last = text.lines().last().unwrap().to_string();
        // t, four commands, four speeds.
        last.split(',').skip(5).map(str::to_string).collect::<Vec<_>>()
    };
    assert_eq!(record("bidir-on.csv"), vec!["0"; 4], "a stopped motor reads 0 rad/s");
    ok(&port, &["set", "motor_bidir_dshot", "=", "0"]);
    ok(&port, &["save"]);
    assert_eq!(record("bidir-saved.csv"), vec!["0"; 4], "in force from the next start only");
    ok(&port, &["reboot"]);
    let off = record("bidir-off.csv");
    assert!(off.iter().all(|speed| speed != "0"), "no speed reported: {off:?}");
    // The bring-up check agrees (docs/bring-up.md): the `esc` line passes, the SITL identifying
    // without speeds (protocol 1.13's capability), and the spin, with no report to check the
    // outputs against, is skipped, pointing at `motor-test`.
    let (code, doctor, stderr) = cli(&port, &["--json", "doctor", "--yes"]);
    assert_eq!(code, 0, "{doctor}{stderr}");
    let lines: Vec<Value> = serde_json::from_str(&doctor).unwrap();
    let line = |name: &str| lines.iter().find(|l| l["name"] == name).unwrap().clone();
    assert_eq!(line("esc")["verdict"], "pass", "{}", line("esc"));
    assert!(line("esc")["found"].as_str().unwrap().contains("from the commands"));
    assert_eq!(line("spin")["verdict"], "skipped", "{}", line("spin"));
    assert!(line("spin")["advice"].as_str().unwrap().contains("motor-test"));
    // Every build identifies from the commands (`flight::learner::no_speed`, issue 56):
    // arming for a throw is accepted although no motor reports, and stays armed past the
    // speed reports' timeout (0.1 s).
    let (code, stdout, stderr) = cli(&port, &["arm-throw-to-fly"]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert!(stdout.contains("from the commands"), "the arming says which: {stdout}");
    std::thread::sleep(std::time::Duration::from_millis(300));
    let status: Value = serde_json::from_str(&ok(&port, &["--json", "status"])).unwrap();
    assert_eq!(status["armed"], true, "{status}");
    assert_eq!(status["learner"]["phase"], "WaitingForThrow", "{status}");
    ok(&port, &["disarm"]);
}
