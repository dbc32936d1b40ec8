//! Diagnosis of the identification of fast-spinning throws (issue 28): one world case's
//! throw-to-fly identification recorded step by step, then replayed into learners with
//! different inertia priors, scored against the truth.
//!
//! ```text
//! cargo run -p sim --release --example spin_diagnose -- SEED [SEED...]   # world hand cases
//! cargo run -p sim --release --example spin_diagnose -- tumble RUNS      # the tumble's J errors
//! ```
//! Environment: `ASPECTS=hand,imu,…` (or `RANDOM=1`: every aspect) chooses the world;
//! `NOMINAL=1` the nominal throws for `tumble`; `AT_ENGAGE=1` scores the replay at the end of the
//! excitation instead of 80 ms later; `SPIN_SCALE=x` scales the throw's spin; `NO_SENS`,
//! `NO_GYRO_CROSS`, `NO_ASENS`, `NO_VIB`, `NO_ANG_DRAG` remove one IMU or airframe error.

use firmware::app::{ControlCommand, StepRecord};
use flight::learner::inertia::InertiaPrior;
use flight::learner::{FlightPhase, Learner, LearnerConfig, MAX_MOTORS};
use nalgebra::Matrix3;
use sim::board::SimBoard;
use sim::identification::{Scores, TrueModel};
use sim::scenario::with_firmware_app;
use sim::world::{random_world_case, Aspect};
use tumble::TumbleInertia;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args[0] == "tumble" {
        let runs: u64 = args[1].parse().unwrap();
        tumble_stats(runs);
        return;
    }
    let seeds: Vec<u64> = args.iter().map(|s| s.parse().unwrap()).collect();
    for seed in seeds {
        diagnose(seed);
    }
}

fn truth_j(airframe: &sim::airframe::Airframe) -> Matrix3<f64> {
    let r = *airframe.q_imu_body().to_rotation_matrix().matrix();
    let i = r * airframe.inertia_matrix() * r.transpose();
    i / i.trace()
}

/// The heuristic's hover commands of `g1` (per unit thrust), bounds widened to ±10.
fn heuristic_u(g1: &[[f64; MAX_MOTORS]; 6], m: usize) -> Option<Vec<f32>> {
    use flight::thrust_axis::{HoverProblem, SolverConfig, ThrustAxisSolver};
    let rows: Vec<Vec<f32>> = (0..6).map(|k| (0..m).map(|i| g1[k][i] as f32).collect()).collect();
    let problem = HoverProblem::new([&rows[0], &rows[1], &rows[2]], [&rows[3], &rows[4], &rows[5]])
        .ok()?
        .with_bounds(&vec![-10.0; m], &vec![10.0; m])
        .ok()?;
    let mut solver = ThrustAxisSolver::new(SolverConfig {
        max_squarings: 6,
        bounded_search: false,
        ..SolverConfig::default()
    });
    let mut u = None;
    for _ in 0..5 {
        u = solver.solve(&problem).ok().map(|s| s.u_hover().to_vec());
    }
    u
}

