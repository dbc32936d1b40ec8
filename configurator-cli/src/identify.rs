//! `configurator-cli identify`: the throw-and-fly identification, guided.
//!
//! Arms the board for throw-to-fly, then follows the learner topic (50 Hz) and the state topic
//! (50 Hz) and tells the person what happens: armed (throw now), throw detected, released and
//! falling, each motor pulsed, identified, flying on the learned model. A failure is reported
//! with its reason, and a board that sees no throw in time is disarmed. The board copies the
//! learned model into its parameters by itself (the `g1_*`, `motor_*` and `thrust_axis_q`
//! parameters), to be saved with `save`.

use crate::link::{Client, LinkError, TelemetrySample};
use protocol::{
    ConfigStatus, LearnerFailure, LearnerPhase, LearnerTelemetry, Reply, Request, SetTelemetryRate,
    StateTelemetry, Telemetry, Topic,
};
use std::time::{Duration, Instant};

/// Rate of the learner and state topics while identifying, Hz (the whole G1 every 40 ms).
const WATCH_RATE_HZ: u16 = 50;
/// How long the flow waits after the excitation for the board to report flying, s.
const ENGAGE_WAIT_S: f64 = 1.0;
/// One listening slice, ms.
const LISTEN_SLICE: Duration = Duration::from_millis(20);

/// How the flow runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdentifyOptions {
    /// Disarm when no throw has come this long after arming, s.
    pub throw_timeout_s: f64,
    /// Disarm this long after the craft flies on the learned model (`None`: leave it flying).
    pub disarm_after_s: Option<f64>,
    /// Stream the state topic at every control step (for a recording) instead of 50 Hz.
    pub every_step: bool,
}

/// What the identification found.
#[derive(Debug, Clone, PartialEq)]
pub struct Identified {
    /// The learner's final state with G1's specific-force rows (block 0) and angular-acceleration
    /// rows (block 1).
    pub blocks: [LearnerTelemetry; 2],
    /// Whether the board flew on the learned model.
    pub flew: bool,
    /// Whether the flow disarmed the board at the end.
    pub disarmed: bool,
    /// The configuration after the board stored the model (`unsaved_changes` set).
    pub config: Option<ConfigStatus>,
}

/// Why the identification gave no model.
#[derive(Debug, thiserror::Error)]
pub enum IdentifyError {
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error("identification failed: {0}")]
    Failed(&'static str),
    #[error("no throw within {0} s; disarmed, nothing spun")]
    NoThrow(f64),
}

/// The learner failure in words.
pub fn failure_text(failure: LearnerFailure) -> &'static str {
    match failure {
        LearnerFailure::None => "stopped without a reason",
        LearnerFailure::NotFreeFall => {
            "the craft was not falling freely after the release (still held, or it hit something); the motors never started"
        }
        LearnerFailure::ThrowTimedOut => "a throw began but no release followed within 3 s",
        LearnerFailure::RankDeficient => {
            "the motors do not give torque about every axis (a motor not spinning, or not connected?)"
        }
        LearnerFailure::NoHover => "no motor combination can hover this craft along the found axis",
        LearnerFailure::Disarmed => "disarmed during the attempt",
        LearnerFailure::ImuLost => "the IMU stopped delivering samples",
        LearnerFailure::NoSpeedTelemetry => {
            "a motor stopped reporting its speed (bidirectional DShot): the learner needs every motor's speed; every motor stopped"
        }
    }
}

/// Arm, follow, report; `say` prints progress lines for the person.
/// Every telemetry sample goes to `on_sample` too (a recording).
pub fn identify(
    client: &mut Client,
    options: IdentifyOptions,
    say: &mut dyn FnMut(String),
    on_sample: &mut dyn FnMut(&TelemetrySample),
) -> Result<Identified, IdentifyError> {
    let rate = |topic, rate_hz| Request::SetTelemetryRate(SetTelemetryRate { topic, rate_hz });
    client.request(&Request::ArmThrowToFly(()), "the arm request")?;
    say("armed: throw the craft now (up, about 3 m, spinning is fine); the motors start after the release. `configurator-cli disarm` or Ctrl-C stops everything.".into());
    let state_hz = if options.every_step { client.info.control_rate_hz } else { WATCH_RATE_HZ };
    client.request(&rate(Topic::Learner, WATCH_RATE_HZ), "the telemetry rate request")?;
    client.request(&rate(Topic::State, state_hz), "the telemetry rate request")?;
    client.telemetry.clear();
    let result = follow(client, options, say, on_sample);
    if matches!(result, Err(IdentifyError::NoThrow(_))) {
        client.request(&Request::Disarm(()), "the disarm request")?;
    }
    for topic in [Topic::Learner, Topic::State] {
        client.request(&rate(topic, 0), "the request to stop telemetry")?;
    }
    result
}

