//! The flight log on a memory card (`firmware::app::card`), against a simulated card in RAM:
//! a file per arming, listed, read back and deleted through `LogFiles` exactly as written; a
//! card of another use formatted; a full card refusing files; and 1,000 power cuts at random
//! points of a logging session (the card stops taking writes, the one in progress torn), after
//! which every earlier file reads back whole and the cut one up to its last complete block.

mod logging;

use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash};
use firmware::app::card::{CardLog, DATA_START, ERASE_CHUNK_BLOCKS, PROGRESS_EVERY_BLOCKS};
use firmware::app::log::{
    FileRead, LogFileError, LogFiles, LogReader, LogRecord, LogSink, LogSinkError, LOG_BLOCK_LEN,
};
use firmware::app::ControlCommand;
use flight::rng::Rng;

const BLOCK: usize = LOG_BLOCK_LEN;

/// A card in RAM. Erased blocks read 0xFF. After `cut_after` writes and erases the power goes:
/// that operation is torn (a write keeps a random prefix of its bytes, the rest garbage or the
/// old bytes; an erase leaves each block erased, as it was, or garbage, at random) and every
/// later one fails, until [`RamCard::power_on`].
struct RamCard {
    bytes: Vec<u8>,
    ops: u64,
    /// The operations that were erases (their numbers, from 1).
    erases: Vec<u64>,
    cut_after: Option<u64>,
    dead: bool,
    rng: Rng,
}

impl RamCard {
    fn new(blocks: u32, fill: u8) -> Self {
        Self {
            bytes: vec![fill; blocks as usize * BLOCK],
            ops: 0,
            erases: Vec::new(),
            cut_after: None,
            dead: false,
            rng: Rng::new(3),
        }
    }

    fn power_on(&mut self) {
        self.dead = false;
        self.cut_after = None;
    }

    fn random(&mut self, below: usize) -> usize {
        ((self.rng.uniform() * below as f64) as usize).min(below.saturating_sub(1))
    }

    /// `Ok(true)`: the operation runs whole; `Ok(false)`: it is torn; `Err`: no power.
    fn operation(&mut self) -> Result<bool, NorFlashErrorKind> {
        if self.dead {
            return Err(NorFlashErrorKind::Other);
        }
        self.ops += 1;
        if self.cut_after.is_some_and(|cut| self.ops > cut) {
            self.dead = true;
            return Ok(false);
        }
        Ok(true)
    }
}

impl ErrorType for RamCard {
    type Error = NorFlashErrorKind;
}

impl ReadNorFlash for RamCard {
    const READ_SIZE: usize = BLOCK;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let at = offset as usize;
        bytes.copy_from_slice(&self.bytes[at..at + bytes.len()]);
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.bytes.len()
    }
}

impl NorFlash for RamCard {
    const WRITE_SIZE: usize = BLOCK;
    const ERASE_SIZE: usize = BLOCK;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let (from, to) = (from as usize, to as usize);
        assert!(from % BLOCK == 0 && to % BLOCK == 0 && to <= self.bytes.len(), "{from}..{to}");
        let whole = self.operation()?;
        self.erases.push(self.ops);
        if whole {
            self.bytes[from..to].fill(0xFF);
            return Ok(());
        }
        for block in (from..to).step_by(BLOCK) {
            match self.random(3) {
                0 => self.bytes[block..block + BLOCK].fill(0xFF),
                1 => {}
                _ => {
                    for i in block..block + BLOCK {
                        self.bytes[i] = self.random(256) as u8;
                    }
                }
            }
        }
        Err(NorFlashErrorKind::Other)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let at = offset as usize;
        assert!(at.is_multiple_of(BLOCK) && bytes.len() == BLOCK, "whole blocks only");
        if self.operation()? {
            self.bytes[at..at + BLOCK].copy_from_slice(bytes);
            return Ok(());
        }
        let kept = self.random(BLOCK + 1);
        self.bytes[at..at + kept].copy_from_slice(&bytes[..kept]);
        if self.ops.is_multiple_of(2) {
            for i in at + kept..at + BLOCK {
                self.bytes[i] = self.random(256) as u8;
            }
        }
        Err(NorFlashErrorKind::Other)
    }
}

