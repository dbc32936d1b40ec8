//! Finding and opening the board: a serial port chosen by the user or found by USB VID/PID, a
//! TCP address, or a SITL started in-process and opened through its pseudo-terminal exactly as a
//! USB port would be.
//!
//! A serial port is opened at a rate ([`Baud`]): USB CDC (the board itself) and pseudo-terminals
//! ignore it, but a telemetry radio's USB-UART adapter does not (a SiK/RFD900 modem runs at
//! 57,600 baud): at the wrong rate every byte arrives garbled, so a handshake that hears bytes
//! but no frame names the rate as the likely cause ([`ConnectError::WrongBaud`]). [`port_kind`]
//! tells such adapters from the board by their USB vendor ID for `ports`.

use crate::link::{Client, LinkError, Transport};
use serialport::SerialPortType;
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

/// Read timeout of the transports: how long one read waits for bytes.
const READ_TIMEOUT: Duration = Duration::from_millis(20);
/// The environment variable read for the serial rate when `--baud` is not given.
pub const BAUD_ENV: &str = "FC_BAUD";

/// A serial port's rate, baud (bits a second on the wire; 8N1: ten bits a byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Baud(u32);

/// Why a baud rate was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BaudError {
    #[error(
        "`{0}` is not a baud rate: give a whole number of bits a second, e.g. 57600 (SiK/RFD900 \
         radios) or 115200"
    )]
    NotANumber(String),
    #[error(
        "{0} baud is outside {min}–{max} baud (SiK/RFD900 radios run at 57600 baud, ESP32 \
         bridges at 115200 or 460800 baud)",
        min = Baud::MIN.0,
        max = Baud::MAX.0
    )]
    OutOfRange(u64),
}

impl Baud {
    /// The rate without `--baud`: what USB CDC (the board, the SITL's pseudo-terminals) is
    /// opened at; it ignores the rate, a USB-UART adapter would not.
    pub const DEFAULT: Baud = Baud(921_600);
    /// The slowest rate accepted, baud (the oldest modems').
    pub const MIN: Baud = Baud(300);
    /// The fastest rate accepted, baud (an FTDI FT232H's 12 Mbaud, the fastest common USB-UART).
    pub const MAX: Baud = Baud(12_000_000);

    /// A rate within [`Baud::MIN`]–[`Baud::MAX`], or why not.
    pub fn new(baud: u64) -> Result<Self, BaudError> {
        match u32::try_from(baud) {
            Ok(baud) if (Self::MIN.0..=Self::MAX.0).contains(&baud) => Ok(Self(baud)),
            _ => Err(BaudError::OutOfRange(baud)),
        }
    }

    /// Parses `--baud` (a whole number, e.g. `57600`), for clap's `value_parser`, so a bad rate
    /// is a usage error (exit 2) before any port is touched.
    pub fn parse(text: &str) -> Result<Self, BaudError> {
        let text = text.trim();
        let baud = text.parse::<u64>().map_err(|_| BaudError::NotANumber(text.to_string()))?;
        Self::new(baud)
    }

    /// The rate in baud.
    pub fn get(self) -> u32 {
        self.0
    }
}

