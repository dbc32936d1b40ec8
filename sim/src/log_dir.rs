//! The flight log's sink on the host: a directory of `LOG00001.BIN`, `LOG00002.BIN`, … files,
//! the blocks exactly as the board's SD card would get them (`firmware::app::log`).
//!
//! The SITL (`sitl --log-dir DIR`) and the bridge (`scenario bridge --log-dir DIR`) write here,
//! so every simulated flight can leave a log for `configurator-cli replay`. A new file takes the
//! number after the highest already in the directory, so earlier logs are never overwritten.
//!
//! It also serves its files to the link ([`LogFiles`]: `configurator-cli log list|download|
//! delete` against the SITL or the bridge), as the board will serve its card's: a listing reads
//! the directory, a read opens the file for one chunk, and the file being written is never
//! deleted. The graph reaches it under the lock the logger writes under, so a read sees whole
//! blocks only.

use firmware::app::log::{
    FileRead, LogFileError, LogFileList, LogFiles, LogSink, LogSinkError, LOG_BLOCK_LEN,
};
use protocol::LogFileInfo;
use std::fs::File;
use std::io::{ErrorKind, Read, Seek, SeekFrom, Write};
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
    /// The number of the file being written.
    writing: Option<u32>,
    /// The files written, in order.
    written: Vec<PathBuf>,
}

impl LogDir {
    /// Log into `dir` (created when missing).
    pub fn create(dir: &Path) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        Ok(Self { dir: dir.to_path_buf(), file: None, writing: None, written: Vec::new() })
    }

    /// The files begun so far, oldest first.
    pub fn files(&self) -> &[PathBuf] {
        &self.written
    }

    /// The numbers of the log files in the directory, ascending.
    fn numbers(&self) -> std::io::Result<Vec<u32>> {
        let mut numbers = Vec::new();
        for entry in std::fs::read_dir(&self.dir)? {
            if let Some(number) = entry?.file_name().to_str().and_then(log_file_number) {
                numbers.push(number);
            }
        }
        numbers.sort_unstable();
        Ok(numbers)
    }

    fn next_number(&self) -> std::io::Result<u32> {
        Ok(self.numbers()?.last().map_or(1, |highest| highest + 1))
    }

    /// The path of file `number`, when it is one of ours.
    fn path(&self, number: u32) -> Result<PathBuf, LogFileError> {
        if !(1..=MAX_LOG_NUMBER).contains(&number) {
            return Err(LogFileError::NoSuchFile);
        }
        Ok(self.dir.join(log_file_name(number)))
    }
}

/// A missing file is [`LogFileError::NoSuchFile`], any other failure [`LogFileError::Io`].
fn file_error(error: std::io::Error) -> LogFileError {
    match error.kind() {
        ErrorKind::NotFound => LogFileError::NoSuchFile,
        _ => LogFileError::Io,
    }
}

impl LogFiles for LogDir {
    fn list(&mut self, first: u32, out: &mut LogFileList) -> Result<bool, LogFileError> {
        out.clear();
        let numbers = self.numbers().map_err(|_| LogFileError::Io)?;
        let mut listed = numbers.into_iter().filter(|&number| number >= first);
        for number in listed.by_ref() {
            // A file deleted meanwhile is left out.
            let Ok(meta) = std::fs::metadata(self.dir.join(log_file_name(number))) else {
                continue;
            };
            let size_bytes = u32::try_from(meta.len()).unwrap_or(u32::MAX);
            let info = LogFileInfo { number, size_bytes, writing: self.writing == Some(number) };
            // Cannot fail: the loop ends once `out` is full.
            let _ = out.push(info);
            if out.is_full() {
                break;
            }
        }
        Ok(listed.next().is_some())
    }

    fn read(&mut self, number: u32, offset: u32, buf: &mut [u8]) -> Result<FileRead, LogFileError> {
        let mut file = File::open(self.path(number)?).map_err(file_error)?;
        let size = file.metadata().map_err(file_error)?.len();
        let size_bytes = u32::try_from(size).unwrap_or(u32::MAX);
        if u64::from(offset) > size {
            return Err(LogFileError::OffsetPastEnd { size_bytes });
        }
        file.seek(SeekFrom::Start(u64::from(offset))).map_err(file_error)?;
        let wanted = buf.len().min((size - u64::from(offset)) as usize);
        file.read_exact(&mut buf[..wanted]).map_err(file_error)?;
        Ok(FileRead { bytes_read: wanted, size_bytes })
    }

