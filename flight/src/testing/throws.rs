//! Synthetic calibration throws: a rigid body held, thrown (spinning), tumbling torque-free,
//! caught and held again, seen by an IMU at offset `r` from the centre of gravity.
//!
//! Phases (all in the IMU frame for body quantities, NED for world quantities):
//! 1. *rest*: held still (`Ω = 0`, CG acceleration 0).
//! 2. *wind-up*: the hand accelerates the CG along `throw_dir_world` with `peak·sin²(πs)` (or, with
//!    [`WindupProfile::Taper`], at `peak` until a raised-cosine taper to zero over the push's last
//!    `taper_s`) and spins the body up smoothly (`Ω = Ω_release · smoothstep(s)`), `s ∈ [0, 1]`.
//! 3. *free fall*: gravity and quadratic drag `−k |v| v` only; torque-free Euler equations
//!    `I Ω̇ = −Ω × (I Ω)` for the given (full, possibly non-diagonal) inertia tensor.
//! 4. *catch*: the hand takes up the weight smoothly (`g (1 − smoothstep(s))` of fall left) and
//!    cancels the velocity with a `sin²` pulse, and stops the spin smoothly.
//! 5. *rest* again.
//!
//! The state (attitude, rate, velocity) is integrated with RK4 at no less than 8 kHz. Each sample
//! gives the exact specific force at `r`,
//! `f = Rᵀ(a_cg − g) + Ω̇ × r + Ω × (Ω × r)`, plus bias, white noise and 16-bit quantisation.

extern crate std;

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::imu::ImuSample;
use crate::rng::Rng;

/// Standard gravity (m/s²), down in NED.
pub const G_MPS2: f64 = 9.80665;
/// Gyro full scale ±2000 °/s (rad/s), 16-bit signed output.
pub const GYRO_FULL_SCALE_RADPS: f64 = 2000.0 * core::f64::consts::PI / 180.0;
/// Accelerometer full scale ±16 g (m/s²), 16-bit signed output.
pub const ACC_FULL_SCALE_MPS2: f64 = 16.0 * G_MPS2;
/// Slowest integration rate (Hz): each sample is reached by RK4 sub-steps at least this fine.
const MIN_INTEGRATION_RATE_HZ: f64 = 8000.0;

/// How the hand's acceleration varies over the wind-up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WindupProfile {
    /// `peak · sin²(π s)`: a push that builds up and fades out over the whole wind-up.
    SinSquared,
    /// The hand's push (its force per unit mass, the specific force the IMU reads apart from the
    /// rotational terms) is `peak` along `throw_dir_world` until the last `taper_s` of the
    /// wind-up, then tapers to zero with a raised cosine: a firm push whose hand lets go over
    /// `taper_s` (0: at once), so the specific force falls continuously to free fall. The CG
    /// accelerates by the push plus gravity.
    Taper {
        /// Duration of the taper, s.
        taper_s: f64,
    },
}

impl WindupProfile {
    /// The fraction of the peak acceleration at wind-up position `s ∈ [0, 1]` of `windup_s`.
    pub fn shape(&self, s: f64, windup_s: f64) -> f64 {
        match *self {
            WindupProfile::SinSquared => sin2(s),
            WindupProfile::Taper { taper_s } => {
                let k = (taper_s / windup_s).clamp(0.0, 1.0);
                let into_taper = s - (1.0 - k);
                if into_taper <= 0.0 {
                    1.0
                } else {
                    0.5 * (1.0 + libm::cos(core::f64::consts::PI * (into_taper / k).min(1.0)))
                }
            }
        }
    }

    /// `∫ shape ds` over the wind-up: the push's speed is `peak · windup_s` times this.
    pub fn mean_shape(&self, windup_s: f64) -> f64 {
        match *self {
            WindupProfile::SinSquared => 0.5,
            WindupProfile::Taper { taper_s } => 1.0 - 0.5 * (taper_s / windup_s).clamp(0.0, 1.0),
        }
    }
}

