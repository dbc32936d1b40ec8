//! The in-flight IMU-offset fit (`imu_offset::in_flight`) against the truth with one part of
//! the simulated world removed at a time, to find what limits it (issue 32):
//! `cargo run -p sim --release --example offset_diag -- RUNS [random | ASPECT]`.

use sim::recovery::{fly, random_case};
use sim::stats::{quantile, run_seeds};
use sim::world::{random_world_case, Aspect};

fn main() {
    let mut args = std::env::args().skip(1);
    let runs: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(40);
    // `random`: every aspect; an aspect's name: that one; nothing: the nominal world.
    let aspects: Vec<Aspect> = match args.next().as_deref() {
        Some("random") => Aspect::ALL.to_vec(),
        Some(name) => vec![Aspect::parse(name).expect("an aspect")],
        None => Vec::new(),
    };
    type Change = fn(&mut sim::airframe::Airframe);
    let variants: [(&str, Change); 4] = [
        ("as drawn", |_| {}),
        ("no drag", |a| a.drag = Default::default()),
        ("no accelerometer noise or bias", |a| {
            a.imu.accel.noise_density_mps2_per_sqrt_hz = 0.0;
            a.imu.accel.bias_mps2 = [0.0; 3];
            a.imu.vibration = Default::default();
        }),
        ("neither", |a| {
            a.drag = Default::default();
            a.imu.accel.noise_density_mps2_per_sqrt_hz = 0.0;
            a.imu.accel.bias_mps2 = [0.0; 3];
            a.imu.vibration = Default::default();
        }),
    ];
    for (name, change) in variants {
        let errors: Vec<f64> = run_seeds(runs, 1, 2, &|_| {}, |seed| {
            let (mut airframe, mut config) = if aspects.is_empty() {
                random_case(seed)
            } else {
                random_world_case(seed, &aspects)
            };
            change(&mut airframe);
            config.known_imu_offset = false;
            let report = fly(&airframe, &config);
            report.r_imu_fit_m.map_or(f64::NAN, |r| (r - report.r_imu_true_m).norm() * 1e3)
        })
        .into_iter()
        .filter(|e| e.is_finite())
        .collect();
        println!(
            "{name}: error median {:.2} mm, 90th {:.2} mm ({} runs)",
            quantile(&errors, 0.5),
            quantile(&errors, 0.9),
            errors.len()
        );
    }
}
