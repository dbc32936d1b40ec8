//! `configurator-cli doctor`: the bring-up check for a board's first power-up.
//!
//! Eight lines, in order, each saying what it checked, what it found (with units) and, when it
//! fails, what to do:
//! 1. **link**: the handshake (firmware and protocol versions, board, serial, the same message
//!    table as this configurator), and that the craft is disarmed;
//! 2. **imu**: the driver's state, then [`IMU_WINDOW_S`] of raw samples at the control rate
//!    (the `imu` telemetry topic: every control step's sample) with the craft at rest: gyro noise
//!    and offset, accelerometer noise and the magnitude of gravity, against the ICM-42688-P
//!    datasheet's figures with a margin ([`NOISE_MARGIN`]); a silent or frozen sensor fails;
//! 3. **flash**: the configuration store's state at start-up (read only: nothing is written);
//! 4. **receiver**: the radio receiver's frames, errors and link quality; a board without one is
//!    information, not a failure (it may be flown over its USB or telemetry link);
//! 4. **gnss**: the GNSS receiver's state (found at which baud, which configuration it took),
//!    its fix, satellites and stated accuracies; a board without a GNSS port, no receiver
//!    found, or no fix yet (indoors) is information; a receiver that stopped sending fails;
//! 5. **battery**: the pack's voltage per cell and the current with the motors stopped, against
//!    what a lithium pack at rest and a board's own draw can be ([`battery_line`]): a divider
//!    or current-sensor scale that does not match the board reads outside them; no pack (USB
//!    power) or no battery sensing is information;
//! 6. **esc**: every motor's ESC answering with its speed (bidirectional DShot); with
//!    `motor_bidir_dshot` = 0 (ESCs that cannot report), whether this firmware identifies the
//!    motors without speeds (`Capabilities::IDENTIFIES_WITHOUT_SPEEDS`) instead;
//! 7. **spin**: asked first (propellers off), each motor spun in turn at [`SPIN_COMMAND`] for
//!    [`SPIN_S`]; its own speed report must rise and the others must not: a motor output whose
//!    speed comes back on another output (commands and speed reports mapped differently) or
//!    not at all is found here. Without speed reports there is nothing to compare: skipped,
//!    with `motor-test` as the way to watch each motor.
//!
//! What the checks assume of the world: the craft stands still on a bench (not in a hand: a
//! hand's tremor is far above the IMU's noise), motors stopped and propellers off; the IMU is an
//! ICM-42688-P or better (a noisier part fails the noise line by design: its figures are the
//! ones the estimators were tuned for); the board is anywhere on Earth (gravity 9.78–9.83 m/s²)
//! in any orientation (only the magnitude of gravity is checked). The checks are pure functions
//! of what the board reports ([`imu_line`], [`flash_line`], …), tested on their own; [`run`]
//! gathers the reports over a [`Client`].

use crate::link::{Client, LinkError};
use protocol::{
    BoardHealth, CompassHealth, CompassSensor, CompassState, ConfigOrigin, ConfigStatus,
    GnssHealth, GnssInterface, GnssState, ImuDriverState, Info, MotorLinkHealth, Reply, Request,
    SensorHealth, SetTelemetryRate, Telemetry, Topic, MAX_MOTORS, PROTOCOL_VERSION,
};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

/// The ICM-42688-P gyroscope's noise spectral density, °/s/√Hz: 2.8 mdps/√Hz, low-noise mode
/// (TDK InvenSense, ICM-42688-P datasheet DS-000347, "Features": "Gyroscope Noise:
/// 2.8 mdps/√Hz").
pub const GYRO_NOISE_DENSITY_DPS_PER_SQRT_HZ: f64 = 0.0028;
/// The ICM-42688-P accelerometer's noise spectral density, mg/√Hz: 70 µg/√Hz, low-noise mode
/// (datasheet DS-000347, "Features": "Accelerometer Noise: 70 µg/√Hz").
pub const ACCEL_NOISE_DENSITY_MG_PER_SQRT_HZ: f64 = 0.070;
/// The ICM-42688-P gyroscope's zero-rate output tolerance, °/s: ±0.5 °/s at 25 °C (datasheet
/// DS-000347, gyroscope specifications, "ZRO initial tolerance", typical).
pub const GYRO_ZERO_RATE_OFFSET_DPS: f64 = 0.5;
/// The ICM-42688-P accelerometer's zero-g offset, mg: ±20 mg (datasheet DS-000347,
/// accelerometer specifications, "Initial tolerance, board-level", typical).
pub const ACCEL_ZERO_G_OFFSET_MG: f64 = 20.0;
/// The ICM-42688-P accelerometer's sensitivity tolerance, fraction: ±0.5 % (datasheet
/// DS-000347, accelerometer specifications, "Initial tolerance", typical).
pub const ACCEL_SENSITIVITY_TOLERANCE: f64 = 0.005;

/// How far above the datasheet's noise a board at rest may read before it is "noisy", ×: a board
/// on a bench picks up a desk's and a fan's vibration, and the board's filters (the IMU's
/// anti-alias filter at 997 Hz, the mean of four 8 kHz samples) shape the noise differently from
/// the ideal brick-wall band the expected figure assumes. A sensor 30× too noisy (a cracked
/// part, a loose board, a running motor) is far beyond it.
pub const NOISE_MARGIN: f64 = 5.0;
/// Largest gyro offset at rest, °/s per axis: twice the datasheet's zero-rate tolerance, for
/// the shift that soldering and board stress add. A craft that moves during the check reads
/// as an offset too.
pub const GYRO_OFFSET_LIMIT_DPS: f64 = 2.0 * GYRO_ZERO_RATE_OFFSET_DPS;
/// Standard gravity, m/s².
pub const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;
/// How far the magnitude of the specific force at rest may be from [`STANDARD_GRAVITY_MPS2`],
/// m/s²: the accelerometer's zero-g offset along gravity (20 mg = 0.196 m/s²), its
/// sensitivity tolerance (0.5 % of 1 g = 0.049 m/s²) and gravity's variation over the Earth
/// (9.780 m/s² at the equator to 9.832 m/s² at the poles: 0.03 m/s² from standard), summed:
/// 0.275, rounded up to 0.3 m/s².
pub const GRAVITY_TOLERANCE_MPS2: f64 = 0.3;
/// How long the IMU is watched at rest, s of board time: 2,000 samples at 2 kHz, so the noise's
/// standard deviation is known to about 2 % and the mean to well under the offset limits.
pub const IMU_WINDOW_S: f64 = 1.0;
/// Fewest IMU samples per control step the board must count during the window: a healthy IMU
/// delivers one per step; a sensor that drops more than one in twenty is failing.
pub const MIN_IMU_DELIVERY: f64 = 0.95;

/// The command each motor is spun at, δ: low enough to be safe with the propellers off, high
/// enough that every ESC starts the motor (ESCs start from about 3–5 %).
pub const SPIN_COMMAND: f32 = 0.08;
/// How long each motor is spun, s of board time: an ESC starts a motor in 0.1–0.3 s and the speed
/// settles within a few time constants (20–60 ms) after that.
pub const SPIN_S: f64 = 1.0;
/// The end of each spin that is averaged, s: the speed has settled by then.
pub const SPIN_SETTLED_S: f64 = 0.3;
/// Pause between two motors, s: the previous motor coasts down (no propeller: little drag).
pub const SPIN_PAUSE_S: f64 = 0.5;
/// Rate of the `motors` telemetry during the spin test, Hz (30 samples in the settled window).
pub const SPIN_TELEMETRY_HZ: u16 = 100;
/// Slowest speed that counts as turning, rad/s (about 290 rpm): a motor at 8 % turns at
/// hundreds to thousands of rad/s (a 2300 KV motor on 4S: about 300 rad/s above its idle).
pub const MIN_SPIN_RAD_S: f64 = 30.0;
/// How much faster than every other motor the spun motor must turn, ×: the others are sent motor
/// stop and stand still, or at most idle (an ESC that idles when armed turns at well under half
/// of its speed at 8 %).
pub const SPIN_DOMINANCE: f64 = 2.0;
/// Largest share of rejected speed reports per motor (bad GCR code, CRC or no answer) before the
/// ESC's signal is suspect.
pub const MAX_SPEED_REPORT_ERRORS: f64 = 0.05;
/// Largest share of rejected receiver frames.
pub const MAX_RECEIVER_FRAME_ERRORS: f64 = 0.01;

/// What a line concluded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Checked and as it should be.
    Pass,
    /// Checked and wrong: the advice says what to do.
    Fail,
    /// Not a check that can fail here (a board without a receiver).
    Info,
    /// Not run (no permission to spin the motors).
    Skipped,
}

impl Verdict {
    fn word(self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Fail => "FAIL",
            Verdict::Info => "info",
            Verdict::Skipped => "skip",
        }
    }
}

/// One line of the report.
#[derive(Clone, Debug, PartialEq)]
pub struct Line {
    /// Short name: link, imu, flash, receiver, esc, spin.
    pub name: &'static str,
    /// What was checked, in words.
    pub checked: &'static str,
    pub verdict: Verdict,
    /// What was found, with units.
    pub found: String,
    /// What to do (on a failure, or how to run a skipped check).
    pub advice: Option<String>,
}

