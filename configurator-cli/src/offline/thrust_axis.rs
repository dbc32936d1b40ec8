//! `configurator-cli solve thrust-axis [--json] EFFECTIVENESS.json`: the hover thrust axis of an
//! airframe from its effectiveness matrices, with the same `flight::thrust_axis` solver the board
//! runs (f32), so the offline answer is the onboard answer.
//!
//! Input (a contract, see issue 3): one JSON object
//! `{"g1_f": 3 rows of m numbers, "g1_tau": 3 rows of m numbers, "u_min": [m] (default 0),
//! "u_max": [m] (default 1), "weights": [m] (default 1), "g": number (default 9.80665)}` in IMU
//! coordinates: specific force (m/s²) and angular acceleration (rad/s²) per unit command,
//! 4 ≤ m ≤ 8. The default `g` is standard gravity (9.81 before 2026-11-29). Unknown fields,
//! wrong shapes, NaN or out-of-range numbers are input errors.
//!
//! Output: `feasible`, `reason` (when not), `bounded`, `u_hover`, `thrust_dir_imu`,
//! `q_thrust_to_imu` `[w, x, y, z]`, `euler_zyx_deg` `{roll, pitch, yaw}`, `eigenvalue`; or the
//! same as readable text with units. An airframe that cannot hover is a valid answer
//! (`feasible: false`), not an input error.

use super::InputError;
use flight::thrust_axis::{HoverProblem, HoverSolution, ThrustAxisError, ThrustAxisSolver};
use serde::Deserialize;
use serde_json::{json, Value};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Arguments of `solve thrust-axis`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Effectiveness file (JSON): g1_f and g1_tau (3 rows of m numbers each, IMU frame, m/s² and
    /// rad/s² per unit command), optional u_min, u_max, weights (m numbers each) and g (m/s²).
    #[arg(value_name = "EFFECTIVENESS.json")]
    pub input: PathBuf,
}

/// The input file, exactly as the contract spells it.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct EffectivenessFile {
    g1_f: Vec<Vec<f64>>,
    g1_tau: Vec<Vec<f64>>,
    u_min: Option<Vec<f64>>,
    u_max: Option<Vec<f64>>,
    weights: Option<Vec<f64>>,
    g: Option<f64>,
}

/// Run the command; the complete stdout, or the input error (nothing printed).
pub fn run(args: &Args) -> Result<String, InputError> {
    let problem = read_problem(&args.input)?;
    let result = ThrustAxisSolver::default().solve(&problem);
    Ok(if args.json { render_json(&result) } else { render_text(&problem, &result) })
}

fn read_problem(path: &Path) -> Result<HoverProblem, InputError> {
    let name = path.display();
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("{name}: cannot read: {e}")))?;
    let file: EffectivenessFile = serde_json::from_str(&text).map_err(|e| {
        InputError(format!(
            "{name}: not a valid effectiveness file: {e} (fields: g1_f, g1_tau, u_min, u_max, \
             weights, g; numbers must be finite: JSON has no NaN)"
        ))
    })?;
    let to_f32 = |values: &[f64]| values.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let rows = |field: &str, matrix: &[Vec<f64>]| -> Result<[Vec<f32>; 3], InputError> {
        match matrix {
            [x, y, z] => Ok([to_f32(x), to_f32(y), to_f32(z)]),
            _ => Err(InputError(format!(
                "{name}: {field} must have 3 rows (x, y, z) of one number per motor, found {} rows",
                matrix.len()
            ))),
        }
    };
    let g1_f = rows("g1_f", &file.g1_f)?;
    let g1_tau = rows("g1_tau", &file.g1_tau)?;
    let refused = |e: ThrustAxisError| InputError(format!("{name}: {e}"));
    let mut problem =
        HoverProblem::new([&g1_f[0], &g1_f[1], &g1_f[2]], [&g1_tau[0], &g1_tau[1], &g1_tau[2]])
            .map_err(refused)?;
    let m = problem.motors();
    let u_min = file.u_min.as_deref().map_or_else(|| vec![0.0; m], to_f32);
    let u_max = file.u_max.as_deref().map_or_else(|| vec![1.0; m], to_f32);
    problem = problem.with_bounds(&u_min, &u_max).map_err(refused)?;
    if let Some(weights) = &file.weights {
        problem = problem.with_weights(&to_f32(weights)).map_err(refused)?;
    }
    if let Some(g) = file.g {
        problem = problem.with_gravity(g as f32).map_err(refused)?;
    }
    Ok(problem)
}

