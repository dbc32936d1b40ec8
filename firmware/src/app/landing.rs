//! Landings and fly-aways: the touchdown detector that ends a landing, the fly-away detector
//! that starts one, and what both assume ([`LandConfig`], the parameters `land_descent_mps`,
//! `land_pose_lost_s`, `flyaway_speed_mps`, `flyaway_time_s`).
//!
//! Both are small state machines on what one control step measures, apart from the pilot
//! (`super::pilot`, which flies the descent and asks them), so that their cost is measured on
//! the Cortex-M7 on its own (`cargo xtask bench-m7`, which compiles this file) and their
//! behaviour tested without a flight.
//!
//! - **The touchdown** ([`Touchdown`]): no range finder, and nothing assumed of the ground's
//!   height (a pose's zero need not be the ground). The signs that must hold together for
//!   [`TOUCHDOWN_CONFIRM_S`]: the thrust well below hover ([`TOUCHDOWN_THRUST_FRACTION`]) or
//!   the ground carrying a share of the weight ([`TOUCHDOWN_CARRIED_G`]); the measured specific
//!   force near 1 g ([`TOUCHDOWN_MIN_FORCE_G`]); no tipping ([`TOUCHDOWN_MAX_RATE_RAD_S`]); with
//!   fixes, no vertical motion ([`TOUCHDOWN_MAX_SPEED_MPS`]). Without fixes an impact
//!   ([`TOUCHDOWN_IMPACT_G`]) spools the motors down ([`TOUCHDOWN_SPOOL_DOWN_S`]), called off
//!   when the craft turns out to be in the air ([`TOUCHDOWN_AIRBORNE_G`]).
//!
//!   With fixes there is a stage before it, the **ground contact** (the idea of PX4's land
//!   detector, "ground contact → maybe landed → landed"; ours): a craft that has been descending
//!   stops doing so while its loop still asks for the descent ([`TOUCHDOWN_CONTACT_SPEED_FRACTION`]
//!   of it, for [`TOUCHDOWN_CONTACT_S`]) and the measured specific force stays near 1 g. The
//!   pilot then stops holding the horizontal position (no lean, no integral: the level hold with
//!   zero horizontal velocity and the descent kept), so a craft that landed leaning against a
//!   wind sits down on all its feet instead of rocking on its upwind ones under the position
//!   loop's lean (Monte Carlo seed 32 of the random world in a 7.3 m/s wind: motors stopped
//!   7.8 s after the touchdown), and it probes: the cap on its upward force falls to
//!   [`TOUCHDOWN_CONTACT_MIN_UP_G`] over [`TOUCHDOWN_CONTACT_SPOOL_S`]. In the air the contact
//!   cannot last: the craft sinks, and a vertical speed above [`TOUCHDOWN_MAX_SPEED_MPS`] ends
//!   it (a wrong contact in a gust costs the craft a few centimetres of height and of drift
//!   downwind); on the ground it lands the craft after [`TOUCHDOWN_CONTACT_LANDED_S`] whatever
//!   its rocking.
//! - **The fly-away** ([`FlyAway`]): moving away from the setpoint faster than
//!   [`LandConfig::flyaway_speed_mps`] for longer than [`LandConfig::flyaway_time_s`] without
//!   braking.

use flight::navigation::STANDARD_GRAVITY_MPS2;
use nalgebra::Vector3;
use protocol::LandReason;

/// Default descent speed of a landing, m/s (the `land_descent_mps` parameter): ArduPilot's
/// `LAND_SPEED` below its `LAND_ALT_LOW` (0.5 m/s); PX4's `MPC_LAND_SPEED` is 0.7 m/s. A
/// landing gear's travel and a frame's arms take that without a bounce (0.5 m/s is a drop from
/// 13 mm).
pub const DEFAULT_LAND_DESCENT_MPS: f32 = 0.5;

/// Default time the pose may stay lost in a flight before the craft lands, s
/// (`land_pose_lost_s`): a motion-capture occlusion or a radio hiccup lasts a fraction of a
/// second; the level hold that replaces the position drifts a metre or more within five.
pub const DEFAULT_LAND_POSE_LOST_S: f32 = 5.0;

/// Default speed away from the setpoint that counts towards a fly-away, m/s
/// (`flyaway_speed_mps`): above the position loop's 2.5 m/s speed limit flown with its 4.6 %
/// overshoot (`flight::position::MAX_SPEED_MPS`), so no manoeuvre of our own controller reaches
/// it.
pub const DEFAULT_FLYAWAY_SPEED_MPS: f32 = 3.0;

/// Default time above [`DEFAULT_FLYAWAY_SPEED_MPS`] without braking after which a craft lands,
/// s (`flyaway_time_s`): a gust of 5 m/s pushes a hovering craft past 3 m/s for a few tenths of
/// a second at most before the velocity loop (a time constant of 0.2–0.5 s) takes it back, and
/// a craft thrown sideways tumbles for up to a second before it brakes (Monte Carlo seed 3 of
/// the random world: 5.7 m/s for 0.9 s); 2 s more at 3 m/s is 6 m.
pub const DEFAULT_FLYAWAY_TIME_S: f32 = 2.0;

/// Fall of the horizontal speed that counts as braking, m/s: a fly-away's count starts afresh
/// whenever the speed has fallen this much below its peak since the count began (a recovery
/// from a sideways throw brakes at 2–6 m/s² once its tumble is over, so by far more than this
/// within [`DEFAULT_FLYAWAY_TIME_S`]).
pub const FLYAWAY_BRAKING_MPS: f32 = 0.5;

/// Thrust below which a landing craft may be on the ground, as the fraction of the way from
/// idle to hover (ours; PX4's land detector asks for its throttle near the minimum the same
/// way, `LNDMC_LOW_T_THR`): INDI lowers the thrust for as long as the measured specific force
/// stays above the descent's, and on the ground it stays at 1 g whatever the motors do.
pub const TOUCHDOWN_THRUST_FRACTION: f32 = 0.5;

