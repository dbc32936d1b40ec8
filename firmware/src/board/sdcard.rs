//! The microSD card on SDMMC1, as the 512-byte-block [`NorFlash`] the flight log's card layout
//! (`app::card`) is written on: stm32h7xx-hal 0.16's SDMMC driver (feature `sdmmc`: card
//! identification, 4-bit bus, single-block reads and writes by polling the FIFO with hardware
//! flow control, so a preempted transfer pauses the card's clock instead of failing), and an
//! erase of our own (CMD32/33/38, which the HAL lacks) through its registers.
//!
//! Only the lowest-priority task calls it (and the link task, for one block, under the log's
//! lock): every call busy-waits for the card, up to its own timeouts (a block write usually a
//! few ms, an erase up to seconds on a slow card; SD Physical Layer spec 4.6.2). Longest block
//! write and blocks written are kept for the idle task's report ([`card_stats`]): that is how
//! the card's write time is measured on the board (docs/flight-log.md).
//!
//! SDHC and SDXC cards only (block addressing; any card of 4 GB or more). A standard-capacity
//! card (2 GB or less, byte addressing, which the HAL does not handle) is refused at start-up.

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::DWT;
use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash};
use stm32h7xx_hal::pac::SDMMC1;
use stm32h7xx_hal::prelude::*;
use stm32h7xx_hal::rcc::{rec, CoreClocks};
use stm32h7xx_hal::sdmmc::{Buswidth, SdCard, Sdmmc, SdmmcExt};

use super::chip;
use super::timing::cycles_per_us;
use crate::app::log::LOG_BLOCK_LEN;
use crate::targets::SdCardWiring;

/// The card's bus clock, Hz: default speed (SD Physical Layer spec 4.3.10: up to 25 MHz on
/// 3.3 V signalling), 12.5 MB/s on four data lines, fifty times what the log needs.
pub const CARD_CLOCK_HZ: u32 = 25_000_000;

/// Status polls (CMD13) an erase may wait for, at a few µs each: about 10 s.
const ERASE_POLLS: u32 = 2_000_000;

/// Longest block write, µs, and blocks written since start-up (written by the card's caller).
static WRITE_MAX_US: AtomicU32 = AtomicU32::new(0);
static BLOCKS_WRITTEN: AtomicU32 = AtomicU32::new(0);

/// What [`card_stats`] reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CardStats {
    /// Longest single-block write so far (command, data, the card's busy time), µs.
    pub write_max_us: u32,
    /// Blocks written since start-up.
    pub blocks: u32,
}

/// The card's write time so far.
pub fn card_stats() -> CardStats {
    CardStats {
        write_max_us: WRITE_MAX_US.load(Ordering::Relaxed),
        blocks: BLOCKS_WRITTEN.load(Ordering::Relaxed),
    }
}

/// The card in the slot, identified and on a 4-bit bus at [`CARD_CLOCK_HZ`].
pub struct BoardCard {
    sdmmc: Sdmmc<SDMMC1, SdCard>,
    /// The card's size, bytes.
    size: u64,
    rca: u32,
}

impl BoardCard {
    /// Connect the slot's pins, start SDMMC1 (kernel clock: PLL1 Q) and identify the card.
    /// `None`: no card, a card that does not answer, or a standard-capacity one.
    pub fn start(
        wiring: SdCardWiring,
        sdmmc1: SDMMC1,
        prec: rec::Sdmmc1,
        clocks: &CoreClocks,
    ) -> Option<Self> {
        // Pull-ups on the command and data lines (an idle card line is high), none on the clock.
        for (pin, _) in wiring.pins() {
            chip::alternate(pin, pin != wiring.clock);
        }
        let mut sdmmc: Sdmmc<SDMMC1, SdCard> = sdmmc1.sdmmc_unchecked(Buswidth::Four, prec, clocks);
        sdmmc.init(CARD_CLOCK_HZ.Hz()).ok()?;
        let card = sdmmc.card().ok()?;
        if !matches!(card.capacity, sdio_host::sd::CardCapacity::HighCapacity) {
            return None;
        }
        let (size, rca) = (card.size(), u32::from(card.rca.address()));
        Some(Self { sdmmc, size, rca })
    }

