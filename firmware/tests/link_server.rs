//! The link server against a scripted host: handshake rules, one response per request, typed
//! errors, telemetry rates and sequence numbers, bad-frame accounting.

use firmware::app::{BoardInfo, ControlSnapshot, LinkServer, StatusView};
use protocol::*;

fn board() -> BoardInfo {
    BoardInfo {
        board: "TEST",
        serial: heapless::String::try_from("42").unwrap(),
        capabilities: Capabilities::TELEMETRY,
        control_rate_hz: 2000,
        motor_count: 4,
    }
}

fn view_at(t_us: u64) -> StatusView {
    StatusView {
        control: ControlSnapshot { t_us, steps: (t_us / 500) as u32, ..Default::default() },
        step_time: Some(StepTime { max_us: 17, overruns: 1 }),
        ..Default::default()
    }
}

/// A scripted host: encodes requests, collects everything the server sends.
struct Host {
    server: LinkServer,
    decoder: Decoder,
    now_us: u64,
}

#[derive(Debug, Clone, PartialEq)]
struct Received {
    seq: u16,
    message: DeviceMessage,
}

impl Host {
    fn new() -> Self {
        Self { server: LinkServer::new(board()), decoder: Decoder::new(), now_us: 0 }
    }

    fn send(&mut self, request: &Request, seq: u16) {
        let mut frame = [0u8; MAX_FRAME_LEN];
        let len = request.encode(seq, &mut frame).unwrap();
        self.server.receive(&frame[..len], self.now_us, &view_at(self.now_us));
    }

    fn send_raw(&mut self, bytes: &[u8]) {
        self.server.receive(bytes, self.now_us, &view_at(self.now_us));
    }

    fn advance(&mut self, dt_us: u64) {
        self.now_us += dt_us;
        self.server.poll(self.now_us, &view_at(self.now_us));
    }

    /// Drain the server's transmit buffer in USB-packet-sized pieces.
    fn read(&mut self) -> Vec<Received> {
        let mut out = Vec::new();
        let mut packet = [0u8; 64];
        loop {
            let n = self.server.transmit_to(|bytes| {
                let n = bytes.len().min(packet.len());
                packet[..n].copy_from_slice(&bytes[..n]);
                n
            });
            if n == 0 {
                return out;
            }
            for &byte in &packet[..n] {
                if let Some(result) = self.decoder.push(byte) {
                    let frame = result.expect("the server only sends valid frames");
                    let message = DeviceMessage::decode(&frame).expect("and only known messages");
                    out.push(Received { seq: frame.seq, message });
                }
            }
        }
    }

    fn request(&mut self, request: &Request, seq: u16) -> Response {
        self.send(request, seq);
        let received = self.read();
        assert_eq!(received.len(), 1, "exactly one answer: {received:?}");
        assert_eq!(received[0].seq, seq, "the answer carries the request's sequence number");
        match &received[0].message {
            DeviceMessage::Response(response) => response.clone(),
            other => panic!("expected a response, got {other:?}"),
        }
    }

    fn handshake(&mut self) -> Info {
        let hello = Hello { protocol: PROTOCOL_VERSION, schema_hash: SCHEMA_HASH };
        match self.request(&Request::Hello(hello), 1) {
            Ok(Reply::Hello(info)) => info,
            other => panic!("handshake failed: {other:?}"),
        }
    }
}

#[test]
fn handshake_reports_versions_board_and_capabilities() {
    let mut host = Host::new();
    let info = host.handshake();
    assert_eq!(info.protocol, PROTOCOL_VERSION);
    assert_eq!(info.schema_hash, SCHEMA_HASH);
    assert_eq!(info.board.as_str(), "TEST");
    assert_eq!(info.serial.as_str(), "42");
    assert!(info.capabilities.has(Capabilities::TELEMETRY));
    assert_eq!((info.control_rate_hz, info.motor_count), (2000, 4));
    assert_eq!(info.firmware.minor, env!("CARGO_PKG_VERSION_MINOR").parse::<u8>().unwrap());
}

#[test]
fn requests_before_the_handshake_are_refused() {
    let mut host = Host::new();
    assert_eq!(host.request(&Request::GetStatus(()), 5), Err(DeviceError::HandshakeRequired));
}

#[test]
fn another_major_version_is_refused_naming_both_versions() {
    let mut host = Host::new();
    let future = Version { major: PROTOCOL_VERSION.major + 1, minor: 3 };
    let hello = Hello { protocol: future, schema_hash: 0 };
    assert_eq!(
        host.request(&Request::Hello(hello), 1),
        Err(DeviceError::IncompatibleProtocol { device: PROTOCOL_VERSION, host: future })
    );
    assert_eq!(host.request(&Request::GetInfo(()), 2), Err(DeviceError::HandshakeRequired));
}

#[test]
fn a_newer_minor_version_is_accepted() {
    let mut host = Host::new();
    let newer = Version { major: PROTOCOL_VERSION.major, minor: PROTOCOL_VERSION.minor + 1 };
    let reply = host.request(&Request::Hello(Hello { protocol: newer, schema_hash: 1 }), 1);
    assert!(matches!(reply, Ok(Reply::Hello(_))));
}

