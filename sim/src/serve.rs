//! The simulator's host links: the byte ports the application's link pass serves (a
//! pseudo-terminal as the board's USB, TCP clients at 127.0.0.1 as more hosts), the simulated
//! board's identity, and the command-line parsing they share.
//!
//! Shared by the SITL ([`crate::sitl`]) and the lockstep bridge (`scenario bridge --tcp-port`).
//! The pass itself (bytes in, requests routed to the tasks' queues, telemetry, bytes out) is
//! the firmware's own ([`firmware::app::system::LinkTask::pass`]); here are only the ports.
//! Everything is non-blocking: what a port does not take now waits in the link's buffer for the
//! next pass.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};

use firmware::app::hal::{Port, PortClosed};
use firmware::app::system::{Link, LinkEnd, Links};
use firmware::app::{BoardInfo, LinkServer, CONTROL_RATE_HZ};
use protocol::{Capabilities, BOARD_NAME_LEN};

/// Capabilities of every simulated board: IMU, motors with RPM telemetry, telemetry streaming,
/// the simulator flag, and the identification without speed reports (every build, as the
/// board's: issue 56).
pub const SIMULATOR_CAPABILITIES: u32 = Capabilities::IMU
    | Capabilities::MOTORS
    | Capabilities::MOTOR_RPM
    | Capabilities::TELEMETRY
    | Capabilities::SIMULATOR
    | Capabilities::IDENTIFIES_WITHOUT_SPEEDS;

/// A signing session for a simulated start-up (`protocol::signing`): the operating system's
/// random numbers, as the board takes its RNG's.
pub fn random_session() -> u64 {
    let mut bytes = [0u8; 8];
    // Without the OS's generator (never seen on a host), the clock still differs per start-up.
    if getrandom::fill(&mut bytes).is_err() {
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH);
        bytes = now.map_or(0, |t| t.as_nanos() as u64).to_le_bytes();
    }
    u64::from_le_bytes(bytes)
}

/// A simulated board's identity: `board` (e.g. "SITL", "BRIDGE"), the serial
/// `"{board}-{seed:08X}"`, [`SIMULATOR_CAPABILITIES`], the 2 kHz control rate and `motor_count`.
pub fn simulator_board_info(board: &'static str, seed: u64, motor_count: u8) -> BoardInfo {
    let mut serial = heapless::String::<BOARD_NAME_LEN>::new();
    let _ = core::fmt::Write::write_fmt(&mut serial, format_args!("{board}-{seed:08X}"));
    BoardInfo {
        board,
        serial,
        capabilities: SIMULATOR_CAPABILITIES,
        control_rate_hz: CONTROL_RATE_HZ,
        motor_count,
    }
}

/// A TCP client's stream as a link port (non-blocking; closed when the client hangs up).
pub struct TcpPort(TcpStream);

impl Port for TcpPort {
    fn read(&mut self, buffer: &mut [u8]) -> Result<usize, PortClosed> {
        match self.0.read(buffer) {
            Ok(0) => Err(PortClosed),
            Ok(n) => Ok(n),
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(0),
            Err(_) => Err(PortClosed),
        }
    }

    fn write(&mut self, bytes: &[u8]) -> Result<usize, PortClosed> {
        match self.0.write(bytes) {
            Ok(n) => Ok(n),
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(0),
            Err(_) => Err(PortClosed),
        }
    }
}

/// The TCP side: a non-blocking listener on 127.0.0.1 and one [`Link`] per accepted client, as a
/// second USB host would be. Served by the application's link pass ([`Links`]); call
/// [`TcpLinks::accept`] before each pass and [`TcpLinks::drop_closed`] after it.
pub struct TcpLinks {
    listener: TcpListener,
    clients: Vec<Link<TcpPort>>,
    info: BoardInfo,
}

impl TcpLinks {
    /// Listens on 127.0.0.1:`port` (0 picks a free one); connections answer as `info`.
    pub fn bind(port: u16, info: BoardInfo) -> std::io::Result<Self> {
        let listener = TcpListener::bind(("127.0.0.1", port))?;
        listener.set_nonblocking(true)?;
        Ok(Self { listener, clients: Vec::new(), info })
    }

