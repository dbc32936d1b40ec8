//! The hover thrust axis `q_U^T` (seed paper §3.3): the most efficient direction in which the
//! motors can produce force without producing torque, and the rotation that maps the thrust frame
//! into the IMU frame.
//!
//! # Problem (paper eq. 6)
//! With `f = G1f u` (specific force, m/s², IMU coordinates) and `τ = G1τ u` (angular acceleration,
//! rad/s²) for a motor command `u ∈ ℝᵐ`, `4 ≤ m ≤ 8`:
//!
//! ```text
//! min uᵀ W u   s.t.   ‖G1f u‖ = g,   G1τ u = 0,   u_min ≤ u ≤ u_max
//! ```
//!
//! # Method
//! 1. **Weights by scaling.** `u = W^{-1/2} ũ` turns the cost into `ũᵀũ` (the paper's `H = I`)
//!    with `G̃ = G W^{-1/2}` and bounds `W^{1/2} u_min ≤ ũ ≤ W^{1/2} u_max`. Everything below
//!    works on the scaled problem.
//! 2. **Null space of G1τ.** For 5 to 8 motors, the Gram blocks of the weighted rows in f64
//!    (`T = G̃1τ G̃1τᵀ`, `K = G̃1f G̃1τᵀ`, `S = G̃1f G̃1fᵀ`, each 3 × 3 whatever `m`): the pivots of
//!    `T` (Cholesky with diagonal pivoting) are the squares of `R`'s diagonal in a
//!    column-pivoting QR of `G̃1τᵀ`, and give the same rank test, which rejects airframes whose
//!    torque map is rank-deficient; the projector onto the null space is
//!    `P = I − G̃1τᵀ T⁻¹ G̃1τ`. Two passes of multiply-accumulates over the motors, instead of a
//!    QR whose reflectors are applied to three force rows and back to the command (about a
//!    third fewer instructions at 6 to 8 motors). For the quad, whose null space is a line, a
//!    column-pivoting Householder QR of `G̃1τᵀ` (`householder`) is cheaper.
//! 3. **Dominant eigen-pair.** The paper iterates on `A = (G̃1f N)ᵀ(G̃1f N)` (`(m−3)²`, `N` an
//!    orthonormal basis of the null space). We use `B = G̃1f N` (`3 × (m−3)`) and iterate on
//!    `C = B Bᵀ = G̃1f P G̃1fᵀ = S − K T⁻¹ Kᵀ`, which is always 3 × 3 and has the same non-zero
//!    eigenvalues: if `C w = λ w` then `v = Bᵀw/‖Bᵀw‖` is the paper's eigenvector of `A`. Two
//!    reasons: the cost does not grow with `m`, and the iterate `w` is the thrust direction
//!    itself in IMU coordinates, so the warm start kept in [`ThrustAxisSolver`] between calls
//!    is independent of any null-space basis. The power iteration returns the warm vector when
//!    a residual bound proves it converged, else is accelerated by repeated squaring
//!    (`C ← C²/tr`, so `k` squarings are `2ᵏ` power steps), stopped when `C` is numerically
//!    rank one and capped at [`SolverConfig::max_squarings`]; the warm-start vector is
//!    re-seeded from the dominant column when `‖C w‖` collapses. For m = 4, `A = ‖b‖²` is
//!    1 × 1 and `w = b/‖b‖` in closed form.
//! 4. **Scaling and sign.** `η = Bᵀw · g/‖C w‖` (the paper's `η = v g/√(vᵀAv)`, which makes
//!    `‖G1f u‖ = g` exact for any `w`), `ũ = ±N η = ±P G̃1fᵀ w · g/‖C w‖`, with the sign that
//!    keeps `u` within the bounds (both fit: the one with positive command sum, as in the
//!    published code).
//! 5. **Bounded optimum.** When neither sign fits, the heuristic's answer is not the solution of
//!    problem (6); `bounded` then searches every active set of clamped motors for the true
//!    bounded optimum, and the result is flagged `bounded = true`.
//! 6. **Attitude.** `d = G1f u*`; `q_thrust_to_imu` is the shortest arc taking `(0, 0, −1)` to
//!    `d/|d|` (`rotation`).
//!
//! Everything is `f32` but the Gram blocks (f64, see `Gram`), fixed-size (`[_; MOTORS_MAX]`
//! plus a count) and allocation-free. The solve dispatches once on the motor count: the quad,
//! and a const-generic body compiled for `MOTORS_MAX` (5 to 7 motors on zero-filled columns,
//! exactly), so every loop has a fixed trip count; square roots are the FPU's `vsqrt.f32`
//! (`math::sqrt`). Cost on the Cortex-M7 (QEMU, `cargo xtask bench-m7`, heuristic
//! path): about 700 instructions at m = 4 and 1,200–1,450 at 5 to 8 motors; see
//! `docs/benchmarks.md`.

// `!(x > limit)` is deliberate throughout: it is also true for NaN, which must take the safe
// branch. Index loops are kept where they mirror the matrix notation of the derivation.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

mod bounded;
mod householder;
mod rotation;

use rotation::shortest_arc_from_down_unit;
pub use rotation::{euler_zyx, rotate, shortest_arc_from_down, EulerZyx, THRUST_DIR_THRUST_FRAME};

use crate::math::{clamp, sqrt};
use householder::{PivotedQr3, RANK_TOLERANCE};

/// Fewest motors the solver accepts: with fewer than four, `G1τ u = 0` (three equations) leaves
/// no thrust direction to choose.
pub const MOTORS_MIN: usize = 4;
/// Most motors the solver accepts (fixed-capacity storage).
pub const MOTORS_MAX: usize = 8;

// Standard gravity is the default `g` of the offline contract (9.81 before 2026-11-29).
use crate::navigation::STANDARD_GRAVITY_MPS2;

/// Largest magnitude accepted for any input number (effectiveness entries, bounds, weights, g).
///
/// Unit: that of the input. Origin: squares of inputs appear in the solver; 1e6² = 1e12 leaves
/// f32 (max 3e38) ample head-room for sums over eight motors and for squaring 3 × 3 matrices,
/// while physical effectiveness values are below 1e4 (m/s² or rad/s² per unit command).
pub const MAX_INPUT_MAGNITUDE: f32 = 1e6;

/// Smallest accepted motor weight (dimensionless); with [`MAX_INPUT_MAGNITUDE`] it bounds the
/// scaling `W^{-1/2}` to 1e3 so that scaled entries stay within f32's comfortable range.
pub const MIN_WEIGHT: f32 = 1e-6;

/// Relative threshold below which the dominant eigenvalue counts as zero: `λ ≤ ZERO_EIGEN · ‖G̃1f‖²_F`.
///
/// Unit: dimensionless. Origin: f32 projection errors in `C` are a few round-offs (6e-8) of
/// `‖G̃1f‖²_F`; 1e-6 is well above that and means "the zero-torque commands produce less than
/// 0.1 % of the force the motors could produce": no hover.
const ZERO_EIGEN: f32 = 1e-6;

