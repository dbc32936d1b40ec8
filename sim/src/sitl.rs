//! The SITL: the firmware's application graph ([`firmware::app::system`]) on a [`SimBoard`],
//! serving the protocol on a pseudo-terminal and on TCP at 127.0.0.1, paced to the wall clock.
//!
//! The pseudo-terminal is the point: the configurator opens its slave side exactly as it opens a
//! board's USB CDC port (`/dev/ttyACM0`), so the same code path is exercised end to end. The TCP
//! port serves tools that prefer sockets; each connection gets its own `LinkServer`, as a second
//! USB host would (the ports are in [`crate::serve`]). The link pass is the firmware's own: what
//! the links ask waits in the control step's queue for the next tick, as on the board.
//!
//! One thread runs everything in the order the board's priorities impose: every 500 µs of
//! simulated time a physics tick and a control tick (then the background work, when samples
//! wait), and a link pass whenever the tick says one is due (every millisecond). A simulated
//! pilot's radio (`--rc`, [`crate::radio`]) feeds the tick's receiver policy. Simulated time
//! follows the wall clock × `speed`; when the host cannot keep up, the simulation runs slower
//! than asked rather than skipping steps (the status's uptime then trails the wall clock).

use crate::airframe::{Airframe, AirframeError};
use crate::board::{SimBoard, SimConfig, SIM_BOARD_HEALTH};
use crate::flash::{FileFlash, FlashFileError};
use crate::hand::{HandPhase, ThrowSpec};
use crate::log_dir::LogDir;
use crate::serve::{simulator_board_info, Pty, RadioPort, TcpLinks};
use firmware::app::radio::Receiver;
use firmware::app::system::{with_logged_system, Link, LogTarget, System, TickHardware};
use firmware::app::{BoardInfo, ControlCommand, LinkServer, Settings};
use firmware::drivers::crsf::RcLinkConfig;
use protocol::Capabilities;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long the loop sleeps when the simulation is ahead of the wall clock.
const IDLE_SLEEP: Duration = Duration::from_micros(250);

