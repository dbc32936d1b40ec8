//! CRSF (TBS Crossfire / ExpressLRS) receiver protocol: a byte-at-a-time frame parser, the
//! decoding of RC channels and link statistics, and the mapping of the pilot's switches to what
//! the pilot asks for ([`RcLink`]), including the signal-loss failsafe.
//!
//! Why here: the board's UART interrupt (or DMA idle-line handler) only hands bytes to
//! [`CrsfParser::push`]; framing, checksums and switch logic are tested on the host.
//!
//! # Frame format
//!
//! From the CRSF specification as published by TBS (Crossfire) and documented by ExpressLRS
//! (`crsf_protocol.h`, "CRSF protocol" pages), serial 420 000 baud 8N1:
//!
//! ```text
//! [address/sync][length][type][payload ...][crc]
//! ```
//!
//! - address/sync: `0xC8` (flight controller); `0xEE` (transmitter module) and `0xEA`
//!   (handset) are accepted too.
//! - length: number of bytes after itself = type + payload + crc, 2..=62 (frames are at most 64
//!   bytes).
//! - crc: CRC-8/DVB-S2 (polynomial 0xD5, initial value 0, no reflection, no final XOR) over type
//!   and payload.
//!
//! Decoded types:
//! - `0x16` RC_CHANNELS_PACKED, 22-byte payload: 16 channels × 11 bits, packed little-endian
//!   (channel 0 in the least significant bits of byte 0). Values 172..=1811 (ExpressLRS / TBS
//!   range), centre 992; in µs `1500 + (raw − 992) · 5/8` (988..=2012 µs).
//! - `0x14` LINK_STATISTICS, 10 bytes: uplink RSSI antenna 1, antenna 2 (dBm, sent as the
//!   positive magnitude of a negative value), uplink link quality (%), uplink SNR (i8, dB),
//!   active antenna, RF mode, uplink TX power (index), downlink RSSI (magnitude, dBm), downlink
//!   link quality (%), downlink SNR (i8, dB).
//!
//! Other types (telemetry, device pings, ...) are checked, counted and skipped.
//!
//! # Resynchronisation
//!
//! A sync byte can also be a payload byte, so a frame start is only a guess until its CRC
//! matches. When a candidate frame fails (bad length or CRC), the parser drops its first byte
//! and re-parses the bytes after it, so a frame truncated by a glitch does not take the next good
//! frame with it. If the board detects an inter-byte gap (idle line), it calls
//! [`CrsfParser::reset`], which reports the unfinished frame as truncated.

/// Address byte of frames to the flight controller (the usual sync byte).
pub const SYNC_FLIGHT_CONTROLLER: u8 = 0xC8;
/// Address byte of the transmitter module.
pub const SYNC_TRANSMITTER: u8 = 0xEE;
/// Address byte of the handset (radio).
pub const SYNC_HANDSET: u8 = 0xEA;
/// Smallest valid length byte (type + crc).
pub const LENGTH_MIN: u8 = 2;
/// Largest valid length byte (64-byte frame minus address and length).
pub const LENGTH_MAX: u8 = 62;
/// Largest frame, bytes (address + length + 62).
pub const FRAME_MAX: usize = LENGTH_MAX as usize + 2;
/// Frame type of RC channels (16 × 11 bits).
pub const TYPE_RC_CHANNELS_PACKED: u8 = 0x16;
/// Frame type of link statistics.
pub const TYPE_LINK_STATISTICS: u8 = 0x14;
/// Frame type of the battery sensor (flight controller → handset): voltage, current, used
/// capacity, remaining charge.
pub const TYPE_BATTERY_SENSOR: u8 = 0x08;
/// Frame type of the attitude (flight controller → handset): pitch, roll, yaw.
pub const TYPE_ATTITUDE: u8 = 0x1E;
/// Frame type of the flight mode (flight controller → handset): a short text.
pub const TYPE_FLIGHT_MODE: u8 = 0x21;
/// Payload length of BATTERY_SENSOR, bytes.
pub const BATTERY_PAYLOAD_LEN: usize = 8;
/// Payload length of ATTITUDE, bytes.
pub const ATTITUDE_PAYLOAD_LEN: usize = 6;
/// Longest flight-mode text sent, bytes (a handset's telemetry screen shows about 16
/// characters; the frame carries a terminating zero after it).
pub const FLIGHT_MODE_MAX_LEN: usize = 15;
/// The attitude frame's unit, rad per count (100 µrad).
pub const ATTITUDE_RAD_PER_COUNT: f32 = 1e-4;
/// Payload length of RC_CHANNELS_PACKED, bytes.
pub const RC_CHANNELS_PAYLOAD_LEN: usize = 22;
/// Payload length of LINK_STATISTICS, bytes.
pub const LINK_STATISTICS_PAYLOAD_LEN: usize = 10;
/// Number of RC channels in a packed frame.
pub const CHANNEL_COUNT: usize = 16;
/// Smallest channel value sent (988 µs).
pub const CHANNEL_RAW_MIN: u16 = 172;
/// Centre channel value (1500 µs).
pub const CHANNEL_RAW_MID: u16 = 992;
/// Largest channel value sent (2012 µs).
pub const CHANNEL_RAW_MAX: u16 = 1811;
/// CRC-8/DVB-S2 polynomial.
pub const CRC8_POLY: u8 = 0xD5;

/// CRC-8/DVB-S2 (poly 0xD5, init 0) over `data`.
pub fn crc8_dvb_s2(data: &[u8]) -> u8 {
    let mut crc: u8 = 0;
    for &byte in data {
        crc ^= byte;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ CRC8_POLY } else { crc << 1 };
        }
    }
    crc
}

/// Channel value → pulse width in µs: `1500 + (raw − 992) · 5/8` (172 → 987.5, 1811 → 2011.9).
pub fn channel_raw_to_us(raw: u16) -> f32 {
    1500.0 + (f32::from(raw) - f32::from(CHANNEL_RAW_MID)) * 0.625
}

/// Channel value → −1..=1: `(µs − 1500) / 512`, clamped (172 → −1, 992 → 0, 1811 → 0.9998).
pub fn channel_raw_to_normalised(raw: u16) -> f32 {
    ((channel_raw_to_us(raw) - 1500.0) / 512.0).clamp(-1.0, 1.0)
}

/// The 16 RC channels of one RC_CHANNELS_PACKED frame, raw 11-bit values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RcChannels {
    /// Raw values, 0..=2047 (172..=1811 in normal use).
    pub raw: [u16; CHANNEL_COUNT],
}

