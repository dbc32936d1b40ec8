//! Cortex-M7 instruction counts of `flight` code, for `cargo xtask bench-m7`.
//!
//! Runs on QEMU's `mps2-an500` (Cortex-M7 with the double-precision FPU of the STM32H743) under
//! `-icount shift=0 -singlestep -d exec,nochain`: every executed instruction is one trace line.
//! Each measured region sits between calls of the two marker functions below; xtask finds
//! their addresses in the ELF symbol table and counts the trace lines between them. Region
//! names are printed first over semihosting, in the order the regions run, and an empty region
//! runs first so that xtask can subtract the marker overhead.
//!
//! The figures are instruction counts, not cycles: QEMU does not model dual issue, FPU latency,
//! caches or wait states.
//!
//! The crate is compiled as the firmware is: the profile of `Cargo.toml` mirrors the root's
//! `[profile.firmware]`, and `flight` is built without its default feature `bounded-search`
//! (the firmware's choice); the feature `bounded-search` of this crate turns it back on and
//! adds the bounded-search regions.
#![no_std]
#![no_main]

use core::hint::black_box;
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use flight::allocation::{AllocationConfig, Allocator};
use flight::attitude::{AttitudeConfig, AttitudeFilter};
use flight::controller::{Controller, ControllerInput, Guidance};
use flight::indi::{IndiConfig, IndiModel, IndiOutput, IndiReference};
use flight::learner::{AxisStatus, LearnedModel, Learner, LearnerConfig, LearnerSlot, MAX_MOTORS};
use flight::navigation::PositionEstimator;
use flight::thrust_axis::{HoverProblem, ThrustAxisSolver, MOTORS_MAX};
use imu_offset::in_flight::OffsetFit;
use imu_offset::{AlignedSample, Config, ImuOffsetEstimator, ImuSample, Model, OffsetRls};
use nalgebra::{UnitQuaternion, Vector3};
use tumble::TumbleInertia;

/// The firmware's hardware boundary and battery monitor, compiled from their own sources (both
/// portable: `protocol`, `flight` and `core` only), for the control tick's battery region.
#[allow(dead_code)]
#[path = "../../firmware/src/app"]
mod app {
    pub mod battery;
    pub mod catch;
    pub mod compass_heading;
    pub mod fix_parts;
    pub mod hal;
    pub mod landing;
    pub mod offset_fit;
    pub mod sticks;
}

/// The firmware's portable drivers, compiled from their own sources: the receiver's stick input
/// (for `app::sticks`) and the DShot framing (`dshot.rs` depends only on `protocol`: the
/// bidirectional answers' decoding is measured as the board runs it, and `app::hal`'s motors
/// queue its commands), without building the board crate for this harness.
#[allow(dead_code)]
#[path = "../../firmware/src/drivers"]
mod drivers {
    pub mod crsf;
    pub mod dshot;
}

use drivers::dshot;

/// What the control tick adds to the step: the flight log's entry into its ring, and a battery
/// reading into the monitor.
fn tick_regions() {
    use app::battery::BatteryMonitor;
    use app::hal::BatteryReading;
    use heapless::spsc::Queue;
    // `firmware::app::log::LogEntry` is 152 bytes (`an_entry_is_a_small_copy…`); its ring holds
    // 512 (`LOG_RING_LEN`). The entry's own type lives with the log's writer, which needs the
    // whole application: an array of its size is copied instead, as `RingProducer::push` does.
    static mut RING: Queue<[u32; 38], 512> = Queue::new();
    // SAFETY: the only reference to the ring, in this single-threaded harness.
    let (mut producer, mut consumer) = unsafe { (*core::ptr::addr_of_mut!(RING)).split() };
    let mut state = ([7u32; 38], 0u32);
    for _ in 0..2 {
        let _ = region(&mut state, |(entry, dropped)| {
            if producer.enqueue(black_box(*entry)).is_err() {
                *dropped += 1;
            }
        });
        let _ = consumer.dequeue();
    }
    if state.1 != 0 {
        fail("tick: the ring was full");
    }
    let mut monitor = BatteryMonitor::new();
    for i in 0..1000u64 {
        monitor.update(i * 1_000, BatteryReading { voltage_v: 16.8, current_a: 0.5 });
    }
    let mut state = (monitor, 1_000_000u64);
    let _ = region(&mut state, |(monitor, t_us)| {
        monitor.update(*t_us, black_box(BatteryReading { voltage_v: 16.2, current_a: 12.0 }));
    });
    let status = region(&mut state, |(monitor, _)| black_box(&*monitor).status());
    if status.map(|s| s.cells) != Some(4) {
        fail("tick: the battery monitor did not count 4 cells");
    }
}

/// What the pilot's sticks and the landing add to a flying control step (`firmware::app::sticks`,
/// `firmware::app::landing`), on a quadrotor's learned model: per step, position mode's setpoint
/// moved, the touchdown detector's step, the fly-away detector's step (hovering, and moving away
/// fast); and what runs less often: a stick frame shaped into its demand (when a stick moves,
/// at the radio's rate) and position mode's velocity turned into the world (when the heading
/// has turned 2°).
fn pilot_regions() {
    use app::landing::{FlyAway, LandConfig, ThrustScale, Touchdown, TouchdownSigns};
    use app::sticks::{move_setpoint, StickConfig};
    use drivers::crsf::StickInput;
    use protocol::LandReason;
    let sticks =
        StickInput { roll: 0.31, pitch: -0.52, throttle: 0.12, yaw: 0.05, position_mode: true };
    // Position mode's step: the setpoint moved, and the fly-away detector counting (the worst
    // step of the sticks and the landing: in angle mode and in a landing neither counts).
    let mut state = (
        Vector3::new(1.0f32, 2.0, -3.0),
        Vector3::new(0.4f32, -0.9, 0.1),
        FlyAway::default(),
        LandConfig::default(),
    );
    let moved = region(&mut state, |(setpoint, velocity, detector, config)| {
        let position = Vector3::new(-0.5f32, 1.5, -3.0);
        let moved = move_setpoint(black_box(setpoint), velocity, &position, 0.0005);
        let offset = position - Vector3::new(-2.5f32, 0.5, -3.0);
        let away = detector.update(&offset, &Vector3::new(3.5, 1.0, 0.0), config, 0.0005);
        (moved, away)
    });
    black_box(moved);
    let mut state = (Vector3::new(1.0f32, 2.0, -3.0), Vector3::new(0.4f32, -0.9, 0.1));
    let moved = region(&mut state, |(setpoint, velocity)| {
        move_setpoint(black_box(setpoint), velocity, &Vector3::new(1.1, 2.1, -3.0), 0.0005)
    });
    black_box(moved);
    let (u, idle, hover, g1) = ([0.35f32; 4], [0.05f32; 4], [0.4f32; 4], [-6.1f32; 4]);
    let mut state = (Touchdown::new(LandReason::Commanded), 0u32);
    let step = region(&mut state, |(touchdown, _)| {
        let signs = TouchdownSigns {
            u: black_box(&u),
            u_idle: &idle,
            u_hover: &hover,
            g1_up_mps2: &g1,
            specific_force_thrust_mps2: [0.1, -0.2, -9.6],
            flown: ThrustScale::default(),
            tilt_rate_rad_s: 0.02,
            accel_mps2: [0.3, 9.1, -3.2],
            // With fixes: the ground contact's stage is followed too.
            fix_vertical_speed_mps: Some(0.5),
            vertical_speed_mps: 0.5,
            descent_sp_mps: 0.5,
        };
        touchdown.step(&signs, 0.0005)
    });
    if step.touched {
        fail("pilot: a descending craft touched down");
    }
    for velocity in [Vector3::new(0.2f32, -0.1, 0.0), Vector3::new(3.5f32, 1.0, 0.0)] {
        let mut state = (FlyAway::default(), LandConfig::default(), velocity);
        let away = region(&mut state, |(detector, config, velocity)| {
            let offset = Vector3::new(2.0f32, 1.0, 0.0);
            detector.update(black_box(&offset), velocity, config, 0.0005)
        });
        black_box(away);
    }
    let mut state = (StickConfig::default(), sticks);
    let demand = region(&mut state, |(config, sticks)| config.demand(black_box(sticks)));
    let mut state = (demand, 0.7f32);
    let velocity = region(&mut state, |(demand, yaw)| demand.setpoint_velocity(black_box(*yaw)));
    black_box(velocity);
}

/// The position estimator with a GNSS receiver's fixes (`flight::navigation`, issue 55): the
/// predict every control step runs, a fix with a velocity taken 100 ms late (the history
/// carried forward), a multipath fix refused, and the heading alignment's velocity fix (5–10
/// of each a second).
fn navigation_regions() {
    use flight::navigation::{Fix, FixOutcome, HeadingAlignment};
    let level = UnitQuaternion::identity();
    let hover = Vector3::new(0.02f32, -0.01, -9.8);
    let mut navigation = PositionEstimator::default();
    let mut alignment = HeadingAlignment::new(0.3);
    for k in 0..400 {
        let _ = navigation.predict(&level, &hover, 0.0005);
        alignment.predict(&Vector3::new(0.3, 0.1, 0.0), 0.0005);
        if k % 200 == 0 {
            let fix = Fix {
                position_ned_m: Vector3::new(0.01, 0.02, -3.0),
                sigma_m: [0.3, 0.45],
                velocity: Some((Vector3::new(0.01, 0.0, 0.0), 0.05)),
                age_s: 0.1,
                dt_fix_s: 0.1,
            };
            let _ = navigation.correct_fix(&fix);
            alignment.fix_velocity(&Vector3::new(0.01 * k as f32, 0.0, 0.0), 0.05, 0.1);
        }
    }
    let mut state = (navigation, hover);
    let predicted = region(&mut state, |(navigation, f)| {
        navigation.predict(&UnitQuaternion::identity(), black_box(f), 0.0005)
    });
    if predicted.is_err() {
        fail("navigation: a finite step was refused");
    }
    let (navigation, _) = state;
    let taken = Fix {
        position_ned_m: Vector3::new(0.05, -0.03, -3.02),
        sigma_m: [0.3, 0.45],
        velocity: Some((Vector3::new(0.02, 0.01, 0.0), 0.05)),
        age_s: 0.1,
        dt_fix_s: 0.1,
    };
    let mut state = (navigation, taken);
    let outcome = region(&mut state, |(navigation, fix)| navigation.correct_fix(black_box(fix)));
    if outcome != Ok(FixOutcome::Taken) {
        fail("navigation: a fix 6 cm off was not taken");
    }
    let (navigation, _) = state;
    let refused = Fix { position_ned_m: Vector3::new(4.0, 3.0, -3.0), ..taken };
    let mut state = (navigation, refused);
    let outcome = region(&mut state, |(navigation, fix)| navigation.correct_fix(black_box(fix)));
    if outcome != Ok(FixOutcome::Rejected) {
        fail("navigation: a 5 m multipath jump was taken");
    }
    let mut state = (alignment, Vector3::new(4.1f32, 0.2, 0.0));
    region(&mut state, |(alignment, velocity)| {
        alignment.fix_velocity(black_box(velocity), 0.05, 0.1)
    });
    black_box(state.0.yaw_rad());
    compass_region();
}

