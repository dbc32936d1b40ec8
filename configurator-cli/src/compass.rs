//! The compass on the GNSS mast: the guided calibration (`compass calibrate`) and the words for
//! its report (`doctor`'s `compass` line).
//!
//! The board does the work (`firmware::app::compass`): it gathers while the user turns the
//! craft, solves in its background task, and stores the result only when the hard- and
//! soft-iron fit and the mounting's fit both succeed. This side asks it to start, shows the
//! progress it reports (samples, the sphere's coverage), asks it to finish, and says what came
//! of it: stored (with the fit's figures) or refused (with the reason and what to do).

use crate::link::{Client, LinkError};
use protocol::{
    CompassCalibrationCommand, CompassCalibrationRefusal, CompassCalibrationStatus, CompassHealth,
    Reply, Request,
};
use serde_json::json;
use std::time::{Duration, Instant};

/// How often the progress is asked for while gathering.
const PROGRESS_POLL: Duration = Duration::from_millis(500);
/// Coverage at which gathering stops before its time, per cent: three quarters of the sphere
/// fit as well as the whole (`flight::magnetometer`: a hemisphere, 25 %, already fits).
pub const ENOUGH_COVERAGE_PCT: u8 = 70;
/// Least gathering before the coverage may end it, s: the mounting's fit wants the craft turned
/// about two axes, which takes a person longer than reaching the coverage by a few flips.
const MIN_GATHERING_S: f64 = 20.0;
/// Longest wait for the board's solve, s (a few tens of milliseconds on the board).
const SOLVE_TIMEOUT: Duration = Duration::from_secs(10);

fn health(client: &mut Client) -> Result<CompassHealth, LinkError> {
    match client.request(&Request::GetCompass(()), "the compass request")? {
        Reply::Compass(health) => Ok(health),
        other => Err(LinkError::Unexpected(format!("the compass request answered {other:?}"))),
    }
}

fn command(client: &mut Client, command: CompassCalibrationCommand) -> Result<(), LinkError> {
    client.request(&Request::CompassCalibration(command), "the compass calibration request")?;
    Ok(())
}

/// Why a fit was refused, and what to do, in words.
pub fn refusal_text(refusal: &CompassCalibrationRefusal) -> String {
    match *refusal {
        CompassCalibrationRefusal::TooFewSamples { samples } => {
            format!("only {samples} samples (100 needed): turn the craft for longer")
        }
        CompassCalibrationRefusal::NotAnEllipsoid => "the samples do not come from one field \
            turned through orientations: keep away from steel and running motors, and turn the \
            craft, not the field"
            .into(),
        CompassCalibrationRefusal::InsufficientCoverage { coverage_pct } => format!(
            "the samples cover {coverage_pct} % of the sphere (20 % needed): turn through more \
             orientations, both sides up, nose up and down"
        ),
        CompassCalibrationRefusal::ResidualTooLarge { residual_ut, field_ut } => format!(
            "the samples lie {residual_ut:.1} µT from the fit in a {field_ut:.1} µT field (more \
             than 10 %): a motor running, steel nearby or a broken sensor"
        ),
        CompassCalibrationRefusal::TooFewAttitudes { samples } => format!(
            "only {samples} samples with an attitude (50 needed) for the mounting: turn longer"
        ),
        CompassCalibrationRefusal::NotTurnedAboutTwoAxes { observability } => format!(
            "the craft turned about one axis only (observability {observability:.3}, 0.02 \
             needed): roll or pitch it as well as turning it round"
        ),
        CompassCalibrationRefusal::Numerical => "the fit failed numerically: run it again".into(),
        CompassCalibrationRefusal::Armed => {
            "the craft was armed while gathering: calibrate disarmed, motors off".into()
        }
        CompassCalibrationRefusal::SensorLost => {
            "the compass was lost while gathering: check its I²C wires (SCL, SDA) and supply".into()
        }
    }
}

/// `compass calibrate`: start, show the progress for up to `duration_s` (or until the coverage
/// is [`ENOUGH_COVERAGE_PCT`]), finish, report. A refused fit is an error (exit code 1) that
/// names its reason; nothing is stored then.
pub fn calibrate(
    client: &mut Client,
    duration_s: f64,
    json_output: bool,
) -> Result<String, LinkError> {
    command(client, CompassCalibrationCommand::Start)?;
    eprintln!(
        "calibrating the compass: keep the motors off and stay away from steel; turn the craft \
         slowly through EVERY orientation: all the way round flat, then on each side, nose up, \
         nose down and upside down. {duration_s:.0} s at most; Ctrl-C stops (nothing stored)."
    );
    let started = Instant::now();
    let mut last = (0, 0);
    loop {
        std::thread::sleep(PROGRESS_POLL);
        let elapsed_s = started.elapsed().as_secs_f64();
        let status = health(client)?.calibration;
        let CompassCalibrationStatus::Gathering { samples, coverage_pct } = status else {
            return Err(LinkError::Unexpected(format!(
                "the board stopped gathering: {}",
                status_text(&status)
            )));
        };
        if (samples / 100, coverage_pct) != last {
            last = (samples / 100, coverage_pct);
            eprintln!("  {elapsed_s:5.1} s: {samples} samples, coverage {coverage_pct} %");
        }
        let enough = coverage_pct >= ENOUGH_COVERAGE_PCT && elapsed_s >= MIN_GATHERING_S;
        if enough || elapsed_s >= duration_s {
            break;
        }
    }
    command(client, CompassCalibrationCommand::Finish)?;
    let asked = Instant::now();
    let status = loop {
        let status = health(client)?.calibration;
        if !matches!(status, CompassCalibrationStatus::Solving { .. }) {
            break status;
        }
        if asked.elapsed() > SOLVE_TIMEOUT {
            return Err(LinkError::Unexpected("the board did not finish its solve in 10 s".into()));
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    match status {
        CompassCalibrationStatus::Stored {
            residual_ut,
            field_ut,
            coverage_pct,
            mounting_std_deg,
        } => Ok(if json_output {
            format!(
                "{:#}\n",
                json!({
                    "stored": true,
                    "residual_ut": residual_ut,
                    "field_ut": field_ut,
                    "coverage_pct": coverage_pct,
                    "mounting_std_deg": mounting_std_deg,
                })
            )
        } else {
            format!("{} (not saved: `save` writes it to flash)\n", status_text(&status))
        }),
        CompassCalibrationStatus::Refused(refusal) => Err(LinkError::Unexpected(format!(
            "compass calibration refused, nothing stored: {}",
            refusal_text(&refusal)
        ))),
        other => Err(LinkError::Unexpected(format!(
            "the compass calibration ended unexpectedly: {}",
            status_text(&other)
        ))),
    }
}

/// The calibration's state in words.
pub fn status_text(status: &CompassCalibrationStatus) -> String {
    match status {
        CompassCalibrationStatus::Idle => "no calibration running".into(),
        CompassCalibrationStatus::Gathering { samples, coverage_pct } => {
            format!("gathering: {samples} samples, coverage {coverage_pct} %")
        }
        CompassCalibrationStatus::Solving { samples } => format!("solving {samples} samples"),
        CompassCalibrationStatus::Stored {
            residual_ut,
            field_ut,
            coverage_pct,
            mounting_std_deg,
        } => {
            format!(
                "stored: field {field_ut:.1} µT, residual {residual_ut:.2} µT, coverage \
                 {coverage_pct} %, mounting within {mounting_std_deg:.2}° (1 σ)"
            )
        }
        CompassCalibrationStatus::Refused(refusal) => format!("refused: {}", refusal_text(refusal)),
    }
}
