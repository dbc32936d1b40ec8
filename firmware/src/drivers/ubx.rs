//! u-blox GNSS receivers speaking UBX on a UART: a streaming frame decoder, the NAV-PVT
//! solution in SI units ([`GnssFix`]), the start-up configuration of M8 and M9/M10 receivers,
//! and a [`GnssReceiver`] state machine that finds the receiver's baud rate, configures it and
//! watches its solutions.
//!
//! Why here: the board's UART interrupt (or DMA idle-line handler) only moves bytes and sets the
//! baud rate this module asks for; framing, checksums, configuration and the search are tested
//! on the host against frames built from the documents.
//!
//! # Why our own code and not the `ublox` crate
//!
//! `ublox` 0.10 (`default-features = false`) builds `no_std` without `alloc`, and its NAV-PVT
//! parser with the four M8 builders is small: 3,226 bytes of `.text` in a `no_std` staticlib for
//! `thumbv7em-none-eabihf` at `opt-level = "z"` with LTO (this module, the same job, 1,640). It
//! fell short elsewhere, measured against this module's tests:
//! - its parser waits for whatever length a header claims up to its protocol maximum (the
//!   largest message of protocol 23, over 1,793 bytes): in our test of a frame cut after its
//!   sync pair (`B5 62`, then the next frame read as its header: length `0x0701` = 1,793) the
//!   next NAV-PVT never came out, held until a buffer's worth (we gave it 1 kB: 2 s of NAV-PVT
//!   at 5 Hz) would have arrived; longer lengths it drops without a count, so "oversize" cannot
//!   be reported;
//! - its CFG-VALSET builder writes through `extend_to` into a growable buffer that it indexes
//!   (a sink too short panics), and it cannot encode NAV-PVT, which the simulator needs, so the
//!   layout would be written twice;
//! - it brings `chrono`, `bitflags`, `num-traits` and a procedural-macro crate to the firmware.
//!
//! We need two messages in (NAV-PVT, ACK) and six out (the MON-VER poll, CFG-VALSET and the four
//! legacy CFG messages); the layouts below are u-blox's, the code ours.
//!
//! # What it assumes of the world
//!
//! Protocol facts are from u-blox's documents:
//! - "u-blox 8 / u-blox M8 Receiver description, including protocol specification"
//!   (UBX-13003221), chapter "UBX Protocol": "UBX Frame Structure", "UBX Checksum",
//!   "UBX Payload Definition Rules" (little-endian), and the messages UBX-NAV-PVT,
//!   UBX-ACK-ACK/NAK, UBX-CFG-PRT (UART), UBX-CFG-RATE, UBX-CFG-NAV5, UBX-CFG-MSG, UBX-MON-VER.
//! - "u-blox M10 SPG 5.10 Interface description" (UBX-21035062), chapter "UBX protocol"
//!   (UBX-CFG-VALSET, UBX-NAV-PVT with the same 92-byte layout) and chapter "Configuration
//!   interface" (the key IDs below; the key's size is in bits 28–30 of its ID, "Configuration
//!   items"). The M9 (UBX-19035940, "u-blox M9 SPG 4.04 Interface description") uses the same
//!   keys.
//!
//! A frame is `0xB5 0x62, class, id, length (u16 LE), payload, CK_A, CK_B`, the checksum an 8-bit
//! Fletcher sum over class, id, length and payload. A sync pair can also occur inside a payload
//! or in line noise, so a frame start is only a guess until its checksum matches: when a
//! candidate fails, the decoder drops its first byte and re-reads the bytes after it (it keeps
//! whole frames, up to [`MAX_PAYLOAD_LEN`]), so a truncated frame does not take the good frame
//! after it along. NMEA sentences (ASCII, never `0xB5`) and garbage between frames are skipped
//! and counted.
//!
//! The receiver starts at a baud rate we do not know (factory defaults: 9,600 on the M8, 38,400
//! on the M10; whatever a previous boot set while the receiver kept power). At each rate of
//! [`DETECT_BAUDS`], the target rate first, the state machine polls UBX-MON-VER (a u-blox
//! receiver answers a poll on a port with UBX input, the factory default) and listens for
//! [`SEARCH_WINDOW_S`]; any frame with a good checksum means the rate is right. It then sends
//! both generations' configuration at that rate: first one CFG-VALSET (M9/M10; an M8 does not
//! know it), then CFG-RATE, CFG-NAV5, CFG-MSG and CFG-PRT (M8 and M9; an M10 has none of them),
//! the baud change last in each, so that what follows a receiver's switch reaches it as
//! garbage, which it ignores. It waits for the bytes to leave the UART at that rate (plus
//! [`DRAIN_MARGIN_S`]), moves to the target rate, and takes the first NAV-PVT there as the
//! receiver configured; none within [`CONFIGURE_TIMEOUT_S`] starts the search again. The
//! receiver's generation is not asked (MON-VER's `PROTVER`): which interface acknowledged is
//! recorded ([`Acknowledged`]) for the report.
//!
//! Nothing here blocks, allocates or panics: a silent or garbled receiver is a status
//! ([`GnssStatus::Lost`], [`GnssStatus::Searching`]) and counters, never a fault of the caller.

/// First sync character ("UBX Frame Structure").
pub const SYNC_1: u8 = 0xB5;
/// Second sync character.
pub const SYNC_2: u8 = 0x62;
/// Bytes before the payload: two sync characters, class, id, two length bytes.
pub const HEADER_LEN: usize = 6;
/// Bytes of a frame besides its payload: header and the two checksum bytes.
pub const FRAME_OVERHEAD: usize = HEADER_LEN + 2;
/// Whole frames the decoder keeps, bytes: longer than any message we configure (NAV-PVT 100)
/// and than a MON-VER answer (40 + 30 bytes per extension string, "UBX-MON-VER": 15 of them).
/// It also bounds how long a false sync with a plausible length can hold the frames behind it:
/// 512 bytes, 0.5 s of NAV-PVT at 10 Hz.
pub const FRAME_CAPACITY: usize = 512;
/// Largest payload accepted, bytes; a longer length field is taken for a false sync.
pub const MAX_PAYLOAD_LEN: usize = FRAME_CAPACITY - FRAME_OVERHEAD;

/// Class NAV (navigation results).
pub const CLASS_NAV: u8 = 0x01;
/// Class ACK (acknowledgements of CFG messages).
pub const CLASS_ACK: u8 = 0x05;
/// Class CFG (configuration).
pub const CLASS_CFG: u8 = 0x06;
/// Class MON (monitoring).
pub const CLASS_MON: u8 = 0x0A;
/// UBX-NAV-PVT: navigation position velocity time solution.
pub const ID_NAV_PVT: u8 = 0x07;
/// UBX-ACK-ACK: message acknowledged.
pub const ID_ACK_ACK: u8 = 0x01;
/// UBX-ACK-NAK: message not acknowledged.
pub const ID_ACK_NAK: u8 = 0x00;
/// UBX-CFG-PRT: port configuration.
pub const ID_CFG_PRT: u8 = 0x00;
/// UBX-CFG-MSG: message rate.
pub const ID_CFG_MSG: u8 = 0x01;
/// UBX-CFG-RATE: navigation and measurement rate.
pub const ID_CFG_RATE: u8 = 0x08;
/// UBX-CFG-NAV5: navigation engine settings.
pub const ID_CFG_NAV5: u8 = 0x24;
/// UBX-CFG-VALSET: set configuration values (M9, M10 and later).
pub const ID_CFG_VALSET: u8 = 0x8A;
/// UBX-MON-VER: receiver and software version (polled with an empty payload).
pub const ID_MON_VER: u8 = 0x04;

/// NAV-PVT payload length, bytes (u-blox 8 protocol 15 and later, M9, M10).
pub const NAV_PVT_LEN: usize = 92;
/// A whole NAV-PVT frame, bytes.
pub const NAV_PVT_FRAME_LEN: usize = NAV_PVT_LEN + FRAME_OVERHEAD;
/// NAV-PVT `lat`/`lon` unit, degrees per count (1e-7 deg).
pub const DEG_PER_LAT_LON_COUNT: f64 = 1e-7;
/// NAV-PVT `pDOP` unit (0.01).
pub const DOP_PER_COUNT: f32 = 0.01;
/// NAV-PVT `valid` bit 0: validDate.
const VALID_DATE: u8 = 1 << 0;
/// NAV-PVT `valid` bit 1: validTime.
const VALID_TIME: u8 = 1 << 1;
/// NAV-PVT `valid` bit 2: fullyResolved (UTC time of day fully resolved).
const VALID_FULLY_RESOLVED: u8 = 1 << 2;
/// NAV-PVT `flags` bit 0: gnssFixOK (a valid fix within the DOP and accuracy masks).
const FLAGS_GNSS_FIX_OK: u8 = 1 << 0;
/// NAV-PVT `flags3` bit 0: invalidLlh (lon, lat, height and hMSL invalid).
const FLAGS3_INVALID_LLH: u8 = 1 << 0;

/// CFG-PRT `portID` of UART1 ("UBX-CFG-PRT", port identifier numbers).
pub const PORT_UART1: u8 = 1;
/// CFG-PRT `mode` for 8 data bits, no parity, 1 stop bit: `charLen` = 0b11 (bits 6–7), `parity`
/// = 0b100 (bits 9–11), `nStopBits` = 0 (bits 12–13).
pub const PRT_MODE_8N1: u32 = (0b11 << 6) | (0b100 << 9);
/// CFG-PRT `inProtoMask`/`outProtoMask` bit 0: UBX.
pub const PROTO_UBX: u16 = 1 << 0;
/// CFG-NAV5 `mask` bit 0 (`dyn`): apply the dynamic model only.
pub const NAV5_MASK_DYN: u16 = 1 << 0;
/// CFG-NAV5 `dynModel` / CFG-NAVSPG-DYNMODEL value 8: airborne with < 4 g acceleration.
pub const DYN_MODEL_AIRBORNE_4G: u8 = 8;
/// CFG-RATE `timeRef` 1: measurements aligned to GPS time.
pub const TIME_REF_GPS: u16 = 1;
/// CFG-VALSET `version` 0 (no transaction).
pub const VALSET_VERSION: u8 = 0;
/// CFG-VALSET `layers` bit 0: the RAM layer (lost at power-off: we configure at every start).
pub const LAYER_RAM: u8 = 1 << 0;

