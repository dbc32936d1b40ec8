//! The GNSS receiver as the application sees it: the u-blox driver's state machine
//! (`crate::drivers::ubx::GnssReceiver`: baud search, configuration, NAV-PVT) and each new
//! solution with a 3D fix turned into a [`PositionFix`] for the control step, in metres north,
//! east and down of the first such fix (the local origin).
//!
//! Portable: the board's GNSS UART, the SITL and the simulator's flights all feed it bytes and
//! the time, and send what it returns ([`GnssInput::output`]) back to the receiver; the fixes go
//! to the control step as [`super::ControlCommand::PositionFix`], so the flight log records
//! them like every other command and a replay needs no receiver.
//!
//! **What it assumes.** The receiver's accuracies (`hAcc`, `vAcc`, `sAcc`) describe its errors:
//! `hAcc` is the horizontal error's RMS (√2 σ per axis), `sAcc` the 3D velocity error's RMS
//! (√3 σ per axis), as u-blox documents them; a receiver that understates them is caught by the
//! estimator's outlier gate only beyond half a metre (`flight::navigation::MIN_OUTLIER_GATE_M`).
//! A solution arrives `latency_s` after the moment it describes (the receiver's computation and
//! the UART: 50–150 ms on M8–M10 receivers at 5–10 Hz); the latency is a setting, not measured,
//! because without the receiver's time pulse the board cannot tell the epoch's time on its own
//! clock. The local plane is flat ("flat earth": the meridian and prime-vertical radii of
//! curvature at the origin): its error grows as the square of the distance, 1 cm at 10 km.
//! Heights are the ellipsoid's (`height`), not above mean sea level: the geoid's undulation is
//! constant over a flight and would only move the origin.

use crate::drivers::ubx::{GnssConfig, GnssFix, GnssOutput, GnssReceiver, GnssStatus};
use protocol::{GnssHealth, GnssInterface, GnssState};

use super::hal::GnssPort;
use super::pilot::{PositionFix, MAX_POSE_LATENCY_S};

/// Bytes read from the GNSS UART per service, at most: a NAV-PVT is 100 bytes, and the board's
/// receive ring holds more than a service interval's worth at any rate the driver configures.
pub const GNSS_CHUNK_BYTES: usize = 256;

/// WGS-84 semi-major axis, m (NIMA TR8350.2, table 3.1).
const WGS84_A_M: f64 = 6_378_137.0;
/// WGS-84 first eccentricity squared, `f(2 − f)` with `f` = 1/298.257223563 (NIMA TR8350.2).
const WGS84_E2: f64 = 6.694_379_990_14e-3;

/// Default latency of a solution, s (ours): the middle of the 50–150 ms an M8–M10 receiver
/// takes from its measurement epoch to the end of a NAV-PVT on the UART.
pub const DEFAULT_GNSS_LATENCY_S: f32 = 0.1;

/// Default rate of solutions asked of the receiver, Hz: 5, which every M8–M10 reaches with all
/// its constellations (`GnssConfig::default`'s period).
pub const DEFAULT_GNSS_RATE_HZ: f32 = 5.0;

/// √2, √3: a horizontal RMS error and a 3D one per axis standard deviation.
const SQRT_2: f32 = core::f32::consts::SQRT_2;
const SQRT_3: f32 = 1.732_050_8;

/// Smallest noise a fix is given, m and m/s (ours): a receiver reporting an accuracy of 0 (an
/// RTK fix rounded to the millimetre) is still not believed beyond a millimetre.
const MIN_SIGMA: f32 = 0.001;

/// The local north-east-down plane about the first fix.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Origin {
    latitude_deg: f64,
    longitude_deg: f64,
    height_m: f64,
    /// Metres per degree of latitude and of longitude at the origin.
    north_m_per_deg: f64,
    east_m_per_deg: f64,
}

