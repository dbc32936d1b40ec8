//! A GNSS solution taken in parts, one per control step, so that no 2 kHz step carries the
//! whole of it (`cargo xtask bench-m7`: the step's target of issue 56 holds in each of them).
//!
//! A solution with its velocity asks for the position estimator's comparison with its
//! estimates of the solution's time, its gains and its correction, and the heading alignment's
//! position and velocity: together a third of a quad's control step (about 2,500 Cortex-M7
//! instructions), where the step itself leaves a few hundred. The solution is 50–150 ms old
//! when it arrives, so taking it over eight consecutive steps (4 ms at 2 kHz, the first in
//! the step after its arrival) delays it by 3–8 % of its latency, and nothing is lost: each
//! part uses the solution's age at its own step (its latency plus the steps since its
//! arrival), as a fix taken whole counts the step between its arrival and its use. The parts
//! ([`Next`], in order):
//! 1. the estimator compares the fix's position with its estimate of the fix's time
//!    (`PositionEstimator::innovation`, in [`start`]);
//! 2. its velocity likewise (`PositionEstimator::velocity_innovation`);
//! 3. the gains from the fix's stated accuracy (`flight::navigation::weigh`);
//! 4. the correction (`PositionEstimator::apply`, carried forward over the age at that step);
//! 5. the heading alignment takes the position into its slot (not a refused one:
//!    [`alignment_fixes`]; `HeadingAlignment::slot_fix`);
//! 6. the alignment's window of the slot it closed, if it did (`HeadingAlignment::close_window`);
//! 7. the alignment's dead-reckoned velocity of the fix's time
//!    (`HeadingAlignment::dead_velocity_at`);
//! 8. the alignment takes the velocity (`HeadingAlignment::fix_velocity_with`), and a yaw just
//!    found restarts the estimator's velocity in the aligned world ([`restart_if_aligned`]).
//!
//! No other fix may come between parts 1 and 4 (the comparison is with a history the other
//! fix would change): a fix that arrives meanwhile waits for the parts to end
//! (`super::pilot`). The parts' state changes in place, one step to the next.

use flight::navigation::{
    weigh, Fix, FixOutcome, HeadingAlignment, Innovation, PositionEstimator, Weights, MAX_FIX_AGE_S,
};
use nalgebra::Vector3;

use super::hal::elapsed_s;

/// The part a solution being taken runs next ([`FixParts`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Next {
    /// Part 2: the velocity compared.
    Velocity,
    /// Part 3: the gains.
    Weigh,
    /// Part 4: the correction.
    Correct,
    /// Part 5: the alignment's position, into its slot.
    AlignPosition,
    /// Part 6: the alignment's window of a slot the position closed.
    Window,
    /// Part 7: the alignment's dead-reckoned velocity of the fix's time.
    DeadVelocity,
    /// Part 8: the alignment's velocity.
    AlignVelocity,
}

/// A solution being taken: what the parts so far found, and the next.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FixParts {
    innovation: Innovation,
    weights: Weights,
    /// The alignment's dead-reckoned velocity of the fix's time, m/s (part 6).
    dead_mps: Vector3<f32>,
    /// The time at which the fix's `age_s` holds, µs.
    at_us: u64,
    /// The alignment had a yaw before this fix was applied.
    aligned_before: bool,
    next: Next,
}

/// `fix`'s age at `now_us`, its `age_s` holding at `at_us`, s (at most `MAX_FIX_AGE_S`).
pub fn age_at(fix: &Fix, at_us: u64, now_us: u64) -> f32 {
    (fix.age_s + elapsed_s(at_us, now_us)).min(MAX_FIX_AGE_S)
}

/// Part 1 for `fix`, whose `age_s` holds at `now_us`: the position compared; `parts` holds
/// the parts that remain (`None` for a fix the estimator refuses as input: nothing changes).
pub fn start(parts: &mut Option<FixParts>, navigation: &PositionEstimator, fix: &Fix, now_us: u64) {
    *parts = navigation.innovation(fix).ok().map(|innovation| FixParts {
        innovation,
        weights: Weights::default(),
        dead_mps: Vector3::zeros(),
        at_us: now_us,
        aligned_before: false,
        next: Next::Velocity,
    });
}

