//! A simulated GNSS receiver: what a u-blox receiver on the craft reports of its true position
//! and velocity, as NAV-PVT solutions ([`GnssFix`]) and as the UBX bytes the board's driver
//! ([`firmware::drivers::ubx`]) parses, so that the SITL can feed the real parser.
//!
//! # Error model
//!
//! Per axis (north, east, down), the position error is the sum of
//! - a first-order Gauss–Markov process (the slowly wandering error of a GNSS solution:
//!   atmosphere, orbits, clocks): `x(k+1) = φ x(k) + σ √(1 − φ²) w(k)`, `φ = exp(−Δt/τ)`,
//!   stationary standard deviation `σ` and correlation time `τ` (autocorrelation `σ² e^{−|t|/τ}`);
//!   the horizontal axes have [`GnssModelConfig::horizontal_sigma_m`], the vertical
//!   [`GnssModelConfig::vertical_sigma_m`];
//! - white noise per solution ([`GnssModelConfig::white_noise_m`], the vertical scaled as the
//!   correlated part is);
//! - multipath: jumps starting as a Poisson process ([`GnssModelConfig::multipath_per_s`]), each
//!   a constant offset (horizontal direction uniform, magnitude normal with
//!   [`GnssModelConfig::multipath_jump_m`] per horizontal axis, half that vertically) held for
//!   [`GnssModelConfig::multipath_s`] seconds.
//!
//! The velocity error is white, [`GnssModelConfig::velocity_noise_mps`] per axis (a receiver's
//! Doppler velocity has no slow wander of its own).
//!
//! The accuracies the receiver reports describe its Gaussian errors, not the multipath it does
//! not know about (as a real receiver's do not): `hAcc = √(σ²_N + σ²_E)` (the horizontal error's
//! RMS), `vAcc` the vertical standard deviation, `sAcc = √3 σ_v` (the 3D velocity error's RMS).
//!
//! # Timing
//!
//! Solutions are computed at measurement epochs on a grid of `1/rate_hz` in GPS time (as a
//! u-blox receiver aligns them), from the truth at the first update at or after the epoch, and
//! arrive `latency_s` later (the receiver's computation and the UART). During a dropout
//! (Poisson starts, [`GnssModelConfig::dropout_s`] long; under a bridge, between buildings) the
//! receiver keeps sending NAV-PVT, but without a fix (`fixType` 0, `gnssFixOK` clear).
//!
//! # Geodesy
//!
//! Positions are north-east-down metres about a home point; [`Home`] converts them to WGS-84
//! latitude, longitude and ellipsoidal height with the local radii of curvature at the home point
//! (meridian `M` and prime vertical `N`) and no curvature of the plane ("flat earth"): `lat =
//! lat₀ + n/(M + h₀)`, `lon = lon₀ + e/((N + h₀) cos lat₀)`, `h = h₀ − d`. Its error against
//! exact geodesy grows as the square of the distance: about 1 cm of horizontal scale at 10 km
//! from home, so fine over the kilometres a multirotor flies; heights follow the ellipsoid, not
//! the tangent plane (8 cm apart at 1 km, which is what a barometer and GNSS see too).

use firmware::drivers::ubx::{FixType, GnssFix};
use nalgebra::Vector3;

use crate::recovery::{FlyReport, Verdict};
use crate::rng::Rng;

/// WGS-84 semi-major axis, m (NIMA TR8350.2, table 3.1).
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS-84 flattening (NIMA TR8350.2, table 3.1).
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// GPS time of week at simulated time 0, s (any value: Wednesday noon).
pub const TOW_AT_START_S: f64 = 3.5 * 86_400.0;
/// Milliseconds in a GPS week (the time of week wraps there).
const MS_PER_WEEK: u64 = 7 * 86_400 * 1_000;

/// A home point and the local north-east-down ↔ WGS-84 conversion about it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Home {
    /// Latitude, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees.
    pub longitude_deg: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub height_ellipsoid_m: f64,
    /// Geoid undulation (ellipsoid height minus height above mean sea level), m.
    pub geoid_undulation_m: f64,
}

impl Default for Home {
    /// Zürich, near the ETH's flying hall: 47.3769° N, 8.5417° E, 408 m above sea level, geoid
    /// 48 m above the ellipsoid (EGM96 there).
    fn default() -> Self {
        Self {
            latitude_deg: 47.3769,
            longitude_deg: 8.5417,
            height_ellipsoid_m: 456.0,
            geoid_undulation_m: 48.0,
        }
    }
}

/// Latitude, longitude and ellipsoidal height of one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geodetic {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub height_ellipsoid_m: f64,
}

impl Home {
    /// The radii of curvature at the home point, m: meridian `M = a(1−e²)/(1−e² sin²φ)^{3/2}` and
    /// prime vertical `N = a/√(1−e² sin²φ)`.
    pub fn radii_m(&self) -> (f64, f64) {
        let e2 = WGS84_F * (2.0 - WGS84_F);
        let s = self.latitude_deg.to_radians().sin();
        let w = 1.0 - e2 * s * s;
        (WGS84_A_M * (1.0 - e2) / (w * w.sqrt()), WGS84_A_M / w.sqrt())
    }

    /// North-east-down metres from home → latitude, longitude, ellipsoidal height.
    pub fn to_geodetic(&self, ned_m: &Vector3<f64>) -> Geodetic {
        let (m, n) = self.radii_m();
        let h0 = self.height_ellipsoid_m;
        Geodetic {
            latitude_deg: self.latitude_deg + (ned_m.x / (m + h0)).to_degrees(),
            longitude_deg: self.longitude_deg
                + (ned_m.y / ((n + h0) * self.latitude_deg.to_radians().cos())).to_degrees(),
            height_ellipsoid_m: h0 - ned_m.z,
        }
    }

    /// Latitude, longitude, ellipsoidal height → north-east-down metres from home.
    pub fn to_ned(&self, point: &Geodetic) -> Vector3<f64> {
        let (m, n) = self.radii_m();
        let h0 = self.height_ellipsoid_m;
        Vector3::new(
            (point.latitude_deg - self.latitude_deg).to_radians() * (m + h0),
            (point.longitude_deg - self.longitude_deg).to_radians()
                * (n + h0)
                * self.latitude_deg.to_radians().cos(),
            h0 - point.height_ellipsoid_m,
        )
    }