impl RcChannels {
    /// Unpack the 22-byte payload (11 bits per channel, little-endian bit order).
    pub fn unpack(payload: &[u8; RC_CHANNELS_PAYLOAD_LEN]) -> Self {
        let mut raw = [0u16; CHANNEL_COUNT];
        let mut acc: u32 = 0;
        let mut acc_bits = 0u32;
        let mut bytes = payload.iter();
        for ch in raw.iter_mut() {
            while acc_bits < 11 {
                let byte = bytes.next().copied().unwrap_or(0);
                acc |= u32::from(byte) << acc_bits;
                acc_bits += 8;
            }
            *ch = (acc & 0x7FF) as u16;
            acc >>= 11;
            acc_bits -= 11;
        }
        Self { raw }
    }

    /// Pack into the 22-byte payload (the inverse of [`RcChannels::unpack`]; values above 11
    /// bits are cut to their low 11 bits). What a transmitter sends; the simulator's radio uses it.
    pub fn pack(&self) -> [u8; RC_CHANNELS_PAYLOAD_LEN] {
        let mut payload = [0u8; RC_CHANNELS_PAYLOAD_LEN];
        let mut acc: u32 = 0;
        let mut acc_bits = 0u32;
        let mut out = 0usize;
        for &value in &self.raw {
            acc |= u32::from(value & 0x7FF) << acc_bits;
            acc_bits += 11;
            while acc_bits >= 8 {
                payload[out] = acc as u8;
                out += 1;
                acc >>= 8;
                acc_bits -= 8;
            }
        }
        payload
    }

    /// The raw value for a pulse width in µs (the inverse of [`channel_raw_to_us`], rounded and
    /// clamped to 11 bits).
    pub fn raw_from_us(us: f32) -> u16 {
        let raw = f32::from(CHANNEL_RAW_MID) + (us - 1500.0) * 1.6;
        libm::roundf(raw).clamp(0.0, 2047.0) as u16
    }

    /// Raw value of channel `index` (0-based), `None` past channel 15.
    pub fn raw(&self, index: usize) -> Option<u16> {
        self.raw.get(index).copied()
    }

    /// Channel `index` in µs (see [`channel_raw_to_us`]).
    pub fn us(&self, index: usize) -> Option<f32> {
        self.raw(index).map(channel_raw_to_us)
    }

    /// Channel `index` normalised to −1..=1 (see [`channel_raw_to_normalised`]).
    pub fn normalised(&self, index: usize) -> Option<f32> {
        self.raw(index).map(channel_raw_to_normalised)
    }
}

/// Encode one frame: `sync`, length (type + payload + CRC), `frame_type`, `payload`, CRC-8
/// DVB-S2 over type and payload. Returns the bytes written into `out`, or `None` when the payload
/// is longer than a frame allows or `out` is too small.
pub fn encode_frame(sync: u8, frame_type: u8, payload: &[u8], out: &mut [u8]) -> Option<usize> {
    let length = payload.len() + 2;
    if length > usize::from(LENGTH_MAX) || out.len() < length + 2 {
        return None;
    }
    out[0] = sync;
    out[1] = length as u8;
    out[2] = frame_type;
    out[3..3 + payload.len()].copy_from_slice(payload);
    out[3 + payload.len()] = crc8_dvb_s2(&out[2..3 + payload.len()]);
    Some(length + 2)
}

/// A telemetry frame the flight controller sends the pilot's handset, in SI units.
#[derive(Debug, Clone, PartialEq)]
pub enum HandsetTelemetry {
    /// Euler angles (ZYX), rad: sent in 100 µrad counts, big-endian `i16` (±3.2767 rad).
    Attitude { pitch_rad: f32, roll_rad: f32, yaw_rad: f32 },
    /// What the craft is doing, in words (at most [`FLIGHT_MODE_MAX_LEN`] bytes).
    FlightMode(heapless::String<FLIGHT_MODE_MAX_LEN>),
    /// Battery: voltage, V (0.1 V), current, A (0.1 A), used capacity, mAh (24 bits),
    /// remaining charge, % — big-endian.
    Battery { voltage_v: f32, current_a: f32, used_mah: u32, remaining_pct: u8 },
}

impl HandsetTelemetry {
    /// Encode as a frame from the flight controller (sync 0xC8) into `out`; returns its length,
    /// or `None` when `out` is too small. Values beyond a field's range are clamped to it.
    pub fn encode(&self, out: &mut [u8]) -> Option<usize> {
        let counts = |rad: f32| {
            let counts = libm::roundf(rad / ATTITUDE_RAD_PER_COUNT);
            counts.clamp(f32::from(i16::MIN), f32::from(i16::MAX)) as i16
        };
        let tenths = |x: f32| libm::roundf(x * 10.0).clamp(0.0, f32::from(i16::MAX)) as u16;
        let mut payload = [0u8; FLIGHT_MODE_MAX_LEN + 1];
        let (frame_type, len) = match self {
            Self::Attitude { pitch_rad, roll_rad, yaw_rad } => {
                for (i, rad) in [pitch_rad, roll_rad, yaw_rad].into_iter().enumerate() {
                    payload[2 * i..2 * i + 2].copy_from_slice(&counts(*rad).to_be_bytes());
                }
                (TYPE_ATTITUDE, ATTITUDE_PAYLOAD_LEN)
            }
            Self::FlightMode(text) => {
                payload[..text.len()].copy_from_slice(text.as_bytes());
                (TYPE_FLIGHT_MODE, text.len() + 1)
            }
            Self::Battery { voltage_v, current_a, used_mah, remaining_pct } => {
                payload[0..2].copy_from_slice(&tenths(*voltage_v).to_be_bytes());
                payload[2..4].copy_from_slice(&tenths(*current_a).to_be_bytes());
                payload[4..7].copy_from_slice(&(*used_mah).min(0xFF_FFFF).to_be_bytes()[1..]);
                payload[7] = (*remaining_pct).min(100);
                (TYPE_BATTERY_SENSOR, BATTERY_PAYLOAD_LEN)
            }
        };
        encode_frame(SYNC_FLIGHT_CONTROLLER, frame_type, &payload[..len], out)
    }

