//! `configurator-cli replay LOG`: a flight log (`firmware::app::log`) fed back through a fresh
//! `firmware::app` application graph, step by step, and every command it writes compared with
//! the logged one.
//!
//! The replay is the board's own code in lockstep with the log: each logged step's IMU sample
//! (as the driver delivered it, NaN bits and all) and motor speeds are what a replay IMU and
//! replay motor outputs return to the control tick; each logged command goes into the control
//! queue before the step it was applied at.
//!
//! The background task's side (format 4, a log from start-up): the replay reads the whole log
//! first, so it knows every handoff the board made. Its background task takes the learner
//! samples its control step produces one at a time; each piece of work (parameters, calibration)
//! goes to it between the same two samples as on the board (the samples processed are logged
//! with the work), and the results it had after each sample count the board's control step
//! adopted are kept. Before each step the control step is handed the results the board's
//! adopted at that step (logged with the step), and otherwise keeps what it has. So the replay
//! does not depend on when the board's (or the SITL's) background task ran: a log from
//! start-up replays bit for bit whatever the airframe, the arming and the tasks' timing, unless
//! the board's control step dropped learner samples (a full queue; noted).
//!
//! A format 1–3 log (no adoptions recorded), and a log that begins at an arming (the board's
//! sample count there is not known), are replayed as the SITL runs the application: the
//! background task runs to completion after every step, and work goes to it after the step it
//! was taken after. Such a replay is exact only where the board's background task kept up as
//! the SITL's does; a log that begins at an arming also starts from a fresh state.
//!
//! With `--set NAME=VALUE` the parameter sets in the log are changed before they are applied,
//! and the replay reports where the outcome departs from the log: the first step whose
//! commands differ, the phase times, and the learned model against the unchanged replay's.
//! (Parameters the identification stored during the flight are the original run's.)

use super::InputError;
use firmware::app::hal::{Imu, ImuSample, Motors, NoBattery, NoBytes, MAX_MOTORS};
use firmware::app::log::{
    phase_code, phase_from_code, ArmingRecord, ArmingTag, Header, LogReader, LogRecord,
    LoggedCommand, LoggedWork, ParamsAssembler, ReadStats, StepLogRecord, LOG_FORMAT_VERSION,
};
use firmware::app::offset_fit::OffsetFitWorker;
use firmware::app::params::{find, Params, LAYOUT_HASH, SPECS};
use firmware::app::system::{with_system, BackgroundWork, Exclusive, TickHardware, TickShared};
use firmware::app::{
    Background, BackgroundCommand, BackgroundResults, ControlSnapshot, ControlState, NoFlash,
    Settings,
};
use flight::learner::{FlightPhase, LearnedModel};
use serde_json::{json, Value};
use std::collections::{BTreeSet, HashMap, VecDeque};
use std::path::{Path, PathBuf};

/// `replay` arguments.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The flight log (LOG00001.BIN from `sitl --log-dir`, or a board's SD card).
    pub log: PathBuf,
    /// Replay with a parameter changed: NAME=VALUE (arrays comma-separated); repeatable.
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
}

/// A parameter changed for the replay.
#[derive(Clone, Debug, PartialEq)]
pub struct Override {
    pub index: usize,
    pub values: Vec<f32>,
}

/// `NAME=VALUE` (or `NAME = VALUE`), the value checked against the parameter's range.
pub fn parse_override(text: &str) -> Result<Override, InputError> {
    let (name, value) = text
        .split_once('=')
        .ok_or_else(|| InputError(format!("--set `{text}`: expected NAME=VALUE")))?;
    let name = name.trim();
    let index = find(name.as_bytes())
        .ok_or_else(|| InputError(format!("--set: unknown parameter `{name}`")))?;
    let values = value
        .split(',')
        .map(|v| {
            v.trim()
                .parse::<f32>()
                .map_err(|_| InputError(format!("--set {name}: `{}` is not a number", v.trim())))
        })
        .collect::<Result<Vec<f32>, _>>()?;
    SPECS[index].validate(&values).map_err(|e| InputError(format!("--set {name}: {e:?}")))?;
    Ok(Override { index, values })
}

