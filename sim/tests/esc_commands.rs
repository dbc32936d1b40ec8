//! ESC commands through the firmware application to the simulated ESCs: the control step hands
//! them to the motor outputs only while nothing is armed, and the ESCs act on the DShot frames
//! as an ESC firmware does (a beep at once, a settings command after six frames in a row).

use firmware::app::ControlCommand;
use protocol::DshotCommand;
use sim::airframe::Airframe;
use sim::board::{SimBoard, SimConfig};
use sim::scenario::{with_firmware_app, FirmwareApp, FlightApp};

/// `steps` control steps of `app` on `board`.
fn run(app: &mut FirmwareApp<'_>, board: &mut SimBoard, steps: usize) {
    for _ in 0..steps {
        board.tick();
        let now_us = board.now_us();
        let (imu, motors) = board.ports();
        app.step(now_us, imu, motors);
    }
}

#[test]
fn a_beep_reaches_its_motor_a_save_reaches_all_and_nothing_passes_while_armed() {
    let airframe = Airframe::builtin("paper-quad").unwrap();
    let mut board = SimBoard::new(&airframe, &SimConfig::default());
    with_firmware_app(|app| {
        run(app, &mut board, 10);
        let command = ControlCommand::EscCommand { command: DshotCommand::Beep2, motor: Some(1) };
        app.command(command, board.now_us());
        run(app, &mut board, 10);
        let beeps: Vec<u32> = board.motors().escs().iter().map(|e| e.beeps).collect();
        assert_eq!(beeps, vec![0, 1, 0, 0], "one beep, on motor 1 only");

        let reverse = DshotCommand::SpinDirectionReversed;
        app.command(ControlCommand::EscCommand { command: reverse, motor: None }, board.now_us());
        run(app, &mut board, 10);
        let save = DshotCommand::SaveSettings;
        app.command(ControlCommand::EscCommand { command: save, motor: None }, board.now_us());
        run(app, &mut board, 10);
        for (i, esc) in board.motors().escs().iter().enumerate() {
            assert!(esc.reversed && esc.saves == 1, "motor {i}: {esc:?}");
            assert_eq!(esc.settings_incomplete, 0, "motor {i}: six frames each");
        }
        assert_eq!(app.snapshot().esc_commands_sent, 3);

        // Armed for a throw: the step refuses the command, no ESC hears it.
        app.command(ControlCommand::ArmThrowToFly, board.now_us());
        run(app, &mut board, 2);
        let command = ControlCommand::EscCommand { command: DshotCommand::Beep1, motor: None };
        app.command(command, board.now_us());
        run(app, &mut board, 10);
        let beeps: Vec<u32> = board.motors().escs().iter().map(|e| e.beeps).collect();
        assert_eq!(beeps, vec![0, 1, 0, 0], "no beep while armed");
        assert_eq!(app.snapshot().esc_commands_refused, 1);
    });
}
