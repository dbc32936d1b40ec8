//! Rest poses: the accelerometer bias seen while the craft rests in the hand.
//!
//! # Why
//! A constant accelerometer bias `b` enters eq. 3 as `f = X r + b`. In free fall it is nearly
//! confounded with the constant part of `X r`, so two throws determine `r` and `b` jointly only
//! poorly, and an ignored bias moves `r̂` by millimetres (a real ICM-42688-P is specified at up to
//! ±20 mg ≈ 0.2 m/s² of zero-g offset). Every calibration session also holds the craft still in
//! the hand before and after each throw, and the catch leaves it in a new attitude. At rest the
//! accelerometer reads gravity plus bias, `|f − b| = g`, independently of `r`.
//!
//! # The equation
//! Linearised about `b = 0` (the neglected term is `|b⊥|²/2g ≤ 2 mm/s²` for `|b| ≤ 0.2 m/s²`):
//! `uᵀ b + δg = |f| − g₀` with `u = f/|f|`: one scalar equation per attitude in the three bias
//! components and the deviation `δg` of the local gravity from the standard `g₀`. Local gravity
//! differs from standard gravity by up to ±0.03 m/s² over the Earth's surface, as much as the bias
//! itself, so `δg` is an unknown with a prior ([`Config::gravity_sigma_mps2`]); with three or more
//! attitudes well apart the data determine both.
//!
//! # Sensitivity
//! The accelerometer's sensitivity error `S` (scale and cross-axis errors, a few per cent) makes
//! a rest pose read `|(I + S) g| ≈ g₀ (1 + uᵀ S u)`: up to 0.3 m/s², more than the bias, and
//! different in every attitude, so a handful of poses cannot tell it from a bias. Measured on 200
//! random airframes (`offset_diag 200 random calibration`): with `S` left out of the model the
//! two-throw calibration's offset was 4.3 / 12.8 mm off (median / 90th percentile) and inside its
//! 95 % ellipsoid in 34 of 200. So the symmetric part of `S` (six elements; `uᵀ S u` sees no
//! other) enters every pose's equation as an unknown under a prior
//! ([`Config::scale_error_sigma`], [`Config::cross_axis_sigma`]) and is profiled out with `δg`:
//! the poses then teach the bias only what the sensitivity cannot also explain.
//!
//! # Detection and noise
//! A filtered sample is at rest when `|Ω| <` [`REST_MAX_RATE_RAD_S`] and `||f| − g₀| <`
//! [`REST_MAX_DEVIATION_MPS2`]. Rest samples are averaged in blocks of [`REST_BLOCK_S`]; the first
//! and the last complete block of every run of rest are dropped (the hand settling after a catch,
//! winding up before a throw). A pose needs [`MIN_POSE_BLOCKS`] kept blocks. Its equation's
//! variance is measured from the spread of its block means of `|f|` (a hand is never perfectly
//! still; the spread shows how much its motion moves the mean), with a floor
//! [`POSE_SIGMA_FLOOR_MPS2`].
//!
//! The sums are 4 × 4 information-form least squares (constant memory, no allocation); poses are
//! added once they end, so the onboard estimator and the batch fitter, which replays the same
//! detector, hold identical rest information.

use nalgebra::{Matrix3, Vector3};

use super::front_end::AlignedSample;
use super::{Config, Scalar};

/// Largest filtered body rate at rest (rad/s): the centripetal term at an offset of 5 cm is then
/// below `0.3² · 0.05 = 4.5 mm/s²`, a fifth of the smallest bias worth knowing (0.02 m/s²); a hand
/// holding a craft still turns it far slower than 17 °/s.
pub const REST_MAX_RATE_RAD_S: f32 = 0.3;

/// Largest deviation of the filtered `|f|` from standard gravity at rest (m/s²): above the
/// largest bias the ICM-42688-P allows (±20 mg per axis, 0.34 m/s² on three axes) plus local
/// gravity (±0.03 m/s²), far below the ≥ 2 m/s² of a throw or a catch.
pub const REST_MAX_DEVIATION_MPS2: f32 = 0.5;

