//! Framing: how one message becomes bytes on the link, and how a byte stream becomes messages.
//!
//! ```text
//! raw   = id: u8 | seq: u16 (postcard varint) | payload (postcard) | crc: u32 LE
//! raw   = id | 0x40 | seq | payload | timestamp | mac | crc      (a signed request: `signing`)
//! frame = COBS(raw) | 0x00
//! ```
//! The CRC is CRC-32C (Castagnoli, [`crc::CRC_32_ISCSI`]) over `id | seq | payload`: it detects all
//! burst errors up to 32 bits and has Hamming distance 6 for frames of our size. COBS makes 0x00 a
//! reliable frame delimiter, so a decoder that lost sync (garbage, a truncated frame, a reset
//! board) is back in step at the next 0x00.
//!
//! Encoding serialises the message straight into the caller's transmit buffer through postcard's
//! CRC and COBS flavors: no intermediate copy. Decoding accumulates one frame, COBS-decodes it in
//! place, checks the CRC and hands out the payload as a borrowed slice.

use crate::signing::{self, Signature};
use serde::Serialize;

/// Largest encoded frame, bytes on the wire including the 0x00 delimiter. 256 keeps a frame in
/// four USB full-speed CDC packets and bounds every buffer on the board.
pub const MAX_FRAME_LEN: usize = 256;
/// Largest raw frame (before COBS) that always fits [`MAX_FRAME_LEN`]: COBS adds at most one
/// byte per 254 raw bytes plus one, so 253 raw bytes encode in at most 254, plus the delimiter.
/// (A raw frame containing zeros may be slightly longer and still fit; the encoder checks.)
pub const MAX_RAW_LEN: usize = 253;
/// Bytes of the CRC at the end of every raw frame.
pub const CRC_LEN: usize = 4;
/// Smallest raw frame: id (1 byte), seq (at least 1 byte) and the CRC.
pub const MIN_RAW_LEN: usize = 2 + CRC_LEN;

/// The frame CRC: CRC-32C.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// A frame that passed COBS and CRC checks, borrowing the decoder's buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// Message id from the table in `messages.rs`.
    pub id: u8,
    /// Sequence number: the request's for a request and its response, per topic for telemetry.
    pub seq: u16,
    /// The postcard-encoded message body.
    pub payload: &'a [u8],
    /// The signature of a signed request ([`crate::signing`]); `None` for an unsigned frame.
    pub signature: Option<Signature<'a>>,
    /// The frame's CRC-32C as received (and checked): a fingerprint of the whole frame.
    pub crc: u32,
}

/// Why bytes did not make a frame. The decoder has already dropped them and is looking for the
/// next delimiter; nothing else is affected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameError {
    /// More than [`MAX_FRAME_LEN`] bytes without a delimiter; discarded up to the next 0x00.
    Oversize,
    /// The bytes between two delimiters are not valid COBS.
    BadCobs,
    /// Too short to hold an id, a sequence number and a CRC (`len` raw bytes).
    TooShort { len: u16 },
    /// The CRC did not match: a corrupted frame.
    BadCrc { expected: u32, actual: u32 },
    /// The sequence number did not decode.
    BadHeader,
}

/// Why a message could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// The output buffer (or [`MAX_FRAME_LEN`]) is too small for this message.
    BufferFull,
}

/// Encode one message into `out`, returning the number of bytes written (delimiter included).
///
/// At most [`MAX_FRAME_LEN`] bytes of `out` are used; a message that does not fit is an error and
/// leaves `out`'s contents unspecified but nothing else changed.
pub fn encode<T: Serialize + ?Sized>(
    id: u8,
    seq: u16,
    payload: &T,
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    let mut serializer = postcard::Serializer { output: frame_flavor(out)? };
    (id, seq, payload).serialize(&mut serializer).map_err(|_| EncodeError::BufferFull)?;
    finish_frame(serializer.output)
}

/// The flavor [`encode`] writes through: CRC over the bytes, then COBS into the slice.
type FrameFlavor<'a> = postcard::ser_flavors::crc::CrcModifier<
    'static,
    postcard::ser_flavors::Cobs<postcard::ser_flavors::Slice<'a>>,
    u32,
>;

