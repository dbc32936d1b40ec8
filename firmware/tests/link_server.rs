//! The link server against a scripted host: handshake rules, one response per request, typed
//! errors, telemetry rates and sequence numbers, bad-frame accounting, the throw-to-fly commands
//! and the learner topic.

mod common;
use common::board;
use firmware::app::hal::ImuSample;
use firmware::app::log::{FileRead, LogFileError, LogFileList, LogFiles};
use firmware::app::{
    ControlCommand, ControlSnapshot, LinkRequest, LinkServer, NoFlash, Settings, StatusView,
    StepRecord,
};
use flight::learner::motor_model::MotorModel;
use flight::learner::LearnedModel;
use protocol::*;

/// The control period at 2 kHz, µs.
const STEP_US: u64 = 500;

/// The record of the control step at `t_us` (step n at n · 500 µs; every third step without an
/// IMU sample).
fn step_record(t_us: u64) -> StepRecord {
    let step = (t_us / STEP_US) as u32;
    StepRecord {
        step,
        t_us,
        imu: (!step.is_multiple_of(3)).then_some(ImuSample {
            gyro_rad_s: [0.1, 0.2, step as f32],
            accel_mps2: [0.0, 0.0, -9.81],
        }),
        motor_count: 4,
        commands: [0.25, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        speeds_rad_s: [Some(900.0), None, None, None, None, None, None, None],
        ..StepRecord::default()
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
    /// The parameters (no flash: a save is refused with a typed error).
    settings: Settings<NoFlash>,
    decoder: Decoder,
    now_us: u64,
    /// What the board's other tasks publish; the time and step count follow `now_us`.
    view: StatusView,
    /// The flight log's files (`None`: a board without log storage).
    logs: Option<MemoryLogs>,
}

/// Log files in memory: (number, bytes, being written).
#[derive(Default)]
struct MemoryLogs {
    files: Vec<(u32, Vec<u8>, bool)>,
}

impl LogFiles for MemoryLogs {
    fn list(&mut self, first: u32, out: &mut LogFileList) -> Result<bool, LogFileError> {
        out.clear();
        let mut listed = self.files.iter().filter(|(number, ..)| *number >= first);
        for (number, bytes, writing) in listed.by_ref().take(LOG_LIST_LEN) {
            let info =
                LogFileInfo { number: *number, size_bytes: bytes.len() as u32, writing: *writing };
            out.push(info).unwrap();
        }
        Ok(listed.next().is_some())
    }

    fn read(&mut self, number: u32, offset: u32, buf: &mut [u8]) -> Result<FileRead, LogFileError> {
        let (_, bytes, _) =
            self.files.iter().find(|(n, ..)| *n == number).ok_or(LogFileError::NoSuchFile)?;
        let size_bytes = bytes.len() as u32;
        let rest =
            bytes.get(offset as usize..).ok_or(LogFileError::OffsetPastEnd { size_bytes })?;
        let count = rest.len().min(buf.len());
        buf[..count].copy_from_slice(&rest[..count]);
        Ok(FileRead { bytes_read: count, size_bytes })
    }

    fn delete(&mut self, number: u32) -> Result<(), LogFileError> {
        let index =
            self.files.iter().position(|(n, ..)| *n == number).ok_or(LogFileError::NoSuchFile)?;
        if self.files[index].2 {
            return Err(LogFileError::BeingWritten);
        }
        self.files.remove(index);
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq)]
struct Received {
    seq: u16,
    message: DeviceMessage,
}

impl Host {
    fn new() -> Self {
        Self::with_view(view_at(0))
    }

    fn with_view(view: StatusView) -> Self {
        Self {
            server: LinkServer::new(board()),
            settings: Settings::without_store(),
            decoder: Decoder::new(),
            now_us: 0,
            view,
            logs: None,
        }
    }

    /// The view at the current time.
    fn view(&self) -> StatusView {
        let mut view = self.view;
        view.control.t_us = self.now_us;
        view.control.steps = (self.now_us / 500) as u32;
        view
    }

    fn send(&mut self, request: &Request, seq: u16) {
        let mut frame = [0u8; MAX_FRAME_LEN];
        let len = request.encode(seq, &mut frame).unwrap();
        let view = self.view();
        self.server.receive(&frame[..len], self.now_us, &view, &mut self.settings, &mut self.logs);
    }

    fn send_raw(&mut self, bytes: &[u8]) {
        let view = self.view();
        self.server.receive(bytes, self.now_us, &view, &mut self.settings, &mut self.logs);
    }

    /// Let `dt_us` pass: a control step every 500 µs, each streaming its record, then a poll
    /// (the board's link task drains the ring and polls once per millisecond).
    fn advance(&mut self, dt_us: u64) {
        let end_us = self.now_us + dt_us;
        while self.now_us + STEP_US <= end_us {
            self.now_us += STEP_US;
            let record = step_record(self.now_us);
            self.server.stream(&record);
        }
        self.now_us = end_us;
        let view = self.view();
        self.server.poll(self.now_us, &view);
    }

    /// Every command the server has queued for the control step, oldest first.
    fn commands(&mut self) -> Vec<ControlCommand> {
        std::iter::from_fn(|| self.server.take_request())
            .map(|request| match request {
                LinkRequest::Control(command) => command,
                other => panic!("expected a control command, got {other:?}"),
            })
            .collect()
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
    let len = frame::encode(0x3e, 77, &(), &mut frame).unwrap();
    host.send_raw(&frame[..len]);
    let len = frame::encode(0x04, 78, &[9u8, 9, 9, 9, 9][..], &mut frame).unwrap();
    host.send_raw(&frame[..len]);
    let received = host.read();
    assert_eq!(
        received,
        vec![
            Received {
                seq: 77,
                message: DeviceMessage::Response(Err(DeviceError::UnknownRequest { id: 0x3e }))
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
            assert_eq!((value, min, max), (5000.0, 0.0, 2000.0));
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
    assert_eq!(
        host.request(&Request::SetTelemetryRate(setting), 2),
        Ok(Reply::TelemetryRate(setting))
    );
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
fn every_control_step_streams_at_2khz_and_a_divided_rate_keeps_consecutive_numbers() {
    let mut host = Host::new();
    host.handshake();
    let state = SetTelemetryRate { topic: Topic::State, rate_hz: 2000 };
    assert_eq!(host.request(&Request::SetTelemetryRate(state), 2), Ok(Reply::TelemetryRate(state)));
    let motors = SetTelemetryRate { topic: Topic::Motors, rate_hz: 500 };
    assert_eq!(
        host.request(&Request::SetTelemetryRate(motors), 3),
        Ok(Reply::TelemetryRate(motors))
    );
    let first_step = (host.now_us / STEP_US) as u32 + 1;
    let mut received = Vec::new();
    for _ in 0..1000 {
        host.advance(1000);
        received.extend(host.read());
    }
    let states: Vec<(u16, StateTelemetry)> = received
        .iter()
        .filter_map(|r| match r.message {
            DeviceMessage::Telemetry(Telemetry::State(s)) => Some((r.seq, s)),
            _ => None,
        })
        .collect();
    assert_eq!(states.len(), 2000, "one state sample per control step for 1 s");
    for (i, (seq, state)) in states.iter().enumerate() {
        let step = first_step + i as u32;
        assert_eq!(u32::from(*seq), step, "the sequence number is the step number");
        assert_eq!(state.t_us, u64::from(step) * STEP_US);
        assert_eq!(state.imu_fresh, !step.is_multiple_of(3));
        assert_eq!((state.motor_count, state.commands[1]), (4, 0.5));
    }
    let motor_seqs: Vec<u16> = received
        .iter()
        .filter(|r| matches!(r.message, DeviceMessage::Telemetry(Telemetry::Motors(_))))
        .map(|r| r.seq)
        .collect();
    assert_eq!(motor_seqs.len(), 500, "500 Hz is every fourth step");
    assert!(motor_seqs.windows(2).all(|w| w[1] == w[0] + 1), "no gaps at 500 Hz");
    assert_eq!(host.server.counters().telemetry_dropped, 0);
}

#[test]
fn imu_samples_a_step_did_not_have_are_gaps_in_the_imu_topic() {
    let mut host = Host::new();
    host.handshake();
    let imu = SetTelemetryRate { topic: Topic::Imu, rate_hz: 2000 };
    assert_eq!(host.request(&Request::SetTelemetryRate(imu), 2), Ok(Reply::TelemetryRate(imu)));
    let mut received = Vec::new();
    for _ in 0..30 {
        host.advance(1000);
        received.extend(host.read());
    }
    let seqs: Vec<u16> = received
        .iter()
        .filter(|r| matches!(r.message, DeviceMessage::Telemetry(Telemetry::Imu(_))))
        .map(|r| r.seq)
        .collect();
    // 60 steps, every third without a sample: 40 samples, 20 gaps.
    assert_eq!(seqs.len(), 40);
    let gaps: u32 = seqs.windows(2).map(|w| u32::from(w[1] - w[0] - 1)).sum();
    assert_eq!(gaps, 19, "the gaps between the first and last sample (one more after the last)");
    assert!(seqs.iter().all(|&seq| seq % 3 != 0));
}

#[test]
fn a_host_that_stops_reading_sees_gaps_but_its_requests_are_still_answered() {
    let mut host = Host::new();
    host.handshake();
    let setting = SetTelemetryRate { topic: Topic::State, rate_hz: 2000 };
    assert_eq!(
        host.request(&Request::SetTelemetryRate(setting), 2),
        Ok(Reply::TelemetryRate(setting))
    );
    let first_step = (host.now_us / STEP_US) as u16 + 1;
    for _ in 0..200 {
        host.advance(1000); // nobody reads for 200 ms: 400 steps
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
    assert!(seqs.len() < 400, "the transmit buffer cannot hold 200 ms of 2 kHz telemetry");
    assert_eq!(seqs.first(), Some(&first_step), "the oldest samples are kept");
    assert!(seqs.windows(2).all(|w| w[1] > w[0]));
    let dropped = 400 - seqs.len() as u32;
    assert_eq!(host.server.counters().telemetry_dropped, dropped);
    host.advance(500);
    let next = host.read().iter().find_map(|r| match r.message {
        DeviceMessage::Telemetry(_) => Some(r.seq),
        _ => None,
    });
    let last_seen = *seqs.last().unwrap();
    assert_eq!(next, Some(first_step + 400), "the next sample continues the count");
    let gaps = u32::from(first_step + 400 - last_seen - 1);
    assert_eq!(gaps, dropped, "the host counts every drop as a gap");
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

/// The learned time constants of the motors in [`learner_view`], s.
const TAU_S: [f32; MAX_MOTORS] = [0.020, 0.025, 0.030, 0.035, 0.040, 0.045, 0.050, 0.055];

/// A view of a board with `motors` motors connected and learned: time constants [`TAU_S`],
/// 1000 rad/s at full command, G1 per unit squared speed `(10·row + motor + 1)·10⁻⁶`.
fn learner_view(motors: u8) -> StatusView {
    let mut view = view_at(0);
    view.control.motor_count = motors;
    // Every motor reports its speed.
    view.control.speeds_reported = ((1u16 << motors) - 1) as u8;
    let learned: &mut LearnedModel = &mut view.background.learned;
    learned.motors = motors;
    for i in 0..usize::from(motors) {
        // ω_full = a + b + ω_idle = 1000 rad/s for every motor, so G1 per unit thrust is G1 per
        // squared speed × 10⁶.
        learned.motor[i] = MotorModel {
            a_rad_s: 600.0,
            b_rad_s: 300.0,
            omega_idle_rad_s: 100.0,
            tau_s: TAU_S[i],
            ..MotorModel::default()
        };
        for (row, values) in learned.g1_per_speed2.iter_mut().enumerate() {
            values[i] = (10 * row + i + 1) as f32 * 1e-6;
        }
    }
    view
}

fn bad_value_name(response: &Response) -> Option<&str> {
    match response {
        Err(DeviceError::BadValue { name, .. }) => Some(name.as_str()),
        _ => None,
    }
}

#[test]
fn arming_throw_to_fly_queues_the_command_with_four_motors_or_more() {
    for motors in [4, 6, 8] {
        let mut host = Host::with_view(learner_view(motors));
        host.handshake();
        assert_eq!(host.request(&Request::ArmThrowToFly(()), 2), Ok(Reply::Done), "{motors}");
        assert_eq!(host.commands(), vec![ControlCommand::ArmThrowToFly], "{motors} motors");
    }
}

/// With `motor_bidir_dshot` = 0 (ESCs without bidirectional DShot) and no motor reporting, arming
/// is queued: the learner identifies from the commands (`flight::learner::no_speed`, in every
/// build). With the parameter at 1 the same silent motors are refused, named, and nothing is
/// queued.
#[test]
fn with_esc_speed_reports_off_arming_depends_on_the_commands_only_identification() {
    for bidirectional in [0.0, 1.0] {
        let mut view = learner_view(4);
        view.control.speeds_reported = 0;
        let mut host = Host::with_view(view);
        host.settings.update(|params| {
            let param = firmware::app::params::Param::MotorBidirDshot as usize;
            params.set(param, &[bidirectional]).unwrap();
        });
        host.handshake();
        let response = host.request(&Request::ArmThrowToFly(()), 2);
        if bidirectional == 0.0 {
            assert_eq!(response, Ok(Reply::Done));
            assert_eq!(host.commands(), vec![ControlCommand::ArmThrowToFly]);
        } else {
            assert_eq!(response, Err(DeviceError::SpeedsNotReported { motors: 0b1111 }));
            assert_eq!(host.commands(), vec![], "nothing queued");
        }
    }
}

#[test]
fn arming_while_a_motor_reports_no_speed_names_the_silent_motors_and_queues_nothing() {
    for (motors, reported, silent) in [(4, 0b0000, 0b1111), (4, 0b1011, 0b0100), (8, 0x7F, 0x80)] {
        let mut view = learner_view(motors);
        view.control.speeds_reported = reported;
        let mut host = Host::with_view(view);
        host.handshake();
        let response = host.request(&Request::ArmThrowToFly(()), 2);
        assert_eq!(response, Err(DeviceError::SpeedsNotReported { motors: silent }));
        assert_eq!(host.commands(), vec![], "nothing queued");
        let status = host.request(&Request::GetHealth(()), 3);
        let Ok(Reply::Health(health)) = status else { panic!("{status:?}") };
        assert_eq!((health.motor_count, health.speeds_reported), (motors, reported));
    }
}

#[test]
fn arming_with_fewer_than_four_motors_names_motor_count_and_queues_nothing() {
    for motors in [0, 3] {
        let mut host = Host::with_view(learner_view(motors));
        host.handshake();
        let response = host.request(&Request::ArmThrowToFly(()), 2);
        assert_eq!(bad_value_name(&response), Some("motor_count"), "{response:?}");
        let Err(DeviceError::BadValue { value, min, max, .. }) = response else { unreachable!() };
        assert_eq!((value, min, max), (f32::from(motors), 4.0, 8.0));
        assert_eq!(host.commands(), vec![], "nothing queued with {motors} motors");
    }
}

#[test]
fn disarm_is_always_done_and_goes_first_even_behind_a_full_queue() {
    let mut host = Host::with_view(learner_view(4));
    host.handshake();
    // Fill the command queue with poses until the board says it is busy.
    let pose = ExternalPose { position_ned_m: [1.0, 2.0, -3.0], heading_rad: 0.5 };
    let mut queued = 0;
    let mut seq = 2;
    loop {
        seq += 1;
        match host.request(&Request::SetExternalPose(pose), seq) {
            Ok(Reply::Done) => queued += 1,
            Err(DeviceError::Busy) => break,
            other => panic!("{other:?}"),
        }
        assert!(queued <= 64, "the command queue never filled");
    }
    assert!(queued >= 1);
    assert_eq!(host.request(&Request::Disarm(()), seq + 1), Ok(Reply::Done));
    assert_eq!(host.commands(), vec![ControlCommand::Disarm], "nothing waits before the disarm");
    // And with nothing queued, or twice in a row, or with an arm waiting: still Done, still first.
    assert_eq!(host.request(&Request::Disarm(()), seq + 2), Ok(Reply::Done));
    assert_eq!(host.request(&Request::ArmThrowToFly(()), seq + 3), Ok(Reply::Done));
    assert_eq!(host.request(&Request::Disarm(()), seq + 4), Ok(Reply::Done));
    assert_eq!(host.commands(), vec![ControlCommand::Disarm]);
    // A board without enough motors to arm is still disarmed.
    let mut host = Host::with_view(learner_view(0));
    host.handshake();
    assert_eq!(host.request(&Request::Disarm(()), 2), Ok(Reply::Done));
    assert_eq!(host.commands(), vec![ControlCommand::Disarm]);
}

#[test]
fn a_pose_with_a_nan_is_refused_and_a_finite_one_is_queued() {
    let mut host = Host::with_view(learner_view(4));
    host.handshake();
    let finite = ExternalPose { position_ned_m: [1.5, -2.0, -0.5], heading_rad: -1.0 };
    let mut seq = 1;
    for index in 0..4 {
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let mut pose = finite;
            if index < 3 {
                pose.position_ned_m[index] = bad;
            } else {
                pose.heading_rad = bad;
            }
            seq += 1;
            let response = host.request(&Request::SetExternalPose(pose), seq);
            assert_eq!(bad_value_name(&response), Some("pose"), "{pose:?}: {response:?}");
            assert_eq!(host.commands(), vec![], "nothing queued for {pose:?}");
        }
    }
    assert_eq!(host.request(&Request::SetExternalPose(finite), seq + 1), Ok(Reply::Done));
    assert_eq!(host.commands(), vec![ControlCommand::ExternalPose(finite)]);
}

#[test]
fn the_learner_topic_at_1000_hz_alternates_the_g1_blocks_with_consecutive_sequence_numbers() {
    let view = learner_view(4);
    let mut host = Host::with_view(view);
    host.handshake();
    let setting = SetTelemetryRate { topic: Topic::Learner, rate_hz: 1000 };
    assert_eq!(
        host.request(&Request::SetTelemetryRate(setting), 2),
        Ok(Reply::TelemetryRate(setting))
    );
    let mut received = Vec::new();
    for _ in 0..100 {
        host.advance(1000);
        received.extend(host.read());
    }
    assert!((99..=101).contains(&received.len()), "{}", received.len());
    let tau_s = [TAU_S[0], TAU_S[1], TAU_S[2], TAU_S[3], 0.0, 0.0, 0.0, 0.0];
    for (i, sample) in received.iter().enumerate() {
        assert_eq!(usize::from(sample.seq), i, "consecutive sequence numbers");
        let DeviceMessage::Telemetry(Telemetry::Learner(learner)) = &sample.message else {
            panic!("{sample:?}")
        };
        let block = i % 2;
        assert_eq!(usize::from(learner.g1_block), block, "sample {i}");
        assert_eq!(learner.tau_s, tau_s, "the view's learned time constants");
        assert_eq!(learner.omega_max_rad_s[..4], [1000.0; 4]);
        assert_eq!(learner.motor_count, 4);
        assert_eq!(learner.phase, LearnerPhase::Idle);
        // Rows 3·block .. 3·block + 3 of G1 per unit thrust (× ω_full² = 10⁶), zero beyond m.
        for (r, row) in learner.g1_rows.iter().enumerate() {
            for (motor, &value) in row.iter().enumerate() {
                let expected =
                    if motor < 4 { (10 * (3 * block + r) + motor + 1) as f32 } else { 0.0 };
                assert!((value - expected).abs() <= 1e-4 * expected.abs(), "row {r}: {row:?}");
            }
        }
    }
}

#[test]
fn get_learner_needs_the_handshake_and_then_answers_with_the_view() {
    let mut host = Host::with_view(learner_view(4));
    assert_eq!(host.request(&Request::GetLearner(()), 1), Err(DeviceError::HandshakeRequired));
    for request in [Request::ArmThrowToFly(()), Request::Disarm(())] {
        assert_eq!(host.request(&request, 2), Err(DeviceError::HandshakeRequired));
    }
    assert_eq!(host.commands(), vec![], "nothing reaches the control step before the handshake");
    host.handshake();
    host.now_us = 1_234_000;
    match host.request(&Request::GetLearner(()), 3) {
        Ok(Reply::Learner(learner)) => {
            assert_eq!(learner.t_us, 1_234_000);
            assert_eq!(learner.g1_block, 0, "the reply carries the specific-force rows");
            assert_eq!(learner.tau_s[..4], TAU_S[..4]);
            assert_eq!(
                (learner.phase, learner.failure),
                (LearnerPhase::Idle, LearnerFailure::None)
            );
            assert!(!learner.thrust_axis_valid);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_setpoint_with_a_nan_is_refused_and_a_finite_one_is_queued() {
    let mut host = Host::new();
    host.handshake();
    let bad = PositionSetpoint { position_ned_m: [1.0, f32::NAN, -1.0], heading_rad: 0.0 };
    let response = host.request(&Request::SetPositionSetpoint(bad), 2);
    assert_eq!(bad_value_name(&response), Some("setpoint"));
    assert!(host.commands().is_empty(), "nothing queued for a refused setpoint");
    let good = PositionSetpoint { position_ned_m: [1.0, -2.0, -1.5], heading_rad: 0.3 };
    assert_eq!(host.request(&Request::SetPositionSetpoint(good), 3), Ok(Reply::Done));
    assert_eq!(host.commands(), vec![ControlCommand::PositionSetpoint(good)]);
}

#[test]
fn get_board_answers_the_boards_health_and_a_simulator_refuses_the_bootloader() {
    let mut view = view_at(0);
    view.board.core_clock_hz = Some(480_000_000);
    view.board.imu = ImuDriverState::WrongIdentity { expected: 0x47, found: 0x00 };
    let mut host = Host::with_view(view);
    host.handshake();
    match host.request(&Request::GetBoard(()), 2) {
        Ok(Reply::Board(board)) => {
            assert_eq!(board.core_clock_hz, Some(480_000_000));
            assert_eq!(board.imu, ImuDriverState::WrongIdentity { expected: 0x47, found: 0x00 });
        }
        other => panic!("expected the board's health, got {other:?}"),
    }
    // This test board has no `Capabilities::BOOTLOADER`: refused, nothing requested.
    assert_eq!(host.request(&Request::RebootToBootloader(()), 3), Err(DeviceError::Unsupported));
    assert_eq!(host.server.take_request(), None);
}

#[test]
fn the_bootloader_restart_is_refused_while_armed_and_requested_when_disarmed() {
    let mut board_info = board();
    board_info.capabilities |= Capabilities::BOOTLOADER;
    let mut host = Host::new();
    host.server = LinkServer::new(board_info);
    host.handshake();
    host.view.control.armed = true;
    assert_eq!(
        host.request(&Request::RebootToBootloader(()), 2),
        Err(DeviceError::RefusedWhileArmed)
    );
    assert_eq!(host.server.take_request(), None);
    host.view.control.armed = false;
    assert_eq!(host.request(&Request::RebootToBootloader(()), 3), Ok(Reply::Done));
    assert_eq!(host.server.take_request(), Some(LinkRequest::RebootToBootloader));
}

#[test]
fn each_failsafe_is_reported_once_as_an_event_with_its_reason_action_and_count() {
    let mut host = Host::new();
    host.handshake();
    host.advance(1_000);
    assert!(host.read().is_empty(), "no failsafe yet, no event");
    host.view.control.pilot.failsafes.pose_lost = 1;
    host.view.control.pilot.last_failsafe = Some(firmware::app::Failsafe::PoseLost);
    host.advance(1_000);
    let events: Vec<Event> = host
        .read()
        .into_iter()
        .filter_map(|r| match r.message {
            DeviceMessage::Event(event) => Some(event),
            _ => None,
        })
        .collect();
    assert_eq!(
        events,
        vec![Event::Failsafe {
            reason: FailsafeReason::PoseLost,
            action: FailsafeAction::LevelHold,
            count: 1
        }]
    );
    host.advance(1_000);
    assert!(host.read().is_empty(), "reported once");
    host.view.control.pilot.failsafes.attitude_lost = 1;
    host.view.control.pilot.last_failsafe = Some(firmware::app::Failsafe::AttitudeLost);
    host.advance(1_000);
    let received = host.read();
    assert!(
        received.iter().any(|r| r.message
            == DeviceMessage::Event(Event::Failsafe {
                reason: FailsafeReason::AttitudeLost,
                action: FailsafeAction::Disarmed,
                count: 1
            })),
        "{received:?}"
    );
}

#[test]
fn the_flight_topic_reports_the_mode_setpoint_and_position() {
    let mut view = view_at(0);
    let pilot = &mut view.control.pilot;
    pilot.flying = true;
    pilot.position_hold = true;
    pilot.q_world_thrust = [1.0, 0.0, 0.0, 0.0];
    pilot.position_ned_m = [0.5, 0.25, -1.0];
    pilot.position_sp_ned_m = [0.5, 0.0, -1.0];
    pilot.has_fix = true;
    view.control.external_pose =
        Some((ExternalPose { position_ned_m: [0.5, 0.25, -1.0], heading_rad: 0.0 }, 0));
    let mut host = Host::with_view(view);
    host.handshake();
    let rate = SetTelemetryRate { topic: Topic::Flight, rate_hz: 100 };
    assert_eq!(host.request(&Request::SetTelemetryRate(rate), 2), Ok(Reply::TelemetryRate(rate)));
    host.advance(50_000);
    let flights: Vec<(u16, FlightTelemetry)> = host
        .read()
        .into_iter()
        .filter_map(|r| match r.message {
            DeviceMessage::Telemetry(Telemetry::Flight(f)) => Some((r.seq, f)),
            _ => None,
        })
        .collect();
    assert!(!flights.is_empty(), "the flight topic streams");
    let (_, flight) = flights[0];
    assert_eq!(flight.mode, FlightMode::PositionHold);
    assert_eq!(flight.position_ned_m, Some([0.5, 0.25, -1.0]));
    assert_eq!(flight.position_sp_ned_m, Some([0.5, 0.0, -1.0]));
    assert!(flight.pose_fresh);
}

/// ESC commands: unsupported where the board has no `Capabilities::ESC_COMMANDS` (the bridge),
/// refused while armed, an unknown motor or command number named in a typed error; a beep to
/// one motor and a save to all are queued for the control step as the driver's commands.
#[test]
fn esc_commands_are_checked_and_queued_for_the_control_step() {
    let beep = EscCommand { motor: 2, command: DshotCommand::Beep1.value() as u8 };
    let mut host = Host::with_view(learner_view(4));
    host.handshake();
    assert_eq!(host.request(&Request::EscCommand(beep), 2), Err(DeviceError::Unsupported));
    let mut board_info = board();
    board_info.capabilities |= Capabilities::ESC_COMMANDS;
    host.server = LinkServer::new(board_info);
    host.handshake();
    host.view.control.armed = true;
    assert_eq!(host.request(&Request::EscCommand(beep), 3), Err(DeviceError::RefusedWhileArmed));
    host.view.control.armed = false;
    let wrong_motor = EscCommand { motor: 4, ..beep };
    assert_eq!(bad_value_name(&host.request(&Request::EscCommand(wrong_motor), 4)), Some("motor"));
    // 16 is reserved in the DShot specification, 48 is a throttle value.
    for number in [0u8, 16, 48] {
        let unknown = EscCommand { command: number, ..beep };
        let response = host.request(&Request::EscCommand(unknown), 5);
        assert_eq!(bad_value_name(&response), Some("command"), "{number}");
    }
    assert!(host.commands().is_empty(), "nothing queued for a refused command");
    assert_eq!(host.request(&Request::EscCommand(beep), 6), Ok(Reply::Done));
    let save = EscCommand { motor: ESC_ALL_MOTORS, command: 12 };
    assert_eq!(host.request(&Request::EscCommand(save), 7), Ok(Reply::Done));
    assert_eq!(
        host.commands(),
        vec![
            ControlCommand::EscCommand { command: DshotCommand::Beep1, motor: Some(2) },
            ControlCommand::EscCommand { command: DshotCommand::SaveSettings, motor: None },
        ]
    );
}

/// A slow link (a 57,600-baud radio: 5,760 B/s) grants each topic what is left of its
/// telemetry share, booking every sample at its topic's longest frame: the rate granted is
/// answered, what streams then fits, and responses still find room.
#[test]
fn a_slow_link_grants_the_rates_its_byte_budget_carries_and_streams_within_them() {
    const BYTES_PER_S: u32 = 5_760;
    let mut host = Host::new();
    host.server = LinkServer::new(board()).with_byte_rate(BYTES_PER_S);
    host.handshake();
    let budget = BYTES_PER_S * firmware::app::TELEMETRY_SHARE_PCT / 100;
    let granted = |host: &mut Host, topic: Topic, rate_hz: u16, seq: u16| match host
        .request(&Request::SetTelemetryRate(SetTelemetryRate { topic, rate_hz }), seq)
    {
        Ok(Reply::TelemetryRate(granted)) => {
            assert_eq!(granted.topic, topic);
            u32::from(granted.rate_hz)
        }
        other => panic!("{other:?}"),
    };
    let imu_hz = granted(&mut host, Topic::Imu, 2000, 2);
    let imu_bytes = imu_hz * u32::from(Topic::Imu.max_frame_len());
    assert!(imu_hz > 0 && imu_bytes <= budget, "{imu_hz} Hz of IMU: {imu_bytes} B/s");
    // The highest that fits: one step fewer between samples would not.
    let divider = 2000 / imu_hz;
    let faster_hz = 2000.0 / f64::from(divider - 1);
    assert!(faster_hz * 45.0 > f64::from(budget), "{imu_hz} Hz is the highest rate that fits");
    // A second topic gets what is left, and the first is stopped for it to get more.
    let left_hz = granted(&mut host, Topic::Control, 100, 3);
    assert!(left_hz < 100 && left_hz * 36 <= budget - imu_bytes, "{left_hz} Hz left");
    assert_eq!(granted(&mut host, Topic::Imu, 0, 4), 0);
    let control_hz = granted(&mut host, Topic::Control, 100, 5);
    assert_eq!(control_hz, 100, "36-byte samples at 100 Hz fit 5,760 B/s");
    let imu_hz = granted(&mut host, Topic::Imu, 2000, 6);
    let booked = control_hz * 36 + imu_hz * 45;
    assert!(booked <= budget, "{booked} B/s booked of {budget}");

    // Ten seconds of streaming: what was sent is within the grant, and a status still answers.
    host.read();
    let mut bytes = 0usize;
    for _ in 0..10_000 {
        host.advance(1_000);
        let mut sent = 0;
        host.server.transmit_to(|pending| {
            sent = pending.len();
            pending.len()
        });
        bytes += sent;
    }
    assert!(bytes as u32 <= 10 * budget, "{bytes} B in 10 s over a {budget} B/s share");
    assert!(bytes as u32 >= 9 * booked / 2, "streamed {bytes} B, booked {booked} B/s");
    assert!(matches!(host.request(&Request::GetStatus(()), 7), Ok(Reply::Status(_))));
}

/// The answer to a log request, each under a fresh sequence number (the same frame again would
/// be a repeat, answered from the board's last answer without acting).
fn log_answer(host: &mut Host, request: Request) -> Response {
    static SEQ: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(40);
    host.request(&request, SEQ.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
}

#[test]
fn log_files_are_listed_in_pages_read_in_chunks_and_deleted_with_typed_refusals() {
    let mut host = Host::new();
    host.handshake();
    // Without log storage every log request is unsupported.
    assert_eq!(
        log_answer(&mut host, Request::ListLogs(ListLogs { first: 0 })),
        Err(DeviceError::Unsupported)
    );

    let file: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
    let mut logs = MemoryLogs::default();
    for number in 1..=20 {
        logs.files.push((number, file.clone(), number == 20));
    }
    host.logs = Some(logs);

    // Two pages: 16 files and `more`, then the last four.
    let Ok(Reply::LogList(page)) = log_answer(&mut host, Request::ListLogs(ListLogs { first: 0 }))
    else {
        panic!("a list")
    };
    assert_eq!(page.files.len(), LOG_LIST_LEN);
    assert!(page.more);
    let next = page.files.last().unwrap().number + 1;
    let Ok(Reply::LogList(page)) =
        log_answer(&mut host, Request::ListLogs(ListLogs { first: next }))
    else {
        panic!("a list")
    };
    assert_eq!(page.files.iter().map(|f| f.number).collect::<Vec<_>>(), [17, 18, 19, 20]);
    assert!(!page.more);
    assert_eq!(page.files[3], LogFileInfo { number: 20, size_bytes: 1000, writing: true });

    // A chunk carries its place; the last one is short; at the end it is empty; past it, refused.
    let read = |offset, len| Request::ReadLog(ReadLog { number: 3, offset, len });
    let Ok(Reply::LogChunk(chunk)) = log_answer(&mut host, read(100, LOG_CHUNK_LEN as u16)) else {
        panic!("a chunk")
    };
    assert_eq!((chunk.number, chunk.offset, chunk.size_bytes), (3, 100, 1000));
    assert_eq!(chunk.bytes.as_slice(), &file[100..100 + LOG_CHUNK_LEN]);
    let Ok(Reply::LogChunk(chunk)) = log_answer(&mut host, read(990, 200)) else {
        panic!("a chunk")
    };
    assert_eq!(chunk.bytes.as_slice(), &file[990..]);
    let Ok(Reply::LogChunk(chunk)) = log_answer(&mut host, read(1000, 200)) else {
        panic!("a chunk")
    };
    assert!(chunk.bytes.is_empty());
    assert_eq!(
        log_answer(&mut host, read(1001, 200)),
        Err(DeviceError::LogOffsetPastEnd { number: 3, size_bytes: 1000 })
    );
    let too_long = log_answer(&mut host, read(0, LOG_CHUNK_LEN as u16 + 1));
    assert_eq!(bad_value_name(&too_long), Some("len"));
    let missing = Request::ReadLog(ReadLog { number: 99, offset: 0, len: 16 });
    assert_eq!(log_answer(&mut host, missing), Err(DeviceError::NoSuchLog { number: 99 }));

    // Delete: the file being written and a missing one are refused; an armed craft refuses all.
    let delete = |number| Request::DeleteLog(DeleteLog { number });
    assert_eq!(log_answer(&mut host, delete(20)), Err(DeviceError::LogBeingWritten { number: 20 }));
    assert_eq!(log_answer(&mut host, delete(3)), Ok(Reply::Done));
    assert_eq!(log_answer(&mut host, delete(3)), Err(DeviceError::NoSuchLog { number: 3 }));
    host.view.control.armed = true;
    assert_eq!(log_answer(&mut host, delete(4)), Err(DeviceError::RefusedWhileArmed));
    assert_eq!(host.logs.as_ref().unwrap().files.len(), 19, "only file 3 was deleted");
    // Reading goes on while armed (it changes nothing).
    assert!(matches!(
        log_answer(&mut host, read(0, 16)),
        Err(DeviceError::NoSuchLog { number: 3 })
    ));
}

/// The compass over the link: `GetCompass` answers the service's report (`Unsupported` without
/// a compass bus); a calibration's start is refused while armed and without a sensor, its
/// finish without a gathering, each with a typed error and nothing routed; accepted, it reaches
/// the compass service.
#[test]
fn the_compass_report_and_its_calibration_requests_are_checked_on_the_link() {
    let mut host = Host::new();
    host.handshake();
    let start = Request::CompassCalibration(CompassCalibrationCommand::Start);
    assert_eq!(host.request(&Request::GetCompass(()), 2), Err(DeviceError::Unsupported));
    assert_eq!(host.request(&start, 3), Err(DeviceError::Unsupported));
    let healthy = CompassHealth {
        sensor: CompassSensor::Qmc5883l,
        address: 0x0D,
        state: CompassState::Healthy,
        rate_hz: 100.0,
        field_ut: 49.0,
        ..CompassHealth::default()
    };
    host.view.compass = Some(CompassHealth { state: CompassState::Absent, ..healthy });
    assert_eq!(host.request(&start, 4), Err(DeviceError::NotReady));
    host.view.compass = Some(healthy);
    assert_eq!(host.request(&Request::GetCompass(()), 5), Ok(Reply::Compass(healthy)));
    host.view.control.armed = true;
    assert_eq!(host.request(&start, 6), Err(DeviceError::RefusedWhileArmed));
    let finish = Request::CompassCalibration(CompassCalibrationCommand::Finish);
    host.view.control.armed = false;
    assert_eq!(host.request(&finish, 7), Err(DeviceError::NotReady));
    assert_eq!(host.server.take_request(), None, "nothing refused was routed");
    assert_eq!(host.request(&start, 8), Ok(Reply::Done));
    assert_eq!(
        host.server.take_request(),
        Some(LinkRequest::Compass(CompassCalibrationCommand::Start))
    );
}
