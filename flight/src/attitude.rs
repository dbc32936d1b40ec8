//! Attitude of the body in the world: a complementary (Mahony-type) filter on gyro and
//! accelerometer, with an external heading when one is given
//! (docs/algorithms/indi.md).
//!
//! ```text
//! ω̂   = gyro − b                                         (b: gyro-bias estimate, body axes)
//! d̂   = q⁻¹·(0, 0, 1)                                    (world down as the filter sees it, body)
//! r̂   = q⁻¹·(g − a)/|g − a|   (the specific force's direction expected, body; d̂ when a = 0)
//! e_a = (−f/|f|) × r̂        only while |f| is within ±20 % of g of |g − a|, |g − a| ≥ 0.8 g
//!                           and |ω̂| ≤ 1 rad/s
//! e_h = wrap(ψ_ext − ψ̂) · d̂          only while an external heading ψ_ext is given
//! b  ← b − (k_i e_a + k_ih e_h) dt    (each only from small errors; clamped)
//! q  ← q ⊗ exp(½ (gyro − b + k_p e_a + k_h e_h) dt)
//! ```
//!
//! Why this shape: the accelerometer measures gravity (`f ≈ −g`, "down" is `−f/|f|`) only when
//! nothing else accelerates the craft, so its correction is applied only while |f| is within
//! ±20 % of g (published) and the craft turns slower than 1 rad/s (ours: the excitation's pulses
//! and a recovery pass through 1 g while tumbling). In free fall, in the throw and while thrusting
//! hard the filter integrates the gyro alone, exactly for a rate constant over the step (the
//! rotation is the exponential of `ω dt`, not its first-order approximation), so any sample rate
//! works: the time step is passed with every sample and the gains are continuous-time. The cross
//! product `e_a` has no component about the vertical, so the accelerometer never moves the yaw;
//! the heading term `e_h` is a rotation about world down (expressed in body axes) and moves only
//! the yaw. The acceleration `a` (world) is zero unless it is known from elsewhere
//! ([`AttitudeFilter::update_accelerating`]: position fixes), and then a large, lasting `e_a`
//! may be corrected faster ([`AttitudeConfig::large_error_gain`]). Without an external heading
//! the yaw drifts on the gyro alone and [`AttitudeFilter::heading_is_external`] says so.
//!
//! The filter estimates `q_world_body`: the attitude of whatever frame the gyro and accelerometer
//! are expressed in (pass them in thrust-frame axes to estimate the thrust frame). The
//! accelerometer passed in must already be moved to the centre of gravity where that matters
//! (`f_cog = f_imu − Ω̇×r − Ω×(Ω×r)`, docs/algorithms/imu-offset.md; the caller knows the offset).
//!
//! Bad input (a non-finite sample or heading, a non-positive time step) changes nothing and is
//! reported as an [`AttitudeError`]; nothing here panics.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::math::clamp;
use crate::navigation::STANDARD_GRAVITY_MPS2;

/// ZYX Euler angles (`R_world_body = R_z(yaw) · R_y(pitch) · R_x(roll)`), the crate's one type.
pub use crate::thrust_axis::EulerZyx;

/// Band of |f| around g within which the accelerometer corrects the tilt, fraction of g
/// (±20 %, published; docs/algorithms/indi.md).
pub const ACCEL_TRUST_BAND: f32 = 0.2;

/// Smallest magnitude of the expected specific force, `|g − a|`, for which its direction
/// corrects the tilt, fraction of g (ours: the lower edge of the published band, so that with
/// no acceleration known the rule is the published one; below it a craft falls almost freely
/// and the direction is mostly the error of the acceleration known).
pub const MIN_REFERENCE_FRACTION_OF_G: f32 = 1.0 - ACCEL_TRUST_BAND;

/// Smoothed tilt error (sine of the angle) above which [`AttitudeConfig::large_error_gain`]
/// begins to act: 5° (ours), above a hold's errors (the compensated filter's in hover is 0.6°,
/// a manoeuvre's reference lag a few degrees).
pub const LARGE_ERROR_START_RAD: f32 = 0.087;

/// Smoothed tilt error at which [`AttitudeConfig::large_error_gain`] acts in full: 15° (ours),
/// what a tumble's gyro sensitivity errors leave (10-30°).
pub const LARGE_ERROR_FULL_RAD: f32 = 0.26;

/// Time constant of the smoothing of the tilt error that [`AttitudeConfig::large_error_gain`]
/// reads, s (ours): long against the rotors' vibration, short against a tumble's aftermath.
pub const LARGE_ERROR_FILTER_S: f32 = 0.2;

/// Largest tilt error (sine of the angle) the gyro-bias integral learns from: 10° (ours). Above
/// it the error is an attitude error (a start, a manoeuvre), and integrating it would wind up a
/// fake bias that takes `k_p/k_i` to unwind; it is above the `bias/k_p` = 5.7° by which a
/// 0.02 rad/s bias holds the tilt off before it is learned.
pub const BIAS_LEARNING_MAX_ERROR: f32 = 0.17;

/// Largest heading error the heading-bias integral learns from, rad (10°, ours, for the same
/// reason as [`BIAS_LEARNING_MAX_ERROR`]).
pub const HEADING_BIAS_LEARNING_MAX_ERROR_RAD: f32 = 0.1745;

/// Smallest horizontal projection of the body x axis (sine of its angle from the vertical) for
/// which the heading is defined and an external heading is applied (ours: pitched within about
/// 6° of ±90° the yaw angle is meaningless).
pub const HEADING_DEFINED_MIN_HORIZONTAL: f32 = 0.1;

/// The accelerometer's sensitivity error assumed when the acceleration is taken out of it,
/// fraction of that acceleration: 5 %, the scale (±3 %) and cross-axis (±2 %, ICM-42688-P
/// datasheet) errors added (the ranges `sim::world` draws; issue 28).
pub const ACCEL_SENSITIVITY_ERROR: f32 = 0.05;

/// Error of a tilt measured from the specific force with the acceleration taken out, in steady
/// flight, m/s² (ours): 0.6° of tilt (the firmware's compensated filter's error measured in
/// hover, Monte Carlo case 2 of `fly`) times g.
pub const STEADY_TILT_ACCEL_ERROR_MPS2: f32 = 0.1;

