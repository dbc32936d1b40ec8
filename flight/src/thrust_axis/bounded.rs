//! The bounded optimum of problem (6) when the paper's heuristic `u*` leaves the motor bounds.
//!
//! In scaled coordinates (cost `‖u‖²`, see the parent module) the problem is
//! `min ‖u‖²  s.t.  ‖G u‖ = g,  T u = 0,  l ≤ u ≤ h` — non-convex because of the sphere-like
//! equality. This module finds its global optimum by **exhaustive active-set enumeration**:
//!
//! 1. The optimum `u*` lies in the relative interior of exactly one face of the box: a set `S`
//!    of motors clamped at a bound (`l` or `h`), the others free and strictly inside. On that
//!    face, `u*` is a *local* minimiser of the face problem with the box dropped (nearby points
//!    of the face stay inside the box), hence a KKT point of it.
//! 2. Face problem. With the clamped motors fixed, the torque constraint `T_F u_F = −T_S c_S` is
//!    solved by the same pivoted QR as the heuristic (minimum-norm particular solution `x₀`
//!    plus null-space coordinates `z`), giving `min ‖z‖² s.t. ‖a + M z‖ = g` with
//!    `a = G_F x₀ + G_S c_S` and `M = G_F N_F` (3 × (free − rank)).
//! 3. KKT points of the face problem. Stationarity gives the force `f = a + M z = (I + μC)⁻¹ a`
//!    with `C = M Mᵀ` (3 × 3) and `‖f‖ = g`. In the eigenbasis of `C` (Jacobi) this is the
//!    secular equation `Σ aᵢ²/(1 + μcᵢ)² = g²`; each term is convex in `μ` between poles, so each
//!    of the at most four intervals holds at most two roots, found by bisection (after locating
//!    the interval's minimum). The "hard case" (`aᵢ ≈ 0`, e.g. every face whose clamped motors
//!    sit at zero) adds `μ = −1/cᵢ` with `fᵢ = ±√(g² − Σ_{j≠i} f_j²)`. For each candidate force
//!    `z = Mᵀ C⁺ (f − a)` (the minimum-norm `z`, which is exactly the KKT `z`).
//! 4. Every candidate is feasible by construction (the free components of `f` are rescaled onto
//!    the sphere); it is kept if the free motors lie within their bounds and the constraints
//!    re-check, and the cheapest over all faces wins.
//!
//! Faces with more than `m − 4` clamped motors are skipped: there the torque constraint leaves
//! at most a point, which meets `‖G u‖ = g` only by coincidence (non-generic data).
//!
//! # Limits
//! - Cost: up to `Σ_{k ≤ m−4} C(m,k) 2ᵏ` faces (1 at m = 4, 73 at m = 6, 1,697 at m = 8), each
//!   a 3-column QR and, unless pruned, a 3 × 3 Jacobi and a few bisections. Faces are visited in
//!   order of the number of clamped motors and pruned by the lower bound
//!   `‖x₀‖² + Σ clamped² + (g − ‖a‖)²/tr(C)`, which skips most of them once a good point is
//!   known. Measured (`docs/benchmarks.md`): about 42,000 Cortex-M7 instructions at m = 6 and
//!   1.1 million at m = 8 (0.43 ms on the host). It runs only when the heuristic fails, and can be disabled
//!   ([`super::SolverConfig::bounded_search`]).
//! - Degenerate inputs: an optimum where the constraint gradient vanishes on its face (LICQ
//!   fails), or where `C` has a repeated eigenvalue in the hard case (a whole circle of
//!   equal-cost KKT points, of which only the eigenbasis points are tried), can be missed; such
//!   data are non-generic (exact symmetries) and the solver then reports the best point it did
//!   find, or no hover.
//! - Components with `|aᵢ|` between [`HARD_CASE_LOW`] and [`HARD_CASE_HIGH`] times `g` are
//!   treated both ways (regular root and hard case) and the cheaper feasible point is kept, which
//!   limits the loss of f32 accuracy near the poles; against an f64 sampling optimiser on 120
//!   random bounded cases the worst relative cost excess was 8e-6 (`flight/tests/thrust_axis.rs`).

