//! What the two I²C compass drivers share: the register bus, their errors, a reading, the
//! health report that tells a lost or stuck sensor from a working one, and the device
//! ([`CompassDevice`]: its bus, address and health, the reset-and-identify and
//! write-then-verify steps both initialisations take); each driver adds its chip's `init` and
//! `read` for its own chip type.
//!
//! Why: a compass on a GNSS mast hangs at the end of a cable on an I²C bus that picks up motor
//! noise; a connector shaken loose, a sensor that stops converting (its registers frozen at the
//! last value) or a magnet next to it (saturated) must be seen and reported, never panic, and
//! never hand the heading a stale field. [`HealthMonitor`] counts what each read returned and
//! says which of these it is; each driver keeps one and updates it on every read.
//!
//! Assumptions: the board polls the sensor at its output rate (50–200 Hz); a working sensor's
//! noise (at least a few tenths of an LSB per axis) changes at least one axis between two
//! conversions, so [`STUCK_AFTER_IDENTICAL_READINGS`] identical readings in a row mean a frozen
//! sensor (for a sensor at 0.3 µT/LSB with 0.4 µT of noise all three axes repeat with a chance of
//! about 0.1 each time: 25 in a row, 10⁻²⁵).

/// Register access on an I²C bus with a 7-bit device address. `read_registers` reads
/// consecutive registers (both sensors auto-increment the register address in a burst).
pub trait I2cRegisterBus {
    /// The bus error (a NACK from an absent device included).
    type Error;
    /// Write one register of the device at `address`.
    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Self::Error>;
    /// Read `buf.len()` consecutive registers of the device at `address` from `first_reg`.
    fn read_registers(
        &mut self,
        address: u8,
        first_reg: u8,
        buf: &mut [u8],
    ) -> Result<(), Self::Error>;

    /// [`Self::write_register`], a bus failure as [`CompassError::Bus`].
    fn write_one(
        &mut self,
        address: u8,
        reg: u8,
        value: u8,
    ) -> Result<(), CompassError<Self::Error>> {
        self.write_register(address, reg, value).map_err(CompassError::Bus)
    }

    /// One register of the device at `address`, a bus failure as [`CompassError::Bus`].
    fn read_one(&mut self, address: u8, reg: u8) -> Result<u8, CompassError<Self::Error>> {
        let mut buf = [0u8; 1];
        self.read_registers(address, reg, &mut buf).map_err(CompassError::Bus)?;
        Ok(buf[0])
    }
}

/// A borrowed bus is a bus: the application's compass service is handed the board's bus for
/// each call and builds its driver around the borrow.
impl<B: I2cRegisterBus + ?Sized> I2cRegisterBus for &mut B {
    type Error = B::Error;
    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Self::Error> {
        (**self).write_register(address, reg, value)
    }
    fn read_registers(
        &mut self,
        address: u8,
        first_reg: u8,
        buf: &mut [u8],
    ) -> Result<(), Self::Error> {
        (**self).read_registers(address, first_reg, buf)
    }
}

pub use super::icm42688::DelayUs;

/// What can go wrong talking to a compass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CompassError<E> {
    /// The bus failed (an absent device does not acknowledge its address).
    Bus(E),
    /// The identity register did not hold the expected value: another device at the address
    /// (0x00 or 0xFF usually mean nothing answered).
    WrongDevice {
        /// The value expected.
        expected: u8,
        /// The value read.
        read: u8,
    },
    /// A configuration register did not read back as written.
    ConfigMismatch {
        /// The register.
        register: u8,
        /// Value written.
        written: u8,
        /// Value read.
        read: u8,
    },
    /// No new measurement yet (read again later).
    NotReady,
    /// The field is beyond the sensor's range on some axis: the reading is not valid (a magnet
    /// or a current-carrying wire next to the sensor).
    Overflow,
}

/// One reading: the raw counts and the field in microtesla, both in the sensor's own axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompassReading {
    /// Raw output counts, X, Y, Z.
    pub raw: [i16; 3],
    /// The field, µT, sensor axes.
    pub field_ut: [f32; 3],
}

/// Consecutive failed reads (bus errors, or no new data when one was due) after which the
/// sensor counts as lost: 10, a tenth of a second at 100 Hz.
pub const LOST_AFTER_FAILED_READS: u16 = 10;
/// Consecutive overflowing reads after which the sensor counts as saturated.
pub const SATURATED_AFTER_OVERFLOWS: u16 = 10;
/// Identical readings in a row after which the sensor counts as stuck (see the module docs).
pub const STUCK_AFTER_IDENTICAL_READINGS: u16 = 25;

/// The compass's state as the health monitor sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CompassState {
    /// No valid reading yet.
    Starting,
    /// Valid readings arrive and change.
    Healthy,
    /// [`LOST_AFTER_FAILED_READS`] reads in a row failed: unplugged, unpowered or the bus is
    /// jammed.
    Lost,
    /// [`STUCK_AFTER_IDENTICAL_READINGS`] identical readings in a row: frozen.
    Stuck,
    /// [`SATURATED_AFTER_OVERFLOWS`] overflowing reads in a row.
    Saturated,
}

