//! The hand-catch detector: a hovering craft grabbed by a hand stops its motors
//! (`Event::Landed { reason: Caught }`), a craft flying freely through a gust never does.
//!
//! **The physics.** INDI (`flight::indi`) asks the motors for the angular acceleration the rate
//! loop wants (`ν`) and measures what the body does. On a free body the motors' torque, by the
//! learned G1, shows in the measured angular acceleration; whatever else acts (a gust's torque,
//! the model's error, a damaged propeller) is the *unexplained* part, measured minus modelled,
//! and INDI cancels it within a motor time constant, so the body turns as asked again. A hand
//! that holds the craft is different: the body turns as the hand turns it, whatever the motors
//! do. The rate loop keeps asking (the hand holds the craft tilted, or away from where the
//! position loop wants it), the measured angular acceleration does not follow, and INDI winds
//! the motors up step after step: the unexplained angular acceleration grows with the motors'
//! torque, towards their authority, and the tracking error (asked minus measured) persists.
//!
//! **The test**, on the tilt axes of the thrust frame (yaw is left out: its model, the rotors'
//! reaction, is the least certain, and a hand turns a craft mostly about its tilt axes), once
//! the flight has been steady (the recovery from the throw is over) and not while landing (the
//! ground constrains the body as a hand does; the touchdown detector handles it):
//! - the unexplained angular acceleration has moved away from its slow average
//!   ([`CATCH_BASELINE_S`]) by more than the bound plus [`CATCH_MODEL_ERROR`] of the motors' own
//!   departure from theirs (a free body's unexplained part moves by the model's error times
//!   what the motors do; a held body's by all of it), and
//! - the tracking error, averaged over [`CATCH_TRACKING_S`], is above a tenth of that bound
//!   ([`CATCH_TRACKING_SHARE`]),
//!   and not decaying as a free body's does after a disturbance (at least
//!   [`CATCH_DECAY_RATIO`] of its slowly decaying peak, [`CATCH_PERSIST_S`]),
//! - all for [`CATCH_CONFIRM_S`] without a break, once the detector has watched the steady
//!   flight for [`CATCH_HOVER_S`].
//!
//! **The bound** is sized from the learned model, not from any simulator:
//! [`CATCH_TORQUE_FRACTION`] of the tilt acceleration the motors' hover thrusts make at their
//! levers (`Σ |G1_tilt,j| u_hover,j`), i.e. the angular acceleration of a force of 1 % of the
//! weight acting at the rotors' distance from the centre of gravity.
//!
//! **What it assumes of the world.**
//! - A gust is a force on a free body: its drag acts near the centre of gravity (the frame and
//!   the rotor discs are symmetric about it), so its torque stays below the bound: a drag of a
//!   tenth of the weight with its centre of pressure within a tenth of the arm's length. Where
//!   that fails (rotors far above the centre of gravity, whose drag has a lever), the body still
//!   turns as commanded: the tracking error is INDI's transient of a motor time constant, and
//!   [`CATCH_CONFIRM_S`] outlasts it. (The simulator's drag acts at the centre of gravity: it
//!   does not test that case.)
//! - The air's own moments can be far larger than the bound, and they are steady: a rotor
//!   moving edgewise through the air flaps its blades and tilts its thrust, a moment that grows
//!   with the airspeed (RotorPy's crazyflie-brushless in an 8 m/s wind: a steady unexplained
//!   57 rad/s², eleven times its bound). The baseline takes such a moment up, but it changes as
//!   the airspeed does (the craft drifting, climbing, a gust), and that change, a slow ramp
//!   INDI follows a little late, looked like a hand's wind-up: that craft's motors were stopped
//!   in the air. Such a moment grows and shrinks along its own direction (set by the airflow's
//!   bearing in the body, which turns slowly), so a free body's unexplained part may also move
//!   *along its steady level* (its average over [`CATCH_STEADY_S`], slower than the baseline's,
//!   so a hand's wind-up of a few tenths of a second hardly moves it) by
//!   [`CATCH_STEADY_SHARE`] of that level. A hand pushes in a direction of its own: across the
//!   level it is found as before, and in calm air the level is the model's error, a bound or
//!   less in most flights (1,000 random worlds: median 0.8, 90th percentile 2.2 bounds).
//! - A propeller that loses thrust makes a step in the unexplained angular acceleration, up to
//!   one motor's share of the hover torque scale (a quarter of it on a quad, far beyond the
//!   bound): INDI takes it over within its closed loop's time, so the tracking error is a
//!   transient that falls from its peak ([`CATCH_DECAY_RATIO`]). A loop that takes longer than
//!   [`CATCH_CONFIRM_S`] to do so, or rings after the loss, is taken for a hand: a stiff test
//!   loop of fixed gains did both after a quarter or half of a propeller, while the firmware's
//!   controller in the simulator flies on with half a propeller gone (`tests/tests/faults.rs`).
//! - The hand moves the craft as people do: it closes within 0.05–0.3 s, tilting it by a few
//!   degrees or pulling it away from the held position, so the controller asks for a rotation the
//!   body does not make. A hand that held the craft exactly at the attitude and place it hovered
//!   at, without moving it at all, leaves nothing the controller asks unanswered: the motors
//!   then run on until the pilot or a host disarms.
//!
//! The detector's step is a handful of multiply-adds per motor: no allocation, no panic.

