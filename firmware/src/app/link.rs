//! The link server: the device's side of the protocol, on any byte transport (USB CDC on the
//! board; a pseudo-terminal or TCP in the simulator).
//!
//! Bytes in → frames → requests → one response each (ok or a typed error), matched by sequence
//! number. Telemetry is serialised straight into the transmit buffer at the rate the host chose:
//! the per-step topics from the control step's records ([`LinkServer::stream`]), the others
//! sampled from the latest snapshot ([`LinkServer::poll`]). Each topic counts its samples in the
//! frame sequence number, so a sample dropped for lack of transmit space is a gap the host can
//! count. Bad frames are counted and
//! reported as an event at most every 100 ms. Nothing here blocks or allocates.

use super::log::{FileRead, LogFileError, LogFiles};
use super::params;
use super::pilot::{failsafe_action, failsafe_counter, failsafe_reason, Failsafe, FAILSAFE_KINDS};
use super::settings::{Settings, SignatureCheck};
use super::telemetry::{flight_telemetry, learner_telemetry, sensor_health, StepRecord};
use super::{BackgroundCommand, BoardInfo, ControlCommand, StatusView};
use embedded_storage::nor_flash::NorFlash;
use flight::learner::FlightPhase;
use protocol::text as short_text;
use protocol::{
    CalibrationThrow, Capabilities, ConfigStatus, ControlStatus, ControlTelemetry, DecodeError,
    Decoder, DeviceError, DeviceMessage, DshotCommand, Event, FailsafeCounters, FrameError,
    IdentificationStatus, ImuStatus, LandReason, LinkCounters, LinkSecurity, ParamRef, Reply,
    Request, Response, SetLinkKey, SetTelemetryRate, Status, Telemetry, Topic, Version,
    MAX_FRAME_LEN, MAX_MOTORS, MAX_TELEMETRY_RATE_HZ, PROTOCOL_VERSION, TOPIC_COUNT,
};

/// Commands for the control step that may wait between two link passes.
const COMMAND_QUEUE_LEN: usize = 4;

/// Transmit buffer size, bytes: eight maximum frames (about 4 ms of USB full-speed bulk traffic).
pub const TX_CAPACITY: usize = 8 * MAX_FRAME_LEN;
/// Transmit space telemetry and events must leave free, bytes: room for two maximum-size
/// responses, so a request is answered even while telemetry saturates the link.
const RESPONSE_RESERVE: usize = 2 * MAX_FRAME_LEN;
/// The part of a slow link's byte rate that telemetry may book, %: the rest is for responses
/// and events, which go first (a status answer is about 200 bytes, 35 ms at 57,600 baud).
pub const TELEMETRY_SHARE_PCT: u32 = 75;
/// Shortest interval between two link-error events, µs.
const LINK_ERROR_EVENT_INTERVAL_US: u64 = 100_000;

/// What a host asked of the other tasks, handed over by the board after each link pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LinkRequest {
    /// For `ControlLoop::command`.
    Control(ControlCommand),
    /// For `Background::command`.
    Background(BackgroundCommand),
    /// Restart the board once the transmit buffer has drained (the reply is in it).
    Reboot,
    /// Restart into the ROM bootloader (USB DFU), likewise.
    RebootToBootloader,
    /// For the compass service (`super::compass::CompassInput::command`), checked already.
    Compass(protocol::CompassCalibrationCommand),
}

/// Per-topic streaming state.
#[derive(Clone, Copy, Debug, Default)]
struct TopicState {
    /// Sampling period, µs; 0 when the topic is off.
    period_us: u32,
    next_due_us: u64,
    /// A per-step topic sends every this many control steps (0 when off).
    step_divider: u32,
    /// Samples taken so far (sent or dropped): the frame sequence number of a sampled topic.
    seq: u16,
}

/// The device's protocol endpoint: the link task's local resource.
pub struct LinkServer {
    info: protocol::Info,
    decoder: Decoder,
    tx: TxBuffer,
    /// The host's protocol version once a handshake succeeded.
    host_version: Option<Version>,
    topics: [TopicState; TOPIC_COUNT],
    counters: LinkCounters,
    event_seq: u16,
    /// Errors arrived since the last link-error event.
    errors_unreported: bool,
    last_error_event_us: Option<u64>,
    /// Commands for the control step, taken by the board with [`LinkServer::take_command`].
    commands: heapless::Deque<ControlCommand, COMMAND_QUEUE_LEN>,
    /// Commands for the background task ([`LinkServer::take_background_command`]).
    background_commands: heapless::Deque<BackgroundCommand, COMMAND_QUEUE_LEN>,
    /// Calibration throws already reported as events.
    calibration_throws_reported: u8,
    /// Motor-test timeouts already reported as events.
    motor_test_timeouts_reported: u16,
    /// The motor this link's host last asked to test (stopped when the host goes away).
    motor_test_started: Option<u8>,
    /// The host asked for a restart ([`LinkServer::take_request`]).
    reboot_requested: Option<LinkRequest>,
    /// A compass calibration command for the compass service.
    compass_command: Option<protocol::CompassCalibrationCommand>,
    /// Failsafe counts already reported as events.
    failsafes_reported: FailsafeCounters,
    /// Landings begun and touchdowns already reported as events.
    landings_reported: (u16, u16),
    /// Whoever holds this link holds the craft (USB, the simulator's own link): unsigned
    /// requests are carried out. `false` for a radio: see [`LinkServer::untrusted`].
    trusted: bool,
    /// Requests this link refused for their signature, since start-up.
    refusals: SignatureRefusals,
    /// The greatest signed timestamp this link accepted since start-up.
    last_timestamp: u64,
    /// The last request that commands the craft, and its answer: the same frame again (the
    /// host asking once more because the answer was lost on a radio) gets the same answer and
    /// is not carried out twice.
    /// The link's byte rate, bytes/s, when it is slower than the topics could fill (a radio):
    /// [`LinkServer::with_byte_rate`].
    byte_rate: Option<u32>,
    /// The answer is kept as its frame (the request's sequence number in it).
    last_command: Option<(RequestFingerprint, heapless::Vec<u8, MAX_FRAME_LEN>)>,
}