fn follow(
    client: &mut Client,
    options: IdentifyOptions,
    say: &mut dyn FnMut(String),
    on_sample: &mut dyn FnMut(&TelemetrySample),
) -> Result<Identified, IdentifyError> {
    let armed_at = Instant::now();
    let mut phase = LearnerPhase::WaitingForThrow;
    let mut exciting = None;
    let mut blocks: [Option<LearnerTelemetry>; 2] = [None, None];
    let mut state: Option<StateTelemetry> = None;
    let mut done_at: Option<Instant> = None;
    loop {
        client.listen(LISTEN_SLICE)?;
        for event in client.events.drain(..) {
            if let protocol::Event::Failsafe { reason, action, count } = event {
                say(crate::report::failsafe_event_text(reason, action, count));
            }
        }
        for sample in client.telemetry.drain(..) {
            on_sample(&sample);
            match sample.data {
                Telemetry::State(s) => state = Some(s),
                Telemetry::Learner(learner) => {
                    if learner.phase != phase {
                        phase = learner.phase;
                        if let Some(text) = phase_news(&learner) {
                            say(text);
                        }
                    }
                    if learner.phase == LearnerPhase::Exciting && learner.exciting_motor != exciting
                    {
                        exciting = learner.exciting_motor;
                        if let Some(motor) = exciting {
                            say(format!(
                                "  pulsing motor {} ({} ms into the excitation)",
                                motor + 1,
                                learner.excitation_ms
                            ));
                        }
                    }
                    if learner.phase == LearnerPhase::Failed {
                        return Err(IdentifyError::Failed(failure_text(learner.failure)));
                    }
                    if learner.phase == LearnerPhase::Done {
                        blocks[usize::from(learner.g1_block.min(1))] = Some(learner);
                    }
                }
                _ => {}
            }
        }
        if phase == LearnerPhase::WaitingForThrow
            && armed_at.elapsed().as_secs_f64() > options.throw_timeout_s
        {
            return Err(IdentifyError::NoThrow(options.throw_timeout_s));
        }
        let [Some(block0), Some(block1)] = blocks else { continue };
        let done_at = *done_at.get_or_insert_with(Instant::now);
        let flying = state.is_some_and(|s| s.flying);
        if !flying && done_at.elapsed().as_secs_f64() < ENGAGE_WAIT_S {
            continue;
        }
        if flying {
            say("flying on the learned model (INDI, in the thrust frame found)".into());
            if let Ok(Reply::Flight(flight)) =
                client.request(&Request::GetFlight(()), "the flight request")
            {
                say(crate::report::flight_text(&flight).trim_end().to_string());
            }
        }
        let mut disarmed = false;
        if let (true, Some(hold_s)) = (flying, options.disarm_after_s) {
            say(format!("holding for {hold_s} s, then disarming"));
            client.listen_with(Duration::from_secs_f64(hold_s), |sample| on_sample(&sample))?;
            client.request(&Request::Disarm(()), "the disarm request")?;
            say("disarmed: every motor stopped".into());
            disarmed = true;
        }
        let config = match client.request(&Request::GetConfig(()), "the configuration request")? {
            Reply::Config(config) => Some(config),
            _ => None,
        };
        return Ok(Identified { blocks: [block0, block1], flew: flying, disarmed, config });
    }
}

/// What a new phase means for the person, if anything.
fn phase_news(learner: &LearnerTelemetry) -> Option<String> {
    Some(match learner.phase {
        LearnerPhase::Throwing => "throw detected".into(),
        LearnerPhase::Released => "released: checking free fall, motors still off".into(),
        LearnerPhase::Exciting => "falling freely: pulsing each motor in turn".into(),
        LearnerPhase::Done if learner.thrust_axis_valid => {
            format!("identified: excitation over after {} ms", learner.excitation_ms)
        }
        LearnerPhase::Done => "excitation over; no hover thrust axis".into(),
        _ => return None,
    })
}
