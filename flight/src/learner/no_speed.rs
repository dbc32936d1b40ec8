//! Identification without speed telemetry (issue 32): the motors' lag from the body's response,
//! and a modelled speed from the commands in place of the measured one
//! (docs/algorithms/learner.md, "Without speed telemetry"). A prototype: the simulator flies it
//! (`fly monte-carlo --no-speed-telemetry`); no board arms without speeds yet
//! (`firmware::app::ControlSettings::arm_without_speeds`), and the board builds without it.
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
//! [`TAU_GRID_S`] (8–100 ms, 22 % apart) models the speeds with its τ and runs these
//! regressions by recursive least squares, and τ is the candidate whose least-squares residual
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
//! **The effectiveness regression waits for the lag.** It never forgets, so what it learned
//! from speeds modelled with the lag of the first pulses, still far off, would stay. The
//! samples (rates, specific force, commands) are held in a ring ([`EFFECTIVENESS_HOLD_S`]) and
//! released to it at the end of the excitation (every motor pulsed and all back below
//! [`PULSE_COMMAND`]: within the schedule's 10 ms end margin, before the controller engages),
//! their speeds modelled with the lag identified over every pulse.
//!
//! **Assumptions, stated** (the simulator's randomised world, `sim::world`, draws across them):
//! - one time constant for every motor (the world's motors differ by ±10 %), in
//!   [`TAU_MIN_S`]–[`TAU_MAX_S`];
//! - the ESC curve is unknown and not identified: the nominal curve ([`NOMINAL_KAPPA`],
//!   [`NOMINAL_IDLE_FRACTION`]) sits in the middle of the families seen (the papers' κ 0–1;
//!   thrust `kδ² + (1 − k)δ`; speed `δ^p`, p 0.6–1.4; idle 3–15 % of full speed). A curve unlike
//!   it biases τ and, through the modelled speeds, G1 (a bank of eight candidate curves chosen
//!   by the same residuals did not help: docs/benchmarks.md);
//! - gyro noise up to 3× the ICM-42688-P's and rotor vibration: filtered by the same 20 Hz
//!   low-pass as the effectiveness signals.
//!
//! Cost (host only so far): per sample the filters and, for each of the 13 candidates, one body
//! axis's regression of `4m` parameters and the specific force's of `m + 9` (three outputs);
//! the ring holds 1,700 samples (≈ 100 KB). Far more than the board's learner budget: see
//! docs/benchmarks.md for what it would take.

// Index loops are kept where they run over axes and motors side by side (several arrays per
// index), as in `effectiveness`.
#![allow(clippy::needless_range_loop)]

use super::motor_model::MotorModel;
use super::rls::{packed_len, Rls, RlsConfig};
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
/// excitation (`ExcitationConfig::max_s`, 0.8 s) and its end margin, so that G1 is learned from
/// speeds modelled with the lag identified over every pulse (see [`CommandSpeedModel::hold`]).
pub const EFFECTIVENESS_HOLD_S: f32 = 0.85;
/// Most samples held: [`EFFECTIVENESS_HOLD_S`] at 2 kHz, the control rate.
pub const HELD_SAMPLES_MAX: usize = 1700;

/// Regressors of one axis: four per motor (thrust, rotor reaction, the gyroscopic torque with
/// the other two axes' rates).
const LAG_PARAMETERS_MAX: usize = 4 * MAX_MOTORS;

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

/// Regressors of the specific-force regression: one per motor (`F x²`) and nine shared ones for
/// the IMU's offset from the centre of gravity (`F Ω̇`, `F Ω_a Ω_b`).
const FORCE_PARAMETERS_MAX: usize = MAX_MOTORS + 9;

