//! `configurator-cli`: talk to a flight controller (USB serial, TCP, or the built-in simulator)
//! and run the offline tools.
//!
//! Exit codes: 0 done; 1 the board could not be reached or refused; 2 bad input or usage.

use clap::{Parser, Subcommand};
use configurator_cli::connect::{connect, ConnectError, Target};
use configurator_cli::link::{Client, DeviceErrorText, LinkError};
use configurator_cli::offline::{self, InputError};
use configurator_cli::report;
use protocol::{Reply, Request, SetTelemetryRate, Telemetry, Topic};
use serde_json::json;
use std::io::Write as _;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(version, about = "Configurator for the self-learning multirotor flight controller")]
struct Cli {
    /// Serial port of the board (default: the one USB board with our VID/PID).
    #[arg(long, global = true, conflicts_with_all = ["tcp", "sitl"])]
    port: Option<String>,
    /// Connect over TCP instead (e.g. a SITL's 127.0.0.1:5760).
    #[arg(long, global = true, conflicts_with = "sitl")]
    tcp: Option<String>,
    /// Start the built-in simulator (SITL) and connect to it through its pseudo-terminal.
    #[arg(long, global = true)]
    sitl: bool,
    /// Airframe of the built-in simulator: a built-in name or a TOML file.
    #[arg(long, global = true, default_value = "paper-quad")]
    airframe: String,
    /// With --sitl: let the simulated hand throw the craft (spinning, 1 m up) and catch it this
    /// many times before the command runs, so the board learns its IMU offset (4× real time).
    #[arg(long, global = true, default_value_t = 0, requires = "sitl",
          value_parser = clap::value_parser!(u8).range(0..=16))]
    sitl_throws: u8,
    /// Print JSON instead of text.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Handshake, then print the board's identity and status.
    Info,
    /// Print the board's status (with the in-flight identification's).
    Status,
    /// Arm throw-to-fly: the next throw starts the motor excitation. Motors WILL spin.
    ArmThrowToFly,
    /// Stop every motor now and leave any armed state.
    Disarm,
    /// Stream a telemetry topic and count what arrives and what is missing. The learner topic
    /// prints every sample on its own line (with --json, one JSON object per line, then the
    /// summary on the last line).
    Stream {
        /// imu, control, motors or learner.
        #[arg(long, default_value = "imu")]
        topic: String,
        /// Samples per second, 1 to 1000.
        #[arg(long, default_value_t = 500)]
        rate_hz: u16,
        /// How long to listen, s.
        #[arg(long, default_value_t = 2.0)]
        duration_s: f64,
    },
    /// List serial ports and mark flight controllers.
    Ports,
    /// Offline fits on recorded logs.
    #[command(subcommand)]
    Fit(FitCommand),
    /// Offline solvers on files.
    #[command(subcommand)]
    Solve(SolveCommand),
}

#[derive(Subcommand, Debug)]
enum FitCommand {
    /// The IMU's position relative to the centre of gravity, from free-fall throws.
    ImuOffset(offline::imu_offset::Args),
}

#[derive(Subcommand, Debug)]
enum SolveCommand {
    /// The most efficient hover thrust axis from effectiveness matrices.
    ThrustAxis(offline::thrust_axis::Args),
}

/// Everything that can end a command early, with its exit code.
enum Failure {
    Input(InputError),
    Connect(ConnectError),
}

impl From<ConnectError> for Failure {
    fn from(e: ConnectError) -> Self {
        Self::Connect(e)
    }
}

impl From<LinkError> for Failure {
    fn from(e: LinkError) -> Self {
        Self::Connect(ConnectError::Link(e))
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(output) => {
            print!("{output}");
            ExitCode::SUCCESS
        }
        Err(Failure::Input(error)) => {
            eprintln!("error: {error}");
            ExitCode::from(2)
        }
        Err(Failure::Connect(error)) => {
            eprintln!("error: {error}");
            ExitCode::from(1)
        }
    }
}

