//! The effectiveness matrices G1 and G2 from the body's response to the motors
//! (docs/algorithms/learner.md, with the two corrections the published recipe lacked).
//!
//! # Model (IMU axes, motor speeds ω in rad/s)
//! ```text
//! f_cog = G1f ω² + f_rest                         (specific force at the centre of gravity)
//! Ω̇     = G1τ ω² + G2 ω̇ − I⁻¹ Ω × (I Ω + h)       (angular acceleration)
//! ```
//! `G1` (6 × m) is per unit squared speed, m/s² or rad/s² per (rad/s)²; `G2` (3 × m) is rad/s²
//! per rad/s² of motor acceleration (the reaction of the rotor inertia, mostly yaw); `h` is the
//! rotors' angular momentum. As published, the regression works on increments (differences of
//! samples) of signals through one 2nd-order Butterworth low-pass (20 Hz): slowly varying
//! disturbances cancel, and Ω̇ comes from differentiating the filtered gyro. The filters run on
//! every sample; the six regressions (three force rows, three rotational rows) take turns
//! ([`REGRESSIONS`]), each row's turn two samples at the 2 kHz control rate
//! ([`MAX_ROW_RATE_HZ`]: its RLS update spread over both), so a row's increments span twelve
//! samples.
//!
//! **Specific-force rows.** The accelerometer is moved to the centre of gravity with the stored
//! IMU offset `r`: `f_cog = f_imu − Ω̇×r − Ω×(Ω×r)`. The rest `f_rest` is mostly aerodynamic drag,
//! which on a tumbling craft is fixed in the *world*, not the body: in body axes it turns at −Ω,
//! so its increment is `−w × f_rest` (`w = Ω dt`), not zero (the main error of the published
//! recipe). Substituting `f_rest = f_cog − G1f ω²` gives an equation that is still linear
//! in G1f, and exact:
//! `Δf_cog + w × f_cog = G1f Δ(ω²) + w × (G1f ω²)`.
//! Its three rows have different regressors (the cross product mixes them), so the force rows
//! are one RLS over all `3m` entries of G1f with three scalar updates (one per row). A constant
//! accelerometer bias `b` is fixed in the *body* and leaves `−w × b` in the equation instead:
//! three more parameters (`b`, index `3m..3m+3`) with the regressor `−w ×`. (Estimating
//! `f_rest` from the current G1f instead is cheaper but biased: early in the excitation G1f is
//! still far off, and the rotation term is a quarter of the signal at 400 °/s; it gave 15–30 %
//! errors on the seed paper's quad.)
//!
//! **Angular-acceleration rows: the angular-momentum balance.** The Euler and rotor-gyroscopic
//! terms are quadratic in the rates and spoil G1τ when ignored. Multiplied by the inertia
//! and divided by its trace, the rotational equation is *linear* in every unknown:
//! ```text
//! J Ω̇ + Ω × (J Ω) + Ω × (K ω) + K ω̇ = T ω²        J = I / tr I,  K = −J G2,  T = J G1τ
//! ```
//! with the rotor momentum `h = tr I · K ω`. The unknowns are `T` (3m), `K` (3m) and five
//! entries of the normalised inertia `J` (`J_zz = 1 − J_xx − J_yy` fixes the scale, which the
//! homogeneous equation leaves free; the trace does not depend on the axes). Its regressors are
//! the filtered Ω̇, squared speeds, motor accelerations and the products `Ωₐ Ω_b` and `Ωₐ ωᵢ`
//! (formed from raw samples, then filtered). G1τ = J⁻¹ T and G2 = −J⁻¹ K are formed when read.
//! The three rows mix the parameters (through `J` and the cross products), so they are one
//! RLS of `6m + 5` parameters with one scalar update per row, like the force rows.
//!
//! Why this form: before it, the body's own dynamics were absorbed by fifteen free regressors
//! per row (the six `Ωₐ Ω_b` and nine products of Ω with the rotor-momentum estimate `−G2 ω`),
//! 45 coefficients estimated and discarded where the physics has five. With the simulator's
//! exact inertia subtracted instead, the Monte Carlo's G1τ error fell from 5.2 % to 1.3 %
//! (median, 300 random airframes): the free coefficients, not the data, were the limit. The
//! balance estimates the five and reaches 2.7 % (docs/benchmarks.md). `J` is seen only through
//! the body's rotation (`J Ω̇ = T ω²` alone holds for any `J`), so it carries a weak prior
//! ([`INERTIA_PRIOR_VARIANCE`](super::inertia::INERTIA_PRIOR_VARIANCE)).
//!
//! Scaling: ω² in (krad/s)², ω̇ and `Ωₐ ωᵢ` in 100 krad/s² (they share `K`); RLS arithmetic is
//! `f64`.

// Index loops are kept where they mirror the matrix notation of the derivation (rows, columns,
// regressors by index), as in `thrust_axis`.
#![allow(clippy::needless_range_loop)]

use super::inertia::{
    inertia_regressors, rate_product, InertiaPrior, INERTIA_PARAMETERS, RATE_PRODUCTS,
};
use super::rls::{packed_len, Rls, RlsConfig, Update, NOISE_WINDOW};
use super::MAX_MOTORS;
use crate::filters::{BiquadCoefficients, Butterworth2, Butterworth2x3};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use nalgebra::{Matrix3, Vector3};

/// Corner of the first-order high-pass applied to every regressor and output of the increment
/// regressions, Hz: with the 20 Hz low-pass, the regressions see a band around 20 Hz. What
/// remains of drag after the world-frame correction (its change with airspeed and with the
/// body's anisotropy), the slow precession of a tumbling body and any error in the rotor
/// momentum term all vary at 0.2–2 Hz, while the motor pulses carry 5–40 Hz. The high-pass is a
/// linear time-invariant filter applied alike to both sides, so the linear relation between them
/// is kept. Chosen on the simulator's Monte Carlo (200 random airframes): the median worst-row G1
/// error was 16 % without it, 15 % at 4 Hz, 9.2 % at 16 Hz and 8.8 % at 20 Hz; 40 Hz low-pass
/// with 16–25 Hz high-pass was no better. The angular-momentum balance models the precession
/// exactly, but a lower corner on its rows still lost (median G1τ error on 300 airframes:
/// 12.5 % at 0.5 Hz, 5.3 % at 5 Hz, 4.1 % at 10 Hz, 3.7 % at 20 Hz, before its inertia prior):
/// what a percent of model error does to a 50–100 rad/s² precession outweighs the pulses.
pub const HIGH_PASS_HZ: f32 = 20.0;

/// The six regressions (the three specific-force rows, the three rows of the angular-momentum
/// balance) take turns, one row at a time, each once a cycle. One sample then costs at most part
/// of one of them, never all six (docs/budget.md, issue 56: the background
/// task must finish every sample within its share of a control period on the Cortex-M7).
pub const REGRESSIONS: u8 = 6;

