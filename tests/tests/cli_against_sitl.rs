//! End to end: the configurator binary against the SITL over the real transports (the
//! pseudo-terminal it opens exactly like a USB serial port, and TCP), and against a fake board
//! that speaks another major protocol version.

use protocol::{
    Capabilities, DeviceMessage, FirmwareVersion, Info, Reply, Request, Version, MAX_FRAME_LEN,
    PROTOCOL_VERSION,
};
use serde_json::Value;
use sim::sitl::{Sitl, SitlConfig};
use std::io::{Read, Write};
use std::net::TcpListener;
use std::time::Duration;
use tests::run_cli;

fn start_sitl(tcp: bool) -> Sitl {
    let config = SitlConfig { tcp_port: tcp.then_some(0), ..SitlConfig::default() };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    // One full one-second statistics window, so the status carries noise figures.
    std::thread::sleep(Duration::from_millis(1200));
    sitl
}

fn json_of(output: &std::process::Output) -> Value {
    assert!(
        output.status.success(),
        "configurator failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).expect("stdout is one JSON object")
}

fn norm(v: &Value) -> f64 {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap().powi(2)).sum::<f64>().sqrt()
}

#[test]
fn info_over_the_pseudo_terminal_reports_the_handshake_and_a_board_at_rest() {
    let sitl = start_sitl(false);
    let port = sitl.pty_path.clone().unwrap();
    let output = run_cli(&["--port", port.to_str().unwrap(), "--json", "info"]);
    let report = json_of(&output);

    let info = &report["info"];
    assert_eq!(info["board"], "SITL");
    assert_eq!(
        info["protocol_version"],
        format!("{}.{}", PROTOCOL_VERSION.major, PROTOCOL_VERSION.minor)
    );
    assert_eq!(info["schema_matches"], true);
    assert_eq!(info["control_rate_hz"], 2000);
    assert_eq!(info["motor_count"], 4, "the paper's quad");
    assert!(info["capabilities"].as_array().unwrap().contains(&Value::from("simulator")));
    // The SITL identifies without speed reports where the user says there are none (1.13).
    let identifies = Value::from("identifies_without_speeds");
    assert!(info["capabilities"].as_array().unwrap().contains(&identifies));

    let status = &report["status"];
    assert_eq!(status["armed"], false);
    let control = &status["control"];
    assert!((control["rate_hz"].as_f64().unwrap() - 2000.0).abs() < 1.0, "{control}");
    assert_eq!(control["late_steps"], 0);
    assert_eq!(control["samples_dropped"], 0);
    assert!(status["uptime_s"].as_f64().unwrap() >= 1.0);
    let imu = &status["imu"];
    assert_eq!(imu["present"], true);
    // Held still by the simulated hand: the accelerometer reads 1 g of specific force, the gyro
    // reads its bias and noise only.
    let accel_mps2 = norm(&imu["accel_mps2"]);
    assert!((accel_mps2 - 9.81).abs() < 0.15, "|a| = {accel_mps2} m/s²");
    assert!(norm(&imu["gyro_rad_s"]) < 0.05);
    for sigma in imu["gyro_std_rad_s"].as_array().unwrap() {
        let sigma = sigma.as_f64().unwrap();
        assert!(sigma > 1e-4 && sigma < 0.02, "gyro noise {sigma} rad/s");
    }
    // Held still: no free fall, no throw, no estimate yet.
    let offset = &status["imu_offset"];
    assert_eq!(
        (&offset["throws"], &offset["in_free_fall"]),
        (&Value::from(0), &Value::from(false))
    );
    assert_eq!(offset["estimated"], false);
    let link = &status["link"];
    assert_eq!(link["bad_crc"], 0);
    assert_eq!(link["frames_rx"], 2, "hello and status");
}

