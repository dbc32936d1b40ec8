//! The thrust-axis solver against independent f64 references on random airframes, the seed
//! paper's quadrotor, the typed errors, and arbitrary input.
//!
//! Every assertion is a physical fact (angles in degrees, forces in m/s², costs, bounds).
// Index loops mirror the matrix notation of the airframe construction.
#![allow(clippy::needless_range_loop)]

mod thrust_axis_common;

use flight::thrust_axis::{
    rotate, HoverProblem, HoverSolution, SolverConfig, ThrustAxisError, ThrustAxisSolver,
    MOTORS_MAX, THRUST_DIR_THRUST_FRAME,
};
use proptest::prelude::*;
use thrust_axis_common::{
    angle_deg, dense_unbounded, random_airframe, rotation_matrix, sampled_bounded, thrust_dir,
    Airframe, Kind, Rng,
};

/// Tolerance of the issue: the thrust axis agrees with the dense reference within 0.01°.
const ANGLE_TOLERANCE_DEG: f64 = 0.01;
/// Below this relative eigen-gap `(λ₁ − λ₂)/λ₁` the dominant direction is ill-conditioned (a
/// 1e-6 perturbation moves it by more than 1e-5 rad) and only the cost is compared.
const MIN_RELATIVE_GAP: f64 = 0.02;

fn to_f64(values: &[f32]) -> Vec<f64> {
    values.iter().map(|&x| x as f64).collect()
}

fn dir_f64(solution: &HoverSolution) -> [f64; 3] {
    solution.thrust_dir_imu.map(|x| x as f64)
}

/// The physical constraints of problem (6) hold for the solver's command.
fn assert_constraints(frame: &Airframe, solution: &HoverSolution, context: &str) {
    let u = to_f64(solution.u_hover());
    let (force, torque) = frame.force_torque(&u);
    assert!(
        (force - frame.g_mps2).abs() <= 1e-3 * frame.g_mps2,
        "{context}: |G1f u| = {force} m/s², expected g = {}",
        frame.g_mps2
    );
    let torque_scale = frame.g1_tau_matrix().norm() * u.iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!(
        torque <= 1e-4 * torque_scale,
        "{context}: |G1τ u| = {torque} rad/s² (scale {torque_scale})"
    );
    assert!(frame.within_bounds(&u, 1e-6), "{context}: u = {u:?} outside the bounds");
    // thrust_dir_imu is the unit vector along G1f u, and the quaternion maps −z onto it.
    assert!(
        angle_deg(dir_f64(solution), thrust_dir(frame, &u)) < 1e-3,
        "{context}: thrust_dir_imu"
    );
    let image = rotate(solution.q_thrust_to_imu, THRUST_DIR_THRUST_FRAME).map(|x| x as f64);
    assert!(angle_deg(image, dir_f64(solution)) < 1e-3, "{context}: q_thrust_to_imu");
}