impl Line {
    /// Whether this line does not fail the check (a pass, information, or skipped).
    pub fn ok(&self) -> bool {
        self.verdict != Verdict::Fail
    }

    /// The line for people: verdict, what was checked, what was found; the advice below it.
    pub fn text(&self) -> String {
        let mut out = format!("[{}] {}: {}\n", self.verdict.word(), self.checked, self.found);
        if let Some(advice) = &self.advice {
            out.push_str(&format!("       → {advice}\n"));
        }
        out
    }

    /// The line for programs.
    pub fn json(&self) -> Value {
        json!({
            "name": self.name,
            "checked": self.checked,
            "ok": self.ok(),
            "verdict": format!("{:?}", self.verdict).to_lowercase(),
            "found": self.found,
            "advice": self.advice,
        })
    }
}

/// A line that informs and neither passes nor fails (something optional not there, or not set up
/// yet).
fn info_line(name: &'static str, checked: &'static str, found: String) -> Line {
    Line { name, checked, verdict: Verdict::Info, found, advice: None }
}

fn line(name: &'static str, checked: &'static str, failures: Vec<String>, found: String) -> Line {
    let verdict = if failures.is_empty() { Verdict::Pass } else { Verdict::Fail };
    let advice = (!failures.is_empty()).then(|| failures.join("; "));
    Line { name, checked, verdict, found, advice }
}

// ---------------------------------------------------------------------------------------------
// 1. Link and identity
// ---------------------------------------------------------------------------------------------

const LINK_CHECKED: &str = "link and identity (handshake)";

/// Line 1 from the handshake's [`Info`], whether both sides share the message table, and whether
/// the craft is armed.
pub fn link_line(info: &Info, schema_matches: bool, armed: bool) -> Line {
    let found = format!(
        "{} serial {}, firmware {}.{}.{}, protocol {}.{} (this configurator {}.{}), {} motors, \
         control at {} Hz{}",
        info.board,
        info.serial,
        info.firmware.major,
        info.firmware.minor,
        info.firmware.patch,
        info.protocol.major,
        info.protocol.minor,
        PROTOCOL_VERSION.major,
        PROTOCOL_VERSION.minor,
        info.motor_count,
        info.control_rate_hz,
        if armed { "; ARMED" } else { "" }
    );
    let mut failures = Vec::new();
    if !schema_matches {
        failures.push(
            "the board's message table differs from this configurator's: flash the firmware \
             and use the configurator of the same release (`cargo xtask flash`)"
                .to_string(),
        );
    }
    if armed {
        failures.push(
            "the craft is armed: `configurator-cli disarm`, put it on a bench and run the check \
             again (nothing was spun)"
                .to_string(),
        );
    }
    line("link", LINK_CHECKED, failures, found)
}

// ---------------------------------------------------------------------------------------------
// 2. IMU
// ---------------------------------------------------------------------------------------------

const IMU_CHECKED: &str = "IMU at rest (driver, noise, offset, gravity)";

/// Running mean and variance of a three-axis signal (Welford's algorithm, f64).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisStats {
    /// Samples added.
    pub count: u64,
    mean: [f64; 3],
    m2: [f64; 3],
}

impl AxisStats {
    /// Add one sample.
    pub fn push(&mut self, x: [f32; 3]) {
        self.count += 1;
        let n = self.count as f64;
        for ((value, mean), m2) in x.iter().zip(&mut self.mean).zip(&mut self.m2) {
            let value = f64::from(*value);
            let delta = value - *mean;
            *mean += delta / n;
            *m2 += delta * (value - *mean);
        }
    }

    /// The mean per axis.
    pub fn mean(&self) -> [f64; 3] {
        self.mean
    }

    /// The standard deviation per axis (0 with fewer than two samples).
    pub fn std(&self) -> [f64; 3] {
        if self.count < 2 {
            return [0.0; 3];
        }
        self.m2.map(|m2| (m2 / (self.count - 1) as f64).sqrt())
    }
}

/// What the IMU delivered during the window.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImuWindow {
    /// The driver's state ([`BoardHealth::imu`]), when the board reports it.
    pub driver: Option<ImuDriverState>,
    /// Rate of the samples, Hz (one per control step).
    pub rate_hz: f64,
    /// Control steps during the window, counted by the board.
    pub steps: u64,
    /// IMU samples during the window, counted by the board.
    pub delivered: u64,
    /// Angular rate, rad/s.
    pub gyro: AxisStats,
    /// Specific force, m/s².
    pub accel: AxisStats,
    /// Whether every sample received repeated the first one bit for bit.
    pub all_identical: bool,
    /// Samples missing from the stream (gaps in the topic's sequence numbers: lost on the link,
    /// or a step without an IMU sample): the statistics use the others.
    pub gaps: u64,
}

impl ImuWindow {
    /// The noise bandwidth of the samples, Hz: half their rate (the board averages its 8 kHz
    /// samples to the control rate behind a 997 Hz anti-alias filter, so no more noise than
    /// this band's reaches them).
    pub fn bandwidth_hz(&self) -> f64 {
        self.rate_hz / 2.0
    }

    /// The gyro noise a datasheet part shows at this bandwidth, °/s RMS.
    pub fn expected_gyro_noise_dps(&self) -> f64 {
        GYRO_NOISE_DENSITY_DPS_PER_SQRT_HZ * self.bandwidth_hz().sqrt()
    }

    /// The accelerometer noise a datasheet part shows at this bandwidth, mg RMS.
    pub fn expected_accel_noise_mg(&self) -> f64 {
        ACCEL_NOISE_DENSITY_MG_PER_SQRT_HZ * self.bandwidth_hz().sqrt()
    }
}

/// Line 2 from what the IMU delivered at rest.
pub fn imu_line(window: &ImuWindow) -> Line {
    let driver_fault = match window.driver {
        Some(ImuDriverState::NotFitted) => Some(
            "the firmware has no IMU driver for this board: flash the firmware built for it"
                .to_string(),
        ),
        Some(ImuDriverState::WrongIdentity { expected, found }) => Some(format!(
            "the IMU answered identity 0x{found:02x}, not the ICM-42688-P's 0x{expected:02x}: 0x00 \
             or 0xff is no answer (check the IMU's 3.3 V supply, its chip select and the SPI \
             wiring); another value is another part, which this firmware does not drive"
        )),
        Some(ImuDriverState::ConfigMismatch { register, written, read }) => Some(format!(
            "IMU register 0x{register:02x} read back 0x{read:02x} after 0x{written:02x}: the SPI \
             link corrupts data (check the SPI clock and wiring) or the part is damaged"
        )),
        Some(ImuDriverState::BusError) => Some(
            "the SPI bus reported an error talking to the IMU: check the wiring, or the board \
             is damaged"
                .to_string(),
        ),
        Some(ImuDriverState::Running | ImuDriverState::Simulated) | None => None,
    };
    let driver = match window.driver {
        Some(ImuDriverState::Running) => "driver running",
        Some(ImuDriverState::Simulated) => "simulated IMU",
        Some(ImuDriverState::NotFitted) => "no IMU driver",
        Some(_) => "driver FAULT",
        None => "driver state not reported",
    };
    let samples = window.gyro.count;
    let delivery =
        if window.steps > 0 { window.delivered as f64 / window.steps as f64 } else { 0.0 };
    if samples == 0 || window.delivered == 0 {
        let mut failures = Vec::from_iter(driver_fault);
        failures.push(
            "the IMU is silent (no samples): check its supply, SPI wiring and data-ready \
             interrupt (INT1); on a finished board, the board is faulty"
                .to_string(),
        );
        let found = format!("{driver}; SILENT: no samples in {IMU_WINDOW_S:.1} s");
        return line("imu", IMU_CHECKED, failures, found);
    }
    let mut failures = Vec::from_iter(driver_fault);
    let gyro_noise_dps = max_abs(window.gyro.std()).to_degrees();
    let gyro_offset_dps = max_abs(window.gyro.mean()).to_degrees();
    let accel_noise_mg = max_abs(window.accel.std()) / STANDARD_GRAVITY_MPS2 * 1000.0;
    let gravity_mps2 = norm(window.accel.mean());
    let gyro_limit_dps = NOISE_MARGIN * window.expected_gyro_noise_dps();
    let accel_limit_mg = NOISE_MARGIN * window.expected_accel_noise_mg();
    let found = if window.all_identical {
        format!("{driver}; FROZEN: all {samples} samples identical bit for bit")
    } else {
        format!(
            "{driver}; {samples} samples at {:.0} Hz{} ({:.1} % of control steps); gyro noise \
             {gyro_noise_dps:.3} °/s RMS (limit {gyro_limit_dps:.3} at {:.0} Hz), offset \
             {gyro_offset_dps:.3} °/s (limit {GYRO_OFFSET_LIMIT_DPS:.1}); accelerometer noise \
             {accel_noise_mg:.2} mg RMS (limit {accel_limit_mg:.2}), |f| {gravity_mps2:.3} m/s² \
             ({STANDARD_GRAVITY_MPS2:.2} ± {GRAVITY_TOLERANCE_MPS2:.1})",
            window.rate_hz,
            if window.gaps > 0 {
                format!(", {} missing from the stream", window.gaps)
            } else {
                String::new()
            },
            100.0 * delivery,
            window.bandwidth_hz()
        )
    };
    if delivery < MIN_IMU_DELIVERY {
        failures.push(format!(
            "the IMU delivered a sample in only {:.1} % of control steps (at least {:.0} % \
             expected): check its data-ready interrupt (INT1) and SPI wiring",
            100.0 * delivery,
            100.0 * MIN_IMU_DELIVERY
        ));
    }
    if window.all_identical {
        failures.push(
            "the IMU repeats one sample (a stuck sensor or a stale read): power-cycle the board; \
             if it persists the IMU is faulty"
                .to_string(),
        );
        return line("imu", IMU_CHECKED, failures, found);
    }
    let noisy = gyro_noise_dps > gyro_limit_dps || accel_noise_mg > accel_limit_mg;
    if noisy {
        failures.push(format!(
            "NOISY: more than {NOISE_MARGIN:.0}× the ICM-42688-P's noise ({:.3} °/s, {:.2} mg \
             RMS at {:.0} Hz): stand the craft still on a bench (not in a hand), motors stopped; \
             if it was still, check that the board is mounted firmly and nothing near it \
             vibrates, else the IMU is damaged",
            window.expected_gyro_noise_dps(),
            window.expected_accel_noise_mg(),
            window.bandwidth_hz()
        ));
    }
    if gyro_offset_dps > GYRO_OFFSET_LIMIT_DPS && !noisy {
        failures.push(format!(
            "the gyro reads {gyro_offset_dps:.2} °/s at rest, more than twice the datasheet's \
             ±{GYRO_ZERO_RATE_OFFSET_DPS} °/s: keep the craft still during the check; if it was \
             still, the gyro is damaged (board stress, a drop)"
        ));
    }
    if (gravity_mps2 - STANDARD_GRAVITY_MPS2).abs() > GRAVITY_TOLERANCE_MPS2 && !noisy {
        failures.push(format!(
            "the accelerometer reads {gravity_mps2:.3} m/s² at rest, not 1 g (the datasheet's \
             ±{ACCEL_ZERO_G_OFFSET_MG:.0} mg offset and ±{:.1} % sensitivity allow \
             ±{GRAVITY_TOLERANCE_MPS2} m/s²): keep the craft still; a stored accelerometer bias \
             (`get acc_bias_mps2`) that is wrong shows here too; else the accelerometer is damaged",
            100.0 * ACCEL_SENSITIVITY_TOLERANCE
        ));
    }
    line("imu", IMU_CHECKED, failures, found)
}

