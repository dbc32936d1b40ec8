//! The host's side of the protocol: a client over any byte transport (a serial port, a
//! pseudo-terminal, TCP).
//!
//! Every request carries a fresh sequence number and waits for the response with that number;
//! when none comes (a frame lost on a radio) the very same frame is sent again, which the board
//! answers without acting twice. Telemetry and events that arrive meanwhile are kept for the
//! caller. Frames start with a 0x00
//! so a board whose decoder holds garbage from an earlier session resynchronises at once.

use protocol::signing::{self, LinkKey};
use protocol::{
    peek_hello_version, Decoder, DeviceError, DeviceMessage, Event, Hello, Info, Reply, Request,
    Response, Signer, StorageStage, Telemetry, Version, MAX_FRAME_LEN, PROTOCOL_VERSION,
    RESPONSE_ID, SCHEMA_HASH,
};
use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::time::{Duration, Instant};

/// How long a request waits for its response by default.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(1500);
/// How long a request waits at least before it is asked again: a USB board answers
/// within milliseconds, a 57,600-baud telemetry radio with 20 ms latency within about 0.1 s (a
/// status frame of 200 bytes takes 35 ms on the air), so 0.4 s means the request or its answer
/// was lost. A slower link waits four of its handshake's round trips instead (9,600 baud with
/// 100 ms latency: about 0.3 s each; 150 ms latency: about 0.35 s).
pub const RETRY_AFTER: Duration = Duration::from_millis(400);
/// Attempts of a request whose answer does not come (the last waits the whole timeout).
const ATTEMPTS: u32 = 3;

/// A byte transport: anything readable and writable whose reads time out (serial ports and
/// sockets with a read timeout set).
pub trait Transport: Read + Write + Send {}
impl<T: Read + Write + Send> Transport for T {}

/// Why talking to the board failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("I/O error on {port}: {source}")]
    Io { port: String, source: std::io::Error },
    #[error("{port} was closed by the other side (board unplugged or simulator stopped?)")]
    Closed { port: String },
    #[error("no answer from {port} within {timeout_ms} ms to {what} (is it a flight controller running our firmware?)")]
    Timeout { port: String, timeout_ms: u128, what: &'static str },
    /// The handshake heard bytes but not one frame: garbage, as a serial line at the wrong rate
    /// gives (`crate::connect` names the rate for serial ports).
    #[error("received {bytes} bytes from {port} but no valid frame to the handshake (is it a flight controller running our firmware?)")]
    NoFrame { port: String, bytes: u64 },
    #[error("incompatible protocol: the board speaks {device}, this configurator speaks {host}; update the {older}")]
    Incompatible { device: VersionText, host: VersionText, older: &'static str },
    #[error("the board refused the request: {0}")]
    Device(DeviceErrorText),
    #[error("unexpected answer from the board: {0}")]
    Unexpected(String),
}

/// A protocol version for messages: "1.0".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VersionText(pub Version);

impl std::fmt::Display for VersionText {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "protocol {}.{}", self.0.major, self.0.minor)
    }
}

/// A device error in words.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceErrorText(pub DeviceError);