/// What tells a repeated request frame from a new one: its sequence number and its CRC-32C (over
/// id, sequence number, payload and signature). A host asks again with the very same frame; a
/// new request has a new sequence number (and a new timestamp when signed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct RequestFingerprint {
    seq: u16,
    crc: u32,
}

impl RequestFingerprint {
    fn of(frame: &protocol::Frame<'_>) -> Self {
        Self { seq: frame.seq, crc: frame.crc }
    }
}

/// Requests a link refused for their signature (reported in [`Reply::LinkSecurity`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct SignatureRefusals {
    unsigned: u32,
    bad_signature: u32,
    replayed: u32,
}

impl LinkServer {
    pub fn new(board: BoardInfo) -> Self {
        Self {
            info: board.info(),
            decoder: Decoder::new(),
            tx: TxBuffer::new(),
            host_version: None,
            topics: [TopicState::default(); TOPIC_COUNT],
            counters: LinkCounters::default(),
            event_seq: 0,
            errors_unreported: false,
            last_error_event_us: None,
            commands: heapless::Deque::new(),
            background_commands: heapless::Deque::new(),
            calibration_throws_reported: 0,
            motor_test_timeouts_reported: 0,
            motor_test_started: None,
            reboot_requested: None,
            compass_command: None,
            failsafes_reported: FailsafeCounters::default(),
            landings_reported: (0, 0),
            trusted: true,
            refusals: SignatureRefusals::default(),
            last_timestamp: 0,
            last_command: None,
            byte_rate: None,
        }
    }

    /// This link carries `bytes_per_s` (a radio's air rate; a UART's baud over 10 for 8N1):
    /// telemetry rates are granted within [`TELEMETRY_SHARE_PCT`] % of it, each sample booked
    /// at its topic's longest frame ([`Topic::max_frame_len`]), so responses and events always
    /// find room and what is streamed arrives evenly decimated rather than randomly dropped.
    pub fn with_byte_rate(mut self, bytes_per_s: u32) -> Self {
        self.byte_rate = Some(bytes_per_s);
        self
    }

    /// This link is heard by others (a telemetry radio): requests that configure, arm, spin or
    /// steer the craft ([`protocol::commands_the_craft`]) are carried out only when signed with
    /// the paired key, and the key itself cannot be set over it.
    pub fn untrusted(mut self) -> Self {
        self.trusted = false;
        self
    }

    /// The host went away (USB unplugged or its port closed): a motor test it started stops
    /// now. Nothing else changes (a flight goes on without its configurator).
    pub fn disconnected(&mut self) {
        if self.motor_test_started.take().is_some() {
            let _ = self.commands.push_back(ControlCommand::StopMotorTest);
        }
        self.host_version = None;
        self.topics = [TopicState::default(); TOPIC_COUNT];
    }

    /// The oldest thing the host asked of another task, if any: commands for the control step
    /// first (arm, disarm, pose, motor test), then the background task's, then a restart. The
    /// board hands each over after every link pass.
    pub fn take_request(&mut self) -> Option<LinkRequest> {
        if let Some(command) = self.commands.pop_front() {
            return Some(LinkRequest::Control(command));
        }
        if let Some(command) = self.background_commands.pop_front() {
            return Some(LinkRequest::Background(command));
        }
        if let Some(command) = self.compass_command.take() {
            return Some(LinkRequest::Compass(command));
        }
        self.reboot_requested.take()
    }

    /// Feed bytes received from the host; answers are queued for [`LinkServer::transmit_to`].
    /// Parameter requests read and change `settings` (a save writes its flash); flight-log
    /// requests list, read (one chunk per request) and delete `logs`' files.
    pub fn receive<F: NorFlash>(
        &mut self,
        bytes: &[u8],
        now_us: u64,
        view: &StatusView,
        settings: &mut Settings<F>,
        logs: &mut dyn LogFiles,
    ) {
        for &byte in bytes {
            let Some(result) = self.decoder.push(byte) else { continue };
            let (seq, signature, decoded, fingerprint) = match result {
                Ok(frame) => {
                    let fingerprint = RequestFingerprint::of(&frame);
                    if let Some((_, answer)) =
                        self.last_command.as_ref().filter(|(last, _)| *last == fingerprint)
                    {
                        // The host asked again (our answer was lost on the way): the same
                        // answer, nothing carried out twice.
                        self.counters.frames_rx = self.counters.frames_rx.wrapping_add(1);
                        if self.tx.push_frame(answer, 0).is_err() {
                            self.counters.responses_dropped =
                                self.counters.responses_dropped.wrapping_add(1);
                        }
                        continue;
                    }
                    let last_timestamp = &mut self.last_timestamp;
                    let check =
                        settings.link_guard().check(frame.signature.as_ref(), last_timestamp);
                    (frame.seq, check, Request::decode(&frame), fingerprint)
                }
                Err(error) => {
                    self.count_frame_error(error);
                    continue;
                }
            };
            self.counters.frames_rx = self.counters.frames_rx.wrapping_add(1);
            let mut commands = false;
            let response = match decoded {
                Ok(Request::Disarm(()))
                    if !self.trusted && signature != SignatureCheck::Accepted =>
                {
                    Ok(self.stranger_disarm(view))
                }
                Ok(request) => {
                    commands = protocol::commands_the_craft(&request);
                    match self.authorise(&request, signature) {
                        Ok(()) => self.handle(request, now_us, view, settings, logs),
                        Err(refusal) => Err(refusal),
                    }
                }
                Err(DecodeError::UnknownId { id }) => {
                    self.counters.unknown_id = self.counters.unknown_id.wrapping_add(1);
                    Err(DeviceError::UnknownRequest { id })
                }
                Err(DecodeError::Malformed { id }) => {
                    self.counters.malformed = self.counters.malformed.wrapping_add(1);
                    Err(DeviceError::Malformed { id })
                }
            };
            match self.tx.push(&DeviceMessage::Response(response), seq, 0) {
                Ok(written) => {
                    self.counters.frames_tx = self.counters.frames_tx.wrapping_add(1);
                    if commands {
                        let answer = heapless::Vec::from_slice(written).unwrap_or_default();
                        self.last_command = Some((fingerprint, answer));
                    }
                }
                Err(TxFull) => {
                    self.counters.responses_dropped =
                        self.counters.responses_dropped.wrapping_add(1);
                }
            }
        }
    }

