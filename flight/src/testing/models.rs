//! Learned models with a known structure, for tests of what flies them (the INDI model, the
//! application's pilot).

use crate::learner::motor_model::MotorModel;
use crate::learner::{AxisStatus, LearnedModel, LearnedThrustAxis, MAX_MOTORS};

/// A quad in X whose IMU is rolled 90° from its thrust frame, motors with ω_full = 2,000 rad/s,
/// its thrust axis found.
pub fn learned_quad() -> LearnedModel {
    let motor = MotorModel {
        a_rad_s: 1000.0,
        b_rad_s: 800.0,
        omega_idle_rad_s: 200.0,
        tau_s: 0.03,
        tau_std_s: 1e-4,
        converged: true,
    };
    let half = core::f32::consts::FRAC_1_SQRT_2;
    let mut learned = LearnedModel {
        motors: 4,
        motor: [motor; MAX_MOTORS],
        thrust_axis: Some(LearnedThrustAxis {
            q_thrust_to_imu: [half, half, 0.0, 0.0],
            thrust_dir_imu: [0.0, 1.0, 0.0],
            u_hover: [0.3, 0.3, 0.3, 0.3, 0.0, 0.0, 0.0, 0.0],
            euler_zyx_rad: [core::f32::consts::FRAC_PI_2, 0.0, 0.0],
            clamped_by: 0.0,
        }),
        axis_status: AxisStatus::Found,
        ..LearnedModel::default()
    };
    for j in 0..4 {
        let sign = |bit: usize| if (j >> bit) & 1 == 0 { 1.0 } else { -1.0 };
        // IMU axes: thrust along +y (IMU), torques about x and z (IMU), yaw about y.
        learned.g1_per_speed2[1][j] = -4e-6;
        learned.g1_per_speed2[3][j] = 5e-5 * sign(0);
        learned.g1_per_speed2[4][j] = 3e-6 * sign(0) * sign(1);
        learned.g1_per_speed2[5][j] = 5e-5 * sign(1);
        learned.g2[1][j] = 2e-3 * sign(0) * sign(1);
    }
    learned
}
