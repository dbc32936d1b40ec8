//! The configurator over a simulated telemetry radio (issue 29, first step): the SITL serves the
//! protocol on a second pseudo-terminal behind a 57,600-baud radio with 20 ms of latency and 2 %
//! of frames lost, and `configurator-cli --port` works through it as through USB. A read-only
//! request whose frame (or answer) is lost is asked again after `RETRY_AFTER` (0.4 s), as the
//! very same frame: the board answers a repeat of a request that commands the craft with its
//! earlier answer, without acting twice.
//!
//! Issue 54: the rate. A radio's USB-UART adapter garbles every byte unless opened at its rate
//! (`--baud`), which `tests::baud_relay` enforces where the SITL's pseudo-terminal would not; and
//! `sitl --radio-port PATH` links the radio where a script can find it.

use sim::serve::RadioConfig;
use sim::sitl::{Sitl, SitlConfig};
use std::time::Instant;
use tests::run_cli;

#[test]
fn status_over_a_lossy_57600_baud_radio_answers_every_time_within_a_second() {
    let config = SitlConfig {
        pty: false,
        seed: 3,
        telemetry_radio: Some(RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.02 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let port = sitl.radio_path.clone().expect("the radio's pseudo-terminal");
    let port = port.to_str().unwrap();
    let mut times_s = Vec::new();
    for _ in 0..10 {
        let started = Instant::now();
        let output = run_cli(&["--port", port, "--json", "status"]);
        times_s.push(started.elapsed().as_secs_f64());
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        let status: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        assert_eq!(status["armed"], false);
    }
    times_s.sort_by(f64::total_cmp);
    eprintln!("status over the radio: {times_s:.2?} s (including the configurator's start)");
    // Measured 0.30 s without a loss and 0.71 s with one retry; the median is a run without.
    assert!(times_s[5] < 1.0, "median {:.2} s", times_s[5]);
}

/// A slow, far radio (9,600 baud, 100 ms each way, 2 % lost): the retry waits four handshake
/// round trips rather than 0.4 s, so answers that are merely slow are not asked for again, and
/// every status still arrives.
#[test]
fn status_over_a_slow_far_radio_answers_every_time() {
    let config = SitlConfig {
        pty: false,
        seed: 5,
        telemetry_radio: Some(RadioConfig { baud: 9_600, latency_s: 0.100, frame_loss: 0.02 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let port = sitl.radio_path.clone().expect("the radio's pseudo-terminal");
    let mut times_s = Vec::new();
    for _ in 0..5 {
        let started = Instant::now();
        let output = run_cli(&["--port", port.to_str().unwrap(), "--json", "status"]);
        times_s.push(started.elapsed().as_secs_f64());
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    }
    eprintln!("status over 9,600 baud and 100 ms: {times_s:.2?} s");
}

/// What a run of the configurator printed, stdout then stderr.
fn output_text(output: &std::process::Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

/// `configurator-cli` with its link keys in `keys` (not the user's).
fn cli_with_keys(keys: &std::path::Path, args: &[&str]) -> std::process::Output {
    std::process::Command::new(tests::cli_binary())
        .env(configurator_cli::keys::KEY_DIR_ENV, keys)
        .args(args)
        .output()
        .expect("start configurator-cli")
}

/// Nobody else's radio commands the craft: over the simulated radio an unpaired configurator's
/// `set` and `arm-throw-to-fly` are refused (typed, counted, nothing changed); after `pair`
/// over the SITL's own link (USB's stand-in), the same configurator's are carried out, signed.
/// Forged and replayed frames are the board tests' (`firmware/tests/link_signing.rs`). The radio
/// loses 2 % of the frames: a lost `set` (or its answer) is asked again.
#[test]
fn over_the_radio_only_the_paired_configurator_configures_the_craft() {
    let config = SitlConfig {
        pty: true,
        seed: 7,
        telemetry_radio: Some(RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.02 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let usb = sitl.pty_path.clone().expect("the SITL's own link");
    let radio = sitl.radio_path.clone().expect("the radio's pseudo-terminal");
    let (usb, radio) = (usb.to_str().unwrap(), radio.to_str().unwrap());
    let keys = std::env::temp_dir().join(format!("fc-keys-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&keys);
    let stranger = keys.join("stranger");
    let ours = keys.join("ours");

    // Unpaired: refused over the radio, with what to do.
    let set =
        cli_with_keys(&stranger, &["--port", radio, "set", "excitation_step_cmd", "=", "0.4"]);
    assert!(!set.status.success());
    assert!(output_text(&set).contains("configurator-cli pair"), "{}", output_text(&set));
    let arm = cli_with_keys(&stranger, &["--port", radio, "arm-throw-to-fly"]);
    assert!(!arm.status.success(), "{}", output_text(&arm));
    // Pairing is refused over the radio.
    let pair = cli_with_keys(&ours, &["--port", radio, "pair"]);
    assert!(!pair.status.success());
    assert!(output_text(&pair).contains("trusted link"), "{}", output_text(&pair));

    // Paired over the SITL's own link: the key file is ours alone.
    let pair = cli_with_keys(&ours, &["--port", usb, "pair"]);
    assert!(pair.status.success(), "{}", output_text(&pair));
    let key_files: Vec<_> = std::fs::read_dir(&ours).unwrap().collect();
    assert_eq!(key_files.len(), 1);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = key_files[0].as_ref().unwrap().metadata().unwrap().permissions().mode();
        assert_eq!(mode & 0o077, 0, "readable by the user only: {mode:o}");
    }

    // The paired configurator's `set` over the radio is carried out; the stranger's still not.
    let set = cli_with_keys(&ours, &["--port", radio, "set", "excitation_step_cmd", "=", "0.4"]);
    assert!(set.status.success(), "{}", output_text(&set));
    let set =
        cli_with_keys(&stranger, &["--port", radio, "set", "excitation_step_cmd", "=", "0.7"]);
    assert!(!set.status.success(), "{}", output_text(&set));
    let get = cli_with_keys(&stranger, &["--port", radio, "--json", "get", "excitation_step_cmd"]);
    assert!(get.status.success(), "reads stay open: {}", output_text(&get));
    assert!(
        output_text(&get).contains("0.4"),
        "the paired value is in force: {}",
        output_text(&get)
    );

    // The refusals are counted on the radio's link and reported.
    let security = cli_with_keys(&ours, &["--port", radio, "--json", "security"]);
    assert!(security.status.success(), "{}", output_text(&security));
    let security: serde_json::Value = serde_json::from_slice(&security.stdout).unwrap();
    assert_eq!(security["trusted"], false);
    assert_eq!(security["paired"], true);
    assert_eq!(security["signing"], true);
    assert!(security["refused"]["unsigned"].as_u64().unwrap() >= 3, "{security}");
    let _ = std::fs::remove_dir_all(&keys);
}

/// The field's operations over the radio, paired once over the SITL's own link (USB's
/// stand-in): `calibrate imu-offset` from two throw-and-catches, `save`, then, on a second
/// SITL, `identify` through a throw-and-fly; each over 57,600 baud, 20 ms and 2 % of frames
/// lost, every request signed and every lost one asked again.
#[test]
fn calibrate_save_and_identify_complete_over_a_lossy_radio() {
    let keys = std::env::temp_dir().join(format!("fc-keys-ops-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&keys);
    let radio = RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.02 };
    let flash = keys.join("flash.bin");
    std::fs::create_dir_all(&keys).unwrap();

    let throwing = SitlConfig {
        seed: 11,
        speed: 4.0,
        // Throws go on while the configurator pairs and connects (a count would be spent
        // before the calibration starts).
        auto_throw_every_s: Some(2.0),
        flash_file: Some(flash.clone()),
        telemetry_radio: Some(radio),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&throwing).expect("the SITL starts");
    let usb = sitl.pty_path.clone().unwrap().display().to_string();
    let port = sitl.radio_path.clone().unwrap().display().to_string();
    let pair = cli_with_keys(&keys, &["--port", &usb, "pair"]);
    assert!(pair.status.success(), "{}", output_text(&pair));
    let calibrate = cli_with_keys(
        &keys,
        &[
            "--port",
            &port,
            "--json",
            "calibrate",
            "imu-offset",
            "--yes",
            "--max-throws",
            "2",
            "--timeout-s",
            "30",
        ],
    );
    assert!(calibrate.status.success(), "{}", output_text(&calibrate));
    let report: serde_json::Value = serde_json::from_slice(&calibrate.stdout).unwrap();
    assert_eq!(report["stored"], true, "{report}");
    let save = cli_with_keys(&keys, &["--port", &port, "save"]);
    assert!(save.status.success(), "{}", output_text(&save));
    let status = cli_with_keys(&keys, &["--port", &port, "--json", "status"]);
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
    assert_eq!(status["config"]["unsaved_changes"], false, "{status}");
    drop(sitl);

    let flying = SitlConfig {
        seed: 12,
        hand_throws_to_fly: true,
        telemetry_radio: Some(radio),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&flying).expect("the SITL starts");
    let usb = sitl.pty_path.clone().unwrap().display().to_string();
    let port = sitl.radio_path.clone().unwrap().display().to_string();
    let pair = cli_with_keys(&keys, &["--port", &usb, "pair"]);
    assert!(pair.status.success(), "{}", output_text(&pair));
    let identify = cli_with_keys(
        &keys,
        &[
            "--port",
            &port,
            "--json",
            "identify",
            "--yes",
            "--timeout-s",
            "30",
            "--disarm-after-s",
            "3",
        ],
    );
    assert!(identify.status.success(), "{}", output_text(&identify));
    let report: serde_json::Value = serde_json::from_slice(&identify.stdout).unwrap();
    assert_eq!(report["phase"], "Done", "{report}");
    assert_eq!(report["flew"], true, "{report}");
    let _ = std::fs::remove_dir_all(&keys);
}

/// `stream --topic learner --rate-hz 1000` over a 57,600-baud radio: the board grants the rate
/// its byte budget carries (75 % of 5,760 B/s, each learner sample booked at 221 bytes: 19 Hz),
/// the configurator says so, and what arrives, with every lost sample counted as a gap, is the
/// granted rate.
#[test]
fn streaming_over_the_radio_gets_the_rate_the_byte_budget_allows_with_gaps_counted() {
    let config = SitlConfig {
        pty: false,
        seed: 13,
        telemetry_radio: Some(RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.02 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let port = sitl.radio_path.clone().unwrap().display().to_string();
    let args = [
        "--port",
        &port,
        "--json",
        "stream",
        "--topic",
        "learner",
        "--rate-hz",
        "1000",
        "--duration-s",
        "5",
    ];
    let output = run_cli(&args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("the most this link carries"), "{stderr}");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let summary: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    let granted_hz = summary["granted_rate_hz"].as_f64().unwrap();
    let budget_hz = (5_760.0 * 0.75 / f64::from(protocol::Topic::Learner.max_frame_len())).floor();
    assert_eq!(granted_hz, budget_hz, "{summary}");
    let received = summary["received"].as_f64().unwrap();
    let gaps = summary["gaps"].as_f64().unwrap();
    let expected = granted_hz * 5.0;
    // Every sample the board sent is received or counted as a gap (a lost frame, or one the
    // radio's latency kept past the end: at most a few).
    assert!(
        (received + gaps - expected).abs() <= 0.1 * expected,
        "{received} received + {gaps} gaps, {expected} expected"
    );
    assert!(gaps <= 0.1 * expected, "{gaps} gaps of {expected}");
}

/// Motion capture → `pose-relay` → the simulated radio → the board: the SITL's motion-capture
/// system sends its poses as UDP lines (`--mocap-udp`), the relay forwards them over the
/// 57,600-baud, 20 ms, 2 %-loss radio, signed, and the craft, thrown by the SITL's hand, recovers
/// and holds its position within 0.3 m.
#[test]
fn poses_relayed_over_the_radio_hold_the_craft_after_a_throw_to_fly() {
    let keys = std::env::temp_dir().join(format!("fc-keys-relay-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&keys);
    let udp = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let listen = udp.local_addr().unwrap();
    drop(udp);
    let config = SitlConfig {
        seed: 21,
        hand_throws_to_fly: true,
        mocap: true,
        mocap_udp: Some(listen),
        telemetry_radio: Some(RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.02 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let usb = sitl.pty_path.clone().unwrap().display().to_string();
    let radio = sitl.radio_path.clone().unwrap().display().to_string();
    let pair = cli_with_keys(&keys, &["--port", &usb, "pair"]);
    assert!(pair.status.success(), "{}", output_text(&pair));
    // Poses the SITL sends a board position the configurator is told to hold; the pilot's
    // setpoint stays where the craft recovers (the default).
    let listen_text = listen.to_string();
    let relay = std::process::Command::new(tests::cli_binary())
        .env(configurator_cli::keys::KEY_DIR_ENV, &keys)
        .args([
            "--port",
            &radio,
            "--json",
            "pose-relay",
            "--listen",
            &listen_text,
            "--duration-s",
            "18",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start the relay");
    std::thread::sleep(std::time::Duration::from_secs(2));
    let arm = cli_with_keys(&keys, &["--port", &usb, "arm-throw-to-fly"]);
    assert!(arm.status.success(), "{}", output_text(&arm));
    // Thrown, recovered and holding by now (12 s after the arming), on the relayed poses.
    std::thread::sleep(std::time::Duration::from_secs(12));
    let status = cli_with_keys(&keys, &["--port", &usb, "--json", "status"]);
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
    let flight = &status["flight"];
    assert_eq!(flight["mode"], "PositionHold", "{flight}");
    let error_m = tests::estimate_from_setpoint_m(flight);
    assert!(error_m < 0.3, "{error_m:.3} m from the setpoint: {flight}");
    let relay = relay.wait_with_output().unwrap();
    assert!(relay.status.success(), "{}", output_text(&relay));
    let summary: serde_json::Value = serde_json::from_slice(&relay.stdout).unwrap();
    let relayed = summary["relayed"].as_u64().unwrap();
    // At least 80 % of the 50 Hz grid: the SITL's radio and poses run in real time on the
    // test machine, and `cargo xtask test` on 2 busy cores once relayed 802 of 900 (89 %;
    // 1,799 poses received).
    assert!(relayed >= 18 * 40, "50 Hz for 18 s: {summary}");
    assert_eq!(summary["refused"], 0, "{summary}");
    assert!(summary["accepted"].as_u64().unwrap() >= relayed * 9 / 10, "{summary}");
    let _ = std::fs::remove_dir_all(&keys);
}

/// Send one request frame (already encoded) over `port` and wait for the response with its
/// sequence number `seq`.
fn raw_request(
    port: &mut Box<dyn configurator_cli::link::Transport>,
    frame: &[u8],
    seq: u16,
) -> protocol::Response {
    use std::io::{Read, Write};
    port.write_all(&[0]).unwrap();
    port.write_all(frame).unwrap();
    port.flush().unwrap();
    let mut decoder = protocol::Decoder::new();
    let deadline = Instant::now() + std::time::Duration::from_secs(3);
    let mut buffer = [0u8; 256];
    while Instant::now() < deadline {
        let n = port.read(&mut buffer).unwrap_or(0);
        for &byte in &buffer[..n] {
            if let Some(Ok(frame)) = decoder.push(byte) {
                if let (Ok(protocol::DeviceMessage::Response(response)), true) =
                    (protocol::DeviceMessage::decode(&frame), frame.seq == seq)
                {
                    return response;
                }
            }
        }
    }
    panic!("no answer to request {seq}");
}

/// The frame of `request` under `seq`, signed with `signer` at `timestamp` when given.
fn frame_of(
    request: &protocol::Request,
    seq: u16,
    signed: Option<(protocol::Signer, u64)>,
) -> Vec<u8> {
    let mut out = [0u8; protocol::MAX_FRAME_LEN];
    let len = match signed {
        Some((signer, timestamp)) => request.encode_signed(seq, &signer, timestamp, &mut out),
        None => request.encode(seq, &mut out),
    };
    out[..len.unwrap()].to_vec()
}

/// Over the simulated radio, frame by frame as a stranger on the channel would send them: a
/// `set` signed with another key, a recording of the paired configurator's earlier `set`
/// replayed after a later one, and an unsigned `arm-throw-to-fly` are refused, change nothing
/// and are counted; the paired key's own requests are carried out. (No frame lost here: the
/// losses are the other tests'.)
#[test]
fn over_the_radio_forged_replayed_and_unsigned_requests_are_refused_and_counted() {
    use protocol::{DeviceError, Hello, Reply, Request, SetParam, Signer};
    let keys = std::env::temp_dir().join(format!("fc-keys-forged-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&keys);
    let config = SitlConfig {
        seed: 31,
        telemetry_radio: Some(RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.0 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let usb = sitl.pty_path.clone().unwrap().display().to_string();
    let radio = sitl.radio_path.clone().unwrap().display().to_string();
    let pair = cli_with_keys(&keys, &["--port", &usb, "pair"]);
    assert!(pair.status.success());
    let key_file = std::fs::read_dir(&keys).unwrap().next().unwrap().unwrap().path();
    let hex = std::fs::read_to_string(key_file).unwrap();
    let key: [u8; 32] =
        std::array::from_fn(|i| u8::from_str_radix(&hex.trim()[2 * i..2 * i + 2], 16).unwrap());

    let baud = configurator_cli::connect::Baud::new(57_600).unwrap();
    let mut port = configurator_cli::connect::open_serial(&radio, baud).unwrap();
    let hello = Request::Hello(Hello { protocol: protocol::PROTOCOL_VERSION, schema_hash: 0 });
    assert!(matches!(raw_request(&mut port, &frame_of(&hello, 1, None), 1), Ok(Reply::Hello(_))));
    let security = |port: &mut _, seq| match raw_request(
        port,
        &frame_of(&Request::GetLinkSecurity(()), seq, None),
        seq,
    ) {
        Ok(Reply::LinkSecurity(security)) => security,
        other => panic!("{other:?}"),
    };
    let session = security(&mut port, 2).session;
    let paired = Signer { key, session };
    let set = |value: f32| {
        Request::SetParam(SetParam {
            name: heapless::String::try_from("excitation_step_cmd").unwrap(),
            values: heapless::Vec::from_slice(&[value]).unwrap(),
        })
    };
    let recorded = frame_of(&set(0.4), 3, Some((paired, 1_000)));
    assert!(matches!(raw_request(&mut port, &recorded, 3), Ok(Reply::Param(_))));
    let forger = Signer { key: [0x42; 32], session };
    let forged = frame_of(&set(0.7), 4, Some((forger, 2_000)));
    assert_eq!(raw_request(&mut port, &forged, 4), Err(DeviceError::BadSignature));
    let later = frame_of(&set(0.45), 5, Some((paired, 3_000)));
    assert!(matches!(raw_request(&mut port, &later, 5), Ok(Reply::Param(_))));
    assert_eq!(
        raw_request(&mut port, &recorded, 3),
        Err(DeviceError::Replayed { last_timestamp: 3_000 })
    );
    let arm = frame_of(&Request::ArmThrowToFly(()), 6, None);
    assert_eq!(raw_request(&mut port, &arm, 6), Err(DeviceError::SignatureRequired));
    let counted = security(&mut port, 7);
    assert_eq!((counted.unsigned_refused, counted.bad_signature, counted.replayed), (1, 1, 1));
    drop(port);
    // The value in force is the paired configurator's last, not the forger's or the replay's.
    let get = cli_with_keys(&keys, &["--port", &usb, "--json", "get", "excitation_step_cmd"]);
    let get: serde_json::Value = serde_json::from_slice(&get.stdout).unwrap();
    assert_eq!(get["value"][0].as_f64().unwrap() as f32, 0.45, "{get}");
    let _ = std::fs::remove_dir_all(&keys);
}

/// A ROS-style sender (world east-north-up, body front-left-up) through `pose-relay --frame enu`:
/// the board receives the same place in north-east-down.
#[test]
fn poses_in_enu_axes_reach_the_board_in_ned() {
    let udp = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let listen = udp.local_addr().unwrap();
    drop(udp);
    let sitl = Sitl::start(&SitlConfig { tcp_port: Some(0), ..SitlConfig::default() })
        .expect("the SITL starts");
    // The relay on the pseudo-terminal, the status over TCP (one host per port).
    let usb = sitl.pty_path.clone().unwrap().display().to_string();
    let tcp = sitl.tcp_addr.unwrap().to_string();
    let listen_text = listen.to_string();
    let relay = std::process::Command::new(tests::cli_binary())
        .args(["--port", &usb, "--json", "pose-relay", "--frame", "enu"])
        .args(["--listen", &listen_text, "--duration-s", "3"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start the relay");
    // 1 m east, 2 m north, 0.5 m up, facing east (identity in ENU), at 50 Hz for 2.5 s.
    let sender = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    for i in 0..125 {
        let line = format!("{:.3} 1.0 2.0 0.5 1 0 0 0\n", f64::from(i) * 0.02);
        let _ = sender.send_to(line.as_bytes(), listen);
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let status = run_cli(&["--tcp", &tcp, "--json", "status"]);
    assert!(status.status.success(), "{}", output_text(&status));
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
    let position: Vec<f64> = status["flight"]["position_ned_m"]
        .as_array()
        .unwrap_or_else(|| panic!("no position: {}", status["flight"]))
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let expected = [2.0, 1.0, -0.5];
    let error_m: f64 =
        position.iter().zip(expected).map(|(p, e)| (p - e).powi(2)).sum::<f64>().sqrt();
    assert!(error_m < 1e-3, "the board holds {position:?}, the sender meant {expected:?} NED");
    let relay = relay.wait_with_output().unwrap();
    assert!(relay.status.success(), "{}", output_text(&relay));
    let summary: serde_json::Value = serde_json::from_slice(&relay.stdout).unwrap();
    assert_eq!(summary["malformed"], 0, "{summary}");
    assert_eq!(summary["refused"], 0, "{summary}");
}

/// Issue 54: a radio's USB-UART adapter runs its UART at one rate (a SiK radio's at 57,600
/// baud), and a configurator that opens it at another hears only garbage. Through
/// `tests::baud_relay` (a pseudo-terminal that forwards to the SITL's 57,600-baud radio and
/// garbles every byte both ways unless the configurator set 57,600 baud on it): `--baud 57600`,
/// or `FC_BAUD=57600`, reaches the board; without either (921,600 baud, right for USB CDC) the
/// handshake fails with exit code 1 and says the rate is probably wrong.
#[cfg(target_os = "linux")]
#[test]
fn through_a_57600_baud_adapter_only_the_right_rate_reaches_the_board() {
    use tests::baud_relay::BaudRelay;
    let config = SitlConfig {
        pty: false,
        seed: 41,
        telemetry_radio: Some(RadioConfig { baud: 57_600, latency_s: 0.020, frame_loss: 0.0 }),
        ..SitlConfig::default()
    };
    let sitl = Sitl::start(&config).expect("the SITL starts");
    let relay = BaudRelay::start(&sitl.radio_path.clone().unwrap(), 57_600).expect("the relay");
    let port = relay.path().to_str().unwrap();
    let cli = || {
        let mut command = std::process::Command::new(tests::cli_binary());
        command.env_remove(configurator_cli::connect::BAUD_ENV);
        command
    };

    let status = cli().args(["--port", port, "--baud", "57600", "--json", "status"]).output();
    let status = status.expect("start configurator-cli");
    assert!(status.status.success(), "{}", output_text(&status));
    let json: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
    assert_eq!(json["armed"], false, "{json}");
    let stats = relay.stats();
    assert_eq!((stats.last_baud, stats.bytes_garbled), (Some(57_600), 0), "{stats:?}");
    assert!(stats.bytes_passed > 100, "{stats:?}");

    let from_env = cli().env("FC_BAUD", "57600").args(["--port", port, "status"]).output();
    let from_env = from_env.expect("start configurator-cli");
    assert!(from_env.status.success(), "{}", output_text(&from_env));

    let started = Instant::now();
    let wrong = cli().args(["--port", port, "status"]).output().expect("start configurator-cli");
    let text = output_text(&wrong);
    assert_eq!(wrong.status.code(), Some(1), "{text}");
    for says in [
        "but no valid frame",
        "the baud rate is probably wrong",
        "opened at 921600 baud",
        "try --baud 57600",
    ] {
        assert!(text.contains(says), "`{says}` in: {text}");
    }
    assert!(wrong.stdout.is_empty(), "{text}");
    eprintln!("the wrong rate found out in {:.1} s", started.elapsed().as_secs_f64());
    let stats = relay.stats();
    assert_eq!(stats.last_baud, Some(921_600), "{stats:?}");
    assert!(stats.bytes_garbled > 0, "{stats:?}");
}

/// Kills the child process it holds when dropped (a test that fails leaves no SITL running).
struct KillOnDrop(std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `sitl --radio-baud 57600 --radio-port PATH` links its simulated radio's pseudo-terminal at
/// PATH, so a script knows where to connect: paired once over the SITL's own link (`--pty-link`),
/// the configurator runs `status`, `identify` (the simulated hand throws the craft for flight)
/// and `stream` at `--port PATH --baud 57600`.
#[test]
fn the_sitl_serves_its_radio_at_the_radio_port_path() {
    let dir = std::env::temp_dir().join(format!("fc-radio-port-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (usb, radio, keys) = (dir.join("usb"), dir.join("radio"), dir.join("keys"));
    let (usb, radio) = (usb.to_str().unwrap(), radio.to_str().unwrap());
    let sitl = std::process::Command::new(tests::sitl_binary())
        .args(["--no-flash", "--hand-throws-to-fly", "--pty-link", usb])
        .args(["--radio-baud", "57600", "--radio-port", radio, "--duration-s", "120"])
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("start sitl");
    let _sitl = KillOnDrop(sitl);
    let started = Instant::now();
    while std::fs::metadata(radio).is_err() {
        assert!(started.elapsed().as_secs() < 10, "no {radio} after 10 s");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }

    let pair = cli_with_keys(&keys, &["--port", usb, "pair"]);
    assert!(pair.status.success(), "{}", output_text(&pair));
    let over_radio = |args: &[&str]| {
        let all: Vec<&str> =
            ["--port", radio, "--baud", "57600", "--json"].iter().chain(args).copied().collect();
        let output = cli_with_keys(&keys, &all);
        assert!(output.status.success(), "{args:?}: {}", output_text(&output));
        output
    };
    let status = over_radio(&["status"]);
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
    assert_eq!(status["armed"], false, "{status}");

    let identify = over_radio(&["identify", "--yes", "--timeout-s", "30", "--disarm-after-s", "1"]);
    let report: serde_json::Value = serde_json::from_slice(&identify.stdout).unwrap();
    assert_eq!(report["phase"], "Done", "{report}");
    assert_eq!(report["flew"], true, "{report}");

    let stream = over_radio(&["stream", "--topic", "imu", "--rate-hz", "50", "--duration-s", "1"]);
    let summary: serde_json::Value = serde_json::from_slice(&stream.stdout).unwrap();
    let received = summary["received"].as_u64().unwrap();
    assert!(received >= 40, "50 Hz for 1 s: {summary}");
    drop(_sitl);
    let _ = std::fs::remove_dir_all(&dir);
}