/// What the logger asked of its sink.
#[derive(Clone, Debug)]
enum Op {
    Open,
    Block(Box<[u8; BLOCK]>),
    Close,
}

/// A sink that records what it is asked (and keeps each file's bytes).
#[derive(Default)]
struct Recorder {
    ops: Vec<Op>,
    files: Vec<Vec<u8>>,
}

impl LogFiles for Recorder {}

impl LogSink for Recorder {
    fn open(&mut self) -> Result<u32, LogSinkError> {
        self.ops.push(Op::Open);
        self.files.push(Vec::new());
        Ok(self.files.len() as u32)
    }
    fn write_block(&mut self, block: &[u8; BLOCK]) -> Result<(), LogSinkError> {
        self.ops.push(Op::Block(Box::new(*block)));
        self.files.last_mut().unwrap().extend_from_slice(block);
        Ok(())
    }
    fn close(&mut self) -> Result<(), LogSinkError> {
        self.ops.push(Op::Close);
        Ok(())
    }
}

/// A session of three armings (0.5 s, 4 s and 0.25 s armed; each file goes on 2 s after the
/// disarm): 12 s of steps.
const STEPS: u64 = 24_000;
fn commands() -> Vec<(u64, ControlCommand)> {
    use ControlCommand::{ArmThrowToFly, Disarm};
    vec![(1, ArmThrowToFly), (1000, Disarm), (6000, ArmThrowToFly), (14_000, Disarm)]
        .into_iter()
        .chain([(19_000, ArmThrowToFly), (19_500, Disarm)])
        .collect()
}

/// The session as the logger writes it: its sink operations and the files' bytes.
fn session() -> Recorder {
    let mut recorder = Recorder::default();
    logging::fly(&mut recorder, STEPS, &commands());
    recorder
}

/// Every file on the card, in pages of the link's length, as (number, bytes, being written).
fn files(log: &mut dyn LogFiles) -> Vec<(u32, Vec<u8>, bool)> {
    let mut listed = Vec::new();
    let mut out = heapless::Vec::new();
    let mut first = 1;
    loop {
        let more = log.list(first, &mut out).unwrap();
        listed.extend(out.iter().copied());
        let Some(last) = out.last() else { break };
        first = last.number + 1;
        if !more {
            break;
        }
    }
    listed
        .into_iter()
        .map(|info| {
            let mut bytes = Vec::new();
            let mut chunk = [0u8; 224];
            loop {
                let FileRead { bytes_read, size_bytes } =
                    log.read(info.number, bytes.len() as u32, &mut chunk).unwrap();
                assert_eq!(size_bytes, info.size_bytes);
                bytes.extend_from_slice(&chunk[..bytes_read]);
                if bytes_read < chunk.len() {
                    break;
                }
            }
            assert_eq!(bytes.len(), info.size_bytes as usize);
            (info.number, bytes, info.writing)
        })
        .collect()
}