#[test]
fn thrust_axis_agrees_with_dense_eigen_decomposition_on_random_airframes() {
    let mut rng = Rng::new(0x5EED_0001);
    let mut compared = 0;
    let mut small_gap = 0;
    let mut worst_angle_deg: f64 = 0.0;
    let mut total = 0;
    for kind in [Kind::Planar, Kind::Tilted] {
        for motors in 4..=MOTORS_MAX {
            for case in 0..50 {
                let mut frame = random_airframe(&mut rng, motors, kind);
                if case % 2 == 1 {
                    // Non-identical motors: weights 0.5–2 (e.g. power per unit command²).
                    frame.weights = (0..motors).map(|_| rng.range(0.5, 2.0)).collect();
                }
                if kind == Kind::Tilted {
                    // Reversible motors, so that tilted frames are mostly hover-capable unbounded.
                    frame.u_min = vec![-1.0; motors];
                }
                total += 1;
                let context = format!("{kind:?} m={motors} case {case}");
                let Some(reference) = dense_unbounded(&frame) else { continue };
                let mut solver = ThrustAxisSolver::default();
                let result = solver.solve(&frame.problem().unwrap());
                let Some(u_reference) = &reference.u else {
                    // Heuristic out of bounds: the bounded test covers these.
                    continue;
                };
                let solution = result.unwrap_or_else(|e| panic!("{context}: {e}"));
                assert!(!solution.bounded, "{context}: heuristic fits, bounded must be false");
                assert_constraints(&frame, &solution, &context);
                let lambda = &reference.eigenvalues;
                let eigen_error = (solution.eigenvalue as f64 - lambda[0]).abs() / lambda[0];
                assert!(
                    eigen_error < 1e-4,
                    "{context}: eigenvalue {} vs {}",
                    solution.eigenvalue,
                    lambda[0]
                );
                let cost = frame.cost(&to_f64(solution.u_hover()));
                let reference_cost = frame.cost(u_reference);
                assert!(
                    cost <= reference_cost * (1.0 + 1e-4),
                    "{context}: cost {cost} vs dense {reference_cost}"
                );
                let gap = if lambda.len() > 1 { (lambda[0] - lambda[1]) / lambda[0] } else { 1.0 };
                if gap < MIN_RELATIVE_GAP {
                    small_gap += 1;
                    continue;
                }
                let angle = angle_deg(dir_f64(&solution), thrust_dir(&frame, u_reference));
                worst_angle_deg = worst_angle_deg.max(angle);
                assert!(angle < ANGLE_TOLERANCE_DEG, "{context}: thrust axis off by {angle}°");
                compared += 1;
            }
        }
    }
    println!(
        "{compared} of {total} airframes compared; worst angle {worst_angle_deg:.2e}°; \
         {small_gap} with eigen-gap < {MIN_RELATIVE_GAP} compared by cost only"
    );
    assert!(compared >= 300, "only {compared} airframes were compared");
    assert!(small_gap * 20 < compared, "too many near-degenerate frames: {small_gap}");
}

#[test]
fn bounded_optimum_is_no_worse_than_a_general_constrained_optimiser() {
    let mut rng = Rng::new(0x5EED_0002);
    let mut cases = 0;
    let mut both_found = 0;
    let mut matched = 0;
    let mut solver_only = 0;
    let mut worst_relative_excess: f64 = f64::NEG_INFINITY;
    for attempt in 0..3000 {
        if cases >= 120 {
            break;
        }
        let motors = 5 + attempt % 4;
        let kind = if attempt % 3 == 0 { Kind::Tilted } else { Kind::Planar };
        let mut frame = random_airframe(&mut rng, motors, kind);
        // Idle thrust, weak motors and uneven weights push the heuristic out of the bounds.
        frame.u_min = (0..motors).map(|_| rng.range(0.0, 0.12)).collect();
        frame.u_max = (0..motors).map(|_| rng.range(0.3, 1.0)).collect();
        frame.weights = (0..motors).map(|_| rng.range(0.5, 2.0)).collect();
        let Some(dense) = dense_unbounded(&frame) else { continue };
        if dense.u.is_some() {
            continue;
        }
        cases += 1;
        let context = format!("attempt {attempt} ({kind:?} m={motors})");
        let reference = sampled_bounded(&frame, &mut rng, 20_000);
        let mut solver = ThrustAxisSolver::default();
        match solver.solve(&frame.problem().unwrap()) {
            Ok(solution) => {
                assert!(solution.bounded, "{context}: the heuristic failed, bounded must be true");
                assert_constraints(&frame, &solution, &context);
                let cost = frame.cost(&to_f64(solution.u_hover()));
                // The bounds can only make hover dearer than the unbounded optimum g²/λ.
                let unbounded_cost = frame.cost(&dense.u_unsigned);
                assert!(
                    cost >= unbounded_cost * (1.0 - 1e-4),
                    "{context}: {cost} < {unbounded_cost}"
                );
                if let Some(reference) = reference {
                    both_found += 1;
                    let excess = (cost - reference.cost) / reference.cost;
                    worst_relative_excess = worst_relative_excess.max(excess);
                    assert!(
                        excess <= 1e-3,
                        "{context}: cost {cost} worse than the general optimiser's {}",
                        reference.cost
                    );
                    if excess.abs() <= 1e-3 {
                        matched += 1;
                    }
                } else {
                    solver_only += 1;
                }
            }
            Err(ThrustAxisError::NoHoverWithinBounds) => {
                assert!(
                    reference.is_none(),
                    "{context}: solver found no hover but the optimiser found cost {:?}",
                    reference.map(|r| r.cost)
                );
            }
            Err(other) => panic!("{context}: unexpected {other}"),
        }
    }
    println!(
        "{cases} bounded cases; {both_found} solved by both ({matched} equal within 0.1 %, worst \
         relative excess {worst_relative_excess:.2e}); {solver_only} found by the solver only"
    );
    assert!(cases >= 100, "only {cases} bounded cases generated");
    // About a third of the generated out-of-bounds frames can hover at all (39–48 of 120 across
    // random streams): at least 30 comparisons with the general optimiser are required.
    assert!(both_found >= 30, "only {both_found} bounded cases had a feasible optimum");
}

