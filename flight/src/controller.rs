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
//! the IMU can sit in any orientation (docs/algorithms/indi.md, seed paper §3.4).
//!
//! - **Attitude** (published): the error between the thrust frame and its setpoint is split into
//!   tilt (the shortest rotation of the current thrust axis onto the wanted one) and yaw about the
//!   thrust axis; each becomes a rate setpoint through the attitude gain, tilt limited to
//!   [`MAX_TILT_RATE_RAD_S`] and yaw to [`MAX_YAW_RATE_RAD_S`], so a craft tumbling after the
//!   excitation first stops its rotation and then levels.
//! - **Large tilts** (ours): the linear law `k_attitude·e` turns a craft lying on its back at
//!   only `π·k_attitude` (430 °/s for τ = 50 ms), and a slow craft thrown to its apex then falls
//!   for a second before it is level. Beyond [`LINEAR_TILT_RAD`] the tilt rate gains a
//!   square-root term, `k·e + √(2α(e − e_lin))`: the rate from which the deceleration α still
//!   brings the craft back to the linear region (as time-optimal attitude controllers do), with α
//!   a quarter of the tilt authority of the learned G1 ([`tilt_authority_rad_s2`]). Along that
//!   curve the rate setpoint falls at α, which the rate loop is given as a feed-forward angular
//!   acceleration so it does not lag behind the planned deceleration. Within 30° of the wanted
//!   axis the loop is exactly the published one.
//! - **Thrust**: the magnitude of the wanted specific force, whatever the tilt (ours), as long as
//!   the thrust axis points above the horizon. Projecting it on the current thrust axis, as a
//!   level flight controller would, starves a tumbling craft of rotor speed: near idle the
//!   differential thrust that stops the spin is small, and the craft falls spinning. Measured on
//!   300 Monte Carlo throws (`fly monte-carlo --runs 300`): projected with a floor of 20 % of the
//!   magnitude, 21 hit the ground; floors of 50 % and 80 %, 16 and 12; the full magnitude, 4;
//!   the projection only beyond 30°, 10; more than the magnitude (1/cos of the tilt up to 60°),
//!   13. Below the horizon every newton of thrust pushes the fall on: there a quarter of it
//!   ([`INVERTED_THRUST_FRACTION`]).
//! - **Gains** from the slowest motor's τ ([`crate::position::Gains`], published).
//! - **Wind** (what the hold assumes of the world, ours): a steady wind of up to 8 m/s (up to
//!   2.9 m/s² of drag, 16° of lean, on the simulator's draggiest airframe per kilogram) and
//!   turbulence on it of σ up to 20 % of the wind + 0.1 m/s, correlated over 1–3 s. The steady
//!   drag is taken up by the measured thrust direction ([`ThrustDirection`], within 0.1 s in a
//!   hold, a 25° cone); what the attitude loop has not yet turned away of a gust's change is
//!   estimated against the commands ([`DisturbanceEstimate`], over 0.2 s, bounded at 3 m/s²) and
//!   half of it fed forward. Turbulence correlated over less than the attitude loop's lag
//!   passes to the position loop; a hold's attitude loop is faster than the published one for
//!   that (`crate::position::Gains::for_hold`: `1/k_attitude` 0.14 s for a 25 ms motor and
//!   0.28 s for a 60 ms one, instead of 0.21 and 0.5 s).
//!
//! A plain struct with [`Controller::update`]; the application decides when it runs and what
//! happens when it reports trouble.

use nalgebra::{UnitQuaternion, Vector3};

use crate::attitude::wrap_pi;
use crate::indi::{Indi, IndiConfig, IndiError, IndiModel, IndiOutput, IndiReference};
use crate::learner::LearnedModel;
use crate::navigation::{NavigationState, STANDARD_GRAVITY_MPS2};
use crate::position::{Gains, PositionController, PositionSetpoint};

/// Largest tilt rate the attitude loop asks for, rad/s (800 °/s, published;
/// docs/algorithms/indi.md).
pub const MAX_TILT_RATE_RAD_S: f32 = 800.0 * core::f32::consts::PI / 180.0;

/// Largest rate-loop gain as a fraction of INDI's own mode (`crate::indi::inner_mode_rad_s`),
/// ours. The published `k_rate = 1/(4ζ²τ)` treats the motors' lag as the rate loop's only
/// one; behind INDI's synchronising filter the loop is a lightly damped pair instead (damping
/// 0.27 at 15.7 ms and 15 Hz), and the faster the motors, the closer the published gain comes to
/// it: a third of it at 15.7 ms, where a 213 g hexarotor (Monte Carlo seed 454 of `fly --world
/// random`) coned at 8 Hz with its motors at their bounds in every world, against a sixth at
/// 50 ms. A quarter binds below about 26 ms at 15 Hz (14.6 /s instead of 19.7 at 15.7 ms).
/// Measured on 1,000 random worlds each (calm / wind / no speeds / no offset): held 998 + 1 →
/// 999 + 1, 994 + 2 → 996 + 2, 990 → 992, 994 + 3 → 995 + 3; GNSS in wind within 1 m 989 either
/// way. The whole chain at half the gain instead (the motors' lag taken as at least 30 ms)
/// held more (1,000 calm, 997 + 2 in wind) but no longer held a motor that lost half its thrust
/// in the recovery (`tests/tests/faults.rs`).
pub const RATE_TO_INNER_MODE: f32 = 0.25;

/// Largest yaw rate the attitude loop asks for, rad/s (400 °/s, published;
/// docs/algorithms/indi.md).
pub const MAX_YAW_RATE_RAD_S: f32 = 400.0 * core::f32::consts::PI / 180.0;

/// Tilt beyond which the yaw error is ignored, rad (90°): the heading of a craft on its side is
/// undefined, and righting it comes first.
pub const YAW_CONTROL_MAX_TILT_RAD: f32 = core::f32::consts::FRAC_PI_2;

/// Fraction of the tilt authority the square-root law plans to decelerate with (ours): half the
/// authority goes to the differential thrust that decelerates while the rest keeps the total
/// thrust, and half of that is margin for a model learned in half a second.
pub const TILT_DECELERATION_FRACTION: f32 = 0.25;

/// Tilt error below which the attitude loop is the published linear one, rad (30°, ours): the
/// square-root term only speeds up recoveries from large tilts.
pub const LINEAR_TILT_RAD: f32 = 30.0 * core::f32::consts::PI / 180.0;

/// Largest vertical acceleration angle mode asks for, and the level hold downwards, m/s² (1 g,
/// ours): the motors cannot pull, so a craft sinks at most at g with them at idle.
pub const LEVEL_MAX_VERTICAL_ACCEL_MPS2: f32 = STANDARD_GRAVITY_MPS2;

/// Largest upward acceleration the level hold asks for, m/s² (2 g, ours): the level hold is what
/// catches a craft falling after the excitation, and the ground is the limit. What it assumes of
/// the world: a throw of the issue's 2.5–4.5 m from a hand 1–2 m up engages 0.5–0.95 s after the
/// release, 3.5–6.5 m above the ground, falling at up to 3 m/s and possibly on its back; the
/// turn-over adds 2–3 m/s of fall (0.2–0.3 s at g). Braking a fall of 6 m/s takes 1.8 m at 1 g and
/// 0.9 m at 2 g, beside the metres the fall itself took: 1,000 random worlds lost 5 such craft
/// in wind at 1 g (docs/benchmarks.md). The published 5 m/s² is a position-control limit and
/// would take 3.6 m. Three times the hover thrust is within reach of the median random airframe
/// (thrust-to-weight 2.5–5); a weaker one saturates and the allocation keeps the attitude first
/// (its weights: the thrust gives way before roll and pitch).
pub const LEVEL_MAX_BRAKING_ACCEL_MPS2: f32 = 2.0 * STANDARD_GRAVITY_MPS2;

/// The thrust asked while the thrust axis points below the horizon, as a fraction of the wanted
/// specific force's magnitude (ours). Upside down, thrust adds to the fall: the level hold's 2–3 g
/// on a craft on its back accelerates it down at 3–4 g while it turns over (seed 280 of the random
/// world in wind: engaged 104° from up at 5.5 m, falling at 1.6 m/s, it reached 8 m/s before it was
/// level and hit the ground). Less thrust costs turning authority (a quad's differential thrust
/// is bounded by its collective): with none, a slow octorotor turned too slowly (seed 694 of the
/// same world hit the ground); a quarter and a half both saved it.
pub const INVERTED_THRUST_FRACTION: f32 = 0.25;

/// Natural frequency of angle mode's tilt reference, rad/s (ours): a stick step is followed by
/// a critically damped second-order reference, its rate and acceleration fed forward; at
/// 15 rad/s it is within 10 % of the step after 0.26 s (3.9/ω) and within 1 % after 0.44 s.
pub const STICK_TILT_RAD_S: f32 = 15.0;

/// The lag the attitude loop is told to expect of a stick's tilt, in motor time constants
/// (ours): the motors' own, and as much again for the rate loop and the filters.
pub const STICK_TILT_LAG_TAUS: f32 = 1.0;

/// The lead of the square-root tilt law, in motor time constants (ours, from the test
/// `a_slow_craft_rights_itself_much_faster_overshooting_less_than_8_degrees`).
pub const TILT_LAG_TAUS: f32 = 2.0;

