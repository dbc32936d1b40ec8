//! iSentek IST8310 3-axis magnetometer on I²C: identity check, configuration, single
//! measurements, decoding to microtesla, and the compass's health.
//!
//! Why: the IST8310 is the compass of many GNSS masts (and of DJI's RoboMaster development
//! board); the heading outdoors comes from it where it is fitted (`flight::magnetometer`). The
//! board adapts its I²C peripheral to [`I2cRegisterBus`], calls [`Ist8310`]'s `init` once, then
//! its `read` at [`MEASUREMENT_RATE_HZ`] or slower: each read collects the measurement
//! the previous one started and starts the next.
//!
//! Register map and values (iSentek IST8310 datasheet, section "register map"; the same values
//! as PX4's `iSentek/ist8310` driver and ArduPilot's `AP_Compass_IST8310`):
//! - I²C address 0x0C–0x0F set by the CAD0/CAD1 pins; GNSS masts use 0x0E ([`DEFAULT_ADDRESS`]);
//! - WAI (0x00) reads 0x10;
//! - STAT1 (0x02): bit 0 DRDY (a measurement is ready), bit 1 DOR (one was skipped);
//! - DATAXL..DATAZH (0x03–0x08): X, Y, Z as 16-bit two's complement, low byte first;
//! - CNTL1 (0x0A): mode bits 3:0, 0001 = single measurement (the device returns to standby);
//! - CNTL2 (0x0B): bit 0 SRST, a soft reset;
//! - AVGCNTL (0x41): bits 5:3 averaging of Y, bits 2:0 of X and Z; 100 = 16 times on both (0x24);
//! - PDCNTL (0x42): bits 7:6 pulse duration, 11 = normal (0xC0);
//! - sensitivity 0.3 µT/LSB; full scale ±1600 µT on X and Y, ±2500 µT on Z: a count beyond it is
//!   not a valid measurement ([`CompassError::Overflow`]; ArduPilot rejects the same counts).
//!
//! The field stays in the sensor's axes; the mounting is learned (`flight::magnetometer`).

use super::compass::{
    le_i16, CompassDevice, CompassError, CompassReading, DelayUs, I2cRegisterBus,
};

/// The 7-bit I²C address with CAD0 and CAD1 high, as GNSS masts wire it.
pub const DEFAULT_ADDRESS: u8 = 0x0E;

/// Register addresses.
pub mod reg {
    /// WAI: device identity.
    pub const WAI: u8 = 0x00;
    /// STAT1: bit 0 DRDY, bit 1 DOR.
    pub const STAT1: u8 = 0x02;
    /// DATAXL: X low byte, first of the six data registers.
    pub const DATAXL: u8 = 0x03;
    /// CNTL1: operating mode.
    pub const CNTL1: u8 = 0x0A;
    /// CNTL2: bit 0 soft reset.
    pub const CNTL2: u8 = 0x0B;
    /// AVGCNTL: averaging.
    pub const AVGCNTL: u8 = 0x41;
    /// PDCNTL: pulse duration.
    pub const PDCNTL: u8 = 0x42;
}

/// WAI value of the IST8310.
pub const WAI_VALUE: u8 = 0x10;
/// STAT1 bit 0: data ready.
pub const STAT1_DRDY: u8 = 0x01;
/// CNTL1: start one measurement.
pub const CNTL1_SINGLE_MEASUREMENT: u8 = 0x01;
/// CNTL2: soft reset.
pub const CNTL2_SOFT_RESET: u8 = 0x01;
/// AVGCNTL: 16 times on Y (bits 5:3 = 100) and on X, Z (bits 2:0 = 100).
pub const AVGCNTL_16_TIMES: u8 = 0x24;
/// PDCNTL: normal pulse duration (bits 7:6 = 11).
pub const PDCNTL_NORMAL: u8 = 0xC0;
/// Wait after the soft reset before the identity is read, µs: 50 ms, a generous margin (we
/// found no reset time in the datasheet to cite).
pub const SOFT_RESET_WAIT_US: u32 = 50_000;
/// Sensitivity, µT per LSB (datasheet).
pub const UT_PER_LSB: f32 = 0.3;
/// Full scale of X and Y, µT (datasheet).
pub const FULL_SCALE_XY_UT: f32 = 1600.0;
/// Full scale of Z, µT (datasheet).
pub const FULL_SCALE_Z_UT: f32 = 2500.0;
/// The largest valid count on X and Y (1600 µT / 0.3 µT, rounded up as ArduPilot does).
pub const MAX_COUNT_XY: i16 = 5_334;
/// The largest valid count on Z (2500 µT / 0.3 µT, rounded up).
pub const MAX_COUNT_Z: i16 = 8_334;
/// The rate a single measurement is read and restarted at, Hz: with 16 times averaging a
/// measurement takes several milliseconds; ArduPilot's driver polls every 10 ms.
pub const MEASUREMENT_RATE_HZ: u32 = 100;
/// Bytes of one read: STAT1 then the six data registers.
pub const READ_LEN: usize = 7;

