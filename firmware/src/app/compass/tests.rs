//! The compass service against simulated sensors on a simulated bus: the register maps of the
//! IST8310 and the QMC5883L as their drivers' documents describe them, a field from a world
//! turned through the craft's attitude, with hard iron, soft iron, a mounting and noise.

use super::*;
use crate::app::system::Exclusive;
use flight::magnetometer::{tilt_compensated_heading, HeadingConfig};
use flight::rng::Rng;

/// A delay that only counts.
struct CountDelay(u64);

impl DelayUs for CountDelay {
    fn delay_us(&mut self, us: u32) {
        self.0 += u64::from(us);
    }
}

/// The bus's error: no acknowledge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Nack;

/// One magnetometer on a bus: its registers answer as the datasheets say, and each conversion
/// measures `raw = S (R_mag←imu Q_world←imuᵀ h) + b + noise` for the attitude set before it.
struct SimSensor {
    sensor: CompassSensor,
    address: u8,
    present: bool,
    registers: [u8; 256],
    world_field_ut: Vector3<f32>,
    q_world_imu: UnitQuaternion<f32>,
    q_mag_imu: UnitQuaternion<f32>,
    soft: Matrix3<f32>,
    hard_ut: Vector3<f32>,
    noise_ut: f32,
    rng: Rng,
    transfers: u32,
}

impl SimSensor {
    fn new(sensor: CompassSensor, address: u8) -> Self {
        let mut registers = [0u8; 256];
        registers[usize::from(ist8310::reg::WAI)] = ist8310::WAI_VALUE;
        if sensor == CompassSensor::Qmc5883l {
            registers[usize::from(qmc5883l::reg::CHIP_ID)] = qmc5883l::CHIP_ID_VALUE;
        }
        Self {
            sensor,
            address,
            present: true,
            registers,
            world_field_ut: Vector3::new(20.0, 2.0, 45.0),
            q_world_imu: UnitQuaternion::identity(),
            q_mag_imu: UnitQuaternion::identity(),
            soft: Matrix3::identity(),
            hard_ut: Vector3::zeros(),
            noise_ut: 0.0,
            rng: Rng::new(7),
            transfers: 0,
        }
    }

    /// The raw field, µT, sensor axes, for the attitude set now.
    fn raw_ut(&mut self) -> Vector3<f32> {
        let field_imu = self.q_world_imu.inverse_transform_vector(&self.world_field_ut);
        let noise = Vector3::from_fn(|_, _| self.rng.normal() as f32 * self.noise_ut);
        self.soft * (self.q_mag_imu * field_imu) + self.hard_ut + noise
    }

    /// A conversion into the data registers, in counts, with DRDY set.
    fn convert(&mut self) {
        let raw = self.raw_ut();
        let (per_lsb, first, status) = match self.sensor {
            CompassSensor::Qmc5883l => {
                (qmc5883l::UT_PER_LSB, qmc5883l::reg::DATA_X_LSB, qmc5883l::reg::STATUS)
            }
            _ => (ist8310::UT_PER_LSB, ist8310::reg::DATAXL, ist8310::reg::STAT1),
        };
        for axis in 0..3 {
            let counts = libm::roundf(raw[axis] / per_lsb) as i16;
            let [low, high] = counts.to_le_bytes();
            self.registers[usize::from(first) + 2 * axis] = low;
            self.registers[usize::from(first) + 2 * axis + 1] = high;
        }
        self.registers[usize::from(status)] |= 1;
    }
}

impl I2cRegisterBus for SimSensor {
    type Error = Nack;
    fn write_register(&mut self, address: u8, reg: u8, value: u8) -> Result<(), Nack> {
        self.transfers += 1;
        if !self.present || address != self.address {
            return Err(Nack);
        }
        match (self.sensor, reg) {
            // A single measurement started: it is ready by the next read (10 ms later).
            (CompassSensor::Ist8310, ist8310::reg::CNTL1) => {
                self.registers[usize::from(ist8310::reg::STAT1)] = 0;
                self.convert();
            }
            // Soft resets: nothing to reset in a simulation.
            (CompassSensor::Ist8310, ist8310::reg::CNTL2)
            | (CompassSensor::Qmc5883l, qmc5883l::reg::CONTROL2) => {}
            _ => self.registers[usize::from(reg)] = value,
        }
        Ok(())
    }

