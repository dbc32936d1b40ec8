//! `configurator-cli land`: end a flight gently and follow the craft down to its touchdown.
//!
//! A disarm stops the motors at once and drops a flying craft; [`Request::Land`] (protocol 1.14)
//! puts it down instead: a flying craft descends at the `land_descent_mps` parameter, detects its
//! touchdown and disarms; one waiting for a throw, or on the ground, stops at once. The request
//! commands the craft, so [`Client::request`] signs it over a paired radio like any other.
//!
//! [`follow_landing`] then asks for the flight's state ten times a second and says once a second
//! how far the craft has come down and how fast, until the board reports itself disarmed: with
//! the touchdown speed from its `Landed` event, or as merely stopped when no touchdown was
//! reported (nothing was flying, or the event was lost). `identify --land-after-s` ends its
//! flight through the same two steps.

use crate::link::{Client, LinkError, TelemetrySample};
use crate::report::{flight_event_text, land_reason_text};
use protocol::{Event, FlightMode, FlightTelemetry, LandReason, Reply, Request};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

/// How long `land` follows a landing by default, s.
pub const DEFAULT_TIMEOUT_S: f64 = 120.0;
/// How often the flight's state is asked for while landing (wall-clock).
const POLL: Duration = Duration::from_millis(100);
/// How often the person reads the progress (wall-clock).
const PROGRESS_EVERY: Duration = Duration::from_secs(1);
/// How long after the board reports itself disarmed its `Landed` event may still be on its way
/// (the event and the answer leave in the same link pass, in either order).
const LATE_EVENT_WAIT: Duration = Duration::from_millis(300);

/// The craft's state when the land request was sent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeforeLanding {
    pub armed: bool,
    pub mode: FlightMode,
}

impl BeforeLanding {
    fn flying(&self) -> bool {
        self.mode != FlightMode::Off
    }
}

/// How a landing ended: the board reported itself disarmed.
#[derive(Debug, Clone, PartialEq)]
pub struct Landing {
    pub before: BeforeLanding,
    /// Why the board landed (its events or flight mode); `None`: it never reported a landing.
    pub reason: Option<LandReason>,
    /// The descent speed at the touchdown, m/s, positive down (the board's `Landed` event);
    /// `None`: the motors stopped without a reported touchdown.
    pub touchdown_speed_mps: Option<f32>,
    /// How far the craft came down while landing, m.
    pub descent: Descent,
    /// From the request to the disarm, s (wall-clock).
    pub took_s: f64,
}

/// Why following a landing ended without the board disarmed.
#[derive(Debug, thiserror::Error)]
pub enum LandError {
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error(
        "the board is still armed {timeout_s} s after the land request (flight mode {mode:?}); \
         the landing goes on: `configurator-cli disarm` stops the motors at once"
    )]
    TimedOut { timeout_s: f64, mode: FlightMode },
}

/// Read the craft's state, then send [`Request::Land`] (events already received are dropped,
/// so those that follow are this landing's).
pub fn request_landing(client: &mut Client) -> Result<BeforeLanding, LinkError> {
    let armed = match client.request(&Request::GetStatus(()), "the status request")? {
        Reply::Status(status) => status.armed,
        other => return Err(LinkError::Unexpected(format!("{other:?} to the status request"))),
    };
    let mode = fetch_flight(client)?.mode;
    client.events.clear();
    client.request(&Request::Land(()), "the land request")?;
    Ok(BeforeLanding { armed, mode })
}

fn fetch_flight(client: &mut Client) -> Result<FlightTelemetry, LinkError> {
    match client.request(&Request::GetFlight(()), "the flight request")? {
        Reply::Flight(flight) => Ok(flight),
        other => Err(LinkError::Unexpected(format!("{other:?} to the flight request"))),
    }
}

