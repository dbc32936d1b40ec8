//! The application graph: the three tasks of the flight controller, what each owns, what they
//! hand each other, and the one place where the order of their work is written down.
//!
//! The board and every simulator run the same graph: the RTIC application (`firmware/src/main.rs`)
//! binds each entry point to an interrupt and each [`Handoffs`] field to an RTIC shared resource
//! behind its own lock; the SITL, the lockstep bridge, the TCP server and the scenarios drive a
//! [`System`], which owns all three parts and locks nothing (one thread, [`Exclusive`] access).
//!
//! | entry point | board task, priority | what |
//! |---|---|---|
//! | [`ControlTask::tick`] | TIM7 at 2 kHz, 3 (highest) | the link's commands, then the pilot's radio (so a kill switch has the last word), the background's results, one control step, the snapshot published, a telemetry frame to the pilot's handset when the receiver granted a slot |
//! | [`LinkTask::pass`] | USB interrupt, pended by the tick every [`LINK_PASS_PERIOD_US`], 2 | every link's bytes in, requests routed, parameters serviced, the step records streamed, telemetry sampled, bytes out |
//! | [`run_background`] | software task, 1 (lowest) | work from the link (calibration, parameters), the flight log drained to its sink, the learner-sample queue drained, results published |
//!
//! The tasks share nothing but [`Handoffs`]: small values copied under a short lock, and two
//! bounded queues of explicit messages (a command for the control step, work for the background
//! task). A parameter change is such a message, sent once to each task that takes parameters,
//! rather than a generation the tasks poll. Nothing here blocks or allocates; a full queue drops
//! the newest message and counts it, except a disarm, which always finds room.
//!
//! The results reach the control step whenever the background task has run, which on the board
//! depends on the load; the tick logs each adoption with its step (`super::log`), so a replay
//! does not depend on that timing.
//!
//! Constants derived from the control rate are defined here once ([`LINK_PASS_TICKS`]).

use embedded_storage::nor_flash::NorFlash;
pub use rtic_core::{Exclusive, Mutex};

use super::battery::{BatteryMonitor, LowBattery};
use super::compass::{run_compass_solve, CompassInput, CompassSolveSlot, CompassSolver};
use super::gnss::GnssInput;
use super::hal::{BatterySensor, GnssPort, Imu, ImuSample, Motors, Port, PortClosed, Uart};
use super::log::{
    Adoption, ArmingTag, FileRead, LogEntry, LogFileError, LogFileList, LogFiles, LogProducer,
    LogSink, Logger, StepEntry,
};
use super::offset_fit::{FitHandoff, OffsetFitWorker};
use super::radio::{CraftState, Receiver};
use super::{
    Background, BackgroundResults, ControlCommand, ControlLoop, ControlSettings, ControlSnapshot,
    LinkRequest, LinkServer, Params, Settings, StatusView, StepConsumer, CONTROL_RATE_HZ,
};
use crate::drivers::compass::{DelayUs, I2cRegisterBus};
use flight::learner::FlightPhase;
use protocol::{BoardHealth, StepTime};

/// How often the link task runs, µs: 1 kHz, the USB full-speed frame rate (a host polls the
/// CDC endpoint once per 1 ms frame, so serving it more often gains nothing).
pub const LINK_PASS_PERIOD_US: u64 = 1_000;
/// Control ticks per link pass (2 at 2 kHz), derived from [`LINK_PASS_PERIOD_US`] and the
/// control rate.
pub const LINK_PASS_TICKS: u32 = {
    let ticks = LINK_PASS_PERIOD_US * CONTROL_RATE_HZ as u64 / 1_000_000;
    if ticks == 0 {
        1
    } else {
        ticks as u32
    }
};
/// Commands for the control step that may wait between two ticks: what a link pass can route
/// (a pose, a setpoint, a disarm, a parameter change) with room to spare.
pub const CONTROL_QUEUE_LEN: usize = 8;
/// Work for the background task that may wait until it next runs.
pub const WORK_QUEUE_LEN: usize = 4;
/// Bytes read from one link per read call, and reads per link per pass: at most 4 KiB per link
/// per pass (4 MB/s at 1 kHz), so a host that never stops writing cannot stall the link task.
const READ_CHUNK_BYTES: usize = 512;
const READS_PER_PASS: usize = 8;
/// Bytes read from the pilot's radio per tick, at most: a CRSF receiver at 420 kbaud delivers
/// 21 bytes per 500 µs control period; this is what the board's DMA ring holds, so even after a
/// stall of several periods one read empties it.
pub const RADIO_CHUNK_BYTES: usize = 256;

/// Commands waiting for the control step.
pub type ControlQueue = heapless::Deque<ControlCommand, CONTROL_QUEUE_LEN>;
/// Work waiting for the background task.
pub type WorkQueue = heapless::Deque<BackgroundWork, WORK_QUEUE_LEN>;

pub use super::log::BackgroundWork;

/// Everything the tasks hand each other. On the board each field is an RTIC shared resource
/// (locked for a copy or a queue operation); in a [`System`] a plain field.
#[derive(Debug)]
pub struct Handoffs {
    /// The control step's snapshot: written by every tick, read by the link pass.
    pub snapshot: ControlSnapshot,
    /// The background task's results: written by every background run, read by the tick
    /// (the learned model) and the link pass (status).
    pub results: BackgroundResults,
    /// The board's drivers and clocks: written at start-up and by the tick at the link rate
    /// (motor link, receiver), read by the link pass.
    pub board: BoardHealth,
    /// Commands for the control step: pushed by the link pass, taken by the next tick.
    pub commands: ControlQueue,
    /// Work for the background task: pushed by the link pass, taken by its next run.
    pub work: WorkQueue,
    /// The compass calibration's solves: what the compass service gathered, copied in by the
    /// link task, solved by the background task, the outcome copied back
    /// (`super::compass::run_compass_solve`).
    pub compass: CompassSolveSlot,
}

