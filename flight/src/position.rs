//! Gains from the motors' time constant and NDI position control (docs/algorithms/indi.md): the
//! specific force the attitude loop ([`crate::controller`]) is asked to produce.
//!
//! **Gains.** The slowest motor's time constant τ limits how fast anything can be controlled, so
//! every loop's gain follows from it. Each loop is a proportional gain closed around the loop
//! inside it, and the inner loop is treated as a first-order lag of time constant 1/k_inner
//! (the motors: τ). A gain `k` around a lag `T` closes to `T s² + s + k`, of damping
//! `ζ = 1/√(4 k T)`, so a loop of damping ζ takes `k = 1/(4 ζ² T)`:
//!
//! ```text
//! k_rate     = 1 / (4 ζ_rate² τ)          rate loop around the motors,        ζ_rate     = 0.9
//! k_attitude = k_rate / (4 ζ_attitude²)   attitude loop around the rate loop, ζ_attitude = 0.8
//! k_velocity = k_attitude / (4 ζ_velocity²)  velocity around attitude,        ζ_velocity = 0.7
//! k_position = k_velocity / (4 ζ_position²)  position around velocity,        ζ_position = 0.9
//! ```
//!
//! (τ clamped to 0.01–0.2 s; ζ, the clamp and the rate limits are published.) Each ζ is the
//! damping of *that* loop closed around the one inside it: the velocity loop, for example, is a
//! second-order system of damping 0.7 behind the attitude loop's lag, and its step response
//! overshoots by `exp(−πζ/√(1−ζ²))` = 4.6 %.
//!
//! **Position** (nonlinear dynamic inversion of the point mass `p̈ = f + g`):
//!
//! ```text
//! v_sp = limit(k_position (p_sp − p) + v_ff)        ≤ 2.5 m/s horizontal (norm), 2.5 m/s vertical
//! a_sp = limit(k_velocity (v_sp − v) + I)           ≤ 5 m/s² horizontal (norm) and vertical
//! İ    = k_vi (v_sp − v)                            with anti-windup, see below
//! f_sp = tilt_limit(a_sp − g)                       g = (0, 0, 9.80665): hover is (0, 0, −g)
//! ```
//!
//! The tilt limit clips the horizontal part of `f_sp` to 30° from vertical and keeps the vertical
//! part. The limits bound the *setpoints*; the flown speed overshoots the velocity setpoint by the
//! velocity loop's 4.6 % (2.61 m/s for a 2.5 m/s limit): pass a lower limit in
//! [`PositionLimits`] where the flown speed itself must stay below a figure.
//!
//! **Anti-windup.** The velocity integral does not integrate (it may only shrink) on an axis
//! while the velocity setpoint is at its limit there (a long transit is not a steady error), nor
//! in the direction in which the acceleration setpoint is being clipped (by the 5 m/s² limit or
//! by the tilt limit). It is itself limited to 5 m/s².
//!
//! **Wind** (what holding in one assumes). A steady wind's drag is a constant push `d` that the
//! velocity integral takes up: the lean is `atan(|d|/g)`, and the integral's zero at
//! [`VELOCITY_INTEGRAL_ZERO_FRACTION`] of `k_position` gives it a time constant of
//! `4/k_position` (5.3 s for a 25 ms motor, 42 s for the slowest, 0.2 s). The simulator's
//! draggiest airframe per kilogram is pushed at 2.9 m/s² by an 8 m/s wind (16°), within the
//! integral's 5 m/s² limit and the 30° tilt limit, so both bound the integral without stopping
//! the hold. A gust's extra drag `Δa` is rejected by the proportional loops alone until the
//! integral catches up: a static error of `Δa / (k_velocity k_position)` (0.5 m for turbulence
//! of σ = 1.5 m/s in an 8 m/s wind on that airframe). On the craft the measured thrust direction
//! (`crate::controller`, 0.1 s in a hold) and the hold's disturbance estimate
//! (`crate::controller::DisturbanceEstimate`) feed most of it back first. Tested on a point mass
//! with that drag: zero steady error, the integral equal to the drag, a 4 m/s gust's excursion
//! within the static error, and back.
//!
//! Rates: designed for the published 500 Hz, but the gains are continuous-time and the time step
//! is passed with every call. Non-finite input is refused with a [`PositionError`] and changes
//! nothing; nothing here panics.

use nalgebra::Vector3;

use crate::math::clamp;
use crate::navigation::STANDARD_GRAVITY_MPS2;

/// Damping of the rate loop around the motors' lag τ (published): `k_rate = 1/(4ζ²τ)`. The
/// controller takes a slower τ for motors fast enough to bring that gain near INDI's own mode
/// (`crate::controller::RATE_TO_INNER_MODE`).
pub const ZETA_RATE: f32 = 0.9;
/// `k_rate τ`'s reciprocal: `4ζ²` for [`ZETA_RATE`].
const RATE_GAIN_PER_TAU: f32 = 4.0 * ZETA_RATE * ZETA_RATE;

/// The motors' time constant, s, for which [`Gains::from_tau`] gives the rate gain `k_rate`
/// (1/s): `1/(4ζ² k_rate)`, the inverse of its published rule.
pub fn tau_for_rate_gain(k_rate: f32) -> f32 {
    1.0 / (RATE_GAIN_PER_TAU * k_rate)
}

/// Damping of the attitude loop around the rate loop (published).
pub const ZETA_ATTITUDE: f32 = 0.8;
/// Damping of the velocity loop around the attitude loop (published).
pub const ZETA_VELOCITY: f32 = 0.7;
/// Damping of the position loop around the velocity loop (published).
pub const ZETA_POSITION: f32 = 0.9;
/// Range τ is clamped to before the gains are made, s (published: 0.01–0.2 s).
pub const TAU_RANGE_S: (f32, f32) = (0.01, 0.2);

