//! Property tests: the decoder accepts any byte stream without panicking, reports typed errors
//! for garbage, bit flips, truncation, oversize frames and unknown ids, and resynchronises at the
//! next delimiter.

use proptest::prelude::*;
use protocol::frame::{encode, MAX_FRAME_LEN};
use protocol::{
    DecodeError, Decoder, DeviceMessage, ExternalPose, FrameError, Hello, LearnerFailure,
    LearnerPhase, LearnerTelemetry, MotorTest, ParamRef, ParamValues, Ping, PositionSetpoint,
    Reply, Request, SetParam, SetTelemetryRate, StopCalibration, Telemetry, Topic, Version,
    PARAM_MAX_LEN, TOPIC_COUNT,
};

/// Everything the decoder said about a byte stream: frames as `(id, seq, payload)` or errors.
type Outcome = Vec<Result<(u8, u16, Vec<u8>), FrameError>>;

fn decode_stream(bytes: &[u8]) -> Outcome {
    let mut decoder = Decoder::new();
    let mut out = Vec::new();
    for &byte in bytes {
        if let Some(result) = decoder.push(byte) {
            out.push(result.map(|frame| (frame.id, frame.seq, frame.payload.to_vec())));
        }
    }
    out
}

fn frame_of(request: &Request, seq: u16) -> Vec<u8> {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = request.encode(seq, &mut buffer).expect("every request fits a frame");
    buffer[..len].to_vec()
}

fn any_request() -> impl Strategy<Value = Request> {
    prop_oneof![
        (any::<u8>(), any::<u8>(), any::<u64>()).prop_map(|(major, minor, schema_hash)| {
            Request::Hello(Hello { protocol: Version { major, minor }, schema_hash })
        }),
        Just(Request::GetInfo(())),
        Just(Request::GetStatus(())),
        (0usize..TOPIC_COUNT, any::<u16>()).prop_map(|(topic, rate_hz)| {
            Request::SetTelemetryRate(SetTelemetryRate { topic: Topic::ALL[topic], rate_hz })
        }),
        any::<u32>().prop_map(|nonce| Request::Ping(Ping { nonce })),
        Just(Request::ArmThrowToFly(())),
        Just(Request::Disarm(())),
        // Finite values only: a NaN never equals itself, so the round trip could not compare.
        (proptest::array::uniform3(-1e6f32..1e6), -10f32..10.0).prop_map(
            |(position_ned_m, heading_rad)| {
                Request::SetExternalPose(ExternalPose { position_ned_m, heading_rad })
            }
        ),
        Just(Request::GetLearner(())),
        prop_oneof![
            any::<u16>().prop_map(|index| Request::GetParam(ParamRef::Index(index))),
            "[a-z_]{1,24}".prop_map(|name| Request::GetParam(ParamRef::Name(
                heapless::String::try_from(name.as_str()).unwrap()
            ))),
        ],
        ("[a-z_]{1,24}", proptest::collection::vec(-1e6f32..1e6, 0..=PARAM_MAX_LEN)).prop_map(
            |(name, values)| Request::SetParam(SetParam {
                name: heapless::String::try_from(name.as_str()).unwrap(),
                values: ParamValues::from_slice(&values).unwrap(),
            })
        ),
        Just(Request::SaveConfig(())),
        Just(Request::ResetConfig(())),
        Just(Request::GetConfig(())),
        Just(Request::StartCalibration(())),
        any::<bool>().prop_map(|accept| Request::StopCalibration(StopCalibration { accept })),
        (any::<u8>(), 0f32..1.0)
            .prop_map(|(motor, command)| Request::MotorTest(MotorTest { motor, command })),
        Just(Request::Reboot(())),
        (proptest::array::uniform3(-1e6f32..1e6), -10f32..10.0).prop_map(
            |(position_ned_m, heading_rad)| {
                Request::SetPositionSetpoint(PositionSetpoint { position_ned_m, heading_rad })
            }
        ),
        Just(Request::GetFlight(())),
        Just(Request::GetBoard(())),
        Just(Request::RebootToBootloader(())),
        (any::<u8>(), any::<u8>()).prop_map(|(motor, command)| Request::EscCommand(
            protocol::EscCommand { motor, command }
        )),
        Just(Request::GetHealth(())),
        Just(Request::GetLinkSecurity(())),
        proptest::option::of(any::<[u8; protocol::signing::KEY_LEN]>()).prop_map(|key| {
            Request::SetLinkKey(protocol::SetLinkKey { key: key.map(heapless::Vec::from_array) })
        }),
        prop_oneof![
            any::<u32>().prop_map(|first| Request::ListLogs(protocol::ListLogs { first })),
            (any::<u32>(), any::<u32>(), any::<u16>()).prop_map(|(number, offset, len)| {
                Request::ReadLog(protocol::ReadLog { number, offset, len })
            }),
            any::<u32>().prop_map(|number| Request::DeleteLog(protocol::DeleteLog { number })),
            Just(Request::GetBattery(())),
            Just(Request::GetIdentification(())),
            Just(Request::Land(())),
            Just(Request::GetGnss(())),
            Just(Request::GetCompass(())),
            Just(Request::CompassCalibration(protocol::CompassCalibrationCommand::Finish)),
        ],
    ]
}

