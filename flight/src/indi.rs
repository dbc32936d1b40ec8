//! Incremental nonlinear dynamic inversion (INDI) of the learned actuators, in the thrust frame.
//!
//! INDI does not need a model of the airframe's dynamics, only of its actuators: the
//! angular acceleration and specific force it measures already contain every unmodelled moment
//! and force, so it asks the motors only for the *increment* that turns the measured `ν₀` into
//! the wanted `ν_ref`. What the learner identified is exactly what this needs
//! (docs/algorithms/indi.md, seed paper §3.4):
//!
//! ```text
//! ν = [f; Ω̇]  (thrust frame)            specific force at the CoG, angular acceleration
//! dv = ν_ref − ν₀,  dv_rot += G2 ω̇₀      horizontal force rows: dv = 0 (no sideways thrust)
//! G  = G1 (+ G2 ω_full²/(2 τ ω₀) on the rotational rows, ω₀ ≥ 0.1 ω_full)
//! du = WLS-allocate(G, dv, −u₀ + u_min ≤ du ≤ 1 − u₀)
//! u  = u₀ + du   →  ω = ω_full √u  →  δ from ω = a δ + b √δ + ω_idle
//! ```
//!
//! - **Synchronised signals.** Ω, f and the actuator state u₀ pass the *same* 2nd-order
//!   Butterworth low-pass (15 Hz, published), so the increment compares like with like; Ω̇₀ is the
//!   backward difference of the filtered Ω, ω̇₀ that of the filtered actuator speed.
//! - **Actuator model.** u₀ is not measured: each motor is a first-order lag of its commanded
//!   speed with the learned τ (exact discretisation), and `u = ω²/ω_full²`. Telemetry speeds are not
//!   needed, so a motor whose eRPM is missing flies the same.
//! - **The G2 term.** A motor's speed change accelerates the rotor and reacts on the frame: a
//!   commanded increment Δu gives at once `Δω̇ = ω_full² Δu / (2 ω₀ τ)`, so the rotational rows
//!   gain `G2 ω_full²/(2 τ ω₀)`. That is what makes yaw (mostly rotor reaction) controllable fast.
//!   On the yaw row only (the thrust frame's z): a rotor tilted off the thrust axis also reacts
//!   about the tilt axes, but only while its speed changes. Counted there, the allocation bought
//!   tilt torque with motor accelerations it could not sustain — at idle, where `1/ω₀` is largest,
//!   the reaction term of a 30°-tilted octorotor's motor was larger than its thrust's lever and of
//!   the other sign, the motors flipped between full and idle every few steps, and the roll rate
//!   ran away to the gyro's limit (Monte Carlo case 962 of `fly`). The tilt rows treat the
//!   reaction as any other disturbance: INDI measures it in `Ω̇₀` and answers it next step.
//! - **Frames.** The learner's G1 and G2 are in IMU axes; [`IndiModel::from_learned`] rotates their
//!   rows into the thrust frame `T` (from `q_U^T`), whose −z is the hover thrust direction. The
//!   allocation weights (1, 1, 50, 50, 50, 5) then mean: horizontal force barely, thrust and
//!   tilt strongly, yaw (about the thrust axis) weakly.
//! - **The accelerometer** is moved to the centre of gravity after filtering,
//!   `f = f_imu − Ω̇×r − Ω×(Ω×r)`, so a board mounted off-centre does not feel a fake thrust
//!   change when the craft turns.
//!
//! The step never allocates and never produces a non-finite command: non-finite inputs are
//! refused ([`IndiError`]) with nothing changed, and a failed allocation holds the last command
//! ([`IndiOutput::allocation`] says so; the caller counts and disarms if it persists).

// Index loops over motors and rows mirror the matrix algebra they implement (several arrays
// indexed together), and `!(x > 0)` is deliberate: it also rejects NaN.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

use nalgebra::{UnitQuaternion, Vector3};

use crate::allocation::{AllocationConfig, AllocationError, AllocationStatus, Allocator};
use crate::filters::{BiquadCoefficients, Butterworth2, Butterworth2x3, FilterDesignError};
use crate::learner::motor_model::MotorModel;
use crate::learner::{LearnedModel, MAX_MOTORS, MIN_MOTORS};
use crate::math::clamp;

/// Cut-off of the synchronising low-pass on Ω, f and u₀, Hz (published; docs/algorithms/indi.md).
pub const SYNC_CUTOFF_HZ: f32 = 15.0;

