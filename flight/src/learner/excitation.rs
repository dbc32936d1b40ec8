//! The excitation schedule: after the throw, each motor in index order is pulsed while the
//! estimators watch the response (docs/algorithms/learner.md).
//!
//! Per motor: a step to [`ExcitationConfig::step_command`] for `step_s`, a jump to
//! `jump_command`, then a linear ramp back to 0 over `ramp_s`. The published levels are 0.35 and
//! 0.70; ours are 0.5 and 1.0: a stronger pulse stands out more against drag and the tumbling
//! body's own dynamics (on the simulator's Monte Carlo the median thrust-axis error fell from
//! 1.5° to 0.7°), and the gyro guard still bounds the rate it adds. The next motor starts
//! `overlap_s` before the current one ends, so motor `i` starts at `delay_s + i·(step_s + ramp_s
//! − overlap_s)`. Motors not being pulsed get δ = 0 (idle while the ESCs are armed).
//!
//! Timing: the published schedule (50 ms step, 100 ms ramp, 50 ms overlap) starts a quad's fourth
//! motor 300 ms into the excitation, so no thrust axis can exist before then, and a hexarotor or
//! octorotor needs 500–700 ms. Our default is half as long per motor: a 25 ms
//! step (one time constant of a 20–27 ms motor, so τ is seen), a 50 ms ramp and a 25 ms overlap,
//! after a 40 ms spin-up of every motor at δ = 0.02 (the ESCs start the motors together before
//! the first pulse, instead of during it). Motor `i` starts at `40 + 50·i` ms: a quad's last
//! pulse ends at 265 ms, an octorotor's at 465 ms.
//!
//! **Gyro guard**: when motor `i` (0-based) of `m` starts, each rate axis gets the bounds
//! `Ω₀ + (Ω_max − Ω₀)/(m − i)` and `Ω₀ − (Ω_max + Ω₀)/(m − i)` around the rate `Ω₀` at that
//! moment: each motor may use its share of the head-room left to `±Ω_max`. Leaving them ends
//! that motor's pulse at once (its command returns to 0); the schedule of the others is kept.
//!
//! **Pulses scaled to the motors.** A pulse much shorter than the motor's time constant barely
//! moves its speed (a 1.5 kg hexarotor's motors with τ = 50 ms reach a fifth of their range in a
//! 25 ms step), and one much longer wastes the half second. So the spin-up doubles as a
//! measurement: the mean reported speed of all motors, a first-order response from standstill,
//! is read at half the spin-up and at its end; `ω(2T)/ω(T) = 1 + e^(−T/τ)` gives τ, and the
//! step, ramp and overlap are scaled by `τ / reference_tau_s` (clamped to
//! [`ExcitationConfig::tau_range_s`]). When the ratio is not that of a first-order response, the
//! times stay as configured (for `reference_tau_s`); when no motor reported a speed at all (ESCs
//! without telemetry, `no_speed`), they are scaled to [`UNREPORTED_TAU_S`].
//!
//! **Never longer than `max_s` (0.8 s).** The scale is capped so that the whole schedule still
//! fits in [`ExcitationConfig::max_s`]: an octorotor with 50 ms motors gets pulses 1.76× the
//! reference instead of 2×, and flies 0.2 s sooner. Measured on `fly monte-carlo --runs 1000`:
//! with a 1.0 s cap, 10 of the 20 craft that hit the ground were octorotors whose excitation ran
//! the full second (flown 1.14 s after release, falling at 4 m/s); with 0.8 s, 11 hit the ground
//! and 985 of 1,000 hovered (975 before). The price is on the identification of the slowest
//! craft: the worse G1 block's 99th percentile on `identify monte-carlo --runs 1000` went from
//! 10.90 % to 11.56 % (median 2.76 % both). A 0.7 s cap hovered 988 but cost the built-in
//! octo-flat its accuracy (worst G1 row 4.2 → 12.2 %); 0.8 s keeps it at 4.7 %.
//!
//! **Safety timeout**: the excitation ends at `min(max_s, delay_s + m·(step_s + ramp_s) −
//! (m − 1)·overlap_s + 10 ms)` whatever happens.
//!
//! Runs in the 2 kHz control step: constant time, no allocation.

