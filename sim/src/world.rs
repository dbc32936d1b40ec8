//! A randomised world: what real hands, motion capture, IMUs, ESCs, motors and air do that the
//! nominal simulator does not, each drawn from a documented physical range with a seed.
//!
//! The nominal Monte Carlo (`fly monte-carlo`) varies the airframe and the throw's spin and
//! height, but releases the craft in one step, sends poses at exactly 100 Hz and flies ideal
//! ESCs of the learner's own curve family. A detector, estimator or controller tuned there can
//! pass only at those points (issue 28 found two such: a real hand's tapering release, and poses
//! at another rate). Here every aspect a user's world varies is drawn at random:
//!
//! | aspect | what varies (range) | why that range |
//! |---|---|---|
//! | `hand` | push 0.1–0.3 s; taper 0–50 ms; spin 0–1,000 °/s about a uniformly random axis; apex 2.5–4.5 m; lobbed up to 3 m/s sideways | hands throw for 0.1–0.3 s and let go over tens of ms (issue 28); the detector's stated range of spins |
//! | `pose` | 30–500 Hz (log-uniform), jitter up to 20 % of the interval, latency 0–30 ms (told to the board), noise 0.5–3 mm, dropouts 0–0.1 per s of 0.1–0.5 s | motion-capture systems, and their poses after a radio link |
//! | `imu` | noise 1–3× the ICM-42688-P's density; gyro bias ±0.5 °/s, accelerometer bias ±0.2 m/s² per axis; scale ±3 % and cross-axis ±2 % per element; rotor vibration 0–5 m/s² and 0–0.1 rad/s at full speed | ICM-42688-P datasheet (offsets ±0.5 dps, ±20 mg; cross-axis ±2 %), and the 1–3 % of scale and cross-axis error; soft-mounted to hard-mounted boards |
//! | `actuators` | the command-to-speed curve: the paper's (κ 0–1), thrust quadratic in δ (`kδ² + (1 − k)δ`, k 0–1) or a power law (δ^p, p 0.6–1.4); each motor ±5 % thrust; idle 3–15 % of full speed; battery sag 5–15 % of thrust over 15 s; ESC answers 0.5–3 ms late, 0–5 % of them lost | ESC firmwares (BLHeli_32, AM32, Bluejay: throttle curves and linearisation), worn propellers, a 4S pack under load |
//! | `hand` (its grab, [`crate::recovery::FlightEnd::Catch`]) | closes with a time constant of 0.05–0.3 s; pulls the craft 0–10 cm down and 0–10 cm sideways; tilts it 3–15° about a random horizontal axis | a hand grabbing a hovering craft: fast or hesitant, pulling it towards the person and tipping it as it closes |
//! | `air` | drag 0.3–3× the airframe's, and each body axis's linear and quadratic coefficients 0.5–2× (log-uniform) on their own; a gust of 0.5–2 m/s from a random horizontal direction for 0.3–1 s, 2–10 s after the start | frames with guards or without; drag differs along the body's axes (rotor drag in the rotor plane, the frame's area from above and from the side); a breeze indoors or out |
//!
//! | `gust` (not in `--world random` unless `--gusts`) | a "1 − cos" gust of 2–8 m/s peak over 0.5–3 s starting 4–8 s after the start, and a step gust of 1–4 m/s for 0.3–1 s starting 4–10 s after it; each from a random bearing, up to 20° from the horizontal | gusts of a breezy day outdoors, the discrete gust of the airworthiness codes (CS-25.341) and a sharp-edged one, while the craft hovers |
//! | `wind` (not in `--world random` unless `--wind`) | a steady horizontal wind of 0–8 m/s (uniform) from a uniform bearing, from the start of the run (the throw included); on it turbulence, each world axis a first-order Gauss–Markov process of σ = 10–20 % of the wind's speed + 0.1 m/s horizontally and half that vertically, correlation time 1–3 s | flying outdoors in up to a moderate breeze (Beaufort 4 ends at 7.9 m/s). The turbulence is a simplified stand-in for the low-altitude Dryden model (MIL-F-8785C, MIL-HDBK-1797): there σ is 0.1 of the wind at 20 ft vertically and about twice that horizontally near the ground, and the length scales of tens of metres pass a hovering craft in seconds at these speeds; one first-order process per axis with one correlation time keeps Dryden's longitudinal spectrum only |
//! | `gnss` (not in `--world random` unless `--gnss-random`) | the craft flies on a simulated u-blox receiver instead of motion capture, drawn by [`GnssModelConfig::random`]: noise 0.02–2 m per horizontal axis (log-uniform) correlated over 2–60 s, vertically 1.5–2.5× that, white 5–30 % of it; 5–10 Hz; 50–150 ms late (the firmware told the drawn latency, as a user sets it); multipath jumps of 1–5 m for 1–10 s at up to one a minute; in half the draws dropouts of 0.5–5 s at up to one every 100 s | the randomised receiver: RTK-like to a single-frequency receiver under trees, the rates and latencies of M8–M10 receivers with several constellations |
//! | `compass` (not in `--world random` unless `--compass`) | a magnetometer on the craft, drawn by [`MagnetometerSpec::random`] (`crate::magnetometer`): the Earth's field 25–65 µT, inclination −70…+70°, declination −30…+30°; hard iron ±300 µT per axis; soft iron 0.8–1.2 per axis and ±0.2 cross-axis per element; mounted at any rotation (uniform on SO(3)); noise 0.3–2 µT per axis; read at 50–100 Hz; each motor's field a random direction, their sum at full thrust 0–50 % of the Earth's field (all uniform) | the field wherever people fly (IGRF-13: 22–67 µT at the surface; beyond ±70° of dip the horizontal field is too weak for a heading); a magnetised screw, strap or buzzer near the sensor; steel nearby and the sensor's own scale and cross-axis errors; a GNSS mast's sensor in any orientation; the IST8310 and QMC5883L with their averaging; the power wires 10–20 cm below a mast (issue 55). Stored with the case (`FlyConfig::compass`); the flight does not use it yet |
//!
//! `fly monte-carlo --world random` draws every aspect but `gust`, `wind`, `gnss` and `compass`
//! (added by `--gusts`, `--wind`, `--gnss-random` and `--compass`, so the hover figures of earlier
//! worlds stay comparable); `--vary NAME` one at a time, so each aspect's pass rate is known alone
//! (docs/benchmarks.md; `--vary gnss` sweeps the receiver alone over the nominal world, its noise
//! over 0.02–2 m); `--wind-mps X` draws the
//! wind with its steady speed forced to X (bearing and turbulence as the seed draws them), for a
//! sweep over the speed. A draw depends only on the case's seed and the aspect, so the same seed
//! gives the same airframe, throw and world, and a world without `wind`, `gnss` or `compass` flies
//! as it did before the aspect existed (each aspect draws from its own generator, so adding one
//! changes no other draw).

