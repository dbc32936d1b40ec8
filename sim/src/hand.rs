//! The hand that holds, throws and catches the vehicle.
//!
//! The hand is kinematic: while it acts, it *prescribes* the CoG acceleration and the body's
//! angular acceleration, whatever the motors and gravity do (it supplies the difference, as a
//! firm hand would). Because the prescription enters the dynamics' derivative, RK4 integrates
//! it like any other motion, and the accelerometer sees exactly the specific force of that
//! motion — so the firmware's throw detector sees a real throw (docs/algorithms/throw.md:
//! |a| > 20 m/s² with a momentum above 4 m/s).
//!
//! Phases:
//! - **Holding**: velocity and body rate are zero.
//! - **Throwing**: the hand pushes (its force per unit mass, which is the specific force at the
//!   centre of gravity, constant) and spins the body up (constant angular acceleration), then
//!   lets go over the push's last `taper_s`: push and spin-up fall to zero along a raised cosine,
//!   so the specific force passes continuously from the push to free fall, as a real hand's
//!   release does (0 to 50 ms; 0 is the published recipe's instant release). The push and the
//!   spin-up are scaled so that the craft leaves the hand with the release velocity and body
//!   rate. The duration is rounded to whole physics steps, not to control periods: a release can
//!   fall anywhere between two of the board's 2 kHz samples, whose average then straddles it.
//! - **Free**: the dynamics alone act.
//! - **Catching**: once the falling vehicle comes back down through the catch height, velocity
//!   and body rate decay exponentially with the catch time constant; after six time constants the
//!   hand holds again.

use nalgebra::Vector3;

use crate::airframe::STANDARD_GRAVITY_MPS2;
use crate::dynamics::{Constraint, State};

/// A throw: the velocity and body rate the vehicle has when the hand lets go.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThrowSpec {
    /// CoG velocity at release, world NED, m/s.
    pub release_velocity_ned_mps: Vector3<f64>,
    /// Body rate at release, body axes, rad/s.
    pub release_rate_body_rad_s: Vector3<f64>,
    /// How long the hand accelerates the vehicle, s (typically 0.1–0.3), taper included.
    pub duration_s: f64,
    /// How long the hand takes to let go at the end of the push, s (0–0.05): its push and spin-up
    /// fall to zero along a raised cosine over this time.
    pub taper_s: f64,
}

/// The push's strength at `t_s` into a throw of `duration_s` whose last `taper_s` taper off:
/// 1, then a raised cosine to 0 at the end; 0 outside the throw.
pub fn push_shape(t_s: f64, duration_s: f64, taper_s: f64) -> f64 {
    let taper_s = taper_s.clamp(0.0, duration_s);
    let into_taper_s = t_s - (duration_s - taper_s);
    if !(0.0..duration_s).contains(&t_s) {
        0.0
    } else if into_taper_s <= 0.0 {
        1.0
    } else {
        0.5 * (1.0 + (std::f64::consts::PI * into_taper_s / taper_s).cos())
    }
}

/// `∫ push_shape dt` over a throw: the time the push would take at full strength, s.
fn push_full_strength_s(duration_s: f64, taper_s: f64) -> f64 {
    duration_s - 0.5 * taper_s.clamp(0.0, duration_s)
}

impl ThrowSpec {
    /// A vertical throw that rises `apex_above_release_m` above the release point (in vacuum).
    pub fn vertical(
        apex_above_release_m: f64,
        rate_body_rad_s: Vector3<f64>,
        duration_s: f64,
    ) -> Self {
        let up_mps = (2.0 * STANDARD_GRAVITY_MPS2 * apex_above_release_m.max(0.0)).sqrt();
        Self {
            release_velocity_ned_mps: Vector3::new(0.0, 0.0, -up_mps),
            release_rate_body_rad_s: rate_body_rad_s,
            duration_s,
            taper_s: 0.0,
        }
    }

    /// The same throw with the hand letting go over `taper_s`.
    pub fn with_taper(self, taper_s: f64) -> Self {
        Self { taper_s, ..self }
    }
}

