//! Fault injection: a schedule of sensor, actuator and pose faults the simulated board applies as
//! it produces the IMU samples, turns the rotors and (through the flight harness) sends poses.
//!
//! # API
//! ```
//! use sim::faults::{Fault, FaultKind, FaultSchedule};
//!
//! // From 2.0 s of board time on, gyro y reads its last value; from 3.0 s for 0.5 s, motor 1
//! // makes half its thrust and drag torque.
//! let schedule = FaultSchedule::default()
//!     .with(Fault::from(2.0, FaultKind::GyroStuck { axis: 1 }))
//!     .with(Fault { start_s: 3.0, duration_s: 0.5, kind: FaultKind::MotorThrust { motor: 1, factor: 0.5 } });
//! assert_eq!(schedule.faults().len(), 2);
//! ```
//! Put the schedule in [`SimConfig::faults`](crate::board::SimConfig::faults), or add faults while
//! flying with [`SimBoard::faults_mut`](crate::board::SimBoard::faults_mut).
//!
//! - **When.** A fault acts on every control tick (500 µs) whose *end* (the board time
//!   [`SimBoard::now_us`](crate::board::SimBoard::now_us) after the tick, which is the time of the
//!   tick's IMU sample) lies in `[start_s, start_s + duration_s)`; so the first faulty sample is
//!   the one the application reads at `now_us ≥ start_s`. A pose is lost while a
//!   [`FaultKind::PoseLost`] is active at the time it would be sent.
//! - **What** (each as the hardware would fail):
//!   - [`FaultKind::ImuNan`]: every gyro and accelerometer value of the sample is NaN (a broken data
//!     path: the ICM-42688-P's registers are 16-bit integers and cannot hold one);
//!   - [`FaultKind::ImuInf`]: one accelerometer axis reads +∞ (the same, through a bad scale);
//!   - [`FaultKind::GyroStuck`]: one gyro axis repeats the value it had in the last sample before
//!     the fault, bit for bit (a frozen register), the others stay live;
//!   - [`FaultKind::AccelSaturated`]: one accelerometer axis reads the ±16 g full scale of the
//!     ICM-42688-P ([`ACCEL_FULL_SCALE_MPS2`]: +32767 or −32768 codes at 2048 LSB/g);
//!   - [`FaultKind::MotorThrust`]: one rotor's thrust and drag-torque coefficients are scaled by
//!     `factor` (a chipped or loose propeller: the motor still turns at the commanded speed and
//!     reports it, but it pushes less);
//!   - [`FaultKind::PoseLost`]: the external pose stops arriving (motion capture lost the craft);
//!   - [`FaultKind::ImuMissing`]: the tick delivers no IMU sample (a late data-ready interrupt, a
//!     failed SPI transfer the driver discarded);
//!   - [`FaultKind::ImuFrozen`]: the sample repeats the previous one delivered, every value bit
//!     for bit (a stale FIFO or register read);
//!   - [`FaultKind::SpeedReportLost`]: one motor's speed report is missing (its ESC does not
//!     answer, or answers garbage the driver rejects);
//!   - [`FaultKind::MotorOutputsSwapped`]: the commands of outputs `a` and `b` drive each other's
//!     rotors while each rotor's speed is still reported under its own index (a motor map that
//!     disagrees with the speed reports: what `configurator-cli doctor`'s spin test finds).
//! - An empty schedule changes nothing: flights without faults are bit-identical to flights on a
//!   board built without one.
//!
//! # The SITL's faults
//! [`SitlFaults`] (the `sitl` binary's and `configurator-cli --sitl`'s `--fault-*` flags,
//! [`SitlFaultArgs`]) start a SITL with a board that is broken from power-up, as a bring-up check
//! (`configurator-cli doctor`) must find it: an ESC that never answers, an IMU that is silent,
//! frozen or [`NOISY_IMU_FACTOR`] times too noisy, a flash whose reads and writes fail
//! ([`crate::flash::FlashFault`]), two motor outputs driving each other's rotors.

use firmware::app::hal::ImuSample;

