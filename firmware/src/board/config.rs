//! Board constants: the assumptions this firmware makes about the PCB and the clock tree, each
//! with its unit and where it comes from (in the manner of stabilizer's `design_parameters.rs`).
//!
//! One `const` [`BOARD`] collects the choices that differ between H743 boards, so porting to a
//! different flight controller is an edit here and nowhere else.

/// What differs between STM32H743 boards.
#[derive(Clone, Copy, Debug)]
pub struct BoardConfig {
    /// Human-readable board name, reported in the protocol handshake.
    pub name: &'static str,
    /// Frequency of the external high-speed clock (HSE), Hz.
    ///
    /// Assumption: an 8 MHz crystal, as fitted on most H743 flight controllers (Matek H743,
    /// Holybro Kakute H7, …). A different crystal only needs this value; the PLL is solved
    /// by stm32h7xx-hal from it. With no HSE fitted, start-up hangs waiting for HSERDY (the
    /// HAL's documented behaviour): a board without a crystal must switch to HSI in `init`.
    pub hse_hz: u32,
    /// `true` when HSE is an external clock *signal* rather than a crystal (the NUCLEO-H743ZI
    /// feeds 8 MHz from the ST-LINK's MCO and needs the oscillator bypassed).
    pub hse_bypass: bool,
}

/// The board this firmware is built for.
pub const BOARD: BoardConfig =
    BoardConfig { name: "STM32H743", hse_hz: 8_000_000, hse_bypass: false };

/// Core clock (sys_ck), Hz.
///
/// 400 MHz at voltage scale 1 (VOS1): the maximum for every H743 silicon revision (revision Y
/// is limited to 400 MHz; 480 MHz needs revision V *and* VOS0, RM0433 rev 8 §6.6.2 and the
/// datasheet DS12110 table 23). Chosen because it is correct on all boards; 480 MHz is a later
/// optimisation worth +20 % of CPU time.
pub const SYS_CK_HZ: u32 = 400_000_000;

/// AHB/AXI clock (hclk), Hz: sys_ck / 2, the maximum the AHB allows (200 MHz, DS12110).
/// USB OTG needs hclk ≥ 30 MHz (RM0433 §57.4.4).
pub const HCLK_HZ: u32 = SYS_CK_HZ / 2;

/// The USB task is pended by the control step every this many control ticks, so the link is
/// serviced at 2 kHz / 2 = 1 kHz (every 1 ms) even when the host sends nothing: the OTG interrupt
/// only fires on bus events, and telemetry must flow without them. The control rate itself is
/// the portable application's (`crate::app::ControlConfig::rate_hz`, 2 kHz).
pub const USB_SERVICE_DIVIDER: u32 = 2;

/// Frequency of the microsecond time base ([`crate::board::time`]), Hz: 1 tick = 1 µs.
pub const TIME_BASE_HZ: u32 = 1_000_000;