use flight::filters::{BiquadCoefficients, Butterworth2x3};
use flight::indi::{IndiModel, SYNC_CUTOFF_HZ};
use nalgebra::{Vector2, Vector3};

use super::hal::MAX_MOTORS;

/// Share of the motors' tilt acceleration scale (`Σ |G1_tilt,j| u_hover,j`, the hover thrusts at
/// their levers) beyond which the unexplained angular acceleration's departure from its average
/// counts as a hand's (ours; module doc): a force of 1 % of the weight at the rotors' distance,
/// or of a tenth of it a tenth of the way out. Measured on 1,000 random worlds with strong
/// gusts (`fly monte-carlo --world random --gusts`, docs/benchmarks.md); at half this bound,
/// before [`CATCH_MODEL_ERROR`] was added, 9 of 1,000 free flights were stopped.
pub const CATCH_TORQUE_FRACTION: f32 = 0.01;

/// The tracking error's bound as a share of the unexplained angular acceleration's (ours): the
/// rate loop asks gently of a craft held a few degrees off (the flight controller's thrust
/// direction follows the measured specific force, which a hand holds at 1 g), so a hand's
/// tracking error is a few tenths of rad/s² on a craft whose bound is 2–7 rad/s²; a free body's,
/// a motor time constant after a disturbance, is the gyro's noise through the rate gain.
pub const CATCH_TRACKING_SHARE: f32 = 0.1;

/// Share of the motors' own departure from their average (the modelled angular acceleration's
/// change) that the unexplained one may reach on a free body, ours: the learned G1 is off by up
/// to 20 % (the random world's 99th percentile at the engagement, docs/benchmarks.md), so a
/// free body's unexplained part changes by at most a fifth of what the motors change; a held
/// body's by all of it (the measured motion does not follow).
pub const CATCH_MODEL_ERROR: f32 = 0.3;

/// Share of the unexplained angular acceleration's steady level (its slow average's size) that
/// it may move by along that level's direction on a free body, beyond the bound (ours; module
/// doc): the air's moments on the rotors grow with the airspeed, which turbulence or the craft's
/// own drift changes by up to a quarter within the baseline's second ([`CATCH_BASELINE_S`]):
/// turbulence of σ = 10–20 % of the wind (the random world's, and the low-altitude Dryden
/// model's), within twice its σ in most seconds. Half measured: 20 of 1,000 grabs more went
/// unnoticed (`fly --end catch monte-carlo --world random`).
pub const CATCH_STEADY_SHARE: f32 = 0.25;

/// Time constant of the unexplained angular acceleration's steady level, s (ours): the air's
/// moment follows the wind over seconds, while a hand's wind-up is over within
/// [`CATCH_CONFIRM_S`] and a few tenths: at 5 s a 0.3 s wind-up moves the level by 6 % of
/// itself, and the bound by 3 %.
pub const CATCH_STEADY_S: f32 = 5.0;

