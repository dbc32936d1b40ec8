//! `cargo bench -p sim`: the simulator's speed, as figures rather than timed tests.
//!
//! Prints the real-time factor of one airframe (8 kHz RK4 physics and IMU, the firmware's 2 kHz
//! control step, one thread) and the wall time of a Monte Carlo batch of throw-and-catch runs on
//! two threads. The same measurements with more options: `scenario bench` and
//! `scenario monte-carlo` (see docs/benchmarks.md).

use sim::airframe::Airframe;
use sim::monte_carlo::{realtime_factor, throw_catch_batch};
use sim::scenario::{with_firmware_app, ScenarioConfig, ScenarioKind};

fn main() {
    // `cargo bench` passes `--bench`; a filter argument selects nothing here.
    for name in ["paper-quad", "octo-flat"] {
        let airframe = Airframe::builtin(name).expect("built-in airframe");
        let config = ScenarioConfig::new(ScenarioKind::ThrowFly);
        let (sim_s, wall_s) =
            with_firmware_app(|app| realtime_factor(&airframe, &config, app, 60.0))
                .expect("scenario runs");
        println!(
            "realtime/{name}: {:.0}x real time ({sim_s:.0} s in {wall_s:.3} s)",
            sim_s / wall_s
        );
    }
    let runs = 1000;
    let summary = throw_catch_batch(runs, 1, 2).expect("batch runs");
    println!(
        "monte-carlo/throw-catch: {runs} runs, {} caught, {:.0} simulated s in {:.2} s on {} threads",
        summary.caught,
        summary.simulated_s,
        summary.wall.as_secs_f64(),
        summary.threads
    );
}