    /// The address served.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// The motor count connections accepted from now on report in their info (those already
    /// open keep theirs, as a board's info does not change during a session).
    pub fn set_motor_count(&mut self, motor_count: u8) {
        self.info.motor_count = motor_count;
    }

    /// Accept the clients waiting to connect.
    pub fn accept(&mut self) {
        while let Ok((stream, _)) = self.listener.accept() {
            if stream.set_nonblocking(true).is_ok() {
                let _ = stream.set_nodelay(true);
                let server = LinkServer::new(self.info.clone());
                self.clients.push(Link::new(server, TcpPort(stream)));
            }
        }
    }

    /// Forget the clients that hung up (after the pass that handed over their last requests).
    pub fn drop_closed(&mut self) {
        self.clients.retain(Link::is_open);
    }

    /// Send what waits for every client, then close every connection (a restart: USB
    /// re-enumerates).
    pub fn close_all(&mut self) {
        self.flush();
        self.clients.clear();
    }

    /// Offer what waits in every connection's transmit buffer once more.
    pub fn flush(&mut self) {
        for client in &mut self.clients {
            client.transmit();
        }
    }

    /// Open connections.
    pub fn connections(&self) -> usize {
        self.clients.len()
    }
}

impl Links for TcpLinks {
    fn each(&mut self, f: &mut dyn FnMut(&mut dyn LinkEnd)) {
        self.clients.as_mut_slice().each(f);
    }
}

/// A pseudo-terminal: the server keeps the master and holds the slave open (in raw mode, so the
/// line discipline neither echoes nor translates bytes, and a client closing it does not hang
/// up the master).
///
/// Bytes the master does not take at once wait in a write-behind buffer of
/// [`PTY_HOST_BUFFER_BYTES`]: a Linux pseudo-terminal holds about 17 KB for a reader that pauses,
/// while a USB host's CDC-ACM driver keeps reading the board's endpoint into its tty buffer
/// (64 KiB) whatever the application does. With the buffer, a configurator that pauses for a
/// moment loses telemetry on the SITL exactly when it would on a board.
pub struct Pty {
    master: std::fs::File,
    _slave: std::fs::File,
    slave_path: PathBuf,
    host_buffer: std::collections::VecDeque<u8>,
}

/// What a USB host buffers for a CDC-ACM reader beyond the endpoint, bytes (the Linux tty
/// layer's flip-buffer limit, 64 KiB).
pub const PTY_HOST_BUFFER_BYTES: usize = 64 * 1024;

impl Pty {
    /// Opens a new pseudo-terminal (non-blocking master, raw slave).
    pub fn open() -> std::io::Result<Self> {
        use std::os::fd::FromRawFd;
        use std::os::unix::fs::OpenOptionsExt;
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
            Ok(Self {
                master,
                _slave: slave,
                slave_path,
                host_buffer: std::collections::VecDeque::with_capacity(PTY_HOST_BUFFER_BYTES),
            })
        }
    }

    /// The slave's path, to open like a serial port.
    pub fn slave_path(&self) -> &Path {
        &self.slave_path
    }

    /// The output rate the client last set on the slave, baud: the rate a USB-UART adapter
    /// would run its UART at (a pseudo-terminal itself ignores it). On Linux a master's mode
    /// requests read its slave's termios (the kernel's `tty_mode_ioctl`); `TCGETS2` gives the
    /// rate in baud whether it was set as a `Bnnn` constant or, as the `serialport` crate does,
    /// as `BOTHER` with the number.
    #[cfg(target_os = "linux")]
    pub fn output_baud(&self) -> std::io::Result<u32> {
        use std::os::fd::AsRawFd;
        // SAFETY: termios2 is plain data, filled by the ioctl before use; the descriptor is ours.
        unsafe {
            let mut termios: libc::termios2 = std::mem::zeroed();
            if libc::ioctl(self.master.as_raw_fd(), libc::TCGETS2, &mut termios) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(termios.c_ospeed)
        }
    }
}

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

