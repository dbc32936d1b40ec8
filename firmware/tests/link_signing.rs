//! Who may command the craft over a radio (`protocol::signing`): a trusted link (USB) pairs a
//! key; on an untrusted one (the radio) requests that configure, arm, spin or steer are carried
//! out only when signed with it, fresh, in this start-up's session. Refusals are typed and
//! counted, and change nothing.

mod common;
use common::board;
use firmware::app::{ControlCommand, LinkRequest, LinkServer, NoFlash, Settings, StatusView};
use protocol::signing::{LinkKey, KEY_LEN};
use protocol::*;

const KEY: LinkKey = [0x5A; KEY_LEN];
const SESSION: u64 = 0x1234_5678_9ABC_DEF0;

/// One board with two links sharing its settings: USB (trusted) and a radio (untrusted).
struct Board {
    settings: Settings<NoFlash>,
    usb: LinkServer,
    radio: LinkServer,
    seq: u16,
}

impl Board {
    fn new() -> Self {
        let mut settings = Settings::without_store();
        settings.set_link_session(SESSION);
        let mut board = Self {
            settings,
            usb: LinkServer::new(board()),
            radio: LinkServer::new(board()).untrusted(),
            seq: 0,
        };
        for radio in [false, true] {
            let hello = Request::Hello(Hello { protocol: PROTOCOL_VERSION, schema_hash: 0 });
            assert!(matches!(board.ask(radio, &hello, None), Ok(Reply::Hello(_))));
        }
        board
    }

    /// Send `request` on the radio (or USB), signed with `signer` at `timestamp` when given,
    /// and return the response.
    fn ask(&mut self, radio: bool, request: &Request, signed: Option<(Signer, u64)>) -> Response {
        self.seq = self.seq.wrapping_add(1);
        let mut frame = [0u8; MAX_FRAME_LEN];
        let len = match signed {
            Some((signer, timestamp)) => {
                request.encode_signed(self.seq, &signer, timestamp, &mut frame).unwrap()
            }
            None => request.encode(self.seq, &mut frame).unwrap(),
        };
        let view = StatusView::default();
        let server = if radio { &mut self.radio } else { &mut self.usb };
        server.receive(
            &frame[..len],
            0,
            &view,
            &mut self.settings,
            &mut firmware::app::log::NoCard,
        );
        let mut decoder = Decoder::new();
        let mut responses = Vec::new();
        server.transmit_to(|bytes| {
            for &byte in bytes {
                if let Some(Ok(frame)) = decoder.push(byte) {
                    if let Ok(DeviceMessage::Response(response)) = DeviceMessage::decode(&frame) {
                        responses.push((frame.seq, response));
                    }
                }
            }
            bytes.len()
        });
        assert_eq!(responses.len(), 1, "one response per request");
        assert_eq!(responses[0].0, self.seq, "matched by sequence number");
        responses.remove(0).1
    }

    fn security(&mut self, radio: bool) -> LinkSecurity {
        match self.ask(radio, &Request::GetLinkSecurity(()), None) {
            Ok(Reply::LinkSecurity(security)) => security,
            other => panic!("{other:?}"),
        }
    }

    fn pair(&mut self, key: LinkKey) {
        let set = Request::SetLinkKey(SetLinkKey { key: Some(heapless::Vec::from_array(key)) });
        assert_eq!(self.ask(false, &set, None), Ok(Reply::Done));
    }

    /// What the links handed over for the control step.
    fn commands(&mut self) -> Vec<ControlCommand> {
        let mut out = Vec::new();
        for server in [&mut self.usb, &mut self.radio] {
            while let Some(request) = server.take_request() {
                if let LinkRequest::Control(command) = request {
                    out.push(command);
                }
            }
        }
        out
    }
}

fn set_rate_p(value: f32) -> Request {
    Request::SetParam(SetParam {
        name: heapless::String::try_from("excitation_step_cmd").unwrap(),
        values: heapless::Vec::from_slice(&[value]).unwrap(),
    })
}

fn signer() -> Signer {
    Signer { key: KEY, session: SESSION }
}

