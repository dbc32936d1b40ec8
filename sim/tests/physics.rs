//! Physics tests that can fail: conservation laws, the intermediate-axis instability, hover
//! against the analytic solution, the accelerometer's rotational terms, the motor time constant.

use firmware::app::hal::{Imu, Motors};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use sim::airframe::{Airframe, STANDARD_GRAVITY_MPS2};
use sim::board::{Arming, SimBoard, SimConfig};
use sim::dynamics::State;
use sim::physics::Physics;

/// Physics at 8 kHz, the rate the simulator runs at.
const RATE_HZ: f64 = 8000.0;

fn drag_free(name: &str) -> Airframe {
    let mut a = Airframe::builtin(name).unwrap();
    a.drag = Default::default();
    a
}

/// A free vehicle high above the ground, spinning at `rate_body_rad_s`, motors stopped.
fn tumbling(airframe: &Airframe, rate_body_rad_s: Vector3<f64>) -> Physics {
    let q0 = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0);
    let mut p = Physics::new(airframe, Vector3::new(0.0, 0.0, -1.0e4), q0, RATE_HZ);
    p.release();
    let mut s: State = *p.state();
    s.rate_body_rad_s = rate_body_rad_s;
    p.set_state(s);
    p
}

#[test]
fn torque_free_tumble_conserves_angular_momentum_and_energy() {
    // paper-quad has products of inertia, so the tumble is not about principal axes.
    let airframe = drag_free("paper-quad");
    let mut p = tumbling(&airframe, Vector3::new(6.0, -9.0, 4.0));
    let l0 = p.model().angular_momentum_world(p.state());
    let e0 = p.model().rotational_energy_j(p.state());
    let mut worst_l: f64 = 0.0;
    let mut worst_e: f64 = 0.0;
    for _ in 0..(2.0 * RATE_HZ) as usize {
        p.step();
        let l = p.model().angular_momentum_world(p.state());
        let e = p.model().rotational_energy_j(p.state());
        worst_l = worst_l.max((l - l0).norm() / l0.norm());
        worst_e = worst_e.max(((e - e0) / e0).abs());
    }
    println!("relative drift over 2 s: |ΔL|/|L| = {worst_l:.2e}, |ΔE|/E = {worst_e:.2e}");
    assert!(worst_l < 1e-6, "angular momentum drift {worst_l:.3e}");
    assert!(worst_e < 1e-6, "energy drift {worst_e:.3e}");
    // The tumble really is a tumble: the body rate changes direction.
    let w = p.state().rate_body_rad_s;
    assert!((w - Vector3::new(6.0, -9.0, 4.0)).norm() > 0.5, "body rate barely moved: {w}");
}

fn principal_body() -> Airframe {
    let mut a = drag_free("racer-5in");
    a.inertia_diag_kg_m2 = [1.0e-3, 2.0e-3, 2.8e-3];
    a.inertia_products_kg_m2 = [0.0; 3];
    a
}

/// Spins about `axis` at 10 rad/s with a 1 mrad/s perturbation on the other axes for 3 s and
/// returns the smallest and largest rate about that axis.
fn spin_about(axis: usize) -> (f64, f64) {
    let airframe = principal_body();
    let mut w0 = Vector3::new(1e-3, 1e-3, 1e-3);
    w0[axis] = 10.0;
    let mut p = tumbling(&airframe, w0);
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for _ in 0..(3.0 * RATE_HZ) as usize {
        p.step();
        let w = p.state().rate_body_rad_s[axis];
        lo = lo.min(w);
        hi = hi.max(w);
    }
    (lo, hi)
}

#[test]
fn intermediate_axis_is_unstable_and_the_others_are_not() {
    // Growth rate about y: 10·√((Iyy−Ixx)(Izz−Iyy)/(Ixx Izz)) = 5.3 /s, so 1e-3 grows to O(10)
    // in about 1.7 s: the spin flips within the 3 s run.
    let (lo_y, _) = spin_about(1);
    assert!(lo_y < -9.0, "intermediate axis did not flip: min Ω_y = {lo_y}");
    for axis in [0, 2] {
        let (lo, hi) = spin_about(axis);
        assert!(lo > 9.99 && hi < 10.01, "axis {axis} not stable: Ω in [{lo}, {hi}]");
    }
}

fn held_board(airframe: &Airframe) -> SimBoard {
    let config = SimConfig { ideal_imu: true, arming: Arming::Armed, ..SimConfig::default() };
    SimBoard::new(airframe, &config)
}