/// Largest horizontal velocity setpoint (norm of the north and east parts), m/s (published).
pub const MAX_SPEED_MPS: f32 = 2.5;
/// Largest vertical velocity setpoint (up or down), m/s. Ours: the published 2.5 m/s applied to
/// the vertical too (the published limit is not split by direction).
pub const MAX_VERTICAL_SPEED_MPS: f32 = 2.5;
/// Largest acceleration setpoint, m/s², on the horizontal norm and on the vertical separately
/// (published).
pub const MAX_ACCEL_MPS2: f32 = 5.0;
/// Largest tilt of the wanted specific force from vertical, rad (30°, published).
pub const MAX_TILT_RAD: f32 = 30.0 * core::f32::consts::PI / 180.0;

/// The velocity integral's zero as a fraction of the position loop's gain (ours):
/// `k_vi = k_velocity · (0.25 k_position)`. A PI `k_v (1 + k_vi/(k_v s))` has its zero at
/// `k_vi/k_v`; a quarter of the position loop's bandwidth removes steady errors (a constant push)
/// in a few `4/k_position` (≈ 5 s for a 25 ms motor) without adding visible overshoot to the
/// position response. (Placing it like another cascade step, `k_v²/(4ζ²)`, would put the zero
/// above the position loop's bandwidth and make the position response ring.)
pub const VELOCITY_INTEGRAL_ZERO_FRACTION: f32 = 0.25;

/// Damping of the attitude loop around the rate loop while holding a position (ours; the
/// published [`ZETA_ATTITUDE`] is 0.8): in a hold the attitude loop is what turns a gust's drag
/// away, and at 0.8 its time constant `1/k_attitude` is 0.25 s for a 30 ms motor and 0.5 s for a
/// 60 ms one, as long as turbulence correlated over 1–3 s takes to change. At 0.6 a tilt step
/// overshoots by 9.5 % instead of 1.5 %, a fraction of a degree at a hold's tilts. See
/// [`HOLD_ATTITUDE_GAIN_MAX`] for what was measured.
pub const ZETA_HOLD_ATTITUDE: f32 = 0.6;

/// Largest attitude-loop gain of a position hold, rad/s per rad (ours): [`ZETA_HOLD_ATTITUDE`]
/// speeds the loop up only to here, and never slows it below the published gain. A fast motor's
/// hold is not short of bandwidth, and what the loop then follows faster is the turbulence's
/// short-lived part, whose push moves the craft little (it is integrated twice) but tilts it:
/// body rates, not hold. 1,000 random worlds in a 0–8 m/s wind with turbulence (`fly --end land
/// monte-carlo --world random --wind --runs 1000`), held within 0.3 m and the hold's body rate
/// (RMS, median / 99th):
///
/// | hold's attitude gain | held | strayed beyond 0.3 m | never hovered | body rate, °/s |
/// |---|---:|---:|---:|---|
/// | published (ζ 0.8) | 959 | 32 | 5 | 3.6 / 19.7 |
/// | ζ 0.6, at most 4 /s | 982 | 9 | 5 | 4.4 / 20.1 |
/// | ζ 0.6, at most 5 /s | 985 | 6 | 5 | 5.1 / 22.8 |
/// | ζ 0.6, at most 7 /s | 988 | 3 | 5 | 6.1 / 30.2 |
/// | ζ 0.6, unbounded (up to 18 /s) | 975 | 2 | 19 | 6.9 / 39.5 |
///
/// Unbounded, 14 crafts with motors of 12–24 ms hold within centimetres but shake at 20–60 °/s
/// and never settle into a hover. (The velocity loop alone made stiffer, ζ_velocity 0.5 on the
/// published attitude gain, held 954 with 19 never hovered: the stiffer loop needs the faster
/// attitude loop under it.)
pub const HOLD_ATTITUDE_GAIN_MAX: f32 = 7.0;

/// Smallest upward specific force the tilt limit returns, fraction of g: the thrust axis must
/// stay defined even if a setpoint asks to fall (ours).
pub const MIN_UP_FRACTION: f32 = 0.1;

/// An acceleration clipped by more than this counts as held at its limit, m/s².
const SATURATION_TOLERANCE_MPS2: f32 = 1e-5;

/// The cascade's gains (all 1/s: rate rad/s² per rad/s, attitude rad/s per rad, velocity m/s² per
/// m/s, position m/s per m) and the velocity integral (1/s²: m/s² per m of integrated velocity
/// error).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Gains {
    /// The τ the gains were made for (after the clamp), s.
    pub tau_s: f32,
    /// Rate loop, rad/s² per rad/s: `1/(4 ζ_rate² τ)`.
    pub k_rate: f32,
    /// Attitude loop, rad/s per rad: `k_rate/(4 ζ_attitude²)`.
    pub k_attitude: f32,
    /// Velocity loop, m/s² per m/s: `k_attitude/(4 ζ_velocity²)`.
    pub k_velocity: f32,
    /// Position loop, m/s per m: `k_velocity/(4 ζ_position²)`.
    pub k_position: f32,
    /// Velocity-loop integral, m/s³ per m/s: `k_velocity · k_position / 4` (see
    /// [`VELOCITY_INTEGRAL_ZERO_FRACTION`]).
    pub k_velocity_integral: f32,
}