/// How much a tilt measured while the acceleration `accel_mps2` (m/s², known from elsewhere,
/// e.g. position fixes) is taken out of the accelerometer may teach the gyro bias, 0–1 (scale
/// [`AttitudeConfig::k_i`] by it). What is left is gravity only up to the accelerometer's
/// sensitivity error on that acceleration: as a measurement of the tilt its variance is
/// `e₀² + (ε a)²` (e₀ [`STEADY_TILT_ACCEL_ERROR_MPS2`], ε [`ACCEL_SENSITIVITY_ERROR`]), so the
/// weight is `e₀² / (e₀² + (ε a)²)`, a half at 2 m/s². The gyro-bias integral keeps what it
/// learns for tens of seconds: a recovery's braking at 3–6 m/s² then leaves no fake bias that
/// holds the tilt off into the hold (issue 28). The proportional gain is not weighted: see
/// `firmware::app::pilot`.
pub fn sensitivity_weight(accel_mps2: f32) -> f32 {
    let ratio = accel_mps2 * ACCEL_SENSITIVITY_ERROR / STEADY_TILT_ACCEL_ERROR_MPS2;
    1.0 / (1.0 + ratio * ratio)
}

/// How the filter is tuned. All gains are continuous-time (independent of the sample rate).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AttitudeConfig {
    /// Proportional gain of the tilt correction, rad/s per unit of cross-product error (per
    /// radian for small errors): the tilt converges with a time constant of about `1/k_p`.
    /// Default 0.2 (ours, 5 s): it must sit well below the position loop (about 0.8 rad/s for a
    /// 25 ms motor), because a horizontal acceleration tilts the specific force like a tilted
    /// craft, and a faster filter would believe it and feed the position loop a wrong "level"
    /// (measured in the simulator: a 1 m, 8 s oscillation with `k_p` = 1).
    pub k_p: f32,
    /// Integral gain (gyro-bias learning from the tilt), rad/s² per unit of cross-product error.
    /// Default 0.01 (ours): `k_p²/4`, the critically damped choice for `s² + k_p s + k_i`; a bias
    /// settles in about `2/√k_i` = 20 s on a craft that does not turn (slower on one that turns
    /// about the vertical at `ω`: the bias then rotates relative to the world and averages out
    /// of the tilt, time constant about `(k_p² + ω²)/(k_i k_p)`, 340 s at 0.8 rad/s). From a
    /// large attitude error (a wrong start) the integral learns a fake bias from the transient
    /// once it is below [`BIAS_LEARNING_MAX_ERROR`], and the tilt overshoots by about e⁻² of
    /// that gate (1.35°) before settling.
    pub k_i: f32,
    /// Gain of the external-heading correction, rad/s per rad of heading error. Default 1.0
    /// (ours): the yaw follows the external heading with a 1 s time constant.
    pub k_heading: f32,
    /// Integral gain of the heading correction (learns the gyro bias about the vertical), rad/s²
    /// per rad of heading error. Default 0 (off, ours): the firmware applies a heading only
    /// within steady stretches and realigns its offset at each, and any disagreement between
    /// that heading and the filter's yaw would be stored as a bias that drifts the yaw once the
    /// heading stops. With a true heading (motion capture) use `k_heading²/4` (critically
    /// damped): without it a bias `b_z` holds the yaw `b_z/k_heading` off.
    pub k_i_heading: f32,
    /// Largest gyro bias believed, per axis, rad/s. Default 0.1 (ours: 5.7 °/s, well above the
    /// offset of a consumer MEMS gyro after start-up, so only a wound-up integral reaches it).
    pub max_bias_rad_s: f32,
    /// Largest body rate (bias-corrected) at which the accelerometer corrects the tilt, rad/s.
    /// Default 1.0 (ours): a craft turning fast is being pushed by something other than gravity
    /// (a throw, the excitation pulses, a recovery), even when |f| happens to pass through 1 g.
    pub max_rate_for_accel_rad_s: f32,
    /// Factor on `k_p` for a large, lasting tilt error: applied in full once the error smoothed
    /// over [`LARGE_ERROR_FILTER_S`] reaches [`LARGE_ERROR_FULL_RAD`], none below
    /// [`LARGE_ERROR_START_RAD`]. Default 1 (none): it is for a reference that can be trusted
    /// in direction, the specific force motion capture's acceleration implies
    /// ([`AttitudeFilter::update_accelerating`]), after a tumble left the estimate far off.
    /// A hold's tilt errors stay below the start (a faster gain throughout, `k_p` 3 instead of 1,
    /// coupled with the position loop: 380 of 1,000 windy worlds held instead of 991), and the
    /// smoothing keeps the rotors' vibration (up to 5 m/s², 30° of a single sample's
    /// direction) from raising it.
    pub large_error_gain: f32,
}

impl Default for AttitudeConfig {
    fn default() -> Self {
        Self {
            k_p: 0.2,
            k_i: 0.01,
            k_heading: 1.0,
            k_i_heading: 0.0,
            max_bias_rad_s: 0.1,
            max_rate_for_accel_rad_s: 1.0,
            large_error_gain: 1.0,
        }
    }
}

impl AttitudeConfig {
    /// This tuning while the acceleration `accel_mps2` (m/s²) is taken out of the
    /// accelerometer: the gyro-bias integral `k_i` weighted by [`sensitivity_weight`], the rest
    /// as it is.
    pub fn with_acceleration_removed(self, accel_mps2: f32) -> Self {
        Self { k_i: self.k_i * sensitivity_weight(accel_mps2), ..self }
    }

    /// Check that every gain and limit is finite and not negative (the rate gate positive).
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn validate(&self) -> Result<(), AttitudeError> {
        let non_negative =
            [self.k_p, self.k_i, self.k_heading, self.k_i_heading, self.max_bias_rad_s]
                .iter()
                .all(|x| x.is_finite() && *x >= 0.0);
        let rate = self.max_rate_for_accel_rad_s;
        let boost_ok = self.large_error_gain.is_finite() && self.large_error_gain >= 1.0;
        if non_negative && boost_ok && rate.is_finite() && rate > 0.0 {
            Ok(())
        } else {
            Err(AttitudeError::BadConfig)
        }
    }
}

/// Why a call was refused (the filter's state is unchanged).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AttitudeError {
    /// A non-finite value or a non-positive time step.
    BadInput,
    /// The specific force is outside the ±20 % band around g, so it is not (only) gravity and
    /// gives no tilt to start from.
    NotGravity,
    /// A configuration value is negative or not finite.
    BadConfig,
}