/// `e₂(C) / tr(C)² ≤ POWER_CONVERGED` stops the squarings: the second elementary symmetric
/// function of the eigenvalues (sum of principal 2 × 2 minors) relative to the trace squared is
/// about `λ₂/λ₁`, so the iterate is then within about 1e-6 rad of the dominant eigenvector.
/// f32 round-off in the minors is about 2e-7, so this is reachable.
const POWER_CONVERGED: f32 = 1e-6;

/// The power iteration returns the warm-start vector unchanged when it is provably within this
/// angle of the dominant eigenvector (rad), the accuracy the squarings stop at
/// ([`POWER_CONVERGED`]).
const WARM_CONVERGED_RAD: f32 = 1e-6;

/// Re-seed when `‖C w‖ < POWER_RESEED · max_j C_jj` (trace-normalised `C`): the warm-start vector
/// is then within about 6° of orthogonal to the dominant eigenvector and would converge slowly.
const POWER_RESEED: f32 = 0.1;

/// Tolerance on the motor bounds, relative to `|u_min| + |u_max|` of each motor (f32 round-off
/// of the solve is about 1e-6 of the command scale). Commands within it are clamped onto the bound.
const BOUND_TOLERANCE: f32 = 1e-5;

/// Which input a validation error refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Input {
    /// `G1f`, specific force per unit command (m/s²).
    G1f,
    /// `G1τ`, angular acceleration per unit command (rad/s²).
    G1Tau,
    /// Lower motor bounds.
    UMin,
    /// Upper motor bounds.
    UMax,
    /// Motor weights.
    Weights,
    /// Gravity, m/s².
    Gravity,
}

impl core::fmt::Display for Input {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Input::G1f => "g1_f",
            Input::G1Tau => "g1_tau",
            Input::UMin => "u_min",
            Input::UMax => "u_max",
            Input::Weights => "weights",
            Input::Gravity => "g",
        })
    }
}

/// Why a problem was refused or has no hover solution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ThrustAxisError {
    /// Input: the motor count is outside `MOTORS_MIN..=MOTORS_MAX`.
    MotorCount {
        /// The count given.
        motors: usize,
    },
    /// Input: a row or vector has a different length from the motor count.
    Length {
        /// Which input.
        input: Input,
        /// Its length.
        found: usize,
        /// The motor count.
        expected: usize,
    },
    /// Input: NaN, infinite, or larger in magnitude than [`MAX_INPUT_MAGNITUDE`].
    OutOfRange {
        /// Which input.
        input: Input,
        /// Motor (column) index; 0 for the scalar `g`.
        motor: usize,
    },
    /// Input: `u_min > u_max` for a motor.
    InvertedBounds {
        /// Motor index.
        motor: usize,
    },
    /// Input: a weight below [`MIN_WEIGHT`], or `g ≤ 0`.
    NotPositive {
        /// Which input.
        input: Input,
        /// Motor index; 0 for `g`.
        motor: usize,
    },
    /// No hover: `G1τ` has rank below 3, so torques cannot all be controlled.
    TorqueRankDeficient {
        /// Numerical rank found (0 to 2).
        rank: u8,
    },
    /// No hover: the dominant eigenvalue is ≈ 0: commands that produce no torque produce no force.
    NoZeroTorqueThrust,
    /// No hover: neither sign of the heuristic's `u*` fits the bounds, and no bounded optimum
    /// exists (or the bounded search is disabled in [`SolverConfig`]).
    NoHoverWithinBounds,
    /// The arithmetic produced a non-finite result (should not happen for validated inputs).
    NumericalFailure,
}

impl core::fmt::Display for ThrustAxisError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            ThrustAxisError::MotorCount { motors } => write!(
                f,
                "{motors} motors: the thrust-axis solver needs {MOTORS_MIN} to {MOTORS_MAX}"
            ),
            ThrustAxisError::Length { input, found, expected } => {
                write!(f, "{input} has length {found}, expected {expected} (one per motor)")
            }
            ThrustAxisError::OutOfRange { input, motor } => write!(
                f,
                "{input} entry for motor {motor} is NaN, infinite or beyond ±{MAX_INPUT_MAGNITUDE:e}"
            ),
            ThrustAxisError::InvertedBounds { motor } => {
                write!(f, "u_min > u_max for motor {motor}")
            }
            ThrustAxisError::NotPositive { input: Input::Gravity, .. } => {
                write!(f, "g must be positive")
            }
            ThrustAxisError::NotPositive { input, motor } => {
                write!(f, "{input} for motor {motor} must be at least {MIN_WEIGHT:e}")
            }
            ThrustAxisError::TorqueRankDeficient { rank } => write!(
                f,
                "G1tau has rank {rank} < 3: the motors cannot control all three torques, no hover"
            ),
            ThrustAxisError::NoZeroTorqueThrust => write!(
                f,
                "the commands that produce no torque produce no force (eigenvalue ~ 0): no hover"
            ),
            ThrustAxisError::NoHoverWithinBounds => write!(
                f,
                "no torque-free command producing thrust g lies within the motor bounds: no hover"
            ),
            ThrustAxisError::NumericalFailure => write!(f, "numerical failure (non-finite result)"),
        }
    }
}

/// A validated hover problem: effectiveness, bounds, weights and gravity for `m` motors.
///
/// Storage is fixed-capacity; entries beyond `motors()` are zero and never read.
#[derive(Clone, Debug, PartialEq)]
pub struct HoverProblem {
    motors: usize,
    /// Rows of `G1f` (m/s² per unit command), IMU coordinates.
    g1_f: [[f32; MOTORS_MAX]; 3],
    /// Rows of `G1τ` (rad/s² per unit command), IMU coordinates.
    g1_tau: [[f32; MOTORS_MAX]; 3],
    u_min: [f32; MOTORS_MAX],
    u_max: [f32; MOTORS_MAX],
    /// `u_min` and `u_max` widened by [`BOUND_TOLERANCE`] (for the sign test), set with the bounds.
    u_min_tolerant: [f32; MOTORS_MAX],
    u_max_tolerant: [f32; MOTORS_MAX],
    weights: [f32; MOTORS_MAX],
    /// `1/√wᵢ`, computed when the weights are set.
    inv_sqrt_weight: [f32; MOTORS_MAX],
    /// All weights are 1 (the scaling is skipped).
    unit_weights: bool,
    g_mps2: f32,
}