impl Handoffs {
    /// The handoffs at start-up.
    pub fn new(snapshot: ControlSnapshot, results: BackgroundResults, board: BoardHealth) -> Self {
        Self {
            snapshot,
            results,
            board,
            commands: ControlQueue::new(),
            work: WorkQueue::new(),
            compass: CompassSolveSlot::new(),
        }
    }
}

/// Put `command` on the control step's queue. A disarm replaces whatever still waits, so it
/// always finds room and nothing queued before it runs after it. Returns false when the queue
/// was full and the command was dropped.
pub fn queue_command(queue: &mut ControlQueue, command: ControlCommand) -> bool {
    if command == ControlCommand::Disarm {
        queue.clear();
    }
    queue.push_back(command).is_ok()
}

/// The control task's own state: the control loop, the pilot's radio (the receiver's policy)
/// and what the tick remembers between steps.
pub struct ControlTask<'q> {
    control: ControlLoop<'q>,
    radio: Option<Receiver>,
    craft: CraftState,
    ticks: u32,
    dropped_commands: u32,
    /// The flight log's ring (`super::log`), when the board logs.
    log: Option<LogProducer<'q>>,
    /// The flight battery, from the board's readings.
    battery: BatteryMonitor,
    /// Whether it has stayed below `land_cell_v`, and whether this flight was told to land
    /// for it.
    low_battery: LowBattery,
    landing_for_battery: bool,
}

/// The IMU as the tick hands it to the step, remembering what it delivered (for the log).
struct TapImu<'a, I> {
    imu: &'a mut I,
    read: Option<ImuSample>,
}

impl<I: Imu> Imu for TapImu<'_, I> {
    fn read(&mut self) -> Option<ImuSample> {
        self.read = self.imu.read();
        self.read
    }
}

/// What a tick asks of the board afterwards.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickOutcome {
    /// Learner samples or log entries wait: run the background task (the board spawns it).
    pub background_due: bool,
    /// A link pass is due (every [`LINK_PASS_TICKS`] ticks; the board pends the USB task).
    pub link_due: bool,
}

/// The board's parts a tick drives: the IMU, the motor outputs, the pilot's receiver UART and
/// the battery's sensor.
pub struct TickHardware<'a, I, M, RS, BS> {
    pub imu: &'a mut I,
    pub motors: &'a mut M,
    pub radio_bytes: &'a mut RS,
    pub battery: &'a mut BS,
}

/// The locks a tick takes, each for a copy or a queue operation.
pub struct TickShared<C, R, S, B> {
    pub commands: C,
    pub results: R,
    pub snapshot: S,
    pub board: B,
}

impl<'q> ControlTask<'q> {
    /// The control task around `control`; `radio` is the pilot's receiver policy when the board
    /// has a receiver port (`None`: no radio, the craft is commanded over the links only).
    pub fn new(control: ControlLoop<'q>, radio: Option<Receiver>) -> Self {
        Self {
            control,
            radio,
            craft: CraftState { armed: false, in_flight: false },
            ticks: 0,
            dropped_commands: 0,
            log: None,
            battery: BatteryMonitor::new(),
            low_battery: LowBattery::default(),
            landing_for_battery: false,
        }
    }

    /// Hand every step's inputs and outputs, and every command applied, to the flight log
    /// through `ring` (one fixed-layout copy per step; a full ring drops the entry, counted).
    pub fn with_log(mut self, ring: LogProducer<'q>) -> Self {
        self.set_log(ring);
        self
    }

    /// Log to `ring` from now on, where the task lies (a board builds it in place).
    pub fn set_log(&mut self, ring: LogProducer<'q>) {
        self.log = Some(ring);
    }