#[test]
fn unknown_and_malformed_requests_get_typed_errors_with_their_sequence_numbers() {
    let mut host = Host::new();
    host.handshake();
    let mut frame = [0u8; MAX_FRAME_LEN];
    let len = frame::encode(0x7e, 77, &(), &mut frame).unwrap();
    host.send_raw(&frame[..len]);
    let len = frame::encode(0x04, 78, &[9u8, 9, 9, 9, 9][..], &mut frame).unwrap();
    host.send_raw(&frame[..len]);
    let received = host.read();
    assert_eq!(
        received,
        vec![
            Received {
                seq: 77,
                message: DeviceMessage::Response(Err(DeviceError::UnknownRequest { id: 0x7e }))
            },
            Received {
                seq: 78,
                message: DeviceMessage::Response(Err(DeviceError::Malformed { id: 0x04 }))
            },
        ]
    );
    let counters = host.server.counters();
    assert_eq!((counters.unknown_id, counters.malformed), (1, 1));
}

#[test]
fn an_out_of_range_rate_names_the_allowed_range_and_changes_nothing() {
    let mut host = Host::new();
    host.handshake();
    let setting = SetTelemetryRate { topic: Topic::Imu, rate_hz: 5000 };
    match host.request(&Request::SetTelemetryRate(setting), 3) {
        Err(DeviceError::BadValue { name, value, min, max, unit }) => {
            assert_eq!((name.as_str(), unit.as_str()), ("rate_hz", "Hz"));
            assert_eq!((value, min, max), (5000.0, 0.0, 1000.0));
        }
        other => panic!("{other:?}"),
    }
    host.advance(100_000);
    assert!(host.read().is_empty(), "the topic stayed off");
}

#[test]
fn telemetry_streams_at_the_chosen_rate_with_consecutive_sequence_numbers() {
    let mut host = Host::new();
    host.handshake();
    let setting = SetTelemetryRate { topic: Topic::Control, rate_hz: 250 };
    assert_eq!(host.request(&Request::SetTelemetryRate(setting), 2), Ok(Reply::Done));
    let mut received = Vec::new();
    for _ in 0..1000 {
        host.advance(1000); // the board polls every millisecond
        received.extend(host.read());
    }
    // 1 s at 250 Hz: 250 samples (the first at the moment the rate was set).
    assert!((249..=251).contains(&received.len()), "{}", received.len());
    for (i, sample) in received.iter().enumerate() {
        assert_eq!(usize::from(sample.seq), i, "no gaps while the host keeps reading");
        assert!(matches!(sample.message, DeviceMessage::Telemetry(Telemetry::Control(_))));
    }
}

#[test]
fn a_host_that_stops_reading_sees_gaps_but_its_requests_are_still_answered() {
    let mut host = Host::new();
    host.handshake();
    let setting = SetTelemetryRate { topic: Topic::Motors, rate_hz: 1000 };
    assert_eq!(host.request(&Request::SetTelemetryRate(setting), 2), Ok(Reply::Done));
    for _ in 0..200 {
        host.advance(1000); // nobody reads for 200 ms
    }
    host.send(&Request::Ping(Ping { nonce: 99 }), 3);
    let received = host.read();
    let answer = received.iter().find(|r| matches!(r.message, DeviceMessage::Response(_)));
    assert_eq!(
        answer.map(|r| (r.seq, r.message.clone())),
        Some((3, DeviceMessage::Response(Ok(Reply::Pong(Ping { nonce: 99 })))))
    );
    let seqs: Vec<u16> = received
        .iter()
        .filter(|r| matches!(r.message, DeviceMessage::Telemetry(_)))
        .map(|r| r.seq)
        .collect();
    // 200 samples were taken (seq 0..=199); the buffer kept the oldest, the rest were dropped.
    assert!(seqs.len() < 200, "the transmit buffer cannot hold 200 ms of 1 kHz telemetry");
    assert!(seqs.windows(2).all(|w| w[1] > w[0]));
    let dropped = 200 - seqs.len() as u32;
    assert_eq!(host.server.counters().telemetry_dropped, dropped);
    host.advance(1000);
    let next = host.read().iter().find_map(|r| match r.message {
        DeviceMessage::Telemetry(_) => Some(r.seq),
        _ => None,
    });
    let last_seen = *seqs.last().unwrap();
    assert_eq!(next, Some(200), "the next sample continues the count");
    assert_eq!(u32::from(200 - last_seen - 1), dropped, "the host counts every drop as a gap");
    assert_eq!(host.server.counters().responses_dropped, 0);
}

#[test]
fn corrupted_frames_are_counted_and_reported_as_one_event() {
    let mut host = Host::new();
    host.handshake();
    let mut frame = [0u8; MAX_FRAME_LEN];
    let len = Request::GetInfo(()).encode(2, &mut frame).unwrap();
    frame[2] ^= 0x01;
    for _ in 0..3 {
        host.send_raw(&frame[..len]);
    }
    host.send_raw(&[0x55; 300]);
    host.send_raw(&[0]);
    host.advance(1000);
    host.advance(1000);
    let received = host.read();
    assert_eq!(received.len(), 1, "one event for the burst, no responses: {received:?}");
    match &received[0].message {
        DeviceMessage::Event(Event::LinkErrors(counters)) => {
            assert_eq!(counters.bad_crc + counters.bad_framing, 3);
            assert_eq!(counters.oversize, 1);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn status_reports_uptime_steps_and_the_boards_step_time() {
    let mut host = Host::new();
    host.handshake();
    host.now_us = 2_500_000;
    match host.request(&Request::GetStatus(()), 2) {
        Ok(Reply::Status(status)) => {
            assert_eq!(status.uptime_ms, 2500);
            assert_eq!(status.control.steps, 5000);
            assert_eq!(status.control.step_time, Some(StepTime { max_us: 17, overruns: 1 }));
            assert_eq!(status.link.frames_rx, 2, "the handshake and this request");
        }
        other => panic!("{other:?}"),
    }
}