/// What the pilot does with each compass sample (`firmware::app::compass_heading`, 100 Hz, in
/// the control step): the interference monitor's update and the tilt-compensated heading
/// (`flight::magnetometer`), for a 48 µT field at 63° of dip seen from a craft tilted 10°.
fn compass_region() {
    use flight::magnetometer::{
        tilt_compensated_yaw, HeadingConfig, InterferenceMonitor, MonitorConfig,
    };
    let q = UnitQuaternion::from_euler_angles(0.17f32, -0.05, 1.1);
    let world = Vector3::new(21.4f32, 1.1, 42.9);
    let field = q.inverse() * world;
    let monitor =
        InterferenceMonitor::new(MonitorConfig::default(), &world, &UnitQuaternion::identity());
    let mut state = (monitor, field, q);
    let heading = region(&mut state, |(monitor, field, q)| {
        let status = monitor.update(black_box(field), q, 0.01);
        (!status.disturbed)
            .then(|| tilt_compensated_yaw(field, q, &HeadingConfig::default()).ok())
            .flatten()
    });
    if heading.is_none() {
        fail("compass: an undisturbed field gave no heading");
    }
}

/// Fails the bench unless `flight::math::sqrt` (`vsqrt.f32` here) and `flight::math::hypot`
/// give `libm::sqrtf`'s and `libm::hypotf`'s values on the Cortex-M7: the host tests compare
/// libm with itself, this compares the instruction the firmware runs.
fn sqrt_matches_libm() {
    let same = |a: f32, b: f32| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
    let check = |x: f32| {
        let x = black_box(x);
        if !same(flight::math::sqrt(x), libm::sqrtf(x))
            || !same(flight::math::hypot(x, 0.75 * x), libm::hypotf(x, 0.75 * x))
        {
            hprintln!("bench-m7 error: the square root or hypot of {:e} differs from libm's", x);
            fail("flight::math::sqrt is not libm::sqrtf on the Cortex-M7");
        }
    };
    let special = [0.0f32, -0.0, 1e-45, 1.1754942e-38, 1e-30, 1.0, 2.0, 1e30, f32::MAX];
    let special = special.into_iter().chain([f32::INFINITY, -1.0, -1e-30, -1e-45]);
    let mut checked = 0u32;
    for x in special.chain([f32::NEG_INFINITY, f32::NAN]) {
        check(x);
        checked += 1;
    }
    for bits in (0..0x7f80_0000u32).step_by(99_991) {
        check(f32::from_bits(bits));
        check(-f32::from_bits(bits));
        checked += 2;
    }
    hprintln!("bench-m7 check: flight::math::sqrt and hypot equal libm's on {} values", checked);
}

/// Start of a measured region. `inputs` is consumed so that no load is hoisted above the call.
#[inline(never)]
#[no_mangle]
pub extern "C" fn bench_region_start(inputs: *const u8) {
    // SAFETY: a no-op instruction; the register operand only pins the pointer.
    unsafe { core::arch::asm!("nop", in("r0") inputs) }
}

/// End of a measured region. `outputs` is consumed so that no result is sunk below the call.
/// Its body differs from the start marker's so that LTO cannot merge the two.
#[inline(never)]
#[no_mangle]
pub extern "C" fn bench_region_end(outputs: *const u8) {
    // SAFETY: no-op instructions; the register operand only pins the pointer.
    unsafe { core::arch::asm!("nop", "nop", in("r0") outputs) }
}

/// Run `f` between the markers.
#[inline(always)]
fn region<I, O>(inputs: &mut I, f: impl FnOnce(&mut I) -> O) -> O {
    bench_region_start(inputs as *mut I as *const u8);
    let out = f(inputs);
    bench_region_end(&out as *const O as *const u8);
    out
}

/// The background task's part of a sample with the in-flight IMU-offset fit in its own task
/// (`firmware::app::offset_fit`), octorotor: its room and the worker's progress checked, the
/// sample pushed, its count kept, and the estimates due taken back (none; one).
const FIT_HANDOFF_CASES: [&str; 2] = [
    "octorotor sample with an estimate due, taken back (the background task's part)",
    "octorotor sample: checked, pushed, counted, none due (the background task's part)",
];

/// [`FIT_HANDOFF_CASES`]: a tumble with the motors pulsed fed through the rings, the worker
/// caught up between samples (outside the regions); run once to find the sample an estimate
/// is due at, then again to measure it and the one after it.
fn fit_handoff_regions() {
    use app::offset_fit::{FitHandoff, FitWork, OffsetFitWorker};
    static mut HANDOFF: FitHandoff = FitHandoff::new();
    static mut WORKER: core::mem::MaybeUninit<OffsetFitWorker<'static>> =
        core::mem::MaybeUninit::uninit();
    let work = |tag: u32| {
        let t = tag as f32 / 2000.0;
        let (sin, cos) = (libm::sinf(9.0 * t), libm::cosf(9.0 * t));
        FitWork::Sample {
            gyro_rad_s: [6.0 * cos, 6.0 * sin, 1.5 + libm::sinf(7.0 * t)],
            accel_mps2: [0.5 * sin, -0.4 * cos, -9.8 + 0.3 * sin],
            speeds_rad_s: core::array::from_fn(|i| {
                if (tag / 100) % 8 == i as u32 {
                    1600.0
                } else {
                    1000.0
                }
            }),
            velocity_imu_mps: [4.0 * cos, -4.0 * sin, 2.0],
        }
    };
    let mut due_at = None;
    for pass in 0..2 {
        // SAFETY: the statics' only references, in this single-threaded harness; the first
        // pass's ends are gone before the second splits the rings again.
        let handoff = unsafe { &mut *core::ptr::addr_of_mut!(HANDOFF) };
        *handoff = FitHandoff::new();
        let (mut client, ends) = handoff.split(2000.0);
        let worker =
            OffsetFitWorker::build_in(unsafe { &mut *core::ptr::addr_of_mut!(WORKER) }, ends);
        client.start(0, 8, 2000.0, 0.0);
        for tag in 1..4_000u32 {
            let mut applied = false;
            let item = work(tag);
            let mut sample = |client: &mut app::offset_fit::FitClient<'_>| {
                let ready = client.ready_for(tag);
                let pushed = client.push(tag, black_box(item));
                client.end_sample(tag);
                client.take_due(tag, |estimate| applied |= estimate.is_some());
                ready && pushed
            };
            let measured = pass == 1 && due_at.is_some_and(|due| tag == due || tag == due + 1);
            let ok =
                if measured { region(&mut client, |c| sample(c)) } else { sample(&mut client) };
            if !ok {
                fail("in-flight fit hand-off: the client was not ready");
            }
            if applied && due_at.is_none() {
                due_at = Some(tag);
            }
            worker.run_pending();
            if pass == 1 && due_at.is_some_and(|due| tag > due) {
                break;
            }
        }
        if due_at.is_none() {
            fail("in-flight fit hand-off: no estimate came back");
        }
    }
}

/// A multirotor: `motors` rotors on a circle of radius 0.15 m with alternating spin, ±10 %
/// strengths, and rotor axes tilted alternately by ±`tilt_rad` about the arm (0: planar; 20°:
/// a fully actuated frame, whose 3 × 3 force matrix has full rank so the power iteration has
/// work to do), seen from an IMU rotated by the seed paper's `q_U^T` (0.837 − 0.491i + 0.242j).
fn airframe(motors: usize, tilt_rad: f32) -> HoverProblem {
    let q = [0.837f32, -0.491, 0.242, 0.0];
    let n = libm::sqrtf(q.iter().map(|v| v * v).sum());
    let [w, x, y, z] = q.map(|v| v / n);
    let r = [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ];
    let mut f = [[0.0f32; MOTORS_MAX]; 3];
    let mut t = [[0.0f32; MOTORS_MAX]; 3];
    for i in 0..motors {
        let angle = 2.0 * core::f32::consts::PI * (i as f32 + 0.5) / motors as f32;
        let (px, py) = (0.15 * libm::cosf(angle), 0.15 * libm::sinf(angle));
        let strength = 9.81 / (0.4 * motors as f32) * (1.0 + 0.1 * libm::sinf(3.0 * i as f32));
        let spin = if i % 2 == 0 { 1.0 } else { -1.0 };
        // Tilt about the arm: the axis leans along the tangent, alternately either way.
        let lean = if i % 2 == 0 { tilt_rad } else { -tilt_rad };
        let (tangent_x, tangent_y) = (-libm::sinf(angle), libm::cosf(angle));
        let (s, c) = (libm::sinf(lean), libm::cosf(lean));
        let force = [strength * s * tangent_x, strength * s * tangent_y, -strength * c];
        // r × F plus rotor drag along the axis, over a diagonal inertia (kg m²).
        let moment = [
            py * force[2] + spin * 0.015 * force[0],
            -px * force[2] + spin * 0.015 * force[1],
            px * force[1] - py * force[0] + spin * 0.015 * force[2],
        ];
        let angular = [moment[0] / 0.01, moment[1] / 0.012, moment[2] / 0.02];
        for row in 0..3 {
            f[row][i] = (0..3).map(|k| r[row][k] * force[k]).sum();
            t[row][i] = (0..3).map(|k| r[row][k] * angular[k]).sum();
        }
    }
    let f_rows = [&f[0][..motors], &f[1][..motors], &f[2][..motors]];
    let t_rows = [&t[0][..motors], &t[1][..motors], &t[2][..motors]];
    match HoverProblem::new(f_rows, t_rows) {
        Ok(problem) => problem,
        Err(_) => fail("airframe refused"),
    }
}

