//! Issue 3 on the project's simulator: how accurate is the IMU offset fitted from two throws, and
//! does the reported 95 % ellipsoid contain the truth about 95 % of the time?
//!
//! A Monte Carlo of two-throw fits on `sim` (rigid-body physics at 8 kHz, anisotropic linear and
//! quadratic drag, the ICM-42688-P noise, bias and quantisation, 8 kHz averaged to 2 kHz): each fit
//! throws one airframe twice, with random spin axes at least 60° apart, random rates of
//! 400–800 °/s, random apex heights and noise seeds, and fits the offset with
//! `imu_offset::BatchFitter` (the configurator's fitter) four ways: offset only, jointly
//! with an accelerometer bias, and each of these with the per-throw drag model
//! (`DragModel::VerticalQuadratic`, the default of `fit imu-offset` and the board). Recorded per model: the error distribution (median and 95th percentile,
//! mm), the coverage of the reported 95 % ellipsoid, and the coverage of the seed paper's
//! white-noise ellipsoid (`white_noise_covariance_m2`), for comparison.
//!
//! Run `cargo test -p tests --test imu_offset_coverage -- --nocapture` to see the table;
//! `IMU_OFFSET_COVERAGE_FITS=<n>` changes the number of fits (default 200),
//! `IMU_OFFSET_COVERAGE_HORIZONTAL_MPS=<v>` adds a horizontal release velocity of up to `v` m/s in
//! a random direction (default 0: vertical throws, which the drag model assumes). The assertions
//! are made for the defaults; with other settings the printed table is the result.

use std::f64::consts::TAU;
use std::sync::atomic::{AtomicUsize, Ordering};

use firmware::app::hal::{Imu, Motors};
use imu_offset::{BatchFitter, Config, DragModel, Estimate, ImuSample, Model, CHI2_3DOF_95};
use nalgebra::{Matrix3, Vector3};
use sim::airframe::Airframe;
use sim::rng::Rng;
use sim::scenario::{self, FlightApp, ScenarioConfig, ScenarioKind};

/// The simulator's IMU rate as the application sees it (2 kHz: 8 kHz averaged in fours).
const RATE_HZ: f32 = 2000.0;

/// Airframes of the run: the seed paper's quad (r = 18 mm, drag ≈ 0.3 m/s² at release) and the
/// 3-inch quad (r = 6.4 mm, 0.18 kg: drag ≈ 0.8 m/s² at release, relatively twice as large).
const AIRFRAMES: [&str; 2] = ["paper-quad", "quad-3in"];

/// Reads every IMU sample into memory, commands nothing.
#[derive(Default)]
struct Recorder(Vec<ImuSample>);

impl FlightApp for Recorder {
    fn step<I: Imu, M: Motors>(&mut self, _now_us: u64, imu: &mut I, _motors: &mut M) {
        if let Some(s) = imu.read() {
            self.0.push(ImuSample {
                gyro_radps: Vector3::from(s.gyro_rad_s),
                acc_mps2: Vector3::from(s.accel_mps2),
            });
        }
    }
}

/// One simulated throw-and-catch: the IMU samples of the whole run.
fn throw(
    airframe: &Airframe,
    rate_body_rad_s: Vector3<f64>,
    apex_m: f64,
    seed: u64,
) -> Vec<ImuSample> {
    let mut config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
    config.throw_rate_body_rad_s = rate_body_rad_s;
    config.throw_apex_m = apex_m;
    // Shortened holds (the detector needs only a few filter time constants of hand around the
    // flight), so that 400 throws fit the time budget.
    config.hold_before_s = 0.15;
    config.after_catch_s = 0.1;
    config.board.seed = seed;
    // Optional horizontal release velocity: up to `max_horizontal_mps()` in a random direction.
    let mut rng = Rng::new(seed ^ 0x40_12);
    let (speed, heading) = (rng.range(0.0, max_horizontal_mps()), rng.range(0.0, TAU));
    config.throw_horizontal_mps = [speed * heading.cos(), speed * heading.sin()];
    let mut recorder = Recorder::default();
    scenario::run::<_, std::io::Sink>(airframe, &config, &mut recorder, None, &mut |_, _| {})
        .expect("the scenario runs");
    recorder.0
}

