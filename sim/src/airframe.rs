//! Airframe descriptions: the TOML file format, its validation, the built-in library and a
//! generator of random airframes for Monte Carlo runs.
//!
//! An airframe is everything the physics needs to know about one vehicle: mass and inertia, drag,
//! where the IMU sits and how it is turned, and each rotor's position, thrust axis, spin and
//! motor. The file format *is* the serde structs below: every field's doc comment gives its
//! unit and allowed range, and [`Airframe::validate`] enforces those ranges with an
//! [`AirframeError`] that names the field (`rotor[2].position_m[0]`) and the range, so a typo in
//! a user's file is a clear message, never a strange flight. Unknown keys are rejected too.
//!
//! Conventions (docs/architecture.md): body axes FRD with the origin at the centre of gravity
//! (CoG); quaternions Hamilton `[w, x, y, z]`; `q_a_b` rotates b-coordinates into a-coordinates.
//!
//! The library (`sim/airframes/*.toml`, compiled in; see [`LIBRARY`]) holds the seed paper's quad
//! with its rotated IMU, a 5-inch racing quad, a 3-inch quad, a flat hexarotor, a fully actuated
//! hexarotor with ±30° tilted rotors and an octorotor.

use firmware::app::CONTROL_RATE_HZ;
use nalgebra::{DMatrix, DVector, Matrix3, Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::rng::Rng;

/// Standard gravity, m/s² (CGPM 1901, ISO 80000-3).
pub const STANDARD_GRAVITY_MPS2: f64 = 9.80665;

/// Most motors an airframe may have: the application's limit
/// ([`firmware::app::hal::MAX_MOTORS`]).
pub const MAX_ROTORS: usize = firmware::app::hal::MAX_MOTORS;
/// Fewest motors an airframe may have (the learner needs at least four).
pub const MIN_ROTORS: usize = 4;

/// The built-in airframes: `(name, TOML text)`, files in `sim/airframes/`.
pub const LIBRARY: &[(&str, &str)] = &[
    ("paper-quad", include_str!("../airframes/paper-quad.toml")),
    ("racer-5in", include_str!("../airframes/racer-5in.toml")),
    ("quad-3in", include_str!("../airframes/quad-3in.toml")),
    ("hex-flat", include_str!("../airframes/hex-flat.toml")),
    ("hex-tilted", include_str!("../airframes/hex-tilted.toml")),
    ("octo-flat", include_str!("../airframes/octo-flat.toml")),
];

/// Why an airframe could not be used. Each variant names what to fix.
#[derive(Debug, thiserror::Error)]
pub enum AirframeError {
    /// The file could not be read.
    #[error("cannot read airframe file `{path}`: {error}")]
    Io {
        /// Path as given.
        path: String,
        /// Operating-system error (in the message, so not also a `source`).
        error: std::io::Error,
    },
    /// Not TOML, or a key is missing, unknown or of the wrong type (the message names it).
    #[error("airframe file is not a valid airframe: {0}")]
    Parse(toml::de::Error),
    /// A number lies outside its allowed range.
    #[error("`{field}` = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// Field path, e.g. `rotor[2].motor.tau_s`.
        field: String,
        /// The offending value.
        value: f64,
        /// The allowed range, with unit.
        allowed: String,
    },
    /// A field is inconsistent in a way a range cannot express.
    #[error("`{field}`: {reason}")]
    Invalid {
        /// Field path.
        field: String,
        /// What is wrong and what would be right.
        reason: String,
    },
    /// Neither a file nor a built-in airframe has this name.
    #[error(
        "unknown airframe `{name}`: not a file, and not one of the built-in airframes ({known})"
    )]
    Unknown {
        /// The name asked for.
        name: String,
        /// The built-in names, comma-separated.
        known: String,
    },
    /// The vehicle cannot hover level with its motors within their speed range.
    #[error("airframe `{name}` cannot hover level: {reason}")]
    CannotHover {
        /// Airframe name.
        name: String,
        /// Why.
        reason: String,
    },
}

impl From<toml::de::Error> for AirframeError {
    fn from(error: toml::de::Error) -> Self {
        Self::Parse(error)
    }
}

/// One multirotor. The TOML file is this struct (see the files in `sim/airframes/`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Airframe {
    /// Short identifier used in logs and on the command line.
    pub name: String,
    /// One line saying what this airframe is.
    #[serde(default)]
    pub description: String,
    /// Total mass, kg. Allowed (0.01, 100].
    pub mass_kg: f64,
    /// Diagonal of the inertia tensor about the CoG in body axes `[Ixx, Iyy, Izz]`, kg·m².
    /// Each in (1e-7, 100]; together they must satisfy the triangle inequalities of a real body.
    pub inertia_diag_kg_m2: [f64; 3],
    /// Off-diagonal entries of the inertia tensor `[Ixy, Ixz, Iyz]`, kg·m², as they appear in
    /// the matrix (so `Ixy = −∫ x y dm`). The whole tensor must be positive definite.
    #[serde(default)]
    pub inertia_products_kg_m2: [f64; 3],
    /// Aerodynamic drag of the whole vehicle (defaults: none).
    #[serde(default)]
    pub drag: Drag,
    /// The inertial measurement unit.
    pub imu: ImuParams,
    /// The motor and propeller shared by all rotors (a rotor may override it).
    pub motor: MotorParams,
    /// The rotors, 4 to 8, in the application's motor order (`[[rotor]]` tables).
    #[serde(rename = "rotor")]
    pub rotors: Vec<Rotor>,
}