/// Time constant of the unexplained angular acceleration's slow average, s (ours): long against
/// [`CATCH_CONFIRM_S`], so a hand's wind-up stands out of it, short against a flight, so the
/// model's own error (a constant torque mismatch) and a refinement's changes do not.
pub const CATCH_BASELINE_S: f32 = 1.0;

/// Time constant over which the tracking error (asked minus measured angular acceleration) is
/// averaged, s (ours): the rate loop's demand carries the gyro's noise times its gain; 30 ms
/// keeps the wind-up's persistent error and drops the noise.
pub const CATCH_TRACKING_S: f32 = 0.03;

/// Time constant with which the tracking error's remembered peak decays, s (ours): a free
/// body's tracking error after a disturbance is a transient of INDI's closed loop (a motor time
/// constant and the filter's delay, 25–70 ms): it rises, peaks and falls below
/// [`CATCH_DECAY_RATIO`] of its peak within a few hundredths of a second. A hand's is fed by
/// the rate loop's lasting demand and falls, if at all, no faster than the loops follow the
/// held attitude (half a second and more), so it stays near its peak decaying this slowly.
pub const CATCH_PERSIST_S: f32 = 0.15;

/// Least ratio of the tracking error to its remembered peak ([`CATCH_PERSIST_S`]) for the error
/// to count as persisting (ours; see there).
pub const CATCH_DECAY_RATIO: f32 = 0.5;

/// How long the detector watches a steady flight before it decides anything, s (ours): its
/// baseline settles within [`CATCH_BASELINE_S`], and the recovery's last transients (the hold
/// starting where the craft stopped, the thrust direction and the model refined in flight)
/// within a few seconds: a hand grabs a craft that hovers.
pub const CATCH_HOVER_S: f32 = 3.0;

/// How long the signs must hold without a break before the motors stop, s (ours): INDI answers
/// a free body's disturbance within a motor time constant (10–55 ms, docs/algorithms/indi.md)
/// plus its 15 Hz filter's delay (15 ms) and the attitude loop's own response, so a tracking
/// error that lasts 0.12 s without falling from its peak is a body that does not turn (0.1 s
/// let a stiff test loop's transient after a quarter of a propeller through; 0.15 s was late
/// for a quick hand on a sluggish craft). The time from a grab to the stop is measured in
/// docs/benchmarks.md.
pub const CATCH_CONFIRM_S: f32 = 0.12;

/// What the detector follows while it watches.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct Watch {
    /// Each motor's normalised thrust, the learned first-order lag of its commands.
    u: [f32; MAX_MOTORS],
    /// The modelled angular acceleration through INDI's synchronising filter, so it compares
    /// with the measured one like for like.
    modelled: Butterworth2x3,
    /// The unexplained tilt acceleration's slow average, rad/s².
    baseline_rad_s2: Vector2<f32>,
    /// Its steady level, a slower average ([`CATCH_STEADY_S`]), rad/s².
    steady_rad_s2: Vector2<f32>,
    /// The modelled tilt acceleration's slow average, rad/s².
    modelled_baseline_rad_s2: Vector2<f32>,
    /// The tracking error's short average, rad/s².
    tracking_rad_s2: Vector2<f32>,
    /// The size of that average's peak, decaying with [`CATCH_PERSIST_S`], rad/s².
    tracking_peak_rad_s2: f32,
    /// The bound, rad/s² (module doc).
    bound_rad_s2: f32,
    /// How long both signs have held, s.
    held_s: f32,
    /// Whether the last step's unexplained departure was beyond its bound.
    departing: bool,
    /// How long it has watched, s: it decides once the baseline has settled
    /// ([`CATCH_BASELINE_S`]).
    watched_s: f32,
}

/// The hand-catch detector (module doc): fed every flying step, it says when a hand holds the
/// craft.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct CatchDetector {
    dt_s: f32,
    /// The per-step gains of the baseline's and the tracking error's averages, and the tracking
    /// peak's decay factor (constant for the step rate: computed once).
    baseline_gain: f32,
    steady_gain: f32,
    tracking_gain: f32,
    peak_decay: f32,
    sync: Option<BiquadCoefficients>,
    watch: Option<Watch>,
}

