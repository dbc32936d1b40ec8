//! A lockstep bridge for external simulators, modelled on Betaflight's SITL, extended to m motors.
//!
//! The external simulator owns the physics; this side runs the flight application. Each step the
//! simulator sends one *sensor packet* (IMU sample, motor speeds, time) over UDP to
//! 127.0.0.1:[`DEFAULT_FC_PORT`]; the bridge runs exactly one application step on it and answers
//! with one *motor packet* (commands δ for m motors) to the packet's source address. Nothing
//! happens between packets, so the two sides advance in lockstep at whatever pace the simulator
//! sets (faster or slower than real time). Betaflight's SITL uses the same two ports (9003 in,
//! 9002 out); a simulator that binds 9002 and sends to 9003 works unchanged with both.
//!
//! The byte layouts (little-endian, fixed-size, versioned) are in `docs/sim-bridge.md` and in
//! [`SensorPacket`] and [`MotorPacket`]. Version 2 lets the sensor packet carry an external pose
//! (what motion capture would give the board), a GNSS receiver's solution ([`GnssSolution`]:
//! what a u-blox receiver would send it, which the bridge encodes as the receiver's NAV-PVT
//! bytes and hands to the firmware's own driver, as the board's GNSS UART would) and the field a
//! compass measures (written into a simulated IST8310's registers, which the firmware's own
//! compass service reads over its I²C driver, as on the board: [`BridgeServer::step`]); version
//! 1 packets stay valid.
//!
//! [`serve_firmware`] is the loop behind `scenario bridge`: the firmware application behind the
//! bridge, optionally serving the configurator protocol on TCP meanwhile.

use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::time::{Duration, Instant};

use firmware::app::compass::CompassCalibration;
use firmware::app::hal::{Imu, ImuSample, Motors, MAX_MOTORS};
use firmware::app::ControlCommand;
use firmware::drivers::compass::I2cRegisterBus;
use firmware::drivers::ubx::{FixType, GnssConfig, GnssFix};
use nalgebra::UnitQuaternion;
use protocol::{ExternalPose, LearnerFailure};

use crate::board::{CONTROL_PERIOD_US, CONTROL_RATE_HZ};
use crate::compass_chip::{ChipKind, CountingDelay, Nack, SimCompassChip};
use crate::gnss::BoardGnss;
use crate::radio::RcTransmitter;
use crate::scenario::{AroundFirmware, AroundStep, FirmwareApp, FlightApp};
use crate::serve::TcpLinks;

/// Port the flight-application side listens on (Betaflight SITL's FDM input port).
pub const DEFAULT_FC_PORT: u16 = 9003;
/// Port an external simulator usually listens on (Betaflight SITL's motor output port).
pub const DEFAULT_SIM_PORT: u16 = 9002;
/// Highest bridge version this side speaks (byte 4 of both packets); every version from
/// [`MIN_BRIDGE_VERSION`] up is accepted.
pub const BRIDGE_VERSION: u8 = 2;
/// Oldest bridge version accepted.
pub const MIN_BRIDGE_VERSION: u8 = 1;
/// Sensor-packet flag (version 2 and later): an external pose follows the motor speeds.
pub const FLAG_POSE: u16 = 1 << 0;
/// Length of the external pose in a sensor packet, bytes: position NED (3 × f32, m) and
/// heading (f32, rad).
pub const POSE_LEN: usize = 16;
/// Sensor-packet flag (version 2 and later): a GNSS solution ([`GnssSolution`]) follows the
/// motor speeds, after the pose when both are present.
pub const FLAG_GNSS: u16 = 1 << 1;
/// Length of the GNSS solution in a sensor packet, bytes ([`GnssSolution`]).
pub const GNSS_LEN: usize = 52;
/// Sensor-packet flag (version 2 and later): the magnetic field the compass measures follows,
/// after the pose and the GNSS solution when they are present.
pub const FLAG_MAGNETOMETER: u16 = 1 << 2;
/// Length of the magnetometer block in a sensor packet, bytes: the field, IMU axes (3 × f32,
/// µT).
pub const MAGNETOMETER_LEN: usize = 12;
/// The compass chip the magnetometer blocks are written into: an IST8310 (0.3 µT/LSB, valid
/// within ±1600 µT on x and y and ±2500 µT on z), at the address of a GNSS mast's (0x0E), the
/// chip the firmware probes first.
pub const BRIDGE_COMPASS_CHIP: ChipKind = ChipKind::Ist8310;
/// Magic of the sensor packet, bytes 0–3 (ASCII).
pub const SENSOR_MAGIC: [u8; 4] = *b"FCSN";
/// Magic of the motor packet, bytes 0–3 (ASCII).
pub const MOTOR_MAGIC: [u8; 4] = *b"FCMO";
/// Sensor packet header length before the motor speeds, bytes.
pub const SENSOR_HEADER_LEN: usize = 48;
/// Motor packet header length before the commands, bytes.
pub const MOTOR_HEADER_LEN: usize = 16;
/// Longest packet, bytes (version-2 sensor packet with 8 motors, a pose, a GNSS solution and a
/// magnetometer block).
pub const MAX_PACKET_LEN: usize =
    SENSOR_HEADER_LEN + 4 * MAX_MOTORS + POSE_LEN + GNSS_LEN + MAGNETOMETER_LEN;

/// Why a packet or an exchange failed.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// Socket error.
    #[error("bridge socket: {0}")]
    Io(std::io::Error),
    /// Nothing arrived in time.
    #[error("no packet within {0:?}")]
    Timeout(Duration),
    /// The packet is shorter than its header, its motor count, or the optional blocks its flags
    /// announce (pose, GNSS solution, magnetometer) need.
    #[error("packet of {len} bytes is too short: {need} bytes needed")]
    TooShort {
        /// Received length.
        len: usize,
        /// Needed length.
        need: usize,
    },
    /// Wrong magic (not a bridge packet, or the other packet type).
    #[error("bad magic {0:?}: expected {1:?}")]
    BadMagic([u8; 4], [u8; 4]),
    /// Unsupported version.
    #[error(
        "bridge version {0} is not supported (this side speaks {MIN_BRIDGE_VERSION} to \
         {BRIDGE_VERSION})"
    )]
    Version(u8),
    /// Motor count outside 1..=8.
    #[error("motor count {0} is out of range: allowed [1, {MAX_MOTORS}]")]
    MotorCount(u8),
}

impl From<std::io::Error> for BridgeError {
    fn from(error: std::io::Error) -> Self {
        Self::Io(error)
    }
}

/// Simulator → application, `48 + 4m` bytes, `+ 16` with a pose, `+ 52` with a GNSS solution,
/// `+ 12` with a magnetometer block.
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | `[u8; 4]` | magic `"FCSN"` |
/// | 4 | `u8` | version (1 or 2) |
/// | 5 | `u8` | motor count m (1–8) |
/// | 6 | `u16` | flags: bit 0 ([`FLAG_POSE`]) = a pose follows, bit 1 ([`FLAG_GNSS`]) = a GNSS solution follows, bit 2 ([`FLAG_MAGNETOMETER`]) = a magnetometer block follows (version 2; ignored in version 1) |
/// | 8 | `u64` | sequence number, echoed in the reply |
/// | 16 | `f64` | simulation time, s |
/// | 24 | `f32 × 3` | gyro, rad/s, IMU axes |
/// | 36 | `f32 × 3` | specific force, m/s², IMU axes |
/// | 48 | `f32 × m` | motor speeds, rad/s; NaN = not reported |
/// | 48 + 4m | `f32 × 3` | with [`FLAG_POSE`]: position of the centre of gravity, world NED, m |
/// | 60 + 4m | `f32` | with [`FLAG_POSE`]: heading (yaw of the body frame about world z), rad |
/// | 48 + 4m (+ 16 after a pose) | 52 bytes | with [`FLAG_GNSS`]: the GNSS solution ([`GnssSolution`]) |
/// | 48 + 4m (+ 16 after a pose, + 52 after a GNSS solution) | `f32 × 3` | with [`FLAG_MAGNETOMETER`]: the magnetic field the compass measures, IMU axes, µT |
///
/// [`SensorPacket::encode`] writes version 2 when [`SensorPacket::pose`],
/// [`SensorPacket::gnss`] or [`SensorPacket::magnetometer_ut`] is set or
/// [`SensorPacket::version`] is 2 or more, version 1 otherwise; [`SensorPacket::decode`] fills
/// `version` from the packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorPacket {
    /// Version to write (1 or 2; a pose always makes it 2); as received when decoded.
    pub version: u8,
    /// Sequence number.
    pub sequence: u64,
    /// Simulation time, s.
    pub time_s: f64,
    /// The IMU sample.
    pub imu: ImuSample,
    /// Number of motors, 1..=8.
    pub motor_count: u8,
    /// Motor speeds, rad/s (`None` = not reported).
    pub speeds_rad_s: [Option<f32>; MAX_MOTORS],
    /// The external pose (version 2 with [`FLAG_POSE`]): motion capture's centre-of-gravity
    /// position and heading.
    pub pose: Option<ExternalPose>,
    /// A GNSS receiver's solution (version 2 with [`FLAG_GNSS`]). With the pose and the
    /// magnetometer block, the only measurements of the world that cross the bridge besides the
    /// IMU's and the motors', and only when sent.
    pub gnss: Option<GnssSolution>,
    /// The magnetic field the compass measures (version 2 with [`FLAG_MAGNETOMETER`]), µT, in
    /// the IMU's axes (the gyro's and the accelerometer's): the Earth's field plus whatever
    /// iron, motor interference and noise the simulator models. Decoded as sent, non-finite
    /// values included ([`BridgeServer::step`] does not use such a block).
    pub magnetometer_ut: Option<[f32; 3]>,
}

