//! Golden bytes: the exact frame of every message. A change here is a protocol version change
//! (bump `PROTOCOL_VERSION`), never a test to update silently.

use protocol::*;

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ")
}

fn request(message: Request, seq: u16) -> String {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = message.encode(seq, &mut buffer).unwrap();
    hex(&buffer[..len])
}

fn device(message: DeviceMessage, seq: u16) -> String {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = message.encode(seq, &mut buffer).unwrap();
    hex(&buffer[..len])
}

fn text<const N: usize>(s: &str) -> heapless::String<N> {
    heapless::String::try_from(s).unwrap()
}

fn info() -> Info {
    Info {
        protocol: Version { major: 1, minor: 0 },
        schema_hash: 0x0123_4567_89ab_cdef,
        firmware: FirmwareVersion { major: 0, minor: 1, patch: 0 },
        board: text("SITL"),
        serial: text("0001"),
        capabilities: Capabilities(Capabilities::IMU | Capabilities::SIMULATOR),
        control_rate_hz: 2000,
        motor_count: 4,
    }
}

/// A fully populated learner sample: eight motors, every `Option` `Some`, every float non-zero.
fn learner() -> LearnerTelemetry {
    let column = |i: usize| 1.0 + 0.125 * i as f32;
    LearnerTelemetry {
        t_us: 2_500_000,
        phase: LearnerPhase::Exciting,
        failure: LearnerFailure::NoHover,
        motor_count: 8,
        exciting_motor: Some(5),
        excitation_ms: 140,
        tau_s: [0.020, 0.022, 0.024, 0.026, 0.028, 0.030, 0.032, 0.034],
        omega_max_rad_s: [2000.0, 2050.0, 2100.0, 2150.0, 2200.0, 2250.0, 2300.0, 2350.0],
        motors_converged: 0b0001_1111,
        g1_converged: 0b0000_0111,
        thrust_axis_valid: true,
        q_thrust_to_imu: [0.5, -0.5, 0.25, 0.75],
        euler_zyx_rad: [0.1, -0.2, 1.5],
        g1_block: 1,
        g1_rows: [
            core::array::from_fn(column),
            core::array::from_fn(|i| -column(i)),
            core::array::from_fn(|i| 2.0 * column(i)),
        ],
    }
}

fn status() -> Status {
    Status {
        uptime_ms: 1500,
        armed: false,
        control: ControlStatus {
            steps: 3000,
            rate_hz: 2000.0,
            late_steps: 1,
            max_interval_us: 750,
            samples_processed: 2990,
            samples_dropped: 0,
            step_time: Some(StepTime { max_us: 42, overruns: 0 }),
        },
        imu: ImuStatus {
            present: true,
            samples: 3000,
            missing: 0,
            gyro_rad_s: [0.0, 0.0, 0.0],
            accel_mps2: [0.0, 0.0, -9.81],
            gyro_mean_rad_s: [0.0; 3],
            gyro_std_rad_s: [0.002; 3],
            accel_std_mps2: [0.03; 3],
        },
        imu_offset: ImuOffsetStatus {
            throws: 2,
            in_free_fall: false,
            estimated: true,
            r_imu_m: [-0.01, -0.013, 0.008],
            ci95_semi_axes_m: [0.0005, 0.0003, 0.0002],
            well_determined: true,
            advice: OffsetAdvice::None,
        },
        link: LinkCounters { frames_rx: 2, frames_tx: 1, ..LinkCounters::default() },
    }
}

#[test]
fn request_frames_are_pinned() {
    let hello = Request::Hello(Hello { protocol: Version { major: 1, minor: 0 }, schema_hash: 42 });
    assert_eq!(request(hello, 1), "04 01 01 01 06 2a b9 87 38 4e 00");
    assert_eq!(request(Request::GetInfo(()), 2), "07 02 02 cb 37 1f 37 00");
    assert_eq!(request(Request::GetStatus(()), 300), "08 03 ac 02 61 a8 a7 3c 00");
    let rate = SetTelemetryRate { topic: Topic::Motors, rate_hz: 500 };
    assert_eq!(request(Request::SetTelemetryRate(rate), 4), "0a 04 04 02 f4 03 2d 17 3a 88 00");
    assert_eq!(
        request(Request::Ping(Ping { nonce: 0xdead_beef }), 5),
        "0c 05 05 ef fd b6 f5 0d 65 87 dc fe 00"
    );
}

#[test]
fn protocol_1_1_request_frames_are_pinned() {
    assert_eq!(request(Request::ArmThrowToFly(()), 6), "07 06 06 08 c1 0f be 00");
    assert_eq!(request(Request::Disarm(()), 7), "07 07 07 7c da c6 5f 00");
    let pose = ExternalPose { position_ned_m: [1.5, -2.25, -0.75], heading_rad: 0.5 };
    assert_eq!(
        request(Request::SetExternalPose(pose), 8),
        "03 08 08 01 03 c0 3f 01 03 10 c0 01 03 40 bf 01 01 06 3f a7 9c eb 88 00"
    );
    assert_eq!(request(Request::GetLearner(()), 9), "07 09 09 d1 f7 65 07 00");
}

