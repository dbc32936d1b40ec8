//! Identification without speed telemetry (issue 32): the motors' lag from the body's response,
//! and a modelled speed from the commands in place of the measured one
//! (docs/algorithms/learner.md, "Without speed telemetry"). Every build has it (issue 56: one
//! firmware image for every craft): a learner built with [`super::LearnerConfig::speed_telemetry`]
//! false, what the application builds when the user sets `motor_bidir_dshot` = 0, runs it. The
//! simulator flies it (`fly monte-carlo --no-speed-telemetry`), and so does the bridge
//! (`scenario bridge --no-speed-telemetry`).
//!
//! **The model.** ESCs without bidirectional DShot report no speed; the learner still knows
//! what it commanded, and the body's motion shows what the motors did with it. Every motor's
//! speed, as a fraction `x` of full speed, is taken as a first-order lag towards a nominal curve
//! of the command:
//!
//! ```text
//! τ ẋ + x = x_s(δ),    x_s(δ) = idle + (1 − idle)(κ δ + (1 − κ) √δ)     (κ 0.5, idle 8 %)
//! ```
//!
//! and the modelled speed `ω = ω_full x` goes to the effectiveness regression exactly where a
//! reported speed would, so G1 is learned per unit of the modelled `ω²`; per unit normalised
//! thrust (`g1_per_unit_thrust`, what the thrust axis and INDI use) it is right wherever the true
//! thrust is proportional to `x²` (a scale between them is absorbed by G1). The controller
//! ([`crate::indi`]) already models each motor's speed from its commands with the learned curve
//! and τ and never reads reports, so the nominal curve and the identified τ
//! ([`CommandSpeedModel::motor_model`]) are what it flies on.
//!
//! **The lag: a grid of candidates.** For a fixed τ the body's response is linear in the
//! unknowns: per body axis `α = Σ C_i x_i² + Σ k_i ẋ_i + Σ g_i,b x_i Ω_b + d` (`C` = G1τ per unit
//! thrust; `k` the rotors' reaction to their acceleration; `g` the gyroscopic torque `Ω × H`
//! of each rotor's momentum, with the other two axes' rates `Ω_b`; `d` the Euler and drag terms,
//! slow), and the specific force `f = Σ c_i x_i² + α × r + Ω × (Ω × r)` (the IMU's offset `r`
//! through nine products of the rates, each with a free coefficient). So each of
//! [`TAU_GRID_S`] (8–100 ms, 22 % apart) models the speeds with its τ and sums the products
//! of these regressions (normal equations), and τ is the candidate whose least-squares residual
//! is smallest (each of the six outputs relative to the candidates' mean, summed), refined by a
//! parabola in `ln τ` through it and its neighbours (σ from the parabola's curvature). This
//! replaced τ as a regressor of `2α = Σ C_i 2 x_i x_s,i − τ α̇ + …` (with `x` from the current
//! τ, a fixed point): that needed α̇, a second derivative of the gyro, and its τ wandered
//! towards the bounds (docs/benchmarks.md). To differentiate nothing, the gyro side passes
//! through `F = LP · HP²` (a 2nd-order Butterworth low-pass at [`LAG_LOWPASS_HZ`] and two
//! first-order high-passes at [`LAG_HIGH_PASS_HZ`]) and its regressors through `F/s = LP·HP·L`
//! (`L` the first-order low-pass at the high-pass corner: `HP/s = L/ω_h`, the scale absorbed
//! by the coefficients); the specific force and its regressors through `F`. The high-passes
//! remove what varies at 0.2–2 Hz (`d`, drag, biases); the pulses carry 5–40 Hz.
//!
//! **At 125 Hz, a share on every sample.** Only the speed models run at the control rate
//! (one multiply-add per motor and candidate) and add their squares and products with the
//! rates to sums over a period of [`LAG_REGRESSION_PERIOD_S`] (8 ms). The period's last sample
//! runs the shared filters; each candidate's filters and sums of products run on the period's
//! means in turn over the next period's other samples, at most one candidate a sample, so that
//! every sample does about the same share. The rates' side sees the difference of
//! two periods' mean rates, which is the angular acceleration summed over a triangle of the two
//! periods; the integrated regressors take the same triangle (weighted sums kept beside the
//! plain ones), so both sides see one filter. The specific force is taken one period back, where
//! the central difference of the filtered rates gives its angular acceleration. The regressions
//! stop at the last pulse's end; the candidates' regressions are then solved for their
//! residuals (three of `4m` unknowns and one of `m + 9` per candidate: all 52 in one sample
//! were 880,000 instructions on a quad), each loaded, factored and solved a row, a column or an
//! output at a time ([`Solve`]), as many steps a sample as a budget of work allows
//! ([`SCORING_WORK_PER_MOTOR`]), and the lag is chosen with the last. Until then the published
//! τ is the prior.
//!
//! **The effectiveness regression waits for the lag.** It never forgets, so what it learned
//! from speeds modelled with the lag of the first pulses, still far off, would stay. The
//! samples are held in a ring ([`EFFECTIVENESS_HOLD_S`]) as their means over
//! [`HOLD_INTERVAL_S`] (4 ms: the rates, the specific force, the nominal curve's steady speed
//! for the commands) and released to it from the end of the excitation (every motor pulsed and
//! all back below [`PULSE_COMMAND`]), their speeds modelled with the lag identified over every
//! pulse, [`RELEASE_PER_SAMPLE`] a sample. Without speed telemetry the effectiveness
//! regression runs at the held samples' rate throughout (250 Hz at 2 kHz: its filters designed
//! for it, its six rows in turn, each at 41.7 Hz on increments over 24 ms), in the free fall
//! before the excitation ([`CommandSpeedModel::prime`]) and in flight after it too, and so does
//! the in-flight IMU-offset fit on its samples. The catch-up is spread over the samples that
//! follow, each within the learner's per-sample budget: the backlog shrinks by 7 held samples
//! in 8 control samples, as fast as releasing 8 full-rate samples a sample did (a quad's 450
//! held samples were 4.9 M instructions, 10 ms at 480 MHz, in one sample; 8 a sample were up
//! to 76,000 instructions on a quad and 146,000 on an octorotor). Until it is done the
//! published model says `pending` and the control step waits for it before engaging
//! (`firmware::app::control`, `ENGAGE_WAIT_MAX_S`).
//!
//! The held samples' assumption, in seconds and hertz: what the effectiveness regression
//! learns from lies below 40 Hz (the pulses carry 5–40 Hz, and every signal passes its 20 Hz
//! low-pass), so a mean over 4 ms keeps it (it passes 20 Hz with 1 % less, 40 Hz with 4 %
//! less, alike on both sides of the regression), and what the mean folds onto the band from
//! above 125 Hz is attenuated by the mean itself (its zeros at multiples of 250 Hz) and then by
//! the 20 Hz low-pass. Rotor vibration (100–500 Hz) and gyro noise up to 3× the ICM-42688-P's
//! are what the simulator's random world draws against it. The modelled speed of a held sample
//! is the root mean square over its interval of the lag's exact response to the interval's
//! mean target ([`CommandSpeedModel::release`]), so that its square is the interval's mean of
//! `x²`, as the rates are their interval's mean. What it costs: each row's regressions come at
//! 41.7 Hz instead of 333 Hz, and on 1,000 random worlds G1 per unit thrust at the excitation's
//! end is 1–2 percentage points further off in median (force 17.1 → 18.3 %, torque 18.2 →
//! 20.2 %) and the thrust axis at engagement 1.79 → 2.39° in median, 4.80 → 7.43° at the 90th
//! percentile, the crafts hovering as often (docs/benchmarks.md, "The catch-up within the
//! learner's budget"); a 2 ms interval learned what every sample did but caught up in 148 ms
//! in median instead of 60.
//!
//! Cost (`cargo xtask bench-m7`, docs/benchmarks.md): during the excitation at most
//! 8,572 Cortex-M7 instructions a sample on the quad and 19,071 on the octorotor (a
//! candidate's sample: its filters and its `5m (5m + 1)/2` products, [`add_outer_lower`]),
//! within the learner's 12,000 and 24,000; after it, the last period's candidates, then the
//! candidates' regressions, a budget of work a sample ([`SCORING_WORK_PER_MOTOR`]), then the
//! catch-up, one held sample a sample (about what a learner sample with telemetry costs), and
//! the sample after its last, which stages and publishes the model to engage on
//! (`Learner::update_carrying`): at most 11,183 instructions a sample on a quad and 22,226 on
//! an octorotor (up to 74,265 and 145,843 when 8 full-rate samples were learned from a sample;
//! 18,078 and 28,016 when the last held sample's own sample also published the model). The
//! ring holds 213 held samples (14 KB; 1,700 samples, 122 KB, before they were means), the
//! candidates' sums ≈ 120 KB.

// Index loops are kept where they run over axes and motors side by side (several arrays per
// index), as in `effectiveness`.
#![allow(clippy::needless_range_loop)]

use super::motor_model::MotorModel;
use super::rls::packed_len;
use super::MAX_MOTORS;
use crate::filters::{BiquadCoefficients, Butterworth2};

