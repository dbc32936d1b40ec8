//! `fly`: throw-and-fly end to end (identification, recovery, position hold of the firmware
//! application) against the simulator's truth, one airframe or a Monte Carlo over random
//! airframes and throws, with every failure classified.
//!
//! ```text
//! cargo run -p sim --release --bin fly -- paper --airframe hex-tilted
//! cargo run -p sim --release --bin fly -- monte-carlo --runs 1000 --threads 2
//! cargo run -p sim --release --bin fly -- case --seed 21 --trace   # one Monte Carlo run again
//! cargo run -p sim --release --bin fly -- monte-carlo --runs 200 --mocap-rate-hz 2000 --mocap-latency-ms 30
//! cargo run -p sim --release --bin fly -- monte-carlo --runs 200 --world random --unknown-imu-offset
//! cargo run -p sim --release --bin fly -- monte-carlo --world random --runs 200 --no-speed-telemetry
//! cargo run -p sim --release --bin fly -- --end land monte-carlo --world random --gnss-random --runs 300
//! ```
//!
//! `--unknown-imu-offset` flies an uncalibrated board: the firmware is not given the airframe's
//! IMU offset (without it every run is a calibrated board's).
//!
//! `--no-speed-telemetry` flies ESCs that report no speed (the application told so through
//! `motor_bidir_dshot` = 0, which arms without them in a build that identifies from the
//! commands, `Params::arms_without_speeds`): the learner's commands-only path
//! (`flight::learner::no_speed`, issue 32). Every summary reports G1 and the thrust axis per
//! unit normalised thrust at the end of the excitation (`sim::recovery::thrust_scores`), the
//! figures that compare with and without telemetry.
//!
//! `--end land` (or `rc-lost`) ends every flight after its hover with a landing, as a host's
//! `land` (or the pilot's receiver once the radio has been lost for its grace) asks the control
//! step: each run then reports the touchdown's vertical speed against the truth and the time
//! from the first ground contact to the motors stopped, and the Monte Carlo how many landed
//! gently (below 0.7 m/s, stopped within 1 s).
//!
//! `--end catch` ends every flight after its hover with a hand grabbing the craft
//! (`sim::hand::GrabSpec`, drawn per seed in the random world): each run reports the time from
//! the grab to the motors stopped by the firmware's hand-catch detector, and every Monte Carlo
//! how often that detector stopped a craft in free flight, without a hand. `--gusts` adds the
//! random world's strong gusts during the hover (`sim::world`, aspect `gust`).
//!
//! `--wind` adds a steady wind of 0–8 m/s with turbulence for the whole run, the throw included
//! (`sim::world`, aspect `wind`; issue 55); `--wind-mps X` adds it with its steady speed forced to
//! X (bearing and turbulence as the seed draws them), so a sweep over the speed flies the same
//! cases. A Monte Carlo with the wind reports the speeds drawn and how many runs held in each
//! 2 m/s band of them; `fly case --seed N` with the same flags flies one of its runs again.
//!
//! `--gnss` flies on a simulated u-blox receiver instead of motion capture (`sim::gnss`, shaped by
//! `--gnss-noise-m`, `--gnss-rate-hz`, `--gnss-latency-ms`, `--gnss-multipath-per-min`,
//! `--gnss-multipath-s`); `--gnss-random` (or `--vary gnss`) on a receiver drawn per run
//! (`sim::world`, aspect `gnss`: 0.02–2 m, 5–10 Hz, 50–150 ms late, multipath, dropouts; the
//! firmware told its latency), and the Monte Carlo then reports, per band of the receivers'
//! noise and of their velocity noise, how many runs hovered and held within their own
//! receiver's bound (0.3 m + 2 hAcc horizontally, `sim::gnss::GnssModelConfig::held`), their
//! hold errors and how many learned their heading, with the seeds that did not hold.
//!
//! `--compass` (or `--vary compass`) draws a compass for every run (`sim::world`, aspect
//! `compass`: `sim::magnetometer`'s ranges, shown by `fly case --seed N --compass`) and flies
//! it: the user's calibration dance before the flight, the chip's registers read by the
//! firmware's compass service, its calibrated field to the pilot, which takes the heading from
//! it (`sim::compass_feed`, `firmware::app::compass_heading`). The compass draws nothing else:
//! with `--gnss` the same seeds fly the same worlds with and without it.
//!
//! Every command takes the motion capture's `--mocap-rate-hz`, `--mocap-jitter-ms`,
//! `--mocap-latency-ms`, `--mocap-noise-mm`, `--mocap-heading-noise-deg`,
//! `--mocap-dropouts-per-s` and `--mocap-dropout-s` (`sim::recovery::MotionCaptureArgs`; the
//! defaults are the nominal 100 Hz, 1 mm, on time). The firmware is told the latency and the
//! noise (its `pose_latency_s` and `pose_noise_m`), as a user would set them.

use std::collections::BTreeMap;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use sim::airframe::Airframe;
use sim::board::WorldEffects;
use sim::gnss::{GnssArgs, GnssModelConfig};
use sim::recovery::{
    fly, monte_carlo, random_case, FlightEnd, FlyConfig, FlyReport, MotionCaptureArgs,
    MotionCaptureConfig, Verdict,
};
use sim::stats::{quantile, BatchArgs};
use sim::world::{self, Aspect};

#[derive(Parser, Debug)]
#[command(version, about = "Throw-and-fly against the simulator's truth")]
struct Args {
    #[command(subcommand)]
    command: Command,
    #[command(flatten)]
    mocap: MotionCaptureArgs,
    #[command(flatten)]
    gnss: GnssArgs,
    /// How each flight ends after its hover: `hover` (the run stops), `land` (a host's
    /// `land`), `rc-lost` (the radio lost in flight: the receiver's landing).
    #[arg(long, global = true, default_value = "hover", value_parser = FlightEnd::parse)]
    end: FlightEnd,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// The seed paper's experiment: a 3.5 m parabola released at (400, 400, 100) °/s.
    Paper {
        /// Airframe: a built-in name or a TOML file.
        #[arg(long, default_value = "paper-quad")]
        airframe: String,
        /// Noise seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print the flight every 100 ms.
        #[arg(long)]
        trace: bool,
        /// Body rate at release, °/s, body axes x,y,z (the paper's 400,400,100).
        #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
        rate_dps: Option<Vec<f64>>,
        /// How long the hand takes to let go at the end of its push, ms (0–50).
        #[arg(long, default_value_t = 0.0)]
        taper_ms: f64,
        /// How long the hand pushes, ms, taper included (100–300).
        #[arg(long, default_value_t = 150.0)]
        push_ms: f64,
        /// ESCs without speed telemetry (see `monte-carlo --no-speed-telemetry`).
        #[arg(long)]
        no_speed_telemetry: bool,
        /// Do not give the firmware the airframe's true IMU offset: it is fitted in flight
        /// (issue 32; see `monte-carlo --unknown-imu-offset`).
        #[arg(long)]
        unknown_imu_offset: bool,
        /// No motion capture: the craft flies level hold on its own estimates.
        #[arg(long)]
        no_mocap: bool,
    },
    /// One Monte Carlo case, replayed alone.
    Case {
        /// The case's seed (as printed by `monte-carlo`).
        #[arg(long)]
        seed: u64,
        /// Print the flight every 100 ms.
        #[arg(long)]
        trace: bool,
        #[command(flatten)]
        world: WorldArgs,
    },
    /// Random airframes (4–8 motors, tilted rotors, any IMU pose) and random throws (300–600 °/s
    /// about a random axis, 2.5–4.5 m apex, up to 2 m/s sideways).
    MonteCarlo {
        #[command(flatten)]
        batch: BatchArgs,
        #[command(flatten)]
        world: WorldArgs,
        /// Also write one line per run to this file (CSV: seed, verdict, motors, the slowest
        /// motor's τ in ms, the steady wind and the turbulence's σ in m/s, its correlation time
        /// in s, the worst distance from the setpoint over the hold and its horizontal part in m,
        /// the share of the hold window flown in position hold, release → hover in s, and on a
        /// GNSS receiver its own worst horizontal error over the hold in m).
        #[arg(long)]
        runs_csv: Option<std::path::PathBuf>,
    },
}