/// Everything that defines one synthetic throw.
#[derive(Debug, Clone)]
pub struct ThrowSpec {
    /// IMU sample rate (Hz).
    pub rate_hz: f64,
    /// IMU offset from the centre of gravity (m, IMU frame): the truth.
    pub r_imu_m: Vector3<f64>,
    /// Inertia tensor about the CG (kg·m², IMU frame).
    pub inertia_kgm2: Matrix3<f64>,
    /// Body rate at release (rad/s, IMU frame).
    pub release_rate_radps: Vector3<f64>,
    /// Attitude at the start (rotates IMU coordinates into NED).
    pub initial_attitude: UnitQuaternion<f64>,
    /// Held still before the wind-up (s).
    pub rest_before_s: f64,
    /// Wind-up duration (s).
    pub windup_s: f64,
    /// Peak CG acceleration of the wind-up (m/s²).
    pub windup_peak_mps2: f64,
    /// Direction of the wind-up acceleration (NED unit vector; upwards is −z).
    pub throw_dir_world: Vector3<f64>,
    /// How the wind-up's acceleration varies.
    pub windup_profile: WindupProfile,
    /// Free-fall duration (s).
    pub free_fall_s: f64,
    /// Catch duration (s).
    pub catch_s: f64,
    /// Held still after the catch (s).
    pub rest_after_s: f64,
    /// Quadratic drag coefficient `k` in `a = −k |v| v` (1/m).
    pub drag_per_m: f64,
    /// Constant accelerometer bias (m/s²).
    pub acc_bias_mps2: Vector3<f64>,
    /// White gyro noise per sample, standard deviation (rad/s).
    pub gyro_noise_radps: f64,
    /// White accelerometer noise per sample, standard deviation (m/s²).
    pub acc_noise_mps2: f64,
    /// Round to 16-bit codes at the full scales above.
    pub quantise: bool,
    /// Noise seed.
    pub seed: u64,
}

/// The inertia tensor `R diag(principal) Rᵀ` of a body whose principal axes are the columns of
/// `R = principal_axes` (IMU frame).
pub fn inertia_from_principal(
    principal_kgm2: Vector3<f64>,
    principal_axes: &UnitQuaternion<f64>,
) -> Matrix3<f64> {
    let r = principal_axes.to_rotation_matrix().into_inner();
    r * Matrix3::from_diagonal(&principal_kgm2) * r.transpose()
}

impl ThrowSpec {
    /// A realistic throw of a 5-inch-class quad (inertia 2.5/2.8/4.6 g·m², principal axes rotated
    /// from the IMU by `principal_axes`): 0.3 s rest, 0.3 s wind-up at 2 g (about 3 g of specific
    /// force), 0.6 s free fall, 0.3 s catch, 0.3 s rest; drag `k = 0.01 /m` (≈ 0.1 m/s² at 3 m/s);
    /// gyro noise 0.002 rad/s, accelerometer noise 0.03 m/s², 16-bit quantisation.
    pub fn typical(
        rate_hz: f64,
        r_imu_m: Vector3<f64>,
        principal_axes: UnitQuaternion<f64>,
        release_rate_radps: Vector3<f64>,
        seed: u64,
    ) -> Self {
        Self {
            rate_hz,
            r_imu_m,
            inertia_kgm2: inertia_from_principal(
                Vector3::new(2.5e-3, 2.8e-3, 4.6e-3),
                &principal_axes,
            ),
            release_rate_radps,
            initial_attitude: UnitQuaternion::identity(),
            rest_before_s: 0.3,
            windup_s: 0.3,
            windup_peak_mps2: 2.0 * G_MPS2,
            throw_dir_world: Vector3::new(0.3, 0.0, -1.0).normalize(),
            windup_profile: WindupProfile::SinSquared,
            free_fall_s: 0.6,
            catch_s: 0.3,
            rest_after_s: 0.3,
            drag_per_m: 0.01,
            acc_bias_mps2: Vector3::zeros(),
            gyro_noise_radps: 0.002,
            acc_noise_mps2: 0.03,
            quantise: true,
            seed,
        }
    }

    /// Index of the first free-fall sample.
    pub fn release_index(&self) -> usize {
        libm::round((self.rest_before_s + self.windup_s) * self.rate_hz) as usize
    }

    /// Index of the first sample of the catch.
    pub fn catch_index(&self) -> usize {
        libm::round((self.rest_before_s + self.windup_s + self.free_fall_s) * self.rate_hz) as usize
    }

    /// Total number of samples.
    pub fn len(&self) -> usize {
        let total = self.rest_before_s
            + self.windup_s
            + self.free_fall_s
            + self.catch_s
            + self.rest_after_s;
        libm::round(total * self.rate_hz) as usize
    }