#[test]
fn response_frames_are_pinned() {
    assert_eq!(device(DeviceMessage::Response(Ok(Reply::Hello(info()))), 1), "03 81 01 01 02 01 0a ef 9b af cd f8 ac d1 91 01 02 01 13 04 53 49 54 4c 04 30 30 30 31 21 d0 0f 04 b3 9b a0 9b 00");
    assert_eq!(device(DeviceMessage::Response(Ok(Reply::Info(info()))), 2), "03 81 02 03 01 01 0a ef 9b af cd f8 ac d1 91 01 02 01 13 04 53 49 54 4c 04 30 30 30 31 21 d0 0f 04 01 f1 92 e5 00");
    assert_eq!(device(DeviceMessage::Response(Ok(Reply::Status(status()))), 3), "03 81 03 04 02 dc 0b 03 b8 17 01 08 fa 44 01 ee 05 ae 17 03 01 2a 04 01 b8 17 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 05 c3 f5 1c c1 01 01 01 01 01 01 01 01 01 01 01 1a 6f 12 03 3b 6f 12 03 3b 6f 12 03 3b 8f c2 f5 3c 8f c2 f5 3c 8f c2 f5 3c 02 1b 01 0a d7 23 bc f4 fd 54 bc 6f 12 03 3c 6f 12 03 3a 52 49 9d 39 17 b7 51 39 01 03 02 01 01 01 01 01 01 01 05 77 29 a2 63 00");
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::Done)), 4),
        "03 81 04 06 03 ae 7f 0c 4a 00"
    );
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::Pong(Ping { nonce: 7 }))), 5),
        "03 81 05 07 04 07 b9 52 e6 2f 00"
    );
}

#[test]
fn learner_frames_are_pinned() {
    assert_eq!(device(DeviceMessage::Response(Ok(Reply::Learner(learner()))), 6), "03 81 06 2d 05 a0 cb 98 01 04 04 08 01 05 8c 01 0a d7 a3 3c 58 39 b4 3c a6 9b c4 3c f4 fd d4 3c 42 60 e5 3c 8f c2 f5 3c 6f 12 03 3d 96 43 0b 3d 01 03 fa 44 02 20 02 45 04 40 03 45 04 60 06 45 04 80 09 45 04 a0 0c 45 04 c0 0f 45 07 e0 12 45 1f 07 01 01 01 02 3f 01 01 02 bf 01 03 80 3e 01 0b 40 3f cd cc cc 3d cd cc 4c be 01 04 c0 3f 01 01 03 80 3f 01 03 90 3f 01 03 a0 3f 01 03 b0 3f 01 03 c0 3f 01 03 d0 3f 01 03 e0 3f 01 03 f0 3f 01 03 80 bf 01 03 90 bf 01 03 a0 bf 01 03 b0 bf 01 03 c0 bf 01 03 d0 bf 01 03 e0 bf 01 03 f0 bf 01 01 02 40 01 03 10 40 01 03 20 40 01 03 30 40 01 03 40 40 01 03 50 40 01 03 60 40 01 07 70 40 fe 61 8a 16 00");
    assert_eq!(device(DeviceMessage::Telemetry(Telemetry::Learner(learner())), 14), "2f 82 0e 03 a0 cb 98 01 04 04 08 01 05 8c 01 0a d7 a3 3c 58 39 b4 3c a6 9b c4 3c f4 fd d4 3c 42 60 e5 3c 8f c2 f5 3c 6f 12 03 3d 96 43 0b 3d 01 03 fa 44 02 20 02 45 04 40 03 45 04 60 06 45 04 80 09 45 04 a0 0c 45 04 c0 0f 45 07 e0 12 45 1f 07 01 01 01 02 3f 01 01 02 bf 01 03 80 3e 01 0b 40 3f cd cc cc 3d cd cc 4c be 01 04 c0 3f 01 01 03 80 3f 01 03 90 3f 01 03 a0 3f 01 03 b0 3f 01 03 c0 3f 01 03 d0 3f 01 03 e0 3f 01 03 f0 3f 01 03 80 bf 01 03 90 bf 01 03 a0 bf 01 03 b0 bf 01 03 c0 bf 01 03 d0 bf 01 03 e0 bf 01 03 f0 bf 01 01 02 40 01 03 10 40 01 03 20 40 01 03 30 40 01 03 40 40 01 03 50 40 01 03 60 40 01 07 70 40 c3 75 a3 d8 00");
}

#[test]
fn learner_enums_keep_their_wire_indices() {
    let phases = [
        LearnerPhase::Idle,
        LearnerPhase::WaitingForThrow,
        LearnerPhase::Throwing,
        LearnerPhase::Released,
        LearnerPhase::Exciting,
        LearnerPhase::Done,
        LearnerPhase::Failed,
    ];
    let failures = [
        LearnerFailure::None,
        LearnerFailure::NotFreeFall,
        LearnerFailure::ThrowTimedOut,
        LearnerFailure::RankDeficient,
        LearnerFailure::NoHover,
        LearnerFailure::Disarmed,
        LearnerFailure::ImuLost,
    ];
    let mut buffer = [0u8; 4];
    for (index, phase) in phases.iter().enumerate() {
        assert_eq!(postcard::to_slice(phase, &mut buffer).unwrap(), [index as u8], "{phase:?}");
    }
    for (index, failure) in failures.iter().enumerate() {
        let bytes = postcard::to_slice(failure, &mut buffer).unwrap();
        assert_eq!(bytes, [index as u8], "{failure:?}");
    }
    assert_eq!(Topic::Learner.index(), 3);
    assert_eq!(postcard::to_slice(&Topic::Learner, &mut buffer).unwrap(), [3]);
}