/// A push under way: the hand's full-strength push (its force per unit mass, world NED) and
/// spin-up (body), scaled by [`push_shape`] over the throw.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Push {
    start_s: f64,
    duration_s: f64,
    taper_s: f64,
    push_ned_mps2: Vector3<f64>,
    rate_dot_body_rad_s2: Vector3<f64>,
}

impl Push {
    /// The constraint over the physics step `[now_s, now_s + step_s]`: the push at the step's
    /// middle (RK4 holds a constraint for a whole step).
    fn constraint(&self, now_s: f64, step_s: f64) -> Constraint {
        let shape = push_shape(now_s + 0.5 * step_s - self.start_s, self.duration_s, self.taper_s);
        let gravity = Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2);
        Constraint::Prescribed {
            accel_ned_mps2: self.push_ned_mps2 * shape + gravity,
            rate_dot_body_rad_s2: self.rate_dot_body_rad_s2 * shape,
        }
    }
}

/// Where and how the hand catches a falling vehicle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CatchSpec {
    /// The hand closes when the descending CoG reaches this NED z, m (e.g. −1.2 for 1.2 m above
    /// the ground).
    pub catch_ned_z_m: f64,
    /// Time constant of the catch's deceleration, s.
    pub tau_s: f64,
}

/// How a hand grabs a hovering vehicle (`Hand::grab`): it closes with a time constant, and
/// moves the vehicle a little as it does, as people do: pulls it (down, towards themselves) and
/// tilts it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GrabSpec {
    /// Time constant of the hand's closing, s (a real hand: 0.05–0.3).
    pub tau_s: f64,
    /// How far the hand moves the CoG, world NED, m.
    pub pull_ned_m: Vector3<f64>,
    /// The tilt it gives the body: a rotation vector in the world (horizontal), rad.
    pub tilt_world_rad: Vector3<f64>,
}

impl Default for GrabSpec {
    /// A hand closing in 0.1 s, pulling the craft 5 cm down and tilting it 5° about north.
    fn default() -> Self {
        Self {
            tau_s: 0.1,
            pull_ned_m: Vector3::new(0.0, 0.0, 0.05),
            tilt_world_rad: Vector3::new(5f64.to_radians(), 0.0, 0.0),
        }
    }
}

/// What the hand is doing, for logs (`hand` column: the discriminant).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum HandPhase {
    /// Not touching the vehicle.
    Free = 0,
    /// Holding it still.
    Holding = 1,
    /// Accelerating it towards release.
    Throwing = 2,
    /// Stopping it after a catch.
    Catching = 3,
}

/// The hand's state machine (see the module doc).
#[derive(Clone, Debug)]
pub struct Hand {
    phase: HandPhase,
    constraint: Constraint,
    /// Throwing: release time; Catching: time the catch started. s.
    phase_time_s: f64,
    catch: Option<CatchSpec>,
    catch_tau_s: f64,
    released_at_s: Option<f64>,
    caught_at_s: Option<f64>,
    push: Option<Push>,
}

impl Hand {
    /// A hand holding the vehicle.
    pub fn holding() -> Self {
        Self {
            phase: HandPhase::Holding,
            constraint: Constraint::Hold,
            phase_time_s: 0.0,
            catch: None,
            catch_tau_s: 0.05,
            released_at_s: None,
            caught_at_s: None,
            push: None,
        }
    }

    /// No hand: the vehicle starts free.
    pub fn free() -> Self {
        Self { phase: HandPhase::Free, constraint: Constraint::Free, ..Self::holding() }
    }

    /// Current phase.
    pub fn phase(&self) -> HandPhase {
        self.phase
    }

    /// The accelerations the hand imposes now.
    pub fn constraint(&self) -> &Constraint {
        &self.constraint
    }

    /// When the last throw released the vehicle, s.
    pub fn released_at_s(&self) -> Option<f64> {
        self.released_at_s
    }

    /// When the last catch started, s.
    pub fn caught_at_s(&self) -> Option<f64> {
        self.caught_at_s
    }

    /// Arms (or disarms, with `None`) catching after the next release.
    pub fn set_catch(&mut self, catch: Option<CatchSpec>) {
        self.catch = catch;
    }

