//! The compass calibration end to end on the host, with a sensor the firmware did not write:
//! `sim::magnetometer::SimMagnetometer` (the random world's ranges: 25–65 µT at −70…+70° of dip,
//! hard iron ±300 µT, soft iron and cross-axis ±20 %, any mounting, 0.3–2 µT of noise) behind an
//! IST8310's register map, read by the firmware's own driver through the application graph as
//! the board runs it (`System::service_compass`: the link task's service, the background task's
//! solve, the parameters). The user's part (the craft turned by hand through every orientation
//! for a minute, disarmed) is a turning of the attitude the control step's snapshot reports.
//!
//! Scored against the simulator's truth: the stored calibration applied to the sensor's clean
//! reading gives the tilt-compensated heading at a grid of attitudes (every 15° of yaw, roll and
//! pitch −45°, 0, +45°), compared with the attitude's yaw, per draw. Measured (seeds 0–31,
//! 2026-12-03): all 32 stored; 31 with a horizontal field of at least 15 µT within 1.61° (27 µT
//! at 42° of dip, 1.9 µT of noise); seed 22, 9.9 µT horizontal (29 µT at 70° of dip) with 1.9 µT
//! of noise, 2.44°: the errors grow with the noise over the horizontal field, as
//! `flight::magnetometer` documents.
//!
//! `cargo test -p tests --release --test compass_calibration -- --nocapture` prints the figures.

use firmware::app::compass::MagneticSample;
use firmware::app::system::with_system;
use firmware::app::{NoFlash, Settings};
use firmware::drivers::compass::{DelayUs, I2cRegisterBus};
use firmware::drivers::ist8310;
use flight::magnetometer::{tilt_compensated_heading, HeadingConfig};
use nalgebra::{UnitQuaternion, Vector3};
use protocol::{CompassCalibrationCommand, CompassCalibrationStatus};
use sim::magnetometer::{MagnetometerSpec, SimMagnetometer};
use sim::rng::Rng;

/// The IST8310's registers around a simulated sensor: WAI, and a single measurement taken at
/// each CNTL1 write (the attitude set before it), its counts at 0.3 µT/LSB with DRDY.
struct Ist8310Bus {
    sensor: SimMagnetometer,
    registers: [u8; 256],
    q_world_imu: UnitQuaternion<f64>,
}

#[derive(Debug)]
struct Nack;

impl Ist8310Bus {
    fn new(sensor: SimMagnetometer) -> Self {
        let mut registers = [0u8; 256];
        registers[usize::from(ist8310::reg::WAI)] = ist8310::WAI_VALUE;
        Self { sensor, registers, q_world_imu: UnitQuaternion::identity() }
    }
}

impl I2cRegisterBus for Ist8310Bus {
    type Error = Nack;
    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Nack> {
        if address != ist8310::DEFAULT_ADDRESS {
            return Err(Nack);
        }
        if reg == ist8310::reg::CNTL1 {
            let raw = self.sensor.sample(&self.q_world_imu, &[0.0; 4]);
            for axis in 0..3 {
                let counts = (raw[axis] / f64::from(ist8310::UT_PER_LSB)).round() as i16;
                let [low, high] = counts.to_le_bytes();
                let at = usize::from(ist8310::reg::DATAXL) + 2 * axis;
                self.registers[at] = low;
                self.registers[at + 1] = high;
            }
            self.registers[usize::from(ist8310::reg::STAT1)] = ist8310::STAT1_DRDY;
        } else if reg != ist8310::reg::CNTL2 {
            self.registers[usize::from(reg)] = value;
        }
        Ok(())
    }

    fn read_registers(&mut self, address: u8, reg: u8, buf: &mut [u8]) -> Result<(), Nack> {
        if address != ist8310::DEFAULT_ADDRESS {
            return Err(Nack);
        }
        for (i, b) in buf.iter_mut().enumerate() {
            *b = self.registers[usize::from(reg) + i];
        }
        Ok(())
    }
}

/// Below this horizontal field, µT, the sensor's noise over the field is what limits the heading
/// (2 µT over 10 µT is 11° a sample): the 2° is asked above it.
const WEAK_HORIZONTAL_UT: f64 = 15.0;

struct NoDelay;

