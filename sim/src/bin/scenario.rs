//! `scenario`: runs a simulator scenario and writes the configurator's CSV log, lists and shows
//! airframes, measures the simulator's speed, and serves the lockstep bridge.
//!
//! ```text
//! cargo run -p sim --release --bin scenario -- throw-catch --airframe paper-quad --out log.csv
//! cargo run -p sim --release --bin scenario -- list
//! cargo run -p sim --release --bin scenario -- bench --seconds 120
//! cargo run -p sim --release --bin scenario -- monte-carlo --runs 1000 --threads 2
//! cargo run -p sim --release --bin scenario -- bridge --listen 127.0.0.1:9003
//! cargo run -p sim --release --bin scenario -- bridge --throw-to-fly --tcp-port 5760
//! ```

use std::fs::File;
use std::io::{BufWriter, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use firmware::app::radio::Receiver;
use firmware::app::ControlCommand;
use firmware::drivers::crsf::RcLinkConfig;
use nalgebra::Vector3;
use sim::airframe::{Airframe, LIBRARY};
use sim::bridge::{serve_firmware, BridgeServer};
use sim::log::CsvLog;
use sim::log_dir::LogDir;
use sim::monte_carlo;
use sim::scenario::{
    self, with_firmware_app, with_logged_firmware_app, ScenarioConfig, ScenarioKind,
};
use sim::serve::{parse_imu_offset_mm, simulator_board_info, TcpLinks};
use sim::stats::BatchArgs;

#[derive(Parser)]
#[command(about = "Multirotor simulator scenarios, airframes, benchmarks and the lockstep bridge")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Hold the craft still in the hand.
    HoldStill(RunArgs),
    /// Throw the craft with spin and catch it (data for the IMU-offset fit).
    ThrowCatch(RunArgs),
    /// Throw the craft and let the application fly it (needs the armed path of
    /// firmware::app::ControlLoop; today it commands zero and the craft falls).
    ThrowFly(RunArgs),
    /// List the built-in airframes.
    List,
    /// Print an airframe's TOML (built-in name or file; `random:<seed>` for a random one).
    Show {
        /// Airframe name, file, or `random:<seed>`.
        airframe: String,
    },
    /// Measure simulated seconds per wall-clock second on one thread.
    Bench {
        /// Airframe name or file.
        #[arg(long, default_value = "paper-quad")]
        airframe: String,
        /// Simulated seconds to run (repeated throw-and-fly runs of 6 s).
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
    },
    /// Run a Monte Carlo batch of throw-and-catch runs on random airframes.
    MonteCarlo {
        #[command(flatten)]
        batch: BatchArgs,
    },
    /// Serve the lockstep UDP bridge for an external simulator (see docs/sim-bridge.md).
    Bridge {
        /// Address to listen on for sensor packets: IP:PORT (a local interface's address).
        #[arg(long, default_value = "127.0.0.1:9003", value_name = "IP:PORT",
              value_parser = parse_listen_address)]
        listen: SocketAddr,
        /// Stop after this many seconds without a packet (0.01 to 86400).
        #[arg(long, default_value_t = 10.0, value_parser = parse_idle_timeout_s)]
        idle_timeout_s: f64,
        /// Arm the application for throw-to-fly at start: the first throw the sensor packets
        /// show starts the motor excitation.
        #[arg(long)]
        throw_to_fly: bool,
        /// IMU offset for the in-flight learner: the IMU's position relative to the centre of
        /// gravity, IMU axes, mm, as `X,Y,Z` (each within ±1000). Default: the onboard estimate.
        #[arg(
            long,
            value_name = "X,Y,Z",
            allow_hyphen_values = true,
            value_parser = parse_imu_offset_mm
        )]
        imu_offset_mm: Option<[f32; 3]>,
        /// The simulator's ESCs report no speed (NaN in the sensor packets): the application is
        /// told so (`motor_bidir_dshot` = 0) and identifies the motors from the commands and the
        /// body's response instead of refusing to arm.
        #[arg(long)]
        no_speed_telemetry: bool,
        /// How late the GNSS solutions in the sensor packets are, ms (0 to 200): each describes
        /// the craft this long before the packet that carries it, as a user tells a board its
        /// receiver's latency (the firmware's default: 100).
        #[arg(long, value_name = "MS", default_value_t = sim::gnss::GnssArgs::LATENCY_MS,
              value_parser = parse_gnss_latency_ms)]
        gnss_latency_ms: f64,
        /// The magnetometer blocks are calibrated fields (no hard or soft iron, the IMU's axes):
        /// store an identity compass calibration at start, as a user's `compass calibrate`
        /// would store theirs, so the firmware's pilot uses the compass for its heading. Without
        /// it the firmware finds and reads the compass but, as on a board without a calibration,
        /// does not use it.
        #[arg(long)]
        compass_calibrated: bool,
        /// The local magnetic declination, degrees east of true north (-90 to 90; the parameter
        /// `compass_declination_deg`): the compass's heading is magnetic north plus it, the
        /// GNSS solutions' (true) north.
        #[arg(long, value_name = "DEG", default_value_t = 0.0, allow_negative_numbers = true,
              value_parser = parse_compass_declination_deg)]
        compass_declination_deg: f32,
        /// Also serve the configurator protocol on TCP at 127.0.0.1:PORT (0 picks a free one),
        /// as the SITL does: `configurator-cli --tcp 127.0.0.1:PORT status`.
        #[arg(long, value_name = "PORT")]
        tcp_port: Option<u16>,
        /// A simulated pilot's radio (a CRSF receiver on the board's UART) playing this script
        /// of `TIME_S:EVENT` items in the packets' time (events: arm, disarm, throw, throw-off,
        /// kill, kill-off, lose, restore; every switch starts off), e.g. `1:arm,1:throw,20:kill`.
        #[arg(long, value_name = "SCRIPT", value_parser = sim::radio::RcScript::parse)]
        rc: Option<sim::radio::RcScript>,
        /// Write the flight log into this directory (LOG00001.BIN, …; created when missing): a
        /// file per arming, as on the board's SD card (`configurator-cli replay` reads them).
        #[arg(long, value_name = "DIR")]
        log_dir: Option<std::path::PathBuf>,
    },
}

