//! `cargo xtask bench` (host, criterion) and `cargo xtask bench-m7` (QEMU Cortex-M7 counts).
//!
//! `bench-m7` builds the `bench-m7/` crate (outside the workspace) for `thumbv7em-none-eabihf`
//! with `-C target-cpu=cortex-m7`, runs it on QEMU's `mps2-an500` with one translation block per
//! instruction and an execution trace, and counts the trace lines between the two marker
//! functions `bench_region_start` / `bench_region_end` (addresses from the ELF symbol table).
//! The binary prints its region names over semihosting in the order it runs them; the first
//! region is empty and measures the marker overhead, which is subtracted from the others.
//! Counts are instructions, not cycles, and repeat exactly from run to run.

use crate::util::{cargo, on_path, root, run};
use anyhow::{bail, Context, Result};
use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

/// Criterion benchmarks of `flight` (thrust-axis solve at m = 4, 6, 8 against the dense f64
/// reference, and the bounded search). Extra arguments go to criterion (e.g. a filter).
pub fn host(args: &[String]) -> Result<()> {
    run(cargo().args(["bench", "--package", "flight", "--bench", "thrust_axis", "--"]).args(args))?;
    eprintln!("criterion reports: {}", root().join("target/criterion").display());
    Ok(())
}

/// QEMU machine and CPU with the same core (Cortex-M7 with its double-precision FPU) as the
/// STM32H743.
const QEMU: &str = "qemu-system-arm";
const QEMU_MACHINE: &str = "mps2-an500";
const QEMU_CPU: &str = "cortex-m7";
/// The bench binary's target and its rustflags (set through `RUSTFLAGS`, which replaces the
/// workspace's firmware flags for this target: flip-link and defmt are not used here). The code
/// generation flags are the firmware's (`.cargo/config.toml`, `[target.thumbv7em-none-eabihf]`):
/// keep the two in step.
const TARGET: &str = "thumbv7em-none-eabihf";
const RUSTFLAGS: &str = "-C link-arg=-Tlink.x -C target-cpu=cortex-m7 \
     -C llvm-args=-inline-threshold=50 -C llvm-args=-enable-machine-outliner=always \
     --cfg sha2_backend_soft=\"compact\"";
/// Semihosting line announcing a region, in run order.
const REGION_PREFIX: &str = "bench-m7 region: ";
/// Targets from issues 3, 7 and 8 (instructions), matched by region-name prefix.
const TARGETS: [(&str, u64); 7] = [
    ("thrust-axis solve m=4", 1_000),
    ("thrust-axis solve m=8", 4_000),
    ("imu-offset RLS update", 300),
    ("learner step m=4", 12_000),
    ("learner step m=8", 40_000),
    ("closed-loop step m=4", 12_000),
    ("closed-loop step m=8", 20_000),
];
/// The argument that adds the thrust-axis bounded search (the bench crate's feature of the same
/// name, which also compiles `flight` with it, unlike the firmware).
const BOUNDED_SEARCH_ARG: &str = "--bounded-search";
/// The argument that adds the learner without speed telemetry (the bench crate's feature
/// `no-speed`, which compiles `flight` with it, unlike the firmware).
const NO_SPEED_ARG: &str = "--no-speed";
/// Debian package that provides `qemu-system-arm`.
const QEMU_PACKAGE: &str = "qemu-system-arm";