/// How to start a SITL.
#[derive(Clone, Debug)]
pub struct SitlConfig {
    /// Airframe: a built-in name (`sim/airframes/`) or a path to a TOML file.
    pub airframe: String,
    /// Serve on a pseudo-terminal.
    pub pty: bool,
    /// Also make this symlink point at the pseudo-terminal (e.g. `/tmp/fc-sitl`).
    pub pty_link: Option<PathBuf>,
    /// Serve on TCP at 127.0.0.1 on this port (0 picks a free one), or not at all.
    pub tcp_port: Option<u16>,
    /// Simulated seconds per wall-clock second.
    pub speed: f64,
    /// Seed of the sensor noise.
    pub seed: u64,
    /// Have the simulated hand throw the craft (spinning, 1 m up) and catch it every this many
    /// simulated seconds, cycling through [`AUTO_THROW_RATES_DPS`]: the calibration throws,
    /// without a person.
    pub auto_throw_every_s: Option<f64>,
    /// Stop the automatic throws after this many (`None`: keep throwing).
    pub auto_throw_count: Option<usize>,
    /// Body rates at release of the automatic throws, °/s, body axes, cycled through in order
    /// (`None`: [`AUTO_THROW_RATES_DPS`]). Each within ±[`MAX_AUTO_THROW_RATE_DPS`] per axis and
    /// not zero.
    pub auto_throw_rates_dps: Option<Vec<[f64; 3]>>,
    /// The accelerometer's constant bias, m/s², IMU axes, instead of the airframe file's
    /// (`imu.accel.bias_mps2`); each component within ±[`MAX_ACC_BIAS_MPS2`].
    pub acc_bias_mps2: Option<[f64; 3]>,
    /// Arm the control loop for throw-to-fly at start (as the protocol's `ArmThrowToFly`
    /// request would): the first throw the board sees starts the motor excitation.
    pub throw_to_fly: bool,
    /// The IMU offset the in-flight learner uses: the IMU's position relative to the centre of
    /// gravity, IMU axes, m (each component finite, within ±[`MAX_IMU_OFFSET_M`]). `None`: the
    /// board's onboard estimate (or zero without one).
    pub imu_offset_m: Option<[f32; 3]>,
    /// Send the simulator's true pose to the firmware as a motion-capture system would
    /// ([`crate::recovery::MotionCapture`], configured by `motion_capture`), so a throw-to-fly
    /// holds a position.
    pub mocap: bool,
    /// The motion capture's rate, jitter, latency, noise and dropouts (default: 100 Hz, 1 mm
    /// and 0.1° of noise, on time, never lost). The firmware is not told: set its
    /// `pose_latency_s` and `pose_noise_m` parameters to match, as on a real system.
    pub motion_capture: crate::recovery::MotionCaptureConfig,
    /// With `mocap`: send each pose as a UDP datagram in the motion-capture line format
    /// ([`crate::pose_line`]) to this address, as a motion-capture system would, instead of
    /// handing it to the firmware (`configurator-cli pose-relay` forwards them over a link).
    pub mocap_udp: Option<std::net::SocketAddr>,
    /// A GNSS receiver on the craft ([`crate::gnss::SimGnss`]): its NAV-PVT bytes go through
    /// the firmware's receiver code (`firmware::app::gnss::GnssInput`, told the receiver's
    /// latency), each solution with a 3D fix reaching the control step as a position fix
    /// without heading, as the board's GNSS UART hands them over.
    pub gnss: Option<crate::gnss::GnssModelConfig>,
    /// A compass on the craft (`crate::magnetometer`): calibrated by the user's dance before
    /// start-up (stored as `compass calibrate` stores it, not saved) and read through its
    /// chip's registers by the firmware's compass service after each link pass, as the board's
    /// link task reads its I²C sensor (`crate::compass_feed`).
    pub compass: Option<crate::magnetometer::MagnetometerSpec>,
    /// A steady wind for the whole run: the air's velocity, world NED, m/s (drag acts on the
    /// airspeed; [`crate::board::WorldEffects::steady_wind_ned_mps`]).
    pub wind_ned_mps: [f64; 3],
    /// The flash file holding the saved configuration (created erased when missing); `None`:
    /// no configuration store (changes last until the SITL stops).
    pub flash_file: Option<PathBuf>,
    /// Have the simulated hand throw the craft for flight, as a person would, once the board
    /// has been armed for throw-to-fly for [`ARMED_TO_THROW_S`]: the seed paper's throw (a
    /// 3.5 m parabola released at (400, 400, 100) °/s), nothing to catch it; the hand grips the
    /// craft again where it is as soon as the board disarms (or its attempt fails). The
    /// automatic calibration throws pause while the board is armed.
    pub hand_throws_to_fly: bool,
    /// A simulated pilot's radio (CRSF receiver on the board's UART, [`crate::radio`]) playing
    /// this script; `None`: no receiver (the craft is commanded over the links only).
    pub rc_script: Option<crate::radio::RcScript>,
    /// RC frames per second of the simulated radio, Hz (1–1,000).
    pub rc_rate_hz: f64,
    /// A second link, on a pseudo-terminal behind a simulated telemetry radio (a byte rate, a
    /// latency, lost frames), as a board's UART with a SiK-class modem; `None`: none.
    pub telemetry_radio: Option<crate::serve::RadioConfig>,
    /// Also make this symlink point at the telemetry radio's pseudo-terminal (e.g.
    /// `/tmp/fc-radio`), so a script knows where to connect; needs `telemetry_radio`.
    pub radio_link: Option<PathBuf>,
    /// Faults the simulated board has from its start (an ESC that never answers, a silent or
    /// noisy IMU, a bad flash, swapped motor outputs: [`crate::faults::SitlFaults`]); default
    /// none.
    pub faults: crate::faults::SitlFaults,
    /// Write the flight log into this directory (`LOG00001.BIN`, …; created when missing): a
    /// file per arming, or one from start-up with the `log_always` parameter, as the board's
    /// SD card would get them. `None`: no log.
    pub log_dir: Option<PathBuf>,
    /// The `log_always` parameter in force from start-up (as if saved): one log file from the
    /// first step on, which replays exactly whatever arms the craft (docs/flight-log.md).
    pub log_always: bool,
    /// Cut the power at this simulated time, s: the SITL sends itself SIGKILL before the first
    /// step at or after it (nothing flushed, no file closed), as a battery unplugged in flight
    /// would stop the board. **It kills the whole process**: for the `sitl` binary only, never
    /// for a SITL inside another program. `None`: never.
    pub power_cut_at_s: Option<f64>,
}

/// How long the simulated hand waits after the board is armed before a throw-to-fly throw,
/// simulated s (the person reads the prompt and throws).
pub const ARMED_TO_THROW_S: f64 = 1.0;

/// Largest accepted IMU offset component, m.
pub const MAX_IMU_OFFSET_M: f32 = 1.0;

/// Body rates of the automatic throws, °/s: about two revolutions per second about three
/// clearly different axes, as the seed paper asks of calibration throws (§3.2).
pub const AUTO_THROW_RATES_DPS: [[f64; 3]; 3] =
    [[700.0, 350.0, 180.0], [-180.0, 230.0, 700.0], [300.0, -650.0, 250.0]];
/// Largest body rate per axis of an automatic throw, °/s: the ICM-42688-P's full scale is
/// 2000 °/s, and a hand does not spin a craft faster.
pub const MAX_AUTO_THROW_RATE_DPS: f64 = 1500.0;
/// Largest accelerometer bias per axis the SITL accepts, m/s²: five times a poorly mounted
/// ICM-42688-P's zero-g offset (±20 mg).
pub const MAX_ACC_BIAS_MPS2: f64 = 1.0;
/// Apex of an automatic throw above the release point, m (the seed paper's 1 m throws).
const AUTO_THROW_APEX_M: f64 = 1.0;
/// How long the hand accelerates the craft, s.
const AUTO_THROW_DURATION_S: f64 = 0.15;
/// How long the simulated hand takes to let go at the end of each push, s: a real hand's
/// release (issue 28 measured about 15 ms in an independent simulator's hand).
const HAND_TAPER_S: f64 = 0.015;
/// Time constant of the catch, s.
const AUTO_CATCH_TAU_S: f64 = 0.05;
/// Shortest interval between automatic throws, s (a 1 m throw flies about 0.9 s).
const MIN_AUTO_THROW_INTERVAL_S: f64 = 2.0;

