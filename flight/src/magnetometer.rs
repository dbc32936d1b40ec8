//! A magnetometer for heading outdoors (issue 55): hard- and soft-iron calibration, the
//! sensor's alignment to the IMU, motor interference, and the tilt-compensated heading.
//!
//! Outdoors a GNSS receiver gives position and velocity but no heading; the only other heading
//! comes from comparing the GNSS track with the acceleration, which needs motion. A compass
//! gives the heading at rest, where one is fitted (an IST8310 or QMC5883L on the GNSS mast,
//! `firmware::drivers::ist8310`, `firmware::drivers::qmc5883l`). Four self-contained pieces, each
//! a plain struct or function tested alone; wiring them into the pilot is not done here.
//!
//! # What the world is assumed to be
//!
//! - The Earth's field is constant over the craft's flight: 22–67 µT at the surface, its
//!   inclination (dip) −90…+90° (World Magnetic Model / IGRF maps). Local disturbances (steel
//!   roofs, cars, rebar) are not modelled; they show as interference.
//! - The sensor sees `m = S h + b + C u + noise`: `h` the Earth's field in the sensor's axes, `b`
//!   the hard iron (permanent magnetisation of the craft and the sensor's offset, up to a few
//!   hundred µT), `S` the soft iron (induced magnetisation and the sensor's scale and
//!   cross-axis errors, near the identity), `C u` the motors' currents' field, linear in each
//!   motor's normalised thrust `u ∈ [0, 1]`.
//! - Noise is white, isotropic, Gaussian (0.3–2 µT per axis for these sensors after their own
//!   averaging).
//!
//! # Hard and soft iron ([`EllipsoidCalibrator`])
//!
//! Turned by hand through every orientation, the raw samples lie on the ellipsoid
//! `(m − b)ᵀ A (m − b) = 1`. The calibrator accumulates the 35 moments `Σ x^a y^b z^c`
//! (`a + b + c ≤ 4`) of the samples shifted to the first one and scaled by
//! [`CALIBRATION_SCALE_UT`], so its memory is fixed (1 KB of `f64`) however long the hand turns;
//! they hold the normal equations of the general quadric `yᵀ A y + 2 lᵀ y + d = 0` (ten
//! coefficients). The fit is the algebraic least squares with the coefficient vector of unit
//! length (the eigenvector of the smallest eigenvalue of the normal matrix, by cyclic Jacobi,
//! [`symmetric_eigen`]), *adjusted* for the noise (Markovsky, Kukush and Van Huffel 2004): each
//! moment is replaced by its Hermite polynomial in the noise variance, which is unbiased for the
//! noise-free moment, and the variance is the one that makes the adjusted matrix singular
//! (bisection). The plain fit's bias grows with the noise squared and pulled the centre of a
//! hemisphere's fit by enough for 6.6° of heading with 0.9 µT of noise (1° adjusted); the
//! adjusted fit is consistent. Shifting to the first sample makes the constant `d` about 0 (the
//! origin lies on the surface), which the unit-length constraint handles where the popular `d = −1`
//! normalisation fails (an offset equal to the field's strength puts the sensor's origin on the
//! ellipsoid). The noise is assumed white, isotropic and Gaussian.
//!
//! The result ([`Calibration`]): the offset `b`, µT; the symmetric soft-iron matrix
//! `W = R M^{1/2}` (`M` the fitted `A` scaled to a right-hand side of 1, `R` the geometric mean
//! of the ellipsoid's semi-axes, the field strength it reports) so that `W (m − b)` lies on the
//! sphere of radius `R`; the fit's residual (RMS distance from that sphere, µT, from the
//! algebraic residual `e ≈ 2 δ/R`); and a coverage figure, `3 λ_min` of the covariance of the
//! calibrated directions: 1 for the whole sphere, 0.25 for a hemisphere, 0 for a single turn
//! about one axis. A fit from too few samples ([`MIN_CALIBRATION_SAMPLES`]), too little
//! coverage ([`MIN_CALIBRATION_COVERAGE`]), a quadric that is not an ellipsoid or a residual above
//! [`MAX_RELATIVE_RESIDUAL`] of the field is refused with a [`CalibrationError`].
//!
//! A symmetric `W` is one choice among `U W` for any rotation `U`: a soft-iron matrix that is not
//! symmetric (sensor axes not orthogonal) leaves the calibrated field rotated by a fixed small
//! rotation, which the alignment below learns with the mounting.
//!
//! # Alignment to the IMU ([`AlignmentEstimator`])
//!
//! The sensor on a GNSS mast sits at an unknown rotation `R = R_mag←imu`. A fixed field `h` in
//! the world seen through the attitude `Q_k = R_world←imu` (gyro-integrated; its yaw need not be
//! referenced to north) gives the calibrated directions `m̂_k = R Q_kᵀ h`. Both `R` and `h` are
//! unknown; the estimator maximises `Σ m̂_kᵀ R Q_kᵀ h` over both: for a fixed `h` the best `R` is
//! Wahba's problem, solved in closed form by Horn's quaternion method (the largest eigenvector
//! of a 4 × 4 symmetric matrix), and for a fixed `R` the best `h` is the mean of the world-frame
//! directions `Q_k Rᵀ m̂_k`. Both need only the 27 sums `Σ Q_k[l][i] m̂_k[j]`, so the memory is
//! fixed. A global search over [`ALIGNMENT_SEARCH_DIRECTIONS`] directions of `h` (Fibonacci
//! lattice) followed by alternating refinement finds the global optimum for any mounting, 180°
//! about any axis included. Assumptions: the attitude's drift over the data is small against the
//! wanted accuracy, and the craft turned about at least two axes: a rotation about the vertical
//! alone cannot tell the mounting's rotation about that axis from the unknown direction of `h`
//! (refused, [`AlignmentError::Unobservable`], from the information matrix of the fit).
//!
//! # Motor interference ([`InterferenceEstimator`], [`InterferenceMonitor`])
//!
//! The currents in the motors' wires and windings add a field `C u` in the sensor's axes. The
//! estimator learns `C` (3 × motors) and the world field `h` (3) together by recursive least
//! squares: `Q_k Rᵀ m_k = h + Q_k Rᵀ C u_k` is linear in both, so the craft may turn while it
//! learns. It tells `C u` from `h` when the thrust changes (a spool-up after a throw, climbs and
//! descents) or the craft turns (the motors' field turns with it, the Earth's does not); hovering
//! at one thrust on one heading it cannot, and its standard deviation of `C u`
//! ([`InterferenceEstimator::interference_ut`]) says so. Telling each motor's share apart needs
//! the motors' thrusts to differ (attitude control does that). The monitor detects what is not compensated: the calibrated field's norm and
//! inclination (the angle below the horizontal, from the attitude's roll and pitch) low-passed
//! and compared with their values with the motors off. A disturbance that turns the field about
//! the vertical without changing its strength changes neither and is not detected: the
//! estimator's compensation is the defence there.
//!
//! # Tilt-compensated heading ([`tilt_compensated_heading`])
//!
//! The field in the IMU's axes rotated into the world with the attitude's roll and pitch only;
//! the yaw in the world is the declination plus the attitude's yaw minus the azimuth of the
//! horizontal field. Its standard deviation: the sensor noise over the horizontal field strength
//! `H`, and a tilt error's leak of the vertical field into the horizontal (`V/H` times it). Near
//! the magnetic poles `H` is small (below 5 µT where the dip exceeds about 84° in a 50 µT field):
//! a heading from less than [`MIN_HORIZONTAL_FIELD_UT`] is refused.
//!
//! # Numbers
//!
//! `f32` in and out, as everywhere on the board; `f64` inside the fits (moments of fourth
//! powers, 27 × 27 covariances), which run at the sensor's rate or once per calibration, in the
//! background task, on the Cortex-M7's double-precision FPU (as the learner's RLS does). Nothing
//! allocates; the largest state is the interference estimator's covariance.
//!
//! # Measured (the tests beside this file, synthetic sensors over the ranges)
//!
//! - Calibration from 3,000 samples at random orientations, hard iron ±300 µT, soft iron 20 %,
//!   noise 0.3–2 µT, 25–65 µT at −70…+70°: worst heading error 0.93° over 24 sensors and a grid
//!   of 840 attitudes (pitch ±60°, roll all round); hard iron within 0.14 µT. A hemisphere: 0.98°.
//!   At the corner of the ranges (25 µT at ±70°, 2 µT of noise, 300 µT and 20 % of iron) a
//!   soft-iron error leaks the vertical field into the heading: 3,000 samples give 2.0° on
//!   average and 4.1° at worst over 16 draws, 10,000 samples (100 s at 100 Hz) 1.2° and 2.0°.
//! - Mounting (any rotation, 180° about each axis included) from 1,200 pairs with 0.5° of
//!   attitude error: within 0.2°; with soft iron that is not symmetric, the heading within 1.2°.
//! - Interference of 50 % of the Earth's field at full thrust (4, 6, 8 motors), learned over a
//!   spool-up and a minute of turning flight: the heading within 1.4° at every thrust (180° off
//!   without); the monitor flags 176 of the 186 random disturbances of 25 % of the field that
//!   turn the heading by more than 2°, and never noise alone.