#[test]
fn error_frames_are_pinned() {
    let errors = [
        DeviceError::IncompatibleProtocol {
            device: Version { major: 1, minor: 0 },
            host: Version { major: 2, minor: 3 },
        },
        DeviceError::HandshakeRequired,
        DeviceError::UnknownRequest { id: 0x7f },
        DeviceError::Malformed { id: 0x04 },
        DeviceError::BadValue {
            name: text("rate_hz"),
            value: 5000.0,
            min: 0.0,
            max: 1000.0,
            unit: text("Hz"),
        },
        DeviceError::Busy,
        DeviceError::RefusedWhileArmed,
    ];
    let golden = ["04 81 09 01 02 01 07 02 03 e9 8a 5b d1 00", "09 81 09 01 01 8f 9f 5b bb 00", "0a 81 09 01 02 7f 22 cf 4f 95 00", "0a 81 09 01 03 04 63 a8 fc 6e 00", "0d 81 09 01 04 07 72 61 74 65 5f 68 7a 04 40 9c 45 01 01 01 01 01 0a 7a 44 02 48 7a 45 4b 0d 51 00", "09 81 09 01 05 90 08 c1 7c 00", "09 81 09 01 06 64 fb 91 6f 00"];
    for (error, expected) in errors.into_iter().zip(golden) {
        assert_eq!(device(DeviceMessage::Response(Err(error.clone())), 9), expected, "{error:?}");
    }
}

#[test]
fn telemetry_and_event_frames_are_pinned() {
    let imu = ImuTelemetry {
        t_us: 1_000_500,
        gyro_rad_s: [0.5, -0.25, 1.0],
        accel_mps2: [0.0, 0.0, -9.81],
    };
    assert_eq!(device(DeviceMessage::Telemetry(Telemetry::Imu(imu)), 10), "03 82 0a 04 b4 88 3d 01 01 02 3f 01 03 80 be 01 03 80 3f 01 01 01 01 01 01 01 09 c3 f5 1c c1 12 fb 5f 6f 00");
    let control =
        ControlTelemetry { t_us: 2_000_000, steps: 4000, late_steps: 2, samples_dropped: 1 };
    assert_eq!(
        device(DeviceMessage::Telemetry(Telemetry::Control(control)), 11),
        "0f 82 0b 01 80 89 7a a0 1f 02 01 d5 70 04 fe 00"
    );
    let mut speeds = [None; MAX_MOTORS];
    speeds[0] = Some(1000.0);
    let motors = MotorTelemetry { t_us: 5, commands: [0.25; MAX_MOTORS], speeds_rad_s: speeds };
    assert_eq!(device(DeviceMessage::Telemetry(Telemetry::Motors(motors)), 12), "05 82 0c 02 05 01 03 80 3e 01 03 80 3e 01 03 80 3e 01 03 80 3e 01 03 80 3e 01 03 80 3e 01 03 80 3e 01 04 80 3e 01 01 03 7a 44 01 01 01 01 01 01 05 bc 08 96 6d 00");
    let counters = LinkCounters { bad_crc: 3, oversize: 1, ..LinkCounters::default() };
    assert_eq!(
        device(DeviceMessage::Event(Event::LinkErrors(counters)), 13),
        "03 83 0d 01 01 02 03 02 01 01 01 01 05 8a b3 f8 5c 00"
    );
}

#[test]
fn the_handshake_reply_exposes_the_device_version_at_a_frozen_offset() {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = DeviceMessage::Response(Ok(Reply::Hello(info()))).encode(1, &mut buffer).unwrap();
    let mut decoder = Decoder::new();
    let frame =
        buffer[..len].iter().find_map(|&b| decoder.push(b).map(|r| r.map(|f| f.payload.to_vec())));
    let payload = frame.unwrap().unwrap();
    assert_eq!(peek_hello_version(&payload), Some(Version { major: 1, minor: 0 }));
}

#[test]
fn the_largest_status_fits_one_frame() {
    // Every counter at its maximum (5-byte varints), every float present: the biggest Status.
    let mut status = status();
    status.uptime_ms = u32::MAX;
    let c = &mut status.control;
    (c.steps, c.late_steps, c.max_interval_us) = (u32::MAX, u32::MAX, u32::MAX);
    (c.samples_processed, c.samples_dropped) = (u32::MAX, u32::MAX);
    c.step_time = Some(StepTime { max_us: u32::MAX, overruns: u32::MAX });
    let advice = OffsetAdvice::BiasNotSeparable { direction_imu: [1.0; 3], spin_about_axis: 2 };
    status.imu_offset.advice = advice;
    (status.imu.samples, status.imu.missing) = (u32::MAX, u32::MAX);
    status.link = LinkCounters {
        frames_rx: u32::MAX,
        frames_tx: u32::MAX,
        bad_crc: u32::MAX,
        bad_framing: u32::MAX,
        oversize: u32::MAX,
        unknown_id: u32::MAX,
        malformed: u32::MAX,
        telemetry_dropped: u32::MAX,
        responses_dropped: u32::MAX,
    };
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = DeviceMessage::Response(Ok(Reply::Status(status))).encode(u16::MAX, &mut buffer);
    let len = len.expect("the largest status fits a frame");
    assert!(len <= MAX_FRAME_LEN - 40, "{len} bytes: less than 40 bytes of room left to grow");
}

