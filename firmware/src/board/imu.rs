//! The ICM-42688-P on SPI with DMA, driven by its data-ready line.
//!
//! - Start-up (`init`, blocking, 2 MHz): [`crate::drivers::icm42688::Icm42688::init`] runs its
//!   register sequence over [`PolledSpi`] (soft reset, WHO_AM_I, configuration, read-back, power
//!   on: ±2000 °/s, ±16 g, 8 kHz, anti-alias filter at 997 Hz, data ready on INT1). Its result
//!   becomes [`BoardImu::state`] (`BoardHealth.imu`): `WrongIdentity`, `ConfigMismatch` or
//!   `BusError` tell the host exactly why there are no samples.
//! - Running (8 kHz): INT1's rising edge (EXTI) calls [`BoardImu::on_data_ready`], which starts a
//!   15-byte full-duplex transfer at 16 MHz (address byte + 14 data bytes) by two DMA streams
//!   between SPI1 and AXI SRAM buffers, and returns. The RX stream's completion interrupt calls
//!   [`BoardImu::on_transfer_complete`]: chip select up, the 14 bytes decoded
//!   ([`RawSample::from_be_bytes`]) and summed in a [`SampleAverager`].
//! - The control step (2 kHz) takes the mean of the four samples summed since its previous step
//!   ([`Imu::read`]): averaging 8 kHz to the control rate, scaled to rad/s and m/s² in the
//!   sensor's own axes.
//!
//! The EXTI, DMA and control tasks run at the same RTIC priority, so they never preempt one
//! another and share this struct without a lock. A data-ready edge that arrives while a
//! transfer is still running (it cannot at 16 MHz: 15 bytes take 7.5 µs of the 125 µs period) is
//! counted in [`BoardImu::overruns`] and skipped; the data registers then hold the newer sample
//! anyway.
//!
//! Caches: the D-cache is off in this firmware, so the AXI SRAM buffers need no cache
//! maintenance. Enabling it requires cleaning the TX buffer and invalidating the RX buffer
//! around each transfer (or an MPU region marking them non-cacheable).

use super::chip::{self, cr, flag, Dma};
use crate::app::hal::{Imu, ImuSample};
use crate::drivers::icm42688::{
    driver_state, DelayUs, Icm42688, RawSample, RegisterBus, SampleAverager, SAMPLE_FIRST_REGISTER,
    SAMPLE_LEN, SPI_READ_FLAG,
};
use crate::targets::h743::{self, rcc, spi};
use crate::targets::{spi_mbr, ImuWiring};
use core::ptr::addr_of_mut;
use protocol::ImuDriverState;

/// The SPI kernel clock: per_ck = HSI, 64 MHz (the HAL's default per_ck), selected for SPI1/2/3
/// in `init` so the SPI clock does not depend on the PLL plan (400 or 480 MHz).
pub const SPI_KERNEL_HZ: u32 = 64_000_000;

/// Bytes of one sample transfer: the address byte, then the 14 data bytes.
const TRANSFER_LEN: usize = 1 + SAMPLE_LEN;

/// The DMA buffers, in AXI SRAM (DMA1 cannot reach DTCM). NOLOAD: written in `BoardImu::new`.
#[repr(C, align(32))]
struct Buffers {
    tx: [u8; 32],
    rx: [u8; 32],
}

#[link_section = ".axisram.imu"]
static mut BUFFERS: core::mem::MaybeUninit<Buffers> = core::mem::MaybeUninit::uninit();

/// The SPI bus error of the polled start-up transfers: a flag that never came.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SpiTimeout;

/// SPI1 with a GPIO chip select, polled (start-up only).
pub struct PolledSpi {
    base: u32,
    cs: crate::targets::Pin,
    mbr: u32,
}

impl PolledSpi {
    fn wait(&self, mask: u32) -> Result<(), SpiTimeout> {
        let mut spins = 100_000u32;
        // SAFETY: SR is read-only.
        while unsafe { chip::read(self.base + spi::SR) } & mask == 0 {
            spins -= 1;
            if spins == 0 {
                return Err(SpiTimeout);
            }
        }
        Ok(())
    }