#[derive(Args)]
struct RunArgs {
    /// Airframe: a built-in name (see `list`), a TOML file, or `random:<seed>`.
    #[arg(long, default_value = "paper-quad")]
    airframe: String,
    /// Output CSV log.
    #[arg(long)]
    out: PathBuf,
    /// Sensor-noise seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Body rate at release, °/s, as `x,y,z` (default: the scenario's).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    rate_dps: Option<Vec<f64>>,
    /// Horizontal release velocity, m/s, as `north,east` (default 0,0).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    horizontal_mps: Option<Vec<f64>>,
    /// Apex of the throw above the release point, m (default: the scenario's).
    #[arg(long)]
    apex_m: Option<f64>,
    /// Height of the hand at the start, m.
    #[arg(long)]
    height_m: Option<f64>,
    /// Longest run, s (default: the scenario's).
    #[arg(long)]
    duration_s: Option<f64>,
    /// Physics (RK4) steps per raw IMU sample: 1 runs the physics at the IMU rate (8 kHz).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    physics_steps_per_imu_sample: u32,
}

/// The bridge's `--gnss-latency-ms`: 0 to the firmware's largest latency of a position fix
/// (`firmware::app::MAX_POSE_LATENCY_S`, 200 ms).
fn parse_gnss_latency_ms(text: &str) -> Result<f64, String> {
    let ms: f64 = text.parse().map_err(|_| format!("`{text}` is not a number of milliseconds"))?;
    let max_ms = f64::from(firmware::app::MAX_POSE_LATENCY_S) * 1e3;
    if !(0.0..=max_ms).contains(&ms) {
        return Err(format!("{text} ms is out of range: allowed [0, {max_ms:.0}] ms"));
    }
    Ok(ms)
}

/// What the bridge's command line puts in force before the first packet.
struct BridgeStart {
    imu_offset_mm: Option<[f32; 3]>,
    no_speed_telemetry: bool,
    compass_calibrated: bool,
    compass_declination_deg: f32,
    throw_to_fly: bool,
}