proptest! {
    #[test]
    fn every_signed_request_decodes_to_itself_and_verifies_only_in_its_session(
        request in any_request(),
        seq in any::<u16>(),
        key in any::<[u8; protocol::signing::KEY_LEN]>(),
        session in any::<u64>(),
        timestamp in 0..=protocol::signing::MAX_TIMESTAMP,
    ) {
        let signer = protocol::Signer { key, session };
        let mut buffer = [0u8; MAX_FRAME_LEN];
        // The largest requests leave no room for a signature: a typed error, never a panic.
        let Ok(len) = request.encode_signed(seq, &signer, timestamp, &mut buffer) else {
            return Ok(());
        };
        let mut decoder = Decoder::new();
        let mut decoded = None;
        for &byte in &buffer[..len] {
            if let Some(frame) = decoder.push(byte) {
                let frame = frame.expect("a valid frame");
                let signature = frame.signature.expect("signed");
                decoded = Some((
                    Request::decode(&frame),
                    frame.seq,
                    signature.timestamp,
                    signature.verify(&key, session),
                    signature.verify(&key, session.wrapping_add(1)),
                ));
            }
        }
        prop_assert_eq!(decoded, Some((Ok(request), seq, timestamp, true, false)));
    }
}

#[test]
fn the_request_strategy_covers_every_id_in_the_table() {
    use proptest::strategy::ValueTree;
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let mut seen = std::collections::BTreeSet::new();
    for _ in 0..2000 {
        seen.insert(any_request().new_tree(&mut runner).unwrap().current().id());
    }
    let table: std::collections::BTreeSet<u8> = Request::IDS.iter().copied().collect();
    assert_eq!(seen, table, "add the new request to any_request()");
}

/// Any learner sample with finite floats (NaN would not compare equal after the round trip).
fn any_learner() -> impl Strategy<Value = LearnerTelemetry> {
    let float = || -1e9f32..1e9;
    let motors = move || proptest::array::uniform8(float());
    (
        (any::<u64>(), 0usize..7, 0usize..7, any::<u8>(), any::<Option<u8>>(), any::<u16>()),
        (motors(), motors(), any::<u8>(), any::<u8>(), any::<bool>()),
        (proptest::array::uniform4(float()), proptest::array::uniform3(float()), 0u8..2),
        proptest::array::uniform3(motors()),
    )
        .prop_map(|(head, motor, axis, g1_rows)| {
            const PHASES: [LearnerPhase; 7] = [
                LearnerPhase::Idle,
                LearnerPhase::WaitingForThrow,
                LearnerPhase::Throwing,
                LearnerPhase::Released,
                LearnerPhase::Exciting,
                LearnerPhase::Done,
                LearnerPhase::Failed,
            ];
            const FAILURES: [LearnerFailure; 7] = [
                LearnerFailure::None,
                LearnerFailure::NotFreeFall,
                LearnerFailure::ThrowTimedOut,
                LearnerFailure::RankDeficient,
                LearnerFailure::NoHover,
                LearnerFailure::Disarmed,
                LearnerFailure::ImuLost,
            ];
            let (t_us, phase, failure, motor_count, exciting_motor, excitation_ms) = head;
            let (tau_s, omega_max_rad_s, motors_converged, g1_converged, thrust_axis_valid) = motor;
            let (q_thrust_to_imu, euler_zyx_rad, g1_block) = axis;
            LearnerTelemetry {
                t_us,
                phase: PHASES[phase],
                failure: FAILURES[failure],
                motor_count,
                exciting_motor,
                excitation_ms,
                tau_s,
                omega_max_rad_s,
                motors_converged,
                g1_converged,
                thrust_axis_valid,
                q_thrust_to_imu,
                euler_zyx_rad,
                g1_block,
                g1_rows,
            }
        })
}

