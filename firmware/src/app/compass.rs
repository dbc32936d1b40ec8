//! The compass as the application sees it: an IST8310 or QMC5883L found on the I²C bus, read at
//! its rate, its stored calibration applied, and each calibrated field handed to the control
//! step as a [`MagneticSample`] in the IMU's axes; and the calibration procedure that fits that
//! calibration (`configurator-cli compass calibrate`).
//!
//! Why: outdoors the GNSS receiver gives position and velocity but no heading (issue 55); a
//! compass on the GNSS mast gives it at rest. The mathematics is in `flight::magnetometer`, the
//! register-level drivers in `crate::drivers::{ist8310, qmc5883l}`; this is the portable service
//! between them, the same on the board (its I²C master, `board::i2c`) and in the simulators, like
//! the GNSS receiver's [`super::gnss::GnssInput`]. Its samples go to the control step as
//! [`super::ControlCommand::MagneticField`], so the flight log records them and a replay needs
//! no sensor.
//!
//! **The service** ([`CompassInput::service`]): called from a low-priority context (the board's
//! link pass, every millisecond; it reads when a reading is due, every
//! [`COMPASS_READ_PERIOD_US`]), never from the 2 kHz step: one read is one or two I²C transfers
//! of about 0.2 ms at 400 kHz. Without a sensor it probes the three addresses once every
//! [`COMPASS_PROBE_PERIOD_US`] (an identity read each; an absent device does not acknowledge,
//! which costs one address byte); the sensor found is initialised through the caller's delay
//! (the IST8310's soft reset asks for 50 ms: at start-up, and once per return of a lost
//! sensor). A sensor lost (ten failed reads in a row, `drivers::compass::HealthMonitor`) is
//! dropped and probed for again; one stuck or saturated stays, but gives no sample until its
//! readings are healthy again.
//!
//! **The calibration** (stored in the parameters `compass_hard_iron_ut`, `compass_soft_iron`,
//! `compass_mount_q`, `compass_noise_ut`, `compass_cal_valid`): the raw field `m` (µT, sensor
//! axes) becomes `W (m − b)` (hard iron `b`, symmetric soft iron `W`), then is rotated into the
//! IMU's axes with the mounting `q_mag_imu`. Without a stored calibration, or with
//! `compass_enabled` = 0, no sample goes to the control step (a raw field's hard iron of up to a
//! few hundred µT would point the heading anywhere); the health report still shows the sensor.
//!
//! **The procedure** ([`CompassCalibrationCommand`]): disarmed, the user turns the craft through
//! every orientation. Every valid reading goes into the ellipsoid fit's sums (fixed memory); the
//! readings with the attitude filter's quaternion at that moment are kept as pairs for the
//! mounting, at most [`MAX_CALIBRATION_PAIRS`] of them, evenly over the whole turning (when the
//! store is full every second pair goes and the spacing doubles). The solves are slow (tens of
//! Jacobi eigen-decompositions): the link hands a copy of what was gathered to the background
//! task through [`CompassSolveSlot`] (a copy under a short lock, never a computation) and
//! [`run_compass_solve`] solves it there: a trial fit every [`TRIAL_FIT_PERIOD_US`] while
//! gathering, for the coverage the user is shown, and the final one when the user finishes:
//! `EllipsoidCalibrator` first, then `AlignmentEstimator` on the calibrated directions with
//! their attitudes. Only when both succeed is the result stored ([`CompassInput::take_solved`],
//! which the link task writes into the parameters); a refusal is reported with its reason and
//! changes nothing.
//!
//! **What it assumes of the world.** The field is the Earth's plus the craft's own iron,
//! constant while the user turns the craft (no motor running, no steel moving nearby; the fit's
//! residual refuses what is not). The attitude filter's roll and pitch are right and its yaw
//! drifts little over the turning (`flight::magnetometer`'s alignment assumes the same); its yaw
//! need not point north. The noise per axis after calibration is the fit's RMS residual.

use crate::drivers::compass::CompassState as DriverState;
use crate::drivers::compass::{
    CompassError, CompassReading, DelayUs, HealthMonitor, I2cRegisterBus,
};
use crate::drivers::{ist8310, qmc5883l};
use flight::magnetometer::{
    AlignmentError, AlignmentEstimator, CalibrationError, EllipsoidCalibrator,
};
use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};
use protocol::{
    CompassCalibrationCommand, CompassCalibrationRefusal, CompassCalibrationStatus, CompassHealth,
    CompassSensor, CompassState,
};

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use rtic_core::Mutex;