impl Gains {
    /// The gains for motors whose slowest time constant is `tau_s`, clamped to [`TAU_RANGE_S`];
    /// a τ that is not finite or not positive takes the slow (safe) end.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn from_tau(tau_s: f32) -> Self {
        let tau = if tau_s.is_finite() && tau_s > 0.0 {
            tau_s.clamp(TAU_RANGE_S.0, TAU_RANGE_S.1)
        } else {
            TAU_RANGE_S.1
        };
        let k_rate = 1.0 / (RATE_GAIN_PER_TAU * tau);
        let k_attitude = k_rate / (4.0 * ZETA_ATTITUDE * ZETA_ATTITUDE);
        let k_velocity = k_attitude / (4.0 * ZETA_VELOCITY * ZETA_VELOCITY);
        let k_position = k_velocity / (4.0 * ZETA_POSITION * ZETA_POSITION);
        Self {
            tau_s: tau,
            k_rate,
            k_attitude,
            k_velocity,
            k_position,
            k_velocity_integral: k_velocity * VELOCITY_INTEGRAL_ZERO_FRACTION * k_position,
        }
    }

    /// The gains of a position hold built on these: the attitude loop at [`ZETA_HOLD_ATTITUDE`]
    /// around the rate loop, at most [`HOLD_ATTITUDE_GAIN_MAX`] and never slower than these
    /// gains', and the velocity and position loops and the integral made on it as in
    /// [`Self::from_tau`]. The rate loop and τ are these gains'.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn for_hold(&self) -> Self {
        let k_attitude = (self.k_rate / (4.0 * ZETA_HOLD_ATTITUDE * ZETA_HOLD_ATTITUDE))
            .min(HOLD_ATTITUDE_GAIN_MAX)
            .max(self.k_attitude);
        let k_velocity = k_attitude / (4.0 * ZETA_VELOCITY * ZETA_VELOCITY);
        let k_position = k_velocity / (4.0 * ZETA_POSITION * ZETA_POSITION);
        self.with_outer_loops(k_attitude, k_velocity, k_position)
    }

    /// These gains' rate loop and τ with the attitude, velocity and position loops given, 1/s,
    /// and the velocity integral made on them ([`VELOCITY_INTEGRAL_ZERO_FRACTION`]).
    fn with_outer_loops(&self, k_attitude: f32, k_velocity: f32, k_position: f32) -> Self {
        Self {
            k_attitude,
            k_velocity,
            k_position,
            k_velocity_integral: k_velocity * VELOCITY_INTEGRAL_ZERO_FRACTION * k_position,
            ..*self
        }
    }

    /// [`Self::for_hold`] within bounds on its position and velocity loops, 1/s (infinite: none),
    /// made from the outside in: the position loop at most `k_position_max`; the velocity loop
    /// as fast as that position loop asks through the cascade (`k_position · 4 ζ_position²`),
    /// never slower than these gains' nor faster than the hold's, and at most `k_velocity_max`
    /// (the position loop then at most what that velocity loop keeps damped); the attitude loop
    /// likewise from the velocity loop. A bound only lowers: a noisy source's hold (GNSS, whose
    /// bounds bite) flies these gains' cascade under its bounds as before the hold had its own,
    /// and the faster attitude loop is left to sources precise enough to use it. 1,000 random
    /// worlds on the receiver in wind (`fly --gnss --end land monte-carlo --world random
    /// --wind`), held within 1 m and the median hold's body rate: 981 and 8.3 °/s RMS on the
    /// published cascade, 985 and 17.7 °/s with the hold's own unbounded (the fixes' noise
    /// turned into tilt), 984 and 10.4 °/s within these bounds.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn for_hold_within(&self, k_position_max: f32, k_velocity_max: f32) -> Self {
        let fast = self.for_hold();
        let (position_ratio, velocity_ratio) =
            (4.0 * ZETA_POSITION * ZETA_POSITION, 4.0 * ZETA_VELOCITY * ZETA_VELOCITY);
        // `max` then `min` rather than `clamp`: no panic path, and `fast` is never below `self`.
        // What a loop asks of the one inside it; the hold's own where it was not lowered
        // (exactly: no rounding through the ratios).
        let asked =
            |k: f32, own: f32, ratio: f32, inner: f32| if k < own { k * ratio } else { inner };
        let k_position = fast.k_position.min(k_position_max);
        let k_velocity = asked(k_position, fast.k_position, position_ratio, fast.k_velocity)
            .max(self.k_velocity)
            .min(fast.k_velocity)
            .min(k_velocity_max);
        let k_position = k_position.min(k_velocity / position_ratio);
        let k_attitude = asked(k_velocity, fast.k_velocity, velocity_ratio, fast.k_attitude)
            .max(self.k_attitude)
            .min(fast.k_attitude);
        self.with_outer_loops(k_attitude, k_velocity, k_position)
    }

    /// Whether every gain is finite and positive (the integral may be zero).
    pub fn is_valid(&self) -> bool {
        let positive = [self.k_rate, self.k_attitude, self.k_velocity, self.k_position];
        positive.iter().all(|k| k.is_finite() && *k > 0.0)
            && self.k_velocity_integral.is_finite()
            && self.k_velocity_integral >= 0.0
    }
}

/// The limits of the position controller; the default is the published set.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PositionLimits {
    /// Largest horizontal velocity setpoint (norm), m/s. Default [`MAX_SPEED_MPS`].
    pub max_horizontal_speed_mps: f32,
    /// Largest vertical velocity setpoint, m/s. Default [`MAX_VERTICAL_SPEED_MPS`].
    pub max_vertical_speed_mps: f32,
    /// Largest acceleration setpoint, horizontal norm and vertical, m/s². Default
    /// [`MAX_ACCEL_MPS2`].
    pub max_accel_mps2: f32,
    /// Largest tilt of the wanted specific force, rad, below 90°. Default [`MAX_TILT_RAD`].
    pub max_tilt_rad: f32,
}

impl Default for PositionLimits {
    fn default() -> Self {
        Self {
            max_horizontal_speed_mps: MAX_SPEED_MPS,
            max_vertical_speed_mps: MAX_VERTICAL_SPEED_MPS,
            max_accel_mps2: MAX_ACCEL_MPS2,
            max_tilt_rad: MAX_TILT_RAD,
        }
    }
}