/// A GNSS receiver's navigation solution as the sensor packet carries it ([`FLAG_GNSS`]): the
/// fields of a u-blox UBX-NAV-PVT message the firmware uses, in SI units, 52 bytes. The bridge
/// writes it as the NAV-PVT frame a receiver would send ([`GnssSolution::to_nav_pvt`]) and feeds
/// the bytes to the firmware's own driver (`firmware::drivers::ubx`,
/// `firmware::app::gnss::GnssInput`), as the board's GNSS UART does.
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | `u32` | time of week of the solution's epoch, ms (NAV-PVT `iTOW`): a solution is taken once, whatever packets repeat it |
/// | 4 | `u8` | fix type (NAV-PVT `fixType`: 0 none, 2 2D, 3 3D, 4 GNSS + dead reckoning) |
/// | 5 | `u8` | flags: bit 0 = `gnssFixOK` (a fix within the receiver's limits); other bits reserved |
/// | 6 | `u8` | satellites used (`numSV`) |
/// | 7 | `u8` | reserved (0) |
/// | 8 | `f64` | latitude, degrees (WGS-84) |
/// | 16 | `f64` | longitude, degrees (WGS-84) |
/// | 24 | `f32` | height above the WGS-84 ellipsoid, m |
/// | 28 | `f32 × 3` | velocity north, east, down, m/s |
/// | 40 | `f32` | horizontal accuracy `hAcc`, m (the horizontal error's RMS) |
/// | 44 | `f32` | vertical accuracy `vAcc`, m (one standard deviation) |
/// | 48 | `f32` | speed accuracy `sAcc`, m/s (the 3D velocity error's RMS) |
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GnssSolution {
    /// Time of week of the solution's epoch, ms.
    pub time_of_week_ms: u32,
    /// NAV-PVT `fixType`.
    pub fix_type: FixType,
    /// NAV-PVT `gnssFixOK`.
    pub fix_ok: bool,
    /// Satellites used.
    pub satellites: u8,
    /// Latitude, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees.
    pub longitude_deg: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub height_ellipsoid_m: f32,
    /// Velocity north, east, down, m/s.
    pub velocity_ned_mps: [f32; 3],
    /// `hAcc`, m.
    pub horizontal_accuracy_m: f32,
    /// `vAcc`, m.
    pub vertical_accuracy_m: f32,
    /// `sAcc`, m/s.
    pub speed_accuracy_mps: f32,
}

/// [`GnssSolution`]'s flags, bit 0: `gnssFixOK`.
const GNSS_FLAG_FIX_OK: u8 = 1 << 0;

impl GnssSolution {
    /// The solution in a receiver's NAV-PVT: date and time valid and resolved, the position
    /// valid, `hMSL` the ellipsoidal height (the geoid's undulation unknown) and `pDOP` 0 (not
    /// given); the firmware uses neither. The frame then rounds as a receiver's does: 1e-7° of
    /// latitude and longitude, 1 mm and 1 mm/s.
    pub fn to_nav_pvt(&self) -> GnssFix {
        GnssFix {
            time_of_week_ms: self.time_of_week_ms,
            date_valid: true,
            time_valid: true,
            time_fully_resolved: true,
            fix_type: self.fix_type,
            gnss_fix_ok: self.fix_ok,
            position_invalid: false,
            satellites: self.satellites,
            latitude_deg: self.latitude_deg,
            longitude_deg: self.longitude_deg,
            height_ellipsoid_m: self.height_ellipsoid_m,
            height_msl_m: self.height_ellipsoid_m,
            horizontal_accuracy_m: self.horizontal_accuracy_m,
            vertical_accuracy_m: self.vertical_accuracy_m,
            velocity_ned_mps: self.velocity_ned_mps,
            speed_accuracy_mps: self.speed_accuracy_mps,
            position_dop: 0.0,
        }
    }

    /// The fields of a receiver's NAV-PVT that the block carries.
    pub fn from_nav_pvt(fix: &GnssFix) -> Self {
        Self {
            time_of_week_ms: fix.time_of_week_ms,
            fix_type: fix.fix_type,
            fix_ok: fix.gnss_fix_ok,
            satellites: fix.satellites,
            latitude_deg: fix.latitude_deg,
            longitude_deg: fix.longitude_deg,
            height_ellipsoid_m: fix.height_ellipsoid_m,
            velocity_ned_mps: fix.velocity_ned_mps,
            horizontal_accuracy_m: fix.horizontal_accuracy_m,
            vertical_accuracy_m: fix.vertical_accuracy_m,
            speed_accuracy_mps: fix.speed_accuracy_mps,
        }
    }

    fn encode(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.time_of_week_ms.to_le_bytes());
        out.extend_from_slice(&[
            self.fix_type.raw(),
            u8::from(self.fix_ok) * GNSS_FLAG_FIX_OK,
            self.satellites,
            0,
        ]);
        out.extend_from_slice(&self.latitude_deg.to_le_bytes());
        out.extend_from_slice(&self.longitude_deg.to_le_bytes());
        let floats = [self.height_ellipsoid_m].into_iter().chain(self.velocity_ned_mps).chain([
            self.horizontal_accuracy_m,
            self.vertical_accuracy_m,
            self.speed_accuracy_mps,
        ]);
        for v in floats {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// Reads the block at `at` (the caller checked the length).
    fn decode(bytes: &[u8], at: usize) -> Self {
        let f64_at = |offset: usize| {
            f64::from_le_bytes(bytes[at + offset..at + offset + 8].try_into().expect("8 bytes"))
        };
        let f32_at = |offset: usize| f32_at(bytes, at + offset);
        Self {
            time_of_week_ms: u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")),
            fix_type: FixType::from_raw(bytes[at + 4]),
            fix_ok: bytes[at + 5] & GNSS_FLAG_FIX_OK != 0,
            satellites: bytes[at + 6],
            latitude_deg: f64_at(8),
            longitude_deg: f64_at(16),
            height_ellipsoid_m: f32_at(24),
            velocity_ned_mps: [f32_at(28), f32_at(32), f32_at(36)],
            horizontal_accuracy_m: f32_at(40),
            vertical_accuracy_m: f32_at(44),
            speed_accuracy_mps: f32_at(48),
        }
    }
}

/// Application → simulator, `16 + 4m` bytes, the same layout in both versions.
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | `[u8; 4]` | magic `"FCMO"` |
/// | 4 | `u8` | version: that of the sensor packet answered (1 or 2) |
/// | 5 | `u8` | motor count m (1–8) |
/// | 6 | `u16` | flags, 0 (reserved) |
/// | 8 | `u64` | sequence number of the sensor packet answered |
/// | 16 | `f32 × m` | commands δ ∈ [0, 1] |
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorPacket {
    /// Version (1 or 2): the answered sensor packet's; written clamped to the versions spoken.
    pub version: u8,
    /// Sequence number of the sensor packet this answers.
    pub sequence: u64,
    /// Number of motors, 1..=8.
    pub motor_count: u8,
    /// Commands δ ∈ [0, 1] (first `motor_count` used).
    pub commands: [f32; MAX_MOTORS],
}

/// Checks magic, version, motor count and the length they need; returns (version, m).
fn check_header(
    bytes: &[u8],
    magic: [u8; 4],
    header_len: usize,
) -> Result<(u8, usize), BridgeError> {
    if bytes.len() < header_len {
        return Err(BridgeError::TooShort { len: bytes.len(), need: header_len });
    }
    let got: [u8; 4] = bytes[0..4].try_into().expect("4 bytes");
    if got != magic {
        return Err(BridgeError::BadMagic(got, magic));
    }
    let version = bytes[4];
    if !(MIN_BRIDGE_VERSION..=BRIDGE_VERSION).contains(&version) {
        return Err(BridgeError::Version(version));
    }
    let m = bytes[5];
    if m == 0 || m as usize > MAX_MOTORS {
        return Err(BridgeError::MotorCount(m));
    }
    let need = header_len + 4 * m as usize;
    if bytes.len() < need {
        return Err(BridgeError::TooShort { len: bytes.len(), need });
    }
    Ok((version, m as usize))
}

/// A version as written: within the versions spoken.
fn wire_version(version: u8) -> u8 {
    version.clamp(MIN_BRIDGE_VERSION, BRIDGE_VERSION)
}

fn f32_at(bytes: &[u8], offset: usize) -> f32 {
    f32::from_le_bytes(bytes[offset..offset + 4].try_into().expect("4 bytes"))
}

fn write_header(
    out: &mut Vec<u8>,
    magic: [u8; 4],
    version: u8,
    motor_count: u8,
    flags: u16,
    sequence: u64,
) {
    out.extend_from_slice(&magic);
    out.push(version);
    out.push(motor_count);
    out.extend_from_slice(&flags.to_le_bytes());
    out.extend_from_slice(&sequence.to_le_bytes());
}

impl SensorPacket {
    /// The version [`SensorPacket::encode`] writes: 2 with a pose, a GNSS solution, a
    /// magnetometer block or when `version` ≥ 2, else 1.
    pub fn wire_version(&self) -> u8 {
        if self.pose.is_some() || self.gnss.is_some() || self.magnetometer_ut.is_some() {
            2
        } else {
            wire_version(self.version)
        }
    }

