//! The flight on record, end to end: a SITL throw-and-fly with a log directory leaves a log, and
//! `configurator-cli replay LOG` feeds it back through a fresh firmware application: bit for
//! bit the same commands at every step; with a parameter changed, the first step that departs,
//! and the effect on the learned model.
//!
//! `cargo test -p tests --release --test flight_log -- --nocapture` prints the replay reports.

use firmware::app::log::{LogReader, LogRecord};
use sim::sitl::{Sitl, SitlConfig};
use std::time::{Duration, Instant};
use tests::run_cli;

/// Steps in the log written so far (its complete blocks).
fn logged_steps(file: &std::path::Path) -> usize {
    let bytes = std::fs::read(file).unwrap_or_default();
    LogReader::new(&bytes).filter(|r| matches!(r, LogRecord::Step(_))).count()
}

fn replay(path: &str, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["replay", path, "--json"];
    args.extend_from_slice(extra);
    let output = run_cli(&args);
    assert!(
        output.status.success(),
        "replay {extra:?} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    eprintln!("{}", String::from_utf8_lossy(&output.stdout));
    serde_json::from_slice(&output.stdout).expect("replay --json prints JSON")
}

#[test]
fn a_sitl_throw_and_fly_leaves_a_log_that_replays_bit_for_bit_and_a_changed_parameter_departs() {
    let dir = std::env::temp_dir().join(format!("flight-log-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let config = SitlConfig {
        pty: false,
        speed: 20.0,
        throw_to_fly: true,
        hand_throws_to_fly: true,
        log_dir: Some(dir.clone()),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let file = dir.join("LOG00001.BIN");
    let started = Instant::now();
    while logged_steps(&file) < 12_000 {
        assert!(started.elapsed() < Duration::from_secs(600), "no log of 6 s within 10 min");
        assert!(sitl.is_running(), "the SITL stopped");
        std::thread::sleep(Duration::from_millis(500));
    }
    // Stopping ends the file in order (its last block and the end record).
    drop(sitl);
    let path = file.to_str().unwrap();

    let same = replay(path, &[]);
    assert!(same["steps"].as_u64().unwrap() > 10_000, "{same}");
    assert_eq!(same["differences"], 0, "{same}");
    assert_eq!(same["from_start_up"], true);
    let phases: Vec<&str> = same["phases"]["logged"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["phase"].as_str().unwrap())
        .collect();
    assert!(phases.ends_with(&["exciting", "done"]), "the throw was identified: {phases:?}");

    // The learner's and the flight's snapshots, at 25 Hz each by their own time: the G1
    // estimate converging, then the flight on it.
    let bytes = std::fs::read(&file).unwrap();
    let mut learner = Vec::new();
    let mut flight = Vec::new();
    for record in LogReader::new(&bytes) {
        match record {
            LogRecord::Learner(sample) if sample.g1_block == 0 => learner.push(sample),
            LogRecord::Flight(sample) => flight.push(sample),
            _ => {}
        }
    }
    let median_period_ms = |times: Vec<u64>| {
        let mut gaps: Vec<u64> = times.windows(2).map(|w| w[1] - w[0]).collect();
        gaps.sort_unstable();
        gaps[gaps.len() / 2] as f64 / 1000.0
    };
    let learner_ms = median_period_ms(learner.iter().map(|l| l.t_us).collect());
    let flight_ms = median_period_ms(flight.iter().map(|f| f.t_us).collect());
    assert!((39.0..=42.0).contains(&learner_ms), "learner every {learner_ms} ms");
    assert!((39.0..=42.0).contains(&flight_ms), "flight every {flight_ms} ms");
    let last = learner.last().unwrap();
    assert_eq!(last.phase, protocol::LearnerPhase::Done, "{last:?}");
    // Every motor at full thrust (u = 1) accelerates the craft by several g (IMU axes).
    let m = usize::from(last.motor_count);
    let full_thrust_mps2 =
        last.g1_rows.iter().map(|row| row[..m].iter().sum::<f32>().powi(2)).sum::<f32>().sqrt();
    assert!(full_thrust_mps2 > 15.0, "the learned G1's force rows: {:?}", last.g1_rows);
    assert!(
        flight.iter().any(|f| f.mode != protocol::FlightMode::Off),
        "the flight on the learned model is on record"
    );

    // The age of a motor-speed report aligns the learner's motor models: at the other end of
    // its range the learned model, and with it the flight on it, must depart.
    let changed = replay(path, &["--set", "motor_speed_age_s=0.003"]);
    assert!(changed["differences"].as_u64().unwrap() > 0, "{changed}");
    let first = &changed["first_difference"];
    let excitation_end_s =
        same["phases"]["logged"].as_array().unwrap().iter().find(|p| p["phase"] == "done").unwrap()
            ["t_s"]
            .as_f64()
            .unwrap();
    // The learner's model first acts when the pilot engages on it, at the excitation's end.
    assert!(
        (first["t_s"].as_f64().unwrap() - excitation_end_s).abs() < 0.01,
        "first difference {first} against the excitation's end at {excitation_end_s} s"
    );
    let learned = &changed["learned_difference"];
    assert!(learned["g1_relative_difference"].as_f64().unwrap() > 0.01, "{learned}");

    // The same flight as the CSV `record` writes: one row per step with an IMU sample, the
    // logged values in their columns, and `plot` reads it.
    let csv = dir.join("flight.csv");
    let output = run_cli(&["log", "to-csv", path, csv.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let rows: Vec<Vec<f64>> =
        lines.map(|l| l.split(',').map(|x| x.parse().unwrap_or(f64::NAN)).collect()).collect();
    let bytes = std::fs::read(&file).unwrap();
    let steps: Vec<_> = LogReader::new(&bytes)
        .filter_map(|r| match r {
            LogRecord::Step(step) if step.imu.is_some() => Some(step),
            _ => None,
        })
        .collect();
    assert_eq!(rows.len(), steps.len(), "one row per step with an IMU sample");
    let column = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("no column {name} in {header:?}"))
    };
    let (gx, az) = (column("gyro_x"), column("acc_z"));
    for (row, step) in rows.iter().zip(&steps).step_by(997) {
        let imu = step.imu.unwrap();
        assert!((row[0] - step.t_us as f64 * 1e-6).abs() < 1e-6);
        assert!(
            (row[gx] - f64::from(imu[0])).abs() < 1e-4
                && (row[az] - f64::from(imu[5])).abs() < 1e-4
        );
    }
    let png = dir.join("flight.png");
    let plotted = run_cli(&["plot", csv.to_str().unwrap(), "-o", png.to_str().unwrap()]);
    assert!(plotted.status.success(), "{}", String::from_utf8_lossy(&plotted.stderr));
    let _ = std::fs::remove_dir_all(&dir);
}
