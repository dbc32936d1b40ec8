//! `fit imu-offset [--offset-only] [--no-drag] [--json] LOG.csv...`: the IMU's offset from the centre of gravity,
//! fitted offline from recorded calibration throws, with its 95 % confidence ellipsoid and advice.
//!
//! The fit is `imu_offset::BatchFitter`, i.e. the board's own free-fall detection, edge
//! trimming, filters and rows, accumulated in `f64` (the seed paper fitted the offset offline in
//! the same way). This module only reads the logs strictly and formats the result.
//!
//! Log format (the contract, also what the configurator records): a header row, then one row per
//! IMU sample with at least the columns `t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z` (seconds; rad/s;
//! m/s² of specific force; IMU frame), in any order among other columns, which are ignored. The
//! rate must be constant (every interval within 10 % of the mean) and within 500 Hz – 8 kHz.

use std::path::{Path, PathBuf};

use imu_offset::{
    BatchFitter, Config, DragModel, Estimate, ImuOffsetError, ImuSample, Model, MAX_RATE_HZ,
    MIN_RATE_HZ,
};
use nalgebra::Vector3;
use serde_json::json;

use firmware::app::params::Param;

use super::InputError;

/// Arguments of `fit imu-offset`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Fit a constant accelerometer bias with the offset (the default; kept for old scripts).
    /// The bias is measured where the craft rests in the hand before and after each throw
    /// (|f − b| = g in several attitudes) and in the free fall.
    #[arg(long, conflicts_with = "offset_only")]
    pub bias: bool,
    /// Fit the offset alone, assuming no accelerometer bias (the seed paper's eq. 3).
    #[arg(long)]
    pub offset_only: bool,
    /// Local gravity (m/s²) for the rest poses, if far from standard gravity (9.80665): e.g.
    /// 9.780 at the equator, 9.832 at the poles. Within 0.01 m/s² it makes no difference.
    #[arg(long, value_name = "M/S²", value_parser = parse_gravity)]
    pub gravity: Option<f32>,
    /// Ignore air drag (the seed paper's eq. 3). By default the drag of each throw is fitted, as
    /// the board does: 3 unknowns per throw, quadratic drag along the world vertical with the
    /// apex at mid-flight, for vertical throws caught at release height (on the simulator it
    /// halves the error: median 0.47 → 0.23 mm).
    #[arg(long)]
    pub no_drag: bool,
    /// The IMU's scale tolerance, ± % (as the board's parameter `imu_scale_tol_pct`: 3 by
    /// default, 0 for a calibrated IMU; cross-axis errors are taken as two thirds of it). Its
    /// sensitivity errors are what no throw reveals: they widen the ellipsoid by about this
    /// fraction of the offset and make the rest poses pin the bias less.
    #[arg(long, value_name = "PCT", value_parser = parse_scale_tolerance)]
    pub imu_scale_tol_pct: Option<f32>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// IMU logs (CSV with a header containing t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z).
    #[arg(required = true, value_name = "LOG.csv")]
    pub logs: Vec<PathBuf>,
}

/// Uncertainty of a local gravity the user typed (m/s²): the International Gravity Formula is
/// good to about 1 mm/s² at sea level for a known latitude.
const KNOWN_GRAVITY_SIGMA_MPS2: f32 = 0.001;

/// Accepted `--gravity` values (m/s²): anywhere on the Earth's surface, with margin.
const GRAVITY_RANGE_MPS2: core::ops::RangeInclusive<f32> = 9.7..=9.9;

fn parse_gravity(text: &str) -> Result<f32, String> {
    let value: f32 = text.trim().parse().map_err(|_| format!("`{text}` is not a number (m/s²)"))?;
    if GRAVITY_RANGE_MPS2.contains(&value) {
        Ok(value)
    } else {
        Err(format!(
            "{value} m/s² is not a gravity on the Earth's surface (allowed {}–{} m/s²)",
            GRAVITY_RANGE_MPS2.start(),
            GRAVITY_RANGE_MPS2.end()
        ))
    }
}