    /// The packet's bytes: `48 + 4m`, `+ 16` with a pose, `+ 52` with a GNSS solution, `+ 12`
    /// with a magnetometer block, in that order.
    pub fn encode(&self) -> Vec<u8> {
        let m = self.motor_count as usize;
        let flags = if self.pose.is_some() { FLAG_POSE } else { 0 }
            | if self.gnss.is_some() { FLAG_GNSS } else { 0 }
            | if self.magnetometer_ut.is_some() { FLAG_MAGNETOMETER } else { 0 };
        let mut out = Vec::with_capacity(MAX_PACKET_LEN);
        let version = self.wire_version();
        write_header(&mut out, SENSOR_MAGIC, version, self.motor_count, flags, self.sequence);
        out.extend_from_slice(&self.time_s.to_le_bytes());
        for v in self.imu.gyro_rad_s.iter().chain(self.imu.accel_mps2.iter()) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for s in &self.speeds_rad_s[..m] {
            out.extend_from_slice(&s.unwrap_or(f32::NAN).to_le_bytes());
        }
        if let Some(pose) = &self.pose {
            for v in pose.position_ned_m.iter().chain([&pose.heading_rad]) {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        if let Some(gnss) = &self.gnss {
            gnss.encode(&mut out);
        }
        for v in self.magnetometer_ut.iter().flatten() {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// Parses a packet. Version 1 ignores the flags; version 2 reads the pose when bit 0 of the
    /// flags is set, then the GNSS solution when bit 1 is, then the magnetometer block when bit
    /// 2 is (other bits are ignored). Bytes after the packet are ignored.
    pub fn decode(bytes: &[u8]) -> Result<Self, BridgeError> {
        let (version, m) = check_header(bytes, SENSOR_MAGIC, SENSOR_HEADER_LEN)?;
        let mut speeds_rad_s = [None; MAX_MOTORS];
        for (i, s) in speeds_rad_s.iter_mut().enumerate().take(m) {
            let v = f32_at(bytes, SENSOR_HEADER_LEN + 4 * i);
            *s = (!v.is_nan()).then_some(v);
        }
        let flags = if version >= 2 { u16::from_le_bytes([bytes[6], bytes[7]]) } else { 0 };
        // Each optional block in turn, where the one before ended.
        let mut at = SENSOR_HEADER_LEN + 4 * m;
        let mut block = |flag: u16, len: usize| {
            if flags & flag == 0 {
                return Ok(None);
            }
            let (start, need) = (at, at + len);
            if bytes.len() < need {
                return Err(BridgeError::TooShort { len: bytes.len(), need });
            }
            at = need;
            Ok(Some(start))
        };
        let pose = block(FLAG_POSE, POSE_LEN)?.map(|at| ExternalPose {
            position_ned_m: [f32_at(bytes, at), f32_at(bytes, at + 4), f32_at(bytes, at + 8)],
            heading_rad: f32_at(bytes, at + 12),
        });
        let gnss = block(FLAG_GNSS, GNSS_LEN)?.map(|at| GnssSolution::decode(bytes, at));
        let magnetometer_ut = block(FLAG_MAGNETOMETER, MAGNETOMETER_LEN)?
            .map(|at| [f32_at(bytes, at), f32_at(bytes, at + 4), f32_at(bytes, at + 8)]);
        Ok(Self {
            version,
            sequence: u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes")),
            time_s: f64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes")),
            imu: ImuSample {
                gyro_rad_s: [f32_at(bytes, 24), f32_at(bytes, 28), f32_at(bytes, 32)],
                accel_mps2: [f32_at(bytes, 36), f32_at(bytes, 40), f32_at(bytes, 44)],
            },
            motor_count: m as u8,
            speeds_rad_s,
            pose,
            gnss,
            magnetometer_ut,
        })
    }
}

impl MotorPacket {
    /// The packet's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let m = self.motor_count as usize;
        let mut out = Vec::with_capacity(MOTOR_HEADER_LEN + 4 * m);
        let version = wire_version(self.version);
        write_header(&mut out, MOTOR_MAGIC, version, self.motor_count, 0, self.sequence);
        for c in &self.commands[..m] {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out
    }

    /// Parses a packet.
    pub fn decode(bytes: &[u8]) -> Result<Self, BridgeError> {
        let (version, m) = check_header(bytes, MOTOR_MAGIC, MOTOR_HEADER_LEN)?;
        let mut commands = [0.0; MAX_MOTORS];
        for (i, c) in commands.iter_mut().enumerate().take(m) {
            *c = f32_at(bytes, MOTOR_HEADER_LEN + 4 * i);
        }
        Ok(Self {
            version,
            sequence: u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes")),
            motor_count: m as u8,
            commands,
        })
    }
}

/// The application's IMU for one bridge step: the packet's sample, read once.
#[derive(Debug)]
pub struct BridgeImu(Option<ImuSample>);

impl Imu for BridgeImu {
    fn read(&mut self) -> Option<ImuSample> {
        self.0.take()
    }
}

/// The application's motors for one bridge step: speeds from the packet, commands kept (and
/// held from step to step, as a DShot output).
#[derive(Debug)]
pub struct BridgeMotors {
    count: u8,
    commands: [f32; MAX_MOTORS],
    speeds_rad_s: [Option<f32>; MAX_MOTORS],
}

impl Motors for BridgeMotors {
    fn count(&self) -> u8 {
        self.count
    }
    fn set_commands(&mut self, commands: &[f32]) {
        for (dst, src) in self.commands.iter_mut().zip(commands).take(self.count as usize) {
            *dst = if src.is_nan() { 0.0 } else { src.clamp(0.0, 1.0) };
        }
    }
    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
        self.speeds_rad_s
    }
}

/// The flight-application side: receives sensor packets, steps the application, replies.
#[derive(Debug)]
pub struct BridgeServer {
    socket: UdpSocket,
    motors: BridgeMotors,
    /// The board's GNSS UART and the firmware's receiver code behind it, fed the packets' GNSS
    /// solutions as NAV-PVT bytes.
    gnss: BoardGnss,
    /// The board's compass bus, the packets' magnetometer blocks in its chip's registers.
    compass: CompassBus,
    /// The compass drivers' waits (simulated time does not pass during a step's service).
    compass_delay: CountingDelay,
    buf: [u8; 1500],
}

/// The board's I²C compass bus behind the bridge: nothing acknowledges (a board without a GNSS
/// mast) until the first packet with a finite magnetometer block puts a [`BRIDGE_COMPASS_CHIP`]
/// on it; from then on the chip converts the latest finite field the packets gave, as a sensor
/// on a mast does (its registers, status bits, conversion time, quantisation and range:
/// `crate::compass_chip`).
#[derive(Debug, Default)]
struct CompassBus(Option<SimCompassChip>);

impl CompassBus {
    /// A packet's magnetometer block at `now_s`, s (a non-finite one is no block: the chip keeps
    /// the last field), then the chip's conversions due by then.
    fn receive(&mut self, field_ut: Option<[f32; 3]>, now_s: f64) {
        if let Some(field_ut) = field_ut.filter(|f| f.iter().all(|x| x.is_finite())) {
            let field_ut = field_ut.map(f64::from);
            match &mut self.0 {
                Some(chip) => chip.give_field_ut(field_ut),
                None => {
                    self.0 = Some(SimCompassChip::with_given_field(BRIDGE_COMPASS_CHIP, field_ut))
                }
            }
        }
        if let Some(chip) = &mut self.0 {
            // A given field needs no attitude or thrusts.
            chip.update(now_s, &UnitQuaternion::identity(), &[]);
        }
    }
}

impl I2cRegisterBus for CompassBus {
    type Error = Nack;

    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Nack> {
        self.0.as_mut().ok_or(Nack)?.write_register(address, reg, value)
    }

    fn read_registers(&mut self, address: u8, first_reg: u8, buf: &mut [u8]) -> Result<(), Nack> {
        self.0.as_mut().ok_or(Nack)?.read_registers(address, first_reg, buf)
    }
}

/// Why a GNSS latency was refused ([`BridgeServer::set_gnss_latency_s`]).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error(
    "GNSS latency {0} s is outside 0..={max} s",
    max = firmware::app::MAX_POSE_LATENCY_S
)]
pub struct GnssLatencyError(pub f64);

impl BridgeServer {
    /// Binds the listening socket (e.g. `127.0.0.1:9003`, or port 0 for any free port).
    pub fn bind(addr: impl ToSocketAddrs) -> Result<Self, BridgeError> {
        Ok(Self {
            socket: UdpSocket::bind(addr)?,
            motors: BridgeMotors {
                count: 0,
                commands: [0.0; MAX_MOTORS],
                speeds_rad_s: [None; MAX_MOTORS],
            },
            gnss: board_gnss(f64::from(firmware::app::gnss::DEFAULT_GNSS_LATENCY_S)),
            compass: CompassBus::default(),
            compass_delay: CountingDelay::default(),
            buf: [0; 1500],
        })
    }

