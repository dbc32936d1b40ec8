//! Shared by the thrust-axis tests and benchmarks: random airframes from physics, and two
//! independent f64 references for problem (6) of the seed paper.
//!
//! - [`dense_unbounded`]: the paper's heuristic done densely and differently from the solver:
//!   null space from a symmetric eigen-decomposition of `G1τᵀG1τ` (not a QR), and the weights
//!   handled as the generalised eigenproblem `A η = λ H η` through a Cholesky factor of
//!   `H = NᵀWN` (not by scaling the columns).
//! - [`sampled_bounded`]: a general constrained optimiser for the bounded problem: dense
//!   sampling of the feasible manifold `{ η : ‖G1f N η‖ = g }` by rays, then random-direction
//!   pattern search from the best feasible samples.
// Each test or bench crate uses a subset; index loops mirror the matrix notation.
#![allow(dead_code, clippy::needless_range_loop)]

use nalgebra::{DMatrix, DVector};

pub use flight::rng::Rng;

/// Rotation matrix of a unit quaternion `[w, x, y, z]` (Hamilton).
pub fn rotation_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// Kinds of random airframe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// Rotor axes within a few degrees of body −z (quad/hexa/octo of the usual kind).
    Planar,
    /// Rotor axes tilted up to 40° in random directions (fully actuated hexa/octo and worse).
    Tilted,
}

/// An airframe's effectiveness in IMU coordinates, f64, plus bounds and weights.
#[derive(Clone, Debug)]
pub struct Airframe {
    pub motors: usize,
    /// Rows of G1f, m/s² per unit command.
    pub g1_f: [Vec<f64>; 3],
    /// Rows of G1τ, rad/s² per unit command.
    pub g1_tau: [Vec<f64>; 3],
    pub u_min: Vec<f64>,
    pub u_max: Vec<f64>,
    pub weights: Vec<f64>,
    pub g_mps2: f64,
}

/// Mass (kg), inertia (kg m², diagonal) and rotor drag-to-thrust ratio (m) of the random frames:
/// a 1 kg class multirotor.
const MASS_KG: f64 = 1.0;
const INERTIA_KGM2: [f64; 3] = [0.010, 0.012, 0.020];
const DRAG_TO_THRUST_M: f64 = 0.015;

/// A random airframe: `motors` rotors around the centre of gravity at random radius, azimuth
/// jitter, height, spin, tilt and strength, seen from an IMU with a random orientation.
pub fn random_airframe(rng: &mut Rng, motors: usize, kind: Kind) -> Airframe {
    let q_imu_body = rng.unit_quaternion();
    let r = rotation_matrix(q_imu_body);
    let g = 9.81;
    let mut g1_f = [vec![0.0; motors], vec![0.0; motors], vec![0.0; motors]];
    let mut g1_tau = [vec![0.0; motors], vec![0.0; motors], vec![0.0; motors]];
    for i in 0..motors {
        let azimuth =
            2.0 * std::f64::consts::PI * (i as f64 + rng.range(-0.2, 0.2)) / motors as f64;
        let radius = rng.range(0.08, 0.3);
        let position = [radius * azimuth.cos(), radius * azimuth.sin(), rng.range(-0.03, 0.03)];
        let max_tilt = match kind {
            Kind::Planar => 3f64.to_radians(),
            Kind::Tilted => 40f64.to_radians(),
        };
        let tilt = rng.range(0.0, max_tilt);
        let tilt_azimuth = rng.range(0.0, 2.0 * std::f64::consts::PI);
        let axis = [tilt.sin() * tilt_azimuth.cos(), tilt.sin() * tilt_azimuth.sin(), -tilt.cos()];
        // Strength: specific force per unit command, 0.6–1.4 of "hover at 40 % with m motors".
        let strength = rng.range(0.6, 1.4) * g / (0.4 * motors as f64);
        let spin =
            if i % 2 == 0 { 1.0 } else { -1.0 } * if rng.uniform() < 0.1 { -1.0 } else { 1.0 };
        let force = [strength * axis[0], strength * axis[1], strength * axis[2]];
        let force_n = force.map(|f| f * MASS_KG);
        let moment = [
            position[1] * force_n[2] - position[2] * force_n[1]
                + spin * DRAG_TO_THRUST_M * force_n[0],
            position[2] * force_n[0] - position[0] * force_n[2]
                + spin * DRAG_TO_THRUST_M * force_n[1],
            position[0] * force_n[1] - position[1] * force_n[0]
                + spin * DRAG_TO_THRUST_M * force_n[2],
        ];
        let angular =
            [moment[0] / INERTIA_KGM2[0], moment[1] / INERTIA_KGM2[1], moment[2] / INERTIA_KGM2[2]];
        for row in 0..3 {
            g1_f[row][i] = (0..3).map(|k| r[row][k] * force[k]).sum();
            g1_tau[row][i] = (0..3).map(|k| r[row][k] * angular[k]).sum();
        }
    }
    Airframe {
        motors,
        g1_f,
        g1_tau,
        u_min: vec![0.0; motors],
        u_max: vec![1.0; motors],
        weights: vec![1.0; motors],
        g_mps2: g,
    }
}