/// The attitude filter.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AttitudeFilter {
    config: AttitudeConfig,
    q_world_body: UnitQuaternion<f32>,
    bias_rad_s: Vector3<f32>,
    initialised: bool,
    accel_used: bool,
    heading_external: bool,
    /// The tilt error the accelerometer showed, low-passed over [`LARGE_ERROR_FILTER_S`] (only
    /// while [`AttitudeConfig::large_error_gain`] is above 1; cleared by a restart).
    tilt_error_smoothed: Vector3<f32>,
}

impl AttitudeFilter {
    /// A filter that takes its tilt from the first sample (see [`AttitudeFilter::update`]). A
    /// `config` that fails [`AttitudeConfig::validate`] is replaced by the default; use
    /// [`AttitudeFilter::try_new`] to be told instead.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn new(config: AttitudeConfig) -> Self {
        Self::try_new(config).unwrap_or_else(|_| Self::uninitialised(AttitudeConfig::default()))
    }

    /// A filter that takes its tilt from the first sample, if `config` is valid.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn try_new(config: AttitudeConfig) -> Result<Self, AttitudeError> {
        config.validate()?;
        Ok(Self::uninitialised(config))
    }

    fn uninitialised(config: AttitudeConfig) -> Self {
        Self {
            config,
            q_world_body: UnitQuaternion::identity(),
            bias_rad_s: Vector3::zeros(),
            initialised: false,
            accel_used: false,
            heading_external: false,
            tilt_error_smoothed: Vector3::zeros(),
        }
    }

    /// The tuning in use.
    pub fn config(&self) -> &AttitudeConfig {
        &self.config
    }

    /// Change the tuning, keeping the attitude and the bias learned; refused (nothing changed)
    /// when the tuning is invalid.
    #[inline] // configuration, not the step: compiled by its caller (crate doc)
    pub fn set_config(&mut self, config: AttitudeConfig) -> Result<(), AttitudeError> {
        config.validate()?;
        self.config = config;
        Ok(())
    }

    /// Start from a known attitude `q_world_body` (renormalised). The gyro-bias estimate is
    /// kept: it belongs to the sensor, not to the attitude.
    pub fn reset_to(&mut self, q_world_body: UnitQuaternion<f32>) -> Result<(), AttitudeError> {
        let q = q_world_body.into_inner();
        if !q.coords.iter().all(|x| x.is_finite()) || crate::math::sqrt(q.norm_squared()) < 0.5 {
            return Err(AttitudeError::BadInput);
        }
        self.q_world_body = crate::math::normalized_quaternion(q);
        self.initialised = true;
        self.tilt_error_smoothed = Vector3::zeros();
        Ok(())
    }

    /// Start from the tilt a specific force `f_mps2` (body axes, at rest: `−g` in body axes)
    /// shows, with the yaw `heading_rad` (rad, about world down) or 0 without one. The tilt is
    /// the smallest rotation taking the measured down `−f/|f|` to world down, so roll and pitch
    /// come from `f` and the yaw is then set exactly. Refused (nothing changed) unless |f| is
    /// within ±20 % of g. The gyro-bias estimate is kept.
    pub fn reset_from_accel(
        &mut self,
        f_mps2: &Vector3<f32>,
        heading_rad: Option<f32>,
    ) -> Result<(), AttitudeError> {
        let finite = f_mps2.iter().all(|x| x.is_finite()) && heading_rad.is_none_or(f32::is_finite);
        if !finite {
            return Err(AttitudeError::BadInput);
        }
        let norm = crate::math::norm(f_mps2);
        if !in_gravity_band(norm) {
            return Err(AttitudeError::NotGravity);
        }
        let down_body = -f_mps2 / norm;
        // Rotates body coordinates of "down" onto world down: that is q_world_body up to yaw.
        let tilt = shortest_rotation(&down_body, &Vector3::z()).unwrap_or_else(|| {
            // Upside down: half a turn about body x also takes body up to world down.
            crate::math::rotation_about(&Vector3::x_axis(), core::f32::consts::PI)
        });
        let yaw_now = yaw_of(&tilt);
        let yaw_wanted = heading_rad.unwrap_or(0.0);
        self.q_world_body =
            crate::math::rotation_about(&Vector3::z_axis(), yaw_wanted - yaw_now) * tilt;
        self.initialised = true;
        self.tilt_error_smoothed = Vector3::zeros();
        Ok(())
    }

    /// One sample: gyro (rad/s) and specific force at the CoG (m/s²) in body axes, an external
    /// heading (rad, about world down) if one is known now, `dt_s` since the previous sample.
    ///
    /// Before the first start ([`AttitudeFilter::reset_to`], [`AttitudeFilter::reset_from_accel`])
    /// the filter starts from this sample's specific force, or, if it is not gravity (free fall,
    /// a throw), level at the given heading (or 0) and lets the gyro run.
    pub fn update(
        &mut self,
        gyro_rad_s: &Vector3<f32>,
        f_mps2: &Vector3<f32>,
        heading_rad: Option<f32>,
        dt_s: f32,
    ) -> Result<(), AttitudeError> {
        self.update_accelerating(gyro_rad_s, f_mps2, &Vector3::zeros(), heading_rad, dt_s)
    }

    /// One sample, as [`AttitudeFilter::update`], of a craft whose acceleration
    /// `accel_world_mps2` (world NED, m/s²) is known from elsewhere (position fixes). The
    /// accelerometer then measures `a − g` rather than `−g`, and the tilt is corrected towards
    /// that reference: `d̂` becomes the reference's direction `(g − a)/|g − a|` seen through the
    /// estimate. Whether the accelerometer is trusted is judged by magnitudes alone (|f| within
    /// ±20 % of g of |g − a|), which no attitude error changes. Taking `q⁻¹ a` out of the
    /// accelerometer instead would rotate `a` by the very error to be corrected: after a
    /// spinning tumble left the estimate 20-30° off while the craft accelerated at 10 m/s²,
    /// `|f − q⁻¹ a|` stayed 12-17 m/s², outside the band, and the error was never corrected
    /// (Monte Carlo seeds 508 and 639 of `fly --end land --world random --wind`: fly-aways,
    /// held since). The reference must be at least [`MIN_REFERENCE_FRACTION_OF_G`] of g for its
    /// direction to mean anything; below that (a craft falling almost freely) the gyro runs
    /// alone.
    pub fn update_accelerating(
        &mut self,
        gyro_rad_s: &Vector3<f32>,
        f_mps2: &Vector3<f32>,
        accel_world_mps2: &Vector3<f32>,
        heading_rad: Option<f32>,
        dt_s: f32,
    ) -> Result<(), AttitudeError> {
        let finite = gyro_rad_s
            .iter()
            .chain(f_mps2.iter())
            .chain(accel_world_mps2.iter())
            .all(|x| x.is_finite())
            && heading_rad.is_none_or(f32::is_finite)
            && dt_s > 0.0
            && dt_s.is_finite();
        if !finite {
            return Err(AttitudeError::BadInput);
        }
        if !self.initialised && self.reset_from_accel(f_mps2, heading_rad).is_err() {
            self.q_world_body =
                crate::math::rotation_about(&Vector3::z_axis(), heading_rad.unwrap_or(0.0));
            self.initialised = true;
        }
        let c = self.config;
        let rate_rad_s = gyro_rad_s - self.bias_rad_s;

        // The specific force expected, world axes, with its magnitude and direction ("down" as
        // the accelerometer sees it); world down itself when nothing else accelerates the craft.
        let reference_world = Vector3::new(0.0, 0.0, STANDARD_GRAVITY_MPS2) - accel_world_mps2;
        let reference_norm = crate::math::norm(&reference_world);
        let f_norm = crate::math::norm(f_mps2);
        self.accel_used = reference_norm >= MIN_REFERENCE_FRACTION_OF_G * STANDARD_GRAVITY_MPS2
            && in_trust_band(f_norm, reference_norm)
            && crate::math::norm(&rate_rad_s) <= c.max_rate_for_accel_rad_s;
        let tilt_error = if self.accel_used {
            let reference_est = self.q_world_body.inverse() * (reference_world / reference_norm);
            (-f_mps2 / f_norm).cross(&reference_est)
        } else {
            Vector3::zeros()
        };

        self.heading_external = heading_rad.is_some();
        // The heading's error, rad, and the rotation about world down, body axes, that corrects
        // it; none without a heading or while it is undefined (and then neither rotation of the
        // attitude is computed: the outdoor step, the control step's worst, has no heading).
        let (yaw_error_rad, heading_error) = match heading_rad {
            Some(heading) => {
                let x_world = self.q_world_body * Vector3::x();
                if crate::math::hypot(x_world.x, x_world.y) >= HEADING_DEFINED_MIN_HORIZONTAL {
                    let error = wrap_pi(heading - libm::atan2f(x_world.y, x_world.x));
                    (error, (self.q_world_body.inverse() * Vector3::z()) * error)
                } else {
                    (0.0, Vector3::zeros())
                }
            }
            None => (0.0, Vector3::zeros()),
        };

        let mut bias = self.bias_rad_s;
        if self.accel_used && crate::math::norm(&tilt_error) < BIAS_LEARNING_MAX_ERROR {
            bias -= tilt_error * (c.k_i * dt_s);
        }
        if yaw_error_rad.abs() < HEADING_BIAS_LEARNING_MAX_ERROR_RAD {
            bias -= heading_error * (c.k_i_heading * dt_s);
        }
        self.bias_rad_s = bias.map(|b| clamp(b, -c.max_bias_rad_s, c.max_bias_rad_s));

        let k_p = if c.large_error_gain > 1.0 {
            c.k_p * self.large_error_boost(&tilt_error, dt_s)
        } else {
            c.k_p
        };
        let omega = gyro_rad_s - self.bias_rad_s + tilt_error * k_p + heading_error * c.k_heading;
        let q = self.q_world_body.into_inner() * exp_half(&(omega * dt_s));
        self.q_world_body = crate::math::normalized_quaternion(q);
        Ok(())
    }

    /// The factor on `k_p` for this sample's `tilt_error` ([`AttitudeConfig::large_error_gain`]):
    /// 1 while the error, smoothed over [`LARGE_ERROR_FILTER_S`], is below
    /// [`LARGE_ERROR_START_RAD`], rising linearly to the configured factor at
    /// [`LARGE_ERROR_FULL_RAD`]. The smoothing follows only samples the accelerometer corrected.
    fn large_error_boost(&mut self, tilt_error: &Vector3<f32>, dt_s: f32) -> f32 {
        if self.accel_used {
            let fraction = (dt_s / LARGE_ERROR_FILTER_S).min(1.0);
            self.tilt_error_smoothed += (tilt_error - self.tilt_error_smoothed) * fraction;
        }
        let error = crate::math::norm(&self.tilt_error_smoothed);
        let ramp = (error - LARGE_ERROR_START_RAD) / (LARGE_ERROR_FULL_RAD - LARGE_ERROR_START_RAD);
        1.0 + (self.config.large_error_gain - 1.0) * clamp(ramp, 0.0, 1.0)
    }

    /// The attitude `q_world_body`: rotates body coordinates into world (NED) coordinates.
    pub fn quaternion(&self) -> UnitQuaternion<f32> {
        self.q_world_body
    }

    /// The attitude as ZYX Euler angles (roll, pitch, yaw), rad.
    pub fn euler_zyx(&self) -> EulerZyx {
        euler_zyx(&self.q_world_body)
    }

    /// The gyro-bias estimate, rad/s, body axes (subtract it from the gyro for the true rate).
    pub fn gyro_bias_rad_s(&self) -> Vector3<f32> {
        self.bias_rad_s
    }

    /// Whether the last sample's accelerometer corrected the tilt (|f| within ±20 % of g and
    /// the craft turning slower than [`AttitudeConfig::max_rate_for_accel_rad_s`]).
    pub fn accel_used(&self) -> bool {
        self.accel_used
    }

    /// Whether the last sample had an external heading (else the yaw drifts on the gyro alone).
    /// The heading is applied only while it is defined: see [`HEADING_DEFINED_MIN_HORIZONTAL`].
    pub fn heading_is_external(&self) -> bool {
        self.heading_external
    }

    /// Whether the filter has started (from a known attitude, a specific force or a first
    /// sample).
    pub fn is_initialised(&self) -> bool {
        self.initialised
    }
}

