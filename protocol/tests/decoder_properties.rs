//! Property tests: the decoder accepts any byte stream without panicking, reports typed errors
//! for garbage, bit flips, truncation, oversize frames and unknown ids, and resynchronises at the
//! next delimiter.

use proptest::prelude::*;
use protocol::frame::{encode, MAX_FRAME_LEN};
use protocol::{
    DecodeError, Decoder, DeviceMessage, FrameError, Hello, Ping, Request, SetTelemetryRate, Topic,
    Version,
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
        (0usize..3, any::<u16>()).prop_map(|(topic, rate_hz)| {
            Request::SetTelemetryRate(SetTelemetryRate { topic: Topic::ALL[topic], rate_hz })
        }),
        any::<u32>().prop_map(|nonce| Request::Ping(Ping { nonce })),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic_and_never_yield_an_unchecked_frame(
        bytes in proptest::collection::vec(any::<u8>(), 0..4096)
    ) {
        // A frame only comes out when its CRC matched; decoding it must give a typed answer
        // either way.
        for (id, seq, payload) in decode_stream(&bytes).into_iter().flatten() {
            let frame = protocol::Frame { id, seq, payload: &payload };
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
        let frame = protocol::Frame { id, seq, payload: &payload };
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
        prop_assume!(!Request::IDS.contains(&id));
        let mut buffer = [0u8; MAX_FRAME_LEN];
        let len = encode(id, seq, &(), &mut buffer).unwrap();
        let outcome = decode_stream(&buffer[..len]);
        let (got_id, got_seq, payload) = outcome[0].clone().expect("the frame itself is valid");
        let frame = protocol::Frame { id: got_id, seq: got_seq, payload: &payload };
        prop_assert_eq!(Request::decode(&frame), Err(DecodeError::UnknownId { id }));
    }

    #[test]
    fn payloads_that_do_not_fit_their_id_are_malformed(extra in proptest::collection::vec(any::<u8>(), 1..16)) {
        // GetInfo has an empty payload: any byte after it is malformed, never silently ignored.
        let mut buffer = [0u8; MAX_FRAME_LEN];
        let len = encode(0x02, 1, &extra[..], &mut buffer).unwrap();
        let outcome = decode_stream(&buffer[..len]);
        let (id, seq, payload) = outcome[0].clone().unwrap();
        let frame = protocol::Frame { id, seq, payload: &payload };
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
    let fits = |n: usize, out: &mut [u8]| encode(0x42, 0xFFFF, &vec![0xAAu8; n][..], out);
    let largest = (0..MAX_FRAME_LEN).rev().find(|&n| fits(n, &mut out).is_ok()).unwrap();
    // id 1 + seq 3 (varint of 0xFFFF) + length 2 (varint of ≥ 128) + payload + CRC = raw limit.
    assert_eq!(1 + 3 + 2 + largest + CRC_LEN, MAX_RAW_LEN);
    let len = fits(largest, &mut out).unwrap();
    assert_eq!(len, MAX_FRAME_LEN - 1, "253 raw bytes without zeros: 254 COBS bytes + 0x00");
    let outcome = decode_stream(&out[..len]);
    let Ok((0x42, 0xFFFF, payload)) = &outcome[0] else { panic!("{outcome:?}") };
    assert_eq!(payload.len(), largest + 2);
    assert!(payload[2..].iter().all(|&b| b == 0xAA));
    assert!(fits(largest + 1, &mut out).is_err());
}