// Index loops read as the formulas; `!(x >= bound)` refuses NaN too.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::attitude::wrap_pi;

/// The calibration's coordinate scale, µT: samples are shifted to the first one and divided by
/// this, so the quadric's monomials are of order 1 (a typical Earth field; the geomagnetic
/// field is 22–67 µT at the surface, IGRF-13).
pub const CALIBRATION_SCALE_UT: f64 = 50.0;

/// Fewest samples a calibration is fitted from: the quadric has 9 degrees of freedom, and the
/// noise of 0.3–2 µT averages down only over many more (a hand turning for 10 s at 10 Hz).
pub const MIN_CALIBRATION_SAMPLES: u32 = 100;

/// Least coverage ([`Calibration::coverage`]) a calibration is accepted with: a hemisphere
/// (0.25) still fits every coefficient; a few turns about one or two axes (below 0.2) leave the
/// ellipsoid's extent along the missing directions to the noise.
pub const MIN_CALIBRATION_COVERAGE: f32 = 0.2;

/// Largest residual a calibration is accepted with, as a fraction of the field strength: an RMS
/// distance from the sphere beyond 10 % is not the noise of these sensors (at most 2 µT per
/// axis, 8 % of the weakest 25 µT field) but a disturbance during the turning (a motor running,
/// a steel table nearby) or a broken sensor.
pub const MAX_RELATIVE_RESIDUAL: f32 = 0.1;

/// Smallest horizontal field a heading is given from, µT: below it the noise of these sensors
/// (up to 2 µT) alone is more than 20° of heading per sample. The Earth's horizontal field is
/// below 5 µT only near the magnetic dip poles (dip above about 84° in a 50 µT field).
pub const MIN_HORIZONTAL_FIELD_UT: f32 = 5.0;

/// Fewest attitude–field pairs an alignment is solved from.
pub const MIN_ALIGNMENT_SAMPLES: u32 = 50;

/// Directions of the world field tried by the alignment's global search (a Fibonacci lattice:
/// neighbours about 15° apart, well inside the refinement's basin).
pub const ALIGNMENT_SEARCH_DIRECTIONS: usize = 200;

/// Smallest eigenvalue of the alignment's information matrix per sample (dimensionless, 1 at
/// most) below which the mounting is refused as unobservable: turning about the vertical alone
/// gives 0 about that axis; tilting by ±20° about two axes gives about 0.1.
pub const MIN_ALIGNMENT_OBSERVABILITY: f64 = 0.02;

/// Most motors the interference estimator models (an octorotor).
pub const MAX_MOTORS: usize = 8;

/// Unknowns of the interference estimator: the world field (3) and 3 per motor.
const MAX_UNKNOWNS: usize = 3 + 3 * MAX_MOTORS;

/// Jacobi sweeps before the eigen-decomposition stops, converged or not (quadratic convergence
/// reaches f64 precision in under 10 sweeps for 10 × 10).
const MAX_JACOBI_SWEEPS: usize = 30;

// ---------------------------------------------------------------------------------------------
// Linear algebra
// ---------------------------------------------------------------------------------------------