/// A JSON number from an f32, via its shortest decimal form (so 0.3f32 prints as 0.3).
fn number(x: f32) -> Value {
    x.to_string()
        .parse::<f64>()
        .ok()
        .and_then(serde_json::Number::from_f64)
        .map_or(Value::Null, Value::Number)
}

fn numbers(values: &[f32]) -> Value {
    Value::Array(values.iter().map(|&x| number(x)).collect())
}

fn render_json(result: &Result<HoverSolution, ThrustAxisError>) -> String {
    let value = match result {
        Ok(solution) => {
            let euler = solution.euler_zyx();
            json!({
                "feasible": true,
                "bounded": solution.bounded,
                "u_hover": numbers(solution.u_hover()),
                "thrust_dir_imu": numbers(&solution.thrust_dir_imu),
                "q_thrust_to_imu": numbers(&solution.q_thrust_to_imu),
                "euler_zyx_deg": {
                    "roll": number(euler.roll_rad.to_degrees()),
                    "pitch": number(euler.pitch_rad.to_degrees()),
                    "yaw": number(euler.yaw_rad.to_degrees()),
                },
                "eigenvalue": number(solution.eigenvalue),
            })
        }
        Err(reason) => json!({
            "feasible": false,
            "reason": reason.to_string(),
            "bounded": false,
        }),
    };
    format!("{value}\n")
}