impl Origin {
    fn at(fix: &GnssFix) -> Self {
        let lat = fix.latitude_deg.to_radians();
        let sin_lat = libm::sin(lat);
        let w2 = 1.0 - WGS84_E2 * sin_lat * sin_lat;
        // Radii of curvature: meridian M = a(1 − e²)/W³, prime vertical N = a/W.
        let w = libm::sqrt(w2);
        let height = f64::from(fix.height_ellipsoid_m);
        let meridian_m = WGS84_A_M * (1.0 - WGS84_E2) / (w2 * w) + height;
        let normal_m = WGS84_A_M / w + height;
        let per_deg = core::f64::consts::PI / 180.0;
        Self {
            latitude_deg: fix.latitude_deg,
            longitude_deg: fix.longitude_deg,
            height_m: height,
            north_m_per_deg: meridian_m * per_deg,
            east_m_per_deg: normal_m * libm::cos(lat) * per_deg,
        }
    }

    fn ned_m_of(&self, fix: &GnssFix) -> [f32; 3] {
        let mut east_deg = fix.longitude_deg - self.longitude_deg;
        // Across the antimeridian the difference is the short way round.
        if east_deg > 180.0 {
            east_deg -= 360.0;
        } else if east_deg < -180.0 {
            east_deg += 360.0;
        }
        [
            ((fix.latitude_deg - self.latitude_deg) * self.north_m_per_deg) as f32,
            (east_deg * self.east_m_per_deg) as f32,
            (self.height_m - f64::from(fix.height_ellipsoid_m)) as f32,
        ]
    }
}

/// Counters for the report (`doctor`, `status`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GnssCounts {
    /// Solutions with a 3D fix turned into position fixes.
    pub fixes: u32,
    /// Solutions without a usable fix (no 3D fix, `gnssFixOK` clear, invalid position).
    pub without_fix: u32,
}

/// The receiver and the local origin.
#[derive(Clone, Debug)]
pub struct GnssInput {
    receiver: GnssReceiver,
    origin: Option<Origin>,
    latency_s: f32,
    /// Time of week of the last solution taken, ms (each is taken once).
    last_time_of_week_ms: Option<u32>,
    counts: GnssCounts,
}

impl GnssInput {
    /// A receiver configured with `config`, whose solutions arrive `latency_s` after their
    /// epoch (clamped to 0–[`MAX_POSE_LATENCY_S`]; not finite: [`DEFAULT_GNSS_LATENCY_S`]).
    pub fn new(config: GnssConfig, latency_s: f32) -> Self {
        let latency_s = if latency_s.is_finite() {
            latency_s.clamp(0.0, MAX_POSE_LATENCY_S)
        } else {
            DEFAULT_GNSS_LATENCY_S
        };
        Self {
            receiver: GnssReceiver::new(config),
            origin: None,
            latency_s,
            last_time_of_week_ms: None,
            counts: GnssCounts::default(),
        }
    }

    /// The solutions' latency from now on, s (the `gnss_latency_s` parameter changed; clamped
    /// as in [`Self::new`]).
    pub fn set_latency_s(&mut self, latency_s: f32) {
        if latency_s.is_finite() {
            self.latency_s = latency_s.clamp(0.0, MAX_POSE_LATENCY_S);
        }
    }

    /// Take the bytes received since the last call and the time (µs, monotonic); a new
    /// solution with a 3D fix comes back as a position fix. Then send [`Self::output`].
    pub fn poll(&mut self, bytes_in: &[u8], now_us: u64) -> Option<PositionFix> {
        let _ = self.receiver.poll(bytes_in, now_us);
        let GnssStatus::Receiving { fix } = self.receiver.status() else { return None };
        if self.last_time_of_week_ms == Some(fix.time_of_week_ms) {
            return None;
        }
        self.last_time_of_week_ms = Some(fix.time_of_week_ms);
        if !fix.has_3d_fix() {
            self.counts.without_fix = self.counts.without_fix.wrapping_add(1);
            return None;
        }
        let origin = *self.origin.get_or_insert_with(|| Origin::at(&fix));
        let position_fix = PositionFix {
            position_ned_m: origin.ned_m_of(&fix),
            sigma_m: [
                (fix.horizontal_accuracy_m / SQRT_2).max(MIN_SIGMA),
                fix.vertical_accuracy_m.max(MIN_SIGMA),
            ],
            velocity_ned_mps: Some(fix.velocity_ned_mps),
            velocity_sigma_mps: (fix.speed_accuracy_mps / SQRT_3).max(MIN_SIGMA),
            latency_s: self.latency_s,
        };
        if !position_fix.is_valid() {
            self.counts.without_fix = self.counts.without_fix.wrapping_add(1);
            return None;
        }
        self.counts.fixes = self.counts.fixes.wrapping_add(1);
        Some(position_fix)
    }

