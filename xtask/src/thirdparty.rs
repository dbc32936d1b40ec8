//! `cargo xtask thirdparty`: the firmware flown in a multirotor simulator we did not write.
//!
//! RotorPy (a published Python simulator, pinned in `sim/thirdparty/requirements.txt`) supplies
//! the rigid body and rotor model; our client `sim/thirdparty/rotorpy_bridge.py` adds the hand,
//! the IMU mount, the ESCs and motion capture, and speaks the lockstep bridge
//! (docs/sim-bridge.md) to the firmware application served by `scenario bridge --throw-to-fly`.
//! Per airframe this command starts its own bridge on a free port (given the airframe's IMU
//! offset, as a calibrated board knows it), runs one throw-and-fly, prints the client's JSON
//! summary and a table, and fails unless every flight recovered to a hover and held within
//! 0.3 m. `--no-speed-telemetry` flies ESCs without bidirectional DShot: the client sends NaN
//! for every rotor speed and the bridge identifies the motors from the commands (issue 32).
//! `--unknown-imu-offset` gives the bridge no offset: one throw with no calibration, the offset
//! fitted in flight where the throw determines it (issue 32). `--gnss` flies outdoors: the client
//! sends a simulated u-blox receiver's solutions instead of motion capture's poses (0.3 m, 10 Hz,
//! 100 ms late, the bridge told the latency) and the hold's bound is 1 m; `--wind-ned-mps`
//! blows a steady wind through RotorPy's drag model (issue 55).
//!
//! The client runs in a virtualenv under `target/thirdparty-venv`, created on demand with the
//! pinned requirements (reinstalled when `requirements.txt` changes), so the system Python is
//! never touched. Needs `python3` with its `venv` module, and PyPI.

use crate::util;
use anyhow::{bail, Context, Result};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Instant;

/// Airframes `cargo xtask test` flies: the first two of the client's list, RotorPy's Hummingbird
/// as shipped and rebuilt asymmetric (CoG off the rotors' centre, spins reversed, another IMU
/// pose and motor order). Both have 5 ms motors; the slower airframes after them need more
/// height than the default throw from 1.5 m gives (`--airframes 5 -- --start-height-m 20`).
pub const TEST_AIRFRAMES: usize = 2;
/// The airframe `cargo xtask test` also flies without speed telemetry (issue 32's commands-only
/// identification in a simulator we did not write).
pub const TEST_NO_SPEED_AIRFRAME: &str = "hummingbird";
/// The airframe `cargo xtask test` also flies with no IMU offset given (issue 32's one throw with
/// no calibration).
pub const TEST_UNKNOWN_OFFSET_AIRFRAME: &str = "hummingbird-asymmetric";
/// The airframe `cargo xtask test` also flies outdoors: a GNSS receiver and no motion capture,
/// in [`TEST_WIND_NED_MPS`] (issue 55: recover and hold within 1 m in a 4 m/s wind).
pub const TEST_GNSS_AIRFRAME: &str = "hummingbird";
/// Its wind, m/s, north-east-down: 4 m/s blowing towards the east.
pub const TEST_WIND_NED_MPS: &str = "0,4,0";
/// The receiver's latency the client simulates and the bridge is told, ms (u-blox M8–M10: 50–150
/// ms; the firmware's default).
const GNSS_LATENCY_MS: &str = "100";
/// Largest wind `--wind-ned-mps` takes on each axis, m/s.
const MAX_WIND_MPS: f64 = 20.0;
/// How long a bridge waits for a packet before it stops by itself, s: outlives a client that
/// died without our noticing, far longer than any gap between a client's packets.
const BRIDGE_IDLE_TIMEOUT_S: &str = "30";

const USAGE: &str = "\
usage: cargo xtask thirdparty [--airframes N | --airframe NAME]... [--taper-ms MS]
                              [--taper-shape cosine|linear] [--jobs J] [--list] [--dev-bridge]
                              [--no-speed-telemetry] [--unknown-imu-offset] [--gnss]
                              [--wind-ned-mps N,E,D] [-- CLIENT-ARGS...]
       cargo xtask thirdparty --test