impl PositionLimits {
    /// Check that every limit is finite and positive and the tilt below 90°.
    pub fn validate(&self) -> Result<(), PositionError> {
        let positive =
            [self.max_horizontal_speed_mps, self.max_vertical_speed_mps, self.max_accel_mps2]
                .iter()
                .all(|x| x.is_finite() && *x > 0.0);
        let tilt_ok = self.max_tilt_rad > 0.0 && self.max_tilt_rad < core::f32::consts::FRAC_PI_2;
        if positive && tilt_ok {
            Ok(())
        } else {
            Err(PositionError::BadConfig)
        }
    }
}

/// Where to be.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionSetpoint {
    /// World NED, m.
    pub position_ned_m: Vector3<f32>,
    /// Feed-forward velocity, world NED, m/s (zero to hold; limited with the position term).
    pub velocity_ned_mps: Vector3<f32>,
}

/// Why a call was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PositionError {
    /// A non-finite value or a non-positive time step.
    BadInput,
    /// A gain or limit is not finite, not positive, or a tilt limit not below 90°.
    BadConfig,
}

/// The NDI position controller.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PositionController {
    gains: Gains,
    limits: PositionLimits,
    /// The velocity loop's integral (an acceleration), world NED, m/s².
    integral_mps2: Vector3<f32>,
    /// The last velocity setpoint, world NED, m/s.
    velocity_sp_mps: Vector3<f32>,
}

impl PositionController {
    /// A controller with `gains` and the published limits, its integral empty.
    pub fn new(gains: Gains) -> Self {
        Self {
            gains,
            limits: PositionLimits::default(),
            integral_mps2: Vector3::zeros(),
            velocity_sp_mps: Vector3::zeros(),
        }
    }

    /// A controller with `gains` and `limits`, if both are valid.
    pub fn with_limits(gains: Gains, limits: PositionLimits) -> Result<Self, PositionError> {
        limits.validate()?;
        if !gains.is_valid() {
            return Err(PositionError::BadConfig);
        }
        Ok(Self { limits, ..Self::new(gains) })
    }

    /// The gains in use.
    pub fn gains(&self) -> &Gains {
        &self.gains
    }

    /// The limits in use.
    pub fn limits(&self) -> &PositionLimits {
        &self.limits
    }

    /// Empty the integral (at a handover, or when the position source changes).
    pub fn reset(&mut self) {
        self.integral_mps2 = Vector3::zeros();
        self.velocity_sp_mps = Vector3::zeros();
    }

    /// The velocity loop's integral (an acceleration), world NED, m/s².
    pub fn integral_mps2(&self) -> Vector3<f32> {
        self.integral_mps2
    }

    /// The velocity setpoint of the last step (after its limits), world NED, m/s.
    pub fn velocity_sp_mps(&self) -> Vector3<f32> {
        self.velocity_sp_mps
    }

    /// One step: position and velocity of the CoG (world NED, m and m/s), the setpoint, `dt_s`
    /// since the last step. Returns the wanted specific force, world NED, m/s² (hover
    /// (0, 0, −g)), its tilt limited.
    pub fn update(
        &mut self,
        position_ned_m: &Vector3<f32>,
        velocity_ned_mps: &Vector3<f32>,
        setpoint: &PositionSetpoint,
        dt_s: f32,
    ) -> Result<Vector3<f32>, PositionError> {
        let finite = [
            position_ned_m,
            velocity_ned_mps,
            &setpoint.position_ned_m,
            &setpoint.velocity_ned_mps,
        ]
        .iter()
        .all(|v| all_finite(v))
            && dt_s > 0.0
            && dt_s.is_finite();
        if !finite {
            return Err(PositionError::BadInput);
        }
        let (k, l) = (&self.gains, &self.limits);
        let velocity_wanted =
            (setpoint.position_ned_m - position_ned_m) * k.k_position + setpoint.velocity_ned_mps;
        let velocity_sp = limit_horizontal_vertical(
            &velocity_wanted,
            l.max_horizontal_speed_mps,
            l.max_vertical_speed_mps,
        );
        let horizontal_speed_held =
            crate::math::hypot(velocity_wanted.x, velocity_wanted.y) > l.max_horizontal_speed_mps;
        let vertical_speed_held = velocity_wanted.z.abs() > l.max_vertical_speed_mps;
        let speed_held = [horizontal_speed_held, horizontal_speed_held, vertical_speed_held];

        let velocity_error = velocity_sp - velocity_ned_mps;
        let accel_wanted = velocity_error * k.k_velocity + self.integral_mps2;
        let accel_sp = limit_horizontal_vertical(&accel_wanted, l.max_accel_mps2, l.max_accel_mps2);
        let gravity = Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2);
        let f_sp = limit_tilt_to(&(accel_sp - gravity), l.max_tilt_rad);
        // What is asked for after every limit, and by how much each axis was clipped.
        let clipped = accel_wanted - (f_sp + gravity);

        let mut integral = self.integral_mps2;
        for (axis, held) in speed_held.iter().enumerate() {
            let step = velocity_error[axis] * k.k_velocity_integral * dt_s;
            let shrinking = step * integral[axis] < 0.0;
            let into_limit =
                clipped[axis].abs() > SATURATION_TOLERANCE_MPS2 && step * clipped[axis] > 0.0;
            if shrinking || !(*held || into_limit) {
                integral[axis] += step;
            }
        }
        self.integral_mps2 =
            limit_horizontal_vertical(&integral, l.max_accel_mps2, l.max_accel_mps2);
        self.velocity_sp_mps = velocity_sp;
        Ok(f_sp)
    }
}

/// `v` with its horizontal part limited to a norm of `limit` and its vertical part to ±`limit`.
pub fn limit_split(v: &Vector3<f32>, limit: f32) -> Vector3<f32> {
    limit_horizontal_vertical(v, limit, limit)
}