    /// The control loop (for inspection; commands go through the queue).
    pub fn control(&self) -> &ControlLoop<'q> {
        &self.control
    }

    /// The control loop, mutably: for a scenario that sets the loop up before its first tick.
    pub fn control_mut(&mut self) -> &mut ControlLoop<'q> {
        &mut self.control
    }

    /// Commands dropped because the queue was full, since start-up.
    pub fn dropped_commands(&self) -> u32 {
        self.dropped_commands
    }

    /// One control tick at `now_us` (µs since start-up, monotonic). Never blocks, never
    /// allocates; every lock is held for a copy or a queue operation.
    ///
    /// Order: the link's commands (oldest first), then the radio's (a kill switch's disarm is the
    /// last word, applied in this very step), the background's results, the step, the battery's
    /// reading, the snapshot.
    pub fn tick<I, M, RS, BS, C, R, S, B>(
        &mut self,
        now_us: u64,
        hardware: TickHardware<'_, I, M, RS, BS>,
        shared: &mut TickShared<C, R, S, B>,
    ) -> TickOutcome
    where
        I: Imu,
        M: Motors,
        RS: Uart,
        BS: BatterySensor,
        C: Mutex<T = ControlQueue>,
        R: Mutex<T = BackgroundResults>,
        S: Mutex<T = ControlSnapshot>,
        B: Mutex<T = BoardHealth>,
    {
        let TickHardware { imu, motors, radio_bytes, battery } = hardware;
        let control = &mut self.control;
        let log = &mut self.log;
        // The step these commands are applied before.
        let step = control.steps().wrapping_add(1);
        shared.commands.lock(|queue| {
            while let Some(command) = queue.pop_front() {
                apply_logged(control, log, step, command, now_us);
            }
        });
        if let Some(radio) = &mut self.radio {
            let mut chunk = [0u8; RADIO_CHUNK_BYTES];
            let count = radio_bytes.read(&mut chunk).min(RADIO_CHUNK_BYTES);
            let settings = control.settings();
            radio.set_stick_channels(settings.stick_map, settings.mode_channel);
            let switches = radio.poll(&chunk[..count], now_us, self.craft);
            for command in [switches, radio.take_sticks(now_us)].into_iter().flatten() {
                apply_logged(control, log, step, command, now_us);
            }
        }
        // The one handoff from the background task: logged with the step (the samples its
        // results were computed from), so a replay adopts the same results at the same step.
        let adopted = shared
            .results
            .lock(|results| control.receive(results).then_some(results.samples_processed));
        // The outputs learn a disarm before this step's frames (a kill switch stops the motors
        // in this very step), and an arming before its commands.
        motors.set_armed(control.armed());
        let mut imu = TapImu { imu, read: None };
        let mut background_due = control.step(now_us, &mut imu, motors);
        if let Some(reading) = battery.read() {
            self.battery.update(now_us, reading);
        }
        let battery_status = self.battery.status();
        // An empty pack lands a flight (once per flight; logged, so a replay lands too).
        let land_cell_v = control.settings().land_cell_v;
        let low = self.low_battery.update(battery_status.as_ref(), land_cell_v, now_us);
        if !self.craft.in_flight {
            self.landing_for_battery = false;
        } else if low && !self.landing_for_battery {
            self.landing_for_battery = true;
            let command = ControlCommand::Land(protocol::LandReason::BatteryLow);
            if let Some(log) = log.as_mut() {
                log.push(LogEntry::Command { step: step.wrapping_add(1), command });
            }
            control.command(command, now_us);
        }
        let snapshot = ControlSnapshot { battery: battery_status, ..control.snapshot() };
        if let Some(log) = log.as_mut() {
            log.push(LogEntry::Step(StepEntry {
                step: snapshot.steps,
                t_us: now_us,
                imu: imu.read,
                motor_count: snapshot.motor_count,
                speeds_rad_s: snapshot.speeds_rad_s,
                commands: snapshot.commands,
                phase: snapshot.phase,
                failed: snapshot.failure != protocol::LearnerFailure::None,
                flying: snapshot.pilot.flying,
                armed: snapshot.armed,
                ring_dropped: log.dropped(),
                adopted: adopted.map(|samples_processed| Adoption {
                    samples_processed,
                    samples_dropped: snapshot.samples_dropped,
                }),
            }));
            background_due |= log.has_waiting();
        }
        motors.set_armed(snapshot.armed);
        self.craft = CraftState {
            armed: snapshot.armed,
            in_flight: snapshot.pilot.flying
                || matches!(snapshot.phase, FlightPhase::Released | FlightPhase::Exciting),
        };
        shared.snapshot.lock(|shared| *shared = snapshot);
        if let Some(radio) = &mut self.radio {
            // One telemetry frame to the pilot's handset per RC frame received.
            let mut frame = [0u8; crate::drivers::crsf::FRAME_MAX];
            if let Some(n) = radio.telemetry_frame(&snapshot, &mut frame) {
                let _ = radio_bytes.write(&frame[..n]);
            }
        }
        self.ticks = self.ticks.wrapping_add(1);
        let link_due = self.ticks.is_multiple_of(LINK_PASS_TICKS);
        if link_due {
            let motor_health = motors.health();
            let radio_health = self.radio.as_ref().map(|radio| radio.health(now_us));
            shared.board.lock(|board| {
                if motor_health.is_some() {
                    board.motors = motor_health;
                }
                if radio_health.is_some() {
                    board.receiver = radio_health;
                }
            });
        }
        TickOutcome { background_due, link_due }
    }
}

/// Apply `command` before `step`, logged first. Before an arming of a disarmed craft the log is
/// offered the loop's state as it stands (a file that begins with this command records it, so
/// its replay starts from the board's state, not a fresh one).
fn apply_logged(
    control: &mut ControlLoop<'_>,
    log: &mut Option<LogProducer<'_>>,
    step: u32,
    command: ControlCommand,
    now_us: u64,
) {
    if let Some(log) = log.as_mut() {
        if super::log::is_arming(&command) && !control.armed() {
            let tag = ArmingTag { step, samples_before: control.samples_handed() };
            log.offer_arming(tag, control.state());
        }
        log.push(LogEntry::Command { step, command });
    }
    control.command(command, now_us);
}

/// One host link: its protocol endpoint and its byte port.
pub struct Link<P> {
    pub server: LinkServer,
    pub port: P,
    open: bool,
}

impl<P: Port> Link<P> {
    /// A link answering as `server` over `port`.
    pub fn new(server: LinkServer, port: P) -> Self {
        Self { server, port, open: true }
    }

