//! The SITL's flash: a file that behaves like the H743's configuration flash.
//!
//! [`FileFlash`] implements `embedded-storage`'s [`NorFlash`] with the H743's geometry
//! ([`WRITE_SIZE`] 32-byte words, [`ERASE_SIZE`] 128 KiB sectors) and its rules: an erased
//! byte reads 0xFF, a word is programmed once after an erase (programming a word that is not
//! erased is refused, as the H743 refuses it), and every write or erase goes to the file before
//! it returns. A saved configuration therefore survives a restart of the SITL exactly as it
//! survives a power cycle of a board. A file of the wrong size is refused rather than
//! reformatted, so a user's configuration is never silently lost.
//!
//! [`FlashFault::Bad`] (the SITL's `--fault-flash bad`) makes the flash fail as a damaged part
//! does: every read reports an error (the H743's ECC reports a damaged word rather than returning
//! it) with garbage in the buffer, and every write or erase fails. The file itself is left
//! untouched. (A flash that returned garbage *without* an error would look erased to
//! sequential-storage: nothing stored, the defaults in force.)

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Programming granularity, bytes: one H743 flash word (256 bits).
pub const WRITE_SIZE: usize = 32;
/// Erase granularity, bytes: one H743 sector.
pub const ERASE_SIZE: usize = 128 * 1024;
/// Sectors of the configuration store (sequential-storage needs at least two).
pub const SECTORS: usize = 2;
/// Size of the flash file, bytes.
pub const FLASH_BYTES: usize = SECTORS * ERASE_SIZE;

/// Why the flash file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum FlashFileError {
    #[error("flash file {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("flash file {path} has {len} bytes, not {FLASH_BYTES}: not a SITL flash file (move it away or pick another --flash-file)")]
    Size { path: PathBuf, len: u64 },
}

/// A flash operation the file refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlashError {
    NotAligned,
    OutOfBounds,
    /// A word that is not erased was programmed.
    NotErased,
    /// The file could not be written.
    Io,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::NotAligned => NorFlashErrorKind::NotAligned,
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            Self::NotErased | Self::Io => NorFlashErrorKind::Other,
        }
    }
}

/// How a [`FileFlash`] fails on purpose (fault injection).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FlashFault {
    /// Reads fail, leaving garbage in the buffer (a fixed pseudo-random byte per address);
    /// writes and erases fail; the file is never touched.
    Bad,
}

/// The flash, mirrored in memory and written through to its file.
pub struct FileFlash {
    file: File,
    bytes: Vec<u8>,
    fault: Option<FlashFault>,
}

impl FileFlash {
    /// Open `path`, creating an erased flash file (and its directory) when it does not exist.
    pub fn open(path: &Path) -> Result<Self, FlashFileError> {
        let io = |source| FlashFileError::Io { path: path.to_path_buf(), source };
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(io)?;
        }
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut bytes = vec![0xFF; FLASH_BYTES];
        if len == 0 {
            file.write_all(&bytes).map_err(io)?;
            file.sync_all().map_err(io)?;
        } else if len != FLASH_BYTES as u64 {
            return Err(FlashFileError::Size { path: path.to_path_buf(), len });
        } else {
            file.read_exact(&mut bytes).map_err(io)?;
        }
        Ok(Self { file, bytes, fault: None })
    }

    /// This flash failing as `fault` says (fault injection).
    pub fn with_fault(self, fault: Option<FlashFault>) -> Self {
        Self { fault, ..self }
    }

    /// The flash range the configuration store uses: all of it.
    pub fn store_range() -> core::ops::Range<u32> {
        0..FLASH_BYTES as u32
    }

    fn write_through(&mut self, offset: usize, len: usize) -> Result<(), FlashError> {
        let slice = &self.bytes[offset..offset + len];
        self.file
            .seek(SeekFrom::Start(offset as u64))
            .and_then(|_| self.file.write_all(slice))
            .and_then(|_| self.file.sync_data())
            .map_err(|_| FlashError::Io)
    }

    fn check(&self, offset: u32, len: usize, align: usize) -> Result<usize, FlashError> {
        let offset = offset as usize;
        if !offset.is_multiple_of(align) || !len.is_multiple_of(align) {
            return Err(FlashError::NotAligned);
        }
        if offset + len > self.bytes.len() {
            return Err(FlashError::OutOfBounds);
        }
        Ok(offset)
    }
}

/// The default flash file: `sitl-flash.bin` in the user's data directory
/// (`~/.local/share/fc-sitl/` on Linux), or the current directory without one.
pub fn default_flash_path() -> PathBuf {
    directories::ProjectDirs::from("", "", "fc-sitl")
        .map(|dirs| dirs.data_dir().join("sitl-flash.bin"))
        .unwrap_or_else(|| PathBuf::from("sitl-flash.bin"))
}

