//! The parameter registry: every tunable and every learned value of the board, in one table.
//!
//! Each parameter has a name, a kind (real, integer, flag), a length (a scalar, or a small fixed
//! array: one element per motor, per axis), a unit, an allowed range, a default, a help line and
//! whether calibration or identification writes it. [`Params`] holds the values in force; every
//! change goes through [`Params::set`], which validates the whole value first and changes nothing
//! when any element is refused (the typed error names the range). The configuration store
//! (`super::settings`) saves and loads them by name.
//!
//! The values reach the application through typed views ([`Params::throw_config`],
//! [`Params::configured_offset_m`], ...), so no code outside this file knows a parameter's slot.

use flight::learner::excitation::ExcitationConfig;
use flight::learner::throw_detector::ThrowConfig;
use flight::learner::{LearnedModel, MAX_MOTORS};
use flight::math::clamp;
use flight::navigation::STANDARD_GRAVITY_MPS2;
use protocol::{
    text, DeviceError, ParamInfo, ParamKind, ParamValues, PARAM_HELP_LEN, PARAM_MAX_LEN,
    PARAM_UNIT_LEN, UNIT_LEN,
};

/// Fastest telemetry-radio baud the parameter takes: the H743's UARTs run far faster, the radios
/// (SiK 250,000, ESP32 bridges 921,600) do not.
pub const MAX_RADIO_BAUD: f32 = 921_600.0;
/// Slowest baud that counts as a radio; below it (0 included) the UART stays off.
pub const MIN_RADIO_BAUD: f32 = 1_200.0;

/// One parameter's description.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamSpec {
    pub name: &'static str,
    /// Elements (1 for a scalar, at most [`PARAM_MAX_LEN`]).
    pub len: usize,
    pub kind: ParamKind,
    pub unit: &'static str,
    pub min: f32,
    pub max: f32,
    /// The default: one value for every element, or one per element.
    pub default: &'static [f32],
    /// Written by calibration or identification.
    pub learned: bool,
    pub help: &'static str,
}

impl ParamSpec {
    /// Element `i` of the default.
    pub fn default_at(&self, i: usize) -> f32 {
        if self.default.len() == 1 {
            self.default[0]
        } else {
            self.default[i]
        }
    }

    /// Check one element against the kind and range.
    fn check(&self, value: f32) -> Result<(), DeviceError> {
        let integral = matches!(self.kind, ParamKind::Integer | ParamKind::Flag);
        if integral && value.is_finite() && libm::roundf(value) != value {
            return Err(DeviceError::NotAnInteger { name: text(self.name), value });
        }
        if !(value >= self.min && value <= self.max) {
            return Err(DeviceError::BadValue {
                name: text(self.name),
                value,
                min: self.min,
                max: self.max,
                unit: text::<UNIT_LEN>(self.unit),
            });
        }
        Ok(())
    }

    /// Check a whole value: length, then every element.
    pub fn validate(&self, values: &[f32]) -> Result<(), DeviceError> {
        if values.len() != self.len {
            return Err(DeviceError::WrongLength {
                name: text(self.name),
                expected: self.len as u8,
                got: values.len().min(usize::from(u8::MAX)) as u8,
            });
        }
        values.iter().try_for_each(|&v| self.check(v))
    }
}

