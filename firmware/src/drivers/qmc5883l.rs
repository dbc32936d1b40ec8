//! QST QMC5883L 3-axis magnetometer on I²C: identity check, configuration for continuous
//! measurement, decoding to microtesla, and the compass's health.
//!
//! Why: the QMC5883L is the compass of the inexpensive GNSS masts (the "HMC5883L" of many
//! modules is in fact this chip); the heading outdoors comes from it where it is fitted
//! (`flight::magnetometer`). The board adapts its I²C peripheral to [`I2cRegisterBus`], calls
//! [`Qmc5883l`]'s `init` once, then its `read` at [`OUTPUT_RATE_HZ`].
//!
//! Register map and values (QST QMC5883L datasheet rev. 1.0, section 9 "register map" and
//! table 2 "specifications"; the same configuration as ArduPilot's `AP_Compass_QMC5883L`):
//! - I²C address 0x0D;
//! - data X, Y, Z (0x00–0x05): 16-bit two's complement, low byte first;
//! - status (0x06): bit 0 DRDY (new data; cleared when the data registers are read), bit 1 OVL
//!   (some axis beyond the range: the data are not valid), bit 2 DOR (data skipped);
//! - control 1 (0x09): OSR bits 7:6 (00 = 512), RNG bits 5:4 (01 = ±8 G), ODR bits 3:2
//!   (10 = 100 Hz), MODE bits 1:0 (01 = continuous): 0x19;
//! - control 2 (0x0A): bit 7 SOFT_RST;
//! - SET/RESET period (0x0B): the datasheet asks for 0x01;
//! - chip ID (0x0D): 0xFF;
//! - sensitivity 3,000 LSB/G at ±8 G (12,000 at ±2 G): 1/30 µT per LSB. The ±8 G range (±800 µT)
//!   leaves room for a few hundred µT of hard iron on a craft, which ±2 G (±200 µT) does not.
//!
//! The status is read first, in its own transfer: reading the data clears DRDY, so a burst over
//! data then status would always report "not ready". The field stays in the sensor's axes.

use super::compass::{
    le_i16, CompassDevice, CompassError, CompassReading, DelayUs, I2cRegisterBus,
};

/// The 7-bit I²C address (fixed).
pub const DEFAULT_ADDRESS: u8 = 0x0D;

/// Register addresses.
pub mod reg {
    /// Data output X low byte, first of the six data registers.
    pub const DATA_X_LSB: u8 = 0x00;
    /// Status: bit 0 DRDY, bit 1 OVL, bit 2 DOR.
    pub const STATUS: u8 = 0x06;
    /// Control 1: OSR, RNG, ODR, MODE.
    pub const CONTROL1: u8 = 0x09;
    /// Control 2: bit 7 soft reset.
    pub const CONTROL2: u8 = 0x0A;
    /// SET/RESET period.
    pub const SET_RESET_PERIOD: u8 = 0x0B;
    /// Chip ID.
    pub const CHIP_ID: u8 = 0x0D;
}

/// Chip ID value of the QMC5883L.
pub const CHIP_ID_VALUE: u8 = 0xFF;
/// Status bit 0: data ready.
pub const STATUS_DRDY: u8 = 0x01;
/// Status bit 1: overflow.
pub const STATUS_OVL: u8 = 0x02;
/// Control 2: soft reset.
pub const CONTROL2_SOFT_RESET: u8 = 0x80;
/// The SET/RESET period the datasheet asks for.
pub const SET_RESET_PERIOD_VALUE: u8 = 0x01;
/// Control 1: OSR 512 (00), ±8 G (01), 100 Hz (10), continuous (01).
#[allow(clippy::identity_op)] // every field spelled out, the zero one too
pub const CONTROL1_VALUE: u8 = (0b00 << 6) | (0b01 << 4) | (0b10 << 2) | 0b01;
/// Output data rate of [`CONTROL1_VALUE`], Hz.
pub const OUTPUT_RATE_HZ: u32 = 100;
/// Wait after the soft reset before the identity is read, µs: 10 ms, a margin (we found no
/// reset time in the datasheet to cite).
pub const SOFT_RESET_WAIT_US: u32 = 10_000;
/// Sensitivity at ±8 G, LSB per gauss (datasheet table 2).
pub const LSB_PER_GAUSS: f32 = 3_000.0;
/// Microtesla per gauss.
pub const UT_PER_GAUSS: f32 = 100.0;
/// Sensitivity, µT per LSB.
pub const UT_PER_LSB: f32 = UT_PER_GAUSS / LSB_PER_GAUSS;

