//! Landing from the configurator (protocol 1.14), end to end: `configurator-cli` against the
//! SITL, whose simulated hand throws the craft to fly once it is armed, over the SITL's own link
//! and over its simulated 57,600-baud telemetry radio. The test watches the flight over a
//! second link (TCP) with the configurator's client, so what it sees is what the board reports.
//! The flying craft gets the SITL's motion-capture poses: without a pose the board's landing
//! does not detect its touchdown in the SITL (the dead-reckoned vertical speed drifts once the
//! craft meets the ground, and the thrust rises above hover; see the report of `land-cli`).
//!
//! Why: over a radio, anyone on the channel can send a disarm, and every way to stop must work;
//! so an unsigned disarm over the radio lands a flying craft instead of dropping it (and stops
//! one on the ground at once), while the paired configurator's signed disarm still stops the
//! motors at once. `land` puts the craft down gently and reports its touchdown speed.

use configurator_cli::connect::{connect, Target};
use configurator_cli::link::Client;
use protocol::{Event, FlightMode, FlightTelemetry, LandReason, Reply, Request};
use serde_json::Value;
use sim::serve::RadioConfig;
use sim::sitl::{Sitl, SitlConfig};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The touchdown speed a landing must stay below, m/s (the default descent is 0.5 m/s).
const MAX_TOUCHDOWN_SPEED_MPS: f64 = 0.7;
/// How long a throw-to-fly may take from the arming to flying on the learned model, s
/// (the hand throws 1 s after the arming; the excitation and the recovery follow).
const FLYING_WITHIN_S: f64 = 20.0;
/// How long a landing from the throw's height may take, s (about 4 m at 0.5 m/s).
const LANDED_WITHIN_S: f64 = 30.0;