    /// The latency the firmware gives the packets' GNSS solutions, s (`scenario bridge
    /// --gnss-latency-ms`; without it the firmware's default, 0.1 s): each describes the craft
    /// this long before the packet that carries it, as a user tells a board its receiver's.
    /// Outside 0–`MAX_POSE_LATENCY_S` (0.2 s) it is refused and nothing changes. Set it before
    /// the first packet: the receiver code starts afresh.
    pub fn set_gnss_latency_s(&mut self, latency_s: f64) -> Result<(), GnssLatencyError> {
        let max_s = f64::from(firmware::app::MAX_POSE_LATENCY_S);
        if !(latency_s.is_finite() && (0.0..=max_s).contains(&latency_s)) {
            return Err(GnssLatencyError(latency_s));
        }
        self.gnss = board_gnss(latency_s);
        Ok(())
    }

    /// The bound address.
    pub fn local_addr(&self) -> Result<SocketAddr, BridgeError> {
        Ok(self.socket.local_addr()?)
    }

    /// Waits up to `timeout` (at least 1 µs) for one sensor packet, runs one application step on
    /// it and sends the motor packet (with the sensor packet's version and sequence number) back
    /// to the sender. A pose in the packet goes to the application first, as
    /// [`ControlCommand::ExternalPose`] at the packet's time; then the GNSS solution, as the
    /// receiver's NAV-PVT bytes through the firmware's driver, which hands a new 3D fix to the
    /// application as [`ControlCommand::PositionFix`] (the driver runs every packet, so its
    /// search, configuration and loss of the receiver keep the packets' time); then the
    /// magnetometer block goes into the compass chip's registers (a non-finite one is not used:
    /// the chip keeps the previous field). After the step the application's compass service
    /// runs ([`FlightApp::service_compass`]: the firmware's reads the chip over its own driver
    /// when a reading is due, every 10 ms, and hands a calibrated field to the next step), as
    /// the board's link task runs it. Returns the packet answered.
    /// Malformed packets are answered with nothing and reported as errors (the caller decides
    /// whether to go on).
    pub fn step<A: FlightApp>(
        &mut self,
        app: &mut A,
        timeout: Duration,
    ) -> Result<(SensorPacket, MotorPacket), BridgeError> {
        self.socket.set_read_timeout(Some(timeout.max(Duration::from_micros(1))))?;
        let (len, from) = self.socket.recv_from(&mut self.buf).map_err(|e| match e.kind() {
            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => {
                BridgeError::Timeout(timeout)
            }
            _ => BridgeError::Io(e),
        })?;
        let sensor = SensorPacket::decode(&self.buf[..len])?;
        if sensor.motor_count != self.motors.count {
            self.motors.count = sensor.motor_count;
            self.motors.commands = [0.0; MAX_MOTORS];
        }
        self.motors.speeds_rad_s = sensor.speeds_rad_s;
        let mut imu = BridgeImu(Some(sensor.imu));
        let now_us = packet_time_us(&sensor);
        if let Some(pose) = sensor.pose {
            app.command(ControlCommand::ExternalPose(pose), now_us);
        }
        let nav_pvt = sensor.gnss.map(|solution| solution.to_nav_pvt().to_frame());
        if let Some(fix) = self.gnss.receive(nav_pvt.as_ref().map_or(&[], |f| &f[..]), now_us) {
            app.command(ControlCommand::PositionFix(fix), now_us);
        }
        self.compass.receive(sensor.magnetometer_ut, now_us as f64 * 1e-6);
        app.step(now_us, &mut imu, &mut self.motors);
        app.service_compass(now_us, &mut self.compass, &mut self.compass_delay);
        let reply = MotorPacket {
            version: sensor.version,
            sequence: sensor.sequence,
            motor_count: sensor.motor_count,
            commands: self.motors.commands,
        };
        self.socket.send_to(&reply.encode(), from)?;
        Ok((sensor, reply))
    }
}

/// The firmware's receiver code behind the bridge, its solutions taken `latency_s` late; it
/// configures the receiver as the board does by default (the outside simulator streams its
/// solutions whatever it is sent).
fn board_gnss(latency_s: f64) -> BoardGnss {
    BoardGnss::new(GnssConfig::default(), latency_s)
}

/// The application time of a sensor packet, µs: `round(t · 10⁶)` (negative times count as 0).
pub fn packet_time_us(packet: &SensorPacket) -> u64 {
    (packet.time_s.max(0.0) * 1e6).round() as u64
}

/// How long [`serve_firmware`] waits for a packet before it serves the TCP links again.
pub const LINK_WAIT: Duration = Duration::from_millis(5);
/// Sensor packets per link pass while packets flow: the board's control ticks per link pass
/// (2: once per simulated millisecond at 2 kHz, as the board pends its USB task).
pub const PACKETS_PER_LINK_PASS: u64 = firmware::app::system::LINK_PASS_TICKS as u64;

/// How far a sensor packet's time may be from one control period after the previous packet's
/// before [`serve_firmware`] reports it, µs: 1 % of the 500 µs period. The application takes
/// every step as one period (its filters, integrators and timers), so a simulator that sends
/// packets at another rate runs the firmware's clock at the wrong speed; a simulator that adds
/// 0.0005 s each time stays within a microsecond after days (f64).
pub const PACKET_PERIOD_TOLERANCE_US: i64 = (CONTROL_PERIOD_US / 100) as i64;

/// What a [`serve_firmware`] run did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BridgeSummary {
    /// Sensor packets answered (application steps run).
    pub steps: u64,
    /// Datagrams rejected as malformed (not answered).
    pub malformed: u64,
    /// Answered packets whose time was not one control period (500 µs, within
    /// [`PACKET_PERIOD_TOLERANCE_US`]) after the previous packet's.
    pub off_period: u64,
}

/// Serves the firmware application `app` on `server` until no datagram arrived for
/// `idle_timeout`: one application step per sensor packet (see [`BridgeServer::step`]).
///
/// With `links`, the configurator protocol is served meanwhile: a link pass after every
/// [`PACKETS_PER_LINK_PASS`] sensor packets, and every [`LINK_WAIT`] while no packet arrives
/// (simulated time then stands still at the last packet's), so a configurator can connect and
/// ask while the external simulator pauses. The pass is the application's own: what the links
/// asked (arm, disarm, external pose) waits in the control step's queue for the next packet's
/// tick, as on the board. Connections accepted after the first
/// packet report its motor count in their info (0 before).
///
/// With `radio`, the pilot's simulated radio plays its script in the packets' time and its RC
/// frames reach the control tick's receiver policy (build `app` with a receiver:
/// [`crate::scenario::with_firmware_app_and_radio`]).
///
/// Malformed datagrams are reported to `report` ([`BridgeNotice::Malformed`]) and not answered;
/// a throw-to-fly attempt that ends without a result, or an arming the control step refuses,
/// is reported with its reason ([`BridgeNotice::AttemptEnded`]). The first packet whose time
/// is not one control period after the previous one's is reported
/// ([`BridgeNotice::OffPeriod`]; the summary counts them all): it is still answered, the step
/// taken as one period. A socket error ends the run.
pub fn serve_firmware(
    server: &mut BridgeServer,
    app: &mut FirmwareApp<'_>,
    mut links: Option<&mut TcpLinks>,
    mut radio: Option<&mut RcTransmitter>,
    idle_timeout: Duration,
    report: &mut dyn FnMut(BridgeNotice<'_>),
) -> Result<BridgeSummary, BridgeError> {
    let mut summary = BridgeSummary::default();
    // An IMU offset given on the command line is in force as if calibrated (not saved: the
    // bridge has no flash; parameters last for the run).
    if let Some(r_imu_m) = app.background.configured_imu_offset() {
        app.link.settings_mut().update(|params| params.store_calibration(r_imu_m, [0.0; 3], None));
    }
    let mut last_datagram = Instant::now();
    let mut now_us = 0u64;
    let mut previous_time_s: Option<f64> = None;
    let mut last_failure = app.snapshot().failure;
    loop {
        let idle = last_datagram.elapsed();
        if idle >= idle_timeout {
            return Ok(summary);
        }
        let wait =
            (idle_timeout - idle).min(if links.is_some() { LINK_WAIT } else { idle_timeout });
        let stepped = server.step(&mut AroundFirmware { app, around: radio.as_deref_mut() }, wait);
        let link_pass_due = match stepped {
            Ok((sensor, _)) => {
                last_datagram = Instant::now();
                summary.steps += 1;
                let failure = app.snapshot().failure;
                if failure != last_failure && failure != LearnerFailure::None {
                    report(BridgeNotice::AttemptEnded(failure));
                }
                last_failure = failure;
                now_us = packet_time_us(&sensor);
                if let Some(previous_s) = previous_time_s {
                    let interval_us = ((sensor.time_s - previous_s) * 1e6).round() as i64;
                    if (interval_us - CONTROL_PERIOD_US as i64).abs() > PACKET_PERIOD_TOLERANCE_US {
                        summary.off_period += 1;
                        if summary.off_period == 1 {
                            report(BridgeNotice::OffPeriod {
                                sequence: sensor.sequence,
                                time_s: sensor.time_s,
                                interval_us,
                            });
                        }
                    }
                }
                previous_time_s = Some(sensor.time_s);
                if let Some(links) = links.as_deref_mut() {
                    links.set_motor_count(sensor.motor_count);
                }
                summary.steps % PACKETS_PER_LINK_PASS == 0
            }
            Err(BridgeError::Timeout(_)) => true,
            Err(error @ BridgeError::Io(_)) => return Err(error),
            Err(error) => {
                last_datagram = Instant::now();
                summary.malformed += 1;
                report(BridgeNotice::Malformed(&error));
                false
            }
        };
        if link_pass_due {
            // The application's own link pass (with no links: the parameters serviced and the
            // telemetry ring drained, as on a board with no host). A restart request is
            // answered but not carried out: the external simulator owns the time line.
            if let Some(links) = links.as_deref_mut() {
                links.accept();
            }
            app.pass(now_us, &mut links.as_deref_mut());
            if let Some(links) = links.as_deref_mut() {
                links.drop_closed();
            }
        }
    }
}

/// The pilot's simulated radio around the firmware's step (when there is one): advanced to each
/// packet's time before the control tick reads its bytes (the board's receiver UART). The
/// external simulator sends no battery (docs/sim-bridge.md).
impl AroundStep for Option<&mut RcTransmitter> {
    fn radio(&mut self, now_us: u64) -> Option<&mut RcTransmitter> {
        let radio = self.as_deref_mut()?;
        radio.advance(now_us);
        Some(radio)
    }
}

/// What [`serve_firmware`] reports as it serves (the `scenario bridge` command prints each on
/// stderr).
#[derive(Debug)]
pub enum BridgeNotice<'e> {
    /// A datagram was malformed; it was not answered.
    Malformed(&'e BridgeError),
    /// A throw-to-fly attempt ended without a result, or the control step refused to arm: why.
    AttemptEnded(LearnerFailure),
    /// The first packet whose time was not one control period after the previous packet's
    /// (reported once a run; [`BridgeSummary::off_period`] counts them all).
    OffPeriod {
        /// Its sequence number.
        sequence: u64,
        /// Its time, s.
        time_s: f64,
        /// Its time minus the previous packet's, µs (negative: the simulator's time went back).
        interval_us: i64,
    },
}

impl std::fmt::Display for BridgeNotice<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Malformed(error) => write!(f, "ignored a malformed packet: {error}"),
            Self::AttemptEnded(failure) => {
                write!(f, "throw-to-fly not armed any more: {}", attempt_text(*failure))
            }
            Self::OffPeriod { sequence, time_s, interval_us } => write!(
                f,
                "packet {sequence} at t = {time_s:.6} s came {interval_us} µs after the one \
                 before: the application takes each packet as one {CONTROL_PERIOD_US} µs step \
                 ({CONTROL_RATE_HZ:.0} Hz), so at another rate its attitude, velocities and \
                 timers run at the wrong speed; send one sensor packet per {CONTROL_PERIOD_US} µs \
                 of simulated time (docs/sim-bridge.md, \"Lockstep\"). Reported once; the stop \
                 line counts them"
            ),
        }
    }
}

