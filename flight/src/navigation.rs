//! Position and velocity of the centre of gravity, world NED: the accelerometer integrated between
//! external position fixes (motion capture, a ground station), corrected by each fix.
//!
//! A third-order complementary filter per axis, with the accelerometer's bias (world axes) as
//! the third state so that a biased accelerometer leaves no steady velocity error:
//!
//! ```text
//! predict (every step):  v ← v + a dt,  p ← p + v dt          a = R_world_body f_cog + g − b
//! correct (each fix):    e = p_fix − p,  p ← p + k_p e,  v ← v + k_v e,  b ← b − k_b e
//! ```
//!
//! The correction gains place the error dynamics' three poles at `z = exp(−ω_c T)`, the
//! discrete image of a triple pole at the crossover `ω_c`, for the time `T` since the previous
//! fix (`m = 1 − exp(−ω_c T)`: `k_p = 1 − (1 − m)³`, `k_v = (3m² − 1.5m³)/T`, `k_b = m³/T²`; for
//! `ω_c T ≪ 1` these are `3ω_c T`, `3ω_c² T`, `ω_c³ T`). So the estimate follows the
//! accelerometer above `ω_c` and the fixes below it whatever the fix rate: 2 kHz, 100 Hz or
//! 10 Hz (`ω_c T` = 0.4, where the continuous-time gains would place the poles elsewhere),
//! evenly spaced or not. With no fix the filter is dead reckoning: velocity from the
//! accelerometer alone, which is what holds zero vertical speed when no pose is available (its
//! drift is the accelerometer's bias times time, about 0.1 m/s per 10 s for a 0.01 m/s² bias).
//! [`PositionEstimator::hold_still`] zeroes the velocity while the craft is known to be at rest
//! (in the hand before a throw), so dead reckoning starts from a true zero.
//!
//! **Late fixes.** A fix that crossed a radio describes the craft as it was some time ago (its
//! age, [`MAX_FIX_AGE_S`] at most). The estimator keeps the positions it predicted over the last
//! [`HISTORY_SPAN_S`] (one every [`HISTORY_SPACING_S`], linear in between; bounded memory), compares
//! the fix with the prediction for the time the fix describes, and carries the correction
//! forward to now through the model (`Δp + Δv·age − Δb·age²/2`, `Δv − Δb·age`), and to the
//! history since then, so the next fix is compared with a history that knows this one. The
//! error dynamics are then those of an estimator running `age` behind and predicting forward with
//! the accelerometer: the delay costs no stability, only the accelerometer's error over `age`.
//!
//! **What it assumes.** The fixes are the position of the centre of gravity in a world whose
//! vertical is the accelerometer's (the yaw between the two is [`HeadingAlignment`]'s job), with
//! independent noise; the accelerometer's error is a slowly varying bias below
//! [`MAX_BIAS_MPS2`]. The crossover [`DEFAULT_CROSSOVER_RAD_S`] suits motion capture (noise of
//! millimetres); fixes with a noise of decimetres (GNSS) pass their noise on at that bandwidth
//! (about `σ·√(ω_c T)` in position), see [`crossover_for_noise`].

use nalgebra::{UnitQuaternion, Vector3};

/// Standard gravity, m/s² (ISO 80000-3; CGPM 1901): the one value of `g` in the crate (the
/// thrust-axis solver's default and the throw detector's are this one).
pub const STANDARD_GRAVITY_MPS2: f32 = 9.806_65;

/// Default crossover of the fixes and the accelerometer, rad/s: motion capture with millimetre
/// noise is trusted down to about 0.3 s (a quarter of the position loop's bandwidth is slower
/// still, so the estimate's lag does not cost phase margin).
pub const DEFAULT_CROSSOVER_RAD_S: f32 = 4.0;

/// Slowest crossover [`crossover_for_noise`] gives, rad/s (ours): below it the accelerometer
/// would be trusted for tens of seconds, and its bias and the attitude filter's tilt error
/// (0.1–0.2 m/s²) would move the estimate by more than the fixes' noise.
pub const MIN_CROSSOVER_RAD_S: f32 = 1.0;

/// Fix noise up to which the default crossover is kept, m (one standard deviation per axis):
/// motion capture (ours; 1 mm is the simulator's and a typical system's figure).
pub const CROSSOVER_NOISE_REFERENCE_M: f32 = 0.01;

/// The crossover for fixes with `noise_m` of noise (one standard deviation per axis, m):
/// [`DEFAULT_CROSSOVER_RAD_S`] up to [`CROSSOVER_NOISE_REFERENCE_M`], then falling as the cube root
/// of the noise (the position noise the filter passes grows as `σ·√ω_c`, the dead-reckoning error
/// it lets through as `δa/ω_c²`; the cube root keeps their balance roughly where it was), down to
/// [`MIN_CROSSOVER_RAD_S`]: 0.5 m of noise (GNSS) gives 1.1 rad/s. A non-finite or non-positive
/// noise gives the default.
pub fn crossover_for_noise(noise_m: f32) -> f32 {
    if !(noise_m.is_finite() && noise_m > CROSSOVER_NOISE_REFERENCE_M) {
        return DEFAULT_CROSSOVER_RAD_S;
    }
    let ratio = libm::cbrtf(CROSSOVER_NOISE_REFERENCE_M / noise_m);
    (DEFAULT_CROSSOVER_RAD_S * ratio).max(MIN_CROSSOVER_RAD_S)
}

/// Largest accelerometer bias the estimator believes, m/s² (a consumer MEMS accelerometer's
/// offset after calibration is well under this; more means the fixes disagree with the IMU).
pub const MAX_BIAS_MPS2: f32 = 0.5;

/// Time after the last fix's arrival at which the estimate counts as dead reckoning, s (ours):
/// three fix periods at the slowest rate the firmware supports (a GNSS receiver's 5 Hz), so that
/// one lost or late fix of a 5 Hz stream is bridged, while a stream that stopped is noticed
/// within 0.6 s (dead reckoning with 0.1 m/s² of acceleration error drifts 2 cm in that time).
pub const FIX_TIMEOUT_S: f32 = 0.6;

/// Spacing of the predicted positions kept for late fixes, s (ours: at 10 m/s² the straight
/// line between two of them is within 20 µm of the parabola, `a·Δt²/8`).
pub const HISTORY_SPACING_S: f32 = 0.004;

/// Positions kept for late fixes (the ring's length).
pub const HISTORY_LEN: usize = 64;

/// Time covered by the history, s: [`HISTORY_LEN`] × [`HISTORY_SPACING_S`] = 0.256 s.
pub const HISTORY_SPAN_S: f32 = HISTORY_LEN as f32 * HISTORY_SPACING_S;

/// Oldest age a fix may have, s: the history's span less one control period at 1 kHz of margin
/// (the application adds at most one step between a fix's arrival and its use). A pose
/// latency of 0–50 ms is what motion capture over a radio link brings, 50–150 ms a GNSS
/// receiver's solution over its UART; 0.2 s is the registry's limit (`pose_latency_s`).
pub const MAX_FIX_AGE_S: f32 = HISTORY_SPAN_S - 0.001;

/// Smallest innovation a fix is ever rejected for, m (ours): below half a metre a fix is
/// taken whatever its stated accuracy, so a source whose noise was understated (a motion-capture
/// `pose_noise_m` left at 1 mm for a noisier system) is smoothed, never shut out.
pub const MIN_OUTLIER_GATE_M: f32 = 0.5;

/// Innovations beyond this many stated accuracies are outliers (ours): a fix's horizontal
/// accuracy is the RMS of its error, so five of it is passed by chance about once in 10⁵
/// fixes of a Gaussian error, while a multipath jump of several metres on a 0.3 m receiver is
/// refused.
pub const OUTLIER_SIGMAS: f32 = 5.0;

/// How fast the gate widens while fixes are refused, m/s (ours: the velocity fixes keep the
/// prediction's velocity within centimetres per second of the truth, so its position drifts
/// by this times the time since the last position taken).
///
/// Only fixes that bring a velocity are gated: without one, nothing else holds the dead
/// reckoning between fixes, and a craft that leaves a tumble with its attitude 20–30° off
/// (a gyro's scale and cross-axis errors of a few per cent, the randomised world) outruns any
/// gate: tried with motion capture, a gate that widened by `½ · 3 m/s² · t²` refused the
/// fixes of such a craft for 5 s while it flew 130 m (seed 336 of `fly monte-carlo --world
/// random`), where the ungated estimator recovers it.
pub const OUTLIER_DRIFT_AIDED_MPS: f32 = 0.05;

/// √3: a 3D velocity's RMS error per axis standard deviation.
const SQRT_3: f32 = 1.732_050_8;

/// Smallest velocity innovation a velocity is ever refused for, m/s (ours).
pub const MIN_VELOCITY_GATE_MPS: f32 = 1.0;

/// Refused fixes for this long in a row are taken as the truth, s (ours): a jump that lasts
/// was not multipath (a receiver that re-converged, a source re-zeroed), and the estimate moves
/// onto it.
pub const MAX_REJECT_S: f32 = 5.0;

/// Velocities refused for this long in a row are taken as the truth, and the whole track with
/// them, s (ours). A receiver's velocity is a Doppler measurement: multipath that moves its
/// position by metres hardly moves it, and a glitch lasts a solution or two. A lasting
/// disagreement is the dead reckoning's: a tumble leaves the attitude 20–35° off (a gyro's
/// sensitivity and cross-axis errors of a few per cent at 1,000 °/s), the prediction then
/// accelerates by `g sin` of it, 3–6 m/s², past the velocity's gate within a few tenths of a
/// second, and a refused velocity would leave only the slow position correction to hold it
/// (Monte Carlo seeds 508 and 679 of `fly --gnss monte-carlo --world random --wind`: the velocity
/// 3 m/s off, the craft flown to the ground and 20 m away). Two or three solutions at 5–10 Hz.
pub const VELOCITY_MAX_REJECT_S: f32 = 0.3;

/// Acceleration error of the velocity prediction that the velocity crossover balances
/// against a fix's velocity noise, m/s² (ours: 1° of tilt error is 0.17 m/s²).
pub const VELOCITY_DRIFT_ACCEL_MPS2: f32 = 0.15;

/// Bounds of the velocity crossover, rad/s (ours): not slower than the position loop's
/// bandwidth would tolerate, not faster than the fixes can feed at 5 Hz.
pub const VELOCITY_CROSSOVER_RAD_S: (f32, f32) = (0.5, 4.0);

/// The position crossover with velocity fixes, per the crossover [`crossover_for_noise`] gives
/// without them (ours): the velocity carries the motion, so the position only removes the
/// velocity's slow drift and can average its own noise over twice as long.
pub const POSITION_WITH_VELOCITY_FACTOR: f32 = 0.5;

/// The crossover of velocity fixes with `noise_mps` of noise per axis arriving every `dt_fix_s`,
/// rad/s: the one that minimises the velocity error `σ_v² ω T + (δa/ω)²` (the noise passed at
/// that bandwidth plus the prediction's drift between corrections), `ω = ∛(2 δa² / (σ_v² T))`
/// with `δa` [`VELOCITY_DRIFT_ACCEL_MPS2`], within [`VELOCITY_CROSSOVER_RAD_S`]: 3.6 rad/s for
/// 0.1 m/s at 10 Hz, 1.7 rad/s for 0.3 m/s.
pub fn velocity_crossover(noise_mps: f32, dt_fix_s: f32) -> f32 {
    let (low, high) = VELOCITY_CROSSOVER_RAD_S;
    if !(noise_mps.is_finite() && noise_mps > 0.0 && is_step(dt_fix_s)) {
        return high;
    }
    let drift = VELOCITY_DRIFT_ACCEL_MPS2;
    libm::cbrtf(2.0 * drift * drift / (noise_mps * noise_mps * dt_fix_s)).clamp(low, high)
}

/// The noise the estimator's velocity keeps of velocity fixes with `noise_mps` of white noise
/// per axis arriving every `dt_fix_s`, `age_s` late (one standard deviation per axis, averaged
/// over the time between fixes, m/s): 0.1 m/s for 0.15 m/s at 10 Hz and 100 ms, 0.04 m/s for
/// 0.05 m/s. Each fix moves the velocity error `x` by `k_v = 2m − m² + k_b·age` of the fix's
/// error (the bias correction carried over the fix's age) and the bias error `y` by
/// `k_b = m²/T` (`m = 1 − exp(−ω T)` at the [`velocity_crossover`] `ω`, as
/// [`PositionEstimator::correct_fix`] does); between fixes the bias error drives the velocity's
/// (`x ← x − y T`). The steady state of that error's covariance, iterated from zero (the poles
/// are at `1 − m`, so [`NOISE_ITERATIONS`] fixes converge it for any crossover within bounds),
/// gives the mean square `P_xx − P_xy T + P_yy T²/3` over an interval. Not finite or not
/// positive input gives 0.
pub fn velocity_estimate_noise_mps(noise_mps: f32, dt_fix_s: f32, age_s: f32) -> f32 {
    let age_ok = age_s.is_finite() && (0.0..=MAX_FIX_AGE_S).contains(&age_s);
    if !(noise_mps.is_finite() && noise_mps > 0.0 && is_step(dt_fix_s) && age_ok) {
        return 0.0;
    }
    let t = dt_fix_s;
    let m = -libm::expm1f(-velocity_crossover(noise_mps, t) * t);
    let k_b = m * m / t;
    let k_v = 2.0 * m - m * m + k_b * age_s;
    let r = noise_mps * noise_mps;
    // Covariance [[xx, xy], [xy, yy]] just after a fix.
    let (mut xx, mut xy, mut yy) = (0.0f32, 0.0f32, 0.0f32);
    for _ in 0..NOISE_ITERATIONS {
        // Between fixes: x ← x − y T.
        let (pxx, pxy) = (xx - 2.0 * xy * t + yy * t * t, xy - yy * t);
        // The fix: x ← (1 − k_v) x + k_v n,  y ← y + k_b x − k_b n.
        let a = 1.0 - k_v;
        let before = xx;
        xx = a * a * pxx + k_v * k_v * r;
        xy = a * (pxy + k_b * pxx) - k_v * k_b * r;
        yy = yy + 2.0 * k_b * pxy + k_b * k_b * pxx + k_b * k_b * r;
        // Settled (a receiver's 10 Hz at 2.7 rad/s: about 40 fixes): the controller is formed
        // in the control step that engages, which should not run a thousand of these.
        if (xx - before).abs() <= NOISE_SETTLED * xx {
            break;
        }
    }
    libm::sqrtf((xx - xy * t + yy * t * t / 3.0).max(0.0))
}