/// The largest possible learner sample: every varint at its longest (`u64::MAX` time,
/// `u16::MAX` excitation time), every `Option` `Some`, the highest enum variants.
fn largest_learner() -> LearnerTelemetry {
    LearnerTelemetry {
        t_us: u64::MAX,
        phase: LearnerPhase::Failed,
        failure: LearnerFailure::ImuLost,
        motor_count: u8::MAX,
        exciting_motor: Some(u8::MAX),
        excitation_ms: u16::MAX,
        tau_s: [f32::MAX; MAX_MOTORS],
        omega_max_rad_s: [f32::MAX; MAX_MOTORS],
        motors_converged: u8::MAX,
        g1_converged: u8::MAX,
        thrust_axis_valid: true,
        q_thrust_to_imu: [f32::MAX; 4],
        euler_zyx_rad: [f32::MAX; 3],
        g1_block: u8::MAX,
        g1_rows: [[f32::MAX; MAX_MOTORS]; 3],
    }
}

/// Bytes left in a frame after the largest learner sample, as telemetry and as a reply.
const LEARNER_MARGIN_BYTES: usize = 34;

#[test]
fn the_largest_learner_telemetry_fits_one_frame() {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let largest = largest_learner();
    let telemetry =
        DeviceMessage::Telemetry(Telemetry::Learner(largest)).encode(u16::MAX, &mut buffer);
    let telemetry = telemetry.expect("the largest learner sample fits a frame");
    let reply = DeviceMessage::Response(Ok(Reply::Learner(largest))).encode(u16::MAX, &mut buffer);
    let reply = reply.expect("the largest learner reply fits a frame");
    // The reply carries two more enum tags (`Ok`, `Reply::Learner`) than the telemetry's one.
    assert_eq!(reply, telemetry + 1);
    println!("largest learner telemetry: {telemetry} bytes, reply: {reply} bytes, frame: {MAX_FRAME_LEN} bytes");
    assert_eq!(MAX_FRAME_LEN - reply, LEARNER_MARGIN_BYTES, "the margin is pinned: {reply} bytes");
}

#[test]
fn protocol_1_2_frames_are_pinned() {
    let name = |s: &str| heapless::String::<NAME_LEN>::try_from(s).unwrap();
    let values = |v: &[f32]| ParamValues::from_slice(v).unwrap();
    let get_index = request(Request::GetParam(ParamRef::Index(3)), 10);
    let get_name = request(Request::GetParam(ParamRef::Name(name("imu_offset_m"))), 11);
    let set = request(
        Request::SetParam(SetParam { name: name("gravity_mps2"), values: values(&[9.79]) }),
        12,
    );
    let test = request(Request::MotorTest(MotorTest { motor: 2, command: 0.25 }), 13);
    let stop = request(Request::StopCalibration(StopCalibration { accept: true }), 14);
    let config = ConfigStatus {
        origin: ConfigOrigin::UnknownLayout { version: 9 },
        layout_version: 1,
        param_count: 23,
        unsaved_changes: true,
        rejected_at_load: 2,
        saves: 300,
        calibrating: false,
        motor_test: true,
    };
    let config = device(DeviceMessage::Response(Ok(Reply::Config(config))), 15);
    let refused = device(
        DeviceMessage::Response(Err(DeviceError::WrongLength {
            name: name("imu_offset_m"),
            expected: 3,
            got: 2,
        })),
        16,
    );
    let timed_out = device(DeviceMessage::Event(Event::MotorTestTimedOut { motor: 2 }), 17);
    assert_eq!(get_index, "03 0a 0a 06 03 9c 94 2a 65 00");
    assert_eq!(get_name, "15 0a 0b 01 0c 69 6d 75 5f 6f 66 66 73 65 74 5f 6d 62 f5 92 0a 00");
    assert_eq!(
        set,
        "19 0b 0c 0c 67 72 61 76 69 74 79 5f 6d 70 73 32 01 d7 a3 1c 41 3d e4 e2 14 00"
    );
    assert_eq!(test, "04 11 0d 02 01 07 80 3e 45 2b df 65 00");
    assert_eq!(stop, "08 10 0e 01 79 cf 76 16 00");
    assert_eq!(config, "03 81 0f 0a 07 02 09 01 17 01 02 ac 02 06 01 c9 7d ab 7e 00");
    assert_eq!(
        refused,
        "18 81 10 01 08 0c 69 6d 75 5f 6f 66 66 73 65 74 5f 6d 03 02 9f 3d e0 a6 00"
    );
    assert_eq!(timed_out, "09 83 11 02 02 2c a4 78 6b 00");
}

