//! `configurator-cli`: talk to a flight controller (USB serial, TCP, or the built-in simulator)
//! and run the offline tools.
//!
//! Exit codes: 0 done; 1 the board could not be reached or refused; 2 bad input or usage.

use clap::{Parser, Subcommand};
use configurator_cli::config;
use configurator_cli::connect::{connect, Baud, ConnectError, Target};
use configurator_cli::link::{Client, DeviceErrorText, LinkError};
use configurator_cli::log_files;
use configurator_cli::offline::{self, InputError};
use configurator_cli::report;
use protocol::{Reply, Request, SetTelemetryRate, Telemetry, Topic};
use serde_json::{json, Value};
use std::io::Write as _;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(version, about = "Configurator for the self-learning multirotor flight controller")]
struct Cli {
    /// Serial port of the board (default: the one USB board with our VID/PID).
    #[arg(long, global = true, conflicts_with_all = ["tcp", "sitl"])]
    port: Option<String>,
    /// The serial port's rate, baud: a telemetry radio's USB-UART adapter needs its UART's
    /// (57600 for SiK/RFD900, 115200 or 460800 for ESP32 bridges); the board's own USB port
    /// ignores it. Without --baud: the environment variable FC_BAUD, else 921600.
    #[arg(long, global = true, conflicts_with_all = ["tcp", "sitl"], value_name = "BAUD",
          value_parser = Baud::parse)]
    baud: Option<Baud>,
    /// Connect over TCP instead: HOST:PORT (e.g. a SITL's 127.0.0.1:5760).
    #[arg(long, global = true, conflicts_with = "sitl", value_name = "HOST:PORT",
          value_parser = configurator_cli::connect::parse_tcp_address)]
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
    /// With --sitl: the simulator's flash file (the saved configuration). Default:
    /// sitl-flash.bin in the user's data directory, as `sitl` uses.
    #[arg(long, global = true, requires = "sitl")]
    sitl_flash_file: Option<std::path::PathBuf>,
    /// With --sitl: a compass on the simulated GNSS mast (drawn as the random world draws one:
    /// iron, mounting, noise, the motors' field), calibrated by a simulated user's dance.
    #[arg(long, global = true, requires = "sitl")]
    sitl_compass: bool,
    /// Print JSON instead of text.
    #[arg(long, global = true)]
    json: bool,
    /// With --sitl: faults the simulated board has from power-up (for `doctor` to find).
    #[command(flatten)]
    sitl_faults: sim::faults::SitlFaultArgs,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Handshake, then print the board's identity and status.
    Info,
    /// Print the board's status (with the in-flight identification's).
    Status,
    /// The bring-up check for a first power-up: link and identity, the IMU at rest against its
    /// datasheet, the flash store, the receiver, every ESC's speed reports, then (asked first:
    /// PROPELLERS OFF) each motor spun in turn at 8 % for a second. Keep the craft still on a
    /// bench. Exit code 1 when a check fails.
    Doctor {
        /// Confirm that the propellers are off without asking (spin every motor in turn).
        #[arg(long)]
        yes: bool,
    },
    /// Arm throw-to-fly: the next throw starts the motor excitation. Motors WILL spin.
    ArmThrowToFly,
    /// Stop every motor now and leave any armed state.
    Disarm,
    /// Land: a flying craft descends at `land_descent_mps`, detects its touchdown and disarms
    /// (one on the ground or waiting for a throw stops at once). Follows the landing and prints
    /// its progress until the board is disarmed, then the touchdown speed.
    Land {
        /// Send the request and return at once, without following the landing.
        #[arg(long)]
        no_wait: bool,
        /// Give up following when the board is still armed this long after the request, s
        /// (the landing goes on).
        #[arg(long, default_value_t = configurator_cli::land::DEFAULT_TIMEOUT_S)]
        timeout_s: f64,
    },
    /// Stream a telemetry topic and count what arrives and what is missing. The learner topic
    /// prints every sample on its own line (with --json, one JSON object per line, then the
    /// summary on the last line).
    Stream {
        /// imu, control, motors, learner or state (every control step: attitude, rates, motor
        /// commands and speeds).
        #[arg(long, default_value = "imu")]
        topic: String,
        /// Samples per second, 1 to 2000 (imu, motors and state reach every 2 kHz control step;
        /// control and learner at most 1000).
        #[arg(long, default_value_t = 500)]
        rate_hz: u16,
        /// How long to listen, s.
        #[arg(long, default_value_t = 2.0)]
        duration_s: f64,
    },
    /// Record telemetry to CSV: one row per control step (state or imu: the log `fit
    /// imu-offset` reads), the slower topics' latest values in their own columns.
    Record {
        /// Comma-separated topics: state, imu, motors, learner, control.
        #[arg(long, default_value = "state")]
        topic: String,
        /// How long to record, s.
        #[arg(long, default_value_t = 10.0)]
        duration_s: f64,
        /// The CSV file to write (replaced if it exists).
        output: std::path::PathBuf,
    },
    /// List the serial ports and what each looks like by its USB IDs: our board, a USB-UART
    /// bridge (FTDI, CP210x, CH340: a telemetry radio or a USB-serial adapter, which needs
    /// --baud), another USB device.
    Ports,
    /// Print one parameter: value, unit, range, default and meaning.
    Get {
        /// Parameter name (`dump` lists them).
        name: String,
    },
    /// Set a parameter (not saved until `save`): `set NAME = VALUE`, arrays comma-separated.
    /// Refused while armed.
    Set {
        /// `NAME = VALUE` (or `NAME=VALUE`).
        #[arg(required = true, num_args = 1.., allow_hyphen_values = true)]
        assignment: Vec<String>,
    },
    /// Print every parameter as `set` lines (with a comment giving meaning, unit and range).
    Dump,
    /// Print the parameters that differ from their defaults, as `set` lines.
    Diff,
    /// Write the parameters in force to the board's flash. Refused while armed.
    Save,
    /// Every parameter back to its default (not saved until `save`). Refused while armed.
    Defaults,
    /// Print the board's and this configurator's versions.
    Version,
    /// Apply a pasted `dump` or `diff` (`-` reads standard input) as one batch; the first bad
    /// line stops it with its line number and nothing changes. Not saved until `save`.
    Apply {
        /// The file, or `-`.
        file: String,
    },
    /// Share a new link key with the board, over USB (a trusted link), and keep it on this
    /// computer: from then on this configurator signs what configures, arms, spins or steers
    /// the craft, so those requests work over a telemetry radio, and nobody else's do.
    /// `--forget` unpairs (the board and this computer forget the key).
    Pair {
        #[arg(long)]
        forget: bool,
    },
    /// How this link is guarded: trusted or not, paired, signing, and the requests refused.
    Security,
    /// Forward motion-capture poses to the board over this link (a radio in the field): UDP
    /// datagrams on --listen, one pose each as the line `t_s n_m e_m d_m qw qx qy qz` (metres,
    /// world north-east-down; the body's attitude quaternion, of which the heading is sent):
    /// docs/field.md. Only the newest pose is sent, at most --rate-hz a second.
    PoseRelay {
        /// Where the motion-capture poses arrive: HOST:PORT (e.g. 0.0.0.0:9870).
        #[arg(long, value_name = "HOST:PORT")]
        listen: std::net::SocketAddr,
        /// The axes the poses are written in: `ned` (world north-east-down, body
        /// front-right-down) or `enu` (world east-north-up, body front-left-up: ROS and most of
        /// its motion-capture bridges), turned into NED before they are sent.
        #[arg(long, value_enum, default_value_t = sim::pose_line::PoseFrame::Ned)]
        frame: sim::pose_line::PoseFrame,
        /// The most poses a second to send, Hz (1–2000).
        #[arg(long, default_value_t = configurator_cli::pose_relay::DEFAULT_RATE_HZ)]
        rate_hz: f64,
        /// Stop after this long, s (default: until interrupted).
        #[arg(long)]
        duration_s: Option<f64>,
    },
    /// Restart the board (the SITL restarts its application and reloads its flash).
    Reboot,
    /// Restart the board into its ROM bootloader (USB DFU) to update the firmware. Refused while
    /// armed and by the simulator.
    Dfu,
    /// Where to hold while flying with an external pose (motion capture): the position of the
    /// centre of gravity in the poses' world (NED, m) and the heading.
    Setpoint {
        /// North, m.
        #[arg(long, allow_hyphen_values = true)]
        north_m: f32,
        /// East, m.
        #[arg(long, allow_hyphen_values = true)]
        east_m: f32,
        /// Down, m (negative is up: -1.5 holds 1.5 m above the origin).
        #[arg(long, allow_hyphen_values = true)]
        down_m: f32,
        /// Heading, degrees (yaw of the thrust frame about down).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        heading_deg: f32,
    },
    /// Guided calibration on the board.
    #[command(subcommand)]
    Calibrate(CalibrateCommand),
    /// The compass on the GNSS mast: `compass calibrate`.
    #[command(subcommand)]
    Compass(CompassCommand),
    /// Throw-and-fly identification: arm, throw the craft, and the board pulses each motor,
    /// learns its actuators and flies on what it learned. MOTORS WILL SPIN. The learned model
    /// goes into the parameters (`save` stores it).
    Identify {
        /// Confirm that the craft is ready to fly (propellers on, area clear) without asking.
        #[arg(long)]
        yes: bool,
        /// Disarm when no throw has come this long after arming, s.
        #[arg(long, default_value_t = 60.0)]
        timeout_s: f64,
        /// Disarm this long after the craft flies on the learned model, s (default: leave it
        /// flying; `disarm` stops it).
        #[arg(long, conflicts_with = "land_after_s")]
        disarm_after_s: Option<f64>,
        /// Land this long after the craft flies on the learned model, s, and wait for the
        /// touchdown (as `land` does).
        #[arg(long)]
        land_after_s: Option<f64>,
        /// Record the attempt (every control step's state, the learner at 100 Hz) to this CSV
        /// (`plot` draws it: attitude, motors, G1 convergence).
        #[arg(long, value_name = "FILE.csv")]
        record: Option<std::path::PathBuf>,
    },
    /// Spin one motor to check its wiring and direction. PROPELLERS OFF. It stops by itself 3 s
    /// after the configurator stops asking, and at once on disconnect or Ctrl-C.
    MotorTest {
        /// Motor index from 0.
        #[arg(long)]
        motor: u8,
        /// Command δ, 0 to 0.5.
        #[arg(long, default_value_t = 0.1)]
        command: f32,
        /// How long to spin, s.
        #[arg(long, default_value_t = 2.0)]
        duration_s: f64,
        /// Confirm that the propellers are off without asking.
        #[arg(long)]
        yes: bool,
    },
    /// Send an ESC command (a DShot special command) to one motor's ESC or to all: `beep1` to
    /// find a motor, `spin-direction-reversed` then `save-settings` to turn a motor round for
    /// good. The motors must be stopped (refused while armed). `esc list` names them all.
    Esc {
        /// The command: `beep1`…`beep5`, `esc-info`, `spin-direction-normal`,
        /// `spin-direction-reversed`, `3d-mode-on`/`-off`, `save-settings`, … or `list`.
        command: String,
        /// Motor index from 0 (default: every motor).
        #[arg(long)]
        motor: Option<u8>,
    },
    /// An interactive shell: the same commands, with history, tab completion and `help`.
    Shell,
    /// Render a recording (CSV from `record`: IMU, attitude, motor and G1-convergence panels) or
    /// an IMU-offset fit (the JSON of `fit imu-offset --json`: its 95 % ellipsoid) to PNG or SVG
    /// (by the output's extension).
    Plot {
        /// The recording.
        input: std::path::PathBuf,
        /// The image to write (.png or .svg).
        #[arg(short, long)]
        output: std::path::PathBuf,
    },
    /// Replay a flight log (LOG00001.BIN) through a fresh copy of the firmware application and
    /// compare every command it writes with the logged one; `--set` replays with a changed
    /// parameter and reports where the outcome departs.
    Replay(offline::replay::Args),
    /// Flight logs: on the board (list, download, delete) and on this computer (to CSV, to MCAP).
    #[command(subcommand)]
    Log(LogCommand),
    /// Offline fits on recorded logs.
    #[command(subcommand)]
    Fit(FitCommand),
    /// Offline solvers on files.
    #[command(subcommand)]
    Solve(SolveCommand),
}

