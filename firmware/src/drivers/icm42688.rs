//! TDK InvenSense ICM-42688-P 6-axis IMU: register map, the verified initialisation sequence,
//! sample decoding to SI units, and the 8 kHz → 2 kHz averaging accumulator.
//!
//! Why here: the board adapts its SPI (+ DMA) to the small [`RegisterBus`] trait and calls
//! [`Icm42688::init`] once; afterwards it reads [`SAMPLE_LEN`] bytes from
//! [`SAMPLE_FIRST_REGISTER`] on every data-ready interrupt (by DMA if it likes) and decodes them
//! with [`RawSample::from_be_bytes`]. Everything that can be wrong in a register value is tested
//! on the host against a mock bus.
//!
//! Configuration (register values from the ICM-42688-P datasheet, DS-000347 rev 1.x, section 14
//! "register map" and section 5.3 "anti-alias filter"):
//! - gyro ±2000 °/s (16.4 LSB per °/s), accel ±16 g (2048 LSB per g), both 8 kHz ODR, low-noise
//!   mode;
//! - anti-alias filter (AAF) of gyro and accel at 997 Hz 3 dB bandwidth (datasheet table in
//!   section 5.3: AAF_DELT 21, AAF_DELTSQR 440, AAF_BITSHIFT 6; the same entry Betaflight's
//!   ICM-42688-P driver uses for its "1 kHz" setting);
//! - UI filter: first order, bandwidth index 1 = max(400 Hz, ODR)/4 = 2 kHz at 8 kHz ODR;
//! - gyro notch filter disabled (it is not configured by us);
//! - INT1: push-pull, active high, pulsed, 8 µs pulses without minimum de-assertion time (the
//!   datasheet's required settings for ODR ≥ 4 kHz), data-ready routed to INT1.
//!
//! Axes stay in the sensor's own frame; rotating into the body frame is the application's job.

use crate::app::hal::ImuSample;

/// Register access as the driver needs it. For SPI the implementation sets bit 7 of the address
/// for reads ([`SPI_READ_FLAG`]) and clears it for writes; `read_registers` reads consecutive
/// registers (the device auto-increments the address in a burst).
pub trait RegisterBus {
    /// The bus error.
    type Error;
    /// Write one register of the currently selected bank.
    fn write_register(&mut self, reg: u8, value: u8) -> Result<(), Self::Error>;
    /// Read `buf.len()` consecutive registers starting at `first_reg`.
    fn read_registers(&mut self, first_reg: u8, buf: &mut [u8]) -> Result<(), Self::Error>;
}

/// A blocking microsecond delay (only used during initialisation).
pub trait DelayUs {
    /// Wait at least `us` microseconds.
    fn delay_us(&mut self, us: u32);
}

/// SPI read flag: bit 7 of the address byte (datasheet section 9.1, "SPI interface").
pub const SPI_READ_FLAG: u8 = 0x80;

/// User bank 0 register addresses (datasheet section 14.1).
pub mod bank0 {
    /// DEVICE_CONFIG: bit 0 SOFT_RESET_CONFIG.
    pub const DEVICE_CONFIG: u8 = 0x11;
    /// INT_CONFIG: INT1/INT2 mode, drive, polarity.
    pub const INT_CONFIG: u8 = 0x14;
    /// TEMP_DATA1: temperature high byte (first of the data registers).
    pub const TEMP_DATA1: u8 = 0x1D;
    /// ACCEL_DATA_X1: accel X high byte.
    pub const ACCEL_DATA_X1: u8 = 0x1F;
    /// GYRO_DATA_X1: gyro X high byte.
    pub const GYRO_DATA_X1: u8 = 0x25;
    /// GYRO_DATA_Z0: gyro Z low byte (last of the data registers).
    pub const GYRO_DATA_Z0: u8 = 0x2A;
    /// INT_STATUS: bit 3 DATA_RDY_INT, bit 4 RESET_DONE_INT.
    pub const INT_STATUS: u8 = 0x2D;
    /// PWR_MGMT0: gyro mode bits 3:2, accel mode bits 1:0.
    pub const PWR_MGMT0: u8 = 0x4E;
    /// GYRO_CONFIG0: FS_SEL bits 7:5, ODR bits 3:0.
    pub const GYRO_CONFIG0: u8 = 0x4F;
    /// ACCEL_CONFIG0: FS_SEL bits 7:5, ODR bits 3:0.
    pub const ACCEL_CONFIG0: u8 = 0x50;
    /// GYRO_CONFIG1: temperature filter, gyro UI filter order.
    pub const GYRO_CONFIG1: u8 = 0x51;
    /// GYRO_ACCEL_CONFIG0: accel UI filter bandwidth bits 7:4, gyro bits 3:0.
    pub const GYRO_ACCEL_CONFIG0: u8 = 0x52;
    /// ACCEL_CONFIG1: accel UI filter order.
    pub const ACCEL_CONFIG1: u8 = 0x53;
    /// INT_CONFIG0: interrupt clear options.
    pub const INT_CONFIG0: u8 = 0x63;
    /// INT_CONFIG1: interrupt pulse duration, de-assertion, async reset.
    pub const INT_CONFIG1: u8 = 0x64;
    /// INT_SOURCE0: bit 3 UI_DRDY_INT1_EN.
    pub const INT_SOURCE0: u8 = 0x65;
    /// WHO_AM_I.
    pub const WHO_AM_I: u8 = 0x75;
    /// REG_BANK_SEL (present in every bank).
    pub const REG_BANK_SEL: u8 = 0x76;
}

