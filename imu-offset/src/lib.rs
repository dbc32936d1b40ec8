//! IMU offset `r`: where the IMU sits relative to the centre of gravity, learned from throws.
//!
//! # What
//! In free fall no external force acts (apart from a little drag), so an accelerometer at offset
//! `r` from the centre of gravity reads only the rotational terms (seed paper §3.2, eq. 2–3):
//! `f = Ω̇ × r + Ω × (Ω × r) = X(Ω, Ω̇) r`, linear in `r`. Throwing the craft (spinning) and
//! catching it gives hundreds of milliseconds of such data. This module
//! 1. finds the free-fall segments in the IMU stream (the published firmware had no free-fall
//!    detector) and trims their edges so the hand never contributes ([`ImuOffsetEstimator`]);
//! 2. filters gyro and accelerometer with the same low-pass and differentiates the filtered gyro
//!    with a central difference, so `X(Ω, Ω̇)` and `f` line up in time ([`front_end`]);
//! 3. accumulates the least-squares normal equations recursively (constant memory, `f32` on the
//!    board; the information form of RLS, see `moments`), or in `f64` over logs ([`BatchFitter`]);
//! 4. reports `r̂` with an *honest* 95 % confidence ellipsoid and a verdict on the excitation
//!    ([`Estimate`], [`Verdict`]); optionally a constant accelerometer bias is fitted jointly
//!    ([`Model::OffsetAndAccBias`]) and so is a drag force per throw
//!    ([`DragModel::VerticalQuadratic`], see below).
//!
//! # Why the ellipsoid is corrected, and how
//! The paper's ellipsoid `Σ = SE² (XᵀX)⁻¹`, `SE² = ‖y − X r̂‖² / (N − 3)` assumes independent
//! residuals. After a 50 Hz low-pass at several kHz, neighbouring residuals are strongly
//! correlated, so the effective number of independent samples is far below `N`; and drag, which
//! the model ignores, adds a slowly varying error. On simulated two-throw fits the truth fell
//! inside the paper's ellipsoid in only 0–18 % of cases. Four corrections, all from the data:
//! 1. *Long-run variance by batch means.* Rows are summed in batches of `L` rows and
//!    `σ²_LR = Σ_b ‖Σ_{n∈b} e_n‖² / (L (3 n_b − p))` (`n_b` batches, `p` unknowns) replaces `SE²`.
//!    It equals `σ²` for white noise and, for correlated noise and slowly varying regressors, is
//!    the variance least squares actually has (Newey–West in batch form).
//! 2. *Two batch lengths.* Short batches ([`Config::block_s`], 20 ms ≈ 4 filter time constants)
//!    measure the filtered sensor noise precisely; long batches ([`Config::long_batch_s`],
//!    160 ms) also see what the model leaves out (horizontal release speed, anisotropic drag),
//!    which changes over the flight and rotates with the spin. The larger of the two covariance
//!    scales is used.
//! 3. *Small-sample widening.* The scale is estimated with `ν = 3 n_b − p` degrees of freedom, so
//!    the 95 % region is Hotelling's `T²(3, ν)`, not `χ²₃`. `Σ` is multiplied by
//!    `T²₀.₉₅(3, ν) / χ²₃(0.95)` so that the stated semi-axes `√(eig(Σ) χ²₃(0.95))` hold.
//! 4. *An unmodelled accelerometer bias (offset-only model).* A constant bias `b` moves the
//!    offset-only estimate by `A b`, `A = (ΣXᵀX)⁻¹ (ΣX)ᵀ`, identically in every batch, so no batch
//!    mean reveals it. The joint fit (computed anyway) estimates it; when the data show one
//!    (`b̂ᵀ Cov(b̂)⁻¹ b̂ > 3`, the value expected from noise alone), the offset-only covariance
//!    becomes `(ΣXᵀX)⁻¹ σ²_joint + A Aᵀ |b̂|²/3`: the joint fit's residual scale (which does not
//!    count the bias's constant residual as noise) plus a bias of the size found, in any
//!    direction. If the excitation suffices (judged at the joint fit's residual scale) but this
//!    term makes `r` poorly determined, the verdict is [`Verdict::BiasSuspected`] (fit the bias),
//!    not "throw again".
//!
//! The ratio `σ²_LR / SE²` is reported as [`Estimate::variance_inflation`], the paper's
//! covariance as [`Estimate::white_noise_covariance_m2`].
//!
//! # Drag
//! Drag is the one force eq. 3 leaves out, and on the simulator it is what limits the joint fit.
//! [`DragModel::VerticalQuadratic`] (the default, onboard and offline; `fit imu-offset --no-drag`
//! leaves it out) models it per throw as quadratic drag along the world vertical,
//! `s(τ) R_rel(t)ᵀ w_k`, with the known profile `s(τ) = |τ| τ` around the segment's mid-time
//! (apex), `R_rel` integrated from the filtered gyro, and one unknown 3-vector `w_k` per throw.
//! The apex is known only when the throw ends, so the throw's blocks are kept until then (10.6 KB
//! on the board) and `w_k` is profiled out at the catch, which keeps the sums constant-size
//! (details in `drag`). The profile was chosen by trying, on 100 simulated two-throw fits with
//! bias, per-throw rotating regressors `R_relᵀ` times: nothing (median error 0.46 mm), `1` (1.10
//! mm: a rotating constant is confounded with the bias along the spin axis), `[1, τ]` (0.52 mm),
//! `[1, τ, τ²]` (1.03 mm), `|τ|τ` (0.18 mm), `[|τ|τ, τ]` (0.22 mm), `[|τ|τ, |τ|]` (0.17 mm, but a
//! longer tail); with 2 m/s of horizontal release speed (which the model ignores) `|τ|τ` still
//! helps (0.70 → 0.46 mm).