/// The byte a [`FlashFault::Bad`] flash reads at `address`: a hash of the address (the same
/// garbage on every read).
fn garbage(address: u32) -> u8 {
    let x = address.wrapping_mul(0x9E37_79B9) ^ 0x5BD1_E995;
    (x ^ (x >> 15)).wrapping_mul(0x2C1B_3C6D).to_le_bytes()[3]
}

impl ErrorType for FileFlash {
    type Error = FlashError;
}

impl ReadNorFlash for FileFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let offset = self.check(offset, bytes.len(), 1)?;
        if self.fault == Some(FlashFault::Bad) {
            for (i, byte) in bytes.iter_mut().enumerate() {
                *byte = garbage((offset + i) as u32);
            }
            return Err(FlashError::Io);
        }
        bytes.copy_from_slice(&self.bytes[offset..offset + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.bytes.len()
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let len = (to as usize).checked_sub(from as usize).ok_or(FlashError::OutOfBounds)?;
        let from = self.check(from, len, ERASE_SIZE)?;
        if self.fault == Some(FlashFault::Bad) {
            return Err(FlashError::Io);
        }
        self.bytes[from..from + len].fill(0xFF);
        self.write_through(from, len)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let offset = self.check(offset, bytes.len(), WRITE_SIZE)?;
        if self.fault == Some(FlashFault::Bad) {
            return Err(FlashError::Io);
        }
        if self.bytes[offset..offset + bytes.len()].iter().any(|&b| b != 0xFF) {
            return Err(FlashError::NotErased);
        }
        self.bytes[offset..offset + bytes.len()].copy_from_slice(bytes);
        self.write_through(offset, bytes.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_word_survives_reopening_and_cannot_be_programmed_twice() {
        let dir = std::env::temp_dir().join(format!("fileflash-{}", std::process::id()));
        let path = dir.join("flash.bin");
        let _ = std::fs::remove_file(&path);
        let mut flash = FileFlash::open(&path).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), FLASH_BYTES as u64);
        let word = [0x5Au8; WRITE_SIZE];
        flash.write(ERASE_SIZE as u32 + 64, &word).unwrap();
        assert_eq!(flash.write(ERASE_SIZE as u32 + 64, &word), Err(FlashError::NotErased));
        assert_eq!(flash.write(3, &word), Err(FlashError::NotAligned));
        drop(flash);
        let mut again = FileFlash::open(&path).unwrap();
        let mut read = [0u8; WRITE_SIZE + 1];
        again.read(ERASE_SIZE as u32 + 64, &mut read).unwrap();
        assert_eq!(&read[..WRITE_SIZE], &word);
        assert_eq!(read[WRITE_SIZE], 0xFF);
        again.erase(ERASE_SIZE as u32, 2 * ERASE_SIZE as u32).unwrap();
        drop(again);
        let mut erased = FileFlash::open(&path).unwrap();
        erased.read(ERASE_SIZE as u32 + 64, &mut read).unwrap();
        assert!(read.iter().all(|&b| b == 0xFF));
        std::fs::write(&path, [0u8; 10]).unwrap();
        assert!(matches!(FileFlash::open(&path), Err(FlashFileError::Size { len: 10, .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_bad_flash_fails_reads_and_writes_and_leaves_its_file_alone() {
        let dir = std::env::temp_dir().join(format!("fileflash-bad-{}", std::process::id()));
        let path = dir.join("flash.bin");
        let _ = std::fs::remove_file(&path);
        let mut bad = FileFlash::open(&path).unwrap().with_fault(Some(FlashFault::Bad));
        let (mut first, mut second) = ([0u8; 256], [0u8; 256]);
        assert_eq!(bad.read(0, &mut first), Err(FlashError::Io));
        assert_eq!(bad.read(0, &mut second), Err(FlashError::Io));
        assert_eq!(first, second, "the same garbage on every read");
        let erased = first.iter().filter(|&&b| b == 0xFF).count();
        assert!(erased < 16, "{erased} of 256 bytes read as erased");
        assert_eq!(bad.write(0, &[0u8; WRITE_SIZE]), Err(FlashError::Io));
        assert_eq!(bad.erase(0, ERASE_SIZE as u32), Err(FlashError::Io));
        drop(bad);
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.iter().all(|&b| b == 0xFF), "the file is still erased");
        // What the application makes of it: the stored configuration cannot be read (the
        // defaults are in force), and a save fails without changing what is in force.
        let bad = FileFlash::open(&path).unwrap().with_fault(Some(FlashFault::Bad));
        let mut settings = firmware::app::Settings::load(bad, FileFlash::store_range());
        assert_eq!(settings.status().origin, protocol::ConfigOrigin::Unreadable);
        assert_eq!(settings.save(), Err(protocol::StorageStage::Write));
        assert_eq!(settings.status().origin, protocol::ConfigOrigin::Unreadable);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