/// Natural frequency of INDI's own closed loop, rad/s: the response of the angular acceleration
/// to its demand through motors of lag `tau_s` synchronised by the 2nd-order Butterworth at
/// `cutoff_hz` (`H`) is `1/(1 + sτ(1 − H))`, whose denominator `τs³ + (1 + √2ωτ)s² + √2ωs + ω²`
/// (`ω = 2π f_c`) has one real pole and a lightly damped pair (damping 0.27 at τ = 16 ms and
/// 15 Hz, 58 rad/s; 0.14 at 50 ms, 35 rad/s): the pair's frequency. `None` for inputs that are
/// not positive numbers.
pub fn inner_mode_rad_s(tau_s: f32, cutoff_hz: f32) -> Option<f32> {
    if !(tau_s > 0.0 && tau_s.is_finite() && cutoff_hz > 0.0 && cutoff_hz.is_finite()) {
        return None;
    }
    let w = 2.0 * core::f32::consts::PI * cutoff_hz;
    let s2w = core::f32::consts::SQRT_2 * w;
    // Monic: s³ + a s² + b s + c.
    let (a, b, c) = ((1.0 + s2w * tau_s) / tau_s, s2w / tau_s, w * w / tau_s);
    // The real root: Newton's steps from −a (left of the root; the cubic is concave there,
    // left of its inflection −a/3, so they approach it from the left).
    let mut r = -a;
    for _ in 0..30 {
        let f = ((r + a) * r + b) * r + c;
        let df = (3.0 * r + 2.0 * a) * r + b;
        if !(df.abs() > 0.0) {
            break;
        }
        r -= f / df;
    }
    // (s − r)(s² + p s + q): q = −c / r.
    let q = -c / r;
    (q > 0.0 && q.is_finite()).then(|| crate::math::sqrt(q))
}

/// Floor of the motor speed in the G2 term, fraction of ω_full: `ω_full²/(2τω₀)` grows without
/// bound as ω₀ → 0. The published floor is 0.1; ours is 0.3 (measured): with 0.1, a craft whose
/// motors sit near idle after a tumble sees a rotor-reaction yaw gain five times its hover value,
/// the allocation spends the motors on that yaw and flickers them between 0 and 1, and the spin
/// grows (Monte Carlo case 37 of `fly`). On 300 Monte Carlo throws: floor 0.1, 7 hit the ground
/// and 264 held; 0.3, 4 and 273; 0.5, 5 and 270.
pub const OMEGA_FLOOR_FRACTION: f32 = 0.3;

/// Largest usable motor time constant, s: a motor slower than this is not a propeller motor
/// (the excitation clamps τ to 55 ms; 0.2 s is the gains' clamp, docs/algorithms/indi.md).
pub const MAX_TAU_S: f32 = 0.2;

/// Smallest usable motor time constant, s (the gain schedule's clamp, docs/algorithms/indi.md).
pub const MIN_TAU_S: f32 = 0.01;

/// The learned actuators as INDI uses them: thrust-frame effectiveness per unit thrust and the
/// motor models.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IndiModel {
    /// Motors.
    pub motors: usize,
    /// G1 per unit thrust `u = ω²/ω_full²`, thrust-frame rows: specific force (m/s²), then
    /// angular acceleration (rad/s²).
    pub g1: [[f32; MAX_MOTORS]; 6],
    /// G2 in the thrust frame: angular acceleration per motor acceleration, rad/s² per rad/s².
    pub g2: [[f32; MAX_MOTORS]; 3],
    /// The motor models (thrust curve and τ).
    pub motor: [MotorModel; MAX_MOTORS],
    /// `q_U^T`: thrust-frame coordinates into IMU coordinates.
    pub q_imu_thrust: UnitQuaternion<f32>,
    /// Smallest thrust of each motor while armed (its idle speed), normalised thrust.
    pub u_idle: [f32; MAX_MOTORS],
    /// Hover thrust of each motor, normalised thrust (the thrust-axis solution).
    pub u_hover: [f32; MAX_MOTORS],
}

/// Why a learned model cannot be flown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelError {
    /// The motor count is outside 4..=8.
    MotorCount { motors: usize },
    /// No hover thrust axis was found.
    NoThrustAxis,
    /// Motor `motor`'s model is not usable (no positive speed gain, τ outside the clamp, or
    /// non-finite).
    Motor { motor: u8 },
    /// The effectiveness contains a non-finite entry.
    NonFinite,
}