    fn read_registers(&mut self, address: u8, reg: u8, buf: &mut [u8]) -> Result<(), Nack> {
        self.transfers += 1;
        if !self.present || address != self.address {
            return Err(Nack);
        }
        for (i, b) in buf.iter_mut().enumerate() {
            *b = self.registers[(usize::from(reg) + i) & 0xFF];
        }
        // The QMC5883L converts continuously; reading its data clears DRDY.
        if self.sensor == CompassSensor::Qmc5883l {
            if reg == qmc5883l::reg::DATA_X_LSB {
                self.registers[usize::from(qmc5883l::reg::STATUS)] = 0;
            } else if reg == qmc5883l::reg::STATUS {
                self.convert();
                buf[0] = self.registers[usize::from(qmc5883l::reg::STATUS)];
            }
        }
        Ok(())
    }
}

fn quaternion(q: [f64; 4]) -> UnitQuaternion<f32> {
    UnitQuaternion::new_normalize(Quaternion::new(
        q[0] as f32,
        q[1] as f32,
        q[2] as f32,
        q[3] as f32,
    ))
}

fn q_array(q: &UnitQuaternion<f32>) -> [f32; 4] {
    [q.w, q.i, q.j, q.k]
}

/// Serviced every millisecond for `seconds`, the attitude from `attitude(t_s)`: the samples.
fn run(
    input: &mut CompassInput,
    sensor: &mut SimSensor,
    from_us: u64,
    seconds: f64,
    mut attitude: impl FnMut(f64) -> UnitQuaternion<f32>,
) -> (Vec<MagneticSample>, u64) {
    let mut samples = Vec::new();
    let mut delay = CountDelay(0);
    let mut now_us = from_us;
    let end_us = from_us + (seconds * 1e6) as u64;
    while now_us < end_us {
        let q = attitude(now_us as f64 * 1e-6);
        sensor.q_world_imu = q;
        input.set_attitude(Some(q_array(&q)));
        samples.extend(input.service(now_us, sensor, &mut delay));
        now_us += 1_000;
    }
    (samples, end_us)
}

#[test]
fn each_sensor_is_found_at_its_address_and_read_at_100_hz() {
    for (sensor, address) in [
        (CompassSensor::Ist8310, 0x0E),
        (CompassSensor::Ist8310, 0x0C),
        (CompassSensor::Qmc5883l, 0x0D),
    ] {
        let mut sim = SimSensor::new(sensor, address);
        sim.noise_ut = 0.5;
        let mut input = CompassInput::new();
        assert_eq!(input.health().state, CompassState::Absent);
        run(&mut input, &mut sim, 0, 3.0, |_| UnitQuaternion::identity());
        let h = input.health();
        assert_eq!((h.sensor, h.address, h.state), (sensor, address, CompassState::Healthy));
        assert!((h.rate_hz - 100.0).abs() <= 2.0, "{sensor:?}: {} Hz", h.rate_hz);
        assert!(h.readings >= 295 && h.failures == 0, "{h:?}");
        // Uncalibrated: the raw field's strength (49.6 µT here, 1 LSB of rounding).
        assert!((h.field_ut - sim.world_field_ut.norm()).abs() < 2.0, "{h:?}");
        assert!(!h.calibrated);
    }
}

#[test]
fn only_a_calibrated_enabled_compass_sends_samples_in_the_imu_axes() {
    let mut sim = SimSensor::new(CompassSensor::Ist8310, 0x0E);
    sim.hard_ut = Vector3::new(120.0, -80.0, 40.0);
    sim.soft = Matrix3::new(1.1, 0.05, 0.0, 0.05, 0.9, 0.02, 0.0, 0.02, 1.05);
    sim.q_mag_imu = UnitQuaternion::from_euler_angles(3.0, 0.2, 1.0);
    sim.noise_ut = 0.3;
    let mut input = CompassInput::new();
    let (samples, t) = run(&mut input, &mut sim, 0, 1.0, |_| UnitQuaternion::identity());
    assert!(samples.is_empty(), "uncalibrated: nothing for the pilot");
    // The exact calibration: W = S⁻¹ (symmetric here), b, the mounting.
    let w = sim.soft.try_inverse().unwrap();
    let calibration = CompassCalibration::new(
        sim.hard_ut.into(),
        core::array::from_fn(|i| core::array::from_fn(|j| w[(i, j)])),
        q_array(&sim.q_mag_imu),
        0.4,
    );
    input.configure(calibration, false);
    let (samples, t) = run(&mut input, &mut sim, t, 1.0, |_| UnitQuaternion::identity());
    assert!(samples.is_empty(), "disabled: nothing for the pilot");
    input.configure(calibration, true);
    let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 2.0);
    let (samples, _) = run(&mut input, &mut sim, t, 1.0, |_| q);
    assert!((98..=102).contains(&samples.len()), "{}", samples.len());
    let truth = q.inverse_transform_vector(&sim.world_field_ut);
    // The first was converted 10 ms before, at the attitude before.
    for s in &samples[1..] {
        assert!(s.is_valid());
        // 0.3 µT of noise and 0.3 µT a count, through W: within 2 µT.
        let error = (Vector3::from(s.field_imu_ut) - truth).norm();
        assert!(error < 2.0, "{s:?} against {truth:?}");
        assert_eq!(s.noise_ut, 0.4);
    }
    assert_eq!(input.health().samples_sent, samples.len() as u32);
}