/// One sample held back for the effectiveness regression.
#[derive(Clone, Copy, Debug, Default)]
struct HeldSample {
    gyro_rad_s: [f32; 3],
    accel_mps2: [f32; 3],
    driving: [f32; MAX_MOTORS],
    running: bool,
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
        let shape = self.kappa * d + (1.0 - self.kappa) * libm::sqrtf(d);
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

/// The regression of one candidate time constant: the modelled speeds, their filtered squares
/// and accelerations, and per body axis the torques that explain the rates best with them.
#[derive(Clone, Debug)]
struct LagHypothesis {
    /// `1 − exp(−dt/τ)`: the exact first-order response to a held target over a step.
    lag: f32,
    /// `F/s · x²` per motor.
    square: [Integrated; MAX_MOTORS],
    /// `F/s · x Ω_b` per motor and body axis (the gyroscopic torque `Ω × H_rotor`).
    gyroscopic: [[Integrated; 3]; MAX_MOTORS],
    /// `F x` per motor (`F/s · ẋ`, the rotor reaction): two high-passes and the low-pass.
    reaction_hp: [[HighPass; 2]; MAX_MOTORS],
    reaction_lp: [Butterworth2; MAX_MOTORS],
    /// `F x²` per motor of this sample.
    band: [f32; MAX_MOTORS],
    /// The filtered squares (`0..m`), reactions (`m..2m`) and gyroscopic products (`2m + 3i
    /// + b`) of this sample.
    regressors: [f32; 5 * MAX_MOTORS],
    /// Per body axis: `C_a` (index `i < m`), `k_a` (`m ≤ i < 2m`) and the gyroscopic
    /// coefficients of the other two axes' rates (`2m..4m`).
    axes: [Rls<LAG_PARAMETERS_MAX, 1, { packed_len(LAG_PARAMETERS_MAX) }>; 3],
    /// The modelled speed of each motor, fraction of full speed.
    speed: [f32; MAX_MOTORS],
    /// Per body axis, `Σ x y` of the regressions (for their residuals).
    xy: [[f64; LAG_PARAMETERS_MAX]; 3],
    /// `F x²` per motor, and the specific force's regression on them and the offset terms.
    square_band: [Banded; MAX_MOTORS],
    force: Rls<FORCE_PARAMETERS_MAX, 3, { packed_len(FORCE_PARAMETERS_MAX) }>,
    force_xy: [[f64; FORCE_PARAMETERS_MAX]; 3],
}

impl LagHypothesis {
    fn new(tau_s: f32, dt_s: f32, motors: usize, butterworth: Butterworth2) -> Self {
        let config = RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 };
        Self {
            lag: 1.0 - libm::expf(-dt_s / tau_s),
            square: [Integrated::new(butterworth); MAX_MOTORS],
            gyroscopic: [[Integrated::new(butterworth); 3]; MAX_MOTORS],
            reaction_hp: [[HighPass::default(); 2]; MAX_MOTORS],
            reaction_lp: [butterworth; MAX_MOTORS],
            band: [0.0; MAX_MOTORS],
            regressors: [0.0; 5 * MAX_MOTORS],
            axes: core::array::from_fn(|_| Rls::new(4 * motors, config)),
            speed: [0.0; MAX_MOTORS],
            xy: [[0.0; LAG_PARAMETERS_MAX]; 3],
            square_band: [Banded::new(butterworth); MAX_MOTORS],
            force: Rls::new(motors + 9, config),
            force_xy: [[0.0; FORCE_PARAMETERS_MAX]; 3],
        }
    }

    fn reset(&mut self) {
        for rls in &mut self.axes {
            rls.reset();
        }
        self.speed = [0.0; MAX_MOTORS];
        self.xy = [[0.0; LAG_PARAMETERS_MAX]; 3];
        self.force.reset();
        self.force_xy = [[0.0; FORCE_PARAMETERS_MAX]; 3];
    }

    /// Advance the modelled speeds towards `targets` by one sample; with `gyro_rad_s`, the
    /// regressors' filters too (`start`: restarted on this sample).
    fn advance(
        &mut self,
        m: usize,
        targets: &[f32; MAX_MOTORS],
        pole: f32,
        gyro_rad_s: Option<[f32; 3]>,
        start: bool,
    ) {
        for i in 0..m {
            self.speed[i] += (targets[i] - self.speed[i]) * self.lag;
            let Some(gyro) = gyro_rad_s else { continue };
            let x = self.speed[i];
            let square = x * x;
            if start {
                self.square[i].reset_to(square);
                self.square_band[i].reset_to(square);
                self.reaction_hp[i][0].reset_to(x);
                self.reaction_hp[i][1].reset_to(0.0);
                self.reaction_lp[i].reset_to(0.0);
                for b in 0..3 {
                    self.gyroscopic[i][b].reset_to(x * gyro[b]);
                }
            }
            self.regressors[i] = self.square[i].update(square, pole);
            self.band[i] = self.square_band[i].update(square, pole);
            let once = self.reaction_hp[i][0].update(x, pole);
            let twice = self.reaction_hp[i][1].update(once, pole);
            self.regressors[m + i] = self.reaction_lp[i].update(twice);
            for b in 0..3 {
                self.regressors[2 * m + 3 * i + b] =
                    self.gyroscopic[i][b].update(x * gyro[b], pole);
            }
        }
    }