/// Time between two reads of the sensor, µs: 100 Hz, the rate both drivers configure (the
/// QMC5883L's output data rate, the IST8310's single measurements at ArduPilot's 10 ms).
pub const COMPASS_READ_PERIOD_US: u64 = 1_000_000 / ist8310::MEASUREMENT_RATE_HZ as u64;

/// Time between two probes of the bus while no sensor is found, µs (ours: a GNSS mast plugged
/// in after power-up is found within a second; a probe is three address bytes).
pub const COMPASS_PROBE_PERIOD_US: u64 = 1_000_000;

/// Length of the window the reading rate is measured over, µs.
pub const RATE_WINDOW_US: u64 = 1_000_000;

/// Noise per axis assumed before a calibration measured it, µT: the middle of the 0.3–2 µT these
/// sensors give after their own averaging (`flight::magnetometer`'s module documentation).
pub const DEFAULT_COMPASS_NOISE_UT: f32 = 1.0;

/// Smallest noise a sample states, µT: a fit's residual from a perfect turn is not a noise.
const MIN_NOISE_UT: f32 = 0.01;

/// Attitude–field pairs kept for the mounting's fit: 256 (7 KB). The fit needs 50
/// (`flight::magnetometer::MIN_ALIGNMENT_SAMPLES`); its accuracy comes from the spread of the
/// attitudes, which the even thinning keeps, not from their number.
pub const MAX_CALIBRATION_PAIRS: usize = 256;

/// How often a trial fit measures the coverage while gathering, µs (ours: the progress line a
/// person watches while turning the craft; each fit takes a few milliseconds of the background
/// task).
pub const TRIAL_FIT_PERIOD_US: u64 = 2_000_000;

/// The addresses probed and the sensor expected at each: the IST8310 at 0x0E (GNSS masts) and
/// 0x0C (its other common strapping), the QMC5883L at its fixed 0x0D.
const PROBES: [(CompassSensor, u8); 3] = [
    (CompassSensor::Ist8310, ist8310::DEFAULT_ADDRESS),
    (CompassSensor::Ist8310, 0x0C),
    (CompassSensor::Qmc5883l, qmc5883l::DEFAULT_ADDRESS),
];

pub use super::compass_heading::MagneticSample;

/// A stored compass calibration: hard iron, soft iron, mounting, noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompassCalibration {
    /// Hard-iron offset `b`, µT, sensor axes.
    pub offset_ut: [f32; 3],
    /// Soft-iron matrix `W` (symmetric), rows.
    pub soft_iron: [[f32; 3]; 3],
    /// `q_mag_imu`, unit, w x y z: rotates IMU coordinates into the sensor's.
    pub q_mag_imu: [f32; 4],
    /// Noise per axis after calibration, µT.
    pub noise_ut: f32,
}

impl CompassCalibration {
    /// A calibration from its parts: `None` when a value is not finite, the quaternion is
    /// degenerate (norm below 0.5) or the noise is not positive; the quaternion is normalised.
    pub fn new(
        offset_ut: [f32; 3],
        soft_iron: [[f32; 3]; 3],
        q_mag_imu: [f32; 4],
        noise_ut: f32,
    ) -> Option<Self> {
        let finite = offset_ut.iter().chain(soft_iron.iter().flatten()).chain(q_mag_imu.iter());
        let valid_noise = noise_ut > 0.0 && noise_ut.is_finite();
        if !(finite.into_iter().all(|x| x.is_finite()) && valid_noise) {
            return None;
        }
        let norm = flight::math::sqrt(q_mag_imu.iter().map(|x| x * x).sum::<f32>());
        // `is_nan` is excluded above (every element finite); a norm below 0.5 is degenerate.
        if norm < 0.5 {
            return None;
        }
        Some(Self { offset_ut, soft_iron, q_mag_imu: q_mag_imu.map(|x| x / norm), noise_ut })
    }

    fn rotation(&self) -> UnitQuaternion<f32> {
        let [w, x, y, z] = self.q_mag_imu;
        UnitQuaternion::new_unchecked(Quaternion::new(w, x, y, z))
    }

    /// The calibrated field in the IMU's axes, µT, from a raw one in the sensor's: `None` when
    /// it is not finite.
    pub fn apply(&self, raw_ut: &[f32; 3]) -> Option<[f32; 3]> {
        let w = Matrix3::from_fn(|i, j| self.soft_iron[i][j]);
        let field_mag = w * (Vector3::from(*raw_ut) - Vector3::from(self.offset_ut));
        let field_imu = self.rotation().inverse_transform_vector(&field_mag);
        let field: [f32; 3] = field_imu.into();
        field.iter().all(|x| x.is_finite()).then_some(field)
    }

