//! Column-pivoting Householder QR of a tall `p × 3` matrix, `p ≤ 8`, with the full `Q` kept in
//! product form (three reflectors), as LAPACK's `xGEQP3` stores it.
//!
//! Why hand-written: the thrust-axis solver needs the *full* `Q` (its last `p − rank` columns are
//! the null space of the torque map), and nalgebra's `ColPivQR::q()` returns only the thin
//! `p × 3` factor. Three reflectors applied to fixed-size arrays are also much cheaper on the
//! Cortex-M7 than nalgebra's generic paths (see `docs/benchmarks.md`).
//!
//! The matrix is given by its three columns, each an `[f32; MOTORS_MAX]` of which the first `p`
//! entries are used: for `X = G1τᵀ` those columns are simply the three rows of `G1τ`.

use super::MOTORS_MAX;

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
#[derive(Clone, Copy, Debug)]
pub(crate) struct PivotedQr3 {
    /// Number of rows `p` (3 ≤ p ≤ 8).
    pub rows: usize,
    /// Numerical rank (0 to 3) from the diagonal of `R` and [`RANK_TOLERANCE`].
    pub rank: usize,
    /// Householder vectors; `v[k][i] = 0` for `i < k`.
    v: [[f32; MOTORS_MAX]; 3],
    /// Householder scalars `beta_k = 2 / (v_kᵀ v_k)` (0 for an identity reflector).
    beta: [f32; 3],
    /// Upper-triangular `R` (row, column).
    r: [[f32; 3]; 3],
    /// Column permutation: column `k` of `Q R` is column `perm[k]` of `X`.
    perm: [usize; 3],
}

impl PivotedQr3 {
    /// Factor the `rows × 3` matrix whose columns are `columns[0..3][0..rows]`.
    ///
    /// `rows` is clamped to `3..=MOTORS_MAX` so that bad callers cannot index out of range.
    pub fn factor(mut columns: [[f32; MOTORS_MAX]; 3], rows: usize) -> Self {
        let rows = rows.clamp(3, MOTORS_MAX);
        let mut qr = PivotedQr3 {
            rows,
            rank: 0,
            v: [[0.0; MOTORS_MAX]; 3],
            beta: [0.0; 3],
            r: [[0.0; 3]; 3],
            perm: [0, 1, 2],
        };
        for k in 0..3 {
            // Pivot: the remaining column with the largest norm below row k.
            let mut best = k;
            let mut best_norm2 = -1.0;
            for (j, column) in columns.iter().enumerate().skip(k) {
                let norm2 = sum_squares(&column[k..rows]);
                if norm2 > best_norm2 {
                    best_norm2 = norm2;
                    best = j;
                }
            }
            columns.swap(k, best);
            qr.perm.swap(k, best);
            qr.r.iter_mut().for_each(|row| row.swap(k, best));

            // Reflector taking columns[k][k..] onto a multiple of e_k.
            let alpha = libm::sqrtf(best_norm2.max(0.0));
            let x0 = columns[k][k];
            if alpha > 0.0 && alpha.is_finite() {
                let diagonal = if x0 >= 0.0 { -alpha } else { alpha };
                let v = &mut qr.v[k];
                v[k] = x0 - diagonal;
                v[k + 1..rows].copy_from_slice(&columns[k][k + 1..rows]);
                // vᵀv = 2 α (α + |x0|)
                qr.beta[k] = 1.0 / (alpha * (alpha + libm::fabsf(x0)));
                qr.r[k][k] = diagonal;
                for j in k + 1..3 {
                    reflect(&qr.v[k], qr.beta[k], k, rows, &mut columns[j]);
                    qr.r[k][j] = columns[j][k];
                }
            } else {
                for j in k + 1..3 {
                    qr.r[k][j] = columns[j][k];
                }
            }
        }
        let r00 = libm::fabsf(qr.r[0][0]);
        qr.rank = (0..3)
            .take_while(|&k| r00 > 0.0 && libm::fabsf(qr.r[k][k]) > RANK_TOLERANCE * r00)
            .count();
        qr
    }

    /// `x ← Qᵀ x` (first `rows` entries).
    pub fn apply_qt(&self, x: &mut [f32; MOTORS_MAX]) {
        for k in 0..3 {
            reflect(&self.v[k], self.beta[k], k, self.rows, x);
        }
    }

    /// `x ← Q x` (first `rows` entries).
    pub fn apply_q(&self, x: &mut [f32; MOTORS_MAX]) {
        for k in (0..3).rev() {
            reflect(&self.v[k], self.beta[k], k, self.rows, x);
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
                rhs -= self.r[i][k] * yi;
                magnitude += libm::fabsf(self.r[i][k] * yi);
            }
            if k < self.rank {
                y[k] = rhs / self.r[k][k];
            } else if libm::fabsf(rhs) > RANK_TOLERANCE * magnitude.max(f32::MIN_POSITIVE) {
                return None;
            }
        }
        Some(y)
    }
}

/// `x ← (I − beta v vᵀ) x` over rows `from..rows` (v is zero above `from`).
#[inline(always)]
fn reflect(v: &[f32; MOTORS_MAX], beta: f32, from: usize, rows: usize, x: &mut [f32; MOTORS_MAX]) {
    let mut dot = 0.0;
    for i in from..rows {
        dot += v[i] * x[i];
    }
    let scale = beta * dot;
    for i in from..rows {
        x[i] -= scale * v[i];
    }
}

fn sum_squares(x: &[f32]) -> f32 {
    x.iter().map(|value| value * value).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn columns(x: &[[f32; 3]]) -> [[f32; MOTORS_MAX]; 3] {
        let mut c = [[0.0; MOTORS_MAX]; 3];
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
        let qr = PivotedQr3::factor(columns(&x), 5);
        assert_eq!(qr.rank, 3);
        for j in 3..5 {
            // Null-space column j of Q: Q e_j, orthogonal to every column of X.
            let mut e = [0.0; MOTORS_MAX];
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
        let qr = PivotedQr3::factor(columns(&x), 4);
        let t = [0.5, -1.0, 2.0];
        let y = qr.min_norm_coordinates(t).expect("full rank");
        let mut sol = [0.0; MOTORS_MAX];
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
        let qr = PivotedQr3::factor(columns(&x), 4);
        assert_eq!(qr.rank, 2);
        assert!(qr.min_norm_coordinates([1.0, 1.0, 5.0]).is_none());
        assert!(qr.min_norm_coordinates([1.0, 1.0, 2.0]).is_some());
    }
}