    /// One command with a short response (R1), by the registers; its response.
    fn command(&mut self, index: u8, argument: u32) -> Result<u32, NorFlashErrorKind> {
        let regs = self.sdmmc.inner_mut();
        regs.icr.write(|w| w.ccrcfailc().set_bit().ctimeoutc().set_bit().cmdrendc().set_bit());
        // SAFETY: any argument is valid; index is a 6-bit command number.
        regs.argr.write(|w| unsafe { w.cmdarg().bits(argument) });
        regs.cmdr
            .write(|w| unsafe { w.waitresp().bits(1).cmdindex().bits(index).cpsmen().set_bit() });
        // The peripheral ends every command: a response, a CRC failure or its 64-clock timeout.
        loop {
            let status = regs.star.read();
            if status.cmdrend().bit_is_set() {
                return Ok(regs.resp1r.read().bits());
            }
            if status.ctimeout().bit_is_set() || status.ccrcfail().bit_is_set() {
                return Err(NorFlashErrorKind::Other);
            }
        }
    }
}

impl ErrorType for BoardCard {
    type Error = NorFlashErrorKind;
}

/// Each 512-byte block of `bytes`, with its block number from byte `offset`.
fn blocks(
    offset: u32,
    len: usize,
) -> Result<impl Iterator<Item = (u32, usize)>, NorFlashErrorKind> {
    let block = LOG_BLOCK_LEN as u32;
    if !offset.is_multiple_of(block) || !len.is_multiple_of(LOG_BLOCK_LEN) {
        return Err(NorFlashErrorKind::NotAligned);
    }
    Ok((0..len / LOG_BLOCK_LEN).map(move |i| (offset / block + i as u32, i * LOG_BLOCK_LEN)))
}

impl ReadNorFlash for BoardCard {
    const READ_SIZE: usize = LOG_BLOCK_LEN;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        for (block, at) in blocks(offset, bytes.len())? {
            let Ok(buf) = (&mut bytes[at..at + LOG_BLOCK_LEN]).try_into() else { unreachable!() };
            self.sdmmc.read_block(block, buf).map_err(|_| NorFlashErrorKind::Other)?;
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        usize::try_from(self.size).unwrap_or(usize::MAX)
    }
}

impl NorFlash for BoardCard {
    const WRITE_SIZE: usize = LOG_BLOCK_LEN;
    const ERASE_SIZE: usize = LOG_BLOCK_LEN;

    /// CMD32/CMD33 the range, CMD38 erase, then the card's status (CMD13) until it is back in
    /// the transfer state. Erased blocks read all 0x00 or all 0xFF (the card's SCR says which).
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let block = LOG_BLOCK_LEN as u32;
        if !from.is_multiple_of(block) || !to.is_multiple_of(block) {
            return Err(NorFlashErrorKind::NotAligned);
        }
        if to <= from {
            return Ok(());
        }
        self.command(32, from / block)?;
        self.command(33, to / block - 1)?;
        self.command(38, 0)?;
        for _ in 0..ERASE_POLLS {
            // R1 bits 12:9, CURRENT_STATE: 4 = transfer.
            if (self.command(13, self.rca << 16)? >> 9) & 0xF == 4 {
                return Ok(());
            }
        }
        Err(NorFlashErrorKind::Other)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        for (block, at) in blocks(offset, bytes.len())? {
            let Ok(buf) = (&bytes[at..at + LOG_BLOCK_LEN]).try_into() else { unreachable!() };
            let started = DWT::cycle_count();
            self.sdmmc.write_block(block, buf).map_err(|_| NorFlashErrorKind::Other)?;
            let us = DWT::cycle_count().wrapping_sub(started) / cycles_per_us();
            WRITE_MAX_US.fetch_max(us, Ordering::Relaxed);
            BLOCKS_WRITTEN.fetch_add(1, Ordering::Relaxed);
        }
        Ok(())
    }
}