/// The compass's health report: its state and what led to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CompassHealth {
    /// The state.
    pub state: CompassState,
    /// Valid readings since start.
    pub readings: u32,
    /// Failed reads since start (bus errors and reads with no new data).
    pub failures: u32,
    /// Overflowing reads since start.
    pub overflows: u32,
    /// Failed reads in a row now.
    pub consecutive_failures: u16,
    /// Overflowing reads in a row now.
    pub consecutive_overflows: u16,
    /// Identical valid readings in a row now (1 for a reading unlike the one before).
    pub identical_readings: u16,
}

/// Counts what the reads return and derives [`CompassHealth`] (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HealthMonitor {
    health: CompassHealth,
    last_raw: Option<[i16; 3]>,
}

impl Default for HealthMonitor {
    fn default() -> Self {
        Self::new()
    }
}

impl HealthMonitor {
    /// Nothing seen yet.
    pub const fn new() -> Self {
        Self {
            health: CompassHealth {
                state: CompassState::Starting,
                readings: 0,
                failures: 0,
                overflows: 0,
                consecutive_failures: 0,
                consecutive_overflows: 0,
                identical_readings: 0,
            },
            last_raw: None,
        }
    }

    /// The report.
    pub fn health(&self) -> CompassHealth {
        self.health
    }

    /// Record one read's result. A [`CompassError::NotReady`] counts as a failure: the board
    /// polls at the output rate, so a sensor that is never ready has stopped converting.
    pub fn record<E>(&mut self, result: &Result<CompassReading, CompassError<E>>) -> CompassHealth {
        let h = &mut self.health;
        match result {
            Ok(reading) => {
                h.readings = h.readings.saturating_add(1);
                h.consecutive_failures = 0;
                h.consecutive_overflows = 0;
                h.identical_readings = if self.last_raw == Some(reading.raw) {
                    h.identical_readings.saturating_add(1)
                } else {
                    1
                };
                self.last_raw = Some(reading.raw);
            }
            Err(CompassError::Overflow) => {
                h.overflows = h.overflows.saturating_add(1);
                h.consecutive_overflows = h.consecutive_overflows.saturating_add(1);
                h.consecutive_failures = 0;
            }
            Err(_) => {
                h.failures = h.failures.saturating_add(1);
                h.consecutive_failures = h.consecutive_failures.saturating_add(1);
            }
        }
        h.state = if h.consecutive_failures >= LOST_AFTER_FAILED_READS {
            CompassState::Lost
        } else if h.consecutive_overflows >= SATURATED_AFTER_OVERFLOWS {
            CompassState::Saturated
        } else if h.identical_readings >= STUCK_AFTER_IDENTICAL_READINGS {
            CompassState::Stuck
        } else if h.readings == 0 {
            CompassState::Starting
        } else if h.state == CompassState::Starting
            || (h.consecutive_failures == 0 && h.consecutive_overflows == 0)
        {
            CompassState::Healthy
        } else {
            // A failure or two after good readings: keep the state until a limit is reached.
            h.state
        };
        *h
    }
}

/// A little-endian 16-bit two's-complement value (both sensors send the low byte first).
pub(crate) fn le_i16(low: u8, high: u8) -> i16 {
    i16::from_le_bytes([low, high])
}

#[cfg(test)]
pub(crate) mod mock {
    //! A mock I²C bus for the compass drivers' tests: one device's 256 registers at one address,
    //! every access recorded.
    use super::{DelayUs, I2cRegisterBus};
    use std::vec::Vec;

    /// A delay that only counts the microseconds asked of it.
    pub struct NoDelay(pub u32);

    impl DelayUs for NoDelay {
        fn delay_us(&mut self, us: u32) {
            self.0 += us;
        }
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Op {
        Write { address: u8, reg: u8, value: u8 },
        Read { address: u8, reg: u8, len: usize },
    }

    /// The error of an unacknowledged address.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub struct Nack;

    pub struct MockBus {
        pub address: u8,
        pub registers: [u8; 256],
        pub ops: Vec<Op>,
        /// Whether the device answers at all.
        pub present: bool,
        /// Registers that ignore writes (their value stays).
        pub read_only: Vec<u8>,
    }

    impl MockBus {
        pub fn new(address: u8) -> Self {
            Self {
                address,
                registers: [0; 256],
                ops: Vec::new(),
                present: true,
                read_only: Vec::new(),
            }
        }
    }

