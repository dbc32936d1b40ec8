//! The flight battery: what the pilot's handset and `status` show of it, from the board's
//! voltage and current readings ([`BatterySensor`](super::hal::BatterySensor)).
//!
//! The control tick hands every reading to a [`BatteryMonitor`], which
//! - smooths voltage and current with a first-order low-pass of [`FILTER_TIME_S`];
//! - integrates the current into the charge drawn;
//! - counts the cells once the pack has rested at a voltage for [`SETTLE_S`];
//! - estimates the charge left from the voltage per cell.
//!
//! It weighs each reading by the time since the previous one, so the board's ADC may deliver
//! at any rate.
//!
//! What it assumes of the world:
//! - **The cells are lithium-polymer or lithium-ion, in series.** A charged cell holds at most
//!   [`CELL_MAX_V`] (4.35 V: high-voltage LiPo, the highest in common use). So the settled
//!   voltage divided by it, less [`CELL_COUNT_TOLERANCE`] for the divider's error and rounded
//!   up, is the cell count (Betaflight counts the same way). A 4S pack then reads as 4S from
//!   3.37 to 4.46 V a cell; a pack plugged in nearly empty reads a cell short.
//! - **The pack is at rest when it is connected.** The board powers up on the pack, or on USB
//!   with the pack plugged in later. Below [`NO_PACK_V`] the board runs on USB alone (its
//!   divider reads 0–1 V), and the count starts again when a pack appears.
//! - **Charge left is linear in the voltage per cell**, from [`CELL_EMPTY_V`] (0 %) to
//!   [`CELL_FULL_V`] (100 %). This is rough: a LiPo's curve is flat in its middle. Under load
//!   the sag (current × internal resistance, 0.1–0.5 V a cell on a punchy flight) makes it
//!   read low. That is the safe side for a pilot deciding to land.
//! - **The ADC sees the ESCs' switching ripple and the motors' load steps**, hence the
//!   smoothing: a quarter second, well inside the handset's one-second display cycle and slow
//!   against PWM ripple at tens of kHz.
//!
//! The charge drawn integrates the readings unsmoothed: a low-pass keeps the integral, and
//! the raw current has no lag.

use super::hal::BatteryReading;
use protocol::BatteryStatus;

/// Most a charged lithium cell holds, V (high-voltage LiPo, 4.35 V; standard LiPo and Li-ion
/// charge to 4.20 V).
pub const CELL_MAX_V: f32 = 4.35;
/// Voltage per cell counted as full (100 %), V: a standard LiPo's charge voltage.
pub const CELL_FULL_V: f32 = 4.2;
/// Voltage per cell counted as empty (0 %), V: where a LiPo's discharge curve turns down, and
/// where ArduPilot and Betaflight put their default low-voltage warnings (3.3–3.5 V).
pub const CELL_EMPTY_V: f32 = 3.3;
/// Below this the board runs without a pack (on USB: the divider then reads 0–1 V), V. Less
/// than one empty cell.
pub const NO_PACK_V: f32 = 2.0;
/// Time constant of the voltage and current smoothing, s.
pub const FILTER_TIME_S: f32 = 0.25;
/// How long the voltage must stay above [`NO_PACK_V`] before the cells are counted, s: a pack
/// plugged in bounces on its connector and charges the board's input capacitors within
/// milliseconds; two time constants of the smoothing average the ripple after that.
pub const SETTLE_S: f32 = 2.0 * FILTER_TIME_S;
/// Cells subtracted before the count is rounded up: a divider of 1 % resistors reads up to
/// 2 % high (0.35 V on a charged 4S pack, 0.08 of a cell).
pub const CELL_COUNT_TOLERANCE: f32 = 0.1;

/// Default of the `land_cell_v` parameter, V per cell: [`CELL_EMPTY_V`], where the remaining
/// charge reads 0 % (ArduPilot's and Betaflight's low-voltage warnings sit at 3.3–3.5 V).
pub const DEFAULT_LAND_CELL_V: f32 = CELL_EMPTY_V;

/// How long the smoothed voltage must stay below the landing threshold before a flight lands,
/// s: a punch-out sags a pack by 0.1–0.5 V a cell for as long as it lasts (a second or two),
/// and the pack recovers when the load eases; a pack that stays low for 2 s under a hover's load
/// is empty.
pub const LOW_BATTERY_S: f32 = 2.0;

