//! `configurator-cli record`: telemetry topics written to CSV as they arrive.
//!
//! One row per sample of the fastest chosen topic (the per-step topics `state`, `imu`, `motors`,
//! up to every 2 kHz control step); the slower topics (`learner`, `control`) fill their columns
//! with their latest sample, empty until the first arrives. So a recording of `state` (or `imu`)
//! is exactly the log `fit imu-offset` reads (`t,gyro_x..z,acc_x..z`, constant rate), and a
//! recording of `state,learner` is what `plot` draws as attitude, motor and G1-convergence
//! panels. Gaps are counted per topic from the sequence numbers and reported, never hidden.
//!
//! Columns, with units in the names or below:
//! - `t`: device time, s;
//! - `gyro_x..z` rad/s, `acc_x..z` m/s² (specific force, stored bias removed), IMU axes;
//! - `roll_deg, pitch_deg, yaw_deg`: ZYX Euler angles of the IMU's attitude in the world (NED);
//!   `phase` (text), `flying` (0/1);
//! - `cmd_i` (δ, 0–1), `speed_i` (rad/s, empty where not reported), one per motor;
//! - `steps, late_steps, samples_dropped` (the control topic);
//! - `learner_phase` (text), `exciting_motor`, `tau_s_i` (s), `omega_max_i` (rad/s),
//!   `g1_fx_i … g1_r_i` (G1 per unit normalised thrust: m/s² or rad/s², IMU axes); the
//!   estimates are empty until the first motor pulse.

use crate::link::TelemetrySample;
use protocol::{
    ControlTelemetry, FlightMode, FlightTelemetry, ImuTelemetry, LearnerPhase, LearnerTelemetry,
    MotorTelemetry, StateTelemetry, Telemetry, Topic,
};
use std::fmt::Write as _;
use std::io::Write;

/// The topic's name on the command line.
pub fn topic_name(topic: Topic) -> &'static str {
    match topic {
        Topic::Imu => "imu",
        Topic::Control => "control",
        Topic::Motors => "motors",
        Topic::Learner => "learner",
        Topic::State => "state",
        Topic::Flight => "flight",
    }
}

/// A topic from its name on the command line.
pub fn parse_topic(name: &str) -> Result<Topic, String> {
    Topic::ALL.into_iter().find(|&t| topic_name(t) == name).ok_or_else(|| {
        let names: Vec<&str> = Topic::ALL.into_iter().map(topic_name).collect();
        format!("unknown topic `{name}`; choose {}", names.join(", "))
    })
}

/// Topics from a comma-separated list (`state,learner`), each once, in wire order.
pub fn parse_topics(list: &str) -> Result<Vec<Topic>, String> {
    let mut topics = Vec::new();
    for name in list.split(',').map(str::trim).filter(|n| !n.is_empty()) {
        let topic = parse_topic(name)?;
        if !topics.contains(&topic) {
            topics.push(topic);
        }
    }
    if topics.is_empty() {
        return Err("no topic given (e.g. --topic state,learner)".into());
    }
    topics.sort_by_key(|t| t.index());
    Ok(topics)
}

/// The telemetry rate a topic is recorded at, Hz: every control step for the per-step topics,
/// 100 Hz for the learner (G1 arrives in two halves, so the whole matrix at 50 Hz), 500 Hz for
/// the flight topic (the link samples it at most once per 1 ms pass), 10 Hz for the control
/// topic.
pub fn recording_rate_hz(topic: Topic, control_rate_hz: u16) -> u16 {
    match topic {
        Topic::Imu | Topic::Motors | Topic::State => control_rate_hz,
        Topic::Learner => 100,
        Topic::Flight => 500,
        Topic::Control => 10,
    }
}

/// The sample's topic.
pub fn topic_of(data: &Telemetry) -> Topic {
    match data {
        Telemetry::Imu(_) => Topic::Imu,
        Telemetry::Control(_) => Topic::Control,
        Telemetry::Motors(_) => Topic::Motors,
        Telemetry::Learner(_) => Topic::Learner,
        Telemetry::State(_) => Topic::State,
        Telemetry::Flight(_) => Topic::Flight,
    }
}

/// Samples received and missing for one topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicCount {
    pub topic: Topic,
    pub received: u64,
    /// Samples missing between the first and the last received (from the sequence numbers).
    pub gaps: u64,
    last_seq: Option<u16>,
}