    impl I2cRegisterBus for MockBus {
        type Error = Nack;
        fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Nack> {
            self.ops.push(Op::Write { address, reg, value });
            if !self.present || address != self.address {
                return Err(Nack);
            }
            if !self.read_only.contains(&reg) {
                self.registers[usize::from(reg)] = value;
            }
            Ok(())
        }
        fn read_registers(&mut self, address: u8, reg: u8, buf: &mut [u8]) -> Result<(), Nack> {
            self.ops.push(Op::Read { address, reg, len: buf.len() });
            if !self.present || address != self.address {
                return Err(Nack);
            }
            for (i, b) in buf.iter_mut().enumerate() {
                *b = self.registers[(usize::from(reg) + i) & 0xFF];
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ok(raw: [i16; 3]) -> Result<CompassReading, CompassError<()>> {
        Ok(CompassReading { raw, field_ut: [0.0; 3] })
    }

    #[test]
    fn a_lost_sensor_is_reported_after_ten_failed_reads() {
        let mut monitor = HealthMonitor::new();
        assert_eq!(monitor.health().state, CompassState::Starting);
        assert_eq!(monitor.record(&ok([1, 2, 3])).state, CompassState::Healthy);
        for i in 1..LOST_AFTER_FAILED_READS {
            let h = monitor.record(&Err::<CompassReading, _>(CompassError::Bus(())));
            assert_eq!(h.state, CompassState::Healthy, "after {i} failures");
        }
        let h = monitor.record(&Err::<CompassReading, _>(CompassError::<()>::NotReady));
        assert_eq!((h.state, h.failures, h.consecutive_failures), (CompassState::Lost, 10, 10));
        // Back: healthy at the first valid reading.
        assert_eq!(monitor.record(&ok([1, 2, 4])).state, CompassState::Healthy);
    }

    #[test]
    fn a_frozen_sensor_is_reported_as_stuck() {
        let mut monitor = HealthMonitor::new();
        for i in 0..STUCK_AFTER_IDENTICAL_READINGS - 1 {
            assert_eq!(monitor.record(&ok([5, 5, 5])).state, CompassState::Healthy, "{i}");
        }
        assert_eq!(monitor.record(&ok([5, 5, 5])).state, CompassState::Stuck);
        assert_eq!(monitor.record(&ok([5, 5, 6])).state, CompassState::Healthy);
    }

    #[test]
    fn a_saturated_sensor_is_reported() {
        let mut monitor = HealthMonitor::new();
        for _ in 0..SATURATED_AFTER_OVERFLOWS {
            monitor.record(&Err::<CompassReading, _>(CompassError::<()>::Overflow));
        }
        let h = monitor.health();
        assert_eq!((h.state, h.overflows, h.readings), (CompassState::Saturated, 10, 0));
    }
}

/// One compass chip `C` at `address` on `bus`, with the health report of its reads. The chip
/// type only selects the driver (`super::ist8310::Ist8310`, `super::qmc5883l::Qmc5883l`),
/// whose `init` and `read` are written for its own `CompassDevice<B, Chip>`.
#[derive(Debug)]
pub struct CompassDevice<B, C> {
    pub(super) bus: B,
    pub(super) address: u8,
    monitor: HealthMonitor,
    chip: core::marker::PhantomData<C>,
}

impl<B: I2cRegisterBus, C> CompassDevice<B, C> {
    /// Wrap a bus; nothing is sent until the driver's `init`.
    pub const fn new(bus: B, address: u8) -> Self {
        Self::resume(bus, address, HealthMonitor::new())
    }

    /// Wrap a bus for a sensor already initialised, carrying on the health report `monitor`
    /// (a service that borrows the bus for each read keeps the monitor between reads).
    pub const fn resume(bus: B, address: u8, monitor: HealthMonitor) -> Self {
        Self { bus, address, monitor, chip: core::marker::PhantomData }
    }

    /// The health monitor, to carry over to the next [`Self::resume`].
    pub fn monitor(&self) -> HealthMonitor {
        self.monitor
    }

    /// Give the bus back.
    pub fn release(self) -> B {
        self.bus
    }

    /// The health report of the reads so far.
    pub fn health(&self) -> CompassHealth {
        self.monitor.health()
    }

    /// Count one read's result in the health report and pass it on.
    pub(super) fn recorded(
        &mut self,
        result: Result<CompassReading, CompassError<B::Error>>,
    ) -> Result<CompassReading, CompassError<B::Error>> {
        self.monitor.record(&result);
        result
    }

    /// Write `value` to the reset register `reset`, wait `wait_us`, and check that the identity
    /// register `identity` reads `expected` ([`CompassError::WrongDevice`] otherwise).
    pub(super) fn reset_and_identify<D: DelayUs>(
        &mut self,
        delay: &mut D,
        (reset, value): (u8, u8),
        wait_us: u32,
        (identity, expected): (u8, u8),
    ) -> Result<(), CompassError<B::Error>> {
        self.bus.write_one(self.address, reset, value)?;
        delay.delay_us(wait_us);
        let read = self.bus.read_one(self.address, identity)?;
        if read != expected {
            return Err(CompassError::WrongDevice { expected, read });
        }
        Ok(())
    }

    /// Write each `(register, value)`, then read each back ([`CompassError::ConfigMismatch`] at
    /// the first that differs).
    pub(super) fn write_verified(
        &mut self,
        config: &[(u8, u8)],
    ) -> Result<(), CompassError<B::Error>> {
        for &(register, value) in config {
            self.bus.write_one(self.address, register, value)?;
        }
        for &(register, written) in config {
            let read = self.bus.read_one(self.address, register)?;
            if read != written {
                return Err(CompassError::ConfigMismatch { register, written, read });
            }
        }
        Ok(())
    }
}