/// Motor counts of the in-flight IMU-offset fit's regions.
const IN_FLIGHT_FIT_MOTOR_COUNTS: [usize; 2] = [4, 8];

/// Motor counts of the learner regions.
const LEARNER_MOTOR_COUNTS: [usize; 2] = [4, 8];

/// Samples the learner is primed with: the next one then begins the first force row of a cycle
/// of the six effectiveness regressions, each row's turn two samples at 2 kHz
/// (`flight::learner::effectiveness::MAX_ROW_RATE_HZ`; the regressions start with the fifteenth
/// sample: two for the filters, a cycle of twelve centred samples).
const LEARNER_PRIMING_SAMPLES: usize = 1202;

/// What each sample of one cycle of the learner runs besides the motor models and the filters.
const LEARNER_CYCLE: [&str; 12] = [
    "sample 1: force row x begun (its whole update)",
    "sample 2: force row x's turn ends, model staged (copy, convergence statistics)",
    "sample 3: force row y begun",
    "sample 4: force row y's turn ends, thrust-axis solve, model published",
    "sample 5: force row z begun",
    "sample 6: force row z's turn ends",
    "sample 7: rotational row x begun (its product P x and the parameters)",
    "sample 8: rotational row x's turn ends (its covariance downdate)",
    "sample 9: rotational row y begun",
    "sample 10: rotational row y's turn ends",
    "sample 11: rotational row z begun",
    "sample 12: rotational row z's turn ends",
];

/// The closed-loop control-step regions of each learner airframe (`closed_loop_regions`).
const CLOSED_LOOP_REGIONS: [&str; 13] = [
    "hover, position hold",
    "hover, position hold, pose fix (position estimator corrected)",
    "recovery 10 ms after a 60° tilt, position hold (allocation saturated)",
    "hover on GNSS, solution part 1 of 8: the position compared with the estimate of its time",
    "hover on GNSS, solution part 2 of 8: the velocity compared",
    "hover on GNSS, solution part 3 of 8: the gains from the stated accuracies",
    "hover on GNSS, solution part 4 of 8: the correction (velocity, accelerometer bias)",
    "hover on GNSS, solution part 5 of 8: the heading alignment's position (its slot closed)",
    "hover on GNSS, solution part 6 of 8: the heading alignment's window",
    "hover on GNSS, solution part 7 of 8: the alignment's dead-reckoned velocity of the fix's time",
    "hover on GNSS, solution part 8 of 8: the alignment's velocity (yaw trusted)",
    "hover on GNSS steered by the compass, sample part 1 of 2: interference monitor",
    "hover on GNSS steered by the compass, sample part 2 of 2: tilt-compensated heading",
];

/// The parts of the hover step on their own.
const CLOSED_LOOP_PARTS: [&str; 9] = [
    "attitude filter update",
    "position estimator predict",
    "controller update, hover (position, attitude, rate, INDI, allocation)",
    "controller update, recovery (allocation saturated)",
    "INDI update, hover (filters, increments, allocation, commands)",
    "allocation solve, hover increment (warm start)",
    "allocation solve, increment beyond the motors' range (warm start)",
    "controller formed from the learned model and started (engagement, re-forming in flight)",
    "hand-catch detector, a watched hover step (`firmware::app::catch`)",
];

/// One synthetic sample: gyro, accelerometer, commands, speeds.
type Sample = ([f32; 3], [f32; 3], [f32; 8], [f32; 8]);

/// A synthetic sample of a craft pulsing its motors: the motor speeds follow `command` through
/// the model `ω = 300 + 2700(0.4δ + 0.6√δ)`, and the body's specific force and angular
/// acceleration are linear in the squared speeds (the planar airframe above); `rate` is the
/// body rate, integrated by the caller from the angular acceleration returned.
fn synthetic_sample(m: usize, level: f32, t_s: f32, rate: [f32; 3]) -> (Sample, [f32; 3]) {
    let problem = airframe(m, 0.0);
    let mut commands = [0.0f32; 8];
    let mut speeds = [0.0f32; 8];
    let mut accel = [0.0f32; 3];
    let mut angular = [0.0f32; 3];
    for i in 0..m {
        // Each motor in turn, 50 ms apart, with a slow wobble so that no two are collinear.
        let phase = t_s - 0.05 * i as f32;
        let pulse = if (0.0..0.075).contains(&phase) { level } else { 0.0 };
        commands[i] = pulse;
        let speed = 300.0 + 2700.0 * (0.4 * pulse + 0.6 * libm::sqrtf(pulse));
        speeds[i] = speed * (1.0 + 0.02 * libm::sinf(40.0 * t_s + i as f32));
        let u = (speeds[i] / 3000.0) * (speeds[i] / 3000.0);
        for k in 0..3 {
            accel[k] += problem.g1_f_row(k)[i] * u;
            angular[k] += problem.g1_tau_row(k)[i] * u;
        }
    }
    ((rate, accel, commands, speeds), angular)
}

/// A learner fed 0.6 s of a synthetic excitation of `m` motors, so that every G1 column has
/// information and the thrust axis exists; with `force_seen` false its accelerometer reads no
/// motor's force, so that its own force rows find no hover.
fn primed_learner(m: usize, force_seen: bool) -> Learner {
    let Ok(mut learner) = Learner::new(m, LearnerConfig::default()) else { fail("learner") };
    let mut rate = [7.0f32, 7.0, 1.7];
    for n in 0..LEARNER_PRIMING_SAMPLES {
        let ((gyro, accel, commands, speeds), angular) =
            synthetic_sample(m, 0.7, n as f32 / 2000.0, rate);
        let accel = if force_seen { accel } else { [0.0; 3] };
        learner.update(gyro, accel, &commands, &speeds);
        for k in 0..3 {
            rate[k] += angular[k] / 2000.0;
        }
    }
    learner
}

/// Samples measured one by one of the learner without speed telemetry: a whole cycle of its
/// round-robin work.
const NO_SPEED_MEASURED_SAMPLES: usize = 13;

/// The learners without speed telemetry measured at the excitation's end: motor count, and the
/// sample on which every motor has been pulsed and all are back below a pulse (the last motor's
/// pulse ends `0.05 (m − 1) + 0.075` s in, `synthetic_sample`, seen three samples later through
/// the learner's command delay). Every sample is measured on its own from two before it until
/// [`NO_SPEED_AFTER_PUBLICATION`] after the one that publishes the model to engage on
/// (`LearnedModel::pending` cleared: [`no_speed_publications`]): the pending candidates; the
/// lag candidates' regressions (52, a few rows or columns at a time, as many a sample as
/// `no_speed::SCORING_WORK_PER_MOTOR` allows); the catch-up, the held samples (the means over
/// `no_speed::HOLD_INTERVAL_S`) learned from, at most `no_speed::RELEASE_PER_SAMPLE` a sample
/// (every one of the six rows of the effectiveness regression among them); the catch-up's last
/// held sample, the model's staging and its publication; and what follows.
const NO_SPEED_ENDS: [(usize, usize); 2] = [(4, 453), (8, 853)];

/// Samples measured after the one that publishes the model without speed telemetry: the
/// learner going on with each held sample as it completes, as in flight (a held sample every
/// 4 ms begins a regression row, the sample after it finishes the row's update): six held
/// samples, a cycle of the rows.
const NO_SPEED_AFTER_PUBLICATION: usize = 48;

/// Samples of pulses the learner without speed telemetry is primed with (0.2 s: three motors
/// pulsed, the lag regressions learning).
const NO_SPEED_PRIMING_SAMPLES: usize = 400;

/// Feeds a learner without speed telemetry of `m` motors, built in `slot`, the synthetic
/// excitation from its first sample until `step` says stop: `step(n, learner, sample)` runs
/// sample `n` into the learner and returns whether to go on.
fn drive_no_speed(
    slot: &mut LearnerSlot,
    m: usize,
    mut step: impl FnMut(usize, &mut Learner, Sample) -> bool,
) {
    let config = LearnerConfig { speed_telemetry: false, ..LearnerConfig::default() };
    let Ok(learner) = slot.build(m, config) else { fail("learner without speeds") };
    let mut rate = [7.0f32, 7.0, 1.7];
    let mut n = 0;
    loop {
        let (sample, angular) = synthetic_sample(m, 0.7, n as f32 / 2000.0, rate);
        if !step(n, learner, sample) {
            return;
        }
        for k in 0..3 {
            rate[k] += angular[k] / 2000.0;
        }
        n += 1;
    }
}

/// For each of [`NO_SPEED_ENDS`], the sample that publishes the model to engage on (the first
/// after which `LearnedModel::pending` is clear), found by a run of its own (nothing
/// measured), so that the regions can be named before they run.
fn no_speed_publications(slot: &mut LearnerSlot) -> [usize; 2] {
    NO_SPEED_ENDS.map(|(m, seen)| {
        let mut published = None;
        drive_no_speed(slot, m, |n, learner, (gyro, accel, commands, speeds)| {
            learner.update(gyro, accel, &commands, &speeds);
            if !learner.model().pending {
                published = Some(n);
            }
            published.is_none() && n < 4 * seen
        });
        match published {
            Some(n) if n >= seen => n,
            _ => fail("the held samples were not learned from after the excitation's end"),
        }
    })
}