impl Airframe {
    pub fn g1_f_matrix(&self) -> DMatrix<f64> {
        DMatrix::from_fn(3, self.motors, |i, j| self.g1_f[i][j])
    }

    pub fn g1_tau_matrix(&self) -> DMatrix<f64> {
        DMatrix::from_fn(3, self.motors, |i, j| self.g1_tau[i][j])
    }

    /// The f32 problem for the solver under test.
    pub fn problem(
        &self,
    ) -> Result<flight::thrust_axis::HoverProblem, flight::thrust_axis::ThrustAxisError> {
        let f32s = |v: &Vec<f64>| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        let (f, t) = (self.g1_f.clone().map(|r| f32s(&r)), self.g1_tau.clone().map(|r| f32s(&r)));
        flight::thrust_axis::HoverProblem::new([&f[0], &f[1], &f[2]], [&t[0], &t[1], &t[2]])?
            .with_bounds(&f32s(&self.u_min), &f32s(&self.u_max))?
            .with_weights(&f32s(&self.weights))?
            .with_gravity(self.g_mps2 as f32)
    }

    /// Cost `uᵀ W u`.
    pub fn cost(&self, u: &[f64]) -> f64 {
        u.iter().zip(&self.weights).map(|(x, w)| w * x * x).sum()
    }

    /// `(‖G1f u‖, ‖G1τ u‖)`.
    pub fn force_torque(&self, u: &[f64]) -> (f64, f64) {
        let u = DVector::from_column_slice(u);
        ((self.g1_f_matrix() * &u).norm(), (self.g1_tau_matrix() * &u).norm())
    }

    pub fn within_bounds(&self, u: &[f64], tolerance: f64) -> bool {
        u.iter()
            .enumerate()
            .all(|(i, &x)| x >= self.u_min[i] - tolerance && x <= self.u_max[i] + tolerance)
    }

    /// Orthonormal null-space basis of G1τ (m × (m−3)) from the eigenvectors of G1τᵀG1τ with the
    /// m − 3 smallest eigenvalues; `None` if G1τ is not of rank 3.
    pub fn null_space(&self) -> Option<DMatrix<f64>> {
        let t = self.g1_tau_matrix();
        let eigen = (t.transpose() * &t).symmetric_eigen();
        let mut order: Vec<usize> = (0..self.motors).collect();
        order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
        let largest = eigen.eigenvalues[order[self.motors - 1]];
        if eigen.eigenvalues[order[self.motors - 3]] <= 1e-10 * largest {
            return None;
        }
        Some(DMatrix::from_fn(self.motors, self.motors - 3, |i, j| {
            eigen.eigenvectors[(i, order[j])]
        }))
    }
}

/// The dense reference for the paper's heuristic (no bounds).
#[derive(Clone, Debug)]
pub struct DenseSolution {
    /// `u*` with the sign chosen as the solver does (`None` when neither sign fits the bounds).
    pub u: Option<Vec<f64>>,
    /// `+N η` before the sign choice.
    pub u_unsigned: Vec<f64>,
    /// Generalised eigenvalues of `A η = λ H η`, descending.
    pub eigenvalues: Vec<f64>,
}