/// Sample rate above which each row's turn takes two samples ([`MAX_SAMPLES_PER_ROW`]) instead
/// of one, Hz: up to 2 kHz, at most 1,000 rows are begun a second. At the 2 kHz control rate a row every 1 ms, each
/// row every 6 ms (167 Hz), the increments spanning twelve samples; at the 250 Hz of the held
/// samples without speed telemetry a row every sample, each every 24 ms. Nothing is lost that
/// the regressions use: every signal has been through the 20 Hz low-pass at the full rate first
/// (at a row's 167 Hz, the filter attenuates the 83 Hz Nyquist frequency by 25 dB, and what would
/// alias onto the 20 Hz band, 147 Hz, by 35 dB), the motor pulses carry 5–40 Hz, and successive
/// increments of a row still tile the signal. On 1,000 random worlds (`fly monte-carlo --world
/// random`), six samples a cycle against twelve: held 997 / 997, G1 per unit thrust at the
/// excitation's end median (99th) force 6.76 (22.18) / 6.67 (22.81) %, torque 5.28 (16.94) /
/// 5.19 (16.87) %, thrust axis 1.27 / 1.29°; without speed telemetry unchanged (one held sample a
/// row). Twelve halve the regressions' mean cost a sample, which the worst control period needs
/// (docs/budget.md).
pub const MAX_ROW_RATE_HZ: f32 = 1000.0;

/// Samples a row takes at most: its RLS update is spread over them (the balance's update, 53
/// regressors on the octorotor, is about 18,000 instructions: [`EffectivenessEstimator::advance`]).
pub const MAX_SAMPLES_PER_ROW: u8 = 2;

/// A row's first sample forms its regressors and high-passes them besides beginning its update:
/// about a quarter of its product's work, counted so (the octorotor's balance row, `cargo xtask
/// bench-m7`: 18,287 instructions on the sample that formed it and took the product, 12,813 on
/// the one that took the downdate, when the two took equal shares of the update alone; 15,641
/// and 15,546 with the formation counted).
const ROW_FORMATION_DIVISOR: usize = 4;

/// Centred samples kept: one cycle of the regressions at its longest.
const CENTRED_RING: usize = (REGRESSIONS * MAX_SAMPLES_PER_ROW) as usize;

/// Which regression a sample fed ([`EffectivenessEstimator::update`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regression {
    /// None (the filters are starting, or the sample was a gap).
    None,
    /// A sample of a row's turn before its last (the row's update goes on).
    Begun,
    /// The last sample of specific-force row 0, 1 or 2's turn (x, y, z).
    ForceRow(u8),
    /// The last sample of angular-momentum balance row 0, 1 or 2's turn (x, y, z).
    RotationRow(u8),
    /// All six (no decimation).
    All,
}

/// Squared-speed unit of the regression, (rad/s)².
pub const SPEED2_SCALE: f32 = 1e6;
/// Motor-acceleration unit of the regression, rad/s²; also the unit of the products of a body
/// rate and a motor speed, (rad/s)², which share the rotor-momentum parameters.
pub const SPEED_DOT_SCALE: f32 = 1e5;
/// Capacity of the rotational regression: the torques `T` (`3·8`), the rotor momenta `K`
/// (`3·8`) and the normalised inertia.
pub const ROT_PARAMETERS_MAX: usize = 6 * MAX_MOTORS + INERTIA_PARAMETERS;
/// Capacity of the force regression: the `3·8` entries of G1f (index `3i + axis`) and the
/// accelerometer bias (the last three).
pub const FORCE_PARAMETERS_MAX: usize = 3 * MAX_MOTORS + 3;

/// One sample of every filtered signal.
#[derive(Clone, Copy, Debug, Default)]
struct Filtered {
    gyro: Vector3<f32>,
    /// Accelerometer less the centripetal term `Ω×(Ω×r)` (formed before filtering).
    accel: Vector3<f32>,
    speed: [f32; MAX_MOTORS],
    speed2: [f32; MAX_MOTORS],
    /// `Ωₐ Ω_b`, (rad/s)².
    rate_products: [f32; RATE_PRODUCTS],
    /// `Ωₐ ωᵢ / SPEED_DOT_SCALE` at `3i + a`.
    momentum_products: [f32; 3 * MAX_MOTORS],
}

/// One centred sample of the filtered signals.
#[derive(Clone, Copy, Debug, Default)]
struct Centred {
    /// ω²/SPEED2_SCALE per motor.
    speed2: [f32; MAX_MOTORS],
    /// ω̇/SPEED_DOT_SCALE per motor.
    speed_dot: [f32; MAX_MOTORS],
    rate: Vector3<f32>,
    rate_dot: Vector3<f32>,
    f_cog: Vector3<f32>,
    rate_products: [f32; RATE_PRODUCTS],
    momentum_products: [f32; 3 * MAX_MOTORS],
}

/// The G1/G2 estimator.
#[derive(Clone, Debug)]
pub struct EffectivenessEstimator {
    motors: usize,
    /// Samples between the two ends of a regression's increment, a cycle of the regressions:
    /// [`REGRESSIONS`] times `samples_per_row`, or 1 for every regression on every sample.
    decimation: u8,
    /// Samples of a row's turn (see [`MAX_ROW_RATE_HZ`]).
    samples_per_row: u8,
    /// Time between the two ends of an increment, s.
    increment_s: f32,
    half_rate_hz: f32,
    r_imu_m: Vector3<f32>,
    /// How much older the speed reports are than the IMU sample of the same step, s.
    speed_lag_s: f32,
    filter: BiquadCoefficients,
    gyro: Butterworth2x3,
    accel: Butterworth2x3,
    speed: [Butterworth2; MAX_MOTORS],
    /// Filters of the squared speeds (ω²/SPEED2_SCALE): the model is linear in ω², and the
    /// square of a filtered speed is not the filtered square while the speed changes fast.
    speed2: [Butterworth2; MAX_MOTORS],
    /// Filters of the rate products and of the products of rates and motor speeds (formed
    /// from raw samples, then filtered: the product of filtered signals is not the filtered
    /// product at 400 °/s).
    rate_products: [Butterworth2; RATE_PRODUCTS],
    momentum_products: [Butterworth2; 3 * MAX_MOTORS],
    /// The filtered signals of the last three samples: a ring, the newest at `newest`.
    history: [Filtered; 3],
    newest: usize,
    seen: u8,
    /// The last centred samples, sample `c` at `c mod CENTRED_RING`.
    centred: [Centred; CENTRED_RING],
    /// Centred samples since the filters started; modulo the decimation it chooses the
    /// regression.
    centred_count: u32,
    force: Rls<FORCE_PARAMETERS_MAX, 1, { packed_len(FORCE_PARAMETERS_MAX) }>,
    /// High-pass of each force row's regressors and output (the output last).
    force_high_pass: [HighPass<{ FORCE_PARAMETERS_MAX + 1 }>; 3],
    /// High-pass of each rotational row's regressors and output (the output last).
    rotation_high_pass: [HighPass<{ ROT_PARAMETERS_MAX + 1 }>; 3],
    /// Pole of the first-order high-passes at the regressions' rate, `exp(−2π f_c / f_s)`.
    high_pass_pole: f32,
    /// Sample rate, Hz (for the pole when the decimation changes).
    rate_hz: f32,
    /// The angular-momentum balance: `T` at `axis·m + i` ([`Self::torque_index`]), `K` at
    /// `3m + 3i + axis`, `J` from `6m` (see the module doc).
    rotation: Rls<ROT_PARAMETERS_MAX, 1, { packed_len(ROT_PARAMETERS_MAX) }>,
    /// A force row's update in progress (begun, not finished), if any.
    force_update: Update<FORCE_PARAMETERS_MAX, 1>,
    /// A balance row's update in progress, if any (never beside a force row's).
    rotation_update: Update<ROT_PARAMETERS_MAX, 1>,
}

