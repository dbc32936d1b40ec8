//! The in-flight IMU-offset fit (`imu_offset::in_flight`) against the truth with one part of
//! the simulated world removed at a time, to find what limits it (issue 32):
//! `cargo run -p sim --release --example offset_diag -- RUNS [random | nominal | ASPECT] [calibration]
//! [first] [no-poses]` (`first`: the world as drawn only; `no-poses`: no motion capture, the
//! navigation's velocity is dead reckoning from the hand). `OFFSET_DIAG_VARIANT=N` runs variant N
//! of `VARIANTS` alone (1: `no gust`; 9 and 10: the drag linear only, quadratic only; 11 and 12:
//! the gyro's common scale error only, the gyro's errors without it; 13: the gyro's error on
//! rates along the release rate removed).
//!
//! Each variant flies the same seeds (airframes, throws, worlds) with one error source switched
//! off; `calibration` also fits the two-throw calibration (`sim::calibration`, as
//! `fit imu-offset` fits it) on the same airframes, IMUs and drag, with and without the gyro's
//! scale and cross-axis errors. Printed per variant: the error's median / 90th / 99th percentile
//! and how often the truth lies inside the reported 95 % ellipsoid.

use imu_offset::{DragModel, Model, CHI2_3DOF_95};
use nalgebra::Matrix3;
use sim::airframe::{identity_3x3, Airframe};
use sim::calibration::{fit, Session};
use sim::recovery::{fly, random_case, FlyConfig, FlyReport, Verdict};
use sim::stats::{quantile, run_seeds};
use sim::world::{random_world_case, Aspect};

type Change = fn(&mut Airframe, &mut FlyConfig);

fn no_gyro_scale(a: &mut Airframe, _: &mut FlyConfig) {
    a.imu.gyro.sensitivity = identity_3x3();
}

fn no_accel_scale(a: &mut Airframe, _: &mut FlyConfig) {
    a.imu.accel.sensitivity = identity_3x3();
}

fn no_noise(a: &mut Airframe, _: &mut FlyConfig) {
    a.imu.accel.noise_density_mps2_per_sqrt_hz = 0.0;
    a.imu.gyro.noise_density_rad_s_per_sqrt_hz = 0.0;
    a.imu.accel.bias_mps2 = [0.0; 3];
    a.imu.gyro.bias_rad_s = [0.0; 3];
    a.imu.vibration = Default::default();
}

fn no_drag(a: &mut Airframe, c: &mut FlyConfig) {
    a.drag = Default::default();
    c.board.world.gust_s = 0.0;
}

/// The gyro's sensitivity reduced to its common scale (the mean of its diagonal times the
/// identity), or with that common scale taken out (the rest kept).
fn gyro_common_scale(a: &mut Airframe, keep_common: bool) {
    let s = &mut a.imu.gyro.sensitivity;
    let common = (s[0][0] + s[1][1] + s[2][2]) / 3.0;
    for (i, row) in s.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = match (keep_common, i == j) {
                (true, true) => common,
                (true, false) => 0.0,
                (false, true) => *x - common + 1.0,
                (false, false) => *x,
            };
        }
    }
}

/// The gyro's error on rates along the release rate removed (`S' = S − (S − I) a aᵀ`, `a` the
/// release rate's direction in IMU axes): what the tumble's attitude change, measured against
/// references before the throw and in hover, could tell of the gyro at best.
fn gyro_error_along_release(a: &mut Airframe, c: &mut FlyConfig) {
    let q = a.imu.q_imu_body_wxyz;
    let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        q[0], q[1], q[2], q[3],
    ));
    let axis = (q * c.throw.rate_body_rad_s).normalize();
    let s = Matrix3::from_fn(|i, j| a.imu.gyro.sensitivity[i][j]);
    let corrected = s - (s - Matrix3::identity()) * axis * axis.transpose();
    for (i, row) in a.imu.gyro.sensitivity.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = corrected[(i, j)];
        }
    }
}

const VARIANTS: [(&str, Change); 14] = [
    ("as drawn", |_, _| {}),
    ("no gust", |_, c| c.board.world.gust_s = 0.0),
    ("no gyro scale/cross-axis error", no_gyro_scale),
    ("no accelerometer scale/cross-axis error", no_accel_scale),
    ("no scale/cross-axis error", |a, c| {
        no_gyro_scale(a, c);
        no_accel_scale(a, c);
    }),
    ("no IMU noise, bias or vibration", no_noise),
    ("no drag or gust", no_drag),
    ("no drag, no scale error", |a, c| {
        no_drag(a, c);
        no_gyro_scale(a, c);
        no_accel_scale(a, c);
    }),
    ("none of these", |a, c| {
        no_drag(a, c);
        no_gyro_scale(a, c);
        no_accel_scale(a, c);
        no_noise(a, c);
    }),
    // The drag's two parts on their own (the fit's quadratic form, 2026-11-28).
    ("linear drag only", |a, _| a.drag.quadratic_n_per_mps2 = [0.0; 3]),
    ("quadratic drag only", |a, _| a.drag.linear_n_per_mps = [0.0; 3]),
    // The gyro's sensitivity error split (2026-11-28): its common scale alone, all but it.
    ("gyro's common scale error only", |a, _| gyro_common_scale(a, true)),
    ("gyro's common scale error taken out", |a, _| gyro_common_scale(a, false)),
    ("gyro's error along the release rate removed", gyro_error_along_release),
];

