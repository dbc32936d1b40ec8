//! Facts about the STM32H743 itself (not a board): the peripherals a flight-controller board
//! wires, their register addresses, the register offsets and bit fields the board layer
//! (`crate::board`) writes, clock-enable bits and DMAMUX request numbers, and the alternate
//! functions of the pins such boards use.
//!
//! Why here and not beside the code that writes them: this module builds on the host, so every
//! number in it is checked there against a definition we did not type. The host test
//! `firmware/tests/registers_match_pac.rs` compares each base address, register offset, bit
//! position, field value and DMAMUX request number below with the `stm32h7` PAC (0.15, feature
//! `stm32h743v`, the PAC `stm32h7xx-hal` 0.16 re-exports), generated from ST's SVD: a wrong or
//! mistyped number fails `cargo test` and names the constant. The board layer writes registers
//! only through these constants (or the HAL/PAC); it types no address, offset or bit of its own.
//!
//! Sources: RM0433 rev 8 (§2.3 memory map, §8.7 RCC registers, §11.4 GPIO, §15.5 DMA, §17 DMAMUX,
//! §20 EXTI, §12 SYSCFG, §39 timers, §48 USART, §50 SPI, Table 121 "DMAMUX1: assignment of
//! multiplexer inputs to resources") and the datasheet DS12110 (Table 9 "Port A–E alternate
//! functions"). The alternate-function table and the flash layout are not in the PAC; the
//! former is checked for internal consistency by `tests/board_description.rs`.

use super::{pin, Pin, Port};

/// Flash bank 1, first address (sector 0).
pub const FLASH_BANK1_START: u32 = 0x0800_0000;
/// Flash bank 2, first address.
pub const FLASH_BANK2_START: u32 = 0x0810_0000;
/// Bytes per bank (STM32H743xI: 2 × 1 MiB).
pub const FLASH_BANK_LEN: u32 = 0x10_0000;
/// Bytes per sector (128 KiB, the erase unit).
pub const FLASH_SECTOR_LEN: u32 = 0x2_0000;
/// Bytes per flash word (256 bits: the programming unit and the ECC unit).
pub const FLASH_WORD_LEN: u32 = 32;
/// The ROM system-memory bootloader's vector table (AN2606 rev 60, STM32H74xxx/75xxx:
/// "system memory" bootloader entry 0x1FF0_9800; USB DFU on OTG_FS PA11/PA12).
pub const SYSTEM_BOOTLOADER_VECTORS: u32 = 0x1FF0_9800;

/// SPI peripherals.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spi {
    Spi1,
    Spi4,
}

/// U(S)ART peripherals.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Uart {
    Usart1,
    Usart2,
    Usart6,
}

/// I²C peripherals.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum I2c {
    I2c1,
    I2c2,
}

/// Timers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timer {
    Tim2,
    Tim3,
    Tim4,
    Tim5,
    Tim7,
    Tim8,
}

/// What a pin can be connected to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Function {
    SpiSck(Spi),
    SpiMiso(Spi),
    SpiMosi(Spi),
    UartRx(Uart),
    UartTx(Uart),
    /// Timer, channel 1..=4 (not the complementary outputs: they cannot capture).
    TimerChannel(Timer, u8),
    UsbDm,
    UsbDp,
    /// SDMMC1's clock, command line and data line 0..=3 (the microSD card).
    SdmmcCk,
    SdmmcCmd,
    SdmmcData(u8),
    /// An I²C peripheral's clock and data lines (open drain).
    I2cScl(I2c),
    I2cSda(I2c),
}

/// An RCC clock-enable register (offsets in the RCC block, RM0433 §8.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RccRegister {
    /// RCC_AHB1ENR (0xD8): DMA1, DMA2.
    Ahb1 = 0xD8,
    /// RCC_AHB4ENR (0xE0): GPIO ports.
    Ahb4 = 0xE0,
    /// RCC_APB1LENR (0xE8): TIM2–TIM7, USART2/3, UART4/5/7/8.
    Apb1L = 0xE8,
    /// RCC_APB2ENR (0xF0): TIM1/8, USART1/6, SPI1/4/5.
    Apb2 = 0xF0,
}

/// A peripheral's clock-enable bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RccEnable {
    pub register: RccRegister,
    pub bit: u8,
}

