//! From accumulated moments to an [`Estimate`]: the 3 × 3 solves for both models, the
//! batch-means covariance, the 95 % ellipsoid and the verdict.
//!
//! With a bias, the 6 × 6 normal equations `[[ΣXᵀX, ΣXᵀ], [ΣX, N I]]` are reduced to 3 × 3 by the
//! Schur complement of the (diagonal) bias block, `S = ΣXᵀX − (ΣX)ᵀ(ΣX)/N`: no 6 × 6 solve is ever
//! needed, and `S` shows directly how much of `XᵀX` is left once constant parts are explained
//! by a bias.
//!
//! With the drag model (`DragModel::VerticalQuadratic`, batch only) the sums are 6 × 6 quadratic
//! forms in `θ = [r; b]` with each throw's drag vector already profiled out (`drag`); the fit
//! solves them directly (`f64`), counting 3 unknowns per throw in every degree-of-freedom figure.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use super::drag::DragSums;
use super::moments::{count_as, BatchMeans, Moments};
#[cfg(doc)]
use super::DragModel;
use super::{Ellipsoid, Estimate, ImuAxis, ImuOffsetError, Model, Scalar, Verdict, CHI2_3DOF_95};

/// Fewest blocks for a fit: the batch-means variance then has at least `3·6 − 6 = 12` degrees of
/// freedom even with a bias (its relative standard error ≈ √(2/12) ≈ 40 %, the worst we accept).
pub(crate) const MIN_BLOCKS: u32 = 6;

/// 95 % quantiles of Fisher's F distribution with (3, m) degrees of freedom, for the listed m
/// (standard statistical tables; the last entry is m = ∞, where 3·F → χ²₃(0.95) = 7.8147).
const F3_95: [(f32, f32); 17] = [
    (3.0, 9.277),
    (4.0, 6.591),
    (5.0, 5.409),
    (6.0, 4.757),
    (7.0, 4.347),
    (8.0, 4.066),
    (9.0, 3.863),
    (10.0, 3.708),
    (12.0, 3.490),
    (15.0, 3.287),
    (20.0, 3.098),
    (24.0, 3.009),
    (30.0, 2.922),
    (40.0, 2.839),
    (60.0, 2.758),
    (120.0, 2.680),
    (f32::INFINITY, 2.605),
];

/// Factor by which `χ²₃(0.95)` must grow when the covariance scale is itself estimated with `ν`
/// degrees of freedom: the 95 % quantile of Hotelling's `T²(3, ν)`,
/// `3ν/(ν − 2) · F₃,ν₋₂(0.95)`, divided by `χ²₃(0.95)`. Interpolated linearly in `1/m` between
/// table entries; 1 in the limit of many degrees of freedom.
pub(crate) fn small_sample_factor(dof: f32) -> f32 {
    let m = dof - 2.0;
    let (m_lo, f_lo) = F3_95[0];
    let f = if m <= m_lo {
        f_lo
    } else {
        let mut f = F3_95[F3_95.len() - 1].1;
        for pair in F3_95.windows(2) {
            let [(m0, f0), (m1, f1)] = [pair[0], pair[1]];
            if m <= m1 {
                // Interpolate in 1/m (1/∞ = 0).
                let (u, u0, u1) = (1.0 / m, 1.0 / m0, 1.0 / m1);
                f = f1 + (f0 - f1) * (u - u1) / (u0 - u1);
                break;
            }
        }
        f
    };
    let t2 = 3.0 * dof / m.max(1.0) * f;
    (t2 / CHI2_3DOF_95).max(1.0)
}

/// Iteration cap for the 3 × 3 symmetric eigen-decomposition (it converges in < 10 sweeps).
const EIGEN_MAX_ITERATIONS: usize = 100;

/// The accumulated problem: sample rows and block sums, relative to `r_ref`.
pub(crate) struct Problem<'a, T: Scalar> {
    pub rows: &'a Moments<T>,
    pub batches: &'a BatchMeans<T>,
    /// Rows per block.
    pub block_len: u32,
    /// Reference offset the measurements are relative to (m).
    pub r_ref: Vector3<T>,
    /// The drag-extended sums ([`DragModel::VerticalQuadratic`], batch fitter, `r_ref = 0`):
    /// when present, the fit uses them instead of `rows` and `batches`.
    pub drag: Option<&'a DragSums>,
}

