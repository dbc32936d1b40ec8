//! The pilot's radio as the control step sees it: CRSF bytes in, at most one
//! [`ControlCommand`] out per control step, and the [`ReceiverHealth`] for the status.
//!
//! The board drains the UART's receive buffer at the start of every control step and hands the
//! bytes to [`Receiver::poll`] together with the state of the previous step; the command it
//! returns is applied before the step runs, so a kill switch disarms within one control step
//! (500 µs at 2 kHz) of its frame's last byte arriving in the buffer.
//!
//! The policy is the application's (it decides what the craft does), the parsing and the switch
//! mapping are the CRSF driver's ([`crate::drivers::crsf`]); the board only moves the bytes.
//!
//! # Switches (the mapping of [`RcLink`], channels 5/6/7 by default)
//! - Kill on: [`ControlCommand::Failsafe`]`(`[`Failsafe::Kill`]`)` on every step while anything is
//!   armed, whatever the other switches say: the craft disarms and the failsafe is counted and
//!   reported. Turning it off again arms nothing until the arm switch has been cycled.
//! - Arm and throw-to-fly on: [`ControlCommand::ArmThrowToFly`], once, on the step the request
//!   first appears, and only after the receiver has seen the arm switch off since start-up or
//!   since its last failsafe (a craft never arms because it powered up with the switch on).
//! - Arm switch turned off (after arm on): [`ControlCommand::Disarm`], once.
//! - Land switch on (channel 8 by default, with the arm switch on):
//!   [`ControlCommand::Land`]`(`[`LandReason::Switch`]`)`, once, on the step it first appears:
//!   a flying craft lands, one waiting for a throw disarms. Turning it off does not stop the
//!   landing (the touchdown or the kill switch does); cycling it again asks again.
//!
//! # Signal loss (no valid RC frame for 250 ms, [`crate::drivers::crsf::DEFAULT_FAILSAFE_TIMEOUT_US`])
//! - On the ground (armed and waiting for or being thrown):
//!   [`ControlCommand::Failsafe`]`(`[`Failsafe::RcLost`]`)` at once.
//! - In flight (released, exciting the motors, or the controller flying): the craft keeps doing
//!   what it does (the learner's schedule and then the hover controller need no stick input) for
//!   [`FLIGHT_FAILSAFE_GRACE_US`]; if no valid frame returned by then,
//!   [`ControlCommand::Land`]`(`[`LandReason::RcLost`]`)`, once: the craft lands (Betaflight's
//!   stage-2 failsafe, PX4's and ArduPilot's radio failsafes descend or land too), counted as
//!   the [`Failsafe::RcLost`] failsafe. A link that comes back within the grace cancels it; one
//!   that comes back later does not stop the landing; after a loss, re-arming needs the arm
//!   switch cycled.
//!
//! What this assumes of the radio: a receiver that stops sending RC frames when its link is lost
//! (CRSF receivers do, or send frames with the failsafe positions a pilot set to "arm off"); a
//! frame rate of at least 4 per 250 ms (ExpressLRS and Crossfire send 50–1000 Hz).
//!
//! A receiver that has never delivered a valid RC frame since start-up is treated as absent: it
//! commands nothing, so the board can be armed over USB without a radio (bench, SITL-like use).

use super::pilot::Failsafe;
use super::{ControlCommand, ControlSnapshot};
use crate::drivers::crsf::{
    CrsfFrame, CrsfParser, LinkStatistics, PilotRequest, RcConfigError, RcLink, RcLinkConfig,
    StickInput, StickMap,
};
use crate::drivers::crsf::{HandsetTelemetry, FLIGHT_MODE_MAX_LEN};
use flight::learner::FlightPhase;
use protocol::{LandReason, ReceiverHealth};

/// How long a craft in flight keeps flying after the radio link is lost, µs.
pub const FLIGHT_FAILSAFE_GRACE_US: u64 = 1_000_000;

/// What the control step was doing at its previous step (from its snapshot).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CraftState {
    /// Anything armed (throw detector, flight, motor test).
    pub armed: bool,
    /// In the air: released from the hand, exciting, or flying on the controller.
    pub in_flight: bool,
}

