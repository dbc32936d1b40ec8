//! `sitl`: run the flight-controller application on a simulated board and serve the protocol.
//!
//! ```text
//! cargo run -p sim --bin sitl -- --airframe paper-quad --pty-link /tmp/fc-sitl --tcp-port 5760
//! configurator-cli --port /tmp/fc-sitl info
//! ```
//!
//! `--throw-every-s 3 --throw-rate-dps 550,0,0 --throw-rate-dps 0,550,0 --acc-bias-mps2
//! 0.06,-0.05,0.06` throws the craft at the given body rates, in turn, with that accelerometer
//! bias (default: the airframe file's). `--throw-to-fly` arms the board for throw-to-fly at start; `--imu-offset-mm X,Y,Z` gives the
//! learner the IMU offset instead of the onboard estimate. The saved configuration lives in
//! `--flash-file PATH` (default: `sitl-flash.bin` in the user's data directory), so it survives
//! a restart of the SITL as a board's survives a power cycle. `--fault-esc-silent N`,
//! `--fault-imu silent|frozen|noisy`, `--fault-flash bad` and `--fault-motor-swap A,B` give the
//! simulated board a fault from power-up (`sim::faults::SitlFaults`), for
//! `configurator-cli doctor` to find. `--radio-baud 57600 [--radio-port PATH]` serves the
//! protocol also behind a simulated telemetry radio, on a second pseudo-terminal (linked at
//! PATH). Bad input exits with code 2.

