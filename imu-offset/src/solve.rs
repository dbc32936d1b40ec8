//! From accumulated moments to an [`Estimate`]: the 3 × 3 solves for both models, the
//! batch-means covariance, the 95 % ellipsoid and the verdict.
//!
//! With a bias, the 6 × 6 normal equations `[[ΣXᵀX, ΣXᵀ], [ΣX, N I]]` are reduced to 3 × 3 by the
//! Schur complement of the (diagonal) bias block, `S = ΣXᵀX − (ΣX)ᵀ(ΣX)/N`: no 6 × 6 solve is ever
//! needed, and `S` shows directly how much of `XᵀX` is left once constant parts are explained
//! by a bias.
//!
//! With the drag model (`DragModel::VerticalQuadratic`, the default) the sums are 6 × 6 quadratic
//! forms in `θ = [r; b]` with each throw's drag vector already profiled out (`drag`, `f64` on
//! the board too: they are built once per throw); the fit solves them directly, counting 3
//! unknowns per throw in every degree-of-freedom figure.

use flight::eigen3::symmetric_eigen3;
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

use super::drag::DragSums;
use super::moments::{count_as, spd_inverse_of, BatchMeans, Moments};
use super::rest::RestModel;
#[cfg(doc)]
use super::DragModel;
use super::{
    Config, Ellipsoid, Estimate, ImuAxis, ImuOffsetError, Model, Scalar, Verdict, CHI2_3DOF_95,
};

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

/// The accumulated problem: sample rows and block sums, relative to `r_ref`.
pub(crate) struct Problem<'a, T: Scalar> {
    pub rows: &'a Moments<T>,
    pub batches: &'a BatchMeans<T>,
    /// Rows per block.
    pub block_len: u32,
    /// Reference offset the measurements are relative to (m).
    pub r_ref: Vector3<T>,
    /// The drag-profiled sums ([`DragModel::VerticalQuadratic`], relative to `r_ref`): when
    /// present, the fit uses them instead of `rows` and `batches`.
    pub drag: Option<&'a DragSums>,
    /// The rest poses (`rest`), which the joint model uses for the accelerometer bias.
    pub rest: Option<RestModel<'a>>,
}

/// One model's fit.
#[derive(Clone, Copy)]
struct Fit<T: Scalar> {
    /// Covariance of `r` per unit covariance scale: `(ΣXᵀX)⁻¹`, or the joint model's `r` block.
    information_inv: Matrix3<T>,
    /// Covariance scale of the free-fall rows: long-run variance times the small-sample factor.
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
    let d = spd_inverse_of(&rows.xtx())? * rows.xty;
    let r = r_ref + d;
    r.iter().all(|v| v.is_finite()).then_some(r)
}