/// The RCC register block.
pub const RCC_BASE: u32 = 0x5802_4400;
/// GPIOA; port n is at `GPIOA_BASE + GPIO_PORT_STRIDE · n` ([`gpio_base`]).
pub const GPIOA_BASE: u32 = 0x5802_0000;
/// Bytes between two GPIO ports' register blocks (GPIOB − GPIOA, …, GPIOE − GPIOD).
pub const GPIO_PORT_STRIDE: u32 = 0x400;
/// DMA1 (DMA2 is 0x400 above).
pub const DMA1_BASE: u32 = 0x4002_0000;
/// DMA2.
pub const DMA2_BASE: u32 = 0x4002_0400;
/// DMAMUX1.
pub const DMAMUX1_BASE: u32 = 0x4002_0800;
/// EXTI (the CPU1 interrupt mask and pending registers included).
pub const EXTI_BASE: u32 = 0x5800_0000;
/// SYSCFG (the EXTI line → port selection).
pub const SYSCFG_BASE: u32 = 0x5800_0400;
/// ADC1 (the battery's voltage and current).
pub const ADC1_BASE: u32 = 0x4002_2000;
/// The registers ADC1 and ADC2 share (their clock).
pub const ADC12_COMMON_BASE: u32 = 0x4002_2300;
/// ADC1/ADC2's clock enable (RCC_AHB1ENR.ADC12EN).
pub const ADC12_ENABLE: RccEnable = RccEnable { register: RccRegister::Ahb1, bit: 5 };

/// The register block of GPIO `port`.
#[inline(always)]
pub const fn gpio_base(port: Port) -> u32 {
    GPIOA_BASE + GPIO_PORT_STRIDE * port.index() as u32
}

/// RCC registers besides the clock-enable registers of [`RccRegister`] (RM0433 §8.7).
pub mod rcc {
    /// RCC_D2CCIP1R, domain 2 kernel clock selection (SPI1/2/3 among others; §8.7.21).
    pub const D2CCIP1R: u32 = 0x50;
    /// D2CCIP1R.SPI123SEL, the SPI1/2/3 kernel clock selection (3 bits).
    pub const D2CCIP1R_SPI123SEL: u32 = 0b111 << 12;
    /// SPI123SEL = 0b100: per_ck.
    pub const D2CCIP1R_SPI123SEL_PER_CK: u32 = 0b100 << 12;
    /// RCC_D3CCIPR, domain 3 kernel clock selection (the ADCs among others; §8.7.22).
    pub const D3CCIPR: u32 = 0x58;
    /// D3CCIPR.ADCSEL, the ADCs' kernel clock selection (2 bits).
    pub const D3CCIPR_ADCSEL: u32 = 0b11 << 16;
    /// ADCSEL = 0b10: per_ck (the HAL leaves per_ck on HSI, 64 MHz).
    pub const D3CCIPR_ADCSEL_PER_CK: u32 = 0b10 << 16;
    /// RCC_APB4ENR, APB4 clock enables (§8.7.44).
    pub const APB4ENR: u32 = 0xF4;
    /// APB4ENR.SYSCFGEN.
    pub const APB4ENR_SYSCFGEN: u32 = 1 << 1;
}

/// GPIO registers and field values (RM0433 §11.4). MODER, OSPEEDR and PUPDR hold a 2-bit field
/// per pin at bit 2·n; AFRL/AFRH a 4-bit field per pin at bit 4·(n mod 8); BSRR sets pin n with
/// bit n and resets it with bit n + 16.
pub mod gpio {
    pub const MODER: u32 = 0x00;
    pub const OSPEEDR: u32 = 0x08;
    pub const PUPDR: u32 = 0x0C;
    /// OTYPER: bit n set makes pin n open drain.
    pub const OTYPER: u32 = 0x04;
    pub const IDR: u32 = 0x10;
    pub const BSRR: u32 = 0x18;
    /// AFRL (pins 0–7); AFRH (pins 8–15) is the next word.
    pub const AFRL: u32 = 0x20;
    /// Bits per pin in MODER, OSPEEDR, PUPDR.
    pub const FIELD2_BITS: u32 = 2;
    /// Bits per pin in AFRL/AFRH, and pins per AFR register.
    pub const AFR_BITS: u32 = 4;
    pub const AFR_PINS: u32 = 8;
    /// BSRR: the reset bit of pin n is bit n + `BSRR_RESET_SHIFT`.
    pub const BSRR_RESET_SHIFT: u32 = 16;
    /// MODER values.
    pub const MODE_INPUT: u32 = 0b00;
    pub const MODE_OUTPUT: u32 = 0b01;
    pub const MODE_ALTERNATE: u32 = 0b10;
    /// Analog (an ADC input; the reset state of most pins).
    pub const MODE_ANALOG: u32 = 0b11;
    /// OSPEEDR values.
    pub const SPEED_HIGH: u32 = 0b10;
    pub const SPEED_VERY_HIGH: u32 = 0b11;
    /// PUPDR values.
    pub const PULL_NONE: u32 = 0b00;
    pub const PULL_UP: u32 = 0b01;
    pub const PULL_DOWN: u32 = 0b10;

    /// Pin `number`'s field in MODER, OSPEEDR, PUPDR starts at this bit.
    #[inline(always)]
    pub const fn field2_shift(number: u32) -> u32 {
        FIELD2_BITS * number
    }

    /// (AFRL or AFRH, the bit pin `number`'s 4-bit field starts at).
    #[inline(always)]
    pub const fn afr_register_and_shift(number: u32) -> (u32, u32) {
        (AFRL + 4 * (number / AFR_PINS), AFR_BITS * (number % AFR_PINS))
    }