/// Smallest measured specific force along the thrust axis, as a fraction of g, at which a
/// craft whose thrust is below [`TOUCHDOWN_THRUST_FRACTION`] counts as carried by the ground
/// (ours): in the air that thrust gives at most about 0.6 g even with a model whose thrust is
/// 20 % low, so 0.8 g is the ground carrying the rest.
pub const TOUCHDOWN_MIN_FORCE_G: f32 = 0.8;

/// Share of the weight, as a fraction of g, that the ground must carry (the measured upward
/// specific force above what the commands push with by the learned model) for a landing craft
/// to count as resting even though its commands' sum is not low (ours). The model's push is
/// first scaled by the thrust measured against it in the flight before the landing
/// ([`ThrustScale`]): with speed telemetry the learned thrust is within 5–10 % after the
/// in-flight refinement, without it 20–40 % and more (docs/benchmarks.md), and a still hover on
/// a model 30 % low read as 0.3 g carried, one 40 % low as a touchdown (Monte Carlo without
/// speed telemetry, `fly --end land monte-carlo --world random --no-speed-telemetry`: 52 of
/// 1,000 landings stopped their motors in the air within 0.2 s of the landing's start).
pub const TOUCHDOWN_CARRIED_G: f32 = 0.35;

/// Time constant of the learned thrust's scale measured in flight ([`ThrustScale`]), s (ours):
/// long against the vibration and the motors' lag (tens of milliseconds), short against the
/// seconds a flight lasts before it lands.
pub const THRUST_SCALE_TIME_S: f32 = 0.5;

/// Smallest upward push, by the learned model, at which [`ThrustScale`] takes a sample, as a
/// fraction of g (ours): below it the ratio of two small numbers (motors spinning up, a fall).
pub const THRUST_SCALE_MIN_PUSH_G: f32 = 0.3;

/// Bounds of [`ThrustScale`] (dimensionless, ours): a model more than four times off in its
/// thrust flies no hover to measure it in.
pub const THRUST_SCALE_RANGE: (f32, f32) = (0.25, 4.0);

/// The thrust measured against the learned model's ([`TouchdownSigns::flown`]): the
/// upward specific force the IMU measures over the one the model says the commands push with,
/// low-passed over [`THRUST_SCALE_TIME_S`] while flying and not landing (the pilot stops it
/// when a landing begins, for the ground carries the craft then). Both sides are the thrust
/// (an accelerometer does not feel gravity), so any flight measures it, not only a hover; the
/// touchdown's two thrust signs use the model scaled by it instead of assuming its thrust right.
/// With it, the commands' sum that flew (low-passed alike) is the hover the touchdown's low mark
/// is taken from: the scale corrects the model's total thrust, not how it shares it among the
/// motors, so the model's own hover commands can sum to more than flies (Monte Carlo seed 245
/// without speed telemetry: stopped in the air at 4.3 m with the scale alone).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ThrustScale {
    /// Measured over modelled thrust; 1 before a sample.
    scale: f32,
    /// The commands' sum that flew, normalised thrust (meaningful once `sampled`; finite: a
    /// non-finite command makes the push non-finite, and no sample is taken).
    flown_u_sum: f32,
    sampled: bool,
}

impl Default for ThrustScale {
    fn default() -> Self {
        Self { scale: 1.0, flown_u_sum: 0.0, sampled: false }
    }
}

impl ThrustScale {
    /// One flying step: the commands `u` (normalised thrust), the learned G1's specific force
    /// along the thrust frame's z per unit thrust of each motor, m/s², and the measured specific
    /// force at the centre of gravity, thrust frame, m/s².
    pub fn update(
        &mut self,
        u: &[f32],
        g1_up_mps2: &[f32],
        specific_force_thrust_mps2: [f32; 3],
        dt_s: f32,
    ) {
        let pushed_up_mps2: f32 = u.iter().zip(g1_up_mps2).map(|(u, g1)| -g1 * u).sum();
        let measured_up_mps2 = -specific_force_thrust_mps2[2];
        let pushing = pushed_up_mps2 > THRUST_SCALE_MIN_PUSH_G * STANDARD_GRAVITY_MPS2;
        if !pushing || !measured_up_mps2.is_finite() || !dt_s.is_finite() {
            return;
        }
        let (low, high) = THRUST_SCALE_RANGE;
        let ratio = (measured_up_mps2 / pushed_up_mps2).clamp(low, high);
        let a = if self.sampled { (dt_s / THRUST_SCALE_TIME_S).clamp(0.0, 1.0) } else { 1.0 };
        self.scale += (ratio - self.scale) * a;
        self.flown_u_sum += (u.iter().sum::<f32>() - self.flown_u_sum) * a;
        self.sampled = true;
    }

    /// Measured over modelled thrust (1 before any sample).
    pub fn scale(&self) -> f32 {
        self.scale
    }

    /// The commands' sum that flew, normalised thrust; `None` before any sample.
    pub fn flown_u_sum(&self) -> Option<f32> {
        self.sampled.then_some(self.flown_u_sum)
    }
}

/// Largest tilt rate (about the thrust frame's x and y) at which a landing craft counts as
/// resting, rad/s (30 °/s): not tipping over. A craft on its gear may yaw (its idle torques
/// against the gear's friction: 150 °/s in Monte Carlo seed 454), which says nothing. A ground
/// contact that has lasted [`TOUCHDOWN_CONTACT_LANDED_S`] lands the craft whatever its tilt
/// rate: rocking or tipping on the ground, its motors cannot help it.
pub const TOUCHDOWN_MAX_RATE_RAD_S: f32 = 0.5;

/// Largest vertical speed from the fixes at which a landing craft counts as resting, m/s.
pub const TOUCHDOWN_MAX_SPEED_MPS: f32 = 0.3;

/// How long the touchdown's signs must hold before the motors stop, s (ours): INDI brings the
/// thrust from hover to below the threshold within a few motor time constants of the contact
/// (0.1–0.2 s), so the motors stop about 0.4 s after it, well within the second the issue
/// allows; a bounce breaks the run and it starts again.
pub const TOUCHDOWN_CONFIRM_S: f32 = 0.2;

