//! End to end: `configurator-cli --sitl doctor`, the bring-up check, against a healthy simulated
//! board (every line passes, exit 0) and against boards with one injected fault each (the
//! SITL's `--fault-*` flags): the line that checks the broken part fails with its advice, the
//! lines of the healthy parts still pass, and the exit code is 1.

use serde_json::Value;
use std::path::PathBuf;
use tests::run_cli;

/// A flash file of this test's own (not the user's), fresh.
fn flash_file(name: &str) -> PathBuf {
    let path = flash_file_path(name);
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let _ = std::fs::remove_file(&path);
    path
}

fn flash_file_path(name: &str) -> PathBuf {
    std::env::temp_dir()
        .join(format!("doctor-test-{}", std::process::id()))
        .join(format!("{name}.bin"))
}

/// Run `configurator-cli --sitl [options] --json doctor [--yes]`: exit code, the lines, stderr.
fn doctor(name: &str, options: &[&str], yes: bool) -> (Option<i32>, Vec<Value>, String) {
    let flash = flash_file(name);
    let mut args = vec!["--sitl", "--sitl-flash-file", flash.to_str().unwrap(), "--json"];
    args.extend_from_slice(options);
    args.push("doctor");
    if yes {
        args.push("--yes");
    }
    let output = run_cli(&args);
    let stderr = String::from_utf8_lossy(&output.stderr).to_string();
    let lines: Vec<Value> = serde_json::from_slice(&output.stdout)
        .unwrap_or_else(|e| panic!("stdout is not a JSON array ({e}); stderr: {stderr}"));
    (output.status.code(), lines, stderr)
}

fn line<'a>(lines: &'a [Value], name: &str) -> &'a Value {
    lines.iter().find(|l| l["name"] == name).unwrap_or_else(|| panic!("no `{name}` line"))
}

fn names(lines: &[Value]) -> Vec<&str> {
    lines.iter().map(|l| l["name"].as_str().unwrap()).collect()
}

fn failing(lines: &[Value]) -> Vec<&str> {
    lines.iter().filter(|l| l["ok"] == false).map(|l| l["name"].as_str().unwrap()).collect()
}

fn number_after(text: &str, label: &str) -> f64 {
    let rest =
        &text[text.find(label).unwrap_or_else(|| panic!("`{label}` in {text}")) + label.len()..];
    let number: String =
        rest.trim_start().chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
    number.parse().unwrap_or_else(|_| panic!("a number after `{label}` in {text}"))
}

#[test]
fn a_healthy_sitl_passes_every_line_with_the_motors_spun_on_their_own_outputs() {
    let (code, lines, stderr) = doctor("healthy", &[], true);
    assert_eq!(code, Some(0), "{stderr}\n{lines:#?}");
    assert_eq!(
        names(&lines),
        ["link", "imu", "flash", "receiver", "gnss", "compass", "battery", "esc", "spin"]
    );
    assert!(failing(&lines).is_empty(), "{lines:#?}");
    assert!(stderr.contains("all checks passed"), "{stderr}");
    for l in &lines {
        assert!(l["checked"].as_str().is_some_and(|c| !c.is_empty()), "{l}");
        assert!(l["advice"].is_null(), "a passing line has no advice: {l}");
    }
    // What the IMU line measured, against the simulated ICM-42688-P (its datasheet's noise
    // densities, 1.4× at the simulator's noise convention) held still by the hand.
    let imu = line(&lines, "imu")["found"].as_str().unwrap();
    let gyro_noise_dps = number_after(imu, "gyro noise");
    assert!((0.05..0.3).contains(&gyro_noise_dps), "{imu}");
    let accel_noise_mg = number_after(imu, "accelerometer noise");
    assert!((1.0..8.0).contains(&accel_noise_mg), "{imu}");
    let gravity_mps2 = number_after(imu, "|f|");
    assert!((gravity_mps2 - 9.81).abs() < 0.15, "{imu}");
    // The SITL has no receiver: information, not a failure.
    let receiver = line(&lines, "receiver");
    assert_eq!(receiver["verdict"], "info");
    assert!(receiver["found"].as_str().unwrap().contains("no receiver"));
    // Each motor at 8 %: the paper quad's curve gives about 845 rad/s; the others idle (300 rad/s)
    // in the simulator, stopped on a board.
    let spin = line(&lines, "spin")["found"].as_str().unwrap();
    for motor in 0..4 {
        let speed = number_after(spin, &format!("motor {motor}:"));
        assert!((700.0..1000.0).contains(&speed), "motor {motor}: {spin}");
    }
}

/// A SITL with a compass on its GNSS mast (`--sitl-compass`: the simulated chip behind the
/// firmware's own driver, calibrated by a simulated user): the compass line finds the sensor,
/// reads it at its 100 Hz service rate, sees the Earth's field, and says it is calibrated.
#[test]
fn a_sitl_with_a_compass_reports_it_found_read_and_calibrated() {
    let (code, lines, stderr) = doctor("compass", &["--sitl-compass"], false);
    assert_eq!(code, Some(0), "{stderr}\n{lines:#?}");
    let compass = line(&lines, "compass")["found"].as_str().unwrap();
    assert!(compass.contains("IST8310") || compass.contains("QMC5883L"), "{compass}");
    assert!(compass.ends_with("calibrated"), "{compass}");
    let rate_hz = number_after(compass, ",");
    assert!((50.0..=110.0).contains(&rate_hz), "{compass}");
    let field_ut = number_after(compass, "field");
    // The raw field: the Earth's 25–65 µT plus up to 300 µT of hard iron per axis.
    assert!((10.0..600.0).contains(&field_ut), "{compass}");
}

