//! `log to-mcap LOG FILE.mcap`: a flight log as an MCAP file, which Foxglove and PlotJuggler open
//! without a plugin.
//!
//! Written with the `mcap` crate (Foxglove's own Rust library for the format; chunked, indexed,
//! uncompressed: its zstd and lz4 features are left out, they would build two C libraries for a
//! file that is read locally). Every channel carries JSON messages described by a JSON schema
//! (`jsonschema` + `json`, the encoding pair both viewers read natively). Log time and publish
//! time are the control step's time (ns since the board's start-up); a command or a parameter
//! set takes the time of the step logged just before it.
//!
//! | topic | one message per | fields |
//! |---|---|---|
//! | `/imu` | step with an IMU sample | `gyro_rad_s` {x, y, z}, `accel_mps2` {x, y, z} (IMU axes, as delivered) |
//! | `/speeds` | step | `m1`… rad/s, only the motors that reported |
//! | `/commands` | step | `m1`… δ ∈ [0, 1] |
//! | `/phase` | step | `phase` (0 idle … 5 done), `name`, `failed`, `flying`, `armed` |
//! | `/command` | command applied | `step`, `command` (the logged command, externally tagged) |
//! | `/parameters` | parameter set completed or changed | by name (a number, or an array): every parameter first, then those that changed |
//! | `/learner` | learner snapshot (25 Hz, each G1 block in turn) | the protocol's `LearnerTelemetry`, field by field |
//! | `/flight` | flight snapshot (25 Hz) | the protocol's `FlightTelemetry`, field by field |
//!
//! Every step message carries `step`, the control step's number. A snapshot takes its own time
//! (`t_us`), not the step's before it.

use std::collections::BTreeMap;
use std::io::{BufWriter, Seek, Write};
use std::path::PathBuf;

use firmware::app::log::{
    flags, phase_from_code, LogReader, LogRecord, ParamsAssembler, StepLogRecord,
};
use firmware::app::Params;
use serde_json::{json, Map, Value};

use super::replay::phase_name;
use super::InputError;

/// `log to-mcap` arguments.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// The flight log (LOG00001.BIN).
    pub log: PathBuf,
    /// The MCAP file to write.
    pub mcap: PathBuf,
}

/// The channels' topics, in the order they are added.
pub const TOPICS: [&str; 8] =
    ["/imu", "/speeds", "/commands", "/phase", "/command", "/parameters", "/learner", "/flight"];

/// Messages written per topic (in [`TOPICS`] order).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Exported {
    pub messages: [u64; TOPICS.len()],
    pub bad_frames: u32,
    pub torn_tail_bytes: u32,
}