/// Which aspects of the world are randomised (`sim::world`).
#[derive(clap::Args, Debug)]
struct WorldArgs {
    /// `nominal` (the airframe and the throw's spin and height vary, nothing else) or `random`
    /// (every aspect of `sim::world` drawn: hand, pose, imu, actuators, air; gust, wind, gnss and
    /// compass only with `--gusts`, `--wind`, `--gnss-random` and `--compass`).
    #[arg(long, default_value = "nominal", value_parser = ["nominal", "random"])]
    world: String,
    /// Randomise only this aspect (hand, pose, imu, actuators, air, gust, wind, gnss, compass);
    /// repeatable.
    #[arg(long)]
    vary: Vec<String>,
    /// Add strong gusts to the random world while the craft hovers (the `gust` aspect:
    /// a 1 − cos gust of 2–8 m/s and a step gust of 1–4 m/s).
    #[arg(long)]
    gusts: bool,
    /// Add a steady wind with turbulence for the whole run (the `wind` aspect: 0–8 m/s from a
    /// random bearing, turbulence of 10–20 % of it + 0.1 m/s, correlated over 1–3 s).
    #[arg(long)]
    wind: bool,
    /// Add the wind (as `--wind`) with its steady speed forced to this, m/s (0–20): the bearing
    /// and the turbulence as the seed draws them, for a sweep over the speed.
    #[arg(long)]
    wind_mps: Option<f64>,
    /// Fly every run on a GNSS receiver drawn for it (the `gnss` aspect: noise 0.02–2 m
    /// correlated over 2–60 s, 5–10 Hz, 50–150 ms late, multipath jumps, dropouts; the firmware
    /// told its latency) instead of motion capture; the report gives the holds per noise band.
    #[arg(long)]
    gnss_random: bool,
    /// Draw a compass for every run (the `compass` aspect: field 25–65 µT, dip ±70°,
    /// declination ±30°, hard iron ±300 µT, soft iron 20 %, any mounting, 0.3–2 µT of noise,
    /// 50–100 Hz, motor interference up to 50 %), calibrated by the user's dance and flown.
    #[arg(long)]
    compass: bool,
    /// Do not give the firmware the airframe's true IMU offset (a board never calibrated: it
    /// flies with none, issue 32).
    #[arg(long)]
    unknown_imu_offset: bool,
    /// ESCs without speed telemetry: the simulated ESCs report no speed and the application is
    /// told so (`motor_bidir_dshot` = 0); the same airframes, throws and worlds otherwise.
    #[arg(long)]
    no_speed_telemetry: bool,
}

impl WorldArgs {
    /// The aspects to randomise, or an error naming the bad one.
    fn aspects(&self) -> Result<Vec<Aspect>, String> {
        if self.world == "random" {
            if !self.vary.is_empty() {
                return Err("--vary goes with --world nominal (random varies everything)".into());
            }
            let mut aspects = Aspect::ALL.to_vec();
            if self.gusts {
                aspects.push(Aspect::Gust);
            }
            if self.windy() {
                aspects.push(Aspect::Wind);
            }
            if self.gnss_random {
                aspects.push(Aspect::Gnss);
            }
            if self.compass {
                aspects.push(Aspect::Compass);
            }
            return Ok(aspects);
        }
        let mut aspects: Vec<Aspect> =
            self.vary.iter().map(|name| Aspect::parse(name)).collect::<Result<_, _>>()?;
        if self.gusts && !aspects.contains(&Aspect::Gust) {
            aspects.push(Aspect::Gust);
        }
        if self.windy() && !aspects.contains(&Aspect::Wind) {
            aspects.push(Aspect::Wind);
        }
        if self.gnss_random && !aspects.contains(&Aspect::Gnss) {
            aspects.push(Aspect::Gnss);
        }
        if self.compass && !aspects.contains(&Aspect::Compass) {
            aspects.push(Aspect::Compass);
        }
        Ok(aspects)
    }

    /// Whether the wind was asked for (`--wind` or `--wind-mps`).
    fn windy(&self) -> bool {
        self.wind || self.wind_mps.is_some()
    }
}

/// Largest steady wind `--wind-mps` takes, m/s: beyond the aspect's 8 m/s, for a sweep past it,
/// and below what a small craft can lean into.
const WIND_MPS_LIMIT: f64 = 20.0;

/// Width of the wind-speed bands the Monte Carlo reports its holds in, m/s.
const WIND_BAND_MPS: f64 = 2.0;

/// Monte Carlo case `seed`: the nominal case with `motion_capture`, or the world with `aspects`
/// randomised; the IMU offset given to the firmware unless `args.unknown_imu_offset`; on the
/// receiver the `gnss` aspect drew, else on `gnss` (`--gnss`), else on motion capture.
fn case(
    seed: u64,
    aspects: &[Aspect],
    motion_capture: MotionCaptureConfig,
    gnss: &Option<GnssModelConfig>,
    args: &WorldArgs,
) -> (Airframe, FlyConfig) {
    // The compass is drawn on its own stream: the nominal world stays nominal, its motion
    // capture the command line's, with a compass on the craft.
    let world_aspects = randomising(aspects);
    let (mut airframe, mut config) = if world_aspects.is_empty() {
        let (airframe, mut config) = random_case(seed);
        config.motion_capture = motion_capture;
        (airframe, config)
    } else {
        world::random_world_case(seed, &world_aspects)
    };
    if aspects.contains(&Aspect::Compass) {
        world::apply(Aspect::Compass, seed, &mut airframe, &mut config);
    }
    if let Some(speed_mps) = args.wind_mps {
        world::apply_wind_at(seed, speed_mps, &mut config);
    }
    config.known_imu_offset = !args.unknown_imu_offset;
    config.speed_telemetry = !args.no_speed_telemetry;
    if config.gnss.is_none() {
        config.gnss.clone_from(gnss);
    }
    (airframe, config)
}

/// The aspects of the world around the craft: all but the compass, which is drawn onto the
/// nominal or random world after them (`FlyConfig::compass`).
fn randomising(aspects: &[Aspect]) -> Vec<Aspect> {
    aspects.iter().copied().filter(|a| *a != Aspect::Compass).collect()
}

/// `label: median …, 90th …, 99th … (n runs)` of `values` times `scale`, in `unit`.
fn print_quantiles(label: &str, values: &[f64], scale: f64, unit: &str) {
    println!(
        "{label}: median {:.2}{unit}, 90th {:.2}{unit}, 99th {:.2}{unit} ({} runs)",
        scale * quantile(values, 0.5),
        scale * quantile(values, 0.9),
        scale * quantile(values, 0.99),
        values.len()
    );
}