/// Full speed of the modelled motor, rad/s: a scale of our own choosing (the truth's is unknown
/// without telemetry), of the order of real ones so that the effectiveness regression's scaling
/// (`SPEED2_SCALE`) holds. G1 per unit thrust does not depend on it.
pub const NOMINAL_FULL_SPEED_RAD_S: f32 = 1000.0;
/// κ of the nominal curve `ω_s = a δ + b √δ + ω_idle`, `κ = a/(a + b)`: the middle of the
/// papers' family, close to a speed `∝ δ^0.75` (the middle of the power laws seen, p 0.6–1.4
/// giving thrust `∝ δ^1.2–2.8`) and to thrust `∝ 0.5 δ² + 0.5 δ`.
pub const NOMINAL_KAPPA: f32 = 0.5;
/// Idle speed of the nominal curve, fraction of full speed (ESCs idle at 3–15 %).
pub const NOMINAL_IDLE_FRACTION: f32 = 0.08;
/// Low-pass of the lag regression's signals, Hz: the effectiveness regression's (the pulses
/// carry 5–40 Hz).
pub const LAG_LOWPASS_HZ: f32 = super::EFFECTIVENESS_CUTOFF_HZ;
/// Corner of the two high-passes of the lag regressions, Hz (see the module doc).
pub const LAG_HIGH_PASS_HZ: f32 = 5.0;
/// The time constant flown before any pulse, s: a 3–5-inch motor's (docs/algorithms/learner.md:
/// 20–27 ms).
pub const TAU_PRIOR_S: f32 = 0.025;
/// Its standard deviation, s.
pub const TAU_PRIOR_STD_S: f32 = 0.02;
/// Smallest time constant reported, s.
pub const TAU_MIN_S: f32 = 0.008;
/// Largest time constant reported, s.
pub const TAU_MAX_S: f32 = 0.1;
/// Command above which a motor counts as pulsed: the lag regression learns from the first
/// pulse on. The spin-up before the pulses (δ = 0.02, `ExcitationConfig::spin_up_command`) starts
/// every motor from rest together: its angular response is the rotors' reaction and the ESCs'
/// start, not the lag of a thrust change, and learning from it pinned τ to its lower bound for
/// the first 80 ms of the excitation on the simulator's airframes.
pub const PULSE_COMMAND: f32 = 0.1;
/// One standard deviation of τ below which the lag counts as identified, s.
pub const TAU_CONVERGED_STD_S: f32 = 0.002;
/// How long the effectiveness regression is held back behind the lag regression, s: the whole
/// excitation (`ExcitationConfig::max_s`, 0.8 s) and the lag's choice after it, so that G1 is
/// learned from speeds modelled with the lag identified over every pulse (see
/// [`CommandSpeedModel::hold`]).
pub const EFFECTIVENESS_HOLD_S: f32 = 0.85;

/// Interval of the samples the effectiveness regression learns from without speed telemetry,
/// s: each held sample is the mean of the control samples over one interval (8 at 2 kHz), and
/// the effectiveness regression runs at its rate, 250 Hz ([`held_rate_hz`]), through its own
/// filters designed for that rate (its 20 Hz low-pass and high-pass, its six rows in turn:
/// each row at 41.7 Hz, on increments over 24 ms). The assumption: what the regression learns
/// from lies below 40 Hz. The pulses carry 5–40 Hz and every signal then passes the 20 Hz
/// low-pass ([`super::EFFECTIVENESS_CUTOFF_HZ`]), so 2 kHz samples are nearly the same
/// information; the interval's mean passes 20 Hz with 1 % less and 40 Hz with 4 % less
/// (`sinc(f T)`, the same on the rates, the specific force and the modelled speeds, which are
/// the interval's means too: no lag between them). Below 125 Hz nothing folds, and the 20 Hz
/// low-pass at 250 Hz takes what lies above the band (100 Hz by 28 dB); what folds onto the
/// 0–40 Hz band comes from within 40 Hz of 250 Hz or 500 Hz (rotor vibration there), which
/// the mean attenuates by 15–23 dB (21–28 dB near 500 Hz), where the full-rate low-pass took
/// 40 dB or more. It serves two ends: the ring holds 8 times fewer samples (14 KB instead of
/// 122 KB), and the backlog after the excitation shrinks by 7 of 8 a control sample while one
/// held sample a sample is learned from ([`RELEASE_PER_SAMPLE`]), as fast as learning 8
/// full-rate samples a sample did, each sample within the learner's budget.
pub const HOLD_INTERVAL_S: f32 = 0.004;

/// Most samples held: [`EFFECTIVENESS_HOLD_S`] at the held rate (250 Hz, [`HOLD_INTERVAL_S`]),
/// rounded up.
pub const HELD_SAMPLES_MAX: usize = 213;

/// Control samples in `interval_s` at `rate_hz`, rounded, at least one.
fn samples_in(interval_s: f32, rate_hz: f32) -> usize {
    let samples = libm::roundf(interval_s * rate_hz);
    if samples >= 1.0 {
        samples as usize
    } else {
        1
    }
}

/// Control samples per held sample at `rate_hz`: [`HOLD_INTERVAL_S`] (8 at 2 kHz, at least 1).
pub fn hold_stride(rate_hz: f32) -> usize {
    samples_in(HOLD_INTERVAL_S, rate_hz)
}

/// The rate of the held samples, Hz, at the control rate `rate_hz`: what the effectiveness
/// regression (and the in-flight IMU-offset fit on its samples) runs at without speed
/// telemetry (250 Hz at 2 kHz).
pub fn held_rate_hz(rate_hz: f32) -> f32 {
    rate_hz / hold_stride(rate_hz) as f32
}

/// Held samples released to the effectiveness regression per control sample at most: the
/// catch-up after the excitation is spread over the samples that follow it, so that the task
/// running the learner keeps up with the control rate. A released sample costs about what a
/// learner sample with speed telemetry does (its filters and one of the six rows), within the
/// learner's budget: 12,000 Cortex-M7 instructions on a quad, 24,000 on an octorotor (issue
/// 56, `cargo xtask bench-m7`). Each control sample adds an eighth of a held sample
/// ([`HOLD_INTERVAL_S`]) and releases one, so the 213 held samples of the longest excitation are
/// learned from within 213 / (7/8) ≈ 243 samples (0.12 s), a quad's 450 control samples (56
/// held) within 32 ms.
pub const RELEASE_PER_SAMPLE: usize = 1;

/// Period over which the lag regressions' inputs are averaged, s: the regressions run once a
/// period (125 Hz at 2 kHz), each candidate's filters and sums in turn over the next period's
/// samples, at most one a sample, so that no sample exceeds the learner's per-sample budget
/// (at 4 ms two candidates fell on some samples: 16,600 instructions against 12,000,
/// docs/benchmarks.md). Three times the pulses' highest frequency (40 Hz) and six times the
/// 20 Hz low-pass: the period's mean attenuates 20 Hz by 4 % (`sinc(f T)`), the same on the
/// rates and on the regressors, so the lag it implies is common to both sides.
pub const LAG_REGRESSION_PERIOD_S: f32 = 0.008;

/// A regressor through `F/s`: `L`, a high-pass and the low-pass.
#[derive(Clone, Copy, Debug)]
struct Integrated {
    l: f32,
    hp: HighPass,
    lp: Butterworth2,
}

impl Integrated {
    fn new(lp: Butterworth2) -> Self {
        Self { l: 0.0, hp: HighPass::default(), lp }
    }

    fn reset_to(&mut self, x: f32) {
        self.l = x;
        self.hp.reset_to(x);
        self.lp.reset_to(0.0);
    }

    fn update(&mut self, x: f32, pole: f32) -> f32 {
        self.l = pole * self.l + (1.0 - pole) * x;
        let high = self.hp.update(self.l, pole);
        self.lp.update(high)
    }
}

/// A signal through `F`: two high-passes and the low-pass.
#[derive(Clone, Copy, Debug)]
struct Banded {
    hp: [HighPass; 2],
    lp: Butterworth2,
}

impl Banded {
    fn new(lp: Butterworth2) -> Self {
        Self { hp: [HighPass::default(); 2], lp }
    }

    fn reset_to(&mut self, x: f32) {
        self.hp[0].reset_to(x);
        self.hp[1].reset_to(0.0);
        self.lp.reset_to(0.0);
    }

    fn update(&mut self, x: f32, pole: f32) -> f32 {
        let once = self.hp[0].update(x, pole);
        let twice = self.hp[1].update(once, pole);
        self.lp.update(twice)
    }
}

/// One sample held back for the effectiveness regression: the means over one
/// [`HOLD_INTERVAL_S`] (or, while it is being formed, the sums).
#[derive(Clone, Copy, Debug, Default)]
struct HeldSample {
    gyro_rad_s: [f32; 3],
    accel_mps2: [f32; 3],
    /// The nominal curve's steady speed for the commands, fraction of full speed (0 where the
    /// ESCs do not run the motors): the lag acts on it linearly, so its mean is what the
    /// modelled speeds need.
    target: [f32; MAX_MOTORS],
    carried: [f32; 3],
}

impl HeldSample {
    /// Add one control sample's values.
    fn add(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        target: &[f32; MAX_MOTORS],
        carried: [f32; 3],
    ) {
        for k in 0..3 {
            self.gyro_rad_s[k] += gyro_rad_s[k];
            self.accel_mps2[k] += accel_mps2[k];
            self.carried[k] += carried[k];
        }
        for (sum, t) in self.target.iter_mut().zip(target) {
            *sum += t;
        }
    }

    /// The sums of `samples` control samples as their means (a non-finite value stays so: the
    /// effectiveness regression takes the held sample as a gap).
    fn mean(&self, samples: usize) -> Self {
        let scale = 1.0 / samples as f32;
        Self {
            gyro_rad_s: self.gyro_rad_s.map(|v| v * scale),
            accel_mps2: self.accel_mps2.map(|v| v * scale),
            target: self.target.map(|v| v * scale),
            carried: self.carried.map(|v| v * scale),
        }
    }
}

/// A sample released to the effectiveness regression, with its speeds modelled (rad/s, the
/// nominal scale) with the lag identified by the time of its release.
#[derive(Clone, Copy, Debug)]
pub struct ReleasedSample {
    /// Body rates, rad/s, IMU axes.
    pub gyro_rad_s: [f32; 3],
    /// Specific force, m/s², IMU axes.
    pub accel_mps2: [f32; 3],
    /// Modelled speeds, rad/s.
    pub speeds_rad_s: [f32; MAX_MOTORS],
    /// What the caller handed in with the sample ([`super::Learner::update_carrying`]).
    pub carried: [f32; 3],
}

/// A first-order high-pass `y_k = p (y_{k−1} + x_k − x_{k−1})`.
#[derive(Clone, Copy, Debug, Default)]
struct HighPass {
    input: f32,
    output: f32,
}

impl HighPass {
    fn reset_to(&mut self, x: f32) {
        *self = Self { input: x, output: 0.0 };
    }

    fn update(&mut self, x: f32, pole: f32) -> f32 {
        self.output = pole * (self.output + x - self.input);
        self.input = x;
        self.output
    }
}

/// An ESC curve: `x_s(δ) = idle + (1 − idle)(κ δ + (1 − κ) √δ)`, fraction of full speed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Curve {
    /// Weight of the linear term.
    pub kappa: f32,
    /// Idle speed, fraction of full speed.
    pub idle: f32,
}