/// Fixes [`velocity_estimate_noise_mps`] iterates its covariance over: the slowest crossover
/// ([`VELOCITY_CROSSOVER_RAD_S`]' 0.5 rad/s) at the fastest fixes it is used for (100 Hz) has
/// its poles at 0.995, within 10⁻⁴ of the steady state after 1,000 fixes; it stops sooner once
/// settled ([`NOISE_SETTLED`]).
const NOISE_ITERATIONS: usize = 1000;

/// Relative change of the velocity error's variance over one fix below which
/// [`velocity_estimate_noise_mps`] stops iterating.
const NOISE_SETTLED: f32 = 1e-5;

/// The crossover at which the estimator takes the positions of fixes with `noise_m` of noise:
/// [`crossover_for_noise`], times [`POSITION_WITH_VELOCITY_FACTOR`] when they bring a velocity.
/// A position loop faster than this only feeds the fixes' noise into the tilt
/// (`flight::controller::Controller::cap_position_gain`).
pub fn position_crossover(noise_m: f32, with_velocity: bool) -> f32 {
    let crossover = crossover_for_noise(noise_m);
    if with_velocity {
        crossover * POSITION_WITH_VELOCITY_FACTOR
    } else {
        crossover
    }
}

/// One position fix with what its source says of its accuracy: motion capture's is the
/// configured noise; a GNSS receiver states one with every solution, with a velocity.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Fix {
    /// Position of the CoG, world NED, m.
    pub position_ned_m: Vector3<f32>,
    /// Position noise, one standard deviation per axis: horizontal (north and east each),
    /// vertical, m.
    pub sigma_m: [f32; 2],
    /// Velocity of the CoG (GNSS Doppler), world NED, m/s, and its noise per axis, m/s.
    pub velocity: Option<(Vector3<f32>, f32)>,
    /// How long before now the fix describes the craft, s (0 to [`MAX_FIX_AGE_S`]).
    pub age_s: f32,
    /// Time since the previous fix, s.
    pub dt_fix_s: f32,
}

/// What became of a fix.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FixOutcome {
    /// It corrected the estimate.
    Taken,
    /// The estimate was moved onto it outright: the first fix, the first after
    /// [`FIX_TIMEOUT_S`], or one after [`MAX_REJECT_S`] of refusals.
    Reset,
    /// An outlier: its position's innovation exceeded the gate ([`OUTLIER_SIGMAS`]) and taught
    /// nothing (its velocity, when within its own gate, still did); counted.
    Rejected,
}

/// Resolution of the histories' clock, s (1/16 µs): a control period of 2 kHz is 8,000 ticks,
/// one of 3.2 kHz 5,000, so every usual period is a whole number of ticks; others are rounded by
/// at most 31 ns a step. A `u32` of ticks wraps after 268 s, far beyond the time any kept value
/// spans ([`HISTORY_LEN`] pushes); ages are differences, exact across the wrap.
const TICK_S: f32 = 1.0 / 16_000_000.0;

/// [`HISTORY_SPACING_S`] in ticks.
const HISTORY_SPACING_TICKS: u32 = (HISTORY_SPACING_S / TICK_S + 0.5) as u32;

/// Corrections [`History`] keeps unapplied (one per fix whose time lies within the history).
/// A receiver's fixes at 10 Hz leave at most three within its span; a fourth, or a faster
/// source's, folds the oldest into the values (a loop over the values since its fix's time).
const PENDING_CORRECTIONS: usize = 4;

/// A correction made at a fix's time and carried forward through the model: a value `τ` after
/// the fix's time changes by `dp + dv τ − db τ²/2`. It applies to the values kept between the
/// fix's time and the moment it was made (those pushed later were pushed from the corrected
/// estimate).
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct Correction {
    /// The history's clock when it was made, ticks.
    made_ticks: u32,
    /// The fix's age then, s.
    age_s: f32,
    dp: Vector3<f32>,
    dv: Vector3<f32>,
    db: Vector3<f32>,
}

impl Correction {
    /// What it adds to a value kept `age_then_s` before it was made: nothing to values older
    /// than its fix.
    fn at(&self, age_then_s: f32) -> Vector3<f32> {
        let tau = self.age_s - age_then_s;
        if tau > 0.0 {
            self.dp + self.dv * tau - self.db * (0.5 * tau * tau)
        } else {
            Vector3::zeros()
        }
    }
}

/// Values at past times, one every [`HISTORY_SPACING_S`], with their times; no allocation.
///
/// **Constant work per step and per fix.** Each value keeps the clock's reading when it was
/// kept, so time passing changes nothing stored, and a value of a given age is found from the
/// spacing at once (a step or two of search where the spacing was irregular). A fix's
/// correction is not added to every value since the fix's time: it is kept as it was made
/// ([`Correction`]), and a value read is the kept one plus the pending corrections that apply to
/// it, the same sum the values would hold had each been shifted.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct History {
    #[serde(with = "crate::serde_array")]
    values: [Vector3<f32>; HISTORY_LEN],
    /// The clock when each value was kept, ticks ([`TICK_S`]).
    #[serde(with = "crate::serde_array")]
    times_ticks: [u32; HISTORY_LEN],
    /// The clock, ticks (wrapping).
    clock_ticks: u32,
    /// Index of the newest value.
    newest: usize,
    len: usize,
    /// Corrections not yet in the values: a ring, the oldest at `pending_head`.
    pending: [Correction; PENDING_CORRECTIONS],
    pending_head: usize,
    pending_len: usize,
}

impl Default for History {
    fn default() -> Self {
        Self {
            values: [Vector3::zeros(); HISTORY_LEN],
            times_ticks: [0; HISTORY_LEN],
            clock_ticks: 0,
            newest: 0,
            len: 0,
            pending: [Correction::default(); PENDING_CORRECTIONS],
            pending_head: 0,
            pending_len: 0,
        }
    }
}

impl History {
    /// Time went on by `dt_s`; `current` is the value now.
    fn advance(&mut self, dt_s: f32, current: &Vector3<f32>) {
        self.clock_ticks = self.clock_ticks.wrapping_add((dt_s / TICK_S + 0.5) as u32);
        if self.len > 0
            && self.clock_ticks.wrapping_sub(self.times_ticks[self.newest]) < HISTORY_SPACING_TICKS
        {
            return;
        }
        self.newest = (self.newest + 1) % HISTORY_LEN;
        self.values[self.newest] = *current;
        self.times_ticks[self.newest] = self.clock_ticks;
        self.len = (self.len + 1).min(HISTORY_LEN);
    }

    /// Index of the `k`-th newest value.
    fn index(&self, k: usize) -> usize {
        (self.newest + HISTORY_LEN - k) % HISTORY_LEN
    }

    /// Age of the value at `index`, s.
    fn age_s(&self, index: usize) -> f32 {
        self.clock_ticks.wrapping_sub(self.times_ticks[index]) as f32 * TICK_S
    }

    /// The value at `index` with the pending corrections that apply to it.
    fn value(&self, index: usize) -> Vector3<f32> {
        let mut value = self.values[index];
        let time = self.times_ticks[index];
        for c in 0..self.pending_len {
            let correction = &self.pending[(self.pending_head + c) % PENDING_CORRECTIONS];
            // Kept at or before the correction was made (ages then, wrapping differences).
            let before = correction.made_ticks.wrapping_sub(time);
            if before <= self.clock_ticks.wrapping_sub(time) {
                value += correction.at(before as f32 * TICK_S);
            }
        }
        value
    }

    /// The value `age_s` ago (`current` now), linear between the kept ones; the oldest kept one
    /// for older ages.
    fn at(&self, age_s: f32, current: &Vector3<f32>) -> Vector3<f32> {
        if self.len == 0 {
            return *current;
        }
        // The first value at least `age_s` old: from the spacing, then a step or two.
        let newest_age = self.age_s(self.newest);
        let mut k = if age_s <= newest_age {
            0
        } else {
            let steps = (age_s - newest_age) * (1.0 / HISTORY_SPACING_S);
            (steps as usize + 1).min(self.len - 1)
        };
        while k + 1 < self.len && self.age_s(self.index(k)) < age_s {
            k += 1;
        }
        while k > 0 && self.age_s(self.index(k - 1)) >= age_s {
            k -= 1;
        }
        let i = self.index(k);
        let age = self.age_s(i);
        if age < age_s {
            // Older than everything kept.
            return self.value(i);
        }
        let (newer_age, newer) = if k == 0 {
            (0.0, *current)
        } else {
            let j = self.index(k - 1);
            (self.age_s(j), self.value(j))
        };
        let span = age - newer_age;
        let w = if span > 0.0 { (age_s - newer_age) / span } else { 0.0 };
        newer + (self.value(i) - newer) * crate::math::clamp(w, 0.0, 1.0)
    }

    /// The rate of change `age_s` ago (per second; `current` now): the central difference over
    /// one spacing either side, exact for a value that changes as a parabola (a position under a
    /// constant acceleration), so the velocity of a fix's time needs no history of its own.
    fn slope_at(&self, age_s: f32, current: &Vector3<f32>) -> Vector3<f32> {
        let h = HISTORY_SPACING_S;
        let newer_age = (age_s - h).max(0.0);
        let older_age = age_s + h;
        (self.at(newer_age, current) - self.at(older_age, current)) / (older_age - newer_age)
    }

    /// Add `dp + dv τ − db τ²/2` to every value younger than `age_s`, `τ` after that time
    /// (a correction made at a fix's time): kept pending ([`Correction`]).
    fn shift(&mut self, age_s: f32, dp: Vector3<f32>, dv: Vector3<f32>, db: Vector3<f32>) {
        if self.len == 0 || age_s <= 0.0 {
            return;
        }
        // Corrections whose values are all gone apply to nothing any more.
        let oldest = self.times_ticks[self.index(self.len - 1)];
        while self.pending_len > 0
            && self.clock_ticks.wrapping_sub(self.pending[self.pending_head].made_ticks)
                > self.clock_ticks.wrapping_sub(oldest)
        {
            self.drop_oldest(1, false);
        }
        if self.pending_len == PENDING_CORRECTIONS {
            self.drop_oldest(1, true);
        }
        let slot = (self.pending_head + self.pending_len) % PENDING_CORRECTIONS;
        self.pending[slot] = Correction { made_ticks: self.clock_ticks, age_s, dp, dv, db };
        self.pending_len += 1;
    }

    /// Remove the `n` oldest pending corrections (at most as many as are pending), added to
    /// the values first when `fold`.
    fn drop_oldest(&mut self, n: usize, fold: bool) {
        let n = n.min(self.pending_len);
        for _ in 0..n {
            let correction = self.pending[self.pending_head];
            self.pending_head = (self.pending_head + 1) % PENDING_CORRECTIONS;
            self.pending_len -= 1;
            if fold {
                for k in 0..self.len {
                    let i = self.index(k);
                    let before = correction.made_ticks.wrapping_sub(self.times_ticks[i]);
                    if before > self.clock_ticks.wrapping_sub(self.times_ticks[i]) {
                        // Kept after the correction was made.
                        continue;
                    }
                    let age_then_s = before as f32 * TICK_S;
                    if age_then_s >= correction.age_s {
                        break;
                    }
                    self.values[i] += correction.at(age_then_s);
                }
            }
        }
    }
}

/// The estimator's output.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NavigationState {
    /// Position of the CoG, world NED, m (meaningful only once a fix has been taken).
    pub position_ned_m: Vector3<f32>,
    /// Velocity, world NED, m/s.
    pub velocity_ned_mps: Vector3<f32>,
    /// Accelerometer bias estimate, world NED, m/s².
    pub accel_bias_ned_mps2: Vector3<f32>,
    /// Whether a fix arrived within [`FIX_TIMEOUT_S`].
    pub has_fix: bool,
}

/// Why an input was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NavigationError {
    /// A non-finite value, a non-positive time step, or a fix age that is negative, not finite
    /// or beyond [`MAX_FIX_AGE_S`].
    BadInput,
}

/// The position and velocity estimator.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct PositionEstimator {
    crossover_rad_s: f32,
    state: NavigationState,
    /// Time since the last fix, s.
    since_fix_s: f32,
    /// Whether any fix has been taken since the last reset.
    fixed_once: bool,
    /// The predicted positions of the last [`HISTORY_SPAN_S`].
    history: History,
    /// Time since the last fix taken (not refused), s.
    since_taken_s: f32,
    /// Time since the last fix's velocity was taken (not refused), s.
    since_velocity_taken_s: f32,
    /// Fixes refused as outliers since start-up.
    rejected: u32,
}

impl Default for PositionEstimator {
    fn default() -> Self {
        Self::new(DEFAULT_CROSSOVER_RAD_S)
    }
}

impl PositionEstimator {
    /// An estimator at rest at the origin, with fixes weighed by `crossover_rad_s` (a
    /// non-finite or non-positive value takes [`DEFAULT_CROSSOVER_RAD_S`]).
    pub fn new(crossover_rad_s: f32) -> Self {
        let crossover_rad_s = if crossover_rad_s.is_finite() && crossover_rad_s > 0.0 {
            crossover_rad_s
        } else {
            DEFAULT_CROSSOVER_RAD_S
        };
        Self {
            crossover_rad_s,
            state: NavigationState::default(),
            since_fix_s: f32::INFINITY,
            fixed_once: false,
            history: History::default(),
            since_taken_s: f32::INFINITY,
            since_velocity_taken_s: f32::INFINITY,
            rejected: 0,
        }
    }

    /// Fixes refused as outliers since start-up.
    pub fn rejected(&self) -> u32 {
        self.rejected
    }

    /// The crossover in use, rad/s.
    pub fn crossover_rad_s(&self) -> f32 {
        self.crossover_rad_s
    }

    /// The estimate.
    pub fn state(&self) -> &NavigationState {
        &self.state
    }

    /// The craft is at rest (held in the hand, on the ground): the velocity is zero.
    pub fn hold_still(&mut self) {
        self.state.velocity_ned_mps = Vector3::zeros();
    }

    /// Replace the velocity (world NED, m/s) and forget the accelerometer bias: the world the
    /// accelerometer was turned into has changed (a new heading alignment).
    pub fn set_velocity(&mut self, velocity_ned_mps: &Vector3<f32>) {
        if velocity_ned_mps.iter().all(|x| x.is_finite()) {
            self.state.velocity_ned_mps = *velocity_ned_mps;
            self.state.accel_bias_ned_mps2 = Vector3::zeros();
        }
    }