/// Eigenvalues and eigenvectors (columns of the second array) of the symmetric `N × N` matrix
/// `a` by cyclic Jacobi rotations; `None` when an entry is not finite. After
/// [`MAX_JACOBI_SWEEPS`] the rotations stop, converged or not (a bounded run time).
pub fn symmetric_eigen<const N: usize>(a: [[f64; N]; N]) -> Option<([f64; N], [[f64; N]; N])> {
    if !a.iter().flatten().all(|x| x.is_finite()) {
        return None;
    }
    let mut a = a;
    let mut v = [[0.0; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..MAX_JACOBI_SWEEPS {
        let mut off = 0.0;
        let mut diag = 0.0;
        for p in 0..N {
            diag += a[p][p] * a[p][p];
            for q in p + 1..N {
                off += a[p][q] * a[p][q];
            }
        }
        if off <= f64::EPSILON * f64::EPSILON * diag || off == 0.0 {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                let apq = a[p][q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
                let t = if libm::fabs(theta) * f64::EPSILON > 1.0 {
                    0.5 / theta
                } else {
                    let sign = if theta >= 0.0 { 1.0 } else { -1.0 };
                    sign / (libm::fabs(theta) + libm::sqrt(theta * theta + 1.0))
                };
                let c = 1.0 / libm::sqrt(t * t + 1.0);
                let s = t * c;
                for row in a.iter_mut() {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
                for k in 0..N {
                    let (pk, qk) = (a[p][k], a[q][k]);
                    a[p][k] = c * pk - s * qk;
                    a[q][k] = s * pk + c * qk;
                }
                a[p][q] = 0.0;
                a[q][p] = 0.0;
                for row in v.iter_mut() {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
            }
        }
    }
    let mut values = [0.0; N];
    for (i, value) in values.iter_mut().enumerate() {
        *value = a[i][i];
    }
    Some((values, v))
}

/// The index of the smallest (`largest == false`) or largest value.
fn extreme_index<const N: usize>(values: &[f64; N], largest: bool) -> usize {
    let mut best = 0;
    for i in 1..N {
        if (largest && values[i] > values[best]) || (!largest && values[i] < values[best]) {
            best = i;
        }
    }
    best
}

/// The unit quaternion `[w, x, y, z]` of the rotation `R` maximising `Σ bᵀ R r` given
/// `s[i][j] = Σ r_i b_j` (Horn 1987, "Closed-form solution of absolute orientation using unit
/// quaternions", section 4: the eigenvector of the largest eigenvalue of `N(s)`), and that
/// eigenvalue (the maximum).
fn horn_rotation(s: &[[f64; 3]; 3]) -> Option<([f64; 4], f64)> {
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = *s;
    let n = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let (values, vectors) = symmetric_eigen(n)?;
    let k = extreme_index(&values, true);
    Some(([vectors[0][k], vectors[1][k], vectors[2][k], vectors[3][k]], values[k]))
}

fn quaternion_f64(q: [f64; 4]) -> UnitQuaternion<f32> {
    crate::math::normalized_quaternion(Quaternion::new(
        q[0] as f32,
        q[1] as f32,
        q[2] as f32,
        q[3] as f32,
    ))
}

/// The rotation matrix of `[w, x, y, z]` (unit), f64.
fn rotation_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

fn unit_quaternion_matrix(q: &UnitQuaternion<f32>) -> [[f64; 3]; 3] {
    rotation_matrix([f64::from(q.w), f64::from(q.i), f64::from(q.j), f64::from(q.k)])
}

fn normalize3(v: [f64; 3]) -> Option<[f64; 3]> {
    let n = libm::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    (n > 0.0 && n.is_finite()).then(|| [v[0] / n, v[1] / n, v[2] / n])
}

fn finite3(v: &Vector3<f32>) -> bool {
    v.iter().all(|x| x.is_finite())
}

// ---------------------------------------------------------------------------------------------
// Hard and soft iron
// ---------------------------------------------------------------------------------------------

/// Why a calibration was refused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CalibrationError {
    /// Fewer than [`MIN_CALIBRATION_SAMPLES`] samples: keep turning.
    TooFewSamples {
        /// Samples taken.
        samples: u32,
    },
    /// The fitted quadric is not an ellipsoid (a hyperboloid or a degenerate surface): the
    /// samples do not come from one field turned through orientations.
    NotAnEllipsoid,
    /// The samples span too little of the sphere: turn through more orientations (both sides
    /// up, nose up and down).
    InsufficientCoverage {
        /// The coverage reached (see [`Calibration::coverage`]).
        coverage: f32,
    },
    /// The samples are too far from the fitted ellipsoid: a disturbance while turning (motors,
    /// steel nearby) or a broken sensor.
    ResidualTooLarge {
        /// RMS distance from the calibrated sphere, µT.
        residual_ut: f32,
        /// The fitted field strength, µT.
        field_strength_ut: f32,
    },
}

/// A hard- and soft-iron calibration: `W (m − b)` lies on a sphere of radius
/// [`Calibration::field_strength_ut`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Hard-iron offset `b`, µT, sensor axes.
    pub offset_ut: Vector3<f32>,
    /// Soft-iron matrix `W` (symmetric, dimensionless).
    pub soft_iron: Matrix3<f32>,
    /// The field strength the calibrated samples lie at (geometric mean of the ellipsoid's
    /// semi-axes), µT.
    pub field_strength_ut: f32,
    /// RMS distance of the calibrated samples from that sphere, µT.
    pub residual_ut: f32,
    /// How much of the sphere the samples span: 3 times the smallest eigenvalue of the
    /// covariance of the calibrated unit directions; 1 for the whole sphere evenly, 0.25 for a
    /// hemisphere, 0 for turns about one axis.
    pub coverage: f32,
    /// Samples fitted.
    pub samples: u32,
}

impl Calibration {
    /// No correction: zero offset, identity soft iron.
    pub fn identity(field_strength_ut: f32) -> Self {
        Self {
            offset_ut: Vector3::zeros(),
            soft_iron: Matrix3::identity(),
            field_strength_ut,
            residual_ut: 0.0,
            coverage: 0.0,
            samples: 0,
        }
    }

    /// The calibrated field `W (m − b)`, µT, sensor axes.
    pub fn apply(&self, raw_ut: &Vector3<f32>) -> Vector3<f32> {
        self.soft_iron * (raw_ut - self.offset_ut)
    }
}

/// Accumulates the moments of the raw samples (fixed memory) and fits the hard- and soft-iron
/// calibration (see the module documentation).
#[derive(Debug, Clone)]
pub struct EllipsoidCalibrator {
    origin_ut: [f64; 3],
    /// `moments[a][b][c] = Σ x^a y^b z^c` for `a + b + c ≤ 4` (scaled, shifted samples).
    moments: [[[f64; 5]; 5]; 5],
    samples: u32,
}

impl Default for EllipsoidCalibrator {
    fn default() -> Self {
        Self::new()
    }
}

/// The quadric's monomials `[x², y², z², 2yz, 2xz, 2xy, 2x, 2y, 2z, 1]` as exponents and
/// factors: the quadric `dᵀ v = 0` with `v = [a, b, c, f, g, h, p, q, r, d]` is
/// `yᵀ A y + 2 lᵀ y + d = 0`, `A = [[a, h, g], [h, b, f], [g, f, c]]`, `l = [p, q, r]`.
const MONOMIALS: [([usize; 3], f64); 10] = [
    ([2, 0, 0], 1.0),
    ([0, 2, 0], 1.0),
    ([0, 0, 2], 1.0),
    ([0, 1, 1], 2.0),
    ([1, 0, 1], 2.0),
    ([1, 1, 0], 2.0),
    ([1, 0, 0], 2.0),
    ([0, 1, 0], 2.0),
    ([0, 0, 1], 2.0),
    ([0, 0, 0], 1.0),
];

/// The coefficients of the Hermite polynomial `H_k(Y) = Σ_t h[t] Y^t` for noise of variance
/// `s2`: `E[H_k(y + e)] = y^k` for `e ~ N(0, s2)`.
fn hermite(k: usize, s2: f64) -> [f64; 5] {
    match k {
        0 => [1.0, 0.0, 0.0, 0.0, 0.0],
        1 => [0.0, 1.0, 0.0, 0.0, 0.0],
        2 => [-s2, 0.0, 1.0, 0.0, 0.0],
        3 => [0.0, -3.0 * s2, 0.0, 1.0, 0.0],
        _ => [3.0 * s2 * s2, 0.0, -6.0 * s2, 0.0, 1.0],
    }
}

/// Bisection steps of the noise variance (relative precision 2⁻⁴⁰ of the bracket).
const NOISE_BISECTION_STEPS: usize = 40;

impl EllipsoidCalibrator {
    /// Nothing accumulated.
    pub const fn new() -> Self {
        Self { origin_ut: [0.0; 3], moments: [[[0.0; 5]; 5]; 5], samples: 0 }
    }

    /// Samples taken.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Add one raw sample, µT, sensor axes; `false` (and nothing added) for a non-finite one.
    pub fn add_sample(&mut self, raw_ut: &Vector3<f32>) -> bool {
        if !finite3(raw_ut) {
            return false;
        }
        let m = [f64::from(raw_ut.x), f64::from(raw_ut.y), f64::from(raw_ut.z)];
        if self.samples == 0 {
            self.origin_ut = m;
        }
        let powers: [[f64; 5]; 3] = core::array::from_fn(|i| {
            let y = (m[i] - self.origin_ut[i]) / CALIBRATION_SCALE_UT;
            [1.0, y, y * y, y * y * y, y * y * y * y]
        });
        for a in 0..5 {
            for b in 0..5 - a {
                for c in 0..5 - a - b {
                    self.moments[a][b][c] += powers[0][a] * powers[1][b] * powers[2][c];
                }
            }
        }
        self.samples += 1;
        true
    }

    /// `Σ y^e` of the noise-free samples estimated from the noisy ones with noise variance
    /// `s2` per axis (scaled units): each power replaced by its Hermite polynomial.
    fn unbiased_moment(&self, e: [usize; 3], s2: f64) -> f64 {
        let (hx, hy, hz) = (hermite(e[0], s2), hermite(e[1], s2), hermite(e[2], s2));
        let mut sum = 0.0;
        for a in 0..=e[0] {
            for b in 0..=e[1] {
                for c in 0..=e[2] {
                    let k = hx[a] * hy[b] * hz[c];
                    if k != 0.0 {
                        sum += k * self.moments[a][b][c];
                    }
                }
            }
        }
        sum
    }

    /// The normal matrix `Σ d dᵀ` of the quadric's monomials, corrected for noise of variance
    /// `s2` per axis (scaled units; 0: the plain sums).
    fn normal(&self, s2: f64) -> [[f64; 10]; 10] {
        core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                let ((ei, ki), (ej, kj)) = (MONOMIALS[i], MONOMIALS[j]);
                ki * kj * self.unbiased_moment([ei[0] + ej[0], ei[1] + ej[1], ei[2] + ej[2]], s2)
            })
        })
    }

    fn smallest_eigen(normal: [[f64; 10]; 10]) -> Option<(f64, [f64; 10])> {
        let (values, vectors) = symmetric_eigen(normal)?;
        let k = extreme_index(&values, false);
        Some((values[k], core::array::from_fn(|i| vectors[i][k])))
    }

    /// Fit the calibration to the samples so far (they are kept: more can be added).
    ///
    /// Adjusted least squares (Markovsky, Kukush and Van Huffel 2004, "Consistent least squares
    /// fitting of ellipsoids"): the normal matrix's moments are corrected for isotropic noise of
    /// variance `s²`, and `s²` is the one at which the corrected matrix becomes singular
    /// (bisection); the plain algebraic fit's bias, which grows with the noise squared and
    /// pulls the centre of a partial sphere, goes.
    pub fn solve(&self) -> Result<Calibration, CalibrationError> {
        let samples = self.samples;
        if samples < MIN_CALIBRATION_SAMPLES {
            return Err(CalibrationError::TooFewSamples { samples });
        }
        let n = f64::from(samples);
        // The noise variance is below every axis's spread.
        let spread = (0..3)
            .map(|axis| {
                let mut e1 = [0; 3];
                e1[axis] = 1;
                let mut e2 = [0; 3];
                e2[axis] = 2;
                let mean = self.unbiased_moment(e1, 0.0) / n;
                self.unbiased_moment(e2, 0.0) / n - mean * mean
            })
            .fold(f64::INFINITY, f64::min)
            .max(0.0);
        let plain = self.normal(0.0);
        let singular = |s2: f64| -> Result<bool, CalibrationError> {
            let (value, _) =
                Self::smallest_eigen(self.normal(s2)).ok_or(CalibrationError::NotAnEllipsoid)?;
            Ok(value <= 0.0)
        };
        let (mut lo, mut hi) = (0.0, spread);
        if singular(hi)? {
            for _ in 0..NOISE_BISECTION_STEPS {
                let mid = 0.5 * (lo + hi);
                if singular(mid)? {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
        }
        let noise_variance = lo;
        let (_, v) = Self::smallest_eigen(self.normal(noise_variance))
            .ok_or(CalibrationError::NotAnEllipsoid)?;
        // The plain residual of this fit (for the residual below).
        let plain_residual: f64 =
            (0..10).map(|i| v[i] * (0..10).map(|j| plain[i][j] * v[j]).sum::<f64>()).sum();
        let mut a = [[v[0], v[5], v[4]], [v[5], v[1], v[3]], [v[4], v[3], v[2]]];
        let mut l = [v[6], v[7], v[8]];
        let mut d = v[9];
        let (mut lambda, basis) =
            crate::eigen3::symmetric_eigen3(a).ok_or(CalibrationError::NotAnEllipsoid)?;
        // An ellipsoid: A definite. Make it positive.
        if lambda.iter().all(|&x| x < 0.0) {
            for row in a.iter_mut() {
                for x in row.iter_mut() {
                    *x = -*x;
                }
            }
            l = l.map(|x| -x);
            d = -d;
            lambda = lambda.map(|x| -x);
        }
        let largest = lambda.iter().fold(0.0f64, |m, &x| m.max(x));
        if !lambda.iter().all(|&x| x > 1e-9 * largest) || largest <= 0.0 {
            return Err(CalibrationError::NotAnEllipsoid);
        }
        // Centre c = −A⁻¹ l with A⁻¹ = V diag(1/λ) Vᵀ.
        let inverse = |x: [f64; 3]| -> [f64; 3] {
            core::array::from_fn(|i| {
                (0..3)
                    .map(|k| {
                        basis[i][k] * (0..3).map(|j| basis[j][k] * x[j]).sum::<f64>() / lambda[k]
                    })
                    .sum()
            })
        };
        let c = inverse(l).map(|x| -x);
        let ac: [f64; 3] = core::array::from_fn(|i| (0..3).map(|j| a[i][j] * c[j]).sum());
        let scale = (0..3).map(|i| c[i] * ac[i]).sum::<f64>() - d;
        if scale <= 0.0 || !scale.is_finite() {
            return Err(CalibrationError::NotAnEllipsoid);
        }
        // M = A / scale: eigenvalues μ = λ / scale, semi-axes 1/√μ (scaled coordinates).
        let mu = lambda.map(|x| x / scale);
        let radius = libm::pow(1.0 / libm::sqrt(mu[0] * mu[1] * mu[2]), 1.0 / 3.0);
        let w: [[f64; 3]; 3] = core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                (0..3).map(|k| basis[i][k] * libm::sqrt(mu[k]) * radius * basis[j][k]).sum()
            })
        });
        let field_strength_ut = radius * CALIBRATION_SCALE_UT;
        let offset: [f64; 3] =
            core::array::from_fn(|i| self.origin_ut[i] + CALIBRATION_SCALE_UT * c[i]);

        // Residual: the normalised quadric's algebraic residual e = (y−c)ᵀM(y−c) − 1 ≈ 2δ/R has
        // Σe² = vᵀ N v / scale² (v of unit length, N the plain sums).
        let mean_e2 = plain_residual.max(0.0) / (scale * scale) / n;
        let residual_ut = 0.5 * field_strength_ut * libm::sqrt(mean_e2);

        // Coverage from the first and second moments, the noise taken out.
        let moment = |e: [usize; 3]| self.unbiased_moment(e, noise_variance) / n;
        let mean = [moment([1, 0, 0]), moment([0, 1, 0]), moment([0, 0, 1])];
        let second = [
            [moment([2, 0, 0]), moment([1, 1, 0]), moment([1, 0, 1])],
            [moment([1, 1, 0]), moment([0, 2, 0]), moment([0, 1, 1])],
            [moment([1, 0, 1]), moment([0, 1, 1]), moment([0, 0, 2])],
        ];
        let cov_y: [[f64; 3]; 3] =
            core::array::from_fn(|i| core::array::from_fn(|j| second[i][j] - mean[i] * mean[j]));
        // Cov(u) = W Cov(y) Wᵀ / R².
        let wc: [[f64; 3]; 3] = core::array::from_fn(|i| {
            core::array::from_fn(|j| (0..3).map(|k| w[i][k] * cov_y[k][j]).sum())
        });
        let cov_u: [[f64; 3]; 3] = core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                (0..3).map(|k| wc[i][k] * w[j][k]).sum::<f64>() / (radius * radius)
            })
        });
        let (cov_values, _) =
            crate::eigen3::symmetric_eigen3(cov_u).ok_or(CalibrationError::NotAnEllipsoid)?;
        let coverage = 3.0 * cov_values.iter().fold(f64::INFINITY, |m, &x| m.min(x)).max(0.0);

        let calibration = Calibration {
            offset_ut: Vector3::new(offset[0] as f32, offset[1] as f32, offset[2] as f32),
            soft_iron: Matrix3::from_fn(|i, j| w[i][j] as f32),
            field_strength_ut: field_strength_ut as f32,
            residual_ut: residual_ut as f32,
            coverage: coverage as f32,
            samples,
        };
        if !(calibration.offset_ut.iter().chain(calibration.soft_iron.iter()))
            .all(|x| x.is_finite())
        {
            return Err(CalibrationError::NotAnEllipsoid);
        }
        if calibration.coverage < MIN_CALIBRATION_COVERAGE {
            return Err(CalibrationError::InsufficientCoverage { coverage: calibration.coverage });
        }
        if calibration.residual_ut > MAX_RELATIVE_RESIDUAL * calibration.field_strength_ut {
            return Err(CalibrationError::ResidualTooLarge {
                residual_ut: calibration.residual_ut,
                field_strength_ut: calibration.field_strength_ut,
            });
        }
        Ok(calibration)
    }
}