#[test]
fn protocol_1_3_state_frames_are_pinned() {
    let mut speeds = [None; MAX_MOTORS];
    speeds[0] = Some(1000.0);
    let state = StateTelemetry {
        t_us: 500,
        phase: LearnerPhase::Exciting,
        flying: false,
        imu_fresh: true,
        gyro_rad_s: [0.5, -1.0, 0.0],
        accel_mps2: [0.0, 0.0, -9.81],
        q_world_imu: [1.0, 0.0, 0.0, 0.0],
        motor_count: 4,
        commands: [0.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        speeds_rad_s: speeds,
    };
    let frame = device(DeviceMessage::Telemetry(Telemetry::State(state)), 7);
    assert_eq!(frame, "07 82 07 04 f4 03 04 02 01 01 01 02 3f 01 03 80 bf 01 01 01 01 01 01 01 01 01 01 01 05 c3 f5 1c c1 01 03 80 3f 01 01 01 01 01 01 01 01 01 01 01 02 04 01 03 80 3e 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 02 01 01 03 7a 44 01 01 01 01 01 01 05 24 84 30 92 00");
    let rate = SetTelemetryRate { topic: Topic::State, rate_hz: 2000 };
    assert_eq!(request(Request::SetTelemetryRate(rate), 5), "0a 04 05 04 d0 0f 8c 06 8c f8 00");
    assert_eq!(Topic::State.index(), 4, "wire index of the new topic");
    assert_eq!(Topic::ALL.iter().filter(|t| t.is_per_step()).count(), 3);
}

#[test]
fn protocol_1_4_flight_board_and_setpoint_frames_are_pinned() {
    let setpoint = PositionSetpoint { position_ned_m: [1.0, -2.0, -1.5], heading_rad: 0.0 };
    assert_eq!(
        request(Request::SetPositionSetpoint(setpoint), 3),
        "03 13 03 01 03 80 3f 01 01 02 c0 01 03 c0 bf 01 01 01 05 33 45 59 b2 00"
    );
    assert_eq!(request(Request::GetFlight(()), 4), "07 14 04 90 70 b4 47 00");
    assert_eq!(request(Request::GetBoard(()), 5), "07 15 05 e4 6b 7d a6 00");
    assert_eq!(request(Request::RebootToBootloader(()), 6), "07 16 06 89 30 ca 81 00");
    let flight = FlightTelemetry {
        t_us: 1_000,
        mode: FlightMode::PositionHold,
        q_world_thrust: [1.0, 0.0, 0.0, 0.0],
        euler_zyx_rad: [0.0, 0.0, 0.5],
        rate_rad_s: [0.1, 0.0, 0.0],
        rate_sp_rad_s: [0.0, 0.0, 0.0],
        specific_force_sp_ned_mps2: [0.0, 0.0, -9.81],
        tilt_error_rad: 0.01,
        position_sp_ned_m: Some([1.0, -2.0, -1.5]),
        position_ned_m: Some([1.0, -2.0, -1.5]),
        velocity_ned_mps: None,
        pose_fresh: true,
        allocation_failures: 0,
        saturated: 0b0001,
        last_failsafe: Some(FailsafeReason::PoseLost),
        failsafes: FailsafeCounters { pose_lost: 1, ..FailsafeCounters::default() },
    };
    assert_eq!(device(DeviceMessage::Telemetry(Telemetry::Flight(flight)), 9), "07 82 09 05 e8 07 02 01 03 80 3f 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 06 3f cd cc cc 3d 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 0a c3 f5 1c c1 0a d7 23 3c 01 01 03 80 3f 01 01 02 c0 01 04 c0 bf 01 01 03 80 3f 01 01 02 c0 01 03 c0 bf 02 01 04 01 01 06 01 01 01 01 01 02 01 01 05 f1 ab 97 70 00");
    let board = BoardHealth {
        core_clock_hz: Some(480_000_000),
        silicon_revision: Some(0x2003),
        imu: ImuDriverState::WrongIdentity { expected: 0x47, found: 0xff },
        motors: None,
        receiver: Some(ReceiverHealth {
            link_up: true,
            link_quality_pct: 100,
            rssi_dbm: -60,
            frames: 10,
            frame_errors: 1,
        }),
    };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::Board(board))), 5),
        "03 81 05 0e 09 01 80 f0 f0 e4 01 01 83 40 02 47 ff 0b 01 01 64 77 0a 01 f0 a4 20 ce 00"
    );
    let event = Event::Failsafe {
        reason: FailsafeReason::Kill,
        action: FailsafeAction::Disarmed,
        count: 2,
    };
    assert_eq!(device(DeviceMessage::Event(event), 1), "05 83 01 03 08 06 02 21 a8 c7 fc 00");
    // Protocol 1.15: a hand's catch, the last `LandReason`.
    let caught = Event::Landed { reason: LandReason::Caught, touchdown_speed_mps: 0.0, count: 1 };
    assert_eq!(
        device(DeviceMessage::Event(caught), 2),
        "05 83 02 05 07 01 01 01 06 01 98 0d 9b 2f 00"
    );
    assert_eq!(
        device(DeviceMessage::Response(Err(DeviceError::Unsupported)), 6),
        "09 81 06 01 0c f0 89 d2 48 00"
    );
    assert_eq!(Topic::Flight.index(), 5, "wire index of the new topic");
    assert!(!Topic::Flight.is_per_step(), "the link samples the flight topic");
}