#[test]
fn a_file_per_arming_is_listed_read_back_whole_deleted_and_found_again_after_a_restart() {
    let expected = session().files;
    assert_eq!(expected.len(), 3, "three armings, three files");
    assert!(expected[1].len() / BLOCK > PROGRESS_EVERY_BLOCKS as usize, "progress recorded");

    // Room for the first file and two as large as the second (the end of the test), and a few
    // blocks to spare: the three files of the session fit too.
    let blocks = |file: &Vec<u8>| (file.len() / BLOCK) as u32;
    let card = RamCard::new(DATA_START + blocks(&expected[0]) + 2 * blocks(&expected[1]) + 64, 0);
    let mut log = mount(card);
    logging::fly(&mut log, STEPS, &commands());
    let on_card = files(&mut log);
    let numbers: Vec<u32> = on_card.iter().map(|f| f.0).collect();
    assert_eq!(numbers, [1, 2, 3]);
    for ((_, bytes, writing), expected) in on_card.iter().zip(&expected) {
        assert!(!writing);
        assert_eq!(bytes, expected, "a file reads back exactly as written");
        let mut reader = LogReader::new(bytes);
        assert!(matches!(reader.next(), Some(LogRecord::Header(_))));
        assert!(matches!(reader.last(), Some(LogRecord::End(_))));
    }

    // A restart finds the same files.
    let mut log = mount(log.into_card());
    assert_eq!(files(&mut log), on_card);

    // Errors change nothing.
    let mut chunk = [0u8; 64];
    let size_bytes = expected[0].len() as u32;
    assert_eq!(log.read(1, size_bytes, &mut chunk), Ok(FileRead { bytes_read: 0, size_bytes }));
    assert_eq!(
        log.read(1, size_bytes + 1, &mut chunk),
        Err(LogFileError::OffsetPastEnd { size_bytes })
    );
    assert_eq!(log.read(4, 0, &mut chunk), Err(LogFileError::NoSuchFile));
    assert_eq!(log.delete(0), Err(LogFileError::NoSuchFile));

    // The file being written cannot go; a closed one can.
    assert_eq!(log.open(), Ok(4));
    log.write_block(&[7; BLOCK]).unwrap();
    assert_eq!(log.delete(4), Err(LogFileError::BeingWritten));
    assert_eq!(log.delete(2), Ok(()));
    assert_eq!(log.delete(2), Err(LogFileError::NoSuchFile));
    let listed = files(&mut log);
    let state: Vec<(u32, usize, bool)> = listed.iter().map(|f| (f.0, f.1.len(), f.2)).collect();
    assert_eq!(
        state,
        [(1, expected[0].len(), false), (3, expected[2].len(), false), (4, 512, true)]
    );
    log.close().unwrap();

    // Deleting the files at the end gives their space back: the card holds the first file and
    // two more as large as the deleted second, once again.
    assert_eq!((log.delete(3), log.delete(4)), (Ok(()), Ok(())));
    let mut log = mount(log.into_card());
    for number in [2, 3] {
        assert_eq!(log.open(), Ok(number));
        for block in expected[1].chunks(BLOCK) {
            log.write_block(block.try_into().unwrap()).unwrap();
        }
        log.close().unwrap();
    }
    let listed = files(&mut log);
    assert_eq!(listed.len(), 3);
    assert_eq!(listed[0].1, expected[0], "the first file untouched");
    assert!(listed[1..].iter().all(|f| f.1 == expected[1]));
}

#[test]
fn a_card_of_another_use_is_formatted_and_a_full_card_refuses_files() {
    // Garbage everywhere: formatted on first use, nothing listed.
    let mut log = mount(RamCard::new(DATA_START + 64, 0xA5));
    assert!(files(&mut log).is_empty());
    // 64 data blocks: a file takes 63 and keeps the block after its last erased; then full.
    assert_eq!(log.open(), Ok(1));
    let block = [0x11; BLOCK];
    for _ in 0..63 {
        log.write_block(&block).unwrap();
    }
    assert_eq!(log.write_block(&block), Err(LogSinkError::Full));
    log.close().unwrap();
    assert_eq!(log.open(), Err(LogSinkError::Full));
    let listed = files(&mut log);
    assert_eq!((listed.len(), listed[0].1.len()), (1, 63 * BLOCK), "the full file kept");
    // Deleting it makes room again.
    log.delete(1).unwrap();
    assert_eq!(log.open(), Ok(1));
}

/// The log on `card` (a RAM card always mounts).
fn mount(card: RamCard) -> CardLog<RamCard> {
    CardLog::mount(card).unwrap_or_else(|(_, error)| panic!("{error:?}"))
}

/// The records of a file's bytes.
fn records(bytes: &[u8]) -> Vec<LogRecord> {
    LogReader::new(bytes).collect()
}

