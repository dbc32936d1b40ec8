//! The hardware boundary: the small traits the application needs from a board.
//!
//! The STM32H743 implements them with stm32h7xx-hal (SPI IMU, DShot timers, USB, flash); the
//! simulator implements them in memory. Nothing above this line knows which one it runs on.

use crate::drivers::dshot::CommandQueue;

/// Maximum number of motors any airframe may have (the learner supports 4 to 8).
pub const MAX_MOTORS: usize = 8;

/// One inertial sample in the IMU's own frame, already scaled to SI units.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImuSample {
    /// Angular rate, rad/s, IMU axes.
    pub gyro_rad_s: [f32; 3],
    /// Specific force (what an accelerometer measures: acceleration minus gravity), m/s², IMU axes.
    pub accel_mps2: [f32; 3],
}

/// The IMU as the control step sees it: one sample per 2 kHz tick, or none when the sensor has
/// nothing new (missing samples are counted by the application, never waited for).
pub trait Imu {
    /// The newest sample since the last call, if any. Must not block.
    fn read(&mut self) -> Option<ImuSample>;
}

/// Motor outputs and their telemetry.
pub trait Motors {
    /// Number of motors connected (1..=[`MAX_MOTORS`]).
    fn count(&self) -> u8;
    /// Set the normalised commands δ ∈ [0, 1] for the first `count()` motors. Must not block.
    fn set_commands(&mut self, commands: &[f32]);
    /// Latest motor speeds in rad/s from RPM telemetry (bidirectional DShot), `None` where a
    /// motor has not reported.
    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS];
    /// Queue an ESC command (a DShot special command) for `motor` (`None` = every motor), sent
    /// instead of the stop frames on the following steps as often as the specification asks:
    /// into [`Motors::esc_command_queue`], refused while armed.
    fn send_command(
        &mut self,
        command: protocol::DshotCommand,
        motor: Option<u8>,
    ) -> Result<(), EscCommandError> {
        let queue = self.esc_command_queue().ok_or(EscCommandError::Unsupported)?;
        queue.queue(command, motor).map_err(|_| EscCommandError::Armed)
    }
    /// The queue of the ESC commands these outputs send instead of their stop frames. Outputs
    /// that cannot send one keep this default (`None`: [`EscCommandError::Unsupported`]).
    fn esc_command_queue(&mut self) -> Option<&mut CommandQueue> {
        None
    }
    /// The control step's arming state after each tick (the board switches its outputs between
    /// sending frames and capturing the ESCs' answers). Outputs without such a switch keep this
    /// default.
    fn set_armed(&mut self, _armed: bool) {}
    /// The DShot link's health for the status (`None`: outputs that do not measure it).
    fn health(&self) -> Option<protocol::MotorLinkHealth> {
        None
    }
}

/// Why the motor outputs did not take an ESC command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EscCommandError {
    /// These outputs send no special commands (the bridge's external simulator, no motors).
    Unsupported,
    /// The motors are armed: a command never reaches a spinning motor.
    Armed,
}

/// The motor outputs of a board that has none connected (or whose driver is not there yet):
/// commands go nowhere and no speeds are reported.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoMotors;

impl Motors for NoMotors {
    fn count(&self) -> u8 {
        0
    }
    fn set_commands(&mut self, _commands: &[f32]) {}
    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
        [None; MAX_MOTORS]
    }
}

/// The UART of the pilot's radio receiver, as the control step drives it.
pub trait Uart {
    /// Copy the bytes received since the last call into `buffer` (at most its length); returns
    /// how many. Must not block.
    fn read(&mut self, buffer: &mut [u8]) -> usize;
    /// Queue `bytes` for sending (telemetry to the pilot's handset); returns how many were taken
    /// (a UART with no room, or no transmitter, takes fewer or none). Must not block.
    fn write(&mut self, _bytes: &[u8]) -> usize {
        0
    }
}

