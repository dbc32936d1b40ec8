//! Rigid-body 6-DoF dynamics of a multirotor with its motors, integrated by fixed-step RK4.
//!
//! State: NED position and velocity of the CoG, attitude `q_world_body` (Hamilton, body FRD to
//! world NED), body rate Ω, and every rotor's speed ω_i (the motors' first-order dynamics are
//! part of the state so RK4 integrates them with the body). Forces and torques:
//! - rotors: thrust `k_f ω²` along each thrust axis `n_i` at position `r_i`, drag torque
//!   `−s_i k_m ω² n_i` (s_i = +1 when the rotor spins about +n_i), rotor angular momentum
//!   `h = Σ J_r s_i ω_i n_i` with its gyroscopic term `−Ω × h` and the reaction to motor
//!   acceleration `−Σ J_r s_i ω̇_i n_i` (the G2 effect);
//! - Euler's equation with the full inertia tensor: `I Ω̇ = τ − Ω × (I Ω + h) − ḣ`;
//! - gravity, linear and quadratic aerodynamic drag on the body-axis airspeed, rotational damping;
//! - ground contact through a landing gear: one foot under each arm ([`VehicleModel::gear_feet_m`],
//!   [`GEAR_LEG_M`] below the lowest rotor along the rotors' mean thrust axis), each a penalty
//!   spring-damper on the ground (NED z = 0) with viscous friction on its sliding. The feet give
//!   the righting torques a real gear gives (a craft resting on a point under its centre of
//!   gravity turned freely under its controller's torques and never came to rest) and the
//!   friction that holds a craft's yaw on the ground — good enough to land, rest and tip, not to
//!   study a gear's dynamics;
//! - an external [`Constraint`], which overrides the accelerations while something holds, throws
//!   or catches the vehicle (the simulated hand, `crate::hand`, chooses it; the dynamics do not
//!   depend on the hand).
//!
//! Why RK4 at a fixed step: the rotor speeds have time constants of 20–50 ms and throws spin at
//! up to ~35 rad/s, so at 8 kHz RK4's error per step is far below the sensors' quantisation, the
//! step stays aligned with the IMU samples, and runs are exactly reproducible.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::airframe::{Airframe, MotorParams, MAX_ROTORS, STANDARD_GRAVITY_MPS2};

/// Gravity in world NED, m/s².
pub fn gravity_ned_mps2() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2)
}

/// Natural frequency of the ground-contact spring, Hz. Stiff enough that a resting vehicle sinks
/// about 0.3 mm, soft enough for an 8 kHz step (period 40 steps).
pub const GROUND_NATURAL_FREQUENCY_HZ: f64 = 30.0;
/// Damping ratio of the ground-contact spring (dimensionless), well damped so landings stick.
pub const GROUND_DAMPING_RATIO: f64 = 0.9;
/// Time constant of the viscous friction that stops sliding and spinning on the ground, s.
pub const GROUND_FRICTION_TIME_CONSTANT_S: f64 = 0.05;

/// Length of the landing gear's legs below the lowest rotor, m: the skids or legs of a 5-inch
/// to 10-inch multirotor (3–10 cm), which keep the propellers off the ground.
pub const GEAR_LEG_M: f64 = 0.06;

/// How far out along each arm its foot stands, as a fraction of the rotor's distance from the
/// thrust axis: legs under the arms, inside the propellers.
pub const GEAR_SPAN_FRACTION: f64 = 0.7;

/// One rotor, precomputed for the inner loop.
#[derive(Clone, Debug)]
pub struct RotorModel {
    /// Hub position relative to the CoG, body, m.
    pub position_m: Vector3<f64>,
    /// Unit thrust axis, body.
    pub axis: Vector3<f64>,
    /// +1 when the rotor spins about +axis, −1 otherwise.
    pub spin_sign: f64,
    /// Motor parameters (curve, τ, coefficients).
    pub motor: MotorParams,
    /// `r × n`, body, m.
    r_cross_axis: Vector3<f64>,
    /// `1/τ`, 1/s.
    inv_tau_per_s: f64,
    /// `s k_m`, N·m/(rad/s)².
    signed_torque_coefficient: f64,
    /// `s J_r`, kg·m².
    signed_rotor_inertia: f64,
}