impl Curve {
    /// The nominal curve ([`NOMINAL_KAPPA`], [`NOMINAL_IDLE_FRACTION`]).
    pub const NOMINAL: Curve = Curve { kappa: NOMINAL_KAPPA, idle: NOMINAL_IDLE_FRACTION };

    /// The curve as a motor model with the time constant `tau_s` (full speed
    /// [`NOMINAL_FULL_SPEED_RAD_S`]).
    pub fn motor(&self, tau_s: f32, tau_std_s: f32) -> MotorModel {
        let idle = self.idle * NOMINAL_FULL_SPEED_RAD_S;
        let span = NOMINAL_FULL_SPEED_RAD_S - idle;
        let mut model = MotorModel {
            a_rad_s: self.kappa * span,
            b_rad_s: (1.0 - self.kappa) * span,
            omega_idle_rad_s: idle,
            tau_s,
            tau_std_s,
            converged: false,
        };
        model.converged = model.is_usable() && tau_std_s < TAU_CONVERGED_STD_S;
        model
    }

    /// The steady speed for command δ, fraction of full speed (0 while the ESC has not yet
    /// started the motor, `running` false).
    pub fn target(&self, command: f32, running: bool) -> f32 {
        if !running {
            return 0.0;
        }
        let d = if command.is_finite() { command.clamp(0.0, 1.0) } else { 0.0 };
        let shape = self.kappa * d + (1.0 - self.kappa) * crate::math::sqrt(d);
        self.idle + (1.0 - self.idle) * shape
    }
}

/// The candidate time constants, s: 8–100 ms in steps of 22 % (`TAU_MIN_S`–`TAU_MAX_S`); each
/// has a regression of its own (see [`CommandSpeedModel`]).
pub const TAU_GRID_S: [f32; 13] = [
    0.008, 0.0098, 0.0119, 0.0145, 0.0177, 0.0216, 0.0264, 0.0322, 0.0393, 0.0479, 0.0585, 0.0714,
    0.1,
];

/// The nominal motor curve with the time constant `tau_s`.
pub fn nominal_motor(tau_s: f32, tau_std_s: f32) -> MotorModel {
    Curve::NOMINAL.motor(tau_s, tau_std_s)
}

/// Sums of one candidate's regressor inputs over one regression period: plain, and weighted
/// by the sample's place in the period (for the triangle, see [`LagHypothesis::close_period`]).
#[derive(Clone, Copy, Debug, Default)]
struct PeriodSums {
    /// `x²` per motor.
    square: [f32; MAX_MOTORS],
    square_weighted: [f32; MAX_MOTORS],
    /// `x` per motor.
    speed: [f32; MAX_MOTORS],
    /// `x Ω_b` per motor and body axis.
    gyroscopic: [[f32; 3]; MAX_MOTORS],
    gyroscopic_weighted: [[f32; 3]; MAX_MOTORS],
}

/// One candidate's regressor inputs of a complete period, as each path needs them.
#[derive(Clone, Copy, Debug, Default)]
struct PeriodInputs {
    /// The period's means of `x²` and `x` (the paths through `F`, like the rates' and the
    /// specific force's).
    square: [f32; MAX_MOTORS],
    speed: [f32; MAX_MOTORS],
    /// `x²` and `x Ω_b` through the triangle over this period and the one before (the paths
    /// through `F/s`).
    square_triangle: [f32; MAX_MOTORS],
    gyroscopic_triangle: [[f32; 3]; MAX_MOTORS],
}

/// The regression of one candidate time constant: the modelled speeds, their filtered squares
/// and accelerations, and the sums of products from which the torques that explain the rates
/// best with them, and their residuals, are solved ([`LagHypothesis::residuals`]).
#[derive(Clone, Debug)]
struct LagHypothesis {
    /// `1 − exp(−dt/τ)`: the exact first-order response to a held target over one sample.
    lag: f32,
    /// The modelled speed of each motor, fraction of full speed.
    speed: [f32; MAX_MOTORS],
    /// Sums of the regressor inputs over the current period.
    sums: PeriodSums,
    /// The last complete period's inputs, processed over the next period's samples.
    pending: PeriodInputs,
    /// The first half of the next period's triangles: this period's late samples, weighted.
    triangle_early_square: [f32; MAX_MOTORS],
    triangle_early_gyroscopic: [[f32; 3]; MAX_MOTORS],
    /// `F/s · x²` per motor.
    square: [Integrated; MAX_MOTORS],
    /// `F/s · x Ω_b` per motor and body axis (the gyroscopic torque `Ω × H_rotor`).
    gyroscopic: [[Integrated; 3]; MAX_MOTORS],
    /// `F x` per motor (`F/s · ẋ`, the rotor reaction).
    reaction: [Banded; MAX_MOTORS],
    /// `F x²` per motor, and its value one period back (the specific force's regressors).
    square_band: [Banded; MAX_MOTORS],
    band_previous: [f32; MAX_MOTORS],
    /// `Σ z zᵀ` (packed lower triangle) of the regressors `z`: the filtered squares (`0..m`),
    /// reactions (`m..2m`) and gyroscopic products (`2m + 3i + b`); each axis regresses on its
    /// `4m` of them ([`axis_regressors`]).
    gram: [f64; packed_len(REGRESSORS_MAX)],
    /// `Σ z y_a` per body axis.
    rate_xy: [[f64; REGRESSORS_MAX]; 3],
    /// The specific force's sums: `Σ b bᵀ` of the bands `b` (packed), `Σ b oᵀ` with the shared
    /// offset terms `o`, and `Σ b fᵀ`.
    band_gram: [f64; packed_len(MAX_MOTORS)],
    band_offset: [[f64; 9]; MAX_MOTORS],
    band_force: [[f64; 3]; MAX_MOTORS],
}

/// What every candidate's processing of one period shares: the filtered rates (this period),
/// the specific force and the offset terms (one period back, centred on the rates' difference),
/// and whether the period is learned from or restarts the filters.
#[derive(Clone, Copy, Debug, Default)]
struct SharedPeriod {
    rate: [f32; 3],
    force: [f32; 3],
    offset_terms: [f32; 9],
    learn: bool,
    start: bool,
    /// Candidates of this period already processed.
    processed: usize,
}

impl LagHypothesis {
    fn new(tau_s: f32, dt_s: f32, butterworth: Butterworth2) -> Self {
        Self {
            lag: 1.0 - libm::expf(-dt_s / tau_s),
            speed: [0.0; MAX_MOTORS],
            sums: PeriodSums::default(),
            pending: PeriodInputs::default(),
            triangle_early_square: [0.0; MAX_MOTORS],
            triangle_early_gyroscopic: [[0.0; 3]; MAX_MOTORS],
            square: [Integrated::new(butterworth); MAX_MOTORS],
            gyroscopic: [[Integrated::new(butterworth); 3]; MAX_MOTORS],
            reaction: [Banded::new(butterworth); MAX_MOTORS],
            square_band: [Banded::new(butterworth); MAX_MOTORS],
            band_previous: [0.0; MAX_MOTORS],
            gram: [0.0; packed_len(REGRESSORS_MAX)],
            rate_xy: [[0.0; REGRESSORS_MAX]; 3],
            band_gram: [0.0; packed_len(MAX_MOTORS)],
            band_offset: [[0.0; 9]; MAX_MOTORS],
            band_force: [[0.0; 3]; MAX_MOTORS],
        }
    }

    fn reset(&mut self) {
        self.speed = [0.0; MAX_MOTORS];
        self.sums = PeriodSums::default();
        self.triangle_early_square = [0.0; MAX_MOTORS];
        self.triangle_early_gyroscopic = [[0.0; 3]; MAX_MOTORS];
        self.gram = [0.0; packed_len(REGRESSORS_MAX)];
        self.rate_xy = [[0.0; REGRESSORS_MAX]; 3];
        self.band_gram = [0.0; packed_len(MAX_MOTORS)];
        self.band_offset = [[0.0; 9]; MAX_MOTORS];
        self.band_force = [[0.0; 3]; MAX_MOTORS];
    }

    /// Advance the modelled speeds towards `targets` by one sample; with `gyro_rad_s`, add the
    /// regressor inputs to the period's sums, the weighted ones by `place` (the sample's index
    /// in the period).
    fn advance(
        &mut self,
        m: usize,
        targets: &[f32; MAX_MOTORS],
        gyro_rad_s: Option<[f32; 3]>,
        place: f32,
    ) {
        for i in 0..m {
            self.speed[i] += (targets[i] - self.speed[i]) * self.lag;
            let Some(gyro) = gyro_rad_s else { continue };
            let x = self.speed[i];
            let square = x * x;
            self.sums.square[i] += square;
            self.sums.square_weighted[i] += place * square;
            self.sums.speed[i] += x;
            for b in 0..3 {
                let product = x * gyro[b];
                self.sums.gyroscopic[i][b] += product;
                self.sums.gyroscopic_weighted[i][b] += place * product;
            }
        }
    }

    /// End of a period of `d` samples: its inputs become the pending ones. The rates' path sees
    /// the difference of two periods' mean rates, `Ω̄_k − Ω̄_{k−1}`: the sum of `α dt` over a
    /// triangle of two periods, sample `p` of period `k − 1` weighted `p/d` and sample `p` of
    /// period `k` weighted `(d − p)/d`. The integrated regressors take the same triangle, so
    /// that both sides see one filter (the two periods' plain mean, a box, attenuates more
    /// at 20 Hz and biased τ low by 7 % at 30 ms).
    fn close_period(&mut self, m: usize, d: f32) {
        let mean = 1.0 / d;
        let triangle = mean * mean;
        let sums = &self.sums;
        for i in 0..m {
            self.pending.square[i] = sums.square[i] * mean;
            self.pending.speed[i] = sums.speed[i] * mean;
            self.pending.square_triangle[i] = self.triangle_early_square[i]
                + (d * sums.square[i] - sums.square_weighted[i]) * triangle;
            self.triangle_early_square[i] = sums.square_weighted[i] * triangle;
            for b in 0..3 {
                self.pending.gyroscopic_triangle[i][b] = self.triangle_early_gyroscopic[i][b]
                    + (d * sums.gyroscopic[i][b] - sums.gyroscopic_weighted[i][b]) * triangle;
                self.triangle_early_gyroscopic[i][b] = sums.gyroscopic_weighted[i][b] * triangle;
            }
        }
        self.sums = PeriodSums::default();
    }

