//! Signed requests: who may command the craft over a link that reaches further than a cable.
//!
//! A telemetry radio is heard by anyone on its channel. The board therefore carries out requests
//! that change its configuration, arm it, spin a motor or steer it (which ones: [`crate::access`];
//! see `firmware::app::link`) from an untrusted link (a radio) only when they are signed with a
//! key that was shared over a trusted one (USB: whoever holds the cable holds the craft).
//! Telemetry and read-only requests stay open. MAVLink 2's message signing is the model: a
//! timestamp that must grow, so a recorded frame replayed later fails, and a truncated MAC over
//! the frame.
//!
//! ```text
//! raw (signed) = id | 0x40 | seq (postcard varint) | payload | timestamp: u48 LE | mac: [u8; 8] | crc: u32 LE
//! mac          = HMAC-SHA256(key, session: u64 LE | id | 0x40 | seq | payload | timestamp)[..8]
//! ```
//! - **The flag**: bit 6 of the id byte ([`SIGNED_FLAG`]) marks a signed frame. Request ids stay
//!   below 0x40 and device messages are 0x80–0xBF, so no id has the bit of its own.
//! - **The timestamp** counts 10 µs since 2015-01-01 00:00 UTC (MAVLink's unit and epoch; 48 bits
//!   last 89 years). The board accepts a signed request only when its timestamp is greater than
//!   every one it accepted on the same link since start-up (one sequence per link, as MAVLink
//!   keeps one per stream: two signers on two links never refuse each other's frames in
//!   flight).
//! - **The session** is a number the board draws at start-up (a hardware random number on the
//!   board) and tells any host that asks (`Request::GetLinkSecurity`). It is not sent in the
//!   frame but enters the MAC, so a frame recorded before a restart, whose timestamp the
//!   restarted board would otherwise accept, fails. (MAVLink persists the last timestamp or
//!   reads a GPS clock instead; the board has neither.)
//! - **The MAC** is HMAC-SHA256 (RFC 2104, RustCrypto's `hmac` and `sha2` crates) truncated to
//!   its first 64 bits (MAVLink keeps 48): a forger's chance per try is 2⁻⁶⁴, and every failed
//!   try is counted and reported. The board compares in constant time.
//! - **The key** is 32 random bytes, set over a trusted link (`Request::SetLinkKey`) and stored
//!   in the board's flash beside (not among) the parameters: it is never sent back.
//!
//! The CRC still covers the whole raw frame, so a frame damaged on the air is a CRC error, not a
//! signature failure.

use hmac::{KeyInit, Mac};

/// Bit of the id byte that marks a signed frame.
pub const SIGNED_FLAG: u8 = 0x40;
/// Bytes of a link key.
pub const KEY_LEN: usize = 32;
/// Bytes of the timestamp on the wire (48 bits, as MAVLink's).
pub const TIMESTAMP_LEN: usize = 6;
/// Bytes of the truncated MAC.
pub const MAC_LEN: usize = 8;
/// Bytes a signature adds to a raw frame.
pub const SIGNATURE_LEN: usize = TIMESTAMP_LEN + MAC_LEN;
/// Largest timestamp (48 bits).
pub const MAX_TIMESTAMP: u64 = (1 << 48) - 1;
/// Timestamp units per second: the timestamp counts 10 µs.
pub const TIMESTAMP_TICKS_PER_S: u64 = 100_000;
/// Seconds from the Unix epoch to the timestamp's epoch, 2015-01-01 00:00:00 UTC.
pub const TIMESTAMP_EPOCH_UNIX_S: u64 = 1_420_070_400;

/// A secret shared by the board and the configurators paired with it.
pub type LinkKey = [u8; KEY_LEN];

type HmacSha256 = hmac::Hmac<sha2::Sha256>;

/// The signature part of a received frame, borrowing the decoder's buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signature<'a> {
    /// The sender's timestamp, 10 µs since 2015-01-01 UTC.
    pub timestamp: u64,
    /// The truncated MAC as received.
    pub mac: [u8; MAC_LEN],
    /// The bytes the MAC covers (after the session): flagged id, seq, payload, timestamp.
    pub signed: &'a [u8],
}

