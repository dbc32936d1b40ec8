//! The pilot's radio, simulated: a CRSF transmitter and receiver pair whose RC-channel frames
//! reach the application's control tick through the same byte path as the board's UART
//! ([`Uart`]), so the real parser, switch mapping and receiver policy
//! ([`firmware::app::radio`]) decide what the craft does.
//!
//! The switches are the default mapping's ([`RcLinkConfig::default`]: arm on channel 5,
//! throw-to-fly on 6, kill on 7, land on 8, the mode switch on 9 (low: angle mode), on at
//! 2,000 µs and off at 1,000 µs; the sticks AETR on 1–4, centred). A [`RcScript`] flips them,
//! moves the sticks, and takes the signal away and gives it back, at given simulated times:
//! `sitl --rc "1:arm,1:throw,6:pitch=0.3,7:pitch=0,9:position,20:land"`.
//!
//! The handset side decodes the telemetry the flight controller sends back (attitude, flight
//! mode, battery: [`RcTransmitter::telemetry`], [`RcTransmitter::flight_modes`]), as a pilot's
//! handset shows it.
//!
//! What it models of a real link: frames at a fixed rate ([`DEFAULT_RC_RATE_HZ`], Crossfire's
//! 150 Hz; ExpressLRS sends 50–1,000 Hz), each frame's bytes delivered at once at the first
//! control tick at or after its time (the 26 bytes take 0.6 ms at 420 kbaud, about one tick),
//! and a lost link as no frames at all (what a CRSF receiver does when its link drops and no
//! failsafe positions are set).

use std::collections::VecDeque;

use firmware::app::hal::Uart;
use firmware::drivers::crsf::{
    encode_frame, HandsetTelemetry, RcChannels, RcLinkConfig, CHANNEL_COUNT, CHANNEL_RAW_MID,
    FRAME_MAX, SYNC_FLIGHT_CONTROLLER, TYPE_RC_CHANNELS_PACKED,
};

/// RC frames per second by default, Hz (TBS Crossfire's rate).
pub const DEFAULT_RC_RATE_HZ: f64 = 150.0;
/// Pulse width of a switch that is on, µs.
const SWITCH_ON_US: f32 = 2_000.0;
/// Pulse width of a switch that is off, µs.
const SWITCH_OFF_US: f32 = 1_000.0;

/// A stick of the pilot's radio.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stick {
    Roll,
    Pitch,
    Throttle,
    Yaw,
}

impl Stick {
    const ALL: [Stick; 4] = [Stick::Roll, Stick::Pitch, Stick::Throttle, Stick::Yaw];

    /// The stick's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Stick::Roll => "roll",
            Stick::Pitch => "pitch",
            Stick::Throttle => "throttle",
            Stick::Yaw => "yaw",
        }
    }
}

/// What the pilot does to the radio.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RcEvent {
    /// The land switch on (`land`) or off (`land-off`).
    Land(bool),
    /// The mode switch to position mode (`position`) or angle mode (`angle`).
    PositionMode(bool),
    /// A stick to a position, −1..1 (`pitch=0.3`: forward 30 % of its travel).
    Stick(Stick, f32),
    /// The arm switch on (`arm`) or off (`disarm`).
    Arm(bool),
    /// The throw-to-fly switch on (`throw`) or off (`throw-off`).
    ThrowToFly(bool),
    /// The kill switch on (`kill`) or off (`kill-off`).
    Kill(bool),
    /// The link comes back (`restore`) or is lost (`lose`).
    Signal(bool),
}

impl RcEvent {
    /// The event's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Arm(true) => "arm",
            Self::Arm(false) => "disarm",
            Self::ThrowToFly(true) => "throw",
            Self::ThrowToFly(false) => "throw-off",
            Self::Kill(true) => "kill",
            Self::Kill(false) => "kill-off",
            Self::Signal(true) => "restore",
            Self::Signal(false) => "lose",
            Self::Land(true) => "land",
            Self::Land(false) => "land-off",
            Self::PositionMode(true) => "position",
            Self::PositionMode(false) => "angle",
            Self::Stick(stick, _) => stick.name(),
        }
    }

    fn parse(text: &str) -> Option<Self> {
        if let Some((name, value)) = text.split_once('=') {
            let stick = Stick::ALL.into_iter().find(|s| s.name() == name.trim())?;
            let value: f32 = value.trim().parse().ok()?;
            return (value.is_finite() && (-1.0..=1.0).contains(&value))
                .then_some(Self::Stick(stick, value));
        }
        [
            Self::Land(true),
            Self::Land(false),
            Self::PositionMode(true),
            Self::PositionMode(false),
            Self::Arm(true),
            Self::Arm(false),
            Self::ThrowToFly(true),
            Self::ThrowToFly(false),
            Self::Kill(true),
            Self::Kill(false),
            Self::Signal(true),
            Self::Signal(false),
        ]
        .into_iter()
        .find(|event| event.name() == text)
    }
}