    /// Serialise one control step's samples of the per-step topics that are on and due (every
    /// `step_divider`-th step). Feed it every record the ring holds, oldest first, before
    /// [`LinkServer::poll`]. A sample that does not fit the transmit buffer is dropped whole and
    /// counted; its sequence number (the step count over the divider) is then a gap.
    pub fn stream(&mut self, record: &StepRecord) {
        for topic in Topic::ALL.into_iter().filter(|t| t.is_per_step()) {
            let divider = self.topics[topic.index()].step_divider;
            if divider == 0 || !record.step.is_multiple_of(divider) {
                continue;
            }
            let Some(sample) = record.sample(topic) else { continue };
            let seq = (record.step / divider) as u16;
            if self.send(&DeviceMessage::Telemetry(sample), seq, RESPONSE_RESERVE).is_err() {
                self.counters.telemetry_dropped = self.counters.telemetry_dropped.wrapping_add(1);
            }
        }
    }

    /// Sample the telemetry topics the link samples itself (not the per-step ones) that are due,
    /// and emit pending events. Call at least as often as the fastest topic (the board calls it
    /// every millisecond).
    pub fn poll(&mut self, now_us: u64, view: &StatusView) {
        for topic in Topic::ALL {
            let state = self.topics[topic.index()];
            if state.period_us == 0 || now_us < state.next_due_us {
                continue;
            }
            let period_us = u64::from(state.period_us);
            // Keep the cadence; after a stall, restart it rather than sending a burst.
            let next_due_us = if now_us - state.next_due_us >= period_us {
                now_us + period_us
            } else {
                state.next_due_us + period_us
            };
            let Some(sample) = sample_topic(topic, view, state.seq) else { continue };
            let message = DeviceMessage::Telemetry(sample);
            if self.send(&message, state.seq, RESPONSE_RESERVE).is_err() {
                self.counters.telemetry_dropped = self.counters.telemetry_dropped.wrapping_add(1);
            }
            let state = &mut self.topics[topic.index()];
            state.seq = state.seq.wrapping_add(1);
            state.next_due_us = next_due_us;
        }
        self.report_operations(view);
        let event_due = self
            .last_error_event_us
            .is_none_or(|last| now_us.saturating_sub(last) >= LINK_ERROR_EVENT_INTERVAL_US);
        if self.errors_unreported && event_due {
            let event = DeviceMessage::Event(Event::LinkErrors(self.counters));
            if self.send(&event, self.event_seq, RESPONSE_RESERVE).is_ok() {
                self.event_seq = self.event_seq.wrapping_add(1);
                self.errors_unreported = false;
                self.last_error_event_us = Some(now_us);
            }
        }
    }

    /// Offer the queued bytes to `write`, which returns how many it took (0 when the transport is
    /// full); those are removed, the rest wait for the next call. Returns the bytes taken.
    pub fn transmit_to(&mut self, mut write: impl FnMut(&[u8]) -> usize) -> usize {
        let taken = write(self.tx.pending()).min(self.tx.len());
        self.tx.consume(taken);
        taken
    }

    /// The link's frame counters.
    pub fn counters(&self) -> LinkCounters {
        self.counters
    }

    /// Events for what the background and control tasks did on this link's behalf: each new
    /// calibration throw, a motor test that stopped by itself.
    fn report_operations(&mut self, view: &StatusView) {
        let offset = &view.background.imu_offset;
        match &view.background.calibration {
            Some(calibration) if offset.throws > self.calibration_throws_reported => {
                let event = Event::CalibrationThrow(CalibrationThrow {
                    free_fall_ms: calibration.last_free_fall_ms,
                    estimate: *offset,
                    acc_bias_mps2: calibration.acc_bias_mps2.unwrap_or([0.0; 3]),
                });
                if self.send_event(event).is_ok() {
                    self.calibration_throws_reported = offset.throws;
                }
            }
            Some(_) => {}
            None => self.calibration_throws_reported = 0,
        }
        self.report_failsafes(view);
        self.report_landings(view);
        let timeouts = view.control.motor_test_timeouts;
        if timeouts != self.motor_test_timeouts_reported {
            if let Some(motor) = self.motor_test_started {
                if self.send_event(Event::MotorTestTimedOut { motor }).is_err() {
                    return;
                }
                self.motor_test_started = None;
            }
            self.motor_test_timeouts_reported = timeouts;
        }
    }