    /// The position of a fix, north-east-down metres from home.
    pub fn fix_to_ned(&self, fix: &GnssFix) -> Vector3<f64> {
        self.to_ned(&Geodetic {
            latitude_deg: fix.latitude_deg,
            longitude_deg: fix.longitude_deg,
            height_ellipsoid_m: f64::from(fix.height_ellipsoid_m),
        })
    }
}

/// The control's own share of [`GnssModelConfig::hold_bound_m`], m: the hold bound with motion
/// capture (`crate::recovery::HOLD_BOUND_M`, the issue's 0.3 m), where the poses' millimetres
/// leave only the control's error.
pub const HOLD_CONTROL_ALLOWANCE_M: f64 = crate::recovery::HOLD_BOUND_M;

/// The fixes' share of [`GnssModelConfig::hold_bound_m`], in multiples of hAcc: 2 hAcc is the
/// "2DRMS" of GNSS accuracy statements; a 2D Gaussian error is within twice its RMS
/// `1 − e⁻⁴` = 98 % of the time (the radius of a circular Gaussian is Rayleigh-distributed).
pub const HOLD_FIX_RMS_MULTIPLE: f64 = 2.0;

/// The range of the correlated horizontal error per axis that [`GnssModelConfig::random`] draws
/// from (log-uniform), m: the issue's 0.02–2 m, an RTK-like receiver to a single-frequency one
/// under a partial sky.
pub const RANDOM_NOISE_M: (f64, f64) = (0.02, 2.0);

/// The range of the velocity noise per axis that [`GnssModelConfig::random`] draws from
/// (uniform), m/s: sAcc of 0.035–0.35 m/s, what u-blox M8–M10 receivers report moving in the
/// open and under a partial sky.
pub const RANDOM_VELOCITY_NOISE_MPS: (f64, f64) = (0.02, 0.2);

/// The simulated receiver's behaviour. Ranges are checked by [`GnssModelConfig::validate`].
#[derive(Clone, Debug, PartialEq)]
pub struct GnssModelConfig {
    /// Solutions per second, Hz (1 to 25; u-blox receivers: 5 to 10 with several constellations).
    pub rate_hz: f64,
    /// Time from a measurement epoch to the solution's arrival at the board, s (0 to 0.5).
    pub latency_s: f64,
    /// Standard deviation of the correlated error per horizontal axis, m (0 to 10).
    pub horizontal_sigma_m: f64,
    /// Standard deviation of the correlated vertical error, m (0 to 20).
    pub vertical_sigma_m: f64,
    /// Correlation time of the correlated error, s (0.1 to 3,600).
    pub correlation_time_s: f64,
    /// White noise per solution per horizontal axis, m (0 to 5; vertically scaled as the
    /// correlated part).
    pub white_noise_m: f64,
    /// Velocity noise per axis, m/s (0 to 5).
    pub velocity_noise_mps: f64,
    /// Multipath jumps per second (Poisson; 0: never).
    pub multipath_per_s: f64,
    /// Standard deviation of a jump per horizontal axis, m (0 to 50).
    pub multipath_jump_m: f64,
    /// How long a jump lasts, s (0 to 60).
    pub multipath_s: f64,
    /// Dropouts (no fix) per second (Poisson; 0: never).
    pub dropouts_per_s: f64,
    /// How long a dropout lasts, s (0 to 600).
    pub dropout_s: f64,
    /// Satellites used in a fix (4 to 60).
    pub satellites: u8,
    /// The home point: where north-east-down 0 is.
    pub home: Home,
}

impl Default for GnssModelConfig {
    /// A u-blox M10 in the open: 5 Hz, 0.1 s late, 0.5 m correlated over 20 s horizontally
    /// (1 m vertically), 5 cm white, 5 cm/s velocity noise, no multipath or dropouts.
    fn default() -> Self {
        Self {
            rate_hz: 5.0,
            latency_s: 0.1,
            horizontal_sigma_m: 0.5,
            vertical_sigma_m: 1.0,
            correlation_time_s: 20.0,
            white_noise_m: 0.05,
            velocity_noise_mps: 0.05,
            multipath_per_s: 0.0,
            multipath_jump_m: 3.0,
            multipath_s: 5.0,
            dropouts_per_s: 0.0,
            dropout_s: 2.0,
            satellites: 16,
            home: Home::default(),
        }
    }
}