/// One model's fit.
#[derive(Clone, Copy)]
struct Fit<T: Scalar> {
    /// Inverse of the (reduced) information matrix: `(ΣXᵀX)⁻¹`, or the Schur complement's.
    information_inv: Matrix3<T>,
    /// Covariance scale: long-run variance times the small-sample factor.
    scale: T,
    /// `Q_rb`, the offset–bias block of the normal equations (`Σ Xᵀ` without drag): an
    /// unmodelled bias `b` moves the offset-only estimate by `(ΣXᵀX)⁻¹ Q_rb b`.
    bias_coupling: Matrix3<T>,
    r_imu_m: Vector3<T>,
    acc_bias_mps2: Option<Vector3<T>>,
    covariance_m2: Matrix3<T>,
    white_noise_covariance_m2: Matrix3<T>,
    acc_bias_covariance: Option<Matrix3<T>>,
    ellipsoid: Ellipsoid<T>,
    residual_rms_mps2: T,
    variance_inflation: T,
}

/// Just `r̂` of the offset-only model (used to move the reference between segments).
pub(crate) fn offset_only<T: Scalar>(rows: &Moments<T>, r_ref: &Vector3<T>) -> Option<Vector3<T>> {
    let d = rows.xtx().cholesky()?.solve(&rows.xty);
    let r = r_ref + d;
    r.iter().all(|v| v.is_finite()).then_some(r)
}

/// Fit, ellipsoid and verdict.
pub(crate) fn estimate<T: Scalar>(
    p: &Problem<'_, T>,
    model: Model,
    max_semi_axis_m: T,
) -> Result<Estimate<T>, ImuOffsetError> {
    if p.batches.short.count < MIN_BLOCKS {
        return Err(ImuOffsetError::TooFewSamples {
            used: p.rows.count,
            required: MIN_BLOCKS.saturating_mul(p.block_len),
        });
    }
    let offset = fit(p, Model::Offset)?;
    let poor = |fit: &Fit<T>| {
        let semi_axis_m = fit.ellipsoid.semi_axes_m[0];
        let direction_imu = fit.ellipsoid.axes[0];
        (semi_axis_m > max_semi_axis_m).then_some((
            direction_imu,
            semi_axis_m,
            ImuAxis::most_perpendicular_to(&direction_imu),
        ))
    };
    let (chosen, verdict) = match model {
        Model::Offset => {
            // Without a joint fit (bias not separable at all) there is no bias figure to use.
            let joint = fit(p, Model::OffsetAndAccBias).ok();
            // Excitation alone: the offset-only geometry at the joint fit's residual scale (the
            // offset-only residuals also contain any bias, which is not a lack of excitation).
            let excitation = match &joint {
                Some(joint) => rescaled(&offset, offset.information_inv * joint.scale)?,
                None => offset,
            };
            match poor(&excitation) {
                // The excitation is insufficient: say so; a bias figure would mean nothing here.
                Some((direction_imu, semi_axis_m, spin_next_about)) => (
                    offset,
                    Verdict::PoorlyDetermined { direction_imu, semi_axis_m, spin_next_about },
                ),
                None => {
                    let corrected = match &joint {
                        Some(joint) => with_unmodelled_bias(&offset, joint)?,
                        None => offset,
                    };
                    let verdict = match poor(&corrected) {
                        // Poor because of the bias, not the excitation: fitting it is the remedy.
                        Some((direction_imu, semi_axis_m, _)) => {
                            Verdict::BiasSuspected { direction_imu, semi_axis_m }
                        }
                        None => Verdict::WellDetermined {
                            largest_semi_axis_m: corrected.ellipsoid.semi_axes_m[0],
                        },
                    };
                    (corrected, verdict)
                }
            }
        }
        Model::OffsetAndAccBias => {
            let joint = fit(p, Model::OffsetAndAccBias)?;
            // Excitation alone: the offset-only geometry `(ΣXᵀX)⁻¹` at the joint fit's residual
            // scale (the offset-only residuals also contain the bias, which would inflate it).
            let mut excitation = offset;
            excitation.ellipsoid = ellipsoid(&(offset.information_inv * joint.scale))
                .ok_or(ImuOffsetError::Singular)?;
            let verdict = match (poor(&excitation), poor(&joint)) {
                (Some((direction_imu, semi_axis_m, spin_next_about)), _) => {
                    Verdict::PoorlyDetermined { direction_imu, semi_axis_m, spin_next_about }
                }
                (None, Some((direction_imu, semi_axis_m, spin_next_about))) => {
                    Verdict::BiasNotSeparable { direction_imu, semi_axis_m, spin_next_about }
                }
                (None, None) => {
                    Verdict::WellDetermined { largest_semi_axis_m: joint.ellipsoid.semi_axes_m[0] }
                }
            };
            (joint, verdict)
        }
    };
    Ok(Estimate {
        model,
        r_imu_m: chosen.r_imu_m,
        acc_bias_mps2: chosen.acc_bias_mps2,
        covariance_m2: chosen.covariance_m2,
        white_noise_covariance_m2: chosen.white_noise_covariance_m2,
        acc_bias_covariance_m2ps4: chosen.acc_bias_covariance,
        ellipsoid: chosen.ellipsoid,
        residual_rms_mps2: chosen.residual_rms_mps2,
        variance_inflation: chosen.variance_inflation,
        samples_used: p.rows.count,
        verdict,
    })
}