/// `--imu-scale-tol-pct`, within the board's range for `imu_scale_tol_pct`.
fn parse_scale_tolerance(text: &str) -> Result<f32, String> {
    let spec = Param::ImuScaleTolPct.spec();
    let value: f32 = text.trim().parse().map_err(|_| format!("`{text}` is not a number (%)"))?;
    if (spec.min..=spec.max).contains(&value) {
        Ok(value)
    } else {
        Err(format!("{value} % is outside {}–{} %", spec.min, spec.max))
    }
}

/// 95 % semi-axes (largest first) of a 3 × 3 covariance: `√(λ χ²₃(0.95))`.
fn semi_axes_95(covariance: &nalgebra::Matrix3<f64>) -> [f64; 3] {
    let mut eig: Vec<f64> = covariance.symmetric_eigenvalues().iter().copied().collect();
    eig.sort_by(|a, b| b.total_cmp(a));
    let chi2 = f64::from(imu_offset::CHI2_3DOF_95);
    [0, 1, 2].map(|i| (eig[i].max(0.0) * chi2).sqrt())
}

/// The required columns, in the order they are stored in [`LogColumns`].
const REQUIRED_COLUMNS: [&str; 7] = ["t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"];

/// Largest deviation of one sample interval from the mean interval, as a fraction of it: allows
/// timestamps printed with limited decimals (e.g. 8 kHz at 10 µs resolution: ±8 %) but rejects a
/// dropped sample (+100 %).
const MAX_INTERVAL_DEVIATION: f64 = 0.10;

/// One log, read and checked.
pub(crate) struct Log {
    path: PathBuf,
    /// Time of each sample (s), as in the file.
    t_s: Vec<f64>,
    pub(crate) samples: Vec<ImuSample>,
    /// Sample rate (Hz), rounded to a whole number of hertz.
    pub(crate) rate_hz: f32,
}

/// Run the command; returns the complete stdout text.
pub fn run(args: &Args) -> Result<String, InputError> {
    if args.logs.is_empty() {
        return Err(InputError("fit imu-offset: give at least one LOG.csv".into()));
    }
    let logs = args.logs.iter().map(|p| read_log(p)).collect::<Result<Vec<_>, _>>()?;
    let model = if args.offset_only { Model::Offset } else { Model::OffsetAndAccBias };
    let drag_model = if args.no_drag { DragModel::Ignored } else { DragModel::VerticalQuadratic };
    let defaults = Config::default();
    let mut config = Config { model, drag_model, ..defaults };
    if let Some(pct) = args.imu_scale_tol_pct {
        // The board maps its parameter the same way (`Params::imu_offset_config`).
        config = config.with_scale_tolerance(pct / 100.0);
    }
    if let Some(gravity_mps2) = args.gravity {
        // The user knows their local gravity: it is then known to about 1 mm/s².
        config.gravity_mps2 = gravity_mps2;
        config.gravity_sigma_mps2 = KNOWN_GRAVITY_SIGMA_MPS2;
    }
    let mut fitter = BatchFitter::new(config);
    for log in &logs {
        let found =
            fitter.add_log(&log.samples, log.rate_hz).map_err(|e| log_error(&log.path, &e))?;
        if found == 0 {
            return Err(InputError(format!(
                "{}: no free fall found (|specific force| must stay well below 1 g for at least \
                 {} ms while the craft tumbles in the air)",
                log.path.display(),
                Config::default().min_free_fall_s * 1000.0
            )));
        }
    }
    let estimate = fitter.estimate().map_err(|e| InputError(format!("fit imu-offset: {e}")))?;
    let segments: Vec<(String, f64, f64)> = fitter
        .segments()
        .iter()
        .filter_map(|s| {
            let log = logs.get(s.log as usize)?;
            let t_start = *log.t_s.get(s.segment.start_index as usize)?;
            let t_end = *log.t_s.get(s.segment.end_index.checked_sub(1)? as usize)?;
            Some((log.path.display().to_string(), t_start, t_end))
        })
        .collect();
    Ok(if args.json {
        json_output(&estimate, &segments, drag_model)
    } else {
        text_output(&estimate, &segments, drag_model)
    })
}

