//! `log to-csv LOG FILE.csv`: a flight log's control steps as the CSV `record` writes, so `plot`
//! and `fit imu-offset` read a flight that was logged onboard as they read one recorded over the
//! link.
//!
//! Every step record becomes one `imu` sample (when the step had one) and one `motors` sample,
//! fed to the same [`Recorder`] `record --topics imu,motors` uses: one row per IMU sample, the
//! columns `t`, the gyro (rad/s) and accelerometer (m/s²) in IMU axes, each motor's command and
//! speed (rad/s). One difference from `record`: the accelerometer columns are the samples as the
//! driver delivered them (the log keeps them so, for the replay), without the stored bias
//! (`acc_bias_mps2`) removed. The log has no attitude (the replay recomputes it), so there are no `state`
//! columns. Records the reader skipped (a torn tail, a bad frame) are counted in the summary;
//! the steps are sequence-numbered, so a lost step is a gap in the `imu` count.

use std::io::Write;
use std::path::PathBuf;

use firmware::app::log::{LogReader, LogRecord};
use protocol::{ImuTelemetry, MotorTelemetry, Telemetry, Topic, MAX_MOTORS};

use super::InputError;
use crate::link::TelemetrySample;
use crate::record::Recorder;

/// `log to-csv` arguments.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// The flight log (LOG00001.BIN from `sitl --log-dir`, or a board's SD card).
    pub log: PathBuf,
    /// The CSV to write.
    pub csv: PathBuf,
}

/// What the conversion did.
#[derive(Debug, Clone, PartialEq)]
pub struct Converted {
    pub steps: u64,
    pub rows: u64,
    pub span_s: f64,
    pub imu_gaps: u64,
    pub bad_frames: u32,
    pub torn_tail_bytes: u32,
}

/// Convert the log's bytes into CSV on `out`.
pub fn convert<W: Write>(bytes: &[u8], out: W) -> Result<Converted, InputError> {
    let mut reader = LogReader::new(bytes);
    let mut recorder: Option<Recorder<W>> = None;
    let mut out = Some(out);
    let mut steps = 0u64;
    let write_error = |e: std::io::Error| InputError(format!("writing the CSV: {e}"));
    for record in reader.by_ref() {
        let LogRecord::Step(step) = record else { continue };
        if recorder.is_none() {
            let motors = step.motor_count();
            let sink = out.take().ok_or_else(|| InputError("internal: no output".into()))?;
            recorder = Some(
                Recorder::new(sink, &[Topic::Imu, Topic::Motors], motors).map_err(write_error)?,
            );
        }
        let Some(recorder) = recorder.as_mut() else { continue };
        steps += 1;
        let seq = step.step as u16;
        let mut commands = [0.0f32; MAX_MOTORS];
        commands[..step.commands.len()].copy_from_slice(&step.commands);
        let motors = Telemetry::Motors(MotorTelemetry {
            t_us: step.t_us,
            commands,
            speeds_rad_s: step.speeds_rad_s,
        });
        recorder.push(&TelemetrySample { seq, data: motors }).map_err(write_error)?;
        if let Some(sample) = step.imu_sample() {
            let imu = Telemetry::Imu(ImuTelemetry {
                t_us: step.t_us,
                gyro_rad_s: sample.gyro_rad_s,
                accel_mps2: sample.accel_mps2,
            });
            recorder.push(&TelemetrySample { seq, data: imu }).map_err(write_error)?;
        }
    }
    let Some(recorder) = recorder else {
        return Err(InputError("the log has no control steps".into()));
    };
    let summary = recorder.summary();
    recorder.finish().map_err(write_error)?;
    let stats = reader.stats();
    let imu_gaps = summary.topics.iter().find(|t| t.topic == Topic::Imu).map_or(0, |t| t.gaps);
    Ok(Converted {
        steps,
        rows: summary.rows,
        span_s: summary.span_s,
        imu_gaps,
        bad_frames: stats.bad_frames,
        torn_tail_bytes: stats.torn_tail_bytes,
    })
}

/// The command: read the log, write the CSV, say what was converted.
pub fn run(args: &Args) -> Result<String, InputError> {
    let bytes = std::fs::read(&args.log)
        .map_err(|e| InputError(format!("cannot read {}: {e}", args.log.display())))?;
    // Built in memory first: bad input leaves no partial file behind.
    let mut csv = Vec::new();
    let converted = convert(&bytes, &mut csv)?;
    std::fs::write(&args.csv, &csv)
        .map_err(|e| InputError(format!("cannot write {}: {e}", args.csv.display())))?;
    Ok(format!(
        "{}: {} control steps, {} rows over {:.3} s ({} IMU samples missing; {} bad frames, {} \
         bytes of torn tail skipped)\n",
        args.csv.display(),
        converted.steps,
        converted.rows,
        converted.span_s,
        converted.imu_gaps,
        converted.bad_frames,
        converted.torn_tail_bytes
    ))
}
