//! `identify`: the in-flight identification (throw-to-fly learner of `firmware::app`) against
//! the simulator's truth, one airframe or a Monte Carlo over random airframes and throws.
//!
//! ```text
//! cargo run -p sim --release --bin identify -- paper --airframe hex-tilted
//! cargo run -p sim --release --bin identify -- monte-carlo --runs 1000 --threads 2
//! cargo run -p sim --release --bin identify -- case --seed 21   # one Monte Carlo run again
//! ```

use clap::{Parser, Subcommand};
use sim::airframe::Airframe;
use sim::identification::{identify, monte_carlo, IdentifyConfig, Scores};
use sim::stats::{quantile, BatchArgs};

#[derive(Parser, Debug)]
#[command(version, about = "In-flight identification against the simulator's truth")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// The seed paper's experiment: a 3.5 m parabola released at (400, 400, 100) °/s.
    Paper {
        /// Airframe: a built-in name or a TOML file.
        #[arg(long, default_value = "paper-quad")]
        airframe: String,
        /// Score the model learned this long after the excitation began, ms.
        #[arg(long, default_value_t = 300.0)]
        capture_ms: f64,
        /// Noise seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Also print the learned and the true G1 and G2.
        #[arg(long)]
        matrices: bool,
    },
    /// One Monte Carlo case, replayed alone.
    Case {
        /// The case's seed (as printed by `monte-carlo`).
        #[arg(long)]
        seed: u64,
    },
    /// Random airframes (4–8 motors, tilted rotors, IMU offset ≤ 30 mm, any IMU rotation) and
    /// random throws (300–600 °/s about a random axis, 2.5–4.5 m apex).
    MonteCarlo {
        #[command(flatten)]
        batch: BatchArgs,
    },
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    match args.command {
        Command::Paper { airframe, capture_ms, seed, matrices } => {
            let airframe = match Airframe::load(&airframe) {
                Ok(a) => a,
                Err(e) => {
                    eprintln!("identify: {e}");
                    return std::process::ExitCode::from(2);
                }
            };
            let mut config = IdentifyConfig::paper();
            config.capture_after_s = capture_ms / 1000.0;
            config.board.seed = seed;
            let report = identify(&airframe, &config);
            let Some(learned) = report.at_capture else {
                eprintln!("identify: the excitation never started (no throw detected)");
                return std::process::ExitCode::FAILURE;
            };
            let s = Scores::of(&learned, &report.truth);
            if matrices {
                print_matrices(&learned, &report.truth);
                println!("  axis status {:?}", learned.axis_status);
            }
            println!("airframe {} ({} motors)", airframe.name, report.truth.motors);
            println!(
                "  release → excitation: {:.1} ms",
                report.release_to_excitation_s.unwrap_or(f64::NAN) * 1e3
            );
            println!(
                "  excitation → first thrust axis: {:.1} ms",
                report.excitation_to_axis_s.unwrap_or(f64::NAN) * 1e3
            );
            println!("  scored at {capture_ms:.0} ms into the excitation:");
            println!(
                "  G1 relative RMS error per row (fx fy fz p q r): {}",
                percent(&s.g1_row_rel)
            );
            println!("  largest τ error: {:.3} ms", s.tau_error_max_s * 1e3);
            println!(
                "  thrust axis: {:.3}° off; roll/pitch/yaw errors {:.3}° / {:.3}° / {:.3}°",
                s.axis_angle_rad.to_degrees(),
                s.euler_error_rad[0].to_degrees(),
                s.euler_error_rad[1].to_degrees(),
                s.euler_error_rad[2].to_degrees()
            );
            std::process::ExitCode::SUCCESS
        }
        Command::Case { seed } => {
            let (airframe, config) = sim::identification::random_case(seed);
            let report = identify(&airframe, &config);
            let Some(learned) = report.at_end else {
                eprintln!("identify: the excitation never ended");
                return std::process::ExitCode::FAILURE;
            };
            let s = Scores::of(&learned, &report.truth);
            let m = report.truth.motors;
            println!(
                "case {seed}: {m} motors, rate {:?} rad/s, apex {:.2} m",
                config.throw.rate_body_rad_s.as_slice(),
                config.throw.apex_m
            );
            print_matrices(&learned, &report.truth);
            println!("  G1 relative RMS error per row: {}", percent(&s.g1_row_rel));
            println!(
                "  τ error {:.3} ms, axis {:.2}°",
                s.tau_error_max_s * 1e3,
                s.axis_angle_rad.to_degrees()
            );
            println!(
                "  motor τ learned {:?} ms",
                (0..m).map(|i| (learned.motor[i].tau_s * 1e4).round() / 10.0).collect::<Vec<_>>()
            );
            println!(
                "  motor τ true    {:?} ms",
                (0..m).map(|i| (report.truth.tau_s[i] * 1e4).round() / 10.0).collect::<Vec<_>>()
            );
            std::process::ExitCode::SUCCESS
        }
        Command::MonteCarlo { batch: BatchArgs { runs, seed, threads } } => {
            let started = std::time::Instant::now();
            let results = monte_carlo(runs, seed, threads, &|done| {
                if done % 50 == 0 || done == runs {
                    eprintln!("identify: {done}/{runs} runs");
                }
            });
            let scored: Vec<(u64, usize, Scores)> =
                results.iter().filter_map(|r| r.scores.map(|s| (r.seed, r.motors, s))).collect();
            let never = runs - scored.len();
            let g1: Vec<f64> =
                scored.iter().map(|(_, _, s)| s.g1_force_rel().max(s.g1_rotation_rel())).collect();
            let tau: Vec<f64> = scored.iter().map(|(_, _, s)| s.tau_error_max_s).collect();
            let axis: Vec<f64> = scored
                .iter()
                .map(
                    |(_, _, s)| {
                        if s.axis_found {
                            s.axis_angle_rad.to_degrees()
                        } else {
                            f64::INFINITY
                        }
                    },
                )
                .collect();
            println!(
                "{runs} runs in {:.0} s on {threads} threads; excitation never started in {never}",
                started.elapsed().as_secs_f64()
            );
            println!(
                "worst-row G1 relative RMS error: median {:.2} %, 90th {:.2} %, 99th {:.2} %",
                100.0 * quantile(&g1, 0.5),
                100.0 * quantile(&g1, 0.9),
                100.0 * quantile(&g1, 0.99)
            );
            let g1_block: Vec<f64> =
                scored.iter().map(|(_, _, s)| s.g1_block_rel[0].max(s.g1_block_rel[1])).collect();
            println!(
                "G1 relative RMS error of the worse block (all entries of the force or the \
                 rotation rows): median {:.2} %, 90th {:.2} %, 99th {:.2} %",
                100.0 * quantile(&g1_block, 0.5),
                100.0 * quantile(&g1_block, 0.9),
                100.0 * quantile(&g1_block, 0.99)
            );
            for (name, block) in [("specific-force", 0), ("angular-acceleration", 1)] {
                let rows: Vec<f64> = scored
                    .iter()
                    .map(
                        |(_, _, s)| if block == 0 { s.g1_force_rel() } else { s.g1_rotation_rel() },
                    )
                    .collect();
                let all: Vec<f64> = scored.iter().map(|(_, _, s)| s.g1_block_rel[block]).collect();
                println!(
                    "  {name} rows: worst row median {:.2} %, 99th {:.2} %; block median {:.2} %, 99th {:.2} %",
                    100.0 * quantile(&rows, 0.5),
                    100.0 * quantile(&rows, 0.99),
                    100.0 * quantile(&all, 0.5),
                    100.0 * quantile(&all, 0.99)
                );
            }
            println!(
                "largest τ error: median {:.3} ms, 99th {:.3} ms; within 1 ms in {:.1} %",
                1e3 * quantile(&tau, 0.5),
                1e3 * quantile(&tau, 0.99),
                100.0 * tau.iter().filter(|t| **t <= 1e-3).count() as f64 / tau.len().max(1) as f64
            );
            println!("thrust-axis angle error: median {:.2}°, 90th {:.2}°, 99th {:.2}°; no axis found in {}",
                quantile(&axis, 0.5), quantile(&axis, 0.9), quantile(&axis, 0.99),
                axis.iter().filter(|a| a.is_infinite()).count());
            for motors in 4..=8 {
                let of: Vec<f64> = scored
                    .iter()
                    .filter(|(_, m, _)| *m == motors)
                    .map(|(_, _, s)| s.g1_force_rel().max(s.g1_rotation_rel()))
                    .collect();
                if !of.is_empty() {
                    println!(
                        "  {motors} motors: {} runs, G1 median {:.2} %, 99th {:.2} %",
                        of.len(),
                        100.0 * quantile(&of, 0.5),
                        100.0 * quantile(&of, 0.99)
                    );
                }
            }
            // The tail of the headline figure (the worse block), then of the worst row.
            let worse_block = |s: &Scores| s.g1_block_rel[0].max(s.g1_block_rel[1]);
            let mut by_block: Vec<_> = scored.iter().collect();
            by_block.sort_by(|a, b| worse_block(&b.2).total_cmp(&worse_block(&a.2)));
            for (seed, motors, s) in by_block.iter().take(5) {
                println!(
                    "  worst block: seed {seed} ({motors} motors): force {:.1} %, rotation {:.1} %; rows {}",
                    100.0 * s.g1_block_rel[0],
                    100.0 * s.g1_block_rel[1],
                    percent(&s.g1_row_rel)
                );
            }
            let mut worst: Vec<_> = scored.iter().collect();
            worst.sort_by(|a, b| {
                b.2.g1_force_rel()
                    .max(b.2.g1_rotation_rel())
                    .total_cmp(&a.2.g1_force_rel().max(a.2.g1_rotation_rel()))
            });
            for (seed, motors, s) in worst.iter().take(5) {
                println!(
                    "  worst: seed {seed} ({motors} motors): G1 rows {}, τ {:.2} ms, axis {:.2}°",
                    percent(&s.g1_row_rel),
                    s.tau_error_max_s * 1e3,
                    s.axis_angle_rad.to_degrees()
                );
            }
            std::process::ExitCode::SUCCESS
        }
    }
}

/// The learned and the true G1 (×1e6, per (rad/s)²) and G2 (×1e3), row by row.
fn print_matrices(learned: &flight::learner::LearnedModel, truth: &sim::identification::TrueModel) {
    let m = truth.motors;
    let row = |values: &[f32], scale: f32| {
        values[..m].iter().map(|v| (v * scale * 100.0).round() / 100.0).collect::<Vec<_>>()
    };
    let true_row = |values: &[f64], scale: f64| {
        values[..m].iter().map(|v| (v * scale * 100.0).round() / 100.0).collect::<Vec<_>>()
    };
    for k in 0..6 {
        println!("  G1 row {k} ×1e6: learned {:?}", row(&learned.g1_per_speed2[k], 1e6));
        println!("                 truth   {:?}", true_row(&truth.g1_per_speed2[k], 1e6));
    }
    for k in 0..3 {
        println!("  G2 row {k} ×1e3: learned {:?}", row(&learned.g2[k], 1e3));
        println!("                 truth   {:?}", true_row(&truth.g2[k], 1e3));
    }
}

fn percent(values: &[f64; 6]) -> String {
    values.iter().map(|v| format!("{:.1} %", 100.0 * v)).collect::<Vec<_>>().join(", ")
}