/// A log file read: its header and its records, in order.
#[derive(Clone, Debug)]
pub struct LogFile {
    pub header: Header,
    pub records: Vec<LogRecord>,
    pub stats: ReadStats,
}

/// Read the log at `path` (its first file: up to a second header, if any).
pub fn read_log(path: &Path) -> Result<LogFile, InputError> {
    let bytes = std::fs::read(path)
        .map_err(|e| InputError(format!("cannot read {}: {e}", path.display())))?;
    parse_log(&bytes).map_err(|e| InputError(format!("{}: {}", path.display(), e.0)))
}

/// The records of a log's bytes.
pub fn parse_log(bytes: &[u8]) -> Result<LogFile, InputError> {
    let mut reader = LogReader::new(bytes);
    let header = match reader.next() {
        Some(LogRecord::Header(header)) => header,
        Some(_) => return Err(InputError("no header: the beginning of the log is lost".into())),
        None => return Err(InputError("not a flight log (no record in it)".into())),
    };
    if !(1..=LOG_FORMAT_VERSION).contains(&header.format) {
        return Err(InputError(format!(
            "log format {} (this configurator reads formats 1 to {LOG_FORMAT_VERSION})",
            header.format
        )));
    }
    if header.params_layout != LAYOUT_HASH {
        return Err(InputError(format!(
            "written by firmware {}.{}.{} with another parameter registry (layout {:08x}, ours \
             {LAYOUT_HASH:08x}): replay it with the configurator of that firmware",
            header.firmware[0], header.firmware[1], header.firmware[2], header.params_layout
        )));
    }
    let mut records = Vec::new();
    for record in reader.by_ref() {
        if matches!(record, LogRecord::Header(_)) {
            break;
        }
        records.push(record);
    }
    Ok(LogFile { header, records, stats: reader.stats() })
}

/// The logged IMU sample of one step, returned once.
struct ReplayImu(Option<ImuSample>);

impl Imu for ReplayImu {
    fn read(&mut self) -> Option<ImuSample> {
        self.0.take()
    }
}

/// The logged motor outputs of one step: their count and the speeds they reported.
struct ReplayMotors {
    count: u8,
    speeds_rad_s: [Option<f32>; MAX_MOTORS],
}

impl Motors for ReplayMotors {
    fn count(&self) -> u8 {
        self.count
    }
    fn set_commands(&mut self, _commands: &[f32]) {}
    fn speeds_rad_s(&self) -> [Option<f32>; MAX_MOTORS] {
        self.speeds_rad_s
    }
}

/// The first step whose outcome differs from the log's.
#[derive(Clone, Debug, PartialEq)]
pub struct Difference {
    pub step: u32,
    pub t_us: u64,
    pub logged_commands: Vec<f32>,
    pub replayed_commands: Vec<f32>,
    pub logged_phase: FlightPhase,
    pub replayed_phase: FlightPhase,
}

/// What one replay did.
#[derive(Clone, Debug)]
pub struct ReplayRun {
    /// Steps replayed and compared.
    pub steps: u64,
    /// Steps whose commands (bit for bit) or phase differ from the log's.
    pub differences: u64,
    pub first_difference: Option<Difference>,
    /// Each phase change (phase, time µs) in the log and in the replay.
    pub logged_phases: Vec<(FlightPhase, u64)>,
    pub replayed_phases: Vec<(FlightPhase, u64)>,
    /// The background task's learned model at the end of the replay.
    pub learned: LearnedModel,
    /// What the replay could not reproduce exactly, in words.
    pub notes: Vec<String>,
}

/// The background task's side of an exact replay (module doc): the work in the order the board
/// took it, each with the samples processed then; the sample counts whose results the board's
/// control step adopted, and those results once reached.
struct BackgroundScript {
    works: VecDeque<(u32, BackgroundWork)>,
    wanted: BTreeSet<u32>,
    results_at: HashMap<u32, BackgroundResults>,
}

