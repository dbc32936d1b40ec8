//! The flight battery the simulated board measures: lithium-polymer cells in series. The pack's
//! voltage sags with the current the motors draw, and the board's divider and current sensor
//! read it with noise.
//!
//! The model, each part with its source:
//! - **Open-circuit voltage per cell** against the charge left: a LiPo's resting voltage,
//!   piecewise linear through [`OPEN_CIRCUIT_CELL_V`]. Those are the figures of the common LiPo
//!   charts: 4.20 V full, 3.87 V at half, 3.27 V empty.
//! - **Terminal voltage** `V = n·V_oc − I·n·R_cell`. The internal resistance of one cell,
//!   [`PackParams::cell_resistance_ohm`], is a few mΩ for a 1.5 Ah pack of 75–100 C.
//! - **Current** `I = I_avionics + P_shaft / (η·V)`. The shaft power `P_shaft = Σ k_m ω³` is
//!   the rotors' drag torque times their speed, the power the motors deliver. η is the motors'
//!   and ESCs' efficiency, 0.7–0.85 for BLDC drives at mid throttle. The two equations meet in
//!   a quadratic in `V` ([`SimBattery::step`]).
//! - **The board's reading**: [`PackParams::voltage_noise_v`] and
//!   [`PackParams::current_noise_a`] of Gaussian noise, for the ADC's quantisation and the
//!   ESCs' switching ripple.
//!
//! The thrust the motors lose as a pack sags is the world's `battery_sag`
//! ([`crate::board::WorldEffects`]), set apart from this model. The randomised world varies
//! the thrust; this model gives the board something true to measure.

use firmware::app::hal::BatteryReading;

/// A LiPo cell's resting voltage, V, at 0 %, 10 %, …, 100 % of its charge.
pub const OPEN_CIRCUIT_CELL_V: [f64; 11] =
    [3.27, 3.69, 3.73, 3.77, 3.79, 3.82, 3.87, 3.93, 3.99, 4.06, 4.20];

/// Milliamp-hours in one ampere-second.
const MAH_PER_AS: f64 = 1_000.0 / 3_600.0;

/// The simulated pack and its sensors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PackParams {
    /// Cells in series.
    pub cells: u8,
    /// Capacity, mAh.
    pub capacity_mah: f64,
    /// Charge at the start, fraction of the capacity, in [0, 1].
    pub initial_charge: f64,
    /// Internal resistance of one cell, Ω.
    pub cell_resistance_ohm: f64,
    /// Current of the board, receiver and the rest, A.
    pub avionics_current_a: f64,
    /// Efficiency of the motors and ESCs, shaft power over electrical power, in (0, 1].
    pub drive_efficiency: f64,
    /// Standard deviation of the board's voltage reading, V.
    pub voltage_noise_v: f64,
    /// Standard deviation of the board's current reading, A.
    pub current_noise_a: f64,
}

impl Default for PackParams {
    /// A charged 4S 1,500 mAh pack of 5 mΩ a cell; 0.5 A for the avionics; 80 % drive
    /// efficiency; 20 mV and 0.2 A of reading noise.
    fn default() -> Self {
        Self {
            cells: 4,
            capacity_mah: 1_500.0,
            initial_charge: 1.0,
            cell_resistance_ohm: 0.005,
            avionics_current_a: 0.5,
            drive_efficiency: 0.8,
            voltage_noise_v: 0.02,
            current_noise_a: 0.2,
        }
    }
}

/// A pack being drained.
#[derive(Clone, Debug)]
pub struct SimBattery {
    params: PackParams,
    used_mah: f64,
    /// The true voltage and current of the latest step.
    truth: BatteryReading,
    rng: crate::rng::Rng,
}

impl SimBattery {
    /// A pack as `params` describe it; `seed` draws its reading noise.
    pub fn new(params: PackParams, seed: u64) -> Self {
        let mut battery = Self {
            params,
            used_mah: 0.0,
            truth: BatteryReading::default(),
            rng: crate::rng::Rng::new(seed ^ 0xBA77),
        };
        battery.truth = battery.solve(0.0);
        battery
    }

    /// Drain the pack for `dt_s` at `shaft_power_w` (what the motors deliver to their rotors);
    /// returns what the board's sensors read.
    pub fn step(&mut self, dt_s: f64, shaft_power_w: f64) -> BatteryReading {
        self.truth = self.solve(shaft_power_w.max(0.0));
        self.used_mah += f64::from(self.truth.current_a) * dt_s * MAH_PER_AS;
        let p = &self.params;
        BatteryReading {
            voltage_v: (f64::from(self.truth.voltage_v) + p.voltage_noise_v * self.rng.normal())
                as f32,
            current_a: (f64::from(self.truth.current_a) + p.current_noise_a * self.rng.normal())
                as f32,
        }
    }