/// The vehicle's constant physical model, derived from a validated [`Airframe`].
#[derive(Clone, Debug)]
pub struct VehicleModel {
    /// Mass, kg.
    pub mass_kg: f64,
    /// Inertia tensor about the CoG, body, kg·m².
    pub inertia_kg_m2: Matrix3<f64>,
    inertia_inv: Matrix3<f64>,
    drag_linear: Vector3<f64>,
    drag_quadratic: Vector3<f64>,
    drag_angular: Vector3<f64>,
    /// The air's velocity, world NED, m/s (gusts, a steady wind, turbulence); drag acts on the
    /// airspeed.
    pub wind_ned_mps: Vector3<f64>,
    /// Rotors in motor order.
    pub rotors: Vec<RotorModel>,
    /// The landing gear's feet, body, m from the CoG (one under each arm).
    pub gear_feet_m: Vec<Vector3<f64>>,
}

impl VehicleModel {
    /// Builds the model of an airframe (which must have been validated).
    pub fn new(airframe: &Airframe) -> Self {
        let inertia = airframe.inertia_matrix();
        let rotors = (0..airframe.rotor_count())
            .map(|i| {
                let axis = airframe.thrust_axis(i);
                let position_m = Vector3::from(airframe.rotors[i].position_m);
                let motor = airframe.rotor_motor(i).clone();
                let spin_sign = airframe.rotors[i].spin.sign();
                RotorModel {
                    position_m,
                    axis,
                    spin_sign,
                    r_cross_axis: position_m.cross(&axis),
                    inv_tau_per_s: 1.0 / motor.tau_s,
                    signed_torque_coefficient: spin_sign * motor.torque_coefficient_nm_per_rad2_s2,
                    signed_rotor_inertia: spin_sign * motor.rotor_inertia_kg_m2,
                    motor,
                }
            })
            .collect::<Vec<RotorModel>>();
        let gear_feet_m = gear_feet(&rotors);
        Self {
            gear_feet_m,
            mass_kg: airframe.mass_kg,
            inertia_kg_m2: inertia,
            inertia_inv: inertia.try_inverse().expect("validated inertia is positive definite"),
            drag_linear: Vector3::from(airframe.drag.linear_n_per_mps),
            drag_quadratic: Vector3::from(airframe.drag.quadratic_n_per_mps2),
            drag_angular: Vector3::from(airframe.drag.angular_nm_per_rad_s),
            wind_ned_mps: Vector3::zeros(),
            rotors,
        }
    }

    /// Height of the lowest landing-gear foot above the ground for the vehicle in `state`, m
    /// (0 or less: on the ground).
    pub fn gear_height_m(&self, state: &State) -> f64 {
        let rot = state.attitude().to_rotation_matrix();
        self.gear_feet_m
            .iter()
            .map(|foot| -(state.position_ned_m + rot * foot).z)
            .fold(f64::INFINITY, f64::min)
    }

    /// The aerodynamic drag on the body in `state`, body axes, N: linear and quadratic in the
    /// body-axis airspeed (the craft's velocity less the air's, [`Self::wind_ned_mps`]); the
    /// force is its negative.
    fn drag_body_n(&self, rot: &nalgebra::Rotation3<f64>, state: &State) -> Vector3<f64> {
        let v_body = rot.transpose() * (state.velocity_ned_mps - self.wind_ned_mps);
        self.drag_linear.component_mul(&v_body)
            + self.drag_quadratic.component_mul(&v_body.map(|v| v.abs() * v))
    }

    /// The aerodynamic drag force on the vehicle in `state`, world NED, N (what
    /// [`Self::derivative`] applies: the airspeed is the velocity less the current wind).
    pub fn drag_force_ned_n(&self, state: &State) -> Vector3<f64> {
        let rot = state.attitude().to_rotation_matrix();
        -(rot * self.drag_body_n(&rot, state))
    }

    /// The direction the thrust must point in for the vehicle in `state` not to accelerate,
    /// world NED, unit: against gravity and the drag at its current airspeed (straight up, −z,
    /// in still air at rest; leaning into the wind when it holds in one).
    pub fn equilibrium_thrust_dir_ned(&self, state: &State) -> Vector3<f64> {
        let needed = -(gravity_ned_mps2() * self.mass_kg + self.drag_force_ned_n(state));
        needed.try_normalize(1e-12).unwrap_or_else(|| -Vector3::z())
    }

    /// Number of rotors.
    pub fn rotor_count(&self) -> usize {
        self.rotors.len()
    }

