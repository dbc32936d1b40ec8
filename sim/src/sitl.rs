//! The SITL: `firmware::app` on a [`SimBoard`], serving the protocol on a pseudo-terminal and on
//! TCP at 127.0.0.1, paced to the wall clock.
//!
//! The pseudo-terminal is the point: the configurator opens its slave side exactly as it opens a
//! board's USB CDC port (`/dev/ttyACM0`), so the same code path is exercised end to end. The TCP
//! port serves tools that prefer sockets; each connection gets its own [`LinkServer`], as a
//! second USB host would.
//!
//! One thread runs everything in the order the board's priorities impose: every 500 µs of
//! simulated time a physics tick and a control step, then the background work, and once per
//! millisecond of simulated time the links. Simulated time follows the wall clock × `speed`;
//! when the host cannot keep up, the simulation runs slower than asked rather than skipping
//! steps (the status's uptime then trails the wall clock).

use crate::airframe::{Airframe, AirframeError};
use crate::board::{SimBoard, SimConfig};
use crate::hand::{HandPhase, ThrowSpec};
use firmware::app::{
    split_queue, Background, BoardInfo, ControlConfig, ControlLoop, LinkServer, SampleQueue,
    StatusView, CONTROL_RATE_HZ,
};
use protocol::Capabilities;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Simulated time between two passes of the link task, µs (the board pends its USB task at
/// 1 kHz).
const LINK_PERIOD_US: u64 = 1000;
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
}

/// Body rates of the automatic throws, °/s: about two revolutions per second about three
/// clearly different axes, as the seed paper asks of calibration throws (§3.2).
pub const AUTO_THROW_RATES_DPS: [[f64; 3]; 3] =
    [[700.0, 350.0, 180.0], [-180.0, 230.0, 700.0], [300.0, -650.0, 250.0]];
/// Apex of an automatic throw above the release point, m (the seed paper's 1 m throws).
const AUTO_THROW_APEX_M: f64 = 1.0;
/// How long the hand accelerates the craft, s.
const AUTO_THROW_DURATION_S: f64 = 0.15;
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
    #[error("could not listen on 127.0.0.1:{port}: {source}")]
    Tcp { port: u16, source: std::io::Error },
    #[error("speed must be between 0.01 and 1000 (got {0})")]
    Speed(f64),
    #[error(
        "automatic throws need at least {MIN_AUTO_THROW_INTERVAL_S} s between them (got {0} s)"
    )]
    AutoThrowInterval(f64),
}

/// A running SITL. Stops when dropped.
pub struct Sitl {
    /// The pseudo-terminal's slave path, to open like a serial port.
    pub pty_path: Option<PathBuf>,
    /// The TCP address served.
    pub tcp_addr: Option<SocketAddr>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    pty_link: Option<PathBuf>,
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
        let airframe = Airframe::load(&config.airframe)?;
        let pty = if config.pty { Some(Pty::open().map_err(SitlError::Pty)?) } else { None };
        let pty_path = pty.as_ref().map(|p| p.slave_path.clone());
        if let (Some(link), Some(target)) = (&config.pty_link, &pty_path) {
            let _ = std::fs::remove_file(link);
            std::os::unix::fs::symlink(target, link)
                .map_err(|source| SitlError::PtyLink { path: link.clone(), source })?;
        }
        let listener = match config.tcp_port {
            Some(port) => {
                let listener = TcpListener::bind(("127.0.0.1", port))
                    .map_err(|source| SitlError::Tcp { port, source })?;
                listener.set_nonblocking(true).map_err(|source| SitlError::Tcp { port, source })?;
                Some(listener)
            }
            None => None,
        };
        let tcp_addr = listener.as_ref().and_then(|l| l.local_addr().ok());
        let stop = Arc::new(AtomicBool::new(false));
        let runner = Runner {
            airframe,
            seed: config.seed,
            speed: config.speed,
            auto_throw_every_s: config.auto_throw_every_s,
            auto_throw_count: config.auto_throw_count,
            pty,
            listener,
            stop: stop.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("sitl".into())
            .spawn(move || runner.run())
            .map_err(SitlError::Pty)?;
        Ok(Self {
            pty_path,
            tcp_addr,
            stop,
            thread: Some(thread),
            pty_link: config.pty_link.clone(),
        })
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
        if let Some(link) = &self.pty_link {
            let _ = std::fs::remove_file(link);
        }
    }
}