/// The largest flight sample: every varint at its longest, every `Option` `Some`.
fn largest_flight() -> FlightTelemetry {
    let counts = FailsafeCounters {
        bad_command: u16::MAX,
        allocation_failed: u16::MAX,
        identification: u16::MAX,
        attitude_lost: u16::MAX,
        imu_lost: u16::MAX,
        imu_fault: u16::MAX,
        pose_lost: u16::MAX,
        rc_lost: u16::MAX,
        kill: u16::MAX,
    };
    FlightTelemetry {
        t_us: u64::MAX,
        mode: FlightMode::PositionHold,
        q_world_thrust: [1.0; 4],
        euler_zyx_rad: [1.0; 3],
        rate_rad_s: [1.0; 3],
        rate_sp_rad_s: [1.0; 3],
        specific_force_sp_ned_mps2: [1.0; 3],
        tilt_error_rad: 1.0,
        position_sp_ned_m: Some([1.0; 3]),
        position_ned_m: Some([1.0; 3]),
        velocity_ned_mps: Some([1.0; 3]),
        pose_fresh: true,
        allocation_failures: u16::MAX,
        saturated: u8::MAX,
        last_failsafe: Some(FailsafeReason::Identification(LearnerFailure::NoHover)),
        failsafes: counts,
    }
}

#[test]
fn the_largest_flight_sample_and_board_health_fit_one_frame() {
    let flight = largest_flight();
    let board = BoardHealth {
        core_clock_hz: Some(u32::MAX),
        silicon_revision: Some(u16::MAX),
        imu: ImuDriverState::ConfigMismatch { register: 0xff, written: 0xff, read: 0xff },
        motors: Some(MotorLinkHealth {
            motor_count: 8,
            frames_sent: u32::MAX,
            reports: [u32::MAX; MAX_MOTORS],
            report_errors: [u32::MAX; MAX_MOTORS],
        }),
        receiver: Some(ReceiverHealth {
            link_up: true,
            link_quality_pct: 100,
            rssi_dbm: i16::MIN,
            frames: u32::MAX,
            frame_errors: u32::MAX,
        }),
    };
    let messages = [
        DeviceMessage::Telemetry(Telemetry::Flight(flight)),
        DeviceMessage::Response(Ok(Reply::Flight(flight))),
        DeviceMessage::Response(Ok(Reply::Board(board))),
    ];
    for message in messages {
        let mut buffer = [0u8; MAX_FRAME_LEN];
        let len = message.encode(u16::MAX, &mut buffer).expect("fits a frame");
        assert!(len <= MAX_FRAME_LEN - 24, "{len} bytes: less than 24 bytes of room to grow");
    }
}

#[test]
fn protocol_1_5_esc_command_is_pinned() {
    // Beep 1 (DShot number 1) to every motor; then spin direction reversed (21) to motor 2.
    let beep = EscCommand { motor: ESC_ALL_MOTORS, command: DshotCommand::Beep1.value() as u8 };
    assert_eq!(request(Request::EscCommand(beep), 7), "09 17 07 ff 01 d9 81 7b 9d 00");
    let reverse = EscCommand { motor: 2, command: 21 };
    assert_eq!(request(Request::EscCommand(reverse), 8), "09 17 08 02 15 68 9f b8 82 00");
}

#[test]
fn protocol_1_6_health_and_speed_refusal_are_pinned() {
    assert_eq!(request(Request::GetHealth(()), 9), "07 18 09 27 9e 02 2b 00");
    let health = SensorHealth {
        imu_held: ImuHeldCounters { missing: 2, non_finite: 1, frozen: 0, accel_saturated: 300 },
        imu_longest_hold_us: 19_500,
        motor_count: 4,
        speeds_reported: 0b1011,
        speed_reports_lost: 1,
    };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::Health(health))), 10),
        "03 81 0a 04 0a 02 01 0d ac 02 ac 98 01 04 0b 01 5c 08 7d ec 00"
    );
    let refusal = DeviceError::SpeedsNotReported { motors: 0b0100 };
    assert_eq!(
        device(DeviceMessage::Response(Err(refusal)), 11),
        "0a 81 0b 01 0d 04 68 19 40 25 00"
    );
    // Appended: the earlier failures keep their indices (`learner_enums_keep_their_wire_indices`).
    let mut buffer = [0u8; 4];
    assert_eq!(postcard::to_slice(&LearnerFailure::NoSpeedTelemetry, &mut buffer).unwrap(), [7]);
}

#[test]
fn protocol_1_7_identification_failures_are_pinned() {
    // Appended after `NoSpeedTelemetry` (7): the earlier failures keep their indices.
    let mut buffer = [0u8; 4];
    assert_eq!(postcard::to_slice(&LearnerFailure::NoThrustAxis, &mut buffer).unwrap(), [8]);
    let motor = LearnerFailure::MotorUnusable { motor: 3 };
    assert_eq!(postcard::to_slice(&motor, &mut buffer).unwrap(), [9, 3]);
    assert_eq!(postcard::to_slice(&LearnerFailure::InvalidModel, &mut buffer).unwrap(), [10]);
}

