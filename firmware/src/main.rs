//! The STM32H743 firmware binary (RTIC). On the host this file builds to an empty program so
//! that `cargo build --workspace` works; the application itself is `firmware::app`.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("the firmware binary only runs on the STM32H743; run the simulator instead: cargo run -p sim --bin sitl");
}