#[derive(Subcommand, Debug)]
enum LogCommand {
    /// The board's flight logs: number, size, duration, and whether still being written.
    List,
    /// Download log N from the board into FILE (with progress); `--resume` continues a partial
    /// FILE from its length.
    Download {
        /// The log's number (`log list`; LOG00001.BIN is 1).
        number: u32,
        /// The file to write.
        file: std::path::PathBuf,
        /// Continue an interrupted download: keep FILE's bytes and fetch the rest.
        #[arg(long)]
        resume: bool,
    },
    /// Delete log N on the board (refused while armed and for the log being written).
    Delete {
        /// The log's number.
        number: u32,
    },
    /// A flight log's control steps as the CSV `record --topics imu,motors` writes (for `plot`
    /// and `fit imu-offset`).
    ToCsv(offline::log_csv::Args),
    /// A flight log as MCAP for Foxglove or PlotJuggler (no plugin): a JSON channel per record
    /// kind (/imu, /speeds, /commands, /phase, /command, /parameters) at the steps' times.
    ToMcap(offline::log_mcap::Args),
}

#[derive(Subcommand, Debug)]
enum FitCommand {
    /// The IMU's position relative to the centre of gravity, from free-fall throws.
    ImuOffset(offline::imu_offset::Args),
}

#[derive(Subcommand, Debug)]
enum CalibrateCommand {
    /// Where the IMU sits relative to the centre of gravity: throw the craft (spinning) and
    /// catch it, hold it still a moment between throws; stores the offset when you accept.
    ImuOffset {
        /// Store the result without asking once it is well determined.
        #[arg(long)]
        yes: bool,
        /// Give up after this many throws.
        #[arg(long, default_value_t = 6)]
        max_throws: u8,
        /// Give up after this long without a throw, s.
        #[arg(long, default_value_t = 120.0)]
        timeout_s: f64,
    },
}

#[derive(Subcommand, Debug)]
enum CompassCommand {
    /// Fit the compass's hard and soft iron and its mounting: turn the craft by hand through
    /// every orientation (disarmed, motors off, away from steel) while the board gathers; it
    /// solves and stores the result only when both fits succeed (`save` keeps it).
    Calibrate {
        /// Gather for this long, s (stops earlier once the coverage reaches 70 %).
        #[arg(long, default_value_t = 60.0)]
        duration_s: f64,
    },
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
    /// Checks ran and some failed (`doctor`): exit code 1, the message names them.
    Checks(String),
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
        Err(Failure::Checks(message)) => {
            eprintln!("error: {message}");
            ExitCode::from(1)
        }
        Err(Failure::Connect(error)) => {
            eprintln!("error: {error}");
            // A value the board refused is bad input too (nothing was changed).
            let bad_input = matches!(
                &error,
                ConnectError::Link(LinkError::Device(DeviceErrorText(
                    protocol::DeviceError::BadValue { .. }
                        | protocol::DeviceError::UnknownParam { .. }
                        | protocol::DeviceError::WrongLength { .. }
                        | protocol::DeviceError::NotAnInteger { .. }
                )))
            );
            ExitCode::from(if bad_input { 2 } else { 1 })
        }
    }
}

/// The link's guard as the board reports it.
fn link_security(client: &mut Client) -> Result<protocol::LinkSecurity, Failure> {
    match client.request(&Request::GetLinkSecurity(()), "the link security request")? {
        Reply::LinkSecurity(security) => Ok(security),
        other => Err(LinkError::Unexpected(format!("{other:?} to GetLinkSecurity")).into()),
    }
}

/// `pair`: a new key to the board over a trusted link, then kept here; or both forget it.
fn pair(client: &mut Client, forget: bool, json: bool) -> Result<String, Failure> {
    use configurator_cli::keys;
    if !link_security(client)?.trusted {
        return Err(Failure::Input(InputError(
            "pairing needs a trusted link: connect the board over USB (the key must not cross \
             the radio)"
                .into(),
        )));
    }
    let serial = client.info.serial.to_string();
    let key_error = |e: keys::KeyError| Failure::Input(InputError(e.to_string()));
    let key = if forget { None } else { Some(keys::new_key().map_err(key_error)?) };
    // Where the key will be kept must be known before the board takes it.
    keys::key_dir().map_err(key_error)?;
    let set = protocol::SetLinkKey { key: key.map(heapless::Vec::from_array) };
    client.set_timeout(SAVE_TIMEOUT);
    let reply = client.request(&Request::SetLinkKey(set), "the pairing request");
    client.set_timeout(configurator_cli::link::DEFAULT_TIMEOUT);
    match reply? {
        Reply::Done => {}
        other => {
            return Err(LinkError::Unexpected(format!("{other:?} to the pairing request")).into())
        }
    }
    let kept = match key {
        Some(key) => {
            let kept = keys::store(&serial, &key).map_err(key_error)?;
            client.sign_with(key)?;
            Some(kept)
        }
        None => {
            keys::forget(&serial).map_err(key_error)?;
            None
        }
    };
    Ok(match (&kept, json) {
        (_, true) => format!(
            "{:#}\n",
            json!({ "serial": serial, "paired": kept.is_some(), "key_file": kept })
        ),
        (Some(file), false) => format!(
            "paired with board {serial}: the key is in its flash and in {}; requests that \
             configure, arm, spin or steer are now signed over any link\n",
            file.display()
        ),
        (None, false) => format!(
            "unpaired: board {serial} and this computer forgot the key; over a radio the board \
             now refuses every request that configures, arms, spins or steers\n"
        ),
    })
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
        Command::Replay(args) => offline::replay::run(args, cli.json).map_err(Failure::Input),
        Command::Log(LogCommand::ToCsv(args)) => {
            offline::log_csv::run(args).map_err(Failure::Input)
        }
        Command::Log(LogCommand::ToMcap(args)) => {
            offline::log_mcap::run(args).map_err(Failure::Input)
        }
        Command::Plot { input, output } => plot(input, output, cli.json),
        Command::Esc { command, .. } if command == "list" => Ok(esc_command_list()),
        // Arguments are validated before any port is touched.
        command => with_board(cli, board_command(command)?),
    }
}