    /// The sample for the control step from a raw field (`None`: not finite).
    pub fn sample(&self, raw_ut: &[f32; 3]) -> Option<MagneticSample> {
        let field_imu_ut = self.apply(raw_ut)?;
        let sample = MagneticSample { field_imu_ut, noise_ut: self.noise_ut.max(MIN_NOISE_UT) };
        sample.is_valid().then_some(sample)
    }
}

/// One raw field and the attitude it was seen at.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct CalibrationPair {
    raw_ut: [f32; 3],
    /// `q_world_imu`, w x y z.
    q_world_imu: [f32; 4],
}

/// What a calibration gathered: the ellipsoid fit's sums over every valid reading, and the pairs
/// kept for the mounting (evenly thinned, see the module documentation).
#[derive(Clone, Debug)]
pub struct CalibrationData {
    ellipsoid: EllipsoidCalibrator,
    pairs: [CalibrationPair; MAX_CALIBRATION_PAIRS],
    count: usize,
    /// Readings with an attitude between two kept pairs.
    stride: u32,
    /// Readings with an attitude since the last kept pair.
    since_kept: u32,
}

impl Default for CalibrationData {
    fn default() -> Self {
        Self::new()
    }
}

impl CalibrationData {
    /// Nothing gathered.
    pub const fn new() -> Self {
        Self {
            ellipsoid: EllipsoidCalibrator::new(),
            pairs: [CalibrationPair { raw_ut: [0.0; 3], q_world_imu: [0.0; 4] };
                MAX_CALIBRATION_PAIRS],
            count: 0,
            stride: 1,
            since_kept: 0,
        }
    }

    /// [`Self::new`] at `slot`, field by field (never 7 KB on a stack).
    ///
    /// # Safety
    /// `slot` is valid for writes and aligned; what it held is overwritten, not dropped.
    unsafe fn init_in(slot: *mut Self) {
        addr_of_mut!((*slot).ellipsoid).write(EllipsoidCalibrator::new());
        // Zero is a valid pair (plain numbers).
        addr_of_mut!((*slot).pairs).write_bytes(0, 1);
        addr_of_mut!((*slot).count).write(0);
        addr_of_mut!((*slot).stride).write(1);
        addr_of_mut!((*slot).since_kept).write(0);
    }

    /// Copy `other` in place (`clone_from`'s default would build the 7 KB copy on the stack
    /// first).
    fn copy_from(&mut self, other: &Self) {
        self.ellipsoid.clone_from(&other.ellipsoid);
        self.pairs.copy_from_slice(&other.pairs);
        self.count = other.count;
        self.stride = other.stride;
        self.since_kept = other.since_kept;
    }

    /// Forget everything (in place).
    fn clear(&mut self) {
        self.ellipsoid = EllipsoidCalibrator::new();
        self.count = 0;
        self.stride = 1;
        self.since_kept = 0;
    }

    /// Samples in the ellipsoid fit.
    pub fn samples(&self) -> u32 {
        self.ellipsoid.samples()
    }

    /// Pairs kept for the mounting.
    pub fn pairs(&self) -> usize {
        self.count
    }

    /// Take one raw reading, with the attitude it was seen at when there is one.
    fn add(&mut self, raw_ut: &[f32; 3], q_world_imu: Option<[f32; 4]>) {
        if !self.ellipsoid.add_sample(&Vector3::from(*raw_ut)) {
            return;
        }
        let Some(q) = q_world_imu.filter(|q| q.iter().all(|x| x.is_finite())) else { return };
        self.since_kept += 1;
        if self.since_kept < self.stride {
            return;
        }
        self.since_kept = 0;
        if self.count == MAX_CALIBRATION_PAIRS {
            // Every second pair goes: the ones kept stay evenly spread over the whole turning.
            for i in 0..MAX_CALIBRATION_PAIRS / 2 {
                self.pairs[i] = self.pairs[2 * i + 1];
            }
            self.count = MAX_CALIBRATION_PAIRS / 2;
            self.stride = self.stride.saturating_mul(2);
        }
        self.pairs[self.count] = CalibrationPair { raw_ut: *raw_ut, q_world_imu: q };
        self.count += 1;
    }