/// The octocopter: eight motors, slower ones (292 rad/s at 8 % against 100 rad/s of idle in the
/// simulator) than the quad's.
#[test]
fn an_octocopter_passes_with_all_eight_motors_spun() {
    let (code, lines, stderr) = doctor("octo", &["--airframe", "octo-flat"], true);
    assert_eq!(code, Some(0), "{stderr}\n{lines:#?}");
    assert!(line(&lines, "link")["found"].as_str().unwrap().contains("8 motors"));
    let spin = line(&lines, "spin")["found"].as_str().unwrap();
    for motor in 0..8 {
        let speed = number_after(spin, &format!("motor {motor}:"));
        assert!((200.0..400.0).contains(&speed), "motor {motor}: {spin}");
    }
}

#[test]
fn without_a_terminal_or_yes_the_spin_is_skipped_and_the_rest_passes() {
    let (code, lines, stderr) = doctor("no-terminal", &[], false);
    assert_eq!(code, Some(0), "{stderr}\n{lines:#?}");
    let spin = line(&lines, "spin");
    assert_eq!(spin["verdict"], "skipped");
    assert!(spin["found"].as_str().unwrap().contains("no terminal"), "{spin}");
    assert!(spin["advice"].as_str().unwrap().contains("--yes"), "{spin}");
    assert!(stderr.contains("propellers OFF? [y/N] (no terminal to ask: use --yes)"), "{stderr}");
}

#[test]
fn a_silent_esc_fails_the_esc_line_naming_the_motor() {
    let (code, lines, stderr) = doctor("esc", &["--fault-esc-silent", "2"], true);
    assert_eq!(code, Some(1), "{stderr}");
    // The spin test cannot see that motor either; nothing else fails.
    assert_eq!(failing(&lines), ["esc", "spin"], "{lines:#?}");
    let esc = line(&lines, "esc");
    assert!(esc["found"].as_str().unwrap().contains("motor 2 of 0–3 reports NO speed"), "{esc}");
    assert!(esc["advice"].as_str().unwrap().contains("check motor 2's ESC"), "{esc}");
    assert!(stderr.contains("2 of 9 checks failed: esc, spin"), "{stderr}");
}

#[test]
fn a_silent_frozen_or_noisy_imu_fails_the_imu_line_with_its_advice() {
    for (how, found, advice) in [
        ("silent", "SILENT", "the IMU is silent"),
        ("frozen", "FROZEN", "repeats one sample"),
        ("noisy", "gyro noise", "NOISY"),
    ] {
        let (code, lines, stderr) = doctor(how, &["--fault-imu", how], false);
        assert_eq!(code, Some(1), "{how}: {stderr}");
        assert_eq!(failing(&lines), ["imu"], "{how}: {lines:#?}");
        let imu = line(&lines, "imu");
        assert!(imu["found"].as_str().unwrap().contains(found), "{how}: {imu}");
        assert!(imu["advice"].as_str().unwrap().contains(advice), "{how}: {imu}");
        if how == "noisy" {
            // 30× the simulated sensor's noise: far above the limit of 5× the datasheet's.
            let text = imu["found"].as_str().unwrap();
            assert!(number_after(text, "gyro noise") > 5.0 * number_after(text, "limit"), "{text}");
        }
    }
}

#[test]
fn a_bad_flash_fails_the_flash_line_and_leaves_the_file_alone() {
    let (code, lines, stderr) = doctor("flash", &["--fault-flash", "bad"], false);
    assert_eq!(code, Some(1), "{stderr}");
    assert_eq!(failing(&lines), ["flash"], "{lines:#?}");
    let flash = line(&lines, "flash");
    assert!(flash["found"].as_str().unwrap().contains("UNREADABLE"), "{flash}");
    assert!(flash["advice"].as_str().unwrap().contains("flash is damaged"), "{flash}");
    let bytes = std::fs::read(flash_file_path("flash")).unwrap();
    assert!(bytes.iter().all(|&b| b == 0xFF), "the check wrote nothing");
}

#[test]
fn swapped_motor_outputs_fail_the_spin_naming_both() {
    let (code, lines, stderr) = doctor("swap", &["--fault-motor-swap", "1,3"], true);
    assert_eq!(code, Some(1), "{stderr}");
    assert_eq!(failing(&lines), ["spin"], "{lines:#?}");
    let advice = line(&lines, "spin")["advice"].as_str().unwrap().to_string();
    assert!(advice.contains("output 1 turned motor 3"), "{advice}");
    assert!(advice.contains("output 3 turned motor 1"), "{advice}");
    assert!(!advice.contains("output 0") && !advice.contains("output 2"), "{advice}");
}

#[test]
fn fault_flags_need_the_sitl_and_a_motor_it_has() {
    let output = run_cli(&["--fault-imu", "noisy", "doctor"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("add --sitl"));
    let flash = flash_file("bad-motor");
    let output = run_cli(&[
        "--sitl",
        "--sitl-flash-file",
        flash.to_str().unwrap(),
        "--fault-esc-silent",
        "4",
        "doctor",
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("--fault-esc-silent 4: the airframe has motors 0 to 3"), "{stderr}");
    assert!(output.stdout.is_empty());
}