/// Build the seed paper's symmetric X quadrotor with the IMU rotated by `q_imu_thrust`.
fn paper_quad(q_imu_thrust: [f64; 4]) -> Airframe {
    let r = rotation_matrix(q_imu_thrust);
    let arm_m = 0.1;
    let strength = 9.81 / (4.0 * 0.4);
    let mut frame = Airframe {
        motors: 4,
        g1_f: [vec![0.0; 4], vec![0.0; 4], vec![0.0; 4]],
        g1_tau: [vec![0.0; 4], vec![0.0; 4], vec![0.0; 4]],
        u_min: vec![0.0; 4],
        u_max: vec![1.0; 4],
        weights: vec![1.0; 4],
        g_mps2: 9.81,
    };
    // Front-right, back-left spin one way; front-left, back-right the other (FRD).
    let motors = [([1.0, 1.0], 1.0), ([-1.0, -1.0], 1.0), ([1.0, -1.0], -1.0), ([-1.0, 1.0], -1.0)];
    for (i, (xy, spin)) in motors.iter().enumerate() {
        let (x, y) = (arm_m * xy[0] / 2f64.sqrt(), arm_m * xy[1] / 2f64.sqrt());
        let force = [0.0, 0.0, -strength];
        // r × F with F along −z, plus rotor drag about z; inertia 0.01 kg m² about each axis.
        let angular = [-y * strength / 0.01, x * strength / 0.01, spin * 0.015 * strength / 0.02];
        for row in 0..3 {
            frame.g1_f[row][i] = (0..3).map(|k| r[row][k] * force[k]).sum();
            frame.g1_tau[row][i] = (0..3).map(|k| r[row][k] * angular[k]).sum();
        }
    }
    frame
}

#[test]
fn seed_paper_quadrotor_with_rotated_imu_recovers_its_rotation() {
    // q_U^T = 0.837 − 0.491i + 0.242j + 0k (paper §3.4), normalised.
    let q = [0.837, -0.491, 0.242, 0.0];
    let n = q.iter().map(|v: &f64| v * v).sum::<f64>().sqrt();
    let q = q.map(|v| v / n);
    let frame = paper_quad(q);
    let solution = ThrustAxisSolver::default().solve(&frame.problem().unwrap()).unwrap();
    assert!(!solution.bounded);
    assert_constraints(&frame, &solution, "paper quad");
    // The quaternion itself: angle of the relative rotation q* ⊗ q̂, as 2 atan2(|v|, |w|)
    // (well conditioned near zero, unlike 2 acos(q·q̂)).
    let [w0, x0, y0, z0] = q;
    let [w1, x1, y1, z1] = solution.q_thrust_to_imu.map(|v| v as f64);
    let relative = [
        w0 * w1 + x0 * x1 + y0 * y1 + z0 * z1,
        w0 * x1 - x0 * w1 - y0 * z1 + z0 * y1,
        w0 * y1 + x0 * z1 - y0 * w1 - z0 * x1,
        w0 * z1 - x0 * y1 + y0 * x1 - z0 * w1,
    ];
    let vector = (relative[1].powi(2) + relative[2].powi(2) + relative[3].powi(2)).sqrt();
    let rotation_error_deg = 2.0 * vector.atan2(relative[0].abs()).to_degrees();
    assert!(rotation_error_deg < ANGLE_TOLERANCE_DEG, "rotation off by {rotation_error_deg}°");
    // The paper's angles (its table swaps the roll and yaw labels; the quaternion is the truth):
    // roll −64°, pitch 24°, yaw −15°, to the degree quoted.
    let euler = solution.euler_zyx();
    let (roll, pitch, yaw) =
        (euler.roll_rad.to_degrees(), euler.pitch_rad.to_degrees(), euler.yaw_rad.to_degrees());
    assert!((roll - -64.0).abs() < 0.5, "roll {roll}°");
    assert!((pitch - 24.0).abs() < 0.5, "pitch {pitch}°");
    assert!((yaw - -15.0).abs() < 0.5, "yaw {yaw}°");
    // Identical motors at equal arms share the hover thrust equally.
    let u = solution.u_hover();
    assert!(u.iter().all(|&x| (x - u[0]).abs() < 1e-5 && x > 0.0), "{u:?}");
}