//! # The accelerometer bias: rest poses ([`Model::OffsetAndAccBias`], the default)
//! Two throws alone separate a bias from the offset poorly (a constant bias looks like the
//! constant part of `X r`). Every calibration session also holds the craft still before and after
//! each throw, and the catch leaves it in a new attitude: at rest `|f − b| = g`, one equation in
//! `b` per attitude, independent of `r` (`rest`). The rest poses' bias information (local gravity
//! and the accelerometer's symmetric sensitivity error profiled out under priors,
//! [`Config::gravity_sigma_mps2`], [`Config::scale_error_sigma`], [`Config::cross_axis_sigma`])
//! is added to the free-fall normal
//! equations weighted by their covariance scale, and the fit is repeated at the scale measured at
//! its own solution. [`Estimate::acc_bias_covariance_m2ps4`] says how well the bias is known.
//!
//! # Measured accuracy and coverage (default model: offset, bias and drag; 160 ms long batches)
//! *The simulator*, 200 two-throw sessions on the built-in quads (apex 0.8–1.5 m, 300–600 °/s
//! about axes ≥ 50° apart, 0.6 s rests, anisotropic linear + quadratic drag, ICM-42688-P noise;
//! `cargo run -p sim --release --bin calibrate -- monte-carlo --bias B`):
//!
//! | bias 1σ per axis | well determined | truth in 95 % ellipsoid | error median / p99 | semi-axis median |
//! |---|---|---|---|---|
//! | 0.02 m/s² | 79.5 % | 97.0 % | 0.35 / 2.85 mm | 1.69 mm |
//! | 0.2 m/s² | 79.5 % | 97.0 % | 0.36 / 2.85 mm | 1.69 mm |
//!
//! These quads' IMUs scale exactly; the defaults assume ±3 % scale and ±2 % cross-axis errors
//! (2026-11-27; before: 94.5 % well determined, 0.24 / 1.15 mm). On 200 airframes of the random
//! world, whose IMUs have those errors (`offset_diag 200 random calibration`): error median /
//! 90th percentile 1.60 / 3.77 mm, the truth inside the ellipsoid in 190 of 200 (4.32 /
//! 12.75 mm and 34 of 200 with an exact sensor assumed).
//!
//! Without the drag model (and with an exact sensor assumed) the same sessions gave a median
//! error of 0.41 mm and a 99th percentile of 2.3 mm, about 60 % well determined after two
//! throws. *Synthetic sessions* of
//! the same kind (`flight::testing`, quadratic drag, bias 0.02 m/s², 300 sessions;
//! `cargo test -p imu-offset --release ellipsoid_coverage -- --nocapture` with 300 trials; their
//! IMU scales exactly and the fit is told so): truth inside the ellipsoid in 95.3 % (vertical, k = 0.01 /m), 92.3 % (vertical, k = 0.05 /m) and
//! 95.7 % (17° from vertical, k = 0.03 /m) of sessions; the paper's formula 0–4 %.
//!
//! # Units and frames
//! IMU frame throughout; rates in rad/s, specific force in m/s², offsets in m, times in s.