/// What an [`EffectivenessEstimator`] is built for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EffectivenessSetup {
    /// Motors (clamped to 1..=8).
    pub motors: usize,
    /// Rate of the samples it is fed, Hz.
    pub rate_hz: f32,
    /// The low-pass every signal goes through.
    pub filter: BiquadCoefficients,
    /// Where the accelerometer sits from the centre of gravity, IMU axes, m: its readings are
    /// moved to the centre of gravity.
    pub r_imu_m: [f32; 3],
    /// How much older the speed reports are than the IMU samples they come with, s
    /// (compensated by moving the filtered squared speeds forward along their derivative).
    pub speed_lag_s: f32,
    /// The regressions' RLS tuning.
    pub rls: RlsConfig,
}

impl EffectivenessEstimator {
    /// An estimator for `setup`.
    pub fn new(setup: EffectivenessSetup) -> Self {
        let mut slot = MaybeUninit::uninit();
        // SAFETY: a local slot, valid and aligned; `build_at` writes every field.
        unsafe {
            Self::build_at(slot.as_mut_ptr(), setup);
            slot.assume_init()
        }
    }

    /// [`EffectivenessEstimator::new`] in place at `this`, field by field (the estimator is
    /// 21 KB; its covariances are built in place too: [`Rls::build_at`]).
    ///
    /// # Safety
    /// `this` must be valid for writes and aligned; every field is written before use.
    pub(crate) unsafe fn build_at(this: *mut Self, setup: EffectivenessSetup) {
        let EffectivenessSetup { motors, rate_hz, filter, r_imu_m, speed_lag_s, rls: config } =
            setup;
        let motors = motors.clamp(1, MAX_MOTORS);
        addr_of_mut!((*this).motors).write(motors);
        addr_of_mut!((*this).decimation).write(1);
        addr_of_mut!((*this).samples_per_row).write(1);
        addr_of_mut!((*this).increment_s).write(0.0);
        addr_of_mut!((*this).half_rate_hz).write(0.5 * rate_hz);
        addr_of_mut!((*this).r_imu_m).write(Vector3::from(r_imu_m));
        let lag = if speed_lag_s.is_finite() { speed_lag_s } else { 0.0 };
        addr_of_mut!((*this).speed_lag_s).write(lag);
        addr_of_mut!((*this).filter).write(filter);
        let butterworth = Butterworth2::from_coefficients(filter);
        addr_of_mut!((*this).gyro).write(Butterworth2x3::from_coefficients(filter));
        addr_of_mut!((*this).accel).write(Butterworth2x3::from_coefficients(filter));
        addr_of_mut!((*this).speed).write([butterworth; MAX_MOTORS]);
        addr_of_mut!((*this).speed2).write([butterworth; MAX_MOTORS]);
        addr_of_mut!((*this).rate_products).write([butterworth; RATE_PRODUCTS]);
        addr_of_mut!((*this).momentum_products).write([butterworth; 3 * MAX_MOTORS]);
        addr_of_mut!((*this).history).write([Filtered::default(); 3]);
        addr_of_mut!((*this).newest).write(0);
        addr_of_mut!((*this).seen).write(0);
        addr_of_mut!((*this).centred).write([Centred::default(); CENTRED_RING]);
        addr_of_mut!((*this).centred_count).write(0);
        Rls::build_at(addr_of_mut!((*this).force), 3 * motors + 3, config);
        addr_of_mut!((*this).force_high_pass).write([HighPass::default(); 3]);
        addr_of_mut!((*this).rotation_high_pass).write([HighPass::default(); 3]);
        addr_of_mut!((*this).high_pass_pole).write(0.0);
        addr_of_mut!((*this).rate_hz).write(rate_hz);
        Rls::build_at(addr_of_mut!((*this).rotation), 6 * motors + INERTIA_PARAMETERS, config);
        addr_of_mut!((*this).force_update).write(Update::new());
        addr_of_mut!((*this).rotation_update).write(Update::new());
        let estimator = &mut *this;
        estimator.reset_inertia();
        estimator.set_decimation(REGRESSIONS);
    }

    /// The same estimator with every regression on every sample (`decimation` 1, as published)
    /// or taking turns (any other value: the default, [`REGRESSIONS`] rows a cycle, each over
    /// the samples [`MAX_ROW_RATE_HZ`] gives it). Restarts the filters.
    pub fn with_decimation(mut self, decimation: u8) -> Self {
        self.set_decimation(decimation);
        self.restart_filters();
        self
    }

    fn set_decimation(&mut self, decimation: u8) {
        self.samples_per_row = if self.rate_hz > MAX_ROW_RATE_HZ { MAX_SAMPLES_PER_ROW } else { 1 };
        self.decimation = if decimation == 1 { 1 } else { REGRESSIONS * self.samples_per_row };
        let regression_rate_hz = self.rate_hz / f32::from(self.decimation);
        self.increment_s = 1.0 / regression_rate_hz;
        self.high_pass_pole =
            libm::expf(-core::f32::consts::TAU * HIGH_PASS_HZ / regression_rate_hz);
        // The noise variance over the same time as at every sample.
        let window = NOISE_WINDOW / f32::from(self.decimation);
        self.force.set_noise_window(window);
        self.rotation.set_noise_window(window);
    }

    /// Forget everything (a new identification), with a new IMU offset.
    pub fn reset(&mut self, r_imu_m: [f32; 3]) {
        self.r_imu_m = Vector3::from(r_imu_m);
        self.force_update.cancel();
        self.rotation_update.cancel();
        self.force.reset();
        self.rotation.reset();
        self.reset_inertia();
        self.restart_filters();
    }