/// CFG-UART1-BAUDRATE (U4, baud).
pub const KEY_UART1_BAUDRATE: u32 = 0x4052_0001;
/// CFG-RATE-MEAS (U2, ms): the measurement period.
pub const KEY_RATE_MEAS: u32 = 0x3021_0001;
/// CFG-RATE-NAV (U2): measurements per navigation solution.
pub const KEY_RATE_NAV: u32 = 0x3021_0002;
/// CFG-NAVSPG-DYNMODEL (E1): the dynamic platform model.
pub const KEY_NAVSPG_DYNMODEL: u32 = 0x2011_0021;
/// CFG-MSGOUT-UBX_NAV_PVT_UART1 (U1): NAV-PVT per navigation solution on UART1.
pub const KEY_MSGOUT_UBX_NAV_PVT_UART1: u32 = 0x2091_0007;
/// CFG-UART1INPROT-UBX (L).
pub const KEY_UART1INPROT_UBX: u32 = 0x1073_0001;
/// CFG-UART1INPROT-NMEA (L).
pub const KEY_UART1INPROT_NMEA: u32 = 0x1073_0002;
/// CFG-UART1OUTPROT-UBX (L).
pub const KEY_UART1OUTPROT_UBX: u32 = 0x1074_0001;
/// CFG-UART1OUTPROT-NMEA (L).
pub const KEY_UART1OUTPROT_NMEA: u32 = 0x1074_0002;

/// Baud rates tried, in this order after the target rate (the factory defaults first: 9,600 M8,
/// 38,400 M10; then the rest of what u-blox receivers offer up to 921,600).
pub const DETECT_BAUDS: [u32; 8] =
    [9_600, 38_400, 115_200, 230_400, 57_600, 19_200, 460_800, 921_600];
/// Time listened at each baud rate for an answer, s: a MON-VER answer of about 250 bytes takes
/// 0.26 s at 9,600 baud (10 bits a byte), plus the receiver's own latency.
pub const SEARCH_WINDOW_S: f32 = 0.5;
/// Extra time after the configuration's bytes have left at the detected rate before the UART
/// moves to the target rate, s (for the receiver to take the last message and switch).
pub const DRAIN_MARGIN_S: f32 = 0.05;
/// Time allowed at the target rate for the first NAV-PVT after configuring, s: several
/// navigation periods (at most 0.2 s) plus a receiver's settling after a port change.
pub const CONFIGURE_TIMEOUT_S: f32 = 1.5;
/// No NAV-PVT for this long while receiving means the receiver is lost, s (5 periods at 5 Hz).
pub const LOST_TIMEOUT_S: f32 = 1.0;
/// Lost for this long starts the baud search again, s (the receiver may have restarted at its
/// factory rate).
pub const LOST_RESEARCH_S: f32 = 3.0;
/// Bits on the line per byte: start, 8 data, 1 stop (8N1).
const BITS_PER_BYTE: f32 = 10.0;

/// Configuration bytes the receiver queues at most (both generations' sequences and a poll).
pub const TX_CAPACITY: usize = 256;

/// The 8-bit Fletcher checksum (CK_A, CK_B) over `bytes` ("UBX Checksum"): for each byte,
/// `CK_A += byte; CK_B += CK_A`, modulo 256.
pub fn checksum(bytes: &[u8]) -> (u8, u8) {
    bytes.iter().fold((0u8, 0u8), |(a, b), &byte| {
        let a = a.wrapping_add(byte);
        (a, b.wrapping_add(a))
    })
}

/// Encode one frame into `out`: sync, `class`, `id`, length, `payload`, checksum. Returns the
/// bytes written, or `None` when `out` is too small or the payload longer than a frame holds.
pub fn encode_frame(class: u8, id: u8, payload: &[u8], out: &mut [u8]) -> Option<usize> {
    let len = payload.len();
    let length = u16::try_from(len).ok()?;
    let frame = out.get_mut(..len + FRAME_OVERHEAD)?;
    let [l0, l1] = length.to_le_bytes();
    frame[..HEADER_LEN].copy_from_slice(&[SYNC_1, SYNC_2, class, id, l0, l1]);
    frame[HEADER_LEN..HEADER_LEN + len].copy_from_slice(payload);
    let (a, b) = checksum(&frame[2..HEADER_LEN + len]);
    frame[HEADER_LEN + len] = a;
    frame[HEADER_LEN + len + 1] = b;
    Some(len + FRAME_OVERHEAD)
}

/// One frame whose checksum matched.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    pub class: u8,
    pub id: u8,
    pub payload: &'a [u8],
}

/// What a frame means to us.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    /// UBX-NAV-PVT.
    NavPvt(GnssFix),
    /// UBX-ACK-ACK for the message `class`, `id`.
    Ack { class: u8, id: u8 },
    /// UBX-ACK-NAK for the message `class`, `id`.
    Nak { class: u8, id: u8 },
    /// Any other frame (or one of ours with an unexpected length), checked and skipped.
    Other { class: u8, id: u8 },
}

impl Message {
    /// Interpret a checked frame.
    pub fn parse(frame: &Frame<'_>) -> Self {
        match (frame.class, frame.id, frame.payload) {
            (CLASS_NAV, ID_NAV_PVT, payload) if payload.len() == NAV_PVT_LEN => {
                Self::NavPvt(GnssFix::from_payload(payload))
            }
            (CLASS_ACK, ID_ACK_ACK, &[class, id]) => Self::Ack { class, id },
            (CLASS_ACK, ID_ACK_NAK, &[class, id]) => Self::Nak { class, id },
            (class, id, _) => Self::Other { class, id },
        }
    }
}

/// What the decoder has seen since it was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Frames whose checksum matched.
    pub frames: u32,
    /// Candidate frames whose checksum did not match (dropped).
    pub checksum_errors: u32,
    /// Candidate frames whose length exceeded [`MAX_PAYLOAD_LEN`] (dropped).
    pub oversize: u32,
    /// Bytes outside frames: NMEA, noise, bytes of failed candidates.
    pub skipped_bytes: u32,
}

/// Streaming UBX frame decoder: bytes in any chunking, frames out in order.
#[derive(Clone, Debug)]
pub struct Decoder {
    buffer: [u8; FRAME_CAPACITY],
    len: usize,
    stats: DecoderStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

/// The state of the bytes held.
enum Candidate {
    /// A frame may still complete.
    Partial,
    /// A frame with a good checksum of this many bytes starts the buffer.
    Complete(usize),
    /// Not a frame: the second byte is not the sync character.
    NotSync,
    /// Length field over [`MAX_PAYLOAD_LEN`].
    Oversize,
    /// Complete, wrong checksum.
    BadChecksum,
}

impl Decoder {
    pub const fn new() -> Self {
        Self {
            buffer: [0; FRAME_CAPACITY],
            len: 0,
            stats: DecoderStats { frames: 0, checksum_errors: 0, oversize: 0, skipped_bytes: 0 },
        }
    }

    /// Counters since construction.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Forget a partial frame (after a baud change: its bytes came at the old rate).
    pub fn reset(&mut self) {
        self.stats.skipped_bytes = self.stats.skipped_bytes.saturating_add(self.len as u32);
        self.len = 0;
    }

    /// Feed `bytes`; `on_frame` is called for every frame whose checksum matches, in order.
    pub fn feed(&mut self, bytes: &[u8], mut on_frame: impl FnMut(Frame<'_>)) {
        for &byte in bytes {
            self.push(byte, &mut on_frame);
        }
    }

    /// Feed one byte (see [`Decoder::feed`]).
    pub fn push(&mut self, byte: u8, on_frame: &mut impl FnMut(Frame<'_>)) {
        if self.len == 0 && byte != SYNC_1 {
            self.stats.skipped_bytes = self.stats.skipped_bytes.saturating_add(1);
            return;
        }
        // `len` never exceeds a complete candidate (at most FRAME_CAPACITY), and a complete
        // candidate is always consumed below, so there is room.
        let Some(slot) = self.buffer.get_mut(self.len) else {
            self.reset();
            return;
        };
        *slot = byte;
        self.len += 1;
        loop {
            match self.candidate() {
                Candidate::Partial => return,
                Candidate::Complete(total) => {
                    self.stats.frames = self.stats.frames.saturating_add(1);
                    let length = total - FRAME_OVERHEAD;
                    on_frame(Frame {
                        class: self.buffer[2],
                        id: self.buffer[3],
                        payload: &self.buffer[HEADER_LEN..HEADER_LEN + length],
                    });
                    self.consume(total, false);
                }
                Candidate::NotSync => self.consume(1, true),
                Candidate::Oversize => {
                    self.stats.oversize = self.stats.oversize.saturating_add(1);
                    self.consume(1, true);
                }
                Candidate::BadChecksum => {
                    self.stats.checksum_errors = self.stats.checksum_errors.saturating_add(1);
                    self.consume(1, true);
                }
            }
            if self.len == 0 {
                return;
            }
        }
    }

    fn candidate(&self) -> Candidate {
        let held = &self.buffer[..self.len];
        if held.len() < 2 {
            return Candidate::Partial;
        }
        if held[1] != SYNC_2 {
            return Candidate::NotSync;
        }
        if held.len() < HEADER_LEN {
            return Candidate::Partial;
        }
        let length = usize::from(u16::from_le_bytes([held[4], held[5]]));
        if length > MAX_PAYLOAD_LEN {
            return Candidate::Oversize;
        }
        let total = length + FRAME_OVERHEAD;
        if held.len() < total {
            return Candidate::Partial;
        }
        let (a, b) = checksum(&held[2..HEADER_LEN + length]);
        if (a, b) == (held[HEADER_LEN + length], held[HEADER_LEN + length + 1]) {
            Candidate::Complete(total)
        } else {
            Candidate::BadChecksum
        }
    }

    /// Drop the first `count` bytes and any that follow up to the next [`SYNC_1`]; `skipped`
    /// counts the dropped ones as outside frames.
    fn consume(&mut self, count: usize, skipped: bool) {
        let start = self.buffer[count.min(self.len)..self.len]
            .iter()
            .position(|&b| b == SYNC_1)
            .map_or(self.len, |p| p + count.min(self.len));
        let dropped_outside = if skipped { start } else { start - count.min(start) };
        self.stats.skipped_bytes = self.stats.skipped_bytes.saturating_add(dropped_outside as u32);
        self.buffer.copy_within(start..self.len, 0);
        self.len -= start;
    }
}

/// NAV-PVT `fixType`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FixType {
    /// 0: no fix.
    NoFix,
    /// 1: dead reckoning only.
    DeadReckoning,
    /// 2: 2D fix.
    Fix2d,
    /// 3: 3D fix.
    Fix3d,
    /// 4: GNSS and dead reckoning combined.
    GnssDeadReckoning,
    /// 5: time only.
    TimeOnly,
    /// A value the documents do not define.
    Unknown(u8),
}

impl FixType {
    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0 => Self::NoFix,
            1 => Self::DeadReckoning,
            2 => Self::Fix2d,
            3 => Self::Fix3d,
            4 => Self::GnssDeadReckoning,
            5 => Self::TimeOnly,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            Self::NoFix => 0,
            Self::DeadReckoning => 1,
            Self::Fix2d => 2,
            Self::Fix3d => 3,
            Self::GnssDeadReckoning => 4,
            Self::TimeOnly => 5,
            Self::Unknown(raw) => raw,
        }
    }
}

