//! The floor a GNSS receiver puts under a position hold (issue 55): a craft that held its true
//! position perfectly *in the fixes' world* would still move, in the world, by the receiver's
//! error wander since the first fix (where the fixes' world has its origin). This draws that
//! wander alone, for the `fly --gnss` receiver given (the default: 0.3 m correlated over 20 s per
//! horizontal axis, 5 cm white, 10 Hz), and reports the worst horizontal `|ε(t) − ε(first fix)|`
//! over a hold window, as `fly`'s hold metric measures it: the share over 1 m is what no hold on
//! these fixes alone can avoid.
//!
//! ```text
//! cargo run -p sim --release --example gnss_hold_floor -- [NOISE_M] [RUNS]
//! ```

use sim::gnss::{GnssArgs, GnssTruth, SimGnss};

fn main() {
    let mut args = std::env::args().skip(1);
    let noise_m: f64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(GnssArgs::NOISE_M);
    let runs: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(2000);
    let receiver = GnssArgs {
        gnss: true,
        gnss_noise_m: noise_m,
        gnss_rate_hz: GnssArgs::RATE_HZ,
        gnss_latency_ms: GnssArgs::LATENCY_MS,
        gnss_multipath_per_min: GnssArgs::MULTIPATH_PER_MIN,
        gnss_multipath_s: GnssArgs::MULTIPATH_S,
    };
    let model = match receiver.config() {
        Ok(Some(model)) => model,
        Ok(None) => unreachable!("`gnss` is set"),
        Err(reason) => {
            eprintln!("gnss_hold_floor: {reason}");
            std::process::exit(2);
        }
    };
    // `fly`'s hold window: the last 10 s of a 13 s flight, the first fix about a second before
    // the release.
    let (hold_from_s, hold_to_s) = (4.0, 14.0);
    let mut worst_m: Vec<f64> = (1..=runs)
        .map(|seed| {
            let mut receiver = SimGnss::new(model.clone(), seed);
            let mut first = None;
            let mut worst: f64 = 0.0;
            let mut t_s = 0.0;
            while t_s < hold_to_s {
                for solution in receiver.update(t_s, &GnssTruth::default()) {
                    let error = solution.error_ned_m;
                    let first = *first.get_or_insert(error);
                    if solution.measured_s >= hold_from_s {
                        worst = worst.max((error - first).xy().norm());
                    }
                }
                t_s += 0.01;
            }
            worst
        })
        .collect();
    worst_m.sort_by(f64::total_cmp);
    let at = |p: usize| worst_m[(worst_m.len() * p / 100).min(worst_m.len() - 1)];
    let over = worst_m.iter().filter(|&&w| w > 1.0).count();
    println!(
        "receiver {noise_m} m correlated over {} s, {} Hz: worst distance a perfect hold on the \
         fixes is moved over {hold_from_s}-{hold_to_s} s: median {:.2} m, 90th {:.2} m, 99th {:.2} m; \
         over 1 m in {over} of {runs} runs ({:.1} %)",
        model.correlation_time_s,
        model.rate_hz,
        at(50),
        at(90),
        at(99),
        100.0 * over as f64 / runs as f64
    );
}