/// The board command of a parsed command line, its arguments checked (before any port is
/// touched).
fn board_command(command: &Command) -> Result<BoardCommand, Failure> {
    let input = |message: String| Failure::Input(InputError(message));
    Ok(match command {
        Command::Info => BoardCommand::Info,
        Command::Log(LogCommand::List) => BoardCommand::LogList,
        Command::Log(LogCommand::Download { number, file, resume }) => {
            BoardCommand::LogDownload { number: *number, file: file.clone(), resume: *resume }
        }
        Command::Log(LogCommand::Delete { number }) => BoardCommand::LogDelete(*number),
        Command::Status => BoardCommand::Status,
        Command::Doctor { yes } => BoardCommand::Doctor { yes: *yes },
        Command::ArmThrowToFly => BoardCommand::Arm,
        Command::Disarm => BoardCommand::Disarm,
        Command::Land { no_wait, timeout_s } => {
            check_timeout_s(*timeout_s)?;
            BoardCommand::Land { follow_timeout_s: (!no_wait).then_some(*timeout_s) }
        }
        Command::Stream { topic, rate_hz, duration_s } => BoardCommand::Stream {
            topic: stream_arguments(topic, *rate_hz, *duration_s).map_err(Failure::Input)?,
            rate_hz: *rate_hz,
            duration_s: *duration_s,
        },
        Command::Record { topic, duration_s, output } => {
            let topics = configurator_cli::record::parse_topics(topic).map_err(input)?;
            check_duration(*duration_s).map_err(Failure::Input)?;
            BoardCommand::Record { topics, duration_s: *duration_s, output: output.clone() }
        }
        Command::Get { name } => BoardCommand::Get(name.clone()),
        Command::Set { assignment } => {
            let words: Vec<&str> = assignment.iter().map(String::as_str).collect();
            let (name, values) = config::parse_assignment(&words).map_err(input)?;
            BoardCommand::Set { name, values }
        }
        Command::Dump => BoardCommand::Dump,
        Command::Diff => BoardCommand::Diff,
        Command::Save => BoardCommand::Save,
        Command::Defaults => BoardCommand::Defaults,
        Command::Version => BoardCommand::Version,
        Command::Reboot => BoardCommand::Reboot,
        Command::Pair { forget } => BoardCommand::Pair { forget: *forget },
        Command::Security => BoardCommand::Security,
        Command::PoseRelay { listen, frame, rate_hz, duration_s } => {
            if duration_s.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
                return Err(input("--duration-s must be a positive number of seconds".into()));
            }
            BoardCommand::PoseRelay {
                listen: *listen,
                frame: *frame,
                rate_hz: *rate_hz,
                duration_s: *duration_s,
            }
        }
        Command::Dfu => BoardCommand::Dfu,
        Command::Setpoint { north_m, east_m, down_m, heading_deg } => {
            let values = [*north_m, *east_m, *down_m, *heading_deg];
            if !values.iter().all(|v| v.is_finite()) {
                return Err(input("setpoint values must be finite numbers".into()));
            }
            BoardCommand::Setpoint(protocol::PositionSetpoint {
                position_ned_m: [*north_m, *east_m, *down_m],
                heading_rad: heading_deg.to_radians(),
            })
        }
        Command::Shell => BoardCommand::Shell,
        Command::Apply { file } => {
            let text = if file == "-" {
                std::io::read_to_string(std::io::stdin())
                    .map_err(|e| input(format!("apply: reading standard input: {e}")))?
            } else {
                std::fs::read_to_string(file).map_err(|e| input(format!("apply: {file}: {e}")))?
            };
            BoardCommand::Apply { file: file.clone(), text }
        }
        Command::Calibrate(CalibrateCommand::ImuOffset { yes, max_throws, timeout_s }) => {
            if !(timeout_s.is_finite() && (1.0..=3600.0).contains(timeout_s)) {
                return Err(input(format!("--timeout-s {timeout_s} is outside 1 to 3600 s")));
            }
            if !(1..=32).contains(max_throws) {
                return Err(input(format!("--max-throws {max_throws} is outside 1 to 32")));
            }
            BoardCommand::Calibrate { yes: *yes, max_throws: *max_throws, timeout_s: *timeout_s }
        }
        Command::Compass(CompassCommand::Calibrate { duration_s }) => {
            if !(duration_s.is_finite() && (10.0..=600.0).contains(duration_s)) {
                return Err(input(format!("--duration-s {duration_s} is outside 10 to 600 s")));
            }
            BoardCommand::CompassCalibrate { duration_s: *duration_s }
        }
        Command::Identify { yes, timeout_s, disarm_after_s, land_after_s, record } => {
            check_timeout_s(*timeout_s)?;
            for (option, hold_s) in
                [("--disarm-after-s", disarm_after_s), ("--land-after-s", land_after_s)]
            {
                if let Some(hold_s) = hold_s {
                    if !(hold_s.is_finite() && (0.0..=600.0).contains(hold_s)) {
                        return Err(input(format!("{option} {hold_s} is outside 0 to 600 s")));
                    }
                }
            }
            BoardCommand::Identify {
                yes: *yes,
                options: configurator_cli::identify::IdentifyOptions {
                    throw_timeout_s: *timeout_s,
                    disarm_after_s: *disarm_after_s,
                    land_after_s: *land_after_s,
                    land_timeout_s: configurator_cli::land::DEFAULT_TIMEOUT_S,
                    every_step: record.is_some(),
                },
                record: record.clone(),
            }
        }
        Command::MotorTest { motor, command, duration_s, yes } => {
            if !(0.0..=protocol::MOTOR_TEST_MAX_COMMAND).contains(command) {
                return Err(input(format!(
                    "--command {command} is outside 0 to {}",
                    protocol::MOTOR_TEST_MAX_COMMAND
                )));
            }
            if !(duration_s.is_finite() && (0.1..=60.0).contains(duration_s)) {
                return Err(input(format!("--duration-s {duration_s} is outside 0.1 to 60 s")));
            }
            BoardCommand::MotorTest {
                motor: *motor,
                command: *command,
                duration_s: *duration_s,
                yes: *yes,
            }
        }
        Command::Esc { command, motor } => {
            let Some(parsed) = protocol::DshotCommand::from_name(command) else {
                return Err(input(format!(
                    "unknown ESC command `{command}`; `esc list` names them: {}",
                    esc_command_names()
                )));
            };
            if *motor == Some(protocol::ESC_ALL_MOTORS) {
                return Err(input(format!("--motor {} is not a motor index", motor.unwrap_or(0))));
            }
            BoardCommand::Esc { command: parsed, motor: *motor }
        }
        other => return Err(input(format!("{other:?} does not talk to a board"))),
    })
}

/// The ESC commands, one per line: name, DShot number, whether it changes a setting.
fn esc_command_list() -> String {
    let mut out =
        String::from("ESC commands (DShot special commands; the motors must be stopped):\n");
    for command in protocol::DshotCommand::ALL {
        let kind = if command.changes_settings() { "setting" } else { "" };
        let line = format!("  {:<26} {:>2}  {kind}", command.name(), command.value());
        out += line.trim_end();
        out.push('\n');
    }
    out
}

/// Every ESC command's name, comma-separated.
fn esc_command_names() -> String {
    protocol::DshotCommand::ALL.map(|c| c.name()).join(", ")
}

/// A command that talks to a board, with its arguments validated.
enum BoardCommand {
    Info,
    Status,
    Doctor {
        yes: bool,
    },
    Arm,
    Disarm,
    /// Land; follow the landing for at most this long, s (`None`: do not follow).
    Land {
        follow_timeout_s: Option<f64>,
    },
    Stream {
        topic: Topic,
        rate_hz: u16,
        duration_s: f64,
    },
    Record {
        topics: Vec<Topic>,
        duration_s: f64,
        output: std::path::PathBuf,
    },
    Get(String),
    Set {
        name: String,
        values: Vec<f32>,
    },
    Dump,
    Diff,
    Save,
    Defaults,
    Version,
    Reboot,
    Pair {
        forget: bool,
    },
    Security,
    PoseRelay {
        listen: std::net::SocketAddr,
        frame: sim::pose_line::PoseFrame,
        rate_hz: f64,
        duration_s: Option<f64>,
    },
    Dfu,
    Setpoint(protocol::PositionSetpoint),
    Shell,
    Apply {
        file: String,
        text: String,
    },
    Calibrate {
        yes: bool,
        max_throws: u8,
        timeout_s: f64,
    },
    CompassCalibrate {
        duration_s: f64,
    },
    Identify {
        yes: bool,
        options: configurator_cli::identify::IdentifyOptions,
        record: Option<std::path::PathBuf>,
    },
    MotorTest {
        motor: u8,
        command: f32,
        duration_s: f64,
        yes: bool,
    },
    Esc {
        command: protocol::DshotCommand,
        motor: Option<u8>,
    },
    LogList,
    LogDownload {
        number: u32,
        file: std::path::PathBuf,
        resume: bool,
    },
    LogDelete(u32),
}

/// Connect (starting a SITL if asked), then run the board command.
fn with_board(cli: &Cli, command: BoardCommand) -> Result<String, Failure> {
    let _sitl; // keeps the simulator alive for the whole command
    let faults = cli.sitl_faults.faults();
    if !cli.sitl && faults != sim::faults::SitlFaults::default() {
        return Err(Failure::Input(InputError(
            "the --fault-* options inject faults into the built-in simulator: add --sitl".into(),
        )));
    }
    let target = if cli.sitl {
        let throwing = cli.sitl_throws > 0;
        let config = sim::sitl::SitlConfig {
            airframe: cli.airframe.clone(),
            flash_file: Some(
                cli.sitl_flash_file.clone().unwrap_or_else(sim::flash::default_flash_path),
            ),
            auto_throw_every_s: throwing.then_some(SITL_THROW_INTERVAL_S),
            auto_throw_count: Some(usize::from(cli.sitl_throws)),
            speed: if throwing { SITL_THROW_SPEED } else { 1.0 },
            // The built-in simulator has a person to throw the craft for `identify`.
            hand_throws_to_fly: true,
            faults,
            compass: cli
                .sitl_compass
                .then(|| {
                    use sim::world::{random_world_case, Aspect};
                    random_world_case(sim::sitl::SitlConfig::default().seed, &[Aspect::Compass])
                        .1
                        .compass
                })
                .flatten(),
            ..Default::default()
        };
        let sitl = match sim::sitl::Sitl::start(&config) {
            Err(sim::sitl::SitlError::Fault(message)) => {
                return Err(Failure::Input(InputError(message)))
            }
            started => started.map_err(ConnectError::from)?,
        };
        let path = sitl.pty_path.clone().expect("the SITL serves a pseudo-terminal when asked");
        eprintln!("started the simulator (airframe `{}`) on {}", cli.airframe, path.display());
        _sitl = sitl;
        Target::Serial { path: path.display().to_string(), baud: Baud::DEFAULT }
    } else if let Some(address) = &cli.tcp {
        Target::Tcp(address.clone())
    } else {
        let baud = serial_baud(cli)?;
        match &cli.port {
            Some(port) => Target::Serial { path: port.clone(), baud },
            None => Target::Discover { baud },
        }
    };
    let mut client = connect(&target)?;
    if !client.schema_matches() {
        eprintln!("warning: the board's message table differs from this configurator's; some fields may be missing");
    }
    if cli.sitl_throws > 0 {
        watch_throws(&mut client, cli.sitl_throws)?;
    } else if cli.sitl
        && matches!(
            command,
            BoardCommand::Info | BoardCommand::Status | BoardCommand::Doctor { .. }
        )
    {
        // Let the simulated board run one full statistics window so the status has figures.
        eprintln!("letting the simulator run for 1.1 s…");
        client.listen(Duration::from_millis(1100))?;
    }
    run_on_board(cli, &mut client, &target, command)
}