/// Share of the commanded descent speed below which a landing craft that has been descending
/// counts as stopped by something (ours): the descent's loop follows its setpoint within a
/// few hundredths of a m/s in the air (the vertical drag of the strongest updraft of the wind
/// aspect, about 1 m/s, is a tenth of a m/s² on the random airframes, against the loop's
/// `k_velocity` of 2–3 m/s² per m/s), so a descent stalled below half its speed is the ground.
pub const TOUCHDOWN_CONTACT_SPEED_FRACTION: f32 = 0.5;

/// How long the descent must stay stalled for a ground contact, s (ours): longer than the
/// loop's own transients at the landing's start (the descent is first required to have
/// reached the same share of its speed), short against the touchdown's confirmation.
pub const TOUCHDOWN_CONTACT_S: f32 = 0.05;

/// How long a ground contact must last for the craft to count as landed whatever its thrust
/// and its rocking, s (ours; PX4's "maybe landed" held for its trigger time is the same idea):
/// in the air the contact's probe ([`TOUCHDOWN_CONTACT_SPOOL_S`]) drops the craft at up to
/// 0.7 g, so it passes [`TOUCHDOWN_MAX_SPEED_MPS`] within the probe's 0.2 s and the slowest
/// motors' lag (0.2 s), ending the contact; on the ground a craft rocking on
/// its feet in wind moves its centre of gravity vertically by a tenth of a m/s at most (Monte
/// Carlo seed 7 of the random world in a 5 m/s wind: 0.14 m/s, rocking at 1–3 rad/s with a
/// motor at full, where the resting signs never held for [`TOUCHDOWN_CONFIRM_S`]). With the
/// contact found within [`TOUCHDOWN_CONTACT_S`] of the stall, the motors stop about 0.5 s after
/// the touchdown.
pub const TOUCHDOWN_CONTACT_LANDED_S: f32 = 0.4;

/// Time over which a ground contact lowers the cap on the upward specific force from 1 g to
/// [`TOUCHDOWN_CONTACT_MIN_UP_G`], s (ours): the contact's probe. On the ground the measured
/// force stays at 1 g whatever the motors do and the rocking dies with the thrust; in the air
/// the craft sinks at once, faster than [`TOUCHDOWN_MAX_SPEED_MPS`] within a few tenths of a
/// second whatever its loops' gains (a slow craft's level hold alone took its descent from
/// 0.2 to 0.3 m/s in more than 0.4 s: Monte Carlo seed 204 of the random world in wind, which
/// stopped its motors 6.4 m up without the probe), and the contact ends.
pub const TOUCHDOWN_CONTACT_SPOOL_S: f32 = 0.2;

/// The upward specific force a ground contact's probe lowers its cap to, as a fraction of g
/// (ours): low enough that a craft in the air falls at 0.7 g, high enough that the thrust
/// axis stays defined.
pub const TOUCHDOWN_CONTACT_MIN_UP_G: f32 = 0.3;

/// Rate at which the touchdown speed's peak decays, m/s per s: keeps the descent speed of the
/// moment before the contact through the confirmation.
const TOUCHDOWN_PEAK_DECAY_MPS2: f32 = 1.0;

/// Specific force at the centre of gravity, as a multiple of g, that counts as the ground's
/// impact in a landing without fixes (ours): a steady descent reads 1 g give or take a gust's
/// few tenths, a landing gear stopping 0.5 m/s within a few centimetres reads several g.
pub const TOUCHDOWN_IMPACT_G: f32 = 2.0;

/// Time over which a landing without fixes lowers its thrust to nothing after an impact, s
/// (ours). Without fixes the vertical speed is the accelerometer's integral, which the bounces
/// of a contact spoil (in the SITL it ran to 10 m/s and beyond, and the descent's loop then
/// climbed to catch it, hopping: the touchdown never came); the spool-down caps the upward
/// force from the hover's to none over this time, whatever the loop asks, so the craft settles
/// and the touchdown's signs follow within a few tenths.
pub const TOUCHDOWN_SPOOL_DOWN_S: f32 = 0.5;

/// Measured upward specific force below which a spooling craft is in the air after all, as a
/// fraction of g (ours): it falls as its thrust does, where the ground would hold it at 1 g.
/// The spool-down is called off and the descent goes on.
pub const TOUCHDOWN_AIRBORNE_G: f32 = 0.6;

/// How long the measured force must stay below [`TOUCHDOWN_AIRBORNE_G`] to call a spool-down
/// off, s (ours): a gear's bounce unloads it for a few hundredths of a second; a craft in the
/// air with its thrust falling stays unloaded.
pub const TOUCHDOWN_AIRBORNE_S: f32 = 0.1;

/// What the pilot assumes of landings and fly-aways (the parameters `land_descent_mps`,
/// `land_pose_lost_s`, `flyaway_speed_mps`, `flyaway_time_s`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LandConfig {
    /// Descent speed of a landing, m/s.
    pub descent_mps: f32,
    /// Time the fixes may stay lost in a flight before it lands, s.
    pub pose_lost_s: f32,
    /// Speed away from the setpoint that counts towards a fly-away, m/s.
    pub flyaway_speed_mps: f32,
    /// Time above that speed after which the craft lands, s.
    pub flyaway_time_s: f32,
    /// Stop the motors when a hand grabs the flying craft (`catch_detect`, `super::catch`).
    pub catch_detect: bool,
}

impl Default for LandConfig {
    fn default() -> Self {
        Self {
            descent_mps: DEFAULT_LAND_DESCENT_MPS,
            pose_lost_s: DEFAULT_LAND_POSE_LOST_S,
            flyaway_speed_mps: DEFAULT_FLYAWAY_SPEED_MPS,
            flyaway_time_s: DEFAULT_FLYAWAY_TIME_S,
            catch_detect: true,
        }
    }
}

