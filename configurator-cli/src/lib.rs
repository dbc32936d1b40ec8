//! The configurator library: the link to a board or the SITL, the commands, the offline tools.

pub mod offline;
