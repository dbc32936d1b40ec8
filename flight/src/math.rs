//! Small numeric helpers with the same arithmetic on the host and on the Cortex-M7: a square
//! root from FPU multiplies and a clamp without a panic path.
//!
//! ## Square root
//!
//! Why not `libm::sqrtf`: libm has no ARM fast path, so on `thumbv7em` it is an integer
//! routine (53 instructions a call in `cargo xtask bench-m7`), and the thrust-axis solver takes
//! about eight roots per call (measured: it was most of the m = 4 instruction count, see
//! `docs/benchmarks.md`); the learner's motor models take one per motor and sample. The
//! `vsqrt.f32` instruction is reachable from stable Rust only through inline assembly that needs
//! the double-precision `vfp2` feature (not in the baseline `thumbv7em-none-eabihf`), so instead:
//! the classic bit-level estimate of `1/√x`, three Newton steps (relative error 2e-3 → 5e-6 →
//! 4e-11, i.e. f32 round-off), then `√x = x · (1/√x)`. About 20 instructions, all FPU.

/// `√x` to within a few f32 ulps; `0` for `x ≤ 0` and for NaN returns NaN. Inputs outside the
/// normal range (subnormal, infinite) fall back to `libm::sqrtf`.
#[inline]
pub(crate) fn sqrt(x: f32) -> f32 {
    if !(f32::MIN_POSITIVE..=f32::MAX).contains(&x) {
        return if x > 0.0 || x.is_nan() { libm::sqrtf(x) } else { 0.0 };
    }
    // Initial estimate of 1/√x from the exponent bits (relative error below 3.5 %).
    let mut r = f32::from_bits(0x5f37_59df - (x.to_bits() >> 1));
    let half_x = 0.5 * x;
    for _ in 0..3 {
        r *= 1.5 - half_x * r * r;
    }
    x * r
}

/// `x` limited to `lo..=hi`; NaN stays NaN (as `f32::clamp`).
///
/// Why not `f32::clamp`: it asserts `lo <= hi` with a message that formats both floats, so
/// every call whose bounds are not constants links core's float formatting into the firmware
/// (about 23 KB of flash at opt-level 3, `docs/benchmarks.md`, "Firmware size"). Here bounds in
/// the wrong order give `lo` below `lo` and `hi` above `hi`, never a panic; callers pass ordered
/// bounds.
#[inline]
pub fn clamp(x: f32, lo: f32, hi: f32) -> f32 {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::{clamp, sqrt};

    #[test]
    fn clamp_limits_to_the_bounds_keeps_nan_and_never_panics() {
        assert_eq!(clamp(-2.0, -1.0, 1.0), -1.0);
        assert_eq!(clamp(2.0, -1.0, 1.0), 1.0);
        assert_eq!(clamp(0.25, -1.0, 1.0), 0.25);
        assert!(clamp(f32::NAN, -1.0, 1.0).is_nan());
        assert_eq!(clamp(f32::INFINITY, 0.0, 1.0), 1.0);
        // Reversed bounds: no panic (f32::clamp would), the result is one of them.
        assert_eq!(clamp(0.5, 1.0, 0.0), 1.0);
        assert_eq!(clamp(-0.5, 1.0, 0.0), 1.0);
    }

    #[test]
    fn matches_libm_to_a_few_ulps_over_the_normal_range() {
        let mut x = f32::MIN_POSITIVE;
        while x < 1e38 {
            for scale in [1.0f32, 1.37, 2.0, 3.99] {
                let value = x * scale;
                let exact = libm::sqrtf(value);
                let error = (sqrt(value) - exact).abs() / exact;
                assert!(error < 4.0 * f32::EPSILON, "√{value}: {} vs {exact}", sqrt(value));
            }
            x *= 7.3;
        }
        assert_eq!(sqrt(0.0), 0.0);
        assert_eq!(sqrt(-1.0), 0.0);
        assert!(sqrt(f32::NAN).is_nan());
        assert_eq!(sqrt(f32::INFINITY), f32::INFINITY);
        assert!((sqrt(1e-40) - libm::sqrtf(1e-40)).abs() < 1e-25);
    }
}