    /// The BSRR bit that drives pin `number` high (`high`) or low.
    #[inline(always)]
    pub const fn bsrr_bit(number: u32, high: bool) -> u32 {
        1 << (number + if high { 0 } else { BSRR_RESET_SHIFT })
    }

    /// Pin `number`'s bit in IDR.
    #[inline(always)]
    pub const fn idr_bit(number: u32) -> u32 {
        1 << number
    }
}

/// EXTI registers (RM0433 §20.6), offsets from [`super::h743::EXTI_BASE`]. Line n (0..=15) is bit
/// n of each.
pub mod exti {
    /// EXTI_RTSR1, rising-edge trigger of lines 0–31.
    pub const RTSR1: u32 = 0x00;
    /// EXTI_CPUIMR1, CPU interrupt mask (1 = unmasked) of lines 0–31.
    pub const CPUIMR1: u32 = 0x80;
    /// EXTI_CPUPR1, CPU pending flags of lines 0–31 (write 1 to clear).
    pub const CPUPR1: u32 = 0x88;

    /// Line `line`'s bit in RTSR1, CPUIMR1 and CPUPR1.
    #[inline(always)]
    pub const fn line_bit(line: u32) -> u32 {
        1 << line
    }
}

/// SYSCFG registers (RM0433 §12.3), offsets from [`super::h743::SYSCFG_BASE`].
pub mod syscfg {
    /// SYSCFG_EXTICR1 (lines 0–3); EXTICR2–4 follow word by word. Line n's 4-bit port field is
    /// at bit 4·(n mod 4) of EXTICR(n / 4 + 1); the value is the port index (A = 0).
    pub const EXTICR1: u32 = 0x08;
    pub const EXTICR_BITS: u32 = 4;
    pub const EXTICR_LINES: u32 = 4;

    /// (EXTICRn, the bit EXTI line `line`'s port field starts at).
    #[inline(always)]
    pub const fn exticr_register_and_shift(line: u32) -> (u32, u32) {
        (EXTICR1 + 4 * (line / EXTICR_LINES), EXTICR_BITS * (line % EXTICR_LINES))
    }
}

/// DMA1/DMA2 registers (RM0433 §15.5), offsets from [`DMA1_BASE`] or
/// [`DMA2_BASE`].
pub mod dma {
    /// Interrupt status of streams 0–3 and 4–7 (read-only).
    pub const LISR: u32 = 0x00;
    pub const HISR: u32 = 0x04;
    /// Interrupt flag clear of streams 0–3 and 4–7 (write 1 to clear).
    pub const LIFCR: u32 = 0x08;
    pub const HIFCR: u32 = 0x0C;
    /// Stream 0's registers; stream s's are `STREAM_STRIDE · s` above.
    pub const STREAM0: u32 = 0x10;
    pub const STREAM_STRIDE: u32 = 0x18;
    /// A stream's registers, offsets from its first (`SxCR`).
    pub const SXCR: u32 = 0x00;
    pub const SXNDTR: u32 = 0x04;
    pub const SXPAR: u32 = 0x08;
    pub const SXM0AR: u32 = 0x0C;
    pub const SXFCR: u32 = 0x14;
    /// SxNDTR.NDT, the data items left (16 bits).
    pub const SXNDTR_NDT: u32 = 0xFFFF;
    /// SxFCR: FIFO on (direct mode disabled, DMDIS) with the threshold at a full FIFO
    /// (FTH = 0b11).
    pub const SXFCR_FIFO_FULL: u32 = (1 << 2) | 0b11;
    /// Where stream s's five flags start in LISR/HISR and LIFCR/HIFCR: bit `FLAG_SHIFTS[s % 4]`
    /// of the low (s < 4) or high register.
    pub const FLAG_SHIFTS: [u32; 4] = [0, 6, 16, 22];

    /// The stream's address of register `offset` (one of the `SX…` offsets).
    #[inline(always)]
    pub const fn stream_register(base: u32, stream: u32, offset: u32) -> u32 {
        base + STREAM0 + STREAM_STRIDE * stream + offset
    }

    /// DMA stream configuration bits (DMA_SxCR, RM0433 §15.5.5).
    pub mod cr {
        pub const EN: u32 = 1 << 0;
        pub const TEIE: u32 = 1 << 2;
        pub const TCIE: u32 = 1 << 4;
        pub const PERIPHERAL_TO_MEMORY: u32 = 0b00 << 6;
        pub const MEMORY_TO_PERIPHERAL: u32 = 0b01 << 6;
        pub const MEMORY_TO_MEMORY: u32 = 0b10 << 6;
        pub const CIRC: u32 = 1 << 8;
        pub const PINC: u32 = 1 << 9;
        pub const MINC: u32 = 1 << 10;
        pub const PSIZE_32: u32 = 0b10 << 11;
        pub const MSIZE_32: u32 = 0b10 << 13;
        pub const PRIORITY_HIGH: u32 = 0b10 << 16;
        pub const PRIORITY_VERY_HIGH: u32 = 0b11 << 16;
    }

