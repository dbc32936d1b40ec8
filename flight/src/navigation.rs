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
//! The correction gains place a triple pole at the crossover `ω_c` (`k_p = 3ω_c·dt_fix`,
//! `k_v = 3ω_c²·dt_fix`, `k_b = ω_c³·dt_fix`), so the estimate follows the accelerometer above
//! `ω_c` and the fixes below it. With no fix the filter is dead reckoning:
//! velocity from the accelerometer alone, which is what holds zero vertical speed when no pose
//! is available (its drift is the accelerometer's bias times time, about 0.1 m/s per 10 s for a
//! 0.01 m/s² bias). [`PositionEstimator::hold_still`] zeroes the velocity while the craft is
//! known to be at rest (in the hand before a throw), so dead reckoning starts from a true zero.

use nalgebra::{UnitQuaternion, Vector3};

/// Standard gravity, m/s² (ISO 80000-3).
pub const STANDARD_GRAVITY_MPS2: f32 = 9.806_65;

/// Default crossover of the fixes and the accelerometer, rad/s: motion capture at 100 Hz with
/// millimetre noise is trusted down to about 0.3 s (a quarter of the position loop's bandwidth
/// is slower still, so the estimate's lag does not cost phase margin).
pub const DEFAULT_CROSSOVER_RAD_S: f32 = 4.0;

/// Largest accelerometer bias the estimator believes, m/s² (a consumer MEMS accelerometer's
/// offset after calibration is well under this; more means the fixes disagree with the IMU).
pub const MAX_BIAS_MPS2: f32 = 0.5;

/// Oldest fix still trusted, s: after this the estimate is dead reckoning and says so.
pub const FIX_TIMEOUT_S: f32 = 0.2;

/// The estimator's output.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
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
    /// A non-finite value or a non-positive time step.
    BadInput,
}

/// The position and velocity estimator.
#[derive(Clone, Copy, Debug)]
pub struct PositionEstimator {
    crossover_rad_s: f32,
    state: NavigationState,
    /// Time since the last fix, s.
    since_fix_s: f32,
    /// Whether any fix has been taken since the last reset.
    fixed_once: bool,
}

impl Default for PositionEstimator {
    fn default() -> Self {
        Self::new(DEFAULT_CROSSOVER_RAD_S)
    }
}

impl PositionEstimator {
    /// An estimator at rest at the origin, with fixes weighed by `crossover_rad_s`.
    pub fn new(crossover_rad_s: f32) -> Self {
        Self {
            crossover_rad_s,
            state: NavigationState::default(),
            since_fix_s: f32::INFINITY,
            fixed_once: false,
        }
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
        self.since_fix_s += dt_s;
        s.has_fix = self.since_fix_s <= FIX_TIMEOUT_S;
        Ok(())
    }

    /// Correct with a position fix of the CoG `position_ned_m`, `dt_fix_s` after the previous
    /// fix (the fix spacing; 0.01 s for 100 Hz motion capture). The first fix (or the first after
    /// [`FIX_TIMEOUT_S`]) sets the position outright.
    pub fn correct(
        &mut self,
        position_ned_m: &Vector3<f32>,
        dt_fix_s: f32,
    ) -> Result<(), NavigationError> {
        if !position_ned_m.iter().all(|x| x.is_finite()) || !is_step(dt_fix_s) {
            return Err(NavigationError::BadInput);
        }
        let s = &mut self.state;
        if !self.fixed_once || self.since_fix_s > FIX_TIMEOUT_S {
            s.position_ned_m = *position_ned_m;
        } else {
            let w = self.crossover_rad_s;
            // A triple pole at ω_c; at most the whole error per fix.
            let k_p = (3.0 * w * dt_fix_s).min(1.0);
            let k_v = 3.0 * w * w * dt_fix_s;
            let k_b = w * w * w * dt_fix_s;
            let error = position_ned_m - s.position_ned_m;
            s.position_ned_m += error * k_p;
            s.velocity_ned_mps += error * k_v;
            let bias = s.accel_bias_ned_mps2 - error * k_b;
            s.accel_bias_ned_mps2 = bias.map(|b| b.clamp(-MAX_BIAS_MPS2, MAX_BIAS_MPS2));
        }
        self.fixed_once = true;
        self.since_fix_s = 0.0;
        s.has_fix = true;
        Ok(())
    }
}

/// Whether `dt_s` is a usable time step: finite and positive.
fn is_step(dt_s: f32) -> bool {
    dt_s.is_finite() && dt_s > 0.0
}

/// Fix spacing of the window over which [`HeadingAlignment`] compares accelerations, fixes
/// (10 at 100 Hz: 0.1 s, long enough for a 1 m/s² acceleration to move the craft 1 cm, ten
/// times the motion-capture noise).
pub const ALIGNMENT_WINDOW_FIXES: usize = 10;

/// Evidence needed before the heading alignment is trusted, m²: `|Σ D'·D + i Σ D'×D|`, the
/// coherent sum (noise and unrelated motion average out of it, unlike a sum of magnitudes):
/// about twenty windows of 2 m/s² (2 cm of second difference each).
pub const ALIGNMENT_EVIDENCE_M2: f32 = 20.0 * 0.02 * 0.02;