impl GnssModelConfig {
    /// Check every field against its documented range; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        let check = |name: &str, value: f64, min: f64, max: f64| {
            if value.is_finite() && value >= min && value <= max {
                Ok(())
            } else {
                Err(format!("GNSS: {name} = {value} is outside {min}..={max}"))
            }
        };
        check("rate_hz", self.rate_hz, 1.0, 25.0)?;
        check("latency_s", self.latency_s, 0.0, 0.5)?;
        check("horizontal_sigma_m", self.horizontal_sigma_m, 0.0, 10.0)?;
        check("vertical_sigma_m", self.vertical_sigma_m, 0.0, 20.0)?;
        check("correlation_time_s", self.correlation_time_s, 0.1, 3_600.0)?;
        check("white_noise_m", self.white_noise_m, 0.0, 5.0)?;
        check("velocity_noise_mps", self.velocity_noise_mps, 0.0, 5.0)?;
        check("multipath_per_s", self.multipath_per_s, 0.0, 10.0)?;
        check("multipath_jump_m", self.multipath_jump_m, 0.0, 50.0)?;
        check("multipath_s", self.multipath_s, 0.0, 60.0)?;
        check("dropouts_per_s", self.dropouts_per_s, 0.0, 10.0)?;
        check("dropout_s", self.dropout_s, 0.0, 600.0)?;
        check("satellites", f64::from(self.satellites), 4.0, 60.0)?;
        check("home latitude_deg", self.home.latitude_deg, -89.0, 89.0)?;
        check("home longitude_deg", self.home.longitude_deg, -180.0, 180.0)
    }

    /// A receiver drawn from the issue's randomised world: noise 0.02–2 m (log-uniform)
    /// correlated over 2–60 s, vertical 1.5–2.5× horizontal, velocity noise 0.02–0.2 m/s per
    /// axis, 5–10 Hz, 50–150 ms late, multipath
    /// jumps of 1–5 m for 1–10 s at up to one a minute, and in half the draws dropouts of 0.5–5 s
    /// at up to one every 100 s.
    pub fn random(rng: &mut Rng) -> Self {
        let (quietest, noisiest) = RANDOM_NOISE_M;
        let sigma = rng.range(quietest.ln(), noisiest.ln()).exp();
        let dropping = rng.uniform() < 0.5;
        Self {
            rate_hz: rng.range(5.0, 10.0),
            latency_s: rng.range(0.05, 0.15),
            horizontal_sigma_m: sigma,
            vertical_sigma_m: sigma * rng.range(1.5, 2.5),
            correlation_time_s: rng.range(2.0, 60.0),
            white_noise_m: sigma * rng.range(0.05, 0.3),
            velocity_noise_mps: rng.range(RANDOM_VELOCITY_NOISE_MPS.0, RANDOM_VELOCITY_NOISE_MPS.1),
            multipath_per_s: rng.range(0.0, 1.0 / 60.0),
            multipath_jump_m: rng.range(1.0, 5.0),
            multipath_s: rng.range(1.0, 10.0),
            dropouts_per_s: if dropping { rng.range(0.0, 0.01) } else { 0.0 },
            dropout_s: rng.range(0.5, 5.0),
            satellites: rng.range(8.0, 25.0) as u8,
            home: Home::default(),
        }
    }

    /// The accuracies this receiver reports with a fix (the module doc's "Error model"): hAcc,
    /// the horizontal error's RMS, m; vAcc, the vertical standard deviation, m; sAcc, the 3D
    /// velocity error's RMS, m/s. Multipath is in none of them.
    pub fn reported_accuracies(&self) -> (f64, f64, f64) {
        let v = self.vertical_scale();
        let per_axis = (self.horizontal_sigma_m.powi(2) + self.white_noise_m.powi(2)).sqrt();
        (
            per_axis * 2f64.sqrt(),
            (self.vertical_sigma_m.powi(2) + (self.white_noise_m * v).powi(2)).sqrt(),
            self.velocity_noise_mps * 3f64.sqrt(),
        )
    }

    /// How far from its position setpoint a craft holding on this receiver may be horizontally
    /// and still count as holding, m: [`HOLD_CONTROL_ALLOWANCE_M`] for the control's own error
    /// plus [`HOLD_FIX_RMS_MULTIPLE`] times hAcc for the fixes'. A craft that holds on fixes
    /// holds the fixes' error: its true distance from the setpoint is, but for the control's
    /// error, the current fix's error (multipath aside), whose horizontal RMS is hAcc. 0.3 m +
    /// 2 hAcc: 1.16 m for the 0.3 m receiver of `fly --gnss` (the issue's "within 1 m"), 0.36 m
    /// for a 2 cm (RTK-like) one, about 6 m for a 2 m one.
    pub fn hold_bound_m(&self) -> f64 {
        HOLD_CONTROL_ALLOWANCE_M + HOLD_FIX_RMS_MULTIPLE * self.reported_accuracies().0
    }

    /// Whether a flight on this receiver held its position: it hovered
    /// ([`Verdict::Held`] or [`Verdict::HoveredLoose`]), and its worst horizontal distance from
    /// the setpoint over the hold window (the part of it flown in position hold, as for
    /// [`Verdict::Held`]: a hold begins once the recovery has stopped and the heading is learned)
    /// is within [`GnssModelConfig::hold_bound_m`]. Vertically a receiver is 1.5–2.5 times
    /// worse, and no bound is drawn there. Multipath is in no receiver's hAcc: a jump the craft
    /// follows (the estimator takes it after refusing it for 5 s) fails the bound.
    pub fn held(&self, report: &FlyReport) -> bool {
        matches!(Verdict::of(report), Verdict::Held | Verdict::HoveredLoose)
            && report.max_hold_error_horizontal_m.is_some_and(|e| e <= self.hold_bound_m())
    }

    /// The ratio of the vertical error to the horizontal (1 when both are 0).
    fn vertical_scale(&self) -> f64 {
        if self.horizontal_sigma_m > 0.0 {
            self.vertical_sigma_m / self.horizontal_sigma_m
        } else {
            1.0
        }
    }
}

/// The board's side of a GNSS receiver: the firmware's own receiver code
/// (`firmware::app::gnss::GnssInput`, told the receiver's latency and rate as a user would set
/// them) behind the board's GNSS UART, fed the bytes a receiver sent. The simulated receivers
/// stream whatever they are sent, so the firmware's configuration is taken as written. Shared by
/// [`GnssFeed`] (`fly --gnss`, `sitl --gnss`) and the bridge's GNSS block
/// (`crate::bridge::GnssSolution`), so both go through the same parser and the same
/// solution-to-fix code as a board.
#[derive(Clone, Debug)]
pub struct BoardGnss {
    input: firmware::app::gnss::GnssInput,
}

impl BoardGnss {
    /// The firmware's receiver code, configuring the receiver with `config`, taking each
    /// solution to describe the craft `latency_s` before it arrives.
    pub fn new(config: firmware::drivers::ubx::GnssConfig, latency_s: f64) -> Self {
        Self { input: firmware::app::gnss::GnssInput::new(config, latency_s as f32) }
    }

    /// The `bytes` that reached the board's UART by `now_us` (the firmware's clock, µs): a new
    /// solution with a 3D fix comes back as the position fix the control step takes. Call it
    /// every control step, with no bytes when none came: the driver's search, configuration
    /// and loss of the receiver run on its clock.
    pub fn receive(&mut self, bytes: &[u8], now_us: u64) -> Option<firmware::app::PositionFix> {
        let unsent = self.input.output().write.len();
        self.input.sent(unsent);
        self.input.poll(bytes, now_us)
    }

    /// The firmware's receiver code (its state machine and counters).
    pub fn input(&self) -> &firmware::app::gnss::GnssInput {
        &self.input
    }
}