/// What the SITL tells the host about itself.
fn board_info(motor_count: u8, seed: u64) -> BoardInfo {
    let mut serial = heapless::String::new();
    let _ = core::fmt::Write::write_fmt(&mut serial, format_args!("SITL-{seed:08X}"));
    BoardInfo {
        board: "SITL",
        serial,
        capabilities: Capabilities::IMU
            | Capabilities::MOTORS
            | Capabilities::MOTOR_RPM
            | Capabilities::TELEMETRY
            | Capabilities::SIMULATOR,
        control_rate_hz: CONTROL_RATE_HZ,
        motor_count,
    }
}

/// A byte transport the link pass serves: the pseudo-terminal master or a TCP stream.
trait Transport {
    /// Read what is available without blocking; `Ok(0)` when nothing is, `Err` when closed.
    fn read_available(&mut self, buffer: &mut [u8]) -> std::io::Result<usize>;
    /// Write without blocking; returns how many bytes were taken.
    fn write_some(&mut self, bytes: &[u8]) -> std::io::Result<usize>;
}

/// One served connection: its transport and its own protocol endpoint.
struct Connection<T> {
    transport: T,
    link: LinkServer,
}

impl<T: Transport> Connection<T> {
    /// Receive, poll telemetry, transmit. Returns false when the transport has closed.
    fn service(&mut self, now_us: u64, view: &StatusView) -> bool {
        let mut buffer = [0u8; 512];
        // At most 4 KiB per pass (4 MB/s), so a client that never stops writing cannot stall
        // the simulation.
        for _ in 0..8 {
            match self.transport.read_available(&mut buffer) {
                Ok(0) => break,
                Ok(n) => self.link.receive(&buffer[..n], now_us, view),
                Err(_) => return false,
            }
        }
        self.link.poll(now_us, view);
        // What the transport does not take now waits in the link's buffer for the next pass.
        let mut closed = false;
        self.link.transmit_to(|bytes| match self.transport.write_some(bytes) {
            Ok(n) => n,
            Err(_) => {
                closed = true;
                0
            }
        });
        if closed {
            return false;
        }
        true
    }
}

struct Runner {
    airframe: Airframe,
    seed: u64,
    speed: f64,
    auto_throw_every_s: Option<f64>,
    auto_throw_count: Option<usize>,
    pty: Option<Pty>,
    listener: Option<TcpListener>,
    stop: Arc<AtomicBool>,
}

impl Runner {
    fn run(self) {
        let config = SimConfig { seed: self.seed, ..SimConfig::default() };
        let mut board = SimBoard::new(&self.airframe, &config);
        let info = board_info(self.airframe.rotor_count() as u8, self.seed);
        let mut queue = SampleQueue::new();
        let (producer, consumer) = split_queue(&mut queue);
        let control_config = ControlConfig::default();
        let mut control = ControlLoop::new(control_config, producer);
        let mut background = Background::new(consumer, control_config.rate_hz);
        let mut pty =
            self.pty.map(|transport| Connection { transport, link: LinkServer::new(info.clone()) });
        let mut clients: Vec<Connection<TcpStream>> = Vec::new();

        let mut throws_done = 0usize;
        let start = Instant::now();
        let ticks_per_link_pass = (LINK_PERIOD_US / firmware_period_us()).max(1);
        while !self.stop.load(Ordering::Relaxed) {
            let due_us = (start.elapsed().as_secs_f64() * self.speed * 1e6) as u64;
            if board.now_us() >= due_us {
                std::thread::sleep(IDLE_SLEEP);
                continue;
            }
            // One link period of simulated time: control ticks, then the link task, as the
            // board's timer pends its USB task once per millisecond.
            for _ in 0..ticks_per_link_pass {
                let more_throws = self.auto_throw_count.is_none_or(|count| throws_done < count);
                if let (Some(every_s), true) = (self.auto_throw_every_s, more_throws) {
                    auto_throw(&mut board, every_s, &mut throws_done);
                }
                board.tick();
                let now_us = board.now_us();
                let (imu, motors) = board.ports();
                if control.step(now_us, imu, motors) {
                    background.run_pending();
                }
            }
            let view = StatusView {
                control: control.snapshot(),
                background: background.results(),
                step_time: None,
            };
            let now_us = board.now_us();
            if let Some(listener) = &self.listener {
                while let Ok((stream, _)) = listener.accept() {
                    if stream.set_nonblocking(true).is_ok() {
                        let _ = stream.set_nodelay(true);
                        let link = LinkServer::new(info.clone());
                        clients.push(Connection { transport: stream, link });
                    }
                }
            }
            if let Some(connection) = &mut pty {
                connection.service(now_us, &view);
            }
            clients.retain_mut(|client| client.service(now_us, &view));
        }
    }
}