/// The touchdown detector of a landing (see the constants above): thrust well below hover while
/// the measured specific force stays near 1 g (the ground carries the craft), the craft not
/// turning and, with fixes, not moving vertically, for [`TOUCHDOWN_CONFIRM_S`]. It assumes
/// nothing of the height: no range finder, and a pose's zero need not be the ground.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Touchdown {
    /// Why the craft lands.
    pub reason: LandReason,
    /// How long the signs have held, s.
    resting_s: f32,
    /// The descent speed's decaying peak, m/s (positive down).
    pub peak_descent_mps: f32,
    /// Time since an impact began the spool-down of a landing without fixes, s.
    spooling_s: Option<f32>,
    /// How long the measured force has been below [`TOUCHDOWN_AIRBORNE_G`] while spooling, s.
    airborne_s: f32,
    /// The craft has descended at [`TOUCHDOWN_CONTACT_SPEED_FRACTION`] of the commanded speed
    /// since the landing began or the last contact ended.
    descending: bool,
    /// How long the descent has been stalled, s (towards [`TOUCHDOWN_CONTACT_S`]).
    stalled_s: f32,
    /// In ground contact (module doc): the pilot stops holding the horizontal position.
    contact: bool,
    /// How long the ground contact has lasted, s (towards [`TOUCHDOWN_CONTACT_LANDED_S`]).
    contact_s: f32,
}

impl Touchdown {
    /// A landing for `reason`, just begun.
    pub fn new(reason: LandReason) -> Self {
        Self {
            reason,
            resting_s: 0.0,
            peak_descent_mps: 0.0,
            spooling_s: None,
            airborne_s: 0.0,
            descending: false,
            stalled_s: 0.0,
            contact: false,
            contact_s: 0.0,
        }
    }

    /// Whether the craft is in ground contact (module doc): the pilot then flies level with
    /// zero horizontal velocity, keeping the descent, instead of holding the position.
    pub fn ground_contact(&self) -> bool {
        self.contact
    }

    /// Follow the ground contact of a landing with fixes: the descent (vertical speed from the
    /// fixes `fix_vz_mps`, positive down) stalled below its share of `descent_sp_mps` for
    /// [`TOUCHDOWN_CONTACT_S`] after the craft had descended, with the ground carrying it
    /// (`force_up_g`, in g, above [`TOUCHDOWN_MIN_FORCE_G`]); ended by a vertical speed above
    /// [`TOUCHDOWN_MAX_SPEED_MPS`] (or the stall's own threshold, if higher) either way.
    fn follow_contact(&mut self, fix_vz_mps: f32, descent_sp_mps: f32, force_up_g: f32, dt_s: f32) {
        let stall_below = TOUCHDOWN_CONTACT_SPEED_FRACTION * descent_sp_mps;
        if self.contact {
            if fix_vz_mps.abs() > TOUCHDOWN_MAX_SPEED_MPS.max(stall_below) {
                self.contact = false;
                self.contact_s = 0.0;
                self.descending = fix_vz_mps > 0.0;
                self.stalled_s = 0.0;
            } else {
                self.contact_s += dt_s;
            }
            return;
        }
        if fix_vz_mps >= stall_below {
            self.descending = true;
        }
        let stalled = self.descending
            && descent_sp_mps > 0.0
            && fix_vz_mps.abs() < stall_below
            && force_up_g > TOUCHDOWN_MIN_FORCE_G;
        self.stalled_s = if stalled { self.stalled_s + dt_s } else { 0.0 };
        if self.stalled_s >= TOUCHDOWN_CONTACT_S {
            self.contact = true;
            self.descending = false;
        }
    }

    /// The cap on the upward specific force, m/s²: none; the spool-down's of a landing without
    /// fixes, falling from 1 g to nothing over [`TOUCHDOWN_SPOOL_DOWN_S`]; or a ground
    /// contact's probe, falling from 1 g to [`TOUCHDOWN_CONTACT_MIN_UP_G`] over
    /// [`TOUCHDOWN_CONTACT_SPOOL_S`].
    pub fn max_up_mps2(&self) -> f32 {
        if self.contact {
            let share = (self.contact_s / TOUCHDOWN_CONTACT_SPOOL_S).min(1.0);
            return STANDARD_GRAVITY_MPS2 * (1.0 - (1.0 - TOUCHDOWN_CONTACT_MIN_UP_G) * share);
        }
        self.spooling_s.map_or(f32::INFINITY, |t| {
            STANDARD_GRAVITY_MPS2 * (1.0 - t / TOUCHDOWN_SPOOL_DOWN_S).max(0.0)
        })
    }

    /// Follow the spool-down of a landing without fixes: it begins at an `impact` (returns
    /// true then), and ends when the measured upward force `force_up_g` (in g) shows the craft
    /// in the air for [`TOUCHDOWN_AIRBORNE_S`] (a bounce's dips are shorter).
    fn spool(&mut self, impact: bool, force_up_g: f32, dt_s: f32) -> bool {
        self.airborne_s =
            if force_up_g < TOUCHDOWN_AIRBORNE_G { self.airborne_s + dt_s } else { 0.0 };
        let (spooling, began) = match self.spooling_s {
            Some(_) if self.airborne_s >= TOUCHDOWN_AIRBORNE_S => (None, false),
            Some(t) => (Some(t + dt_s), false),
            None if impact => (Some(0.0), true),
            None => (None, false),
        };
        self.spooling_s = spooling;
        began
    }

    /// One step: whether the craft has been resting long enough.
    fn update(&mut self, resting: bool, descent_mps: f32, dt_s: f32) -> bool {
        self.peak_descent_mps =
            descent_mps.max(self.peak_descent_mps - TOUCHDOWN_PEAK_DECAY_MPS2 * dt_s);
        self.resting_s = if resting { self.resting_s + dt_s } else { 0.0 };
        self.resting_s >= TOUCHDOWN_CONFIRM_S
    }