fn print_report(name: &str, report: &FlyReport) {
    println!("{name}: {:?} ({:?})", Verdict::of(report), report.outcome);
    println!(
        "  release → engage {:.0} ms (the excitation's end → engage {:.1} ms), → hover {:.2} s",
        report.release_to_engage_s.unwrap_or(f64::NAN) * 1e3,
        report.excitation_end_to_engage_s.unwrap_or(f64::NAN) * 1e3,
        report.release_to_hover_s.unwrap_or(f64::NAN)
    );
    println!("  worst drop below the release point {:.2} m", report.max_drop_below_release_m);
    if let (Some(height), Some(descent), Some(axis)) =
        (report.engaged_height_m, report.engaged_descent_mps, report.engaged_axis_from_up_deg)
    {
        println!(
            "  engaged {height:.2} m above the ground, falling at {descent:.2} m/s, thrust axis {axis:.0}° from up"
        );
    }
    println!(
        "  worst distance from the position setpoint over the last {:.0} s: {:.3} m",
        report.hold_window_s,
        report.max_hold_error_m.unwrap_or(f64::NAN)
    );
    println!(
        "  body rate in position hold over that window: {:.1} °/s RMS",
        report.hold_rate_rms_rad_s.unwrap_or(f64::NAN).to_degrees()
    );
    let blocks = |b: Option<[f64; 2]>| match b {
        Some([force, rotation]) => {
            format!("force {:.2} %, rotation {:.2} %", 100.0 * force, 100.0 * rotation)
        }
        None => "none".to_owned(),
    };
    println!(
        "  G1 relative RMS error per block: at engagement {}; learned at the end {}; flown at the end {} ({} refinements in flight, {} controllers re-formed)",
        blocks(report.g1_block_rel_at_engage),
        blocks(report.g1_block_rel_learned_at_end),
        blocks(report.g1_block_rel_flown_at_end),
        report.refinements,
        report.reforms
    );
    if let Some(fit) = report.r_imu_fit_m {
        println!(
            "  IMU offset fitted in flight {:.1?} mm (true {:.1?} mm): error {:.2} mm, largest 95 % semi-axis {:.2} mm",
            (fit * 1e3).as_slice(),
            (report.r_imu_true_m * 1e3).as_slice(),
            (fit - report.r_imu_true_m).norm() * 1e3,
            report.r_imu_fit_semi_axis_m.unwrap_or(f64::NAN) * 1e3
        );
    }
    if let Some(catch) = report.catch {
        println!(
            "  grabbed by a hand (τ {:.2} s, tilt {:.1}°, pull {:.2} m): motors stopped {}",
            catch.grab.tau_s,
            catch.grab.tilt_world_rad.norm().to_degrees(),
            catch.grab.pull_ned_m.norm(),
            catch.stopped_after_s.map_or("never".into(), |t| format!("{t:.3} s after the grab"))
        );
    }
    if let Some(at_s) = report.false_catch_s {
        println!("  the hand-catch detector stopped the motors in free flight {at_s:.2} s after the release");
    }
    if let Some((reason, at_s)) = report.landed_by_itself {
        println!(
            "  the firmware began a landing by itself {at_s:.2} s after the release: {reason:?}"
        );
    }
    if let Some(landing) = report.landing {
        let or_nan = |v: Option<f64>| v.unwrap_or(f64::NAN);
        println!(
            "  landing from {:.2} m: touchdown at {:.2} m/s, {:.2} m from where it began, motors stopped {:.2} s after it{}",
            landing.requested_height_m,
            or_nan(landing.touchdown_speed_mps),
            or_nan(landing.horizontal_drift_m),
            or_nan(landing.stop_delay_s),
            landing
                .stopped_in_air_m
                .map_or(String::new(), |h| format!("; STOPPED IN THE AIR at {h:.2} m")),
        );
    }
    if let Some(s) = report.thrust_scores_at_excitation_end {
        println!(
            "  per unit thrust at the end of the excitation: G1 force {:.2} %, rotation {:.2} %, thrust axis {:.2}°, worst |τ error| {:.2} ms",
            100.0 * s.g1_block_rel[0],
            100.0 * s.g1_block_rel[1],
            s.axis_angle_rad.to_degrees(),
            1e3 * s.tau_error_max_s
        );
    }
}

/// The landings of a Monte Carlo (`--end land` or `rc-lost`): how many of the runs still
/// flying when it was asked for landed gently, the touchdown speeds and stop delays, and every
/// seed that did not.
fn print_landings(results: &[sim::recovery::CaseResult]) {
    let landings: Vec<(u64, sim::recovery::LandingReport)> =
        results.iter().filter_map(|r| Some((r.seed, r.report.landing?))).collect();
    if landings.is_empty() {
        return;
    }
    let gentle = landings.iter().filter(|(_, l)| l.gentle()).count();
    println!(
        "landings: {gentle} of {} gentle ({:.1} %: below {} m/s, motors stopped within {} s)",
        landings.len(),
        100.0 * gentle as f64 / landings.len() as f64,
        sim::recovery::GENTLE_TOUCHDOWN_MPS,
        sim::recovery::STOP_AFTER_TOUCHDOWN_S
    );
    let speeds: Vec<f64> = landings.iter().filter_map(|(_, l)| l.touchdown_speed_mps).collect();
    let delays: Vec<f64> = landings.iter().filter_map(|(_, l)| l.stop_delay_s).collect();
    let drifts: Vec<f64> = landings.iter().filter_map(|(_, l)| l.horizontal_drift_m).collect();
    print_quantiles("  touchdown vertical speed", &speeds, 1.0, " m/s");
    print_quantiles("  touchdown → motors stopped", &delays, 1.0, " s");
    print_quantiles("  touchdown's distance from where the landing began", &drifts, 1.0, " m");
    let worst_speed = speeds.iter().copied().fold(0.0, f64::max);
    let worst_delay = delays.iter().copied().fold(0.0, f64::max);
    println!("  worst: touchdown {worst_speed:.2} m/s, stopped {worst_delay:.2} s after it");
    let not_gentle: Vec<String> = landings
        .iter()
        .filter(|(_, l)| !l.gentle())
        .map(|(seed, l)| match (l.stopped_in_air_m, l.touchdown_speed_mps, l.stop_delay_s) {
            (Some(h), _, _) => format!("{seed} (stopped in the air at {h:.2} m)"),
            (_, Some(v), Some(t)) => format!("{seed} ({v:.2} m/s, stopped after {t:.2} s)"),
            (_, Some(v), None) => format!("{seed} ({v:.2} m/s, motors never stopped)"),
            _ => format!("{seed} (never touched down)"),
        })
        .collect();
    if !not_gentle.is_empty() {
        println!("  not gentle: {}", not_gentle.join(", "));
    }
}