/// User bank 1 register addresses (datasheet section 14.2): gyro anti-alias filter.
pub mod bank1 {
    /// GYRO_CONFIG_STATIC2: bit 1 GYRO_AAF_DIS, bit 0 GYRO_NF_DIS.
    pub const GYRO_CONFIG_STATIC2: u8 = 0x0B;
    /// GYRO_CONFIG_STATIC3: GYRO_AAF_DELT bits 5:0.
    pub const GYRO_CONFIG_STATIC3: u8 = 0x0C;
    /// GYRO_CONFIG_STATIC4: GYRO_AAF_DELTSQR bits 7:0.
    pub const GYRO_CONFIG_STATIC4: u8 = 0x0D;
    /// GYRO_CONFIG_STATIC5: GYRO_AAF_BITSHIFT bits 7:4, GYRO_AAF_DELTSQR bits 11:8 in 3:0.
    pub const GYRO_CONFIG_STATIC5: u8 = 0x0E;
}

/// User bank 2 register addresses (datasheet section 14.3): accel anti-alias filter.
pub mod bank2 {
    /// ACCEL_CONFIG_STATIC2: ACCEL_AAF_DELT bits 6:1, bit 0 ACCEL_AAF_DIS.
    pub const ACCEL_CONFIG_STATIC2: u8 = 0x03;
    /// ACCEL_CONFIG_STATIC3: ACCEL_AAF_DELTSQR bits 7:0.
    pub const ACCEL_CONFIG_STATIC3: u8 = 0x04;
    /// ACCEL_CONFIG_STATIC4: ACCEL_AAF_BITSHIFT bits 7:4, ACCEL_AAF_DELTSQR bits 11:8 in 3:0.
    pub const ACCEL_CONFIG_STATIC4: u8 = 0x05;
}

/// WHO_AM_I value of the ICM-42688-P.
pub const WHO_AM_I_VALUE: u8 = 0x47;
/// DEVICE_CONFIG value that starts a soft reset.
pub const DEVICE_CONFIG_SOFT_RESET: u8 = 0x01;
/// Wait after a soft reset before any register access, µs (datasheet: 1 ms; doubled for margin).
pub const SOFT_RESET_WAIT_US: u32 = 2_000;
/// PWR_MGMT0: gyro and accel in low-noise mode, temperature sensor on.
pub const PWR_MGMT0_GYRO_ACCEL_LOW_NOISE: u8 = 0x0F;
/// No register writes for this long after leaving the OFF mode, µs (datasheet PWR_MGMT0 note).
pub const POWER_ON_WAIT_US: u32 = 200;
/// Gyro start-up time from off to valid data, µs (datasheet table 1: 30 ms). [`Icm42688::init`]
/// waits this long so that the first sample read after it is valid.
pub const GYRO_STARTUP_US: u32 = 30_000;

/// Anti-alias filter setting for 997 Hz 3 dB bandwidth (datasheet section 5.3 table).
pub const AAF_DELT: u8 = 21;
/// AAF_DELTSQR for 997 Hz (= AAF_DELT², 12 bits).
pub const AAF_DELTSQR: u16 = 440;
/// AAF_BITSHIFT for 997 Hz.
pub const AAF_BITSHIFT: u8 = 6;
/// The AAF 3 dB bandwidth these values give, Hz (datasheet section 5.3 table).
pub const AAF_BANDWIDTH_HZ: u32 = 997;

/// Gyro sensitivity at ±2000 °/s, LSB per °/s (datasheet table 1).
pub const GYRO_LSB_PER_DPS: f32 = 16.4;
/// Accel sensitivity at ±16 g, LSB per g (datasheet table 2).
pub const ACCEL_LSB_PER_G: f32 = 2048.0;
// Standard gravity (CGPM 1901), for g → m/s².
use flight::navigation::STANDARD_GRAVITY_MPS2;
/// Temperature sensitivity, LSB per °C (datasheet section 14.1, TEMP_DATA: °C = raw/132.48 + 25).
pub const TEMP_LSB_PER_C: f32 = 132.48;
/// Temperature at raw 0, °C.
pub const TEMP_OFFSET_C: f32 = 25.0;
/// Gyro scale: rad/s per LSB.
pub const GYRO_RAD_S_PER_LSB: f32 = core::f32::consts::PI / 180.0 / GYRO_LSB_PER_DPS;
/// Accel scale: m/s² per LSB.
pub const ACCEL_MPS2_PER_LSB: f32 = STANDARD_GRAVITY_MPS2 / ACCEL_LSB_PER_G;