    /// The hard- and soft-iron fit's coverage (0 when the fit is refused for another reason
    /// than coverage).
    fn trial_coverage(&self) -> f32 {
        match self.ellipsoid.solve() {
            Ok(calibration) => calibration.coverage,
            Err(CalibrationError::InsufficientCoverage { coverage }) => coverage,
            Err(_) => 0.0,
        }
    }

    /// The whole fit: hard and soft iron, then the mounting on the calibrated directions.
    fn solve(&self) -> Result<SolvedCalibration, CompassCalibrationRefusal> {
        let iron = self.ellipsoid.solve().map_err(|error| match error {
            CalibrationError::TooFewSamples { samples } => {
                CompassCalibrationRefusal::TooFewSamples { samples }
            }
            CalibrationError::NotAnEllipsoid => CompassCalibrationRefusal::NotAnEllipsoid,
            CalibrationError::InsufficientCoverage { coverage } => {
                CompassCalibrationRefusal::InsufficientCoverage { coverage_pct: percent(coverage) }
            }
            CalibrationError::ResidualTooLarge { residual_ut, field_strength_ut } => {
                CompassCalibrationRefusal::ResidualTooLarge {
                    residual_ut,
                    field_ut: field_strength_ut,
                }
            }
        })?;
        let mut alignment = AlignmentEstimator::new();
        for pair in &self.pairs[..self.count] {
            let [w, x, y, z] = pair.q_world_imu;
            let q = UnitQuaternion::new_normalize(Quaternion::new(w, x, y, z));
            alignment.add(&iron.apply(&Vector3::from(pair.raw_ut)), &q);
        }
        let mounting = alignment.solve().map_err(|error| match error {
            AlignmentError::TooFewSamples { samples } => {
                CompassCalibrationRefusal::TooFewAttitudes { samples }
            }
            AlignmentError::Unobservable { observability } => {
                CompassCalibrationRefusal::NotTurnedAboutTwoAxes { observability }
            }
            AlignmentError::Numerical => CompassCalibrationRefusal::Numerical,
        })?;
        let q = mounting.q_mag_imu.into_inner();
        let calibration = CompassCalibration::new(
            iron.offset_ut.into(),
            core::array::from_fn(|i| core::array::from_fn(|j| iron.soft_iron[(i, j)])),
            [q.w, q.i, q.j, q.k],
            iron.residual_ut.max(MIN_NOISE_UT),
        )
        .ok_or(CompassCalibrationRefusal::Numerical)?;
        Ok(SolvedCalibration {
            calibration,
            field_ut: iron.field_strength_ut,
            residual_ut: iron.residual_ut,
            coverage: iron.coverage,
            mounting_std_rad: mounting.std_rad,
        })
    }
}

/// Per cent of a fraction, rounded, 0–100.
fn percent(fraction: f32) -> u8 {
    if fraction.is_finite() {
        libm::roundf(fraction.clamp(0.0, 1.0) * 100.0) as u8
    } else {
        0
    }
}

/// A calibration solved from what was gathered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolvedCalibration {
    pub calibration: CompassCalibration,
    /// Field strength of the fit, µT.
    pub field_ut: f32,
    /// RMS residual of the fit, µT.
    pub residual_ut: f32,
    /// Coverage of the sphere (`flight::magnetometer::Calibration::coverage`).
    pub coverage: f32,
    /// The mounting's standard deviation about its worst axis, rad.
    pub mounting_std_rad: f32,
}

/// Which solve the link asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SolveKind {
    /// The hard- and soft-iron fit alone, for its coverage (progress).
    Trial,
    /// The whole calibration.
    Final,
}

/// What a solve gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SolveOutcome {
    Trial { coverage: f32 },
    Final(Result<SolvedCalibration, CompassCalibrationRefusal>),
}

impl SolveOutcome {
    /// The kind of solve it answers.
    pub fn kind(&self) -> SolveKind {
        match self {
            Self::Trial { .. } => SolveKind::Trial,
            Self::Final(_) => SolveKind::Final,
        }
    }
}

/// The handoff between the link task (which gathers) and the background task (which solves):
/// what was gathered, copied in with a request; the outcome, copied back. Locked for a copy
/// only. On the board an RTIC shared resource of its own (15 KB, a static); in a
/// [`super::system::System`] a field.
#[derive(Clone, Debug, Default)]
pub struct CompassSolveSlot {
    request: Option<SolveKind>,
    data: CalibrationData,
    outcome: Option<SolveOutcome>,
}

impl CompassSolveSlot {
    /// Nothing asked, nothing solved.
    pub const fn new() -> Self {
        Self { request: None, data: CalibrationData::new(), outcome: None }
    }

