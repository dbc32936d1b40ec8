//! Facts about the STM32H743 itself (not a board): the peripherals a flight-controller board
//! wires, their register addresses, clock-enable bits and DMAMUX request numbers, and the
//! alternate functions of the pins such boards use.
//!
//! Sources: RM0433 rev 8 (§2.3 memory map, §8.7 RCC registers, Table 121 "DMAMUX1: assignment
//! of multiplexer inputs to resources") and the datasheet DS12110 (Table 9 "Port A–E alternate
//! functions"). Addresses and bit positions were checked against the `stm32h7` 0.15 PAC
//! (`stm32h743v`). The board layer writes registers at these addresses; a wrong number here
//! shows up in the host test of the board description only where the table is incomplete, so
//! every entry carries its source.

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
    Usart6,
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
/// GPIOA; port n is at `GPIOA_BASE + 0x400 · n`.
pub const GPIOA_BASE: u32 = 0x5802_0000;
/// DMA1 (DMA2 is 0x400 above).
pub const DMA1_BASE: u32 = 0x4002_0000;
/// DMA2.
pub const DMA2_BASE: u32 = 0x4002_0400;
/// DMAMUX1.
pub const DMAMUX1_BASE: u32 = 0x4002_0800;

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
        // USB OTG2 full speed (the H743's "OTG_FS" pins, AF10): DM PA11, DP PA12.
        (pin(A, 11), UsbDm, 10),
        (pin(A, 12), UsbDp, 10),
    ]
};

/// The AF number connecting `function` to `pin`, if the chip has that connection (in the table).
pub fn alternate_function(pin: Pin, function: Function) -> Option<u8> {
    ALTERNATE_FUNCTIONS.iter().find(|(p, f, _)| *p == pin && *f == function).map(|(_, _, af)| *af)
}