fn record(seed: u64) -> (sim::airframe::Airframe, Vec<StepRecord>, TrueModel, f32, f64) {
    let aspects: Vec<Aspect> = match std::env::var("ASPECTS") {
        Ok(names) => {
            names.split(',').filter(|n| !n.is_empty()).map(|n| Aspect::parse(n).unwrap()).collect()
        }
        Err(_) if std::env::var("RANDOM").is_ok() => Aspect::ALL.to_vec(),
        Err(_) => vec![Aspect::Hand],
    };
    let (mut airframe, mut config) = random_world_case(seed, &aspects);
    if let Ok(scale) = std::env::var("SPIN_SCALE") {
        config.throw.rate_body_rad_s *= scale.parse::<f64>().unwrap();
    }
    if std::env::var("NO_ANG_DRAG").is_ok() {
        airframe.drag.angular_nm_per_rad_s = [0.0; 3];
    }
    if std::env::var("NO_SENS").is_ok() {
        airframe.imu.gyro.sensitivity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    if std::env::var("NO_GYRO_CROSS").is_ok() {
        for i in 0..3 {
            for j in 0..3 {
                if i != j {
                    airframe.imu.gyro.sensitivity[i][j] = 0.0;
                }
            }
        }
    }
    if std::env::var("NO_VIB").is_ok() {
        airframe.imu.vibration.gyro_rad_s_at_max_speed = 0.0;
        airframe.imu.vibration.accel_mps2_at_max_speed = 0.0;
    }
    if std::env::var("NO_ASENS").is_ok() {
        airframe.imu.accel.sensitivity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let truth = TrueModel::of(&airframe);
    let mut records = Vec::new();
    let mut hand_release_us = 0.0;
    with_firmware_app(|app| {
        let mut board = SimBoard::new(&airframe, &config.board);
        let r = truth.r_imu_m;
        app.background.set_imu_offset(Some([r.x as f32, r.y as f32, r.z as f32]));
        app.submit(ControlCommand::ArmThrowToFly);
        let spec = config.throw.spec();
        let mut done_ticks = 0;
        for tick in 0..10_000u64 {
            if tick == 1000 {
                board.physics_mut().throw(&spec);
            }
            board.tick_and_step(app);
            if let Some(r) = board.physics().hand().released_at_s() {
                if hand_release_us == 0.0 {
                    hand_release_us = r * 1e6;
                }
            }
            records.extend(std::iter::from_fn(|| app.link.take_record()));
            if app.snapshot().phase == FlightPhase::Done {
                if done_ticks == 0 {
                    let learned = app.background.results().learned;
                    let m = truth.motors;
                    let per_thrust = learned.g1_per_unit_thrust().map(|r| r.map(f64::from));
                    let mut true_thrust = truth.g1_per_speed2;
                    for row in true_thrust.iter_mut() {
                        for (x, full) in row.iter_mut().zip(&truth.omega_full_rad_s).take(m) {
                            *x *= full.powi(2);
                        }
                    }
                    let s = Scores::of(&learned, &truth);
                    println!(
                        "  at engage: {:?}, G1 force {:.1} % rot {:.1} %",
                        learned.axis_status,
                        100.0 * s.g1_block_rel[0],
                        100.0 * s.g1_block_rel[1]
                    );
                    println!("  true u_hover (heuristic)    {:.3?}", heuristic_u(&true_thrust, m));
                    println!("  learned u_hover (heuristic) {:.3?}", heuristic_u(&per_thrust, m));
                }
                done_ticks += 1;
                if done_ticks > 160 {
                    break;
                }
            }
        }
    });
    println!(
        "seed {seed}: {} motors, throw {:.0?} °/s (|Ω| {:.0}), push {:.0} ms, taper {:.0} ms",
        airframe.rotor_count(),
        config.throw.rate_body_rad_s.map(f64::to_degrees).as_slice(),
        config.throw.rate_body_rad_s.norm().to_degrees(),
        config.throw.push_s * 1e3,
        config.throw.taper_s * 1e3
    );
    let age = airframe.rotor_motor(0).telemetry_delay_s as f32;
    (airframe, records, truth, age, hand_release_us)
}

fn j_of(p: &InertiaPrior) -> Matrix3<f64> {
    let m = p.mean.map(f64::from);
    Matrix3::new(m[0], m[2], m[3], m[2], m[1], m[4], m[3], m[4], 1.0 - m[0] - m[1])
}

fn prior_of(j: &Matrix3<f64>, variance: f32) -> InertiaPrior {
    let mut p = InertiaPrior::sphere();
    p.mean = [j[(0, 0)], j[(1, 1)], j[(0, 1)], j[(0, 2)], j[(1, 2)]].map(|v| v as f32);
    for (k, row) in p.covariance.iter_mut().enumerate() {
        row[k] = variance;
    }
    p
}

/// Replay into a learner with `prior` (None: the tumble's, as the firmware does).
fn replay(
    records: &[StepRecord],
    truth: &TrueModel,
    age: f32,
    prior: Option<InertiaPrior>,
    exact_k: Option<&Matrix3<f64>>,
) -> (Scores, Matrix3<f64>, InertiaPrior, flight::learner::LearnedModel) {
    let mut tumble = TumbleInertia::new(2000.0);
    let mut learner: Option<Learner> = None;
    let mut used = InertiaPrior::sphere();
    let mut after = 0;
    let mut previous = FlightPhase::Idle;
    let r = truth.r_imu_m;
    for rec in records {
        let Some(imu) = rec.imu else { continue };
        match rec.phase {
            FlightPhase::Released => tumble.update(imu.gyro_rad_s),
            FlightPhase::Exciting => {}
            _ => tumble.reset(),
        }
        let speeds: [f32; MAX_MOTORS] =
            core::array::from_fn(|i| rec.speeds_rad_s[i].unwrap_or(f32::NAN));
        // As the firmware's background task: restarted at the release, primed through it.
        if rec.phase == FlightPhase::Released && previous != FlightPhase::Released {
            let config = LearnerConfig {
                r_imu_m: [r.x as f32, r.y as f32, r.z as f32],
                ..LearnerConfig::default()
            }
            .with_speed_age(age);
            learner = Some(Learner::new(rec.motor_count as usize, config).unwrap());
        }
        if rec.phase == FlightPhase::Released {
            if let Some(l) = &mut learner {
                l.prime(imu.gyro_rad_s, imu.accel_mps2, &speeds);
            }
        }
        if rec.phase == FlightPhase::Exciting && previous != FlightPhase::Exciting {
            used = prior.unwrap_or_else(|| tumble.prior());
            if let Some(l) = &mut learner {
                l.set_inertia_prior(&used);
            }
            let _ = exact_k;
        }
        previous = rec.phase;
        if rec.phase == FlightPhase::Done {
            after += 1;
            let limit = if std::env::var("AT_ENGAGE").is_ok() { 1 } else { 160 };
            if after > limit {
                break;
            }
        }
        if matches!(rec.phase, FlightPhase::Exciting | FlightPhase::Done) {
            if let Some(l) = &mut learner {
                l.update(imu.gyro_rad_s, imu.accel_mps2, &rec.commands, &speeds);
            }
        }
    }
    let l = learner.unwrap();
    let j = l.normalised_inertia();
    let j = Matrix3::from_fn(|a, b| f64::from(j[a][b]));
    (Scores::of(l.model(), truth), j, used, *l.model())
}

fn diagnose(seed: u64) {
    let (airframe, records, truth, age, hand_release_us) = record(seed);
    let jt = truth_j(&airframe);
    let released: Vec<&StepRecord> =
        records.iter().filter(|r| r.phase == FlightPhase::Released).collect();
    if let Some(first) = released.first() {
        println!(
            "  declared release {:.1} ms after the hand let go; released phase {} steps",
            (first.t_us as f64 - hand_release_us) * 1e-3,
            released.len()
        );
    }
    for skip_ms in [0usize, 5, 10, 20, 30, 50] {
        let mut tumble = TumbleInertia::new(2000.0);
        for r in released.iter().skip(skip_ms * 2) {
            if let Some(imu) = r.imu {
                tumble.update(imu.gyro_rad_s);
            }
        }
        let p = tumble.prior();
        let jp = j_of(&p);
        let sd: Vec<f32> = (0..5).map(|k| p.covariance[k][k].sqrt()).collect();
        println!(
            "  tumble skipping {skip_ms:2} ms: J err {:.3} (diag {:.3?}) prior σ {:.3?}",
            (jp - jt).abs().max(),
            jp.diagonal().as_slice(),
            sd
        );
    }
    // Rates during the excitation, and pulses' peak commands.
    let exciting: Vec<&StepRecord> =
        records.iter().filter(|r| r.phase == FlightPhase::Exciting).collect();
    let rate = |r: &StepRecord| {
        r.imu.map(|i| i.gyro_rad_s.iter().map(|g| g * g).sum::<f32>().sqrt().to_degrees())
    };
    if let (Some(first), Some(last)) = (exciting.first(), exciting.last()) {
        println!(
            "  |Ω| at excitation start {:.0} °/s, end {:.0} °/s, {} steps",
            rate(first).unwrap_or(f32::NAN),
            rate(last).unwrap_or(f32::NAN),
            exciting.len()
        );
    }
    let m = truth.motors;
    let peak: Vec<f32> =
        (0..m).map(|i| exciting.iter().map(|r| r.commands[i]).fold(0.0, f32::max)).collect();
    let pulse_steps: Vec<usize> =
        (0..m).map(|i| exciting.iter().filter(|r| r.commands[i] > 0.05).count()).collect();
    println!("  peak commands {peak:.2?}, steps above 0.05: {pulse_steps:?}");
    println!(
        "  true J diag {:.3?} offdiag {:.3?}",
        jt.diagonal().as_slice(),
        [jt[(0, 1)], jt[(0, 2)], jt[(1, 2)]]
    );
    let cases: [(&str, Option<InertiaPrior>, bool); 3] = [
        ("tumble prior", None, false),
        ("sphere prior", Some(InertiaPrior::sphere()), false),
        ("exact J, var 1e-8", Some(prior_of(&jt, 1e-8)), false),
    ];
    for (name, prior, fix_k) in cases {
        let (s, j, used, model) = replay(&records, &truth, age, prior, fix_k.then_some(&jt));
        println!(
            "  {name:18}: G1 force {:5.1} % rot {:6.1} % rows {:.0?} %  axis {:?} {:.1}°",
            100.0 * s.g1_block_rel[0],
            100.0 * s.g1_block_rel[1],
            s.g1_row_rel.map(|x| 100.0 * x),
            model.axis_status,
            s.axis_angle_rad.to_degrees()
        );
        let jp = j_of(&used);
        println!(
            "      prior J err {:.3} (diag {:.3?}); final J err {:.3} (diag {:.3?})",
            (jp - jt).abs().max(),
            jp.diagonal().as_slice(),
            (j - jt).abs().max(),
            j.diagonal().as_slice()
        );
    }
}

fn tumble_stats(runs: u64) {
    // The fit leaves out `HAND_CONTACT_S` itself; more can be skipped here.
    let variants: [(&str, usize, bool); 2] =
        [("as built", 0, true), ("10 ms more left out", 20, true)];
    let mut errors: Vec<Vec<f64>> = vec![Vec::new(); variants.len()];
    let mut zs: Vec<Vec<f64>> = vec![Vec::new(); variants.len()];
    let mut fast = 0;
    for seed in 1..=runs {
        let (airframe, records, _truth, _age, _hr) = record_quiet(seed);
        let jt = truth_j(&airframe);
        let released: Vec<&StepRecord> =
            records.iter().filter(|r| r.phase == FlightPhase::Released).collect();
        let rate = released
            .first()
            .and_then(|r| r.imu)
            .map(|i| i.gyro_rad_s.iter().map(|g| g * g).sum::<f32>().sqrt().to_degrees())
            .unwrap_or(0.0);
        if rate < 300.0 {
            continue;
        }
        fast += 1;
        for (v, &(_, skip, constants)) in variants.iter().enumerate() {
            let _ = constants;
            let mut tumble = TumbleInertia::new(2000.0);
            for r in released.iter().skip(skip) {
                if let Some(imu) = r.imu {
                    tumble.update(imu.gyro_rad_s);
                }
            }
            let p = tumble.prior();
            let jp = j_of(&p);
            let truth = [jt[(0, 0)], jt[(1, 1)], jt[(0, 1)], jt[(0, 2)], jt[(1, 2)]];
            let err = (jp - jt).abs().max();
            let z = (0..5)
                .map(|k| {
                    (f64::from(p.mean[k]) - truth[k]).abs() / f64::from(p.covariance[k][k]).sqrt()
                })
                .fold(0.0, f64::max);
            errors[v].push(err);
            zs[v].push(z);
        }
    }
    println!("{fast} throws above 300 °/s of {runs}");
    for (v, (name, _, _)) in variants.iter().enumerate() {
        let q = |x: &Vec<f64>, p: f64| sim::stats::quantile(x, p);
        let over = |x: &Vec<f64>, t: f64| x.iter().filter(|&&e| e > t).count();
        println!(
            "{name:28}: J err median {:.4} 90th {:.4} 99th {:.4} max {:.3}; > 0.05: {}; worst z median {:.2} 90th {:.2} 99th {:.2}; z > 3: {}",
            q(&errors[v], 0.5), q(&errors[v], 0.9), q(&errors[v], 0.99), q(&errors[v], 1.0), over(&errors[v], 0.05),
            q(&zs[v], 0.5), q(&zs[v], 0.9), q(&zs[v], 0.99), over(&zs[v], 3.0)
        );
    }
}

fn record_quiet(seed: u64) -> (sim::airframe::Airframe, Vec<StepRecord>, TrueModel, f32, f64) {
    let aspects: &[Aspect] = if std::env::var("NOMINAL").is_ok() { &[] } else { &[Aspect::Hand] };
    let (airframe, config) = random_world_case(seed, aspects);
    let truth = TrueModel::of(&airframe);
    let mut records = Vec::new();
    with_firmware_app(|app| {
        let mut board = SimBoard::new(&airframe, &config.board);
        app.submit(ControlCommand::ArmThrowToFly);
        let spec = config.throw.spec();
        for tick in 0..4000u64 {
            if tick == 1000 {
                board.physics_mut().throw(&spec);
            }
            board.tick_and_step(app);
            records.extend(std::iter::from_fn(|| app.link.take_record()));
            if app.snapshot().phase == FlightPhase::Exciting {
                break;
            }
        }
    });
    (airframe, records, truth, 0.0, 0.0)
}