/// The pseudo-terminal never closes for the server: a client closing the slave is like a USB
/// host closing its port (the board does not see it), and an error reading or writing the
/// master reads as "nothing now".
impl Port for Pty {
    fn read(&mut self, buffer: &mut [u8]) -> Result<usize, PortClosed> {
        // EIO: no client has the slave open right now; WouldBlock: nothing waits.
        Ok(self.master.read(buffer).unwrap_or(0))
    }

    /// Takes as much of `bytes` as the write-behind buffer has room for, and offers the buffer
    /// to the master before and after.
    fn write(&mut self, bytes: &[u8]) -> Result<usize, PortClosed> {
        self.flush_host_buffer();
        let taken = bytes.len().min(PTY_HOST_BUFFER_BYTES - self.host_buffer.len());
        self.host_buffer.extend(&bytes[..taken]);
        self.flush_host_buffer();
        Ok(taken)
    }
}

impl Pty {
    /// Writes what the master takes now from the write-behind buffer (what it does not take,
    /// or cannot take while no client has the slave open, waits).
    fn flush_host_buffer(&mut self) {
        while !self.host_buffer.is_empty() {
            let (front, _) = self.host_buffer.as_slices();
            match self.master.write(front) {
                Ok(n @ 1..) => drop(self.host_buffer.drain(..n)),
                _ => break,
            }
        }
    }
}

/// What a simulated telemetry radio does to the bytes between the configurator and the board
/// (a SiK/RFD900-class modem on a UART): a byte rate, a latency and whole frames lost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadioConfig {
    /// The serial rate, baud (8N1: ten bits a byte), in each direction.
    pub baud: u32,
    /// Time from a frame's last byte into the radio to its first byte out of the other, s.
    pub latency_s: f64,
    /// Probability that a frame (bytes up to a 0x00 delimiter) is lost, in [0, 1).
    pub frame_loss: f64,
}

impl RadioConfig {
    /// Bytes a second in each direction (8N1: ten bits a byte).
    pub fn bytes_per_s(&self) -> u32 {
        self.baud / 10
    }
}

/// One direction of a simulated radio: the bytes the sender gave it, at most the byte rate's
/// worth per second, cut into frames at the delimiter; each frame lost or delivered after the
/// latency.
#[derive(Debug, Default)]
struct RadioDirection {
    /// Bytes the serial line can still take now (the rate's credit, at most one second's).
    credit: f64,
    frame: Vec<u8>,
    in_flight: std::collections::VecDeque<(u64, Vec<u8>)>,
}

impl RadioDirection {
    fn advance(&mut self, elapsed_s: f64, config: &RadioConfig) {
        let rate = f64::from(config.bytes_per_s());
        self.credit = (self.credit + elapsed_s * rate).min(rate);
    }

    /// Take as many of `bytes` as the line allows now; returns how many.
    fn take(
        &mut self,
        bytes: &[u8],
        now_us: u64,
        config: &RadioConfig,
        rng: &mut crate::rng::Rng,
    ) -> usize {
        let n = bytes.len().min(self.credit.max(0.0) as usize);
        self.credit -= n as f64;
        for &byte in &bytes[..n] {
            self.frame.push(byte);
            if byte == 0 {
                let frame = std::mem::take(&mut self.frame);
                if rng.uniform() >= config.frame_loss {
                    let due_us = now_us + (config.latency_s * 1e6) as u64;
                    self.in_flight.push_back((due_us, frame));
                }
            }
        }
        n
    }

    /// The frames due by `now_us`, in order.
    fn due(&mut self, now_us: u64, out: &mut Vec<u8>) {
        while self.in_flight.front().is_some_and(|(due, _)| *due <= now_us) {
            if let Some((_, frame)) = self.in_flight.pop_front() {
                out.extend_from_slice(&frame);
            }
        }
    }
}

