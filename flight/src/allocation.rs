//! Control allocation: weighted least squares with bounds, solved by a warm-started active-set
//! method with a bounded number of iterations per call (algorithms.md §6).
//!
//! ```text
//! minimise ‖W_v (G du − dv)‖² + γ² ‖W_u (du − du_pref)‖²   subject to  du_min ≤ du ≤ du_max
//! ```
//!
//! G is 6 × m (specific force then angular acceleration per unit thrust), `du` the thrust
//! increments. The weights say what to give up first when the motors cannot do everything:
//! published `W_v = (1, 1, 50, 50, 50, 5)` keeps thrust, roll and pitch and lets horizontal force
//! and yaw go. The secondary term only breaks ties (a quad has no spare freedom; a hexarotor or
//! octorotor has 2–4): γ² is relative to G's scale (`γ² = γ²_rel · trace(GᵀW_v²G)/m`), so it
//! means the same on every airframe.
//!
//! **Method** (the primal active-set method for bounded least squares, as in Härkegård's WLS
//! allocator): with `H = GᵀW_v²G + γ²W_u²` and `c = GᵀW_v²dv + γ²W_u²du_pref` the problem is
//! `min ½ duᵀH du − cᵀdu` in a box. Each iteration solves the free variables by Cholesky with the
//! bounded ones fixed; a step that leaves the box stops at the first bound and fixes that
//! variable; a feasible step checks the multipliers of the fixed ones and frees the one pulling
//! hardest inward, or stops: optimal. The working set and the solution carry over between calls
//! (the next 2 kHz step asks nearly the same), so one or two iterations usually suffice.
//!
//! **Cost** per call for m motors: forming H and c, about 6m² + 6m multiply-adds (96 + 24 for a
//! quad, 384 + 48 for an octorotor); per iteration one Cholesky of at most m × m (m³/6) and two
//! triangular solves, plus O(m²) for the multipliers.
//!
//! Never allocates, never panics, never returns a non-finite increment: non-finite or
//! inconsistent input is refused with [`AllocationStatus::Failed`] and the warm start is left as
//! it was; the increment returned then is zero clamped into the bounds (or zero).

// Index loops over motors and rows mirror the matrix algebra they implement (several arrays
// indexed together), and `!(x > 0)` is deliberate: it also rejects NaN.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

use crate::learner::{MAX_MOTORS, MIN_MOTORS};

/// Published weights of the virtual controls: fx, fy, fz, roll, pitch, yaw.
pub const DEFAULT_WV: [f32; 6] = [1.0, 1.0, 50.0, 50.0, 50.0, 5.0];

/// Default γ² relative to the control objective's scale: ties broken, the objective moved by
/// about 1e-4 of its scale at most (and H stays well conditioned in f32).
pub const DEFAULT_GAMMA2_RELATIVE: f32 = 1e-4;

/// Default iteration budget per call: enough to go from any working set to the optimum of a
/// quad (every variable changes status at most once), a few steps for an octorotor whose warm
/// start is close.
pub const DEFAULT_MAX_ITERATIONS: u8 = 10;

/// How the allocation is weighted and bounded in time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AllocationConfig {
    /// Weights of the six virtual controls.
    pub wv: [f32; 6],
    /// Weights of the motors in the secondary objective.
    pub wu: [f32; MAX_MOTORS],
    /// γ² relative to `trace(GᵀW_v²G)/m`.
    pub gamma2_relative: f32,
    /// Iterations per call at most.
    pub max_iterations: u8,
}

impl Default for AllocationConfig {
    fn default() -> Self {
        Self {
            wv: DEFAULT_WV,
            wu: [1.0; MAX_MOTORS],
            gamma2_relative: DEFAULT_GAMMA2_RELATIVE,
            max_iterations: DEFAULT_MAX_ITERATIONS,
        }
    }
}

/// Why an allocator could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AllocationError {
    /// The motor count is outside 4..=8.
    MotorCount { motors: usize },
    /// A weight is negative or not finite, or γ² is not positive.
    Weights,
}

/// Why a call failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AllocationFailure {
    /// G, dv, the bounds or the preference held a non-finite value.
    NonFinite,
    /// A lower bound above its upper bound.
    Bounds,
    /// The free system was not positive definite (cannot happen with γ² > 0 unless G is
    /// enormous).
    Singular,
}

/// How a call ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AllocationStatus {
    /// The optimum.
    Optimal,
    /// Feasible, but the budget ended before optimality was confirmed.
    IterationLimit,
    /// Refused; the increment is the safe fallback.
    Failed(AllocationFailure),
}