fn log_error(path: &Path, e: &ImuOffsetError) -> InputError {
    let file = path.display();
    InputError(match e {
        // Sample index i is on line i + 2 (line 1 is the header).
        ImuOffsetError::NonFiniteInput { index } | ImuOffsetError::InputOutOfRange { index } => {
            format!("{file}:{}: {e}", u64::from(*index) + 2)
        }
        ImuOffsetError::RateMismatch { .. } => {
            format!("{file}: {e}; fit logs of one sample rate together")
        }
        _ => format!("{file}: {e}"),
    })
}

fn vec3(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn json_output(e: &Estimate<f64>, segments: &[(String, f64, f64)], drag: DragModel) -> String {
    let c = &e.covariance_m2;
    let mut out = json!({
        "r_imu_m": vec3(&e.r_imu_m),
        "ci95_semi_axes_m": e.ellipsoid.semi_axes_m,
        "ci95_axes": e.ellipsoid.axes.iter().map(vec3).collect::<Vec<_>>(),
        "covariance_m2": (0..3).map(|i| [c[(i, 0)], c[(i, 1)], c[(i, 2)]]).collect::<Vec<_>>(),
        "well_determined": e.verdict.is_well_determined(),
        "advice": e.verdict.to_string(),
        "segments": segments
            .iter()
            .map(|(file, t_start, t_end)| json!({"file": file, "t_start": t_start, "t_end": t_end}))
            .collect::<Vec<_>>(),
        "samples_used": e.samples_used,
        "model": match e.model { Model::Offset => "offset", Model::OffsetAndAccBias => "offset+bias" },
    });
    if let (Some(bias), Some(object)) = (e.acc_bias_mps2, out.as_object_mut()) {
        object.insert("acc_bias_mps2".into(), json!(vec3(&bias)));
        if let Some(c) = e.acc_bias_covariance_m2ps4 {
            object.insert("acc_bias_ci95_semi_axes_mps2".into(), json!(semi_axes_95(&c)));
        }
        object.insert("rest_poses".into(), json!(e.rest_poses));
    }
    if let Some(object) = out.as_object_mut() {
        object.insert("drag_model".into(), json!(drag_model_name(drag)));
    }
    let mut text = serde_json::to_string_pretty(&out).unwrap_or_default();
    text.push('\n');
    text
}

/// The drag model's name in the JSON.
fn drag_model_name(drag: DragModel) -> &'static str {
    match drag {
        DragModel::VerticalQuadratic => "vertical-quadratic",
        DragModel::Ignored => "ignored",
    }
}