impl IndiModel {
    /// The flyable model from what the learner found. τ is clamped to
    /// [`MIN_TAU_S`]..=[`MAX_TAU_S`].
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn from_learned(learned: &LearnedModel) -> Result<Self, ModelError> {
        let motors = usize::from(learned.motors);
        if !(MIN_MOTORS..=MAX_MOTORS).contains(&motors) {
            return Err(ModelError::MotorCount { motors });
        }
        let axis = learned.thrust_axis.ok_or(ModelError::NoThrustAxis)?;
        let q_imu_thrust = axis.rotation_thrust_to_imu().ok_or(ModelError::NonFinite)?;
        let g1_imu = learned.g1_per_unit_thrust();
        let mut model = Self {
            motors,
            g1: [[0.0; MAX_MOTORS]; 6],
            g2: [[0.0; MAX_MOTORS]; 3],
            motor: learned.motor,
            q_imu_thrust,
            u_idle: [0.0; MAX_MOTORS],
            u_hover: axis.u_hover,
        };
        let to_thrust = q_imu_thrust.inverse();
        for j in 0..motors {
            let m = &mut model.motor[j];
            let full = m.omega_full_rad_s();
            if !m.is_usable() || !full.is_finite() || full <= 0.0 || !m.tau_s.is_finite() {
                return Err(ModelError::Motor { motor: j as u8 });
            }
            m.tau_s = m.tau_s.clamp(MIN_TAU_S, MAX_TAU_S);
            let idle = m.omega_idle_rad_s.max(0.0) / full;
            model.u_idle[j] = (idle * idle).min(0.5);
            for (block, rows) in [(0, 0..3), (1, 3..6)] {
                let column = Vector3::new(
                    g1_imu[rows.start][j],
                    g1_imu[rows.start + 1][j],
                    g1_imu[rows.start + 2][j],
                );
                let rotated = to_thrust * column;
                for k in 0..3 {
                    model.g1[3 * block + k][j] = rotated[k];
                }
            }
            let column = Vector3::new(learned.g2[0][j], learned.g2[1][j], learned.g2[2][j]);
            let rotated = to_thrust * column;
            for k in 0..3 {
                model.g2[k][j] = rotated[k];
            }
        }
        let finite = model.g1.iter().chain(&model.g2).flatten().all(|v| v.is_finite())
            && model.u_hover.iter().all(|v| v.is_finite());
        if !finite {
            return Err(ModelError::NonFinite);
        }
        Ok(model)
    }

    /// Move G1 and G2 a fraction `gain` (0..=1) of the way towards what `learned` says now, in
    /// this model's thrust frame and per unit of this model's thrust (its motor models, thrust
    /// frame, idle and hover thrusts stay): the in-flight refinement. Returns `false` and
    /// changes nothing when `learned` is for another motor count or has a non-finite entry.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn refine_effectiveness(&mut self, learned: &LearnedModel, gain: f32) -> bool {
        let motors = self.motors;
        if usize::from(learned.motors) != motors || !(0.0..=1.0).contains(&gain) {
            return false;
        }
        let to_thrust = self.q_imu_thrust.inverse();
        let mut g1 = self.g1;
        let mut g2 = self.g2;
        for j in 0..motors {
            let full = self.motor[j].omega_full_rad_s();
            let column = |rows: [[f32; MAX_MOTORS]; 3], scale: f32| {
                to_thrust * Vector3::new(rows[0][j], rows[1][j], rows[2][j]) * scale
            };
            let g = &learned.g1_per_speed2;
            let force = column([g[0], g[1], g[2]], full * full);
            let torque = column([g[3], g[4], g[5]], full * full);
            let reaction = column(learned.g2, 1.0);
            for k in 0..3 {
                g1[k][j] += gain * (force[k] - g1[k][j]);
                g1[3 + k][j] += gain * (torque[k] - g1[3 + k][j]);
                g2[k][j] += gain * (reaction[k] - g2[k][j]);
            }
        }
        if !g1.iter().chain(&g2).flatten().all(|v| v.is_finite()) {
            return false;
        }
        self.g1 = g1;
        self.g2 = g2;
        true
    }

    /// The motor command δ ∈ [0, 1] that holds motor `j` at normalised thrust `u`: the inverse
    /// of the steady thrust curve `ω = a δ + b √δ + ω_idle` at `ω = ω_full √u`.
    pub fn command_for_thrust(&self, j: usize, u: f32) -> f32 {
        let m = &self.motor[j];
        let omega = m.omega_full_rad_s() * crate::math::sqrt(u.clamp(0.0, 1.0));
        command_for_speed(m, omega)
    }
}

