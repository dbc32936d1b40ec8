//! Scenario tests with physical checks: gravity and bias at rest, the throw's ballistics and
//! what the throw detector sees, the IMU offset recovered from two throw-and-catch logs, the log
//! format, ground contact.

use firmware::app::hal::{Imu, ImuSample, Motors};
use nalgebra::{UnitQuaternion, Vector3};
use sim::airframe::{Airframe, STANDARD_GRAVITY_MPS2};
use sim::log::CsvLog;
use sim::physics::Physics;
use sim::scenario::{
    self, ballistic_flight_time_s, FlightApp, Outcome, ScenarioConfig, ScenarioError, ScenarioKind,
};

/// Records every sample the application sees, commands nothing.
#[derive(Default)]
struct Recorder(Vec<ImuSample>);

impl FlightApp for Recorder {
    fn step<I: Imu, M: Motors>(&mut self, _now_us: u64, imu: &mut I, _motors: &mut M) {
        self.0.push(imu.read().expect("one sample per tick"));
    }
}

fn run(airframe: &Airframe, config: &ScenarioConfig) -> (Outcome, Vec<ImuSample>) {
    let mut rec = Recorder::default();
    let outcome =
        scenario::run::<_, std::io::Sink>(airframe, config, &mut rec, None, &mut |_, _| {})
            .unwrap();
    (outcome, rec.0)
}

fn v(a: [f32; 3]) -> Vector3<f64> {
    Vector3::from(a.map(f64::from))
}

#[test]
fn held_still_the_imu_reads_gravity_plus_bias_in_its_own_axes() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let (_, samples) = run(&airframe, &ScenarioConfig::new(ScenarioKind::HoldStill));
    assert_eq!(samples.len(), 4000, "2 s at 2 kHz");
    let n = samples.len() as f64;
    let mean_acc = samples.iter().map(|s| v(s.accel_mps2)).sum::<Vector3<f64>>() / n;
    let mean_gyro = samples.iter().map(|s| v(s.gyro_rad_s)).sum::<Vector3<f64>>() / n;
    let expected_acc = airframe.q_imu_body() * Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_MPS2)
        + Vector3::from(airframe.imu.accel.bias_mps2);
    // Noise σ ≈ 0.03 m/s² per 2 kHz sample, quantisation 4.8 mm/s²: the mean is good to ~1e-3.
    assert!((mean_acc - expected_acc).norm() < 3e-3, "{mean_acc} vs {expected_acc}");
    assert!((mean_gyro - Vector3::from(airframe.imu.gyro.bias_rad_s)).norm() < 1e-3);
    // And it is noisy, as a real IMU.
    let spread =
        samples.iter().map(|s| (v(s.accel_mps2) - mean_acc).norm_squared()).sum::<f64>() / n;
    assert!(spread.sqrt() > 0.02, "accelerometer noise missing: {}", spread.sqrt());
}

#[test]
fn throw_and_catch_follows_ballistics_and_looks_like_a_throw() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
    let (outcome, samples) = run(&airframe, &config);
    let released = outcome.released_at_s.expect("released");
    let caught = outcome.caught_at_s.expect("caught");
    assert!((released - (config.hold_before_s + config.throw_duration_s)).abs() < 1e-3);
    // Drag shortens the flight a little: within 5 % of the vacuum figure.
    let flight_s = caught - released;
    let vacuum_s = ballistic_flight_time_s(config.throw_apex_m);
    assert!(((flight_s - vacuum_s) / vacuum_s).abs() < 0.05, "{flight_s} s vs {vacuum_s} s");
    let release_height_m = config.hold_height_m
        + 0.5
            * (2.0 * STANDARD_GRAVITY_MPS2 * config.throw_apex_m).sqrt()
            * config.throw_duration_s;
    let apex_m = outcome.max_height_m - release_height_m;
    assert!(apex_m < config.throw_apex_m && apex_m > 0.95 * config.throw_apex_m, "apex {apex_m}");
    assert!((outcome.max_rate_rad_s - config.throw_rate_body_rad_s.norm()).abs() < 0.5);
    assert!(!outcome.touched_ground);

    // What the published throw detector needs (docs/algorithms/throw.md): |a| > 20 m/s² during the
    // throw, with a momentum Σ(clip(|a|, 0, 45) − g)·dt above 4 m/s.
    let dt = 1.0 / 2000.0;
    let throw = |s: &&ImuSample| v(s.accel_mps2).norm() > 20.0;
    let momentum: f64 = samples
        .iter()
        .filter(throw)
        .map(|s| (v(s.accel_mps2).norm().min(45.0) - STANDARD_GRAVITY_MPS2) * dt)
        .sum();
    assert!(momentum > 4.0, "throw momentum {momentum} m/s");
    // In free flight the accelerometer reads only the small rotational terms and drag.
    let first_free = ((released + 0.05) * 2000.0) as usize;
    let last_free = ((caught - 0.05) * 2000.0) as usize;
    let worst_free =
        samples[first_free..last_free].iter().map(|s| v(s.accel_mps2).norm()).fold(0.0, f64::max);
    assert!(worst_free < 2.0, "free-fall |f| up to {worst_free} m/s²");
}

