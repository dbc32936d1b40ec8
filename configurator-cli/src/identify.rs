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
    ConfigStatus, FlightMode, FlightTelemetry, LearnerFailure, LearnerPhase, LearnerTelemetry,
    Reply, Request, SetTelemetryRate, StateTelemetry, Telemetry, Topic,
};
use std::time::{Duration, Instant};

/// Rate of the learner and state topics while identifying, Hz (the whole G1 every 40 ms).
const WATCH_RATE_HZ: u16 = 50;
/// How long the flow waits after the excitation for the board to report flying, s.
const ENGAGE_WAIT_S: f64 = 1.0;
/// One listening slice, ms.
const LISTEN_SLICE: Duration = Duration::from_millis(20);
/// How often the flow asks for the flight's state while the craft holds, wall-clock.
const FLIGHT_POLL: Duration = Duration::from_millis(100);
// A hover, as the simulator's scores define it: body rate below 20 °/s, the thrust axis within
// 10° of its setpoint and the vertical speed below 0.3 m/s, for 0.5 s (defined once, there).
use sim::recovery::{HOVER_CLIMB_MPS, HOVER_HOLD_S, HOVER_RATE_RAD_S, HOVER_TILT_RAD};

/// How the flow runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdentifyOptions {
    /// Disarm when no throw has come this long after arming, s.
    pub throw_timeout_s: f64,
    /// Disarm this long after the craft flies on the learned model (`None`: leave it flying).
    pub disarm_after_s: Option<f64>,
    /// Land this long after the craft flies on the learned model and follow it down to the
    /// touchdown (`crate::land`); before `disarm_after_s` when both are given.
    pub land_after_s: Option<f64>,
    /// How long the landing may take before the flow gives up following it, s.
    pub land_timeout_s: f64,
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
    /// Whether the flow disarmed the board at the end (by a disarm, or by a landing).
    pub disarmed: bool,
    /// How the landing went with `land_after_s` (`None`: no landing).
    pub landing: Option<crate::land::Landing>,
    /// The configuration after the board stored the model (`unsaved_changes` set).
    pub config: Option<ConfigStatus>,
    /// How the flight on the learned model went during `--disarm-after-s` (`None`: not held).
    pub flight: Option<FlightWatch>,
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
    #[error(transparent)]
    Landing(#[from] crate::land::LandError),
}