/// A call's result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AllocationResult {
    /// The thrust increments (zero beyond the motor count).
    pub du: [f32; MAX_MOTORS],
    pub status: AllocationStatus,
    /// Iterations used.
    pub iterations: u8,
}

/// Where a variable stands in the working set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bound {
    Free,
    Lower,
    Upper,
}

/// The allocator with its warm start.
#[derive(Clone, Debug)]
pub struct Allocator {
    motors: usize,
    config: AllocationConfig,
    du: [f32; MAX_MOTORS],
    working: [Bound; MAX_MOTORS],
}

type Square = [[f32; MAX_MOTORS]; MAX_MOTORS];

impl Allocator {
    /// An allocator for `motors` motors, starting from zero with every variable free.
    pub fn new(motors: usize, config: AllocationConfig) -> Result<Self, AllocationError> {
        if !(MIN_MOTORS..=MAX_MOTORS).contains(&motors) {
            return Err(AllocationError::MotorCount { motors });
        }
        let weights_ok = config.wv.iter().chain(&config.wu).all(|w| w.is_finite() && *w >= 0.0)
            && config.gamma2_relative > 0.0
            && config.gamma2_relative.is_finite();
        if !weights_ok {
            return Err(AllocationError::Weights);
        }
        Ok(Self { motors, config, du: [0.0; MAX_MOTORS], working: [Bound::Free; MAX_MOTORS] })
    }

    /// Forget the warm start.
    pub fn reset(&mut self) {
        self.du = [0.0; MAX_MOTORS];
        self.working = [Bound::Free; MAX_MOTORS];
    }

    /// Solve for `du` (see the module docs).
    pub fn solve(
        &mut self,
        g: &[[f32; MAX_MOTORS]; 6],
        dv: &[f32; 6],
        du_min: &[f32; MAX_MOTORS],
        du_max: &[f32; MAX_MOTORS],
        du_pref: &[f32; MAX_MOTORS],
    ) -> AllocationResult {
        let m = self.motors;
        let fallback = |failure| {
            let mut du = [0.0; MAX_MOTORS];
            for j in 0..m {
                if du_min[j] <= du_max[j] && du_min[j].is_finite() && du_max[j].is_finite() {
                    du[j] = 0.0f32.clamp(du_min[j], du_max[j]);
                }
            }
            AllocationResult { du, status: AllocationStatus::Failed(failure), iterations: 0 }
        };
        let finite = g.iter().all(|row| row[..m].iter().all(|x| x.is_finite()))
            && dv.iter().all(|x| x.is_finite())
            && [du_min, du_max, du_pref].iter().all(|v| v[..m].iter().all(|x| x.is_finite()));
        if !finite {
            return fallback(AllocationFailure::NonFinite);
        }
        if (0..m).any(|j| du_min[j] > du_max[j]) {
            return fallback(AllocationFailure::Bounds);
        }

        // H = GᵀW_v²G + γ²W_u², c = GᵀW_v²dv + γ²W_u²du_pref.
        let mut h: Square = [[0.0; MAX_MOTORS]; MAX_MOTORS];
        let mut c = [0.0f32; MAX_MOTORS];
        for (k, row) in g.iter().enumerate() {
            let w2 = self.config.wv[k] * self.config.wv[k];
            for i in 0..m {
                let wi = w2 * row[i];
                c[i] += wi * dv[k];
                for j in i..m {
                    h[i][j] += wi * row[j];
                }
            }
        }
        let trace: f32 = (0..m).map(|i| h[i][i]).sum();
        let gamma2 = self.config.gamma2_relative * (trace / m as f32).max(1e-12);
        for i in 0..m {
            let wu2 = gamma2 * self.config.wu[i] * self.config.wu[i];
            h[i][i] += wu2;
            c[i] += wu2 * du_pref[i];
            for j in 0..i {
                h[i][j] = h[j][i];
            }
        }

        // Warm start, moved into the new box.
        let mut x = self.du;
        let mut working = self.working;
        for j in 0..m {
            match working[j] {
                Bound::Lower => x[j] = du_min[j],
                Bound::Upper => x[j] = du_max[j],
                Bound::Free => x[j] = x[j].clamp(du_min[j], du_max[j]),
            }
        }

        let mut status = AllocationStatus::IterationLimit;
        let mut iterations = 0u8;
        while iterations < self.config.max_iterations {
            iterations += 1;
            let Some(optimum) = free_optimum(&h, &c, &x, &working, m) else {
                return fallback(AllocationFailure::Singular);
            };
            // The largest step towards the free optimum that stays in the box.
            let mut alpha = 1.0f32;
            let mut blocking = None;
            for j in 0..m {
                if working[j] != Bound::Free {
                    continue;
                }
                let step = optimum[j] - x[j];
                if step < 0.0 && optimum[j] < du_min[j] {
                    let a = (du_min[j] - x[j]) / step;
                    if a < alpha {
                        alpha = a;
                        blocking = Some((j, Bound::Lower));
                    }
                } else if step > 0.0 && optimum[j] > du_max[j] {
                    let a = (du_max[j] - x[j]) / step;
                    if a < alpha {
                        alpha = a;
                        blocking = Some((j, Bound::Upper));
                    }
                }
            }
            let alpha = alpha.clamp(0.0, 1.0);
            for j in 0..m {
                if working[j] == Bound::Free {
                    x[j] += alpha * (optimum[j] - x[j]);
                }
            }
            if let Some((j, bound)) = blocking {
                working[j] = bound;
                x[j] = if bound == Bound::Lower { du_min[j] } else { du_max[j] };
                continue;
            }
            // Feasible: the multipliers of the fixed variables. The gradient of ½xᵀHx − cᵀx is
            // Hx − c; at a lower bound it must be ≥ 0, at an upper bound ≤ 0.
            let mut worst = (0.0f32, None);
            for j in 0..m {
                let gradient: f32 = (0..m).map(|i| h[j][i] * x[i]).sum::<f32>() - c[j];
                let pull = match working[j] {
                    Bound::Free => 0.0,
                    Bound::Lower => gradient,
                    Bound::Upper => -gradient,
                };
                if pull < worst.0 {
                    worst = (pull, Some(j));
                }
            }
            // A small tolerance relative to H's scale keeps rounding from cycling.
            let tolerance = -1e-7 * (trace / m as f32).max(1e-12);
            match worst {
                (pull, Some(j)) if pull < tolerance => working[j] = Bound::Free,
                _ => {
                    status = AllocationStatus::Optimal;
                    break;
                }
            }
        }
        for j in 0..m {
            x[j] = if x[j].is_finite() {
                x[j].clamp(du_min[j], du_max[j])
            } else {
                0.0f32.clamp(du_min[j], du_max[j])
            };
        }
        self.du = x;
        self.working = working;
        AllocationResult { du: x, status, iterations }
    }
}