/// The learner without speed telemetry (`flight::learner::no_speed`, issue 32): the quad's in
/// the middle of its excitation (the lag regressions and the held samples), and the quad's and
/// the octorotor's at the excitation's end until after the model's publication
/// (`published`, [`no_speed_publications`]), each sample measured on its own.
fn no_speed_regions(slot: &mut LearnerSlot, published: [usize; 2]) {
    for ((m, seen), published) in NO_SPEED_ENDS.into_iter().zip(published) {
        let first = seen - 2;
        let last = published + NO_SPEED_AFTER_PUBLICATION;
        let mut published_on = None;
        let mut learned = 0;
        let mut tau_s = 0.0;
        drive_no_speed(slot, m, |n, learner, (gyro, accel, commands, speeds)| {
            let measured = if m == 4 {
                (NO_SPEED_PRIMING_SAMPLES..NO_SPEED_PRIMING_SAMPLES + NO_SPEED_MEASURED_SAMPLES)
                    .contains(&n)
            } else {
                false
            } || (first..=last).contains(&n);
            if measured {
                let mut state = (&mut *learner, gyro, accel, commands, speeds);
                region(&mut state, |(learner, gyro, accel, commands, speeds)| {
                    learner.update(black_box(*gyro), *accel, commands, speeds)
                });
            } else {
                learner.update(gyro, accel, &commands, &speeds);
            }
            if published_on.is_none() && !learner.model().pending {
                published_on = Some(n);
                learned = learner.model().samples;
                tau_s = learner.model().tau_max_s();
            }
            n < last
        });
        if published_on != Some(published) || learned == 0 {
            fail("the model without speeds was not published on the sample named");
        }
        hprintln!(
            "bench-m7 check: m={} lag without speeds {} ms, {} samples learned, the model \
             published {} samples after the excitation's end (sample {})",
            m,
            1000.0 * tau_s,
            learned,
            published - seen,
            published
        );
    }
}

/// The control rate, Hz, and step, s.
const RATE_HZ: f32 = 2000.0;
const DT_S: f32 = 1.0 / RATE_HZ;

/// Steps between external position fixes (100 Hz motion capture at the 2 kHz control rate).
const FIX_EVERY_STEPS: usize = 20;

/// The closed-loop half of the firmware's 2 kHz control step (`firmware::app::pilot`: `observe`
/// then `step`), from `flight`'s parts: the attitude filter, the position estimator (predict on
/// every step, a correction on the steps a pose arrives), and the controller cascade (position
/// hold → attitude → rate → INDI with one allocation solve). The pilot's bookkeeping around them
/// (heading alignment, failsafe counters, status) is left out: a few hundred instructions.
#[derive(Clone)]
struct ClosedLoop {
    attitude: AttitudeFilter,
    navigation: PositionEstimator,
    controller: Controller,
    guidance: Guidance,
    r_imu_m: Vector3<f32>,
}

impl ClosedLoop {
    /// One step with the IMU sample `gyro`/`accel` and, when one arrived, a position fix.
    #[inline(always)]
    fn step(&mut self, gyro: [f32; 3], accel: [f32; 3], fix: Option<&Vector3<f32>>) -> IndiOutput {
        let w = Vector3::from(gyro);
        let f = Vector3::from(accel) - w.cross(&w.cross(&self.r_imu_m));
        let _ = self.attitude.update(&w, &f, None, DT_S);
        let q = self.attitude.quaternion();
        if let Some(position) = fix {
            let _ = self.navigation.correct(position, FIX_EVERY_STEPS as f32 * DT_S);
        }
        let _ = self.navigation.predict(&q, &f, DT_S);
        self.control(gyro, accel, q)
    }

    /// The controller's half of a step at the attitude `q`.
    #[inline(always)]
    fn control(&mut self, gyro: [f32; 3], accel: [f32; 3], q: UnitQuaternion<f32>) -> IndiOutput {
        let input = ControllerInput {
            gyro_rad_s: gyro,
            accel_mps2: accel,
            q_world_imu: q,
            navigation: *self.navigation.state(),
            unexplained_torque: false,
        };
        match self.controller.update(&input, &self.guidance) {
            Ok(output) => output.indi,
            Err(_) => fail("controller step refused"),
        }
    }

    /// One step outdoors, as `firmware::app::pilot` runs it: the compass's part and its heading
    /// steering the filter (the yaw less the alignment's, which is 0 for the compass's world),
    /// the heading alignment's and the estimator's predictions, and the GNSS solution's part
    /// (`firmware::app::fix_parts`) or the start of a solution waiting. `now_us`: the step's
    /// time.
    #[inline(always)]
    fn step_outdoors(
        &mut self,
        gyro: [f32; 3],
        accel: [f32; 3],
        outdoors: &mut Outdoors,
        now_us: u64,
    ) -> IndiOutput {
        let w = Vector3::from(gyro);
        let f = Vector3::from(accel) - w.cross(&w.cross(&self.r_imu_m));
        let busy = outdoors.part.is_some() || outdoors.waiting.is_some();
        let yaw = outdoors.compass.step(now_us, &self.attitude.quaternion(), false, busy);
        let heading = yaw.map(|yaw| flight::attitude::wrap_pi(yaw - outdoors.alignment_yaw()));
        let _ = self.attitude.update(&w, &f, heading, DT_S);
        let q = self.attitude.quaternion();
        let gravity = Vector3::new(0.0, 0.0, flight::navigation::STANDARD_GRAVITY_MPS2);
        outdoors.alignment.predict(&(q * f + gravity), DT_S);
        let _ = self.navigation.predict(&q, &f, DT_S);
        if outdoors.part.is_some() {
            let navigation = &mut self.navigation;
            app::fix_parts::step(&mut outdoors.part, navigation, &mut outdoors.alignment, now_us);
        } else if let Some(fix) = outdoors.waiting.take() {
            app::fix_parts::start(&mut outdoors.part, &self.navigation, &fix, now_us);
        }
        self.control(gyro, accel, q)
    }
}

/// What a step outdoors adds to the closed loop: the heading alignment, the GNSS solution
/// waiting or being taken, and the compass.
#[derive(Clone)]
struct Outdoors {
    alignment: flight::navigation::HeadingAlignment,
    waiting: Option<flight::navigation::Fix>,
    part: Option<app::fix_parts::FixParts>,
    compass: app::compass_heading::CompassHeading,
}

impl Outdoors {
    fn alignment_yaw(&self) -> f32 {
        self.alignment.yaw_rad().unwrap_or(0.0)
    }
}

/// The yaw between the fixes' world and the filter's in the outdoor regions, rad.
const OUTDOOR_YAW_RAD: f32 = 0.5;

/// A heading alignment for a receiver's 0.3 m and 5 cm/s that found its yaw
/// ([`OUTDOOR_YAW_RAD`]) on 6 s of circles at 2 m/s² (10 Hz fixes, 100 ms late), so that each
/// velocity fix evaluates the yaw again, as in a flight after the alignment.
fn aligned_alignment() -> flight::navigation::HeadingAlignment {
    let mut alignment = flight::navigation::HeadingAlignment::new(0.3);
    let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), OUTDOOR_YAW_RAD);
    let omega = 2.0f32;
    let (a, latency_s) = (2.0f32, 0.1f32);
    // Circles: v = (a/ω)(sin ωt, −cos ωt), the filter's world.
    let velocity =
        |t: f32| Vector3::new(libm::sinf(omega * t), -libm::cosf(omega * t), 0.0) * (a / omega);
    let position = |t: f32| {
        Vector3::new(-libm::cosf(omega * t), -libm::sinf(omega * t), 0.0) * (a / (omega * omega))
    };
    let steps = (6.0 / DT_S) as usize;
    for n in 0..steps {
        let t = n as f32 * DT_S;
        let accel = Vector3::new(libm::cosf(omega * t), libm::sinf(omega * t), 0.0) * a;
        alignment.predict(&accel, DT_S);
        if n % 200 == 0 && t > latency_s {
            let then = t - latency_s;
            alignment.fix(&(turn * position(then)), latency_s);
            alignment.fix_velocity(&(turn * velocity(then)), 0.05, latency_s);
        }
    }
    if alignment.yaw_rad().is_none() {
        fail("outdoors: the alignment found no yaw");
    }
    alignment
}

/// A hover sample of a craft flying `model`: a small wobble of the body rate (rad/s) and the
/// specific force of hover (`−g` along the thrust frame's z), IMU axes.
fn hover_sample(model: &IndiModel, n: usize) -> ([f32; 3], [f32; 3]) {
    let t = n as f32 * DT_S;
    let rate_thrust = Vector3::new(
        0.05 * libm::sinf(31.0 * t),
        0.04 * libm::sinf(23.0 * t + 1.0),
        0.02 * libm::sinf(7.0 * t),
    );
    let force_thrust = Vector3::new(0.0, 0.0, -flight::navigation::STANDARD_GRAVITY_MPS2);
    let gyro = model.q_imu_thrust * rate_thrust;
    let accel = model.q_imu_thrust * force_thrust;
    (gyro.into(), accel.into())
}

/// The closed loop of a craft that learned its model with `learner` (the primed learner of the
/// learner regions: the model the firmware would fly after that excitation), engaged at hover
/// with its thrust frame level and holding its position at the origin, then flown for 0.2 s of
/// hover samples with a fix every [`FIX_EVERY_STEPS`] so that every filter has settled.
///
/// The synthetic excitation's motors follow their command without lag, so the learned time
/// constants are not usable: every motor model is taken as the synthetic curve
/// (`ω = 300 + 1080 δ + 1620 √δ` rad/s) with τ = 30 ms, a 5-inch motor's.
fn hovering_closed_loop(learner: &Learner) -> (ClosedLoop, usize) {
    let learned = flyable_model(learner);
    let Some(mut controller) = formed_controller(&learned) else { fail("controller") };
    let model = *controller.indi().model();
    let (commands, speeds) = hover_commands(&model);
    let (gyro, accel) = hover_sample(&model, 0);
    controller.start(gyro, accel, &commands, &speeds);
    let mut attitude = AttitudeFilter::new(AttitudeConfig::default());
    // Thrust frame level: q_world_imu = q_world_thrust · q_thrust_imu with q_world_thrust = 1.
    if attitude.reset_to(model.q_imu_thrust.inverse()).is_err() {
        fail("attitude reset");
    }
    let mut closed = ClosedLoop {
        attitude,
        navigation: PositionEstimator::default(),
        controller,
        guidance: Guidance::Position {
            position_ned_m: Vector3::zeros(),
            yaw_rad: 0.0,
            vertical_speed_mps: None,
        },
        r_imu_m: Vector3::from(BENCH_R_IMU_M),
    };
    let origin = Vector3::zeros();
    let steps = 400;
    for n in 1..=steps {
        let (gyro, accel) = hover_sample(&model, n);
        let fix = (n % FIX_EVERY_STEPS == 0).then_some(&origin);
        closed.step(gyro, accel, fix);
    }
    (closed, steps + 1)
}