/// Dense f64 reference for the unbounded problem; `None` if G1τ is rank-deficient.
pub fn dense_unbounded(frame: &Airframe) -> Option<DenseSolution> {
    let n = frame.null_space()?;
    let b = frame.g1_f_matrix() * &n;
    let a = b.transpose() * &b;
    let w = DMatrix::from_diagonal(&DVector::from_column_slice(&frame.weights));
    let h = n.transpose() * w * &n;
    let l = h.clone().cholesky()?.l();
    let l_inv = l.clone().try_inverse()?;
    let symmetric = &l_inv * &a * l_inv.transpose();
    let symmetric = (&symmetric + symmetric.transpose()) * 0.5;
    let eigen = symmetric.symmetric_eigen();
    let mut order: Vec<usize> = (0..eigen.eigenvalues.len()).collect();
    order.sort_by(|&x, &y| eigen.eigenvalues[y].total_cmp(&eigen.eigenvalues[x]));
    let zeta = eigen.eigenvectors.column(order[0]).into_owned();
    let eta = l_inv.transpose() * zeta;
    let eta = &eta * (frame.g_mps2 / (eta.transpose() * &a * &eta)[(0, 0)].sqrt());
    let u_unsigned: Vec<f64> = (&n * eta).iter().copied().collect();
    let negative: Vec<f64> = u_unsigned.iter().map(|x| -x).collect();
    let tolerance = 1e-6;
    let u = match (
        frame.within_bounds(&u_unsigned, tolerance),
        frame.within_bounds(&negative, tolerance),
    ) {
        (true, true) if u_unsigned.iter().sum::<f64>() >= 0.0 => Some(u_unsigned.clone()),
        (true, true) | (false, true) => Some(negative),
        (true, false) => Some(u_unsigned.clone()),
        (false, false) => None,
    };
    Some(DenseSolution {
        u,
        u_unsigned,
        eigenvalues: order.iter().map(|&i| eigen.eigenvalues[i]).collect(),
    })
}

/// Angle between two 3-vectors, degrees.
pub fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let cross = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let sin = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
    sin.atan2(dot).to_degrees()
}

/// Direction of `G1f u` (unit).
pub fn thrust_dir(frame: &Airframe, u: &[f64]) -> [f64; 3] {
    let d = frame.g1_f_matrix() * DVector::from_column_slice(u);
    let n = d.norm();
    [d[0] / n, d[1] / n, d[2] / n]
}

/// The best feasible point found by the sampling optimiser, with its cost.
#[derive(Clone, Debug)]
pub struct SampledSolution {
    pub u: Vec<f64>,
    pub cost: f64,
}

/// General constrained optimiser for problem (6) with bounds (f64, no structure beyond the
/// torque null space): every point of `{‖G1f u‖ = g, G1τ u = 0}` is `u = N s g/‖G1f N s‖` for a
/// unit `s`, so sample `s` densely (`samples` random directions, plus ± the coordinate axes),
/// keep the feasible ones (bounds within `1e-9`), and refine the best few by a pattern search
/// along random directions with a shrinking step.
pub fn sampled_bounded(frame: &Airframe, rng: &mut Rng, samples: usize) -> Option<SampledSolution> {
    let n = frame.null_space()?;
    let k = n.ncols();
    let b = frame.g1_f_matrix() * &n;
    let evaluate = |s: &DVector<f64>| -> Option<(f64, Vec<f64>)> {
        let force = (&b * s).norm();
        if force <= 1e-12 * s.norm() {
            return None;
        }
        let u: Vec<f64> = (&n * s * (frame.g_mps2 / force)).iter().copied().collect();
        frame.within_bounds(&u, 1e-9).then(|| (frame.cost(&u), u))
    };
    let mut feasible: Vec<(f64, DVector<f64>)> = Vec::new();
    let consider = |s: DVector<f64>, feasible: &mut Vec<(f64, DVector<f64>)>| {
        if let Some((cost, _)) = evaluate(&s) {
            feasible.push((cost, s));
        }
    };
    for axis in 0..k {
        for sign in [1.0, -1.0] {
            let mut s = DVector::zeros(k);
            s[axis] = sign;
            consider(s, &mut feasible);
        }
    }
    for _ in 0..samples {
        let s = DVector::from_fn(k, |_, _| rng.normal());
        consider(s.normalize(), &mut feasible);
    }
    if feasible.is_empty() {
        return None;
    }
    feasible.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut best: Option<SampledSolution> = None;
    for (start_cost, start) in feasible.iter().take(6) {
        let (mut cost, mut s) = (*start_cost, start.clone());
        let mut step = 0.1;
        while step > 1e-10 {
            let mut improved = false;
            for _ in 0..(8 * k) {
                let direction = DVector::from_fn(k, |_, _| rng.normal()).normalize();
                let candidate = (&s + direction * step).normalize();
                if let Some((c, _)) = evaluate(&candidate) {
                    if c < cost {
                        cost = c;
                        s = candidate;
                        improved = true;
                    }
                }
            }
            if !improved {
                step *= 0.5;
            }
        }
        let (cost, u) = evaluate(&s).expect("refinement keeps feasibility");
        if best.as_ref().is_none_or(|b| cost < b.cost) {
            best = Some(SampledSolution { u, cost });
        }
    }
    best
}