impl TopicCount {
    pub fn new(topic: Topic) -> Self {
        Self { topic, received: 0, gaps: 0, last_seq: None }
    }

    /// Count a sample with sequence number `seq`.
    pub fn count(&mut self, seq: u16) {
        self.received += 1;
        if let Some(previous) = self.last_seq {
            self.gaps += u64::from(seq.wrapping_sub(previous).wrapping_sub(1));
        }
        self.last_seq = Some(seq);
    }
}

/// A column's name: fixed, or a prefix and a motor index.
#[derive(Debug, Clone, Copy)]
enum Name {
    Fixed(&'static str),
    Motor(&'static str, usize),
}

impl std::fmt::Display for Name {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Name::Fixed(name) => f.write_str(name),
            Name::Motor(prefix, i) => write!(f, "{prefix}{i}"),
        }
    }
}

/// A field's value: a number (written in its shortest exact form), a count, text, or nothing
/// yet.
enum Value<'a> {
    Number(f32),
    Count(u32),
    Text(&'a str),
    Empty,
}

/// The latest sample of each topic, and the columns they fill.
#[derive(Default)]
struct Table {
    has_state: bool,
    has_imu: bool,
    has_motors: bool,
    has_control: bool,
    has_learner: bool,
    has_flight: bool,
    motor_count: usize,
    state: Option<StateTelemetry>,
    imu: Option<ImuTelemetry>,
    motors: Option<MotorTelemetry>,
    control: Option<ControlTelemetry>,
    /// G1 rows arrive alternately: block 0 (specific force) and block 1 (angular acceleration).
    learner: [Option<LearnerTelemetry>; 2],
    flight: Option<FlightTelemetry>,
}

/// The G1 rows' names, specific force then angular acceleration.
const G1_ROWS: [&str; 6] = ["g1_fx_", "g1_fy_", "g1_fz_", "g1_p_", "g1_q_", "g1_r_"];