#[test]
fn an_unpaired_radio_reads_and_disarms_but_cannot_configure_arm_or_steer() {
    let mut board = Board::new();
    let security = board.security(true);
    assert!(!security.trusted && !security.paired);
    assert_eq!(security.session, SESSION);
    assert!(matches!(board.ask(true, &Request::GetStatus(()), None), Ok(Reply::Status(_))));
    assert_eq!(board.ask(true, &Request::Disarm(()), None), Ok(Reply::Done));
    // Every way to stop works: a stranger's disarm stops a craft on the ground and lands one in
    // the air (the control step tells which, `ControlCommand::Land`).
    assert_eq!(board.commands(), vec![ControlCommand::Land(LandReason::UnsignedDisarm)]);
    let before = *board.settings.params();
    for request in [
        set_rate_p(0.3),
        Request::SaveConfig(()),
        Request::ArmThrowToFly(()),
        Request::MotorTest(MotorTest { motor: 0, command: 0.1 }),
        Request::SetPositionSetpoint(PositionSetpoint {
            position_ned_m: [0.0, 0.0, -1.0],
            heading_rad: 0.0,
        }),
        Request::SetLinkKey(SetLinkKey { key: Some(heapless::Vec::from_array(KEY)) }),
        Request::Land(()),
    ] {
        assert_eq!(board.ask(true, &request, None), Err(DeviceError::SignatureRequired));
    }
    // Signed without a pairing: no key to verify against.
    assert_eq!(
        board.ask(true, &set_rate_p(0.3), Some((signer(), 10))),
        Err(DeviceError::BadSignature)
    );
    assert_eq!(board.commands(), vec![], "nothing reached the control step");
    assert!(*board.settings.params() == before, "no parameter changed");
    let security = board.security(true);
    assert_eq!((security.unsigned_refused, security.bad_signature), (7, 1));
    // The same requests over USB are carried out unsigned.
    assert!(matches!(board.ask(false, &set_rate_p(0.3), None), Ok(Reply::Param(_))));
}

#[test]
fn a_paired_signer_commands_over_the_radio_and_forgeries_and_replays_are_refused_and_counted() {
    let mut board = Board::new();
    board.pair(KEY);
    assert!(board.security(true).paired);

    // The paired configurator's signed request is carried out.
    let accepted = board.ask(true, &set_rate_p(0.31), Some((signer(), 1_000)));
    assert!(matches!(accepted, Ok(Reply::Param(_))), "{accepted:?}");
    let value =
        |board: &Board| board.settings.params().info(params_index("excitation_step_cmd")).unwrap();
    let in_force = value(&board).value[0];
    assert_eq!(in_force, 0.31);

    // The same frame again (a recording replayed), and an older timestamp: refused.
    assert_eq!(
        board.ask(true, &set_rate_p(0.31), Some((signer(), 1_000))),
        Err(DeviceError::Replayed { last_timestamp: 1_000 })
    );
    assert_eq!(
        board.ask(true, &set_rate_p(0.5), Some((signer(), 999))),
        Err(DeviceError::Replayed { last_timestamp: 1_000 })
    );
    // Another key, and the right key in another session (signed before a restart).
    let forger = Signer { key: [0x11; KEY_LEN], session: SESSION };
    assert_eq!(
        board.ask(true, &set_rate_p(0.5), Some((forger, 2_000))),
        Err(DeviceError::BadSignature)
    );
    let stale = Signer { key: KEY, session: SESSION + 1 };
    assert_eq!(
        board.ask(true, &set_rate_p(0.5), Some((stale, 2_000))),
        Err(DeviceError::BadSignature)
    );
    // Unsigned on the radio still refused once paired.
    assert_eq!(
        board.ask(true, &Request::ArmThrowToFly(()), None),
        Err(DeviceError::SignatureRequired)
    );
    assert_eq!(value(&board).value[0], 0.31, "no refused request changed anything");

    // Signed arming goes through to the control step (this board reports no motors: the arm
    // itself is refused for the motor count, after the signature was accepted).
    let arm = board.ask(true, &Request::ArmThrowToFly(()), Some((signer(), 3_000)));
    assert!(matches!(arm, Err(DeviceError::BadValue { .. })), "past the signature: {arm:?}");
    // The paired configurator's disarm stops the motors at once (it is no stranger's), and its
    // landing is carried out.
    board.commands();
    assert_eq!(board.ask(true, &Request::Disarm(()), Some((signer(), 4_000))), Ok(Reply::Done));
    assert_eq!(board.ask(true, &Request::Land(()), Some((signer(), 5_000))), Ok(Reply::Done));
    assert_eq!(
        board.commands(),
        vec![ControlCommand::Disarm, ControlCommand::Land(LandReason::Commanded)]
    );

    let security = board.security(true);
    assert_eq!((security.unsigned_refused, security.bad_signature, security.replayed), (1, 2, 2));
    assert_eq!(security.last_timestamp, 5_000);
    // Only the radio counts its refusals; the key never travels back.
    assert_eq!(board.security(false).bad_signature, 0);
    // The key cannot be changed over the radio, even signed.
    let rekey = Request::SetLinkKey(SetLinkKey { key: None });
    assert_eq!(board.ask(true, &rekey, Some((signer(), 6_000))), Err(DeviceError::TrustedLinkOnly));
    // Unpairing over USB: the old signer is refused from then on.
    assert_eq!(board.ask(false, &rekey, None), Ok(Reply::Done));
    assert_eq!(
        board.ask(true, &set_rate_p(0.5), Some((signer(), 5_000))),
        Err(DeviceError::BadSignature)
    );
}