fn vector3() -> Value {
    json!({"type": "object", "properties": {
        "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}})
}

fn per_motor(unit: &str) -> Value {
    json!({"type": "object", "properties": {"step": {"type": "integer"}},
           "patternProperties": {"^m[1-8]$": {"type": "number", "description": unit}}})
}

/// The JSON schema of each topic's messages.
fn schemas() -> [Value; TOPICS.len()] {
    [
        json!({"type": "object", "properties": {
            "step": {"type": "integer"}, "gyro_rad_s": vector3(), "accel_mps2": vector3()}}),
        per_motor("rad/s"),
        per_motor("command δ, 0 to 1"),
        json!({"type": "object", "properties": {
            "step": {"type": "integer"}, "phase": {"type": "integer"}, "name": {"type": "string"},
            "failed": {"type": "boolean"}, "flying": {"type": "boolean"},
            "armed": {"type": "boolean"}}}),
        json!({"type": "object", "properties": {
            "step": {"type": "integer"}, "command": {"type": ["object", "string"]}}}),
        json!({"type": "object", "additionalProperties": {"type": ["number", "array"]}}),
        snapshot("the learner's state: protocol LearnerTelemetry (docs/protocol.md)"),
        snapshot("the closed loop's state: protocol FlightTelemetry (docs/protocol.md)"),
    ]
}

/// A snapshot's schema: an object whose fields are the protocol type's (serde's names).
fn snapshot(description: &str) -> Value {
    json!({"type": "object", "description": description,
           "properties": {"t_us": {"type": "integer"}}})
}

fn xyz(v: &[f32]) -> Value {
    json!({"x": v[0], "y": v[1], "z": v[2]})
}

/// `m1`, `m2`, … for the values that are there.
fn motors(step: u32, values: impl Iterator<Item = Option<f32>>) -> Value {
    let mut map = Map::new();
    map.insert("step".into(), json!(step));
    for (i, value) in values.enumerate() {
        if let Some(value) = value {
            map.insert(format!("m{}", i + 1), json!(value));
        }
    }
    Value::Object(map)
}

/// The messages of one step, by topic index.
fn step_messages(step: &StepLogRecord) -> Vec<(usize, Value)> {
    let mut out = Vec::with_capacity(4);
    if let Some(imu) = step.imu {
        out.push((
            0,
            json!({"step": step.step, "gyro_rad_s": xyz(&imu[..3]),
                            "accel_mps2": xyz(&imu[3..])}),
        ));
    }
    let count = step.commands.len();
    out.push((1, motors(step.step, step.speeds_rad_s[..count].iter().copied())));
    out.push((2, motors(step.step, step.commands.iter().map(|&c| Some(c)))));
    let name = phase_from_code(step.phase).map_or("unknown", phase_name);
    out.push((
        3,
        json!({"step": step.step, "phase": step.phase, "name": name,
               "failed": step.flags & flags::FAILED != 0,
               "flying": step.flags & flags::FLYING != 0,
               "armed": step.flags & flags::ARMED != 0}),
    ));
    out
}

/// The parameters of `params` by name: every one, or those that differ from `before` (the
/// in-flight refinement stores a new model hundreds of times a second; the whole set each time
/// would make the file ten times the log's size).
fn parameters(params: &Params, before: Option<&Params>) -> Value {
    let mut map = Map::new();
    let changed = |i: usize| before.is_none_or(|b| b.values(i) != params.values(i));
    let infos = (0..).map_while(|i| params.info(i));
    for info in infos.filter(|info| changed(usize::from(info.index))) {
        let value = match info.value.as_slice() {
            [one] => json!(one),
            many => json!(many),
        };
        map.insert(info.name.to_string(), value);
    }
    Value::Object(map)
}

/// Write the log's records as MCAP to `out`.
pub fn export<W: Write + Seek>(bytes: &[u8], out: W) -> Result<Exported, InputError> {
    let mcap_error = |e: mcap::McapError| InputError(format!("writing the MCAP: {e}"));
    let mut writer =
        mcap::WriteOptions::new().compression(None).profile("").create(out).map_err(mcap_error)?;
    let mut channels = [0u16; TOPICS.len()];
    for ((topic, schema), channel) in TOPICS.iter().zip(schemas()).zip(channels.iter_mut()) {
        let name = format!("fc{}", topic.replace('/', "."));
        let schema_id = writer
            .add_schema(&name, "jsonschema", schema.to_string().as_bytes())
            .map_err(mcap_error)?;
        *channel =
            writer.add_channel(schema_id, topic, "json", &BTreeMap::new()).map_err(mcap_error)?;
    }
    let mut exported = Exported::default();
    let mut write = |topic: usize, t_us: u64, message: &Value| {
        let header = mcap::records::MessageHeader {
            channel_id: channels[topic],
            sequence: exported.messages[topic] as u32,
            log_time: t_us * 1000,
            publish_time: t_us * 1000,
        };
        exported.messages[topic] += 1;
        writer.write_to_known_channel(&header, message.to_string().as_bytes()).map_err(mcap_error)
    };
    let mut reader = LogReader::new(bytes);
    let mut t_us = 0u64;
    let mut assembler = ParamsAssembler::default();
    let mut last_params: Option<Params> = None;
    let mut steps = 0u64;
    for record in reader.by_ref() {
        match record {
            LogRecord::Header(header) => t_us = header.first_t_us,
            LogRecord::Step(step) => {
                t_us = step.t_us;
                steps += 1;
                for (topic, message) in step_messages(&step) {
                    write(topic, t_us, &message)?;
                }
            }
            LogRecord::Command(command) => {
                let message = json!({"step": command.step, "command": command.command});
                write(4, t_us, &message)?;
            }
            LogRecord::Params(part) => {
                if let Some(params) = assembler.push(&part) {
                    if last_params.as_ref() != Some(&params) {
                        write(5, t_us, &parameters(&params, last_params.as_ref()))?;
                        last_params = Some(params);
                    }
                }
            }
            LogRecord::Learner(learner) => {
                write(6, learner.t_us, &serde_json::to_value(learner).unwrap_or_default())?;
            }
            LogRecord::Flight(flight) => {
                write(7, flight.t_us, &serde_json::to_value(flight).unwrap_or_default())?;
            }
            LogRecord::Work(_)
            | LogRecord::Dropped(_)
            | LogRecord::End(_)
            | LogRecord::Adopted(_)
            | LogRecord::Arming(_)
            | LogRecord::State(_) => {}
        }
    }
    if steps == 0 {
        return Err(InputError("the log has no control steps".into()));
    }
    writer.finish().map_err(mcap_error)?;
    let stats = reader.stats();
    exported.bad_frames = stats.bad_frames;
    exported.torn_tail_bytes = stats.torn_tail_bytes;
    Ok(exported)
}

/// The command: read the log, write the MCAP, say what was written.
pub fn run(args: &Args) -> Result<String, InputError> {
    let bytes = std::fs::read(&args.log)
        .map_err(|e| InputError(format!("cannot read {}: {e}", args.log.display())))?;
    // Built in memory first: bad input leaves no partial file behind.
    let mut mcap = std::io::Cursor::new(Vec::new());
    let exported = export(&bytes, BufWriter::new(&mut mcap))?;
    std::fs::write(&args.mcap, mcap.get_ref())
        .map_err(|e| InputError(format!("cannot write {}: {e}", args.mcap.display())))?;
    let counts: Vec<String> = TOPICS
        .iter()
        .zip(exported.messages)
        .map(|(topic, count)| format!("{topic} {count}"))
        .collect();
    Ok(format!(
        "{}: {} ({} bad frames, {} bytes of torn tail skipped)\n",
        args.mcap.display(),
        counts.join(", "),
        exported.bad_frames,
        exported.torn_tail_bytes
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::app::log::{
        id, CommandRecord, Header, LoggedCommand, ParamsRecord, LOG_FORMAT_VERSION,
        PARAMS_CHUNK_SLOTS,
    };
    use protocol::frame::encode;

    /// One record framed as the logger frames it, appended to `bytes`.
    fn put<T: serde::Serialize>(bytes: &mut Vec<u8>, seq: &mut u16, record_id: u8, record: &T) {
        let mut out = [0u8; 256];
        let len = encode(record_id, *seq, record, &mut out).unwrap();
        *seq += 1;
        bytes.extend_from_slice(&out[..len]);
    }

    /// A log of `steps` steps (every second one with an IMU sample), a whole parameter set and
    /// an arming.
    fn log(steps: u32) -> (Vec<u8>, Vec<StepLogRecord>) {
        let mut bytes = Vec::new();
        let mut seq = 0u16;
        let header = Header {
            format: LOG_FORMAT_VERSION,
            firmware: [0, 1, 0],
            board: protocol::text("SITL"),
            control_rate_hz: 2000,
            params_layout: firmware::app::params::LAYOUT_HASH,
            param_slots: firmware::app::params::PARAM_SLOTS as u16,
            first_step: 1,
            first_t_us: 500,
            always: true,
        };
        put(&mut bytes, &mut seq, id::HEADER, &header);
        let params = Params::default();
        for (i, part) in params.slots().chunks(PARAMS_CHUNK_SLOTS).enumerate() {
            let record = ParamsRecord {
                offset: (i * PARAMS_CHUNK_SLOTS) as u16,
                values: heapless::Vec::from_slice(part).unwrap(),
            };
            put(&mut bytes, &mut seq, id::PARAMS, &record);
        }
        let arm = CommandRecord { step: 1, command: LoggedCommand::ArmThrowToFly };
        put(&mut bytes, &mut seq, id::COMMAND, &arm);
        let records: Vec<StepLogRecord> = (1..=steps)
            .map(|step| StepLogRecord {
                step,
                t_us: u64::from(step) * 500,
                imu: (step % 2 == 0).then_some([0.1, 0.2, step as f32, 0.0, 0.0, -9.81]),
                speeds_rad_s: [
                    Some(900.0 + step as f32),
                    None,
                    Some(1.0),
                    Some(2.0),
                    None,
                    None,
                    None,
                    None,
                ],
                commands: heapless::Vec::from_slice(&[0.25, 0.5, 0.0, 1.0]).unwrap(),
                phase: 4,
                flags: flags::ARMED,
            })
            .collect();
        for record in &records {
            put(&mut bytes, &mut seq, id::STEP, record);
        }
        // Snapshots at their own time (the logger may write one before the steps it follows).
        let learner = protocol::LearnerTelemetry { t_us: 7_250, g1_block: 1, ..Default::default() };
        put(&mut bytes, &mut seq, id::LEARNER, &learner);
        let flight =
            protocol::FlightTelemetry { t_us: 7_000, tilt_error_rad: 0.25, ..Default::default() };
        put(&mut bytes, &mut seq, id::FLIGHT, &flight);
        (bytes, records)
    }

    #[test]
    fn the_mcap_reads_back_with_a_message_per_step_and_record_at_the_steps_time() {
        let (bytes, steps) = log(40);
        let mut out = std::io::Cursor::new(Vec::new());
        let exported = export(&bytes, &mut out).unwrap();
        assert_eq!(exported.messages, [20, 40, 40, 40, 1, 1, 1, 1]);
        let mcap = out.into_inner();
        let mut by_topic: BTreeMap<String, Vec<(u64, Value)>> = BTreeMap::new();
        for message in mcap::MessageStream::new(&mcap).unwrap() {
            let message = message.unwrap();
            assert_eq!(message.channel.message_encoding, "json");
            let schema = message.channel.schema.as_ref().expect("every channel has a schema");
            assert_eq!(schema.encoding, "jsonschema");
            let value: Value = serde_json::from_slice(&message.data).unwrap();
            by_topic
                .entry(message.channel.topic.clone())
                .or_default()
                .push((message.log_time, value));
        }
        let counts: Vec<usize> =
            TOPICS.iter().map(|t| by_topic.get(*t).map_or(0, Vec::len)).collect();
        assert_eq!(counts, [20, 40, 40, 40, 1, 1, 1, 1]);
        // The snapshots at their own time, field by field.
        let (t_ns, learner) = &by_topic["/learner"][0];
        assert_eq!((*t_ns, learner["g1_block"].as_u64()), (7_250_000, Some(1)));
        let (t_ns, flight) = &by_topic["/flight"][0];
        assert_eq!((*t_ns, flight["tilt_error_rad"].as_f64()), (7_000_000, Some(0.25)));

        // IMU of step 10: the logged sample at the step's time.
        let (t_ns, imu) = &by_topic["/imu"][4];
        assert_eq!((*t_ns, imu["step"].as_u64()), (5_000_000, Some(10)));
        assert_eq!(imu["gyro_rad_s"]["z"], 10.0);
        assert!((imu["accel_mps2"]["z"].as_f64().unwrap() + 9.81).abs() < 1e-6);
        // Speeds only where reported; commands for every motor.
        let (_, speeds) = &by_topic["/speeds"][6];
        assert_eq!(speeds["m1"].as_f64(), Some(f64::from(steps[6].speeds_rad_s[0].unwrap())));
        assert!(speeds.get("m2").is_none() && speeds["m4"] == 2.0);
        let (_, commands) = &by_topic["/commands"][0];
        assert_eq!((commands["m2"].as_f64(), commands["m4"].as_f64()), (Some(0.5), Some(1.0)));
        let (_, phase) = &by_topic["/phase"][0];
        assert_eq!(
            (phase["name"].as_str(), phase["armed"].as_bool()),
            (Some("exciting"), Some(true))
        );
        // The arming, before the first step, at the header's time; the parameters by name.
        assert_eq!(by_topic["/command"][0].0, 500_000);
        assert_eq!(by_topic["/command"][0].1["command"], "ArmThrowToFly");
        let (_, params) = &by_topic["/parameters"][0];
        assert_eq!(params["log_always"], 0.0);
        assert_eq!(params["imu_offset_m"].as_array().map(Vec::len), Some(3));
    }

    #[test]
    fn a_log_without_steps_is_refused() {
        let (bytes, _) = log(0);
        let error = export(&bytes, std::io::Cursor::new(Vec::new())).unwrap_err();
        assert!(error.0.contains("no control steps"), "{}", error.0);
    }
}