impl Default for SitlConfig {
    fn default() -> Self {
        Self {
            airframe: "paper-quad".into(),
            pty: true,
            pty_link: None,
            tcp_port: None,
            speed: 1.0,
            seed: 1,
            auto_throw_every_s: None,
            auto_throw_count: None,
            auto_throw_rates_dps: None,
            acc_bias_mps2: None,
            throw_to_fly: false,
            mocap: false,
            mocap_udp: None,
            gnss: None,
            compass: None,
            wind_ned_mps: [0.0; 3],
            motion_capture: crate::recovery::MotionCaptureConfig::default(),
            imu_offset_m: None,
            flash_file: None,
            hand_throws_to_fly: false,
            rc_script: None,
            rc_rate_hz: crate::radio::DEFAULT_RC_RATE_HZ,
            telemetry_radio: None,
            radio_link: None,
            faults: crate::faults::SitlFaults::default(),
            log_dir: None,
            log_always: false,
            power_cut_at_s: None,
        }
    }
}

/// Why a SITL did not start.
#[derive(Debug, thiserror::Error)]
pub enum SitlError {
    #[error("airframe: {0}")]
    Airframe(#[from] AirframeError),
    #[error("could not create a pseudo-terminal: {0}")]
    Pty(std::io::Error),
    #[error("could not link {path} to the pseudo-terminal: {source}")]
    PtyLink { path: PathBuf, source: std::io::Error },
    #[error("a link to the telemetry radio's pseudo-terminal ({0}) needs a telemetry radio (--radio-baud)")]
    RadioLinkWithoutRadio(PathBuf),
    #[error("could not listen on 127.0.0.1:{port}: {source}")]
    Tcp { port: u16, source: std::io::Error },
    #[error("speed must be between 0.01 and 1000 (got {0})")]
    Speed(f64),
    #[error(
        "automatic throws need at least {MIN_AUTO_THROW_INTERVAL_S} s between them (got {0} s)"
    )]
    AutoThrowInterval(f64),
    #[error(
        "the IMU offset must be finite and within ±{MAX_IMU_OFFSET_M} m on each axis (got {0:?} m)"
    )]
    ImuOffset([f32; 3]),
    /// A motion-capture setting is outside its range (the message names it).
    #[error("{0}")]
    MotionCapture(String),
    #[error(
        "automatic throw rates must be non-zero and within ±{MAX_AUTO_THROW_RATE_DPS} °/s on \
         each axis (got {0:?} °/s)"
    )]
    AutoThrowRates(Vec<[f64; 3]>),
    #[error(
        "the accelerometer bias must be finite and within ±{MAX_ACC_BIAS_MPS2} m/s² on each \
         axis (got {0:?} m/s²)"
    )]
    AccBias([f64; 3]),
    #[error(transparent)]
    Flash(#[from] FlashFileError),
    /// A fault flag names something the airframe does not have (the message says which).
    #[error("{0}")]
    Fault(String),
    #[error("could not create the log directory {path}: {source}")]
    LogDir { path: PathBuf, source: std::io::Error },
    #[error("cannot open a UDP socket for the motion-capture poses: {0}")]
    MocapUdp(std::io::Error),
    /// The simulated user's compass calibration was refused (`crate::compass_calibration`).
    #[error("the compass's calibration dance was refused: {0:?}")]
    Compass(crate::compass_calibration::DanceError),
}

/// A running SITL. Stops when dropped.
pub struct Sitl {
    /// The pseudo-terminal's slave path, to open like a serial port.
    pub pty_path: Option<PathBuf>,
    /// The TCP address served.
    pub tcp_addr: Option<SocketAddr>,
    /// The simulated telemetry radio's pseudo-terminal, to open like the radio's serial port.
    pub radio_path: Option<PathBuf>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// The symlinks made to the pseudo-terminals (`pty_link`, `radio_link`), removed on drop.
    links: Vec<PathBuf>,
}

/// Make each `(link, target)` a symlink to its pseudo-terminal, replacing what was at `link`;
/// when one fails, those already made are removed again.
fn make_links(links: &[(PathBuf, PathBuf)]) -> Result<(), SitlError> {
    for (made, (link, target)) in links.iter().enumerate() {
        let _ = std::fs::remove_file(link);
        if let Err(source) = std::os::unix::fs::symlink(target, link) {
            for (earlier, _) in &links[..made] {
                let _ = std::fs::remove_file(earlier);
            }
            return Err(SitlError::PtyLink { path: link.clone(), source });
        }
    }
    Ok(())
}

