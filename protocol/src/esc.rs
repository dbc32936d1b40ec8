//! The ESC commands a host may send through the flight controller: the DShot special commands
//! (values 1..=47 of a DShot frame), which every DShot ESC firmware (BLHeli_32, Bluejay, AM32,
//! KISS) understands while its motor is stopped: beeps to find a motor, spin direction, 3D
//! mode, save. They are the wire's vocabulary ([`crate::EscCommand`] carries the number) and the
//! motor driver's (`firmware::drivers::dshot` encodes them).

/// The DShot special commands (values 1..=47), with their standard numbers (Betaflight
/// `dshotCommands_e`, BLHeli_32 and KISS documentation). Value 0 (motor stop) is not a command:
/// motor stop is what a motor output sends when it has no command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[repr(u8)]
pub enum DshotCommand {
    /// Beep (beacon) tone 1.
    Beep1 = 1,
    /// Beep tone 2.
    Beep2 = 2,
    /// Beep tone 3.
    Beep3 = 3,
    /// Beep tone 4.
    Beep4 = 4,
    /// Beep tone 5.
    Beep5 = 5,
    /// Request ESC information (answered over the telemetry wire).
    EscInfo = 6,
    /// Spin direction 1.
    SpinDirection1 = 7,
    /// Spin direction 2.
    SpinDirection2 = 8,
    /// 3D mode off.
    ThreeDModeOff = 9,
    /// 3D mode on.
    ThreeDModeOn = 10,
    /// Settings request (not implemented by most ESCs).
    SettingsRequest = 11,
    /// Save settings to the ESC's flash.
    SaveSettings = 12,
    /// Enable extended DShot telemetry (EDT).
    ExtendedTelemetryEnable = 13,
    /// Disable extended DShot telemetry.
    ExtendedTelemetryDisable = 14,
    /// Spin direction normal (as configured).
    SpinDirectionNormal = 20,
    /// Spin direction reversed.
    SpinDirectionReversed = 21,
    /// LED 0 on (BLHeli_32).
    Led0On = 22,
    /// LED 1 on (BLHeli_32).
    Led1On = 23,
    /// LED 2 on (BLHeli_32).
    Led2On = 24,
    /// LED 3 on (BLHeli_32).
    Led3On = 25,
    /// LED 0 off (BLHeli_32).
    Led0Off = 26,
    /// LED 1 off (BLHeli_32).
    Led1Off = 27,
    /// LED 2 off (BLHeli_32).
    Led2Off = 28,
    /// LED 3 off (BLHeli_32).
    Led3Off = 29,
    /// Audio stream mode on/off (KISS).
    AudioStreamModeToggle = 30,
    /// Silent mode on/off (KISS).
    SilentModeToggle = 31,
}

impl DshotCommand {
    /// Every command, in the order of their numbers.
    pub const ALL: [DshotCommand; 26] = [
        Self::Beep1,
        Self::Beep2,
        Self::Beep3,
        Self::Beep4,
        Self::Beep5,
        Self::EscInfo,
        Self::SpinDirection1,
        Self::SpinDirection2,
        Self::ThreeDModeOff,
        Self::ThreeDModeOn,
        Self::SettingsRequest,
        Self::SaveSettings,
        Self::ExtendedTelemetryEnable,
        Self::ExtendedTelemetryDisable,
        Self::SpinDirectionNormal,
        Self::SpinDirectionReversed,
        Self::Led0On,
        Self::Led1On,
        Self::Led2On,
        Self::Led3On,
        Self::Led0Off,
        Self::Led1Off,
        Self::Led2Off,
        Self::Led3Off,
        Self::AudioStreamModeToggle,
        Self::SilentModeToggle,
    ];