    /// Drop the current period's sums (a non-finite sample in it).
    fn drop_period(&mut self) {
        self.sums = PeriodSums::default();
    }

    /// The pending period through the filters, and into the sums of products when learned.
    fn process(&mut self, m: usize, pole: f32, shared: &SharedPeriod) {
        let now = self.pending;
        let mut z = [0.0f32; REGRESSORS_MAX];
        let mut band = [0.0f32; MAX_MOTORS];
        for i in 0..m {
            let square = now.square_triangle[i];
            let gyroscopic = now.gyroscopic_triangle[i];
            if shared.start {
                self.square[i].reset_to(square);
                self.square_band[i].reset_to(now.square[i]);
                self.reaction[i].reset_to(now.speed[i]);
                for b in 0..3 {
                    self.gyroscopic[i][b].reset_to(gyroscopic[b]);
                }
                self.band_previous[i] = 0.0;
            }
            z[i] = self.square[i].update(square, pole);
            z[m + i] = self.reaction[i].update(now.speed[i], pole);
            for b in 0..3 {
                z[2 * m + 3 * i + b] = self.gyroscopic[i][b].update(gyroscopic[b], pole);
            }
            band[i] = self.square_band[i].update(now.square[i], pole);
        }
        if shared.learn {
            let n = 5 * m;
            add_outer_lower(&mut self.gram, &z[..n]);
            for (xy, rate) in self.rate_xy.iter_mut().zip(shared.rate) {
                for (xy, &zr) in xy[..n].iter_mut().zip(&z[..n]) {
                    *xy += f64::from(zr * rate);
                }
            }
            let b = &self.band_previous;
            add_outer_lower(&mut self.band_gram, &b[..m]);
            for r in 0..m {
                for t in 0..9 {
                    self.band_offset[r][t] += f64::from(b[r] * shared.offset_terms[t]);
                }
                for a in 0..3 {
                    self.band_force[r][a] += f64::from(b[r] * shared.force[a]);
                }
            }
        }
        self.band_previous = band;
    }

    /// Row `r` of part `part`'s regression into `solve` (its lower triangle and its
    /// outputs' products): rate axis `part` (0–2: `4m` unknowns, one output) or the specific
    /// force (3: `m + 9` unknowns, three outputs), given the shared offset terms' sums.
    fn load_row(&self, m: usize, shared: &SharedSums, part: usize, r: usize, solve: &mut Solve) {
        if part < 3 {
            let row = solve.index[r];
            let first = row * (row + 1) / 2;
            for (g, &column) in solve.gram[r][..=r].iter_mut().zip(&solve.index) {
                // Both orders: the regressors of the other axes' products interleave.
                *g = if column <= row {
                    self.gram[first + column]
                } else {
                    self.gram[column * (column + 1) / 2 + row]
                };
            }
            solve.xy[r][0] = self.rate_xy[part][row];
            return;
        }
        if r < m {
            let first = r * (r + 1) / 2;
            solve.gram[r][..=r].copy_from_slice(&self.band_gram[first..=first + r]);
            solve.xy[r] = self.band_force[r];
            return;
        }
        let t = r - m;
        for c in 0..m {
            solve.gram[r][c] = self.band_offset[c][t];
        }
        let first = t * (t + 1) / 2;
        solve.gram[r][m..=r].copy_from_slice(&shared.offset_gram[first..=first + t]);
        solve.xy[r] = shared.offset_force[t];
    }
}

/// `z zᵀ` added to the sums of squares `packed` (its lower triangle packed by rows: row `r`
/// holds columns `0..=r` from `r (r + 1)/2`), each product formed in `f32` and summed in `f64`,
/// row by row over slices: an index with an inclusive range per row took 20 Cortex-M7
/// instructions an entry, 16,500 of an octorotor candidate's 40 × 41 / 2 (`cargo xtask
/// bench-m7`). A `packed` shorter than `z`'s triangle takes the rows that fit.
fn add_outer_lower(packed: &mut [f64], z: &[f32]) {
    let mut rows = packed;
    for (r, &zr) in z.iter().enumerate() {
        let Some((row, rest)) = core::mem::take(&mut rows).split_at_mut_checked(r + 1) else {
            return;
        };
        for (sum, &zc) in row.iter_mut().zip(z) {
            *sum += f64::from(zr * zc);
        }
        rows = rest;
    }
}

/// The parts of one candidate's residuals ([`LagHypothesis::load_row`]): the three rate axes'
/// regressions and the specific force's.
const RESIDUAL_PARTS: usize = 4;

/// The candidates' regressions solved after the excitation's end ([`CommandSpeedModel::chosen`]
/// after them): 52, each loaded, factored and solved a few rows or columns at a time, as many
/// a sample as [`SCORING_WORK_PER_MOTOR`] allows.
pub const SCORING_PARTS: usize = RESIDUAL_PARTS * TAU_GRID_S.len();

/// Work of the candidates' regressions a sample may take after the excitation's end, per motor,
/// in f64 multiply-adds (and copies) of their Cholesky factorisations ([`Solve`]), each step
/// (a row loaded, a column factored, an output solved) counted [`SCORING_STEP_WORK`] more: the
/// budget is checked before each step, so a sample takes at most this and one step more, the
/// largest an octorotor's column of 16 × 17. 280 a motor is a quad's 1,120 and an octorotor's
/// 2,240, within the learner's 12,000 and 24,000 Cortex-M7 instructions a sample with the
/// rest of its work (issue 56, `cargo xtask bench-m7`: a unit costs 6–7 instructions; at 400 a
/// motor the quad's samples reached 13,152 and the octorotor's 28,800). All 52 regressions
/// then take a quad about 95 samples (48 ms), an octorotor about 170 (85 ms). A compute
/// budget per control period, not a window: the regressions are solved sooner the faster they
/// are. (Before: whole regressions a sample, 64,000 and 128,000 instructions a motor.)
pub const SCORING_WORK_PER_MOTOR: u32 = 280;

/// What one step of the candidates' regressions costs besides its multiply-adds, in the units
/// of [`SCORING_WORK_PER_MOTOR`]: the step's own bookkeeping.
const SCORING_STEP_WORK: u32 = 30;

/// One of the candidates' regressions being solved ([`CommandSpeedModel::score_next`]): its
/// sums of squares loaded row by row into a square array, factored (Cholesky, in place) column
/// by column, then its outputs solved, a budget of work a sample, resumed in the next.
#[derive(Clone, Debug)]
struct Solve {
    /// The sums of squares, lower triangle: the Cholesky factor as it is formed.
    gram: [[f64; AXIS_PARAMETERS_MAX]; AXIS_PARAMETERS_MAX],
    /// The products with the outputs (one column per output).
    xy: [[f64; 3]; AXIS_PARAMETERS_MAX],
    /// Rows loaded, then columns factored (each `0..=n`), then outputs solved.
    loaded: usize,
    factored: usize,
    solved: usize,
    /// The factor failed (not positive, or non-finite sums): nothing is explained.
    failed: bool,
    /// The part of each output's `Σ y²` the fit explains, `bᵀ (G + ridge·I)⁻¹ b`.
    explained: [f64; 3],
    /// A rate axis's regressors among the five per motor ([`axis_regressor`]).
    index: [usize; AXIS_PARAMETERS_MAX],
}

impl Solve {
    /// A regression starting.
    fn start(&mut self) {
        self.loaded = 0;
        self.factored = 0;
        self.solved = 0;
        self.failed = false;
        self.explained = [0.0; 3];
    }

    /// Column `j` of the Cholesky factor of `G + ridge·I` (`n × n`, lower triangle, rows
    /// `..n` loaded); its work in multiply-adds.
    fn factor_column(&mut self, j: usize, n: usize, ridge: f64) -> u32 {
        let n = n.min(AXIS_PARAMETERS_MAX);
        let j = j.min(n - 1);
        let (above, below) = self.gram.split_at_mut(j + 1);
        let row_j = &mut above[j];
        row_j[j] += ridge;
        // The products in order, subtracted one by one (the arithmetic of the whole solve
        // before it was spread, result for result).
        let (done, rest) = row_j.split_at_mut(j);
        let d = done.iter().fold(rest[0], |d, &l| d - l * l);
        // Not positive, or NaN from non-finite sums.
        if d.is_nan() || d <= 0.0 {
            self.failed = true;
            return j as u32;
        }
        let d = libm::sqrt(d);
        rest[0] = d;
        for row_i in &mut below[..n - j - 1] {
            let (left, right) = row_i.split_at_mut(j);
            let s = left.iter().zip(done.iter()).fold(right[0], |s, (a, b)| s - a * b);
            right[0] = s / d;
        }
        ((n - j) * (j + 1)) as u32
    }

    /// Output `o` through the factor: `|L⁻¹ b|²` into `explained[o]`; its work in
    /// multiply-adds.
    fn solve_output(&mut self, o: usize, n: usize) -> u32 {
        let n = n.min(AXIS_PARAMETERS_MAX);
        let mut w = [0.0f64; AXIS_PARAMETERS_MAX];
        let mut explained = 0.0;
        for (i, (row, xy)) in self.gram[..n].iter().zip(&self.xy).enumerate() {
            let s = row[..i].iter().zip(&w[..i]).fold(xy[o], |s, (a, b)| s - a * b);
            w[i] = s / row[i];
            explained += w[i] * w[i];
        }
        self.explained[o] = explained;
        (n * (n + 1) / 2) as u32
    }
}

/// Regressors of all three axes' regressions: five per motor (see [`LagHypothesis::gram`]).
const REGRESSORS_MAX: usize = 5 * MAX_MOTORS;

/// The largest regression solved: an axis's `4m`, or the specific force's `m + 9`.
const AXIS_PARAMETERS_MAX: usize = 4 * MAX_MOTORS;