/// The minimiser over the free variables with the fixed ones held at `x`: solve
/// `H_FF x_F = c_F − H_FB x_B` by Cholesky. `None` if `H_FF` is not positive definite.
fn free_optimum(
    h: &Square,
    c: &[f32; MAX_MOTORS],
    x: &[f32; MAX_MOTORS],
    working: &[Bound; MAX_MOTORS],
    m: usize,
) -> Option<[f32; MAX_MOTORS]> {
    let mut index = [0usize; MAX_MOTORS];
    let mut n = 0;
    for j in 0..m {
        if working[j] == Bound::Free {
            index[n] = j;
            n += 1;
        }
    }
    let mut result = *x;
    if n == 0 {
        return Some(result);
    }
    let mut l: Square = [[0.0; MAX_MOTORS]; MAX_MOTORS];
    let mut rhs = [0.0f32; MAX_MOTORS];
    for a in 0..n {
        let i = index[a];
        rhs[a] = c[i]
            - (0..m).filter(|&j| working[j] != Bound::Free).map(|j| h[i][j] * x[j]).sum::<f32>();
        for b in 0..n {
            l[a][b] = h[i][index[b]];
        }
    }
    // In-place Cholesky: lower triangle of l.
    for a in 0..n {
        for b in 0..=a {
            let mut sum = l[a][b];
            for k in 0..b {
                sum -= l[a][k] * l[b][k];
            }
            if a == b {
                if !(sum > 0.0) {
                    return None;
                }
                l[a][a] = libm::sqrtf(sum);
            } else {
                l[a][b] = sum / l[b][b];
            }
        }
    }
    // Forward then backward substitution.
    let mut y = [0.0f32; MAX_MOTORS];
    for a in 0..n {
        let sum: f32 = (0..a).map(|k| l[a][k] * y[k]).sum();
        y[a] = (rhs[a] - sum) / l[a][a];
    }
    for a in (0..n).rev() {
        let sum: f32 = (a + 1..n).map(|k| l[k][a] * y[k]).sum();
        y[a] = (y[a] - sum) / l[a][a];
    }
    for a in 0..n {
        result[index[a]] = y[a];
    }
    result.iter().all(|v| v.is_finite()).then_some(result)
}