/// First register of the sample burst (temperature, then accel X/Y/Z, then gyro X/Y/Z).
pub const SAMPLE_FIRST_REGISTER: u8 = bank0::TEMP_DATA1;
/// Length of the sample burst, bytes (0x1D..=0x2A).
pub const SAMPLE_LEN: usize = 14;
/// Output data rate, Hz (GYRO_CONFIG0 / ACCEL_CONFIG0 ODR = 0x03).
pub const ODR_HZ: u32 = 8_000;

/// One register the initialisation writes: its bank, address, value, the bits it owns (checked
/// on read-back; reserved bits are written with their reset value but not checked) and its
/// datasheet name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConfigRegister {
    /// User bank (0, 1 or 2).
    pub bank: u8,
    /// Address within the bank.
    pub address: u8,
    /// Value written.
    pub value: u8,
    /// Bits compared on read-back.
    pub mask: u8,
    /// Datasheet register name.
    pub name: &'static str,
}

const fn reg(bank: u8, address: u8, value: u8, mask: u8, name: &'static str) -> ConfigRegister {
    ConfigRegister { bank, address, value, mask, name }
}

/// The configuration written after the WHO_AM_I check, in order (grouped by bank), with the
/// sensors still off. PWR_MGMT0 is written separately, last.
pub const CONFIG_REGISTERS: [ConfigRegister; 16] = [
    // INT1 push-pull (bit 1), active high (bit 0), pulsed (bit 2 = 0); INT2 left at 0.
    reg(0, bank0::INT_CONFIG, 0x03, 0x3F, "INT_CONFIG"),
    // UI_DRDY_INT_CLEAR (bits 5:4) = 10: data-ready cleared by reading the sensor registers.
    reg(0, bank0::INT_CONFIG0, 0x20, 0x3F, "INT_CONFIG0"),
    // INT_TPULSE_DURATION 8 µs (bit 6), INT_TDEASSERT_DISABLE (bit 5), both required for
    // ODR ≥ 4 kHz; INT_ASYNC_RESET (bit 4) cleared as the datasheet requires for INT operation.
    reg(0, bank0::INT_CONFIG1, 0x60, 0x70, "INT_CONFIG1"),
    // UI_DRDY_INT1_EN (bit 3) only.
    reg(0, bank0::INT_SOURCE0, 0x08, 0x7F, "INT_SOURCE0"),
    // GYRO_FS_SEL 000 = ±2000 °/s, GYRO_ODR 0011 = 8 kHz.
    reg(0, bank0::GYRO_CONFIG0, 0x03, 0xEF, "GYRO_CONFIG0"),
    // ACCEL_FS_SEL 000 = ±16 g, ACCEL_ODR 0011 = 8 kHz.
    reg(0, bank0::ACCEL_CONFIG0, 0x03, 0xEF, "ACCEL_CONFIG0"),
    // TEMP_FILT_BW 000 (4 kHz), GYRO_UI_FILT_ORD 00 = 1st order, GYRO_DEC2_M2_ORD 10 = 3rd order
    // (the only valid value); bit 4 reserved (reset value 1).
    reg(0, bank0::GYRO_CONFIG1, 0x12, 0xEF, "GYRO_CONFIG1"),
    // ACCEL_UI_FILT_BW 1, GYRO_UI_FILT_BW 1: max(400 Hz, ODR)/4 = 2 kHz.
    reg(0, bank0::GYRO_ACCEL_CONFIG0, 0x11, 0xFF, "GYRO_ACCEL_CONFIG0"),
    // ACCEL_UI_FILT_ORD 00 = 1st order, ACCEL_DEC2_M2_ORD 10 = 3rd order; bit 0 reserved (1).
    reg(0, bank0::ACCEL_CONFIG1, 0x05, 0x1E, "ACCEL_CONFIG1"),
    // Bits 7:2 reserved (reset 101000); GYRO_AAF_DIS (bit 1) = 0: AAF on; GYRO_NF_DIS (bit 0) =
    // 1: notch off.
    reg(1, bank1::GYRO_CONFIG_STATIC2, 0xA1, 0x03, "GYRO_CONFIG_STATIC2"),
    reg(1, bank1::GYRO_CONFIG_STATIC3, AAF_DELT, 0x3F, "GYRO_CONFIG_STATIC3"),
    reg(1, bank1::GYRO_CONFIG_STATIC4, (AAF_DELTSQR & 0xFF) as u8, 0xFF, "GYRO_CONFIG_STATIC4"),
    reg(
        1,
        bank1::GYRO_CONFIG_STATIC5,
        (AAF_BITSHIFT << 4) | (AAF_DELTSQR >> 8) as u8,
        0xFF,
        "GYRO_CONFIG_STATIC5",
    ),
    // ACCEL_AAF_DELT in bits 6:1, ACCEL_AAF_DIS (bit 0) = 0: AAF on.
    reg(2, bank2::ACCEL_CONFIG_STATIC2, AAF_DELT << 1, 0x7F, "ACCEL_CONFIG_STATIC2"),
    reg(2, bank2::ACCEL_CONFIG_STATIC3, (AAF_DELTSQR & 0xFF) as u8, 0xFF, "ACCEL_CONFIG_STATIC3"),
    reg(
        2,
        bank2::ACCEL_CONFIG_STATIC4,
        (AAF_BITSHIFT << 4) | (AAF_DELTSQR >> 8) as u8,
        0xFF,
        "ACCEL_CONFIG_STATIC4",
    ),
];