impl BackgroundScript {
    /// Read from the whole log (`changed` applies the replay's parameter overrides). The board's
    /// sample counts are taken as counts of the replay's background task, less `samples_before`
    /// (the samples the board's took before the file's first step: 0 from start-up).
    fn read(log: &LogFile, changed: &dyn Fn(&Params) -> Params, samples_before: u32) -> Self {
        let mut assembler = ParamsAssembler::default();
        let mut params = Params::default();
        let mut works = VecDeque::new();
        let mut wanted = BTreeSet::new();
        for record in &log.records {
            match record {
                LogRecord::Params(part) => {
                    if let Some(complete) = assembler.push(part) {
                        params = complete;
                    }
                }
                LogRecord::Work(work) => {
                    if let Some(samples) = work.samples_processed {
                        let at = samples.saturating_sub(samples_before);
                        works.push_back((at, background_work(work.work, &changed(&params))));
                    }
                }
                LogRecord::Adopted(adopted) => {
                    wanted.insert(adopted.samples_processed.saturating_sub(samples_before));
                }
                LogRecord::End(_) => break,
                _ => {}
            }
        }
        Self { works, wanted, results_at: HashMap::new() }
    }

    /// Keep the results at the current sample count when a step adopted them.
    fn keep(&mut self, worker: &Background<'_>) {
        let results = worker.results_ref();
        if self.wanted.contains(&results.samples_processed) {
            self.results_at.insert(results.samples_processed, *results);
        }
    }

    /// The work taken at the current sample count.
    fn take_due_work(&mut self, worker: &mut Background<'_>) {
        let count = worker.results_ref().samples_processed;
        while self.works.front().is_some_and(|(at, _)| *at <= count) {
            if let Some((_, work)) = self.works.pop_front() {
                match work {
                    BackgroundWork::Command(command) => worker.command(command),
                    BackgroundWork::Configure(params) => worker.configure(&params),
                }
            }
        }
    }

    /// Every waiting sample, one at a time, with the work due between them; the in-flight
    /// IMU-offset fit's task caught up before each (its estimates are applied a fixed number
    /// of samples after the one that completed them, so when it ran on the board does not
    /// matter: `firmware::app::offset_fit`).
    fn advance(&mut self, worker: &mut Background<'_>, offset_fit: &mut OffsetFitWorker<'_>) {
        loop {
            self.take_due_work(worker);
            offset_fit.run_pending();
            if !worker.run_one() {
                break;
            }
            self.keep(worker);
        }
    }
}

/// Background work as the log names it, with `params` for a parameter change.
fn background_work(work: LoggedWork, params: &Params) -> BackgroundWork {
    match work {
        LoggedWork::Configure => BackgroundWork::Configure(*params),
        LoggedWork::StartCalibration => {
            BackgroundWork::Command(BackgroundCommand::StartCalibration)
        }
        LoggedWork::StopCalibration => BackgroundWork::Command(BackgroundCommand::StopCalibration),
    }
}

