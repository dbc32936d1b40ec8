//! Column-pivoting Householder QR of a tall `p × 3` matrix, `p ≤ 8`, with the full `Q` kept in
//! product form (three reflectors), as LAPACK's `xGEQP3` stores it.
//!
//! Used by the quad's solve and by the bounded search (5 to 8 motors use the Gram blocks of the
//! parent module, cheaper there). Why hand-written: they need the *full* `Q` (its last
//! `p − rank` columns are the null space of the torque map), and nalgebra's `ColPivQR::q()`
//! returns only the thin
//! `p × 3` factor. Three reflectors applied to fixed-size arrays are also much cheaper on the
//! Cortex-M7 than nalgebra's generic paths (see `docs/benchmarks.md`).
//!
//! The matrix is given by its three columns, each an `[f32; P]`: for `X = G1τᵀ` those columns are
//! simply the three rows of `G1τ`. The row count `P` is a const parameter so that every loop has
//! a fixed trip count and unrolls without bounds checks (the solver dispatches once on the
//! motor count); callers with a varying row count pad with zero rows, which leaves the
//! factorisation of the non-zero block unchanged (`Q` acts as the identity on zero rows).

use crate::math::sqrt;

/// Relative threshold on `|R_kk| / |R_00|` below which a pivot is treated as zero (rank test).
///
/// Unit: dimensionless. Origin: f32 has a unit round-off of 6e-8; after the QR the diagonal
/// carries errors of a few round-offs times `|R_00|`, so 1e-4 leaves three orders of margin and
/// still flags torque maps that are dependent to within 0.01 % (an airframe that cannot hover in
/// practice).
pub(crate) const RANK_TOLERANCE: f32 = 1e-4;

/// `X Π = Q R` for `X` of size `p × 3`: `Q = H0 H1 H2` (Householder reflectors
/// `Hk = I − beta_k v_k v_kᵀ`, `v_k` zero above row `k`), `R` upper triangular, `Π` a column
/// permutation with `X[:, perm[k]] = (Q R)[:, k]`.
///
/// Storage is in place, as LAPACK's: after the factorisation `cols[j][k]` (`k < j`) holds
/// `R[k][j]`, and `cols[k][k+1..p]` holds the tail of `v_k`, which equals the untouched part of
/// the pivot column (`v_k = x − R_kk e_k` changes only entry `k`, kept in `head[k]`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct PivotedQr3<const P: usize> {
    /// Numerical rank (0 to 3) from the diagonal of `R` and [`RANK_TOLERANCE`].
    pub rank: usize,
    /// The factored columns (see the type docs).
    cols: [[f32; P]; 3],
    /// Entry `k` of `v_k`.
    head: [f32; 3],
    /// Householder scalars `beta_k = 2 / (v_kᵀ v_k)` (0 for an identity reflector).
    beta: [f32; 3],
    /// Diagonal of `R`.
    diag: [f32; 3],
    /// Column permutation: column `k` of `Q R` is column `perm[k]` of `X`.
    perm: [usize; 3],
}

impl<const P: usize> PivotedQr3<P> {
    /// Compile-time check: at least as many rows as columns.
    const TALL: () = assert!(P >= 3, "PivotedQr3 needs at least three rows");

    /// Factor the `P × 3` matrix whose columns are `columns`.
    ///
    /// Always inlined: as a call it returns the factorisation through a stack copy (about 100
    /// instructions of `memcpy` at P = 4 on the Cortex-M7, measured).
    #[inline(always)]
    pub fn factor(columns: [[f32; P]; 3]) -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::TALL;
        let mut qr = PivotedQr3 {
            rank: 0,
            cols: columns,
            head: [0.0; 3],
            beta: [0.0; 3],
            diag: [0.0; 3],
            perm: [0, 1, 2],
        };
        // Three explicit steps so that `k` is a constant in each (full unrolling).
        qr.step(0);
        qr.step(1);
        qr.step(2);
        let r00 = libm::fabsf(qr.diag[0]);
        qr.rank = (0..3)
            .take_while(|&k| r00 > 0.0 && libm::fabsf(qr.diag[k]) > RANK_TOLERANCE * r00)
            .count();
        qr
    }

    /// Householder step `k`: pivot, reflector, update of the remaining columns.
    #[inline(always)]
    fn step(&mut self, k: usize) {
        // Pivot: the remaining column with the largest norm below row k.
        let mut best = k;
        let mut best_norm2 = sum_squares_from(&self.cols[k], k);
        for j in k + 1..3 {
            let norm2 = sum_squares_from(&self.cols[j], k);
            if norm2 > best_norm2 {
                best_norm2 = norm2;
                best = j;
            }
        }
        if best != k {
            self.cols.swap(k, best);
            self.perm.swap(k, best);
        }
        // Reflector taking cols[k][k..] onto R_kk e_k.
        let alpha = sqrt(best_norm2);
        let x0 = self.cols[k][k];
        if alpha > 0.0 && alpha.is_finite() {
            let diagonal = if x0 >= 0.0 { -alpha } else { alpha };
            self.head[k] = x0 - diagonal;
            // vᵀv = 2 α (α + |x0|)
            self.beta[k] = 1.0 / (alpha * (alpha + libm::fabsf(x0)));
            self.diag[k] = diagonal;
            let (done, rest) = self.cols.split_at_mut(k + 1);
            for column in rest.iter_mut() {
                reflect(&done[k], self.head[k], self.beta[k], k, column);
            }
        }
    }

    /// `R[i][k]` for `i ≤ k`.
    fn r(&self, i: usize, k: usize) -> f32 {
        if i == k {
            self.diag[k]
        } else {
            self.cols[k][i]
        }
    }

    /// `x ← Qᵀ x`.
    #[inline(always)]
    pub fn apply_qt(&self, x: &mut [f32; P]) {
        for k in 0..3 {
            reflect(&self.cols[k], self.head[k], self.beta[k], k, x);
        }
    }

    /// `x ← Q x`.
    #[inline(always)]
    pub fn apply_q(&self, x: &mut [f32; P]) {
        for k in (0..3).rev() {
            reflect(&self.cols[k], self.head[k], self.beta[k], k, x);
        }
    }

    /// Coordinates `y[0..rank]` (in the `Q` basis) of the minimum-norm solution of `Xᵀ x = t`,
    /// i.e. `x = Q [y; 0]`; `None` when `t` is not in the range of `Xᵀ` (to a relative tolerance
    /// of [`RANK_TOLERANCE`]).
    ///
    /// Derivation: `Πᵀ Xᵀ = Rᵀ Qᵀ`, so `Xᵀ x = t` reads `Rᵀ (Qᵀ x) = Πᵀ t`, a lower-triangular
    /// system solved by forward substitution over the first `rank` rows; the remaining rows
    /// must then hold by themselves (consistency).
    pub fn min_norm_coordinates(&self, t: [f32; 3]) -> Option<[f32; 3]> {
        let mut y = [0.0f32; 3];
        for k in 0..3 {
            let mut rhs = t[self.perm[k]];
            // Magnitude of the terms summed, for a cancellation-aware consistency test.
            let mut magnitude = libm::fabsf(rhs);
            for (i, yi) in y.iter().enumerate().take(k.min(self.rank)) {
                rhs -= self.r(i, k) * yi;
                magnitude += libm::fabsf(self.r(i, k) * yi);
            }
            if k < self.rank {
                y[k] = rhs / self.diag[k];
            } else if libm::fabsf(rhs) > RANK_TOLERANCE * magnitude.max(f32::MIN_POSITIVE) {
                return None;
            }
        }
        Some(y)
    }
}

