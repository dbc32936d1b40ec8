//! Small discrete-time filters for sensor streams: a 2nd-order Butterworth low-pass (single
//! channel and a three-axis bank sharing one design) and a central-difference differentiator.
//!
//! Why these: the seed paper filters gyro and accelerometer with *the same* 2nd-order Butterworth
//! low-pass and differentiates the filtered gyro (50 Hz offline, 10 Hz onboard). Filtering both
//! signals with one design gives them the same delay and the same attenuation, so quantities built
//! from them line up in time. The differentiator here is a central difference, which has *no*
//! phase error relative to the sample it is centred on: it is one sample late relative to the
//! newest input, and the caller lines up with it by using the filtered signals delayed by exactly
//! one sample (a backward difference would be half a sample late, which cannot be matched by a
//! whole-sample delay).
//!
//! Everything is `f32`, `no_std`, allocation-free, and `update` never panics (non-finite inputs
//! simply propagate into the output; callers validate their inputs).
//!
//! Design facts used by callers (all for the Butterworth low-pass at cut-off `f_c`):
//! - DC gain 1; −3 dB at `f_c`; group delay at low frequency `√2 / (2π f_c)` (4.5 ms at 50 Hz).
//! - Impulse-response envelope `exp(−t / τ)` with `τ = 1 / (ζ ω_c) = √2 / (2π f_c)`, ζ = 1/√2:
//!   after `4 τ` (18 ms at 50 Hz) a step has settled to within 2 %; see [`Butterworth2::settling_s`].
//! - Equivalent noise bandwidth `π f_c / (2√2) ≈ 1.11 f_c` (analog prototype).

use nalgebra::Vector3;

/// Coefficients of a normalised biquad `H(z) = (b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ + a2 z⁻²)`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BiquadCoefficients {
    /// Feed-forward coefficients `b0, b1, b2`.
    pub b: [f32; 3],
    /// Feedback coefficients `a1, a2` (`a0 = 1`).
    pub a: [f32; 2],
}

/// Why a filter design was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilterDesignError {
    /// The cut-off must be positive, finite and below a quarter of the sample rate (above that the
    /// bilinear transform warps the response so much that the stated delay figures no longer hold).
    CutoffOutOfRange,
    /// The sample rate must be positive and finite.
    InvalidRate,
}

/// Largest accepted ratio `cutoff_hz / rate_hz` (a quarter of the sample rate, half of Nyquist).
pub const MAX_CUTOFF_FRACTION: f32 = 0.25;

impl BiquadCoefficients {
    /// 2nd-order Butterworth low-pass by the bilinear transform with the cut-off pre-warped, so the
    /// −3 dB point is exactly at `cutoff_hz`.
    pub fn butterworth_lowpass(cutoff_hz: f32, rate_hz: f32) -> Result<Self, FilterDesignError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(FilterDesignError::InvalidRate);
        }
        if !(cutoff_hz.is_finite() && cutoff_hz > 0.0 && cutoff_hz <= MAX_CUTOFF_FRACTION * rate_hz)
        {
            return Err(FilterDesignError::CutoffOutOfRange);
        }
        // Computed in f64 (design time only) so the coefficients are correctly rounded to f32.
        // tan as sin/cos (`crate::math`: libm's trigonometry costs the firmware 6.5 KB of flash).
        let (sin, cos) = crate::math::sin_cos_f64(
            core::f64::consts::PI * f64::from(cutoff_hz) / f64::from(rate_hz),
        );
        let k = sin / cos;
        let sqrt2 = core::f64::consts::SQRT_2;
        let norm = 1.0 / (1.0 + sqrt2 * k + k * k);
        let b0 = k * k * norm;
        Ok(Self {
            b: [b0 as f32, (2.0 * b0) as f32, b0 as f32],
            a: [(2.0 * (k * k - 1.0) * norm) as f32, ((1.0 - sqrt2 * k + k * k) * norm) as f32],
        })
    }
}

/// One channel of a 2nd-order Butterworth low-pass (transposed direct form II).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Butterworth2 {
    c: BiquadCoefficients,
    /// The two state registers of the transposed direct form II.
    z: [f32; 2],
}

impl Butterworth2 {
    /// A low-pass with −3 dB at `cutoff_hz` for samples arriving at `rate_hz`, state at zero.
    pub fn new(cutoff_hz: f32, rate_hz: f32) -> Result<Self, FilterDesignError> {
        Ok(Self::from_coefficients(BiquadCoefficients::butterworth_lowpass(cutoff_hz, rate_hz)?))
    }