/// Tell the application behind the bridge that the simulator's ESCs report no speed (NaN in
/// every sensor packet), as a user sets `motor_bidir_dshot` = 0 for ESCs without bidirectional
/// DShot (`scenario bridge --no-speed-telemetry`; over TCP, `set motor_bidir_dshot = 0` does
/// the same while disarmed). In force from the first packet (call it before an arm request),
/// for the run only (the bridge has no flash). Every build identifies from the commands then
/// (`flight::learner::no_speed`), so throw-to-fly arms without speeds.
pub fn set_no_speed_telemetry(app: &mut FirmwareApp<'_>) {
    app.configure(|params| {
        // A flag's 0 is always within its range.
        let _ = params.set(firmware::app::Param::MotorBidirDshot as usize, &[0.0]);
    });
}

/// The compass calibration `scenario bridge --compass-calibrated` stores: no hard iron, no soft
/// iron (the identity), the chip's axes the IMU's (the mounting the identity), and the
/// firmware's default noise per axis ([`firmware::app::compass::DEFAULT_COMPASS_NOISE_UT`],
/// 1 µT, the middle of what these sensors give after their averaging). The magnetometer blocks'
/// fields then reach the pilot as sent (to the chip's 0.3 µT), already calibrated.
pub fn identity_compass_calibration() -> CompassCalibration {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let noise_ut = firmware::app::compass::DEFAULT_COMPASS_NOISE_UT;
    CompassCalibration::new([0.0; 3], identity, [1.0, 0.0, 0.0, 0.0], noise_ut)
        .expect("finite, a unit quaternion, a positive noise")
}

/// Why a compass declination was refused ([`configure_compass`]).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("compass declination {0}° is outside {min}..={max}°", min = declination_range_deg().0,
        max = declination_range_deg().1)]
pub struct CompassDeclinationError(pub f32);

/// The range of `compass_declination_deg`, degrees.
pub fn declination_range_deg() -> (f32, f32) {
    let spec = firmware::app::Param::CompassDeclinationDeg.spec();
    (spec.min, spec.max)
}

/// Tell the application behind the bridge about its compass, as a user who calibrated theirs
/// and looked up the local declination: with `calibrated` (`scenario bridge
/// --compass-calibrated`), [`identity_compass_calibration`] is stored (`compass_cal_valid` = 1),
/// so the magnetometer blocks' fields reach the pilot as they are; the declination
/// `declination_deg` (`--compass-declination-deg`: east of true north positive, the parameter
/// `compass_declination_deg`, within ±90°; outside it, or not finite, it is refused and nothing
/// changes) always. In force from the first packet (call it before an arm request), for the run
/// only (the bridge has no flash). Without a calibration the firmware finds and reads the
/// compass but, as on a board, hands the pilot nothing from it (a raw field's hard iron would
/// point the heading anywhere).
pub fn configure_compass(
    app: &mut FirmwareApp<'_>,
    calibrated: bool,
    declination_deg: f32,
) -> Result<(), CompassDeclinationError> {
    let (min, max) = declination_range_deg();
    if !(declination_deg.is_finite() && (min..=max).contains(&declination_deg)) {
        return Err(CompassDeclinationError(declination_deg));
    }
    app.configure(|params| {
        if calibrated {
            params.store_compass_calibration(&identity_compass_calibration());
        }
        // Within the parameter's range: checked above.
        let _ =
            params.set(firmware::app::Param::CompassDeclinationDeg as usize, &[declination_deg]);
    });
    Ok(())
}

/// What the latest identification found, for a person reading the bridge's stderr when it
/// stops (the same as `status` over `--tcp-port` shows): the thrust axis and the hover commands
/// (said when they are the last resort, `u*` clamped to the motor bounds), whether the motor
/// speeds were measured or modelled from the commands, and the IMU offset the model used with
/// where it came from (fitted in flight: its 95 % semi-axes too). `None` before any model.
pub fn identification_summary(results: &firmware::app::BackgroundResults) -> Option<String> {
    use protocol::ImuOffsetSource;
    let learned = &results.learned;
    let axis = learned.thrust_axis?;
    let m = usize::from(learned.motors).min(MAX_MOTORS);
    let mm = |v: [f32; 3]| format!("({:.1}, {:.1}, {:.1}) mm", v[0] * 1e3, v[1] * 1e3, v[2] * 1e3);
    let [roll, pitch, yaw] = axis.euler_zyx_rad.map(f32::to_degrees);
    let hover: Vec<String> = axis.u_hover[..m].iter().map(|u| format!("{u:.3}")).collect();
    let mut text = format!(
        "identified {m} motors: thrust axis (roll, pitch, yaw of the thrust frame in IMU axes) \
         ({roll:.1}, {pitch:.1}, {yaw:.1})°, hover commands [{}] (normalised thrust)",
        hover.join(", ")
    );
    if !axis.within_bounds() {
        text += &format!(
            " clamped to the motor bounds: no hover within them was found, u* was {:.2} \
             outside (the axis flown is the clamped commands')",
            axis.clamped_by
        );
    }
    text += if learned.speeds_modelled {
        "; motor speeds modelled from the commands (no speed telemetry)"
    } else {
        "; motor speeds measured"
    };
    let offset = match results.learner_offset {
        ImuOffsetSource::FittedInFlight => {
            let fit = &results.imu_offset;
            // On modelled speeds its ellipsoid leaves out their errors: flown, never stored
            // (`firmware::app::settings::Settings::service`).
            let kept =
                if learned.speeds_modelled { " (on modelled speeds: not stored)" } else { "" };
            format!(
                "fitted in flight {}, 95 % semi-axes {}{kept}",
                mm(fit.r_imu_m),
                mm(fit.ci95_semi_axes_m)
            )
        }
        ImuOffsetSource::Configured => format!("given {}", mm(results.learner_r_imu_m)),
        ImuOffsetSource::Onboard => {
            format!("from the onboard estimate {}", mm(results.learner_r_imu_m))
        }
        ImuOffsetSource::Zero | ImuOffsetSource::NotUsed => match &results.flight_offset {
            // Fitted, but never within `imu_offset::in_flight::USABLE_SEMI_AXIS_M`: not flown.
            Some(fit) => format!(
                "none known (taken as zero); fitted in flight {} but not used, its 95 % \
                 semi-axes {} wider than {:.0} mm",
                mm(fit.r_imu_m),
                mm(fit.ci95_semi_axes_m),
                imu_offset::in_flight::USABLE_SEMI_AXIS_M * 1e3
            ),
            None => "none known or fitted (taken as zero)".to_string(),
        },
    };
    Some(format!("{text}; IMU offset {offset}"))
}