/// One step's signals, all in the thrust frame.
#[derive(Clone, Copy, Debug)]
pub struct CatchSignals<'a> {
    /// The model flown.
    pub model: &'a IndiModel,
    /// The normalised thrusts this step commanded.
    pub u: &'a [f32; MAX_MOTORS],
    /// The angular acceleration the rate loop asked of INDI, rad/s².
    pub asked_rad_s2: Vector3<f32>,
    /// The measured (filtered) angular acceleration, rad/s².
    pub measured_rad_s2: Vector3<f32>,
}

impl CatchDetector {
    /// A detector for steps at `rate_hz`, not watching.
    pub fn new(rate_hz: f32) -> Self {
        let sync = BiquadCoefficients::butterworth_lowpass(SYNC_CUTOFF_HZ, rate_hz).ok();
        let dt_s = 1.0 / rate_hz;
        Self {
            dt_s,
            baseline_gain: dt_s / (CATCH_BASELINE_S + dt_s),
            steady_gain: dt_s / (CATCH_STEADY_S + dt_s),
            tracking_gain: dt_s / (CATCH_TRACKING_S + dt_s),
            peak_decay: 1.0 - dt_s / (CATCH_PERSIST_S + dt_s),
            sync,
            watch: None,
        }
    }

    /// Whether it is watching (the flight steady, not landing, the parameter on).
    pub fn watching(&self) -> bool {
        self.watch.is_some()
    }

    /// The bound of the flight watched, rad/s² (module doc).
    pub fn bound_rad_s2(&self) -> Option<f32> {
        self.watch.map(|w| w.bound_rad_s2)
    }

    /// Whether the last step's unexplained angular acceleration departed from its average beyond
    /// the bound (module doc): a torque that the model does not explain and that a free body
    /// does not meet acts on the craft. The controller then stops taking the craft's tilt for a
    /// drag ([`flight::controller::ControllerInput::unexplained_torque`]), so a hand's tilt stays
    /// a tilt the rate loop asks back, and its tracking error persists.
    pub fn departing(&self) -> bool {
        self.watch.is_some_and(|w| w.departing)
    }

    /// Stop watching (not flying freely now); the next watched step starts afresh.
    pub fn stop(&mut self) {
        self.watch = None;
    }