/// Replay `log` with `overrides` applied to every parameter set; `each_step` sees every logged
/// step with the replayed snapshot after it.
pub fn replay(
    log: &LogFile,
    overrides: &[Override],
    mut each_step: impl FnMut(&StepLogRecord, &ControlSnapshot),
) -> ReplayRun {
    let changed = |params: &Params| {
        let mut params = *params;
        for o in overrides {
            // Validated by `parse_override`.
            let _ = params.set(o.index, &o.values);
        }
        params
    };
    let from_start_up = log.header.first_step <= 1;
    // A file begun at an arming: the control loop's state there, when the file has it whole.
    let arming = if from_start_up { None } else { arming_state(log) };
    let (arming, arming_problem) = match arming {
        Some(Ok(arming)) => (Some(arming), None),
        Some(Err(problem)) => (None, Some(problem)),
        None => (None, None),
    };
    // The handoffs as the board made them (module doc).
    let exact = (from_start_up || arming.is_some()) && log.header.format >= 4;
    let samples_before = arming.as_ref().map_or(0, |(tag, _)| tag.samples_before);
    let mut run = ReplayRun {
        steps: 0,
        differences: 0,
        first_difference: None,
        logged_phases: Vec::new(),
        replayed_phases: Vec::new(),
        learned: LearnedModel::default(),
        notes: Vec::new(),
    };
    if let Some(problem) = arming_problem {
        run.notes.push(format!(
            "the log begins at step {} (an arming) but its record of the control loop's state \
             there is unusable ({problem}): replayed from a fresh application",
            log.header.first_step
        ));
    }
    if !from_start_up && arming.is_none() {
        run.notes.push(format!(
            "the log begins at step {} (an arming), not at start-up, and holds no state of the \
             control loop there (written by a firmware before log format 6, or the board's logger \
             was still busy with an earlier arming): replayed from a fresh application, whose \
             filters had not seen the steps before, with the background task run after every \
             step as the SITL runs it",
            log.header.first_step
        ));
    } else if !exact {
        run.notes.push(format!(
            "a format {} log records no handoff from the background task: replayed with the \
             background task run after every step, as the SITL runs it",
            log.header.format
        ));
    }
    let mut script = BackgroundScript::read(log, &changed, samples_before);
    with_system(Settings::<NoFlash>::without_store(), Default::default(), None, |system| {
        let mut assembler = ParamsAssembler::default();
        let mut params = Params::default();
        let mut started = false;
        let mut injected = false;
        let mut expected_step = log.header.first_step;
        let mut last = (None, None);
        // What the control step reads from the background task (exact replay).
        let mut handed = system.background.results();
        script.keep(&system.background);
        let mut adoption = None;
        // Samples the board's control step had dropped before the file (its background task's
        // past, not this replay's).
        let mut samples_dropped = match &arming {
            Some(_) => log
                .records
                .iter()
                .find_map(|r| match r {
                    LogRecord::Adopted(adopted) => Some(adopted.samples_dropped),
                    _ => None,
                })
                .unwrap_or(0),
            None => 0,
        };
        if let Some((_, state)) = &arming {
            // The board's control loop as it stood before the arming command; the results it
            // had adopted then are the ones it keeps until the log shows another adoption (only
            // their version and IMU offset are compared: `ControlLoop::receive`).
            system.control.control_mut().restore(*state);
            if let Some(version) = system.control.control().model_version() {
                handed.learned.samples = version.samples;
                handed.learned.pending = version.pending;
                handed.learning_ended = version.learning_ended;
            }
            if let Some(r_imu_m) = system.control.control().imu_offset_m() {
                handed.learner_r_imu_m = r_imu_m;
            }
        }
        for record in &log.records {
            match record {
                LogRecord::Header(_) => {}
                LogRecord::Params(part) => {
                    if let Some(complete) = assembler.push(part) {
                        params = complete;
                        if !from_start_up && !started && !injected {
                            injected = true;
                            // The parameters in force at the arming, as the board had them (the
                            // control loop's are in its state, when the log has it).
                            let current = changed(&params);
                            let command = LoggedCommand::Configure { from_params: true };
                            if let Some(command) = command.to_command(&current) {
                                if arming.is_none() {
                                    system.submit(command);
                                }
                            }
                            let _ =
                                system.handoffs.work.push_back(BackgroundWork::Configure(current));
                            system.run_background();
                        }
                    }
                }
                LogRecord::Command(record) => {
                    if let LoggedCommand::Configure { from_params: false } = record.command {
                        run.notes.push(format!(
                            "step {}: the control settings applied were not those of the \
                             parameters (replayed with the parameters')",
                            record.step
                        ));
                    }
                    match record.command.to_command(&changed(&params)) {
                        // Straight into the queue, in the order applied (a logged disarm
                        // must not clear what was applied before it).
                        Some(command) => {
                            if system.handoffs.commands.push_back(command).is_err() {
                                run.notes.push(format!(
                                    "step {}: more commands than the queue holds",
                                    record.step
                                ));
                            }
                        }
                        None => run.notes.push(format!(
                            "step {}: an ESC command this firmware does not know",
                            record.step
                        )),
                    }
                }
                LogRecord::Adopted(adopted) => adoption = Some(*adopted),
                LogRecord::Step(step) => {
                    started = true;
                    if step.step != expected_step {
                        run.notes.push(format!(
                            "steps {}..{} are missing from the log",
                            expected_step,
                            step.step.wrapping_sub(1)
                        ));
                    }
                    expected_step = step.step.wrapping_add(1);
                    let mut imu = ReplayImu(step.imu_sample());
                    let mut motors =
                        ReplayMotors { count: step.motor_count(), speeds_rad_s: step.speeds_rad_s };
                    // The log keeps no battery readings: the control never uses them (an empty
                    // pack's landing is a logged command).
                    let hardware = TickHardware {
                        imu: &mut imu,
                        motors: &mut motors,
                        radio_bytes: &mut NoBytes,
                        battery: &mut NoBattery,
                    };
                    if exact {
                        if let Some(adopted) = adoption.take().filter(|a| a.step == step.step) {
                            let at = adopted.samples_processed.saturating_sub(samples_before);
                            match script.results_at.get(&at) {
                                Some(results) => handed = *results,
                                None => run.notes.push(format!(
                                    "step {}: the board adopted the results of {} learner \
                                     samples, which the replay's background task did not reach",
                                    step.step, adopted.samples_processed
                                )),
                            }
                            if adopted.samples_dropped > samples_dropped {
                                samples_dropped = adopted.samples_dropped;
                                run.notes.push(format!(
                                    "by step {}: the board's control step had dropped {} learner \
                                     samples (its queue full), which the replay's background \
                                     task did learn from: not exact from there on",
                                    step.step, samples_dropped
                                ));
                            }
                        }
                        let handoffs = &mut system.handoffs;
                        let mut shared = TickShared {
                            commands: Exclusive(&mut handoffs.commands),
                            results: Exclusive(&mut handed),
                            snapshot: Exclusive(&mut handoffs.snapshot),
                            board: Exclusive(&mut handoffs.board),
                        };
                        system.control.tick(step.t_us, hardware, &mut shared);
                        script.advance(&mut system.background, &mut system.offset_fit);
                    } else {
                        system.tick(step.t_us, hardware);
                    }
                    let snapshot = system.snapshot();
                    run.steps += 1;
                    let count = step.commands.len();
                    let replayed = &snapshot.commands[..count];
                    let same_commands = replayed
                        .iter()
                        .zip(&step.commands)
                        .all(|(a, b)| a.to_bits() == b.to_bits());
                    let logged_phase = phase_from_code(step.phase).unwrap_or_default();
                    if !same_commands || phase_code(snapshot.phase) != step.phase {
                        run.differences += 1;
                        if run.first_difference.is_none() {
                            run.first_difference = Some(Difference {
                                step: step.step,
                                t_us: step.t_us,
                                logged_commands: step.commands.to_vec(),
                                replayed_commands: replayed.to_vec(),
                                logged_phase,
                                replayed_phase: snapshot.phase,
                            });
                        }
                    }
                    if last.0 != Some(logged_phase) {
                        run.logged_phases.push((logged_phase, step.t_us));
                        last.0 = Some(logged_phase);
                    }
                    if last.1 != Some(snapshot.phase) {
                        run.replayed_phases.push((snapshot.phase, step.t_us));
                        last.1 = Some(snapshot.phase);
                    }
                    each_step(step, &snapshot);
                }
                LogRecord::Work(work) => {
                    // An exact replay took it from the script, between its samples.
                    if !(exact && work.samples_processed.is_some()) {
                        let item = background_work(work.work, &changed(&params));
                        let _ = system.handoffs.work.push_back(item);
                        system.run_background();
                    }
                }
                LogRecord::Dropped(dropped) => run.notes.push(format!(
                    "the board's log ring was full: {} entries dropped since start-up",
                    dropped.entries
                )),
                LogRecord::End(_) => break,
                // The board's own outputs, not inputs: the replay computes them afresh.
                LogRecord::Learner(_) | LogRecord::Flight(_) => {}
                // Read before the replay began (`arming_state`).
                LogRecord::Arming(_) | LogRecord::State(_) => {}
            }
        }
        run.learned = if exact {
            script.advance(&mut system.background, &mut system.offset_fit);
            system.background.results_ref().learned
        } else {
            system.handoffs.results.learned
        };
    });
    if log.stats.bad_frames > 0 || log.stats.missing_records > 0 {
        run.notes.push(format!(
            "{} damaged frames skipped, {} records missing",
            log.stats.bad_frames, log.stats.missing_records
        ));
    }
    run
}