    /// Restart the filters only (after a gap in the data), keeping the estimates.
    pub fn restart_filters(&mut self) {
        self.gyro = Butterworth2x3::from_coefficients(self.filter);
        self.accel = Butterworth2x3::from_coefficients(self.filter);
        self.speed = [Butterworth2::from_coefficients(self.filter); MAX_MOTORS];
        self.speed2 = [Butterworth2::from_coefficients(self.filter); MAX_MOTORS];
        self.rate_products = [Butterworth2::from_coefficients(self.filter); RATE_PRODUCTS];
        self.momentum_products = [Butterworth2::from_coefficients(self.filter); 3 * MAX_MOTORS];
        self.seen = 0;
        self.centred_count = 0;
        self.force_high_pass = [HighPass::default(); 3];
        self.rotation_high_pass = [HighPass::default(); 3];
    }

    /// One sample: gyro (rad/s) and accelerometer (m/s²) in IMU axes, motor speeds (rad/s).
    /// Non-finite values restart the filters (the sample is a gap). Returns the regression the
    /// sample fed.
    pub fn update(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds_rad_s: &[f32],
    ) -> Regression {
        self.step(gyro_rad_s, accel_mps2, speeds_rad_s, true)
    }

    /// One sample of the body's motion before the motors start (the free fall of the release
    /// delay): the filters run, no regression does, and the regressions' count starts again, so
    /// that the first regression comes a cycle ([`EffectivenessEstimator::cycle_samples`])
    /// after the first [`EffectivenessEstimator::update`], as without priming.
    ///
    /// Why: a filter restarted at the first sample takes the body's rates as constant before
    /// it, but a thrown body precesses (`J Ω̇ = −Ω × J Ω`, 50–100 rad/s² at 800 °/s): for the
    /// filters' first 50 ms the differentiated rate misses `Ω̇` while the filtered products
    /// carry `Ω × J Ω`, and the balance, which forgets nothing, pins that transient on the
    /// motors that start in it. On an exact tumbling octorotor with its exact `J` the torque
    /// block was 21 % off at 800 °/s and 48 % at 1,200 °/s (0.6 % at rest); primed for 100 ms,
    /// 0.7 % and 1.2 % (`a_fast_tumble_primes_the_filters_…` below). Speeds that are not finite
    /// count as stopped motors.
    pub fn prime(&mut self, gyro_rad_s: [f32; 3], accel_mps2: [f32; 3], speeds_rad_s: &[f32]) {
        let mut stopped = [0.0; MAX_MOTORS];
        for (s, &reported) in stopped.iter_mut().zip(speeds_rad_s) {
            *s = if reported.is_finite() { reported } else { 0.0 };
        }
        let m = self.motors.min(speeds_rad_s.len());
        self.step(gyro_rad_s, accel_mps2, &stopped[..m], false);
        self.centred_count = 0;
    }

    fn step(
        &mut self,
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds_rad_s: &[f32],
        regress: bool,
    ) -> Regression {
        if regress {
            self.advance();
        }
        let m = self.motors;
        let finite = gyro_rad_s.iter().chain(&accel_mps2).chain(speeds_rad_s.iter().take(m));
        if speeds_rad_s.len() < m || !finite.into_iter().all(|v| v.is_finite()) {
            self.restart_filters();
            return Regression::None;
        }
        let gyro = Vector3::from(gyro_rad_s);
        let r = self.r_imu_m;
        let accel = Vector3::from(accel_mps2) - gyro.cross(&gyro.cross(&r));
        let mut speed2 = [0.0; MAX_MOTORS];
        for i in 0..m {
            speed2[i] = speeds_rad_s[i] * speeds_rad_s[i] / SPEED2_SCALE;
        }
        let mut rate_products = [0.0; RATE_PRODUCTS];
        for a in 0..3 {
            for b in a..3 {
                rate_products[rate_product(a, b)] = gyro[a] * gyro[b];
            }
        }
        let mut momentum_products = [0.0; 3 * MAX_MOTORS];
        for i in 0..m {
            let speed = speeds_rad_s[i] / SPEED_DOT_SCALE;
            for a in 0..3 {
                momentum_products[3 * i + a] = gyro[a] * speed;
            }
        }
        if self.seen == 0 {
            self.gyro.reset_to(&gyro);
            self.accel.reset_to(&accel);
            for i in 0..m {
                self.speed[i].reset_to(speeds_rad_s[i]);
                self.speed2[i].reset_to(speed2[i]);
            }
            for (f, x) in self.rate_products.iter_mut().zip(rate_products) {
                f.reset_to(x);
            }
            for (f, x) in self.momentum_products.iter_mut().zip(momentum_products).take(3 * m) {
                f.reset_to(x);
            }
        }
        // Filtered in place into the ring's oldest slot.
        self.newest = (self.newest + 1) % 3;
        let filtered = &mut self.history[self.newest];
        filtered.gyro = self.gyro.update(&gyro);
        filtered.accel = self.accel.update(&accel);
        for i in 0..m {
            filtered.speed[i] = self.speed[i].update(speeds_rad_s[i]);
            filtered.speed2[i] = self.speed2[i].update(speed2[i]);
        }
        for j in 0..RATE_PRODUCTS {
            filtered.rate_products[j] = self.rate_products[j].update(rate_products[j]);
        }
        for j in 0..3 * m {
            filtered.momentum_products[j] = self.momentum_products[j].update(momentum_products[j]);
        }
        if self.seen < 2 {
            self.seen += 1;
            return Regression::None;
        }
        let [filtered, previous, before] = [0, 2, 1].map(|k| &self.history[(self.newest + k) % 3]);
        // Centred on the previous sample: central differences of gyro and speeds.
        let rate_dot = (filtered.gyro - before.gyro) * self.half_rate_hz;
        let f_cog = previous.accel - rate_dot.cross(&r);
        let mut now = Centred {
            rate: previous.gyro,
            rate_dot,
            f_cog,
            rate_products: previous.rate_products,
            // The products of rate and speed are taken as they are: moving them forward by the
            // speed reports' lag like the squared speeds changed nothing measurable (1,000
            // random airframes) and cost 70 instructions a sample on the quad's budget.
            momentum_products: previous.momentum_products,
            ..Centred::default()
        };
        let lead = self.speed_lag_s * self.half_rate_hz;
        for i in 0..m {
            now.speed2[i] = previous.speed2[i] + (filtered.speed2[i] - before.speed2[i]) * lead;
            let speed_dot = (filtered.speed[i] - before.speed[i]) * self.half_rate_hz;
            let speed_ddot = (filtered.speed[i] - 2.0 * previous.speed[i] + before.speed[i])
                * (4.0 * self.half_rate_hz * self.half_rate_hz);
            // The motor accelerations are moved forward by the report lag too: the rotor
            // reaction (G2) acts at once.
            now.speed_dot[i] = (speed_dot + speed_ddot * self.speed_lag_s) / SPEED_DOT_SCALE;
        }
        if !regress {
            return Regression::None;
        }
        // This sample's regression, on the increment from `decimation` centred samples back.
        // The ring holds the centred samples of the last cycle; `now` takes the oldest's place
        // after it has been read.
        let count = self.centred_count;
        self.centred_count = count.saturating_add(1);
        let decimation = u32::from(self.decimation);
        let last = self.centred[count.wrapping_sub(decimation) as usize % CENTRED_RING];
        self.centred[count as usize % CENTRED_RING] = now;
        if count < decimation {
            return Regression::None;
        }
        if decimation == 1 {
            for k in 0..3 {
                self.regress_force_row(k, &last, &now);
                self.finish_pending();
                self.regress_rotation_row(k, &last, &now);
                self.finish_pending();
            }
            return Regression::All;
        }
        // The cycle: the three force rows, then the three rotational rows, each over
        // `samples_per_row` samples: begun on the first, carried on by every sample
        // (`advance`, above).
        let samples_per_row = usize::from(self.samples_per_row);
        let k = (count % decimation) as usize;
        let (row, part) = (k / samples_per_row, k % samples_per_row);
        if part == 0 {
            // Normally finished by now (the row before took its samples); after a gap, here.
            self.finish_pending();
            if row < 3 {
                self.regress_force_row(row, &last, &now);
            } else {
                self.regress_rotation_row(row - 3, &last, &now);
            }
            self.advance_by(self.work_per_sample() - self.formation_work());
        }
        match (part + 1 < samples_per_row, row < 3) {
            (true, _) => Regression::Begun,
            (false, true) => Regression::ForceRow(row as u8),
            (false, false) => Regression::RotationRow((row - 3) as u8),
        }
    }