use nalgebra::Vector3;

use crate::airframe::{Airframe, SpeedCurve};
use crate::gnss::GnssModelConfig;
use crate::magnetometer::MagnetometerSpec;
use crate::recovery::{random_case, CaseResult, FlyConfig, MotionCaptureConfig};
use crate::rng::Rng;

/// One aspect of the world that can be randomised.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Aspect {
    /// How the hand throws and lets go.
    Hand,
    /// The external pose's rate, timing, noise and dropouts.
    Pose,
    /// The IMU's errors.
    Imu,
    /// ESCs, motors and battery.
    Actuators,
    /// Drag and a gust.
    Air,
    /// Strong gusts while the craft hovers (not in [`Aspect::ALL`]).
    Gust,
    /// A steady wind and turbulence for the whole run (not in [`Aspect::ALL`]).
    Wind,
    /// A GNSS receiver instead of motion capture, its noise, timing, multipath and dropouts
    /// drawn (not in [`Aspect::ALL`]). After the others, so that every other aspect's seed
    /// stays the same.
    Gnss,
    /// A compass on the craft ([`MagnetometerSpec::random`]; not in [`Aspect::ALL`]). Last, so
    /// that every other aspect's seed stays the same.
    Compass,
}

impl Aspect {
    /// Every aspect, in the order of the module doc's table.
    pub const ALL: [Aspect; 5] =
        [Aspect::Hand, Aspect::Pose, Aspect::Imu, Aspect::Actuators, Aspect::Air];

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Aspect::Hand => "hand",
            Aspect::Pose => "pose",
            Aspect::Imu => "imu",
            Aspect::Actuators => "actuators",
            Aspect::Air => "air",
            Aspect::Gust => "gust",
            Aspect::Wind => "wind",
            Aspect::Gnss => "gnss",
            Aspect::Compass => "compass",
        }
    }

    /// The aspects drawn only when asked for, not by `--world random` ([`Aspect::ALL`]).
    pub const ON_REQUEST: [Aspect; 4] = [Aspect::Gust, Aspect::Wind, Aspect::Gnss, Aspect::Compass];

    /// The aspect called `name`.
    pub fn parse(name: &str) -> Result<Self, String> {
        let every = || Self::ALL.into_iter().chain(Self::ON_REQUEST);
        every().find(|a| a.name() == name).ok_or_else(|| {
            let names: Vec<_> = every().map(|a| a.name()).collect();
            format!("unknown aspect `{name}` (one of {})", names.join(", "))
        })
    }

    /// A seed for this aspect's draws, independent of the others'.
    fn rng(self, seed: u64) -> Rng {
        Rng::new(seed ^ (0x5752_4C44_0000_0000 | ((self as u64 + 1) * 0x9E37_79B9)))
    }
}