    /// One step while the craft flies freely: whether a hand holds it (the motors must stop).
    pub fn update(&mut self, s: &CatchSignals<'_>) -> bool {
        let finite = s.asked_rad_s2.iter().chain(s.measured_rad_s2.iter()).all(|x| x.is_finite());
        let Some(sync) = self.sync.filter(|_| finite) else {
            return false;
        };
        let model = s.model;
        let motors = model.motors.min(MAX_MOTORS);
        let dt_s = self.dt_s;
        let watch = match &mut self.watch {
            Some(watch) => watch,
            None => {
                let mut bound_rad_s2 = 0.0;
                for j in 0..motors {
                    bound_rad_s2 +=
                        libm::hypotf(model.g1[3][j], model.g1[4][j]) * model.u_hover[j].max(0.0);
                }
                let mut modelled = Butterworth2x3::from_coefficients(sync);
                let start = modelled_accel(model, s.u);
                modelled.reset_to(&start);
                self.watch.insert(Watch {
                    u: *s.u,
                    modelled,
                    baseline_rad_s2: (s.measured_rad_s2 - start).xy(),
                    steady_rad_s2: (s.measured_rad_s2 - start).xy(),
                    modelled_baseline_rad_s2: start.xy(),
                    tracking_rad_s2: Vector2::zeros(),
                    tracking_peak_rad_s2: 0.0,
                    bound_rad_s2: CATCH_TORQUE_FRACTION * bound_rad_s2,
                    held_s: 0.0,
                    departing: false,
                    watched_s: 0.0,
                })
            }
        };
        for j in 0..motors {
            let tau_s = model.motor[j].tau_s.max(dt_s);
            let gain = dt_s / (tau_s + dt_s);
            let u = if s.u[j].is_finite() { s.u[j] } else { watch.u[j] };
            watch.u[j] += (u - watch.u[j]) * gain;
        }
        let modelled = watch.modelled.update(&modelled_accel(model, &watch.u));
        let unexplained = (s.measured_rad_s2 - modelled).xy();
        let deviation = unexplained - watch.baseline_rad_s2;
        watch.baseline_rad_s2 += deviation * self.baseline_gain;
        watch.steady_rad_s2 += (unexplained - watch.steady_rad_s2) * self.steady_gain;
        let commanded = modelled.xy() - watch.modelled_baseline_rad_s2;
        watch.modelled_baseline_rad_s2 += commanded * self.baseline_gain;
        let tracking = (s.asked_rad_s2 - s.measured_rad_s2).xy();
        watch.tracking_rad_s2 += (tracking - watch.tracking_rad_s2) * self.tracking_gain;
        let tracking_now = watch.tracking_rad_s2.norm();
        watch.tracking_peak_rad_s2 = tracking_now.max(watch.tracking_peak_rad_s2 * self.peak_decay);
        let bound = watch.bound_rad_s2;
        watch.watched_s += dt_s;
        let unexplained_bound = bound + CATCH_MODEL_ERROR * commanded.norm();
        // The departure, less what the air's steady moment may change along its own direction.
        let level = watch.steady_rad_s2.norm();
        let along = if level > 0.0 { deviation.dot(&watch.steady_rad_s2) / level } else { 0.0 };
        let across_squared = (deviation.norm_squared() - along * along).max(0.0);
        let along_beyond = (libm::fabsf(along) - CATCH_STEADY_SHARE * level).max(0.0);
        let departure_squared = across_squared + along_beyond * along_beyond;
        watch.departing = departure_squared > unexplained_bound * unexplained_bound;
        let held = watch.departing
            && tracking_now > CATCH_TRACKING_SHARE * bound
            && tracking_now >= CATCH_DECAY_RATIO * watch.tracking_peak_rad_s2;
        watch.held_s = if held { watch.held_s + dt_s } else { 0.0 };
        watch.held_s >= CATCH_CONFIRM_S && watch.watched_s >= CATCH_HOVER_S
    }
}

/// The angular acceleration the motors at normalised thrusts `u` make by the learned G1,
/// thrust frame, rad/s².
fn modelled_accel(model: &IndiModel, u: &[f32; MAX_MOTORS]) -> Vector3<f32> {
    let mut accel = Vector3::zeros();
    for j in 0..model.motors.min(MAX_MOTORS) {
        let u = if u[j].is_finite() { u[j] } else { 0.0 };
        accel += Vector3::new(model.g1[3][j], model.g1[4][j], model.g1[5][j]) * u;
    }
    accel
}

#[cfg(test)]
mod tests {
    use super::*;
    use flight::indi::{Indi, IndiConfig, IndiReference};
    use flight::navigation::STANDARD_GRAVITY_MPS2;
    use nalgebra::UnitQuaternion;

    const RATE_HZ: f32 = 2000.0;
    const DT_S: f32 = 1.0 / RATE_HZ;
    /// The tilt loop flown around INDI here: attitude and rate gains, 1/s (gentle ones: the
    /// flight controller's are at least as stiff, and a stiffer loop winds up faster).
    const K_ATTITUDE: f32 = 8.0;
    const K_RATE: f32 = 20.0;
    /// When the event (grab, gust) comes, s: after the detector's baseline
    /// has settled.
    const EVENT_S: f32 = CATCH_HOVER_S + 0.5;

    /// What acts on the body besides its motors.
    #[derive(Clone, Copy)]
    enum World {
        /// A hand grabs it at [`EVENT_S`], closing with this time constant (s) and tilting it by
        /// this much (rad, about thrust-frame x).
        Hand { tau_s: f32, tilt_rad: f32 },
        /// A torque (as an angular acceleration about x, rad/s²) rising as `1 − cos` to its peak
        /// over the duration, s.
        CosineTorque { peak_rad_s2: f32, duration_s: f32 },
        /// A torque stepping to this angular acceleration about x, rad/s².
        StepTorque { rad_s2: f32 },
        /// The air's steady moment on the rotors (blade flapping in a wind) from the start, an
        /// angular acceleration about x, rad/s², growing by `change` of itself over `over_s`
        /// from [`EVENT_S`] on (the airspeed growing as the craft drifts or a gust builds).
        AirMoment { rad_s2: f32, change: f32, over_s: f32 },
        /// The air's steady moment about y (rad/s²) until a hand grabs the craft at [`EVENT_S`]
        /// as in [`World::Hand`], tilting it about x.
        HandInWind { tau_s: f32, tilt_rad: f32, air_rad_s2: f32 },
    }