/// Aerodynamic drag of the whole vehicle, body axes. Force `F_i = −c1_i v_i − c2_i |v_i| v_i`
/// for body-axis airspeed components `v_i`; torque `M_i = −d_i Ω_i`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Drag {
    /// Linear drag coefficients per body axis, N/(m/s). Each in [0, 100].
    #[serde(default)]
    pub linear_n_per_mps: [f64; 3],
    /// Quadratic drag coefficients per body axis, N/(m/s)². Each in [0, 100].
    #[serde(default)]
    pub quadratic_n_per_mps2: [f64; 3],
    /// Rotational damping per body axis, N·m/(rad/s). Each in [0, 10].
    #[serde(default)]
    pub angular_nm_per_rad_s: [f64; 3],
}

/// Where the IMU sits, how it is turned, and how good it is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuParams {
    /// Position `r` of the IMU relative to the CoG, body axes, m. Each component in [−1, 1].
    pub position_m: [f64; 3],
    /// Rotation `q_imu_body` taking body (FRD) coordinates into IMU coordinates, Hamilton
    /// `[w, x, y, z]` (the seed paper's `q_U^T` when the body frame is the thrust frame). Its norm
    /// must be within 1 % of 1; it is normalised on use.
    #[serde(default = "identity_wxyz")]
    pub q_imu_body_wxyz: [f64; 4],
    /// Raw sample rate, Hz. In [2000, 32000] and a whole multiple of the 2 kHz control rate;
    /// the board averages consecutive samples down to 2 kHz. Default 8000 (ICM-42688-P setting in
    /// the papers).
    #[serde(default = "default_imu_rate_hz")]
    pub sample_rate_hz: f64,
    /// Gyroscope.
    pub gyro: GyroParams,
    /// Accelerometer.
    pub accel: AccelParams,
    /// Motor vibration seen by the IMU (default: none).
    #[serde(default)]
    pub vibration: VibrationParams,
}

/// Gyroscope errors and limits, per axis, IMU axes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroParams {
    /// White-noise density, rad/s/√Hz, in [0, 0.1] (ICM-42688-P: 2.8 mdps/√Hz = 4.9e-5).
    pub noise_density_rad_s_per_sqrt_hz: f64,
    /// Constant bias, rad/s, each in [−1, 1].
    #[serde(default)]
    pub bias_rad_s: [f64; 3],
    /// Full-scale range ±, rad/s, in [1, 100] (±2000 °/s = 34.9).
    pub range_rad_s: f64,
    /// ADC resolution, bits, in [8, 24], or 0 for no quantisation. Default 16.
    #[serde(default = "default_bits")]
    pub bits: u32,
    /// Sensitivity matrix, rows per IMU axis: the reading is this times the truth (scale errors
    /// on the diagonal, cross-axis sensitivity and misalignment off it; ICM-42688-P: ±0.5 %
    /// scale, ±2 % cross-axis at most). Default the identity.
    #[serde(default = "identity_3x3")]
    pub sensitivity: [[f64; 3]; 3],
}

/// Accelerometer errors and limits, per axis, IMU axes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelParams {
    /// White-noise density, m/s²/√Hz, in [0, 0.1] (ICM-42688-P: 70 µg/√Hz = 6.9e-4).
    pub noise_density_mps2_per_sqrt_hz: f64,
    /// Constant bias, m/s², each in [−5, 5].
    #[serde(default)]
    pub bias_mps2: [f64; 3],
    /// Full-scale range ±, m/s², in [19, 1000] (±16 g = 156.9).
    pub range_mps2: f64,
    /// ADC resolution, bits, in [8, 24], or 0 for no quantisation. Default 16.
    #[serde(default = "default_bits")]
    pub bits: u32,
    /// Sensitivity matrix, as the gyroscope's (ICM-42688-P: ±0.5 % scale, ±2 % cross-axis).
    #[serde(default = "identity_3x3")]
    pub sensitivity: [[f64; 3]; 3],
}

/// The identity sensitivity: an error-free sensor's.
pub fn identity_3x3() -> [[f64; 3]; 3] {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
}

/// Vibration from rotor imbalance: each rotor adds a sinusoid at its own rotation frequency,
/// rotating in its rotor plane, with amplitude proportional to `(ω/ω_max)²`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VibrationParams {
    /// Accelerometer amplitude per rotor at maximum speed, m/s², in [0, 100].
    #[serde(default)]
    pub accel_mps2_at_max_speed: f64,
    /// Gyroscope amplitude per rotor at maximum speed, rad/s, in [0, 10].
    #[serde(default)]
    pub gyro_rad_s_at_max_speed: f64,
}

