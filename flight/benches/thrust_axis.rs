//! Host benchmarks of the thrust-axis solver (criterion), against the dense f64 reference of the
//! tests: `cargo xtask bench` (or `cargo bench -p flight --bench thrust_axis`).
//!
//! Airframes: a random planar multirotor with a random IMU orientation per motor count, the same
//! generator as the tests; for the bounded search, a frame whose heuristic optimum leaves the
//! bounds. Figures go in docs/benchmarks.md.

#[path = "../tests/thrust_axis_common/mod.rs"]
mod thrust_axis_common;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use flight::thrust_axis::{HoverProblem, ThrustAxisSolver};
use std::hint::black_box;
use thrust_axis_common::{dense_unbounded, random_airframe, Airframe, Kind, Rng};

/// A hover-capable (unbounded heuristic within bounds) random planar frame with `motors` rotors.
fn feasible_frame(rng: &mut Rng, motors: usize) -> (Airframe, HoverProblem) {
    loop {
        let frame = random_airframe(rng, motors, Kind::Planar);
        if dense_unbounded(&frame).is_some_and(|d| d.u.is_some()) {
            let problem = frame.problem().expect("valid frame");
            return (frame, problem);
        }
    }
}

/// A frame whose heuristic optimum leaves the bounds but which can still hover (bounded search).
fn bounded_frame(rng: &mut Rng, motors: usize) -> HoverProblem {
    loop {
        let mut frame = random_airframe(rng, motors, Kind::Planar);
        frame.u_max = (0..motors).map(|_| rng.range(0.3, 1.0)).collect();
        let heuristic_fails = dense_unbounded(&frame).is_some_and(|d| d.u.is_none());
        let problem = frame.problem().expect("valid frame");
        if heuristic_fails && ThrustAxisSolver::default().solve(&problem).is_ok_and(|s| s.bounded) {
            return problem;
        }
    }
}

fn solve(c: &mut Criterion) {
    let mut rng = Rng::new(0xBE7C_0001);
    let mut group = c.benchmark_group("thrust_axis_solve");
    for motors in [4, 6, 8] {
        let (frame, problem) = feasible_frame(&mut rng, motors);
        let mut solver = ThrustAxisSolver::default();
        group.bench_with_input(BenchmarkId::new("flight_f32", motors), &problem, |b, p| {
            b.iter(|| solver.solve(black_box(p)))
        });
        group.bench_with_input(BenchmarkId::new("dense_f64_reference", motors), &frame, |b, f| {
            b.iter(|| dense_unbounded(black_box(f)))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("thrust_axis_bounded");
    group.sample_size(20);
    for motors in [6, 8] {
        let problem = bounded_frame(&mut rng, motors);
        let mut solver = ThrustAxisSolver::default();
        group.bench_with_input(BenchmarkId::new("flight_f32", motors), &problem, |b, p| {
            b.iter(|| solver.solve(black_box(p)))
        });
    }
    group.finish();
}

criterion_group!(benches, solve);
criterion_main!(benches);