#![no_std]

mod batch;
mod drag;
pub mod front_end;
pub mod in_flight;
mod moments;
mod rest;
mod solve;
mod stream;
#[cfg(test)]
mod tests;

pub use batch::{BatchFitter, LogSegment};
pub use drag::{DragModel, MAX_THROW_BLOCKS};
pub use front_end::{regressor, AlignedSample, FrontEnd};
pub use rest::{
    RestPose, MAX_REST_POSES, MIN_POSE_BLOCKS, POSE_SIGMA_FLOOR_MPS2, REST_BLOCK_S,
    REST_MAX_DEVIATION_MPS2, REST_MAX_RATE_RAD_S,
};
pub use stream::{ImuOffsetEstimator, OffsetRls};

use nalgebra::{Matrix3, RealField, Vector3};

/// The scalar types the estimator runs in: `f32` on the board, `f64` on the host.
pub trait Scalar: RealField + Copy + From<f32> {}
impl Scalar for f32 {}
impl Scalar for f64 {}

/// One raw IMU sample (`flight`'s type: its synthetic throws, `flight::testing::throws`, are
/// made of them).
pub use flight::imu::ImuSample;

/// Lowest accepted IMU sample rate (Hz): the 50 Hz default low-pass needs at least 4× margin to
/// Nyquist for its design figures to hold (`filters::MAX_CUTOFF_FRACTION`), and typical IMU
/// output data rates start here.
pub const MIN_RATE_HZ: f32 = 500.0;
/// Highest accepted IMU sample rate (Hz): the ICM-42688-P's fastest useful output rate; the
/// sample counters and `f32` sums are sized for it.
pub const MAX_RATE_HZ: f32 = 8000.0;

/// χ²₃(0.95): the 95 % quantile of the chi-squared distribution with 3 degrees of freedom
/// (`iCDF(χ²₃, 0.95)`, seed paper §4.1).
pub const CHI2_3DOF_95: f32 = 7.8147;

/// Most free-fall segments one estimator keeps; further throws are counted and ignored.
pub const MAX_SEGMENTS: usize = 16;

/// Which unknowns are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Model {
    /// `r` only (3 unknowns), as in the seed paper.
    Offset,
    /// `r` and a constant accelerometer bias `b` (6 unknowns): `f = X r + b`.
    OffsetAndAccBias,
}

/// Tunables of the estimator. [`Config::default`] documents the origin of every default.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Config {
    /// Unknowns to fit.
    pub model: Model,
    /// Drag treatment: [`DragModel::VerticalQuadratic`] (the default) adds a drag vector per
    /// throw; [`DragModel::Ignored`] is the seed paper's eq. 3.
    pub drag_model: DragModel,
    /// Cut-off of the matched 2nd-order Butterworth low-pass on gyro and accelerometer (Hz).
    pub cutoff_hz: f32,
    /// Free-fall test: `|f| < acc_floor_mps2 + max_offset_m (|Ω̇| + |Ω|²)` (filtered signals).
    /// The floor covers noise, drag and accelerometer bias (m/s²).
    pub acc_floor_mps2: f32,
    /// Largest IMU offset the free-fall test allows for (m): in free fall `|f| ≤ |r| (|Ω̇| + |Ω|²)`.
    pub max_offset_m: f32,
    /// Shortest free fall accepted as a throw (s), measured before trimming.
    pub min_free_fall_s: f32,
    /// Free-fall test: the bound never exceeds this (m/s²), so that a craft spun up in the hand
    /// (which feels ≥ 1 g) is never taken for free fall.
    pub acc_ceiling_mps2: f32,
    /// Samples dropped after the free fall is detected (s): the low-pass settling after release.
    pub trim_start_s: f32,
    /// Samples dropped before the end of free fall is detected (s): the catching hand's force
    /// rises for a while before it crosses the threshold.
    pub trim_end_s: f32,
    /// Block length for the batch-means variance and the end-of-segment rollback (s).
    pub block_s: f32,
    /// Length of the long batches of the batch-means variance (s), a whole number of blocks.
    pub long_batch_s: f32,
    /// Largest 95 % semi-axis (m) of what the throws leave uncertain for `r` to count as well
    /// determined (the IMU's sensitivity errors, which no throw reduces, are added to the
    /// reported ellipsoid after this judgement).
    pub max_semi_axis_m: f32,
    /// Nominal gravity `g₀` (m/s²) of the rest equations `|f − b| = g` (`rest`).
    pub gravity_mps2: f32,
    /// Prior standard deviation of the local gravity about `gravity_mps2` (m/s²).
    pub gravity_sigma_mps2: f32,
    /// Standard deviation of each scale error (a diagonal element of the sensitivity error) of
    /// the gyro and the accelerometer, fraction; 0 for an IMU whose sensitivity is calibrated.
    /// No residual shows these errors: they move the rest poses' `|f|` (`rest`) and rescale the
    /// free-fall regressors, so they are priors, not fitted.
    pub scale_error_sigma: f32,
    /// Standard deviation of each cross-axis sensitivity (an off-diagonal element), fraction; 0
    /// for a calibrated IMU.
    pub cross_axis_sigma: f32,
}

