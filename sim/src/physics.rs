//! The physical world of one vehicle: its dynamics, its motors' targets and the hand, advanced
//! in fixed steps.
//!
//! [`Physics`] owns the [`State`], the constant [`VehicleModel`], the [`Hand`] and the rotor
//! speed targets the motor commands set (the commands are held constant between control ticks,
//! as a DShot output is). After each step it keeps the derivative at the new state, which is
//! what the IMU samples (Ω̇ and the specific force at that instant), and the rotor angles for
//! vibration.

use nalgebra::{UnitQuaternion, Vector3};

use crate::airframe::{Airframe, MAX_ROTORS};
use crate::dynamics::{Derivative, State, VehicleModel};
use crate::hand::{CatchSpec, Hand, ThrowSpec};

/// One vehicle in the world, stepped at a fixed rate.
#[derive(Clone, Debug)]
pub struct Physics {
    model: VehicleModel,
    state: State,
    hand: Hand,
    step_s: f64,
    steps: u64,
    target_rad_s: [f64; MAX_ROTORS],
    derivative: Derivative,
    rotor_angle_rad: [f64; MAX_ROTORS],
    /// The airframe's model while a fault scales rotors ([`Physics::set_rotor_thrust_factors`]).
    nominal_model: Option<VehicleModel>,
}

impl Physics {
    /// A vehicle held by the hand at `position_ned_m` with attitude `q_world_body`, rotors
    /// stopped, stepping at `rate_hz`.
    pub fn new(
        airframe: &Airframe,
        position_ned_m: Vector3<f64>,
        q_world_body: UnitQuaternion<f64>,
        rate_hz: f64,
    ) -> Self {
        let model = VehicleModel::new(airframe);
        let state = State::at_rest(position_ned_m, q_world_body);
        let hand = Hand::holding();
        let target_rad_s = [0.0; MAX_ROTORS];
        let derivative = model.derivative(&state, &target_rad_s, hand.constraint());
        Self {
            model,
            state,
            hand,
            step_s: 1.0 / rate_hz,
            steps: 0,
            target_rad_s,
            derivative,
            rotor_angle_rad: [0.0; MAX_ROTORS],
            nominal_model: None,
        }
    }

    /// Replaces the state (e.g. to start a free tumble), keeping time and hand.
    pub fn set_state(&mut self, state: State) {
        self.state = state;
        self.refresh_derivative();
    }

    /// Sets the rotor speed targets, rad/s (the steady-state speeds of the current commands).
    pub fn set_rotor_targets(&mut self, target_rad_s: &[f64; MAX_ROTORS]) {
        if *target_rad_s != self.target_rad_s {
            self.target_rad_s = *target_rad_s;
            self.refresh_derivative();
        }
    }

    /// One RK4 step, then the hand's phase logic.
    pub fn step(&mut self) {
        let constraint = *self.hand.constraint();
        self.state = self.model.rk4_step(
            &self.state,
            &self.derivative,
            self.step_s,
            &self.target_rad_s,
            &constraint,
        );
        self.steps += 1;
        let now = self.time_s();
        self.hand.update(now, self.step_s, &mut self.state);
        self.refresh_derivative();
        let m = self.model.rotor_count();
        for (angle, w) in
            self.rotor_angle_rad.iter_mut().zip(self.state.rotor_speed_rad_s.iter()).take(m)
        {
            // One step turns a rotor far less than a revolution: a subtraction wraps it.
            *angle += w * self.step_s;
            while *angle >= std::f64::consts::TAU {
                *angle -= std::f64::consts::TAU;
            }
        }
    }

    /// Sets the air's velocity, world NED, m/s (zero: still air).
    pub fn set_wind(&mut self, wind_ned_mps: Vector3<f64>) {
        self.model.wind_ned_mps = wind_ned_mps;
        if let Some(nominal) = self.nominal_model.as_mut() {
            nominal.wind_ned_mps = wind_ned_mps;
        }
        self.refresh_derivative();
    }

