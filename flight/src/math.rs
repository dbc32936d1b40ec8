//! Small numeric helpers with the same arithmetic on the host and on the Cortex-M7: a square
//! root from FPU multiplies, a clamp without a panic path, and sine and cosine for the angles a
//! flight controller turns through.
//!
//! ## Sine and cosine
//!
//! Why not `libm::sincosf`: its argument reduction for huge angles (`rem_pio2_large`, Payne–
//! Hanek over 1,200 bits of 2/π) and its three entry points cost the firmware 6.5 KB of flash for
//! angles that are never beyond a few turns here (attitude steps, headings, tilt limits).
//! [`sin_cos`] reduces by multiples of π/2 in f64 (the M7's double-precision FPU), which is
//! exact to f32 round-off for |x| up to 10⁵ rad, and sums the Taylor series to degree 13/12 on
//! [−π/4, π/4] (truncation below 10⁻¹¹). Larger angles lose accuracy gradually (no panic);
//! NaN and infinities give NaN.
//!
//! ## Compact products
//!
//! [`mul_compact`]: a matrix product over runtime sizes in one shared, not unrolled body, for
//! the once-per-throw solves (IMU offset, drag model). nalgebra's fixed-size products are fully
//! unrolled at the firmware's opt-level (a 9 × 6 · 9 × 9 · 9 × 6 f64 product alone is kilobytes
//! of flash); those paths have no speed target, the flash budget is tight. Same sums in the same
//! order as nalgebra's product (`Σ_k a_ik b_kj`, k ascending), so the results are the same bit
//! for bit (tested).
//!
//! ## Square root
//!
//! Why not `libm::sqrtf` (nor nalgebra's `norm()`, `normalize()` and
//! `UnitQuaternion::new_normalize`, which call it through simba): libm 0.2.16 has no ARM fast
//! path, so on `thumbv7em` every call is an integer routine of about 50 instructions (51 in
//! `cargo xtask bench-m7`), and the control step made 36 of them on a quad and 52 on an
//! octorotor (1,836 and 2,652 instructions). The Cortex-M7's FPU has `vsqrt.f32`, correctly
//! rounded as IEEE 754 requires, and so is `libm::sqrtf`: [`sqrt`] is the one instruction on
//! an ARM hard-float target and `libm::sqrtf` elsewhere, the same value bit for bit on both
//! (tested on the host against libm, and on the Cortex-M7 by `cargo xtask bench-m7`, which
//! fails when the instruction's result differs from libm's on its sweep). [`hypot`], [`norm`],
//! [`normalize`], [`try_normalize`] and [`normalized_quaternion`] are libm's `hypotf` and
//! nalgebra's methods with the same arithmetic around it, so their results are the same too.
//!
//! The register class `sreg` of Rust's inline assembly needs the target feature `vfp2`
//! (double-precision VFP), which the Cortex-M7 has (`-C target-cpu=cortex-m7`, as the firmware
//! and bench-m7 build) and the bare `thumbv7em-none-eabihf` baseline (single precision) has not:
//! there the assembly does not compile rather than silently taking the slow path. ARM's target
//! features are not visible to `cfg` on stable Rust (`rustc --print cfg --target
//! thumbv7em-none-eabihf -C target-cpu=cortex-m7` lists none), so the path is chosen by
//! `target_arch = "arm"` and `target_abi = "eabihf"` (every hard-float ARM core has `vsqrt`).

use nalgebra::{Quaternion, SMatrix, Unit, UnitQuaternion, Vector3};

/// `a · b` computed by [`mul_slices`] (see "Compact products" in the module docs).
pub fn mul_compact<const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<f64, R, K>,
    b: &SMatrix<f64, K, C>,
) -> SMatrix<f64, R, C> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    mul_slices(a.as_slice(), (1, R), b.as_slice(), out.as_mut_slice(), R, K);
    out
}

/// `aᵀ · b` computed by [`mul_slices`] without a transposed copy: the same as nalgebra's
/// `a.transpose() * b`, and as its `tr_mul` when `a` has at most three rows (longer dot products
/// it sums in another order).
pub fn tr_mul_compact<const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<f64, K, R>,
    b: &SMatrix<f64, K, C>,
) -> SMatrix<f64, R, C> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    mul_slices(a.as_slice(), (K, 1), b.as_slice(), out.as_mut_slice(), R, K);
    out
}

