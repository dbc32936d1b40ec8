//! Which requests a link anyone can hear (a radio) must sign ([`crate::signing`]): the firmware's
//! link server and the configurator ask it here. It reads the message table, which names the
//! link key's length from `signing`; kept apart from `signing`, the two do not import each other.

use crate::Request;

/// Whether `request` configures, arms, spins or steers the craft, or deletes what it stored (a
/// flight log): such a request is carried out from an untrusted link (a radio) only when signed.
/// Everything else (handshake, reads, telemetry rates and [`Request::Disarm`]: every way to stop
/// must work) stays open. Exhaustive, so a new request is classified when it is added.
pub fn commands_the_craft(request: &Request) -> bool {
    match request {
        Request::ArmThrowToFly(())
        | Request::SetExternalPose(_)
        | Request::SetParam(_)
        | Request::SaveConfig(())
        | Request::ResetConfig(())
        | Request::StartCalibration(())
        | Request::StopCalibration(_)
        | Request::MotorTest(_)
        | Request::Reboot(())
        | Request::SetPositionSetpoint(_)
        | Request::RebootToBootloader(())
        | Request::EscCommand(_)
        | Request::SetLinkKey(_)
        | Request::DeleteLog(_)
        | Request::Land(())
        | Request::CompassCalibration(_) => true,
        Request::Hello(_)
        | Request::GetInfo(())
        | Request::GetStatus(())
        | Request::SetTelemetryRate(_)
        | Request::Ping(_)
        | Request::Disarm(())
        | Request::GetLearner(())
        | Request::GetParam(_)
        | Request::GetConfig(())
        | Request::GetFlight(())
        | Request::GetBoard(())
        | Request::GetHealth(())
        | Request::GetLinkSecurity(())
        | Request::ListLogs(_)
        | Request::ReadLog(_)
        | Request::GetBattery(())
        | Request::GetIdentification(())
        | Request::GetGnss(())
        | Request::GetCompass(()) => false,
    }
}