    /// The command with DShot number `value`, if it is one of [`DshotCommand::ALL`].
    pub fn from_value(value: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.value() == u16::from(value))
    }

    /// The command's name in the configurator (`beep1`, `spin-direction-reversed`, …).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Beep1 => "beep1",
            Self::Beep2 => "beep2",
            Self::Beep3 => "beep3",
            Self::Beep4 => "beep4",
            Self::Beep5 => "beep5",
            Self::EscInfo => "esc-info",
            Self::SpinDirection1 => "spin-direction-1",
            Self::SpinDirection2 => "spin-direction-2",
            Self::ThreeDModeOff => "3d-mode-off",
            Self::ThreeDModeOn => "3d-mode-on",
            Self::SettingsRequest => "settings-request",
            Self::SaveSettings => "save-settings",
            Self::ExtendedTelemetryEnable => "extended-telemetry-on",
            Self::ExtendedTelemetryDisable => "extended-telemetry-off",
            Self::SpinDirectionNormal => "spin-direction-normal",
            Self::SpinDirectionReversed => "spin-direction-reversed",
            Self::Led0On => "led0-on",
            Self::Led1On => "led1-on",
            Self::Led2On => "led2-on",
            Self::Led3On => "led3-on",
            Self::Led0Off => "led0-off",
            Self::Led1Off => "led1-off",
            Self::Led2Off => "led2-off",
            Self::Led3Off => "led3-off",
            Self::AudioStreamModeToggle => "audio-stream-mode-toggle",
            Self::SilentModeToggle => "silent-mode-toggle",
        }
    }

    /// The command named `name` ([`DshotCommand::name`], ASCII case ignored).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name().eq_ignore_ascii_case(name))
    }

    /// The command's 11-bit DShot value.
    pub const fn value(self) -> u16 {
        self as u16
    }

    /// Whether the command changes ESC settings. Those must be sent with the telemetry bit set
    /// and repeated ([`DshotCommand::min_repeats`]) for the ESC to accept them (DShot
    /// specification; Betaflight `dshotCommandWrite`).
    pub const fn changes_settings(self) -> bool {
        matches!(
            self,
            Self::SpinDirection1
                | Self::SpinDirection2
                | Self::ThreeDModeOff
                | Self::ThreeDModeOn
                | Self::SettingsRequest
                | Self::SaveSettings
                | Self::ExtendedTelemetryEnable
                | Self::ExtendedTelemetryDisable
                | Self::SpinDirectionNormal
                | Self::SpinDirectionReversed
        )
    }

    /// How many consecutive frames the command must be sent in: 6 for settings commands (the
    /// specification's minimum; Betaflight sends 10), 1 otherwise.
    pub const fn min_repeats(self) -> u8 {
        if self.changes_settings() {
            6
        } else {
            1
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Numbers of the DShot specification (Betaflight `dshotCommands_e`), pinned: they are what
    /// the ESC receives and what the wire carries.
    #[test]
    fn numbers_names_and_round_trips() {
        let pinned: [(DshotCommand, u16); 14] = [
            (DshotCommand::Beep1, 1),
            (DshotCommand::Beep5, 5),
            (DshotCommand::EscInfo, 6),
            (DshotCommand::SpinDirection1, 7),
            (DshotCommand::SpinDirection2, 8),
            (DshotCommand::ThreeDModeOff, 9),
            (DshotCommand::ThreeDModeOn, 10),
            (DshotCommand::SaveSettings, 12),
            (DshotCommand::ExtendedTelemetryEnable, 13),
            (DshotCommand::ExtendedTelemetryDisable, 14),
            (DshotCommand::SpinDirectionNormal, 20),
            (DshotCommand::SpinDirectionReversed, 21),
            (DshotCommand::Led3Off, 29),
            (DshotCommand::SilentModeToggle, 31),
        ];
        for (command, value) in pinned {
            assert_eq!(command.value(), value);
        }
        for command in DshotCommand::ALL {
            assert_eq!(DshotCommand::from_value(command.value() as u8), Some(command));
            assert_eq!(DshotCommand::from_name(command.name()), Some(command));
        }
        // Numbers 15..=19 and 32..=47 are reserved or not standard; 0 is motor stop.
        for value in [0u8, 15, 19, 32, 47, 48, 255] {
            assert_eq!(DshotCommand::from_value(value), None, "{value}");
        }
        assert_eq!(DshotCommand::from_name("BEEP3"), Some(DshotCommand::Beep3));
        assert_eq!(DshotCommand::from_name("beep6"), None);
    }
}