/// One navigation solution (UBX-NAV-PVT) in SI units. Heading, date and time of day are not
/// kept (the solution's time is its GPS time of week).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GnssFix {
    /// `iTOW`: GPS time of week of the navigation epoch, ms.
    pub time_of_week_ms: u32,
    /// `valid.validDate`: the UTC date is valid.
    pub date_valid: bool,
    /// `valid.validTime`: the UTC time of day is valid.
    pub time_valid: bool,
    /// `valid.fullyResolved`: the UTC time of day has no seconds uncertainty.
    pub time_fully_resolved: bool,
    /// `fixType`.
    pub fix_type: FixType,
    /// `flags.gnssFixOK`: a valid fix (within the receiver's DOP and accuracy masks).
    pub gnss_fix_ok: bool,
    /// `flags3.invalidLlh`: latitude, longitude and heights are invalid.
    pub position_invalid: bool,
    /// `numSV`: satellites used in the solution.
    pub satellites: u8,
    /// `lat`, degrees (WGS-84).
    pub latitude_deg: f64,
    /// `lon`, degrees (WGS-84).
    pub longitude_deg: f64,
    /// `height`: above the WGS-84 ellipsoid, m.
    pub height_ellipsoid_m: f32,
    /// `hMSL`: above mean sea level, m.
    pub height_msl_m: f32,
    /// `hAcc`: horizontal accuracy estimate, m.
    pub horizontal_accuracy_m: f32,
    /// `vAcc`: vertical accuracy estimate, m.
    pub vertical_accuracy_m: f32,
    /// `velN`, `velE`, `velD`: velocity north, east, down, m/s.
    pub velocity_ned_mps: [f32; 3],
    /// `sAcc`: speed accuracy estimate, m/s.
    pub speed_accuracy_mps: f32,
    /// `pDOP`: position dilution of precision.
    pub position_dop: f32,
}

/// Millimetres (the frame's unit of lengths and speeds) per metre.
const MM_PER_M: f32 = 1000.0;
/// The same in the encoder's direction, m per mm.
const M_PER_MM: f64 = 1e-3;

fn u16_at(p: &[u8], at: usize) -> u16 {
    p.get(at..at + 2).and_then(|s| s.try_into().ok()).map_or(0, u16::from_le_bytes)
}
fn u32_at(p: &[u8], at: usize) -> u32 {
    p.get(at..at + 4).and_then(|s| s.try_into().ok()).map_or(0, u32::from_le_bytes)
}
fn i32_at(p: &[u8], at: usize) -> i32 {
    u32_at(p, at) as i32
}
fn u8_at(p: &[u8], at: usize) -> u8 {
    p.get(at).copied().unwrap_or(0)
}
/// SI value → the frame's integer, rounded and saturated.
fn to_count(value: f64, per_count: f64) -> i32 {
    let counts = value / per_count;
    if counts.is_nan() {
        0
    } else {
        // `as` saturates; round half away from zero.
        (if counts >= 0.0 { counts + 0.5 } else { counts - 0.5 }) as i32
    }
}
fn to_unsigned_count(value: f64, per_count: f64) -> u32 {
    to_count(value, per_count).max(0) as u32
}

impl GnssFix {
    /// Decode a NAV-PVT payload (fields at their documented byte offsets; a short payload reads
    /// as zeros, but [`Message::parse`] only passes whole ones).
    pub fn from_payload(p: &[u8]) -> Self {
        let valid = u8_at(p, 11);
        let flags = u8_at(p, 21);
        let mm = |at| i32_at(p, at) as f32 / MM_PER_M;
        let umm = |at| u32_at(p, at) as f32 / MM_PER_M;
        Self {
            time_of_week_ms: u32_at(p, 0),
            date_valid: valid & VALID_DATE != 0,
            time_valid: valid & VALID_TIME != 0,
            time_fully_resolved: valid & VALID_FULLY_RESOLVED != 0,
            fix_type: FixType::from_raw(u8_at(p, 20)),
            gnss_fix_ok: flags & FLAGS_GNSS_FIX_OK != 0,
            position_invalid: u16_at(p, 78) & u16::from(FLAGS3_INVALID_LLH) != 0,
            satellites: u8_at(p, 23),
            longitude_deg: f64::from(i32_at(p, 24)) * DEG_PER_LAT_LON_COUNT,
            latitude_deg: f64::from(i32_at(p, 28)) * DEG_PER_LAT_LON_COUNT,
            height_ellipsoid_m: mm(32),
            height_msl_m: mm(36),
            horizontal_accuracy_m: umm(40),
            vertical_accuracy_m: umm(44),
            velocity_ned_mps: [mm(48), mm(52), mm(56)],
            speed_accuracy_mps: umm(68),
            position_dop: f32::from(u16_at(p, 76)) * DOP_PER_COUNT,
        }
    }

    /// Whether the solution is a 3D position to navigate by: `gnssFixOK`, a 3D (or GNSS + dead
    /// reckoning) fix, and a valid position.
    pub fn has_3d_fix(&self) -> bool {
        self.gnss_fix_ok
            && matches!(self.fix_type, FixType::Fix3d | FixType::GnssDeadReckoning)
            && !self.position_invalid
    }

    /// Encode as a NAV-PVT payload (the inverse of [`GnssFix::from_payload`], rounded to the
    /// frame's units; fields this type does not keep are zero). What a receiver sends: the
    /// simulator's GNSS uses it.
    pub fn to_payload(&self) -> [u8; NAV_PVT_LEN] {
        let mut p = [0u8; NAV_PVT_LEN];
        let mut put = |at: usize, bytes: &[u8]| p[at..at + bytes.len()].copy_from_slice(bytes);
        let mm = |m: f32| to_count(f64::from(m), M_PER_MM).to_le_bytes();
        let umm = |m: f32| to_unsigned_count(f64::from(m), M_PER_MM).to_le_bytes();
        put(0, &self.time_of_week_ms.to_le_bytes());
        let valid = (u8::from(self.date_valid) * VALID_DATE)
            | (u8::from(self.time_valid) * VALID_TIME)
            | (u8::from(self.time_fully_resolved) * VALID_FULLY_RESOLVED);
        put(11, &[valid]);
        put(
            20,
            &[
                self.fix_type.raw(),
                u8::from(self.gnss_fix_ok) * FLAGS_GNSS_FIX_OK,
                0,
                self.satellites,
            ],
        );
        put(24, &to_count(self.longitude_deg, DEG_PER_LAT_LON_COUNT).to_le_bytes());
        put(28, &to_count(self.latitude_deg, DEG_PER_LAT_LON_COUNT).to_le_bytes());
        put(32, &mm(self.height_ellipsoid_m));
        put(36, &mm(self.height_msl_m));
        put(40, &umm(self.horizontal_accuracy_m));
        put(44, &umm(self.vertical_accuracy_m));
        put(48, &mm(self.velocity_ned_mps[0]));
        put(52, &mm(self.velocity_ned_mps[1]));
        put(56, &mm(self.velocity_ned_mps[2]));
        let [n, e] = [self.velocity_ned_mps[0], self.velocity_ned_mps[1]];
        put(60, &mm(libm::sqrtf(n * n + e * e)));
        put(68, &umm(self.speed_accuracy_mps));
        let pdop = to_unsigned_count(f64::from(self.position_dop), f64::from(DOP_PER_COUNT));
        put(76, &(pdop.min(u32::from(u16::MAX)) as u16).to_le_bytes());
        put(78, &u16::from(u8::from(self.position_invalid) * FLAGS3_INVALID_LLH).to_le_bytes());
        p
    }

    /// The whole NAV-PVT frame of [`GnssFix::to_payload`].
    pub fn to_frame(&self) -> [u8; NAV_PVT_FRAME_LEN] {
        let mut frame = [0u8; NAV_PVT_FRAME_LEN];
        // The array is exactly one NAV-PVT frame long: always fits.
        let _ = encode_frame(CLASS_NAV, ID_NAV_PVT, &self.to_payload(), &mut frame);
        frame
    }
}

/// What the receiver is configured to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GnssConfig {
    /// The UART's rate once configured, baud (NAV-PVT, 100 bytes, at 10 Hz needs 10,000).
    pub target_baud: u32,
    /// Time between navigation solutions, s: 0.1 (10 Hz) or 0.2 (5 Hz); sent in whole ms.
    pub measurement_period_s: f32,
}

/// The UART's rate once configured by default, baud: NAV-PVT at 10 Hz needs 10,000, and 115,200
/// is a rate every u-blox receiver and flight-controller UART runs reliably.
pub const DEFAULT_TARGET_BAUD: u32 = 115_200;

impl Default for GnssConfig {
    /// 115,200 baud, 5 Hz (every M8/M9/M10 reaches 5 Hz with all its constellations).
    fn default() -> Self {
        Self { target_baud: DEFAULT_TARGET_BAUD, measurement_period_s: 0.2 }
    }
}

impl GnssConfig {
    /// The measurement period in the receiver's unit, ms (at least 25, the fastest u-blox rate).
    pub fn measurement_period_ms(&self) -> u16 {
        let ms = libm::roundf(self.measurement_period_s * 1000.0);
        if ms.is_nan() {
            200
        } else {
            ms.clamp(25.0, f32::from(u16::MAX)) as u16
        }
    }
}

/// Append a frame to `out` at `*at`; `None` when it does not fit.
fn append(out: &mut [u8], at: &mut usize, class: u8, id: u8, payload: &[u8]) -> Option<()> {
    *at += encode_frame(class, id, payload, out.get_mut(*at..)?)?;
    Some(())
}