/// The command δ ∈ [0, 1] at which the steady speed of `m` is `omega_rad_s`: the positive root
/// `s = √δ` of `a s² + b s − (ω − ω_idle) = 0`.
pub fn command_for_speed(m: &MotorModel, omega_rad_s: f32) -> f32 {
    let excess = omega_rad_s - m.omega_idle_rad_s;
    if !(excess > 0.0) {
        return 0.0;
    }
    let (a, b) = (m.a_rad_s, m.b_rad_s);
    let s = if a.abs() < 1e-3 * (a.abs() + b.abs()) {
        // Practically pure square-root curve.
        excess / b
    } else {
        let discriminant = b * b + 4.0 * a * excess;
        if discriminant <= 0.0 {
            // Beyond the curve's reach (a < 0 bends it back): full command.
            return 1.0;
        }
        // The numerically stable form of (−b + √disc)/(2a).
        2.0 * excess / (b + crate::math::sqrt(discriminant))
    };
    let delta = s * s;
    if delta.is_finite() {
        delta.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// How the INDI loop is set up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndiConfig {
    /// Step rate, Hz.
    pub rate_hz: f32,
    /// The synchronising low-pass cut-off, Hz.
    pub sync_cutoff_hz: f32,
    /// The allocation's weights and iteration budget.
    pub allocation: AllocationConfig,
}

impl Default for IndiConfig {
    fn default() -> Self {
        Self {
            rate_hz: 2000.0,
            sync_cutoff_hz: SYNC_CUTOFF_HZ,
            allocation: AllocationConfig::default(),
        }
    }
}

/// Why an INDI loop could not be built or a step was refused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum IndiError {
    Filter(FilterDesignError),
    Model(ModelError),
    Allocation(AllocationError),
    /// An input was not finite; nothing changed.
    NonFiniteInput,
}

/// What one INDI step asks of the motors.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IndiOutput {
    /// Motor commands δ ∈ [0, 1].
    pub commands: [f32; MAX_MOTORS],
    /// Commanded normalised thrust per motor.
    pub u: [f32; MAX_MOTORS],
    /// How the allocation ended.
    pub allocation: AllocationStatus,
    /// Motors at a bound of their thrust range after the allocation (bit i: motor i).
    pub saturated: u8,
}

/// One step's wish: thrust-frame specific-force z and angular acceleration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndiReference {
    /// Wanted specific force along the thrust frame's z, m/s² (hover: −g; negative is upward
    /// thrust).
    pub specific_force_z_mps2: f32,
    /// Wanted angular acceleration, thrust frame, rad/s².
    pub angular_accel_rad_s2: Vector3<f32>,
}

/// The filtered state INDI increments from (thrust frame), for telemetry and the outer loops.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IndiState {
    /// Filtered body rate, rad/s.
    pub rate_rad_s: Vector3<f32>,
    /// Its derivative, rad/s².
    pub angular_accel_rad_s2: Vector3<f32>,
    /// Filtered specific force at the CoG, m/s².
    pub specific_force_mps2: Vector3<f32>,
}

/// The allocation's input of one step ([`Indi::update`]), kept from step to step so that it is
/// never cleared: each step writes the first m entries of every array (the first m columns of
/// `g`), the only ones the allocation reads; beyond them the zeros of construction stay. As
/// locals, cleared and then filled, these 320 B cost 89 instructions of `__aeabi_memclr4` a
/// step (bench-m7, 2026-12-04).
#[derive(Clone, Copy, Default)]
struct StepInput {
    /// The actuators' filtered state, normalised thrust.
    u0: [f32; MAX_MOTORS],
    /// G1, with the rotor reaction on the yaw row (module doc, "The G2 term").
    g: [[f32; MAX_MOTORS]; 6],
    du_min: [f32; MAX_MOTORS],
    du_max: [f32; MAX_MOTORS],
    du_pref: [f32; MAX_MOTORS],
}

impl core::fmt::Debug for StepInput {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        // Rewritten before it is read on every step: not the loop's state.
        f.write_str("StepInput")
    }
}

