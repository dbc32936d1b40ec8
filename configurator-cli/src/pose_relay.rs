//! `pose-relay`: poses from a motion-capture system forwarded to the board over its link, so a
//! craft that flies free (the link a telemetry radio) can hold a position.
//!
//! Motion capture → (UDP, one pose a datagram in the line format of [`sim::pose_line`]) → this
//! relay → (the link: USB, TCP or a radio; signed when the link needs it) → the board's
//! `SetExternalPose`. The relay
//! - keeps only the newest pose: a pose is about now, and an older one waiting behind it is
//!   superseded, not queued (counted);
//! - sends at most `rate_hz` a second, which a radio's uplink must carry (a signed pose is about
//!   40 bytes: 50 Hz is a third of a 57,600-baud radio);
//! - never waits for an answer before the next pose (a radio's round trip is 50 ms or more);
//!   the answers are counted as they come, and a refusal is reported with its reason.
//!
//! Latency: the board places each pose in time with its `pose_latency_s` parameter, which
//! should cover the motion-capture system's own latency plus the link's (docs/field.md).

use crate::link::{Client, DeviceErrorText, LinkError};
use protocol::Request;
use sim::pose_line::{PoseFrame, PoseLine};
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

/// Default for the most poses a second the relay sends: motion capture runs at 100–500 Hz, a
/// radio carries this comfortably and position hold needs no more.
pub const DEFAULT_RATE_HZ: f64 = 50.0;
/// Highest accepted `rate_hz`: the board's control rate.
pub const MAX_RATE_HZ: f64 = 2000.0;

/// Why the relay stopped.
#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    #[error("cannot listen for poses on {address}: {source}")]
    Listen { address: SocketAddr, source: std::io::Error },
    #[error("the pose rate must be within 1–{MAX_RATE_HZ} Hz, not {0}")]
    Rate(f64),
    #[error(transparent)]
    Link(#[from] LinkError),
}

/// What the relay did, so far or in all.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct RelaySummary {
    /// Datagrams that were poses.
    pub received: u64,
    /// Datagrams that were not (the reason of the last one in `last_malformed`).
    pub malformed: u64,
    pub last_malformed: Option<String>,
    /// Poses sent to the board.
    pub relayed: u64,
    /// Poses dropped because a newer one arrived before they could be sent.
    pub superseded: u64,
    /// Answers from the board: carried out, and refused (the last refusal's reason).
    pub accepted: u64,
    pub refused: u64,
    pub last_refusal: Option<String>,
    /// Time relayed, s.
    pub duration_s: f64,
}

/// Relay poses received on `listen`, written in `frame`, to `client` at most `rate_hz` a
/// second, for `duration` (or until the link fails), calling `progress` about once a second.
pub fn run(
    client: &mut Client,
    listen: SocketAddr,
    frame: PoseFrame,
    rate_hz: f64,
    duration: Option<Duration>,
    mut progress: impl FnMut(&RelaySummary),
) -> Result<RelaySummary, RelayError> {
    if !(1.0..=MAX_RATE_HZ).contains(&rate_hz) {
        return Err(RelayError::Rate(rate_hz));
    }
    let socket =
        UdpSocket::bind(listen).map_err(|source| RelayError::Listen { address: listen, source })?;
    socket
        .set_nonblocking(true)
        .map_err(|source| RelayError::Listen { address: listen, source })?;
    let interval = Duration::from_secs_f64(1.0 / rate_hz);
    let started = Instant::now();
    let mut summary = RelaySummary::default();
    let mut newest: Option<PoseLine> = None;
    let mut next_due = started;
    let mut last_progress = started;
    let mut datagram = [0u8; 512];
    while duration.is_none_or(|d| started.elapsed() < d) {
        while let Ok(n) = socket.recv(&mut datagram) {
            match std::str::from_utf8(&datagram[..n])
                .map_err(|e| e.to_string())
                .and_then(|text| PoseLine::parse_in(text, frame).map_err(|e| e.to_string()))
            {
                Ok(pose) => {
                    summary.received += 1;
                    if newest.replace(pose).is_some() {
                        summary.superseded += 1;
                    }
                }
                Err(reason) => {
                    summary.malformed += 1;
                    summary.last_malformed = Some(reason);
                }
            }
        }
        // On a grid of `interval`: a late send (the link's read waits up to its timeout) does
        // not slow the ones after it; after a pause (no pose) the grid starts again.
        let now = Instant::now();
        if now >= next_due {
            if let Some(pose) = newest.take() {
                client.post(&Request::SetExternalPose(pose.external_pose()))?;
                summary.relayed += 1;
                next_due = (next_due + interval).max(now - interval);
            }
        }
        count_answers(client, &mut summary)?;
        if last_progress.elapsed() >= Duration::from_secs(1) {
            last_progress = Instant::now();
            summary.duration_s = started.elapsed().as_secs_f64();
            progress(&summary);
        }
    }
    summary.duration_s = started.elapsed().as_secs_f64();
    // The last answers on their way.
    let settle = Instant::now();
    while summary.accepted + summary.refused < summary.relayed
        && settle.elapsed() < Duration::from_millis(500)
    {
        count_answers(client, &mut summary)?;
    }
    Ok(summary)
}

/// Count the board's answers that have arrived.
fn count_answers(client: &mut Client, summary: &mut RelaySummary) -> Result<(), LinkError> {
    for (_, response) in client.take_responses()? {
        match response {
            Ok(_) => summary.accepted += 1,
            Err(error) => {
                summary.refused += 1;
                summary.last_refusal = Some(DeviceErrorText(error).to_string());
            }
        }
    }
    Ok(())
}

/// The summary in words.
pub fn summary_text(summary: &RelaySummary) -> String {
    let rate_hz = summary.relayed as f64 / summary.duration_s.max(1e-9);
    let mut text =
        format!(
        "relayed {} poses in {:.1} s ({rate_hz:.0} Hz) of {} received ({} superseded by a newer \
         one); the board accepted {}, refused {}",
        summary.relayed, summary.duration_s, summary.received, summary.superseded,
        summary.accepted, summary.refused
    );
    if let Some(reason) = &summary.last_refusal {
        text.push_str(&format!(" (last: {reason})"));
    }
    if summary.malformed > 0 {
        text.push_str(&format!(
            "; {} datagrams were not poses (last: {})",
            summary.malformed,
            summary.last_malformed.as_deref().unwrap_or("")
        ));
    }
    text.push('\n');
    text
}