impl HoverProblem {
    /// A problem from the rows of `G1f` (m/s² per unit command) and `G1τ` (rad/s² per unit
    /// command), with the defaults of the offline contract: bounds `[0, 1]`, unit weights,
    /// `g` = [`STANDARD_GRAVITY_MPS2`]. All six rows must have the same length `m`, 4 ≤ m ≤ 8.
    pub fn new(g1_f: [&[f32]; 3], g1_tau: [&[f32]; 3]) -> Result<Self, ThrustAxisError> {
        let motors = g1_f[0].len();
        if !(MOTORS_MIN..=MOTORS_MAX).contains(&motors) {
            return Err(ThrustAxisError::MotorCount { motors });
        }
        let mut problem = HoverProblem {
            motors,
            g1_f: [[0.0; MOTORS_MAX]; 3],
            g1_tau: [[0.0; MOTORS_MAX]; 3],
            u_min: [0.0; MOTORS_MAX],
            u_max: [0.0; MOTORS_MAX],
            u_min_tolerant: [0.0; MOTORS_MAX],
            u_max_tolerant: [0.0; MOTORS_MAX],
            weights: [0.0; MOTORS_MAX],
            inv_sqrt_weight: [0.0; MOTORS_MAX],
            unit_weights: true,
            g_mps2: STANDARD_GRAVITY_MPS2,
        };
        problem.u_max[..motors].fill(1.0);
        problem.set_tolerant_bounds();
        problem.weights[..motors].fill(1.0);
        problem.inv_sqrt_weight[..motors].fill(1.0);
        for k in 0..3 {
            problem.g1_f[k] = problem.checked(Input::G1f, g1_f[k])?;
            problem.g1_tau[k] = problem.checked(Input::G1Tau, g1_tau[k])?;
        }
        Ok(problem)
    }

    /// Replace the motor bounds (command units, one per motor, `u_min ≤ u_max`).
    pub fn with_bounds(mut self, u_min: &[f32], u_max: &[f32]) -> Result<Self, ThrustAxisError> {
        let lower = self.checked(Input::UMin, u_min)?;
        let upper = self.checked(Input::UMax, u_max)?;
        if let Some(motor) = (0..self.motors).find(|&i| lower[i] > upper[i]) {
            return Err(ThrustAxisError::InvertedBounds { motor });
        }
        self.u_min = lower;
        self.u_max = upper;
        self.set_tolerant_bounds();
        Ok(self)
    }

    fn set_tolerant_bounds(&mut self) {
        for i in 0..self.motors {
            let tolerance =
                BOUND_TOLERANCE * (libm::fabsf(self.u_min[i]) + libm::fabsf(self.u_max[i]));
            self.u_min_tolerant[i] = self.u_min[i] - tolerance;
            self.u_max_tolerant[i] = self.u_max[i] + tolerance;
        }
    }

    /// Replace the diagonal of the actuator weight matrix `W` (dimensionless, ≥ [`MIN_WEIGHT`]):
    /// the cost is `Σ wᵢ uᵢ²`, e.g. a motor's power per unit command squared.
    pub fn with_weights(mut self, weights: &[f32]) -> Result<Self, ThrustAxisError> {
        let weights = self.checked(Input::Weights, weights)?;
        if let Some(motor) = (0..self.motors).find(|&i| weights[i] < MIN_WEIGHT) {
            return Err(ThrustAxisError::NotPositive { input: Input::Weights, motor });
        }
        self.weights = weights;
        for i in 0..self.motors {
            self.inv_sqrt_weight[i] = 1.0 / sqrt(weights[i]);
        }
        self.unit_weights = weights[..self.motors].iter().all(|&w| w == 1.0);
        Ok(self)
    }

    /// Replace the gravity (m/s², positive): the specific force the hover must produce.
    pub fn with_gravity(mut self, g_mps2: f32) -> Result<Self, ThrustAxisError> {
        let out_of_range = ThrustAxisError::OutOfRange { input: Input::Gravity, motor: 0 };
        if !(g_mps2.is_finite() && libm::fabsf(g_mps2) <= MAX_INPUT_MAGNITUDE) {
            return Err(out_of_range);
        }
        if g_mps2 <= 0.0 {
            return Err(ThrustAxisError::NotPositive { input: Input::Gravity, motor: 0 });
        }
        self.g_mps2 = g_mps2;
        Ok(self)
    }

    /// Number of motors `m`.
    pub fn motors(&self) -> usize {
        self.motors
    }

    /// Gravity, m/s².
    pub fn g_mps2(&self) -> f32 {
        self.g_mps2
    }

    /// Row `axis` of `G1f`, m/s² per unit command (`motors()` entries).
    pub fn g1_f_row(&self, axis: usize) -> &[f32] {
        &self.g1_f[axis.min(2)][..self.motors]
    }

    /// Row `axis` of `G1τ`, rad/s² per unit command (`motors()` entries).
    pub fn g1_tau_row(&self, axis: usize) -> &[f32] {
        &self.g1_tau[axis.min(2)][..self.motors]
    }

    /// Lower motor bounds.
    pub fn u_min(&self) -> &[f32] {
        &self.u_min[..self.motors]
    }

    /// Upper motor bounds.
    pub fn u_max(&self) -> &[f32] {
        &self.u_max[..self.motors]
    }

    /// Motor weights (diagonal of `W`).
    pub fn weights(&self) -> &[f32] {
        &self.weights[..self.motors]
    }

    fn checked(&self, input: Input, values: &[f32]) -> Result<[f32; MOTORS_MAX], ThrustAxisError> {
        if values.len() != self.motors {
            return Err(ThrustAxisError::Length {
                input,
                found: values.len(),
                expected: self.motors,
            });
        }
        let mut out = [0.0; MOTORS_MAX];
        for (motor, (&value, slot)) in values.iter().zip(out.iter_mut()).enumerate() {
            if !(value.is_finite() && libm::fabsf(value) <= MAX_INPUT_MAGNITUDE) {
                return Err(ThrustAxisError::OutOfRange { input, motor });
            }
            *slot = value;
        }
        Ok(out)
    }
}

/// Whether the bounded search (`bounded`) is compiled in (cargo feature `bounded-search`, on
/// by default). Without it [`SolverConfig::bounded_search`] has no effect: a heuristic `u*`
/// outside the bounds gives [`ThrustAxisError::NoHoverWithinBounds`]. The firmware builds
/// without it: its learner never runs the search (`bounded_search: false`, the 2 kHz deadline),
/// and the search is about 48 KB of code at `opt-level = 3` (docs/benchmarks.md, "Firmware
/// size").
pub const BOUNDED_SEARCH_COMPILED: bool = cfg!(feature = "bounded-search");

/// Tuning of [`ThrustAxisSolver`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SolverConfig {
    /// Cap on repeated squarings of the 3 × 3 matrix per call: at most `2^max_squarings` power
    /// steps. Default 6 (64 steps): an eigenvalue ratio λ₂/λ₁ = 0.8 converges to 1e-6 in one
    /// call; closer ratios keep improving across calls through the warm start.
    pub max_squarings: u8,
    /// Search for the true bounded optimum of problem (6) when the heuristic's `u*` leaves the
    /// bounds (default true). Its cost grows with the number of active sets (about 1,700 faces
    /// at m = 8), so a caller with a hard deadline may turn it off and get
    /// [`ThrustAxisError::NoHoverWithinBounds`] instead.
    pub bounded_search: bool,
    /// When the heuristic's `u*` leaves the bounds and no bounded search runs: return `u*`
    /// clamped to the bounds ([`HoverSolution::clamped_by`], a hover whose torque is not zero)
    /// instead of [`ThrustAxisError::NoHoverWithinBounds`] (default false), unless every motor
    /// at its upper bound gives less than `g` along that axis (the model says the craft is too
    /// weak to hover at all). For a caller that would rather fly an approximate axis than none,
    /// as a last resort.
    pub clamp_outside_bounds: bool,
}