    /// One stream's interrupt flags, shifted down to bit 0 (RM0433 §15.5.1: FEIF, DMEIF, TEIF,
    /// HTIF, TCIF; the same layout in LIFCR/HIFCR).
    pub mod flag {
        pub const TRANSFER_ERROR: u32 = 1 << 3;
        pub const TRANSFER_COMPLETE: u32 = 1 << 5;
        /// FIFO, direct-mode, transfer errors, half and full transfer.
        pub const ALL: u32 = 0b11_1101;
    }
}

/// DMAMUX1 registers (RM0433 §17.6), offsets from [`DMAMUX1_BASE`].
pub mod dmamux {
    /// DMAMUX1_C0CR; channel c's is `CCR_STRIDE · c` above (channels 0–7 feed DMA1's streams,
    /// 8–15 DMA2's).
    pub const C0CR: u32 = 0x00;
    pub const CCR_STRIDE: u32 = 4;
    /// CxCR.DMAREQ_ID, the request routed to the channel (0: none).
    pub const CCR_DMAREQ_ID: u32 = 0xFF;

    /// DMAMUX1 channel `channel`'s CxCR.
    #[inline(always)]
    pub const fn ccr(channel: u32) -> u32 {
        C0CR + CCR_STRIDE * channel
    }
}

/// Timer registers and bits (RM0433 §39.4, general-purpose TIM2–TIM5; the same offsets hold for
/// the advanced TIM1/TIM8 registers used here).
pub mod tim {
    pub const CR1: u32 = 0x00;
    pub const DIER: u32 = 0x0C;
    pub const SR: u32 = 0x10;
    pub const EGR: u32 = 0x14;
    /// CCMR1 (channels 1, 2) and CCMR2 (channels 3, 4).
    pub const CCMR1: u32 = 0x18;
    pub const CCMR2: u32 = 0x1C;
    pub const CCER: u32 = 0x20;
    pub const CNT: u32 = 0x24;
    pub const PSC: u32 = 0x28;
    pub const ARR: u32 = 0x2C;
    /// CCR1; channel c's compare register is `CCR1 + 4 · (c − 1)`.
    pub const CCR1: u32 = 0x34;
    pub const DCR: u32 = 0x48;
    pub const DMAR: u32 = 0x4C;
    pub const CR1_CEN: u32 = 1 << 0;
    pub const CR1_ARPE: u32 = 1 << 7;
    pub const DIER_UDE: u32 = 1 << 8;
    /// CC1DE; channel c (1..=4) is bit 8 + c.
    pub const DIER_CC1DE: u32 = 1 << 9;
    pub const EGR_UG: u32 = 1 << 0;
    /// Bits between two channels' fields in the same CCMR register (an even channel's field is
    /// this much higher than the odd channel's).
    pub const CCMR_CHANNEL_SHIFT: u32 = 8;
    /// OCxM = PWM mode 1 (0b0110) with the compare preload (OCxPE), for an odd channel.
    pub const CCMR_PWM1_PRELOAD: u32 = (0b110 << 4) | (1 << 3);
    /// CCxS = 01 (input capture on TIx) with ICxF = 0011 (8 samples at the timer clock: 33 ns
    /// at 240 MHz, well below the 1.33 µs answer bit), for an odd channel.
    pub const CCMR_INPUT_FILTERED: u32 = 0b01 | (0b0011 << 4);
    /// Bits between two channels' fields in CCER (channel c, 0-based, at 4c).
    pub const CCER_CHANNEL_SHIFT: u32 = 4;
    /// CCER bits of channel 1: enable, polarity (output: active low; input: with CCxNP both
    /// edges), and CCxNP.
    pub const CCER_E: u32 = 1 << 0;
    pub const CCER_P: u32 = 1 << 1;
    pub const CCER_NP: u32 = 1 << 3;
    /// DCR.DBL (burst length − 1) starts at this bit; DCR.DBA (the first register of the burst,
    /// in words from CR1) at bit 0.
    pub const DCR_DBL_SHIFT: u32 = 8;

    /// Channel `channel`'s (1..=4) capture/compare register.
    #[inline(always)]
    pub const fn ccr(channel: u32) -> u32 {
        CCR1 + 4 * (channel - 1)
    }

    /// (CCMR1 or CCMR2, the shift of channel `channel`'s (1..=4) field relative to the odd
    /// channel's: [`CCMR_PWM1_PRELOAD`] and [`CCMR_INPUT_FILTERED`] are shifted by it).
    #[inline(always)]
    pub const fn ccmr_register_and_shift(channel: u32) -> (u32, u32) {
        let c = channel - 1;
        (if c < 2 { CCMR1 } else { CCMR2 }, CCMR_CHANNEL_SHIFT * (c % 2))
    }

    /// The shift of channel `channel`'s (1..=4) CCER bits relative to channel 1's
    /// ([`CCER_E`], [`CCER_P`], [`CCER_NP`]).
    #[inline(always)]
    pub const fn ccer_shift(channel: u32) -> u32 {
        CCER_CHANNEL_SHIFT * (channel - 1)
    }