use super::householder::PivotedQr3;
use super::{ScaledProblem, BOUND_TOLERANCE, MOTORS_MAX};
use crate::eigen3::symmetric_eigen3;
use crate::math::sqrt;

/// `|aᵢ| ≤ HARD_CASE_LOW · g` is treated as exactly zero in the secular equation (dimensionless;
/// f32 round-off of `a` is about 1e-7 g).
const HARD_CASE_LOW: f32 = 1e-6;
/// `|aᵢ| ≤ HARD_CASE_HIGH · g` also gets hard-case candidates, and a second secular pass without
/// it (dimensionless; covers roots within 1 % of a pole, where f32 loses accuracy).
const HARD_CASE_HIGH: f32 = 1e-2;
/// Eigenvalues of `C` below `ZERO_FORCE · ‖G‖²_F` are zero (that force direction is fixed).
const ZERO_FORCE: f32 = 1e-6;
/// Bisection steps on a unit interval; f32 has a 24-bit mantissa, so 32 reach its resolution.
const BISECTION_STEPS: usize = 32;
/// Relative tolerance of the final constraint re-check of a candidate (`‖Gu‖² = g²`, `Tu = 0`).
const CONSTRAINT_TOLERANCE: f32 = 1e-3;
/// Most KKT candidates per face: two secular passes × 6 roots + 2 hard-case points × 3.
const MAX_CANDIDATES: usize = 18;

/// The global optimum `ũ` of the scaled bounded problem, or `None` when no feasible point exists.
/// `force_scale2 = ‖G̃1f‖²_F` sets the scale of the zero tests.
///
/// Never inlined and marked cold: it is the rare fallback, and inlining it into the solver's
/// hot path costs the heuristic path registers and instructions.
#[cold]
#[inline(never)]
pub(super) fn optimum(s: &ScaledProblem, force_scale2: f32) -> Option<[f32; MOTORS_MAX]> {
    let m = s.motors.min(MOTORS_MAX);
    if m < 4 {
        return None;
    }
    let torque_scale2: f32 =
        s.g1_tau.iter().map(|row| row[..m].iter().map(|x| x * x).sum::<f32>()).sum();
    let mut best = Best { u: [0.0; MOTORS_MAX], cost: f32::INFINITY };
    // Faces in order of the number of clamped motors, so that the cheap optima with few clamped
    // motors are found first and prune the rest. A face: a set of clamped motors (bit mask) and,
    // for each of them, lower or upper bound (`upper_bits`, one bit per clamped motor in order).
    for clamped in 0..=m - 4 {
        // Masks with `clamped` bits set, in increasing order (Gosper's hack).
        let mut mask: u32 = (1 << clamped) - 1;
        while mask < 1 << m {
            for upper_bits in 0u32..(1 << clamped) {
                let mut state = [FREE; MOTORS_MAX];
                let mut clamped_cost = 0.0;
                let mut slot = 0;
                for i in 0..m {
                    if mask & (1 << i) != 0 {
                        let value = if upper_bits & (1 << slot) == 0 {
                            state[i] = LOWER;
                            s.lower[i]
                        } else {
                            state[i] = UPPER;
                            s.upper[i]
                        };
                        clamped_cost += value * value;
                        slot += 1;
                    }
                }
                // The clamped motors alone must not already cost more than the best so far.
                if clamped_cost < best.cost {
                    let face = Face { s, state: &state, force_scale2, torque_scale2 };
                    face.search(m - clamped, clamped_cost, &mut best);
                }
            }
            if mask == 0 {
                break;
            }
            let lowest = mask & mask.wrapping_neg();
            let ripple = mask + lowest;
            mask = ripple | (((mask ^ ripple) >> 2) / lowest);
        }
    }
    best.cost.is_finite().then_some(best.u)
}