    /// An event when a landing begins ([`Event::Landing`]) and when it touches down
    /// ([`Event::Landed`]); a count is marked reported only once its event is in the transmit
    /// buffer.
    fn report_landings(&mut self, view: &StatusView) {
        let pilot = &view.control.pilot;
        let (begun, landed) = self.landings_reported;
        if pilot.landings != begun {
            if let Some(reason) = pilot.landing.or(pilot.last_landing) {
                let event = Event::Landing { reason, count: pilot.landings };
                if self.send_event(event).is_err() {
                    return;
                }
            }
            self.landings_reported.0 = pilot.landings;
        }
        if pilot.touchdowns != landed {
            if let Some(reason) = pilot.last_landing {
                let event = Event::Landed {
                    reason,
                    touchdown_speed_mps: pilot.touchdown_speed_mps,
                    count: pilot.touchdowns,
                };
                if self.send_event(event).is_err() {
                    return;
                }
            }
            self.landings_reported.1 = pilot.touchdowns;
        }
    }

    /// One event per failsafe whose counter rose since the last report, with its reason and
    /// count; a counter is marked reported only once its event is in the transmit buffer.
    fn report_failsafes(&mut self, view: &StatusView) {
        let mut counts = view.control.pilot.failsafes;
        if counts == self.failsafes_reported {
            return;
        }
        let last = view.control.pilot.last_failsafe;
        for kind in FAILSAFE_KINDS {
            let now = *failsafe_counter(&mut counts, kind);
            if now <= *failsafe_counter(&mut self.failsafes_reported, kind) {
                continue;
            }
            // The identification's detail comes from the latest failsafe when it is one.
            let failsafe = match (kind, last) {
                (Failsafe::Identification(_), Some(latest @ Failsafe::Identification(_))) => latest,
                _ => kind,
            };
            let event = Event::Failsafe {
                reason: failsafe_reason(failsafe),
                action: failsafe_action(failsafe),
                count: now,
            };
            if self.send_event(event).is_err() {
                return;
            }
            *failsafe_counter(&mut self.failsafes_reported, kind) = now;
        }
    }

    fn send_event(&mut self, event: Event) -> Result<(), TxFull> {
        self.send(&DeviceMessage::Event(event), self.event_seq, RESPONSE_RESERVE)?;
        self.event_seq = self.event_seq.wrapping_add(1);
        Ok(())
    }

    /// A disarm over an untrusted link without a valid signature (anyone on the radio's channel
    /// may have sent it): a craft in the air lands instead of falling
    /// ([`ControlCommand::Land`] with [`LandReason::UnsignedDisarm`], counted with the unsigned
    /// refusals); on the ground, waiting for a throw or in a motor test it stops at once, as
    /// every way to stop must work. The control step decides which from its own state, so a
    /// throw in the link's blind moment still lands rather than falls.
    fn stranger_disarm(&mut self, view: &StatusView) -> Reply {
        let control = &view.control;
        let in_the_air = control.pilot.flying
            || matches!(control.phase, FlightPhase::Released | FlightPhase::Exciting);
        if in_the_air {
            self.refusals.unsigned = self.refusals.unsigned.wrapping_add(1);
        }
        self.push_landing(LandReason::UnsignedDisarm);
        Reply::Done
    }

    /// Queue a landing for the control step: it always fits (commands still waiting to arm or
    /// steer make room; a disarm waiting among them stays, ahead of it).
    fn push_landing(&mut self, reason: LandReason) {
        let land = ControlCommand::Land(reason);
        if self.commands.push_back(land).is_ok() {
            return;
        }
        let disarm_waiting = self.commands.iter().any(|c| *c == ControlCommand::Disarm);
        self.commands.clear();
        if disarm_waiting {
            let _ = self.commands.push_back(ControlCommand::Disarm);
        }
        let _ = self.commands.push_back(land);
    }

    /// Whether `request` may be carried out given its signature: signed ones only with a valid,
    /// fresh signature; unsigned ones on a trusted link, or when they do not command the craft.
    /// A disarm always passes: every way to stop must work.
    fn authorise(
        &mut self,
        request: &Request,
        signature: SignatureCheck,
    ) -> Result<(), DeviceError> {
        let refusals = &mut self.refusals;
        match signature {
            _ if matches!(request, Request::Disarm(())) => Ok(()),
            SignatureCheck::Accepted => Ok(()),
            SignatureCheck::Unsigned if self.trusted || !protocol::commands_the_craft(request) => {
                Ok(())
            }
            SignatureCheck::Unsigned => {
                refusals.unsigned = refusals.unsigned.wrapping_add(1);
                Err(DeviceError::SignatureRequired)
            }
            SignatureCheck::BadSignature => {
                refusals.bad_signature = refusals.bad_signature.wrapping_add(1);
                Err(DeviceError::BadSignature)
            }
            SignatureCheck::Replayed { last_timestamp } => {
                refusals.replayed = refusals.replayed.wrapping_add(1);
                Err(DeviceError::Replayed { last_timestamp })
            }
        }
    }