/// The rate to open a serial port at: `--baud`, else the environment's `FC_BAUD` (checked like
/// `--baud`: a bad one is bad input, before any port is touched), else [`Baud::DEFAULT`]. Read
/// only for serial ports, so an `FC_BAUD` set in the shell does not trouble `--tcp` or `--sitl`.
fn serial_baud(cli: &Cli) -> Result<Baud, Failure> {
    use configurator_cli::connect::BAUD_ENV;
    if let Some(baud) = cli.baud {
        return Ok(baud);
    }
    match std::env::var(BAUD_ENV) {
        Ok(text) => Baud::parse(&text)
            .map_err(|error| Failure::Input(InputError(format!("{BAUD_ENV}={text}: {error}")))),
        Err(std::env::VarError::NotPresent) => Ok(Baud::DEFAULT),
        Err(std::env::VarError::NotUnicode(text)) => Err(Failure::Input(InputError(format!(
            "{BAUD_ENV}={}: not a baud rate",
            text.to_string_lossy()
        )))),
    }
}

/// Run one board command on a connected client (the one-shot commands and the shell).
fn run_on_board(
    cli: &Cli,
    client: &mut Client,
    target: &Target,
    command: BoardCommand,
) -> Result<String, Failure> {
    match command {
        BoardCommand::Info => {
            let status = fetch_status(client)?;
            let board = fetch_optional(client, Request::GetBoard(()), "the board request")?;
            let board = board.and_then(|reply| match reply {
                Reply::Board(board) => Some(board),
                _ => None,
            });
            let gnss = fetch_optional(client, Request::GetGnss(()), "the GNSS request")?.and_then(
                |reply| match reply {
                    Reply::Gnss(gnss) => Some(gnss),
                    _ => None,
                },
            );
            Ok(if cli.json {
                format!(
                    "{:#}\n",
                    json!({
                        "info": report::info_json(&client.info, client.port()),
                        "board": board.as_ref().map(report::board_json),
                        "gnss": gnss.as_ref().map(report::gnss_json),
                        "status": report::status_json(&status),
                    })
                )
            } else {
                format!(
                    "{}{}{}{}",
                    report::info_text(&client.info, client.port()),
                    board.as_ref().map(report::board_text).unwrap_or_default(),
                    report::gnss_text(gnss.as_ref()),
                    report::status_text(&status, fetch_stored_offset(client)?)
                )
            })
        }
        BoardCommand::Status => {
            let status = fetch_status(client)?;
            let learner = fetch_learner(client)?;
            let flight = fetch_optional(client, Request::GetFlight(()), "the flight request")?;
            let flight = flight.and_then(|reply| match reply {
                Reply::Flight(flight) => Some(flight),
                _ => None,
            });
            let health = match fetch_optional(client, Request::GetHealth(()), "the health request")?
            {
                Some(Reply::Health(health)) => Some(health),
                _ => None,
            };
            let battery = fetch_battery(client)?;
            let identification = fetch_optional(
                client,
                Request::GetIdentification(()),
                "the identification request",
            )?
            .and_then(|reply| match reply {
                Reply::Identification(identification) => Some(identification),
                _ => None,
            });
            let stored = fetch_stored_offset(client)?;
            let config = match client.request(&Request::GetConfig(()), "the configuration request")
            {
                Ok(Reply::Config(config)) => Some(config),
                Ok(_) | Err(LinkError::Device(_)) => None,
                Err(error) => return Err(error.into()),
            };
            Ok(if cli.json {
                let mut value = report::status_json(&status);
                if let Some(map) = value.as_object_mut() {
                    map.insert("imu_offset_stored_m".into(), json!(stored));
                    if let Some(health) = &health {
                        map.insert("health".into(), report::health_json(health));
                    }
                    map.insert("battery".into(), json!(battery.as_ref().map(report::battery_json)));
                    if let Some(learner) = &learner {
                        map.insert("learner".into(), report::learner_json(learner));
                    }
                    if let Some(identification) = &identification {
                        map.insert(
                            "identification".into(),
                            report::identification_json(identification),
                        );
                    }
                    // What `imu_offset` shows: the throws' estimate, or the offset fitted in
                    // the latest flight (protocol 1.12; a 1.11 board only has throws).
                    let fitted =
                        identification.is_some_and(|i| i.imu_offset_status_fitted_in_flight);
                    if let Some(offset) = map.get_mut("imu_offset").and_then(Value::as_object_mut) {
                        offset.insert(
                            "source".into(),
                            json!(if fitted { "fitted_in_flight" } else { "throws" }),
                        );
                    }
                    if let Some(config) = &config {
                        map.insert("config".into(), report::config_json(config));
                    }
                    if let Some(flight) = &flight {
                        map.insert("flight".into(), report::flight_json(flight));
                    }
                }
                format!("{value:#}\n")
            } else {
                let mut text = report::status_text(&status, stored);
                if let Some(health) = &health {
                    text.push_str(&report::health_text(health));
                }
                if let Some(battery) = &battery {
                    text.push_str(&report::battery_text(battery));
                }
                if let Some(learner) = &learner {
                    text.push_str(&report::learner_text(learner));
                }
                if let Some(identification) = &identification {
                    text.push_str(&report::identification_text(identification));
                }
                if let Some(flight) = &flight {
                    text.push_str(&report::flight_text(flight));
                }
                if let Some(config) = &config {
                    text.push_str(&report::config_text(config));
                }
                text
            })
        }
        BoardCommand::Doctor { yes } => doctor(client, yes, cli.json),
        BoardCommand::Arm => {
            client.request(&Request::ArmThrowToFly(()), "the arm request")?;
            eprintln!(
                "WARNING: armed for throw-to-fly: the motors WILL SPIN after the next throw. \
                 Keep clear of the propellers; stop them at any time with `configurator-cli disarm`."
            );
            // Which identification the board runs: one image has both (issue 56), the
            // parameter `motor_bidir_dshot` chooses.
            let from_commands = configurator_cli::doctor::speed_reports_off(client)?;
            let (identification, how) = if from_commands {
                (
                    "commands",
                    "the motors identified from the commands and the body's response \
                     (motor_bidir_dshot = 0: ESCs without speed telemetry)",
                )
            } else {
                ("speeds", "the motors identified from their speed reports (motor_bidir_dshot = 1)")
            };
            Ok(if cli.json {
                format!("{:#}\n", json!({"armed": true, "identification": identification}))
            } else {
                format!("armed for throw-to-fly: {how}\n")
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
        BoardCommand::Land { follow_timeout_s } => land(client, follow_timeout_s, cli.json),
        BoardCommand::Stream { topic, rate_hz, duration_s } => {
            stream(client, topic, rate_hz, duration_s, cli.json)
        }
        BoardCommand::Record { topics, duration_s, output } => {
            record(client, &topics, duration_s, &output, cli.json)
        }
        BoardCommand::Get(name) => {
            let info = config::fetch(client, protocol::ParamRef::Name(protocol::text(&name)))?;
            Ok(if cli.json {
                format!("{:#}\n", param_json(&info))
            } else {
                config::describe(&info)
            })
        }
        BoardCommand::Set { name, values } => {
            let info = config::set(client, &name, &values)?;
            Ok(if cli.json {
                format!("{:#}\n", param_json(&info))
            } else {
                format!(
                    "{} = {} (not saved: `save` stores it)\n",
                    info.name,
                    config::format_values(&info.value)
                )
            })
        }
        BoardCommand::Dump | BoardCommand::Diff => {
            let only_changed = matches!(command, BoardCommand::Diff);
            let params = config::fetch_all(client)?;
            if cli.json {
                let list: Vec<_> = params
                    .iter()
                    .filter(|p| !only_changed || p.value != p.default)
                    .map(param_json)
                    .collect();
                return Ok(format!("{:#}\n", json!(list)));
            }
            let header = format!(
                "{} of {} {} (firmware {}.{}.{}), {} parameters",
                if only_changed { "diff" } else { "dump" },
                client.info.board,
                client.info.serial,
                client.info.firmware.major,
                client.info.firmware.minor,
                client.info.firmware.patch,
                params.len()
            );
            Ok(config::listing(&params, only_changed, &header))
        }
        BoardCommand::Save => {
            client.set_timeout(SAVE_TIMEOUT);
            let reply = client.request(&Request::SaveConfig(()), "the save request");
            client.set_timeout(configurator_cli::link::DEFAULT_TIMEOUT);
            let status = config_reply(reply?)?;
            Ok(if cli.json {
                format!("{:#}\n", report::config_json(&status))
            } else {
                format!("saved to flash ({} saves since start-up)\n", status.saves)
            })
        }
        BoardCommand::Defaults => {
            let status =
                config_reply(client.request(&Request::ResetConfig(()), "the defaults request")?)?;
            Ok(if cli.json {
                format!("{:#}\n", report::config_json(&status))
            } else {
                "every parameter is at its default (not saved: `save` stores it)\n".into()
            })
        }
        BoardCommand::Version => {
            let info = &client.info;
            Ok(if cli.json {
                format!(
                    "{:#}\n",
                    json!({
                        "configurator": env!("CARGO_PKG_VERSION"),
                        "firmware": format!("{}.{}.{}", info.firmware.major, info.firmware.minor, info.firmware.patch),
                        "board_protocol": format!("{}.{}", info.protocol.major, info.protocol.minor),
                        "configurator_protocol": format!("{}.{}", protocol::PROTOCOL_VERSION.major, protocol::PROTOCOL_VERSION.minor),
                    })
                )
            } else {
                format!(
                    "configurator {} (protocol {}.{}); board {} firmware {}.{}.{} (protocol {}.{})\n",
                    env!("CARGO_PKG_VERSION"),
                    protocol::PROTOCOL_VERSION.major,
                    protocol::PROTOCOL_VERSION.minor,
                    info.board,
                    info.firmware.major,
                    info.firmware.minor,
                    info.firmware.patch,
                    info.protocol.major,
                    info.protocol.minor
                )
            })
        }
        BoardCommand::Pair { forget } => pair(client, forget, cli.json),
        BoardCommand::PoseRelay { listen, frame, rate_hz, duration_s } => {
            use configurator_cli::pose_relay;
            eprintln!(
                "relaying poses ({frame:?} axes) from {listen} to the board, at most {rate_hz} Hz…"
            );
            let duration = duration_s.map(Duration::from_secs_f64);
            let summary = pose_relay::run(client, listen, frame, rate_hz, duration, |so_far| {
                eprint!("\r{}", pose_relay::summary_text(so_far).trim_end());
            })
            .map_err(|e| match e {
                pose_relay::RelayError::Link(link) => Failure::from(link),
                other => Failure::Input(InputError(other.to_string())),
            })?;
            eprintln!();
            Ok(if cli.json {
                format!("{:#}\n", serde_json::to_value(&summary).unwrap_or_default())
            } else {
                pose_relay::summary_text(&summary)
            })
        }
        BoardCommand::Security => {
            let security = link_security(client)?;
            Ok(if cli.json {
                format!("{:#}\n", report::link_security_json(&security, client.signs()))
            } else {
                report::link_security_text(&security, client.signs())
            })
        }
        BoardCommand::Reboot => {
            client.request(&Request::Reboot(()), "the reboot request")?;
            eprintln!("the board is restarting…");
            *client = reconnect(client, target)?;
            let origin = match client.request(&Request::GetConfig(()), "the configuration request")
            {
                Ok(Reply::Config(config)) => report::config_text(&config),
                _ => String::new(),
            };
            Ok(format!(
                "the board restarted{}",
                if origin.is_empty() { "\n".into() } else { format!("; {}", origin.trim_start()) }
            ))
        }
        BoardCommand::Dfu => {
            client.request(&Request::RebootToBootloader(()), "the bootloader request")?;
            Ok(if cli.json {
                format!("{:#}\n", json!({"bootloader": true}))
            } else {
                "the board restarts into its USB DFU bootloader (USB id 0483:df11); flash it with \
                 `cargo xtask flash --dfu`, or unplug it to start the firmware again\n"
                    .into()
            })
        }
        BoardCommand::Setpoint(setpoint) => {
            client.request(&Request::SetPositionSetpoint(setpoint), "the setpoint request")?;
            let [n, e, d] = setpoint.position_ned_m;
            let heading_deg = setpoint.heading_rad.to_degrees();
            Ok(if cli.json {
                format!(
                    "{:#}\n",
                    json!({"position_sp_ned_m": [n, e, d], "heading_sp_deg": heading_deg})
                )
            } else {
                format!(
                    "holding N {n:+.3} m, E {e:+.3} m, D {d:+.3} m, heading {heading_deg:+.1}° \
                     whenever an external pose arrives\n"
                )
            })
        }
        BoardCommand::Apply { file, text } => {
            let before = config::fetch_all(client)?;
            let batch = config::parse_apply(&text, &before)
                .map_err(|e| Failure::Input(InputError(format!("apply {file}: {e}"))))?;
            let changed = config::apply(client, &batch, &before).map_err(|e| {
                Failure::Connect(ConnectError::Link(LinkError::Unexpected(format!(
                    "apply {file}: {e}"
                ))))
            })?;
            Ok(format!(
                "applied {} lines from {file} ({changed} values changed; not saved: `save` stores them)\n",
                batch.len()
            ))
        }
        BoardCommand::Calibrate { yes, max_throws, timeout_s } => {
            calibrate_imu_offset(client, yes, max_throws, timeout_s, cli.json)
        }
        BoardCommand::CompassCalibrate { duration_s } => {
            configurator_cli::compass::calibrate(client, duration_s, cli.json)
                .map_err(Failure::from)
        }
        BoardCommand::Identify { yes, options, record } => {
            identify(client, yes, options, record.as_deref(), cli.json)
        }
        BoardCommand::MotorTest { motor, command, duration_s, yes } => {
            motor_test(client, motor, command, duration_s, yes)
        }
        BoardCommand::Esc { command, motor } => esc_command(client, command, motor),
        BoardCommand::LogList => {
            let files = log_files::list_with_durations(client)?;
            Ok(if cli.json {
                format!("{:#}\n", log_files::list_json(&files))
            } else {
                log_files::list_text(&files)
            })
        }
        BoardCommand::LogDownload { number, file, resume } => {
            log_download(client, number, &file, resume, cli.json)
        }
        BoardCommand::LogDelete(number) => {
            log_files::delete(client, number)?;
            Ok(if cli.json {
                format!("{:#}\n", json!({"deleted": number}))
            } else {
                format!("deleted log {number}\n")
            })
        }
        BoardCommand::Shell => shell(cli, client, target),
    }
}

/// How long a save may take on the board (a sector erase is about 2 s), before giving up.
const SAVE_TIMEOUT: Duration = Duration::from_secs(6);

fn config_reply(reply: Reply) -> Result<protocol::ConfigStatus, Failure> {
    match reply {
        Reply::Config(status) => Ok(status),
        other => Err(LinkError::Unexpected(format!("{other:?} to a configuration request")).into()),
    }
}

fn param_json(info: &protocol::ParamInfo) -> serde_json::Value {
    json!({
        "name": info.name.as_str(),
        "value": info.value.as_slice(),
        "default": info.default.as_slice(),
        "unit": info.unit.as_str(),
        "min": info.min,
        "max": info.max,
        "kind": format!("{:?}", info.kind).to_lowercase(),
        "learned": info.learned,
        "help": info.help.as_str(),
    })
}

/// Ask a yes/no question on the terminal; `false` without one (scripts use `--yes`).
fn confirm(question: &str) -> bool {
    ask(question).unwrap_or(false)
}

/// Ask a yes/no question on the terminal: the answer, or `None` without a terminal to ask.
fn ask(question: &str) -> Option<bool> {
    use std::io::IsTerminal as _;
    if !std::io::stdin().is_terminal() {
        eprintln!("{question} [y/N] (no terminal to ask: use --yes)");
        return None;
    }
    eprint!("{question} [y/N] ");
    let mut answer = String::new();
    let _ = std::io::stdin().read_line(&mut answer);
    Some(matches!(answer.trim(), "y" | "Y" | "yes" | "Yes"))
}

/// How long `calibrate imu-offset` keeps watching the board's estimate after the last throw it
/// allows, for the rest after the catch (wall-clock). The board counts a rest once the hand has
/// settled (about 0.3 s after a catch) and five 50 ms blocks have been still (the first and the
/// last are dropped: `imu_offset::MIN_POSE_BLOCKS` + 2): about 0.6 s after the catch. A
/// person told to hold the craft still for a second has done so well within 3 s.
const REST_AFTER_LAST_CATCH: Duration = Duration::from_secs(3);

/// How often the guided calibration asks for the board's status between throws: the estimate
/// follows each 50 ms block of rest (`imu_offset::REST_BLOCK_S`), so 10 Hz sees it change
/// without loading the link.
const CALIBRATION_POLL: Duration = Duration::from_millis(100);

/// The guided IMU-offset calibration: start, report each throw, ask, store.
///
/// Each throw is reported as the board accepts it, at the catch. The rest that follows (the craft
/// held still in a new attitude) tells an accelerometer bias from the offset, which two throws at
/// the same spin rate alone cannot along the cross product of their axes; the board's estimate
/// follows the rest, so between throws (and for [`REST_AFTER_LAST_CATCH`] after the last) the
/// board's status is watched, and the calibration concludes as soon as the estimate is well
/// determined.
fn calibrate_imu_offset(
    client: &mut Client,
    yes: bool,
    max_throws: u8,
    timeout_s: f64,
    json_output: bool,
) -> Result<String, Failure> {
    client.request(&Request::StartCalibration(()), "the calibration request")?;
    client.events.clear();
    eprintln!(
        "calibrating the IMU offset: throw the craft about 1 m up, spinning (about two turns per \
         second, a different axis each time), catch it, and hold it still for a second between \
         throws. Up to {max_throws} throws; Ctrl-C stops."
    );
    let mut last: Option<protocol::ImuOffsetStatus> = None;
    let mut throws = 0u8;
    let mut waited = std::time::Instant::now();
    let stop = |client: &mut Client, accept: bool| {
        let request = Request::StopCalibration(protocol::StopCalibration { accept });
        client.request(&request, "the request to end the calibration")
    };
    loop {
        let resting_after_last = throws >= max_throws;
        if resting_after_last && waited.elapsed() > REST_AFTER_LAST_CATCH {
            break;
        }
        if !resting_after_last && waited.elapsed().as_secs_f64() > timeout_s {
            let _ = stop(client, false);
            return Err(LinkError::Unexpected(format!(
                "no throw seen for {timeout_s} s; calibration stopped, nothing stored"
            ))
            .into());
        }
        client.listen(CALIBRATION_POLL)?;
        while let Some(event) = client.events.pop_front() {
            let protocol::Event::CalibrationThrow(throw) = event else { continue };
            throws = throw.estimate.throws;
            waited = std::time::Instant::now();
            eprintln!("{}", report::calibration_throw_text(&throw));
            last = Some(throw.estimate);
        }
        if last.is_some_and(|t| t.well_determined) {
            break;
        }
        if throws > 0 {
            // The rest after the catch: the board's estimate follows it.
            let Reply::Status(status) = client.request(&Request::GetStatus(()), "the status")?
            else {
                continue;
            };
            let estimate = status.imu_offset;
            if estimate.throws == throws && estimate.well_determined {
                eprintln!("{}", report::calibration_rest_text(&estimate));
                last = Some(estimate);
                break;
            }
        }
    }
    let Some(result) = last.filter(|t| t.well_determined) else {
        let _ = stop(client, false);
        return Err(LinkError::Unexpected(format!(
            "the offset is not well determined after {throws} throws; nothing stored (run the \
             calibration again, following the advice)"
        ))
        .into());
    };
    if !yes && !confirm("store this IMU offset in the board's parameters?") {
        stop(client, false)?;
        return Ok("calibration ended; nothing stored\n".into());
    }
    // The board stores its estimate with the accelerometer bias fitted with it, added to the
    // bias parameter: the difference is the bias this calibration found.
    let bias_ref = || protocol::ParamRef::Name(protocol::text("acc_bias_mps2"));
    let bias_before = config::fetch(client, bias_ref())?.value;
    let status = config_reply(stop(client, true)?)?;
    let bias_after = config::fetch(client, bias_ref())?.value;
    let acc_bias_mps2: Vec<f32> =
        bias_after.iter().zip(bias_before.iter()).map(|(a, b)| a - b).collect();
    let r_mm = result.r_imu_m.map(|x| 1000.0 * x);
    let axes_mm = result.ci95_semi_axes_m.map(|x| 1000.0 * x);
    Ok(if json_output {
        format!(
            "{:#}\n",
            json!({
                "stored": true,
                "throws": result.throws,
                "r_imu_mm": r_mm,
                "ci95_semi_axes_mm": axes_mm,
                "acc_bias_mps2": acc_bias_mps2,
                "unsaved_changes": status.unsaved_changes,
            })
        )
    } else {
        format!(
            "stored: IMU offset ({:+.2}, {:+.2}, {:+.2}) mm, 95 % semi-axes {:.2}, {:.2}, {:.2} mm \
             (not saved: `save` writes it to flash)\n",
            r_mm[0], r_mm[1], r_mm[2], axes_mm[0], axes_mm[1], axes_mm[2]
        )
    })
}

/// The guided throw-and-fly identification: confirm, arm, follow, show the model in units.
fn identify(
    client: &mut Client,
    yes: bool,
    options: configurator_cli::identify::IdentifyOptions,
    record_to: Option<&std::path::Path>,
    json_output: bool,
) -> Result<String, Failure> {
    use configurator_cli::identify::{self as id, IdentifyError};
    use configurator_cli::record::Recorder;
    if !yes
        && !confirm(
            "IDENTIFY: the motors WILL SPIN after the next throw. Propellers on, area clear, ready to throw?",
        )
    {
        return Ok("identification cancelled: nothing armed\n".into());
    }
    let mut recorder = match record_to {
        Some(path) => {
            let file = std::fs::File::create(path).map_err(|e| {
                Failure::Input(InputError(format!(
                    "--record: cannot create {}: {e}",
                    path.display()
                )))
            })?;
            let topics = [protocol::Topic::Learner, protocol::Topic::State];
            let writer = std::io::BufWriter::new(file);
            Some(Recorder::new(writer, &topics, client.info.motor_count).map_err(|e| {
                Failure::Input(InputError(format!("--record: {}: {e}", path.display())))
            })?)
        }
        None => None,
    };
    let mut write_error = None;
    let mut on_sample = |sample: &configurator_cli::link::TelemetrySample| {
        if let Some(recorder) = recorder.as_mut() {
            if let Err(e) = recorder.push(sample) {
                write_error.get_or_insert(e);
            }
        }
    };
    let found = id::identify(client, options, &mut |line| eprintln!("{line}"), &mut on_sample);
    if let (Some(recorder), Some(path)) = (recorder, record_to) {
        let summary = recorder.summary();
        match recorder.finish().err().or(write_error) {
            Some(e) => eprintln!("warning: the recording {} is incomplete: {e}", path.display()),
            None => eprintln!(
                "recorded {} rows ({} samples missing) to {}",
                summary.rows,
                summary.gaps(),
                path.display()
            ),
        }
    }
    let found = match found {
        Ok(found) => found,
        Err(IdentifyError::Link(error)) => return Err(error.into()),
        Err(IdentifyError::Landing(configurator_cli::land::LandError::Link(error))) => {
            return Err(error.into())
        }
        Err(IdentifyError::Landing(error)) => return Err(Failure::Checks(error.to_string())),
        Err(error) => return Err(LinkError::Unexpected(error.to_string()).into()),
    };
    let [force, rotation] = &found.blocks;
    let stored = found.config.is_some_and(|c| c.unsaved_changes);
    if json_output {
        let mut value = report::learner_json(force);
        if let Some(map) = value.as_object_mut() {
            map.insert("g1_per_unit_thrust".into(), report::g1_json(force, rotation));
            map.insert("flew".into(), json!(found.flew));
            map.insert("disarmed".into(), json!(found.disarmed));
            map.insert(
                "landing".into(),
                found.landing.as_ref().map_or(json!(null), configurator_cli::land::Landing::json),
            );
            map.insert("flight".into(), found.flight.as_ref().map_or(json!(null), |f| f.json()));
            map.insert("stored_in_parameters".into(), json!(stored));
        }
        return Ok(format!("{value:#}\n"));
    }
    let mut out = String::from("learned model:\n");
    out.push_str(&report::learner_text(force));
    out.push_str(&report::g1_text(force, rotation));
    out.push_str(if stored {
        "stored in the parameters (not saved: `save` writes them to flash; `diff` shows them)\n"
    } else {
        "the parameters did not change (the board stores a model only with a hover thrust axis)\n"
    });
    if found.flew && !found.disarmed {
        out.push_str("the craft is flying on the learned model: `configurator-cli disarm` stops the motors\n");
    }
    Ok(out)
}

/// `land`: the request, then (unless `follow_timeout_s` is `None`) the landing followed to the
/// disarm, its progress on stderr.
fn land(
    client: &mut Client,
    follow_timeout_s: Option<f64>,
    json_output: bool,
) -> Result<String, Failure> {
    use configurator_cli::land;
    let before = land::request_landing(client)?;
    let Some(timeout_s) = follow_timeout_s else {
        let flying = before.mode != protocol::FlightMode::Off;
        return Ok(if json_output {
            format!("{:#}\n", json!({"land_requested": true, "was_flying": flying}))
        } else if flying {
            "landing requested: the craft descends and disarms at the touchdown\n".into()
        } else {
            "land requested: nothing was flying, so the motors stop at once\n".into()
        });
    };
    let say = &mut |line| eprintln!("{line}");
    match land::follow_landing(client, before, timeout_s, say, &mut |_| {}) {
        Ok(landing) if json_output => Ok(format!("{:#}\n", landing.json())),
        Ok(landing) => Ok(landing.text()),
        Err(land::LandError::Link(error)) => Err(error.into()),
        // Not a link failure: the board answers, the craft is still armed (exit code 1).
        Err(error) => Err(Failure::Checks(error.to_string())),
    }
}

/// `--timeout-s` of `land` and `identify`: a finite time from 1 s to an hour.
fn check_timeout_s(timeout_s: f64) -> Result<(), Failure> {
    if timeout_s.is_finite() && (1.0..=3600.0).contains(&timeout_s) {
        return Ok(());
    }
    Err(Failure::Input(InputError(format!("--timeout-s {timeout_s} is outside 1 to 3600 s"))))
}

/// The bring-up check: each line printed as it is done (text), or all of them as one JSON array;
/// exit code 1 (through the error) when any line fails.
fn doctor(client: &mut Client, yes: bool, json_output: bool) -> Result<String, Failure> {
    use configurator_cli::doctor::{self, Consent};
    eprintln!("checking the board: keep the craft still on a bench, motors stopped…");
    let mut report = |line: &doctor::Line| {
        if !json_output {
            print!("{}", line.text());
            let _ = std::io::stdout().flush();
        }
    };
    let mut consent = || {
        if yes {
            return Consent::Yes;
        }
        match ask(
            "SPIN TEST: each motor spins in turn at 8 % for a second. Are the propellers OFF?",
        ) {
            Some(true) => Consent::Yes,
            Some(false) => Consent::No,
            None => Consent::NoTerminal,
        }
    };
    let lines = doctor::run(client, &mut report, &mut consent)?;
    if json_output {
        let list: Vec<_> = lines.iter().map(doctor::Line::json).collect();
        println!("{:#}", json!(list));
    }
    let failed: Vec<&str> = lines.iter().filter(|l| !l.ok()).map(|l| l.name).collect();
    if failed.is_empty() {
        eprintln!("all checks passed");
        return Ok(String::new());
    }
    Err(Failure::Checks(format!(
        "{} of {} checks failed: {}",
        failed.len(),
        lines.len(),
        failed.join(", ")
    )))
}

/// Spin one motor for `duration_s`, keeping it alive every 0.5 s; the board stops it 3 s after
/// the last keep-alive, so a configurator that dies cannot leave it spinning.
fn motor_test(
    client: &mut Client,
    motor: u8,
    command: f32,
    duration_s: f64,
    yes: bool,
) -> Result<String, Failure> {
    if !yes && !confirm("MOTOR TEST: are the propellers OFF?") {
        return Ok("motor test cancelled: nothing spun\n".into());
    }
    let request = Request::MotorTest(protocol::MotorTest { motor, command });
    let started = std::time::Instant::now();
    eprintln!(
        "spinning motor {motor} at {command} for {duration_s} s (Ctrl-C stops it within 3 s)"
    );
    while started.elapsed().as_secs_f64() < duration_s {
        client.request(&request, "the motor test request")?;
        client.listen(Duration::from_millis(500).min(Duration::from_secs_f64(
            (duration_s - started.elapsed().as_secs_f64()).max(0.0),
        )))?;
    }
    client.request(&Request::Disarm(()), "the request to stop the motor")?;
    Ok(format!("motor {motor} stopped after {:.1} s\n", started.elapsed().as_secs_f64()))
}

/// Send one ESC command; says which motors it went to and what an ESC does with it.
fn esc_command(
    client: &mut Client,
    command: protocol::DshotCommand,
    motor: Option<u8>,
) -> Result<String, Failure> {
    let request = Request::EscCommand(protocol::EscCommand {
        motor: motor.unwrap_or(protocol::ESC_ALL_MOTORS),
        command: command.value() as u8,
    });
    client.request(&request, "the ESC command")?;
    let to = match motor {
        Some(m) => format!("motor {m}'s ESC"),
        None => "every ESC".to_string(),
    };
    let note = if command.changes_settings() {
        format!(" ({} frames in a row, as the DShot specification asks)", command.min_repeats())
    } else {
        String::new()
    };
    Ok(format!("sent {} (DShot command {}) to {to}{note}\n", command.name(), command.value()))
}

/// Close `client` and open the board again once it has restarted; says so.
fn reconnect(client: &mut Client, target: &Target) -> Result<Client, Failure> {
    let port = client.port().to_string();
    client.close();
    let (new, took) =
        configurator_cli::connect::reconnect(target, configurator_cli::connect::RECONNECT_TIMEOUT)
            .map_err(Failure::Connect)?;
    eprintln!(
        "reconnected to {} {} on {} after {:.1} s{}",
        new.info.board,
        new.info.serial,
        new.port(),
        took.as_secs_f64(),
        if new.port() == port { String::new() } else { format!(" (was {port})") }
    );
    Ok(new)
}

/// A failure in words.
fn failure_text(failure: &Failure) -> String {
    match failure {
        Failure::Input(error) => error.to_string(),
        Failure::Connect(error) => error.to_string(),
        Failure::Checks(message) => message.clone(),
    }
}

/// The interactive shell on a connected board.
fn shell(cli: &Cli, client: &mut Client, target: &Target) -> Result<String, Failure> {
    use configurator_cli::shell::{self as sh, CommandHelp, Next, Vocabulary};
    let parameters = config::fetch_all(client)?.iter().map(|p| p.name.to_string()).collect();
    let commands = SHELL_COMMANDS
        .iter()
        .map(|&(name, usage, help)| CommandHelp { name, usage, help })
        .collect();
    let vocabulary = Vocabulary::new(commands, parameters);
    eprintln!(
        "connected to {} {}; `help` lists the commands, Tab completes, Ctrl-D leaves",
        client.info.board, client.info.serial
    );
    let history = sh::default_history_path();
    let result = sh::run(&vocabulary, history.as_deref(), "fc> ", |words| {
        let args = std::iter::once("configurator-cli".to_string()).chain(words.iter().cloned());
        let parsed = match Cli::try_parse_from(args) {
            Ok(parsed) => parsed,
            Err(error) => {
                eprintln!("{}", error.render().to_string().trim_end());
                return Next::Continue;
            }
        };
        let outcome = match &parsed.command {
            Command::Shell => Err(Failure::Input(InputError("already in the shell".into()))),
            Command::Fit(_)
            | Command::Solve(_)
            | Command::Plot { .. }
            | Command::Ports
            | Command::Replay(_)
            | Command::Log(LogCommand::ToCsv(_) | LogCommand::ToMcap(_)) => run(&parsed),
            Command::Esc { command, .. } if command == "list" => Ok(esc_command_list()),
            other => match board_command(other) {
                Ok(command) => {
                    let cli = Cli { json: parsed.json || cli.json, ..parsed };
                    run_on_board(&cli, client, target, command)
                }
                Err(failure) => Err(failure),
            },
        };
        match outcome {
            Ok(text) => print!("{text}"),
            Err(Failure::Input(error)) => eprintln!("error: {error}"),
            Err(Failure::Checks(message)) => eprintln!("error: {message}"),
            Err(Failure::Connect(error)) => {
                eprintln!("error: {error}");
                // The board went away (unplugged, restarted by a button): find it again.
                if matches!(
                    error,
                    ConnectError::Link(LinkError::Closed { .. } | LinkError::Io { .. })
                ) {
                    eprintln!("the connection was lost; looking for the board again…");
                    match reconnect(client, target) {
                        Ok(new) => *client = new,
                        Err(error) => eprintln!("error: {}", failure_text(&error)),
                    }
                }
            }
        }
        Next::Continue
    });
    result.map_err(|e| LinkError::Unexpected(format!("the shell's terminal failed: {e}")))?;
    Ok(String::new())
}

/// The shell's commands: name, usage, help.
const SHELL_COMMANDS: &[(&str, &str, &str)] = &[
    ("get", "get NAME", "print a parameter: value, unit, range, default"),
    ("set", "set NAME = VALUE", "set a parameter (arrays comma-separated); `save` stores it"),
    ("dump", "dump", "every parameter as set lines"),
    ("diff", "diff", "the parameters not at their default"),
    ("save", "save", "write the parameters to flash"),
    ("defaults", "defaults", "every parameter back to its default (not saved)"),
    ("apply", "apply FILE", "apply a dump or diff file as one batch"),
    ("status", "status", "the board's state, the IMU offset and the identification"),
    ("info", "info", "the board's identity and status"),
    ("doctor", "doctor [--yes]", "bring-up check: IMU, flash, receiver, ESCs, each motor spun"),
    ("version", "version", "firmware and configurator versions"),
    ("calibrate", "calibrate imu-offset [--yes]", "guided IMU-offset calibration"),
    (
        "identify",
        "identify [--disarm-after-s 5 | --land-after-s 5]",
        "throw-and-fly: learn the motors and fly",
    ),
    ("record", "record --topic state --duration-s 10 FILE.csv", "record telemetry to CSV"),
    ("motor-test", "motor-test --motor N [--command 0.1]", "spin one motor (propellers off!)"),
    ("esc", "esc beep1 [--motor N] | esc list", "send an ESC command (beep, direction, save)"),
    ("stream", "stream --topic imu [--rate-hz 500]", "stream a telemetry topic, count gaps"),
    ("arm-throw-to-fly", "arm-throw-to-fly", "the motors spin after the next throw"),
    ("disarm", "disarm", "stop every motor now"),
    ("land", "land [--no-wait] [--timeout-s 120]", "descend, touch down, disarm; follow it down"),
    ("reboot", "reboot", "restart the board"),
    ("dfu", "dfu", "restart into the USB DFU bootloader (firmware update)"),
    ("setpoint", "setpoint --north-m N --east-m E --down-m D", "where to hold with a pose"),
    ("plot", "plot FILE.csv -o OUT.png", "render a recording"),
    ("log", "log list | log download N FILE [--resume] | log delete N", "the board's flight logs"),
];

/// `log download`: the file with a progress bar (bytes, rate, time left) on stderr, then what
/// was downloaded.
fn log_download(
    client: &mut Client,
    number: u32,
    file: &std::path::Path,
    resume: bool,
    json_output: bool,
) -> Result<String, Failure> {
    use log_files::{DownloadError, Progress};
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "log {msg} {bar:30} {bytes}/{total_bytes} {bytes_per_sec} {eta} left",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(number.to_string());
    let downloaded =
        log_files::download(client, number, file, resume, &mut |progress| match progress {
            Progress::Total { bytes, done } => {
                bar.set_length(bytes);
                bar.set_position(done);
                bar.reset_eta();
            }
            Progress::Done { bytes } => bar.set_position(bytes),
        });
    bar.finish_and_clear();
    let downloaded = downloaded.map_err(|error| match error {
        DownloadError::Link(link) => Failure::from(link),
        other => Failure::Input(InputError(other.to_string())),
    })?;
    let fetched = downloaded.size_bytes - downloaded.resumed_from;
    let rate_kbps = fetched as f64 / 1000.0 / downloaded.seconds.max(1e-9);
    if downloaded.still_writing {
        eprintln!(
            "warning: log {number} is still being written; {} holds its first {} bytes",
            file.display(),
            downloaded.size_bytes
        );
    }
    Ok(if json_output {
        format!(
            "{:#}\n",
            json!({
                "number": number,
                "file": file.display().to_string(),
                "size_bytes": downloaded.size_bytes,
                "resumed_from": downloaded.resumed_from,
                "seconds": downloaded.seconds,
                "kb_per_s": rate_kbps,
                "retries": downloaded.retries,
                "complete": !downloaded.still_writing,
            })
        )
    } else {
        let resumed = if downloaded.resumed_from > 0 {
            format!(" (resumed at byte {})", downloaded.resumed_from)
        } else {
            String::new()
        };
        format!(
            "log {number} → {}: {} bytes{resumed} in {:.2} s ({rate_kbps:.0} kB/s, {} chunks asked again)\n",
            file.display(),
            downloaded.size_bytes,
            downloaded.seconds,
            downloaded.retries
        )
    })
}

fn plot(
    input: &std::path::Path,
    output: &std::path::Path,
    json_output: bool,
) -> Result<String, Failure> {
    let plot_error = |e| Failure::Input(InputError(format!("plot: {e}")));
    if input.extension().is_some_and(|ext| ext == "json") {
        configurator_cli::plot::plot_fit(input, output).map_err(plot_error)?;
        return Ok(if json_output {
            format!(
                "{:#}\n",
                json!({"output": output.display().to_string(), "panels": ["xy", "xz", "yz"]})
            )
        } else {
            format!(
                "wrote {} (the 95 % ellipsoid projected on the xy, xz and yz planes)\n",
                output.display()
            )
        });
    }
    let summary = configurator_cli::plot::plot_recording(input, output).map_err(plot_error)?;
    Ok(if json_output {
        format!(
            "{:#}\n",
            json!({
                "output": output.display().to_string(),
                "panels": summary.panels,
                "samples": summary.samples,
                "axes": summary.axes.iter().map(|a| json!({
                    "panel": a.title,
                    "y_min": a.y_range.start,
                    "y_max": a.y_range.end,
                    "clipped_samples": a.clipped_samples,
                    "legend_entries": a.legend_entries,
                })).collect::<Vec<_>>(),
            })
        )
    } else {
        format!(
            "wrote {} ({} samples; panels: {})\n",
            output.display(),
            summary.samples,
            summary.panels.join(", ")
        )
    })
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
                report::well_determined_text(offset.ci95_semi_axes_m[0])
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

/// The IMU offset a calibration stored (`imu_offset_m` while `imu_offset_valid` is 1), or
/// `None` (nothing stored, or a board without the parameters).
fn fetch_stored_offset(client: &mut Client) -> Result<Option<[f32; 3]>, Failure> {
    let mut param = |name: &str| -> Result<Option<Vec<f32>>, Failure> {
        let request = Request::GetParam(protocol::ParamRef::Name(protocol::text(name)));
        match client.request(&request, "the parameter request") {
            Ok(Reply::Param(info)) => Ok(Some(info.value.to_vec())),
            Ok(_) | Err(LinkError::Device(_)) => Ok(None),
            Err(error) => Err(error.into()),
        }
    };
    if param("imu_offset_valid")?.as_deref() != Some(&[1.0]) {
        return Ok(None);
    }
    Ok(param("imu_offset_m")?.and_then(|v| <[f32; 3]>::try_from(v.as_slice()).ok()))
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

/// A request a board of an older protocol may not know: `None` when it answers
/// `UnknownRequest`.
fn fetch_optional(
    client: &mut Client,
    request: Request,
    what: &'static str,
) -> Result<Option<Reply>, Failure> {
    match client.request(&request, what) {
        Ok(reply) => Ok(Some(reply)),
        Err(LinkError::Device(DeviceErrorText(protocol::DeviceError::UnknownRequest {
            ..
        }))) => Ok(None),
        Err(error) => Err(error.into()),
    }
}

/// The flight battery, or `None` from a board that measures none (`Unsupported`) or predates
/// protocol 1.11.
fn fetch_battery(client: &mut Client) -> Result<Option<protocol::BatteryStatus>, Failure> {
    match client.request(&Request::GetBattery(()), "the battery request") {
        Ok(Reply::Battery(battery)) => Ok(Some(battery)),
        Ok(_)
        | Err(LinkError::Device(DeviceErrorText(
            protocol::DeviceError::Unsupported | protocol::DeviceError::UnknownRequest { .. },
        ))) => Ok(None),
        Err(error) => Err(error.into()),
    }
}

fn stream_arguments(topic: &str, rate_hz: u16, duration_s: f64) -> Result<Topic, InputError> {
    let topic = configurator_cli::record::parse_topic(topic).map_err(InputError)?;
    if !(1..=protocol::MAX_TELEMETRY_RATE_HZ).contains(&rate_hz) {
        return Err(InputError(format!(
            "--rate-hz {rate_hz} is outside 1 to {} Hz",
            protocol::MAX_TELEMETRY_RATE_HZ
        )));
    }
    check_duration(duration_s)?;
    Ok(topic)
}

/// A listening time between 0.1 s and one hour.
fn check_duration(duration_s: f64) -> Result<(), InputError> {
    if !(duration_s.is_finite() && (0.1..=3600.0).contains(&duration_s)) {
        return Err(InputError(format!("--duration-s {duration_s} is outside 0.1 to 3600 s")));
    }
    Ok(())
}

/// Record topics to a CSV file; the file is created only once the board is connected.
fn record(
    client: &mut Client,
    topics: &[Topic],
    duration_s: f64,
    output: &std::path::Path,
    json_output: bool,
) -> Result<String, Failure> {
    use configurator_cli::record::{self, RecordError};
    let file = std::fs::File::create(output).map_err(|e| {
        Failure::Input(InputError(format!("record: cannot create {}: {e}", output.display())))
    })?;
    let names: Vec<&str> = topics.iter().map(|&t| record::topic_name(t)).collect();
    eprintln!("recording {} for {duration_s} s into {}…", names.join(", "), output.display());
    let duration = Duration::from_secs_f64(duration_s);
    let (summary, bytes) =
        match record::record(client, topics, duration, std::io::BufWriter::new(file)) {
            Ok(done) => done,
            Err(RecordError::Link(error)) => return Err(error.into()),
            Err(RecordError::Write(error)) => {
                return Err(LinkError::Unexpected(format!(
                    "record: writing {}: {error}",
                    output.display()
                ))
                .into())
            }
        };
    let bytes_per_s = bytes as f64 / duration_s;
    if json_output {
        let topics: Vec<_> = summary
            .topics
            .iter()
            .map(|c| {
                json!({"topic": record::topic_name(c.topic), "received": c.received, "gaps": c.gaps})
            })
            .collect();
        return Ok(format!(
            "{:#}\n",
            json!({
                "output": output.display().to_string(),
                "rows": summary.rows,
                "span_s": summary.span_s,
                "gaps": summary.gaps(),
                "topics": topics,
                "bytes": bytes,
                "bytes_per_s": bytes_per_s,
                "bad_frames": client.bad_frames,
            })
        ));
    }
    let mut out = format!(
        "wrote {}: {} rows over {:.3} s of board time; {:.0} kB/s received\n",
        output.display(),
        summary.rows,
        summary.span_s,
        bytes_per_s / 1000.0
    );
    for count in &summary.topics {
        out.push_str(&format!(
            "  {}: {} samples, {} missing\n",
            record::topic_name(count.topic),
            count.received,
            count.gaps
        ));
    }
    if summary.gaps() > 0 {
        out.push_str("  samples are missing: the link could not keep up (see the gaps above)\n");
    }
    Ok(out)
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
    // The board grants what its link carries (a radio's byte budget), or the nearest rate a
    // per-step topic can send.
    let granted_hz = match client.request(&set(rate_hz), "the telemetry rate request")? {
        Reply::TelemetryRate(granted) => granted.rate_hz,
        _ => rate_hz,
    };
    let name = format!("{topic:?}").to_lowercase();
    if granted_hz == 0 {
        return Err(Failure::Input(InputError(format!(
            "the link has no room for the {name} topic (a slow radio already carrying other \
             topics?); stop them or ask a lower rate"
        ))));
    }
    if granted_hz < rate_hz {
        eprintln!(
            "streaming {name} at {granted_hz} Hz, the most this link carries (asked {rate_hz} Hz)"
        );
    }
    // Count as samples arrive (nothing is kept): only this topic, only from now on.
    client.telemetry.clear();
    let bytes_before = client.bytes_rx;
    let (mut received, mut gaps, mut previous_seq) = (0u64, 0u64, None::<u16>);
    let (mut first_t_us, mut last_t_us) = (None::<u64>, 0u64);
    let (mut last_imu, mut last_learner) = (None, None);
    // Learner samples are printed as they arrive, one line each (text or JSON).
    let mut stdout = std::io::stdout().lock();
    client.listen_with(Duration::from_secs_f64(duration_s), |sample| {
        if configurator_cli::record::topic_of(&sample.data) != topic {
            return;
        }
        received += 1;
        let t_us = configurator_cli::record::time_us(&sample.data);
        first_t_us.get_or_insert(t_us);
        last_t_us = t_us;
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
    let bytes_per_s = (client.bytes_rx - bytes_before) as f64 / duration_s;
    client.request(&set(0), "the request to stop telemetry")?;
    let achieved_hz = received as f64 / duration_s;
    let span_s = first_t_us.map_or(0.0, |first| (last_t_us - first) as f64 * 1e-6);
    if json_output {
        let summary = json!({
            "topic": format!("{topic:?}").to_lowercase(),
            "requested_rate_hz": rate_hz,
            "granted_rate_hz": granted_hz,
            "duration_s": duration_s,
            "received": received,
            "gaps": gaps,
            "received_rate_hz": achieved_hz,
            "board_time_span_s": span_s,
            "bytes_per_s": bytes_per_s,
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
        "{topic:?}: {received} samples in {duration_s:.1} s ({achieved_hz:.1} Hz of {rate_hz} Hz requested, {span_s:.3} s of board time), {gaps} missing, {} bad frames, {:.0} kB/s\n",
        client.bad_frames,
        bytes_per_s / 1000.0
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

/// `ports`: every serial port, and what it looks like by its USB IDs: our board, a USB-UART
/// bridge (a telemetry radio or adapter: give `--baud`), another USB device, or not USB.
fn ports(json_output: bool) -> Result<String, Failure> {
    use configurator_cli::connect::{port_kind, PortKind};
    let ports = serialport::available_ports().map_err(ConnectError::Enumerate)?;
    let rows: Vec<(String, PortKind)> =
        ports.iter().map(|port| (port.port_name.clone(), port_kind(&port.port_type))).collect();
    if json_output {
        let list: Vec<_> = rows
            .iter()
            .map(|(name, kind)| {
                let (vid, pid, chip) = match kind {
                    PortKind::Board => (Some(protocol::USB_VID), Some(protocol::USB_PID), None),
                    PortKind::UsbUart { chip, vid, pid } => (Some(*vid), Some(*pid), Some(*chip)),
                    PortKind::OtherUsb { vid, pid } => (Some(*vid), Some(*pid), None),
                    PortKind::NotUsb => (None, None, None),
                };
                json!({
                    "port": name,
                    "kind": kind.name(),
                    "vid": vid.map(|v| format!("{v:04x}")),
                    "pid": pid.map(|p| format!("{p:04x}")),
                    "chip": chip,
                    "description": kind.description(),
                })
            })
            .collect();
        return Ok(format!("{:#}\n", json!(list)));
    }
    if rows.is_empty() {
        return Ok("no serial ports found\n".into());
    }
    Ok(rows.iter().map(|(name, kind)| format!("{name}  {}\n", kind.description())).collect())
}