/// The IMU offset the closed-loop regions fly with, m.
const BENCH_R_IMU_M: [f32; 3] = [0.01, -0.013, 0.008];

/// The model `learner` learned, with every motor model taken as the synthetic curve
/// (`ω = 300 + 1080 δ + 1620 √δ` rad/s) and τ = 30 ms (see [`hovering_closed_loop`]).
fn flyable_model(learner: &Learner) -> LearnedModel {
    let mut learned = *learner.model();
    for motor in &mut learned.motor[..usize::from(learned.motors)] {
        motor.a_rad_s = 1080.0;
        motor.b_rad_s = 1620.0;
        motor.omega_idle_rad_s = 300.0;
        motor.tau_s = 0.03;
        motor.converged = true;
    }
    learned
}

/// The controller the firmware forms from a learned model at engagement and when it re-forms in
/// flight (`firmware::app::pilot`: `IndiModel::from_learned`, then `Controller::new`), with the
/// IMU offset of the closed-loop regions; `None` when the model is refused.
fn formed_controller(learned: &LearnedModel) -> Option<Controller> {
    let model = match IndiModel::from_learned(learned) {
        Ok(model) => model,
        Err(error) => {
            hprintln!("bench-m7 error: learned model refused: {:?}", error);
            return None;
        }
    };
    let config = IndiConfig { rate_hz: RATE_HZ, ..IndiConfig::default() };
    Controller::new(model, BENCH_R_IMU_M, config).ok()
}

/// Each motor's hover command and speed on `model`.
fn hover_commands(model: &IndiModel) -> ([f32; MAX_MOTORS], [f32; MAX_MOTORS]) {
    let mut commands = [0.0f32; MAX_MOTORS];
    let mut speeds = [0.0f32; MAX_MOTORS];
    for j in 0..model.motors {
        commands[j] = model.command_for_thrust(j, model.u_hover[j]);
        speeds[j] = model.motor[j].omega_full_rad_s() * libm::sqrtf(model.u_hover[j]);
    }
    (commands, speeds)
}

/// The closed-loop 2 kHz control step of the craft `learner` identified (`m` motors), in the
/// order of [`CLOSED_LOOP_REGIONS`] and [`CLOSED_LOOP_PARTS`].
fn closed_loop_regions(m: usize, learner: &Learner) {
    let (hover, n) = hovering_closed_loop(learner);
    let model = *hover.controller.indi().model();
    let (gyro, accel) = hover_sample(&model, n);
    let origin = Vector3::<f32>::zeros();

    let mut state = (hover.clone(), gyro, accel);
    let out = region(&mut state, |(c, gyro, accel)| c.step(black_box(*gyro), *accel, None));
    hprintln!(
        "bench-m7 check: closed loop m={} hover: commands {:?}, allocation {:?}, saturated {:#x}",
        m,
        &out.commands[..m],
        out.allocation,
        out.saturated
    );
    let mut state = (hover.clone(), gyro, accel, origin);
    let _ = region(&mut state, |(c, gyro, accel, fix)| c.step(black_box(*gyro), *accel, Some(fix)));

    // Recovery: the filter told the craft is tilted 60° about the thrust frame's x, then 10 ms
    // of steps, so the rate loop asks for the largest tilt rate and the allocation saturates.
    let mut tilted = hover.clone();
    let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 60f32.to_radians());
    if tilted.attitude.reset_to(tilt * model.q_imu_thrust.inverse()).is_err() {
        fail("attitude reset");
    }
    for k in 1..=20 {
        let (gyro, accel) = hover_sample(&model, n + k);
        tilted.step(gyro, accel, None);
    }
    let (gyro_t, accel_t) = hover_sample(&model, n + 21);
    let mut state = (tilted.clone(), gyro_t, accel_t);
    let out = region(&mut state, |(c, gyro, accel)| c.step(black_box(*gyro), *accel, None));
    hprintln!(
        "bench-m7 check: closed loop m={} recovery: commands {:?}, allocation {:?}, saturated {:#x}",
        m,
        &out.commands[..m],
        out.allocation,
        out.saturated
    );

    outdoor_regions(m, &hover, n);

    // The parts of the hover step.
    let w = Vector3::from(gyro);
    let f = Vector3::from(accel);
    let mut state = (hover.attitude, w, f);
    let _ = region(&mut state, |(a, w, f)| a.update(black_box(w), f, None, DT_S));
    let q = hover.attitude.quaternion();
    let mut state = (hover.navigation, q, f);
    let _ = region(&mut state, |(nav, q, f)| nav.predict(black_box(q), f, DT_S));
    for (closed, gyro, accel) in [(&hover, gyro, accel), (&tilted, gyro_t, accel_t)] {
        let input = ControllerInput {
            gyro_rad_s: gyro,
            accel_mps2: accel,
            q_world_imu: closed.attitude.quaternion(),
            navigation: *closed.navigation.state(),
            unexplained_torque: false,
        };
        let mut state = (closed.controller.clone(), input, closed.guidance);
        let _ = region(&mut state, |(c, input, guidance)| c.update(black_box(input), guidance));
        black_box(&state);
    }
    let reference = IndiReference {
        specific_force_z_mps2: -flight::navigation::STANDARD_GRAVITY_MPS2,
        angular_accel_rad_s2: Vector3::new(0.5, -0.3, 0.1),
    };
    let mut state = (hover.controller.indi().clone(), gyro, accel, reference);
    let _ = region(&mut state, |(indi, gyro, accel, r)| {
        indi.update(black_box(*gyro), *accel, r).copied()
    });
    black_box(&state);

    // The allocation alone on the model's G1: a hover-sized increment, then one no motor set
    // can give (the working set changes), each after a first call from the same problem.
    let Ok(mut allocator) = Allocator::new(m, AllocationConfig::default()) else { fail("alloc") };
    let mut du_min = [0.0f32; MAX_MOTORS];
    let mut du_max = [0.0f32; MAX_MOTORS];
    for j in 0..m {
        du_min[j] = model.u_idle[j] - model.u_hover[j];
        du_max[j] = 1.0 - model.u_hover[j];
    }
    let du_pref = [0.0f32; MAX_MOTORS];
    for dv in [[0.0, 0.0, -0.3, 2.0, -1.5, 0.5], [0.0, 0.0, -4.0, 900.0, -700.0, 300.0]] {
        let _ = allocator.solve(&model.g1, &dv, &du_min, &du_max, &du_pref);
        let mut state = (allocator.clone(), dv);
        let out = region(&mut state, |(a, dv)| {
            a.solve(black_box(&model.g1), dv, &du_min, &du_max, &du_pref)
        });
        hprintln!(
            "bench-m7 check: allocation m={}: {:?} after {} iterations",
            m,
            out.status,
            out.iterations
        );
    }

    // Engagement and the in-flight re-forming: the controller formed from the learned model
    // and started on a sample, in the 2 kHz step that takes over.
    let learned = flyable_model(learner);
    let (commands, speeds) = hover_commands(&model);
    let mut state = (learned, gyro, accel, commands, speeds);
    let formed = region(&mut state, |(learned, gyro, accel, commands, speeds)| {
        formed_controller(black_box(learned)).map(|mut controller| {
            controller.start(*gyro, *accel, commands, speeds);
            controller
        })
    });
    if formed.is_none() {
        fail("controller formed");
    }

    // The hand-catch detector on a watched hover step (its first step starts the watch).
    let mut u = [0.0f32; MAX_MOTORS];
    u[..m].copy_from_slice(&model.u_hover[..m]);
    let mut detector = app::catch::CatchDetector::new(1.0 / DT_S);
    let signals = app::catch::CatchSignals {
        model: &model,
        u: &u,
        asked_rad_s2: Vector3::new(0.2, -0.1, 0.0),
        measured_rad_s2: Vector3::new(0.15, -0.12, 0.01),
    };
    let _ = detector.update(&signals);
    let mut state = (detector, signals);
    let caught = region(&mut state, |(detector, signals)| detector.update(black_box(signals)));
    if caught {
        fail("a hover taken for a hand");
    }
}