/// Face state of a motor: free, clamped at its lower bound, clamped at its upper bound.
const FREE: u8 = 0;
const LOWER: u8 = 1;
const UPPER: u8 = 2;

struct Best {
    u: [f32; MOTORS_MAX],
    cost: f32,
}

struct Face<'a> {
    s: &'a ScaledProblem,
    state: &'a [u8; MOTORS_MAX],
    force_scale2: f32,
    torque_scale2: f32,
}

/// The face problem with `P` free motors, reduced to force space, with what is needed to map a
/// candidate force back to motor commands.
struct Reduced<const P: usize> {
    /// Free motor indices.
    free_index: [usize; P],
    /// The full command with clamped motors at their bounds (free entries filled per candidate).
    fixed_u: [f32; MOTORS_MAX],
    qr: PivotedQr3<P>,
    /// Particular-solution coordinates (first `qr.rank`), in the `Q` basis.
    y: [f32; 3],
    /// Rows of `Qᵀ G_Fᵀ`; entries `rank..P` of row k are row k of `M`.
    g_q: [[f32; P]; 3],
    force: ForceSpace,
    /// Cost of the clamped motors plus `‖x₀‖²`.
    base_cost: f32,
}

/// The face problem in force space: `min ‖z‖² s.t. ‖a + M z‖ = g`, in the eigenbasis of `C = M Mᵀ`.
struct ForceSpace {
    /// Eigenvalues of `C` and eigenvectors (columns).
    c: [f32; 3],
    v: [[f32; 3]; 3],
    /// `a` in the eigenbasis.
    a: [f32; 3],
    /// Which eigen-directions carry no force (`cᵢ ≈ 0`).
    zero: [bool; 3],
}