    /// Decode one whole frame (sync, length, type, payload, CRC): what a handset does with it.
    /// Checks the length byte, the CRC and the payload length of each type.
    pub fn decode(frame: &[u8]) -> Result<Self, CrsfError> {
        let length = *frame.get(1).ok_or(CrsfError::Length { length: 0 })?;
        if !(LENGTH_MIN..=LENGTH_MAX).contains(&length) || frame.len() != usize::from(length) + 2 {
            return Err(CrsfError::Length { length });
        }
        let body = &frame[2..frame.len() - 1];
        let received = frame[frame.len() - 1];
        let computed = crc8_dvb_s2(body);
        if computed != received {
            return Err(CrsfError::Crc { computed, received });
        }
        let (frame_type, payload) = (body[0], &body[1..]);
        let wrong = CrsfError::PayloadLength { frame_type, length: payload.len() as u8 };
        let be16 = |i: usize| [payload[i], payload[i + 1]];
        match frame_type {
            TYPE_ATTITUDE if payload.len() == ATTITUDE_PAYLOAD_LEN => {
                let rad =
                    |i: usize| f32::from(i16::from_be_bytes(be16(i))) * ATTITUDE_RAD_PER_COUNT;
                Ok(Self::Attitude { pitch_rad: rad(0), roll_rad: rad(2), yaw_rad: rad(4) })
            }
            TYPE_FLIGHT_MODE => {
                let text = payload.split(|&b| b == 0).next().unwrap_or(&[]);
                let text = core::str::from_utf8(text).map_err(|_| wrong)?;
                let mut words = heapless::String::new();
                words.push_str(text).map_err(|_| wrong)?;
                Ok(Self::FlightMode(words))
            }
            TYPE_BATTERY_SENSOR if payload.len() == BATTERY_PAYLOAD_LEN => Ok(Self::Battery {
                voltage_v: f32::from(u16::from_be_bytes(be16(0))) / 10.0,
                current_a: f32::from(u16::from_be_bytes(be16(2))) / 10.0,
                used_mah: u32::from_be_bytes([0, payload[4], payload[5], payload[6]]),
                remaining_pct: payload[7],
            }),
            _ => Err(wrong),
        }
    }
}

/// Link statistics as sent by the receiver (frame type 0x14).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkStatistics {
    /// Uplink RSSI at antenna 1, dBm (negative; the frame carries the magnitude).
    pub uplink_rssi_ant1_dbm: i16,
    /// Uplink RSSI at antenna 2, dBm.
    pub uplink_rssi_ant2_dbm: i16,
    /// Uplink link quality, % of packets received.
    pub uplink_link_quality_pct: u8,
    /// Uplink signal-to-noise ratio, dB.
    pub uplink_snr_db: i8,
    /// Active antenna (0 or 1).
    pub active_antenna: u8,
    /// RF mode (packet-rate index; meaning depends on the link: Crossfire or ExpressLRS).
    pub rf_mode: u8,
    /// Uplink transmit power index (0 = 0 mW, 1 = 10, 2 = 25, 3 = 100, 4 = 500, 5 = 1000,
    /// 6 = 2000, 7 = 250, 8 = 50 mW in the TBS / ExpressLRS table).
    pub uplink_tx_power_index: u8,
    /// Downlink RSSI, dBm (negative).
    pub downlink_rssi_dbm: i16,
    /// Downlink link quality, %.
    pub downlink_link_quality_pct: u8,
    /// Downlink signal-to-noise ratio, dB.
    pub downlink_snr_db: i8,
}

impl LinkStatistics {
    /// Decode the 10-byte payload.
    pub fn decode(p: &[u8; LINK_STATISTICS_PAYLOAD_LEN]) -> Self {
        Self {
            uplink_rssi_ant1_dbm: -i16::from(p[0]),
            uplink_rssi_ant2_dbm: -i16::from(p[1]),
            uplink_link_quality_pct: p[2],
            uplink_snr_db: i8::from_le_bytes([p[3]]),
            active_antenna: p[4],
            rf_mode: p[5],
            uplink_tx_power_index: p[6],
            downlink_rssi_dbm: -i16::from(p[7]),
            downlink_link_quality_pct: p[8],
            downlink_snr_db: i8::from_le_bytes([p[9]]),
        }
    }
}

/// A decoded frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CrsfFrame {
    /// RC channels.
    RcChannels(RcChannels),
    /// Link statistics.
    LinkStatistics(LinkStatistics),
}

/// What can go wrong in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CrsfError {
    /// The CRC did not match.
    Crc {
        /// CRC computed over type + payload.
        computed: u8,
        /// CRC byte received.
        received: u8,
    },
    /// The length byte was outside 2..=62.
    Length {
        /// The length byte received.
        length: u8,
    },
    /// A known frame type had the wrong payload length (the CRC matched).
    PayloadLength {
        /// Frame type.
        frame_type: u8,
        /// Payload length received, bytes.
        length: u8,
    },
    /// The frame was cut short ([`CrsfParser::reset`] called mid-frame).
    Truncated {
        /// Bytes of the frame received (including address and length).
        received: u8,
        /// Bytes the frame should have had.
        expected: u8,
    },
}

/// Parser counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CrsfStats {
    /// Frames with a matching CRC (decoded or skipped).
    pub good_frames: u32,
    /// RC channel frames decoded.
    pub rc_frames: u32,
    /// Link statistics frames decoded.
    pub link_statistics_frames: u32,
    /// Good frames of other types, skipped.
    pub other_frames: u32,
    /// CRC mismatches (including false frame starts found while resynchronising).
    pub crc_errors: u32,
    /// Length bytes out of range, and known types with a wrong payload length.
    pub length_errors: u32,
    /// Frames cut short by [`CrsfParser::reset`].
    pub truncated: u32,
    /// Bytes discarded while looking for a sync byte.
    pub discarded_bytes: u32,
}

/// Capacity of the input queue: a candidate frame plus the byte being pushed fit in 65 bytes
/// (see [`CrsfParser`]); 128 keeps the ring index a cheap mask.
const QUEUE_LEN: usize = 128;

/// Byte-at-a-time CRSF parser. No allocation, never panics.
///
/// Internally the pushed byte joins a small queue; bytes move from the queue into the current
/// candidate frame. When a candidate fails, its bytes after the first go back to the front of
/// the queue and are parsed again. Each failure or success discards at least one byte, so the
/// candidate plus the queue never hold more than 65 bytes.
#[derive(Debug, Clone)]
pub struct CrsfParser {
    frame: [u8; FRAME_MAX],
    frame_len: usize,
    queue: [u8; QUEUE_LEN],
    queue_head: usize,
    queue_len: usize,
    stats: CrsfStats,
}

impl Default for CrsfParser {
    fn default() -> Self {
        Self::new()
    }
}

impl CrsfParser {
    /// A parser waiting for a sync byte.
    pub const fn new() -> Self {
        Self {
            frame: [0; FRAME_MAX],
            frame_len: 0,
            queue: [0; QUEUE_LEN],
            queue_head: 0,
            queue_len: 0,
            stats: CrsfStats {
                good_frames: 0,
                rc_frames: 0,
                link_statistics_frames: 0,
                other_frames: 0,
                crc_errors: 0,
                length_errors: 0,
                truncated: 0,
                discarded_bytes: 0,
            },
        }
    }

    /// The counters.
    pub fn stats(&self) -> CrsfStats {
        self.stats
    }

    /// Whether `byte` is an accepted address/sync byte.
    pub const fn is_sync(byte: u8) -> bool {
        matches!(byte, SYNC_FLIGHT_CONTROLLER | SYNC_TRANSMITTER | SYNC_HANDSET)
    }