impl Config {
    /// The IMU's sensitivity errors as a 1σ error of the fitted offset per axis, relative to
    /// `|r̂|`. They rescale the regressors, so a fit follows them and no residual shows them: the
    /// gyro's error `E` enters the centripetal term `Ω × (Ω × r)` twice (`r̂ ≈ r − 2E r`), the
    /// accelerometer's `S` once (`r̂ ≈ r + S r`). With every scale error of standard deviation
    /// `σ_d` ([`Config::scale_error_sigma`]) and every cross-axis one `σ_o`
    /// ([`Config::cross_axis_sigma`]), independent, each axis of `E r` has the variance
    /// `(σ_d² + 2σ_o²)/3 · |r|²` on average over directions, so `r̂` gains
    /// `5 (σ_d² + 2σ_o²)/3 · |r̂|²` per axis: 3.1 % of `|r̂|` at the defaults. Both the
    /// calibration and the in-flight fit (`in_flight`) add it to their covariance.
    pub fn sensitivity_offset_sigma(&self) -> f32 {
        let (d, o) = (self.scale_error_sigma, self.cross_axis_sigma);
        libm::sqrtf(5.0 * (d * d + 2.0 * o * o) / 3.0)
    }

    /// `self` with the sensitivity priors of an IMU whose scale errors are within
    /// `±scale_tolerance` (a fraction), spread uniformly (σ = tolerance/√3), and whose cross-axis
    /// sensitivities are within two thirds of that (the MPU-6000's ±2 % beside its ±3 %).
    pub fn with_scale_tolerance(self, scale_tolerance: f32) -> Self {
        const FRAC_1_SQRT_3: f32 = 0.577_350_26;
        let scale_error_sigma = scale_tolerance * FRAC_1_SQRT_3;
        Self { scale_error_sigma, cross_axis_sigma: scale_error_sigma * (2.0 / 3.0), ..self }
    }
}