impl Face<'_> {
    /// Search the face with `free` free motors: one dispatch to a body with fixed sizes.
    fn search(&self, free: usize, clamped_cost: f32, best: &mut Best) {
        match free {
            4 => self.search_fixed::<4>(clamped_cost, best),
            5 => self.search_fixed::<5>(clamped_cost, best),
            6 => self.search_fixed::<6>(clamped_cost, best),
            7 => self.search_fixed::<7>(clamped_cost, best),
            8 => self.search_fixed::<8>(clamped_cost, best),
            _ => {}
        }
    }

    #[inline(always)]
    fn search_fixed<const P: usize>(&self, clamped_cost: f32, best: &mut Best) {
        let Some(reduced) = self.reduce::<P>(clamped_cost, best.cost) else { return };
        let g = self.s.g_mps2;
        let mut candidates = [[0.0f32; 3]; MAX_CANDIDATES];
        let count = reduced.force.candidates(g, &mut candidates);
        for f in candidates.iter().take(count) {
            self.evaluate(&reduced, *f, best);
        }
    }

    /// The face problem in the eigenbasis of `C`; `None` when the face is empty, degenerate, or
    /// provably no cheaper than `best_cost`.
    #[inline(always)]
    fn reduce<const P: usize>(&self, clamped_cost: f32, best_cost: f32) -> Option<Reduced<P>> {
        let s = self.s;
        let m = s.motors.min(MOTORS_MAX);
        let mut free_index = [0usize; P];
        let mut free = 0;
        let mut t_columns = [[0.0f32; P]; 3];
        let mut g_q = [[0.0f32; P]; 3];
        let mut torque_rhs = [0.0f32; 3];
        let mut force_clamped = [0.0f32; 3];
        let mut fixed_u = [0.0f32; MOTORS_MAX];
        for i in 0..m {
            let value = match self.state[i] {
                LOWER => s.lower[i],
                UPPER => s.upper[i],
                _ if free >= P => return None,
                _ => {
                    free_index[free] = i;
                    for k in 0..3 {
                        t_columns[k][free] = s.g1_tau[k][i];
                        g_q[k][free] = s.g1_f[k][i];
                    }
                    free += 1;
                    continue;
                }
            };
            fixed_u[i] = value;
            for k in 0..3 {
                torque_rhs[k] -= s.g1_tau[k][i] * value;
                force_clamped[k] += s.g1_f[k][i] * value;
            }
        }
        let qr = PivotedQr3::factor(t_columns);
        let y = qr.min_norm_coordinates(torque_rhs)?;
        let rank = qr.rank;
        if free != P || P <= rank {
            return None;
        }
        for row in g_q.iter_mut() {
            qr.apply_qt(row);
        }
        let mut a_imu = force_clamped;
        for (k, a_k) in a_imu.iter_mut().enumerate() {
            *a_k += (0..rank).map(|l| g_q[k][l] * y[l]).sum::<f32>();
        }
        let mut c_matrix = [[0.0f32; 3]; 3];
        for i in 0..3 {
            for j in i..3 {
                let dot: f32 = (rank..P).map(|l| g_q[i][l] * g_q[j][l]).sum();
                c_matrix[i][j] = dot;
                c_matrix[j][i] = dot;
            }
        }
        // Lower bound before the eigen-decomposition: ‖M z‖ ≥ |g − ‖a‖| and ‖M z‖² ≤ tr(C) ‖z‖².
        let base_cost = clamped_cost + y[..rank].iter().map(|x| x * x).sum::<f32>();
        let trace = c_matrix[0][0] + c_matrix[1][1] + c_matrix[2][2];
        let shortfall = self.s.g_mps2 - sqrt(a_imu.iter().map(|x| x * x).sum::<f32>());
        if !(base_cost + shortfall * shortfall / trace < best_cost) {
            return None;
        }
        let (c, v) = symmetric_eigen3(c_matrix)?;
        let mut a = [0.0f32; 3];
        let mut zero = [false; 3];
        for i in 0..3 {
            a[i] = v[0][i] * a_imu[0] + v[1][i] * a_imu[1] + v[2][i] * a_imu[2];
            zero[i] = !(c[i] > ZERO_FORCE * self.force_scale2);
        }
        let force = ForceSpace { c, v, a, zero };
        Some(Reduced { free_index, fixed_u, qr, y, g_q, force, base_cost })
    }

    /// Map a candidate force (eigenbasis) to a command, check it, and keep it if cheapest.
    fn evaluate<const P: usize>(&self, r: &Reduced<P>, f: [f32; 3], best: &mut Best) {
        let s = self.s;
        let rank = r.qr.rank;
        let force = &r.force;
        // φ = C⁺ (f − a) in IMU coordinates; z = Mᵀ φ.
        let mut phi = [0.0f32; 3];
        for i in 0..3 {
            if !force.zero[i] {
                let weight = (f[i] - force.a[i]) / force.c[i];
                for (k, phi_k) in phi.iter_mut().enumerate() {
                    *phi_k += force.v[k][i] * weight;
                }
            }
        }
        let mut x = [0.0f32; P];
        x[..rank].copy_from_slice(&r.y[..rank]);
        let mut cost = r.base_cost;
        for (l, slot) in x.iter_mut().enumerate().skip(rank) {
            let z = r.g_q[0][l] * phi[0] + r.g_q[1][l] * phi[1] + r.g_q[2][l] * phi[2];
            *slot = z;
            cost += z * z;
        }
        if !(cost < best.cost) {
            return;
        }
        r.qr.apply_q(&mut x);
        let mut u = r.fixed_u;
        for (j, &i) in r.free_index.iter().enumerate() {
            let tolerance = BOUND_TOLERANCE * (libm::fabsf(s.lower[i]) + libm::fabsf(s.upper[i]));
            if !(x[j] >= s.lower[i] - tolerance && x[j] <= s.upper[i] + tolerance) {
                return;
            }
            u[i] = x[j];
        }
        if self.constraints_hold(&u) {
            best.u = u;
            best.cost = cost;
        }
    }

    /// Re-check `‖G u‖² ≈ g²` and `T u ≈ 0` (defence against round-off in degenerate faces).
    fn constraints_hold(&self, u: &[f32; MOTORS_MAX]) -> bool {
        let s = self.s;
        let m = s.motors;
        let u_norm2: f32 = u[..m].iter().map(|x| x * x).sum();
        let mut force2 = 0.0;
        let mut torque2 = 0.0;
        for k in 0..3 {
            let force: f32 = (0..m).map(|i| s.g1_f[k][i] * u[i]).sum();
            let torque: f32 = (0..m).map(|i| s.g1_tau[k][i] * u[i]).sum();
            force2 += force * force;
            torque2 += torque * torque;
        }
        let g2 = s.g_mps2 * s.g_mps2;
        libm::fabsf(force2 - g2) <= CONSTRAINT_TOLERANCE * g2
            && torque2 <= CONSTRAINT_TOLERANCE * CONSTRAINT_TOLERANCE * self.torque_scale2 * u_norm2
    }
}