/// Time constant of the measured thrust direction, s (ours): long against the attitude loop, so
/// the trim is a slow correction of the model and not a loop of its own. Used outside a position
/// hold: in a recovery, the level hold, angle mode and a landing's ground contact.
pub const THRUST_DIRECTION_TIME_S: f32 = 0.5;

/// Time constant of the measured thrust direction while holding a position, s (ours): the
/// direction the accelerometer measures is that of the thrust *and the drag*, so pointing it
/// along the wanted specific force feeds a gust's drag back within this time instead of leaving
/// it to the position loop (whose static error for a push `Δa` is `Δa / (k_velocity k_position)`,
/// 0.5 m for the turbulence of an 8 m/s wind). 1,000 random worlds in a 0–8 m/s wind with
/// turbulence (`fly --end land monte-carlo --world random --wind`): held within 0.3 m 858 at
/// 0.5 s, 881 at 0.25 s, 894 at 0.1 s; at 0.1 s everywhere, a few recoveries that circle on a
/// poor model did not settle (seed 846 of the calm random world hit the ground), hence only in
/// the hold, where the craft is steady: 897 at 0.1 s, 899 at 0.05 s (no gain worth the
/// accelerometer's vibration passed on faster).
pub const THRUST_DIRECTION_HOLD_TIME_S: f32 = 0.1;

/// Largest angle the measured thrust direction may take from the model's axis, rad (25°, ours):
/// beyond that the model is wrong in a way a trim should not hide. The direction measured is
/// that of the thrust and the drag, so the cone must hold the drag of the strongest wind the
/// hold is made for: the simulator's draggiest airframe per kilogram leans 16.5° from its thrust
/// in an 8 m/s wind (2.9 m/s² of drag), and turbulence of 20 % of the wind moves the drag by 40 %
/// (22°); the thrust axis learned may be a few degrees off besides. At 15° the trim was held at
/// the cone in strong wind: 1,000 random worlds in a 0–8 m/s wind with turbulence (`fly --end
/// land monte-carlo --world random --wind`) held within 0.3 m 898 at 15°, 911 at 25°, 910 at
/// 35°; ended more than 2 m from where they recovered 9, 1, 1; calm air and GNSS the same at 15°
/// and 25° (held 982 and 982; GNSS within 1 m 979 and 979).
pub const THRUST_DIRECTION_MAX_RAD: f32 = 25.0 * core::f32::consts::PI / 180.0;

/// Closing rate, as a fraction of the tilt-rate setpoint, from which the craft counts as following
/// the square-root curve and gets its full deceleration feed-forward; below it the feed-forward
/// shrinks in proportion (ours). Without this, a craft that turned slowly towards a wanted
/// direction that moved with it (the velocity loop of the level hold, circling) was told to
/// decelerate as hard as the rate loop pushed it on: it stayed 31° off for 10 s (Monte Carlo
/// seed 25). 1,000 throws (`fly monte-carlo --runs 1000`): held 89.4 → 91.6 %, never hovered
/// 0.9 → 0.1 %, release to hover median 2.44 → 2.41 s; at 1.0 (full feed-forward only at the
/// setpoint's rate) 92.0 % held, but the motors' lag keeps a decelerating craft below its
/// setpoint and the righting from 150° overshoots 10° (test below) instead of 6°.
pub const FOLLOWING_FRACTION: f32 = 0.5;

/// The noise a position hold's velocity loop may make of its velocity estimate's noise, m/s²
/// (one standard deviation; ours): 0.15 m/s² is 0.9° of tilt. The loop's gain turns the
/// estimate's noise into the acceleration it asks for; a receiver's 0.15 m/s of velocity noise
/// leaves 0.1 m/s in the estimate (`crate::navigation::velocity_estimate_noise_mps`), which the
/// 4 m/s² per m/s of a 15 ms motor flew as body rates of 34 °/s RMS where the same craft on
/// motion capture flies at 1.5 °/s (seed 157 of the random receiver world; 16 °/s with the bound).
/// 1,000 random receiver worlds (`fly --gnss --end land monte-carlo --world random
/// --gnss-random`; receivers of 0.02–0.2 m/s):
///
/// | bound, m/s² | held within the receiver's bound | never hovered | heading within 10° at the end |
/// |---|---|---|---|
/// | none | 866 | 32 | 908 |
/// | 0.2 | 882 | 14 | 903 |
/// | 0.15 | 887 | 3 | 887 |
/// | 0.1 | 880 | 2 | 872 |
///
/// A quieter hold moves less, and the heading alignment, which keeps learning from the hold's
/// accelerations, learns a little less: hence not lower. Motion capture (no velocity fixes) is
/// not bound.
pub const HOLD_VELOCITY_NOISE_ACCEL_MPS2: f32 = 0.15;

/// The largest velocity-loop gain for a velocity estimate with `noise_mps` of noise (one
/// standard deviation per axis), 1/s: [`HOLD_VELOCITY_NOISE_ACCEL_MPS2`] / noise; infinite
/// (no bound) for a noise that is not finite and positive.
pub fn max_velocity_gain(noise_mps: f32) -> f32 {
    if noise_mps.is_finite() && noise_mps > 0.0 {
        HOLD_VELOCITY_NOISE_ACCEL_MPS2 / noise_mps
    } else {
        f32::INFINITY
    }
}

/// Smallest specific force the thrust direction is measured from, m/s² (half a g: thrust, not the
/// excitation's pulses or free fall).
const THRUST_DIRECTION_MIN_FORCE_MPS2: f32 = 0.5 * STANDARD_GRAVITY_MPS2;

/// Largest rate the thrust direction is measured at, rad/s (rotation adds no specific force at
/// the CoG, but a tumble is no time to trust a low-passed direction).
const THRUST_DIRECTION_MAX_RATE_RAD_S: f32 = 1.0;

/// The direction the motors really push along, measured (ours).
///
/// The specific force at the centre of gravity is the thrust (plus a drag that is small at hover
/// speeds) divided by the mass, whatever the craft's acceleration: its direction in the thrust
/// frame is where the motors push, measured. The learned thrust axis is only as good as G1 after
/// half a second of excitation; a few degrees off, and a craft "level" in the thrust frame
/// accelerates sideways at `g·sin(error)` (1.5 m/s² for 9°, seen on the tilted hex) until the
/// position loop's slow integral catches up. Pointing the *measured* direction along the wanted
/// specific force removes that error at its source. Low-passed over
/// [`THRUST_DIRECTION_TIME_S`] ([`THRUST_DIRECTION_HOLD_TIME_S`] in a position hold, where it
/// also feeds the drag of a gust back), only from thrusting, slowly turning samples, within
/// [`THRUST_DIRECTION_MAX_RAD`] of the model's axis.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ThrustDirection {
    /// The craft's "down" as the motors push it: −(specific force direction), thrust frame.
    down: Vector3<f32>,
}

impl Default for ThrustDirection {
    fn default() -> Self {
        Self { down: Vector3::z() }
    }
}

impl ThrustDirection {
    /// One step with the filtered specific force at the CoG and the rate (thrust frame).
    pub fn update(
        &mut self,
        specific_force_mps2: &Vector3<f32>,
        rate_rad_s: &Vector3<f32>,
        time_s: f32,
        dt_s: f32,
    ) {
        let force = crate::math::norm(specific_force_mps2);
        let usable = force > THRUST_DIRECTION_MIN_FORCE_MPS2
            && crate::math::norm(rate_rad_s) < THRUST_DIRECTION_MAX_RATE_RAD_S
            && force.is_finite()
            && dt_s > 0.0;
        if !usable {
            return;
        }
        let measured = -specific_force_mps2 / force;
        let blended = self.down + (measured - self.down) * (dt_s / time_s).min(1.0);
        let Some(down) = crate::math::try_normalize(&blended, 1e-6) else { return };
        // Within the cone about the model's axis.
        let angle = libm::acosf(down.z.clamp(-1.0, 1.0));
        self.down = if angle > THRUST_DIRECTION_MAX_RAD {
            let side = crate::math::normalize(&Vector3::new(down.x, down.y, 0.0));
            let (sin, cos) = crate::math::sin_cos(THRUST_DIRECTION_MAX_RAD);
            side * sin + Vector3::z() * cos
        } else {
            down
        };
    }

    /// The craft's "down" as the motors push it (unit, thrust frame; (0, 0, 1) on the model).
    pub fn down(&self) -> Vector3<f32> {
        self.down
    }
}

/// Time constant of the hold's disturbance estimate, s (ours): the accelerometer's vibration and
/// the attitude model's error are passed on as tilt faster than this. 300 random worlds in a
/// 0–8 m/s wind with turbulence (`fly --end land monte-carlo --world random --wind --runs 300`;
/// without the estimate 286 held within 0.3 m): 0.1 s with the whole estimate fed forward held
/// 280 (body rate in the hold 3.4 → 4.1 °/s RMS, the 45–60 ms motors 48 → 40 of 54); 0.2 s with
/// half of it ([`DISTURBANCE_FEED_FORWARD_FRACTION`]) 290 (3.6 °/s).
pub const DISTURBANCE_TIME_S: f32 = 0.2;