    /// One full-duplex transfer of `bytes` (in place) with chip select low.
    fn transfer(&mut self, bytes: &mut [u8]) -> Result<(), SpiTimeout> {
        let base = self.base;
        chip::set(self.cs, false);
        // SAFETY: SPI1 belongs to this driver; configuration written while SPE = 0; TXDR and
        // RXDR are accessed as bytes (8-bit frames: a 32-bit access would pack four frames).
        let result = unsafe {
            chip::write(base + spi::CR1, spi::CR1_SSI);
            chip::write(base + spi::CFG1, (self.mbr << spi::CFG1_MBR_SHIFT) | spi::CFG1_DSIZE_8);
            chip::write(base + spi::CR2, bytes.len() as u32);
            chip::write(base + spi::CR1, spi::CR1_SSI | spi::CR1_SPE);
            chip::write(base + spi::CR1, spi::CR1_SSI | spi::CR1_SPE | spi::CR1_CSTART);
            let mut result = Ok(());
            for byte in bytes.iter_mut() {
                result = self.wait(spi::SR_TXP);
                if result.is_err() {
                    break;
                }
                core::ptr::write_volatile((base + spi::TXDR) as *mut u8, *byte);
                result = self.wait(spi::SR_RXP);
                if result.is_err() {
                    break;
                }
                *byte = core::ptr::read_volatile((base + spi::RXDR) as *const u8);
            }
            if result.is_ok() {
                result = self.wait(spi::SR_EOT);
            }
            chip::write(base + spi::IFCR, spi::IFCR_ALL);
            chip::write(base + spi::CR1, spi::CR1_SSI);
            result
        };
        chip::set(self.cs, true);
        result
    }
}

impl RegisterBus for PolledSpi {
    type Error = SpiTimeout;

    fn write_register(&mut self, reg: u8, value: u8) -> Result<(), SpiTimeout> {
        self.transfer(&mut [reg & !SPI_READ_FLAG, value])
    }

    fn read_registers(&mut self, first_reg: u8, buf: &mut [u8]) -> Result<(), SpiTimeout> {
        let mut frame = [0u8; 1 + 16];
        let len = 1 + buf.len().min(16);
        frame[0] = first_reg | SPI_READ_FLAG;
        self.transfer(&mut frame[..len])?;
        buf[..len - 1].copy_from_slice(&frame[1..len]);
        Ok(())
    }
}

/// A busy-wait delay on the core clock (start-up only).
pub struct CycleDelay {
    /// Core clock cycles per microsecond.
    pub cycles_per_us: u32,
}

impl DelayUs for CycleDelay {
    fn delay_us(&mut self, us: u32) {
        cortex_m::asm::delay(us.saturating_mul(self.cycles_per_us));
    }
}

/// The board's IMU (see the module documentation).
pub struct BoardImu {
    wiring: ImuWiring,
    base: u32,
    rx: Dma,
    tx: Dma,
    read_mbr: u32,
    averager: SampleAverager,
    busy: bool,
    state: ImuDriverState,
    transfers: u32,
    overruns: u32,
    errors: u32,
}

impl BoardImu {
    /// Configure the pins, SPI and DMA, run the start-up sequence and, if it passed, arm the
    /// data-ready interrupt. Never fails: a failed check is reported by [`BoardImu::state`] and
    /// the IMU then delivers no samples.
    pub fn new(wiring: ImuWiring, cycles_per_us: u32) -> Self {
        let info = h743::spi(wiring.spi);
        // SPI1/2/3 kernel clock = per_ck (RCC_D2CCIP1R.SPI123SEL, RM0433 §8.7.21).
        // SAFETY: the SPI123SEL field only, before SPI1 is enabled.
        unsafe {
            chip::modify(
                h743::RCC_BASE + rcc::D2CCIP1R,
                rcc::D2CCIP1R_SPI123SEL,
                rcc::D2CCIP1R_SPI123SEL_PER_CK,
            )
        };
        chip::enable_clock(info.enable);
        chip::output(wiring.cs, true);
        chip::alternate(wiring.sck, false);
        chip::alternate(wiring.miso, false);
        chip::alternate(wiring.mosi, false);
        chip::input_pull_down(wiring.data_ready);
        let base = info.base;
        // SAFETY: SPI1 is this driver's; configured while disabled.
        unsafe {
            chip::write(base + spi::CR1, spi::CR1_SSI);
            chip::write(base + spi::CFG2, spi::CFG2_MASTER_MODE3);
        }
        // Chip select must rise between transfers; give the device its 1 µs after power-up.
        cortex_m::asm::delay(100 * cycles_per_us);

        let init_mbr = u32::from(spi_mbr(SPI_KERNEL_HZ, wiring.init_clock_hz));
        let mut device = Icm42688::new(PolledSpi { base, cs: wiring.cs, mbr: init_mbr });
        let result = device.init(&mut CycleDelay { cycles_per_us });
        let state = driver_state(&result);

        let rx = Dma::new(wiring.rx_dma);
        let tx = Dma::new(wiring.tx_dma);
        rx.route(wiring.rx_dma, info.rx_request);
        tx.route(wiring.tx_dma, info.tx_request);
        // SAFETY: the buffers are only touched here (before any transfer) and by the DMA and
        // `on_transfer_complete` afterwards, all from one priority level.
        unsafe {
            let buffers = addr_of_mut!(BUFFERS) as *mut Buffers;
            core::ptr::write_volatile(buffers, Buffers { tx: [0; 32], rx: [0; 32] });
            (*buffers).tx[0] = SAMPLE_FIRST_REGISTER | SPI_READ_FLAG;
        }
        if state == ImuDriverState::Running {
            chip::exti_rising(wiring.data_ready);
        }
        Self {
            wiring,
            base,
            rx,
            tx,
            read_mbr: u32::from(spi_mbr(SPI_KERNEL_HZ, wiring.read_clock_hz)),
            averager: SampleAverager::new(),
            busy: false,
            state,
            transfers: 0,
            overruns: 0,
            errors: 0,
        }
    }