    /// False once its port has closed (the host went away); the pass has then stopped what the
    /// host started (a motor test).
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// Offer the transmit buffer to the port until it takes no more; a closed port closes the
    /// link.
    pub fn transmit(&mut self) {
        if !self.open {
            return;
        }
        let port = &mut self.port;
        let mut closed = false;
        while self.server.transmit_to(|bytes| match port.write(bytes) {
            Ok(taken) => taken,
            Err(PortClosed) => {
                closed = true;
                0
            }
        }) > 0
        {}
        self.port.flush();
        if closed {
            self.close();
        }
    }

    fn close(&mut self) {
        if self.open {
            self.open = false;
            self.server.disconnected();
        }
    }
}

/// The set of links a pass serves: one USB port on the board; a pseudo-terminal and any number
/// of TCP clients in the SITL.
pub trait Links {
    /// Call `f` with every link, open or closed (a closed one still hands over its last
    /// requests).
    fn each(&mut self, f: &mut dyn FnMut(&mut dyn LinkEnd));
}

/// One link as the pass sees it (object-safe, so links over different ports serve together).
pub trait LinkEnd {
    fn server(&mut self) -> &mut LinkServer;
    /// Read what the host sent into `chunk`: the bytes read, 0 when none wait or the link is
    /// closed (a port found closed closes the link).
    fn read_into(&mut self, chunk: &mut [u8]) -> usize;
    fn transmit(&mut self);
}

/// The flight log's files as the link pass reaches them: each call takes the lock the
/// background task writes under (`PassShared::logs`) for that one bounded operation.
struct LockedLogFiles<'a, L>(&'a mut L);

impl<L: Mutex<T = T>, T: LogFiles> LogFiles for LockedLogFiles<'_, L> {
    fn list(&mut self, first: u32, out: &mut LogFileList) -> Result<bool, LogFileError> {
        self.0.lock(|files| files.list(first, out))
    }
    fn read(&mut self, number: u32, offset: u32, buf: &mut [u8]) -> Result<FileRead, LogFileError> {
        self.0.lock(|files| files.read(number, offset, buf))
    }
    fn delete(&mut self, number: u32) -> Result<(), LogFileError> {
        self.0.lock(|files| files.delete(number))
    }
    fn snapshot(&mut self, now_us: u64, view: &StatusView) {
        self.0.lock(|files| files.snapshot(now_us, view));
    }
}

impl<P: Port> LinkEnd for Link<P> {
    fn server(&mut self) -> &mut LinkServer {
        &mut self.server
    }

    fn read_into(&mut self, chunk: &mut [u8]) -> usize {
        if !self.open {
            return 0;
        }
        match self.port.read(chunk) {
            Ok(count) => count.min(chunk.len()),
            Err(PortClosed) => {
                self.close();
                0
            }
        }
    }

    fn transmit(&mut self) {
        Link::transmit(self);
    }
}

impl<P: Port> Links for Link<P> {
    fn each(&mut self, f: &mut dyn FnMut(&mut dyn LinkEnd)) {
        f(self);
    }
}

impl<P: Port> Links for [Link<P>] {
    fn each(&mut self, f: &mut dyn FnMut(&mut dyn LinkEnd)) {
        for link in self {
            f(link);
        }
    }
}

impl<L: Links + ?Sized> Links for &mut L {
    fn each(&mut self, f: &mut dyn FnMut(&mut dyn LinkEnd)) {
        (**self).each(f);
    }
}

impl<L: Links> Links for Option<L> {
    fn each(&mut self, f: &mut dyn FnMut(&mut dyn LinkEnd)) {
        if let Some(links) = self {
            links.each(f);
        }
    }
}

impl<A: Links, B: Links> Links for (A, B) {
    fn each(&mut self, f: &mut dyn FnMut(&mut dyn LinkEnd)) {
        self.0.each(f);
        self.1.each(f);
    }
}

/// No links at all (a scenario, or the bridge without a TCP port).
pub struct NoLinks;

impl Links for NoLinks {
    fn each(&mut self, _f: &mut dyn FnMut(&mut dyn LinkEnd)) {}
}

/// A restart a host asked for; the board carries it out once the reply has gone out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Restart {
    /// Start the firmware again.
    Reboot,
    /// Start the ROM bootloader (USB DFU).
    Bootloader,
}

/// What a link pass asks of the board afterwards.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PassOutcome {
    /// Work waits for the background task (the board spawns it).
    pub background_due: bool,
    /// A host asked for a restart (the links refuse it while anything is armed).
    pub restart: Option<Restart>,
}

/// The locks a link pass takes.
pub struct PassShared<S, R, B, C, W, L> {
    pub snapshot: S,
    pub results: R,
    pub board: B,
    pub commands: C,
    pub work: W,
    /// The flight log's storage ([`LogFiles`]), shared with the background task that writes
    /// through it: locked per request (one listing, one chunk of at most
    /// [`protocol::LOG_CHUNK_LEN`] bytes, one delete), never for a whole pass. A board without
    /// log storage passes [`super::log::NoCard`].
    pub logs: L,
}

/// The link task's own state: the parameters and their store, its end of the telemetry ring,
/// and the GNSS receiver's driver on a board with a GNSS port (serviced with the links: its
/// solutions come at 5–10 Hz, a link pass runs at 1 kHz).
pub struct LinkTask<'q, F: NorFlash> {
    settings: Settings<F>,
    telemetry: StepConsumer<'q>,
    dropped_work: u32,
    /// The GNSS receiver's driver (about 1 KB: on the board a static of its own, so `init`
    /// never copies it; in a [`System`] a local of [`with_system`]).
    gnss: Option<&'q mut GnssInput>,
    /// Position fixes dropped because the control queue was full, since start-up.
    dropped_fixes: u32,
    /// The compass service (about 8 KB with its calibration's store: on the board a static of
    /// its own, like the GNSS driver).
    compass: Option<&'q mut CompassInput>,
    /// Magnetic samples dropped because the control queue was full, since start-up.
    dropped_magnetic: u32,
}