/// The control loop's state a file begun at an arming records (its [`ArmingRecord`] and the
/// [`StateChunk`]s after it), with the step and sample count it was taken at: `None` when the file
/// has no such record, an error naming what is wrong when it is incomplete or does not decode
/// (written by another firmware, or torn by a power cut).
fn arming_state(log: &LogFile) -> Option<Result<(ArmingTag, ControlState), String>> {
    let mut announced: Option<ArmingRecord> = None;
    let mut bytes = Vec::new();
    for record in &log.records {
        match record {
            LogRecord::Arming(record) => {
                announced = Some(*record);
                bytes.clear();
            }
            LogRecord::State(chunk) if announced.is_some() => {
                if chunk.offset as usize != bytes.len() {
                    return Some(Err(format!(
                        "a chunk at byte {} where byte {} was due",
                        chunk.offset,
                        bytes.len()
                    )));
                }
                bytes.extend_from_slice(&chunk.bytes);
            }
            LogRecord::Step(_) => break,
            _ => {}
        }
    }
    let record = announced?;
    Some(if bytes.len() != record.len as usize {
        Err(format!("{} of its {} bytes", bytes.len(), record.len))
    } else if record.tag.step != log.header.first_step {
        Err(format!(
            "taken at step {}, the file begins at {}",
            record.tag.step, log.header.first_step
        ))
    } else {
        postcard::from_bytes::<ControlState>(&bytes)
            .map(|state| (record.tag, state))
            .map_err(|e| format!("it does not decode: {e}"))
    })
}