/// After the recovery, until a landing began or the flight ended: the fastest horizontal speed
/// and the distance from where each craft recovered at the end, and every seed that ended more
/// than [`END_FROM_RECOVERY_LIMIT_M`] away.
fn print_after_recovery(results: &[sim::recovery::CaseResult]) {
    let speeds: Vec<f64> =
        results.iter().filter_map(|r| r.report.max_speed_after_recovery_mps).collect();
    let ends: Vec<(u64, f64)> =
        results.iter().filter_map(|r| Some((r.seed, r.report.end_from_recovery_m?))).collect();
    if ends.is_empty() {
        return;
    }
    println!("after the recovery ({} runs that recovered):", ends.len());
    print_quantiles("  fastest horizontal speed", &speeds, 1.0, " m/s");
    let hold_rates: Vec<f64> =
        results.iter().filter_map(|r| r.report.hold_rate_rms_rad_s).collect();
    print_quantiles(
        "  body rate in the hold window (RMS)",
        &hold_rates,
        180.0 / std::f64::consts::PI,
        " °/s",
    );
    let distances: Vec<f64> = ends.iter().map(|(_, d)| *d).collect();
    print_quantiles("  distance at the end from where it recovered", &distances, 1.0, " m");
    let far: Vec<String> = ends
        .iter()
        .filter(|(_, d)| *d > END_FROM_RECOVERY_LIMIT_M)
        .map(|(seed, d)| format!("{seed} ({d:.2} m)"))
        .collect();
    println!(
        "  ended more than {END_FROM_RECOVERY_LIMIT_M} m from where it recovered: {}{}",
        far.len(),
        if far.is_empty() { String::new() } else { format!(": {}", far.join(", ")) }
    );
}

/// Upper edges of the bands of the slowest motor's time constant a Monte Carlo reports its holds
/// in, s: the loops' gains scale as 1/τ, so a push the position loop must take up leaves a
/// static error growing as τ² (`flight::position`), and a figure over all airframes hides where
/// it fails.
const MOTOR_TAU_BAND_EDGES_S: [f64; 3] = [0.03, 0.045, 0.06];

/// Holds per band of [`MOTOR_TAU_BAND_EDGES_S`].
fn print_by_motor_tau(results: &[sim::recovery::CaseResult]) {
    let band_of = |tau: f64| MOTOR_TAU_BAND_EDGES_S.iter().take_while(|&&edge| tau >= edge).count();
    for band in 0..=MOTOR_TAU_BAND_EDGES_S.len() {
        let of: Vec<_> =
            results.iter().filter(|r| band_of(r.slowest_motor_tau_s) == band).collect();
        if of.is_empty() {
            continue;
        }
        let held = of.iter().filter(|r| r.verdict == Verdict::Held).count();
        let from_ms = if band == 0 { 0.0 } else { MOTOR_TAU_BAND_EDGES_S[band - 1] * 1e3 };
        let range = match MOTOR_TAU_BAND_EDGES_S.get(band) {
            Some(edge) => format!("{from_ms:.0}–{:.0} ms", edge * 1e3),
            None => format!("≥ {from_ms:.0} ms"),
        };
        println!(
            "  slowest motor τ {range}: {} runs, held {held} ({:.1} %)",
            of.len(),
            100.0 * held as f64 / of.len() as f64
        );
    }
}

/// The runs as CSV, one line each after a header (`--runs-csv`); empty fields where a figure
/// does not exist (no wind drawn, no hold flown).
fn runs_csv_text(results: &[sim::recovery::CaseResult], worlds: &[WorldEffects]) -> String {
    let optional = |x: Option<f64>| x.map(|x| format!("{x:.4}")).unwrap_or_default();
    let mut text = String::from(
        "seed,verdict,motors,slowest_tau_ms,wind_mps,turbulence_sigma_mps,turbulence_correlation_s,worst_hold_m,worst_hold_horizontal_m,hold_coverage,release_to_hover_s,worst_fix_error_horizontal_m\n",
    );
    for (r, world) in results.iter().zip(worlds) {
        let wind = nalgebra::Vector3::from(world.steady_wind_ned_mps).norm();
        let (sigma, correlation) = match &world.turbulence {
            Some(t) => (Some(t.sigma_ned_mps[0]), Some(t.correlation_s)),
            None => (None, None),
        };
        text += &format!(
            "{},{:?},{},{:.1},{:.3},{},{},{},{},{:.3},{},{}\n",
            r.seed,
            r.verdict,
            r.motors,
            r.slowest_motor_tau_s * 1e3,
            wind,
            optional(sigma),
            optional(correlation),
            optional(r.report.max_hold_error_m),
            optional(r.report.max_hold_error_horizontal_m),
            r.report.hold_coverage,
            optional(r.report.release_to_hover_s),
            optional(r.report.max_fix_error_horizontal_m),
        );
    }
    text
}

/// How far from where it recovered a craft with a fresh pose may end its flight, m (issue 53).
const END_FROM_RECOVERY_LIMIT_M: f64 = 2.0;

/// The wind of a Monte Carlo that drew it (`worlds[i]` is `results[i]`'s): the steady speeds
/// and the turbulence drawn, and per [`WIND_BAND_MPS`] band of the speed how many runs held, how
/// the others ended and, with a landing, how many landed gently.
fn print_winds(results: &[sim::recovery::CaseResult], worlds: &[WorldEffects]) {
    let speeds: Vec<f64> =
        worlds.iter().map(|w| nalgebra::Vector3::from(w.steady_wind_ned_mps).norm()).collect();
    let turbulence: Vec<_> = worlds.iter().filter_map(|w| w.turbulence).collect();
    let sigmas: Vec<f64> = turbulence.iter().map(|t| t.sigma_ned_mps[0]).collect();
    let times: Vec<f64> = turbulence.iter().map(|t| t.correlation_s).collect();
    println!(
        "steady wind: min {:.2} m/s, median {:.2} m/s, 90th {:.2} m/s, max {:.2} m/s ({} runs)",
        speeds.iter().copied().fold(f64::INFINITY, f64::min),
        quantile(&speeds, 0.5),
        quantile(&speeds, 0.9),
        speeds.iter().copied().fold(0.0, f64::max),
        speeds.len()
    );
    print_quantiles("  turbulence's horizontal σ", &sigmas, 1.0, " m/s");
    print_quantiles("  turbulence's correlation time", &times, 1.0, " s");
    let mut bands: BTreeMap<u32, Vec<&sim::recovery::CaseResult>> = BTreeMap::new();
    for (r, speed) in results.iter().zip(&speeds) {
        // The speed from its components may fall a rounding short of a forced band edge.
        let band = (speed / WIND_BAND_MPS + 1e-9).floor() as u32;
        bands.entry(band).or_default().push(r);
    }
    for (band, runs) in &bands {
        let held = runs.iter().filter(|r| r.verdict == Verdict::Held).count();
        let mut others: BTreeMap<String, usize> = BTreeMap::new();
        for r in runs.iter().filter(|r| r.verdict != Verdict::Held) {
            *others.entry(format!("{:?}", r.verdict)).or_default() += 1;
        }
        let others: Vec<String> = others.iter().map(|(v, n)| format!("{v} {n}")).collect();
        let landings: Vec<_> = runs.iter().filter_map(|r| r.report.landing).collect();
        let gentle = landings.iter().filter(|l| l.gentle()).count();
        println!(
            "  wind {:.0}–{:.0} m/s: {} runs, held {held} ({:.1} %), not held {}{}{}",
            f64::from(*band) * WIND_BAND_MPS,
            f64::from(band + 1) * WIND_BAND_MPS,
            runs.len(),
            100.0 * held as f64 / runs.len() as f64,
            runs.len() - held,
            if others.is_empty() { String::new() } else { format!(" ({})", others.join(", ")) },
            if landings.is_empty() {
                String::new()
            } else {
                format!("; landed gently {gentle} of {}", landings.len())
            }
        );
    }
}