/// The Monte Carlo case `seed` ([`random_case`]: airframe and nominal throw) in a world whose
/// `aspects` are randomised.
pub fn random_world_case(seed: u64, aspects: &[Aspect]) -> (Airframe, FlyConfig) {
    let (mut airframe, mut config) = random_case(seed);
    for aspect in aspects {
        apply(*aspect, seed, &mut airframe, &mut config);
    }
    (airframe, config)
}

/// Runs `runs` cases (seeds `seed..seed + runs`) with `aspects` randomised on `threads`
/// workers; `progress` is called with the number done after each.
pub fn monte_carlo(
    runs: usize,
    seed: u64,
    threads: usize,
    aspects: &[Aspect],
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<CaseResult> {
    crate::recovery::monte_carlo(runs, seed, threads, progress, |seed| {
        random_world_case(seed, aspects)
    })
}

/// Draw `aspect` for case `seed` into the airframe and the run's configuration.
pub fn apply(aspect: Aspect, seed: u64, airframe: &mut Airframe, config: &mut FlyConfig) {
    let mut rng = aspect.rng(seed);
    match aspect {
        Aspect::Hand => hand(&mut rng, config),
        Aspect::Pose => config.motion_capture = pose(&mut rng),
        Aspect::Imu => imu(&mut rng, airframe),
        Aspect::Actuators => actuators(&mut rng, airframe, config),
        Aspect::Air => air(&mut rng, airframe, config),
        Aspect::Gust => gusts(&mut rng, config),
        Aspect::Wind => wind(&mut rng, None, config),
        // The receiver's noise itself is drawn from the board's seed (`GnssFeed`), as motion
        // capture's is.
        Aspect::Gnss => config.gnss = Some(GnssModelConfig::random(&mut rng)),
        // Its noise is drawn from the sensor's own seed (`SimMagnetometer::new`), as the
        // receiver's is.
        Aspect::Compass => {
            config.compass = Some(MagnetometerSpec::random(&mut rng, airframe.rotor_count()));
        }
    }
}

/// Draws the `wind` aspect of case `seed` with its steady speed forced to `speed_mps` (`fly
/// --wind-mps`, for a sweep): the bearing and the turbulence's share of the speed, its
/// correlation time and its draws are those [`apply`] gives the seed.
pub fn apply_wind_at(seed: u64, speed_mps: f64, config: &mut FlyConfig) {
    wind(&mut Aspect::Wind.rng(seed), Some(speed_mps), config);
}

fn random_unit(rng: &mut Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(rng.normal(), rng.normal(), rng.normal());
        if v.norm() > 1e-6 {
            return v.normalize();
        }
    }
}

