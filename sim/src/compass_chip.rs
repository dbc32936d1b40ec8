//! Simulated compass chips on I²C (issue 55): an IST8310 and a QMC5883L as register devices
//! behind `firmware::drivers::compass::I2cRegisterBus`, so the firmware's own drivers
//! (`firmware::drivers::{ist8310, qmc5883l}`) run against them unchanged, as the GNSS receiver's
//! NAV-PVT bytes (`crate::gnss`) go through the firmware's UBX parser.
//!
//! Why registers and not a convenient field: what a real chip does to a reading (quantisation to
//! its LSB, its byte order, its range and overflow flag, the time a conversion takes, a status
//! bit that clears when the data are read, a device that stops answering) is what the drivers and
//! the calibration meet on a board; a simulator that hands the firmware microtesla skips all of
//! it.
//!
//! # The chips
//!
//! Both hold the latest sample of a [`SimMagnetometer`] (the field, soft and hard iron, motor
//! interference and noise of its [`MagnetometerSpec`]), drawn when a conversion completes in
//! simulated time ([`SimCompassChip::update`], called from the physics with the attitude and the
//! motors' thrusts), quantised to the chip's LSB (rounded), little-endian (low byte first, X, Y,
//! Z) in both chips. A chip made with [`SimCompassChip::with_given_field`] senses a field given
//! from outside instead (an external simulator's, through `crate::bridge`): each conversion takes
//! the latest one given ([`SimCompassChip::give_field_ut`]) as it is, its noise and iron the
//! giver's.
//!
//! | | IST8310 (iSentek datasheet, `firmware::drivers::ist8310`) | QMC5883L (QST datasheet rev. 1.0, `firmware::drivers::qmc5883l`) |
//! |---|---|---|
//! | address | 0x0C–0x0F (CAD pins), 0x0E on GNSS masts | 0x0D |
//! | identity | WAI 0x00 = 0x10 | chip ID 0x0D = 0xFF |
//! | mode | CNTL1 0x0A = 0x01 starts one measurement; the chip returns to standby when it is done | control 1 0x09: MODE 01 continuous at ODR 10/50/100/200 Hz, RNG ±2 G or ±8 G |
//! | conversion | [`IST8310_CONVERSION_S`] after the start | every `1/ODR` from the mode's write |
//! | status | STAT1 0x02: DRDY, DOR | 0x06: DRDY, OVL, DOR |
//! | data | 0x03–0x08, 0.3 µT/LSB, valid within ±1600 µT (X, Y) and ±2500 µT (Z) | 0x00–0x05, 1/30 µT/LSB at ±8 G (1/120 at ±2 G) |
//! | reset | CNTL2 0x0B bit 0 | control 2 0x0A bit 7 |
//!
//! Reading any data register clears DRDY and DOR (both datasheets); DOR is set when a conversion
//! completes while DRDY is still set (a sample skipped). Writes to read-only registers (identity,
//! status, data) are acknowledged and ignored.
//!
//! # Faults the world injects ([`ChipFaults`])
//!
//! - **lost** from a time: the chip acknowledges nothing (a NACK, as an unplugged mast or a dead
//!   sensor gives), the drivers' `CompassError::Bus`;
//! - **frozen** from a time: conversions still complete and set DRDY, but the data registers keep
//!   their last values (a sensor whose front end stopped): the drivers see identical readings;
//! - **magnet** from a time: a field added to the sensor's (a magnet or a current-carrying wire
//!   beside it), beyond the range: the QMC5883L's OVL flag, the IST8310's counts beyond its full
//!   scale.
//!
//! # Assumptions (not from a datasheet)
//!
//! - Beyond its range an IST8310's output keeps counting linearly up to the 16-bit limit (its
//!   datasheet does not say what it reads there; ArduPilot's and our driver's check of the
//!   full-scale count expects that); a QMC5883L's data registers hold the count clamped to 16
//!   bits with OVL set.
//! - A soft reset takes effect at once (the drivers wait 10–50 ms after it anyway); the power-on
//!   values of registers the drivers write (AVGCNTL, PDCNTL, the SET/RESET period) are 0.
//! - A bus transfer takes no simulated time: it sees the chip as the last `update` left it.

use std::cell::RefCell;
use std::rc::Rc;

use firmware::drivers::compass::{DelayUs, I2cRegisterBus};
use firmware::drivers::{ist8310, qmc5883l};
use nalgebra::{UnitQuaternion, Vector3};

