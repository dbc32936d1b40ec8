//! Tests of the IMU-offset estimator on synthetic throws (`flight::testing::throws`): physical
//! checks in millimetres and degrees against the simulated truth.
//!
//! Run with `cargo test -p imu-offset -- --nocapture` to see the measured figures.

extern crate std;

use std::vec::Vec;
use std::{eprintln, vec};

use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;

use super::*;
use flight::rng::Rng;
use flight::testing::throws::ThrowSpec;

/// Principal axes of the simulated craft, rotated away from the IMU axes (as when the flight
/// controller is mounted at an angle), so that "the right axis" is not trivially an IMU axis.
/// The estimator configured for these tests' IMU, whose sensitivity is exact (`ThrowSpec` scales
/// nothing): the figures asserted here are then the throws' geometry's, the noise's, the bias's
/// and the drag's. The defaults' sensitivity priors are tested on the simulator's IMU, which has
/// the errors (`tests/tests/imu_offset_calibration.rs`).
fn synthetic_imu() -> Config {
    Config::default().with_scale_tolerance(0.0)
}

fn principal_axes() -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(0.35, -0.25, 0.6)
}

/// A principal axis (0, 1, 2 = smallest to largest inertia) in IMU coordinates.
fn principal_axis(k: usize) -> Vector3<f64> {
    principal_axes() * Vector3::ith(k, 1.0)
}

fn r_true() -> Vector3<f64> {
    // The seed paper's vehicle: r ≈ (−10, −13, 8) mm.
    Vector3::new(-0.010, -0.013, 0.008)
}

/// A spin of `rate_radps` mostly about principal axis `k`, with `wobble` of it about the others
/// (which makes the body nutate, so Ω̇ ≠ 0).
fn spin_about(k: usize, rate_radps: f64, wobble: f64) -> Vector3<f64> {
    let others = principal_axis((k + 1) % 3) + principal_axis((k + 2) % 3) * 0.7;
    (principal_axis(k) + others * wobble).normalize() * rate_radps
}

fn samples(spec: &ThrowSpec) -> Vec<ImuSample> {
    spec.samples().collect()
}

fn throw(rate_hz: f64, release_rate: Vector3<f64>, seed: u64) -> ThrowSpec {
    ThrowSpec::typical(rate_hz, r_true(), principal_axes(), release_rate, seed)
}

/// Two throws in one stream (the craft is held between them).
fn two_throws(rate_hz: f64, seed: u64) -> Vec<ImuSample> {
    let mut all = samples(&throw(rate_hz, spin_about(2, 12.0, 0.25), seed));
    all.extend(samples(&throw(rate_hz, spin_about(0, 9.0, 0.25), seed + 1)));
    all
}

fn stream_fit(samples: &[ImuSample], rate_hz: f64, config: Config) -> ImuOffsetEstimator {
    let mut est = ImuOffsetEstimator::new(rate_hz as f32, config).unwrap();
    for s in samples {
        est.update(s).unwrap();
    }
    est.finish();
    est
}

fn batch_fit(logs: &[&[ImuSample]], rate_hz: f64, config: Config) -> BatchFitter {
    let mut fitter = BatchFitter::new(config);
    for log in logs {
        fitter.add_log(log, rate_hz as f32).unwrap();
    }
    fitter
}

fn mm(v: f64) -> f64 {
    v * 1000.0
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    // Directions: the sign of an axis is arbitrary.
    let c = (a.dot(b) / (a.norm() * b.norm())).abs().min(1.0);
    libm::acos(c).to_degrees()
}

#[test]
fn segments_cover_the_free_fall_and_exclude_the_hand() {
    for rate_hz in [500.0, 2000.0, 8000.0] {
        let spec = throw(rate_hz, spin_about(2, 12.0, 0.25), 7);
        let est = stream_fit(&samples(&spec), rate_hz, synthetic_imu());
        let segments = est.segments();
        assert_eq!(segments.len(), 1, "{rate_hz} Hz: one throw, one segment");
        let seg = segments[0];
        let release = spec.release_index() as u32;
        let catch = spec.catch_index() as u32;
        let ms = |samples: u32| f64::from(samples) * 1000.0 / rate_hz;
        let (after_release_ms, before_catch_ms) =
            (ms(seg.start_index.saturating_sub(release)), ms(catch.saturating_sub(seg.end_index)));
        eprintln!(
            "{rate_hz} Hz: segment starts {after_release_ms:.1} ms after the release and ends \
             {before_catch_ms:.1} ms before the catch"
        );
        // At least 10 ms clear of the hand at both ends (the filtered signal is causal, so
        // samples before the catch carry no trace of it).
        let margin = (0.01 * rate_hz) as u32;
        assert!(seg.start_index >= release + margin, "{rate_hz} Hz: starts in the hand");
        assert!(seg.end_index + margin <= catch, "{rate_hz} Hz: ends in the hand");
        let used_s = f64::from(seg.len()) / rate_hz;
        assert!(used_s > 0.4, "{rate_hz} Hz: only {used_s} s of a 0.6 s free fall used");
    }
}