/// Why a throw-to-fly attempt ended, for a person reading the bridge's stderr.
pub fn attempt_text(failure: LearnerFailure) -> String {
    match failure {
        LearnerFailure::NoSpeedTelemetry => format!(
            "motor speeds not reported (NaN in the sensor packets for {} ms): the in-flight \
             learner needs every motor's speed, rad/s; send them, or run the bridge with \
             --no-speed-telemetry to identify from the commands. Every motor was stopped.",
            protocol::SPEED_REPORT_TIMEOUT_MS
        ),
        LearnerFailure::NotFreeFall => {
            "the release was refused: not falling freely (motors never started)".into()
        }
        LearnerFailure::ThrowTimedOut => {
            // The detector's own limits (not parameters: `ThrowConfig`'s defaults).
            let throw = flight::learner::throw_detector::ThrowConfig::default();
            format!(
                "a throw began but no release followed within {} s (an IMU far from the centre of \
                 gravity reads a fast spin as a push that never ends: Ω²·r above {} m/s²)",
                throw.give_up_s, throw.acc_high_mps2
            )
        }
        LearnerFailure::RankDeficient => "no torque about every axis: no hover axis".into(),
        LearnerFailure::NoHover => "no hover within the motor limits".into(),
        LearnerFailure::NoThrustAxis => "the excitation ended without a hover thrust axis".into(),
        LearnerFailure::MotorUnusable { motor } => {
            format!("motor {motor}'s model is unusable (time constant or full speed out of range)")
        }
        LearnerFailure::InvalidModel => "the learned model is not finite".into(),
        LearnerFailure::Disarmed => "disarmed by request".into(),
        LearnerFailure::ImuLost => "the IMU samples stopped or went bad".into(),
        LearnerFailure::None => "no reason".into(),
    }
}

/// The external-simulator side, for tests and as a reference implementation: sends a sensor
/// packet and waits for the matching motor packet.
#[derive(Debug)]
pub struct BridgeClient {
    socket: UdpSocket,
    buf: [u8; 1500],
}

impl BridgeClient {
    /// Binds `local` (e.g. `127.0.0.1:9002` or port 0) and sends to `server`.
    pub fn connect(
        local: impl ToSocketAddrs,
        server: impl ToSocketAddrs,
    ) -> Result<Self, BridgeError> {
        let socket = UdpSocket::bind(local)?;
        socket.connect(server)?;
        Ok(Self { socket, buf: [0; 1500] })
    }