fn max_abs(v: [f64; 3]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

fn norm(v: [f64; 3]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

// ---------------------------------------------------------------------------------------------
// 3. Flash
// ---------------------------------------------------------------------------------------------

const FLASH_CHECKED: &str = "configuration flash (read at start-up)";

/// Line 3 from the configuration store's state (`None`: the board did not report it).
pub fn flash_line(config: Option<&ConfigStatus>) -> Line {
    let Some(config) = config else {
        return line(
            "flash",
            FLASH_CHECKED,
            vec!["the board does not report its configuration store: update its firmware".into()],
            "no answer to the configuration request".into(),
        );
    };
    let unsaved = if config.unsaved_changes { "; unsaved changes in force" } else { "" };
    let mut failures = Vec::new();
    let origin = match config.origin {
        ConfigOrigin::Loaded => "configuration loaded from flash".to_string(),
        ConfigOrigin::Defaults => {
            "nothing stored yet: the defaults are in force (the first `save` writes it)".into()
        }
        ConfigOrigin::UnknownLayout { version } => {
            failures.push(format!(
                "the flash holds a configuration of layout {version}, written by a newer \
                 firmware: flash that firmware again, or `save` to replace it with this \
                 firmware's (layout {})",
                config.layout_version
            ));
            format!("UNKNOWN LAYOUT {version}: the defaults are in force")
        }
        ConfigOrigin::Unreadable => {
            failures.push(
                "the stored configuration could not be read: `save` writes it again; if `save` \
                 fails, or this line fails again after `reboot`, the flash is damaged (replace \
                 the board)"
                    .into(),
            );
            "UNREADABLE: the defaults are in force".into()
        }
        ConfigOrigin::NoStore => {
            failures.push(
                "this board has no configuration store: calibrations and identifications are \
                 lost at power-off (a SITL started with --no-flash; on a board, a firmware \
                 built without its flash store)"
                    .into(),
            );
            "NO STORE".into()
        }
    };
    if config.rejected_at_load > 0 {
        failures.push(format!(
            "{} stored values were outside their range and took their defaults: `diff` shows \
             what is in force; set them again and `save`",
            config.rejected_at_load
        ));
    }
    let found = format!(
        "{origin} ({} parameters, layout {}, {} rejected at load){unsaved}",
        config.param_count, config.layout_version, config.rejected_at_load
    );
    line("flash", FLASH_CHECKED, failures, found)
}

// ---------------------------------------------------------------------------------------------
// 4. Receiver
// ---------------------------------------------------------------------------------------------

const RECEIVER_CHECKED: &str = "radio receiver (frames, errors, link quality)";

/// Line 4 from the board's hardware report (`None`: the board did not answer the request).
pub fn receiver_line(board: Option<&BoardHealth>) -> Line {
    let Some(receiver) = board.and_then(|b| b.receiver) else {
        return Line {
            name: "receiver",
            checked: RECEIVER_CHECKED,
            verdict: Verdict::Info,
            found: "no receiver: the craft is commanded over its USB or telemetry link only".into(),
            advice: None,
        };
    };
    let found = format!(
        "CRSF, {}; {} frames, {} rejected; link quality {} %, RSSI {} dBm",
        if receiver.link_up { "link up" } else { "NO SIGNAL" },
        receiver.frames,
        receiver.frame_errors,
        receiver.link_quality_pct,
        receiver.rssi_dbm
    );
    let mut failures = Vec::new();
    if receiver.frames == 0 {
        failures.push(
            "no frame ever arrived: check the receiver's supply, its TX wire to the board's RX \
             (and RX to TX), the UART the firmware expects, that the receiver is bound and the \
             transmitter on"
                .to_string(),
        );
    } else if !receiver.link_up {
        failures.push(
            "frames arrived but the link is down now: switch the transmitter on and keep it \
             near; check the binding"
                .to_string(),
        );
    }
    let total = f64::from(receiver.frames) + f64::from(receiver.frame_errors);
    if total > 0.0 && f64::from(receiver.frame_errors) / total > MAX_RECEIVER_FRAME_ERRORS {
        failures.push(format!(
            "{:.1} % of frames were rejected (at most {:.0} % expected): check the wiring and the \
             baud rate (CRSF: 420,000 baud), and keep the receiver's wires away from the ESCs",
            100.0 * f64::from(receiver.frame_errors) / total,
            100.0 * MAX_RECEIVER_FRAME_ERRORS
        ));
    }
    line("receiver", RECEIVER_CHECKED, failures, found)
}

// ---------------------------------------------------------------------------------------------
// 4. GNSS
// ---------------------------------------------------------------------------------------------

const GNSS_CHECKED: &str = "GNSS receiver (found, configured, fix and accuracy)";

/// The fix type of a 3D fix in NAV-PVT (u-blox: 3 = 3D, 4 = GNSS and dead reckoning).
const FIX_3D: u8 = 3;
/// The same with dead reckoning.
const FIX_GNSS_DEAD_RECKONING: u8 = 4;

/// The GNSS line from the board's report (`None`: the board has no GNSS port, or its firmware
/// predates the report). Indoors a receiver finds no fix: that is information, not a failure.
pub fn gnss_line(gnss: Option<&GnssHealth>) -> Line {
    let info = |found: String| info_line("gnss", GNSS_CHECKED, found);
    let Some(gnss) = gnss else {
        return info(
            "no GNSS port: positions come from motion capture or a ground station only".into(),
        );
    };
    let interface = match gnss.interface {
        GnssInterface::ConfigurationKeys => "u-blox M9/M10 (configuration keys)",
        GnssInterface::LegacyMessages => "u-blox M8 (CFG messages)",
        GnssInterface::Unknown => "u-blox (configuration not acknowledged)",
    };
    match gnss.state {
        GnssState::Searching => info(format!(
            "no receiver answering (trying {} baud; every rate from 9,600 to 921,600 is \
             tried): for flying outdoors connect a u-blox M8/M9/M10 to the GNSS pads, its TX to \
             the board's RX",
            gnss.baud
        )),
        GnssState::Configuring => {
            info(format!("receiver found, configuring it to {} baud", gnss.baud))
        }
        GnssState::Lost => line(
            "gnss",
            GNSS_CHECKED,
            vec!["the receiver stopped sending solutions for more than a second: check its \
             supply and its TX wire to the board's RX; the firmware searches for it again"
                .into()],
            format!("{interface}, lost; {} fixes taken before", gnss.fixes),
        ),
        GnssState::Receiving => {
            let found = format!(
                "{interface} at {} baud; fix type {}, {} satellites; accuracy {:.2} m \
                 horizontal, {:.2} m vertical, {:.2} m/s; {} fixes taken, {} without a fix, {} \
                 frames with a bad checksum",
                gnss.baud,
                gnss.fix_type,
                gnss.satellites,
                gnss.horizontal_accuracy_m,
                gnss.vertical_accuracy_m,
                gnss.speed_accuracy_mps,
                gnss.fixes,
                gnss.without_fix,
                gnss.checksum_errors
            );
            if matches!(gnss.fix_type, FIX_3D | FIX_GNSS_DEAD_RECKONING) {
                line("gnss", GNSS_CHECKED, Vec::new(), found)
            } else {
                info(format!(
                    "{found}: no 3D fix yet (normal indoors; outdoors give it a view of the sky \
                     and a minute)"
                ))
            }
        }
    }
}

const COMPASS_CHECKED: &str = "compass (I²C magnetometer: found, rate, field, calibrated)";

/// The compass line from the board's report (`None`: no compass bus, or a firmware before
/// protocol 1.17). No compass, or one not calibrated yet, is information: the compass is for
/// the heading outdoors. A sensor lost, stuck or saturated fails.
pub fn compass_line(compass: Option<&CompassHealth>) -> Line {
    let info = |found: String| info_line("compass", COMPASS_CHECKED, found);
    let Some(compass) = compass else {
        return info(
            "no compass bus: the heading comes from motion capture or the GNSS track".into(),
        );
    };
    let sensor = match compass.sensor {
        CompassSensor::Ist8310 => "IST8310",
        CompassSensor::Qmc5883l => "QMC5883L",
        CompassSensor::None => "none",
    };
    let calibrated = if compass.calibrated {
        "calibrated".to_string()
    } else {
        "not calibrated: run `configurator-cli compass calibrate`".to_string()
    };
    let found = format!(
        "{sensor} at 0x{:02X}, {:.0} Hz, field {:.1} µT, {calibrated}{}",
        compass.address,
        compass.rate_hz,
        compass.field_ut,
        if compass.enabled { "" } else { " (compass_enabled = 0: not used)" }
    );
    match compass.state {
        CompassState::Absent => info(
            "no compass found at 0x0C, 0x0D or 0x0E: for a heading outdoors connect the GNSS mast's SCL and SDA to the board's I²C pads"
                .into(),
        ),
        CompassState::Lost => line(
            "compass",
            COMPASS_CHECKED,
            vec![format!(
                "the compass stopped answering ({} times since start-up): check its SCL and SDA wires and its supply; the board probes for it every second",
                compass.lost
            )],
            "lost".into(),
        ),
        CompassState::Stuck => line(
            "compass",
            COMPASS_CHECKED,
            vec!["the compass repeats the same reading: it stopped converting; power it off and on"
                .into()],
            found,
        ),
        CompassState::Saturated => line(
            "compass",
            COMPASS_CHECKED,
            vec!["the field is beyond the sensor's range: a magnet, a speaker or a power wire next to it; move the mast away"
                .into()],
            found,
        ),
        CompassState::Starting | CompassState::Healthy if !compass.calibrated => info(found),
        CompassState::Starting | CompassState::Healthy => line("compass", COMPASS_CHECKED, Vec::new(), found),
    }
}

// ---------------------------------------------------------------------------------------------
// 5. Battery
// ---------------------------------------------------------------------------------------------

const BATTERY_CHECKED: &str = "battery (voltage per cell, current at rest)";

/// Lowest voltage a lithium cell at rest reads while healthy, V: discharged to 3.0 V it is
/// damaged (LiPo makers' absolute minimum); a reading lower per counted cell is a divider scale
/// set too low.
pub const MIN_REST_CELL_V: f32 = 3.0;
/// Highest, V: a high-voltage LiPo's full charge, 4.35 V, plus 0.05 V for the divider's error; a
/// reading higher is a divider scale set too high.
pub const MAX_REST_CELL_V: f32 = 4.4;
/// Most current the board may draw with the motors stopped, A: a flight controller, receiver,
/// camera and video transmitter draw 0.3–1.5 A from a 4S pack; 3 A is a current sensor's scale
/// or offset set wrong (or something shorted).
pub const MAX_REST_CURRENT_A: f32 = 3.0;
/// Most negative current a sensor at rest may read, A: a small offset; below it, the sensor's
/// offset is set wrong.
pub const MIN_REST_CURRENT_A: f32 = -0.5;

/// Line 5 from the board's battery report (`None`: the board measures none, or predates
/// protocol 1.11).
pub fn battery_line(battery: Option<&protocol::BatteryStatus>) -> Line {
    let info = |found: String| Line {
        name: "battery",
        checked: BATTERY_CHECKED,
        verdict: Verdict::Info,
        found,
        advice: None,
    };
    let Some(battery) = battery else {
        return info("the board measures no battery".into());
    };
    use firmware::app::battery::{Pack, SETTLE_S};
    let cells = match Pack::of(battery) {
        Pack::Absent => {
            return info(format!(
                "no pack connected ({:.2} V at the divider: powered over USB); connect one to \
                 check the voltage and current scales",
                battery.voltage_v
            ))
        }
        Pack::Settling => {
            return info(format!(
                "{:.2} V, cells not counted yet (the pack settles for {SETTLE_S} s): run the \
                 check again",
                battery.voltage_v
            ))
        }
        Pack::Cells(cells) => cells,
    };
    let cell_v = battery.voltage_v / f32::from(cells);
    // A divider's scale that is wrong by a cell's worth or more shows as a wrong cell count,
    // which only the builder knows: said in the line.
    let found = format!(
        "{}S {:.2} V ({:.2} V a cell), {:.2} A with the motors stopped (a pack of another cell \
         count means the voltage divider is not the board file's)",
        cells, battery.voltage_v, cell_v, battery.current_a
    );
    let mut failures = Vec::new();
    if !(MIN_REST_CELL_V..=MAX_REST_CELL_V).contains(&cell_v) {
        failures.push(format!(
            "{cell_v:.2} V a cell is outside what a lithium cell at rest reads ({MIN_REST_CELL_V}–{MAX_REST_CELL_V} V): measure the pack with a multimeter; if it differs, the board's voltage divider is not the one its board file assumes"
        ));
    }
    if !(MIN_REST_CURRENT_A..=MAX_REST_CURRENT_A).contains(&battery.current_a) {
        failures.push(format!(
            "{:.2} A with the motors stopped (a board draws 0.3–1.5 A): the current sensor's scale or offset is not the one the board file assumes, or something draws too much",
            battery.current_a
        ));
    }
    line("battery", BATTERY_CHECKED, failures, found)
}

// ---------------------------------------------------------------------------------------------
// 6. ESC speed reports
// ---------------------------------------------------------------------------------------------

const ESC_CHECKED: &str = "ESC speed reports (bidirectional DShot)";

/// What the board was told of its ESCs' speed reports, and what its firmware does without them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SpeedReports {
    /// `motor_bidir_dshot` = 0: the user says the ESCs cannot report their speed.
    pub off: bool,
    /// The firmware identifies the motors without speed reports
    /// (`Capabilities::IDENTIFIES_WITHOUT_SPEEDS`, protocol 1.13: every image built since
    /// issue 56, and the simulators; older board images had it only in a separate build).
    pub identifies_without: bool,
}

/// Where ESCs without bidirectional DShot are flown: this firmware, or, on an older one, the
/// current image (every image identifies without speeds since issue 56).
fn without_reports_advice(reports: SpeedReports) -> &'static str {
    if reports.identifies_without {
        "this firmware then identifies the motors from the commands"
    } else {
        "after updating the firmware (`cargo xtask flash`: every current image identifies the \
         motors from the commands)"
    }
}