    /// The regressors of axis `a`: squares, reactions, and the products with the other two
    /// axes' rates.
    fn regressors_of(&self, m: usize, a: usize) -> [f32; LAG_PARAMETERS_MAX] {
        let mut x = [0.0; LAG_PARAMETERS_MAX];
        x[..2 * m].copy_from_slice(&self.regressors[..2 * m]);
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        for i in 0..m {
            x[2 * m + 2 * i] = self.regressors[2 * m + 3 * i + b];
            x[2 * m + 2 * i + 1] = self.regressors[2 * m + 3 * i + c];
        }
        x
    }

    /// One regression of axis `a`: `F·Ω_a = Σ C_a,i (F/s)x_i² + Σ k_a,i F x_i + Σ g_a,i,b (F/s)
    /// x_i Ω_b`.
    fn learn(&mut self, m: usize, a: usize, rate: f32) {
        let x = self.regressors_of(m, a);
        // Refused only for non-finite values, which the caller excluded.
        let _ = self.axes[a].update(&x[..4 * m], &[rate]);
        for j in 0..4 * m {
            self.xy[a][j] += f64::from(x[j]) * f64::from(rate);
        }
    }

    /// One regression of the specific force: `F f = Σ c_i F x_i² + (offset terms)`.
    fn learn_force(&mut self, m: usize, offset_terms: &[f32; 9], force: &[f32; 3]) {
        let mut x = [0.0; FORCE_PARAMETERS_MAX];
        x[..m].copy_from_slice(&self.band[..m]);
        x[m..m + 9].copy_from_slice(offset_terms);
        let _ = self.force.update(&x[..m + 9], force);
        for k in 0..3 {
            for j in 0..m + 9 {
                self.force_xy[k][j] += f64::from(x[j]) * f64::from(force[k]);
            }
        }
    }

    /// The least-squares residual of the specific force's axis `k` given `Σ y²` (`yy`).
    fn force_residual(&self, m: usize, k: usize, yy: f64) -> f32 {
        let explained: f64 =
            (0..m + 9).map(|j| f64::from(self.force.theta(j, k)) * self.force_xy[k][j]).sum();
        (yy - explained).max(0.0) as f32
    }

    /// The least-squares residual of axis `a` given `Σ y²` (`yy`): `Σ y² − θ·Σ x y`.
    fn residual(&self, m: usize, a: usize, yy: f64) -> f32 {
        let explained: f64 =
            (0..4 * m).map(|j| f64::from(self.axes[a].theta(j, 0)) * self.xy[a][j]).sum();
        (yy - explained).max(0.0) as f32
    }
}

/// The time constant from the angular response, and the modelled speeds (see the module doc).
#[derive(Clone, Debug)]
pub struct CommandSpeedModel {
    motors: usize,
    dt_s: f32,
    /// Pole of the high-passes and of the low-pass `L`, `exp(−2π f_h dt)`.
    pole: f32,
    /// The two high-passes and the low-pass of the body rates (`F·Ω`).
    rate_hp: [[HighPass; 2]; 3],
    rate_lp: [Butterworth2; 3],
    seen: bool,
    /// Whether a motor has been pulsed ([`PULSE_COMMAND`]) since the reset.
    pulsed: bool,
    /// Bit i: motor i has been pulsed since the reset.
    pulsed_motors: u8,
    /// The axis whose regression runs next.
    next_axis: u8,
    /// One regression per candidate time constant ([`TAU_GRID_S`]).
    hypotheses: [LagHypothesis; TAU_GRID_S.len()],
    /// Per body axis, `Σ y²` of the regressions, and their count.
    yy: [f64; 3],
    /// The specific force through `F`, the offset terms' filters, the filtered rates of the
    /// previous sample, and `Σ y²` of the specific-force regressions.
    force_band: [Banded; 3],
    products_band: [Banded; 6],
    rate_previous: [f32; 3],
    force_yy: [f64; 3],
    regressions: u32,
    /// The time constant identified so far, s, and its standard deviation.
    tau_s: f32,
    tau_std_s: f32,
    /// Samples held back for the effectiveness regression: a ring, the oldest at `held_first`.
    held: [HeldSample; HELD_SAMPLES_MAX],
    held_first: usize,
    held_len: usize,
    /// Samples held before the oldest is released (0 once the excitation is over).
    hold_samples: usize,
    /// The modelled speed of each motor at the oldest held sample's time, fraction of full speed.
    held_speed: [f32; MAX_MOTORS],
}

