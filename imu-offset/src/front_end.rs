//! The signal path from raw IMU samples to time-aligned rows of eq. 3 (seed paper §3.2).
//!
//! Gyro and accelerometer pass through the *same* 2nd-order Butterworth low-pass, so both carry
//! the same delay and attenuation. The filtered gyro is differentiated by a central difference,
//! which is centred one sample in the past; the rate and specific force are therefore taken one
//! sample in the past too. The result, [`AlignedSample`], holds `Ω`, `Ω̇` and `f` for the same
//! instant, from which [`regressor`] builds `X(Ω, Ω̇)` with `f = X r` in free fall.

use nalgebra::{Matrix3, Vector3};

use flight::filters::{Butterworth2x3, CentralDifference3, FilterDesignError};

use super::ImuSample;

/// Filtered rate, its derivative and the filtered specific force, all for the same instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlignedSample {
    /// Index of the raw sample this instant corresponds to (one before the newest input).
    pub index: u32,
    /// Filtered body rate (rad/s, IMU frame).
    pub gyro_radps: Vector3<f32>,
    /// Derivative of the filtered body rate (rad/s², IMU frame).
    pub gyro_dot_radps2: Vector3<f32>,
    /// Filtered specific force (m/s², IMU frame).
    pub acc_mps2: Vector3<f32>,
}

/// Filters and differentiator; see the module documentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontEnd {
    gyro_lp: Butterworth2x3,
    acc_lp: Butterworth2x3,
    gyro_diff: CentralDifference3,
    /// Filtered specific force of the previous sample (to pair with the centred derivative).
    acc_previous: Vector3<f32>,
    /// Whether the filters hold a state (false at start and after [`FrontEnd::restart`]).
    primed: bool,
    /// Index the next raw sample will get.
    next_index: u32,
}

impl FrontEnd {
    /// A front end with low-pass cut-off `cutoff_hz` for samples at `rate_hz`.
    pub fn new(cutoff_hz: f32, rate_hz: f32) -> Result<Self, FilterDesignError> {
        Ok(Self {
            gyro_lp: Butterworth2x3::new(cutoff_hz, rate_hz)?,
            acc_lp: Butterworth2x3::new(cutoff_hz, rate_hz)?,
            gyro_diff: CentralDifference3::new(rate_hz),
            acc_previous: Vector3::zeros(),
            primed: false,
            next_index: 0,
        })
    }

    /// Forget the filter history (after a gap or a bad sample); indices keep counting.
    pub fn restart(&mut self) {
        self.primed = false;
        self.gyro_diff.reset();
    }

    /// Count a raw sample that is not fed through the filters (rejected input), so later indices
    /// still match the raw stream.
    pub fn skip(&mut self) {
        self.skip_many(1);
    }

    /// Count `count` raw samples that never arrived.
    pub fn skip_many(&mut self, count: u32) {
        self.next_index = self.next_index.saturating_add(count);
    }

    /// Index the next raw sample will get (samples fed or skipped so far).
    pub fn next_index(&self) -> u32 {
        self.next_index
    }

    /// Feed one raw sample; from the third sample after a (re)start, returns the aligned values
    /// for the previous sample's instant.
    #[inline]
    pub fn update(&mut self, sample: &ImuSample) -> Option<AlignedSample> {
        let index = self.next_index;
        self.next_index = self.next_index.saturating_add(1);
        if !self.primed {
            // Start in steady state: no filter transient from a zero initial state.
            self.gyro_lp.reset_to(&sample.gyro_radps);
            self.acc_lp.reset_to(&sample.acc_mps2);
            self.primed = true;
        }
        let gyro = self.gyro_lp.update(&sample.gyro_radps);
        let acc = self.acc_lp.update(&sample.acc_mps2);
        let acc_centre = core::mem::replace(&mut self.acc_previous, acc);
        let (gyro_centre, gyro_dot) = self.gyro_diff.update(&gyro)?;
        Some(AlignedSample {
            index: index.saturating_sub(1),
            gyro_radps: gyro_centre,
            gyro_dot_radps2: gyro_dot,
            acc_mps2: acc_centre,
        })
    }
}

/// `X(Ω, Ω̇)` of eq. 3: the specific force at offset `r` from the centre of gravity of a body in
/// free fall is `Ω̇ × r + Ω × (Ω × r) = X r`.
#[inline]
pub fn regressor<T: nalgebra::RealField + Copy>(w: &Vector3<T>, w_dot: &Vector3<T>) -> Matrix3<T> {
    let (xx, yy, zz) = (w.x * w.x, w.y * w.y, w.z * w.z);
    let (xy, xz, yz) = (w.x * w.y, w.x * w.z, w.y * w.z);
    Matrix3::new(
        -(yy + zz),
        xy - w_dot.z,
        xz + w_dot.y,
        xy + w_dot.z,
        -(xx + zz),
        yz - w_dot.x,
        xz - w_dot.y,
        yz + w_dot.x,
        -(xx + yy),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_derivative_and_specific_force_line_up_in_time() {
        // A 5 Hz sinusoid on gyro x and, identically, on acc x. If the derivative were offset in
        // time (e.g. a backward difference, half a sample late), x² + (ẋ/ω)² would oscillate at
        // 2ω by about ωT relative (1.6 % at 1 kHz); lined up, it is constant.
        let (rate_hz, f_hz) = (1000.0f32, 5.0f32);
        let w = 2.0 * core::f32::consts::PI * f_hz;
        let mut fe = FrontEnd::new(50.0, rate_hz).unwrap();
        let (mut lo, mut hi) = (f32::MAX, f32::MIN);
        for n in 0..3000u32 {
            let v = libm::sinf(w * n as f32 / rate_hz);
            let sample = ImuSample {
                gyro_radps: Vector3::new(v, 0.0, 0.0),
                acc_mps2: Vector3::new(v, 0.0, 0.0),
            };
            let Some(a) = fe.update(&sample) else { continue };
            assert_eq!(a.gyro_radps.x, a.acc_mps2.x, "same filter, same instant");
            if n > 1000 {
                let energy = a.gyro_radps.x.powi(2) + (a.gyro_dot_radps2.x / w).powi(2);
                lo = lo.min(energy);
                hi = hi.max(energy);
            }
        }
        assert!((hi - lo) / hi < 2e-3, "derivative misaligned: {lo}..{hi}");
    }

    #[test]
    fn regressor_matches_the_cross_products() {
        let w = Vector3::new(3.0, -7.0, 11.0);
        let w_dot = Vector3::new(-20.0, 5.0, 13.0);
        let r = Vector3::new(0.012, -0.034, 0.056);
        let direct = w_dot.cross(&r) + w.cross(&w.cross(&r));
        assert!((regressor(&w, &w_dot) * r - direct).norm() < 1e-12);
    }
}
