//! `cargo xtask telemetry [SECONDS]`: the SITL's 2 kHz `state` topic (every control step's
//! attitude, rates, motor commands and speeds) streamed to the configurator over the
//! pseudo-terminal for SECONDS (default 60) of simulated time. Fails unless the sequence
//! numbers show zero gaps and every step arrived; prints the throughput.

use crate::util;
use anyhow::{bail, Context, Result};
use std::process::{Command, Stdio};

/// Simulated seconds streamed by default (issue 9: one minute).
const DEFAULT_SECONDS: f64 = 60.0;
/// The control rate the state topic is streamed at, Hz.
const STATE_RATE_HZ: u32 = 2000;

pub fn telemetry(args: &[String]) -> Result<()> {
    let seconds = match args {
        [] => DEFAULT_SECONDS,
        [value] => value
            .parse::<f64>()
            .ok()
            .filter(|s| s.is_finite() && (1.0..=3600.0).contains(s))
            .with_context(|| format!("SECONDS must be 1 to 3600 (got `{value}`)"))?,
        _ => bail!("usage: cargo xtask telemetry [SECONDS]"),
    };
    util::run(util::cargo().args(["build", "--quiet", "-p", "configurator-cli"]))?;
    let cli = util::root().join("target").join("debug").join("configurator-cli");
    // A little longer than asked, so the board-time span covers `seconds` in full.
    let listen_s = format!("{}", seconds + 0.2);
    let mut command = Command::new(&cli);
    command
        .args(["--sitl", "--json", "stream", "--topic", "state", "--rate-hz"])
        .arg(STATE_RATE_HZ.to_string())
        .args(["--duration-s", &listen_s])
        .stderr(Stdio::inherit());
    eprintln!("streaming the SITL's state topic at {STATE_RATE_HZ} Hz for {seconds} s…");
    let output = command.output().context("could not start the configurator")?;
    if !output.status.success() {
        bail!("the configurator failed ({})", output.status);
    }
    let report: serde_json::Value =
        serde_json::from_slice(&output.stdout).context("the configurator's JSON summary")?;
    let number =
        |key: &str| report[key].as_f64().with_context(|| format!("no `{key}` in {report}"));
    let (received, gaps) = (number("received")?, number("gaps")?);
    let (span_s, bytes_per_s) = (number("board_time_span_s")?, number("bytes_per_s")?);
    let expected = (span_s * f64::from(STATE_RATE_HZ)).round() + 1.0;
    println!("state topic over {span_s:.3} s of simulated time:");
    println!("  samples received {received}, expected {expected} (one per 500 µs step)");
    println!("  gaps counted by sequence number: {gaps}");
    println!("  throughput: {bytes_per_s:.0} bytes/s ({:.1} kB/s)", bytes_per_s / 1000.0);
    println!("  bad frames: {}", report["bad_frames"]);
    if gaps > 0.0 || received < expected {
        bail!("{gaps} samples missing: the stream did not keep up");
    }
    if span_s < seconds {
        bail!("only {span_s:.3} s of simulated time streamed (asked {seconds} s)");
    }
    Ok(())
}