/// [`encode`]'s start and end, the same for every message type: not generic, so that the
/// firmware holds them once rather than once per message type.
#[inline(never)]
fn frame_flavor(out: &mut [u8]) -> Result<FrameFlavor<'_>, EncodeError> {
    let limit = out.len().min(MAX_FRAME_LEN);
    let flavor =
        postcard::ser_flavors::Cobs::try_new(postcard::ser_flavors::Slice::new(&mut out[..limit]))
            .map_err(|_| EncodeError::BufferFull)?;
    Ok(postcard::ser_flavors::crc::CrcModifier::new(flavor, CRC.digest()))
}

/// See [`frame_flavor`].
#[inline(never)]
fn finish_frame(flavor: FrameFlavor<'_>) -> Result<usize, EncodeError> {
    use postcard::ser_flavors::Flavor;
    let written = flavor.finalize().map_err(|_| EncodeError::BufferFull)?;
    Ok(written.len())
}

/// A streaming frame decoder: feed it any bytes, one at a time; it never panics, never allocates,
/// and resynchronises at the next 0x00 after any error.
pub struct Decoder {
    buffer: [u8; MAX_FRAME_LEN],
    len: usize,
    /// Set after an oversize frame: drop bytes until the next delimiter.
    discarding: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub const fn new() -> Self {
        Self { buffer: [0; MAX_FRAME_LEN], len: 0, discarding: false }
    }

    /// Push one byte. Returns a frame or an error when `byte` completes (or overflows) one;
    /// `None` while a frame is still being received, and for empty frames (consecutive 0x00,
    /// which senders may use to flush a receiver).
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame<'_>, FrameError>> {
        if byte != 0 {
            if self.discarding {
                return None;
            }
            if self.len == MAX_FRAME_LEN - 1 {
                self.len = 0;
                self.discarding = true;
                return Some(Err(FrameError::Oversize));
            }
            self.buffer[self.len] = byte;
            self.len += 1;
            return None;
        }
        let encoded_len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.discarding, false) || encoded_len == 0 {
            return None;
        }
        Some(parse(&mut self.buffer[..encoded_len]))
    }
}

/// COBS-decode `encoded` in place, check its CRC and split the header from the payload.
fn parse(encoded: &mut [u8]) -> Result<Frame<'_>, FrameError> {
    let raw_len = cobs::decode_in_place(encoded).map_err(|_| FrameError::BadCobs)?;
    let raw = &encoded[..raw_len];
    if raw_len < MIN_RAW_LEN {
        return Err(FrameError::TooShort { len: raw_len as u16 });
    }
    let (body, crc_bytes) = raw.split_at(raw_len - CRC_LEN);
    let expected = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
    let actual = CRC.checksum(body);
    if expected != actual {
        return Err(FrameError::BadCrc { expected, actual });
    }
    let (body, signature) =
        signing::split(body).ok_or(FrameError::TooShort { len: raw_len as u16 })?;
    let (id, rest) = (body[0] & !signing::SIGNED_FLAG, &body[1..]);
    let (seq, payload) =
        postcard::take_from_bytes::<u16>(rest).map_err(|_| FrameError::BadHeader)?;
    Ok(Frame { id, seq, payload, signature, crc: expected })
}