#[test]
fn status_text_has_units_and_tcp_reaches_the_same_board() {
    let sitl = start_sitl(true);
    let address = sitl.tcp_addr.unwrap().to_string();
    let output = run_cli(&["--tcp", &address, "status"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let text = String::from_utf8(output.stdout).unwrap();
    for expected in ["Hz", "m/s²", "°/s", "µs", "uptime", "battery"] {
        assert!(text.contains(expected), "`{expected}` missing from:\n{text}");
    }
    // The simulated pack: a 4S charged at start-up (16.8 V open circuit), counted once it has
    // settled; the SITL may have drawn a little from it already.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let battery = loop {
        let status = json_of(&run_cli(&["--tcp", &address, "--json", "status"]));
        let battery = status["battery"].clone();
        if battery["cells"] == 4 || std::time::Instant::now() > deadline {
            break battery;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(battery["cells"], 4, "{battery}");
    let voltage_v = battery["voltage_v"].as_f64().unwrap();
    assert!((16.0..16.85).contains(&voltage_v), "{battery}");
    assert!(battery["remaining_pct"].as_u64().unwrap() >= 90, "{battery}");
}

#[test]
fn streaming_imu_telemetry_over_the_pseudo_terminal_has_no_gaps() {
    let sitl = start_sitl(false);
    let port = sitl.pty_path.clone().unwrap();
    let args = ["--port", port.to_str().unwrap(), "--json", "stream", "--topic", "imu"];
    let output = run_cli(&[&args[..], &["--rate-hz", "500", "--duration-s", "1"]].concat());
    let report = json_of(&output);
    let received = report["received"].as_u64().unwrap();
    // 500 Hz for 1 s of wall time; the SITL is paced to the wall clock.
    assert!((400..=560).contains(&received), "received {received}");
    assert_eq!(report["gaps"], 0);
    assert_eq!(report["bad_frames"], 0);
}

#[test]
fn a_missing_port_is_a_clear_error_with_exit_code_1() {
    let output = run_cli(&["--port", "/dev/does-not-exist", "info"]);
    assert_eq!(output.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("cannot open /dev/does-not-exist"), "{stderr}");
    assert!(output.stdout.is_empty());
}

/// A malformed `--tcp` address is bad input like any other (exit 2, clap's message naming the
/// flag, the value and the expected form), before anything is opened; a well-formed address
/// where nothing listens is a board that cannot be reached (exit 1).
#[test]
fn a_bad_tcp_address_exits_2_naming_the_expected_form() {
    for bad in ["notanaddress", "127.0.0.1", "127.0.0.1:99999", "::1:5760"] {
        let output = run_cli(&["--tcp", bad, "status"]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{bad}: {stderr}");
        assert!(
            stderr.contains(&format!("invalid value '{bad}' for '--tcp <HOST:PORT>'")),
            "{stderr}"
        );
        assert!(stderr.contains("e.g. 127.0.0.1:5760"), "{stderr}");
        assert!(output.stdout.is_empty());
    }
    // A loopback port just freed: well-formed, and nothing listens there.
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let closed = listener.local_addr().unwrap().to_string();
    drop(listener);
    let output = run_cli(&["--tcp", &closed, "status"]);
    assert_eq!(output.status.code(), Some(1), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(String::from_utf8_lossy(&output.stderr).contains(&format!("cannot open {closed}")));
}

#[test]
fn an_out_of_range_stream_rate_is_refused_before_connecting() {
    let output = run_cli(&["--port", "/dev/does-not-exist", "stream", "--rate-hz", "5000"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("outside 1 to 2000 Hz"));
}

/// `esc`: a beep to one motor and a save to every ESC are sent to the SITL's simulated ESCs (the
/// SITL announces `esc_commands`), a motor the board does not have is refused naming the range,
/// and an unknown command is refused before connecting, naming the known ones.
#[test]
fn esc_commands_reach_the_sitl_and_bad_ones_are_refused_with_their_range() {
    let sitl = start_sitl(false);
    let port = sitl.pty_path.clone().unwrap();
    let port = port.to_str().unwrap();
    let info = json_of(&run_cli(&["--port", port, "--json", "info"]));
    assert!(info["info"]["capabilities"]
        .as_array()
        .unwrap()
        .contains(&Value::from("esc_commands")));
    let beep = run_cli(&["--port", port, "esc", "beep1", "--motor", "2"]);
    assert!(beep.status.success(), "{}", String::from_utf8_lossy(&beep.stderr));
    assert_eq!(
        String::from_utf8_lossy(&beep.stdout),
        "sent beep1 (DShot command 1) to motor 2's ESC\n"
    );
    let save = run_cli(&["--port", port, "esc", "save-settings"]);
    assert!(String::from_utf8_lossy(&save.stdout).contains("to every ESC (6 frames in a row"));
    let wrong = run_cli(&["--port", port, "esc", "beep1", "--motor", "7"]);
    assert_eq!(wrong.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&wrong.stderr);
    assert!(stderr.contains("motor = 7 is outside the allowed range 0 to 3"), "{stderr}");
    let unknown = run_cli(&["--port", "/dev/does-not-exist", "esc", "beep9"]);
    assert_eq!(unknown.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&unknown.stderr).contains("spin-direction-reversed"));
}

/// A fake board's identity reply with the given protocol version and board name.
fn fake_info(protocol: Version, board: &str) -> Info {
    Info {
        protocol,
        schema_hash: 0,
        firmware: FirmwareVersion { major: 9, minor: 0, patch: 0 },
        board: heapless::String::try_from(board).unwrap(),
        serial: heapless::String::new(),
        capabilities: Capabilities(0),
        control_rate_hz: 2000,
        motor_count: 4,
    }
}

fn frame(message: &DeviceMessage, seq: u16) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME_LEN];
    let len = message.encode(seq, &mut out).unwrap();
    out[..len].to_vec()
}

/// A fake board on TCP at the returned address: on connection it first sends `stale` bytes,
/// then answers the first Hello with `Ok(Reply::Hello(info))`, then hangs up.
fn fake_board(stale: Vec<u8>, info: Info) -> (String, std::thread::JoinHandle<()>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap().to_string();
    let board = std::thread::spawn(move || {
        let (mut stream, _) = listener.accept().unwrap();
        stream.write_all(&stale).unwrap();
        stream.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut decoder = protocol::Decoder::new();
        let mut buffer = [0u8; 256];
        loop {
            let n = stream.read(&mut buffer).unwrap();
            assert!(n > 0, "the configurator hung up before the handshake");
            for &byte in &buffer[..n] {
                let Some(Ok(request)) = decoder.push(byte) else { continue };
                assert!(matches!(Request::decode(&request), Ok(Request::Hello(_))));
                let reply = DeviceMessage::Response(Ok(Reply::Hello(info)));
                stream.write_all(&frame(&reply, request.seq)).unwrap();
                // Stay up long enough for a status request to time out, if one is made.
                std::thread::sleep(Duration::from_millis(100));
                return;
            }
        }
    });
    (address, board)
}

#[test]
fn a_board_of_another_major_version_is_refused_naming_both_versions() {
    let future = Version { major: PROTOCOL_VERSION.major + 1, minor: 0 };
    let (address, board) = fake_board(Vec::new(), fake_info(future, "FUTURE"));
    let output = run_cli(&["--tcp", &address, "info"]);
    board.join().unwrap();
    assert_eq!(output.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&output.stderr);
    let device = format!("protocol {}.0", PROTOCOL_VERSION.major + 1);
    let host = format!("protocol {}.{}", PROTOCOL_VERSION.major, PROTOCOL_VERSION.minor);
    assert!(stderr.contains(&device) && stderr.contains(&host), "{stderr}");
    assert!(stderr.contains("update the configurator"), "{stderr}");
}

#[test]
fn stale_answers_from_an_earlier_session_are_not_taken_for_the_handshake() {
    // Late handshake replies of an earlier session, for every sequence number a new session
    // could start with (a future-major board name, so accepting one would fail the command),
    // then the board that answers this session (it then hangs up).
    let stale_info = fake_info(Version { major: PROTOCOL_VERSION.major + 1, minor: 0 }, "STALE");
    let stale_reply = DeviceMessage::Response(Ok(Reply::Hello(stale_info)));
    let stale: Vec<u8> = (0..=u16::MAX).flat_map(|seq| frame(&stale_reply, seq)).collect();
    let (address, board) = fake_board(stale, fake_info(PROTOCOL_VERSION, "FRESH"));
    let output = run_cli(&["--tcp", &address, "status"]);
    board.join().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    // The handshake succeeded with the fresh board; the status request then finds the
    // connection closed, which is reported as such, not as a timeout or a version clash.
    assert!(!stderr.contains("incompatible"), "a stale reply was taken: {stderr}");
    assert_eq!(output.status.code(), Some(1));
    assert!(stderr.contains("closed by the other side"), "{stderr}");
}

#[test]
fn too_many_sitl_throws_are_refused() {
    let output = run_cli(&["--sitl", "--sitl-throws", "17", "status"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("17"));
}

#[test]
fn the_sitl_board_learns_its_imu_offset_from_automatic_throws_and_reports_it_over_the_link() {
    // Three throws, 2 simulated seconds apart, at 4× real time: about 2 s of wall time.
    let config = SitlConfig { auto_throw_every_s: Some(2.0), speed: 4.0, ..SitlConfig::default() };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let port = sitl.pty_path.clone().unwrap();
    let port = port.to_str().unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let offset = loop {
        let status = json_of(&run_cli(&["--port", port, "--json", "status"]));
        let offset = status["imu_offset"].clone();
        if offset["well_determined"] == true || std::time::Instant::now() > deadline {
            break offset;
        }
        std::thread::sleep(Duration::from_millis(300));
    };
    assert_eq!(offset["well_determined"], true, "{offset}");
    // One throw may suffice: the first spins at (700, 350, 180) °/s, about no principal axis,
    // so the nutation excites every direction of r, and with the drag modelled its estimate is
    // within the 2 mm the verdict asks (the error is asserted below).
    let throws = offset["throws"].as_u64().unwrap();
    assert!((1..=4).contains(&throws), "{offset}");
    let airframe = sim::airframe::Airframe::builtin("paper-quad").unwrap();
    let truth = airframe.q_imu_body() * airframe.r_imu_m();
    let r: Vec<f64> =
        offset["r_imu_m"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let error_mm = ((r[0] - truth.x).powi(2) + (r[1] - truth.y).powi(2) + (r[2] - truth.z).powi(2))
        .sqrt()
        * 1e3;
    assert!(error_mm < 1.0, "onboard estimate over the link off by {error_mm:.3} mm: {offset}");
}

#[test]
fn too_frequent_automatic_throws_are_refused() {
    let config = SitlConfig { auto_throw_every_s: Some(0.5), ..SitlConfig::default() };
    let error = Sitl::start(&config).err().expect("refused");
    assert!(error.to_string().contains("at least 2 s"), "{error}");
}

#[test]
fn sitl_throws_from_the_configurator_end_with_the_offset_in_the_status() {
    let report = json_of(&run_cli(&["--sitl", "--sitl-throws", "2", "--json", "status"]));
    let offset = &report["imu_offset"];
    assert_eq!(offset["throws"], 2, "{offset}");
    assert_eq!(offset["estimated"], true);
    assert_eq!(offset["in_free_fall"], false);
    // At rest in the hand again, with a full quiet statistics window.
    let accel_mps2 = norm(&report["imu"]["accel_mps2"]);
    assert!((accel_mps2 - 9.81).abs() < 0.15, "|a| = {accel_mps2} m/s²");
    let output = run_cli(&["--sitl-throws", "2", "status"]);
    assert_eq!(output.status.code(), Some(2), "--sitl-throws needs --sitl");
}

#[test]
fn sitl_disarm_is_done_at_once() {
    let output = run_cli(&["--sitl", "disarm"]);
    assert_eq!(output.status.code(), Some(0), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(String::from_utf8_lossy(&output.stdout).contains("disarmed"));
}

#[test]
fn sitl_status_json_carries_an_idle_learner() {
    let report = json_of(&run_cli(&["--sitl", "--json", "status"]));
    let learner = &report["learner"];
    assert_eq!(learner["phase"], "Idle", "{learner}");
    assert_eq!(learner["failure"], "None", "{learner}");
    assert_eq!(learner["exciting_motor"], Value::Null);
    assert_eq!(learner["thrust_axis"], Value::Null, "no thrust axis before a throw");
    // The status itself is unchanged by the learner request that follows it.
    assert_eq!(report["link"]["frames_rx"], 2, "hello and status");
}

#[test]
fn sitl_learner_stream_in_json_is_one_object_per_sample_then_the_summary() {
    let args = ["--sitl", "--json", "stream", "--topic", "learner"];
    let output = run_cli(&[&args[..], &["--rate-hz", "200", "--duration-s", "0.5"]].concat());
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let lines: Vec<Value> = String::from_utf8(output.stdout)
        .unwrap()
        .lines()
        .map(|line| serde_json::from_str(line).expect("every line is one JSON object"))
        .collect();
    let (summary, samples) = lines.split_last().expect("at least the summary");
    assert_eq!(summary["topic"], "learner");
    assert_eq!(summary["received"].as_u64(), Some(samples.len() as u64));
    assert!(samples.len() >= 50, "{} samples at 200 Hz for 0.5 s", samples.len());
    for pair in samples.windows(2) {
        assert_eq!(pair[1]["seq"].as_u64(), pair[0]["seq"].as_u64().map(|s| s + 1));
        // The G1 blocks alternate: specific force, then angular acceleration.
        let force = |v: &Value| v.get("g1_specific_force_mps2_per_unit_thrust").is_some();
        assert_ne!(force(&pair[0]), force(&pair[1]));
    }
    assert!(samples.iter().all(|s| s["phase"] == "Idle"));
}

/// The simulated motion capture goes on after a restart of the board: its poses are timed by
/// the firmware's clock, which starts again at zero (a capture kept across the restart sent
/// nothing until the new clock passed the old one: the walkthrough's flight after `reboot` had
/// no position and drifted).
#[test]
fn the_sitls_motion_capture_reaches_the_board_again_right_after_a_restart() {
    let config = SitlConfig { mocap: true, speed: 4.0, ..SitlConfig::default() };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let port = sitl.pty_path.clone().unwrap();
    let port = port.to_str().unwrap();
    let pose_fresh = |port: &str| {
        let status = json_of(&run_cli(&["--port", port, "--json", "status"]));
        status["flight"]["pose_fresh"].as_bool().expect("pose_fresh is a boolean")
    };
    // 2 s of wall time at 4× real time: the firmware's clock is at about 8 s.
    std::thread::sleep(Duration::from_millis(2000));
    assert!(pose_fresh(port), "poses arrive before the restart");
    let output = run_cli(&["--port", port, "reboot"]);
    assert!(output.status.success(), "reboot: {}", String::from_utf8_lossy(&output.stderr));
    // Well under the firmware's 8 s before the restart, at 4× real time.
    std::thread::sleep(Duration::from_millis(300));
    assert!(pose_fresh(port), "poses arrive within a second of the restart");
}