    /// The learned quad as INDI flies it, its tilt authority scaled by `size` (0.3: a large
    /// craft, slow to turn; 2.5: a small one) and hovering at `u_hover` on every motor.
    fn craft(size: f32, u_hover: f32) -> IndiModel {
        let mut model = IndiModel::from_learned(&flight::testing::models::learned_quad()).unwrap();
        for row in &mut model.g1[3..6] {
            for g in row.iter_mut() {
                *g *= size;
            }
        }
        model.u_hover = [u_hover; MAX_MOTORS];
        model
    }

    /// Flies `model` in hover for `duration_s` with the real INDI in a tilt loop, the body's
    /// true effectiveness 5 % above the model's, in `world`: the time the detector said "held",
    /// s after [`EVENT_S`], and its bound.
    fn fly(model: &IndiModel, world: World, duration_s: f32) -> (Option<f32>, f32) {
        let mut indi = Indi::new(*model, [0.0; 3], IndiConfig::default()).unwrap();
        let q_imu_thrust: UnitQuaternion<f32> = model.q_imu_thrust;
        let hover_imu = q_imu_thrust * Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2);
        let mut commands = [0.0; MAX_MOTORS];
        for (j, c) in commands.iter_mut().enumerate().take(model.motors) {
            *c = model.command_for_thrust(j, model.u_hover[j]);
        }
        indi.start([0.0; 3], hover_imu.into(), &commands, &[f32::NAN; MAX_MOTORS]);
        let mut detector = CatchDetector::new(RATE_HZ);
        let mut u_true = model.u_hover;
        let (mut tilt, mut rate) = (Vector3::<f32>::zeros(), Vector3::<f32>::zeros());
        let effectiveness = [1.05f32; MAX_MOTORS];
        // The true torque of the hover commands (the model's mismatch, a constant).
        let torque = |u: &[f32; MAX_MOTORS], effectiveness: &[f32; MAX_MOTORS]| {
            let mut accel = Vector3::zeros();
            for j in 0..model.motors {
                accel += Vector3::new(model.g1[3][j], model.g1[4][j], model.g1[5][j])
                    * (u[j] * effectiveness[j]);
            }
            accel
        };
        let trim = -torque(&u_true, &effectiveness);
        let thrust_trim =
            (0..model.motors).map(|j| model.g1[2][j] * u_true[j] * effectiveness[j]).sum::<f32>()
                + STANDARD_GRAVITY_MPS2;
        // The tilt acceleration the motors can add around the hover: a quarter of the hover
        // thrusts at their levers.
        let authority: f32 = 0.25
            * (0..model.motors)
                .map(|j| libm::hypotf(model.g1[3][j], model.g1[4][j]) * model.u_hover[j])
                .sum::<f32>();
        let mut bound = f32::NAN;
        for step in 0..(duration_s * RATE_HZ) as usize {
            let t_s = step as f32 * DT_S;
            let after_s = t_s - EVENT_S;
            let mut disturbance = Vector3::zeros();
            let mut held = None;
            match world {
                World::Hand { tau_s, tilt_rad } if after_s >= 0.0 => held = Some((tau_s, tilt_rad)),
                World::CosineTorque { peak_rad_s2, duration_s } if after_s >= 0.0 => {
                    let phase = (after_s / duration_s).min(1.0);
                    disturbance.x =
                        peak_rad_s2 * 0.5 * (1.0 - libm::cosf(core::f32::consts::TAU * phase));
                }
                World::StepTorque { rad_s2 } if after_s >= 0.0 => disturbance.x = rad_s2,
                World::HandInWind { tau_s, tilt_rad, .. } if after_s >= 0.0 => {
                    held = Some((tau_s, tilt_rad));
                }
                World::HandInWind { air_rad_s2, .. } => disturbance.y = air_rad_s2,
                World::AirMoment { rad_s2, change, over_s } => {
                    disturbance.x = rad_s2 * (1.0 + change * (after_s / over_s).clamp(0.0, 1.0));
                }
                _ => {}
            }
            let accel = match held {
                // The hand: critically damped towards its tilt, whatever the motors do.
                Some((tau_s, tilt_rad)) => {
                    let w = 1.0 / tau_s;
                    (Vector3::new(tilt_rad, 0.0, 0.0) - tilt) * (w * w) - rate * (2.0 * w)
                }
                None => torque(&u_true, &effectiveness) + trim + disturbance,
            };
            rate += accel * DT_S;
            tilt += rate * DT_S;
            let gyro = q_imu_thrust * rate;
            // Within the craft's authority, as the flight controller's rate loop asks.
            let asked =
                (((-tilt) * K_ATTITUDE - rate) * K_RATE).map(|a| a.clamp(-authority, authority));
            let reference = IndiReference {
                specific_force_z_mps2: -STANDARD_GRAVITY_MPS2,
                angular_accel_rad_s2: asked,
            };
            // The thrust acts on the free body (the hand holds the tilt axes only).
            let thrust: f32 =
                (0..model.motors).map(|j| model.g1[2][j] * u_true[j] * effectiveness[j]).sum();
            let force = q_imu_thrust * Vector3::new(0.0, 0.0, thrust - thrust_trim);
            let out = *indi.update(gyro.into(), force.into(), &reference).unwrap();
            for (j, u) in u_true.iter_mut().enumerate().take(model.motors) {
                let gain = DT_S / (model.motor[j].tau_s + DT_S);
                *u += (out.u[j] - *u) * gain;
            }
            let caught = detector.update(&CatchSignals {
                model,
                u: &out.u,
                asked_rad_s2: asked,
                measured_rad_s2: indi.state().angular_accel_rad_s2,
            });
            bound = detector.bound_rad_s2().unwrap_or(bound);
            if caught {
                return (Some(after_s), bound);
            }
        }
        (None, bound)
    }

    const SIZES: [f32; 3] = [0.3, 1.0, 2.5];
    const HOVERS: [f32; 2] = [0.25, 0.5];

    /// A hand closing in 0.05–0.15 s and tilting the craft by 5°: the motors stop within
    /// 0.3 s of the grab, on crafts from sluggish to nimble, hovering low or high on their
    /// motors.
    #[test]
    fn a_hand_that_grabs_a_hovering_craft_is_found_within_0_3_s() {
        for size in SIZES {
            for u_hover in HOVERS {
                for tau_s in [0.05, 0.1, 0.15] {
                    let world = World::Hand { tau_s, tilt_rad: 5f32.to_radians() };
                    let (found, _) = fly(&craft(size, u_hover), world, EVENT_S + 1.0);
                    let label = format!("size {size}, hover {u_hover}, τ {tau_s} s");
                    let after_s = found.unwrap_or_else(|| panic!("{label}: never found"));
                    assert!((0.0..0.3).contains(&after_s), "{label}: after {after_s} s");
                }
            }
        }
    }

    /// A free body under a torque up to the bound (the most a gust's drag makes by the module's
    /// assumption), smooth or sharp, long or short, is never held: INDI cancels it and the
    /// body turns as asked again.
    #[test]
    fn a_gust_like_torque_on_a_free_body_is_never_a_hand() {
        for size in SIZES {
            for u_hover in HOVERS {
                let model = craft(size, u_hover);
                let (_, bound) = fly(&model, World::StepTorque { rad_s2: 0.0 }, EVENT_S);
                assert!(bound > 0.0, "{bound}");
                let worlds = [
                    World::CosineTorque { peak_rad_s2: bound, duration_s: 0.5 },
                    World::CosineTorque { peak_rad_s2: -bound, duration_s: 3.0 },
                    World::StepTorque { rad_s2: bound },
                ];
                for world in worlds {
                    let (found, _) = fly(&model, world, EVENT_S + 3.5);
                    assert_eq!(found, None, "size {size}, hover {u_hover}");
                }
            }
        }
    }

    /// A craft in a strong wind, whose rotors' steady moment is many times the bound, is never
    /// held when that moment grows by up to [`CATCH_STEADY_SHARE`] of itself, however quickly
    /// (RotorPy's crazyflie-brushless in 8 m/s: eleven times its bound, growing by 14 % in about
    /// a second, had its motors stopped in the air).
    #[test]
    fn the_airs_steady_moment_changing_with_the_airspeed_is_never_a_hand() {
        for size in SIZES {
            for u_hover in HOVERS {
                let model = craft(size, u_hover);
                let (_, bound) = fly(&model, World::StepTorque { rad_s2: 0.0 }, EVENT_S);
                let share = CATCH_STEADY_SHARE;
                for (level, change, over_s) in
                    [(11.0, 0.15, 1.0), (5.0, share, 1.0), (11.0, share, 0.3)]
                {
                    let world = World::AirMoment { rad_s2: level * bound, change, over_s };
                    let (found, _) = fly(&model, world, EVENT_S + 2.0);
                    let label = format!("size {size}, hover {u_hover}, {level}× bound, {change}");
                    assert_eq!(found, None, "{label}");
                }
            }
        }
    }

    /// In a wind whose steady moment is eleven times the bound, a hand that tilts the craft
    /// across that moment is found within 0.3 s as in still air.
    #[test]
    fn a_hand_is_found_in_a_strong_wind_too() {
        for size in SIZES {
            for u_hover in HOVERS {
                let model = craft(size, u_hover);
                let (_, bound) = fly(&model, World::StepTorque { rad_s2: 0.0 }, EVENT_S);
                for tau_s in [0.05, 0.15] {
                    let tilt_rad = 5f32.to_radians();
                    let world = World::HandInWind { tau_s, tilt_rad, air_rad_s2: 11.0 * bound };
                    let (found, _) = fly(&model, world, EVENT_S + 1.0);
                    let label = format!("size {size}, hover {u_hover}, τ {tau_s} s");
                    let after_s = found.unwrap_or_else(|| panic!("{label}: never found"));
                    assert!((0.0..0.3).contains(&after_s), "{label}: after {after_s} s");
                }
            }
        }
    }

    /// Nothing is decided before the detector has watched for [`CATCH_HOVER_S`], and a stop
    /// starts afresh.
    #[test]
    fn it_decides_only_after_watching_for_the_baseline_time() {
        let model = craft(1.0, 0.4);
        let mut detector = CatchDetector::new(RATE_HZ);
        // A hand's wind-up half a second before CATCH_HOVER_S (its signs would hold long enough
        // by then): nothing is decided before CATCH_HOVER_S.
        let signals = |u: &'static [f32; MAX_MOTORS]| CatchSignals {
            model: &model,
            u,
            asked_rad_s2: Vector3::new(100.0, 0.0, 0.0),
            measured_rad_s2: Vector3::zeros(),
        };
        static HOVER: [f32; MAX_MOTORS] = [0.4; MAX_MOTORS];
        static WOUND: [f32; MAX_MOTORS] = [0.8, 0.0, 0.8, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!(!detector.update(&signals(&HOVER)));
        assert!(detector.watching());
        let mut first = None;
        let wind_up_from = ((CATCH_HOVER_S - 0.5) * RATE_HZ) as usize;
        for step in 1..((CATCH_HOVER_S + 1.0) * RATE_HZ) as usize {
            let u = if step < wind_up_from { &HOVER } else { &WOUND };
            if detector.update(&signals(u)) {
                first = Some(step as f32 * DT_S);
                break;
            }
        }
        let first = first.expect("never decided");
        assert!((CATCH_HOVER_S - 1e-3..CATCH_HOVER_S + 0.01).contains(&first), "after {first} s");
        detector.stop();
        assert!(!detector.watching());
        assert!(!detector.update(&signals(&WOUND)), "a stop starts afresh");
    }
}