impl Default for SolverConfig {
    fn default() -> Self {
        SolverConfig { max_squarings: 6, bounded_search: true, clamp_outside_bounds: false }
    }
}

/// A hover solution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HoverSolution {
    motors: usize,
    u_hover: [f32; MOTORS_MAX],
    /// Unit vector along `G1f · u_hover`, IMU coordinates.
    pub thrust_dir_imu: [f32; 3],
    /// Shortest-arc rotation taking `(0, 0, −1)` to `thrust_dir_imu`, `[w, x, y, z]`: maps
    /// thrust-frame coordinates into IMU coordinates (the paper's `q_U^T`).
    pub q_thrust_to_imu: [f32; 4],
    /// Dominant eigenvalue `λ` of `A = (G̃1f N)ᵀ(G̃1f N)` (weighted), (m/s²)² per unit command²:
    /// the unbounded optimum costs `g²/λ`.
    pub eigenvalue: f32,
    /// `true` when the heuristic's `u*` left the bounds and this is the bounded optimum.
    pub bounded: bool,
    /// 0 for a hover within the bounds. Otherwise the heuristic's `u*` left the bounds and this
    /// is `u*` clamped to them ([`SolverConfig::clamp_outside_bounds`]): not a hover of the model
    /// (its torque is not zero), only the nearest axis that a controller finding its own torque
    /// balance can fly; the value is the largest distance, in normalised thrust, by which a motor
    /// of `u*` was outside its bounds.
    pub clamped_by: f32,
    /// The cost `u_hoverᵀ W u_hover` (command units squared).
    pub cost: f32,
}

impl HoverSolution {
    /// The hover command, one entry per motor.
    pub fn u_hover(&self) -> &[f32] {
        &self.u_hover[..self.motors]
    }

    /// ZYX Euler angles of `q_thrust_to_imu`, radians.
    pub fn euler_zyx(&self) -> EulerZyx {
        euler_zyx(self.q_thrust_to_imu)
    }
}

/// The problem after the weight substitution `u = W^{-1/2} ũ` (so the cost is `ũᵀũ`).
#[derive(Clone, Copy, Debug)]
struct ScaledProblem {
    motors: usize,
    g1_f: [[f32; MOTORS_MAX]; 3],
    g1_tau: [[f32; MOTORS_MAX]; 3],
    lower: [f32; MOTORS_MAX],
    upper: [f32; MOTORS_MAX],
    /// `1/√wᵢ`: `uᵢ = ũᵢ · inv_sqrt_weight[i]`.
    inv_sqrt_weight: [f32; MOTORS_MAX],
    g_mps2: f32,
}

impl ScaledProblem {
    fn new(p: &HoverProblem) -> Self {
        let mut s = ScaledProblem {
            motors: p.motors,
            g1_f: [[0.0; MOTORS_MAX]; 3],
            g1_tau: [[0.0; MOTORS_MAX]; 3],
            lower: [0.0; MOTORS_MAX],
            upper: [0.0; MOTORS_MAX],
            inv_sqrt_weight: p.inv_sqrt_weight,
            g_mps2: p.g_mps2,
        };
        for i in 0..p.motors.min(MOTORS_MAX) {
            let inv = p.inv_sqrt_weight[i];
            for k in 0..3 {
                s.g1_f[k][i] = p.g1_f[k][i] * inv;
                s.g1_tau[k][i] = p.g1_tau[k][i] * inv;
            }
            s.lower[i] = p.u_min[i] / inv;
            s.upper[i] = p.u_max[i] / inv;
        }
        s
    }
}

/// The thrust-axis solver. Keeps the last dominant direction (IMU coordinates) to warm-start the
/// power iteration of the next call: the effectiveness estimate changes slowly, so successive
/// calls keep improving the same eigenvector (paper §3.3, step 4).
#[derive(Clone, Copy, Debug)]
pub struct ThrustAxisSolver {
    config: SolverConfig,
    /// Unit vector, IMU coordinates: the last dominant eigenvector of `C`.
    warm_dir: [f32; 3],
}

impl Default for ThrustAxisSolver {
    fn default() -> Self {
        Self::new(SolverConfig::default())
    }
}

impl ThrustAxisSolver {
    /// A solver with no history: the first iterate is "thrust along −z of the IMU" (a board
    /// mounted flat, FRD), a good guess for most airframes.
    pub const fn new(config: SolverConfig) -> Self {
        ThrustAxisSolver { config, warm_dir: THRUST_DIR_THRUST_FRAME }
    }

    /// The configuration.
    pub fn config(&self) -> SolverConfig {
        self.config
    }

    /// The warm-start direction (unit, IMU coordinates): the dominant eigenvector of the last
    /// successful call, or `(0, 0, −1)` before any.
    pub fn warm_direction(&self) -> [f32; 3] {
        self.warm_dir
    }

    /// Forget the history (e.g. after the airframe or the IMU mounting changed).
    pub fn reset(&mut self) {
        self.warm_dir = THRUST_DIR_THRUST_FRAME;
    }

    /// Solve problem (6) for `problem`. Bounded time: one 3-column QR, at most
    /// `max_squarings` 3 × 3 squarings, and (only when the heuristic's `u*` leaves the bounds
    /// and `bounded_search` is on) the active-set search of the `bounded` module.
    pub fn solve(&mut self, problem: &HoverProblem) -> Result<HoverSolution, ThrustAxisError> {
        // Two compiled sizes, so that every loop below has a fixed trip count: the quad (its
        // one-dimensional null space has a closed form) and `MOTORS_MAX`, which also solves 5 to
        // 7 motors on the problem's zero-filled columns. That is exact: a zero column of `G1τ`
        // and `G1f` stays zero through every reflection (their vectors are zero there), so the
        // padding adds exact zeros to every sum and gets a zero command. One copy instead of
        // four saves 16.7 KB of flash at opt-level 3 (docs/benchmarks.md, "Firmware size").
        match problem.motors {
            4 => self.solve_quad(problem),
            5..=MOTORS_MAX => self.solve_fixed::<MOTORS_MAX>(problem),
            motors => Err(ThrustAxisError::MotorCount { motors }),
        }
    }