/// The share of the disturbance estimate fed forward (ours, measured with
/// [`DISTURBANCE_TIME_S`]): the attitude loop's model is two first-order lags, and what it gets
/// wrong of the loop's response is fed back through the estimate as a loop of its own.
pub const DISTURBANCE_FEED_FORWARD_FRACTION: f32 = 0.5;

/// Largest horizontal disturbance the hold's estimate holds, m/s² (ours): the drag of the
/// strongest wind the hold is made for (the simulator's draggiest airframe per kilogram meets
/// 2.9 m/s² in an 8 m/s wind). The estimate holds only the part of a push the measured thrust
/// direction has not yet taken up, a fraction of that; the bound is what a wrong model or a
/// hand not yet detected can make of it.
pub const DISTURBANCE_MAX_MPS2: f32 = 3.0;

/// The hold's disturbance estimate (ours): the horizontal specific force measured (thrust and
/// drag, world) against the one the attitude loop was asked for, delayed by that loop's lags.
///
/// The measured thrust direction ([`ThrustDirection`]) already points thrust *and drag* along
/// the wanted specific force, so a steady wind needs nothing more; but it acts through the
/// attitude loop, and what that loop has not yet turned away of a gust's drag (a high-pass at
/// about `k_attitude`: 16–45 % of the push of turbulence correlated over 1–3 s for a 60 ms motor
/// on the published `k_attitude` of 2 /s; the hold's is 3.6 /s) reaches the position loop, whose static error for it is `Δa / (k_velocity k_position)`. The measured force minus
/// the command passed through the rate loop's lag `1/k_rate` and the attitude loop's
/// `1/k_attitude` is that part, whatever the command did: fed forward with the opposite sign
/// ([`DISTURBANCE_FEED_FORWARD_FRACTION`] of it), the attitude loop starts turning it away at
/// once instead of after the trim's own lag. The estimate is low-passed over
/// [`DISTURBANCE_TIME_S`], is zero in steady flight (the trim has taken the drag up: no integral
/// fights it) and is bounded by [`DISTURBANCE_MAX_MPS2`]. Only in a position hold without an
/// unexplained torque (a hand is no drag to lean into); elsewhere it decays.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DisturbanceEstimate {
    /// The horizontal specific force the attitude loop is expected to have produced, world
    /// north and east, m/s².
    expected: [f32; 2],
    /// The disturbance not yet taken up, world north and east, m/s².
    residual: [f32; 2],
    /// The command after the rate loop's lag, world north and east, m/s².
    first: [f32; 2],
}

impl DisturbanceEstimate {
    /// One step with the measured horizontal specific force (world north and east, m/s²); returns
    /// the acceleration to add to the wanted specific force, m/s² (north, east).
    fn feed_forward(&mut self, measured: [f32; 2], active: bool, dt_s: f32) -> [f32; 2] {
        let alpha = (dt_s / DISTURBANCE_TIME_S).min(1.0);
        for ((estimate, measured), expected) in
            self.residual.iter_mut().zip(measured).zip(self.expected)
        {
            let residual = if active { measured - expected } else { 0.0 };
            *estimate += (residual - *estimate) * alpha;
        }
        let norm = crate::math::hypot(self.residual[0], self.residual[1]);
        if norm > DISTURBANCE_MAX_MPS2 {
            let scale = DISTURBANCE_MAX_MPS2 / norm;
            self.residual = [self.residual[0] * scale, self.residual[1] * scale];
        }
        let gain = DISTURBANCE_FEED_FORWARD_FRACTION;
        [-self.residual[0] * gain, -self.residual[1] * gain]
    }

    /// The command of this step (world north and east, m/s²) into the model of the attitude
    /// loop: the lag `second_s` (the rate loop's), then `lag_s` (the attitude loop's), s.
    fn commanded(&mut self, command: [f32; 2], lag_s: f32, second_s: f32, dt_s: f32) {
        let alpha = (dt_s / lag_s).min(1.0);
        let beta = if second_s > 0.0 { (dt_s / second_s).min(1.0) } else { 1.0 };
        for ((first, expected), command) in
            self.first.iter_mut().zip(self.expected.iter_mut()).zip(command)
        {
            *first += (command - *first) * beta;
            *expected += (*first - *expected) * alpha;
        }
    }
}

/// What the attitude loop asks of the rate loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttitudeCommand {
    /// Rate setpoint, thrust frame, rad/s.
    pub rate_sp_rad_s: Vector3<f32>,
    /// Feed-forward angular acceleration along the planned tilt deceleration, thrust frame,
    /// rad/s².
    pub accel_ff_rad_s2: Vector3<f32>,
    /// Angle between the thrust axis and the wanted one, rad.
    pub tilt_error_rad: f32,
    /// Thrust, the thrust-frame z of the specific force asked, m/s² (positive): the wanted
    /// specific force's magnitude times the cosine of the measured thrust direction's angle from
    /// the thrust axis ([`ThrustDirection`]).
    pub thrust_mps2: f32,
}

/// What the craft is asked to do.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Guidance {
    /// Hold a position (world NED, m) and heading (rad) from external position fixes. With
    /// `vertical_speed_mps` the height is not held: the craft moves vertically at that speed
    /// (world NED, m/s, positive down: a landing's descent) while it holds the horizontal
    /// position.
    Position { position_ned_m: Vector3<f32>, yaw_rad: f32, vertical_speed_mps: Option<f32> },
    /// No position: thrust axis up, the velocity `velocity_ned_mps` (an estimate, from the fixes
    /// or by dead reckoning, world NED, m/s) brought to zero horizontally and to
    /// `vertical_speed_mps` vertically (positive down; 0 holds the height), heading `yaw_rad`;
    /// the upward specific force at most `max_up_mps2` (`f32::INFINITY`: no cap; a landing's
    /// spool-down on the ground lowers it, whatever a drifting estimate asks).
    Level {
        yaw_rad: f32,
        velocity_ned_mps: Vector3<f32>,
        vertical_speed_mps: f32,
        max_up_mps2: f32,
    },
    /// The pilot's angle mode: the thrust axis tilted `forward_rad` and `right_rad` from up in
    /// the frame of the heading `yaw_rad` (forward: nose down, the craft accelerates forward),
    /// the vertical speed brought to `vertical_speed_mps` (positive down) on the estimate
    /// `velocity_ned_mps`'s z, as the level hold does. Nothing holds the horizontal speed: the
    /// pilot does.
    Tilt {
        forward_rad: f32,
        right_rad: f32,
        yaw_rad: f32,
        velocity_ned_mps: Vector3<f32>,
        vertical_speed_mps: f32,
    },
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
    /// A torque the learned model does not explain acts on the body beyond what a free body
    /// meets (the hand-catch detector's sign, `firmware::app::catch`: a hand, a damaged
    /// propeller). The measured thrust direction then follows the specific force at
    /// [`THRUST_DIRECTION_TIME_S`] even in a hold: what tilts the craft then is not a drag to lean
    /// into, and a hand's tilt taken up within [`THRUST_DIRECTION_HOLD_TIME_S`] left the rate loop
    /// nothing to ask, so the hand went unnoticed.
    pub unexplained_torque: bool,
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
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct Controller {
    indi: Indi,
    gains: Gains,
    position: PositionController,
    rate_hz: f32,
    /// Deceleration the square-root tilt law plans with, rad/s².
    tilt_decel_rad_s2: f32,
    thrust_direction: ThrustDirection,
    disturbance: DisturbanceEstimate,
    /// The bounds on the hold's position and velocity loops, 1/s ([`Self::cap_position_gain`],
    /// [`Self::cap_hold_velocity_gain`]; infinite: none).
    hold_bounds: [f32; 2],
    /// Angle mode's tilt reference, forward and right: angles (rad) and rates (rad/s); `None`
    /// outside angle mode.
    stick_tilt: Option<[(f32, f32); 2]>,
}

impl Controller {
    /// A controller flying `model` with the IMU `r_imu_m` from the CoG (IMU axes, m).
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn new(model: IndiModel, r_imu_m: [f32; 3], config: IndiConfig) -> Result<Self, IndiError> {
        let tau_max = model.motor[..model.motors].iter().map(|m| m.tau_s).fold(0.0, f32::max);
        // The rate loop at most RATE_TO_INNER_MODE of INDI's own mode: fast motors (τ below about
        // 26 ms at 15 Hz) take the gains of a slower one.
        let tau_gains = crate::indi::inner_mode_rad_s(tau_max, config.sync_cutoff_hz)
            .map_or(tau_max, |mode| {
                tau_max.max(crate::position::tau_for_rate_gain(RATE_TO_INNER_MODE * mode))
            });
        let gains = Gains::from_tau(tau_gains);
        let tilt_decel_rad_s2 = TILT_DECELERATION_FRACTION * tilt_authority_rad_s2(&model);
        Ok(Self {
            tilt_decel_rad_s2,
            thrust_direction: ThrustDirection::default(),
            disturbance: DisturbanceEstimate::default(),
            hold_bounds: [f32::INFINITY; 2],
            stick_tilt: None,
            indi: Indi::new(model, r_imu_m, config)?,
            position: PositionController::new(gains.for_hold()),
            gains,
            rate_hz: config.rate_hz,
        })
    }