/// Ridge on the diagonal of every sum of squares before the solve, per hertz of the
/// regression rate: a prior of zero on each coefficient whose weight against the data does not
/// depend on how often the regressions run (the sums grow with the rate). It regularises as
/// the recursive least squares this replaced did (`P₀ = 10⁶`, each axis regressed at a third
/// of 2 kHz: `10⁻⁶ / 667 Hz`). With a numerical ridge only (`10⁻⁹` of the diagonal) the lag
/// was exact on noise-free responses, but on 1,000 random worlds without speed telemetry its
/// 90th-percentile error grew from 16 to 20 ms and 96.4 % → 94.1 % of the crafts hovered: a
/// coefficient with little information fits the noise, differently for each candidate. The
/// absolute `10⁻⁶` of the recursive least squares, at 250 Hz 2.7 times its weight, moved τ
/// 6 % low on noise-free responses (docs/benchmarks.md); per hertz the figures hold at any
/// period.
const RIDGE_PER_HZ: f64 = 1.5e-9;

/// Regressor `j` of axis `a`'s regression among the five per motor: the squares and the
/// reactions (`j < 2m`), then each motor's products with the other two axes' rates.
fn axis_regressor(m: usize, a: usize, j: usize) -> usize {
    if j < 2 * m {
        return j;
    }
    let (i, other) = ((j - 2 * m) / 2, (j - 2 * m) % 2);
    2 * m + 3 * i + (a + 1 + other) % 3
}

/// The sums every candidate's specific-force regression shares (the offset terms do not depend
/// on the lag), and `Σ y²` of the six outputs.
#[derive(Clone, Copy, Debug)]
struct SharedSums {
    offset_gram: [f64; packed_len(9)],
    offset_force: [[f64; 3]; 9],
    rate_yy: [f64; 3],
    force_yy: [f64; 3],
    /// The ridge of the solves ([`RIDGE_PER_HZ`] at the regression rate).
    ridge: f64,
}

impl SharedSums {
    fn zero(regression_rate_hz: f32) -> Self {
        Self {
            offset_gram: [0.0; packed_len(9)],
            offset_force: [[0.0; 3]; 9],
            rate_yy: [0.0; 3],
            force_yy: [0.0; 3],
            ridge: RIDGE_PER_HZ * f64::from(regression_rate_hz),
        }
    }
}

/// The time constant from the angular response, and the modelled speeds (see the module doc).
#[derive(Clone, Debug)]
pub struct CommandSpeedModel {
    motors: usize,
    dt_s: f32,
    /// Samples per regression period ([`LAG_REGRESSION_PERIOD_S`]), and the sample of the
    /// current period (`0..period_samples`).
    period_samples: usize,
    phase: usize,
    /// Whether every sample of the current period was finite.
    period_finite: bool,
    /// Pole of the high-passes and of the low-pass `L` at the regression rate, `exp(−2π f_h T)`.
    pole: f32,
    /// The body rates, specific force and rate products summed over the current period.
    rate_sum: [f32; 3],
    force_sum: [f32; 3],
    products_sum: [f32; 6],
    /// Their filters at the regression rate (`F`), and the history the offset terms need: the
    /// filtered rates of the last two periods, the specific force and products of the last.
    rate_band: [Banded; 3],
    force_band: [Banded; 3],
    products_band: [Banded; 6],
    rate_history: [[f32; 3]; 2],
    force_previous: [f32; 3],
    products_previous: [f32; 6],
    /// Complete periods since the filters last restarted.
    warm_periods: u32,
    /// The period every candidate processes in turn.
    shared: SharedPeriod,
    shared_sums: SharedSums,
    /// Whether a motor has been pulsed ([`PULSE_COMMAND`]) since the reset.
    pulsed: bool,
    /// Bit i: motor i has been pulsed since the reset.
    pulsed_motors: u8,
    /// One regression per candidate time constant ([`TAU_GRID_S`]).
    hypotheses: [LagHypothesis; TAU_GRID_S.len()],
    /// Periods learned from.
    regressions: u32,
    /// Whether the excitation is over: the regressions stop, and the candidates are scored,
    /// a budget of regressions a sample ([`CommandSpeedModel::score_next`]).
    selected: bool,
    /// Regressions of the candidates solved so far ([`RESIDUAL_PARTS`] a candidate), and their
    /// residuals: the lag is chosen once all are.
    scored: usize,
    residuals: [[f32; 6]; TAU_GRID_S.len()],
    /// The regression being solved (part `scored % RESIDUAL_PARTS` of candidate
    /// `scored / RESIDUAL_PARTS`).
    solve: Solve,
    /// The time constant identified, s, and its standard deviation (the prior until chosen).
    tau_s: f32,
    tau_std_s: f32,
    /// Samples held back for the effectiveness regression: a ring, the oldest at `held_first`.
    held: [HeldSample; HELD_SAMPLES_MAX],
    held_first: usize,
    held_len: usize,
    /// Samples held before the oldest is released (0 once the excitation is over).
    hold_samples: usize,
    /// The modelled speed of each motor at the end of the oldest held sample's interval,
    /// fraction of full speed.
    held_speed: [f32; MAX_MOTORS],
    /// Control samples per held sample ([`hold_stride`]), the sums of the one being formed and
    /// how many it has.
    stride: usize,
    forming: HeldSample,
    formed: usize,
}

/// Samples in one regression period at `rate_hz` (at least one).
pub fn period_samples(rate_hz: f32) -> usize {
    samples_in(LAG_REGRESSION_PERIOD_S, rate_hz)
}

/// The rate the lag regressions run at, Hz: the rate of the samples over
/// [`period_samples`] (125 Hz at 2 kHz). Their low-pass is designed for it.
pub fn regression_rate_hz(rate_hz: f32) -> f32 {
    rate_hz / period_samples(rate_hz) as f32
}

impl CommandSpeedModel {
    /// Build a model for `motors` motors (clamped to 1..=8) at `rate_hz` in place at `this`,
    /// its regressions' signals through the low-pass `lowpass` (designed by the caller at
    /// [`LAG_LOWPASS_HZ`] for [`regression_rate_hz`]): the model is about 200 KB (the
    /// candidates' sums and the held samples) and is never a temporary on the stack.
    ///
    /// # Safety
    /// `this` must be valid for writes and aligned; every field is written.
    pub unsafe fn build_at(
        this: *mut Self,
        motors: usize,
        rate_hz: f32,
        lowpass: BiquadCoefficients,
    ) {
        use core::ptr::addr_of_mut;
        let motors = motors.clamp(1, MAX_MOTORS);
        let dt_s = 1.0 / rate_hz;
        let period = period_samples(rate_hz);
        let butterworth = Butterworth2::from_coefficients(lowpass);
        // SAFETY: the caller's; each field is written once through a raw field pointer. The
        // held samples are all zeros (0.0 and false), a valid value.
        unsafe {
            addr_of_mut!((*this).motors).write(motors);
            addr_of_mut!((*this).dt_s).write(dt_s);
            addr_of_mut!((*this).period_samples).write(period);
            addr_of_mut!((*this).phase).write(0);
            addr_of_mut!((*this).period_finite).write(true);
            let period_s = period as f32 * dt_s;
            let pole = libm::expf(-core::f32::consts::TAU * LAG_HIGH_PASS_HZ * period_s);
            addr_of_mut!((*this).pole).write(pole);
            addr_of_mut!((*this).rate_sum).write([0.0; 3]);
            addr_of_mut!((*this).force_sum).write([0.0; 3]);
            addr_of_mut!((*this).products_sum).write([0.0; 6]);
            addr_of_mut!((*this).rate_band).write([Banded::new(butterworth); 3]);
            addr_of_mut!((*this).force_band).write([Banded::new(butterworth); 3]);
            addr_of_mut!((*this).products_band).write([Banded::new(butterworth); 6]);
            addr_of_mut!((*this).rate_history).write([[0.0; 3]; 2]);
            addr_of_mut!((*this).force_previous).write([0.0; 3]);
            addr_of_mut!((*this).products_previous).write([0.0; 6]);
            addr_of_mut!((*this).warm_periods).write(0);
            let shared = SharedPeriod { processed: TAU_GRID_S.len(), ..SharedPeriod::default() };
            addr_of_mut!((*this).shared).write(shared);
            addr_of_mut!((*this).shared_sums).write(SharedSums::zero(regression_rate_hz(rate_hz)));
            addr_of_mut!((*this).pulsed).write(false);
            addr_of_mut!((*this).pulsed_motors).write(0);
            let hypotheses = addr_of_mut!((*this).hypotheses).cast::<LagHypothesis>();
            for (j, &tau) in TAU_GRID_S.iter().enumerate() {
                hypotheses.add(j).write(LagHypothesis::new(tau, dt_s, butterworth));
            }
            addr_of_mut!((*this).regressions).write(0);
            addr_of_mut!((*this).selected).write(false);
            addr_of_mut!((*this).scored).write(0);
            addr_of_mut!((*this).residuals).write([[0.0; 6]; TAU_GRID_S.len()]);
            // Zero bytes are a valid solve (plain numbers, `false`), started.
            addr_of_mut!((*this).solve).write_bytes(0, 1);
            addr_of_mut!((*this).tau_s).write(TAU_PRIOR_S);
            addr_of_mut!((*this).tau_std_s).write(TAU_PRIOR_STD_S);
            addr_of_mut!((*this).held).write_bytes(0, 1);
            addr_of_mut!((*this).held_first).write(0);
            addr_of_mut!((*this).held_len).write(0);
            addr_of_mut!((*this).hold_samples).write(Self::hold_samples(rate_hz));
            addr_of_mut!((*this).held_speed).write([0.0; MAX_MOTORS]);
            addr_of_mut!((*this).stride).write(hold_stride(rate_hz));
            addr_of_mut!((*this).forming).write(HeldSample::default());
            addr_of_mut!((*this).formed).write(0);
        }
    }

    fn hold_samples(rate_hz: f32) -> usize {
        ((EFFECTIVENESS_HOLD_S * held_rate_hz(rate_hz)) as usize).min(HELD_SAMPLES_MAX)
    }

