//! The lockstep bridge round-trips packets over loopback UDP, bounded by timeouts.

use std::time::Duration;

use firmware::app::hal::{Imu, ImuSample, Motors, MAX_MOTORS};
use sim::bridge::{BridgeClient, BridgeError, BridgeServer, SensorPacket};
use sim::scenario::FlightApp;

/// Echoes what it saw into the commands: |gyro x|, the first motor speed / 1000, and the time.
struct Echo;

impl FlightApp for Echo {
    fn step<I: Imu, M: Motors>(&mut self, now_us: u64, imu: &mut I, motors: &mut M) {
        let sample = imu.read().expect("the packet's sample");
        let speed = motors.speeds_rad_s()[0].unwrap_or(0.0);
        let mut c = [0.0f32; MAX_MOTORS];
        c[0] = sample.gyro_rad_s[0].abs();
        c[1] = speed / 1000.0;
        c[2] = (now_us as f32) * 1e-6;
        c[3] = if motors.speeds_rad_s()[1].is_none() { 1.0 } else { 0.0 };
        motors.set_commands(&c[..motors.count() as usize]);
    }
}

const TIMEOUT: Duration = Duration::from_secs(2);

#[test]
fn bridge_round_trips_a_packet_over_loopback() {
    let mut server = BridgeServer::bind("127.0.0.1:0").unwrap();
    let server_addr = server.local_addr().unwrap();
    let handle = std::thread::spawn(move || {
        let mut app = Echo;
        let first = server.step(&mut app, TIMEOUT);
        let second = server.step(&mut app, TIMEOUT);
        (first.map(|(s, _)| s), second.map(|(s, _)| s))
    });
    let mut client = BridgeClient::connect("127.0.0.1:0", server_addr).unwrap();
    let mut speeds_rad_s = [None; MAX_MOTORS];
    speeds_rad_s[0] = Some(750.0);
    let mut packet = SensorPacket {
        sequence: 41,
        time_s: 0.25,
        imu: ImuSample { gyro_rad_s: [-0.5, 0.0, 0.0], accel_mps2: [0.0, 0.0, -9.81] },
        motor_count: 6,
        speeds_rad_s,
    };
    let reply = client.exchange(&packet, TIMEOUT).unwrap();
    assert_eq!(reply.sequence, 41);
    assert_eq!(reply.motor_count, 6);
    assert_eq!(&reply.commands[..4], &[0.5, 0.75, 0.25, 1.0]);
    packet.sequence = 42;
    packet.time_s = 0.2505;
    let reply = client.exchange(&packet, TIMEOUT).unwrap();
    assert_eq!(reply.sequence, 42);
    assert!((reply.commands[2] - 0.2505).abs() < 1e-6);
    let (first, second) = handle.join().unwrap();
    assert_eq!(first.unwrap().sequence, 41);
    assert_eq!(second.unwrap(), packet);
}

#[test]
fn bridge_times_out_without_a_simulator() {
    let mut server = BridgeServer::bind("127.0.0.1:0").unwrap();
    let timeout = Duration::from_millis(50);
    match server.step(&mut Echo, timeout) {
        Err(BridgeError::Timeout(t)) => assert_eq!(t, timeout),
        other => panic!("expected a timeout, got {other:?}"),
    }
}

#[test]
fn the_simulator_flies_an_application_through_the_bridge_in_lockstep() {
    use sim::airframe::Airframe;
    use sim::board::{SimBoard, SimConfig};
    use sim::scenario::OpenLoop;

    // The application side: open-loop hover commands for the racer, served over UDP.
    let airframe = Airframe::builtin("racer-5in").unwrap();
    let hover = airframe.hover_speeds_rad_s().unwrap();
    let commands: Vec<f32> = hover
        .iter()
        .enumerate()
        .map(|(i, w)| airframe.rotor_motor(i).command_for_speed(*w) as f32)
        .collect();
    let steps = 600; // 0.3 s at 2 kHz
    let mut server = BridgeServer::bind("127.0.0.1:0").unwrap();
    let server_addr = server.local_addr().unwrap();
    let served = commands.clone();
    let handle = std::thread::spawn(move || {
        let mut app = OpenLoop(move |_t: f64, c: &mut [f32]| c.copy_from_slice(&served));
        (0..steps)
            .map(|_| server.step(&mut app, TIMEOUT).map(|_| ()))
            .collect::<Result<Vec<_>, _>>()
    });

    // The simulator side: our own physics as the "external" simulator.
    let mut board = SimBoard::new(&airframe, &SimConfig::default());
    let mut client = BridgeClient::connect("127.0.0.1:0", server_addr).unwrap();
    for sequence in 0..steps as u64 {
        board.tick();
        let packet = SensorPacket {
            sequence,
            time_s: board.time_s(),
            imu: board.last_sample(),
            motor_count: board.motors().count(),
            speeds_rad_s: board.motors().speeds_rad_s(),
        };
        let reply = client.exchange(&packet, TIMEOUT).unwrap();
        assert_eq!(reply.sequence, sequence);
        board.motors_mut().set_commands(&reply.commands[..reply.motor_count as usize]);
    }
    handle.join().unwrap().unwrap();
    // After 0.3 s (12 motor time constants) the rotors run at the hover speed.
    for (i, w) in board.physics().state().rotor_speed_rad_s[..4].iter().enumerate() {
        assert!(((w - hover[i]) / hover[i]).abs() < 1e-4, "rotor {i}: {w} vs {}", hover[i]);
    }
}