/// The M8 sequence (legacy CFG messages), written to `out`; returns its length. In order:
/// CFG-RATE (`measRate`, `navRate` 1, `timeRef` GPS), CFG-NAV5 (only `dynModel`: airborne
/// < 4 g), CFG-MSG (NAV-PVT every solution on UART1, off on the other ports), and last CFG-PRT
/// (UART1: 8N1 at the target baud, UBX only in and out), whose baud change makes anything after
/// it unreadable to the receiver.
pub fn m8_configuration(config: &GnssConfig, out: &mut [u8]) -> Option<usize> {
    let mut at = 0;
    let [r0, r1] = config.measurement_period_ms().to_le_bytes();
    let [t0, t1] = TIME_REF_GPS.to_le_bytes();
    append(out, &mut at, CLASS_CFG, ID_CFG_RATE, &[r0, r1, 1, 0, t0, t1])?;
    let mut nav5 = [0u8; 36];
    nav5[..2].copy_from_slice(&NAV5_MASK_DYN.to_le_bytes());
    nav5[2] = DYN_MODEL_AIRBORNE_4G;
    append(out, &mut at, CLASS_CFG, ID_CFG_NAV5, &nav5)?;
    // msgClass, msgID, then the rate on I2C (DDC), UART1, UART2, USB, SPI, reserved port.
    append(out, &mut at, CLASS_CFG, ID_CFG_MSG, &[CLASS_NAV, ID_NAV_PVT, 0, 1, 0, 0, 0, 0])?;
    let mut prt = [0u8; 20];
    prt[0] = PORT_UART1;
    prt[4..8].copy_from_slice(&PRT_MODE_8N1.to_le_bytes());
    prt[8..12].copy_from_slice(&config.target_baud.to_le_bytes());
    prt[12..14].copy_from_slice(&PROTO_UBX.to_le_bytes());
    prt[14..16].copy_from_slice(&PROTO_UBX.to_le_bytes());
    append(out, &mut at, CLASS_CFG, ID_CFG_PRT, &prt)?;
    Some(at)
}

/// Bytes of a configuration value for a key: bits 28–30 of the key ID ("Configuration items":
/// 1 = one bit, stored in a byte; 2 = one byte; 3 = two; 4 = four; 5 = eight).
pub fn key_value_len(key: u32) -> usize {
    match (key >> 28) & 0b111 {
        1 | 2 => 1,
        3 => 2,
        4 => 4,
        _ => 8,
    }
}

/// The M9/M10 sequence: one CFG-VALSET to the RAM layer with UART1 at the target baud,
/// UBX only in and out, the measurement period (one measurement per solution), the airborne
/// < 4 g model and NAV-PVT every solution on UART1. One message, so the receiver applies it
/// whole, baud change included.
pub fn m10_configuration(config: &GnssConfig, out: &mut [u8]) -> Option<usize> {
    let values: [(u32, u32); 9] = [
        (KEY_UART1INPROT_UBX, 1),
        (KEY_UART1INPROT_NMEA, 0),
        (KEY_UART1OUTPROT_UBX, 1),
        (KEY_UART1OUTPROT_NMEA, 0),
        (KEY_RATE_MEAS, u32::from(config.measurement_period_ms())),
        (KEY_RATE_NAV, 1),
        (KEY_NAVSPG_DYNMODEL, u32::from(DYN_MODEL_AIRBORNE_4G)),
        (KEY_MSGOUT_UBX_NAV_PVT_UART1, 1),
        (KEY_UART1_BAUDRATE, config.target_baud),
    ];
    let mut payload = [0u8; 4 + 9 * 8];
    payload[..4].copy_from_slice(&[VALSET_VERSION, LAYER_RAM, 0, 0]);
    let mut len = 4;
    for (key, value) in values {
        let size = key_value_len(key);
        let item = payload.get_mut(len..len + 4 + size)?;
        item[..4].copy_from_slice(&key.to_le_bytes());
        item[4..].copy_from_slice(&u64::from(value).to_le_bytes()[..size]);
        len += 4 + size;
    }
    let mut at = 0;
    append(out, &mut at, CLASS_CFG, ID_CFG_VALSET, &payload[..len])?;
    Some(at)
}

/// Both generations' sequences, the M9/M10 one first (an M9 takes either; the first baud change
/// garbles the rest, which it ignores); returns the length.
pub fn configuration(config: &GnssConfig, out: &mut [u8]) -> Option<usize> {
    let first = m10_configuration(config, out)?;
    Some(first + m8_configuration(config, out.get_mut(first..)?)?)
}

/// The receiver as the application sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GnssStatus {
    /// Listening at `baud` for any UBX frame (after polling MON-VER).
    Searching { baud: u32 },
    /// Found at `baud`: configuration sent, waiting for NAV-PVT at the target rate.
    Configuring { baud: u32 },
    /// NAV-PVT arriving; `fix` is the newest (its own fields say whether it is a usable fix).
    Receiving { fix: GnssFix },
    /// Was receiving, no NAV-PVT for [`LOST_TIMEOUT_S`].
    Lost,
}

/// What the board does after a [`GnssReceiver::poll`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GnssOutput<'a> {
    /// The rate the UART should run at from now on, baud: set it first (when it differs)...
    pub baud: u32,
    /// ...then queue these bytes (and report how many it took with [`GnssReceiver::sent`]).
    pub write: &'a [u8],
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    Start,
    Searching {
        index: usize,
        since_us: u64,
    },
    /// Configuration queued at `baud` at `since_us`; `sent_us` once the UART took the last byte.
    Configuring {
        baud: u32,
        bytes: usize,
        since_us: u64,
        sent_us: Option<u64>,
    },
    AwaitingFix {
        since_us: u64,
    },
    Receiving {
        last_us: u64,
    },
    Lost {
        since_us: u64,
    },
}

/// Which configuration interface acknowledged our messages.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Acknowledged {
    /// CFG-VALSET acknowledged: an M9/M10 (or later) receiver.
    pub valset: bool,
    /// A legacy CFG message (RATE, NAV5, MSG, PRT) acknowledged: an M8 (or an M9).
    pub legacy: bool,
    /// Negative acknowledgements of any of ours.
    pub naks: u32,
}

/// The GNSS receiver's state machine: detect the baud, configure, watch NAV-PVT. Driven by
/// [`GnssReceiver::poll`] from the board's UART handling; never blocks.
#[derive(Clone, Debug)]
pub struct GnssReceiver {
    config: GnssConfig,
    decoder: Decoder,
    phase: Phase,
    fix: Option<GnssFix>,
    tx: [u8; TX_CAPACITY],
    tx_start: usize,
    tx_end: usize,
    acknowledged: Acknowledged,
    /// Times the search found the receiver and configuration was sent.
    configure_attempts: u32,
}

/// Seconds from `since_us` to `now_us` (0 if the clock went back).
fn elapsed_s(now_us: u64, since_us: u64) -> f32 {
    now_us.saturating_sub(since_us) as f32 * 1e-6
}

impl GnssReceiver {
    pub fn new(config: GnssConfig) -> Self {
        Self {
            config,
            decoder: Decoder::new(),
            phase: Phase::Start,
            fix: None,
            tx: [0; TX_CAPACITY],
            tx_start: 0,
            tx_end: 0,
            acknowledged: Acknowledged::default(),
            configure_attempts: 0,
        }
    }

    /// The rate at search step `index`: the target first, then [`DETECT_BAUDS`] without it.
    fn search_baud(&self, index: usize) -> u32 {
        let target = self.config.target_baud;
        if index == 0 {
            return target;
        }
        DETECT_BAUDS.iter().copied().filter(|&b| b != target).nth(index - 1).unwrap_or(target)
    }

    fn search_len(&self) -> usize {
        1 + DETECT_BAUDS.iter().filter(|&&b| b != self.config.target_baud).count()
    }

    /// The rate the UART should run at now.
    pub fn baud(&self) -> u32 {
        match self.phase {
            Phase::Searching { index, .. } => self.search_baud(index),
            Phase::Configuring { baud, .. } => baud,
            Phase::Start
            | Phase::AwaitingFix { .. }
            | Phase::Receiving { .. }
            | Phase::Lost { .. } => self.config.target_baud,
        }
    }

    /// What the application reports.
    pub fn status(&self) -> GnssStatus {
        match (self.phase, self.fix) {
            (Phase::Start, _) => GnssStatus::Searching { baud: self.config.target_baud },
            (Phase::Searching { index, .. }, _) => {
                GnssStatus::Searching { baud: self.search_baud(index) }
            }
            (Phase::Configuring { baud, .. }, _) => GnssStatus::Configuring { baud },
            (Phase::AwaitingFix { .. }, _) => {
                GnssStatus::Configuring { baud: self.config.target_baud }
            }
            (Phase::Receiving { .. }, Some(fix)) => GnssStatus::Receiving { fix },
            (Phase::Receiving { .. }, None) | (Phase::Lost { .. }, _) => GnssStatus::Lost,
        }
    }

    /// The decoder's counters.
    pub fn decoder_stats(&self) -> DecoderStats {
        self.decoder.stats()
    }

    /// Which configuration interface answered.
    pub fn acknowledged(&self) -> Acknowledged {
        self.acknowledged
    }

    /// Times the receiver was found and configured (more than one: it was lost and found again,
    /// or a configuration did not take).
    pub fn configure_attempts(&self) -> u32 {
        self.configure_attempts
    }

    /// The UART took `count` of the bytes [`GnssReceiver::poll`] offered.
    pub fn sent(&mut self, count: usize) {
        self.tx_start = self.tx_start.saturating_add(count).min(self.tx_end);
    }

    fn queue(&mut self, build: impl FnOnce(&mut [u8]) -> Option<usize>) {
        self.tx_start = 0;
        self.tx_end = build(&mut self.tx).unwrap_or(0);
    }

    fn start_search(&mut self, index: usize, now_us: u64) {
        self.phase = Phase::Searching { index, since_us: now_us };
        self.decoder.reset();
        // Poll MON-VER: an empty payload asks for the message.
        self.queue(|out| encode_frame(CLASS_MON, ID_MON_VER, &[], out));
    }