#[test]
fn symmetric_quad_hovers_at_the_analytic_speed() {
    let airframe = drag_free("racer-5in");
    // Closed form for four identical vertical rotors: 4 k_f ω² = m g.
    let omega_hover = (airframe.mass_kg * STANDARD_GRAVITY_MPS2
        / (4.0 * airframe.motor.thrust_coefficient_n_per_rad2_s2))
        .sqrt();
    let command = airframe.motor.command_for_speed(omega_hover) as f32;
    let mut board = held_board(&airframe);
    board.motors_mut().set_commands(&[command; 4]);
    for _ in 0..1000 {
        board.tick(); // 0.5 s held while the motors spin up
    }
    board.physics_mut().release();
    let p0 = board.physics().state().position_ned_m;
    for _ in 0..2000 {
        board.tick(); // 1 s free
    }
    let s = *board.physics().state();
    let drift_m = (s.position_ned_m - p0).norm();
    assert!(drift_m < 1e-3, "hover drifted {drift_m} m");
    assert!(s.rate_body_rad_s.norm() < 1e-6, "hover rotates {}", s.rate_body_rad_s);
    // f32 commands: the speed is exact to the command's resolution (~1e-7 relative).
    for (i, w) in s.rotor_speed_rad_s[..4].iter().enumerate() {
        assert!(((w - omega_hover) / omega_hover).abs() < 1e-6, "rotor {i}: {w} vs {omega_hover}");
    }
    // Telemetry: the DShot-quantised speed within its resolution.
    for (i, w) in board.motors().speeds_rad_s()[..4].iter().enumerate() {
        let w = f64::from(w.expect("telemetry reported"));
        assert!(((w - omega_hover) / omega_hover).abs() < 0.01, "rotor {i} telemetry {w}");
    }
    // The level IMU reads −g on z.
    let acc = board.last_sample().accel_mps2;
    assert!((f64::from(acc[2]) + STANDARD_GRAVITY_MPS2).abs() < 1e-4, "acc {acc:?}");
}

#[test]
fn tilted_hexarotor_hovers_on_its_allocation_solution() {
    let airframe = drag_free("hex-tilted");
    let speeds = airframe.hover_speeds_rad_s().unwrap();
    let commands: Vec<f32> = speeds
        .iter()
        .enumerate()
        .map(|(i, w)| airframe.rotor_motor(i).command_for_speed(*w) as f32)
        .collect();
    let mut board = held_board(&airframe);
    board.motors_mut().set_commands(&commands);
    for _ in 0..1500 {
        board.tick();
    }
    board.physics_mut().release();
    let p0 = board.physics().state().position_ned_m;
    for _ in 0..2000 {
        board.tick();
    }
    let s = board.physics().state();
    let drift_m = (s.position_ned_m - p0).norm();
    assert!(drift_m < 2e-3, "hover drifted {drift_m} m");
    assert!(s.rate_body_rad_s.norm() < 1e-3, "hover rotates {}", s.rate_body_rad_s);
    // Tilted rotors each push sideways; only the right mix cancels: check it is not trivial.
    let lateral: f64 = (0..6).map(|i| airframe.thrust_axis(i).xy().norm()).sum();
    assert!(lateral > 2.9, "rotors are not tilted");
}

/// The seed paper's eq. 3 regressor X(Ω, Ω̇), written out, so the check does not reuse the
/// simulator's cross products.
fn paper_regressor(w: Vector3<f64>, wd: Vector3<f64>) -> Matrix3<f64> {
    let (x, y, z) = (w.x, w.y, w.z);
    Matrix3::new(
        -y * y - z * z,
        x * y - wd.z,
        x * z + wd.y,
        x * y + wd.z,
        -x * x - z * z,
        y * z - wd.x,
        x * z - wd.y,
        y * z + wd.x,
        -x * x - y * y,
    )
}