/// The hover of `hover` (`n` steps flown) outdoors: 1 s with GNSS solutions at 10 Hz, 100 ms
/// late, taken in parts as the firmware does, and compass samples at 100 Hz; then the eight
/// steps of one more solution and the two of a compass sample, each a region (in the order of
/// [`CLOSED_LOOP_REGIONS`]).
fn outdoor_regions(m: usize, hover: &ClosedLoop, n: usize) {
    use app::compass_heading::{CompassHeading, MagneticSample};
    let model = *hover.controller.indi().model();
    let mut closed = hover.clone();
    // The hold bounded for the receiver as `firmware::app::pilot` bounds it when it forms the
    // controller: its position loop by the fixes' 0.3 m, its velocity loop by their velocity's
    // noise (the solutions below). Unbounded, the hold a motion-capture hover flies chases
    // these open-loop samples' fixes harder than any receiver's hold does, and the octorotor's
    // allocation then works 1,600 instructions more a step.
    closed.controller.cap_position_gain(flight::navigation::position_crossover(0.3, true));
    closed.controller.cap_hold_velocity_gain(flight::controller::max_velocity_gain(
        flight::navigation::velocity_estimate_noise_mps(0.05, 0.1, 0.1),
    ));
    let mut outdoors = Outdoors {
        alignment: aligned_alignment(),
        waiting: None,
        part: None,
        compass: CompassHeading::default(),
    };
    // A 48 µT field at 63° of dip in the fixes' world (the filter's turned by the alignment's
    // yaw), magnetic north 2.9° east of true north, in the IMU's axes: the motors-off reference
    // from a second of still samples, then flight samples.
    let world = Vector3::new(21.4f32, 1.1, 42.9);
    outdoors.compass.configure(libm::atan2f(world.y, world.x));
    // The field seen at the filter's attitude turned by the alignment's yaw: the compass then
    // agrees with the filter's heading, as in a steady flight.
    let sample = |q_filter: &UnitQuaternion<f32>, outdoors: &Outdoors| {
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), outdoors.alignment_yaw());
        MagneticSample { field_imu_ut: ((turn * q_filter).inverse() * world).into(), noise_ut: 0.5 }
    };
    let q0 = closed.attitude.quaternion();
    for k in 0..100u64 {
        outdoors.compass.sample(&sample(&q0, &outdoors), 10_000 * k + 1);
        outdoors.compass.step(10_000 * k + 1, &q0, true, false);
        outdoors.compass.step(10_000 * k + 501, &q0, true, false);
    }
    let fix = |k: usize| flight::navigation::Fix {
        position_ned_m: Vector3::new(0.02 * libm::sinf(k as f32), -0.01, 0.01),
        sigma_m: [0.3, 0.45],
        velocity: Some((Vector3::new(0.01, -0.02 * libm::cosf(k as f32), 0.0), 0.05)),
        age_s: 0.1,
        dt_fix_s: 0.1,
    };
    let t0_us = 1_000_000u64;
    let time_us = |k: usize| t0_us + (k as u64) * 500;
    // 1 s: a solution every 200 steps, a compass sample every 20 (none with a solution's part).
    let steps = 2000;
    for k in 0..steps {
        let (gyro, accel) = hover_sample(&model, n + k);
        if k % 200 == 0 {
            outdoors.waiting = Some(fix(k));
        }
        if k % 20 == 10 {
            let field = sample(&closed.attitude.quaternion(), &outdoors);
            outdoors.compass.sample(&field, time_us(k));
        }
        closed.step_outdoors(gyro, accel, &mut outdoors, time_us(k));
    }
    if outdoors.part.is_some() || closed.navigation.rejected() > 0 {
        fail("outdoors: a solution was refused or not taken");
    }
    // One more solution: its eight parts, each a region.
    outdoors.waiting = Some(fix(steps));
    for part in 0..8 {
        let k = steps + part;
        let (gyro, accel) = hover_sample(&model, n + k);
        let mut state = (closed.clone(), outdoors.clone(), gyro, accel);
        let _ = region(&mut state, |(c, o, gyro, accel)| {
            c.step_outdoors(black_box(*gyro), *accel, o, time_us(k))
        });
        (closed, outdoors) = (state.0, state.1);
    }
    if outdoors.part.is_some() {
        fail("outdoors: the solution took more than eight parts");
    }
    // A compass sample: its two parts.
    let field = sample(&closed.attitude.quaternion(), &outdoors);
    outdoors.compass.sample(&field, time_us(steps + 8));
    for part in 0..2 {
        let k = steps + 8 + part;
        let (gyro, accel) = hover_sample(&model, n + k);
        let mut state = (closed.clone(), outdoors.clone(), gyro, accel);
        let _ = region(&mut state, |(c, o, gyro, accel)| {
            c.step_outdoors(black_box(*gyro), *accel, o, time_us(k))
        });
        (closed, outdoors) = (state.0, state.1);
    }
    let q = closed.attitude.quaternion();
    match outdoors.compass.step(time_us(steps + 10), &q, false, false) {
        Some(yaw) => hprintln!(
            "bench-m7 check: outdoors m={}: compass heading {} rad, alignment yaw {:?} rad, {} fixes refused",
            m,
            yaw,
            outdoors.alignment.yaw_rad(),
            closed.navigation.rejected()
        ),
        None => fail("outdoors: the compass gave no heading"),
    }
}

fn fail(message: &str) -> ! {
    hprintln!("bench-m7 error: {}", message);
    debug::exit(debug::EXIT_FAILURE);
    // Unreachable under QEMU (semihosting exit ends it); on a board without a debugger, sleep.
    loop {
        cortex_m::asm::wfi();
    }
}

/// The DShot regions: what the motor task does per 2 kHz step for eight motors.
fn dshot_regions() {
    const MOTORS: usize = 8;
    // The board's capture timer at 240 MHz: 320 ticks per 750 kbit/s telemetry bit.
    const BIT_TICKS: u32 = 320;
    const POLE_PAIRS: u8 = 7;
    // Electrical periods 600–698 µs (mantissa 300–349, exponent 1): about 90,000 eRPM, a
    // 5-inch motor at hover, 1,300–1,500 rad/s with 7 pole pairs.
    let values: [u16; MOTORS] = core::array::from_fn(|i| (1 << 9) | (300 + 7 * i as u16));
    // As the capture timer records them (wrapping within the answer); the ESC's side is the
    // firmware file's own encoder.
    let captures: [_; MOTORS] = core::array::from_fn(|i| {
        dshot::answer_edges(values[i], 1_000 * i as u32 + 0xFFFF_F000, BIT_TICKS)
    });
    let mut state = (captures, [dshot::MotorTelemetry::default(); MOTORS]);
    let _ = region(&mut state, |(captures, telemetry)| {
        for (capture, motor) in black_box(&*captures).iter().zip(telemetry.iter_mut()) {
            let answer = dshot::telemetry_from_edges(&capture.0[..capture.1], BIT_TICKS);
            motor.record(answer, POLE_PAIRS);
        }
    });
    for (i, motor) in state.1.iter().enumerate() {
        let expected = dshot::mechanical_rad_s(dshot::erpm_from_telemetry(values[i]), POLE_PAIRS);
        if motor.speed_rad_s() != Some(expected) || motor.counters.frames_ok != 1 {
            fail("dshot: an answer did not decode to its value");
        }
    }
    hprintln!(
        "bench-m7 check: dshot motor 0 at {} rad/s",
        state.1[0].speed_rad_s().unwrap_or(f32::NAN)
    );
    let commands: [f32; MOTORS] = core::array::from_fn(|i| 0.3 + 0.05 * i as f32);
    let mut state = (commands, [0u16; MOTORS]);
    let _ = region(&mut state, |(commands, frames)| {
        for (command, frame) in black_box(&*commands).iter().zip(frames.iter_mut()) {
            *frame = dshot::output_frame(*command, true);
        }
    });
    black_box(&state);
}

/// The link's cost on the board: a request frame decoded byte by byte (COBS, CRC-32C, the
/// signature split off, postcard), and a signed request's HMAC-SHA256 verified (SHA-256 as the
/// firmware compiles it: `sha2_backend_soft = "compact"`).
fn link_regions() {
    use protocol::{Decoder, Request, SetParam, Signer, MAX_FRAME_LEN, PARAM_MAX_LEN};
    const _: () = assert!(PARAM_MAX_LEN == 8, "the region's name says 8 values");
    let values = [0.025f32; PARAM_MAX_LEN];
    let request = Request::SetParam(SetParam {
        name: protocol::text("motor_tau_s"),
        values: protocol::ParamValues::from_slice(&values).unwrap_or_default(),
    });
    let signer = Signer { key: [0x5A; protocol::signing::KEY_LEN], session: 7 };
    let mut frame = [0u8; MAX_FRAME_LEN];
    let Ok(len) = request.encode_signed(1, &signer, 1_000, &mut frame) else {
        fail("link: the signed request does not fit a frame");
    };
    hprintln!(
        "bench-m7 check: link: a signed SetParam of {} values is {} bytes",
        PARAM_MAX_LEN,
        len
    );
    let mut state = (Decoder::new(), frame, len, 0u32);
    let _ = region(&mut state, |(decoder, frame, len, decoded)| {
        for &byte in black_box(&frame[..*len]) {
            if let Some(Ok(frame)) = decoder.push(byte) {
                *decoded += u32::from(Request::decode(&frame).is_ok());
            }
        }
    });
    if state.3 != 1 {
        fail("link: the frame did not decode");
    }
    let mut decoder = Decoder::new();
    for &byte in &frame[..len - 1] {
        let _ = decoder.push(byte);
    }
    let Some(Ok(decoded)) = decoder.push(0) else { fail("link: no frame") };
    let Some(signature) = decoded.signature else { fail("link: no signature") };
    let mut state = (signature, signer.key, false);
    let _ = region(&mut state, |(signature, key, ok)| *ok = signature.verify(black_box(key), 7));
    if !state.2 {
        fail("link: the signature did not verify");
    }
}