    /// The pack's true voltage and current now.
    pub fn truth(&self) -> BatteryReading {
        self.truth
    }

    /// Charge drawn so far, mAh.
    pub fn used_mah(&self) -> f64 {
        self.used_mah
    }

    /// Terminal voltage and current at `shaft_power_w`. With `a = V_oc − R·I₀`:
    /// `V² − a·V + R·P/η = 0`, the larger root. Past the pack's power limit (no real root) it
    /// gives the voltage of that limit, `a/2`.
    fn solve(&self, shaft_power_w: f64) -> BatteryReading {
        let p = &self.params;
        let cells = f64::from(p.cells);
        let charge = (p.initial_charge - self.used_mah / p.capacity_mah).clamp(0.0, 1.0);
        let open_circuit_v = cells * open_circuit_cell_v(charge);
        let resistance_ohm = cells * p.cell_resistance_ohm;
        let a = open_circuit_v - resistance_ohm * p.avionics_current_a;
        let electrical_w = shaft_power_w / p.drive_efficiency;
        let discriminant = (a * a - 4.0 * resistance_ohm * electrical_w).max(0.0);
        let voltage_v = (a + discriminant.sqrt()) / 2.0;
        let current_a = if resistance_ohm > 0.0 {
            (open_circuit_v - voltage_v) / resistance_ohm
        } else {
            p.avionics_current_a + electrical_w / voltage_v
        };
        BatteryReading { voltage_v: voltage_v as f32, current_a: current_a as f32 }
    }
}

/// A cell's resting voltage at `charge` (fraction, clamped to [0, 1]), V.
pub fn open_circuit_cell_v(charge: f64) -> f64 {
    let x = charge.clamp(0.0, 1.0) * 10.0;
    let i = (x.floor() as usize).min(9);
    let f = x - i as f64;
    OPEN_CIRCUIT_CELL_V[i] + f * (OPEN_CIRCUIT_CELL_V[i + 1] - OPEN_CIRCUIT_CELL_V[i])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quiet() -> PackParams {
        PackParams { voltage_noise_v: 0.0, current_noise_a: 0.0, ..PackParams::default() }
    }

    #[test]
    fn a_resting_pack_reads_its_open_circuit_voltage() {
        let mut pack = SimBattery::new(quiet(), 1);
        let reading = pack.step(0.001, 0.0);
        // 0.5 A of avionics through 20 mΩ: 10 mV below 16.8 V.
        assert!((reading.voltage_v - 16.79).abs() < 1e-3, "{} V", reading.voltage_v);
        assert!((reading.current_a - 0.5).abs() < 1e-4, "{} A", reading.current_a);
    }

    #[test]
    fn power_balances_and_the_voltage_sags_under_load() {
        let mut pack = SimBattery::new(quiet(), 1);
        let shaft_w = 200.0;
        let reading = pack.step(0.001, shaft_w);
        let (v, i) = (f64::from(reading.voltage_v), f64::from(reading.current_a));
        // What the pack delivers is what the drive draws: V·I = V·I₀ + P/η.
        assert!((v * i - (v * 0.5 + shaft_w / 0.8)).abs() < 0.05, "{v} V × {i} A");
        // And the drop is the current through the internal resistance.
        assert!((16.8 - v - i * 0.02).abs() < 1e-3, "{v} V at {i} A");
        assert!(i > 15.0 && v < 16.5);
    }

    #[test]
    fn the_charge_drawn_integrates_the_current_and_lowers_the_voltage() {
        let mut pack = SimBattery::new(quiet(), 1);
        // 150 W at the shafts for 60 s.
        let mut first = None;
        for _ in 0..60_000 {
            let r = pack.step(0.001, 150.0);
            first.get_or_insert(r);
        }
        let first = first.unwrap();
        let last = pack.truth();
        let mean_a = 0.5 * f64::from(first.current_a + last.current_a);
        assert!((pack.used_mah() - mean_a * 60.0 / 3.6).abs() < 1.0, "{} mAh", pack.used_mah());
        assert!(last.voltage_v < first.voltage_v, "the pack runs down");
    }

    #[test]
    fn the_open_circuit_curve_runs_from_empty_to_full() {
        assert_eq!(open_circuit_cell_v(0.0), 3.27);
        assert_eq!(open_circuit_cell_v(1.0), 4.20);
        assert!((open_circuit_cell_v(0.55) - 3.845).abs() < 1e-9);
        assert_eq!(open_circuit_cell_v(-1.0), 3.27);
        let mut previous = 0.0;
        for k in 0..=100 {
            let v = open_circuit_cell_v(f64::from(k) / 100.0);
            assert!(v > previous, "monotonic at {k} %");
            previous = v;
        }
    }
}