/// The simulated receiver wired to the firmware's side of it ([`BoardGnss`]), as the board's
/// GNSS UART would connect them: the one feed of `fly --gnss` and `sitl --gnss`.
#[derive(Clone, Debug)]
pub struct GnssFeed {
    receiver: SimGnss,
    board: BoardGnss,
    /// Where the fixes' world has its origin in the simulator's, NED, m: the first fix's
    /// measured position, its error included.
    origin_ned_m: Option<Vector3<f64>>,
    /// The position error of the last solution that reached the board, NED, m.
    last_error_ned_m: Option<Vector3<f64>>,
}

impl GnssFeed {
    /// The receiver `model`, its noise drawn from `seed`.
    pub fn new(model: &GnssModelConfig, seed: u64) -> Self {
        Self {
            receiver: SimGnss::new(model.clone(), seed),
            board: BoardGnss::new(
                firmware::drivers::ubx::GnssConfig {
                    measurement_period_s: (1.0 / model.rate_hz) as f32,
                    ..firmware::drivers::ubx::GnssConfig::default()
                },
                model.latency_s,
            ),
            origin_ned_m: None,
            last_error_ned_m: None,
        }
    }

    /// Simulated time `now_s` with the craft at `truth`, the firmware's clock at `now_us`: the
    /// bytes that reached the board go through the firmware's receiver code; a new fix comes
    /// back for the control step.
    pub fn step(
        &mut self,
        now_s: f64,
        truth: &GnssTruth,
        now_us: u64,
    ) -> Option<firmware::app::PositionFix> {
        let delivered = self.receiver.update(now_s, truth);
        let mut bytes = Vec::new();
        for solution in &delivered {
            bytes.extend_from_slice(&solution.fix.to_frame());
        }
        if let Some(last) = delivered.last() {
            self.last_error_ned_m = Some(last.error_ned_m);
        }
        let fix = self.board.receive(&bytes, now_us)?;
        if self.origin_ned_m.is_none() {
            let home = self.receiver.config().home;
            let first = delivered.iter().rev().find(|d| d.fix.has_3d_fix());
            self.origin_ned_m =
                first.map(|d| home.fix_to_ned(&d.fix) - Vector3::from(fix.position_ned_m).cast());
        }
        Some(fix)
    }

    /// Where the fixes' world has its origin in the simulator's, NED, m, once a fix came.
    pub fn origin_ned_m(&self) -> Option<Vector3<f64>> {
        self.origin_ned_m
    }

    /// The position error the receiver gave the last solution that reached the board, NED, m:
    /// what a craft holding on the fixes holds on top of its own control error.
    pub fn last_error_ned_m(&self) -> Option<Vector3<f64>> {
        self.last_error_ned_m
    }
}

/// The simulated receiver on the board's GNSS UART, as the SITL's board has it: its bytes wait
/// for the firmware's link task to read them (`firmware::app::system::System::service_gnss`,
/// the board's `LinkTask::service_gnss`), which also sends it the configuration and sets the
/// rate. The simulated receiver takes the configuration as written and streams at any rate
/// (the rate-enforcing receiver is the driver's test double, `firmware::drivers::ubx`).
#[derive(Clone, Debug)]
pub struct SimGnssPort {
    receiver: SimGnss,
    waiting: std::collections::VecDeque<u8>,
}

impl SimGnssPort {
    /// The receiver `model`, its noise drawn from `seed`.
    pub fn new(model: &GnssModelConfig, seed: u64) -> Self {
        Self { receiver: SimGnss::new(model.clone(), seed), waiting: Default::default() }
    }

    /// Simulated time `now_s` with the craft at `truth`: the solutions due reach the UART.
    pub fn advance(&mut self, now_s: f64, truth: &GnssTruth) {
        self.waiting.extend(self.receiver.update_bytes(now_s, truth));
    }
}

impl firmware::app::hal::Uart for SimGnssPort {
    fn read(&mut self, buffer: &mut [u8]) -> usize {
        let count = buffer.len().min(self.waiting.len());
        for (slot, byte) in buffer.iter_mut().zip(self.waiting.drain(..count)) {
            *slot = byte;
        }
        count
    }

    fn write(&mut self, bytes: &[u8]) -> usize {
        bytes.len()
    }
}

impl firmware::app::hal::GnssPort for SimGnssPort {
    fn set_baud(&mut self, _baud: u32) {}
}

/// The GNSS receiver on a command line (`fly`, later `sitl`): `--gnss` flies on it instead of
/// motion capture; the rest shape it in the units a user thinks in (the other fields are
/// [`GnssModelConfig::default`]'s: correlated over 20 s, 5 cm white, 5 cm/s velocity noise).
#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct GnssArgs {
    /// Fly on a simulated u-blox GNSS receiver (its NAV-PVT bytes through the firmware's
    /// driver) instead of motion capture: position and velocity, no heading.
    #[arg(long, global = true)]
    pub gnss: bool,
    /// GNSS: correlated position error per horizontal axis, one standard deviation, m (the
    /// vertical 1.5 times it).
    #[arg(long, global = true, default_value_t = GnssArgs::NOISE_M)]
    pub gnss_noise_m: f64,
    /// GNSS: solutions per second, Hz (5–10 for u-blox receivers with several constellations).
    #[arg(long, global = true, default_value_t = GnssArgs::RATE_HZ)]
    pub gnss_rate_hz: f64,
    /// GNSS: time from a solution's epoch to its arrival at the board, ms (told to the firmware).
    #[arg(long, global = true, default_value_t = GnssArgs::LATENCY_MS)]
    pub gnss_latency_ms: f64,
    /// GNSS: multipath jumps (1–5 m for `--gnss-multipath-s`) per minute.
    #[arg(long, global = true, default_value_t = GnssArgs::MULTIPATH_PER_MIN)]
    pub gnss_multipath_per_min: f64,
    /// GNSS: how long a multipath jump lasts, s.
    #[arg(long, global = true, default_value_t = GnssArgs::MULTIPATH_S)]
    pub gnss_multipath_s: f64,
}

impl GnssArgs {
    /// `--gnss-noise-m`'s default, m.
    pub const NOISE_M: f64 = 0.3;
    /// `--gnss-rate-hz`'s default, Hz.
    pub const RATE_HZ: f64 = 10.0;
    /// `--gnss-latency-ms`'s default, ms (the firmware's own default,
    /// `firmware::app::gnss::DEFAULT_GNSS_LATENCY_S`).
    pub const LATENCY_MS: f64 = 100.0;
    /// `--gnss-multipath-per-min`'s default (none).
    pub const MULTIPATH_PER_MIN: f64 = 0.0;
    /// `--gnss-multipath-s`'s default, s.
    pub const MULTIPATH_S: f64 = 5.0;

