//! The flight log's files on a memory card: a small block layout of our own over any
//! [`NorFlash`] of 512-byte blocks (the board's microSD card through SDMMC1, a RAM card in the
//! host tests), as a [`LogSink`] and [`LogFiles`]: the same files, numbers and answers as the
//! host's `LogDir`.
//!
//! **Why not FAT.** A FAT file system (embedded-sdmmc) would let a PC read the card, but costs
//! about 15 KB of flash where the whole log fits in 256 KiB only by a few KB (docs/benchmarks.md,
//! "Firmware size": embedded-sdmmc's volume manager 12.4 KB and the `core::fmt` it links; this
//! layout 1.8 KB), and FAT updates a file's size only when the file is closed: a power cut
//! would lose everything since. Here the card is read over the link (`configurator-cli log
//! download`), as the SITL's logs are; a PC sees an unformatted card.
//!
//! **Layout** (block numbers; a block is [`LOG_BLOCK_LEN`] bytes):
//! - block 0: the mark ([`CARD_MAGIC`]). A card without it is formatted on first use: its
//!   directory erased and the mark written (what it held is lost);
//! - blocks 1..=2 × [`MAX_FILES`]: the directory, two blocks per entry (file number, first
//!   block, length in blocks or "open"; CRC-32C): the first written when the file begins (open),
//!   the second when it ends (its length). Writing one can tear no other, and a second torn by a
//!   power cut leaves the first, open: the file is then found as a cut one (below);
//! - blocks [`PROGRESS_BLOCKS`]: the open file's length so far, written every
//!   [`PROGRESS_EVERY_BLOCKS`] blocks, alternately in the two (a sequence number says which is
//!   newer, so a torn one leaves the other);
//! - from [`DATA_START`] (4 MiB, an SD allocation unit): the files' blocks, each file
//!   contiguous, in the order written.
//!
//! **Power cuts.** Every block after the open file's last one is kept erased (all 0x00 or all
//! 0xFF, whichever the card returns): before a block is written, the one after it must already
//! be erased, else the next [`ERASE_CHUNK_BLOCKS`] are erased first, so an erase cut short only
//! ever leaves erased blocks next to the file. A log block is never erased-looking (each holds
//! at least one frame byte and one 0x00 delimiter: frames are at most 256 bytes). When the card
//! is mounted again, an entry still open is closed at its first erased block after the last
//! recorded progress (and before the next file's first): every earlier file is whole, the cut
//! one holds every block written before the cut (and the torn one, whose frames the reader
//! skips). A cut while a file begins loses that file (it holds nothing yet); a cut while one is
//! deleted may leave it there.
//!
//! **Space.** A file is deleted by erasing its entry; its blocks are taken again once no later
//! file remains (new files go after the last live one), so deleting every file frees the
//! whole card. At most [`MAX_FILES`] files and the card's first 4 GiB ([`NorFlash`] offsets are
//! `u32`); then a new file is refused as [`LogSinkError::Full`].
//!
//! Every call does a bounded amount of work except [`CardLog::mount`] (one directory read, and
//! after a cut a scan of at most [`PROGRESS_EVERY_BLOCKS`] blocks) and an erase, which the card
//! does in one command.

use embedded_storage::nor_flash::NorFlash;

use super::log::{
    FileRead, LogFileError, LogFileList, LogFiles, LogSink, LogSinkError, LOG_BLOCK_LEN,
};

/// The mark of a card formatted for the log (block 0's first bytes), with the layout's version.
pub const CARD_MAGIC: [u8; 8] = *b"FCLOG001";

/// Directory entries (two blocks each, blocks 1..=2 × `MAX_FILES`).
pub const MAX_FILES: usize = 255;

/// The two blocks recording the open file's progress.
pub const PROGRESS_BLOCKS: [u32; 2] = [2 * MAX_FILES as u32 + 1, 2 * MAX_FILES as u32 + 2];

/// The first block of the files' data: 4 MiB, so that the data begins on an SD card's
/// allocation unit (cards write whole units fastest; SD Physical Layer spec, 4.13).
pub const DATA_START: u32 = 8192;

/// Blocks erased ahead of the open file at a time: 1 MiB, about 4.5 s of a 2 kHz log
/// (230 kB/s). An SD card erases a range in one command (CMD32/33/38).
pub const ERASE_CHUNK_BLOCKS: u32 = 2048;

/// The open file's length is recorded every this many blocks (512 KiB, about 2.3 s of log):
/// after a power cut, mounting scans at most this many blocks for the file's end.
pub const PROGRESS_EVERY_BLOCKS: u32 = 1024;