    /// Forget everything (a new identification).
    pub fn reset(&mut self) {
        for h in &mut self.hypotheses {
            h.reset();
        }
        self.phase = 0;
        self.period_finite = true;
        self.rate_sum = [0.0; 3];
        self.force_sum = [0.0; 3];
        self.products_sum = [0.0; 6];
        self.warm_periods = 0;
        self.shared = SharedPeriod { processed: TAU_GRID_S.len(), ..SharedPeriod::default() };
        self.shared_sums = SharedSums::zero(regression_rate_hz(1.0 / self.dt_s));
        self.regressions = 0;
        self.selected = false;
        self.scored = 0;
        self.solve.start();
        self.tau_s = TAU_PRIOR_S;
        self.tau_std_s = TAU_PRIOR_STD_S;
        self.pulsed = false;
        self.pulsed_motors = 0;
        self.held_first = 0;
        self.held_len = 0;
        self.hold_samples = Self::hold_samples(1.0 / self.dt_s);
        self.held_speed = [0.0; MAX_MOTORS];
        self.forming = HeldSample::default();
        self.formed = 0;
    }

    /// Hold a sample back for the effectiveness regression (the commands driving the motors at
    /// it and whether the ESCs run them), in the mean over [`HOLD_INTERVAL_S`] it is part of.
    /// The effectiveness regression never forgets, so what it learned from speeds modelled
    /// with the lag of the first pulses, still far off, would stay: it learns instead from the
    /// end of the excitation (every motor pulsed and all back below [`PULSE_COMMAND`], seen by
    /// [`CommandSpeedModel::update`]), or at most [`EFFECTIVENESS_HOLD_S`] behind, from speeds
    /// modelled with the lag identified over every pulse. A full ring drops its oldest sample.
    pub fn hold(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        driving: &[f32; MAX_MOTORS],
        running: bool,
        carried: [f32; 3],
    ) {
        let mut target = [0.0; MAX_MOTORS];
        for i in 0..self.motors {
            target[i] = Self::target_speed(driving[i], running);
        }
        let Some(held) = self.form(gyro_rad_s, accel_mps2, &target, carried) else { return };
        let index = (self.held_first + self.held_len) % HELD_SAMPLES_MAX;
        self.held[index] = held;
        if self.held_len < HELD_SAMPLES_MAX {
            self.held_len += 1;
        } else {
            self.held_first = (self.held_first + 1) % HELD_SAMPLES_MAX;
        }
    }

    /// One sample of the free fall before the excitation (motors off) into the interval's
    /// mean: the interval's mean once it is complete, its speeds zero, for the effectiveness
    /// regression's filters to settle on ([`super::Learner::prime`]), never held.
    pub fn prime(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        carried: [f32; 3],
    ) -> Option<ReleasedSample> {
        let held = self.form(gyro_rad_s, accel_mps2, &[0.0; MAX_MOTORS], carried)?;
        Some(ReleasedSample {
            gyro_rad_s: held.gyro_rad_s,
            accel_mps2: held.accel_mps2,
            speeds_rad_s: [0.0; MAX_MOTORS],
            carried: held.carried,
        })
    }

    /// One control sample into the interval's sums: the interval's means once it is complete.
    fn form(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        target: &[f32; MAX_MOTORS],
        carried: [f32; 3],
    ) -> Option<HeldSample> {
        self.forming.add(gyro_rad_s, accel_mps2, target, carried);
        self.formed += 1;
        if self.formed < self.stride {
            return None;
        }
        let held = self.forming.mean(self.formed);
        self.forming = HeldSample::default();
        self.formed = 0;
        Some(held)
    }

    /// The oldest held sample, its speeds modelled with the lag identified, once the lag has
    /// been chosen at the end of the excitation ([`CommandSpeedModel::chosen`]). Each motor's
    /// speed is the root mean square over the interval of the first-order lag's exact response
    /// to the interval's mean target, control sample by control sample, so that its square is
    /// the interval's mean of `x²` as the rates and the specific force are its means.
    pub fn release(&mut self) -> Option<ReleasedSample> {
        if self.held_len == 0 || self.held_len <= self.hold_samples || !self.chosen() {
            return None;
        }
        let sample = self.held[self.held_first];
        self.held_first = (self.held_first + 1) % HELD_SAMPLES_MAX;
        self.held_len -= 1;
        // x_k = u + e a^k after k control samples (a = exp(−dt/τ), e the start's distance
        // from the target u): over k = 1..D, the means of a^k and a^2k.
        let step = self.dt_s / self.tau_s;
        let d = self.stride as f32;
        let a = libm::expf(-step);
        let a_end = libm::expf(-d * step);
        let mean_a = a * libm::expm1f(-d * step) / (d * libm::expm1f(-step));
        let mean_a2 = a * a * libm::expm1f(-2.0 * d * step) / (d * libm::expm1f(-2.0 * step));
        let mut speeds_rad_s = [0.0; MAX_MOTORS];
        for i in 0..self.motors {
            let u = sample.target[i];
            let e = self.held_speed[i] - u;
            let square = u * u + 2.0 * u * e * mean_a + e * e * mean_a2;
            self.held_speed[i] = u + e * a_end;
            speeds_rad_s[i] = NOMINAL_FULL_SPEED_RAD_S * crate::math::sqrt(square.max(0.0));
        }
        Some(ReleasedSample {
            gyro_rad_s: sample.gyro_rad_s,
            accel_mps2: sample.accel_mps2,
            speeds_rad_s,
            carried: sample.carried,
        })
    }

    /// Whether samples of the excitation are still to be released to the effectiveness
    /// regression: until the excitation is over and every held sample released.
    pub fn pending(&self) -> bool {
        self.hold_samples > 0 || self.held_len > 0
    }

    /// The nominal curve's steady speed for command δ, fraction of full speed (0 while the ESC
    /// has not yet started the motor, `running` false).
    pub fn target_speed(command: f32, running: bool) -> f32 {
        Curve::NOMINAL.target(command, running)
    }

