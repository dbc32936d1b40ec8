//! `calibrate`: IMU-offset calibration sessions (two throw-and-catches, held still before and
//! after each) on the simulator, fitted as `configurator-cli fit imu-offset` fits them, judged
//! against the truth.
//!
//! ```text
//! cargo run -p sim --release --bin calibrate -- monte-carlo --sessions 200 --bias 0.02
//! cargo run -p sim --release --bin calibrate -- monte-carlo --airframe hex-flat --no-drag
//! cargo run -p sim --release --bin calibrate -- monte-carlo --bias 0.1 --spins body-axes
//! ```
//!
//! Besides the two logs fitted offline, each session is thrown as one stream and fed to the
//! board's estimator: its verdict at the second catch and after the rest that follows.

use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use imu_offset::DragModel;
use sim::airframe::Airframe;
use sim::calibration::{monte_carlo, Judged, Plan, SpinDraw, Summary, AIRFRAMES, REST_S};

#[derive(Parser, Debug)]
#[command(version, about = "IMU-offset calibration sessions against the simulator's truth")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Random two-throw sessions (0.8–1.5 m apex, 300–600 °/s about axes ≥ 50° apart, a random
    /// accelerometer bias) cycling through the built-in airframes.
    MonteCarlo {
        /// Number of sessions.
        #[arg(long, default_value_t = 200)]
        sessions: usize,
        /// Accelerometer bias, 1σ per axis (m/s²).
        #[arg(long, default_value_t = 0.02)]
        bias: f64,
        /// First seed (session i uses seed + i).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Worker threads.
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// One airframe for every session (a built-in name or a TOML file) instead of the quads.
        #[arg(long)]
        airframe: Option<String>,
        /// Fit without the per-throw drag model (the seed paper's eq. 3), as
        /// `fit imu-offset --no-drag`.
        #[arg(long)]
        no_drag: bool,
        /// How the two spins are drawn: `random` (each its own rate), `equal-rate` (one rate,
        /// random axes ≥ 50° apart), `body-axes` (one rate, about two different body axes).
        #[arg(long, value_enum, default_value_t = Spins::Random)]
        spins: Spins,
        /// Print every session's result.
        #[arg(long)]
        verbose: bool,
    },
}

/// [`SpinDraw`] on the command line.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum Spins {
    Random,
    EqualRate,
    BodyAxes,
}

fn main() -> ExitCode {
    let Command::MonteCarlo { sessions, bias, seed, threads, airframe, no_drag, spins, verbose } =
        Args::parse().command;
    let spins = match spins {
        Spins::Random => SpinDraw::Random,
        Spins::EqualRate => SpinDraw::EqualRate,
        Spins::BodyAxes => SpinDraw::BodyAxes,
    };
    if !(bias.is_finite() && (0.0..=1.0).contains(&bias)) {
        eprintln!("calibrate: --bias must be within 0–1 m/s² (got {bias})");
        return ExitCode::FAILURE;
    }
    let airframe = match airframe.as_deref().map(Airframe::load) {
        None => None,
        Some(Ok(a)) => Some(a),
        Some(Err(e)) => {
            eprintln!("calibrate: {e}");
            return ExitCode::FAILURE;
        }
    };
    let airframes = match &airframe {
        Some(_) => "as given".to_string(),
        None => AIRFRAMES.join(", "),
    };
    let started = std::time::Instant::now();
    let drag_model = if no_drag { DragModel::Ignored } else { DragModel::VerticalQuadratic };
    let plan = Plan { bias_sigma_mps2: bias, airframe: airframe.as_ref(), drag_model, spins };
    let results = monte_carlo(sessions, seed, &plan, threads, &|done| {
        if done % 20 == 0 || done == sessions {
            eprintln!("calibrate: {done}/{sessions} sessions");
        }
    });
    println!(
        "{sessions} sessions (bias {bias} m/s² 1σ per axis, spins {spins:?}, rests of {REST_S} s, \
         airframes {}) in {:.0} s",
        airframes,
        started.elapsed().as_secs_f64()
    );
    if verbose {
        for r in &results {
            println!(
                "session {}: offset only {:?}; with bias {:?}; onboard at the catch {:?}; \
                 onboard after the rest {:?}",
                r.seed, r.offset_only, r.with_bias, r.onboard_at_catch, r.onboard_after_rest
            );
        }
    }
    let columns: [(&str, Vec<Option<Judged>>); 5] = [
        ("offset only (two logs)", results.iter().map(|r| r.offset_only).collect()),
        ("offset + bias, rest poses (two logs)", results.iter().map(|r| r.with_bias).collect()),
        ("one stream, fit imu-offset", results.iter().map(|r| r.offline_stream).collect()),
        (
            "one stream, onboard at the second catch",
            results.iter().map(|r| r.onboard_at_catch).collect(),
        ),
        (
            "one stream, onboard after the rest",
            results.iter().map(|r| r.onboard_after_rest).collect(),
        ),
    ];
    for (name, fits) in &columns {
        let s = Summary::of(fits);
        println!(
            "{name}: well determined {:.1} %, truth inside 95 % ellipsoid {:.1} % (axes × {:.2} for \
             exactly 95 %), error median {:.2} mm / 99th {:.2} mm / worst {:.2} mm, largest \
             semi-axis median {:.2} mm{}{}",
            100.0 * s.well_determined,
            100.0 * s.coverage,
            s.axes_factor,
            s.error_median_m * 1e3,
            s.error_p99_m * 1e3,
            s.error_max_m * 1e3,
            s.semi_axis_median_m * 1e3,
            s.bias_error_median_mps2
                .map(|b| format!(", bias error median {:.4} m/s²", b))
                .unwrap_or_default(),
            if s.failed > 0 { format!(", {} fits failed", s.failed) } else { String::new() },
        );
    }
    ExitCode::SUCCESS
}