impl Table {
    /// Every column in order: its name and its value now (`t` is written by the caller).
    fn visit(&self, field: &mut dyn FnMut(Name, Value<'_>)) {
        let number = |x: Option<f32>| x.map_or(Value::Empty, Value::Number);
        let count = |x: Option<u32>| x.map_or(Value::Empty, Value::Count);
        let m = self.motor_count;
        if self.has_state || self.has_imu {
            // The state's IMU sample when recorded (the same numbers), else the IMU topic's.
            let imu = match (&self.state, &self.imu) {
                (Some(s), _) if self.has_state => Some((s.gyro_rad_s, s.accel_mps2)),
                (_, Some(i)) => Some((i.gyro_rad_s, i.accel_mps2)),
                _ => None,
            };
            for (k, name) in ["gyro_x", "gyro_y", "gyro_z"].into_iter().enumerate() {
                field(Name::Fixed(name), number(imu.map(|(g, _)| g[k])));
            }
            for (k, name) in ["acc_x", "acc_y", "acc_z"].into_iter().enumerate() {
                field(Name::Fixed(name), number(imu.map(|(_, a)| a[k])));
            }
        }
        if self.has_state {
            let euler = self.state.map(|s| euler_zyx_deg(s.q_world_imu).map(|x| x as f32));
            for (k, name) in ["roll_deg", "pitch_deg", "yaw_deg"].into_iter().enumerate() {
                field(Name::Fixed(name), number(euler.map(|e| e[k])));
            }
            let phase = self.state.map(|s| phase_name(s.phase));
            field(Name::Fixed("phase"), phase.map_or(Value::Empty, Value::Text));
            field(Name::Fixed("flying"), count(self.state.map(|s| u32::from(s.flying))));
        }
        if self.has_state || self.has_motors {
            let motors = match (&self.state, &self.motors) {
                (Some(s), _) if self.has_state => Some((s.commands, s.speeds_rad_s)),
                (_, Some(m)) => Some((m.commands, m.speeds_rad_s)),
                _ => None,
            };
            for i in 0..m {
                field(Name::Motor("cmd_", i), number(motors.map(|(c, _)| c[i])));
            }
            for i in 0..m {
                field(Name::Motor("speed_", i), number(motors.and_then(|(_, s)| s[i])));
            }
        }
        if self.has_flight {
            let f = self.flight;
            field(Name::Fixed("mode"), f.map_or(Value::Empty, |f| Value::Text(mode_name(f.mode))));
            let euler = f.map(|f| f.euler_zyx_rad.map(f32::to_degrees));
            let names = ["thrust_roll_deg", "thrust_pitch_deg", "thrust_yaw_deg"];
            for (k, name) in names.into_iter().enumerate() {
                field(Name::Fixed(name), number(euler.map(|e| e[k])));
            }
            let vectors: [(&[&'static str; 3], Option<[f32; 3]>); 6] = [
                (&["rate_p", "rate_q", "rate_r"], f.map(|f| f.rate_rad_s)),
                (&["rate_sp_p", "rate_sp_q", "rate_sp_r"], f.map(|f| f.rate_sp_rad_s)),
                (
                    &["force_sp_n", "force_sp_e", "force_sp_d"],
                    f.map(|f| f.specific_force_sp_ned_mps2),
                ),
                (&["pos_n", "pos_e", "pos_d"], f.and_then(|f| f.position_ned_m)),
                (&["vel_n", "vel_e", "vel_d"], f.and_then(|f| f.velocity_ned_mps)),
                (&["pos_sp_n", "pos_sp_e", "pos_sp_d"], f.and_then(|f| f.position_sp_ned_m)),
            ];
            for (names, values) in vectors {
                for (k, name) in names.iter().enumerate() {
                    field(Name::Fixed(name), number(values.map(|v| v[k])));
                }
            }
            field(Name::Fixed("tilt_error_rad"), number(f.map(|f| f.tilt_error_rad)));
            let failures = f.map(|f| u32::from(f.allocation_failures));
            field(Name::Fixed("allocation_failures"), count(failures));
            field(Name::Fixed("saturated_mask"), count(f.map(|f| u32::from(f.saturated))));
        }
        if self.has_control {
            let c = self.control;
            field(Name::Fixed("steps"), count(c.map(|c| c.steps)));
            field(Name::Fixed("late_steps"), count(c.map(|c| c.late_steps)));
            field(Name::Fixed("samples_dropped"), count(c.map(|c| c.samples_dropped)));
        }
        if self.has_learner {
            let latest = self.learner.iter().flatten().max_by_key(|l| l.t_us);
            let phase = latest.map(|l| phase_name(l.phase));
            field(Name::Fixed("learner_phase"), phase.map_or(Value::Empty, Value::Text));
            let exciting = latest.and_then(|l| l.exciting_motor).map(u32::from);
            field(Name::Fixed("exciting_motor"), count(exciting));
            // Before the motors are pulsed the learner's fields are its initial zeros, not
            // estimates: left empty, so that a plot scaled to what the estimates converged to
            // does not count the wait for the throw, however long, as part of it.
            let latest = latest.filter(|l| has_estimates(l.phase));
            for i in 0..m {
                field(Name::Motor("tau_s_", i), number(latest.map(|l| l.tau_s[i])));
            }
            for i in 0..m {
                let omega = latest.map(|l| l.omega_max_rad_s[i]);
                field(Name::Motor("omega_max_", i), number(omega));
            }
            for (row, prefix) in G1_ROWS.into_iter().enumerate() {
                let block = &self.learner[row / 3];
                for i in 0..m {
                    let value =
                        block.filter(|l| has_estimates(l.phase)).map(|l| l.g1_rows[row % 3][i]);
                    field(Name::Motor(prefix, i), number(value));
                }
            }
        }
    }

    /// Keep a sample as its topic's latest.
    fn take(&mut self, data: &Telemetry) {
        match *data {
            Telemetry::State(s) => self.state = Some(s),
            Telemetry::Imu(i) => self.imu = Some(i),
            Telemetry::Motors(m) => self.motors = Some(m),
            Telemetry::Control(c) => self.control = Some(c),
            Telemetry::Learner(l) => self.learner[usize::from(l.g1_block.min(1))] = Some(l),
            Telemetry::Flight(f) => self.flight = Some(f),
        }
    }
}

/// Whether the learner's G1, lag and top-speed fields are estimates in this phase: from the
/// first motor pulse on (a failed identification keeps what it had learned).
fn has_estimates(phase: LearnerPhase) -> bool {
    matches!(phase, LearnerPhase::Exciting | LearnerPhase::Done | LearnerPhase::Failed)
}

/// The sample's device time, µs.
pub fn time_us(data: &Telemetry) -> u64 {
    match data {
        Telemetry::State(s) => s.t_us,
        Telemetry::Imu(i) => i.t_us,
        Telemetry::Motors(m) => m.t_us,
        Telemetry::Control(c) => c.t_us,
        Telemetry::Learner(l) => l.t_us,
        Telemetry::Flight(f) => f.t_us,
    }
}

/// The flight mode's name as the status prints it.
pub fn mode_name(mode: FlightMode) -> &'static str {
    match mode {
        FlightMode::Off => "off",
        FlightMode::LevelHold => "level-hold",
        FlightMode::PositionHold => "position-hold",
        FlightMode::Landing(_) => "landing",
        FlightMode::Angle => "angle",
    }
}

/// The phase's name as the status prints it.
fn phase_name(phase: protocol::LearnerPhase) -> &'static str {
    use protocol::LearnerPhase as P;
    match phase {
        P::Idle => "idle",
        P::WaitingForThrow => "waiting-for-throw",
        P::Throwing => "throwing",
        P::Released => "released",
        P::Exciting => "exciting",
        P::Done => "done",
        P::Failed => "failed",
    }
}

/// ZYX Euler angles (roll, pitch, yaw) of a `[w, x, y, z]` quaternion, degrees.
pub fn euler_zyx_deg(q: [f32; 4]) -> [f64; 3] {
    let [w, x, y, z] = q.map(f64::from);
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    [roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()]
}

/// What a recording held.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordSummary {
    /// Rows written.
    pub rows: u64,
    /// Device time from the first to the last sample, s.
    pub span_s: f64,
    pub topics: Vec<TopicCount>,
}