/// Upper edges of the receiver-noise bands a Monte Carlo with the `gnss` aspect reports its
/// holds in, m (the correlated horizontal error per axis; the bands run over
/// [`sim::gnss::RANDOM_NOISE_M`]): RTK-like and dual-frequency receivers below 0.1 m, a good
/// single-frequency one in the open up to 0.3 m (`fly --gnss`'s), a partial sky up to 1 m, and
/// worse.
const GNSS_NOISE_BAND_EDGES_M: [f64; 3] = [0.1, 0.3, 1.0];

/// Upper edges of the velocity-noise bands the same report gives, m/s per axis (over
/// [`sim::gnss::RANDOM_VELOCITY_NOISE_MPS`]): the heading is learned from the receiver's
/// velocity changes, so its noise decides how soon the craft can hold a position.
const GNSS_VELOCITY_BAND_EDGES_MPS: [f64; 3] = [0.05, 0.1, 0.15];

/// Seeds listed per band of a report, at most (the rest are counted).
const SEEDS_LISTED: usize = 20;

/// The receivers of a Monte Carlo that drew them (`receivers[i]` is `results[i]`'s): what was
/// drawn, and per [`GNSS_NOISE_BAND_EDGES_M`] band of the noise and per
/// [`GNSS_VELOCITY_BAND_EDGES_MPS`] band of the velocity noise how many runs hovered and held,
/// the worst horizontal distance from the setpoint over the hold window, the heading, the fixes
/// refused and the landings, with the seeds that did not hold.
///
/// "Held" scales with each run's receiver ([`GnssModelConfig::held`]): within 0.3 m + 2 hAcc of
/// the setpoint horizontally. Per band of the receiver's noise that is about 0.36–0.6 m in
/// 0.02–0.1 m, 0.6–1.2 m in 0.1–0.3 m, 1.2–3.2 m in 0.3–1 m and 3.1–6.2 m in 1–2 m (the white
/// noise, drawn per run, makes the ranges overlap a little; each band prints its own).
fn print_gnss_bands(results: &[sim::recovery::CaseResult], receivers: &[GnssModelConfig]) {
    let sigmas: Vec<f64> = receivers.iter().map(|g| g.horizontal_sigma_m).collect();
    print_quantiles(
        "GNSS receivers drawn: correlated error per horizontal axis",
        &sigmas,
        1.0,
        " m",
    );
    let rates: Vec<f64> = receivers.iter().map(|g| g.rate_hz).collect();
    let latencies: Vec<f64> = receivers.iter().map(|g| g.latency_s).collect();
    print_quantiles("  solutions per second", &rates, 1.0, " Hz");
    print_quantiles("  latency (the firmware told it)", &latencies, 1e3, " ms");
    println!(
        "  held: hovered, and the worst horizontal distance from the setpoint over the hold \
         window within {} m + {} hAcc of the run's receiver",
        sim::gnss::HOLD_CONTROL_ALLOWANCE_M,
        sim::gnss::HOLD_FIX_RMS_MULTIPLE
    );
    let runs: Vec<_> = results.iter().zip(receivers).collect();
    print_gnss_band_lines(
        &runs,
        "noise",
        " m",
        &GNSS_NOISE_BAND_EDGES_M,
        sim::gnss::RANDOM_NOISE_M,
        |g| g.horizontal_sigma_m,
    );
    print_gnss_band_lines(
        &runs,
        "velocity noise",
        " m/s",
        &GNSS_VELOCITY_BAND_EDGES_MPS,
        sim::gnss::RANDOM_VELOCITY_NOISE_MPS,
        |g| g.velocity_noise_mps,
    );
    let held = runs.iter().filter(|(r, g)| g.held(&r.report)).count();
    println!(
        "  held within their receivers' bounds: {held} of {} runs ({:.1} %)",
        results.len(),
        100.0 * held as f64 / results.len().max(1) as f64
    );
}

/// One line per band of `value` (edges `edges`, the whole over `range`) of the runs on their
/// receivers: see [`print_gnss_bands`].
fn print_gnss_band_lines(
    runs: &[(&sim::recovery::CaseResult, &GnssModelConfig)],
    name: &str,
    unit: &str,
    edges: &[f64],
    range: (f64, f64),
    value: fn(&GnssModelConfig) -> f64,
) {
    let mut bands: BTreeMap<usize, Vec<(&sim::recovery::CaseResult, &GnssModelConfig)>> =
        BTreeMap::new();
    for &(r, g) in runs {
        bands
            .entry(edges.iter().filter(|&&edge| value(g) >= edge).count())
            .or_default()
            .push((r, g));
    }
    let hovered =
        |r: &sim::recovery::CaseResult| matches!(r.verdict, Verdict::Held | Verdict::HoveredLoose);
    for (band, runs) in &bands {
        let low = if *band == 0 { range.0 } else { edges[band - 1] };
        let high = edges.get(*band).copied().unwrap_or(range.1);
        let hovered_runs = runs.iter().filter(|(r, _)| hovered(r)).count();
        let held_runs = runs.iter().filter(|(r, g)| g.held(&r.report)).count();
        let bounds: Vec<f64> = runs.iter().map(|(_, g)| g.hold_bound_m()).collect();
        let errors: Vec<f64> =
            runs.iter().filter_map(|(r, _)| r.report.max_hold_error_horizontal_m).collect();
        let aligned = runs.iter().filter(|(r, _)| r.report.heading_aligned_s.is_some()).count();
        let within_10_deg = runs
            .iter()
            .filter(|(r, _)| r.report.heading_error_deg.is_some_and(|e| e.abs() <= 10.0))
            .count();
        let refused = runs.iter().filter(|(r, _)| r.report.fixes_rejected > 0).count();
        let landings: Vec<_> = runs.iter().filter_map(|(r, _)| r.report.landing).collect();
        let gentle = landings.iter().filter(|l| l.gentle()).count();
        println!(
            "  {name} {low:.2}–{high:.2}{unit}: {} runs, hovered {hovered_runs}, held {held_runs} \
             ({:.1} %; bounds {:.2}–{:.2} m); horizontal hold error median {:.2} m, 90th {:.2} \
             m; heading learned {aligned}, within 10° at the end {within_10_deg}; fixes refused \
             in {refused}{}",
            runs.len(),
            100.0 * held_runs as f64 / runs.len() as f64,
            bounds.iter().copied().fold(f64::INFINITY, f64::min),
            bounds.iter().copied().fold(0.0, f64::max),
            quantile(&errors, 0.5),
            quantile(&errors, 0.9),
            if landings.is_empty() {
                String::new()
            } else {
                format!("; landed gently {gentle} of {}", landings.len())
            }
        );
        let not_held: Vec<String> = runs
            .iter()
            .filter(|(r, g)| !g.held(&r.report))
            .map(|(r, g)| match r.report.max_hold_error_horizontal_m {
                Some(e) if hovered(r) => format!(
                    "{} ({e:.2} m, bound {:.2} m, in hold {:.0} % of the window)",
                    r.seed,
                    g.hold_bound_m(),
                    100.0 * r.report.hold_coverage
                ),
                None if hovered(r) && r.report.heading_aligned_s.is_none() => {
                    format!("{} (heading never learned)", r.seed)
                }
                None if hovered(r) => format!("{} (no position hold)", r.seed),
                _ => format!("{} ({:?})", r.seed, r.verdict),
            })
            .collect();
        if !not_held.is_empty() {
            let more = not_held.len().saturating_sub(SEEDS_LISTED);
            println!(
                "    not held: {}{}",
                not_held[..not_held.len().min(SEEDS_LISTED)].join(", "),
                if more > 0 { format!(" and {more} more") } else { String::new() }
            );
        }
    }
}

