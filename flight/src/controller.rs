//! The closed-loop cascade from a learned model: guidance → attitude → rate → INDI.
//!
//! ```text
//! position fix ─► NDI position (P → PI) ─► f_sp (world) ─┐        (or level + zero climb rate
//!                                                         ▼         without a position)
//! attitude (filter) ─► tilt/yaw error in the thrust frame ─► Ω_sp (≤ 800 °/s tilt, 400 °/s yaw)
//!                  gyro ─► rate error × k_rate ─► Ω̇_ref ─┐
//!                  thrust |f_sp| projected on the current thrust axis ─► f_z,ref ─► INDI ─► δ
//! ```
//!
//! Everything is expressed in the **thrust frame** T found by the thrust-axis solver: its −z is
//! the direction in which the motors push most efficiently, so "level" means that axis up, and
//! the IMU can sit in any orientation (algorithms.md §6–8, seed paper §3.4).
//!
//! - **Attitude** (§7): the error between the thrust frame and its setpoint is split into tilt
//!   (the shortest rotation of the current thrust axis onto the wanted one) and yaw about the
//!   thrust axis; each becomes a rate setpoint through the attitude gain, tilt limited to
//!   [`MAX_TILT_RATE_RAD_S`] and yaw to [`MAX_YAW_RATE_RAD_S`], so a craft tumbling after the
//!   excitation first stops its rotation and then levels.
//! - **Thrust**: the wanted specific force projected on the *current* thrust axis (no thrust is
//!   wasted pushing sideways while tilted), at least [`MIN_THRUST_FRACTION`] of it so the motors
//!   keep authority when upside down.
//! - **Gains** from the slowest motor's τ ([`crate::position::Gains`], §7).
//!
//! A plain struct with [`Controller::update`]; the application decides when it runs and what
//! happens when it reports trouble.

use nalgebra::{UnitQuaternion, Vector3};

use crate::attitude::wrap_pi;
use crate::indi::{Indi, IndiConfig, IndiError, IndiModel, IndiOutput, IndiReference};
use crate::navigation::{NavigationState, STANDARD_GRAVITY_MPS2};
use crate::position::{Gains, PositionController, PositionSetpoint};

/// Largest tilt rate the attitude loop asks for, rad/s (800 °/s, algorithms.md §7).
pub const MAX_TILT_RATE_RAD_S: f32 = 800.0 * core::f32::consts::PI / 180.0;

/// Largest yaw rate the attitude loop asks for, rad/s (400 °/s, algorithms.md §7).
pub const MAX_YAW_RATE_RAD_S: f32 = 400.0 * core::f32::consts::PI / 180.0;

/// Smallest thrust while the thrust axis points away from the wanted one, fraction of the wanted
/// specific force: a tumbling craft keeps enough spin on its rotors for differential thrust to
/// right it, without driving itself into the ground.
pub const MIN_THRUST_FRACTION: f32 = 0.2;

/// Tilt beyond which the yaw error is ignored, rad (90°): the heading of a craft on its side is
/// undefined, and righting it comes first.
pub const YAW_CONTROL_MAX_TILT_RAD: f32 = core::f32::consts::FRAC_PI_2;

/// What the craft is asked to do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Guidance {
    /// Hold a position (world NED, m) and heading (rad) from external position fixes.
    Position { position_ned_m: Vector3<f32>, yaw_rad: f32 },
    /// No position: thrust axis up, the velocity `velocity_ned_mps` (an estimate by dead
    /// reckoning, world NED, m/s) brought to zero, heading `yaw_rad`.
    Level { yaw_rad: f32, velocity_ned_mps: Vector3<f32> },
}

/// One step's measurements.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerInput {
    /// Raw gyro, IMU axes, rad/s.
    pub gyro_rad_s: [f32; 3],
    /// Raw accelerometer, IMU axes, m/s².
    pub accel_mps2: [f32; 3],
    /// Attitude of the IMU in the world (from the attitude filter).
    pub q_world_imu: UnitQuaternion<f32>,
    /// Position and velocity of the CoG.
    pub navigation: NavigationState,
}

/// What one step decided, for the motors and for telemetry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerOutput {
    /// INDI's commands and allocation status.
    pub indi: IndiOutput,
    /// Attitude of the thrust frame in the world.
    pub q_world_thrust: UnitQuaternion<f32>,
    /// Wanted specific force, world NED, m/s².
    pub specific_force_sp_ned_mps2: Vector3<f32>,
    /// Rate setpoint, thrust frame, rad/s.
    pub rate_sp_rad_s: Vector3<f32>,
    /// Angular acceleration asked of INDI, thrust frame, rad/s².
    pub angular_accel_sp_rad_s2: Vector3<f32>,
    /// Angle between the thrust axis and the wanted one, rad.
    pub tilt_error_rad: f32,
}

/// The cascade.
#[derive(Clone, Debug)]
pub struct Controller {
    indi: Indi,
    gains: Gains,
    position: PositionController,
    rate_hz: f32,
}

impl Controller {
    /// A controller flying `model` with the IMU `r_imu_m` from the CoG (IMU axes, m).
    pub fn new(model: IndiModel, r_imu_m: [f32; 3], config: IndiConfig) -> Result<Self, IndiError> {
        let tau_max = model.motor[..model.motors].iter().map(|m| m.tau_s).fold(0.0, f32::max);
        let gains = Gains::from_tau(tau_max);
        Ok(Self {
            indi: Indi::new(model, r_imu_m, config)?,
            position: PositionController::new(gains),
            gains,
            rate_hz: config.rate_hz,
        })
    }