impl<'q, F: NorFlash> LinkTask<'q, F> {
    pub fn new(settings: Settings<F>, telemetry: StepConsumer<'q>) -> Self {
        Self {
            settings,
            telemetry,
            dropped_work: 0,
            gnss: None,
            dropped_fixes: 0,
            compass: None,
            dropped_magnetic: 0,
        }
    }

    /// Drive a compass ([`Self::service_compass`]) with `compass`.
    pub fn with_compass(mut self, compass: &'q mut CompassInput) -> Self {
        self.set_compass(compass);
        self
    }

    /// [`Self::with_compass`] in place.
    pub fn set_compass(&mut self, compass: &'q mut CompassInput) {
        self.compass = Some(compass);
    }

    /// The compass service, when there is one.
    pub fn compass(&self) -> Option<&CompassInput> {
        self.compass.as_deref()
    }

    /// The compass service, mutably: for a simulator or a test that drives the calibration
    /// without a link (a link's request goes through [`Self::pass`]).
    pub fn compass_mut(&mut self) -> Option<&mut CompassInput> {
        self.compass.as_deref_mut()
    }

    /// Magnetic samples dropped because the control queue was full, since start-up.
    pub fn dropped_magnetic(&self) -> u32 {
        self.dropped_magnetic
    }

    /// Service the compass on `bus` at `now_us` (`CompassInput::service`), with the parameters
    /// in force and the attitude filter's latest quaternion from `snapshot`: a calibrated
    /// field goes to the control step's queue as [`ControlCommand::MagneticField`]; then the
    /// calibration's exchange with the background task through `solve`, and a solved
    /// calibration stored in the parameters (saved by `save`). Returns whether a solve waits
    /// for the background task (the board runs it). Call it from a low-priority context, at
    /// least at the sensor's 100 Hz (the board: every link pass; it reads when due).
    #[allow(clippy::too_many_arguments)]
    pub fn service_compass<B, D, C, S, K>(
        &mut self,
        now_us: u64,
        bus: &mut B,
        delay: &mut D,
        commands: &mut C,
        snapshot: &mut S,
        solve: &mut K,
    ) -> bool
    where
        B: I2cRegisterBus,
        D: DelayUs,
        C: Mutex<T = ControlQueue>,
        S: Mutex<T = ControlSnapshot>,
        K: Mutex<T = CompassSolveSlot>,
    {
        let Some(compass) = self.compass.as_mut() else { return false };
        let params = self.settings.params();
        compass.configure(params.compass_calibration(), params.compass_enabled());
        let (q_world_imu, armed) =
            snapshot.lock(|snapshot| (snapshot.pilot.q_world_imu, snapshot.armed));
        compass.set_attitude(Some(q_world_imu));
        compass.set_armed(armed);
        if let Some(sample) = compass.service(now_us, bus, delay) {
            let command = ControlCommand::MagneticField(sample);
            if !commands.lock(|queue| queue_command(queue, command)) {
                self.dropped_magnetic = self.dropped_magnetic.wrapping_add(1);
            }
        }
        let due = compass.exchange(now_us, solve);
        if let Some(solved) = compass.take_solved() {
            self.settings.update(|params| params.store_compass_calibration(&solved.calibration));
            // In force at once, as stored (clamped into the parameters' ranges).
            let params = self.settings.params();
            compass.configure(params.compass_calibration(), params.compass_enabled());
        }
        due
    }

    /// Drive a GNSS receiver ([`Self::service_gnss`]) with `gnss` (made from the parameters at
    /// start-up: `Params::gnss_config`, `gnss_baud` and `gnss_rate_hz`).
    pub fn with_gnss(mut self, gnss: &'q mut GnssInput) -> Self {
        self.gnss = Some(gnss);
        self
    }

    /// The GNSS receiver's driver, when there is one.
    pub fn gnss(&self) -> Option<&GnssInput> {
        self.gnss.as_deref()
    }

    /// Position fixes dropped because the control queue was full, since start-up.
    pub fn dropped_fixes(&self) -> u32 {
        self.dropped_fixes
    }

    /// Service the GNSS receiver through `port` at `now_us` (`GnssInput::service`): a new
    /// position fix goes to the control step's queue, like a pose from a link. Call it at
    /// least as often as the port's receive buffer fills (the board: every link pass).
    pub fn service_gnss<P: GnssPort, C: Mutex<T = ControlQueue>>(
        &mut self,
        now_us: u64,
        port: &mut P,
        commands: &mut C,
    ) {
        let Some(gnss) = self.gnss.as_mut() else { return };
        gnss.set_latency_s(self.settings.params().gnss_latency_s());
        if let Some(fix) = gnss.service(port, now_us) {
            let command = ControlCommand::PositionFix(fix);
            if !commands.lock(|queue| queue_command(queue, command)) {
                self.dropped_fixes = self.dropped_fixes.wrapping_add(1);
            }
        }
    }

    /// The parameters in force and their store.
    pub fn settings(&self) -> &Settings<F> {
        &self.settings
    }

