//! What the board says, for people (aligned text, units on every number) and for programs (JSON
//! with units in the key names).

use protocol::{
    BoardHealth, Capabilities, FailsafeAction, FailsafeReason, FlightMode, FlightTelemetry,
    IdentificationStatus, ImuDriverState, ImuOffsetSource, Info, LandReason, LearnerFailure,
    LearnerPhase, LearnerTelemetry, OffsetAdvice, Status, PROTOCOL_VERSION, SCHEMA_HASH,
};
use serde_json::{json, Value};
use std::fmt::Write as _;

const CAPABILITY_NAMES: [(u32, &str); 10] = [
    (Capabilities::IMU, "imu"),
    (Capabilities::MOTORS, "motors"),
    (Capabilities::MOTOR_RPM, "motor_rpm"),
    (Capabilities::TELEMETRY, "telemetry"),
    (Capabilities::PERSISTENT_STORE, "persistent_store"),
    (Capabilities::SIMULATOR, "simulator"),
    (Capabilities::BOOTLOADER, "bootloader"),
    (Capabilities::RECEIVER, "receiver"),
    (Capabilities::ESC_COMMANDS, "esc_commands"),
    (Capabilities::IDENTIFIES_WITHOUT_SPEEDS, "identifies_without_speeds"),
];

fn capability_list(capabilities: Capabilities) -> Vec<&'static str> {
    CAPABILITY_NAMES.iter().filter(|(flag, _)| capabilities.has(*flag)).map(|(_, n)| *n).collect()
}

/// Board identity as JSON.
pub fn info_json(info: &Info, port: &str) -> Value {
    json!({
        "port": port,
        "board": info.board.as_str(),
        "serial": info.serial.as_str(),
        "firmware_version": format!("{}.{}.{}", info.firmware.major, info.firmware.minor, info.firmware.patch),
        "protocol_version": format!("{}.{}", info.protocol.major, info.protocol.minor),
        "schema_hash": format!("{:016x}", info.schema_hash),
        "schema_matches": info.schema_hash == SCHEMA_HASH,
        "capabilities": capability_list(info.capabilities),
        "control_rate_hz": info.control_rate_hz,
        "motor_count": info.motor_count,
    })
}

/// Board identity as text.
pub fn info_text(info: &Info, port: &str) -> String {
    let mut out = String::new();
    let schema = if info.schema_hash == SCHEMA_HASH {
        "matches this configurator".to_string()
    } else {
        format!(
            "differs from this configurator's {:016x} (protocol {}.{}): fields may be missing",
            SCHEMA_HASH, PROTOCOL_VERSION.major, PROTOCOL_VERSION.minor
        )
    };
    let _ = writeln!(out, "Board {} (serial {}) on {port}", info.board, info.serial);
    let _ = writeln!(
        out,
        "  firmware        {}.{}.{}",
        info.firmware.major, info.firmware.minor, info.firmware.patch
    );
    let _ = writeln!(out, "  protocol        {}.{}", info.protocol.major, info.protocol.minor);
    let _ = writeln!(out, "  schema          {:016x}, {schema}", info.schema_hash);
    let _ = writeln!(out, "  capabilities    {}", capability_list(info.capabilities).join(", "));
    let _ = writeln!(out, "  control rate    {} Hz", info.control_rate_hz);
    let _ = writeln!(out, "  motors          {}", info.motor_count);
    out
}

/// Status as JSON.
pub fn status_json(status: &Status) -> Value {
    let c = &status.control;
    let imu = &status.imu;
    let l = &status.link;
    json!({
        "uptime_s": f64::from(status.uptime_ms) / 1000.0,
        "armed": status.armed,
        "control": {
            "rate_hz": c.rate_hz,
            "steps": c.steps,
            "late_steps": c.late_steps,
            "max_interval_us": c.max_interval_us,
            "samples_processed": c.samples_processed,
            "samples_dropped": c.samples_dropped,
            "max_step_us": c.step_time.map(|t| t.max_us),
            "step_overruns": c.step_time.map(|t| t.overruns),
        },
        "imu": {
            "present": imu.present,
            "samples": imu.samples,
            "missing": imu.missing,
            "gyro_rad_s": imu.gyro_rad_s,
            "accel_mps2": imu.accel_mps2,
            "gyro_mean_rad_s": imu.gyro_mean_rad_s,
            "gyro_std_rad_s": imu.gyro_std_rad_s,
            "accel_std_mps2": imu.accel_std_mps2,
        },
        "imu_offset": {
            "throws": status.imu_offset.throws,
            "in_free_fall": status.imu_offset.in_free_fall,
            "estimated": status.imu_offset.estimated,
            "r_imu_m": status.imu_offset.r_imu_m,
            "ci95_semi_axes_m": status.imu_offset.ci95_semi_axes_m,
            "well_determined": status.imu_offset.well_determined,
            "advice": advice_text(&status.imu_offset.advice),
        },
        "link": {
            "frames_rx": l.frames_rx,
            "frames_tx": l.frames_tx,
            "bad_crc": l.bad_crc,
            "bad_framing": l.bad_framing,
            "oversize": l.oversize,
            "unknown_id": l.unknown_id,
            "malformed": l.malformed,
            "telemetry_dropped": l.telemetry_dropped,
            "responses_dropped": l.responses_dropped,
        },
    })
}

fn vector(v: [f32; 3], scale: f32, decimals: usize) -> String {
    format!("({:+.d$}, {:+.d$}, {:+.d$})", v[0] * scale, v[1] * scale, v[2] * scale, d = decimals)
}

/// The board's IMU-offset advice in words.
pub fn advice_text(advice: &OffsetAdvice) -> String {
    const AXES: [&str; 3] = ["x (forward)", "y (right)", "z (down)"];
    let axis = |index: u8| AXES.get(usize::from(index)).copied().unwrap_or("another axis");
    let direction = |d: &[f32; 3]| format!("({:+.2}, {:+.2}, {:+.2})", d[0], d[1], d[2]);
    match advice {
        OffsetAdvice::None => String::new(),
        OffsetAdvice::ThrowAgain { direction_imu, spin_about_axis } => format!(
            "poorly determined along {} (IMU axes): throw again spinning about IMU {}",
            direction(direction_imu),
            axis(*spin_about_axis)
        ),
        OffsetAdvice::BiasNotSeparable { direction_imu, spin_about_axis } => format!(
            "along {} the offset cannot be told from an accelerometer bias yet: throw again at \
             a different spin rate, about IMU {} (a rest in a new attitude after the catch also \
             helps, as far as the accelerometer's scale errors allow)",
            direction(direction_imu),
            axis(*spin_about_axis)
        ),
        OffsetAdvice::FitBias => "an accelerometer bias spoils the fit: fit the bias too".into(),
    }
}