    fn handle<F: NorFlash>(
        &mut self,
        request: Request,
        now_us: u64,
        view: &StatusView,
        settings: &mut Settings<F>,
        logs: &mut dyn LogFiles,
    ) -> Response {
        // Requests that change the configuration or start an operation wait for a disarm; a
        // running motor test counts as armed for them (disarm ends it).
        let armed = view.control.armed;
        let refuse_if_armed = matches!(
            request,
            Request::SetParam(_)
                | Request::SaveConfig(())
                | Request::ResetConfig(())
                | Request::StartCalibration(())
                | Request::Reboot(())
                | Request::RebootToBootloader(())
                | Request::EscCommand(_)
                | Request::SetLinkKey(_)
                | Request::DeleteLog(_)
        );
        if refuse_if_armed && armed && self.host_version.is_some() {
            return Err(DeviceError::RefusedWhileArmed);
        }
        // For a refusal that names the request (the table's id, not a second copy of it).
        let request_id = request.id();
        match request {
            Request::Hello(hello) => self.handshake(hello.protocol),
            _ if self.host_version.is_none() => Err(DeviceError::HandshakeRequired),
            Request::GetInfo(()) => Ok(Reply::Info(self.info.clone())),
            Request::GetStatus(()) => Ok(Reply::Status(self.status(view))),
            Request::SetTelemetryRate(setting) => self.set_rate(setting, now_us),
            Request::Ping(ping) => Ok(Reply::Pong(ping)),
            Request::ArmThrowToFly(()) => {
                if usize::from(view.control.motor_count) < flight::learner::MIN_MOTORS {
                    return Err(DeviceError::BadValue {
                        name: short_text("motor_count"),
                        value: f32::from(view.control.motor_count),
                        min: flight::learner::MIN_MOTORS as f32,
                        max: MAX_MOTORS as f32,
                        unit: short_text(""),
                    });
                }
                // Unless the user says the ESCs cannot report (`Params::arms_without_speeds`:
                // the learner then identifies from the commands), the learner needs every
                // motor's speed.
                if !settings.params().arms_without_speeds() {
                    // Every motor must report its speed: an ESC that does not answer now will
                    // not answer in the air (`ControlLoop`'s module doc).
                    let all =
                        ((1u16 << usize::from(view.control.motor_count).min(MAX_MOTORS)) - 1) as u8;
                    let silent = all & !view.control.speeds_reported;
                    if silent != 0 {
                        return Err(DeviceError::SpeedsNotReported { motors: silent });
                    }
                }
                self.commands
                    .push_back(ControlCommand::ArmThrowToFly)
                    .map(|_| Reply::Done)
                    .map_err(|_| DeviceError::Busy)
            }
            Request::Disarm(()) => {
                // Always accepted: whatever waits is dropped, the disarm goes through.
                self.commands.clear();
                let _ = self.commands.push_back(ControlCommand::Disarm);
                Ok(Reply::Done)
            }
            Request::Land(()) => {
                // Like a disarm, it always goes through (a craft on the ground stops).
                self.push_landing(LandReason::Commanded);
                Ok(Reply::Done)
            }
            Request::SetExternalPose(pose) => {
                refuse_non_finite("pose", &pose.position_ned_m, pose.heading_rad)?;
                self.commands
                    .push_back(ControlCommand::ExternalPose(pose))
                    .map(|_| Reply::Done)
                    .map_err(|_| DeviceError::Busy)
            }
            Request::GetLearner(()) => Ok(Reply::Learner(learner_telemetry(view, 0))),
            Request::GetParam(reference) => {
                let index = match &reference {
                    ParamRef::Index(index) => Some(usize::from(*index)),
                    ParamRef::Name(name) => params::find(name.as_bytes()),
                };
                let info = index.and_then(|i| settings.params().info(i));
                info.map(Reply::Param).ok_or_else(|| DeviceError::UnknownParam {
                    name: match reference {
                        ParamRef::Name(name) => name,
                        ParamRef::Index(index) => index_text(index),
                    },
                })
            }
            Request::SetParam(set) => {
                let index = settings.set(&set.name, &set.values)?;
                settings.params().info(index).map(Reply::Param).ok_or(DeviceError::NotReady)
            }
            Request::SaveConfig(()) => {
                settings.save().map_err(|stage| DeviceError::StorageFailed { stage })?;
                Ok(Reply::Config(config_status(settings, view)))
            }
            Request::ResetConfig(()) => {
                settings.reset();
                Ok(Reply::Config(config_status(settings, view)))
            }
            Request::GetConfig(()) => Ok(Reply::Config(config_status(settings, view))),
            Request::StartCalibration(()) => {
                self.calibration_throws_reported = 0;
                self.background_commands
                    .push_back(BackgroundCommand::StartCalibration)
                    .map(|_| Reply::Done)
                    .map_err(|_| DeviceError::Busy)
            }
            Request::StopCalibration(stop) => {
                let Some(calibration) = view.background.calibration else {
                    return Err(DeviceError::NotReady);
                };
                let offset = &view.background.imu_offset;
                if stop.accept {
                    if !offset.well_determined || armed {
                        return Err(if armed {
                            DeviceError::RefusedWhileArmed
                        } else {
                            DeviceError::NotReady
                        });
                    }
                    settings.update(|p| {
                        p.store_calibration(
                            offset.r_imu_m,
                            offset.ci95_semi_axes_m,
                            calibration.acc_bias_mps2,
                        )
                    });
                }
                self.background_commands
                    .push_back(BackgroundCommand::StopCalibration)
                    .map_err(|_| DeviceError::Busy)?;
                let mut status = config_status(settings, view);
                status.calibrating = false;
                Ok(Reply::Config(status))
            }
            Request::MotorTest(test) => {
                let flight_armed = armed && view.control.motor_test.is_none();
                if flight_armed {
                    return Err(DeviceError::RefusedWhileArmed);
                }
                let motors = view.control.motor_count;
                if test.motor >= motors {
                    return Err(DeviceError::BadValue {
                        name: short_text("motor"),
                        value: f32::from(test.motor),
                        min: 0.0,
                        max: f32::from(motors) - 1.0,
                        unit: short_text(""),
                    });
                }
                if !(0.0..=protocol::MOTOR_TEST_MAX_COMMAND).contains(&test.command) {
                    return Err(DeviceError::BadValue {
                        name: short_text("command"),
                        value: test.command,
                        min: 0.0,
                        max: protocol::MOTOR_TEST_MAX_COMMAND,
                        unit: short_text(""),
                    });
                }
                let command =
                    ControlCommand::MotorTest { motor: test.motor, command: test.command };
                self.commands.push_back(command).map_err(|_| DeviceError::Busy)?;
                self.motor_test_started = Some(test.motor);
                Ok(Reply::Done)
            }
            Request::Reboot(()) => {
                self.reboot_requested = Some(LinkRequest::Reboot);
                Ok(Reply::Done)
            }
            Request::SetPositionSetpoint(setpoint) => {
                refuse_non_finite("setpoint", &setpoint.position_ned_m, setpoint.heading_rad)?;
                self.commands
                    .push_back(ControlCommand::PositionSetpoint(setpoint))
                    .map(|_| Reply::Done)
                    .map_err(|_| DeviceError::Busy)
            }
            Request::GetFlight(()) => Ok(Reply::Flight(flight_telemetry(view))),
            Request::GetBoard(()) => Ok(Reply::Board(view.board)),
            Request::GetGnss(()) => view.gnss.map(Reply::Gnss).ok_or(DeviceError::Unsupported),
            Request::GetCompass(()) => {
                view.compass.map(Reply::Compass).ok_or(DeviceError::Unsupported)
            }
            Request::CompassCalibration(command) => {
                let health = view.compass.ok_or(DeviceError::Unsupported)?;
                super::compass::CompassInput::check_command(&health, command, armed)?;
                if self.compass_command.is_some() {
                    return Err(DeviceError::Busy);
                }
                self.compass_command = Some(command);
                Ok(Reply::Done)
            }
            Request::GetHealth(()) => Ok(Reply::Health(sensor_health(view))),
            Request::GetIdentification(()) => Ok(Reply::Identification(IdentificationStatus {
                speeds_modelled: view.background.learned.speeds_modelled,
                imu_offset_source: view.background.learner_offset,
                r_imu_m: view.background.learner_r_imu_m,
                imu_offset_status_fitted_in_flight: view.background.imu_offset_fitted_in_flight,
            })),
            Request::GetBattery(()) => {
                view.control.battery.map(Reply::Battery).ok_or(DeviceError::Unsupported)
            }
            Request::GetLinkSecurity(()) => {
                let guard = settings.link_guard();
                Ok(Reply::LinkSecurity(LinkSecurity {
                    trusted: self.trusted,
                    paired: guard.paired(),
                    session: guard.session(),
                    last_timestamp: self.last_timestamp,
                    unsigned_refused: self.refusals.unsigned,
                    bad_signature: self.refusals.bad_signature,
                    replayed: self.refusals.replayed,
                }))
            }
            Request::SetLinkKey(SetLinkKey { key }) => {
                if !self.trusted {
                    return Err(DeviceError::TrustedLinkOnly);
                }
                // Another length than a key's is a host bug, as a payload that does not decode.
                let key = match key.map(heapless::Vec::into_array) {
                    None => None,
                    Some(Ok(key)) => Some(key),
                    Some(Err(_)) => return Err(DeviceError::Malformed { id: request_id }),
                };
                settings.set_link_key(key).map_err(|stage| DeviceError::StorageFailed { stage })?;
                Ok(Reply::Done)
            }
            Request::ListLogs(list) => {
                let mut files = heapless::Vec::new();
                let more = logs.list(list.first, &mut files).map_err(|e| log_error(e, 0))?;
                Ok(Reply::LogList(protocol::LogList { files, more }))
            }
            Request::ReadLog(read) => {
                let len = usize::from(read.len);
                if len > protocol::LOG_CHUNK_LEN {
                    return Err(DeviceError::BadValue {
                        name: short_text("len"),
                        value: f32::from(read.len),
                        min: 0.0,
                        max: protocol::LOG_CHUNK_LEN as f32,
                        unit: short_text("B"),
                    });
                }
                let mut buf = [0u8; protocol::LOG_CHUNK_LEN];
                let FileRead { bytes_read, size_bytes } = logs
                    .read(read.number, read.offset, &mut buf[..len])
                    .map_err(|e| log_error(e, read.number))?;
                Ok(Reply::LogChunk(protocol::LogChunk {
                    number: read.number,
                    offset: read.offset,
                    size_bytes,
                    // Cannot fail: `bytes_read` ≤ `len` ≤ the capacity.
                    bytes: heapless::Vec::from_slice(&buf[..bytes_read.min(len)])
                        .unwrap_or_default(),
                }))
            }
            Request::DeleteLog(delete) => {
                logs.delete(delete.number).map_err(|e| log_error(e, delete.number))?;
                Ok(Reply::Done)
            }
            Request::RebootToBootloader(()) => {
                if !self.info.capabilities.has(Capabilities::BOOTLOADER) {
                    return Err(DeviceError::Unsupported);
                }
                self.reboot_requested = Some(LinkRequest::RebootToBootloader);
                Ok(Reply::Done)
            }
            Request::EscCommand(request) => {
                if !self.info.capabilities.has(Capabilities::ESC_COMMANDS) {
                    return Err(DeviceError::Unsupported);
                }
                let motors = view.control.motor_count;
                if request.motor >= motors && request.motor != protocol::ESC_ALL_MOTORS {
                    return Err(DeviceError::BadValue {
                        name: short_text("motor"),
                        value: f32::from(request.motor),
                        min: 0.0,
                        max: f32::from(motors.max(1)) - 1.0,
                        unit: short_text(""),
                    });
                }
                let Some(command) = DshotCommand::from_value(request.command) else {
                    let numbers = DshotCommand::ALL.map(|c| f32::from(c.value()));
                    return Err(DeviceError::BadValue {
                        name: short_text("command"),
                        value: f32::from(request.command),
                        min: numbers.iter().copied().fold(f32::INFINITY, f32::min),
                        max: numbers.iter().copied().fold(0.0, f32::max),
                        unit: short_text(""),
                    });
                };
                let motor = (request.motor != protocol::ESC_ALL_MOTORS).then_some(request.motor);
                self.commands
                    .push_back(ControlCommand::EscCommand { command, motor })
                    .map(|_| Reply::Done)
                    .map_err(|_| DeviceError::Busy)
            }
        }
    }