impl Sitl {
    /// Start serving. Returns once the endpoints exist, so a client may connect at once.
    pub fn start(config: &SitlConfig) -> Result<Self, SitlError> {
        if !(0.01..=1000.0).contains(&config.speed) {
            return Err(SitlError::Speed(config.speed));
        }
        if let Some(every_s) = config.auto_throw_every_s {
            if !(every_s.is_finite() && every_s >= MIN_AUTO_THROW_INTERVAL_S) {
                return Err(SitlError::AutoThrowInterval(every_s));
            }
        }
        if let Some(offset_m) = config.imu_offset_m {
            if !offset_m.iter().all(|x| x.is_finite() && x.abs() <= MAX_IMU_OFFSET_M) {
                return Err(SitlError::ImuOffset(offset_m));
            }
        }
        config.motion_capture.validate().map_err(SitlError::MotionCapture)?;
        let auto_throw_rates_dps =
            config.auto_throw_rates_dps.clone().unwrap_or_else(|| AUTO_THROW_RATES_DPS.to_vec());
        let rate_ok = |r: &[f64; 3]| {
            r.iter().all(|x| x.is_finite() && x.abs() <= MAX_AUTO_THROW_RATE_DPS)
                && r.iter().any(|&x| x != 0.0)
        };
        if auto_throw_rates_dps.is_empty() || !auto_throw_rates_dps.iter().all(rate_ok) {
            return Err(SitlError::AutoThrowRates(auto_throw_rates_dps));
        }
        let mut airframe = Airframe::load(&config.airframe)?;
        if let Some(bias) = config.acc_bias_mps2 {
            if !bias.iter().all(|x| x.is_finite() && x.abs() <= MAX_ACC_BIAS_MPS2) {
                return Err(SitlError::AccBias(bias));
            }
            airframe.imu.accel.bias_mps2 = bias;
        }
        config.faults.validate(airframe.rotor_count()).map_err(SitlError::Fault)?;
        config.faults.apply_to_airframe(&mut airframe);
        let flash = config.flash_file.as_deref().map(FileFlash::open).transpose()?;
        let flash = flash.map(|flash| flash.with_fault(config.faults.flash));
        let log_dir = match &config.log_dir {
            Some(path) => Some(
                LogDir::create(path)
                    .map_err(|source| SitlError::LogDir { path: path.clone(), source })?,
            ),
            None => None,
        };
        let mut info = simulator_board_info("SITL", config.seed, airframe.rotor_count() as u8);
        // The simulated ESCs take DShot special commands (`SimMotors::escs`); the bridge's do not.
        info.capabilities |= Capabilities::ESC_COMMANDS;
        if flash.is_some() {
            info.capabilities |= Capabilities::PERSISTENT_STORE;
        }
        let pty = if config.pty { Some(Pty::open().map_err(SitlError::Pty)?) } else { None };
        let pty_path = pty.as_ref().map(|p| p.slave_path().to_path_buf());
        if let (Some(link), None) = (&config.radio_link, &config.telemetry_radio) {
            return Err(SitlError::RadioLinkWithoutRadio(link.clone()));
        }
        let telemetry_radio = match config.telemetry_radio {
            Some(radio) => {
                Some(RadioPort::new(Pty::open().map_err(SitlError::Pty)?, radio, config.seed))
            }
            None => None,
        };
        let radio_path = telemetry_radio.as_ref().map(|r| r.slave_path().to_path_buf());
        let tcp = match config.tcp_port {
            Some(port) => Some(
                TcpLinks::bind(port, info.clone())
                    .map_err(|source| SitlError::Tcp { port, source })?,
            ),
            None => None,
        };
        let tcp_addr = tcp.as_ref().and_then(|t| t.local_addr().ok());
        let links: Vec<(PathBuf, PathBuf)> =
            [(&config.pty_link, &pty_path), (&config.radio_link, &radio_path)]
                .into_iter()
                .filter_map(|(link, target)| Some((link.clone()?, target.clone()?)))
                .collect();
        make_links(&links)?;
        let links: Vec<PathBuf> = links.into_iter().map(|(link, _)| link).collect();
        let stop = Arc::new(AtomicBool::new(false));
        let runner = Runner {
            airframe,
            seed: config.seed,
            speed: config.speed,
            auto_throw_every_s: config.auto_throw_every_s,
            auto_throw_count: config.auto_throw_count,
            auto_throw_rates_dps,
            throw_to_fly: config.throw_to_fly,
            hand_throws_to_fly: config.hand_throws_to_fly,
            mocap: config.mocap,
            gnss: config.gnss.clone(),
            compass: match &config.compass {
                Some(spec) => Some(SitlCompass::new(spec, config.seed)?),
                None => None,
            },
            wind_ned_mps: config.wind_ned_mps,
            motion_capture: config.motion_capture,
            mocap_udp: match config.mocap_udp {
                Some(to) => Some(MocapSender::open(to).map_err(SitlError::MocapUdp)?),
                None => None,
            },
            radio: config
                .rc_script
                .as_ref()
                .map(|script| crate::radio::RcTransmitter::new(config.rc_rate_hz, script)),
            imu_offset_m: config.imu_offset_m,
            info,
            pty,
            telemetry_radio,
            tcp,
            flash,
            fault_schedule: config.faults.schedule(),
            log_dir,
            log_always: config.log_always,
            power_cut_at_us: config.power_cut_at_s.map(|s| (s.max(0.0) * 1e6) as u64),
            stop: stop.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("sitl".into())
            .spawn(move || runner.run())
            .map_err(SitlError::Pty)?;
        Ok(Self { pty_path, tcp_addr, radio_path, stop, thread: Some(thread), links })
    }

    /// Whether the simulation thread is still running.
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for Sitl {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
        for link in &self.links {
            let _ = std::fs::remove_file(link);
        }
    }
}

struct Runner {
    airframe: Airframe,
    seed: u64,
    speed: f64,
    auto_throw_every_s: Option<f64>,
    auto_throw_count: Option<usize>,
    auto_throw_rates_dps: Vec<[f64; 3]>,
    throw_to_fly: bool,
    hand_throws_to_fly: bool,
    imu_offset_m: Option<[f32; 3]>,
    mocap: bool,
    motion_capture: crate::recovery::MotionCaptureConfig,
    mocap_udp: Option<MocapSender>,
    gnss: Option<crate::gnss::GnssModelConfig>,
    compass: Option<SitlCompass>,
    wind_ned_mps: [f64; 3],
    /// The simulated pilot's radio, when there is one (it goes on across restarts).
    radio: Option<crate::radio::RcTransmitter>,
    info: BoardInfo,
    pty: Option<Pty>,
    /// The simulated telemetry radio's port (its link session starts afresh at each boot).
    telemetry_radio: Option<RadioPort>,
    tcp: Option<TcpLinks>,
    flash: Option<FileFlash>,
    /// The faults of the simulated board ([`crate::faults::SitlFaults::schedule`]).
    fault_schedule: crate::faults::FaultSchedule,
    log_dir: Option<LogDir>,
    log_always: bool,
    /// [`SitlConfig::power_cut_at_s`], µs of simulated time.
    power_cut_at_us: Option<u64>,
    stop: Arc<AtomicBool>,
}

/// How one run of the application ended.
enum Ending {
    /// The SITL is stopping.
    Stop,
    /// A link asked for a restart.
    Reboot,
}

impl Runner {
    /// Boot the application, serve until stopped, and boot it again after every restart
    /// request: the physics and the links' endpoints go on, the application and its link
    /// sessions start afresh, and the configuration is loaded from the flash file again.
    fn run(mut self) {
        let mut config = SimConfig {
            seed: self.seed,
            faults: self.fault_schedule.clone(),
            ..SimConfig::default()
        };
        config.world.steady_wind_ned_mps = self.wind_ned_mps;
        let mut board = SimBoard::new(&self.airframe, &config);
        let mut throws_done = 0usize;
        let mut flight_hand = FlightHand::default();
        let start = Instant::now();
        let mut first_boot = true;
        loop {
            // The motion capture times its poses by the firmware's clock, which starts again at
            // every start-up: a capture kept across a restart would wait for the clock to reach
            // its last pose's time before sending the next.
            let mut mocap = self.mocap.then(|| {
                crate::recovery::MotionCapture::with_config(self.motion_capture, self.seed)
            });
            // The receiver keeps its own time (the simulator's); the firmware's side of it
            // starts again with the firmware.
            let mut gnss =
                self.gnss.as_ref().map(|model| crate::gnss::SimGnssPort::new(model, self.seed));
            let mut settings = match self.flash.take() {
                Some(flash) => Settings::load(flash, FileFlash::store_range()),
                None => Settings::without_store(),
            };
            // A signing session per start-up, drawn as the board draws it (`protocol::signing`).
            settings.set_link_session(crate::serve::random_session());
            if let Some(r_imu_m) = self.imu_offset_m {
                // The command line's offset is in force as if calibrated (not saved).
                settings.update(|params| params.store_calibration(r_imu_m, [0.0; 3], None));
            }
            if let Some(model) = &self.gnss {
                // The receiver's rate and latency in force from start-up, as a user would set
                // them for theirs (`gnss_rate_hz`, `gnss_latency_s`; not saved).
                settings.update(|params| {
                    for (name, value) in [
                        (&b"gnss_rate_hz"[..], model.rate_hz),
                        (b"gnss_latency_s", model.latency_s),
                    ] {
                        if let Some(index) = firmware::app::params::find(name) {
                            let _ = params.set(index, &[value as f32]);
                        }
                    }
                });
            }
            if let Some(compass) = &self.compass {
                // The user's calibration and declination in force from start-up (not saved).
                settings.update(|params| {
                    params.store_compass_calibration(&compass.calibration);
                    if let Some(index) = firmware::app::params::find(b"compass_declination_deg") {
                        let _ = params.set(index, &[compass.declination_deg]);
                    }
                });
            }
            if self.log_always {
                // In force before the first step, as a saved value is at a board's start-up.
                settings.update(|params| {
                    if let Some(index) = firmware::app::params::find(b"log_always") {
                        let _ = params.set(index, &[1.0]);
                    }
                });
            }
            // Read at start-up, as the board's motor outputs do.
            board.ports().1.set_bidirectional(settings.params().bidirectional_dshot());
            // The receiver's policy starts afresh with the firmware, as on the board.
            let receiver =
                self.radio.as_ref().and_then(|_| Receiver::new(RcLinkConfig::default()).ok());
            // The log directory is taken out for the run (the system borrows it) and put back.
            let mut log_dir = self.log_dir.take();
            let log = log_dir.as_mut().map(|sink| LogTarget { sink, board: self.info.board });
            let (ending, settings) =
                with_logged_system(settings, SIM_BOARD_HEALTH, receiver, log, |system| {
                    if self.throw_to_fly && first_boot {
                        system.submit(ControlCommand::ArmThrowToFly);
                    }
                    let boot_us = board.now_us();
                    let mut clock = Clock { board: &mut board, boot_us, start };
                    let hands = Hands { throws_done: &mut throws_done, flight: &mut flight_hand };
                    let sources = Sources { mocap: &mut mocap, gnss: &mut gnss };
                    let ending = self.serve(system, &mut clock, sources, hands);
                    system.finish_log();
                    ending
                });
            self.log_dir = log_dir;
            first_boot = false;
            self.flash = settings.into_flash();
            match ending {
                Ending::Stop => return,
                Ending::Reboot => {
                    if let Some(tcp) = &mut self.tcp {
                        tcp.close_all();
                    }
                }
            }
        }
    }