fn device_round_trip(message: &DeviceMessage, seq: u16) -> Result<DeviceMessage, String> {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    let len = message.encode(seq, &mut buffer).map_err(|e| format!("does not fit: {e:?}"))?;
    let outcome = decode_stream(&buffer[..len]);
    let [Ok((id, got_seq, payload))] = &outcome[..] else { return Err(format!("{outcome:?}")) };
    if *got_seq != seq {
        return Err(format!("seq {got_seq} instead of {seq}"));
    }
    let frame = protocol::Frame { id: *id, seq, payload, signature: None, crc: 0 };
    DeviceMessage::decode(&frame).map_err(|e| format!("{e:?}"))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn every_learner_sample_and_reply_round_trips_in_one_frame(
        learner in any_learner(),
        seq in any::<u16>(),
    ) {
        let telemetry = DeviceMessage::Telemetry(Telemetry::Learner(learner));
        prop_assert_eq!(device_round_trip(&telemetry, seq), Ok(telemetry));
        let reply = DeviceMessage::Response(Ok(Reply::Learner(learner)));
        prop_assert_eq!(device_round_trip(&reply, seq), Ok(reply));
    }

    #[test]
    fn random_bytes_never_panic_and_never_yield_an_unchecked_frame(
        bytes in proptest::collection::vec(any::<u8>(), 0..4096)
    ) {
        // A frame only comes out when its CRC matched; decoding it must give a typed answer
        // either way.
        for (id, seq, payload) in decode_stream(&bytes).into_iter().flatten() {
            let frame = protocol::Frame { id, seq, payload: &payload, signature: None, crc: 0 };
            let _ = Request::decode(&frame);
            let _ = DeviceMessage::decode(&frame);
        }
    }

    #[test]
    fn every_request_round_trips(request in any_request(), seq in any::<u16>()) {
        let bytes = frame_of(&request, seq);
        prop_assert!(bytes.len() <= MAX_FRAME_LEN);
        prop_assert_eq!(bytes.iter().filter(|&&b| b == 0).count(), 1, "only the delimiter is 0x00");
        let outcome = decode_stream(&bytes);
        prop_assert_eq!(outcome.len(), 1);
        let (id, got_seq, payload) = outcome[0].clone().expect("a valid frame decodes");
        prop_assert_eq!(got_seq, seq);
        let frame = protocol::Frame { id, seq, payload: &payload, signature: None, crc: 0 };
        prop_assert_eq!(Request::decode(&frame), Ok(request));
    }

    #[test]
    fn a_single_bit_flip_is_always_detected_and_the_next_frame_survives(
        request in any_request(),
        seq in any::<u16>(),
        flip in any::<prop::sample::Index>(),
        bit in 0u8..8,
    ) {
        let mut corrupted = frame_of(&request, seq);
        let last = corrupted.len() - 1;
        // Flip a bit of the frame body (flipping the delimiter is the truncation case below).
        let position = flip.index(last);
        corrupted[position] ^= 1 << bit;
        let good = frame_of(&Request::GetStatus(()), 7);
        let mut stream = corrupted.clone();
        stream.extend_from_slice(&good);
        let outcome = decode_stream(&stream);
        let oks: Vec<_> = outcome.iter().filter_map(|r| r.as_ref().ok()).collect();
        // The corrupted frame never comes out as a frame; the good one always does.
        prop_assert_eq!(oks.len(), 1, "outcome: {:?}", outcome);
        prop_assert_eq!(oks[0].1, 7);
        prop_assert!(outcome.iter().any(|r| r.is_err()), "the corruption is reported");
    }

    #[test]
    fn a_truncated_frame_costs_at_most_itself_when_the_sender_leads_with_a_delimiter(
        request in any_request(),
        seq in any::<u16>(),
        cut in any::<prop::sample::Index>(),
    ) {
        let whole = frame_of(&request, seq);
        let truncated = &whole[..cut.index(whole.len() - 1)];
        let mut stream = truncated.to_vec();
        stream.push(0); // the next sender's leading delimiter
        stream.extend_from_slice(&frame_of(&Request::GetInfo(()), 9));
        let outcome = decode_stream(&stream);
        let last = outcome.last().expect("the good frame is reported").clone();
        prop_assert_eq!(last.map(|(id, seq, _)| (id, seq)), Ok((0x02, 9)));
        prop_assert!(outcome.len() <= 2);
        if outcome.len() == 2 {
            prop_assert!(outcome[0].is_err(), "a truncated frame is never accepted");
        }
    }

    #[test]
    fn an_oversize_run_is_reported_and_skipped(
        filler in proptest::collection::vec(1u8..=255, MAX_FRAME_LEN..3 * MAX_FRAME_LEN)
    ) {
        let mut stream = filler;
        stream.push(0);
        stream.extend_from_slice(&frame_of(&Request::Ping(Ping { nonce: 5 }), 3));
        let outcome = decode_stream(&stream);
        prop_assert_eq!(outcome.len(), 2);
        prop_assert_eq!(outcome[0].clone(), Err(FrameError::Oversize));
        prop_assert_eq!(outcome[1].clone().map(|(id, seq, _)| (id, seq)), Ok((0x05, 3)));
    }

    #[test]
    fn ids_outside_the_table_are_typed_errors(id in any::<u8>(), seq in any::<u16>()) {
        // The flag bit marks a signed frame, whose last 14 bytes are its signature.
        let id = id & !protocol::signing::SIGNED_FLAG;
        prop_assume!(!Request::IDS.contains(&id));
        let mut buffer = [0u8; MAX_FRAME_LEN];
        let len = encode(id, seq, &(), &mut buffer).unwrap();
        let outcome = decode_stream(&buffer[..len]);
        let (got_id, got_seq, payload) = outcome[0].clone().expect("the frame itself is valid");
        let frame = protocol::Frame { id: got_id, seq: got_seq, payload: &payload, signature: None, crc: 0 };
        prop_assert_eq!(Request::decode(&frame), Err(DecodeError::UnknownId { id }));
    }

    #[test]
    fn payloads_that_do_not_fit_their_id_are_malformed(extra in proptest::collection::vec(any::<u8>(), 1..16)) {
        // GetInfo has an empty payload: any byte after it is malformed, never silently ignored.
        let mut buffer = [0u8; MAX_FRAME_LEN];
        let len = encode(0x02, 1, &extra[..], &mut buffer).unwrap();
        let outcome = decode_stream(&buffer[..len]);
        let (id, seq, payload) = outcome[0].clone().unwrap();
        let frame = protocol::Frame { id, seq, payload: &payload, signature: None, crc: 0 };
        prop_assert_eq!(Request::decode(&frame), Err(DecodeError::Malformed { id: 0x02 }));
    }
}