/// Instruction counts on QEMU's Cortex-M7; prints a table. `--bounded-search` adds the
/// thrust-axis bounded-search regions and `--no-speed` the learner without speed telemetry (each
/// compiles `flight` with its feature, as the firmware does not).
pub fn m7(args: &[String]) -> Result<()> {
    let mut features = Vec::new();
    for arg in args {
        match arg.as_str() {
            BOUNDED_SEARCH_ARG => features.push("bounded-search"),
            NO_SPEED_ARG => features.push("no-speed"),
            other => bail!(
                "bench-m7: unknown argument `{other}` (usage: cargo xtask bench-m7 \
                 [{BOUNDED_SEARCH_ARG}] [{NO_SPEED_ARG}])"
            ),
        }
    }
    ensure_qemu()?;
    crate::build::ensure_target_installed()?;
    let crate_dir = root().join("bench-m7");
    // Its own target directory (a workspace of its own), under CARGO_TARGET_DIR when set.
    let target_dir = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) => root().join(dir).join("bench-m7"),
        None => crate_dir.join("target"),
    };
    let mut build = cargo();
    build
        .current_dir(&crate_dir)
        .args(["build", "--release", "--target", TARGET, "--target-dir"])
        .arg(&target_dir)
        .env("RUSTFLAGS", RUSTFLAGS)
        .env("CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER", "rust-lld");
    if !features.is_empty() {
        build.args(["--features", &features.join(",")]);
    }
    run(&mut build)?;
    let elf = target_dir.join(TARGET).join("release/bench-m7");

    let symbols = elf_symbols(&elf)?;
    let start = *symbols.get("bench_region_start").context("no bench_region_start in the ELF")?;
    let end = *symbols.get("bench_region_end").context("no bench_region_end in the ELF")?;

    // The trace goes to QEMU's stderr, a pipe counted as it streams: it is one line per
    // executed instruction (tens of GB for the whole run), never written to disk.
    let mut qemu = Command::new(QEMU);
    qemu.args(["-machine", QEMU_MACHINE, "-cpu", QEMU_CPU, "-icount", "shift=0", "-nographic"])
        .args(["-semihosting-config", "enable=on,target=native", "-kernel"])
        .arg(&elf)
        .args(["-d", "exec,nochain", "-singlestep", "-D", "/dev/stderr"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    eprintln!(
        "$ {QEMU} -machine {QEMU_MACHINE} -cpu {QEMU_CPU} -icount shift=0 -nographic \
         -semihosting-config enable=on,target=native -kernel {} -d exec,nochain -singlestep \
         -D /dev/stderr",
        elf.display()
    );
    let mut child = qemu.spawn().with_context(|| format!("could not start {QEMU}"))?;
    let mut stdout_pipe = child.stdout.take().context("no stdout pipe")?;
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        std::io::Read::read_to_string(&mut stdout_pipe, &mut text).map(|_| text)
    });
    let trace = BufReader::with_capacity(1 << 20, child.stderr.take().context("no stderr pipe")?);
    let counts = count_regions(trace, start, end)?;
    let status = child.wait()?;
    let stdout = reader.join().map_err(|_| anyhow::anyhow!("stdout reader panicked"))??;
    if !status.success() {
        bail!("the benchmark failed on QEMU ({status}):\n{stdout}");
    }
    let names: Vec<&str> = stdout.lines().filter_map(|l| l.strip_prefix(REGION_PREFIX)).collect();
    if counts.len() != names.len() || counts.is_empty() {
        bail!("{} regions announced but {} measured in the trace", names.len(), counts.len());
    }
    let overhead = counts[0];
    println!(
        "Cortex-M7 instruction counts (QEMU {QEMU_MACHINE}, -icount shift=0, one instruction per \
         trace line; marker overhead of {overhead} subtracted)\n"
    );
    println!("| region | instructions | target |");
    println!("|---|---:|---:|");
    for (name, count) in names.iter().zip(&counts).skip(1) {
        let net = count.saturating_sub(overhead);
        let target = TARGETS.iter().find(|(prefix, _)| name.starts_with(prefix));
        let verdict = match target {
            Some((_, limit)) if net <= *limit => format!("≤ {limit} ok"),
            Some((_, limit)) => format!("≤ {limit} OVER"),
            None => "—".to_string(),
        };
        println!("| {name} | {net} | {verdict} |");
    }
    for line in stdout.lines().filter(|l| l.starts_with("bench-m7 check:")) {
        println!("{line}");
    }
    Ok(())
}