// ---------------------------------------------------------------------------------------------
// Alignment to the IMU
// ---------------------------------------------------------------------------------------------

/// Why an alignment was refused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AlignmentError {
    /// Fewer than [`MIN_ALIGNMENT_SAMPLES`] pairs.
    TooFewSamples {
        /// Pairs taken.
        samples: u32,
    },
    /// The craft did not turn about enough axes for the mounting to be told from the field's
    /// unknown direction (turn about two axes: roll or pitch as well as yaw).
    Unobservable {
        /// The information matrix's smallest eigenvalue per sample (see
        /// [`MIN_ALIGNMENT_OBSERVABILITY`]).
        observability: f32,
    },
    /// The eigen-decomposition failed (non-finite sums).
    Numerical,
}

/// The sensor's mounting, learned.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// `q_mag_imu`: rotates IMU coordinates into the magnetometer's.
    pub q_mag_imu: UnitQuaternion<f32>,
    /// The field's direction in the attitude's world frame (unit).
    pub field_direction_world: Vector3<f32>,
    /// RMS angle between the world-frame directions and their mean, rad (noise, attitude error,
    /// interference).
    pub residual_rad: f32,
    /// Standard deviation of the mounting rotation about its worst axis, rad (from the residual
    /// and the information matrix; an estimate for white errors).
    pub std_rad: f32,
    /// Pairs used.
    pub samples: u32,
}