    /// Take the bytes received since the last call at [`GnssReceiver::baud`] and the time (µs,
    /// monotonic); returns what to write and the rate the UART should run at.
    pub fn poll(&mut self, bytes_in: &[u8], now_us: u64) -> GnssOutput<'_> {
        if self.phase == Phase::Start {
            self.start_search(0, now_us);
        }
        let mut any_frame = false;
        let mut newest: Option<GnssFix> = None;
        let mut acknowledged = self.acknowledged;
        self.decoder.feed(bytes_in, |frame| {
            any_frame = true;
            match Message::parse(&frame) {
                Message::NavPvt(fix) => newest = Some(fix),
                Message::Ack { class: CLASS_CFG, id: ID_CFG_VALSET } => acknowledged.valset = true,
                Message::Ack {
                    class: CLASS_CFG,
                    id: ID_CFG_RATE | ID_CFG_NAV5 | ID_CFG_MSG | ID_CFG_PRT,
                } => acknowledged.legacy = true,
                Message::Nak { class: CLASS_CFG, .. } => {
                    acknowledged.naks = acknowledged.naks.saturating_add(1)
                }
                _ => {}
            }
        });
        self.acknowledged = acknowledged;
        if let Some(fix) = newest {
            self.fix = Some(fix);
        }
        self.step(any_frame, newest.is_some(), now_us);
        self.output()
    }

    /// What [`GnssReceiver::poll`] last asked for and is still unsent: the rate the UART should
    /// run at and the bytes to queue.
    pub fn output(&self) -> GnssOutput<'_> {
        GnssOutput { write: &self.tx[self.tx_start..self.tx_end], baud: self.baud() }
    }

    fn step(&mut self, any_frame: bool, new_fix: bool, now_us: u64) {
        match self.phase {
            Phase::Start => self.start_search(0, now_us),
            Phase::Searching { index, since_us } => {
                if any_frame {
                    let baud = self.search_baud(index);
                    let config = self.config;
                    self.queue(|out| configuration(&config, out));
                    self.configure_attempts = self.configure_attempts.saturating_add(1);
                    self.phase = Phase::Configuring {
                        baud,
                        bytes: self.tx_end,
                        since_us: now_us,
                        sent_us: None,
                    };
                } else if elapsed_s(now_us, since_us) >= SEARCH_WINDOW_S {
                    self.start_search((index + 1) % self.search_len(), now_us);
                }
            }
            Phase::Configuring { baud, bytes, since_us, sent_us } => match sent_us {
                None if self.tx_start >= self.tx_end => {
                    self.phase =
                        Phase::Configuring { baud, bytes, since_us, sent_us: Some(now_us) };
                }
                // The UART never took the bytes: start again.
                None if elapsed_s(now_us, since_us) >= CONFIGURE_TIMEOUT_S => {
                    self.start_search(0, now_us)
                }
                None => {}
                Some(sent_us) => {
                    let line_s = bytes as f32 * BITS_PER_BYTE / baud.max(1) as f32;
                    if elapsed_s(now_us, sent_us) >= line_s + DRAIN_MARGIN_S {
                        self.decoder.reset();
                        self.phase = Phase::AwaitingFix { since_us: now_us };
                    }
                }
            },
            Phase::AwaitingFix { since_us } => {
                if new_fix {
                    self.phase = Phase::Receiving { last_us: now_us };
                } else if elapsed_s(now_us, since_us) >= CONFIGURE_TIMEOUT_S {
                    self.start_search(0, now_us);
                }
            }
            Phase::Receiving { last_us } => {
                if new_fix {
                    self.phase = Phase::Receiving { last_us: now_us };
                } else if elapsed_s(now_us, last_us) >= LOST_TIMEOUT_S {
                    self.phase = Phase::Lost { since_us: now_us };
                }
            }
            Phase::Lost { since_us } => {
                if new_fix {
                    self.phase = Phase::Receiving { last_us: now_us };
                } else if elapsed_s(now_us, since_us) >= LOST_RESEARCH_S {
                    self.start_search(0, now_us);
                }
            }
        }
    }
}
#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    // ----- Frames built by hand from the documents (independent of the code under test) -----

    /// Fletcher-8 as "UBX Checksum" states it, written as two running sums in wider integers.
    fn fletcher(bytes: &[u8]) -> [u8; 2] {
        let (mut a, mut b) = (0u32, 0u32);
        for &byte in bytes {
            a = (a + u32::from(byte)) % 256;
            b = (b + a) % 256;
        }
        [a as u8, b as u8]
    }

    /// A frame: sync, class, id, little-endian length, payload, checksum over class..payload.
    fn frame(class: u8, id: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![0xB5, 0x62, class, id, payload.len() as u8, (payload.len() >> 8) as u8];
        f.extend_from_slice(payload);
        let ck = fletcher(&f[2..]);
        f.extend_from_slice(&ck);
        f
    }

    /// Values of a NAV-PVT in the frame's own units.
    #[derive(Clone, Copy)]
    struct RawPvt {
        itow_ms: u32,
        valid: u8,
        fix_type: u8,
        flags: u8,
        num_sv: u8,
        lon_e7: i32,
        lat_e7: i32,
        height_mm: i32,
        hmsl_mm: i32,
        hacc_mm: u32,
        vacc_mm: u32,
        vel_mm_s: [i32; 3],
        sacc_mm_s: u32,
        pdop_e2: u16,
        flags3: u16,
    }

    const RAW: RawPvt = RawPvt {
        itow_ms: 123_456_789,
        valid: 0x07,
        fix_type: 3,
        flags: 0x01,
        num_sv: 17,
        lon_e7: -1_224_194_155,
        lat_e7: 377_749_295,
        height_mm: 45_678,
        hmsl_mm: 12_345,
        hacc_mm: 850,
        vacc_mm: 1_230,
        vel_mm_s: [-1_500, 250, -75],
        sacc_mm_s: 320,
        pdop_e2: 153,
        flags3: 0,
    };

    /// The 92-byte payload at the offsets of "UBX-NAV-PVT": iTOW 0, year 4, month 6, day 7,
    /// hour 8, min 9, sec 10, valid 11, tAcc 12, nano 16, fixType 20, flags 21, flags2 22,
    /// numSV 23, lon 24, lat 28, height 32, hMSL 36, hAcc 40, vAcc 44, velN 48, velE 52, velD 56,
    /// gSpeed 60, headMot 64, sAcc 68, headAcc 72, pDOP 76, flags3 78, reserved 80, headVeh 84,
    /// magDec 88, magAcc 90.
    fn nav_pvt_payload(r: &RawPvt) -> Vec<u8> {
        let mut p = Vec::new();
        p.extend_from_slice(&r.itow_ms.to_le_bytes()); // 0 iTOW
        p.extend_from_slice(&2026u16.to_le_bytes()); // 4 year
        p.extend_from_slice(&[12, 2, 3, 41, 7, r.valid]); // 6 month .. 11 valid
        p.extend_from_slice(&25u32.to_le_bytes()); // 12 tAcc
        p.extend_from_slice(&(-1_234i32).to_le_bytes()); // 16 nano
        p.extend_from_slice(&[r.fix_type, r.flags, 0xE0, r.num_sv]); // 20 .. 23
        p.extend_from_slice(&r.lon_e7.to_le_bytes()); // 24
        p.extend_from_slice(&r.lat_e7.to_le_bytes()); // 28
        p.extend_from_slice(&r.height_mm.to_le_bytes()); // 32
        p.extend_from_slice(&r.hmsl_mm.to_le_bytes()); // 36
        p.extend_from_slice(&r.hacc_mm.to_le_bytes()); // 40
        p.extend_from_slice(&r.vacc_mm.to_le_bytes()); // 44
        for v in r.vel_mm_s {
            p.extend_from_slice(&v.to_le_bytes()); // 48, 52, 56
        }
        p.extend_from_slice(&1_520i32.to_le_bytes()); // 60 gSpeed
        p.extend_from_slice(&9_000_000i32.to_le_bytes()); // 64 headMot
        p.extend_from_slice(&r.sacc_mm_s.to_le_bytes()); // 68
        p.extend_from_slice(&500_000u32.to_le_bytes()); // 72 headAcc
        p.extend_from_slice(&r.pdop_e2.to_le_bytes()); // 76
        p.extend_from_slice(&r.flags3.to_le_bytes()); // 78
        p.extend_from_slice(&[0; 4]); // 80 reserved
        p.extend_from_slice(&0i32.to_le_bytes()); // 84 headVeh
        p.extend_from_slice(&0i16.to_le_bytes()); // 88 magDec
        p.extend_from_slice(&0u16.to_le_bytes()); // 90 magAcc
        assert_eq!(p.len(), 92);
        p
    }

    fn nav_pvt_frame(r: &RawPvt) -> Vec<u8> {
        frame(0x01, 0x07, &nav_pvt_payload(r))
    }

    /// Every message the decoder reports for `bytes` fed in chunks of `chunk`.
    fn decode(decoder: &mut Decoder, bytes: &[u8], chunk: usize) -> Vec<Message> {
        let mut out = Vec::new();
        for piece in bytes.chunks(chunk) {
            decoder.feed(piece, |f| out.push(Message::parse(&f)));
        }
        out
    }

    fn fixes(messages: &[Message]) -> Vec<GnssFix> {
        messages
            .iter()
            .filter_map(|m| match m {
                Message::NavPvt(fix) => Some(*fix),
                _ => None,
            })
            .collect()
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn checksum_matches_frames_published_with_the_protocol() {
        // The MON-VER poll and CFG-RATE 200 ms / 100 ms (GPS time), byte strings widely quoted
        // for u-blox receivers; both implementations here must agree with their checksums.
        let published: [&[u8]; 3] = [
            &[0xB5, 0x62, 0x0A, 0x04, 0x00, 0x00, 0x0E, 0x34],
            &[0xB5, 0x62, 0x06, 0x08, 0x06, 0x00, 0xC8, 0x00, 0x01, 0x00, 0x01, 0x00, 0xDE, 0x6A],
            &[0xB5, 0x62, 0x06, 0x08, 0x06, 0x00, 0x64, 0x00, 0x01, 0x00, 0x01, 0x00, 0x7A, 0x12],
        ];
        for f in published {
            let body = &f[2..f.len() - 2];
            assert_eq!(fletcher(body), [f[f.len() - 2], f[f.len() - 1]]);
            assert_eq!(checksum(body), (f[f.len() - 2], f[f.len() - 1]));
            let mut out = [0u8; 16];
            let n = encode_frame(f[2], f[3], &f[6..f.len() - 2], &mut out).unwrap();
            assert_eq!(&out[..n], f);
        }
        assert_eq!(encode_frame(1, 7, &[0; 92], &mut [0u8; 99]), None, "no room: no frame");
    }

    #[test]
    fn nav_pvt_from_the_documented_layout_decodes_to_si_units() {
        let mut decoder = Decoder::new();
        let messages = decode(&mut decoder, &nav_pvt_frame(&RAW), 100);
        assert_eq!(messages.len(), 1);
        let Message::NavPvt(fix) = messages[0] else { panic!("not NAV-PVT: {:?}", messages[0]) };
        assert_eq!(fix.time_of_week_ms, 123_456_789);
        assert!(fix.date_valid && fix.time_valid && fix.time_fully_resolved);
        assert_eq!(fix.fix_type, FixType::Fix3d);
        assert!(fix.gnss_fix_ok && !fix.position_invalid && fix.has_3d_fix());
        assert_eq!(fix.satellites, 17);
        assert!(close(fix.latitude_deg, 37.774_929_5, 1e-12), "{}", fix.latitude_deg);
        assert!(close(fix.longitude_deg, -122.419_415_5, 1e-12), "{}", fix.longitude_deg);
        assert!(close(f64::from(fix.height_ellipsoid_m), 45.678, 1e-5));
        assert!(close(f64::from(fix.height_msl_m), 12.345, 1e-5));
        assert!(close(f64::from(fix.horizontal_accuracy_m), 0.85, 1e-6));
        assert!(close(f64::from(fix.vertical_accuracy_m), 1.23, 1e-6));
        let expected_velocity = [-1.5, 0.25, -0.075];
        for (got, want) in fix.velocity_ned_mps.iter().zip(expected_velocity) {
            assert!(close(f64::from(*got), want, 1e-6), "{got} vs {want}");
        }
        assert!(close(f64::from(fix.speed_accuracy_mps), 0.32, 1e-6));
        assert!(close(f64::from(fix.position_dop), 1.53, 1e-6));
        assert_eq!(decoder.stats(), DecoderStats { frames: 1, ..DecoderStats::default() });

        // No fix, gnssFixOK clear, invalidLlh set: decoded as such, and not a 3D fix.
        let raw = RawPvt { fix_type: 0, flags: 0, flags3: 1, valid: 0, ..RAW };
        let fix = fixes(&decode(&mut decoder, &nav_pvt_frame(&raw), 7))[0];
        assert_eq!(fix.fix_type, FixType::NoFix);
        assert!(!fix.gnss_fix_ok && fix.position_invalid && !fix.has_3d_fix());
        assert!(!fix.date_valid && !fix.time_valid);
        // A 3D fix the receiver does not vouch for is not one to navigate by.
        let raw = RawPvt { flags: 0, ..RAW };
        assert!(!fixes(&decode(&mut decoder, &nav_pvt_frame(&raw), 92))[0].has_3d_fix());
    }

    #[test]
    fn garbage_nmea_and_truncated_frames_between_frames_do_not_break_decoding() {
        let nmea = b"$GNGGA,092725.00,4717.11399,N,00833.91590,E,1,08,1.01,499.6,M,48.0,M,,*5B\r\n";
        let mut stream = Vec::new();
        let mut expected = Vec::new();
        for (i, itow) in [1_000u32, 1_200, 1_400, 1_600].into_iter().enumerate() {
            let good = nav_pvt_frame(&RawPvt { itow_ms: itow, ..RAW });
            match i {
                0 => stream.extend_from_slice(&[0x00, 0xB5, 0x13, 0xFF, 0xB5, 0x62, 0x01]),
                1 => stream.extend_from_slice(nmea),
                // A frame cut off after 40 bytes (the receiver restarted mid-frame).
                2 => stream.extend_from_slice(&nav_pvt_frame(&RawPvt { itow_ms: 7, ..RAW })[..40]),
                _ => {
                    stream.extend_from_slice(nmea);
                    stream.extend_from_slice(&[0xB5, 0x62]); // a lone sync pair, then the frame
                }
            }
            stream.extend_from_slice(&good);
            expected.push(itow);
        }
        stream.extend_from_slice(nmea);
        for chunk in [1, 3, 64, stream.len()] {
            let mut decoder = Decoder::new();
            let got: Vec<u32> = fixes(&decode(&mut decoder, &stream, chunk))
                .iter()
                .map(|f| f.time_of_week_ms)
                .collect();
            assert_eq!(got, expected, "chunks of {chunk}");
            assert_eq!(decoder.stats().frames, 4, "chunks of {chunk}");
        }
    }

    #[test]
    fn a_corrupted_frame_is_counted_and_dropped() {
        let mut corrupted = nav_pvt_frame(&RawPvt { itow_ms: 5, ..RAW });
        corrupted[30] ^= 0x40; // a payload bit flipped on the line
        let mut bad_checksum = nav_pvt_frame(&RawPvt { itow_ms: 6, ..RAW });
        let last = bad_checksum.len() - 1;
        bad_checksum[last] = bad_checksum[last].wrapping_add(1);
        let mut stream = corrupted;
        stream.extend(bad_checksum);
        stream.extend(nav_pvt_frame(&RawPvt { itow_ms: 8, ..RAW }));
        let mut decoder = Decoder::new();
        let messages = decode(&mut decoder, &stream, 16);
        assert_eq!(fixes(&messages).iter().map(|f| f.time_of_week_ms).collect::<Vec<_>>(), [8]);
        assert_eq!(messages.len(), 1);
        assert_eq!(decoder.stats().checksum_errors, 2);
        assert_eq!(decoder.stats().frames, 1);
    }

    #[test]
    fn a_frame_longer_than_the_buffer_is_counted_and_the_next_one_decodes() {
        // A message of 1,100 bytes (a class we never enable), then a NAV-PVT.
        let mut stream = frame(0x0D, 0x01, &[0x55; 1_100]);
        stream.extend(nav_pvt_frame(&RAW));
        let mut decoder = Decoder::new();
        let messages = decode(&mut decoder, &stream, 32);
        assert_eq!(fixes(&messages).len(), 1);
        assert_eq!(decoder.stats().oversize, 1);
    }

    #[test]
    fn acknowledgements_and_other_messages_decode() {
        let mut stream = frame(0x05, 0x01, &[0x06, 0x8A]);
        stream.extend(frame(0x05, 0x00, &[0x06, 0x24]));
        stream.extend(frame(0x01, 0x03, &[0; 16])); // NAV-STATUS: not ours
        stream.extend(frame(0x01, 0x07, &[0; 84])); // a NAV-PVT of the wrong length (protocol < 15)
        let mut decoder = Decoder::new();
        let messages = decode(&mut decoder, &stream, 5);
        assert_eq!(
            messages,
            [
                Message::Ack { class: 0x06, id: 0x8A },
                Message::Nak { class: 0x06, id: 0x24 },
                Message::Other { class: 0x01, id: 0x03 },
                Message::Other { class: 0x01, id: 0x07 },
            ]
        );
        assert_eq!(decoder.stats(), DecoderStats { frames: 4, ..DecoderStats::default() });
    }

    // ----- Configuration, byte for byte -----

    const CONFIG: GnssConfig = GnssConfig { target_baud: 115_200, measurement_period_s: 0.1 };

    /// The M8 sequence from the u-blox 8 protocol description's field tables.
    fn m8_expected(baud: u32, period_ms: u16) -> Vec<u8> {
        // UBX-CFG-RATE: measRate (ms), navRate 1, timeRef 1 (GPS time).
        let mut rate = period_ms.to_le_bytes().to_vec();
        rate.extend_from_slice(&[1, 0, 1, 0]);
        // UBX-CFG-NAV5: mask 0x0001 (apply dynModel only), dynModel 8 (airborne < 4 g); the
        // other fields are not applied (zero).
        let mut nav5 = vec![0u8; 36];
        nav5[0] = 0x01;
        nav5[2] = 8;
        // UBX-CFG-MSG: class 0x01 id 0x07, rates on ports 0..5 (I2C, UART1, UART2, USB, SPI, -).
        let msg = [0x01, 0x07, 0, 1, 0, 0, 0, 0];
        // UBX-CFG-PRT (UART): portID 1, reserved, txReady 0, mode 0x000008C0 (charLen 0b11 bits
        // 6-7 = 8 bits, parity 0b100 bits 9-11 = none, nStopBits 0 = 1), baudRate,
        // inProtoMask 0x0001 (UBX), outProtoMask 0x0001 (UBX), flags 0, reserved.
        let mut prt = vec![1, 0, 0, 0, 0xC0, 0x08, 0, 0];
        prt.extend_from_slice(&baud.to_le_bytes());
        prt.extend_from_slice(&[0x01, 0x00, 0x01, 0x00, 0, 0, 0, 0]);
        let mut out = frame(0x06, 0x08, &rate);
        out.extend(frame(0x06, 0x24, &nav5));
        out.extend(frame(0x06, 0x01, &msg));
        out.extend(frame(0x06, 0x00, &prt));
        out
    }

    /// The M10 CFG-VALSET from the M10 interface description's key table.
    fn m10_expected(baud: u32, period_ms: u16) -> Vec<u8> {
        // version 0, layers 0x01 (RAM), reserved 2 bytes; then key (u32 LE), value (LE, its
        // size from key bits 28-30: 1 = bit in one byte, 2 = byte, 3 = two, 4 = four).
        let mut p = vec![0x00, 0x01, 0x00, 0x00];
        let mut item = |key: u32, value: &[u8]| {
            p.extend_from_slice(&key.to_le_bytes());
            p.extend_from_slice(value);
        };
        item(0x1073_0001, &[1]); // CFG-UART1INPROT-UBX = true
        item(0x1073_0002, &[0]); // CFG-UART1INPROT-NMEA = false
        item(0x1074_0001, &[1]); // CFG-UART1OUTPROT-UBX = true
        item(0x1074_0002, &[0]); // CFG-UART1OUTPROT-NMEA = false
        item(0x3021_0001, &period_ms.to_le_bytes()); // CFG-RATE-MEAS (ms)
        item(0x3021_0002, &1u16.to_le_bytes()); // CFG-RATE-NAV = 1
        item(0x2011_0021, &[8]); // CFG-NAVSPG-DYNMODEL = AIR4
        item(0x2091_0007, &[1]); // CFG-MSGOUT-UBX_NAV_PVT_UART1 = 1
        item(0x4052_0001, &baud.to_le_bytes()); // CFG-UART1-BAUDRATE
        frame(0x06, 0x8A, &p)
    }

    #[test]
    fn the_m8_configuration_is_the_documented_frames_byte_for_byte() {
        let mut out = [0u8; TX_CAPACITY];
        let n = m8_configuration(&CONFIG, &mut out).unwrap();
        assert_eq!(out[..n], m8_expected(115_200, 100)[..]);
        let five_hz = GnssConfig { target_baud: 230_400, measurement_period_s: 0.2 };
        let n = m8_configuration(&five_hz, &mut out).unwrap();
        assert_eq!(out[..n], m8_expected(230_400, 200)[..]);
        // The first frame is the published CFG-RATE 200 ms.
        assert_eq!(
            out[..14],
            [0xB5, 0x62, 0x06, 0x08, 0x06, 0x00, 0xC8, 0x00, 0x01, 0x00, 0x01, 0x00, 0xDE, 0x6A]
        );
        assert_eq!(m8_configuration(&CONFIG, &mut [0u8; 60]), None, "no room: nothing claimed");
    }

    #[test]
    fn the_m10_configuration_is_the_documented_valset_byte_for_byte() {
        let mut out = [0u8; TX_CAPACITY];
        let n = m10_configuration(&CONFIG, &mut out).unwrap();
        assert_eq!(out[..n], m10_expected(115_200, 100)[..]);
        let n = m10_configuration(
            &GnssConfig { target_baud: 921_600, measurement_period_s: 0.2 },
            &mut out,
        )
        .unwrap();
        assert_eq!(out[..n], m10_expected(921_600, 200)[..]);
        assert_eq!(m10_configuration(&CONFIG, &mut [0u8; 40]), None);
    }

    #[test]
    fn the_whole_sequence_is_m10_then_m8_and_fits_the_queue() {
        let mut out = [0u8; TX_CAPACITY];
        let n = configuration(&CONFIG, &mut out).unwrap();
        let mut expected = m10_expected(115_200, 100);
        expected.extend(m8_expected(115_200, 100));
        assert_eq!(out[..n], expected[..]);
        assert_eq!(CONFIG.measurement_period_ms(), 100);
        assert_eq!(
            GnssConfig { measurement_period_s: f32::NAN, ..CONFIG }.measurement_period_ms(),
            200
        );
        assert_eq!(
            GnssConfig { measurement_period_s: 0.001, ..CONFIG }.measurement_period_ms(),
            25
        );
    }

    // ----- The state machine against a test double receiver -----

    #[derive(Clone, Copy, PartialEq, Eq, Debug)]
    pub(crate) enum Generation {
        M8,
        M10,
    }

    /// A u-blox receiver on the other end of the UART, from the documents' behaviour: it answers
    /// a MON-VER poll, takes the configuration messages of its generation (acknowledging them at
    /// the rate they came in, then switching baud), and sends NAV-PVT every period once enabled,
    /// NMEA once a second while NMEA output is on. Bytes at a baud other than its own reach either
    /// side as garbage: a receiver ignores them, and the host gets random bytes, about as many as
    /// the ratio of the rates makes of them.
    pub(crate) struct FakeReceiver {
        generation: Generation,
        baud: u32,
        period_s: f64,
        dyn_model: u8,
        nav_pvt_on: bool,
        nmea_out: bool,
        ubx_out: bool,
        silent: bool,
        /// (time it reaches the host, s; the baud it was sent at; the bytes).
        outbox: Vec<(f64, u32, Vec<u8>)>,
        next_pvt_s: f64,
        next_nmea_s: f64,
        noise: u64,
        acked: Vec<(u8, u8, bool)>,
    }

    /// The receiver's answer latency, s.
    const FAKE_LATENCY_S: f64 = 0.02;

    impl FakeReceiver {
        pub(crate) fn new(generation: Generation, baud: u32) -> Self {
            Self {
                generation,
                baud,
                period_s: 1.0,
                dyn_model: 0,
                nav_pvt_on: false,
                nmea_out: true,
                ubx_out: true,
                silent: false,
                outbox: Vec::new(),
                next_pvt_s: 0.0,
                next_nmea_s: 0.0,
                noise: 0x2545_F491_4F6C_DD1D,
                acked: Vec::new(),
            }
        }

        fn send(&mut self, now_s: f64, bytes: Vec<u8>) {
            if self.silent {
                return;
            }
            let line_s = bytes.len() as f64 * 10.0 / f64::from(self.baud);
            self.outbox.push((now_s + FAKE_LATENCY_S + line_s, self.baud, bytes));
        }

        fn ack(&mut self, now_s: f64, class: u8, id: u8, ok: bool) {
            self.acked.push((class, id, ok));
            self.send(now_s, frame(0x05, u8::from(ok), &[class, id]));
        }

        /// Frames in what the host wrote (a scanner of our own: sync, length, checksum).
        fn frames(bytes: &[u8]) -> Vec<(u8, u8, Vec<u8>)> {
            let mut out = Vec::new();
            let mut i = 0;
            while i + 8 <= bytes.len() {
                if bytes[i] != 0xB5 || bytes[i + 1] != 0x62 {
                    i += 1;
                    continue;
                }
                let len = usize::from(bytes[i + 4]) | usize::from(bytes[i + 5]) << 8;
                let end = i + 6 + len + 2;
                if end <= bytes.len() && fletcher(&bytes[i + 2..end - 2]) == bytes[end - 2..end] {
                    out.push((bytes[i + 2], bytes[i + 3], bytes[i + 6..end - 2].to_vec()));
                    i = end;
                } else {
                    i += 1;
                }
            }
            out
        }

        pub(crate) fn receive(&mut self, bytes: &[u8], host_baud: u32, now_s: f64) {
            if host_baud != self.baud || self.silent {
                return;
            }
            for (class, id, p) in Self::frames(bytes) {
                let mut new_baud = None;
                match (self.generation, class, id) {
                    (_, 0x0A, 0x04) if p.is_empty() => {
                        let mut ver = vec![0u8; 40];
                        ver[..22].copy_from_slice(b"ROM CORE 3.01 (107888)");
                        ver[30..38].copy_from_slice(b"00080000");
                        for ext in ["FWVER=SPG 3.01", "PROTVER=18.00", "GPS;GLO;GAL;BDS"] {
                            let mut field = [0u8; 30];
                            field[..ext.len()].copy_from_slice(ext.as_bytes());
                            ver.extend_from_slice(&field);
                        }
                        self.send(now_s, frame(0x0A, 0x04, &ver));
                    }
                    (Generation::M8, 0x06, 0x08) if p.len() == 6 => {
                        self.period_s = f64::from(u16::from_le_bytes([p[0], p[1]])) / 1000.0;
                        self.ack(now_s, class, id, true);
                    }
                    (Generation::M8, 0x06, 0x24) if p.len() == 36 => {
                        if p[0] & 1 != 0 {
                            self.dyn_model = p[2];
                        }
                        self.ack(now_s, class, id, true);
                    }
                    (Generation::M8, 0x06, 0x01) if p.len() == 8 => {
                        if (p[0], p[1]) == (0x01, 0x07) {
                            self.nav_pvt_on = p[3] != 0;
                        }
                        self.ack(now_s, class, id, true);
                    }
                    (Generation::M8, 0x06, 0x00) if p.len() == 20 && p[0] == 1 => {
                        self.ubx_out = p[14] & 1 != 0;
                        self.nmea_out = p[14] & 2 != 0;
                        new_baud = Some(u32::from_le_bytes([p[8], p[9], p[10], p[11]]));
                        self.ack(now_s, class, id, true);
                    }
                    (Generation::M8, 0x06, 0x8A) => self.ack(now_s, class, id, false),
                    (Generation::M10, 0x06, 0x8A) if p.len() >= 4 => {
                        let mut i = 4;
                        while i + 4 <= p.len() {
                            let key = u32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]]);
                            let size = match (key >> 28) & 7 {
                                1 | 2 => 1,
                                3 => 2,
                                4 => 4,
                                _ => 8,
                            };
                            let mut v = [0u8; 8];
                            v[..size].copy_from_slice(&p[i + 4..i + 4 + size]);
                            let value = u64::from_le_bytes(v);
                            match key {
                                0x4052_0001 => new_baud = Some(value as u32),
                                0x3021_0001 => self.period_s = value as f64 / 1000.0,
                                0x2011_0021 => self.dyn_model = value as u8,
                                0x2091_0007 => self.nav_pvt_on = value != 0,
                                0x1074_0001 => self.ubx_out = value != 0,
                                0x1074_0002 => self.nmea_out = value != 0,
                                _ => {}
                            }
                            i += 4 + size;
                        }
                        self.ack(now_s, class, id, true);
                    }
                    // An M10 has no legacy CFG messages: silence.
                    _ => {}
                }
                if let Some(baud) = new_baud {
                    // Switches once the acknowledgement has left at the old rate; the rest of
                    // what the host sent at the old rate is garbage to it.
                    self.baud = baud;
                    return;
                }
            }
        }

        fn garble(&mut self, bytes: &[u8], from_baud: u32, host_baud: u32) -> Vec<u8> {
            let count = ((bytes.len() as f64) * f64::from(host_baud) / f64::from(from_baud)).ceil()
                as usize;
            (0..count.max(1))
                .map(|_| {
                    self.noise ^= self.noise << 13;
                    self.noise ^= self.noise >> 7;
                    self.noise ^= self.noise << 17;
                    (self.noise >> 24) as u8
                })
                .collect()
        }

        /// What reached the host by `now_s`, read at `host_baud`.
        pub(crate) fn transmit(&mut self, now_s: f64, host_baud: u32) -> Vec<u8> {
            if !self.silent {
                if self.nav_pvt_on && self.ubx_out && now_s >= self.next_pvt_s {
                    let itow = (now_s * 1000.0).round() as u32;
                    let pvt = nav_pvt_frame(&RawPvt { itow_ms: itow, ..RAW });
                    self.send(now_s, pvt);
                    self.next_pvt_s = now_s + self.period_s;
                }
                if self.nmea_out && now_s >= self.next_nmea_s {
                    self.send(now_s, b"$GNGGA,092725.00,,,,,0,00,99.99,,,,,,*77\r\n".to_vec());
                    self.next_nmea_s = now_s + 1.0;
                }
            }
            let (due, later): (Vec<_>, Vec<_>) =
                self.outbox.drain(..).partition(|(t, _, _)| *t <= now_s);
            self.outbox = later;
            let mut out = Vec::new();
            for (_, baud, bytes) in due {
                if baud == host_baud {
                    out.extend(bytes);
                } else {
                    let garbage = self.garble(&bytes, baud, host_baud);
                    out.extend(garbage);
                }
            }
            out
        }
    }

    /// The board's side: a UART polled every `STEP_S`, which takes every byte offered.
    const STEP_S: f64 = 0.005;

    struct Link {
        receiver: GnssReceiver,
        fake: FakeReceiver,
        host_baud: u32,
        now_s: f64,
        /// (time, status) at every change of status.
        history: Vec<(f64, GnssStatus)>,
    }

    impl Link {
        fn new(config: GnssConfig, fake: FakeReceiver) -> Self {
            Self {
                receiver: GnssReceiver::new(config),
                fake,
                host_baud: 0,
                now_s: 0.0,
                history: Vec::new(),
            }
        }

        fn step(&mut self) {
            let incoming = self.fake.transmit(self.now_s, self.host_baud);
            let out = self.receiver.poll(&incoming, (self.now_s * 1e6).round() as u64);
            self.host_baud = out.baud;
            let written = out.write.to_vec();
            self.receiver.sent(written.len());
            self.fake.receive(&written, self.host_baud, self.now_s);
            let status = self.receiver.status();
            let changed = match (self.history.last(), status) {
                (Some((_, GnssStatus::Receiving { .. })), GnssStatus::Receiving { .. }) => false,
                (Some((_, last)), _) => *last != status,
                (None, _) => true,
            };
            if changed {
                self.history.push((self.now_s, status));
            }
            self.now_s += STEP_S;
        }

        /// Steps until `until(status)` or `limit_s`; the time it held, if it did.
        fn run_until(&mut self, limit_s: f64, until: impl Fn(&GnssStatus) -> bool) -> Option<f64> {
            while self.now_s <= limit_s {
                self.step();
                if until(&self.receiver.status()) {
                    return Some(self.now_s - STEP_S);
                }
            }
            None
        }
    }

    fn receiving(status: &GnssStatus) -> bool {
        matches!(status, GnssStatus::Receiving { .. })
    }

    /// The latest time the receiver may report `Receiving` when it sits at search step `index`:
    /// every earlier window, its own, the configuration's bytes leaving at `baud`, the margin,
    /// the first NAV-PVT period at the target rate and its bytes, and one poll step.
    fn expected_by_s(index: usize, baud: u32, config: &GnssConfig) -> f64 {
        let mut out = [0u8; TX_CAPACITY];
        let config_bytes = configuration(config, &mut out).unwrap();
        (index + 1) as f64 * f64::from(SEARCH_WINDOW_S)
            + config_bytes as f64 * 10.0 / f64::from(baud)
            + f64::from(DRAIN_MARGIN_S)
            + f64::from(config.measurement_period_s)
            + FAKE_LATENCY_S
            + 100.0 * 10.0 / f64::from(config.target_baud)
            + 2.0 * STEP_S
    }

    #[test]
    fn an_m8_at_its_factory_baud_is_found_configured_and_received() {
        let config = GnssConfig { target_baud: 115_200, measurement_period_s: 0.2 };
        let mut link = Link::new(config, FakeReceiver::new(Generation::M8, 9_600));
        let found = link.run_until(10.0, receiving).expect("never received");
        // Search order: the target first, then 9,600 (step 1).
        assert!(found <= expected_by_s(1, 9_600, &config), "received at {found:.3} s");
        assert!(found >= f64::from(SEARCH_WINDOW_S), "found before the 9,600 window: {found}");
        let statuses: Vec<GnssStatus> = link.history.iter().map(|(_, s)| *s).collect();
        assert_eq!(statuses[0], GnssStatus::Searching { baud: 115_200 });
        assert_eq!(statuses[1], GnssStatus::Searching { baud: 9_600 });
        assert_eq!(statuses[2], GnssStatus::Configuring { baud: 9_600 });
        assert_eq!(statuses[3], GnssStatus::Configuring { baud: 115_200 });
        assert!(receiving(&statuses[4]));
        // The receiver took the M8 messages: rate, model, NAV-PVT, UBX only, the new baud.
        let fake = &link.fake;
        assert_eq!((fake.baud, fake.period_s, fake.dyn_model), (115_200, 0.2, 8));
        assert!(fake.nav_pvt_on && fake.ubx_out && !fake.nmea_out);
        assert_eq!(
            link.receiver.acknowledged(),
            Acknowledged { valset: false, legacy: true, naks: 1 }
        );
        assert_eq!(link.receiver.configure_attempts(), 1);
        // It keeps receiving, a fix every period, the fix's values the receiver's.
        link.run_until(found + 2.0, |_| false);
        let GnssStatus::Receiving { fix } = link.receiver.status() else { panic!("lost") };
        assert_eq!(fix.satellites, RAW.num_sv);
        assert!((link.now_s * 1000.0 - f64::from(fix.time_of_week_ms)) < 250.0);
    }

    #[test]
    fn an_m10_at_its_factory_baud_is_found_and_configured_by_valset() {
        let config = GnssConfig { target_baud: 230_400, measurement_period_s: 0.1 };
        let mut link = Link::new(config, FakeReceiver::new(Generation::M10, 38_400));
        let found = link.run_until(10.0, receiving).expect("never received");
        // Search order: 230,400, 9,600, 38,400 (step 2).
        assert!(found <= expected_by_s(2, 38_400, &config), "received at {found:.3} s");
        assert!(found >= 2.0 * f64::from(SEARCH_WINDOW_S), "found too early: {found}");
        let fake = &link.fake;
        assert_eq!((fake.baud, fake.period_s, fake.dyn_model), (230_400, 0.1, 8));
        assert!(fake.nav_pvt_on && fake.ubx_out && !fake.nmea_out);
        assert_eq!(
            link.receiver.acknowledged(),
            Acknowledged { valset: true, legacy: false, naks: 0 }
        );
    }

    #[test]
    fn a_receiver_already_at_the_target_baud_is_found_in_the_first_window() {
        let config = GnssConfig::default();
        let mut fake = FakeReceiver::new(Generation::M10, config.target_baud);
        (fake.nav_pvt_on, fake.nmea_out, fake.period_s) = (true, false, 0.2);
        let mut link = Link::new(config, fake);
        let found = link.run_until(10.0, receiving).expect("never received");
        assert!(found <= expected_by_s(0, config.target_baud, &config), "received at {found:.3} s");
    }

    #[test]
    fn a_silent_receiver_is_searched_at_every_rate_in_turn() {
        let mut fake = FakeReceiver::new(Generation::M8, 9_600);
        fake.silent = true;
        let config = GnssConfig::default();
        let mut link = Link::new(config, fake);
        let cycle_s = 8.0 * f64::from(SEARCH_WINDOW_S);
        assert_eq!(
            link.run_until(cycle_s * 1.5, |s| !matches!(s, GnssStatus::Searching { .. })),
            None
        );
        let bauds: Vec<u32> = link
            .history
            .iter()
            .map(|(_, s)| match s {
                GnssStatus::Searching { baud } => *baud,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(
            bauds[..9],
            [115_200, 9_600, 38_400, 230_400, 57_600, 19_200, 460_800, 921_600, 115_200]
        );
        // Each rate held for one window.
        for pair in link.history.windows(2) {
            let held = pair[1].0 - pair[0].0;
            assert!((held - f64::from(SEARCH_WINDOW_S)).abs() <= STEP_S + 1e-9, "held {held} s");
        }
        // One MON-VER poll per window, nothing else: the receiver sent nothing to configure.
        assert_eq!(link.receiver.configure_attempts(), 0);
    }

    #[test]
    fn a_receiver_that_goes_silent_is_reported_lost_and_then_searched_for() {
        let config = GnssConfig { target_baud: 115_200, measurement_period_s: 0.2 };
        let mut link = Link::new(config, FakeReceiver::new(Generation::M8, 9_600));
        let found = link.run_until(10.0, receiving).expect("never received");
        link.run_until(found + 1.0, |_| false);
        link.fake.silent = true;
        link.fake.outbox.clear();
        let silent_at = link.now_s;
        let lost_at =
            link.run_until(silent_at + 5.0, |s| *s == GnssStatus::Lost).expect("never lost");
        // The last NAV-PVT came at most one period before the silence.
        let after = lost_at - silent_at;
        assert!(
            after >= f64::from(LOST_TIMEOUT_S) - 0.2 - STEP_S,
            "lost {after:.3} s after silence"
        );
        assert!(after <= f64::from(LOST_TIMEOUT_S) + STEP_S, "lost {after:.3} s after silence");
        let searching_at = link
            .run_until(lost_at + 10.0, |s| matches!(s, GnssStatus::Searching { .. }))
            .expect("never searched again");
        assert!((searching_at - lost_at - f64::from(LOST_RESEARCH_S)).abs() <= STEP_S + 1e-9);
        assert_eq!(link.receiver.status(), GnssStatus::Searching { baud: 115_200 });
    }

    #[test]
    fn a_receiver_back_before_the_search_is_received_again() {
        let config = GnssConfig { target_baud: 115_200, measurement_period_s: 0.2 };
        let mut link = Link::new(config, FakeReceiver::new(Generation::M10, 38_400));
        let found = link.run_until(10.0, receiving).expect("never received");
        link.run_until(found + 0.5, |_| false);
        link.fake.silent = true;
        link.fake.outbox.clear();
        let lost_at =
            link.run_until(link.now_s + 5.0, |s| *s == GnssStatus::Lost).expect("never lost");
        link.fake.silent = false;
        let back = link.run_until(lost_at + 1.0, receiving).expect("not received again");
        assert!(back - lost_at <= 0.2 + 2.0 * STEP_S + FAKE_LATENCY_S + 0.01);
        assert_eq!(link.receiver.configure_attempts(), 1, "no new configuration needed");
    }

    #[test]
    fn a_garbled_receiver_is_never_taken_for_one_and_nothing_faults() {
        // Everything arrives at a rate the search never tries: garbage at every step.
        let mut link = Link::new(GnssConfig::default(), FakeReceiver::new(Generation::M8, 4_800));
        link.fake.nav_pvt_on = true;
        link.fake.period_s = 0.1;
        assert_eq!(link.run_until(10.0, |s| !matches!(s, GnssStatus::Searching { .. })), None);
        assert_eq!(link.receiver.decoder_stats().frames, 0);
        assert_eq!(link.receiver.configure_attempts(), 0);
    }
}