/// Addresses (Thumb bit cleared) and sizes of the function symbols of a 32-bit little-endian
/// ELF, by name: `(address, size)`.
fn elf_symbols(path: &Path) -> Result<HashMap<String, (u32, u32)>> {
    let data = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let u16_at = |offset: usize| -> Result<u16> {
        let bytes = data.get(offset..offset + 2).context("truncated ELF")?;
        Ok(u16::from_le_bytes([bytes[0], bytes[1]]))
    };
    let u32_at = |offset: usize| -> Result<u32> {
        let bytes = data.get(offset..offset + 4).context("truncated ELF")?;
        Ok(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
    };
    if data.get(0..6) != Some(&[0x7f, b'E', b'L', b'F', 1, 1][..]) {
        bail!("{} is not a 32-bit little-endian ELF", path.display());
    }
    let section_offset = u32_at(0x20)? as usize;
    let section_size = u16_at(0x2E)? as usize;
    let sections = u16_at(0x30)? as usize;
    let header = |index: usize| section_offset + index * section_size;
    const SHT_SYMTAB: u32 = 2;
    let symtab = (0..sections)
        .find(|&i| u32_at(header(i) + 4).is_ok_and(|kind| kind == SHT_SYMTAB))
        .context("ELF has no symbol table")?;
    let (sym_offset, sym_size) = (u32_at(header(symtab) + 16)?, u32_at(header(symtab) + 20)?);
    let strtab = u32_at(header(symtab) + 24)? as usize;
    let str_offset = u32_at(header(strtab) + 16)? as usize;
    let mut symbols = HashMap::new();
    for entry in (sym_offset as usize..(sym_offset + sym_size) as usize).step_by(16) {
        let name_offset = str_offset + u32_at(entry)? as usize;
        let name_bytes = data.get(name_offset..).context("bad symbol name")?;
        let name_end = name_bytes.iter().position(|&b| b == 0).unwrap_or(name_bytes.len());
        let name = String::from_utf8_lossy(&name_bytes[..name_end]).into_owned();
        symbols.insert(name, (u32_at(entry + 4)? & !1, u32_at(entry + 8)?));
    }
    Ok(symbols)
}

/// For each execution of the start marker, the number of trace lines from the first
/// instruction after it returns up to (not including) the first instruction of the end marker.
fn count_regions(trace: impl BufRead, start: (u32, u32), end: (u32, u32)) -> Result<Vec<u64>> {
    let in_start = |pc: u32| pc >= start.0 && pc < start.0 + start.1.max(2);
    let mut counts = Vec::new();
    let mut inside_start = false;
    let mut counting: Option<u64> = None;
    for line in trace.split(b'\n') {
        let line = line?;
        let line = String::from_utf8_lossy(&line);
        // "Trace 0: 0x7f... [00800408/00000400/00000110/ff020201] symbol": the PC is field 2.
        let Some(pc) = line
            .split_once('[')
            .and_then(|(_, rest)| rest.split('/').nth(1))
            .and_then(|hex| u32::from_str_radix(hex, 16).ok())
        else {
            continue;
        };
        if in_start(pc) {
            inside_start = true;
            continue;
        }
        if inside_start {
            inside_start = false;
            counting = Some(0);
        }
        if let Some(count) = counting.as_mut() {
            if pc == end.0 {
                counts.push(*count);
                counting = None;
            } else {
                *count += 1;
            }
        }
    }
    Ok(counts)
}

/// Install QEMU with the distribution's package manager when it is missing (as `cargo xtask
/// test` installs its tools): `apt-get update` once, then `apt-get install -y qemu-system-arm`,
/// through `sudo` when not root.
fn ensure_qemu() -> Result<()> {
    if on_path(QEMU) {
        return Ok(());
    }
    if !on_path("apt-get") {
        bail!(
            "`{QEMU}` not found on PATH and there is no apt-get to install it: bench-m7 runs the \
             benchmark on QEMU's {QEMU_MACHINE} (Cortex-M7). Install the package providing \
             `{QEMU}` (Debian/Ubuntu: `{QEMU_PACKAGE}`; macOS: `brew install qemu`), then run \
             `cargo xtask bench-m7` again."
        );
    }
    let root_user = Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false);
    let apt = |args: &[&str]| {
        let mut command = if root_user { Command::new("apt-get") } else { Command::new("sudo") };
        if !root_user {
            command.arg("apt-get");
        }
        command.args(args).env("DEBIAN_FRONTEND", "noninteractive");
        command
    };
    eprintln!("bench-m7: `{QEMU}` is missing; installing the Debian package `{QEMU_PACKAGE}`");
    run(&mut apt(&["update"]))?;
    run(&mut apt(&["install", "-y", QEMU_PACKAGE]))?;
    if !on_path(QEMU) {
        bail!("installed `{QEMU_PACKAGE}` but `{QEMU}` is still not on PATH");
    }
    Ok(())
}