/// Decode a burst from STAT1 (STAT1, XL, XH, YL, YH, ZL, ZH): the reading, or
/// [`CompassError::NotReady`] without DRDY, or [`CompassError::Overflow`] beyond the full scale.
pub fn decode<E>(bytes: &[u8; READ_LEN]) -> Result<CompassReading, CompassError<E>> {
    if bytes[0] & STAT1_DRDY == 0 {
        return Err(CompassError::NotReady);
    }
    let raw = [le_i16(bytes[1], bytes[2]), le_i16(bytes[3], bytes[4]), le_i16(bytes[5], bytes[6])];
    let limits = [MAX_COUNT_XY, MAX_COUNT_XY, MAX_COUNT_Z];
    if raw.iter().zip(limits).any(|(&r, limit)| r > limit || r < -limit) {
        return Err(CompassError::Overflow);
    }
    Ok(CompassReading { raw, field_ut: raw.map(|r| f32::from(r) * UT_PER_LSB) })
}

/// The IST8310 chip: selects this driver's `init` and `read` for a [`CompassDevice`].
#[derive(Debug)]
pub enum Chip {}

/// The IST8310 on an [`I2cRegisterBus`].
pub type Ist8310<B> = CompassDevice<B, Chip>;

impl<B: I2cRegisterBus> CompassDevice<B, Chip> {
    /// Soft reset, wait, check WAI, set the averaging and pulse duration, read them back, and
    /// start the first measurement. Nothing more is written after a WAI mismatch.
    pub fn init<D: DelayUs>(&mut self, delay: &mut D) -> Result<(), CompassError<B::Error>> {
        let (reset, identity) = ((reg::CNTL2, CNTL2_SOFT_RESET), (reg::WAI, WAI_VALUE));
        self.reset_and_identify(delay, reset, SOFT_RESET_WAIT_US, identity)?;
        self.write_verified(&[(reg::AVGCNTL, AVGCNTL_16_TIMES), (reg::PDCNTL, PDCNTL_NORMAL)])?;
        self.bus.write_one(self.address, reg::CNTL1, CNTL1_SINGLE_MEASUREMENT)
    }

    /// Collect the measurement started before and start the next one; the health report
    /// counts the result. After a bus error or an overflow the next measurement is started
    /// too (best effort), so one bad read does not stop the sensor.
    pub fn read(&mut self) -> Result<CompassReading, CompassError<B::Error>> {
        let mut bytes = [0u8; READ_LEN];
        let result = match self.bus.read_registers(self.address, reg::STAT1, &mut bytes) {
            Ok(()) => decode(&bytes),
            Err(e) => Err(CompassError::Bus(e)),
        };
        // Not ready: the measurement is still running; do not restart it.
        let result = if matches!(result, Err(CompassError::NotReady)) {
            result
        } else {
            match self.bus.write_one(self.address, reg::CNTL1, CNTL1_SINGLE_MEASUREMENT) {
                Err(e) if result.is_ok() => Err(e),
                _ => result,
            }
        };
        self.recorded(result)
    }
}

#[cfg(test)]
mod tests {
    use super::super::compass::mock::{MockBus, Nack, NoDelay, Op};
    use super::super::compass::CompassState;
    use super::*;
    use std::vec::Vec;

    fn device() -> MockBus {
        let mut bus = MockBus::new(DEFAULT_ADDRESS);
        bus.registers[usize::from(reg::WAI)] = WAI_VALUE;
        bus
    }

    #[test]
    fn init_writes_the_sequence_byte_for_byte() {
        let mut compass = Ist8310::new(device(), DEFAULT_ADDRESS);
        let mut delay = NoDelay(0);
        compass.init(&mut delay).unwrap();
        let a = DEFAULT_ADDRESS;
        let expected: Vec<Op> = std::vec![
            Op::Write { address: a, reg: 0x0B, value: 0x01 },
            Op::Read { address: a, reg: 0x00, len: 1 },
            Op::Write { address: a, reg: 0x41, value: 0x24 },
            Op::Write { address: a, reg: 0x42, value: 0xC0 },
            Op::Read { address: a, reg: 0x41, len: 1 },
            Op::Read { address: a, reg: 0x42, len: 1 },
            Op::Write { address: a, reg: 0x0A, value: 0x01 },
        ];
        assert_eq!(compass.release().ops, expected);
        assert_eq!(delay.0, SOFT_RESET_WAIT_US);
    }