    /// Run the application until the SITL stops or a link asks for a restart: the physics and
    /// the hands around the application graph's control ticks, and its link pass whenever a
    /// tick says one is due, exactly as the board's timer pends its USB task.
    fn serve(
        &mut self,
        system: &mut System<'_, FileFlash>,
        clock: &mut Clock<'_>,
        sources: Sources<'_>,
        hands: Hands<'_>,
    ) -> Ending {
        let Hands { throws_done, flight: flight_hand } = hands;
        let Sources { mocap, gnss } = sources;
        // A fresh link session per boot, as USB re-enumerates.
        let mut pty =
            self.pty.take().map(|port| Link::new(LinkServer::new(self.info.clone()), port));
        let mut radio = self.telemetry_radio.take().map(|port| {
            let bytes_per_s = port.config().bytes_per_s();
            let server = LinkServer::new(self.info.clone()).untrusted().with_byte_rate(bytes_per_s);
            Link::new(server, port)
        });
        let ending = loop {
            if self.stop.load(Ordering::Relaxed) {
                break Ending::Stop;
            }
            let due_us = (clock.start.elapsed().as_secs_f64() * self.speed * 1e6) as u64;
            if clock.board.now_us() >= due_us {
                std::thread::sleep(IDLE_SLEEP);
                continue;
            }
            let snapshot = system.snapshot();
            let more_throws = self.auto_throw_count.is_none_or(|count| *throws_done < count);
            if let (Some(every_s), true, false) =
                (self.auto_throw_every_s, more_throws, snapshot.armed)
            {
                auto_throw(clock.board, every_s, &self.auto_throw_rates_dps, throws_done);
            }
            if self.hand_throws_to_fly {
                flight_hand.act(clock.board, &snapshot);
            }
            clock.board.tick();
            if self.power_cut_at_us.is_some_and(|cut_us| clock.board.now_us() >= cut_us) {
                power_cut();
            }
            let now_us = clock.firmware_us();
            let state = clock.board.physics().state();
            if let Some(pose) = mocap.as_mut().and_then(|m| m.sample(state, now_us)) {
                match &self.mocap_udp {
                    Some(sender) => sender.send(now_us, &pose),
                    None => {
                        system.submit(ControlCommand::ExternalPose(pose));
                    }
                }
            }
            if let Some(compass) = &mut self.compass {
                let q_world_imu = state.attitude() * self.airframe.q_imu_body().inverse();
                let motors = clock.board.motors();
                let thrust: Vec<f64> = motors.commands().iter().map(|&u| f64::from(u)).collect();
                compass.chip.update(clock.board.time_s(), &q_world_imu, &thrust);
            }
            if let Some(port) = gnss.as_mut() {
                let truth = crate::gnss::GnssTruth {
                    position_ned_m: state.position_ned_m,
                    velocity_ned_mps: state.velocity_ned_mps,
                };
                port.advance(clock.board.time_s(), &truth);
            }
            if let Some(radio) = &mut self.radio {
                radio.advance(clock.board.now_us());
            }
            let battery = &mut clock.board.battery_reading();
            let (imu, motors) = clock.board.ports();
            let hardware = TickHardware { imu, motors, radio_bytes: &mut self.radio, battery };
            if !system.tick(now_us, hardware).link_due {
                continue;
            }
            if let Some(tcp) = &mut self.tcp {
                tcp.accept();
            }
            if let Some(radio) = &mut radio {
                radio.port.set_time(clock.board.now_us());
            }
            let outcome = system.pass(now_us, &mut ((&mut pty, &mut radio), &mut self.tcp));
            if let Some(port) = gnss.as_mut() {
                // The board's link task services the receiver after each pass.
                system.service_gnss(now_us, port);
            }
            if let Some(compass) = &mut self.compass {
                // And the compass on its I²C bus.
                system.service_compass(now_us, &mut compass.chip, &mut compass.delay);
            }
            if let Some(tcp) = &mut self.tcp {
                tcp.drop_closed();
            }
            // A restart waits until the reply has gone out. (The simulator's links refuse the
            // bootloader: no `Capabilities::BOOTLOADER`.)
            if outcome.restart.is_some() {
                if let Some(link) = &mut pty {
                    link.transmit();
                }
                if let Some(tcp) = &mut self.tcp {
                    tcp.flush();
                }
                break Ending::Reboot;
            }
        };
        self.pty = pty.map(|link| link.port);
        self.telemetry_radio = radio.map(|link| link.port);
        ending
    }
}

/// The power goes: this process ends at once by SIGKILL, as a board stops when its battery is
/// unplugged (no destructor runs, no buffer is flushed, no file is closed).
fn power_cut() -> ! {
    // SAFETY: `getpid` and `kill` take and return plain integers; nothing is shared.
    unsafe {
        libc::kill(libc::getpid(), libc::SIGKILL);
    }
    // SIGKILL cannot be caught; should it not have been delivered yet, end without unwinding.
    std::process::abort()
}

/// Simulated time, and the firmware's time since its latest boot.
struct Clock<'b> {
    board: &'b mut SimBoard,
    /// Simulated time of the boot, µs.
    boot_us: u64,
    /// Wall-clock start of the SITL.
    start: Instant,
}