/// Status as text. `stored_offset_m`: the IMU offset stored by a calibration (the
/// `imu_offset_m` parameter while `imu_offset_valid` is 1), if any.
pub fn status_text(status: &Status, stored_offset_m: Option<[f32; 3]>) -> String {
    let c = &status.control;
    let imu = &status.imu;
    let l = &status.link;
    let norm = |v: [f32; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let mut out = String::new();
    let _ = writeln!(out, "Status");
    let _ = writeln!(out, "  uptime          {:.3} s", f64::from(status.uptime_ms) / 1000.0);
    let _ = writeln!(out, "  armed           {}", if status.armed { "yes" } else { "no" });
    let _ = writeln!(
        out,
        "  control loop    {:.1} Hz, {} steps, {} late, longest interval {} µs",
        c.rate_hz, c.steps, c.late_steps, c.max_interval_us
    );
    let _ = match c.step_time {
        Some(t) => writeln!(
            out,
            "  step time       longest {} µs, {} over the deadline",
            t.max_us, t.overruns
        ),
        None => writeln!(out, "  step time       not measured on this board (simulator)"),
    };
    let _ = writeln!(
        out,
        "  background      {} samples processed, {} dropped",
        c.samples_processed, c.samples_dropped
    );
    if imu.present {
        let _ = writeln!(out, "  imu             {} samples, {} missing", imu.samples, imu.missing);
        let _ = writeln!(
            out,
            "  gyro            {} °/s",
            vector(imu.gyro_rad_s, 180.0 / std::f32::consts::PI, 2)
        );
        let _ = writeln!(
            out,
            "  accelerometer   {} m/s² (|a| = {:.3} m/s²)",
            vector(imu.accel_mps2, 1.0, 3),
            norm(imu.accel_mps2)
        );
        let _ = writeln!(
            out,
            "  gyro spread     {} mrad/s (1σ over the last second: the noise at rest), mean {} mrad/s",
            vector(imu.gyro_std_rad_s, 1000.0, 2),
            vector(imu.gyro_mean_rad_s, 1000.0, 2)
        );
        let _ = writeln!(
            out,
            "  accel spread    {} m/s² (1σ over the last second)",
            vector(imu.accel_std_mps2, 1.0, 4)
        );
    } else {
        let _ = writeln!(out, "  imu             absent ({} steps without a sample)", imu.missing);
    }
    out.push_str(&imu_offset_text(&status.imu_offset, stored_offset_m));
    let _ = writeln!(
        out,
        "  link            {} frames in, {} out; errors: {} CRC, {} framing, {} oversize, {} unknown id, {} malformed; dropped: {} telemetry, {} responses",
        l.frames_rx, l.frames_tx, l.bad_crc, l.bad_framing, l.oversize, l.unknown_id, l.malformed,
        l.telemetry_dropped, l.responses_dropped
    );
    out
}

/// The IMU offset: the stored calibration and the onboard estimator's live estimate, apart.
/// With a calibration stored, the live estimate's advice is not given: the calibration is what
/// the board uses, and the estimator (which sees throws and rests of an unpowered craft only)
/// merely follows the throws since start-up.
pub fn imu_offset_text(offset: &protocol::ImuOffsetStatus, stored: Option<[f32; 3]>) -> String {
    let mut out = String::new();
    if let Some(r) = stored {
        let _ = writeln!(
            out,
            "  imu offset      {} mm from the CoG (IMU axes): stored calibration, in use",
            vector(r, 1000.0, 2)
        );
    }
    let label = if stored.is_some() { "  live estimate  " } else { "  imu offset     " };
    let throws = match offset.throws {
        1 => "1 throw".to_string(),
        n => format!("{n} throws"),
    };
    if offset.estimated {
        let verdict = match (offset.well_determined, stored.is_some()) {
            (true, _) => well_determined_text(offset.ci95_semi_axes_m[0]),
            (false, true) => "not well determined (the stored calibration is used)".to_string(),
            (false, false) => format!("not yet well determined: {}", advice_text(&offset.advice)),
        };
        let _ = writeln!(
            out,
            "{label} {} mm from the CoG (IMU axes), 95 % semi-axes {} mm, {throws} since start-up, {verdict}",
            vector(offset.r_imu_m, 1000.0, 2),
            vector(offset.ci95_semi_axes_m, 1000.0, 2).replace('+', ""),
        );
    } else if stored.is_some() {
        let _ =
            writeln!(out, "{label} {throws} since start-up (none needed: a calibration is stored)");
    } else if offset.throws > 0 {
        let _ = writeln!(
            out,
            "{label} {throws}, too little free fall to estimate from yet: throw again, higher"
        );
    } else {
        let _ = writeln!(out, "{label} no throw yet (throw the craft spinning and catch it)");
    }
    out
}

/// The sensors' health (protocol 1.6): IMU samples held over, motors reporting their speed.
pub fn health_text(health: &protocol::SensorHealth) -> String {
    let mut out = String::new();
    let held = &health.imu_held;
    let _ = if held.total() == 0 {
        writeln!(out, "  imu glitches    none held over while armed")
    } else {
        writeln!(
            out,
            "  imu glitches    {} samples held over while armed ({} missing, {} not finite, {} frozen, {} accelerometer saturated), longest run {:.1} ms",
            held.total(),
            held.missing,
            held.non_finite,
            held.frozen,
            held.accel_saturated,
            f64::from(health.imu_longest_hold_us) / 1000.0
        )
    };
    let all = ((1u16 << health.motor_count.min(8)) - 1) as u8;
    let silent = all & !health.speeds_reported;
    let _ = if health.motor_count == 0 {
        writeln!(out, "  motor speeds    no motors")
    } else if silent == 0 {
        writeln!(out, "  motor speeds    reported by all {} motors", health.motor_count)
    } else {
        writeln!(
            out,
            "  motor speeds    NOT reported by motor {} (none within {} ms): throw-to-fly is refused; the learner needs bidirectional DShot",
            crate::link::motor_list(silent),
            protocol::SPEED_REPORT_TIMEOUT_MS
        )
    };
    if health.speed_reports_lost > 0 {
        let _ = writeln!(
            out,
            "  speed reports   lost {} times while the motors spun",
            health.speed_reports_lost
        );
    }
    out
}

/// The sensors' health as JSON.
pub fn health_json(health: &protocol::SensorHealth) -> Value {
    let held = &health.imu_held;
    json!({
        "imu_held": {
            "missing": held.missing,
            "non_finite": held.non_finite,
            "frozen": held.frozen,
            "accel_saturated": held.accel_saturated,
            "total": held.total(),
        },
        "imu_longest_hold_s": f64::from(health.imu_longest_hold_us) * 1e-6,
        "motor_count": health.motor_count,
        "speeds_reported": (0..health.motor_count).map(|i| health.speeds_reported & (1 << i) != 0).collect::<Vec<_>>(),
        "speed_reports_lost": health.speed_reports_lost,
    })
}

/// Where the latest identification's IMU offset came from, one word for JSON.
fn offset_source_name(source: ImuOffsetSource) -> &'static str {
    match source {
        ImuOffsetSource::NotUsed => "none_yet",
        ImuOffsetSource::Configured => "calibration",
        ImuOffsetSource::Onboard => "throws",
        ImuOffsetSource::Zero => "zero",
        ImuOffsetSource::FittedInFlight => "fitted_in_flight",
    }
}