#[entry]
fn main() -> ! {
    const MOTOR_COUNTS: [usize; 3] = [4, 6, 8];
    const TILTED_MOTOR_COUNTS: [usize; 2] = [6, 8];
    #[cfg(feature = "bounded-search")]
    const BOUNDED_MOTOR_COUNTS: [usize; 2] = [6, 8];
    const TILT_RAD: f32 = 20.0 * core::f32::consts::PI / 180.0;
    hprintln!("bench-m7 region: empty (marker overhead)");
    for m in MOTOR_COUNTS {
        hprintln!("bench-m7 region: thrust-axis solve m={} cold", m);
        hprintln!("bench-m7 region: thrust-axis solve m={} warm", m);
    }
    for m in TILTED_MOTOR_COUNTS {
        hprintln!("bench-m7 region: thrust-axis solve m={} tilted 20°, cold", m);
        hprintln!("bench-m7 region: thrust-axis solve m={} tilted 20°, warm", m);
    }
    #[cfg(feature = "bounded-search")]
    for m in BOUNDED_MOTOR_COUNTS {
        hprintln!("bench-m7 region: thrust-axis bounded search m={} (one motor capped)", m);
    }
    // The learner without speed telemetry, built in place (25 KB: never on the stack).
    static mut NO_SPEED_SLOT: LearnerSlot = LearnerSlot::empty();
    // SAFETY: the only reference to the slot, in this single-threaded harness.
    let no_speed_slot = unsafe { &mut *core::ptr::addr_of_mut!(NO_SPEED_SLOT) };
    let published = no_speed_publications(no_speed_slot);
    for ((m, seen), published) in NO_SPEED_ENDS.into_iter().zip(published) {
        if m == 4 {
            for k in 1..=NO_SPEED_MEASURED_SAMPLES {
                hprintln!("bench-m7 region: learner step m=4, no speed telemetry, sample {}", k);
            }
        }
        for n in seen - 2..=published + NO_SPEED_AFTER_PUBLICATION {
            let what = match n.cmp(&published) {
                core::cmp::Ordering::Less => "",
                core::cmp::Ordering::Equal => ": the model published (caught up)",
                core::cmp::Ordering::Greater => ": after the publication (as in flight)",
            };
            hprintln!(
                "bench-m7 region: learner m={}, no speed telemetry, sample {} at the excitation's \
                 end (from {}: the lag candidates' regressions, a work budget a sample, then the \
                 held samples, means over {} ms, at most {} a sample){}",
                m,
                n,
                seen,
                1000.0 * flight::learner::no_speed::HOLD_INTERVAL_S,
                flight::learner::no_speed::RELEASE_PER_SAMPLE,
                what
            );
        }
    }
    hprintln!("bench-m7 region: imu-offset RLS update");
    hprintln!("bench-m7 region: imu-offset estimator per sample, held");
    hprintln!("bench-m7 region: imu-offset estimator per sample, free fall");
    for m in IN_FLIGHT_FIT_MOTOR_COUNTS {
        hprintln!(
            "bench-m7 region: imu-offset in-flight fit per sample m={}, summed (W and its first row)",
            m
        );
        hprintln!("bench-m7 region: imu-offset in-flight fit per sample m={}, its second row", m);
        hprintln!("bench-m7 region: imu-offset in-flight fit per sample m={}, its third row", m);
        hprintln!(
            "bench-m7 region: imu-offset in-flight fit m={}, 4 samples: one 2 ms sum interval",
            m
        );
        hprintln!("bench-m7 region: imu-offset in-flight fit solve m={}", m);
    }
    for what in FIT_HANDOFF_CASES {
        hprintln!("bench-m7 region: in-flight fit hand-off, {}", what);
    }
    for m in LEARNER_MOTOR_COUNTS {
        for what in LEARNER_CYCLE {
            hprintln!("bench-m7 region: learner step m={}, {}", m, what);
        }
        hprintln!("bench-m7 region: learner cycle m={}: the same twelve samples in one region", m);
        hprintln!(
            "bench-m7 region: learner step m={}, sample 6 after its own rows found no hover: \
             force row z's turn ends, thrust-axis solve on the fallback rows, model published",
            m
        );
        for what in CLOSED_LOOP_REGIONS {
            hprintln!("bench-m7 region: closed-loop step m={}, {}", m, what);
        }
        for what in CLOSED_LOOP_PARTS {
            hprintln!("bench-m7 region: closed-loop part m={}: {}", m, what);
        }
    }
    hprintln!("bench-m7 region: learner part: effectiveness update m=4, a force row begun (filters, its whole update)");
    hprintln!("bench-m7 region: learner part: effectiveness update m=4, a force row's turn ends (filters)");
    hprintln!("bench-m7 region: learner part: effectiveness update m=4, a rotational row begun (filters, its product P x)");
    hprintln!("bench-m7 region: learner part: effectiveness update m=4, a rotational row's turn ends (filters, its downdate)");
    hprintln!("bench-m7 region: learner part: one motor model update");
    hprintln!("bench-m7 region: learner part: RLS update, 29 regressors, 1 output (one quad rotational row)");
    hprintln!(
        "bench-m7 region: learner part: RLS update, 15 regressors, 1 output (one quad force row)"
    );
    hprintln!("bench-m7 region: learner part: tumble inertia, one free-fall sample");
    hprintln!(
        "bench-m7 region: learner part: tumble inertia prior (once, as the excitation starts)"
    );
    hprintln!(
        "bench-m7 region: libm part: one libm::sqrtf call (the allocation makes 2-3 per motor)"
    );
    hprintln!(
        "bench-m7 region: libm part: one libm::hypotf call (Givens rotations of the allocation)"
    );
    hprintln!("bench-m7 region: flight part: one flight::math::sqrt call (vsqrt.f32)");
    hprintln!(
        "bench-m7 region: flight part: one flight::math::hypot call (libm's hypotf on vsqrt.f32)"
    );
    hprintln!("bench-m7 region: dshot: decode 8 bidirectional answers (edges → GCR → checksum → rad/s, counted)");
    hprintln!("bench-m7 region: dshot: encode 8 bidirectional throttle frames");
    hprintln!("bench-m7 region: link: decode a signed SetParam frame of 8 values, byte by byte (COBS, CRC-32C, postcard)");
    hprintln!("bench-m7 region: link: verify a signed request's HMAC-SHA256");
    hprintln!("bench-m7 region: tick part: a 152-byte log entry into its ring of 512 (first)");
    hprintln!("bench-m7 region: tick part: a 152-byte log entry into its ring of 512 (second)");
    hprintln!("bench-m7 region: tick part: one battery reading into the monitor");
    hprintln!("bench-m7 region: tick part: the battery's status for the snapshot");
    hprintln!("bench-m7 region: pilot step: position mode, the setpoint moved and the fly-away detector counting");
    hprintln!("bench-m7 region: pilot part: position mode's setpoint moved");
    hprintln!("bench-m7 region: pilot step: a landing, the touchdown detector (no fixes)");
    hprintln!("bench-m7 region: pilot part: the fly-away detector, hovering");
    hprintln!("bench-m7 region: pilot part: the fly-away detector, moving away fast");
    hprintln!("bench-m7 region: pilot part: a stick frame shaped (when a stick moves)");
    hprintln!("bench-m7 region: pilot part: position mode's velocity turned (every 2° of heading)");
    hprintln!("bench-m7 region: navigation part: predict (every step, the history advanced)");
    hprintln!(
        "bench-m7 region: navigation part: a GNSS fix taken, position and velocity, 100 ms late"
    );
    hprintln!("bench-m7 region: navigation part: a GNSS fix refused (multipath)");
    hprintln!("bench-m7 region: navigation part: the heading alignment's velocity fix");
    hprintln!(
        "bench-m7 region: compass part: a field sample's monitor update and tilt-compensated heading (100 Hz)"
    );

    let mut nothing = 0u32;
    region(&mut nothing, |n| black_box(*n));

    let planar = MOTOR_COUNTS.map(|m| (m, 0.0));
    let tilted = TILTED_MOTOR_COUNTS.map(|m| (m, TILT_RAD));
    for (m, tilt_rad) in planar.into_iter().chain(tilted) {
        let problem = airframe(m, tilt_rad);
        let mut state = (ThrustAxisSolver::default(), problem);
        let cold = region(&mut state, |(solver, problem)| solver.solve(black_box(problem)));
        let warm = region(&mut state, |(solver, problem)| solver.solve(black_box(problem)));
        match (cold, warm) {
            (Ok(a), Ok(b)) if !a.bounded && !b.bounded => {
                let e = b.euler_zyx();
                hprintln!(
                    "bench-m7 check: m={} tilt {} deg: roll {} pitch {} yaw {} deg",
                    m,
                    tilt_rad.to_degrees(),
                    e.roll_rad.to_degrees(),
                    e.pitch_rad.to_degrees(),
                    e.yaw_rad.to_degrees()
                );
            }
            _ => fail("thrust-axis solve failed or needed the bounded search"),
        }
    }

    // The bounded search: the planar hexa and octo with motor 0 capped below its heuristic
    // command, so the heuristic's u* leaves the bounds and the active-set search runs. Only with
    // the feature `bounded-search` (`cargo xtask bench-m7 --bounded-search`): the firmware is
    // built without it, and so is the default bench, so that the other regions are compiled as
    // the firmware compiles them.
    #[cfg(feature = "bounded-search")]
    for m in BOUNDED_MOTOR_COUNTS {
        let mut upper = [1.0f32; MOTORS_MAX];
        upper[0] = 0.3;
        let capped = airframe(m, 0.0).with_bounds(&[0.0; MOTORS_MAX][..m], &upper[..m]);
        let Ok(capped) = capped else { fail("bounds refused") };
        let mut state = (ThrustAxisSolver::default(), capped);
        match region(&mut state, |(solver, problem)| solver.solve(black_box(problem))) {
            Ok(solution) if solution.bounded => {
                hprintln!("bench-m7 check: bounded m={} u_hover {:?}", m, solution.u_hover());
            }
            _ => fail("bounded search did not run or found nothing"),
        }
    }

    no_speed_regions(no_speed_slot, published);

    let sample = AlignedSample {
        index: 7,
        gyro_radps: Vector3::new(6.1, -2.3, 1.4),
        gyro_dot_radps2: Vector3::new(-12.0, 30.5, 4.2),
        acc_mps2: Vector3::new(0.9, -1.7, 0.35),
    };
    let mut rls = (OffsetRls::new(Vector3::zeros()), sample);
    rls.0.update(&rls.1);
    region(&mut rls, |(rls, sample)| rls.update(black_box(sample)));
    black_box(&rls);

    // The whole onboard per-sample path the background task runs at 2 kHz (filters, Ω̇, the
    // free-fall detector, block accumulation), as configured in `firmware::app`: first with
    // the craft held still, then 0.3 s into a free-fall tumble (r = 18 mm, Ω = 6.5 rad/s).
    let config = Config { model: Model::OffsetAndAccBias, ..Config::default() };
    let Ok(mut estimator) = ImuOffsetEstimator::new(2000.0, config) else { fail("estimator") };
    let held = ImuSample { gyro_radps: Vector3::zeros(), acc_mps2: Vector3::new(0.0, 0.0, -9.81) };
    for _ in 0..200 {
        let _ = estimator.update(&held);
    }
    let mut state = (estimator, held);
    let _ = region(&mut state, |(estimator, sample)| estimator.update(black_box(sample)));
    let omega = Vector3::new(6.0, -2.0, 1.5);
    let r_m = Vector3::new(-0.010, -0.013, 0.008);
    let tumbling = ImuSample { gyro_radps: omega, acc_mps2: omega.cross(&omega.cross(&r_m)) };
    state.1 = tumbling;
    for _ in 0..600 {
        let _ = state.0.update(&tumbling);
    }
    if !state.0.in_free_fall() {
        fail("the tumble was not detected as free fall");
    }
    let _ = region(&mut state, |(estimator, sample)| estimator.update(black_box(sample)));
    black_box(&state);

    // The IMU offset fitted in flight (`imu_offset::in_flight`, issue 32; the background task
    // runs it beside the learner on a throw-to-fly that knows no offset): a tumble with the
    // motors pulsed, 0.8 s in, one sample that goes into the sums and the two after it (a row
    // each), the 2 ms interval it begins, and one solve (the cost only: the synthetic tumble is
    // not physical enough for the fit to be right).
    for m in IN_FLIGHT_FIT_MOTOR_COUNTS {
        let Some(mut fit) = OffsetFit::new(m, 2000.0, 0.0) else { fail("in-flight fit") };
        let tumble = |n: usize| {
            let t = n as f32 / 2000.0;
            // A precessing spin.
            let (sin, cos) = (libm::sinf(9.0 * t), libm::cosf(9.0 * t));
            let omega = Vector3::new(6.0 * cos, 6.0 * sin, 1.5 + libm::sinf(7.0 * t));
            let omega_dot = Vector3::new(-54.0 * sin, 54.0 * cos, 7.0 * libm::cosf(7.0 * t));
            let accel = omega_dot.cross(&r_m) + omega.cross(&omega.cross(&r_m));
            // Each motor pulsed in turn for 50 ms, as the excitation does.
            let speeds: [f32; MOTORS_MAX] =
                core::array::from_fn(|i| if (n / 100) % m == i { 1600.0 } else { 1000.0 });
            // The navigation's velocity in the body (the drag's regressor), m/s.
            let velocity = [4.0 * cos, -4.0 * sin, 2.0 + libm::sinf(3.0 * t)];
            ([omega.x, omega.y, omega.z], [accel.x, accel.y, accel.z], speeds, velocity)
        };
        // Up to a sample that begins going into the sums (one in every `SUM_INTERVAL_S`).
        let mut n = 0;
        loop {
            let (gyro, accel, speeds, velocity) = tumble(n);
            let mut next = fit.clone();
            next.update(gyro, accel, &speeds[..m], velocity);
            if n >= 1600 && next.summing() && !fit.summing() {
                break;
            }
            fit = next;
            n += 1;
        }
        let mut each = fit.clone();
        for k in 0..3 {
            let mut state = (each, tumble(n + k));
            region(&mut state, |(fit, (gyro, accel, speeds, velocity))| {
                fit.update(black_box(*gyro), *accel, &speeds[..m], *velocity)
            });
            each = state.0;
        }
        if each.summing() {
            fail("the in-flight fit's sample was not summed in three calls");
        }
        let samples: [_; 4] = core::array::from_fn(|k| tumble(n + k));
        let mut four = (fit, samples);
        region(&mut four, |(fit, samples)| {
            for (gyro, accel, speeds, velocity) in samples.iter() {
                fit.update(black_box(*gyro), *accel, &speeds[..m], *velocity);
            }
        });
        let mut state = (four.0, tumble(n + 4));
        let estimate = region(&mut state, |(fit, _)| black_box(&*fit).estimate());
        if estimate.is_err() {
            fail("the in-flight fit was not determined");
        }
        black_box(&state);
    }

    fit_handoff_regions();

    // Background learner steps in the middle of an identification, for a quad and an
    // octorotor: the motor models and the filters on every sample, and the effectiveness
    // regressions in turn, a row over two samples (`flight::learner::effectiveness::
    // MAX_ROW_RATE_HZ`), the model staged in the second sample of each cycle and published
    // with a thrust-axis solve in the fourth (`LEARNER_CYCLE`). Each sample is measured on its
    // own (the worst is the figure the background task must meet on every sample), then the
    // twelve together from the same state.
    for m in LEARNER_MOTOR_COUNTS {
        let primed = primed_learner(m, true);
        let samples: [Sample; 12] = core::array::from_fn(|k| {
            synthetic_sample(m, 0.7, 0.601 + k as f32 / 2000.0, [7.0, 7.0, 1.7]).0
        });
        let mut learner = primed.clone();
        for sample in &samples {
            let mut state = (learner, *sample);
            region(&mut state, |(learner, (gyro, accel, commands, speeds))| {
                learner.update(*gyro, *accel, black_box(commands), black_box(speeds))
            });
            learner = state.0;
        }
        let mut state = (primed, samples);
        region(&mut state, |(learner, samples)| {
            for (gyro, accel, commands, speeds) in samples.iter() {
                learner.update(*gyro, *accel, black_box(commands), black_box(speeds));
            }
        });
        black_box(&state);
        if learner.model().axis_status != AxisStatus::Found {
            fail("the learner had no thrust axis after its excitation");
        }
        // The same cycle where the learner's own force rows find no hover and the fallback
        // rows (the airframe's, per squared speed) are given
        // (`Learner::set_fallback_force_rows`): the publication (sample 4) finds none, and the
        // next sample that ends a row's turn (6) solves on the fallback rows.
        let mut blind = primed_learner(m, false);
        if blind.model().thrust_axis.is_some() {
            fail("the learner's own rows found a hover with no force seen");
        }
        let problem = airframe(m, 0.0);
        let per_speed2 = 1.0 / (3000.0 * 3000.0);
        let mut fallback = [[0.0f32; MAX_MOTORS]; 3];
        for (k, row) in fallback.iter_mut().enumerate() {
            for (to, from) in row.iter_mut().zip(problem.g1_f_row(k)) {
                *to = from * per_speed2;
            }
        }
        blind.set_fallback_force_rows(Some(fallback));
        for (gyro, _, commands, speeds) in &samples[..5] {
            blind.update(*gyro, [0.0; 3], commands, speeds);
        }
        let (gyro, _, commands, speeds) = samples[5];
        let mut state = (blind, gyro, commands, speeds);
        region(&mut state, |(learner, gyro, commands, speeds)| {
            learner.update(*gyro, [0.0; 3], black_box(commands), black_box(speeds))
        });
        if state.0.model().thrust_axis.is_none() {
            fail("the fallback rows gave no thrust axis");
        }
        let axis = learner.model().thrust_axis.map(|a| a.thrust_dir_imu).unwrap_or_default();
        hprintln!("bench-m7 check: learner m={} thrust direction {:?}", m, axis);
        closed_loop_regions(m, &learner);
    }

    // Where a quad's learner step goes: its three largest parts on their own.
    {
        let filter = flight::filters::BiquadCoefficients::butterworth_lowpass(20.0, 2000.0)
            .unwrap_or_else(|_| fail("filter"));
        let config = flight::learner::rls::RlsConfig { lambda: 1.0, p0: 1e6, p_max: 1e10 };
        use flight::learner::effectiveness::{EffectivenessEstimator, EffectivenessSetup};
        let mut est = EffectivenessEstimator::new(EffectivenessSetup {
            motors: 4,
            rate_hz: 2000.0,
            filter,
            r_imu_m: [0.01, 0.0, 0.0],
            speed_lag_s: 3e-4,
            rls: config,
        });
        let mut rate = [7.0f32, 7.0, 1.7];
        for n in 0..402 {
            let ((gyro, accel, _c, speeds), angular) =
                synthetic_sample(4, 0.7, n as f32 / 2000.0, rate);
            est.update(gyro, accel, &speeds[..4]);
            for k in 0..3 {
                rate[k] += angular[k] / 2000.0;
            }
        }
        // 402 samples: the next begins force row z; then its turn ends, then rotational row x
        // begins and its turn ends.
        for t in [0.201, 0.2015, 0.202, 0.2025] {
            let ((gyro, accel, _c, speeds), _) = synthetic_sample(4, 0.7, t, rate);
            let mut state = (est, gyro, accel, speeds);
            region(&mut state, |(est, gyro, accel, speeds)| {
                est.update(black_box(*gyro), *accel, &speeds[..4])
            });
            est = black_box(state).0;
        }
        let fast = flight::filters::BiquadCoefficients::butterworth_lowpass(40.0, 2000.0)
            .unwrap_or_else(|_| fail("filter"));
        let mut mm = flight::learner::motor_model::MotorModelEstimator::new(fast, 2000.0, config);
        for n in 0..100 {
            mm.update(0.3, true, 1000.0 + n as f32);
        }
        let mut st = (mm, 0.4f32, 1200.0f32);
        region(&mut st, |(mm, c, w)| mm.update(black_box(*c), true, *w));
        black_box(&st);
        let mut rls = flight::learner::rls::Rls::<53, 1, 1431>::new(29, config);
        let x: [f32; 29] = core::array::from_fn(|j| 0.1 + 0.01 * j as f32);
        for _ in 0..10 {
            let _ = rls.update(&x, &[1.0]);
        }
        let mut st = (rls, x);
        let _ = region(&mut st, |(rls, x)| rls.update(black_box(&x[..]), &[1.0]));
        black_box(&st);
        let mut rls = flight::learner::rls::Rls::<27, 1, 378>::new(15, config);
        let x: [f32; 15] = core::array::from_fn(|j| 0.1 + 0.01 * j as f32);
        for _ in 0..10 {
            let _ = rls.update(&x, &[1.0]);
        }
        let mut st = (rls, x);
        let _ = region(&mut st, |(rls, x)| rls.update(black_box(&x[..]), &[1.0]));
        black_box(&st);
    }
    // The free tumble's inertia fit (the `tumble` crate): its per-sample update during
    // the release delay, and the prior it hands to the learner once, as the excitation starts
    // (the background task's sample that also restarts the learner).
    {
        let mut tumble = TumbleInertia::new(2000.0);
        let mut rate = Vector3::new(5.0f32, -3.0, 4.0);
        for _ in 0..200 {
            tumble.update(rate.into());
            rate = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001) * rate;
        }
        let mut state = (tumble, <[f32; 3]>::from(rate));
        region(&mut state, |(tumble, gyro)| tumble.update(black_box(*gyro)));
        for _ in 0..99 {
            rate = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001) * rate;
            state.0.update(rate.into());
        }
        let prior = region(&mut state, |(tumble, _)| black_box(&*tumble).prior());
        if prior.equations == 0 {
            fail("the tumble gave no prior");
        }
        black_box(&prior);
    }
    // libm's square root is software on this target (no `vsqrt.f32` path): what one call costs.
    let mut x = (2.0f32, 3.0f32);
    let _ = region(&mut x, |(a, _)| libm::sqrtf(black_box(*a)));
    let _ = region(&mut x, |(a, b)| libm::hypotf(black_box(*a), *b));
    // What `flight` calls instead (`flight::math`, "Square root"), and a check that the
    // instruction gives libm's value on this target: every 9,973rd positive bit pattern
    // (subnormals, normals, infinity), their negatives and the edge cases.
    let _ = region(&mut x, |(a, _)| flight::math::sqrt(black_box(*a)));
    let _ = region(&mut x, |(a, b)| flight::math::hypot(black_box(*a), *b));
    sqrt_matches_libm();
    dshot_regions();
    link_regions();
    tick_regions();
    pilot_regions();
    navigation_regions();
    hprintln!("bench-m7 done");
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    fail("panic")
}