/// Throw the craft when the next automatic throw is due and the hand holds it.
fn auto_throw(board: &mut SimBoard, every_s: f64, throws_done: &mut usize) {
    let due_s = every_s * (*throws_done + 1) as f64;
    if board.time_s() < due_s || board.physics().hand().phase() != HandPhase::Holding {
        return;
    }
    let rate_dps = AUTO_THROW_RATES_DPS[*throws_done % AUTO_THROW_RATES_DPS.len()];
    let rate_rad_s = nalgebra::Vector3::from(rate_dps).map(f64::to_radians);
    let spec = ThrowSpec::vertical(AUTO_THROW_APEX_M, rate_rad_s, AUTO_THROW_DURATION_S);
    board.physics_mut().throw_and_catch_at_release_height(&spec, AUTO_CATCH_TAU_S);
    *throws_done += 1;
}

/// The control period, µs.
fn firmware_period_us() -> u64 {
    1_000_000 / u64::from(CONTROL_RATE_HZ)
}

impl Transport for TcpStream {
    fn read_available(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        match self.read(buffer) {
            Ok(0) => Err(ErrorKind::UnexpectedEof.into()),
            Ok(n) => Ok(n),
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn write_some(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        match self.write(bytes) {
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(0),
            other => other,
        }
    }
}

/// A pseudo-terminal: the SITL keeps the master and holds the slave open (in raw mode, so the
/// line discipline neither echoes nor translates bytes, and a client closing it does not hang
/// up the master).
struct Pty {
    master: std::fs::File,
    _slave: std::fs::File,
    slave_path: PathBuf,
}

impl Pty {
    fn open() -> std::io::Result<Self> {
        use std::os::fd::FromRawFd;
        // SAFETY: plain libc calls on a descriptor we own; every return value is checked and the
        // descriptor is wrapped in a `File` (closed on drop) before any early return.
        unsafe {
            let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK);
            if fd < 0 {
                return Err(std::io::Error::last_os_error());
            }
            let master = std::fs::File::from_raw_fd(fd);
            if libc::grantpt(fd) != 0 || libc::unlockpt(fd) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            let mut name = [0 as libc::c_char; 128];
            if libc::ptsname_r(fd, name.as_mut_ptr(), name.len()) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            let slave_path = PathBuf::from(
                std::ffi::CStr::from_ptr(name.as_ptr()).to_string_lossy().into_owned(),
            );
            let slave = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .custom_flags(libc::O_NOCTTY)
                .open(&slave_path)?;
            set_raw(&slave)?;
            Ok(Self { master, _slave: slave, slave_path })
        }
    }
}

use std::os::unix::fs::OpenOptionsExt;

fn set_raw(file: &std::fs::File) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    // SAFETY: termios is plain data; tcgetattr fills it before use.
    unsafe {
        let mut termios: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(file.as_raw_fd(), &mut termios) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        libc::cfmakeraw(&mut termios);
        if libc::tcsetattr(file.as_raw_fd(), libc::TCSANOW, &termios) != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

impl Transport for Pty {
    fn read_available(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        match self.master.read(buffer) {
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(0),
            // EIO: no client has the slave open right now; not an error for the server.
            Err(e) if e.raw_os_error() == Some(libc::EIO) => Ok(0),
            other => other,
        }
    }

    fn write_some(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        match self.master.write(bytes) {
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(0),
            other => other,
        }
    }
}
