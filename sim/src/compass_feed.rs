//! A compass on the simulated craft, as the board has it: the world's field through a simulated
//! chip's registers (`crate::compass_chip`), read by the firmware's own compass service
//! (`firmware::app::compass::CompassInput`, the board's link task calls it), which applies the
//! calibration the user stored and hands the control step a calibrated field
//! (`ControlCommand::MagneticField`).
//!
//! The calibration is the user's: before the flight the craft is turned by hand for
//! [`DANCE_S`] (`crate::compass_calibration::calibration_dance`, the board's attitude filter on
//! the world's IMU), and what that dance fitted is stored, its errors included; the declination
//! is the world's, as a user reads it off a map (NOAA's calculator gives it within a fraction of
//! a degree). A dance the fit refused leaves the craft without a compass, as the board would.

use firmware::app::compass::{CompassCalibration, CompassInput, MagneticSample};
use nalgebra::UnitQuaternion;

use crate::compass_calibration::{calibration_dance, DanceError};
use crate::compass_chip::{CountingDelay, SharedCompassChip, SimCompassChip};
use crate::magnetometer::MagnetometerSpec;

/// How long the user turns the craft for its calibration, s (the middle of the 30–60 s a user
/// gives it: `crate::compass_calibration`).
pub const DANCE_S: f64 = 45.0;

/// The compass chip on the craft and the firmware's service reading it.
pub struct CompassFeed {
    chip: SharedCompassChip,
    input: Box<CompassInput>,
    delay: CountingDelay,
    declination_deg: f32,
}

/// The compass `spec` on the craft as the user leaves it: the calibration their dance (drawn
/// from `seed`) stored, and the chip it was read from, ready to be read in flight; or why the
/// dance's fit was refused.
pub fn calibrated_chip(
    spec: &MagnetometerSpec,
    seed: u64,
) -> Result<(CompassCalibration, SimCompassChip), DanceError> {
    let dance = calibration_dance(spec, seed, DANCE_S)?;
    let c = dance.calibration;
    let soft_iron = [0, 1, 2].map(|i| [0, 1, 2].map(|j| c.soft_iron[(i, j)]));
    let q = dance.alignment.q_mag_imu.into_inner();
    let calibration = CompassCalibration::new(
        c.offset_ut.into(),
        soft_iron,
        [q.w, q.i, q.j, q.k],
        c.residual_ut.max(f32::EPSILON),
    )
    .ok_or(DanceError::NotStorable)?;
    let chip = SimCompassChip::new(dance.chip, spec.clone(), seed ^ 0x434F_4D50_4153_5300);
    Ok((calibration, chip))
}

impl CompassFeed {
    /// The compass `spec` after the user's calibration dance (drawn from `seed`), or why the
    /// dance's fit was refused.
    pub fn new(spec: &MagnetometerSpec, seed: u64) -> Result<Self, DanceError> {
        let (calibration, chip) = calibrated_chip(spec, seed)?;
        let mut input = Box::<CompassInput>::default();
        input.configure(Some(calibration), true);
        Ok(Self {
            chip: SharedCompassChip::new(chip),
            input,
            delay: CountingDelay::default(),
            declination_deg: spec.declination_rad.to_degrees() as f32,
        })
    }

    /// The declination the user sets (`compass_declination_deg`), degrees.
    pub fn declination_deg(&self) -> f32 {
        self.declination_deg
    }

    /// Simulated time `now_s`, the IMU at `q_world_imu`, the motors at normalised thrusts
    /// `thrust`; the firmware's clock at `now_us`: the service reads the chip when a reading is
    /// due, and a calibrated field comes back for the control step.
    pub fn step(
        &mut self,
        now_s: f64,
        q_world_imu: &UnitQuaternion<f64>,
        thrust: &[f64],
        now_us: u64,
    ) -> Option<MagneticSample> {
        self.chip.update(now_s, q_world_imu, thrust);
        self.input.service(now_us, &mut self.chip, &mut self.delay)
    }
}