    /// [`Self::new`] in place (the board's static).
    #[inline(never)]
    pub fn build_in(slot: &mut MaybeUninit<Self>) -> &mut Self {
        let p = slot.as_mut_ptr();
        // SAFETY: every field is written through raw field pointers before the reference is
        // formed.
        unsafe {
            addr_of_mut!((*p).request).write(None);
            addr_of_mut!((*p).outcome).write(None);
            CalibrationData::init_in(addr_of_mut!((*p).data));
            slot.assume_init_mut()
        }
    }

    /// Whether a solve waits for the background task.
    pub fn pending(&self) -> bool {
        self.request.is_some()
    }
}

/// The background task's side of the solves: its own copy of the data (solved outside the lock).
#[derive(Clone, Debug, Default)]
pub struct CompassSolver {
    data: CalibrationData,
}

impl CompassSolver {
    pub const fn new() -> Self {
        Self { data: CalibrationData::new() }
    }

    /// [`Self::new`] in place (the board's static).
    #[inline(never)]
    pub fn build_in(slot: &mut MaybeUninit<Self>) -> &mut Self {
        // SAFETY: the one field is written through its raw pointer before the reference is
        // formed.
        unsafe {
            CalibrationData::init_in(addr_of_mut!((*slot.as_mut_ptr()).data));
            slot.assume_init_mut()
        }
    }
}

/// Solve what waits in `slot`, if anything (the background task, after its other work): the
/// data copied out under the lock, solved outside it, the outcome copied back.
pub fn run_compass_solve<S: Mutex<T = CompassSolveSlot>>(solver: &mut CompassSolver, slot: &mut S) {
    let data = &mut solver.data;
    let Some(kind) = slot.lock(|slot| {
        let kind = slot.request.take()?;
        data.copy_from(&slot.data);
        Some(kind)
    }) else {
        return;
    };
    let outcome = match kind {
        SolveKind::Trial => SolveOutcome::Trial { coverage: data.trial_coverage() },
        SolveKind::Final => SolveOutcome::Final(data.solve()),
    };
    slot.lock(|slot| slot.outcome = Some(outcome));
}

/// The sensor found, and its health monitor (carried between the reads: the driver is built
/// around the borrowed bus for each one).
#[derive(Clone, Copy, Debug)]
struct Found {
    sensor: CompassSensor,
    address: u8,
    monitor: HealthMonitor,
}

/// The compass service (see the module documentation): its state, and the calibration's store
/// beside it (7 KB, built in place on the board: [`CompassInput::build_in`]).
#[derive(Clone, Debug)]
pub struct CompassInput {
    s: Service,
    /// What the calibration gathers (kept in place: never moved or copied whole on a stack).
    data: CalibrationData,
}

/// The service's state but the calibration's store (small, built by value).
#[derive(Clone, Debug)]
struct Service {
    found: Option<Found>,
    /// The state reported (the monitor's while a sensor is found; `Lost` after a loss until
    /// one is found again).
    state: CompassState,
    next_probe_us: u64,
    next_read_us: u64,
    calibration: Option<CompassCalibration>,
    enabled: bool,
    /// The attitude filter's latest `q_world_imu` (set by the link task before each service).
    attitude: Option<[f32; 4]>,
    window_start_us: Option<u64>,
    window_readings: u32,
    rate_hz: f32,
    field_ut: f32,
    health: CompassHealth,
    /// Counters of the sensors lost before (the monitor starts afresh with each sensor found).
    past: (u32, u32, u32),
    /// Whether the calibration is gathering now.
    gathering: bool,
    /// When the next trial fit is due while gathering, µs.
    next_trial_us: u64,
    /// A solve asked of the background task and not yet answered.
    solving: Option<SolveKind>,
    calibration_status: CompassCalibrationStatus,
    solved: Option<SolvedCalibration>,
}

impl Service {
    const fn new() -> Self {
        Self {
            found: None,
            state: CompassState::Absent,
            next_probe_us: 0,
            next_read_us: 0,
            calibration: None,
            enabled: true,
            attitude: None,
            window_start_us: None,
            window_readings: 0,
            rate_hz: 0.0,
            field_ut: f32::NAN,
            health: CompassHealth {
                sensor: CompassSensor::None,
                address: 0,
                state: CompassState::Absent,
                enabled: true,
                calibrated: false,
                rate_hz: 0.0,
                field_ut: f32::NAN,
                readings: 0,
                failures: 0,
                overflows: 0,
                lost: 0,
                stuck: 0,
                saturated: 0,
                samples_sent: 0,
                calibration: CompassCalibrationStatus::Idle,
            },
            past: (0, 0, 0),
            gathering: false,
            next_trial_us: 0,
            solving: None,
            calibration_status: CompassCalibrationStatus::Idle,
            solved: None,
        }
    }
}