    /// The start-up result (what `GetBoard` reports).
    pub fn state(&self) -> ImuDriverState {
        self.state
    }

    /// Sample transfers completed, data-ready edges skipped (a transfer still running), and
    /// transfers that failed (DMA transfer error).
    pub fn counters(&self) -> (u32, u32, u32) {
        (self.transfers, self.overruns, self.errors)
    }

    /// The data-ready interrupt: start reading the sample. Returns at once.
    pub fn on_data_ready(&mut self) {
        chip::exti_clear(self.wiring.data_ready.number);
        if self.state != ImuDriverState::Running {
            return;
        }
        if self.busy {
            self.overruns = self.overruns.wrapping_add(1);
            return;
        }
        self.busy = true;
        let base = self.base;
        chip::set(self.wiring.cs, false);
        // SAFETY: RM0433 §50.4.14 order for full-duplex DMA: RX DMA request enabled, both
        // streams started, TX DMA request enabled, then SPE and CSTART. The buffers are in AXI
        // SRAM and not touched by the CPU until the RX stream completes.
        unsafe {
            let buffers = addr_of_mut!(BUFFERS) as *mut Buffers;
            let cfg1 = (self.read_mbr << spi::CFG1_MBR_SHIFT) | spi::CFG1_DSIZE_8;
            chip::write(base + spi::CR1, spi::CR1_SSI);
            chip::write(base + spi::IFCR, spi::IFCR_ALL);
            chip::write(base + spi::CFG1, cfg1 | spi::CFG1_RXDMAEN);
            chip::write(base + spi::CR2, TRANSFER_LEN as u32);
            self.rx.start(
                base + spi::RXDR,
                addr_of_mut!((*buffers).rx) as u32,
                TRANSFER_LEN as u16,
                cr::PERIPHERAL_TO_MEMORY | cr::MINC | cr::TCIE | cr::TEIE | cr::PRIORITY_VERY_HIGH,
            );
            self.tx.start(
                base + spi::TXDR,
                addr_of_mut!((*buffers).tx) as u32,
                TRANSFER_LEN as u16,
                cr::MEMORY_TO_PERIPHERAL | cr::MINC | cr::PRIORITY_HIGH,
            );
            chip::write(base + spi::CFG1, cfg1 | spi::CFG1_RXDMAEN | spi::CFG1_TXDMAEN);
            chip::write(base + spi::CR1, spi::CR1_SSI | spi::CR1_SPE);
            chip::write(base + spi::CR1, spi::CR1_SSI | spi::CR1_SPE | spi::CR1_CSTART);
        }
    }

    /// The RX stream's interrupt: end the transfer and add the sample.
    pub fn on_transfer_complete(&mut self) {
        let flags = self.rx.flags();
        self.rx.clear_flags();
        self.tx.clear_flags();
        if !self.busy {
            return;
        }
        let base = self.base;
        // SAFETY: the transfer is over (RX complete or failed); end it as RM0433 §50.4.14
        // says: streams off, SPE off, DMA requests off.
        unsafe {
            let mut spins = 1_000u32;
            while chip::read(base + spi::SR) & spi::SR_EOT == 0 && spins > 0 {
                spins -= 1;
            }
            self.tx.disable();
            self.rx.disable();
            chip::write(base + spi::IFCR, spi::IFCR_ALL);
            chip::write(base + spi::CR1, spi::CR1_SSI);
            chip::modify(base + spi::CFG1, spi::CFG1_RXDMAEN | spi::CFG1_TXDMAEN, 0);
        }
        chip::set(self.wiring.cs, true);
        self.busy = false;
        if flags & flag::TRANSFER_ERROR != 0 || flags & flag::TRANSFER_COMPLETE == 0 {
            self.errors = self.errors.wrapping_add(1);
            return;
        }
        let mut bytes = [0u8; SAMPLE_LEN];
        // SAFETY: the DMA has finished writing the RX buffer.
        unsafe {
            let buffers = addr_of_mut!(BUFFERS) as *const Buffers;
            let rx = core::ptr::read_volatile(addr_of_mut!((*buffers.cast_mut()).rx));
            bytes.copy_from_slice(&rx[1..TRANSFER_LEN]);
        }
        self.averager.add(&RawSample::from_be_bytes(&bytes));
        self.transfers = self.transfers.wrapping_add(1);
    }
}

impl Imu for BoardImu {
    /// The mean of the samples read since the previous call (four at 8 kHz / 2 kHz), or `None`
    /// when none arrived. Never blocks.
    fn read(&mut self) -> Option<ImuSample> {
        self.averager.take().map(|sample| sample.to_imu_sample())
    }
}
