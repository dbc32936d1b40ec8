//! Every flight log from start-up replays exactly (issue 54): whatever the airframe, whatever
//! arms the craft (at start-up, `identify` over TCP, the pilot's switches), with or without
//! motion capture, on a loaded machine, and whenever the background task runs relative to the
//! control step (as on the board, where it runs when the higher-priority tasks leave it time).
//! And a SITL killed without warning in flight leaves a log that lists, converts and replays up
//! to its last whole block, holding the flight to within 1 s of the cut.
//!
//! The arming at start-up (paper quad, no motion capture, idle machine) is `flight_log.rs`.
//! Each flight here is at least 10,000 steps (5 s at 2 kHz).
//!
//! `cargo test -p tests --test replay_exact -- --nocapture` prints the replays' reports.

use configurator_cli::offline::replay::{parse_log, replay};
use firmware::app::hal::{NoBattery, NoBytes};
use firmware::app::log::{LogReader, LogRecord};
use firmware::app::system::{with_logged_system, LogTarget, NoLinks, TickHardware};
use firmware::app::{ControlCommand, NoFlash, Settings};
use sim::sitl::{Sitl, SitlConfig};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tests::{run_cli, sitl_binary};

/// Steps a replay must cover: 5 s at 2 kHz.
const MIN_STEPS: usize = 10_000;

/// Largest gap allowed between the cut and the last step a killed SITL's log holds, s (the
/// issue's bound).
const MAX_LOG_LAG_AT_CUT_S: f64 = 1.0;

/// The tests here run one at a time: one of them keeps both cores busy on purpose, and the
/// others' SITLs should not share the machine with it (nor their time with each other).
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("replay-exact-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn records(file: &Path) -> Vec<LogRecord> {
    let bytes = std::fs::read(file).unwrap_or_default();
    LogReader::new(&bytes).collect()
}

fn steps_in(records: &[LogRecord]) -> usize {
    records.iter().filter(|r| matches!(r, LogRecord::Step(_))).count()
}

