//! The configurator library: link, commands, offline tools.