impl std::fmt::Display for DeviceErrorText {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            DeviceError::IncompatibleProtocol { device, host } => write!(
                f,
                "incompatible protocol (board {}.{}, configurator {}.{})",
                device.major, device.minor, host.major, host.minor
            ),
            DeviceError::HandshakeRequired => write!(f, "handshake required first"),
            DeviceError::UnknownRequest { id } => {
                write!(f, "the board does not know request 0x{id:02x} (older firmware?)")
            }
            DeviceError::Malformed { id } => write!(f, "request 0x{id:02x} was malformed"),
            DeviceError::BadValue { name, value, .. } if !value.is_finite() => {
                write!(f, "{name} is not a finite number")
            }
            DeviceError::BadValue { name, value, min, max, unit } => {
                let unit = if unit.is_empty() { String::new() } else { format!(" {unit}") };
                write!(
                    f,
                    "{name} = {value}{unit} is outside the allowed range {min} to {max}{unit}"
                )
            }
            DeviceError::Busy => write!(f, "the board is busy; try again"),
            DeviceError::RefusedWhileArmed => write!(f, "refused while armed; disarm first"),
            DeviceError::UnknownParam { name } => {
                write!(f, "no parameter is called `{name}` (`dump` lists them)")
            }
            DeviceError::WrongLength { name, expected, got } => write!(
                f,
                "{name} takes {expected} value{} (comma-separated), not {got}",
                if *expected == 1 { "" } else { "s" }
            ),
            DeviceError::NotAnInteger { name, value } => {
                write!(f, "{name} takes whole numbers, not {value}")
            }
            DeviceError::StorageFailed { stage } => {
                let stage = match stage {
                    StorageStage::NoStore => "the board has no configuration store",
                    StorageStage::Read => "reading the flash failed",
                    StorageStage::Write => "writing the flash failed",
                    StorageStage::TooLarge => "the configuration is too large (firmware bug)",
                };
                write!(f, "save failed: {stage}; the saved configuration is unchanged")
            }
            DeviceError::NotReady => write!(f, "not ready (see `status`)"),
            DeviceError::Unsupported => write!(f, "this device cannot do that"),
            DeviceError::SignatureRequired => write!(
                f,
                "refused: over this link (a radio) the board takes configuration, arming, motor \
                 and steering requests only signed with the key paired over USB; connect once \
                 over USB and run `configurator-cli pair`"
            ),
            DeviceError::BadSignature => write!(
                f,
                "refused: the request's signature is not the board's paired key (paired with \
                 another computer, or unpaired?); pair again over USB"
            ),
            DeviceError::Replayed { last_timestamp } => write!(
                f,
                "refused as a replay: the board has accepted a signed request with a later \
                 timestamp ({last_timestamp}; this computer's clock behind?)"
            ),
            DeviceError::TrustedLinkOnly => {
                write!(f, "refused: only over USB (a trusted link) can the link key be set")
            }
            DeviceError::SpeedsNotReported { motors } => write!(
                f,
                "not armed: motor{} {} report{} no speed (no answer within {} ms); the learner \
                 needs every motor's speed: ESCs with bidirectional DShot (BLHeli_32, Bluejay, \
                 AM32) and `motor_bidir_dshot` = 1 (ESCs without it: `motor_bidir_dshot` = 0, \
                 `save`, `reboot`: the firmware then identifies from the commands)",
                if motors.count_ones() == 1 { "" } else { "s" },
                motor_list(*motors),
                if motors.count_ones() == 1 { "s" } else { "" },
                protocol::SPEED_REPORT_TIMEOUT_MS
            ),
            DeviceError::NoSuchLog { number } => {
                write!(f, "the board has no log {number} (`log list` lists them)")
            }
            DeviceError::LogOffsetPastEnd { number, size_bytes } => write!(
                f,
                "log {number} holds only {size_bytes} bytes (a partial download longer than the log is not one of it)"
            ),
            DeviceError::LogBeingWritten { number } => write!(
                f,
                "log {number} is still being written (the craft is armed or just disarmed); try again once it has closed"
            ),
            DeviceError::LogStorageFailed => write!(f, "the board's log storage failed"),
        }
    }
}

/// Whether a paired configurator signs `request`: what commands the craft
/// ([`protocol::commands_the_craft`]), and a disarm. A disarm needs no signature to be obeyed,
/// but since protocol 1.14 an unsigned one over an untrusted link (a radio) lands a flying craft
/// instead of stopping it, as anyone on the channel may have sent it; the paired configurator's
/// signed disarm stops the motors at once.
pub fn signed_when_paired(request: &Request) -> bool {
    protocol::commands_the_craft(request) || matches!(request, Request::Disarm(()))
}