    fn handshake(&mut self, host: Version) -> Response {
        // Either way a new session begins: nothing streams until the host asks for it, and no
        // request of the old session is answered again.
        self.topics = [TopicState::default(); TOPIC_COUNT];
        self.last_command = None;
        if host.major != PROTOCOL_VERSION.major {
            self.host_version = None;
            return Err(DeviceError::IncompatibleProtocol { device: PROTOCOL_VERSION, host });
        }
        self.host_version = Some(host);
        Ok(Reply::Hello(self.info.clone()))
    }

    fn set_rate(&mut self, setting: SetTelemetryRate, now_us: u64) -> Response {
        if setting.rate_hz > MAX_TELEMETRY_RATE_HZ {
            return Err(DeviceError::BadValue {
                name: short_text("rate_hz"),
                value: f32::from(setting.rate_hz),
                min: 0.0,
                max: f32::from(MAX_TELEMETRY_RATE_HZ),
                unit: short_text("Hz"),
            });
        }
        let mut rate_hz = u32::from(setting.rate_hz);
        if let Some(bytes_per_s) = self.byte_rate {
            // What the other topics already book, bytes/s.
            let booked: u32 = Topic::ALL
                .into_iter()
                .filter(|&topic| topic != setting.topic)
                .map(|topic| self.granted_hz(topic) * u32::from(topic.max_frame_len()))
                .sum();
            let budget = bytes_per_s.saturating_mul(TELEMETRY_SHARE_PCT) / 100;
            let left = budget.saturating_sub(booked);
            rate_hz = rate_hz.min(left / u32::from(setting.topic.max_frame_len()).max(1));
        }
        let state = &mut self.topics[setting.topic.index()];
        state.period_us = 1_000_000u32.checked_div(rate_hz).unwrap_or(0);
        state.next_due_us = now_us;
        // The nearest whole number of control steps per sample.
        let control_hz = u32::from(self.info.control_rate_hz).max(1);
        state.step_divider =
            (control_hz + rate_hz / 2).checked_div(rate_hz).map_or(0, |divider| divider.max(1));
        if setting.topic.is_per_step() && state.step_divider > 0 {
            // Never more than granted: a whole number of steps at or above the granted period.
            state.step_divider = state.step_divider.max(control_hz.div_ceil(rate_hz));
        }
        let granted_hz = self.granted_hz(setting.topic).min(u32::from(u16::MAX)) as u16;
        Ok(Reply::TelemetryRate(SetTelemetryRate { topic: setting.topic, rate_hz: granted_hz }))
    }