fn text_output(e: &Estimate<f64>, segments: &[(String, f64, f64)], drag: DragModel) -> String {
    use std::fmt::Write;
    let mm = |v: f64| v * 1000.0;
    let r = &e.r_imu_m;
    let mut s = String::new();
    let _ = writeln!(s, "IMU offset from the centre of gravity (IMU frame):");
    let _ = writeln!(s, "  r = ({:.2}, {:.2}, {:.2}) mm", mm(r.x), mm(r.y), mm(r.z));
    let _ = writeln!(s, "95 % confidence ellipsoid (semi-axis along unit direction, IMU frame):");
    for (semi, axis) in e.ellipsoid.semi_axes_m.iter().zip(e.ellipsoid.axes.iter()) {
        let _ = writeln!(
            s,
            "  {:8.3} mm along ({:+.3}, {:+.3}, {:+.3})",
            mm(*semi),
            axis.x,
            axis.y,
            axis.z
        );
    }
    if let Some(b) = e.acc_bias_mps2 {
        let known = e
            .acc_bias_covariance_m2ps4
            .map(|c| {
                format!(", known within {:.3} m/s² (largest 95 % semi-axis)", semi_axes_95(&c)[0])
            })
            .unwrap_or_default();
        let _ = writeln!(
            s,
            "Accelerometer bias: ({:.3}, {:.3}, {:.3}) m/s²{known}, from the free fall and {} \
             rest pose(s) in the hand",
            b.x, b.y, b.z, e.rest_poses
        );
    }
    let _ = match drag {
        DragModel::VerticalQuadratic => {
            writeln!(s, "Drag: fitted per throw (quadratic, along the world vertical)")
        }
        DragModel::Ignored => writeln!(s, "Drag: ignored (--no-drag)"),
    };
    let _ = writeln!(
        s,
        "Residual RMS {:.4} m/s² per axis; correlated residuals widen the ellipsoid ×{:.1} in \
         variance over the white-noise formula",
        e.residual_rms_mps2, e.variance_inflation
    );
    let verdict =
        if e.verdict.is_well_determined() { "well determined" } else { "NOT well determined" };
    let _ = writeln!(s, "Verdict: {verdict}");
    let _ = writeln!(s, "Advice: {}", e.verdict);
    let _ = writeln!(s, "Free-fall segments used ({} samples):", e.samples_used);
    for (file, t_start, t_end) in segments {
        let _ = writeln!(s, "  {file}: {t_start:.3} s to {t_end:.3} s");
    }
    s
}

/// Read and check one log.
pub(crate) fn read_log(path: &Path) -> Result<Log, InputError> {
    let file = path.display();
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("{file}: cannot read: {e}")))?;
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end_matches('\r')));
    let (_, header) = lines
        .next()
        .ok_or_else(|| InputError(format!("{file}: empty file (expected a header row)")))?;
    let names: Vec<&str> =
        header.trim_start_matches('\u{feff}').split(',').map(str::trim).collect();
    let mut columns = [0usize; 7];
    for (slot, wanted) in columns.iter_mut().zip(REQUIRED_COLUMNS) {
        let mut found = names.iter().enumerate().filter(|(_, n)| **n == wanted).map(|(i, _)| i);
        *slot = found.next().ok_or_else(|| {
            InputError(format!("{file}:1: missing column `{wanted}` in the header"))
        })?;
        if found.next().is_some() {
            return Err(InputError(format!("{file}:1: column `{wanted}` appears twice")));
        }
    }

    let mut t_s = Vec::new();
    let mut samples = Vec::new();
    for (line, row) in lines {
        if row.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = row.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err(InputError(format!(
                "{file}:{line}: {} fields, the header has {}",
                fields.len(),
                names.len()
            )));
        }
        let mut values = [0.0f64; 7];
        for ((value, &column), name) in values.iter_mut().zip(&columns).zip(REQUIRED_COLUMNS) {
            let field = fields.get(column).copied().unwrap_or("");
            let v: f64 = field.parse().map_err(|_| {
                InputError(format!("{file}:{line}: column `{name}`: `{field}` is not a number"))
            })?;
            if !v.is_finite() {
                return Err(InputError(format!(
                    "{file}:{line}: column `{name}`: `{field}` is not finite (NaN or infinite)"
                )));
            }
            *value = v;
        }
        let [t, gx, gy, gz, ax, ay, az] = values;
        t_s.push(t);
        samples.push(ImuSample {
            gyro_radps: Vector3::new(gx, gy, gz).cast::<f32>(),
            acc_mps2: Vector3::new(ax, ay, az).cast::<f32>(),
        });
    }
    let rate_hz = sample_rate_hz(path, &t_s)?;
    Ok(Log { path: path.to_path_buf(), t_s, samples, rate_hz })
}