    /// This model with each rotor's thrust and drag-torque coefficients scaled by `factors`
    /// (fault injection, [`crate::faults`]: a damaged propeller pushes and drags less at the same
    /// speed).
    pub fn with_thrust_factors(&self, factors: &[f64; MAX_ROTORS]) -> Self {
        let mut model = self.clone();
        for (rotor, factor) in model.rotors.iter_mut().zip(factors) {
            rotor.motor.thrust_coefficient_n_per_rad2_s2 *= factor;
            rotor.motor.torque_coefficient_nm_per_rad2_s2 *= factor;
            rotor.signed_torque_coefficient *= factor;
        }
        model
    }
}

/// The landing gear of `rotors`: "down" is against the rotors' mean thrust axis; one foot under
/// each rotor, [`GEAR_SPAN_FRACTION`] of its distance out from that axis, [`GEAR_LEG_M`] below
/// the lowest rotor.
fn gear_feet(rotors: &[RotorModel]) -> Vec<Vector3<f64>> {
    let sum: Vector3<f64> = rotors.iter().map(|r| r.axis).sum();
    let down = -sum.try_normalize(1e-9).unwrap_or_else(|| -Vector3::z());
    let depth = rotors.iter().map(|r| r.position_m.dot(&down)).fold(0.0, f64::max) + GEAR_LEG_M;
    rotors
        .iter()
        .map(|r| {
            let across = r.position_m - down * r.position_m.dot(&down);
            across * GEAR_SPAN_FRACTION + down * depth
        })
        .collect()
}

/// Accelerations imposed on the rigid body from outside its dynamics: what a kinematic agent (the
/// simulated hand, `crate::hand`) prescribes while it holds, throws or catches the vehicle. The
/// dynamics own this type because they are what obeys it; the hand only chooses one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Constraint {
    /// No hand: the dynamics act alone.
    Free,
    /// Zero acceleration and angular acceleration (the state is at rest).
    Hold,
    /// Given CoG acceleration (world NED, m/s²) and angular acceleration (body, rad/s²).
    Prescribed {
        /// CoG acceleration, world NED, m/s².
        accel_ned_mps2: Vector3<f64>,
        /// Angular acceleration, body, rad/s².
        rate_dot_body_rad_s2: Vector3<f64>,
    },
    /// Velocity and body rate decay with this time constant, s.
    Damp {
        /// Time constant, s.
        tau_s: f64,
    },
    /// A hand closing on the vehicle and holding it where it wants it: the CoG goes to
    /// `position_ned_m` and the body to `q_world_body` as a critically damped motion of time
    /// constant `tau_s` (its velocity and rate decay within a few `tau_s`), then stays.
    Track {
        /// Time constant, s.
        tau_s: f64,
        /// Where the hand brings the CoG, world NED, m.
        position_ned_m: Vector3<f64>,
        /// The attitude it brings the body to.
        q_world_body: UnitQuaternion<f64>,
    },
}

impl Constraint {
    /// The accelerations `(CoG world NED, angular body)` given the free ones and the state.
    pub fn apply(
        &self,
        free_accel_ned: Vector3<f64>,
        free_rate_dot_body: Vector3<f64>,
        s: &State,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let (velocity_ned, rate_body) = (s.velocity_ned_mps, s.rate_body_rad_s);
        match *self {
            Constraint::Free => (free_accel_ned, free_rate_dot_body),
            Constraint::Hold => (Vector3::zeros(), Vector3::zeros()),
            Constraint::Prescribed { accel_ned_mps2, rate_dot_body_rad_s2 } => {
                (accel_ned_mps2, rate_dot_body_rad_s2)
            }
            Constraint::Damp { tau_s } => (-velocity_ned / tau_s, -rate_body / tau_s),
            Constraint::Track { tau_s, position_ned_m, q_world_body } => {
                let w = 1.0 / tau_s;
                let accel =
                    (position_ned_m - s.position_ned_m) * (w * w) - velocity_ned * (2.0 * w);
                let q = UnitQuaternion::new_normalize(s.q_world_body);
                let error_body = (q.inverse() * q_world_body).scaled_axis();
                (accel, error_body * (w * w) - rate_body * (2.0 * w))
            }
        }
    }
}

/// The integrated state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct State {
    /// CoG position, world NED, m (z = 0 is the ground; negative is above it).
    pub position_ned_m: Vector3<f64>,
    /// CoG velocity, world NED, m/s.
    pub velocity_ned_mps: Vector3<f64>,
    /// Attitude `q_world_body` (kept normalised between steps).
    pub q_world_body: Quaternion<f64>,
    /// Body rate Ω, body axes, rad/s.
    pub rate_body_rad_s: Vector3<f64>,
    /// Rotor speeds, rad/s (entries past the rotor count stay 0).
    pub rotor_speed_rad_s: [f64; MAX_ROTORS],
}