/// A SITL whose hand throws the craft to fly when armed (`hand`, with motion capture), with its own link (a
/// pseudo-terminal), a TCP link for watching, and a 57,600-baud radio (20 ms, no frame lost).
fn start_sitl(seed: u64, hand: bool) -> (Sitl, String, String, Client) {
    let config = SitlConfig {
        seed,
        hand_throws_to_fly: hand,
        mocap: hand,
        tcp_port: Some(0),
        telemetry_radio: Some(RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.0 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let usb = sitl.pty_path.clone().unwrap().display().to_string();
    let radio = sitl.radio_path.clone().unwrap().display().to_string();
    let watch = connect(&Target::Tcp(sitl.tcp_addr.unwrap().to_string())).expect("TCP link");
    (sitl, usb, radio, watch)
}

/// A fresh directory of link keys for one configurator.
fn keys_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("fc-land-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// `configurator-cli` with its link keys in `keys`; asserts that it succeeded.
fn cli(keys: &Path, args: &[&str]) -> std::process::Output {
    let output = std::process::Command::new(tests::cli_binary())
        .env(configurator_cli::keys::KEY_DIR_ENV, keys)
        .args(args)
        .output()
        .expect("start configurator-cli");
    assert!(
        output.status.success(),
        "{args:?}: {}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// Flying on the learned model, not landing.
fn flying(flight: &FlightTelemetry) -> bool {
    matches!(flight.mode, FlightMode::LevelHold | FlightMode::PositionHold)
}

fn flight(watch: &mut Client) -> FlightTelemetry {
    match watch.request(&Request::GetFlight(()), "the flight request") {
        Ok(Reply::Flight(flight)) => flight,
        other => panic!("{other:?}"),
    }
}

fn armed(watch: &mut Client) -> bool {
    match watch.request(&Request::GetStatus(()), "the status request") {
        Ok(Reply::Status(status)) => status.armed,
        other => panic!("{other:?}"),
    }
}

/// Poll the flight every 50 ms until `done` accepts it; panics after `within_s`.
fn wait_for(
    watch: &mut Client,
    within_s: f64,
    what: &str,
    mut done: impl FnMut(&FlightTelemetry) -> bool,
) -> FlightTelemetry {
    let started = Instant::now();
    loop {
        let flight = flight(watch);
        if done(&flight) {
            return flight;
        }
        assert!(started.elapsed().as_secs_f64() < within_s, "not {what} after {within_s} s");
        watch.listen(Duration::from_millis(50)).unwrap();
    }
}

fn unsigned_refused_over(radio: &str, keys: &Path) -> u64 {
    let security = cli(keys, &["--port", radio, "--json", "security"]);
    let security: Value = serde_json::from_slice(&security.stdout).unwrap();
    security["refused"]["unsigned"].as_u64().unwrap()
}

/// The landing events the watching link received since it last looked.
fn landing_events(watch: &mut Client) -> Vec<Event> {
    watch.listen(Duration::from_millis(100)).unwrap();
    watch
        .events
        .drain(..)
        .filter(|e| matches!(e, Event::Landing { .. } | Event::Landed { .. }))
        .collect()
}

/// Over the radio, a stranger's (unsigned) `disarm` lands a flying craft: it descends, touches
/// down slowly and disarms, and the refusal is counted; the paired configurator's (signed)
/// `disarm` stops a flying craft at once.
#[test]
fn over_the_radio_an_unsigned_disarm_lands_a_flying_craft_and_a_signed_one_stops_it() {
    let (sitl, usb, radio, mut watch) = start_sitl(51, true);
    let (ours, stranger) = (keys_dir("ours"), keys_dir("stranger"));
    cli(&ours, &["--port", &usb, "pair"]);

    cli(&ours, &["--port", &radio, "arm-throw-to-fly"]);
    wait_for(&mut watch, FLYING_WITHIN_S, "flying", flying);
    let refused_before = unsigned_refused_over(&radio, &stranger);
    landing_events(&mut watch);
    let disarmed = cli(&stranger, &["--port", &radio, "disarm"]);
    eprintln!("{}", String::from_utf8_lossy(&disarmed.stdout));
    let landing = FlightMode::Landing(LandReason::UnsignedDisarm);
    wait_for(&mut watch, 1.0, "landing", |f| f.mode == landing);
    // It comes down, slowly, still armed, until the touchdown disarms it.
    let started = Instant::now();
    let mut fastest_descent_mps = 0.0_f32;
    let on_the_ground = wait_for(&mut watch, LANDED_WITHIN_S, "landed", |f| {
        let descent_mps = f.velocity_ned_mps.map_or(0.0, |v| v[2]);
        fastest_descent_mps = fastest_descent_mps.max(descent_mps);
        f.mode != landing
    });
    let landing_s = started.elapsed().as_secs_f64();
    assert_eq!(on_the_ground.mode, FlightMode::Off);
    assert!(!armed(&mut watch));
    eprintln!("landed in {landing_s:.1} s, descending at most {fastest_descent_mps:.2} m/s");
    assert!(landing_s > 1.0, "a fall, not a landing: {landing_s:.2} s");
    assert!((0.2..1.0).contains(&fastest_descent_mps), "{fastest_descent_mps} m/s");
    let events = landing_events(&mut watch);
    assert!(
        events.iter().any(|e| matches!(e,
            Event::Landed { reason: LandReason::UnsignedDisarm, touchdown_speed_mps, .. }
                if f64::from(*touchdown_speed_mps) < MAX_TOUCHDOWN_SPEED_MPS)),
        "{events:?}"
    );
    assert_eq!(unsigned_refused_over(&radio, &stranger), refused_before + 1);

    // The hand picks the craft up again; the paired configurator's disarm stops it at once.
    std::thread::sleep(Duration::from_millis(500));
    cli(&ours, &["--port", &radio, "arm-throw-to-fly"]);
    wait_for(&mut watch, FLYING_WITHIN_S, "flying again", flying);
    cli(&ours, &["--port", &radio, "disarm"]);
    assert_eq!(flight(&mut watch).mode, FlightMode::Off, "stopped at once, no landing");
    assert!(!armed(&mut watch));
    assert_eq!(landing_events(&mut watch), []);
    drop(sitl);
    let _ = std::fs::remove_dir_all(&ours);
    let _ = std::fs::remove_dir_all(&stranger);
}

/// On the ground a stranger's `disarm` over the radio stops the craft at once, armed (waiting
/// for a throw that never comes: no hand here) or not, and is not counted as a refusal.
#[test]
fn over_the_radio_an_unsigned_disarm_stops_a_craft_on_the_ground_at_once() {
    let (sitl, usb, radio, mut watch) = start_sitl(52, false);
    let stranger = keys_dir("ground");
    cli(&stranger, &["--port", &radio, "disarm"]);
    assert!(!armed(&mut watch));
    cli(&stranger, &["--port", &usb, "arm-throw-to-fly"]);
    assert!(armed(&mut watch));
    cli(&stranger, &["--port", &radio, "disarm"]);
    assert!(!armed(&mut watch), "stopped at once");
    assert_eq!(flight(&mut watch).mode, FlightMode::Off);
    assert_eq!(landing_events(&mut watch), []);
    assert_eq!(unsigned_refused_over(&radio, &stranger), 0);
    drop(sitl);
    let _ = std::fs::remove_dir_all(&stranger);
}

/// `land` over the SITL's own link: on a craft at rest it says nothing was flying; on a flying
/// one it follows the descent and ends with the board disarmed and the touchdown below
/// 0.7 m/s. A bad timeout is bad input (exit code 2) and sends nothing.
#[test]
fn land_puts_a_flying_craft_down_slowly_and_reports_the_touchdown() {
    let bad = tests::run_cli(&["--sitl", "land", "--timeout-s", "0"]);
    assert_eq!(bad.status.code(), Some(2), "{}", String::from_utf8_lossy(&bad.stderr));
    let (sitl, usb, _radio, mut watch) = start_sitl(53, true);
    let keys = keys_dir("land");
    let idle = cli(&keys, &["--port", &usb, "--json", "land"]);
    let idle: Value = serde_json::from_slice(&idle.stdout).unwrap();
    assert_eq!((&idle["was_flying"], &idle["landed"]), (&Value::from(false), &Value::from(false)));

    cli(&keys, &["--port", &usb, "arm-throw-to-fly"]);
    wait_for(&mut watch, FLYING_WITHIN_S, "flying", flying);
    let land = cli(&keys, &["--port", &usb, "--json", "land", "--timeout-s", "60"]);
    let progress = String::from_utf8_lossy(&land.stderr);
    let report: Value = serde_json::from_slice(&land.stdout).unwrap();
    eprintln!("{progress}{report:#}");
    assert_eq!(report["reason"], "Commanded", "{report}");
    assert_eq!(report["landed"], true, "{report}");
    let touchdown_mps = report["touchdown_speed_mps"].as_f64().unwrap();
    assert!((0.0..MAX_TOUCHDOWN_SPEED_MPS).contains(&touchdown_mps), "{report}");
    assert!(report["descended_m"].as_f64().unwrap() > 0.5, "{report}");
    assert!(progress.contains("m below where the descent began, descending at"), "{progress}");
    assert!(progress.contains("LANDED: touched down at"), "{progress}");
    assert!(!armed(&mut watch));
    assert_eq!(flight(&mut watch).mode, FlightMode::Off);
    drop(sitl);
    let _ = std::fs::remove_dir_all(&keys);
}