use crate::math::clamp;

/// Most motors the schedule handles.
pub const MAX_MOTORS: usize = 8;

/// The time constant the pulses are scaled to when no motor reported a speed during the
/// spin-up (ESCs without telemetry, `no_speed`), s: the lag is then identified from the body's
/// response to the pulses, and a pulse much shorter than a slow motor's lag shows it poorly.
/// Measured on 200 random worlds without telemetry (`fly monte-carlo --world random
/// --no-speed-telemetry`, docs/benchmarks.md): at the reference 25 ms, 190 hovered; at 32.5 ms
/// (pulses 1.3 × as long), 192.
pub const UNREPORTED_TAU_S: f32 = 0.0325;

/// Time after the last pulse ends before the excitation does, s: the motor's speed settles
/// towards idle while the estimators still watch.
pub const END_MARGIN_S: f32 = 0.010;

/// The schedule's shape.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExcitationConfig {
    /// Time after the throw is confirmed before the first pulse, s, with every motor at
    /// `spin_up_command`.
    pub delay_s: f32,
    /// Command of every motor during `delay_s`, δ: low, so the craft is barely pushed, but
    /// above zero, so the ESCs start the motors and they settle near idle before the first
    /// pulse (a spin-up of all motors at once during a pulse blurs which motor did what).
    pub spin_up_command: f32,
    /// Length of the first level of each pulse, s.
    pub step_s: f32,
    /// Command of the first level, δ.
    pub step_command: f32,
    /// Command the pulse jumps to at the end of the step, δ, from which it ramps down to 0.
    pub jump_command: f32,
    /// Length of the ramp from `jump_command` to 0, s.
    pub ramp_s: f32,
    /// How long a motor's pulse overlaps the next motor's, s.
    pub overlap_s: f32,
    /// Rate bound of the gyro guard, rad/s (published: 1150–1600 °/s).
    pub rate_limit_rad_s: f32,
    /// Longest excitation whatever the motor count, s: the pulses scaled to slow motors are
    /// shortened to fit it, and it ends the excitation whatever happens (safety timeout).
    pub max_s: f32,
    /// Motor time constant the step, ramp and overlap above are meant for, s.
    pub reference_tau_s: f32,
    /// Range of the time constant measured during the spin-up that the pulses are scaled to, s.
    pub tau_range_s: [f32; 2],
}

impl Default for ExcitationConfig {
    fn default() -> Self {
        Self {
            delay_s: 0.040,
            spin_up_command: 0.02,
            step_s: 0.025,
            step_command: 0.5,
            jump_command: 1.0,
            ramp_s: 0.050,
            overlap_s: 0.025,
            rate_limit_rad_s: 1400.0_f32.to_radians(),
            max_s: 0.8,
            reference_tau_s: 0.025,
            tau_range_s: [0.012, 0.055],
        }
    }
}

/// What the schedule asks for at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExcitationOutput {
    /// Commands δ ∈ [0, 1] for every motor (first `m` used).
    pub commands: [f32; MAX_MOTORS],
    /// The motor whose pulse started most recently and is still running.
    pub active_motor: Option<u8>,
    /// Whether the excitation is over (safety timeout reached).
    pub finished: bool,
}

/// The running schedule of one excitation.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Excitation {
    config: ExcitationConfig,
    motors: usize,
    elapsed_s: f32,
    /// Gyro-guard bounds of each motor's pulse, set when it starts: `[lower, upper]` per axis.
    bounds: [[[f32; 2]; 3]; MAX_MOTORS],
    started: [bool; MAX_MOTORS],
    /// Pulses cut short by the gyro guard.
    stopped: [bool; MAX_MOTORS],
    /// Mean motor speed at half the spin-up, rad/s.
    spin_up_half_speed: Option<f32>,
    /// Motor time constant measured during the spin-up, s (when it could be).
    measured_tau_s: Option<f32>,
    /// Whether the pulse times have been scaled (at the end of the spin-up).
    scaled: bool,
    /// Whether any speed was reported during the spin-up.
    speeds_seen: bool,
}