impl Default for Config {
    fn default() -> Self {
        Self {
            // The bias is fitted with the offset: a real ICM-42688-P carries up to ±20 mg
            // (0.2 m/s²), which moves an offset-only estimate by millimetres; the rest poses
            // separate the two.
            model: Model::OffsetAndAccBias,
            // Drag, not noise or bias, is what limits eq. 3 on real throws (docs/benchmarks.md):
            // a drag vector per throw, on the board as offline.
            drag_model: DragModel::VerticalQuadratic,
            // Seed paper: 50 Hz offline. A tumble's content is a few Hz, so 50 Hz passes it with
            // negligible distortion while removing most of the differentiated gyro noise.
            cutoff_hz: 50.0,
            // 0.3 g: far below the ≥ 1 g of any hand phase (holding, throwing, catching), far
            // above noise (0.03 m/s²), drag at throwing speeds (≲ 0.2 m/s²) and MEMS bias.
            acc_floor_mps2: 3.0,
            // 5 cm: flight controllers of craft up to ~7-inch props sit closer than this to the
            // centre of gravity. Raise for larger craft.
            max_offset_m: 0.05,
            // A throw worth fitting climbs ≥ 0.1 m (≥ 0.28 s of flight); hand motions that unload
            // the IMU (a quick drop of the hand) last well under 0.15 s.
            min_free_fall_s: 0.15,
            // 0.6 g: well below the 1 g a hand holding the craft must apply; allows
            // |Ω̇ × r + Ω × (Ω × r)| up to 5.9 m/s² (2 cm at 13 rad/s even while tumbling).
            acc_ceiling_mps2: 0.6 * 9.80665,
            // 40 ms = 18 ms low-pass settling at 50 Hz (4 time constants, `filters`) + 22 ms for
            // the hand's last touch around the release.
            trim_start_s: 0.04,
            // 60 ms: a soft catch (force rising as sin² over 0.3 s to ~2 g) crosses the 0.6 g
            // ceiling ~25–40 ms after first contact; 60 ms leaves ≥ 20 ms clear of the hand.
            trim_end_s: 0.06,
            // 20 ms ≈ 4.4 filter time constants at 50 Hz, short enough for ≥ 15 blocks per throw.
            block_s: 0.02,
            // 160 ms (8 blocks): what the model leaves out (horizontal release speed, linear and
            // anisotropic drag, the apex not exactly at mid-flight) changes over the flight and
            // rotates with the spin at 1–3 rev/s, which 20 ms batches do not see. The length is
            // what calibrates the ellipsoid (longer batches see more of it but have fewer degrees
            // of freedom and a larger small-sample widening). Truth inside the 95 % ellipsoid of
            // the default model (offset, bias and drag), 8 blocks / 9 blocks:
            // - 200 sessions on the built-in quads (`calibrate monte-carlo`, bias 0.02 / 0.2
            //   m/s²): 95.0 / 94.5 % and 96.5 / 97.0 %;
            // - 300 synthetic sessions of issue 11's kind (`flight::testing`, vertical, drag
            //   k = 0.01 / 0.05 /m; 17° from vertical, k = 0.03 /m): 95.3 / 92.3 / 95.7 % and
            //   96.7 / 98.0 / 96.3 %.
            // 8 blocks centres both families on 95 % (the semi-axes need × 0.97–1.07 for exactly
            // 95 % against × 0.87–0.96 at 9 blocks).
            long_batch_s: 0.16,
            // 2 mm, from what the offset is for: the identification compensates the
            // accelerometer to the centre of gravity, and an offset error δr adds `ΔΩ̇ × δr` to
            // every specific-force increment of a motor pulse, a relative error of up to
            // `k |δr|` on the force rows of G1, with `k = |ΔΩ̇|/|Δf|` per motor: 29–54 /m on the
            // built-in quads (racer-5in 28.8, paper-quad 34.6, quad-3in 53.7; 11–13 /m on the
            // hexacopters and the octocopter). A 95 % bound of 2 mm keeps that error within
            // 10 % (the identification's target for the worst G1 row) at k = 50 /m, and within
            // 7 % on a 5-inch quad.
            max_semi_axis_m: 0.002,
            // Standard gravity (CGPM 1901).
            gravity_mps2: flight::navigation::STANDARD_GRAVITY_MPS2,
            // Local gravity is 9.780 m/s² at the equator and 9.832 at the poles (International
            // Gravity Formula), 9.797–9.815 between latitudes 35° and 55° at sea level, and drops
            // 3 mm/s² per km of altitude: 1σ = 0.01 m/s² about standard gravity covers where
            // most users live; elsewhere set `gravity_mps2` to the local value (`--gravity`).
            // A wrong g reads as a bias along "up" of the rest poses.
            gravity_sigma_mps2: 0.01,
            // Set below (`with_scale_tolerance`).
            scale_error_sigma: 0.0,
            cross_axis_sigma: 0.0,
        }
        // Scale errors spread uniformly over ±3 % (1σ = 3 %/√3 = 1.73 %) and cross-axis
        // sensitivities over ±2 % (1.15 %): the MPU-6000's initial tolerances, the widest of the
        // flight controllers' IMUs, and the range `sim::world` draws (issue 12). Without them
        // the two-throw calibration's ellipsoid held the truth in 34 of 200 random airframes
        // (`offset_diag 200 random calibration`; docs/algorithms/imu-offset.md).
        .with_scale_tolerance(0.03)
    }
}