Flies the firmware (scenario bridge --throw-to-fly) in RotorPy, one throw-and-fly per airframe,
and fails unless each recovers to a hover and holds within 0.3 m (1 m with --gnss).

  --airframes N      the first N airframes of the client's list (default 2)
  --airframe NAME    this airframe (repeatable; see --list)
  --taper-ms MS      taper of the hand's push at release, ms, 0-50 (default 15, as a real hand;
                     0: a one-step release)
  --taper-shape S    cosine (default) or linear
  --jobs J           flights run at once, 1-8 (default 2)
  --list             list the airframes and stop
  --dev-bridge       build and run `scenario` with the dev profile instead of --release
  --no-speed-telemetry  ESCs without bidirectional DShot: the client sends NaN speeds and the
                     bridge identifies the motors from the commands
  --unknown-imu-offset  no IMU offset for the bridge (no calibration): fitted in flight where
                     the throw determines it
  --gnss             outdoors: a GNSS receiver's solutions (0.3 m, 10 Hz, 100 ms late) instead
                     of motion capture's poses
  --wind-ned-mps V   a steady wind, m/s, north,east,down (each within ±20; default none)
  -- ARGS            passed to `rotorpy_bridge.py fly` (e.g. -- --trace --spin-dps 450)
  --test             the check `cargo xtask test` runs: the first two airframes with a real
                     hand's release, then hummingbird without speed telemetry,
                     hummingbird-asymmetric with no IMU offset given, and hummingbird on a GNSS
                     receiver in a 4 m/s wind
";

/// What to fly.
#[derive(Debug, Clone, PartialEq)]
struct Options {
    airframes: Selection,
    taper_ms: f64,
    taper_shape: String,
    jobs: usize,
    list: bool,
    /// Build and run the bridge with cargo's release profile (else the dev profile).
    release_bridge: bool,
    /// The ESCs report no speed: NaN from the client, `--no-speed-telemetry` to the bridge.
    no_speed_telemetry: bool,
    /// Give the bridge no IMU offset (no `--imu-offset-mm`).
    unknown_imu_offset: bool,
    /// A GNSS receiver instead of motion capture (`--gnss` to the client, the latency to both).
    gnss: bool,
    /// A steady wind for the client, m/s, north-east-down, as given (checked).
    wind_ned_mps: Option<String>,
    client_args: Vec<String>,
    /// The dev-profile `scenario` is already built, by `cargo test --workspace --no-run` with
    /// the test build's features (`cargo xtask test`): building it again with `cargo build -p
    /// sim`, whose feature resolution is its own, compiled every dependency a second time. Not
    /// a command-line option.
    bridge_built: bool,
}

#[derive(Debug, Clone, PartialEq)]
enum Selection {
    First(usize),
    Named(Vec<String>),
}

impl Options {
    fn parse(args: &[String]) -> Result<Self> {
        let mut options = Options {
            airframes: Selection::First(TEST_AIRFRAMES),
            taper_ms: DEFAULT_TAPER_MS,
            taper_shape: "cosine".into(),
            jobs: 2,
            list: false,
            release_bridge: true,
            no_speed_telemetry: false,
            unknown_imu_offset: false,
            gnss: false,
            wind_ned_mps: None,
            client_args: Vec::new(),
            bridge_built: false,
        };
        let mut named = Vec::new();
        let mut iter = args.iter();
        while let Some(arg) = iter.next() {
            let mut value = |name: &str| {
                iter.next().cloned().with_context(|| format!("{name} needs a value\n\n{USAGE}"))
            };
            match arg.as_str() {
                "--airframes" => {
                    let text = value("--airframes")?;
                    let n =
                        text.parse::<usize>().ok().filter(|n| (1..=16).contains(n)).with_context(
                            || format!("--airframes must be 1 to 16 (got `{text}`)"),
                        )?;
                    options.airframes = Selection::First(n);
                }
                "--airframe" => named.push(value("--airframe")?),
                "--taper-ms" => {
                    let text = value("--taper-ms")?;
                    options.taper_ms = text
                        .parse::<f64>()
                        .ok()
                        .filter(|ms| ms.is_finite() && (0.0..=50.0).contains(ms))
                        .with_context(|| format!("--taper-ms must be 0 to 50 (got `{text}`)"))?;
                }
                "--taper-shape" => {
                    let shape = value("--taper-shape")?;
                    if shape != "cosine" && shape != "linear" {
                        bail!("--taper-shape must be cosine or linear (got `{shape}`)");
                    }
                    options.taper_shape = shape;
                }
                "--jobs" => {
                    let text = value("--jobs")?;
                    options.jobs = text
                        .parse::<usize>()
                        .ok()
                        .filter(|j| (1..=8).contains(j))
                        .with_context(|| format!("--jobs must be 1 to 8 (got `{text}`)"))?;
                }
                "--list" => options.list = true,
                "--dev-bridge" => options.release_bridge = false,
                "--no-speed-telemetry" => options.no_speed_telemetry = true,
                "--unknown-imu-offset" => options.unknown_imu_offset = true,
                "--gnss" => options.gnss = true,
                "--wind-ned-mps" => {
                    let text = value("--wind-ned-mps")?;
                    let parts: Vec<Option<f64>> =
                        text.split(',').map(|p| p.trim().parse::<f64>().ok()).collect();
                    let ok = parts.len() == 3
                        && parts.iter().all(|v| v.is_some_and(|v| v.abs() <= MAX_WIND_MPS));
                    if !ok {
                        bail!(
                            "--wind-ned-mps must be three speeds in m/s, north,east,down, each \
                             within ±{MAX_WIND_MPS} (got `{text}`)"
                        );
                    }
                    options.wind_ned_mps = Some(text);
                }
                "-h" | "--help" => {
                    print!("{USAGE}");
                    std::process::exit(0);
                }
                "--" => options.client_args = iter.by_ref().cloned().collect(),
                other => bail!("unknown argument `{other}`\n\n{USAGE}"),
            }
        }
        if !named.is_empty() {
            options.airframes = Selection::Named(named);
        }
        Ok(options)
    }
}