/// The GNSS receiver's UART: bytes both ways and a baud rate the driver chooses (it searches
/// for the receiver's rate, then moves both to the configured one: `super::gnss`).
pub trait GnssPort: Uart {
    /// Run the UART at `baud` from now on (bytes in flight may be lost: the driver expects it).
    fn set_baud(&mut self, baud: u32);
}

/// No receiver connected: never any bytes.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoBytes;

impl Uart for NoBytes {
    fn read(&mut self, _buffer: &mut [u8]) -> usize {
        0
    }
}

/// A receiver that may not be there: no bytes when absent.
impl<B: Uart> Uart for Option<B> {
    fn read(&mut self, buffer: &mut [u8]) -> usize {
        self.as_mut().map_or(0, |source| source.read(buffer))
    }
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.as_mut().map_or(0, |sink| sink.write(bytes))
    }
}

/// One measurement of the flight battery, already scaled to SI units by the board (its divider
/// and current-sensor scale are board data: `targets::BatterySensing` on the STM32H743).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BatteryReading {
    /// Pack voltage, V.
    pub voltage_v: f32,
    /// Current drawn from the pack, A.
    pub current_a: f32,
}

/// The flight battery's voltage and current, as the control tick polls it.
pub trait BatterySensor {
    /// The newest reading since the last call, if any. Must not block (a board starts the next
    /// conversion and returns; the tick asks again next period).
    fn read(&mut self) -> Option<BatteryReading>;
}

/// A board that measures no battery (the bridge's external simulator, a board without the
/// divider).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoBattery;

impl BatterySensor for NoBattery {
    fn read(&mut self) -> Option<BatteryReading> {
        None
    }
}

/// One reading handed over once (the simulator's board measures its battery each tick).
impl BatterySensor for Option<BatteryReading> {
    fn read(&mut self) -> Option<BatteryReading> {
        self.take()
    }
}

/// A host link's byte port: USB CDC on the board, a pseudo-terminal or a TCP stream in the
/// simulator, later a radio's UART.
pub trait Port {
    /// Read what is available now into `buffer`: `Ok(0)` when nothing is. Must not block.
    fn read(&mut self, buffer: &mut [u8]) -> Result<usize, PortClosed>;
    /// Offer `bytes`; returns how many the port took (0 when full). Must not block.
    fn write(&mut self, bytes: &[u8]) -> Result<usize, PortClosed>;
    /// Push what the port buffered towards the host. Must not block.
    fn flush(&mut self) {}
}

/// The host went away: the port was closed (a TCP client disconnected).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PortClosed;

/// Default of the `imu_fault_timeout_s` parameter, s: how long, armed, the step flies on the
/// last good IMU sample before bad or missing samples count as a failed IMU. Origin: a held
/// sample freezes the measured rate and specific force, so under an angular acceleration α the
/// controller does not see, the rate it believes drifts by α·T and the attitude by ½·α·T². In a
/// hover (α of gusts and vibration, ≲ 20 rad/s²) 20 ms cost 0.4 rad/s and 0.2°; in the recovery
/// from a throw, where INDI commands up to a few hundred rad/s², about 4 rad/s and 2°: what the
/// rate loop corrects within its own time constant. At 50 ms the same recovery would fly
/// 10 rad/s and 14° blind while the motors (τ 25–50 ms) ran their whole response to stale
/// increments. Measured (`tests/tests/faults.rs`): 39 bad samples (19.5 ms) of every kind, in
/// the recovery and in hover, are ridden through; the paper quad recovers and holds its position.
pub const IMU_FAULT_TIMEOUT_S: f32 = 0.02;

/// Seconds from `since_us` to `now_us` (0 when `now_us` is earlier), through a 32-bit count
/// of microseconds (71 minutes at most, then saturated): the Cortex-M7 converts that in one
/// instruction, where a 64-bit one is a library call of about 30 (`cargo xtask bench-m7`).
pub fn elapsed_s(since_us: u64, now_us: u64) -> f32 {
    let us = now_us.saturating_sub(since_us).min(u64::from(u32::MAX)) as u32;
    us as f32 * 1e-6
}
