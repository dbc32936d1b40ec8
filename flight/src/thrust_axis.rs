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
//! 2. **Null space of G1τ.** Column-pivoting Householder QR of `G̃1τᵀ` (`m × 3`) with the full
//!    `Q` in product form (`householder`); the rank test on `R`'s diagonal rejects airframes
//!    whose torque map is rank-deficient. `N = Q[:, 3..m]`.
//! 3. **Dominant eigen-pair.** The paper iterates on `A = (G̃1f N)ᵀ(G̃1f N)` (`(m−3)²`). We use
//!    `B = G̃1f N` (`3 × (m−3)`, read straight off `Qᵀ G̃1fᵀ`) and iterate on `C = B Bᵀ`, which is
//!    always 3 × 3 and has the same non-zero eigenvalues: if `C w = λ w` then `v = Bᵀw/‖Bᵀw‖` is
//!    the paper's eigenvector of `A`. Two reasons: the cost does not grow with `m`, and the
//!    iterate `w` is the thrust direction itself in IMU coordinates, so the warm start kept in
//!    [`ThrustAxisSolver`] between calls is independent of the null-space basis (which can flip or
//!    rotate from one call to the next when the pivot order changes). The power iteration is
//!    accelerated by repeated squaring (`C ← C²/tr`, so `k` squarings are `2ᵏ` power steps),
//!    stopped when `C` is numerically rank one and capped at [`SolverConfig::max_squarings`];
//!    the warm-start vector is re-seeded from the dominant column when `‖C w‖` collapses. For
//!    m = 4 the null space is a line, `A = ‖b‖²` is 1 × 1 and `w = b/‖b‖` in closed form.
//! 4. **Scaling and sign.** `η = Bᵀw · g/‖C w‖` (the paper's `η = v g/√(vᵀAv)`, which makes
//!    `‖G1f u‖ = g` exact for any `w`), `ũ = ±Q [0; η]`, with the sign that keeps `u` within the
//!    bounds (both fit: the one with positive command sum, as in the published code).
//! 5. **Bounded optimum.** When neither sign fits, the heuristic's answer is not the solution of
//!    problem (6); `bounded` then searches every active set of clamped motors for the true
//!    bounded optimum, and the result is flagged `bounded = true`.
//! 6. **Attitude.** `d = G1f u*`; `q_thrust_to_imu` is the shortest arc taking `(0, 0, −1)` to
//!    `d/|d|` (`rotation`).
//!
//! Everything is `f32`, fixed-size (`[_; MOTORS_MAX]` plus a count) and allocation-free. The
//! solve dispatches once on the motor count to a const-generic body, compiled for the quad and
//! for `MOTORS_MAX` (5 to 7 motors on zero-filled columns, exactly), so every loop has a fixed
//! trip count; square roots are the FPU's `vsqrt.f32` (`math::sqrt`). Cost on the Cortex-M7 (QEMU,
//! `cargo xtask bench-m7`): about 900 instructions at m = 4 and 1,850–2,000 at 5 to 8 motors
//! (heuristic path); see `docs/benchmarks.md`.

// `!(x > limit)` is deliberate throughout: it is also true for NaN, which must take the safe
// branch. Index loops are kept where they mirror the matrix notation of the derivation.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

mod bounded;
mod householder;
mod rotation;

use rotation::shortest_arc_from_down_unit;
pub use rotation::{euler_zyx, rotate, shortest_arc_from_down, EulerZyx, THRUST_DIR_THRUST_FRAME};