#[test]
fn a_lost_sensor_is_counted_probed_for_and_found_again_and_a_stuck_one_sends_nothing() {
    let mut sim = SimSensor::new(CompassSensor::Qmc5883l, 0x0D);
    sim.noise_ut = 0.5;
    let mut input = CompassInput::new();
    input.configure(
        CompassCalibration::new(
            [0.0; 3],
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [1.0, 0.0, 0.0, 0.0],
            1.0,
        ),
        true,
    );
    let (_, t) = run(&mut input, &mut sim, 0, 1.0, |_| UnitQuaternion::identity());
    sim.present = false;
    let (samples, t) = run(&mut input, &mut sim, t, 0.5, |_| UnitQuaternion::identity());
    assert!(samples.is_empty());
    let h = input.health();
    assert_eq!((h.state, h.sensor, h.lost), (CompassState::Lost, CompassSensor::None, 1), "{h:?}");
    // Probed once a second while absent: three addresses a probe.
    sim.transfers = 0;
    let (_, t) = run(&mut input, &mut sim, t, 3.0, |_| UnitQuaternion::identity());
    assert!((6..=12).contains(&sim.transfers), "{} transfers in 3 s", sim.transfers);
    sim.present = true;
    let (samples, t) = run(&mut input, &mut sim, t, 2.0, |_| UnitQuaternion::identity());
    let h = input.health();
    assert_eq!((h.state, h.sensor, h.lost), (CompassState::Healthy, CompassSensor::Qmc5883l, 1));
    assert!(samples.len() > 90, "{}", samples.len());
    // A sensor that converts but whose value no longer changes (noise gone, craft still):
    // stuck after 25 identical readings, and no sample from then on.
    sim.noise_ut = 0.0;
    let (samples, _) = run(&mut input, &mut sim, t, 1.0, |_| UnitQuaternion::identity());
    let h = input.health();
    assert_eq!((h.state, h.stuck), (CompassState::Stuck, 1), "{h:?}");
    assert!(samples.len() <= 25, "{} samples from a frozen sensor", samples.len());
}

/// The attitude of a hand turning the craft: yaw all round, and roll and pitch through ±180°
/// and ±80° at other rates, so every face points up and down in a minute.
fn turning(t_s: f64) -> UnitQuaternion<f32> {
    let yaw = 0.9 * t_s;
    let roll = core::f64::consts::PI * (0.23 * t_s).sin();
    let pitch = 1.4 * (0.37 * t_s).sin();
    UnitQuaternion::from_euler_angles(roll as f32, pitch as f32, yaw as f32)
}

/// Gather for `seconds` with `attitude`, finish, solve in a background pass: the status.
fn calibrate(
    input: &mut CompassInput,
    sim: &mut SimSensor,
    seconds: f64,
    attitude: impl FnMut(f64) -> UnitQuaternion<f32> + Copy,
) -> (CompassCalibrationStatus, Vec<u8>) {
    let mut slot = CompassSolveSlot::new();
    let mut solver = CompassSolver::new();
    input.command(CompassCalibrationCommand::Start, 0);
    let mut coverage = Vec::new();
    let mut t = 0;
    // A second at a time, the background task running when the link asked it to.
    for _ in 0..(seconds as u64) {
        let (_, end) = run(input, sim, t, 1.0, attitude);
        t = end;
        if input.exchange(t, &mut Exclusive(&mut slot)) {
            run_compass_solve(&mut solver, &mut Exclusive(&mut slot));
            input.exchange(t, &mut Exclusive(&mut slot));
        }
        if let CompassCalibrationStatus::Gathering { coverage_pct, .. } = input.health().calibration
        {
            coverage.push(coverage_pct);
        }
    }
    input.command(CompassCalibrationCommand::Finish, t);
    assert!(input.exchange(t, &mut Exclusive(&mut slot)), "the final solve is asked for");
    assert!(matches!(input.health().calibration, CompassCalibrationStatus::Solving { .. }));
    run_compass_solve(&mut solver, &mut Exclusive(&mut slot));
    input.exchange(t, &mut Exclusive(&mut slot));
    (input.health().calibration, coverage)
}