    /// Samples a cycle of the regressions takes (every row's turn once): the interval at which
    /// the learner publishes.
    pub fn cycle_samples(&self) -> u8 {
        self.decimation
    }

    /// Carries the row update in progress on by one sample's share of work: half of a balance
    /// row's update and formation (`work_per_sample`; a force row's whole update is
    /// less). [`EffectivenessEstimator::update`] does it
    /// on every sample; call it on the samples in between when the estimator is fed fewer
    /// samples than the caller's (the held samples without speed telemetry), so that a row
    /// begun in one is finished in the next.
    pub fn advance(&mut self) {
        self.advance_by(self.work_per_sample());
    }

    /// A sample's share of a row's work, covariance entries: half of the balance row's update
    /// (`2 n (n + 1)/2` entries) and of its formation ([`Self::formation_work`]), so that the
    /// row's two samples carry equal loads.
    fn work_per_sample(&self) -> usize {
        (2 * packed_len(self.rotation.len()) + self.formation_work()) / 2
    }

    /// What forming a row's regressors and high-passing them costs, counted in covariance
    /// entries of its update: a quarter of its product (see [`ROW_FORMATION_DIVISOR`]).
    fn formation_work(&self) -> usize {
        packed_len(self.rotation.len()) / ROW_FORMATION_DIVISOR
    }

    /// [`EffectivenessEstimator::advance`] by `budget` covariance entries.
    fn advance_by(&mut self, budget: usize) {
        if self.force_update.is_pending() {
            let _ = self.force.advance(&mut self.force_update, budget);
        } else if self.rotation_update.is_pending() {
            let _ = self.rotation.advance(&mut self.rotation_update, budget);
        }
    }

    /// Finishes the row update in progress, if any: before the next row begins (normally
    /// already finished by then) and before the estimates are read for a publication that
    /// must not change afterwards.
    pub fn finish_pending(&mut self) {
        if self.force_update.is_pending() {
            let _ = self.force.advance(&mut self.force_update, usize::MAX);
        }
        if self.rotation_update.is_pending() {
            let _ = self.rotation.advance(&mut self.rotation_update, usize::MAX);
        }
    }

    /// Force row `k`: (Δf_cog + w × f_cog)ₖ = (G1f Δ(ω²) + w × (G1f ω²))ₖ, parameters
    /// G1f[axis][i] at index 3i + axis; the regressor is Δ(ω²)ᵢ on (i, k) and the cross-product
    /// terms.
    fn regress_force_row(&mut self, k: usize, last: &Centred, now: &Centred) {
        let m = self.motors;
        let n = 3 * m + 3;
        let w = now.rate * self.increment_s;
        let y = (now.f_cog - last.f_cog) + w.cross(&last.f_cog);
        let mut x = [0.0f32; FORCE_PARAMETERS_MAX + 1];
        for i in 0..m {
            let (du, u) = (now.speed2[i] - last.speed2[i], last.speed2[i]);
            let column = &mut x[3 * i..3 * i + 3];
            // (w × g)ₖ = w_{k+1} g_{k+2} − w_{k+2} g_{k+1} (indices mod 3).
            column[k] = du;
            column[(k + 2) % 3] = w[(k + 1) % 3] * u;
            column[(k + 1) % 3] = -w[(k + 2) % 3] * u;
        }
        // −(w × b)ₖ = −w_{k+1} b_{k+2} + w_{k+2} b_{k+1}.
        let bias = &mut x[3 * m..3 * m + 3];
        bias[k] = 0.0;
        bias[(k + 2) % 3] = -w[(k + 1) % 3];
        bias[(k + 1) % 3] = w[(k + 2) % 3];
        x[n] = y[k];
        let all = 0..n + 1;
        self.force_high_pass[k].apply(&mut x, [all], self.high_pass_pole);
        // Refused (a non-finite regressor): nothing begun, as the update would change nothing.
        let _ = self.force.begin(&x[..n], &[x[n]], &mut self.force_update);
    }