    /// DIER.CCxDE of channel `channel` (1..=4): its capture/compare DMA request.
    #[inline(always)]
    pub const fn dier_ccde(channel: u32) -> u32 {
        DIER_CC1DE << (channel - 1)
    }
}

/// SPI registers and bits (RM0433 §50.11, the H7's SPI with FIFO).
pub mod spi {
    pub const CR1: u32 = 0x00;
    pub const CR2: u32 = 0x04;
    pub const CFG1: u32 = 0x08;
    pub const CFG2: u32 = 0x0C;
    pub const SR: u32 = 0x14;
    pub const IFCR: u32 = 0x18;
    pub const TXDR: u32 = 0x20;
    pub const RXDR: u32 = 0x30;
    pub const CR1_SPE: u32 = 1 << 0;
    pub const CR1_CSTART: u32 = 1 << 9;
    pub const CR1_SSI: u32 = 1 << 12;
    /// 8-bit frames (DSIZE = bits − 1), FIFO threshold one frame (FTHLV = 0).
    pub const CFG1_DSIZE_8: u32 = 7;
    pub const CFG1_RXDMAEN: u32 = 1 << 14;
    pub const CFG1_TXDMAEN: u32 = 1 << 15;
    /// CFG1.MBR, the baud-rate divider 2^(MBR+1), starts at this bit.
    pub const CFG1_MBR_SHIFT: u32 = 28;
    /// Master, software slave management, mode 3 (CPOL = CPHA = 1), pins kept driven while the
    /// SPI is disabled (AFCNTR, so SCK idles high between transfers).
    pub const CFG2_MASTER_MODE3: u32 = (1 << 22) | (1 << 24) | (1 << 25) | (1 << 26) | (1 << 31);
    pub const SR_RXP: u32 = 1 << 0;
    pub const SR_TXP: u32 = 1 << 1;
    pub const SR_EOT: u32 = 1 << 3;
    /// Every clearable flag.
    pub const IFCR_ALL: u32 = 0xFF8;
}

/// I²C registers and bits (RM0433 §47.7).
pub mod i2c {
    pub const CR1: u32 = 0x00;
    pub const CR2: u32 = 0x04;
    pub const TIMINGR: u32 = 0x10;
    pub const ISR: u32 = 0x18;
    pub const ICR: u32 = 0x1C;
    pub const RXDR: u32 = 0x24;
    pub const TXDR: u32 = 0x28;
    pub const CR1_PE: u32 = 1 << 0;
    /// CR2: SADD (bits 7:1 hold a 7-bit address), RD_WRN, START, STOP, NBYTES (bits 23:16),
    /// AUTOEND.
    pub const CR2_SADD_SHIFT: u32 = 1;
    pub const CR2_RD_WRN: u32 = 1 << 10;
    pub const CR2_START: u32 = 1 << 13;
    pub const CR2_STOP: u32 = 1 << 14;
    pub const CR2_NBYTES_SHIFT: u32 = 16;
    pub const CR2_AUTOEND: u32 = 1 << 25;
    pub const ISR_TXIS: u32 = 1 << 1;
    pub const ISR_RXNE: u32 = 1 << 2;
    pub const ISR_NACKF: u32 = 1 << 4;
    pub const ISR_STOPF: u32 = 1 << 5;
    pub const ISR_TC: u32 = 1 << 6;
    pub const ISR_BERR: u32 = 1 << 8;
    pub const ISR_ARLO: u32 = 1 << 9;
    pub const ISR_BUSY: u32 = 1 << 15;
    /// ICR: NACKCF, STOPCF, BERRCF, ARLOCF (the flags the transfers end on).
    pub const ICR_ALL: u32 = (1 << 4) | (1 << 5) | (1 << 8) | (1 << 9);
}

/// An I²C peripheral's facts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct I2cInfo {
    pub base: u32,
    pub enable: RccEnable,
}

/// I2C1 and I2C2 (RM0433 §2.3; RCC_APB1LENR.I2C1EN bit 21, I2C2EN bit 22). Their kernel clock is
/// rcc_pclk1 by default (RCC_D2CCIP2R.I2C123SEL = 0).
pub const fn i2c(i2c: I2c) -> I2cInfo {
    match i2c {
        I2c::I2c1 => I2cInfo {
            base: 0x4000_5400,
            enable: RccEnable { register: RccRegister::Apb1L, bit: 21 },
        },
        I2c::I2c2 => I2cInfo {
            base: 0x4000_5800,
            enable: RccEnable { register: RccRegister::Apb1L, bit: 22 },
        },
    }
}