/// A motor with its propeller and ESC.
///
/// Steady-state speed for a command δ ∈ (0, 1] while armed (the seed paper's motor model,
/// docs/algorithms/learner.md):
/// `ω_s(δ) = ω_idle + (ω_max − ω_idle)·(κδ + (1 − κ)√δ)`, so δ = 1 gives `omega_max_rad_s`. In the
/// learner's notation (`ω = aδ + b√δ + ω_idle`): `a = κ(ω_max − ω_idle)`,
/// `b = (1 − κ)(ω_max − ω_idle)`, and the papers' "ω_max = a + b" is our `ω_max − ω_idle`.
/// Thrust `k_f ω²`, drag torque `k_m ω²`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorParams {
    /// Speed at δ = 0 while armed, rad/s, in [0, ω_max).
    pub omega_idle_rad_s: f64,
    /// Speed at δ = 1, rad/s, in (0, 10000].
    pub omega_max_rad_s: f64,
    /// Nonlinearity κ of the command-to-speed curve, in [0, 1] (1: linear in δ).
    pub kappa: f64,
    /// First-order speed time constant τ, s, in [0.002, 0.5]: `ω̇ = (ω_s − ω)/τ`.
    pub tau_s: f64,
    /// Thrust coefficient `k_f` (thrust = k_f ω²), N/(rad/s)², in (0, 1e-3].
    pub thrust_coefficient_n_per_rad2_s2: f64,
    /// Drag-torque coefficient `k_m` (torque = k_m ω²), N·m/(rad/s)², in [0, 1e-4].
    pub torque_coefficient_nm_per_rad2_s2: f64,
    /// Moment of inertia of the rotating parts (rotor bell and propeller) about the shaft,
    /// kg·m², in [0, 1e-2]. Causes the reaction torque to motor acceleration (the G2 effect).
    pub rotor_inertia_kg_m2: f64,
    /// Magnet pole pairs (eRPM = RPM × pole pairs), in [1, 50]. Typical 7 (12N14P).
    #[serde(default = "default_pole_pairs")]
    pub pole_pairs: u32,
    /// Age of the bidirectional-DShot speed report when the application reads it, s, in
    /// [0, 0.05]. Rounded to whole 2 kHz control periods. Default 0.0005.
    #[serde(default = "default_telemetry_delay_s")]
    pub telemetry_delay_s: f64,
    /// The family of the command-to-speed curve (default the seed paper's, with `kappa`).
    #[serde(default)]
    pub curve: SpeedCurve,
}

/// How an ESC and its motor turn a command δ ∈ [0, 1] into a steady speed, as the fraction
/// `x(δ)` of the way from idle to full speed. The learner assumes the seed paper's family; the
/// others are what other ESC firmwares and motor/propeller pairs give (issue 28's randomised
/// world), so that the learner is tried on curves it does not model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "family")]
pub enum SpeedCurve {
    /// `x = κδ + (1 − κ)√δ` (docs/algorithms/learner.md, "The motor model"), κ = `kappa`.
    #[default]
    Paper,
    /// Thrust (∝ x²) quadratic in δ: `x = √(kδ² + (1 − k)δ)`, k in [0, 1] (k = 1: speed linear
    /// in δ; k = 0: thrust linear in δ, as a thrust-linearising ESC).
    ThrustPolynomial {
        /// Weight of the quadratic term, in [0, 1].
        k: f64,
    },
    /// `x = δ^p`, p in [0.5, 1.5].
    Power {
        /// Exponent.
        p: f64,
    },
}

impl SpeedCurve {
    /// The fraction of the way from idle to full speed at command `d` ∈ [0, 1], with the paper
    /// family's `kappa`.
    pub fn fraction(&self, d: f64, kappa: f64) -> f64 {
        match *self {
            SpeedCurve::Paper => kappa * d + (1.0 - kappa) * d.sqrt(),
            SpeedCurve::ThrustPolynomial { k } => (k * d * d + (1.0 - k) * d).max(0.0).sqrt(),
            SpeedCurve::Power { p } => d.powf(p),
        }
    }
}

/// Sense of rotation of a rotor, seen looking at the rotor from the side its thrust points to
/// (from above, for an ordinary multirotor).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Spin {
    /// Clockwise: the rotor's angular velocity points against the thrust axis.
    Cw,
    /// Counter-clockwise: the rotor's angular velocity points along the thrust axis.
    Ccw,
}

impl Spin {
    /// +1 when the rotor's angular velocity points along the thrust axis, −1 against it.
    pub fn sign(self) -> f64 {
        match self {
            Spin::Ccw => 1.0,
            Spin::Cw => -1.0,
        }
    }
}

/// One rotor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rotor {
    /// Rotor hub position relative to the CoG, body axes, m. Each component in [−5, 5].
    pub position_m: [f64; 3],
    /// Direction of the thrust force on the vehicle, body axes (any length > 0.1; normalised
    /// on use). Default `[0, 0, −1]`, i.e. up for a level FRD body.
    #[serde(default = "thrust_up")]
    pub thrust_axis: [f64; 3],
    /// Sense of rotation, `"cw"` or `"ccw"` (see [`Spin`]).
    pub spin: Spin,
    /// This rotor's own motor, replacing the airframe's `[motor]` table (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motor: Option<MotorParams>,
}

fn identity_wxyz() -> [f64; 4] {
    [1.0, 0.0, 0.0, 0.0]
}
fn default_imu_rate_hz() -> f64 {
    8000.0
}
fn default_bits() -> u32 {
    16
}
fn default_pole_pairs() -> u32 {
    7
}
fn default_telemetry_delay_s() -> f64 {
    0.0005
}
fn thrust_up() -> [f64; 3] {
    [0.0, 0.0, -1.0]
}