/// The next part of `parts` at `now_us` (`None` once all are done, or before any); the
/// estimator's outcome in the step that corrects.
pub fn step(
    parts: &mut Option<FixParts>,
    navigation: &mut PositionEstimator,
    alignment: &mut HeadingAlignment,
    now_us: u64,
) -> Option<FixOutcome> {
    let p = parts.as_mut()?;
    let fix = p.innovation.fix;
    let later_s = elapsed_s(p.at_us, now_us);
    match p.next {
        Next::Velocity => {
            navigation.velocity_innovation(&mut p.innovation, later_s);
            p.next = Next::Weigh;
        }
        Next::Weigh => {
            p.weights = weigh(&p.innovation);
            p.next = Next::Correct;
        }
        Next::Correct => {
            p.aligned_before = alignment.yaw_rad().is_some();
            let outcome = navigation.apply(&p.innovation, &p.weights, later_s);
            p.next =
                if alignment_fixes(outcome) { Next::AlignPosition } else { Next::DeadVelocity };
            return Some(outcome);
        }
        Next::AlignPosition => {
            alignment.slot_fix(&fix.position_ned_m, age_at(&fix, p.at_us, now_us));
            p.next = Next::Window;
        }
        Next::Window => {
            alignment.close_window();
            p.next = Next::DeadVelocity;
        }
        Next::DeadVelocity => {
            if fix.velocity.is_some() {
                p.dead_mps = alignment.dead_velocity_at(age_at(&fix, p.at_us, now_us));
                p.next = Next::AlignVelocity;
            } else {
                restart_if_aligned(navigation, alignment, &fix, p.at_us, now_us, p.aligned_before);
                *parts = None;
            }
        }
        Next::AlignVelocity => {
            let age_s = age_at(&fix, p.at_us, now_us);
            if let Some((velocity, noise)) = fix.velocity {
                alignment.fix_velocity_with(&velocity, noise, age_s, &p.dead_mps);
            }
            restart_if_aligned(navigation, alignment, &fix, p.at_us, now_us, p.aligned_before);
            *parts = None;
        }
    }
    None
}

/// Whether the heading alignment takes the position of a fix the estimator judged `outcome`.
///
/// The estimator refuses a position that strays from its prediction, but before the alignment
/// that prediction is flown in the wrong world: a craft whose filter is tilted accelerates
/// where its dead reckoning sees nothing, and every fix would be refused while it drifts (the
/// random receiver world's seed 131: 9 s without a velocity for the alignment, 25 m/s). The
/// velocity alignment compares differences over its window and needs no prediction; a Doppler
/// velocity hardly moves with multipath. Refused positions stay out of the position alignment.
pub fn alignment_fixes(outcome: FixOutcome) -> bool {
    outcome != FixOutcome::Rejected
}

/// The yaw from the filter's world to the fixes' world applied to `filter_world` (none until
/// the alignment has one).
pub fn aligned_world(alignment: &HeadingAlignment, filter_world: &Vector3<f32>) -> Vector3<f32> {
    let yaw = alignment.yaw_rad().unwrap_or(0.0);
    flight::math::rotation_about(&Vector3::z_axis(), yaw) * filter_world
}

/// The heading alignment has taken `fix` (its `age_s` holding at `at_us`); when it found the
/// yaw with it (it had none `aligned_before`), the accelerometer's world turned: the estimator's
/// velocity restarts from the velocity fix carried forward by the dead reckoning since its time,
/// or without one from the dead reckoning alone. Before the alignment nothing corrected the
/// filter's tilt, and the dead reckoning missed what a tilted filter makes the craft do (the
/// random receiver world's seed 315: 12° after an 845 °/s tumble, the dead reckoning at 2.2 m/s
/// where the fixes said 7.8 m/s, and a hold that braked on the former went on for 3 s).
pub fn restart_if_aligned(
    navigation: &mut PositionEstimator,
    alignment: &HeadingAlignment,
    fix: &Fix,
    at_us: u64,
    now_us: u64,
    aligned_before: bool,
) {
    if alignment.yaw_rad().is_none() || aligned_before {
        return;
    }
    let restart = match fix.velocity {
        Some((velocity, _)) => {
            let age_s = age_at(fix, at_us, now_us);
            velocity + aligned_world(alignment, &alignment.dead_reckoned_change_since_mps(age_s))
        }
        None => aligned_world(alignment, &alignment.dead_reckoned_velocity_mps()),
    };
    navigation.set_velocity(&restart);
}