    /// Integrate one step of `dt_s` with the specific force at the CoG `f_body_mps2` (body axes)
    /// and the attitude `q_world_body`.
    pub fn predict(
        &mut self,
        q_world_body: &UnitQuaternion<f32>,
        f_body_mps2: &Vector3<f32>,
        dt_s: f32,
    ) -> Result<(), NavigationError> {
        if !is_step(dt_s) || !f_body_mps2.iter().all(|x| x.is_finite()) {
            return Err(NavigationError::BadInput);
        }
        let s = &mut self.state;
        let accel = q_world_body * f_body_mps2 + Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2)
            - s.accel_bias_ned_mps2;
        s.position_ned_m += s.velocity_ned_mps * dt_s + accel * (0.5 * dt_s * dt_s);
        s.velocity_ned_mps += accel * dt_s;
        self.history.advance(dt_s, &s.position_ned_m);
        self.since_fix_s += dt_s;
        self.since_taken_s += dt_s;
        self.since_velocity_taken_s += dt_s;
        s.has_fix = self.since_fix_s <= FIX_TIMEOUT_S;
        Ok(())
    }

    /// Correct with a position fix of the CoG `position_ned_m` that describes now, `dt_fix_s`
    /// after the previous fix: [`Self::correct_late`] with age 0.
    pub fn correct(
        &mut self,
        position_ned_m: &Vector3<f32>,
        dt_fix_s: f32,
    ) -> Result<(), NavigationError> {
        self.correct_late(position_ned_m, 0.0, dt_fix_s)
    }

    /// Correct with a position fix of the CoG `position_ned_m` that describes the craft `age_s`
    /// ago (its latency; at most [`MAX_FIX_AGE_S`]), taken `dt_fix_s` after the previous fix
    /// (the fix spacing, s). The first fix (or the first after [`FIX_TIMEOUT_S`]) sets the
    /// position outright.
    pub fn correct_late(
        &mut self,
        position_ned_m: &Vector3<f32>,
        age_s: f32,
        dt_fix_s: f32,
    ) -> Result<(), NavigationError> {
        let age_ok = age_s.is_finite() && (0.0..=MAX_FIX_AGE_S).contains(&age_s);
        if !position_ned_m.iter().all(|x| x.is_finite()) || !is_step(dt_fix_s) || !age_ok {
            return Err(NavigationError::BadInput);
        }
        let s = &self.state;
        let error = position_ned_m - self.history.at(age_s, &s.position_ned_m);
        if !self.fixed_once || self.since_fix_s > FIX_TIMEOUT_S {
            // The whole track moves onto the fix.
            self.carry_forward(age_s, error, Vector3::zeros(), Vector3::zeros());
        } else {
            let (k_p, k_v, k_b) = gains(self.crossover_rad_s, dt_fix_s);
            let bias = (s.accel_bias_ned_mps2 - error * k_b)
                .map(|b| b.clamp(-MAX_BIAS_MPS2, MAX_BIAS_MPS2));
            let db = bias - s.accel_bias_ned_mps2;
            self.carry_forward(age_s, error * k_p, error * k_v, db);
        }
        self.fix_taken();
        Ok(())
    }

    /// Apply a correction made at the fix's time (`age_s` ago): `dp`, `dv` and the bias change
    /// `db`, carried forward through the model to now and to the history since then (a bias
    /// change changes the acceleration by −Δb from then on).
    fn carry_forward(&mut self, age_s: f32, dp: Vector3<f32>, dv: Vector3<f32>, db: Vector3<f32>) {
        let s = &mut self.state;
        s.position_ned_m += dp + dv * age_s - db * (0.5 * age_s * age_s);
        s.velocity_ned_mps += dv - db * age_s;
        s.accel_bias_ned_mps2 += db;
        self.history.shift(age_s, dp, dv, db);
    }

    /// A fix arrived and was taken: the estimate has a fix again.
    fn fix_taken(&mut self) {
        self.fixed_once = true;
        self.since_fix_s = 0.0;
        self.since_taken_s = 0.0;
        self.state.has_fix = true;
    }

    /// Correct with `fix`, weighted by its stated accuracy: the position with the crossover
    /// [`crossover_for_noise`] of its noise (horizontal and vertical each their own); with a
    /// velocity, the velocity and the accelerometer bias from the velocity's error at the
    /// [`velocity_crossover`] of its noise, and the position then only first-order at
    /// [`POSITION_WITH_VELOCITY_FACTOR`] of its crossover. Compared with the estimates of the
    /// fix's time (`age_s` ago) and carried forward as in [`Self::correct_late`]. A fix whose
    /// horizontal or vertical innovation exceeds the gate (`max(`[`MIN_OUTLIER_GATE_M`]`,`
    /// [`OUTLIER_SIGMAS`]` × its RMS error) + `[`OUTLIER_DRIFT_AIDED_MPS`]` t`, `t` since the last
    /// position taken; only a fix with a velocity, see there) is
    /// refused and counted, until refusals have lasted [`MAX_REJECT_S`]; a velocity beyond
    /// `max(`[`MIN_VELOCITY_GATE_MPS`]`,`[`OUTLIER_SIGMAS`]` × √3 σ_v)` is left out, until
    /// velocities have been refused for [`VELOCITY_MAX_REJECT_S`]: then the whole track moves
    /// onto the fix (a [`FixOutcome::Reset`]).
    pub fn correct_fix(&mut self, fix: &Fix) -> Result<FixOutcome, NavigationError> {
        let mut innovation = self.innovation(fix)?;
        self.velocity_innovation(&mut innovation, 0.0);
        let weights = weigh(&innovation);
        Ok(self.apply(&innovation, &weights, 0.0))
    }

    /// The first part of [`Self::correct_fix`]: `fix` checked and its position compared with
    /// the estimate of its time; nothing changed. The other parts ([`Self::velocity_innovation`],
    /// [`weigh`], [`Self::apply`]) may each run in a later control step: a fix is 50–150 ms old
    /// when it arrives, and splitting keeps each step's share of the work small
    /// (`firmware::app::fix_parts`). No other fix may be applied in between: the innovation is
    /// the difference with a history that fix would change.
    pub fn innovation(&self, fix: &Fix) -> Result<Innovation, NavigationError> {
        let Fix { position_ned_m, sigma_m, velocity, age_s, dt_fix_s } = *fix;
        let age_ok = age_s.is_finite() && (0.0..=MAX_FIX_AGE_S).contains(&age_s);
        let sigma_ok = sigma_m.iter().all(|x| x.is_finite() && *x > 0.0);
        let velocity_ok = velocity.is_none_or(|(v, noise)| {
            v.iter().all(|x| x.is_finite()) && noise.is_finite() && noise > 0.0
        });
        if !position_ned_m.iter().all(|x| x.is_finite())
            || !is_step(dt_fix_s)
            || !age_ok
            || !sigma_ok
            || !velocity_ok
        {
            return Err(NavigationError::BadInput);
        }
        let error = position_ned_m - self.history.at(age_s, &self.state.position_ned_m);
        Ok(Innovation { fix: *fix, error, velocity_error: None })
    }

    /// The second part of [`Self::correct_fix`]: the fix's velocity (if any) compared with the
    /// estimate of its time, `later_s` after [`Self::innovation`] (the fix is then that much
    /// older).
    pub fn velocity_innovation(&self, innovation: &mut Innovation, later_s: f32) {
        let Some((velocity, noise)) = innovation.fix.velocity else { return };
        let age_s = (innovation.fix.age_s + later_s.max(0.0)).min(MAX_FIX_AGE_S);
        let slope = self.history.slope_at(age_s, &self.state.position_ned_m);
        innovation.velocity_error = Some((velocity - slope, noise));
    }

    /// The last part of [`Self::correct_fix`]: the gate and the correction of an
    /// `innovation` with its `weights` ([`weigh`]), `later_s` after [`Self::innovation`] (the
    /// correction is carried forward over the fix's age plus `later_s`).
    pub fn apply(
        &mut self,
        innovation: &Innovation,
        weights: &Weights,
        later_s: f32,
    ) -> FixOutcome {
        let Innovation { fix, error, .. } = *innovation;
        let later_s = if later_s.is_finite() { later_s.max(0.0) } else { 0.0 };
        let age_s = (fix.age_s + later_s).min(MAX_FIX_AGE_S);
        let sigma_m = fix.sigma_m;
        let velocity_error = weights.velocity.map(|(ev, _, _)| ev);
        let s = self.state;
        let restart = !self.fixed_once || self.since_fix_s > FIX_TIMEOUT_S;
        let t = self.since_taken_s;
        let gate = |rms_m: f32| {
            (OUTLIER_SIGMAS * rms_m).max(MIN_OUTLIER_GATE_M) + OUTLIER_DRIFT_AIDED_MPS * t
        };
        let outlier = velocity_error.is_some()
            && (crate::math::hypot(error.x, error.y)
                > gate(core::f32::consts::SQRT_2 * sigma_m[0])
                || error.z.abs() > gate(sigma_m[1]));
        let velocity_refused = innovation.velocity_error.is_some() && velocity_error.is_none();
        let velocity_lost =
            velocity_refused && self.since_velocity_taken_s >= VELOCITY_MAX_REJECT_S;
        if innovation.velocity_error.is_some() && !velocity_refused {
            self.since_velocity_taken_s = 0.0;
        }
        let outcome = if restart || velocity_lost || (outlier && t >= MAX_REJECT_S) {
            // The whole track moves onto the fix, and turns to its velocity (taken whatever its
            // gate said: the estimate it was compared with is the one being replaced).
            let dv = innovation.velocity_error.map_or_else(Vector3::zeros, |(ev, _)| ev);
            self.carry_forward(age_s, error, dv, Vector3::zeros());
            if innovation.velocity_error.is_some() {
                self.since_velocity_taken_s = 0.0;
            }
            FixOutcome::Reset
        } else {
            let (mut dp, mut dv, mut db) = (Vector3::zeros(), Vector3::zeros(), Vector3::zeros());
            for i in 0..3 {
                let (k_p, k_v, k_b) = if i < 2 { weights.horizontal } else { weights.vertical };
                let b = s.accel_bias_ned_mps2[i];
                // An outlier's position teaches nothing; its velocity (a Doppler measurement
                // multipath hardly moves) still does.
                let e = if outlier { 0.0 } else { error[i] };
                dp[i] = e * k_p;
                let new_b = match weights.velocity {
                    None => {
                        dv[i] = e * k_v;
                        b - e * k_b
                    }
                    Some((ev, k_vv, k_bv)) => {
                        dv[i] = ev[i] * k_vv;
                        b - ev[i] * k_bv
                    }
                };
                db[i] = new_b.clamp(-MAX_BIAS_MPS2, MAX_BIAS_MPS2) - b;
            }
            self.carry_forward(age_s, dp, dv, db);
            if outlier {
                // The source is alive, its position not believed: the gate keeps widening.
                self.rejected = self.rejected.wrapping_add(1);
                let since_taken_s = self.since_taken_s;
                self.fix_taken();
                self.since_taken_s = since_taken_s;
                return FixOutcome::Rejected;
            }
            FixOutcome::Taken
        };
        self.fix_taken();
        outcome
    }
}

/// A fix compared with the estimates of its time ([`PositionEstimator::innovation`] and
/// [`PositionEstimator::velocity_innovation`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Innovation {
    /// The fix.
    pub fix: Fix,
    /// Its position less the estimate of its time, m.
    pub error: Vector3<f32>,
    /// Its velocity less the estimate of its time, m/s, with the velocity's noise (once
    /// compared).
    pub velocity_error: Option<(Vector3<f32>, f32)>,
}

/// How much of an innovation the estimator takes ([`weigh`]): the gains `(k_p, k_v, k_b)` of
/// the position, horizontal and vertical, and the velocity's error with its gains `(k_v, k_b)`
/// when it passed its gate.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Weights {
    /// The horizontal position's gains (1, 1/s, 1/s²).
    pub horizontal: (f32, f32, f32),
    /// The vertical position's gains.
    pub vertical: (f32, f32, f32),
    /// The velocity's error (m/s) and its gains (1, 1/s), when it passed its gate.
    pub velocity: Option<(Vector3<f32>, f32, f32)>,
}

/// The third part of [`PositionEstimator::correct_fix`], from the fix alone (no state): the
/// velocity's gate (`max(`[`MIN_VELOCITY_GATE_MPS`]`,`[`OUTLIER_SIGMAS`]` × √3 σ_v)`: beyond, it is
/// left out), then the gains by the fix's stated accuracy: the position's at the crossover
/// [`crossover_for_noise`] of its noise (horizontal and vertical each their own, once when the
/// same, as motion capture's); with a velocity, the velocity's and the bias's at the
/// [`velocity_crossover`] of its noise (a double pole at `exp(−ω T)`), and the position's then
/// first-order at [`POSITION_WITH_VELOCITY_FACTOR`] of its crossover.
pub fn weigh(innovation: &Innovation) -> Weights {
    let Fix { sigma_m, dt_fix_s, .. } = innovation.fix;
    // A 3D velocity's RMS error is √3 σ.
    let velocity_error = innovation.velocity_error.filter(|(ev, noise)| {
        crate::math::norm(ev) <= (OUTLIER_SIGMAS * SQRT_3 * noise).max(MIN_VELOCITY_GATE_MPS)
    });
    let position_gains = |sigma: f32| match velocity_error {
        None => gains(crossover_for_noise(sigma), dt_fix_s),
        Some(_) => (-libm::expm1f(-position_crossover(sigma, true) * dt_fix_s), 0.0, 0.0),
    };
    let horizontal = position_gains(sigma_m[0]);
    let vertical = if sigma_m[1] == sigma_m[0] { horizontal } else { position_gains(sigma_m[1]) };
    let velocity = velocity_error.map(|(ev, noise)| {
        let m = -libm::expm1f(-velocity_crossover(noise, dt_fix_s) * dt_fix_s);
        (ev, 2.0 * m - m * m, m * m / dt_fix_s)
    });
    Weights { horizontal, vertical, velocity }
}

/// The correction gains `(k_p, k_v, k_b)` (1, 1/s, 1/s²) that put the three poles of the error
/// dynamics over one fix interval `dt_fix_s` at `exp(−ω_c dt_fix_s)` (see the module doc).
fn gains(crossover_rad_s: f32, dt_fix_s: f32) -> (f32, f32, f32) {
    let m = -libm::expm1f(-crossover_rad_s * dt_fix_s);
    let (m2, m3) = (m * m, m * m * m);
    let k_p = 3.0 * m - 3.0 * m2 + m3;
    let k_v = (3.0 * m2 - 1.5 * m3) / dt_fix_s;
    let k_b = m3 / (dt_fix_s * dt_fix_s);
    (k_p, k_v, k_b)
}

