//! Small statistics for the Monte Carlo reports, and the parallel runner they share.

/// A Monte Carlo batch as a command line asks for it (`fly`, `identify`, `scenario`
/// `monte-carlo`): `--runs` runs from `--seed` on `--threads` workers, as [`run_seeds`] and
/// [`crate::monte_carlo::throw_catch_batch`] take them. One definition, so every batch is asked
/// for in the same words, with the same defaults.
#[derive(clap::Args, Clone, Copy, Debug, PartialEq, Eq)]
pub struct BatchArgs {
    /// Number of runs.
    #[arg(long, default_value_t = 1000)]
    pub runs: usize,
    /// First seed (run i uses seed + i, so any run can be replayed alone).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
}

/// Runs `run(seed + i)` for `i` in `0..runs` on `threads` workers (rayon) and returns the
/// results in seed order; `progress` is called with the number done after each run.
pub fn run_seeds<T: Send>(
    runs: usize,
    seed: u64,
    threads: usize,
    progress: &(dyn Fn(usize) + Sync),
    run: impl Fn(u64) -> T + Sync,
) -> Vec<T> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .expect("a rayon pool with a positive thread count builds");
    let done = std::sync::atomic::AtomicUsize::new(0);
    pool.install(|| {
        use rayon::prelude::*;
        (0..runs as u64)
            .into_par_iter()
            .map(|i| {
                let result = run(seed + i);
                progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
                result
            })
            .collect()
    })
}

/// The `q` quantile (nearest rank) of `values`; NaN when empty.
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_quantiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.5), 50.0);
        assert_eq!(quantile(&v, 0.99), 99.0);
        assert_eq!(quantile(&v, 1.0), 100.0);
        assert_eq!(quantile(&[3.0, 1.0, 2.0], 0.0), 1.0);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
