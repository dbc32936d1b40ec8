//! The host tests, their binaries run two at a time.
//!
//! Why: `cargo test` runs one test binary after the other, and about half of the workspace's
//! test time is spent in binaries that wait on the clock rather than the CPU (a 57,600 baud
//! radio's byte budget, a calibration's 20 s of gathering, a SITL paced in real time). Measured
//! on 2 cores (warm): the 57 test binaries in a row took 282 s, the eight slowest (radio,
//! `doctor`, the compass calibration, the CLI against the SITL, landing, replay, configurator
//! flows, the SD card) 158 s of it; two at a time they take 166 s. Here `cargo test --no-run`
//! builds every test binary once, and they then run
//! [`CONCURRENT_BINARIES`] at a time, each as `cargo test` would run it: from its package's
//! directory, with `CARGO_MANIFEST_DIR` and `CARGO_PKG_NAME` set, its tests on their own threads,
//! and told that the executables the end-to-end tests drive are built ([`PREBUILT_ENV`]).
//! Each binary's output is printed whole when it ends (never interleaved), with its time; every
//! binary runs even after one fails, and the step fails naming each that did. The doc-tests run
//! after, with `cargo test --doc`.

use crate::util;
use anyhow::{bail, Context, Result};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Test binaries running at once: two, on the 2-core machine the README's test command is sized
/// for (each runs its own tests on as many threads as there are cores, so the CPU-bound
/// simulations are not slowed much, while a binary that waits on the clock leaves its core to
/// the other).
pub const CONCURRENT_BINARIES: usize = 2;

/// Told to every test binary: `cargo test --no-run` has built the workspace's executables the
/// end-to-end tests drive (`sitl`, and `configurator-cli` through its own integration test),
/// so their helpers take them as built (`tests/src/lib.rs`, the same name).
const PREBUILT_ENV: &str = "FC_TEST_EXECUTABLES_BUILT";

/// One test binary `cargo test --no-run` built.
#[derive(Debug, Clone, PartialEq)]
struct TestBinary {
    executable: PathBuf,
    /// The package's directory (where `cargo test` runs it) and name.
    package_dir: PathBuf,
    package: String,
    /// The target's name and kind ("lib", "test", "bin"), for the report.
    target: String,
}

/// Build every test binary of the workspace, run them [`CONCURRENT_BINARIES`] at a time, then
/// the doc-tests.
pub fn run_all() -> Result<()> {
    let binaries = build()?;
    eprintln!("{} test binaries, {CONCURRENT_BINARIES} at a time", binaries.len());
    let queue = Arc::new(Mutex::new(binaries.into_iter().collect::<VecDeque<_>>()));
    let failed = Arc::new(Mutex::new(Vec::new()));
    let workers: Vec<_> = (0..CONCURRENT_BINARIES)
        .map(|_| {
            let (queue, failed) = (Arc::clone(&queue), Arc::clone(&failed));
            std::thread::spawn(move || loop {
                let Some(binary) = queue.lock().expect("queue").pop_front() else { break };
                if !run_one(&binary) {
                    failed.lock().expect("failures").push(binary.target.clone());
                }
            })
        })
        .collect();
    for worker in workers {
        worker.join().map_err(|_| anyhow::anyhow!("a test worker panicked"))?;
    }
    let failed = failed.lock().expect("failures").clone();
    if !failed.is_empty() {
        bail!("{} test binaries failed: {}", failed.len(), failed.join(", "));
    }
    util::run(util::cargo().args(["test", "--workspace", "--doc"]))
}