/// The offset-only fit with the error an accelerometer bias would cause, when the data reveal
/// one. An unmodelled constant bias `b` moves the offset-only estimate by `A b`,
/// `A = (ΣXᵀX)⁻¹ (ΣX)ᵀ`, the same in every batch, so batch means cannot see it. Its size is taken
/// from the joint fit, `b̂`, but not its direction (`b̂` also absorbs drag, and its direction is
/// what is least certain): `b` is treated as isotropic with `E[b bᵀ] = |b̂|²/3 · I` (which, through
/// `E|b̂|² = |b|² + tr Cov(b̂)`, also carries the joint fit's uncertainty). The statistical part
/// uses the joint fit's residual scale, which does not count the bias's constant residual as
/// noise. A bias no larger than its own noise (`b̂ᵀ Cov(b̂)⁻¹ b̂ ≤ 3`, the mean of that statistic
/// when there is no bias) leaves the fit as it is: `b̂` is then noise already in the statistical
/// error. With the drag model, `(ΣX)ᵀ` is the profiled offset–bias block `Q_rb`.
fn with_unmodelled_bias<T: Scalar>(
    offset: &Fit<T>,
    joint: &Fit<T>,
) -> Result<Fit<T>, ImuOffsetError> {
    let (Some(b), Some(cov_b)) = (joint.acc_bias_mps2, joint.acc_bias_covariance) else {
        return Ok(*offset);
    };
    let three: T = nalgebra::convert(3.0);
    let significant = cov_b.cholesky().is_some_and(|c| b.dot(&c.solve(&b)) > three);
    if !significant {
        return Ok(*offset);
    }
    let statistical = offset.information_inv * joint.scale;
    let a = offset.information_inv * offset.bias_coupling;
    let systematic = a * a.transpose() * (b.norm_squared() / three);
    rescaled(offset, statistical + systematic)
}

/// `fit` with another covariance of `r` (and its ellipsoid).
fn rescaled<T: Scalar>(fit: &Fit<T>, covariance_m2: Matrix3<T>) -> Result<Fit<T>, ImuOffsetError> {
    if !covariance_m2.iter().all(|v| v.is_finite()) {
        return Err(ImuOffsetError::Singular);
    }
    let ellipsoid = ellipsoid(&covariance_m2).ok_or(ImuOffsetError::Singular)?;
    Ok(Fit { covariance_m2, ellipsoid, ..*fit })
}

