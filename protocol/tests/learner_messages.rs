//! The messages of the in-flight identification (protocol 1.1): exact bytes of each request, and
//! the largest learner sample fits one frame.

use protocol::*;

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ")
}

fn request(message: Request, seq: u16) -> String {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = message.encode(seq, &mut buffer).unwrap();
    hex(&buffer[..len])
}

/// Every field at its largest encoding (varints at their maximum, every option present).
fn largest_learner() -> LearnerTelemetry {
    LearnerTelemetry {
        t_us: u64::MAX,
        phase: LearnerPhase::Failed,
        failure: LearnerFailure::ImuLost,
        motor_count: 8,
        exciting_motor: Some(u8::MAX),
        excitation_ms: u16::MAX,
        tau_s: [f32::MAX; MAX_MOTORS],
        omega_max_rad_s: [f32::MAX; MAX_MOTORS],
        motors_converged: u8::MAX,
        g1_converged: u8::MAX,
        thrust_axis_valid: true,
        q_thrust_to_imu: [1.0; 4],
        euler_zyx_rad: [3.0; 3],
        g1_block: 1,
        g1_rows: [[f32::MAX; MAX_MOTORS]; 3],
    }
}

#[test]
fn the_largest_learner_sample_fits_one_frame_as_telemetry_and_as_a_reply() {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let telemetry = DeviceMessage::Telemetry(Telemetry::Learner(largest_learner()));
    let len = telemetry.encode(u16::MAX, &mut buffer).expect("fits a frame");
    eprintln!("largest learner telemetry frame: {len} B of {MAX_FRAME_LEN} B");
    assert!(len <= MAX_FRAME_LEN);
    let reply = DeviceMessage::Response(Ok(Reply::Learner(largest_learner())));
    assert!(reply.encode(u16::MAX, &mut buffer).is_ok());
}

#[test]
fn learner_messages_round_trip() {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let sample = largest_learner();
    let len = DeviceMessage::Telemetry(Telemetry::Learner(sample)).encode(7, &mut buffer).unwrap();
    let mut decoder = Decoder::new();
    let mut decoded = None;
    for byte in &buffer[..len] {
        if let Some(result) = decoder.push(*byte) {
            let frame = result.expect("a valid frame");
            assert_eq!(frame.seq, 7);
            decoded = Some(DeviceMessage::decode(&frame).expect("decodes"));
        }
    }
    assert_eq!(decoded, Some(DeviceMessage::Telemetry(Telemetry::Learner(sample))));
}

#[test]
fn identification_requests_have_fixed_bytes() {
    // COBS(id, sequence varint, postcard payload, CRC-32C), then the 0x00 delimiter. A change
    // here is a protocol version change.
    let arm = request(Request::ArmThrowToFly(()), 1);
    let disarm = request(Request::Disarm(()), 1);
    let learner = request(Request::GetLearner(()), 1);
    let pose = request(
        Request::SetExternalPose(ExternalPose {
            position_ned_m: [1.0, -2.0, -3.5],
            heading_rad: 0.5,
        }),
        1,
    );
    assert_eq!(arm, "07 06 01 e3 a5 c5 6a 00");
    assert_eq!(disarm, "07 07 01 94 3d 67 79 00");
    assert_eq!(learner, "07 09 01 1e af bc 8d 00");
    // 1.0 = 0x3f800000, −2.0 = 0xc0000000, −3.5 = 0xc0600000, 0.5 = 0x3f000000 (little-endian,
    // the zero bytes taken out by COBS).
    assert_eq!(pose, "03 08 01 01 03 80 3f 01 01 02 c0 01 03 60 c0 01 01 06 3f 29 a7 35 a8 00");
}
