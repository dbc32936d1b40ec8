//! The hardware boundary: the small traits the application needs from a board.
//!
//! The STM32H743 implements them with stm32h7xx-hal (SPI IMU, DShot timers, USB, flash); the
//! simulator implements them in memory. Nothing above this line knows which one it runs on.

/// Maximum number of motors any airframe may have (the learner supports 4 to 8).
pub const MAX_MOTORS: usize = 8;

/// One inertial sample in the IMU's own frame, already scaled to SI units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
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
    /// with the next stop frames. Outputs that cannot send one keep this default.
    fn send_command(
        &mut self,
        _command: protocol::DshotCommand,
        _motor: Option<u8>,
    ) -> Result<(), EscCommandError> {
        Err(EscCommandError::Unsupported)
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