/// What the pilot does, when: events at simulated times, s, in time order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RcScript {
    pub events: Vec<(f64, RcEvent)>,
}

impl RcScript {
    /// Parses `T:EVENT,T:EVENT,...` (T in simulated seconds, finite and ≥ 0; EVENT one of `arm`,
    /// `disarm`, `throw`, `throw-off`, `kill`, `kill-off`, `land`, `land-off`, `position`,
    /// `angle`, `lose`, `restore`, or a stick's position `roll=X`, `pitch=X`, `throttle=X`,
    /// `yaw=X` with X in −1..1); the events are sorted by time (equal times keep their order).
    /// An empty text is an empty script.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut events = Vec::new();
        for item in text.split(',').map(str::trim).filter(|item| !item.is_empty()) {
            let (time, name) = item
                .split_once(':')
                .ok_or_else(|| format!("`{item}`: expected TIME_S:EVENT, e.g. 1.5:arm"))?;
            let time_s: f64 = time
                .trim()
                .parse()
                .map_err(|_| format!("`{item}`: `{time}` is not a time in s"))?;
            if !time_s.is_finite() || time_s < 0.0 {
                return Err(format!("`{item}`: the time must be finite and at least 0 s"));
            }
            let event = RcEvent::parse(name.trim()).ok_or_else(|| {
                format!(
                    "`{item}`: unknown event `{name}` (arm, disarm, throw, throw-off, kill, \
                     kill-off, land, land-off, position, angle, lose, restore, or roll=X, \
                     pitch=X, throttle=X, yaw=X with X in -1..1)"
                )
            })?;
            events.push((time_s, event));
        }
        events.sort_by(|a, b| a.0.total_cmp(&b.0));
        Ok(Self { events })
    }
}

/// The simulated transmitter and receiver: the switches, the link, the frames on their way.
#[derive(Clone, Debug)]
pub struct RcTransmitter {
    config: RcLinkConfig,
    arm: bool,
    throw_to_fly: bool,
    kill: bool,
    land: bool,
    position_mode: bool,
    /// Roll, pitch, throttle, yaw, −1..1.
    sticks: [f32; 4],
    signal: bool,
    frame_period_us: u64,
    next_frame_us: u64,
    script: VecDeque<(u64, RcEvent)>,
    pending: VecDeque<u8>,
    frames_sent: u64,
    /// Bytes the flight controller sent towards the handset, not yet a whole frame.
    downlink: Vec<u8>,
    /// The telemetry frames the handset received, decoded, in order.
    telemetry: Vec<HandsetTelemetry>,
    /// Telemetry frames that did not decode (length, CRC, layout).
    telemetry_errors: u64,
}

impl RcTransmitter {
    /// A transmitter with every switch off and the link up, sending `rate_hz` frames per second
    /// (clamped to 1–1,000 Hz) from time 0, then playing `script`.
    pub fn new(rate_hz: f64, script: &RcScript) -> Self {
        let rate_hz = if rate_hz.is_finite() { rate_hz.clamp(1.0, 1_000.0) } else { 150.0 };
        Self {
            config: RcLinkConfig::default(),
            arm: false,
            throw_to_fly: false,
            kill: false,
            land: false,
            position_mode: false,
            sticks: [0.0; 4],
            signal: true,
            frame_period_us: (1e6 / rate_hz).round() as u64,
            next_frame_us: 0,
            script: script.events.iter().map(|&(t, e)| ((t * 1e6).round() as u64, e)).collect(),
            pending: VecDeque::new(),
            frames_sent: 0,
            downlink: Vec::new(),
            telemetry: Vec::new(),
            telemetry_errors: 0,
        }
    }