#[cfg(test)]
mod tests {
    //! (1) unconstrained: matches the closed-form weighted least squares; (2) bounded: equals the
    //! brute-force optimum over every active set, on random quads, hexarotors and octorotors;
    //! (3) bounds always hold, bad input is refused and leaves the warm start as it was; (4) warm
    //! start: a repeated problem takes one iteration; (5) saturation sacrifices yaw (weight 5)
    //! before roll and pitch (weight 50).
    extern crate std;
    use super::*;
    use crate::rng::Rng;
    use nalgebra::{DMatrix, DVector};
    use proptest::prelude::*;
    use std::vec;
    use std::vec::Vec;

    /// G per unit thrust of a random airframe: m rotors on a circle (radius 0.1–0.3 m) with
    /// random tilts (≤ 20°), spin directions alternating, thrust 20–40 m/s² per unit, inertia
    /// giving 300–1500 rad/s² per unit of roll torque.
    fn airframe(m: usize, rng: &mut Rng) -> [[f32; MAX_MOTORS]; 6] {
        let mut g = [[0.0f32; MAX_MOTORS]; 6];
        let radius = rng.range(0.1, 0.3);
        for j in 0..m {
            let angle = core::f64::consts::TAU * (j as f64 + 0.5) / m as f64;
            let tilt = rng.range(0.0, 20f64.to_radians());
            let tilt_dir = rng.range(0.0, core::f64::consts::TAU);
            let axis = [tilt.sin() * tilt_dir.cos(), tilt.sin() * tilt_dir.sin(), -tilt.cos()];
            let thrust = rng.range(20.0, 40.0);
            let pos = [radius * angle.cos(), radius * angle.sin(), 0.0];
            let spin = if j % 2 == 0 { 1.0 } else { -1.0 };
            let inertia = rng.range(0.01, 0.03);
            let torque = [
                pos[1] * axis[2] - pos[2] * axis[1],
                pos[2] * axis[0] - pos[0] * axis[2],
                pos[0] * axis[1] - pos[1] * axis[0],
            ];
            for k in 0..3 {
                g[k][j] = (thrust * axis[k]) as f32;
                let drag = spin * 0.015 * axis[k];
                g[3 + k][j] = (thrust * 0.1 * (torque[k] + drag) / inertia / 3.0) as f32;
            }
        }
        g
    }

    fn objective(
        g: &[[f32; MAX_MOTORS]; 6],
        dv: &[f32; 6],
        du: &[f64],
        pref: &[f32; MAX_MOTORS],
        gamma2: f64,
        wv: &[f32; 6],
    ) -> f64 {
        let m = du.len();
        let mut total = 0.0;
        for k in 0..6 {
            let r: f64 = (0..m).map(|j| f64::from(g[k][j]) * du[j]).sum::<f64>() - f64::from(dv[k]);
            total += (f64::from(wv[k]) * r).powi(2);
        }
        total + gamma2 * (0..m).map(|j| (du[j] - f64::from(pref[j])).powi(2)).sum::<f64>()
    }

    fn gamma2_of(g: &[[f32; MAX_MOTORS]; 6], m: usize) -> f64 {
        let trace: f64 = (0..m)
            .map(|j| {
                (0..6).map(|k| (f64::from(DEFAULT_WV[k]) * f64::from(g[k][j])).powi(2)).sum::<f64>()
            })
            .sum();
        f64::from(DEFAULT_GAMMA2_RELATIVE) * trace / m as f64
    }