#[test]
fn two_throw_and_catch_logs_recover_the_imu_offset_within_a_millimetre() {
    use imu_offset::{BatchFitter, Config, ImuSample as FitSample, Model};
    // Drag off: eq. 3 has no drag term, and at these throw speeds the paper-quad's drag
    // (≈0.3 m/s² at release) biases the fit by a few mm — a fitter matter, measured and reported
    // in the issue note; here the check is that the simulated sensors (noise, bias, quantisation,
    // averaging) carry the offset to within a millimetre.
    let mut airframe = Airframe::builtin("paper-quad").unwrap();
    airframe.drag = Default::default();
    let mut fitter =
        BatchFitter::new(Config { model: Model::OffsetAndAccBias, ..Config::default() });
    // Two throws spinning about clearly different axes (seed paper §3.2).
    for (i, rate) in
        [Vector3::new(6.0, 3.0, 1.5), Vector3::new(-1.5, 2.0, 6.0)].into_iter().enumerate()
    {
        let mut config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
        config.throw_rate_body_rad_s = rate;
        config.board.seed = 10 + i as u64;
        let (_, samples) = run(&airframe, &config);
        let samples: Vec<FitSample> = samples
            .iter()
            .map(|s| FitSample {
                gyro_radps: Vector3::from(s.gyro_rad_s),
                acc_mps2: Vector3::from(s.accel_mps2),
            })
            .collect();
        let throws = fitter.add_log(&samples, 2000.0).unwrap();
        assert_eq!(throws, 1, "log {i}: one throw expected");
    }
    let estimate = fitter.estimate().unwrap();
    // Truth in IMU axes: r rotated by q_imu_body.
    let truth = airframe.q_imu_body() * airframe.r_imu_m();
    let error_m = (estimate.r_imu_m - truth).norm();
    println!(
        "r̂ = {:.5?} m, truth {:.5?} m, error {:.3} mm",
        estimate.r_imu_m,
        truth,
        error_m * 1e3
    );
    assert!(error_m < 1e-3, "IMU offset error {:.3} mm", error_m * 1e3);
}

#[test]
fn the_log_starts_with_the_configurator_columns_and_has_one_row_per_tick() {
    let airframe = Airframe::builtin("hex-flat").unwrap();
    let mut config = ScenarioConfig::new(ScenarioKind::HoldStill);
    config.duration_s = 0.1;
    let mut log = CsvLog::new(Vec::new(), airframe.rotor_count()).unwrap();
    let outcome =
        scenario::run(&airframe, &config, &mut scenario::NoApp, Some(&mut log), &mut |_, _| {})
            .unwrap();
    let text = String::from_utf8(log.finish().unwrap()).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(&header[..7], &["t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"]);
    assert!(
        header.contains(&"cmd_5") && header.contains(&"rpm_5") && header.contains(&"true_omega_5")
    );
    assert!(!header.contains(&"cmd_6"));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len() as u64, outcome.ticks);
    assert!(rows.iter().all(|r| r.split(',').count() == header.len()));
    let t_last: f64 = rows.last().unwrap().split(',').next().unwrap().parse().unwrap();
    assert!((t_last - 0.1).abs() < 1e-9);
}

#[test]
fn a_dropped_craft_comes_to_rest_on_the_ground() {
    let airframe = Airframe::builtin("racer-5in").unwrap();
    let mut p =
        Physics::new(&airframe, Vector3::new(0.0, 0.0, -0.5), UnitQuaternion::identity(), 8000.0);
    p.release();
    for _ in 0..16_000 {
        p.step();
    }
    let s = p.state();
    // On its landing gear: each foot carries its share, sinking m g / (m ω_n²) = g / (2π·30 Hz)²
    // = 0.28 mm; the centre of gravity rests the gear's height above the ground.
    let gear_m = p.model().gear_height_m(s);
    assert!(gear_m < 0.0 && gear_m > -1e-3, "the gear sinks {gear_m} m");
    assert!(s.position_ned_m.z < -0.03, "the CoG rests at {} m, on its legs", s.position_ned_m.z);
    assert!(s.velocity_ned_mps.norm() < 1e-3, "still moving {}", s.velocity_ned_mps);
    assert!(s.rate_body_rad_s.norm() < 1e-3, "still turning {}", s.rate_body_rad_s);
}