use crate::magnetometer::{MagnetometerSpec, SimMagnetometer};

/// Time an IST8310 single measurement takes with 16 times averaging, s (6 ms). Ours, an
/// assumption: the datasheet's largest single-measurement rate (200 Hz) bounds one plain
/// measurement at 5 ms, the averaging lengthens it, and PX4's and ArduPilot's drivers collect a
/// measurement 10 ms after starting it.
pub const IST8310_CONVERSION_S: f64 = 0.006;

/// QMC5883L status bit 2: a sample skipped (datasheet section 9).
pub const QMC5883L_STATUS_DOR: u8 = 0x04;
/// IST8310 STAT1 bit 1: a sample skipped (datasheet, register map).
pub const IST8310_STAT1_DOR: u8 = 0x02;
/// QMC5883L control 1 MODE (bits 1:0) for continuous measurement.
const QMC5883L_MODE_CONTINUOUS: u8 = 0b01;
/// QMC5883L full scales, gauss, by RNG (bits 5:4 of control 1: 00 ±2 G, 01 ±8 G; datasheet
/// table 2), and their sensitivities, LSB per gauss.
const QMC5883L_RANGES_GAUSS: [(f64, f64); 2] = [(2.0, 12_000.0), (8.0, 3_000.0)];
/// QMC5883L output data rates by ODR (bits 3:2 of control 1), Hz (datasheet section 9).
const QMC5883L_ODR_HZ: [f64; 4] = [10.0, 50.0, 100.0, 200.0];
/// Microtesla per gauss.
const UT_PER_GAUSS: f64 = qmc5883l::UT_PER_GAUSS as f64;

/// Which chip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChipKind {
    /// iSentek IST8310: single measurements, 0.3 µT/LSB.
    Ist8310,
    /// QST QMC5883L: continuous, 1/30 µT/LSB at ±8 G.
    Qmc5883l,
}

impl ChipKind {
    /// The address the chip answers at on a GNSS mast.
    pub fn default_address(self) -> u8 {
        match self {
            ChipKind::Ist8310 => ist8310::DEFAULT_ADDRESS,
            ChipKind::Qmc5883l => qmc5883l::DEFAULT_ADDRESS,
        }
    }

    /// The chip's LSB as the firmware's driver configures it, µT.
    pub fn lsb_ut(self) -> f64 {
        match self {
            ChipKind::Ist8310 => f64::from(ist8310::UT_PER_LSB),
            ChipKind::Qmc5883l => f64::from(qmc5883l::UT_PER_LSB),
        }
    }
}

/// Where a chip keeps what the simulation touches (the datasheets' register maps, as the
/// firmware's drivers name them).
struct RegisterMap {
    identity: u8,
    status: u8,
    /// The first of the six data registers (X, Y, Z, low byte first).
    first_data: u8,
    /// Status bits: data ready, data skipped.
    drdy: u8,
    dor: u8,
    /// The soft reset's register and bit.
    reset: u8,
    reset_bit: u8,
    /// The register whose write starts conversions.
    mode: u8,
}

impl ChipKind {
    fn registers(self) -> RegisterMap {
        match self {
            ChipKind::Ist8310 => RegisterMap {
                identity: ist8310::reg::WAI,
                status: ist8310::reg::STAT1,
                first_data: ist8310::reg::DATAXL,
                drdy: ist8310::STAT1_DRDY,
                dor: IST8310_STAT1_DOR,
                reset: ist8310::reg::CNTL2,
                reset_bit: ist8310::CNTL2_SOFT_RESET,
                mode: ist8310::reg::CNTL1,
            },
            ChipKind::Qmc5883l => RegisterMap {
                identity: qmc5883l::reg::CHIP_ID,
                status: qmc5883l::reg::STATUS,
                first_data: qmc5883l::reg::DATA_X_LSB,
                drdy: qmc5883l::STATUS_DRDY,
                dor: QMC5883L_STATUS_DOR,
                reset: qmc5883l::reg::CONTROL2,
                reset_bit: qmc5883l::CONTROL2_SOFT_RESET,
                mode: qmc5883l::reg::CONTROL1,
            },
        }
    }
}

/// A magnet brought next to the sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Magnet {
    /// From this simulated time, s.
    pub from_s: f64,
    /// Its field at the sensor, µT, sensor axes.
    pub field_ut: [f64; 3],
}