#[test]
fn two_throws_about_different_axes_give_r_within_1mm() {
    for (rate_hz, seed) in [(500.0, 11), (1000.0, 12), (2000.0, 13), (8000.0, 14)] {
        let data = two_throws(rate_hz, seed);
        let stream = stream_fit(&data, rate_hz, synthetic_imu());
        assert_eq!(stream.segments().len(), 2);
        let board = stream.estimate().unwrap();
        let host = batch_fit(&[&data], rate_hz, synthetic_imu()).estimate().unwrap();
        let err_board = mm((board.r_imu_m.cast::<f64>() - r_true()).norm());
        let err_host = mm((host.r_imu_m - r_true()).norm());
        eprintln!(
            "{rate_hz} Hz two throws: error {err_host:.3} mm (host f64), {err_board:.3} mm \
             (board f32); 95 % semi-axes {:.3?} mm; variance inflation {:.1}",
            host.ellipsoid.semi_axes_m.map(mm),
            host.variance_inflation
        );
        assert!(err_host < 1.0, "{rate_hz} Hz: r off by {err_host} mm");
        assert!(err_board < 1.0, "{rate_hz} Hz: r off by {err_board} mm");
        assert!(host.verdict.is_well_determined(), "{rate_hz} Hz: {}", host.verdict);
        assert!(board.verdict.is_well_determined(), "{rate_hz} Hz: {}", board.verdict);
    }
}

#[test]
fn one_throw_about_a_principal_axis_is_flagged_with_that_axis() {
    for (k, rate) in [(2usize, 12.0), (0, 9.0)] {
        let spec = throw(2000.0, spin_about(k, rate, 0.002), 21 + k as u64);
        let est = batch_fit(&[&samples(&spec)], 2000.0, synthetic_imu()).estimate().unwrap();
        let Verdict::PoorlyDetermined { direction_imu, semi_axis_m, spin_next_about } = est.verdict
        else {
            panic!("spin about principal axis {k} not flagged: {}", est.verdict);
        };
        let angle = angle_deg(&direction_imu, &principal_axis(k));
        eprintln!(
            "one throw about principal axis {k}: flagged direction {angle:.2}° from it, \
             semi-axis {:.1} mm; advice: {}",
            mm(semi_axis_m),
            est.verdict
        );
        assert!(angle < 10.0, "flagged direction {angle}° from the spin axis");
        // The suggested IMU axis is far from the flagged direction (it can observe it).
        let suggested = match spin_next_about {
            ImuAxis::X => Vector3::x(),
            ImuAxis::Y => Vector3::y(),
            ImuAxis::Z => Vector3::z(),
        };
        assert!(angle_deg(&suggested, &direction_imu) > 45.0);
        // The spin axis is the one direction the throw cannot see: the others are known at least
        // ten times better (with the bias fitted and two rest attitudes, to a few millimetres).
        let [worst, next, _] = est.ellipsoid.semi_axes_m;
        assert!(next * 10.0 < worst && mm(next) < 5.0, "{:?}", est.ellipsoid.semi_axes_m);
    }
}

#[test]
fn recursive_equals_batch_within_0_1mm() {
    for (rate_hz, seed) in [(500.0, 31), (8000.0, 32)] {
        let data = two_throws(rate_hz, seed);
        let stream = stream_fit(&data, rate_hz, synthetic_imu());
        let batch = batch_fit(&[&data], rate_hz, synthetic_imu());
        let board = stream.estimate().unwrap();
        let host = batch.estimate().unwrap();
        assert_eq!(stream.samples_used(), batch.samples_used(), "same samples");
        let diff_mm = mm((board.r_imu_m.cast::<f64>() - host.r_imu_m).norm());
        let axes_diff = (0..3)
            .map(|i| f64::from(board.ellipsoid.semi_axes_m[i]) / host.ellipsoid.semi_axes_m[i])
            .fold(0.0f64, |m, ratio| m.max((ratio - 1.0).abs()));
        eprintln!(
            "{rate_hz} Hz: recursive f32 vs batch f64 differ by {:.5} mm; semi-axes by {:.2} %",
            diff_mm,
            100.0 * axes_diff
        );
        assert!(diff_mm < 0.1, "{rate_hz} Hz: {diff_mm} mm apart");
        assert!(axes_diff < 0.05, "{rate_hz} Hz: ellipsoids differ by {axes_diff}");
    }
}

#[test]
fn offset_rls_unit_equals_batch() {
    // The benchmarked unit alone: OffsetRls over the aligned samples of a noisy free fall.
    let spec = throw(2000.0, spin_about(1, 10.0, 0.6), 41);
    let data = samples(&spec);
    let mut front = FrontEnd::new(50.0, 2000.0).unwrap();
    let mut rls = OffsetRls::new(Vector3::zeros());
    let (lo, hi) = (spec.release_index() as u32 + 200, spec.catch_index() as u32 - 200);
    for s in &data {
        if let Some(a) = front.update(s) {
            if (lo..hi).contains(&a.index) {
                rls.update(&a);
            }
        }
    }
    let r = rls.estimate().unwrap().cast::<f64>();
    assert!(mm((r - r_true()).norm()) < 1.0, "OffsetRls off by {} mm", mm((r - r_true()).norm()));
}

fn bias() -> Vector3<f64> {
    Vector3::new(0.15, -0.10, 0.20)
}