    /// Lower the position hold's position-loop gain to at most `k_position_max` (1/s: m/s per
    /// m): with noisy fixes (GNSS) a position loop faster than the estimator's trust in them
    /// (`crate::navigation::position_crossover`) only turns their noise into tilt. The loops
    /// inside it follow ([`Gains::for_hold_within`]). A bound that is not finite and positive,
    /// or above the gain, changes nothing; bounds set before stay.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn cap_position_gain(&mut self, k_position_max: f32) {
        if k_position_max.is_finite() && k_position_max > 0.0 {
            self.hold_bounds[0] = self.hold_bounds[0].min(k_position_max);
            self.form_hold();
        }
    }

    /// Lower the position hold's velocity-loop gain to at most `k_velocity_max` (1/s: m/s² per
    /// m/s), the loops around and inside it with it ([`Gains::for_hold_within`]): with a noisy
    /// velocity (GNSS) a velocity loop faster than [`max_velocity_gain`] turns the estimate's
    /// noise into tilt. The level hold keeps its gain: before the heading is known it must stop
    /// the drift a tumble's tilt error leaves, and softened as well (to half the velocity
    /// crossover) it let 31 of 1,000 random receiver worlds end more than 10 m from where they
    /// recovered instead of 14 (`fly --gnss --end land monte-carlo --world random
    /// --gnss-random`). A bound that is not finite and positive, or above the gain, changes
    /// nothing; bounds set before stay.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn cap_hold_velocity_gain(&mut self, k_velocity_max: f32) {
        if k_velocity_max.is_finite() && k_velocity_max > 0.0 {
            self.hold_bounds[1] = self.hold_bounds[1].min(k_velocity_max);
            self.form_hold();
        }
    }

    /// The hold's position controller on the attitude loops' gains within the bounds set, in
    /// whatever order they were set.
    fn form_hold(&mut self) {
        let [k_position_max, k_velocity_max] = self.hold_bounds;
        let gains = self.gains.for_hold_within(k_position_max, k_velocity_max);
        if let Ok(position) = PositionController::with_limits(gains, *self.position.limits()) {
            self.position = position;
        }
    }

    /// The position hold's gains (the velocity and position loops'; [`Self::gains`] are the
    /// attitude loops' and the level hold's).
    pub fn hold_gains(&self) -> &Gains {
        self.position.gains()
    }

    /// The handover from the excitation: prime the filters with the current sample and what the
    /// motors were last told (δ) and report (rad/s, NaN where unknown).
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn start(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        commands: &[f32; crate::learner::MAX_MOTORS],
        speeds_rad_s: &[f32; crate::learner::MAX_MOTORS],
    ) {
        self.indi.start(gyro_rad_s, accel_mps2, commands, speeds_rad_s);
        self.position.reset();
        self.thrust_direction = ThrustDirection::default();
        self.disturbance = DisturbanceEstimate::default();
        self.stick_tilt = None;
    }

    /// The direction the motors are measured to push along, thrust frame (unit).
    pub fn thrust_direction(&self) -> Vector3<f32> {
        -self.thrust_direction.down()
    }

    /// The gains in use.
    pub fn gains(&self) -> &Gains {
        &self.gains
    }

    /// The IMU's offset from the CoG from the next step on ([`Indi::set_imu_offset`]).
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn set_imu_offset(&mut self, r_imu_m: [f32; 3]) -> bool {
        self.indi.set_imu_offset(r_imu_m)
    }

    /// Move the flown G1 and G2 a fraction `gain` towards `learned` (the in-flight refinement,
    /// [`IndiModel::refine_effectiveness`]). Returns whether it did.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn refine_effectiveness(&mut self, learned: &LearnedModel, gain: f32) -> bool {
        self.indi.refine_effectiveness(learned, gain)
    }

    /// The INDI loop (its model and filtered state).
    pub fn indi(&self) -> &Indi {
        &self.indi
    }

    /// The position controller's specific force for `setpoint` (hover's when it refuses the
    /// input: a non-finite estimate).
    fn position_force(
        &mut self,
        nav: &NavigationState,
        setpoint: &PositionSetpoint,
        dt_s: f32,
    ) -> Vector3<f32> {
        self.position
            .update(&nav.position_ned_m, &nav.velocity_ned_mps, setpoint, dt_s)
            .unwrap_or(Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2))
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
        // Angle mode's tilt rate and acceleration, fed forward (heading frame: forward, right).
        let mut tilt_ff = [(0.0, 0.0); 2];
        if !matches!(guidance, Guidance::Tilt { .. }) {
            self.stick_tilt = None;
        }
        let (f_sp, yaw_sp) = match *guidance {
            Guidance::Position { position_ned_m, yaw_rad, vertical_speed_mps } => {
                // A vertical speed replaces the height: the setpoint sits at the craft's own
                // height, so only the feed-forward speed acts vertically.
                let setpoint = match vertical_speed_mps {
                    Some(speed) => PositionSetpoint {
                        position_ned_m: Vector3::new(
                            position_ned_m.x,
                            position_ned_m.y,
                            nav.position_ned_m.z,
                        ),
                        velocity_ned_mps: Vector3::new(0.0, 0.0, speed),
                    },
                    None => PositionSetpoint { position_ned_m, velocity_ned_mps: Vector3::zeros() },
                };
                let f = self.position_force(nav, &setpoint, dt_s);
                // INDI drives the *measured* specific force to its setpoint; the accelerometer
                // reads the true one plus the bias the navigation learned from the fixes (its
                // offset, its scale and cross-axis errors at 1 g: 3 % of g is 0.3 m/s², and the
                // attitude filter's tilt error). Asking for the bias on top makes the true force
                // the one the position loop wants, instead of leaving the loop's slow integral
                // to find it (a 0.3 m sag for 5-10 s). Horizontally the estimate follows the
                // attitude filter's tilt corrections with a lag, so early in a hold it moves the
                // craft a little (0.12 m for the seed paper's quad, tests/tests/faults.rs); over
                // 1,000 random airframes the hold is better with it (held 96.5 % → 98.9 %).
                (f + nav.accel_bias_ned_mps2, yaw_rad)
            }
            Guidance::Level { yaw_rad, velocity_ned_mps, vertical_speed_mps, max_up_mps2 } => (
                level_specific_force(
                    &velocity_ned_mps,
                    vertical_speed_mps,
                    max_up_mps2,
                    &self.gains,
                ),
                yaw_rad,
            ),
            Guidance::Tilt {
                forward_rad,
                right_rad,
                yaw_rad,
                velocity_ned_mps,
                vertical_speed_mps,
            } => {
                // The vertical as the level hold flies it; the horizontal part of the specific
                // force is the tilt's, at that vertical force.
                let error = velocity_ned_mps.z - vertical_speed_mps;
                let accel_z = crate::math::clamp(
                    -error * self.gains.k_rate,
                    -LEVEL_MAX_VERTICAL_ACCEL_MPS2,
                    LEVEL_MAX_VERTICAL_ACCEL_MPS2,
                );
                let up = (STANDARD_GRAVITY_MPS2 - accel_z)
                    .max(crate::position::MIN_UP_FRACTION * STANDARD_GRAVITY_MPS2);
                let tan = |angle: f32| {
                    let (sin, cos) = crate::math::sin_cos(angle);
                    sin / cos
                };
                // The stick followed by a critically damped reference of natural frequency
                // STICK_TILT_RAD_S, whose rate and acceleration are fed forward: the tilt follows
                // the stick within the motors' lag rather than the attitude loop's (a quarter
                // second for a 30 ms motor), without overshoot.
                let [(angle_f, angle_r), (rate_f, rate_r)] =
                    self.stick_tilt.unwrap_or([(0.0, 0.0); 2]);
                let w = STICK_TILT_RAD_S;
                let accel =
                    |target: f32, angle: f32, rate: f32| w * w * (target - angle) - 2.0 * w * rate;
                let (accel_f, accel_r) =
                    (accel(forward_rad, angle_f, rate_f), accel(right_rad, angle_r, rate_r));
                let (rate_f, rate_r) = (rate_f + accel_f * dt_s, rate_r + accel_r * dt_s);
                let (forward_rad, right_rad) = (angle_f + rate_f * dt_s, angle_r + rate_r * dt_s);
                self.stick_tilt = Some([(forward_rad, right_rad), (rate_f, rate_r)]);
                tilt_ff = [(rate_f, rate_r), (accel_f, accel_r)];
                // The attitude loop is held to where the craft can be: the reference as it was
                // the motors' and loops' lag ago, so it does not push on top of the feed-forward.
                let lag_s = STICK_TILT_LAG_TAUS * self.gains.tau_s;
                let (forward_rad, right_rad) =
                    (forward_rad - rate_f * lag_s, right_rad - rate_r * lag_s);
                let (forward, right) = (tan(forward_rad) * up, tan(right_rad) * up);
                let (sin, cos) = crate::math::sin_cos(yaw_rad);
                let f = Vector3::new(cos * forward - sin * right, sin * forward + cos * right, -up);
                (f, yaw_rad)
            }
        };
        let to_thrust = self.indi.model().q_imu_thrust.inverse();
        let rate = to_thrust * Vector3::from(input.gyro_rad_s);
        let holding = matches!(guidance, Guidance::Position { .. });
        let trim_time_s = if holding && !input.unexplained_torque {
            THRUST_DIRECTION_HOLD_TIME_S
        } else {
            THRUST_DIRECTION_TIME_S
        };
        let specific_force = self.indi.state().specific_force_mps2;
        self.thrust_direction.update(&specific_force, &rate, trim_time_s, dt_s);
        let measured = q_world_thrust * specific_force;
        let push = self.disturbance.feed_forward(
            [measured.x, measured.y],
            holding && !input.unexplained_torque,
            dt_s,
        );
        let f_sp = Vector3::new(f_sp.x + push[0], f_sp.y + push[1], f_sp.z);
        // A hold turns with its own, faster attitude loop (`Gains::for_hold`).
        let attitude_gains = if holding {
            Gains { k_attitude: self.position.gains().k_attitude, ..self.gains }
        } else {
            self.gains
        };
        let lag_s = 1.0 / attitude_gains.k_attitude;
        let second_s = 1.0 / self.gains.k_rate;
        self.disturbance.commanded([f_sp.x, f_sp.y], lag_s, second_s, dt_s);
        let command = attitude_loop(
            &q_world_thrust,
            &self.thrust_direction.down(),
            &rate,
            &f_sp,
            yaw_sp,
            &attitude_gains,
            self.tilt_decel_rad_s2,
            holding,
        );
        // Leaning forward is a negative rotation about the thrust frame's y (its nose goes
        // down), leaning right a positive one about x.
        let [(rate_f, rate_r), (accel_f, accel_r)] = tilt_ff;
        let rate_ff = Vector3::new(rate_r, -rate_f, 0.0);
        let accel_ff = Vector3::new(accel_r, -accel_f, 0.0);
        let (rate_sp, tilt_error_rad) = (command.rate_sp_rad_s + rate_ff, command.tilt_error_rad);
        let accel_sp = (rate_sp - rate) * self.gains.k_rate + command.accel_ff_rad_s2 + accel_ff;
        let accel_sp = ahead_of_yaw(&accel_sp, rate.z, TILT_LAG_TAUS * self.gains.tau_s);
        let reference = IndiReference {
            specific_force_z_mps2: -command.thrust_mps2,
            angular_accel_rad_s2: accel_sp,
        };
        let indi = *self.indi.update(input.gyro_rad_s, input.accel_mps2, &reference)?;
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