    /// The exact optimum by enumerating every assignment of free/lower/upper (3^m), f64.
    fn brute_force(
        g: &[[f32; MAX_MOTORS]; 6],
        dv: &[f32; 6],
        lo: &[f32; MAX_MOTORS],
        hi: &[f32; MAX_MOTORS],
        pref: &[f32; MAX_MOTORS],
        m: usize,
    ) -> f64 {
        let gamma2 = gamma2_of(g, m);
        let mut a = DMatrix::<f64>::zeros(6 + m, m);
        let mut b = DVector::<f64>::zeros(6 + m);
        for k in 0..6 {
            for j in 0..m {
                a[(k, j)] = f64::from(DEFAULT_WV[k]) * f64::from(g[k][j]);
            }
            b[k] = f64::from(DEFAULT_WV[k]) * f64::from(dv[k]);
        }
        for j in 0..m {
            a[(6 + j, j)] = gamma2.sqrt();
            b[6 + j] = gamma2.sqrt() * f64::from(pref[j]);
        }
        let mut best = f64::INFINITY;
        for code in 0..3usize.pow(m as u32) {
            let mut state = [0u8; MAX_MOTORS];
            let mut rest = code;
            for s in state.iter_mut().take(m) {
                *s = (rest % 3) as u8;
                rest /= 3;
            }
            let mut x = vec![0.0f64; m];
            let free: Vec<usize> = (0..m).filter(|&j| state[j] == 0).collect();
            for j in 0..m {
                x[j] = match state[j] {
                    1 => f64::from(lo[j]),
                    2 => f64::from(hi[j]),
                    _ => 0.0,
                };
            }
            if !free.is_empty() {
                let fixed_part = &a * DVector::from_vec(x.clone());
                let rhs = &b - fixed_part;
                let af = a.select_columns(&free);
                let Some(sol) =
                    (af.transpose() * &af).cholesky().map(|c| c.solve(&(af.transpose() * rhs)))
                else {
                    continue;
                };
                for (n, &j) in free.iter().enumerate() {
                    x[j] = sol[n];
                }
            }
            if (0..m).all(|j| x[j] >= f64::from(lo[j]) - 1e-9 && x[j] <= f64::from(hi[j]) + 1e-9) {
                best = best.min(objective(g, dv, &x, pref, gamma2, &DEFAULT_WV));
            }
        }
        best
    }

    /// G, dv, lower and upper bounds, preference.
    type Problem =
        ([[f32; MAX_MOTORS]; 6], [f32; 6], [f32; MAX_MOTORS], [f32; MAX_MOTORS], [f32; MAX_MOTORS]);

    fn random_problem(m: usize, seed: u64) -> Problem {
        let mut rng = Rng::new(seed);
        let g = airframe(m, &mut rng);
        let mut lo = [0.0f32; MAX_MOTORS];
        let mut hi = [0.0f32; MAX_MOTORS];
        let mut pref = [0.0f32; MAX_MOTORS];
        for j in 0..m {
            let u0 = rng.range(0.05, 0.95) as f32;
            lo[j] = -u0;
            hi[j] = 1.0 - u0;
            pref[j] = (rng.range(-0.1, 0.1) as f32).clamp(lo[j], hi[j]);
        }
        let scale = rng.range(0.1, 3.0) as f32;
        let dv = [
            0.0,
            0.0,
            scale * rng.range(-15.0, 15.0) as f32,
            scale * rng.range(-200.0, 200.0) as f32,
            scale * rng.range(-200.0, 200.0) as f32,
            scale * rng.range(-50.0, 50.0) as f32,
        ];
        (g, dv, lo, hi, pref)
    }