impl State {
    /// At rest at `position_ned_m` with attitude `q_world_body`, rotors stopped.
    pub fn at_rest(position_ned_m: Vector3<f64>, q_world_body: UnitQuaternion<f64>) -> Self {
        Self {
            position_ned_m,
            velocity_ned_mps: Vector3::zeros(),
            q_world_body: *q_world_body.quaternion(),
            rate_body_rad_s: Vector3::zeros(),
            rotor_speed_rad_s: [0.0; MAX_ROTORS],
        }
    }

    /// The attitude as a unit quaternion.
    pub fn attitude(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::from_quaternion(self.q_world_body)
    }

    fn advanced(&self, d: &Derivative, h: f64, m: usize) -> Self {
        let mut rotor = self.rotor_speed_rad_s;
        for (w, wd) in rotor.iter_mut().zip(d.rotor_accel_rad_s2.iter()).take(m) {
            *w += h * wd;
        }
        Self {
            position_ned_m: self.position_ned_m + d.velocity_ned_mps * h,
            velocity_ned_mps: self.velocity_ned_mps + d.accel_ned_mps2 * h,
            q_world_body: self.q_world_body + d.q_dot * h,
            rate_body_rad_s: self.rate_body_rad_s + d.rate_dot_body_rad_s2 * h,
            rotor_speed_rad_s: rotor,
        }
    }
}

/// Time derivative of [`State`], plus the specific force the accelerometer needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Derivative {
    /// Ṗ, m/s.
    pub velocity_ned_mps: Vector3<f64>,
    /// CoG acceleration, world NED, m/s² (gravity included).
    pub accel_ned_mps2: Vector3<f64>,
    /// q̇.
    pub q_dot: Quaternion<f64>,
    /// Ω̇, body, rad/s².
    pub rate_dot_body_rad_s2: Vector3<f64>,
    /// ω̇ of each rotor, rad/s².
    pub rotor_accel_rad_s2: [f64; MAX_ROTORS],
    /// Specific force at the CoG (acceleration minus gravity), body axes, m/s².
    pub specific_force_body_mps2: Vector3<f64>,
}

impl VehicleModel {
    /// Time derivative of `s` with rotor target speeds `target_rad_s` (from the commands) and the
    /// hand's `constraint`.
    pub fn derivative(
        &self,
        s: &State,
        target_rad_s: &[f64; MAX_ROTORS],
        constraint: &Constraint,
    ) -> Derivative {
        let q = UnitQuaternion::new_normalize(s.q_world_body);
        let rot = q.to_rotation_matrix();
        let omega = s.rate_body_rad_s;

        let mut force_body = Vector3::zeros();
        let mut torque_body = Vector3::zeros();
        let mut h_body = Vector3::zeros();
        let mut h_dot_body = Vector3::zeros();
        let mut rotor_accel = [0.0; MAX_ROTORS];
        for (i, r) in self.rotors.iter().enumerate() {
            let w = s.rotor_speed_rad_s[i];
            let w_dot = (target_rad_s[i] - w) * r.inv_tau_per_s;
            rotor_accel[i] = w_dot;
            let w2 = w * w;
            let thrust = r.motor.thrust_coefficient_n_per_rad2_s2 * w2;
            force_body += r.axis * thrust;
            torque_body += r.r_cross_axis * thrust - r.axis * (r.signed_torque_coefficient * w2);
            h_body += r.axis * (r.signed_rotor_inertia * w);
            h_dot_body += r.axis * (r.signed_rotor_inertia * w_dot);
        }

        force_body -= self.drag_body_n(&rot, s);
        torque_body -= self.drag_angular.component_mul(&omega);

        // The landing gear: each foot a spring-damper on the ground carrying its share of the
        // mass, with viscous friction on its sliding.
        let mut external_ned = Vector3::zeros();
        let share_kg = self.mass_kg / self.gear_feet_m.len().max(1) as f64;
        let wn = std::f64::consts::TAU * GROUND_NATURAL_FREQUENCY_HZ;
        for foot in &self.gear_feet_m {
            let position = s.position_ned_m + rot * foot;
            if position.z <= 0.0 {
                continue;
            }
            let velocity = s.velocity_ned_mps + rot * omega.cross(foot);
            // The ground pushes, never pulls.
            let normal = (share_kg
                * (wn * wn * position.z + 2.0 * GROUND_DAMPING_RATIO * wn * velocity.z))
                .max(0.0);
            let friction = share_kg / GROUND_FRICTION_TIME_CONSTANT_S;
            let force = Vector3::new(-friction * velocity.x, -friction * velocity.y, -normal);
            external_ned += force;
            torque_body += foot.cross(&(rot.transpose() * force));
        }

        let free_accel_ned = gravity_ned_mps2() + (rot * force_body + external_ned) / self.mass_kg;
        let free_rate_dot = self.inertia_inv
            * (torque_body - omega.cross(&(self.inertia_kg_m2 * omega + h_body)) - h_dot_body);
        let (accel_ned, rate_dot) = constraint.apply(free_accel_ned, free_rate_dot, s);
        let specific_force_body = rot.transpose() * (accel_ned - gravity_ned_mps2());
        Derivative {
            velocity_ned_mps: s.velocity_ned_mps,
            accel_ned_mps2: accel_ned,
            q_dot: s.q_world_body * Quaternion::from_imag(omega) * 0.5,
            rate_dot_body_rad_s2: rate_dot,
            rotor_accel_rad_s2: rotor_accel,
            specific_force_body_mps2: specific_force_body,
        }
    }