    /// [`Self::solve`] with the first `M ≥ problem.motors` columns (zero beyond the motors).
    fn solve_fixed<const M: usize>(
        &mut self,
        problem: &HoverProblem,
    ) -> Result<HoverSolution, ThrustAxisError> {
        // Steps 1 and 2: the weighted Gram blocks, the torque map's rank, and the projection
        // onto its null space.
        let gram = if problem.unit_weights {
            Gram::of::<M, false>(problem)
        } else {
            Gram::of::<M, true>(problem)
        };
        let rank = torque_rank(&gram.t);
        if rank < 3 {
            return Err(ThrustAxisError::TorqueRankDeficient { rank: rank as u8 });
        }
        let (c, torque_part) = gram.null_space_blocks();
        let force_scale2 = (gram.s[0] + gram.s[3] + gram.s[5]) as f32;

        // Step 3: the dominant eigenvector of C by warm-started power iteration.
        let w = dominant_direction(&c, self.warm_dir, self.config.max_squarings);
        let cw = mat3_vec(&c, w);
        let eigenvalue = dot3(w, cw);
        if !(eigenvalue > ZERO_EIGEN * force_scale2) {
            return Err(no_thrust(eigenvalue));
        }
        self.warm_dir = w;

        // Step 4: ũ = P G̃1fᵀ w g/‖C w‖ with the projector P = I − G̃1τᵀ T⁻¹ G̃1τ, so
        // uᵢ = (g/‖C w‖) (f_i·w − τ_i·y)/wᵢ with y = T⁻¹ Kᵀ w (f_i, τ_i: motor i's columns of
        // G1f and G1τ, unweighted; wᵢ its weight).
        let scale = problem.g_mps2 / norm3(cw);
        let w_scaled = [w[0] * scale, w[1] * scale, w[2] * scale];
        let y = torque_part.solve(w_scaled);
        let mut u = [0.0f32; M];
        for i in 0..M {
            u[i] = problem.g1_f[0][i] * w_scaled[0]
                + problem.g1_f[1][i] * w_scaled[1]
                + problem.g1_f[2][i] * w_scaled[2]
                - problem.g1_tau[0][i] * y[0]
                - problem.g1_tau[1][i] * y[1]
                - problem.g1_tau[2][i] * y[2];
        }
        if !problem.unit_weights {
            for i in 0..M {
                u[i] *= problem.inv_sqrt_weight[i] * problem.inv_sqrt_weight[i];
            }
        }

        self.within_bounds(problem, u, eigenvalue, force_scale2)
    }

    /// The quad: its torque null space is a line, which one Householder QR of `G̃1τᵀ` (4 × 3)
    /// gives in closed form: `A = ‖b‖²` is 1 × 1 with `b = G̃1f n`, `w = b/‖b‖` and `η = g/‖b‖`
    /// (the power iteration would converge in one step to the same). At four motors the QR is
    /// cheaper than the Gram blocks of [`Self::solve_fixed`] (about 700 against 1,050
    /// instructions on the Cortex-M7, measured).
    fn solve_quad(&mut self, problem: &HoverProblem) -> Result<HoverSolution, ThrustAxisError> {
        const M: usize = 4;
        // Step 1: weights by scaling (G̃ = G W^{-1/2}); a plain copy for identical motors.
        let mut tau = [[0.0f32; M]; 3];
        let mut b = [[0.0f32; M]; 3];
        for k in 0..3 {
            tau[k].copy_from_slice(&problem.g1_tau[k][..M]);
            b[k].copy_from_slice(&problem.g1_f[k][..M]);
        }
        if !problem.unit_weights {
            for k in 0..3 {
                for i in 0..M {
                    tau[k][i] *= problem.inv_sqrt_weight[i];
                    b[k][i] *= problem.inv_sqrt_weight[i];
                }
            }
        }
        // Step 2: null space of G̃1τ by pivoted QR of G̃1τᵀ (columns = rows of G̃1τ).
        let qr = PivotedQr3::<M>::factor(tau);
        if qr.rank < 3 {
            return Err(ThrustAxisError::TorqueRankDeficient { rank: qr.rank as u8 });
        }
        // Rows of Qᵀ G̃1fᵀ; entry 3 of row k is entry k of b = G̃1f n. Qᵀ is orthogonal, so
        // the sum of all squares is ‖G̃1f‖²_F.
        let mut force_scale2 = 0.0;
        for row in b.iter_mut() {
            qr.apply_qt(row);
            for x in row.iter() {
                force_scale2 += x * x;
            }
        }
        // Steps 3 and 4 in closed form.
        let column = [b[0][3], b[1][3], b[2][3]];
        let eigenvalue = dot3(column, column);
        if !(eigenvalue > ZERO_EIGEN * force_scale2) {
            return Err(no_thrust(eigenvalue));
        }
        let inv = 1.0 / sqrt(eigenvalue);
        self.warm_dir = [column[0] * inv, column[1] * inv, column[2] * inv];
        let mut u = [0.0f32; M];
        u[3] = problem.g_mps2 * inv;
        qr.apply_q(&mut u);
        if !problem.unit_weights {
            for i in 0..M {
                u[i] *= problem.inv_sqrt_weight[i];
            }
        }
        self.within_bounds(problem, u, eigenvalue, force_scale2)
    }

    /// Step 5: the sign of `u` (one entry per motor, either sign of the hover) that fits the
    /// bounds, else the bounded optimum, else the configured fallback.
    fn within_bounds<const M: usize>(
        &self,
        problem: &HoverProblem,
        mut u: [f32; M],
        eigenvalue: f32,
        force_scale2: f32,
    ) -> Result<HoverSolution, ThrustAxisError> {
        match sign_within_bounds(problem, &u) {
            Some(sign) => finish(problem, &u, sign, eigenvalue, false),
            None if BOUNDED_SEARCH_COMPILED && self.config.bounded_search => {
                let scaled = ScaledProblem::new(problem);
                let u_scaled = bounded::optimum(&scaled, force_scale2)
                    .ok_or(ThrustAxisError::NoHoverWithinBounds)?;
                for i in 0..M {
                    u[i] = u_scaled[i] * scaled.inv_sqrt_weight[i];
                }
                finish(problem, &u, 1.0, eigenvalue, true)
            }
            None if self.config.clamp_outside_bounds => {
                clamp_to_bounds(problem, &mut u, eigenvalue)
            }
            None => Err(ThrustAxisError::NoHoverWithinBounds),
        }
    }
}

/// The Gram blocks of the weighted rows (`G̃ = G W^{-1/2}`), in f64: `T = G̃1τ G̃1τᵀ`,
/// `K = G̃1f G̃1τᵀ` and `S = G̃1f G̃1fᵀ`, each 3 × 3 whatever the motor count; `T` and `S` as
/// their upper triangles `[00, 01, 02, 11, 12, 22]`.
///
/// Why f64: the rank test compares the pivots of `T` (the squares of `R`'s diagonal in a QR of
/// `G̃1τᵀ`) at [`RANK_TOLERANCE`]² = 1e-8, below f32's resolution, and `C = S − K T⁻¹ Kᵀ`
/// subtracts the part of the force rows that produces torque, which can be most of them. The
/// products of two f32 are exact in f64 and the sums of eight keep 1e-16 of their size, so both
/// are resolved with many digits to spare. The Cortex-M7's FPU is double precision: one
/// instruction per multiply-accumulate, as in f32.
struct Gram {
    t: [f64; 6],
    k: [[f64; 3]; 3],
    s: [f64; 6],
}