#[test]
fn upside_down_imu_gives_half_turn_about_x() {
    let frame = paper_quad([0.0, 1.0, 0.0, 0.0]);
    let solution = ThrustAxisSolver::default().solve(&frame.problem().unwrap()).unwrap();
    assert!(angle_deg(dir_f64(&solution), [0.0, 0.0, 1.0]) < 1e-3);
    let euler = solution.euler_zyx();
    assert!((euler.roll_rad.to_degrees().abs() - 180.0).abs() < 1e-3, "{euler:?}");
    assert!(euler.pitch_rad.to_degrees().abs() < 1e-3 && euler.yaw_rad.to_degrees().abs() < 1e-3);
}

#[test]
fn warm_start_keeps_improving_across_calls() {
    // A tilted octo whose second eigenvalue is not negligible (random tilted octos mostly have
    // λ₂/λ₁ of 0.02–0.17; above 0.12 is common enough to find at once): with one squaring per
    // call (two power steps) a single call is not converged, later calls are.
    let mut rng = Rng::new(0x5EED_0003);
    let (frame, reference) = loop {
        let mut frame = random_airframe(&mut rng, 8, Kind::Tilted);
        frame.u_min = vec![-1.0; 8];
        let Some(reference) = dense_unbounded(&frame) else { continue };
        let ratio = reference.eigenvalues[1] / reference.eigenvalues[0];
        if reference.u.is_some() && (0.12..0.9).contains(&ratio) {
            break (frame, reference);
        }
    };
    let expected = thrust_dir(&frame, reference.u.as_ref().unwrap());
    let problem = frame.problem().unwrap();
    let mut solver =
        ThrustAxisSolver::new(SolverConfig { max_squarings: 1, ..SolverConfig::default() });
    // The first call starts from the default seed (−z of the IMU, a random direction here).
    let mut errors = Vec::new();
    for _ in 0..40 {
        let solution = solver.solve(&problem).unwrap();
        errors.push(angle_deg(dir_f64(&solution), expected));
    }
    assert!(errors[0] > ANGLE_TOLERANCE_DEG, "one capped call should not converge: {errors:?}");
    assert!(errors[39] < ANGLE_TOLERANCE_DEG, "after 40 calls: {}°", errors[39]);
    assert!(errors[39] <= errors[0], "{errors:?}");
    // And the full default cap converges in one call.
    let solution = ThrustAxisSolver::default().solve(&problem).unwrap();
    assert!(angle_deg(dir_f64(&solution), expected) < ANGLE_TOLERANCE_DEG);
}

#[test]
fn typed_errors_for_bad_shapes_and_values() {
    let row4 = [1.0f32, 2.0, 3.0, 4.0];
    let row3 = [1.0f32, 2.0, 3.0];
    let row9 = [1.0f32; 9];
    assert_eq!(
        HoverProblem::new([&row3, &row3, &row3], [&row3, &row3, &row3]),
        Err(ThrustAxisError::MotorCount { motors: 3 })
    );
    assert_eq!(
        HoverProblem::new([&row9, &row9, &row9], [&row9, &row9, &row9]),
        Err(ThrustAxisError::MotorCount { motors: 9 })
    );
    assert!(matches!(
        HoverProblem::new([&row4, &row4, &row3], [&row4, &row4, &row4]),
        Err(ThrustAxisError::Length { found: 3, expected: 4, .. })
    ));
    let nan = [1.0, f32::NAN, 0.0, 0.0];
    assert!(matches!(
        HoverProblem::new([&row4, &row4, &row4], [&row4, &nan, &row4]),
        Err(ThrustAxisError::OutOfRange { motor: 1, .. })
    ));
    let ok = HoverProblem::new([&row4, &row4, &row4], [&row4, &row4, &row4]).unwrap();
    assert!(matches!(
        ok.clone().with_bounds(&[0.0, 0.0, 0.5, 0.0], &[1.0, 1.0, 0.4, 1.0]),
        Err(ThrustAxisError::InvertedBounds { motor: 2 })
    ));
    assert!(matches!(
        ok.clone().with_weights(&[1.0, 0.0, 1.0, 1.0]),
        Err(ThrustAxisError::NotPositive { motor: 1, .. })
    ));
    assert!(ok.clone().with_gravity(f32::INFINITY).is_err());
    assert!(ok.with_gravity(-9.81).is_err());
}