use crate::airframe::{Airframe, MAX_ROTORS, STANDARD_GRAVITY_MPS2};
use crate::flash::FlashFault;

/// The accelerometer's full scale, m/s²: the ICM-42688-P at ±16 g (the library airframes'
/// `range_mps2` = 156.9). A saturated axis reads +32767/32768 of it or −1 times it.
pub const ACCEL_FULL_SCALE_MPS2: f64 = 16.0 * STANDARD_GRAVITY_MPS2;

/// One kind of fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FaultKind {
    /// Every value of the IMU sample is NaN.
    ImuNan,
    /// Accelerometer axis `axis` (0–2, IMU axes) reads +∞.
    ImuInf {
        /// The axis.
        axis: usize,
    },
    /// Gyro axis `axis` (0–2, IMU axes) repeats its last value before the fault.
    GyroStuck {
        /// The axis.
        axis: usize,
    },
    /// Accelerometer axis `axis` (0–2, IMU axes) reads full scale, `+` or `−` ([`ACCEL_FULL_SCALE_MPS2`]).
    AccelSaturated {
        /// The axis.
        axis: usize,
        /// At −16 g rather than +16 g.
        negative: bool,
    },
    /// Rotor `motor`'s thrust and drag torque are scaled by `factor` (e.g. 0.5).
    MotorThrust {
        /// The rotor (motor order).
        motor: usize,
        /// The factor, in (0, 1] for a loss.
        factor: f64,
    },
    /// No external pose is sent.
    PoseLost,
    /// No IMU sample is delivered.
    ImuMissing,
    /// The IMU sample repeats the previous one delivered, bit for bit.
    ImuFrozen,
    /// Motor `motor`'s speed is not reported.
    SpeedReportLost {
        /// The motor (motor order).
        motor: usize,
    },
    /// Output `a`'s command drives rotor `b` and output `b`'s drives rotor `a`; the speed
    /// reports stay with the rotors (rotor `a`'s speed is reported as motor `a`).
    MotorOutputsSwapped {
        /// One output (motor order).
        a: usize,
        /// The other.
        b: usize,
    },
}

/// One fault: what, from when, for how long.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fault {
    /// Board time it starts, s.
    pub start_s: f64,
    /// How long it lasts, s (`f64::INFINITY`: to the end).
    pub duration_s: f64,
    /// What fails.
    pub kind: FaultKind,
}

impl Fault {
    /// `kind` from `start_s` to the end of the run.
    pub fn from(start_s: f64, kind: FaultKind) -> Self {
        Self { start_s, duration_s: f64::INFINITY, kind }
    }

    /// Whether it acts on the tick ending at board time `t_s`.
    pub fn active(&self, t_s: f64) -> bool {
        t_s >= self.start_s && t_s < self.start_s + self.duration_s
    }
}

/// A schedule of faults (the configuration; [`FaultInjector`] applies it).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FaultSchedule {
    faults: Vec<Fault>,
}

impl FaultSchedule {
    /// The schedule with `fault` added.
    pub fn with(mut self, fault: Fault) -> Self {
        self.faults.push(fault);
        self
    }

    /// The faults, in the order added.
    pub fn faults(&self) -> &[Fault] {
        &self.faults
    }
}

/// Applies a [`FaultSchedule`] tick by tick (what [`SimBoard`](crate::board::SimBoard) holds).
#[derive(Clone, Debug, Default)]
pub struct FaultInjector {
    schedule: FaultSchedule,
    /// The gyro of the last sample delivered (for a stuck axis).
    last_gyro_rad_s: Option<[f32; 3]>,
    /// The last sample delivered (for a frozen IMU).
    last_sample: Option<ImuSample>,
    /// The thrust factor each rotor has now.
    factors: [f64; MAX_ROTORS],
}

impl FaultInjector {
    /// An injector for `schedule`.
    pub fn new(schedule: &FaultSchedule) -> Self {
        Self {
            schedule: schedule.clone(),
            last_gyro_rad_s: None,
            last_sample: None,
            factors: [1.0; MAX_ROTORS],
        }
    }