/// The whole procedure on a sensor with hard iron (±200 µT), soft iron (±10 %), any mounting
/// and noise (0.3–1 µT), in a field of 40–60 µT at 30–65° of dip either way, turned as a hand
/// would for a minute, 12 draws: the stored calibration gives headings within 2° over a grid
/// of attitudes (pitch ±45°, roll ±45°, every yaw).
#[test]
fn the_procedure_stores_a_calibration_that_gives_headings_within_two_degrees() {
    let mut rng = Rng::new(55);
    for draw in 0..12 {
        let mut sim = SimSensor::new(CompassSensor::Ist8310, 0x0E);
        sim.hard_ut = Vector3::from_fn(|_, _| rng.range(-200.0, 200.0) as f32);
        let e = Matrix3::from_fn(|_, _| rng.range(-0.1, 0.1) as f32);
        sim.soft = Matrix3::identity() + (e + e.transpose()) * 0.5;
        sim.q_mag_imu = quaternion(rng.unit_quaternion());
        sim.noise_ut = rng.range(0.3, 1.0) as f32;
        // 40–60 µT, dip 30–65° either way, declination ±20°.
        let strength_ut = rng.range(40.0, 60.0) as f32;
        let decl = (rng.range(-20.0, 20.0) as f32).to_radians();
        let dip_deg = rng.range(30.0, 65.0) as f32 * if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
        let dip = dip_deg.to_radians();
        sim.world_field_ut =
            Vector3::new(decl.cos() * dip.cos(), decl.sin() * dip.cos(), dip.sin()) * strength_ut;
        let mut input = CompassInput::new();
        let (status, coverage) = calibrate(&mut input, &mut sim, 60.0, turning);
        let CompassCalibrationStatus::Stored { residual_ut, field_ut, coverage_pct, .. } = status
        else {
            panic!("draw {draw}: {status:?}");
        };
        // The fit's field strength is the ellipsoid's geometric mean: 50 µT scaled by the soft
        // iron's determinant's cube root.
        let scaled_ut = strength_ut * libm::cbrtf(sim.soft.determinant());
        assert!((field_ut - scaled_ut).abs() < 0.5, "{status:?} against {scaled_ut} µT");
        assert!(residual_ut < 1.5 * sim.noise_ut + 0.2, "{status:?}");
        assert!(coverage_pct >= 50, "{status:?}");
        // The progress grew as the craft turned.
        assert!(coverage.last() > coverage.first(), "{coverage:?}");
        let solved = input.take_solved().expect("solved");
        assert!(input.take_solved().is_none(), "handed over once");
        let calibration = solved.calibration;
        // The calibration judged without the noise (0.8 µT over a 25 µT horizontal field is
        // 1.8° per sample by itself).
        sim.noise_ut = 0.0;
        let config = HeadingConfig { declination_rad: decl, ..HeadingConfig::default() };
        let mut worst_deg = 0f32;
        for yaw in (0..360).step_by(15) {
            for pitch in [-45, 0, 45] {
                for roll in [-45, 0, 45] {
                    let q = UnitQuaternion::from_euler_angles(
                        (roll as f32).to_radians(),
                        (pitch as f32).to_radians(),
                        (yaw as f32).to_radians(),
                    );
                    sim.q_world_imu = q;
                    let raw: [f32; 3] = sim.raw_ut().into();
                    let sample = calibration.sample(&raw).expect("a sample");
                    let heading =
                        tilt_compensated_heading(&Vector3::from(sample.field_imu_ut), &q, &config)
                            .expect("a heading");
                    let error =
                        flight::attitude::wrap_pi(heading.yaw_rad - (yaw as f32).to_radians());
                    worst_deg = worst_deg.max(error.abs().to_degrees());
                }
            }
        }
        eprintln!("draw {draw}: {status:?}, worst heading error {worst_deg:.2}°");
        assert!(worst_deg < 2.0, "draw {draw}: worst heading error {worst_deg}°");
    }
}

