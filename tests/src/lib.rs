//! Shared helpers for the end-to-end tests: the configurator and SITL binaries, built on
//! demand, and [`baud_relay`], a radio adapter that enforces its serial rate.

use std::path::PathBuf;
use std::process::{Command, Output};
use std::sync::OnceLock;

#[cfg(target_os = "linux")]
pub mod baud_relay;

/// The `configurator-cli` executable of this workspace and profile, built once per test run.
pub fn cli_binary() -> PathBuf {
    static BINARY: OnceLock<PathBuf> = OnceLock::new();
    BINARY.get_or_init(|| build_binary("configurator-cli", "configurator-cli")).clone()
}

/// The `sitl` executable (the standalone simulator) of this workspace and profile, built once
/// per test run.
pub fn sitl_binary() -> PathBuf {
    static BINARY: OnceLock<PathBuf> = OnceLock::new();
    BINARY.get_or_init(|| build_binary("sim", "sitl")).clone()
}

/// Set by `cargo xtask test` once `cargo test --workspace --no-run` has built every test binary
/// and, with them, the workspace's executables that have integration tests of their own (`sitl`,
/// `configurator-cli`), with the test build's features: the helpers then take those instead of
/// building them again with a feature resolution of their own, which compiled every
/// dependency a second time (docs/benchmarks.md, "The test command").
pub const PREBUILT_ENV: &str = "FC_TEST_EXECUTABLES_BUILT";

/// Build the binary `bin` of `package` in this test's profile (or take it as built, see
/// [`PREBUILT_ENV`]); returns its path.
fn build_binary(package: &str, bin: &str) -> PathBuf {
    // target/<profile>/deps/<test> → target/<profile>
    let exe = std::env::current_exe().expect("test executable path");
    let profile_dir = exe.parent().and_then(|deps| deps.parent()).expect("target dir");
    let prebuilt = profile_dir.join(bin);
    if std::env::var_os(PREBUILT_ENV).is_some() && prebuilt.is_file() {
        return prebuilt;
    }
    let release = profile_dir.file_name().is_some_and(|name| name == "release");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut build = Command::new(cargo);
    build.args(["build", "--quiet", "-p", package, "--bin", bin]);
    if release {
        build.arg("--release");
    }
    let status = build.status().unwrap_or_else(|e| panic!("run cargo build for {bin}: {e}"));
    assert!(status.success(), "building {bin} failed");
    let binary = profile_dir.join(bin);
    assert!(binary.is_file(), "no {bin} at {}", binary.display());
    binary
}

/// Run the configurator with `args`; returns its output (never panics on a failing command).
pub fn run_cli(args: &[&str]) -> Output {
    Command::new(cli_binary()).args(args).output().expect("start configurator-cli")
}

/// The seed paper's quad, 1.5 m up, armed for throw-to-fly on `app` and thrown (3.5 m/s up,
/// 400 / 400 / 100 °/s) 0.5 s in, then stepped for `ticks` steps of 2 kHz. In the first step
/// whose snapshot before it `disarm_when` accepts, a disarm is submitted; from that step on
/// every snapshot must show every command at zero, the attempt ended as `Disarmed`, nothing
/// armed or flying, and the board's motors told zero. Returns whether it disarmed.
pub fn disarm_during_throw_to_fly(
    board: &mut sim::board::SimBoard,
    app: &mut sim::scenario::FirmwareApp<'_>,
    ticks: u64,
    disarm_when: impl Fn(&firmware::app::ControlSnapshot) -> bool,
) -> bool {
    use firmware::app::hal::Imu;
    use firmware::app::ControlCommand;
    use sim::scenario::FlightApp;
    app.submit(ControlCommand::ArmThrowToFly);
    let spec = sim::hand::ThrowSpec::vertical(
        3.5,
        nalgebra::Vector3::new(400.0, 400.0, 100.0).map(f64::to_radians),
        0.15,
    );
    let mut disarmed_at = None;
    for tick in 0..ticks {
        if tick == 1000 {
            board.physics_mut().throw(&spec);
        }
        board.tick();
        let now_us = board.now_us();
        if disarmed_at.is_none() && disarm_when(&app.snapshot()) {
            app.submit(ControlCommand::Disarm);
            disarmed_at = Some(tick);
        }
        let (imu, motors) = board.ports();
        app.step(now_us, imu, motors);
        if disarmed_at.is_some() {
            let snapshot = app.snapshot();
            assert!(snapshot.commands.iter().all(|c| *c == 0.0), "tick {tick}: {snapshot:?}");
            assert_eq!(snapshot.failure, protocol::LearnerFailure::Disarmed);
            assert!(!snapshot.armed && !snapshot.pilot.flying, "tick {tick}: {snapshot:?}");
            let _ = imu.read();
            assert!(motors.commands().iter().all(|c| *c == 0.0));
        }
    }
    disarmed_at.is_some()
}

/// The distance of the board's position estimate from its position setpoint, m, from the
/// `flight` object of `configurator-cli --json status` (both NED, m). Panics with the object
/// when either is missing: the craft was not holding a position.
pub fn estimate_from_setpoint_m(flight: &serde_json::Value) -> f64 {
    let vector = |name: &str| -> Vec<f64> {
        flight[name]
            .as_array()
            .unwrap_or_else(|| panic!("no {name} in {flight}"))
            .iter()
            .map(|x| x.as_f64().unwrap_or(f64::NAN))
            .collect()
    };
    let (position, setpoint) = (vector("position_ned_m"), vector("position_sp_ned_m"));
    position.iter().zip(&setpoint).map(|(p, s)| (p - s).powi(2)).sum::<f64>().sqrt()
}