    /// One sample: the body rates (rad/s, IMU axes), the commands driving the motors, whether
    /// the ESCs run them, and whether to learn from it (else only the filters run). Each
    /// sample sums the regressors' inputs and advances a share of the candidates through the
    /// last period ([`LAG_REGRESSION_PERIOD_S`]): the work is the same on every sample.
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        driving: &[f32; MAX_MOTORS],
        running: bool,
        learn: bool,
    ) {
        if self.selected {
            // The regressions have stopped: the candidates are scored, a share a sample.
            if !self.chosen() {
                self.score_next();
            }
            return;
        }
        self.process_share();
        let m = self.motors;
        let mut targets = [0.0; MAX_MOTORS];
        let mut all_low = true;
        for i in 0..m {
            let d = if driving[i].is_finite() { driving[i] } else { 0.0 };
            if d > PULSE_COMMAND {
                self.pulsed = true;
                self.pulsed_motors |= 1 << i;
                all_low = false;
            }
            targets[i] = Self::target_speed(d, running);
        }
        // Every motor pulsed and all back below a pulse: the last pulse's ramp has ended, the
        // excitation ends within its end margin (`excitation::END_MARGIN_S`), and the
        // effectiveness regression catches up with the held samples before the controller
        // engages on its model.
        if all_low && u16::from(self.pulsed_motors) == (1u16 << m) - 1 {
            // The regressions stop here: the candidates finish the last period's pending
            // processing and are scored in the samples that follow. (Going on through the last
            // pulse's tail, 20 ms, changed nothing over 1,000 random worlds but the wait:
            // docs/benchmarks.md.)
            self.hold_samples = 0;
            self.selected = true;
            return;
        }
        let finite = gyro_rad_s.iter().chain(&accel_mps2).all(|w| w.is_finite());
        let gyro = finite.then_some(gyro_rad_s);
        let place = self.phase as f32;
        for h in &mut self.hypotheses {
            h.advance(m, &targets, gyro, place);
        }
        if finite {
            let w = gyro_rad_s;
            let products =
                [w[0] * w[0], w[1] * w[1], w[2] * w[2], w[0] * w[1], w[0] * w[2], w[1] * w[2]];
            for k in 0..3 {
                self.rate_sum[k] += w[k];
                self.force_sum[k] += accel_mps2[k];
            }
            for (sum, p) in self.products_sum.iter_mut().zip(products) {
                *sum += p;
            }
        } else {
            self.period_finite = false;
        }
        self.phase += 1;
        if self.phase >= self.period_samples {
            self.phase = 0;
            self.close_period(learn && self.pulsed);
        }
    }

    /// The end of a period: the shared signals through their filters, each candidate's
    /// averages pending (processed over the next period's samples, [`Self::process_share`]).
    /// A period with a non-finite sample is dropped and the filters restart after it.
    fn close_period(&mut self, learn: bool) {
        // Whatever of the last period a candidate has not processed yet (none when the period
        // is at least as many samples as the candidates).
        self.process_candidates(TAU_GRID_S.len());
        let m = self.motors;
        let finite = self.period_finite;
        self.period_finite = true;
        if !finite {
            for h in &mut self.hypotheses {
                h.drop_period();
            }
            self.rate_sum = [0.0; 3];
            self.force_sum = [0.0; 3];
            self.products_sum = [0.0; 6];
            self.warm_periods = 0;
            return;
        }
        let samples = self.period_samples as f32;
        for h in &mut self.hypotheses {
            h.close_period(m, samples);
        }
        let scale = 1.0 / samples;
        let start = self.warm_periods == 0;
        let pole = self.pole;
        let mut rate = [0.0; 3];
        let mut force = [0.0; 3];
        for k in 0..3 {
            let (w, f) = (self.rate_sum[k] * scale, self.force_sum[k] * scale);
            if start {
                self.rate_band[k].reset_to(w);
                self.force_band[k].reset_to(f);
            }
            rate[k] = self.rate_band[k].update(w, pole);
            force[k] = self.force_band[k].update(f, pole);
        }
        let mut products = [0.0; 6];
        for j in 0..6 {
            let p = self.products_sum[j] * scale;
            if start {
                self.products_band[j].reset_to(p);
            }
            products[j] = self.products_band[j].update(p, pole);
        }
        self.rate_sum = [0.0; 3];
        self.force_sum = [0.0; 3];
        self.products_sum = [0.0; 6];
        // The specific force one period back, with the angular acceleration there: the central
        // difference of the filtered rates over the two periods around it.
        let period_s = self.period_samples as f32 * self.dt_s;
        let mut offset_terms = [0.0; 9];
        for a in 0..3 {
            offset_terms[a] = (rate[a] - self.rate_history[1][a]) / (2.0 * period_s);
        }
        offset_terms[3..].copy_from_slice(&self.products_previous);
        let learn = learn && self.warm_periods >= 2;
        self.shared = SharedPeriod {
            rate,
            force: self.force_previous,
            offset_terms,
            learn,
            start,
            processed: 0,
        };
        self.rate_history = [rate, self.rate_history[0]];
        self.force_previous = force;
        self.products_previous = products;
        self.warm_periods = self.warm_periods.saturating_add(1);
        if learn {
            let sums = &mut self.shared_sums;
            add_outer_lower(&mut sums.offset_gram, &offset_terms);
            for t in 0..9 {
                for a in 0..3 {
                    sums.offset_force[t][a] += f64::from(offset_terms[t] * self.shared.force[a]);
                }
            }
            for a in 0..3 {
                sums.rate_yy[a] += f64::from(rate[a]) * f64::from(rate[a]);
                sums.force_yy[a] +=
                    f64::from(self.shared.force[a]) * f64::from(self.shared.force[a]);
            }
            self.regressions += 1;
        }
    }

    /// This sample's share of the candidates through the pending period: all of them over the
    /// period's samples but its last, which closes the period (the shared filters and sums).
    fn process_share(&mut self) {
        let n = TAU_GRID_S.len();
        let spread = self.period_samples.saturating_sub(1).max(1);
        let through = (self.phase + 1) * n / spread;
        self.process_candidates(through.min(n));
    }

    /// The candidates up to `through` (exclusive) through the pending period.
    fn process_candidates(&mut self, through: usize) {
        let (m, pole) = (self.motors, self.pole);
        while self.shared.processed < through {
            let shared = self.shared;
            self.hypotheses[shared.processed].process(m, pole, &shared);
            self.shared.processed += 1;
        }
    }

    /// Whether the lag has been chosen: every candidate scored after the excitation's end.
    pub fn chosen(&self) -> bool {
        self.scored == SCORING_PARTS
    }

    /// The candidates' regressions solved for their residuals (three of `4m` unknowns and one
    /// of `m + 9` per candidate) after the excitation's end, a step at a time (a row loaded, a
    /// column factored, an output solved: [`Solve`]) while the sample's budget of work
    /// ([`SCORING_WORK_PER_MOTOR`]) lasts, at least one step a sample, so that no sample
    /// carries more than the learner's budget (all 52 in one sample were 880,000 Cortex-M7
    /// instructions on a quad, a whole regression up to 61,000 on an octorotor); with the
    /// last, the lag is chosen ([`Self::choose`]).
    fn score_next(&mut self) {
        let n = TAU_GRID_S.len();
        if self.shared.processed < n {
            // First the last period's candidates not yet through it, one a sample.
            self.process_candidates(self.shared.processed + 1);
            return;
        }
        if self.regressions == 0 {
            // Nothing learned: the prior stays.
            self.scored = SCORING_PARTS;
            return;
        }
        let m = self.motors;
        let budget = SCORING_WORK_PER_MOTOR * m as u32;
        let ridge = self.shared_sums.ridge;
        let mut spent = 0;
        while !self.chosen() && spent < budget {
            let (j, part) = (self.scored / RESIDUAL_PARTS, self.scored % RESIDUAL_PARTS);
            let (size, outputs) = if part < 3 { (4 * m, 1) } else { (m + 9, 3) };
            let solve = &mut self.solve;
            if solve.loaded < size {
                let r = solve.loaded;
                if r == 0 && part < 3 {
                    for (k, index) in solve.index[..size].iter_mut().enumerate() {
                        *index = axis_regressor(m, part, k);
                    }
                    spent += SCORING_STEP_WORK;
                }
                self.hypotheses[j].load_row(m, &self.shared_sums, part, r, solve);
                solve.loaded += 1;
                spent += SCORING_STEP_WORK + r as u32 + 1;
            } else if solve.factored < size && !solve.failed {
                spent += SCORING_STEP_WORK + solve.factor_column(solve.factored, size, ridge);
                solve.factored += 1;
            } else if solve.solved < outputs && !solve.failed {
                spent += SCORING_STEP_WORK + solve.solve_output(solve.solved, size);
                solve.solved += 1;
            } else {
                // Solved (or failed: nothing explained): the residuals, `Σ y²` less the part
                // the fit explains.
                let shared = &self.shared_sums;
                let out = &mut self.residuals[j];
                if part < 3 {
                    out[part] = (shared.rate_yy[part] - solve.explained[0]).max(0.0) as f32;
                } else {
                    for a in 0..3 {
                        out[3 + a] = (shared.force_yy[a] - solve.explained[a]).max(0.0) as f32;
                    }
                }
                solve.start();
                self.scored += 1;
            }
        }
        if self.chosen() {
            self.choose();
        }
    }

    /// Choose the time constant whose regressions explain the response best (the least-squares
    /// residual, per output relative to the candidates' mean, as they all see the same rates
    /// and forces, summed over the six), refined between the grid's points by a parabola through
    /// the best and its neighbours in `ln τ`. Its standard deviation from the parabola's
    /// curvature: the residual grows by one error variance one σ away.
    fn choose(&mut self) {
        let n = TAU_GRID_S.len();
        let residuals = self.residuals;
        let mut mean = [0.0f32; 6];
        for r in &residuals {
            for a in 0..6 {
                mean[a] += r[a] / n as f32;
            }
        }
        let score = |r: &[f32; 6]| -> f32 {
            (0..6).filter(|&a| mean[a] > 0.0).map(|a| r[a] / mean[a]).sum()
        };
        let scores: [f32; TAU_GRID_S.len()] = core::array::from_fn(|j| score(&residuals[j]));
        let mut best = 0;
        for j in 1..n {
            if scores[j] < scores[best] {
                best = j;
            }
        }
        let ln = |j: usize| libm::logf(TAU_GRID_S[j]);
        let (mut ln_tau, mut std_ln) = (ln(best), f32::INFINITY);
        if best > 0 && best + 1 < n {
            // Equal steps in ln τ but for the last: the parabola through three points.
            let (u0, u1, u2) = (ln(best - 1), ln(best), ln(best + 1));
            let (s0, s1, s2) = (scores[best - 1], scores[best], scores[best + 1]);
            let d01 = (s1 - s0) / (u1 - u0);
            let d12 = (s2 - s1) / (u2 - u1);
            let curvature = (d12 - d01) / (u2 - u0);
            if curvature > 0.0 {
                let vertex = 0.5 * (u0 + u1) - d01 / (2.0 * curvature);
                ln_tau = crate::math::clamp(vertex, u0, u2);
                // One error variance of the relative scores: the best's score over the
                // regressions.
                if self.regressions > 0 {
                    let variance = s1 / self.regressions as f32;
                    std_ln = libm::sqrtf(variance / curvature);
                }
            }
        }
        let tau = libm::expf(ln_tau);
        self.tau_s = crate::math::clamp(tau, TAU_MIN_S, TAU_MAX_S);
        self.tau_std_s = (self.tau_s * std_ln).min(TAU_MAX_S);
    }

    /// The time constant identified so far, s.
    pub fn tau_s(&self) -> f32 {
        self.tau_s
    }

    /// The motor model the controller flies: the nominal curve with the identified lag.
    pub fn motor_model(&self) -> MotorModel {
        nominal_motor(self.tau_s, self.tau_std_s)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// A tumbling body whose rates answer four motors through torques `C x²`, and its specific
    /// force through the thrust `Σ c x²`; each motor's speed `x` a first-order lag `tau` towards
    /// `curve(δ)` (fraction of full speed); the excitation's own schedule (no speeds reported:
    /// its pulses scaled to `UNREPORTED_TAU_S`). Returns the identified τ.
    fn identify(tau: f32, curve: impl Fn(f32) -> f32) -> f32 {
        identify_with_gap(tau, curve, None)
    }

    /// The test quad's angular acceleration per squared speed, per axis and motor.
    const QUAD_TORQUE_PER_SPEED2: [[f32; 4]; 3] = [
        [300.0, -300.0, 300.0, -300.0],
        [300.0, 300.0, -300.0, -300.0],
        [40.0, -40.0, -40.0, 40.0],
    ];
    /// Its tumble at the excitation's start, rad/s.
    const QUAD_TUMBLE_RAD_S: [f32; 3] = [3.0, -2.0, 1.0];

    /// A quad's model at `rate_hz`, on the heap.
    fn quad_model(rate_hz: f32) -> std::boxed::Box<CommandSpeedModel> {
        let lowpass =
            BiquadCoefficients::butterworth_lowpass(LAG_LOWPASS_HZ, regression_rate_hz(rate_hz))
                .unwrap();
        let mut slot = std::boxed::Box::<CommandSpeedModel>::new_uninit();
        // SAFETY: a fresh, aligned allocation, every field written by `build_at`.
        unsafe {
            CommandSpeedModel::build_at(slot.as_mut_ptr(), 4, rate_hz, lowpass);
            slot.assume_init()
        }
    }

    /// As [`identify`], the gyro reading NaN on sample `nan_at`.
    fn identify_with_gap(tau: f32, curve: impl Fn(f32) -> f32, nan_at: Option<usize>) -> f32 {
        use crate::learner::excitation::{Excitation, ExcitationConfig};
        let rate_hz = 2000.0;
        let dt = 1.0 / rate_hz;
        let mut model = quad_model(rate_hz);
        let mut excitation = Excitation::new(ExcitationConfig::default(), 4);
        let c = QUAD_TORQUE_PER_SPEED2;
        let (mut speed, mut rate) = ([0.0f32; 4], QUAD_TUMBLE_RAD_S);
        let mut n = 0;
        let mut finished = false;
        loop {
            // After the excitation the motors idle while the candidates are scored.
            let out = excitation.update(rate, None, dt);
            finished |= out.finished;
            if finished && model.chosen() {
                break;
            }
            assert!(n < 4000, "no lag chosen 2 s in");
            let commands = if finished { [0.0; MAX_MOTORS] } else { out.commands };
            for i in 0..4 {
                let target = curve(commands[i]);
                speed[i] += (target - speed[i]) * (1.0 - libm::expf(-dt / tau));
            }
            for a in 0..3 {
                let alpha: f32 = (0..4).map(|i| c[a][i] * speed[i] * speed[i]).sum::<f32>();
                rate[a] += alpha * dt;
            }
            let thrust: f32 = (0..4).map(|i| 10.0 * speed[i] * speed[i]).sum();
            let gyro = if nan_at == Some(n) { [f32::NAN; 3] } else { rate };
            n += 1;
            model.update(gyro, [0.0, 0.0, -thrust], &commands, true, true);
            model.hold(gyro, [0.0, 0.0, -thrust], &commands, true, [0.0; 3]);
        }
        // The lag is chosen: the held samples go.
        assert!(model.release().is_some());
        model.tau_s()
    }

    /// G1 of a tumbling quad (torques `C x²`, thrust `Σ 10 x²`, the excitation's own schedule
    /// with the lag `tau` and the nominal curve) learned by the effectiveness regression: at the
    /// full 2 kHz rate from the true speeds; at the full rate from the speeds modelled with the
    /// lag identified (every sample held, as before the held samples were means); from the held
    /// samples (the means over [`HOLD_INTERVAL_S`], released once the lag is chosen) at their
    /// rate. The relative RMS errors of the force and torque blocks of each, and the control
    /// samples from the lag's choice to the last held sample released, one a sample.
    fn g1_full_rate_and_held(tau: f32) -> ([f32; 2], [f32; 2], [f32; 2], usize) {
        use crate::learner::effectiveness::{EffectivenessEstimator, EffectivenessSetup};
        use crate::learner::excitation::{Excitation, ExcitationConfig};
        use crate::learner::rls::RlsConfig;
        use crate::learner::EFFECTIVENESS_CUTOFF_HZ;
        let rate_hz = 2000.0;
        let dt = 1.0 / rate_hz;
        let mut model = quad_model(rate_hz);
        let rls = RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 };
        let estimator = |rate_hz: f32| {
            let filter =
                BiquadCoefficients::butterworth_lowpass(EFFECTIVENESS_CUTOFF_HZ, rate_hz).unwrap();
            // The speeds modelled at the end of each sample, the rates its mean over it.
            std::boxed::Box::new(EffectivenessEstimator::new(EffectivenessSetup {
                motors: 4,
                rate_hz,
                filter,
                r_imu_m: [0.0; 3],
                speed_lag_s: 0.0,
                rls,
            }))
        };
        let mut full = estimator(rate_hz);
        let mut modelled = estimator(rate_hz);
        let mut held = estimator(held_rate_hz(rate_hz));
        let mut samples = std::vec::Vec::new();
        let mut excitation = Excitation::new(ExcitationConfig::default(), 4);
        let c = QUAD_TORQUE_PER_SPEED2;
        let (mut speed, mut rate) = ([0.0f32; 4], QUAD_TUMBLE_RAD_S);
        let (mut finished, mut chosen_at, mut n) = (false, None, 0);
        loop {
            let out = excitation.update(rate, None, dt);
            finished |= out.finished;
            if chosen_at.is_some() && !model.pending() {
                break;
            }
            assert!(n < 4000, "not caught up 2 s in");
            let commands = if finished { [0.0; MAX_MOTORS] } else { out.commands };
            let mut mean_rate = [0.0f32; 3];
            for i in 0..4 {
                let target = CommandSpeedModel::target_speed(commands[i], true);
                speed[i] += (target - speed[i]) * (1.0 - libm::expf(-dt / tau));
            }
            for a in 0..3 {
                let alpha: f32 = (0..4).map(|i| c[a][i] * speed[i] * speed[i]).sum::<f32>();
                mean_rate[a] = rate[a] + 0.5 * alpha * dt;
                rate[a] += alpha * dt;
            }
            let thrust: f32 = (0..4).map(|i| 10.0 * speed[i] * speed[i]).sum();
            let accel = [0.0, 0.0, -thrust];
            n += 1;
            let speeds: [f32; 4] = speed.map(|x| NOMINAL_FULL_SPEED_RAD_S * x);
            full.update(mean_rate, accel, &speeds);
            model.update(mean_rate, accel, &commands, true, true);
            model.hold(mean_rate, accel, &commands, true, [0.0; 3]);
            samples.push((mean_rate, accel, commands));
            if model.chosen() && chosen_at.is_none() {
                chosen_at = Some(n);
            }
            if let Some(sample) = model.release() {
                held.update(sample.gyro_rad_s, sample.accel_mps2, &sample.speeds_rad_s[..4]);
            }
        }
        // Every sample, its speeds modelled at the full rate with the lag identified.
        let lag = 1.0 - libm::expf(-dt / model.tau_s());
        let mut x = [0.0f32; 4];
        for (gyro, accel, commands) in &samples {
            for i in 0..4 {
                x[i] += (CommandSpeedModel::target_speed(commands[i], true) - x[i]) * lag;
            }
            modelled.update(*gyro, *accel, &x.map(|x| NOMINAL_FULL_SPEED_RAD_S * x));
        }
        let errors = |estimator: &EffectivenessEstimator| {
            let g1 = estimator.g1_per_speed2();
            let scale = 1e-6;
            let block = |rows: core::ops::Range<usize>, truth: &dyn Fn(usize, usize) -> f32| {
                let (mut err, mut norm) = (0.0, 0.0);
                for k in rows.clone() {
                    for i in 0..4 {
                        let t = truth(k - rows.start, i) * scale;
                        err += (g1[k][i] - t) * (g1[k][i] - t);
                        norm += t * t;
                    }
                }
                libm::sqrtf(err / norm)
            };
            let force = block(0..3, &|k, _| if k == 2 { -10.0 } else { 0.0 });
            let torque = block(3..6, &|k, i| c[k][i]);
            [force, torque]
        };
        (errors(&full), errors(&modelled), errors(&held), n - chosen_at.unwrap())
    }

    #[test]
    fn g1_from_the_held_samples_is_the_full_rate_one_and_the_backlog_goes_within_its_time() {
        // The world's lags (15–45 ms scaled by the craft's size). The held samples (the means
        // over 4 ms, learned from at 250 Hz once the lag is chosen) give G1 within 1.5
        // percentage points of the full-rate regression on the speeds modelled with the same
        // lag, force and torque blocks alike; both are off the true speeds' by what the lag's
        // error does. Measured (true speeds / modelled, full rate / held): force 0.02 / 2.57 /
        // 2.43 %, torque 0.07 / 2.04 / 3.06 % at 15 ms; 0.05 / 1.93 / 1.57 % and 0.07 / 1.58 /
        // 2.41 % at 30 ms; 0.54 / 8.67 / 7.83 % and 0.20 / 7.72 / 8.31 % at 60 ms. Caught up
        // 93 control samples (46.5 ms) after the lag's choice.
        for tau in [0.015, 0.03, 0.06] {
            let (truth, full, held, catch_up) = g1_full_rate_and_held(tau);
            std::eprintln!(
                "τ {} ms: force {:.2} / {:.2} / {:.2} %, torque {:.2} / {:.2} / {:.2} % \
                 (true speeds / modelled, full rate / held); caught up {catch_up} samples after \
                 the lag's choice",
                tau * 1e3,
                truth[0] * 1e2,
                full[0] * 1e2,
                held[0] * 1e2,
                truth[1] * 1e2,
                full[1] * 1e2,
                held[1] * 1e2
            );
            for block in 0..2 {
                assert!(held[block] < full[block] + 0.015, "τ {tau}: {held:?} against {full:?}");
            }
            // The backlog: at most the ring's samples and one more in every eight control
            // samples, one released a sample.
            let stride = hold_stride(2000.0);
            assert!(catch_up * (stride - 1) <= HELD_SAMPLES_MAX * stride, "{catch_up}");
        }
    }

    #[test]
    fn a_non_finite_sample_costs_its_period_and_nothing_else() {
        // The gyro reads NaN once, in the middle of the pulses (sample 700, 0.35 s in) or at a
        // period's last sample: its period is dropped, the filters restart after it, and the
        // lag is found as without it (within 5 % of the truth, as below).
        for nan_at in [700, 703, 704] {
            let tau = 0.03;
            let found =
                identify_with_gap(tau, |d| CommandSpeedModel::target_speed(d, true), Some(nan_at));
            assert!((found / tau - 1.0).abs() < 0.05, "NaN at {nan_at}: τ {found}");
        }
    }

    #[test]
    fn the_lag_is_identified_from_the_body_response_across_the_range() {
        // The world's lags (`sim::airframe`: 15–45 ms scaled by the craft's size, ±10 % per
        // motor) and idles (3–15 % of full speed).
        // As the learner runs: the regressions stop at the last pulse's end (the test once
        // learned on through the schedule's end margin, which flattered every figure below).
        for tau in [0.015, 0.03, 0.06] {
            // The nominal curve itself: within 6 % (1.2 % at 15 ms, 5.4 % low at 60 ms today).
            let nominal = identify(tau, |d| CommandSpeedModel::target_speed(d, true));
            assert!((nominal / tau - 1.0).abs() < 0.06, "τ {tau}: {nominal}");
            for idle in [0.03, 0.15] {
                // Concave curves like the nominal one (speed ∝ √δ, δ^0.6, κ 0.5) at either end
                // of the idle range: within 45 % (worst today at idle 3 %: +24 % at 15 ms with
                // √δ, +27 % at 30 ms and −40 % at 60 ms with κ 0.5; at idle 15 % within 18 %).
                for p in [0.5, 0.6] {
                    let found = identify(tau, |d| idle + (1.0 - idle) * libm::powf(d, p));
                    assert!(
                        (found / tau - 1.0).abs() < 0.45,
                        "τ {tau}, δ^{p}, idle {idle}: {found}"
                    );
                }
                let paper = |d: f32| idle + (1.0 - idle) * (0.5 * d + 0.5 * libm::sqrtf(d));
                let found = identify(tau, paper);
                assert!((found / tau - 1.0).abs() < 0.45, "τ {tau}, κ 0.5, idle {idle}: {found}");
                // Convex ones (speed ∝ δ, δ^1.4), unlike the nominal curve: τ comes out low, by
                // up to half (the curve is not identified: the module doc), never much high
                // (at most 25 % today, at 15 ms with δ and idle 15 %: a lag under two of the
                // regression's 8 ms periods).
                for p in [1.0, 1.4] {
                    let found = identify(tau, |d| idle + (1.0 - idle) * libm::powf(d, p));
                    let within = found > 0.45 * tau && found < 1.3 * tau;
                    assert!(within, "τ {tau}, δ^{p}, idle {idle}: {found}");
                }
            }
        }
    }
}
