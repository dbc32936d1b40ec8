//! Throw-to-arm: is the craft being thrown, has it left the hand, and is it falling freely?
//!
//! The published detector (algorithms.md §1), then a free-fall check it lacked:
//! 1. **Waiting**: the specific force `|f|` rises above [`ThrowConfig::acc_high_mps2`] (20 m/s²):
//!    the hand is accelerating the craft.
//! 2. **Throwing**: integrate the momentum `Σ (min(|f|, 45) − g) dt`. When `|f|` falls back below
//!    20 m/s² (or the body rate exceeds 600 °/s) with the momentum above 4 m/s, the craft has been
//!    released; with less, it was not a throw (a shake, a knock): back to waiting. A throw that
//!    does not release within 3 s is abandoned.
//! 3. **Released**: for the release delay (150 ms) the motors stay off and every sample is checked
//!    for free fall: in flight the accelerometer reads only drag and the rotational terms
//!    `Ω̇×r + Ω×(Ω×r)`, far below g, while a craft still in the hand, caught, or lying on the
//!    ground reads about g. Each sample must stay below [`ThrowConfig::free_fall_max_mps2`] and
//!    their mean below [`ThrowConfig::free_fall_mean_mps2`], both raised by the centripetal
//!    reading `Ω² r_max` of an IMU up to [`ThrowConfig::max_imu_offset_m`] from the centre of
//!    gravity; otherwise the attempt is refused (the detector goes back to waiting, nothing
//!    spins). A release seen from the body rate (a spinning throw passes 600 °/s while the hand
//!    still pushes) starts the delay only when the push ends, within 100 ms.
//! 4. **Thrown**: the release delay passed in free fall: the excitation may start.
//!
//! The check uses the raw accelerometer and the gyro, so it needs no IMU offset: the
//! centripetal allowance covers any offset up to 30 mm, and drag at 9 m/s stays below 2 m/s² for
//! the airframes in the library, under the 0.5 g mean limit.
//!
//! Runs in the 2 kHz control step: a handful of multiplications per sample, no allocation.

/// Tuning of the throw detector. Defaults are the published figures (algorithms.md §1) plus the
/// free-fall check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThrowConfig {
    /// Specific force that starts (and, falling below it, ends) a throw, m/s².
    pub acc_high_mps2: f32,
    /// Clip of `|f|` in the momentum integral, m/s².
    pub acc_clip_mps2: f32,
    /// Momentum that makes the acceleration a throw, m/s.
    pub momentum_mps: f32,
    /// Body rate that counts as a release even while `|f|` is high, rad/s (600 °/s).
    pub release_rate_rad_s: f32,
    /// Time from release to the start of the excitation, with the motors off, s.
    pub release_delay_s: f32,
    /// Longest throw (acceleration phase) before it is abandoned, s.
    pub give_up_s: f32,
    /// Largest `|f|` of any sample during the release delay, m/s² (0.8 g).
    pub free_fall_max_mps2: f32,
    /// Largest mean `|f|` over the release delay, m/s² (0.5 g).
    pub free_fall_mean_mps2: f32,
    /// Largest IMU offset from the centre of gravity the free-fall check allows for, m: at body
    /// rate Ω the accelerometer of a freely falling craft reads up to `Ω² r` (centripetal), so
    /// both limits above grow by `Ω² · max_imu_offset_m`.
    pub max_imu_offset_m: f32,
    /// After a release seen from the body rate while the hand still pushes (|f| above
    /// `acc_high_mps2`), longest wait for the push to end before the release delay starts, s.
    pub push_end_wait_s: f32,
    /// Gravity, m/s².
    pub g_mps2: f32,
}

impl Default for ThrowConfig {
    fn default() -> Self {
        Self {
            acc_high_mps2: 20.0,
            acc_clip_mps2: 45.0,
            momentum_mps: 4.0,
            release_rate_rad_s: 600.0_f32.to_radians(),
            release_delay_s: 0.150,
            give_up_s: 3.0,
            free_fall_max_mps2: 0.8 * 9.81,
            free_fall_mean_mps2: 0.5 * 9.81,
            max_imu_offset_m: 0.03,
            push_end_wait_s: 0.1,
            g_mps2: 9.81,
        }
    }
}

/// Where the detector stands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ThrowState {
    /// Armed, waiting for the hand to accelerate the craft.
    Waiting,
    /// Accelerating: the momentum so far, m/s, and the time since it began, s.
    Throwing { momentum_mps: f32, elapsed_s: f32 },
    /// Released: time since release, s, and the sum of the free-fall margins `|f| − Ω² r_max`
    /// so far (for the mean), and samples. `pushing` while a release seen from the body rate
    /// waits for the hand's push to end (the delay starts then).
    Released { elapsed_s: f32, sum_acc_mps2: f32, samples: u32, pushing: bool },
    /// Thrown and falling freely since the release delay passed: the excitation may start.
    Thrown,
}

