//! Project automation (matklad's cargo-xtask pattern): `cargo xtask <command>`.
//!
//! One binary, no dependencies a user needs at run time. Each command lives in its own module.

mod bench;
mod build;
mod ci;
mod telemetry;
mod test_runner;
mod thirdparty;
mod util;

use std::process::ExitCode;

const USAGE: &str = "\
usage: cargo xtask <command> [args]

commands:
  test        install what the checks need, then fmt, clippy, host tests, no_std builds, firmware
  build       build the release firmware ELF for the STM32H743 and print flash and RAM use
              (--stack: worst-case stack per task); one image for every craft, with or
              without ESC speed telemetry (the parameter motor_bidir_dshot)
  flash       program a board through probe-rs, or through the ROM DFU bootloader (dfu-util)
              ([--dfu])
  sitl        run the configurator against the built-in simulator (the README's main job)
  telemetry   stream the SITL's 2 kHz state topic for 60 s (or SECONDS) and count gaps
  thirdparty  fly the firmware in RotorPy (a third-party simulator) through the bridge
  bench       host benchmarks (criterion)
  bench-m7    Cortex-M7 instruction counts under QEMU (mps2-an500)
";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(command) = args.first() else {
        eprint!("{USAGE}");
        return ExitCode::from(2);
    };
    let rest = &args[1..];
    let result = match command.as_str() {
        "test" | "ci" => ci::test(rest),
        "build" => build::build(rest).map(|_| ()),
        "flash" => build::flash(rest),
        "sitl" => ci::sitl(rest),
        "telemetry" => telemetry::telemetry(rest),
        "thirdparty" => thirdparty::thirdparty(rest),
        "bench" => bench::host(rest),
        "bench-m7" => bench::m7(rest),
        "-h" | "--help" | "help" => {
            print!("{USAGE}");
            Ok(())
        }
        other => {
            eprintln!("xtask: unknown command `{other}`\n\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("xtask: error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