    /// One control step of a landing on what it measured (`signs`), `dt_s` after the last:
    /// whether the touchdown is confirmed (the motors stop), and whether an impact began a
    /// spool-down in this step (the dead reckoning is then lost: the caller holds it still).
    pub fn step(&mut self, signs: &TouchdownSigns<'_>, dt_s: f32) -> TouchdownStep {
        let motors = signs.u.len().min(signs.u_idle.len()).min(signs.u_hover.len());
        let motors = motors.min(signs.g1_up_mps2.len());
        // What the flight before the landing measured (`ThrustScale`, bounded where it is
        // taken): the hover that flew, and the model's push times the thrust measured over it.
        let flown = &signs.flown;
        let mut thrust = 0.0;
        let (mut idle, mut hover) = (0.0, 0.0);
        let mut pushed_up_mps2 = 0.0;
        for i in 0..motors {
            thrust += signs.u[i];
            idle += signs.u_idle[i];
            hover += signs.u_hover[i];
            pushed_up_mps2 -= signs.g1_up_mps2[i] * signs.u[i];
        }
        // The hover that flew, else the model's.
        let hover = flown.flown_u_sum().unwrap_or(hover).max(idle);
        let low = idle + TOUCHDOWN_THRUST_FRACTION * (hover - idle);
        pushed_up_mps2 *= flown.scale();
        let force_up_g = -signs.specific_force_thrust_mps2[2] / STANDARD_GRAVITY_MPS2;
        // What the motors' commands push with, by the learned model: the ground carries the
        // difference. On the ground INDI's torque demands (against the gear's friction) can
        // hold a motor or two high while the rest idle, so the commands' sum alone may never
        // fall.
        let carried = force_up_g - pushed_up_mps2 / STANDARD_GRAVITY_MPS2 > TOUCHDOWN_CARRIED_G;
        // Without fixes, an impact spools the motors down (see TOUCHDOWN_SPOOL_DOWN_S).
        let mut impact = false;
        if signs.fix_vertical_speed_mps.is_none() {
            let [x, y, z] = signs.accel_mps2;
            let limit = TOUCHDOWN_IMPACT_G * STANDARD_GRAVITY_MPS2;
            impact = self.spool(x * x + y * y + z * z > limit * limit, force_up_g, dt_s);
        }
        if let Some(vz) = signs.fix_vertical_speed_mps {
            self.follow_contact(vz, signs.descent_sp_mps, force_up_g, dt_s);
        } else {
            (self.contact, self.contact_s) = (false, 0.0);
        }
        let still_vertically =
            signs.fix_vertical_speed_mps.is_none_or(|v| v.abs() < TOUCHDOWN_MAX_SPEED_MPS);
        let resting = (thrust < low || carried)
            && force_up_g > TOUCHDOWN_MIN_FORCE_G
            && signs.tilt_rate_rad_s < TOUCHDOWN_MAX_RATE_RAD_S
            && still_vertically;
        let descent_mps = signs.vertical_speed_mps;
        let rested = self.update(resting, descent_mps, dt_s);
        TouchdownStep { touched: rested || self.contact_s >= TOUCHDOWN_CONTACT_LANDED_S, impact }
    }
}

/// What the touchdown detector reads in one control step: the commands and the learned
/// model's view of them, and what the IMU and the estimator measured.
#[derive(Clone, Copy, Debug)]
pub struct TouchdownSigns<'a> {
    /// The motors' commands, normalised thrust (INDI's `u`).
    pub u: &'a [f32],
    /// Each motor's idle and hover thrust in the learned model, normalised thrust.
    pub u_idle: &'a [f32],
    pub u_hover: &'a [f32],
    /// The learned G1's specific force along the thrust frame's z (down) per unit thrust of
    /// each motor, m/s².
    pub g1_up_mps2: &'a [f32],
    /// The measured specific force at the centre of gravity, thrust frame, m/s².
    pub specific_force_thrust_mps2: [f32; 3],
    /// What the flight before the landing measured of its thrust ([`ThrustScale`]; its default
    /// where it measured nothing: the model taken as right).
    pub flown: ThrustScale,
    /// The tilt rate (about the thrust frame's x and y), rad/s: a craft on its gear may yaw.
    pub tilt_rate_rad_s: f32,
    /// The accelerometer's reading, m/s² (any axes: its magnitude tells an impact).
    pub accel_mps2: [f32; 3],
    /// The vertical speed from the fixes, m/s (positive down), or `None` without fixes.
    pub fix_vertical_speed_mps: Option<f32>,
    /// The estimator's vertical speed, m/s (positive down): the touchdown speed reported.
    pub vertical_speed_mps: f32,
    /// The descent speed the landing flies, m/s (positive down).
    pub descent_sp_mps: f32,
}

/// What [`Touchdown::step`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TouchdownStep {
    /// The touchdown is confirmed: stop the motors.
    pub touched: bool,
    /// An impact began a spool-down in this step (a landing without fixes).
    pub impact: bool,
}

/// The fly-away detector: how long the craft has moved away from its setpoint (or, before one,
/// from where the flight first had a usable pose) faster than [`LandConfig::flyaway_speed_mps`]
/// without braking by [`FLYAWAY_BRAKING_MPS`], and its fastest speed since. The radial speed
/// counts, so a craft circling while its heading settles (Monte Carlo seed 355 of the random
/// world: 6 m/s for 2 s, then held within 0.16 m) is no fly-away; braking is none either: a
/// craft thrown sideways at 3–6 m/s recovers that way, once its tumble is over.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FlyAway {
    /// Time counted and the peak radial speed since, s and m/s; `None`: not counting.
    counting: Option<(f32, f32)>,
}

impl FlyAway {
    /// Stop counting (the pilot steers, no pose, or a landing).
    pub fn reset(&mut self) {
        self.counting = None;
    }