#[test]
fn protocol_1_8_link_security_and_signed_frames_are_pinned() {
    assert_eq!(request(Request::GetLinkSecurity(()), 1), "07 19 01 9f 5e 79 b2 00");
    let key =
        SetLinkKey { key: Some(heapless::Vec::from_array([0x11; protocol::signing::KEY_LEN])) };
    assert_eq!(request(Request::SetLinkKey(key), 2), "29 1a 02 01 20 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 11 a0 57 c8 81 00");
    assert_eq!(
        request(Request::SetLinkKey(SetLinkKey { key: None }), 3),
        "03 1a 03 05 a1 1a 1f 53 00"
    );
    let security = LinkSecurity {
        trusted: false,
        paired: true,
        session: 0x0102_0304,
        last_timestamp: 1000,
        unsigned_refused: 2,
        bad_signature: 1,
        replayed: 3,
    };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::LinkSecurity(security))), 4),
        "03 81 04 02 0b 0f 01 84 86 88 08 e8 07 02 01 03 88 32 f3 a8 00"
    );
    for (error, expected) in [
        (DeviceError::SignatureRequired, "09 81 05 01 0e 74 39 c7 43 00"),
        (DeviceError::BadSignature, "09 81 05 01 0f 77 ba ac b1 00"),
        (DeviceError::Replayed { last_timestamp: 300 }, "0b 81 05 01 10 ac 02 03 6d 4c 67 00"),
        (DeviceError::TrustedLinkOnly, "09 81 05 01 11 3f c2 8a 0d 00"),
    ] {
        assert_eq!(device(DeviceMessage::Response(Err(error)), 5), expected);
    }
    // A signed SetParam: id 0x0B | 0x40, seq 6, payload, timestamp 0x01_0203 (6 bytes LE),
    // the first 8 bytes of HMAC-SHA256(key 0x22 × 32, session 7 LE | the bytes before), CRC.
    let signer = Signer { key: [0x22; protocol::signing::KEY_LEN], session: 7 };
    let set = Request::SetParam(SetParam {
        name: text("rate_p"),
        values: heapless::Vec::from_slice(&[0.5]).unwrap(),
    });
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = set.encode_signed(6, &signer, 0x01_0203, &mut buffer).unwrap();
    assert_eq!(hex(&buffer[..len]), "0b 4b 06 06 72 61 74 65 5f 70 01 01 01 05 3f 03 02 01 01 01 0d ff db 39 32 ac a4 14 60 ab b7 f3 bd 00");
}

#[test]
fn every_topic_sample_fits_its_booked_frame_length() {
    let largest_imu = ImuTelemetry { t_us: u64::MAX, gyro_rad_s: [1.0; 3], accel_mps2: [1.0; 3] };
    let largest_control = ControlTelemetry {
        t_us: u64::MAX,
        steps: u32::MAX,
        late_steps: u32::MAX,
        samples_dropped: u32::MAX,
    };
    let largest_motors = MotorTelemetry {
        t_us: u64::MAX,
        commands: [1.0; MAX_MOTORS],
        speeds_rad_s: [Some(1.0); MAX_MOTORS],
    };
    let largest_state = StateTelemetry {
        t_us: u64::MAX,
        phase: LearnerPhase::Failed,
        flying: true,
        imu_fresh: true,
        gyro_rad_s: [1.0; 3],
        accel_mps2: [1.0; 3],
        q_world_imu: [1.0; 4],
        motor_count: MAX_MOTORS as u8,
        commands: [1.0; MAX_MOTORS],
        speeds_rad_s: [Some(1.0); MAX_MOTORS],
    };
    let mut learner_blocks = [largest_learner(), largest_learner()];
    learner_blocks[1].g1_block = 0;
    let samples: Vec<(Topic, Telemetry)> = vec![
        (Topic::Imu, Telemetry::Imu(largest_imu)),
        (Topic::Control, Telemetry::Control(largest_control)),
        (Topic::Motors, Telemetry::Motors(largest_motors)),
        (Topic::Learner, Telemetry::Learner(learner_blocks[0])),
        (Topic::Learner, Telemetry::Learner(learner_blocks[1])),
        (Topic::State, Telemetry::State(largest_state)),
        (Topic::Flight, Telemetry::Flight(largest_flight())),
    ];
    for topic in Topic::ALL {
        let longest = samples
            .iter()
            .filter(|(t, _)| *t == topic)
            .map(|(_, sample)| {
                let mut buffer = [0u8; MAX_FRAME_LEN];
                DeviceMessage::Telemetry(*sample).encode(u16::MAX, &mut buffer).unwrap()
            })
            .max()
            .expect("a sample of every topic");
        assert_eq!(usize::from(topic.max_frame_len()), longest, "{topic:?}");
    }
}