/// The SITL's compass: the chip on the craft, the calibration the user's dance stored, the
/// declination they set.
struct SitlCompass {
    chip: crate::compass_chip::SimCompassChip,
    delay: crate::compass_chip::CountingDelay,
    calibration: firmware::app::compass::CompassCalibration,
    declination_deg: f32,
}

impl SitlCompass {
    fn new(spec: &crate::magnetometer::MagnetometerSpec, seed: u64) -> Result<Self, SitlError> {
        let (calibration, chip) =
            crate::compass_feed::calibrated_chip(spec, seed).map_err(SitlError::Compass)?;
        Ok(Self {
            chip,
            delay: crate::compass_chip::CountingDelay::default(),
            calibration,
            declination_deg: spec.declination_rad.to_degrees() as f32,
        })
    }
}

impl Clock<'_> {
    fn firmware_us(&self) -> u64 {
        self.board.now_us() - self.boot_us
    }
}

/// What tells the firmware where the craft is, for one boot: the motion capture and the GNSS
/// receiver (the simulator's receiver and the firmware's side of it).
struct Sources<'s> {
    mocap: &'s mut Option<crate::recovery::MotionCapture>,
    gnss: &'s mut Option<crate::gnss::SimGnssPort>,
}

/// The simulated hand's state across restarts: calibration throws done, the flight throw.
struct Hands<'h> {
    throws_done: &'h mut usize,
    flight: &'h mut FlightHand,
}