use clap::Parser;
use sim::serve::parse_imu_offset_mm;
use sim::sitl::{Sitl, SitlConfig};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "Software-in-the-loop flight controller: firmware::app on a simulated board"
)]
struct Args {
    /// Airframe: a built-in name (paper-quad, racer-5in, quad-3in, hex-flat, hex-tilted,
    /// octo-flat) or a path to a TOML file.
    #[arg(long, default_value = "paper-quad")]
    airframe: String,
    /// Do not serve on a pseudo-terminal.
    #[arg(long)]
    no_pty: bool,
    /// Make this path a symlink to the pseudo-terminal.
    #[arg(long)]
    pty_link: Option<PathBuf>,
    /// Serve on TCP at 127.0.0.1 on this port (0 picks a free one).
    #[arg(long)]
    tcp_port: Option<u16>,
    /// Simulated seconds per wall-clock second.
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Throw the craft (spinning, 1 m up) and catch it every this many seconds, so the
    /// board's onboard IMU-offset estimate can be watched with `configurator-cli status`.
    #[arg(long)]
    throw_every_s: Option<f64>,
    /// Stop throwing after this many throws (default: keep throwing).
    #[arg(long, requires = "throw_every_s")]
    throws: Option<usize>,
    /// Body rate at release of the automatic throws, °/s, body axes, as `X,Y,Z`; repeat for the
    /// next throws (they cycle). Default: (700, 350, 180), (−180, 230, 700), (300, −650, 250).
    #[arg(long = "throw-rate-dps", value_name = "X,Y,Z", allow_hyphen_values = true,
          value_parser = parse_triple, requires = "throw_every_s")]
    throw_rates_dps: Vec<[f64; 3]>,
    /// The accelerometer's constant bias, m/s², IMU axes, as `X,Y,Z` (each within ±1), instead
    /// of the airframe file's.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_triple)]
    acc_bias_mps2: Option<[f64; 3]>,
    /// Arm the board for throw-to-fly at start: the first throw starts the motor excitation
    /// (as `ArmThrowToFly` over the protocol would).
    #[arg(long)]
    throw_to_fly: bool,
    /// Have the simulated hand throw the craft for flight (the seed paper's 3.5 m throw at
    /// (400, 400, 100) °/s) one second after the board is armed for throw-to-fly, and grip it
    /// again when the board disarms: `configurator-cli identify` then needs no person.
    #[arg(long)]
    hand_throws_to_fly: bool,
    /// IMU offset for the in-flight learner: the IMU's position relative to the centre of
    /// gravity, IMU axes, mm, as `X,Y,Z` (each within ±1000). Default: the onboard estimate.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_imu_offset_mm)]
    imu_offset_mm: Option<[f32; 3]>,
    /// Send the simulator's true pose to the firmware as motion capture would (by default
    /// 100 Hz, 1 mm and 0.1° noise, on time; see the --mocap-* options), so the craft holds a
    /// position after a throw-to-fly. Tell the firmware the latency and noise with its
    /// `pose_latency_s` and `pose_noise_m` parameters.
    #[arg(long)]
    mocap: bool,
    /// With --mocap: send the poses as UDP datagrams in the motion-capture line format to
    /// HOST:PORT instead (`configurator-cli pose-relay --listen HOST:PORT` forwards them to the
    /// board over a link, e.g. the simulated radio): docs/field.md.
    #[arg(long, value_name = "HOST:PORT", requires = "mocap")]
    mocap_udp: Option<std::net::SocketAddr>,
    #[command(flatten)]
    motion_capture: sim::recovery::MotionCaptureArgs,
    #[command(flatten)]
    gnss: sim::gnss::GnssArgs,
    /// A compass on the GNSS mast, drawn from --seed as the random world draws one (field,
    /// hard and soft iron, mounting, noise, the motors' interference: `sim::magnetometer`),
    /// calibrated by a simulated user's dance before start-up and read through its chip's
    /// registers by the firmware's compass service (`doctor` shows it).
    #[arg(long)]
    compass: bool,
    /// A steady wind for the whole run: the air's velocity north, east, down, m/s (e.g.
    /// `0,4,0`: 4 m/s blowing towards the east), each within ±20.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 3,
        allow_hyphen_values = true,
        value_name = "N,E,D"
    )]
    wind_ned_mps: Option<Vec<f64>>,
    /// The flash file holding the saved configuration (`save` writes it; created erased when
    /// missing). Default: sitl-flash.bin in the user's data directory.
    #[arg(long, value_name = "PATH")]
    flash_file: Option<PathBuf>,
    /// Run without a configuration store (nothing is saved).
    #[arg(long, conflicts_with = "flash_file")]
    no_flash: bool,
    /// A simulated pilot's radio (a CRSF receiver on the board's UART) playing this script of
    /// `TIME_S:EVENT` items, comma-separated, in simulated seconds since start; events: `arm`,
    /// `disarm`, `throw`, `throw-off` (the throw-to-fly switch), `kill`, `kill-off`, `lose`,
    /// `restore` (the link). Every switch starts off. E.g. `--rc 1:arm,1:throw,20:kill`.
    /// Default: no receiver.
    #[arg(long, value_name = "SCRIPT", value_parser = sim::radio::RcScript::parse)]
    rc: Option<sim::radio::RcScript>,
    /// RC frames per second of the simulated radio, Hz (1–1000).
    #[arg(long, value_name = "HZ", default_value_t = sim::radio::DEFAULT_RC_RATE_HZ,
          value_parser = parse_rc_rate_hz)]
    rc_rate_hz: f64,
    #[command(flatten)]
    faults: sim::faults::SitlFaultArgs,
    /// Write the flight log into this directory (LOG00001.BIN, …; created when missing): a file
    /// per arming, or one from start-up with the `log_always` parameter, as the board's SD card
    /// gets them (`configurator-cli replay` reads them).
    #[arg(long, value_name = "DIR")]
    log_dir: Option<PathBuf>,
    /// With --log-dir: the `log_always` parameter in force from start-up (as if saved), so one
    /// file runs from the first step and replays exactly whatever arms the craft.
    #[arg(long, requires = "log_dir")]
    log_always: bool,
    /// Cut the power at this simulated time, s: the SITL kills itself (SIGKILL) before the first
    /// step at or after it, nothing flushed or closed, as a battery unplugged in flight would
    /// stop the board (what a flight log keeps then: docs/flight-log.md).
    #[arg(long, value_name = "S")]
    power_cut_at_s: Option<f64>,
    /// Serve the protocol also on a second pseudo-terminal behind a simulated telemetry radio at
    /// this serial rate, baud (e.g. 57600; a SiK-class modem on a UART): open its path (printed
    /// at start) with `configurator-cli --port`.
    #[arg(long, value_name = "BAUD", value_parser = clap::value_parser!(u32).range(1200..=2_000_000))]
    radio_baud: Option<u32>,
    /// Make this path a symlink to the simulated telemetry radio's pseudo-terminal (as
    /// --pty-link does for the USB link), so a script knows where to connect:
    /// `configurator-cli --port PATH --baud 57600 status`.
    #[arg(long, value_name = "PATH", requires = "radio_baud")]
    radio_port: Option<PathBuf>,
    /// The simulated radio's latency, ms (0–1000).
    #[arg(long, value_name = "MS", default_value_t = 20.0, requires = "radio_baud")]
    radio_latency_ms: f64,
    /// The simulated radio's frame loss, in [0, 0.5].
    #[arg(long, value_name = "P", default_value_t = 0.0, requires = "radio_baud")]
    radio_loss: f64,
    /// Stop after this many wall-clock seconds (default: run until interrupted).
    #[arg(long)]
    duration_s: Option<f64>,
}