#[test]
fn a_truncated_frame_without_a_delimiter_swallows_only_the_frame_it_runs_into() {
    let whole = frame_of(&Request::GetStatus(()), 1);
    let mut stream = whole[..whole.len() / 2].to_vec();
    stream.extend_from_slice(&frame_of(&Request::GetInfo(()), 2));
    stream.extend_from_slice(&frame_of(&Request::GetInfo(()), 3));
    let outcome = decode_stream(&stream);
    assert_eq!(outcome.len(), 2, "{outcome:?}");
    assert!(outcome[0].is_err());
    assert_eq!(outcome[1].clone().map(|(id, seq, _)| (id, seq)), Ok((0x02, 3)));
}

#[test]
fn largest_message_fits_the_frame_limit_and_one_byte_more_does_not() {
    use protocol::frame::{CRC_LEN, MAX_RAW_LEN};
    let mut out = [0u8; 2 * MAX_FRAME_LEN];
    let fits = |n: usize, out: &mut [u8]| encode(0x22, 0xFFFF, &vec![0xAAu8; n][..], out);
    let largest = (0..MAX_FRAME_LEN).rev().find(|&n| fits(n, &mut out).is_ok()).unwrap();
    // id 1 + seq 3 (varint of 0xFFFF) + length 2 (varint of ≥ 128) + payload + CRC = raw limit.
    assert_eq!(1 + 3 + 2 + largest + CRC_LEN, MAX_RAW_LEN);
    let len = fits(largest, &mut out).unwrap();
    assert_eq!(len, MAX_FRAME_LEN - 1, "253 raw bytes without zeros: 254 COBS bytes + 0x00");
    let outcome = decode_stream(&out[..len]);
    let Ok((0x22, 0xFFFF, payload)) = &outcome[0] else { panic!("{outcome:?}") };
    assert_eq!(payload.len(), largest + 2);
    assert!(payload[2..].iter().all(|&b| b == 0xAA));
    assert!(fits(largest + 1, &mut out).is_err());
}