/// The level hold's wanted specific force, world NED, m/s²: the velocity `velocity_ned_mps`
/// (world NED, m/s) brought to zero horizontally and to `vertical_speed_mps` (positive down)
/// vertically, the upward specific force at most `max_up_mps2`, tilted at most
/// [`crate::position::MAX_TILT_RAD`] from vertical. The velocity loop's P alone (no integral on a
/// drifting estimate); vertically the thrust acts through the motors alone, not behind the
/// attitude loop, so the rate loop's gain (designed around the motor lag) applies there, up to
/// [`LEVEL_MAX_BRAKING_ACCEL_MPS2`] upwards and [`LEVEL_MAX_VERTICAL_ACCEL_MPS2`] downwards.
pub fn level_specific_force(
    velocity_ned_mps: &Vector3<f32>,
    vertical_speed_mps: f32,
    max_up_mps2: f32,
    gains: &Gains,
) -> Vector3<f32> {
    let velocity_error = velocity_ned_mps - Vector3::new(0.0, 0.0, vertical_speed_mps);
    let gain = Vector3::new(gains.k_velocity, gains.k_velocity, gains.k_rate);
    let mut accel = crate::position::limit_horizontal_vertical(
        &(-velocity_error.component_mul(&gain)),
        crate::position::MAX_ACCEL_MPS2,
        LEVEL_MAX_BRAKING_ACCEL_MPS2,
    );
    // Downwards no faster than a fall with the motors at idle (NED: z down).
    accel.z = accel.z.min(LEVEL_MAX_VERTICAL_ACCEL_MPS2);
    let mut f = accel - Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2);
    f.z = f.z.max(-max_up_mps2);
    crate::position::limit_tilt(&f)
}

/// A tilt demand (thrust-frame x and y of `accel_rad_s2`) turned to where the craft will point
/// once it takes effect, `lag_s` later: a craft yawing at `yaw_rate_rad_s` sees every world-fixed
/// axis turn by `−yaw_rate · lag` about its z meanwhile, so an angular acceleration demanded about
/// today's body axis would act about one `yaw_rate · lag` off (25° for a craft still spinning at
/// 320 °/s with 80 ms of motor and loop lag, cases 140 and 183 of the Monte Carlo, whose tilt
/// then oscillated into the ground). z is unchanged. 1,000 throws (`fly monte-carlo --runs
/// 1000`): ground 27 → 19, hovered 96.7 → 97.4 % with the lag of [`TILT_LAG_TAUS`] motor time
/// constants (300-run screens, ground: none 6, one τ 3, two 2, three 2, the opposite sign 16;
/// three τ on 1,000 throws: 19 as well).
pub fn ahead_of_yaw(accel_rad_s2: &Vector3<f32>, yaw_rate_rad_s: f32, lag_s: f32) -> Vector3<f32> {
    let angle = -yaw_rate_rad_s * lag_s;
    if !angle.is_finite() {
        return *accel_rad_s2;
    }
    let (sin, cos) = crate::math::sin_cos(angle);
    let a = accel_rad_s2;
    Vector3::new(cos * a.x - sin * a.y, sin * a.x + cos * a.y, a.z)
}

/// The smaller of the two tilt axes' angular-acceleration authority of `model`, rad/s²: the
/// angular acceleration about thrust-frame x (and y) from every motor at the middle of its
/// range moved to the end that helps, `½ Σ |G1_row,i| (1 − u_idle,i)`.
pub fn tilt_authority_rad_s2(model: &IndiModel) -> f32 {
    let about = |row: usize| -> f32 {
        (0..model.motors).map(|i| 0.5 * model.g1[row][i].abs() * (1.0 - model.u_idle[i])).sum()
    };
    about(3).min(about(4))
}

/// Tilt rate setpoint, rad/s, for a tilt error `error_rad` ≥ 0 closing at `closing_rad_s`:
/// `k·e` within [`LINEAR_TILT_RAD`], `k·e + √(2α(e − lead − e_lin))` beyond, where
/// `lead = closing · lag_s` is the angle the craft turns before a change of demand takes effect;
/// at most [`MAX_TILT_RATE_RAD_S`]. A non-positive or non-finite α keeps the linear law.
pub fn tilt_rate_rad_s(
    error_rad: f32,
    closing_rad_s: f32,
    k_attitude: f32,
    decel_rad_s2: f32,
    lag_s: f32,
) -> f32 {
    let linear = k_attitude * error_rad;
    let beyond = error_rad - closing_rad_s.max(0.0) * lag_s - LINEAR_TILT_RAD;
    let rate = if decel_rad_s2 > 0.0 && decel_rad_s2.is_finite() && beyond > 0.0 {
        linear + crate::math::sqrt(2.0 * decel_rad_s2 * beyond)
    } else {
        linear
    };
    rate.min(MAX_TILT_RATE_RAD_S)
}

/// The tilt rate setpoint ([`tilt_rate_rad_s`]) and the feed-forward angular acceleration along
/// it, rad/s and rad/s²: along the square-root curve its planned part falls at
/// α·(closing rate / planned rate), and the rate loop is told so it decelerates on time (in full
/// once the craft closes at [`FOLLOWING_FRACTION`] of the setpoint, less below). None at
/// the rate limit (the setpoint is flat there) or within the linear region. The lead is taken
/// over [`TILT_LAG_TAUS`] motor time constants: the motors' own lag and about as much again for
/// the rate loop and the filters (one τ overshot by 14° in the test below, two by 6°).
pub fn tilt_rate_and_feed_forward(
    error_rad: f32,
    closing_rad_s: f32,
    gains: &Gains,
    decel_rad_s2: f32,
) -> (f32, f32) {
    let lag_s = TILT_LAG_TAUS * gains.tau_s;
    let rate = tilt_rate_rad_s(error_rad, closing_rad_s, gains.k_attitude, decel_rad_s2, lag_s);
    let planned = rate - gains.k_attitude * error_rad;
    let closing = closing_rad_s.max(0.0);
    let ff = if planned > 0.0 && rate < MAX_TILT_RATE_RAD_S {
        // Only as far as the craft follows the curve (see `FOLLOWING_FRACTION`).
        let following = (closing / (FOLLOWING_FRACTION * rate)).min(1.0);
        -decel_rad_s2 * (closing / planned).min(1.0) * following
    } else {
        0.0
    };
    (rate, ff)
}