/// An RC frame rate, Hz, within 1–1000.
fn parse_rc_rate_hz(text: &str) -> Result<f64, String> {
    let hz: f64 = text.parse().map_err(|_| format!("`{text}` is not a rate in Hz"))?;
    if (1.0..=1000.0).contains(&hz) {
        Ok(hz)
    } else {
        Err(format!("{text} Hz is out of range: allowed 1–1000 Hz"))
    }
}

/// Three comma-separated numbers (`X,Y,Z`); ranges are checked when the SITL starts.
fn parse_triple(text: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let [x, y, z] = parts.as_slice() else {
        return Err(format!("expected three comma-separated numbers X,Y,Z, got `{text}`"));
    };
    let number = |part: &str| part.parse::<f64>().map_err(|_| format!("`{part}` is not a number"));
    Ok([number(x)?, number(y)?, number(z)?])
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    let wind_ned_mps = match args.wind_ned_mps.as_deref() {
        None => [0.0; 3],
        Some(&[n, e, d]) if [n, e, d].iter().all(|x| x.is_finite() && x.abs() <= 20.0) => [n, e, d],
        Some(_) => {
            eprintln!("sitl: --wind-ned-mps takes three finite speeds within ±20 m/s");
            return std::process::ExitCode::from(2);
        }
    };
    let gnss = match args.gnss.config() {
        Ok(gnss) => gnss,
        Err(e) => {
            eprintln!("sitl: {e}");
            return std::process::ExitCode::from(2);
        }
    };
    let motion_capture = match args.motion_capture.config() {
        Ok(config) => config,
        Err(error) => {
            eprintln!("sitl: {error}");
            return std::process::ExitCode::from(2);
        }
    };
    if !(0.0..=1000.0).contains(&args.radio_latency_ms) || !(0.0..=0.5).contains(&args.radio_loss) {
        eprintln!(
            "sitl: --radio-latency-ms must be within 0–1000 ms and --radio-loss within 0–0.5 \
             (got {} ms, {})",
            args.radio_latency_ms, args.radio_loss
        );
        return std::process::ExitCode::from(2);
    }
    let config = SitlConfig {
        airframe: args.airframe.clone(),
        pty: !args.no_pty,
        pty_link: args.pty_link,
        tcp_port: args.tcp_port,
        speed: args.speed,
        seed: args.seed,
        auto_throw_every_s: args.throw_every_s,
        auto_throw_count: args.throws,
        auto_throw_rates_dps: (!args.throw_rates_dps.is_empty())
            .then(|| args.throw_rates_dps.clone()),
        acc_bias_mps2: args.acc_bias_mps2,
        throw_to_fly: args.throw_to_fly,
        hand_throws_to_fly: args.hand_throws_to_fly,
        imu_offset_m: args.imu_offset_mm,
        mocap: args.mocap,
        mocap_udp: args.mocap_udp,
        gnss: gnss.clone(),
        compass: args
            .compass
            .then(|| {
                sim::world::random_world_case(args.seed, &[sim::world::Aspect::Compass]).1.compass
            })
            .flatten(),
        wind_ned_mps,
        motion_capture,
        rc_script: args.rc.clone(),
        rc_rate_hz: args.rc_rate_hz,
        telemetry_radio: args.radio_baud.map(|baud| sim::serve::RadioConfig {
            baud,
            latency_s: args.radio_latency_ms * 1e-3,
            frame_loss: args.radio_loss,
        }),
        radio_link: args.radio_port.clone(),
        log_dir: args.log_dir.clone(),
        log_always: args.log_always,
        power_cut_at_s: args.power_cut_at_s,
        flash_file: (!args.no_flash)
            .then(|| args.flash_file.clone().unwrap_or_else(sim::flash::default_flash_path)),
        faults: args.faults.faults(),
    };
    let sitl = match Sitl::start(&config) {
        Ok(sitl) => sitl,
        Err(error) => {
            eprintln!("sitl: {error}");
            return std::process::ExitCode::from(2);
        }
    };
    println!("SITL running airframe `{}` at {}× real time", args.airframe, args.speed);
    if let (Some(path), Some(radio)) = (&sitl.radio_path, &config.telemetry_radio) {
        println!("  telemetry radio (pty):    {} ({} baud)", path.display(), radio.baud);
    }
    if let Some(link) = &config.radio_link {
        println!("  telemetry radio link:     {}", link.display());
    }
    if let Some(path) = &sitl.pty_path {
        println!("  serial (pseudo-terminal): {}", path.display());
    }
    if let Some(link) = &config.pty_link {
        println!("  serial link:              {}", link.display());
    }
    if let Some(addr) = sitl.tcp_addr {
        println!("  TCP:                      {addr}");
    }
    match &config.flash_file {
        Some(path) => println!("  configuration flash:      {}", path.display()),
        None => println!("  no configuration flash: `save` is refused"),
    }
    if let Some(every_s) = args.throw_every_s {
        println!("  throwing the craft every {every_s} s (spinning, 1 m up) and catching it");
        for rate in &args.throw_rates_dps {
            println!("    at ({:.0}, {:.0}, {:.0}) °/s, body axes", rate[0], rate[1], rate[2]);
        }
    }
    if args.throw_to_fly {
        println!("  armed for throw-to-fly: the first throw starts the motor excitation");
    }
    if let Some(dir) = &args.log_dir {
        println!("  flight log:               {} (a file per arming)", dir.display());
    }
    if args.hand_throws_to_fly {
        println!("  the hand throws the craft for flight 1 s after the board is armed");
    }
    if let Some([x, y, z]) = args.acc_bias_mps2 {
        println!("  accelerometer bias: ({x}, {y}, {z}) m/s², IMU axes");
    }
    if args.compass {
        println!("  compass: drawn from the seed, calibrated by a simulated user's dance");
    }
    if let Some(g) = &gnss {
        println!(
            "  GNSS: a u-blox receiver at {} Hz, {} ms late, {} m per horizontal axis (correlated over {} s), {} m vertically, no heading",
            g.rate_hz,
            g.latency_s * 1e3,
            g.horizontal_sigma_m,
            g.correlation_time_s,
            g.vertical_sigma_m
        );
    }
    if args.mocap {
        let m = motion_capture;
        println!(
            "  motion capture: the true pose at {} Hz (± {} ms), {} ms late, {} mm and {:.2}° of noise, {} dropouts/s of {} s",
            m.rate_hz,
            m.jitter_s * 1e3,
            m.latency_s * 1e3,
            m.noise_m * 1e3,
            m.heading_noise_rad.to_degrees(),
            m.dropouts_per_s,
            m.dropout_s
        );
    }
    if let Some([x, y, z]) = args.imu_offset_mm {
        println!(
            "  IMU offset for the learner: ({:.1}, {:.1}, {:.1}) mm, IMU axes",
            x * 1000.0,
            y * 1000.0,
            z * 1000.0
        );
    }
    let faults = &config.faults;
    if faults != &sim::faults::SitlFaults::default() {
        println!("  injected faults: {faults:?}");
    }
    println!("Stop with Ctrl-C.");
    let started = std::time::Instant::now();
    while sitl.is_running() {
        if args.duration_s.is_some_and(|d| started.elapsed().as_secs_f64() >= d) {
            return std::process::ExitCode::SUCCESS;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    eprintln!("sitl: the simulation thread stopped unexpectedly");
    std::process::ExitCode::FAILURE
}
