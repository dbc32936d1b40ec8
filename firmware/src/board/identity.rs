//! Who this board is: the STM32's 96-bit unique device ID as text, used as the USB serial number
//! and as the `serial` of the protocol's board info, so a host can tell several boards apart.

use stm32h7xx_hal::signature::Uid;

/// Bytes of the unique device ID (RM0433 rev 8 §61.1, read-only at 0x1FF1_E800).
pub const UID_BYTES: usize = 12;

/// Characters of the ID as text: upper-case hex, two per byte.
pub const UID_HEX_CHARS: usize = 2 * UID_BYTES;

/// Write this chip's unique ID as upper-case hex into `text` and return it as a string.
pub fn uid_hex(text: &mut heapless::String<UID_HEX_CHARS>) -> &str {
    hex_upper(Uid::read(), text)
}

/// Digits pushed as `&str` pieces (ASCII), so no UTF-8 check is linked (`from_utf8`, 0.5 KB).
fn hex_upper<'t>(
    bytes: &[u8; UID_BYTES],
    text: &'t mut heapless::String<UID_HEX_CHARS>,
) -> &'t str {
    const DIGITS: &str = "0123456789ABCDEF";
    text.clear();
    for byte in bytes {
        for digit in [usize::from(byte >> 4), usize::from(byte & 0x0F)] {
            // Two digits a byte: exactly the capacity, never refused.
            let _ = text.push_str(DIGITS.get(digit..digit + 1).unwrap_or("0"));
        }
    }
    text.as_str()
}