/// `sum += w vᵀ` on the upper triangle of a symmetric 3×3 (`w` a weighted `v`), packed by
/// rows: (0,0) (0,1) (0,2) (1,1) (1,2) (2,2).
#[inline(always)]
fn add_outer_upper(sum: &mut [f64; 6], w: [f64; 3], v: [f64; 3]) {
    sum[0] += w[0] * v[0];
    sum[1] += w[0] * v[1];
    sum[2] += w[0] * v[2];
    sum[3] += w[1] * v[1];
    sum[4] += w[1] * v[2];
    sum[5] += w[2] * v[2];
}

impl Gram {
    /// The blocks for the first `M` motors of `problem` (zero columns beyond its motors add
    /// exact zeros), with the weights when `WEIGHTED` (`false` only for unit weights, whose
    /// scaling is the identity). Two passes over the motors, so that each keeps its sums in the
    /// FPU's 16 double registers: `T` and `S` (12 sums), then `K` (9).
    #[inline(always)]
    fn of<const M: usize, const WEIGHTED: bool>(problem: &HoverProblem) -> Gram {
        let column = |rows: &[[f32; MOTORS_MAX]; 3], i: usize| {
            [rows[0][i] as f64, rows[1][i] as f64, rows[2][i] as f64]
        };
        // Motor i's torque column times 1/wᵢ, the weight of its outer products.
        let weighted = |a: [f64; 3], i: usize| {
            if WEIGHTED {
                let x = problem.inv_sqrt_weight[i] as f64;
                let r = x * x;
                [a[0] * r, a[1] * r, a[2] * r]
            } else {
                a
            }
        };
        let (mut t, mut s) = ([0.0f64; 6], [0.0f64; 6]);
        for i in 0..M {
            let a = column(&problem.g1_tau, i);
            let f = column(&problem.g1_f, i);
            add_outer_upper(&mut t, weighted(a, i), a);
            add_outer_upper(&mut s, weighted(f, i), f);
        }
        let mut k = [[0.0f64; 3]; 3];
        for i in 0..M {
            let ar = weighted(column(&problem.g1_tau, i), i);
            let f = column(&problem.g1_f, i);
            for row in 0..3 {
                for col in 0..3 {
                    k[row][col] += f[row] * ar[col];
                }
            }
        }
        Gram { t, k, s }
    }

    /// For a torque map of full rank: `C = S − K T⁻¹ Kᵀ = B Bᵀ` (the force of the zero-torque
    /// commands, step 3, in f32) and what step 4 needs of `T⁻¹ Kᵀ`, by the factorisation
    /// `T = L D Lᵀ` (`L` unit lower triangular; no square root): `V = L⁻¹ Kᵀ`,
    /// `C = S − Vᵀ D⁻¹ V`. After the rank test `T`'s condition is at most 1e8, so its pivots
    /// are positive in f64. Always inlined: as a call it returns its 156 bytes through a
    /// `memcpy` (about 120 instructions on the Cortex-M7, measured).
    #[inline(always)]
    fn null_space_blocks(&self) -> ([[f32; 3]; 3], TorquePart) {
        let t = &self.t;
        let l10 = t[1] / t[0];
        let l20 = t[2] / t[0];
        let d1 = t[3] - l10 * t[1];
        let l21 = (t[4] - l20 * t[1]) / d1;
        let d2 = t[5] - l20 * t[2] - l21 * l21 * d1;
        let inv_d = [1.0 / t[0], 1.0 / d1, 1.0 / d2];
        // Column j of V solves L v = (row j of K); W = D⁻¹ V.
        let mut v = [[0.0f64; 3]; 3];
        let mut w = [[0.0f64; 3]; 3];
        for j in 0..3 {
            let kj = self.k[j];
            let v0 = kj[0];
            let v1 = kj[1] - l10 * v0;
            let v2 = kj[2] - l20 * v0 - l21 * v1;
            v[0][j] = v0;
            v[1][j] = v1;
            v[2][j] = v2;
            w[0][j] = v0 * inv_d[0];
            w[1][j] = v1 * inv_d[1];
            w[2][j] = v2 * inv_d[2];
        }
        // Entry n of the upper triangle, (i, j).
        let c_entry = |n: usize, i: usize, j: usize| {
            (self.s[n] - (v[0][i] * w[0][j] + v[1][i] * w[1][j] + v[2][i] * w[2][j])) as f32
        };
        let (c01, c02, c12) = (c_entry(1, 0, 1), c_entry(2, 0, 2), c_entry(4, 1, 2));
        let c = [
            [c_entry(0, 0, 0), c01, c02],
            [c01, c_entry(3, 1, 1), c12],
            [c02, c12, c_entry(5, 2, 2)],
        ];
        (c, TorquePart { w, l: [l10, l20, l21] })
    }
}

/// `W = D⁻¹ L⁻¹ Kᵀ` and `L` (below its diagonal) of [`Gram::null_space_blocks`]:
/// `T⁻¹ Kᵀ x = L⁻ᵀ (W x)`.
struct TorquePart {
    w: [[f64; 3]; 3],
    /// `[L₁₀, L₂₀, L₂₁]`.
    l: [f64; 3],
}

impl TorquePart {
    /// `y = T⁻¹ Kᵀ x`: the torque-map coordinates of the torque that the force direction `x`
    /// brings with it (what step 4 removes).
    fn solve(&self, x: [f32; 3]) -> [f32; 3] {
        let x = x.map(|value| value as f64);
        let wx = self.w.map(|row| row[0] * x[0] + row[1] * x[1] + row[2] * x[2]);
        let [l10, l20, l21] = self.l;
        let y2 = wx[2];
        let y1 = wx[1] - l21 * y2;
        let y0 = wx[0] - l10 * y1 - l20 * y2;
        [y0 as f32, y1 as f32, y2 as f32]
    }
}

/// Numerical rank (0 to 3) of the weighted torque map, from the pivots of `T = G̃1τ G̃1τᵀ` in a
/// Cholesky factorisation with diagonal pivoting: those are the squares of `R`'s diagonal in the
/// column-pivoting QR of `G̃1τᵀ`, so the test is the QR's, `|R_kk| > RANK_TOLERANCE · |R_00|`.
fn torque_rank(packed: &[f64; 6]) -> usize {
    let t = [
        [packed[0], packed[1], packed[2]],
        [packed[1], packed[3], packed[4]],
        [packed[2], packed[4], packed[5]],
    ];
    // First pivot: the largest diagonal entry; `q` and `r` are the other two rows.
    let (p, q, r) = if t[1][1] > t[0][0] {
        if t[2][2] > t[1][1] {
            (2, 0, 1)
        } else {
            (1, 0, 2)
        }
    } else if t[2][2] > t[0][0] {
        (2, 0, 1)
    } else {
        (0, 1, 2)
    };
    let d0 = t[p][p];
    if !(d0 > 0.0) {
        return 0;
    }
    // The Schur complement of the first pivot, then the larger of its diagonal as the second
    // pivot and what remains as the third.
    let (tq, tr) = (t[q][p] / d0, t[r][p] / d0);
    let sqq = t[q][q] - tq * t[q][p];
    let srr = t[r][r] - tr * t[r][p];
    let sqr = t[q][r] - tq * t[r][p];
    let (d1, d2) =
        if srr > sqq { (srr, sqq - sqr * sqr / srr) } else { (sqq, srr - sqr * sqr / sqq) };
    let tolerance = (RANK_TOLERANCE as f64) * (RANK_TOLERANCE as f64) * d0;
    if !(d1 > tolerance) {
        1
    } else if !(d2 > tolerance) {
        2
    } else {
        3
    }
}