impl Excitation {
    /// The schedule for `motors` motors (clamped to 1..=8), at time 0.
    pub fn new(config: ExcitationConfig, motors: usize) -> Self {
        Self {
            config,
            motors: motors.clamp(1, MAX_MOTORS),
            elapsed_s: 0.0,
            bounds: [[[0.0; 2]; 3]; MAX_MOTORS],
            started: [false; MAX_MOTORS],
            stopped: [false; MAX_MOTORS],
            spin_up_half_speed: None,
            measured_tau_s: None,
            scaled: false,
            speeds_seen: false,
        }
    }

    /// The motor time constant measured during the spin-up, s, if it could be.
    pub fn measured_tau_s(&self) -> Option<f32> {
        self.measured_tau_s
    }

    /// Measure during the spin-up and, at its end, scale the pulses (see the module doc).
    fn spin_up(&mut self, t: f32, dt_s: f32, mean_speed_rad_s: Option<f32>) {
        let c = self.config;
        let half = 0.5 * c.delay_s;
        self.speeds_seen |= mean_speed_rad_s.is_some_and(f32::is_finite);
        if self.spin_up_half_speed.is_none() && t + 0.5 * dt_s >= half {
            self.spin_up_half_speed = mean_speed_rad_s.filter(|s| s.is_finite() && *s > 0.0);
        }
        if self.scaled || t + 0.5 * dt_s < c.delay_s {
            return;
        }
        self.scaled = true;
        let tau = if self.speeds_seen {
            let ratio = match (self.spin_up_half_speed, mean_speed_rad_s) {
                (Some(first), Some(second)) if second.is_finite() => second / first,
                _ => return,
            };
            // ω(2T)/ω(T) = 1 + e^(−T/τ) lies in (1, 2) for a first-order response from rest.
            if !(ratio > 1.0 && ratio < 2.0) {
                return;
            }
            let tau = -half / libm::logf(ratio - 1.0);
            if !tau.is_finite() {
                return;
            }
            let tau = clamp(tau, c.tau_range_s[0], c.tau_range_s[1]);
            self.measured_tau_s = Some(tau);
            tau
        } else {
            UNREPORTED_TAU_S
        };
        // Longer pulses for slower motors, but never past `max_s`: every motor keeps its whole
        // pulse, and the craft is flown while it still has height to recover in. (A `max_s`
        // that leaves no room for pulses at all scales nothing; the timeout still ends it.)
        let fits = (c.max_s - c.delay_s - END_MARGIN_S) / self.pulses_s();
        if fits.is_nan() || fits <= 0.0 {
            return;
        }
        let scale = (tau / c.reference_tau_s).min(fits);
        self.config.step_s *= scale;
        self.config.ramp_s *= scale;
        self.config.overlap_s *= scale;
    }

    /// Time from the start of the excitation to the start of motor `i`'s pulse, s.
    pub fn start_s(&self, motor: usize) -> f32 {
        let c = &self.config;
        c.delay_s + motor as f32 * (c.step_s + c.ramp_s - c.overlap_s)
    }

    /// Total length including the [`END_MARGIN_S`] margin, capped at `max_s`, s.
    pub fn duration_s(&self) -> f32 {
        (self.config.delay_s + self.pulses_s() + END_MARGIN_S).min(self.config.max_s)
    }

    /// From the first pulse's start to the last one's end, s.
    fn pulses_s(&self) -> f32 {
        let c = &self.config;
        let m = self.motors as f32;
        m * (c.step_s + c.ramp_s) - (m - 1.0) * c.overlap_s
    }

    /// Time since the excitation began, s.
    pub fn elapsed_s(&self) -> f32 {
        self.elapsed_s
    }

    /// Whether motor `i`'s pulse was ended early by the gyro guard.
    pub fn cut_short(&self, motor: usize) -> bool {
        self.stopped.get(motor).copied().unwrap_or(false)
    }

