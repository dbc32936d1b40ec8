//! A power cut in the middle of a logging flight: the card stops taking the file at a random
//! byte (the block being written is torn: cut short, or its rest is garbage, as a card that
//! loses power mid-sector may leave it). Every time, the file reads back up to its last complete
//! block, the records read are exactly the flight's first records (nothing invented, nothing
//! reordered), and the reader says the tail was torn or damaged.

mod logging;

use firmware::app::log::{LogReader, LogRecord, LogSink, LogSinkError, LOG_BLOCK_LEN};
use firmware::app::ControlCommand;
use flight::rng::Rng;
use protocol::Decoder;

/// The card: keeps every block of the one file.
#[derive(Default)]
struct Card {
    bytes: Vec<u8>,
}

impl firmware::app::log::LogFiles for Card {}

impl LogSink for Card {
    fn open(&mut self) -> Result<u32, LogSinkError> {
        assert!(self.bytes.is_empty(), "one arming, one file");
        Ok(1)
    }
    fn write_block(&mut self, block: &[u8; LOG_BLOCK_LEN]) -> Result<(), LogSinkError> {
        self.bytes.extend_from_slice(block);
        Ok(())
    }
    fn close(&mut self) -> Result<(), LogSinkError> {
        Ok(())
    }
}

/// The bytes of a 2 s logging flight (4,000 steps, armed at start, link passes at 1 kHz).
fn flight_log() -> Vec<u8> {
    let mut card = Card::default();
    logging::fly(&mut card, 4000, &[(1, ControlCommand::ArmThrowToFly)]);
    card.bytes
}

#[test]
fn a_power_cut_at_1000_random_bytes_leaves_the_file_readable_up_to_its_last_complete_block() {
    let full = flight_log();
    let records: Vec<LogRecord> = LogReader::new(&full).collect();
    let steps = records.iter().filter(|r| matches!(r, LogRecord::Step(_))).count();
    assert_eq!(steps, 4000, "the whole flight is in the uncut file");
    // Where each record's frame ends (its delimiter), in the uncut file.
    let mut decoder = Decoder::new();
    let ends: Vec<usize> = full
        .iter()
        .enumerate()
        .filter_map(|(i, &byte)| matches!(decoder.push(byte), Some(Ok(_))).then_some(i))
        .collect();
    assert_eq!(ends.len(), records.len());

    let mut rng = Rng::new(30);
    let mut torn_seen = 0;
    for trial in 0..1000 {
        let cut = (rng.uniform() * full.len() as f64) as usize;
        let mut file = full[..cut].to_vec();
        let complete = cut / LOG_BLOCK_LEN * LOG_BLOCK_LEN;
        if trial % 2 == 1 && cut > complete {
            // The torn block's rest holds garbage instead of being cut short.
            let rest = LOG_BLOCK_LEN - (cut - complete);
            file.extend((0..rest).map(|_| (rng.uniform() * 256.0) as u8));
        }
        let mut reader = LogReader::new(&file);
        let read: Vec<LogRecord> = reader.by_ref().collect();
        let stats = reader.stats();
        let whole_blocks = ends.iter().filter(|&&end| end < complete).count();
        assert!(
            read.len() >= whole_blocks,
            "cut at byte {cut}: {} records read, {whole_blocks} lie in complete blocks",
            read.len()
        );
        assert_eq!(read[..], records[..read.len()], "cut at byte {cut}: not the flight's records");
        // A file that ends inside a frame (not right after a delimiter) says it is torn.
        if file.last().is_some_and(|&byte| byte != 0) {
            torn_seen += 1;
            assert!(
                stats.torn_tail_bytes > 0 || stats.bad_frames > 0,
                "cut at byte {cut}: the torn tail went unnoticed ({stats:?})"
            );
        }
    }
    assert!(torn_seen > 900, "most cuts tear a block ({torn_seen})");
}