/// Whether a specific-force magnitude (m/s²) is within [`ACCEL_TRUST_BAND`] of g.
fn in_gravity_band(f_norm_mps2: f32) -> bool {
    in_trust_band(f_norm_mps2, STANDARD_GRAVITY_MPS2)
}

/// Whether a specific-force magnitude (m/s²) is within [`ACCEL_TRUST_BAND`] (a fraction of g)
/// of the magnitude expected, `reference_mps2`.
fn in_trust_band(f_norm_mps2: f32, reference_mps2: f32) -> bool {
    (f_norm_mps2 - reference_mps2).abs() <= ACCEL_TRUST_BAND * STANDARD_GRAVITY_MPS2
}

/// The unit quaternion of the rotation vector `phi` (rad): `exp(½ φ)`, exact for any angle.
fn exp_half(phi: &Vector3<f32>) -> Quaternion<f32> {
    let angle = crate::math::norm(phi);
    let half = 0.5 * angle;
    // sin(½θ)/θ, by its series below 1e-4 rad where the quotient loses precision.
    let (sin, cos) = crate::math::sin_cos(half);
    let k = if angle < 1e-4 { 0.5 - angle * angle / 48.0 } else { sin / angle };
    Quaternion::new(cos, k * phi.x, k * phi.y, k * phi.z)
}