/// Line 6 from the sensors' health (`None`: a board older than protocol 1.6), where the board
/// has a DShot link its per-motor report counters, and what it was told of the reports.
pub fn esc_line(
    health: Option<&SensorHealth>,
    link: Option<&MotorLinkHealth>,
    reports: SpeedReports,
) -> Line {
    if reports.off {
        let found = "speed reports off (`motor_bidir_dshot` = 0: ESCs without bidirectional \
                     DShot)";
        let (failures, found) = if reports.identifies_without {
            let found = format!(
                "{found}: throw-to-fly identifies the motors from the commands and the body's \
                 response (measured speeds, with bidirectional DShot, are the better path)"
            );
            (Vec::new(), found)
        } else {
            let failure = format!(
                "this firmware's throw-to-fly needs every motor's speed: ESCs with bidirectional \
                 DShot (BLHeli_32, Bluejay, AM32) and `set motor_bidir_dshot = 1`, `save`, \
                 `reboot`; or keep these ESCs {}",
                without_reports_advice(reports)
            );
            (vec![failure], found.to_string())
        };
        return line("esc", ESC_CHECKED, failures, found);
    }
    let Some(health) = health else {
        return line(
            "esc",
            ESC_CHECKED,
            vec![
                "the board does not report its motors' speeds (protocol 1.6): update its firmware"
                    .into(),
            ],
            "not reported".into(),
        );
    };
    let count = usize::from(health.motor_count).min(MAX_MOTORS);
    if count == 0 {
        return line(
            "esc",
            ESC_CHECKED,
            vec!["no motor outputs configured: check the firmware's airframe setup".into()],
            "no motors".into(),
        );
    }
    let silent: Vec<usize> =
        (0..count).filter(|&i| health.speeds_reported & (1 << i) == 0).collect();
    let mut failures = Vec::new();
    let mut found = if silent.is_empty() {
        format!(
            "all {count} motors report their speed (each within {} ms)",
            protocol::SPEED_REPORT_TIMEOUT_MS
        )
    } else {
        format!(
            "motor {} of 0–{} report{} NO speed (none within {} ms)",
            list(&silent),
            count - 1,
            if silent.len() == 1 { "s" } else { "" },
            protocol::SPEED_REPORT_TIMEOUT_MS
        )
    };
    if silent.len() == count {
        failures.push(format!(
            "no ESC answers: ESCs with bidirectional DShot (BLHeli_32, Bluejay, AM32) and \
             `set motor_bidir_dshot = 1`, `save`, `reboot`, since throw-to-fly needs every \
             motor's speed; ESCs without it: `set motor_bidir_dshot = 0`, `save`, `reboot`, {}",
            without_reports_advice(reports)
        ));
    } else if !silent.is_empty() {
        failures.push(format!(
            "check motor {}'s ESC: its signal wire and ground, its firmware (bidirectional \
             DShot: BLHeli_32, Bluejay, AM32), its power; the throw-to-fly identification \
             needs every motor's speed",
            list(&silent)
        ));
    }
    if let Some(link) = link {
        let bad: Vec<String> = (0..count)
            .filter_map(|i| {
                let total = f64::from(link.reports[i]) + f64::from(link.report_errors[i]);
                let share =
                    if total > 0.0 { f64::from(link.report_errors[i]) / total } else { 0.0 };
                (share > MAX_SPEED_REPORT_ERRORS).then(|| format!("{i}: {:.1} %", 100.0 * share))
            })
            .collect();
        if !bad.is_empty() {
            found.push_str(&format!("; reports rejected on motor {}", bad.join(", ")));
            failures.push(format!(
                "more than {:.0} % of a motor's speed reports were rejected: check that motor's \
                 signal wire and ground (short, away from the battery leads)",
                100.0 * MAX_SPEED_REPORT_ERRORS
            ));
        }
    }
    line("esc", ESC_CHECKED, failures, found)
}