/// USART registers and bits (RM0433 §48.7).
pub mod usart {
    pub const CR1: u32 = 0x00;
    pub const CR3: u32 = 0x08;
    pub const BRR: u32 = 0x0C;
    pub const ICR: u32 = 0x20;
    pub const RDR: u32 = 0x24;
    pub const ISR: u32 = 0x1C;
    pub const TDR: u32 = 0x28;
    /// ISR's TXE, which reads "transmit FIFO not full" (TXFNF) with the FIFO enabled.
    pub const ISR_TXFNF: u32 = 1 << 7;
    /// The 16-byte transmit and receive FIFOs (RM0433 §48.5.4).
    pub const CR1_FIFOEN: u32 = 1 << 29;
    pub const CR1_UE: u32 = 1 << 0;
    pub const CR1_RE: u32 = 1 << 2;
    pub const CR1_TE: u32 = 1 << 3;
    /// RXFNEIE: an interrupt while the receive FIFO holds a byte (RXNEIE without the FIFO).
    pub const CR1_RXFNEIE: u32 = 1 << 5;
    /// ISR's RXNE, which reads "receive FIFO not empty" (RXFNE) with the FIFO enabled.
    pub const ISR_RXFNE: u32 = 1 << 5;
    pub const CR3_DMAR: u32 = 1 << 6;
    /// Overrun does not stop reception (a lost byte is a CRC error for the parser).
    pub const CR3_OVRDIS: u32 = 1 << 12;
    /// Every flag ICR clears (PE, FE, NE, ORE, IDLE, TXFE, TC, TCBGT, LBD, CTS, RTO, EOB, UDR,
    /// CM, WUF); the reserved bits are written 0.
    pub const ICR_ALL: u32 = 0x0012_3BFF;
}

/// ADC registers and bits (RM0433 §25.6), for single conversions of one channel at a time.
pub mod adc {
    pub const ISR: u32 = 0x00;
    pub const CR: u32 = 0x08;
    pub const CFGR: u32 = 0x0C;
    pub const SMPR1: u32 = 0x14;
    pub const SMPR2: u32 = 0x18;
    pub const PCSEL: u32 = 0x1C;
    pub const SQR1: u32 = 0x30;
    pub const DR: u32 = 0x40;
    /// The ADC is ready for conversions (written 1 to clear).
    pub const ISR_ADRDY: u32 = 1 << 0;
    /// A conversion ended (cleared by reading DR).
    pub const ISR_EOC: u32 = 1 << 2;
    pub const CR_ADEN: u32 = 1 << 0;
    pub const CR_ADSTART: u32 = 1 << 2;
    /// Calibrate the linearity too (with ADCAL).
    pub const CR_ADCALLIN: u32 = 1 << 16;
    /// The ADC's voltage regulator on (10 µs to start: TADCVREG_STUP, DS12110 Table 229).
    pub const CR_ADVREGEN: u32 = 1 << 28;
    /// Deep power-down (set at reset).
    pub const CR_DEEPPWD: u32 = 1 << 29;
    /// Start a calibration; reads 1 until it ends.
    pub const CR_ADCAL: u32 = 1 << 31;
    /// CFGR.RES, the resolution (3 bits; 0b000 = 16 bits on both silicon revisions).
    pub const CFGR_RES: u32 = 0b111 << 2;
    /// SMPRx hold a 3-bit sample time per channel: channel n in SMPR1 (n < 10) or SMPR2 at bit
    /// 3·(n mod 10).
    pub const SMP_BITS: u32 = 3;
    /// Sample time 810.5 ADC clock cycles, the longest: a resistor divider's source impedance
    /// (kΩ) charges the sampling capacitor fully.
    pub const SMP_810_CYCLES: u32 = 0b111;
    /// SQR1.SQ1, the first conversion's channel (5 bits); SQR1.L = 0: one conversion.
    pub const SQR1_SQ1_SHIFT: u32 = 6;
    /// ADCx_COMMON registers: CCR, the clock.
    pub const CCR: u32 = 0x08;
    /// CCR.CKMODE (2 bits; 0b00: the asynchronous kernel clock) and CCR.PRESC (4 bits).
    pub const CCR_CKMODE: u32 = 0b11 << 16;
    pub const CCR_PRESC: u32 = 0b1111 << 18;
    /// PRESC = 0b0011: the kernel clock divided by 6.
    pub const CCR_PRESC_DIV6: u32 = 0b0011 << 18;

    /// The sample-time register of channel `channel` and the shift of its field.
    pub const fn sample_time_register_and_shift(channel: u32) -> (u32, u32) {
        let register = if channel < 10 { SMPR1 } else { SMPR2 };
        (register, SMP_BITS * (channel % 10))
    }
}

/// (pin, ADC1 input channel) from DS12110 Table 9 ("ADC1_INPn" in the additional functions),
/// single-ended, for the pins of ports A–E that have one (INP0/1 are the PA0_C/PA1_C pads).
const ADC1_INPUTS: &[(Pin, u8)] = {
    use Port::*;
    &[
        (pin(A, 6), 3),
        (pin(C, 4), 4),
        (pin(B, 1), 5),
        (pin(A, 7), 7),
        (pin(C, 5), 8),
        (pin(B, 0), 9),
        (pin(C, 0), 10),
        (pin(C, 1), 11),
        (pin(C, 2), 12),
        (pin(C, 3), 13),
        (pin(A, 2), 14),
        (pin(A, 3), 15),
        (pin(A, 0), 16),
        (pin(A, 1), 17),
        (pin(A, 4), 18),
        (pin(A, 5), 19),
    ]
};