impl Default for CompassInput {
    fn default() -> Self {
        Self::new()
    }
}

impl CompassInput {
    /// Nothing found yet; the first service probes the bus.
    pub const fn new() -> Self {
        Self { s: Service::new(), data: CalibrationData::new() }
    }

    /// [`Self::new`] in place, field by field (the board's static: the 7 KB store is never
    /// built on `init`'s stack and moved).
    #[inline(never)]
    pub fn build_in(slot: &mut MaybeUninit<Self>) -> &mut Self {
        let input = slot.as_mut_ptr();
        // SAFETY: both fields are written through raw field pointers before the reference is
        // formed.
        unsafe {
            addr_of_mut!((*input).s).write(Service::new());
            CalibrationData::init_in(addr_of_mut!((*input).data));
            slot.assume_init_mut()
        }
    }

    /// Take the parameters: the stored calibration (`None`: not calibrated) and whether the
    /// samples go to the control step.
    pub fn configure(&mut self, calibration: Option<CompassCalibration>, enabled: bool) {
        self.s.calibration = calibration;
        self.s.enabled = enabled;
    }

    /// The attitude filter's latest `q_world_imu` (w x y z), for the calibration's pairs.
    pub fn set_attitude(&mut self, q_world_imu: Option<[f32; 4]>) {
        self.s.attitude = q_world_imu;
    }

    /// The craft is armed (the control step's snapshot): a calibration gathering ends, refused
    /// (spinning motors' currents would be fitted as iron).
    pub fn set_armed(&mut self, armed: bool) {
        if armed && core::mem::take(&mut self.s.gathering) {
            self.s.solving = None;
            self.s.calibration_status =
                CompassCalibrationStatus::Refused(CompassCalibrationRefusal::Armed);
        }
    }

    /// One service at `now_us` (µs, monotonic): probe when no sensor is found and a probe is
    /// due, read when a reading is due; a calibrated field comes back for the control step.
    /// Bounded: at most three identity reads, or one initialisation (its delays through
    /// `delay`), or one read.
    pub fn service<B: I2cRegisterBus, D: DelayUs>(
        &mut self,
        now_us: u64,
        bus: &mut B,
        delay: &mut D,
    ) -> Option<MagneticSample> {
        self.measure_rate(now_us);
        let Some(found) = self.s.found else {
            if now_us >= self.s.next_probe_us {
                self.s.next_probe_us = now_us + COMPASS_PROBE_PERIOD_US;
                self.probe(now_us, bus, delay);
            }
            return None;
        };
        if now_us < self.s.next_read_us {
            return None;
        }
        self.s.next_read_us =
            self.s.next_read_us.saturating_add(COMPASS_READ_PERIOD_US).max(now_us);
        let (result, monitor) = read(&found, bus);
        self.s.found = Some(Found { monitor, ..found });
        self.after_read(&result, monitor.health().state)
    }

    /// Identity reads at the three addresses; the first that answers as its sensor is
    /// initialised.
    fn probe<B: I2cRegisterBus, D: DelayUs>(&mut self, now_us: u64, bus: &mut B, delay: &mut D) {
        for (sensor, address) in PROBES {
            let (register, expected) = match sensor {
                CompassSensor::Qmc5883l => (qmc5883l::reg::CHIP_ID, qmc5883l::CHIP_ID_VALUE),
                _ => (ist8310::reg::WAI, ist8310::WAI_VALUE),
            };
            if bus.read_one(address, register).ok() != Some(expected) {
                continue;
            }
            let initialised = match sensor {
                CompassSensor::Qmc5883l => {
                    qmc5883l::Qmc5883l::new(&mut *bus, address).init(delay).is_ok()
                }
                _ => ist8310::Ist8310::new(&mut *bus, address).init(delay).is_ok(),
            };
            if initialised {
                self.s.found = Some(Found { sensor, address, monitor: HealthMonitor::new() });
                self.s.state = CompassState::Starting;
                self.s.next_read_us = now_us + COMPASS_READ_PERIOD_US;
                return;
            }
        }
    }