fn render_text(problem: &HoverProblem, result: &Result<HoverSolution, ThrustAxisError>) -> String {
    let solution = match result {
        Ok(solution) => solution,
        Err(reason) => return format!("hover thrust axis: NOT FEASIBLE\n  reason: {reason}\n"),
    };
    let list = |values: &[f32], digits: usize| {
        values.iter().map(|x| format!("{x:.digits$}")).collect::<Vec<_>>().join(", ")
    };
    let euler = solution.euler_zyx();
    let mut out = String::new();
    let _ = writeln!(
        out,
        "hover thrust axis: feasible, {} motors, g = {} m/s²",
        problem.motors(),
        problem.g_mps2()
    );
    let _ = writeln!(
        out,
        "  optimum:           {}",
        if solution.bounded {
            "bounded (the unbounded heuristic left the motor bounds; true optimum with bounds)"
        } else {
            "unbounded heuristic (paper §3.3), within the motor bounds"
        }
    );
    let _ = writeln!(out, "  u_hover:           [{}] (command units)", list(solution.u_hover(), 4));
    let _ = writeln!(
        out,
        "  thrust direction:  [{}] (unit vector, IMU frame)",
        list(&solution.thrust_dir_imu, 5)
    );
    let _ = writeln!(
        out,
        "  q_thrust_to_imu:   [{}] ([w, x, y, z], thrust frame -> IMU frame)",
        list(&solution.q_thrust_to_imu, 5)
    );
    let _ = writeln!(
        out,
        "  Euler ZYX:         roll {:.2}°, pitch {:.2}°, yaw {:.2}°",
        euler.roll_rad.to_degrees(),
        euler.pitch_rad.to_degrees(),
        euler.yaw_rad.to_degrees()
    );
    let _ = writeln!(
        out,
        "  eigenvalue:        {:.4} (m/s²)² per unit command² (hover cost uᵀWu = {:.4})",
        solution.eigenvalue, solution.cost
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// Write `text` to a fresh file in the temp dir; the path.
    fn temp_file(text: &str) -> PathBuf {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "thrust-axis-cli-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("EFFECTIVENESS.json");
        std::fs::write(&path, text).unwrap();
        path
    }

    fn run_on(text: &str, json: bool) -> Result<String, InputError> {
        run(&Args { json, input: temp_file(text) })
    }

    /// The solver's default `g`, m/s².
    const G_MPS2: f64 = flight::navigation::STANDARD_GRAVITY_MPS2 as f64;

    /// An X quad (arm 0.1 m, inertia 0.01 kg m², hover at 40 %) seen by an IMU rotated by `q`.
    fn quad_json(q: [f64; 4], extra: &str) -> String {
        let [w, x, y, z] = q;
        let r = [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
            [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
            [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
        ];
        let k = G_MPS2 / 1.6;
        let arm = 0.1 / 2f64.sqrt();
        let motors = [(arm, arm, 1.0), (-arm, -arm, 1.0), (arm, -arm, -1.0), (-arm, arm, -1.0)];
        let mut f = vec![vec![0.0; 4]; 3];
        let mut t = vec![vec![0.0; 4]; 3];
        for (i, (px, py, spin)) in motors.iter().enumerate() {
            let force = [0.0, 0.0, -k];
            let torque = [-py * k / 0.01, px * k / 0.01, spin * 0.015 * k / 0.02];
            for row in 0..3 {
                f[row][i] = (0..3).map(|c| r[row][c] * force[c]).sum::<f64>();
                t[row][i] = (0..3).map(|c| r[row][c] * torque[c]).sum::<f64>();
            }
        }
        format!(r#"{{"g1_f": {f:?}, "g1_tau": {t:?}{extra}}}"#)
    }

    /// A flat hexarotor (radius 0.15 m, alternating spin, hover at 40 %), IMU aligned with FRD.
    fn hexa_json(extra: &str) -> String {
        let k = G_MPS2 / 2.4;
        let mut f = vec![vec![0.0; 6]; 3];
        let mut t = vec![vec![0.0; 6]; 3];
        for i in 0..6 {
            let angle = std::f64::consts::PI * (i as f64 + 0.5) / 3.0;
            let (px, py) = (0.15 * angle.cos(), 0.15 * angle.sin());
            let spin = if i % 2 == 0 { 1.0 } else { -1.0 };
            f[2][i] = -k;
            t[0][i] = -py * k / 0.01;
            t[1][i] = px * k / 0.01;
            t[2][i] = spin * 0.015 * k / 0.02;
        }
        format!(r#"{{"g1_f": {f:?}, "g1_tau": {t:?}{extra}}}"#)
    }

    #[test]
    fn capped_motor_gives_the_bounded_optimum() {
        // Unbounded, every motor would hover at 0.4; motor 0 may give at most 0.3.
        let out = run_on(&hexa_json(r#", "u_max": [0.3, 1, 1, 1, 1, 1]"#), true).unwrap();
        let v: Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["feasible"], true, "{out}");
        assert_eq!(v["bounded"], true, "{out}");
        let u: Vec<f64> =
            v["u_hover"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        assert!(u[0] <= 0.3 + 1e-6 && u.iter().all(|&x| (0.0..=1.0).contains(&x)), "{u:?}");
        // Still hovering straight up in the IMU frame (the frame is symmetric about z).
        let d = v["thrust_dir_imu"].as_array().unwrap();
        assert!((d[2].as_f64().unwrap() + 1.0).abs() < 1e-3, "{d:?}");
        let text = run_on(&hexa_json(r#", "u_max": [0.3, 1, 1, 1, 1, 1]"#), false).unwrap();
        assert!(text.contains("bounded"), "{text}");
    }

    fn paper_q() -> [f64; 4] {
        let q = [0.837f64, -0.491, 0.242, 0.0];
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        q.map(|v| v / n)
    }

    #[test]
    fn json_output_has_the_contract_fields_and_the_paper_angles() {
        let out = run_on(&quad_json(paper_q(), ""), true).unwrap();
        let v: Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["feasible"], true);
        assert_eq!(v["bounded"], false);
        assert!(v.get("reason").is_none());
        let u = v["u_hover"].as_array().unwrap();
        assert_eq!(u.len(), 4);
        assert!(u.iter().all(|x| (x.as_f64().unwrap() - 0.4).abs() < 1e-4), "{u:?}");
        let d: Vec<f64> =
            v["thrust_dir_imu"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        assert!((d.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-5);
        let q: Vec<f64> =
            v["q_thrust_to_imu"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        let expected = paper_q();
        assert!((0..4).all(|i| (q[i] - expected[i]).abs() < 1e-4), "{q:?}");
        let e = &v["euler_zyx_deg"];
        assert!((e["roll"].as_f64().unwrap() + 64.0).abs() < 0.5);
        assert!((e["pitch"].as_f64().unwrap() - 24.0).abs() < 0.5);
        assert!((e["yaw"].as_f64().unwrap() + 15.0).abs() < 0.5);
        assert!(v["eigenvalue"].as_f64().unwrap() > 0.0);
    }

    #[test]
    fn text_output_states_units() {
        let out =
            run_on(&quad_json(paper_q(), r#", "g": 9.80665, "weights": [1, 1, 1, 1]"#), false)
                .unwrap();
        assert!(
            out.contains("feasible") && out.contains("°") && out.contains("IMU frame"),
            "{out}"
        );
        assert!(out.contains("roll -6") && out.contains("m/s²"), "{out}");
    }

    #[test]
    fn infeasible_airframe_is_an_answer_not_an_error() {
        let out =
            run_on(&quad_json(paper_q(), r#", "u_max": [0.3, 0.3, 0.3, 0.3]"#), true).unwrap();
        let v: Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["feasible"], false);
        assert!(v["reason"].as_str().unwrap().contains("bounds"));
        let text =
            run_on(&quad_json(paper_q(), r#", "u_max": [0.3, 0.3, 0.3, 0.3]"#), false).unwrap();
        assert!(text.contains("NOT FEASIBLE"));
    }

    #[test]
    fn bad_input_is_refused_with_the_problem_named() {
        let malformed = [
            (
                r#"{"g1_f": [[1,2,3],[1,2,3],[1,2,3]], "g1_tau": [[1,2,3],[1,2,3],[1,2,3]]}"#,
                "3 motors",
            ),
            (
                r#"{"g1_f": [[1,2,3,4,5,6,7,8,9],[1,2,3,4,5,6,7,8,9],[1,2,3,4,5,6,7,8,9]],
                    "g1_tau": [[1,2,3,4,5,6,7,8,9],[1,2,3,4,5,6,7,8,9],[1,2,3,4,5,6,7,8,9]]}"#,
                "9 motors",
            ),
            (
                r#"{"g1_f": [[1,2,3,4],[1,2,3,4]], "g1_tau": [[1,2,3,4],[1,2,3,4],[1,2,3,4]]}"#,
                "g1_f must have 3 rows",
            ),
            (
                r#"{"g1_f": [[1,2,3,4],[1,2,3,4],[1,2,3,4]], "g1_tau": [[1,2,3,4],[1,2,3],[1,2,3,4]]}"#,
                "g1_tau has length 3",
            ),
            (
                r#"{"g1_f": [[1,2,3,NaN],[1,2,3,4],[1,2,3,4]], "g1_tau": [[1,2,3,4],[1,2,3,4],[1,2,3,4]]}"#,
                "no NaN",
            ),
            (
                r#"{"g1_f": [[1,2,3,1e300],[1,2,3,4],[1,2,3,4]], "g1_tau": [[1,2,3,4],[1,2,3,4],[1,2,3,4]]}"#,
                "g1_f entry for motor 3",
            ),
            ("not json", "not a valid effectiveness file"),
        ];
        // The matrices of a valid four-motor file, with one field more.
        let matrices =
            r#""g1_f": [[1,2,3,4],[1,2,3,4],[1,2,3,4]], "g1_tau": [[1,2,3,4],[1,2,3,4],[1,2,3,4]]"#;
        let one_field_more = [
            (r#""u_max": [1,1,1]"#, "u_max has length 3"),
            (r#""mass": 1"#, "unknown field `mass`"),
            (r#""weights": [1,0,1,1]"#, "weights for motor 1"),
            (r#""g": -1"#, "g must be positive"),
        ]
        .map(|(field, expected)| (format!("{{{matrices}, {field}}}"), expected));
        let cases = malformed.map(|(text, expected)| (text.to_string(), expected));
        for (text, expected) in cases.into_iter().chain(one_field_more) {
            let error = run_on(&text, true).expect_err(&text);
            assert!(error.0.contains(expected), "{text}: {error}");
            assert!(error.0.contains("EFFECTIVENESS.json"), "{error}");
        }
        let missing =
            run(&Args { json: false, input: PathBuf::from("/nonexistent/EFFECTIVENESS.json") });
        assert!(missing.unwrap_err().0.contains("cannot read"));
    }
}