/// `cargo xtask thirdparty ARGS`; `--test` alone is [`test`].
pub fn thirdparty(args: &[String]) -> Result<()> {
    if args.iter().any(|arg| arg == "--test") {
        if args.len() > 1 {
            bail!("`--test` takes no other arguments (it is what `cargo xtask test` runs)");
        }
        return test(false);
    }
    run(&Options::parse(args)?)
}

/// The check `cargo xtask test` runs: the client's unit tests (packets byte for byte, frames,
/// ESC curve, IMU readings, the hand's release), then the first [`TEST_AIRFRAMES`] airframes
/// with a real hand's tapering release ([`DEFAULT_TAPER_MS`]), then [`TEST_NO_SPEED_AIRFRAME`]
/// without speed telemetry, [`TEST_UNKNOWN_OFFSET_AIRFRAME`] with no IMU offset given and
/// [`TEST_GNSS_AIRFRAME`] on a GNSS receiver in [`TEST_WIND_NED_MPS`] (the three at once), against the dev-profile bridge: `cargo test --workspace` has built
/// it already, while a release build of `sim` (fat LTO) costs minutes on two cores, and the
/// bridge's share of a flight is small either way (0.4 s of CPU for 15 s of flight, the same in
/// both profiles, against about 20 s for the Python client; the flights are identical).
/// `bridge_built`: `cargo xtask test` has just built the dev-profile bridge with the test build
/// (see `Options::bridge_built`); `cargo xtask thirdparty --test` builds it.
pub fn test(bridge_built: bool) -> Result<()> {
    let python = ensure_venv()?;
    util::run(
        Command::new(&python).args(["-m", "unittest", "test_thirdparty"]).current_dir(client_dir()),
    )
    .context("the RotorPy client's unit tests failed")?;
    let parse = |args: &[&str]| -> Result<Options> {
        let args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        Ok(Options { bridge_built, ..Options::parse(&args)? })
    };
    run(&parse(&["--dev-bridge"])?)?;
    // The first run has built the bridge if it was not.
    let parse =
        |args: &[&str]| -> Result<Options> { Ok(Options { bridge_built: true, ..parse(args)? }) };
    let no_speed =
        parse(&["--dev-bridge", "--airframe", TEST_NO_SPEED_AIRFRAME, "--no-speed-telemetry"])?;
    let unknown_offset = parse(&[
        "--dev-bridge",
        "--airframe",
        TEST_UNKNOWN_OFFSET_AIRFRAME,
        "--unknown-imu-offset",
    ])?;
    let gnss = parse(&[
        "--dev-bridge",
        "--airframe",
        TEST_GNSS_AIRFRAME,
        "--gnss",
        "--wind-ned-mps",
        TEST_WIND_NED_MPS,
    ])?;
    let results = std::thread::scope(|scope| {
        let flights = [&no_speed, &unknown_offset, &gnss].map(|o| scope.spawn(move || run(o)));
        flights.map(|flight| flight.join().expect("a flight thread panicked"))
    });
    results.into_iter().collect()
}