/// Faults injected into a chip (none by default).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChipFaults {
    /// From this time, s, the chip acknowledges nothing.
    pub lost_from_s: Option<f64>,
    /// From this time, s, the data registers stop updating (DRDY still comes).
    pub frozen_from_s: Option<f64>,
    /// A magnet beside the sensor.
    pub magnet: Option<Magnet>,
}

/// The bus error: the address was not acknowledged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Nack;

/// What a chip's conversions sample.
#[derive(Clone, Debug)]
enum Sensed {
    /// A simulated magnetometer in the simulator's world, at the attitude and thrusts
    /// [`SimCompassChip::update`] is given.
    World(Box<SimMagnetometer>),
    /// The latest field given from outside, µT, sensor axes ([`SimCompassChip::give_field_ut`]).
    Given(Vector3<f64>),
}

/// One simulated compass chip and the field it senses (see the module documentation).
#[derive(Clone, Debug)]
pub struct SimCompassChip {
    kind: ChipKind,
    address: u8,
    sensed: Sensed,
    registers: [u8; 256],
    now_s: f64,
    faults: ChipFaults,
    /// When the running conversion completes (IST8310: the single measurement; QMC5883L: the
    /// next one of the continuous series), s.
    conversion_due_s: Option<f64>,
    latest_field_ut: Option<Vector3<f64>>,
    conversions: u64,
}

impl SimCompassChip {
    /// A chip of `kind` at its default address, sensing `spec` with noise fixed by `seed`, just
    /// powered (registers at their power-on values, no conversion running).
    pub fn new(kind: ChipKind, spec: MagnetometerSpec, seed: u64) -> Self {
        Self::sensing(kind, Sensed::World(Box::new(SimMagnetometer::new(spec, seed))))
    }

    /// A chip of `kind` at its default address, just powered, sensing `field_ut` (µT, sensor
    /// axes) and then whatever [`Self::give_field_ut`] gives it: no world, no noise of its own
    /// (its conversions quantise the given field to the LSB and nothing else).
    pub fn with_given_field(kind: ChipKind, field_ut: [f64; 3]) -> Self {
        Self::sensing(kind, Sensed::Given(Vector3::from(field_ut)))
    }

    fn sensing(kind: ChipKind, sensed: Sensed) -> Self {
        let mut chip = Self {
            kind,
            address: kind.default_address(),
            sensed,
            registers: [0; 256],
            now_s: 0.0,
            faults: ChipFaults::default(),
            conversion_due_s: None,
            latest_field_ut: None,
            conversions: 0,
        };
        chip.power_on_registers();
        chip
    }

    /// The same chip answering at `address` (an IST8310's CAD pins strapped otherwise).
    pub fn at_address(self, address: u8) -> Self {
        Self { address, ..self }
    }

    /// The same chip with these faults.
    pub fn with_faults(self, faults: ChipFaults) -> Self {
        Self { faults, ..self }
    }

    /// Which chip.
    pub fn kind(&self) -> ChipKind {
        self.kind
    }

    /// The 7-bit address it answers at.
    pub fn address(&self) -> u8 {
        self.address
    }

    /// The simulated sensor's spec (`None` for a chip given its field from outside).
    pub fn spec(&self) -> Option<&MagnetometerSpec> {
        match &self.sensed {
            Sensed::World(sensor) => Some(sensor.spec()),
            Sensed::Given(_) => None,
        }
    }

    /// The field the conversions from now on sample, µT, sensor axes, until the next one given
    /// (the chip senses it from then on, whatever it sensed before). Non-finite values are the
    /// caller's to refuse: a conversion writes what the field rounds to, clamped to 16 bits (NaN as
    /// 0).
    pub fn give_field_ut(&mut self, field_ut: [f64; 3]) {
        self.sensed = Sensed::Given(Vector3::from(field_ut));
    }

    /// The field of the latest conversion that reached the data registers, µT, sensor axes,
    /// before quantisation (the magnet's field included).
    pub fn latest_field_ut(&self) -> Option<Vector3<f64>> {
        self.latest_field_ut
    }

    /// Conversions completed so far (frozen ones included).
    pub fn conversions(&self) -> u64 {
        self.conversions
    }

    fn power_on_registers(&mut self) {
        self.registers = [0; 256];
        *self.reg_mut(self.kind.registers().identity) = match self.kind {
            ChipKind::Ist8310 => ist8310::WAI_VALUE,
            ChipKind::Qmc5883l => qmc5883l::CHIP_ID_VALUE,
        };
        self.conversion_due_s = None;
    }