fn hand(rng: &mut Rng, config: &mut FlyConfig) {
    let throw = &mut config.throw;
    throw.push_s = rng.range(0.1, 0.3);
    throw.taper_s = rng.range(0.0, 0.05);
    throw.rate_body_rad_s = random_unit(rng) * rng.range(0.0, 1000.0).to_radians();
    throw.apex_m = rng.range(2.5, 4.5);
    let heading = rng.range(0.0, std::f64::consts::TAU);
    let sideways_mps = rng.range(0.0, 3.0);
    throw.horizontal_mps = [sideways_mps * heading.cos(), sideways_mps * heading.sin()];
    // The grab, drawn after the throw so that a seed's throw is the one it was before.
    let grab = &mut config.grab;
    grab.tau_s = rng.range(0.05, 0.3);
    let bearing = rng.range(0.0, std::f64::consts::TAU);
    let sideways_m = rng.range(0.0, 0.1);
    grab.pull_ned_m =
        Vector3::new(sideways_m * bearing.cos(), sideways_m * bearing.sin(), rng.range(0.0, 0.1));
    let axis = rng.range(0.0, std::f64::consts::TAU);
    grab.tilt_world_rad =
        Vector3::new(axis.cos(), axis.sin(), 0.0) * rng.range(3.0, 15.0).to_radians();
}

/// A direction from a uniformly random bearing, up to `max_elevation_rad` above or below the
/// horizontal, times `speed_mps`.
fn gust_velocity(rng: &mut Rng, speed_mps: f64, max_elevation_rad: f64) -> [f64; 3] {
    let bearing = rng.range(0.0, std::f64::consts::TAU);
    let elevation = rng.range(-max_elevation_rad, max_elevation_rad);
    let horizontal = speed_mps * elevation.cos();
    [horizontal * bearing.cos(), horizontal * bearing.sin(), -speed_mps * elevation.sin()]
}

/// Largest angle of a gust from the horizontal, rad (20°): near the ground the air moves mostly
/// along it.
const GUST_MAX_ELEVATION_RAD: f64 = 20.0 * std::f64::consts::PI / 180.0;

fn gusts(rng: &mut Rng, config: &mut FlyConfig) {
    use crate::board::{Gust, GustShape};
    let peak = rng.range(2.0, 8.0);
    let cosine = Gust {
        shape: GustShape::OneMinusCosine,
        peak_ned_mps: gust_velocity(rng, peak, GUST_MAX_ELEVATION_RAD),
        start_s: rng.range(4.0, 8.0),
        duration_s: rng.range(0.5, 3.0),
    };
    let speed = rng.range(1.0, 4.0);
    let step = Gust {
        shape: GustShape::Step,
        peak_ned_mps: gust_velocity(rng, speed, GUST_MAX_ELEVATION_RAD),
        start_s: rng.range(4.0, 10.0),
        duration_s: rng.range(0.3, 1.0),
    };
    config.board.world.gusts = [Some(cosine), Some(step)];
}

/// Largest steady wind the `wind` aspect draws, m/s (uniform from calm): the top of a moderate
/// breeze (Beaufort 4, 5.5–7.9 m/s), the windiest day a small craft is commonly flown on.
pub const WIND_MAX_MPS: f64 = 8.0;

/// The horizontal turbulence's standard deviation as a share of the steady wind's speed, drawn
/// uniformly in this range. The low-altitude Dryden model (MIL-F-8785C, MIL-HDBK-1797) gives the
/// vertical σ as 0.1 of the wind at 20 ft and, at 10 ft (its lowest height, about where the
/// craft hovers), the horizontal σ about twice that: 10–20 % runs from calmer air up to it.
pub const TURBULENCE_SHARE_OF_WIND: (f64, f64) = (0.1, 0.2);

/// Horizontal turbulence present even in calm air, m/s (its standard deviation, added to the
/// share of the wind): air is never perfectly still outdoors.
pub const TURBULENCE_FLOOR_MPS: f64 = 0.1;

/// The vertical turbulence's standard deviation over the horizontal one: the Dryden model's
/// ratio at 10 ft (`σ_w / σ_u = (0.177 + 0.000823 h)^0.4` with `h` in ft, ≈ 0.5), the ground
/// damping the air's motion across it.
pub const TURBULENCE_VERTICAL_SHARE: f64 = 0.5;