#[test]
fn bias_is_estimated_jointly_with_the_offset() {
    let rate_hz = 2000.0;
    let config = Config { model: Model::OffsetAndAccBias, ..synthetic_imu() };
    // Tumbling throws (well off the principal axes) at different rates: the centripetal term
    // varies, so a constant bias is distinguishable from it.
    let mut a = throw(rate_hz, spin_about(2, 13.0, 0.6), 51);
    let mut b = throw(rate_hz, spin_about(0, 8.0, 0.6), 52);
    a.acc_bias_mps2 = bias();
    b.acc_bias_mps2 = bias();
    let (a, b) = (samples(&a), samples(&b));
    let joint = batch_fit(&[&a, &b], rate_hz, config).estimate().unwrap();
    let offset_only = Config { model: Model::Offset, ..synthetic_imu() };
    let plain = batch_fit(&[&a, &b], rate_hz, offset_only).estimate().unwrap();
    let err_joint = mm((joint.r_imu_m - r_true()).norm());
    let err_plain = mm((plain.r_imu_m - r_true()).norm());
    let bias_est = joint.acc_bias_mps2.unwrap();
    let err_bias = (bias_est - bias()).norm();
    eprintln!(
        "bias 0.27 m/s²: r error {err_joint:.3} mm with joint bias (bias error {err_bias:.4} m/s²), \
         {err_plain:.2} mm ignoring it; verdict: {}",
        joint.verdict
    );
    assert!(err_joint < 1.0, "joint fit: r off by {err_joint} mm");
    assert!(err_bias < 0.02, "bias off by {err_bias} m/s²");
    assert!(err_plain > err_joint, "fitting the bias should help when there is one");
    assert!(joint.verdict.is_well_determined(), "{}", joint.verdict);
}

#[test]
fn offset_only_fit_with_a_large_bias_advises_fitting_it() {
    // A 0.5 m/s² bias (a poorly calibrated accelerometer) moves the offset-only estimate by
    // millimetres. The offset-only ellipsoid must say so (contain the truth) and the verdict must
    // name the bias, not ask for more throws.
    let rate_hz = 2000.0;
    let mut a = throw(rate_hz, spin_about(2, 13.0, 0.6), 71);
    let mut b = throw(rate_hz, spin_about(0, 8.0, 0.6), 72);
    a.acc_bias_mps2 = bias().normalize() * 0.5;
    b.acc_bias_mps2 = bias().normalize() * 0.5;
    let (a, b) = (samples(&a), samples(&b));
    let offset_only = Config { model: Model::Offset, ..synthetic_imu() };
    let plain = batch_fit(&[&a, &b], rate_hz, offset_only).estimate().unwrap();
    let e = plain.r_imu_m - r_true();
    let m = e.dot(&(plain.covariance_m2.try_inverse().unwrap() * e)) / f64::from(CHI2_3DOF_95);
    eprintln!(
        "bias 0.5 m/s², offset only: error {:.2} mm, Mahalanobis²/χ² {m:.2}; {}",
        mm(e.norm()),
        plain.verdict
    );
    assert!(mm(e.norm()) > 1.0, "the bias should matter here");
    assert!(m <= 1.0, "truth outside the offset-only ellipsoid ({m:.2})");
    assert!(matches!(plain.verdict, Verdict::BiasSuspected { .. }), "{}", plain.verdict);
    assert!(std::format!("{}", plain.verdict).contains("--bias"));
}

/// Two clean spins about principal axes at the same rate, with a bias; `rest_s` of rest before
/// and after each throw.
fn equal_rate_principal_spins(rest_s: f64) -> [Vec<ImuSample>; 2] {
    let rate_hz = 2000.0;
    let mut a = throw(rate_hz, spin_about(2, 11.0, 0.0), 61);
    let mut b = throw(rate_hz, spin_about(0, 11.0, 0.0), 62);
    for spec in [&mut a, &mut b] {
        spec.acc_bias_mps2 = bias();
        spec.rest_before_s = rest_s;
        spec.rest_after_s = rest_s;
        // Caught in a new attitude: the catch turns the craft by the spin it had.
    }
    [samples(&a), samples(&b)]
}

#[test]
fn bias_and_offset_inseparable_at_one_constant_spin_rate_without_rest_poses() {
    // The centripetal term is constant in each throw and has the same size in both, so along the
    // axis perpendicular to both spins a bias and an offset look the same in free fall. Rests of
    // 0.15 s are too short for a pose (5 blocks of 50 ms are needed), so nothing else tells them
    // apart.
    let [a, b] = equal_rate_principal_spins(0.15);
    let config = Config { model: Model::OffsetAndAccBias, ..synthetic_imu() };
    let joint = batch_fit(&[&a, &b], 2000.0, config).estimate().unwrap();
    assert_eq!(joint.rest_poses, 0);
    let Verdict::BiasNotSeparable { direction_imu, semi_axis_m, .. } = joint.verdict else {
        panic!("expected bias/offset confusion, got: {}", joint.verdict);
    };
    let angle = angle_deg(&direction_imu, &principal_axis(1));
    eprintln!(
        "equal-rate principal spins: {} ({angle:.1}° from the common perpendicular)",
        joint.verdict
    );
    assert!(mm(semi_axis_m) > 2.0);
    assert!(angle < 10.0, "confused direction {angle}° from the axis perpendicular to both");
    assert_eq!(semi_axis_m, joint.ellipsoid.semi_axes_m[0], "advice and ellipsoid agree");
}

#[test]
fn rest_poses_separate_bias_and_offset() {
    // The same throws held still for 0.5 s before and after: the rest poses (two attitudes per
    // throw) measure the bias, and the offset is well determined and accurate.
    let [a, b] = equal_rate_principal_spins(0.5);
    let config = Config { model: Model::OffsetAndAccBias, ..synthetic_imu() };
    let joint = batch_fit(&[&a, &b], 2000.0, config).estimate().unwrap();
    assert_eq!(joint.rest_poses, 4);
    let error = joint.r_imu_m - r_true();
    let bias_error = joint.acc_bias_mps2.unwrap() - bias();
    eprintln!(
        "with rest poses: {}; error {:.2} mm, bias error {:.4} m/s²",
        joint.verdict,
        mm(error.norm()),
        bias_error.norm()
    );
    assert!(joint.verdict.is_well_determined(), "{}", joint.verdict);
    assert!(mm(error.norm()) < 0.5, "offset off by {:.2} mm", mm(error.norm()));
    // Three attitudes (both throws start level) leave local gravity and the bias partly
    // confounded (gravity's prior is ±0.03 m/s²): the bias is as good as its covariance says.
    let cov_b = joint.acc_bias_covariance_m2ps4.unwrap();
    let m2 = bias_error.dot(&(cov_b.try_inverse().unwrap() * bias_error));
    eprintln!("bias σ {:?} m/s², Mahalanobis² {m2:.2}", cov_b.diagonal().map(f64::sqrt));
    assert!(m2 < f64::from(CHI2_3DOF_95), "bias error {bias_error:?} outside its 95 % region");
}