/// Motors named by a bit mask, numbered from 1 as on the craft: "1, 3".
pub fn motor_list(motors: u8) -> String {
    (0..8)
        .filter(|i| motors & (1 << i) != 0)
        .map(|i| (i + 1).to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The transport of a closed client.
struct Closed;

impl Read for Closed {
    fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
        Ok(0)
    }
}

impl Write for Closed {
    fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
        Err(ErrorKind::NotConnected.into())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// A telemetry sample with its per-topic sequence number.
#[derive(Debug, Clone, PartialEq)]
pub struct TelemetrySample {
    pub seq: u16,
    pub data: Telemetry,
}

/// A connected, handshaken board.
pub struct Client {
    transport: Box<dyn Transport>,
    port: String,
    decoder: Decoder,
    next_seq: u16,
    timeout: Duration,
    /// The board's identity from the handshake.
    pub info: Info,
    /// Telemetry that arrived while waiting for responses, oldest first.
    pub telemetry: VecDeque<TelemetrySample>,
    /// Events that arrived, oldest first.
    pub events: VecDeque<Event>,
    /// Frames from the board that failed to decode (CRC, framing) since connecting.
    pub bad_frames: u32,
    /// Bytes received from the board since connecting.
    pub bytes_rx: u64,
    /// Frames from the board that decoded (framing and CRC good) since connecting.
    pub frames_rx: u64,
    /// Requests asked again after a lost frame or answer, since connecting.
    retries: u32,
    /// How long a request waits before it is asked again: [`RETRY_AFTER`], or four
    /// handshake round trips on a slower link (a radio with a long latency).
    retry_after: Duration,
    /// The paired key and the board's session, when this computer keeps a key for the board
    /// (`crate::keys`): requests that command the craft are then signed.
    signer: Option<Signer>,
    /// The last timestamp signed with (10 µs since 2015-01-01 UTC); the next is greater.
    last_timestamp: u64,
}

impl Client {
    /// Handshake over `transport` (named `port` in messages). Refuses another major version.
    pub fn connect(transport: Box<dyn Transport>, port: &str) -> Result<Self, LinkError> {
        let mut client = Self {
            transport,
            port: port.to_string(),
            decoder: Decoder::new(),
            next_seq: initial_seq(),
            timeout: DEFAULT_TIMEOUT,
            info: placeholder_info(),
            telemetry: VecDeque::new(),
            events: VecDeque::new(),
            bad_frames: 0,
            bytes_rx: 0,
            frames_rx: 0,
            retries: 0,
            retry_after: RETRY_AFTER,
            signer: None,
            last_timestamp: 0,
        };
        client.discard_stale_input()?;
        let hello = Request::Hello(Hello { protocol: PROTOCOL_VERSION, schema_hash: SCHEMA_HASH });
        let sent = Instant::now();
        // Asked again like any request when its frame or answer is lost on a radio (a hello
        // changes nothing). The round trip sets the retry interval only when the first frame
        // was answered: after a loss, the time measured is the retry's, not the link's.
        let answer = match client.ask(&hello, "the handshake") {
            // Bytes came, yet not one frame: garbage, not silence (a serial line at the wrong
            // rate garbles every byte both ways; the board counts our garbled hellos as link
            // errors and reports them, garbled in turn).
            Err(LinkError::Timeout { .. }) if client.bytes_rx > 0 && client.frames_rx == 0 => {
                return Err(LinkError::NoFrame {
                    port: client.port.clone(),
                    bytes: client.bytes_rx,
                });
            }
            answer => answer?,
        };
        if client.retries == 0 {
            client.retry_after = RETRY_AFTER.max(sent.elapsed() * 4).min(client.timeout);
        }
        let info = match answer {
            Ok(Reply::Hello(info)) => info,
            Err(DeviceError::IncompatibleProtocol { device, host }) => {
                return Err(incompatible(device, host));
            }
            Err(error) => return Err(LinkError::Device(DeviceErrorText(error))),
            Ok(other) => return Err(LinkError::Unexpected(format!("{other:?} to the handshake"))),
        };
        if info.protocol.major != PROTOCOL_VERSION.major {
            return Err(incompatible(info.protocol, PROTOCOL_VERSION));
        }
        client.info = info;
        if let Ok(Some(key)) = crate::keys::load(&client.info.serial) {
            client.sign_with(key)?;
        }
        Ok(client)
    }

    /// Sign what commands the craft with `key` from now on, in the board's current session (a
    /// board older than protocol 1.8 signs nothing).
    pub fn sign_with(&mut self, key: LinkKey) -> Result<(), LinkError> {
        match self.request(&Request::GetLinkSecurity(()), "the link security") {
            Ok(Reply::LinkSecurity(security)) => {
                self.signer = Some(Signer { key, session: security.session });
                self.last_timestamp = self.last_timestamp.max(security.last_timestamp);
                Ok(())
            }
            Err(LinkError::Device(DeviceErrorText(DeviceError::UnknownRequest { .. }))) => Ok(()),
            Err(error) => Err(error),
            Ok(other) => Err(LinkError::Unexpected(format!("{other:?} to GetLinkSecurity"))),
        }
    }

    /// Whether requests that command the craft are signed on this connection.
    pub fn signs(&self) -> bool {
        self.signer.is_some()
    }

    /// The next signing timestamp: the clock in 10 µs since 2015-01-01 UTC, or one more than
    /// the last when the clock has not moved past it.
    fn next_timestamp(&mut self) -> u64 {
        let unix =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        let since_epoch = unix.saturating_sub(Duration::from_secs(signing::TIMESTAMP_EPOCH_UNIX_S));
        let now = (since_epoch.as_micros() / 10) as u64;
        self.last_timestamp = now.max(self.last_timestamp + 1).min(signing::MAX_TIMESTAMP);
        self.last_timestamp
    }

    /// Close the transport now (the board is restarting, or the port must be reopened); every
    /// later request fails with [`LinkError::Closed`].
    pub fn close(&mut self) {
        self.transport = Box::new(Closed);
    }

    /// Whether both sides were built from the same message table.
    pub fn schema_matches(&self) -> bool {
        self.info.schema_hash == SCHEMA_HASH && self.info.protocol == PROTOCOL_VERSION
    }

    /// How long requests wait for their response (a save erasing a 128 KiB flash sector on the
    /// board takes about two seconds).
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    /// The port's name.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// Send a request and wait for its response; a device error becomes [`LinkError::Device`].
    pub fn request(&mut self, request: &Request, what: &'static str) -> Result<Reply, LinkError> {
        let response = match self.ask(request, what)? {
            // Refused as a replay (nothing was done): this computer's clock is behind what the
            // board accepted last; sign once more past it.
            Err(DeviceError::Replayed { last_timestamp }) if self.signer.is_some() => {
                self.last_timestamp = self.last_timestamp.max(last_timestamp);
                self.ask(request, what)?
            }
            other => other,
        };
        response.map_err(|e| LinkError::Device(DeviceErrorText(e)))
    }

    /// Send `request` as one frame and wait for its answer. When none comes within the retry
    /// interval (a frame lost on a radio), send the very same frame again ([`ATTEMPTS`] in all,
    /// the last waiting the whole timeout). Nothing is carried out twice: a read changes
    /// nothing, and the board keeps its answer to the last request that commands the craft and
    /// gives it again for the same frame (`firmware::app::link`).
    fn ask(
        &mut self,
        request: &Request,
        what: &'static str,
    ) -> Result<Result<Reply, DeviceError>, LinkError> {
        let (seq, frame) = self.encode(request)?;
        for _ in 1..ATTEMPTS {
            self.write_frame(&frame)?;
            match self.await_response(seq, what, self.retry_after) {
                Err(LinkError::Timeout { .. }) => self.retries += 1,
                other => return other,
            }
        }
        self.write_frame(&frame)?;
        self.await_response(seq, what, self.timeout)
    }

    /// Send `request` without waiting for its answer (a stream of poses, pipelined log chunks:
    /// each would otherwise wait a round trip); [`Client::take_responses`] or
    /// [`Client::answers`] collects the answers. Returns its sequence number.
    pub fn post(&mut self, request: &Request) -> Result<u16, LinkError> {
        let (seq, frame) = self.encode(request)?;
        self.write_frame(&frame)?;
        Ok(seq)
    }

    /// Read what has arrived (waiting at most the transport's read timeout): telemetry and
    /// events are kept as always; the responses are returned, with their sequence numbers.
    pub fn take_responses(&mut self) -> Result<Vec<(u16, protocol::Response)>, LinkError> {
        let mut responses = Vec::new();
        self.read_some(|seq, message| {
            if let Ok(DeviceMessage::Response(response)) = message {
                responses.push((seq, response));
            }
        })?;
        Ok(responses)
    }

    /// Requests asked again after a lost frame or answer, since the connection opened.
    pub fn retries(&self) -> u32 {
        self.retries
    }

    /// How long a read-only request waits before it is asked again on this link.
    pub fn retry_after(&self) -> Duration {
        self.retry_after
    }

    /// Count a request asked again by a caller that pipelines ([`Client::retries`]).
    pub fn count_retry(&mut self) {
        self.retries += 1;
    }

    /// Wait up to `timeout` for answers to the requests numbered `pending`: every such answer
    /// that arrived by the first read that brought one (empty after the timeout). Answers to
    /// other numbers (a request asked twice) are dropped.
    pub fn answers(
        &mut self,
        pending: &[u16],
        timeout: Duration,
    ) -> Result<Vec<(u16, Response)>, LinkError> {
        let deadline = Instant::now() + timeout;
        let mut answers = Vec::new();
        let mut undecodable = false;
        while answers.is_empty() && Instant::now() < deadline {
            self.read_some(|seq, message| match message {
                Ok(DeviceMessage::Response(response)) if pending.contains(&seq) => {
                    answers.push((seq, response))
                }
                Err(_) if pending.contains(&seq) => undecodable = true,
                _ => {}
            })?;
            if undecodable {
                return Err(LinkError::Unexpected("undecodable response".into()));
            }
        }
        Ok(answers)
    }

    /// Read for `duration`, collecting telemetry and events.
    pub fn listen(&mut self, duration: Duration) -> Result<(), LinkError> {
        let deadline = Instant::now() + duration;
        while Instant::now() < deadline {
            self.read_some(|_, _| {})?;
        }
        Ok(())
    }

    /// Read for `duration`, handing each telemetry sample to `on_sample` as it arrives (nothing
    /// is kept, so a long stream needs no memory).
    pub fn listen_with(
        &mut self,
        duration: Duration,
        mut on_sample: impl FnMut(TelemetrySample),
    ) -> Result<(), LinkError> {
        let deadline = Instant::now() + duration;
        while Instant::now() < deadline {
            self.read_some(|_, _| {})?;
            self.telemetry.drain(..).for_each(&mut on_sample);
        }
        Ok(())
    }

    /// Drop whatever the port holds from an earlier session (late responses, telemetry nobody
    /// stopped) so it cannot be taken for an answer: read until the line has been quiet for
    /// [`QUIET_BEFORE_HELLO`], for at most [`MAX_DISCARD_TIME`].
    fn discard_stale_input(&mut self) -> Result<(), LinkError> {
        let started = Instant::now();
        let mut last_byte = Instant::now();
        let mut buffer = [0u8; 1024];
        while last_byte.elapsed() < QUIET_BEFORE_HELLO && started.elapsed() < MAX_DISCARD_TIME {
            match self.transport.read(&mut buffer) {
                Ok(0) => return Err(self.io(ErrorKind::UnexpectedEof.into())),
                Ok(_) => last_byte = Instant::now(),
                Err(e) if is_no_data(&e) => {}
                Err(source) => return Err(self.io(source)),
            }
        }
        self.decoder = Decoder::new();
        Ok(())
    }

    /// `request` as one frame (a leading 0x00 included) under a fresh sequence number; signed
    /// when [`signed_when_paired`] and this computer keeps the board's key.
    fn encode(&mut self, request: &Request) -> Result<(u16, Vec<u8>), LinkError> {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        let mut frame = [0u8; MAX_FRAME_LEN + 1];
        let encoded = match self.signer {
            Some(signer) if signed_when_paired(request) => {
                let timestamp = self.next_timestamp();
                request.encode_signed(seq, &signer, timestamp, &mut frame[1..])
            }
            _ => request.encode(seq, &mut frame[1..]),
        };
        let len = encoded
            .map_err(|e| LinkError::Unexpected(format!("request does not fit a frame: {e:?}")))?;
        Ok((seq, frame[..=len].to_vec()))
    }

    fn write_frame(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.transport.write_all(frame).map_err(|source| self.io(source))?;
        self.transport.flush().map_err(|source| self.io(source))
    }

    fn await_response(
        &mut self,
        seq: u16,
        what: &'static str,
        timeout: Duration,
    ) -> Result<Result<Reply, DeviceError>, LinkError> {
        let deadline = Instant::now() + timeout;
        let mut answer = None;
        let mut undecodable: Option<Vec<u8>> = None;
        loop {
            if let Some(payload) = undecodable.take() {
                // A response we cannot decode: if it is a handshake reply, name the board's
                // version.
                return Err(match peek_hello_version(&payload) {
                    Some(device) if device.major != PROTOCOL_VERSION.major => {
                        incompatible(device, PROTOCOL_VERSION)
                    }
                    _ => LinkError::Unexpected(format!("undecodable response to {what}")),
                });
            }
            if let Some(response) = answer.take() {
                return Ok(response);
            }
            if Instant::now() >= deadline {
                return Err(LinkError::Timeout {
                    port: self.port.clone(),
                    timeout_ms: self.timeout.as_millis(),
                    what,
                });
            }
            self.read_some(|frame_seq, message| match message {
                Ok(DeviceMessage::Response(response)) if frame_seq == seq => {
                    answer = Some(response)
                }
                Err(payload) if frame_seq == seq => undecodable = Some(payload),
                _ => {}
            })?;
        }
    }

    /// Read what is available (waiting up to the transport's read timeout) and dispatch frames:
    /// telemetry and events are queued, other messages (and undecodable response payloads)
    /// are handed to `on_message`.
    fn read_some(
        &mut self,
        mut on_message: impl FnMut(u16, Result<DeviceMessage, Vec<u8>>),
    ) -> Result<(), LinkError> {
        // 4 KiB: 16 ms of the 2 kHz state topic per read.
        let mut buffer = [0u8; 4096];
        let n = match self.transport.read(&mut buffer) {
            // End of file: the board closed the connection (TCP) or hung up (serial).
            Ok(0) => return Err(self.io(ErrorKind::UnexpectedEof.into())),
            Ok(n) => n,
            Err(e) if is_no_data(&e) => 0,
            Err(source) => return Err(self.io(source)),
        };
        if n == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
        self.bytes_rx += n as u64;
        for &byte in &buffer[..n] {
            let Some(result) = self.decoder.push(byte) else { continue };
            let Ok(frame) = result else {
                self.bad_frames += 1;
                continue;
            };
            self.frames_rx += 1;
            match DeviceMessage::decode(&frame) {
                Ok(DeviceMessage::Telemetry(data)) => {
                    self.telemetry.push_back(TelemetrySample { seq: frame.seq, data })
                }
                Ok(DeviceMessage::Event(event)) => self.events.push_back(event),
                Ok(message) => on_message(frame.seq, Ok(message)),
                Err(_) if frame.id == RESPONSE_ID => {
                    on_message(frame.seq, Err(frame.payload.to_vec()))
                }
                Err(_) => self.bad_frames += 1,
            }
        }
        Ok(())
    }

    fn io(&self, source: std::io::Error) -> LinkError {
        let port = self.port.clone();
        match source.kind() {
            ErrorKind::UnexpectedEof
            | ErrorKind::ConnectionReset
            | ErrorKind::ConnectionAborted
            | ErrorKind::BrokenPipe => LinkError::Closed { port },
            _ => LinkError::Io { port, source },
        }
    }
}

/// How long the line must be quiet before the handshake is sent.
const QUIET_BEFORE_HELLO: Duration = Duration::from_millis(20);
/// Longest time spent discarding stale input (a board streaming telemetry from an earlier
/// session never goes quiet; its frames are then told apart by sequence number).
const MAX_DISCARD_TIME: Duration = Duration::from_millis(300);

/// A read that found nothing (yet), as opposed to a broken link.
fn is_no_data(error: &std::io::Error) -> bool {
    matches!(error.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted)
}

/// A sequence number to start from that differs between sessions, so a late answer to an
/// earlier session's request is not mistaken for the answer to this one's.
fn initial_seq() -> u16 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    (nanos ^ std::process::id()) as u16 | 1
}

fn incompatible(device: Version, host: Version) -> LinkError {
    let older = if device.major < host.major { "board's firmware" } else { "configurator" };
    LinkError::Incompatible { device: VersionText(device), host: VersionText(host), older }
}

fn placeholder_info() -> Info {
    Info {
        protocol: PROTOCOL_VERSION,
        schema_hash: 0,
        firmware: protocol::FirmwareVersion { major: 0, minor: 0, patch: 0 },
        board: heapless::String::new(),
        serial: heapless::String::new(),
        capabilities: protocol::Capabilities(0),
        control_rate_hz: 0,
        motor_count: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bad_value(name: &str, value: f32, min: f32, max: f32, unit: &str) -> String {
        let error = DeviceError::BadValue {
            name: name.try_into().unwrap(),
            value,
            min,
            max,
            unit: unit.try_into().unwrap(),
        };
        DeviceErrorText(error).to_string()
    }

    /// A board behind a radio that loses the first `lost` frames it is sent, then answers each
    /// hello.
    struct LossyBoard {
        lost: u32,
        decoder: Decoder,
        answers: Vec<u8>,
    }

    impl Read for LossyBoard {
        fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
            if self.answers.is_empty() {
                std::thread::sleep(Duration::from_millis(1));
                return Err(ErrorKind::TimedOut.into());
            }
            let n = buffer.len().min(self.answers.len());
            buffer[..n].copy_from_slice(&self.answers[..n]);
            self.answers.drain(..n);
            Ok(n)
        }
    }

    impl Write for LossyBoard {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            for &byte in bytes {
                let Some(Ok(frame)) = self.decoder.push(byte) else { continue };
                let seq = frame.seq;
                if self.lost > 0 {
                    self.lost -= 1;
                    continue;
                }
                let mut info = placeholder_info();
                info.serial = "LOSSY".try_into().unwrap();
                let mut out = [0u8; MAX_FRAME_LEN];
                let answer = DeviceMessage::Response(Ok(Reply::Hello(info)));
                let n = answer.encode(seq, &mut out).unwrap();
                self.answers.extend_from_slice(&out[..n]);
            }
            Ok(bytes.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_handshake_lost_on_the_radio_is_asked_again() {
        for lost in [0, 1, 2] {
            let board = LossyBoard { lost, decoder: Decoder::new(), answers: Vec::new() };
            let client = Client::connect(Box::new(board), "radio").expect("connected");
            assert_eq!(client.info.serial.as_str(), "LOSSY");
            assert_eq!(client.retries(), lost, "{lost} hellos lost");
        }
        // Three lost: every attempt was, and the handshake fails as a timeout.
        let board = LossyBoard { lost: 3, decoder: Decoder::new(), answers: Vec::new() };
        let error = Client::connect(Box::new(board), "radio").err().expect("no answer");
        assert!(matches!(error, LinkError::Timeout { .. }), "{error}");
    }

    /// A board behind a serial line at the wrong rate: each byte written reaches it garbled, so
    /// it never answers, and it sends garbage back (here the bytes written, scrambled). (Silence
    /// stays a timeout: `a_handshake_lost_on_the_radio_is_asked_again`.)
    struct GarbledLine {
        garbage: Vec<u8>,
        written: std::sync::Arc<std::sync::atomic::AtomicU64>,
    }

    impl Read for GarbledLine {
        fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
            if self.garbage.is_empty() {
                std::thread::sleep(Duration::from_millis(1));
                return Err(ErrorKind::TimedOut.into());
            }
            let n = buffer.len().min(self.garbage.len());
            buffer[..n].copy_from_slice(&self.garbage[..n]);
            self.garbage.drain(..n);
            Ok(n)
        }
    }

    impl Write for GarbledLine {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            self.garbage.extend(bytes.iter().map(|b| b.rotate_left(3) ^ 0x5a));
            self.written.fetch_add(bytes.len() as u64, std::sync::atomic::Ordering::Relaxed);
            Ok(bytes.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_handshake_hearing_only_garbage_says_so() {
        let written = std::sync::Arc::default();
        let line = GarbledLine { garbage: Vec::new(), written: std::sync::Arc::clone(&written) };
        let error = Client::connect(Box::new(line), "radio").err().expect("no frame");
        let LinkError::NoFrame { bytes, .. } = &error else { panic!("{error}") };
        // The three hellos came back garbled: every byte counted, none a frame.
        assert_eq!(*bytes, written.load(std::sync::atomic::Ordering::Relaxed), "{error}");
        assert!(*bytes > 3 * 10, "{error}");
        assert!(error.to_string().contains("but no valid frame"), "{error}");
    }

    #[test]
    fn out_of_range_values_read_well_with_and_without_a_unit() {
        assert_eq!(
            bad_value("rate_hz", 5000.0, 0.0, 1000.0, "Hz"),
            "rate_hz = 5000 Hz is outside the allowed range 0 to 1000 Hz"
        );
        assert_eq!(
            bad_value("motor_count", 3.0, 4.0, 8.0, ""),
            "motor_count = 3 is outside the allowed range 4 to 8"
        );
        assert_eq!(
            bad_value("pose", f32::NAN, -f32::MAX, f32::MAX, "m, rad"),
            "pose is not a finite number"
        );
    }
}