/// `IMU_OFFSET_COVERAGE_HORIZONTAL_MPS`: largest horizontal release speed (m/s), default 0
/// (vertical throws, caught at release height, as the calibration procedure asks).
fn max_horizontal_mps() -> f64 {
    std::env::var("IMU_OFFSET_COVERAGE_HORIZONTAL_MPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|v: &f64| v.is_finite() && *v >= 0.0)
        .unwrap_or(0.0)
}

fn unit(rng: &mut Rng) -> Vector3<f64> {
    Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize()
}

/// The two spin vectors (body axes, rad/s) of fit `seed`: random axes at least 60° apart, random
/// rates of 400–800 °/s.
fn spins(rng: &mut Rng) -> [Vector3<f64>; 2] {
    let a = unit(rng);
    let b = loop {
        let b = unit(rng);
        if a.dot(&b).abs() <= 0.5 {
            break b;
        }
    };
    [a, b].map(|axis| axis * rng.range(400.0, 800.0).to_radians())
}

/// `(r̂ − r)ᵀ Σ⁻¹ (r̂ − r) / χ²₃(0.95)`: at most 1 when the truth lies inside the 95 % ellipsoid.
fn normalised_mahalanobis(error: &Vector3<f64>, covariance: &Matrix3<f64>) -> f64 {
    let inv = covariance.try_inverse().unwrap_or_else(Matrix3::zeros);
    error.dot(&(inv * error)) / f64::from(CHI2_3DOF_95)
}

/// One model's result in one fit.
#[derive(Clone, Copy, Debug)]
struct Outcome {
    error_mm: f64,
    /// Normalised Mahalanobis² of the truth in the reported ellipsoid.
    reported: f64,
    /// The same in the seed paper's white-noise ellipsoid.
    white: f64,
}

impl Outcome {
    fn new(estimate: &Estimate<f64>, truth: &Vector3<f64>) -> Self {
        let error = estimate.r_imu_m - truth;
        Self {
            error_mm: error.norm() * 1e3,
            reported: normalised_mahalanobis(&error, &estimate.covariance_m2),
            white: normalised_mahalanobis(&error, &estimate.white_noise_covariance_m2),
        }
    }
}

/// The fitted models, in the order of [`MODELS`].
const MODELS: [(&str, Model, DragModel); 4] = [
    ("offset", Model::Offset, DragModel::Ignored),
    ("bias", Model::OffsetAndAccBias, DragModel::Ignored),
    ("drag", Model::Offset, DragModel::VerticalQuadratic),
    ("bias+drag", Model::OffsetAndAccBias, DragModel::VerticalQuadratic),
];

#[derive(Clone, Copy, Debug)]
struct Fit {
    airframe: usize,
    outcomes: [Outcome; MODELS.len()],
}

fn fit_one(index: u64, airframes: &[Airframe]) -> Fit {
    let seed = 0x1A0_0FF5 + index;
    let mut rng = Rng::new(seed);
    let which = index as usize % airframes.len();
    let airframe = &airframes[which];
    let truth = airframe.q_imu_body() * airframe.r_imu_m();
    let logs: Vec<Vec<ImuSample>> = spins(&mut rng)
        .iter()
        .enumerate()
        .map(|(k, spin)| throw(airframe, *spin, rng.range(0.8, 1.2), seed * 2 + k as u64))
        .collect();
    let fit = |(_, model, drag_model): (&str, Model, DragModel)| {
        // These airframes' IMUs scale exactly, and the fit is told so: the figures here are the
        // physics' (drag, noise, bias); the defaults' sensitivity priors are tested on IMUs that
        // have the errors (`imu_offset_calibration.rs`).
        let exact_imu = Config::default().with_scale_tolerance(0.0);
        let mut fitter = BatchFitter::new(Config { model, drag_model, ..exact_imu });
        for log in &logs {
            let found = fitter.add_log(log, RATE_HZ).expect("a valid log");
            assert_eq!(found, 1, "fit {index}: one free fall per throw, found {found}");
        }
        let estimate = fitter.estimate().expect("two spinning throws give an estimate");
        Outcome::new(&estimate, &truth)
    };
    Fit { airframe: which, outcomes: MODELS.map(fit) }
}

/// Largest |specific force| (m/s²) an airframe's IMU can feel in free fall at `rate_rad_s`: the
/// rotational terms `|r| (|Ω̇| + |Ω|²)` with the torque-free `|Ω̇| ≤ (λmax − λmin)/(2 λmin) |Ω|²`
/// (Euler's equations: `IΩ̇ = −Ω × (I − λ̄)Ω`), plus drag at the release speed of a 1.2 m throw and
/// the accelerometer bias.
fn free_fall_envelope_mps2(airframe: &Airframe, rate_rad_s: f64) -> f64 {
    let eig = airframe.inertia_matrix().symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    let omega_dot = (hi - lo) / (2.0 * lo) * rate_rad_s.powi(2);
    let rotational = airframe.r_imu_m().norm() * (omega_dot + rate_rad_s.powi(2));
    let v = (2.0 * 9.80665 * 1.2f64).sqrt();
    let drag = &airframe.drag;
    let worst = (0..3)
        .map(|i| drag.linear_n_per_mps[i] * v + drag.quadratic_n_per_mps2[i] * v * v)
        .fold(0.0, f64::max);
    let bias = Vector3::from(airframe.imu.accel.bias_mps2).norm();
    rotational + worst / airframe.mass_kg + bias
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

struct Summary {
    median_mm: f64,
    p95_mm: f64,
    coverage: f64,
    white_coverage: f64,
    /// Factor the reported semi-axes would need for exactly 95 % coverage (< 1: too wide).
    calibration: f64,
}

fn summarise(outcomes: &[Outcome]) -> Summary {
    let mut errors: Vec<f64> = outcomes.iter().map(|o| o.error_mm).collect();
    errors.sort_by(f64::total_cmp);
    let n = outcomes.len() as f64;
    let mut reported: Vec<f64> = outcomes.iter().map(|o| o.reported).collect();
    reported.sort_by(f64::total_cmp);
    Summary {
        calibration: percentile(&reported, 0.95).sqrt(),
        median_mm: percentile(&errors, 0.5),
        p95_mm: percentile(&errors, 0.95),
        coverage: outcomes.iter().filter(|o| o.reported <= 1.0).count() as f64 / n,
        white_coverage: outcomes.iter().filter(|o| o.white <= 1.0).count() as f64 / n,
    }
}

#[test]
fn two_throw_fits_on_the_simulator_are_accurate_and_their_ellipsoids_cover_the_truth() {
    let airframes: Vec<Airframe> =
        AIRFRAMES.iter().map(|name| Airframe::builtin(name).unwrap()).collect();
    let ceiling = Config::default().acc_ceiling_mps2;
    for airframe in &airframes {
        assert!(airframe.r_imu_m().norm() <= f64::from(Config::default().max_offset_m));
        let envelope = free_fall_envelope_mps2(airframe, 800f64.to_radians());
        assert!(
            envelope < f64::from(ceiling),
            "{}: free fall at 800 °/s may read {envelope:.2} m/s², above the detector's {ceiling} \
             m/s² ceiling",
            airframe.name
        );
    }

    let fits: usize =
        std::env::var("IMU_OFFSET_COVERAGE_FITS").ok().and_then(|v| v.parse().ok()).unwrap_or(200);
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get()).clamp(1, 8);
    let next = AtomicUsize::new(0);
    let mut results: Vec<(usize, Fit)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        if i >= fits {
                            break mine;
                        }
                        mine.push((i, fit_one(i as u64, &airframes)));
                    }
                })
            })
            .collect();
        workers.into_iter().flat_map(|w| w.join().expect("a worker finishes")).collect()
    });
    results.sort_by_key(|(i, _)| *i);

    println!(
        "IMU offset, two-throw fits on the simulator ({fits} fits, 400–800 °/s, horizontal \
         release speed ≤ {} m/s):",
        max_horizontal_mps()
    );
    println!(
        "{:<12} {:<9} {:>5} {:>9} {:>9} {:>9} {:>8} {:>11}",
        "airframe", "model", "fits", "median", "p95", "coverage", "axes ×", "paper's"
    );
    let mut overall = Vec::new();
    for (which, name) in
        AIRFRAMES.iter().enumerate().map(|(i, n)| (Some(i), *n)).chain([(None, "all")])
    {
        for (m, (model, _, _)) in MODELS.iter().enumerate() {
            let outcomes: Vec<Outcome> = results
                .iter()
                .filter(|(_, f)| which.is_none_or(|w| w == f.airframe))
                .map(|(_, f)| f.outcomes[m])
                .collect();
            let s = summarise(&outcomes);
            println!(
                "{name:<12} {model:<9} {:>5} {:>6.3} mm {:>6.3} mm {:>8.1} % {:>8.2} {:>9.1} %",
                outcomes.len(),
                s.median_mm,
                s.p95_mm,
                100.0 * s.coverage,
                s.calibration,
                100.0 * s.white_coverage
            );
            if which.is_none() {
                overall.push((model, s));
            }
        }
    }

    // Coverage band: with n independent fits and a true coverage of 95 %, the observed fraction
    // has standard deviation √(0.95·0.05/n) (1.5 % at n = 200); ±3σ (4.6 %) is crossed by chance
    // with probability 0.3 %. Above, a conservative ellipsoid is tolerated up to 99.5 % (at
    // n = 200, 99.5 % is 4.5σ above 95 %: clearly too wide, but wasting throws misleads no one);
    // the offset-only models may reach 100 %: their allowance for an unmodelled bias is a bound
    // (a bias of the size found, in the worst direction), not an estimate.
    let n = fits as f64;
    let sigma = (0.95 * 0.05 / n).sqrt();
    let lower = 0.95 - 3.0 * sigma;
    for (m, (model, s)) in overall.iter().enumerate() {
        let upper = if MODELS[m].1 == Model::Offset { 1.0 } else { 0.995 };
        assert!(
            s.coverage >= lower && s.coverage <= upper,
            "{model}: the reported 95 % ellipsoid holds the truth in {:.1} % of {fits} fits \
             (band {:.1}–{:.1} %)",
            100.0 * s.coverage,
            100.0 * lower,
            100.0 * upper
        );
        // Not uselessly wide either: semi-axes at most 1/0.6 ≈ 1.7 × what exact 95 % coverage
        // needs (the verdict would otherwise reject good throws).
        assert!(s.calibration >= 0.6, "{model}: semi-axes {:.2} × too wide", 1.0 / s.calibration);
        // The seed paper's white-noise ellipsoid ignores the filter's correlation and the
        // systematic errors: far too small on this data (the reason for the correction).
        assert!(s.white_coverage < 0.5, "{model}: white-noise coverage {:.1} %", s.white_coverage);
        // Accuracy, in physical terms: two throws place the IMU within a millimetre typically,
        // and within 2.5 mm in 95 % of the fits (drag and bias being the limits, not noise).
        assert!(s.median_mm < 1.0, "{model}: median error {:.3} mm", s.median_mm);
        assert!(s.p95_mm < 2.5, "{model}: 95th percentile error {:.3} mm", s.p95_mm);
    }
    // With a real accelerometer bias (0.1 m/s² on these airframes) fitting it jointly helps, and
    // with drag (0.3–0.8 m/s² at release) modelling it helps further, in the bulk and the tail.
    let [offset, bias, _, bias_drag] = [0, 1, 2, 3].map(|m| &overall[m].1);
    assert!(bias.median_mm < offset.median_mm, "joint bias fit should be more accurate");
    assert!(
        bias_drag.median_mm < 0.6 * bias.median_mm && bias_drag.p95_mm < 0.75 * bias.p95_mm,
        "drag model: median {:.3} mm, p95 {:.3} mm vs {:.3} / {:.3} mm without",
        bias_drag.median_mm,
        bias_drag.p95_mm,
        bias.median_mm,
        bias.p95_mm
    );
}