/// A pseudo-terminal behind a simulated telemetry radio ([`RadioConfig`]): the configurator opens
/// the slave as it would the radio's USB serial port (`--port`), the board's link serves this
/// port as it would a UART. Call [`RadioPort::set_time`] with the simulated time before each
/// link pass.
pub struct RadioPort {
    pty: Pty,
    config: RadioConfig,
    rng: crate::rng::Rng,
    now_us: u64,
    up: RadioDirection,
    down: RadioDirection,
    /// Host bytes read from the pty and not yet taken by the line.
    from_host: std::collections::VecDeque<u8>,
    /// Bytes delivered to the board, not yet read.
    to_board: std::collections::VecDeque<u8>,
}

impl RadioPort {
    /// The radio's settings.
    pub fn config(&self) -> RadioConfig {
        self.config
    }

    /// A radio over `pty`; the seed draws the lost frames.
    pub fn new(pty: Pty, config: RadioConfig, seed: u64) -> Self {
        Self {
            pty,
            config,
            rng: crate::rng::Rng::new(seed),
            now_us: 0,
            up: RadioDirection::default(),
            down: RadioDirection::default(),
            from_host: std::collections::VecDeque::new(),
            to_board: std::collections::VecDeque::new(),
        }
    }

    /// The slave's path, to open like the radio's serial port.
    pub fn slave_path(&self) -> &Path {
        self.pty.slave_path()
    }

    /// Advance the radio to simulated time `now_us`: the lines' credit grows, frames whose
    /// latency has passed come out at the other end.
    pub fn set_time(&mut self, now_us: u64) {
        let elapsed_s = now_us.saturating_sub(self.now_us) as f64 * 1e-6;
        self.now_us = now_us;
        self.up.advance(elapsed_s, &self.config);
        self.down.advance(elapsed_s, &self.config);
        // Host → board: what the host wrote, through the line.
        let mut buffer = [0u8; 512];
        while let Ok(n @ 1..) = Port::read(&mut self.pty, &mut buffer) {
            self.from_host.extend(&buffer[..n]);
        }
        let pending = self.from_host.make_contiguous();
        let taken = self.down.take(pending, now_us, &self.config, &mut self.rng);
        self.from_host.drain(..taken);
        let mut delivered = Vec::new();
        self.down.due(now_us, &mut delivered);
        self.to_board.extend(delivered);
        // Board → host: frames whose latency has passed.
        let mut out = Vec::new();
        self.up.due(now_us, &mut out);
        if !out.is_empty() {
            let _ = Port::write(&mut self.pty, &out);
        }
    }
}

impl Port for RadioPort {
    fn read(&mut self, buffer: &mut [u8]) -> Result<usize, PortClosed> {
        let n = buffer.len().min(self.to_board.len());
        for (dst, src) in buffer.iter_mut().zip(self.to_board.drain(..n)) {
            *dst = src;
        }
        Ok(n)
    }

    /// Takes what the line's rate allows now (the link server keeps the rest queued).
    fn write(&mut self, bytes: &[u8]) -> Result<usize, PortClosed> {
        Ok(self.up.take(bytes, self.now_us, &self.config, &mut self.rng))
    }
}

/// Parses `X,Y,Z` in millimetres (three comma-separated finite numbers, each within
/// ±[`MAX_IMU_OFFSET_MM`]) into metres: the `--imu-offset-mm` option of `sitl` and
/// `scenario bridge`.
pub fn parse_imu_offset_mm(text: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers X,Y,Z in mm (IMU axes), got {} value(s) in \
             `{text}`",
            parts.len()
        ));
    }
    let mut offset_m = [0.0f32; 3];
    for (axis, (part, out)) in ["X", "Y", "Z"].iter().zip(parts.iter().zip(&mut offset_m)) {
        let mm: f64 = part.parse().map_err(|_| format!("{axis} = `{part}` is not a number"))?;
        if !mm.is_finite() || mm.abs() > MAX_IMU_OFFSET_MM {
            return Err(format!(
                "{axis} = {part} mm is out of range: allowed [-{MAX_IMU_OFFSET_MM}, \
                 {MAX_IMU_OFFSET_MM}] mm"
            ));
        }
        *out = (mm / 1000.0) as f32;
    }
    Ok(offset_m)
}