#[test]
fn no_hover_cases_are_reported_not_guessed() {
    let frame = paper_quad([1.0, 0.0, 0.0, 0.0]);
    let mut solver = ThrustAxisSolver::default();

    // Rank-deficient G1τ: no yaw authority (all rotor drag removed).
    let mut no_yaw = frame.clone();
    no_yaw.g1_tau[2] = vec![0.0; 4];
    assert_eq!(
        solver.solve(&no_yaw.problem().unwrap()),
        Err(ThrustAxisError::TorqueRankDeficient { rank: 2 })
    );

    // Zero-torque commands produce no force: G1f lies in the row space of G1τ.
    let mut no_force = frame.clone();
    no_force.g1_f = [no_force.g1_tau[0].clone(), no_force.g1_tau[1].clone(), vec![0.0; 4]];
    assert_eq!(
        solver.solve(&no_force.problem().unwrap()),
        Err(ThrustAxisError::NoZeroTorqueThrust)
    );

    // Motors too weak: hover needs 0.4 of full command, the bounds allow 0.3.
    let mut weak = frame.clone();
    weak.u_max = vec![0.3; 4];
    assert_eq!(solver.solve(&weak.problem().unwrap()), Err(ThrustAxisError::NoHoverWithinBounds));

    // Idle thrust above the hover command: also impossible (m = 4 has no bounded alternative).
    let mut idle = frame;
    idle.u_min = vec![0.5; 4];
    assert_eq!(solver.solve(&idle.problem().unwrap()), Err(ThrustAxisError::NoHoverWithinBounds));
}

#[test]
fn heuristic_only_configuration_refuses_instead_of_searching() {
    let frame = hexarotor_without_hover_within_bounds(&mut Rng::new(0x5EED_0004));
    let problem = frame.problem().unwrap();
    let mut heuristic =
        ThrustAxisSolver::new(SolverConfig { bounded_search: false, ..SolverConfig::default() });
    assert_eq!(heuristic.solve(&problem), Err(ThrustAxisError::NoHoverWithinBounds));
}

/// A random planar hexarotor, its upper bounds drawn in 0.3–1, whose unbounded hover leaves them.
fn hexarotor_without_hover_within_bounds(rng: &mut Rng) -> Airframe {
    loop {
        let mut frame = random_airframe(rng, 6, Kind::Planar);
        frame.u_max = (0..6).map(|_| rng.range(0.3, 1.0)).collect();
        if dense_unbounded(&frame).is_some_and(|dense| dense.u.is_none()) {
            return frame;
        }
    }
}

/// With `clamp_outside_bounds`, a `u*` outside the bounds is clamped to them and returned,
/// marked: its thrust direction is that of the clamped commands, and `clamped_by` is how far
/// `u*` was outside.
#[test]
fn clamping_gives_the_axis_of_the_clamped_commands_and_says_by_how_much() {
    let clamping = SolverConfig {
        bounded_search: false,
        clamp_outside_bounds: true,
        ..SolverConfig::default()
    };
    // The paper's quad, whose hover needs 0.4 of full command, with one motor allowed 0.3:
    // clamped, it is 0.1 short and the others carry on at u*.
    let frame = paper_quad([1.0, 0.0, 0.0, 0.0]);
    let free = ThrustAxisSolver::default().solve(&frame.problem().unwrap()).unwrap();
    assert_eq!(free.clamped_by, 0.0);
    let mut one_limited = frame.clone();
    one_limited.u_max[0] = free.u_hover()[0] as f64 - 0.1;
    let clamped = ThrustAxisSolver::new(clamping).solve(&one_limited.problem().unwrap()).unwrap();
    assert!((clamped.clamped_by - 0.1).abs() < 1e-4, "{}", clamped.clamped_by);
    assert!(!clamped.bounded);
    for (i, (&u, &u_free)) in clamped.u_hover().iter().zip(free.u_hover()).enumerate() {
        let expected = if i == 0 { u_free - 0.1 } else { u_free };
        assert!((u - expected).abs() < 1e-4, "motor {i}: {u} vs {expected}");
    }
    assert_thrust_along_clamped_commands(&one_limited, &clamped);

    // Every motor allowed 0.3: not even all four at their bound lift it. Refused.
    let mut weak = frame.clone();
    weak.u_max = vec![0.3; 4];
    assert_eq!(
        ThrustAxisSolver::new(clamping).solve(&weak.problem().unwrap()),
        Err(ThrustAxisError::NoHoverWithinBounds)
    );

    // Random hexarotors whose hover leaves the bounds: the direction of G1f times the clamped
    // commands, every command within the bounds.
    let mut rng = Rng::new(0x5EED_0005);
    let mut seen = 0;
    while seen < 20 {
        let frame = hexarotor_without_hover_within_bounds(&mut rng);
        let problem = frame.problem().unwrap();
        let Ok(solution) = ThrustAxisSolver::new(clamping).solve(&problem) else { continue };
        seen += 1;
        assert!(solution.clamped_by > 0.0);
        assert_thrust_along_clamped_commands(&frame, &solution);
    }
}