#[test]
fn throw_and_fly_without_a_controller_falls() {
    // Until firmware::app::ControlLoop exists, nothing commands the motors: the craft falls.
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let (outcome, _) = run(&airframe, &ScenarioConfig::new(ScenarioKind::ThrowFly));
    assert!(outcome.touched_ground);
    assert!(
        outcome.max_height_m > 4.0,
        "3.5 m apex above a ~1.5 m release: {}",
        outcome.max_height_m
    );
}

#[test]
fn an_out_of_range_scenario_parameter_is_an_error() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let mut config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
    config.throw_duration_s = 0.0;
    match scenario::run::<_, std::io::Sink>(
        &airframe,
        &config,
        &mut scenario::NoApp,
        None,
        &mut |_, _| {},
    ) {
        Err(ScenarioError::OutOfRange { field, .. }) => assert_eq!(field, "throw_duration_s"),
        other => panic!("expected OutOfRange, got {other:?}"),
    }
}

/// Hold the racer at δ = 0.5 with sensor errors off (vibration optionally on) and return the
/// 2 kHz accelerometer samples of the last second and the rotor frequency, Hz.
fn vibration_run(vibration: bool) -> (Vec<Vector3<f64>>, f64) {
    let mut airframe = Airframe::builtin("racer-5in").unwrap();
    airframe.imu.accel.noise_density_mps2_per_sqrt_hz = 0.0;
    airframe.imu.accel.bias_mps2 = [0.0; 3];
    airframe.imu.accel.bits = 0;
    if !vibration {
        airframe.imu.vibration = Default::default();
    }
    assert!(airframe.imu.vibration.accel_mps2_at_max_speed > 0.0 || !vibration);
    let mut config = ScenarioConfig::new(ScenarioKind::HoldStill);
    config.duration_s = 1.5;
    /// Commands δ = 0.5 on every motor and records the accelerometer.
    struct Probe(Vec<Vector3<f64>>);
    impl FlightApp for Probe {
        fn step<I: Imu, M: Motors>(&mut self, _now_us: u64, imu: &mut I, motors: &mut M) {
            self.0.push(v(imu.read().expect("one sample per tick").accel_mps2));
            motors.set_commands(&[0.5; 8][..motors.count() as usize]);
        }
    }
    let mut probe = Probe(Vec::new());
    scenario::run::<_, std::io::Sink>(&airframe, &config, &mut probe, None, &mut |_, _| {})
        .unwrap();
    let rotor_hz = airframe.motor.steady_speed_rad_s(0.5) / std::f64::consts::TAU;
    let last_second = probe.0.split_off(probe.0.len() - 2000);
    (last_second, rotor_hz)
}

/// Amplitude of the component at `f_hz` (single-sided DFT magnitude), per axis summed in
/// quadrature, m/s².
fn amplitude_at(samples: &[Vector3<f64>], f_hz: f64) -> f64 {
    let n = samples.len() as f64;
    let mean = samples.iter().sum::<Vector3<f64>>() / n;
    let (mut c, mut s) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
    for (k, x) in samples.iter().enumerate() {
        let phase = std::f64::consts::TAU * f_hz * k as f64 / 2000.0;
        c += (x - mean) * phase.cos();
        s += (x - mean) * phase.sin();
    }
    2.0 / n * (c.norm_squared() + s.norm_squared()).sqrt()
}

#[test]
fn motor_vibration_appears_at_the_rotor_frequency() {
    let (quiet, rotor_hz) = vibration_run(false);
    let (shaking, _) = vibration_run(true);
    // The spectrum's peak over 20–990 Hz (1 Hz bins) sits at the rotor frequency.
    let peak_hz = (20..990)
        .map(f64::from)
        .max_by(|a, b| amplitude_at(&shaking, *a).total_cmp(&amplitude_at(&shaking, *b)))
        .unwrap();
    assert!((peak_hz - rotor_hz).abs() <= 1.5, "peak {peak_hz} Hz, rotor {rotor_hz:.1} Hz");
    let amplitude = amplitude_at(&shaking, rotor_hz);
    assert!(amplitude > 0.3, "vibration amplitude {amplitude} m/s²");
    assert!(amplitude_at(&quiet, rotor_hz) < 1e-6, "vibration without vibration configured");
}