/// Milliamp-hours in one ampere-second.
const MAH_PER_AS: f64 = 1_000.0 / 3_600.0;

/// The battery as the readings so far describe it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BatteryMonitor {
    /// The smoothed reading and its time, µs; `None` before the first.
    smoothed: Option<(BatteryReading, u64)>,
    /// Readings averaged since the smoothing started (saturates).
    averaged: u32,
    /// Since when the voltage is above [`NO_PACK_V`], µs.
    pack_since_us: Option<u64>,
    /// Cells in series; 0 until counted.
    cells: u8,
    /// Charge drawn since start-up, mAh (f64: a millisecond's charge is 10⁻⁶ of a pack's).
    used_mah: f64,
}

impl BatteryMonitor {
    /// A monitor that has seen no reading.
    pub const fn new() -> Self {
        Self { smoothed: None, averaged: 0, pack_since_us: None, cells: 0, used_mah: 0.0 }
    }

    /// Take `reading`, measured at `now_us` (µs since start-up, monotonic). A non-finite
    /// reading (a broken conversion) is dropped.
    pub fn update(&mut self, now_us: u64, reading: BatteryReading) {
        if !(reading.voltage_v.is_finite() && reading.current_a.is_finite()) {
            return;
        }
        // A pack plugged in or pulled out is a step, not noise: the smoothing starts afresh.
        let pack = reading.voltage_v >= NO_PACK_V;
        let restart = self.smoothed.is_none() || pack != self.pack_since_us.is_some();
        let smoothed = match self.smoothed {
            Some((previous, t_us)) if !restart => {
                let dt_s = now_us.saturating_sub(t_us) as f32 * 1e-6;
                self.used_mah += f64::from(reading.current_a) * f64::from(dt_s) * MAH_PER_AS;
                // The mean of the readings so far until it spans the time constant, so one
                // noisy first reading does not linger: then the low-pass.
                self.averaged = self.averaged.saturating_add(1);
                let alpha = (dt_s / (FILTER_TIME_S + dt_s)).max(1.0 / self.averaged as f32);
                BatteryReading {
                    voltage_v: previous.voltage_v
                        + alpha * (reading.voltage_v - previous.voltage_v),
                    current_a: previous.current_a
                        + alpha * (reading.current_a - previous.current_a),
                }
            }
            _ => {
                self.averaged = 1;
                reading
            }
        };
        self.smoothed = Some((smoothed, now_us));
        if !pack {
            self.pack_since_us = None;
            self.cells = 0;
            return;
        }
        let since_us = *self.pack_since_us.get_or_insert(now_us);
        let settled = now_us.saturating_sub(since_us) as f32 * 1e-6 >= SETTLE_S;
        if self.cells == 0 && settled {
            // Rounded up: the whole cells below, plus one for any part of a cell.
            let cells = flight::math::clamp(
                smoothed.voltage_v / CELL_MAX_V - CELL_COUNT_TOLERANCE,
                0.0,
                254.0,
            );
            let whole = cells as u8;
            self.cells = (whole + u8::from(cells > f32::from(whole))).max(1);
        }
    }

    /// What `status` and the handset show: `None` before the first reading (a board that
    /// measures no battery).
    pub fn status(&self) -> Option<BatteryStatus> {
        let (smoothed, _) = self.smoothed?;
        let remaining_pct = if self.cells == 0 {
            0
        } else {
            let cell_v = smoothed.voltage_v / f32::from(self.cells);
            let fraction = (cell_v - CELL_EMPTY_V) / (CELL_FULL_V - CELL_EMPTY_V);
            (flight::math::clamp(fraction, 0.0, 1.0) * 100.0 + 0.5) as u8
        };
        Some(BatteryStatus {
            voltage_v: smoothed.voltage_v,
            current_a: smoothed.current_a,
            used_mah: self.used_mah as f32,
            cells: self.cells,
            remaining_pct,
        })
    }
}

