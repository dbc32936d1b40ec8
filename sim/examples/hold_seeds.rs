//! The runs of chosen Monte Carlo seeds, one line each: verdict, worst hold error, the
//! firmware's attitude error (tilt, heading) against the truth at engagement and when the hold
//! window began, and how much of the window was flown in position hold (issue 28's loose
//! holds).
//!
//! ```text
//! cargo run -p sim --release --example hold_seeds -- SEED [SEED...]   # or FIRST..END
//! ```
//! Environment: `ASPECTS=hand,imu,…` (default: every aspect, the random world; `ASPECTS=` for
//! the nominal world), `THREADS` (default 2).

use sim::recovery::Verdict;
use sim::world::{random_world_case, Aspect};

fn main() {
    let mut seeds: Vec<u64> = Vec::new();
    for arg in std::env::args().skip(1) {
        match arg.split_once("..") {
            Some((a, b)) => seeds.extend(a.parse::<u64>().unwrap()..b.parse::<u64>().unwrap()),
            None => seeds.push(arg.parse().unwrap()),
        }
    }
    let aspects: Vec<Aspect> = match std::env::var("ASPECTS") {
        Ok(list) => {
            list.split(',').filter(|s| !s.is_empty()).map(|s| Aspect::parse(s).unwrap()).collect()
        }
        Err(_) => Aspect::ALL.to_vec(),
    };
    let threads = std::env::var("THREADS").ok().and_then(|t| t.parse().ok()).unwrap_or(2);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    let results: Vec<_> = pool.install(|| {
        use rayon::prelude::*;
        seeds
            .par_iter()
            .map(|&seed| {
                let (airframe, config) = random_world_case(seed, &aspects);
                let report = sim::recovery::fly(&airframe, &config);
                let spin = config.throw.rate_body_rad_s.norm().to_degrees();
                (seed, spin, Verdict::of(&report), report)
            })
            .collect()
    });
    let mut held = 0;
    for (seed, spin, verdict, r) in &results {
        held += usize::from(*verdict == Verdict::Held);
        let e = r.attitude_error_at_engage_deg.unwrap_or([f64::NAN; 2]);
        let w = r.attitude_error_at_window_deg.unwrap_or([f64::NAN; 2]);
        println!(
            "{seed:5} spin {spin:5.0} °/s  {:<14} hold {:6.3} m  engage tilt {:5.2}° yaw {:6.2}°  window tilt {:5.2}° yaw {:6.2}°  G1 engage {:5.1} {:5.1} % flown {:5.1} {:5.1} %  held for {:4.0} % of the window",
            format!("{verdict:?}"),
            r.max_hold_error_m.unwrap_or(f64::NAN),
            e[0], e[1], w[0], w[1],
            100.0 * r.g1_block_rel_at_engage.map_or(f64::NAN, |g| g[0]),
            100.0 * r.g1_block_rel_at_engage.map_or(f64::NAN, |g| g[1]),
            100.0 * r.g1_block_rel_flown_at_end.map_or(f64::NAN, |g| g[0]),
            100.0 * r.g1_block_rel_flown_at_end.map_or(f64::NAN, |g| g[1]),
            100.0 * r.hold_coverage,
        );
    }
    println!("held {held} of {}", results.len());
}