/// Range checks that build field paths and errors.
struct Checker<'a> {
    prefix: &'a str,
}

impl Checker<'_> {
    fn field(&self, name: &str) -> String {
        if self.prefix.is_empty() {
            name.to_string()
        } else {
            format!("{}.{name}", self.prefix)
        }
    }

    /// `lo ≤ value ≤ hi` (or `lo < value` when `lo_open`).
    fn range(
        &self,
        name: &str,
        value: f64,
        lo: f64,
        hi: f64,
        lo_open: bool,
        unit: &str,
    ) -> Result<(), AirframeError> {
        let lo_ok = if lo_open { value > lo } else { value >= lo };
        if lo_ok && value <= hi && value.is_finite() {
            Ok(())
        } else {
            let open = if lo_open { "(" } else { "[" };
            Err(AirframeError::OutOfRange {
                field: self.field(name),
                value,
                allowed: format!("{open}{lo}, {hi}] {unit}"),
            })
        }
    }

    fn range3(
        &self,
        name: &str,
        values: &[f64; 3],
        lo: f64,
        hi: f64,
        unit: &str,
    ) -> Result<(), AirframeError> {
        for (i, v) in values.iter().enumerate() {
            self.range(&format!("{name}[{i}]"), *v, lo, hi, false, unit)?;
        }
        Ok(())
    }

    fn bits(&self, name: &str, bits: u32) -> Result<(), AirframeError> {
        if bits == 0 || (8..=24).contains(&bits) {
            Ok(())
        } else {
            Err(AirframeError::OutOfRange {
                field: self.field(name),
                value: bits as f64,
                allowed: "0 (no quantisation) or [8, 24] bits".into(),
            })
        }
    }
}

impl MotorParams {
    /// Checks every field; `prefix` is the path used in errors (`motor`, `rotor[3].motor`).
    pub fn validate(&self, prefix: &str) -> Result<(), AirframeError> {
        let c = Checker { prefix };
        c.range("omega_max_rad_s", self.omega_max_rad_s, 0.0, 10_000.0, true, "rad/s")?;
        if !(self.omega_idle_rad_s >= 0.0 && self.omega_idle_rad_s < self.omega_max_rad_s) {
            return Err(AirframeError::OutOfRange {
                field: c.field("omega_idle_rad_s"),
                value: self.omega_idle_rad_s,
                allowed: format!("[0, {}) rad/s (below omega_max_rad_s)", self.omega_max_rad_s),
            });
        }
        c.range("kappa", self.kappa, 0.0, 1.0, false, "")?;
        c.range("tau_s", self.tau_s, 0.002, 0.5, false, "s")?;
        c.range(
            "thrust_coefficient_n_per_rad2_s2",
            self.thrust_coefficient_n_per_rad2_s2,
            0.0,
            1e-3,
            true,
            "N/(rad/s)²",
        )?;
        c.range(
            "torque_coefficient_nm_per_rad2_s2",
            self.torque_coefficient_nm_per_rad2_s2,
            0.0,
            1e-4,
            false,
            "N·m/(rad/s)²",
        )?;
        c.range("rotor_inertia_kg_m2", self.rotor_inertia_kg_m2, 0.0, 1e-2, false, "kg·m²")?;
        c.range("pole_pairs", self.pole_pairs as f64, 1.0, 50.0, false, "")?;
        c.range("telemetry_delay_s", self.telemetry_delay_s, 0.0, 0.05, false, "s")?;
        Ok(())
    }

    /// Steady-state speed for command δ while armed (δ clamped to [0, 1]), rad/s.
    pub fn steady_speed_rad_s(&self, command: f64) -> f64 {
        let d = command.clamp(0.0, 1.0);
        self.omega_idle_rad_s
            + (self.omega_max_rad_s - self.omega_idle_rad_s) * self.curve.fraction(d, self.kappa)
    }

    /// The command δ whose steady-state speed is `omega_rad_s` (clamped to the reachable range).
    /// Inverts the curve: with `s = √δ`, `κs² + (1 − κ)s − x = 0` for the normalised speed `x`.
    pub fn command_for_speed(&self, omega_rad_s: f64) -> f64 {
        let x = ((omega_rad_s - self.omega_idle_rad_s)
            / (self.omega_max_rad_s - self.omega_idle_rad_s))
            .clamp(0.0, 1.0);
        if self.curve != SpeedCurve::Paper {
            // Every family is increasing in δ: bisect.
            let (mut lo, mut hi) = (0.0, 1.0);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if self.curve.fraction(mid, self.kappa) < x {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return 0.5 * (lo + hi);
        }
        let k = self.kappa;
        let s = if k < 1e-12 {
            x
        } else {
            (-(1.0 - k) + ((1.0 - k) * (1.0 - k) + 4.0 * k * x).sqrt()) / (2.0 * k)
        };
        (s * s).clamp(0.0, 1.0)
    }
}

impl Airframe {
    /// Parses and validates an airframe from TOML text.
    pub fn from_toml_str(text: &str) -> Result<Self, AirframeError> {
        let airframe: Airframe = toml::from_str(text)?;
        airframe.validate()?;
        Ok(airframe)
    }

