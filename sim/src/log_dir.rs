//! The flight log's sink on the host: a directory of `LOG00001.BIN`, `LOG00002.BIN`, … files,
//! the blocks exactly as the board's SD card would get them (`firmware::app::log`).
//!
//! The SITL (`sitl --log-dir DIR`) and the bridge (`scenario bridge --log-dir DIR`) write here,
//! so every simulated flight can leave a log for `configurator-cli replay`. A new file takes the
//! number after the highest already in the directory, so earlier logs are never overwritten.

use firmware::app::log::{LogSink, LogSinkError, LOG_BLOCK_LEN};
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Highest file number (`LOG99999.BIN`).
pub const MAX_LOG_NUMBER: u32 = 99_999;

/// The name of log file `number`.
pub fn log_file_name(number: u32) -> String {
    format!("LOG{number:05}.BIN")
}

/// The number of a file called `LOGnnnnn.BIN`.
pub fn log_file_number(name: &str) -> Option<u32> {
    let digits = name.strip_prefix("LOG")?.strip_suffix(".BIN")?;
    (digits.len() == 5 && digits.bytes().all(|b| b.is_ascii_digit()))
        .then(|| digits.parse().ok())
        .flatten()
}

/// A directory of log files.
#[derive(Debug)]
pub struct LogDir {
    dir: PathBuf,
    file: Option<File>,
    /// The files written, in order.
    written: Vec<PathBuf>,
}

impl LogDir {
    /// Log into `dir` (created when missing).
    pub fn create(dir: &Path) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        Ok(Self { dir: dir.to_path_buf(), file: None, written: Vec::new() })
    }

    /// The files begun so far, oldest first.
    pub fn files(&self) -> &[PathBuf] {
        &self.written
    }

    fn next_number(&self) -> std::io::Result<u32> {
        let mut highest = 0;
        for entry in std::fs::read_dir(&self.dir)? {
            if let Some(number) = entry?.file_name().to_str().and_then(log_file_number) {
                highest = highest.max(number);
            }
        }
        Ok(highest + 1)
    }
}

impl LogSink for LogDir {
    fn open(&mut self) -> Result<u32, LogSinkError> {
        self.file = None;
        let number = self.next_number().map_err(|_| LogSinkError::Io)?;
        if number > MAX_LOG_NUMBER {
            return Err(LogSinkError::Full);
        }
        let path = self.dir.join(log_file_name(number));
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|_| LogSinkError::Io)?;
        self.file = Some(file);
        self.written.push(path);
        Ok(number)
    }

    fn write_block(&mut self, block: &[u8; LOG_BLOCK_LEN]) -> Result<(), LogSinkError> {
        let file = self.file.as_mut().ok_or(LogSinkError::Io)?;
        file.write_all(block).map_err(|_| LogSinkError::Io)
    }

    fn close(&mut self) -> Result<(), LogSinkError> {
        match self.file.take() {
            Some(mut file) => file.flush().map_err(|_| LogSinkError::Io),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_are_numbered_after_the_highest_present_and_never_overwritten() {
        let dir = std::env::temp_dir().join(format!("log-dir-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut logs = LogDir::create(&dir).unwrap();
        std::fs::write(dir.join("LOG00007.BIN"), b"old").unwrap();
        std::fs::write(dir.join("LOG7.BIN"), b"not ours").unwrap();
        assert_eq!(logs.open(), Ok(8));
        logs.write_block(&[1; LOG_BLOCK_LEN]).unwrap();
        assert_eq!(logs.close(), Ok(()));
        assert_eq!(logs.open(), Ok(9));
        assert_eq!(std::fs::read(dir.join("LOG00007.BIN")).unwrap(), b"old");
        assert_eq!(std::fs::read(dir.join("LOG00008.BIN")).unwrap(), vec![1; LOG_BLOCK_LEN]);
        assert_eq!(log_file_number("LOG00042.BIN"), Some(42));
        assert_eq!(log_file_number("LOG0042.BIN"), None);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