    fn reg(&self, r: u8) -> u8 {
        self.registers[usize::from(r)]
    }

    fn reg_mut(&mut self, r: u8) -> &mut u8 {
        &mut self.registers[usize::from(r)]
    }

    fn lost(&self) -> bool {
        self.faults.lost_from_s.is_some_and(|t| self.now_s >= t)
    }

    fn frozen(&self) -> bool {
        self.faults.frozen_from_s.is_some_and(|t| self.now_s >= t)
    }

    /// The QMC5883L's conversion period and full scale (µT) and LSB (µT) as control 1 sets them.
    fn qmc_config(&self) -> (f64, f64, f64) {
        let control1 = self.reg(qmc5883l::reg::CONTROL1);
        let odr_hz = QMC5883L_ODR_HZ[usize::from((control1 >> 2) & 0b11)];
        // RNG 10 and 11 are reserved: taken as ±8 G.
        let (range_gauss, lsb_per_gauss) =
            QMC5883L_RANGES_GAUSS[usize::from((control1 >> 4) & 0b11 != 0)];
        (1.0 / odr_hz, range_gauss * UT_PER_GAUSS, UT_PER_GAUSS / lsb_per_gauss)
    }

    /// Advance the chip to `now_s` (simulated time, s, not decreasing), completing the
    /// conversions due with the field at the attitude `q_world_imu` and the motors' normalised
    /// thrusts `thrust` (both unused by a chip given its field from outside).
    pub fn update(&mut self, now_s: f64, q_world_imu: &UnitQuaternion<f64>, thrust: &[f64]) {
        self.now_s = now_s.max(self.now_s);
        let Some(due_s) = self.conversion_due_s else {
            return;
        };
        if self.now_s < due_s {
            return;
        }
        match self.kind {
            ChipKind::Ist8310 => {
                self.conversion_due_s = None;
                // Back to standby.
                *self.reg_mut(ist8310::reg::CNTL1) &= !0x0F;
            }
            ChipKind::Qmc5883l => {
                let (period_s, _, _) = self.qmc_config();
                // On the chip's grid; a caller that fell behind gets one conversion, not a burst.
                let missed = ((self.now_s - due_s) / period_s).floor();
                self.conversion_due_s = Some(due_s + (missed + 1.0) * period_s);
            }
        }
        self.convert(q_world_imu, thrust);
    }

    /// One conversion: the sensor sampled into the data registers (unless frozen), the status
    /// flags set.
    fn convert(&mut self, q_world_imu: &UnitQuaternion<f64>, thrust: &[f64]) {
        self.conversions += 1;
        let map = self.kind.registers();
        let mut status = self.reg(map.status);
        if status & map.drdy != 0 {
            status |= map.dor;
        }
        status |= map.drdy;
        if !self.frozen() {
            let mut field = match &mut self.sensed {
                Sensed::World(sensor) => sensor.sample(q_world_imu, thrust),
                Sensed::Given(field) => *field,
            };
            if let Some(magnet) = self.faults.magnet.filter(|m| self.now_s >= m.from_s) {
                field += Vector3::from(magnet.field_ut);
            }
            self.latest_field_ut = Some(field);
            let lsb_ut = match self.kind {
                ChipKind::Ist8310 => self.kind.lsb_ut(),
                ChipKind::Qmc5883l => {
                    let (_, range_ut, lsb_ut) = self.qmc_config();
                    let overflow = field.iter().any(|b| b.abs() > range_ut);
                    status = (status & !qmc5883l::STATUS_OVL)
                        | if overflow { qmc5883l::STATUS_OVL } else { 0 };
                    lsb_ut
                }
            };
            for (axis, b) in field.iter().enumerate() {
                let count = (b / lsb_ut).round().clamp(f64::from(i16::MIN), f64::from(i16::MAX));
                let bytes = (count as i16).to_le_bytes();
                let at = usize::from(map.first_data) + 2 * axis;
                self.registers[at..at + 2].copy_from_slice(&bytes);
            }
        }
        *self.reg_mut(map.status) = status;
    }