    /// One step `dt_s` long, the craft `offset_ned_m` from where it should be and moving at
    /// `velocity_ned_mps`: whether it has flown away (for longer than the configured time).
    pub fn update(
        &mut self,
        offset_ned_m: &Vector3<f32>,
        velocity_ned_mps: &Vector3<f32>,
        config: &LandConfig,
        dt_s: f32,
    ) -> bool {
        // The radial speed is `along / distance`; whether it exceeds the limit needs no root,
        // so the common step (not moving away fast) takes none.
        let v = velocity_ned_mps;
        let along = offset_ned_m.x * v.x + offset_ned_m.y * v.y;
        let distance2 = offset_ned_m.x * offset_ned_m.x + offset_ned_m.y * offset_ned_m.y;
        let limit = config.flyaway_speed_mps;
        let counting = distance2 > 1e-6 && along > 0.0 && along * along > limit * limit * distance2;
        if !counting {
            self.counting = None;
            return false;
        }
        let speed = along / libm::sqrtf(distance2);
        self.counting = match self.counting {
            Some((_, peak)) if counting && speed < peak - FLYAWAY_BRAKING_MPS => Some((0.0, speed)),
            Some((since_s, peak)) if counting => Some((since_s + dt_s, peak.max(speed))),
            _ if counting => Some((0.0, speed)),
            _ => None,
        };
        self.counting.is_some_and(|(since_s, _)| since_s > config.flyaway_time_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT_S: f32 = 0.0005;
    /// A quadrotor's learned model: idle 0.05, hover 0.4, G1 down so that the hover makes 1 g.
    const U_IDLE: [f32; 4] = [0.05; 4];
    const U_HOVER: [f32; 4] = [0.4; 4];
    const G1_UP: [f32; 4] = [-STANDARD_GRAVITY_MPS2 / 1.6; 4];

    fn signs(u: f32, force_up_g: f32, fix_vz: Option<f32>) -> TouchdownSigns<'static> {
        // Leaked once per call in a test: the signs borrow their commands.
        let u: &'static [f32; 4] = Box::leak(Box::new([u; 4]));
        TouchdownSigns {
            u,
            u_idle: &U_IDLE,
            u_hover: &U_HOVER,
            g1_up_mps2: &G1_UP,
            specific_force_thrust_mps2: [0.0, 0.0, -force_up_g * STANDARD_GRAVITY_MPS2],
            flown: ThrustScale::default(),
            tilt_rate_rad_s: 0.05,
            accel_mps2: [0.0, 0.0, -force_up_g * STANDARD_GRAVITY_MPS2],
            fix_vertical_speed_mps: fix_vz,
            vertical_speed_mps: fix_vz.unwrap_or(0.5),
            descent_sp_mps: DEFAULT_LAND_DESCENT_MPS,
        }
    }

    /// Steps until the touchdown is confirmed, within `max_s`.
    fn seconds_to_touchdown(touchdown: &mut Touchdown, signs: &TouchdownSigns, max_s: f32) -> f32 {
        let steps = (max_s / DT_S) as u32;
        (1..=steps)
            .find(|_| touchdown.step(signs, DT_S).touched)
            .map_or(f32::INFINITY, |n| n as f32 * DT_S)
    }

    #[test]
    fn a_craft_hovering_or_descending_in_the_air_never_touches_down() {
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        // The hover's thrust makes 1 g, and the descent's a little less; with and without fixes.
        for (u, g, vz) in [(0.4, 1.0, Some(0.5)), (0.38, 0.95, Some(0.5)), (0.38, 0.95, None)] {
            let t = seconds_to_touchdown(&mut touchdown, &signs(u, g, vz), 5.0);
            assert!(t.is_infinite(), "u {u}, {g} g, fixes {vz:?}: touched down after {t} s");
        }
    }

    #[test]
    fn a_hover_flown_on_a_model_up_to_30_percent_off_is_never_a_touchdown() {
        // The hardest case in the air: hovering still (fixes say 0 m/s), at 1 g, not turning.
        // The model's thrust per command off by `error`: it thinks the hover needs
        // `u / (1 + error)` and that the commands push with `(1 + error)` g.
        for error in [-0.3f32, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3] {
            let hover: [f32; 4] = [0.4 / (1.0 + error); 4];
            let g1: [f32; 4] = [(1.0 + error) * G1_UP[0]; 4];
            let u = [0.4f32; 4];
            let signs = TouchdownSigns {
                u: &u,
                u_idle: &U_IDLE,
                u_hover: &hover,
                g1_up_mps2: &g1,
                ..signs(0.4, 1.0, Some(0.0))
            };
            let mut touchdown = Touchdown::new(LandReason::Commanded);
            let t = seconds_to_touchdown(&mut touchdown, &signs, 3.0);
            assert!(t.is_infinite(), "model {:+.0} %: touched down after {t} s", 100.0 * error);
        }
    }

    /// A craft whose hover at `u` 0.4 makes 1 g, flown on a model whose thrust per command is
    /// `1 + error` times the true one, its [`ThrustScale`] measured in that hover for a second.
    fn model_off_by(error: f32) -> ([f32; 4], [f32; 4], ThrustScale) {
        let hover = [0.4 / (1.0 + error); 4];
        let g1 = [(1.0 + error) * G1_UP[0]; 4];
        let mut scale = ThrustScale::default();
        for _ in 0..2000 {
            scale.update(&[0.4; 4], &g1, [0.0, 0.0, -STANDARD_GRAVITY_MPS2], DT_S);
        }
        (hover, g1, scale)
    }

    #[test]
    fn with_the_thrust_measured_before_the_landing_a_model_far_off_neither_lands_in_the_air_nor_stays_up_on_the_ground(
    ) {
        // Without speed telemetry the learned thrust can be 40 % off and more.
        for error in [-0.6f32, -0.4, 0.5, 1.0, 1.5] {
            let (hover, g1, scale) = model_off_by(error);
            assert!((scale.scale() * (1.0 + error) - 1.0).abs() < 1e-3, "{error}: {scale:?}");
            let with = |u: &'static [f32; 4], force_up_g: f32, fix_vz, flown| TouchdownSigns {
                u,
                u_hover: Box::leak(Box::new(hover)),
                g1_up_mps2: Box::leak(Box::new(g1)),
                flown,
                ..signs(0.0, force_up_g, fix_vz)
            };
            // Hovering still at the landing's start, with fixes and without: no touchdown.
            for fix_vz in [Some(0.0), None] {
                let hovering = with(&[0.4; 4], 1.0, fix_vz, scale);
                let t = seconds_to_touchdown(
                    &mut Touchdown::new(LandReason::Commanded),
                    &hovering,
                    3.0,
                );
                assert!(t.is_infinite(), "model {:+.0} %: touched down after {t} s", 100.0 * error);
            }
            // On the ground, the commands at a quarter of the hover's: a touchdown.
            let resting = with(&[0.1; 4], 1.0, Some(0.0), scale);
            let t = seconds_to_touchdown(&mut Touchdown::new(LandReason::Commanded), &resting, 1.0);
            assert!(
                t < TOUCHDOWN_CONFIRM_S + 0.01,
                "model {:+.0} %: {t} s on the ground",
                100.0 * error
            );
        }
        // A model whose total thrust is right but whose hover commands sum to twice what flies
        // (how it shares the thrust among the motors is off): the hover that flew counts.
        let (_, g1, scale) = model_off_by(0.0);
        let hovering = TouchdownSigns {
            u: &[0.4; 4],
            u_hover: &[0.8; 4],
            g1_up_mps2: &g1,
            flown: scale,
            ..signs(0.4, 1.0, Some(0.0))
        };
        let t = seconds_to_touchdown(&mut Touchdown::new(LandReason::Commanded), &hovering, 3.0);
        assert!(t.is_infinite(), "hover commands off: touched down after {t} s");
        // The premise: taken as right, a model 40 % low reads a still hover as the ground.
        let (hover, g1, _) = model_off_by(-0.4);
        let unscaled = TouchdownSigns {
            u: &[0.4; 4],
            u_hover: &hover,
            g1_up_mps2: &g1,
            ..signs(0.4, 1.0, Some(0.0))
        };
        let t = seconds_to_touchdown(&mut Touchdown::new(LandReason::Commanded), &unscaled, 3.0);
        assert!(t < 1.0, "the unscaled model did not mistake the hover: {t} s");
    }