    /// What to send the receiver now: set the UART to `baud` first (when it differs), then
    /// queue `write` and report how much was taken with [`Self::sent`].
    pub fn output(&self) -> GnssOutput<'_> {
        self.receiver.output()
    }

    /// The UART took `count` of the bytes [`Self::output`] offered.
    pub fn sent(&mut self, count: usize) {
        self.receiver.sent(count);
    }

    /// The receiver's state machine (status, decoder counters, what acknowledged).
    pub fn receiver(&self) -> &GnssReceiver {
        &self.receiver
    }

    /// The counters.
    pub fn counts(&self) -> GnssCounts {
        self.counts
    }

    /// One service of the receiver through its UART at `now_us`: the bytes received since the
    /// last service in, the baud rate and the bytes the driver wants out; a new position fix
    /// comes back for the control step. Never blocks: what the UART does not take now goes
    /// next time. The same code on the board (its GNSS UART) and in the simulators.
    pub fn service<P: GnssPort>(&mut self, port: &mut P, now_us: u64) -> Option<PositionFix> {
        let mut bytes = [0u8; GNSS_CHUNK_BYTES];
        let count = port.read(&mut bytes).min(GNSS_CHUNK_BYTES);
        let fix = self.poll(&bytes[..count], now_us);
        let output = self.receiver.output();
        port.set_baud(output.baud);
        let taken = port.write(output.write);
        self.receiver.sent(taken);
        fix
    }

    /// The report for `status` and `doctor` (protocol `BoardHealth::gnss`).
    pub fn health(&self) -> GnssHealth {
        let output = self.receiver.output();
        let (state, newest) = match self.receiver.status() {
            GnssStatus::Searching { .. } => (GnssState::Searching, None),
            GnssStatus::Configuring { .. } => (GnssState::Configuring, None),
            GnssStatus::Receiving { fix } => (GnssState::Receiving, Some(fix)),
            GnssStatus::Lost => (GnssState::Lost, None),
        };
        let acknowledged = self.receiver.acknowledged();
        let interface = if acknowledged.valset {
            GnssInterface::ConfigurationKeys
        } else if acknowledged.legacy {
            GnssInterface::LegacyMessages
        } else {
            GnssInterface::Unknown
        };
        GnssHealth {
            state,
            baud: output.baud,
            interface,
            fix_type: newest.map_or(0, |fix| fix.fix_type.raw()),
            satellites: newest.map_or(0, |fix| fix.satellites),
            horizontal_accuracy_m: newest.map_or(f32::NAN, |fix| fix.horizontal_accuracy_m),
            vertical_accuracy_m: newest.map_or(f32::NAN, |fix| fix.vertical_accuracy_m),
            speed_accuracy_mps: newest.map_or(f32::NAN, |fix| fix.speed_accuracy_mps),
            fixes: self.counts.fixes,
            without_fix: self.counts.without_fix,
            checksum_errors: self.receiver.decoder_stats().checksum_errors,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drivers::ubx::FixType;

    /// A solution at `latitude_deg`, `longitude_deg`, `height_m` with the accuracies given.
    fn solution(
        time_of_week_ms: u32,
        latitude_deg: f64,
        longitude_deg: f64,
        height_m: f32,
    ) -> GnssFix {
        GnssFix {
            time_of_week_ms,
            date_valid: true,
            time_valid: true,
            time_fully_resolved: true,
            fix_type: FixType::Fix3d,
            gnss_fix_ok: true,
            position_invalid: false,
            satellites: 14,
            latitude_deg,
            longitude_deg,
            height_ellipsoid_m: height_m,
            height_msl_m: height_m - 48.0,
            horizontal_accuracy_m: 0.42,
            vertical_accuracy_m: 0.6,
            velocity_ned_mps: [1.0, -2.0, 0.5],
            speed_accuracy_mps: 0.173,
            position_dop: 1.2,
        }
    }

    /// A receiver already found and configured: bytes at its rate until it reports NAV-PVT.
    fn receiving(input: &mut GnssInput, first: &GnssFix) -> u64 {
        let mut now_us = 0;
        let frame = first.to_frame();
        // Poll until the state machine has searched, configured and taken a NAV-PVT.
        for _ in 0..200 {
            now_us += 50_000;
            let output = input.output();
            let taken = output.write.len();
            input.sent(taken);
            if input.poll(&frame, now_us).is_some() {
                return now_us;
            }
        }
        panic!("the receiver never reached Receiving: {:?}", input.receiver().status());
    }

    #[test]
    fn solutions_become_fixes_in_metres_about_the_first_with_their_accuracies() {
        // Zürich, 47.4° N, 500 m: 1" of latitude is M × 1" with the meridian radius
        // M = a(1 − e²)/W³ = 6,370,563 m (height included): 30.89 m.
        let mut input = GnssInput::new(GnssConfig::default(), 0.08);
        let home = solution(1000, 47.4, 8.5, 500.0);
        receiving(&mut input, &home);
        assert_eq!(input.counts().fixes, 1);
        // 1" north, 2" east, 3 m up.
        let moved = solution(1200, 47.4 + 1.0 / 3600.0, 8.5 + 2.0 / 3600.0, 503.0);
        let fix = input.poll(&moved.to_frame(), 10_000_000).expect("a fix");
        let [north, east, down] = fix.position_ned_m;
        assert!((north - 30.89).abs() < 0.02, "north {north} m");
        // 2" of longitude at 47.4°: N cos φ × 2" with the prime-vertical radius N = a/W =
        // 6,390,225 m (W² = 1 − e² sin² φ), cos φ = 0.67688: 41.94 m.
        assert!((east - 41.94).abs() < 0.02, "east {east} m");
        assert!((down + 3.0).abs() < 0.01, "down {down} m");
        // hAcc is the 2D RMS, sAcc the 3D RMS: per-axis standard deviations.
        assert!((fix.sigma_m[0] - 0.42 / SQRT_2).abs() < 1e-3);
        assert!((fix.sigma_m[1] - 0.6).abs() < 1e-3);
        assert!((fix.velocity_sigma_mps - 0.1).abs() < 1e-3);
        assert_eq!(fix.velocity_ned_mps, Some([1.0, -2.0, 0.5]));
        assert_eq!(fix.latency_s, 0.08);
        // The same solution again (the receiver's status still shows it) is taken once.
        assert_eq!(input.poll(&[], 10_010_000), None);
        assert_eq!(input.counts().fixes, 2);
    }

    #[test]
    fn a_solution_without_a_3d_fix_is_counted_and_gives_nothing() {
        let mut input = GnssInput::new(GnssConfig::default(), DEFAULT_GNSS_LATENCY_S);
        let home = solution(1000, -33.9, 151.2, 40.0);
        receiving(&mut input, &home);
        let mut lost = solution(1200, -33.9, 151.2, 40.0);
        lost.fix_type = FixType::NoFix;
        lost.gnss_fix_ok = false;
        assert_eq!(input.poll(&lost.to_frame(), 10_000_000), None);
        assert_eq!(input.counts(), GnssCounts { fixes: 1, without_fix: 1 });
        // Garbage on the line is the driver's to count, never a fix.
        assert_eq!(input.poll(&[0xB5, 0x62, 0x01, 0x07, 0xFF, 0xFF, 0x00], 10_100_000), None);
    }

    #[test]
    fn the_antimeridian_is_crossed_the_short_way_and_a_bad_latency_is_bounded() {
        let mut input = GnssInput::new(GnssConfig::default(), f32::NAN);
        let home = solution(1000, 0.0, 179.9999, 0.0);
        receiving(&mut input, &home);
        let across = solution(1200, 0.0, -179.9999, 0.0);
        let fix = input.poll(&across.to_frame(), 10_000_000).expect("a fix");
        // 0.0002° of longitude at the equator: 22.3 m east, not 40,000 km west.
        assert!((fix.position_ned_m[1] - 22.26).abs() < 0.05, "{:?}", fix.position_ned_m);
        assert_eq!(fix.latency_s, DEFAULT_GNSS_LATENCY_S);
        assert_eq!(GnssInput::new(GnssConfig::default(), 5.0).latency_s, MAX_POSE_LATENCY_S);
    }

    /// The board's GNSS UART as a test double that enforces its rate: the u-blox receiver of
    /// the driver's tests (it answers and switches rate as the documents say; bytes at another
    /// rate reach either side as garbage), read and written at the rate the driver set.
    struct RatedPort {
        receiver: crate::drivers::ubx::tests::FakeReceiver,
        baud: u32,
        now_s: f64,
        bauds_set: Vec<u32>,
    }

    impl crate::app::hal::Uart for RatedPort {
        fn read(&mut self, buffer: &mut [u8]) -> usize {
            let bytes = self.receiver.transmit(self.now_s, self.baud);
            let count = bytes.len().min(buffer.len());
            buffer[..count].copy_from_slice(&bytes[..count]);
            count
        }
        fn write(&mut self, bytes: &[u8]) -> usize {
            self.receiver.receive(bytes, self.baud, self.now_s);
            bytes.len()
        }
    }

    impl GnssPort for RatedPort {
        fn set_baud(&mut self, baud: u32) {
            if self.bauds_set.last() != Some(&baud) {
                self.bauds_set.push(baud);
            }
            self.baud = baud;
        }
    }

    /// Serviced every 5 ms through a UART that enforces its rate, an M8 at its factory 9,600
    /// baud and an M10 at its 38,400 are found, configured to the parameters' rate and deliver
    /// position fixes; the report says where the receiver stands at each stage.
    #[test]
    fn a_receiver_at_its_factory_rate_is_found_configured_and_delivers_fixes_through_the_uart() {
        use crate::drivers::ubx::tests::{FakeReceiver, Generation};
        for (generation, factory_baud, interface) in [
            (Generation::M8, 9_600, GnssInterface::LegacyMessages),
            (Generation::M10, 38_400, GnssInterface::ConfigurationKeys),
        ] {
            let params = super::super::Params::default();
            let mut input = GnssInput::new(params.gnss_config(), params.gnss_latency_s());
            assert_eq!(input.health().state, GnssState::Searching);
            let mut port = RatedPort {
                receiver: FakeReceiver::new(generation, factory_baud),
                baud: 0,
                now_s: 0.0,
                bauds_set: Vec::new(),
            };
            let mut fixes = 0;
            let mut first_fix_s = None;
            for step in 0..2_000 {
                port.now_s = f64::from(step) * 0.005;
                let now_us = (port.now_s * 1e6) as u64;
                if input.service(&mut port, now_us).is_some() {
                    fixes += 1;
                    first_fix_s.get_or_insert(port.now_s);
                }
            }
            let health = input.health();
            assert_eq!(health.state, GnssState::Receiving, "{health:?}");
            assert_eq!(health.baud, params.gnss_config().target_baud);
            assert_eq!(port.baud, params.gnss_config().target_baud, "the UART moved with it");
            assert!(port.bauds_set.contains(&factory_baud), "searched {:?}", port.bauds_set);
            assert_eq!(health.interface, interface);
            assert_eq!((health.fix_type, health.satellites), (3, 17));
            assert!((health.horizontal_accuracy_m - 0.85).abs() < 1e-3, "{health:?}");
            // 5 Hz from the first fix to the end of the 10 s.
            let first_fix_s = first_fix_s.expect("a fix came");
            assert!(first_fix_s < 6.0, "found and configured within {first_fix_s} s");
            let expected = (10.0 - first_fix_s) * f64::from(super::DEFAULT_GNSS_RATE_HZ);
            assert!((fixes as f64 - expected).abs() <= 2.0, "{fixes} fixes, {expected} expected");
            assert_eq!(health.fixes, fixes);
        }
    }
}