/// The hand's grabs of a Monte Carlo (`--end catch`), and the hand-catch detector's stops
/// without a hand (every `--end`).
fn print_catches(results: &[sim::recovery::CaseResult]) {
    let false_catches: Vec<String> = results
        .iter()
        .filter(|r| r.report.false_catch_s.is_some())
        .map(|r| r.seed.to_string())
        .collect();
    println!(
        "hand-catch detector in free flight (no hand): {} of {} runs stopped{}",
        false_catches.len(),
        results.len(),
        if false_catches.is_empty() {
            String::new()
        } else {
            format!(" (seeds {})", false_catches.join(", "))
        }
    );
    let grabs: Vec<(u64, sim::recovery::CatchReport)> =
        results.iter().filter_map(|r| Some((r.seed, r.report.catch?))).collect();
    if grabs.is_empty() {
        return;
    }
    let latencies: Vec<f64> = grabs.iter().filter_map(|(_, c)| c.stopped_after_s).collect();
    let in_time = latencies.iter().filter(|&&t| t <= sim::recovery::CATCH_DETECT_MAX_S).count();
    println!(
        "grabs: {} of {} hovering craft stopped, {in_time} within {} s",
        latencies.len(),
        grabs.len(),
        sim::recovery::CATCH_DETECT_MAX_S
    );
    if !latencies.is_empty() {
        println!(
            "  grab → motors stopped: median {:.3} s, 99th {:.3} s, worst {:.3} s",
            quantile(&latencies, 0.5),
            quantile(&latencies, 0.99),
            latencies.iter().cloned().fold(0.0, f64::max)
        );
    }
    let late: Vec<String> = grabs
        .iter()
        .filter(|(_, c)| c.stopped_after_s.is_none_or(|t| t > sim::recovery::CATCH_DETECT_MAX_S))
        .map(|(seed, c)| {
            format!(
                "{seed} ({}; τ {:.2} s, tilt {:.1}°, pull {:.2} m)",
                c.stopped_after_s.map_or("never".into(), |t| format!("{t:.3} s")),
                c.grab.tau_s,
                c.grab.tilt_world_rad.norm().to_degrees(),
                c.grab.pull_ned_m.norm()
            )
        })
        .collect();
    if !late.is_empty() {
        println!("  late or never: {}", late.join(", "));
    }
}

/// The aspects to randomise; a usage error (exit code 2) for a bad name, for motion-capture
/// flags beside a randomised world, or for receiver flags beside a drawn receiver.
fn checked_aspects(
    args: &WorldArgs,
    motion_capture: MotionCaptureConfig,
    gnss: &GnssArgs,
) -> Result<Vec<Aspect>, ExitCode> {
    let aspects = args.aspects().map_err(|e| {
        eprintln!("fly: {e}");
        ExitCode::from(2)
    })?;
    if let Some(speed_mps) = args.wind_mps {
        if !(0.0..=WIND_MPS_LIMIT).contains(&speed_mps) {
            eprintln!("fly: --wind-mps must be within 0–{WIND_MPS_LIMIT} m/s");
            return Err(ExitCode::from(2));
        }
    }
    if !randomising(&aspects).is_empty() && motion_capture != MotionCaptureConfig::default() {
        eprintln!("fly: the --mocap-* flags do not combine with --world random or --vary");
        return Err(ExitCode::from(2));
    }
    if aspects.contains(&Aspect::Gnss) && gnss.shapes_receiver() {
        eprintln!(
            "fly: the --gnss-* flags do not combine with the gnss aspect (--gnss-random, --vary \
             gnss), which draws each run's receiver"
        );
        return Err(ExitCode::from(2));
    }
    Ok(aspects)
}