/// A free-fall segment actually used for the fit: raw-sample indices `[start_index, end_index)`
/// of the stream (index 0 = first sample fed), after trimming.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segment {
    /// First sample used.
    pub start_index: u32,
    /// One past the last sample used.
    pub end_index: u32,
}

impl Segment {
    /// Number of samples used.
    pub fn len(&self) -> u32 {
        self.end_index.saturating_sub(self.start_index)
    }

    /// True when no sample is used (never the case for a reported segment).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Time of the first sample used (s after the first sample fed).
    pub fn t_start_s(&self, rate_hz: f32) -> f32 {
        self.start_index as f32 / rate_hz
    }

    /// Time of the last sample used (s after the first sample fed).
    pub fn t_end_s(&self, rate_hz: f32) -> f32 {
        self.end_index.saturating_sub(1) as f32 / rate_hz
    }
}

/// Why no estimate could be produced. Every fallible entry point returns one of these; nothing
/// here panics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ImuOffsetError {
    /// The sample rate is outside [`MIN_RATE_HZ`, `MAX_RATE_HZ`] or not finite.
    RateOutOfRange {
        /// The rejected rate (Hz).
        rate_hz: f32,
    },
    /// A configuration value is out of range; the text names it.
    InvalidConfig(&'static str),
    /// A sample contains NaN or ±∞; the throw in progress (if any) is discarded.
    NonFiniteInput {
        /// Index of the offending sample in the stream or log.
        index: u32,
    },
    /// A sample exceeds any IMU's range (|gyro| > 100 rad/s or |acc| > 2000 m/s² on an axis):
    /// treated as corrupt, like a non-finite sample.
    InputOutOfRange {
        /// Index of the offending sample in the stream or log.
        index: u32,
    },
    /// Logs of different sample rates cannot be pooled in one batch fit.
    RateMismatch {
        /// Rate of the logs already added (Hz).
        expected_hz: f32,
        /// Rate of the rejected log (Hz).
        found_hz: f32,
    },
    /// No free-fall segment long enough was found.
    NoFreeFall,
    /// Too little data for a fit with an honest variance.
    TooFewSamples {
        /// Samples available.
        used: u32,
        /// Samples needed.
        required: u32,
    },
    /// The normal equations are singular (no rotation at all in the data): `r` is unobservable.
    Singular,
}

impl core::fmt::Display for ImuOffsetError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::RateOutOfRange { rate_hz } => {
                write!(f, "sample rate {rate_hz} Hz is outside {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz")
            }
            Self::InvalidConfig(what) => write!(f, "invalid configuration: {what}"),
            Self::NonFiniteInput { index } => write!(f, "sample {index} is NaN or infinite"),
            Self::InputOutOfRange { index } => {
                write!(f, "sample {index} exceeds any IMU's range (corrupt data)")
            }
            Self::RateMismatch { expected_hz, found_hz } => {
                write!(f, "log at {found_hz} Hz cannot be pooled with logs at {expected_hz} Hz")
            }
            Self::NoFreeFall => f.write_str("no free fall found (throw the craft, spinning)"),
            Self::TooFewSamples { used, required } => {
                write!(f, "too few free-fall samples: {used} used, at least {required} needed")
            }
            Self::Singular => f.write_str("no rotation in the free-fall data: r is unobservable"),
        }
    }
}

/// An IMU axis, to tell the user what to spin about next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImuAxis {
    /// IMU x (forward).
    X,
    /// IMU y (right).
    Y,
    /// IMU z (down).
    Z,
}

impl ImuAxis {
    /// The IMU axis most nearly perpendicular to `direction`.
    pub fn most_perpendicular_to<T: Scalar>(direction: &Vector3<T>) -> Self {
        let a = direction.map(|v| v.abs());
        if a.x <= a.y && a.x <= a.z {
            Self::X
        } else if a.y <= a.z {
            Self::Y
        } else {
            Self::Z
        }
    }

    /// Lower-case name (`"x"`, `"y"`, `"z"`).
    pub fn name(&self) -> &'static str {
        match self {
            Self::X => "x",
            Self::Y => "y",
            Self::Z => "z",
        }
    }
}

