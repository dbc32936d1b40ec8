//! The portable flight-controller application.
pub mod hal;