impl BridgeStart {
    /// The parameters first, then the IMU offset, then the arming: a change of the parameters
    /// hands them to the background task, whose configured IMU offset is then the parameters'
    /// (none stored in a bridge: `serve_firmware` stores the offset given here from the
    /// background's), so an offset set before would be lost.
    fn apply(&self, app: &mut scenario::FirmwareApp<'_>) -> Result<()> {
        if self.no_speed_telemetry {
            sim::bridge::set_no_speed_telemetry(app);
        }
        if self.compass_calibrated || self.compass_declination_deg != 0.0 {
            let (calibrated, declination_deg) =
                (self.compass_calibrated, self.compass_declination_deg);
            sim::bridge::configure_compass(app, calibrated, declination_deg)?;
        }
        if self.imu_offset_mm.is_some() {
            app.background.set_imu_offset(self.imu_offset_mm);
        }
        if self.throw_to_fly {
            app.submit(ControlCommand::ArmThrowToFly);
        }
        Ok(())
    }
}

/// The bridge's `--compass-declination-deg`: within the parameter's range (±90°).
fn parse_compass_declination_deg(text: &str) -> Result<f32, String> {
    let deg: f32 = text.parse().map_err(|_| format!("`{text}` is not a number of degrees"))?;
    let (min, max) = sim::bridge::declination_range_deg();
    if !(min..=max).contains(&deg) {
        return Err(format!("{text}° is out of range: allowed [{min:.0}, {max:.0}]°"));
    }
    Ok(deg)
}

fn parse_idle_timeout_s(text: &str) -> Result<f64, String> {
    let s: f64 = text.parse().map_err(|_| format!("`{text}` is not a number of seconds"))?;
    if !(0.01..=86_400.0).contains(&s) {
        return Err(format!("{text} s is out of range: allowed [0.01, 86400] s"));
    }
    Ok(s)
}

/// The bridge's `--listen` address: an IP literal and a port (a name would need resolving to
/// know which interface to bind; a bad one is a usage error, exit 2).
fn parse_listen_address(text: &str) -> Result<SocketAddr, String> {
    text.parse().map_err(|_| {
        "expected IP:PORT, an address of this machine and a port (e.g. 127.0.0.1:9003, [::1]:9003)"
            .to_string()
    })
}

fn load_airframe(spec: &str) -> Result<Airframe> {
    if let Some(seed) = spec.strip_prefix("random:") {
        let seed: u64 = seed.parse().with_context(|| format!("`{seed}` is not a seed (u64)"))?;
        return Ok(Airframe::random(seed));
    }
    Ok(Airframe::load(spec)?)
}