/// Largest accepted IMU offset component, mm.
pub const MAX_IMU_OFFSET_MM: f64 = 1000.0;

/// A configurator's side of the protocol over TCP, just enough for tests: this crate's own and
/// its integration tests (`tests/bridge.rs`). Panics where a test would fail: no connection, no
/// answer within 2 s, the server closing the connection.
pub struct TestHost {
    stream: TcpStream,
    decoder: protocol::Decoder,
    seq: u16,
}

impl TestHost {
    /// Connects to a server's TCP port at `addr`.
    pub fn connect(addr: SocketAddr) -> Self {
        let stream = TcpStream::connect(addr).unwrap();
        stream.set_read_timeout(Some(std::time::Duration::from_millis(10))).unwrap();
        Self { stream, decoder: protocol::Decoder::new(), seq: 0 }
    }

    /// Sends `request` and waits (up to 2 s) for its response.
    pub fn request(&mut self, request: protocol::Request) -> protocol::Response {
        use protocol::DeviceMessage;
        self.seq += 1;
        let mut frame = [0u8; 256];
        let n = request.encode(self.seq, &mut frame).unwrap();
        self.stream.write_all(&frame[..n]).unwrap();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(2);
        let mut buffer = [0u8; 512];
        while std::time::Instant::now() < deadline {
            let Ok(n) = self.stream.read(&mut buffer) else { continue };
            assert!(n > 0, "the server closed the connection");
            for &byte in &buffer[..n] {
                if let Some(Ok(frame)) = self.decoder.push(byte) {
                    let seq = frame.seq;
                    if let Ok(DeviceMessage::Response(response)) = DeviceMessage::decode(&frame) {
                        if seq == self.seq {
                            return response;
                        }
                    }
                }
            }
        }
        panic!("no answer to request {}", self.seq);
    }

