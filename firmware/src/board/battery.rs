//! The flight battery's voltage and current through ADC1: one conversion at a time, started
//! by one control tick and read by the next, so the tick never waits for the ADC.
//!
//! The ADC runs from per_ck (HSI, 64 MHz) divided by 6: 10.7 MHz on silicon revision Y, 5.3 MHz
//! on revision V (which halves the clock again). Both are under the 6.25 MHz and 20 MHz the
//! two revisions allow without BOOST (RM0433 §25.4.3). Each conversion samples for 810.5 ADC
//! cycles, so the divider's kΩ source charges the sampling capacitor fully. At most 160 µs
//! pass before the result, inside one 500 µs control period. The two channels take turns, so
//! a reading comes every second tick (1 kHz); [`BatteryMonitor`](crate::app::battery) weighs
//! it by time.
//!
//! Start-up (`new`, called from `init`) follows RM0433 §25.4.6–§25.4.9: leave deep power-down,
//! start the regulator and wait 10 µs; calibrate offset and linearity; enable. A step that
//! does not finish within its timeout leaves the sensor off. The board then reports no
//! battery; it never hangs in `init`.
//!
//! Register numbers come from `targets::h743`, which `tests/registers_match_pac.rs` checks
//! against the PAC. We use them rather than stm32h7xx-hal's `adc` module because the HAL
//! types each input pin (`PC0<Analog>`), while the board description names its pins as
//! data. The HAL's start-up, with its clock and resolution checks, also costs flash that the
//! board does not have to spare.

use super::chip::{self, modify, read, write};
use crate::app::hal::{BatteryReading, BatterySensor};
use crate::targets::h743::{self, adc, rcc};
use crate::targets::BatterySensing;

/// Full scale of a 16-bit conversion.
const FULL_SCALE: u32 = 0xFFFF;
/// The regulator's start-up time, µs (TADCVREG_STUP, DS12110: 10 µs).
const REGULATOR_STARTUP_US: u32 = 10;
/// Longest wait for the calibration or the ready flag, µs. Calibration takes about 16,000
/// ADC clock cycles (3 ms at 5.3 MHz); ten times that is a broken ADC.
const STEP_TIMEOUT_US: u32 = 30_000;

/// The battery's ADC channels and the conversion in flight.
pub struct BoardBattery {
    sensing: BatterySensing,
    /// ADC1 input channels: [voltage, current].
    channels: [u8; 2],
    /// The channel converting now (index into `channels`), or `None`: the sensor is off.
    converting: Option<usize>,
    /// The voltage conversion's result, waiting for the current's.
    voltage_raw: u32,
}

impl BoardBattery {
    /// Start ADC1 on `sensing`'s pins and begin the first conversion. `cycles_per_us`: the core
    /// clock, for the start-up waits.
    pub fn new(sensing: BatterySensing, cycles_per_us: u32) -> Self {
        let off = Self { sensing, channels: [0; 2], converting: None, voltage_raw: 0 };
        let (Some(voltage), Some(current)) =
            (h743::adc1_input(sensing.voltage_pin), h743::adc1_input(sensing.current_pin))
        else {
            // `BoardDescription::check` refuses such a board; nothing to start.
            return off;
        };
        chip::analog(sensing.voltage_pin);
        chip::analog(sensing.current_pin);
        chip::enable_clock(h743::ADC12_ENABLE);
        let base = h743::ADC1_BASE;
        // SAFETY: ADC1, its common clock register and the ADC kernel clock selection belong to
        // this driver alone; `init` runs it once, before any task.
        let started = unsafe {
            modify(h743::RCC_BASE + rcc::D3CCIPR, rcc::D3CCIPR_ADCSEL, rcc::D3CCIPR_ADCSEL_PER_CK);
            modify(
                h743::ADC12_COMMON_BASE + adc::CCR,
                adc::CCR_CKMODE | adc::CCR_PRESC,
                adc::CCR_PRESC_DIV6,
            );
            // Out of deep power-down, regulator on.
            write(base + adc::CR, adc::CR_ADVREGEN);
            cortex_m::asm::delay(REGULATOR_STARTUP_US * cycles_per_us);
            // Calibrate offset and linearity, single-ended.
            write(base + adc::CR, adc::CR_ADVREGEN | adc::CR_ADCALLIN | adc::CR_ADCAL);
            let calibrated = wait(cycles_per_us, || read(base + adc::CR) & adc::CR_ADCAL == 0);
            // Enable and wait until ready.
            write(base + adc::ISR, adc::ISR_ADRDY);
            modify(base + adc::CR, 0, adc::CR_ADEN);
            let ready = wait(cycles_per_us, || read(base + adc::ISR) & adc::ISR_ADRDY != 0);
            if calibrated && ready {
                // 16 bits, one conversion a start; the longest sample time on both channels;
                // both preselected (RM0433 §25.4.12).
                modify(base + adc::CFGR, adc::CFGR_RES, 0);
                for channel in [voltage, current] {
                    let (register, shift) = adc::sample_time_register_and_shift(channel.into());
                    let mask = ((1 << adc::SMP_BITS) - 1) << shift;
                    modify(base + register, mask, adc::SMP_810_CYCLES << shift);
                    modify(base + adc::PCSEL, 0, 1 << channel);
                }
            }
            calibrated && ready
        };
        if !started {
            return off;
        }
        let mut battery = Self { channels: [voltage, current], converting: Some(0), ..off };
        battery.start(0);
        battery
    }

    /// Whether the ADC started (a board without it reports no battery).
    pub fn is_running(&self) -> bool {
        self.converting.is_some()
    }

    /// Start converting `channels[index]`.
    fn start(&mut self, index: usize) {
        self.converting = Some(index);
        let base = h743::ADC1_BASE;
        // SAFETY: the driver's own ADC; no conversion is running (the previous one ended).
        unsafe {
            write(base + adc::SQR1, u32::from(self.channels[index]) << adc::SQR1_SQ1_SHIFT);
            modify(base + adc::CR, 0, adc::CR_ADSTART);
        }
    }
}

impl BatterySensor for BoardBattery {
    /// Every second call at most: the current's conversion completes a reading.
    fn read(&mut self) -> Option<BatteryReading> {
        let index = self.converting?;
        let base = h743::ADC1_BASE;
        // SAFETY: the driver's own ADC; ISR is read-only here, DR read clears EOC.
        let raw = unsafe {
            if read(base + adc::ISR) & adc::ISR_EOC == 0 {
                return None;
            }
            read(base + adc::DR) & FULL_SCALE
        };
        let next = 1 - index;
        self.start(next);
        if index == 0 {
            self.voltage_raw = raw;
            None
        } else {
            Some(self.sensing.reading(self.voltage_raw, raw, FULL_SCALE))
        }
    }
}

/// Poll `done` until it holds or [`STEP_TIMEOUT_US`] passes; whether it held.
fn wait(cycles_per_us: u32, mut done: impl FnMut() -> bool) -> bool {
    const POLL_US: u32 = 10;
    for _ in 0..STEP_TIMEOUT_US / POLL_US {
        if done() {
            return true;
        }
        cortex_m::asm::delay(POLL_US * cycles_per_us);
    }
    done()
}