impl Alignment {
    /// A calibrated field in the magnetometer's axes, rotated into the IMU's.
    pub fn to_imu(&self, field_mag_ut: &Vector3<f32>) -> Vector3<f32> {
        self.q_mag_imu.inverse_transform_vector(field_mag_ut)
    }
}

/// Accumulates (calibrated field direction, attitude) pairs in fixed memory and solves for the
/// mounting rotation (see the module documentation).
#[derive(Debug, Clone, Default)]
pub struct AlignmentEstimator {
    /// `t[l][i][j] = Σ Q_k[l][i] m̂_k[j]`.
    t: [[[f64; 3]; 3]; 3],
    /// `Σ m̂ m̂ᵀ`.
    sum_mm: [[f64; 3]; 3],
    /// `Σ Q_k`.
    sum_q: [[f64; 3]; 3],
    samples: u32,
}

impl AlignmentEstimator {
    /// Nothing accumulated.
    pub fn new() -> Self {
        Self::default()
    }

    /// Pairs taken.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Add a calibrated field (magnetometer axes, any length above 0) seen at the attitude
    /// `q_world_imu`; `false` (nothing added) for a zero or non-finite field.
    pub fn add(&mut self, field_mag_ut: &Vector3<f32>, q_world_imu: &UnitQuaternion<f32>) -> bool {
        let raw = [f64::from(field_mag_ut.x), f64::from(field_mag_ut.y), f64::from(field_mag_ut.z)];
        let Some(m) = normalize3(raw) else {
            return false;
        };
        let q = unit_quaternion_matrix(q_world_imu);
        if !q.iter().flatten().all(|x| x.is_finite()) {
            return false;
        }
        for l in 0..3 {
            for i in 0..3 {
                for j in 0..3 {
                    self.t[l][i][j] += q[l][i] * m[j];
                }
                self.sum_q[l][i] += q[l][i];
                self.sum_mm[l][i] += m[l] * m[i];
            }
        }
        self.samples += 1;
        true
    }