fn list(items: &[usize]) -> String {
    items.iter().map(usize::to_string).collect::<Vec<_>>().join(", ")
}

// ---------------------------------------------------------------------------------------------
// 6. Motor spin
// ---------------------------------------------------------------------------------------------

const SPIN_CHECKED: &str = "each motor spun in turn, its speed on its own output";

/// What the motors reported while one of them was spun.
#[derive(Clone, Debug, PartialEq)]
pub struct Spin {
    /// The motor spun (index from 0).
    pub motor: u8,
    /// Whether the board's output showed the command during the spin.
    pub commanded: bool,
    /// Mean reported speed of every motor over the settled end of the spin, rad/s (`None`: no
    /// report).
    pub speeds_rad_s: Vec<Option<f64>>,
}

/// Line 6 from the spins, one per motor.
pub fn spin_line(spins: &[Spin]) -> Line {
    let mut failures = Vec::new();
    let mut found = Vec::new();
    let mut crossed = Vec::new();
    for spin in spins {
        let m = usize::from(spin.motor);
        let own = spin.speeds_rad_s.get(m).copied().flatten();
        let others = spin
            .speeds_rad_s
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != m)
            .filter_map(|(i, s)| s.map(|s| (i, s)));
        let fastest_other = others.fold(None, |best: Option<(usize, f64)>, (i, s)| match best {
            Some((_, b)) if b >= s => best,
            _ => Some((i, s)),
        });
        let others_text = match fastest_other {
            Some((_, s)) => format!("others ≤ {s:.0} rad/s"),
            None => "no other motor".into(),
        };
        if !spin.commanded {
            found.push(format!("motor {m}: NOT COMMANDED"));
            failures.push(format!(
                "the board did not drive output {m} (motor test refused or stopped): see \
                 `status`"
            ));
            continue;
        }
        let Some(own) = own else {
            found.push(format!("motor {m}: NO SPEED REPORT ({others_text})"));
            failures.push(format!(
                "motor {m} reports no speed, so its spin cannot be seen: fix the ESC speed \
                 reports first (the esc line)"
            ));
            continue;
        };
        let rpm = own * 60.0 / std::f64::consts::TAU;
        found.push(format!("motor {m}: {own:.0} rad/s ({rpm:.0} rpm), {others_text}"));
        match fastest_other {
            Some((other, s)) if s >= MIN_SPIN_RAD_S && s * SPIN_DOMINANCE > own => {
                crossed.push(format!("output {m} turned motor {other} ({s:.0} rad/s)"));
            }
            _ if own < MIN_SPIN_RAD_S => failures.push(format!(
                "motor {m} did not turn ({own:.0} rad/s at command {SPIN_COMMAND}): check its \
                 ESC's power and the motor's three phase wires, and that nothing blocks the bell"
            )),
            _ => {}
        }
    }
    if !crossed.is_empty() {
        failures.push(format!(
            "{}: the motor outputs and their speed reports are crossed; check that each ESC's \
             speed report comes back on its own output: the board definition's motor timer \
             channels and capture DMA (firmware/src/boards/), or, with a separate ESC telemetry \
             wire, which ESC it comes from",
            crossed.join(", ")
        ));
    }
    line("spin", SPIN_CHECKED, failures, found.join("; "))
}

/// Line 6 when the motors were not spun, saying why.
/// Line 7 where the ESCs report no speed (`motor_bidir_dshot` = 0): nothing to check the
/// outputs' order against, so the motors are not spun; a person watches them instead.
pub fn spin_without_reports() -> Line {
    Line {
        name: "spin",
        checked: SPIN_CHECKED,
        verdict: Verdict::Skipped,
        found: "not run: the ESCs report no speed (`motor_bidir_dshot` = 0), so no report can \
                show which motor turned"
            .into(),
        advice: Some(
            "with the propellers OFF, spin each motor in turn and watch which one turns and \
             which way: `configurator-cli motor-test --motor N`"
                .into(),
        ),
    }
}

pub fn spin_skipped(why: &str) -> Line {
    Line {
        name: "spin",
        checked: SPIN_CHECKED,
        verdict: Verdict::Skipped,
        found: format!("not run: {why}"),
        advice: Some(
            "with the propellers OFF, run `configurator-cli doctor` on a terminal and answer y, \
             or `doctor --yes`"
                .into(),
        ),
    }
}

// ---------------------------------------------------------------------------------------------
// Gathering the reports
// ---------------------------------------------------------------------------------------------

/// Whether the motors may be spun.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Consent {
    /// Propellers are off: spin.
    Yes,
    /// The person said no.
    No,
    /// Nobody to ask (not a terminal) and no `--yes`.
    NoTerminal,
}

/// Run the eight checks on a connected board, handing each line to `report` as it is done;
/// `consent` is asked just before the motors would spin. Returns every line.
pub fn run(
    client: &mut Client,
    report: &mut dyn FnMut(&Line),
    consent: &mut dyn FnMut() -> Consent,
) -> Result<Vec<Line>, LinkError> {
    let mut lines = Vec::new();
    let mut emit = |line: Line, lines: &mut Vec<Line>| {
        report(&line);
        lines.push(line);
    };
    let status = status(client)?;
    let schema_matches = client.schema_matches();
    let armed = status.armed;
    emit(link_line(&client.info, schema_matches, armed), &mut lines);

    let board = match optional(client, Request::GetBoard(()), "the board request")? {
        Some(Reply::Board(board)) => Some(board),
        _ => None,
    };
    let window = imu_window(client, board.as_ref().map(|b| b.imu))?;
    emit(imu_line(&window), &mut lines);

    let config = match client.request(&Request::GetConfig(()), "the configuration request") {
        Ok(Reply::Config(config)) => Some(config),
        Ok(_) | Err(LinkError::Device(_)) => None,
        Err(error) => return Err(error),
    };
    emit(flash_line(config.as_ref()), &mut lines);
    emit(receiver_line(board.as_ref()), &mut lines);
    let gnss = match optional(client, Request::GetGnss(()), "the GNSS request")? {
        Some(Reply::Gnss(gnss)) => Some(gnss),
        _ => None,
    };
    emit(gnss_line(gnss.as_ref()), &mut lines);
    let compass = match optional(client, Request::GetCompass(()), "the compass request")? {
        Some(Reply::Compass(compass)) => Some(compass),
        _ => None,
    };
    emit(compass_line(compass.as_ref()), &mut lines);
    let battery = match optional(client, Request::GetBattery(()), "the battery request")? {
        Some(Reply::Battery(battery)) => Some(battery),
        _ => None,
    };
    emit(battery_line(battery.as_ref()), &mut lines);

    let health = match optional(client, Request::GetHealth(()), "the health request")? {
        Some(Reply::Health(health)) => Some(health),
        _ => None,
    };
    let reports = SpeedReports {
        off: speed_reports_off(client)?,
        identifies_without: client
            .info
            .capabilities
            .has(protocol::Capabilities::IDENTIFIES_WITHOUT_SPEEDS),
    };
    let motors = board.as_ref().and_then(|b| b.motors.as_ref());
    emit(esc_line(health.as_ref(), motors, reports), &mut lines);

    let spin = if armed {
        spin_skipped("the craft is armed")
    } else if client.info.motor_count == 0 {
        spin_skipped("no motors")
    } else if reports.off {
        spin_without_reports()
    } else {
        match consent() {
            Consent::Yes => spin_line(&spin_motors(client)?),
            Consent::No => spin_skipped("you did not confirm that the propellers are off"),
            Consent::NoTerminal => {
                spin_skipped("no terminal to ask whether the propellers are off")
            }
        }
    };
    emit(spin, &mut lines);
    Ok(lines)
}