    #[test]
    fn unconstrained_matches_the_closed_form_weighted_least_squares() {
        let mut rng = Rng::new(3);
        let m = 6;
        let g = airframe(m, &mut rng);
        let dv = [0.0, 0.0, -1.0, 20.0, -10.0, 5.0];
        let wide = [10.0f32; MAX_MOTORS];
        let mut allocator = Allocator::new(m, AllocationConfig::default()).unwrap();
        let result = allocator.solve(&g, &dv, &wide.map(|w| -w), &wide, &[0.0; MAX_MOTORS]);
        assert_eq!(result.status, AllocationStatus::Optimal);
        let gamma2 = gamma2_of(&g, m);
        let mut h = DMatrix::<f64>::zeros(m, m);
        let mut c = DVector::<f64>::zeros(m);
        for k in 0..6 {
            let w2 = f64::from(DEFAULT_WV[k]).powi(2);
            for i in 0..m {
                c[i] += w2 * f64::from(g[k][i]) * f64::from(dv[k]);
                for j in 0..m {
                    h[(i, j)] += w2 * f64::from(g[k][i]) * f64::from(g[k][j]);
                }
            }
        }
        for i in 0..m {
            h[(i, i)] += gamma2;
        }
        let exact = h.cholesky().unwrap().solve(&c);
        for j in 0..m {
            // f32 normal equations: a few parts in 10⁴ of the largest increment.
            assert!(
                (f64::from(result.du[j]) - exact[j]).abs() < 2e-3 * exact.amax(),
                "motor {j}: {} vs {}",
                result.du[j],
                exact[j]
            );
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn bounded_result_is_the_brute_force_optimum(seed in 0u64..1_000_000, m in 4usize..=8) {
            let (g, dv, lo, hi, pref) = random_problem(m, seed);
            let mut allocator = Allocator::new(m, AllocationConfig { max_iterations: 30, ..AllocationConfig::default() }).unwrap();
            let result = allocator.solve(&g, &dv, &lo, &hi, &pref);
            prop_assert_eq!(result.status, AllocationStatus::Optimal);
            for j in 0..m {
                prop_assert!(result.du[j] >= lo[j] && result.du[j] <= hi[j]);
            }
            let du: Vec<f64> = result.du[..m].iter().map(|&x| f64::from(x)).collect();
            let ours = objective(&g, &dv, &du, &pref, gamma2_of(&g, m), &DEFAULT_WV);
            let best = brute_force(&g, &dv, &lo, &hi, &pref, m);
            prop_assert!(ours <= best * (1.0 + 1e-3) + 1e-3, "ours {} best {}", ours, best);
        }
    }

    #[test]
    fn bad_input_is_refused_within_the_bounds_and_leaves_the_warm_start() {
        let (g, dv, lo, hi, pref) = random_problem(4, 11);
        let mut a = Allocator::new(4, AllocationConfig::default()).unwrap();
        let mut b = a.clone();
        let first = a.solve(&g, &dv, &lo, &hi, &pref);
        b.solve(&g, &dv, &lo, &hi, &pref);
        let mut bad = g;
        bad[3][1] = f32::NAN;
        let refused = a.solve(&bad, &dv, &lo, &hi, &pref);
        assert_eq!(refused.status, AllocationStatus::Failed(AllocationFailure::NonFinite));
        assert!(refused.du.iter().all(|x| x.is_finite()));
        for j in 0..4 {
            assert!(refused.du[j] >= lo[j] && refused.du[j] <= hi[j]);
        }
        let mut crossed = lo;
        crossed[0] = hi[0] + 0.1;
        assert_eq!(
            a.solve(&g, &dv, &crossed, &hi, &pref).status,
            AllocationStatus::Failed(AllocationFailure::Bounds)
        );
        assert_eq!(
            a.solve(&g, &[f32::INFINITY; 6], &lo, &hi, &pref).status,
            AllocationStatus::Failed(AllocationFailure::NonFinite)
        );
        // The next valid call gives what it would have without the bad ones.
        assert_eq!(a.solve(&g, &dv, &lo, &hi, &pref), b.solve(&g, &dv, &lo, &hi, &pref));
        assert!(first.du.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn a_repeated_problem_is_solved_in_one_iteration() {
        for seed in 0..50 {
            let (g, dv, lo, hi, pref) = random_problem(8, seed);
            let mut a = Allocator::new(
                8,
                AllocationConfig { max_iterations: 30, ..AllocationConfig::default() },
            )
            .unwrap();
            assert_eq!(a.solve(&g, &dv, &lo, &hi, &pref).status, AllocationStatus::Optimal);
            let again = a.solve(&g, &dv, &lo, &hi, &pref);
            assert_eq!(again.status, AllocationStatus::Optimal);
            assert_eq!(again.iterations, 1, "seed {seed}");
        }
    }

    #[test]
    fn saturation_gives_up_yaw_before_roll_and_pitch() {
        // A flat quad at hover thrust asked for a large roll and an impossible yaw.
        let mut rng = Rng::new(1);
        let g = airframe(4, &mut rng);
        let u0 = 0.4f32;
        let lo = [-u0; MAX_MOTORS];
        let hi = [1.0 - u0; MAX_MOTORS];
        let dv = [0.0, 0.0, 0.0, 3.0, 0.0, 30.0];
        let mut a = Allocator::new(
            4,
            AllocationConfig { max_iterations: 30, ..AllocationConfig::default() },
        )
        .unwrap();
        let result = a.solve(&g, &dv, &lo, &hi, &[0.0; MAX_MOTORS]);
        assert_eq!(result.status, AllocationStatus::Optimal);
        let achieved = |k: usize| (0..4).map(|j| g[k][j] * result.du[j]).sum::<f32>();
        let roll_miss = (achieved(3) - dv[3]).abs() / dv[3];
        let yaw_miss = (achieved(5) - dv[5]).abs() / dv[5];
        assert!(yaw_miss > 0.5, "the yaw demand is impossible: {yaw_miss}");
        assert!(roll_miss < 0.1 * yaw_miss, "roll missed by {roll_miss}, yaw by {yaw_miss}");
    }
}