/// `(r̂ − r)ᵀ Σ⁻¹ (r̂ − r) / χ²₃(0.95)`: at most 1 when the truth is inside the ellipsoid.
fn normalised_mahalanobis(error: &nalgebra::Vector3<f64>, covariance: &Matrix3<f64>) -> f64 {
    let inverse = covariance.try_inverse().unwrap_or_else(Matrix3::zeros);
    error.dot(&(inverse * error)) / f64::from(CHI2_3DOF_95)
}

fn summary(name: &str, results: &[(f64, f64, Option<Verdict>)]) {
    let hovered = results
        .iter()
        .filter(|(_, _, v)| matches!(v, Some(Verdict::Held | Verdict::HoveredLoose)))
        .count();
    let held = results.iter().filter(|(_, _, v)| *v == Some(Verdict::Held)).count();
    let ok: Vec<(f64, f64)> =
        results.iter().map(|(e, m, _)| (*e, *m)).filter(|(e, _)| e.is_finite()).collect();
    let errors: Vec<f64> = ok.iter().map(|(e, _)| *e).collect();
    let inside = ok.iter().filter(|(_, m)| *m <= 1.0).count();
    println!(
        "{name}: error median {:.2} mm, 90th {:.2} mm, 99th {:.2} mm, inside the 95 % ellipsoid \
         {inside} of {} fitted{}",
        quantile(&errors, 0.5),
        quantile(&errors, 0.9),
        quantile(&errors, 0.99),
        errors.len(),
        if results.iter().any(|r| r.2.is_some()) {
            format!("; hovered {hovered}, held {held} of {}", results.len())
        } else {
            String::new()
        }
    );
}

fn flight_result(seed: u64, report: &FlyReport) -> (f64, f64, Option<Verdict>) {
    let verdict = Some(Verdict::of(report));
    let Some(fit) = report.r_imu_fit_m else { return (f64::NAN, f64::NAN, verdict) };
    let error = fit - report.r_imu_true_m;
    if let (Ok(path), Some(c)) = (std::env::var("OFFSET_DIAG_CSV"), report.r_imu_fit_covariance_m2)
    {
        use std::io::Write;
        let mut file = std::fs::OpenOptions::new().create(true).append(true).open(path).unwrap();
        let (f, t) = (fit * 1e3, report.r_imu_true_m * 1e3);
        let c = c * 1e6;
        writeln!(
            file,
            "{seed},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            f.x,
            f.y,
            f.z,
            t.x,
            t.y,
            t.z,
            c[(0, 0)],
            c[(0, 1)],
            c[(0, 2)],
            c[(1, 1)],
            c[(1, 2)],
            c[(2, 2)],
            report.outcome == sim::recovery::Outcome::Flying,
            0,
            0
        )
        .unwrap();
    }
    let mahalanobis = report
        .r_imu_fit_covariance_m2
        .map_or(f64::INFINITY, |c| normalised_mahalanobis(&error, &c));
    (error.norm() * 1e3, mahalanobis, verdict)
}

/// The two-throw calibration of `airframe` (its IMU errors and drag; its own accelerometer bias
/// kept), fitted as `fit imu-offset` fits it.
fn calibration_result(seed: u64, airframe: &Airframe) -> (f64, f64, Option<Verdict>) {
    let session = Session::on_airframe(seed, airframe);
    let truth = session.truth_m();
    match fit(&session.logs(), Model::OffsetAndAccBias, DragModel::VerticalQuadratic) {
        Ok(estimate) => {
            let error = estimate.r_imu_m - truth;
            let mahalanobis = normalised_mahalanobis(&error, &estimate.covariance_m2);
            (error.norm() * 1e3, mahalanobis, None)
        }
        Err(_) => (f64::NAN, f64::NAN, None),
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let runs: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(40);
    // `random`: every aspect; an aspect's name: that one; `nominal` or nothing: none.
    let mut aspects: Vec<Aspect> = Vec::new();
    let mut calibration = false;
    let mut first_only = false;
    let mut poses = true;
    for arg in args {
        match arg.as_str() {
            "random" => aspects = Aspect::ALL.to_vec(),
            "nominal" => aspects.clear(),
            "calibration" => calibration = true,
            "first" => first_only = true,
            "no-poses" => poses = false,
            name => aspects.push(Aspect::parse(name).expect("an aspect")),
        }
    }
    let case = |seed: u64| {
        if aspects.is_empty() {
            random_case(seed)
        } else {
            random_world_case(seed, &aspects)
        }
    };
    let variants = if first_only { &VARIANTS[..1] } else { &VARIANTS[..] };
    let variants = match std::env::var("OFFSET_DIAG_VARIANT").ok().and_then(|v| v.parse().ok()) {
        Some(i) => &VARIANTS[i..=i],
        None => variants,
    };
    for &(name, change) in variants {
        let results = run_seeds(runs, 1, 2, &|_| {}, |seed| {
            let (mut airframe, mut config) = case(seed);
            change(&mut airframe, &mut config);
            config.known_imu_offset = false;
            config.mocap &= poses;
            flight_result(seed, &fly(&airframe, &config))
        });
        summary(&format!("in flight, {name}"), &results);
    }
    if calibration {
        for (name, change) in [VARIANTS[0], VARIANTS[2], VARIANTS[3], VARIANTS[5], VARIANTS[6]] {
            let results = run_seeds(runs, 1, 2, &|_| {}, |seed| {
                let (mut airframe, mut config) = case(seed);
                change(&mut airframe, &mut config);
                calibration_result(seed, &airframe)
            });
            summary(&format!("two-throw calibration, {name}"), &results);
        }
    }
}