/// The receiver: parser, switch mapping, failsafe policy, counters.
#[derive(Debug, Clone)]
pub struct Receiver {
    parser: CrsfParser,
    link: RcLink,
    statistics: Option<LinkStatistics>,
    /// A valid RC frame has arrived since start-up.
    present: bool,
    /// The arm switch was seen off since start-up or the last failsafe: arming is allowed.
    interlock_clear: bool,
    previous: PilotRequest,
    /// When the failsafe began in flight, µs.
    failsafe_since_us: Option<u64>,
    /// The landing for this loss of the link was asked for.
    rc_lost_landing: bool,
    /// An RC frame arrived since the last telemetry frame: the receiver granted a slot.
    telemetry_slot: bool,
    /// The handset's telemetry cycle.
    handset: HandsetCycle,
    /// The sticks last handed to the control step.
    sticks_sent: Option<StickInput>,
}

impl Receiver {
    /// A receiver with the given switch mapping.
    pub fn new(config: RcLinkConfig) -> Result<Self, RcConfigError> {
        Ok(Self {
            parser: CrsfParser::new(),
            link: RcLink::new(config)?,
            statistics: None,
            present: false,
            interlock_clear: false,
            previous: PilotRequest::Failsafe,
            failsafe_since_us: None,
            rc_lost_landing: false,
            telemetry_slot: false,
            handset: HandsetCycle::default(),
            sticks_sent: None,
        })
    }

    /// Take the stick and mode-switch channels in force (`rc_map`, `rc_mode_channel`).
    pub fn set_stick_channels(&mut self, sticks: StickMap, mode_channel: u8) {
        self.link.set_stick_channels(sticks, mode_channel);
    }

    /// The pilot's sticks for the control step, when they changed since the last call
    /// ([`ControlCommand::Sticks`]; `None` inside once the link is lost). Called after
    /// [`Receiver::poll`] in the same tick.
    pub fn take_sticks(&mut self, now_us: u64) -> Option<ControlCommand> {
        let sticks = if self.present { self.link.sticks(now_us) } else { None };
        (sticks != self.sticks_sent).then(|| {
            self.sticks_sent = sticks;
            ControlCommand::Sticks(sticks)
        })
    }

    /// Feed the bytes received since the last call, then decide. Never blocks, never allocates.
    pub fn poll(&mut self, bytes: &[u8], now_us: u64, craft: CraftState) -> Option<ControlCommand> {
        for &byte in bytes {
            self.push(byte, now_us);
        }
        self.decide(now_us, craft)
    }

    fn push(&mut self, byte: u8, now_us: u64) {
        // One byte can complete several events (a failed candidate, then a good frame found
        // while resynchronising): take them all now, so none waits for the next byte.
        let mut event = self.parser.push(byte);
        while let Some(result) = event {
            match result {
                Ok(CrsfFrame::RcChannels(channels)) => {
                    self.link.on_channels(&channels, now_us);
                    self.present = true;
                    self.telemetry_slot = true;
                }
                Ok(CrsfFrame::LinkStatistics(statistics)) => self.statistics = Some(statistics),
                // Counted by the parser.
                Err(_) => {}
            }
            event = self.parser.next_event();
        }
    }

    fn decide(&mut self, now_us: u64, craft: CraftState) -> Option<ControlCommand> {
        if !self.present {
            return None;
        }
        let request = self.link.request(now_us);
        let previous = core::mem::replace(&mut self.previous, request);
        if request != PilotRequest::Failsafe {
            self.failsafe_since_us = None;
            self.rc_lost_landing = false;
        }
        match request {
            PilotRequest::Kill => {
                // Turning the kill switch off again must not re-arm a craft whose arm and
                // throw-to-fly switches are still on: the arm switch has to be cycled.
                self.interlock_clear = false;
                craft.armed.then_some(ControlCommand::Failsafe(Failsafe::Kill))
            }
            PilotRequest::Disarmed => {
                self.interlock_clear = true;
                let was_armed = matches!(
                    previous,
                    PilotRequest::Armed | PilotRequest::ThrowToFly | PilotRequest::Land
                );
                (craft.armed && was_armed).then_some(ControlCommand::Disarm)
            }
            PilotRequest::Armed => None,
            PilotRequest::Land => (craft.armed && previous != PilotRequest::Land)
                .then_some(ControlCommand::Land(LandReason::Switch)),
            PilotRequest::ThrowToFly => {
                (self.interlock_clear && previous != PilotRequest::ThrowToFly && !craft.armed)
                    .then_some(ControlCommand::ArmThrowToFly)
            }
            PilotRequest::Failsafe => {
                self.interlock_clear = false;
                if !craft.armed {
                    self.failsafe_since_us = None;
                    return None;
                }
                if !craft.in_flight {
                    return Some(ControlCommand::Failsafe(Failsafe::RcLost));
                }
                let since = *self.failsafe_since_us.get_or_insert(now_us);
                let land = now_us.saturating_sub(since) >= FLIGHT_FAILSAFE_GRACE_US
                    && !core::mem::replace(&mut self.rc_lost_landing, true);
                land.then_some(ControlCommand::Land(LandReason::RcLost))
            }
        }
    }