    /// Rotational row `k` of the angular-momentum balance
    /// `J Ω̇ + Ω × (J Ω) + Ω × (K ω) + K ω̇ = T ω²` on increments, with `J_zz = 1 − J_xx − J_yy`
    /// moved to the output side: `T` at `axis·m + i` (regressor Δ(ω²)ᵢ on row k only), `K` at
    /// `3m + 3i + axis`, the five free entries of `J` from `6m`.
    ///
    /// Row k's torque regressors of the other two axes are zero by construction: the torques
    /// are stored axis by axis so that they form two whole blocks, which the high-pass skips and
    /// the RLS's product `P x` skips in pairs ([`super::rls`]): on the quad's balance-row
    /// sample, the row's 8 zero regressors of 29.
    fn regress_rotation_row(&mut self, k: usize, last: &Centred, now: &Centred) {
        let m = self.motors;
        let n = 6 * m + INERTIA_PARAMETERS;
        let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
        let mut x = [0.0f32; ROT_PARAMETERS_MAX + 1];
        for i in 0..m {
            x[Self::torque_index(m, i, k)] = now.speed2[i] - last.speed2[i];
            // −(Ω × Kᵢ ωᵢ + Kᵢ ω̇ᵢ)ₖ with (Ω × v)ₖ = Ω_{k+1} v_{k+2} − Ω_{k+2} v_{k+1}.
            let d = |a: usize| now.momentum_products[3 * i + a] - last.momentum_products[3 * i + a];
            let momentum = &mut x[3 * m + 3 * i..3 * m + 3 * i + 3];
            momentum[k] = -(now.speed_dot[i] - last.speed_dot[i]);
            momentum[k2] = -d(k1);
            momentum[k1] = d(k2);
        }
        // On increments of the filtered signals.
        let rate_dot = now.rate_dot - last.rate_dot;
        let product = |a: usize, b: usize| {
            let j = rate_product(a, b);
            now.rate_products[j] - last.rate_products[j]
        };
        let (inertia, zz) = inertia_regressors(k, [rate_dot.x, rate_dot.y, rate_dot.z], product);
        x[6 * m..6 * m + INERTIA_PARAMETERS].copy_from_slice(&inertia);
        x[n] = zz;
        // The other axes' torque regressors stay zero: not filtered.
        let channels = [k * m..(k + 1) * m, 3 * m..n + 1];
        self.rotation_high_pass[k].apply(&mut x, channels, self.high_pass_pole);
        let _ = self.rotation.begin(&x[..n], &[x[n]], &mut self.rotation_update);
    }

    /// The prior of the normalised inertia: a sphere's ([`InertiaPrior::sphere`]).
    fn reset_inertia(&mut self) {
        self.set_inertia_prior(&InertiaPrior::sphere());
    }

    /// Replace the prior of the normalised inertia (mean and covariance), e.g. by the one the
    /// free tumble after the release gave ([`super::inertia`]). Before the first update only: it
    /// overwrites the estimate. A non-finite prior is refused and changes nothing.
    #[inline(never)]
    pub fn set_inertia_prior(&mut self, prior: &InertiaPrior) {
        let finite =
            prior.mean.iter().chain(prior.covariance.iter().flatten()).all(|v| v.is_finite());
        if !finite {
            return;
        }
        let base = 6 * self.motors;
        for i in 0..INERTIA_PARAMETERS {
            self.rotation.set_theta(base + i, 0, prior.mean[i]);
            for j in i..INERTIA_PARAMETERS {
                self.rotation.set_prior_covariance(base + i, base + j, prior.covariance[i][j]);
            }
        }
    }

    /// The normalised inertia `J = I / tr I` estimated so far, IMU axes.
    pub fn normalised_inertia(&self) -> Matrix3<f32> {
        let t = |j: usize| self.rotation.theta(6 * self.motors + j, 0);
        let (xx, yy, xy, xz, yz) = (t(0), t(1), t(2), t(3), t(4));
        Matrix3::new(xx, xy, xz, xy, yy, yz, xz, yz, 1.0 - xx - yy)
    }

    /// Index of `T[axis][i]` (motor `i`'s torque about `axis` over `tr I`) in the balance's
    /// parameters, for `m` motors: axis by axis.
    const fn torque_index(m: usize, i: usize, axis: usize) -> usize {
        axis * m + i
    }

    /// Column `i` of `T` (torque per squared speed over `tr I`) and of `K` (rotor momentum per
    /// speed over `tr I`), in the regression's units.
    fn torque_and_momentum(&self, i: usize) -> (Vector3<f32>, Vector3<f32>) {
        let m = self.motors;
        let t = Vector3::from_fn(|k, _| self.rotation.theta(Self::torque_index(m, i, k), 0));
        let h = Vector3::from_fn(|k, _| self.rotation.theta(3 * m + 3 * i + k, 0));
        (t, h)
    }

    /// Number of motors.
    pub fn motors(&self) -> usize {
        self.motors
    }

    /// G1 per unit squared speed: rows 0–2 m/s², rows 3–5 rad/s², per (rad/s)², IMU axes. The
    /// rotational rows are `J⁻¹ T`, zero while the inertia estimate is singular.
    pub fn g1_per_speed2(&self) -> [[f32; MAX_MOTORS]; 6] {
        let mut g1 = [[0.0; MAX_MOTORS]; 6];
        let inverse = self.normalised_inertia().try_inverse().unwrap_or_default();
        for i in 0..self.motors {
            let torque = inverse * self.torque_and_momentum(i).0 / SPEED2_SCALE;
            for k in 0..3 {
                g1[k][i] = self.force.theta(3 * i + k, 0) / SPEED2_SCALE;
                g1[3 + k][i] = torque[k];
            }
        }
        g1
    }

    /// G2, rad/s² of body angular acceleration per rad/s² of motor acceleration, IMU axes:
    /// `−J⁻¹ K`, zero while the inertia estimate is singular.
    pub fn g2(&self) -> [[f32; MAX_MOTORS]; 3] {
        let mut g2 = [[0.0; MAX_MOTORS]; 3];
        let inverse = self.normalised_inertia().try_inverse().unwrap_or_default();
        for i in 0..self.motors {
            let column = -(inverse * self.torque_and_momentum(i).1) / SPEED_DOT_SCALE;
            for k in 0..3 {
                g2[k][i] = column[k];
            }
        }
        g2
    }

    /// What is known of motor `i`'s columns ([`ColumnStatistics`]), the information left with
    /// the prior's diagonal `p0`. Both figures read the same covariance diagonals, read once
    /// here (the learner's staging asks for both of every motor), and the square root is the
    /// FPU's (`crate::math::sqrt`, libm's value bit for bit; `libm::sqrtf` is a software loop of
    /// about 50 instructions).
    pub fn column_statistics(&self, i: usize, p0: f32) -> ColumnStatistics {
        let per_sample = 1.0 / f32::from(self.decimation);
        let relative = |rls_p: f32, var: [f32; 3], theta: [f32; 3]| {
            let norm2 = theta.iter().map(|t| t * t).sum::<f32>();
            let var_sum = var.iter().sum::<f32>() * rls_p * per_sample;
            if norm2 > 0.0 {
                crate::math::sqrt(var_sum / norm2)
            } else {
                f32::INFINITY
            }
        };
        let force_p = (0..3).map(|k| self.force.p_diag(3 * i + k)).fold(0.0, f32::max);
        let torque_p = (0..3)
            .map(|k| self.rotation.p_diag(Self::torque_index(self.motors, i, k)))
            .fold(0.0, f32::max);
        let f = relative(
            force_p,
            [self.force.error_var(0); 3],
            core::array::from_fn(|k| self.force.theta(3 * i + k, 0)),
        );
        let t = relative(
            torque_p,
            [self.rotation.error_var(0); 3],
            core::array::from_fn(|k| self.rotation.theta(Self::torque_index(self.motors, i, k), 0)),
        );
        ColumnStatistics { relative_std: (f, t), information_left: (force_p / p0, torque_p / p0) }
    }
}