    /// Whether any flag shaping the receiver differs from its default: a world that draws its
    /// receiver (the `gnss` aspect, `crate::world`) has no use for them.
    pub fn shapes_receiver(&self) -> bool {
        [
            (self.gnss_noise_m, Self::NOISE_M),
            (self.gnss_rate_hz, Self::RATE_HZ),
            (self.gnss_latency_ms, Self::LATENCY_MS),
            (self.gnss_multipath_per_min, Self::MULTIPATH_PER_MIN),
            (self.gnss_multipath_s, Self::MULTIPATH_S),
        ]
        .iter()
        .any(|(value, default)| value != default)
    }

    /// The receiver, checked ([`GnssModelConfig::validate`]); `None` without `--gnss`.
    pub fn config(&self) -> Result<Option<GnssModelConfig>, String> {
        if !self.gnss {
            return Ok(None);
        }
        let config = GnssModelConfig {
            rate_hz: self.gnss_rate_hz,
            latency_s: self.gnss_latency_ms * 1e-3,
            horizontal_sigma_m: self.gnss_noise_m,
            vertical_sigma_m: 1.5 * self.gnss_noise_m,
            multipath_per_s: self.gnss_multipath_per_min / 60.0,
            multipath_s: self.gnss_multipath_s,
            ..GnssModelConfig::default()
        };
        config.validate().map(|()| Some(config))
    }
}

/// The truth the receiver measures at an update.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GnssTruth {
    /// Antenna position, north-east-down from home, m.
    pub position_ned_m: Vector3<f64>,
    /// Antenna velocity, north-east-down, m/s.
    pub velocity_ned_mps: Vector3<f64>,
}

/// One solution as it reaches the board.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Delivered {
    /// What the receiver sends.
    pub fix: GnssFix,
    /// The measurement epoch, simulated s.
    pub measured_s: f64,
    /// When it reaches the board, simulated s.
    pub arrives_s: f64,
    /// The position error it was given (before the frame's rounding), north-east-down, m.
    pub error_ned_m: Vector3<f64>,
    /// Whether a multipath jump was part of that error.
    pub multipath: bool,
}

/// The simulated receiver. Call [`SimGnss::update`] with the truth as simulated time advances
/// (every control tick, or at least once per solution period).
#[derive(Clone, Debug)]
pub struct SimGnss {
    config: GnssModelConfig,
    rng: Rng,
    /// The Gauss–Markov state per axis, m.
    correlated_m: Vector3<f64>,
    /// The current multipath offset and when it ends, s.
    multipath: Option<(f64, Vector3<f64>)>,
    next_multipath_s: f64,
    dropout_until_s: f64,
    next_dropout_s: f64,
    /// The next measurement epoch's index on the `1/rate_hz` grid.
    next_epoch: u64,
    /// Solutions on their way to the board, in order.
    in_flight: Vec<Delivered>,
}

impl SimGnss {
    /// A receiver with `config`, its noise drawn from `seed`; the correlated error starts from
    /// its stationary distribution.
    pub fn new(config: GnssModelConfig, seed: u64) -> Self {
        let mut rng = Rng::new(seed ^ 0x676e_7373);
        let v = config.vertical_scale();
        let correlated_m =
            Vector3::new(rng.normal(), rng.normal(), rng.normal() * v) * config.horizontal_sigma_m;
        let next_multipath_s = poisson_next(&mut rng, 0.0, config.multipath_per_s);
        let next_dropout_s = poisson_next(&mut rng, 0.0, config.dropouts_per_s);
        Self {
            config,
            rng,
            correlated_m,
            multipath: None,
            next_multipath_s,
            dropout_until_s: f64::NEG_INFINITY,
            next_dropout_s,
            next_epoch: 0,
            in_flight: Vec::new(),
        }
    }

    pub fn config(&self) -> &GnssModelConfig {
        &self.config
    }

    /// The accuracies the receiver reports: hAcc, vAcc (m) and sAcc (m/s)
    /// ([`GnssModelConfig::reported_accuracies`]).
    pub fn reported_accuracies(&self) -> (f64, f64, f64) {
        self.config.reported_accuracies()
    }

    /// Measure at every epoch up to `now_s` (with `truth`, the state now), and return the
    /// solutions that have reached the board by `now_s`, oldest first.
    pub fn update(&mut self, now_s: f64, truth: &GnssTruth) -> Vec<Delivered> {
        let period_s = 1.0 / self.config.rate_hz;
        while self.next_epoch as f64 * period_s <= now_s {
            let epoch_s = self.next_epoch as f64 * period_s;
            let solution = self.measure(epoch_s, period_s, truth);
            self.in_flight.push(solution);
            self.next_epoch += 1;
        }
        let arrived = self.in_flight.iter().take_while(|d| d.arrives_s <= now_s).count();
        self.in_flight.drain(..arrived).collect()
    }

    /// [`SimGnss::update`] as the bytes on the receiver's UART: one NAV-PVT frame per solution.
    pub fn update_bytes(&mut self, now_s: f64, truth: &GnssTruth) -> Vec<u8> {
        let mut bytes = Vec::new();
        for delivered in self.update(now_s, truth) {
            bytes.extend_from_slice(&delivered.fix.to_frame());
        }
        bytes
    }