#[test]
fn a_key_of_another_length_is_malformed_and_changes_nothing() {
    let mut board = Board::new();
    board.pair(KEY);
    let short =
        Request::SetLinkKey(SetLinkKey { key: Some(heapless::Vec::from_slice(&[1; 16]).unwrap()) });
    assert_eq!(board.ask(false, &short, None), Err(DeviceError::Malformed { id: 0x1A }));
    let ok = board.ask(true, &set_rate_p(0.31), Some((signer(), 1)));
    assert!(matches!(ok, Ok(Reply::Param(_))), "the paired key is still in force: {ok:?}");
}

fn params_index(name: &str) -> usize {
    firmware::app::params::find(name.as_bytes()).expect("a parameter")
}

/// A request whose answer was lost on the radio is asked again as the very same frame: the
/// board answers it again and does not act twice (here a setpoint queued once; an arm or a save
/// likewise), though a signed frame's timestamp is no longer fresh.
#[test]
fn the_same_frame_again_gets_the_same_answer_and_is_carried_out_once() {
    let mut board = Board::new();
    board.pair(KEY);
    {
        let setpoint = PositionSetpoint { position_ned_m: [1.0, 2.0, -3.0], heading_rad: 0.5 };
        let request = Request::SetPositionSetpoint(setpoint);
        let mut frame = [0u8; MAX_FRAME_LEN];
        let len = request.encode_signed(900, &signer(), 77, &mut frame).unwrap();
        let view = StatusView::default();
        let mut responses = Vec::new();
        for _ in 0..3 {
            board.radio.receive(
                &frame[..len],
                0,
                &view,
                &mut board.settings,
                &mut firmware::app::log::NoCard,
            );
            let mut decoder = Decoder::new();
            board.radio.transmit_to(|bytes| {
                for &byte in bytes {
                    if let Some(Ok(frame)) = decoder.push(byte) {
                        if let Ok(DeviceMessage::Response(response)) = DeviceMessage::decode(&frame)
                        {
                            responses.push((frame.seq, response));
                        }
                    }
                }
                bytes.len()
            });
        }
        assert_eq!(responses.len(), 3, "every copy is answered");
        assert!(responses.iter().all(|r| *r == responses[0]), "the same answer: {responses:?}");
        assert_eq!(responses[0], (900, Ok(Reply::Done)));
        assert_eq!(
            board.commands(),
            vec![ControlCommand::PositionSetpoint(setpoint)],
            "carried out once"
        );
        assert_eq!(board.security(true).replayed, 0, "a repeat is not a replay");
    }
    // A new frame with the old timestamp is a replay.
    let setpoint = PositionSetpoint { position_ned_m: [0.0; 3], heading_rad: 0.0 };
    let again = board.ask(true, &Request::SetPositionSetpoint(setpoint), Some((signer(), 77)));
    assert_eq!(again, Err(DeviceError::Replayed { last_timestamp: 77 }));
}