    /// The telemetry frame for the pilot's handset, if the receiver granted a slot since the
    /// last call (one frame per RC frame received, as a CRSF receiver forwards one telemetry
    /// frame per uplink frame): written into `out`, its length returned. The frames cycle
    /// attitude → flight mode (→ battery, when the snapshot has one), so at 150 RC frames per
    /// second the handset sees each within 20 ms.
    pub fn telemetry_frame(&mut self, snapshot: &ControlSnapshot, out: &mut [u8]) -> Option<usize> {
        self.handset.observe(snapshot);
        if !core::mem::take(&mut self.telemetry_slot) {
            return None;
        }
        self.handset.next(snapshot).encode(out)
    }

    /// What the status reports.
    pub fn health(&self, now_us: u64) -> ReceiverHealth {
        let stats = self.parser.stats();
        let (link_quality_pct, rssi_dbm) = self.statistics.map_or((0, 0), |s| {
            let rssi =
                if s.active_antenna == 0 { s.uplink_rssi_ant1_dbm } else { s.uplink_rssi_ant2_dbm };
            (s.uplink_link_quality_pct, rssi)
        });
        ReceiverHealth {
            link_up: self.link.is_fresh(now_us),
            link_quality_pct,
            rssi_dbm,
            frames: stats.good_frames,
            frame_errors: stats
                .crc_errors
                .saturating_add(stats.length_errors)
                .saturating_add(stats.truncated),
        }
    }
}

/// A battery measurement for the handset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Battery {
    pub voltage_v: f32,
    pub current_a: f32,
    pub used_mah: u32,
    pub remaining_pct: u8,
}

/// The handset's telemetry cycle, and whether a failsafe is still to be shown.
#[derive(Clone, Copy, Debug, Default)]
struct HandsetCycle {
    next: u8,
    failsafes_seen: u32,
    /// A failsafe stopped the craft and it has not been armed since.
    failsafe_shown: bool,
}

impl HandsetCycle {
    /// Follow the craft between frames: a new failsafe is shown until the craft is armed again.
    fn observe(&mut self, snapshot: &ControlSnapshot) {
        let total = snapshot.pilot.failsafes.total();
        if total != self.failsafes_seen {
            self.failsafes_seen = total;
            self.failsafe_shown = true;
        }
        if snapshot.armed {
            self.failsafe_shown = false;
        }
    }

    fn next(&mut self, snapshot: &ControlSnapshot) -> HandsetTelemetry {
        let battery = snapshot.battery;
        let kinds = if battery.is_some() { 3 } else { 2 };
        let kind = self.next % kinds;
        self.next = (kind + 1) % kinds;
        match (kind, battery) {
            (0, _) => attitude(snapshot),
            (2, Some(b)) => HandsetTelemetry::Battery {
                voltage_v: b.voltage_v,
                current_a: b.current_a,
                // CRSF carries whole mAh (24 bits); a negative drift of the sensor reads 0.
                used_mah: b.used_mah as u32,
                remaining_pct: b.remaining_pct,
            },
            _ => HandsetTelemetry::FlightMode(flight_mode_words(snapshot, self.failsafe_shown)),
        }
    }
}

/// The craft's attitude for the handset: the thrust frame's once the craft flies on its learned
/// model (the frame it hovers in), the IMU's before; Euler angles ZYX.
fn attitude(snapshot: &ControlSnapshot) -> HandsetTelemetry {
    let pilot = &snapshot.pilot;
    let q = if pilot.flying { pilot.q_world_thrust } else { pilot.q_world_imu };
    let [roll_rad, pitch_rad, yaw_rad] = flight::attitude::euler_zyx_rad(q);
    HandsetTelemetry::Attitude { pitch_rad, roll_rad, yaw_rad }
}