/// `out = a · b`, column-major `b` and `out`; `a`'s element `(i, k)` at
/// `a[i · strides.0 + k · strides.1]` (`a` or a transposed view of it), `rows` × `inner`.
#[inline(never)]
fn mul_slices(
    a: &[f64],
    strides: (usize, usize),
    b: &[f64],
    out: &mut [f64],
    rows: usize,
    inner: usize,
) {
    let (row_stride, inner_stride) = strides;
    for (j, column) in out.chunks_exact_mut(rows).enumerate() {
        let b_j = &b[j * inner..(j + 1) * inner];
        for (i, value) in column.iter_mut().enumerate() {
            let a_i = |k: usize| a[i * row_stride + k * inner_stride];
            let mut sum = a_i(0) * b_j[0];
            for (k, b_kj) in b_j.iter().enumerate().skip(1) {
                sum += a_i(k) * b_kj;
            }
            *value = sum;
        }
    }
}

/// `√x`, correctly rounded: the value of `libm::sqrtf` for every input (NaN for a negative or
/// NaN input, `−0` for `−0`, `+∞` for `+∞`). One `vsqrt.f32` on an ARM hard-float target,
/// `libm::sqrtf` elsewhere (see "Square root" in the module docs).
#[inline(always)]
pub fn sqrt(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        let root: f32;
        // SAFETY: one FPU instruction on registers: no memory, no stack, no flags (`vsqrt`
        // sets only the FPSCR's cumulative exception bits, which nothing here reads).
        unsafe {
            core::arch::asm!(
                "vsqrt.f32 {root}, {x}",
                root = lateout(sreg) root,
                x = in(sreg) x,
                options(pure, nomem, nostack, preserves_flags)
            );
        }
        root
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

/// `√(x² + y²)` without undue overflow or underflow: `libm::hypotf` (0.2.16) with [`sqrt`] for
/// its square root, so the same value for every input.
#[inline]
pub fn hypot(x: f32, y: f32) -> f32 {
    // 2⁹⁰ and 2⁻⁹⁰: the rescaling of arguments whose squares would leave the f32 range.
    const TWO_POW_90: f32 = f32::from_bits(0x6c80_0000);
    const TWO_POW_MINUS_90: f32 = f32::from_bits(0x1280_0000);
    let (mut big, mut small) = (x.to_bits() & !(1 << 31), y.to_bits() & !(1 << 31));
    if big < small {
        core::mem::swap(&mut big, &mut small);
    }
    let (mut x, mut y) = (f32::from_bits(big), f32::from_bits(small));
    if small == 0xff << 23 {
        return y;
    }
    if big >= 0xff << 23 || small == 0 || big - small >= 25 << 23 {
        return x + y;
    }
    let mut z = 1.0;
    if big >= (0x7f + 60) << 23 {
        z = TWO_POW_90;
        x *= TWO_POW_MINUS_90;
        y *= TWO_POW_MINUS_90;
    } else if small < (0x7f - 60) << 23 {
        z = TWO_POW_MINUS_90;
        x *= TWO_POW_90;
        y *= TWO_POW_90;
    }
    z * sqrt((f64::from(x) * f64::from(x) + f64::from(y) * f64::from(y)) as f32)
}

/// `‖v‖`: nalgebra's `norm()` with [`sqrt`] (the same value).
#[inline]
pub fn norm(v: &Vector3<f32>) -> f32 {
    sqrt(v.norm_squared())
}

/// `v / ‖v‖`: nalgebra's `normalize()` with [`sqrt`] (the same value; NaN for a zero vector).
#[inline]
pub fn normalize(v: &Vector3<f32>) -> Vector3<f32> {
    v.unscale(norm(v))
}

/// `v / ‖v‖` unless `‖v‖ ≤ min_norm`: nalgebra's `try_normalize` with [`sqrt`].
#[inline]
pub fn try_normalize(v: &Vector3<f32>, min_norm: f32) -> Option<Vector3<f32>> {
    let n = norm(v);
    if n <= min_norm {
        None
    } else {
        Some(v.unscale(n))
    }
}

/// `q / ‖q‖` as a rotation: `UnitQuaternion::new_normalize` with [`sqrt`] (the same value).
#[inline]
pub fn normalized_quaternion(q: Quaternion<f32>) -> UnitQuaternion<f32> {
    let n = sqrt(q.coords.norm_squared());
    UnitQuaternion::new_unchecked(Quaternion::from(q.coords.unscale(n)))
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

/// `(sin x, cos x)` for `x` in rad (see the module documentation for the range).
pub fn sin_cos(x: f32) -> (f32, f32) {
    let (sin, cos) = sin_cos_f64(f64::from(x));
    (sin as f32, cos as f32)
}

/// `(sin x, cos x)` in f64: to about 10⁻¹¹ (the series' truncation) for |x| up to 10⁵ rad;
/// NaN for NaN and infinities.
pub fn sin_cos_f64(x: f64) -> (f64, f64) {
    if !x.is_finite() {
        return (f64::NAN, f64::NAN);
    }
    // The nearest whole number of quarter turns (`f64::round` is not in `core`).
    let y = x * core::f64::consts::FRAC_2_PI;
    // In i32 whenever it fits: the FPU converts those itself, an i64 takes two library calls
    // (`__aeabi_d2lz`, `__aeabi_l2d`: about 55 instructions a call on the Cortex-M7, three
    // calls in a control step). The same whole number either way.
    let (turns, quadrant) = if y.abs() < 1e9 {
        let q = if y >= 0.0 { (y + 0.5) as i32 } else { (y - 0.5) as i32 };
        (f64::from(q), q & 3)
    } else {
        let q = if y >= 0.0 { (y + 0.5) as i64 } else { (y - 0.5) as i64 };
        (q as f64, q.rem_euclid(4) as i32)
    };
    let r = x - turns * core::f64::consts::FRAC_PI_2;
    let r2 = r * r;
    // Horner forms of the Taylor series: sin to r¹³, cos to r¹².
    let sin = r
        * (1.0
            + r2 * (-1.0 / 6.0
                + r2 * (1.0 / 120.0
                    + r2 * (-1.0 / 5040.0
                        + r2 * (1.0 / 362_880.0
                            + r2 * (-1.0 / 39_916_800.0 + r2 * (1.0 / 6_227_020_800.0)))))));
    let cos = 1.0
        + r2 * (-0.5
            + r2 * (1.0 / 24.0
                + r2 * (-1.0 / 720.0
                    + r2 * (1.0 / 40_320.0
                        + r2 * (-1.0 / 3_628_800.0 + r2 * (1.0 / 479_001_600.0))))));
    match quadrant {
        0 => (sin, cos),
        1 => (cos, -sin),
        2 => (-sin, -cos),
        _ => (-cos, sin),
    }
}

/// The rotation by `angle_rad` about `axis` (right-handed), as [`UnitQuaternion`]'s
/// `from_axis_angle` but through [`sin_cos`].
pub fn rotation_about(axis: &Unit<Vector3<f32>>, angle_rad: f32) -> UnitQuaternion<f32> {
    let (sin, cos) = sin_cos(0.5 * angle_rad);
    let v = axis.into_inner() * sin;
    UnitQuaternion::new_unchecked(Quaternion::new(cos, v.x, v.y, v.z))
}

/// The rotation of rotation vector `phi` (axis times angle, rad), as [`UnitQuaternion`]'s
/// `from_scaled_axis` but through [`sin_cos`]; the identity for a zero vector.
pub fn rotation_from_scaled_axis(phi: &Vector3<f32>) -> UnitQuaternion<f32> {
    let angle = norm(phi);
    if angle == 0.0 || !angle.is_finite() {
        return UnitQuaternion::identity();
    }
    rotation_about(&Unit::new_unchecked(phi / angle), angle)
}

/// The inverse of a symmetric positive-definite matrix through its Cholesky factor `L Lᵀ`
/// (its lower triangle is read); `None` when a pivot is not positive and finite. Plain loops:
/// nalgebra's generic inverse, instantiated for one size only, cost the firmware 12 KB of flash.
/// The tumble's inertia fit, the IMU-offset calibration and the in-flight IMU-offset fit solve
/// with it. Every size shares one body, [`spd_inverse_flat`].
pub fn spd_inverse<const N: usize>(a: &[[f64; N]; N]) -> Option<[[f64; N]; N]> {
    let mut l = [[0.0; N]; N];
    let mut inverse = [[0.0; N]; N];
    spd_inverse_into(a, &mut l, &mut inverse).then_some(inverse)
}

/// [`spd_inverse`] into `inverse`, with `factor` for the Cholesky factor (neither needs to be
/// cleared): for matrices too large for the stack, kept where their owner is (the in-flight
/// IMU-offset fit's 33 × 33, three of which were 26 KB of the background task's stack).
/// `false` when a pivot is not positive and finite or the inverse is not finite.
pub fn spd_inverse_into<const N: usize>(
    a: &[[f64; N]; N],
    factor: &mut [[f64; N]; N],
    inverse: &mut [[f64; N]; N],
) -> bool {
    spd_inverse_flat(a.as_flattened(), factor.as_flattened_mut(), inverse.as_flattened_mut(), N)
}

/// [`spd_inverse`] of the `n × n` row-major `a` into `inverse`, with `l` (`n × n`) for the
/// factor; `false` when a pivot is not positive and finite or the inverse is not finite.
///
/// Over a runtime size so that a crate holds one copy for every size it inverts (each
/// instance of a generic body is about 640 B of flash at the background crates' opt-level
/// "z"), and `#[inline]` so that the copy is compiled in the calling crate, at its opt-level
/// (`flight` is at 2 on the board, where loops are unrolled). Same sums in the same order for
/// every size.
#[inline]
fn spd_inverse_flat(a: &[f64], l: &mut [f64], inverse: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        let pivot = a[j * n + j] - (0..j).map(|k| l[j * n + k] * l[j * n + k]).sum::<f64>();
        if !(pivot > 0.0 && pivot.is_finite()) {
            return false;
        }
        l[j * n + j] = libm::sqrt(pivot);
        for i in j + 1..n {
            let dot: f64 = (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum();
            l[i * n + j] = (a[i * n + j] - dot) / l[j * n + j];
        }
    }
    // Column by column: L y = e_c, then Lᵀ x = y, both in the column of the inverse. `y` is zero
    // above row c (L is lower triangular), so the forward solve starts there.
    for c in 0..n {
        for i in 0..c {
            inverse[i * n + c] = 0.0;
        }
        for i in c..n {
            let known: f64 = (c..i).map(|k| l[i * n + k] * inverse[k * n + c]).sum();
            inverse[i * n + c] = (if i == c { 1.0 } else { 0.0 } - known) / l[i * n + i];
        }
        for i in (0..n).rev() {
            let known: f64 = (i + 1..n).map(|k| l[k * n + i] * inverse[k * n + c]).sum();
            inverse[i * n + c] = (inverse[i * n + c] - known) / l[i * n + i];
        }
    }
    inverse.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::{
        clamp, hypot, mul_compact, norm, normalize, normalized_quaternion, rotation_about,
        rotation_from_scaled_axis, sin_cos, sqrt, tr_mul_compact, try_normalize,
    };
    use nalgebra::Quaternion;

    #[test]
    #[allow(clippy::needless_range_loop)] // the product's indices, as in the notation
    fn spd_inverse_times_the_matrix_is_the_identity_and_an_indefinite_one_is_refused() {
        // A = B Bᵀ + I for a fixed B with entries of both signs: 7 × 7, well conditioned.
        const N: usize = 7;
        let b: [[f64; N]; N] = core::array::from_fn(|i| {
            core::array::from_fn(|j| (((i * 7 + j * 3) % 11) as f64 - 5.0) / 3.0)
        });
        let a: [[f64; N]; N] = core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                (0..N).map(|k| b[i][k] * b[j][k]).sum::<f64>() + if i == j { 1.0 } else { 0.0 }
            })
        });
        let inverse = super::spd_inverse(&a).expect("positive definite");
        for i in 0..N {
            for j in 0..N {
                let product: f64 = (0..N).map(|k| a[i][k] * inverse[k][j]).sum();
                let identity = if i == j { 1.0 } else { 0.0 };
                assert!((product - identity).abs() < 1e-9, "({i}, {j}): {product}");
                assert!((inverse[i][j] - inverse[j][i]).abs() < 1e-12, "symmetric");
            }
        }
        let mut indefinite = a;
        indefinite[3][3] = -1.0;
        assert_eq!(super::spd_inverse(&indefinite), None);
        assert_eq!(super::spd_inverse(&[[f64::NAN]]), None);
        assert_eq!(super::spd_inverse(&[[4.0]]), Some([[0.25]]));
    }
    use nalgebra::{SMatrix, UnitQuaternion, Vector3};

    #[test]
    fn compact_products_equal_nalgebras_bit_for_bit() {
        let mut rng = crate::rng::Rng::new(11);
        for _ in 0..200 {
            let a = SMatrix::<f64, 9, 6>::from_fn(|_, _| rng.normal() * 1e3);
            let b = SMatrix::<f64, 9, 9>::from_fn(|_, _| rng.normal());
            let c = SMatrix::<f64, 6, 4>::from_fn(|_, _| rng.normal() * 1e-3);
            let same =
                |x: &[f64], y: &[f64]| x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits());
            assert!(same(mul_compact(&b, &a).as_slice(), (b * a).as_slice()));
            assert!(same(mul_compact(&a, &c).as_slice(), (a * c).as_slice()));
            assert!(same(tr_mul_compact(&a, &b).as_slice(), (a.transpose() * b).as_slice()));
            // nalgebra's `tr_mul` sums dot products of up to three terms in this order too.
            let g = SMatrix::<f64, 3, 9>::from_fn(|_, _| rng.normal());
            assert!(same(tr_mul_compact(&g, &g).as_slice(), g.tr_mul(&g).as_slice()));
        }
    }

    #[test]
    fn sin_cos_matches_libm_to_f32_round_off_over_many_turns_and_gives_nan_for_non_finite() {
        let mut worst = 0.0f64;
        for i in -200_000..=200_000 {
            let x = i as f32 * 1e-3 * core::f32::consts::PI; // ±628 rad
            let (s, c) = sin_cos(x);
            let (xs, xc) = (f64::from(x).sin(), f64::from(x).cos());
            worst = worst.max((f64::from(s) - xs).abs()).max((f64::from(c) - xc).abs());
        }
        assert!(worst < 1.2e-7, "worst error {worst:e}");
        for x in [1e4f32, -3.3e4, 99_999.0] {
            let (s, c) = sin_cos(x);
            assert!((f64::from(s) - f64::from(x).sin()).abs() < 2e-7, "{x}");
            assert!((f64::from(c) - f64::from(x).cos()).abs() < 2e-7, "{x}");
        }
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let (s, c) = sin_cos(x);
            assert!(s.is_nan() && c.is_nan(), "{x}");
        }
        assert_eq!(sin_cos(0.0), (0.0, 1.0));
        // The f64 form, on a filter's prewarping angles (π f/fs below π/2).
        for i in 1..1000 {
            let x = i as f64 * 1.5e-3;
            let (s, c) = super::sin_cos_f64(x);
            assert!((s / c - x.tan()).abs() <= 1e-9 * x.tan().max(1.0), "{x}");
        }
    }

    /// The quarter turns counted in i32 where they fit give the i64 count's results bit for
    /// bit, on both sides of the switch (|x| ≈ 1.57·10⁹ rad) and far beyond it.
    #[test]
    fn sin_cos_counts_quarter_turns_in_i32_with_the_i64_results() {
        let reference = |x: f64| {
            let y = x * core::f64::consts::FRAC_2_PI;
            let q = if y >= 0.0 { (y + 0.5) as i64 } else { (y - 0.5) as i64 };
            let r = x - q as f64 * core::f64::consts::FRAC_PI_2;
            let (s, c) = super::sin_cos_f64(r);
            match q.rem_euclid(4) {
                0 => (s, c),
                1 => (c, -s),
                2 => (-s, -c),
                _ => (-c, s),
            }
        };
        let mut x = 1e-3f64;
        while x < 1e13 {
            for value in [x, -x, x * 1.37, -x * 2.9, 1.5707963e9 + x.min(1e3), -1.5707964e9] {
                let (s, c) = super::sin_cos_f64(value);
                let (rs, rc) = reference(value);
                assert_eq!((s.to_bits(), c.to_bits()), (rs.to_bits(), rc.to_bits()), "{value}");
            }
            x *= 1.9;
        }
    }

    #[test]
    fn rotations_agree_with_nalgebras() {
        let axis = Vector3::new(0.3f32, -0.5, 0.8);
        for angle in [-7.0f32, -1.0, 0.0, 0.5, 3.0, 12.0] {
            let ours = rotation_about(&nalgebra::Unit::new_normalize(axis), angle);
            let theirs =
                UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle);
            assert!(ours.angle_to(&theirs) < 1e-5, "{angle}");
            let phi = axis.normalize() * angle;
            let scaled = rotation_from_scaled_axis(&phi);
            assert!(scaled.angle_to(&UnitQuaternion::from_scaled_axis(phi)) < 1e-5, "{angle}");
        }
        assert_eq!(rotation_from_scaled_axis(&Vector3::zeros()), UnitQuaternion::identity());
    }

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
    fn sqrt_is_libm_bit_for_bit_with_its_nan_for_negative_and_nan() {
        let same = |x: f32| {
            let (ours, libm) = (sqrt(x), libm::sqrtf(x));
            assert!(
                ours.to_bits() == libm.to_bits() || (ours.is_nan() && libm.is_nan()),
                "√{x:e} ({:#010x}): {ours:e} vs libm {libm:e}",
                x.to_bits()
            );
        };
        // Zeros, the smallest and largest subnormals, and the ends of the normal range.
        for x in [0.0, -0.0, f32::from_bits(1), f32::from_bits(0x007f_ffff), f32::MIN_POSITIVE] {
            same(x);
        }
        for x in [1e-30, 1e-20, 1.0, 2.0, 1e30, f32::MAX, f32::INFINITY] {
            same(x);
        }
        // Every 997th bit pattern of the positive floats (subnormals, normals, infinity) and
        // the same magnitudes negative: about 2.1 million values each way.
        for bits in (0..=0x7f80_0000u32).step_by(997) {
            same(f32::from_bits(bits));
            same(-f32::from_bits(bits));
        }
        // Negative inputs and NaN give NaN, as libm's.
        for x in [-1.0, -1e-30, -f32::from_bits(1), f32::NEG_INFINITY, f32::NAN, -f32::NAN] {
            assert!(sqrt(x).is_nan(), "√{x}");
        }
        assert_eq!(sqrt(-0.0).to_bits(), (-0.0f32).to_bits());
    }

    #[test]
    fn hypot_norm_and_normalize_are_libm_and_nalgebra_bit_for_bit() {
        let values = [
            0.0,
            -0.0,
            1e-45,
            1e-40,
            1e-30,
            3.7e-19,
            0.3,
            1.0,
            -2.5,
            7.0,
            1e19,
            3e30,
            1e38,
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        let same = |a: f32, b: f32| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        for &x in &values {
            for &y in &values {
                assert!(same(hypot(x, y), libm::hypotf(x, y)), "hypot({x}, {y})");
                for &z in &values[..12] {
                    let v = Vector3::new(x, y, z);
                    assert!(same(norm(&v), v.norm()), "{v:?}");
                    let (ours, theirs) = (normalize(&v), v.normalize());
                    assert!(ours.iter().zip(&theirs).all(|(a, b)| same(*a, *b)), "{v:?}");
                    for min in [0.0, 1e-6] {
                        let (ours, theirs) = (try_normalize(&v, min), v.try_normalize(min));
                        let agree = match (ours, theirs) {
                            (Some(a), Some(b)) => a.iter().zip(&b).all(|(a, b)| same(*a, *b)),
                            (None, None) => true,
                            _ => false,
                        };
                        assert!(agree, "{v:?} {min}");
                    }
                    let q = Quaternion::new(0.5, x, y, z);
                    let (ours, theirs) =
                        (normalized_quaternion(q), UnitQuaternion::new_normalize(q));
                    assert!(
                        ours.coords.iter().zip(&theirs.coords).all(|(a, b)| same(*a, *b)),
                        "{q:?}"
                    );
                }
            }
        }
    }
}
