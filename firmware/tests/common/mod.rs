//! What the link tests share: the board they talk to.

use firmware::app::BoardInfo;
use protocol::Capabilities;

/// A test board: 2 kHz, four motors, telemetry.
pub fn board() -> BoardInfo {
    BoardInfo {
        board: "TEST",
        serial: heapless::String::try_from("42").unwrap(),
        capabilities: Capabilities::TELEMETRY,
        control_rate_hz: 2000,
        motor_count: 4,
    }
}
