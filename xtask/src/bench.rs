//! `cargo xtask bench` (host, criterion) and `cargo xtask bench-m7` (QEMU Cortex-M7 counts).

use anyhow::{bail, Result};

pub fn host(_args: &[String]) -> Result<()> {
    bail!("host benchmarks not wired yet")
}

pub fn m7(_args: &[String]) -> Result<()> {
    bail!("Cortex-M7 benchmarks not wired yet")
}