/// How the latest identification was made (protocol 1.12), for programs.
pub fn identification_json(identification: &IdentificationStatus) -> Value {
    json!({
        "speeds": if identification.speeds_modelled { "modelled" } else { "measured" },
        "imu_offset_source": offset_source_name(identification.imu_offset_source),
        "r_imu_m": identification.r_imu_m,
    })
}

/// How the latest identification was made, in words: which path gave the motor speeds and
/// where the IMU offset came from.
pub fn identification_text(identification: &IdentificationStatus) -> String {
    if identification.imu_offset_source == ImuOffsetSource::NotUsed {
        return "  identification  none since start-up\n".into();
    }
    let speeds = if identification.speeds_modelled {
        "modelled from the commands (the ESCs report no speed: the weaker path)"
    } else {
        "measured (bidirectional DShot)"
    };
    let r = vector(identification.r_imu_m, 1000.0, 2);
    let offset = match identification.imu_offset_source {
        ImuOffsetSource::NotUsed => unreachable!("returned above"),
        ImuOffsetSource::Configured => format!("the stored calibration, {r} mm"),
        ImuOffsetSource::Onboard => format!("the onboard estimate from throws, {r} mm"),
        ImuOffsetSource::Zero => "none known: zero (no calibration, not fitted)".into(),
        ImuOffsetSource::FittedInFlight => format!("fitted in this flight, {r} mm"),
    };
    format!("  identification  speeds {speeds}\n                  IMU offset {offset}\n")
}

/// The flight battery in words: voltage (per cell), current, charge drawn, charge left.
pub fn battery_text(battery: &protocol::BatteryStatus) -> String {
    use firmware::app::battery::{Pack, SETTLE_S};
    match Pack::of(battery) {
        Pack::Absent => format!(
            "  battery         no pack connected ({:.2} V at the divider: powered over USB)\n",
            battery.voltage_v
        ),
        Pack::Settling => format!(
            "  battery         {:.2} V, {:.1} A (cells not counted yet: the pack settles for {SETTLE_S} s)\n",
            battery.voltage_v, battery.current_a,
        ),
        Pack::Cells(cells) => format!(
            "  battery         {cells}S {:.2} V ({:.2} V a cell), {:.1} A, {:.0} mAh drawn, about {} % left (from the voltage: reads low under load)\n",
            battery.voltage_v,
            battery.voltage_v / f32::from(cells),
            battery.current_a,
            battery.used_mah,
            battery.remaining_pct
        ),
    }
}

/// The flight battery as JSON (units in the names).
pub fn battery_json(battery: &protocol::BatteryStatus) -> Value {
    json!({
        "voltage_v": battery.voltage_v,
        "current_a": battery.current_a,
        "used_mah": battery.used_mah,
        "cells": battery.cells,
        "remaining_pct": battery.remaining_pct,
    })
}

/// The in-flight learner's state in words.
fn learner_phase_text(learner: &LearnerTelemetry) -> String {
    let failure = match learner.failure {
        LearnerFailure::None => "",
        LearnerFailure::NotFreeFall => {
            "the last release was refused: the craft was not falling freely (motors never started)"
        }
        LearnerFailure::ThrowTimedOut => "a throw began but no release followed within 3 s",
        LearnerFailure::RankDeficient => {
            "the motors cannot produce every torque (rank-deficient effectiveness): no hover axis"
        }
        LearnerFailure::NoHover => "no hover within the motor limits along any thrust axis",
        LearnerFailure::NoThrustAxis => "the excitation ended without a hover thrust axis",
        LearnerFailure::MotorUnusable { .. } => {
            "a motor's model is unusable (its time constant or full speed out of range)"
        }
        LearnerFailure::InvalidModel => "the learned model has non-finite entries",
        LearnerFailure::Disarmed => "stopped by a disarm request",
        LearnerFailure::ImuLost => "stopped: the IMU stopped delivering samples",
        LearnerFailure::NoSpeedTelemetry => {
            "stopped: a motor reported no speed (bidirectional DShot); the learner needs them all"
        }
    };
    let phase = match learner.phase {
        LearnerPhase::Idle => "idle (not armed: nothing spins)".to_string(),
        LearnerPhase::WaitingForThrow => "armed: waiting for a throw".to_string(),
        LearnerPhase::Throwing => "a throw is under way".to_string(),
        LearnerPhase::Released => "released: checking free fall, motors off".to_string(),
        LearnerPhase::Exciting => format!(
            "pulsing the motors ({} ms in{})",
            learner.excitation_ms,
            learner.exciting_motor.map(|m| format!(", motor {}", m + 1)).unwrap_or_default()
        ),
        LearnerPhase::Done => format!("done after {} ms of excitation", learner.excitation_ms),
        LearnerPhase::Failed => "failed".to_string(),
    };
    if failure.is_empty() {
        phase
    } else {
        format!("{phase}: {failure}")
    }
}