#[test]
fn vertical_drag_model_removes_most_of_the_drag_error() {
    // Vertical throws (release and catch at one height, apex at mid-flight) with strong quadratic
    // drag, k = 0.05 /m (≈ 0.4 m/s² at release), and a bias, fitted jointly with the bias: with
    // drag ignored, the slowly rotating drag force biases r; the per-throw drag vector of
    // `DragModel::VerticalQuadratic` models it (the synthetic drag is isotropic, as assumed).
    let rate_hz = 1000.0;
    let mut rng = Rng::new(91);
    let (mut ignored, mut modelled) = (Vec::new(), Vec::new());
    for trial in 0..10u64 {
        let logs: Vec<Vec<ImuSample>> = [spin_about(2, 12.0, 0.4), spin_about(0, 9.0, 0.4)]
            .iter()
            .enumerate()
            .map(|(k, spin)| {
                let mut spec =
                    throw(rate_hz, *spin * rng.range(0.8, 1.2), 900 + 2 * trial + k as u64);
                spec.throw_dir_world = -Vector3::z();
                spec.drag_per_m = 0.05;
                spec.acc_bias_mps2 = bias();
                samples(&spec)
            })
            .collect();
        let logs: Vec<&[ImuSample]> = logs.iter().map(Vec::as_slice).collect();
        for (drag_model, errors) in
            [(DragModel::Ignored, &mut ignored), (DragModel::VerticalQuadratic, &mut modelled)]
        {
            let config = Config { model: Model::OffsetAndAccBias, drag_model, ..synthetic_imu() };
            let est = batch_fit(&logs, rate_hz, config).estimate().unwrap();
            errors.push(mm((est.r_imu_m - r_true()).norm()));
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (ignored, modelled) = (median(&mut ignored), median(&mut modelled));
    eprintln!(
        "k = 0.05 /m, 10 two-throw fits with bias: median error {ignored:.3} mm with drag \
               ignored, {modelled:.3} mm with the vertical drag model"
    );
    assert!(modelled < 0.5 * ignored, "{modelled} mm vs {ignored} mm");
}

/// Coverage of one set of fits: the share with the truth inside the reported 95 % ellipsoid, the
/// same for the paper's white-noise ellipsoid, and the factor the reported semi-axes would need
/// for exactly 95 % (below 1: too wide).
struct Coverage {
    reported: f64,
    paper: f64,
    axes_factor: f64,
}

/// Monte Carlo over calibration sessions of the kind a user makes (and issue 11 describes): two
/// vertical throw-and-catches, apex 0.8–1.5 m (0.81–1.11 s of free fall), 300–600 °/s about
/// random axes at least 50° apart, held still 0.6 s before and after each throw, quadratic drag
/// `k` (1/m), a constant accelerometer bias of 0.02 m/s² per axis (1σ), gyro noise 0.002 rad/s
/// and accelerometer noise 0.03 m/s² per sample, 16-bit quantisation; random offsets up to 2 cm
/// and principal axes; `horizontal_fraction` of the release speed is horizontal.
fn coverage(trials: u32, rate_hz: f64, seed: u64, drag_per_m: f64, horizontal: f64) -> Coverage {
    let chi2 = f64::from(CHI2_3DOF_95);
    let mut rng = Rng::new(seed);
    let (mut inside, mut inside_paper) = (0u32, 0u32);
    let mut normalised = Vec::new();
    for trial in 0..trials {
        // Within the detector's envelope: |r| (|Ω̇| + |Ω|²) stays below the 0.6 g ceiling.
        let r = rng.unit_vector() * rng.range(0.0, 0.02);
        let axes = UnitQuaternion::from_scaled_axis(
            rng.unit_vector() * rng.range(0.0, core::f64::consts::PI),
        );
        let spin_a = rng.unit_vector();
        let spin_b = loop {
            let v = rng.unit_vector();
            if angle_deg(&v, &spin_a) > 50.0 {
                break v;
            }
        };
        let bias = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.02;
        let seed_a = seed.wrapping_mul(1000).wrapping_add(u64::from(trial) * 2);
        let logs: Vec<Vec<ImuSample>> = [(spin_a, seed_a), (spin_b, seed_a + 1)]
            .into_iter()
            .map(|(axis, noise_seed)| {
                let rate_radps = rng.range(300.0, 600.0).to_radians();
                let mut spec = ThrowSpec::typical(rate_hz, r, axes, axis * rate_radps, noise_seed);
                let apex_m = rng.range(0.8, 1.5);
                let speed_mps = libm::sqrt(2.0 * flight::testing::throws::G_MPS2 * apex_m);
                spec.free_fall_s = 2.0 * speed_mps / flight::testing::throws::G_MPS2;
                spec.windup_peak_mps2 = 2.0 * speed_mps / spec.windup_s;
                spec.throw_dir_world = Vector3::new(horizontal, 0.0, -1.0).normalize();
                spec.drag_per_m = drag_per_m;
                spec.acc_bias_mps2 = bias;
                spec.rest_before_s = 0.6;
                spec.rest_after_s = 0.6;
                samples(&spec)
            })
            .collect();
        let est = batch_fit(&[&logs[0], &logs[1]], rate_hz, synthetic_imu()).estimate().unwrap();
        let e = est.r_imu_m - r;
        let (Some(inv), Some(inv_paper)) =
            (est.covariance_m2.try_inverse(), est.white_noise_covariance_m2.try_inverse())
        else {
            continue;
        };
        inside += u32::from(e.dot(&(inv * e)) <= chi2);
        inside_paper += u32::from(e.dot(&(inv_paper * e)) <= chi2);
        normalised.push(e.dot(&(inv * e)) / chi2);
    }
    normalised.sort_by(f64::total_cmp);
    let p95 = normalised.get(normalised.len() * 95 / 100).copied().unwrap_or(f64::NAN);
    Coverage {
        reported: f64::from(inside) / f64::from(trials),
        paper: f64::from(inside_paper) / f64::from(trials),
        axes_factor: libm::sqrt(p95),
    }
}

#[test]
fn ellipsoid_coverage_is_about_95_percent() {
    // 100 sessions per case at 2 kHz (`coverage`). The binomial standard error at 95 % is 2.2 %
    // with 100 fits; the band asserted, 90–99 %, is about ±2σ around 95 % (and excludes the
    // 100 % of an ellipsoid that is merely safe). The drag model takes out vertical quadratic
    // drag; a horizontal release speed (the third case: 0.3 of it, 17° from vertical) is not
    // modelled, and the long batches widen the ellipsoid for it. Release figures (200 sessions,
    // `cargo test -p imu-offset --release ellipsoid_coverage -- --nocapture` with `trials = 200`) are
    // in docs/benchmarks.md. The seed paper's white-noise ellipsoid is far below every case.
    let trials = 100;
    for (seed, drag_per_m, horizontal) in [(71, 0.01, 0.0), (72, 0.05, 0.0), (73, 0.03, 0.3)] {
        let c = coverage(trials, 2000.0, seed, drag_per_m, horizontal);
        eprintln!(
            "drag k = {drag_per_m} /m, horizontal {horizontal}, {trials} sessions: truth inside \
             the 95 % ellipsoid {:.1} % (axes × {:.2} for exactly 95 %), {:.1} % for the \
             paper's SE² (XᵀX)⁻¹",
            100.0 * c.reported,
            c.axes_factor,
            100.0 * c.paper
        );
        assert!((0.90..=0.99).contains(&c.reported), "coverage {}", c.reported);
        assert!(c.paper < 0.5, "the uncorrected ellipsoid should be overconfident here");
    }
}

#[test]
fn onboard_state_is_small() {
    // Constant memory: 3 KB of sums and the drag model's store of one throw's blocks
    // (`MAX_THROW_BLOCKS` × 33 f32 = 10.6 KB).
    let bytes = core::mem::size_of::<ImuOffsetEstimator>();
    eprintln!("ImuOffsetEstimator: {bytes} bytes");
    assert!(bytes < 16 * 1024, "{bytes} bytes");
    // The offline fitter keeps the throw in progress on the stack only while reading a log.
    let batch = core::mem::size_of::<BatchFitter>();
    eprintln!("BatchFitter: {batch} bytes");
    assert!(batch < 16384, "{batch} bytes");
}

#[test]
fn a_free_fall_longer_than_the_drag_store_is_counted_not_used() {
    // 1.9 s of free fall (an 4.4 m apex) outlasts the 80 blocks of 20 ms the drag model keeps:
    // the throw is counted as too long, by the board and offline alike; without the drag model
    // the same throw is used.
    let rate_hz = 2000.0;
    let mut spec = throw(rate_hz, spin_about(2, 10.0, 0.3), 85);
    spec.free_fall_s = 1.9;
    spec.windup_peak_mps2 = 2.0 * (flight::testing::throws::G_MPS2 * 0.95) / spec.windup_s;
    let data = samples(&spec);
    let board = stream_fit(&data, rate_hz, synthetic_imu());
    assert_eq!((board.segments().len(), board.throws_too_long()), (0, 1));
    let host = batch_fit(&[&data], rate_hz, synthetic_imu());
    assert!(host.segments().is_empty());
    let ignored = Config { drag_model: DragModel::Ignored, ..synthetic_imu() };
    let board = stream_fit(&data, rate_hz, ignored);
    assert_eq!((board.segments().len(), board.throws_too_long()), (1, 0));
    let used_s = board.segments()[0].len() as f64 / rate_hz;
    assert!(used_s > 1.6, "{used_s} s used");
}

#[test]
fn a_restart_in_place_forgets_the_throws_and_refuses_a_bad_configuration() {
    let rate_hz = 2000.0;
    let data = two_throws(rate_hz, 87);
    let mut est = stream_fit(&data, rate_hz, synthetic_imu());
    assert_eq!(est.segments().len(), 2);
    let fitted = est.estimate().unwrap();
    // A bad configuration changes nothing.
    let bad = Config { block_s: -1.0, ..synthetic_imu() };
    assert!(matches!(est.restart(bad), Err(ImuOffsetError::InvalidConfig(_))));
    for (scale, cross) in [(-0.01, 0.0), (0.0, 0.5), (f32::NAN, 0.0)] {
        let bad = Config { scale_error_sigma: scale, cross_axis_sigma: cross, ..synthetic_imu() };
        assert!(matches!(est.restart(bad), Err(ImuOffsetError::InvalidConfig(_))));
    }
    assert_eq!(est.segments().len(), 2);
    assert_eq!(est.estimate().unwrap().r_imu_m, fitted.r_imu_m);
    // A good one starts again: nothing learnt, and the same data give the same estimate.
    est.restart(synthetic_imu()).unwrap();
    assert!(est.segments().is_empty() && est.samples_used() == 0);
    assert_eq!(est.estimate().unwrap_err(), ImuOffsetError::NoFreeFall);
    for s in &data {
        est.update(s).unwrap();
    }
    est.finish();
    assert_eq!(est.estimate().unwrap().r_imu_m, fitted.r_imu_m);
}

#[test]
fn errors_are_typed() {
    let rate_hz = 2000.0;
    // Unsupported rate.
    assert!(matches!(
        ImuOffsetEstimator::new(100.0, synthetic_imu()),
        Err(ImuOffsetError::RateOutOfRange { .. })
    ));
    // Held still: no free fall.
    let mut still = throw(rate_hz, Vector3::zeros(), 81);
    still.windup_peak_mps2 = 0.0;
    still.free_fall_s = 0.0;
    still.catch_s = 0.0;
    let fitter = batch_fit(&[&samples(&still)], rate_hz, synthetic_imu());
    assert_eq!(fitter.estimate().unwrap_err(), ImuOffsetError::NoFreeFall);
    // Free falls cut short by an abrupt catch (held still from then on): the shortest one the
    // detector accepts is too short for an honest variance (fewer than 6 blocks of 20 ms).
    let full = throw(rate_hz, spin_about(2, 12.0, 0.3), 82);
    let release = full.release_index();
    let shortest = (10..40)
        .map(|centiseconds| {
            let cut = release + centiseconds * rate_hz as usize / 100;
            let mut data = samples(&full);
            for s in data.iter_mut().skip(cut) {
                *s = ImuSample {
                    gyro_radps: Vector3::zeros(),
                    acc_mps2: Vector3::new(0.0, 0.0, -9.81),
                };
            }
            batch_fit(&[&data], rate_hz, synthetic_imu())
        })
        .find(|fitter| !fitter.segments().is_empty())
        .unwrap();
    let result = shortest.estimate();
    assert!(matches!(result, Err(ImuOffsetError::TooFewSamples { .. })), "{result:?}");
    // A log shorter than any throw.
    let mut fitter = BatchFitter::new(synthetic_imu());
    let tiny = &samples(&still)[..10];
    assert!(matches!(fitter.add_log(tiny, 2000.0), Err(ImuOffsetError::TooFewSamples { .. })));
    // NaN input: typed error with the sample index, from both estimators.
    let mut data = samples(&throw(rate_hz, spin_about(2, 12.0, 0.3), 83));
    data[1234].acc_mps2.y = f32::NAN;
    let mut fitter = BatchFitter::new(synthetic_imu());
    assert_eq!(
        fitter.add_log(&data, 2000.0).unwrap_err(),
        ImuOffsetError::NonFiniteInput { index: 1234 }
    );
    let mut est = ImuOffsetEstimator::new(2000.0, synthetic_imu()).unwrap();
    let errors: Vec<_> = data.iter().filter_map(|s| est.update(s).err()).collect();
    assert_eq!(errors, vec![ImuOffsetError::NonFiniteInput { index: 1234 }]);
    // Logs at different rates are not pooled.
    let mut fitter = BatchFitter::new(synthetic_imu());
    fitter.add_log(&data[..2000], 2000.0).unwrap_err();
    let ok = samples(&throw(1000.0, spin_about(2, 12.0, 0.3), 84));
    fitter.add_log(&ok, 1000.0).unwrap();
    assert!(matches!(fitter.add_log(&ok, 2000.0), Err(ImuOffsetError::RateMismatch { .. })));
}

fn any_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => -50.0f32..50.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => prop::num::f32::ANY,
        1 => Just(0.0f32),
    ]
}