/// What one update concluded, besides the state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ThrowEvent {
    /// Nothing new.
    None,
    /// A throw began (acceleration above the threshold).
    ThrowStarted,
    /// The acceleration ended without enough momentum: not a throw.
    NotAThrow,
    /// Released with enough momentum: the release delay starts.
    Released,
    /// The release delay passed, but not in free fall: refused.
    NotFreeFall,
    /// The acceleration phase lasted longer than the give-up time.
    TimedOut,
    /// The release delay passed in free fall: thrown.
    Thrown,
}

/// The detector (one per armed attempt).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThrowDetector {
    config: ThrowConfig,
    state: ThrowState,
    /// After a timed-out throw, a new one starts only once the acceleration has dropped below
    /// the threshold (the same long push is not a new throw).
    calm_required: bool,
}

impl ThrowDetector {
    /// A detector waiting for a throw.
    pub fn new(config: ThrowConfig) -> Self {
        Self { config, state: ThrowState::Waiting, calm_required: false }
    }

    /// The current state.
    pub fn state(&self) -> ThrowState {
        self.state
    }

    /// Back to waiting.
    pub fn reset(&mut self) {
        self.state = ThrowState::Waiting;
        self.calm_required = false;
    }

    /// One sample: specific force `acc_mps2` and body rate `gyro_rad_s` (IMU axes), `dt_s` since
    /// the previous one. Non-finite samples count as "not free fall" and never release.
    pub fn update(&mut self, acc_mps2: [f32; 3], gyro_rad_s: [f32; 3], dt_s: f32) -> ThrowEvent {
        let c = &self.config;
        let acc = norm(acc_mps2);
        let rate = norm(gyro_rad_s);
        let finite = acc.is_finite() && rate.is_finite();
        if finite && acc < c.acc_high_mps2 {
            self.calm_required = false;
        }
        let (state, event) = match self.state {
            ThrowState::Waiting if finite && acc > c.acc_high_mps2 && !self.calm_required => (
                ThrowState::Throwing { momentum_mps: 0.0, elapsed_s: 0.0 },
                ThrowEvent::ThrowStarted,
            ),
            ThrowState::Waiting | ThrowState::Thrown => (self.state, ThrowEvent::None),
            ThrowState::Throwing { momentum_mps, elapsed_s } => {
                let momentum_mps = if finite {
                    momentum_mps + (acc.min(c.acc_clip_mps2) - c.g_mps2) * dt_s
                } else {
                    momentum_mps
                };
                let elapsed_s = elapsed_s + dt_s;
                let released = finite && (acc < c.acc_high_mps2 || rate > c.release_rate_rad_s);
                if released && momentum_mps >= c.momentum_mps {
                    let pushing = acc >= c.acc_high_mps2;
                    (
                        ThrowState::Released {
                            elapsed_s: 0.0,
                            sum_acc_mps2: 0.0,
                            samples: 0,
                            pushing,
                        },
                        ThrowEvent::Released,
                    )
                } else if finite && acc < c.acc_high_mps2 {
                    (ThrowState::Waiting, ThrowEvent::NotAThrow)
                } else if elapsed_s > c.give_up_s {
                    self.calm_required = true;
                    (ThrowState::Waiting, ThrowEvent::TimedOut)
                } else {
                    (ThrowState::Throwing { momentum_mps, elapsed_s }, ThrowEvent::None)
                }
            }
            ThrowState::Released { elapsed_s, pushing: true, .. } => {
                let elapsed_s = elapsed_s + dt_s;
                if finite && acc < c.acc_high_mps2 {
                    let state = ThrowState::Released {
                        elapsed_s: 0.0,
                        sum_acc_mps2: 0.0,
                        samples: 0,
                        pushing: false,
                    };
                    (state, ThrowEvent::None)
                } else if elapsed_s > c.push_end_wait_s {
                    (ThrowState::Waiting, ThrowEvent::NotFreeFall)
                } else {
                    let state = ThrowState::Released {
                        elapsed_s,
                        sum_acc_mps2: 0.0,
                        samples: 0,
                        pushing: true,
                    };
                    (state, ThrowEvent::None)
                }
            }
            ThrowState::Released { elapsed_s, sum_acc_mps2, samples, pushing: false } => {
                let elapsed_s = elapsed_s + dt_s;
                let centripetal = rate * rate * c.max_imu_offset_m;
                let margin = acc - centripetal;
                let sum_acc_mps2 = sum_acc_mps2 + margin;
                let samples = samples + 1;
                if !(finite && margin <= c.free_fall_max_mps2) {
                    (ThrowState::Waiting, ThrowEvent::NotFreeFall)
                } else if elapsed_s + 0.5 * dt_s >= c.release_delay_s {
                    if sum_acc_mps2 / samples as f32 <= c.free_fall_mean_mps2 {
                        (ThrowState::Thrown, ThrowEvent::Thrown)
                    } else {
                        (ThrowState::Waiting, ThrowEvent::NotFreeFall)
                    }
                } else {
                    let state =
                        ThrowState::Released { elapsed_s, sum_acc_mps2, samples, pushing: false };
                    (state, ThrowEvent::None)
                }
            }
        };
        self.state = state;
        event
    }
}