/// The turbulence's correlation time, s, drawn uniformly in this range. Dryden's horizontal length
/// scale near the ground is tens of metres (`L_u = h / (0.177 + 0.000823 h)^1.2`: about 23 m at
/// 10 ft), carried past a hovering craft by the wind: seconds at these speeds (2.9 s at 8 m/s,
/// longer in lighter air); 1–3 s is at or below that, so the air changes within a hold.
pub const TURBULENCE_CORRELATION_S: (f64, f64) = (1.0, 3.0);

/// The `wind` aspect: a steady horizontal wind of 0–[`WIND_MAX_MPS`] from a uniform bearing (its
/// speed `speed_mps` when forced) and turbulence on every world axis.
fn wind(rng: &mut Rng, speed_mps: Option<f64>, config: &mut FlyConfig) {
    use crate::board::Turbulence;
    let drawn_mps = rng.range(0.0, WIND_MAX_MPS);
    let speed_mps = speed_mps.unwrap_or(drawn_mps);
    let bearing = rng.range(0.0, std::f64::consts::TAU);
    let share = rng.range(TURBULENCE_SHARE_OF_WIND.0, TURBULENCE_SHARE_OF_WIND.1);
    let horizontal_mps = share * speed_mps + TURBULENCE_FLOOR_MPS;
    let turbulence = Turbulence {
        sigma_ned_mps: [horizontal_mps, horizontal_mps, TURBULENCE_VERTICAL_SHARE * horizontal_mps],
        correlation_s: rng.range(TURBULENCE_CORRELATION_S.0, TURBULENCE_CORRELATION_S.1),
        seed: rng.next_u64(),
    };
    let world = &mut config.board.world;
    world.steady_wind_ned_mps = [speed_mps * bearing.cos(), speed_mps * bearing.sin(), 0.0];
    world.turbulence = Some(turbulence);
}

fn pose(rng: &mut Rng) -> MotionCaptureConfig {
    let rate_hz = (rng.range(30f64.ln(), 500f64.ln())).exp();
    let dropping = rng.uniform() < 0.5;
    MotionCaptureConfig {
        rate_hz,
        jitter_s: rng.range(0.0, 0.2) / rate_hz,
        latency_s: rng.range(0.0, 0.03),
        noise_m: rng.range(0.0005, 0.003),
        dropouts_per_s: if dropping { rng.range(0.0, 0.1) } else { 0.0 },
        dropout_s: rng.range(0.1, 0.5),
        ..MotionCaptureConfig::default()
    }
}

fn imu(rng: &mut Rng, airframe: &mut Airframe) {
    let imu = &mut airframe.imu;
    let noise = rng.range(1.0, 3.0);
    imu.gyro.noise_density_rad_s_per_sqrt_hz *= noise;
    imu.accel.noise_density_mps2_per_sqrt_hz *= noise;
    for axis in 0..3 {
        imu.gyro.bias_rad_s[axis] = rng.range(-0.5, 0.5).to_radians();
        imu.accel.bias_mps2[axis] = rng.range(-0.2, 0.2);
    }
    let sensitivity = |rng: &mut Rng| {
        let mut m = [[0.0; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, x) in row.iter_mut().enumerate() {
                *x = if i == j { 1.0 + rng.range(-0.03, 0.03) } else { rng.range(-0.02, 0.02) };
            }
        }
        m
    };
    imu.gyro.sensitivity = sensitivity(rng);
    imu.accel.sensitivity = sensitivity(rng);
    imu.vibration.accel_mps2_at_max_speed = rng.range(0.0, 5.0);
    imu.vibration.gyro_rad_s_at_max_speed = rng.range(0.0, 0.1);
}