/// The attitude loop for a wanted specific force `f_sp` (world NED, m/s²) and heading
/// `yaw_sp_rad`, with the thrust frame at `q_world_thrust` turning at `rate_rad_s` (thrust frame),
/// the motors pushing the craft towards `−thrust_down_t` (unit, thrust frame; (0, 0, 1) for the
/// model's axis, see [`ThrustDirection`]), planning to decelerate large tilts at
/// `tilt_decel_rad_s2` ([`tilt_rate_rad_s`]). With `thrust_along_measured` (a position hold)
/// the thrust asked gives `|f_sp|` along the measured direction, else along the thrust axis
/// ([`INVERTED_THRUST_FRACTION`] of it while that points below the horizon).
///
/// Why only in a hold: there the vertical is the slow position loop's, and a force 1/cos θ − 1
/// too large (10 % at the cone) holds the craft off its setpoint by a static error (the random
/// world in wind climbed 0.26 m, seed 7); elsewhere the vertical is a climb-rate loop at
/// `k_rate`, stiff enough to take that up, and a recovery on a poor model is no time to take
/// thrust away. 1,000 random worlds in a 0–8 m/s wind (`fly --end land monte-carlo --world
/// random --wind`): held within 0.3 m 911 → 942 (939 with it in every phase, where a calm
/// recovery, seed 70, swung back 0.24 m further).
#[allow(clippy::too_many_arguments)]
pub fn attitude_loop(
    q_world_thrust: &UnitQuaternion<f32>,
    thrust_down_t: &Vector3<f32>,
    rate_rad_s: &Vector3<f32>,
    f_sp: &Vector3<f32>,
    yaw_sp_rad: f32,
    gains: &Gains,
    tilt_decel_rad_s2: f32,
    thrust_along_measured: bool,
) -> AttitudeCommand {
    let f_norm = crate::math::norm(f_sp);
    // The wanted thrust-frame z ("down" of the craft) in the world: opposite the specific force.
    let z_wanted_world = if f_norm > 1e-3 { -f_sp / f_norm } else { Vector3::new(0.0, 0.0, 1.0) };
    let z_wanted = q_world_thrust.inverse() * z_wanted_world;
    // Tilt: rotate the axis the motors really push along onto the wanted one.
    let axis = thrust_down_t.cross(&z_wanted);
    let sin_tilt = crate::math::norm(&axis);
    let tilt = libm::atan2f(sin_tilt, thrust_down_t.dot(&z_wanted));
    let tilt_axis = if sin_tilt > 1e-6 { axis / sin_tilt } else { Vector3::new(1.0, 0.0, 0.0) };
    let closing = rate_rad_s.dot(&tilt_axis).max(0.0);
    let (tilt_rate_sp, ff) = tilt_rate_and_feed_forward(tilt, closing, gains, tilt_decel_rad_s2);
    let mut rate_sp = tilt_axis * tilt_rate_sp;
    let accel_ff = tilt_axis * ff;
    // Yaw: the heading error once tilted onto the wanted axis.
    if tilt < YAW_CONTROL_MAX_TILT_RAD {
        let tilt_world =
            crate::attitude::shortest_rotation(&(q_world_thrust * Vector3::z()), &z_wanted_world)
                .unwrap_or_else(UnitQuaternion::identity);
        let levelled = tilt_world * q_world_thrust;
        let x = levelled * Vector3::x();
        let yaw = libm::atan2f(x.y, x.x);
        let error = wrap_pi(yaw_sp_rad - yaw);
        rate_sp.z = (gains.k_attitude * error).clamp(-MAX_YAW_RATE_RAD_S, MAX_YAW_RATE_RAD_S);
    }
    // INDI holds the thrust-frame z of the measured specific force at `−thrust`; with the motors
    // pushing along `thrust_down_t`, θ off that z, the force along it is `thrust / cos θ`, so
    // ask `|f_sp| cos θ` of z for `|f_sp|` along the wanted direction.
    // Outside a hold, the whole magnitude (module doc), but a quarter of it while the motors push
    // below the horizon (`thrust_down_t` pointing up in the world: NED z < 0).
    let thrust_mps2 = if thrust_along_measured {
        f_norm * thrust_down_t.z
    } else if (q_world_thrust * thrust_down_t).z < 0.0 {
        f_norm * INVERTED_THRUST_FRACTION
    } else {
        f_norm
    };
    AttitudeCommand {
        rate_sp_rad_s: rate_sp,
        accel_ff_rad_s2: accel_ff,
        tilt_error_rad: tilt,
        thrust_mps2,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::clamp;

    /// One tilt axis: the error `e` closes at the rate `r`, the angular acceleration follows the
    /// rate loop's demand through the motors' lag τ and saturates at the authority. Returns the
    /// time to come within 5° (s) and the worst overshoot past level (rad).
    fn right_from(error_rad: f32, tau_s: f32, authority_rad_s2: f32, shaped: bool) -> (f32, f32) {
        let gains = Gains::from_tau(tau_s);
        let decel = if shaped { TILT_DECELERATION_FRACTION * authority_rad_s2 } else { 0.0 };
        let dt = 1.0 / 2000.0;
        let (mut e, mut r, mut accel) = (error_rad, 0.0f32, 0.0f32);
        let (mut settled_s, mut overshoot) = (f32::NAN, 0.0f32);
        for step in 0..20_000 {
            let (rate_sp, ff) = tilt_rate_and_feed_forward(e.max(0.0), r, &gains, decel);
            let demand =
                clamp(gains.k_rate * (rate_sp - r) + ff, -authority_rad_s2, authority_rad_s2);
            accel += (demand - accel) * (dt / tau_s);
            r += accel * dt;
            e -= r * dt;
            overshoot = overshoot.max(-e);
            if settled_s.is_nan() && e < 5f32.to_radians() {
                settled_s = step as f32 * dt;
            }
        }
        (settled_s, overshoot)
    }

    /// Motors faster than INDI's own mode allows take the gains of slower ones: the rate gain
    /// is at most `RATE_TO_INNER_MODE` of the mode (15.7 ms motors: 14.6 /s instead of 19.7),
    /// and motors slow enough keep the published `1/(4ζ²τ)`.
    #[test]
    fn the_rate_gain_stays_below_indis_own_mode() {
        let config = IndiConfig { rate_hz: 2000.0, ..IndiConfig::default() };
        let with_tau = |tau_s: f32| {
            let mut model =
                IndiModel::from_learned(&crate::testing::models::learned_quad()).unwrap();
            for motor in &mut model.motor[..model.motors] {
                motor.tau_s = tau_s;
            }
            *Controller::new(model, [0.0; 3], config).unwrap().gains()
        };
        for tau_s in [0.0157f32, 0.02, 0.03, 0.05, 0.1] {
            let mode = crate::indi::inner_mode_rad_s(tau_s, config.sync_cutoff_hz).unwrap();
            let gains = with_tau(tau_s);
            let published = Gains::from_tau(tau_s);
            assert!(gains.k_rate <= RATE_TO_INNER_MODE * mode * 1.0001, "τ {tau_s}: {gains:?}");
            assert!(gains.k_rate <= published.k_rate, "τ {tau_s}");
            if published.k_rate <= RATE_TO_INNER_MODE * mode {
                assert_eq!(gains, published, "τ {tau_s}: slow enough, as published");
            }
        }
        let fast = with_tau(0.0157);
        assert!((fast.k_rate - 14.6).abs() < 0.3, "{fast:?}");
        assert_eq!(with_tau(0.05), Gains::from_tau(0.05));
    }

    /// A noisy velocity lowers the position hold's velocity gain to the bound and the position
    /// loop behind it to its cascade damping, and leaves the attitude loops and the level hold
    /// (which must stop a tumble's drift before the heading is known) as the motors allow.
    #[test]
    fn a_noisy_velocity_softens_the_hold_and_nothing_else() {
        let model = IndiModel::from_learned(&crate::testing::models::learned_quad()).unwrap();
        let config = IndiConfig { rate_hz: 2000.0, ..IndiConfig::default() };
        let mut controller = Controller::new(model, [0.0; 3], config).unwrap();
        let before = *controller.gains();
        assert_eq!(*controller.hold_gains(), before.for_hold());
        // A receiver's 0.15 m/s at 10 Hz, 100 ms late: 0.1 m/s in the estimate.
        let noise_mps = crate::navigation::velocity_estimate_noise_mps(0.15, 0.1, 0.1);
        let bound = max_velocity_gain(noise_mps);
        let hold_before = before.for_hold();
        assert!(bound < hold_before.k_velocity, "bound {bound}, gain {}", hold_before.k_velocity);
        assert!(
            (bound * noise_mps - HOLD_VELOCITY_NOISE_ACCEL_MPS2).abs() < 1e-6,
            "the bound makes {} m/s² of the estimate's noise",
            bound * noise_mps
        );
        controller.cap_hold_velocity_gain(bound);
        let hold = *controller.hold_gains();
        assert_eq!(hold.k_velocity, bound);
        let zeta = crate::position::ZETA_POSITION;
        assert!((hold.k_position - bound / (4.0 * zeta * zeta)).abs() < 1e-6);
        let fraction = hold.k_velocity_integral / (hold.k_velocity * hold.k_position);
        assert!((fraction - crate::position::VELOCITY_INTEGRAL_ZERO_FRACTION).abs() < 1e-6);
        assert_eq!(*controller.gains(), before, "the attitude loops and the level hold");
        // With the position loop capped too, in either order, the same hold.
        let k_position_max = 0.5 * hold.k_position;
        let mut position_first = Controller::new(model, [0.0; 3], config).unwrap();
        position_first.cap_position_gain(k_position_max);
        position_first.cap_hold_velocity_gain(bound);
        controller.cap_position_gain(k_position_max);
        assert_eq!(*position_first.hold_gains(), *controller.hold_gains());
        assert_eq!(controller.hold_gains().k_velocity, bound);
        assert_eq!(controller.hold_gains().k_position, k_position_max);
        // Nothing to bound: motion capture's velocity, a bound above the gain, bad input.
        for k in [max_velocity_gain(0.0), 2.0 * hold_before.k_velocity, f32::NAN, -1.0] {
            let mut unbound = Controller::new(model, [0.0; 3], config).unwrap();
            unbound.cap_hold_velocity_gain(k);
            assert_eq!(*unbound.hold_gains(), hold_before, "bound {k}");
        }
    }

    /// The hold's disturbance estimate feeds forward what the attitude loop's model does not
    /// explain: nothing while the measured force follows the commands through that model (a
    /// manoeuvre is no disturbance), half of a push not yet taken up within a few of its time
    /// constants, never more than its bound, and nothing once the hold ends.
    #[test]
    fn the_disturbance_estimate_feeds_forward_only_what_the_commands_do_not_explain() {
        let dt = 1.0 / 2000.0;
        let gains = Gains::from_tau(0.05);
        let (lag, second) = (1.0 / gains.k_attitude, 1.0 / gains.k_rate);
        // A craft whose horizontal force follows the commands exactly as the model has it.
        let (mut estimate, mut craft) =
            (DisturbanceEstimate::default(), DisturbanceEstimate::default());
        let mut worst = 0.0f32;
        for step in 0..20_000 {
            let t = step as f32 * dt;
            let wanted = [2.0 * libm::sinf(1.5 * t), if t > 1.0 { -1.5 } else { 0.0 }];
            let push = estimate.feed_forward(craft.expected, true, dt);
            worst = worst.max(crate::math::hypot(push[0], push[1]));
            let command = [wanted[0] + push[0], wanted[1] + push[1]];
            estimate.commanded(command, lag, second, dt);
            craft.commanded(command, lag, second, dt);
        }
        assert!(worst < 1e-4, "a manoeuvre fed forward as {worst} m/s²");
        // A push of 2 m/s² north that the trim has not taken up: half of it against it after
        // five time constants.
        let settle = (5.0 * DISTURBANCE_TIME_S / dt) as usize;
        let mut push = [0.0; 2];
        for _ in 0..settle {
            push = estimate.feed_forward([craft.expected[0] + 2.0, craft.expected[1]], true, dt);
        }
        let expected = -DISTURBANCE_FEED_FORWARD_FRACTION * 2.0;
        assert!((push[0] - expected).abs() < 0.02 * 2.0, "{push:?}");
        assert!(push[1].abs() < 1e-3, "{push:?}");
        // A push beyond any drag the hold is made for is bounded.
        for _ in 0..settle {
            push = estimate.feed_forward([craft.expected[0], craft.expected[1] - 20.0], true, dt);
        }
        let bound = DISTURBANCE_FEED_FORWARD_FRACTION * DISTURBANCE_MAX_MPS2;
        assert!(crate::math::hypot(push[0], push[1]) <= bound * 1.0001, "{push:?}");
        assert!(push[1] > 0.9 * bound, "{push:?}");
        // Out of the hold it decays, whatever is measured.
        for _ in 0..2 * settle {
            push = estimate.feed_forward([5.0, -5.0], false, dt);
        }
        assert!(crate::math::hypot(push[0], push[1]) < 1e-3 * bound, "{push:?}");
    }

    #[test]
    fn tilt_law_is_the_published_one_within_30_degrees_and_continuous_beyond() {
        let k = 2.4;
        for e in [0.0, 0.1, 0.3, LINEAR_TILT_RAD] {
            assert_eq!(tilt_rate_rad_s(e, 0.0, k, 40.0, 0.05), k * e);
        }
        let just_beyond = tilt_rate_rad_s(LINEAR_TILT_RAD + 1e-4, 0.0, k, 40.0, 0.05);
        assert!((just_beyond - k * LINEAR_TILT_RAD).abs() < 0.2, "{just_beyond}");
        // Upside down at rest: k·π + √(2·40·(π − π/6)) = 7.5 + 14.5 rad/s, capped at 800 °/s.
        let upside_down = tilt_rate_rad_s(core::f32::consts::PI, 0.0, k, 40.0, 0.05);
        assert_eq!(upside_down, MAX_TILT_RATE_RAD_S);
        // Closing at 10 rad/s with a 50 ms lag: the curve is taken 0.5 rad further on.
        let closing = tilt_rate_rad_s(1.6, 10.0, k, 40.0, 0.05);
        let expected = k * 1.6 + libm::sqrtf(2.0 * 40.0 * (1.6 - 0.5 - LINEAR_TILT_RAD));
        assert!((closing - expected).abs() < 1e-4, "{closing} vs {expected}");
        assert_eq!(tilt_rate_rad_s(2.0, 0.0, k, f32::NAN, 0.05), k * 2.0);
    }

    #[test]
    fn a_tilt_demand_is_turned_ahead_by_the_yaw_the_lag_will_bring() {
        let demand = Vector3::new(10.0, 0.0, 3.0);
        assert_eq!(ahead_of_yaw(&demand, 0.0, 0.08), demand);
        // Yawing at +5 rad/s for 80 ms: the world-fixed axis will be 0.4 rad clockwise in body
        // axes, so the demand about x moves to x cos 0.4 − y sin 0.4; z is untouched.
        let ahead = ahead_of_yaw(&demand, 5.0, 0.08);
        let expected = Vector3::new(10.0 * libm::cosf(-0.4), 10.0 * libm::sinf(-0.4), 3.0);
        assert!((ahead - expected).norm() < 1e-5, "{ahead:?}");
        assert!((ahead.norm() - demand.norm()).abs() < 1e-4, "a rotation keeps the size");
        assert_eq!(ahead_of_yaw(&demand, f32::NAN, 0.08), demand);
    }

    #[test]
    fn a_craft_turning_slowly_towards_its_target_is_pushed_not_told_to_decelerate() {
        // Monte Carlo seed 25: 31° off, closing at 0.19 rad/s against a setpoint near 2 rad/s,
        // 160 rad/s² of planned deceleration. The feed-forward must leave the rate loop's push
        // standing (it cancelled it before), and stay in full for a craft on the curve.
        let gains = Gains::from_tau(0.04);
        let (error, decel) = (31f32.to_radians(), 160.0);
        let (rate, ff) = tilt_rate_and_feed_forward(error, 0.19, &gains, decel);
        let push = gains.k_rate * (rate - 0.19);
        assert!(push + ff > 0.5 * push, "rate {rate} rad/s: push {push}, feed-forward {ff}");
        // 60° off and closing at 60 % of the setpoint: on the curve, the full deceleration.
        let (error, decel) = (60f32.to_radians(), 40.0);
        let (at_rest, _) = tilt_rate_and_feed_forward(error, 0.0, &gains, decel);
        let closing = 0.6 * at_rest;
        let (rate, ff_on_curve) = tilt_rate_and_feed_forward(error, closing, &gains, decel);
        let planned = rate - gains.k_attitude * error;
        assert!(planned > 0.0 && rate < MAX_TILT_RATE_RAD_S, "{rate} rad/s, planned {planned}");
        assert!(closing >= FOLLOWING_FRACTION * rate);
        let expected = -decel * (closing / planned).min(1.0);
        assert!((ff_on_curve - expected).abs() < 1e-3, "{ff_on_curve} vs {expected}");
    }

    #[test]
    fn a_slow_craft_rights_itself_much_faster_overshooting_less_than_8_degrees() {
        // The hex of the simulator: τ = 50 ms, about 150 rad/s² of tilt authority.
        let (linear_s, linear_overshoot) = right_from(150f32.to_radians(), 0.05, 150.0, false);
        let (shaped_s, shaped_overshoot) = right_from(150f32.to_radians(), 0.05, 150.0, true);
        // Measured: 0.52 s against 0.86 s to within 5°; overshoot 6.3° against 1.3°.
        assert!(shaped_s < 0.65 * linear_s, "shaped {shaped_s} s, linear {linear_s} s");
        assert!(
            shaped_overshoot < 8f32.to_radians(),
            "overshoot shaped {shaped_overshoot} rad, linear {linear_overshoot} rad"
        );
    }

    #[test]
    fn the_measured_thrust_direction_follows_the_specific_force_slowly_and_within_its_cone() {
        let dt = 1.0 / 2000.0;
        let g = STANDARD_GRAVITY_MPS2;
        let still = Vector3::zeros();
        // Thrust 4° off the model's axis about x: after 3 s (6 time constants) within 0.02°.
        let tilt = 4f32.to_radians();
        let force = Vector3::new(0.0, libm::sinf(tilt), -libm::cosf(tilt)) * g;
        let mut direction = ThrustDirection::default();
        for _ in 0..1000 {
            direction.update(&force, &still, THRUST_DIRECTION_TIME_S, dt);
        }
        let half_s = libm::acosf(direction.down().z);
        // After one time constant: 1 − e⁻¹ of the way.
        assert!((half_s - tilt * (1.0 - libm::expf(-1.0))).abs() < 0.05 * tilt, "{half_s}");
        for _ in 0..5000 {
            direction.update(&force, &still, THRUST_DIRECTION_TIME_S, dt);
        }
        assert!((libm::acosf(direction.down().z) - tilt).abs() < 0.02f32.to_radians());
        // Free fall, a tumble and non-finite input leave it alone.
        let before = direction;
        direction.update(&Vector3::new(0.0, 0.0, -1.0), &still, THRUST_DIRECTION_TIME_S, dt);
        direction.update(&force, &Vector3::new(3.0, 0.0, 0.0), THRUST_DIRECTION_TIME_S, dt);
        direction.update(&Vector3::new(f32::NAN, 0.0, -g), &still, THRUST_DIRECTION_TIME_S, dt);
        assert_eq!(direction, before);
        // 40° off: held at the cone.
        let far = Vector3::new(libm::sinf(0.7), 0.0, -libm::cosf(0.7)) * g;
        for _ in 0..20_000 {
            direction.update(&far, &still, THRUST_DIRECTION_TIME_S, dt);
        }
        let angle = libm::acosf(direction.down().z);
        assert!((angle - THRUST_DIRECTION_MAX_RAD).abs() < 1e-3, "{angle}");
        // In a hold it follows within its own, shorter time constant: 1 − e⁻¹ of the way
        // after one.
        let mut direction = ThrustDirection::default();
        let steps = (THRUST_DIRECTION_HOLD_TIME_S / dt) as usize;
        for _ in 0..steps {
            direction.update(&force, &still, THRUST_DIRECTION_HOLD_TIME_S, dt);
        }
        let one = libm::acosf(direction.down().z);
        assert!((one - tilt * (1.0 - libm::expf(-1.0))).abs() < 0.05 * tilt, "{one}");
    }

    /// With the measured direction of the push (thrust and drag) θ off the thrust axis, the
    /// attitude loop points that direction along the wanted specific force and asks of the
    /// thrust-frame z only its share: the force INDI then holds, `thrust / cos θ` along the
    /// measured direction, has the wanted magnitude (asking the whole magnitude of z pushed
    /// 1/cos θ − 1 too hard: 6 % at 20°, a craft in a strong wind climbing off its setpoint).
    #[test]
    fn the_thrust_asked_along_a_trimmed_direction_gives_the_wanted_force() {
        let gains = Gains::from_tau(0.03);
        let f_sp = Vector3::new(1.5, -0.8, -9.6);
        for theta_deg in [0.0f32, 5.0, 12.0, 20.0, 25.0] {
            let theta = theta_deg.to_radians();
            let down = Vector3::new(libm::sinf(theta), 0.0, libm::cosf(theta));
            let command = attitude_loop(
                &UnitQuaternion::identity(),
                &down,
                &Vector3::zeros(),
                &f_sp,
                0.0,
                &gains,
                0.0,
                true,
            );
            // INDI holds the measured force's thrust-frame z at the thrust: along `down`, that
            // force is `thrust / down.z`.
            let force_along_down = command.thrust_mps2 / down.z;
            let wanted = f_sp.norm();
            assert!((force_along_down - wanted).abs() < 1e-4 * wanted, "{theta_deg}°");
        }
    }

    /// The recovery's rules: today's, or before 2026-12-03 (the whole thrust whatever the
    /// attitude, braking at 1 g).
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Rules {
        Now,
        Before,
    }

    /// A planar craft (two motors, thrust axis `φ` from up in the x–z plane) engaged on its
    /// back while falling, flown by the level hold ([`level_specific_force`]) and the attitude
    /// loop ([`attitude_loop`]) through an ideal allocation that keeps the differential thrust
    /// first (as the WLS weights do) and motors of lag `tau_s`. Returns the height lost from the
    /// engagement until the fall has stopped, m (infinite if it has not within 3 s).
    fn height_to_stop_a_fall(
        axis_from_up_rad: f32,
        falling_mps: f32,
        thrust_to_weight: f32,
        arm_m: f32,
        tau_s: f32,
        rules: Rules,
    ) -> f32 {
        let g = STANDARD_GRAVITY_MPS2;
        let dt = 1.0 / 2000.0;
        let gains = Gains::from_tau(tau_s);
        // Per unit mass: each motor gives up to half the thrust; the inertia is that of the
        // random airframes (radius of gyration 0.6 arm), so α = (t₁ − t₂) · arm / (0.6 arm)².
        let motor_max = 0.5 * thrust_to_weight * g;
        let alpha_per_diff = arm_m / (0.36 * arm_m * arm_m);
        let tilt_decel = TILT_DECELERATION_FRACTION * 0.5 * (2.0 * motor_max) * alpha_per_diff;
        let (mut phi, mut phi_rate) = (axis_from_up_rad, 0.0f32);
        let (mut vx, mut vz, mut z) = (0.0f32, falling_mps, 0.0f32);
        let mut thrust = [0.0f32; 2];
        for _ in 0..6000 {
            let mut f_sp =
                level_specific_force(&Vector3::new(vx, 0.0, vz), 0.0, f32::INFINITY, &gains);
            if rules == Rules::Before {
                f_sp.z = f_sp.z.max(-2.0 * g);
                f_sp = crate::position::limit_tilt(&f_sp);
            }
            // The thrust frame's z (the craft's down) is (−sin φ, 0, cos φ): a rotation by −φ
            // about y, whose rate is −φ̇.
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -phi);
            let rate = Vector3::new(0.0, -phi_rate, 0.0);
            let command =
                attitude_loop(&q, &Vector3::z(), &rate, &f_sp, 0.0, &gains, tilt_decel, false);
            let accel_y =
                (command.rate_sp_rad_s.y - rate.y) * gains.k_rate + command.accel_ff_rad_s2.y;
            let diff = clamp(-accel_y / alpha_per_diff, -motor_max, motor_max);
            let asked = match rules {
                Rules::Now => command.thrust_mps2,
                Rules::Before => f_sp.norm(),
            };
            let sum = clamp(asked, diff.abs(), 2.0 * motor_max - diff.abs());
            for (t, wanted) in thrust.iter_mut().zip([0.5 * (sum + diff), 0.5 * (sum - diff)]) {
                *t += (wanted - *t) * (dt / tau_s);
            }
            let total = thrust[0] + thrust[1];
            phi_rate += (thrust[0] - thrust[1]) * alpha_per_diff * dt;
            phi += phi_rate * dt;
            vx += total * libm::sinf(phi) * dt;
            vz += (g - total * libm::cosf(phi)) * dt;
            z += vz * dt;
            if vz <= 0.0 {
                return z;
            }
        }
        f32::INFINITY
    }

    /// The lowest throw a user brings (the issue's 2.5 m apex from a hand 1.5 m up) engages
    /// 0.95 s after the release (an octorotor's 0.8 s excitation after the 0.15 s release delay)
    /// 3.7 m above the ground, falling at 2.4 m/s, in any attitude. The random world's crafts
    /// (thrust-to-weight 2.5–5, arms of 66–165 mm, motors of 15–60 ms) engaged so, falling at
    /// 3 m/s: every one engaged within 90° of up, and every one with motors of 30 ms or faster
    /// in any attitude, stops its fall with 0.5 m to spare; and in every attitude today's rules
    /// lose less height than the whole thrust upside down and a 1 g brake did (on its back, 175°
    /// from up: 3.3–8.1 m before, 1.7–4.5 m now). The large slow crafts on their backs (165 mm
    /// arms, 45–60 ms motors: 3.0–4.5 m) need more than such a throw leaves: they turn over at
    /// their motors' pace, which no thrust rule changes.
    #[test]
    fn a_craft_engaged_on_its_back_stops_its_fall_within_the_height_a_low_throw_leaves() {
        extern crate std;
        let budget_m = 3.7 - 0.5;
        for (arm_m, tau_s) in [(0.066, 0.015), (0.11, 0.03), (0.165, 0.045), (0.165, 0.06)] {
            for thrust_to_weight in [2.5f32, 3.5, 5.0] {
                for axis_deg in [0.0f32, 60.0, 90.0, 120.0, 150.0, 175.0] {
                    let lost = |rules| {
                        height_to_stop_a_fall(
                            axis_deg.to_radians(),
                            3.0,
                            thrust_to_weight,
                            arm_m,
                            tau_s,
                            rules,
                        )
                    };
                    let (now, before) = (lost(Rules::Now), lost(Rules::Before));
                    let case = std::format!(
                        "arm {arm_m} m, τ {tau_s} s, T/W {thrust_to_weight}, {axis_deg}° from up"
                    );
                    assert!(now < before, "{case}: {now:.2} m, before {before:.2} m");
                    if tau_s <= 0.03 || axis_deg <= 90.0 {
                        assert!(now < budget_m, "{case}: {now:.2} m");
                    }
                }
            }
        }
    }

    #[test]
    fn tilt_authority_is_half_the_differential_range_of_the_weaker_axis() {
        let mut model = IndiModel {
            motors: 4,
            g1: [[0.0; crate::learner::MAX_MOTORS]; 6],
            g2: [[0.0; crate::learner::MAX_MOTORS]; 3],
            motor: [crate::learner::motor_model::MotorModel::default(); crate::learner::MAX_MOTORS],
            q_imu_thrust: UnitQuaternion::identity(),
            u_idle: [0.1; crate::learner::MAX_MOTORS],
            u_hover: [0.4; crate::learner::MAX_MOTORS],
        };
        model.g1[3][..4].copy_from_slice(&[-100.0, 100.0, 100.0, -100.0]);
        model.g1[4][..4].copy_from_slice(&[80.0, 80.0, -80.0, -80.0]);
        // About y: ½ · 4 · 80 · 0.9 = 144 rad/s².
        assert!((tilt_authority_rad_s2(&model) - 144.0).abs() < 1e-3);
    }
}