    /// Add `fault` to the schedule (e.g. when the flight reaches a state).
    pub fn add(&mut self, fault: Fault) {
        self.schedule.faults.push(fault);
    }

    /// The schedule.
    pub fn schedule(&self) -> &FaultSchedule {
        &self.schedule
    }

    fn active(&self, t_s: f64) -> impl Iterator<Item = &FaultKind> {
        self.schedule.faults.iter().filter(move |f| f.active(t_s)).map(|f| &f.kind)
    }

    /// The thrust factor of every rotor on the tick ending at `t_s`, and whether any changed
    /// since the previous call (only then must the physics be told).
    pub fn thrust_factors(&mut self, t_s: f64) -> Option<[f64; MAX_ROTORS]> {
        if self.schedule.faults.is_empty() {
            return None;
        }
        let mut factors = [1.0; MAX_ROTORS];
        for kind in self.active(t_s) {
            if let FaultKind::MotorThrust { motor, factor } = *kind {
                if let Some(f) = factors.get_mut(motor) {
                    *f *= factor;
                }
            }
        }
        let changed = factors != self.factors;
        self.factors = factors;
        changed.then_some(factors)
    }

    /// Corrupt the sample of the tick ending at `t_s` as the active IMU faults say. Returns
    /// whether the sample is delivered at all ([`FaultKind::ImuMissing`]).
    pub fn corrupt_imu(&mut self, t_s: f64, sample: &mut ImuSample) -> bool {
        if self.schedule.faults.is_empty() {
            // Remembered for a stuck axis or a frozen IMU added later.
            self.last_gyro_rad_s = Some(sample.gyro_rad_s);
            self.last_sample = Some(*sample);
            return true;
        }
        let last = self.last_gyro_rad_s;
        let kinds: Vec<FaultKind> = self.active(t_s).copied().collect();
        let mut delivered = true;
        for kind in kinds {
            match kind {
                FaultKind::ImuNan => {
                    sample.gyro_rad_s = [f32::NAN; 3];
                    sample.accel_mps2 = [f32::NAN; 3];
                }
                FaultKind::ImuInf { axis } => sample.accel_mps2[axis % 3] = f32::INFINITY,
                FaultKind::GyroStuck { axis } => {
                    if let Some(last) = last {
                        sample.gyro_rad_s[axis % 3] = last[axis % 3];
                    }
                }
                FaultKind::AccelSaturated { axis, negative } => {
                    sample.accel_mps2[axis % 3] = if negative {
                        -ACCEL_FULL_SCALE_MPS2 as f32
                    } else {
                        (ACCEL_FULL_SCALE_MPS2 * 32767.0 / 32768.0) as f32
                    };
                }
                FaultKind::ImuMissing => delivered = false,
                FaultKind::ImuFrozen => {
                    if let Some(last) = self.last_sample {
                        *sample = last;
                    }
                }
                FaultKind::MotorThrust { .. }
                | FaultKind::PoseLost
                | FaultKind::SpeedReportLost { .. }
                | FaultKind::MotorOutputsSwapped { .. } => {}
            }
        }
        if delivered {
            self.last_gyro_rad_s = Some(sample.gyro_rad_s);
            self.last_sample = Some(*sample);
        }
        delivered
    }

    /// Whether motor `motor`'s speed report is lost on the tick ending at `t_s`.
    pub fn speed_report_lost(&self, t_s: f64, motor: usize) -> bool {
        self.active(t_s).any(|kind| *kind == FaultKind::SpeedReportLost { motor })
    }

    /// The output whose command drives rotor `rotor` on the tick ending at `t_s` (the rotor's
    /// own index unless a [`FaultKind::MotorOutputsSwapped`] names it).
    pub fn output_of_rotor(&self, t_s: f64, rotor: usize) -> usize {
        let mut output = rotor;
        for kind in self.active(t_s) {
            if let FaultKind::MotorOutputsSwapped { a, b } = *kind {
                if output == a {
                    output = b;
                } else if output == b {
                    output = a;
                }
            }
        }
        output
    }