/// Is the excitation sufficient, and if not, what to do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict<T: Scalar> {
    /// Every 95 % semi-axis of what the throws leave uncertain is within
    /// [`Config::max_semi_axis_m`] (the reported ellipsoid also holds the IMU's sensitivity
    /// errors, which no throw reduces).
    WellDetermined {
        /// Largest 95 % semi-axis (m).
        largest_semi_axis_m: T,
    },
    /// `r` is poorly determined along `direction_imu` (typically the spin axis of a throw about a
    /// principal axis, where `Ω̇ ≈ 0` and eq. 4 loses that component): throw again spinning about
    /// another axis.
    PoorlyDetermined {
        /// Unit vector (IMU frame) of the direction the throws did not excite (the spin axis of
        /// a single throw): the longest axis of the ellipsoid `r` would have from the free fall
        /// alone.
        direction_imu: Vector3<T>,
        /// How far the reported 95 % ellipsoid reaches along `direction_imu` (m): at most its
        /// largest semi-axis.
        semi_axis_m: T,
        /// The IMU axis most perpendicular to `direction_imu`: a spin about it observes it.
        spin_next_about: ImuAxis,
    },
    /// `r` alone is well determined, but with a fitted accelerometer bias it is not: along
    /// `direction_imu` the offset's centripetal term was nearly constant over the data and cannot
    /// be told apart from a bias. Throw again at a different spin rate, about another axis.
    BiasNotSeparable {
        /// Unit vector (IMU frame) of the largest semi-axis of the 95 % ellipsoid of `r`.
        direction_imu: Vector3<T>,
        /// That semi-axis (m).
        semi_axis_m: T,
        /// The IMU axis most perpendicular to `direction_imu`.
        spin_next_about: ImuAxis,
    },
    /// Offset-only fit: `r` is poorly determined because the data show an accelerometer bias
    /// that the model ignores (its effect on `r`, not the excitation, makes the ellipsoid large
    /// along `direction_imu`). Fit the bias jointly ([`Model::OffsetAndAccBias`]).
    BiasSuspected {
        /// Unit vector (IMU frame) of the largest semi-axis of the 95 % ellipsoid of `r`.
        direction_imu: Vector3<T>,
        /// That semi-axis (m).
        semi_axis_m: T,
    },
}

impl<T: Scalar> Verdict<T> {
    /// True for [`Verdict::WellDetermined`].
    pub fn is_well_determined(&self) -> bool {
        matches!(self, Self::WellDetermined { .. })
    }
}

/// Relative error added to the force rows of G1 per metre of offset error (1/m): `|ΔΩ̇|/|Δf|` of
/// one motor's pulse, rounded up from the largest of the built-in quads (quad-3in, 53.7 /m; see
/// [`Config::max_semi_axis_m`]). Turns a semi-axis into the consequence the advice states.
pub const FORCE_ROW_ERROR_PER_M: f32 = 50.0;

/// The advice in words (no allocation: written straight into the formatter). Every figure is the
/// reported ellipsoid's, with its consequence for the identification.
impl<T: Scalar> core::fmt::Display for Verdict<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let mm: T = nalgebra::convert(1000.0);
        let percent_per_m: T = nalgebra::convert(100.0 * FORCE_ROW_ERROR_PER_M);
        let consequence = |semi: T| semi * percent_per_m;
        match self {
            Self::WellDetermined { largest_semi_axis_m } => write!(
                f,
                "well determined: within {:.2} mm (largest 95 % semi-axis), which adds at most \
                 {:.0} % to the motor force effectiveness learned in flight",
                *largest_semi_axis_m * mm,
                consequence(*largest_semi_axis_m)
            ),
            Self::PoorlyDetermined { direction_imu: d, semi_axis_m, spin_next_about } => write!(
                f,
                "poorly determined along ({:.2}, {:.2}, {:.2}) in IMU axes, which the throws \
                 did not excite: within {:.2} mm along it (95 %), up to {:.0} % error in the \
                 motor force effectiveness learned in flight: throw again spinning about another \
                 axis, e.g. the IMU {} axis",
                d.x,
                d.y,
                d.z,
                *semi_axis_m * mm,
                consequence(*semi_axis_m),
                spin_next_about.name()
            ),
            Self::BiasNotSeparable { direction_imu: d, semi_axis_m, spin_next_about } => write!(
                f,
                "accelerometer bias and offset cannot be separated along ({:.2}, {:.2}, {:.2}) \
                 in IMU axes: within {:.2} mm (largest 95 % semi-axis), up to {:.0} % error in \
                 the motor force effectiveness learned in flight: hold the craft still for a \
                 second before and after each throw, in different attitudes, or throw again at \
                 a different spin rate, e.g. about the IMU {} axis",
                d.x,
                d.y,
                d.z,
                *semi_axis_m * mm,
                consequence(*semi_axis_m),
                spin_next_about.name()
            ),
            Self::BiasSuspected { direction_imu: d, semi_axis_m } => write!(
                f,
                "poorly determined along ({:.2}, {:.2}, {:.2}) in IMU axes: within {:.2} mm \
                 (largest 95 % semi-axis) because of an accelerometer bias the offset-only model \
                 ignores: fit the bias jointly (--bias)",
                d.x,
                d.y,
                d.z,
                *semi_axis_m * mm
            ),
        }
    }
}