/// `cargo test --workspace --no-run`, reading the executables from its JSON messages.
fn build() -> Result<Vec<TestBinary>> {
    let mut command = util::cargo();
    command.args(["test", "--workspace", "--no-run", "--message-format=json-render-diagnostics"]);
    eprintln!("$ cargo test --workspace --no-run --message-format=json-render-diagnostics");
    let output = command
        .stderr(Stdio::inherit())
        .output()
        .context("could not start `cargo test --no-run`")?;
    if !output.status.success() {
        bail!("`cargo test --workspace --no-run` failed ({})", output.status);
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    let binaries: Vec<TestBinary> = stdout.lines().filter_map(parse_artifact).collect();
    if binaries.is_empty() {
        bail!("`cargo test --no-run` reported no test binary");
    }
    Ok(binaries)
}

/// A test binary from one line of cargo's JSON messages (`compiler-artifact` with a test
/// profile and an executable), or `None`.
fn parse_artifact(line: &str) -> Option<TestBinary> {
    let message: serde_json::Value = serde_json::from_str(line).ok()?;
    if message["reason"] != "compiler-artifact" || message["profile"]["test"] != true {
        return None;
    }
    let executable = PathBuf::from(message["executable"].as_str()?);
    let manifest = PathBuf::from(message["manifest_path"].as_str()?);
    let package_dir = manifest.parent()?.to_path_buf();
    let package = message["package_id"].as_str().map(package_name).unwrap_or_default();
    let kind = message["target"]["kind"][0].as_str().unwrap_or("test");
    let name = message["target"]["name"].as_str().unwrap_or("?");
    Some(TestBinary { executable, package_dir, package, target: format!("{name} ({kind})") })
}

/// The package's name from a cargo package id: `path+file:///…/sim#0.1.0` (the name is the
/// last path segment unless `#name@version` names it) or the older `sim 0.1.0 (path+…)`.
fn package_name(id: &str) -> String {
    if let Some((_, fragment)) = id.rsplit_once('#') {
        if let Some((name, _)) = fragment.split_once('@') {
            return name.to_string();
        }
        let path = id.split('#').next().unwrap_or("");
        return path.rsplit('/').next().unwrap_or("").to_string();
    }
    id.split(' ').next().unwrap_or("").to_string()
}

/// Run one binary as `cargo test` would; print its output whole; whether it passed.
fn run_one(binary: &TestBinary) -> bool {
    let started = Instant::now();
    let output = Command::new(&binary.executable)
        .current_dir(&binary.package_dir)
        // The executables were built with the test binaries (`tests::PREBUILT_ENV`).
        .env(PREBUILT_ENV, "1")
        .env("CARGO_MANIFEST_DIR", &binary.package_dir)
        .env("CARGO_PKG_NAME", &binary.package)
        .output();
    let seconds = started.elapsed().as_secs_f64();
    match output {
        Ok(output) => {
            let passed = output.status.success();
            eprintln!(
                "\n--- {} [{}]: {} in {seconds:.1} s ({})",
                binary.target,
                binary.package,
                if passed { "passed" } else { "FAILED" },
                binary.executable.display()
            );
            eprint!("{}", String::from_utf8_lossy(&output.stdout));
            eprint!("{}", String::from_utf8_lossy(&output.stderr));
            passed
        }
        Err(error) => {
            eprintln!(
                "\n--- {}: could not start {}: {error}",
                binary.target,
                binary.executable.display()
            );
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_test_artifact_is_read_and_everything_else_is_not() {
        let test = r#"{"reason":"compiler-artifact","package_id":"path+file:///w/main/sim#0.1.0","manifest_path":"/w/main/sim/Cargo.toml","target":{"kind":["test"],"name":"bridge"},"profile":{"test":true},"executable":"/w/main/target/debug/deps/bridge-1"}"#;
        let binary = parse_artifact(test).expect("a test binary");
        assert_eq!(binary.executable, PathBuf::from("/w/main/target/debug/deps/bridge-1"));
        assert_eq!(binary.package_dir, PathBuf::from("/w/main/sim"));
        assert_eq!(binary.package, "sim");
        assert_eq!(binary.target, "bridge (test)");
        // A library built for the tests (no test profile), a build script, a diagnostic, junk.
        let lib = test.replace(r#""test":true"#, r#""test":false"#);
        assert_eq!(parse_artifact(&lib), None);
        let no_executable = test.replace(
            r#""executable":"/w/main/target/debug/deps/bridge-1""#,
            r#""executable":null"#,
        );
        assert_eq!(parse_artifact(&no_executable), None);
        assert_eq!(parse_artifact(r#"{"reason":"build-finished","success":true}"#), None);
        assert_eq!(parse_artifact("not json"), None);
    }

    #[test]
    fn package_names_are_read_from_both_id_forms() {
        assert_eq!(package_name("path+file:///w/main/sim#0.1.0"), "sim");
        assert_eq!(
            package_name("path+file:///w/main/cli#configurator-cli@0.1.0"),
            "configurator-cli"
        );
        assert_eq!(package_name("sim 0.1.0 (path+file:///w/main/sim)"), "sim");
    }
}