    /// The handover from the excitation: prime the filters with the current sample and what the
    /// motors were last told (δ) and report (rad/s, NaN where unknown).
    pub fn start(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        commands: &[f32; crate::learner::MAX_MOTORS],
        speeds_rad_s: &[f32; crate::learner::MAX_MOTORS],
    ) {
        self.indi.start(gyro_rad_s, accel_mps2, commands, speeds_rad_s);
        self.position.reset();
    }

    /// The gains in use.
    pub fn gains(&self) -> &Gains {
        &self.gains
    }

    /// The INDI loop (its model and filtered state).
    pub fn indi(&self) -> &Indi {
        &self.indi
    }

    /// One control step.
    pub fn update(
        &mut self,
        input: &ControllerInput,
        guidance: &Guidance,
    ) -> Result<ControllerOutput, IndiError> {
        let dt_s = 1.0 / self.rate_hz;
        let q_world_thrust = input.q_world_imu * self.indi.model().q_imu_thrust;
        let nav = &input.navigation;
        let (f_sp, yaw_sp) = match *guidance {
            Guidance::Position { position_ned_m, yaw_rad } => {
                let setpoint =
                    PositionSetpoint { position_ned_m, velocity_ned_mps: Vector3::zeros() };
                let f = self
                    .position
                    .update(&nav.position_ned_m, &nav.velocity_ned_mps, &setpoint, dt_s)
                    .unwrap_or(Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2));
                (f, yaw_rad)
            }
            Guidance::Level { yaw_rad, velocity_ned_mps } => {
                // Zero velocity: the velocity loop's P alone (no integral on a drifting estimate).
                let accel = crate::position::limit_split(
                    &(velocity_ned_mps * -self.gains.k_velocity),
                    crate::position::MAX_ACCEL_MPS2,
                );
                let f = accel - Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2);
                (crate::position::limit_tilt(&f), yaw_rad)
            }
        };
        let (rate_sp, tilt_error_rad, thrust) =
            attitude_loop(&q_world_thrust, &f_sp, yaw_sp, &self.gains);
        let to_thrust = self.indi.model().q_imu_thrust.inverse();
        let rate = to_thrust * Vector3::from(input.gyro_rad_s);
        let accel_sp = (rate_sp - rate) * self.gains.k_rate;
        let reference =
            IndiReference { specific_force_z_mps2: -thrust, angular_accel_rad_s2: accel_sp };
        let indi = self.indi.update(input.gyro_rad_s, input.accel_mps2, &reference)?;
        Ok(ControllerOutput {
            indi,
            q_world_thrust,
            specific_force_sp_ned_mps2: f_sp,
            rate_sp_rad_s: rate_sp,
            angular_accel_sp_rad_s2: accel_sp,
            tilt_error_rad,
        })
    }
}

/// The attitude loop: rate setpoint (thrust frame, rad/s), tilt error (rad) and thrust (m/s²) for
/// a wanted specific force `f_sp` (world NED) and heading `yaw_sp_rad`.
pub fn attitude_loop(
    q_world_thrust: &UnitQuaternion<f32>,
    f_sp: &Vector3<f32>,
    yaw_sp_rad: f32,
    gains: &Gains,
) -> (Vector3<f32>, f32, f32) {
    let f_norm = f_sp.norm();
    // The wanted thrust-frame z ("down" of the craft) in the world: opposite the specific force.
    let z_wanted_world = if f_norm > 1e-3 { -f_sp / f_norm } else { Vector3::new(0.0, 0.0, 1.0) };
    let z_wanted = q_world_thrust.inverse() * z_wanted_world;
    // Tilt: rotate the body z onto the wanted one about e3 × z_wanted.
    let axis = Vector3::new(-z_wanted.y, z_wanted.x, 0.0);
    let sin_tilt = axis.norm();
    let tilt = libm::atan2f(sin_tilt, z_wanted.z);
    let tilt_axis = if sin_tilt > 1e-6 { axis / sin_tilt } else { Vector3::new(1.0, 0.0, 0.0) };
    let mut rate_sp = tilt_axis * (gains.k_attitude * tilt);
    let tilt_rate = rate_sp.norm();
    if tilt_rate > MAX_TILT_RATE_RAD_S {
        rate_sp *= MAX_TILT_RATE_RAD_S / tilt_rate;
    }
    // Yaw: the heading error once tilted onto the wanted axis.
    if tilt < YAW_CONTROL_MAX_TILT_RAD {
        let tilt_world =
            UnitQuaternion::rotation_between(&(q_world_thrust * Vector3::z()), &z_wanted_world)
                .unwrap_or_else(UnitQuaternion::identity);
        let levelled = tilt_world * q_world_thrust;
        let x = levelled * Vector3::x();
        let yaw = libm::atan2f(x.y, x.x);
        let error = wrap_pi(yaw_sp_rad - yaw);
        rate_sp.z = (gains.k_attitude * error).clamp(-MAX_YAW_RATE_RAD_S, MAX_YAW_RATE_RAD_S);
    }
    let thrust = (f_norm * libm::cosf(tilt)).max(MIN_THRUST_FRACTION * f_norm);
    (rate_sp, tilt, thrust)
}