/// Highest file number (`LOG99999.BIN`, as the host's log directory).
pub const MAX_FILE_NUMBER: u32 = 99_999;

/// An entry's `blocks` while its file is being written.
const OPEN: u32 = u32::MAX;
const ENTRY_MAGIC: u32 = u32::from_le_bytes(*b"FCLE");
const PROGRESS_MAGIC: u32 = u32::from_le_bytes(*b"FCLP");
const BLOCK: u32 = LOG_BLOCK_LEN as u32;

/// A directory entry as kept in memory (`number` 0: a free slot).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Entry {
    number: u32,
    start: u32,
    blocks: u32,
}

/// The file being written.
#[derive(Clone, Copy, Debug)]
struct Writing {
    slot: usize,
    /// Blocks written so far.
    blocks: u32,
}

/// The log's files on a card of 512-byte blocks (see the module docs).
pub struct CardLog<D> {
    card: D,
    /// The card's blocks used (at most 4 GiB worth).
    end: u32,
    entries: [Entry; MAX_FILES],
    writing: Option<Writing>,
    /// The next file's first block: after the last live file.
    append: u32,
    /// Blocks `append..erased_to` are known to be erased.
    erased_to: u32,
    progress_seq: u32,
    buf: [u8; LOG_BLOCK_LEN],
}

/// Four little-endian words and their CRC-32C, as an entry and a progress block hold them.
fn record(words: [u32; 4], buf: &mut [u8; LOG_BLOCK_LEN]) {
    buf.fill(0);
    for (i, word) in words.iter().enumerate() {
        buf[i * 4..i * 4 + 4].copy_from_slice(&word.to_le_bytes());
    }
    let crc = protocol::frame::CRC.checksum(&buf[..16]);
    buf[16..20].copy_from_slice(&crc.to_le_bytes());
}

/// The words of a block written by [`record`] with `magic` first, when it checks out.
fn parse(magic: u32, buf: &[u8; LOG_BLOCK_LEN]) -> Option<[u32; 3]> {
    let word = |i: usize| u32::from_le_bytes([buf[i], buf[i + 1], buf[i + 2], buf[i + 3]]);
    let valid = word(0) == magic && word(16) == protocol::frame::CRC.checksum(&buf[..16]);
    valid.then(|| [word(4), word(8), word(12)])
}

/// The block of copy `copy` of directory slot `slot`.
fn entry_block(slot: usize, copy: usize) -> u32 {
    (2 * slot + copy) as u32 + 1
}

/// An erased block (what the card returns after an erase: all 0x00 or all 0xFF).
fn erased(buf: &[u8; LOG_BLOCK_LEN]) -> bool {
    buf.iter().all(|&b| b == buf[0]) && (buf[0] == 0 || buf[0] == 0xFF)
}

impl<D: NorFlash> CardLog<D> {
    /// Mount the log on `card`: format it when it lacks the mark, read the directory, and close
    /// a file a power cut left open at its last block written. `Err`: the card failed (it is
    /// handed back).
    pub fn mount(card: D) -> Result<Self, (D, D::Error)> {
        let end = u32::try_from(card.capacity() / LOG_BLOCK_LEN).unwrap_or(u32::MAX);
        let mut log = Self {
            card,
            end: end.min(u32::MAX / BLOCK),
            entries: [Entry::default(); MAX_FILES],
            writing: None,
            append: DATA_START,
            erased_to: DATA_START,
            progress_seq: 0,
            buf: [0; LOG_BLOCK_LEN],
        };
        match log.load() {
            Ok(()) => Ok(log),
            Err(error) => Err((log.card, error)),
        }
    }

    /// The card, given back.
    pub fn into_card(self) -> D {
        self.card
    }