    /// The parameters, mutably: for a start-up that puts a command-line value in force.
    pub fn settings_mut(&mut self) -> &mut Settings<F> {
        &mut self.settings
    }

    /// Give the settings (and their flash) back.
    pub fn into_settings(self) -> Settings<F> {
        self.settings
    }

    /// The oldest step record waiting in the telemetry ring (a host tool reading every step
    /// instead of the link pass; what it takes is not streamed).
    pub fn take_record(&mut self) -> Option<super::StepRecord> {
        self.telemetry.pop()
    }

    /// Work for the background task dropped because its queue was full, since start-up.
    pub fn dropped_work(&self) -> u32 {
        self.dropped_work
    }

    /// One link pass at `now_us`: every link's received bytes answered (parameter requests read
    /// and change the settings, a save writes its flash), what the hosts asked of the other
    /// tasks routed to their queues, a changed configuration sent to both tasks, every step
    /// record streamed to every link, the sampled topics and events polled, and everything
    /// offered to the ports. Never blocks, except a configuration save (a flash erase).
    pub fn pass<S, R, B, C, W, L, LT>(
        &mut self,
        now_us: u64,
        links: &mut dyn Links,
        step_time: Option<StepTime>,
        shared: &mut PassShared<S, R, B, C, W, L>,
    ) -> PassOutcome
    where
        S: Mutex<T = ControlSnapshot>,
        R: Mutex<T = BackgroundResults>,
        B: Mutex<T = BoardHealth>,
        C: Mutex<T = ControlQueue>,
        W: Mutex<T = WorkQueue>,
        L: Mutex<T = LT>,
        LT: LogFiles,
    {
        let view = StatusView {
            control: shared.snapshot.lock(|snapshot| *snapshot),
            background: shared.results.lock(|results| *results),
            step_time,
            board: shared.board.lock(|board| *board),
            gnss: self.gnss.as_deref().map(GnssInput::health),
            compass: self.compass.as_deref().map(CompassInput::health),
        };
        let settings = &mut self.settings;
        // Erased here: the server's request handling, inlined into this pass, would otherwise be
        // compiled with the lock's calls inlined into it too (about 550 B more flash).
        let logs: &mut dyn LogFiles = &mut LockedLogFiles(&mut shared.logs);
        links.each(&mut |link| {
            let mut chunk = [0u8; READ_CHUNK_BYTES];
            for _ in 0..READS_PER_PASS {
                let count = link.read_into(&mut chunk);
                if count == 0 {
                    break;
                }
                link.server().receive(&chunk[..count], now_us, &view, settings, logs);
            }
        });
        logs.snapshot(now_us, &view);

        let mut outcome = PassOutcome::default();
        let mut compass_command = None;
        let mut work = heapless::Vec::<BackgroundWork, WORK_QUEUE_LEN>::new();
        let mut dropped_work = 0u32;
        let mut push_work = |item: BackgroundWork, work: &mut heapless::Vec<_, WORK_QUEUE_LEN>| {
            if work.push(item).is_err() {
                dropped_work += 1;
            }
        };
        shared.commands.lock(|commands| {
            links.each(&mut |link| {
                while let Some(request) = link.server().take_request() {
                    match request {
                        LinkRequest::Control(command) => {
                            let _ = queue_command(commands, command);
                        }
                        LinkRequest::Background(command) => {
                            push_work(BackgroundWork::Command(command), &mut work);
                        }
                        LinkRequest::Reboot => outcome.restart = Some(Restart::Reboot),
                        LinkRequest::RebootToBootloader => {
                            outcome.restart = Some(Restart::Bootloader);
                        }
                        LinkRequest::Compass(command) => compass_command = Some(command),
                    }
                }
            });
            if let Some(params) = settings.service(&view) {
                let _ = queue_command(
                    commands,
                    ControlCommand::Configure(ControlSettings::from(&params)),
                );
                push_work(BackgroundWork::Configure(params), &mut work);
            }
        });
        self.dropped_work = self.dropped_work.wrapping_add(dropped_work);
        if let (Some(command), Some(compass)) = (compass_command, self.compass.as_mut()) {
            compass.command(command, now_us);
        }
        if !work.is_empty() {
            shared.work.lock(|queue| {
                for item in work {
                    if queue.push_back(item).is_err() {
                        self.dropped_work = self.dropped_work.wrapping_add(1);
                    }
                }
            });
            outcome.background_due = true;
        }
        // Every step's record, offered to every link at once so no transmit buffer holds more
        // than a few frames; what a port does not take is dropped whole (a counted gap).
        while let Some(record) = self.telemetry.pop() {
            links.each(&mut |link| {
                link.server().stream(&record);
                link.transmit();
            });
        }
        links.each(&mut |link| {
            link.server().poll(now_us, &view);
            link.transmit();
        });
        outcome
    }
}

