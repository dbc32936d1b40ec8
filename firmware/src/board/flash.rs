//! The configuration sectors of the internal flash as an `embedded-storage` [`NorFlash`], with
//! reads that report a torn word instead of faulting.
//!
//! # Layout
//! The store owns whole sectors of bank 2 ([`crate::targets::FlashLayout`]: 0x081C_0000, two
//! 128 KiB sectors); the firmware is linked into bank 1 only (`memory.x`), so the store can never
//! erase code, and an erase of bank 2 never stalls instruction fetches from bank 1 (the banks
//! read while the other one writes, RM0433 §4.3.10). Offsets of this driver count from the first
//! configuration sector; erase and program are refused outside the window.
//!
//! # Why reads go through DMA
//! A 32-byte flash word whose programming was cut by a power loss can hold an inconsistent ECC
//! code; a CPU load of such a word gets a bus error, a HardFault even with the ECC interrupt
//! disabled (toolchain notes; RM0433 §4.3.9). A board that faulted on every boot while loading
//! its configuration could not even be reconfigured. The two ways out were a bus-fault-tolerant
//! CPU read (FAULTMASK + CCR.BFHFNMIGN around the load, then checking CFSR) or a DMA copy. This
//! driver copies each flash word with a DMA memory-to-memory transfer into an AXI SRAM bounce
//! buffer: a double ECC error is then a *DMA transfer error* (TEIF) and FLASH_SR2.DBECCERR,
//! both ordinary flags, with no exception, no fault-handler state and no dependence on whether
//! the M7 reports the AXI error precisely. The word is reported as [`FlashError::Ecc`], and
//! `app::settings::ConfigFlash` turns it into zeros that sequential-storage's checksums reject:
//! a torn word is a torn item, and the previous configuration loads. Cost: about a microsecond
//! per 32-byte word, at the link task's priority or in `init` (never the control task).
//!
//! Erase and program use stm32h7xx-hal's bank driver (`UnlockedFlashBank`: 32-byte program
//! words, 128 KiB sectors). Erasing a sector takes up to seconds; the link task (priority 2)
//! does it when the host saves, the control task keeps preempting it.

use super::chip::{cr, flag, Dma};
use crate::targets::{h743, DmaStream};
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use stm32h7xx_hal::flash::LockedFlashBank;

/// Flash word, bytes: the program and ECC unit.
const WORD: usize = h743::FLASH_WORD_LEN as usize;

/// Clear bank 2's ECC flags (FLASH_CCR2: CLR_DBECCERR, CLR_SNECCERR; RM0433 §4.9.27) and
/// return whether a double-bit error had been detected (FLASH_SR2.DBECCERR).
fn take_double_ecc_error() -> bool {
    // SAFETY: FLASH_SR2 is read-only status; FLASH_CCR2 is write-1-to-clear of the two ECC
    // flags only. Used by the configuration driver's task alone.
    let bank = unsafe { (*stm32h7xx_hal::pac::FLASH::ptr()).bank2() };
    let double = bank.sr.read().dbeccerr().bit_is_set();
    bank.ccr.write(|w| w.clr_dbeccerr().set_bit().clr_sneccerr().set_bit());
    double
}

/// The bounce buffer the DMA copies one flash word into (AXI SRAM).
#[repr(C, align(32))]
struct Bounce([u8; WORD]);

#[link_section = ".axisram.flash"]
static mut BOUNCE: core::mem::MaybeUninit<Bounce> = core::mem::MaybeUninit::uninit();

/// What the configuration flash can report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashError {
    /// Outside the configuration sectors.
    OutOfBounds,
    /// Not on a 32-byte word (program) or sector (erase) boundary.
    NotAligned,
    /// A word had an uncorrectable (double-bit) ECC error: torn by a power cut.
    Ecc,
    /// The DMA copy did not finish.
    Timeout,
    /// The flash controller refused an erase or program.
    Controller,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            FlashError::NotAligned => NorFlashErrorKind::NotAligned,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// The configuration sectors (see the module documentation).
pub struct ConfigSectors {
    bank: LockedFlashBank,
    /// First configuration byte as an offset in bank 2.
    bank_offset: u32,
    /// First configuration byte, address.
    address: u32,
    len: u32,
    dma: Dma,
    ecc_errors: u32,
}