/// Turned about the vertical alone the fit is refused with its reason, and nothing is stored;
/// too short a turning is refused for its samples.
#[test]
fn a_refused_fit_says_why_and_stores_nothing() {
    let mut sim = SimSensor::new(CompassSensor::Qmc5883l, 0x0D);
    sim.hard_ut = Vector3::new(50.0, 20.0, -30.0);
    sim.noise_ut = 0.5;
    let mut input = CompassInput::new();
    let yaw_only = |t: f64| UnitQuaternion::from_euler_angles(0.0, 0.0, (0.9 * t) as f32);
    let (status, _) = calibrate(&mut input, &mut sim, 30.0, yaw_only);
    assert!(
        matches!(
            status,
            CompassCalibrationStatus::Refused(
                CompassCalibrationRefusal::InsufficientCoverage { .. }
                    | CompassCalibrationRefusal::NotAnEllipsoid
            )
        ),
        "{status:?}"
    );
    assert!(input.take_solved().is_none());
    // Not even a second of samples.
    let mut slot = CompassSolveSlot::new();
    let mut solver = CompassSolver::new();
    input.command(CompassCalibrationCommand::Start, 0);
    run(&mut input, &mut sim, 0, 0.5, turning);
    input.command(CompassCalibrationCommand::Finish, 500_000);
    assert!(input.exchange(500_000, &mut Exclusive(&mut slot)));
    run_compass_solve(&mut solver, &mut Exclusive(&mut slot));
    input.exchange(500_000, &mut Exclusive(&mut slot));
    assert!(
        matches!(
            input.health().calibration,
            CompassCalibrationStatus::Refused(CompassCalibrationRefusal::TooFewSamples { samples })
                if samples < 100
        ),
        "{:?}",
        input.health().calibration
    );
    assert!(input.take_solved().is_none());
}

#[test]
fn start_is_refused_while_armed_or_without_a_sensor_and_finish_without_a_gathering() {
    use protocol::DeviceError;
    let healthy = CompassHealth { state: CompassState::Healthy, ..CompassHealth::default() };
    let start = CompassCalibrationCommand::Start;
    assert_eq!(
        CompassInput::check_command(&healthy, start, true),
        Err(DeviceError::RefusedWhileArmed)
    );
    assert_eq!(CompassInput::check_command(&healthy, start, false), Ok(()));
    let absent = CompassHealth::default();
    assert_eq!(CompassInput::check_command(&absent, start, false), Err(DeviceError::NotReady));
    let finish = CompassCalibrationCommand::Finish;
    assert_eq!(CompassInput::check_command(&healthy, finish, false), Err(DeviceError::NotReady));
    let gathering = CompassHealth {
        calibration: CompassCalibrationStatus::Gathering { samples: 10, coverage_pct: 0 },
        ..healthy
    };
    assert_eq!(CompassInput::check_command(&gathering, finish, false), Ok(()));
}

#[test]
fn a_calibration_with_a_non_finite_value_or_a_degenerate_mounting_is_none() {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    assert!(CompassCalibration::new([f32::NAN, 0.0, 0.0], identity, [1.0, 0.0, 0.0, 0.0], 1.0)
        .is_none());
    assert!(CompassCalibration::new([0.0; 3], identity, [0.1, 0.0, 0.0, 0.0], 1.0).is_none());
    assert!(CompassCalibration::new([0.0; 3], identity, [1.0, 0.0, 0.0, 0.0], 0.0).is_none());
    let c = CompassCalibration::new([0.0; 3], identity, [2.0, 0.0, 0.0, 0.0], 1.0).unwrap();
    assert_eq!(c.q_mag_imu, [1.0, 0.0, 0.0, 0.0]);
    assert!(c.sample(&[f32::INFINITY, 0.0, 0.0]).is_none());
}