    /// Grips the vehicle where it is: velocity and body rate become zero.
    pub fn grip(&mut self, state: &mut State) {
        self.push = None;
        state.velocity_ned_mps = Vector3::zeros();
        state.rate_body_rad_s = Vector3::zeros();
        self.phase = HandPhase::Holding;
        self.constraint = Constraint::Hold;
    }

    /// Moves the vehicle while holding it (see `Physics::move_with_hand`).
    pub fn move_with(&mut self, accel_ned_mps2: Vector3<f64>, rate_dot_body_rad_s2: Vector3<f64>) {
        self.push = None;
        self.phase = HandPhase::Holding;
        self.constraint = Constraint::Prescribed { accel_ned_mps2, rate_dot_body_rad_s2 };
    }

    /// Grabs the (flying) vehicle at `now_s` as `spec` says and holds it there from then on.
    pub fn grab(&mut self, spec: &GrabSpec, state: &State, now_s: f64) {
        self.push = None;
        self.phase = HandPhase::Holding;
        let q = nalgebra::UnitQuaternion::new_normalize(state.q_world_body);
        self.constraint = Constraint::Track {
            tau_s: spec.tau_s.max(1e-3),
            position_ned_m: state.position_ned_m + spec.pull_ned_m,
            q_world_body: nalgebra::UnitQuaternion::from_scaled_axis(spec.tilt_world_rad) * q,
        };
        self.caught_at_s = Some(now_s);
    }

    /// Lets go immediately.
    pub fn release(&mut self, now_s: f64) {
        self.push = None;
        self.phase = HandPhase::Free;
        self.constraint = Constraint::Free;
        self.released_at_s = Some(now_s);
    }

    /// Starts a throw at `now_s` from the current velocity and rate. The duration is rounded to
    /// whole steps of `step_s` (at least one), the taper limited to it.
    pub fn throw(&mut self, spec: &ThrowSpec, state: &State, now_s: f64, step_s: f64) {
        let steps = (spec.duration_s / step_s).round().max(1.0);
        let duration_s = steps * step_s;
        let taper_s = spec.taper_s.clamp(0.0, duration_s);
        let full_s = push_full_strength_s(duration_s, taper_s);
        let gravity = Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2);
        // Δv = ∫ (push + g) dt = push · full_s + g · duration_s.
        let push = Push {
            start_s: now_s,
            duration_s,
            taper_s,
            push_ned_mps2: (spec.release_velocity_ned_mps
                - state.velocity_ned_mps
                - gravity * duration_s)
                / full_s,
            rate_dot_body_rad_s2: (spec.release_rate_body_rad_s - state.rate_body_rad_s) / full_s,
        };
        self.phase = HandPhase::Throwing;
        self.phase_time_s = now_s + duration_s;
        self.constraint = push.constraint(now_s, step_s);
        self.push = Some(push);
    }

    /// Advances the phase after a physics step ending at `now_s`; may change `state` (a grip
    /// zeroes the residual velocity). Returns `true` when the constraint changed.
    pub fn update(&mut self, now_s: f64, step_s: f64, state: &mut State) -> bool {
        let tolerance_s = 0.25 * step_s;
        match self.phase {
            HandPhase::Throwing if now_s + tolerance_s >= self.phase_time_s => {
                self.release(now_s);
                true
            }
            HandPhase::Throwing => match self.push {
                Some(push) => {
                    self.constraint = push.constraint(now_s, step_s);
                    true
                }
                None => false,
            },
            HandPhase::Free => match self.catch {
                Some(c)
                    if self.released_at_s.is_some()
                        && state.velocity_ned_mps.z > 0.0
                        && state.position_ned_m.z >= c.catch_ned_z_m =>
                {
                    self.phase = HandPhase::Catching;
                    self.phase_time_s = now_s;
                    self.catch_tau_s = c.tau_s;
                    self.constraint = Constraint::Damp { tau_s: c.tau_s };
                    self.caught_at_s = Some(now_s);
                    true
                }
                _ => false,
            },
            HandPhase::Catching if now_s - self.phase_time_s >= 6.0 * self.catch_tau_s => {
                self.grip(state);
                true
            }
            _ => false,
        }
    }
}
