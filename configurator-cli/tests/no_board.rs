//! The configurator's executable with no board behind it: a port that does not exist is a
//! clear error naming the port and why, with the link-failure exit code (1), never a panic.
//! (Being an integration test of this package, it also makes `cargo test` build the executable
//! the end-to-end tests in `tests/` drive, with the workspace's test features.)

use std::process::Command;

#[test]
fn a_port_that_does_not_exist_is_named_with_the_reason_and_exit_code_1() {
    let port = "/nonexistent/fc-port";
    let output = Command::new(env!("CARGO_BIN_EXE_configurator-cli"))
        .args(["--port", port, "info"])
        .output()
        .expect("start configurator-cli");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "stderr: {stderr}");
    assert!(stderr.contains(port), "the port is named: {stderr}");
    assert!(stderr.contains("No such file or directory"), "the reason is given: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}