    /// A filter with the given (already designed) coefficients, state at zero.
    pub fn from_coefficients(c: BiquadCoefficients) -> Self {
        Self { c, z: [0.0; 2] }
    }

    /// Set the state to the steady state for a constant input `x`, so the output starts at `x`
    /// without a start-up transient.
    pub fn reset_to(&mut self, x: f32) {
        let [b0, _, b2] = self.c.b;
        let [_, a2] = self.c.a;
        self.z = [(1.0 - b0) * x, (b2 - a2) * x];
    }

    /// Filter one sample.
    #[inline]
    pub fn update(&mut self, x: f32) -> f32 {
        let [b0, b1, b2] = self.c.b;
        let [a1, a2] = self.c.a;
        let y = b0 * x + self.z[0];
        self.z[0] = b1 * x - a1 * y + self.z[1];
        self.z[1] = b2 * x - a2 * y;
        y
    }

    /// Low-frequency group delay `√2 / (2π f_c)` of the analog prototype, in seconds.
    pub fn group_delay_s(cutoff_hz: f32) -> f32 {
        core::f32::consts::SQRT_2 / (2.0 * core::f32::consts::PI * cutoff_hz)
    }

    /// Time for the impulse-response envelope to decay to `e⁻⁴` (2 %): `4 √2 / (2π f_c)` seconds.
    pub fn settling_s(cutoff_hz: f32) -> f32 {
        4.0 * Self::group_delay_s(cutoff_hz)
    }
}

/// Three channels (x, y, z) filtered by the same 2nd-order Butterworth design.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Butterworth2x3 {
    channels: [Butterworth2; 3],
}

impl Butterworth2x3 {
    /// Three identical low-passes with −3 dB at `cutoff_hz` at `rate_hz`.
    pub fn new(cutoff_hz: f32, rate_hz: f32) -> Result<Self, FilterDesignError> {
        let one = Butterworth2::new(cutoff_hz, rate_hz)?;
        Ok(Self { channels: [one; 3] })
    }

    /// Three identical filters with the given (already designed) coefficients, state at zero.
    pub fn from_coefficients(c: BiquadCoefficients) -> Self {
        Self { channels: [Butterworth2::from_coefficients(c); 3] }
    }

    /// Start every channel in steady state at `x` (no start-up transient).
    pub fn reset_to(&mut self, x: &Vector3<f32>) {
        for (channel, value) in self.channels.iter_mut().zip(x.iter()) {
            channel.reset_to(*value);
        }
    }

    /// Filter one three-axis sample.
    #[inline]
    pub fn update(&mut self, x: &Vector3<f32>) -> Vector3<f32> {
        let [cx, cy, cz] = &mut self.channels;
        Vector3::new(cx.update(x.x), cy.update(x.y), cz.update(x.z))
    }
}

/// `N` channels filtered by the same 2nd-order Butterworth design, stored as one coefficient set
/// and `N` pairs of state registers: a bank of dozens of signals (the in-flight IMU-offset fit's
/// fifty) in one loop, rather than `N` filters each carrying its own copy of the coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ButterworthBank<const N: usize> {
    c: BiquadCoefficients,
    /// The two state registers of each channel (transposed direct form II).
    z: [[f32; 2]; N],
}

impl<const N: usize> ButterworthBank<N> {
    /// `N` identical filters with the given (already designed) coefficients, state at zero.
    pub fn from_coefficients(c: BiquadCoefficients) -> Self {
        Self { c, z: [[0.0; 2]; N] }
    }

    /// Start every channel in steady state at its value in `x` (no start-up transient).
    pub fn reset_to(&mut self, x: &[f32; N]) {
        for (channel, &x) in self.z.iter_mut().zip(x) {
            let mut one = Butterworth2 { c: self.c, z: [0.0; 2] };
            one.reset_to(x);
            *channel = one.z;
        }
    }

    /// Filter one sample of every channel.
    pub fn update(&mut self, x: &[f32; N]) -> [f32; N] {
        let mut y = [0.0; N];
        for ((channel, &x), y) in self.z.iter_mut().zip(x).zip(&mut y) {
            let mut one = Butterworth2 { c: self.c, z: *channel };
            *y = one.update(x);
            *channel = one.z;
        }
        y
    }
}

/// Central-difference differentiator of a three-axis signal sampled every `dt_s`:
/// `ẋ[n−1] = (x[n] − x[n−2]) / (2 dt)`.
///
/// The derivative is *centred* on the previous sample: to line it up with other signals, pair it
/// with their values delayed by one sample ([`CentralDifference3::update`] also returns the signal
/// itself at that instant). Its gain is `sin(ωT)/T` instead of `ω`: −1.6 % at a tenth of the
/// Nyquist rate, negligible for a signal already low-passed well below Nyquist.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CentralDifference3 {
    half_rate_hz: f32,
    /// `x[n−1]`, `x[n−2]`, and how many samples have been seen (saturating at 2).
    previous: [Vector3<f32>; 2],
    seen: u8,
}