fn run_scenario(kind: ScenarioKind, args: RunArgs) -> Result<()> {
    let airframe = load_airframe(&args.airframe)?;
    let mut config = ScenarioConfig::new(kind);
    config.board.seed = args.seed;
    config.board.physics_steps_per_imu_sample = args.physics_steps_per_imu_sample;
    if let Some(r) = &args.rate_dps {
        if r.len() != 3 {
            bail!("--rate-dps needs three values x,y,z in °/s, got {}", r.len());
        }
        config.throw_rate_body_rad_s = Vector3::new(r[0], r[1], r[2]).map(f64::to_radians);
    }
    if let Some(v) = &args.horizontal_mps {
        if v.len() != 2 {
            bail!("--horizontal-mps needs two values north,east in m/s, got {}", v.len());
        }
        config.throw_horizontal_mps = [v[0], v[1]];
    }
    if let Some(a) = args.apex_m {
        config.throw_apex_m = a;
    }
    if let Some(h) = args.height_m {
        config.hold_height_m = h;
    }
    if let Some(d) = args.duration_s {
        config.duration_s = d;
    }
    let file = File::create(&args.out)
        .with_context(|| format!("cannot create the log file {}", args.out.display()))?;
    let mut log = CsvLog::new(BufWriter::new(file), airframe.rotor_count())?;
    let mut last_shown = -1.0;
    let mut progress = |t: f64, total: f64| {
        if t - last_shown >= 0.5 {
            eprint!("\r{:?} on {}: {t:5.1} / {total:.1} s", kind, airframe.name);
            last_shown = t;
        }
    };
    let outcome = with_firmware_app(|app| {
        scenario::run(&airframe, &config, app, Some(&mut log), &mut progress)
    })?;
    log.finish()?.flush()?;
    eprintln!();
    println!(
        "{} rows ({:.3} s) written to {}",
        outcome.ticks,
        outcome.duration_s,
        args.out.display()
    );
    if let Some(t) = outcome.released_at_s {
        println!("released at {t:.3} s");
    }
    if let Some(t) = outcome.caught_at_s {
        println!("caught at {t:.3} s");
    }
    println!(
        "max height {:.2} m, max body rate {:.0} °/s, touched ground: {}",
        outcome.max_height_m,
        outcome.max_rate_rad_s.to_degrees(),
        outcome.touched_ground
    );
    if kind == ScenarioKind::ThrowFly {
        println!(
            "note: firmware::app::ControlLoop has no armed path yet (controller issue): it \
             commanded zero and the craft fell"
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::HoldStill(a) => run_scenario(ScenarioKind::HoldStill, a),
        Command::ThrowCatch(a) => run_scenario(ScenarioKind::ThrowCatch, a),
        Command::ThrowFly(a) => run_scenario(ScenarioKind::ThrowFly, a),
        Command::List => {
            for (name, _) in LIBRARY {
                let a = Airframe::builtin(name)?;
                println!(
                    "{name:12} {} rotors, {:.2} kg  {}",
                    a.rotor_count(),
                    a.mass_kg,
                    a.description
                );
            }
            Ok(())
        }
        Command::Show { airframe } => {
            print!("{}", load_airframe(&airframe)?.to_toml_string());
            Ok(())
        }
        Command::Bench { airframe, seconds } => {
            let airframe = load_airframe(&airframe)?;
            let config = ScenarioConfig::new(ScenarioKind::ThrowFly);
            let (sim_s, wall_s) = with_firmware_app(|app| {
                monte_carlo::realtime_factor(&airframe, &config, app, seconds)
            })?;
            println!(
                "{}: {sim_s:.1} simulated s in {wall_s:.3} wall s = {:.0}x real time \
                 (physics {:.0} Hz RK4, IMU {:.0} Hz, application 2 kHz, one thread)",
                airframe.name,
                sim_s / wall_s,
                airframe.imu.sample_rate_hz * f64::from(config.board.physics_steps_per_imu_sample),
                airframe.imu.sample_rate_hz,
            );
            Ok(())
        }
        Command::MonteCarlo { batch: BatchArgs { runs, seed, threads } } => {
            eprintln!("{runs} throw-and-catch runs on random airframes, {threads} threads ...");
            let s = monte_carlo::throw_catch_batch(runs, seed, threads)?;
            println!(
                "{} runs ({} caught), {:.0} simulated s in {:.2} wall s on {} threads \
                 ({:.0}x real time overall)",
                s.runs,
                s.caught,
                s.simulated_s,
                s.wall.as_secs_f64(),
                s.threads,
                s.simulated_s / s.wall.as_secs_f64()
            );
            if s.caught != s.runs {
                bail!("{} runs were not caught", s.runs - s.caught);
            }
            Ok(())
        }
        Command::Bridge {
            listen,
            idle_timeout_s,
            throw_to_fly,
            imu_offset_mm,
            no_speed_telemetry,
            gnss_latency_ms,
            compass_calibrated,
            compass_declination_deg,
            tcp_port,
            rc,
            log_dir,
        } => {
            let mut server =
                BridgeServer::bind(listen).with_context(|| format!("cannot listen on {listen}"))?;
            server.set_gnss_latency_s(gnss_latency_ms * 1e-3)?;
            let udp = server.local_addr()?;
            eprintln!("bridge listening on {udp} (sensor packets in, motor packets back)");
            // The motor count comes with the packets: 0 in the info until the first one.
            let info = simulator_board_info("BRIDGE", u64::from(udp.port()), 0);
            let mut links = match tcp_port {
                Some(port) => {
                    let links = TcpLinks::bind(port, info)
                        .with_context(|| format!("cannot listen on 127.0.0.1:{port}"))?;
                    eprintln!("configurator protocol on TCP {}", links.local_addr()?);
                    Some(links)
                }
                None => None,
            };
            if throw_to_fly {
                eprintln!("armed for throw-to-fly: the first throw starts the motor excitation");
            }
            if no_speed_telemetry {
                eprintln!(
                    "ESCs without speed telemetry (motor_bidir_dshot = 0): the motors are \
                     identified from the commands and the body's response"
                );
            }
            if compass_calibrated {
                eprintln!(
                    "compass: the magnetometer blocks taken as calibrated (identity calibration \
                     stored), declination {compass_declination_deg}°"
                );
            }
            if let Some([x, y, z]) = imu_offset_mm {
                eprintln!(
                    "IMU offset for the learner: ({:.1}, {:.1}, {:.1}) mm, IMU axes",
                    x * 1000.0,
                    y * 1000.0,
                    z * 1000.0
                );
            }
            let timeout = Duration::from_secs_f64(idle_timeout_s);
            let mut radio = rc.as_ref().map(|script| {
                eprintln!("pilot's radio: {} scripted events", script.events.len());
                sim::radio::RcTransmitter::new(sim::radio::DEFAULT_RC_RATE_HZ, script)
            });
            let receiver = radio.as_ref().and_then(|_| Receiver::new(RcLinkConfig::default()).ok());
            let mut logs = match &log_dir {
                Some(dir) => Some(LogDir::create(dir).with_context(|| {
                    format!("cannot create the log directory {}", dir.display())
                })?),
                None => None,
            };
            let sink = logs.as_mut().map(|logs| logs as &mut dyn firmware::app::log::LogSink);
            let result = with_logged_firmware_app(sink, "BRIDGE", receiver, |app| {
                let start = BridgeStart {
                    imu_offset_mm,
                    no_speed_telemetry,
                    compass_calibrated,
                    compass_declination_deg,
                    throw_to_fly,
                };
                start.apply(app)?;
                let summary = serve_firmware(
                    &mut server,
                    app,
                    links.as_mut(),
                    radio.as_mut(),
                    timeout,
                    &mut |notice| eprintln!("{notice}"),
                );
                app.finish_log();
                if let Some(text) = sim::bridge::identification_summary(&app.background.results()) {
                    eprintln!("{text}");
                }
                let summary = summary?;
                eprintln!(
                    "no packet for {idle_timeout_s} s after {} steps ({} malformed packets, {} \
                     not {} µs after the one before); stopping",
                    summary.steps,
                    summary.malformed,
                    summary.off_period,
                    sim::board::CONTROL_PERIOD_US
                );
                Ok(())
            });
            if let Some(logs) = &logs {
                for file in logs.files() {
                    eprintln!("flight log written: {}", file.display());
                }
            }
            result
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::error::ErrorKind;

    /// A bad `--listen` address is clap's usage error (exit code 2, the value and the expected
    /// form named), refused before any socket is opened; a good one is taken as given.
    #[test]
    fn a_bad_listen_address_is_a_usage_error_with_exit_code_2() {
        for bad in ["notanaddress", "127.0.0.1", "localhost:9003", "127.0.0.1:99999"] {
            let error = Cli::try_parse_from(["scenario", "bridge", "--listen", bad])
                .err()
                .unwrap_or_else(|| panic!("`{bad}` was accepted"));
            assert_eq!(error.kind(), ErrorKind::ValueValidation, "{bad}");
            assert_eq!(error.exit_code(), 2, "{bad}");
            let message = error.to_string();
            assert!(message.contains(bad) && message.contains("expected IP:PORT"), "{message}");
        }
        let cli = Cli::try_parse_from(["scenario", "bridge", "--listen", "[::1]:9004"]).unwrap();
        let Command::Bridge { listen, no_speed_telemetry, .. } = cli.command else {
            panic!("not the bridge")
        };
        assert_eq!(listen, "[::1]:9004".parse::<SocketAddr>().unwrap());
        assert!(!no_speed_telemetry, "speeds are reported unless told otherwise");
        let cli = Cli::try_parse_from(["scenario", "bridge", "--no-speed-telemetry"]).unwrap();
        assert!(matches!(cli.command, Command::Bridge { no_speed_telemetry: true, .. }));
    }

    /// `--gnss-latency-ms` takes 0–200 ms (the firmware's largest fix latency), defaults to the
    /// firmware's 100 ms, and anything else is a usage error naming the value and the range.
    #[test]
    fn the_bridges_gnss_latency_is_checked_and_defaults_to_the_firmwares() {
        let latency = |args: &[&str]| {
            let cli = Cli::try_parse_from([&["scenario", "bridge"], args].concat());
            cli.map(|cli| match cli.command {
                Command::Bridge { gnss_latency_ms, .. } => gnss_latency_ms,
                _ => panic!("not the bridge"),
            })
        };
        let default_ms = f64::from(firmware::app::gnss::DEFAULT_GNSS_LATENCY_S) * 1e3;
        assert!((latency(&[]).unwrap() - default_ms).abs() < 1e-3);
        assert_eq!(latency(&["--gnss-latency-ms", "150"]).unwrap(), 150.0);
        assert_eq!(latency(&["--gnss-latency-ms", "0"]).unwrap(), 0.0);
        for bad in ["201", "-1", "NaN", "soon"] {
            let error = latency(&[&format!("--gnss-latency-ms={bad}")]).expect_err(bad);
            assert_eq!(error.kind(), ErrorKind::ValueValidation, "{bad}");
            assert!(error.to_string().contains(bad), "{error}");
        }
    }

    /// Every start-up option together: the IMU offset survives the parameters' changes (no speed
    /// telemetry, the compass's calibration and declination), which hand the background task
    /// the parameters' offset (none); each is in force.
    #[test]
    fn the_bridges_start_up_keeps_the_imu_offset_given_with_the_parameters_it_changes() {
        let start = BridgeStart {
            imu_offset_mm: Some([0.012, -0.003, -0.02]),
            no_speed_telemetry: true,
            compass_calibrated: true,
            compass_declination_deg: -7.5,
            throw_to_fly: false,
        };
        with_firmware_app(|app| {
            start.apply(app).unwrap();
            assert_eq!(app.background.configured_imu_offset(), start.imu_offset_mm);
            let params = app.link.settings().params();
            assert!(!params.bidirectional_dshot());
            let calibration = sim::bridge::identity_compass_calibration();
            assert_eq!(params.compass_calibration(), Some(calibration));
            assert_eq!(params.compass_declination_rad(), (-7.5f32).to_radians());
        });
    }

    /// `--compass-calibrated` is off unless given; `--compass-declination-deg` defaults to 0,
    /// takes the parameter's ±90° (negative values west) and refuses anything else as a usage
    /// error naming the value.
    #[test]
    fn the_bridges_compass_flags_are_parsed_and_the_declination_checked() {
        let compass = |args: &[&str]| {
            let cli = Cli::try_parse_from([&["scenario", "bridge"], args].concat());
            cli.map(|cli| match cli.command {
                Command::Bridge { compass_calibrated, compass_declination_deg, .. } => {
                    (compass_calibrated, compass_declination_deg)
                }
                _ => panic!("not the bridge"),
            })
        };
        assert_eq!(compass(&[]).unwrap(), (false, 0.0));
        assert_eq!(compass(&["--compass-calibrated"]).unwrap(), (true, 0.0));
        let west = compass(&["--compass-calibrated", "--compass-declination-deg", "-12.5"]);
        assert_eq!(west.unwrap(), (true, -12.5));
        assert_eq!(compass(&["--compass-declination-deg=90"]).unwrap(), (false, 90.0));
        for bad in ["90.5", "-91", "NaN", "east"] {
            let error = compass(&[&format!("--compass-declination-deg={bad}")]).expect_err(bad);
            assert_eq!(error.kind(), ErrorKind::ValueValidation, "{bad}");
            assert_eq!(error.exit_code(), 2, "{bad}");
            assert!(error.to_string().contains(bad), "{error}");
        }
    }
}