/// Length of the averaging blocks of a rest pose (s): 10 time constants of the 50 Hz front end,
/// short enough that a half-second rest gives ten of them.
pub const REST_BLOCK_S: f32 = 0.05;

/// Fewest kept blocks for a pose (after dropping the first and the last): 3 × 50 ms, enough for a
/// spread with two degrees of freedom.
pub const MIN_POSE_BLOCKS: u32 = 3;

/// Smallest standard deviation of a pose's equation (m/s²): what the model leaves out even for a
/// perfectly still craft (the centripetal term at the rate bound above, the linearisation, the
/// accelerometer's nonlinearity of about 0.1 %·g over a small range of attitudes).
pub const POSE_SIGMA_FLOOR_MPS2: f32 = 0.003;

/// The run of rest samples in progress, averaged in blocks.
#[derive(Debug, Clone, Copy, PartialEq)]
struct RestRun {
    /// Sum of `f` over the block being filled, and its sample count.
    block_sum: Vector3<f32>,
    block_count: u32,
    /// The last complete block's mean `f`, not yet kept (it may be the run's last).
    pending: Option<Vector3<f32>>,
    /// Whether the run's first complete block has been dropped.
    first_dropped: bool,
    /// Kept blocks: sum of unit vectors, sum of `|f̄_b| − ref`, its squares, count; `ref` is the
    /// first kept block's `|f̄_b|` (so the spread is not lost to cancellation in `f32`).
    unit_sum: Vector3<f32>,
    norm_ref: f32,
    norm_dev_sum: f32,
    norm_dev_sq_sum: f32,
    blocks: u32,
}

impl RestRun {
    const fn new() -> Self {
        Self {
            block_sum: Vector3::new(0.0, 0.0, 0.0),
            block_count: 0,
            pending: None,
            first_dropped: false,
            unit_sum: Vector3::new(0.0, 0.0, 0.0),
            norm_ref: 0.0,
            norm_dev_sum: 0.0,
            norm_dev_sq_sum: 0.0,
            blocks: 0,
        }
    }

    fn keep(&mut self, mean_f: &Vector3<f32>) {
        let norm = mean_f.norm();
        if norm <= 0.0 {
            return;
        }
        if self.blocks == 0 {
            self.norm_ref = norm;
        }
        let dev = norm - self.norm_ref;
        self.unit_sum += mean_f / norm;
        self.norm_dev_sum += dev;
        self.norm_dev_sq_sum += dev * dev;
        self.blocks += 1;
    }
}

/// One rest pose: its attitude and its mean `|f|` with the variance of that mean.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestPose {
    /// Direction of the mean specific force (unit vector, IMU frame): "up" as the IMU sees it.
    pub up_imu: Vector3<f32>,
    /// Mean `|f|` (m/s²).
    pub specific_force_mps2: f32,
    /// Standard deviation of that mean (m/s²), at least [`POSE_SIGMA_FLOOR_MPS2`].
    pub sigma_mps2: f32,
    /// Blocks averaged.
    pub blocks: u32,
}

/// Finds rest poses in the aligned stream (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RestDetector {
    block_len: u32,
    gravity_mps2: f32,
    run: Option<RestRun>,
}

impl RestDetector {
    /// A detector for a stream at `rate_hz`, with `gravity_mps2` the nominal gravity `g₀`.
    pub(crate) fn new(rate_hz: f32, gravity_mps2: f32) -> Self {
        let block_len = libm::roundf(REST_BLOCK_S * rate_hz).max(1.0) as u32;
        Self { block_len, gravity_mps2, run: None }
    }