    /// Whether the external pose is lost at board time `t_s`.
    pub fn pose_lost(&self, t_s: f64) -> bool {
        self.active(t_s).any(|kind| *kind == FaultKind::PoseLost)
    }
}

/// How much noisier than its airframe's model a `--fault-imu noisy` IMU is (gyro and
/// accelerometer white-noise densities): 30×, far beyond any margin a bring-up check allows for
/// a bench's vibration (`configurator-cli doctor` fails above 5× the datasheet's noise).
pub const NOISY_IMU_FACTOR: f64 = 30.0;

/// How the SITL's IMU fails from power-up (`--fault-imu`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ImuFault {
    /// No sample ever arrives ([`FaultKind::ImuMissing`]): a dead sensor or a broken bus.
    Silent,
    /// Every sample repeats the first one bit for bit ([`FaultKind::ImuFrozen`]).
    Frozen,
    /// Gyro and accelerometer white noise [`NOISY_IMU_FACTOR`] times the airframe's.
    Noisy,
}

/// The faults a SITL runs with from its start (see the module doc). The default: none.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SitlFaults {
    /// Motors (index from 0) whose ESC never reports a speed ([`FaultKind::SpeedReportLost`]).
    pub esc_silent: Vec<u8>,
    /// How the IMU fails, if it does.
    pub imu: Option<ImuFault>,
    /// How the configuration flash fails, if it does.
    pub flash: Option<FlashFault>,
    /// Two motor outputs (index from 0) whose commands drive each other's rotors
    /// ([`FaultKind::MotorOutputsSwapped`]).
    pub motor_swap: Option<[u8; 2]>,
}

impl SitlFaults {
    /// Checked against an airframe of `motor_count` motors: the message names the bad value.
    pub fn validate(&self, motor_count: usize) -> Result<(), String> {
        let in_range = |m: u8| usize::from(m) < motor_count;
        if let Some(&bad) = self.esc_silent.iter().find(|&&m| !in_range(m)) {
            return Err(format!(
                "--fault-esc-silent {bad}: the airframe has motors 0 to {}",
                motor_count.saturating_sub(1)
            ));
        }
        if let Some([a, b]) = self.motor_swap {
            if a == b || !in_range(a) || !in_range(b) {
                return Err(format!(
                    "--fault-motor-swap {a},{b}: two different motors of 0 to {}",
                    motor_count.saturating_sub(1)
                ));
            }
        }
        Ok(())
    }

    /// The schedule of these faults, each from board time 0 to the end.
    pub fn schedule(&self) -> FaultSchedule {
        let mut schedule = FaultSchedule::default();
        for &motor in &self.esc_silent {
            let kind = FaultKind::SpeedReportLost { motor: usize::from(motor) };
            schedule = schedule.with(Fault::from(0.0, kind));
        }
        match self.imu {
            Some(ImuFault::Silent) => {
                schedule = schedule.with(Fault::from(0.0, FaultKind::ImuMissing))
            }
            Some(ImuFault::Frozen) => {
                schedule = schedule.with(Fault::from(0.0, FaultKind::ImuFrozen))
            }
            Some(ImuFault::Noisy) | None => {}
        }
        if let Some([a, b]) = self.motor_swap {
            let kind = FaultKind::MotorOutputsSwapped { a: usize::from(a), b: usize::from(b) };
            schedule = schedule.with(Fault::from(0.0, kind));
        }
        schedule
    }

    /// `airframe` with the IMU these faults give it (a noisy IMU's noise densities scaled).
    pub fn apply_to_airframe(&self, airframe: &mut Airframe) {
        if self.imu == Some(ImuFault::Noisy) {
            airframe.imu.gyro.noise_density_rad_s_per_sqrt_hz *= NOISY_IMU_FACTOR;
            airframe.imu.accel.noise_density_mps2_per_sqrt_hz *= NOISY_IMU_FACTOR;
        }
    }
}

