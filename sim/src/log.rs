//! The configurator's CSV log, written by the simulator at the 2 kHz control rate.
//!
//! Logs from the simulator and from a board are read by the same tools, so the first seven
//! columns are fixed: `t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z` — time in s, angular rate in
//! rad/s and specific force in m/s², in IMU axes, exactly the 2 kHz samples the application
//! sees (with all sensor errors). The simulator then appends, for m motors:
//!
//! | columns | unit | meaning |
//! |---|---|---|
//! | `cmd_0 … cmd_{m−1}` | 1 | motor command δ ∈ [0, 1] held during the next period |
//! | `rpm_0 … rpm_{m−1}` | rev/min | RPM telemetry as the application reads it (DShot-quantised, delayed); empty when not reported |
//! | `true_omega_0 … true_omega_{m−1}` | rad/s | true rotor speeds |
//! | `true_gyro_x,y,z` | rad/s | error-free gyro reading, IMU axes (same averaging as the sample) |
//! | `true_acc_x,y,z` | m/s² | error-free specific force at the IMU, IMU axes (same averaging) |
//! | `true_rate_x,y,z` | rad/s | body rate Ω, body FRD axes |
//! | `true_pos_n,e,d` | m | CoG position, world NED (d = 0 is the ground) |
//! | `true_vel_n,e,d` | m/s | CoG velocity, world NED |
//! | `true_qw,qx,qy,qz` | 1 | attitude `q_world_body`, Hamilton |
//! | `hand` | — | 0 free, 1 holding, 2 throwing, 3 catching |
//!
//! A row is written after each control tick, with the commands the application has just set.

use std::f64::consts::TAU;
use std::io::{self, Write};

use firmware::app::hal::Motors;

use crate::board::SimBoard;

/// Writes the CSV log to any writer (buffer it: a row is a few hundred bytes, 2000 rows per s).
#[derive(Debug)]
pub struct CsvLog<W: Write> {
    out: W,
    rotor_count: usize,
    line: String,
}

impl<W: Write> CsvLog<W> {
    /// Writes the header for `rotor_count` motors.
    pub fn new(mut out: W, rotor_count: usize) -> io::Result<Self> {
        let mut header = String::from("t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z");
        for prefix in ["cmd", "rpm", "true_omega"] {
            for i in 0..rotor_count {
                header.push_str(&format!(",{prefix}_{i}"));
            }
        }
        header.push_str(
            ",true_gyro_x,true_gyro_y,true_gyro_z,true_acc_x,true_acc_y,true_acc_z\
             ,true_rate_x,true_rate_y,true_rate_z,true_pos_n,true_pos_e,true_pos_d\
             ,true_vel_n,true_vel_e,true_vel_d,true_qw,true_qx,true_qy,true_qz,hand",
        );
        writeln!(out, "{header}")?;
        Ok(Self { out, rotor_count, line: String::with_capacity(1024) })
    }

    /// Appends the row for the board's last tick.
    pub fn record(&mut self, board: &SimBoard) -> io::Result<()> {
        use std::fmt::Write as _;
        let line = &mut self.line;
        line.clear();
        let sample = board.last_sample();
        let _ = write!(line, "{:.6}", board.time_s());
        for v in sample.gyro_rad_s.iter().chain(sample.accel_mps2.iter()) {
            let _ = write!(line, ",{v}");
        }
        let motors = board.motors();
        for c in motors.commands() {
            let _ = write!(line, ",{c}");
        }
        let speeds = motors.speeds_rad_s();
        for s in speeds.iter().take(self.rotor_count) {
            match s {
                Some(w) => {
                    let _ = write!(line, ",{:.1}", f64::from(*w) * 60.0 / TAU);
                }
                None => line.push(','),
            }
        }
        let state = board.physics().state();
        for w in &state.rotor_speed_rad_s[..self.rotor_count] {
            let _ = write!(line, ",{w:.3}");
        }
        let truth = board.last_truth_sample();
        for v in truth
            .gyro_rad_s
            .iter()
            .chain(truth.accel_mps2.iter())
            .chain(state.rate_body_rad_s.iter())
            .chain(state.position_ned_m.iter())
            .chain(state.velocity_ned_mps.iter())
        {
            let _ = write!(line, ",{v:.7}");
        }
        let q = state.q_world_body;
        let _ = write!(line, ",{:.9},{:.9},{:.9},{:.9}", q.w, q.i, q.j, q.k);
        let _ = writeln!(line, ",{}", board.physics().hand().phase() as u8);
        self.out.write_all(line.as_bytes())
    }

    /// Flushes and returns the writer.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}