fn any_sample() -> impl Strategy<Value = ImuSample> {
    prop::array::uniform6(any_value()).prop_map(|v| ImuSample {
        gyro_radps: Vector3::new(v[0], v[1], v[2]),
        acc_mps2: Vector3::new(v[3], v[4], v[5]),
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Arbitrary input (finite, huge, NaN, ∞) never panics: every outcome is a value or a typed
    /// error, and any estimate produced is finite.
    #[test]
    fn never_panics(samples in prop::collection::vec(any_sample(), 0..3000), rate in 400.0f32..9000.0) {
        if let Ok(mut est) = ImuOffsetEstimator::new(rate, synthetic_imu()) {
            for s in &samples {
                let _ = est.update(s);
            }
            est.finish();
            if let Ok(e) = est.estimate() {
                prop_assert!(e.r_imu_m.iter().all(|v| v.is_finite()));
            }
        }
        for drag_model in [DragModel::Ignored, DragModel::VerticalQuadratic] {
            let config = Config { model: Model::OffsetAndAccBias, drag_model, ..synthetic_imu() };
            let mut fitter = BatchFitter::new(config);
            let _ = fitter.add_log(&samples, rate);
            if let Ok(e) = fitter.estimate() {
                prop_assert!(e.r_imu_m.iter().all(|v| v.is_finite()));
            }
        }
    }

    /// Free-fall-like random rotation data (no hand phases at all): still no panic, and any
    /// estimate is finite.
    #[test]
    fn never_panics_on_tumbling_noise(seed in any::<u64>(), n in 0usize..4000) {
        let mut rng = Rng::new(seed);
        let samples: Vec<ImuSample> = (0..n)
            .map(|_| ImuSample {
                gyro_radps: (rng.unit_vector() * rng.range(0.0, 20.0)).cast(),
                acc_mps2: (rng.unit_vector() * rng.range(0.0, 2.0)).cast(),
            })
            .collect();
        for (model, drag_model) in [
            (Model::Offset, DragModel::Ignored),
            (Model::Offset, DragModel::VerticalQuadratic),
            (Model::OffsetAndAccBias, DragModel::VerticalQuadratic),
        ] {
            let mut fitter = BatchFitter::new(Config { model, drag_model, ..synthetic_imu() });
            let _ = fitter.add_log(&samples, 1000.0);
            if let Ok(e) = fitter.estimate() {
                prop_assert!(e.r_imu_m.iter().all(|v| v.is_finite()));
                prop_assert!(e.ellipsoid.semi_axes_m.iter().all(|v| v.is_finite()));
            }
        }
    }
}

/// One calibration session as the board sees it (`flight::testing::throws::session`): held still
/// 0.6 s, thrown spinning at `rate_radps` about `spins[0]`, caught, held still 1.2 s in the
/// attitude the catch left, thrown at the same rate about `spins[1]`, caught, held still 0.6 s.
/// Vertical throws to a 1 m apex (0.9 s of free fall), quadratic drag k = 0.01 /m, the craft's
/// principal axes `axes`, IMU offset `r`, accelerometer bias `bias`; the session starts in
/// `attitude`. Returns the stream and the index of the first sample after the second catch.
fn equal_rate_session(
    r: Vector3<f64>,
    axes: UnitQuaternion<f64>,
    spins: [Vector3<f64>; 2],
    rate_radps: f64,
    bias: Vector3<f64>,
    attitude: UnitQuaternion<f64>,
    seed: u64,
) -> (Vec<ImuSample>, usize) {
    let specs: Vec<ThrowSpec> = spins
        .iter()
        .enumerate()
        .map(|(k, axis)| {
            let mut spec =
                ThrowSpec::typical(2000.0, r, axes, axis.normalize() * rate_radps, seed + k as u64);
            let speed_mps = libm::sqrt(2.0 * flight::testing::throws::G_MPS2 * 1.0);
            spec.free_fall_s = 2.0 * speed_mps / flight::testing::throws::G_MPS2;
            spec.windup_peak_mps2 = 2.0 * speed_mps / spec.windup_s;
            spec.throw_dir_world = -Vector3::z();
            spec.acc_bias_mps2 = bias;
            spec.initial_attitude = attitude;
            spec.rest_before_s = 0.6;
            spec.rest_after_s = 0.6;
            spec
        })
        .collect();
    let after_second_catch = specs[0].len()
        + specs[1].catch_index()
        + libm::round(specs[1].catch_s * specs[1].rate_hz) as usize;
    (flight::testing::throws::session(&specs), after_second_catch)
}

/// The board's estimator over `data`: its estimate when the second throw is accepted (the catch,
/// when the board reports the throw) and at the end (the rest after the catch in progress).
fn onboard_at_catch_and_end(data: &[ImuSample]) -> (Estimate<f32>, Estimate<f32>) {
    let mut est = ImuOffsetEstimator::new(2000.0, synthetic_imu()).unwrap();
    let mut at_catch = None;
    for s in data {
        if let Ok(Some(_)) = est.update(s) {
            if est.segments().len() == 2 {
                at_catch = est.estimate().ok();
            }
        }
    }
    assert_eq!(est.segments().len(), 2, "both throws detected");
    (at_catch.expect("an estimate at the second catch"), est.estimate().unwrap())
}

fn normalised_mahalanobis(e: &Estimate<f64>, truth: &Vector3<f64>) -> f64 {
    let error = e.r_imu_m - truth;
    error.dot(&(e.covariance_m2.try_inverse().unwrap() * error)) / f64::from(CHI2_3DOF_95)
}

#[test]
fn two_equal_rate_throws_with_a_bias_conclude_onboard_as_offline() {
    // Issue 28: 40 sessions of two throws at one spin rate (300–600 °/s) about random axes at
    // least 50° apart, a 0.1 m/s² accelerometer bias in a random direction, random offsets up to
    // 2 cm and principal axes, the craft held still before, between and after. The board's f32
    // estimator on the stream, once the craft rests after the second catch, gives what
    // `fit imu-offset` (BatchFitter, f64) gives on a recording of the same stream: the same
    // verdict, the same offset and ellipsoid; it concludes, within a millimetre of the truth,
    // and the truth lies inside the 95 % ellipsoid about as often as it says.
    let sessions = 40u32;
    let mut rng = Rng::new(280);
    let (mut inside, mut concluded) = (0u32, 0u32);
    let mut normalised = Vec::new();
    let mut errors_mm = Vec::new();
    for session in 0..sessions {
        let r = rng.unit_vector() * rng.range(0.0, 0.02);
        let axes = UnitQuaternion::from_scaled_axis(
            rng.unit_vector() * rng.range(0.0, core::f64::consts::PI),
        );
        let first = rng.unit_vector();
        let second = loop {
            let v = rng.unit_vector();
            if angle_deg(&v, &first) > 50.0 {
                break v;
            }
        };
        let rate = rng.range(300.0, 600.0).to_radians();
        let bias = rng.unit_vector() * 0.1;
        let (data, _) = equal_rate_session(
            r,
            axes,
            [first, second],
            rate,
            bias,
            UnitQuaternion::identity(),
            2800 + 2 * u64::from(session),
        );
        let (_, board) = onboard_at_catch_and_end(&data);
        let host = batch_fit(&[&data], 2000.0, synthetic_imu()).estimate().unwrap();
        let apart_mm = mm((board.r_imu_m.cast::<f64>() - host.r_imu_m).norm());
        let axes_ratio = (0..3)
            .map(|i| f64::from(board.ellipsoid.semi_axes_m[i]) / host.ellipsoid.semi_axes_m[i])
            .fold(0.0f64, |m, ratio| m.max((ratio - 1.0).abs()));
        assert!(apart_mm < 0.01, "session {session}: board and host {apart_mm} mm apart");
        assert!(axes_ratio < 0.01, "session {session}: semi-axes differ by {axes_ratio}");
        assert_eq!(
            board.verdict.is_well_determined(),
            host.verdict.is_well_determined(),
            "session {session}: board {} / host {}",
            board.verdict,
            host.verdict
        );
        assert_eq!(board.rest_poses, 3, "before, between and after the throws");
        let error_mm = mm((host.r_imu_m - r).norm());
        assert!(error_mm < 1.0, "session {session}: offset off by {error_mm:.3} mm");
        errors_mm.push(error_mm);
        concluded += u32::from(board.verdict.is_well_determined());
        let m = normalised_mahalanobis(&host, &r);
        inside += u32::from(m <= 1.0);
        normalised.push(m);
    }
    normalised.sort_by(f64::total_cmp);
    errors_mm.sort_by(f64::total_cmp);
    let coverage = f64::from(inside) / f64::from(sessions);
    let axes_factor = libm::sqrt(normalised[normalised.len() * 95 / 100]);
    eprintln!(
        "{sessions} equal-rate sessions, bias 0.1 m/s²: concluded {concluded}, error median \
         {:.3} mm / worst {:.3} mm, truth inside the 95 % ellipsoid {:.1} % (axes × {axes_factor:.2} \
         for exactly 95 %)",
        errors_mm[errors_mm.len() / 2],
        errors_mm[errors_mm.len() - 1],
        100.0 * coverage
    );
    assert_eq!(concluded, sessions, "two throws and their rests are enough");
    // Honest: 95 % − 2σ of the binomial spread over 40 sessions is 88 %; not merely safe either
    // (an ellipsoid more than twice too wide would be inside in every session at axes × < 0.5).
    assert!(coverage >= 0.875, "truth inside the ellipsoid in {:.1} %", 100.0 * coverage);
    assert!(axes_factor > 0.5, "ellipsoid {:.1}× too wide", 1.0 / axes_factor);
}

#[test]
fn the_rest_after_the_catch_separates_what_two_equal_spins_and_one_attitude_cannot() {
    // The hard case of issue 28: the first throw spins about the principal axis that is vertical
    // (a yaw spin: the catch leaves the craft level, so the rests before and after it are one
    // attitude), the second about another principal axis at the same rate. Until the craft rests
    // after the second catch, bias and offset are inseparable along the cross product of the
    // spin axes: free fall sees `ω² r + b` there in both throws, and neither rest attitude looks
    // along it. The rest after the catch (tilted by the second spin) measures the bias there.
    let axes = principal_axes();
    let level_yaw = UnitQuaternion::rotation_between(&principal_axis(2), &Vector3::z()).unwrap();
    let rate = 11.0;
    let spins = [principal_axis(2), principal_axis(0)];
    let (data, after_catch) =
        equal_rate_session(r_true(), axes, spins, rate, bias().normalize() * 0.1, level_yaw, 290);
    let (at_catch, board) = onboard_at_catch_and_end(&data);
    let Verdict::BiasNotSeparable { direction_imu, .. } = at_catch.verdict else {
        panic!("expected bias and offset confused at the second catch: {}", at_catch.verdict);
    };
    let cross = principal_axis(2).cross(&principal_axis(0));
    let angle = angle_deg(&direction_imu.cast(), &cross);
    assert!(angle < 15.0, "confused direction {angle:.1}° from the spins' cross product");
    assert_eq!(at_catch.rest_poses, 2, "before and after the yaw spin, both level");
    // Offline, a recording cut at the catch says the same; with the rest after it, both conclude.
    let cut = batch_fit(&[&data[..after_catch]], 2000.0, synthetic_imu()).estimate().unwrap();
    assert!(matches!(cut.verdict, Verdict::BiasNotSeparable { .. }), "{}", cut.verdict);
    let host = batch_fit(&[&data], 2000.0, synthetic_imu()).estimate().unwrap();
    eprintln!(
        "yaw spin then roll at {rate} rad/s: at the catch {} ({angle:.1}° from the cross \
         product); after the rest {}",
        at_catch.verdict, board.verdict
    );
    assert!(board.verdict.is_well_determined(), "{}", board.verdict);
    assert!(host.verdict.is_well_determined(), "{}", host.verdict);
    assert_eq!(board.rest_poses, 3);
    let error_mm = mm((board.r_imu_m.cast::<f64>() - r_true()).norm());
    assert!(error_mm < 1.0, "offset off by {error_mm:.3} mm");
    // Not asserted here: whether the truth is inside this one ellipsoid. Spins about principal
    // axes keep `X` constant within each throw, so any constant force the drag model leaves out
    // reads as bias or offset and no batch mean sees it: on 60 such sessions (yaw first, random
    // offsets and rates) with k = 0.01 /m the truth was inside in 70 %, missed by hundredths of
    // a millimetre (semi-axes of 0.03–0.2 mm); without drag in 98 % (issue 28 report).
}