impl DelayUs for NoDelay {
    fn delay_us(&mut self, _us: u32) {}
}

/// A hand turning the craft: all round in yaw, roll through ±180°, pitch through ±80°, at
/// incommensurate rates, so every face points up and down within the minute.
fn turning(t_s: f64) -> UnitQuaternion<f64> {
    let roll = std::f64::consts::PI * (0.23 * t_s).sin();
    let pitch = 1.4 * (0.37 * t_s).sin();
    UnitQuaternion::from_euler_angles(roll, pitch, 0.9 * t_s)
}

/// Calibrate `spec`'s sensor through the application graph; the calibration's status and the
/// worst heading error over the grid, degrees (`None` when nothing was stored).
fn calibrate(spec: MagnetometerSpec, seed: u64) -> (CompassCalibrationStatus, Option<f64>) {
    let mut bus = Ist8310Bus::new(SimMagnetometer::new(spec.clone(), seed));
    let settings: Settings<NoFlash> = Settings::without_store();
    let ((status, calibration), _) = with_system(settings, Default::default(), None, |system| {
        let service = |system: &mut firmware::app::system::System<'_, NoFlash>,
                       bus: &mut Ist8310Bus,
                       ms: u64| {
            let q = turning(ms as f64 * 1e-3);
            bus.q_world_imu = q;
            let qf = q.cast::<f32>();
            system.handoffs.snapshot.pilot.q_world_imu = [qf.w, qf.i, qf.j, qf.k];
            system.service_compass(ms * 1_000, bus, &mut NoDelay);
            system.handoffs.commands.clear();
        };
        for ms in 0..1_000 {
            service(system, &mut bus, ms);
        }
        let compass = system.link.compass_mut().expect("a compass bus");
        compass.command(CompassCalibrationCommand::Start, 1_000_000);
        for ms in 1_000..61_000 {
            service(system, &mut bus, ms);
        }
        let compass = system.link.compass_mut().expect("a compass bus");
        compass.command(CompassCalibrationCommand::Finish, 61_000_000);
        service(system, &mut bus, 61_000);
        service(system, &mut bus, 61_001);
        let status = system.status_view().compass.expect("a compass").calibration;
        (status, system.link.settings().params().compass_calibration())
    });
    let Some(calibration) = calibration else { return (status, None) };
    let config =
        HeadingConfig { declination_rad: spec.declination_rad as f32, ..HeadingConfig::default() };
    let mut worst_deg = 0f64;
    for yaw_deg in (0..360).step_by(15) {
        for pitch_deg in [-45.0f64, 0.0, 45.0] {
            for roll_deg in [-45.0f64, 0.0, 45.0] {
                let yaw = f64::from(yaw_deg).to_radians();
                let q = UnitQuaternion::from_euler_angles(
                    roll_deg.to_radians(),
                    pitch_deg.to_radians(),
                    yaw,
                );
                let raw = spec.clean_reading_ut(&q, &[0.0; 4]).cast::<f32>();
                let sample: MagneticSample = calibration.sample(&raw.into()).expect("a sample");
                let heading = tilt_compensated_heading(
                    &Vector3::from(sample.field_imu_ut),
                    &q.cast::<f32>(),
                    &config,
                )
                .expect("a heading");
                let error = flight::attitude::wrap_pi(heading.yaw_rad - yaw as f32);
                worst_deg = worst_deg.max(f64::from(error.abs()).to_degrees());
            }
        }
    }
    (status, Some(worst_deg))
}

