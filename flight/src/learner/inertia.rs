//! The body's normalised inertia `J = I / tr I`: its model, shared by the angular-momentum
//! balance of [`super::effectiveness`] (which refines `J` in flight) and the free tumble between
//! the release and the first motor pulse, whose fit gives the balance its prior
//! ([`InertiaPrior`]).
//!
//! The tumble's fit itself (`TumbleInertia`, the why and the how: the `tumble` crate) lives in a
//! crate of its own so that the firmware compiles it for size: it runs only in the release delay
//! and once per throw, never in the 2 kHz step or the learner's sample (docs/benchmarks.md,
//! "Firmware size"). What stays here is what the balance needs on every sample.

// Index loops are kept where they mirror the matrix notation (entries of J by index), as in
// `effectiveness`.
#![allow(clippy::needless_range_loop)]

// The normalised inertia's model, shared by the balance rows of the effectiveness regression
// (`super::effectiveness`) and the free tumble (the `tumble` crate).

/// The six distinct products `Ωₐ Ω_b` (a ≤ b), in this order.
pub const RATE_PRODUCTS: usize = 6;
/// Index of `Ωₐ Ω_b` in the rate products.
pub const fn rate_product(a: usize, b: usize) -> usize {
    const INDEX: [[usize; 3]; 3] = [[0, 1, 2], [1, 3, 4], [2, 4, 5]];
    INDEX[a][b]
}
/// Parameters of the normalised inertia `J = I / tr I`: `J_xx, J_yy, J_xy, J_xz, J_yz`
/// (`J_zz = 1 − J_xx − J_yy`).
pub const INERTIA_PARAMETERS: usize = 5;
/// Prior variance `P₀` of the normalised inertia's five parameters, about a sphere's `J = I/3`
/// (the other parameters start at `RlsConfig::p0`, uninformed). The data fix `J` only through
/// the body's rotation (the Euler and rotor-momentum terms: `J Ω̇ = T ω²` alone holds for any
/// `J` with `T` scaled to match), a few per cent of the signal in the regressions' band, and on
/// some throws they leave a direction of `J` almost free: unregularised, the Monte Carlo's
/// 99th-percentile G1τ error was 42 % (the learned `J` had principal moments above half the
/// trace, which no rigid body has). This weak prior pulls only such directions towards the
/// sphere. Chosen on the simulator's Monte Carlo (300 random airframes, block error median /
/// 99th percentile): 1 → 3.4 / 36 %, 0.1 → 2.8 / 16 %, 0.02 → 2.7 / 11 %, 0.003 → 3.2 / 11 %
/// (1,000 airframes at 0.02: docs/benchmarks.md).
pub const INERTIA_PRIOR_VARIANCE: f32 = 2e-2;

/// Row `k` of `J a + Ω × (J Ω)` as a linear function of the five free entries of `J`
/// (`J_xx, J_yy, J_xy, J_xz, J_yz`, with `J_zz = 1 − J_xx − J_yy`), given `a` (the angular
/// acceleration, or a change of rate) and `product(a, b)` for the matching `Ωₐ Ω_b` (or its
/// integral): returns the regressors of the five and the output, so that
/// `regressors · J = output + torque` for the row's torque terms moved to the left. Shared by the
/// balance ([`super::effectiveness`]) and the tumble (the `tumble` crate).
///
/// Row k for `J = E_pq` (1 at (p, q)) is `L_pq = δ_kp a_q + δ_{k+2,p} (ΩΩᵀ)_{q,k+1}
/// − δ_{k+1,p} (ΩΩᵀ)_{q,k+2}`: row k of L is `aᵀ`, row k+2 column k+1 of ΩΩᵀ, row k+1 minus
/// column k+2; and `J = J_xx (E_xx − E_zz) + J_yy (E_yy − E_zz) + J_xy (E_xy + E_yx) + … + E_zz`,
/// whose constant `E_zz` part is the output.
pub fn inertia_regressors(
    k: usize,
    a: [f32; 3],
    product: impl Fn(usize, usize) -> f32,
) -> ([f32; INERTIA_PARAMETERS], f32) {
    let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
    let mut l = [[0.0f32; 3]; 3];
    l[k] = a;
    l[k2] = [product(0, k1), product(1, k1), product(2, k1)];
    l[k1] = [-product(0, k2), -product(1, k2), -product(2, k2)];
    let zz = l[2][2];
    let regressors = [
        zz - l[0][0],
        zz - l[1][1],
        -(l[0][1] + l[1][0]),
        -(l[0][2] + l[2][0]),
        -(l[1][2] + l[2][1]),
    ];
    (regressors, zz)
}