/// PWR_MGMT0, written last (sensors on); bits 5:0 owned.
pub const POWER_REGISTER: ConfigRegister =
    reg(0, bank0::PWR_MGMT0, PWR_MGMT0_GYRO_ACCEL_LOW_NOISE, 0x3F, "PWR_MGMT0");

/// What can go wrong talking to the ICM-42688-P.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Icm42688Error<E> {
    /// The bus failed.
    Bus(E),
    /// WHO_AM_I was not 0x47: wrong or absent device (0x00 / 0xFF usually mean no answer).
    WhoAmI {
        /// The value read.
        read: u8,
    },
    /// A configuration register did not read back as written (in the bits the driver owns).
    ReadBack {
        /// The register (bank, address, name).
        register: ConfigRegister,
        /// Value written.
        expected: u8,
        /// Value read.
        read: u8,
    },
}

/// The protocol's driver state for the result of [`Icm42688::init`] (what `GetBoard` reports).
pub fn driver_state<E>(result: &Result<(), Icm42688Error<E>>) -> protocol::ImuDriverState {
    use protocol::ImuDriverState;
    match result {
        Ok(()) => ImuDriverState::Running,
        Err(Icm42688Error::Bus(_)) => ImuDriverState::BusError,
        Err(Icm42688Error::WhoAmI { read }) => {
            ImuDriverState::WrongIdentity { expected: WHO_AM_I_VALUE, found: *read }
        }
        Err(Icm42688Error::ReadBack { register, expected, read }) => {
            ImuDriverState::ConfigMismatch {
                register: register.address,
                written: *expected,
                read: *read,
            }
        }
    }
}

/// One raw sample as the device sends it (big-endian registers, sensor axes).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RawSample {
    /// TEMP_DATA, LSB.
    pub temperature: i16,
    /// ACCEL_DATA X, Y, Z, LSB.
    pub accel: [i16; 3],
    /// GYRO_DATA X, Y, Z, LSB.
    pub gyro: [i16; 3],
}

impl RawSample {
    /// Decode the 14-byte burst read from [`SAMPLE_FIRST_REGISTER`].
    pub fn from_be_bytes(b: &[u8; SAMPLE_LEN]) -> Self {
        let word = |i: usize| i16::from_be_bytes([b[2 * i], b[2 * i + 1]]);
        Self {
            temperature: word(0),
            accel: [word(1), word(2), word(3)],
            gyro: [word(4), word(5), word(6)],
        }
    }

    /// Whether every accel and gyro axis reads -32768 (0x8000), the value the data registers
    /// hold when the sensors are off or have no data yet (datasheet reset value). A real
    /// saturated reading would not be negative full scale on all six axes at once.
    pub fn is_no_data(&self) -> bool {
        self.accel.iter().chain(self.gyro.iter()).all(|&v| v == i16::MIN)
    }

    /// Scale to SI units (sensor axes). -32768 scales like any other value (-2000 °/s, -16 g).
    pub fn to_si(&self) -> Icm42688Sample {
        Icm42688Sample {
            gyro_rad_s: self.gyro.map(|v| f32::from(v) * GYRO_RAD_S_PER_LSB),
            accel_mps2: self.accel.map(|v| f32::from(v) * ACCEL_MPS2_PER_LSB),
            temperature_c: f32::from(self.temperature) / TEMP_LSB_PER_C + TEMP_OFFSET_C,
        }
    }
}

/// One sample in SI units, sensor axes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Icm42688Sample {
    /// Angular rate, rad/s.
    pub gyro_rad_s: [f32; 3],
    /// Specific force, m/s².
    pub accel_mps2: [f32; 3],
    /// Die temperature, °C.
    pub temperature_c: f32,
}

impl Icm42688Sample {
    /// The application's IMU sample (without temperature).
    pub fn to_imu_sample(&self) -> ImuSample {
        ImuSample { gyro_rad_s: self.gyro_rad_s, accel_mps2: self.accel_mps2 }
    }
}

/// The ICM-42688-P on a [`RegisterBus`].
#[derive(Debug)]
pub struct Icm42688<B> {
    bus: B,
}

