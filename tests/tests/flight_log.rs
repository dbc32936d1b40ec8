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
    let _ = std::fs::remove_dir_all(&dir);
}
