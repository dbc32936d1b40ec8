//! The board's flight logs over the link: `log list`, `log download N FILE`, `log delete N`
//! (protocol 1.9: `ListLogs`, `ReadLog`, `DeleteLog`).
//!
//! **Download.** A file is read in chunks of [`LOG_CHUNK_LEN`] bytes, [`PIPELINE_DEPTH`]
//! requests in flight at once: one chunk per round trip would leave a radio (or USB, at the
//! board's 1 ms link pass) idle most of the time. Every answer names its file and offset, so it
//! is checked against the request it answers; answers may arrive in any order (a lost one is
//! asked for again after the link's retry time, [`Client::retry_after`]: a read changes nothing,
//! so asking twice is harmless) and are written in file order, so FILE always holds a contiguous
//! beginning of the log. `--resume` continues such a partial FILE from its length (its bytes are
//! not compared with the board's: a FILE longer than the log is refused).
//!
//! **Duration.** `log list` reads each file's first chunk (the header: the first step's time)
//! and its last [`TAIL_BYTES`] (the last step's time): two small reads per file, no download.

use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

use firmware::app::log::{LogReader, LogRecord};
use protocol::{
    DeleteLog, ListLogs, LogChunk, LogFileInfo, ReadLog, Reply, Request, LOG_CHUNK_LEN,
};

use crate::link::{Client, DeviceErrorText, LinkError};

/// Chunk requests in flight during a download. The board answers every request of a link pass
/// into its transmit buffer (eight frames, `firmware::app::TX_CAPACITY`); six chunk answers
/// leave room for events and a telemetry frame, so none is dropped for want of space.
pub const PIPELINE_DEPTH: usize = 6;
/// Times one chunk is asked for before the download gives up.
const CHUNK_ATTEMPTS: u32 = 6;
/// Bytes read from the end of a file to find its last step's time: a step record is at most
/// about 110 bytes framed, and a file closed in order ends with an end record and at most one
/// block of zeros (512 bytes), so the last 1,024 bytes hold at least one whole step.
pub const TAIL_BYTES: u32 = 1024;

/// One file as `log list` shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct ListedLog {
    pub info: LogFileInfo,
    /// From the first step to the last, s (`None` when the file holds no step).
    pub duration_s: Option<f64>,
}

/// Every log file on the board, ascending (as many `ListLogs` requests as pages).
pub fn list(client: &mut Client) -> Result<Vec<LogFileInfo>, LinkError> {
    let mut files = Vec::new();
    let mut first = 0;
    loop {
        let page = match client.request(&Request::ListLogs(ListLogs { first }), "the log list")? {
            Reply::LogList(page) => page,
            other => return Err(unexpected(&other, "the log list")),
        };
        let Some(last) = page.files.last().map(|f| f.number) else { break };
        files.extend(page.files);
        if !page.more {
            break;
        }
        first = last.saturating_add(1);
    }
    Ok(files)
}

/// Every log file with its duration.
pub fn list_with_durations(client: &mut Client) -> Result<Vec<ListedLog>, LinkError> {
    let files = list(client)?;
    let mut out = Vec::with_capacity(files.len());
    for info in files {
        let head_len = info.size_bytes.min(LOG_CHUNK_LEN as u32);
        let head = read_range(client, info.number, 0, head_len)?;
        let tail_start = info.size_bytes.saturating_sub(TAIL_BYTES).max(head_len);
        let tail = read_range(client, info.number, tail_start, info.size_bytes)?;
        out.push(ListedLog { info, duration_s: duration_s(&head, &tail) });
    }
    Ok(out)
}

/// From the header's first step to the last step record in `tail` (or in `head`), s.
fn duration_s(head: &[u8], tail: &[u8]) -> Option<f64> {
    let first_t_us = LogReader::new(head).find_map(|record| match record {
        LogRecord::Header(header) => Some(header.first_t_us),
        _ => None,
    })?;
    let last_step = |bytes: &[u8]| {
        LogReader::new(bytes)
            .filter_map(|record| match record {
                LogRecord::Step(step) => Some(step.t_us),
                _ => None,
            })
            .last()
    };
    let last_t_us = last_step(tail).or_else(|| last_step(head))?;
    Some(last_t_us.saturating_sub(first_t_us) as f64 * 1e-6)
}

/// What a download did.
#[derive(Debug, Clone, PartialEq)]
pub struct Downloaded {
    pub number: u32,
    /// Bytes in FILE now.
    pub size_bytes: u64,
    /// Bytes it already held (`--resume`).
    pub resumed_from: u64,
    pub seconds: f64,
    /// Chunk requests asked again after a lost answer.
    pub retries: u32,
    /// The file was still being written on the board (FILE holds what it had then).
    pub still_writing: bool,
}