fn status(client: &mut Client) -> Result<protocol::Status, LinkError> {
    match client.request(&Request::GetStatus(()), "the status request")? {
        Reply::Status(status) => Ok(status),
        other => Err(LinkError::Unexpected(format!("{other:?} to the status request"))),
    }
}

/// Whether the user told the board that its ESCs report no speed (`motor_bidir_dshot` = 0);
/// false where the board has no such parameter.
pub fn speed_reports_off(client: &mut Client) -> Result<bool, LinkError> {
    let name = protocol::ParamRef::Name(protocol::text("motor_bidir_dshot"));
    match optional(client, Request::GetParam(name), "the parameter request")? {
        Some(Reply::Param(info)) => Ok(info.value.first() == Some(&0.0)),
        _ => Ok(false),
    }
}

/// A request an older board may not know: `None` when it answers with a device error.
fn optional(
    client: &mut Client,
    request: Request,
    what: &'static str,
) -> Result<Option<Reply>, LinkError> {
    match client.request(&request, what) {
        Ok(reply) => Ok(Some(reply)),
        Err(LinkError::Device(_)) => Ok(None),
        Err(error) => Err(error),
    }
}

fn set_rate(client: &mut Client, topic: Topic, rate_hz: u16) -> Result<(), LinkError> {
    let request = Request::SetTelemetryRate(SetTelemetryRate { topic, rate_hz });
    client.request(&request, "the telemetry rate request").map(|_| ())
}

/// Listen to `topic` until `board_s` of board time have passed in its samples, or `wall` has
/// elapsed (a silent topic), handing each sample to `on_sample`. Returns the samples lost on the
/// way (gaps in the sequence numbers).
fn listen_for(
    client: &mut Client,
    topic: Topic,
    board_s: f64,
    wall: Duration,
    mut on_sample: impl FnMut(&Telemetry),
) -> Result<u64, LinkError> {
    let started = Instant::now();
    let mut first_us: Option<u64> = None;
    let mut last_us = 0u64;
    let (mut previous_seq, mut lost) = (None::<u16>, 0u64);
    while started.elapsed() < wall {
        let mut done = false;
        client.listen_with(Duration::from_millis(20), |sample| {
            if crate::record::topic_of(&sample.data) != topic {
                return;
            }
            if let Some(previous) = previous_seq {
                lost += u64::from(sample.seq.wrapping_sub(previous).wrapping_sub(1));
            }
            previous_seq = Some(sample.seq);
            let t_us = crate::record::time_us(&sample.data);
            let first = *first_us.get_or_insert(t_us);
            last_us = t_us;
            if (last_us.saturating_sub(first)) as f64 * 1e-6 >= board_s {
                done = true;
            }
            on_sample(&sample.data);
        })?;
        if done {
            break;
        }
    }
    Ok(lost)
}

/// Extra wall-clock time a window may take beyond its board time before the topic counts as
/// silent, s (the link's latency and a host that runs the SITL slower than real time).
const WALL_SLACK_S: f64 = 2.0;

fn imu_window(client: &mut Client, driver: Option<ImuDriverState>) -> Result<ImuWindow, LinkError> {
    let rate_hz = client.info.control_rate_hz.clamp(1, protocol::MAX_TELEMETRY_RATE_HZ);
    let before = status(client)?;
    set_rate(client, Topic::Imu, rate_hz)?;
    client.telemetry.clear();
    let mut window = ImuWindow { driver, rate_hz: f64::from(rate_hz), ..ImuWindow::default() };
    let mut first: Option<([f32; 3], [f32; 3])> = None;
    let mut identical = true;
    let wall = Duration::from_secs_f64(IMU_WINDOW_S + WALL_SLACK_S);
    window.gaps = listen_for(client, Topic::Imu, IMU_WINDOW_S, wall, |data| {
        if let Telemetry::Imu(imu) = data {
            let sample = (imu.gyro_rad_s, imu.accel_mps2);
            let first = *first.get_or_insert(sample);
            identical &= bits(first) == bits(sample);
            window.gyro.push(imu.gyro_rad_s);
            window.accel.push(imu.accel_mps2);
        }
    })?;
    set_rate(client, Topic::Imu, 0)?;
    let after = status(client)?;
    window.steps = u64::from(after.control.steps.wrapping_sub(before.control.steps));
    window.delivered = u64::from(after.imu.samples.wrapping_sub(before.imu.samples));
    window.all_identical = identical && window.gyro.count > 1;
    Ok(window)
}

fn bits((gyro, accel): ([f32; 3], [f32; 3])) -> [u32; 6] {
    let mut out = [0; 6];
    for (o, v) in out.iter_mut().zip(gyro.iter().chain(&accel)) {
        *o = v.to_bits();
    }
    out
}

/// Spin each motor in turn; the board stops a test by itself 3 s after its last keep-alive, and
/// each is ended with a disarm.
fn spin_motors(client: &mut Client) -> Result<Vec<Spin>, LinkError> {
    let count = usize::from(client.info.motor_count).min(MAX_MOTORS);
    set_rate(client, Topic::Motors, SPIN_TELEMETRY_HZ)?;
    let mut spins = Vec::new();
    let result = (|| {
        for motor in 0..count as u8 {
            spins.push(spin_one(client, motor, count)?);
            client.request(&Request::Disarm(()), "the request to stop the motor")?;
            client.listen(Duration::from_secs_f64(SPIN_PAUSE_S))?;
        }
        Ok(())
    })();
    // Whatever happened, nothing spins afterwards.
    let _ = client.request(&Request::Disarm(()), "the request to stop the motors");
    let _ = set_rate(client, Topic::Motors, 0);
    result.map(|()| spins)
}