/// What the craft is doing, in words a pilot reads on a handset: `DISARMED`, `WAIT THROW`,
/// `THROWN`, `RELEASED`, `EXCITE k/m` (motor k of m pulsed), `HANDOVER`, `HOVER`, `POS HOLD`,
/// `ANGLE` (the sticks fly it in angle mode), `LANDING`, `MOTOR TEST`, `FAILSAFE` (a failsafe
/// stopped it and it has not been armed since).
pub fn flight_mode_words(
    snapshot: &ControlSnapshot,
    failsafe_shown: bool,
) -> heapless::String<FLIGHT_MODE_MAX_LEN> {
    let mut words = heapless::String::new();
    let pilot = &snapshot.pilot;
    let text = if pilot.flying {
        match (pilot.landing, pilot.piloted, pilot.position_hold) {
            (Some(_), _, _) => "LANDING",
            (None, Some(false), _) => "ANGLE",
            (None, _, true) => "POS HOLD",
            (None, _, false) => "HOVER",
        }
    } else if snapshot.armed {
        match (snapshot.phase, snapshot.exciting_motor) {
            (FlightPhase::WaitingForThrow, _) => "WAIT THROW",
            (FlightPhase::Throwing, _) => "THROWN",
            (FlightPhase::Released, _) => "RELEASED",
            (FlightPhase::Exciting, Some(motor)) => {
                // At most 8 motors: one digit each (no formatting machinery in the firmware).
                let digit = |n: u8| char::from(b'0' + n.min(9));
                for c in
                    "EXCITE ".chars().chain([digit(motor + 1), '/', digit(snapshot.motor_count)])
                {
                    let _ = words.push(c);
                }
                return words;
            }
            (FlightPhase::Exciting, None) => "EXCITE",
            (FlightPhase::Done, _) => "HANDOVER",
            (FlightPhase::Idle, _) if snapshot.motor_test.is_some() => "MOTOR TEST",
            (FlightPhase::Idle, _) => "ARMED",
        }
    } else if failsafe_shown {
        "FAILSAFE"
    } else {
        "DISARMED"
    };
    let _ = words.push_str(text);
    words
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drivers::crsf::{crc8_dvb_s2, TYPE_RC_CHANNELS_PACKED};

    /// A CRSF RC-channels frame with the switches given, the land switch off.
    fn frame(arm: bool, throw: bool, kill: bool) -> heapless::Vec<u8, 26> {
        frame_with(arm, throw, kill, false)
    }

    /// A CRSF RC-channels frame with every channel centred except the switches given.
    fn frame_with(arm: bool, throw: bool, kill: bool, land: bool) -> heapless::Vec<u8, 26> {
        let us = |on: bool| if on { 2000.0f32 } else { 1000.0 };
        let mut values = [992u16; 16];
        // µs → raw: raw = 992 + (us − 1500) · 8/5.
        let raw = |us: f32| (992.0 + (us - 1500.0) * 1.6) as u16;
        values[4] = raw(us(arm));
        values[5] = raw(us(throw));
        values[6] = raw(us(kill));
        values[7] = raw(us(land));
        let mut payload = [0u8; 22];
        let mut bit = 0usize;
        for v in values {
            for b in 0..11 {
                if (v >> b) & 1 == 1 {
                    payload[bit / 8] |= 1 << (bit % 8);
                }
                bit += 1;
            }
        }
        let mut out = heapless::Vec::new();
        out.extend_from_slice(&[0xC8, 24, TYPE_RC_CHANNELS_PACKED]).unwrap();
        out.extend_from_slice(&payload).unwrap();
        out.push(crc8_dvb_s2(&out[2..])).unwrap();
        out
    }

    const KILL: ControlCommand = ControlCommand::Failsafe(Failsafe::Kill);
    const RC_LOST: ControlCommand = ControlCommand::Failsafe(Failsafe::RcLost);
    const RC_LOST_LAND: ControlCommand = ControlCommand::Land(LandReason::RcLost);
    const SWITCH_LAND: ControlCommand = ControlCommand::Land(LandReason::Switch);
    const GROUND_ARMED: CraftState = CraftState { armed: true, in_flight: false };
    const FLYING: CraftState = CraftState { armed: true, in_flight: true };
    const IDLE: CraftState = CraftState { armed: false, in_flight: false };

    fn receiver() -> Receiver {
        Receiver::new(RcLinkConfig::default()).unwrap()
    }

    #[test]
    fn absent_receiver_commands_nothing() {
        let mut rx = receiver();
        for t in 0..10 {
            assert_eq!(rx.poll(&[], t * 1_000_000, FLYING), None);
        }
        assert!(!rx.health(0).link_up);
    }

    #[test]
    fn arming_needs_the_switch_seen_off_first() {
        let mut rx = receiver();
        // Powered up with arm and throw-to-fly on: no arm.
        assert_eq!(rx.poll(&frame(true, true, false), 1_000, IDLE), None);
        assert_eq!(rx.poll(&frame(true, true, false), 2_000, IDLE), None);
        // Switch off, then on again: one arm command, not repeated.
        assert_eq!(rx.poll(&frame(false, false, false), 3_000, IDLE), None);
        assert_eq!(
            rx.poll(&frame(true, true, false), 4_000, IDLE),
            Some(ControlCommand::ArmThrowToFly)
        );
        assert_eq!(rx.poll(&frame(true, true, false), 5_000, GROUND_ARMED), None);
        // Arm switch off: one disarm.
        assert_eq!(
            rx.poll(&frame(false, false, false), 6_000, GROUND_ARMED),
            Some(ControlCommand::Disarm)
        );
        assert_eq!(rx.poll(&frame(false, false, false), 7_000, IDLE), None);
        let health = rx.health(7_000);
        assert!(health.link_up);
        assert_eq!((health.frames, health.frame_errors), (7, 0));
    }

    #[test]
    fn kill_disarms_in_the_step_its_frame_arrives_and_every_step_after() {
        let mut rx = receiver();
        rx.poll(&frame(false, false, false), 0, IDLE);
        rx.poll(&frame(true, true, false), 500, IDLE);
        assert_eq!(rx.poll(&frame(true, true, true), 1_000, FLYING), Some(KILL));
        // No new frame, still armed (say the disarm was lost): kill again.
        assert_eq!(rx.poll(&[], 1_500, FLYING), Some(KILL));
        assert_eq!(rx.poll(&[], 2_000, IDLE), None);
    }

    #[test]
    fn kill_switch_off_again_does_not_re_arm_until_the_arm_switch_is_cycled() {
        let mut rx = receiver();
        rx.poll(&frame(false, false, false), 0, IDLE);
        assert_eq!(
            rx.poll(&frame(true, true, false), 500, IDLE),
            Some(ControlCommand::ArmThrowToFly)
        );
        assert_eq!(rx.poll(&frame(true, true, true), 1_000, GROUND_ARMED), Some(KILL));
        assert_eq!(rx.poll(&frame(true, true, false), 1_500, IDLE), None, "kill off: no re-arm");
        assert_eq!(rx.poll(&frame(true, true, false), 2_000, IDLE), None);
        assert_eq!(rx.poll(&frame(false, false, false), 2_500, IDLE), None);
        assert_eq!(
            rx.poll(&frame(true, true, false), 3_000, IDLE),
            Some(ControlCommand::ArmThrowToFly)
        );
    }

    #[test]
    fn failsafe_on_the_ground_disarms_at_once() {
        let mut rx = receiver();
        rx.poll(&frame(false, false, false), 0, IDLE);
        assert_eq!(rx.poll(&[], 200_000, GROUND_ARMED), None);
        assert_eq!(rx.poll(&[], 250_000, GROUND_ARMED), Some(RC_LOST));
        assert_eq!(rx.poll(&[], 260_000, IDLE), None);
    }

    #[test]
    fn failsafe_in_flight_keeps_flying_then_lands_once() {
        let mut rx = receiver();
        rx.poll(&frame(false, false, false), 0, IDLE);
        rx.poll(&frame(true, true, false), 1_000, IDLE);
        // Lost at 1 ms; failsafe from 251 ms; the landing 1 s later, asked for once.
        assert_eq!(rx.poll(&[], 251_000, FLYING), None);
        assert_eq!(rx.poll(&[], 1_250_000, FLYING), None);
        assert_eq!(rx.poll(&[], 1_251_000, FLYING), Some(RC_LOST_LAND));
        assert_eq!(rx.poll(&[], 1_251_500, FLYING), None);
        assert_eq!(rx.poll(&[], 5_000_000, FLYING), None);
        // Touched down (disarmed): nothing more.
        assert_eq!(rx.poll(&[], 9_000_000, IDLE), None);
    }

    #[test]
    fn the_land_switch_lands_once_per_flip_with_the_arm_switch_on() {
        let mut rx = receiver();
        let land = |on: bool| frame_with(true, true, false, on);
        rx.poll(&frame(false, false, false), 0, IDLE);
        assert_eq!(
            rx.poll(&frame(true, true, false), 500, IDLE),
            Some(ControlCommand::ArmThrowToFly)
        );
        assert_eq!(rx.poll(&land(true), 1_000, FLYING), Some(SWITCH_LAND));
        assert_eq!(rx.poll(&land(true), 1_500, FLYING), None, "asked once");
        assert_eq!(rx.poll(&land(false), 2_000, FLYING), None, "off: the landing goes on");
        assert_eq!(rx.poll(&land(true), 2_500, FLYING), Some(SWITCH_LAND), "flipped again");
        // The arm switch off still disarms at once, landing or not.
        assert_eq!(
            rx.poll(&frame_with(false, false, false, true), 3_000, FLYING),
            Some(ControlCommand::Disarm)
        );
        // Disarmed, the land switch asks nothing.
        let mut idle = receiver();
        idle.poll(&frame(false, false, false), 0, IDLE);
        assert_eq!(idle.poll(&frame_with(true, false, false, true), 500, IDLE), None);
    }

    #[test]
    fn link_back_within_the_grace_cancels_and_rearming_needs_a_switch_cycle() {
        let mut rx = receiver();
        rx.poll(&frame(false, false, false), 0, IDLE);
        rx.poll(&frame(true, true, false), 1_000, IDLE);
        assert_eq!(rx.poll(&[], 500_000, FLYING), None);
        assert_eq!(rx.poll(&frame(true, true, false), 600_000, FLYING), None);
        assert_eq!(rx.poll(&[], 1_700_000, FLYING), None, "grace restarts after the link returned");
        // Landed and disarmed by USB while the link is up: switches still on, no re-arm.
        assert_eq!(rx.poll(&frame(true, true, false), 1_800_000, IDLE), None);
    }

    #[test]
    fn the_sticks_reach_the_control_step_when_they_change_and_go_when_the_link_does() {
        let mut rx = receiver();
        assert_eq!(rx.take_sticks(0), None, "no receiver: nothing");
        rx.poll(&frame(false, false, false), 0, IDLE);
        let Some(ControlCommand::Sticks(Some(centred))) = rx.take_sticks(0) else {
            panic!("the first frame's sticks")
        };
        assert!(centred.roll.abs() < 0.01 && centred.throttle.abs() < 0.01, "{centred:?}");
        assert!(centred.position_mode, "the mode switch centred (1500 µs): position mode");
        rx.poll(&frame(false, false, false), 7_000, IDLE);
        assert_eq!(rx.take_sticks(7_000), None, "unchanged: nothing");
        // Lost: the sticks go, once.
        rx.poll(&[], 300_000, FLYING);
        assert_eq!(rx.take_sticks(300_000), Some(ControlCommand::Sticks(None)));
        assert_eq!(rx.take_sticks(300_500), None);
    }

    #[test]
    fn corrupted_frames_are_counted_and_ignored() {
        let mut rx = receiver();
        let mut bad = frame(false, false, true);
        let last = bad.len() - 1;
        bad[last] ^= 0x01;
        assert_eq!(rx.poll(&bad, 0, FLYING), None);
        // Truncated frame followed by a good one.
        let good = frame(false, false, false);
        assert_eq!(rx.poll(&good[..10], 100, IDLE), None);
        assert_eq!(rx.poll(&good, 200, IDLE), None);
        let health = rx.health(200);
        assert!(health.link_up);
        assert_eq!(health.frames, 1);
        assert!(health.frame_errors >= 2, "{health:?}");
    }
}