/// `v` with its horizontal part (x, y) limited to a norm of `horizontal` (direction kept) and
/// its vertical part (z) to ±`vertical`.
pub fn limit_horizontal_vertical(v: &Vector3<f32>, horizontal: f32, vertical: f32) -> Vector3<f32> {
    let norm = crate::math::hypot(v.x, v.y);
    let scale = if norm > horizontal { horizontal / norm } else { 1.0 };
    Vector3::new(v.x * scale, v.y * scale, clamp(v.z, -vertical, vertical))
}

/// A wanted specific force with its horizontal part limited to [`MAX_TILT_RAD`] from vertical.
pub fn limit_tilt(f_sp: &Vector3<f32>) -> Vector3<f32> {
    limit_tilt_to(f_sp, MAX_TILT_RAD)
}

/// A wanted specific force (world NED, m/s²) with its horizontal part limited to `max_tilt_rad`
/// from vertical: the vertical part is kept (at least [`MIN_UP_FRACTION`] of g upward, so the
/// axis is defined), the horizontal part scaled down in its own direction.
pub fn limit_tilt_to(f_sp: &Vector3<f32>, max_tilt_rad: f32) -> Vector3<f32> {
    let up = (-f_sp.z).max(MIN_UP_FRACTION * STANDARD_GRAVITY_MPS2);
    // tan as sin/cos (`crate::math`: libm's trigonometry costs the firmware 6.5 KB of flash).
    let (sin, cos) = crate::math::sin_cos(max_tilt_rad);
    let horizontal_max = up * sin / cos;
    let horizontal = crate::math::hypot(f_sp.x, f_sp.y);
    let scale = if horizontal > horizontal_max { horizontal_max / horizontal } else { 1.0 };
    Vector3::new(f_sp.x * scale, f_sp.y * scale, -up)
}