    fn measure_rate(&mut self, now_us: u64) {
        let start = *self.s.window_start_us.get_or_insert(now_us);
        let elapsed_us = now_us.saturating_sub(start);
        if elapsed_us >= RATE_WINDOW_US {
            self.s.rate_hz = self.s.window_readings as f32 * 1e6 / elapsed_us as f32;
            self.s.window_readings = 0;
            self.s.window_start_us = Some(now_us);
        }
    }

    /// Count a read's result and its health, feed a calibration in progress, and make the
    /// sample.
    fn after_read<E>(
        &mut self,
        result: &Result<CompassReading, CompassError<E>>,
        driver_state: DriverState,
    ) -> Option<MagneticSample> {
        let state = match driver_state {
            DriverState::Starting => CompassState::Starting,
            DriverState::Healthy => CompassState::Healthy,
            DriverState::Lost => CompassState::Lost,
            DriverState::Stuck => CompassState::Stuck,
            DriverState::Saturated => CompassState::Saturated,
        };
        if state != self.s.state {
            let counter = match state {
                CompassState::Lost => Some(&mut self.s.health.lost),
                CompassState::Stuck => Some(&mut self.s.health.stuck),
                CompassState::Saturated => Some(&mut self.s.health.saturated),
                _ => None,
            };
            if let Some(counter) = counter {
                *counter = counter.saturating_add(1);
            }
            self.s.state = state;
        }
        if state == CompassState::Lost {
            // Dropped: probed for again (a mast plugged back in is initialised afresh).
            if let Some(found) = self.s.found.take() {
                let h = found.monitor.health();
                self.s.past = (
                    self.s.past.0.saturating_add(h.readings),
                    self.s.past.1.saturating_add(h.failures),
                    self.s.past.2.saturating_add(h.overflows),
                );
            }
            if core::mem::take(&mut self.s.gathering) || self.s.solving == Some(SolveKind::Trial) {
                self.s.solving = None;
                self.s.calibration_status =
                    CompassCalibrationStatus::Refused(CompassCalibrationRefusal::SensorLost);
            }
            return None;
        }
        let Ok(reading) = result else { return None };
        if state != CompassState::Healthy {
            return None;
        }
        self.s.window_readings = self.s.window_readings.saturating_add(1);
        if self.s.gathering {
            self.data.add(&reading.field_ut, self.s.attitude);
        }
        let calibrated = self.s.calibration.and_then(|c| c.apply(&reading.field_ut));
        let field = calibrated.unwrap_or(reading.field_ut);
        self.s.field_ut = flight::math::sqrt(field.iter().map(|x| x * x).sum::<f32>());
        let sample = self.s.calibration.and_then(|c| c.sample(&reading.field_ut))?;
        if !self.s.enabled {
            return None;
        }
        self.s.health.samples_sent = self.s.health.samples_sent.wrapping_add(1);
        Some(sample)
    }

    /// Carry out a calibration command (the link checked it: [`Self::check_command`]).
    pub fn command(&mut self, command: CompassCalibrationCommand, now_us: u64) {
        match command {
            CompassCalibrationCommand::Start => {
                self.data.clear();
                self.s.gathering = true;
                self.s.solving = None;
                self.s.solved = None;
                self.s.next_trial_us = now_us + TRIAL_FIT_PERIOD_US;
                self.s.calibration_status =
                    CompassCalibrationStatus::Gathering { samples: 0, coverage_pct: 0 };
            }
            CompassCalibrationCommand::Finish => {
                if self.s.gathering {
                    self.s.calibration_status =
                        CompassCalibrationStatus::Solving { samples: self.data.samples() };
                }
            }
            CompassCalibrationCommand::Cancel => {
                self.s.gathering = false;
                self.s.solving = None;
                self.s.calibration_status = CompassCalibrationStatus::Idle;
            }
        }
    }

    /// Whether `command` can be carried out now (`armed`: anything armed): the link's answer.
    pub fn check_command(
        health: &CompassHealth,
        command: CompassCalibrationCommand,
        armed: bool,
    ) -> Result<(), protocol::DeviceError> {
        use protocol::DeviceError;
        match command {
            CompassCalibrationCommand::Start if armed => Err(DeviceError::RefusedWhileArmed),
            CompassCalibrationCommand::Start => {
                matches!(health.state, CompassState::Starting | CompassState::Healthy)
                    .then_some(())
                    .ok_or(DeviceError::NotReady)
            }
            CompassCalibrationCommand::Finish => {
                matches!(health.calibration, CompassCalibrationStatus::Gathering { .. })
                    .then_some(())
                    .ok_or(DeviceError::NotReady)
            }
            CompassCalibrationCommand::Cancel => Ok(()),
        }
    }