/// Encode one message as a signed request into `out` (`crate::signing`'s layout), returning
/// the bytes written, delimiter included. `timestamp` above [`signing::MAX_TIMESTAMP`] is cut to 48 bits.
pub fn encode_signed<T: Serialize + ?Sized>(
    id: u8,
    seq: u16,
    payload: &T,
    signer: &signing::Signer,
    timestamp: u64,
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    let mut raw = [0u8; MAX_RAW_LEN];
    let header_and_payload =
        postcard::to_slice(&(id | signing::SIGNED_FLAG, seq, payload), &mut raw)
            .map_err(|_| EncodeError::BufferFull)?
            .len();
    let signed_len = header_and_payload + signing::TIMESTAMP_LEN;
    let raw_len = signed_len + signing::MAC_LEN + CRC_LEN;
    if raw_len > raw.len() {
        return Err(EncodeError::BufferFull);
    }
    raw[header_and_payload..signed_len].copy_from_slice(
        &(timestamp & signing::MAX_TIMESTAMP).to_le_bytes()[..signing::TIMESTAMP_LEN],
    );
    let mac = signing::mac(&signer.key, signer.session, &raw[..signed_len]);
    let mac_end = signed_len + signing::MAC_LEN;
    raw[signed_len..mac_end].copy_from_slice(&mac);
    let crc = CRC.checksum(&raw[..mac_end]);
    raw[mac_end..raw_len].copy_from_slice(&crc.to_le_bytes());
    let limit = out.len().min(MAX_FRAME_LEN);
    if cobs::max_encoding_length(raw_len) + 1 > limit {
        return Err(EncodeError::BufferFull);
    }
    let encoded = cobs::encode(&raw[..raw_len], &mut out[..limit]);
    out[encoded] = 0;
    Ok(encoded + 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signing::{
        mac, LinkKey, Signer, KEY_LEN, SIGNATURE_LEN, SIGNED_FLAG, TIMESTAMP_LEN,
    };

    const KEY: LinkKey = [7; KEY_LEN];
    const SIGNER: Signer = Signer { key: KEY, session: 0x0123_4567_89AB_CDEF };

    fn decode_one(bytes: &[u8]) -> (u8, u16, Vec<u8>, Option<(u64, bool)>) {
        let mut decoder = Decoder::new();
        let mut out = None;
        for &byte in bytes {
            if let Some(result) = decoder.push(byte) {
                let frame = result.expect("a valid frame");
                let signature =
                    frame.signature.map(|s| (s.timestamp, s.verify(&KEY, SIGNER.session)));
                out = Some((frame.id, frame.seq, frame.payload.to_vec(), signature));
            }
        }
        out.expect("one frame")
    }

    #[test]
    fn a_signed_frame_decodes_to_its_message_and_verifies_only_under_its_key_and_session() {
        let mut out = [0u8; MAX_FRAME_LEN];
        let timestamp = 0x0000_1234_5678_9ABC;
        let len = encode_signed(0x0B, 300, &(1.5f32, 7u8), &SIGNER, timestamp, &mut out).unwrap();
        let (id, seq, payload, signature) = decode_one(&out[..len]);
        assert_eq!((id, seq), (0x0B, 300), "the flag is removed from the id");
        assert_eq!(postcard::from_bytes::<(f32, u8)>(&payload).unwrap(), (1.5, 7));
        assert_eq!(signature, Some((timestamp, true)));

        let mut decoder = Decoder::new();
        for &byte in &out[..len - 1] {
            assert!(decoder.push(byte).is_none());
        }
        let frame = decoder.push(0).unwrap().unwrap();
        let signature = frame.signature.unwrap();
        assert!(!signature.verify(&[8; KEY_LEN], SIGNER.session), "another key");
        assert!(!signature.verify(&KEY, SIGNER.session ^ 1), "another session (a restart)");
    }

    #[test]
    fn an_unsigned_frame_has_no_signature_and_a_changed_byte_of_a_signed_one_fails() {
        let mut out = [0u8; MAX_FRAME_LEN];
        let len = encode(0x0B, 3, &42u32, &mut out).unwrap();
        assert_eq!(decode_one(&out[..len]).3, None);

        // Change the payload under a recomputed CRC: the CRC passes, the MAC does not.
        let mut raw = [0u8; MAX_RAW_LEN];
        let n = postcard::to_slice(&(0x0Bu8 | SIGNED_FLAG, 3u16, 42u32), &mut raw).unwrap().len();
        raw[n..n + TIMESTAMP_LEN].copy_from_slice(&[1, 0, 0, 0, 0, 0]);
        let tag = mac(&KEY, SIGNER.session, &raw[..n + TIMESTAMP_LEN]);
        raw[n + TIMESTAMP_LEN..n + SIGNATURE_LEN].copy_from_slice(&tag);
        raw[n - 1] ^= 1; // the payload's last byte
        let crc = CRC.checksum(&raw[..n + SIGNATURE_LEN]);
        raw[n + SIGNATURE_LEN..n + SIGNATURE_LEN + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
        let mut framed = vec![0u8; MAX_FRAME_LEN];
        let m = cobs::encode(&raw[..n + SIGNATURE_LEN + CRC_LEN], &mut framed);
        framed[m] = 0;
        assert_eq!(decode_one(&framed[..=m]).3, Some((1, false)));
    }

    #[test]
    fn a_request_too_long_to_sign_is_refused() {
        let mut out = [0u8; MAX_FRAME_LEN];
        let big = [1u8; 240];
        assert_eq!(
            encode_signed(0x0B, 1, &big[..], &SIGNER, 1, &mut out),
            Err(EncodeError::BufferFull)
        );
    }
}