/// The constant sample rate of the time column (Hz, rounded to a whole hertz), or why not.
fn sample_rate_hz(path: &Path, t_s: &[f64]) -> Result<f32, InputError> {
    let file = path.display();
    let (Some(first), Some(last)) = (t_s.first(), t_s.last()) else {
        return Err(InputError(format!("{file}: too few samples: no data rows")));
    };
    if t_s.len() < 3 {
        return Err(InputError(format!(
            "{file}: too few samples: {} rows, a sample rate needs at least 3",
            t_s.len()
        )));
    }
    let mean_dt_s = (last - first) / (t_s.len() - 1) as f64;
    if mean_dt_s <= 0.0 {
        return Err(InputError(format!("{file}: column `t` does not increase")));
    }
    for (i, pair) in t_s.windows(2).enumerate() {
        let dt = pair[1] - pair[0];
        if (dt - mean_dt_s).abs() > MAX_INTERVAL_DEVIATION * mean_dt_s {
            return Err(InputError(format!(
                "{file}:{}: sample rate not constant: interval {:.6} s, mean {:.6} s",
                i + 3,
                dt,
                mean_dt_s
            )));
        }
    }
    let rate_hz = (1.0 / mean_dt_s).round();
    if !(f64::from(MIN_RATE_HZ)..=f64::from(MAX_RATE_HZ)).contains(&rate_hz) {
        return Err(InputError(format!(
            "{file}: sample rate {rate_hz} Hz is outside {MIN_RATE_HZ}–{MAX_RATE_HZ} Hz"
        )));
    }
    Ok(rate_hz as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use flight::testing::throws::ThrowSpec;
    use nalgebra::UnitQuaternion;
    use std::fmt::Write as _;

    /// The default fit (offset, bias and drag) of `logs`, as text or JSON.
    fn fit_args(logs: Vec<std::path::PathBuf>, json: bool) -> Args {
        Args {
            bias: false,
            offset_only: false,
            gravity: None,
            no_drag: false,
            imu_scale_tol_pct: None,
            json,
            logs,
        }
    }

    fn r_true() -> Vector3<f64> {
        Vector3::new(-0.010, -0.013, 0.008)
    }

    fn spec(rate_hz: f64, spin: Vector3<f64>, seed: u64) -> ThrowSpec {
        let axes = UnitQuaternion::from_euler_angles(0.35, -0.25, 0.6);
        ThrowSpec::typical(rate_hz, r_true(), axes, axes * spin, seed)
    }

    /// A unique scratch directory for one test.
    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir()
            .join(format!("configurator-imu-offset-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Write a throw as CSV, with the columns in a shuffled order among extra ones.
    fn write_log(path: &Path, spec: &ThrowSpec, t0_s: f64) {
        let mut csv = String::from("acc_z,motor_0,t,gyro_x,acc_x,gyro_y,gyro_z,acc_y,note\n");
        for (i, s) in spec.samples().enumerate() {
            let t = t0_s + i as f64 / spec.rate_hz;
            let (g, a) = (s.gyro_radps, s.acc_mps2);
            let _ = writeln!(csv, "{},0,{t:.6},{},{},{},{},{},x", a.z, g.x, a.x, g.y, g.z, a.y);
        }
        std::fs::write(path, csv).unwrap();
    }

    fn two_logs(name: &str, rate_hz: f64) -> Vec<PathBuf> {
        let dir = scratch(name);
        let a = dir.join("throw_a.csv");
        let b = dir.join("throw_b.csv");
        write_log(&a, &spec(rate_hz, Vector3::new(2.5, 1.0, 12.0), 1), 12.5);
        write_log(&b, &spec(rate_hz, Vector3::new(9.0, 2.0, 1.5), 2), 0.0);
        vec![a, b]
    }

    fn parse_vec3(v: &serde_json::Value) -> Vector3<f64> {
        let a = v.as_array().unwrap();
        assert_eq!(a.len(), 3);
        Vector3::new(a[0].as_f64().unwrap(), a[1].as_f64().unwrap(), a[2].as_f64().unwrap())
    }

    #[test]
    fn json_from_two_throws_is_within_1mm() {
        let logs = two_logs("json", 2000.0);
        for bias in [false, true] {
            let out =
                run(&Args { bias, offset_only: !bias, ..fit_args(logs.clone(), true) }).unwrap();
            let v: serde_json::Value = serde_json::from_str(&out).unwrap();
            let r = parse_vec3(&v["r_imu_m"]);
            let err_mm = (r - r_true()).norm() * 1000.0;
            assert!(err_mm < 1.0, "bias={bias}: r off by {err_mm} mm");
            let semi: Vec<f64> = v["ci95_semi_axes_m"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            assert_eq!(semi.len(), 3);
            assert!(semi.iter().all(|s| *s > 0.0 && *s < 0.002), "semi-axes {semi:?} m");
            let axes = v["ci95_axes"].as_array().unwrap();
            assert_eq!(axes.len(), 3);
            for a in axes {
                assert!((parse_vec3(a).norm() - 1.0).abs() < 1e-9, "unit vectors");
            }
            let cov = v["covariance_m2"].as_array().unwrap();
            assert_eq!(cov.len(), 3);
            assert!(cov.iter().all(|row| row.as_array().unwrap().len() == 3));
            assert_eq!(v["well_determined"], serde_json::Value::Bool(true));
            let advice = v["advice"].as_str().unwrap();
            assert!(advice.contains("well determined"));
            // The advice states the reported ellipsoid's largest semi-axis, to the hundredth of
            // a millimetre it prints.
            let stated = format!("within {:.2} mm", semi[0] * 1000.0);
            assert!(advice.contains(&stated), "advice `{advice}` does not say `{stated}`");
            let segments = v["segments"].as_array().unwrap();
            assert_eq!(segments.len(), 2);
            // First log starts at t = 12.5 s; release at 0.6 s into it, free fall for 0.6 s.
            let t_start = segments[0]["t_start"].as_f64().unwrap();
            let t_end = segments[0]["t_end"].as_f64().unwrap();
            assert!(t_start > 13.1 && t_end < 13.7 && t_end - t_start > 0.4, "{t_start}..{t_end}");
            assert!(segments[1]["file"].as_str().unwrap().ends_with("throw_b.csv"));
            assert!(v["samples_used"].as_u64().unwrap() > 1000);
            assert_eq!(v.get("acc_bias_mps2").is_some(), bias);
            if bias {
                assert!(parse_vec3(&v["acc_bias_mps2"]).norm() < 0.05, "no bias was simulated");
            }
        }
    }

    #[test]
    fn without_drag_the_contract_and_the_accuracy_hold() {
        let logs = two_logs("drag", 2000.0);
        let out = run(&Args { bias: true, no_drag: true, ..fit_args(logs, true) }).unwrap();
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        for key in [
            "r_imu_m",
            "ci95_semi_axes_m",
            "ci95_axes",
            "covariance_m2",
            "well_determined",
            "advice",
            "segments",
            "samples_used",
            "acc_bias_mps2",
        ] {
            assert!(v.get(key).is_some(), "missing `{key}`");
        }
        assert_eq!(v["drag_model"], "ignored");
        let err_mm = (parse_vec3(&v["r_imu_m"]) - r_true()).norm() * 1000.0;
        assert!(err_mm < 1.0, "r off by {err_mm} mm");
    }

    #[test]
    fn text_output_has_units_and_advice() {
        let logs = two_logs("text", 1000.0);
        let out = run(&Args {
            bias: false,
            offset_only: false,
            gravity: None,
            no_drag: false,
            imu_scale_tol_pct: None,
            json: false,
            logs,
        })
        .unwrap();
        assert!(out.contains(" mm"), "{out}");
        assert!(out.contains("Advice: well determined"), "{out}");
        assert!(out.contains("throw_b.csv"), "{out}");
    }

    #[test]
    fn a_calibrated_imu_narrows_the_ellipsoid_and_a_tolerance_out_of_range_is_refused() {
        // The synthetic throws scale exactly. With the default ±3 % the ellipsoid carries the
        // sensitivity errors no throw reveals (3.1 % of |r| = 18 mm, 1σ per axis); with 0 % it
        // does not, and the estimate stays as accurate.
        let logs = two_logs("scale", 2000.0);
        let fit = |pct: Option<f32>| {
            let out = run(&Args { imu_scale_tol_pct: pct, ..fit_args(logs.clone(), true) });
            let v: serde_json::Value = serde_json::from_str(&out.unwrap()).unwrap();
            let largest_m = v["ci95_semi_axes_m"][0].as_f64().unwrap();
            ((parse_vec3(&v["r_imu_m"]) - r_true()).norm(), largest_m)
        };
        let (default_err_m, default_axis_m) = fit(None);
        let (calibrated_err_m, calibrated_axis_m) = fit(Some(0.0));
        assert!(
            calibrated_axis_m < 0.8 * default_axis_m,
            "largest semi-axis {calibrated_axis_m} m with 0 %, {default_axis_m} m with ±3 %"
        );
        assert!(calibrated_err_m < 0.001 && default_err_m < 0.001);
        assert_eq!(fit(Some(3.0)), (default_err_m, default_axis_m), "3 % is the default");
        for bad in ["12", "-1", "three"] {
            assert!(parse_scale_tolerance(bad).is_err(), "`{bad}` accepted");
        }
        assert_eq!(parse_scale_tolerance(" 0.5 "), Ok(0.5));
    }

    #[test]
    fn one_throw_advises_another_axis() {
        let dir = scratch("one");
        let path = dir.join("one.csv");
        write_log(&path, &spec(1000.0, Vector3::new(0.0, 0.0, 12.0), 3), 0.0);
        let out = run(&fit_args(vec![path], true)).unwrap();
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["well_determined"], serde_json::Value::Bool(false));
        assert!(v["advice"].as_str().unwrap().contains("throw again"));
    }

    fn expect_error(name: &str, csv: &str, needles: &[&str]) {
        let path = scratch(name).join("bad.csv");
        std::fs::write(&path, csv).unwrap();
        let err = run(&fit_args(vec![path], true)).unwrap_err();
        for needle in needles {
            assert!(err.0.contains(needle), "`{}` does not mention `{needle}`", err.0);
        }
        assert!(err.0.contains("bad.csv"), "{}", err.0);
    }

    fn still_rows(rate_hz: f64, n: usize) -> String {
        let mut csv = String::from("t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z\n");
        for i in 0..n {
            let _ = writeln!(csv, "{},0,0,0,0,0,-9.81", i as f64 / rate_hz);
        }
        csv
    }

    #[test]
    fn bad_input_is_named() {
        expect_error(
            "missing",
            "t,gyro_x,gyro_y,acc_x,acc_y,acc_z\n0,0,0,0,0,0\n",
            &["gyro_z", ":1"],
        );
        let mut nan = still_rows(1000.0, 100);
        nan = nan.replacen("0,0,0,0,0,-9.81", "0,0,NaN,0,0,-9.81", 1);
        expect_error("nan", &nan, &[":2:", "gyro_z", "not finite"]);
        expect_error("text", "t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z\n0,a,0,0,0,0,0\n", &[":2:"]);
        expect_error("few", &still_rows(1000.0, 2), &["too few samples"]);
        expect_error("slow", &still_rows(100.0, 1000), &["100 Hz", "outside"]);
        let mut gap = still_rows(1000.0, 1000);
        gap = gap.replace("\n0.5,", "\n0.5005,");
        expect_error("jitter", &gap, &["not constant"]);
        expect_error("still", &still_rows(1000.0, 3000), &["no free fall"]);
        expect_error("short", &still_rows(1000.0, 50), &["too few"]);
        let missing = scratch("absent").join("does-not-exist.csv");
        let err = run(&fit_args(vec![missing], false)).unwrap_err();
        assert!(err.0.contains("cannot read"), "{}", err.0);
    }
}