/// How long the simulated hand takes to let go, ms: a real hand's release (issue 28 measured
/// about 15 ms in an independent simulator's hand).
const DEFAULT_TAPER_MS: f64 = 15.0;

/// One airframe of the client's list.
#[derive(Debug, Clone)]
struct Airframe {
    name: String,
    /// `--imu-offset-mm` for the bridge: the IMU offset in IMU axes, mm.
    imu_offset_mm: [f64; 3],
}

fn run(options: &Options) -> Result<()> {
    let started = Instant::now();
    let python = ensure_venv()?;
    let client = client_dir().join("rotorpy_bridge.py");
    let listed = list_airframes(&python, &client)?;
    if options.list {
        for (index, a) in listed.iter().enumerate() {
            println!(
                "{:>2}. {:<24} IMU offset {:?} mm (IMU axes)",
                index + 1,
                a.name,
                a.imu_offset_mm
            );
        }
        return Ok(());
    }
    let chosen: Vec<Airframe> = match &options.airframes {
        Selection::First(n) => {
            if *n > listed.len() {
                bail!("--airframes {n}: the client has {} airframes", listed.len());
            }
            listed[..*n].to_vec()
        }
        Selection::Named(names) => names
            .iter()
            .map(|name| {
                listed.iter().find(|a| &a.name == name).cloned().with_context(|| {
                    let known: Vec<&str> = listed.iter().map(|a| a.name.as_str()).collect();
                    format!("no airframe `{name}` (known: {})", known.join(", "))
                })
            })
            .collect::<Result<_>>()?,
    };
    let profile_dir = if options.release_bridge { "release" } else { "debug" };
    let scenario = util::root().join("target").join(profile_dir).join("scenario");
    let built = options.bridge_built && !options.release_bridge && scenario.is_file();
    if !built {
        let mut build = util::cargo();
        build.args(["build", "-p", "sim", "--bin", "scenario"]);
        if options.release_bridge {
            build.arg("--release");
        }
        util::run(&mut build)?;
    }

    eprintln!(
        "\nflying {} airframe(s) in RotorPy, taper {} ms ({}), {}, {}, {}, wind {} m/s NED, {} at \
         a time…",
        chosen.len(),
        options.taper_ms,
        options.taper_shape,
        if options.no_speed_telemetry { "no speed telemetry" } else { "speeds reported" },
        if options.unknown_imu_offset { "no IMU offset given" } else { "IMU offset given" },
        if options.gnss { "a GNSS receiver" } else { "motion capture" },
        options.wind_ned_mps.as_deref().unwrap_or("0,0,0"),
        options.jobs
    );
    let results: Vec<(String, Result<serde_json::Value>)> = std::thread::scope(|scope| {
        let mut results = Vec::new();
        for batch in chosen.chunks(options.jobs) {
            let handles: Vec<_> = batch
                .iter()
                .map(|airframe| {
                    let (python, client, scenario) = (&python, &client, &scenario);
                    scope.spawn(move || {
                        (airframe.name.clone(), fly(python, client, scenario, airframe, options))
                    })
                })
                .collect();
            for handle in handles {
                results.push(handle.join().expect("a flight thread panicked"));
            }
        }
        results
    });

    println!();
    println!(
        "{:<24} {:>6} {:>8} {:>11} {:>11} {:>9} {:>9}  verdict",
        "airframe", "taper", "accepted", "rel→hover s", "hold err m", "lowest m", "wall s"
    );
    let mut failed = Vec::new();
    for (name, result) in &results {
        match result {
            Ok(report) => {
                let number = |key: &str| match report[key].as_f64() {
                    Some(v) => format!("{v:.3}"),
                    None => "-".into(),
                };
                println!(
                    "{:<24} {:>6} {:>8} {:>11} {:>11} {:>9} {:>9}  {}",
                    name,
                    number("taper_ms"),
                    report["throw_accepted"].as_bool().unwrap_or(false),
                    number("release_to_hover_s"),
                    number("hold_error_m"),
                    number("min_height_m"),
                    number("wall_s"),
                    report["verdict"].as_str().unwrap_or("?"),
                );
                if report["passed"].as_bool() != Some(true) {
                    failed.push(name.clone());
                }
            }
            Err(error) => {
                println!("{name:<24} error: {error:#}");
                failed.push(name.clone());
            }
        }
    }
    eprintln!("\nxtask thirdparty: {:.0} s", started.elapsed().as_secs_f64());
    if !failed.is_empty() {
        bail!(
            "{} of {} flights did not recover and hold within their bound (0.3 m; 1 m with GNSS): {}",
            failed.len(),
            results.len(),
            failed.join(", ")
        );
    }
    Ok(())
}

