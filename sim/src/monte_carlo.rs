//! Monte Carlo batches of throw-and-catch runs on random airframes, in parallel with rayon, and
//! the single-run speed measurement (simulated seconds per wall-clock second).
//!
//! Each run `i` of a batch uses [`Airframe::random`]`(seed + i)` and a throw whose body rate has
//! a random direction and a magnitude of 4–10 rad/s, drawn from the same per-run seed, so any
//! run can be replayed alone. Runs are independent: the batch result does not depend on the
//! thread count. The application is the firmware's ([`with_firmware_app`]).

use std::time::{Duration, Instant};

use nalgebra::Vector3;

use crate::airframe::Airframe;
use crate::rng::Rng;
use crate::scenario::{
    self, with_firmware_app, FlightApp, Outcome, ScenarioConfig, ScenarioError, ScenarioKind,
};

/// Summary of a batch.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchSummary {
    /// Runs completed.
    pub runs: usize,
    /// Runs in which the hand caught the craft.
    pub caught: usize,
    /// Total simulated time, s.
    pub simulated_s: f64,
    /// Wall-clock time of the whole batch.
    pub wall: Duration,
    /// Worker threads used.
    pub threads: usize,
}

/// The scenario of run `seed`: throw-and-catch on a random airframe with a random spin.
pub fn random_throw_catch(seed: u64) -> (Airframe, ScenarioConfig) {
    let airframe = Airframe::random(seed);
    let mut rng = Rng::new(seed ^ 0x5EED_0F7E_7409);
    let direction = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    let mut config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
    config.throw_rate_body_rad_s = direction * rng.range(4.0, 10.0);
    config.throw_apex_m = rng.range(0.6, 1.5);
    config.board.seed = seed;
    (airframe, config)
}

/// Runs `runs` throw-and-catch scenarios (seeds `seed..seed + runs`) on `threads` workers.
pub fn throw_catch_batch(
    runs: usize,
    seed: u64,
    threads: usize,
) -> Result<BatchSummary, ScenarioError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .expect("a rayon pool with a positive thread count builds");
    let start = Instant::now();
    let outcomes: Vec<Outcome> = pool.install(|| {
        use rayon::prelude::*;
        (0..runs as u64)
            .into_par_iter()
            .map(|i| {
                let (airframe, config) = random_throw_catch(seed + i);
                with_firmware_app(|app| {
                    scenario::run::<_, std::io::Sink>(&airframe, &config, app, None, &mut |_, _| {})
                })
            })
            .collect::<Result<_, _>>()
    })?;
    Ok(BatchSummary {
        runs,
        caught: outcomes.iter().filter(|o| o.caught_at_s.is_some()).count(),
        simulated_s: outcomes.iter().map(|o| o.duration_s).sum(),
        wall: start.elapsed(),
        threads: threads.max(1),
    })
}

/// Runs `config` on `airframe` with `app` repeatedly (no log) until at least `simulated_s` of
/// simulated time, and returns `(simulated s, wall-clock s)`.
pub fn realtime_factor<A: FlightApp>(
    airframe: &Airframe,
    config: &ScenarioConfig,
    app: &mut A,
    simulated_s: f64,
) -> Result<(f64, f64), ScenarioError> {
    let start = Instant::now();
    let mut total = 0.0;
    while total < simulated_s {
        let outcome =
            scenario::run::<_, std::io::Sink>(airframe, config, app, None, &mut |_, _| {})?;
        total += outcome.duration_s;
    }
    Ok((total, start.elapsed().as_secs_f64()))
}