/// `x ← (I − beta v vᵀ) x` with `v = (0, …, 0, head, tail[from+1..P])`, `from < 3 ≤ P`.
#[inline(always)]
fn reflect<const P: usize>(tail: &[f32; P], head: f32, beta: f32, from: usize, x: &mut [f32; P]) {
    let mut dot = head * x[from];
    for i in from + 1..P {
        dot += tail[i] * x[i];
    }
    let scale = beta * dot;
    x[from] -= scale * head;
    for i in from + 1..P {
        x[i] -= scale * tail[i];
    }
}

/// `Σ_{i ≥ from} x[i]²`.
#[inline(always)]
fn sum_squares_from<const P: usize>(x: &[f32; P], from: usize) -> f32 {
    let mut sum = 0.0;
    for value in &x[from..] {
        sum += value * value;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    fn columns<const P: usize>(x: &[[f32; 3]; P]) -> [[f32; P]; 3] {
        let mut c = [[0.0; P]; 3];
        for (i, row) in x.iter().enumerate() {
            for j in 0..3 {
                c[j][i] = row[j];
            }
        }
        c
    }

    #[test]
    fn q_is_orthogonal_and_nulls_the_torque_map() {
        let x = [
            [1.0, 2.0, -0.5],
            [0.3, -1.0, 0.7],
            [-2.0, 0.1, 0.2],
            [0.5, 0.5, 1.5],
            [0.0, -0.4, 0.9],
        ];
        let qr = PivotedQr3::factor(columns(&x));
        assert_eq!(qr.rank, 3);
        for j in 3..5 {
            // Null-space column j of Q: Q e_j, orthogonal to every column of X.
            let mut e = [0.0; 5];
            e[j] = 1.0;
            qr.apply_q(&mut e);
            let norm: f32 = e.iter().map(|v| v * v).sum();
            assert!((norm - 1.0).abs() < 1e-5);
            for c in 0..3 {
                let dot: f32 = (0..5).map(|i| x[i][c] * e[i]).sum();
                assert!(dot.abs() < 1e-5, "column {c}: {dot}");
            }
        }
    }

    #[test]
    fn min_norm_solution_solves_the_system() {
        let x = [[1.0, 0.0, 2.0], [0.0, 1.0, 1.0], [1.0, 1.0, 0.0], [2.0, -1.0, 1.0]];
        let qr = PivotedQr3::factor(columns(&x));
        let t = [0.5, -1.0, 2.0];
        let y = qr.min_norm_coordinates(t).expect("full rank");
        let mut sol = [0.0; 4];
        sol[..3].copy_from_slice(&y);
        qr.apply_q(&mut sol);
        for c in 0..3 {
            let value: f32 = (0..4).map(|i| x[i][c] * sol[i]).sum();
            assert!((value - t[c]).abs() < 1e-5);
        }
    }

    #[test]
    fn rank_deficiency_is_detected_and_inconsistency_refused() {
        // Third column = first + second.
        let x = [[1.0, 2.0, 3.0], [0.0, 1.0, 1.0], [4.0, -1.0, 3.0], [1.0, 1.0, 2.0]];
        let qr = PivotedQr3::factor(columns(&x));
        assert_eq!(qr.rank, 2);
        assert!(qr.min_norm_coordinates([1.0, 1.0, 5.0]).is_none());
        assert!(qr.min_norm_coordinates([1.0, 1.0, 2.0]).is_some());
    }
}