/// Whether `dt_s` is a usable time step: finite and positive.
fn is_step(dt_s: f32) -> bool {
    dt_s.is_finite() && dt_s > 0.0
}

/// Shortest window over which [`HeadingAlignment`] compares accelerations, s (0.1 s: long enough
/// for a 1 m/s² acceleration to move the craft 1 cm, ten times the motion-capture noise).
pub const MIN_ALIGNMENT_WINDOW_S: f32 = 0.1;

/// Longest window, s (ours): the recovery after a throw accelerates the craft for about a second,
/// and a window much longer than that only adds dead-reckoning error.
pub const MAX_ALIGNMENT_WINDOW_S: f32 = 2.5;

/// Acceleration a window should resolve, m/s², against the fixes' noise: the window is long
/// enough for it to give a second difference of ten noise standard deviations (ours).
pub const ALIGNMENT_REFERENCE_ACCEL_MPS2: f32 = 1.0;

/// The window for fixes with `noise_m` of noise (one standard deviation per axis, m): the time
/// `T` in which [`ALIGNMENT_REFERENCE_ACCEL_MPS2`] makes a second difference `a T²` of ten
/// standard deviations, within [`MIN_ALIGNMENT_WINDOW_S`] and [`MAX_ALIGNMENT_WINDOW_S`]: 0.1 s up to
/// 1 mm of noise (motion capture), 0.71 s for 5 cm, 2.2 s for 0.5 m (GNSS).
pub fn alignment_window_s(noise_m: f32) -> f32 {
    let noise = if noise_m.is_finite() && noise_m > 0.0 { noise_m } else { 0.0 };
    crate::math::sqrt(10.0 * noise / ALIGNMENT_REFERENCE_ACCEL_MPS2)
        .clamp(MIN_ALIGNMENT_WINDOW_S, MAX_ALIGNMENT_WINDOW_S)
}

/// Slots (averaged fixes) per window: fixes are grouped by time into slots of a sixteenth of
/// the window, so a 2 kHz stream and a 100 Hz one give the same windows, and the fixes within a
/// slot average their noise down.
pub const ALIGNMENT_SLOTS_PER_WINDOW: usize = 16;

/// Slots kept: two windows and a margin (a slot spans at least a sixteenth of the window).
const ALIGNMENT_SLOTS: usize = 2 * ALIGNMENT_SLOTS_PER_WINDOW + 4;

/// Evidence needed before the heading alignment is trusted, in "seconds of windows that saw
/// 2 m/s²" (0.2 s): the coherent sum `|Σ w (D'·D) + i Σ w (D'×D)|`, each window weighted by the
/// time `w` it stands for, must reach `ALIGNMENT_EVIDENCE_S · (2 m/s² · T²)²` m²·s. Noise and
/// unrelated motion average out of a coherent sum, unlike a sum of magnitudes. At `T` = 0.1 s
/// and 100 Hz this is the twenty windows of 2 cm the alignment has always asked for.
pub const ALIGNMENT_EVIDENCE_S: f32 = 0.2;

/// How many times the evidence must exceed its own noise (one standard deviation, from the
/// fixes' noise and the slots' averaging): 30 puts one standard deviation of the yaw below 2°.
/// With motion capture this is met long before [`ALIGNMENT_EVIDENCE_S`]; with 0.5 m of noise it is
/// what decides, and the alignment takes as long as the motion needs to rise above the noise.
pub const ALIGNMENT_SIGNIFICANCE: f32 = 30.0;

/// Acceleration the velocity window should resolve against the fixes' velocity noise, m/s²
/// (ours, as [`ALIGNMENT_REFERENCE_ACCEL_MPS2`]): the window `T` gives a velocity difference
/// `a T` of ten noise standard deviations.
pub const VELOCITY_ALIGNMENT_REFERENCE_ACCEL_MPS2: f32 = 1.0;

/// Bounds of the velocity window, s (ours): at least two fixes of a 10 Hz stream apart, at most
/// 2 s (a velocity noise of 0.2 m/s, the worst the randomised world draws).
pub const VELOCITY_ALIGNMENT_WINDOW_S: (f32, f32) = (0.2, 2.0);

/// How many times the velocity evidence must exceed its own noise (ours): 10, one standard
/// deviation of the yaw about 6°, where the positions ask for 30 (2°). A craft without the yaw
/// cannot brake on the fixes' velocity and drifts (seed 118 of the GNSS Monte Carlo went 16 m
/// in the 6.5 s the stricter bound took on a slow drift), while a velocity loop flown 6° off
/// still brakes with 99.5 % of its gain; the yaw goes on refining as the sums grow.
pub const VELOCITY_ALIGNMENT_SIGNIFICANCE: f32 = 10.0;

/// Velocity fixes kept for the velocity differences: the longest window of a 10 Hz stream and
/// a margin.
const VELOCITY_POINTS: usize = 24;

/// The window of velocity fixes with `noise_mps` of noise per axis, s: `10 σ_v / a` with `a`
/// [`VELOCITY_ALIGNMENT_REFERENCE_ACCEL_MPS2`], within [`VELOCITY_ALIGNMENT_WINDOW_S`]: 0.5 s
/// for a receiver's 5 cm/s.
pub fn velocity_alignment_window_s(noise_mps: f32) -> f32 {
    let noise = if noise_mps.is_finite() && noise_mps > 0.0 { noise_mps } else { 0.0 };
    let (low, high) = VELOCITY_ALIGNMENT_WINDOW_S;
    (10.0 * noise / VELOCITY_ALIGNMENT_REFERENCE_ACCEL_MPS2).clamp(low, high)
}

/// The variance of one component of a velocity difference of fixes with `noise_mps` of noise:
/// each component has the noise of two fixes (interpolation only lowers it).
fn var_d_of(noise_mps: f32) -> f32 {
    2.0 * noise_mps * noise_mps
}

/// A velocity fix and the dead-reckoned velocity of its time.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct VelocityPoint {
    t_s: f32,
    fix: Vector3<f32>,
    dead: Vector3<f32>,
}

/// The yaw from velocity fixes (a GNSS receiver's Doppler velocity): the same coherent sum as
/// the positions' ([`HeadingAlignment`]), over first differences of velocity `Δv = v(t) − v(t−T)`
/// instead of second differences of position. Both are integrals of the acceleration, but a
/// velocity difference carries far less noise: 5 cm/s of velocity noise against 0.3 m of
/// position noise resolves 1 m/s² in 0.5 s instead of 1.7 s, with twenty times the margin.
///
/// **A tilted attitude.** The filter's attitude may be a few degrees off after a tumble, and in
/// flight nothing but the fixes shows it: the craft then accelerates at `g · sin(tilt error)` in
/// the fixes' world while the dead reckoning sees nothing (the random world's seed 212: 5.5°,
/// 1 m/s² for 20 s, 95 m). Every velocity difference then carries the same extra `b T`, which
/// turns the coherent sum towards the wrong yaw. So the sums are kept centred too (each
/// window's differences less their weighted means, which removes any constant `b`): the plain
/// sum's yaw is taken only when the constant it leaves unexplained is below
/// [`MAX_ALIGNMENT_BIAS_MPS2`]; beyond, the centred sum's, once it is significant itself.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct VelocityAlignment {
    noise_mps: f32,
    window_s: f32,
    #[serde(with = "crate::serde_array")]
    points: [VelocityPoint; VELOCITY_POINTS],
    head: usize,
    filled: usize,
    cross: f32,
    dot: f32,
    noise_var: f32,
    evidence: f32,
    /// Σ w, Σ w², and the weighted sums of the differences (horizontal), for the centred sums.
    weight: f32,
    weight2: f32,
    sum_dead: [f32; 2],
    sum_fix: [f32; 2],
    /// Σ w² Δd, for the centred sum's noise.
    sum_dead_w2: [f32; 2],
}

/// Largest constant acceleration, fixes' world, the plain velocity alignment may leave
/// unexplained, m/s² (ours): `g · sin 2°`, the filter's tilt error beyond which the yaw of the
/// plain sum is more than a few degrees off (a constant of 0.34 m/s² against the nudge's
/// 1 m/s²). Beyond it the centred sum decides ([`VelocityAlignment`]).
pub const MAX_ALIGNMENT_BIAS_MPS2: f32 = 0.34;

/// Share of the plain sums' evidence ([`ALIGNMENT_EVIDENCE_S`]) the centred sums need (ours).
/// The evidence floor keeps a yaw from being trusted on motion the dead reckoning got wrong;
/// the centred sums have the constant part of that error taken out (a filter left tilted by a
/// tumble, which before the alignment nothing corrects), and what remains is bounded by their
/// significance test, the plain sums' own. Measured on 1,000 runs of the random receiver world
/// (`fly --gnss monte-carlo --world random --gnss-random`): runs ending more than 10 m from
/// their recovery 30 with the whole floor, 15 with half, 14 with a quarter and 14 with none,
/// where the significance alone decides. The craft drifts at the tilt's `g · sin e` while it
/// waits (seed 160: 8°, 4.6 m/s and 50 m).
pub const CENTRED_EVIDENCE_SHARE: f32 = 0.25;

impl VelocityAlignment {
    fn new(noise_mps: f32) -> Self {
        Self {
            noise_mps,
            window_s: velocity_alignment_window_s(noise_mps),
            points: [VelocityPoint::default(); VELOCITY_POINTS],
            head: 0,
            filled: 0,
            cross: 0.0,
            dot: 0.0,
            noise_var: 0.0,
            evidence: 0.0,
            weight: 0.0,
            weight2: 0.0,
            sum_dead: [0.0; 2],
            sum_fix: [0.0; 2],
            sum_dead_w2: [0.0; 2],
        }
    }

    /// The fix and dead velocities at `t_s`, linear between the two points around it; `None`
    /// outside the points kept.
    fn at(&self, t_s: f32) -> Option<(Vector3<f32>, Vector3<f32>)> {
        let mut newer: Option<&VelocityPoint> = None;
        for k in 0..self.filled {
            let point = &self.points[(self.head + VELOCITY_POINTS - k) % VELOCITY_POINTS];
            if point.t_s <= t_s {
                let newer = newer?;
                let span = newer.t_s - point.t_s;
                let a = if span > 0.0 { ((t_s - point.t_s) / span).clamp(0.0, 1.0) } else { 0.0 };
                return Some((
                    point.fix + (newer.fix - point.fix) * a,
                    point.dead + (newer.dead - point.dead) * a,
                ));
            }
            newer = Some(point);
        }
        None
    }

    /// Take a velocity fix; the yaw once the evidence suffices.
    fn add(&mut self, point: VelocityPoint) -> Option<f32> {
        let t = self.window_s;
        let previous_t_s = (self.filled > 0).then(|| self.points[self.head].t_s);
        if let (Some(previous_t_s), Some((fix_then, dead_then))) =
            (previous_t_s, self.at(point.t_s - t))
        {
            let d = point.fix - fix_then;
            let d_filter = point.dead - dead_then;
            let w = crate::math::clamp(point.t_s - previous_t_s, 0.0, t);
            let var_d = var_d_of(self.noise_mps);
            let (dx, dy) = (d_filter.x, d_filter.y);
            self.cross += w * (dx * d.y - dy * d.x);
            self.dot += w * (dx * d.x + dy * d.y);
            self.noise_var += w * w * (dx * dx + dy * dy) * var_d;
            self.evidence = crate::math::sqrt(self.cross * self.cross + self.dot * self.dot);
            self.weight += w;
            self.weight2 += w * w;
            self.sum_dead = [self.sum_dead[0] + w * dx, self.sum_dead[1] + w * dy];
            self.sum_fix = [self.sum_fix[0] + w * d.x, self.sum_fix[1] + w * d.y];
            self.sum_dead_w2 = [self.sum_dead_w2[0] + w * w * dx, self.sum_dead_w2[1] + w * w * dy];
        }
        self.head = (self.head + 1) % VELOCITY_POINTS;
        self.points[self.head] = point;
        self.filled = (self.filled + 1).min(VELOCITY_POINTS);
        let needed = ALIGNMENT_EVIDENCE_S * (2.0 * t) * (2.0 * t);
        let significant =
            self.evidence >= VELOCITY_ALIGNMENT_SIGNIFICANCE * crate::math::sqrt(self.noise_var);
        if !(self.evidence >= needed && significant) || self.weight <= 0.0 {
            return None;
        }
        let yaw = libm::atan2f(self.cross, self.dot);
        // What the plain yaw leaves unexplained per window, as an acceleration: the weighted
        // mean of `Δf − R(yaw) Δd`, over the window's length. The yaw's sine and cosine are
        // the sums' over their length (the evidence, positive here).
        let (sin, cos) = (self.cross / self.evidence, self.dot / self.evidence);
        let [sdx, sdy] = self.sum_dead;
        let [sfx, sfy] = self.sum_fix;
        let bias_x = (sfx - (cos * sdx - sin * sdy)) / self.weight;
        let bias_y = (sfy - (sin * sdx + cos * sdy)) / self.weight;
        let bias_mps2 = crate::math::sqrt(bias_x * bias_x + bias_y * bias_y) / t;
        if bias_mps2 <= MAX_ALIGNMENT_BIAS_MPS2 {
            return Some(yaw);
        }
        self.centred_yaw(CENTRED_EVIDENCE_SHARE * needed, var_d_of(self.noise_mps))
    }

    /// The yaw of the centred sums (module doc of [`VelocityAlignment`]), once they hold the
    /// evidence `needed` with the significance the plain sums need; each difference's variance
    /// per component is `var_d`.
    fn centred_yaw(&self, needed: f32, var_d: f32) -> Option<f32> {
        let w = self.weight;
        let [sdx, sdy] = self.sum_dead;
        let [sfx, sfy] = self.sum_fix;
        let cross = self.cross - (sdx * sfy - sdy * sfx) / w;
        let dot = self.dot - (sdx * sfx + sdy * sfy) / w;
        let evidence = crate::math::sqrt(cross * cross + dot * dot);
        // Σ w² |Δd − μ|² = Σ w²|Δd|² − 2 μ·Σ w² Δd + |μ|² Σ w², with μ = Σ w Δd / Σ w.
        let (mx, my) = (sdx / w, sdy / w);
        let [px, py] = self.sum_dead_w2;
        let spread = self.noise_var / var_d.max(f32::MIN_POSITIVE) - 2.0 * (mx * px + my * py)
            + (mx * mx + my * my) * self.weight2;
        let noise_var = spread.max(0.0) * var_d;
        let significant =
            evidence >= VELOCITY_ALIGNMENT_SIGNIFICANCE * crate::math::sqrt(noise_var);
        (evidence >= needed && significant).then(|| libm::atan2f(cross, dot))
    }