impl<B: RegisterBus> Icm42688<B> {
    /// Wrap a bus. Nothing is sent until [`Icm42688::init`].
    pub const fn new(bus: B) -> Self {
        Self { bus }
    }

    /// The bus (e.g. to start DMA reads after initialisation).
    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    /// Give the bus back.
    pub fn release(self) -> B {
        self.bus
    }

    /// Initialise: select bank 0, soft reset, wait, check WHO_AM_I, write
    /// [`CONFIG_REGISTERS`], read every one back, power the sensors on ([`POWER_REGISTER`]),
    /// wait, check PWR_MGMT0, and wait for the gyro to start.
    ///
    /// On a WHO_AM_I mismatch nothing more is written. On a read-back mismatch the driver
    /// selects bank 0 again (best effort) and leaves the sensors off.
    pub fn init<D: DelayUs>(&mut self, delay: &mut D) -> Result<(), Icm42688Error<B::Error>> {
        // The bank may be left at 1 or 2 if only the MCU was reset.
        self.write(bank0::REG_BANK_SEL, 0)?;
        self.write(bank0::DEVICE_CONFIG, DEVICE_CONFIG_SOFT_RESET)?;
        delay.delay_us(SOFT_RESET_WAIT_US);

        let who_am_i = self.read_one(bank0::WHO_AM_I)?;
        if who_am_i != WHO_AM_I_VALUE {
            return Err(Icm42688Error::WhoAmI { read: who_am_i });
        }

        let mut bank = 0u8;
        for r in CONFIG_REGISTERS.iter() {
            self.select_bank(&mut bank, r.bank)?;
            self.write(r.address, r.value)?;
        }
        self.select_bank(&mut bank, 0)?;

        if let Err(e) = self.verify_all(&mut bank) {
            // Best effort: leave the device in bank 0; the first error is the one reported.
            let _ = self.select_bank(&mut bank, 0);
            return Err(e);
        }

        self.write(POWER_REGISTER.address, POWER_REGISTER.value)?;
        delay.delay_us(POWER_ON_WAIT_US);
        self.verify(&POWER_REGISTER)?;
        delay.delay_us(GYRO_STARTUP_US);
        Ok(())
    }

    /// Read one sample (14-byte burst from TEMP_DATA1).
    pub fn read_raw(&mut self) -> Result<RawSample, Icm42688Error<B::Error>> {
        let mut buf = [0u8; SAMPLE_LEN];
        self.bus.read_registers(SAMPLE_FIRST_REGISTER, &mut buf).map_err(Icm42688Error::Bus)?;
        Ok(RawSample::from_be_bytes(&buf))
    }

    /// Read one sample and scale it to SI units.
    pub fn read_sample(&mut self) -> Result<Icm42688Sample, Icm42688Error<B::Error>> {
        self.read_raw().map(|raw| raw.to_si())
    }

    fn write(&mut self, reg: u8, value: u8) -> Result<(), Icm42688Error<B::Error>> {
        self.bus.write_register(reg, value).map_err(Icm42688Error::Bus)
    }

    fn read_one(&mut self, reg: u8) -> Result<u8, Icm42688Error<B::Error>> {
        let mut buf = [0u8; 1];
        self.bus.read_registers(reg, &mut buf).map_err(Icm42688Error::Bus)?;
        Ok(buf[0])
    }

    fn select_bank(&mut self, current: &mut u8, bank: u8) -> Result<(), Icm42688Error<B::Error>> {
        if *current != bank {
            self.write(bank0::REG_BANK_SEL, bank)?;
            *current = bank;
        }
        Ok(())
    }

    fn verify(&mut self, r: &ConfigRegister) -> Result<(), Icm42688Error<B::Error>> {
        let read = self.read_one(r.address)?;
        if (read ^ r.value) & r.mask != 0 {
            return Err(Icm42688Error::ReadBack { register: *r, expected: r.value, read });
        }
        Ok(())
    }

    fn verify_all(&mut self, bank: &mut u8) -> Result<(), Icm42688Error<B::Error>> {
        for r in CONFIG_REGISTERS.iter() {
            self.select_bank(bank, r.bank)?;
            self.verify(r)?;
        }
        self.select_bank(bank, 0)
    }
}

/// Sums 8 kHz samples and yields their mean at the control rate (e.g. every 4 samples for
/// 2 kHz). Sums are kept in raw LSB as integers, so averaging is exact until the final scaling.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SampleAverager {
    count: u32,
    sum_accel: [i64; 3],
    sum_gyro: [i64; 3],
    sum_temperature: i64,
}

impl SampleAverager {
    /// An empty accumulator.
    pub const fn new() -> Self {
        Self { count: 0, sum_accel: [0; 3], sum_gyro: [0; 3], sum_temperature: 0 }
    }