/// Heading of a body: the yaw of its x axis projected on the horizontal plane, rad (the ZYX yaw).
pub fn yaw_of(q_world_body: &UnitQuaternion<f32>) -> f32 {
    let x = q_world_body * Vector3::x();
    libm::atan2f(x.y, x.x)
}

/// ZYX Euler angles of `q_world_body` (`R = R_z(yaw) R_y(pitch) R_x(roll)`), rad; the yaw is
/// [`yaw_of`]. At pitch ±90° roll and yaw are not separable; the split returned there is one of
/// the valid ones.
pub fn euler_zyx(q_world_body: &UnitQuaternion<f32>) -> EulerZyx {
    crate::thrust_axis::euler_zyx([q_world_body.w, q_world_body.i, q_world_body.j, q_world_body.k])
}

/// The smallest rotation taking the direction `from` onto the direction `to` (neither need be
/// unit length), or `None` when they are (nearly) opposite, a zero vector or not finite: the
/// half-way construction `(1 + a·b, a × b)` normalised, with `a`, `b` the unit directions. Unlike
/// an arccosine of `a·b`, it keeps its precision for small angles.
pub fn shortest_rotation(from: &Vector3<f32>, to: &Vector3<f32>) -> Option<UnitQuaternion<f32>> {
    let a = crate::math::try_normalize(from, 0.0)?;
    let b = crate::math::try_normalize(to, 0.0)?;
    let axis = a.cross(&b);
    let q = Quaternion::new(1.0 + a.dot(&b), axis.x, axis.y, axis.z);
    // |q|² = 2 (1 + a·b): below 1e-10 the vectors are within about 1e-5 rad of opposite and the
    // axis is noise.
    if q.norm_squared() > 1e-10 && q.coords.iter().all(|x| x.is_finite()) {
        Some(crate::math::normalized_quaternion(q))
    } else {
        None
    }
}

/// The ZYX Euler angles `[roll, pitch, yaw]`, rad, of the unit quaternion `[w, x, y, z]`
/// (rotating body into world coordinates): what `UnitQuaternion::euler_angles` gives, from one
/// arcsine and two arctangents (nalgebra's goes through a rotation matrix and links libm's
/// cosine: 3.7 KB of flash on the board with its argument reduction).
pub fn euler_zyx_rad([w, x, y, z]: [f32; 4]) -> [f32; 3] {
    let roll = libm::atan2f(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y));
    let pitch = libm::asinf(crate::math::clamp(2.0 * (w * y - z * x), -1.0, 1.0));
    let yaw = libm::atan2f(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z));
    [roll, pitch, yaw]
}