fn run(cli: &Cli) -> Result<String, Failure> {
    match &cli.command {
        Command::Fit(FitCommand::ImuOffset(args)) => {
            offline::imu_offset::run(args).map_err(Failure::Input)
        }
        Command::Solve(SolveCommand::ThrustAxis(args)) => {
            offline::thrust_axis::run(args).map_err(Failure::Input)
        }
        Command::Ports => ports(cli.json),
        Command::Info => with_board(cli, BoardCommand::Info),
        Command::Status => with_board(cli, BoardCommand::Status),
        Command::ArmThrowToFly => with_board(cli, BoardCommand::Arm),
        Command::Disarm => with_board(cli, BoardCommand::Disarm),
        Command::Stream { topic, rate_hz, duration_s } => {
            // Validate arguments before touching any port.
            let topic = stream_arguments(topic, *rate_hz, *duration_s).map_err(Failure::Input)?;
            let command =
                BoardCommand::Stream { topic, rate_hz: *rate_hz, duration_s: *duration_s };
            with_board(cli, command)
        }
    }
}

/// A command that talks to a board, with its arguments validated.
enum BoardCommand {
    Info,
    Status,
    Arm,
    Disarm,
    Stream { topic: Topic, rate_hz: u16, duration_s: f64 },
}

/// Connect (starting a SITL if asked), then run the board command.
fn with_board(cli: &Cli, command: BoardCommand) -> Result<String, Failure> {
    let _sitl; // keeps the simulator alive for the whole command
    let target = if cli.sitl {
        let throwing = cli.sitl_throws > 0;
        let config = sim::sitl::SitlConfig {
            airframe: cli.airframe.clone(),
            auto_throw_every_s: throwing.then_some(SITL_THROW_INTERVAL_S),
            auto_throw_count: Some(usize::from(cli.sitl_throws)),
            speed: if throwing { SITL_THROW_SPEED } else { 1.0 },
            ..Default::default()
        };
        let sitl = sim::sitl::Sitl::start(&config).map_err(ConnectError::from)?;
        let path = sitl.pty_path.clone().expect("the SITL serves a pseudo-terminal when asked");
        eprintln!("started the simulator (airframe `{}`) on {}", cli.airframe, path.display());
        _sitl = sitl;
        Target::Serial(path.display().to_string())
    } else if let Some(address) = &cli.tcp {
        Target::Tcp(address.clone())
    } else if let Some(port) = &cli.port {
        Target::Serial(port.clone())
    } else {
        Target::Discover
    };
    let mut client = connect(&target)?;
    if !client.schema_matches() {
        eprintln!("warning: the board's message table differs from this configurator's; some fields may be missing");
    }
    if cli.sitl_throws > 0 {
        watch_throws(&mut client, cli.sitl_throws)?;
    } else if cli.sitl && matches!(command, BoardCommand::Info | BoardCommand::Status) {
        // Let the simulated board run one full statistics window so the status has figures.
        eprintln!("letting the simulator run for 1.1 s…");
        client.listen(Duration::from_millis(1100))?;
    }
    match command {
        BoardCommand::Info => {
            let status = fetch_status(&mut client)?;
            Ok(if cli.json {
                format!(
                    "{:#}\n",
                    json!({
                        "info": report::info_json(&client.info, client.port()),
                        "status": report::status_json(&status),
                    })
                )
            } else {
                format!(
                    "{}{}",
                    report::info_text(&client.info, client.port()),
                    report::status_text(&status)
                )
            })
        }
        BoardCommand::Status => {
            let status = fetch_status(&mut client)?;
            let learner = fetch_learner(&mut client)?;
            Ok(if cli.json {
                let mut value = report::status_json(&status);
                if let (Some(learner), Some(map)) = (&learner, value.as_object_mut()) {
                    map.insert("learner".into(), report::learner_json(learner));
                }
                format!("{value:#}\n")
            } else {
                let mut text = report::status_text(&status);
                if let Some(learner) = &learner {
                    text.push_str(&report::learner_text(learner));
                }
                text
            })
        }
        BoardCommand::Arm => {
            client.request(&Request::ArmThrowToFly(()), "the arm request")?;
            eprintln!(
                "WARNING: armed for throw-to-fly: the motors WILL SPIN after the next throw. \
                 Keep clear of the propellers; stop them at any time with `configurator-cli disarm`."
            );
            Ok(if cli.json {
                format!("{:#}\n", json!({"armed": true}))
            } else {
                "armed for throw-to-fly\n".into()
            })
        }
        BoardCommand::Disarm => {
            client.request(&Request::Disarm(()), "the disarm request")?;
            Ok(if cli.json {
                format!("{:#}\n", json!({"disarmed": true}))
            } else {
                "disarmed: every motor stopped\n".into()
            })
        }
        BoardCommand::Stream { topic, rate_hz, duration_s } => {
            stream(&mut client, topic, rate_hz, duration_s, cli.json)
        }
    }
}