    /// Move every kept time back by `by_s` (the alignment's clock rebased).
    fn rebase(&mut self, by_s: f32) {
        for point in &mut self.points {
            point.t_s -= by_s;
        }
    }
}

/// Fixes averaged over one slot of the window.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct Slot {
    /// Mean capture time on the alignment's clock, s.
    t_s: f32,
    /// Mean fix position, the poses' world, m.
    fix: Vector3<f32>,
    /// Mean dead-reckoned position at the same times, the filter's world, m.
    dead: Vector3<f32>,
    /// Fixes in the slot.
    n: u32,
}

impl Slot {
    fn add(&mut self, t_s: f32, fix: &Vector3<f32>, dead: &Vector3<f32>) {
        self.n += 1;
        let w = 1.0 / self.n as f32;
        self.t_s += (t_s - self.t_s) * w;
        self.fix += (fix - self.fix) * w;
        self.dead += (dead - self.dead) * w;
    }
}

/// A point of a window: the slots interpolated to a time.
#[derive(Clone, Copy, Debug)]
struct WindowPoint {
    fix: Vector3<f32>,
    dead: Vector3<f32>,
    /// `Σ weight²/n` over the two slots: the point's noise variance per fix variance.
    noise_factor: f32,
}

/// The alignment's clock is moved back by this much whenever it passes it, s, so that f32
/// times keep a resolution of 0.1 ms or better.
const CLOCK_REBASE_S: f32 = 1000.0;

/// The yaw between the attitude filter's world and the world of the position fixes.
///
/// Without a compass the attitude filter's heading is arbitrary, and an external heading is
/// that of a frame (the motion-capture body) whose yaw relative to the IMU nobody told us. The
/// position fixes fix it: the second difference of positions over a window `T`,
/// `D = p(t) − 2p(t−T) + p(t−2T)`, is the double integral of the acceleration and does not depend
/// on the velocity; the same second difference of the filter's own dead reckoning `D'` is that
/// integral seen in the filter's world. `D = R_z(ψ) D'`, so `ψ = atan2(Σ D'×D, Σ D'·D)` over the
/// windows (horizontal components). Any horizontal acceleration informs it: the recovery
/// after a throw, and the position loop's own corrections.
///
/// **In time, not in fixes.** The window is a time span ([`alignment_window_s`] of the fixes'
/// noise); fixes are averaged into slots of `T/16` by their capture time, the points `T` and
/// `2T` back are interpolated between slots, and each window counts for the time since the
/// previous one. The dead-reckoned positions go through exactly the same averaging and
/// interpolation at the same times, so `D = R_z(ψ) D'` holds whatever the fix rate (10 Hz to
/// 2 kHz), spacing or dropouts; only how much evidence a second of motion gives depends on them.
/// A late fix (age `L`) is paired with the dead reckoning `L` ago (a short history, as in
/// [`PositionEstimator`]).
///
/// **What it assumes.** The two worlds differ by a yaw alone (both vertical axes are
/// gravity's), the fixes' noise is independent with the standard deviation it was built for,
/// and the dead reckoning is good over `2T` (its acceleration error times `T²` small against
/// `D`). Trust needs [`ALIGNMENT_EVIDENCE_S`] of motion and [`ALIGNMENT_SIGNIFICANCE`] times the
/// evidence's noise.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct HeadingAlignment {
    window_s: f32,
    noise_m: f32,
    /// Clock of the dead reckoning, s (rebased, see [`CLOCK_REBASE_S`]).
    clock_s: f32,
    /// Dead-reckoned position and velocity in the filter's world (no corrections).
    dead_position: Vector3<f32>,
    dead_velocity: Vector3<f32>,
    /// The dead-reckoned positions of the last [`HISTORY_SPAN_S`].
    history: History,
    /// The slot being filled.
    open: Slot,
    /// A slot closed whose window waits ([`Self::close_window`]).
    closed: Option<Slot>,
    /// Closed slots, newest at `head`.
    #[serde(with = "crate::serde_array")]
    slots: [Slot; ALIGNMENT_SLOTS],
    head: usize,
    filled: usize,
    /// Capture time of the open slot's first fix, s.
    open_first_t_s: f32,
    /// Capture time of the latest fix taken, s.
    last_fix_t_s: Option<f32>,
    cross: f32,
    dot: f32,
    /// Variance of the evidence from the fixes' noise, m⁴·s².
    noise_var: f32,
    evidence: f32,
    /// The yaw, once the evidence sufficed.
    trusted_yaw_rad: Option<f32>,
    /// The velocity fixes' alignment, from the first velocity fix on.
    velocity: Option<VelocityAlignment>,
    /// Capture time of the latest velocity fix taken, s.
    last_velocity_t_s: Option<f32>,
    /// The trusted yaw came from the velocity fixes.
    yaw_from_velocity: bool,
    /// The trusted yaw was assumed ([`Self::assume_yaw`]), not yet shown by the fixes.
    yaw_assumed: bool,
}

impl Default for HeadingAlignment {
    /// For motion capture: 1 mm of noise, a 0.1 s window.
    fn default() -> Self {
        Self::new(0.001)
    }
}

impl HeadingAlignment {
    /// An alignment for fixes with `noise_m` of noise (one standard deviation per axis, m).
    pub fn new(noise_m: f32) -> Self {
        let noise_m = if noise_m.is_finite() && noise_m > 0.0 { noise_m } else { 0.001 };
        Self {
            window_s: alignment_window_s(noise_m),
            noise_m,
            clock_s: 0.0,
            dead_position: Vector3::zeros(),
            dead_velocity: Vector3::zeros(),
            history: History::default(),
            open: Slot::default(),
            closed: None,
            slots: [Slot::default(); ALIGNMENT_SLOTS],
            head: 0,
            filled: 0,
            open_first_t_s: 0.0,
            last_fix_t_s: None,
            cross: 0.0,
            dot: 0.0,
            noise_var: 0.0,
            evidence: 0.0,
            trusted_yaw_rad: None,
            velocity: None,
            last_velocity_t_s: None,
            yaw_from_velocity: false,
            yaw_assumed: false,
        }
    }

    /// The fixes' noise it was built for, m.
    pub fn noise_m(&self) -> f32 {
        self.noise_m
    }

    /// The window, s.
    pub fn window_s(&self) -> f32 {
        self.window_s
    }

    /// The velocity alignment's window, s, once velocity fixes came (`fix_velocity`): a motion
    /// meant to show the yaw should change the velocity over this span (a velocity that swings
    /// back within it shows nothing).
    pub fn velocity_window_s(&self) -> Option<f32> {
        self.velocity.as_ref().map(|velocity| velocity.window_s)
    }

    /// The evidence needed, m²·s (see [`ALIGNMENT_EVIDENCE_S`]).
    pub fn evidence_needed(&self) -> f32 {
        let d = 2.0 * self.window_s * self.window_s;
        ALIGNMENT_EVIDENCE_S * d * d
    }

    /// Integrate the acceleration `accel_ned_mps2` (the filter's world, gravity removed) over
    /// `dt_s`.
    pub fn predict(&mut self, accel_ned_mps2: &Vector3<f32>, dt_s: f32) {
        if !(accel_ned_mps2.iter().all(|x| x.is_finite()) && is_step(dt_s)) {
            return;
        }
        self.dead_position += self.dead_velocity * dt_s + accel_ned_mps2 * (0.5 * dt_s * dt_s);
        self.dead_velocity += accel_ned_mps2 * dt_s;
        self.history.advance(dt_s, &self.dead_position);
        self.clock_s += dt_s;
        if self.clock_s > 2.0 * CLOCK_REBASE_S {
            self.clock_s -= CLOCK_REBASE_S;
            if let Some(velocity) = &mut self.velocity {
                velocity.rebase(CLOCK_REBASE_S);
            }
            if let Some(t) = &mut self.last_velocity_t_s {
                *t -= CLOCK_REBASE_S;
            }
            self.open.t_s -= CLOCK_REBASE_S;
            if let Some(closed) = &mut self.closed {
                closed.t_s -= CLOCK_REBASE_S;
            }
            for slot in &mut self.slots {
                slot.t_s -= CLOCK_REBASE_S;
            }
            self.open_first_t_s -= CLOCK_REBASE_S;
            if let Some(t) = &mut self.last_fix_t_s {
                *t -= CLOCK_REBASE_S;
            }
        }
    }

    /// A fix (position, world NED, m) that describes the craft `age_s` ago (0 to
    /// [`MAX_FIX_AGE_S`]; others are ignored, as are non-finite positions and fixes older than
    /// the previous one).
    pub fn fix(&mut self, position_ned_m: &Vector3<f32>, age_s: f32) {
        self.slot_fix(position_ned_m, age_s);
        self.close_window();
    }

    /// The first half of [`Self::fix`]: the position into its slot. A slot it closes waits
    /// for [`Self::close_window`] (in a later step, `firmware::app::fix_parts`), or for the next
    /// slot to close.
    pub fn slot_fix(&mut self, position_ned_m: &Vector3<f32>, age_s: f32) {
        let age_ok = age_s.is_finite() && (0.0..=MAX_FIX_AGE_S).contains(&age_s);
        if !position_ned_m.iter().all(|x| x.is_finite()) || !age_ok {
            return;
        }
        let t_s = self.clock_s - age_s;
        if self.last_fix_t_s.is_some_and(|last| t_s < last) {
            return;
        }
        self.last_fix_t_s = Some(t_s);
        let dead = self.history.at(age_s, &self.dead_position);
        let slot_s = self.window_s / ALIGNMENT_SLOTS_PER_WINDOW as f32;
        if self.open.n > 0 && t_s - self.open_first_t_s >= slot_s {
            self.close_window();
            self.closed = Some(self.open);
            self.open = Slot::default();
        }
        if self.open.n == 0 {
            self.open_first_t_s = t_s;
        }
        self.open.add(t_s, position_ned_m, &dead);
    }

    /// A velocity fix (world NED, m/s, with `noise_mps` of noise per axis) that describes the
    /// craft `age_s` ago (as [`Self::fix`]): velocity differences over a window of
    /// [`velocity_alignment_window_s`] against the dead reckoning's (see `VelocityAlignment`).
    /// Once they give the yaw it is the one trusted (the positions' is the fallback of a source
    /// without velocity). Non-finite values and a non-positive noise are ignored.
    pub fn fix_velocity(&mut self, velocity_ned_mps: &Vector3<f32>, noise_mps: f32, age_s: f32) {
        let dead = self.dead_velocity_at(age_s);
        self.fix_velocity_with(velocity_ned_mps, noise_mps, age_s, &dead);
    }

    /// The dead-reckoned velocity `age_s` ago (0 to [`MAX_FIX_AGE_S`]), the filter's world,
    /// m/s: the first half of [`Self::fix_velocity`], which [`Self::fix_velocity_with`] completes
    /// (in a later step, `firmware::app::fix_parts`).
    pub fn dead_velocity_at(&self, age_s: f32) -> Vector3<f32> {
        self.history.slope_at(age_s, &self.dead_position)
    }

    /// [`Self::fix_velocity`] with the dead-reckoned velocity of the fix's time
    /// `dead_mps` ([`Self::dead_velocity_at`] its age then), `age_s` being the fix's age now.
    pub fn fix_velocity_with(
        &mut self,
        velocity_ned_mps: &Vector3<f32>,
        noise_mps: f32,
        age_s: f32,
        dead_mps: &Vector3<f32>,
    ) {
        let age_ok = age_s.is_finite() && (0.0..=MAX_FIX_AGE_S).contains(&age_s);
        let noise_ok = noise_mps.is_finite() && noise_mps > 0.0;
        let finite = velocity_ned_mps.iter().chain(dead_mps.iter()).all(|x| x.is_finite());
        if !finite || !age_ok || !noise_ok {
            return;
        }
        let t_s = self.clock_s - age_s;
        if self.last_velocity_t_s.is_some_and(|last| t_s <= last) {
            return;
        }
        self.last_velocity_t_s = Some(t_s);
        self.take_velocity(t_s, velocity_ned_mps, noise_mps, *dead_mps);
    }

    /// A velocity fix of the time `t_s` with the dead-reckoned velocity `dead` of that time.
    fn take_velocity(
        &mut self,
        t_s: f32,
        velocity_ned_mps: &Vector3<f32>,
        noise_mps: f32,
        dead: Vector3<f32>,
    ) {
        let alignment = self.velocity.get_or_insert_with(|| VelocityAlignment::new(noise_mps));
        if let Some(yaw) = alignment.add(VelocityPoint { t_s, fix: *velocity_ned_mps, dead }) {
            self.trusted_yaw_rad = Some(yaw);
            self.yaw_from_velocity = true;
            self.yaw_assumed = false;
        }
    }

    /// The second half of [`Self::fix`]: the window that ends at the slot the position
    /// closed, if it did.
    pub fn close_window(&mut self) {
        if let Some(slot) = self.closed.take() {
            self.push(slot);
        }
    }

    /// Keep a closed slot and take the window that ends at it.
    fn push(&mut self, slot: Slot) {
        let previous_t_s = (self.filled > 0).then(|| self.slots[self.head].t_s);
        self.head = (self.head + 1) % ALIGNMENT_SLOTS;
        self.slots[self.head] = slot;
        self.filled = (self.filled + 1).min(ALIGNMENT_SLOTS);
        let t = self.window_s;
        let (Some(previous_t_s), Some(one), Some(two)) =
            (previous_t_s, self.interpolate(slot.t_s - t), self.interpolate(slot.t_s - 2.0 * t))
        else {
            return;
        };
        let d = slot.fix - one.fix * 2.0 + two.fix;
        let d_filter = slot.dead - one.dead * 2.0 + two.dead;
        // The time this window stands for: since the previous slot, at most a window (windows
        // a window apart no longer overlap). `math::clamp`, not `f32::clamp`: the bound is not a
        // constant, and `f32::clamp`'s assertion would link core's float formatting (15 KB).
        let w = crate::math::clamp(slot.t_s - previous_t_s, 0.0, t);
        // Variance of each component of D from the fixes' noise (means of slots).
        let sigma2 = self.noise_m * self.noise_m;
        let var_d = sigma2 * (1.0 / slot.n as f32 + 4.0 * one.noise_factor + two.noise_factor);
        let (dx, dy) = (d_filter.x, d_filter.y);
        self.cross += w * (dx * d.y - dy * d.x);
        self.dot += w * (dx * d.x + dy * d.y);
        self.noise_var += w * w * (dx * dx + dy * dy) * var_d;
        self.evidence = crate::math::sqrt(self.cross * self.cross + self.dot * self.dot);
        if !self.yaw_from_velocity
            && self.evidence >= self.evidence_needed()
            && self.evidence >= ALIGNMENT_SIGNIFICANCE * crate::math::sqrt(self.noise_var)
        {
            self.trusted_yaw_rad = Some(libm::atan2f(self.cross, self.dot));
            self.yaw_assumed = false;
        }
    }