/// One flight: its own bridge on a free port, the client against it, the client's JSON back.
fn fly(
    python: &Path,
    client: &Path,
    scenario: &Path,
    airframe: &Airframe,
    options: &Options,
) -> Result<serde_json::Value> {
    let [x, y, z] = airframe.imu_offset_mm;
    let offset = format!("--imu-offset-mm={x},{y},{z}");
    let mut bridge = Command::new(scenario)
        .args(["bridge", "--listen", "127.0.0.1:0", "--throw-to-fly"])
        .args(["--idle-timeout-s", BRIDGE_IDLE_TIMEOUT_S])
        .args((!options.unknown_imu_offset).then_some(offset))
        .args(options.no_speed_telemetry.then_some("--no-speed-telemetry"))
        .args(options.gnss.then_some(["--gnss-latency-ms", GNSS_LATENCY_MS]).into_iter().flatten())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("could not start {}", scenario.display()))?;
    let result = fly_against(&mut bridge, python, client, airframe, options);
    let _ = bridge.kill();
    let _ = bridge.wait();
    result
}

fn fly_against(
    bridge: &mut Child,
    python: &Path,
    client: &Path,
    airframe: &Airframe,
    options: &Options,
) -> Result<serde_json::Value> {
    // The bridge prints "bridge listening on ADDR (…)" on stderr once bound; the rest of its
    // stderr is echoed with the airframe's name so that nothing blocks on a full pipe.
    let stderr = bridge.stderr.take().context("the bridge's stderr")?;
    let mut lines = BufReader::new(stderr).lines();
    let address = loop {
        let line = lines
            .next()
            .context("the bridge stopped before it listened")?
            .context("reading the bridge's stderr")?;
        if let Some(rest) = line.strip_prefix("bridge listening on ") {
            break rest.split_whitespace().next().unwrap_or_default().to_string();
        }
    };
    let name = airframe.name.clone();
    std::thread::spawn(move || {
        for line in lines.map_while(Result::ok) {
            eprintln!("[{name} bridge] {line}");
        }
    });
    let mut command = Command::new(python);
    command
        .arg(client)
        .args(["fly", "--airframe", &airframe.name, "--bridge", &address])
        .arg(format!("--taper-ms={}", options.taper_ms))
        .args(["--taper-shape", &options.taper_shape])
        .args(options.no_speed_telemetry.then_some("--no-speed-telemetry"))
        .args(
            options
                .gnss
                .then_some(["--gnss", "--gnss-latency-ms", GNSS_LATENCY_MS])
                .into_iter()
                .flatten(),
        )
        .args(options.wind_ned_mps.iter().flat_map(|w| ["--wind-ned-mps", w.as_str()]))
        .args(&options.client_args)
        .current_dir(client_dir())
        .stdin(Stdio::null())
        .stderr(Stdio::inherit());
    eprintln!("[{}] bridge on {address}; flying", airframe.name);
    let output = command.output().context("could not start the RotorPy client")?;
    let stdout = String::from_utf8_lossy(&output.stdout);
    let json_line = stdout.lines().rev().find(|line| line.starts_with('{'));
    match (output.status.code(), json_line) {
        (Some(0 | 1), Some(line)) => {
            println!("{line}");
            serde_json::from_str(line).context("the client's JSON summary")
        }
        (code, _) => bail!("the RotorPy client failed (exit {code:?}): {stdout}"),
    }
}

fn client_dir() -> PathBuf {
    util::root().join("sim").join("thirdparty")
}