    /// Feed one aligned sample that is not part of a free fall; returns a pose when a run of rest
    /// long enough has just ended.
    pub(crate) fn update(&mut self, s: &AlignedSample) -> Option<RestPose> {
        let still = s.gyro_radps.norm() < REST_MAX_RATE_RAD_S
            && (s.acc_mps2.norm() - self.gravity_mps2).abs() < REST_MAX_DEVIATION_MPS2;
        if !still {
            return self.end();
        }
        let run = self.run.get_or_insert(RestRun::new());
        run.block_sum += s.acc_mps2;
        run.block_count += 1;
        if run.block_count >= self.block_len {
            let mean = run.block_sum / run.block_count as f32;
            run.block_sum = Vector3::zeros();
            run.block_count = 0;
            if !run.first_dropped {
                run.first_dropped = true;
            } else if let Some(previous) = run.pending.replace(mean) {
                run.keep(&previous);
            }
        }
        None
    }

    /// The pose the run in progress would give if it ended now ([`Self::end`] on a copy).
    pub(crate) fn in_progress(&self) -> Option<RestPose> {
        let mut copy = *self;
        copy.end()
    }

    /// Blocks kept by the run in progress (0 when none): it changes once per kept block.
    pub(crate) fn kept_blocks(&self) -> u32 {
        self.run.map_or(0, |run| run.blocks)
    }

    /// The run in progress ends here (its last complete block and partial block are dropped);
    /// returns its pose when it was long enough.
    pub(crate) fn end(&mut self) -> Option<RestPose> {
        let run = self.run.take()?;
        if run.blocks < MIN_POSE_BLOCKS {
            return None;
        }
        let n = run.blocks as f32;
        let mean_dev = run.norm_dev_sum / n;
        let spread_var = ((run.norm_dev_sq_sum - n * mean_dev * mean_dev) / (n - 1.0)).max(0.0);
        let sigma_mps2 =
            libm::sqrtf(spread_var / n + POSE_SIGMA_FLOOR_MPS2 * POSE_SIGMA_FLOOR_MPS2);
        let up_imu = run.unit_sum.try_normalize(f32::EPSILON)?;
        let pose = RestPose {
            up_imu,
            specific_force_mps2: run.norm_ref + mean_dev,
            sigma_mps2,
            blocks: run.blocks,
        };
        pose.is_finite().then_some(pose)
    }
}

impl RestPose {
    fn is_finite(&self) -> bool {
        self.up_imu.iter().all(|v| v.is_finite())
            && self.specific_force_mps2.is_finite()
            && self.sigma_mps2.is_finite()
            && self.sigma_mps2 > 0.0
    }
}

/// Most rest poses kept (a calibration session has two per throw); later ones are ignored.
pub const MAX_REST_POSES: usize = 32;

/// The rest poses found so far (fixed capacity, no allocation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RestPoses {
    poses: [RestPose; MAX_REST_POSES],
    len: usize,
}

/// The rest equations reduced to the bias: information `J` ((m/s²)⁻²) and `h = J b̂_rest`, with
/// the gravity deviation profiled out under its prior.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BiasInformation<T: Scalar> {
    pub(crate) information: Matrix3<T>,
    pub(crate) rhs: Vector3<T>,
}

/// The rest poses with the gravity model they are read with.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RestModel<'a> {
    pub(crate) poses: &'a [RestPose],
    /// Nominal gravity `g₀` (m/s²).
    pub(crate) gravity_mps2: f32,
    /// Prior standard deviation of the local gravity about `g₀` (m/s²).
    pub(crate) gravity_sigma_mps2: f32,
    /// Prior standard deviations of the accelerometer's scale errors and of the off-diagonal
    /// elements of its symmetric sensitivity error (fractions).
    pub(crate) scale_sigma: f32,
    pub(crate) symmetric_cross_sigma: f32,
}

impl RestPoses {
    pub(crate) fn new() -> Self {
        let none = RestPose {
            up_imu: Vector3::zeros(),
            specific_force_mps2: 0.0,
            sigma_mps2: 1.0,
            blocks: 0,
        };
        Self { poses: [none; MAX_REST_POSES], len: 0 }
    }