fn spin_one(client: &mut Client, motor: u8, count: usize) -> Result<Spin, LinkError> {
    let request = Request::MotorTest(protocol::MotorTest { motor, command: SPIN_COMMAND });
    client.request(&request, "the motor test request")?;
    client.telemetry.clear();
    // (board time µs, speeds) of every sample with the command on the output.
    let mut commanded: Vec<(u64, [Option<f32>; MAX_MOTORS])> = Vec::new();
    let keep_alive = Duration::from_millis(500);
    let started = Instant::now();
    let wall = Duration::from_secs_f64(SPIN_S + WALL_SLACK_S);
    let mut last_request = Instant::now();
    let mut span_s = 0.0;
    while started.elapsed() < wall && span_s < SPIN_S {
        if last_request.elapsed() >= keep_alive {
            client.request(&request, "the motor test request")?;
            last_request = Instant::now();
        }
        client.listen_with(Duration::from_millis(20), |sample| {
            if let Telemetry::Motors(m) = sample.data {
                if m.commands[usize::from(motor)] >= SPIN_COMMAND * 0.999 {
                    commanded.push((m.t_us, m.speeds_rad_s));
                }
            }
        })?;
        if let (Some(first), Some(last)) = (commanded.first(), commanded.last()) {
            span_s = (last.0 - first.0) as f64 * 1e-6;
        }
    }
    let settled_from_us =
        commanded.last().map_or(0, |last| last.0.saturating_sub((SPIN_SETTLED_S * 1e6) as u64));
    let settled: Vec<_> = commanded.iter().filter(|(t, _)| *t >= settled_from_us).collect();
    let speeds_rad_s = (0..count)
        .map(|i| {
            let reports: Vec<f64> =
                settled.iter().filter_map(|(_, s)| s[i]).map(f64::from).collect();
            (!reports.is_empty()).then(|| reports.iter().sum::<f64>() / reports.len() as f64)
        })
        .collect();
    Ok(Spin { motor, commanded: !commanded.is_empty(), speeds_rad_s })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A receiver with a 3D fix passes and says its accuracy; none, searching or no fix yet
    /// (indoors) are information; one that stopped sending fails and says what to check.
    #[test]
    fn the_gnss_line_passes_a_fix_informs_without_one_and_fails_a_lost_receiver() {
        assert_eq!(gnss_line(None).verdict, Verdict::Info);
        let receiving = GnssHealth {
            state: GnssState::Receiving,
            baud: 115_200,
            interface: GnssInterface::ConfigurationKeys,
            fix_type: 3,
            satellites: 14,
            horizontal_accuracy_m: 0.85,
            vertical_accuracy_m: 1.3,
            speed_accuracy_mps: 0.2,
            fixes: 50,
            without_fix: 2,
            checksum_errors: 0,
        };
        let fix = gnss_line(Some(&receiving));
        assert_eq!(fix.verdict, Verdict::Pass, "{}", fix.found);
        assert!(
            fix.found.contains("0.85 m horizontal") && fix.found.contains("14 satellites"),
            "{}",
            fix.found
        );
        let indoors = GnssHealth { fix_type: 0, satellites: 2, ..receiving };
        let no_fix = gnss_line(Some(&indoors));
        assert_eq!(no_fix.verdict, Verdict::Info);
        assert!(no_fix.found.contains("no 3D fix yet"), "{}", no_fix.found);
        let searching = GnssHealth { state: GnssState::Searching, baud: 9_600, ..receiving };
        assert_eq!(gnss_line(Some(&searching)).verdict, Verdict::Info);
        let lost = gnss_line(Some(&GnssHealth { state: GnssState::Lost, ..receiving }));
        assert_eq!(lost.verdict, Verdict::Fail);
        assert!(lost.advice.unwrap().contains("TX wire"));
    }

    #[test]
    fn the_compass_line_names_the_sensor_and_asks_for_a_calibration_and_fails_a_lost_one() {
        assert_eq!(compass_line(None).verdict, Verdict::Info);
        let healthy = CompassHealth {
            sensor: CompassSensor::Ist8310,
            address: 0x0E,
            state: CompassState::Healthy,
            enabled: true,
            calibrated: true,
            rate_hz: 99.6,
            field_ut: 48.3,
            ..CompassHealth::default()
        };
        let pass = compass_line(Some(&healthy));
        assert_eq!(pass.verdict, Verdict::Pass);
        assert!(
            pass.found.contains("IST8310 at 0x0E, 100 Hz, field 48.3 µT, calibrated"),
            "{}",
            pass.found
        );
        let raw = compass_line(Some(&CompassHealth { calibrated: false, ..healthy }));
        assert_eq!(raw.verdict, Verdict::Info);
        assert!(raw.found.contains("not calibrated: run `configurator-cli compass calibrate`"));
        let absent = compass_line(Some(&CompassHealth::default()));
        assert_eq!(absent.verdict, Verdict::Info);
        assert!(absent.found.contains("no compass found"));
        let lost =
            compass_line(Some(&CompassHealth { state: CompassState::Lost, lost: 2, ..healthy }));
        assert_eq!(lost.verdict, Verdict::Fail);
        assert!(lost.advice.unwrap().contains("SCL and SDA"));
    }

    /// An IMU window of `n` samples at 2 kHz: white noise of `gyro_sigma` rad/s and
    /// `accel_sigma` m/s² per axis about the means (a fixed pseudo-random sequence).
    fn window(n: usize, gyro: ([f64; 3], f64), accel: ([f64; 3], f64)) -> ImuWindow {
        let mut rng = flight::rng::Rng::new(7);
        let mut w = ImuWindow {
            driver: Some(ImuDriverState::Running),
            rate_hz: 2000.0,
            steps: n as u64,
            delivered: n as u64,
            ..ImuWindow::default()
        };
        for _ in 0..n {
            let g = gyro.0.map(|m| (m + gyro.1 * rng.normal()) as f32);
            let a = accel.0.map(|m| (m + accel.1 * rng.normal()) as f32);
            w.gyro.push(g);
            w.accel.push(a);
        }
        w
    }

    /// The datasheet's noise at the 1 kHz bandwidth of 2 kHz samples, rad/s and m/s².
    fn datasheet_sigmas() -> (f64, f64) {
        let gyro = GYRO_NOISE_DENSITY_DPS_PER_SQRT_HZ.to_radians() * 1000f64.sqrt();
        let accel =
            ACCEL_NOISE_DENSITY_MG_PER_SQRT_HZ * 1e-3 * STANDARD_GRAVITY_MPS2 * 1000f64.sqrt();
        (gyro, accel)
    }

    #[test]
    fn a_datasheet_imu_at_rest_passes_in_any_orientation_and_within_the_offsets() {
        let (gyro_sigma, accel_sigma) = datasheet_sigmas();
        let g = STANDARD_GRAVITY_MPS2;
        // Level, upside down, on its side and tilted; gyro offsets at the datasheet's ±0.5 °/s;
        // gravity at the equator and the poles, plus a 20 mg offset along it.
        let poses = [[0.0, 0.0, -g], [0.0, 0.0, g], [g, 0.0, 0.0], [0.3 * g, -0.5 * g, 0.81 * g]];
        let offset_rad_s = [0.5f64.to_radians(), -0.5f64.to_radians(), 0.3f64.to_radians()];
        for (pose, scale) in poses.iter().zip([9.780 / g, 9.832 / g, 1.0 + 0.02, 1.0 - 0.02]) {
            let accel = pose.map(|x| x * scale);
            // Up to 1.4× the datasheet's noise, as the simulator's IMU reads.
            let w = window(2000, (offset_rad_s, 1.4 * gyro_sigma), (accel, 1.4 * accel_sigma));
            let line = imu_line(&w);
            assert_eq!(line.verdict, Verdict::Pass, "{pose:?}: {}", line.text());
            assert!(
                line.found.contains("°/s RMS") && line.found.contains("m/s²"),
                "{}",
                line.found
            );
        }
    }

    #[test]
    fn a_noisy_imu_fails_at_thirty_times_and_passes_at_the_margin_boundary() {
        let (gyro_sigma, accel_sigma) = datasheet_sigmas();
        let level = [0.0, 0.0, -STANDARD_GRAVITY_MPS2];
        let noisy =
            imu_line(&window(2000, ([0.0; 3], 30.0 * gyro_sigma), (level, 30.0 * accel_sigma)));
        assert_eq!(noisy.verdict, Verdict::Fail);
        assert!(noisy.advice.as_deref().unwrap().contains("NOISY"), "{}", noisy.text());
        // Only the accelerometer noisy: still found.
        let accel_only =
            imu_line(&window(2000, ([0.0; 3], gyro_sigma), (level, 8.0 * accel_sigma)));
        assert_eq!(accel_only.verdict, Verdict::Fail, "{}", accel_only.text());
        // 4× (a bench with a fan): passes.
        let bench =
            imu_line(&window(2000, ([0.0; 3], 4.0 * gyro_sigma), (level, 4.0 * accel_sigma)));
        assert_eq!(bench.verdict, Verdict::Pass, "{}", bench.text());
    }

    #[test]
    fn silent_frozen_sparse_moving_and_wrong_gravity_imus_fail_with_their_advice() {
        let (gyro_sigma, accel_sigma) = datasheet_sigmas();
        let level = [0.0, 0.0, -STANDARD_GRAVITY_MPS2];
        let silent = ImuWindow { rate_hz: 2000.0, steps: 2000, ..ImuWindow::default() };
        let line = imu_line(&silent);
        assert_eq!(line.verdict, Verdict::Fail);
        assert!(line.found.contains("SILENT") && line.advice.unwrap().contains("silent"));

        let mut frozen = window(2000, ([0.01; 3], 0.0), (level, 0.0));
        frozen.all_identical = true;
        let line = imu_line(&frozen);
        assert!(line.found.contains("FROZEN") && line.advice.unwrap().contains("repeats"));

        let mut sparse = window(1800, ([0.0; 3], gyro_sigma), (level, accel_sigma));
        sparse.steps = 2000;
        let line = imu_line(&sparse);
        assert!(line.advice.unwrap().contains("90.0 % of control steps"));

        // Turning at 2 °/s (someone carrying it): an offset beyond 1 °/s.
        let moving =
            window(2000, ([0.0, 0.0, 2f64.to_radians()], gyro_sigma), (level, accel_sigma));
        assert!(imu_line(&moving).advice.unwrap().contains("at rest"));

        // 0.5 m/s² off 1 g: a bad accelerometer or a wrong stored bias.
        let heavy = window(2000, ([0.0; 3], gyro_sigma), ([0.0, 0.0, -10.3], accel_sigma));
        assert!(imu_line(&heavy).advice.unwrap().contains("not 1 g"));

        let mut wrong = window(2000, ([0.0; 3], gyro_sigma), (level, accel_sigma));
        wrong.driver = Some(ImuDriverState::WrongIdentity { expected: 0x47, found: 0x00 });
        let line = imu_line(&wrong);
        assert_eq!(line.verdict, Verdict::Fail);
        assert!(line.advice.unwrap().contains("0x00"));
    }

    #[test]
    fn the_flash_line_passes_a_loaded_or_empty_store_and_fails_what_cannot_be_used() {
        let status = |origin, rejected| ConfigStatus {
            origin,
            layout_version: 1,
            param_count: 40,
            rejected_at_load: rejected,
            ..ConfigStatus::default()
        };
        assert!(flash_line(Some(&status(ConfigOrigin::Loaded, 0))).ok());
        assert!(flash_line(Some(&status(ConfigOrigin::Defaults, 0))).ok());
        for bad in [
            status(ConfigOrigin::Unreadable, 0),
            status(ConfigOrigin::UnknownLayout { version: 9 }, 0),
            status(ConfigOrigin::NoStore, 0),
            status(ConfigOrigin::Loaded, 2),
        ] {
            let line = flash_line(Some(&bad));
            assert_eq!(line.verdict, Verdict::Fail, "{bad:?}");
            assert!(line.advice.is_some());
        }
        assert!(!flash_line(None).ok());
    }

    #[test]
    fn no_receiver_is_information_and_a_receiver_without_frames_fails() {
        let none = receiver_line(Some(&BoardHealth::default()));
        assert_eq!(none.verdict, Verdict::Info);
        assert!(none.ok() && none.found.contains("no receiver"));
        let receiver = |link_up, frames, frame_errors| BoardHealth {
            receiver: Some(protocol::ReceiverHealth {
                link_up,
                link_quality_pct: 100,
                rssi_dbm: -40,
                frames,
                frame_errors,
            }),
            ..BoardHealth::default()
        };
        assert_eq!(receiver_line(Some(&receiver(true, 1500, 2))).verdict, Verdict::Pass);
        let silent = receiver_line(Some(&receiver(false, 0, 0)));
        assert!(silent.advice.unwrap().contains("no frame"));
        assert!(receiver_line(Some(&receiver(false, 800, 0))).advice.unwrap().contains("down"));
        assert!(receiver_line(Some(&receiver(true, 900, 100))).advice.unwrap().contains("baud"));
    }

    #[test]
    fn a_pack_at_rest_passes_and_wrong_scales_fail_saying_which() {
        let pack = |voltage_v: f32, current_a: f32, cells: u8| protocol::BatteryStatus {
            voltage_v,
            current_a,
            used_mah: 1.0,
            cells,
            remaining_pct: 80,
        };
        let good = battery_line(Some(&pack(16.4, 0.6, 4)));
        assert_eq!(good.verdict, Verdict::Pass, "{good:?}");
        assert!(good.found.contains("4S 16.40 V (4.10 V a cell)"), "{}", good.found);
        // A pack that has run down since its cells were counted, or a divider read with the
        // wrong ratio (a 1S count: 2.2 V; a 4S count: 4.5 V a cell).
        let low = battery_line(Some(&pack(2.2, 0.6, 1)));
        assert_eq!(low.verdict, Verdict::Fail);
        assert!(low.advice.as_ref().unwrap().contains("voltage divider"), "{low:?}");
        let high = battery_line(Some(&pack(18.0, 0.6, 4)));
        assert!(high.advice.as_ref().unwrap().contains("voltage divider"), "{high:?}");
        assert_eq!(high.verdict, Verdict::Fail, "{high:?}");
        for current_a in [4.0, -1.0] {
            let line = battery_line(Some(&pack(16.4, current_a, 4)));
            assert_eq!(line.verdict, Verdict::Fail);
            assert!(line.advice.as_ref().unwrap().contains("current sensor"), "{line:?}");
        }
        // Nothing to judge: information, never a failure.
        for info in [None, Some(pack(0.3, 0.0, 0)), Some(pack(16.4, 0.5, 0))] {
            assert_eq!(battery_line(info.as_ref()).verdict, Verdict::Info, "{info:?}");
        }
    }

    #[test]
    fn the_esc_line_names_the_motors_without_speed_and_the_noisy_signals() {
        let health = |reported| SensorHealth {
            motor_count: 4,
            speeds_reported: reported,
            ..SensorHealth::default()
        };
        let on = SpeedReports::default();
        assert_eq!(esc_line(Some(&health(0b1111)), None, on).verdict, Verdict::Pass);
        let one = esc_line(Some(&health(0b1011)), None, on);
        assert_eq!(one.verdict, Verdict::Fail);
        assert!(one.found.contains("motor 2 of 0–3 reports NO speed"), "{}", one.found);
        assert!(one.advice.unwrap().contains("check motor 2's ESC"));
        let none = esc_line(Some(&health(0)), None, on).advice.unwrap();
        assert!(none.contains("motor_bidir_dshot = 1") && none.contains("updating"), "{none}");
        let mut link = MotorLinkHealth { motor_count: 4, ..MotorLinkHealth::default() };
        link.reports = [1000, 1000, 900, 1000, 0, 0, 0, 0];
        link.report_errors = [0, 3, 100, 0, 0, 0, 0, 0];
        let noisy = esc_line(Some(&health(0b1111)), Some(&link), on);
        assert_eq!(noisy.verdict, Verdict::Fail);
        assert!(noisy.found.contains("motor 2: 10.0 %"), "{}", noisy.found);
        assert!(!esc_line(None, None, on).ok());
    }

    /// With `motor_bidir_dshot` = 0 silent ESCs are what the user said: a firmware that
    /// identifies without speeds passes, one that needs them fails pointing at both ways out;
    /// and the spin is not run, there being no report to check it against.
    #[test]
    fn speed_reports_turned_off_pass_only_where_the_firmware_identifies_without_them() {
        let silent = SensorHealth { motor_count: 4, speeds_reported: 0, ..SensorHealth::default() };
        let able = SpeedReports { off: true, identifies_without: true };
        let line = esc_line(Some(&silent), None, able);
        assert_eq!(line.verdict, Verdict::Pass, "{line:?}");
        assert!(line.found.contains("from the commands"), "{}", line.found);
        let unable = SpeedReports { off: true, identifies_without: false };
        let line = esc_line(Some(&silent), None, unable);
        assert_eq!(line.verdict, Verdict::Fail);
        let advice = line.advice.unwrap();
        assert!(advice.contains("motor_bidir_dshot = 1"), "{advice}");
        assert!(advice.contains("cargo xtask flash`"), "{advice}");
        let spin = spin_without_reports();
        assert_eq!(spin.verdict, Verdict::Skipped);
        assert!(spin.advice.unwrap().contains("motor-test --motor N"));
    }

    fn spin(motor: u8, speeds: &[f64]) -> Spin {
        Spin { motor, commanded: true, speeds_rad_s: speeds.iter().map(|&s| Some(s)).collect() }
    }

    #[test]
    fn each_motor_answering_on_its_own_output_passes_with_others_stopped_or_idling() {
        // A board: the others stopped. The simulator: the others idle at 300 rad/s.
        let stopped: Vec<Spin> = (0..4)
            .map(|m| spin(m, &(0..4).map(|i| if i == m { 845.0 } else { 0.0 }).collect::<Vec<_>>()))
            .collect();
        assert_eq!(spin_line(&stopped).verdict, Verdict::Pass);
        let idling: Vec<Spin> = (0..4)
            .map(|m| {
                spin(m, &(0..4).map(|i| if i == m { 845.0 } else { 300.0 }).collect::<Vec<_>>())
            })
            .collect();
        let line = spin_line(&idling);
        assert_eq!(line.verdict, Verdict::Pass, "{}", line.text());
        assert!(
            line.found.contains("motor 0: 845 rad/s (8069 rpm), others ≤ 300 rad/s"),
            "{}",
            line.found
        );
    }

    #[test]
    fn crossed_outputs_silent_and_dead_motors_fail_the_spin() {
        // Outputs 1 and 3 crossed: spinning 1 turns 3.
        let crossed = [spin(0, &[845.0, 0.0, 0.0, 0.0]), spin(1, &[0.0, 0.0, 0.0, 845.0])];
        let line = spin_line(&crossed);
        assert_eq!(line.verdict, Verdict::Fail);
        assert!(line.advice.unwrap().starts_with("output 1 turned motor 3 (845 rad/s)"));
        let mut silent = spin(2, &[0.0, 0.0, 0.0, 0.0]);
        silent.speeds_rad_s[2] = None;
        assert!(spin_line(&[silent]).advice.unwrap().contains("reports no speed"));
        let dead = spin_line(&[spin(0, &[5.0, 0.0, 0.0, 0.0])]);
        assert!(dead.advice.unwrap().contains("did not turn"));
        let refused = Spin { commanded: false, ..spin(0, &[0.0; 4]) };
        assert!(spin_line(&[refused]).advice.unwrap().contains("did not drive output 0"));
        assert_eq!(spin_skipped("no terminal").verdict, Verdict::Skipped);
        assert!(spin_skipped("no terminal").ok());
    }

    #[test]
    fn axis_statistics_match_the_textbook_formulas() {
        let mut stats = AxisStats::default();
        for x in [1.0f32, 2.0, 4.0] {
            stats.push([x, -x, 0.0]);
        }
        let mean = 7.0 / 3.0;
        assert!((stats.mean()[0] - mean).abs() < 1e-12 && (stats.mean()[1] + mean).abs() < 1e-12);
        let var = ((1.0 - mean) * (1.0f64 - mean)
            + (2.0 - mean) * (2.0 - mean)
            + (4.0 - mean) * (4.0 - mean))
            / 2.0;
        assert!((stats.std()[0] - var.sqrt()).abs() < 1e-12);
        assert_eq!(stats.std()[2], 0.0);
    }
}