    /// [`Self::mount`]'s work: the mark, the directory, a cut file closed.
    fn load(&mut self) -> Result<(), D::Error> {
        let log = self;
        let end = log.end;
        log.read_block(0)?;
        if log.buf[..CARD_MAGIC.len()] != CARD_MAGIC {
            log.erase(0, DATA_START)?;
            log.buf.fill(0);
            log.buf[..CARD_MAGIC.len()].copy_from_slice(&CARD_MAGIC);
            log.write_buf(0)?;
        }
        // The open file's progress: the newer of the two records.
        let mut progress = None;
        for block in PROGRESS_BLOCKS {
            log.read_block(block)?;
            if let Some([number, seq, blocks]) = parse(PROGRESS_MAGIC, &log.buf) {
                if progress.is_none_or(|(_, newest, _)| seq > newest) {
                    progress = Some((number, seq, blocks));
                }
            }
        }
        log.progress_seq = progress.map_or(0, |(_, seq, _)| seq);
        for slot in 0..MAX_FILES {
            // The entry written when the file ended, unless it is torn or another file's.
            let mut copies = [None; 2];
            for (copy, found) in copies.iter_mut().enumerate() {
                log.read_block(entry_block(slot, copy))?;
                *found = parse(ENTRY_MAGIC, &log.buf);
            }
            let entry = match copies {
                [Some(begun), Some(ended)] if begun[..2] != ended[..2] => Some(begun),
                [begun, ended] => ended.or(begun),
            };
            if let Some([number, start, blocks]) = entry {
                let fits = start >= DATA_START
                    && (blocks == OPEN || start.checked_add(blocks).is_some_and(|e| e <= end));
                if (1..=MAX_FILE_NUMBER).contains(&number) && fits {
                    log.entries[slot] = Entry { number, start, blocks };
                }
            }
        }
        for slot in 0..MAX_FILES {
            let entry = log.entries[slot];
            if entry.number != 0 && entry.blocks == OPEN {
                let known = match progress {
                    Some((number, _, blocks)) if number == entry.number => blocks,
                    _ => 0,
                };
                // Up to the next file's first block at most.
                let limit = log.entries.iter().map(|e| e.start).filter(|&s| s > entry.start);
                let limit = limit.min().unwrap_or(log.end);
                let mut blocks = known.min(limit - entry.start);
                while entry.start + blocks < limit {
                    log.read_block(entry.start + blocks)?;
                    if erased(&log.buf) {
                        break;
                    }
                    blocks += 1;
                }
                log.entries[slot].blocks = blocks;
                log.write_entry(slot, 1)?;
            }
        }
        log.append = log.after_last();
        log.erased_to = log.append;
        Ok(())
    }

    /// The block after the last live file.
    fn after_last(&self) -> u32 {
        let ends = self.entries.iter().filter(|e| e.number != 0).map(|e| e.start + e.blocks);
        ends.max().unwrap_or(DATA_START)
    }

    fn read_block(&mut self, block: u32) -> Result<(), D::Error> {
        self.card.read(block * BLOCK, &mut self.buf)
    }

    fn write_buf(&mut self, block: u32) -> Result<(), D::Error> {
        self.card.write(block * BLOCK, &self.buf)
    }

    fn erase(&mut self, first: u32, count: u32) -> Result<(), D::Error> {
        self.card.erase(first * BLOCK, (first + count) * BLOCK)
    }

    /// Write copy `copy` of slot `slot`'s entry (0: the file begun, 1: ended).
    fn write_entry(&mut self, slot: usize, copy: usize) -> Result<(), D::Error> {
        let Entry { number, start, blocks } = self.entries[slot];
        record([ENTRY_MAGIC, number, start, blocks], &mut self.buf);
        self.write_buf(entry_block(slot, copy))
    }

    /// Make sure the blocks `block` and `block + 1` are erased (erasing the next chunk first).
    fn erase_ahead(&mut self, block: u32) -> Result<(), D::Error> {
        if block + 1 < self.erased_to {
            return Ok(());
        }
        let from = self.erased_to.max(block);
        let to = from.saturating_add(ERASE_CHUNK_BLOCKS).min(self.end);
        self.erase(from, to - from)?;
        self.erased_to = to;
        Ok(())
    }

    fn find(&self, number: u32) -> Result<usize, LogFileError> {
        if number == 0 {
            return Err(LogFileError::NoSuchFile);
        }
        let slot = self.entries.iter().position(|e| e.number == number);
        slot.ok_or(LogFileError::NoSuchFile)
    }

    /// Blocks of the file in slot `slot` now.
    fn blocks(&self, slot: usize) -> u32 {
        match self.writing {
            Some(w) if w.slot == slot => w.blocks,
            _ => self.entries[slot].blocks,
        }
    }
}

impl<D: NorFlash> LogFiles for CardLog<D> {
    fn list(&mut self, first: u32, out: &mut LogFileList) -> Result<bool, LogFileError> {
        out.clear();
        let mut from = first;
        loop {
            // The next number from `from` on (the directory is in slot order, not by number).
            let next = (0..MAX_FILES)
                .filter(|&s| self.entries[s].number >= from.max(1))
                .min_by_key(|&s| self.entries[s].number);
            let Some(slot) = next else { return Ok(false) };
            if out.is_full() {
                return Ok(true);
            }
            let number = self.entries[slot].number;
            let size_bytes = self.blocks(slot).saturating_mul(BLOCK);
            let writing = self.writing.is_some_and(|w| w.slot == slot);
            // Cannot fail: checked above.
            let _ = out.push(protocol::LogFileInfo { number, size_bytes, writing });
            from = number + 1;
        }
    }