/// Over 32 of the random world's sensors and fields, every calibration is stored and gives
/// headings within 2° where the horizontal field is at least [`WEAK_HORIZONTAL_UT`]; below it
/// (near the dip poles) within 3°, reported apart.
#[test]
fn the_stored_calibration_gives_headings_within_two_degrees_over_the_random_worlds_sensors() {
    let mut rng = Rng::new(55);
    let mut worst = (0, 0f64);
    let mut weak = Vec::new();
    for seed in 0..32u64 {
        let spec = MagnetometerSpec::random(&mut rng, 4);
        let horizontal_ut = spec.strength_ut * spec.inclination_rad.cos();
        let (status, worst_deg) = calibrate(spec.clone(), seed);
        let worst_deg = worst_deg.unwrap_or_else(|| panic!("seed {seed}: {status:?}"));
        println!(
            "seed {seed}: {:.0} µT at {:+.0}°, horizontal {horizontal_ut:.1} µT, noise {:.2} µT: \
             {status:?}, worst heading error {worst_deg:.2}°",
            spec.strength_ut,
            spec.inclination_rad.to_degrees(),
            spec.noise_ut
        );
        if horizontal_ut < WEAK_HORIZONTAL_UT {
            assert!(worst_deg < 3.0, "seed {seed} (weak field): {worst_deg:.2}°");
            weak.push((seed, worst_deg));
        } else {
            assert!(worst_deg < 2.0, "seed {seed}: worst heading error {worst_deg:.2}°");
            if worst_deg > worst.1 {
                worst = (seed, worst_deg);
            }
        }
    }
    println!("worst: seed {}, {:.2}°; horizontal field below 15 µT: {weak:?}", worst.0, worst.1);
}

/// `configurator-cli compass calibrate`'s flow (`configurator_cli::compass::calibrate`) over
/// TCP against the application graph serving its links in real time, its compass the
/// simulator's behind the IST8310's registers, turned by hand: the board gathers while the
/// configurator shows the progress, solves, stores; the parameters say so over the link, and
/// `doctor`'s line reads "calibrated". Runs about 20 s (the least gathering time).
#[test]
fn compass_calibrate_over_tcp_stores_the_calibration_in_the_parameters() {
    use configurator_cli::link::Client;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    let mut links = sim::serve::TcpLinks::bind(0, sim::serve::simulator_board_info("SITL", 3, 4))
        .expect("a TCP port");
    let address = links.local_addr().expect("its address");
    let stop = Arc::new(AtomicBool::new(false));
    let stop_board = stop.clone();
    let mut rng = Rng::new(9);
    let spec = MagnetometerSpec { noise_ut: 0.8, ..MagnetometerSpec::random(&mut rng, 4) };
    let board = std::thread::spawn(move || {
        let mut bus = Ist8310Bus::new(SimMagnetometer::new(spec, 9));
        let settings: Settings<NoFlash> = Settings::without_store();
        with_system(settings, Default::default(), None, |system| {
            let start = Instant::now();
            while !stop_board.load(Ordering::Relaxed) {
                let now_us = start.elapsed().as_micros() as u64;
                // Turned twice as fast as `turning`: the sphere is covered in about 10 s of the
                // 20 s, so a test machine that stalls this thread for seconds (measured: 4 s
                // with three builds beside it) still gives the coverage.
                let q = turning(2.0 * now_us as f64 * 1e-6);
                bus.q_world_imu = q;
                let qf = q.cast::<f32>();
                system.handoffs.snapshot.pilot.q_world_imu = [qf.w, qf.i, qf.j, qf.k];
                links.accept();
                system.pass(now_us, &mut links);
                system.service_compass(now_us, &mut bus, &mut NoDelay);
                system.handoffs.commands.clear();
                std::thread::sleep(Duration::from_millis(1));
            }
        });
    });
    let stream = std::net::TcpStream::connect(address).expect("connected");
    stream.set_read_timeout(Some(Duration::from_millis(50))).expect("a read timeout");
    let mut client = Client::connect(Box::new(stream), "tcp").expect("a handshake");
    let result = configurator_cli::compass::calibrate(&mut client, 20.0, false);
    let health = match client.request(&protocol::Request::GetCompass(()), "compass") {
        Ok(protocol::Reply::Compass(health)) => health,
        other => panic!("{other:?}"),
    };
    let valid = configurator_cli::config::fetch(
        &mut client,
        protocol::ParamRef::Name(protocol::text("compass_cal_valid")),
    )
    .expect("the parameter");
    stop.store(true, Ordering::Relaxed);
    board.join().expect("the board's thread");
    let text = result.expect("stored");
    println!("{text}");
    assert!(text.starts_with("stored: field"), "{text}");
    assert_eq!(valid.value.as_slice(), &[1.0]);
    assert!(health.calibrated, "{health:?}");
    let line = configurator_cli::doctor::compass_line(Some(&health));
    assert!(
        line.found.contains("IST8310 at 0x0E") && line.found.ends_with("calibrated"),
        "{}",
        line.found
    );
}