/// Fit, ellipsoid and verdict.
///
/// The figures the verdict states are always the reported ellipsoid's (its largest semi-axis,
/// or its extent along the direction the throws did not excite); the analyses behind it (is the
/// excitation lacking, or a bias?) choose which advice is given and about which direction.
/// Whether the offset is well determined is judged before the IMU's sensitivity errors are
/// added ([`with_sensitivity_error`]): more throws cannot reduce them, so a verdict asking for
/// more would never be met. A calibration "well determined" may therefore report a largest
/// semi-axis above [`Config::max_semi_axis_m`], which is then the sensor's, not the throws'.
pub(crate) fn estimate<T: Scalar>(
    p: &Problem<'_, T>,
    config: &Config,
) -> Result<Estimate<T>, ImuOffsetError> {
    let model = config.model;
    let max_semi_axis_m: T = nalgebra::convert(f64::from(config.max_semi_axis_m));
    if p.batches.short.count < MIN_BLOCKS {
        return Err(ImuOffsetError::TooFewSamples {
            used: p.rows.count,
            required: MIN_BLOCKS.saturating_mul(p.block_len),
        });
    }
    let offset = fit(p, Model::Offset)?;
    // Without bias information a joint fit may be impossible (bias not separable at all).
    let joint = fit(p, Model::OffsetAndAccBias);
    // Excitation alone: the offset-only geometry at the joint fit's residual scale (the
    // offset-only residuals also contain any bias, which is not a lack of excitation).
    let excitation = match &joint {
        Ok(joint) => rescaled(&offset, offset.information_inv * joint.scale)?,
        Err(_) => offset,
    };
    let excitation_lacking = excitation.ellipsoid.semi_axes_m[0] > max_semi_axis_m;
    let chosen = match model {
        // An unmodelled bias the data reveal widens the offset-only ellipsoid.
        Model::Offset => match &joint {
            Ok(joint) if !excitation_lacking => with_unmodelled_bias(&offset, joint)?,
            _ => offset,
        },
        // Bias and offset inseparable (e.g. one spin about a principal axis, one rest attitude):
        // the offset-only fit is reported, and the verdict says what is missing.
        Model::OffsetAndAccBias => joint.unwrap_or(offset),
    };
    // What the throws leave uncertain decides whether they were enough; what the IMU's
    // sensitivity adds, which no further throw reduces, is in the ellipsoid and its figures.
    let throws_semi_axis_m = chosen.ellipsoid.semi_axes_m[0];
    let chosen = with_sensitivity_error(&chosen, config)?;
    let semi_axis_m = chosen.ellipsoid.semi_axes_m[0];
    let direction_imu = chosen.ellipsoid.axes[0];
    let spin_next_about = ImuAxis::most_perpendicular_to(&direction_imu);
    let verdict = if throws_semi_axis_m <= max_semi_axis_m {
        Verdict::WellDetermined { largest_semi_axis_m: semi_axis_m }
    } else if excitation_lacking {
        // The direction the throws did not excite (a single spin's axis), which another spin
        // observes, and how far the reported ellipsoid reaches along it. It need not be the
        // ellipsoid's longest axis: with one rest attitude the bias also leaves the plane across
        // the spin uncertain, which the next throw fixes too.
        let direction_imu = excitation.ellipsoid.axes[0];
        Verdict::PoorlyDetermined {
            direction_imu,
            semi_axis_m: extent_95(&chosen.covariance_m2, &direction_imu),
            spin_next_about: ImuAxis::most_perpendicular_to(&direction_imu),
        }
    } else if model == Model::Offset {
        // Poor because of the bias, not the excitation: fitting it is the remedy.
        Verdict::BiasSuspected { direction_imu, semi_axis_m }
    } else {
        Verdict::BiasNotSeparable { direction_imu, semi_axis_m, spin_next_about }
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
        rest_poses: match model {
            Model::OffsetAndAccBias => p.rest.map_or(0, |r| r.poses.len() as u32),
            Model::Offset => 0,
        },
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
    let significant = spd_inverse_of(&cov_b).is_some_and(|inverse| b.dot(&(inverse * b)) > three);
    if !significant {
        return Ok(*offset);
    }
    let statistical = offset.information_inv * joint.scale;
    let a = offset.information_inv * offset.bias_coupling;
    let systematic = a * a.transpose() * (b.norm_squared() / three);
    rescaled(offset, statistical + systematic)
}

/// `fit` with the IMU's sensitivity errors added to its covariance: a sphere of 1σ
/// [`Config::sensitivity_offset_sigma`] `|r̂|`. Measured on 200 random airframes' two-throw
/// calibrations (`offset_diag 200 random calibration`): the truth inside the 95 % ellipsoid in
/// 137 of 200 without this term (the rest poses already modelled), 190 with it.
fn with_sensitivity_error<T: Scalar>(
    fit: &Fit<T>,
    config: &Config,
) -> Result<Fit<T>, ImuOffsetError> {
    let relative: T = nalgebra::convert(f64::from(config.sensitivity_offset_sigma()));
    let per_r2 = relative * relative;
    rescaled(fit, fit.covariance_m2 + Matrix3::identity() * (fit.r_imu_m.norm_squared() * per_r2))
}

/// `fit` with another covariance of `r` (and its ellipsoid).
fn rescaled<T: Scalar>(fit: &Fit<T>, covariance_m2: Matrix3<T>) -> Result<Fit<T>, ImuOffsetError> {
    if !covariance_m2.iter().all(|v| v.is_finite()) {
        return Err(ImuOffsetError::Singular);
    }
    let ellipsoid = ellipsoid(&covariance_m2).ok_or(ImuOffsetError::Singular)?;
    Ok(Fit { covariance_m2, ellipsoid, ..*fit })
}

/// The free-fall sums seen as quadratic forms in `θ = [d; b]` (offset relative to the reference,
/// bias): the normal equations `Q θ = g`, and the residual figures at any `θ`.
enum Sums<'a, T: Scalar> {
    /// The rows of eq. 3 and their block sums.
    Rows { rows: &'a Moments<T>, batches: &'a BatchMeans<T>, block_len: u32 },
    /// The drag-extended sums, each throw's drag vector profiled out (3 more unknowns a throw).
    Drag { sums: &'a DragSums, block_len: u32, group: u32 },
}

/// Residual figures of a fit at one `θ`.
#[derive(Clone, Copy)]
struct Residuals<T: Scalar> {
    /// Residual sum of squares over the rows.
    rss: T,
    /// `rss` per degree of freedom (the white-noise variance).
    white_variance: T,
    /// The batch-means long-run variance chosen, and the covariance scale (it times the
    /// small-sample factor).
    long_run_variance: T,
    scale: T,
}

impl<T: Scalar> Sums<'_, T> {
    fn new<'a>(p: &Problem<'a, T>) -> Sums<'a, T> {
        match p.drag {
            Some(sums) => Sums::Drag { sums, block_len: p.block_len, group: p.batches.group },
            None => Sums::Rows { rows: p.rows, batches: p.batches, block_len: p.block_len },
        }
    }

    fn count(&self) -> u32 {
        match self {
            Sums::Rows { rows, .. } => rows.count,
            Sums::Drag { sums, .. } => sums.rows.count,
        }
    }

    /// Unknowns besides `θ`'s: each throw's drag vector.
    fn extra_unknowns(&self) -> u32 {
        match self {
            Sums::Rows { .. } => 0,
            Sums::Drag { sums, .. } => sums.segments.saturating_mul(3),
        }
    }

    /// `Q` and `g` of the normal equations in `θ = [d; b]`.
    fn normal_equations(&self) -> (Matrix6<T>, Vector6<T>) {
        match self {
            Sums::Rows { rows, .. } => {
                let n: T = count_as(rows.count);
                let mut q = Matrix6::zeros();
                q.fixed_view_mut::<3, 3>(0, 0).copy_from(&rows.xtx());
                q.fixed_view_mut::<3, 3>(0, 3).copy_from(&rows.xsum.transpose());
                q.fixed_view_mut::<3, 3>(3, 0).copy_from(&rows.xsum);
                q.fixed_view_mut::<3, 3>(3, 3).copy_from(&(Matrix3::identity() * n));
                let mut g = Vector6::zeros();
                g.fixed_rows_mut::<3>(0).copy_from(&rows.xty);
                g.fixed_rows_mut::<3>(3).copy_from(&rows.ysum);
                (q, g)
            }
            Sums::Drag { sums, .. } => (sums.rows.q.map(to_scalar), sums.rows.g.map(to_scalar)),
        }
    }

    /// Residual figures at `θ` with `unknowns` fitted (besides the drag vectors).
    fn residuals(&self, theta: &Vector6<T>, unknowns: u32) -> Result<Residuals<T>, ImuOffsetError> {
        let unknowns = unknowns.saturating_add(self.extra_unknowns());
        let too_few = |block_len: u32| ImuOffsetError::TooFewSamples {
            used: self.count(),
            required: MIN_BLOCKS.saturating_mul(block_len),
        };
        let (rss, short, long, block_len) = match self {
            Sums::Rows { rows, batches, block_len } => {
                let d: Vector3<T> = theta.fixed_rows::<3>(0).into_owned();
                let b: Vector3<T> = theta.fixed_rows::<3>(3).into_owned();
                let rss = rows.sum_sq_residual(&d, &b, T::one());
                let short = batch_means_variance(&batches.short, *block_len, &d, &b, unknowns);
                let long_len = block_len.saturating_mul(batches.group);
                let long = batch_means_variance(&batches.long, long_len, &d, &b, unknowns);
                (rss, short, long, *block_len)
            }
            Sums::Drag { sums, block_len, group } => {
                let theta = theta.map(|v| nalgebra::try_convert::<T, f64>(v).unwrap_or(f64::NAN));
                let variance = |q: &super::drag::Quadratic, batch_len: u32| -> Option<(T, T)> {
                    let dof = q.count.saturating_mul(3).saturating_sub(unknowns);
                    if dof < 2 || batch_len == 0 {
                        return None;
                    }
                    let v = q.at(&theta).max(0.0) / (f64::from(batch_len) * f64::from(dof));
                    let scale = v * f64::from(small_sample_factor(dof as f32));
                    Some((to_scalar(v), to_scalar(scale)))
                };
                let short = variance(&sums.short, *block_len);
                let long = variance(&sums.long, block_len.saturating_mul(*group));
                (to_scalar(sums.rows.at(&theta)), short, long, *block_len)
            }
        };
        let dof_rows = self.count().saturating_mul(3).saturating_sub(unknowns);
        if dof_rows == 0 {
            return Err(too_few(block_len));
        }
        let rss = rss.max(T::zero());
        let (long_run_variance, scale) = more_conservative(short, long, self.count(), block_len)?;
        Ok(Residuals { rss, white_variance: rss / count_as(dof_rows), long_run_variance, scale })
    }
}