/// Every command of `solution` within `frame`'s bounds, and its thrust direction that of
/// `G1f u`.
fn assert_thrust_along_clamped_commands(frame: &Airframe, solution: &HoverSolution) {
    let u = to_f64(solution.u_hover());
    let mut force = [0.0f64; 3];
    for (i, &ui) in u.iter().enumerate() {
        assert!(ui >= frame.u_min[i] - 1e-6 && ui <= frame.u_max[i] + 1e-6, "{ui}");
        for k in 0..3 {
            force[k] += frame.g1_f[k][i] * ui;
        }
    }
    let norm = force.iter().map(|f| f * f).sum::<f64>().sqrt();
    let dir = dir_f64(solution);
    for k in 0..3 {
        assert!((force[k] / norm - dir[k]).abs() < 1e-4, "{force:?} vs {dir:?}");
    }
}

fn any_row(len: usize) -> impl Strategy<Value = Vec<f32>> {
    prop::collection::vec(
        prop_oneof![
            4 => -50.0f32..50.0,
            1 => proptest::num::f32::ANY,
            1 => Just(0.0f32),
        ],
        len,
    )
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 200,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    /// Arbitrary input (NaN, infinities, zeros, any shape) never panics: the constructor or the
    /// solver answers with a typed error, or the solution satisfies its own invariants.
    #[test]
    fn never_panics_on_arbitrary_input(
        m in 0usize..10,
        lengths in prop::collection::vec(0usize..10, 6),
        data in prop::collection::vec(any_row(10), 9),
        bounds in prop::collection::vec(-2.0f32..2.0, 20),
        g in prop_oneof![Just(9.81f32), proptest::num::f32::ANY],
        mismatch in any::<bool>(),
    ) {
        let len = |k: usize| if mismatch { lengths[k] } else { m };
        let f = [&data[0][..len(0)], &data[1][..len(1)], &data[2][..len(2)]];
        let t = [&data[3][..len(3)], &data[4][..len(4)], &data[5][..len(5)]];
        let mut lower: Vec<f32> = bounds[..m].to_vec();
        let mut upper: Vec<f32> = bounds[10..10 + m].to_vec();
        for i in 0..m {
            if lower[i] > upper[i] { core::mem::swap(&mut lower[i], &mut upper[i]); }
        }
        let weights: Vec<f32> = data[6][..m].iter().map(|w| w.abs()).collect();
        let problem = HoverProblem::new(f, t)
            .and_then(|p| p.with_bounds(&lower, &upper))
            .and_then(|p| p.with_weights(&weights))
            .and_then(|p| p.with_gravity(g));
        if let Ok(problem) = problem {
            if let Ok(solution) = ThrustAxisSolver::default().solve(&problem) {
                prop_assert!(solution.u_hover().iter().all(|x| x.is_finite()));
                let norm: f32 = solution.q_thrust_to_imu.iter().map(|x| x * x).sum();
                prop_assert!((norm - 1.0).abs() < 1e-4);
                for (i, &x) in solution.u_hover().iter().enumerate() {
                    prop_assert!(x >= problem.u_min()[i] && x <= problem.u_max()[i]);
                }
            }
        }
    }
}