    fn delete(&mut self, number: u32) -> Result<(), LogFileError> {
        if self.writing == Some(number) {
            return Err(LogFileError::BeingWritten);
        }
        std::fs::remove_file(self.path(number)?).map_err(file_error)
    }
}

impl LogSink for LogDir {
    fn open(&mut self) -> Result<u32, LogSinkError> {
        self.file = None;
        self.writing = None;
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
        self.writing = Some(number);
        self.written.push(path);
        Ok(number)
    }

    /// The block goes to the file at once, whole, in one `write_all` on an unbuffered `File`:
    /// a SITL killed without warning (a power cut) leaves every complete block in the file.
    fn write_block(&mut self, block: &[u8; LOG_BLOCK_LEN]) -> Result<(), LogSinkError> {
        let file = self.file.as_mut().ok_or(LogSinkError::Io)?;
        file.write_all(block).map_err(|_| LogSinkError::Io)
    }

    fn close(&mut self) -> Result<(), LogSinkError> {
        self.writing = None;
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

    #[test]
    fn files_are_listed_read_and_deleted_but_not_the_one_being_written() {
        let dir = std::env::temp_dir().join(format!("log-dir-files-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut logs = LogDir::create(&dir).unwrap();
        for number in [3, 5] {
            std::fs::write(dir.join(log_file_name(number)), vec![number as u8; 700]).unwrap();
        }
        std::fs::write(dir.join("NOTES.TXT"), b"not a log").unwrap();
        assert_eq!(logs.open(), Ok(6));
        logs.write_block(&[9; LOG_BLOCK_LEN]).unwrap();

        let mut out = heapless::Vec::new();
        assert_eq!(logs.list(0, &mut out), Ok(false));
        let listed: Vec<_> = out.iter().map(|f| (f.number, f.size_bytes, f.writing)).collect();
        assert_eq!(listed, [(3, 700, false), (5, 700, false), (6, 512, true)]);
        assert_eq!(logs.list(4, &mut out), Ok(false));
        assert_eq!(out.len(), 2);

        let mut buf = [0u8; 224];
        assert_eq!(logs.read(5, 600, &mut buf), Ok(FileRead { bytes_read: 100, size_bytes: 700 }));
        assert!(buf[..100].iter().all(|&b| b == 5));
        assert_eq!(logs.read(5, 700, &mut buf), Ok(FileRead { bytes_read: 0, size_bytes: 700 }));
        assert_eq!(
            logs.read(5, 701, &mut buf),
            Err(LogFileError::OffsetPastEnd { size_bytes: 700 })
        );
        assert_eq!(logs.read(4, 0, &mut buf), Err(LogFileError::NoSuchFile));
        assert_eq!(logs.read(0, 0, &mut buf), Err(LogFileError::NoSuchFile));

        assert_eq!(logs.delete(6), Err(LogFileError::BeingWritten));
        assert_eq!(logs.delete(3), Ok(()));
        assert_eq!(logs.delete(3), Err(LogFileError::NoSuchFile));
        assert!(!dir.join("LOG00003.BIN").exists());
        assert_eq!(logs.close(), Ok(()));
        assert_eq!(logs.delete(6), Ok(()), "a closed file can go");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_listing_comes_in_pages_of_sixteen() {
        let dir = std::env::temp_dir().join(format!("log-dir-pages-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut logs = LogDir::create(&dir).unwrap();
        for number in 1..=20 {
            std::fs::write(dir.join(log_file_name(number)), b"x").unwrap();
        }
        let mut out = heapless::Vec::new();
        assert_eq!(logs.list(1, &mut out), Ok(true));
        assert_eq!(out.iter().map(|f| f.number).collect::<Vec<_>>(), (1..=16).collect::<Vec<_>>());
        assert_eq!(logs.list(17, &mut out), Ok(false));
        assert_eq!(out.iter().map(|f| f.number).collect::<Vec<_>>(), [17, 18, 19, 20]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