    /// The slots' means at time `t_s`, linear between the two slots around it. `None` before
    /// the oldest slot kept or after the newest.
    fn interpolate(&self, t_s: f32) -> Option<WindowPoint> {
        let filled = self.filled;
        let slot_at = |k: usize| &self.slots[(self.head + ALIGNMENT_SLOTS - k) % ALIGNMENT_SLOTS];
        if filled < 2 || slot_at(0).t_s <= t_s {
            // Later than the newest slot: not a point of a window.
            return None;
        }
        // The newest slot at or before `t_s`: from the slots' mean spacing, then a step or two.
        let (newest, oldest) = (slot_at(0).t_s, slot_at(filled - 1).t_s);
        let spacing = (newest - oldest) / (filled - 1) as f32;
        let guess = if spacing > 0.0 { (newest - t_s) / spacing } else { 1.0 };
        let mut k = crate::math::clamp(guess, 1.0, (filled - 1) as f32) as usize;
        while k > 1 && slot_at(k - 1).t_s <= t_s {
            k -= 1;
        }
        while k < filled && slot_at(k).t_s > t_s {
            k += 1;
        }
        if k == filled {
            return None;
        }
        let (slot, newer) = (slot_at(k), slot_at(k - 1));
        let span = newer.t_s - slot.t_s;
        let a = if span > 0.0 { ((t_s - slot.t_s) / span).clamp(0.0, 1.0) } else { 0.0 };
        Some(WindowPoint {
            fix: slot.fix + (newer.fix - slot.fix) * a,
            dead: slot.dead + (newer.dead - slot.dead) * a,
            noise_factor: (1.0 - a) * (1.0 - a) / slot.n as f32 + a * a / newer.n as f32,
        })
    }

    /// The craft is at rest: the dead-reckoned velocity is zero.
    pub fn hold_still(&mut self) {
        self.dead_velocity = Vector3::zeros();
    }

    /// The velocity by dead reckoning (accelerometer only since the last rest), in the
    /// filter's world, m/s.
    pub fn dead_reckoned_velocity_mps(&self) -> Vector3<f32> {
        self.dead_velocity
    }

    /// How much the dead-reckoned velocity changed over the last `age_s` (0 to
    /// [`MAX_FIX_AGE_S`]), filter's world, m/s: what carries a velocity fix of that age forward
    /// to now.
    pub fn dead_reckoned_change_since_mps(&self, age_s: f32) -> Vector3<f32> {
        if !(age_s.is_finite() && age_s > 0.0) {
            return Vector3::zeros();
        }
        let age_s = age_s.min(MAX_FIX_AGE_S);
        self.dead_velocity - self.history.slope_at(age_s, &self.dead_position)
    }

    /// The yaw from the filter's world to the fixes' world, rad, once the evidence suffices.
    pub fn yaw_rad(&self) -> Option<f32> {
        self.trusted_yaw_rad
    }

    /// Take `yaw_rad` as the yaw until the fixes' own evidence gives one: a compass that has
    /// already turned the filter's world to the fixes' north assumes 0. The evidence keeps
    /// gathering, and once it suffices its yaw replaces the assumed one (a compass's error then
    /// shows as a yaw of its own). Ignored when the fixes have already given a yaw, or not finite.
    pub fn assume_yaw(&mut self, yaw_rad: f32) {
        if yaw_rad.is_finite() && (self.trusted_yaw_rad.is_none() || self.yaw_assumed) {
            // Wrapped to (−π, π] as the evidence's `atan2` gives it.
            self.trusted_yaw_rad = Some(libm::atan2f(libm::sinf(yaw_rad), libm::cosf(yaw_rad)));
            self.yaw_assumed = true;
        }
    }

    /// Whether the yaw is an assumed one ([`Self::assume_yaw`]) that the fixes have not yet
    /// shown.
    pub fn yaw_is_assumed(&self) -> bool {
        self.yaw_assumed
    }

    /// Evidence gathered so far, m²·s (see [`ALIGNMENT_EVIDENCE_S`]).
    pub fn evidence(&self) -> f32 {
        self.evidence
    }

    /// One standard deviation of the evidence from the fixes' noise, m²·s.
    pub fn evidence_noise(&self) -> f32 {
        crate::math::sqrt(self.noise_var)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A history's pending corrections read as the values shifted at once: fixes 5–100 ms
    /// apart (so that more than `PENDING_CORRECTIONS` lie within the history and the oldest
    /// fold), 0–0.2 s late, read at every age after each.
    #[test]
    fn pending_corrections_read_as_values_shifted_at_once() {
        let (mut lazy, mut eager) = (History::default(), History::default());
        let mut rng = crate::rng::Rng::new(5);
        let mut small =
            |scale: f64| rng.unit_vector().cast::<f32>() * (scale * rng.uniform()) as f32;
        let (mut position, mut velocity) = (Vector3::zeros(), Vector3::new(0.5f32, -0.2, 0.1));
        let (mut next_fix, mut folded) = (40usize, 0usize);
        for k in 0..6000usize {
            let dt_s = 0.0005;
            velocity += small(0.01);
            position += velocity * dt_s;
            lazy.advance(dt_s, &position);
            eager.advance(dt_s, &position);
            if k != next_fix {
                continue;
            }
            let age_s = (k % 7) as f32 * 0.03;
            let (dp, dv, db) = (small(0.3), small(0.2), small(0.05));
            position += dp + dv * age_s - db * (0.5 * age_s * age_s);
            folded += usize::from(lazy.pending_len == PENDING_CORRECTIONS);
            lazy.shift(age_s, dp, dv, db);
            eager.shift(age_s, dp, dv, db);
            eager.drop_oldest(eager.pending_len, true);
            for a in 0..70 {
                let age_s = a as f32 * 0.0037;
                let (l, e) = (lazy.at(age_s, &position), eager.at(age_s, &position));
                assert!((l - e).norm() < 1e-4, "step {k}, age {age_s}: {l:?} against {e:?}");
            }
            next_fix = k + [10, 200, 30, 120, 60][k % 5];
        }
        assert!(folded > 10, "{folded} folds");
    }

    /// A tilted attitude: the fixes' velocity gains a constant 1 m/s² (g · sin 6°) the dead
    /// reckoning does not see, while the craft moves with a swinging velocity on top of a steady
    /// push (a recovery that brakes one way). The plain coherent sum turns towards the constant,
    /// more than 10° off; the alignment leaves that yaw, whose unexplained constant is above
    /// `MAX_ALIGNMENT_BIAS_MPS2`, and takes the centred sums', within 3°. Without the constant,
    /// the plain yaw is taken and is right.
    #[test]
    fn the_velocity_alignment_sees_through_a_constant_acceleration_from_a_tilted_attitude() {
        let yaw = 0.7f32;
        let (sin, cos) = (libm::sinf(yaw), libm::cosf(yaw));
        for (bias_mps2, plain_off) in [(1.0f32, true), (0.0, false)] {
            let noise_mps = 0.05;
            let mut alignment = VelocityAlignment::new(noise_mps);
            let mut rng = crate::rng::Rng::new(3);
            let mut found = None;
            for k in 0..200 {
                let t_s = k as f32 * 0.1;
                // Dead-reckoned velocity, filter's world: 0.5 m/s swings every 3 s on a 1 m/s²
                // push along x.
                let phase = 2.0 * core::f32::consts::PI * t_s / 3.0;
                let dead =
                    Vector3::new(0.5 * libm::sinf(phase) + t_s, 0.5 * libm::cosf(phase), 0.0);
                let rotated =
                    Vector3::new(cos * dead.x - sin * dead.y, sin * dead.x + cos * dead.y, 0.0);
                let noise = Vector3::new(rng.normal() as f32, rng.normal() as f32, 0.0) * noise_mps;
                let fix = rotated + Vector3::new(0.0, bias_mps2 * t_s, 0.0) + noise;
                if let Some(found_yaw) = alignment.add(VelocityPoint { t_s, fix, dead }) {
                    found = Some(found_yaw);
                }
            }
            let found = found.expect("a yaw");
            assert!(
                crate::attitude::wrap_pi(found - yaw).abs() < 3f32.to_radians(),
                "bias {bias_mps2} m/s²: yaw {:.1}° against {:.1}°",
                found.to_degrees(),
                yaw.to_degrees()
            );
            let plain = libm::atan2f(alignment.cross, alignment.dot);
            let plain_error = crate::attitude::wrap_pi(plain - yaw).abs();
            assert_eq!(
                plain_error > 10f32.to_radians(),
                plain_off,
                "plain {:.1}°",
                plain.to_degrees()
            );
        }
    }

    /// An assumed yaw (a compass's) is the yaw at once; the fixes' evidence replaces it when it
    /// suffices, and a later assumption no longer overrides what the fixes showed.
    #[test]
    fn an_assumed_yaw_holds_until_the_fixes_show_their_own() {
        let yaw = 0.4f32;
        let mut align = HeadingAlignment::default();
        assert_eq!(align.yaw_rad(), None);
        align.assume_yaw(f32::NAN);
        assert_eq!(align.yaw_rad(), None);
        align.assume_yaw(0.0);
        assert_eq!(align.yaw_rad(), Some(0.0));
        assert!(align.yaw_is_assumed());
        // Motion the fixes see turned by `yaw`: a swinging acceleration along the filter's x
        // and y, at 100 Hz motion capture.
        let dt = 0.0005f32;
        let (sin, cos) = (libm::sinf(yaw), libm::cosf(yaw));
        let (mut p, mut v) = (Vector3::<f32>::zeros(), Vector3::<f32>::zeros());
        for k in 0..8000 {
            let t = k as f32 * dt;
            let a = Vector3::new(2.0 * libm::sinf(3.0 * t), 2.0 * libm::cosf(2.0 * t), 0.0);
            align.predict(&a, dt);
            p += v * dt + a * (0.5 * dt * dt);
            v += a * dt;
            if k % 20 == 0 {
                let fix = Vector3::new(cos * p.x - sin * p.y, sin * p.x + cos * p.y, p.z);
                align.fix(&fix, 0.0);
            }
        }
        let found = align.yaw_rad().expect("a yaw");
        assert!(!align.yaw_is_assumed());
        assert!((found - yaw).abs() < 0.5f32.to_radians(), "{:.2}°", found.to_degrees());
        align.assume_yaw(0.0);
        assert_eq!(align.yaw_rad(), Some(found));
    }

    const DT: f32 = 1.0 / 2000.0;

    fn level() -> UnitQuaternion<f32> {
        UnitQuaternion::identity()
    }

    #[test]
    fn at_rest_level_the_estimate_stays_put() {
        let mut nav = PositionEstimator::default();
        let hover_f = Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2);
        for _ in 0..20_000 {
            nav.predict(&level(), &hover_f, DT).unwrap();
        }
        let s = nav.state();
        assert!(s.velocity_ned_mps.norm() < 1e-4, "{:?}", s.velocity_ned_mps);
        assert!(s.position_ned_m.norm() < 1e-3);
        assert!(!s.has_fix);
    }

    #[test]
    fn free_fall_for_one_second_is_9_8_mps_down() {
        let mut nav = PositionEstimator::default();
        for _ in 0..2000 {
            nav.predict(&level(), &Vector3::zeros(), DT).unwrap();
        }
        let s = nav.state();
        assert!(
            (s.velocity_ned_mps.z - STANDARD_GRAVITY_MPS2).abs() < 1e-3,
            "{}",
            s.velocity_ned_mps.z
        );
        assert!((s.position_ned_m.z - 0.5 * STANDARD_GRAVITY_MPS2).abs() < 1e-3);
    }

    #[test]
    fn fixes_pull_a_biased_velocity_back_to_the_truth_at_10_hz_100_hz_and_2_khz() {
        // The craft hovers still at (1, 2, −3) m; the accelerometer has a 0.05 m/s² bias along x
        // and the estimate starts 0.5 m/s wrong. Fixes every `every` steps.
        for (rate_hz, every) in [(10.0, 200), (100.0, 20), (2000.0, 1)] {
            let mut nav = PositionEstimator::default();
            let truth = Vector3::new(1.0, 2.0, -3.0);
            nav.correct(&truth, 0.01).unwrap();
            nav.state.velocity_ned_mps = Vector3::new(0.5, 0.0, 0.0);
            let f = Vector3::new(0.05, 0.0, -STANDARD_GRAVITY_MPS2);
            let mut worst_after_3_s = 0.0f32;
            for step in 0..(10 * 2000) {
                nav.predict(&level(), &f, DT).unwrap();
                if step % every == every - 1 {
                    nav.correct(&truth, every as f32 * DT).unwrap();
                }
                if step >= 3 * 2000 {
                    let e = (nav.state().position_ned_m - truth).norm();
                    worst_after_3_s = worst_after_3_s.max(e);
                }
            }
            let s = nav.state();
            // The same triple pole at 4 rad/s whatever the rate: within 1 cm after 3 s (the
            // initial 0.5 m/s error moves the estimate about 8 cm at first).
            assert!(worst_after_3_s < 0.01, "{rate_hz} Hz: {worst_after_3_s} m");
            // The bias is learned, so no steady velocity error remains (a second-order filter
            // would keep 2b/ω_c = 2.5 cm/s).
            assert!(s.velocity_ned_mps.norm() < 0.003, "{rate_hz} Hz: {:?}", s.velocity_ned_mps);
            let bias = s.accel_bias_ned_mps2.x;
            assert!((bias - 0.05).abs() < 0.005, "{rate_hz} Hz: {bias}");
            assert!(s.has_fix);
        }
    }