    /// Advance by `dt_s` with the body rate `gyro_rad_s` and the mean reported motor speed
    /// now; returns the commands to apply.
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        mean_speed_rad_s: Option<f32>,
        dt_s: f32,
    ) -> ExcitationOutput {
        let t = self.elapsed_s;
        self.spin_up(t, dt_s, mean_speed_rad_s);
        let c = self.config;
        let mut out =
            ExcitationOutput { commands: [0.0; MAX_MOTORS], active_motor: None, finished: false };
        if t >= self.duration_s() {
            out.finished = true;
            return out;
        }
        let pulse_s = c.step_s + c.ramp_s;
        if t < c.delay_s {
            out.commands[..self.motors].fill(c.spin_up_command);
        }
        for i in 0..self.motors {
            let local = t - self.start_s(i);
            if local < 0.0 || local >= pulse_s {
                continue;
            }
            if !self.started[i] {
                self.started[i] = true;
                let share = (self.motors - i) as f32;
                for (axis, rate) in gyro_rad_s.iter().enumerate() {
                    let rate = if rate.is_finite() { *rate } else { 0.0 };
                    self.bounds[i][axis] = [
                        rate - (c.rate_limit_rad_s + rate) / share,
                        rate + (c.rate_limit_rad_s - rate) / share,
                    ];
                }
            }
            let outside = gyro_rad_s
                .iter()
                .zip(&self.bounds[i])
                .any(|(rate, [lower, upper])| !(*rate >= *lower && *rate <= *upper));
            if outside {
                self.stopped[i] = true;
            }
            if self.stopped[i] {
                continue;
            }
            out.commands[i] = if local < c.step_s {
                c.step_command
            } else {
                c.jump_command * (1.0 - (local - c.step_s) / c.ramp_s)
            };
            out.active_motor = Some(i as u8);
        }
        self.elapsed_s = t + dt_s;
        out
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    const DT: f32 = 0.0005;

    #[test]
    fn published_schedule_for_a_quad_has_its_documented_timing() {
        let config = ExcitationConfig {
            delay_s: 0.0,
            step_command: 0.35,
            jump_command: 0.70,
            step_s: 0.05,
            ramp_s: 0.1,
            overlap_s: 0.05,
            ..ExcitationConfig::default()
        };
        let mut e = Excitation::new(config, 4);
        assert!((e.start_s(3) - 0.300).abs() < 1e-6);
        assert!((e.duration_s() - 0.460).abs() < 1e-6, "450 ms + 10 ms margin");
        let mut trace = Vec::new();
        loop {
            // Speed reports that do not scale the pulses (a constant speed).
            let out = e.update([0.0; 3], Some(400.0), DT);
            if out.finished {
                break;
            }
            trace.push(out.commands);
        }
        // Samples at 0.5 ms: motor 0 at 0.35 for 50 ms, jumps to 0.7, ramps to 0 by 150 ms.
        assert_eq!(trace[10][0], 0.35);
        assert!((trace[101][0] - 0.7 * (1.0 - 0.0005 / 0.1)).abs() < 1e-4);
        assert!((trace[200][0] - 0.35).abs() < 1e-6 && trace[200][1] > 0.0);
        assert_eq!(trace[302][0], 0.0, "motor 0 is done at 150 ms");
        assert_eq!(trace[650][3], 0.35, "motor 3 is in its step at 325 ms");
        assert!((919..=921).contains(&trace.len()), "{} samples of 0.5 ms", trace.len());
    }

    #[test]
    fn the_gyro_guard_ends_a_pulse_that_spins_the_craft_too_fast() {
        let config = ExcitationConfig { delay_s: 0.0, ..ExcitationConfig::default() };
        let mut e = Excitation::new(config, 4);
        let limit = config.rate_limit_rad_s;
        // Motor 0 starts at rate 0: its share is ±limit/4.
        assert_eq!(e.update([0.0; 3], None, DT).commands[0], config.step_command);
        assert!(e.update([0.2 * limit, 0.0, 0.0], None, DT).commands[0] > 0.0);
        let out = e.update([0.26 * limit, 0.0, 0.0], None, DT);
        assert_eq!(out.commands[0], 0.0);
        assert!(e.cut_short(0) && !e.cut_short(1));
    }

    #[test]
    fn pulses_are_scaled_to_the_time_constant_seen_in_the_spin_up() {
        for tau in [0.02f32, 0.05] {
            let config = ExcitationConfig::default();
            let mut e = Excitation::new(config, 6);
            let mut t = 0.0;
            let mut out = e.update([0.0; 3], Some(0.0), DT);
            while t < config.delay_s + 0.002 {
                t += DT;
                // Mean speed of motors starting from rest towards 400 rad/s.
                let speed = 400.0 * (1.0 - libm::expf(-t / tau));
                out = e.update([0.0; 3], Some(speed), DT);
            }
            let measured = e.measured_tau_s().unwrap();
            assert!((measured - tau).abs() < 0.03 * tau, "τ {tau} measured {measured}");
            let expected_spacing = 2.0 * tau;
            assert!(((e.start_s(1) - e.start_s(0)) - expected_spacing).abs() < 1e-3);
            assert_eq!(out.commands[0], config.step_command, "motor 0's pulse has begun");
        }
        // Reports that are not a first-order response (a constant speed): the configured times
        // stay.
        let mut e = Excitation::new(ExcitationConfig::default(), 4);
        for _ in 0..200 {
            e.update([0.0; 3], Some(400.0), DT);
        }
        assert_eq!(e.measured_tau_s(), None);
        assert!((e.start_s(1) - e.start_s(0) - 0.05).abs() < 1e-6);
        // No speed reported at all (ESCs without telemetry): scaled to `UNREPORTED_TAU_S`,
        // nothing measured.
        let mut e = Excitation::new(ExcitationConfig::default(), 4);
        for _ in 0..200 {
            e.update([0.0; 3], None, DT);
        }
        assert_eq!(e.measured_tau_s(), None);
        let spacing = 0.05 * UNREPORTED_TAU_S / ExcitationConfig::default().reference_tau_s;
        assert!((e.start_s(1) - e.start_s(0) - spacing).abs() < 1e-6);
    }

    #[test]
    fn the_default_schedule_excites_every_quad_motor_within_300_ms() {
        let e = Excitation::new(ExcitationConfig::default(), 4);
        // The last pulse ends early enough for the filters (20 Hz: ~20 ms) to settle by 300 ms.
        assert!(e.duration_s() < 0.28, "{}", e.duration_s());
        let octo = Excitation::new(ExcitationConfig::default(), 8);
        assert!(octo.duration_s() <= 0.8);
    }

    #[test]
    fn pulses_for_slow_motors_are_shortened_to_fit_the_longest_excitation() {
        let config = ExcitationConfig::default();
        // Slower than the range: the measured τ is clamped to its top, 55 ms (scale 2.2).
        let tau = 0.080;
        let wanted_scale = config.tau_range_s[1] / config.reference_tau_s;
        for motors in 4..=MAX_MOTORS {
            let mut e = Excitation::new(config, motors);
            let mut t = 0.0;
            while t < config.delay_s + 0.002 {
                t += DT;
                e.update([0.0; 3], Some(400.0 * (1.0 - libm::expf(-t / tau))), DT);
            }
            let scale = (e.start_s(1) - e.start_s(0)) / 0.050;
            // Nominal: 75 ms pulses every 50 ms, so the pulses span 50·m + 25 ms.
            let nominal_pulses_s = 0.050 * motors as f32 + 0.025;
            let room_s = config.max_s - config.delay_s - END_MARGIN_S;
            let expected = wanted_scale.min(room_s / nominal_pulses_s);
            assert!((scale - expected).abs() < 1e-3 * expected, "{motors} motors: scale {scale}");
            // Every pulse whole, the last ending within the longest excitation.
            let last_end_s = e.start_s(motors - 1) + 0.075 * scale;
            assert!(last_end_s <= config.max_s - END_MARGIN_S + 1e-4, "{motors}: {last_end_s} s");
            assert!(e.duration_s() <= config.max_s);
            // Up to 6 motors fit at the full scale; 7 and 8 are shortened.
            assert_eq!(scale < wanted_scale - 1e-3, motors >= 7, "{motors} motors: scale {scale}");
        }
        // A longest excitation shorter than the spin-up leaves no room: nothing is scaled.
        let cramped = ExcitationConfig { max_s: 0.030, ..config };
        let mut e = Excitation::new(cramped, 4);
        let mut t = 0.0;
        while t < cramped.delay_s + 0.002 {
            t += DT;
            e.update([0.0; 3], Some(400.0 * (1.0 - libm::expf(-t / tau))), DT);
        }
        assert!(((e.start_s(1) - e.start_s(0)) - 0.050).abs() < 1e-6);
        assert!(e.duration_s() <= cramped.max_s);
    }
}