/// An angle wrapped into [−π, π) (0 for a non-finite angle).
pub fn wrap_pi(angle: f32) -> f32 {
    let two_pi = 2.0 * core::f32::consts::PI;
    let wrapped = angle - two_pi * libm::floorf(angle / two_pi + 0.5);
    if wrapped.is_finite() {
        wrapped
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;

    /// The control rate, Hz, at which the firmware runs the filter.
    const RATE_HZ: f32 = 2000.0;
    const DT: f32 = 1.0 / RATE_HZ;
    const G: f32 = STANDARD_GRAVITY_MPS2;

    fn level_f() -> Vector3<f32> {
        Vector3::new(0.0, 0.0, -G)
    }

    #[test]
    fn the_gyro_bias_learns_half_as_fast_at_2_m_per_s2_taken_out_and_the_tilt_gain_stays() {
        // At 2 m/s² the sensitivity error on the acceleration taken out (5 %: 0.1 m/s²) equals
        // the steady error of the tilt measured: the variance doubles, the weight halves.
        assert!((sensitivity_weight(2.0) - 0.5).abs() < 1e-6);
        assert_eq!(sensitivity_weight(0.0), 1.0);
        // A recovery's hardest braking (6 m/s²): a tenth.
        assert!((sensitivity_weight(6.0) - 0.1).abs() < 1e-6, "{}", sensitivity_weight(6.0));
        let tuning = AttitudeConfig { k_p: 1.0, k_i: 0.25, ..AttitudeConfig::default() };
        let braking = tuning.with_acceleration_removed(4.0);
        assert!((braking.k_i - 0.05).abs() < 1e-6, "{}", braking.k_i);
        assert_eq!(AttitudeConfig { k_i: tuning.k_i, ..braking }, tuning);
    }

    /// Angle between the body's down axis and world down, degrees (by atan2: an arccosine
    /// near 1 resolves only 0.02° in f32).
    fn tilt_deg(q: &UnitQuaternion<f32>) -> f32 {
        let down = q * Vector3::z();
        libm::atan2f(libm::hypotf(down.x, down.y), down.z).to_degrees()
    }

    fn started(q: UnitQuaternion<f32>) -> AttitudeFilter {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        filter.reset_to(q).unwrap();
        filter
    }

    #[test]
    fn a_30_degree_tilt_error_on_a_level_craft_falls_below_half_a_degree_within_50_s() {
        // k_p = 0.2 rad/s: the error decays as e^(−k_p t) until it is below the 10° learning
        // gate; from there the bias integral (critically damped with k_p) learns a fake bias
        // from the transient and gives it back by overshooting: a PI must, since the integral
        // ends at the true bias (zero). The overshoot of a critically damped pair started with
        // the integral at zero is e⁻² = 13.5 % of the 10° gate: 1.35°. Measured: below 0.5°
        // from 47 s on, peak overshoot 1.32° at 26 s.
        let mut filter =
            started(UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 30f32.to_radians()));
        let mut last_above_s = 0.0;
        let mut passed_level = false;
        let mut overshoot_deg = 0.0f32;
        for n in 0..(80 * RATE_HZ as usize) {
            filter.update(&Vector3::zeros(), &level_f(), None, DT).unwrap();
            assert!(filter.accel_used());
            let tilt = tilt_deg(&filter.quaternion());
            let roll = filter.euler_zyx().roll_rad;
            passed_level |= roll < 0.0;
            if passed_level {
                overshoot_deg = overshoot_deg.max(tilt);
            }
            if tilt >= 0.5 {
                last_above_s = n as f32 * DT;
            }
        }
        assert!(last_above_s < 50.0, "above 0.5° at {last_above_s} s");
        assert!(overshoot_deg < 1.5, "overshoot {overshoot_deg}°");
        assert!(filter.gyro_bias_rad_s().norm() < 1e-4, "fake bias left");
    }

    #[test]
    fn a_constant_turn_with_a_biased_gyro_is_tracked_within_a_degree_and_the_bias_learned() {
        // Level, turning about down at 0.8 rad/s (just below the 1 rad/s accelerometer gate),
        // gyro biased by 0.02 rad/s about each horizontal body axis, at 500 Hz (the rate of the
        // published estimator). The bias rotates relative to the world, so it averages out of
        // the tilt and is learned with a time constant of about (k_p² + ω²)/(k_i k_p) = 340 s;
        // until then it holds the tilt off by up to |b|/√(k_p² + ω²) = 2°. "Settled": after
        // 300 s. Two filters: without a heading (the yaw is unobservable and takes up what the
        // tilt error couples into it while turning: measured 4.5°, so only the tilt is held to
        // a degree) and with the true heading (every angle held to a degree).
        let rate_hz = 500.0;
        let dt = 1.0 / rate_hz;
        let bias = Vector3::new(0.02, -0.02, 0.0);
        let turn = Vector3::new(0.0, 0.0, 0.8);
        let mut free_yaw = started(UnitQuaternion::identity());
        let mut with_heading = free_yaw;
        let mut truth = UnitQuaternion::identity();
        let step = UnitQuaternion::from_scaled_axis(turn * dt);
        let (mut worst_tilt, mut worst_angle) = (0.0f32, 0.0f32);
        for n in 0..(900 * rate_hz as usize) {
            free_yaw.update(&(turn + bias), &level_f(), None, dt).unwrap();
            with_heading.update(&(turn + bias), &level_f(), Some(yaw_of(&truth)), dt).unwrap();
            truth *= step;
            if n as f32 * dt > 300.0 {
                worst_tilt = worst_tilt.max(tilt_deg(&free_yaw.quaternion()));
                worst_angle =
                    worst_angle.max(with_heading.quaternion().angle_to(&truth).to_degrees());
            }
        }
        assert!(worst_tilt < 1.0, "tilt {worst_tilt}°");
        assert!(worst_angle < 1.0, "attitude with a heading {worst_angle}°");
        for filter in [free_yaw, with_heading] {
            let learned = filter.gyro_bias_rad_s();
            assert!((learned - bias).norm() < 0.2 * bias.norm(), "{learned:?}");
        }
    }

    #[test]
    fn a_3g_manoeuvre_does_not_pull_the_tilt() {
        let mut filter = started(UnitQuaternion::identity());
        // 3 g, mostly sideways: far outside the ±20 % band, 70° away from "level".
        let f = Vector3::new(libm::sqrtf(8.0) * G, 0.0, -G);
        assert!((f.norm() - 3.0 * G).abs() < 1e-3);
        for _ in 0..(2 * RATE_HZ as usize) {
            filter.update(&Vector3::zeros(), &f, None, DT).unwrap();
            assert!(!filter.accel_used());
        }
        assert!(tilt_deg(&filter.quaternion()) < 1e-3);
    }

    #[test]
    fn a_25_degree_error_while_accelerating_at_10_m_per_s2_is_corrected_against_the_known_acceleration(
    ) {
        // A craft leaning 45° to accelerate at g horizontally (the fixes show it), its estimate
        // 25° off about the body's y axis (a tumble's gyro errors). The reference `g − a` is
        // 1.41 g, so |f| = 1.41 g: far outside ±20 % of g, but equal to what is expected. The
        // filter corrects towards the reference: with k_p 1 rad/s the error falls as e^(−t),
        // below 1° within 4 s (the bias integral weighted for 10 m/s² as the firmware weights
        // it, `sensitivity_weight`). Taking `q⁻¹ a` out of f instead, through the wrong estimate,
        // leaves |f − q⁻¹ a| 7 m/s² from g: never trusted, the error never corrected.
        let accel = Vector3::new(G, 0.0, 0.0);
        let config = AttitudeConfig { k_p: 1.0, k_i: 0.25, ..AttitudeConfig::default() }
            .with_acceleration_removed(G);
        let q_true = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 45f32.to_radians());
        let f = q_true.inverse() * (accel - Vector3::new(0.0, 0.0, G));
        let q_off = q_true * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.436);
        let error_deg =
            |filter: &AttitudeFilter| filter.quaternion().angle_to(&q_true).to_degrees();

        let mut referenced = AttitudeFilter::new(config);
        referenced.reset_to(q_off).unwrap();
        let mut subtracted = referenced;
        for _ in 0..(4 * RATE_HZ as usize) {
            referenced.update_accelerating(&Vector3::zeros(), &f, &accel, None, DT).unwrap();
            assert!(referenced.accel_used());
            let f_less_a = f - subtracted.quaternion().inverse() * accel;
            subtracted.update(&Vector3::zeros(), &f_less_a, None, DT).unwrap();
        }
        assert!(error_deg(&referenced) < 1.0, "{}°", error_deg(&referenced));
        assert!(!subtracted.accel_used());
        assert!((error_deg(&subtracted) - 25.0).abs() < 0.1, "{}°", error_deg(&subtracted));

        // A craft falling almost freely (the reference below 0.8 g): the gyro runs alone.
        let falling = Vector3::new(0.0, 0.0, 0.5 * G);
        let f_falling = q_true.inverse() * (falling - Vector3::new(0.0, 0.0, G));
        referenced.reset_to(q_off).unwrap();
        referenced.update_accelerating(&Vector3::zeros(), &f_falling, &falling, None, DT).unwrap();
        assert!(!referenced.accel_used());
    }

    #[test]
    fn a_large_lasting_error_is_corrected_faster_with_the_large_error_gain_and_a_small_one_is_not()
    {
        // The craft of the test above, accelerating at g with the estimate 25° off: with the
        // gain 3 the error is below half the plain filter's after 1.5 s (the plain one falls as
        // e^(−t): 5.6°; measured 2.2°, the boost fading as the error passes 15° to 5°). One 3°
        // off is never boosted: bit for bit the plain filter.
        let accel = Vector3::new(G, 0.0, 0.0);
        let plain = AttitudeConfig { k_p: 1.0, k_i: 0.0, ..AttitudeConfig::default() };
        let boosted = AttitudeConfig { large_error_gain: 3.0, ..plain };
        let q_true = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 45f32.to_radians());
        let f = q_true.inverse() * (accel - Vector3::new(0.0, 0.0, G));
        let run = |config: AttitudeConfig, error_deg: f32, seconds: f32| {
            let mut filter = AttitudeFilter::new(config);
            let off = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), error_deg.to_radians());
            filter.reset_to(q_true * off).unwrap();
            for _ in 0..((seconds * RATE_HZ) as usize) {
                filter.update_accelerating(&Vector3::zeros(), &f, &accel, None, DT).unwrap();
            }
            filter.quaternion()
        };
        let error_deg = |q: UnitQuaternion<f32>| q.angle_to(&q_true).to_degrees();
        let (slow, fast) = (error_deg(run(plain, 25.0, 1.5)), error_deg(run(boosted, 25.0, 1.5)));
        assert!((slow - 5.6).abs() < 0.5, "{slow}°");
        assert!(fast < slow / 2.0, "{fast}° against {slow}°");
        assert_eq!(run(plain, 3.0, 1.0), run(boosted, 3.0, 1.0));
        let bad = AttitudeConfig { large_error_gain: 0.5, ..plain };
        assert_eq!(bad.validate(), Err(AttitudeError::BadConfig));
        let bad = AttitudeConfig { large_error_gain: f32::NAN, ..plain };
        assert_eq!(bad.validate(), Err(AttitudeError::BadConfig));
    }

    #[test]
    fn one_g_while_turning_fast_is_not_trusted() {
        let mut filter = started(UnitQuaternion::identity());
        // 1 g, but 30° off and at 1.5 rad/s: a tumble passing through 1 g.
        let f = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.5) * level_f();
        filter.update(&Vector3::new(1.5, 0.0, 0.0), &f, None, DT).unwrap();
        assert!(!filter.accel_used());
        filter.update(&Vector3::new(0.5, 0.0, 0.0), &f, None, DT).unwrap();
        assert!(filter.accel_used());
    }

    #[test]
    fn an_external_heading_pulls_the_yaw_and_without_it_the_yaw_stays() {
        let mut filter = started(UnitQuaternion::identity());
        for _ in 0..(6 * RATE_HZ as usize) {
            filter.update(&Vector3::zeros(), &level_f(), Some(1.0), DT).unwrap();
        }
        // k_heading = 1 rad/s: e⁻⁶ of the 1 rad error is left.
        assert!((filter.euler_zyx().yaw_rad - 1.0).abs() < 0.01);
        assert!(tilt_deg(&filter.quaternion()) < 1e-3, "the heading moved the tilt");
        assert!(filter.heading_is_external());
        let yaw = filter.euler_zyx().yaw_rad;
        for _ in 0..(RATE_HZ as usize) {
            filter.update(&Vector3::zeros(), &level_f(), None, DT).unwrap();
        }
        assert!(!filter.heading_is_external());
        assert!((filter.euler_zyx().yaw_rad - yaw).abs() < 1e-5);
    }

    #[test]
    fn a_heading_converges_on_a_tilted_craft_and_across_the_wrap() {
        let q0 = UnitQuaternion::from_euler_angles(0.3, -0.2, 3.0);
        let mut filter = started(q0);
        let f = q0.inverse() * level_f();
        for _ in 0..(8 * RATE_HZ as usize) {
            filter.update(&Vector3::zeros(), &f, Some(-3.0), DT).unwrap();
        }
        let euler = filter.euler_zyx();
        assert!(wrap_pi(euler.yaw_rad + 3.0).abs() < 0.01, "{euler:?}");
        assert!((euler.roll_rad - 0.3).abs() < 0.01 && (euler.pitch_rad + 0.2).abs() < 0.01);
    }

    #[test]
    fn with_the_heading_integral_the_bias_about_the_vertical_is_learned() {
        let config = AttitudeConfig { k_i_heading: 0.25, ..AttitudeConfig::default() };
        let mut filter = AttitudeFilter::try_new(config).unwrap();
        filter.reset_to(UnitQuaternion::identity()).unwrap();
        let bias = Vector3::new(0.0, 0.0, 0.02);
        for _ in 0..(30 * RATE_HZ as usize) {
            filter.update(&bias, &level_f(), Some(0.0), DT).unwrap();
        }
        assert!((filter.gyro_bias_rad_s() - bias).norm() < 0.05 * bias.norm());
        assert!(filter.euler_zyx().yaw_rad.abs() < 1e-3);
    }

    #[test]
    fn the_quaternion_stays_unit_over_a_million_steps_of_tumbling() {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        let gyro = Vector3::new(7.0, 7.0, 1.7);
        for n in 0..1_000_000 {
            // Alternate 1 g (rejected by the rate gate) and free fall, with a heading now and then.
            let f = if n % 2 == 0 { level_f() } else { Vector3::zeros() };
            let heading = (n % 3 == 0).then_some(0.5);
            filter.update(&gyro, &f, heading, DT).unwrap();
        }
        assert!((filter.quaternion().into_inner().norm() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn free_fall_integrates_the_gyro_exactly_at_any_rate() {
        // 0.5 s at (400, 400, 100) °/s with no accelerometer information, as after a throw.
        let rate = Vector3::new(400.0f32, 400.0, 100.0).map(f32::to_radians);
        let truth = UnitQuaternion::from_scaled_axis(rate * 0.5);
        for rate_hz in [8000.0, 2000.0, 500.0, 50.0] {
            let mut filter = started(UnitQuaternion::identity());
            for _ in 0..((0.5 * rate_hz) as usize) {
                filter.update(&rate, &Vector3::zeros(), None, 1.0 / rate_hz).unwrap();
            }
            let error = filter.quaternion().angle_to(&truth).to_degrees();
            assert!(error < 0.01, "{error}° at {rate_hz} Hz");
        }
    }

    #[test]
    fn the_first_sample_starts_the_filter_from_gravity_or_level() {
        let q = UnitQuaternion::from_euler_angles(0.4, -0.3, 0.0);
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        assert!(!filter.is_initialised());
        filter.update(&Vector3::zeros(), &(q.inverse() * level_f()), Some(1.2), DT).unwrap();
        let euler = filter.euler_zyx();
        assert!((euler.roll_rad - 0.4).abs() < 1e-4 && (euler.pitch_rad + 0.3).abs() < 1e-4);
        assert!((euler.yaw_rad - 1.2).abs() < 1e-3);

        let mut falling = AttitudeFilter::new(AttitudeConfig::default());
        falling.update(&Vector3::zeros(), &Vector3::zeros(), None, DT).unwrap();
        assert!(falling.is_initialised());
        assert!(falling.quaternion().angle() < 1e-6);
    }

    #[test]
    fn reset_from_accel_takes_the_tilt_from_f_and_the_yaw_from_the_heading() {
        let truth = UnitQuaternion::from_euler_angles(-0.5, 0.7, 2.0);
        let f = truth.inverse() * level_f() * 1.1;
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        filter.reset_from_accel(&f, Some(2.0)).unwrap();
        assert!(filter.quaternion().angle_to(&truth) < 1e-4);
        filter.reset_from_accel(&f, None).unwrap();
        let euler = filter.euler_zyx();
        assert!(euler.yaw_rad.abs() < 1e-5);
        assert!((euler.roll_rad + 0.5).abs() < 1e-4 && (euler.pitch_rad - 0.7).abs() < 1e-4);
        // Upside down is a tilt like any other.
        filter.reset_from_accel(&-level_f(), Some(0.0)).unwrap();
        assert!((tilt_deg(&filter.quaternion()) - 180.0).abs() < 1e-3);

        let before = filter;
        assert_eq!(
            filter.reset_from_accel(&(level_f() * 1.3), None),
            Err(AttitudeError::NotGravity)
        );
        assert_eq!(
            filter.reset_from_accel(&Vector3::zeros(), None),
            Err(AttitudeError::NotGravity)
        );
        assert_eq!(
            filter.reset_from_accel(&level_f(), Some(f32::NAN)),
            Err(AttitudeError::BadInput)
        );
        assert_eq!(filter, before);
    }

    #[test]
    fn euler_angles_follow_the_zyx_convention() {
        for (roll, pitch, yaw) in [(0.1, 0.2, 0.3), (-2.5, 1.2, -3.0), (3.0, -1.4, 1.0)] {
            let q = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
            let euler = euler_zyx(&q);
            assert!((euler.roll_rad - roll).abs() < 1e-4, "{euler:?}");
            assert!((euler.pitch_rad - pitch).abs() < 1e-4, "{euler:?}");
            assert!((euler.yaw_rad - yaw).abs() < 1e-4, "{euler:?}");
            assert!((yaw_of(&q) - yaw).abs() < 1e-4);
            // R_z(yaw) R_y(pitch) R_x(roll), built by hand.
            let built = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
                * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), pitch)
                * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), roll);
            assert!(built.angle_to(&q) < 1e-5);
        }
    }

    #[test]
    fn the_shortest_rotation_is_exact_for_small_and_large_angles() {
        for angle in [1e-6f32, 1e-3, 0.5, 3.0] {
            let from = Vector3::new(0.3, -0.2, 0.9);
            let axis = Unit::new_normalize(from.cross(&Vector3::new(1.0, 0.0, 0.0)));
            let to = UnitQuaternion::from_axis_angle(&axis, angle) * from * 2.0;
            let q = shortest_rotation(&from, &to).unwrap();
            assert!((q.angle() - angle).abs() < 1e-6 + 1e-6 * angle, "{angle}: {}", q.angle());
            assert!((q * from.normalize() - to.normalize()).norm() < 1e-6);
        }
        assert!(shortest_rotation(&Vector3::z(), &-Vector3::z()).is_none());
        assert!(shortest_rotation(&Vector3::zeros(), &Vector3::z()).is_none());
        assert!(shortest_rotation(&Vector3::new(f32::NAN, 0.0, 0.0), &Vector3::z()).is_none());
    }

    #[test]
    fn bad_input_changes_nothing() {
        let mut filter = AttitudeFilter::new(AttitudeConfig::default());
        let f = Vector3::new(0.5, -0.3, -G);
        filter.update(&Vector3::new(0.01, 0.0, 0.0), &f, Some(0.2), DT).unwrap();
        let before = filter;
        let nan = Vector3::new(f32::NAN, 0.0, 0.0);
        let zero = Vector3::zeros();
        assert_eq!(filter.update(&nan, &f, None, DT), Err(AttitudeError::BadInput));
        assert_eq!(filter.update(&zero, &nan, None, DT), Err(AttitudeError::BadInput));
        assert_eq!(filter.update(&zero, &f, Some(f32::INFINITY), DT), Err(AttitudeError::BadInput));
        assert_eq!(filter.update(&zero, &f, None, f32::NAN), Err(AttitudeError::BadInput));
        assert_eq!(filter.update(&zero, &f, None, 0.0), Err(AttitudeError::BadInput));
        assert_eq!(filter.update(&zero, &f, None, -DT), Err(AttitudeError::BadInput));
        assert_eq!(
            filter.update_accelerating(&zero, &f, &nan, None, DT),
            Err(AttitudeError::BadInput)
        );
        let bad_q = UnitQuaternion::new_unchecked(Quaternion::new(f32::NAN, 0.0, 0.0, 0.0));
        assert_eq!(filter.reset_to(bad_q), Err(AttitudeError::BadInput));
        assert_eq!(filter, before);
    }

    #[test]
    fn a_bad_config_is_refused() {
        let bad = AttitudeConfig { k_p: -1.0, ..AttitudeConfig::default() };
        assert_eq!(AttitudeFilter::try_new(bad), Err(AttitudeError::BadConfig));
        let bad = AttitudeConfig { max_rate_for_accel_rad_s: 0.0, ..AttitudeConfig::default() };
        assert_eq!(bad.validate(), Err(AttitudeError::BadConfig));
        let bad = AttitudeConfig { k_i: f32::NAN, ..AttitudeConfig::default() };
        assert_eq!(*AttitudeFilter::new(bad).config(), AttitudeConfig::default());
    }
}