    /// Apply `event` now.
    pub fn apply(&mut self, event: RcEvent) {
        match event {
            RcEvent::Arm(on) => self.arm = on,
            RcEvent::ThrowToFly(on) => self.throw_to_fly = on,
            RcEvent::Kill(on) => self.kill = on,
            RcEvent::Signal(on) => self.signal = on,
            RcEvent::Land(on) => self.land = on,
            RcEvent::PositionMode(on) => self.position_mode = on,
            RcEvent::Stick(stick, value) => self.sticks[stick as usize] = value,
        }
    }

    /// Advance to `now_us` (simulated time, µs): the script's events that are due, then the
    /// frames due by now (none while the link is lost), queued for the next read.
    pub fn advance(&mut self, now_us: u64) {
        while self.next_frame_us <= now_us {
            let frame_us = self.next_frame_us;
            while let Some(&(at_us, event)) = self.script.front() {
                if at_us > frame_us {
                    break;
                }
                self.apply(event);
                self.script.pop_front();
            }
            if self.signal {
                self.queue_frame();
            }
            self.next_frame_us += self.frame_period_us;
        }
        while let Some(&(at_us, event)) = self.script.front() {
            if at_us > now_us {
                break;
            }
            self.apply(event);
            self.script.pop_front();
        }
    }

    /// The telemetry frames the handset received, decoded, in order.
    pub fn telemetry(&self) -> &[HandsetTelemetry] {
        &self.telemetry
    }

    /// Telemetry frames that did not decode.
    pub fn telemetry_errors(&self) -> u64 {
        self.telemetry_errors
    }

    /// The flight-mode words the handset showed, each change once, in order.
    pub fn flight_modes(&self) -> Vec<String> {
        let mut modes: Vec<String> = Vec::new();
        for frame in &self.telemetry {
            if let HandsetTelemetry::FlightMode(words) = frame {
                if modes.last().map(String::as_str) != Some(words.as_str()) {
                    modes.push(words.as_str().to_owned());
                }
            }
        }
        modes
    }

    /// RC frames sent so far.
    pub fn frames_sent(&self) -> u64 {
        self.frames_sent
    }

    fn queue_frame(&mut self) {
        let mut raw = [CHANNEL_RAW_MID; CHANNEL_COUNT];
        let us = |on: bool| RcChannels::raw_from_us(if on { SWITCH_ON_US } else { SWITCH_OFF_US });
        raw[self.config.arm.channel] = us(self.arm);
        raw[self.config.throw_to_fly.channel] = us(self.throw_to_fly);
        raw[self.config.kill.channel] = us(self.kill);
        raw[self.config.land.channel] = us(self.land);
        raw[self.config.mode.channel] = us(self.position_mode);
        let map = self.config.sticks;
        for (channel, value) in
            [map.roll, map.pitch, map.throttle, map.yaw].into_iter().zip(self.sticks)
        {
            // 1500 µs centred, ±512 µs of travel (988–2012 µs, a CRSF handset's full range).
            raw[usize::from(channel)] = RcChannels::raw_from_us(1_500.0 + 512.0 * value);
        }
        let payload = RcChannels { raw }.pack();
        let mut frame = [0u8; FRAME_MAX];
        if let Some(n) =
            encode_frame(SYNC_FLIGHT_CONTROLLER, TYPE_RC_CHANNELS_PACKED, &payload, &mut frame)
        {
            self.pending.extend(&frame[..n]);
            self.frames_sent += 1;
        }
    }
}

impl Uart for RcTransmitter {
    fn read(&mut self, buffer: &mut [u8]) -> usize {
        let n = buffer.len().min(self.pending.len());
        for (dst, src) in buffer.iter_mut().zip(self.pending.drain(..n)) {
            *dst = src;
        }
        n
    }

    /// The flight controller's telemetry on its way to the handset: split into frames at the
    /// length byte and decoded as a handset would.
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.downlink.extend_from_slice(bytes);
        while self.downlink.len() >= 2 {
            let total = usize::from(self.downlink[1]) + 2;
            if self.downlink[0] != SYNC_FLIGHT_CONTROLLER || !(4..=FRAME_MAX).contains(&total) {
                self.telemetry_errors += 1;
                self.downlink.remove(0);
                continue;
            }
            if self.downlink.len() < total {
                break;
            }
            match HandsetTelemetry::decode(&self.downlink[..total]) {
                Ok(frame) => self.telemetry.push(frame),
                Err(_) => self.telemetry_errors += 1,
            }
            self.downlink.drain(..total);
        }
        bytes.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::app::radio::{CraftState, Receiver};
    use firmware::app::ControlCommand;

