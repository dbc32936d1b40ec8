//! Shared helpers for the end-to-end tests: the configurator binary, built on demand.

use std::path::PathBuf;
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The `configurator-cli` executable of this workspace and profile, built once per test run.
pub fn cli_binary() -> PathBuf {
    static BINARY: OnceLock<PathBuf> = OnceLock::new();
    BINARY
        .get_or_init(|| {
            // target/<profile>/deps/<test> → target/<profile>
            let exe = std::env::current_exe().expect("test executable path");
            let profile_dir = exe.parent().and_then(|deps| deps.parent()).expect("target dir");
            let release = profile_dir.file_name().is_some_and(|name| name == "release");
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
            let mut build = Command::new(cargo);
            build.args(["build", "--quiet", "-p", "configurator-cli", "--bin", "configurator-cli"]);
            if release {
                build.arg("--release");
            }
            let status = build.status().expect("run cargo build for the configurator");
            assert!(status.success(), "building configurator-cli failed");
            let binary = profile_dir.join("configurator-cli");
            assert!(binary.is_file(), "no configurator-cli at {}", binary.display());
            binary
        })
        .clone()
}

/// Run the configurator with `args`; returns its output (never panics on a failing command).
pub fn run_cli(args: &[&str]) -> Output {
    Command::new(cli_binary()).args(args).output().expect("start configurator-cli")
}