/// The error for a dominant eigenvalue that is not clearly positive.
fn no_thrust(eigenvalue: f32) -> ThrustAxisError {
    if eigenvalue.is_finite() {
        ThrustAxisError::NoZeroTorqueThrust
    } else {
        ThrustAxisError::NumericalFailure
    }
}

/// The last resort of [`SolverConfig::clamp_outside_bounds`]: `u*` (either sign) clamped to the
/// bounds, unless every motor at its upper bound gives less than `g` along the axis of the
/// clamped commands (the model says the craft is too weak to hover at all, whatever the
/// torque; a motor that pushes against the axis counts against it). Not generic over the motor count: it runs only when a hover leaves the bounds, so
/// one copy serves every count.
fn clamp_to_bounds(
    problem: &HoverProblem,
    u: &mut [f32],
    eigenvalue: f32,
) -> Result<HoverSolution, ThrustAxisError> {
    // The sign along which the motors push (the larger total command).
    let sign = if u.iter().sum::<f32>() >= 0.0 { 1.0 } else { -1.0 };
    u.iter_mut().for_each(|x| *x *= sign);
    let solution = finish(problem, u, 1.0, eigenvalue, false)?;
    // How far u* was outside, and the force of every motor at its upper bound.
    let mut clamped_by = 0.0f32;
    let mut force_max = [0.0f32; 3];
    for (i, (&x, &clamped)) in u.iter().zip(&solution.u_hover).enumerate() {
        clamped_by = clamped_by.max(libm::fabsf(x - clamped));
        for k in 0..3 {
            force_max[k] += problem.g1_f[k][i] * problem.u_max[i];
        }
    }
    let thrust_max = dot3(force_max, solution.thrust_dir_imu);
    if !(thrust_max >= problem.g_mps2) {
        return Err(ThrustAxisError::NoHoverWithinBounds);
    }
    Ok(HoverSolution { clamped_by, ..solution })
}

/// Step 6 and the final checks: clamp round-off onto the bounds, cost, `d = G1f u`, quaternion.
/// `u` has one entry per motor. Not generic over the motor count, and never inlined: one copy
/// for its three callers in each motor count's solve.
#[inline(never)]
fn finish(
    problem: &HoverProblem,
    u: &[f32],
    sign: f32,
    eigenvalue: f32,
    bounded: bool,
) -> Result<HoverSolution, ThrustAxisError> {
    let mut u_hover = [0.0f32; MOTORS_MAX];
    let mut cost = 0.0;
    let mut d = [0.0f32; 3];
    for i in 0..u.len() {
        let ui = clamp(sign * u[i], problem.u_min[i], problem.u_max[i]);
        u_hover[i] = ui;
        cost += problem.weights[i] * ui * ui;
        for k in 0..3 {
            d[k] += problem.g1_f[k][i] * ui;
        }
    }
    let d_norm = norm3(d);
    if !(positive_finite(d_norm) && cost <= f32::MAX) {
        return Err(ThrustAxisError::NumericalFailure);
    }
    let inv = 1.0 / d_norm;
    let thrust_dir_imu = [d[0] * inv, d[1] * inv, d[2] * inv];
    Ok(HoverSolution {
        motors: problem.motors,
        u_hover,
        thrust_dir_imu,
        q_thrust_to_imu: shortest_arc_from_down_unit(thrust_dir_imu),
        eigenvalue,
        bounded,
        clamped_by: 0.0,
        cost,
    })
}

/// Power iteration on the symmetric positive semi-definite 3 × 3 `c` from `warm` (unit), by
/// repeated squaring; returns a unit vector (the warm vector itself if `c` is zero or invalid).
fn dominant_direction(c: &[[f32; 3]; 3], warm: [f32; 3], max_squarings: u8) -> [f32; 3] {
    // The upper triangle, [00, 01, 02, 11, 12, 22]: the matrix and its squares are symmetric.
    let trace = c[0][0] + c[1][1] + c[2][2];
    if !(positive_finite(trace)) {
        return warm;
    }
    // The warm vector already converged (the usual case from one call to the next): with
    // ρ = wᵀ C w ≤ λ₁ and so λ₂ ≤ tr − ρ, its angle to the dominant eigenvector is at most
    // ‖C w − ρ w‖ / (2ρ − tr) (the residual bound of Davis and Kahan).
    let cw = mat3_vec(c, warm);
    let rho = dot3(warm, cw);
    let residual = [cw[0] - rho * warm[0], cw[1] - rho * warm[1], cw[2] - rho * warm[2]];
    let gap = (2.0 * rho - trace) * WARM_CONVERGED_RAD;
    if gap > 0.0 && dot3(residual, residual) <= gap * gap {
        return warm;
    }
    let inv = 1.0 / trace;
    let mut p = [c[0][0], c[0][1], c[0][2], c[1][1], c[1][2], c[2][2]].map(|x| x * inv);
    for _ in 0..max_squarings {
        // e₂ = Σ principal 2 × 2 minors; tr(p) = 1 here.
        let e2 = p[0] * p[3] - p[1] * p[1] + p[0] * p[5] - p[2] * p[2] + p[3] * p[5] - p[4] * p[4];
        if e2 <= POWER_CONVERGED {
            break;
        }
        let sq = [
            p[0] * p[0] + p[1] * p[1] + p[2] * p[2],
            p[0] * p[1] + p[1] * p[3] + p[2] * p[4],
            p[0] * p[2] + p[1] * p[4] + p[2] * p[5],
            p[1] * p[1] + p[3] * p[3] + p[4] * p[4],
            p[1] * p[2] + p[3] * p[4] + p[4] * p[5],
            p[2] * p[2] + p[4] * p[4] + p[5] * p[5],
        ];
        let t = sq[0] + sq[3] + sq[5];
        if !(t > 0.0) {
            break;
        }
        let inv = 1.0 / t;
        p = sq.map(|x| x * inv);
    }
    let rows = [[p[0], p[1], p[2]], [p[1], p[3], p[4]], [p[2], p[4], p[5]]];
    let mut x = mat3_vec(&rows, warm);
    let dominant = if p[3] > p[0] {
        if p[5] > p[3] {
            2
        } else {
            1
        }
    } else if p[5] > p[0] {
        2
    } else {
        0
    };
    let threshold = POWER_RESEED * rows[dominant][dominant];
    if !(dot3(x, x) >= threshold * threshold) {
        x = rows[dominant];
    }
    let n = norm3(x);
    if !(positive_finite(n)) {
        return warm;
    }
    let inv = 1.0 / n;
    [x[0] * inv, x[1] * inv, x[2] * inv]
}