    /// Feed one received byte. Returns a decoded frame or an error when one completes; `None`
    /// otherwise (including for good frames of types not decoded, which are counted). If a
    /// single byte completes several things (after resynchronising), the first is returned
    /// now and the rest on the following calls; all are counted.
    pub fn push(&mut self, byte: u8) -> Option<Result<CrsfFrame, CrsfError>> {
        if self.queue_len >= QUEUE_LEN {
            // Cannot happen (see the type's documentation); drop the oldest byte defensively.
            self.pop_front();
            self.stats.discarded_bytes = self.stats.discarded_bytes.saturating_add(1);
        }
        let tail = (self.queue_head + self.queue_len) % QUEUE_LEN;
        self.queue[tail] = byte;
        self.queue_len += 1;
        while let Some(b) = self.pop_front() {
            if let Some(event) = self.step(b) {
                return Some(event);
            }
        }
        None
    }

    /// The next event already decidable from the bytes queued for re-parsing, without a new
    /// byte: when one [`CrsfParser::push`] completes several events (a failed candidate, then a
    /// good frame found while resynchronising), call this until `None` to take them all now.
    pub fn next_event(&mut self) -> Option<Result<CrsfFrame, CrsfError>> {
        while let Some(b) = self.pop_front() {
            if let Some(event) = self.step(b) {
                return Some(event);
            }
        }
        None
    }

    /// Abandon the frame in progress (call on an inter-byte timeout the board detects, e.g. UART
    /// idle line). Returns [`CrsfError::Truncated`] if a frame was in progress; also clears any
    /// bytes queued for re-parsing.
    pub fn reset(&mut self) -> Option<CrsfError> {
        let in_progress = self.frame_len;
        let expected = if in_progress >= 2 { self.frame[1].saturating_add(2) } else { 0 };
        self.frame_len = 0;
        self.queue_len = 0;
        self.queue_head = 0;
        if in_progress > 0 {
            self.stats.truncated = self.stats.truncated.saturating_add(1);
            Some(CrsfError::Truncated { received: in_progress as u8, expected })
        } else {
            None
        }
    }

    fn pop_front(&mut self) -> Option<u8> {
        if self.queue_len == 0 {
            return None;
        }
        let b = self.queue[self.queue_head];
        self.queue_head = (self.queue_head + 1) % QUEUE_LEN;
        self.queue_len -= 1;
        Some(b)
    }

    /// Put the candidate frame's bytes `from..` back at the front of the queue and drop the
    /// candidate.
    fn requeue_candidate(&mut self, from: usize) {
        let end = self.frame_len;
        self.frame_len = 0;
        if from >= end {
            return;
        }
        for i in (from..end).rev() {
            if self.queue_len >= QUEUE_LEN {
                break;
            }
            self.queue_head = (self.queue_head + QUEUE_LEN - 1) % QUEUE_LEN;
            self.queue[self.queue_head] = self.frame[i];
            self.queue_len += 1;
        }
    }

    fn step(&mut self, byte: u8) -> Option<Result<CrsfFrame, CrsfError>> {
        match self.frame_len {
            0 => {
                if Self::is_sync(byte) {
                    self.frame[0] = byte;
                    self.frame_len = 1;
                } else {
                    self.stats.discarded_bytes = self.stats.discarded_bytes.saturating_add(1);
                }
                None
            }
            1 => {
                self.frame[1] = byte;
                self.frame_len = 2;
                if (LENGTH_MIN..=LENGTH_MAX).contains(&byte) {
                    None
                } else {
                    self.stats.length_errors = self.stats.length_errors.saturating_add(1);
                    // The length byte may itself be the next sync byte: parse it again.
                    self.requeue_candidate(1);
                    Some(Err(CrsfError::Length { length: byte }))
                }
            }
            n => {
                if n >= FRAME_MAX {
                    // Unreachable: a frame completes at its length. Drop it defensively.
                    self.frame_len = 0;
                    return None;
                }
                self.frame[n] = byte;
                self.frame_len = n + 1;
                if self.frame_len == usize::from(self.frame[1]) + 2 {
                    self.finish()
                } else {
                    None
                }
            }
        }
    }

    fn finish(&mut self) -> Option<Result<CrsfFrame, CrsfError>> {
        let len = self.frame_len;
        let body = &self.frame[2..len - 1];
        let computed = crc8_dvb_s2(body);
        let received = self.frame[len - 1];
        if computed != received {
            self.stats.crc_errors = self.stats.crc_errors.saturating_add(1);
            self.requeue_candidate(1);
            return Some(Err(CrsfError::Crc { computed, received }));
        }
        self.stats.good_frames = self.stats.good_frames.saturating_add(1);
        let frame_type = self.frame[2];
        let payload = &self.frame[3..len - 1];
        self.frame_len = 0;
        let result = match frame_type {
            TYPE_RC_CHANNELS_PACKED => match <&[u8; RC_CHANNELS_PAYLOAD_LEN]>::try_from(payload) {
                Ok(p) => {
                    self.stats.rc_frames = self.stats.rc_frames.saturating_add(1);
                    Ok(CrsfFrame::RcChannels(RcChannels::unpack(p)))
                }
                Err(_) => Err(payload.len()),
            },
            TYPE_LINK_STATISTICS => match <&[u8; LINK_STATISTICS_PAYLOAD_LEN]>::try_from(payload) {
                Ok(p) => {
                    self.stats.link_statistics_frames =
                        self.stats.link_statistics_frames.saturating_add(1);
                    Ok(CrsfFrame::LinkStatistics(LinkStatistics::decode(p)))
                }
                Err(_) => Err(payload.len()),
            },
            _ => {
                self.stats.other_frames = self.stats.other_frames.saturating_add(1);
                return None;
            }
        };
        Some(result.map_err(|length| {
            self.stats.length_errors = self.stats.length_errors.saturating_add(1);
            CrsfError::PayloadLength { frame_type, length: length as u8 }
        }))
    }
}

/// One two-position switch: a channel and the pulse width above which it counts as on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwitchConfig {
    /// Channel index, 0-based (channel 5 on the radio = index 4).
    pub channel: usize,
    /// The switch is on when the channel is above this, µs.
    pub on_above_us: f32,
}

/// Switch assignment and failsafe timing of the RC link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RcLinkConfig {
    /// Arm switch.
    pub arm: SwitchConfig,
    /// Throw-to-fly switch (only meaningful with the arm switch on).
    pub throw_to_fly: SwitchConfig,
    /// Kill switch (wins over everything but the failsafe).
    pub kill: SwitchConfig,
    /// Land switch (with the arm switch on: a flying craft lands).
    pub land: SwitchConfig,
    /// Flight-mode switch: on, position mode (when a pose is fresh); off, angle mode.
    pub mode: SwitchConfig,
    /// The sticks' channels.
    pub sticks: StickMap,
    /// Failsafe after this long without a good RC channels frame, µs.
    pub failsafe_timeout_us: u64,
}