fn norm(v: [f32; 3]) -> f32 {
    libm::sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::{vec, vec::Vec};

    const DT: f32 = 0.0005;

    /// Feed `seconds` of a constant specific force (z) and rate; return the events seen.
    fn feed(d: &mut ThrowDetector, acc_z: f32, rate: f32, seconds: f32) -> Vec<ThrowEvent> {
        let n = (seconds / DT).round() as usize;
        (0..n)
            .map(|_| d.update([0.0, 0.0, acc_z], [rate, 0.0, 0.0], DT))
            .filter(|e| *e != ThrowEvent::None)
            .collect()
    }

    #[test]
    fn a_real_throw_is_detected_after_the_release_delay() {
        let mut d = ThrowDetector::new(ThrowConfig::default());
        feed(&mut d, -9.81, 0.0, 0.5); // held
                                       // 0.15 s at 55 m/s² (clipped to 45): momentum (45 − 9.81) × 0.15 = 5.3 m/s.
        assert_eq!(feed(&mut d, -55.0, 3.0, 0.15), vec![ThrowEvent::ThrowStarted]);
        // Free flight: drag and rotation give ~1.5 m/s².
        let events = feed(&mut d, -1.5, 7.0, 0.149);
        assert_eq!(events, vec![ThrowEvent::Released]);
        assert!(matches!(d.state(), ThrowState::Released { .. }));
        assert_eq!(feed(&mut d, -1.5, 7.0, 0.002), vec![ThrowEvent::Thrown]);
        assert_eq!(d.state(), ThrowState::Thrown);
    }

    #[test]
    fn a_fast_spinning_throw_released_before_the_push_ends_is_accepted() {
        let mut d = ThrowDetector::new(ThrowConfig::default());
        // The hand spins the craft past 600 °/s (12.2 rad/s) while still pushing at 39 m/s².
        assert_eq!(
            feed(&mut d, -39.0, 12.2, 0.15),
            vec![ThrowEvent::ThrowStarted, ThrowEvent::Released]
        );
        // Free flight at 12.2 rad/s with the IMU 25 mm from the centre of gravity: the
        // accelerometer reads the centripetal 3.7 m/s² plus drag.
        let events = feed(&mut d, -(12.2f32 * 12.2 * 0.025 + 1.0), 12.2, 0.16);
        assert_eq!(events, vec![ThrowEvent::Thrown]);
    }

    #[test]
    fn too_little_momentum_is_not_a_throw() {
        let mut d = ThrowDetector::new(ThrowConfig::default());
        // 0.05 s at 45 m/s²: 1.8 m/s, a knock or a shake.
        feed(&mut d, -45.0, 0.0, 0.05);
        assert_eq!(feed(&mut d, -9.81, 0.0, 0.01), vec![ThrowEvent::NotAThrow]);
        assert_eq!(d.state(), ThrowState::Waiting);
    }

    #[test]
    fn a_release_without_free_fall_is_refused() {
        let mut d = ThrowDetector::new(ThrowConfig::default());
        feed(&mut d, -45.0, 0.0, 0.3); // enough momentum, but the craft stays in the hand
        let events = feed(&mut d, -9.81, 0.0, 0.2);
        assert_eq!(events, vec![ThrowEvent::Released, ThrowEvent::NotFreeFall]);
        assert_eq!(d.state(), ThrowState::Waiting);
    }

    #[test]
    fn a_catch_during_the_release_delay_is_refused_at_once() {
        let mut d = ThrowDetector::new(ThrowConfig::default());
        feed(&mut d, -45.0, 0.0, 0.3);
        feed(&mut d, -1.0, 0.0, 0.05);
        assert_eq!(feed(&mut d, -12.0, 0.0, 0.001), vec![ThrowEvent::NotFreeFall]);
    }

    #[test]
    fn a_throw_that_never_releases_times_out() {
        let mut d = ThrowDetector::new(ThrowConfig::default());
        let events = feed(&mut d, -30.0, 0.0, 3.05);
        assert_eq!(events, vec![ThrowEvent::ThrowStarted, ThrowEvent::TimedOut]);
    }

    #[test]
    fn non_finite_samples_never_release() {
        let mut d = ThrowDetector::new(ThrowConfig::default());
        feed(&mut d, -45.0, 0.0, 0.3);
        for _ in 0..1000 {
            let e = d.update([f32::NAN, 0.0, 0.0], [0.0; 3], DT);
            assert_ne!(e, ThrowEvent::Released);
        }
        assert!(matches!(d.state(), ThrowState::Throwing { .. } | ThrowState::Waiting));
    }
}