impl RecordSummary {
    /// Samples missing over every topic.
    pub fn gaps(&self) -> u64 {
        self.topics.iter().map(|c| c.gaps).sum()
    }
}

/// Writes telemetry samples as CSV rows.
pub struct Recorder<W: Write> {
    out: W,
    table: Table,
    /// Each sample of this topic writes a row.
    row_topic: Topic,
    counts: Vec<TopicCount>,
    rows: u64,
    first_t_us: Option<u64>,
    last_t_us: u64,
    line: String,
}

impl<W: Write> Recorder<W> {
    /// A recorder of `topics` (at least one) for a board with `motor_count` motors; writes the
    /// header at once.
    pub fn new(mut out: W, topics: &[Topic], motor_count: u8) -> std::io::Result<Self> {
        let row_topic = [
            Topic::State,
            Topic::Imu,
            Topic::Motors,
            Topic::Flight,
            Topic::Learner,
            Topic::Control,
        ]
        .into_iter()
        .find(|t| topics.contains(t))
        .unwrap_or(Topic::State);
        let table = Table {
            has_state: topics.contains(&Topic::State),
            has_imu: topics.contains(&Topic::Imu),
            has_motors: topics.contains(&Topic::Motors),
            has_control: topics.contains(&Topic::Control),
            has_learner: topics.contains(&Topic::Learner),
            has_flight: topics.contains(&Topic::Flight),
            motor_count: usize::from(motor_count).min(protocol::MAX_MOTORS),
            ..Table::default()
        };
        let mut header = String::from("t");
        table.visit(&mut |name, _| {
            let _ = write!(header, ",{name}");
        });
        writeln!(out, "{header}")?;
        Ok(Self {
            out,
            table,
            row_topic,
            counts: topics.iter().map(|&t| TopicCount::new(t)).collect(),
            rows: 0,
            first_t_us: None,
            last_t_us: 0,
            line: String::new(),
        })
    }

    /// Take one sample: counted, kept as its topic's latest, and a row when it is of the row
    /// topic. Samples of topics not recorded are ignored.
    pub fn push(&mut self, sample: &TelemetrySample) -> std::io::Result<()> {
        let topic = topic_of(&sample.data);
        let Some(count) = self.counts.iter_mut().find(|c| c.topic == topic) else {
            return Ok(());
        };
        count.count(sample.seq);
        let t_us = time_us(&sample.data);
        self.first_t_us.get_or_insert(t_us);
        self.last_t_us = self.last_t_us.max(t_us);
        self.table.take(&sample.data);
        if topic != self.row_topic {
            return Ok(());
        }
        self.line.clear();
        let _ = write!(self.line, "{:.6}", t_us as f64 * 1e-6);
        let line = &mut self.line;
        self.table.visit(&mut |_, value| {
            let _ = match value {
                Value::Number(x) => write!(line, ",{x}"),
                Value::Count(n) => write!(line, ",{n}"),
                Value::Text(text) => write!(line, ",{text}"),
                Value::Empty => write!(line, ","),
            };
        });
        self.line.push('\n');
        self.out.write_all(self.line.as_bytes())?;
        self.rows += 1;
        Ok(())
    }