/// Time from the declared release to the tumble's first sample, s: the hand may still touch the
/// craft then, and its torque is not the free body's.
///
/// The throw detector ([`super::throw_detector`]) declares the release at the first sample whose
/// specific force is within 0.8 g of what the spin explains at an IMU 30 mm out: up to 17 m/s² at
/// 1,000 °/s, a third to a half of a 35–50 m/s² push. A hand that lets go over its stated 0–50 ms
/// still pushes, and spins, for up to half its taper after that: 25 ms. Measured on the world's
/// hand (`sim::world`, tapers 0–50 ms, spins up to 1,000 °/s): the hand let go 2–15 ms after the
/// declared release, and a tumble from the declared release learned `J` wrong by up to 0.4 while
/// trusting it (the balance then kept it: rotational rows of G1 35–345 % off, no hover). Any touch
/// that outlasts this is absorbed by the rows' constants (see the module doc).
pub const HAND_CONTACT_S: f32 = 0.025;

/// A prior for the normalised inertia: mean and covariance of `J_xx, J_yy, J_xy, J_xz, J_yz`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InertiaPrior {
    /// Mean of the five free entries (IMU axes).
    pub mean: [f32; INERTIA_PARAMETERS],
    /// Their covariance.
    pub covariance: [[f32; INERTIA_PARAMETERS]; INERTIA_PARAMETERS],
    /// Equations (three per sample) behind it; 0 for the sphere alone.
    pub equations: u32,
}

impl InertiaPrior {
    /// A sphere's `J = I/3` with variance [`INERTIA_PRIOR_VARIANCE`] per entry, uncorrelated: the
    /// prior when nothing is known of the body.
    pub fn sphere() -> Self {
        let mut covariance = [[0.0; INERTIA_PARAMETERS]; INERTIA_PARAMETERS];
        for (j, row) in covariance.iter_mut().enumerate() {
            row[j] = INERTIA_PRIOR_VARIANCE;
        }
        Self { mean: [1.0 / 3.0, 1.0 / 3.0, 0.0, 0.0, 0.0], covariance, equations: 0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::spd_inverse;

    #[test]
    fn the_cholesky_inverse_inverts_and_refuses_what_is_not_positive_definite() {
        let mut a = [[0.0; INERTIA_PARAMETERS]; INERTIA_PARAMETERS];
        for i in 0..INERTIA_PARAMETERS {
            for j in 0..INERTIA_PARAMETERS {
                a[i][j] = 1.0 / (1.0 + i as f64 + j as f64); // Hilbert-like, positive definite
            }
            a[i][i] += 0.1;
        }
        let inverse = spd_inverse(&a).expect("positive definite");
        for i in 0..INERTIA_PARAMETERS {
            for j in 0..INERTIA_PARAMETERS {
                let product: f64 = (0..INERTIA_PARAMETERS).map(|k| a[i][k] * inverse[k][j]).sum();
                let identity = if i == j { 1.0 } else { 0.0 };
                assert!((product - identity).abs() < 1e-12, "({i}, {j}): {product}");
            }
        }
        a[2][2] = -1.0;
        assert_eq!(spd_inverse(&a), None);
        a[2][2] = f64::NAN;
        assert_eq!(spd_inverse(&a), None);
    }
}