    /// A built-in airframe by name (see [`LIBRARY`]).
    pub fn builtin(name: &str) -> Result<Self, AirframeError> {
        match LIBRARY.iter().find(|(n, _)| *n == name) {
            Some((_, text)) => Self::from_toml_str(text),
            None => Err(AirframeError::Unknown { name: name.into(), known: builtin_names() }),
        }
    }

    /// A built-in airframe by name, or else a TOML file at that path.
    pub fn load(name_or_path: &str) -> Result<Self, AirframeError> {
        if LIBRARY.iter().any(|(n, _)| *n == name_or_path) {
            return Self::builtin(name_or_path);
        }
        let path = std::path::Path::new(name_or_path);
        if !path.exists() {
            return Err(AirframeError::Unknown {
                name: name_or_path.into(),
                known: builtin_names(),
            });
        }
        let text = std::fs::read_to_string(path)
            .map_err(|error| AirframeError::Io { path: name_or_path.into(), error })?;
        Self::from_toml_str(&text)
    }

    /// The file text of this airframe (validated airframes round-trip through it).
    pub fn to_toml_string(&self) -> String {
        toml::to_string(self).expect("airframe fields are all TOML-representable")
    }

    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<(), AirframeError> {
        let c = Checker { prefix: "" };
        c.range("mass_kg", self.mass_kg, 0.01, 100.0, true, "kg")?;
        for (i, v) in self.inertia_diag_kg_m2.iter().enumerate() {
            c.range(&format!("inertia_diag_kg_m2[{i}]"), *v, 1e-7, 100.0, true, "kg·m²")?;
        }
        let [a, b, cc] = self.inertia_diag_kg_m2;
        if a + b < cc || a + cc < b || b + cc < a {
            return Err(AirframeError::Invalid {
                field: "inertia_diag_kg_m2".into(),
                reason: "a real body needs Ixx + Iyy ≥ Izz, Ixx + Izz ≥ Iyy and Iyy + Izz ≥ Ixx"
                    .into(),
            });
        }
        c.range3("inertia_products_kg_m2", &self.inertia_products_kg_m2, -100.0, 100.0, "kg·m²")?;
        let eig = self.inertia_matrix().symmetric_eigenvalues();
        if eig.min() <= 0.0 {
            return Err(AirframeError::Invalid {
                field: "inertia_products_kg_m2".into(),
                reason: format!(
                    "the inertia tensor must be positive definite (smallest eigenvalue {:.3e} kg·m²)",
                    eig.min()
                ),
            });
        }
        c.range3("drag.linear_n_per_mps", &self.drag.linear_n_per_mps, 0.0, 100.0, "N/(m/s)")?;
        c.range3(
            "drag.quadratic_n_per_mps2",
            &self.drag.quadratic_n_per_mps2,
            0.0,
            100.0,
            "N/(m/s)²",
        )?;
        c.range3(
            "drag.angular_nm_per_rad_s",
            &self.drag.angular_nm_per_rad_s,
            0.0,
            10.0,
            "N·m/(rad/s)",
        )?;

        let imu = &self.imu;
        c.range3("imu.position_m", &imu.position_m, -1.0, 1.0, "m")?;
        let qn = imu.q_imu_body_wxyz.iter().map(|x| x * x).sum::<f64>().sqrt();
        if !(0.99..=1.01).contains(&qn) {
            return Err(AirframeError::OutOfRange {
                field: "imu.q_imu_body_wxyz".into(),
                value: qn,
                allowed: "a quaternion norm in [0.99, 1.01]".into(),
            });
        }
        c.range("imu.sample_rate_hz", imu.sample_rate_hz, 2000.0, 32_000.0, false, "Hz")?;
        let ratio = imu.sample_rate_hz / f64::from(CONTROL_RATE_HZ);
        if (ratio - ratio.round()).abs() > 1e-9 {
            return Err(AirframeError::Invalid {
                field: "imu.sample_rate_hz".into(),
                reason: format!(
                    "{} Hz is not a whole multiple of the {} Hz control rate",
                    imu.sample_rate_hz, CONTROL_RATE_HZ
                ),
            });
        }
        let g = &imu.gyro;
        c.range(
            "imu.gyro.noise_density_rad_s_per_sqrt_hz",
            g.noise_density_rad_s_per_sqrt_hz,
            0.0,
            0.1,
            false,
            "rad/s/√Hz",
        )?;
        c.range3("imu.gyro.bias_rad_s", &g.bias_rad_s, -1.0, 1.0, "rad/s")?;
        c.range("imu.gyro.range_rad_s", g.range_rad_s, 1.0, 100.0, false, "rad/s")?;
        c.bits("imu.gyro.bits", g.bits)?;
        let a = &imu.accel;
        c.range(
            "imu.accel.noise_density_mps2_per_sqrt_hz",
            a.noise_density_mps2_per_sqrt_hz,
            0.0,
            0.1,
            false,
            "m/s²/√Hz",
        )?;
        c.range3("imu.accel.bias_mps2", &a.bias_mps2, -5.0, 5.0, "m/s²")?;
        c.range("imu.accel.range_mps2", a.range_mps2, 19.0, 1000.0, false, "m/s²")?;
        c.bits("imu.accel.bits", a.bits)?;
        c.range(
            "imu.vibration.accel_mps2_at_max_speed",
            imu.vibration.accel_mps2_at_max_speed,
            0.0,
            100.0,
            false,
            "m/s²",
        )?;
        c.range(
            "imu.vibration.gyro_rad_s_at_max_speed",
            imu.vibration.gyro_rad_s_at_max_speed,
            0.0,
            10.0,
            false,
            "rad/s",
        )?;

        self.motor.validate("motor")?;
        let m = self.rotors.len();
        if !(MIN_ROTORS..=MAX_ROTORS).contains(&m) {
            return Err(AirframeError::OutOfRange {
                field: "rotor".into(),
                value: m as f64,
                allowed: format!("[{MIN_ROTORS}, {MAX_ROTORS}] rotors ([[rotor]] tables)"),
            });
        }
        for (i, r) in self.rotors.iter().enumerate() {
            let prefix = format!("rotor[{i}]");
            let c = Checker { prefix: &prefix };
            c.range3("position_m", &r.position_m, -5.0, 5.0, "m")?;
            let n = Vector3::from(r.thrust_axis).norm();
            if !(n > 0.1 && n.is_finite()) {
                return Err(AirframeError::OutOfRange {
                    field: c.field("thrust_axis"),
                    value: n,
                    allowed: "a direction of length > 0.1".into(),
                });
            }
            if let Some(motor) = &r.motor {
                motor.validate(&c.field("motor"))?;
            }
        }
        Ok(())
    }