    /// A register write's effect.
    fn write(&mut self, reg: u8, value: u8) {
        let map = self.kind.registers();
        let read_only = reg == map.identity
            || reg == map.status
            || (map.first_data..map.first_data + 6).contains(&reg);
        if read_only {
            return;
        }
        if reg == map.reset && value & map.reset_bit != 0 {
            self.power_on_registers();
            return;
        }
        *self.reg_mut(reg) = value;
        if reg == map.mode {
            self.conversion_due_s = match self.kind {
                ChipKind::Ist8310 => (value & 0x0F == ist8310::CNTL1_SINGLE_MEASUREMENT)
                    .then_some(self.now_s + IST8310_CONVERSION_S),
                ChipKind::Qmc5883l => (value & 0b11 == QMC5883L_MODE_CONTINUOUS)
                    .then_some(self.now_s + self.qmc_config().0),
            };
        }
    }

    /// A burst read's bytes, then its effect (reading data clears DRDY and DOR).
    fn read(&mut self, first_reg: u8, buf: &mut [u8]) {
        let map = self.kind.registers();
        let mut read_data = false;
        for (i, b) in buf.iter_mut().enumerate() {
            let r = first_reg.wrapping_add(i as u8);
            *b = self.reg(r);
            read_data |= (map.first_data..map.first_data + 6).contains(&r);
        }
        if read_data {
            *self.reg_mut(map.status) &= !(map.drdy | map.dor);
        }
    }
}

impl I2cRegisterBus for SimCompassChip {
    type Error = Nack;

    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Nack> {
        if address != self.address || self.lost() {
            return Err(Nack);
        }
        self.write(reg, value);
        Ok(())
    }

    fn read_registers(&mut self, address: u8, first_reg: u8, buf: &mut [u8]) -> Result<(), Nack> {
        if address != self.address || self.lost() {
            return Err(Nack);
        }
        self.read(first_reg, buf);
        Ok(())
    }
}

/// A chip shared between the simulator (which advances it) and the firmware's driver (which
/// owns its bus): a clone is the same chip.
#[derive(Clone, Debug)]
pub struct SharedCompassChip(Rc<RefCell<SimCompassChip>>);

impl SharedCompassChip {
    /// Share `chip`.
    pub fn new(chip: SimCompassChip) -> Self {
        Self(Rc::new(RefCell::new(chip)))
    }

    /// [`SimCompassChip::update`].
    pub fn update(&self, now_s: f64, q_world_imu: &UnitQuaternion<f64>, thrust: &[f64]) {
        self.0.borrow_mut().update(now_s, q_world_imu, thrust);
    }

    /// [`SimCompassChip::latest_field_ut`].
    pub fn latest_field_ut(&self) -> Option<Vector3<f64>> {
        self.0.borrow().latest_field_ut()
    }

    /// Run `f` on the chip.
    pub fn with<R>(&self, f: impl FnOnce(&mut SimCompassChip) -> R) -> R {
        f(&mut self.0.borrow_mut())
    }
}

impl I2cRegisterBus for SharedCompassChip {
    type Error = Nack;

    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Nack> {
        self.0.borrow_mut().write_register(address, reg, value)
    }

    fn read_registers(&mut self, address: u8, first_reg: u8, buf: &mut [u8]) -> Result<(), Nack> {
        self.0.borrow_mut().read_registers(address, first_reg, buf)
    }
}

/// A delay for the drivers' `init` in simulated time: it only counts what it was asked to wait
/// (a bus transfer and a soft reset take no simulated time here, see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CountingDelay {
    /// Microseconds asked for so far.
    pub waited_us: u64,
}

