//! The configurator library: the link to a board or the SITL, the commands, the offline tools.
//!
//! - [`link`]: the protocol client (handshake, requests, telemetry);
//! - [`log_files`]: the board's flight logs over the link (list, download, delete);
//! - [`config`]: the board's parameters: get, set, dump, diff, apply;
//! - [`connect`]: finding and opening a board, a TCP endpoint or an in-process SITL;
//! - [`doctor`]: the bring-up check for a first power-up;
//! - [`compass`]: the guided compass calibration and the compass's report in words;
//! - [`identify`]: the guided throw-and-fly identification;
//! - [`land`]: the guided landing (the request, then the craft followed to its touchdown);
//! - [`keys`]: the link keys shared with boards, for signed requests over a radio;
//! - [`report`]: what the board says, in words with units, or as JSON;
//! - [`offline`]: the `flight` estimators applied to recorded logs and files;
//! - [`pose_relay`]: motion-capture poses forwarded to the board over its link;
//! - [`plot`]: recordings and calibration ellipsoids drawn to PNG or SVG;
//! - [`record`]: telemetry topics written to CSV;
//! - [`shell`]: the interactive shell (line editing, completion, history).

pub mod compass;
pub mod config;
pub mod connect;
pub mod doctor;
pub mod identify;
pub mod keys;
pub mod land;
pub mod link;
pub mod log_files;
pub mod offline;
pub mod plot;
pub mod pose_relay;
pub mod record;
pub mod report;
pub mod shell;