/// ADC1's input channel of `input`, if it has one.
pub fn adc1_input(input: Pin) -> Option<u8> {
    ADC1_INPUTS.iter().find(|(p, _)| *p == input).map(|(_, channel)| *channel)
}

/// A timer's facts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TimerInfo {
    pub base: u32,
    pub enable: RccEnable,
    /// DMAMUX1 request of the update event (TIMx_UP).
    pub update_request: u8,
    /// DMAMUX1 requests of the capture/compare channels 1–4 (TIMx_CHn; 0: the channel has none,
    /// as TIM4 CH4). RM0433 table "DMAMUX1: assignment of multiplexer inputs to resources".
    pub channel_requests: [u8; 4],
    /// Counter width, bits.
    pub bits: u8,
}

/// The timers that can drive DShot (general-purpose TIM2–TIM5 and advanced TIM8; the basic
/// TIM7 has no channels and is not listed).
pub const fn timer(timer: Timer) -> Option<TimerInfo> {
    const fn apb1(bit: u8) -> RccEnable {
        RccEnable { register: RccRegister::Apb1L, bit }
    }
    Some(match timer {
        Timer::Tim2 => {
            let channel_requests = [18, 19, 20, 21];
            TimerInfo {
                base: 0x4000_0000,
                enable: apb1(0),
                update_request: 22,
                channel_requests,
                bits: 32,
            }
        }
        Timer::Tim3 => {
            let channel_requests = [23, 24, 25, 26];
            TimerInfo {
                base: 0x4000_0400,
                enable: apb1(1),
                update_request: 27,
                channel_requests,
                bits: 16,
            }
        }
        Timer::Tim4 => {
            let channel_requests = [29, 30, 31, 0];
            TimerInfo {
                base: 0x4000_0800,
                enable: apb1(2),
                update_request: 32,
                channel_requests,
                bits: 16,
            }
        }
        Timer::Tim5 => {
            let channel_requests = [55, 56, 57, 58];
            TimerInfo {
                base: 0x4000_0C00,
                enable: apb1(3),
                update_request: 59,
                channel_requests,
                bits: 32,
            }
        }
        Timer::Tim8 => TimerInfo {
            base: 0x4001_0400,
            enable: RccEnable { register: RccRegister::Apb2, bit: 1 },
            update_request: 51,
            channel_requests: [47, 48, 49, 50],
            bits: 16,
        },
        Timer::Tim7 => return None,
    })
}

/// An SPI's facts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SpiInfo {
    pub base: u32,
    pub enable: RccEnable,
    pub rx_request: u8,
    pub tx_request: u8,
}

pub const fn spi(spi: Spi) -> SpiInfo {
    const fn apb2(bit: u8) -> RccEnable {
        RccEnable { register: RccRegister::Apb2, bit }
    }
    match spi {
        Spi::Spi1 => {
            SpiInfo { base: 0x4001_3000, enable: apb2(12), rx_request: 37, tx_request: 38 }
        }
        Spi::Spi4 => {
            SpiInfo { base: 0x4001_3400, enable: apb2(13), rx_request: 83, tx_request: 84 }
        }
    }
}

/// A UART's facts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UartInfo {
    pub base: u32,
    pub enable: RccEnable,
    pub rx_request: u8,
}

pub const fn uart(uart: Uart) -> UartInfo {
    const fn apb2(bit: u8) -> RccEnable {
        RccEnable { register: RccRegister::Apb2, bit }
    }
    match uart {
        Uart::Usart1 => UartInfo { base: 0x4001_1000, enable: apb2(4), rx_request: 41 },
        Uart::Usart2 => UartInfo {
            base: 0x4000_4400,
            enable: RccEnable { register: RccRegister::Apb1L, bit: 17 },
            rx_request: 43,
        },
        Uart::Usart6 => UartInfo { base: 0x4001_1400, enable: apb2(5), rx_request: 71 },
    }
}

/// DMA controllers' clock enables (RCC_AHB1ENR bits 0 and 1).
pub const fn dma_enable(controller: u8) -> RccEnable {
    RccEnable { register: RccRegister::Ahb1, bit: if controller == 2 { 1 } else { 0 } }
}

/// A GPIO port's clock enable (RCC_AHB4ENR bit = port index).
pub const fn gpio_enable(port: Port) -> RccEnable {
    RccEnable { register: RccRegister::Ahb4, bit: port.index() }
}