impl ForceSpace {
    /// All KKT forces of the face problem (eigenbasis coordinates), written into `out`;
    /// returns how many.
    fn candidates(&self, g: f32, out: &mut [[f32; 3]; MAX_CANDIDATES]) -> usize {
        let mut count = 0;
        let mut push = |f: [f32; 3], out: &mut [[f32; 3]; MAX_CANDIDATES]| {
            if count < MAX_CANDIDATES {
                out[count] = f;
                count += 1;
            }
        };
        // Components with no force are fixed at aᵢ; the rest share the remaining g².
        let fixed2: f32 = (0..3).filter(|&i| self.zero[i]).map(|i| self.a[i] * self.a[i]).sum();
        let remaining2 = g * g - fixed2;
        if !(remaining2 > 0.0) {
            return 0;
        }
        // Secular passes: first with every component above HARD_CASE_LOW, then (if it differs)
        // without those below HARD_CASE_HIGH.
        let mut previous_mask = None;
        for threshold in [HARD_CASE_LOW, HARD_CASE_HIGH] {
            let mut mask = [false; 3];
            for i in 0..3 {
                mask[i] = !self.zero[i] && libm::fabsf(self.a[i]) > threshold * g;
            }
            if previous_mask == Some(mask) {
                continue;
            }
            previous_mask = Some(mask);
            let mut roots = [0.0f32; 6];
            let n = secular_roots(&self.a, &self.c, &mask, remaining2, &mut roots);
            for &mu in roots.iter().take(n) {
                let mut f = [0.0f32; 3];
                for i in 0..3 {
                    f[i] = if self.zero[i] {
                        self.a[i]
                    } else if mask[i] {
                        self.a[i] / (1.0 + mu * self.c[i])
                    } else {
                        0.0
                    };
                }
                if let Some(f) = self.onto_sphere(f, remaining2) {
                    push(f, out);
                }
            }
        }
        // Hard case: μ = −1/cᵢ for a component with aᵢ ≈ 0; fᵢ takes up the rest of g².
        for i in 0..3 {
            if self.zero[i] || libm::fabsf(self.a[i]) > HARD_CASE_HIGH * g {
                continue;
            }
            let mut f = [0.0f32; 3];
            let mut used2 = 0.0;
            let mut valid = true;
            for j in 0..3 {
                if j == i || self.zero[j] {
                    f[j] = if self.zero[j] { self.a[j] } else { 0.0 };
                    continue;
                }
                let denominator = 1.0 - self.c[j] / self.c[i];
                if libm::fabsf(self.a[j]) <= HARD_CASE_HIGH * g {
                    f[j] = 0.0;
                } else if libm::fabsf(denominator) > 1e-4 {
                    f[j] = self.a[j] / denominator;
                    used2 += f[j] * f[j];
                } else {
                    valid = false;
                }
            }
            let rest2 = remaining2 - used2;
            if valid && rest2 >= 0.0 {
                let fi = sqrt(rest2);
                f[i] = fi;
                push(f, out);
                f[i] = -fi;
                push(f, out);
            }
        }
        count
    }