    /// Number of rotors.
    pub fn rotor_count(&self) -> usize {
        self.rotors.len()
    }

    /// The motor of rotor `i` (its own, or the shared one).
    pub fn rotor_motor(&self, i: usize) -> &MotorParams {
        self.rotors[i].motor.as_ref().unwrap_or(&self.motor)
    }

    /// Unit thrust axis of rotor `i`, body axes.
    pub fn thrust_axis(&self, i: usize) -> Vector3<f64> {
        Vector3::from(self.rotors[i].thrust_axis).normalize()
    }

    /// The full inertia tensor about the CoG, body axes, kg·m².
    pub fn inertia_matrix(&self) -> Matrix3<f64> {
        let [ixx, iyy, izz] = self.inertia_diag_kg_m2;
        let [ixy, ixz, iyz] = self.inertia_products_kg_m2;
        Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz)
    }

    /// `q_imu_body`, normalised.
    pub fn q_imu_body(&self) -> UnitQuaternion<f64> {
        let [w, x, y, z] = self.imu.q_imu_body_wxyz;
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
    }

    /// IMU position relative to the CoG, body axes, m.
    pub fn r_imu_m(&self) -> Vector3<f64> {
        Vector3::from(self.imu.position_m)
    }

    /// The 6 × m map from squared rotor speeds `ω_i²` to body force (rows 0–2, N) and torque
    /// about the CoG (rows 3–5, N·m), steady state (no rotor acceleration, no body rate).
    pub fn wrench_per_speed_squared(&self) -> DMatrix<f64> {
        let m = self.rotor_count();
        let mut b = DMatrix::zeros(6, m);
        for i in 0..m {
            let motor = self.rotor_motor(i);
            let n = self.thrust_axis(i);
            let r = Vector3::from(self.rotors[i].position_m);
            let force = n * motor.thrust_coefficient_n_per_rad2_s2;
            let torque = r.cross(&force)
                - n * (self.rotors[i].spin.sign() * motor.torque_coefficient_nm_per_rad2_s2);
            for k in 0..3 {
                b[(k, i)] = force[k];
                b[(k + 3, i)] = torque[k];
            }
        }
        b
    }

    /// Rotor speeds (rad/s) that hold the vehicle level (body axes aligned with NED) in hover:
    /// the minimum-norm squared speeds that give force `(0, 0, −m g)` and zero torque. Errors
    /// when no such speeds exist within `[ω_idle, ω_max]` of each motor.
    pub fn hover_speeds_rad_s(&self) -> Result<Vec<f64>, AirframeError> {
        let b = self.wrench_per_speed_squared();
        let target =
            DVector::from_vec(vec![0.0, 0.0, -self.mass_kg * STANDARD_GRAVITY_MPS2, 0.0, 0.0, 0.0]);
        let svd = b.clone().svd(true, true);
        let w2 = svd.solve(&target, 1e-12).map_err(|e| AirframeError::CannotHover {
            name: self.name.clone(),
            reason: e.to_string(),
        })?;
        let residual = (&b * &w2 - &target).norm();
        if residual > 1e-6 * self.mass_kg * STANDARD_GRAVITY_MPS2 {
            return Err(AirframeError::CannotHover {
                name: self.name.clone(),
                reason: format!(
                    "no rotor speeds balance force and torque (residual {residual:.3e})"
                ),
            });
        }
        let mut speeds = Vec::with_capacity(w2.len());
        for (i, w) in w2.iter().enumerate() {
            let motor = self.rotor_motor(i);
            if *w < motor.omega_idle_rad_s.powi(2) || *w > motor.omega_max_rad_s.powi(2) {
                return Err(AirframeError::CannotHover {
                    name: self.name.clone(),
                    reason: format!(
                        "rotor {i} would need {:.0} rad/s, outside [{:.0}, {:.0}] rad/s",
                        w.max(0.0).sqrt(),
                        motor.omega_idle_rad_s,
                        motor.omega_max_rad_s
                    ),
                });
            }
            speeds.push(w.sqrt());
        }
        Ok(speeds)
    }