/// Simulated seconds between the SITL's automatic throws.
const SITL_THROW_INTERVAL_S: f64 = 2.0;
/// Simulation speed while the SITL throws, × real time.
const SITL_THROW_SPEED: f64 = 4.0;

/// Follow the board's onboard IMU-offset estimate while the simulated hand throws `count` times.
fn watch_throws(client: &mut Client, count: u8) -> Result<(), Failure> {
    let wall_s_per_throw = SITL_THROW_INTERVAL_S / SITL_THROW_SPEED;
    let deadline = std::time::Instant::now()
        + Duration::from_secs_f64(2.0 * wall_s_per_throw * f64::from(count) + 5.0);
    let mut reported = 0;
    eprintln!("the simulated hand throws the craft {count} times (spinning, 1 m up)…");
    while reported < count {
        if std::time::Instant::now() > deadline {
            return Err(LinkError::Unexpected(format!(
                "the board saw {reported} of {count} throws before the time ran out"
            ))
            .into());
        }
        client.listen(Duration::from_millis(100))?;
        let offset = fetch_status(client)?.imu_offset;
        if offset.throws > reported {
            reported = offset.throws;
            let r_mm = offset.r_imu_m.map(|x| x * 1000.0);
            let largest_mm = offset.ci95_semi_axes_m[0] * 1000.0;
            let verdict = if offset.well_determined {
                "well determined".to_string()
            } else {
                report::advice_text(&offset.advice)
            };
            eprintln!(
                "  throw {reported}: IMU offset ({:+.2}, {:+.2}, {:+.2}) mm, largest 95 % semi-axis {largest_mm:.2} mm: {verdict}",
                r_mm[0], r_mm[1], r_mm[2]
            );
        }
    }
    // Let the craft rest in the hand for a full one-second statistics window after the catch
    // (2.4 simulated seconds at 4× speed) before the command's own status.
    client.listen(Duration::from_millis(600))?;
    Ok(())
}

fn fetch_status(client: &mut Client) -> Result<protocol::Status, Failure> {
    match client.request(&Request::GetStatus(()), "the status request")? {
        Reply::Status(status) => Ok(status),
        other => Err(LinkError::Unexpected(format!("{other:?} to the status request")).into()),
    }
}

/// The learner's state, or `None` from a board that does not know the request (protocol 1.0).
fn fetch_learner(client: &mut Client) -> Result<Option<protocol::LearnerTelemetry>, Failure> {
    match client.request(&Request::GetLearner(()), "the learner request") {
        Ok(Reply::Learner(learner)) => Ok(Some(learner)),
        Ok(other) => Err(LinkError::Unexpected(format!("{other:?} to the learner request")).into()),
        Err(LinkError::Device(DeviceErrorText(protocol::DeviceError::UnknownRequest {
            ..
        }))) => Ok(None),
        Err(error) => Err(error.into()),
    }
}

fn stream_arguments(topic: &str, rate_hz: u16, duration_s: f64) -> Result<Topic, InputError> {
    let topic = match topic {
        "imu" => Topic::Imu,
        "control" => Topic::Control,
        "motors" => Topic::Motors,
        "learner" => Topic::Learner,
        other => {
            return Err(InputError(format!(
                "unknown topic `{other}`; choose imu, control, motors or learner"
            )))
        }
    };
    if !(1..=protocol::MAX_TELEMETRY_RATE_HZ).contains(&rate_hz) {
        return Err(InputError(format!(
            "--rate-hz {rate_hz} is outside 1 to {} Hz",
            protocol::MAX_TELEMETRY_RATE_HZ
        )));
    }
    if !(duration_s.is_finite() && (0.1..=3600.0).contains(&duration_s)) {
        return Err(InputError(format!("--duration-s {duration_s} is outside 0.1 to 3600 s")));
    }
    Ok(topic)
}

/// Whether a telemetry sample belongs to `topic`.
fn is_topic(data: &Telemetry, topic: Topic) -> bool {
    matches!(
        (data, topic),
        (Telemetry::Imu(_), Topic::Imu)
            | (Telemetry::Control(_), Topic::Control)
            | (Telemetry::Motors(_), Topic::Motors)
            | (Telemetry::Learner(_), Topic::Learner)
    )
}

