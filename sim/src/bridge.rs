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
//! [`SensorPacket`] and [`MotorPacket`].

use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::time::Duration;

use firmware::app::hal::{Imu, ImuSample, Motors, MAX_MOTORS};

use crate::scenario::FlightApp;

/// Port the flight-application side listens on (Betaflight SITL's FDM input port).
pub const DEFAULT_FC_PORT: u16 = 9003;
/// Port an external simulator usually listens on (Betaflight SITL's motor output port).
pub const DEFAULT_SIM_PORT: u16 = 9002;
/// Protocol version carried in byte 4 of both packets.
pub const BRIDGE_VERSION: u8 = 1;
/// Magic of the sensor packet, bytes 0–3 (ASCII).
pub const SENSOR_MAGIC: [u8; 4] = *b"FCSN";
/// Magic of the motor packet, bytes 0–3 (ASCII).
pub const MOTOR_MAGIC: [u8; 4] = *b"FCMO";
/// Sensor packet header length before the motor speeds, bytes.
pub const SENSOR_HEADER_LEN: usize = 48;
/// Motor packet header length before the commands, bytes.
pub const MOTOR_HEADER_LEN: usize = 16;
/// Longest packet, bytes (sensor packet with 8 motors).
pub const MAX_PACKET_LEN: usize = SENSOR_HEADER_LEN + 4 * MAX_MOTORS;

/// Why a packet or an exchange failed.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// Socket error.
    #[error("bridge socket: {0}")]
    Io(std::io::Error),
    /// Nothing arrived in time.
    #[error("no packet within {0:?}")]
    Timeout(Duration),
    /// The packet is shorter than its header or its motor count needs.
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
    #[error("bridge version {0} is not supported (this side speaks {BRIDGE_VERSION})")]
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

/// Simulator → application, `48 + 4m` bytes.
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | `[u8; 4]` | magic `"FCSN"` |
/// | 4 | `u8` | version (1) |
/// | 5 | `u8` | motor count m (1–8) |
/// | 6 | `u16` | flags, 0 (reserved) |
/// | 8 | `u64` | sequence number, echoed in the reply |
/// | 16 | `f64` | simulation time, s |
/// | 24 | `f32 × 3` | gyro, rad/s, IMU axes |
/// | 36 | `f32 × 3` | specific force, m/s², IMU axes |
/// | 48 | `f32 × m` | motor speeds, rad/s; NaN = not reported |
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorPacket {
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
}

/// Application → simulator, `16 + 4m` bytes.
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | `[u8; 4]` | magic `"FCMO"` |
/// | 4 | `u8` | version (1) |
/// | 5 | `u8` | motor count m (1–8) |
/// | 6 | `u16` | flags, 0 (reserved) |
/// | 8 | `u64` | sequence number of the sensor packet answered |
/// | 16 | `f32 × m` | commands δ ∈ [0, 1] |
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorPacket {
    /// Sequence number of the sensor packet this answers.
    pub sequence: u64,
    /// Number of motors, 1..=8.
    pub motor_count: u8,
    /// Commands δ ∈ [0, 1] (first `motor_count` used).
    pub commands: [f32; MAX_MOTORS],
}

fn check_header(bytes: &[u8], magic: [u8; 4], header_len: usize) -> Result<usize, BridgeError> {
    if bytes.len() < header_len {
        return Err(BridgeError::TooShort { len: bytes.len(), need: header_len });
    }
    let got: [u8; 4] = bytes[0..4].try_into().expect("4 bytes");
    if got != magic {
        return Err(BridgeError::BadMagic(got, magic));
    }
    if bytes[4] != BRIDGE_VERSION {
        return Err(BridgeError::Version(bytes[4]));
    }
    let m = bytes[5];
    if m == 0 || m as usize > MAX_MOTORS {
        return Err(BridgeError::MotorCount(m));
    }
    let need = header_len + 4 * m as usize;
    if bytes.len() < need {
        return Err(BridgeError::TooShort { len: bytes.len(), need });
    }
    Ok(m as usize)
}

fn f32_at(bytes: &[u8], offset: usize) -> f32 {
    f32::from_le_bytes(bytes[offset..offset + 4].try_into().expect("4 bytes"))
}

fn write_header(out: &mut Vec<u8>, magic: [u8; 4], motor_count: u8, sequence: u64) {
    out.extend_from_slice(&magic);
    out.push(BRIDGE_VERSION);
    out.push(motor_count);
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&sequence.to_le_bytes());
}

