//! Every message that crosses the link between the configurator and the flight controller.
#![cfg_attr(not(feature = "std"), no_std)]

/// USB vendor ID of the board's CDC-ACM interface: pid.codes' open-source VID.
pub const USB_VID: u16 = 0x1209;
/// USB product ID: pid.codes' test PID, used until the project is allocated its own.
pub const USB_PID: u16 = 0x0001;