fn fit<T: Scalar>(p: &Problem<'_, T>, model: Model) -> Result<Fit<T>, ImuOffsetError> {
    if let Some(sums) = p.drag {
        return fit_with_drag(p, sums, model);
    }
    let rows = p.rows;
    let n: T = count_as(rows.count);
    let three: T = nalgebra::convert(3.0);
    let (information, rhs, unknowns) = match model {
        Model::Offset => (rows.xtx(), rows.xty, 3u32),
        Model::OffsetAndAccBias => (
            rows.xtx() - rows.xsum.tr_mul(&rows.xsum) / n,
            rows.xty - rows.xsum.tr_mul(&rows.ysum) / n,
            6u32,
        ),
    };
    let chol = information.cholesky().ok_or(ImuOffsetError::Singular)?;
    let d = chol.solve(&rhs);
    let information_inv = chol.inverse();
    let bias = match model {
        Model::Offset => None,
        Model::OffsetAndAccBias => Some((rows.ysum - rows.xsum * d) / n),
    };
    let b = bias.unwrap_or_else(Vector3::zeros);

    // Degrees of freedom: 3 per row.
    let dof_rows: T = count_as(rows.count.saturating_mul(3).saturating_sub(unknowns));
    let rss = rows.sum_sq_residual(&d, &b, T::one()).max(T::zero());
    let white_variance = rss / dof_rows;
    // Long-run variance from short and long batches, each widened for its own degrees of
    // freedom; the larger (more conservative) one is used.
    let short = batch_means_variance(&p.batches.short, p.block_len, &d, &b, unknowns);
    let long_len = p.block_len.saturating_mul(p.batches.group);
    let long = batch_means_variance(&p.batches.long, long_len, &d, &b, unknowns);
    let (long_run_variance, scale) = more_conservative(short, long, rows.count, p.block_len)?;

    let covariance_m2 = information_inv * scale;
    let acc_bias_covariance = bias.map(|_| {
        (Matrix3::identity() / n + rows.xsum * information_inv * rows.xsum.transpose() / (n * n))
            * scale
    });
    let ellipsoid = ellipsoid(&covariance_m2).ok_or(ImuOffsetError::Singular)?;
    let values_finite = d.iter().chain(b.iter()).chain(covariance_m2.iter()).all(|v| v.is_finite());
    if !values_finite {
        return Err(ImuOffsetError::Singular);
    }
    Ok(Fit {
        information_inv,
        scale,
        bias_coupling: rows.xsum.transpose(),
        r_imu_m: p.r_ref + d,
        acc_bias_mps2: bias,
        covariance_m2,
        white_noise_covariance_m2: information_inv * white_variance,
        acc_bias_covariance,
        ellipsoid,
        residual_rms_mps2: (rss / (n * three)).sqrt(),
        variance_inflation: if white_variance > T::zero() {
            long_run_variance / white_variance
        } else {
            T::one()
        },
    })
}

/// [`fit`] with per-segment drag ([`DragModel::VerticalQuadratic`]): the same estimates from the
/// 6 × 6 quadratic forms in `θ = [r; b]` left after profiling out each segment's drag vector.
/// The drag vectors count as unknowns in every degree-of-freedom figure.
fn fit_with_drag<T: Scalar>(
    p: &Problem<'_, T>,
    sums: &DragSums,
    model: Model,
) -> Result<Fit<T>, ImuOffsetError> {
    use nalgebra::{Matrix6, Vector6};
    let rows = &sums.rows;
    let q_rr: Matrix3<f64> = rows.q.fixed_view::<3, 3>(0, 0).into_owned();
    let g_r: Vector3<f64> = rows.g.fixed_rows::<3>(0).into_owned();
    let (theta, information_inv, bias_information_inv, unknowns) = match model {
        Model::Offset => {
            let chol = q_rr.cholesky().ok_or(ImuOffsetError::Singular)?;
            let r = chol.solve(&g_r);
            let mut theta = Vector6::zeros();
            theta.fixed_rows_mut::<3>(0).copy_from(&r);
            (theta, chol.inverse(), None, 3u32)
        }
        Model::OffsetAndAccBias => {
            let chol = rows.q.cholesky().ok_or(ImuOffsetError::Singular)?;
            let inv: Matrix6<f64> = chol.inverse();
            let rr: Matrix3<f64> = inv.fixed_view::<3, 3>(0, 0).into_owned();
            let bb: Matrix3<f64> = inv.fixed_view::<3, 3>(3, 3).into_owned();
            (chol.solve(&rows.g), rr, Some(bb), 6u32)
        }
    };
    let unknowns = unknowns.saturating_add(sums.segments.saturating_mul(3));
    let dof_rows = rows.count.saturating_mul(3).saturating_sub(unknowns);
    if dof_rows == 0 {
        return Err(ImuOffsetError::TooFewSamples {
            used: rows.count,
            required: MIN_BLOCKS.saturating_mul(p.block_len),
        });
    }
    let rss = rows.at(&theta).max(0.0);
    let white_variance = rss / f64::from(dof_rows);
    let variance = |q: &super::drag::Quadratic, batch_len: u32| -> Option<(f64, f64)> {
        let dof = q.count.saturating_mul(3).saturating_sub(unknowns);
        if dof < 2 || batch_len == 0 {
            return None;
        }
        let v = q.at(&theta).max(0.0) / (f64::from(batch_len) * f64::from(dof));
        Some((v, v * f64::from(small_sample_factor(dof as f32))))
    };
    let short = variance(&sums.short, p.block_len);
    let long = variance(&sums.long, p.block_len.saturating_mul(p.batches.group));
    let (long_run_variance, scale) = more_conservative(short, long, rows.count, p.block_len)?;
    let to_t = |m: Matrix3<f64>| m.map(|v| nalgebra::convert::<f64, T>(v));
    let r: Vector3<f64> = theta.fixed_rows::<3>(0).into_owned();
    let b: Vector3<f64> = theta.fixed_rows::<3>(3).into_owned();
    let covariance_m2 = information_inv * scale;
    let values_finite = theta.iter().chain(covariance_m2.iter()).all(|v| v.is_finite());
    if !values_finite {
        return Err(ImuOffsetError::Singular);
    }
    let covariance_m2 = to_t(covariance_m2);
    let ellipsoid = ellipsoid(&covariance_m2).ok_or(ImuOffsetError::Singular)?;
    let n = f64::from(rows.count.max(1));
    Ok(Fit {
        information_inv: to_t(information_inv),
        scale: nalgebra::convert(scale),
        bias_coupling: to_t(rows.q.fixed_view::<3, 3>(0, 3).into_owned()),
        r_imu_m: p.r_ref + r.map(|v| nalgebra::convert::<f64, T>(v)),
        acc_bias_mps2: bias_information_inv.map(|_| b.map(|v| nalgebra::convert::<f64, T>(v))),
        covariance_m2,
        white_noise_covariance_m2: to_t(information_inv * white_variance),
        acc_bias_covariance: bias_information_inv.map(|bb| to_t(bb * scale)),
        ellipsoid,
        residual_rms_mps2: nalgebra::convert(libm::sqrt(rss / (n * 3.0))),
        variance_inflation: nalgebra::convert(if white_variance > 0.0 {
            long_run_variance / white_variance
        } else {
            1.0
        }),
    })
}

