//! `cargo xtask test` (everything CI checks, installing what it needs first) and
//! `cargo xtask sitl` (the README's main job: the configurator against the built-in simulator).

use crate::{build, util};
use anyhow::{bail, Result};
use std::process::Command;
use std::time::Instant;

/// The crates that must build without `std` for the board.
const NO_STD_CRATES: [&str; 2] = ["protocol", "flight"];

/// Install what the checks need, then run them in order, failing at the first that fails.
pub fn test(args: &[String]) -> Result<()> {
    if let Some(unknown) = args.first() {
        bail!("`cargo xtask test` takes no arguments (got `{unknown}`)");
    }
    let started = Instant::now();
    step("install: rustfmt and clippy components", ensure_components)?;
    step("install: thumbv7em-none-eabihf target", build::ensure_target_installed)?;
    step("install: flip-link", build::ensure_flip_link)?;
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
    step("lint: clippy on the firmware for the STM32H743", || {
        util::run(util::cargo().args([
            "clippy",
            "-p",
            "firmware",
            "--release",
            "--target",
            build::TARGET,
            "--",
            "-D",
            "warnings",
        ]))
    })?;
    step("test: all host tests", || util::run(util::cargo().args(["test", "--workspace"])))?;
    step("build: no_std crates for thumbv7em-none-eabihf", || {
        let mut command = util::cargo();
        command.args(["build", "--target", build::TARGET]);
        for krate in NO_STD_CRATES {
            command.args(["-p", krate]);
        }
        util::run(&mut command)
    })?;
    step("build: release firmware ELF", || build::build(&[]).map(|_| ()))?;
    eprintln!("\nxtask test: all checks passed in {:.0} s", started.elapsed().as_secs_f64());
    Ok(())
}

/// Run the configurator against the built-in simulator: `cargo xtask sitl [CONFIGURATOR ARGS]`
/// (default `--sitl-throws 3 info`: the simulated hand throws the craft three times, the board
/// learns its IMU offset onboard, and the configurator prints the board's info and status).
pub fn sitl(args: &[String]) -> Result<()> {
    let mut command = util::cargo();
    command.args(["run", "--quiet", "-p", "configurator-cli", "--", "--sitl"]);
    if args.is_empty() {
        command.args(["--sitl-throws", "3", "info"]);
    } else {
        command.args(args);
    }
    util::run(&mut command)
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