/// Wait until the log holds `steps` steps (its complete blocks), the SITL still running.
fn wait_for_steps(sitl: &Sitl, file: &Path, steps: usize) {
    let started = Instant::now();
    while steps_in(&records(file)) < steps {
        assert!(started.elapsed() < Duration::from_secs(300), "no {steps} steps within 5 min");
        assert!(sitl.is_running(), "the SITL stopped");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Run a SITL with `config` (logging into its `log_dir`) until its first log holds
/// [`MIN_STEPS`] and a margin, then stop it; the log's path.
fn fly_logged(config: &SitlConfig) -> PathBuf {
    let dir = config.log_dir.clone().expect("a log directory");
    let sitl = Sitl::start(config).expect("the SITL starts");
    let file = dir.join("LOG00001.BIN");
    wait_for_steps(&sitl, &file, MIN_STEPS + 2_000);
    drop(sitl);
    file
}

/// `configurator-cli replay FILE --json`.
fn replay_cli(file: &Path) -> serde_json::Value {
    let output = run_cli(&["replay", file.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "replay failed: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("replay --json prints JSON")
}

/// The log replays over at least [`MIN_STEPS`] steps with no difference, the craft flew on its
/// learned model, and the control step adopted the background's results many times (the
/// handoff this is about was exercised). `from_start_up`: the file runs from start-up
/// (`log_always`), else it begins at the arming and carries the control loop's state there.
fn assert_exact_flight(file: &Path, from_start_up: bool) {
    let report = replay_cli(file);
    eprintln!("{}: {report}", file.display());
    assert_eq!(report["from_start_up"], from_start_up, "{report}");
    if !from_start_up {
        let records = records(file);
        let state = records.iter().filter(|r| matches!(r, LogRecord::State(_))).count();
        assert!(state > 10, "the file begins with the control loop's state ({state} chunks)");
    }
    assert!(report["steps"].as_u64().unwrap() >= MIN_STEPS as u64, "{report}");
    assert_eq!(report["differences"], 0, "{report}");
    assert_eq!(report["notes"], serde_json::json!([]), "{report}");
    let records = records(file);
    let adoptions = records.iter().filter(|r| matches!(r, LogRecord::Adopted(_))).count();
    assert!(adoptions > 100, "{adoptions} adoptions: the learner's versions were handed over");
    let flew = records.iter().any(|r| match r {
        LogRecord::Step(s) => s.flags & firmware::app::log::flags::FLYING != 0,
        _ => false,
    });
    assert!(flew, "the craft flew on its learned model");
}

/// A tilted hexarotor armed by `identify` over TCP, logged from start-up or from the arming.
fn armed_by_identify_over_tcp(log_always: bool) {
    let _alone = one_at_a_time();
    let dir = scratch_dir(if log_always { "identify-always" } else { "identify-arming" });
    let config = SitlConfig {
        airframe: "hex-tilted".into(),
        pty: false,
        tcp_port: Some(0),
        speed: 5.0,
        hand_throws_to_fly: true,
        log_dir: Some(dir.clone()),
        log_always,
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let tcp = sitl.tcp_addr.unwrap().to_string();
    // The board sits on the bench first, so its filters have a past when the arming comes.
    let status = run_cli(&["status", "--tcp", &tcp]);
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    std::thread::sleep(Duration::from_millis(500));
    // Returns once the craft flies on the learned model (the model stored in the parameters:
    // a parameter change handed to both tasks in flight).
    let identified = run_cli(&["identify", "--tcp", &tcp, "--yes", "--json"]);
    assert!(identified.status.success(), "{}", String::from_utf8_lossy(&identified.stderr));
    let file = dir.join("LOG00001.BIN");
    wait_for_steps(&sitl, &file, MIN_STEPS + 2_000);
    drop(sitl);
    assert_exact_flight(&file, log_always);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_tilted_hexarotor_armed_by_identify_over_tcp_replays_exactly_from_start_up() {
    armed_by_identify_over_tcp(true);
}

/// The default file (`log_always` = 0) begins at the arming: it carries the control loop's
/// state there, and replays as exactly as a file from start-up.
#[test]
fn a_tilted_hexarotor_armed_by_identify_over_tcp_replays_exactly_from_its_arming() {
    armed_by_identify_over_tcp(false);
}

/// A throw-to-fly on a 10 Hz GNSS receiver, with `compass` on the mast if any, logged from
/// start-up into the scratch directory `name`: the log file, and how many of its commands
/// `logged` picks.
fn fly_on_gnss(
    name: &str,
    compass: Option<sim::magnetometer::MagnetometerSpec>,
    logged: fn(&firmware::app::log::LoggedCommand) -> bool,
) -> (PathBuf, PathBuf, usize) {
    let dir = scratch_dir(name);
    let config = SitlConfig {
        pty: false,
        speed: 5.0,
        throw_to_fly: true,
        hand_throws_to_fly: true,
        gnss: Some(sim::gnss::GnssModelConfig { rate_hz: 10.0, ..Default::default() }),
        compass,
        log_dir: Some(dir.clone()),
        log_always: true,
        ..SitlConfig::default()
    };
    let file = fly_logged(&config);
    let count = records(&file)
        .iter()
        .filter(|r| matches!(r, LogRecord::Command(c) if logged(&c.command)))
        .count();
    (dir, file, count)
}

/// A flight on a GNSS receiver instead of motion capture (log format 5): its fixes are logged as
/// commands with their accuracies, so the replay needs no receiver and is exact.
#[test]
fn a_flight_on_gnss_fixes_replays_exactly_without_a_receiver() {
    let _alone = one_at_a_time();
    let (dir, file, fixes) = fly_on_gnss("gnss", None, |c| {
        matches!(c, firmware::app::log::LoggedCommand::PositionFix(_))
    });
    // 10 Hz over at least 6 s of the run.
    assert!(fixes >= 50, "{fixes} GNSS fixes logged");
    assert_exact_flight(&file, true);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A flight on GNSS fixes with a compass on the mast (log format 7): the compass's calibrated
/// fields are logged as commands, the pilot's compass state (the motors-off reference, the
/// heading it last trusted) with the rest, and the replay is exact without the sensor.
#[test]
fn a_flight_on_gnss_with_a_compass_replays_exactly_without_the_sensors() {
    let _alone = one_at_a_time();
    let compass = sim::world::random_world_case(3, &[sim::world::Aspect::Compass]).1.compass;
    assert!(compass.is_some(), "no compass drawn");
    let (dir, file, fields) = fly_on_gnss("compass", compass, |c| {
        matches!(c, firmware::app::log::LoggedCommand::MagneticField(_))
    });
    // 100 Hz over at least 6 s of the run.
    assert!(fields >= 500, "{fields} compass fields logged");
    assert_exact_flight(&file, true);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_octorotor_armed_by_the_pilots_switches_with_motion_capture_on_a_loaded_machine_replays_exactly_from_its_arming(
) {
    let _alone = one_at_a_time();
    let dir = scratch_dir("switches");
    // Another process's worth of work on both cores for the whole flight.
    let busy = Arc::new(AtomicBool::new(true));
    let burners: Vec<_> = (0..2)
        .map(|_| {
            let busy = busy.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while busy.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect();
    let config = SitlConfig {
        airframe: "octo-flat".into(),
        pty: false,
        speed: 5.0,
        hand_throws_to_fly: true,
        mocap: true,
        rc_script: Some(sim::radio::RcScript::parse("0.5:arm,0.5:throw").unwrap()),
        log_dir: Some(dir.clone()),
        log_always: false,
        ..SitlConfig::default()
    };
    let file = fly_logged(&config);
    busy.store(false, Ordering::Relaxed);
    for burner in burners {
        burner.join().unwrap();
    }
    let commands: Vec<_> = records(&file)
        .into_iter()
        .filter_map(|r| match r {
            LogRecord::Command(c) => Some(c.command),
            _ => None,
        })
        .collect();
    assert!(
        commands.contains(&firmware::app::log::LoggedCommand::ArmThrowToFly),
        "the switches armed the craft"
    );
    assert!(
        commands.iter().any(|c| matches!(c, firmware::app::log::LoggedCommand::ExternalPose(_))),
        "motion capture fed the flight"
    );
    assert_exact_flight(&file, config.log_always);
    let _ = std::fs::remove_dir_all(&dir);
}

/// What the simulated bench does at a moment of [`fly_with_a_lagging_background`]'s run.
#[derive(Clone, Copy, Debug)]
enum Bench {
    /// `arm-throw-to-fly` from a link.
    Arm,
    /// The hand throws the craft (the paper's throw), not catching it.
    Throw,
    /// A hand grips the flying craft where it is, and the link disarms it.
    GripAndDisarm,
}

/// A tilted hexarotor's application in process, the bench acting at the given times (s), its
/// background task lagging the control step 0 to 25 steps at random (as on the board, where it
/// runs when the higher-priority tasks leave it time; its queue holds 63 samples) and the link
/// pass's work waiting for it; the in-flight IMU-offset fit's task (the board's `idle`: no
/// offset is known) runs after a background run at random, three times in ten, or when the
/// background task waits for it. Logs into `dir`; returns the background's lags, in steps, and
/// how often it waited for the fit.
fn fly_with_a_lagging_background(
    dir: &Path,
    log_always: bool,
    bench: &[(f64, Bench)],
    ticks: u32,
) -> (Vec<u32>, u32) {
    let airframe = sim::airframe::Airframe::load("hex-tilted").unwrap();
    let mut board = sim::board::SimBoard::new(&airframe, &sim::board::SimConfig::default());
    let mut sink = sim::log_dir::LogDir::create(dir).unwrap();
    let mut settings = Settings::<NoFlash>::without_store();
    settings.update(|params| {
        let index = firmware::app::params::find(b"log_always").unwrap();
        params.set(index, &[f32::from(u8::from(log_always))]).unwrap();
    });
    let mut rng = flight::rng::Rng::new(54);
    let mut lags = Vec::new();
    let mut waited_for_fit = 0;
    let mut due = bench.iter().peekable();
    let log = Some(LogTarget { sink: &mut sink, board: "SITL" });
    let health = sim::board::SIM_BOARD_HEALTH;
    with_logged_system(settings, health, None, log, |system| {
        let mut wait = 0u32;
        for tick in 1..=ticks {
            while let Some((_, action)) = due.next_if(|(at_s, _)| board.time_s() >= *at_s) {
                let physics = board.physics_mut();
                match action {
                    Bench::Arm => assert!(system.submit(ControlCommand::ArmThrowToFly)),
                    Bench::Throw => {
                        physics.set_catch(None);
                        physics.throw(&sim::identification::Throw::paper().spec());
                    }
                    Bench::GripAndDisarm => {
                        physics.grip();
                        assert!(system.submit(ControlCommand::Disarm));
                    }
                }
            }
            board.tick();
            let now_us = board.now_us();
            let (imu, motors) = board.ports();
            let hardware =
                TickHardware { imu, motors, radio_bytes: &mut NoBytes, battery: &mut NoBattery };
            let outcome = system.tick_alone(now_us, hardware);
            if outcome.link_due {
                // The link pass: its work waits in the queue for the background task.
                system.pass_alone(now_us, &mut NoLinks);
            }
            if wait == 0 {
                let mut fit_now = rng.uniform() < 0.3;
                loop {
                    system.run_background_alone();
                    let waits = system.background.waits_for_offset_fit();
                    if !(fit_now || waits) || system.offset_fit.run_pending() == 0 {
                        break;
                    }
                    waited_for_fit += u32::from(waits);
                    fit_now = false;
                }
                wait = (rng.uniform() * 26.0) as u32;
                lags.push(wait);
            } else {
                wait -= 1;
            }
            assert_eq!(system.snapshot().samples_dropped, 0, "tick {tick}: the queue held");
        }
        system.run_background();
        system.finish_log();
    });
    (lags, waited_for_fit)
}

/// The board's background task runs when the higher-priority tasks leave it time: its results
/// reach the control step some steps after the samples they were computed from, a different
/// number each time, and a parameter change reaches it between other samples than the SITL's
/// would. Here it lags 0 to 25 steps at random, and the log replays exactly; the same log read
/// as a format 3 replay (the background run after every step, as before the adoptions were
/// logged) departs.
#[test]
fn a_background_task_lagging_the_control_step_at_random_replays_exactly() {
    let _alone = one_at_a_time();
    let dir = scratch_dir("lagging");
    let bench = [(0.0, Bench::Arm), (1.0, Bench::Throw)];
    let (lags, waited_for_fit) =
        fly_with_a_lagging_background(&dir, true, &bench, MIN_STEPS as u32 + 1_000);
    assert!(waited_for_fit > 0, "the in-flight fit was never late");
    let mean_lag = lags.iter().sum::<u32>() as f64 / lags.len() as f64;
    assert!((10.0..15.0).contains(&mean_lag), "the background ran every {mean_lag} steps");
    let bytes = std::fs::read(dir.join("LOG00001.BIN")).unwrap();
    let log = parse_log(&bytes).unwrap();
    let records = &log.records;
    // The control step adopted the background's results when it had run, a varying number of
    // steps apart (the SITL's adopts at every step while the learner learns).
    let adopted_at: Vec<u32> = records
        .iter()
        .filter_map(|r| match r {
            LogRecord::Adopted(a) => Some(a.step),
            _ => None,
        })
        .collect();
    let gaps: std::collections::BTreeSet<u32> =
        adopted_at.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(gaps.len() > 10, "adoptions {gaps:?} steps apart");
    let works: Vec<_> = records
        .iter()
        .filter_map(|r| match r {
            LogRecord::Work(w) => Some(*w),
            _ => None,
        })
        .collect();
    assert!(works.len() >= 2, "the start-up parameters and the stored model: {works:?}");

    let exact = replay(&log, &[], |_, _| {});
    eprintln!(
        "lagging background: {} steps, {} differences, notes {:?}",
        exact.steps, exact.differences, exact.notes
    );
    assert!(exact.steps >= MIN_STEPS as u64);
    assert_eq!((exact.differences, exact.notes.len()), (0, 0), "{:?}", exact.first_difference);
    assert!(exact.replayed_phases.iter().any(|(p, _)| *p == flight::learner::FlightPhase::Done));

    let mut as_format_3 = log.clone();
    as_format_3.header.format = 3;
    let before = replay(&as_format_3, &[], |_, _| {});
    eprintln!("the same log replayed as format 3: {} differences", before.differences);
    assert!(before.differences > 100, "the handoffs' steps mattered: {}", before.differences);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The default files (`log_always` = 0), one per arming: the second flight of a power cycle
/// begins its file with the control loop's state at its arming (the attitude filter, the
/// navigation, the first flight's model) and the learner sample count there, and replays
/// exactly, its background task lagging at random as above. Without that state (the records
/// dropped, as a firmware before format 6 wrote it) the same file departs.
#[test]
fn a_second_flight_logged_from_its_arming_replays_exactly() {
    let _alone = one_at_a_time();
    let dir = scratch_dir("second-flight");
    let bench = [
        (0.5, Bench::Arm),
        (1.5, Bench::Throw),
        (8.0, Bench::GripAndDisarm),
        (12.0, Bench::Arm),
        (13.0, Bench::Throw),
    ];
    fly_with_a_lagging_background(&dir, false, &bench, 2 * 12_000 + MIN_STEPS as u32);
    let first = parse_log(&std::fs::read(dir.join("LOG00001.BIN")).unwrap()).unwrap();
    let bytes =
        std::fs::read(dir.join("LOG00002.BIN")).expect("a second file for the second arming");
    let second = parse_log(&bytes).unwrap();
    assert!(
        second.header.first_step > 20_000,
        "it begins at the second arming: {:?}",
        second.header
    );
    for log in [&first, &second] {
        let exact = replay(log, &[], |_, _| {});
        eprintln!(
            "file from step {}: {} steps, {} differences, notes {:?}",
            log.header.first_step, exact.steps, exact.differences, exact.notes
        );
        assert!(exact.steps >= MIN_STEPS as u64);
        assert_eq!((exact.differences, exact.notes.len()), (0, 0), "{:?}", exact.first_difference);
        assert!(exact
            .replayed_phases
            .iter()
            .any(|(p, _)| *p == flight::learner::FlightPhase::Done));
    }
    let mut stateless = second.clone();
    stateless.records.retain(|r| !matches!(r, LogRecord::Arming(_) | LogRecord::State(_)));
    let fresh = replay(&stateless, &[], |_, _| {});
    eprintln!("the second file without the state: {} differences", fresh.differences);
    assert!(fresh.differences > 100, "the state mattered: {}", fresh.differences);
    assert!(!fresh.notes.is_empty(), "and the replay says it starts from a fresh application");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The last step a log's complete blocks hold, and its time, µs.
fn last_step(records: &[LogRecord]) -> Option<(u32, u64)> {
    records.iter().rev().find_map(|r| match r {
        LogRecord::Step(s) => Some((s.step, s.t_us)),
        _ => None,
    })
}

/// Ten SITLs (the binary, as a board would run) lose their power at random moments of their
/// flight (`--power-cut-at-s`: the process sends itself SIGKILL, so the cut's simulated time is
/// known exactly, however loaded the machine): no end record, a block cut where the kill fell;
/// every log lists on a SITL serving the directory again, converts to CSV, replays with no
/// difference over what it holds, and holds the flight to within [`MAX_LOG_LAG_AT_CUT_S`] of
/// the cut.
#[test]
fn ten_sitls_killed_in_flight_leave_logs_that_list_convert_and_replay_exactly() {
    let _alone = one_at_a_time();
    use std::os::unix::process::ExitStatusExt;
    const KILLS: usize = 10;
    let root = scratch_dir("killed");
    let mut rng = flight::rng::Rng::new(0x54);
    let mut flights = Vec::new();
    for k in 0..KILLS {
        let dir = root.join(format!("run{k}"));
        std::fs::create_dir_all(&dir).unwrap();
        // Armed at start-up; the hand throws at 1 s, the learned model flies from about 2.1 s.
        let cut_s = 2.5 + 3.5 * rng.uniform();
        let airframe = ["paper-quad", "hex-tilted", "octo-flat"][k % 3];
        let mut command = std::process::Command::new(sitl_binary());
        command.args(["--airframe", airframe, "--no-pty", "--no-flash", "--throw-to-fly"]);
        command.args(["--hand-throws-to-fly", "--log-always", "--speed", "4"]);
        command.args(["--power-cut-at-s", &cut_s.to_string()]);
        // Stops by itself should the cut never come.
        command.args(["--duration-s", "60"]).arg("--log-dir").arg(&dir);
        if k % 2 == 1 {
            command.arg("--mocap");
        }
        command.stdout(std::process::Stdio::null()).stderr(std::process::Stdio::null());
        let child = command.spawn().expect("start the sitl binary");
        flights.push((dir, cut_s, child));
    }
    let flights: Vec<_> = flights
        .into_iter()
        .enumerate()
        .map(|(k, (dir, cut_s, mut child))| {
            let status = child.wait().unwrap();
            assert_eq!(status.signal(), Some(libc::SIGKILL), "run {k}: {status:?}");
            (dir, cut_s)
        })
        .collect();
    for (k, (dir, cut_s)) in flights.iter().enumerate() {
        let file = dir.join("LOG00001.BIN");
        let held = records(&file);
        assert!(
            !held.iter().any(|r| matches!(r, LogRecord::End(_))),
            "run {k}: killed, not closed"
        );
        let (step, t_us) = last_step(&held).expect("steps logged");
        let last_s = t_us as f64 * 1e-6;
        eprintln!(
            "run {k}: cut at {cut_s:.4} s, last step {step} at {last_s:.4} s ({:.1} ms before), \
             {} bytes",
            (*cut_s - last_s) * 1e3,
            std::fs::metadata(&file).unwrap().len()
        );
        assert!(last_s < *cut_s, "run {k}: a step after the cut");
        assert!(
            *cut_s - last_s <= MAX_LOG_LAG_AT_CUT_S,
            "run {k}: the log ends at {last_s} s, the cut was at {cut_s} s"
        );
        let report = replay_cli(&file);
        assert_eq!(report["differences"], 0, "run {k}: {report}");
        assert_eq!(report["steps"].as_u64(), Some(u64::from(step)), "run {k}: every step held");
        let csv = dir.join("flight.csv");
        let output = run_cli(&["log", "to-csv", file.to_str().unwrap(), csv.to_str().unwrap()]);
        assert!(output.status.success(), "run {k}: {}", String::from_utf8_lossy(&output.stderr));
        let rows = std::fs::read_to_string(&csv).unwrap().lines().count() - 1;
        assert!(rows + 10 >= step as usize, "run {k}: {rows} rows for {step} steps");
    }
    // Listed over the link by a SITL serving the directories again (one at a time).
    for (k, (dir, ..)) in flights.iter().enumerate() {
        let config = SitlConfig {
            pty: false,
            tcp_port: Some(0),
            log_dir: Some(dir.clone()),
            ..SitlConfig::default()
        };
        let sitl = Sitl::start(&config).unwrap();
        let tcp = sitl.tcp_addr.unwrap().to_string();
        let output = run_cli(&["log", "list", "--tcp", &tcp, "--json"]);
        drop(sitl);
        assert!(output.status.success(), "run {k}: {}", String::from_utf8_lossy(&output.stderr));
        let size = std::fs::metadata(dir.join("LOG00001.BIN")).unwrap().len();
        let listed = String::from_utf8_lossy(&output.stdout);
        assert!(listed.contains(&size.to_string()), "run {k}: {size} bytes not in {listed}");
    }
    let _ = std::fs::remove_dir_all(&root);
}