/// The whole graph as the board runs it (`System::service_compass`, the link task's service):
/// the calibration gathered with the attitude from the control step's snapshot, solved by the
/// background task, stored in the parameters by the link task; from then on calibrated samples
/// wait in the control queue.
#[test]
fn through_the_system_a_calibration_is_stored_in_the_parameters_and_samples_reach_the_queue() {
    use crate::app::system::with_system;
    use crate::app::{ControlCommand, Settings};
    let mut sim = SimSensor::new(CompassSensor::Ist8310, 0x0E);
    sim.hard_ut = Vector3::new(80.0, -150.0, 60.0);
    sim.q_mag_imu = UnitQuaternion::from_euler_angles(0.0, 0.0, 1.2);
    sim.noise_ut = 0.5;
    let settings: Settings<crate::app::NoFlash> = Settings::without_store();
    let (stored, _) = with_system(settings, Default::default(), None, |system| {
        let mut delay = CountDelay(0);
        let mut service =
            |system: &mut crate::app::system::System<'_, _>, sim: &mut SimSensor, t_us: u64| {
                let q = turning(t_us as f64 * 1e-6);
                sim.q_world_imu = q;
                system.handoffs.snapshot.pilot.q_world_imu = q_array(&q);
                system.service_compass(t_us, sim, &mut delay);
                system.handoffs.commands.clear();
            };
        // Found, then a minute of turning.
        for ms in 0..1_000 {
            service(system, &mut sim, ms * 1_000);
        }
        assert!(system.link.compass_mut().is_some());
        system.link.compass_mut().unwrap().command(CompassCalibrationCommand::Start, 1_000_000);
        for ms in 1_000..61_000 {
            service(system, &mut sim, ms * 1_000);
        }
        system.link.compass_mut().unwrap().command(CompassCalibrationCommand::Finish, 61_000_000);
        service(system, &mut sim, 61_000_000);
        service(system, &mut sim, 61_001_000);
        let health = system.status_view().compass.expect("a compass");
        assert!(
            matches!(health.calibration, CompassCalibrationStatus::Stored { .. }),
            "{health:?}"
        );
        assert!(health.calibrated, "in force at once");
        // Calibrated samples now reach the control queue.
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
        sim.q_world_imu = q;
        // (The first read collects the conversion started at the attitude before.)
        system.service_compass(61_020_000, &mut sim, &mut delay);
        system.handoffs.commands.clear();
        system.service_compass(61_030_000, &mut sim, &mut delay);
        system.service_compass(61_040_000, &mut sim, &mut delay);
        let truth = q.inverse_transform_vector(&sim.world_field_ut);
        let samples: Vec<MagneticSample> = system
            .handoffs
            .commands
            .iter()
            .filter_map(|c| match c {
                ControlCommand::MagneticField(s) => Some(*s),
                _ => None,
            })
            .collect();
        assert_eq!(samples.len(), 2);
        for s in &samples {
            // The fit's field strength is the raw one's (no soft iron here): within 2 µT.
            assert!((Vector3::from(s.field_imu_ut) - truth).norm() < 2.0, "{s:?} {truth:?}");
        }
        system.link.settings().params().compass_calibration()
    });
    let stored = stored.expect("stored");
    for (fitted, truth) in stored.offset_ut.iter().zip(sim.hard_ut.iter()) {
        assert!((fitted - truth).abs() < 1.0, "{:?} against {:?}", stored.offset_ut, sim.hard_ut);
    }
}

/// A trial fit the background task finishes after the final solve was asked for is dropped:
/// the final outcome is the one taken. Arming while gathering refuses the calibration.
#[test]
fn a_late_trial_outcome_is_dropped_and_arming_refuses_a_gathering() {
    let mut sim = SimSensor::new(CompassSensor::Ist8310, 0x0E);
    sim.hard_ut = Vector3::new(30.0, -40.0, 10.0);
    sim.noise_ut = 0.5;
    let mut input = CompassInput::new();
    let mut slot = CompassSolveSlot::new();
    let mut solver = CompassSolver::new();
    input.command(CompassCalibrationCommand::Start, 0);
    let (_, t) = run(&mut input, &mut sim, 0, 40.0, turning);
    assert!(input.exchange(t, &mut Exclusive(&mut slot)), "a trial asked for");
    input.command(CompassCalibrationCommand::Finish, t);
    assert!(input.exchange(t, &mut Exclusive(&mut slot)), "the final replaces it");
    // The trial's outcome written late, after the final request.
    slot.outcome = Some(SolveOutcome::Trial { coverage: 0.3 });
    assert!(!input.exchange(t, &mut Exclusive(&mut slot)));
    assert!(matches!(input.health().calibration, CompassCalibrationStatus::Solving { .. }));
    run_compass_solve(&mut solver, &mut Exclusive(&mut slot));
    input.exchange(t, &mut Exclusive(&mut slot));
    assert!(
        matches!(input.health().calibration, CompassCalibrationStatus::Stored { .. }),
        "{:?}",
        input.health().calibration
    );
    input.command(CompassCalibrationCommand::Start, t);
    input.set_armed(true);
    assert_eq!(
        input.health().calibration,
        CompassCalibrationStatus::Refused(CompassCalibrationRefusal::Armed)
    );
    assert!(!input.exchange(t + 3_000_000, &mut Exclusive(&mut slot)), "nothing more solved");
}