    fn measure(&mut self, epoch_s: f64, period_s: f64, truth: &GnssTruth) -> Delivered {
        let c = self.config.clone();
        let v = c.vertical_scale();
        // Gauss–Markov step over one period (the first epoch keeps its stationary draw).
        if self.next_epoch > 0 {
            let phi = (-period_s / c.correlation_time_s).exp();
            let drive = c.horizontal_sigma_m * (1.0 - phi * phi).sqrt();
            let w = Vector3::new(self.rng.normal(), self.rng.normal(), self.rng.normal() * v);
            self.correlated_m = self.correlated_m * phi + w * drive;
        }
        let white = Vector3::new(self.rng.normal(), self.rng.normal(), self.rng.normal() * v)
            * c.white_noise_m;
        // Multipath: end the current jump, start a new one when its Poisson time has come.
        if self.multipath.is_some_and(|(until, _)| epoch_s >= until) {
            self.multipath = None;
        }
        while epoch_s >= self.next_multipath_s {
            let angle = self.rng.range(0.0, std::f64::consts::TAU);
            let size = self.rng.normal() * c.multipath_jump_m;
            let offset = Vector3::new(
                angle.cos() * size,
                angle.sin() * size,
                self.rng.normal() * 0.5 * c.multipath_jump_m,
            );
            self.multipath = Some((self.next_multipath_s + c.multipath_s, offset));
            self.next_multipath_s =
                poisson_next(&mut self.rng, self.next_multipath_s, c.multipath_per_s);
        }
        while epoch_s >= self.next_dropout_s {
            self.dropout_until_s = self.next_dropout_s + c.dropout_s;
            self.next_dropout_s =
                poisson_next(&mut self.rng, self.next_dropout_s, c.dropouts_per_s);
        }
        let multipath = self.multipath.map(|(_, offset)| offset);
        let error_ned_m = self.correlated_m + white + multipath.unwrap_or_default();
        let velocity_error = Vector3::new(self.rng.normal(), self.rng.normal(), self.rng.normal())
            * c.velocity_noise_mps;
        let position = c.home.to_geodetic(&(truth.position_ned_m + error_ned_m));
        let velocity = truth.velocity_ned_mps + velocity_error;
        let (h_acc, v_acc, s_acc) = self.reported_accuracies();
        let tow_ms = ((TOW_AT_START_S + epoch_s) * 1000.0).round() as u64 % MS_PER_WEEK;
        let has_fix = epoch_s >= self.dropout_until_s;
        let fix = GnssFix {
            time_of_week_ms: tow_ms as u32,
            date_valid: true,
            time_valid: true,
            time_fully_resolved: true,
            fix_type: if has_fix { FixType::Fix3d } else { FixType::NoFix },
            gnss_fix_ok: has_fix,
            position_invalid: false,
            satellites: if has_fix { c.satellites } else { 0 },
            latitude_deg: position.latitude_deg,
            longitude_deg: position.longitude_deg,
            height_ellipsoid_m: position.height_ellipsoid_m as f32,
            height_msl_m: (position.height_ellipsoid_m - c.home.geoid_undulation_m) as f32,
            horizontal_accuracy_m: if has_fix { h_acc as f32 } else { NO_FIX_ACCURACY_M },
            vertical_accuracy_m: if has_fix { v_acc as f32 } else { NO_FIX_ACCURACY_M },
            velocity_ned_mps: [velocity.x as f32, velocity.y as f32, velocity.z as f32],
            speed_accuracy_mps: if has_fix { s_acc as f32 } else { NO_FIX_SPEED_ACCURACY_MPS },
            position_dop: if has_fix { DOP_WITH_FIX } else { DOP_WITHOUT_FIX },
        };
        Delivered {
            fix,
            measured_s: epoch_s,
            arrives_s: epoch_s + c.latency_s,
            error_ned_m,
            multipath: multipath.is_some(),
        }
    }
}

/// hAcc/vAcc a u-blox receiver reports without a fix: its accuracy estimate grows without bound
/// (a few km after a while); a large number the application cannot mistake for a fix.
const NO_FIX_ACCURACY_M: f32 = 4_000.0;
/// sAcc without a fix, m/s (as large, for the same reason).
const NO_FIX_SPEED_ACCURACY_MPS: f32 = 20.0;
/// pDOP with a good sky view.
const DOP_WITH_FIX: f32 = 1.4;
/// pDOP a u-blox receiver reports without a solution (the field's 99.99).
const DOP_WITHOUT_FIX: f32 = 99.99;