impl Signature<'_> {
    /// Whether the MAC is `key`'s over this frame in `session` (compared in constant time).
    pub fn verify(&self, key: &LinkKey, session: u64) -> bool {
        keyed(key, session, self.signed).verify_truncated_left(&self.mac).is_ok()
    }
}

/// What a host needs to sign: the key and the board's session.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Signer {
    pub key: LinkKey,
    pub session: u64,
}

impl core::fmt::Debug for Signer {
    /// Never prints the key.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Signer").field("session", &self.session).finish_non_exhaustive()
    }
}

/// HMAC-SHA256 keyed with `key`, fed `session` and `signed`.
fn keyed(key: &LinkKey, session: u64, signed: &[u8]) -> HmacSha256 {
    // A 32-byte key is always a valid HMAC key (any length is).
    let mut mac = <HmacSha256 as KeyInit>::new_from_slice(key).unwrap_or_else(|_| unreachable!());
    mac.update(&session.to_le_bytes());
    mac.update(signed);
    mac
}

/// The truncated MAC of `signed` under `key` in `session`.
pub fn mac(key: &LinkKey, session: u64, signed: &[u8]) -> [u8; MAC_LEN] {
    let full = keyed(key, session, signed).finalize().into_bytes();
    let mut out = [0; MAC_LEN];
    out.copy_from_slice(&full[..MAC_LEN]);
    out
}

/// Split a CRC-checked raw frame body (`id | seq | payload [| timestamp | mac]`, CRC removed)
/// into the unsigned body and its signature, when the id carries [`SIGNED_FLAG`]. `None` for a
/// signed body too short to hold a signature.
pub(crate) fn split(body: &[u8]) -> Option<(&[u8], Option<Signature<'_>>)> {
    if body.first().is_none_or(|id| id & SIGNED_FLAG == 0) {
        return Some((body, None));
    }
    let unsigned_len = body.len().checked_sub(SIGNATURE_LEN).filter(|&len| len >= 2)?;
    let (signed, mac_bytes) = body.split_at(body.len() - MAC_LEN);
    let mut timestamp = [0u8; 8];
    timestamp[..TIMESTAMP_LEN].copy_from_slice(&signed[unsigned_len..]);
    let mut mac = [0; MAC_LEN];
    mac.copy_from_slice(mac_bytes);
    let signature = Signature { timestamp: u64::from_le_bytes(timestamp), mac, signed };
    Some((&body[..unsigned_len], Some(signature)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mac_is_hmac_sha256_of_the_session_and_the_signed_bytes() {
        // RFC 4231 test case 2 ("Jefe", "what do ya want for nothing?") fixes the primitive;
        // here the same construction through our framing of the input: key, session, bytes.
        let mut key = [0u8; KEY_LEN];
        key[..4].copy_from_slice(b"Jefe");
        let mut reference = <HmacSha256 as KeyInit>::new_from_slice(b"Jefe").unwrap();
        reference.update(b"what do ya want for nothing?");
        let rfc = reference.finalize().into_bytes();
        assert_eq!(rfc[..4], [0x5b, 0xdc, 0xc1, 0x46], "RFC 4231 case 2");
        // A key zero-padded to 32 bytes is the same HMAC key (padded to the block anyway).
        let mut padded = <HmacSha256 as KeyInit>::new_from_slice(&key).unwrap();
        padded.update(b"what do ya want for nothing?");
        assert_eq!(padded.finalize().into_bytes(), rfc);
        let ours = mac(&key, 5, b"abc");
        let mut manual = <HmacSha256 as KeyInit>::new_from_slice(&key).unwrap();
        manual.update(&5u64.to_le_bytes());
        manual.update(b"abc");
        assert_eq!(ours[..], manual.finalize().into_bytes()[..MAC_LEN]);
    }

    #[test]
    fn a_signed_body_too_short_for_its_signature_is_not_a_frame() {
        assert!(split(&[0x0B | SIGNED_FLAG, 1, 2, 3]).is_none());
    }
}