    #[test]
    fn scripts_parse_in_seconds_and_bad_ones_say_why() {
        let script = RcScript::parse("6:kill, 1:arm,1:throw ,2.5:lose").unwrap();
        assert_eq!(
            script.events,
            vec![
                (1.0, RcEvent::Arm(true)),
                (1.0, RcEvent::ThrowToFly(true)),
                (2.5, RcEvent::Signal(false)),
                (6.0, RcEvent::Kill(true)),
            ]
        );
        assert_eq!(RcScript::parse("").unwrap().events, vec![]);
        for (bad, says) in [
            ("1arm", "TIME_S:EVENT"),
            ("x:arm", "not a time"),
            ("-1:arm", "at least 0"),
            ("nan:arm", "finite"),
            ("1:fly", "unknown event `fly`"),
            ("1:pitch=1.5", "unknown event `pitch=1.5`"),
            ("1:wobble=0.2", "unknown event"),
        ] {
            let error = RcScript::parse(bad).unwrap_err();
            assert!(error.contains(says), "`{bad}`: {error}");
        }
    }

    #[test]
    fn the_sticks_and_the_land_and_mode_switches_reach_the_receiver() {
        let script = RcScript::parse("0:pitch=0.5,0:roll=-1,0:position,0.1:arm,0.2:land").unwrap();
        assert_eq!(script.events[0], (0.0, RcEvent::Stick(Stick::Pitch, 0.5)));
        let mut radio = RcTransmitter::new(150.0, &script);
        let mut receiver = Receiver::new(RcLinkConfig::default()).unwrap();
        let flying = CraftState { armed: true, in_flight: true };
        let mut chunk = [0u8; 256];
        let (mut sticks, mut landed) = (None, false);
        for tick in 0..600u64 {
            let now_us = tick * 500;
            radio.advance(now_us);
            let n = radio.read(&mut chunk);
            let command = receiver.poll(&chunk[..n], now_us, flying);
            landed |= command == Some(ControlCommand::Land(protocol::LandReason::Switch));
            if let Some(ControlCommand::Sticks(Some(input))) = receiver.take_sticks(now_us) {
                sticks = Some(input);
            }
        }
        let sticks = sticks.expect("sticks");
        assert!((sticks.pitch - 0.5).abs() < 0.01, "{sticks:?}");
        assert!((sticks.roll + 1.0).abs() < 0.01, "{sticks:?}");
        assert!(sticks.throttle.abs() < 0.01 && sticks.position_mode, "{sticks:?}");
        assert!(landed, "the land switch with the arm switch on lands");
    }

    #[test]
    fn the_switches_reach_the_receiver_policy_at_the_frame_rate() {
        let script = RcScript::parse("0.1:arm,0.1:throw,0.3:lose").unwrap();
        let mut radio = RcTransmitter::new(150.0, &script);
        let mut receiver = Receiver::new(RcLinkConfig::default()).unwrap();
        let idle = CraftState { armed: false, in_flight: false };
        let mut chunk = [0u8; 256];
        let mut armed_at_us = None;
        for tick in 0..1_000u64 {
            let now_us = tick * 500;
            radio.advance(now_us);
            let n = radio.read(&mut chunk);
            let command = receiver.poll(&chunk[..n], now_us, idle);
            if command == Some(ControlCommand::ArmThrowToFly) && armed_at_us.is_none() {
                armed_at_us = Some(now_us);
            }
        }
        // Switches off at start-up (the interlock clears), on at 0.1 s: the arm arrives with the
        // first frame after 0.1 s (150 Hz: within 6.7 ms).
        let armed_at_us = armed_at_us.expect("armed by the switches");
        assert!((100_000..=106_700).contains(&armed_at_us), "armed at {armed_at_us} µs");
        // 0.3 s of frames at 150 Hz, then none: the link counts as down 250 ms after the last
        // one (at 293 ms).
        assert_eq!(radio.frames_sent(), 45);
        assert!(receiver.health(540_000).link_up);
        assert!(!receiver.health(546_000).link_up);
        assert_eq!(
            (receiver.health(546_000).frames, receiver.health(546_000).frame_errors),
            (45, 0)
        );
    }
}