/// The phase's name as the status shows it.
pub fn phase_name(phase: FlightPhase) -> &'static str {
    match phase {
        FlightPhase::Idle => "idle",
        FlightPhase::WaitingForThrow => "waiting-for-throw",
        FlightPhase::Throwing => "throwing",
        FlightPhase::Released => "released",
        FlightPhase::Exciting => "exciting",
        FlightPhase::Done => "done",
    }
}

/// How two learned models differ: G1 per unit thrust (relative Frobenius norm of the
/// difference), each motor's τ, and the angle between the thrust directions.
pub fn model_difference(a: &LearnedModel, b: &LearnedModel) -> Value {
    let (ga, gb) = (a.g1_per_unit_thrust(), b.g1_per_unit_thrust());
    let m = usize::from(a.motors.max(b.motors)).min(MAX_MOTORS);
    let (mut diff2, mut norm2) = (0.0f64, 0.0f64);
    for (ra, rb) in ga.iter().zip(&gb) {
        for i in 0..m {
            diff2 += f64::from(ra[i] - rb[i]).powi(2);
            norm2 += f64::from(ra[i]).powi(2);
        }
    }
    let relative = (norm2 > 0.0).then(|| (diff2 / norm2).sqrt());
    let angle_deg = match (&a.thrust_axis, &b.thrust_axis) {
        (Some(x), Some(y)) => {
            let dot: f32 = x.thrust_dir_imu.iter().zip(&y.thrust_dir_imu).map(|(p, q)| p * q).sum();
            Some(f64::from(dot.clamp(-1.0, 1.0)).acos().to_degrees())
        }
        _ => None,
    };
    json!({
        "g1_relative_difference": relative,
        "tau_s": [
            a.motor[..m].iter().map(|x| x.tau_s).collect::<Vec<_>>(),
            b.motor[..m].iter().map(|x| x.tau_s).collect::<Vec<_>>(),
        ],
        "thrust_axis_angle_deg": angle_deg,
    })
}

