//! What the flight-log tests share: a craft at rest on the bench, logged.

use firmware::app::hal::{Imu, ImuSample, Motors, NoBattery, NoBytes, MAX_MOTORS};
use firmware::app::log::LogSink;
use firmware::app::system::{with_logged_system, LogTarget, NoLinks, TickHardware};
use firmware::app::{ControlCommand, NoFlash, Settings};
use flight::rng::Rng;
use protocol::BoardHealth;

/// An IMU at rest with noise, a sample missing now and then.
pub struct NoisyImu(pub Rng);

impl Imu for NoisyImu {
    fn read(&mut self) -> Option<ImuSample> {
        let mut n = || self.0.normal() as f32;
        let sample = ImuSample {
            gyro_rad_s: [0.01 * n(), 0.01 * n(), 0.01 * n()],
            accel_mps2: [0.05 * n(), 0.05 * n(), -9.81 + 0.05 * n()],
        };
        (self.0.uniform() > 0.001).then_some(sample)
    }
}

/// Four motors reporting speeds.
pub struct FourMotors;

impl Motors for FourMotors {
    fn count(&self) -> u8 {
        4
    }
    fn set_commands(&mut self, _commands: &[f32]) {}
    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
        [Some(0.0), Some(0.0), Some(0.0), Some(0.0), None, None, None, None]
    }
}

/// Run `steps` control steps at 2 kHz (link passes at 1 kHz) logging into `sink`, submitting
/// each `(step, command)` of `commands` before its step; the file open at the end is closed.
pub fn fly(sink: &mut dyn LogSink, steps: u64, commands: &[(u64, ControlCommand)]) {
    let target = LogTarget { sink, board: "TEST" };
    let settings = Settings::<NoFlash>::without_store();
    with_logged_system(settings, BoardHealth::default(), None, Some(target), |system| {
        let mut imu = NoisyImu(Rng::new(7));
        for step in 1..=steps {
            for (_, command) in commands.iter().filter(|(at, _)| *at == step) {
                system.submit(*command);
            }
            let now_us = step * 500;
            let hardware = TickHardware {
                imu: &mut imu,
                motors: &mut FourMotors,
                radio_bytes: &mut NoBytes,
                battery: &mut NoBattery,
            };
            if system.tick(now_us, hardware).link_due {
                system.pass(now_us, &mut NoLinks);
            }
        }
        system.finish_log();
    });
}