/// What is known of one motor's columns of G1, force rows then rotational rows
/// ([`EffectivenessEstimator::column_statistics`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColumnStatistics {
    /// Relative standard deviation of the column of G1f and of G1τ (one σ of the column's norm
    /// over the norm), from the covariance and the a-priori residuals. Referred to increments
    /// over one sample, as it was defined: the residuals of increments over `decimation`
    /// samples are about `decimation` times larger and the covariance of the same data about
    /// `decimation` times smaller, so their product is about `decimation` times larger.
    pub relative_std: (f32, f32),
    /// How much has been learned: the covariance diagonal of the motor's squared-speed
    /// regressor relative to the prior (1: nothing yet; small: well excited).
    ///
    /// Not rescaled for the decimation: the learner's gate on it
    /// ([`super::AXIS_INFORMATION_FRACTION`]) is crossed in the first milliseconds of a pulse,
    /// while the prior still dominates `P`, and the decimated regressions cross it when the
    /// every-sample ones did (the simulator's paper quad, measured with four regressions per
    /// cycle: first thrust axis 163.5 ms into the excitation, 161.5 ms at every sample;
    /// referring `P` to one-sample increments, × 4, would delay it to 221.5 ms; with the six of
    /// the angular-momentum balance: 166.5 ms).
    pub information_left: (f32, f32),
}

/// A first-order high-pass (DC blocker) over `N` channels: `y[n] = p·y[n−1] + x[n] − x[n−1]`.
#[derive(Clone, Copy, Debug)]
struct HighPass<const N: usize> {
    input: [f32; N],
    output: [f32; N],
    primed: bool,
}

impl<const N: usize> Default for HighPass<N> {
    fn default() -> Self {
        Self { input: [0.0; N], output: [0.0; N], primed: false }
    }
}

impl<const N: usize> HighPass<N> {
    /// Filter the channels in the ranges `channels` of `x` in place (the others are left
    /// alone: channels that are zero by construction). The first call only primes the state
    /// with the input, so a signal that starts at a non-zero level gives no transient.
    fn apply<const R: usize>(
        &mut self,
        x: &mut [f32],
        channels: [core::ops::Range<usize>; R],
        pole: f32,
    ) {
        for range in channels {
            let end = range.end.min(N).min(x.len());
            let start = range.start.min(end);
            let states = self.input[start..end].iter_mut().zip(&mut self.output[start..end]);
            for (value, (input, output)) in x[start..end].iter_mut().zip(states) {
                let out = if self.primed { pole * *output + *value - *input } else { 0.0 };
                *input = *value;
                *output = out;
                *value = out;
            }
        }
        self.primed = true;
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use nalgebra::Matrix3;

    /// A tumbling rigid body with `m` motors whose squared speeds produce torque and force
    /// (exact model: `I Ω̇ = Σ tᵢ ωᵢ² − Ω × IΩ`, `f = Σ fᵢ ωᵢ²`), motors pulsed one after the
    /// other through first-order lags, sampled at 2 kHz (mean of four 8 kHz samples), IMU at the
    /// centre of gravity. Returns the relative RMS errors of the force and torque blocks.
    fn identify_synthetic(
        inertia: Matrix3<f64>,
        omega_max: f64,
        tau_s: f64,
        decimation: u8,
    ) -> (f64, f64, EffectivenessEstimator) {
        let rate = nalgebra::Vector3::new(7.0, 7.0, 1.7);
        identify_thrown(inertia, omega_max, tau_s, decimation, rate, None, 0.0)
    }

    /// [`identify_synthetic`] thrown at `rate` (rad/s), with the exact normalised inertia as
    /// the balance's prior when `exact_inertia` gives its variance, and the estimator primed
    /// for `prime_s` of free tumble (motors stopped) before the motors start.
    fn identify_thrown(
        inertia: Matrix3<f64>,
        omega_max: f64,
        tau_s: f64,
        decimation: u8,
        rate: nalgebra::Vector3<f64>,
        exact_inertia: Option<f32>,
        prime_s: f64,
    ) -> (f64, f64, EffectivenessEstimator) {
        let m = 8;
        let arm = 0.3;
        let kf = 3e-5_f64;
        let inv = inertia.try_inverse().unwrap();
        let mass = 2.5;
        let mut torque_cols = std::vec::Vec::new();
        let mut force_cols = std::vec::Vec::new();
        for i in 0..m {
            let a = core::f64::consts::TAU * (i as f64 + 0.5) / m as f64;
            let r = nalgebra::Vector3::new(arm * a.cos(), arm * a.sin(), 0.0);
            let n = nalgebra::Vector3::new(0.0, 0.0, -1.0);
            let spin = if i % 2 == 0 { 1.0 } else { -1.0 };
            let t = r.cross(&(n * kf)) - n * (spin * kf * 0.015);
            torque_cols.push(inv * t);
            force_cols.push(n * kf / mass);
        }
        let filter = BiquadCoefficients::butterworth_lowpass(20.0, 2000.0).unwrap();
        let config = RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 };
        // Speeds sampled at the end of each 2 kHz sample, the gyro averaged over it: the speeds
        // are 187.5 µs *newer* than the IMU sample.
        let mut est = EffectivenessEstimator::new(EffectivenessSetup {
            motors: m,
            rate_hz: 2000.0,
            filter,
            r_imu_m: [0.0; 3],
            speed_lag_s: -187.5e-6,
            rls: config,
        })
        .with_decimation(decimation);
        if let Some(variance) = exact_inertia {
            let j = inertia / inertia.trace();
            let mut prior = InertiaPrior::sphere();
            prior.mean = [j[(0, 0)], j[(1, 1)], j[(0, 1)], j[(0, 2)], j[(1, 2)]].map(|v| v as f32);
            prior.covariance = [[0.0; INERTIA_PARAMETERS]; INERTIA_PARAMETERS];
            for (k, row) in prior.covariance.iter_mut().enumerate() {
                row[k] = variance;
            }
            est.set_inertia_prior(&prior);
        }
        let mut rate = rate;
        let mut speed = [0.0f64; 8];
        let dt = 1.0 / 8000.0;
        let idle = 0.1 * omega_max;
        let primed = (prime_s * 2000.0).round() as usize;
        for n in 0..2000 + primed {
            let mut gyro = nalgebra::Vector3::zeros();
            let mut accel = nalgebra::Vector3::zeros();
            for j in 0..4 {
                let t = (4 * n as i64 - 4 * primed as i64 + j) as f64 * dt;
                for (i, w) in speed.iter_mut().enumerate() {
                    if t < 0.0 {
                        continue; // stopped before the excitation
                    }
                    // The default excitation for this τ: step τ, ramp 2τ, start every 2τ.
                    let local = t - 2.0 * tau_s * i as f64;
                    let command: f64 = if (0.0..tau_s).contains(&local) {
                        0.5
                    } else if (tau_s..3.0 * tau_s).contains(&local) {
                        1.0 - (local - tau_s) / (2.0 * tau_s)
                    } else {
                        0.0
                    };
                    let target = idle + (omega_max - idle) * command.sqrt();
                    *w += (target - *w) / tau_s * dt;
                }
                let mut torque = nalgebra::Vector3::zeros();
                let mut force = nalgebra::Vector3::zeros();
                for i in 0..m {
                    torque += torque_cols[i] * speed[i] * speed[i];
                    force += force_cols[i] * speed[i] * speed[i];
                }
                let euler = -inv * rate.cross(&(inertia * rate));
                rate += (torque + euler) * dt;
                gyro += rate / 4.0;
                accel += force / 4.0;
            }
            let speeds: [f32; 8] = core::array::from_fn(|i| speed[i] as f32);
            let (gyro, accel) = (gyro.map(|x| x as f32).into(), accel.map(|x| x as f32).into());
            if n < primed {
                est.prime(gyro, accel, &speeds);
            } else {
                est.update(gyro, accel, &speeds);
            }
        }
        let g1 = est.g1_per_speed2();
        let block = |rows: core::ops::Range<usize>, truth: &dyn Fn(usize, usize) -> f64| {
            let (mut err, mut norm) = (0.0, 0.0);
            for k in rows.clone() {
                for i in 0..m {
                    let t = truth(k - rows.start, i);
                    err += (f64::from(g1[k][i]) - t).powi(2);
                    norm += t * t;
                }
            }
            (err / norm).sqrt()
        };
        let force = block(0..3, &|k, i| force_cols[i][k]);
        let torque = block(3..6, &|k, i| torque_cols[i][k]);
        (force, torque, est)
    }