    #[test]
    fn the_thrust_scale_takes_no_sample_of_a_small_push_and_stays_within_its_bounds() {
        let mut scale = ThrustScale::default();
        // Motors barely turning in a fall: nothing learned.
        scale.update(&[0.02; 4], &G1_UP, [0.0, 0.0, -9.0], DT_S);
        assert_eq!(scale.scale(), 1.0);
        // A reading ten times the model's: bounded.
        scale.update(&[0.4; 4], &G1_UP, [0.0, 0.0, -100.0], DT_S);
        assert_eq!(scale.scale(), THRUST_SCALE_RANGE.1);
        // Then the truth, over the time constant: most of the way there.
        for _ in 0..(THRUST_SCALE_TIME_S / DT_S) as usize {
            scale.update(&[0.4; 4], &G1_UP, [0.0, 0.0, -STANDARD_GRAVITY_MPS2], DT_S);
        }
        let left = (scale.scale() - 1.0) / (THRUST_SCALE_RANGE.1 - 1.0);
        assert!((0.3..0.4).contains(&left), "{} left: {left}", scale.scale());
    }

    #[test]
    fn a_craft_the_ground_carries_touches_down_after_the_confirmation_time() {
        // Thrust at idle, 1 g measured, still: the ground carries it.
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        let t = seconds_to_touchdown(&mut touchdown, &signs(0.06, 1.0, Some(0.0)), 1.0);
        assert!((t - TOUCHDOWN_CONFIRM_S).abs() < 2.0 * DT_S, "confirmed after {t} s");
        // Thrust above the low mark (INDI's torque demands against the gear), the commands
        // pushing with 0.62 g by the model: the ground carries 0.38 g.
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        let t = seconds_to_touchdown(&mut touchdown, &signs(0.25, 1.0, None), 1.0);
        assert!(t < TOUCHDOWN_CONFIRM_S + 0.01, "carried: confirmed after {t} s");
    }

    #[test]
    fn still_moving_vertically_or_tipping_over_is_no_touchdown() {
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        let sinking = signs(0.06, 1.0, Some(0.5));
        assert!(seconds_to_touchdown(&mut touchdown, &sinking, 1.0).is_infinite());
        // Tipping without a ground contact first (the descent never stalled: this landing
        // never descended) is none either.
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        let mut tipping = signs(0.06, 1.0, Some(0.0));
        tipping.tilt_rate_rad_s = 1.0;
        assert!(seconds_to_touchdown(&mut touchdown, &tipping, 1.0).is_infinite());
        // After a descent stalled on the ground, the contact lands the craft whatever its
        // rocking or tipping, once it has lasted (on the ground the motors cannot help it).
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        assert!(
            seconds_to_touchdown(&mut touchdown, &signs(0.4, 1.0, Some(0.5)), 1.0).is_infinite()
        );
        let t = seconds_to_touchdown(&mut touchdown, &tipping, 1.0);
        let expected = TOUCHDOWN_CONTACT_S + TOUCHDOWN_CONTACT_LANDED_S;
        assert!((t - expected).abs() < 3.0 * DT_S, "landed after {t} s, not {expected} s");
    }

    #[test]
    fn an_impact_without_fixes_spools_down_and_a_fall_calls_it_off() {
        let mut touchdown = Touchdown::new(LandReason::RcLost);
        assert_eq!(touchdown.max_up_mps2(), f32::INFINITY);
        let mut impact = signs(0.4, 3.0, None);
        impact.accel_mps2 = [0.0, 0.0, -3.0 * STANDARD_GRAVITY_MPS2];
        assert!(touchdown.step(&impact, DT_S).impact, "a 3 g impact begins the spool-down");
        assert!(!touchdown.step(&impact, DT_S).impact, "once");
        for _ in 0..(0.25 / DT_S) as u32 {
            let _ = touchdown.step(&signs(0.3, 1.0, None), DT_S);
        }
        let cap = touchdown.max_up_mps2();
        assert!((cap - 0.5 * STANDARD_GRAVITY_MPS2).abs() < 0.1, "half-way down: {cap} m/s²");
        // In the air after all: the force falls with the thrust for longer than a bounce.
        for _ in 0..(1.5 * TOUCHDOWN_AIRBORNE_S / DT_S) as u32 {
            let _ = touchdown.step(&signs(0.2, 0.4, None), DT_S);
        }
        assert_eq!(touchdown.max_up_mps2(), f32::INFINITY, "the spool-down is called off");
    }

