//! RPM telemetry as bidirectional DShot reports it.
//!
//! The ESC measures the electrical period of the motor (one electrical revolution = one
//! mechanical revolution / pole pairs) in whole microseconds and sends it back in a 16-bit
//! frame whose 12 payload bits are a 3-bit exponent `e` and a 9-bit mantissa `m`, the period
//! being `m << e` µs (the remaining 4 bits are a CRC, not modelled: frames are never corrupted
//! here). The flight controller turns the period into eRPM (Betaflight reports eRPM/100) and
//! divides by the pole pairs. Those encoding facts come from the Betaflight/BLHeli_32
//! bidirectional-DShot specification; the code is ours.
//!
//! The quantisation therefore has two steps: whole microseconds of period, then 9 significant
//! bits. At high speed the resolution of the speed is coarse (≈1 % at 30 000 RPM on 7 pole
//! pairs), at very low speed the period saturates and the motor reads as stopped.

use std::f64::consts::TAU;

/// The period value an ESC sends for a motor that is stopped (or slower than the longest
/// representable period): mantissa 511, exponent 7 (`0x1FF << 7 = 65408` µs).
pub const STOPPED_PERIOD_US: u32 = 0x1FF << 7;

/// Encodes a mechanical speed (rad/s) as the 12-bit exponent/mantissa payload of a telemetry
/// frame (`eee mmmmmmmmm`).
pub fn encode_speed(omega_rad_s: f64, pole_pairs: u32) -> u16 {
    let electrical_hz = omega_rad_s.abs() / TAU * pole_pairs as f64;
    let period_us = if electrical_hz > 0.0 { 1e6 / electrical_hz } else { f64::INFINITY };
    if period_us.is_nan() || period_us >= STOPPED_PERIOD_US as f64 {
        return encode_period(STOPPED_PERIOD_US);
    }
    encode_period(period_us as u32)
}

/// Packs a period in µs into exponent and mantissa, keeping the 9 most significant bits.
pub fn encode_period(period_us: u32) -> u16 {
    let mut exponent = 0u32;
    let mut mantissa = period_us;
    while mantissa > 0x1FF {
        mantissa >>= 1;
        exponent += 1;
    }
    if exponent > 7 {
        return ((7u16) << 9) | 0x1FF;
    }
    ((exponent as u16) << 9) | mantissa as u16
}

/// Decodes a 12-bit payload into the mechanical speed the flight controller would compute,
/// rad/s, or 0 for a stopped motor. Like Betaflight, it goes through eRPM/100 as an integer.
pub fn decode_speed(payload: u16, pole_pairs: u32) -> f64 {
    let period_us = ((payload & 0x1FF) as u32) << ((payload >> 9) & 0x7);
    if period_us == 0 || period_us >= STOPPED_PERIOD_US {
        return 0.0;
    }
    // eRPM/100, rounded to nearest, as an integer.
    let erpm_100 = (600_000 + period_us / 2) / period_us;
    let rpm = erpm_100 as f64 * 100.0 / pole_pairs as f64;
    rpm * TAU / 60.0
}

/// What the flight controller reads for a true speed: encode, then decode.
pub fn quantise_speed(omega_rad_s: f64, pole_pairs: u32) -> f64 {
    decode_speed(encode_speed(omega_rad_s, pole_pairs), pole_pairs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_error_is_within_the_encoding_resolution() {
        for rpm in [2_000.0, 10_000.0, 25_000.0, 40_000.0] {
            let omega = rpm * TAU / 60.0;
            let back = quantise_speed(omega, 7);
            // 9 significant bits of period plus whole microseconds and eRPM/100 rounding.
            let period_us = 60e6 / (rpm * 7.0);
            let rel_resolution = 1.0 / 256.0 + 1.0 / period_us + 100.0 / (rpm * 7.0);
            assert!(
                ((back - omega) / omega).abs() <= rel_resolution,
                "{rpm} RPM read as {} RPM",
                back * 60.0 / TAU
            );
        }
    }

    #[test]
    fn stopped_and_very_slow_motors_read_zero() {
        assert_eq!(quantise_speed(0.0, 7), 0.0);
        // 100 RPM on 7 pole pairs: period 85.7 ms, longer than the longest representable.
        assert_eq!(quantise_speed(100.0 * TAU / 60.0, 7), 0.0);
    }

    #[test]
    fn period_packing_keeps_nine_significant_bits() {
        assert_eq!(encode_period(511), 511);
        assert_eq!(encode_period(512), (1 << 9) | 256);
        assert_eq!(encode_period(1000), (1 << 9) | 500);
    }
}
