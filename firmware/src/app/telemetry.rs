//! Telemetry at the control rate: the control step writes one [`StepRecord`] per step into a
//! lock-free ring ([`StepRing`]); the link task drains it and serialises the per-step topics
//! (`Topic::is_per_step`: IMU, motors, state) straight into its transmit buffer
//! (`LinkServer::stream`).
//!
//! Why a ring and not a snapshot: a snapshot read at the link's pace (1 kHz) can only ever show
//! every second step, and a late link pass silently skips more. The ring hands every step to the
//! link; when the link falls behind (the host reads slowly, the transmit buffer is full), records
//! or frames are dropped whole and the topic's sequence number, derived from the step count,
//! shows each one as a gap. The step's cost is one copy of about 110 bytes.

use super::hal::{ImuSample, MAX_MOTORS};
use super::queue::{RingConsumer, RingProducer};
use flight::learner::FlightPhase;
use heapless::spsc::Queue;
use protocol::{ImuTelemetry, LearnerPhase, MotorTelemetry, StateTelemetry, Telemetry, Topic};

/// Ring capacity, records: 64 records are 32 ms at 2 kHz, 32 link passes at 1 kHz (heapless'
/// ring keeps one slot free, so 63 are usable). About 7.7 KB.
pub const STEP_RING_LEN: usize = 64;

/// What one control step did, for the per-step telemetry topics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepRecord {
    /// The step's number since start-up (the first step is 1): the per-step topics' sequence.
    pub step: u32,
    /// Time of the step, µs since start-up.
    pub t_us: u64,
    /// The IMU sample the step used (bias removed), if it had a new one.
    pub imu: Option<ImuSample>,
    /// Attitude of the IMU in the world (NED), `[w, x, y, z]`.
    pub q_world_imu: [f32; 4],
    pub phase: FlightPhase,
    /// Whether the attempt ended without a result (the phase then reads as failed).
    pub failed: bool,
    pub flying: bool,
    pub motor_count: u8,
    /// Commands δ ∈ [0, 1] written by the step.
    pub commands: [f32; MAX_MOTORS],
    /// Speeds reported after the step's commands, rad/s.
    pub speeds_rad_s: [Option<f32>; MAX_MOTORS],
}

/// The ring's storage; split it once with [`super::split_queue`].
pub type StepRing = Queue<StepRecord, STEP_RING_LEN>;
/// The control step's end of the ring.
pub type StepProducer<'q> = RingProducer<'q, StepRecord>;
/// The link task's end of the ring.
pub type StepConsumer<'q> = RingConsumer<'q, StepRecord>;

/// The throw-to-fly phase for the wire (an attempt that ended without a result reads as failed).
pub fn wire_phase(phase: FlightPhase, failed: bool) -> LearnerPhase {
    match phase {
        FlightPhase::Idle if failed => LearnerPhase::Failed,
        FlightPhase::Idle => LearnerPhase::Idle,
        FlightPhase::WaitingForThrow => LearnerPhase::WaitingForThrow,
        FlightPhase::Throwing => LearnerPhase::Throwing,
        FlightPhase::Released => LearnerPhase::Released,
        FlightPhase::Exciting => LearnerPhase::Exciting,
        FlightPhase::Done => LearnerPhase::Done,
    }
}

impl StepRecord {
    /// This step's sample of a per-step topic; `None` for the IMU topic in a step without a new
    /// sample (its sequence number is then a gap: a sample the IMU did not deliver) and for the
    /// topics the link samples itself.
    pub fn sample(&self, topic: Topic) -> Option<Telemetry> {
        match topic {
            Topic::Imu => self.imu.map(|imu| {
                Telemetry::Imu(ImuTelemetry {
                    t_us: self.t_us,
                    gyro_rad_s: imu.gyro_rad_s,
                    accel_mps2: imu.accel_mps2,
                })
            }),
            Topic::Motors => Some(Telemetry::Motors(MotorTelemetry {
                t_us: self.t_us,
                commands: self.commands,
                speeds_rad_s: self.speeds_rad_s,
            })),
            Topic::State => {
                let imu = self.imu.unwrap_or_default();
                Some(Telemetry::State(StateTelemetry {
                    t_us: self.t_us,
                    phase: wire_phase(self.phase, self.failed),
                    flying: self.flying,
                    imu_fresh: self.imu.is_some(),
                    gyro_rad_s: imu.gyro_rad_s,
                    accel_mps2: imu.accel_mps2,
                    q_world_imu: self.q_world_imu,
                    motor_count: self.motor_count,
                    commands: self.commands,
                    speeds_rad_s: self.speeds_rad_s,
                }))
            }
            Topic::Control | Topic::Learner | Topic::Flight => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{DeviceMessage, MAX_FRAME_LEN};

    #[test]
    fn the_largest_state_sample_fits_one_frame_and_a_step_without_imu_has_no_imu_sample() {
        let record = StepRecord {
            step: u32::MAX,
            t_us: u64::MAX,
            imu: Some(ImuSample { gyro_rad_s: [-1e30; 3], accel_mps2: [1e30; 3] }),
            q_world_imu: [1.0, 0.0, 0.0, 0.0],
            phase: FlightPhase::Exciting,
            failed: false,
            flying: true,
            motor_count: MAX_MOTORS as u8,
            commands: [1.0; MAX_MOTORS],
            speeds_rad_s: [Some(3000.0); MAX_MOTORS],
        };
        let mut buffer = [0u8; MAX_FRAME_LEN];
        for topic in Topic::ALL.into_iter().filter(|t| t.is_per_step()) {
            let sample = record.sample(topic).expect("a per-step topic has a sample");
            let frame = DeviceMessage::Telemetry(sample).encode(u16::MAX, &mut buffer);
            assert!(frame.is_ok(), "{topic:?} does not fit one frame");
        }
        let without_imu = StepRecord { imu: None, ..record };
        assert_eq!(without_imu.sample(Topic::Imu), None);
        match without_imu.sample(Topic::State) {
            Some(Telemetry::State(state)) => assert!(!state.imu_fresh),
            other => panic!("expected a state sample, got {other:?}"),
        }
        assert_eq!(record.sample(Topic::Learner), None, "the link samples the learner itself");
    }
}
