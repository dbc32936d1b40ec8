//! `cargo xtask test` (everything CI checks, installing what it needs first) and
//! `cargo xtask sitl` (the README's main job: the configurator against the built-in simulator).

use crate::{build, thirdparty, util};
use anyhow::{bail, Result};
use std::process::Command;
use std::time::Instant;

/// The crates that must build without `std` for the board (checked for it, with their own
/// default features, by the firmware's clippy step).
const NO_STD_CRATES: [&str; 4] = ["protocol", "flight", "imu-offset", "tumble"];

/// Install what the checks need, then run them in order, failing at the first that fails.
pub fn test(args: &[String]) -> Result<()> {
    if let Some(unknown) = args.first() {
        bail!("`cargo xtask test` takes no arguments (got `{unknown}`)");
    }
    let started = Instant::now();
    step("install: rustfmt and clippy components", ensure_components)?;
    step("install: thumbv7em-none-eabihf target", build::ensure_target_installed)?;
    step("install: flip-link", build::ensure_flip_link)?;
    // The RotorPy client's virtualenv comes from PyPI (about 40 s on a fresh machine, mostly
    // the network): made while the compilers run, and waited for before its step.
    let venv = std::thread::spawn(thirdparty::ensure_venv);
    step("format: cargo fmt --check", || {
        util::run(util::cargo().args(["fmt", "--all", "--", "--check"]))
    })?;
    step("lint: clippy on the host workspace", || {
        util::run(util::cargo().args([
            "clippy",
            "--workspace",
            "--all-targets",
            "--",
            "-D",
            "warnings",
        ]))
    })?;
    // One check of the board's target for both: the firmware, and the crates that must build
    // without `std` with their own default features (a separate `cargo build` of them for the
    // board compiled their dependencies a second time, in another profile).
    step("lint: clippy on the firmware and the no_std crates for the STM32H743", || {
        let mut command = util::cargo();
        command.args(["clippy", "-p", "firmware", "--release", "--target", build::TARGET]);
        for krate in NO_STD_CRATES {
            command.args(["-p", krate]);
        }
        util::run(command.args(["--", "-D", "warnings"]))
    })?;
    step("test: all host tests", crate::test_runner::run_all)?;
    step(
        "test: the firmware flown in RotorPy, a simulator we did not write (2 airframes)",
        || {
            venv.join().map_err(|_| anyhow::anyhow!("the virtualenv's thread panicked"))??;
            thirdparty::test(true)
        },
    )?;
    // With the stack analysis: fails when init or the nested tasks need more than is free.
    step("build: release firmware ELF and its worst-case stack", || {
        build::build(&[build::STACK_ARG.into()]).map(|_| ())
    })?;
    eprintln!("\nxtask test: all checks passed in {:.0} s", started.elapsed().as_secs_f64());
    Ok(())
}

/// Run the configurator against the built-in simulator: `cargo xtask sitl [CONFIGURATOR ARGS]`
/// (default `--sitl-throws 3 info`: the simulated hand throws the craft three times, the board
/// learns its IMU offset onboard, and the configurator prints the board's info and status).
pub fn sitl(args: &[String]) -> Result<()> {
    if !args.is_empty() {
        let mut command = util::cargo();
        command.args(["run", "--quiet", "-p", "configurator-cli", "--", "--sitl"]);
        command.args(args);
        return util::run(&mut command);
    }
    walkthrough()
}

/// The walkthrough's steps: what the newcomer reads, then the configurator's arguments.
const WALKTHROUGH: [(&str, &[&str]); 9] = [
    ("the board: identity and state (nothing configured yet)", &["info"]),
    (
        "find the motors: an ESC command makes every ESC beep (only ever sent to stopped motors)",
        &["esc", "beep1"],
    ),
    (
        "calibrate the IMU offset: the simulated hand throws the craft, spinning, and catches it",
        &["calibrate", "imu-offset", "--yes"],
    ),
    ("save the configuration to the board's flash", &["save"]),
    ("restart the board: it loads the saved configuration", &["reboot"]),
    (
        "throw-and-fly: the hand throws the craft, the board pulses each motor, learns its \
         actuators and the hover thrust axis, flies on them, holds its position (the simulated \
         motion capture's poses) for 2 s, then lands and stops its motors",
        &["identify", "--yes", "--land-after-s", "2"],
    ),
    ("save the learned model", &["save"]),
    ("what differs from the defaults (paste it into `apply` to restore it)", &["diff"]),
    ("the status, with the configuration's origin", &["status"]),
];

/// The README's main job: a SITL with a flash file, motion capture and a hand that throws the
/// craft three times, every 2.5 simulated seconds (4× real time), then throws it to fly once it
/// is armed, and the configurator walking through an ESC beep → calibrate → save → restart →
/// identify (fly, hold, land) → save → diff against it.
fn walkthrough() -> Result<()> {
    util::run(util::cargo().args([
        "build",
        "--quiet",
        "-p",
        "sim",
        "--bin",
        "sitl",
        "-p",
        "configurator-cli",
        "--bin",
        "configurator-cli",
    ]))?;
    let bin = util::root().join("target").join("debug");
    let work = util::root().join("target").join("walkthrough");
    std::fs::create_dir_all(&work)?;
    let flash = work.join("sitl-flash.bin");
    let link = work.join("fc-sitl");
    // A fresh board each time: nothing stored.
    let _ = std::fs::remove_file(&flash);
    let mut sitl = Command::new(bin.join("sitl"))
        .args(["--pty-link", &link.display().to_string()])
        .args(["--flash-file", &flash.display().to_string()])
        .args(["--speed", "4", "--throw-every-s", "2.5", "--throws", "3"])
        .arg("--hand-throws-to-fly")
        // Poses from the simulated motion capture: without a position the craft drifts (its
        // tilt cannot be told from its acceleration), and a landing that drifts can tip over.
        .arg("--mocap")
        .stdout(std::process::Stdio::null())
        .spawn()?;
    let started = Instant::now();
    while !link.exists() && started.elapsed().as_secs() < 10 {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let mut result = Ok(());
    for (index, (what, args)) in WALKTHROUGH.iter().enumerate() {
        eprintln!("\n==> {}. {what}: configurator-cli {}", index + 1, args.join(" "));
        let mut command = Command::new(bin.join("configurator-cli"));
        command.args(["--port", &link.display().to_string()]).args(*args);
        result = util::run(&mut command);
        if result.is_err() {
            break;
        }
    }
    let _ = sitl.kill();
    let _ = sitl.wait();
    result?;
    eprintln!(
        "\nThe saved configuration is in {}; `cargo run -p sim --bin sitl -- --flash-file PATH` \
         serves it again, `configurator-cli shell` explores it.",
        flash.display()
    );
    Ok(())
}

fn step(name: &str, action: impl FnOnce() -> Result<()>) -> Result<()> {
    eprintln!("\n==> {name}");
    let started = Instant::now();
    action().map_err(|error| error.context(format!("step `{name}` failed")))?;
    eprintln!("    ({name}: {:.1} s)", started.elapsed().as_secs_f64());
    Ok(())
}

fn ensure_components() -> Result<()> {
    let output = Command::new("rustup").args(["component", "list", "--installed"]).output()?;
    let installed = String::from_utf8_lossy(&output.stdout);
    let missing: Vec<&str> = ["rustfmt", "clippy"]
        .into_iter()
        .filter(|component| !installed.lines().any(|line| line.starts_with(component)))
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    util::run(Command::new("rustup").arg("component").arg("add").args(&missing))
}