impl CentralDifference3 {
    /// A differentiator for samples arriving at `rate_hz`.
    pub fn new(rate_hz: f32) -> Self {
        Self { half_rate_hz: 0.5 * rate_hz, previous: [Vector3::zeros(); 2], seen: 0 }
    }

    /// Forget the history (the next two samples produce no output).
    pub fn reset(&mut self) {
        self.seen = 0;
    }

    /// Push `x[n]`; once two earlier samples exist, return `(x[n−1], ẋ[n−1])`.
    #[inline]
    pub fn update(&mut self, x: &Vector3<f32>) -> Option<(Vector3<f32>, Vector3<f32>)> {
        let [x1, x2] = self.previous;
        self.previous = [*x, x1];
        if self.seen < 2 {
            self.seen += 1;
            return None;
        }
        Some((x1, (x - x2) * self.half_rate_hz))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn butterworth_has_unit_dc_gain_and_minus_3db_at_cutoff() {
        let rate_hz = 2000.0;
        let cutoff_hz = 50.0;
        let mut dc = Butterworth2::new(cutoff_hz, rate_hz).unwrap();
        let mut y = 0.0;
        for _ in 0..4000 {
            y = dc.update(1.0);
        }
        assert!((y - 1.0).abs() < 1e-5);

        let mut f = Butterworth2::new(cutoff_hz, rate_hz).unwrap();
        let mut peak = 0.0f32;
        for n in 0..8000 {
            let t = n as f32 / rate_hz;
            let y = f.update(libm::sinf(2.0 * core::f32::consts::PI * cutoff_hz * t));
            if n > 4000 {
                peak = peak.max(y.abs());
            }
        }
        let gain_db = 20.0 * libm::log10f(peak);
        assert!((gain_db + 3.01).abs() < 0.05, "gain at cut-off {gain_db} dB");
    }

    #[test]
    fn reset_to_starts_in_steady_state() {
        let mut f = Butterworth2::new(30.0, 1000.0).unwrap();
        f.reset_to(9.81);
        for _ in 0..10 {
            assert!((f.update(9.81) - 9.81).abs() < 1e-5);
        }
    }

    /// Each channel of a bank is the single filter on its own input, from a reset and from zero.
    #[test]
    fn a_bank_filters_each_channel_as_one_filter_would() {
        let c = BiquadCoefficients::butterworth_lowpass(20.0, 2000.0).unwrap();
        let mut bank = ButterworthBank::<3>::from_coefficients(c);
        let mut single = [Butterworth2::from_coefficients(c); 3];
        let start = [1.0, -2.0, 9.81];
        bank.reset_to(&start);
        for (f, x) in single.iter_mut().zip(start) {
            f.reset_to(x);
        }
        for n in 0..200 {
            let x = [n as f32, libm::sinf(n as f32 * 0.1), if n < 50 { 0.0 } else { 3.0 }];
            let y = bank.update(&x);
            for k in 0..3 {
                assert_eq!(y[k], single[k].update(x[k]), "channel {k}, sample {n}");
            }
        }
    }

    #[test]
    fn refuses_cutoff_above_quarter_rate() {
        assert_eq!(Butterworth2::new(300.0, 1000.0), Err(FilterDesignError::CutoffOutOfRange));
        assert_eq!(Butterworth2::new(f32::NAN, 1000.0), Err(FilterDesignError::CutoffOutOfRange));
        assert_eq!(Butterworth2::new(50.0, 0.0), Err(FilterDesignError::InvalidRate));
    }

    #[test]
    fn central_difference_is_exact_on_a_parabola_and_centred() {
        let rate_hz = 1000.0;
        let mut d = CentralDifference3::new(rate_hz);
        let x = |n: u32| {
            let t = n as f32 / rate_hz;
            Vector3::new(t * t, 3.0 * t, -t * t)
        };
        assert!(d.update(&x(0)).is_none());
        assert!(d.update(&x(1)).is_none());
        for n in 2..50 {
            let (centre, rate) = d.update(&x(n)).unwrap();
            let t = (n - 1) as f32 / rate_hz;
            assert!((centre - x(n - 1)).norm() < 1e-6);
            assert!((rate - Vector3::new(2.0 * t, 3.0, -2.0 * t)).norm() < 1e-3);
        }
    }
}