/// Whether the pack has stayed below a voltage per cell for [`LOW_BATTERY_S`]: the failsafe
/// that lands a flight on an empty battery (`land_cell_v`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LowBattery {
    /// Since when the voltage is below the threshold, µs.
    below_since_us: Option<u64>,
}

impl LowBattery {
    /// Follow `status` at `now_us` against `cell_v` per cell (`None`: never low): whether the
    /// pack has been below it for [`LOW_BATTERY_S`]. A pack whose cells are not counted yet
    /// (or no pack) is never low.
    pub fn update(
        &mut self,
        status: Option<&BatteryStatus>,
        cell_v: Option<f32>,
        now_us: u64,
    ) -> bool {
        let below = match (status, cell_v) {
            (Some(status), Some(cell_v)) if status.cells > 0 => {
                status.voltage_v < cell_v * f32::from(status.cells)
            }
            _ => false,
        };
        if !below {
            self.below_since_us = None;
            return false;
        }
        let since_us = *self.below_since_us.get_or_insert(now_us);
        now_us.saturating_sub(since_us) as f32 * 1e-6 >= LOW_BATTERY_S
    }
}

/// What a [`BatteryStatus`] says of the pack, for whoever shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pack {
    /// Under [`NO_PACK_V`]: the board runs on USB.
    Absent,
    /// Connected, its cells not counted yet ([`SETTLE_S`]).
    Settling,
    /// Connected, this many cells in series.
    Cells(u8),
}