    /// The rate `topic` streams at now, Hz (rounded down): the control rate over the step
    /// divider for a per-step topic, one over the period for the others; 0 when off.
    fn granted_hz(&self, topic: Topic) -> u32 {
        let state = &self.topics[topic.index()];
        if topic.is_per_step() {
            u32::from(self.info.control_rate_hz).checked_div(state.step_divider).unwrap_or(0)
        } else {
            1_000_000u32.checked_div(state.period_us).unwrap_or(0)
        }
    }

    fn status(&self, view: &StatusView) -> Status {
        let control = &view.control;
        let background = &view.background;
        Status {
            uptime_ms: (control.t_us / 1000).min(u64::from(u32::MAX)) as u32,
            armed: control.armed,
            control: ControlStatus {
                steps: control.steps,
                rate_hz: control.rate_hz,
                late_steps: control.late_steps,
                max_interval_us: control.max_interval_us,
                samples_processed: background.samples_processed,
                samples_dropped: control.samples_dropped,
                step_time: view.step_time,
            },
            imu: ImuStatus {
                present: control.imu_present,
                samples: control.imu_samples,
                missing: control.imu_missing,
                gyro_rad_s: control.imu.gyro_rad_s,
                accel_mps2: control.imu.accel_mps2,
                gyro_mean_rad_s: background.gyro_mean_rad_s,
                gyro_std_rad_s: background.gyro_std_rad_s,
                accel_std_mps2: background.accel_std_mps2,
            },
            imu_offset: background.imu_offset,
            link: self.counters,
        }
    }

    /// Encode a message into the transmit buffer, leaving `reserve` bytes free.
    fn send(&mut self, message: &DeviceMessage, seq: u16, reserve: usize) -> Result<(), TxFull> {
        let _ = self.tx.push(message, seq, reserve)?;
        self.counters.frames_tx = self.counters.frames_tx.wrapping_add(1);
        Ok(())
    }