/// Batch-means long-run variance per row and axis, `σ²_LR = Σ_b ‖Σ_{n∈b} e_n‖² / (L (3 n_b − p))`,
/// and the covariance scale: `σ²_LR` times the small-sample factor for `3 n_b − p` degrees of
/// freedom (the estimated scale makes the ellipsoid a Hotelling `T²` region, wider than `χ²₃`).
/// `None` with fewer than 2 degrees of freedom.
/// The more conservative (larger scale) of the short- and long-batch `(variance, scale)`
/// estimates; too few samples when not even the short batches could be formed.
fn more_conservative<V, S: PartialOrd>(
    short: Option<(V, S)>,
    long: Option<(V, S)>,
    samples_used: u32,
    block_len: u32,
) -> Result<(V, S), ImuOffsetError> {
    match (short, long) {
        (Some(s), Some(l)) if l.1 > s.1 => Ok(l),
        (Some(s), _) => Ok(s),
        (None, _) => Err(ImuOffsetError::TooFewSamples {
            used: samples_used,
            required: MIN_BLOCKS.saturating_mul(block_len),
        }),
    }
}

fn batch_means_variance<T: Scalar>(
    batches: &Moments<T>,
    batch_len: u32,
    d: &Vector3<T>,
    b: &Vector3<T>,
    unknowns: u32,
) -> Option<(T, T)> {
    let dof = batches.count.saturating_mul(3).saturating_sub(unknowns);
    if dof < 2 || batch_len == 0 {
        return None;
    }
    let len: T = count_as(batch_len);
    let ss = batches.sum_sq_residual(d, b, len).max(T::zero());
    let variance = ss / (len * count_as(dof));
    Some((variance, variance * T::from(small_sample_factor(dof as f32))))
}

/// Semi-axes and directions of the 95 % ellipsoid of a 3 × 3 covariance.
pub(crate) fn ellipsoid<T: Scalar>(covariance: &Matrix3<T>) -> Option<Ellipsoid<T>> {
    let chi2: T = CHI2_3DOF_95.into();
    let eig = SymmetricEigen::try_new(*covariance, T::default_epsilon(), EIGEN_MAX_ITERATIONS)?;
    let mut order = [0usize, 1, 2];
    order.sort_unstable_by(|&i, &j| {
        eig.eigenvalues[j].partial_cmp(&eig.eigenvalues[i]).unwrap_or(core::cmp::Ordering::Equal)
    });
    let mut semi_axes_m = [T::zero(); 3];
    let mut axes = [Vector3::zeros(); 3];
    for ((semi, axis), &k) in semi_axes_m.iter_mut().zip(axes.iter_mut()).zip(order.iter()) {
        *semi = (eig.eigenvalues[k].max(T::zero()) * chi2).sqrt();
        let v: Vector3<T> = eig.eigenvectors.column(k).into_owned();
        let v = v.normalize();
        let largest = v.iter().fold(T::zero(), |acc, c| if c.abs() > acc.abs() { *c } else { acc });
        *axis = if largest < T::zero() { -v } else { v };
    }
    Some(Ellipsoid { semi_axes_m, axes })
}