/// The `--fault-*` flags of a SITL (the `sitl` binary and `configurator-cli --sitl`).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SitlFaultArgs {
    /// Fault injection: motor N's ESC (index from 0, as `motor-test --motor`) never reports its
    /// speed. Repeat for more motors.
    #[arg(long, global = true, value_name = "N")]
    pub fault_esc_silent: Vec<u8>,
    /// Fault injection: the IMU delivers no samples (silent), repeats its first sample (frozen),
    /// or is 30× noisier than the airframe's (noisy).
    #[arg(long, global = true, value_enum, value_name = "HOW")]
    pub fault_imu: Option<ImuFault>,
    /// Fault injection: every read of the configuration flash reports an error and every write
    /// fails (bad); the flash file is left untouched.
    #[arg(long, global = true, value_enum, value_name = "HOW")]
    pub fault_flash: Option<FlashFault>,
    /// Fault injection: outputs A and B (index from 0) drive each other's motors, while each
    /// motor's speed is reported under its own number.
    #[arg(long, global = true, value_name = "A,B", value_parser = parse_motor_pair)]
    pub fault_motor_swap: Option<[u8; 2]>,
}

impl SitlFaultArgs {
    /// The faults the flags ask for.
    pub fn faults(&self) -> SitlFaults {
        SitlFaults {
            esc_silent: self.fault_esc_silent.clone(),
            imu: self.fault_imu,
            flash: self.fault_flash,
            motor_swap: self.fault_motor_swap,
        }
    }
}