/// The learner's state and estimates, for people.
pub fn learner_text(learner: &LearnerTelemetry) -> String {
    let mut out = String::new();
    let m = usize::from(learner.motor_count).min(protocol::MAX_MOTORS);
    let _ = writeln!(out, "  identification  {}", learner_phase_text(learner));
    if m == 0 {
        return out;
    }
    let list = |values: &[f32], scale: f32, decimals: usize| {
        values[..m]
            .iter()
            .map(|v| format!("{:.*}", decimals, v * scale))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(out, "  motor τ         {} ms", list(&learner.tau_s, 1000.0, 1));
    let _ = writeln!(out, "  motor ω_full    {} rad/s", list(&learner.omega_max_rad_s, 1.0, 0));
    let converged = |bits: u8| (0..m).filter(|i| bits & (1 << i) != 0).count();
    let _ = writeln!(
        out,
        "  converged       {} of {m} motor models, {} of {m} effectiveness columns",
        converged(learner.motors_converged),
        converged(learner.g1_converged)
    );
    if learner.thrust_axis_valid {
        let [w, x, y, z] = learner.q_thrust_to_imu;
        let [roll, pitch, yaw] = learner.euler_zyx_rad.map(f32::to_degrees);
        let _ = writeln!(
            out,
            "  thrust axis     q_U^T = {w:+.4} {x:+.4}i {y:+.4}j {z:+.4}k (roll {roll:+.2}°, pitch {pitch:+.2}°, yaw {yaw:+.2}°)"
        );
    } else {
        let _ = writeln!(out, "  thrust axis     not found yet");
    }
    out
}

/// G1 per unit normalised thrust as a table: a column per motor, the specific-force rows (m/s²)
/// from `force` (block 0) and the angular-acceleration rows (rad/s²) from `rotation` (block 1).
pub fn g1_text(force: &LearnerTelemetry, rotation: &LearnerTelemetry) -> String {
    let m = usize::from(force.motor_count).min(protocol::MAX_MOTORS);
    let mut out = format!("  {:<30}", "G1 per unit thrust, IMU axes");
    for i in 0..m {
        let _ = write!(out, "{:>10}", format!("motor {}", i + 1));
    }
    out.push('\n');
    let rows = [
        ("specific force x", "m/s²", force.g1_rows[0]),
        ("specific force y", "m/s²", force.g1_rows[1]),
        ("specific force z", "m/s²", force.g1_rows[2]),
        ("angular accel. x", "rad/s²", rotation.g1_rows[0]),
        ("angular accel. y", "rad/s²", rotation.g1_rows[1]),
        ("angular accel. z", "rad/s²", rotation.g1_rows[2]),
    ];
    for (name, unit, row) in rows {
        let _ = write!(out, "    {name:<17} {unit:<10}");
        for value in &row[..m] {
            let _ = write!(out, "{value:>10.1}");
        }
        out.push('\n');
    }
    out
}

/// G1 per unit normalised thrust for programs: six rows (fx, fy, fz in m/s²; p, q, r in rad/s²)
/// of one value per motor.
pub fn g1_json(force: &LearnerTelemetry, rotation: &LearnerTelemetry) -> Value {
    let m = usize::from(force.motor_count).min(protocol::MAX_MOTORS);
    let rows: Vec<&[f32]> =
        force.g1_rows.iter().chain(&rotation.g1_rows).map(|r| &r[..m]).collect();
    json!({ "rows": ["fx_mps2", "fy_mps2", "fz_mps2", "p_radps2", "q_radps2", "r_radps2"], "values": rows })
}

/// The learner's state and estimates, for programs. `exciting_motor` and the bits of the masks
/// are motor indices from 0 (the text numbers motors from 1); `thrust_axis` is null until found.
pub fn learner_json(learner: &LearnerTelemetry) -> Value {
    let m = usize::from(learner.motor_count).min(protocol::MAX_MOTORS);
    let thrust_axis = learner.thrust_axis_valid.then(|| {
        let [roll, pitch, yaw] = learner.euler_zyx_rad.map(f32::to_degrees);
        json!({
            "q_thrust_to_imu": learner.q_thrust_to_imu,
            "euler_zyx_deg": { "roll": roll, "pitch": pitch, "yaw": yaw },
        })
    });
    json!({
        "phase": format!("{:?}", learner.phase),
        "failure": format!("{:?}", learner.failure),
        "description": learner_phase_text(learner),
        "motor_count": learner.motor_count,
        "exciting_motor": learner.exciting_motor,
        "excitation_ms": learner.excitation_ms,
        "tau_s": &learner.tau_s[..m],
        "omega_full_rad_s": &learner.omega_max_rad_s[..m],
        "motors_converged_mask": learner.motors_converged,
        "g1_columns_converged_mask": learner.g1_converged,
        "thrust_axis_valid": learner.thrust_axis_valid,
        "thrust_axis": thrust_axis,
        "g1_block": if learner.g1_block == 0 { "specific_force_mps2_per_unit_thrust" } else { "angular_accel_radps2_per_unit_thrust" },
        "g1_rows": learner.g1_rows.iter().map(|row| row[..m].to_vec()).collect::<Vec<_>>(),
    })
}

/// The phase in one or two words, for one line per sample.
fn learner_phase_short(learner: &LearnerTelemetry) -> String {
    let failure = match learner.failure {
        LearnerFailure::None => "",
        LearnerFailure::NotFreeFall => "not free fall",
        LearnerFailure::ThrowTimedOut => "throw timed out",
        LearnerFailure::RankDeficient => "rank deficient",
        LearnerFailure::NoHover => "no hover",
        LearnerFailure::NoThrustAxis => "no thrust axis",
        LearnerFailure::MotorUnusable { .. } => "motor model unusable",
        LearnerFailure::InvalidModel => "invalid model",
        LearnerFailure::Disarmed => "disarmed",
        LearnerFailure::ImuLost => "IMU lost",
        LearnerFailure::NoSpeedTelemetry => "no speed telemetry",
    };
    let phase = match learner.phase {
        LearnerPhase::Idle => "idle",
        LearnerPhase::WaitingForThrow => "waiting for a throw",
        LearnerPhase::Throwing => "throwing",
        LearnerPhase::Released => "released",
        LearnerPhase::Exciting => "exciting",
        LearnerPhase::Done => "done",
        LearnerPhase::Failed => "failed",
    };
    if failure.is_empty() {
        phase.to_string()
    } else {
        format!("{phase} ({failure})")
    }
}

/// The G1 rows a sample carries: what they are, their unit, their axis names.
fn g1_block_names(block: u8) -> (&'static str, &'static str, [&'static str; 3]) {
    if block == 0 {
        ("specific force", "m/s²", ["x", "y", "z"])
    } else {
        ("angular acceleration", "rad/s²", ["p", "q", "r"])
    }
}

/// One learner telemetry sample on one line: sequence number, time, phase, the motor being
/// pulsed, the time constants and the sample's three G1 rows (per unit normalised thrust).
pub fn learner_sample_text(seq: u16, learner: &LearnerTelemetry) -> String {
    let m = usize::from(learner.motor_count).min(protocol::MAX_MOTORS);
    let mut out =
        format!("#{seq} {:.4} s {}", learner.t_us as f64 * 1e-6, learner_phase_short(learner));
    if let Some(motor) = learner.exciting_motor {
        let _ = write!(out, ", motor {} pulsed", u16::from(motor) + 1);
    }
    if learner.phase == LearnerPhase::Exciting {
        let _ = write!(out, ", {} ms into the excitation", learner.excitation_ms);
    } else if learner.excitation_ms > 0 {
        let _ = write!(out, ", after {} ms of excitation", learner.excitation_ms);
    }
    if m == 0 {
        return out + "\n";
    }
    let numbers = |values: &[f32], scale: f32, decimals: usize| {
        values[..m].iter().map(|v| format!("{:.*}", decimals, v * scale)).collect::<Vec<_>>()
    };
    let _ = write!(out, " | τ {} ms", numbers(&learner.tau_s, 1000.0, 1).join(" "));
    let (what, unit, axes) = g1_block_names(learner.g1_block);
    let _ = write!(out, " | G1 {what} per unit thrust ({unit}):");
    for (axis, row) in axes.iter().zip(&learner.g1_rows) {
        let row: Vec<String> = row[..m].iter().map(|v| format!("{v:+.2}")).collect();
        let _ = write!(out, " {axis} [{}]", row.join(" "));
    }
    out + "\n"
}

/// One learner telemetry sample as one JSON object (for one line per sample): [`learner_json`]
/// with the sequence number and the device time, and the G1 rows under a key that names what
/// they are and their unit (`g1_specific_force_mps2_per_unit_thrust` or
/// `g1_angular_accel_rad_s2_per_unit_thrust`).
pub fn learner_sample_json(seq: u16, learner: &LearnerTelemetry) -> Value {
    let m = usize::from(learner.motor_count).min(protocol::MAX_MOTORS);
    let mut value = learner_json(learner);
    if let Some(map) = value.as_object_mut() {
        // The rows go under a key naming what they are and their unit instead.
        map.remove("g1_rows");
        map.remove("g1_block");
        map.insert("seq".into(), json!(seq));
        map.insert("t_s".into(), json!(learner.t_us as f64 * 1e-6));
        let key = if learner.g1_block == 0 {
            "g1_specific_force_mps2_per_unit_thrust"
        } else {
            "g1_angular_accel_rad_s2_per_unit_thrust"
        };
        let rows: Vec<&[f32]> = learner.g1_rows.iter().map(|row| &row[..m]).collect();
        map.insert(key.into(), json!(rows));
    }
    value
}

/// The configuration store's state as JSON.
pub fn config_json(status: &protocol::ConfigStatus) -> Value {
    json!({
        "origin": origin_text(status.origin),
        "layout_version": status.layout_version,
        "param_count": status.param_count,
        "unsaved_changes": status.unsaved_changes,
        "rejected_at_load": status.rejected_at_load,
        "saves": status.saves,
        "calibrating": status.calibrating,
        "motor_test": status.motor_test,
    })
}

/// The configuration store's state in words.
pub fn config_text(status: &protocol::ConfigStatus) -> String {
    let mut out = format!(
        "configuration: {} parameters, {}; {}\n",
        status.param_count,
        origin_text(status.origin),
        if status.unsaved_changes { "unsaved changes (`save` stores them)" } else { "saved" },
    );
    if status.rejected_at_load > 0 {
        out.push_str(&format!(
            "  {} stored values were outside their range and took their defaults\n",
            status.rejected_at_load
        ));
    }
    out
}

fn origin_text(origin: protocol::ConfigOrigin) -> String {
    match origin {
        protocol::ConfigOrigin::Defaults => "nothing stored yet (defaults)".into(),
        protocol::ConfigOrigin::Loaded => "loaded from flash".into(),
        protocol::ConfigOrigin::UnknownLayout { version } => format!(
            "the flash holds layout {version}, unknown to this firmware: defaults in force, the \
             stored bytes are kept until `save`"
        ),
        protocol::ConfigOrigin::Unreadable => {
            "the stored configuration could not be read: defaults in force".into()
        }
        protocol::ConfigOrigin::NoStore => {
            "no flash store on this board (lost at power-off)".into()
        }
    }
}

/// "well determined", with why a reported semi-axis may exceed the limit the verdict names
/// (`cal_max_semi_axis_mm`, 2 mm by default): the limit judges what the throws leave uncertain,
/// and the reported ellipsoid also holds the IMU's sensitivity errors (`imu_scale_tol_pct`),
/// which no throw reduces.
pub fn well_determined_text(largest_semi_axis_m: f32) -> String {
    let default_limit_mm = firmware::app::params::Param::CalMaxSemiAxisMm.spec().default[0];
    if largest_semi_axis_m * 1000.0 > default_limit_mm {
        "well determined (by the throws; the semi-axes also hold the IMU's scale tolerance, \
         imu_scale_tol_pct, which no throw reduces)"
            .to_string()
    } else {
        "well determined".to_string()
    }
}

/// One calibration throw in words: the free fall, the estimate, its ellipsoid and the advice.
pub fn calibration_throw_text(throw: &protocol::CalibrationThrow) -> String {
    let estimate = &throw.estimate;
    let r_mm = estimate.r_imu_m.map(|x| x * 1000.0);
    let axes_mm = estimate.ci95_semi_axes_m.map(|x| x * 1000.0);
    let verdict = if estimate.well_determined {
        well_determined_text(estimate.ci95_semi_axes_m[0])
    } else if !estimate.estimated {
        "no estimate yet: throw again, spinning".to_string()
    } else {
        advice_text(&estimate.advice)
    };
    format!(
        "  throw {}: {} ms of free fall; IMU offset ({:+.2}, {:+.2}, {:+.2}) mm, 95 % semi-axes \
         {:.2}, {:.2}, {:.2} mm: {verdict}",
        estimate.throws,
        throw.free_fall_ms,
        r_mm[0],
        r_mm[1],
        r_mm[2],
        axes_mm[0],
        axes_mm[1],
        axes_mm[2]
    )
}

/// The estimate once the craft has rested after the latest catch, when that rest made it well
/// determined (the rest tells an accelerometer bias from the offset).
pub fn calibration_rest_text(estimate: &protocol::ImuOffsetStatus) -> String {
    let r_mm = estimate.r_imu_m.map(|x| x * 1000.0);
    let axes_mm = estimate.ci95_semi_axes_m.map(|x| x * 1000.0);
    format!(
        "  held still after throw {}: IMU offset ({:+.2}, {:+.2}, {:+.2}) mm, 95 % semi-axes \
         {:.2}, {:.2}, {:.2} mm: {}",
        estimate.throws,
        r_mm[0],
        r_mm[1],
        r_mm[2],
        axes_mm[0],
        axes_mm[1],
        axes_mm[2],
        well_determined_text(estimate.ci95_semi_axes_m[0])
    )
}

/// A failsafe's reason in words.
pub fn failsafe_reason_text(reason: FailsafeReason) -> String {
    match reason {
        FailsafeReason::BadCommand => "a motor command was not finite or out of range".into(),
        FailsafeReason::AllocationFailed => "the control allocation kept failing".into(),
        FailsafeReason::Identification(failure) => {
            format!("the identification gave no flyable model ({failure:?})")
        }
        FailsafeReason::AttitudeLost => "the attitude was lost (thrust axis far from up)".into(),
        FailsafeReason::ImuLost => "the IMU stopped delivering samples".into(),
        FailsafeReason::ImuFault => "the IMU delivered implausible samples".into(),
        FailsafeReason::PoseLost => "the external pose stopped arriving".into(),
        FailsafeReason::RcLost => "the radio link was lost".into(),
        FailsafeReason::Kill => "the kill switch".into(),
    }
}

/// A failsafe event in words.
pub fn failsafe_event_text(reason: FailsafeReason, action: FailsafeAction, count: u16) -> String {
    let action = match action {
        FailsafeAction::Disarmed => "every motor stopped, disarmed",
        FailsafeAction::LevelHold => "flying on in level hold (no position)",
        FailsafeAction::HeldLastSample => "flying on with the last good IMU sample",
        FailsafeAction::Land => "landing (descends, stops the motors at the touchdown)",
    };
    format!("FAILSAFE: {}: {action} ({count}× since start-up)", failsafe_reason_text(reason))
}

fn mode_text(mode: FlightMode) -> String {
    match mode {
        FlightMode::Off => "not flying".into(),
        FlightMode::LevelHold => "level hold (no external pose: the position drifts)".into(),
        FlightMode::PositionHold => "position hold (external pose)".into(),
        FlightMode::Landing(reason) => format!("landing: {}", land_reason_text(reason)),
        FlightMode::Angle => "angle mode (the pilot's sticks: tilt, climb rate, yaw rate)".into(),
    }
}

/// Why a craft lands, in words.
pub fn land_reason_text(reason: LandReason) -> &'static str {
    match reason {
        LandReason::Commanded => "asked by `land`",
        LandReason::Switch => "the pilot's land switch",
        LandReason::RcLost => "the radio link was lost in flight",
        LandReason::BatteryLow => "the battery is below land_cell_v",
        LandReason::PoseLost => "the external pose stayed lost longer than land_pose_lost_s",
        LandReason::UnsignedDisarm => {
            "an unsigned disarm over an untrusted link (a stranger on the radio's channel?)"
        }
        LandReason::FlyAway => {
            "a fly-away: moving away faster than flyaway_speed_mps for flyaway_time_s"
        }
        LandReason::Caught => "a hand caught it in flight (catch_detect)",
    }
}

/// A landing event in words.
pub fn landing_event_text(event: &protocol::Event) -> Option<String> {
    match *event {
        protocol::Event::Landing { reason, count } => {
            Some(format!("LANDING: {} ({count}× since start-up)", land_reason_text(reason)))
        }
        protocol::Event::Landed { reason: LandReason::Caught, count, .. } => Some(format!(
            "CAUGHT: a hand holds the craft, motors stopped ({count}× landed since start-up)"
        )),
        protocol::Event::Landed { reason, touchdown_speed_mps, count } => Some(format!(
            "LANDED: touched down at {touchdown_speed_mps:.2} m/s, motors stopped ({}; \
             {count}× since start-up)",
            land_reason_text(reason)
        )),
        _ => None,
    }
}

/// What happened to the flight, in words: a failsafe or a landing event (`None` for the
/// other events, which belong to their own commands).
pub fn flight_event_text(event: &protocol::Event) -> Option<String> {
    match *event {
        protocol::Event::Failsafe { reason, action, count } => {
            Some(failsafe_event_text(reason, action, count))
        }
        _ => landing_event_text(event),
    }
}

/// The closed loop's state as text.
pub fn flight_text(flight: &FlightTelemetry) -> String {
    let mut out = String::new();
    let deg = 180.0 / std::f32::consts::PI;
    let _ = writeln!(out, "  flight          {}", mode_text(flight.mode));
    let [roll, pitch, yaw] = flight.euler_zyx_rad.map(|a| a * deg);
    let frame = if flight.mode == FlightMode::Off { "IMU" } else { "thrust frame" };
    let _ = writeln!(
        out,
        "  attitude        roll {roll:+.1}°, pitch {pitch:+.1}°, yaw {yaw:+.1}° ({frame} in NED)"
    );
    if flight.mode != FlightMode::Off {
        let _ = writeln!(
            out,
            "  rates           {} °/s, setpoint {} °/s",
            vector(flight.rate_rad_s, deg, 1),
            vector(flight.rate_sp_rad_s, deg, 1)
        );
        let _ = writeln!(
            out,
            "  thrust axis     {:.1}° from its setpoint; allocation {}; motors at a bound: {}",
            flight.tilt_error_rad * deg,
            match flight.allocation_failures {
                0 => "ok".to_string(),
                n => format!("failing for {n} steps"),
            },
            bits_text(flight.saturated)
        );
    }
    match flight.position_ned_m {
        Some(p) => {
            let _ = writeln!(
                out,
                "  position        {} m NED{}",
                vector(p, 1.0, 3),
                if flight.pose_fresh { "" } else { " (pose not recent)" }
            );
        }
        None => {
            let _ =
                writeln!(out, "  position        unknown (no external pose or GNSS fix received)");
        }
    }
    if let Some(v) = flight.velocity_ned_mps {
        let _ = writeln!(out, "  velocity        {} m/s NED", vector(v, 1.0, 3));
    }
    if let Some(sp) = flight.position_sp_ned_m {
        let _ = writeln!(out, "  setpoint        {} m NED", vector(sp, 1.0, 3));
    }
    let total = flight.failsafes.total();
    match flight.last_failsafe {
        Some(reason) => {
            let _ = writeln!(
                out,
                "  failsafes       {total} since start-up; last: {}",
                failsafe_reason_text(reason)
            );
        }
        None => {
            let _ = writeln!(out, "  failsafes       none since start-up");
        }
    }
    out
}

/// The closed loop's state as JSON (units in the key names).
pub fn flight_json(flight: &FlightTelemetry) -> Value {
    json!({
        "mode": format!("{:?}", flight.mode),
        "q_world_thrust": flight.q_world_thrust,
        "euler_zyx_deg": flight.euler_zyx_rad.map(f32::to_degrees),
        "rate_deg_s": flight.rate_rad_s.map(f32::to_degrees),
        "rate_sp_deg_s": flight.rate_sp_rad_s.map(f32::to_degrees),
        "specific_force_sp_ned_mps2": flight.specific_force_sp_ned_mps2,
        "tilt_error_deg": flight.tilt_error_rad.to_degrees(),
        "position_ned_m": flight.position_ned_m,
        "velocity_ned_mps": flight.velocity_ned_mps,
        "position_sp_ned_m": flight.position_sp_ned_m,
        "pose_fresh": flight.pose_fresh,
        "allocation_failures": flight.allocation_failures,
        "saturated_motors": (0..8).filter(|i| flight.saturated & (1 << i) != 0).collect::<Vec<u8>>(),
        "last_failsafe": flight.last_failsafe.map(|r| format!("{r:?}")),
        "failsafes": flight
            .failsafes
            .named()
            .iter()
            .map(|&(name, count)| (name.to_string(), json!(count)))
            .collect::<serde_json::Map<String, Value>>(),
    })
}

fn bits_text(bits: u8) -> String {
    let set: Vec<String> = (0..8).filter(|i| bits & (1 << i) != 0).map(|i| i.to_string()).collect();
    if set.is_empty() {
        "none".into()
    } else {
        set.join(", ")
    }
}

fn imu_driver_text(state: ImuDriverState) -> String {
    match state {
        ImuDriverState::NotFitted => "no IMU driver".into(),
        ImuDriverState::Running => "running".into(),
        ImuDriverState::WrongIdentity { expected, found } => format!(
            "FAULT: identity register read 0x{found:02x}, expected 0x{expected:02x} (wrong part, or no answer on the bus)"
        ),
        ImuDriverState::ConfigMismatch { register, written, read } => format!(
            "FAULT: register 0x{register:02x} read back 0x{read:02x} after 0x{written:02x} was written"
        ),
        ImuDriverState::BusError => "FAULT: the SPI bus reported an error".into(),
        ImuDriverState::Simulated => "simulated".into(),
    }
}

/// The board's hardware as text.
pub fn board_text(board: &BoardHealth) -> String {
    let mut out = String::new();
    match (board.core_clock_hz, board.silicon_revision) {
        (Some(hz), revision) => {
            let revision = match revision {
                Some(0x1003) => ", silicon revision Y".to_string(),
                Some(0x2003) => ", silicon revision V".to_string(),
                Some(other) => format!(", silicon revision 0x{other:04x}"),
                None => String::new(),
            };
            let _ = writeln!(out, "  core clock      {:.0} MHz{revision}", f64::from(hz) / 1e6);
        }
        (None, _) => {
            let _ = writeln!(out, "  core clock      none (simulator)");
        }
    }
    let _ = writeln!(out, "  imu driver      {}", imu_driver_text(board.imu));
    match &board.motors {
        Some(m) => {
            let n = usize::from(m.motor_count).min(protocol::MAX_MOTORS);
            let per_motor = (0..n)
                .map(|i| format!("{}: {} ok / {} bad", i, m.reports[i], m.report_errors[i]))
                .collect::<Vec<_>>()
                .join("; ");
            let _ = writeln!(
                out,
                "  motor outputs   {} (DShot), {} frames sent; speed reports {per_motor}",
                m.motor_count, m.frames_sent
            );
        }
        None => {
            let _ = writeln!(out, "  motor outputs   no DShot link on this device");
        }
    }
    match &board.receiver {
        Some(r) => {
            let link = if r.link_up {
                format!("link up, {} % link quality, {} dBm", r.link_quality_pct, r.rssi_dbm)
            } else {
                "NO SIGNAL".to_string()
            };
            let _ = writeln!(
                out,
                "  receiver        CRSF, {link}; {} frames, {} bad",
                r.frames, r.frame_errors
            );
        }
        None => {
            let _ = writeln!(out, "  receiver        none");
        }
    }
    out
}

/// The GNSS receiver's line of `info` (protocol 1.16's `GetGnss`; `None`: no GNSS port).
pub fn gnss_text(gnss: Option<&protocol::GnssHealth>) -> String {
    match gnss {
        Some(g) => format!(
            "  gnss            {:?} at {} baud ({:?}); fix type {}, {} satellites, accuracy \
             {:.2} m horizontal, {:.2} m vertical, {:.2} m/s; {} fixes, {} without a fix\n",
            g.state,
            g.baud,
            g.interface,
            g.fix_type,
            g.satellites,
            g.horizontal_accuracy_m,
            g.vertical_accuracy_m,
            g.speed_accuracy_mps,
            g.fixes,
            g.without_fix
        ),
        None => "  gnss            no GNSS port\n".to_string(),
    }
}

/// The GNSS receiver as JSON (units in the names).
pub fn gnss_json(gnss: &protocol::GnssHealth) -> Value {
    json!({
        "state": format!("{:?}", gnss.state),
        "baud": gnss.baud,
        "interface": format!("{:?}", gnss.interface),
        "fix_type": gnss.fix_type,
        "satellites": gnss.satellites,
        "horizontal_accuracy_m": finite(gnss.horizontal_accuracy_m),
        "vertical_accuracy_m": finite(gnss.vertical_accuracy_m),
        "speed_accuracy_mps": finite(gnss.speed_accuracy_mps),
        "fixes": gnss.fixes,
        "without_fix": gnss.without_fix,
        "checksum_errors": gnss.checksum_errors,
    })
}

/// `value`, or JSON null when it is not finite (JSON has no NaN).
fn finite(value: f32) -> Option<f32> {
    value.is_finite().then_some(value)
}

/// The board's hardware as JSON.
pub fn board_json(board: &BoardHealth) -> Value {
    json!({
        "core_clock_hz": board.core_clock_hz,
        "silicon_revision": board.silicon_revision,
        "imu_driver": format!("{:?}", board.imu),
        "motors": board.motors.map(|m| json!({
            "motor_count": m.motor_count,
            "frames_sent": m.frames_sent,
            "reports": m.reports[..usize::from(m.motor_count).min(8)].to_vec(),
            "report_errors": m.report_errors[..usize::from(m.motor_count).min(8)].to_vec(),
        })),
        "receiver": board.receiver.map(|r| json!({
            "link_up": r.link_up,
            "link_quality_pct": r.link_quality_pct,
            "rssi_dbm": r.rssi_dbm,
            "frames": r.frames,
            "frame_errors": r.frame_errors,
        })),
    })
}

/// `security`: how the link is guarded, in words.
pub fn link_security_text(security: &protocol::LinkSecurity, signing: bool) -> String {
    let link = if security.trusted {
        "trusted (USB or the simulator's own link): every request is carried out unsigned"
    } else {
        "untrusted (a radio): configuration, arming, motor and steering requests must be signed"
    };
    let paired = match (security.paired, signing) {
        (true, true) => "paired; this computer keeps the key and signs",
        (true, false) => "paired with another computer (no key for this board here)",
        (false, _) => "not paired (`configurator-cli pair` over USB)",
    };
    format!(
        "link: {link}\nkey: {paired}\nsession: {:016x}\nrefused here since start-up: {} unsigned, \
         {} with a bad signature, {} replayed\n",
        security.session, security.unsigned_refused, security.bad_signature, security.replayed
    )
}

/// `security --json`.
pub fn link_security_json(security: &protocol::LinkSecurity, signing: bool) -> serde_json::Value {
    serde_json::json!({
        "trusted": security.trusted,
        "paired": security.paired,
        "signing": signing,
        "session": format!("{:016x}", security.session),
        "last_timestamp": security.last_timestamp,
        "refused": {
            "unsigned": security.unsigned_refused,
            "bad_signature": security.bad_signature,
            "replayed": security.replayed,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_well_determined_offset_beyond_the_limit_says_why() {
        // The walkthrough's first throw: 95 % semi-axes 2.19, 1.89, 1.81 mm, judged well
        // determined on the throws' part (the rest is the ±3 % sensitivity sphere at 18 mm).
        let beyond = well_determined_text(0.00219);
        assert!(beyond.starts_with("well determined (by the throws"), "{beyond}");
        assert!(beyond.contains("imu_scale_tol_pct"), "{beyond}");
        assert_eq!(well_determined_text(0.0015), "well determined");
    }

    fn exciting_quad(block: u8) -> LearnerTelemetry {
        let mut learner = LearnerTelemetry {
            t_us: 12_345_600,
            phase: LearnerPhase::Exciting,
            motor_count: 4,
            exciting_motor: Some(2),
            excitation_ms: 112,
            g1_block: block,
            ..LearnerTelemetry::default()
        };
        learner.tau_s[..4].copy_from_slice(&[0.0201, 0.025, 0.0302, 0.035]);
        learner.g1_rows[0][..4].copy_from_slice(&[1.25, -1.5, 2.0, 0.5]);
        learner
    }

    #[test]
    fn a_learner_sample_line_has_the_phase_the_motor_the_time_constants_and_units() {
        let line = learner_sample_text(41, &exciting_quad(0));
        assert_eq!(line.lines().count(), 1, "{line}");
        for expected in [
            "#41 12.3456 s exciting",
            "motor 3 pulsed",
            "112 ms into the excitation",
            "τ 20.1 25.0 30.2 35.0 ms",
            "G1 specific force per unit thrust (m/s²): x [+1.25 -1.50 +2.00 +0.50]",
        ] {
            assert!(line.contains(expected), "`{expected}` missing from {line}");
        }
        let line = learner_sample_text(42, &exciting_quad(1));
        assert!(line.contains("angular acceleration per unit thrust (rad/s²): p ["), "{line}");
        let idle = learner_sample_text(0, &LearnerTelemetry::default());
        assert_eq!(idle, "#0 0.0000 s idle\n");
    }

    #[test]
    fn a_learner_sample_in_json_names_its_g1_block_and_units() {
        let value = learner_sample_json(7, &exciting_quad(0));
        assert_eq!(value["seq"], 7);
        assert_eq!(value["phase"], "Exciting");
        assert_eq!(value["exciting_motor"], 2);
        assert!((value["t_s"].as_f64().unwrap() - 12.3456).abs() < 1e-9);
        let rows = &value["g1_specific_force_mps2_per_unit_thrust"];
        assert_eq!(rows[0], json!([1.25, -1.5, 2.0, 0.5]));
        assert_eq!(rows.as_array().unwrap().len(), 3);
        let value = learner_sample_json(8, &exciting_quad(1));
        assert!(value["g1_angular_accel_rad_s2_per_unit_thrust"].is_array());
        assert!(value.get("g1_specific_force_mps2_per_unit_thrust").is_none());
        assert!(value.get("g1_rows").is_none());
        assert!(!value.to_string().contains('\n'), "one line per sample");
    }

    #[test]
    fn with_a_stored_calibration_the_live_estimate_is_shown_apart_and_never_advises_a_throw() {
        let live = protocol::ImuOffsetStatus {
            throws: 3,
            estimated: true,
            r_imu_m: [0.010, -0.002, 0.004],
            ci95_semi_axes_m: [0.006, 0.004, 0.001],
            well_determined: false,
            advice: OffsetAdvice::ThrowAgain { direction_imu: [1.0, 0.0, 0.0], spin_about_axis: 1 },
            ..Default::default()
        };
        let alone = imu_offset_text(&live, None);
        assert!(alone.contains("throw again"), "{alone}");
        let text = imu_offset_text(&live, Some([0.012, -0.003, 0.005]));
        assert!(text.contains("+12.00, -3.00, +5.00") || text.contains("12.00"), "{text}");
        assert!(text.contains("stored calibration, in use"), "{text}");
        assert!(
            text.contains("live estimate") && text.contains("3 throws since start-up"),
            "{text}"
        );
        assert!(!text.contains("throw again"), "no advice with a calibration stored: {text}");
        let none = imu_offset_text(&protocol::ImuOffsetStatus::default(), Some([0.0; 3]));
        assert!(none.contains("none needed"), "{none}");
    }

    #[test]
    fn the_health_text_names_held_samples_and_the_motors_without_speed_reports() {
        let mut health = protocol::SensorHealth {
            motor_count: 4,
            speeds_reported: 0b1011,
            ..Default::default()
        };
        health.imu_held.non_finite = 1;
        health.imu_longest_hold_us = 0;
        let text = health_text(&health);
        assert!(text.contains("1 samples held over") && text.contains("1 not finite"), "{text}");
        assert!(text.contains("NOT reported by motor 3") && text.contains("refused"), "{text}");
        health.speeds_reported = 0b1111;
        assert!(health_text(&health).contains("reported by all 4 motors"));
    }

    #[test]
    fn status_learner_text_names_failures_and_the_thrust_axis_in_degrees() {
        let mut learner = exciting_quad(0);
        learner.phase = LearnerPhase::Failed;
        learner.failure = LearnerFailure::NoHover;
        let text = learner_text(&learner);
        assert!(text.contains("failed: no hover within the motor limits"), "{text}");
        assert!(text.contains("thrust axis     not found yet"), "{text}");
        learner.phase = LearnerPhase::Done;
        learner.failure = LearnerFailure::None;
        learner.thrust_axis_valid = true;
        learner.q_thrust_to_imu = [1.0, 0.0, 0.0, 0.0];
        learner.euler_zyx_rad = [0.0, 0.0, std::f32::consts::FRAC_PI_2];
        let text = learner_text(&learner);
        assert!(text.contains("yaw +90.00°"), "{text}");
        let axis = &learner_json(&learner)["thrust_axis"];
        assert_eq!(axis["q_thrust_to_imu"], json!([1.0, 0.0, 0.0, 0.0]));
        assert!((axis["euler_zyx_deg"]["yaw"].as_f64().unwrap() - 90.0).abs() < 1e-4, "{axis}");
        learner.thrust_axis_valid = false;
        assert!(learner_json(&learner)["thrust_axis"].is_null());
        assert!(text.contains("20.1, 25.0, 30.2, 35.0 ms"), "{text}");
    }
}