/// Default failsafe timeout: 250 ms without RC frames (ExpressLRS sends at 50..=1000 Hz, so this
/// is many missed packets).
pub const DEFAULT_FAILSAFE_TIMEOUT_US: u64 = 250_000;
/// Default switch threshold, µs (between a centred 1500 µs and a high 2012 µs).
pub const DEFAULT_SWITCH_ON_ABOVE_US: f32 = 1_700.0;

impl Default for RcLinkConfig {
    /// Arm on channel 5 (index 4), throw-to-fly on channel 6 (index 5), kill on channel 7
    /// (index 6), land on channel 8 (index 7), all on above 1700 µs; the mode switch on channel
    /// 9 (index 8), position mode above 1500 µs; sticks AETR on channels 1–4; failsafe after
    /// 250 ms.
    fn default() -> Self {
        Self {
            arm: SwitchConfig { channel: 4, on_above_us: DEFAULT_SWITCH_ON_ABOVE_US },
            throw_to_fly: SwitchConfig { channel: 5, on_above_us: DEFAULT_SWITCH_ON_ABOVE_US },
            kill: SwitchConfig { channel: 6, on_above_us: DEFAULT_SWITCH_ON_ABOVE_US },
            land: SwitchConfig { channel: 7, on_above_us: DEFAULT_SWITCH_ON_ABOVE_US },
            mode: SwitchConfig { channel: 8, on_above_us: DEFAULT_MODE_ON_ABOVE_US },
            sticks: StickMap::AETR,
            failsafe_timeout_us: DEFAULT_FAILSAFE_TIMEOUT_US,
        }
    }
}

/// Pulse width above which the mode switch asks for position mode, µs: below a three-position
/// switch's middle (1500 µs), so its upper two positions and a two-position switch's upper one
/// select position mode, its lowest angle mode.
pub const DEFAULT_MODE_ON_ABOVE_US: f32 = 1_400.0;

/// Which channel (0-based) carries each stick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct StickMap {
    pub roll: u8,
    pub pitch: u8,
    pub throttle: u8,
    pub yaw: u8,
}

impl StickMap {
    /// Aileron, elevator, throttle, rudder on channels 1–4 (ExpressLRS's and Betaflight's
    /// default).
    pub const AETR: Self = Self { roll: 0, pitch: 1, throttle: 2, yaw: 3 };

    /// The map from 1-based channel numbers in the order roll, pitch, throttle, yaw (the
    /// `rc_map` parameter); `None` when one is outside 1–16 or two are the same.
    pub fn from_channels(channels: [u8; 4]) -> Option<Self> {
        let distinct = (0..4).all(|i| (i + 1..4).all(|j| channels[i] != channels[j]));
        let valid = channels.iter().all(|&c| (1..=CHANNEL_COUNT as u8).contains(&c));
        (distinct && valid).then(|| {
            let [roll, pitch, throttle, yaw] = channels.map(|c| c - 1);
            Self { roll, pitch, throttle, yaw }
        })
    }
}

/// The pilot's sticks and mode switch, each stick normalised to −1..1 (1000–2000 µs, 1500 µs
/// centred): roll right, pitch forward (nose down), throttle up and yaw right are positive.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StickInput {
    pub roll: f32,
    pub pitch: f32,
    pub throttle: f32,
    pub yaw: f32,
    /// The mode switch asks for position mode.
    pub position_mode: bool,
}

/// An invalid [`RcLinkConfig`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RcConfigError {
    /// A switch channel index is 16 or more.
    ChannelOutOfRange {
        /// The index given.
        channel: usize,
    },
    /// A threshold is not finite.
    ThresholdNotFinite,
}

/// What the pilot asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PilotRequest {
    /// Arm switch off.
    Disarmed,
    /// Arm switch on, throw-to-fly off.
    Armed,
    /// Arm switch and throw-to-fly switch on: arm the throw detector.
    ThrowToFly,
    /// Kill switch on: stop the motors now, whatever the other switches say.
    Kill,
    /// Arm switch and land switch on: land (a flying craft descends and disarms at the
    /// touchdown).
    Land,
    /// No good RC frame for the failsafe timeout (or never): the switches are unknown.
    Failsafe,
}

/// The pilot's RC link: the latest channels, when they arrived, and the switch mapping.
///
/// This maps switch positions to a request and nothing more; arming interlocks (e.g. the arm
/// switch must be seen off before arming) belong to the application.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RcLink {
    config: RcLinkConfig,
    channels: Option<RcChannels>,
    last_frame_us: u64,
}

impl RcLink {
    /// A link with no frame yet (in failsafe until the first RC frame).
    pub fn new(config: RcLinkConfig) -> Result<Self, RcConfigError> {
        for switch in [config.arm, config.throw_to_fly, config.kill, config.land, config.mode] {
            if switch.channel >= CHANNEL_COUNT {
                return Err(RcConfigError::ChannelOutOfRange { channel: switch.channel });
            }
            if !switch.on_above_us.is_finite() {
                return Err(RcConfigError::ThresholdNotFinite);
            }
        }
        let sticks = config.sticks;
        if let Some(&channel) = [sticks.roll, sticks.pitch, sticks.throttle, sticks.yaw]
            .iter()
            .find(|&&c| usize::from(c) >= CHANNEL_COUNT)
        {
            return Err(RcConfigError::ChannelOutOfRange { channel: usize::from(channel) });
        }
        Ok(Self { config, channels: None, last_frame_us: 0 })
    }

    /// Take other stick and mode-switch channels (the `rc_map` and `rc_mode_channel`
    /// parameters); channels beyond the 16 of a frame are ignored.
    pub fn set_stick_channels(&mut self, sticks: StickMap, mode_channel: u8) {
        let all = [sticks.roll, sticks.pitch, sticks.throttle, sticks.yaw, mode_channel];
        if all.iter().all(|&c| usize::from(c) < CHANNEL_COUNT) {
            self.config.sticks = sticks;
            self.config.mode.channel = usize::from(mode_channel);
        }
    }