use crate::math::{clamp, sqrt};
use householder::PivotedQr3;

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
            4 => self.solve_fixed::<4>(problem),
            5..=MOTORS_MAX => self.solve_fixed::<MOTORS_MAX>(problem),
            motors => Err(ThrustAxisError::MotorCount { motors }),
        }
    }

    /// [`Self::solve`] with the first `M ≥ problem.motors` columns (zero beyond the motors).
    fn solve_fixed<const M: usize>(
        &mut self,
        problem: &HoverProblem,
    ) -> Result<HoverSolution, ThrustAxisError> {
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
        // Rows of Qᵀ G̃1fᵀ; entries 3..M of row k are row k of B = G̃1f N. Qᵀ is orthogonal,
        // so the sum of all squares is ‖G̃1f‖²_F.
        let mut force_scale2 = 0.0;
        for row in b.iter_mut() {
            qr.apply_qt(row);
            for x in row.iter() {
                force_scale2 += x * x;
            }
        }

        // Step 3: C = B Bᵀ and its dominant eigenvector by warm-started power iteration.
        // Step 4: η = Bᵀw g/‖Cw‖, ũ = Q [0; η] (η in entries 3..M).
        let mut u = [0.0f32; M];
        let eigenvalue;
        if M == 4 {
            // One-dimensional null space: A = ‖b‖² is 1 × 1, C = b bᵀ, w = b/‖b‖ exactly and
            // η = g/‖b‖ (the power iteration would converge in one step to the same).
            let column = [b[0][3], b[1][3], b[2][3]];
            eigenvalue = dot3(column, column);
            if !(eigenvalue > ZERO_EIGEN * force_scale2) {
                return Err(no_thrust(eigenvalue));
            }
            let norm = sqrt(eigenvalue);
            let inv = 1.0 / norm;
            self.warm_dir = [column[0] * inv, column[1] * inv, column[2] * inv];
            u[3] = problem.g_mps2 * inv;
        } else {
            let mut c = [[0.0f32; 3]; 3];
            for i in 0..3 {
                for j in i..3 {
                    let mut dot = 0.0;
                    for l in 3..M {
                        dot += b[i][l] * b[j][l];
                    }
                    c[i][j] = dot;
                    c[j][i] = dot;
                }
            }
            let w = dominant_direction(&c, self.warm_dir, self.config.max_squarings);
            let cw = mat3_vec(&c, w);
            eigenvalue = dot3(w, cw);
            if !(eigenvalue > ZERO_EIGEN * force_scale2) {
                return Err(no_thrust(eigenvalue));
            }
            self.warm_dir = w;
            let scale = problem.g_mps2 / norm3(cw);
            for l in 3..M {
                u[l] = (b[0][l] * w[0] + b[1][l] * w[1] + b[2][l] * w[2]) * scale;
            }
        }
        qr.apply_q(&mut u);
        if !problem.unit_weights {
            for i in 0..M {
                u[i] *= problem.inv_sqrt_weight[i];
            }
        }

        // The sign that fits the bounds, else the bounded optimum (step 5).
        match sign_within_bounds(problem, &u) {
            Some(sign) => {
                u.iter_mut().for_each(|x| *x *= sign);
                finish(problem, &u, eigenvalue, false)
            }
            None if BOUNDED_SEARCH_COMPILED && self.config.bounded_search => {
                let scaled = ScaledProblem::new(problem);
                let u_scaled = bounded::optimum(&scaled, force_scale2)
                    .ok_or(ThrustAxisError::NoHoverWithinBounds)?;
                for i in 0..M {
                    u[i] = u_scaled[i] * scaled.inv_sqrt_weight[i];
                }
                finish(problem, &u, eigenvalue, true)
            }
            None if self.config.clamp_outside_bounds => {
                clamp_to_bounds(problem, &mut u, eigenvalue)
            }
            None => Err(ThrustAxisError::NoHoverWithinBounds),
        }
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
    let solution = finish(problem, u, eigenvalue, false)?;
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
    eigenvalue: f32,
    bounded: bool,
) -> Result<HoverSolution, ThrustAxisError> {
    let mut u_hover = [0.0f32; MOTORS_MAX];
    let mut cost = 0.0;
    let mut d = [0.0f32; 3];
    for i in 0..u.len() {
        let ui = clamp(u[i], problem.u_min[i], problem.u_max[i]);
        u_hover[i] = ui;
        cost += problem.weights[i] * ui * ui;
        for k in 0..3 {
            d[k] += problem.g1_f[k][i] * ui;
        }
    }
    let d_norm = norm3(d);
    if !(d_norm > 0.0 && d_norm.is_finite() && cost.is_finite()) {
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
    let mut p = *c;
    let trace = p[0][0] + p[1][1] + p[2][2];
    if !(trace > 0.0 && trace.is_finite()) {
        return warm;
    }
    scale3(&mut p, 1.0 / trace);
    for _ in 0..max_squarings {
        // e₂ = Σ principal 2 × 2 minors; tr(p) = 1 here.
        let e2 = p[0][0] * p[1][1] - p[0][1] * p[0][1] + p[0][0] * p[2][2] - p[0][2] * p[0][2]
            + p[1][1] * p[2][2]
            - p[1][2] * p[1][2];
        if e2 <= POWER_CONVERGED {
            break;
        }
        let mut sq = [[0.0f32; 3]; 3];
        for i in 0..3 {
            for j in i..3 {
                let v = p[i][0] * p[0][j] + p[i][1] * p[1][j] + p[i][2] * p[2][j];
                sq[i][j] = v;
                sq[j][i] = v;
            }
        }
        let t = sq[0][0] + sq[1][1] + sq[2][2];
        if !(t > 0.0) {
            break;
        }
        scale3(&mut sq, 1.0 / t);
        p = sq;
    }
    let mut x = mat3_vec(&p, warm);
    let mut dominant = 0;
    for j in 1..3 {
        if p[j][j] > p[dominant][dominant] {
            dominant = j;
        }
    }
    let threshold = POWER_RESEED * p[dominant][dominant];
    if !(dot3(x, x) >= threshold * threshold) {
        x = [p[0][dominant], p[1][dominant], p[2][dominant]];
    }
    let n = norm3(x);
    if !(n > 0.0 && n.is_finite()) {
        return warm;
    }
    let inv = 1.0 / n;
    [x[0] * inv, x[1] * inv, x[2] * inv]
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

fn scale3(a: &mut [[f32; 3]; 3], factor: f32) {
    a.iter_mut().flatten().for_each(|x| *x *= factor);
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