fn actuators(rng: &mut Rng, airframe: &mut Airframe, config: &mut FlyConfig) {
    let curve = match rng.next_u64() % 3 {
        0 => SpeedCurve::Paper,
        1 => SpeedCurve::ThrustPolynomial { k: rng.range(0.0, 1.0) },
        _ => SpeedCurve::Power { p: rng.range(0.6, 1.4) },
    };
    let kappa = rng.range(0.0, 1.0);
    let idle_fraction = rng.range(0.03, 0.15);
    let delay_s = rng.range(0.0005, 0.003);
    let mut shared = airframe.motor.clone();
    for motor in std::iter::once(&mut shared)
        .chain(airframe.rotors.iter_mut().filter_map(|r| r.motor.as_mut()))
    {
        motor.curve = curve;
        motor.kappa = kappa;
        motor.omega_idle_rad_s = idle_fraction * motor.omega_max_rad_s;
        motor.telemetry_delay_s = delay_s;
    }
    airframe.motor = shared;
    for rotor in airframe.rotors.iter_mut() {
        let motor = rotor.motor.get_or_insert_with(|| airframe.motor.clone());
        motor.thrust_coefficient_n_per_rad2_s2 *= rng.range(0.95, 1.05);
    }
    config.board.world.battery_sag = rng.range(0.05, 0.15);
    config.board.world.battery_sag_over_s = 15.0;
    config.board.world.telemetry_loss_probability = rng.range(0.0, 0.05);
}

fn air(rng: &mut Rng, airframe: &mut Airframe, config: &mut FlyConfig) {
    let scale = rng.range(0.3, 3.0);
    for c in
        airframe.drag.linear_n_per_mps.iter_mut().chain(&mut airframe.drag.quadratic_n_per_mps2)
    {
        *c *= scale;
    }
    let heading = rng.range(0.0, std::f64::consts::TAU);
    let speed_mps = rng.range(0.5, 2.0);
    let world = &mut config.board.world;
    world.gust_ned_mps = [speed_mps * heading.cos(), speed_mps * heading.sin(), 0.0];
    world.gust_start_s = rng.range(2.0, 10.0);
    world.gust_s = rng.range(0.3, 1.0);
    // Drawn after the gust, so that the gust of a seed is the one it was before (2026-11-27).
    for c in
        airframe.drag.linear_n_per_mps.iter_mut().chain(&mut airframe.drag.quadratic_n_per_mps2)
    {
        *c *= DRAG_AXIS_FACTOR.0 * (DRAG_AXIS_FACTOR.1 / DRAG_AXIS_FACTOR.0).powf(rng.uniform());
    }
}