#[test]
fn accelerometer_at_an_offset_reads_the_rotational_terms() {
    let mut airframe = drag_free("paper-quad");
    // One IMU sample per control tick, so the 2 kHz sample is an instant, not an average.
    airframe.imu.sample_rate_hz = 2000.0;
    let inertia = airframe.inertia_matrix();
    let inertia_inv = inertia.try_inverse().unwrap();
    let r = airframe.r_imu_m();
    let rot_imu_body = airframe.q_imu_body().to_rotation_matrix();
    let mut board = SimBoard::new(&airframe, &SimConfig { ideal_imu: true, ..Default::default() });
    board.physics_mut().release();
    let mut s = *board.physics().state();
    s.rate_body_rad_s = Vector3::new(7.0, -4.0, 3.0);
    board.physics_mut().set_state(s);
    let mut worst = 0.0f64;
    let mut smallest_signal = f64::MAX;
    for _ in 0..600 {
        board.tick();
        let sample = board.ports().0.read().expect("one sample per tick");
        let gyro = Vector3::from(sample.gyro_rad_s.map(f64::from));
        let acc = Vector3::from(sample.accel_mps2.map(f64::from));
        // Everything from the gyro and the airframe file: Ω in body axes, Ω̇ from Euler's
        // equation (torque-free), then eq. 3 rotated into IMU axes.
        let w = rot_imu_body.inverse() * gyro;
        let wd = inertia_inv * (-w.cross(&(inertia * w)));
        let expected = rot_imu_body * (paper_regressor(w, wd) * r);
        worst = worst.max((acc - expected).norm() / expected.norm());
        smallest_signal = smallest_signal.min(expected.norm());
    }
    println!("accelerometer vs eq. 3: worst relative error {worst:.2e}");
    assert!(smallest_signal > 0.3, "signal too small to test: {smallest_signal} m/s²");
    // f32 samples: ~1e-7 relative; the gyro's f32 rounding enters Ω² terms.
    assert!(worst < 1e-5, "relative error {worst:.3e}");
}

#[test]
fn motor_step_response_has_the_configured_time_constant() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let tau_s = airframe.motor.tau_s;
    let mut board = held_board(&airframe);
    board.motors_mut().set_commands(&[0.2; 4]);
    for _ in 0..2000 {
        board.tick(); // settle at δ = 0.2
    }
    let w0 = board.physics().state().rotor_speed_rad_s[0];
    let w_final = airframe.motor.steady_speed_rad_s(f64::from(0.8f32));
    assert!((w0 - airframe.motor.steady_speed_rad_s(f64::from(0.2f32))).abs() < 1e-6);
    board.motors_mut().set_commands(&[0.8; 4]);
    let t0 = board.time_s();
    // Least-squares slope of ln((ω_s − ω)/(ω_s − ω₀)) = −t/τ over three time constants.
    let (mut stt, mut sty) = (0.0, 0.0);
    while board.time_s() - t0 < 3.0 * tau_s {
        board.tick();
        let t = board.time_s() - t0;
        let w = board.physics().state().rotor_speed_rad_s[0];
        let y = ((w_final - w) / (w_final - w0)).ln();
        stt += t * t;
        sty += t * y;
    }
    let tau_fit = -stt / sty;
    println!("τ fitted {tau_fit:.9} s, configured {tau_s} s");
    assert!(((tau_fit - tau_s) / tau_s).abs() < 1e-4, "τ {tau_fit} vs {tau_s}");
}

#[test]
fn spinning_up_a_rotor_turns_the_body_the_other_way() {
    // Rotor inertia alone (thrust and drag torque negligible): total angular momentum — body
    // plus rotors — stays zero, so the body ends at Ω = −I⁻¹ h_rotors (the G2 reaction torque
    // and the gyroscopic term −Ω × h together).
    let mut airframe = drag_free("paper-quad");
    airframe.motor.thrust_coefficient_n_per_rad2_s2 = 1e-15;
    airframe.motor.torque_coefficient_nm_per_rad2_s2 = 0.0;
    let mut board = held_board(&airframe);
    board.physics_mut().release();
    board.motors_mut().set_commands(&[0.9, 0.0, 0.0, 0.3]);
    for _ in 0..400 {
        board.tick(); // 0.2 s: motors 0 and 3 (both CW) accelerate at different rates
    }
    let model = board.physics().model();
    let s = board.physics().state();
    let h_rotors: Vector3<f64> = model
        .rotors
        .iter()
        .enumerate()
        .map(|(i, r)| r.axis * (r.motor.rotor_inertia_kg_m2 * r.spin_sign * s.rotor_speed_rad_s[i]))
        .sum();
    let expected = -(airframe.inertia_matrix().try_inverse().unwrap() * h_rotors);
    let w = s.rate_body_rad_s;
    assert!(expected.norm() > 0.5, "reaction too small to test: {expected}");
    assert!((w - expected).norm() / expected.norm() < 1e-6, "Ω {w} vs {expected}");
    let l_world = model.angular_momentum_world(s).norm();
    let rel = (w - expected).norm() / expected.norm();
    println!(
        "|Ω − Ω_expected|/|Ω_expected| = {rel:.2e}, |L|/|h| = {:.2e}",
        l_world / h_rotors.norm()
    );
    assert!(l_world / h_rotors.norm() < 1e-6, "total angular momentum {l_world}");
}