    /// `S(h)[i][j] = Σ (Q_kᵀ h)_i m̂_k[j]`.
    fn cross(&self, h: &[f64; 3]) -> [[f64; 3]; 3] {
        core::array::from_fn(|i| {
            core::array::from_fn(|j| (0..3).map(|l| h[l] * self.t[l][i][j]).sum())
        })
    }

    /// `Σ Q_k Rᵀ m̂_k` for the rotation matrix `r` (`R_mag←imu`).
    fn world_sum(&self, r: &[[f64; 3]; 3]) -> [f64; 3] {
        core::array::from_fn(|l| {
            let mut s = 0.0;
            for i in 0..3 {
                for j in 0..3 {
                    s += r[j][i] * self.t[l][i][j];
                }
            }
            s
        })
    }

    /// Solve for the mounting.
    pub fn solve(&self) -> Result<Alignment, AlignmentError> {
        let samples = self.samples;
        if samples < MIN_ALIGNMENT_SAMPLES {
            return Err(AlignmentError::TooFewSamples { samples });
        }
        let n = f64::from(samples);
        // Global search over the field's direction.
        let golden = core::f64::consts::PI * (3.0 - libm::sqrt(5.0));
        let mut best = (f64::NEG_INFINITY, [0.0, 0.0, 1.0]);
        for k in 0..ALIGNMENT_SEARCH_DIRECTIONS {
            let z = 1.0 - (2.0 * k as f64 + 1.0) / ALIGNMENT_SEARCH_DIRECTIONS as f64;
            let r = libm::sqrt((1.0 - z * z).max(0.0));
            let (s, c) = crate::math::sin_cos_f64(golden * k as f64);
            let h = [r * c, r * s, z];
            let (_, score) = horn_rotation(&self.cross(&h)).ok_or(AlignmentError::Numerical)?;
            if score > best.0 {
                best = (score, h);
            }
        }
        // Alternating refinement.
        let mut h = best.1;
        let mut q = [1.0, 0.0, 0.0, 0.0];
        let mut world = [0.0; 3];
        for _ in 0..100 {
            q = horn_rotation(&self.cross(&h)).ok_or(AlignmentError::Numerical)?.0;
            world = self.world_sum(&rotation_matrix(q));
            let next = normalize3(world).ok_or(AlignmentError::Numerical)?;
            let change = (0..3).map(|i| (next[i] - h[i]) * (next[i] - h[i])).sum::<f64>();
            h = next;
            if change < 1e-24 {
                break;
            }
        }
        let r = rotation_matrix(q);
        let coherence = libm::sqrt(world.iter().map(|x| x * x).sum::<f64>()) / n;
        let residual_rad = libm::sqrt((2.0 - 2.0 * coherence).max(0.0));
        // Information per sample about a small rotation of the mounting (h eliminated):
        // I − Σ e eᵀ/n − Q̄ᵀ (I − h hᵀ) Q̄, e = Rᵀ m̂ (IMU axes), Q̄ = Σ Q / n.
        let ee: [[f64; 3]; 3] = core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                let mut s = 0.0;
                for a in 0..3 {
                    for b in 0..3 {
                        s += r[a][i] * self.sum_mm[a][b] * r[b][j];
                    }
                }
                s / n
            })
        });
        let qbar: [[f64; 3]; 3] =
            core::array::from_fn(|i| core::array::from_fn(|j| self.sum_q[i][j] / n));
        let projector: [[f64; 3]; 3] = core::array::from_fn(|i| {
            core::array::from_fn(|j| f64::from(u8::from(i == j)) - h[i] * h[j])
        });
        let info: [[f64; 3]; 3] = core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                let mut s = 0.0;
                for a in 0..3 {
                    for b in 0..3 {
                        s += qbar[a][i] * projector[a][b] * qbar[b][j];
                    }
                }
                f64::from(u8::from(i == j)) - ee[i][j] - s
            })
        });
        let (info_values, _) =
            crate::eigen3::symmetric_eigen3(info).ok_or(AlignmentError::Numerical)?;
        let observability = info_values.iter().fold(f64::INFINITY, |m, &x| m.min(x));
        if observability < MIN_ALIGNMENT_OBSERVABILITY {
            return Err(AlignmentError::Unobservable { observability: observability as f32 });
        }
        // Per-axis direction noise: the residual spreads over two axes.
        let sigma_axis = residual_rad / core::f64::consts::SQRT_2;
        let std_rad = sigma_axis / libm::sqrt(n * observability);
        Ok(Alignment {
            q_mag_imu: quaternion_f64(q),
            field_direction_world: Vector3::new(h[0] as f32, h[1] as f32, h[2] as f32),
            residual_rad: residual_rad as f32,
            std_rad: std_rad as f32,
            samples,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Motor interference
// ---------------------------------------------------------------------------------------------

/// The interference estimator's prior and noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterferenceConfig {
    /// Prior standard deviation of each unknown (world field component, interference per motor
    /// at full thrust), µT: 100 µT, more than any Earth field and a motor's wires a few cm away.
    pub prior_std_ut: f32,
    /// Calibrated field noise per axis, µT (the calibration's residual is a fair value).
    pub noise_ut: f32,
}

impl Default for InterferenceConfig {
    fn default() -> Self {
        Self { prior_std_ut: 100.0, noise_ut: 1.0 }
    }
}

/// Learns the world field and each motor's interference `C u` by recursive least squares (see
/// the module documentation). Memory: a 27 × 27 `f64` covariance (5.8 KB).
#[derive(Debug, Clone)]
pub struct InterferenceEstimator {
    motors: usize,
    /// `[h (3), C[a][i] at 3 + a·motors + i]`.
    theta: [f64; MAX_UNKNOWNS],
    p: [[f64; MAX_UNKNOWNS]; MAX_UNKNOWNS],
    noise_var: f64,
    samples: u32,
}

impl InterferenceEstimator {
    /// An estimator for `motors` motors (clamped to 1..=[`MAX_MOTORS`]).
    pub fn new(motors: usize, config: InterferenceConfig) -> Self {
        let motors = motors.clamp(1, MAX_MOTORS);
        let mut p = [[0.0; MAX_UNKNOWNS]; MAX_UNKNOWNS];
        let prior = f64::from(config.prior_std_ut) * f64::from(config.prior_std_ut);
        for (i, row) in p.iter_mut().enumerate().take(3 + 3 * motors) {
            row[i] = prior;
        }
        let noise = f64::from(config.noise_ut).max(1e-3);
        Self { motors, theta: [0.0; MAX_UNKNOWNS], p, noise_var: noise * noise, samples: 0 }
    }

    /// Motors modelled.
    pub fn motors(&self) -> usize {
        self.motors
    }

    /// Samples taken.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    fn unknowns(&self) -> usize {
        3 + 3 * self.motors
    }

    /// Add one calibrated field (magnetometer axes, µT) with the attitude, the mounting and
    /// each motor's normalised thrust (0..=1; missing motors count as 0, extra ones are
    /// ignored). `false` (nothing learned) for non-finite input.
    pub fn update(
        &mut self,
        field_mag_ut: &Vector3<f32>,
        q_world_imu: &UnitQuaternion<f32>,
        q_mag_imu: &UnitQuaternion<f32>,
        thrust: &[f32],
    ) -> bool {
        if !finite3(field_mag_ut) || !thrust.iter().all(|u| u.is_finite()) {
            return false;
        }
        // G = Q Rᵀ: magnetometer axes → world.
        let g_q = q_world_imu * q_mag_imu.inverse();
        let g = unit_quaternion_matrix(&g_q);
        let m = [f64::from(field_mag_ut.x), f64::from(field_mag_ut.y), f64::from(field_mag_ut.z)];
        let u: [f64; MAX_MOTORS] =
            core::array::from_fn(|i| thrust.get(i).map_or(0.0, |&x| f64::from(x)));
        let n = self.unknowns();
        for j in 0..3 {
            let y: f64 = (0..3).map(|a| g[j][a] * m[a]).sum();
            let mut h = [0.0; MAX_UNKNOWNS];
            h[j] = 1.0;
            for a in 0..3 {
                for (i, &ui) in u.iter().enumerate().take(self.motors) {
                    h[3 + a * self.motors + i] = g[j][a] * ui;
                }
            }
            let mut ph = [0.0; MAX_UNKNOWNS];
            for r in 0..n {
                ph[r] = (0..n).map(|c| self.p[r][c] * h[c]).sum();
            }
            let s = (0..n).map(|r| h[r] * ph[r]).sum::<f64>() + self.noise_var;
            let predicted: f64 = (0..n).map(|r| h[r] * self.theta[r]).sum();
            let innovation = y - predicted;
            for r in 0..n {
                self.theta[r] += ph[r] / s * innovation;
            }
            for r in 0..n {
                for c in 0..n {
                    self.p[r][c] -= ph[r] * ph[c] / s;
                }
            }
        }
        self.samples += 1;
        true
    }

    /// The world field learned, µT (in the attitude's world frame).
    pub fn world_field_ut(&self) -> Vector3<f32> {
        Vector3::new(self.theta[0] as f32, self.theta[1] as f32, self.theta[2] as f32)
    }

    /// Motor `i`'s interference at full thrust, µT, magnetometer axes.
    pub fn motor_field_ut(&self, i: usize) -> Vector3<f32> {
        if i >= self.motors {
            return Vector3::zeros();
        }
        Vector3::from_fn(|a, _| self.theta[3 + a * self.motors + i] as f32)
    }

    /// The interference `C u` at these thrusts, µT, magnetometer axes, and its standard
    /// deviation (root of the trace of its covariance), µT.
    pub fn interference_ut(&self, thrust: &[f32]) -> (Vector3<f32>, f32) {
        let u: [f64; MAX_MOTORS] =
            core::array::from_fn(|i| thrust.get(i).map_or(0.0, |&x| f64::from(x)));
        let mut field = [0.0; 3];
        let mut variance = 0.0;
        for (a, value) in field.iter_mut().enumerate() {
            for i in 0..self.motors {
                let ri = 3 + a * self.motors + i;
                *value += self.theta[ri] * u[i];
                for k in 0..self.motors {
                    variance += u[i] * u[k] * self.p[ri][3 + a * self.motors + k];
                }
            }
        }
        (
            Vector3::new(field[0] as f32, field[1] as f32, field[2] as f32),
            libm::sqrt(variance.max(0.0)) as f32,
        )
    }

    /// The calibrated field with the interference at these thrusts removed, µT.
    pub fn compensate(&self, field_mag_ut: &Vector3<f32>, thrust: &[f32]) -> Vector3<f32> {
        field_mag_ut - self.interference_ut(thrust).0
    }
}