    /// Sends `packet` and returns the reply with the same sequence number (older replies are
    /// skipped), or [`BridgeError::Timeout`].
    pub fn exchange(
        &mut self,
        packet: &SensorPacket,
        timeout: Duration,
    ) -> Result<MotorPacket, BridgeError> {
        self.socket.send(&packet.encode())?;
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return Err(BridgeError::Timeout(timeout));
            }
            self.socket.set_read_timeout(Some(left))?;
            let len = self.socket.recv(&mut self.buf).map_err(|e| match e.kind() {
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => {
                    BridgeError::Timeout(timeout)
                }
                _ => BridgeError::Io(e),
            })?;
            let reply = MotorPacket::decode(&self.buf[..len])?;
            if reply.sequence == packet.sequence {
                return Ok(reply);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stop summary names the last resort and the offset fitted in flight with its
    /// ellipsoid, in millimetres; before any model there is none.
    /// A throw that never releases is told with the detector's own limits (its give-up time
    /// and push threshold, in s and m/s²), as the configurator says them.
    #[test]
    fn a_throw_that_never_releases_names_the_detectors_limits() {
        let text = attempt_text(LearnerFailure::ThrowTimedOut);
        assert!(text.contains("within 3 s"), "{text}");
        assert!(text.contains("above 20 m/s²"), "{text}");
    }

    #[test]
    fn the_identification_summary_says_what_was_clamped_and_where_the_offset_came_from() {
        use flight::learner::LearnedThrustAxis;
        let mut results = firmware::app::BackgroundResults::default();
        assert_eq!(identification_summary(&results), None);
        results.learned.motors = 4;
        let mut axis = LearnedThrustAxis { clamped_by: 0.25, ..LearnedThrustAxis::default() };
        axis.u_hover[..4].copy_from_slice(&[1.0, 0.5, 0.5, 0.25]);
        results.learned.thrust_axis = Some(axis);
        results.learner_offset = protocol::ImuOffsetSource::FittedInFlight;
        results.imu_offset.r_imu_m = [0.012, -0.0034, 0.02];
        results.imu_offset.ci95_semi_axes_m = [0.003, 0.002, 0.001];
        let text = identification_summary(&results).unwrap();
        assert!(text.contains("[1.000, 0.500, 0.500, 0.250]"), "{text}");
        assert!(text.contains("u* was 0.25 outside"), "{text}");
        assert!(text.contains("motor speeds measured"), "{text}");
        assert!(
            text.contains(
                "fitted in flight (12.0, -3.4, 20.0) mm, 95 % semi-axes (3.0, 2.0, 1.0) mm"
            ),
            "{text}"
        );
        assert!(!text.contains("not stored"), "{text}");
        results.learned.speeds_modelled = true;
        let text = identification_summary(&results).unwrap();
        assert!(text.contains("(3.0, 2.0, 1.0) mm (on modelled speeds: not stored)"), "{text}");
        results.learned.thrust_axis = Some(LearnedThrustAxis::default());
        let text = identification_summary(&results).unwrap();
        assert!(!text.contains("clamped"), "within the bounds: {text}");
        // A fit never determined well enough to fly is named as such, not as the offset used.
        results.learner_offset = protocol::ImuOffsetSource::Zero;
        let text = identification_summary(&results).unwrap();
        assert!(text.contains("none known or fitted (taken as zero)"), "{text}");
        results.flight_offset = Some(imu_offset::in_flight::OffsetFitEstimate {
            r_imu_m: [0.0001, 0.0082, 0.0196],
            ci95_semi_axes_m: [0.0026, 0.007, 0.0237],
            ..Default::default()
        });
        let text = identification_summary(&results).unwrap();
        assert!(
            text.contains(
                "none known (taken as zero); fitted in flight (0.1, 8.2, 19.6) mm but \
                           not used, its 95 % semi-axes (2.6, 7.0, 23.7) mm wider than 5 mm"
            ),
            "{text}"
        );
    }

    fn sensor() -> SensorPacket {
        let mut speeds_rad_s = [None; MAX_MOTORS];
        speeds_rad_s[..6].copy_from_slice(&[
            Some(1.5),
            None,
            Some(300.25),
            Some(0.0),
            None,
            Some(7.0),
        ]);
        SensorPacket {
            version: 1,
            sequence: 0x0102_0304_0506_0708,
            time_s: 12.5,
            imu: ImuSample { gyro_rad_s: [0.1, -0.2, 0.3], accel_mps2: [1.0, 2.0, -9.80665] },
            motor_count: 6,
            speeds_rad_s,
            pose: None,
            gnss: None,
            magnetometer_ut: None,
        }
    }

    const POSE: ExternalPose =
        ExternalPose { position_ned_m: [1.5, -2.0, -0.5], heading_rad: 0.25 };

    /// A small packet with exactly representable values, for byte-exact checks.
    fn small(pose: Option<ExternalPose>) -> SensorPacket {
        let mut speeds_rad_s = [None; MAX_MOTORS];
        speeds_rad_s[0] = Some(2.0);
        SensorPacket {
            version: 1,
            sequence: 0x0102,
            time_s: 0.5,
            imu: ImuSample { gyro_rad_s: [1.0, -1.0, 0.0], accel_mps2: [0.0, 0.0, -2.0] },
            motor_count: 2,
            speeds_rad_s,
            pose,
            gnss: None,
            magnetometer_ut: None,
        }
    }

    /// The bytes of `small(..)` up to the motor speeds, for `version` and `flags`.
    fn small_head(version: u8, flags: u8) -> Vec<u8> {
        let v = vec![
            0x46, 0x43, 0x53, 0x4E, // "FCSN"
            version, 0x02, flags, 0x00, // version, m = 2, flags
            0x02, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // sequence 0x0102
            0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xE0, 0x3F, // time 0.5 (f64)
            0x00, 0x00, 0x80, 0x3F, // gyro x 1.0
            0x00, 0x00, 0x80, 0xBF, // gyro y -1.0
            0x00, 0x00, 0x00, 0x00, // gyro z 0.0
            0x00, 0x00, 0x00, 0x00, // accel x 0.0
            0x00, 0x00, 0x00, 0x00, // accel y 0.0
            0x00, 0x00, 0x00, 0xC0, // accel z -2.0
            0x00, 0x00, 0x00, 0x40, // motor 0: 2.0 rad/s
            0x00, 0x00, 0xC0, 0x7F, // motor 1: NaN (not reported)
        ];
        assert_eq!(v.len(), 48 + 4 * 2);
        v
    }

    #[test]
    fn version_1_golden_bytes() {
        let bytes = small(None).encode();
        assert_eq!(bytes, small_head(1, 0));
        assert_eq!(SensorPacket::decode(&bytes).unwrap(), small(None));
    }

    #[test]
    fn version_2_golden_bytes_with_a_pose() {
        let packet = small(Some(POSE));
        let bytes = packet.encode();
        let mut expected = small_head(2, 0x01);
        expected.extend_from_slice(&[
            0x00, 0x00, 0xC0, 0x3F, // north 1.5 m
            0x00, 0x00, 0x00, 0xC0, // east -2.0 m
            0x00, 0x00, 0x00, 0xBF, // down -0.5 m
            0x00, 0x00, 0x80, 0x3E, // heading 0.25 rad
        ]);
        assert_eq!(bytes.len(), 48 + 4 * 2 + 16);
        assert_eq!(bytes, expected);
        let decoded = SensorPacket::decode(&bytes).unwrap();
        assert_eq!(decoded, SensorPacket { version: 2, ..packet });
        assert_eq!(decoded.pose, Some(POSE));
    }

    /// A 3D fix at 47.5° N, 8.5° E, 456 m, moving (0.5, −0.25, 0.125) m/s, hAcc 0.5 m, vAcc 1 m,
    /// sAcc 0.25 m/s, 16 satellites, at Wednesday noon's time of week: exactly representable,
    /// for byte-exact checks.
    const GNSS: GnssSolution = GnssSolution {
        time_of_week_ms: 302_400_000,
        fix_type: FixType::Fix3d,
        fix_ok: true,
        satellites: 16,
        latitude_deg: 47.5,
        longitude_deg: 8.5,
        height_ellipsoid_m: 456.0,
        velocity_ned_mps: [0.5, -0.25, 0.125],
        horizontal_accuracy_m: 0.5,
        vertical_accuracy_m: 1.0,
        speed_accuracy_mps: 0.25,
    };

    /// [`GNSS`]'s 52 bytes, as docs/sim-bridge.md shows them.
    const GNSS_BYTES: [u8; GNSS_LEN] = [
        0x00, 0x42, 0x06, 0x12, // time of week 302,400,000 ms
        0x03, 0x01, 0x10, 0x00, // fix type 3 (3D), flags: gnssFixOK, 16 satellites, reserved
        0x00, 0x00, 0x00, 0x00, 0x00, 0xC0, 0x47, 0x40, // latitude 47.5° (f64)
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x21, 0x40, // longitude 8.5° (f64)
        0x00, 0x00, 0xE4, 0x43, // height above the ellipsoid 456 m
        0x00, 0x00, 0x00, 0x3F, // velocity north 0.5 m/s
        0x00, 0x00, 0x80, 0xBE, // velocity east -0.25 m/s
        0x00, 0x00, 0x00, 0x3E, // velocity down 0.125 m/s
        0x00, 0x00, 0x00, 0x3F, // hAcc 0.5 m
        0x00, 0x00, 0x80, 0x3F, // vAcc 1.0 m
        0x00, 0x00, 0x80, 0x3E, // sAcc 0.25 m/s
    ];

    #[test]
    fn version_2_golden_bytes_with_a_gnss_solution_and_no_pose() {
        let packet = SensorPacket { gnss: Some(GNSS), ..small(None) };
        let bytes = packet.encode();
        let mut expected = small_head(2, 0x02);
        expected.extend_from_slice(&GNSS_BYTES);
        assert_eq!(bytes.len(), 48 + 4 * 2 + 52);
        assert_eq!(bytes, expected);
        let decoded = SensorPacket::decode(&bytes).unwrap();
        assert_eq!(decoded, SensorPacket { version: 2, ..packet });
        assert_eq!(decoded.gnss, Some(GNSS));
    }

    #[test]
    fn version_2_golden_bytes_with_a_pose_then_a_gnss_solution() {
        let packet = SensorPacket { version: 2, gnss: Some(GNSS), ..small(Some(POSE)) };
        let bytes = packet.encode();
        // The pose's packet, flags bit 1 set, and the solution after the pose.
        let mut expected = small(Some(POSE)).encode();
        expected[6] = 0x03;
        expected.extend_from_slice(&GNSS_BYTES);
        assert_eq!(bytes.len(), 48 + 4 * 2 + 16 + 52);
        assert_eq!(bytes, expected);
        assert_eq!(SensorPacket::decode(&bytes).unwrap(), packet);
    }

    /// The solution becomes the NAV-PVT a receiver sends: the firmware's own parser reads back
    /// every field the block carries (at the frame's resolution), a valid date, time and
    /// position, and a 3D fix.
    #[test]
    fn a_gnss_solution_is_a_nav_pvt_frame_the_firmwares_parser_reads_back() {
        use firmware::drivers::ubx::{Decoder, Message};
        let solution = GnssSolution {
            latitude_deg: 47.376_912_34,
            longitude_deg: -122.123_456_78,
            velocity_ned_mps: [1.234, -5.678, 0.9],
            ..GNSS
        };
        let mut parsed = Vec::new();
        Decoder::new().feed(&solution.to_nav_pvt().to_frame(), |frame| {
            if let Message::NavPvt(fix) = Message::parse(&frame) {
                parsed.push(fix);
            }
        });
        let [fix] = parsed[..] else { panic!("{} NAV-PVT frames", parsed.len()) };
        assert!(fix.has_3d_fix() && fix.date_valid && fix.time_valid && !fix.position_invalid);
        let back = GnssSolution::from_nav_pvt(&fix);
        assert_eq!(back.time_of_week_ms, solution.time_of_week_ms);
        assert_eq!((back.fix_type, back.fix_ok, back.satellites), (FixType::Fix3d, true, 16));
        // 1e-7° (1.1 cm) for latitude and longitude, 1 mm and 1 mm/s for the rest.
        assert!((back.latitude_deg - solution.latitude_deg).abs() <= 0.5e-7 + 1e-12);
        assert!((back.longitude_deg - solution.longitude_deg).abs() <= 0.5e-7 + 1e-12);
        for (b, s) in back.velocity_ned_mps.iter().zip(solution.velocity_ned_mps) {
            assert!((b - s).abs() <= 0.5e-3 + 1e-6, "{b} vs {s}");
        }
        assert_eq!(back.height_ellipsoid_m, 456.0);
        assert_eq!(back.horizontal_accuracy_m, 0.5);
        // Without a fix the receiver says so and the firmware's test of a fix agrees.
        let none = GnssSolution { fix_type: FixType::NoFix, fix_ok: false, ..solution };
        assert!(!none.to_nav_pvt().has_3d_fix());
    }

    /// A field of 48.4 µT at 65° of dip, exactly representable, for byte-exact checks.
    const FIELD_UT: [f32; 3] = [20.0, -2.5, 44.0];

    /// [`FIELD_UT`]'s 12 bytes, as docs/sim-bridge.md shows them.
    const FIELD_BYTES: [u8; MAGNETOMETER_LEN] = [
        0x00, 0x00, 0xA0, 0x41, // x 20.0 µT
        0x00, 0x00, 0x20, 0xC0, // y -2.5 µT
        0x00, 0x00, 0x30, 0x42, // z 44.0 µT
    ];

    /// The doc's magnetometer example: the pose example's packet without its pose, flags bit 2
    /// and the field after the motor speeds (68 bytes).
    #[test]
    fn version_2_golden_bytes_with_a_magnetometer_block_alone() {
        let packet = SensorPacket { magnetometer_ut: Some(FIELD_UT), ..small(None) };
        let bytes = packet.encode();
        let mut expected = small_head(2, 0x04);
        expected.extend_from_slice(&FIELD_BYTES);
        assert_eq!(bytes.len(), 48 + 4 * 2 + 12);
        assert_eq!(bytes, expected);
        let decoded = SensorPacket::decode(&bytes).unwrap();
        assert_eq!(decoded, SensorPacket { version: 2, ..packet });
        assert_eq!(decoded.magnetometer_ut, Some(FIELD_UT));
        assert_eq!(packet.wire_version(), 2, "a magnetometer block makes it version 2");
    }

    /// All three blocks: the pose, then the GNSS solution, then the field (136 bytes).
    #[test]
    fn version_2_golden_bytes_with_a_pose_a_gnss_solution_and_a_magnetometer_block() {
        let packet = SensorPacket {
            version: 2,
            gnss: Some(GNSS),
            magnetometer_ut: Some(FIELD_UT),
            ..small(Some(POSE))
        };
        let bytes = packet.encode();
        let mut expected = SensorPacket { gnss: Some(GNSS), ..small(Some(POSE)) }.encode();
        expected[6] = 0x07;
        expected.extend_from_slice(&FIELD_BYTES);
        assert_eq!(bytes.len(), 48 + 4 * 2 + 16 + 52 + 12);
        assert_eq!(bytes, expected);
        assert_eq!(SensorPacket::decode(&bytes).unwrap(), packet);
        // Non-finite values cross as sent: the server, not the decoder, refuses them.
        let nan = SensorPacket { magnetometer_ut: Some([f32::NAN, 1.0, 2.0]), ..small(None) };
        let decoded = SensorPacket::decode(&nan.encode()).unwrap().magnetometer_ut.unwrap();
        assert!(decoded[0].is_nan() && decoded[1..] == [1.0, 2.0]);
    }

    /// The compass bus behind the bridge through the firmware's own IST8310 driver: nothing
    /// answers before the first block; the chip then converts the latest finite field (to its
    /// 0.3 µT), a non-finite block leaves the previous field in place, and a field beyond the
    /// chip's ±1600 µT on x is an overflow.
    #[test]
    fn the_compass_bus_holds_the_latest_finite_field_behind_the_ist8310s_registers() {
        use firmware::drivers::compass::CompassError;
        use firmware::drivers::ist8310::{self, Ist8310};
        let mut bus = CompassBus::default();
        let mut delay = CountingDelay::default();
        bus.receive(None, 0.0);
        let mut driver = Ist8310::new(&mut bus, ist8310::DEFAULT_ADDRESS);
        assert_eq!(driver.init(&mut delay), Err(CompassError::Bus(Nack)), "no chip yet");
        // A non-finite first block puts no chip on the bus either.
        bus.receive(Some([f32::NAN, 0.0, 0.0]), 0.001);
        assert!(bus.0.is_none());
        // The reads of a 100 Hz service, 10 ms apart (a conversion takes 6 ms).
        let mut t_s = 0.002;
        let mut read = |bus: &mut CompassBus, block: Option<[f32; 3]>| {
            bus.receive(block, t_s);
            t_s += 0.010;
            bus.receive(None, t_s);
            Ist8310::new(&mut *bus, ist8310::DEFAULT_ADDRESS).read()
        };
        bus.receive(Some(FIELD_UT), 0.002);
        Ist8310::new(&mut bus, ist8310::DEFAULT_ADDRESS).init(&mut delay).unwrap();
        let first = read(&mut bus, None).unwrap();
        for (got, sent) in first.field_ut.iter().zip(FIELD_UT) {
            assert!((got - sent).abs() <= 0.15 + 1e-4, "{got} µT read, {sent} µT sent");
        }
        let second = read(&mut bus, Some([f32::INFINITY, 0.0, 0.0])).unwrap();
        assert_eq!(second.field_ut, first.field_ut, "the non-finite block was not used");
        let third = read(&mut bus, Some([-12.3, 4.5, 30.0])).unwrap();
        assert!((third.field_ut[0] + 12.3).abs() <= 0.15 + 1e-4, "{:?}", third.field_ut);
        assert_eq!(read(&mut bus, Some([1700.0, 0.0, 0.0])), Err(CompassError::Overflow));
    }

    #[test]
    fn version_2_without_a_pose_has_no_trailer() {
        let packet = SensorPacket { version: 2, ..small(None) };
        let bytes = packet.encode();
        assert_eq!(bytes, small_head(2, 0));
        assert_eq!(SensorPacket::decode(&bytes).unwrap(), packet);
    }

    #[test]
    fn version_1_ignores_the_flags_and_version_2_ignores_unknown_bits() {
        // Version 1 with bits 0, 1 and 2 set and trailing bytes: no pose, no GNSS solution, no
        // field.
        let mut v1 = small_head(1, 0x07);
        v1.extend_from_slice(&[0xAA; 16 + 52 + 12]);
        v1[7] = 0x80;
        assert_eq!(SensorPacket::decode(&v1).unwrap(), small(None));
        // Version 2 with unknown bits only (3–15): no block, no trailer needed.
        let mut v2 = small_head(2, 0xF8);
        v2[7] = 0xFF;
        let decoded = SensorPacket::decode(&v2).unwrap();
        assert_eq!((decoded.pose, decoded.gnss, decoded.magnetometer_ut), (None, None, None));
        // Version 2 with bit 0 and unknown bits (3 and 4, 14): the pose.
        let mut v2 = small(Some(POSE)).encode();
        v2[6] |= 0x18;
        v2[7] = 0x40;
        assert_eq!(SensorPacket::decode(&v2).unwrap().pose, Some(POSE));
    }

    #[test]
    fn packets_round_trip_through_bytes() {
        let s = sensor();
        let bytes = s.encode();
        assert_eq!(bytes.len(), 48 + 4 * 6);
        assert_eq!(&bytes[0..4], b"FCSN");
        assert_eq!(bytes[4], 1, "no pose: version 1");
        assert_eq!(bytes[8], 0x08, "sequence is little-endian");
        assert_eq!(SensorPacket::decode(&bytes).unwrap(), s);
        let with_pose = SensorPacket { version: 2, pose: Some(POSE), ..s };
        let bytes = with_pose.encode();
        assert_eq!(bytes.len(), 48 + 4 * 6 + 16);
        assert_eq!(SensorPacket::decode(&bytes).unwrap(), with_pose);
        assert_eq!(
            SensorPacket { version: 1, ..with_pose }.wire_version(),
            2,
            "a pose always makes it version 2"
        );
        for version in [1, 2] {
            let m = MotorPacket {
                version,
                sequence: 9,
                motor_count: 3,
                commands: [0.25, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            };
            let bytes = m.encode();
            assert_eq!(bytes.len(), 16 + 4 * 3, "same layout in both versions");
            assert_eq!(bytes[4], version);
            assert_eq!(&bytes[16..20], &0.25f32.to_le_bytes());
            assert_eq!(MotorPacket::decode(&bytes).unwrap(), m);
        }
    }

    #[test]
    fn motor_packet_golden_bytes() {
        let m = MotorPacket {
            version: 2,
            sequence: 5,
            motor_count: 1,
            commands: [0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        };
        assert_eq!(
            m.encode(),
            [
                0x46, 0x43, 0x4D, 0x4F, 0x02, 0x01, 0x00, 0x00, // "FCMO", v2, m = 1, flags 0
                0x05, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // sequence 5
                0x00, 0x00, 0x00, 0x3F, // 0.5
            ]
        );
    }

    #[test]
    fn malformed_packets_are_typed_errors() {
        let bytes = sensor().encode();
        assert!(matches!(
            SensorPacket::decode(&bytes[..50]),
            Err(BridgeError::TooShort { len: 50, need: 72 })
        ));
        assert!(matches!(MotorPacket::decode(&bytes), Err(BridgeError::BadMagic(..))));
        let mut v = bytes.clone();
        v[4] = 3;
        assert!(matches!(SensorPacket::decode(&v), Err(BridgeError::Version(3))));
        v[4] = 0;
        assert!(matches!(SensorPacket::decode(&v), Err(BridgeError::Version(0))));
        let mut v = bytes;
        v[5] = 9;
        assert!(matches!(SensorPacket::decode(&v), Err(BridgeError::MotorCount(9))));
        // Version 2 announcing a pose it does not carry (in full).
        let v2 = SensorPacket { pose: Some(POSE), ..sensor() }.encode();
        assert_eq!(v2.len(), 88);
        assert!(matches!(
            SensorPacket::decode(&v2[..72]),
            Err(BridgeError::TooShort { len: 72, need: 88 })
        ));
        assert!(matches!(
            SensorPacket::decode(&v2[..87]),
            Err(BridgeError::TooShort { len: 87, need: 88 })
        ));
        // Announcing a GNSS solution, after a pose or alone, it does not carry in full.
        let both = SensorPacket { pose: Some(POSE), gnss: Some(GNSS), ..sensor() }.encode();
        assert_eq!(both.len(), 140);
        for len in [88, 139] {
            assert!(matches!(
                SensorPacket::decode(&both[..len]),
                Err(BridgeError::TooShort { len: l, need: 140 }) if l == len
            ));
        }
        let alone = SensorPacket { gnss: Some(GNSS), ..sensor() }.encode();
        assert_eq!(alone.len(), 124);
        assert!(matches!(
            SensorPacket::decode(&alone[..123]),
            Err(BridgeError::TooShort { len: 123, need: 124 })
        ));
        // Announcing a magnetometer block it does not carry in full, alone (m = 6: 72 + 12),
        // after a pose (72 + 16 + 12), after a GNSS solution (72 + 52 + 12) and after both
        // (72 + 16 + 52 + 12); cut anywhere from the block's start to its last byte, the need
        // is the whole packet, and a cut in an earlier block names that block's end.
        for (pose, gnss, need) in [
            (None, None, 84),
            (Some(POSE), None, 100),
            (None, Some(GNSS), 136),
            (Some(POSE), Some(GNSS), 152),
        ] {
            let bytes =
                SensorPacket { pose, gnss, magnetometer_ut: Some(FIELD_UT), ..sensor() }.encode();
            assert_eq!(bytes.len(), need);
            for len in [need - MAGNETOMETER_LEN, need - 1] {
                assert!(
                    matches!(
                        SensorPacket::decode(&bytes[..len]),
                        Err(BridgeError::TooShort { len: l, need: n }) if l == len && n == need
                    ),
                    "{len} of {need} bytes"
                );
            }
            assert!(SensorPacket::decode(&bytes).is_ok());
        }
        let with_all = SensorPacket {
            pose: Some(POSE),
            gnss: Some(GNSS),
            magnetometer_ut: Some(FIELD_UT),
            ..sensor()
        }
        .encode();
        assert!(matches!(
            SensorPacket::decode(&with_all[..100]),
            Err(BridgeError::TooShort { len: 100, need: 140 })
        ));
        assert_eq!(MAX_PACKET_LEN, 48 + 4 * 8 + 16 + 52 + 12);
    }
}