/// Why a download stopped.
#[derive(Debug, thiserror::Error)]
pub enum DownloadError {
    #[error(transparent)]
    Link(#[from] LinkError),
    /// Bad input: nothing was downloaded.
    #[error("{0}")]
    Input(String),
    #[error("writing {path}: {source}")]
    Write { path: String, source: std::io::Error },
}

/// Download log `number` into `path` (continuing a partial `path` when `resume`), calling
/// `progress` with the bytes in `path` after every write and once with the total first.
pub fn download(
    client: &mut Client,
    number: u32,
    path: &Path,
    resume: bool,
    progress: &mut dyn FnMut(Progress),
) -> Result<Downloaded, DownloadError> {
    let started = Instant::now();
    let info = list(client)?.into_iter().find(|f| f.number == number).ok_or_else(|| {
        LinkError::Device(DeviceErrorText(protocol::DeviceError::NoSuchLog { number }))
    })?;
    let write_error =
        |source: std::io::Error| DownloadError::Write { path: path.display().to_string(), source };
    let existing = if resume {
        match std::fs::metadata(path) {
            Ok(meta) => meta.len(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => 0,
            Err(e) => return Err(write_error(e)),
        }
    } else {
        0
    };
    let size = u64::from(info.size_bytes);
    if existing > size {
        return Err(DownloadError::Input(format!(
            "{} holds {existing} bytes, more than log {number} ({size} bytes): not a partial \
             download of it",
            path.display()
        )));
    }
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .write(true)
        .append(resume)
        .truncate(!resume)
        .open(path)
        .map_err(write_error)?;
    progress(Progress::Total { bytes: size, done: existing });
    let retries_before = client.retries();
    let mut write = |bytes: &[u8], done: u64| -> Result<(), DownloadError> {
        file.write_all(bytes).map_err(write_error)?;
        progress(Progress::Done { bytes: done });
        Ok(())
    };
    let mut written = existing;
    read_chunks(client, number, existing as u32, info.size_bytes, &mut |chunk| {
        written += chunk.len() as u64;
        write(chunk, written)
    })?;
    file.flush().map_err(write_error)?;
    Ok(Downloaded {
        number,
        size_bytes: written,
        resumed_from: existing,
        seconds: started.elapsed().as_secs_f64(),
        retries: client.retries() - retries_before,
        still_writing: info.writing,
    })
}

/// How far a download is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Progress {
    /// The file's size, and what FILE held before.
    Total { bytes: u64, done: u64 },
    /// Bytes in FILE now.
    Done { bytes: u64 },
}

/// Delete log `number`.
pub fn delete(client: &mut Client, number: u32) -> Result<(), LinkError> {
    match client.request(&Request::DeleteLog(DeleteLog { number }), "the delete request")? {
        Reply::Done => Ok(()),
        other => Err(unexpected(&other, "the delete request")),
    }
}

/// Bytes `start..end` of log `number`, in memory.
fn read_range(
    client: &mut Client,
    number: u32,
    start: u32,
    end: u32,
) -> Result<Vec<u8>, LinkError> {
    let mut bytes = Vec::new();
    read_chunks(client, number, start, end, &mut |chunk| {
        bytes.extend_from_slice(chunk);
        Ok::<(), DownloadError>(())
    })
    .map_err(|e| match e {
        DownloadError::Link(link) => link,
        other => LinkError::Unexpected(other.to_string()),
    })?;
    Ok(bytes)
}

/// A chunk request in flight.
struct InFlight {
    offset: u32,
    sent: Instant,
    attempt: u32,
}

/// Read bytes `start..end` of log `number`, [`PIPELINE_DEPTH`] chunk requests in flight, and
/// hand them to `sink` in file order.
fn read_chunks(
    client: &mut Client,
    number: u32,
    start: u32,
    end: u32,
    sink: &mut dyn FnMut(&[u8]) -> Result<(), DownloadError>,
) -> Result<(), DownloadError> {
    let chunk_len = LOG_CHUNK_LEN as u32;
    let request = |offset: u32| {
        let len = (end - offset).min(chunk_len) as u16;
        Request::ReadLog(ReadLog { number, offset, len })
    };
    let retry_after = client.retry_after();
    // Chunks asked for, by sequence number; chunks arrived ahead of the write point.
    let mut in_flight: HashMap<u16, InFlight> = HashMap::new();
    let mut arrived: BTreeMap<u32, Vec<u8>> = BTreeMap::new();
    let mut next_offset = start;
    let mut write_offset = start;
    while write_offset < end {
        while in_flight.len() < PIPELINE_DEPTH && next_offset < end {
            let seq = client.post(&request(next_offset))?;
            in_flight
                .insert(seq, InFlight { offset: next_offset, sent: Instant::now(), attempt: 1 });
            next_offset = next_offset.saturating_add(chunk_len).min(end);
        }
        let pending: Vec<u16> = in_flight.keys().copied().collect();
        for (seq, response) in client.answers(&pending, retry_after / 4)? {
            let Some(asked) = in_flight.remove(&seq) else { continue };
            let chunk = match response {
                Ok(Reply::LogChunk(chunk)) => chunk,
                Ok(other) => return Err(unexpected(&other, "a log read").into()),
                Err(error) => return Err(LinkError::Device(DeviceErrorText(error)).into()),
            };
            check_chunk(&chunk, number, asked.offset, end)?;
            arrived.insert(asked.offset, chunk.bytes.to_vec());
        }
        while let Some(bytes) = arrived.remove(&write_offset) {
            sink(&bytes)?;
            write_offset += bytes.len() as u32;
        }
        // Lost requests or answers: ask again under a new sequence number.
        let lost: Vec<u16> = in_flight
            .iter()
            .filter(|(_, f)| f.sent.elapsed() >= retry_after)
            .map(|(s, _)| *s)
            .collect();
        for seq in lost {
            let Some(asked) = in_flight.remove(&seq) else { continue };
            if asked.attempt >= CHUNK_ATTEMPTS {
                return Err(LinkError::Timeout {
                    port: client.port().to_string(),
                    timeout_ms: (retry_after * CHUNK_ATTEMPTS).as_millis(),
                    what: "a log read",
                }
                .into());
            }
            client.count_retry();
            let seq = client.post(&request(asked.offset))?;
            in_flight.insert(
                seq,
                InFlight { offset: asked.offset, sent: Instant::now(), attempt: asked.attempt + 1 },
            );
        }
    }
    Ok(())
}

/// An answer must be the chunk asked for, whole (short only at the file's end as listed).
fn check_chunk(chunk: &LogChunk, number: u32, offset: u32, end: u32) -> Result<(), LinkError> {
    let wanted = (end - offset).min(LOG_CHUNK_LEN as u32) as usize;
    if chunk.number != number || chunk.offset != offset || chunk.bytes.len() != wanted {
        return Err(LinkError::Unexpected(format!(
            "log {number} at byte {offset}: the answer is {} bytes of log {} at byte {} ({} \
             expected)",
            chunk.bytes.len(),
            chunk.number,
            chunk.offset,
            wanted
        )));
    }
    Ok(())
}

fn unexpected(reply: &Reply, what: &str) -> LinkError {
    LinkError::Unexpected(format!("{reply:?} to {what}"))
}

/// `log list` as text: number, size in kB, duration, state.
pub fn list_text(files: &[ListedLog]) -> String {
    if files.is_empty() {
        return "no flight logs on the board\n".into();
    }
    let mut text = format!("{:>6}  {:>10}  {:>10}  state\n", "log", "size kB", "duration s");
    for file in files {
        let duration = file.duration_s.map_or_else(|| "-".into(), |s| format!("{s:.1}"));
        text.push_str(&format!(
            "{:>6}  {:>10.1}  {:>10}  {}\n",
            file.info.number,
            f64::from(file.info.size_bytes) / 1000.0,
            duration,
            if file.info.writing { "being written" } else { "complete" }
        ));
    }
    text
}

/// `log list --json`.
pub fn list_json(files: &[ListedLog]) -> serde_json::Value {
    serde_json::Value::Array(
        files
            .iter()
            .map(|file| {
                serde_json::json!({
                    "number": file.info.number,
                    "size_bytes": file.info.size_bytes,
                    "duration_s": file.duration_s,
                    "writing": file.info.writing,
                })
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::app::log::{id, Header, StepLogRecord, LOG_FORMAT_VERSION};
    use protocol::frame::encode;

    fn frame<T: serde::Serialize>(record_id: u8, seq: u16, record: &T) -> Vec<u8> {
        let mut out = [0u8; 256];
        let len = encode(record_id, seq, record, &mut out).unwrap();
        out[..len].to_vec()
    }

    #[test]
    fn the_duration_runs_from_the_headers_first_step_to_the_last_step_in_the_tail() {
        let header = Header {
            format: LOG_FORMAT_VERSION,
            firmware: [0, 1, 0],
            board: protocol::text("SITL"),
            control_rate_hz: 2000,
            params_layout: 0,
            param_slots: 0,
            first_step: 1,
            first_t_us: 500,
            always: false,
        };
        let step = |t_us| StepLogRecord {
            step: 3,
            t_us,
            imu: None,
            speeds_rad_s: [None; 8],
            commands: heapless::Vec::new(),
            phase: 0,
            flags: 0,
        };
        let head = frame(id::HEADER, 0, &header);
        // The tail begins inside a frame (skipped) and ends with zeros.
        let mut tail = frame(id::STEP, 7, &step(2_000_500))[5..].to_vec();
        tail.extend(frame(id::STEP, 8, &step(3_000_500)));
        tail.extend([0; 40]);
        assert_eq!(duration_s(&head, &tail), Some(3.0));
        assert_eq!(duration_s(&head, &[0; 10]), None, "no step: no duration");
        assert_eq!(duration_s(&[0; 10], &tail), None, "no header: no duration");
    }
}