/// Follow the landing asked for ([`request_landing`]) until the board reports itself disarmed,
/// at most `timeout_s`; `say` prints the progress and the board's failsafe and landing events,
/// and every telemetry sample streamed meanwhile goes to `on_sample` (a recording).
pub fn follow_landing(
    client: &mut Client,
    before: BeforeLanding,
    timeout_s: f64,
    say: &mut dyn FnMut(String),
    on_sample: &mut dyn FnMut(&TelemetrySample),
) -> Result<Landing, LandError> {
    let started = Instant::now();
    let deadline = started + Duration::from_secs_f64(timeout_s);
    let mut descent = Descent::default();
    let mut reason = None;
    let mut touchdown_speed_mps = None;
    let mut landing_seen = before.flying();
    let mut next_progress = started + PROGRESS_EVERY;
    let mut disarmed_at: Option<Instant> = None;
    loop {
        client.listen_with(POLL, |sample| on_sample(&sample))?;
        for event in client.events.drain(..) {
            if let Some(text) = flight_event_text(&event) {
                say(text);
            }
            match event {
                Event::Landing { reason: why, .. } => {
                    reason.get_or_insert(why);
                    landing_seen = true;
                }
                Event::Landed { reason: why, touchdown_speed_mps: speed_mps, .. } => {
                    reason = Some(why);
                    touchdown_speed_mps = Some(speed_mps);
                }
                _ => {}
            }
        }
        if let Some(at) = disarmed_at {
            if touchdown_speed_mps.is_some() || !landing_seen || at.elapsed() >= LATE_EVENT_WAIT {
                let took_s = at.duration_since(started).as_secs_f64();
                return Ok(Landing { before, reason, touchdown_speed_mps, descent, took_s });
            }
            continue;
        }
        let flight = fetch_flight(client)?;
        if let FlightMode::Landing(why) = flight.mode {
            reason.get_or_insert(why);
            landing_seen = true;
            descent.add(&flight);
            if Instant::now() >= next_progress {
                say(descent.progress_text());
                next_progress += PROGRESS_EVERY;
            }
        }
        if flight.mode == FlightMode::Off {
            let armed = match client.request(&Request::GetStatus(()), "the status request")? {
                Reply::Status(status) => status.armed,
                other => {
                    let text = format!("{other:?} to the status request");
                    return Err(LinkError::Unexpected(text).into());
                }
            };
            if !armed {
                disarmed_at = Some(Instant::now());
                continue;
            }
        }
        if Instant::now() >= deadline {
            return Err(LandError::TimedOut { timeout_s, mode: flight.mode });
        }
    }
}

/// How far a landing craft has come down, from the board's flight state while it lands: the
/// positions when a pose is fresh, else its vertical velocity integrated over the board's time.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Descent {
    /// Down since the landing began, m (negative: it climbed).
    pub descended_m: f32,
    /// The latest vertical speed, m/s, positive down (`None`: not known).
    pub descent_speed_mps: Option<f32>,
    /// The latest sample: board time, µs, and the position down when fresh, m.
    last: Option<(u64, Option<f32>)>,
}

impl Descent {
    /// One sample of the flight's state while landing.
    pub fn add(&mut self, flight: &FlightTelemetry) {
        let speed_mps = flight.velocity_ned_mps.map(|v| v[2]);
        let down_m = flight.position_ned_m.filter(|_| flight.pose_fresh).map(|p| p[2]);
        if let Some((t_us, last_down_m)) = self.last {
            self.descended_m += match (last_down_m, down_m) {
                (Some(from_m), Some(to_m)) => to_m - from_m,
                _ => {
                    let dt_s = flight.t_us.saturating_sub(t_us) as f32 * 1e-6;
                    speed_mps.unwrap_or(0.0) * dt_s
                }
            };
        }
        self.descent_speed_mps = speed_mps;
        self.last = Some((flight.t_us, down_m));
    }

    /// The progress line: e.g. "landing: 1.8 m below where the descent began, descending at
    /// 0.49 m/s".
    pub fn progress_text(&self) -> String {
        let speed = match self.descent_speed_mps {
            Some(v) if v >= 0.0 => format!("descending at {v:.2} m/s"),
            Some(v) => format!("climbing at {:.2} m/s", -v),
            None => "vertical speed unknown".into(),
        };
        format!("landing: {:.1} m below where the descent began, {speed}", self.descended_m)
    }
}