/// Decode the status byte and the six data bytes: the reading, [`CompassError::NotReady`]
/// without DRDY, [`CompassError::Overflow`] with OVL.
pub fn decode<E>(status: u8, data: &[u8; 6]) -> Result<CompassReading, CompassError<E>> {
    if status & STATUS_DRDY == 0 {
        return Err(CompassError::NotReady);
    }
    if status & STATUS_OVL != 0 {
        return Err(CompassError::Overflow);
    }
    let raw = [le_i16(data[0], data[1]), le_i16(data[2], data[3]), le_i16(data[4], data[5])];
    Ok(CompassReading { raw, field_ut: raw.map(|r| f32::from(r) * UT_PER_LSB) })
}

/// The QMC5883L chip: selects this driver's `init` and `read` for a [`CompassDevice`].
#[derive(Debug)]
pub enum Chip {}

/// The QMC5883L on an [`I2cRegisterBus`].
pub type Qmc5883l<B> = CompassDevice<B, Chip>;

impl<B: I2cRegisterBus> CompassDevice<B, Chip> {
    /// Soft reset, wait, check the chip ID, write the SET/RESET period and control 1 (which
    /// starts continuous measurement), and read both back. Nothing more is written after a chip
    /// ID mismatch.
    pub fn init<D: DelayUs>(&mut self, delay: &mut D) -> Result<(), CompassError<B::Error>> {
        let (reset, identity) =
            ((reg::CONTROL2, CONTROL2_SOFT_RESET), (reg::CHIP_ID, CHIP_ID_VALUE));
        self.reset_and_identify(delay, reset, SOFT_RESET_WAIT_US, identity)?;
        self.write_verified(&[
            (reg::SET_RESET_PERIOD, SET_RESET_PERIOD_VALUE),
            (reg::CONTROL1, CONTROL1_VALUE),
        ])
    }

    /// Read the status, then (when ready) the data; the health report counts the result.
    pub fn read(&mut self) -> Result<CompassReading, CompassError<B::Error>> {
        let result = self.read_unrecorded();
        self.recorded(result)
    }

    fn read_unrecorded(&mut self) -> Result<CompassReading, CompassError<B::Error>> {
        let status = self.bus.read_one(self.address, reg::STATUS)?;
        if status & STATUS_DRDY == 0 {
            return Err(CompassError::NotReady);
        }
        let mut data = [0u8; 6];
        self.bus
            .read_registers(self.address, reg::DATA_X_LSB, &mut data)
            .map_err(CompassError::Bus)?;
        decode(status, &data)
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
        bus.registers[usize::from(reg::CHIP_ID)] = CHIP_ID_VALUE;
        bus
    }

    #[test]
    fn init_writes_the_sequence_byte_for_byte() {
        assert_eq!(CONTROL1_VALUE, 0x19);
        let mut compass = Qmc5883l::new(device(), DEFAULT_ADDRESS);
        let mut delay = NoDelay(0);
        compass.init(&mut delay).unwrap();
        let a = DEFAULT_ADDRESS;
        let expected: Vec<Op> = std::vec![
            Op::Write { address: a, reg: 0x0A, value: 0x80 },
            Op::Read { address: a, reg: 0x0D, len: 1 },
            Op::Write { address: a, reg: 0x0B, value: 0x01 },
            Op::Write { address: a, reg: 0x09, value: 0x19 },
            Op::Read { address: a, reg: 0x0B, len: 1 },
            Op::Read { address: a, reg: 0x09, len: 1 },
        ];
        assert_eq!(compass.release().ops, expected);
        assert_eq!(delay.0, SOFT_RESET_WAIT_US);
    }

