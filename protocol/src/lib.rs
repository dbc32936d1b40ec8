//! Every message that crosses the link between the configurator and the flight controller.
//!
//! - [`messages`]: the one table of message types and ids;
//! - [`access`]: which requests an untrusted link must sign;
//! - [`esc`]: the ESC commands (DShot special commands) a host may send;
//! - [`frame`]: postcard in COBS frames with a CRC-32C, a streaming decoder that never panics;
//! - [`signing`]: requests signed with HMAC-SHA256, for links anyone may hear (a radio);
//! - [`PROTOCOL_VERSION`] and [`SCHEMA_HASH`]: what the handshake compares.
//!
//! `no_std` without allocation; the `std` feature adds `std::error::Error` impls for the host.
//! Behaviour (who answers what) lives in `firmware::app` and the configurator, not here.
#![cfg_attr(not(any(feature = "std", test)), no_std)]

pub mod access;
pub mod esc;
pub mod frame;
pub mod messages;
pub mod signing;
mod table;

pub use access::commands_the_craft;
pub use esc::DshotCommand;
pub use frame::{Decoder, EncodeError, Frame, FrameError, MAX_FRAME_LEN};
pub use messages::*;
pub use signing::{LinkKey, Signer};
pub use table::DecodeError;

/// This protocol's version. Bump the minor for additions an older peer can ignore, the major
/// for anything else (any change to the golden bytes of an existing message).
pub const PROTOCOL_VERSION: Version = Version { major: 1, minor: 17 };

/// Hash of the message table: FNV-1a (64 bit) of `messages.rs` with comments and white space
/// removed. Equal hashes mean both sides were built from the same table.
pub const SCHEMA_HASH: u64 = schema_hash(include_str!("messages.rs"));

/// USB vendor ID of the board's CDC-ACM interface: pid.codes' open-source VID.
pub const USB_VID: u16 = 0x1209;
/// USB product ID: pid.codes' test PID, used until the project is allocated its own.
pub const USB_PID: u16 = 0x0001;

/// `text` as a wire string of capacity `N`, cut at a character boundary when too long (names,
/// units and help texts are built from `&str` on both sides).
pub fn text<const N: usize>(text: &str) -> heapless::String<N> {
    let mut out = heapless::String::new();
    for c in text.chars() {
        if out.push(c).is_err() {
            break;
        }
    }
    out
}

/// FNV-1a over the bytes of `source` that are neither white space nor inside `//` comments.
const fn schema_hash(source: &str) -> u64 {
    const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;
    let bytes = source.as_bytes();
    let mut hash = FNV_OFFSET;
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'/' && i + 1 < bytes.len() && bytes[i + 1] == b'/' {
            while i < bytes.len() && bytes[i] != b'\n' {
                i += 1;
            }
            continue;
        }
        if !bytes[i].is_ascii_whitespace() {
            hash ^= bytes[i] as u64;
            hash = hash.wrapping_mul(FNV_PRIME);
        }
        i += 1;
    }
    hash
}

/// Read the device's protocol version from a handshake reply's payload without decoding the rest,
/// so that a host can name the version of a device whose other types it does not understand.
/// Relies on the frozen layout: `Ok` (0), [`Reply::Hello`] (0), then [`Info::protocol`].
pub fn peek_hello_version(response_payload: &[u8]) -> Option<Version> {
    match response_payload {
        [0, 0, major, minor, ..] => Some(Version { major: *major, minor: *minor }),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schema_hash_ignores_comments_and_white_space_only() {
        let base = schema_hash("struct A { x: u8 }");
        assert_eq!(base, schema_hash("struct  A {\n  // a comment\n  x: u8\n}"));
        assert_ne!(base, schema_hash("struct A { x: u16 }"));
        assert_ne!(base, schema_hash("struct A { y: u8 }"));
    }
}