    /// Keep one pose (ignored when full).
    pub(crate) fn push(&mut self, pose: RestPose) {
        if let Some(slot) = self.poses.get_mut(self.len) {
            *slot = pose;
            self.len += 1;
        }
    }

    /// Keep all poses of `other`.
    pub(crate) fn extend(&mut self, other: &Self) {
        for pose in other.as_slice() {
            self.push(*pose);
        }
    }

    pub(crate) fn as_slice(&self) -> &[RestPose] {
        self.poses.get(..self.len).unwrap_or(&[])
    }

    /// The poses read with `config`'s gravity model.
    pub(crate) fn model(&self, config: &Config) -> RestModel<'_> {
        RestModel {
            poses: self.as_slice(),
            gravity_mps2: config.gravity_mps2,
            gravity_sigma_mps2: config.gravity_sigma_mps2,
            scale_sigma: config.scale_error_sigma,
            // The symmetric part's element is the mean of two independent cross-axis terms.
            symmetric_cross_sigma: config.cross_axis_sigma * core::f32::consts::FRAC_1_SQRT_2,
        }
    }
}

impl RestModel<'_> {
    /// The rest equations linearised about the bias `b0` (the neglected term is then of second
    /// order in `b − b0`), the nuisances `n = [δg; s]` profiled out under their priors; `None`
    /// without poses.
    ///
    /// Pose `k`: `|f_k − b| = g₀ + δg + g₀ u_kᵀ S u_k` ≈ `|f_k − b0| − u_kᵀ (b − b0)`,
    /// `u_k = (f_k − b0)/|f_k − b0|`, so `u_kᵀ b + δg + g₀ q(u_k)ᵀ s = |f_k − b0| + u_kᵀ b0 − g₀`
    /// with weight `1/σ_k²`, where `s` holds the six elements of the symmetric part of the
    /// accelerometer's sensitivity error `S` (module doc, "Sensitivity") and `q(u)` their
    /// coefficients in `uᵀ S u`. Each nuisance is counted in units of its prior's standard
    /// deviation (`n = σ ⊙ n'`, `n' ~ N(0, I)`), so a zero deviation (a calibrated IMU) simply
    /// removes it. The information over `[b; n']` is summed pose by pose and the nuisances are
    /// eliminated (Gaussian elimination, which leaves the Schur complement
    /// `J = J_bb − J_bn C⁻¹ J_nb`, `C = J_nn + I`; `C` is positive definite by its `+ I`).
    ///
    /// Summed and solved in `f64` with plain loops whatever `T` is: the board's build is short of
    /// flash, and nalgebra's 10 × 10 products and a 7 × 7 inverse cost about 1 KB more.
    #[allow(clippy::needless_range_loop)] // the matrices' indices, as in the notation
    pub(crate) fn bias_information<T: Scalar>(
        &self,
        b0: &Vector3<T>,
    ) -> Option<BiasInformation<T>> {
        if self.poses.is_empty() {
            return None;
        }
        let wide = |v: T| nalgebra::try_convert::<T, f64>(v).unwrap_or(f64::NAN);
        let b0 = b0.map(wide);
        let g0 = f64::from(self.gravity_mps2);
        let scale = g0 * f64::from(self.scale_sigma);
        let cross = 2.0 * g0 * f64::from(self.symmetric_cross_sigma);
        // Lower triangle of the information over [b; n'] and its right-hand side.
        let mut j = [[0.0f64; REST_UNKNOWNS]; REST_UNKNOWNS];
        let mut h = [0.0f64; REST_UNKNOWNS];
        for pose in self.poses {
            let relative = pose.up_imu.map(f64::from) * f64::from(pose.specific_force_mps2) - b0;
            let norm = relative.norm();
            let u = relative / norm;
            let w = [
                u.x,
                u.y,
                u.z,
                f64::from(self.gravity_sigma_mps2),
                scale * u.x * u.x,
                scale * u.y * u.y,
                scale * u.z * u.z,
                cross * u.x * u.y,
                cross * u.x * u.z,
                cross * u.y * u.z,
            ];
            let weight = 1.0 / f64::from(pose.sigma_mps2 * pose.sigma_mps2);
            let y = norm + u.dot(&b0) - g0;
            for i in 0..REST_UNKNOWNS {
                h[i] += w[i] * y * weight;
                for k in 0..=i {
                    j[i][k] += w[i] * w[k] * weight;
                }
            }
        }
        // The nuisances' priors, then Gaussian elimination of the nuisances from the last one
        // down: what is left in the first three rows and columns is the Schur complement.
        for p in (3..REST_UNKNOWNS).rev() {
            let pivot = j[p][p] + 1.0;
            for i in 0..p {
                let factor = j[p][i] / pivot;
                h[i] -= factor * h[p];
                for k in 0..=i {
                    j[i][k] -= factor * j[p][k];
                }
            }
        }
        let information = Matrix3::<T>::from_fn(|i, k| nalgebra::convert(j[i.max(k)][i.min(k)]));
        let rhs = Vector3::<T>::from_fn(|i, _| nalgebra::convert(h[i]));
        let finite = information.iter().chain(rhs.iter()).all(|v| v.is_finite());
        finite.then_some(BiasInformation { information, rhs })
    }
}