    /// True when the throw has no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The samples, generated on the fly.
    pub fn samples(&self) -> ThrowSamples {
        ThrowSamples::new(self.clone())
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Rest,
    Windup,
    FreeFall,
    Catch,
}

#[derive(Debug, Clone, Copy)]
struct State {
    attitude: Quaternion<f64>,
    rate_radps: Vector3<f64>,
    velocity_mps: Vector3<f64>,
}

/// Iterator over the samples of a [`ThrowSpec`].
#[derive(Debug, Clone)]
pub struct ThrowSamples {
    spec: ThrowSpec,
    inertia_inv: Matrix3<f64>,
    rng: Rng,
    index: usize,
    state: State,
    /// Rate and velocity when the catch began.
    at_catch: Option<(Vector3<f64>, Vector3<f64>)>,
    substeps: usize,
}

/// `smoothstep(s) = 3s² − 2s³` and its derivative, clamped to [0, 1].
fn smoothstep(s: f64) -> (f64, f64) {
    let s = s.clamp(0.0, 1.0);
    (s * s * (3.0 - 2.0 * s), 6.0 * s * (1.0 - s))
}

fn sin2(s: f64) -> f64 {
    let v = libm::sin(core::f64::consts::PI * s.clamp(0.0, 1.0));
    v * v
}

impl ThrowSamples {
    fn new(spec: ThrowSpec) -> Self {
        let inertia_inv = spec.inertia_kgm2.try_inverse().unwrap_or_else(Matrix3::identity);
        let substeps = libm::ceil(MIN_INTEGRATION_RATE_HZ / spec.rate_hz).max(1.0) as usize;
        Self {
            rng: Rng::new(spec.seed),
            state: State {
                attitude: spec.initial_attitude.into_inner(),
                rate_radps: Vector3::zeros(),
                velocity_mps: Vector3::zeros(),
            },
            spec,
            inertia_inv,
            index: 0,
            at_catch: None,
            substeps,
        }
    }

    fn phase_at(&self, index_time: f64) -> (Phase, f64) {
        let s = &self.spec;
        let t1 = s.rest_before_s;
        let t2 = t1 + s.windup_s;
        let t3 = t2 + s.free_fall_s;
        let t4 = t3 + s.catch_s;
        // Phase boundaries fall on sample instants; a tiny tolerance keeps rounding from
        // selecting the previous phase exactly at a boundary.
        let t = index_time + 1e-9;
        if t < t1 {
            (Phase::Rest, 0.0)
        } else if t < t2 {
            (Phase::Windup, (index_time - t1) / s.windup_s)
        } else if t < t3 {
            (Phase::FreeFall, 0.0)
        } else if t < t4 {
            (Phase::Catch, (index_time - t3) / s.catch_s)
        } else {
            (Phase::Rest, 0.0)
        }
    }

    /// Rate derivative (rad/s², IMU) and CG acceleration (m/s², NED) at phase position `s`.
    fn dynamics(&self, phase: Phase, s: f64, state: &State) -> (Vector3<f64>, Vector3<f64>) {
        let spec = &self.spec;
        let g = Vector3::new(0.0, 0.0, G_MPS2);
        match phase {
            Phase::Rest => (Vector3::zeros(), Vector3::zeros()),
            Phase::Windup => {
                let (_, ds) = smoothstep(s);
                let rate_dot = spec.release_rate_radps * ds / spec.windup_s;
                let shape = spec.windup_profile.shape(s, spec.windup_s);
                let push = spec.throw_dir_world * spec.windup_peak_mps2 * shape;
                match spec.windup_profile {
                    WindupProfile::SinSquared => (rate_dot, push),
                    WindupProfile::Taper { .. } => (rate_dot, push + g),
                }
            }
            Phase::FreeFall => {
                let w = state.rate_radps;
                let rate_dot = -(self.inertia_inv * w.cross(&(spec.inertia_kgm2 * w)));
                let v = state.velocity_mps;
                (rate_dot, g - v * (spec.drag_per_m * v.norm()))
            }
            Phase::Catch => {
                let (w_c, v_c) = self.at_catch.unwrap_or((Vector3::zeros(), Vector3::zeros()));
                // Gravity support grows smoothly (ending at rest, a = 0) while a sin² pulse
                // removes the remaining velocity: ∫ g (1 − S) dt = g T/2.
                let (support, ds) = smoothstep(s);
                let hand = -(v_c + g * (0.5 * spec.catch_s)) * (2.0 / spec.catch_s * sin2(s));
                (-w_c * ds / spec.catch_s, g * (1.0 - support) + hand)
            }
        }
    }

    fn derivative(&self, phase: Phase, s: f64, x: &State) -> State {
        let (rate_dot, acc) = self.dynamics(phase, s, x);
        let w = x.rate_radps;
        State {
            attitude: x.attitude * Quaternion::new(0.0, w.x, w.y, w.z) * 0.5,
            rate_radps: rate_dot,
            velocity_mps: acc,
        }
    }

