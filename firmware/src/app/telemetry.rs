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
//!
//! The sampled topics are built here too, from the tasks' snapshots ([`flight_telemetry`],
//! [`learner_telemetry`], [`sensor_health`]): the link streams them, and the flight log records
//! them exactly as streamed (`super::log`), so both read them from here.

use super::hal::{ImuSample, MAX_MOTORS};
use super::pilot::failsafe_reason;
use super::queue::{RingConsumer, RingProducer};
use super::StatusView;
use flight::learner::AxisStatus;
use flight::learner::FlightPhase;
use heapless::spsc::Queue;
use nalgebra::Vector3;
use protocol::{
    FlightMode, FlightTelemetry, ImuTelemetry, LearnerFailure, LearnerPhase, LearnerTelemetry,
    MotorTelemetry, SensorHealth, StateTelemetry, Telemetry, Topic,
};

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

/// How the control step coped with its sensors, for the wire.
pub fn sensor_health(view: &StatusView) -> SensorHealth {
    let control = &view.control;
    SensorHealth {
        imu_held: control.imu_held,
        imu_longest_hold_us: control.imu_longest_hold_us,
        motor_count: control.motor_count,
        speeds_reported: control.speeds_reported,
        speed_reports_lost: control.speed_reports_lost,
    }
}

/// The closed loop's state for the wire.
pub fn flight_telemetry(view: &StatusView) -> FlightTelemetry {
    let control = &view.control;
    let pilot = &control.pilot;
    let mode = match (pilot.flying, pilot.landing, pilot.piloted, pilot.position_hold) {
        (false, ..) => FlightMode::Off,
        (true, Some(reason), ..) => FlightMode::Landing(reason),
        (true, None, Some(false), _) => FlightMode::Angle,
        (true, None, _, false) => FlightMode::LevelHold,
        (true, None, _, true) => FlightMode::PositionHold,
    };
    let q = if pilot.flying { pilot.q_world_thrust } else { pilot.q_world_imu };
    let [roll, pitch, yaw] = flight::attitude::euler_zyx_rad(q);
    // The rate in the thrust frame: the IMU's rate turned by the learned q_U^T while flying.
    let gyro = Vector3::from(control.imu.gyro_rad_s);
    let thrust_to_imu =
        view.background.learned.thrust_axis.and_then(|a| a.rotation_thrust_to_imu());
    let rate = match (thrust_to_imu, pilot.flying) {
        (Some(q), true) => q.inverse() * gyro,
        _ => gyro,
    };
    let known = control.external_pose.is_some() || control.position_fix.is_some();
    FlightTelemetry {
        t_us: control.t_us,
        mode,
        q_world_thrust: q,
        euler_zyx_rad: [roll, pitch, yaw],
        rate_rad_s: rate.into(),
        rate_sp_rad_s: pilot.rate_sp_rad_s,
        specific_force_sp_ned_mps2: pilot.specific_force_sp_ned_mps2,
        tilt_error_rad: pilot.tilt_error_rad,
        position_sp_ned_m: pilot.position_hold.then_some(pilot.position_sp_ned_m),
        position_ned_m: known.then_some(pilot.position_ned_m),
        velocity_ned_mps: (known || pilot.flying).then_some(pilot.velocity_ned_mps),
        pose_fresh: pilot.has_fix,
        allocation_failures: pilot.allocation_failures,
        saturated: pilot.saturated,
        last_failsafe: pilot.last_failsafe.map(failsafe_reason),
        failsafes: pilot.failsafes,
    }
}

/// The learner's state for the wire, with rows `3·block .. 3·block + 3` of G1 (per unit
/// normalised thrust).
pub fn learner_telemetry(view: &StatusView, block: u8) -> LearnerTelemetry {
    let control = &view.control;
    let learned = &view.background.learned;
    let m = usize::from(learned.motors).min(MAX_MOTORS);
    let attempt_over = control.phase == FlightPhase::Done;
    let axis_failure = match learned.axis_status {
        AxisStatus::RankDeficient => LearnerFailure::RankDeficient,
        AxisStatus::NoHover => LearnerFailure::NoHover,
        AxisStatus::Waiting | AxisStatus::Found => LearnerFailure::None,
    };
    let failure = if control.failure != LearnerFailure::None {
        control.failure
    } else if attempt_over && learned.thrust_axis.is_none() {
        if axis_failure == LearnerFailure::None {
            LearnerFailure::RankDeficient
        } else {
            axis_failure
        }
    } else {
        LearnerFailure::None
    };
    let phase = match control.phase {
        _ if attempt_over && failure != LearnerFailure::None => LearnerPhase::Failed,
        phase => wire_phase(phase, failure != LearnerFailure::None),
    };
    let mut out = LearnerTelemetry {
        t_us: control.t_us,
        phase,
        failure,
        motor_count: learned.motors,
        exciting_motor: control.exciting_motor,
        excitation_ms: control.excitation_ms,
        motors_converged: learned.motors_converged,
        g1_converged: learned.g1_converged,
        g1_block: block.min(1),
        ..LearnerTelemetry::default()
    };
    for i in 0..m {
        out.tau_s[i] = learned.motor[i].tau_s;
        out.omega_max_rad_s[i] = learned.motor[i].omega_full_rad_s();
    }
    if let Some(axis) = &learned.thrust_axis {
        out.thrust_axis_valid = true;
        out.q_thrust_to_imu = axis.q_thrust_to_imu;
        out.euler_zyx_rad = axis.euler_zyx_rad;
    }
    let g1 = learned.g1_per_unit_thrust();
    let first = 3 * usize::from(out.g1_block);
    for (row, source) in out.g1_rows.iter_mut().zip(&g1[first..first + 3]) {
        row[..m].copy_from_slice(&source[..m]);
    }
    out
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