impl CommandSpeedModel {
    /// Build a model for `motors` motors (clamped to 1..=8) at `rate_hz` in place at `this`,
    /// its signals through the low-pass `lowpass` (designed by the caller at
    /// [`LAG_LOWPASS_HZ`]): the model is about 300 KB (the candidates' covariances and the held
    /// samples) and is never a temporary on the stack.
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
        let butterworth = Butterworth2::from_coefficients(lowpass);
        // SAFETY: the caller's; each field is written once through a raw field pointer. The
        // held samples are all zeros (0.0 and false), a valid value.
        unsafe {
            addr_of_mut!((*this).motors).write(motors);
            addr_of_mut!((*this).dt_s).write(dt_s);
            let pole = libm::expf(-core::f32::consts::TAU * LAG_HIGH_PASS_HZ * dt_s);
            addr_of_mut!((*this).pole).write(pole);
            addr_of_mut!((*this).rate_hp).write([[HighPass::default(); 2]; 3]);
            addr_of_mut!((*this).rate_lp).write([butterworth; 3]);
            addr_of_mut!((*this).seen).write(false);
            addr_of_mut!((*this).pulsed).write(false);
            addr_of_mut!((*this).pulsed_motors).write(0);
            addr_of_mut!((*this).next_axis).write(0);
            let hypotheses = addr_of_mut!((*this).hypotheses).cast::<LagHypothesis>();
            for (j, &tau) in TAU_GRID_S.iter().enumerate() {
                hypotheses.add(j).write(LagHypothesis::new(tau, dt_s, motors, butterworth));
            }
            addr_of_mut!((*this).yy).write([0.0; 3]);
            addr_of_mut!((*this).force_band).write([Banded::new(butterworth); 3]);
            addr_of_mut!((*this).products_band).write([Banded::new(butterworth); 6]);
            addr_of_mut!((*this).rate_previous).write([0.0; 3]);
            addr_of_mut!((*this).force_yy).write([0.0; 3]);
            addr_of_mut!((*this).regressions).write(0);
            addr_of_mut!((*this).tau_s).write(TAU_PRIOR_S);
            addr_of_mut!((*this).tau_std_s).write(TAU_PRIOR_STD_S);
            addr_of_mut!((*this).held).write_bytes(0, 1);
            addr_of_mut!((*this).held_first).write(0);
            addr_of_mut!((*this).held_len).write(0);
            addr_of_mut!((*this).hold_samples).write(Self::hold_samples(rate_hz));
            addr_of_mut!((*this).held_speed).write([0.0; MAX_MOTORS]);
        }
    }

    fn hold_samples(rate_hz: f32) -> usize {
        ((EFFECTIVENESS_HOLD_S * rate_hz) as usize).min(HELD_SAMPLES_MAX)
    }

    /// Forget everything (a new identification).
    pub fn reset(&mut self) {
        for h in &mut self.hypotheses {
            h.reset();
        }
        self.yy = [0.0; 3];
        self.force_yy = [0.0; 3];
        self.regressions = 0;
        self.tau_s = TAU_PRIOR_S;
        self.tau_std_s = TAU_PRIOR_STD_S;
        self.next_axis = 0;
        self.seen = false;
        self.pulsed = false;
        self.pulsed_motors = 0;
        self.held_first = 0;
        self.held_len = 0;
        self.hold_samples = Self::hold_samples(1.0 / self.dt_s);
        self.held_speed = [0.0; MAX_MOTORS];
    }

    /// Hold a sample back for the effectiveness regression (the commands driving the motors at
    /// it and whether the ESCs run them). The effectiveness regression never forgets, so what
    /// it learned from speeds modelled with the lag of the first pulses, still far off, would
    /// stay: it learns instead from the end of the excitation (every motor pulsed and all back
    /// below [`PULSE_COMMAND`], seen by [`CommandSpeedModel::update`]), or at most
    /// [`EFFECTIVENESS_HOLD_S`] behind, from speeds modelled with the lag identified over
    /// every pulse. A full ring releases its oldest sample first.
    pub fn hold(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        driving: &[f32; MAX_MOTORS],
        running: bool,
    ) {
        let index = (self.held_first + self.held_len) % HELD_SAMPLES_MAX;
        self.held[index] = HeldSample { gyro_rad_s, accel_mps2, driving: *driving, running };
        if self.held_len < HELD_SAMPLES_MAX {
            self.held_len += 1;
        } else {
            self.held_first = (self.held_first + 1) % HELD_SAMPLES_MAX;
        }
    }

    /// The oldest held sample when more than the hold are held, its speeds modelled with the
    /// lag identified so far.
    pub fn release(&mut self) -> Option<ReleasedSample> {
        if self.held_len == 0 || self.held_len <= self.hold_samples {
            return None;
        }
        let sample = self.held[self.held_first];
        self.held_first = (self.held_first + 1) % HELD_SAMPLES_MAX;
        self.held_len -= 1;
        let lag = 1.0 - libm::expf(-self.dt_s / self.tau_s);
        let mut speeds_rad_s = [0.0; MAX_MOTORS];
        for i in 0..self.motors {
            let target = Self::target_speed(sample.driving[i], sample.running);
            self.held_speed[i] += (target - self.held_speed[i]) * lag;
            speeds_rad_s[i] = NOMINAL_FULL_SPEED_RAD_S * self.held_speed[i];
        }
        Some(ReleasedSample {
            gyro_rad_s: sample.gyro_rad_s,
            accel_mps2: sample.accel_mps2,
            speeds_rad_s,
        })
    }

    /// The nominal curve's steady speed for command δ, fraction of full speed (0 while the ESC
    /// has not yet started the motor, `running` false).
    pub fn target_speed(command: f32, running: bool) -> f32 {
        Curve::NOMINAL.target(command, running)
    }

    /// One sample: the body rates (rad/s, IMU axes), the commands driving the motors, whether
    /// the ESCs run them, and whether to learn from it (else only the filters run).
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        driving: &[f32; MAX_MOTORS],
        running: bool,
        learn: bool,
    ) {
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
            self.hold_samples = 0;
        }
        let pole = self.pole;
        if !gyro_rad_s.iter().chain(&accel_mps2).all(|w| w.is_finite()) {
            self.seen = false;
            for h in &mut self.hypotheses {
                h.advance(m, &targets, pole, None, false);
            }
            return;
        }
        let start = !self.seen;
        self.seen = true;
        let w = gyro_rad_s;
        let products =
            [w[0] * w[0], w[1] * w[1], w[2] * w[2], w[0] * w[1], w[0] * w[2], w[1] * w[2]];
        if start {
            for k in 0..3 {
                self.force_band[k].reset_to(accel_mps2[k]);
            }
            for (band, p) in self.products_band.iter_mut().zip(products) {
                band.reset_to(p);
            }
            for a in 0..3 {
                self.rate_hp[a][0].reset_to(gyro_rad_s[a]);
                self.rate_hp[a][1].reset_to(0.0);
                self.rate_lp[a].reset_to(0.0);
            }
        }
        let mut rate = [0.0; 3];
        for a in 0..3 {
            let once = self.rate_hp[a][0].update(gyro_rad_s[a], pole);
            let twice = self.rate_hp[a][1].update(once, pole);
            rate[a] = self.rate_lp[a].update(twice);
        }
        let force: [f32; 3] =
            core::array::from_fn(|k| self.force_band[k].update(accel_mps2[k], pole));
        let mut offset_terms = [0.0; 9];
        for a in 0..3 {
            offset_terms[a] = (rate[a] - self.rate_previous[a]) / self.dt_s;
        }
        for (j, (band, p)) in self.products_band.iter_mut().zip(products).enumerate() {
            offset_terms[3 + j] = band.update(p, pole);
        }
        self.rate_previous = rate;
        for h in &mut self.hypotheses {
            h.advance(m, &targets, pole, Some(gyro_rad_s), start);
        }
        if !(learn && self.pulsed) || start {
            return;
        }
        // One axis per sample.
        let a = usize::from(self.next_axis);
        self.next_axis = (self.next_axis + 1) % 3;
        for h in &mut self.hypotheses {
            h.learn(m, a, rate[a]);
            h.learn_force(m, &offset_terms, &force);
        }
        self.yy[a] += f64::from(rate[a]) * f64::from(rate[a]);
        for k in 0..3 {
            self.force_yy[k] += f64::from(force[k]) * f64::from(force[k]);
        }
        self.regressions += 1;
        self.select();
    }

    /// The time constant whose regressions explain the response best (the least-squares
    /// residual, per axis relative to the candidates' mean, as they all see the same rates,
    /// summed over the axes), refined between the grid's points by a parabola through the best
    /// and its neighbours in `ln τ`. Its standard deviation from the parabola's curvature: the
    /// residual grows by one error variance one σ away.
    fn select(&mut self) {
        let n = TAU_GRID_S.len();
        let m = self.motors;
        let residuals: [[f32; 6]; TAU_GRID_S.len()] = core::array::from_fn(|j| {
            let h = &self.hypotheses[j];
            core::array::from_fn(|a| {
                if a < 3 {
                    h.residual(m, a, self.yy[a])
                } else {
                    h.force_residual(m, a - 3, self.force_yy[a - 3])
                }
            })
        });
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
        use crate::learner::excitation::{Excitation, ExcitationConfig};
        let rate_hz = 2000.0;
        let dt = 1.0 / rate_hz;
        let lowpass = BiquadCoefficients::butterworth_lowpass(LAG_LOWPASS_HZ, rate_hz).unwrap();
        let mut slot = std::boxed::Box::<CommandSpeedModel>::new_uninit();
        // SAFETY: a fresh, aligned allocation, every field written by `build_at`.
        let mut model = unsafe {
            CommandSpeedModel::build_at(slot.as_mut_ptr(), 4, rate_hz, lowpass);
            slot.assume_init()
        };
        let mut excitation = Excitation::new(ExcitationConfig::default(), 4);
        let c = [
            [300.0, -300.0, 300.0, -300.0],
            [300.0, 300.0, -300.0, -300.0],
            [40.0, -40.0, -40.0, 40.0],
        ];
        let mut speed = [0.0f32; 4];
        let mut rate = [3.0f32, -2.0, 1.0];
        loop {
            let out = excitation.update(rate, None, dt);
            if out.finished {
                break;
            }
            for i in 0..4 {
                let target = curve(out.commands[i]);
                speed[i] += (target - speed[i]) * (1.0 - libm::expf(-dt / tau));
            }
            for a in 0..3 {
                let alpha: f32 = (0..4).map(|i| c[a][i] * speed[i] * speed[i]).sum::<f32>();
                rate[a] += alpha * dt;
            }
            let thrust: f32 = (0..4).map(|i| 10.0 * speed[i] * speed[i]).sum();
            model.update(rate, [0.0, 0.0, -thrust], &out.commands, true, true);
        }
        model.tau_s()
    }

    #[test]
    fn the_lag_is_identified_from_the_body_response_across_the_range() {
        // The world's lags (`sim::airframe`: 15–45 ms scaled by the craft's size, ±10 % per
        // motor) and idles (3–15 % of full speed).
        for tau in [0.015, 0.03, 0.06] {
            // The nominal curve itself: within 5 % (2.3 % at 15 ms, 3.7 % at 60 ms today).
            let nominal = identify(tau, |d| CommandSpeedModel::target_speed(d, true));
            assert!((nominal / tau - 1.0).abs() < 0.05, "τ {tau}: {nominal}");
            for idle in [0.03, 0.15] {
                // Concave curves like the nominal one (speed ∝ √δ, δ^0.6, κ 0.5) at either end
                // of the idle range: within 35 % (worst today: −33 % at 60 ms, idle 3 %, κ 0.5).
                for p in [0.5, 0.6] {
                    let found = identify(tau, |d| idle + (1.0 - idle) * libm::powf(d, p));
                    assert!(
                        (found / tau - 1.0).abs() < 0.35,
                        "τ {tau}, δ^{p}, idle {idle}: {found}"
                    );
                }
                let paper = |d: f32| idle + (1.0 - idle) * (0.5 * d + 0.5 * libm::sqrtf(d));
                let found = identify(tau, paper);
                assert!((found / tau - 1.0).abs() < 0.35, "τ {tau}, κ 0.5, idle {idle}: {found}");
                // Convex ones (speed ∝ δ, δ^1.4), unlike the nominal curve: τ comes out low, by
                // up to half (the curve is not identified: the module doc), never much high.
                for p in [1.0, 1.4] {
                    let found = identify(tau, |d| idle + (1.0 - idle) * libm::powf(d, p));
                    let within = found > 0.45 * tau && found < 1.1 * tau;
                    assert!(within, "τ {tau}, δ^{p}, idle {idle}: {found}");
                }
            }
        }
    }
}