fn to_scalar<T: Scalar>(v: f64) -> T {
    nalgebra::convert(v)
}

/// Fit one model. The offset-only model is the joint one with `b = 0`.
///
/// With rest poses the joint model weighs the free-fall rows by the inverse of their covariance
/// scale and adds the rest poses' bias information `J` (already in (m/s²)⁻²):
/// `(Q/s + diag(0, J)) θ = g/s + (0, J b̂_rest)`. The scale `s` is measured at the solution, so the
/// solve is repeated twice (the first time at the free-fall solution's scale).
fn fit<T: Scalar>(p: &Problem<'_, T>, model: Model) -> Result<Fit<T>, ImuOffsetError> {
    let sums = Sums::new(p);
    let (q, g) = sums.normal_equations();
    let q_rr: Matrix3<T> = q.fixed_view::<3, 3>(0, 0).into_owned();
    // The offset-only solution `θ = [d; 0]` and the inverse of `Q_rr`.
    let offset_only = || {
        let q_rr_inv = spd_inverse_of(&q_rr).ok_or(ImuOffsetError::Singular)?;
        let mut theta = Vector6::zeros();
        theta.fixed_rows_mut::<3>(0).copy_from(&(q_rr_inv * g.fixed_rows::<3>(0)));
        Ok::<_, ImuOffsetError>((theta, q_rr_inv))
    };
    let bias_coupling: Matrix3<T> = q.fixed_view::<3, 3>(0, 3).into_owned();
    let (theta, residuals, covariance) = match model {
        Model::Offset => {
            let (theta, q_rr_inv) = offset_only()?;
            let residuals = sums.residuals(&theta, 3)?;
            let mut covariance = Matrix6::zeros();
            covariance.fixed_view_mut::<3, 3>(0, 0).copy_from(&q_rr_inv);
            (theta, residuals, covariance * residuals.scale)
        }
        Model::OffsetAndAccBias => match p.rest.filter(|r| !r.poses.is_empty()) {
            None => {
                let q_inv = spd_inverse_of(&q).ok_or(ImuOffsetError::Singular)?;
                let theta = q_inv * g;
                let residuals = sums.residuals(&theta, 6)?;
                let covariance = q_inv * residuals.scale;
                (theta, residuals, covariance)
            }
            Some(rest) => {
                // Solve at covariance scale `s`, the rest equations linearised about `b0`.
                let solve = |scale: T, b0: &Vector3<T>| {
                    let info = rest.bias_information(b0).ok_or(ImuOffsetError::Singular)?;
                    let mut m = q / scale;
                    let mut rhs = g / scale;
                    let mut bb = m.fixed_view_mut::<3, 3>(3, 3);
                    bb += info.information;
                    let mut hb = rhs.fixed_rows_mut::<3>(3);
                    hb += info.rhs;
                    let m_inv = spd_inverse_of(&m).ok_or(ImuOffsetError::Singular)?;
                    Ok::<_, ImuOffsetError>((m_inv * rhs, m_inv))
                };
                // First scale: at the free-fall joint solution, or offset-only without bias.
                let start = match spd_inverse_of(&q) {
                    Some(q_inv) => q_inv * g,
                    None => offset_only()?.0,
                };
                let mut residuals = sums.residuals(&start, 6)?;
                let mut solution = solve(residuals.scale, &Vector3::zeros())?;
                for _ in 0..2 {
                    residuals = sums.residuals(&solution.0, 6)?;
                    let b0: Vector3<T> = solution.0.fixed_rows::<3>(3).into_owned();
                    solution = solve(residuals.scale, &b0)?;
                }
                (solution.0, residuals, solution.1)
            }
        },
    };
    let covariance_m2: Matrix3<T> = covariance.fixed_view::<3, 3>(0, 0).into_owned();
    let acc_bias_covariance = (model == Model::OffsetAndAccBias)
        .then(|| covariance.fixed_view::<3, 3>(3, 3).into_owned());
    let d: Vector3<T> = theta.fixed_rows::<3>(0).into_owned();
    let acc_bias_mps2 =
        (model == Model::OffsetAndAccBias).then(|| theta.fixed_rows::<3>(3).into_owned());
    let values_finite = theta.iter().chain(covariance_m2.iter()).all(|v| v.is_finite());
    if !values_finite || residuals.scale <= T::zero() {
        return Err(ImuOffsetError::Singular);
    }
    let information_inv = covariance_m2 / residuals.scale;
    let ellipsoid = ellipsoid(&covariance_m2).ok_or(ImuOffsetError::Singular)?;
    let three: T = nalgebra::convert(3.0);
    let n: T = count_as(sums.count().max(1));
    Ok(Fit {
        information_inv,
        scale: residuals.scale,
        bias_coupling,
        r_imu_m: p.r_ref + d,
        acc_bias_mps2,
        covariance_m2,
        white_noise_covariance_m2: information_inv * residuals.white_variance,
        acc_bias_covariance,
        ellipsoid,
        residual_rms_mps2: (residuals.rss / (n * three)).sqrt(),
        variance_inflation: if residuals.white_variance > T::zero() {
            residuals.long_run_variance / residuals.white_variance
        } else {
            T::one()
        },
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

/// How far the 95 % ellipsoid of `covariance` reaches along the unit vector `direction`:
/// `√(χ²₃(0.95) dᵀΣd)` (m).
fn extent_95<T: Scalar>(covariance: &Matrix3<T>, direction: &Vector3<T>) -> T {
    let chi2: T = CHI2_3DOF_95.into();
    (direction.dot(&(covariance * direction)).max(T::zero()) * chi2).sqrt()
}

/// Semi-axes and directions of the 95 % ellipsoid of a 3 × 3 covariance.
pub(crate) fn ellipsoid<T: Scalar>(covariance: &Matrix3<T>) -> Option<Ellipsoid<T>> {
    let chi2: T = CHI2_3DOF_95.into();
    let (values, vectors) =
        symmetric_eigen3(core::array::from_fn(|i| core::array::from_fn(|j| covariance[(i, j)])))?;
    let mut order = [0usize, 1, 2];
    order.sort_unstable_by(|&i, &j| {
        values[j].partial_cmp(&values[i]).unwrap_or(core::cmp::Ordering::Equal)
    });
    let mut semi_axes_m = [T::zero(); 3];
    let mut axes = [Vector3::zeros(); 3];
    for ((semi, axis), &k) in semi_axes_m.iter_mut().zip(axes.iter_mut()).zip(order.iter()) {
        *semi = (values[k].max(T::zero()) * chi2).sqrt();
        let v = Vector3::new(vectors[0][k], vectors[1][k], vectors[2][k]).normalize();
        let largest = v.iter().fold(T::zero(), |acc, c| if c.abs() > acc.abs() { *c } else { acc });
        *axis = if largest < T::zero() { -v } else { v };
    }
    Some(Ellipsoid { semi_axes_m, axes })
}