/// Each body axis's drag coefficients (linear and quadratic, independently) are scaled by a
/// log-uniform factor in this range: a multirotor's drag is not the same along every axis (the
/// rotors' drag acts in their plane, a frame shows another area from above than from the side;
/// the built-in airframes have z twice x and y), so up to 4× between two axes. A model of drag
/// that assumes it the same along every axis, or along the IMU's axes, fails here.
const DRAG_AXIS_FACTOR: (f64, f64) = (0.5, 2.0);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_aspect_draws_within_its_documented_range_and_the_airframe_stays_valid() {
        for seed in 0..200 {
            let (airframe, config) = random_world_case(seed, &Aspect::ALL);
            airframe.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let t = &config.throw;
            assert!((0.1..=0.3).contains(&t.push_s) && (0.0..=0.05).contains(&t.taper_s));
            assert!(t.rate_body_rad_s.norm() <= 1000f64.to_radians() + 1e-9);
            let mc = &config.motion_capture;
            assert!((30.0..=500.0).contains(&mc.rate_hz), "{}", mc.rate_hz);
            assert!(mc.jitter_s <= 0.2 / mc.rate_hz && mc.latency_s <= 0.03);
            let w = &config.board.world;
            assert!((0.05..=0.15).contains(&w.battery_sag));
            assert!((0.5..=2.0).contains(&Vector3::from(w.gust_ned_mps).norm()));
            for i in 0..airframe.rotor_count() {
                let m = airframe.rotor_motor(i);
                let idle = m.omega_idle_rad_s / m.omega_max_rad_s;
                assert!((0.03..=0.15).contains(&idle), "seed {seed}: idle {idle}");
                // Every curve runs from idle at δ = 0 to full speed at δ = 1, increasing.
                assert!((m.steady_speed_rad_s(1.0) - m.omega_max_rad_s).abs() < 1e-6);
                assert!(m.steady_speed_rad_s(0.5) > m.steady_speed_rad_s(0.25));
                let back = m.command_for_speed(m.steady_speed_rad_s(0.4));
                assert!((back - 0.4).abs() < 1e-6, "seed {seed}: {back}");
            }
        }
    }

    #[test]
    fn an_aspect_left_out_is_nominal_and_a_draw_depends_only_on_seed_and_aspect() {
        let (nominal_airframe, nominal) = random_case(7);
        let (airframe, config) = random_world_case(7, &[Aspect::Hand]);
        assert_eq!(airframe, nominal_airframe);
        assert_eq!(config.motion_capture, nominal.motion_capture);
        assert_eq!(config.board, nominal.board);
        assert_ne!(config.throw, nominal.throw);
        let (_, both) = random_world_case(7, &[Aspect::Air, Aspect::Hand]);
        assert_eq!(both.throw, config.throw);
        assert_eq!(Aspect::parse("imu"), Ok(Aspect::Imu));
        assert_eq!(Aspect::parse("wind"), Ok(Aspect::Wind));
        assert!(Aspect::parse("rain").is_err());
    }

    #[test]
    fn the_wind_draws_within_its_documented_ranges() {
        let (mut slowest, mut fastest) = (f64::INFINITY, 0.0f64);
        for seed in 0..200 {
            let (airframe, config) = random_world_case(seed, &[Aspect::Wind]);
            let (nominal_airframe, nominal) = random_case(seed);
            assert_eq!(airframe, nominal_airframe);
            assert_eq!(config.throw, nominal.throw);
            let w = &config.board.world;
            let steady = Vector3::from(w.steady_wind_ned_mps);
            let speed = steady.norm();
            assert!((0.0..=WIND_MAX_MPS).contains(&speed), "seed {seed}: {speed} m/s");
            assert_eq!(steady.z, 0.0, "seed {seed}: the steady wind is horizontal");
            (slowest, fastest) = (slowest.min(speed), fastest.max(speed));
            let t = w.turbulence.unwrap_or_else(|| panic!("seed {seed}: no turbulence"));
            let [north, east, down] = t.sigma_ned_mps;
            let share = (north - TURBULENCE_FLOOR_MPS) / speed.max(1e-9);
            assert!(
                speed < 1e-3
                    || (TURBULENCE_SHARE_OF_WIND.0 - 1e-9..=TURBULENCE_SHARE_OF_WIND.1 + 1e-9)
                        .contains(&share),
                "seed {seed}: σ {north} m/s at {speed} m/s"
            );
            assert!(north >= TURBULENCE_FLOOR_MPS && east == north);
            assert!((down - TURBULENCE_VERTICAL_SHARE * north).abs() < 1e-12);
            let range = TURBULENCE_CORRELATION_S.0..=TURBULENCE_CORRELATION_S.1;
            assert!(range.contains(&t.correlation_s), "seed {seed}: τ {}", t.correlation_s);
            // The rest of the world is left as it was: the wind comes on its own aspect's draws.
            let mut without = config.board.world;
            without.steady_wind_ned_mps = [0.0; 3];
            without.turbulence = None;
            assert_eq!(without, nominal.board.world);
        }
        // The range is covered, not only respected.
        assert!(slowest < 0.5 && fastest > WIND_MAX_MPS - 0.5, "{slowest}–{fastest} m/s");
    }

    #[test]
    fn the_gnss_aspect_draws_a_receiver_and_leaves_the_rest_of_the_world_as_it_was() {
        let (mut quietest, mut noisiest) = (f64::INFINITY, 0.0f64);
        for seed in 0..200 {
            let (airframe, config) = random_world_case(seed, &[Aspect::Gnss]);
            let (nominal_airframe, nominal) = random_case(seed);
            assert_eq!(airframe, nominal_airframe);
            let receiver = config.gnss.clone().unwrap_or_else(|| panic!("seed {seed}: none"));
            receiver.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let sigma = receiver.horizontal_sigma_m;
            assert!((0.02..=2.0).contains(&sigma), "seed {seed}: {sigma} m");
            assert!((0.05..=0.15).contains(&receiver.latency_s), "seed {seed}");
            assert!((5.0..=10.0).contains(&receiver.rate_hz), "seed {seed}");
            (quietest, noisiest) = (quietest.min(sigma), noisiest.max(sigma));
            // Everything else is the nominal case's: the receiver comes on its own draws.
            assert_eq!(crate::recovery::FlyConfig { gnss: None, ..config }, nominal);
            // The rest of the random world is the same with the receiver and without it.
            let (with_airframe, with) =
                random_world_case(seed, &[Aspect::ALL.as_slice(), &[Aspect::Gnss]].concat());
            let (without_airframe, without) = random_world_case(seed, &Aspect::ALL);
            assert_eq!(with_airframe, without_airframe);
            assert_eq!(without.gnss, None, "no receiver unless asked for");
            assert_eq!(with.gnss, Some(receiver), "the same receiver in any world");
            assert_eq!(crate::recovery::FlyConfig { gnss: None, ..with }, without);
        }
        // Log-uniform over 0.02–2 m: the range is covered, not only respected.
        assert!(quietest < 0.03 && noisiest > 1.5, "{quietest}–{noisiest} m");
        assert_eq!(Aspect::parse("gnss"), Ok(Aspect::Gnss));
    }

    #[test]
    fn the_compass_aspect_draws_a_sensor_and_leaves_the_rest_of_the_world_as_it_was() {
        let (mut weakest, mut strongest) = (f64::INFINITY, 0.0f64);
        for seed in 0..200 {
            let every = [Aspect::ALL.as_slice(), &[Aspect::Gnss, Aspect::Compass]].concat();
            let (airframe, config) = random_world_case(seed, &every);
            let spec = config.compass.clone().unwrap_or_else(|| panic!("seed {seed}: none"));
            spec.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            assert_eq!(spec.motor_field_ut.len(), airframe.rotor_count(), "seed {seed}");
            assert!((25.0..=65.0).contains(&spec.strength_ut), "seed {seed}");
            assert!(spec.inclination_rad.abs() <= 70f64.to_radians(), "seed {seed}");
            assert!(spec.declination_rad.abs() <= 30f64.to_radians(), "seed {seed}");
            assert!(spec.hard_iron_ut.iter().all(|b| b.abs() <= 300.0), "seed {seed}");
            assert!((0.3..=2.0).contains(&spec.noise_ut) && (50.0..=100.0).contains(&spec.rate_hz));
            let share =
                spec.interference_ut(&vec![1.0; airframe.rotor_count()]).norm() / spec.strength_ut;
            assert!(share <= 0.5 + 1e-12, "seed {seed}: interference {share}");
            (weakest, strongest) = (weakest.min(spec.strength_ut), strongest.max(spec.strength_ut));
            // Every other draw is the one the seed gave without the compass.
            let (without_airframe, without) =
                random_world_case(seed, &[Aspect::ALL.as_slice(), &[Aspect::Gnss]].concat());
            assert_eq!(airframe, without_airframe);
            assert_eq!(without.compass, None, "no compass unless asked for");
            assert_eq!(FlyConfig { compass: None, ..config }, without);
            // The same sensor whatever else is drawn.
            let (_, alone) = random_world_case(seed, &[Aspect::Compass]);
            assert_eq!(alone.compass, Some(spec), "seed {seed}");
        }
        // The range is covered, not only respected.
        assert!(weakest < 27.0 && strongest > 63.0, "{weakest}–{strongest} µT");
        assert_eq!(Aspect::parse("compass"), Ok(Aspect::Compass));
    }

    #[test]
    fn a_forced_wind_speed_keeps_the_seeds_bearing_and_turbulence_draws() {
        let (_, drawn) = random_world_case(11, &[Aspect::Wind]);
        let (_, mut forced) = random_case(11);
        apply_wind_at(11, 5.0, &mut forced);
        let (d, f) = (&drawn.board.world, &forced.board.world);
        let (d_steady, f_steady) =
            (Vector3::from(d.steady_wind_ned_mps), Vector3::from(f.steady_wind_ned_mps));
        assert!((f_steady.norm() - 5.0).abs() < 1e-12);
        assert!((d_steady.normalize() - f_steady.normalize()).norm() < 1e-12, "the same bearing");
        let (dt, ft) = (d.turbulence.unwrap(), f.turbulence.unwrap());
        assert_eq!((dt.correlation_s, dt.seed), (ft.correlation_s, ft.seed));
        let share = |t: crate::board::Turbulence, speed: f64| {
            (t.sigma_ned_mps[0] - TURBULENCE_FLOOR_MPS) / speed
        };
        assert!((share(dt, d_steady.norm()) - share(ft, 5.0)).abs() < 1e-9);
    }
}