    #[test]
    fn an_exact_tumbling_octorotor_is_identified_within_a_percent() {
        // Strong motors (ω_max 3000 rad/s) on an axisymmetric body spinning at (7, 7, 1.7) rad/s:
        // the Euler term precesses the rates, the model accounts for it.
        let axisymmetric = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.06, 0.06, 0.11));
        let (force, torque, estimator) =
            identify_synthetic(axisymmetric, 3000.0, 0.025, REGRESSIONS);
        // The balance learns the body's normalised inertia J = I / tr I on the way (measured:
        // every entry within 0.004 of diag(0.261, 0.261, 0.478)).
        let truth = axisymmetric.map(|v| v as f32) / axisymmetric.trace() as f32;
        let inertia_error = (estimator.normalised_inertia() - truth).abs().max();
        assert!(inertia_error < 0.01, "J off by {inertia_error}");
        std::eprintln!(
            "axisymmetric, strong motors: force {:.2} %, torque {:.2} %",
            force * 1e2,
            torque * 1e2
        );
        assert!(force < 0.002 && torque < 0.01, "force {force}, torque {torque}");
        // Weak motors (ω_max 1100 rad/s, the library's octorotor): the pulses change the rates
        // less than the precession does, and the rows lose accuracy (measured 0.3 % and 4.6 %).
        let (force, torque, _) = identify_synthetic(axisymmetric, 1100.0, 0.025, REGRESSIONS);
        std::eprintln!(
            "axisymmetric, weak motors: force {:.2} %, torque {:.2} %",
            force * 1e2,
            torque * 1e2
        );
        assert!(force < 0.03 && torque < 0.06, "force {force}, torque {torque}");
    }

    /// Thrown at 800 and 1,000 °/s about an axis far from every principal one, an asymmetric
    /// octorotor with weak motors (the precession then changes the rates as fast as the pulses
    /// do), its exact `J` given: primed through 100 ms of the free fall before the motors start,
    /// the torque block is within 2 % (measured 0.75 % and 0.77 %; started cold at the first
    /// motor sample, as before priming, 21 % at 800 °/s: the filters' start took the precessing
    /// body for a steady one).
    #[test]
    fn a_fast_tumble_primes_the_filters_and_the_torques_are_found_within_two_percent() {
        let body = Matrix3::new(0.05, 0.004, -0.003, 0.004, 0.07, 0.005, -0.003, 0.005, 0.11);
        let axis = nalgebra::Vector3::new(7.0, -9.0, 8.0).normalize();
        for spin_dps in [800.0f64, 1000.0] {
            let rate = axis * spin_dps.to_radians();
            let (force, torque, _) =
                identify_thrown(body, 1100.0, 0.025, REGRESSIONS, rate, Some(1e-8), 0.1);
            std::eprintln!(
                "{spin_dps} °/s, primed: force {:.2} %, torque {:.2} %",
                force * 1e2,
                torque * 1e2
            );
            assert!(
                force < 0.01 && torque < 0.02,
                "{spin_dps} °/s: force {force}, torque {torque}"
            );
        }
    }

    /// The regressions taking turns (each row every twelfth sample at 2 kHz, its update spread
    /// over two samples) learn G1 about as well as the same regressions at every sample: errors
    /// against the truth within 0.3 percentage points with strong motors and 4 with weak ones
    /// (where the body's own rotation is larger than the pulses' effect and the data leave the
    /// inertia loosely determined: half the rows inform it half as much in this one second).
    /// Measured: force 0.04 / 0.05 %, torque 0.69 / 1.11 % (strong, taking turns / every
    /// sample); force 0.14 / 1.85 %, torque 5.9 / 2.1 % (weak; 4.6 % with a row every sixth
    /// sample, before 2026-12-05). On 1,000 random worlds the two cycles learn alike (see
    /// [`MAX_ROW_RATE_HZ`]).
    #[test]
    fn decimated_regressions_learn_what_every_sample_regressions_learn() {
        let axisymmetric = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.06, 0.06, 0.11));
        for (omega_max, tolerance) in [(3000.0, 0.003), (1100.0, 0.04)] {
            let (every_force, every_torque, _) =
                identify_synthetic(axisymmetric, omega_max, 0.025, 1);
            let (force, torque, _) =
                identify_synthetic(axisymmetric, omega_max, 0.025, REGRESSIONS);
            std::eprintln!(
                "ω_max {omega_max}: force {:.2} / {:.2} %, torque {:.2} / {:.2} % \
                 (decimated / every sample)",
                force * 1e2,
                every_force * 1e2,
                torque * 1e2,
                every_torque * 1e2
            );
            assert!(
                force < every_force + tolerance && torque < every_torque + tolerance,
                "ω_max {omega_max}: force {force} vs {every_force}, torque {torque} vs \
                 {every_torque}"
            );
        }
    }
}