impl DelayUs for CountingDelay {
    fn delay_us(&mut self, us: u32) {
        self.waited_us += u64::from(us);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::drivers::compass::{CompassError, CompassState};
    use firmware::drivers::ist8310::Ist8310;
    use firmware::drivers::qmc5883l::Qmc5883l;

    use crate::rng::Rng;

    /// A random sensor, its mounting turned by a random attitude each step: the field moves.
    fn spec(seed: u64) -> MagnetometerSpec {
        MagnetometerSpec::random(&mut Rng::new(seed), 4)
    }

    /// The simulator's loop: the physics at 1 kHz advancing the chip, the driver polling at
    /// `poll_hz`; `read` is the driver's read, returning what it gives. Each valid reading is
    /// checked against the chip's latest field (within one LSB) and its count returned.
    fn poll<E: core::fmt::Debug>(
        chip: &SharedCompassChip,
        seconds: f64,
        poll_hz: f64,
        start_s: f64,
        mut read: impl FnMut() -> Result<firmware::drivers::compass::CompassReading, CompassError<E>>,
    ) -> (usize, usize) {
        let mut rng = Rng::new(3);
        let (mut valid, mut not_ready) = (0, 0);
        let mut next_poll_s = start_s;
        let steps = (seconds * 1000.0) as usize;
        for k in 0..steps {
            let t = start_s + k as f64 * 1e-3;
            let q = UnitQuaternion::from_euler_angles(0.3 * t.sin(), 0.2, 0.7 * t);
            chip.update(t, &q, &[rng.range(0.0, 1.0); 4]);
            if t >= next_poll_s {
                next_poll_s += 1.0 / poll_hz;
                match read() {
                    Ok(reading) => {
                        valid += 1;
                        let truth = chip.latest_field_ut().unwrap();
                        let lsb = chip.with(|c| c.kind().lsb_ut());
                        for axis in 0..3 {
                            let got = f64::from(reading.field_ut[axis]);
                            assert!(
                                (got - truth[axis]).abs() <= lsb,
                                "axis {axis}: read {got} µT, field {} µT",
                                truth[axis]
                            );
                        }
                    }
                    Err(CompassError::NotReady) => not_ready += 1,
                    Err(e) => panic!("{e:?}"),
                }
            }
        }
        (valid, not_ready)
    }

    /// The firmware's IST8310 driver inits the chip (identity, averaging, pulse duration, the
    /// first single measurement) and reads the simulated field within one LSB at 100 Hz, every
    /// poll a new measurement (6 ms of conversion within the 10 ms poll); polled 2 ms after a
    /// start, the measurement is not ready yet.
    #[test]
    fn the_ist8310_driver_reads_the_simulated_field() {
        let chip = SharedCompassChip::new(SimCompassChip::new(ChipKind::Ist8310, spec(1), 1));
        let mut driver = Ist8310::new(chip.clone(), ist8310::DEFAULT_ADDRESS);
        let mut delay = CountingDelay::default();
        driver.init(&mut delay).unwrap();
        assert_eq!(delay.waited_us, u64::from(ist8310::SOFT_RESET_WAIT_US));
        assert_eq!(chip.with(|c| c.reg(ist8310::reg::AVGCNTL)), ist8310::AVGCNTL_16_TIMES);
        let (valid, not_ready) = poll(&chip, 2.0, 100.0, 0.01, || driver.read());
        assert!(valid >= 199 && not_ready == 0, "{valid} valid, {not_ready} not ready");
        assert_eq!(driver.health().state, CompassState::Healthy);
        // A read 2 ms after the restart: still converting.
        let q = UnitQuaternion::identity();
        chip.update(3.0, &q, &[]);
        driver.read().unwrap();
        chip.update(3.002, &q, &[]);
        assert_eq!(driver.read(), Err(CompassError::NotReady));
        chip.update(3.0 + IST8310_CONVERSION_S + 1e-6, &q, &[]);
        assert!(driver.read().is_ok());
        // Nothing answers at another address.
        let mut elsewhere = Ist8310::new(chip.clone(), 0x0C);
        assert_eq!(elsewhere.init(&mut delay), Err(CompassError::Bus(Nack)));
    }

    /// The firmware's QMC5883L driver inits the chip (continuous, ±8 G, 100 Hz) and reads the
    /// field within one LSB; polled at 150 Hz it finds no new data every third poll or so (the
    /// chip converts at 100 Hz).
    #[test]
    fn the_qmc5883l_driver_reads_the_simulated_field() {
        let chip = SharedCompassChip::new(SimCompassChip::new(ChipKind::Qmc5883l, spec(2), 2));
        let mut driver = Qmc5883l::new(chip.clone(), qmc5883l::DEFAULT_ADDRESS);
        driver.init(&mut CountingDelay::default()).unwrap();
        let (valid, not_ready) = poll(&chip, 2.0, 150.0, 0.0, || driver.read());
        assert!((195..=201).contains(&valid), "{valid} conversions read in 2 s at 100 Hz");
        assert!((95..=110).contains(&not_ready), "{not_ready} polls found nothing new");
        assert_eq!(driver.health().state, CompassState::Healthy);
        // Before the mode is written nothing converts.
        let idle = SharedCompassChip::new(SimCompassChip::new(ChipKind::Qmc5883l, spec(2), 2));
        idle.update(1.0, &UnitQuaternion::identity(), &[]);
        assert_eq!(idle.with(|c| c.conversions()), 0);
    }

    /// Both chips' counts, bytes and flags at the edge of their ranges: the IST8310's counts
    /// beyond its full scale, the QMC5883L's OVL.
    #[test]
    fn quantisation_byte_order_and_range_follow_the_datasheets() {
        let field = MagnetometerSpec { noise_ut: 0.0, ..MagnetometerSpec::default() };
        // A magnet of (+10, −20, +30) µT on no Earth field: exactly representable counts.
        let zero = MagnetometerSpec { strength_ut: 1.0, ..field };
        for (kind, magnet_ut, want) in [
            (ChipKind::Ist8310, [300.0, -150.0, 600.0], [1000i16, -500, 2000]),
            (ChipKind::Qmc5883l, [20.0, -50.0, 1.0], [600, -1500, 30]),
        ] {
            let q = UnitQuaternion::identity();
            let earth = zero.clean_reading_ut(&q, &[]);
            let faults = ChipFaults {
                magnet: Some(Magnet {
                    from_s: 0.0,
                    field_ut: std::array::from_fn(|i| magnet_ut[i] - earth[i]),
                }),
                ..ChipFaults::default()
            };
            let mut chip = SimCompassChip::new(kind, zero.clone(), 1).with_faults(faults);
            let a = chip.address();
            match kind {
                ChipKind::Ist8310 => chip.write_register(a, 0x0A, 0x01).unwrap(),
                ChipKind::Qmc5883l => chip.write_register(a, 0x09, 0x19).unwrap(),
            }
            chip.update(0.011, &q, &[]);
            let (first, status_reg) = match kind {
                ChipKind::Ist8310 => (0x03, 0x02),
                ChipKind::Qmc5883l => (0x00, 0x06),
            };
            let mut status = [0u8];
            chip.read_registers(a, status_reg, &mut status).unwrap();
            assert_eq!(status[0], 0x01, "{kind:?}: DRDY alone");
            let mut bytes = [0u8; 6];
            chip.read_registers(a, first, &mut bytes).unwrap();
            let expected: Vec<u8> = want.iter().flat_map(|c| c.to_le_bytes()).collect();
            assert_eq!(bytes.as_slice(), expected.as_slice(), "{kind:?}: low byte first");
            chip.read_registers(a, status_reg, &mut status).unwrap();
            assert_eq!(status[0], 0x00, "{kind:?}: reading the data cleared DRDY");
        }
        // The QMC5883L at ±8 G: 801 µT overflows, 799 µT does not.
        for (x_ut, ovl) in [(799.0, false), (801.0, true)] {
            let magnet = Magnet { from_s: 0.0, field_ut: [x_ut, 0.0, 0.0] };
            let mut chip = SimCompassChip::new(ChipKind::Qmc5883l, zero.clone(), 1)
                .with_faults(ChipFaults { magnet: Some(magnet), ..ChipFaults::default() });
            chip.write_register(0x0D, 0x09, 0x19).unwrap();
            chip.update(0.011, &UnitQuaternion::identity(), &[]);
            let status = chip.reg(qmc5883l::reg::STATUS);
            assert_eq!(status & qmc5883l::STATUS_OVL != 0, ovl, "{x_ut} µT: status {status:#x}");
        }
    }

    /// A soft reset puts back the power-on registers (the identity stays, the configuration
    /// goes, nothing converts); a reader slower than the QMC5883L's conversions finds DOR with
    /// DRDY, and reading the data clears both.
    #[test]
    fn a_soft_reset_and_a_skipped_sample_behave_as_the_datasheets_say() {
        let q = UnitQuaternion::identity();
        let mut ist = SimCompassChip::new(ChipKind::Ist8310, spec(7), 7);
        let a = ist.address();
        ist.write_register(a, ist8310::reg::AVGCNTL, ist8310::AVGCNTL_16_TIMES).unwrap();
        ist.write_register(a, ist8310::reg::CNTL1, ist8310::CNTL1_SINGLE_MEASUREMENT).unwrap();
        ist.write_register(a, ist8310::reg::CNTL2, ist8310::CNTL2_SOFT_RESET).unwrap();
        ist.update(0.1, &q, &[]);
        let mut bytes = [0u8; 3];
        ist.read_registers(a, ist8310::reg::WAI, &mut bytes).unwrap();
        assert_eq!(bytes, [ist8310::WAI_VALUE, 0, 0], "identity kept, no DRDY");
        assert_eq!(ist.reg(ist8310::reg::AVGCNTL), 0);
        assert_eq!(ist.conversions(), 0, "the reset stopped the measurement");
        // The identity register ignores writes.
        ist.write_register(a, ist8310::reg::WAI, 0x55).unwrap();
        assert_eq!(ist.reg(ist8310::reg::WAI), ist8310::WAI_VALUE);

        let mut qmc = SimCompassChip::new(ChipKind::Qmc5883l, spec(8), 8);
        let a = qmc.address();
        qmc.write_register(a, qmc5883l::reg::CONTROL1, qmc5883l::CONTROL1_VALUE).unwrap();
        // Two conversions (at 10 and 20 ms of the 100 Hz series), neither read.
        qmc.update(0.011, &q, &[]);
        qmc.update(0.021, &q, &[]);
        assert_eq!(qmc.conversions(), 2);
        let status = qmc.reg(qmc5883l::reg::STATUS);
        assert_eq!(status, qmc5883l::STATUS_DRDY | QMC5883L_STATUS_DOR);
        let mut data = [0u8; 6];
        qmc.read_registers(a, qmc5883l::reg::DATA_X_LSB, &mut data).unwrap();
        assert_eq!(qmc.reg(qmc5883l::reg::STATUS), 0);
        qmc.write_register(a, qmc5883l::reg::CONTROL2, qmc5883l::CONTROL2_SOFT_RESET).unwrap();
        qmc.update(0.1, &q, &[]);
        assert_eq!(qmc.conversions(), 2, "standby after the reset");
        assert_eq!(qmc.reg(qmc5883l::reg::CHIP_ID), qmc5883l::CHIP_ID_VALUE);
    }

    /// Faults through the firmware's drivers: a chip lost at 1 s is reported lost ten polls
    /// later, a frozen one stuck after 25 identical readings, a magnet beyond the range
    /// saturated after ten overflows; each chip healthy from its first readings to its fault.
    #[test]
    fn injected_faults_make_the_drivers_report_lost_stuck_and_saturated() {
        let magnet = Magnet { from_s: 1.0, field_ut: [0.0, 0.0, 3_000.0] };
        let cases = [
            (ChipFaults { lost_from_s: Some(1.0), ..ChipFaults::default() }, CompassState::Lost),
            (ChipFaults { frozen_from_s: Some(1.0), ..ChipFaults::default() }, CompassState::Stuck),
            (ChipFaults { magnet: Some(magnet), ..ChipFaults::default() }, CompassState::Saturated),
        ];
        for kind in [ChipKind::Ist8310, ChipKind::Qmc5883l] {
            for (faults, state) in cases {
                let chip = SimCompassChip::new(kind, spec(5), 5).with_faults(faults);
                let chip = SharedCompassChip::new(chip);
                let mut ist = Ist8310::new(chip.clone(), ist8310::DEFAULT_ADDRESS);
                let mut qmc = Qmc5883l::new(chip.clone(), qmc5883l::DEFAULT_ADDRESS);
                let mut delay = CountingDelay::default();
                match kind {
                    ChipKind::Ist8310 => ist.init(&mut delay).unwrap(),
                    ChipKind::Qmc5883l => qmc.init(&mut delay).unwrap(),
                }
                // 100 Hz polls from 5 ms, the physics at 1 kHz; the field turns.
                let mut reported_at_s = None;
                for k in 0..2_000 {
                    let t = k as f64 * 1e-3;
                    let q = UnitQuaternion::from_euler_angles(0.2, 0.1 * t, 0.5 * t);
                    chip.update(t, &q, &[]);
                    if k % 10 == 5 {
                        let h = match kind {
                            ChipKind::Ist8310 => {
                                let _ = ist.read();
                                ist.health()
                            }
                            ChipKind::Qmc5883l => {
                                let _ = qmc.read();
                                qmc.health()
                            }
                        };
                        if (0.1..1.0).contains(&t) {
                            assert_eq!(h.state, CompassState::Healthy, "{kind:?} {state:?} {t} s");
                        } else if h.state == state && reported_at_s.is_none() {
                            reported_at_s = Some(t);
                        }
                    }
                }
                let at = reported_at_s.unwrap_or_else(|| panic!("{kind:?}: never {state:?}"));
                // Ten failed or overflowing polls, or 25 identical readings, at 100 Hz.
                let limit_s = if state == CompassState::Stuck { 0.27 } else { 0.12 };
                assert!(at - 1.0 <= limit_s, "{kind:?}: {state:?} only {:.3} s after", at - 1.0);
            }
        }
    }
}