    /// The sticks and the mode switch at `now_us`, while the link is fresh.
    pub fn sticks(&self, now_us: u64) -> Option<StickInput> {
        let channels = self.channels(now_us)?;
        let map = self.config.sticks;
        let stick = |channel: u8| channels.normalised(usize::from(channel)).unwrap_or(0.0);
        let mode = self.config.mode;
        Some(StickInput {
            roll: stick(map.roll),
            pitch: stick(map.pitch),
            throttle: stick(map.throttle),
            yaw: stick(map.yaw),
            position_mode: channels.us(mode.channel).is_some_and(|us| us > mode.on_above_us),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &RcLinkConfig {
        &self.config
    }

    /// Record a good RC channels frame received at `now_us` (caller's monotonic clock, µs).
    pub fn on_channels(&mut self, channels: &RcChannels, now_us: u64) {
        self.channels = Some(*channels);
        self.last_frame_us = now_us;
    }

    /// The latest channels, if they are fresh at `now_us`.
    pub fn channels(&self, now_us: u64) -> Option<&RcChannels> {
        if self.is_fresh(now_us) {
            self.channels.as_ref()
        } else {
            None
        }
    }

    /// Whether a good RC frame arrived within the failsafe timeout before `now_us`. A clock that
    /// went backwards counts as fresh (elapsed time 0).
    pub fn is_fresh(&self, now_us: u64) -> bool {
        self.channels.is_some()
            && now_us.saturating_sub(self.last_frame_us) < self.config.failsafe_timeout_us
    }

    /// What the pilot asks for at `now_us`. Priority: failsafe, kill, arm off, land,
    /// throw-to-fly.
    pub fn request(&self, now_us: u64) -> PilotRequest {
        let Some(channels) = self.channels(now_us) else {
            return PilotRequest::Failsafe;
        };
        let on = |switch: SwitchConfig| {
            channels.us(switch.channel).is_some_and(|us| us > switch.on_above_us)
        };
        if on(self.config.kill) {
            PilotRequest::Kill
        } else if !on(self.config.arm) {
            PilotRequest::Disarmed
        } else if on(self.config.land) {
            PilotRequest::Land
        } else if on(self.config.throw_to_fly) {
            PilotRequest::ThrowToFly
        } else {
            PilotRequest::Armed
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent packer: writes channel bits one at a time, LSB first.
    fn pack_channels(values: &[u16; 16]) -> [u8; 22] {
        let mut out = [0u8; 22];
        let mut bit_pos = 0usize;
        for &v in values {
            for b in 0..11 {
                if (v >> b) & 1 == 1 {
                    out[bit_pos / 8] |= 1 << (bit_pos % 8);
                }
                bit_pos += 1;
            }
        }
        out
    }

    /// Independent bitwise CRC-8/DVB-S2 (MSB-first long division).
    fn reference_crc(data: &[u8]) -> u8 {
        let mut reg: u16 = 0;
        for &byte in data.iter().chain(core::iter::once(&0u8)) {
            for b in (0..8).rev() {
                reg = (reg << 1) | u16::from((byte >> b) & 1);
                if reg & 0x100 != 0 {
                    reg ^= 0x1D5;
                }
            }
        }
        reg as u8
    }

    /// Build a frame into a fixed buffer, returning (buffer, length).
    fn build_frame(frame_type: u8, payload: &[u8]) -> ([u8; 64], usize) {
        let mut buf = [0u8; 64];
        buf[0] = SYNC_FLIGHT_CONTROLLER;
        buf[1] = (payload.len() + 2) as u8;
        buf[2] = frame_type;
        buf[3..3 + payload.len()].copy_from_slice(payload);
        let crc = reference_crc(&buf[2..3 + payload.len()]);
        buf[3 + payload.len()] = crc;
        (buf, payload.len() + 4)
    }

    fn feed(
        parser: &mut CrsfParser,
        bytes: &[u8],
    ) -> ([Option<Result<CrsfFrame, CrsfError>>; 8], usize) {
        let mut events = [None; 8];
        let mut n = 0;
        for &b in bytes {
            if let Some(e) = parser.push(b) {
                if n < events.len() {
                    events[n] = Some(e);
                }
                n += 1;
            }
        }
        (events, n)
    }

    #[test]
    fn crc_matches_reference_and_check_value() {
        // CRC-8/DVB-S2 check value over "123456789" is 0xBC.
        assert_eq!(crc8_dvb_s2(b"123456789"), 0xBC);
        assert_eq!(reference_crc(b"123456789"), 0xBC);
        let data = [0x16u8, 0xE0, 0x03, 0x1F, 0x58, 0xC0, 0x07];
        assert_eq!(crc8_dvb_s2(&data), reference_crc(&data));
    }

    #[test]
    fn centred_channels_are_1500_us() {
        let payload = pack_channels(&[992; 16]);
        let (buf, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &payload);
        assert_eq!(len, 26);
        assert_eq!(buf[1], 24);
        let mut parser = CrsfParser::new();
        let (events, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 1);
        let Some(Ok(CrsfFrame::RcChannels(ch))) = events[0] else {
            panic!("expected channels, got {:?}", events[0]);
        };
        assert_eq!(ch.raw, [992; 16]);
        for i in 0..16 {
            assert_eq!(ch.us(i), Some(1500.0));
            assert_eq!(ch.normalised(i), Some(0.0));
        }
        assert_eq!(ch.us(16), None);
        assert_eq!(parser.stats().good_frames, 1);
        assert_eq!(parser.stats().rc_frames, 1);
    }

    #[test]
    fn distinct_channels_round_trip() {
        let mut values = [0u16; 16];
        for (i, v) in values.iter_mut().enumerate() {
            *v = 172 + 109 * i as u16; // 172, 281, ..., 1807
        }
        values[15] = 2047;
        values[14] = 0;
        let payload = pack_channels(&values);
        let (buf, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &payload);
        let mut parser = CrsfParser::new();
        let (events, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 1);
        assert_eq!(events[0], Some(Ok(CrsfFrame::RcChannels(RcChannels { raw: values }))));
        assert_eq!(channel_raw_to_us(172), 987.5);
        assert_eq!(channel_raw_to_us(1811), 2011.875);
        assert_eq!(channel_raw_to_normalised(172), -1.0);
        assert!((channel_raw_to_normalised(1811) - 0.999_756).abs() < 1e-5);
        assert_eq!(channel_raw_to_normalised(2047), 1.0);
    }

    #[test]
    fn flipped_bit_is_crc_error_and_counted() {
        let payload = pack_channels(&[992; 16]);
        let (mut buf, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &payload);
        buf[10] ^= 0x04;
        let mut parser = CrsfParser::new();
        let (events, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 1);
        assert!(matches!(events[0], Some(Err(CrsfError::Crc { .. }))));
        let s = parser.stats();
        assert_eq!((s.crc_errors, s.good_frames, s.length_errors), (1, 0, 0));
        // The parser recovers: the next good frame parses.
        let (buf, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &payload);
        let (events, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 1);
        assert!(matches!(events[0], Some(Ok(CrsfFrame::RcChannels(_)))));
    }

    #[test]
    fn truncated_frame_then_good_frame_without_reset() {
        let payload = pack_channels(&[992; 16]);
        let (good, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &payload);
        let mut parser = CrsfParser::new();
        // The first 11 bytes of a frame, then a complete frame.
        let (_, n) = feed(&mut parser, &good[..11]);
        assert_eq!(n, 0);
        let (events, n) = feed(&mut parser, &good[..len]);
        // The truncated candidate swallows part of the good frame and fails its CRC; the parser
        // re-parses from the good frame's sync byte and still delivers it.
        assert_eq!(n, 2, "{events:?}");
        assert!(matches!(events[0], Some(Err(CrsfError::Crc { .. }))));
        assert_eq!(events[1], Some(Ok(CrsfFrame::RcChannels(RcChannels { raw: [992; 16] }))));
        assert_eq!(parser.stats().good_frames, 1);
    }

    #[test]
    fn truncated_frame_then_good_frame_with_reset() {
        let payload = pack_channels(&[992; 16]);
        let (good, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &payload);
        let mut parser = CrsfParser::new();
        feed(&mut parser, &good[..11]);
        assert_eq!(parser.reset(), Some(CrsfError::Truncated { received: 11, expected: 26 }));
        assert_eq!(parser.reset(), None);
        let (events, n) = feed(&mut parser, &good[..len]);
        assert_eq!(n, 1);
        assert!(matches!(events[0], Some(Ok(CrsfFrame::RcChannels(_)))));
        let s = parser.stats();
        assert_eq!((s.truncated, s.crc_errors, s.good_frames), (1, 0, 1));
    }

    #[test]
    fn bad_length_then_resync() {
        let payload = pack_channels(&[992; 16]);
        let (good, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &payload);
        let mut parser = CrsfParser::new();
        // Sync, length 63 (out of range), then a good frame.
        let (events, n) = feed(&mut parser, &[0x00, SYNC_FLIGHT_CONTROLLER, 63]);
        assert_eq!(n, 1);
        assert_eq!(events[0], Some(Err(CrsfError::Length { length: 63 })));
        let (events, n) = feed(&mut parser, &good[..len]);
        assert_eq!(n, 1);
        assert!(matches!(events[0], Some(Ok(CrsfFrame::RcChannels(_)))));
        // Length 1 too.
        let (events, _) = feed(&mut parser, &[SYNC_FLIGHT_CONTROLLER, 1]);
        assert_eq!(events[0], Some(Err(CrsfError::Length { length: 1 })));
        // A stray sync byte right before a real frame: its "length" is the real sync byte
        // (0xC8 = 200, out of range) which is then taken as the start.
        let mut stream = [0u8; 27];
        stream[0] = SYNC_FLIGHT_CONTROLLER;
        stream[1..].copy_from_slice(&good[..len]);
        let (events, n) = feed(&mut parser, &stream);
        assert_eq!(n, 2);
        assert_eq!(events[0], Some(Err(CrsfError::Length { length: 0xC8 })));
        assert!(matches!(events[1], Some(Ok(CrsfFrame::RcChannels(_)))));
        let s = parser.stats();
        // Discarded: the leading 0x00 and the two rejected length bytes (63 and 1).
        assert_eq!((s.length_errors, s.good_frames, s.discarded_bytes), (3, 2, 3));
    }

    #[test]
    fn link_statistics_decode() {
        let payload = [70u8, 95, 100, 0xF6, 1, 7, 3, 60, 98, 12];
        let (buf, len) = build_frame(TYPE_LINK_STATISTICS, &payload);
        assert_eq!(buf[1], 12);
        let mut parser = CrsfParser::new();
        let (events, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 1);
        assert_eq!(
            events[0],
            Some(Ok(CrsfFrame::LinkStatistics(LinkStatistics {
                uplink_rssi_ant1_dbm: -70,
                uplink_rssi_ant2_dbm: -95,
                uplink_link_quality_pct: 100,
                uplink_snr_db: -10,
                active_antenna: 1,
                rf_mode: 7,
                uplink_tx_power_index: 3,
                downlink_rssi_dbm: -60,
                downlink_link_quality_pct: 98,
                downlink_snr_db: 12,
            })))
        );
        assert_eq!(parser.stats().link_statistics_frames, 1);
    }

    #[test]
    fn other_types_counted_and_skipped_and_wrong_payload_length() {
        let mut parser = CrsfParser::new();
        // Battery sensor (0x08), 8 bytes: good CRC, skipped.
        let (buf, len) = build_frame(0x08, &[0, 1, 2, 3, 4, 5, 6, 7]);
        let (_, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 0);
        // Link statistics with 9 bytes: payload length error.
        let (buf, len) = build_frame(TYPE_LINK_STATISTICS, &[0; 9]);
        let (events, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 1);
        assert_eq!(
            events[0],
            Some(Err(CrsfError::PayloadLength { frame_type: TYPE_LINK_STATISTICS, length: 9 }))
        );
        let s = parser.stats();
        assert_eq!((s.other_frames, s.good_frames, s.length_errors), (1, 2, 1));
    }

    #[test]
    fn arbitrary_bytes_never_panic_and_stay_bounded() {
        let mut parser = CrsfParser::new();
        let mut x: u32 = 0x1234_5678;
        for i in 0..200_000u32 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            // Bias toward sync bytes and plausible lengths to exercise resynchronisation.
            let byte = match i % 7 {
                0 => SYNC_FLIGHT_CONTROLLER,
                1 => (x % 64) as u8,
                _ => (x >> 8) as u8,
            };
            let _ = parser.push(byte);
            assert!(parser.queue_len + parser.frame_len <= 65);
        }
        // Still parses a good frame afterwards (after an idle-line reset).
        parser.reset();
        let (buf, len) = build_frame(TYPE_RC_CHANNELS_PACKED, &pack_channels(&[1000; 16]));
        let (events, n) = feed(&mut parser, &buf[..len]);
        assert_eq!(n, 1);
        assert!(matches!(events[0], Some(Ok(CrsfFrame::RcChannels(_)))));
    }

    fn channels_with(arm_us: f32, throw_us: f32, kill_us: f32) -> RcChannels {
        let to_raw = |us: f32| (992.0 + (us - 1500.0) * 1.6) as u16;
        let mut raw = [992u16; 16];
        raw[4] = to_raw(arm_us);
        raw[5] = to_raw(throw_us);
        raw[6] = to_raw(kill_us);
        RcChannels { raw }
    }

    #[test]
    fn failsafe_after_250_ms() {
        let mut link = RcLink::new(RcLinkConfig::default()).unwrap();
        assert_eq!(link.request(0), PilotRequest::Failsafe);
        link.on_channels(&channels_with(2000.0, 1000.0, 1000.0), 1_000_000);
        assert_eq!(link.request(1_000_000), PilotRequest::Armed);
        assert_eq!(link.request(1_249_999), PilotRequest::Armed);
        assert_eq!(link.request(1_250_000), PilotRequest::Failsafe);
        assert!(link.channels(1_250_000).is_none());
        // Clock going backwards: still fresh, no panic.
        assert_eq!(link.request(10), PilotRequest::Armed);
        // A new frame ends the failsafe.
        link.on_channels(&channels_with(1000.0, 1000.0, 1000.0), 2_000_000);
        assert_eq!(link.request(2_100_000), PilotRequest::Disarmed);
    }

    #[test]
    fn switch_mapping_and_kill_wins() {
        let mut link = RcLink::new(RcLinkConfig::default()).unwrap();
        let t = 5_000;
        link.on_channels(&channels_with(2000.0, 2000.0, 2000.0), t);
        assert_eq!(link.request(t), PilotRequest::Kill);
        link.on_channels(&channels_with(2000.0, 1000.0, 2000.0), t);
        assert_eq!(link.request(t), PilotRequest::Kill);
        link.on_channels(&channels_with(2000.0, 2000.0, 1000.0), t);
        assert_eq!(link.request(t), PilotRequest::ThrowToFly);
        link.on_channels(&channels_with(1000.0, 2000.0, 1000.0), t);
        assert_eq!(link.request(t), PilotRequest::Disarmed);
        link.on_channels(&channels_with(1500.0, 1000.0, 1500.0), t);
        assert_eq!(link.request(t), PilotRequest::Disarmed);
        link.on_channels(&channels_with(1800.0, 1000.0, 1000.0), t);
        assert_eq!(link.request(t), PilotRequest::Armed);
    }

    #[test]
    fn config_validation() {
        let mut config = RcLinkConfig::default();
        config.kill.channel = 16;
        assert_eq!(RcLink::new(config), Err(RcConfigError::ChannelOutOfRange { channel: 16 }));
        let mut config = RcLinkConfig::default();
        config.arm.on_above_us = f32::NAN;
        assert_eq!(RcLink::new(config), Err(RcConfigError::ThresholdNotFinite));
    }

    #[test]
    fn packed_channels_encode_to_a_frame_the_parser_reads_back() {
        let mut raw = [0u16; CHANNEL_COUNT];
        for (i, value) in raw.iter_mut().enumerate() {
            *value = (172 + 109 * i as u16) & 0x7FF;
        }
        raw[4] = RcChannels::raw_from_us(2000.0);
        let channels = RcChannels { raw };
        let mut out = [0u8; FRAME_MAX];
        let n = encode_frame(
            SYNC_FLIGHT_CONTROLLER,
            TYPE_RC_CHANNELS_PACKED,
            &channels.pack(),
            &mut out,
        )
        .unwrap();
        assert_eq!(n, 26, "sync, length, type, 22 payload bytes, CRC");
        assert_eq!(out[1], 24);
        let mut parser = CrsfParser::new();
        let mut decoded = None;
        for &byte in &out[..n] {
            if let Some(event) = parser.push(byte) {
                decoded = Some(event);
            }
        }
        match decoded {
            Some(Ok(CrsfFrame::RcChannels(back))) => {
                assert_eq!(back, channels);
                assert!((back.us(4).unwrap() - 2000.0).abs() <= 0.625);
            }
            other => panic!("expected the channels back, got {other:?}"),
        }
        // A payload longer than a frame allows, or no room: refused.
        assert_eq!(encode_frame(SYNC_FLIGHT_CONTROLLER, 0x21, &[0; 61], &mut [0u8; 128]), None);
        assert_eq!(encode_frame(SYNC_FLIGHT_CONTROLLER, 0x21, &[0; 4], &mut [0u8; 7]), None);
    }

    #[test]
    fn handset_telemetry_frames_have_the_specified_layout_and_decode_back() {
        let mut out = [0u8; FRAME_MAX];
        // Attitude: 0.5 rad pitch = 5000 counts, −1 rad roll, 3 rad yaw; big-endian i16.
        let attitude = HandsetTelemetry::Attitude { pitch_rad: 0.5, roll_rad: -1.0, yaw_rad: 3.0 };
        let n = attitude.encode(&mut out).unwrap();
        assert_eq!(&out[..3], &[SYNC_FLIGHT_CONTROLLER, 8, TYPE_ATTITUDE]);
        assert_eq!(&out[3..9], &[0x13, 0x88, 0xD8, 0xF0, 0x75, 0x30]);
        assert_eq!(out[9], crc8_dvb_s2(&out[2..9]));
        assert_eq!(n, 10);
        match HandsetTelemetry::decode(&out[..n]).unwrap() {
            HandsetTelemetry::Attitude { pitch_rad, roll_rad, yaw_rad } => {
                assert!((pitch_rad - 0.5).abs() < 1e-4 && (roll_rad + 1.0).abs() < 1e-4);
                assert!((yaw_rad - 3.0).abs() < 1e-4);
            }
            other => panic!("{other:?}"),
        }
        // Battery: 25.2 V = 0x00FC, 18.9 A = 0x00BD, 2199 mAh = 0x000897, 20 %.
        let battery = HandsetTelemetry::Battery {
            voltage_v: 25.2,
            current_a: 18.9,
            used_mah: 2199,
            remaining_pct: 20,
        };
        let n = battery.encode(&mut out).unwrap();
        assert_eq!(&out[..3], &[SYNC_FLIGHT_CONTROLLER, 10, TYPE_BATTERY_SENSOR]);
        assert_eq!(&out[3..11], &[0x00, 0xFC, 0x00, 0xBD, 0x00, 0x08, 0x97, 20]);
        assert_eq!(HandsetTelemetry::decode(&out[..n]).unwrap(), battery);
        // Flight mode: the text and a terminating zero.
        let mode = HandsetTelemetry::FlightMode(heapless::String::try_from("EXCITE 3/4").unwrap());
        let n = mode.encode(&mut out).unwrap();
        assert_eq!(&out[..3], &[SYNC_FLIGHT_CONTROLLER, 13, TYPE_FLIGHT_MODE]);
        assert_eq!(&out[3..14], b"EXCITE 3/4\0");
        assert_eq!(HandsetTelemetry::decode(&out[..n]).unwrap(), mode);
        // A flipped bit is a CRC error; a short attitude payload a length error.
        out[5] ^= 1;
        assert!(matches!(HandsetTelemetry::decode(&out[..n]), Err(CrsfError::Crc { .. })));
        let n = encode_frame(SYNC_FLIGHT_CONTROLLER, TYPE_ATTITUDE, &[0; 4], &mut out).unwrap();
        assert!(matches!(
            HandsetTelemetry::decode(&out[..n]),
            Err(CrsfError::PayloadLength { frame_type: TYPE_ATTITUDE, length: 4 })
        ));
    }
}