/// `x > 0` and finite (false for NaN), as two comparisons: written as `x > 0 && x.is_finite()`
/// the compiler merges the two into a class test of the bits, about 30 integer instructions on
/// the Cortex-M7 instead of two `vcmp`.
#[inline(always)]
fn positive_finite(x: f32) -> bool {
    x > 0.0 && x <= f32::MAX
}

/// The sign (`+1` or `−1`) with which `u` fits the bounds, as the paper prescribes; if both
/// fit, the one with the positive command sum (as the published code). Entries within
/// [`BOUND_TOLERANCE`] of a bound count as inside.
fn sign_within_bounds<const M: usize>(problem: &HoverProblem, u: &[f32; M]) -> Option<f32> {
    // Branch-free: the smallest margin to a lower bound and the largest excess over an upper
    // bound, for +u and −u (vminnm/vmaxnm on the Cortex-M7).
    let mut sum = 0.0;
    let (mut low_plus, mut high_plus) = (f32::INFINITY, f32::NEG_INFINITY);
    let (mut low_minus, mut high_minus) = (f32::INFINITY, f32::NEG_INFINITY);
    for i in 0..M {
        let (lower, upper) = (problem.u_min_tolerant[i], problem.u_max_tolerant[i]);
        low_plus = low_plus.min(u[i] - lower);
        high_plus = high_plus.max(u[i] - upper);
        low_minus = low_minus.min(-u[i] - lower);
        high_minus = high_minus.max(-u[i] - upper);
        sum += u[i];
    }
    if !sum.is_finite() {
        return None;
    }
    let positive = low_plus >= 0.0 && high_plus <= 0.0;
    let negative = low_minus >= 0.0 && high_minus <= 0.0;
    match (positive, negative) {
        (true, true) => Some(if sum >= 0.0 { 1.0 } else { -1.0 }),
        (true, false) => Some(1.0),
        (false, true) => Some(-1.0),
        (false, false) => None,
    }
}

fn mat3_vec(a: &[[f32; 3]; 3], x: [f32; 3]) -> [f32; 3] {
    [dot3(a[0], x), dot3(a[1], x), dot3(a[2], x)]
}

fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm3(a: [f32; 3]) -> f32 {
    sqrt(dot3(a, a))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Angle between the lines through `a` and `b` (eigenvectors have no sign), from the cross
    /// product, which is well conditioned near zero.
    fn angle_rad(a: [f32; 3], b: [f32; 3]) -> f32 {
        let cross =
            [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
        libm::atan2f(norm3(cross), dot3(a, b).abs())
    }

    #[test]
    fn power_iteration_reseeds_when_the_warm_vector_is_orthogonal() {
        // C = diag(1, 4, 2): dominant eigenvector e_y; the warm vector e_x is an eigenvector
        // itself (‖C w‖ collapses relative to C_yy after squaring), so it must be re-seeded.
        let c = [[1.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 2.0]];
        let w = dominant_direction(&c, [1.0, 0.0, 0.0], 6);
        assert!(angle_rad(w, [0.0, 1.0, 0.0]) < 1e-5, "{w:?}");
    }

    #[test]
    fn power_iteration_converges_from_a_poor_warm_start_with_close_eigenvalues() {
        // Eigenvalues 1.0, 0.9, 0.1 in a rotated basis; 64 power steps give (0.9)^64 ≈ 1e-3.
        let v = [[0.6f32, 0.8, 0.0], [-0.8, 0.6, 0.0], [0.0, 0.0, 1.0]];
        let lambda = [1.0f32, 0.9, 0.1];
        let mut c = [[0.0f32; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] = (0..3).map(|k| v[k][i] * lambda[k] * v[k][j]).sum();
            }
        }
        let mut w = [0.0, 0.0, 1.0];
        for _ in 0..3 {
            w = dominant_direction(&c, w, 6);
        }
        assert!(angle_rad(w, v[0]) < 1e-5, "{w:?}");
    }

    /// A random airframe of `m` rotors: tilted thrust columns about −z, torques of both signs,
    /// bounds `[lower, 1]` and weights 0.5–2 (so the weight scaling runs).
    fn random_problem(rng: &mut crate::rng::Rng, m: usize) -> HoverProblem {
        let mut f = [[0.0f32; MOTORS_MAX]; 3];
        let mut tau = [[0.0f32; MOTORS_MAX]; 3];
        for i in 0..m {
            let strength = rng.range(8.0, 12.0) as f32;
            f[0][i] = strength * rng.range(-0.3, 0.3) as f32;
            f[1][i] = strength * rng.range(-0.3, 0.3) as f32;
            f[2][i] = -strength;
            for row in tau.iter_mut() {
                row[i] = rng.range(-60.0, 60.0) as f32;
            }
        }
        let mut lower = [0.0f32; MOTORS_MAX];
        let mut weights = [0.0f32; MOTORS_MAX];
        for i in 0..m {
            lower[i] = rng.range(-0.2, 0.05) as f32;
            weights[i] = rng.range(0.5, 2.0) as f32;
        }
        HoverProblem::new(
            [&f[0][..m], &f[1][..m], &f[2][..m]],
            [&tau[0][..m], &tau[1][..m], &tau[2][..m]],
        )
        .and_then(|p| p.with_bounds(&lower[..m], &[1.0; MOTORS_MAX][..m]))
        .and_then(|p| p.with_weights(&weights[..m]))
        .expect("a valid random problem")
    }

    #[test]
    fn five_to_seven_motors_on_zero_columns_give_exactly_their_own_solution() {
        // `solve` runs 5 to 7 motors through the eight-motor body; the body compiled for their
        // own count must give the same bits (solution or error), warm direction included.
        let mut rng = crate::rng::Rng::new(0x7e57_0a11);
        let mut solved = 0;
        for case in 0..300 {
            let m = 5 + case % 3;
            let problem = random_problem(&mut rng, m);
            let config =
                SolverConfig { max_squarings: 6, bounded_search: false, ..SolverConfig::default() };
            let (mut padded, mut own) =
                (ThrustAxisSolver::new(config), ThrustAxisSolver::new(config));
            let by_padding = padded.solve(&problem);
            let by_own_count = match m {
                5 => own.solve_fixed::<5>(&problem),
                6 => own.solve_fixed::<6>(&problem),
                _ => own.solve_fixed::<7>(&problem),
            };
            assert_eq!(by_padding, by_own_count, "case {case}, m = {m}");
            assert_eq!(padded.warm_direction(), own.warm_direction(), "case {case}, m = {m}");
            if let Ok(solution) = by_padding {
                assert_eq!(solution.u_hover().len(), m);
                solved += 1;
            }
        }
        // Most random airframes hover within their bounds: the comparison covered solutions,
        // not only refusals.
        assert!(solved > 100, "only {solved} of 300 solved");
    }

    #[test]
    fn zero_or_invalid_matrix_keeps_the_warm_vector() {
        let warm = [0.0, 0.6, -0.8];
        assert_eq!(dominant_direction(&[[0.0; 3]; 3], warm, 6), warm);
        assert_eq!(dominant_direction(&[[f32::NAN; 3]; 3], warm, 6), warm);
    }
}