/// (pin, function, AF number) from DS12110 Table 9 (only the pins and functions H743 flight
/// controllers commonly use; extend when porting).
const ALTERNATE_FUNCTIONS: &[(Pin, Function, u8)] = {
    use Function::*;
    use Port::*;
    &[
        // TIM5 CH1–CH4 on PA0–PA3 (AF2).
        (pin(A, 0), TimerChannel(Timer::Tim5, 1), 2),
        (pin(A, 1), TimerChannel(Timer::Tim5, 2), 2),
        (pin(A, 2), TimerChannel(Timer::Tim5, 3), 2),
        (pin(A, 3), TimerChannel(Timer::Tim5, 4), 2),
        // TIM2 CH1–CH4 on PA0–PA3 (AF1).
        (pin(A, 0), TimerChannel(Timer::Tim2, 1), 1),
        (pin(A, 1), TimerChannel(Timer::Tim2, 2), 1),
        (pin(A, 2), TimerChannel(Timer::Tim2, 3), 1),
        (pin(A, 3), TimerChannel(Timer::Tim2, 4), 1),
        // TIM3 CH3/CH4 on PB0/PB1 (AF2); TIM3 CH1/CH2 on PB4/PB5 (AF2).
        (pin(B, 0), TimerChannel(Timer::Tim3, 3), 2),
        (pin(B, 1), TimerChannel(Timer::Tim3, 4), 2),
        (pin(B, 4), TimerChannel(Timer::Tim3, 1), 2),
        (pin(B, 5), TimerChannel(Timer::Tim3, 2), 2),
        // TIM4 CH1–CH4 on PD12–PD15 (AF2); CH1/CH2 on PB6/PB7 (AF2).
        (pin(D, 12), TimerChannel(Timer::Tim4, 1), 2),
        (pin(D, 13), TimerChannel(Timer::Tim4, 2), 2),
        (pin(D, 14), TimerChannel(Timer::Tim4, 3), 2),
        (pin(D, 15), TimerChannel(Timer::Tim4, 4), 2),
        (pin(B, 6), TimerChannel(Timer::Tim4, 1), 2),
        (pin(B, 7), TimerChannel(Timer::Tim4, 2), 2),
        // TIM8 CH1–CH4 on PC6–PC9 (AF3).
        (pin(C, 6), TimerChannel(Timer::Tim8, 1), 3),
        (pin(C, 7), TimerChannel(Timer::Tim8, 2), 3),
        (pin(C, 8), TimerChannel(Timer::Tim8, 3), 3),
        (pin(C, 9), TimerChannel(Timer::Tim8, 4), 3),
        // SPI1 (AF5): SCK PA5, MISO PA6, MOSI PA7 or PD7.
        (pin(A, 5), SpiSck(Spi::Spi1), 5),
        (pin(A, 6), SpiMiso(Spi::Spi1), 5),
        (pin(A, 7), SpiMosi(Spi::Spi1), 5),
        (pin(D, 7), SpiMosi(Spi::Spi1), 5),
        // SPI4 (AF5): SCK PE12, MISO PE13, MOSI PE14.
        (pin(E, 12), SpiSck(Spi::Spi4), 5),
        (pin(E, 13), SpiMiso(Spi::Spi4), 5),
        (pin(E, 14), SpiMosi(Spi::Spi4), 5),
        // USART6 (AF7): TX PC6, RX PC7. USART1 (AF7): TX PA9, RX PA10.
        (pin(C, 6), UartTx(Uart::Usart6), 7),
        (pin(C, 7), UartRx(Uart::Usart6), 7),
        (pin(A, 9), UartTx(Uart::Usart1), 7),
        (pin(A, 10), UartRx(Uart::Usart1), 7),
        (pin(D, 5), UartTx(Uart::Usart2), 7),
        (pin(D, 6), UartRx(Uart::Usart2), 7),
        // USB OTG2 full speed (the H743's "OTG_FS" pins, AF10): DM PA11, DP PA12.
        (pin(A, 11), UsbDm, 10),
        (pin(A, 12), UsbDp, 10),
        // SDMMC1 (AF12): D0–D3 PC8–PC11, CK PC12, CMD PD2.
        (pin(C, 8), SdmmcData(0), 12),
        (pin(C, 9), SdmmcData(1), 12),
        (pin(C, 10), SdmmcData(2), 12),
        (pin(C, 11), SdmmcData(3), 12),
        (pin(C, 12), SdmmcCk, 12),
        (pin(D, 2), SdmmcCmd, 12),
        // I2C1 (AF4): SCL PB6 or PB8, SDA PB7 or PB9. I2C2 (AF4): SCL PB10, SDA PB11.
        (pin(B, 6), I2cScl(I2c::I2c1), 4),
        (pin(B, 7), I2cSda(I2c::I2c1), 4),
        (pin(B, 8), I2cScl(I2c::I2c1), 4),
        (pin(B, 9), I2cSda(I2c::I2c1), 4),
        (pin(B, 10), I2cScl(I2c::I2c2), 4),
        (pin(B, 11), I2cSda(I2c::I2c2), 4),
    ]
};

/// The AF number connecting `function` to `pin`, if the chip has that connection (in the table).
pub fn alternate_function(pin: Pin, function: Function) -> Option<u8> {
    ALTERNATE_FUNCTIONS.iter().find(|(p, f, _)| *p == pin && *f == function).map(|(_, _, af)| *af)
}
