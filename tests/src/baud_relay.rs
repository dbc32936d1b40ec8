//! A test double for a telemetry radio's USB-UART adapter that enforces its rate.
//!
//! USB CDC and pseudo-terminals ignore the rate a serial port is opened at, so a configurator
//! that opens a SiK radio's adapter at the wrong rate passes every test against the SITL. This
//! relay does not let it: it serves a pseudo-terminal whose slave the configurator opens with
//! `--port`, forwards the bytes between it and a far end (the SITL's simulated radio), and reads
//! the output rate the configurator set on the slave ([`sim::serve::Pty::output_baud`]). At the
//! adapter's rate the bytes pass untouched; at any other rate every byte in both directions is
//! garbled as a UART at the wrong rate garbles it ([`Garbler`]): scrambled, some lost, breaks
//! read as 0x00, so no COBS/CRC frame survives but bytes still arrive. Linux only (the rate is
//! read with `TCGETS2`).

use firmware::app::hal::Port;
use sim::serve::Pty;
use std::io::{ErrorKind, Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// What the relay has seen and done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RelayStats {
    /// Bytes forwarded untouched (the configurator at the adapter's rate), both directions.
    pub bytes_passed: u64,
    /// Bytes that went in garbled (the configurator at another rate), both directions.
    pub bytes_garbled: u64,
    /// The output rate last read on the slave while bytes moved, baud.
    pub last_baud: Option<u32>,
}

/// A running relay: stops (and closes its pseudo-terminal) when dropped.
pub struct BaudRelay {
    path: PathBuf,
    stats: Arc<Mutex<RelayStats>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl BaudRelay {
    /// A relay between a new pseudo-terminal and the serial device `far_end` (opened
    /// non-blocking), enforcing `uart_baud` on the new pseudo-terminal's slave.
    pub fn start(far_end: &Path, uart_baud: u32) -> std::io::Result<Self> {
        let mut pty = Pty::open()?;
        let path = pty.slave_path().to_path_buf();
        pty.output_baud()?;
        let mut far = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
            .open(far_end)?;
        let stats = Arc::new(Mutex::new(RelayStats::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let (thread_stats, thread_stop) = (Arc::clone(&stats), Arc::clone(&stop));
        let thread = std::thread::Builder::new().name("baud-relay".into()).spawn(move || {
            let mut up = Garbler::default();
            let mut down = Garbler::default();
            let mut buffer = [0u8; 1024];
            while !thread_stop.load(Ordering::Relaxed) {
                let baud = pty.output_baud().ok();
                let at_rate = baud == Some(uart_baud);
                let mut moved = 0;
                // Configurator → far end.
                let n = Port::read(&mut pty, &mut buffer).unwrap_or(0);
                if n > 0 {
                    let bytes = pass(&buffer[..n], at_rate, &mut up);
                    write_all_nonblocking(&mut far, &bytes);
                }
                moved += n;
                // Far end → configurator.
                // WouldBlock: nothing waits; another error (the far end gone): nothing comes.
                let n = far.read(&mut buffer).unwrap_or(0);
                if n > 0 {
                    let bytes = pass(&buffer[..n], at_rate, &mut down);
                    let _ = Port::write(&mut pty, &bytes);
                }
                moved += n;
                if moved == 0 {
                    std::thread::sleep(Duration::from_millis(1));
                    continue;
                }
                let mut stats = thread_stats.lock().unwrap();
                stats.last_baud = baud;
                if at_rate {
                    stats.bytes_passed += moved as u64;
                } else {
                    stats.bytes_garbled += moved as u64;
                }
            }
        })?;
        Ok(Self { path, stats, stop, thread: Some(thread) })
    }

    /// The pseudo-terminal's slave: the configurator's `--port`.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What the relay has seen and done so far.
    pub fn stats(&self) -> RelayStats {
        *self.stats.lock().unwrap()
    }
}

impl Drop for BaudRelay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// `bytes` as the far UART receives them: untouched at its rate, else garbled.
fn pass(bytes: &[u8], at_rate: bool, garbler: &mut Garbler) -> Vec<u8> {
    if at_rate {
        bytes.to_vec()
    } else {
        garbler.garble(bytes)
    }
}

/// Write all of `bytes` to a non-blocking `file`, waiting while it is full (at most 1 s).
fn write_all_nonblocking(file: &mut std::fs::File, mut bytes: &[u8]) {
    let deadline = std::time::Instant::now() + Duration::from_secs(1);
    while !bytes.is_empty() && std::time::Instant::now() < deadline {
        match file.write(bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(1))
            }
            Err(_) => return,
        }
    }
}

/// What a UART at another rate makes of a byte stream, deterministically: every twelfth byte
/// a break (read as 0x00, which also ends the receiver's COBS frame, so its decoder counts an
/// error rather than waiting), a quarter of the others lost, the rest scrambled. A frame's
/// CRC-32C then fails; bytes still arrive, as they do from a real radio at the wrong rate.
#[derive(Debug, Default)]
pub struct Garbler {
    /// Bytes garbled so far in this direction.
    position: u64,
}

/// Every how many bytes a break (0x00) is read.
const BREAK_EVERY: u64 = 12;

impl Garbler {
    /// `bytes` garbled.
    pub fn garble(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::with_capacity(bytes.len());
        for &byte in bytes {
            let position = self.position;
            self.position += 1;
            let hash = splitmix64(position ^ (u64::from(byte) << 40));
            if position % BREAK_EVERY == BREAK_EVERY - 1 {
                out.push(0);
            } else if !hash.is_multiple_of(4) {
                out.push(byte.rotate_left(3) ^ (hash >> 32) as u8);
            }
        }
        out
    }
}

/// SplitMix64's output function: a well-mixed 64-bit hash of `x`.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// No frame survives the garbling, yet most bytes arrive.
    #[test]
    fn a_garbled_stream_keeps_its_bytes_but_not_one_frame() {
        let request = protocol::Request::GetStatus(());
        let mut stream = Vec::new();
        for seq in 0..200u16 {
            let mut frame = [0u8; protocol::MAX_FRAME_LEN];
            let n = request.encode(seq, &mut frame).unwrap();
            stream.push(0);
            stream.extend_from_slice(&frame[..n]);
        }
        let decoded = |bytes: &[u8]| {
            let mut decoder = protocol::Decoder::new();
            bytes.iter().filter(|&&b| matches!(decoder.push(b), Some(Ok(_)))).count()
        };
        assert_eq!(decoded(&stream), 200, "the stream as sent is 200 frames");
        let garbled = Garbler::default().garble(&stream);
        assert_eq!(decoded(&garbled), 0);
        assert!(garbled.len() * 2 > stream.len(), "{} of {} bytes", garbled.len(), stream.len());
        assert!(garbled.iter().filter(|&&b| b == 0).count() as u64 >= stream.len() as u64 / 12);
    }
}