fn phases_json(phases: &[(FlightPhase, u64)]) -> Value {
    Value::Array(
        phases
            .iter()
            .map(|(phase, t_us)| json!({"phase": phase_name(*phase), "t_s": *t_us as f64 * 1e-6}))
            .collect(),
    )
}

/// `replay LOG [--set NAME=VALUE]...`: the report, as text or JSON.
pub fn run(args: &Args, json_output: bool) -> Result<String, InputError> {
    let overrides = args.set.iter().map(|s| parse_override(s)).collect::<Result<Vec<_>, _>>()?;
    let log = read_log(&args.log)?;
    let run = replay(&log, &overrides, |_, _| {});
    let baseline = (!overrides.is_empty()).then(|| replay(&log, &[], |_, _| {}));
    let first = run.first_difference.as_ref();
    let learned_difference =
        baseline.as_ref().map(|base| model_difference(&base.learned, &run.learned));
    if json_output {
        let value = json!({
            "log": args.log.display().to_string(),
            "board": log.header.board.as_str(),
            "firmware": log.header.firmware,
            "first_step": log.header.first_step,
            "from_start_up": log.header.first_step <= 1,
            "steps": run.steps,
            "differences": run.differences,
            "first_difference": first.map(|d| json!({
                "step": d.step,
                "t_s": d.t_us as f64 * 1e-6,
                "logged_commands": d.logged_commands,
                "replayed_commands": d.replayed_commands,
                "logged_phase": phase_name(d.logged_phase),
                "replayed_phase": phase_name(d.replayed_phase),
            })),
            "phases": {
                "logged": phases_json(&run.logged_phases),
                "replayed": phases_json(&run.replayed_phases),
            },
            "set": args.set,
            "learned_difference": learned_difference,
            "damaged_frames": log.stats.bad_frames,
            "notes": run.notes,
        });
        return Ok(format!("{value:#}\n"));
    }
    let mut out = format!(
        "{}: {} steps from {} (firmware {}.{}.{}, {}{})\n",
        args.log.display(),
        run.steps,
        log.header.board,
        log.header.firmware[0],
        log.header.firmware[1],
        log.header.firmware[2],
        if log.header.first_step <= 1 { "from start-up" } else { "from an arming" },
        if args.set.is_empty() { String::new() } else { format!(", with {}", args.set.join(" ")) },
    );
    match first {
        None => out += "replayed bit for bit: every command and phase as logged\n",
        Some(d) => {
            out += &format!(
                "{} steps differ; the first at step {} (t = {:.4} s): commands {:?} logged, {:?} \
                 replayed; phase {} logged, {} replayed\n",
                run.differences,
                d.step,
                d.t_us as f64 * 1e-6,
                d.logged_commands,
                d.replayed_commands,
                phase_name(d.logged_phase),
                phase_name(d.replayed_phase)
            );
        }
    }
    let times = |phases: &[(FlightPhase, u64)]| {
        phases
            .iter()
            .map(|(p, t)| format!("{} {:.3} s", phase_name(*p), *t as f64 * 1e-6))
            .collect::<Vec<_>>()
            .join(", ")
    };
    out += &format!("phases logged:   {}\n", times(&run.logged_phases));
    out += &format!("phases replayed: {}\n", times(&run.replayed_phases));
    if let Some(difference) = learned_difference {
        out += &format!("learned model against the unchanged replay: {difference}\n");
    }
    for note in &run.notes {
        out += &format!("note: {note}\n");
    }
    Ok(out)
}