#[test]
fn protocol_1_9_flight_log_files_are_pinned() {
    assert_eq!(request(Request::ListLogs(ListLogs { first: 17 }), 1), "08 1b 01 11 5d fc 2e 33 00");
    let read = ReadLog { number: 3, offset: 1000, len: 224 };
    assert_eq!(request(Request::ReadLog(read), 2), "0c 1c 02 03 e8 07 e0 01 5e 61 b4 7a 00");
    assert_eq!(
        request(Request::DeleteLog(DeleteLog { number: 3 }), 3),
        "08 1d 03 03 3c 8d bf 34 00"
    );
    let list = LogList {
        files: heapless::Vec::from_slice(&[
            LogFileInfo { number: 1, size_bytes: 512, writing: false },
            LogFileInfo { number: 2, size_bytes: 70_000, writing: true },
        ])
        .unwrap(),
        more: false,
    };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::LogList(list))), 4),
        "03 81 04 06 0c 02 01 80 04 06 02 f0 a2 04 01 05 57 4b 90 c6 00"
    );
    let chunk = LogChunk {
        number: 3,
        offset: 1000,
        size_bytes: 1536,
        bytes: heapless::Vec::from_slice(&[0x00, 0x01, 0xff]).unwrap(),
    };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::LogChunk(chunk))), 5),
        "03 81 05 08 0d 03 e8 07 80 0c 03 07 01 ff 18 d6 c1 4e 00"
    );
    for (error, expected) in [
        (DeviceError::NoSuchLog { number: 9 }, "0a 81 06 01 12 09 6a 56 f7 12 00"),
        (
            DeviceError::LogOffsetPastEnd { number: 9, size_bytes: 512 },
            "0c 81 06 01 13 09 80 04 10 49 34 5d 00",
        ),
        (DeviceError::LogBeingWritten { number: 9 }, "0a 81 06 01 14 09 58 07 38 7b 00"),
        (DeviceError::LogStorageFailed, "09 81 06 01 15 53 95 3e 20 00"),
    ] {
        assert_eq!(device(DeviceMessage::Response(Err(error)), 6), expected);
    }
}

#[test]
fn protocol_1_10_granted_telemetry_rate_is_pinned() {
    let granted = SetTelemetryRate { topic: Topic::Learner, rate_hz: 19 };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::TelemetryRate(granted))), 3),
        "03 81 03 08 0e 03 13 61 44 28 32 00"
    );
}

#[test]
fn the_largest_log_chunk_and_the_longest_log_list_fit_a_frame() {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let chunk = LogChunk {
        number: u32::MAX,
        offset: u32::MAX,
        size_bytes: u32::MAX,
        bytes: heapless::Vec::from_slice(&[0xAA; LOG_CHUNK_LEN]).unwrap(),
    };
    let message = DeviceMessage::Response(Ok(Reply::LogChunk(chunk)));
    let len = message.encode(u16::MAX, &mut buffer).expect("the largest chunk fits a frame");
    // Raw: id, seq (3), Ok, variant, three u32 varints (5 each), length (2), bytes, CRC (4).
    assert_eq!(len, 1 + (1 + 3 + 1 + 1 + 15 + 2 + LOG_CHUNK_LEN + 4) + 1);
    // Zeros in the bytes cost nothing more: COBS replaces each with its code byte.
    let zeros = LogChunk {
        number: u32::MAX,
        offset: u32::MAX,
        size_bytes: u32::MAX,
        bytes: heapless::Vec::from_slice(&[0; LOG_CHUNK_LEN]).unwrap(),
    };
    let message = DeviceMessage::Response(Ok(Reply::LogChunk(zeros)));
    assert!(message.encode(u16::MAX, &mut buffer).is_ok());
    let widest = LogFileInfo { number: u32::MAX, size_bytes: u32::MAX, writing: true };
    let list =
        LogList { files: heapless::Vec::from_slice(&[widest; LOG_LIST_LEN]).unwrap(), more: true };
    let message = DeviceMessage::Response(Ok(Reply::LogList(list)));
    assert!(message.encode(u16::MAX, &mut buffer).is_ok(), "sixteen of the widest entries fit");
}

#[test]
fn protocol_1_11_battery_is_pinned() {
    assert_eq!(request(Request::GetBattery(()), 1), "07 1e 01 da 97 14 c8 00");
    let battery = BatteryStatus {
        voltage_v: 16.5,
        current_a: 12.25,
        used_mah: 250.0,
        cells: 4,
        remaining_pct: 92,
    };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::Battery(battery))), 2),
        "03 81 02 02 0f 01 03 84 41 01 03 44 41 01 09 7a 43 04 5c 69 dc 1a b7 00"
    );
}

#[test]
fn protocol_1_12_identification_is_pinned() {
    assert_eq!(request(Request::GetIdentification(()), 1), "07 1f 01 ad 0f b6 db 00");
    let identification = IdentificationStatus {
        speeds_modelled: true,
        imu_offset_source: ImuOffsetSource::FittedInFlight,
        r_imu_m: [0.0125, -0.25, 0.5],
        imu_offset_status_fitted_in_flight: true,
    };
    assert_eq!(
        device(DeviceMessage::Response(Ok(Reply::Identification(identification))), 2),
        "03 81 02 08 10 01 04 cd cc 4c 3c 01 03 80 be 01 01 07 3f 01 eb 72 99 be 00"
    );
}