/// The person who throws the craft for a throw-to-fly and catches it after the flight.
#[derive(Debug, Default)]
struct FlightHand {
    /// When the board was first seen armed and waiting while held, simulated s.
    armed_since_s: Option<f64>,
    /// A flight throw is in the air.
    in_flight: bool,
}

impl FlightHand {
    fn act(&mut self, board: &mut SimBoard, snapshot: &firmware::app::ControlSnapshot) {
        let now_s = board.time_s();
        let holding = board.physics().hand().phase() == HandPhase::Holding;
        let waiting = snapshot.phase == flight::learner::FlightPhase::WaitingForThrow;
        if self.in_flight {
            if !snapshot.armed {
                board.physics_mut().grip();
                self.in_flight = false;
            }
            return;
        }
        if !(holding && waiting) {
            self.armed_since_s = None;
            return;
        }
        let since_s = *self.armed_since_s.get_or_insert(now_s);
        if now_s - since_s >= ARMED_TO_THROW_S {
            let physics = board.physics_mut();
            physics.set_catch(None);
            let throw = crate::identification::Throw {
                taper_s: HAND_TAPER_S,
                ..crate::identification::Throw::paper()
            };
            physics.throw(&throw.spec());
            self.in_flight = true;
            self.armed_since_s = None;
        }
    }
}

/// Throw the craft when the next automatic throw is due and the hand holds it, at the next of
/// `rates_dps` (body axes, °/s; never empty).
fn auto_throw(board: &mut SimBoard, every_s: f64, rates_dps: &[[f64; 3]], throws_done: &mut usize) {
    let due_s = every_s * (*throws_done + 1) as f64;
    if board.time_s() < due_s || board.physics().hand().phase() != HandPhase::Holding {
        return;
    }
    let Some(&rate_dps) = rates_dps.get(*throws_done % rates_dps.len().max(1)) else { return };
    let rate_rad_s = nalgebra::Vector3::from(rate_dps).map(f64::to_radians);
    let spec = ThrowSpec::vertical(AUTO_THROW_APEX_M, rate_rad_s, AUTO_THROW_DURATION_S)
        .with_taper(HAND_TAPER_S);
    board.physics_mut().throw_and_catch_at_release_height(&spec, AUTO_CATCH_TAU_S);
    *throws_done += 1;
}

/// The SITL's motion-capture system on the network: each pose one datagram in the line format.
struct MocapSender {
    socket: std::net::UdpSocket,
    to: std::net::SocketAddr,
}