    fn read(&mut self, number: u32, offset: u32, buf: &mut [u8]) -> Result<FileRead, LogFileError> {
        let slot = self.find(number)?;
        let size_bytes = self.blocks(slot) * BLOCK;
        if offset > size_bytes {
            return Err(LogFileError::OffsetPastEnd { size_bytes });
        }
        let wanted = buf.len().min((size_bytes - offset) as usize);
        let mut done = 0;
        while done < wanted {
            let at = offset + done as u32;
            let block = self.entries[slot].start + at / BLOCK;
            self.read_block(block).map_err(|_| LogFileError::Io)?;
            let within = (at % BLOCK) as usize;
            let take = (wanted - done).min(LOG_BLOCK_LEN - within);
            buf[done..done + take].copy_from_slice(&self.buf[within..within + take]);
            done += take;
        }
        Ok(FileRead { bytes_read: wanted, size_bytes })
    }

    fn delete(&mut self, number: u32) -> Result<(), LogFileError> {
        let slot = self.find(number)?;
        if self.writing.is_some_and(|w| w.slot == slot) {
            return Err(LogFileError::BeingWritten);
        }
        // The begun copy first: cut in between, the ended copy still holds the whole file.
        for copy in 0..2 {
            self.erase(entry_block(slot, copy), 1).map_err(|_| LogFileError::Io)?;
        }
        self.entries[slot] = Entry::default();
        if self.writing.is_none() {
            // The space after the last live file is taken again (erased before it is written).
            self.append = self.after_last();
            self.erased_to = self.erased_to.min(self.append);
        }
        Ok(())
    }
}

impl<D: NorFlash + Send> LogSink for CardLog<D> {
    fn open(&mut self) -> Result<u32, LogSinkError> {
        if self.writing.is_some() {
            self.close()?;
        }
        let slot = self.entries.iter().position(|e| e.number == 0);
        let number = self.entries.iter().map(|e| e.number).max().unwrap_or(0) + 1;
        let start = self.append;
        let (Some(slot), true) = (slot, number <= MAX_FILE_NUMBER && start + 1 < self.end) else {
            return Err(LogSinkError::Full);
        };
        // Before the entry says the file is open: its blocks erased, no progress recorded (of an
        // earlier file of the same number), the slot's ended copy gone.
        let io = |_| LogSinkError::Io;
        self.erase_ahead(start).map_err(io)?;
        self.erase(PROGRESS_BLOCKS[0], 2).map_err(io)?;
        self.erase(entry_block(slot, 0), 2).map_err(io)?;
        self.entries[slot] = Entry { number, start, blocks: OPEN };
        self.write_entry(slot, 0).map_err(io)?;
        self.writing = Some(Writing { slot, blocks: 0 });
        Ok(number)
    }

    fn write_block(&mut self, block: &[u8; LOG_BLOCK_LEN]) -> Result<(), LogSinkError> {
        let Some(writing) = self.writing else { return Err(LogSinkError::Io) };
        let at = self.entries[writing.slot].start + writing.blocks;
        // The block after this one stays erased: the file's end after a power cut.
        if at + 1 >= self.end {
            return Err(LogSinkError::Full);
        }
        self.erase_ahead(at).map_err(|_| LogSinkError::Io)?;
        self.card.write(at * BLOCK, block).map_err(|_| LogSinkError::Io)?;
        let blocks = writing.blocks + 1;
        self.writing = Some(Writing { blocks, ..writing });
        self.append = at + 1;
        if blocks.is_multiple_of(PROGRESS_EVERY_BLOCKS) {
            self.progress_seq = self.progress_seq.wrapping_add(1);
            let number = self.entries[writing.slot].number;
            record([PROGRESS_MAGIC, number, self.progress_seq, blocks], &mut self.buf);
            let which = PROGRESS_BLOCKS[(self.progress_seq % 2) as usize];
            self.write_buf(which).map_err(|_| LogSinkError::Io)?;
        }
        Ok(())
    }

    fn close(&mut self) -> Result<(), LogSinkError> {
        let Some(writing) = self.writing.take() else { return Ok(()) };
        self.entries[writing.slot].blocks = writing.blocks;
        self.append = self.entries[writing.slot].start + writing.blocks;
        self.write_entry(writing.slot, 1).map_err(|_| LogSinkError::Io)
    }
}