/// Two motor indices `A,B`.
fn parse_motor_pair(text: &str) -> Result<[u8; 2], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let [a, b] = parts.as_slice() else {
        return Err(format!("expected two comma-separated motor indices A,B, got `{text}`"));
    };
    let index =
        |part: &str| part.parse::<u8>().map_err(|_| format!("`{part}` is not a motor index"));
    Ok([index(a)?, index(b)?])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(x: f32) -> ImuSample {
        ImuSample { gyro_rad_s: [x, x + 1.0, x + 2.0], accel_mps2: [0.0, 0.0, -9.8] }
    }

    #[test]
    fn faults_act_from_their_start_for_their_duration() {
        let fault = Fault { start_s: 1.0, duration_s: 0.001, kind: FaultKind::PoseLost };
        let injector = FaultInjector::new(&FaultSchedule::default().with(fault));
        assert!(!injector.pose_lost(0.9995));
        assert!(injector.pose_lost(1.0) && injector.pose_lost(1.0005));
        assert!(!injector.pose_lost(1.001));
    }

    #[test]
    fn a_stuck_axis_repeats_the_last_value_before_the_fault() {
        let schedule =
            FaultSchedule::default().with(Fault::from(1.0, FaultKind::GyroStuck { axis: 1 }));
        let mut injector = FaultInjector::new(&schedule);
        let mut s = sample(0.5);
        injector.corrupt_imu(0.9995, &mut s);
        assert_eq!(s, sample(0.5));
        for (i, t) in [1.0, 1.0005, 1.001].into_iter().enumerate() {
            let mut s = sample(i as f32);
            injector.corrupt_imu(t, &mut s);
            assert_eq!(s.gyro_rad_s, [i as f32, 1.5, i as f32 + 2.0]);
        }
    }

    #[test]
    fn saturation_reads_the_register_extremes_and_nan_and_inf_replace_values() {
        let schedule = FaultSchedule::default()
            .with(Fault::from(0.0, FaultKind::AccelSaturated { axis: 2, negative: true }))
            .with(Fault::from(0.0, FaultKind::ImuInf { axis: 0 }));
        let mut s = sample(0.0);
        FaultInjector::new(&schedule).corrupt_imu(0.0, &mut s);
        assert_eq!(s.accel_mps2, [f32::INFINITY, 0.0, -156.9064]);
        let mut s = sample(0.0);
        let schedule = FaultSchedule::default().with(Fault::from(0.0, FaultKind::ImuNan));
        FaultInjector::new(&schedule).corrupt_imu(0.0, &mut s);
        assert!(s.gyro_rad_s.iter().chain(&s.accel_mps2).all(|x| x.is_nan()));
    }

    #[test]
    fn a_missing_sample_is_not_delivered_and_a_frozen_one_repeats_the_last_delivered() {
        let schedule = FaultSchedule::default()
            .with(Fault { start_s: 1.0, duration_s: 0.001, kind: FaultKind::ImuMissing })
            .with(Fault::from(2.0, FaultKind::ImuFrozen))
            .with(Fault::from(3.0, FaultKind::SpeedReportLost { motor: 1 }));
        let mut injector = FaultInjector::new(&schedule);
        let mut s = sample(0.5);
        assert!(injector.corrupt_imu(0.9995, &mut s));
        assert!(!injector.corrupt_imu(1.0, &mut sample(1.0)));
        assert!(!injector.corrupt_imu(1.0005, &mut sample(1.5)));
        // Frozen at the last sample delivered (0.5), not at the missing ones.
        for t in [2.0, 2.0005, 2.5] {
            let mut s = sample(t as f32);
            assert!(injector.corrupt_imu(t, &mut s));
            assert_eq!(s, sample(0.5), "{t}");
        }
        assert!(!injector.speed_report_lost(2.9995, 1));
        assert!(injector.speed_report_lost(3.0, 1) && !injector.speed_report_lost(3.0, 0));
    }

    #[test]
    fn swapped_outputs_drive_each_others_rotors_and_leave_the_rest() {
        let swap = FaultKind::MotorOutputsSwapped { a: 1, b: 3 };
        let injector = FaultInjector::new(&FaultSchedule::default().with(Fault::from(0.5, swap)));
        let outputs = |t: f64| (0..4).map(|r| injector.output_of_rotor(t, r)).collect::<Vec<_>>();
        assert_eq!(outputs(0.0), [0, 1, 2, 3]);
        assert_eq!(outputs(0.5), [0, 3, 2, 1]);
    }

    #[test]
    fn sitl_faults_are_checked_against_the_airframe_and_scheduled_from_the_start() {
        let faults = SitlFaults {
            esc_silent: vec![2],
            imu: Some(ImuFault::Silent),
            flash: None,
            motor_swap: Some([0, 3]),
        };
        assert_eq!(faults.validate(4), Ok(()));
        assert!(faults.validate(3).unwrap_err().contains("--fault-motor-swap 0,3"));
        let same = SitlFaults { motor_swap: Some([1, 1]), ..SitlFaults::default() };
        assert!(same.validate(4).is_err());
        let far = SitlFaults { esc_silent: vec![8], ..SitlFaults::default() };
        assert!(far.validate(8).unwrap_err().contains("motors 0 to 7"));
        let kinds: Vec<FaultKind> = faults.schedule().faults().iter().map(|f| f.kind).collect();
        assert_eq!(
            kinds,
            [
                FaultKind::SpeedReportLost { motor: 2 },
                FaultKind::ImuMissing,
                FaultKind::MotorOutputsSwapped { a: 0, b: 3 }
            ]
        );
        assert!(faults.schedule().faults().iter().all(|f| f.active(0.0) && f.active(1e6)));
        assert_eq!(SitlFaults::default().schedule(), FaultSchedule::default());
        assert_eq!(parse_motor_pair("1, 2"), Ok([1, 2]));
        assert!(parse_motor_pair("1").is_err() && parse_motor_pair("1,x").is_err());
    }

    #[test]
    fn thrust_factors_are_reported_when_they_change() {
        let fault = Fault {
            start_s: 1.0,
            duration_s: 1.0,
            kind: FaultKind::MotorThrust { motor: 2, factor: 0.5 },
        };
        let mut injector = FaultInjector::new(&FaultSchedule::default().with(fault));
        assert_eq!(injector.thrust_factors(0.5), None);
        let factors = injector.thrust_factors(1.0).expect("changed");
        assert_eq!(factors[..4], [1.0, 1.0, 0.5, 1.0]);
        assert_eq!(injector.thrust_factors(1.5), None);
        assert_eq!(injector.thrust_factors(2.0).map(|f| f[2]), Some(1.0));
    }
}