    /// The link task's exchange with the background task after a service: an outcome taken,
    /// a solve asked for when one is due. Returns whether a solve now waits (the board runs
    /// the background task).
    pub fn exchange<S: Mutex<T = CompassSolveSlot>>(&mut self, now_us: u64, slot: &mut S) -> bool {
        // Only the outcome of the solve asked for last: a trial the background task finished
        // after the final one was asked for (the final request replaced it in the slot, its
        // outcome came after) is dropped.
        let outcome = match self.s.solving {
            Some(kind) => slot.lock(|s| match s.outcome.take() {
                Some(outcome) if outcome.kind() == kind => Some(outcome),
                _ => None,
            }),
            None => None,
        };
        match outcome {
            Some(SolveOutcome::Trial { coverage }) => {
                self.s.solving = None;
                if let CompassCalibrationStatus::Gathering { coverage_pct, .. } =
                    &mut self.s.calibration_status
                {
                    *coverage_pct = percent(coverage);
                }
            }
            Some(SolveOutcome::Final(result)) => {
                self.s.solving = None;
                self.s.calibration_status = match result {
                    Ok(solved) => {
                        self.s.solved = Some(solved);
                        CompassCalibrationStatus::Stored {
                            residual_ut: solved.residual_ut,
                            field_ut: solved.field_ut,
                            coverage_pct: percent(solved.coverage),
                            mounting_std_deg: solved.mounting_std_rad.to_degrees(),
                        }
                    }
                    Err(refusal) => CompassCalibrationStatus::Refused(refusal),
                };
            }
            None => {}
        }
        if let CompassCalibrationStatus::Gathering { samples, .. } = &mut self.s.calibration_status
        {
            *samples = self.data.samples();
        }
        let kind = match self.s.calibration_status {
            CompassCalibrationStatus::Solving { .. }
                if self.s.solving != Some(SolveKind::Final) =>
            {
                SolveKind::Final
            }
            CompassCalibrationStatus::Gathering { .. }
                if self.s.solving.is_none() && now_us >= self.s.next_trial_us =>
            {
                self.s.next_trial_us = now_us + TRIAL_FIT_PERIOD_US;
                SolveKind::Trial
            }
            _ => return false,
        };
        if !self.s.gathering {
            return false;
        }
        let data = &self.data;
        slot.lock(|s| {
            s.data.copy_from(data);
            s.request = Some(kind);
            s.outcome = None;
        });
        if kind == SolveKind::Final {
            self.s.gathering = false;
        }
        self.s.solving = Some(kind);
        true
    }

    /// A calibration solved and not yet stored: the link task stores it in the parameters
    /// (once).
    pub fn take_solved(&mut self) -> Option<SolvedCalibration> {
        self.s.solved.take()
    }

    /// The report for `doctor` and `compass calibrate` (protocol `GetCompass`).
    pub fn health(&self) -> CompassHealth {
        let h = self.s.found.map(|f| f.monitor.health());
        CompassHealth {
            sensor: self.s.found.map_or(CompassSensor::None, |f| f.sensor),
            address: self.s.found.map_or(0, |f| f.address),
            state: self.s.state,
            enabled: self.s.enabled,
            calibrated: self.s.calibration.is_some(),
            rate_hz: if self.s.found.is_some() { self.s.rate_hz } else { 0.0 },
            field_ut: self.s.field_ut,
            readings: self.s.past.0.saturating_add(h.map_or(0, |h| h.readings)),
            failures: self.s.past.1.saturating_add(h.map_or(0, |h| h.failures)),
            overflows: self.s.past.2.saturating_add(h.map_or(0, |h| h.overflows)),
            calibration: self.s.calibration_status,
            ..self.s.health
        }
    }
}

/// One read of the sensor `found` through `bus`: the result and the monitor after it.
fn read<B: I2cRegisterBus>(
    found: &Found,
    bus: &mut B,
) -> (Result<CompassReading, CompassError<B::Error>>, HealthMonitor) {
    match found.sensor {
        CompassSensor::Qmc5883l => {
            let mut sensor = qmc5883l::Qmc5883l::resume(&mut *bus, found.address, found.monitor);
            let result = sensor.read();
            (result, sensor.monitor())
        }
        _ => {
            let mut sensor = ist8310::Ist8310::resume(&mut *bus, found.address, found.monitor);
            let result = sensor.read();
            (result, sensor.monitor())
        }
    }
}

#[cfg(test)]
mod tests;
