//! Who this board is: the STM32's 96-bit unique device ID as text, used as the USB serial number
//! and as the `serial` of the protocol's board info, so a host can tell several boards apart.

use stm32h7xx_hal::signature::Uid;

/// Bytes of the unique device ID (RM0433 rev 8 §61.1, read-only at 0x1FF1_E800).
pub const UID_BYTES: usize = 12;

/// Characters of the ID as text: upper-case hex, two per byte.
pub const UID_HEX_CHARS: usize = 2 * UID_BYTES;

/// Write this chip's unique ID as upper-case hex into `text` and return it as a string.
pub fn uid_hex(text: &mut [u8; UID_HEX_CHARS]) -> &str {
    hex_upper(Uid::read(), text)
}

fn hex_upper<'t>(bytes: &[u8; UID_BYTES], text: &'t mut [u8; UID_HEX_CHARS]) -> &'t str {
    const DIGITS: &[u8; 16] = b"0123456789ABCDEF";
    for (pair, byte) in text.chunks_exact_mut(2).zip(bytes) {
        pair[0] = DIGITS[usize::from(byte >> 4)];
        pair[1] = DIGITS[usize::from(byte & 0x0F)];
    }
    // Only ASCII hex digits were written, so this is valid UTF-8.
    core::str::from_utf8(text).unwrap_or_default()
}