    /// Rescale the non-fixed components so that `‖f‖² = g²` exactly (`remaining2` = their share).
    fn onto_sphere(&self, mut f: [f32; 3], remaining2: f32) -> Option<[f32; 3]> {
        let free2: f32 = (0..3).filter(|&i| !self.zero[i]).map(|i| f[i] * f[i]).sum();
        if !(free2 > 0.0 && free2.is_finite()) {
            return None;
        }
        let scale = sqrt(remaining2 / free2);
        for i in 0..3 {
            if !self.zero[i] {
                f[i] *= scale;
            }
        }
        Some(f)
    }
}

/// Real roots of `h(μ) = Σ_{mask} aᵢ²/(1 + μcᵢ)² − target` (all `cᵢ > 0` in the mask).
fn secular_roots(
    a: &[f32; 3],
    c: &[f32; 3],
    mask: &[bool; 3],
    target: f32,
    roots: &mut [f32; 6],
) -> usize {
    let h = |mu: f32| -> f32 {
        let mut sum = -target;
        for i in 0..3 {
            if mask[i] {
                let d = 1.0 + mu * c[i];
                sum += a[i] * a[i] / (d * d);
            }
        }
        sum
    };
    let dh = |mu: f32| -> f32 {
        let mut sum = 0.0;
        for i in 0..3 {
            if mask[i] {
                let d = 1.0 + mu * c[i];
                sum -= 2.0 * a[i] * a[i] * c[i] / (d * d * d);
            }
        }
        sum
    };
    // Poles, ascending.
    let mut poles = [0.0f32; 3];
    let mut n_poles = 0;
    for i in 0..3 {
        if mask[i] {
            poles[n_poles] = -1.0 / c[i];
            n_poles += 1;
        }
    }
    if n_poles == 0 {
        return 0;
    }
    poles[..n_poles].sort_unstable_by(|x, y| x.total_cmp(y));
    let mut count = 0;
    let mut push = |mu: f32, roots: &mut [f32; 6]| {
        if count < roots.len() && mu.is_finite() {
            roots[count] = mu;
            count += 1;
        }
    };
    // Outer intervals: h runs monotonically from +∞ at the pole to −target at infinity.
    let first = poles[0];
    let left = move |s: f32| first - s / (1.0 - s);
    push(left(bisect(|s| h(left(s)) > 0.0)), roots);
    let last = poles[n_poles - 1];
    let right = move |s: f32| last + s / (1.0 - s);
    push(right(bisect(|s| h(right(s)) > 0.0)), roots);
    // Inner intervals: h convex, +∞ at both poles: locate the minimum, then a root on each side.
    for k in 1..n_poles {
        let (low, high) = (poles[k - 1], poles[k]);
        if !(high > low) {
            continue;
        }
        let at = move |s: f32| low + s * (high - low);
        let s_min = bisect(|s| dh(at(s)) < 0.0);
        if h(at(s_min)) > 0.0 {
            continue;
        }
        let s_left = bisect_between(0.0, s_min, |s| h(at(s)) > 0.0);
        let s_right = bisect_between(s_min, 1.0, |s| h(at(s)) <= 0.0);
        push(at(s_left), roots);
        push(at(s_right), roots);
    }
    count
}

/// The boundary in (0, 1) of a predicate that holds left of it.
fn bisect(holds_left: impl Fn(f32) -> bool) -> f32 {
    bisect_between(0.0, 1.0, holds_left)
}

fn bisect_between(mut low: f32, mut high: f32, holds_left: impl Fn(f32) -> bool) -> f32 {
    for _ in 0..BISECTION_STEPS {
        let mid = 0.5 * (low + high);
        if holds_left(mid) {
            low = mid;
        } else {
            high = mid;
        }
    }
    0.5 * (low + high)
}