    fn step(&mut self, phase: Phase, s0: f64, ds_per_step: f64, h: f64) {
        let add = |x: &State, k: &State, f: f64| State {
            attitude: x.attitude + k.attitude * f,
            rate_radps: x.rate_radps + k.rate_radps * f,
            velocity_mps: x.velocity_mps + k.velocity_mps * f,
        };
        let x = self.state;
        let k1 = self.derivative(phase, s0, &x);
        let k2 = self.derivative(phase, s0 + 0.5 * ds_per_step, &add(&x, &k1, 0.5 * h));
        let k3 = self.derivative(phase, s0 + 0.5 * ds_per_step, &add(&x, &k2, 0.5 * h));
        let k4 = self.derivative(phase, s0 + ds_per_step, &add(&x, &k3, h));
        let mut next = State {
            attitude: x.attitude
                + (k1.attitude + k2.attitude * 2.0 + k3.attitude * 2.0 + k4.attitude) * (h / 6.0),
            rate_radps: x.rate_radps
                + (k1.rate_radps + k2.rate_radps * 2.0 + k3.rate_radps * 2.0 + k4.rate_radps)
                    * (h / 6.0),
            velocity_mps: x.velocity_mps
                + (k1.velocity_mps
                    + k2.velocity_mps * 2.0
                    + k3.velocity_mps * 2.0
                    + k4.velocity_mps)
                    * (h / 6.0),
        };
        next.attitude = next.attitude.normalize();
        if phase == Phase::Rest {
            next.rate_radps = Vector3::zeros();
            next.velocity_mps = Vector3::zeros();
        }
        self.state = next;
    }

    /// The attitude the body has reached (rotates IMU coordinates into NED): after the last
    /// sample, where the next throw of a session starts.
    pub fn attitude(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::from_quaternion(self.state.attitude)
    }

    fn quantise(value: f64, full_scale: f64) -> f64 {
        let lsb = full_scale / 32768.0;
        libm::round(value / lsb).clamp(-32768.0, 32767.0) * lsb
    }
}

impl Iterator for ThrowSamples {
    type Item = ImuSample;

    fn next(&mut self) -> Option<ImuSample> {
        if self.index >= self.spec.len() {
            return None;
        }
        let dt = 1.0 / self.spec.rate_hz;
        let t = self.index as f64 * dt;
        let (phase, s) = self.phase_at(t);
        if phase == Phase::Catch && self.at_catch.is_none() {
            self.at_catch = Some((self.state.rate_radps, self.state.velocity_mps));
        }

        // The exact measurement at this instant.
        let (rate_dot, acc_world) = self.dynamics(phase, s, &self.state);
        let w = self.state.rate_radps;
        let r = self.spec.r_imu_m;
        let attitude = UnitQuaternion::from_quaternion(self.state.attitude);
        let g = Vector3::new(0.0, 0.0, G_MPS2);
        let specific_force = attitude.inverse_transform_vector(&(acc_world - g))
            + rate_dot.cross(&r)
            + w.cross(&w.cross(&r))
            + self.spec.acc_bias_mps2;
        let mut gyro = w;
        let mut acc = specific_force;
        for v in gyro.iter_mut() {
            *v += self.spec.gyro_noise_radps * self.rng.normal();
        }
        for v in acc.iter_mut() {
            *v += self.spec.acc_noise_mps2 * self.rng.normal();
        }
        if self.spec.quantise {
            gyro = gyro.map(|v| Self::quantise(v, GYRO_FULL_SCALE_RADPS));
            acc = acc.map(|v| Self::quantise(v, ACC_FULL_SCALE_MPS2));
        }

        // Advance to the next sample.
        let h = dt / self.substeps as f64;
        let phase_len_s = match phase {
            Phase::Windup => self.spec.windup_s,
            Phase::Catch => self.spec.catch_s,
            _ => 1.0,
        };
        for k in 0..self.substeps {
            let s0 = s + k as f64 * h / phase_len_s;
            self.step(phase, s0, h / phase_len_s, h);
        }
        self.index += 1;
        Some(ImuSample { gyro_radps: gyro.cast::<f32>(), acc_mps2: acc.cast::<f32>() })
    }
}

/// One calibration session as the board sees it: the throws of `specs` one after the other in a
/// single stream, each starting in the attitude the previous catch left the craft in (the
/// `initial_attitude` of every spec but the first is replaced), so a rest after a catch and the
/// rest before the next throw are one pose held still.
pub fn session(specs: &[ThrowSpec]) -> std::vec::Vec<ImuSample> {
    let mut all = std::vec::Vec::new();
    let mut attitude = None;
    for spec in specs {
        let mut spec = spec.clone();
        if let Some(q) = attitude {
            spec.initial_attitude = q;
        }
        let mut samples = spec.samples();
        all.extend(samples.by_ref());
        attitude = Some(samples.attitude());
    }
    all
}