/// The virtualenv's python, creating the venv and installing the pinned requirements if the
/// venv is missing or was made from another `requirements.txt`.
pub fn ensure_venv() -> Result<PathBuf> {
    let venv = util::root().join("target").join("thirdparty-venv");
    let python = venv.join("bin").join("python");
    let requirements = client_dir().join("requirements.txt");
    let wanted = std::fs::read_to_string(&requirements)
        .with_context(|| format!("reading {}", requirements.display()))?;
    let stamp = venv.join("installed-requirements.txt");
    if python.is_file() && std::fs::read_to_string(&stamp).ok().as_deref() == Some(&wanted) {
        return Ok(python);
    }
    eprintln!("==> creating the RotorPy virtualenv in {}", venv.display());
    let system_python = if util::on_path("python3") { "python3" } else { "python" };
    util::run(Command::new(system_python).args(["-m", "venv"]).arg(&venv)).context(
        "could not create a virtualenv (python3 with its venv module is needed; on Debian: \
         apt-get install python3-venv)",
    )?;
    util::run(
        Command::new(&python)
            .args(["-m", "pip", "install", "--disable-pip-version-check", "--quiet", "-r"])
            .arg(&requirements),
    )
    .context("could not install the pinned RotorPy requirements from PyPI")?;
    std::fs::write(&stamp, wanted)?;
    Ok(python)
}

/// The client's airframes (`rotorpy_bridge.py list`).
fn list_airframes(python: &Path, client: &Path) -> Result<Vec<Airframe>> {
    let output = Command::new(python)
        .arg(client)
        .arg("list")
        .current_dir(client_dir())
        .stderr(Stdio::inherit())
        .output()
        .context("could not run the RotorPy client")?;
    if !output.status.success() {
        bail!("`rotorpy_bridge.py list` failed ({})", output.status);
    }
    let rows: serde_json::Value =
        serde_json::from_slice(&output.stdout).context("the client's airframe list")?;
    let rows = rows.as_array().context("the airframe list is not a JSON array")?;
    rows.iter()
        .map(|row| {
            let name = row["name"].as_str().context("an airframe without a name")?.to_string();
            let offset = row["imu_offset_mm"].as_array().context("no imu_offset_mm")?;
            let mm = |i: usize| offset.get(i).and_then(|v| v.as_f64()).context("imu_offset_mm");
            Ok(Airframe { name, imu_offset_mm: [mm(0)?, mm(1)?, mm(2)?] })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(text: &str) -> Vec<String> {
        text.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn defaults_fly_the_test_airframes_with_a_real_hands_tapering_release() {
        let options = Options::parse(&[]).unwrap();
        assert_eq!(options.airframes, Selection::First(TEST_AIRFRAMES));
        assert_eq!(options.taper_ms, 15.0);
        assert_eq!(options.taper_shape, "cosine");
        assert!(options.release_bridge);
        assert!(!options.no_speed_telemetry, "speeds are reported unless told otherwise");
        assert!(!Options::parse(&args("--dev-bridge")).unwrap().release_bridge);
        assert!(Options::parse(&args("--no-speed-telemetry")).unwrap().no_speed_telemetry);
        assert!(!options.unknown_imu_offset, "the airframe's offset is given unless told");
        assert!(Options::parse(&args("--unknown-imu-offset")).unwrap().unknown_imu_offset);
        assert!(!options.gnss && options.wind_ned_mps.is_none(), "motion capture, still air");
        let outdoors = Options::parse(&args("--gnss --wind-ned-mps 0,4,0")).unwrap();
        assert!(outdoors.gnss);
        assert_eq!(outdoors.wind_ned_mps.as_deref(), Some("0,4,0"));
    }

    #[test]
    fn options_parse_and_bad_values_are_refused() {
        let options = Options::parse(&args(
            "--airframe crazyflie --airframe hummingbird --taper-ms 15 --taper-shape linear \
             --jobs 1 -- --trace --spin-dps 450",
        ))
        .unwrap();
        assert_eq!(
            options.airframes,
            Selection::Named(vec!["crazyflie".into(), "hummingbird".into()])
        );
        assert_eq!(options.taper_ms, 15.0);
        assert_eq!(options.taper_shape, "linear");
        assert_eq!(options.jobs, 1);
        assert_eq!(options.client_args, args("--trace --spin-dps 450"));
        for bad in [
            "--taper-ms 51",
            "--taper-ms -1",
            "--taper-ms nan",
            "--taper-shape square",
            "--airframes 0",
            "--jobs 0",
            "--airframe",
            "--frobnicate",
            "--wind-ned-mps 0,4",
            "--wind-ned-mps 0,21,0",
            "--wind-ned-mps 0,nan,0",
            "--wind-ned-mps",
        ] {
            assert!(Options::parse(&args(bad)).is_err(), "`{bad}` was accepted");
        }
    }
}