impl std::fmt::Display for Baud {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} baud", self.0)
    }
}

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
    /// A serial device path (`/dev/ttyACM0`, a radio's `/dev/ttyUSB0`, a pseudo-terminal),
    /// opened at `baud`.
    Serial { path: String, baud: Baud },
    /// A TCP address (`127.0.0.1:5760`, `localhost:5760`), as [`parse_tcp_address`] accepts.
    Tcp(String),
    /// The first serial port with our USB VID/PID, opened at `baud`.
    Discover { baud: Baud },
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
    #[error(
        "received {bytes} bytes from {port} but no valid frame: the baud rate is probably wrong \
         (opened at {baud}; SiK/RFD900 radios default to 57600 baud: try --baud 57600)"
    )]
    WrongBaud { port: String, bytes: u64, baud: Baud },
    #[error("cannot start the simulator: {0}")]
    Sitl(#[from] sim::sitl::SitlError),
    #[error(transparent)]
    Link(#[from] LinkError),
}

/// Open the target's transport and handshake.
/// Bytes that arrive but never make a frame say which rate the serial port was opened at.
pub fn connect(target: &Target) -> Result<Client, ConnectError> {
    let (transport, name, baud): (Box<dyn Transport>, String, Option<Baud>) = match target {
        Target::Serial { path, baud } => (open_serial(path, *baud)?, path.clone(), Some(*baud)),
        Target::Tcp(address) => (open_tcp(address)?, address.clone(), None),
        Target::Discover { baud } => {
            let path = discover()?;
            (open_serial(&path, *baud)?, path, Some(*baud))
        }
    };
    match (Client::connect(transport, &name), baud) {
        (Err(LinkError::NoFrame { port, bytes }), Some(baud)) => {
            Err(ConnectError::WrongBaud { port, bytes, baud })
        }
        (result, _) => Ok(result?),
    }
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

/// Open the serial device (or pseudo-terminal) at `path` at `baud` as a transport with the
/// link's read timeout, without a handshake (tests that speak raw frames use it).
pub fn open_serial(path: &str, baud: Baud) -> Result<Box<dyn Transport>, ConnectError> {
    let port = serialport::new(path, baud.get())
        .timeout(READ_TIMEOUT)
        .open()
        .map_err(|e| ConnectError::Open { port: path.to_string(), reason: e.to_string() })?;
    Ok(Box::new(port))
}

/// USB vendor IDs of the USB-UART bridge chips that telemetry radios (SiK, RFD900, ESP32
/// bridges) and USB-serial adapters carry, with the chip's name.
pub const USB_UART_VENDORS: [(u16, &str); 3] =
    [(0x0403, "FTDI"), (0x10c4, "Silicon Labs CP210x"), (0x1a86, "WCH CH340")];

/// What a serial port looks like, by its USB vendor and product IDs. (`serialport` reads them
/// from sysfs, `/sys/class/tty/<name>/device/../idVendor`, without libudev.)
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PortKind {
    /// Our board over USB ([`protocol::USB_VID`]:[`protocol::USB_PID`]): USB CDC, any rate.
    Board,
    /// A USB-UART bridge ([`USB_UART_VENDORS`]): a telemetry radio or a USB-serial adapter,
    /// which must be opened at its UART's rate.
    UsbUart { chip: &'static str, vid: u16, pid: u16 },
    /// Another USB device.
    OtherUsb { vid: u16, pid: u16 },
    /// Not on USB (a built-in UART, PCI, Bluetooth, or unknown).
    NotUsb,
}

impl PortKind {
    /// A short name for JSON: `board`, `usb-uart`, `usb` or `other`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Board => "board",
            Self::UsbUart { .. } => "usb-uart",
            Self::OtherUsb { .. } => "usb",
            Self::NotUsb => "other",
        }
    }

    /// What the port is and how to open it, in words.
    pub fn description(&self) -> String {
        match self {
            Self::Board => format!(
                "flight controller over USB ({:04x}:{:04x}; no --baud needed)",
                protocol::USB_VID,
                protocol::USB_PID
            ),
            Self::UsbUart { chip, vid, pid } => format!(
                "{chip} USB-UART ({vid:04x}:{pid:04x}): a radio or USB-serial adapter: give \
                 --baud, 57600 for SiK/RFD900"
            ),
            Self::OtherUsb { vid, pid } => format!("USB {vid:04x}:{pid:04x}"),
            Self::NotUsb => "not USB (a built-in UART, PCI or Bluetooth)".into(),
        }
    }
}

/// What the port of `port_type` looks like ([`PortKind`]).
pub fn port_kind(port_type: &SerialPortType) -> PortKind {
    let SerialPortType::UsbPort(usb) = port_type else { return PortKind::NotUsb };
    let (vid, pid) = (usb.vid, usb.pid);
    if (vid, pid) == (protocol::USB_VID, protocol::USB_PID) {
        return PortKind::Board;
    }
    match USB_UART_VENDORS.iter().find(|(vendor, _)| *vendor == vid) {
        Some(&(_, chip)) => PortKind::UsbUart { chip, vid, pid },
        None => PortKind::OtherUsb { vid, pid },
    }
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

    #[test]
    fn baud_rates_in_range_are_taken_and_others_say_why() {
        for (text, baud) in [("57600", 57_600), (" 115200 ", 115_200), ("300", 300)] {
            assert_eq!(Baud::parse(text).map(Baud::get), Ok(baud), "{text}");
        }
        assert_eq!(Baud::parse("12000000"), Ok(Baud::MAX));
        for (bad, says) in [
            ("0", "0 baud is outside 300–12000000 baud"),
            ("299", "299 baud is outside"),
            ("12000001", "12000001 baud is outside"),
            ("99999999999999999999", "is not a baud rate"),
            ("57,600", "`57,600` is not a baud rate"),
            ("-9600", "`-9600` is not a baud rate"),
            ("", "`` is not a baud rate"),
        ] {
            let error = Baud::parse(bad).expect_err(bad).to_string();
            assert!(error.contains(says), "{bad}: {error}");
            assert!(error.contains("57600"), "{bad}: the SiK rate is named: {error}");
        }
    }

    fn usb(vid: u16, pid: u16) -> SerialPortType {
        SerialPortType::UsbPort(serialport::UsbPortInfo {
            vid,
            pid,
            serial_number: None,
            manufacturer: None,
            product: None,
        })
    }

    #[test]
    fn usb_uart_bridges_are_told_from_the_board_by_their_ids() {
        assert_eq!(port_kind(&usb(0x1209, 0x0001)), PortKind::Board);
        assert_eq!(
            port_kind(&usb(0x0403, 0x6015)),
            PortKind::UsbUart { chip: "FTDI", vid: 0x0403, pid: 0x6015 }
        );
        assert!(matches!(port_kind(&usb(0x10c4, 0xea60)), PortKind::UsbUart { .. }));
        assert!(matches!(port_kind(&usb(0x1a86, 0x7523)), PortKind::UsbUart { .. }));
        // Another pid.codes product is not our board.
        assert_eq!(
            port_kind(&usb(0x1209, 0x0002)),
            PortKind::OtherUsb { vid: 0x1209, pid: 0x0002 }
        );
        assert_eq!(port_kind(&SerialPortType::PciPort), PortKind::NotUsb);
        let radio = port_kind(&usb(0x0403, 0x6001)).description();
        assert!(radio.contains("give --baud, 57600 for SiK/RFD900"), "{radio}");
    }
}