impl Landing {
    /// What the person reads.
    pub fn text(&self) -> String {
        let why = self.reason.map(|r| format!(" ({})", land_reason_text(r))).unwrap_or_default();
        match self.touchdown_speed_mps {
            Some(speed_mps) => format!(
                "landed{why}: touched down at {speed_mps:.2} m/s after descending {:.1} m, every \
                 motor stopped ({:.1} s)\n",
                self.descent.descended_m, self.took_s
            ),
            None if self.reason.is_some() || self.before.flying() => format!(
                "stopped{why}: the board disarmed without reporting a touchdown (came down \
                 {:.1} m)\n",
                self.descent.descended_m
            ),
            None if self.before.armed => "motors stopped: nothing was flying\n".into(),
            None => "nothing was armed or flying: the motors were already stopped\n".into(),
        }
    }

    /// The same as JSON, units in the key names.
    pub fn json(&self) -> Value {
        json!({
            "was_armed": self.before.armed,
            "was_flying": self.before.flying(),
            "reason": self.reason.map(|r| format!("{r:?}")),
            "landed": self.touchdown_speed_mps.is_some(),
            "touchdown_speed_mps": self.touchdown_speed_mps,
            "descended_m": self.descent.descended_m,
            "disarmed": true,
            "took_s": self.took_s,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::FailsafeCounters;

    /// The flight at board time `t_s`, landing: vertical speed `vz_mps`, position down `z_m`
    /// when given (a fresh pose).
    fn landing(t_s: f64, vz_mps: f32, z_m: Option<f32>) -> FlightTelemetry {
        FlightTelemetry {
            t_us: (t_s * 1e6) as u64,
            mode: FlightMode::Landing(LandReason::Commanded),
            q_world_thrust: [1.0, 0.0, 0.0, 0.0],
            euler_zyx_rad: [0.0; 3],
            rate_rad_s: [0.0; 3],
            rate_sp_rad_s: [0.0; 3],
            specific_force_sp_ned_mps2: [0.0, 0.0, -9.81],
            tilt_error_rad: 0.0,
            position_sp_ned_m: None,
            position_ned_m: z_m.map(|z| [0.0, 0.0, z]),
            velocity_ned_mps: Some([0.0, 0.0, vz_mps]),
            pose_fresh: z_m.is_some(),
            allocation_failures: 0,
            saturated: 0,
            last_failsafe: None,
            failsafes: FailsafeCounters::default(),
        }
    }

    #[test]
    fn without_a_pose_the_descent_is_the_vertical_speed_integrated_over_board_time() {
        let mut descent = Descent::default();
        // 0.5 m/s down for 3 s, sampled every 0.1 s.
        for k in 0..=30 {
            descent.add(&landing(10.0 + 0.1 * f64::from(k), 0.5, None));
        }
        assert!((descent.descended_m - 1.5).abs() < 1e-3, "{descent:?}");
        let text = descent.progress_text();
        assert!(text.contains("1.5 m below") && text.contains("descending at 0.50 m/s"), "{text}");
    }

    #[test]
    fn with_a_fresh_pose_the_descent_is_the_change_of_position() {
        let mut descent = Descent::default();
        descent.add(&landing(0.0, 0.0, Some(-2.0)));
        descent.add(&landing(1.0, 0.4, Some(-1.2)));
        assert!((descent.descended_m - 0.8).abs() < 1e-5, "{descent:?}");
    }

    #[test]
    fn a_landing_reads_as_its_touchdown_or_as_a_stop() {
        let flying = BeforeLanding { armed: true, mode: FlightMode::LevelHold };
        let landed = Landing {
            before: flying,
            reason: Some(LandReason::Commanded),
            touchdown_speed_mps: Some(0.43),
            descent: Descent { descended_m: 2.26, ..Descent::default() },
            took_s: 5.0,
        };
        let text = landed.text();
        assert!(text.contains("touched down at 0.43 m/s") && text.contains("2.3 m"), "{text}");
        assert_eq!(landed.json()["touchdown_speed_mps"].as_f64().unwrap() as f32, 0.43);
        let waiting = BeforeLanding { armed: true, mode: FlightMode::Off };
        let stopped =
            Landing { before: waiting, reason: None, touchdown_speed_mps: None, ..landed };
        assert_eq!(stopped.text(), "motors stopped: nothing was flying\n");
        assert_eq!(stopped.json()["landed"], false);
    }
}