/// The learner failure in words.
pub fn failure_text(failure: LearnerFailure) -> &'static str {
    match failure {
        LearnerFailure::None => "stopped without a reason",
        LearnerFailure::NotFreeFall => {
            "the craft was not falling freely after the release (still held, or it hit something); the motors never started"
        }
        LearnerFailure::ThrowTimedOut => {
            "a throw began but no release followed within 3 s (still held? An IMU far from the centre of gravity reads a fast spin as a push that never ends: Ω²·r above 20 m/s², 66 mm out at 1,000 °/s; throw with less spin); the motors never started"
        }
        LearnerFailure::RankDeficient => {
            "the motors do not give torque about every axis (a motor not spinning, or not connected?)"
        }
        LearnerFailure::NoHover => "no motor combination can hover this craft along the found axis",
        LearnerFailure::NoThrustAxis => {
            "the excitation ended without a hover thrust axis (throw higher, or check the motors)"
        }
        LearnerFailure::MotorUnusable { .. } => {
            "a motor's model is unusable (its time constant or full speed out of range): check that motor and its ESC"
        }
        LearnerFailure::InvalidModel => "the learned model has non-finite entries",
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
    // A slow link (a radio's byte budget) may have no room left for the state topic: then
    // whether the craft flies is asked (`GetFlight`) instead of streamed.
    let state_streamed = !matches!(
        client.request(&rate(Topic::State, state_hz), "the telemetry rate request")?,
        Reply::TelemetryRate(SetTelemetryRate { rate_hz: 0, .. })
    );
    client.telemetry.clear();
    let result = follow(client, options, state_streamed, say, on_sample);
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
    state_streamed: bool,
    say: &mut dyn FnMut(String),
    on_sample: &mut dyn FnMut(&TelemetrySample),
) -> Result<Identified, IdentifyError> {
    let armed_at = Instant::now();
    let mut phase = LearnerPhase::WaitingForThrow;
    let mut exciting = None;
    let mut blocks: [Option<LearnerTelemetry>; 2] = [None, None];
    let mut state: Option<StateTelemetry> = None;
    let mut done_at: Option<Instant> = None;
    let mut released_us: Option<u64> = None;
    loop {
        client.listen(LISTEN_SLICE)?;
        for event in client.events.drain(..) {
            if let Some(text) = crate::report::flight_event_text(&event) {
                say(text);
            }
        }
        for sample in client.telemetry.drain(..) {
            on_sample(&sample);
            match sample.data {
                Telemetry::State(s) => {
                    if s.phase == LearnerPhase::Released && released_us.is_none() {
                        released_us = Some(s.t_us);
                    }
                    state = Some(s);
                }
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
        let flying = if state_streamed {
            state.is_some_and(|s| s.flying)
        } else {
            matches!(
                client.request(&Request::GetFlight(()), "the flight request"),
                Ok(Reply::Flight(flight)) if flight.mode != protocol::FlightMode::Off
            )
        };
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
        let mut watched = None;
        let mut landing = None;
        let end = match (options.land_after_s, options.disarm_after_s) {
            (Some(hold_s), _) => Some((hold_s, "landing")),
            (None, Some(hold_s)) => Some((hold_s, "disarming")),
            (None, None) => None,
        };
        if let (true, Some((hold_s, then))) = (flying, end) {
            say(format!("holding for {hold_s} s, then {then}"));
            let mut watch = FlightWatch::new(released_us);
            let until = Instant::now() + Duration::from_secs_f64(hold_s);
            while Instant::now() < until {
                let slice = FLIGHT_POLL.min(until.saturating_duration_since(Instant::now()));
                client.listen_with(slice, |sample| on_sample(&sample))?;
                if let Ok(Reply::Flight(flight)) =
                    client.request(&Request::GetFlight(()), "the flight request")
                {
                    watch.add(&flight);
                }
            }
            for line in watch.summary() {
                say(line);
            }
            if options.land_after_s.is_some() {
                let before = crate::land::request_landing(client)?;
                say("landing: descending to the ground".into());
                let timeout_s = options.land_timeout_s;
                let landed =
                    crate::land::follow_landing(client, before, timeout_s, say, on_sample)?;
                say(landed.text().trim_end().to_string());
                landing = Some(landed);
            } else {
                client.request(&Request::Disarm(()), "the disarm request")?;
                say("disarmed: every motor stopped".into());
            }
            disarmed = true;
            watched = Some(watch);
        }
        let config = match client.request(&Request::GetConfig(()), "the configuration request")? {
            Reply::Config(config) => Some(config),
            _ => None,
        };
        return Ok(Identified {
            blocks: [block0, block1],
            flew: flying,
            disarmed,
            landing,
            config,
            flight: watched,
        });
    }
}

/// How the flight on the learned model went, from the board's flight state sampled while it
/// holds: when it reached a hover (in the board's time since the release), and how well it held.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightWatch {
    released_us: Option<u64>,
    /// Since when (board µs) every hover condition has held.
    hovering_since_us: Option<u64>,
    /// When the hover began, s after the release (or after the first sample without a release).
    pub hover_after_s: Option<f64>,
    first_us: Option<u64>,
    /// While hovering: the largest thrust-axis error, rad, body rate, rad/s, and distance from
    /// the position setpoint, m (with an external pose in position hold).
    pub worst_tilt_rad: f32,
    pub worst_rate_rad_s: f32,
    pub worst_position_m: Option<f32>,
    /// The last sample.
    pub last: Option<FlightTelemetry>,
}

impl FlightWatch {
    /// A watch of a flight released at board time `released_us`.
    pub fn new(released_us: Option<u64>) -> Self {
        Self {
            released_us,
            hovering_since_us: None,
            hover_after_s: None,
            first_us: None,
            worst_tilt_rad: 0.0,
            worst_rate_rad_s: 0.0,
            worst_position_m: None,
            last: None,
        }
    }

    /// One sample of the flight's state.
    pub fn add(&mut self, flight: &FlightTelemetry) {
        let first_us = *self.first_us.get_or_insert(flight.t_us);
        let rate = norm(flight.rate_rad_s);
        let climb = flight.velocity_ned_mps.map_or(0.0, |v| v[2].abs());
        let hovering = flight.mode != FlightMode::Off
            && f64::from(rate) < HOVER_RATE_RAD_S
            && f64::from(flight.tilt_error_rad.abs()) < HOVER_TILT_RAD
            && f64::from(climb) < HOVER_CLIMB_MPS;
        if !hovering {
            self.hovering_since_us = None;
        } else {
            let since = *self.hovering_since_us.get_or_insert(flight.t_us);
            let held_s = flight.t_us.saturating_sub(since) as f64 * 1e-6;
            if self.hover_after_s.is_none() && held_s >= HOVER_HOLD_S {
                let from = self.released_us.unwrap_or(first_us);
                self.hover_after_s = Some(since.saturating_sub(from) as f64 * 1e-6);
            }
        }
        if self.hover_after_s.is_some() {
            self.worst_tilt_rad = self.worst_tilt_rad.max(flight.tilt_error_rad.abs());
            self.worst_rate_rad_s = self.worst_rate_rad_s.max(rate);
            if let (FlightMode::PositionHold, Some(p), Some(sp), true) =
                (flight.mode, flight.position_ned_m, flight.position_sp_ned_m, flight.pose_fresh)
            {
                let d = norm([p[0] - sp[0], p[1] - sp[1], p[2] - sp[2]]);
                self.worst_position_m = Some(self.worst_position_m.unwrap_or(0.0).max(d));
            }
        }
        self.last = Some(*flight);
    }

    /// The same as JSON, units in the key names: `hover_after_s` (null: no steady hover),
    /// `worst_tilt_deg`, `worst_rate_deg_s`, `worst_position_m` (null: no position hold),
    /// `last_mode`.
    pub fn json(&self) -> serde_json::Value {
        let deg = 180.0 / core::f32::consts::PI;
        serde_json::json!({
            "hover_after_s": self.hover_after_s,
            "worst_tilt_deg": self.hover_after_s.map(|_| self.worst_tilt_rad * deg),
            "worst_rate_deg_s": self.hover_after_s.map(|_| self.worst_rate_rad_s * deg),
            "worst_position_m": self.worst_position_m,
            "last_mode": self.last.map(|last| format!("{:?}", last.mode)),
        })
    }

    /// What the person reads: how the flight went, with units.
    pub fn summary(&self) -> Vec<String> {
        let deg = 180.0 / core::f32::consts::PI;
        let Some(after_s) = self.hover_after_s else {
            return vec![match &self.last {
                Some(last) => format!(
                    "flight: no steady hover during the hold (at the end: thrust axis {:.1}° from its setpoint, rates {:.0} °/s)",
                    last.tilt_error_rad.abs() * deg,
                    norm(last.rate_rad_s) * deg
                ),
                None => "flight: the board did not report its flight during the hold".into(),
            }];
        };
        let from = if self.released_us.is_some() { "the release" } else { "the flight began" };
        let mut lines = vec![
            format!("flight: recovered to a hover {after_s:.2} s after {from}"),
            format!(
                "  while hovering: thrust axis within {:.1}° of its setpoint, rates below {:.0} °/s",
                self.worst_tilt_rad * deg,
                self.worst_rate_rad_s * deg
            ),
        ];
        lines.push(match self.worst_position_m {
            Some(d) => format!("  position held within {d:.3} m of the setpoint (external pose)"),
            None => "  position not held: no external pose (level hold; the craft drifts)".into(),
        });
        lines
    }
}

fn norm(v: [f32; 3]) -> f32 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
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

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::FailsafeCounters;

    /// The flight at board time `t_s`: body rate `rate_dps`, thrust-axis error `tilt_deg`,
    /// position `x_m` north of a setpoint at the origin.
    fn flight(t_s: f64, rate_dps: f32, tilt_deg: f32, x_m: f32) -> FlightTelemetry {
        FlightTelemetry {
            t_us: (t_s * 1e6) as u64,
            mode: FlightMode::PositionHold,
            q_world_thrust: [1.0, 0.0, 0.0, 0.0],
            euler_zyx_rad: [0.0; 3],
            rate_rad_s: [rate_dps.to_radians(), 0.0, 0.0],
            rate_sp_rad_s: [0.0; 3],
            specific_force_sp_ned_mps2: [0.0, 0.0, -9.81],
            tilt_error_rad: tilt_deg.to_radians(),
            position_sp_ned_m: Some([0.0; 3]),
            position_ned_m: Some([x_m, 0.0, 0.0]),
            velocity_ned_mps: Some([0.0; 3]),
            pose_fresh: true,
            allocation_failures: 0,
            saturated: 0,
            last_failsafe: None,
            failsafes: FailsafeCounters::default(),
        }
    }

    #[test]
    fn the_hover_begins_when_every_condition_has_held_for_half_a_second() {
        // Released at 10 s; tumbling until 11.2 s, a wobble at 11.5 s, steady from 11.6 s.
        let mut watch = FlightWatch::new(Some(10_000_000));
        for k in 0..40 {
            let t = 10.5 + 0.1 * f64::from(k);
            let (rate, tilt) = match t {
                t if t < 11.2 => (300.0, 40.0),
                t if (11.45..11.55).contains(&t) => (30.0, 5.0),
                _ => (5.0, 2.0),
            };
            watch.add(&flight(t, rate, tilt, 0.05));
        }
        let after = watch.hover_after_s.unwrap();
        assert!((after - 1.6).abs() < 1e-6, "hover from 11.6 s: {after}");
        assert!((watch.worst_tilt_rad.to_degrees() - 2.0).abs() < 1e-4);
        assert!((watch.worst_position_m.unwrap() - 0.05).abs() < 1e-6);
        let text = watch.summary().join("\n");
        assert!(text.contains("recovered to a hover 1.60 s after the release"), "{text}");
        assert!(text.contains("within 0.050 m"), "{text}");
    }

    #[test]
    fn a_flight_that_never_settles_says_so_with_its_last_errors() {
        let mut watch = FlightWatch::new(Some(0));
        for k in 0..30 {
            watch.add(&flight(0.1 * f64::from(k), 90.0, 25.0, 1.0));
        }
        assert_eq!(watch.hover_after_s, None);
        let text = watch.summary().join("\n");
        assert!(text.contains("no steady hover"), "{text}");
        assert!(text.contains("25.0°") && text.contains("90 °/s"), "{text}");
    }
}