impl ConfigSectors {
    /// The configuration window `bank_offsets` of bank 2 (whole sectors), read through
    /// `dma_stream` (memory to memory, no DMAMUX request).
    pub fn new(
        bank2: LockedFlashBank,
        bank_offsets: core::ops::Range<u32>,
        dma_stream: DmaStream,
    ) -> Self {
        let dma = Dma::new(dma_stream);
        dma.route(dma_stream, 0);
        Self {
            address: bank2.address() as u32 + bank_offsets.start,
            bank: bank2,
            bank_offset: bank_offsets.start,
            len: bank_offsets.end - bank_offsets.start,
            dma,
            ecc_errors: 0,
        }
    }

    /// Words found torn so far.
    pub fn ecc_errors(&self) -> u32 {
        self.ecc_errors
    }

    fn check(&self, offset: u32, len: usize) -> Result<(), FlashError> {
        match offset.checked_add(len as u32) {
            Some(end) if end <= self.len => Ok(()),
            _ => Err(FlashError::OutOfBounds),
        }
    }

    /// Copy the flash word at `word_address` (32-byte aligned) by DMA into `out`.
    fn read_word(&mut self, word_address: u32, out: &mut [u8; WORD]) -> Result<(), FlashError> {
        let bounce = core::ptr::addr_of_mut!(BOUNCE) as *mut Bounce;
        take_double_ecc_error();
        // SAFETY: the bounce buffer is in AXI SRAM and only this driver (one task) uses it; the
        // CPU reads it after the stream stopped.
        unsafe {
            self.dma.start(
                word_address,
                bounce as u32,
                (WORD / 4) as u16,
                cr::MEMORY_TO_MEMORY | cr::PINC | cr::MINC | cr::PSIZE_32 | cr::MSIZE_32,
            );
            let mut spins = 10_000u32;
            let flags = loop {
                let flags = self.dma.flags();
                if flags & (flag::TRANSFER_COMPLETE | flag::TRANSFER_ERROR) != 0 || spins == 0 {
                    break flags;
                }
                spins -= 1;
            };
            self.dma.disable();
            self.dma.clear_flags();
            if take_double_ecc_error() || flags & flag::TRANSFER_ERROR != 0 {
                self.ecc_errors = self.ecc_errors.wrapping_add(1);
                return Err(FlashError::Ecc);
            }
            if flags & flag::TRANSFER_COMPLETE == 0 {
                return Err(FlashError::Timeout);
            }
            *out = core::ptr::read_volatile(bounce).0;
        }
        Ok(())
    }
}

impl ErrorType for ConfigSectors {
    type Error = FlashError;
}

impl ReadNorFlash for ConfigSectors {
    const READ_SIZE: usize = 1;

    /// Read through DMA word by word; the first torn word makes the whole read
    /// [`FlashError::Ecc`] (the caller re-reads word by word to keep the good ones).
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        self.check(offset, bytes.len())?;
        let mut at = 0usize;
        while at < bytes.len() {
            let address = self.address + offset + at as u32;
            let word_address = address & !(WORD as u32 - 1);
            let skip = (address - word_address) as usize;
            let take = (WORD - skip).min(bytes.len() - at);
            let mut word = [0u8; WORD];
            self.read_word(word_address, &mut word)?;
            bytes[at..at + take].copy_from_slice(&word[skip..skip + take]);
            at += take;
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.len as usize
    }
}

impl NorFlash for ConfigSectors {
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = h743::FLASH_SECTOR_LEN as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if from > to {
            return Err(FlashError::OutOfBounds);
        }
        self.check(from, (to - from) as usize)?;
        let sector = Self::ERASE_SIZE as u32;
        if !from.is_multiple_of(sector) || !to.is_multiple_of(sector) {
            return Err(FlashError::NotAligned);
        }
        let (from, to) = (self.bank_offset + from, self.bank_offset + to);
        self.bank.unlocked().erase(from, to).map_err(|_| FlashError::Controller)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        self.check(offset, bytes.len())?;
        if !(offset as usize).is_multiple_of(WORD) || !bytes.len().is_multiple_of(WORD) {
            return Err(FlashError::NotAligned);
        }
        let offset = self.bank_offset + offset;
        self.bank.unlocked().write(offset, bytes).map_err(|_| FlashError::Controller)
    }
}