/// The yaw between the attitude filter's world and the world of the position fixes.
///
/// Without a compass the attitude filter's heading is arbitrary, and an external heading is
/// that of a frame (the motion-capture body) whose yaw relative to the IMU nobody told us. The
/// position fixes fix it: the second difference of positions over a window,
/// `D = p(t) − 2p(t−T) + p(t−2T)`, is the double integral of the acceleration and does not depend
/// on the velocity; the same second difference of the filter's own dead reckoning `D'` is that
/// integral seen in the filter's world. `D = R_z(ψ) D'`, so `ψ = atan2(Σ D'×D, Σ D'·D)` over the
/// windows (horizontal components). Any horizontal acceleration informs it: the recovery
/// after a throw, and the position loop's own corrections.
#[derive(Clone, Copy, Debug)]
pub struct HeadingAlignment {
    /// Dead-reckoned position and velocity in the filter's world (no corrections).
    dead_position: Vector3<f32>,
    dead_velocity: Vector3<f32>,
    /// The last `2N + 1` fixes: (fix position, dead-reckoned position), newest at `head`.
    ring: [(Vector3<f32>, Vector3<f32>); 2 * ALIGNMENT_WINDOW_FIXES + 1],
    head: usize,
    filled: usize,
    cross: f32,
    dot: f32,
    evidence_m2: f32,
    /// The yaw, once the evidence sufficed.
    trusted_yaw_rad: Option<f32>,
}

impl Default for HeadingAlignment {
    fn default() -> Self {
        Self {
            dead_position: Vector3::zeros(),
            dead_velocity: Vector3::zeros(),
            ring: [(Vector3::zeros(), Vector3::zeros()); 2 * ALIGNMENT_WINDOW_FIXES + 1],
            head: 0,
            filled: 0,
            cross: 0.0,
            dot: 0.0,
            evidence_m2: 0.0,
            trusted_yaw_rad: None,
        }
    }
}

impl HeadingAlignment {
    /// Integrate the acceleration `accel_ned_mps2` (the filter's world, gravity removed).
    pub fn predict(&mut self, accel_ned_mps2: &Vector3<f32>, dt_s: f32) {
        if accel_ned_mps2.iter().all(|x| x.is_finite()) && dt_s.is_finite() {
            self.dead_position += self.dead_velocity * dt_s + accel_ned_mps2 * (0.5 * dt_s * dt_s);
            self.dead_velocity += accel_ned_mps2 * dt_s;
        }
    }

    /// A fix (position, world NED, m) at evenly spaced times.
    pub fn fix(&mut self, position_ned_m: &Vector3<f32>) {
        if !position_ned_m.iter().all(|x| x.is_finite()) {
            return;
        }
        let len = self.ring.len();
        self.head = (self.head + 1) % len;
        self.ring[self.head] = (*position_ned_m, self.dead_position);
        self.filled = (self.filled + 1).min(len);
        if self.filled < len {
            return;
        }
        let n = ALIGNMENT_WINDOW_FIXES;
        let at = |back: usize| self.ring[(self.head + len - back) % len];
        let (p0, q0) = at(0);
        let (p1, q1) = at(n);
        let (p2, q2) = at(2 * n);
        let d = p0 - p1 * 2.0 + p2;
        let d_filter = q0 - q1 * 2.0 + q2;
        self.cross += d_filter.x * d.y - d_filter.y * d.x;
        self.dot += d_filter.x * d.x + d_filter.y * d.y;
        self.evidence_m2 = libm::sqrtf(self.cross * self.cross + self.dot * self.dot);
        if self.evidence_m2 >= ALIGNMENT_EVIDENCE_M2 {
            self.trusted_yaw_rad = Some(libm::atan2f(self.cross, self.dot));
        }
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

    /// The yaw from the filter's world to the fixes' world, rad, once the evidence suffices.
    pub fn yaw_rad(&self) -> Option<f32> {
        self.trusted_yaw_rad
    }

    /// Evidence gathered so far, m² (see [`ALIGNMENT_EVIDENCE_M2`]).
    pub fn evidence_m2(&self) -> f32 {
        self.evidence_m2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn fixes_pull_a_biased_velocity_back_to_the_truth() {
        // The craft hovers still at (1, 2, −3) m; the accelerometer has a 0.05 m/s² bias along x
        // and the estimate starts 0.5 m/s wrong. Motion capture at 100 Hz.
        let mut nav = PositionEstimator::default();
        let truth = Vector3::new(1.0, 2.0, -3.0);
        nav.correct(&truth, 0.01).unwrap();
        nav.state.velocity_ned_mps = Vector3::new(0.5, 0.0, 0.0);
        let f = Vector3::new(0.05, 0.0, -STANDARD_GRAVITY_MPS2);
        for step in 0..(10 * 2000) {
            nav.predict(&level(), &f, DT).unwrap();
            if step % 20 == 19 {
                nav.correct(&truth, 0.01).unwrap();
            }
        }
        let s = nav.state();
        assert!((s.position_ned_m - truth).norm() < 0.01, "{:?}", s.position_ned_m);
        // The bias is learned, so no steady velocity error remains (a second-order filter would
        // keep 2b/ω_c = 2.5 cm/s).
        assert!(s.velocity_ned_mps.norm() < 0.003, "{:?}", s.velocity_ned_mps);
        assert!((s.accel_bias_ned_mps2.x - 0.05).abs() < 0.005, "{:?}", s.accel_bias_ned_mps2);
        assert!(s.has_fix);
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
                align.fix(&(truth_p + noise * 0.001));
            }
        }
        let found = align.yaw_rad().expect("enough evidence after 3 s of 1–3 m/s²");
        assert!((found - yaw).abs() < 1f32.to_radians(), "{}° for 70°", found.to_degrees());
    }

    #[test]
    fn hovering_still_gives_no_alignment() {
        let mut align = HeadingAlignment::default();
        for step in 0..(3 * 2000) {
            align.predict(&Vector3::zeros(), DT);
            if step % 20 == 0 {
                align.fix(&Vector3::new(1.0, 2.0, -3.0));
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
}