    #[test]
    fn the_gains_place_a_triple_pole_at_the_crossover_for_any_fix_spacing() {
        // The error dynamics over one fix interval (correct, then predict T): characteristic
        // polynomial u³ + s u² + (T k_v + 1.5 T² k_b) u + T² k_b with u = z − 1 and
        // s = k_p + T k_v + T² k_b / 2 must equal (u + m)³, m = 1 − exp(−ω_c T).
        for t in [0.0005f32, 0.01, 0.1, 0.3] {
            let (k_p, k_v, k_b) = gains(DEFAULT_CROSSOVER_RAD_S, t);
            let m = 1.0 - (-DEFAULT_CROSSOVER_RAD_S * t).exp();
            let s = k_p + t * k_v + t * t * k_b / 2.0;
            assert!((s - 3.0 * m).abs() < 1e-5 * (1.0 + 3.0 * m), "{t}");
            assert!((t * k_v + 1.5 * t * t * k_b - 3.0 * m * m).abs() < 1e-5, "{t}");
            assert!((t * t * k_b - m * m * m).abs() < 1e-6, "{t}");
        }
    }

    /// A craft swinging along x (2 m/s² at 1 Hz) with an accelerometer bias: the truth and
    /// the specific force it would measure at `t`.
    fn swing(t: f32) -> (Vector3<f32>, Vector3<f32>) {
        let w = 2.0 * core::f32::consts::PI;
        let amplitude = 2.0 / (w * w);
        let p = Vector3::new(amplitude * libm::sinf(w * t), 0.0, -2.0);
        let a = Vector3::new(-2.0 * libm::sinf(w * t), 0.0, 0.0);
        (p, a - Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2))
    }

    /// The worst position error over the last 5 of 10 s of swinging, with fixes at `rate_hz`
    /// that arrive `latency_s` late and are declared `declared_age_s` old.
    fn swing_error(rate_hz: f32, latency_s: f32, declared_age_s: f32) -> f32 {
        let mut nav = PositionEstimator::default();
        let every = (2000.0 / rate_hz) as usize;
        let late = (latency_s / DT).round() as usize;
        let mut worst = 0.0f32;
        for step in 0..(10 * 2000) {
            let t = (step + 1) as f32 * DT;
            let (_, f) = swing(t);
            nav.predict(&level(), &f, DT).unwrap();
            // The fix arriving now was captured `late` steps ago.
            if step >= late && (step - late).is_multiple_of(every) {
                let captured = (step + 1 - late) as f32 * DT;
                let (p, _) = swing(captured);
                nav.correct_late(&p, declared_age_s, every as f32 * DT).unwrap();
            }
            if step >= 5 * 2000 {
                worst = worst.max((nav.state().position_ned_m - swing(t).0).norm());
            }
        }
        worst
    }

    #[test]
    fn a_late_fix_is_compared_with_the_estimate_of_its_own_time() {
        // 30 ms late: declared, the estimate stays within a millimetre of the truth (as with
        // fixes on time); taken as new, it lags the swing by centimetres.
        for rate_hz in [10.0, 100.0, 2000.0] {
            let on_time = swing_error(rate_hz, 0.0, 0.0);
            let compensated = swing_error(rate_hz, 0.03, 0.03);
            let ignored = swing_error(rate_hz, 0.03, 0.0);
            assert!(on_time < 0.001, "{rate_hz} Hz on time: {on_time} m");
            assert!(compensated < 0.001, "{rate_hz} Hz, 30 ms declared: {compensated} m");
            assert!(ignored > 0.005, "{rate_hz} Hz, 30 ms ignored: {ignored} m");
        }
        // The largest age the history holds.
        let compensated = swing_error(100.0, 0.1, 0.1);
        assert!(compensated < 0.002, "100 Hz, 100 ms: {compensated} m");
    }

    #[test]
    fn a_late_fix_leaves_the_same_estimate_as_the_same_fix_on_time() {
        // Two estimators see the same biased accelerometer and the same fixes (100 Hz, noisy);
        // one gets each fix when it was taken, the other 40 ms later with its age. After the
        // last fix has reached both, their estimates agree (the history is exact up to its
        // linear interpolation).
        let mut on_time = PositionEstimator::default();
        let mut late = PositionEstimator::default();
        let mut rng = crate::rng::Rng::new(3);
        let lag = 80; // steps, 40 ms
        let mut pending: [(usize, Vector3<f32>); 8] = [(usize::MAX, Vector3::zeros()); 8];
        for step in 0..(4 * 2000 + lag) {
            let t = step as f32 * DT;
            let f = Vector3::new(0.1 + libm::sinf(3.0 * t), 0.5 * libm::cosf(t), -9.7);
            on_time.predict(&level(), &f, DT).unwrap();
            late.predict(&level(), &f, DT).unwrap();
            if step % 20 == 0 && step < 4 * 2000 {
                let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()).cast::<f32>();
                let fix = Vector3::new(libm::sinf(t), 0.0, -1.0) + noise * 0.01;
                on_time.correct(&fix, 0.01).unwrap();
                pending[(step / 20) % 8] = (step + lag, fix);
            }
            for (due, fix) in &mut pending {
                if *due == step {
                    late.correct_late(fix, lag as f32 * DT, 0.01).unwrap();
                    *due = usize::MAX;
                }
            }
        }
        let (a, b) = (on_time.state(), late.state());
        assert!((a.position_ned_m - b.position_ned_m).norm() < 1e-4, "{a:?} vs {b:?}");
        assert!((a.velocity_ned_mps - b.velocity_ned_mps).norm() < 1e-3, "{a:?} vs {b:?}");
        assert!((a.accel_bias_ned_mps2 - b.accel_bias_ned_mps2).norm() < 1e-3);
    }

    #[test]
    fn a_stale_fix_is_reported_and_the_next_one_resets_the_position() {
        let mut nav = PositionEstimator::default();
        nav.correct(&Vector3::new(0.0, 0.0, -1.0), 0.01).unwrap();
        for _ in 0..((FIX_TIMEOUT_S / DT) as usize + 2) {
            nav.predict(&level(), &Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2), DT).unwrap();
        }
        assert!(!nav.state().has_fix);
        nav.correct(&Vector3::new(5.0, 0.0, -1.0), 0.01).unwrap();
        assert_eq!(nav.state().position_ned_m, Vector3::new(5.0, 0.0, -1.0));
    }

    #[test]
    fn the_yaw_between_two_worlds_is_found_from_accelerations_alone() {
        // The fixes' world is the filter's turned by 70° about down. The craft accelerates
        // about in circles (1–3 m/s²) with an unknown initial velocity of 2 m/s; fixes at 100 Hz
        // with 1 mm noise.
        let yaw = 70f32.to_radians();
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        let mut align = HeadingAlignment::default();
        let mut rng = crate::rng::Rng::new(5);
        let mut truth_v = Vector3::new(2.0, -1.0, 0.0);
        let mut truth_p = Vector3::zeros();
        for step in 0..(3 * 2000) {
            let t = step as f32 * DT;
            let a_filter = Vector3::new(2.0 * libm::sinf(3.0 * t), 1.0 + libm::cosf(2.0 * t), 0.0);
            let a_world = turn * a_filter;
            truth_p += truth_v * DT + a_world * (0.5 * DT * DT);
            truth_v += a_world * DT;
            align.predict(&a_filter, DT);
            if step % 20 == 0 {
                let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()).cast::<f32>();
                align.fix(&(truth_p + noise * 0.001), 0.0);
            }
        }
        let found = align.yaw_rad().expect("enough evidence after 3 s of 1–3 m/s²");
        assert!((found - yaw).abs() < 1f32.to_radians(), "{}° for 70°", found.to_degrees());
    }

    /// Circles of 1–3 m/s² with an unknown initial velocity of 2 m/s, in the filter's world; the
    /// fixes' world is turned by `yaw` about down. Fixes at `rate_hz` (spacing jittered by up
    /// to `jitter` of a period), captured `latency_s` before they arrive and declared
    /// `declared_age_s` old, with `noise_m` of noise. Returns the alignment after `seconds`.
    #[allow(clippy::too_many_arguments)]
    fn align_circles(
        yaw: f32,
        rate_hz: f32,
        jitter: f32,
        latency_s: f32,
        declared_age_s: f32,
        noise_m: f32,
        seconds: f32,
        accel: impl Fn(f32) -> Vector3<f32>,
    ) -> HeadingAlignment {
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        let mut align = HeadingAlignment::new(noise_m);
        let mut rng = crate::rng::Rng::new(5);
        let mut truth_v = Vector3::new(2.0, -1.0, 0.0);
        let mut truth_p = Vector3::zeros();
        // Past true positions for the latency, one per step (at most 0.1 s).
        let mut past = [Vector3::zeros(); 256];
        let late = (latency_s / DT).round() as usize;
        let mut next_fix_s = 0.0f32;
        for step in 0..((seconds / DT) as usize) {
            let t = step as f32 * DT;
            let a_filter = accel(t);
            let a_world = turn * a_filter;
            truth_p += truth_v * DT + a_world * (0.5 * DT * DT);
            truth_v += a_world * DT;
            past[step % 256] = truth_p;
            align.predict(&a_filter, DT);
            if t >= next_fix_s && step >= late {
                let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()).cast::<f32>();
                align.fix(&(past[(step - late) % 256] + noise * noise_m), declared_age_s);
                let spread = (rng.uniform() as f32 * 2.0 - 1.0) * jitter;
                next_fix_s += (1.0 + spread) / rate_hz;
            }
        }
        align
    }

    fn circles(t: f32) -> Vector3<f32> {
        Vector3::new(2.0 * libm::sinf(3.0 * t), 1.0 + libm::cosf(2.0 * t), 0.0)
    }

    #[test]
    fn the_alignment_gathers_the_same_evidence_per_second_at_10_hz_100_hz_and_2_khz() {
        let yaw = 70f32.to_radians();
        let at = |rate_hz: f32| align_circles(yaw, rate_hz, 0.0, 0.0, 0.0, 0.001, 1.5, circles);
        let reference = at(100.0).evidence();
        for rate_hz in [10.0, 2000.0] {
            let align = at(rate_hz);
            let ratio = align.evidence() / reference;
            // The same motion gives the same evidence (windows weighted by the time they stand
            // for): at 2 kHz the windows start every 6.25 ms instead of 10 ms, at 10 Hz the
            // points are interpolated over 0.1 s; within 15 %.
            assert!((ratio - 1.0).abs() < 0.15, "{rate_hz} Hz: {ratio} of the 100 Hz evidence");
            // Fewer fixes average less noise out: at 10 Hz the evidence rises above its noise
            // later (25 times its noise at 1.5 s).
            let align = align_circles(yaw, rate_hz, 0.0, 0.0, 0.0, 0.001, 3.0, circles);
            let found = align.yaw_rad().expect("aligned");
            assert!(
                (found - yaw).abs() < 1f32.to_radians(),
                "{rate_hz} Hz: {}°",
                found.to_degrees()
            );
        }
    }

    #[test]
    fn irregular_fixes_align_as_well_as_even_ones() {
        let yaw = -120f32.to_radians();
        for rate_hz in [10.0, 30.0, 500.0] {
            let align = align_circles(yaw, rate_hz, 0.5, 0.0, 0.0, 0.001, 3.0, circles);
            let found = align.yaw_rad().expect("aligned");
            let error = flight_wrap(found - yaw);
            assert!(
                error.abs() < 1f32.to_radians(),
                "{rate_hz} Hz ± 50 %: {}°",
                error.to_degrees()
            );
        }
    }

    fn flight_wrap(angle: f32) -> f32 {
        crate::attitude::wrap_pi(angle)
    }

    #[test]
    fn a_late_fix_is_aligned_with_the_dead_reckoning_of_its_own_time() {
        // 50 ms late at 100 Hz: with its age the yaw is found within 1°; taken as new, the
        // acceleration turning at 3 rad/s has turned by 3 rad/s × 50 ms = 8.6° meanwhile.
        let yaw = 70f32.to_radians();
        let circles =
            |t: f32| Vector3::new(2.0 * libm::cosf(3.0 * t), 2.0 * libm::sinf(3.0 * t), 0.0);
        let declared = align_circles(yaw, 100.0, 0.0, 0.05, 0.05, 0.001, 3.0, circles);
        let error = flight_wrap(declared.yaw_rad().expect("aligned") - yaw);
        assert!(error.abs() < 1f32.to_radians(), "declared: {}°", error.to_degrees());
        let ignored = align_circles(yaw, 100.0, 0.0, 0.05, 0.0, 0.001, 3.0, circles);
        let error = flight_wrap(ignored.yaw_rad().expect("aligned") - yaw);
        assert!(error.abs() > 3f32.to_radians(), "ignored: {}°", error.to_degrees());
    }

    #[test]
    fn gnss_like_noise_aligns_later_on_slow_manoeuvres_and_never_on_noise() {
        // 0.5 m of noise at 10 Hz: a 2.2 s window. A slow manoeuvre (2 m/s² turning at
        // 0.5 rad/s) aligns within 3°, after more than the motion-capture case needs.
        let yaw = 40f32.to_radians();
        let slow = |t: f32| Vector3::new(2.0 * libm::cosf(0.5 * t), 2.0 * libm::sinf(0.5 * t), 0.0);
        let align = align_circles(yaw, 10.0, 0.2, 0.0, 0.0, 0.5, 30.0, slow);
        assert!((align.window_s() - 2.236).abs() < 0.01, "{}", align.window_s());
        let found = align.yaw_rad().expect("aligned after 30 s of 2 m/s²");
        assert!(flight_wrap(found - yaw).abs() < 3f32.to_radians(), "{}°", found.to_degrees());
        // Gentle motion (0.1 m/s²) for 10 s does not rise above 0.5 m of noise: no yaw trusted
        // rather than a wrong one.
        let gentle =
            |t: f32| Vector3::new(0.1 * libm::cosf(0.5 * t), 0.1 * libm::sinf(0.5 * t), 0.0);
        for yaw_deg in [0.0f32, 90.0, -150.0] {
            let align = align_circles(yaw_deg.to_radians(), 10.0, 0.2, 0.0, 0.0, 0.5, 10.0, gentle);
            if let Some(found) = align.yaw_rad() {
                let error = flight_wrap(found - yaw_deg.to_radians());
                assert!(
                    error.abs() < 6f32.to_radians(),
                    "{yaw_deg}°: trusted {}°",
                    found.to_degrees()
                );
            }
        }
    }

    #[test]
    fn the_window_follows_the_noise() {
        assert_eq!(alignment_window_s(0.001), MIN_ALIGNMENT_WINDOW_S);
        assert!((alignment_window_s(0.05) - 0.707).abs() < 0.01);
        assert_eq!(alignment_window_s(10.0), MAX_ALIGNMENT_WINDOW_S);
        assert_eq!(alignment_window_s(f32::NAN), MIN_ALIGNMENT_WINDOW_S);
        assert_eq!(crossover_for_noise(0.001), DEFAULT_CROSSOVER_RAD_S);
        assert!((crossover_for_noise(0.5) - 1.086).abs() < 0.01, "{}", crossover_for_noise(0.5));
    }

    #[test]
    fn hovering_still_gives_no_alignment() {
        let mut align = HeadingAlignment::default();
        for step in 0..(3 * 2000) {
            align.predict(&Vector3::zeros(), DT);
            if step % 20 == 0 {
                align.fix(&Vector3::new(1.0, 2.0, -3.0), 0.0);
            }
        }
        assert_eq!(align.yaw_rad(), None);
    }

    #[test]
    fn bad_input_changes_nothing() {
        let mut nav = PositionEstimator::default();
        nav.correct(&Vector3::new(1.0, 1.0, 1.0), 0.01).unwrap();
        let before = *nav.state();
        assert_eq!(
            nav.predict(&level(), &Vector3::new(f32::NAN, 0.0, 0.0), DT),
            Err(NavigationError::BadInput)
        );
        assert_eq!(nav.predict(&level(), &Vector3::zeros(), 0.0), Err(NavigationError::BadInput));
        assert_eq!(
            nav.correct(&Vector3::new(f32::INFINITY, 0.0, 0.0), 0.01),
            Err(NavigationError::BadInput)
        );
        assert_eq!(*nav.state(), before);
    }

    /// A GNSS-like run: the craft swings along x (`swing`) with a 0.05 m/s² accelerometer
    /// bias; fixes at 10 Hz, 100 ms late, with white position noise `sigma_m` per axis and,
    /// when `velocity_noise_mps` is given, a velocity of that noise. Each fix's position is
    /// offset by `jump(t)`. Returns the worst and the RMS position error over the last 10 of
    /// 20 s, the RMS velocity error there, and the estimator.
    fn gnss_run(
        sigma_m: f32,
        velocity_noise_mps: Option<f32>,
        jump: impl Fn(f32) -> Vector3<f32>,
        seed: u64,
    ) -> (f32, f32, f32, PositionEstimator) {
        let mut rng = crate::rng::Rng::new(seed);
        let mut noise = |s: f32| Vector3::from_fn(|_, _| rng.normal() as f32 * s);
        let mut nav = PositionEstimator::default();
        let (every, late) = (200usize, 200usize);
        let bias = Vector3::new(0.05, 0.0, 0.0);
        let (mut worst, mut sum2, mut vsum2, mut n) = (0.0f32, 0.0f32, 0.0f32, 0);
        let w = 2.0 * core::f32::consts::PI;
        for step in 0..(20 * 2000) {
            let t = (step + 1) as f32 * DT;
            let (_, f) = swing(t);
            nav.predict(&level(), &(f + bias), DT).unwrap();
            if step >= late && (step - late).is_multiple_of(every) {
                let captured = (step + 1 - late) as f32 * DT;
                let (p, _) = swing(captured);
                let v_true = Vector3::new(2.0 / w * libm::cosf(w * captured), 0.0, 0.0);
                let fix = Fix {
                    position_ned_m: p + noise(sigma_m) + jump(captured),
                    sigma_m: [sigma_m, sigma_m],
                    velocity: velocity_noise_mps.map(|s| (v_true + noise(s), s)),
                    age_s: late as f32 * DT,
                    dt_fix_s: every as f32 * DT,
                };
                nav.correct_fix(&fix).unwrap();
            }
            if step >= 10 * 2000 {
                let e = (nav.state().position_ned_m - swing(t).0).norm();
                let v_true = Vector3::new(2.0 / w * libm::cosf(w * t), 0.0, 0.0);
                let ev = (nav.state().velocity_ned_mps - v_true).norm();
                worst = worst.max(e);
                sum2 += e * e;
                vsum2 += ev * ev;
                n += 1;
            }
        }
        (worst, libm::sqrtf(sum2 / n as f32), libm::sqrtf(vsum2 / n as f32), nav)
    }

    #[test]
    fn gnss_fixes_are_weighted_by_their_accuracy_and_their_velocity_is_used() {
        let none = |_| Vector3::zeros();
        // 0.3 m of noise at 10 Hz, 100 ms late: the estimate averages the noise down (its RMS
        // error well under the fixes' 0.52 m 3D RMS) and never strays a metre.
        let (worst, rms, v_rms, _) = gnss_run(0.3, None, none, 1);
        assert!(rms < 0.3 && worst < 1.0, "position only: RMS {rms} m, worst {worst} m");
        // Its Doppler velocity (0.1 m/s) makes the velocity better than the positions alone
        // give it, and the position no worse.
        let (worst_v, rms_v, v_rms_v, _) = gnss_run(0.3, Some(0.1), none, 1);
        assert!(v_rms_v < 0.7 * v_rms, "velocity RMS {v_rms_v} m/s with, {v_rms} m/s without");
        assert!(rms_v < 0.3 && worst_v < 1.0, "with velocity: RMS {rms_v} m, worst {worst_v} m");
        // The same fixes said to be ten times less accurate than they are move the estimate
        // less per fix: it follows the truth more loosely than when told the truth.
        let mut told_exact = PositionEstimator::default();
        let mut told_coarse = PositionEstimator::default();
        for nav in [&mut told_exact, &mut told_coarse] {
            nav.correct(&Vector3::zeros(), 0.1).unwrap();
        }
        let fix = |sigma: f32| Fix {
            position_ned_m: Vector3::new(0.3, 0.0, 0.0),
            sigma_m: [sigma, sigma],
            velocity: None,
            age_s: 0.0,
            dt_fix_s: 0.1,
        };
        assert_eq!(told_exact.correct_fix(&fix(0.03)), Ok(FixOutcome::Taken));
        assert_eq!(told_coarse.correct_fix(&fix(0.3)), Ok(FixOutcome::Taken));
        let moved = |nav: &PositionEstimator| nav.state().position_ned_m.x;
        assert!(
            moved(&told_coarse) < 0.8 * moved(&told_exact),
            "{} vs {}",
            moved(&told_coarse),
            moved(&told_exact)
        );
    }

    #[test]
    fn a_multipath_jump_is_refused_with_a_velocity_and_a_lasting_one_is_taken_after_five_seconds() {
        // A 4 m jump north for 3 s (from 12 s on): refused, counted, the estimate stays with
        // the truth on its velocity fixes.
        let brief = |t: f32| {
            if (12.0..15.0).contains(&t) {
                Vector3::new(4.0, 0.0, 0.0)
            } else {
                Vector3::zeros()
            }
        };
        let (worst, _, _, nav) = gnss_run(0.3, Some(0.1), brief, 2);
        assert!(worst < 1.0, "worst {worst} m through the jump");
        assert!(nav.rejected() >= 25, "{} refused", nav.rejected());
        // Without a velocity nothing else holds the dead reckoning: such fixes are never gated.
        let (_, _, _, nav) = gnss_run(0.3, None, brief, 2);
        assert_eq!(nav.rejected(), 0);
        // The same jump from 8 s on, for good: after MAX_REJECT_S the estimate moves onto it.
        let lasting =
            |t: f32| if t >= 8.0 { Vector3::new(4.0, 0.0, 0.0) } else { Vector3::zeros() };
        let (_, rms, _, nav) = gnss_run(0.3, Some(0.1), lasting, 2);
        let offset = nav.state().position_ned_m.x - swing(20.0).0.x;
        assert!((offset - 4.0).abs() < 1.0, "moved by {offset} m");
        assert!(rms > 3.0, "the last 10 s follow the jump: RMS {rms} m from the truth");
    }

    #[test]
    fn a_velocity_glitch_is_refused_and_a_lasting_disagreement_moves_the_estimate_onto_the_fixes() {
        // A receiver (0.3 m, Doppler 0.05 m/s, 10 Hz, 0.1 s late) over a craft hovering still,
        // its dead reckoning exact: the fix of `glitch_at` carries a velocity 5 m/s off.
        let hover_f = Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2);
        let fix = |velocity_ned_mps: Vector3<f32>| Fix {
            position_ned_m: Vector3::zeros(),
            sigma_m: [0.3, 0.45],
            velocity: Some((velocity_ned_mps, 0.05)),
            age_s: 0.1,
            dt_fix_s: 0.1,
        };
        let mut nav = PositionEstimator::default();
        let mut outcomes = [FixOutcome::Rejected; 20];
        let glitch = Vector3::new(5.0, 0.0, 0.0);
        for (k, outcome) in outcomes.iter_mut().enumerate() {
            for _ in 0..200 {
                nav.predict(&level(), &hover_f, DT).unwrap();
            }
            let v = if k == 10 { glitch } else { Vector3::zeros() };
            *outcome = nav.correct_fix(&fix(v)).unwrap();
            assert!(nav.state().velocity_ned_mps.norm() < 1e-3, "fix {k}: {:?}", nav.state());
        }
        assert_eq!(outcomes[0], FixOutcome::Reset, "the first fix starts the track");
        assert!(outcomes[1..].iter().all(|o| *o == FixOutcome::Taken), "{outcomes:?}");
        // A tumble left the dead reckoning 3 m/s off (its attitude tilted, its prediction
        // accelerating): the true velocities are refused for VELOCITY_MAX_REJECT_S, then
        // taken with the whole track, whatever the fixes' rate.
        for rate_hz in [5.0f32, 10.0] {
            let mut nav = PositionEstimator::default();
            let every = (2000.0 / rate_hz) as usize;
            let mut reset_at_s = None;
            for k in 0..10 {
                if k == 1 {
                    nav.set_velocity(&Vector3::new(3.0, 0.0, 0.0));
                }
                for _ in 0..every {
                    nav.predict(&level(), &hover_f, DT).unwrap();
                }
                let outcome =
                    nav.correct_fix(&Fix { dt_fix_s: 1.0 / rate_hz, ..fix(Vector3::zeros()) });
                let since_wrong_s = (k as f32 - 1.0) / rate_hz;
                let v = nav.state().velocity_ned_mps.norm();
                if k >= 1 && reset_at_s.is_none() {
                    if outcome == Ok(FixOutcome::Reset) {
                        reset_at_s = Some(since_wrong_s);
                    } else {
                        assert!(v > 2.0, "{rate_hz} Hz, fix {k}: {v} m/s");
                    }
                }
                if reset_at_s.is_some() {
                    assert!(v < 0.05, "{rate_hz} Hz, fix {k}: {v} m/s");
                    assert!(nav.state().position_ned_m.norm() < 0.05, "{:?}", nav.state());
                }
            }
            let reset_at_s = reset_at_s.unwrap_or(f32::INFINITY);
            assert!(
                reset_at_s >= VELOCITY_MAX_REJECT_S - 1.5 / rate_hz
                    && reset_at_s <= VELOCITY_MAX_REJECT_S + 1.0 / rate_hz,
                "{rate_hz} Hz: reset {reset_at_s} s after the velocity went wrong"
            );
        }
    }

    #[test]
    fn a_fix_with_a_bad_accuracy_or_velocity_changes_nothing() {
        let mut nav = PositionEstimator::default();
        nav.correct(&Vector3::new(1.0, 2.0, 3.0), 0.1).unwrap();
        let before = *nav.state();
        let good = Fix {
            position_ned_m: Vector3::new(1.1, 2.0, 3.0),
            sigma_m: [0.3, 0.5],
            velocity: Some((Vector3::zeros(), 0.1)),
            age_s: 0.1,
            dt_fix_s: 0.1,
        };
        let bad = [
            Fix { sigma_m: [0.0, 0.5], ..good },
            Fix { sigma_m: [0.3, f32::NAN], ..good },
            Fix { velocity: Some((Vector3::new(f32::INFINITY, 0.0, 0.0), 0.1)), ..good },
            Fix { velocity: Some((Vector3::zeros(), -0.1)), ..good },
            Fix { age_s: MAX_FIX_AGE_S + 0.01, ..good },
            Fix { dt_fix_s: 0.0, ..good },
        ];
        for fix in bad {
            assert_eq!(nav.correct_fix(&fix), Err(NavigationError::BadInput), "{fix:?}");
            assert_eq!(*nav.state(), before);
        }
        assert_eq!(nav.correct_fix(&good), Ok(FixOutcome::Taken));
    }

    #[test]
    fn the_velocity_keeps_the_share_of_the_fixes_noise_its_gain_lets_through() {
        // Measured over 10 s of fixes whose errors are correlated over a few fix intervals: the
        // RMS is known to about ±15 % (0.106 against 0.092 m/s at 0.15 m/s, 0.041 against 0.039
        // at 0.05 m/s).
        for (noise_mps, seed) in [(0.15, 3), (0.05, 2)] {
            let (_, _, v_rms, _) = gnss_run(0.3, Some(noise_mps), |_| Vector3::zeros(), seed);
            let per_axis = v_rms / SQRT_3;
            let predicted = velocity_estimate_noise_mps(noise_mps, 0.1, 0.1);
            assert!(
                (per_axis / predicted - 1.0).abs() < 0.2,
                "{noise_mps} m/s fixes: velocity error {per_axis} m/s per axis, said {predicted}"
            );
        }
        assert_eq!(velocity_estimate_noise_mps(f32::NAN, 0.1, 0.1), 0.0);
        assert_eq!(velocity_estimate_noise_mps(0.1, 0.0, 0.1), 0.0);
        assert_eq!(velocity_estimate_noise_mps(0.1, 0.1, 1.0), 0.0);
    }

    #[test]
    fn the_velocity_crossover_balances_noise_against_drift_within_its_bounds() {
        let at_10_hz = |noise| velocity_crossover(noise, 0.1);
        assert!((at_10_hz(0.1) - 3.56).abs() < 0.05, "{}", at_10_hz(0.1));
        assert!(at_10_hz(0.3) < at_10_hz(0.1));
        assert_eq!(at_10_hz(100.0), VELOCITY_CROSSOVER_RAD_S.0);
        assert_eq!(at_10_hz(1e-6), VELOCITY_CROSSOVER_RAD_S.1);
        assert_eq!(at_10_hz(f32::NAN), VELOCITY_CROSSOVER_RAD_S.1);
    }
}