impl MocapSender {
    fn open(to: std::net::SocketAddr) -> std::io::Result<Self> {
        let any: std::net::SocketAddr =
            if to.is_ipv4() { ([0, 0, 0, 0], 0).into() } else { ([0u16; 8], 0).into() };
        Ok(Self { socket: std::net::UdpSocket::bind(any)?, to })
    }

    /// Send `pose`, captured at `now_us` on the simulation's clock. A datagram the network
    /// refuses (nobody listening yet) is lost, as a motion-capture stream's would be.
    fn send(&self, now_us: u64, pose: &protocol::ExternalPose) {
        let [n, e, d] = pose.position_ned_m.map(f64::from);
        let line = crate::pose_line::PoseLine::with_heading(
            now_us as f64 * 1e-6,
            [n, e, d],
            f64::from(pose.heading_rad),
        );
        let _ = self.socket.send_to(line.format().as_bytes(), self.to);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::serve::TestHost;
    use protocol::{Reply, Request};

    fn armed(host: &mut TestHost) -> bool {
        match host.request(Request::GetStatus(())) {
            Ok(Reply::Status(status)) => status.armed,
            other => panic!("expected the status, got {other:?}"),
        }
    }

    #[test]
    fn bad_throw_rates_or_bias_are_refused_at_start() {
        let start = |config: SitlConfig| Sitl::start(&SitlConfig { pty: false, ..config });
        let rates = |rates: Vec<[f64; 3]>| SitlConfig {
            auto_throw_every_s: Some(3.0),
            auto_throw_rates_dps: Some(rates),
            ..SitlConfig::default()
        };
        for bad in [vec![], vec![[0.0; 3]], vec![[550.0, 0.0, 0.0], [0.0, f64::NAN, 0.0]]] {
            assert!(matches!(start(rates(bad)), Err(SitlError::AutoThrowRates(_))));
        }
        assert!(matches!(
            start(rates(vec![[2000.0, 0.0, 0.0]])),
            Err(SitlError::AutoThrowRates(_))
        ));
        let bias = SitlConfig { acc_bias_mps2: Some([0.0, 1.5, 0.0]), ..SitlConfig::default() };
        assert!(matches!(start(bias), Err(SitlError::AccBias(_))));
        assert!(start(rates(vec![[0.0, 0.0, 550.0], [550.0, 0.0, 0.0]])).is_ok());
    }

    #[test]
    fn armed_at_start_and_disarmed_over_tcp() {
        let config = SitlConfig {
            pty: false,
            tcp_port: Some(0),
            throw_to_fly: true,
            imu_offset_m: Some([0.01, -0.02, 0.0]),
            ..SitlConfig::default()
        };
        let sitl = Sitl::start(&config).unwrap();
        let mut host = TestHost::connect(sitl.tcp_addr.unwrap());
        assert!(matches!(host.hello(), Ok(Reply::Hello(_))));
        assert!(armed(&mut host), "--throw-to-fly arms the control loop at start");
        assert_eq!(host.request(Request::Disarm(())), Ok(Reply::Done));
        // The command reaches the control step after the link pass that received it.
        assert!(!armed(&mut host), "the link's disarm reached the control loop");
        assert_eq!(host.request(Request::ArmThrowToFly(())), Ok(Reply::Done));
        assert!(armed(&mut host), "the link's arm reached the control loop");
    }

    #[test]
    fn an_imu_offset_out_of_range_is_refused() {
        for offset_m in [[0.0, 1.5, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 0.0, -1.001]] {
            let config =
                SitlConfig { pty: false, imu_offset_m: Some(offset_m), ..SitlConfig::default() };
            assert!(matches!(Sitl::start(&config), Err(SitlError::ImuOffset(_))), "{offset_m:?}");
        }
        assert!(!SitlConfig::default().throw_to_fly);
        assert_eq!(SitlConfig::default().imu_offset_m, None);
    }

    #[test]
    fn both_pseudo_terminals_are_linked_where_asked_until_the_sitl_stops() {
        let dir = std::env::temp_dir().join(format!("sitl-links-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (usb, radio) = (dir.join("fc"), dir.join("fc-radio"));
        // Without a radio there is nothing to link: refused, nothing made.
        let no_radio = SitlConfig { radio_link: Some(radio.clone()), ..SitlConfig::default() };
        assert!(matches!(Sitl::start(&no_radio), Err(SitlError::RadioLinkWithoutRadio(_))));
        assert!(!radio.exists());
        let config = SitlConfig {
            pty_link: Some(usb.clone()),
            radio_link: Some(radio.clone()),
            telemetry_radio: Some(crate::serve::RadioConfig {
                baud: 57_600,
                latency_s: 0.02,
                frame_loss: 0.0,
            }),
            ..SitlConfig::default()
        };
        let sitl = Sitl::start(&config).unwrap();
        assert_eq!(std::fs::read_link(&usb).unwrap(), sitl.pty_path.clone().unwrap());
        assert_eq!(std::fs::read_link(&radio).unwrap(), sitl.radio_path.clone().unwrap());
        drop(sitl);
        assert!(
            std::fs::symlink_metadata(&usb).is_err() && std::fs::symlink_metadata(&radio).is_err()
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