impl SensorPacket {
    /// The packet's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let m = self.motor_count as usize;
        let mut out = Vec::with_capacity(SENSOR_HEADER_LEN + 4 * m);
        write_header(&mut out, SENSOR_MAGIC, self.motor_count, self.sequence);
        out.extend_from_slice(&self.time_s.to_le_bytes());
        for v in self.imu.gyro_rad_s.iter().chain(self.imu.accel_mps2.iter()) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for s in &self.speeds_rad_s[..m] {
            out.extend_from_slice(&s.unwrap_or(f32::NAN).to_le_bytes());
        }
        out
    }

    /// Parses a packet.
    pub fn decode(bytes: &[u8]) -> Result<Self, BridgeError> {
        let m = check_header(bytes, SENSOR_MAGIC, SENSOR_HEADER_LEN)?;
        let mut speeds_rad_s = [None; MAX_MOTORS];
        for (i, s) in speeds_rad_s.iter_mut().enumerate().take(m) {
            let v = f32_at(bytes, SENSOR_HEADER_LEN + 4 * i);
            *s = (!v.is_nan()).then_some(v);
        }
        Ok(Self {
            sequence: u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes")),
            time_s: f64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes")),
            imu: ImuSample {
                gyro_rad_s: [f32_at(bytes, 24), f32_at(bytes, 28), f32_at(bytes, 32)],
                accel_mps2: [f32_at(bytes, 36), f32_at(bytes, 40), f32_at(bytes, 44)],
            },
            motor_count: m as u8,
            speeds_rad_s,
        })
    }
}

impl MotorPacket {
    /// The packet's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let m = self.motor_count as usize;
        let mut out = Vec::with_capacity(MOTOR_HEADER_LEN + 4 * m);
        write_header(&mut out, MOTOR_MAGIC, self.motor_count, self.sequence);
        for c in &self.commands[..m] {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out
    }

    /// Parses a packet.
    pub fn decode(bytes: &[u8]) -> Result<Self, BridgeError> {
        let m = check_header(bytes, MOTOR_MAGIC, MOTOR_HEADER_LEN)?;
        let mut commands = [0.0; MAX_MOTORS];
        for (i, c) in commands.iter_mut().enumerate().take(m) {
            *c = f32_at(bytes, MOTOR_HEADER_LEN + 4 * i);
        }
        Ok(Self {
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
    buf: [u8; 1500],
}

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
            buf: [0; 1500],
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> Result<SocketAddr, BridgeError> {
        Ok(self.socket.local_addr()?)
    }

    /// Waits up to `timeout` for one sensor packet, runs one application step on it and sends
    /// the motor packet back to the sender. Returns the packet answered. Malformed packets are
    /// answered with nothing and reported as errors (the caller decides whether to go on).
    pub fn step<A: FlightApp>(
        &mut self,
        app: &mut A,
        timeout: Duration,
    ) -> Result<(SensorPacket, MotorPacket), BridgeError> {
        self.socket.set_read_timeout(Some(timeout))?;
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
        let now_us = (sensor.time_s.max(0.0) * 1e6).round() as u64;
        app.step(now_us, &mut imu, &mut self.motors);
        let reply = MotorPacket {
            sequence: sensor.sequence,
            motor_count: sensor.motor_count,
            commands: self.motors.commands,
        };
        self.socket.send_to(&reply.encode(), from)?;
        Ok((sensor, reply))
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
            sequence: 0x0102_0304_0506_0708,
            time_s: 12.5,
            imu: ImuSample { gyro_rad_s: [0.1, -0.2, 0.3], accel_mps2: [1.0, 2.0, -9.80665] },
            motor_count: 6,
            speeds_rad_s,
        }
    }

    #[test]
    fn packets_round_trip_through_bytes() {
        let s = sensor();
        let bytes = s.encode();
        assert_eq!(bytes.len(), 48 + 4 * 6);
        assert_eq!(&bytes[0..4], b"FCSN");
        assert_eq!(bytes[8], 0x08, "sequence is little-endian");
        assert_eq!(SensorPacket::decode(&bytes).unwrap(), s);
        let m = MotorPacket {
            sequence: 9,
            motor_count: 3,
            commands: [0.25, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        };
        let bytes = m.encode();
        assert_eq!(bytes.len(), 16 + 4 * 3);
        assert_eq!(&bytes[16..20], &0.25f32.to_le_bytes());
        assert_eq!(MotorPacket::decode(&bytes).unwrap(), m);
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
        v[4] = 2;
        assert!(matches!(SensorPacket::decode(&v), Err(BridgeError::Version(2))));
        let mut v = bytes;
        v[5] = 9;
        assert!(matches!(SensorPacket::decode(&v), Err(BridgeError::MotorCount(9))));
    }
}