#[test]
fn after_1000_random_power_cuts_every_file_reads_back_to_its_last_complete_block() {
    let session = session();
    let expected = &session.files;
    let expected_records: Vec<Vec<LogRecord>> = expected.iter().map(|f| records(f)).collect();
    // A log block never looks erased (what the card's layout relies on to find a cut file's end).
    for block in expected.iter().flat_map(|f| f.chunks(BLOCK)) {
        assert!(!(block.iter().all(|&b| b == 0) || block.iter().all(|&b| b == 0xFF)));
    }
    let data_blocks: u32 = expected.iter().map(|f| (f.len() / BLOCK) as u32).sum();
    // The card held an older log: its valid frames fill the data area, so a file read past its
    // end would show records that are not its own.
    let mut template = RamCard::new(DATA_START + data_blocks + ERASE_CHUNK_BLOCKS + 16, 0xFF);
    let old = &expected[1];
    let data = &mut template.bytes[DATA_START as usize * BLOCK..];
    for (i, byte) in data.iter_mut().enumerate() {
        *byte = old[(i + 37 * BLOCK) % old.len()];
    }

    // The operations of an uncut session.
    let run = |card: RamCard| -> (RamCard, Vec<u32>, Option<(usize, usize)>) {
        // Files closed whole, and the file in progress at the cut with its blocks written.
        let mut closed = Vec::new();
        let mut current = None;
        // A cut while mounting (formatting the card) leaves no file.
        let mut log = match CardLog::mount(card) {
            Ok(log) => log,
            Err((card, _)) => return (card, closed, current),
        };
        let mut file = 0;
        let mut blocks = 0;
        for op in &session.ops {
            let result = match op {
                Op::Open => log.open().map(|number| {
                    file += 1;
                    blocks = 0;
                    assert_eq!(number as usize, file);
                    current = Some((file, 0));
                }),
                Op::Block(block) => log.write_block(block).map(|()| {
                    blocks += 1;
                    current = Some((file, blocks));
                }),
                Op::Close => log.close().map(|()| {
                    closed.push(file as u32);
                    current = None;
                }),
            };
            if result.is_err() {
                break;
            }
        }
        (log.into_card(), closed, current)
    };
    let (uncut, closed, current) =
        run(RamCard { bytes: template.bytes.clone(), ..RamCard::new(0, 0) });
    assert_eq!((&closed[..], current), (&[1, 2, 3][..], None));
    let total_ops = uncut.ops;
    assert!(uncut.erases.len() > 5, "{} erases", uncut.erases.len());

    let mut rng = Rng::new(30);
    let mut cut_files = 0;
    for trial in 0..1000 {
        // Two cuts in three at any operation, one in three in an erase (they are few).
        let cut = if trial % 3 == 2 {
            uncut.erases[(rng.uniform() * uncut.erases.len() as f64) as usize] - 1
        } else {
            (rng.uniform() * total_ops as f64) as u64
        };
        let mut card = RamCard { bytes: template.bytes.clone(), ..RamCard::new(0, 0) };
        card.rng = Rng::new(trial);
        card.cut_after = Some(cut);
        let (mut card, closed, current) = run(card);
        card.power_on();
        let mut log = mount(card);
        let on_card = files(&mut log);
        for &number in &closed {
            let (_, bytes, writing) = on_card.iter().find(|f| f.0 == number).unwrap_or_else(|| {
                panic!("trial {trial}, cut after {cut}: closed file {number} is gone")
            });
            assert!(!writing);
            assert_eq!(bytes, &expected[number as usize - 1], "trial {trial}: file {number}");
        }
        if let Some((file, blocks)) = current {
            cut_files += 1;
            let found = on_card.iter().find(|f| f.0 == file as u32);
            let (_, bytes, _) = found.unwrap_or_else(|| {
                panic!("trial {trial}, cut after {cut}: file {file} ({blocks} blocks) is gone")
            });
            let complete = blocks * BLOCK;
            let reference = &expected[file - 1];
            assert!(
                bytes.len() >= complete && bytes.len() <= complete + BLOCK,
                "trial {trial}: {} bytes for {blocks} blocks written",
                bytes.len()
            );
            assert_eq!(bytes[..complete], reference[..complete], "trial {trial}");
            let read = records(bytes);
            let whole = records(&reference[..complete]).len();
            assert!(read.len() >= whole, "trial {trial}: {} of {whole} records", read.len());
            assert_eq!(read[..], expected_records[file - 1][..read.len()], "trial {trial}");
        }
        // Nothing else: a file begun at the cut holds nothing.
        for (number, bytes, _) in &on_card {
            let known = closed.contains(number) || current.is_some_and(|c| c.0 == *number as usize);
            assert!(known || bytes.is_empty(), "trial {trial}: file {number} of {} B", bytes.len());
        }
        // And the card takes the next file after the cut ones.
        let next = log.open().unwrap();
        assert!(on_card.iter().all(|f| f.0 < next));
    }
    assert!(cut_files > 600, "most cuts fall in a file ({cut_files})");
}