/// Unknowns of a rest pose's equation: the bias (3), the gravity deviation and the six elements
/// of the accelerometer's symmetric sensitivity error.
const REST_UNKNOWNS: usize = 10;

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;

    const G: f32 = 9.80665;

    /// Rest samples in attitude `up` (unit vector) with bias `b`, for `seconds` at `rate_hz`.
    fn rest(detector: &mut RestDetector, up: Vector3<f32>, b: Vector3<f32>, seconds: f32) {
        rest_scaled(detector, up, &Matrix3::zeros(), b, seconds);
    }

    /// The same from an accelerometer with sensitivity error `s` (`f = (I + S) f_true + b`).
    fn rest_scaled(
        detector: &mut RestDetector,
        up: Vector3<f32>,
        s: &Matrix3<f32>,
        b: Vector3<f32>,
        seconds: f32,
    ) {
        let rate_hz = 2000.0;
        let n = (seconds * rate_hz) as u32;
        for index in 0..n {
            let sample = AlignedSample {
                index,
                gyro_radps: Vector3::zeros(),
                gyro_dot_radps2: Vector3::zeros(),
                acc_mps2: (Matrix3::identity() + s) * up * G + b,
            };
            assert_eq!(detector.update(&sample), None);
        }
    }

    #[test]
    fn poses_in_four_attitudes_recover_the_bias_to_a_millimetre_per_second_squared() {
        let b = Vector3::new(0.05, -0.12, 0.2);
        let ups = [
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.6, 0.0, -0.8),
            Vector3::new(0.0, -0.8, 0.6),
            Vector3::new(-0.7, 0.7, 0.1),
        ];
        let mut detector = RestDetector::new(2000.0, G);
        let mut poses = RestPoses::new();
        for up in ups {
            rest(&mut detector, up.normalize(), b, 0.4);
            let pose = detector.end().expect("0.4 s of rest is a pose");
            // 8 blocks of 50 ms, the first and the last dropped.
            assert_eq!(pose.blocks, 6);
            poses.push(pose);
        }
        let model = RestModel {
            poses: poses.as_slice(),
            gravity_mps2: G,
            gravity_sigma_mps2: 0.03,
            scale_sigma: 0.0,
            symmetric_cross_sigma: 0.0,
        };
        // Linearised about zero the bias is off by about |b|²/2g (3 mm/s² here); relinearised
        // about the first solution, by far less.
        let mut found = Vector3::<f64>::zeros();
        let mut errors = [0.0; 2];
        for error in &mut errors {
            let info = model.bias_information(&found).expect("poses");
            found = info.information.cholesky().expect("four attitudes observe b").solve(&info.rhs);
            *error = (found - b.map(f64::from)).norm();
        }
        assert!(errors[0] > 1e-3 && errors[0] < 5e-3, "first solution off by {errors:?}");
        assert!(errors[1] < 1e-4, "relinearised bias off by {} m/s²: {found:?}", errors[1]);
    }

    #[test]
    fn the_bias_from_rest_poses_is_as_good_as_its_covariance_says_despite_scale_errors() {
        // 200 accelerometers with scale errors over ±3 % and cross-axis ones over ±2 % (the
        // defaults' assumption), a bias of 0.1 m/s² per axis (1σ), held in five random attitudes.
        // `g₀ uᵀ S u` reaches 0.3 m/s²: the bias read from the poses with the sensitivity left out
        // is far outside its covariance, and inside it 95 % of the time with it in the model.
        let mut rng = flight::rng::Rng::new(7);
        let chi2 = f64::from(crate::CHI2_3DOF_95);
        let (mut inside_with, mut inside_without, mut trials) = (0u32, 0u32, 0u32);
        for _ in 0..200 {
            let s = Matrix3::from_fn(|i, j| {
                let bound = if i == j { 0.03 } else { 0.02 };
                rng.range(-bound, bound) as f32
            });
            let b = Vector3::from_fn(|_, _| 0.1 * rng.normal() as f32);
            let mut detector = RestDetector::new(2000.0, G);
            let mut poses = RestPoses::new();
            for _ in 0..5 {
                rest_scaled(&mut detector, rng.unit_vector().cast::<f32>(), &s, b, 0.4);
                // A pose reading more than REST_MAX_DEVIATION_MPS2 off g is no rest.
                if let Some(pose) = detector.end() {
                    poses.push(pose);
                }
            }
            if poses.as_slice().len() < 4 {
                continue;
            }
            trials += 1;
            let exact = Config::default().with_scale_tolerance(0.0);
            for (config, inside) in
                [(Config::default(), &mut inside_with), (exact, &mut inside_without)]
            {
                let model = poses.model(&config);
                let info = model.bias_information(&Vector3::<f64>::zeros()).expect("poses");
                let covariance = info.information.try_inverse().expect("five attitudes");
                let error = covariance * info.rhs - b.map(f64::from);
                *inside += u32::from(error.dot(&(info.information * error)) <= chi2);
            }
        }
        let (with, without) = (
            f64::from(inside_with) / f64::from(trials),
            f64::from(inside_without) / f64::from(trials),
        );
        std::eprintln!(
            "{trials} accelerometers: bias inside its 95 % ellipsoid {:.1} % with the \
             sensitivity modelled, {:.1} % without",
            100.0 * with,
            100.0 * without
        );
        assert!(trials >= 150, "{trials} sessions with four poses or more");
        assert!((0.9..=0.995).contains(&with), "inside with the sensitivity modelled: {with}");
        assert!(without < 0.5, "inside with it left out: {without}");
    }

    #[test]
    fn a_short_rest_or_a_moving_craft_gives_no_pose() {
        let mut detector = RestDetector::new(2000.0, G);
        // 0.2 s = 4 blocks: 2 kept after trimming, fewer than 3.
        rest(&mut detector, Vector3::new(0.0, 0.0, -1.0), Vector3::zeros(), 0.2);
        assert_eq!(detector.end(), None);
        // Turning at 0.5 rad/s is not rest.
        for index in 0..2000 {
            let s = AlignedSample {
                index,
                gyro_radps: Vector3::new(0.5, 0.0, 0.0),
                gyro_dot_radps2: Vector3::zeros(),
                acc_mps2: Vector3::new(0.0, 0.0, -G),
            };
            assert_eq!(detector.update(&s), None);
        }
        assert_eq!(detector.end(), None);
    }
}