    /// The handshake.
    pub fn hello(&mut self) -> protocol::Response {
        self.request(protocol::Request::Hello(protocol::Hello {
            protocol: protocol::PROTOCOL_VERSION,
            schema_hash: protocol::SCHEMA_HASH,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::with_firmware_app;

    /// Set the output and input rate of the terminal `file` to `baud` as the `serialport` crate
    /// does on Linux (`TCSETS2` with `BOTHER`).
    #[cfg(target_os = "linux")]
    fn set_baud_bother(file: &std::fs::File, baud: u32) {
        use std::os::fd::AsRawFd;
        // SAFETY: termios2 is plain data, read by the first ioctl before it is changed.
        unsafe {
            let mut termios: libc::termios2 = std::mem::zeroed();
            assert_eq!(libc::ioctl(file.as_raw_fd(), libc::TCGETS2, &mut termios), 0);
            termios.c_cflag &= !(libc::CBAUD | libc::CIBAUD);
            termios.c_cflag |= libc::BOTHER;
            termios.c_ispeed = baud;
            termios.c_ospeed = baud;
            assert_eq!(libc::ioctl(file.as_raw_fd(), libc::TCSETS2, &termios), 0);
        }
    }

    /// The rate a client sets on the slave is read on the master, whichever way it was set.
    #[cfg(target_os = "linux")]
    #[test]
    fn the_master_reads_the_rate_the_client_set_on_the_slave() {
        use std::os::fd::AsRawFd;
        let pty = Pty::open().unwrap();
        let client =
            std::fs::OpenOptions::new().read(true).write(true).open(pty.slave_path()).unwrap();
        for baud in [57_600, 921_600, 250_000] {
            set_baud_bother(&client, baud);
            assert_eq!(pty.output_baud().unwrap(), baud);
        }
        // As a C program would: tcsetattr with a B-constant.
        // SAFETY: termios is plain data, filled by tcgetattr before it is changed.
        unsafe {
            let mut termios: libc::termios = std::mem::zeroed();
            assert_eq!(libc::tcgetattr(client.as_raw_fd(), &mut termios), 0);
            assert_eq!(libc::cfsetspeed(&mut termios, libc::B115200), 0);
            assert_eq!(libc::tcsetattr(client.as_raw_fd(), libc::TCSANOW, &termios), 0);
        }
        assert_eq!(pty.output_baud().unwrap(), 115_200);
    }
    use firmware::app::system::ControlQueue;
    use firmware::app::ControlCommand;
    use protocol::{Decoder, DeviceMessage, ExternalPose, Hello, Reply, Request};
    use std::cell::RefCell;
    use std::collections::VecDeque;
    use std::rc::Rc;
    use std::time::{Duration, Instant};

    /// An in-memory port: bytes the host wrote, bytes the device wrote, and whether the host has
    /// hung up (shared with the test, which plays the host).
    #[derive(Clone, Default)]
    struct Memory(Rc<RefCell<Wire>>);

    #[derive(Default)]
    struct Wire {
        to_device: VecDeque<u8>,
        to_host: Vec<u8>,
        closed: bool,
    }

    impl Port for Memory {
        fn read(&mut self, buffer: &mut [u8]) -> Result<usize, PortClosed> {
            let mut wire = self.0.borrow_mut();
            if wire.to_device.is_empty() && wire.closed {
                return Err(PortClosed);
            }
            let n = buffer.len().min(wire.to_device.len());
            for (dst, src) in buffer.iter_mut().zip(wire.to_device.drain(..n)) {
                *dst = src;
            }
            Ok(n)
        }
        fn write(&mut self, bytes: &[u8]) -> Result<usize, PortClosed> {
            self.0.borrow_mut().to_host.extend_from_slice(bytes);
            Ok(bytes.len())
        }
    }

    fn frame(request: &Request, seq: u16) -> Vec<u8> {
        let mut out = [0u8; 256];
        let n = request.encode(seq, &mut out).unwrap();
        out[..n].to_vec()
    }

    fn hello() -> Request {
        Request::Hello(Hello {
            protocol: protocol::PROTOCOL_VERSION,
            schema_hash: protocol::SCHEMA_HASH,
        })
    }

    /// Every response in `bytes`, with its sequence number.
    fn responses(bytes: &[u8]) -> Vec<(u16, protocol::Response)> {
        let mut decoder = Decoder::new();
        let mut out = Vec::new();
        for &b in bytes {
            if let Some(Ok(frame)) = decoder.push(b) {
                if let Ok(DeviceMessage::Response(r)) = DeviceMessage::decode(&frame) {
                    out.push((frame.seq, r));
                }
            }
        }
        out
    }

    /// The commands waiting for the control step, oldest first, without the configuration the
    /// first pass sends (the parameters at start-up).
    fn queued(queue: &ControlQueue) -> Vec<ControlCommand> {
        queue.iter().copied().filter(|c| !matches!(c, ControlCommand::Configure(_))).collect()
    }

    const POSE: ExternalPose =
        ExternalPose { position_ned_m: [1.0, -2.0, -3.5], heading_rad: 0.75 };

    #[test]
    fn a_pass_answers_and_queues_the_commands_in_order() {
        let wire = Memory::default();
        let info = simulator_board_info("BRIDGE", 7, 4);
        let mut link = Link::new(LinkServer::new(info), wire.clone());
        let mut bytes = frame(&hello(), 1);
        // (A disarm drops the commands waiting before it, so it comes first here.)
        bytes.extend(frame(&Request::Disarm(()), 2));
        bytes.extend(frame(&Request::SetExternalPose(POSE), 3));
        wire.0.borrow_mut().to_device.extend(bytes);
        with_firmware_app(|system| {
            system.pass(1000, &mut link);
            assert_eq!(
                queued(&system.handoffs.commands),
                vec![ControlCommand::Disarm, ControlCommand::ExternalPose(POSE)]
            );
            let answers = responses(&wire.0.borrow().to_host);
            assert_eq!(answers.len(), 3);
            match &answers[0] {
                (1, Ok(Reply::Hello(info))) => {
                    assert_eq!(info.board.as_str(), "BRIDGE");
                    assert_eq!(info.serial.as_str(), "BRIDGE-00000007");
                    assert_eq!(info.motor_count, 4);
                    assert_eq!(info.capabilities.0, SIMULATOR_CAPABILITIES);
                }
                other => panic!("expected the hello reply, got {other:?}"),
            }
            assert_eq!(answers[1], (2, Ok(Reply::Done)));
            assert_eq!(answers[2], (3, Ok(Reply::Done)));
            // Nothing is queued twice.
            system.pass(2000, &mut link);
            assert_eq!(queued(&system.handoffs.commands).len(), 2);
        });
    }

    #[test]
    fn a_closed_connection_still_hands_over_what_it_received() {
        let wire = Memory::default();
        let mut link = Link::new(LinkServer::new(simulator_board_info("SITL", 1, 4)), wire.clone());
        let mut bytes = frame(&hello(), 1);
        bytes.extend(frame(&Request::Disarm(()), 2));
        wire.0.borrow_mut().to_device.extend(bytes);
        wire.0.borrow_mut().closed = true;
        with_firmware_app(|system| {
            system.pass(0, &mut link);
            assert!(!link.is_open());
            assert_eq!(queued(&system.handoffs.commands), vec![ControlCommand::Disarm]);
        });
    }

    #[test]
    fn tcp_links_accept_answer_and_drop_closed_clients() {
        let mut links = TcpLinks::bind(0, simulator_board_info("BRIDGE", 1, 0)).unwrap();
        links.set_motor_count(6);
        let addr = links.local_addr().unwrap();
        let mut client = TcpStream::connect(addr).unwrap();
        client.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
        client.write_all(&frame(&hello(), 9)).unwrap();
        client.write_all(&frame(&Request::SetExternalPose(POSE), 10)).unwrap();
        with_firmware_app(|system| {
            let mut received = Vec::new();
            let mut commands = Vec::new();
            let deadline = Instant::now() + Duration::from_secs(2);
            while responses(&received).len() < 2 && Instant::now() < deadline {
                links.accept();
                system.pass(0, &mut links);
                links.drop_closed();
                commands.extend(queued(&system.handoffs.commands));
                system.handoffs.commands.clear();
                let mut buffer = [0u8; 1024];
                if let Ok(n) = client.read(&mut buffer) {
                    received.extend_from_slice(&buffer[..n]);
                }
            }
            assert_eq!(links.connections(), 1);
            let answers = responses(&received);
            assert!(
                matches!(&answers[0], (9, Ok(Reply::Hello(info))) if info.motor_count == 6),
                "{answers:?}"
            );
            assert_eq!(answers[1], (10, Ok(Reply::Done)));
            assert_eq!(commands, vec![ControlCommand::ExternalPose(POSE)]);
            drop(client);
            let deadline = Instant::now() + Duration::from_secs(2);
            while links.connections() > 0 && Instant::now() < deadline {
                system.pass(0, &mut links);
                links.drop_closed();
                std::thread::sleep(Duration::from_millis(1));
            }
            assert_eq!(links.connections(), 0, "the closed client is dropped");
        });
    }

    #[test]
    fn imu_offsets_parse_in_millimetres_and_bad_ones_say_why() {
        assert_eq!(parse_imu_offset_mm("10,-20.5, 30").unwrap(), [0.01, -0.0205, 0.03]);
        assert_eq!(parse_imu_offset_mm("-1000,0,1000").unwrap(), [-1.0, 0.0, 1.0]);
        for (bad, says) in [
            ("1,2", "three"),
            ("1,2,3,4", "three"),
            ("1,x,3", "Y = `x` is not a number"),
            ("1,2,1000.5", "Z = 1000.5 mm is out of range"),
            ("nan,0,0", "X = nan mm is out of range"),
            ("inf,0,0", "out of range"),
            ("", "three"),
        ] {
            let error = parse_imu_offset_mm(bad).unwrap_err();
            assert!(error.contains(says), "`{bad}`: {error}");
        }
    }
}