/// The INDI inner loop.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct Indi {
    model: IndiModel,
    rate_hz: f32,
    /// IMU position relative to the CoG, thrust frame, m.
    r_thrust_m: Vector3<f32>,
    allocator: Allocator,
    rate_filter: Butterworth2x3,
    force_filter: Butterworth2x3,
    /// The actuator model's speed per motor, rad/s (unfiltered).
    omega_model_rad_s: [f32; MAX_MOTORS],
    /// One synchronising filter per motor on the model speed.
    omega_filter: [Butterworth2; MAX_MOTORS],
    /// Previous filtered rate and motor speeds (for the differences).
    previous_rate: Vector3<f32>,
    previous_omega: [f32; MAX_MOTORS],
    /// Per-step actuator-model gains `1 − exp(−dt/τ)`.
    lag_gain: [f32; MAX_MOTORS],
    state: IndiState,
    last: IndiOutput,
    /// Not state: rewritten where it is read on every step, neither saved nor restored.
    #[serde(skip)]
    input: StepInput,
}

impl Indi {
    /// An INDI loop for `model`, with the IMU at `r_imu_m` from the CoG (IMU axes, m), starting
    /// from the motors at `commands` (δ) and the body at rest in the synchronising filters
    /// until [`Indi::start`] primes them.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn new(model: IndiModel, r_imu_m: [f32; 3], config: IndiConfig) -> Result<Self, IndiError> {
        let c = BiquadCoefficients::butterworth_lowpass(config.sync_cutoff_hz, config.rate_hz)
            .map_err(IndiError::Filter)?;
        let allocator =
            Allocator::new(model.motors, config.allocation).map_err(IndiError::Allocation)?;
        let r = Vector3::from(r_imu_m);
        if !r.iter().all(|x| x.is_finite()) {
            return Err(IndiError::NonFiniteInput);
        }
        let dt = 1.0 / config.rate_hz;
        let mut lag_gain = [0.0; MAX_MOTORS];
        for (gain, m) in lag_gain.iter_mut().zip(&model.motor).take(model.motors) {
            *gain = 1.0 - libm::expf(-dt / m.tau_s);
        }
        Ok(Self {
            r_thrust_m: model.q_imu_thrust.inverse() * r,
            model,
            rate_hz: config.rate_hz,
            allocator,
            rate_filter: Butterworth2x3::from_coefficients(c),
            force_filter: Butterworth2x3::from_coefficients(c),
            omega_model_rad_s: [0.0; MAX_MOTORS],
            omega_filter: [Butterworth2::from_coefficients(c); MAX_MOTORS],
            previous_rate: Vector3::zeros(),
            previous_omega: [0.0; MAX_MOTORS],
            lag_gain,
            state: IndiState::default(),
            last: IndiOutput {
                commands: [0.0; MAX_MOTORS],
                u: [0.0; MAX_MOTORS],
                allocation: AllocationStatus::Optimal,
                saturated: 0,
            },
            input: StepInput::default(),
        })
    }

    /// Prime the filters for a handover: the body at `gyro_rad_s` and `accel_mps2` (IMU axes),
    /// the motors running at the speeds their last commands `commands` (δ) settle to, or at
    /// `speeds_rad_s` where those are known (finite). The first step then increments from there
    /// without a start-up transient.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn start(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        commands: &[f32; MAX_MOTORS],
        speeds_rad_s: &[f32; MAX_MOTORS],
    ) {
        let to_thrust = self.model.q_imu_thrust.inverse();
        let rate = to_thrust * Vector3::from(gyro_rad_s);
        let force =
            to_thrust * Vector3::from(accel_mps2) - rate.cross(&rate.cross(&self.r_thrust_m));
        let (rate, force) = if rate.iter().chain(force.iter()).all(|x| x.is_finite()) {
            (rate, force)
        } else {
            (Vector3::zeros(), Vector3::zeros())
        };
        self.rate_filter.reset_to(&rate);
        self.force_filter.reset_to(&force);
        self.previous_rate = rate;
        for j in 0..self.model.motors {
            let m = &self.model.motor[j];
            let steady = m.steady_speed_rad_s(commands[j]);
            let omega = if speeds_rad_s[j].is_finite() && speeds_rad_s[j] >= 0.0 {
                speeds_rad_s[j]
            } else {
                steady
            };
            self.omega_model_rad_s[j] = omega;
            self.omega_filter[j].reset_to(omega);
            self.previous_omega[j] = omega;
            let full = m.omega_full_rad_s();
            self.last.u[j] = (omega / full) * (omega / full);
            self.last.commands[j] = commands[j].clamp(0.0, 1.0);
        }
        self.state = IndiState {
            rate_rad_s: rate,
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_mps2: force,
        };
        self.allocator.reset();
    }

    /// Move the flown G1 and G2 a fraction `gain` towards `learned`
    /// ([`IndiModel::refine_effectiveness`]): the in-flight refinement. Returns whether it did.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn refine_effectiveness(&mut self, learned: &LearnedModel, gain: f32) -> bool {
        self.model.refine_effectiveness(learned, gain)
    }

    /// Compensate the accelerometer with the IMU at `r_imu_m` from the CoG (IMU axes, m) from
    /// the next step on: an offset determined in flight after the loop was formed. A
    /// non-finite offset is refused (`false`) and changes nothing.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn set_imu_offset(&mut self, r_imu_m: [f32; 3]) -> bool {
        let r = Vector3::from(r_imu_m);
        if !r.iter().all(|x| x.is_finite()) {
            return false;
        }
        self.r_thrust_m = self.model.q_imu_thrust.inverse() * r;
        true
    }

    /// The model flown.
    pub fn model(&self) -> &IndiModel {
        &self.model
    }

    /// The filtered state of the latest step.
    pub fn state(&self) -> &IndiState {
        &self.state
    }

    /// The latest output.
    pub fn last_output(&self) -> &IndiOutput {
        &self.last
    }

    /// One step: the raw IMU sample (IMU axes) and the wish; returns the motor commands (the
    /// [`Indi::last_output`], by reference: returned by value, the 68 B were copied by
    /// `__aeabi_memcpy4` here and twice more in the controller, ~92 instructions each, bench-m7).
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        reference: &IndiReference,
    ) -> Result<&IndiOutput, IndiError> {
        let finite = gyro_rad_s.iter().chain(&accel_mps2).all(|x| x.is_finite())
            && reference.specific_force_z_mps2.is_finite()
            && reference.angular_accel_rad_s2.iter().all(|x| x.is_finite());
        if !finite {
            return Err(IndiError::NonFiniteInput);
        }
        let m = self.model.motors;
        let to_thrust = self.model.q_imu_thrust.inverse();

        // Measurements, filtered, in the thrust frame.
        let rate = self.rate_filter.update(&(to_thrust * Vector3::from(gyro_rad_s)));
        let force_imu = self.force_filter.update(&(to_thrust * Vector3::from(accel_mps2)));
        let angular_accel = (rate - self.previous_rate) * self.rate_hz;
        self.previous_rate = rate;
        let r = self.r_thrust_m;
        let force = force_imu - angular_accel.cross(&r) - rate.cross(&rate.cross(&r));
        self.state = IndiState {
            rate_rad_s: rate,
            angular_accel_rad_s2: angular_accel,
            specific_force_mps2: force,
        };

        // The actuators' filtered state.
        // The rotor reaction on the yaw row only (module doc, "The G2 term").
        let StepInput { u0, g, du_min, du_max, du_pref } = &mut self.input;
        let mut yaw_reaction_now = 0.0f32;
        for j in 0..m {
            let motor = &self.model.motor[j];
            let full = motor.omega_full_rad_s();
            let omega = self.omega_filter[j].update(self.omega_model_rad_s[j]);
            let omega_dot = (omega - self.previous_omega[j]) * self.rate_hz;
            self.previous_omega[j] = omega;
            u0[j] = (omega / full) * (omega / full);
            let omega_floor = omega.max(OMEGA_FLOOR_FRACTION * full);
            let reaction = full * full / (2.0 * motor.tau_s * omega_floor);
            for k in 0..6 {
                g[k][j] = self.model.g1[k][j];
            }
            g[5][j] += self.model.g2[2][j] * reaction;
            yaw_reaction_now += self.model.g2[2][j] * omega_dot;
        }

        // The increment wanted.
        let mut rot = reference.angular_accel_rad_s2 - angular_accel;
        rot.z += yaw_reaction_now;
        let dv = [0.0, 0.0, reference.specific_force_z_mps2 - force.z, rot.x, rot.y, rot.z];

        for j in 0..m {
            du_min[j] = (self.model.u_idle[j] - u0[j]).min(0.0);
            du_max[j] = (1.0 - u0[j]).max(0.0);
            du_pref[j] = clamp(self.model.u_hover[j] - u0[j], du_min[j], du_max[j]);
        }
        let solution = self.allocator.solve(g, &dv, du_min, du_max, du_pref);

        // Updated in place: copying it in and out cost about 200 instructions (bench-m7).
        let out = &mut self.last;
        out.allocation = solution.status;
        if !matches!(solution.status, AllocationStatus::Failed(_)) {
            out.saturated = 0;
            for j in 0..m {
                let u = u0[j] + solution.du[j];
                let u = if u.is_finite() { clamp(u, self.model.u_idle[j], 1.0) } else { out.u[j] };
                out.u[j] = u;
                out.commands[j] = self.model.command_for_thrust(j, u);
                if solution.du[j] <= du_min[j] + 1e-6 || solution.du[j] >= du_max[j] - 1e-6 {
                    out.saturated |= 1 << j;
                }
            }
        }
        // The actuator model follows what was commanded.
        for j in 0..m {
            let target = self.model.motor[j].steady_speed_rad_s(out.commands[j]);
            self.omega_model_rad_s[j] += (target - self.omega_model_rad_s[j]) * self.lag_gain[j];
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::models::learned_quad;

    /// The inner mode is the complex pair of `τs³ + (1 + √2ωτ)s² + √2ωs + ω²`: found here
    /// independently, by Newton's method in the complex plane from a point near the imaginary
    /// axis, and compared by magnitude; the mode slows as the motors do; nonsense inputs give
    /// none.
    #[test]
    fn the_inner_mode_is_the_lightly_damped_pair_of_indis_own_loop() {
        for (tau_s, cutoff_hz) in [(0.0157f32, 15.0f32), (0.03, 15.0), (0.05, 15.0), (0.02, 30.0)] {
            let w = 2.0 * core::f64::consts::PI * f64::from(cutoff_hz);
            let t = f64::from(tau_s);
            let s2w = core::f64::consts::SQRT_2 * w;
            // z = (re, im); p(z) and p'(z) by Horner's rule in complex arithmetic.
            let mul = |a: (f64, f64), b: (f64, f64)| (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
            let coefficients = [t, 1.0 + s2w * t, s2w, w * w];
            let mut z = (-1.0, 0.5 * w);
            for _ in 0..200 {
                let (mut p, mut dp) = ((0.0, 0.0), (0.0, 0.0));
                for c in coefficients {
                    dp = (mul(dp, z).0 + p.0, mul(dp, z).1 + p.1);
                    p = (mul(p, z).0 + c, mul(p, z).1);
                }
                let d = dp.0 * dp.0 + dp.1 * dp.1;
                let step = ((p.0 * dp.0 + p.1 * dp.1) / d, (p.1 * dp.0 - p.0 * dp.1) / d);
                z = (z.0 - step.0, z.1 - step.1);
            }
            assert!(z.1.abs() > 1.0, "τ {tau_s}: converged to a real root {z:?}");
            let expected = (z.0 * z.0 + z.1 * z.1).sqrt();
            let mode = f64::from(inner_mode_rad_s(tau_s, cutoff_hz).unwrap());
            assert!(
                (mode - expected).abs() < 1e-3 * expected,
                "τ {tau_s}: {mode} against {expected}"
            );
            let damping = -z.0 / expected;
            assert!(damping > 0.0 && damping < 0.5, "τ {tau_s}: damping {damping}");
        }
        let fast = inner_mode_rad_s(0.0157, 15.0).unwrap();
        assert!((fast - 58.4).abs() < 1.0, "{fast} rad/s");
        assert!(inner_mode_rad_s(0.05, 15.0).unwrap() < fast);
        for (tau_s, cutoff_hz) in
            [(0.0, 15.0), (-0.01, 15.0), (f32::NAN, 15.0), (0.02, 0.0), (0.02, f32::INFINITY)]
        {
            assert_eq!(inner_mode_rad_s(tau_s, cutoff_hz), None, "τ {tau_s}, {cutoff_hz} Hz");
        }
    }

    /// The refinement moves G1 and G2 the given fraction towards the new estimate, in the frame
    /// and per unit of the thrust the model was built with; the motor models, the frame and
    /// the hover thrusts stay; a model for another motor count or with a non-finite entry, or
    /// a gain outside 0..=1, changes nothing.
    #[test]
    fn the_refinement_moves_the_effectiveness_a_fraction_of_the_way_and_nothing_else() {
        let learned = learned_quad();
        let mut model = IndiModel::from_learned(&learned).unwrap();
        let before = model;
        // The craft turns out 10 % stronger in roll (IMU x) and its thrust frame is re-solved.
        let mut newer = learned;
        for j in 0..4 {
            newer.g1_per_speed2[3][j] *= 1.1;
        }
        if let Some(axis) = &mut newer.thrust_axis {
            axis.q_thrust_to_imu = [1.0, 0.0, 0.0, 0.0];
        }
        assert!(model.refine_effectiveness(&newer, 0.25));
        let full2 = 2000.0f32 * 2000.0;
        for j in 0..4 {
            // IMU x is thrust-frame x (a roll about x keeps x).
            let target = newer.g1_per_speed2[3][j] * full2;
            let expected = before.g1[3][j] + 0.25 * (target - before.g1[3][j]);
            assert!((model.g1[3][j] - expected).abs() < 1e-4 * target.abs(), "motor {j}");
            // A quarter of the 10 % step: 2.5 % of the old value.
            assert!((model.g1[3][j] / before.g1[3][j] - 1.025).abs() < 1e-5);
            for k in [0, 1, 2, 4, 5] {
                // Within rounding of the rotation (entries up to 200 rad/s²).
                assert!((model.g1[k][j] - before.g1[k][j]).abs() < 1e-3, "row {k} moved");
            }
        }
        let g2_moved = model.g2.iter().flatten().zip(before.g2.iter().flatten());
        assert!(g2_moved.map(|(a, b)| (a - b).abs()).fold(0.0, f32::max) < 1e-7, "G2 stays");
        assert_eq!(model.q_imu_thrust, before.q_imu_thrust);
        assert_eq!(model.motor, before.motor);
        assert_eq!(model.u_hover, before.u_hover);
        let refined = model;
        let mut other = newer;
        other.motors = 6;
        assert!(!model.refine_effectiveness(&other, 0.25));
        let mut broken = newer;
        broken.g2[0][1] = f32::NAN;
        assert!(!model.refine_effectiveness(&broken, 0.25));
        assert!(!model.refine_effectiveness(&newer, 1.5));
        assert!(!model.refine_effectiveness(&newer, f32::NAN));
        assert_eq!(model, refined, "refused refinements change nothing");
    }

    /// Rotors tilted so that each one's reaction about the roll axis, at idle, is twice its
    /// thrust's roll lever and of the other sign (as in `fly` case 962): a roll demand is still
    /// met by the motors whose *thrust* rolls the craft the right way, because a reaction lasts
    /// only while a motor accelerates and cannot hold a tilt torque.
    #[test]
    fn a_tilt_demand_is_met_by_thrust_not_by_a_rotor_reaction_that_cannot_last() {
        let mut learned = learned_quad();
        for j in 0..4 {
            let roll_sign = if j & 1 == 0 { 1.0 } else { -1.0 };
            // Reaction at idle: ω_full²/(2 τ ω_floor) = 4e6/(2 · 0.03 · 600) ≈ 1.1e5 per unit
            // thrust, × 4e-3 = 444 rad/s² against the thrust's 200.
            learned.g2[0][j] = -4e-3 * roll_sign;
        }
        let model = IndiModel::from_learned(&learned).unwrap();
        let mut indi = Indi::new(model, [0.0; 3], IndiConfig::default()).unwrap();
        let idle = [200.0f32; MAX_MOTORS];
        // Falling freely, motors at idle.
        indi.start([0.0; 3], [0.0; 3], &[0.0; MAX_MOTORS], &idle);
        let reference = IndiReference {
            specific_force_z_mps2: -3.0,
            angular_accel_rad_s2: Vector3::new(100.0, 0.0, 0.0),
        };
        let out = indi.update([0.0; 3], [0.0; 3], &reference).unwrap();
        let roll_from_thrust: f32 = (0..4).map(|j| model.g1[3][j] * out.u[j]).sum();
        assert!(roll_from_thrust > 20.0, "roll from thrust {roll_from_thrust} rad/s²: {out:?}");
        assert!(out.u[0] > out.u[1] && out.u[2] > out.u[3], "the right-rolling motors: {out:?}");
    }
}