/// The interference monitor's reference and tolerances.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MonitorConfig {
    /// Low-pass time constant of the deviations, s.
    pub time_constant_s: f32,
    /// Largest deviation of the field strength from the reference, as a fraction of it.
    pub norm_tolerance: f32,
    /// Largest deviation of the inclination from the reference, rad.
    pub inclination_tolerance_rad: f32,
}

impl Default for MonitorConfig {
    /// 0.5 s (a hundred samples at 100 Hz: 2 µT of noise averages to about 0.2 µT, 0.5° of
    /// inclination in a 25 µT field); 8 % of the strength and 3° of inclination, several times
    /// that averaged noise, so noise alone never trips them (tested over a minute), while a
    /// disturbance of a quarter of the field trips one of them in nine cases out of ten where it
    /// turns the heading by more than 2° (tested).
    fn default() -> Self {
        Self {
            time_constant_s: 0.5,
            norm_tolerance: 0.08,
            inclination_tolerance_rad: 3.0 * core::f32::consts::PI / 180.0,
        }
    }
}

/// What the monitor saw in the latest sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterferenceStatus {
    /// Low-passed field strength minus the reference, µT.
    pub norm_error_ut: f32,
    /// Low-passed inclination minus the reference, rad.
    pub inclination_error_rad: f32,
    /// Either beyond its tolerance: distrust the heading.
    pub disturbed: bool,
}

/// Detects interference the compensation left: the calibrated field's strength and inclination
/// against their values with the motors off (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct InterferenceMonitor {
    config: MonitorConfig,
    reference_norm_ut: f32,
    reference_inclination_rad: f32,
    norm_error_ut: f32,
    inclination_error_rad: f32,
}