    /// Recorded bytes: X = +600 (0x0258), Y = −1500 (0xFA24), Z = +30 (0x001E), low bytes
    /// first, X then Y then Z, 1/30 µT each; status read first, alone.
    #[test]
    fn decodes_sign_scale_and_axis_order() {
        let mut bus = device();
        bus.registers[0..7].copy_from_slice(&[0x58, 0x02, 0x24, 0xFA, 0x1E, 0x00, 0x01]);
        let mut compass = Qmc5883l::new(bus, DEFAULT_ADDRESS);
        let reading = compass.read().unwrap();
        assert_eq!(reading.raw, [600, -1500, 30]);
        for (got, want) in reading.field_ut.iter().zip([20.0, -50.0, 1.0]) {
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
        let a = DEFAULT_ADDRESS;
        assert_eq!(
            compass.release().ops,
            std::vec![
                Op::Read { address: a, reg: 0x06, len: 1 },
                Op::Read { address: a, reg: 0x00, len: 6 }
            ]
        );
    }

    #[test]
    fn overflow_and_not_ready_are_errors() {
        // DRDY and OVL: the data are not valid.
        assert_eq!(decode::<()>(0x03, &[0xFF, 0x7F, 0, 0, 0, 0]), Err(CompassError::Overflow));
        // No DRDY: the data are not read at all.
        let mut compass = Qmc5883l::new(device(), DEFAULT_ADDRESS);
        assert_eq!(compass.read(), Err(CompassError::NotReady));
        assert_eq!(compass.release().ops.len(), 1);
        // DOR alone (a sample skipped) with DRDY is a valid reading.
        assert!(decode::<()>(0x05, &[1, 0, 2, 0, 3, 0]).is_ok());
    }

    #[test]
    fn a_missing_or_wrong_device_is_an_error() {
        let mut absent = device();
        absent.present = false;
        let mut compass = Qmc5883l::new(absent, DEFAULT_ADDRESS);
        assert_eq!(compass.init(&mut NoDelay(0)), Err(CompassError::Bus(Nack)));
        let mut other = device();
        other.registers[usize::from(reg::CHIP_ID)] = 0x00;
        let mut compass = Qmc5883l::new(other, DEFAULT_ADDRESS);
        assert_eq!(
            compass.init(&mut NoDelay(0)),
            Err(CompassError::WrongDevice { expected: 0xFF, read: 0x00 })
        );
        assert_eq!(compass.release().ops.len(), 2);
        let mut stubborn = device();
        stubborn.read_only.push(reg::CONTROL1);
        let mut compass = Qmc5883l::new(stubborn, DEFAULT_ADDRESS);
        assert_eq!(
            compass.init(&mut NoDelay(0)),
            Err(CompassError::ConfigMismatch { register: 0x09, written: 0x19, read: 0x00 })
        );
    }

    /// A sensor that stops converting (DRDY never set again) is reported lost; a saturated one
    /// (a magnet beside it) as saturated; never a panic.
    #[test]
    fn health_reports_a_lost_and_a_saturated_sensor() {
        let mut bus = device();
        bus.registers[0..7].copy_from_slice(&[0x58, 0x02, 0x24, 0xFA, 0x1E, 0x00, 0x01]);
        let mut compass = Qmc5883l::new(bus, DEFAULT_ADDRESS);
        compass.init(&mut NoDelay(0)).unwrap();
        compass.read().unwrap();
        assert_eq!(compass.health().state, CompassState::Healthy);
        let mut bus = compass.release();
        bus.registers[usize::from(reg::STATUS)] = 0x00;
        let mut compass = Qmc5883l::new(bus, DEFAULT_ADDRESS);
        for _ in 0..10 {
            assert_eq!(compass.read(), Err(CompassError::NotReady));
        }
        assert_eq!(compass.health().state, CompassState::Lost);
        let mut bus = compass.release();
        bus.registers[usize::from(reg::STATUS)] = STATUS_DRDY | STATUS_OVL;
        let mut compass = Qmc5883l::new(bus, DEFAULT_ADDRESS);
        for _ in 0..10 {
            assert_eq!(compass.read(), Err(CompassError::Overflow));
        }
        assert_eq!(compass.health().state, CompassState::Saturated);
    }
}