/// Declare the registry: the [`Param`] enum (its discriminant is the table index) and [`SPECS`].
macro_rules! registry {
    ($( $(#[$doc:meta])* $variant:ident = $name:literal, $len:expr, $kind:ident, $unit:literal,
        $min:expr, $max:expr, [$($default:expr),+], $learned:literal, $help:literal; )*) => {
        /// A parameter of the registry.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[repr(u16)]
        pub enum Param { $( $(#[$doc])* $variant, )* }

        /// Every parameter's description, in registry order (the order of [`Param`]).
        pub const SPECS: &[ParamSpec] = &[ $( ParamSpec {
            name: $name,
            len: $len,
            kind: ParamKind::$kind,
            unit: $unit,
            min: $min,
            max: $max,
            default: &[$($default),+],
            learned: $learned,
            help: $help,
        }, )* ];
    };
}

/// Largest IMU offset component a parameter accepts, m (a board 0.5 m from the centre of
/// gravity is no longer on the same craft).
const MAX_OFFSET_M: f32 = 0.5;

registry! {
    // Learned by the IMU-offset calibration.
    ImuOffsetValid = "imu_offset_valid", 1, Flag, "", 0.0, 1.0, [0.0], true,
        "1: the learner uses imu_offset_m; 0: the onboard estimate";
    ImuOffsetM = "imu_offset_m", 3, Real, "m", -MAX_OFFSET_M, MAX_OFFSET_M, [0.0], true,
        "IMU position relative to the centre of gravity, IMU axes";
    ImuOffsetCi95M = "imu_offset_ci95_m", 3, Real, "m", 0.0, MAX_OFFSET_M, [0.0], true,
        "semi-axes of imu_offset_m's 95 % ellipsoid, largest first (0: not known)";
    AccBiasMps2 = "acc_bias_mps2", 3, Real, "m/s²", -2.0, 2.0, [0.0], true,
        "accelerometer bias, subtracted from every sample, IMU axes";
    // Learned by the in-flight identification (throw-to-fly).
    ModelMotors = "model_motors", 1, Integer, "", 0.0, MAX_MOTORS as f32, [0.0], true,
        "motors in the learned model below (0: nothing learned yet)";
    MotorTauS = "motor_tau_s", PARAM_MAX_LEN, Real, "s", 0.0, 0.5, [0.0], true,
        "first-order time constant of each motor";
    MotorARadS = "motor_a_rad_s", PARAM_MAX_LEN, Real, "rad/s", -5000.0, 10000.0, [0.0], true,
        "motor model: speed per unit command (linear term)";
    MotorBRadS = "motor_b_rad_s", PARAM_MAX_LEN, Real, "rad/s", -5000.0, 10000.0, [0.0], true,
        "motor model: speed per square root of the command";
    MotorIdleRadS = "motor_idle_rad_s", PARAM_MAX_LEN, Real, "rad/s", 0.0, 5000.0, [0.0], true,
        "motor model: speed at zero command while armed";
    G1Fx = "g1_fx", PARAM_MAX_LEN, Real, "m/s² per u", -500.0, 500.0, [0.0], true,
        "G1 specific force x per unit thrust u = (w/w_full)^2, IMU axes";
    G1Fy = "g1_fy", PARAM_MAX_LEN, Real, "m/s² per u", -500.0, 500.0, [0.0], true,
        "G1 specific force y per unit thrust, IMU axes";
    G1Fz = "g1_fz", PARAM_MAX_LEN, Real, "m/s² per u", -500.0, 500.0, [0.0], true,
        "G1 specific force z per unit thrust, IMU axes";
    G1P = "g1_p", PARAM_MAX_LEN, Real, "rad/s² per u", -50000.0, 50000.0, [0.0], true,
        "G1 angular acceleration about x per unit thrust, IMU axes";
    G1Q = "g1_q", PARAM_MAX_LEN, Real, "rad/s² per u", -50000.0, 50000.0, [0.0], true,
        "G1 angular acceleration about y per unit thrust, IMU axes";
    G1R = "g1_r", PARAM_MAX_LEN, Real, "rad/s² per u", -50000.0, 50000.0, [0.0], true,
        "G1 angular acceleration about z per unit thrust, IMU axes";
    G2P = "g2_p", PARAM_MAX_LEN, Real, "rad/s² per rad/s²", -10.0, 10.0, [0.0], true,
        "G2 rotor reaction about x per motor acceleration, IMU axes";
    G2Q = "g2_q", PARAM_MAX_LEN, Real, "rad/s² per rad/s²", -10.0, 10.0, [0.0], true,
        "G2 rotor reaction about y per motor acceleration, IMU axes";
    G2R = "g2_r", PARAM_MAX_LEN, Real, "rad/s² per rad/s²", -10.0, 10.0, [0.0], true,
        "G2 rotor reaction about z per motor acceleration, IMU axes";
    ThrustAxisQ = "thrust_axis_q", 4, Real, "", -1.0, 1.0, [1.0, 0.0, 0.0, 0.0], true,
        "q_U^T: rotation from the thrust frame to the IMU axes, w x y z";
    // Tunables.
    ThrowMomentumMps = "throw_momentum_mps", 1, Real, "m/s", 2.0, 10.0, [4.0], false,
        "throw detection: speed gained above which a throw begins";
    ThrowReleaseDelayS = "throw_release_delay_s", 1, Real, "s", 0.05, 0.5, [0.150], false,
        "free fall checked this long after release before any motor spins";
    ExcitationStepCmd = "excitation_step_cmd", 1, Real, "", 0.2, 0.8, [0.5], false,
        "identification: command of each motor's pulse (0 to 1)";
    CalMaxSemiAxisMm = "cal_max_semi_axis_mm", 1, Real, "mm", 0.5, 20.0, [2.0], false,
        "calibration done when the throws' 95 % semi-axes are all below this";
    GravityMps2 = "gravity_mps2", 1, Real, "m/s²", 9.7, 9.9, [STANDARD_GRAVITY_MPS2], false,
        "local gravity for the rest poses of the calibration";
    ImuScaleTolPct = "imu_scale_tol_pct", 1, Real, "%", 0.0, 10.0, [3.0], false,
        "IMU scale tolerance (±); 0 for a calibrated IMU";
    MotorBidirDshot = "motor_bidir_dshot", 1, Flag, "", 0.0, 1.0, [1.0], false,
        "1: ESCs report speed (bidirectional DShot); 0: they cannot. At restart";
    RadioBaud = "radio_baud", 1, Integer, "baud", 0.0, MAX_RADIO_BAUD, [0.0], false,
        "telemetry radio on pads TX1/RX1 (57600 for SiK): 0 off. At restart";
    MotorSpeedAgeS = "motor_speed_age_s", 1, Real, "s", 0.0, flight::learner::MAX_SPEED_AGE_S,
        [flight::learner::DEFAULT_SPEED_AGE_S], false,
        "age of an ESC speed report when read: aligns the identification";
    // What the external poses (motion capture, a ground station) are: the pilot's `PoseConfig`.
    PoseLatencyS = "pose_latency_s", 1, Real, "s", 0.0, super::pilot::MAX_POSE_LATENCY_S,
        [super::pilot::DEFAULT_POSE_LATENCY_S], false,
        "age of an external pose when it arrives: capture, processing, radio";
    PoseNoiseM = "pose_noise_m", 1, Real, "m", 0.0001, 2.0, [super::pilot::DEFAULT_POSE_NOISE_M],
        false, "external pose noise, 1 sigma per axis (motion capture 0.001, GNSS 0.5)";
    // The GNSS receiver on a board with a GNSS port (`super::gnss`).
    GnssBaud = "gnss_baud", 1, Integer, "baud", 9_600.0, 921_600.0,
        [crate::drivers::ubx::DEFAULT_TARGET_BAUD as f32], false,
        "GNSS UART rate after configuring (found at any rate). At restart";
    GnssRateHz = "gnss_rate_hz", 1, Real, "Hz", 1.0, 10.0,
        [super::gnss::DEFAULT_GNSS_RATE_HZ], false,
        "GNSS solutions a second (M8-M10: 5-10). At restart";
    GnssLatencyS = "gnss_latency_s", 1, Real, "s", 0.0, super::pilot::MAX_POSE_LATENCY_S,
        [super::gnss::DEFAULT_GNSS_LATENCY_S], false,
        "age of a GNSS solution when it arrives (M8-M10: 0.05-0.15)";
    // The compass on the GNSS mast's I²C (`super::compass`): learned by `compass calibrate`,
    // except whether to use it and the declination.
    CompassEnabled = "compass_enabled", 1, Flag, "", 0.0, 1.0, [1.0], false,
        "1: a calibrated compass's samples go to the pilot; 0: never";
    CompassCalValid = "compass_cal_valid", 1, Flag, "", 0.0, 1.0, [0.0], true,
        "1: the compass_* calibration below is stored (compass calibrate)";
    CompassHardIronUt = "compass_hard_iron_ut", 3, Real, "µT", -MAX_HARD_IRON_UT,
        MAX_HARD_IRON_UT, [0.0], true,
        "hard-iron offset b, subtracted from the raw field, sensor axes";
    CompassSoftIron = "compass_soft_iron", 6, Real, "", -MAX_SOFT_IRON, MAX_SOFT_IRON,
        [1.0, 1.0, 1.0, 0.0, 0.0, 0.0], true,
        "soft-iron matrix W (symmetric): xx yy zz xy xz yz";
    CompassMountQ = "compass_mount_q", 4, Real, "", -1.0, 1.0, [1.0, 0.0, 0.0, 0.0], true,
        "q_mag_imu: rotation from IMU axes to the compass's, w x y z";
    CompassNoiseUt = "compass_noise_ut", 1, Real, "µT", MIN_COMPASS_NOISE_UT, 20.0,
        [super::compass::DEFAULT_COMPASS_NOISE_UT], true,
        "compass noise per axis after calibration (the fit's RMS residual)";
    CompassDeclinationDeg = "compass_declination_deg", 1, Real, "°", -90.0, 90.0, [0.0], false,
        "magnetic declination, east of true north (a map or NOAA's calculator)";
    ImuFaultTimeoutS = "imu_fault_timeout_s", 1, Real, "s", 0.0, 0.1,
        [super::hal::IMU_FAULT_TIMEOUT_S], false,
        "armed: bad IMU samples held (last good) this long, then failsafe";
    // Landing and the failsafes that land (`super::landing::LandConfig`).
    LandDescentMps = "land_descent_mps", 1, Real, "m/s", 0.2, 2.0,
        [super::landing::DEFAULT_LAND_DESCENT_MPS], false,
        "landing: descent speed (straight down with a pose, level without)";
    LandPoseLostS = "land_pose_lost_s", 1, Real, "s", 0.5, 600.0,
        [super::landing::DEFAULT_LAND_POSE_LOST_S], false,
        "in flight: land when the external pose stays lost this long";
    FlyawaySpeedMps = "flyaway_speed_mps", 1, Real, "m/s", 1.0, 20.0,
        [super::landing::DEFAULT_FLYAWAY_SPEED_MPS], false,
        "with a pose: moving away from the setpoint faster counts as a fly-away";
    FlyawayTimeS = "flyaway_time_s", 1, Real, "s", 0.2, 10.0,
        [super::landing::DEFAULT_FLYAWAY_TIME_S], false,
        "a fly-away this long lands the craft";
    LandCellV = "land_cell_v", 1, Real, "V", 0.0, 4.0, [super::battery::DEFAULT_LAND_CELL_V],
        false, "in flight: land when the battery stays below this per cell (0: never)";
    // The pilot's radio and sticks (`super::sticks`).
    RcMap = "rc_map", 4, Integer, "", 1.0, 16.0, [1.0, 2.0, 3.0, 4.0], false,
        "channels of roll, pitch, throttle, yaw (AETR: 1,2,3,4)";
    RcModeChannel = "rc_mode_channel", 1, Integer, "", 1.0, 16.0, [9.0], false,
        "flight-mode switch channel: high position mode, low angle mode";
    StickDeadband = "stick_deadband", 1, Real, "", 0.0, 0.2, [super::sticks::DEFAULT_DEADBAND],
        false, "sticks: deadband around centre, fraction of half travel";
    StickExpo = "stick_expo", 1, Real, "", 0.0, 1.0, [super::sticks::DEFAULT_EXPO], false,
        "sticks: expo, 0 linear to 1 cubic";
    StickMaxTiltDeg = "stick_max_tilt_deg", 1, Real, "°", 5.0, 60.0, [30.0], false,
        "angle mode: tilt of the thrust axis at full roll or pitch stick";
    StickYawRateDps = "stick_yaw_rate_dps", 1, Real, "°/s", 10.0, 360.0, [120.0], false,
        "yaw rate at full yaw stick";
    StickClimbMps = "stick_climb_mps", 1, Real, "m/s", 0.2, 5.0,
        [super::sticks::DEFAULT_MAX_CLIMB_MPS], false,
        "climb rate at full throttle (centre: hold height)";
    StickSpeedMps = "stick_speed_mps", 1, Real, "m/s", 0.2, 10.0,
        [super::sticks::DEFAULT_MAX_SPEED_MPS], false,
        "position mode: setpoint speed at full stick";
    // The flight log (`super::log`).
    LogAlways = "log_always", 1, Flag, "", 0.0, 1.0, [0.0], false,
        "1: log from start-up on; 0: a new log file per arming (and 2 s after)";
    // The hand-catch detector (`super::catch`).
    CatchDetect = "catch_detect", 1, Flag, "", 0.0, 1.0, [1.0], false,
        "in flight: stop the motors when a hand grabs the craft (0: never)";
}

/// Largest hard-iron offset a parameter accepts, µT: beyond the IST8310's ±1,600 µT X/Y range
/// half the range would be gone; a craft's permanent magnetisation is a few hundred µT at most.
const MAX_HARD_IRON_UT: f32 = 1_000.0;
/// Largest soft-iron element a parameter accepts (dimensionless): a soft iron near the identity
/// is a few per cent off; 3 leaves room for a sensor's scale error of either sign.
const MAX_SOFT_IRON: f32 = 3.0;
/// Smallest compass noise a parameter accepts, µT: a hundredth of the best sensor's (the fit's
/// residual of a perfect turn would otherwise claim no noise at all).
const MIN_COMPASS_NOISE_UT: f32 = 0.01;

/// How much further than a calibrated IMU offset the throw detector's free-fall check allows
/// the IMU to be from the centre of gravity, m: the calibration's 95 % semi-axes are below
/// 2 mm by default (`cal_max_semi_axis_mm`), and a battery moved between flights shifts the
/// centre of gravity by a few millimetres.
pub const THROW_OFFSET_MARGIN_M: f32 = 0.005;

/// Number of parameters.
pub const PARAM_COUNT: usize = SPECS.len();

/// Slots of every parameter's elements laid end to end.
const SLOTS: usize = {
    let mut total = 0;
    let mut i = 0;
    while i < SPECS.len() {
        total += SPECS[i].len;
        i += 1;
    }
    total
};

/// First slot of each parameter.
const OFFSETS: [usize; PARAM_COUNT] = {
    let mut offsets = [0; PARAM_COUNT];
    let mut i = 1;
    while i < PARAM_COUNT {
        offsets[i] = offsets[i - 1] + SPECS[i - 1].len;
        i += 1;
    }
    offsets
};

impl Param {
    pub fn spec(self) -> &'static ParamSpec {
        &SPECS[self as usize]
    }
}

/// A fingerprint of the registry's layout (every name and length, in order; FNV-1a, 32 bits):
/// what the flight log writes beside the raw slots, so a reader knows whether its own registry
/// reads them.
pub const LAYOUT_HASH: u32 = {
    let mut hash: u32 = 0x811c_9dc5;
    let mut i = 0;
    while i < SPECS.len() {
        let name = SPECS[i].name.as_bytes();
        let mut j = 0;
        while j < name.len() {
            hash = (hash ^ name[j] as u32).wrapping_mul(0x0100_0193);
            j += 1;
        }
        hash = (hash ^ SPECS[i].len as u32).wrapping_mul(0x0100_0193);
        i += 1;
    }
    hash
};

/// Number of `f32` slots of all parameters laid end to end ([`Params::slots`]).
pub const PARAM_SLOTS: usize = SLOTS;

/// The index of the parameter called `name` (bytes: a stored name is matched without a UTF-8
/// check, which would link `from_utf8`, 0.5 KB).
pub fn find(name: &[u8]) -> Option<usize> {
    SPECS.iter().position(|spec| spec.name.as_bytes() == name)
}

/// The values in force of every parameter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    slots: [f32; SLOTS],
}

impl Default for Params {
    fn default() -> Self {
        let mut slots = [0.0; SLOTS];
        for (index, spec) in SPECS.iter().enumerate() {
            for i in 0..spec.len {
                slots[OFFSETS[index] + i] = spec.default_at(i);
            }
        }
        Self { slots }
    }
}

impl Params {
    /// Every parameter's elements laid end to end, in registry order (the flight log's copy;
    /// [`LAYOUT_HASH`] says which registry they belong to).
    pub fn slots(&self) -> &[f32; SLOTS] {
        &self.slots
    }

    /// The values from `slots` as [`Params::slots`] gave them, each parameter validated; `None`
    /// when any value is out of its range (nothing is taken then).
    pub fn from_slots(slots: &[f32; SLOTS]) -> Option<Self> {
        let params = Self { slots: *slots };
        SPECS
            .iter()
            .enumerate()
            .all(|(i, spec)| spec.validate(params.values(i)).is_ok())
            .then_some(params)
    }

    /// Whether the flight log runs from start-up on rather than per arming.
    /// The GNSS receiver's configuration from `gnss_baud` and `gnss_rate_hz`.
    pub fn gnss_config(&self) -> crate::drivers::ubx::GnssConfig {
        crate::drivers::ubx::GnssConfig {
            target_baud: self.scalar(Param::GnssBaud) as u32,
            measurement_period_s: 1.0 / self.scalar(Param::GnssRateHz),
        }
    }

    /// `gnss_latency_s`.
    pub fn gnss_latency_s(&self) -> f32 {
        self.scalar(Param::GnssLatencyS)
    }

    /// The compass calibration stored by `compass calibrate`, when `compass_cal_valid` is set
    /// and its mounting quaternion is not degenerate (normalised here).
    pub fn compass_calibration(&self) -> Option<super::compass::CompassCalibration> {
        if self.scalar(Param::CompassCalValid) != 1.0 {
            return None;
        }
        let s = self.get(Param::CompassSoftIron);
        let q = self.get(Param::CompassMountQ);
        super::compass::CompassCalibration::new(
            vec3(self.get(Param::CompassHardIronUt)),
            [[s[0], s[3], s[4]], [s[3], s[1], s[5]], [s[4], s[5], s[2]]],
            [q[0], q[1], q[2], q[3]],
            self.scalar(Param::CompassNoiseUt),
        )
    }

    /// Store a compass calibration (`compass calibrate`): `compass_cal_valid` set.
    pub fn store_compass_calibration(&mut self, calibration: &super::compass::CompassCalibration) {
        let w = calibration.soft_iron;
        self.set_learned(Param::CompassHardIronUt, &calibration.offset_ut);
        self.set_learned(
            Param::CompassSoftIron,
            &[w[0][0], w[1][1], w[2][2], w[0][1], w[0][2], w[1][2]],
        );
        self.set_learned(Param::CompassMountQ, &calibration.q_mag_imu);
        self.set_learned(Param::CompassNoiseUt, &[calibration.noise_ut]);
        self.set_learned(Param::CompassCalValid, &[1.0]);
    }

    /// Whether a calibrated compass's samples go to the pilot (`compass_enabled`).
    pub fn compass_enabled(&self) -> bool {
        self.scalar(Param::CompassEnabled) == 1.0
    }

    /// `compass_declination_deg`, in radians (east of true north positive).
    pub fn compass_declination_rad(&self) -> f32 {
        self.scalar(Param::CompassDeclinationDeg).to_radians()
    }

    pub fn log_always(&self) -> bool {
        self.scalar(Param::LogAlways) == 1.0
    }

    /// Parameter `index`'s value.
    pub fn values(&self, index: usize) -> &[f32] {
        &self.slots[OFFSETS[index]..OFFSETS[index] + SPECS[index].len]
    }

    /// A parameter's value.
    pub fn get(&self, param: Param) -> &[f32] {
        self.values(param as usize)
    }

    /// A scalar parameter's value.
    pub fn scalar(&self, param: Param) -> f32 {
        self.get(param)[0]
    }

    /// Set parameter `index` to `values` after validating all of them; nothing changes on an
    /// error. Returns whether the value changed.
    pub fn set(&mut self, index: usize, values: &[f32]) -> Result<bool, DeviceError> {
        let spec = SPECS.get(index).ok_or_else(|| DeviceError::UnknownParam { name: text("") })?;
        spec.validate(values)?;
        let slots = &mut self.slots[OFFSETS[index]..OFFSETS[index] + spec.len];
        let changed = slots != values;
        slots.copy_from_slice(values);
        Ok(changed)
    }

    /// Set a parameter the firmware computed (calibration, identification): elements are
    /// clamped into range and non-finite ones take the default, so a learned value is always a
    /// valid parameter.
    pub fn set_learned(&mut self, param: Param, values: &[f32]) {
        let spec = param.spec();
        let slots = &mut self.slots[OFFSETS[param as usize]..][..spec.len];
        for (i, slot) in slots.iter_mut().enumerate() {
            let value = values.get(i).copied().unwrap_or(0.0);
            *slot = if value.is_finite() {
                clamp(value, spec.min, spec.max)
            } else {
                spec.default_at(i)
            };
        }
    }

    /// Parameter `index` described for the wire, with its value in force.
    pub fn info(&self, index: usize) -> Option<ParamInfo> {
        let spec = SPECS.get(index)?;
        let default: ParamValues = (0..spec.len).map(|i| spec.default_at(i)).collect();
        Some(ParamInfo {
            index: index as u16,
            count: PARAM_COUNT as u16,
            name: text(spec.name),
            kind: spec.kind,
            unit: text::<PARAM_UNIT_LEN>(spec.unit),
            min: spec.min,
            max: spec.max,
            default,
            value: self.values(index).iter().copied().collect(),
            learned: spec.learned,
            help: text::<PARAM_HELP_LEN>(spec.help),
        })
    }

    // ---- Typed views for the application --------------------------------------------------

    /// The calibrated IMU offset (IMU position relative to the CoG, IMU axes, m), when stored.
    pub fn configured_offset_m(&self) -> Option<[f32; 3]> {
        (self.scalar(Param::ImuOffsetValid) == 1.0).then(|| vec3(self.get(Param::ImuOffsetM)))
    }

    /// Whether the ESCs speak bidirectional DShot (the motor outputs read it at start-up; the
    /// learner needs the speeds it reports).
    pub fn bidirectional_dshot(&self) -> bool {
        self.scalar(Param::MotorBidirDshot) == 1.0
    }

    /// Whether throw-to-fly arms although the ESCs report no speed: the user says they cannot
    /// (`motor_bidir_dshot` = 0), and the learner identifies the motors from the commands and
    /// the body's response (`flight::learner::no_speed`). Else the learner needs every motor's
    /// speed, and arming without them is refused.
    pub fn arms_without_speeds(&self) -> bool {
        !self.bidirectional_dshot()
    }

    /// The telemetry radio's baud, when one is configured (the board reads it at start-up).
    pub fn radio_baud(&self) -> Option<u32> {
        let baud = self.scalar(Param::RadioBaud);
        (baud >= MIN_RADIO_BAUD).then_some(baud as u32)
    }

    /// How long the control step rides through bad or missing IMU samples while armed (the
    /// last good sample held) before the IMU failsafe acts, s.
    pub fn imu_fault_timeout_s(&self) -> f32 {
        self.scalar(Param::ImuFaultTimeoutS)
    }

    /// The accelerometer bias to subtract from every sample, m/s², IMU axes.
    pub fn acc_bias_mps2(&self) -> [f32; 3] {
        vec3(self.get(Param::AccBiasMps2))
    }

    /// The throw detector's configuration. With a calibrated IMU offset, the free-fall check
    /// allows for the rotational terms of that offset (and [`THROW_OFFSET_MARGIN_M`] more)
    /// instead of the default 30 mm (and `MAX_IMU_OFFSET_ANYWHERE_M` once the hand is gone): a
    /// tighter check where the offset is known to be small, and a craft whose IMU sits further
    /// out is not refused for its spin.
    pub fn throw_config(&self) -> ThrowConfig {
        let default = ThrowConfig::default();
        let stored = self
            .configured_offset_m()
            .map(|r| libm::sqrtf(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) + THROW_OFFSET_MARGIN_M);
        ThrowConfig {
            release_speed_mps: self.scalar(Param::ThrowMomentumMps),
            release_delay_s: self.scalar(Param::ThrowReleaseDelayS),
            max_imu_offset_m: stored.unwrap_or(default.max_imu_offset_m),
            max_imu_offset_after_hand_m: stored.unwrap_or(default.max_imu_offset_after_hand_m),
            ..default
        }
    }

    /// What the external poses are assumed to be.
    pub fn pose_config(&self) -> super::pilot::PoseConfig {
        super::pilot::PoseConfig {
            latency_s: self.scalar(Param::PoseLatencyS),
            noise_m: self.scalar(Param::PoseNoiseM),
        }
    }

    /// What landings and fly-aways are.
    pub fn land_config(&self) -> super::landing::LandConfig {
        super::landing::LandConfig {
            descent_mps: self.scalar(Param::LandDescentMps),
            pose_lost_s: self.scalar(Param::LandPoseLostS),
            flyaway_speed_mps: self.scalar(Param::FlyawaySpeedMps),
            flyaway_time_s: self.scalar(Param::FlyawayTimeS),
            catch_detect: self.scalar(Param::CatchDetect) != 0.0,
        }
    }

    /// How the pilot's sticks are flown.
    pub fn stick_config(&self) -> super::sticks::StickConfig {
        let radians = core::f32::consts::PI / 180.0;
        super::sticks::StickConfig {
            deadband: self.scalar(Param::StickDeadband),
            expo: self.scalar(Param::StickExpo),
            max_tilt_rad: self.scalar(Param::StickMaxTiltDeg) * radians,
            max_yaw_rate_rad_s: self.scalar(Param::StickYawRateDps) * radians,
            max_climb_mps: self.scalar(Param::StickClimbMps),
            max_speed_mps: self.scalar(Param::StickSpeedMps),
        }
    }

    /// The sticks' channels (`rc_map`); AETR when two are the same.
    pub fn stick_map(&self) -> crate::drivers::crsf::StickMap {
        let map = self.get(Param::RcMap);
        let channels = [map[0], map[1], map[2], map[3]].map(|c| c as u8);
        crate::drivers::crsf::StickMap::from_channels(channels)
            .unwrap_or(crate::drivers::crsf::StickMap::AETR)
    }

    /// The mode switch's channel, 0-based.
    pub fn mode_channel(&self) -> u8 {
        (self.scalar(Param::RcModeChannel) as u8).saturating_sub(1)
    }

    /// The battery voltage per cell below which a flight lands, V (`None`: never).
    pub fn land_cell_v(&self) -> Option<f32> {
        let volts = self.scalar(Param::LandCellV);
        (volts > 0.0).then_some(volts)
    }

    /// How old a motor-speed report is when the control step reads it, s.
    pub fn motor_speed_age_s(&self) -> f32 {
        self.scalar(Param::MotorSpeedAgeS)
    }

    /// The excitation schedule's configuration.
    pub fn excitation_config(&self) -> ExcitationConfig {
        ExcitationConfig {
            step_command: self.scalar(Param::ExcitationStepCmd),
            ..ExcitationConfig::default()
        }
    }

    /// The IMU-offset estimator's configuration.
    pub fn imu_offset_config(&self) -> imu_offset::Config {
        imu_offset::Config {
            max_semi_axis_m: 1e-3 * self.scalar(Param::CalMaxSemiAxisMm),
            gravity_mps2: self.scalar(Param::GravityMps2),
            ..imu_offset::Config::default()
        }
        .with_scale_tolerance(self.scalar(Param::ImuScaleTolPct) / 100.0)
    }

    /// Store an accepted calibration (the throws', or the fit of a flight with none): the
    /// offset with the semi-axes of its 95 % ellipsoid, and the bias when it was fitted (`None`
    /// keeps the bias in force).
    pub fn store_calibration(
        &mut self,
        r_imu_m: [f32; 3],
        ci95_semi_axes_m: [f32; 3],
        acc_bias_mps2: Option<[f32; 3]>,
    ) {
        self.set_learned(Param::ImuOffsetM, &r_imu_m);
        self.set_learned(Param::ImuOffsetCi95M, &ci95_semi_axes_m);
        self.set_learned(Param::ImuOffsetValid, &[1.0]);
        if let Some(bias) = acc_bias_mps2 {
            // The fitted bias is what remains after the bias in force was subtracted.
            let total: [f32; 3] = core::array::from_fn(|i| self.acc_bias_mps2()[i] + bias[i]);
            self.set_learned(Param::AccBiasMps2, &total);
        }
    }

    /// Store what an identification learned: motor models, G1 per unit thrust, G2 and the
    /// thrust axis.
    pub fn store_learned(&mut self, learned: &LearnedModel) {
        let m = usize::from(learned.motors).min(MAX_MOTORS);
        let per_motor = |f: &dyn Fn(usize) -> f32| -> [f32; PARAM_MAX_LEN] {
            core::array::from_fn(|i| if i < m { f(i) } else { 0.0 })
        };
        self.set_learned(Param::ModelMotors, &[m as f32]);
        self.set_learned(Param::MotorTauS, &per_motor(&|i| learned.motor[i].tau_s));
        self.set_learned(Param::MotorARadS, &per_motor(&|i| learned.motor[i].a_rad_s));
        self.set_learned(Param::MotorBRadS, &per_motor(&|i| learned.motor[i].b_rad_s));
        self.set_learned(Param::MotorIdleRadS, &per_motor(&|i| learned.motor[i].omega_idle_rad_s));
        let g1 = learned.g1_per_unit_thrust();
        let g1_params = [Param::G1Fx, Param::G1Fy, Param::G1Fz, Param::G1P, Param::G1Q, Param::G1R];
        for (param, row) in g1_params.into_iter().zip(&g1) {
            self.set_learned(param, &per_motor(&|i| row[i]));
        }
        for (param, row) in [Param::G2P, Param::G2Q, Param::G2R].into_iter().zip(&learned.g2) {
            self.set_learned(param, &per_motor(&|i| row[i]));
        }
        if let Some(axis) = &learned.thrust_axis {
            self.set_learned(Param::ThrustAxisQ, &axis.q_thrust_to_imu);
        }
    }
}

fn vec3(values: &[f32]) -> [f32; 3] {
    [values[0], values[1], values[2]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use flight::learner::throw_detector::MAX_IMU_OFFSET_ANYWHERE_M;
    use protocol::NAME_LEN;

    #[test]
    fn every_description_fits_the_wire_and_its_default_is_allowed() {
        for (index, spec) in SPECS.iter().enumerate() {
            assert!(spec.name.len() <= NAME_LEN, "{}", spec.name);
            assert!(spec.unit.len() <= PARAM_UNIT_LEN, "{}: unit {}", spec.name, spec.unit);
            assert!(
                spec.help.len() <= PARAM_HELP_LEN,
                "{}: help {} bytes",
                spec.name,
                spec.help.len()
            );
            assert!((1..=PARAM_MAX_LEN).contains(&spec.len), "{}", spec.name);
            assert!(spec.default.len() == 1 || spec.default.len() == spec.len, "{}", spec.name);
            assert!(spec.min < spec.max, "{}", spec.name);
            let defaults: ParamValues = (0..spec.len).map(|i| spec.default_at(i)).collect();
            assert_eq!(spec.validate(&defaults), Ok(()), "{}", spec.name);
            assert_eq!(find(spec.name.as_bytes()), Some(index), "{} is not unique", spec.name);
            assert!(spec
                .name
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_'));
        }
    }

    #[test]
    fn the_largest_description_fits_one_frame() {
        let params = Params::default();
        let mut buffer = [0u8; protocol::MAX_FRAME_LEN];
        let mut largest = 0;
        for (index, spec) in SPECS.iter().enumerate() {
            let mut info = params.info(index).unwrap();
            info.value = (0..spec.len).map(|_| f32::MAX).collect();
            info.index = u16::MAX;
            let reply = protocol::DeviceMessage::Response(Ok(protocol::Reply::Param(info)));
            let len = reply.encode(u16::MAX, &mut buffer).expect("a parameter fits a frame");
            largest = largest.max(len);
        }
        // Room for longer help texts and units than today's.
        assert!(largest + 24 <= protocol::MAX_FRAME_LEN, "largest reply {largest} bytes");
    }

    #[test]
    fn the_imu_scale_tolerance_sets_the_calibrations_sensitivity_priors() {
        let mut params = Params::default();
        // ±3 % by default: 1σ of 1.73 % on the scale and 1.15 % across the axes.
        let default = params.imu_offset_config();
        assert!((default.scale_error_sigma - 0.0173).abs() < 1e-4);
        assert!((default.cross_axis_sigma - 0.0115).abs() < 1e-4);
        // A calibrated IMU: no sensitivity prior at all.
        params.set(Param::ImuScaleTolPct as usize, &[0.0]).unwrap();
        let calibrated = params.imu_offset_config();
        assert_eq!((calibrated.scale_error_sigma, calibrated.cross_axis_sigma), (0.0, 0.0));
        assert_eq!(calibrated.sensitivity_offset_sigma(), 0.0);
        // Beyond 10 % is refused and changes nothing.
        assert!(params.set(Param::ImuScaleTolPct as usize, &[12.0]).is_err());
        assert_eq!(params.imu_offset_config(), calibrated);
    }

    #[test]
    fn the_registry_defaults_are_the_flight_defaults() {
        let params = Params::default();
        assert_eq!(params.throw_config(), ThrowConfig::default());
        assert_eq!(params.excitation_config(), ExcitationConfig::default());
        assert_eq!(params.imu_offset_config(), imu_offset::Config::default());
        assert_eq!(params.configured_offset_m(), None);
        assert_eq!(params.get(Param::ThrustAxisQ), &[1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn a_stored_offset_sets_both_throw_allowances_and_none_leaves_the_far_one_for_after_the_hand() {
        let mut params = Params::default();
        let unknown = params.throw_config();
        assert_eq!(unknown.max_imu_offset_after_hand_m, MAX_IMU_OFFSET_ANYWHERE_M);
        assert!(unknown.max_imu_offset_m < unknown.max_imu_offset_after_hand_m);
        params.set(Param::ImuOffsetM as usize, &[0.0, 0.03, 0.04]).unwrap();
        params.set(Param::ImuOffsetValid as usize, &[1.0]).unwrap();
        let stored = params.throw_config();
        let expected = 0.05 + THROW_OFFSET_MARGIN_M;
        assert!((stored.max_imu_offset_m - expected).abs() < 1e-6, "{stored:?}");
        assert_eq!(stored.max_imu_offset_after_hand_m, stored.max_imu_offset_m);
    }

    #[test]
    fn a_refused_value_changes_nothing_and_names_the_range() {
        let mut params = Params::default();
        let before = params;
        let index = Param::ImuOffsetM as usize;
        let error = params.set(index, &[0.01, 0.7, 0.0]).unwrap_err();
        match error {
            DeviceError::BadValue { name, value, min, max, unit } => {
                assert_eq!((name.as_str(), value, min, max), ("imu_offset_m", 0.7, -0.5, 0.5));
                assert_eq!(unit.as_str(), "m");
            }
            other => panic!("unexpected error {other:?}"),
        }
        assert_eq!(params, before);
        let error = params.set(index, &[0.01, 0.02]).unwrap_err();
        assert!(matches!(error, DeviceError::WrongLength { expected: 3, got: 2, .. }), "{error:?}");
        let error = params.set(Param::ModelMotors as usize, &[2.5]).unwrap_err();
        assert!(matches!(error, DeviceError::NotAnInteger { value: 2.5, .. }), "{error:?}");
        let error = params.set(index, &[f32::NAN, 0.0, 0.0]).unwrap_err();
        assert!(matches!(error, DeviceError::BadValue { .. }), "{error:?}");
        assert_eq!(params, before);
        assert_eq!(params.set(index, &[0.01, -0.02, 0.03]), Ok(true));
        assert_eq!(params.get(Param::ImuOffsetM), &[0.01, -0.02, 0.03]);
        assert_eq!(params.set(index, &[0.01, -0.02, 0.03]), Ok(false));
    }

    #[test]
    fn a_calibration_adds_its_residual_bias_to_the_bias_in_force() {
        let mut params = Params::default();
        params.set(Param::AccBiasMps2 as usize, &[0.1, 0.0, -0.2]).unwrap();
        params.store_calibration(
            [0.012, -0.004, 0.03],
            [0.002, 0.001, 0.0005],
            Some([0.05, 0.01, 0.0]),
        );
        assert_eq!(params.configured_offset_m(), Some([0.012, -0.004, 0.03]));
        assert_eq!(params.get(Param::ImuOffsetCi95M), &[0.002, 0.001, 0.0005]);
        let bias = params.acc_bias_mps2();
        assert!((bias[0] - 0.15).abs() < 1e-6 && (bias[1] - 0.01).abs() < 1e-6, "{bias:?}");
        assert!((bias[2] + 0.2).abs() < 1e-6);
    }

    #[test]
    fn catch_detect_turns_the_hand_catch_detector_on_and_off() {
        let mut params = Params::default();
        assert!(params.land_config().catch_detect, "on by default");
        params.set(Param::CatchDetect as usize, &[0.0]).unwrap();
        assert!(!params.land_config().catch_detect);
        assert!(params.set(Param::CatchDetect as usize, &[2.0]).is_err());
        assert!(!params.land_config().catch_detect, "a refused value changes nothing");
    }

    /// A stored compass calibration reads back as stored (the soft iron's six elements as the
    /// symmetric matrix, the mounting normalised); none before one is stored; a declination
    /// outside ±90° is refused with its range and changes nothing.
    #[test]
    fn a_compass_calibration_is_stored_and_read_back_and_a_bad_declination_is_refused() {
        use super::super::compass::CompassCalibration;
        let mut params = Params::default();
        assert_eq!(params.compass_calibration(), None, "not calibrated by default");
        assert!(params.compass_enabled());
        let w = [[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]];
        let half = core::f32::consts::FRAC_1_SQRT_2;
        let stored =
            CompassCalibration::new([120.0, -45.5, 8.0], w, [half, 0.0, 0.0, half], 0.7).unwrap();
        params.store_compass_calibration(&stored);
        let read = params.compass_calibration().expect("stored");
        assert_eq!(read.offset_ut, stored.offset_ut);
        assert_eq!(read.soft_iron, w);
        assert!(read.q_mag_imu.iter().zip(stored.q_mag_imu).all(|(a, b)| (a - b).abs() < 1e-6));
        assert_eq!(read.noise_ut, 0.7);
        let index = Param::CompassDeclinationDeg as usize;
        assert!(matches!(params.set(index, &[95.0]), Err(DeviceError::BadValue { .. })));
        assert_eq!(params.compass_declination_rad(), 0.0);
        params.set(index, &[-12.5]).unwrap();
        assert!((params.compass_declination_rad() - (-12.5f32).to_radians()).abs() < 1e-7);
    }
}