    /// What was recorded so far.
    pub fn summary(&self) -> RecordSummary {
        let span_us = self.first_t_us.map_or(0, |first| self.last_t_us - first);
        RecordSummary {
            rows: self.rows,
            span_s: span_us as f64 * 1e-6,
            topics: self.counts.clone(),
        }
    }

    /// Flush and give the writer back.
    pub fn finish(mut self) -> std::io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}

/// Why a recording stopped early.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Link(#[from] crate::link::LinkError),
    #[error("writing the recording: {0}")]
    Write(#[from] std::io::Error),
}

/// Record `topics` from a connected board for `duration` into `out`: each topic at its
/// [`recording_rate_hz`], a progress bar on a terminal, the topics stopped afterwards (also when
/// writing fails).
pub fn record<W: Write>(
    client: &mut crate::link::Client,
    topics: &[Topic],
    duration: std::time::Duration,
    out: W,
) -> Result<(RecordSummary, u64), RecordError> {
    use protocol::{Request, SetTelemetryRate};
    let rate = |topic, rate_hz| Request::SetTelemetryRate(SetTelemetryRate { topic, rate_hz });
    let mut recorder = Recorder::new(out, topics, client.info.motor_count)?;
    for &topic in topics {
        let rate_hz = recording_rate_hz(topic, client.info.control_rate_hz);
        client.request(&rate(topic, rate_hz), "the telemetry rate request")?;
    }
    client.telemetry.clear();
    let bytes_before = client.bytes_rx;
    let progress = indicatif::ProgressBar::new(duration.as_millis() as u64);
    progress.set_style(
        indicatif::ProgressStyle::with_template("recording {bar:30} {elapsed}/{duration} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let started = std::time::Instant::now();
    let mut write_error = None;
    let listened = client.listen_with(duration, |sample| {
        if write_error.is_none() {
            if let Err(e) = recorder.push(&sample) {
                write_error = Some(e);
            }
        }
        if recorder.rows.is_multiple_of(500) {
            let summary = recorder.summary();
            progress.set_position(started.elapsed().as_millis() as u64);
            progress.set_message(format!("{} rows, {} missing", summary.rows, summary.gaps()));
        }
    });
    progress.finish_and_clear();
    let bytes = client.bytes_rx - bytes_before;
    for &topic in topics {
        client.request(&rate(topic, 0), "the request to stop telemetry")?;
    }
    listened?;
    if let Some(error) = write_error {
        return Err(error.into());
    }
    let summary = recorder.summary();
    recorder.finish()?;
    Ok((summary, bytes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::MAX_MOTORS;

    fn state(step: u32) -> TelemetrySample {
        // 30° of roll: q = (cos 15°, sin 15°, 0, 0).
        let half = 15f32.to_radians();
        let mut speeds = [None; MAX_MOTORS];
        speeds[0] = Some(1200.0);
        TelemetrySample {
            seq: step as u16,
            data: Telemetry::State(StateTelemetry {
                t_us: u64::from(step) * 500,
                phase: LearnerPhase::Exciting,
                flying: false,
                imu_fresh: true,
                gyro_rad_s: [0.1, -0.2, step as f32],
                accel_mps2: [0.0, 0.0, -9.81],
                q_world_imu: [half.cos(), half.sin(), 0.0, 0.0],
                motor_count: 4,
                commands: [0.5, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.0],
                speeds_rad_s: speeds,
            }),
        }
    }

    fn learner(block: u8, t_us: u64) -> TelemetrySample {
        let mut g1_rows = [[0.0; MAX_MOTORS]; 3];
        g1_rows[2][1] = if block == 0 { -9.5 } else { 120.0 };
        TelemetrySample {
            seq: u16::from(block),
            data: Telemetry::Learner(LearnerTelemetry {
                t_us,
                phase: LearnerPhase::Exciting,
                motor_count: 4,
                g1_block: block,
                g1_rows,
                ..LearnerTelemetry::default()
            }),
        }
    }

    #[test]
    fn state_rows_carry_the_latest_learner_values_and_gaps_are_counted() {
        let topics = parse_topics("learner, state").unwrap();
        assert_eq!(topics, vec![Topic::Learner, Topic::State], "wire order");
        let mut recorder = Recorder::new(Vec::new(), &topics, 4).unwrap();
        recorder.push(&state(1)).unwrap();
        recorder.push(&learner(0, 600)).unwrap();
        recorder.push(&learner(1, 1100)).unwrap();
        recorder.push(&state(2)).unwrap();
        recorder.push(&state(5)).unwrap(); // steps 3 and 4 lost
        let summary = recorder.summary();
        let csv = String::from_utf8(recorder.finish().unwrap()).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        let header: Vec<&str> = lines[0].split(',').collect();
        assert_eq!(&header[..7], ["t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"]);
        assert_eq!(lines.len(), 4, "one row per state sample: {csv}");
        let column = |row: usize, name: &str| {
            let index = header.iter().position(|h| *h == name).unwrap();
            lines[row].split(',').nth(index).unwrap().to_string()
        };
        assert_eq!(column(1, "t"), "0.000500");
        assert_eq!(column(1, "gyro_z"), "1");
        assert!((column(1, "roll_deg").parse::<f64>().unwrap() - 30.0).abs() < 1e-4);
        assert_eq!(column(1, "phase"), "exciting");
        assert_eq!((column(1, "cmd_3").as_str(), column(1, "speed_0").as_str()), ("0.25", "1200"));
        assert_eq!(column(1, "speed_1"), "", "a motor that did not report is empty");
        assert_eq!(column(1, "g1_fz_1"), "", "no learner sample yet");
        assert_eq!(column(2, "g1_fz_1"), "-9.5");
        assert_eq!(column(2, "g1_r_1"), "120");
        assert!(!header.contains(&"cmd_4"), "only the board's four motors");
        assert_eq!(summary.rows, 3);
        assert_eq!(summary.gaps(), 2, "{summary:?}");
        assert!((summary.span_s - 0.002).abs() < 1e-9);
    }

    /// Waiting for the throw, the learner reports its phase but no estimate: its zeros are not
    /// written as G1 values (a plot would count them as what the learner converged to).
    #[test]
    fn the_learner_columns_are_empty_until_the_motors_are_pulsed() {
        let topics = parse_topics("learner, state").unwrap();
        let mut recorder = Recorder::new(Vec::new(), &topics, 4).unwrap();
        let mut waiting = learner(0, 600);
        if let Telemetry::Learner(l) = &mut waiting.data {
            l.phase = LearnerPhase::WaitingForThrow;
        }
        recorder.push(&waiting).unwrap();
        recorder.push(&state(2)).unwrap();
        recorder.push(&learner(0, 1100)).unwrap();
        recorder.push(&state(3)).unwrap();
        let csv = String::from_utf8(recorder.finish().unwrap()).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        let header: Vec<&str> = lines[0].split(',').collect();
        let column = |row: usize, name: &str| {
            let index = header.iter().position(|h| *h == name).unwrap();
            lines[row].split(',').nth(index).unwrap().to_string()
        };
        assert_eq!(column(1, "learner_phase"), "waiting-for-throw");
        for name in ["g1_fz_1", "g1_fx_0", "tau_s_0", "omega_max_0"] {
            assert_eq!(column(1, name), "", "{name} before the first pulse");
        }
        assert_eq!(column(2, "learner_phase"), "exciting");
        assert_eq!(column(2, "g1_fz_1"), "-9.5");
        assert_eq!(column(2, "tau_s_0"), "0");
    }

    #[test]
    fn a_state_recording_is_a_log_fit_imu_offset_reads() {
        let mut recorder = Recorder::new(Vec::new(), &[Topic::State], 4).unwrap();
        for step in 1..=40 {
            recorder.push(&state(step)).unwrap();
        }
        let csv = recorder.finish().unwrap();
        let path = std::env::temp_dir().join(format!("record-test-{}.csv", std::process::id()));
        std::fs::write(&path, csv).unwrap();
        let log = crate::offline::imu_offset::read_log(&path);
        let _ = std::fs::remove_file(&path);
        let log = log.map_err(|e| e.0).unwrap();
        assert_eq!(log.rate_hz, 2000.0);
        assert_eq!(log.samples.len(), 40);
    }

    #[test]
    fn unknown_and_empty_topic_lists_are_refused() {
        assert!(parse_topics("state,attitude").unwrap_err().contains("`attitude`"));
        assert!(parse_topics(" , ").is_err());
        assert_eq!(parse_topics("imu,imu").unwrap(), vec![Topic::Imu]);
    }
}