    /// Add one sample. Samples flagged [`RawSample::is_no_data`] are not added (returns
    /// `false`).
    pub fn add(&mut self, sample: &RawSample) -> bool {
        if sample.is_no_data() || self.count == u32::MAX {
            return false;
        }
        for i in 0..3 {
            self.sum_accel[i] += i64::from(sample.accel[i]);
            self.sum_gyro[i] += i64::from(sample.gyro[i]);
        }
        self.sum_temperature += i64::from(sample.temperature);
        self.count += 1;
        true
    }

    /// Samples accumulated since the last [`SampleAverager::take`].
    pub fn count(&self) -> u32 {
        self.count
    }

    /// The mean of the accumulated samples in SI units, and reset; `None` if empty.
    pub fn take(&mut self) -> Option<Icm42688Sample> {
        if self.count == 0 {
            return None;
        }
        let n = f64::from(self.count);
        let mean = |sum: i64| (sum as f64 / n) as f32;
        let out = Icm42688Sample {
            gyro_rad_s: self.sum_gyro.map(|s| mean(s) * GYRO_RAD_S_PER_LSB),
            accel_mps2: self.sum_accel.map(|s| mean(s) * ACCEL_MPS2_PER_LSB),
            temperature_c: mean(self.sum_temperature) / TEMP_LSB_PER_C + TEMP_OFFSET_C,
        };
        *self = Self::new();
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Op {
        Write { reg: u8, value: u8 },
        Read { reg: u8, len: usize },
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    struct BusFault;

    /// A register file of three banks that records every access.
    struct MockBus {
        banks: [[u8; 128]; 3],
        bank: usize,
        ops: Vec<Op>,
        /// A register (bank, address) that ignores writes.
        stuck: Option<(usize, u8)>,
        /// Fail the nth operation.
        fail_at: Option<usize>,
    }

    impl MockBus {
        fn new(who_am_i: u8) -> Self {
            let mut banks = [[0u8; 128]; 3];
            banks[0][usize::from(bank0::WHO_AM_I)] = who_am_i;
            Self { banks, bank: 0, ops: Vec::new(), stuck: None, fail_at: None }
        }

        fn writes(&self) -> Vec<(u8, u8)> {
            self.ops
                .iter()
                .filter_map(|op| match *op {
                    Op::Write { reg, value } => Some((reg, value)),
                    Op::Read { .. } => None,
                })
                .collect()
        }

        fn check_fail(&mut self) -> Result<(), BusFault> {
            if self.fail_at == Some(self.ops.len()) {
                return Err(BusFault);
            }
            Ok(())
        }
    }

    impl RegisterBus for MockBus {
        type Error = BusFault;

        fn write_register(&mut self, reg: u8, value: u8) -> Result<(), BusFault> {
            self.check_fail()?;
            self.ops.push(Op::Write { reg, value });
            if reg == bank0::REG_BANK_SEL {
                self.bank = usize::from(value).min(2);
            } else if self.stuck != Some((self.bank, reg)) {
                self.banks[self.bank][usize::from(reg & 0x7F)] = value;
            }
            Ok(())
        }

        fn read_registers(&mut self, first_reg: u8, buf: &mut [u8]) -> Result<(), BusFault> {
            self.check_fail()?;
            self.ops.push(Op::Read { reg: first_reg, len: buf.len() });
            for (i, b) in buf.iter_mut().enumerate() {
                *b = self.banks[self.bank][(usize::from(first_reg) + i) & 0x7F];
            }
            Ok(())
        }
    }

    #[derive(Default)]
    struct MockDelay {
        calls: Vec<u32>,
    }

    impl DelayUs for MockDelay {
        fn delay_us(&mut self, us: u32) {
            self.calls.push(us);
        }
    }

    #[test]
    fn init_write_sequence_is_pinned() {
        let mut imu = Icm42688::new(MockBus::new(0x47));
        let mut delay = MockDelay::default();
        assert_eq!(imu.init(&mut delay), Ok(()));
        let expected_writes: [(u8, u8); 25] = [
            (0x76, 0x00),
            (0x11, 0x01),
            (0x14, 0x03),
            (0x63, 0x20),
            (0x64, 0x60),
            (0x65, 0x08),
            (0x4F, 0x03),
            (0x50, 0x03),
            (0x51, 0x12),
            (0x52, 0x11),
            (0x53, 0x05),
            (0x76, 0x01),
            (0x0B, 0xA1),
            (0x0C, 21),
            (0x0D, 0xB8), // 440 & 0xFF
            (0x0E, 0x61), // 6 << 4 | 440 >> 8
            (0x76, 0x02),
            (0x03, 0x2A), // 21 << 1
            (0x04, 0xB8),
            (0x05, 0x61),
            (0x76, 0x00),
            // Read-back bank switches.
            (0x76, 0x01),
            (0x76, 0x02),
            (0x76, 0x00),
            (0x4E, 0x0F),
        ];
        let bus = imu.release();
        assert_eq!(bus.writes(), expected_writes.to_vec());
        // The WHO_AM_I read comes right after the reset; each config register is read back
        // once, PWR_MGMT0 last.
        assert_eq!(bus.ops[2], Op::Read { reg: 0x75, len: 1 });
        let reads: Vec<u8> = bus
            .ops
            .iter()
            .filter_map(|op| match *op {
                Op::Read { reg, len: 1 } => Some(reg),
                _ => None,
            })
            .collect();
        assert_eq!(
            reads,
            [
                0x75, 0x14, 0x63, 0x64, 0x65, 0x4F, 0x50, 0x51, 0x52, 0x53, 0x0B, 0x0C, 0x0D, 0x0E,
                0x03, 0x04, 0x05, 0x4E
            ]
            .to_vec()
        );
        assert_eq!(delay.calls, [2_000, 200, 30_000].to_vec());
        assert_eq!(bus.bank, 0);
    }

    #[test]
    fn wrong_who_am_i_stops_before_configuration() {
        let mut imu = Icm42688::new(MockBus::new(0x6A));
        let mut delay = MockDelay::default();
        assert_eq!(imu.init(&mut delay), Err(Icm42688Error::WhoAmI { read: 0x6A }));
        let bus = imu.release();
        assert_eq!(bus.writes(), [(0x76, 0x00), (0x11, 0x01)].to_vec());
        assert_eq!(bus.ops.len(), 3);
    }

    #[test]
    fn read_back_mismatch_names_the_register() {
        let mut bus = MockBus::new(0x47);
        // GYRO_CONFIG_STATIC3 (bank 1) ignores writes and reads 13 (its reset value).
        bus.banks[1][0x0C] = 13;
        bus.stuck = Some((1, 0x0C));
        let mut imu = Icm42688::new(bus);
        let mut delay = MockDelay::default();
        let result = imu.init(&mut delay);
        let Err(Icm42688Error::ReadBack { register, expected, read }) = result else {
            panic!("expected a read-back error, got {result:?}");
        };
        assert_eq!(register.name, "GYRO_CONFIG_STATIC3");
        assert_eq!((register.bank, register.address), (1, 0x0C));
        assert_eq!((expected, read), (21, 13));
        let bus = imu.release();
        // Back in bank 0, and the sensors were never powered on.
        assert_eq!(bus.bank, 0);
        assert!(!bus.writes().contains(&(0x4E, 0x0F)));
    }

    #[test]
    fn reserved_bits_are_not_compared() {
        let mut bus = MockBus::new(0x47);
        // GYRO_CONFIG_STATIC2 with read-only reserved bits reading 0xA8: owned bits still match.
        bus.banks[1][0x0B] = 0xA9;
        bus.stuck = Some((1, 0x0B));
        let mut imu = Icm42688::new(bus);
        assert_eq!(imu.init(&mut MockDelay::default()), Ok(()));
    }

    #[test]
    fn bus_errors_propagate() {
        let mut bus = MockBus::new(0x47);
        bus.fail_at = Some(5);
        let mut imu = Icm42688::new(bus);
        assert_eq!(imu.init(&mut MockDelay::default()), Err(Icm42688Error::Bus(BusFault)));
    }

    #[test]
    fn sample_decoding_and_scaling() {
        let mut bus = MockBus::new(0x47);
        let data: [u8; 14] = [
            0x00, 0x00, // temperature 0 → 25 °C
            0x08, 0x00, // accel X 2048 → 1 g
            0xF8, 0x00, // accel Y -2048
            0x80, 0x00, // accel Z -32768 → -16 g
            0x00, 0xA4, // gyro X 164 → 10 °/s
            0xFF, 0x5C, // gyro Y -164
            0x7F, 0xFF, // gyro Z 32767
        ];
        bus.banks[0][0x1D..0x1D + 14].copy_from_slice(&data);
        let mut imu = Icm42688::new(bus);
        let raw = imu.read_raw();
        assert_eq!(
            raw,
            Ok(RawSample {
                temperature: 0,
                accel: [2048, -2048, -32768],
                gyro: [164, -164, 32767],
            })
        );
        let s = imu.read_sample().unwrap();
        let close = |a: f32, b: f32, tol: f32| (a - b).abs() <= tol;
        assert!(close(s.accel_mps2[0], 9.80665, 1e-5), "{s:?}");
        assert!(close(s.accel_mps2[1], -9.80665, 1e-5));
        assert!(close(s.accel_mps2[2], -16.0 * 9.80665, 1e-3));
        let ten_dps = 10.0_f32.to_radians();
        assert!(close(s.gyro_rad_s[0], ten_dps, 1e-6));
        assert!(close(s.gyro_rad_s[1], -ten_dps, 1e-6));
        // 32767 / 16.4 = 1997.99 °/s.
        assert!(close(s.gyro_rad_s[2], 1997.988_f32.to_radians(), 1e-4));
        assert!(close(s.temperature_c, 25.0, 1e-6));
        assert_eq!(imu.bus_mut().ops.last(), Some(&Op::Read { reg: 0x1D, len: 14 }));

        // 16.4 LSB = 1 °/s (raw 164 above = 10 °/s); -32768 → -1998.05 °/s.
        let raw = RawSample {
            temperature: 1325, // 1325 / 132.48 + 25 = 35.0 °C
            accel: [0, 0, 2048],
            gyro: [i16::MIN, 0, 0],
        };
        let s = raw.to_si();
        assert!(close(s.gyro_rad_s[0], (-32768.0_f32 / 16.4).to_radians(), 1e-4));
        assert!(close(s.gyro_rad_s[0], -34.872, 1e-3));
        assert!(close(s.temperature_c, 35.0015, 1e-3));
        assert_eq!(s.to_imu_sample().accel_mps2, [0.0, 0.0, 9.80665]);
    }

    #[test]
    fn start_up_results_become_driver_states() {
        use protocol::ImuDriverState;
        assert_eq!(driver_state::<()>(&Ok(())), ImuDriverState::Running);
        assert_eq!(driver_state(&Err(Icm42688Error::Bus(()))), ImuDriverState::BusError);
        assert_eq!(
            driver_state::<()>(&Err(Icm42688Error::WhoAmI { read: 0xFF })),
            ImuDriverState::WrongIdentity { expected: 0x47, found: 0xFF }
        );
        let register = CONFIG_REGISTERS[4];
        assert_eq!(
            driver_state::<()>(&Err(Icm42688Error::ReadBack {
                register,
                expected: 0x03,
                read: 0x06
            })),
            ImuDriverState::ConfigMismatch { register: 0x4F, written: 0x03, read: 0x06 }
        );
    }

    #[test]
    fn no_data_marker() {
        let raw = RawSample::from_be_bytes(&[0x80, 0x00].repeat(7).try_into().unwrap());
        assert_eq!(raw.temperature, i16::MIN);
        assert!(raw.is_no_data());
        let mut one_real = raw;
        one_real.gyro[1] = 5;
        assert!(!one_real.is_no_data());
    }

    #[test]
    fn averaging_of_four_samples() {
        let mut avg = SampleAverager::new();
        assert_eq!(avg.take(), None);
        let samples = [
            RawSample { temperature: 0, accel: [0, 0, 2048], gyro: [164, 0, -10] },
            RawSample { temperature: 132, accel: [100, 0, 2048], gyro: [328, 1, -10] },
            RawSample { temperature: 264, accel: [-100, 3, 2048], gyro: [0, 2, -10] },
            RawSample { temperature: 396, accel: [0, 1, 2048], gyro: [164, 3, -11] },
        ];
        for s in &samples {
            assert!(avg.add(s));
        }
        // The no-data marker is not averaged in.
        assert!(!avg.add(&RawSample {
            temperature: i16::MIN,
            accel: [i16::MIN; 3],
            gyro: [i16::MIN; 3],
        }));
        assert_eq!(avg.count(), 4);
        let m = avg.take().unwrap();
        assert_eq!(avg.count(), 0);
        assert_eq!(avg.take(), None);
        let close = |a: f32, b: f32, tol: f32| (a - b).abs() <= tol;
        // Mean gyro X = 164 LSB = 10 °/s; Y = 1.5 LSB; Z = -10.25 LSB.
        assert!(close(m.gyro_rad_s[0], 10.0_f32.to_radians(), 1e-6));
        assert!(close(m.gyro_rad_s[1], 1.5 * GYRO_RAD_S_PER_LSB, 1e-9));
        assert!(close(m.gyro_rad_s[2], -10.25 * GYRO_RAD_S_PER_LSB, 1e-8));
        assert!(close(m.accel_mps2[0], 0.0, 0.0));
        assert!(close(m.accel_mps2[1], 1.0 * ACCEL_MPS2_PER_LSB, 1e-9));
        assert!(close(m.accel_mps2[2], 9.80665, 1e-5));
        // Mean temperature 198 LSB → 26.4946 °C.
        assert!(close(m.temperature_c, 198.0 / 132.48 + 25.0, 1e-5));
    }

    #[test]
    fn register_table_matches_datasheet_addresses() {
        assert_eq!(bank0::ACCEL_DATA_X1, SAMPLE_FIRST_REGISTER + 2);
        assert_eq!(bank0::GYRO_DATA_X1, bank0::ACCEL_DATA_X1 + 6);
        assert_eq!(usize::from(bank0::GYRO_DATA_Z0 - SAMPLE_FIRST_REGISTER) + 1, SAMPLE_LEN);
        // Banks are grouped so each is selected once.
        let mut last = 0;
        for r in CONFIG_REGISTERS.iter() {
            assert!(r.bank >= last);
            last = r.bank;
        }
        // The 997 Hz AAF entry, as written to the gyro (bank 1) and accel (bank 2) registers.
        assert_eq!((AAF_DELT, AAF_DELTSQR, AAF_BITSHIFT), (21, 440, 6));
    }
}