/// The time of the next event of a Poisson process of `rate_per_s` after `after_s` (never when
/// the rate is 0).
fn poisson_next(rng: &mut Rng, after_s: f64, rate_per_s: f64) -> f64 {
    if rate_per_s > 0.0 {
        after_s - (1.0 - rng.uniform()).ln() / rate_per_s
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::drivers::ubx::{Decoder, Message, NAV_PVT_FRAME_LEN};

    /// A receiver with only the noise under test.
    fn quiet() -> GnssModelConfig {
        GnssModelConfig {
            rate_hz: 10.0,
            latency_s: 0.0,
            horizontal_sigma_m: 0.0,
            vertical_sigma_m: 0.0,
            white_noise_m: 0.0,
            velocity_noise_mps: 0.0,
            ..GnssModelConfig::default()
        }
    }

    /// Run a still receiver at home for `seconds`, one update per epoch; every solution.
    fn run(config: GnssModelConfig, seconds: f64, seed: u64) -> Vec<Delivered> {
        config.validate().unwrap();
        let period = 1.0 / config.rate_hz;
        let mut gnss = SimGnss::new(config, seed);
        let mut out = Vec::new();
        let steps = (seconds / period).round() as usize;
        for k in 0..steps {
            out.extend(gnss.update(k as f64 * period + 1e-9, &GnssTruth::default()));
        }
        out
    }

    fn std_dev(values: &[f64]) -> f64 {
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
    }

    /// Normalised autocorrelation of `values` at `lag` samples.
    fn autocorrelation(values: &[f64], lag: usize) -> f64 {
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
        let cov: f64 =
            values.windows(lag + 1).map(|w| (w[0] - mean) * (w[lag] - mean)).sum::<f64>();
        cov / var
    }

    #[test]
    fn the_correlated_error_has_the_configured_sigma_and_correlation_time() {
        let config = GnssModelConfig {
            horizontal_sigma_m: 0.8,
            vertical_sigma_m: 1.6,
            correlation_time_s: 5.0,
            ..quiet()
        };
        // 20,000 s: 4,000 correlation times, so the variance is known to about 2 %.
        let solutions = run(config.clone(), 20_000.0, 7);
        let home = config.home;
        for (axis, sigma) in [(0, 0.8), (1, 0.8), (2, 1.6)] {
            let error: Vec<f64> = solutions.iter().map(|d| home.fix_to_ned(&d.fix)[axis]).collect();
            let s = std_dev(&error);
            assert!((s / sigma - 1.0).abs() < 0.08, "axis {axis}: σ {s} vs {sigma}");
            // At a lag of one correlation time the autocorrelation is e^-1.
            let lag = (config.correlation_time_s * config.rate_hz) as usize;
            let rho = autocorrelation(&error, lag);
            let tau = config.correlation_time_s / -rho.ln();
            assert!((tau / 5.0 - 1.0).abs() < 0.15, "axis {axis}: ρ {rho}, τ {tau} s");
        }
    }

    #[test]
    fn the_white_error_has_the_configured_sigma_and_no_correlation() {
        let config = GnssModelConfig { white_noise_m: 0.3, velocity_noise_mps: 0.1, ..quiet() };
        let solutions = run(config.clone(), 2_000.0, 11);
        let north: Vec<f64> = solutions.iter().map(|d| config.home.fix_to_ned(&d.fix).x).collect();
        // The frame's 1e-7° (1.1 cm) rounding adds (1.1 cm)²/12 of variance: negligible.
        assert!((std_dev(&north) / 0.3 - 1.0).abs() < 0.05, "σ {}", std_dev(&north));
        assert!(autocorrelation(&north, 1).abs() < 0.03);
        let velocity_east: Vec<f64> =
            solutions.iter().map(|d| f64::from(d.fix.velocity_ned_mps[1])).collect();
        assert!((std_dev(&velocity_east) / 0.1 - 1.0).abs() < 0.05);
    }

    #[test]
    fn the_reported_accuracies_match_the_errors() {
        let config = GnssModelConfig {
            horizontal_sigma_m: 0.6,
            vertical_sigma_m: 1.2,
            correlation_time_s: 2.0,
            white_noise_m: 0.2,
            velocity_noise_mps: 0.15,
            ..quiet()
        };
        let solutions = run(config.clone(), 10_000.0, 3);
        let n = solutions.len() as f64;
        let rms = |f: &dyn Fn(&Delivered) -> f64| {
            (solutions.iter().map(|d| f(d).powi(2)).sum::<f64>() / n).sqrt()
        };
        let horizontal = rms(&|d| d.error_ned_m.xy().norm());
        let vertical = rms(&|d| d.error_ned_m.z);
        let speed = rms(&|d| Vector3::from(d.fix.velocity_ned_mps.map(f64::from)).norm());
        let fix = &solutions[0].fix;
        for (name, measured, reported) in [
            ("hAcc", horizontal, fix.horizontal_accuracy_m),
            ("vAcc", vertical, fix.vertical_accuracy_m),
            ("sAcc", speed, fix.speed_accuracy_mps),
        ] {
            let reported = f64::from(reported);
            assert!(
                (measured / reported - 1.0).abs() < 0.06,
                "{name}: RMS {measured} vs {reported}"
            );
        }
        // The figures themselves: √2·√(0.6² + 0.2²), √(1.2² + 0.4²), √3·0.15.
        assert!((f64::from(fix.horizontal_accuracy_m) - 0.894_4).abs() < 1e-3);
        assert!((f64::from(fix.vertical_accuracy_m) - 1.264_9).abs() < 1e-3);
        assert!((f64::from(fix.speed_accuracy_mps) - 0.259_8).abs() < 1e-3);
    }

    #[test]
    fn solutions_come_at_the_configured_rate_and_latency() {
        for (rate_hz, latency_s) in [(5.0, 0.05), (10.0, 0.15), (8.0, 0.1)] {
            let config = GnssModelConfig { rate_hz, latency_s, ..GnssModelConfig::default() };
            let mut gnss = SimGnss::new(config, 5);
            let step_s = 0.0005; // the 2 kHz control tick
            let mut delivered = Vec::new();
            for k in 0..=20_000 {
                let now = f64::from(k) * step_s;
                for d in gnss.update(now, &GnssTruth::default()) {
                    delivered.push((now, d));
                }
            }
            // 10 s: one solution per period (the last ones still in flight).
            let expected = ((10.0 - latency_s) * rate_hz).floor() as usize + 1;
            assert_eq!(delivered.len(), expected, "{rate_hz} Hz");
            for (now, d) in &delivered {
                let late = now - d.measured_s;
                assert!(
                    late >= latency_s - 1e-9 && late < latency_s + step_s + 1e-9,
                    "late {late}"
                );
            }
            for pair in delivered.windows(2) {
                let (a, b) = (&pair[0].1, &pair[1].1);
                assert!((b.measured_s - a.measured_s - 1.0 / rate_hz).abs() < 1e-9);
                let tow_step = b.fix.time_of_week_ms - a.fix.time_of_week_ms;
                assert!(
                    (f64::from(tow_step) - 1000.0 / rate_hz).abs() <= 1.0,
                    "iTOW step {tow_step}"
                );
            }
        }
    }

    #[test]
    fn multipath_jumps_last_their_duration_and_have_their_size() {
        let config = GnssModelConfig {
            multipath_per_s: 0.05,
            multipath_jump_m: 4.0,
            multipath_s: 3.0,
            ..quiet()
        };
        let solutions = run(config.clone(), 20_000.0, 13);
        // Runs of solutions with a jump, and the offset each held.
        let mut runs: Vec<(f64, f64, Vector3<f64>)> = Vec::new();
        for d in &solutions {
            match runs.last_mut() {
                Some((_, end, offset))
                    if d.multipath && (d.error_ned_m - *offset).norm() < 1e-9 =>
                {
                    *end = d.measured_s
                }
                _ if d.multipath => runs.push((d.measured_s, d.measured_s, d.error_ned_m)),
                _ => {}
            }
        }
        // About rate × time jumps (overlapping ones merge into the later).
        let expected = 0.05 * 20_000.0;
        assert!((runs.len() as f64 / expected - 1.0).abs() < 0.15, "{} jumps", runs.len());
        let period = 1.0 / config.rate_hz;
        let complete: Vec<_> = runs[..runs.len() - 1].iter().collect();
        let long = complete.iter().filter(|(s, e, _)| e - s + period > 3.0 + period + 1e-9).count();
        assert_eq!(long, 0, "a jump outlasted its 3 s");
        let full = complete
            .iter()
            .filter(|(s, e, _)| (e - s + period - 3.0).abs() <= period + 1e-9)
            .count();
        // Most last the full 3 s (the others were cut short by the next jump).
        assert!(full as f64 > 0.8 * complete.len() as f64, "{full} of {}", complete.len());
        let horizontal: Vec<f64> = runs.iter().flat_map(|(_, _, o)| [o.x, o.y]).collect();
        let rms = (horizontal.iter().map(|v| v * v).sum::<f64>() / horizontal.len() as f64).sqrt();
        assert!((rms / (4.0 / 2f64.sqrt()) - 1.0).abs() < 0.1, "jump RMS per axis {rms}");
    }

    #[test]
    fn dropouts_send_solutions_without_a_fix() {
        let config = GnssModelConfig { dropouts_per_s: 0.02, dropout_s: 2.0, ..quiet() };
        let solutions = run(config, 20_000.0, 17);
        let without: Vec<&Delivered> = solutions.iter().filter(|d| !d.fix.gnss_fix_ok).collect();
        // Fraction of time without a fix: rate × duration, as long as dropouts rarely overlap.
        let fraction = without.len() as f64 / solutions.len() as f64;
        assert!((fraction / 0.04 - 1.0).abs() < 0.2, "{fraction}");
        for d in without {
            assert_eq!(d.fix.fix_type, FixType::NoFix);
            assert!(!d.fix.has_3d_fix());
            assert!(d.fix.horizontal_accuracy_m > 1_000.0);
        }
    }

    #[test]
    fn the_geodetic_conversion_uses_the_wgs84_radii_and_inverts() {
        let home = Home {
            latitude_deg: 45.0,
            longitude_deg: 10.0,
            height_ellipsoid_m: 0.0,
            geoid_undulation_m: 0.0,
        };
        let (m, n) = home.radii_m();
        // At 45°: M = 6,367,381.8 m, N = 6,388,838.3 m.
        assert!((m - 6_367_381.8).abs() < 0.1, "{m}");
        assert!((n - 6_388_838.3).abs() < 0.1, "{n}");
        // One degree of latitude is M·π/180 of north.
        let p = home.to_geodetic(&Vector3::new(m.to_radians(), 0.0, -5.0));
        assert!(
            (p.latitude_deg - 46.0).abs() < 1e-12 && (p.height_ellipsoid_m - 5.0).abs() < 1e-12
        );
        for ned in [Vector3::new(1_234.5, -987.6, -120.0), Vector3::new(-3_000.0, 4_000.0, 15.0)] {
            let back = Home::default().to_ned(&Home::default().to_geodetic(&ned));
            assert!((back - ned).norm() < 1e-6, "{back:?} vs {ned:?}");
        }
    }

    #[test]
    fn ned_through_the_frame_and_the_driver_comes_back_within_the_frame_resolution() {
        let config = quiet(); // no noise: the fix is the truth
        let home = config.home;
        let mut gnss = SimGnss::new(config.clone(), 1);
        let mut decoder = Decoder::new();
        let (m, n) = home.radii_m();
        // Half of the frame's last digit: 1e-7° of latitude and longitude, 1 mm of height.
        let half_north_m = 0.5e-7f64.to_radians() * (m + home.height_ellipsoid_m);
        let half_east_m = 0.5e-7f64.to_radians()
            * (n + home.height_ellipsoid_m)
            * home.latitude_deg.to_radians().cos();
        let mut rng = Rng::new(99);
        let mut checked = 0;
        for k in 0..200 {
            let truth = GnssTruth {
                position_ned_m: Vector3::new(
                    rng.range(-2e3, 2e3),
                    rng.range(-2e3, 2e3),
                    rng.range(-300.0, 5.0),
                ),
                velocity_ned_mps: Vector3::new(
                    rng.range(-20.0, 20.0),
                    rng.range(-20.0, 20.0),
                    rng.range(-5.0, 5.0),
                ),
            };
            let bytes = gnss.update_bytes(f64::from(k) / config.rate_hz + 1e-9, &truth);
            let mut fixes = Vec::new();
            decoder.feed(&bytes, |frame| {
                if let Message::NavPvt(fix) = Message::parse(&frame) {
                    fixes.push(fix);
                }
            });
            assert_eq!(fixes.len(), 1);
            let back = home.fix_to_ned(&fixes[0]);
            let error = back - truth.position_ned_m;
            assert!(error.x.abs() <= half_north_m + 1e-6, "north {} m", error.x);
            assert!(error.y.abs() <= half_east_m + 1e-6, "east {} m", error.y);
            // Height: 1 mm steps, carried as f32 (7.6e-6 m resolution at 500 m).
            assert!(error.z.abs() <= 0.5e-3 + 1e-4, "down {} m", error.z);
            for axis in 0..3 {
                let v = f64::from(fixes[0].velocity_ned_mps[axis]);
                assert!((v - truth.velocity_ned_mps[axis]).abs() <= 0.5e-3 + 1e-5);
            }
            checked += 1;
        }
        assert_eq!(checked, 200);
        assert!(half_north_m < 0.006 && half_east_m < 0.004, "{half_north_m} {half_east_m}");
        assert_eq!(decoder.stats().checksum_errors, 0);
    }

    #[test]
    fn random_receivers_are_within_the_issues_ranges() {
        let mut rng = Rng::new(2026);
        for _ in 0..1_000 {
            let c = GnssModelConfig::random(&mut rng);
            c.validate().unwrap();
            assert!((0.02..=2.0).contains(&c.horizontal_sigma_m));
            assert!((5.0..=10.0).contains(&c.rate_hz));
            assert!((0.05..=0.15).contains(&c.latency_s));
        }
        let bad = GnssModelConfig { rate_hz: 0.0, ..GnssModelConfig::default() };
        assert_eq!(bad.validate(), Err("GNSS: rate_hz = 0 is outside 1..=25".to_string()));
    }

    #[test]
    fn a_frame_is_one_nav_pvt() {
        let mut gnss = SimGnss::new(GnssModelConfig::default(), 2);
        let bytes = gnss.update_bytes(0.2, &GnssTruth::default());
        assert_eq!(bytes.len(), NAV_PVT_FRAME_LEN); // epoch 0 arrived at 0.1 s, epoch 1 in flight
    }
}