    /// A random but plausible airframe that can hover level, for Monte Carlo runs: 4 to 8
    /// rotors at jittered angles and arm lengths, a CoG off the geometric centre, per-motor
    /// spread of ±10 % in the coefficients, a random IMU position (±30 mm) and orientation, and
    /// sizes from a 3-inch to a 7-inch class. About a third of the 6- and 8-rotor airframes have
    /// their rotors tilted alternately by ±10–30° about their arms (fully actuated, like
    /// `hex-tilted`). The same seed gives the same airframe.
    pub fn random(seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        loop {
            let candidate = random_candidate(&mut rng, seed);
            if candidate.validate().is_ok() && candidate.hover_speeds_rad_s().is_ok() {
                return candidate;
            }
        }
    }
}

/// Comma-separated built-in names.
pub fn builtin_names() -> String {
    LIBRARY.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ")
}

fn random_candidate(rng: &mut Rng, seed: u64) -> Airframe {
    let m = MIN_ROTORS + (rng.next_u64() % (MAX_ROTORS - MIN_ROTORS + 1) as u64) as usize;
    // Size class: 1 ≈ a 5-inch racer; scales lengths, and masses with the cube of `s`.
    let s = rng.range(0.6, 1.5);
    let arm_m = 0.11 * s;
    let mass_kg = 0.6 * s.powi(3) * (m as f64 / 4.0);
    let radius_of_gyration_m = 0.6 * arm_m;
    let i_xy = mass_kg * radius_of_gyration_m.powi(2);
    let inertia_diag = [
        i_xy * rng.range(0.85, 1.15),
        i_xy * rng.range(0.85, 1.15),
        2.0 * i_xy * rng.range(0.85, 1.0),
    ];
    let products = [
        i_xy * rng.range(-0.05, 0.05),
        i_xy * rng.range(-0.05, 0.05),
        i_xy * rng.range(-0.05, 0.05),
    ];
    // Motor sized for a thrust-to-weight ratio between 2.5 and 5.
    let omega_max = 3300.0 / s * rng.range(0.85, 1.15);
    let t_max_total = mass_kg * STANDARD_GRAVITY_MPS2 * rng.range(2.5, 5.0);
    let k_f = t_max_total / (m as f64 * omega_max * omega_max);
    let base_motor = MotorParams {
        omega_idle_rad_s: omega_max * rng.range(0.05, 0.12),
        omega_max_rad_s: omega_max,
        kappa: rng.range(0.2, 0.7),
        tau_s: rng.range(0.015, 0.045) * s,
        thrust_coefficient_n_per_rad2_s2: k_f,
        torque_coefficient_nm_per_rad2_s2: k_f * rng.range(0.01, 0.02) * s,
        rotor_inertia_kg_m2: 2.5e-6 * s.powi(4),
        pole_pairs: 7,
        telemetry_delay_s: 0.0005,
        curve: SpeedCurve::Paper,
    };
    let cog_offset = [rng.range(-0.1, 0.1) * arm_m, rng.range(-0.1, 0.1) * arm_m, 0.0];
    let tilt_rad = if m.is_multiple_of(2) && m >= 6 && rng.uniform() < 0.35 {
        rng.range(10.0f64, 30.0).to_radians()
    } else {
        0.0
    };
    let rotors = (0..m)
        .map(|i| {
            let angle = std::f64::consts::TAU * (i as f64 + 0.5) / m as f64 + rng.range(-0.1, 0.1);
            let arm = arm_m * rng.range(0.9, 1.1);
            let mut motor = base_motor.clone();
            motor.thrust_coefficient_n_per_rad2_s2 *= rng.range(0.9, 1.1);
            motor.torque_coefficient_nm_per_rad2_s2 *= rng.range(0.9, 1.1);
            motor.tau_s *= rng.range(0.9, 1.1);
            Rotor {
                position_m: [
                    arm * angle.cos() - cog_offset[0],
                    arm * angle.sin() - cog_offset[1],
                    rng.range(-0.02, 0.0) * s,
                ],
                // Tilted about the arm: the axis leans tangentially, alternating in sign.
                thrust_axis: {
                    let t = if i % 2 == 0 { tilt_rad } else { -tilt_rad };
                    [-angle.sin() * t.sin(), angle.cos() * t.sin(), -t.cos()]
                },
                spin: if i % 2 == 0 { Spin::Ccw } else { Spin::Cw },
                motor: Some(motor),
            }
        })
        .collect();
    // Uniformly random IMU orientation (Shoemake's method for a random unit quaternion).
    let (u1, u2, u3) = (rng.uniform(), rng.uniform(), rng.uniform());
    let tau = std::f64::consts::TAU;
    let q = [
        (1.0 - u1).sqrt() * (tau * u2).sin(),
        (1.0 - u1).sqrt() * (tau * u2).cos(),
        u1.sqrt() * (tau * u3).sin(),
        u1.sqrt() * (tau * u3).cos(),
    ];
    Airframe {
        name: format!("random-{seed}"),
        description: format!("random airframe, {m} rotors, seed {seed}"),
        mass_kg,
        inertia_diag_kg_m2: inertia_diag,
        inertia_products_kg_m2: products,
        drag: Drag {
            linear_n_per_mps: [0.05 * s * s; 3],
            quadratic_n_per_mps2: [0.01 * s * s; 3],
            angular_nm_per_rad_s: [0.0; 3],
        },
        imu: ImuParams {
            position_m: [rng.range(-0.03, 0.03), rng.range(-0.03, 0.03), rng.range(-0.015, 0.015)],
            q_imu_body_wxyz: q,
            sample_rate_hz: 8000.0,
            gyro: GyroParams {
                noise_density_rad_s_per_sqrt_hz: 4.9e-5,
                bias_rad_s: [
                    rng.range(-0.01, 0.01),
                    rng.range(-0.01, 0.01),
                    rng.range(-0.01, 0.01),
                ],
                range_rad_s: 34.9,
                bits: 16,
                sensitivity: identity_3x3(),
            },
            accel: AccelParams {
                noise_density_mps2_per_sqrt_hz: 6.9e-4,
                bias_mps2: [rng.range(-0.1, 0.1), rng.range(-0.1, 0.1), rng.range(-0.1, 0.1)],
                range_mps2: 156.9,
                bits: 16,
                sensitivity: identity_3x3(),
            },
            vibration: VibrationParams::default(),
        },
        motor: base_motor,
        rotors,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_airframe_validates_and_can_hover() {
        for (name, _) in LIBRARY {
            let a = Airframe::builtin(name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(&a.name, name);
            let speeds = a.hover_speeds_rad_s().unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(speeds.len(), a.rotor_count());
        }
    }

    #[test]
    fn paper_quad_has_the_seed_papers_imu_pose() {
        let a = Airframe::builtin("paper-quad").unwrap();
        // docs/algorithms/thrust-axis.md: ZYX Euler roll −64°, pitch 24°, yaw −15°;
        // docs/algorithms/imu-offset.md: r ≈ (−10, −13, 8) mm.
        let (roll, pitch, yaw) = a.q_imu_body().euler_angles();
        for (got, want) in [(roll, -64.0), (pitch, 24.0), (yaw, -15.0)] {
            assert!((got.to_degrees() - want).abs() < 0.5, "{} vs {want}", got.to_degrees());
        }
        assert_eq!(a.imu.position_m, [-0.010, -0.013, 0.008]);
    }

    #[test]
    fn command_curve_inverts() {
        let a = Airframe::builtin("quad-3in").unwrap();
        for d in [0.0, 0.01, 0.2, 0.5, 0.93, 1.0] {
            let w = a.motor.steady_speed_rad_s(d);
            assert!((a.motor.command_for_speed(w) - d).abs() < 1e-12, "δ {d}");
        }
        assert_eq!(a.motor.steady_speed_rad_s(1.0), a.motor.omega_max_rad_s);
        assert_eq!(a.motor.steady_speed_rad_s(0.0), a.motor.omega_idle_rad_s);
    }

    #[test]
    fn out_of_range_field_is_named_with_its_range() {
        let text = LIBRARY[0].1.replace("tau_s = 0.025", "tau_s = 3.0");
        match Airframe::from_toml_str(&text) {
            Err(AirframeError::OutOfRange { field, value, allowed }) => {
                assert_eq!(field, "motor.tau_s");
                assert_eq!(value, 3.0);
                assert!(allowed.contains("0.002") && allowed.contains("0.5"), "{allowed}");
            }
            other => panic!("expected OutOfRange, got {other:?}"),
        }
    }

    #[test]
    fn unknown_key_is_rejected_by_name() {
        let text = LIBRARY[0].1.replace("mass_kg", "mass_kgs");
        let err = Airframe::from_toml_str(&text).unwrap_err();
        assert!(matches!(err, AirframeError::Parse(_)));
        assert!(err.to_string().contains("mass_kgs"), "{err}");
    }

    #[test]
    fn too_few_rotors_is_an_error() {
        let mut a = Airframe::builtin("racer-5in").unwrap();
        a.rotors.truncate(3);
        match a.validate() {
            Err(AirframeError::OutOfRange { field, .. }) => assert_eq!(field, "rotor"),
            other => panic!("expected OutOfRange, got {other:?}"),
        }
    }

    #[test]
    fn non_physical_inertia_is_an_error() {
        let mut a = Airframe::builtin("racer-5in").unwrap();
        a.inertia_products_kg_m2 = [0.01, 0.0, 0.0];
        assert!(matches!(a.validate(), Err(AirframeError::Invalid { .. })));
    }

    #[test]
    fn random_airframes_cover_rotor_counts_and_tilts() {
        let mut counts = [0usize; MAX_ROTORS + 1];
        let mut tilted = 0;
        for seed in 0..200 {
            let a = Airframe::random(seed);
            counts[a.rotor_count()] += 1;
            if (0..a.rotor_count()).any(|i| a.thrust_axis(i).z > -0.99) {
                tilted += 1;
            }
        }
        assert!(counts[MIN_ROTORS..].iter().all(|c| *c > 10), "rotor counts {counts:?}");
        assert!(tilted > 10, "only {tilted} tilted airframes in 200");
    }

    #[test]
    fn random_airframes_are_valid_reproducible_and_round_trip() {
        for seed in 0..20 {
            let a = Airframe::random(seed);
            assert_eq!(a, Airframe::random(seed));
            let back = Airframe::from_toml_str(&a.to_toml_string()).unwrap();
            assert_eq!(a, back);
        }
    }
}