impl Pack {
    /// The pack `status` describes.
    pub fn of(status: &BatteryStatus) -> Self {
        match status.cells {
            _ if status.voltage_v < NO_PACK_V => Self::Absent,
            0 => Self::Settling,
            cells => Self::Cells(cells),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TICK_US: u64 = 1_000;

    /// Feed `seconds` of a constant reading at 1 kHz from `start_us`; returns the end time.
    fn feed(
        monitor: &mut BatteryMonitor,
        start_us: u64,
        seconds: f32,
        voltage_v: f32,
        current_a: f32,
    ) -> u64 {
        let ticks = (seconds * 1e6) as u64 / TICK_US;
        for i in 0..ticks {
            monitor.update(start_us + i * TICK_US, BatteryReading { voltage_v, current_a });
        }
        start_us + ticks * TICK_US
    }

    #[test]
    fn no_reading_means_no_battery() {
        assert_eq!(BatteryMonitor::new().status(), None);
    }

    #[test]
    fn cells_are_counted_once_the_pack_has_settled() {
        for (cells, cell_v) in [(1u8, 4.2f32), (3, 3.7), (4, 4.35), (4, 3.4), (6, 3.9), (8, 4.2)] {
            let mut monitor = BatteryMonitor::new();
            let v = f32::from(cells) * cell_v;
            feed(&mut monitor, 0, SETTLE_S * 0.5, v, 0.5);
            assert_eq!(monitor.status().unwrap().cells, 0, "{cells}S not counted before settling");
            feed(&mut monitor, 300_000, SETTLE_S, v, 0.5);
            assert_eq!(monitor.status().unwrap().cells, cells, "{cells}S at {cell_v} V a cell");
        }
    }

    #[test]
    fn a_pack_plugged_after_usb_is_counted_from_its_own_voltage() {
        let mut monitor = BatteryMonitor::new();
        let t = feed(&mut monitor, 0, 1.0, 0.4, 0.0);
        assert_eq!(monitor.status().unwrap().cells, 0, "USB alone: no pack");
        assert_eq!(monitor.status().unwrap().remaining_pct, 0);
        // The smoothed voltage rises from 0.4 V while the count waits for it to settle.
        let t = feed(&mut monitor, t, 1.0, 16.8, 0.3);
        let status = monitor.status().unwrap();
        assert_eq!(status.cells, 4);
        assert!((status.voltage_v - 16.8).abs() < 0.05, "{} V", status.voltage_v);
        assert_eq!(status.remaining_pct, 100);
        // Unplugged: counted again when the next pack (3S) arrives.
        let t = feed(&mut monitor, t, 0.5, 0.3, 0.0);
        assert_eq!(monitor.status().unwrap().cells, 0);
        feed(&mut monitor, t, 2.0, 11.4, 0.3);
        assert_eq!(monitor.status().unwrap().cells, 3);
    }

    #[test]
    fn charge_drawn_is_the_integral_of_the_current_at_any_reading_rate() {
        // 10 A for 36 s is 100 mAh, whether readings come at 1 kHz or irregularly at ~50 Hz.
        let mut fast = BatteryMonitor::new();
        feed(&mut fast, 0, 36.0 + 0.001, 16.0, 10.0);
        let used = fast.status().unwrap().used_mah;
        assert!((used - 100.0).abs() < 0.01, "{used} mAh at 1 kHz");
        let mut slow = BatteryMonitor::new();
        let mut t_us = 0;
        let mut gaps = [13_000u64, 27_000, 20_000, 5_000].iter().cycle();
        while t_us <= 36_000_000 {
            slow.update(t_us, BatteryReading { voltage_v: 16.0, current_a: 10.0 });
            t_us += gaps.next().unwrap();
        }
        let used = slow.status().unwrap().used_mah;
        assert!((used - 100.0).abs() < 0.3, "{used} mAh at irregular ~50 Hz");
    }

    #[test]
    fn smoothing_follows_a_load_step_within_its_time_constant() {
        let mut monitor = BatteryMonitor::new();
        let t = feed(&mut monitor, 0, 2.0, 16.0, 1.0);
        // Throttle up: 30 A; after one time constant the smoothed current is 63 % of the way.
        feed(&mut monitor, t, FILTER_TIME_S, 15.0, 30.0);
        let current = monitor.status().unwrap().current_a;
        let fraction = (current - 1.0) / 29.0;
        assert!((fraction - 0.632).abs() < 0.01, "{fraction} of the step after one time constant");
    }

    #[test]
    fn remaining_charge_runs_from_empty_to_full_cell_voltage() {
        // One cell: counted as one at any voltage (a 4S pack below 3.37 V a cell reads as 3S).
        for (cell_v, expected) in [(3.0f32, 0u8), (3.3, 0), (3.75, 50), (4.2, 100), (4.35, 100)] {
            let mut monitor = BatteryMonitor::new();
            feed(&mut monitor, 0, 1.0, cell_v, 0.0);
            let status = monitor.status().unwrap();
            assert_eq!(status.cells, 1, "{cell_v} V a cell");
            assert_eq!(status.remaining_pct, expected, "{cell_v} V a cell");
        }
    }

    #[test]
    fn a_pack_lands_the_craft_only_after_staying_below_its_threshold() {
        let status = |voltage_v: f32, cells: u8| BatteryStatus {
            voltage_v,
            current_a: 20.0,
            used_mah: 0.0,
            cells,
            remaining_pct: 0,
        };
        let mut low = LowBattery::default();
        let threshold = Some(3.3);
        // A 4S pack sagging to 3.2 V a cell in a punch-out for 1.5 s: not low.
        for ms in 0..1500u64 {
            assert!(!low.update(Some(&status(12.8, 4)), threshold, ms * 1000));
        }
        assert!(!low.update(Some(&status(14.8, 4)), threshold, 1_500_000));
        // Below for LOW_BATTERY_S: low, not a moment before.
        let start = 2_000_000;
        assert!(!low.update(Some(&status(13.1, 4)), threshold, start));
        assert!(!low.update(Some(&status(13.1, 4)), threshold, start + 1_999_000));
        assert!(low.update(Some(&status(13.1, 4)), threshold, start + 2_000_000));
        // No threshold, no count of cells yet, or no battery at all: never low.
        let mut never = LowBattery::default();
        for t in [0, 5_000_000] {
            assert!(!never.update(Some(&status(13.1, 4)), None, t));
            assert!(!never.update(Some(&status(1.0, 0)), threshold, t));
            assert!(!never.update(None, threshold, t));
        }
    }

    #[test]
    fn a_broken_conversion_changes_nothing() {
        let mut monitor = BatteryMonitor::new();
        feed(&mut monitor, 0, 1.0, 16.0, 5.0);
        let before = monitor;
        monitor.update(1_000_000, BatteryReading { voltage_v: f32::NAN, current_a: 5.0 });
        monitor.update(1_001_000, BatteryReading { voltage_v: 16.0, current_a: f32::INFINITY });
        assert_eq!(monitor, before);
    }
}
