//! Build script: hand `memory.x` and the linker scripts to the linker for the STM32H743 target.
//!
//! cortex-m-rt's `link.x` does `INCLUDE memory.x`, so the file must be on the linker's search
//! path. Host builds (the portable `app` tested on the PC, the simulator) need nothing here.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return;
    }
    let out_dir = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::copy("memory.x", out_dir.join("memory.x")).expect("copy memory.x into OUT_DIR");
    println!("cargo:rustc-link-search={}", out_dir.display());
    // Linker scripts for the firmware binary only (see `.cargo/config.toml` for why not there):
    // `--nmagic` keeps sections unaligned to pages (flash is not paged), `link.x` is
    // cortex-m-rt's (it includes `memory.x`), `defmt.x` places defmt's interned strings.
    // `--icf=all` folds functions whose machine code is identical (monomorphised copies of one
    // generic body, trivial trait methods) into one: about 1 KB of flash, no effect on speed;
    // Rust never relies on two functions having different addresses.
    for arg in ["--nmagic", "-Tlink.x", "-Tdefmt.x", "--icf=all"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