fn main() -> ExitCode {
    let args = Args::parse();
    let motion_capture = match args.mocap.config() {
        Ok(config) => config,
        Err(e) => {
            eprintln!("fly: {e}");
            return ExitCode::from(2);
        }
    };
    let gnss = match args.gnss.config() {
        Ok(config) => config,
        Err(e) => {
            eprintln!("fly: {e}");
            return ExitCode::from(2);
        }
    };
    if let Some(gnss) = &gnss {
        println!("GNSS instead of motion capture: {gnss:?}");
    }
    if motion_capture != MotionCaptureConfig::default() {
        println!("motion capture: {motion_capture:?}");
    }
    match args.command {
        Command::Paper {
            airframe,
            seed,
            trace,
            rate_dps,
            taper_ms,
            push_ms,
            no_speed_telemetry,
            unknown_imu_offset,
            no_mocap,
        } => {
            let airframe = match Airframe::load(&airframe) {
                Ok(a) => a,
                Err(e) => {
                    eprintln!("fly: {e}");
                    return ExitCode::from(2);
                }
            };
            let mut config = FlyConfig { motion_capture, end: args.end, ..FlyConfig::paper() };
            if !(0.0..=50.0).contains(&taper_ms) || !(100.0..=300.0).contains(&push_ms) {
                eprintln!("fly: --taper-ms must be within 0–50 and --push-ms within 100–300");
                return ExitCode::from(2);
            }
            if let Some(rate) = rate_dps {
                if rate.len() != 3 || !rate.iter().all(|x| x.is_finite() && x.abs() <= 2000.0) {
                    eprintln!("fly: --rate-dps takes three rates within ±2000 °/s");
                    return ExitCode::from(2);
                }
                config.throw.rate_body_rad_s =
                    nalgebra::Vector3::new(rate[0], rate[1], rate[2]).map(f64::to_radians);
            }
            config.throw.taper_s = taper_ms * 1e-3;
            config.throw.push_s = push_ms * 1e-3;
            config.board.seed = seed;
            config.trace = trace;
            config.mocap = !no_mocap;
            config.speed_telemetry = !no_speed_telemetry;
            config.known_imu_offset = !unknown_imu_offset;
            config.gnss = gnss;
            print_report(&airframe.name, &fly(&airframe, &config));
        }
        Command::Case { seed, trace, world: world_args } => {
            let aspects = match checked_aspects(&world_args, motion_capture, &args.gnss) {
                Ok(aspects) => aspects,
                Err(code) => return code,
            };
            let (airframe, mut config) = case(seed, &aspects, motion_capture, &gnss, &world_args);
            config.trace = trace;
            config.end = args.end;
            if !aspects.is_empty() {
                println!("world: {config:#?}");
            }
            println!(
                "case {seed}: {} motors, thrust-to-weight {:.2}, rate {:.0?} °/s, apex {:.2} m, sideways {:.2?} m/s",
                airframe.rotor_count(),
                sim::recovery::thrust_to_weight(&airframe),
                config.throw.rate_body_rad_s.map(f64::to_degrees).as_slice(),
                config.throw.apex_m,
                config.throw.horizontal_mps
            );
            print_report(&format!("case {seed}"), &fly(&airframe, &config));
        }
        Command::MonteCarlo {
            batch: BatchArgs { runs, seed, threads },
            world: world_args,
            runs_csv,
        } => {
            let aspects = match checked_aspects(&world_args, motion_capture, &args.gnss) {
                Ok(aspects) => aspects,
                Err(code) => return code,
            };
            let started = std::time::Instant::now();
            let progress = |done: usize| {
                if done.is_multiple_of(50) || done == runs {
                    eprintln!("fly: {done}/{runs} runs");
                }
            };
            let randomised = randomising(&aspects);
            if !randomised.is_empty() {
                let names: Vec<_> = randomised.iter().map(|a| a.name()).collect();
                println!("randomised: {}", names.join(", "));
            }
            if let Some(speed_mps) = world_args.wind_mps {
                println!("steady wind forced to {speed_mps} m/s (bearing and turbulence drawn)");
            }
            if world_args.unknown_imu_offset {
                println!("IMU offset not given to the firmware");
            }
            if world_args.no_speed_telemetry {
                println!("ESC speed telemetry: none (motor_bidir_dshot = 0)");
            }
            if aspects.contains(&Aspect::Compass) {
                println!("compass: drawn per run, calibrated by the user's dance, flown");
            }
            let end = args.end;
            let results = monte_carlo(runs, seed, threads, &progress, |seed| {
                let (airframe, config) = case(seed, &aspects, motion_capture, &gnss, &world_args);
                (airframe, FlyConfig { end, ..config })
            });
            println!(
                "{runs} runs in {:.0} s on {threads} threads",
                started.elapsed().as_secs_f64()
            );
            let mut verdicts: BTreeMap<String, Vec<u64>> = BTreeMap::new();
            for r in &results {
                verdicts.entry(format!("{:?}", r.verdict)).or_default().push(r.seed);
            }
            // Every seed of a failure class (each reproducible with `fly case --seed N`); five
            // examples of a success class.
            for (verdict, seeds) in &verdicts {
                let success = verdict == "Held" || verdict == "HoveredLoose";
                let shown = if success { 5 } else { seeds.len() };
                let listed: Vec<String> = seeds.iter().take(shown).map(u64::to_string).collect();
                println!(
                    "  {verdict}: {} ({:.1} %), {} {}",
                    seeds.len(),
                    100.0 * seeds.len() as f64 / runs.max(1) as f64,
                    if success { "e.g. seeds" } else { "seeds" },
                    listed.join(", ")
                );
            }
            // Controllers formed afresh in flight on a thrust axis that moved beyond
            // `pilot::REFORM_AXIS_CHANGE_RAD`, and how those runs ended.
            let mut reformed: BTreeMap<String, usize> = BTreeMap::new();
            for r in results.iter().filter(|r| r.report.reforms > 0) {
                *reformed.entry(format!("{:?}", r.verdict)).or_default() += 1;
            }
            let endings: Vec<String> = reformed.iter().map(|(v, n)| format!("{v} {n}")).collect();
            println!(
                "controller re-formed in flight: {} runs ({})",
                reformed.values().sum::<usize>(),
                endings.join(", ")
            );
            // Controllers engaged on the learner's last resort: a thrust axis whose hover leaves
            // the motor bounds, clamped to them.
            let mut clamped: BTreeMap<String, Vec<String>> = BTreeMap::new();
            let mut clamped_by = Vec::new();
            for r in results.iter() {
                if let Some(by) = r.report.engaged_clamped_by {
                    clamped
                        .entry(format!("{:?}", r.verdict))
                        .or_default()
                        .push(format!("{} ({by:.2})", r.seed));
                    clamped_by.push(by);
                }
            }
            let endings: Vec<String> = clamped
                .iter()
                .map(|(v, seeds)| format!("{v}: seeds {}", seeds.join(", ")))
                .collect();
            println!(
                "engaged on a thrust axis clamped to the motor bounds: {} runs ({})",
                clamped_by.len(),
                endings.join("; ")
            );
            if !clamped_by.is_empty() {
                print_quantiles(
                    "  u* outside the bounds by (normalised thrust)",
                    &clamped_by,
                    1.0,
                    "",
                );
            }
            let hover: Vec<f64> =
                results.iter().filter_map(|r| r.report.release_to_hover_s).collect();
            let hold: Vec<f64> = results.iter().filter_map(|r| r.report.max_hold_error_m).collect();
            let drop: Vec<f64> = results
                .iter()
                .filter(|r| r.report.release_to_engage_s.is_some())
                .map(|r| r.report.max_drop_below_release_m)
                .collect();
            let wait: Vec<f64> =
                results.iter().filter_map(|r| r.report.excitation_end_to_engage_s).collect();
            print_quantiles("the excitation's end → engage", &wait, 1e3, " ms");
            println!(
                "release → hover: median {:.2} s, 90th {:.2} s, 99th {:.2} s",
                quantile(&hover, 0.5),
                quantile(&hover, 0.9),
                quantile(&hover, 0.99)
            );
            println!(
                "worst distance from the setpoint over the hold: median {:.3} m, 90th {:.3} m, 99th {:.3} m",
                quantile(&hold, 0.5),
                quantile(&hold, 0.9),
                quantile(&hold, 0.99)
            );
            let horizontal: Vec<f64> =
                results.iter().filter_map(|r| r.report.max_hold_error_horizontal_m).collect();
            print_quantiles("  of it horizontally", &horizontal, 1.0, " m");
            let aligned: Vec<f64> =
                results.iter().filter_map(|r| r.report.heading_error_deg.map(f64::abs)).collect();
            let within_10_deg = aligned.iter().filter(|e| **e <= 10.0).count();
            print_quantiles("heading's error at the end (runs aligned)", &aligned, 1.0, "°");
            println!(
                "  heading within 10° at the end: {within_10_deg} of {runs} runs ({:.1} %)",
                100.0 * within_10_deg as f64 / runs.max(1) as f64
            );
            let within_1_m = horizontal.iter().filter(|e| **e <= 1.0).count();
            println!(
                "  held within 1 m horizontally: {within_1_m} of {runs} runs ({:.1} %)",
                100.0 * within_1_m as f64 / runs.max(1) as f64
            );
            let fix_errors: Vec<f64> =
                results.iter().filter_map(|r| r.report.max_fix_error_horizontal_m).collect();
            if !fix_errors.is_empty() {
                // What holding on the fixes cannot take out: their own error.
                print_quantiles(
                    "  the receiver's own worst horizontal error over those steps",
                    &fix_errors,
                    1.0,
                    " m",
                );
                let beyond: Vec<String> = results
                    .iter()
                    .filter(|r| r.report.max_fix_error_horizontal_m.is_some_and(|e| e > 1.0))
                    .map(|r| r.seed.to_string())
                    .collect();
                println!(
                    "  the receiver alone beyond 1 m: {} runs{}{}",
                    beyond.len(),
                    if beyond.is_empty() { "" } else { ", seeds " },
                    beyond.join(", ")
                );
            }
            // A hold starts once the craft has stopped (firmware::app::pilot): how much of the
            // window it covered, over the runs that hovered.
            let coverage: Vec<f64> = results
                .iter()
                .filter(|r| r.report.release_to_hover_s.is_some())
                .map(|r| 100.0 * r.report.hold_coverage)
                .collect();
            println!(
                "hold window flown in position hold: median {:.1} %, 10th {:.1} %, 1st {:.1} %",
                quantile(&coverage, 0.5),
                quantile(&coverage, 0.1),
                quantile(&coverage, 0.01)
            );
            println!(
                "drop below the release point: median {:.2} m, 90th {:.2} m, 99th {:.2} m",
                quantile(&drop, 0.5),
                quantile(&drop, 0.9),
                quantile(&drop, 0.99)
            );
            // The learner's G1 (worse block) when the controller engaged and after the flight's
            // in-flight refinement, and the model flown at the end, over the runs still flying.
            let g1 = |pick: fn(&sim::recovery::FlyReport) -> Option<[f64; 2]>| -> Vec<f64> {
                results.iter().filter_map(|r| pick(&r.report)).map(|[f, t]| f.max(t)).collect()
            };
            // The specific-force block alone: the rows an unknown IMU offset spoils.
            let force = |pick: fn(&sim::recovery::FlyReport) -> Option<[f64; 2]>| -> Vec<f64> {
                results.iter().filter_map(|r| pick(&r.report)).map(|[f, _]| f).collect()
            };
            for (name, values) in [
                ("at engage", force(|r| r.g1_block_rel_at_engage)),
                ("learned at the end", force(|r| r.g1_block_rel_learned_at_end)),
                (
                    "at the end, corrected by the fitted offset",
                    force(|r| r.g1_block_rel_corrected_by_fit),
                ),
                ("fitted with the offset", force(|r| r.g1_block_rel_fitted_jointly)),
            ] {
                print_quantiles(&format!("G1 force block error {name}"), &values, 100.0, " %");
            }
            let axis = |pick: fn(&sim::recovery::FlyReport) -> Option<f64>| -> Vec<f64> {
                results.iter().filter_map(|r| pick(&r.report)).collect()
            };
            for (name, values) in [
                ("at engage", g1(|r| r.g1_block_rel_at_engage)),
                ("learned at the end", g1(|r| r.g1_block_rel_learned_at_end)),
                ("flown at the end", g1(|r| r.g1_block_rel_flown_at_end)),
            ] {
                print_quantiles(
                    &format!("G1 error of the worse block {name}"),
                    &values,
                    100.0,
                    " %",
                );
            }
            for (name, values) in [
                ("at engage", axis(|r| r.axis_error_at_engage_deg)),
                ("learned at the end", axis(|r| r.axis_error_at_end_deg)),
            ] {
                print_quantiles(&format!("thrust-axis error {name}"), &values, 1.0, "°");
            }
            // The IMU offset fitted in flight (runs without the offset given).
            let fits: Vec<(f64, f64, bool)> = results
                .iter()
                .filter_map(|r| {
                    let fit = r.report.r_imu_fit_m?;
                    let error = fit - r.report.r_imu_true_m;
                    // Inside the 95 % ellipsoid: δrᵀ Σ⁻¹ δr ≤ χ²₃(0.95).
                    let inside = r.report.r_imu_fit_covariance_m2.is_some_and(|c| {
                        c.try_inverse().is_some_and(|inverse| {
                            error.dot(&(inverse * error)) <= f64::from(imu_offset::CHI2_3DOF_95)
                        })
                    });
                    Some((error.norm(), r.report.r_imu_fit_semi_axis_m?, inside))
                })
                .collect();
            if !fits.is_empty() {
                let errors: Vec<f64> = fits.iter().map(|f| f.0 * 1e3).collect();
                let axes: Vec<f64> = fits.iter().map(|f| f.1 * 1e3).collect();
                let within = fits.iter().filter(|f| f.0 <= f.1).count();
                let inside = fits.iter().filter(|f| f.2).count();
                println!(
                    "IMU offset fitted in flight: error median {:.2} mm, 90th {:.2} mm, 99th {:.2} mm; \
                     largest 95 % semi-axis median {:.2} mm; error within it in {within} of {} runs, \
                     inside the 95 % ellipsoid in {inside}",
                    quantile(&errors, 0.5),
                    quantile(&errors, 0.9),
                    quantile(&errors, 0.99),
                    quantile(&axes, 0.5),
                    fits.len()
                );
            }
            // Per unit normalised thrust (`sim::recovery::thrust_scores`), at the end of the
            // excitation of every run that got there: comparable with and without telemetry.
            let engaged: Vec<sim::identification::Scores> =
                results.iter().filter_map(|r| r.report.thrust_scores_at_excitation_end).collect();
            // Over the runs where the figure exists (the thrust axis: where one was found).
            let per_thrust = |pick: fn(&sim::identification::Scores) -> f64, scale: f64| {
                let values: Vec<f64> =
                    engaged.iter().map(|s| scale * pick(s)).filter(|v| v.is_finite()).collect();
                format!(
                    "median {:.2}, 90th {:.2}, 99th {:.2} ({} runs)",
                    quantile(&values, 0.5),
                    quantile(&values, 0.9),
                    quantile(&values, 0.99),
                    values.len()
                )
            };
            println!(
                "per unit thrust at the end of the excitation: G1 force block {} %; torque block {} %; thrust axis {} °; worst |τ error| {} ms",
                per_thrust(|s| s.g1_block_rel[0], 100.0),
                per_thrust(|s| s.g1_block_rel[1], 100.0),
                per_thrust(|s| s.axis_angle_rad.to_degrees(), 1.0),
                per_thrust(|s| s.tau_error_max_s, 1e3),
            );
            if aspects.contains(&Aspect::Wind) {
                let worlds: Vec<WorldEffects> = results
                    .iter()
                    .map(|r| {
                        case(r.seed, &aspects, motion_capture, &gnss, &world_args).1.board.world
                    })
                    .collect();
                print_winds(&results, &worlds);
            }
            if aspects.contains(&Aspect::Gnss) {
                let receivers: Vec<GnssModelConfig> = results
                    .iter()
                    .filter_map(|r| {
                        case(r.seed, &aspects, motion_capture, &gnss, &world_args).1.gnss
                    })
                    .collect();
                print_gnss_bands(&results, &receivers);
            }
            print_landings(&results);
            print_after_recovery(&results);
            print_catches(&results);
            let mut by_itself: BTreeMap<String, Vec<String>> = BTreeMap::new();
            for r in &results {
                if let Some((reason, at_s)) = r.report.landed_by_itself {
                    by_itself
                        .entry(format!("{reason:?}"))
                        .or_default()
                        .push(format!("{} ({at_s:.1} s)", r.seed));
                }
            }
            for (reason, seeds) in &by_itself {
                println!(
                    "landed by itself ({reason}): {} runs, seeds {}",
                    seeds.len(),
                    seeds.join(", ")
                );
            }
            for motors in 4..=8 {
                let of: Vec<&_> = results.iter().filter(|r| r.motors == motors).collect();
                if !of.is_empty() {
                    let held = of.iter().filter(|r| r.verdict == Verdict::Held).count();
                    println!("  {motors} motors: {} runs, held {held}", of.len());
                }
            }
            print_by_motor_tau(&results);
            if let Some(path) = runs_csv {
                let worlds: Vec<WorldEffects> = results
                    .iter()
                    .map(|r| {
                        case(r.seed, &aspects, motion_capture, &gnss, &world_args).1.board.world
                    })
                    .collect();
                if let Err(e) = std::fs::write(&path, runs_csv_text(&results, &worlds)) {
                    eprintln!("fly: cannot write {}: {e}", path.display());
                    return ExitCode::from(2);
                }
                println!("one line per run: {}", path.display());
            }
        }
    }
    ExitCode::SUCCESS
}