    /// Scales each rotor's thrust and drag-torque coefficients by `factors`, relative to the
    /// airframe's (fault injection, [`crate::faults`]); all ones restores them.
    pub fn set_rotor_thrust_factors(&mut self, factors: &[f64; MAX_ROTORS]) {
        let nominal = self.nominal_model.get_or_insert_with(|| self.model.clone());
        self.model = nominal.with_thrust_factors(factors);
        self.refresh_derivative();
    }

    fn refresh_derivative(&mut self) {
        self.derivative =
            self.model.derivative(&self.state, &self.target_rad_s, self.hand.constraint());
    }

    /// Starts a throw now.
    pub fn throw(&mut self, spec: &ThrowSpec) {
        let now = self.time_s();
        self.hand.throw(spec, &self.state, now, self.step_s);
        self.refresh_derivative();
    }

    /// Starts a throw now and arms the hand to catch the vehicle when it comes back down to the
    /// height at which it will be released (the hand accelerates it uniformly over
    /// `spec.duration_s`, so release is half the release speed × duration above the start).
    pub fn throw_and_catch_at_release_height(&mut self, spec: &ThrowSpec, catch_tau_s: f64) {
        let rise_m = 0.5 * spec.release_velocity_ned_mps.z.abs() * spec.duration_s;
        let catch_ned_z_m = self.state.position_ned_m.z - rise_m;
        self.set_catch(Some(CatchSpec { catch_ned_z_m, tau_s: catch_tau_s }));
        self.throw(spec);
    }

    /// Lets go of the vehicle now.
    pub fn release(&mut self) {
        let now = self.time_s();
        self.hand.release(now);
        self.refresh_derivative();
    }

    /// Moves the vehicle with the hand: from now on, until the next call, grip, throw or
    /// release, the CoG accelerates at `accel_ned_mps2` (world NED) and the body turns with
    /// `rate_dot_body_rad_s2` (a shake, a swing). The hand keeps holding.
    pub fn move_with_hand(
        &mut self,
        accel_ned_mps2: Vector3<f64>,
        rate_dot_body_rad_s2: Vector3<f64>,
    ) {
        self.hand.move_with(accel_ned_mps2, rate_dot_body_rad_s2);
        self.refresh_derivative();
    }

    /// A hand grabs the flying vehicle now ([`crate::hand::GrabSpec`]) and holds it.
    pub fn grab(&mut self, spec: &crate::hand::GrabSpec) {
        let now = self.time_s();
        self.hand.grab(spec, &self.state, now);
        self.refresh_derivative();
    }

    /// Grips the vehicle where it is.
    pub fn grip(&mut self) {
        self.hand.grip(&mut self.state);
        self.refresh_derivative();
    }

    /// Arms catching after the next release (`None`: let it fall).
    pub fn set_catch(&mut self, catch: Option<CatchSpec>) {
        self.hand.set_catch(catch);
    }

    /// Simulated time, s (a whole number of steps).
    pub fn time_s(&self) -> f64 {
        self.steps as f64 * self.step_s
    }

    /// Step length, s.
    pub fn step_s(&self) -> f64 {
        self.step_s
    }

    /// The state now.
    pub fn state(&self) -> &State {
        &self.state
    }

    /// The derivative at the state now (Ω̇, specific force, rotor accelerations).
    pub fn derivative(&self) -> &Derivative {
        &self.derivative
    }

    /// The constant vehicle model.
    pub fn model(&self) -> &VehicleModel {
        &self.model
    }

    /// The hand.
    pub fn hand(&self) -> &Hand {
        &self.hand
    }

    /// Rotor angles about their axes, rad, in [0, 2π).
    pub fn rotor_angle_rad(&self) -> &[f64; MAX_ROTORS] {
        &self.rotor_angle_rad
    }
}