    /// One classical RK4 step of length `h_s`; `k1` is the derivative at `s` (callers usually
    /// have it already). Returns the state after the step, quaternion renormalised.
    pub fn rk4_step(
        &self,
        s: &State,
        k1: &Derivative,
        h_s: f64,
        target_rad_s: &[f64; MAX_ROTORS],
        constraint: &Constraint,
    ) -> State {
        let m = self.rotor_count();
        let k2 = self.derivative(&s.advanced(k1, 0.5 * h_s, m), target_rad_s, constraint);
        let k3 = self.derivative(&s.advanced(&k2, 0.5 * h_s, m), target_rad_s, constraint);
        let k4 = self.derivative(&s.advanced(&k3, h_s, m), target_rad_s, constraint);
        let w = h_s / 6.0;
        let mut rotor = s.rotor_speed_rad_s;
        for (i, x) in rotor.iter_mut().enumerate().take(m) {
            *x += w
                * (k1.rotor_accel_rad_s2[i]
                    + 2.0 * (k2.rotor_accel_rad_s2[i] + k3.rotor_accel_rad_s2[i])
                    + k4.rotor_accel_rad_s2[i]);
        }
        let q = s.q_world_body + (k1.q_dot + (k2.q_dot + k3.q_dot) * 2.0 + k4.q_dot) * w;
        State {
            position_ned_m: s.position_ned_m
                + (k1.velocity_ned_mps
                    + 2.0 * (k2.velocity_ned_mps + k3.velocity_ned_mps)
                    + k4.velocity_ned_mps)
                    * w,
            velocity_ned_mps: s.velocity_ned_mps
                + (k1.accel_ned_mps2
                    + 2.0 * (k2.accel_ned_mps2 + k3.accel_ned_mps2)
                    + k4.accel_ned_mps2)
                    * w,
            q_world_body: q.normalize(),
            rate_body_rad_s: s.rate_body_rad_s
                + (k1.rate_dot_body_rad_s2
                    + 2.0 * (k2.rate_dot_body_rad_s2 + k3.rate_dot_body_rad_s2)
                    + k4.rate_dot_body_rad_s2)
                    * w,
            rotor_speed_rad_s: rotor,
        }
    }

    /// Angular momentum of the body about the CoG in world axes (rotors included), kg·m²/s.
    pub fn angular_momentum_world(&self, s: &State) -> Vector3<f64> {
        let h_rotors: Vector3<f64> = self
            .rotors
            .iter()
            .enumerate()
            .map(|(i, r)| {
                r.axis * (r.motor.rotor_inertia_kg_m2 * r.spin_sign * s.rotor_speed_rad_s[i])
            })
            .sum();
        s.attitude() * (self.inertia_kg_m2 * s.rate_body_rad_s + h_rotors)
    }

    /// Rotational kinetic energy of the body, J.
    pub fn rotational_energy_j(&self, s: &State) -> f64 {
        0.5 * s.rate_body_rad_s.dot(&(self.inertia_kg_m2 * s.rate_body_rad_s))
    }
}