/// A 95 % confidence ellipsoid `(r − r̂)ᵀ Σ⁻¹ (r − r̂) ≤ χ²₃(0.95)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipsoid<T: Scalar> {
    /// Semi-axes (m), largest first: `√(λᵢ χ²₃(0.95))` for the eigenvalues `λᵢ` of `Σ`.
    pub semi_axes_m: [T; 3],
    /// Unit vectors (IMU frame) along the semi-axes, same order; sign chosen so the component
    /// of largest magnitude is positive.
    pub axes: [Vector3<T>; 3],
}

/// The fitted IMU offset with its uncertainty and verdict.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate<T: Scalar> {
    /// Which unknowns were fitted.
    pub model: Model,
    /// Offset of the IMU from the centre of gravity (m, IMU frame).
    pub r_imu_m: Vector3<T>,
    /// Constant accelerometer bias (m/s², IMU frame), with [`Model::OffsetAndAccBias`].
    pub acc_bias_mps2: Option<Vector3<T>>,
    /// Covariance of `r_imu_m` (m²), corrected for correlated residuals.
    pub covariance_m2: Matrix3<T>,
    /// The seed paper's covariance `SE² (XᵀX)⁻¹` (m²), which assumes white residuals: for
    /// comparison only (it is far too small for filtered data).
    pub white_noise_covariance_m2: Matrix3<T>,
    /// Covariance of `acc_bias_mps2` ((m/s²)²), with [`Model::OffsetAndAccBias`].
    pub acc_bias_covariance_m2ps4: Option<Matrix3<T>>,
    /// 95 % confidence ellipsoid of `r_imu_m`.
    pub ellipsoid: Ellipsoid<T>,
    /// RMS of the residuals per axis (m/s²).
    pub residual_rms_mps2: T,
    /// Long-run variance over white-noise variance of the residuals: the factor by which the
    /// paper's ellipsoid volume-scale is corrected (the variance is multiplied by it).
    pub variance_inflation: T,
    /// Samples (rows of eq. 3) in the fit.
    pub samples_used: u32,
    /// Rest poses whose bias information the fit used ([`Model::OffsetAndAccBias`] only).
    pub rest_poses: u32,
    /// Whether the excitation suffices, and advice if not.
    pub verdict: Verdict<T>,
}

/// Check one raw sample: finite and within any IMU's range.
pub(crate) fn validate_sample(sample: &ImuSample, index: u32) -> Result<(), ImuOffsetError> {
    /// No MEMS gyro measures beyond ±6000 °/s (105 rad/s); values above are corrupt.
    const MAX_GYRO_RADPS: f32 = 100.0;
    /// No MEMS accelerometer measures beyond ±200 g; values above are corrupt.
    const MAX_ACC_MPS2: f32 = 2000.0;
    let values = sample.gyro_radps.iter().chain(sample.acc_mps2.iter());
    if values.clone().any(|v| !v.is_finite()) {
        return Err(ImuOffsetError::NonFiniteInput { index });
    }
    let gyro_ok = sample.gyro_radps.iter().all(|v| v.abs() <= MAX_GYRO_RADPS);
    let acc_ok = sample.acc_mps2.iter().all(|v| v.abs() <= MAX_ACC_MPS2);
    if gyro_ok && acc_ok {
        Ok(())
    } else {
        Err(ImuOffsetError::InputOutOfRange { index })
    }
}
