//! Finding and opening the board: a serial port chosen by the user or found by USB VID/PID, a
//! TCP address, or a SITL started in-process and opened through its pseudo-terminal exactly as a
//! USB port would be.

use crate::link::{Client, LinkError, Transport};
use serialport::SerialPortType;
use std::net::TcpStream;
use std::time::Duration;

/// Read timeout of the transports: how long one read waits for bytes.
const READ_TIMEOUT: Duration = Duration::from_millis(20);
/// Baud rate passed to the serial port; USB CDC ignores it, a UART bridge would not.
const BAUD_RATE: u32 = 921_600;

/// Where to find the board.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// A serial device path (`/dev/ttyACM0`, a pseudo-terminal).
    Serial(String),
    /// A TCP address (`127.0.0.1:5760`).
    Tcp(String),
    /// The first serial port with our USB VID/PID.
    Discover,
}

/// Why no connection was made.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    #[error(
        "no flight controller found on USB (looked for VID {vid:04x} PID {pid:04x} among {ports} serial port(s)); \
connect the board, choose a port with --port PATH, or try the simulator with --sitl"
    )]
    NotFound { vid: u16, pid: u16, ports: usize },
    #[error("several flight controllers found ({0}); choose one with --port PATH")]
    Ambiguous(String),
    #[error("cannot list serial ports: {0}")]
    Enumerate(serialport::Error),
    #[error("cannot open {port}: {reason}")]
    Open { port: String, reason: String },
    #[error("cannot start the simulator: {0}")]
    Sitl(#[from] sim::sitl::SitlError),
    #[error(transparent)]
    Link(#[from] LinkError),
}

/// Open the target's transport and handshake.
pub fn connect(target: &Target) -> Result<Client, ConnectError> {
    let (transport, name): (Box<dyn Transport>, String) = match target {
        Target::Serial(path) => (open_serial(path)?, path.clone()),
        Target::Tcp(address) => (open_tcp(address)?, address.clone()),
        Target::Discover => {
            let path = discover()?;
            (open_serial(&path)?, path)
        }
    };
    Ok(Client::connect(transport, &name)?)
}

/// How long [`reconnect`] waits for a restarting board to come back.
pub const RECONNECT_TIMEOUT: Duration = Duration::from_secs(15);
/// Pause between two attempts to find and open a restarting board.
const RECONNECT_RETRY: Duration = Duration::from_millis(250);

/// Open the target again after the board restarted (its USB port disappears and comes back,
/// perhaps under another name, which [`Target::Discover`] follows): retry [`connect`] until it
/// succeeds or `timeout` has passed. Close the old client first (serial ports are opened
/// exclusively). Returns the client and how long the board took to come back.
pub fn reconnect(target: &Target, timeout: Duration) -> Result<(Client, Duration), ConnectError> {
    let started = std::time::Instant::now();
    loop {
        std::thread::sleep(RECONNECT_RETRY);
        match connect(target) {
            Ok(client) => return Ok((client, started.elapsed())),
            Err(error) if started.elapsed() >= timeout => return Err(error),
            Err(_) => {}
        }
    }
}

/// The serial port of the one attached board with our VID/PID.
pub fn discover() -> Result<String, ConnectError> {
    let ports = serialport::available_ports().map_err(ConnectError::Enumerate)?;
    let ours: Vec<String> = ports
        .iter()
        .filter(|port| match &port.port_type {
            SerialPortType::UsbPort(usb) => {
                usb.vid == protocol::USB_VID && usb.pid == protocol::USB_PID
            }
            _ => false,
        })
        .map(|port| port.port_name.clone())
        .collect();
    match ours.as_slice() {
        [] => Err(ConnectError::NotFound {
            vid: protocol::USB_VID,
            pid: protocol::USB_PID,
            ports: ports.len(),
        }),
        [one] => Ok(one.clone()),
        many => Err(ConnectError::Ambiguous(many.join(", "))),
    }
}

fn open_serial(path: &str) -> Result<Box<dyn Transport>, ConnectError> {
    let port = serialport::new(path, BAUD_RATE)
        .timeout(READ_TIMEOUT)
        .open()
        .map_err(|e| ConnectError::Open { port: path.to_string(), reason: e.to_string() })?;
    Ok(Box::new(port))
}

fn open_tcp(address: &str) -> Result<Box<dyn Transport>, ConnectError> {
    let open_error =
        |e: std::io::Error| ConnectError::Open { port: address.to_string(), reason: e.to_string() };
    let stream = TcpStream::connect(address).map_err(open_error)?;
    stream.set_read_timeout(Some(READ_TIMEOUT)).map_err(open_error)?;
    stream.set_nodelay(true).map_err(open_error)?;
    Ok(Box::new(stream))
}