/// The background task's run: the work the links sent (oldest first, each logged with the
/// learner samples processed before it), the flight log's waiting entries to its sink (when the
/// board logs), then every waiting learner sample, then the results published (a copy under a
/// short lock).
///
/// The log is locked per entry (and per piece of work): the link task, which reads the log's
/// files under the same lock, waits at most for one entry's encoding and one block write.
pub fn run_background<'l, W, R, L>(
    worker: &mut Background<'_>,
    mut log: Option<&mut L>,
    work: &mut W,
    results: &mut R,
) where
    W: Mutex<T = WorkQueue>,
    R: Mutex<T = BackgroundResults>,
    L: Mutex<T = Logger<'l>>,
{
    // The work first: a parameter change reaches the control step as a command in the same
    // link pass, and the tick may have applied (and logged) it already; taken first, the new
    // parameters are in the file before that command, which names them.
    while let Some(item) = work.lock(|queue| queue.pop_front()) {
        if let Some(log) = log.as_deref_mut() {
            let samples_processed = worker.results_ref().samples_processed;
            log.lock(|log| log.work(&item, samples_processed));
        }
        match item {
            BackgroundWork::Command(command) => worker.command(command),
            BackgroundWork::Configure(params) => worker.configure(&params),
        }
    }
    if let Some(log) = log {
        while log.lock(|log| log.drain_one()) {}
    }
    worker.run_pending();
    let published = worker.results_ref();
    results.lock(|shared| *shared = *published);
}

/// The whole graph on one thread (the simulators, the scenarios, host tests): the three tasks
/// and their handoffs, run in the board's order by whoever drives the time line.
pub struct System<'q, F: NorFlash> {
    pub control: ControlTask<'q>,
    pub link: LinkTask<'q, F>,
    pub background: Background<'q>,
    /// The in-flight IMU-offset fit's task, run after the background task as the board's
    /// `idle` runs it (`super::offset_fit`).
    pub offset_fit: OffsetFitWorker<'q>,
    pub handoffs: Handoffs,
    /// The flight log's writer, run with the background task (`None`: no log).
    pub log: Option<Logger<'q>>,
    /// The compass calibration's solver, run with the background task.
    pub compass_solver: CompassSolver,
}

impl<'q, F: NorFlash> System<'q, F> {
    /// A control tick (see [`ControlTask::tick`]); when it queued learner samples, the background
    /// task runs to completion right after, as the board's lowest-priority task does when it
    /// has time to spare before the next tick.
    pub fn tick<I: Imu, M: Motors, RS: Uart, BS: BatterySensor>(
        &mut self,
        now_us: u64,
        hardware: TickHardware<'_, I, M, RS, BS>,
    ) -> TickOutcome {
        let outcome = self.tick_alone(now_us, hardware);
        if outcome.background_due {
            self.run_background();
        }
        outcome
    }

    /// The control tick alone: the background task does not run after it (a test that makes it
    /// lag, as the board's may).
    pub fn tick_alone<I: Imu, M: Motors, RS: Uart, BS: BatterySensor>(
        &mut self,
        now_us: u64,
        hardware: TickHardware<'_, I, M, RS, BS>,
    ) -> TickOutcome {
        let handoffs = &mut self.handoffs;
        let mut shared = TickShared {
            commands: Exclusive(&mut handoffs.commands),
            results: Exclusive(&mut handoffs.results),
            snapshot: Exclusive(&mut handoffs.snapshot),
            board: Exclusive(&mut handoffs.board),
        };
        self.control.tick(now_us, hardware, &mut shared)
    }

    /// A link pass (see [`LinkTask::pass`]); work it queued for the background task runs at
    /// once.
    pub fn pass(&mut self, now_us: u64, links: &mut dyn Links) -> PassOutcome {
        let outcome = self.pass_alone(now_us, links);
        if outcome.background_due {
            self.run_background();
        }
        outcome
    }

    /// The link pass alone: the work it queues waits for the background task.
    pub fn pass_alone(&mut self, now_us: u64, links: &mut dyn Links) -> PassOutcome {
        let handoffs = &mut self.handoffs;
        let mut shared = PassShared {
            snapshot: Exclusive(&mut handoffs.snapshot),
            results: Exclusive(&mut handoffs.results),
            board: Exclusive(&mut handoffs.board),
            commands: Exclusive(&mut handoffs.commands),
            work: Exclusive(&mut handoffs.work),
            logs: Exclusive(&mut self.log),
        };
        self.link.pass(now_us, links, None, &mut shared)
    }

    /// The background task's run (see [`run_background`]).
    pub fn run_background(&mut self) {
        loop {
            self.run_background_alone();
            // Then the fit, as `idle` does between the tasks' runs; and the background task
            // again if its samples waited for the fit (a slow board's case: here the fit
            // keeps up with each tick).
            let fitted = self.offset_fit.run_pending();
            if fitted == 0 || !self.background.has_waiting_samples() {
                break;
            }
        }
    }

    /// The background task's run alone: the in-flight IMU-offset fit's task does not run after
    /// it (a test that makes it lag, as the board's `idle` may).
    pub fn run_background_alone(&mut self) {
        let handoffs = &mut self.handoffs;
        run_background(
            &mut self.background,
            self.log.as_mut().map(Exclusive).as_mut(),
            &mut Exclusive(&mut handoffs.work),
            &mut Exclusive(&mut handoffs.results),
        );
        run_compass_solve(&mut self.compass_solver, &mut Exclusive(&mut handoffs.compass));
    }

    /// End the flight log's file in order (what waits is written first): the application
    /// stops. Nothing happens without a log.
    pub fn finish_log(&mut self) {
        if let Some(log) = &mut self.log {
            log.finish();
        }
    }

    /// Change the parameters before anything runs (a simulator's command-line option): in the
    /// link's settings, so `status` and `get` show them, and handed to the control step and the
    /// background task through their queues now rather than at the first link pass, so that
    /// an arm request queued after this finds them in force (the control step takes new
    /// settings only while disarmed).
    pub fn configure(&mut self, change: impl FnOnce(&mut Params)) {
        let settings = self.link.settings_mut();
        settings.update(change);
        let params = *settings.params();
        self.submit(ControlCommand::Configure(ControlSettings::from(&params)));
        if self.handoffs.work.push_back(BackgroundWork::Configure(params)).is_err() {
            self.link.dropped_work = self.link.dropped_work.wrapping_add(1);
        }
        self.run_background();
    }

