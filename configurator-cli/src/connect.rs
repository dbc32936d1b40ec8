//! Finding and opening the board: a serial port chosen by the user or found by USB VID/PID, a
//! TCP address, or a SITL started in-process and opened through its pseudo-terminal exactly as a
//! USB port would be.

use crate::link::{Client, LinkError, Transport};
use serialport::SerialPortType;
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

/// Read timeout of the transports: how long one read waits for bytes.
const READ_TIMEOUT: Duration = Duration::from_millis(20);
/// Baud rate passed to the serial port; USB CDC ignores it, a UART bridge would not.
const BAUD_RATE: u32 = 921_600;

/// Longest host name DNS carries (RFC 1035 §2.3.4: 255 octets on the wire, 253 as text).
const MAX_HOST_NAME_LEN: usize = 253;
/// Longest label (dot-separated part) of a host name (RFC 1035 §2.3.4).
const MAX_HOST_LABEL_LEN: usize = 63;

/// Checks a `--tcp` address, for clap's `value_parser` (so a bad one is a usage error, exit 2,
/// before anything is opened): `IP:PORT` (`127.0.0.1:5760`, `[::1]:5760`) or `NAME:PORT` with a
/// host name of letters, digits, hyphens and dots (RFC 1123), and a port from 1 to 65535. Only
/// the form is checked here; whether a name resolves is learnt when connecting (exit 1 if not,
/// like any board that cannot be reached). Returns the address as given.
pub fn parse_tcp_address(text: &str) -> Result<String, String> {
    let example = "e.g. 127.0.0.1:5760, [::1]:5760 or localhost:5760";
    if let Ok(address) = text.parse::<SocketAddr>() {
        return if address.port() == 0 {
            Err(format!("port 0 cannot be connected to; give the server's port ({example})"))
        } else {
            Ok(text.to_string())
        };
    }
    let Some((host, port)) = text.rsplit_once(':') else {
        return Err(format!("expected HOST:PORT ({example})"));
    };
    port.parse::<u16>()
        .ok()
        .filter(|&p| p > 0)
        .ok_or_else(|| format!("the port `{port}` is not a number from 1 to 65535 ({example})"))?;
    if host.contains(':') || host.starts_with('[') {
        return Err(format!("`{host}` is not an IPv6 address in brackets ({example})"));
    }
    let label_ok = |label: &str| {
        (1..=MAX_HOST_LABEL_LEN).contains(&label.len())
            && label.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
            && !label.starts_with('-')
            && !label.ends_with('-')
    };
    let name = host.strip_suffix('.').unwrap_or(host);
    if name.is_empty() || name.len() > MAX_HOST_NAME_LEN || !name.split('.').all(label_ok) {
        return Err(format!("`{host}` is neither an IP address nor a host name ({example})"));
    }
    Ok(text.to_string())
}

/// Where to find the board.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// A serial device path (`/dev/ttyACM0`, a pseudo-terminal).
    Serial(String),
    /// A TCP address (`127.0.0.1:5760`, `localhost:5760`), as [`parse_tcp_address`] accepts.
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

/// Open the serial device (or pseudo-terminal) at `path` as a transport with the link's read
/// timeout, without a handshake (tests that speak raw frames use it).
pub fn open_serial(path: &str) -> Result<Box<dyn Transport>, ConnectError> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tcp_addresses_of_every_form_are_accepted() {
        for good in ["127.0.0.1:5760", "[::1]:5760", "localhost:5760", "sitl-1.lan.:1", "a:65535"] {
            assert_eq!(parse_tcp_address(good).as_deref(), Ok(good));
        }
    }

    #[test]
    fn a_bad_tcp_address_says_what_is_wrong() {
        let cases = [
            ("notanaddress", "expected HOST:PORT"),
            ("127.0.0.1", "expected HOST:PORT"),
            ("127.0.0.1:", "the port `` is not a number"),
            ("127.0.0.1:70000", "the port `70000` is not a number from 1 to 65535"),
            ("127.0.0.1:0", "port 0 cannot be connected to"),
            ("localhost:http", "the port `http` is not a number"),
            ("::1:5760", "not an IPv6 address in brackets"),
            ("[::1:5760", "not an IPv6 address in brackets"),
            (":5760", "neither an IP address nor a host name"),
            ("bad_name:5760", "neither an IP address nor a host name"),
            ("-lead.example:5760", "neither an IP address nor a host name"),
            ("a..b:5760", "neither an IP address nor a host name"),
        ];
        for (bad, message) in cases {
            let error = parse_tcp_address(bad).expect_err(bad);
            assert!(error.contains(message), "{bad}: {error}");
            assert!(error.contains("e.g. 127.0.0.1:5760"), "{bad}: an example is given: {error}");
        }
        let long_label = format!("{}:5760", "a".repeat(MAX_HOST_LABEL_LEN + 1));
        assert!(parse_tcp_address(&long_label).is_err());
    }
}
