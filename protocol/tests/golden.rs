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
