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

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

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
        }
    }
}

impl RestModel<'_> {
    /// The rest equations linearised about the bias `b0` (the neglected term is then of second
    /// order in `b − b0`), `δg` profiled out under its prior; `None` without poses.
    ///
    /// Pose `k`: `|f_k − b| = g₀ + δg` ≈ `|f_k − b0| − u_kᵀ (b − b0)`, `u_k = (f_k − b0)/|f_k − b0|`,
    /// so `u_kᵀ b + δg = |f_k − b0| + u_kᵀ b0 − g₀` with weight `1/σ_k²`.
    pub(crate) fn bias_information<T: Scalar>(
        &self,
        b0: &Vector3<T>,
    ) -> Option<BiasInformation<T>> {
        if self.poses.is_empty() {
            return None;
        }
        let mut information = Matrix4::<T>::zeros();
        let mut rhs = Vector4::<T>::zeros();
        for pose in self.poses {
            let f = pose.up_imu.map(T::from) * T::from(pose.specific_force_mps2);
            let relative = f - b0;
            let norm = relative.norm();
            let u = relative / norm;
            let w = Vector4::new(u.x, u.y, u.z, T::one());
            let weight = T::one() / T::from(pose.sigma_mps2 * pose.sigma_mps2);
            let y = norm + u.dot(b0) - T::from(self.gravity_mps2);
            information += w * w.transpose() * weight;
            rhs += w * (y * weight);
        }
        let s = T::from(self.gravity_sigma_mps2);
        let gg = information[(3, 3)] + T::one() / (s * s);
        let bg: Vector3<T> = information.fixed_view::<3, 1>(0, 3).into_owned();
        let bb: Matrix3<T> = information.fixed_view::<3, 3>(0, 0).into_owned();
        let hb: Vector3<T> = rhs.fixed_rows::<3>(0).into_owned();
        let information = bb - bg * bg.transpose() / gg;
        let rhs = hb - bg * (rhs[3] / gg);
        let finite = information.iter().chain(rhs.iter()).all(|v| v.is_finite());
        finite.then_some(BiasInformation { information, rhs })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const G: f32 = 9.80665;

    /// Rest samples in attitude `up` (unit vector) with bias `b`, for `seconds` at `rate_hz`.
    fn rest(detector: &mut RestDetector, up: Vector3<f32>, b: Vector3<f32>, seconds: f32) {
        let rate_hz = 2000.0;
        let n = (seconds * rate_hz) as u32;
        for index in 0..n {
            let s = AlignedSample {
                index,
                gyro_radps: Vector3::zeros(),
                gyro_dot_radps2: Vector3::zeros(),
                acc_mps2: up * G + b,
            };
            assert_eq!(detector.update(&s), None);
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
        let model =
            RestModel { poses: poses.as_slice(), gravity_mps2: G, gravity_sigma_mps2: 0.03 };
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