/// Inclination of a field in the IMU's axes at an attitude: the angle of its world-frame
/// direction below the horizontal (NED: positive down), rad.
pub fn inclination_rad(field_imu_ut: &Vector3<f32>, q_world_imu: &UnitQuaternion<f32>) -> f32 {
    let f = q_world_imu * field_imu_ut;
    libm::atan2f(f.z, crate::math::hypot(f.x, f.y))
}

impl InterferenceMonitor {
    /// A monitor whose reference is a calibrated field (IMU axes, averaged) seen with the
    /// motors off at the attitude `q_world_imu`.
    pub fn new(
        config: MonitorConfig,
        reference_field_imu_ut: &Vector3<f32>,
        q_world_imu: &UnitQuaternion<f32>,
    ) -> Self {
        Self {
            config,
            reference_norm_ut: crate::math::norm(reference_field_imu_ut),
            reference_inclination_rad: inclination_rad(reference_field_imu_ut, q_world_imu),
            norm_error_ut: 0.0,
            inclination_error_rad: 0.0,
        }
    }

    /// One calibrated (and compensated, where an estimator runs) field in the IMU's axes, `dt_s`
    /// after the previous one. A non-finite field counts as disturbed and changes nothing.
    pub fn update(
        &mut self,
        field_imu_ut: &Vector3<f32>,
        q_world_imu: &UnitQuaternion<f32>,
        dt_s: f32,
    ) -> InterferenceStatus {
        if !finite3(field_imu_ut) || !dt_s.is_finite() {
            return InterferenceStatus { disturbed: true, ..self.status() };
        }
        let alpha = crate::math::clamp(dt_s / self.config.time_constant_s.max(dt_s), 0.0, 1.0);
        let norm_error = crate::math::norm(field_imu_ut) - self.reference_norm_ut;
        let inclination_error =
            inclination_rad(field_imu_ut, q_world_imu) - self.reference_inclination_rad;
        self.norm_error_ut += alpha * (norm_error - self.norm_error_ut);
        self.inclination_error_rad += alpha * (inclination_error - self.inclination_error_rad);
        self.status()
    }

    /// The latest status.
    pub fn status(&self) -> InterferenceStatus {
        let disturbed = libm::fabsf(self.norm_error_ut)
            > self.config.norm_tolerance * self.reference_norm_ut
            || libm::fabsf(self.inclination_error_rad) > self.config.inclination_tolerance_rad;
        InterferenceStatus {
            norm_error_ut: self.norm_error_ut,
            inclination_error_rad: self.inclination_error_rad,
            disturbed,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Heading
// ---------------------------------------------------------------------------------------------

/// What the heading needs besides the field and the attitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingConfig {
    /// Magnetic declination, rad, east positive (true north = magnetic north + declination).
    pub declination_rad: f32,
    /// The calibrated field's noise per axis, µT.
    pub noise_ut: f32,
    /// The attitude's tilt standard deviation, rad.
    pub tilt_std_rad: f32,
    /// Smallest horizontal field a heading is given from, µT ([`MIN_HORIZONTAL_FIELD_UT`]).
    pub min_horizontal_ut: f32,
}

impl Default for HeadingConfig {
    /// No declination, 1 µT of noise, 1° of tilt error.
    fn default() -> Self {
        Self {
            declination_rad: 0.0,
            noise_ut: 1.0,
            tilt_std_rad: core::f32::consts::PI / 180.0,
            min_horizontal_ut: MIN_HORIZONTAL_FIELD_UT,
        }
    }
}

/// A heading from the compass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Heading {
    /// Yaw of the IMU in the world (ZYX, from true north), rad, in [−π, π).
    pub yaw_rad: f32,
    /// Its standard deviation, rad.
    pub std_rad: f32,
    /// The horizontal field strength, µT.
    pub horizontal_ut: f32,
    /// The field's inclination (below the horizontal), rad.
    pub inclination_rad: f32,
}

/// Why no heading was given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HeadingError {
    /// The horizontal field is below the bound (near a magnetic pole, or the sensor reads
    /// nothing).
    HorizontalFieldTooWeak {
        /// The horizontal field strength, µT.
        horizontal_ut: f32,
    },
    /// A non-finite field or attitude.
    NotFinite,
}

/// The yaw in the world from a calibrated field in the IMU's axes, the attitude's roll and
/// pitch (`q_world_imu`; its yaw does not matter) and the declination (see the module
/// documentation).
pub fn tilt_compensated_heading(
    field_imu_ut: &Vector3<f32>,
    q_world_imu: &UnitQuaternion<f32>,
    config: &HeadingConfig,
) -> Result<Heading, HeadingError> {
    let (yaw_rad, std_rad, f, horizontal_ut) = tilt_compensated(field_imu_ut, q_world_imu, config)?;
    Ok(Heading {
        yaw_rad,
        std_rad,
        horizontal_ut,
        inclination_rad: libm::atan2f(f.z, horizontal_ut),
    })
}

/// [`tilt_compensated_heading`]'s yaw and its standard deviation alone, rad: one arctangent
/// fewer (the inclination), for the pilot's every compass sample.
pub fn tilt_compensated_yaw(
    field_imu_ut: &Vector3<f32>,
    q_world_imu: &UnitQuaternion<f32>,
    config: &HeadingConfig,
) -> Result<(f32, f32), HeadingError> {
    let (yaw_rad, std_rad, _, _) = tilt_compensated(field_imu_ut, q_world_imu, config)?;
    Ok((yaw_rad, std_rad))
}

/// The yaw and its standard deviation, the field in the world and its horizontal strength.
fn tilt_compensated(
    field_imu_ut: &Vector3<f32>,
    q_world_imu: &UnitQuaternion<f32>,
    config: &HeadingConfig,
) -> Result<(f32, f32, Vector3<f32>, f32), HeadingError> {
    let f = q_world_imu * field_imu_ut;
    if !finite3(&f) || !q_world_imu.coords.iter().all(|x| x.is_finite()) {
        return Err(HeadingError::NotFinite);
    }
    let horizontal_ut = crate::math::hypot(f.x, f.y);
    if !(horizontal_ut >= config.min_horizontal_ut) {
        return Err(HeadingError::HorizontalFieldTooWeak { horizontal_ut });
    }
    // The IMU's yaw (`yaw_of`, its x axis's azimuth) less the field's azimuth, in one
    // arctangent: the angle from the field to the x axis, both seen from above.
    let x = q_world_imu * Vector3::x();
    let turn = libm::atan2f(x.y * f.x - x.x * f.y, x.x * f.x + x.y * f.y);
    let yaw_rad = wrap_pi(config.declination_rad + turn);
    let noise = config.noise_ut / horizontal_ut;
    let tilt = f.z / horizontal_ut * config.tilt_std_rad;
    Ok((yaw_rad, crate::math::sqrt(noise * noise + tilt * tilt), f, horizontal_ut))
}

#[cfg(test)]
mod tests;
