//! Offline commands: the same `flight` code the board runs, applied to recorded logs and files.
//!
//! Each command module exposes a clap `Args` struct and `run(&Args) -> Result<String, InputError>`.
//! The whole output is built before anything is printed, so bad input never leaves partial output.

pub mod imu_offset;
pub mod log_csv;
pub mod log_mcap;
pub mod replay;
pub mod thrust_axis;

/// Bad input to an offline command. The message names the problem (file, column, row, field);
/// the CLI prints it to stderr, prints nothing on stdout, and exits with code 2.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputError(pub String);

impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for InputError {}
