//! A small deterministic random-number generator: sensor noise and random airframes in the
//! simulator, synthetic data in tests.
//!
//! Why our own: simulations and tests must be reproducible from one `u64` seed across platforms
//! and crate versions, and they need only uniform and Gaussian draws. `no_std` (libm), so every
//! crate of the workspace can use this one generator. The generator is
//! xoshiro256++ (Blackman and Vigna, 2019) seeded through SplitMix64; Gaussian draws use
//! Marsaglia's polar method (no trigonometry), caching the second value.

/// Deterministic pseudo-random source (xoshiro256++), seeded from one `u64`.
#[derive(Clone, Debug)]
pub struct Rng {
    s: [u64; 4],
    spare_normal: Option<f64>,
}

impl Rng {
    /// A generator whose whole sequence is fixed by `seed`.
    pub fn new(seed: u64) -> Self {
        let mut x = seed;
        let mut next = || {
            // SplitMix64 step: spreads any seed (including 0) over the full state.
            x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = x;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        Self { s: [next(), next(), next(), next()], spare_normal: None }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Standard normal N(0, 1).
    pub fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare_normal.take() {
            return z;
        }
        // Marsaglia polar method: a uniform point in the unit disc (accepted with probability
        // π/4) gives two independent normals.
        loop {
            let x = 2.0 * self.uniform() - 1.0;
            let y = 2.0 * self.uniform() - 1.0;
            let s = x * x + y * y;
            if s > 0.0 && s < 1.0 {
                let scale = libm::sqrt(-2.0 * libm::log(s) / s);
                self.spare_normal = Some(y * scale);
                return x * scale;
            }
        }
    }

    /// An independent generator derived from this one (for per-run streams in Monte Carlo).
    pub fn fork(&mut self) -> Self {
        Self::new(self.next_u64())
    }

    /// A unit vector uniformly distributed on the sphere.
    pub fn unit_vector(&mut self) -> nalgebra::Vector3<f64> {
        loop {
            let v = nalgebra::Vector3::new(self.normal(), self.normal(), self.normal());
            let n = v.norm();
            if n > 1e-6 {
                return v / n;
            }
        }
    }

    /// A uniformly distributed unit quaternion `[w, x, y, z]`.
    pub fn unit_quaternion(&mut self) -> [f64; 4] {
        loop {
            let q = [self.normal(), self.normal(), self.normal(), self.normal()];
            let n = libm::sqrt(q.iter().map(|v| v * v).sum::<f64>());
            if n > 1e-6 {
                return q.map(|v| v / n);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_has_unit_variance_and_zero_mean() {
        let mut rng = Rng::new(7);
        let n = 200_000;
        let (mut sum, mut sum_sq) = (0.0, 0.0);
        for _ in 0..n {
            let z = rng.normal();
            sum += z;
            sum_sq += z * z;
        }
        let mean = sum / n as f64;
        let var = sum_sq / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "variance {var}");
    }

    #[test]
    fn same_seed_same_sequence() {
        let (mut a, mut b) = (Rng::new(42), Rng::new(42));
        for _ in 0..100 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
    }
}