/// Stream a topic and count samples and gaps (from the per-topic sequence numbers).
fn stream(
    client: &mut Client,
    topic: Topic,
    rate_hz: u16,
    duration_s: f64,
    json_output: bool,
) -> Result<String, Failure> {
    let set = |rate_hz| Request::SetTelemetryRate(SetTelemetryRate { topic, rate_hz });
    client.request(&set(rate_hz), "the telemetry rate request")?;
    // Count as samples arrive (nothing is kept): only this topic, only from now on.
    client.telemetry.clear();
    let (mut received, mut gaps, mut previous_seq) = (0u64, 0u64, None::<u16>);
    let (mut last_imu, mut last_learner) = (None, None);
    // Learner samples are printed as they arrive, one line each (text or JSON).
    let mut stdout = std::io::stdout().lock();
    client.listen_with(Duration::from_secs_f64(duration_s), |sample| {
        if !is_topic(&sample.data, topic) {
            return;
        }
        received += 1;
        if let Some(previous) = previous_seq {
            gaps += u64::from(sample.seq.wrapping_sub(previous).wrapping_sub(1));
        }
        previous_seq = Some(sample.seq);
        match sample.data {
            Telemetry::Imu(imu) => last_imu = Some(imu),
            Telemetry::Learner(learner) => {
                last_learner = Some(learner);
                // A closed stdout (the reader went away) only stops the printing.
                let _ = if json_output {
                    writeln!(stdout, "{}", report::learner_sample_json(sample.seq, &learner))
                } else {
                    write!(stdout, "{}", report::learner_sample_text(sample.seq, &learner))
                };
            }
            _ => {}
        }
    })?;
    let _ = stdout.flush();
    drop(stdout);
    client.request(&set(0), "the request to stop telemetry")?;
    let achieved_hz = received as f64 / duration_s;
    if json_output {
        let summary = json!({
            "topic": format!("{topic:?}").to_lowercase(),
            "requested_rate_hz": rate_hz,
            "duration_s": duration_s,
            "received": received,
            "gaps": gaps,
            "received_rate_hz": achieved_hz,
            "bad_frames": client.bad_frames,
        });
        // After one JSON object per learner sample, the summary too takes one line.
        return Ok(if topic == Topic::Learner {
            format!("{summary}\n")
        } else {
            format!("{summary:#}\n")
        });
    }
    let mut out = format!(
        "{topic:?}: {received} samples in {duration_s:.1} s ({achieved_hz:.1} Hz of {rate_hz} Hz requested), {gaps} missing, {} bad frames\n",
        client.bad_frames
    );
    if let Some(imu) = last_imu {
        out.push_str(&format!(
            "last sample at {:.4} s: gyro ({:+.4}, {:+.4}, {:+.4}) rad/s, accel ({:+.3}, {:+.3}, {:+.3}) m/s²\n",
            imu.t_us as f64 * 1e-6,
            imu.gyro_rad_s[0], imu.gyro_rad_s[1], imu.gyro_rad_s[2],
            imu.accel_mps2[0], imu.accel_mps2[1], imu.accel_mps2[2]
        ));
    }
    if let Some(learner) = last_learner {
        // The last sample in full: ω_full, convergence and the thrust axis too.
        out.push_str("last sample:\n");
        out.push_str(&report::learner_text(&learner));
    }
    Ok(out)
}

fn ports(json_output: bool) -> Result<String, Failure> {
    let ports = serialport::available_ports().map_err(ConnectError::Enumerate)?;
    let rows: Vec<(String, String)> = ports
        .iter()
        .map(|port| {
            let kind = match &port.port_type {
                serialport::SerialPortType::UsbPort(usb)
                    if usb.vid == protocol::USB_VID && usb.pid == protocol::USB_PID =>
                {
                    "flight controller".to_string()
                }
                serialport::SerialPortType::UsbPort(usb) => {
                    format!("USB {:04x}:{:04x}", usb.vid, usb.pid)
                }
                other => format!("{other:?}"),
            };
            (port.port_name.clone(), kind)
        })
        .collect();
    if json_output {
        let list: Vec<_> =
            rows.iter().map(|(name, kind)| json!({"port": name, "kind": kind})).collect();
        return Ok(format!("{:#}\n", json!(list)));
    }
    if rows.is_empty() {
        return Ok("no serial ports found\n".into());
    }
    Ok(rows.iter().map(|(name, kind)| format!("{name}  {kind}\n")).collect())
}