    fn count_frame_error(&mut self, error: FrameError) {
        let counters = &mut self.counters;
        let counter = match error {
            FrameError::Oversize => &mut counters.oversize,
            FrameError::BadCrc { .. } => &mut counters.bad_crc,
            FrameError::BadCobs | FrameError::TooShort { .. } | FrameError::BadHeader => {
                &mut counters.bad_framing
            }
        };
        *counter = counter.wrapping_add(1);
        self.errors_unreported = true;
    }
}

/// The wire's refusal for a log-file error about file `number`.
fn log_error(error: LogFileError, number: u32) -> DeviceError {
    match error {
        LogFileError::Unsupported => DeviceError::Unsupported,
        LogFileError::NoSuchFile => DeviceError::NoSuchLog { number },
        LogFileError::OffsetPastEnd { size_bytes } => {
            DeviceError::LogOffsetPastEnd { number, size_bytes }
        }
        LogFileError::BeingWritten => DeviceError::LogBeingWritten { number },
        LogFileError::Io => DeviceError::LogStorageFailed,
    }
}

/// A sample of a topic the link samples itself, from the latest snapshot (`None` for the
/// per-step topics, which [`LinkServer::stream`] sends).
fn sample_topic(topic: Topic, view: &StatusView, seq: u16) -> Option<Telemetry> {
    let control = &view.control;
    match topic {
        Topic::Learner => Some(Telemetry::Learner(learner_telemetry(view, (seq % 2) as u8))),
        Topic::Control => Some(Telemetry::Control(ControlTelemetry {
            t_us: control.t_us,
            steps: control.steps,
            late_steps: control.late_steps,
            samples_dropped: control.samples_dropped,
        })),
        Topic::Flight => Some(Telemetry::Flight(flight_telemetry(view))),
        Topic::Imu | Topic::Motors | Topic::State => None,
    }
}

/// `BadValue` naming `name` when a pose or setpoint is not finite.
fn refuse_non_finite(
    name: &str,
    position_m: &[f32; 3],
    heading_rad: f32,
) -> Result<(), DeviceError> {
    if super::is_finite_pose(position_m, heading_rad) {
        return Ok(());
    }
    Err(DeviceError::BadValue {
        name: short_text(name),
        value: f32::NAN,
        min: -f32::MAX,
        max: f32::MAX,
        unit: short_text("m, rad"),
    })
}

/// The configuration status with what the other tasks run.
fn config_status<F: NorFlash>(settings: &Settings<F>, view: &StatusView) -> ConfigStatus {
    ConfigStatus {
        calibrating: view.background.calibration.is_some(),
        motor_test: view.control.motor_test.is_some(),
        ..settings.status()
    }
}

/// "#12" for a parameter index that does not exist. The digits are written by hand: this was
/// the firmware's only use of `core::fmt::write` (about 0.5 KB of flash).
fn index_text(index: u16) -> heapless::String<{ protocol::NAME_LEN }> {
    let mut digits = [0u8; 5];
    let mut n = index;
    let mut len = 0;
    loop {
        digits[len] = b'0' + (n % 10) as u8;
        len += 1;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    let mut out = heapless::String::new();
    let _ = out.push('#');
    for &digit in digits[..len].iter().rev() {
        let _ = out.push(char::from(digit));
    }
    out
}

/// Not enough transmit space for the frame (with the reserve the caller asked to keep).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct TxFull;

/// A linear transmit buffer that frames are encoded into in place; drained from the front,
/// compacted when the tail has no room for a maximum-size frame.
struct TxBuffer {
    bytes: [u8; TX_CAPACITY],
    start: usize,
    end: usize,
}

impl TxBuffer {
    const fn new() -> Self {
        Self { bytes: [0; TX_CAPACITY], start: 0, end: 0 }
    }

    fn len(&self) -> usize {
        self.end - self.start
    }

    /// Encode `message` at the end, leaving `reserve` bytes free; returns the frame written.
    fn push(&mut self, message: &DeviceMessage, seq: u16, reserve: usize) -> Result<&[u8], TxFull> {
        self.make_room(reserve)?;
        // Cannot fail: MAX_FRAME_LEN bytes are free and every message fits a frame (tested).
        let written = message.encode(seq, &mut self.bytes[self.end..]).map_err(|_| TxFull)?;
        self.end += written;
        Ok(&self.bytes[self.end - written..self.end])
    }

    /// Queue an already encoded frame (at most [`MAX_FRAME_LEN`] bytes).
    fn push_frame(&mut self, frame: &[u8], reserve: usize) -> Result<(), TxFull> {
        self.make_room(reserve)?;
        let end = self.end + frame.len().min(MAX_FRAME_LEN);
        self.bytes[self.end..end].copy_from_slice(&frame[..end - self.end]);
        self.end = end;
        Ok(())
    }

    /// Make room for one frame at the end with `reserve` bytes left over.
    fn make_room(&mut self, reserve: usize) -> Result<(), TxFull> {
        if TX_CAPACITY - self.len() < MAX_FRAME_LEN + reserve {
            return Err(TxFull);
        }
        if TX_CAPACITY - self.end < MAX_FRAME_LEN {
            self.bytes.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        Ok(())
    }

    fn pending(&self) -> &[u8] {
        &self.bytes[self.start..self.end]
    }

    fn consume(&mut self, n: usize) {
        self.start += n.min(self.len());
        if self.start == self.end {
            self.start = 0;
            self.end = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::index_text;

    #[test]
    fn an_unknown_parameter_index_reads_as_hash_and_decimal_digits() {
        for (index, text) in [(0, "#0"), (7, "#7"), (12, "#12"), (1000, "#1000"), (65535, "#65535")]
        {
            assert_eq!(index_text(index).as_str(), text);
        }
    }
}