    /// Recorded bytes: STAT1 = DRDY; X = +100 (0x0064), Y = −50 (0xFFCE), Z = +2000 (0x07D0):
    /// low bytes first, X then Y then Z, 0.3 µT each.
    #[test]
    fn decodes_sign_scale_and_axis_order() {
        let mut bus = device();
        bus.registers[2..9].copy_from_slice(&[0x01, 0x64, 0x00, 0xCE, 0xFF, 0xD0, 0x07]);
        let mut compass = Ist8310::new(bus, DEFAULT_ADDRESS);
        let reading = compass.read().unwrap();
        assert_eq!(reading.raw, [100, -50, 2000]);
        for (got, want) in reading.field_ut.iter().zip([30.0, -15.0, 600.0]) {
            assert!((got - want).abs() < 1e-4, "{got} vs {want}");
        }
        // The read restarted the measurement.
        let ops = compass.release().ops;
        assert_eq!(
            ops.last(),
            Some(&Op::Write { address: DEFAULT_ADDRESS, reg: reg::CNTL1, value: 0x01 })
        );
        // The full scale's last counts are valid.
        let edge = decode::<()>(&[0x01, 0xD6, 0x14, 0x2A, 0xEB, 0x8E, 0x20]).unwrap();
        assert_eq!(edge.raw, [MAX_COUNT_XY, -MAX_COUNT_XY, MAX_COUNT_Z]);
    }

    #[test]
    fn overflow_and_not_ready_are_errors() {
        // X = 5335 (0x14D7): one count beyond ±1600 µT.
        assert_eq!(
            decode::<()>(&[0x01, 0xD7, 0x14, 0x00, 0x00, 0x00, 0x00]),
            Err(CompassError::Overflow)
        );
        // Z = −8335 (0xDF71).
        assert_eq!(
            decode::<()>(&[0x01, 0x00, 0x00, 0x00, 0x00, 0x71, 0xDF]),
            Err(CompassError::Overflow)
        );
        // No DRDY: not ready, and the running measurement is not restarted.
        let mut compass = Ist8310::new(device(), DEFAULT_ADDRESS);
        assert_eq!(compass.read(), Err(CompassError::NotReady));
        assert!(!compass.release().ops.iter().any(|op| matches!(op, Op::Write { .. })));
    }

    #[test]
    fn a_missing_or_wrong_device_is_an_error() {
        let mut absent = device();
        absent.present = false;
        let mut compass = Ist8310::new(absent, DEFAULT_ADDRESS);
        assert_eq!(compass.init(&mut NoDelay(0)), Err(CompassError::Bus(Nack)));
        // Another chip answering with another identity: nothing written after the check.
        let mut other = device();
        other.registers[usize::from(reg::WAI)] = 0xFF;
        let mut compass = Ist8310::new(other, DEFAULT_ADDRESS);
        assert_eq!(
            compass.init(&mut NoDelay(0)),
            Err(CompassError::WrongDevice { expected: 0x10, read: 0xFF })
        );
        assert_eq!(compass.release().ops.len(), 2);
        // AVGCNTL not taking the value.
        let mut stubborn = device();
        stubborn.read_only.push(reg::AVGCNTL);
        let mut compass = Ist8310::new(stubborn, DEFAULT_ADDRESS);
        assert_eq!(
            compass.init(&mut NoDelay(0)),
            Err(CompassError::ConfigMismatch { register: 0x41, written: 0x24, read: 0x00 })
        );
    }

    /// A sensor unplugged after working is reported lost after ten reads, never a panic; one
    /// whose registers freeze is reported stuck.
    #[test]
    fn health_reports_a_lost_and_a_stuck_sensor() {
        let mut bus = device();
        bus.registers[2..9].copy_from_slice(&[0x01, 0x64, 0x00, 0xCE, 0xFF, 0xD0, 0x07]);
        let mut compass = Ist8310::new(bus, DEFAULT_ADDRESS);
        compass.init(&mut NoDelay(0)).unwrap();
        // The mock's registers never change: the same reading every time.
        for _ in 0..24 {
            compass.read().unwrap();
        }
        assert_eq!(compass.health().state, CompassState::Healthy);
        compass.read().unwrap();
        assert_eq!(compass.health().state, CompassState::Stuck);
        let mut bus = compass.release();
        bus.present = false;
        let mut compass = Ist8310::new(bus, DEFAULT_ADDRESS);
        for _ in 0..10 {
            assert_eq!(compass.read(), Err(CompassError::Bus(Nack)));
        }
        assert_eq!(compass.health().state, CompassState::Lost);
        assert_eq!(compass.health().failures, 10);
    }
}