    /// Queue a command for the next tick, as a link pass would (a scenario's arm, a simulated
    /// motion-capture pose). Returns false when the queue was full and it was dropped.
    pub fn submit(&mut self, command: ControlCommand) -> bool {
        queue_command(&mut self.handoffs.commands, command)
    }

    /// Service the GNSS receiver on `port` at `now_us`, as the board's link task does after
    /// each pass ([`LinkTask::service_gnss`]): its new fix waits in the control queue.
    pub fn service_gnss<P: GnssPort>(&mut self, now_us: u64, port: &mut P) {
        let mut commands = Exclusive(&mut self.handoffs.commands);
        self.link.service_gnss(now_us, port, &mut commands);
    }

    /// Service the compass on `bus` at `now_us`, as the board's link task does after each pass
    /// ([`LinkTask::service_compass`]): its new sample waits in the control queue; a solve it
    /// asks for runs at once, as the board's background task would.
    pub fn service_compass<B: I2cRegisterBus, D: DelayUs>(
        &mut self,
        now_us: u64,
        bus: &mut B,
        delay: &mut D,
    ) {
        let handoffs = &mut self.handoffs;
        let due = self.link.service_compass(
            now_us,
            bus,
            delay,
            &mut Exclusive(&mut handoffs.commands),
            &mut Exclusive(&mut handoffs.snapshot),
            &mut Exclusive(&mut handoffs.compass),
        );
        if due {
            self.run_background();
        }
    }

    /// The control step's latest snapshot.
    pub fn snapshot(&self) -> ControlSnapshot {
        self.control.control().snapshot()
    }

    /// What a link would answer from now (no step-time measurement on a host).
    pub fn status_view(&self) -> StatusView {
        StatusView {
            control: self.handoffs.snapshot,
            background: self.handoffs.results,
            step_time: None,
            board: self.handoffs.board,
            gnss: self.link.gnss().map(GnssInput::health),
            compass: self.link.compass().map(CompassInput::health),
        }
    }
}

/// Runs `f` with a fresh [`System`]: the default control configuration, `settings` (handed to
/// the tasks at the first link pass, as at a board's start-up), `board` as the drivers' health,
/// and `radio` as the pilot's receiver policy. The queues live for the call; the settings (and
/// their flash) are given back with `f`'s result.
pub fn with_system<F: NorFlash, R>(
    settings: Settings<F>,
    board: BoardHealth,
    radio: Option<Receiver>,
    f: impl FnOnce(&mut System<'_, F>) -> R,
) -> (R, Settings<F>) {
    with_logged_system(settings, board, radio, None, f)
}

/// Where a [`System`] logs: the sink, and the board's name for the files' header.
pub struct LogTarget<'s> {
    pub sink: &'s mut dyn LogSink,
    pub board: &'static str,
}

/// [`with_system`] with a flight log written to `log` (`None`: no log). The caller ends the
/// file with [`System::finish_log`] when the run ends in order.
pub fn with_logged_system<F: NorFlash, R>(
    settings: Settings<F>,
    board: BoardHealth,
    radio: Option<Receiver>,
    log: Option<LogTarget<'_>>,
    f: impl FnOnce(&mut System<'_, F>) -> R,
) -> (R, Settings<F>) {
    // The simulated board has a GNSS port, as the board does: its driver from the parameters
    // at start-up, serviced by [`System::service_gnss`] when a receiver is simulated.
    let mut gnss =
        GnssInput::new(settings.params().gnss_config(), settings.params().gnss_latency_s());
    // And a compass bus, serviced by [`System::service_compass`] when a sensor is simulated.
    let mut compass = CompassInput::new();
    let mut log_ring = super::log::LogRing::new();
    let mut arming = super::log::ArmingBox::new();
    let (log_producer, log_consumer) = super::log::split_log(&mut log_ring, &mut arming);
    let mut samples = super::SampleQueue::new();
    let (producer, consumer) = super::split_queue(&mut samples);
    let mut ring = super::StepRing::new();
    let (ring_producer, ring_consumer) = super::split_queue(&mut ring);
    let config = super::ControlConfig::default();
    let control = ControlLoop::new(config, producer).with_telemetry(ring_producer);
    let mut fit_handoff = FitHandoff::new();
    let (fit_client, fit_ends) = fit_handoff.split(f32::from(config.rate_hz));
    let offset_fit = OffsetFitWorker::new(fit_ends);
    let background = Background::new(consumer, fit_client, config.rate_hz);
    let handoffs = Handoffs::new(control.snapshot(), background.results(), board);
    let control = ControlTask::new(control, radio);
    let (control, log) = match log {
        Some(target) => (
            control.with_log(log_producer),
            Some(
                Logger::new(log_consumer, target.sink, target.board, config.rate_hz)
                    .with_params(settings.params()),
            ),
        ),
        None => (control, None),
    };
    let link =
        LinkTask::new(settings, ring_consumer).with_gnss(&mut gnss).with_compass(&mut compass);
    let compass_solver = CompassSolver::new();
    let mut system =
        System { control, link, background, offset_fit, handoffs, log, compass_solver };
    let result = f(&mut system);
    (result, system.link.into_settings())
}