fn all_finite(v: &Vector3<f32>) -> bool {
    v.iter().all(|x| x.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The published position-loop rate.
    const DT: f32 = 1.0 / 500.0;
    const G: f32 = STANDARD_GRAVITY_MPS2;
    /// The motor time constant of the tests, s (a typical small-quad motor).
    const TAU_S: f32 = 0.025;

    /// The step overshoot of a second-order loop of damping ζ.
    fn overshoot_of(zeta: f32) -> f32 {
        libm::expf(-core::f32::consts::PI * zeta / libm::sqrtf(1.0 - zeta * zeta))
    }

    /// What a simulated flight measured.
    #[derive(Debug)]
    struct Flight {
        /// Largest horizontal speed flown, m/s.
        worst_speed: f32,
        /// Largest vertical speed flown, m/s.
        worst_vertical_speed: f32,
        /// Largest horizontal velocity setpoint, m/s.
        worst_speed_sp: f32,
        /// Largest tilt of the wanted specific force, rad.
        worst_tilt: f32,
        /// Largest |integral| while the velocity setpoint was at its limit, m/s².
        worst_integral_in_transit: f32,
        /// Largest distance beyond the target along the direction of travel, m.
        overshoot: f32,
        /// Last time the distance to the target was at least `tolerance`, s.
        last_outside_s: f32,
        /// Final position (the target is the origin), m.
        end: Vector3<f32>,
    }

    /// A point mass `p̈ = a + d` whose acceleration follows `f_sp + g` through a first-order lag
    /// of the attitude loop's time constant 1/k_attitude, pushed by `disturbance` (m/s²),
    /// flown to the origin from `start` for `seconds`.
    fn fly(
        mut controller: PositionController,
        start: Vector3<f32>,
        disturbance: Vector3<f32>,
        seconds: f32,
        tolerance: f32,
    ) -> Flight {
        let setpoint = PositionSetpoint {
            position_ned_m: Vector3::zeros(),
            velocity_ned_mps: Vector3::zeros(),
        };
        let gravity = Vector3::new(0.0, 0.0, G);
        let lag = DT * controller.gains().k_attitude;
        let direction = start.try_normalize(1e-9).unwrap_or_else(Vector3::zeros);
        let (mut p, mut v, mut accel) = (start, Vector3::zeros(), Vector3::zeros());
        let mut flight = Flight {
            worst_speed: 0.0,
            worst_vertical_speed: 0.0,
            worst_speed_sp: 0.0,
            worst_tilt: 0.0,
            worst_integral_in_transit: 0.0,
            overshoot: 0.0,
            last_outside_s: 0.0,
            end: start,
        };
        for n in 0..((seconds / DT) as usize) {
            let f = controller.update(&p, &v, &setpoint, DT).unwrap();
            let v_sp = controller.velocity_sp_mps();
            let horizontal_sp = libm::hypotf(v_sp.x, v_sp.y);
            flight.worst_speed_sp = flight.worst_speed_sp.max(horizontal_sp);
            if horizontal_sp >= MAX_SPEED_MPS - 1e-4 {
                let integral = controller.integral_mps2().norm();
                flight.worst_integral_in_transit = flight.worst_integral_in_transit.max(integral);
            }
            flight.worst_tilt = flight.worst_tilt.max(libm::atan2f(libm::hypotf(f.x, f.y), -f.z));
            accel += (f + gravity - accel) * lag;
            v += (accel + disturbance) * DT;
            p += v * DT;
            flight.worst_speed = flight.worst_speed.max(libm::hypotf(v.x, v.y));
            flight.worst_vertical_speed = flight.worst_vertical_speed.max(v.z.abs());
            flight.overshoot = flight.overshoot.max(-p.dot(&direction));
            if p.norm() >= tolerance {
                flight.last_outside_s = (n + 1) as f32 * DT;
            }
        }
        flight.end = p;
        flight
    }

    fn controller() -> PositionController {
        PositionController::new(Gains::from_tau(TAU_S))
    }

    #[test]
    fn gains_follow_the_published_formula_and_tau_is_clamped() {
        let g = Gains::from_tau(TAU_S);
        // The formula in f64.
        let k_rate = 1.0 / (4.0 * 0.81 * 0.025f64);
        let k_attitude = k_rate / (4.0 * 0.64);
        let k_velocity = k_attitude / (4.0 * 0.49);
        let k_position = k_velocity / (4.0 * 0.81);
        let k_vi = k_velocity * k_position / 4.0;
        for (got, want) in [
            (g.k_rate, k_rate),
            (g.k_attitude, k_attitude),
            (g.k_velocity, k_velocity),
            (g.k_position, k_position),
            (g.k_velocity_integral, k_vi),
        ] {
            assert!((f64::from(got) / want - 1.0).abs() < 1e-6, "{got} against {want}");
        }
        assert_eq!(g.tau_s, TAU_S);
        assert_eq!(Gains::from_tau(0.001), Gains::from_tau(0.01));
        assert_eq!(Gains::from_tau(0.001).tau_s, 0.01);
        assert_eq!(Gains::from_tau(1.0), Gains::from_tau(0.2));
        assert_eq!(Gains::from_tau(1.0).tau_s, 0.2);
        for bad in [f32::NAN, f32::INFINITY, 0.0, -0.05] {
            assert_eq!(Gains::from_tau(bad).tau_s, 0.2, "τ = {bad}");
        }
        assert!(g.is_valid());
    }

    #[test]
    fn hovering_on_the_setpoint_asks_for_one_g_up() {
        let mut controller = controller();
        let here = Vector3::new(1.0, 2.0, -3.0);
        let setpoint =
            PositionSetpoint { position_ned_m: here, velocity_ned_mps: Vector3::zeros() };
        let f = controller.update(&here, &Vector3::zeros(), &setpoint, DT).unwrap();
        assert!((f - Vector3::new(0.0, 0.0, -G)).norm() < 1e-6);
    }

    #[test]
    fn a_2_m_offset_is_flown_out_within_4_s_and_the_limits() {
        // 2 m along a direction with a vertical part. Measured: inside 5 cm from 3.5 s on; the
        // last few millimetres go with the integral's slow zero (k_position/4, 5 s).
        let start = Vector3::new(0.6, -0.64, 0.48) * 2.0;
        let flight = fly(controller(), start, Vector3::zeros(), 15.0, 0.05);
        assert!(flight.last_outside_s < 4.0, "{flight:?}");
        assert!(flight.end.norm() < 0.01, "{flight:?}");
        assert!(flight.worst_speed <= MAX_SPEED_MPS, "{flight:?}");
        assert!(flight.worst_vertical_speed <= MAX_VERTICAL_SPEED_MPS, "{flight:?}");
        assert!(flight.worst_tilt <= MAX_TILT_RAD + 1e-5, "{flight:?}");
        assert!(flight.overshoot < 0.05, "{flight:?}");
    }

    #[test]
    fn a_steady_1_mps2_push_is_taken_up_by_the_integral() {
        // Horizontal, vertical and both. Without the integral the error would be
        // d/(k_velocity k_position) = 0.54 m. Measured: inside 1 cm from 22.4 s on.
        for push in
            [Vector3::new(0.6, 0.8, 0.0), Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.6, 0.0, -0.8)]
        {
            let flight = fly(controller(), Vector3::zeros(), push, 60.0, 0.01);
            assert!(flight.last_outside_s < 30.0, "{push:?}: {flight:?}");
            assert!(flight.end.norm() < 1e-3, "{push:?}: {flight:?}");
        }
    }

    #[test]
    fn a_100_m_step_keeps_the_speed_limit_and_does_not_wind_up() {
        let start = Vector3::new(-80.0, 60.0, 0.0);
        let flight = fly(controller(), start, Vector3::zeros(), 70.0, 0.05);
        // The setpoint is held to the limit; the flown speed overshoots it by the velocity
        // loop's ζ = 0.7 step overshoot (4.6 %: 2.61 m/s), and no more.
        assert!(flight.worst_speed_sp <= MAX_SPEED_MPS + 1e-5, "{flight:?}");
        let bound = MAX_SPEED_MPS * (1.0 + overshoot_of(ZETA_VELOCITY)) + 0.01;
        assert!(flight.worst_speed <= bound, "{flight:?}, bound {bound}");
        assert!(flight.worst_tilt <= MAX_TILT_RAD + 1e-5, "{flight:?}");
        // No integration in transit, so no overshoot on arrival. Measured: inside 5 cm from
        // 50.2 s on (40 s at 2.5 m/s, then the position loop's approach).
        assert!(flight.worst_integral_in_transit < 1e-3, "{flight:?}");
        assert!(flight.overshoot < 0.05, "{flight:?}");
        assert!(flight.last_outside_s < 55.0, "{flight:?}");

        // With the limit lowered by that overshoot, the flown speed stays within 2.5 m/s.
        let limits = PositionLimits {
            max_horizontal_speed_mps: MAX_SPEED_MPS / (1.0 + overshoot_of(ZETA_VELOCITY)),
            ..PositionLimits::default()
        };
        let lowered = PositionController::with_limits(Gains::from_tau(TAU_S), limits).unwrap();
        let flight = fly(lowered, start, Vector3::zeros(), 70.0, 0.05);
        assert!(flight.worst_speed <= MAX_SPEED_MPS, "{flight:?}");
        assert!(flight.overshoot < 0.05, "{flight:?}");
    }

    /// A hold's attitude loop is faster than the published one where the motors allow it, never
    /// slower, bounded, and the loops outside it keep their published damping around it; over
    /// the whole range of τ the gains are made for.
    #[test]
    fn a_hold_turns_faster_within_its_bound_and_keeps_the_cascade_around_it() {
        let mut tau_s = TAU_RANGE_S.0;
        let (mut faster, mut bounded) = (0, 0);
        while tau_s <= TAU_RANGE_S.1 {
            let published = Gains::from_tau(tau_s);
            let hold = published.for_hold();
            assert!(hold.is_valid(), "τ {tau_s}: {hold:?}");
            assert_eq!((hold.tau_s, hold.k_rate), (published.tau_s, published.k_rate));
            assert!(hold.k_attitude >= published.k_attitude, "τ {tau_s}: slower than published");
            let at_damping = published.k_rate / (4.0 * ZETA_HOLD_ATTITUDE * ZETA_HOLD_ATTITUDE);
            if at_damping <= HOLD_ATTITUDE_GAIN_MAX {
                assert!((hold.k_attitude - at_damping).abs() <= 1e-5 * at_damping, "τ {tau_s}");
                faster += 1;
            } else {
                let expected = HOLD_ATTITUDE_GAIN_MAX.max(published.k_attitude);
                assert_eq!(hold.k_attitude, expected, "τ {tau_s}");
                bounded += 1;
            }
            // The velocity and position loops stand to the hold's attitude loop as the
            // published ones stand to the published attitude loop.
            let ratio = |a: f32, b: f32| a / b;
            let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * b.abs();
            assert!(close(
                ratio(hold.k_velocity, hold.k_attitude),
                ratio(published.k_velocity, published.k_attitude)
            ));
            assert!(close(
                ratio(hold.k_position, hold.k_velocity),
                ratio(published.k_position, published.k_velocity)
            ));
            assert!(close(
                hold.k_velocity_integral,
                hold.k_velocity * VELOCITY_INTEGRAL_ZERO_FRACTION * hold.k_position
            ));
            tau_s += 0.001;
        }
        // Both regimes occur in the range: slow motors at the hold's damping, fast ones bounded.
        assert!(faster > 0 && bounded > 0, "{faster} at the damping, {bounded} bounded");
        // A 60 ms motor: its hold's attitude loop is (0.8/0.6)² = 1.8 times as fast, so the
        // stiffness against a push, `k_velocity k_position` (the static error is
        // `Δa / (k_velocity k_position)`), is (0.8/0.6)⁴ = 3.2 times the published one's.
        let slow = Gains::from_tau(0.06);
        let stiffening = slow.for_hold().k_velocity * slow.for_hold().k_position
            / (slow.k_velocity * slow.k_position);
        let expected = (ZETA_ATTITUDE / ZETA_HOLD_ATTITUDE).powi(4);
        assert!((stiffening - expected).abs() < 1e-3 * expected, "{stiffening} vs {expected}");
    }

    /// Bounds on a hold rebuild it from the outside in: none leaves the hold's own gains, a
    /// position bound below the published loop's (a receiver's) leaves the published velocity
    /// and attitude loops under it, a velocity bound lowers the position loop with it, and no
    /// bound raises a gain; for every τ of the range.
    #[test]
    fn bounds_on_a_hold_slow_it_from_the_outside_in_and_never_below_the_published_loops() {
        let mut tau_s = TAU_RANGE_S.0;
        while tau_s <= TAU_RANGE_S.1 {
            let published = Gains::from_tau(tau_s);
            let fast = published.for_hold();
            assert_eq!(published.for_hold_within(f32::INFINITY, f32::INFINITY), fast);
            let receiver = published.for_hold_within(0.5 * published.k_position, f32::INFINITY);
            assert_eq!(receiver.k_position, 0.5 * published.k_position, "τ {tau_s}");
            assert_eq!(receiver.k_velocity, published.k_velocity, "τ {tau_s}");
            assert_eq!(receiver.k_attitude, published.k_attitude, "τ {tau_s}");
            let noisy = published.for_hold_within(f32::INFINITY, 0.5 * published.k_velocity);
            assert_eq!(noisy.k_velocity, 0.5 * published.k_velocity, "τ {tau_s}");
            let damped = noisy.k_velocity / (4.0 * ZETA_POSITION * ZETA_POSITION);
            assert!((noisy.k_position - damped).abs() <= 1e-6 * damped, "τ {tau_s}");
            assert_eq!(noisy.k_attitude, published.k_attitude, "τ {tau_s}");
            for bounded in [receiver, noisy] {
                assert!(bounded.is_valid());
                assert!(bounded.k_position <= fast.k_position);
                assert!(bounded.k_velocity <= fast.k_velocity);
                assert!(bounded.k_attitude <= fast.k_attitude);
            }
            tau_s += 0.001;
        }
    }

    #[test]
    fn a_point_mass_holds_against_a_steady_8_mps_wind_and_its_gusts() {
        // The draggiest airframe per kilogram of the simulator's random world (`sim::airframe`:
        // size 0.6, four rotors, 0.130 kg; drag 0.05 s² N/(m/s) and 0.01 s² N/(m/s)², s the
        // size): 0.139 /s and 0.0278 /m per unit mass, so an 8 m/s wind pushes it at 2.9 m/s²
        // (a 16° lean). The point mass follows the wanted specific force through the attitude
        // loop's lag and is pushed by the drag on its airspeed (velocity less the wind's). A
        // 1 − cos gust of 4 m/s more over 3 s comes at 60 s.
        const LINEAR_PER_S: f32 = 0.139;
        const QUADRATIC_PER_M: f32 = 0.0278;
        const WIND_MPS: f32 = 8.0;
        let drag = |airspeed: Vector3<f32>| {
            -(airspeed * LINEAR_PER_S + airspeed * (airspeed.norm() * QUADRATIC_PER_M))
        };
        let steady_push = drag(Vector3::new(-WIND_MPS, 0.0, 0.0));
        let mut controller = controller();
        let setpoint = PositionSetpoint {
            position_ned_m: Vector3::zeros(),
            velocity_ned_mps: Vector3::zeros(),
        };
        let gravity = Vector3::new(0.0, 0.0, G);
        let lag = DT * controller.gains().k_attitude;
        let (mut p, mut v, mut accel) = (Vector3::zeros(), Vector3::zeros(), Vector3::zeros());
        let (mut worst_before_gust, mut worst_in_gust, mut worst_tilt) = (0.0f32, 0.0f32, 0.0f32);
        let mut worst_integral = 0.0f32;
        for n in 0..((90.0 / DT) as usize) {
            let t = n as f32 * DT;
            let gust = if (60.0..63.0).contains(&t) {
                4.0 * 0.5 * (1.0 - libm::cosf(core::f32::consts::TAU * (t - 60.0) / 3.0))
            } else {
                0.0
            };
            let wind = Vector3::new(WIND_MPS + gust, 0.0, 0.0);
            let f = controller.update(&p, &v, &setpoint, DT).unwrap();
            worst_tilt = worst_tilt.max(libm::atan2f(libm::hypotf(f.x, f.y), -f.z));
            worst_integral = worst_integral.max(controller.integral_mps2().norm());
            accel += (f + gravity - accel) * lag;
            v += (accel + drag(v - wind)) * DT;
            p += v * DT;
            if (50.0..60.0).contains(&t) {
                worst_before_gust = worst_before_gust.max(p.norm());
            }
            if t >= 60.0 {
                worst_in_gust = worst_in_gust.max(p.norm());
            }
        }
        // Zero steady error: the integral has taken the drag up (measured: 0.1 mm).
        assert!(worst_before_gust < 1e-3, "off by {worst_before_gust} m before the gust");
        assert!(p.norm() < 1e-3, "off by {} m at the end", p.norm());
        let integral = controller.integral_mps2();
        assert!((integral + steady_push).norm() < 0.01, "{integral:?} against {steady_push:?}");
        // Bounded: the integral within its limit, the lean within the tilt limit, and the
        // gust's excursion within the proportional loops' static error for the gust's extra
        // drag, `Δa / (k_velocity k_position)` (2.8 m/s², 1.5 m; measured: 1.0 m), and back
        // (the end above, 27 s after it): no fly-away. The excursion is what the position loop
        // alone can do: on the craft the measured thrust direction (`crate::controller`'s
        // `ThrustDirection`, 0.1 s in a hold) takes up part of a gust's drag before the loop sees it.
        assert!(worst_integral <= MAX_ACCEL_MPS2 + 1e-4, "integral {worst_integral} m/s²");
        assert!(worst_tilt <= MAX_TILT_RAD + 1e-5, "tilt {worst_tilt} rad");
        let gains = controller.gains();
        let extra_push = (drag(Vector3::new(-WIND_MPS - 4.0, 0.0, 0.0)) - steady_push).norm();
        let bound = extra_push / (gains.k_velocity * gains.k_position);
        assert!(worst_in_gust < bound, "the gust took it {worst_in_gust} m away (bound {bound})");
    }

    #[test]
    fn the_integral_does_not_grow_into_the_tilt_limit() {
        // Sinking hard (5 m/s² down leaves 4.8 m/s² of thrust, so 30° allows only 2.8 m/s² of
        // horizontal acceleration) while pushed sideways by more than that: the horizontal
        // acceleration is clipped by the tilt limit, and the integral must not wind up.
        let mut controller = controller();
        let setpoint = PositionSetpoint {
            position_ned_m: Vector3::zeros(),
            velocity_ned_mps: Vector3::new(0.0, 0.0, 2.5),
        };
        for _ in 0..1000 {
            let f = controller
                .update(&Vector3::zeros(), &Vector3::new(-1.5, 0.0, 0.0), &setpoint, DT)
                .unwrap();
            let tilt = libm::atan2f(libm::hypotf(f.x, f.y), -f.z);
            assert!(tilt <= MAX_TILT_RAD + 1e-5);
        }
        assert!(controller.integral_mps2().x.abs() < 1e-6, "{:?}", controller.integral_mps2());
    }

    #[test]
    fn bad_input_changes_nothing() {
        let mut controller = controller();
        let setpoint = PositionSetpoint {
            position_ned_m: Vector3::zeros(),
            velocity_ned_mps: Vector3::zeros(),
        };
        let far = Vector3::new(5.0, 0.0, 0.0);
        let slow = Vector3::new(0.3, 0.0, 0.0);
        for _ in 0..10 {
            controller.update(&far, &slow, &setpoint, DT).unwrap();
        }
        let before = controller;
        let nan = Vector3::new(f32::NAN, 0.0, 0.0);
        let zero = Vector3::zeros();
        assert_eq!(controller.update(&nan, &zero, &setpoint, DT), Err(PositionError::BadInput));
        assert_eq!(controller.update(&far, &nan, &setpoint, DT), Err(PositionError::BadInput));
        let bad_sp = PositionSetpoint { position_ned_m: zero, velocity_ned_mps: nan };
        assert_eq!(controller.update(&far, &zero, &bad_sp, DT), Err(PositionError::BadInput));
        for dt in [0.0, -DT, f32::NAN, f32::INFINITY] {
            assert_eq!(controller.update(&far, &zero, &setpoint, dt), Err(PositionError::BadInput));
        }
        assert_eq!(controller, before);
    }

    #[test]
    fn bad_limits_are_refused() {
        let gains = Gains::from_tau(TAU_S);
        for limits in [
            PositionLimits { max_horizontal_speed_mps: -1.0, ..PositionLimits::default() },
            PositionLimits { max_accel_mps2: f32::NAN, ..PositionLimits::default() },
            PositionLimits { max_tilt_rad: 1.6, ..PositionLimits::default() },
        ] {
            assert_eq!(
                PositionController::with_limits(gains, limits),
                Err(PositionError::BadConfig)
            );
        }
        let bad_gains = Gains { k_velocity: f32::NAN, ..gains };
        assert_eq!(
            PositionController::with_limits(bad_gains, PositionLimits::default()),
            Err(PositionError::BadConfig)
        );
    }
}