    /// Steps `seconds` of a landing whose signs at time `t` (s from the start) are
    /// `signs_at(t)`; the time the motors stop, and whether a ground contact was ever found.
    fn landing(
        touchdown: &mut Touchdown,
        seconds: f32,
        signs_at: impl Fn(f32) -> TouchdownSigns<'static>,
    ) -> (Option<f32>, bool) {
        let mut contact = false;
        for n in 0..(seconds / DT_S) as u32 {
            let t = n as f32 * DT_S;
            let touched = touchdown.step(&signs_at(t), DT_S).touched;
            contact |= touchdown.ground_contact();
            if touched {
                return (Some(t), contact);
            }
        }
        (None, contact)
    }

    #[test]
    fn a_craft_rocking_on_its_feet_in_wind_lands_within_a_second_of_the_touchdown() {
        // Descending at 0.5 m/s in the air for 2 s, then on its feet from 2 s: rocking at
        // 1.5 Hz with tilt rates up to 3 rad/s, one motor at full against the ground while the
        // rest idle (more thrust than the hover's: neither low nor carried), the measured force
        // 0.9-1.4 g, the centre of gravity moving up and down at 0.14 m/s: Monte Carlo seed 7 of
        // the random world in a 5 m/s wind, where the resting signs never held long enough.
        const TOUCHDOWN_S: f32 = 2.0;
        let rocking = |t: f32| {
            if t < TOUCHDOWN_S {
                return signs(0.4, 1.0, Some(DEFAULT_LAND_DESCENT_MPS));
            }
            let phase = core::f32::consts::TAU * 1.5 * (t - TOUCHDOWN_S);
            let mut on_feet = signs(0.05, 1.15 + 0.25 * libm::sinf(phase), Some(0.0));
            on_feet.u = &[1.0, 0.05, 0.05, 0.05];
            on_feet.tilt_rate_rad_s = 3.0 * libm::cosf(phase).abs();
            on_feet.fix_vertical_speed_mps = Some(0.14 * libm::cosf(phase));
            on_feet
        };
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        let (stopped_s, contact) = landing(&mut touchdown, 10.0, rocking);
        let stopped_s = stopped_s.expect("the motors never stopped");
        assert!(contact, "no ground contact");
        assert!(
            (TOUCHDOWN_S..TOUCHDOWN_S + 1.0).contains(&stopped_s),
            "stopped {:.3} s after the touchdown",
            stopped_s - TOUCHDOWN_S
        );
    }

    #[test]
    fn a_gust_that_stalls_the_descent_in_the_air_never_stops_the_motors() {
        // Descending in the air when a gust stalls the descent for 0.3 s (the measured force
        // near 1 g, the thrust at hover): a ground contact for all the detector can tell. In
        // contact the pilot flies the level hold's descent, which takes the craft back to
        // 0.5 m/s with the vertical loop's lag (0.1 s); then more stalls, one every second.
        // Harsher than the air: against the level hold's vertical gain (`k_rate`, about 12 /s)
        // a stall of 0.3 s at 0.05 m/s needs a vertical push of 5 m/s² for all that time.
        let gusty = |t: f32| {
            let since_stall = t % 1.0;
            let vz = if since_stall < 0.3 {
                0.05
            } else {
                DEFAULT_LAND_DESCENT_MPS * (1.0 - libm::expf(-(since_stall - 0.3) / 0.1))
            };
            signs(0.4, 1.0, Some(vz))
        };
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        // Descending first, so that a stall counts.
        let (stopped_s, _) = landing(&mut touchdown, 1.0, |_| signs(0.4, 1.0, Some(0.5)));
        assert_eq!(stopped_s, None);
        let (stopped_s, contact) = landing(&mut touchdown, 20.0, gusty);
        assert!(contact, "the stalls look like contacts: the test tests nothing");
        assert_eq!(stopped_s, None, "stopped in the air");
    }

    #[test]
    fn a_landing_begun_in_a_hover_is_no_ground_contact_before_it_descends() {
        // The landing's first tenths: still at the hover's height, the descent not yet flown.
        let mut touchdown = Touchdown::new(LandReason::Commanded);
        let (stopped_s, contact) = landing(&mut touchdown, 2.0, |_| signs(0.4, 1.0, Some(0.0)));
        assert_eq!((stopped_s, contact), (None, false));
    }

    /// `seconds` of flight `offset` from the setpoint at `velocity`; whether it flew away.
    fn flies_away(offset: [f32; 3], velocity: impl Fn(f32) -> [f32; 3], seconds: f32) -> bool {
        let mut detector = FlyAway::default();
        let config = LandConfig::default();
        let dt_s = 0.0005;
        (0..(seconds / dt_s) as u32).any(|n| {
            let v = Vector3::from(velocity(n as f32 * dt_s));
            detector.update(&Vector3::from(offset), &v, &config, dt_s)
        })
    }

    #[test]
    fn moving_away_fast_without_braking_is_a_fly_away_after_the_configured_time() {
        let config = LandConfig::default();
        let away = |_| [config.flyaway_speed_mps + 0.5, 0.0, 0.0];
        assert!(!flies_away([2.0, 0.0, 0.0], away, 0.95 * config.flyaway_time_s));
        assert!(flies_away([2.0, 0.0, 0.0], away, 1.05 * config.flyaway_time_s));
        // Towards the setpoint, or around it, at the same speed: none.
        assert!(!flies_away([-2.0, 0.0, 0.0], away, 5.0));
        assert!(!flies_away([0.0, 2.0, 0.0], away, 5.0));
    }

    #[test]
    fn a_craft_that_brakes_is_no_fly_away() {
        // Thrown sideways at 6 m/s, braking at 1 m/s² once its tumble is over.
        let braking = |t: f32| [(6.0 - t).max(0.0), 0.0, 0.0];
        assert!(!flies_away([1.0, 0.0, 0.0], braking, 6.0));
    }
}
