//! `cargo xtask build` and `cargo xtask flash`: the STM32H743 firmware.
//!
//! `build` installs what the cross build needs (the rustup target, flip-link), builds the
//! firmware ELF (cargo profile `firmware`: the release profile, its cold dependencies compiled
//! for size) and prints its flash and RAM use, read from the ELF's section headers by a small
//! reader below (no binutils needed); it fails when the image exceeds its 384 KiB flash budget
//! or links core's float formatting. One image for every craft (issue 56): with or without ESC
//! speed telemetry, chosen at run time by the parameter `motor_bidir_dshot`. `flash` programs a board through a debug probe (probe-rs) or
//! through the STM32's ROM DFU bootloader (dfu-util), and says what to install or connect when
//! neither is possible.

use crate::util;
use anyhow::{bail, ensure, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The firmware's target triple (Cortex-M7 with a single-precision FPU, hard-float ABI).
pub const TARGET: &str = "thumbv7em-none-eabihf";

/// The chip name probe-rs knows the board by (matches `.cargo/config.toml`'s runner).
const PROBE_RS_CHIP: &str = "STM32H743ZITx";

/// Internal flash of the STM32H743xI, bytes (RM0433: 2 banks × 1 MiB).
const FLASH_BYTES: u64 = 2 * 1024 * 1024;

/// DTCM, the RAM region of `firmware/memory.x`, bytes.
const RAM_BYTES: u64 = 128 * 1024;

/// Start of DTCM (RAM) in the address map.
const RAM_ORIGIN: u64 = 0x2000_0000;

/// AXI SRAM, the DMA-reachable `.axisram` region of `firmware/memory.x`, bytes.
const AXISRAM_BYTES: u64 = 512 * 1024;

/// Where the ROM DFU bootloader writes (start of flash bank 1).
const FLASH_ORIGIN: u32 = 0x0800_0000;

/// USB ID of the STM32 ROM DFU bootloader (STMicroelectronics, "STM Device in DFU Mode").
const DFU_VID_PID: &str = "0483:df11";

/// Sections that occupy flash: the vector table, code, constants, and the initial values of
/// `.data` (copied to RAM at start-up). `.gnu.sgstubs` is empty unless TrustZone is used.
const FLASH_SECTIONS: &[&str] = &[".vector_table", ".text", ".rodata", ".data", ".gnu.sgstubs"];

/// Sections that occupy DTCM statically.
const RAM_SECTIONS: &[&str] = &[".data", ".bss", ".uninit"];

/// The cargo profile of the firmware (root `Cargo.toml`: the release profile at opt-level 3, the
/// crates the control step and the learner never run at "z"; `bench-m7` mirrors it for `flight`).
pub const PROFILE: &str = "firmware";

/// Flash budget of the firmware image, bytes: three 128 KiB sectors of the H743's flash
/// (issue 56, which set it for one image with everything: the pilot's sticks, the landing, a
/// GNSS receiver, the identification with and without ESC speed telemetry; issue 31's two
/// sectors were full at 262,124 B before the landing, 265,580 B with it). The H743's bank 1
/// (1 MiB) holds it; docs/benchmarks.md, "Firmware size".
const FLASH_BUDGET_BYTES: u64 = 384 * 1024;

/// Symbol-name fragments of core's float formatting (`core::num::flt2dec`, Grisu and Dragon4),
/// about 15 KB of flash. The firmware never formats a float (defmt sends them raw); they are
/// linked when a panic message formats one, e.g. `f32::clamp` with bounds that are not constants
/// (its assertion prints both): use `flight::math::clamp` there.
const FLOAT_FORMATTING_SYMBOLS: &[&str] = &["flt2dec"];

/// Build the firmware ELF (profile [`PROFILE`]) and print its flash and RAM use; returns the
/// ELF's path. Fails when the image exceeds [`FLASH_BUDGET_BYTES`] or links float formatting
/// ([`FLOAT_FORMATTING_SYMBOLS`]), so CI catches either.
///
/// Extra `args` are passed to `cargo build` (e.g. `--features ...`).
///
/// `--stack` (not passed to cargo) adds the worst-case stack of every interrupt handler and of
/// `main` (init, idle), from the ELF's code: see [`stack_report`].
pub fn build(args: &[String]) -> Result<PathBuf> {
    ensure_target_installed()?;
    ensure_flip_link()?;
    let stack = args.iter().any(|arg| arg == STACK_ARG);

    let mut cargo = util::cargo();
    cargo.args(["build", "--profile", PROFILE, "-p", "firmware", "--bin", "firmware"]);
    cargo.args(["--target", TARGET]);
    cargo.args(registry_remaps());
    cargo.args(args.iter().filter(|arg| *arg != STACK_ARG));
    if std::env::var_os("DEFMT_LOG").is_none() {
        // defmt compiles out everything below `error` unless told otherwise.
        cargo.env("DEFMT_LOG", "info");
    }
    util::run(&mut cargo)?;

    let elf = target_dir().join(TARGET).join(PROFILE).join("firmware");
    ensure!(elf.is_file(), "the build succeeded but {} is missing", elf.display());
    let bytes = std::fs::read(&elf).with_context(|| format!("reading {}", elf.display()))?;
    let sections = elf32_sections(&bytes).with_context(|| format!("parsing {}", elf.display()))?;
    let used = MemoryUse::of(&sections);
    print!("{}", used.report(&elf));
    if stack {
        print!("{}", stack_report(&bytes, &sections, used.stack_bytes)?);
    }
    check_budget(used.flash_bytes, FLASH_BUDGET_BYTES)?;
    let formatting = float_formatting_symbols(&bytes)?;
    ensure!(
        formatting.is_empty(),
        "the firmware links core's float formatting (about 15 KB of flash), through {}: a panic \
         message formats a float somewhere (e.g. `f32::clamp` with bounds that are not constants: \
         use `flight::math::clamp`); `llvm-objdump -d` on {} shows the caller",
        formatting.join(", "),
        elf.display()
    );
    Ok(elf)
}

/// Fails when `init` or the running tasks nested (see [`stack_report`]) need more stack than
/// the `free_bytes` below the statics: flip-link would turn the overflow into a fault at boot
/// or in flight.
fn check_stack(init_bytes: u64, running_bytes: u64, free_bytes: u64) -> Result<()> {
    ensure!(
        init_bytes <= free_bytes,
        "init needs {init_bytes} B of stack, {free_bytes} B are free: the board would fault \
         before its first task (a large value built on the stack and moved? build it in place, \
         flight::slot::Slot)"
    );
    ensure!(
        running_bytes <= free_bytes,
        "idle under every handler nested needs {running_bytes} B of stack, {free_bytes} B are \
         free"
    );
    Ok(())
}

/// Fails when the image does not fit `budget_bytes` ([`FLASH_BUDGET_BYTES`]).
fn check_budget(flash_bytes: u64, budget_bytes: u64) -> Result<()> {
    ensure!(
        flash_bytes <= budget_bytes,
        "the firmware uses {flash_bytes} B of flash, over its budget of {budget_bytes} B \
         ({} KiB, {} flash sectors) by {} B: see docs/benchmarks.md, \"Firmware size\", for \
         what takes the space and what was done",
        budget_bytes / 1024,
        budget_bytes / (128 * 1024),
        flash_bytes - budget_bytes
    );
    Ok(())
}

/// The names of the ELF's symbols that belong to core's float formatting
/// ([`FLOAT_FORMATTING_SYMBOLS`]), sorted.
fn float_formatting_symbols(elf: &[u8]) -> Result<Vec<String>> {
    let mut found: Vec<String> = elf32_symbol_names(elf)?
        .into_iter()
        .filter(|name| FLOAT_FORMATTING_SYMBOLS.iter().any(|part| name.contains(part)))
        .collect();
    found.sort();
    found.dedup();
    Ok(found)
}
/// `--config` arguments that strip the cargo registry's source directories from the paths
/// compiled into the firmware (`--remap-path-prefix`, appended to `.cargo/config.toml`'s
/// rustflags for [`TARGET`]): every panic location carries its file's name in flash, and
/// `~/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/nalgebra-0.35.0/src/base/blas.rs`
/// becomes `nalgebra-0.35.0/src/base/blas.rs`: about 1.9 KB of flash for 32 files. The prefix
/// depends on the machine, so it cannot be written in `.cargo/config.toml`. No effect on code.
fn registry_remaps() -> Vec<String> {
    let cargo_home = match std::env::var_os("CARGO_HOME") {
        Some(dir) => PathBuf::from(dir),
        None => match std::env::var_os("HOME").or_else(|| std::env::var_os("USERPROFILE")) {
            Some(home) => PathBuf::from(home).join(".cargo"),
            None => return Vec::new(),
        },
    };
    let Ok(entries) = std::fs::read_dir(cargo_home.join("registry").join("src")) else {
        return Vec::new();
    };
    let mut dirs: Vec<PathBuf> =
        entries.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.is_dir()).collect();
    dirs.sort();
    dirs.iter()
        .filter_map(|dir| dir.to_str())
        // A TOML literal string cannot hold a single quote; such a directory keeps its paths.
        .filter(|dir| !dir.contains('\''))
        .flat_map(|dir| {
            let separator = std::path::MAIN_SEPARATOR;
            [
                "--config".to_string(),
                format!("target.{TARGET}.rustflags=['--remap-path-prefix={dir}{separator}=']"),
            ]
        })
        .collect()
}

/// The `build` argument that adds the stack analysis.
pub const STACK_ARG: &str = "--stack";

/// Program a board: `cargo xtask flash` through a debug probe with probe-rs, or
/// `cargo xtask flash --dfu` through the ROM DFU bootloader with dfu-util.
pub fn flash(args: &[String]) -> Result<()> {
    let mut dfu = false;
    for arg in args {
        match arg.as_str() {
            "--dfu" => dfu = true,
            other => bail!("flash: unknown argument `{other}` (usage: cargo xtask flash [--dfu])"),
        }
    }
    // Check the tool and the device before the (long) build, so a missing one fails fast.
    if dfu {
        require_tool(
            "dfu-util",
            "install dfu-util (Debian/Ubuntu: `sudo apt-get install dfu-util`, macOS: \
             `brew install dfu-util`), then start the board in DFU mode (hold its BOOT button \
             while plugging in USB) and retry; or flash through a debug probe: `cargo xtask flash`",
        )?;
        require_dfu_device()?;
    } else {
        require_tool(
            "probe-rs",
            "install probe-rs (`cargo install probe-rs-tools --locked`, see https://probe.rs) and \
             connect an ST-LINK, J-Link or CMSIS-DAP debug probe to the board's SWD pins; or, \
             without a probe, use the ROM bootloader over USB: `cargo xtask flash --dfu` (needs \
             dfu-util and the board in DFU mode)",
        )?;
        require_probe()?;
    }

    let elf = build(&[])?;
    if dfu {
        let bin = elf.with_extension("bin");
        let image = elf_to_flash_image(&std::fs::read(&elf)?)?;
        ensure!(
            image.load_address == FLASH_ORIGIN,
            "the image starts at {:#010x}, not at flash ({FLASH_ORIGIN:#010x})",
            image.load_address
        );
        std::fs::write(&bin, &image.bytes).with_context(|| format!("writing {}", bin.display()))?;
        eprintln!("wrote {} ({} bytes)", bin.display(), image.bytes.len());
        util::run(
            Command::new("dfu-util")
                .args(["-d", DFU_VID_PID, "-a", "0", "-s"])
                .arg(format!("{FLASH_ORIGIN:#010x}:leave"))
                .arg("-D")
                .arg(&bin),
        )
    } else {
        util::run(Command::new("probe-rs").args(["download", "--chip", PROBE_RS_CHIP]).arg(&elf))?;
        util::run(Command::new("probe-rs").args(["reset", "--chip", PROBE_RS_CHIP]))?;
        eprintln!(
            "flashed; to see the defmt log: probe-rs attach --chip {PROBE_RS_CHIP} {}",
            elf.display()
        );
        Ok(())
    }
}

/// `rustup target add` the firmware target unless it is installed already.
pub(crate) fn ensure_target_installed() -> Result<()> {
    let output = Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output()
        .context("could not run `rustup`: install Rust through https://rustup.rs")?;
    let installed = String::from_utf8_lossy(&output.stdout);
    if output.status.success() && installed.lines().any(|line| line.trim() == TARGET) {
        return Ok(());
    }
    util::run(Command::new("rustup").args(["target", "add", TARGET]))
}

/// `cargo install flip-link` unless it is on PATH (it is the firmware's linker).
pub(crate) fn ensure_flip_link() -> Result<()> {
    if util::on_path("flip-link") {
        return Ok(());
    }
    util::run(util::cargo().args(["install", "flip-link", "--locked"]))
}

/// The cargo target directory (honours `CARGO_TARGET_DIR`).
fn target_dir() -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) => {
            let dir = PathBuf::from(dir);
            if dir.is_absolute() {
                dir
            } else {
                util::root().join(dir)
            }
        }
        None => util::root().join("target"),
    }
}

fn require_tool(program: &str, how_to_install: &str) -> Result<()> {
    if util::on_path(program) {
        Ok(())
    } else {
        bail!("`{program}` is not on PATH: {how_to_install}")
    }
}

/// Fail unless probe-rs sees at least one debug probe.
fn require_probe() -> Result<()> {
    let output =
        Command::new("probe-rs").arg("list").output().context("could not run `probe-rs list`")?;
    let text = String::from_utf8_lossy(&output.stdout);
    let found = output.status.success()
        && !text.contains("No debug probes were found")
        && text.lines().any(|line| line.trim_start().starts_with('['));
    if !found {
        bail!(
            "no debug probe found: connect an ST-LINK/J-Link/CMSIS-DAP probe to the board's SWD pins \
             (and check udev permissions), or flash over USB with the ROM bootloader: \
             `cargo xtask flash --dfu`"
        );
    }
    Ok(())
}

/// Fail unless dfu-util sees the STM32 ROM bootloader.
fn require_dfu_device() -> Result<()> {
    let output =
        Command::new("dfu-util").arg("-l").output().context("could not run `dfu-util -l`")?;
    // Versions differ in which stream lists the devices: look at both.
    let text = String::from_utf8_lossy(&output.stdout) + String::from_utf8_lossy(&output.stderr);
    if !text.contains(&format!("[{DFU_VID_PID}]")) {
        bail!(
            "no STM32 DFU device ({DFU_VID_PID}) found: hold the board's BOOT button while plugging \
             in USB so the ROM bootloader starts (and check udev permissions), then retry"
        );
    }
    Ok(())
}

/// Bytes the core pushes on exception entry with the FPU context (Cortex-M7, lazy stacking
/// reserves it whenever the interrupted code has used the FPU): 26 words plus the alignment
/// word (ARMv7-M ARM, B1.5.7). Without FPU context it is 8 words.
const EXCEPTION_FRAME_FPU_BYTES: u64 = 104;

/// One function of the disassembly, for the stack analysis.
#[derive(Clone, Debug, Default)]
struct Function {
    name: String,
    start: u64,
    /// Bytes its own code moves the stack pointer down by, summed over every `push`, `vpush`,
    /// `sub sp` and pre-indexed store to `sp` in its body (an upper bound of its frame: a
    /// function with two exits that each push counts both).
    frame_bytes: u64,
    /// Addresses it calls (`bl`, `blx #imm`) or branches to outside itself (tail calls).
    targets: Vec<u64>,
    /// Calls through a register (`blx rN`, `bx rN` other than `lr`): their callees are unknown.
    indirect_calls: u32,
    /// The stack pointer moved by a register amount (a dynamic allocation): frame unknown.
    dynamic: bool,
}

/// The worst path from one function.
#[derive(Clone, Debug, Default)]
struct StackPath {
    bytes: u64,
    /// Function indices from the root down.
    path: Vec<usize>,
}

/// Worst-case stack per root of `elf`, from its disassembly (`llvm-objdump`, from rustup's
/// `llvm-tools`): each function's frame from its stack adjustments, the call graph from its
/// `bl` and tail branches, the longest path from each interrupt handler of the vector table and
/// from `main` (init, then idle). Indirect calls (through a function pointer or a trait object)
/// and recursion cannot be followed: they are counted and reported, not bounded. A second
/// column leaves out paths into the panic handler (a panic ends the flight; its stack is
/// needed once, at the end).
fn stack_report(elf: &[u8], sections: &[Section], free_bytes: u64) -> Result<String> {
    let functions = disassembled_functions(&llvm_objdump_disassembly(elf)?);
    ensure!(!functions.is_empty(), "llvm-objdump listed no functions");
    let index_of = |address: u64| -> Option<usize> {
        let i = functions.partition_point(|f| f.start <= address);
        i.checked_sub(1)
    };
    // Call edges as function indices (branches within a function are not edges). A call or a
    // tail call lands on a function's first instruction; a "branch" into the middle of another
    // function is data decoded as code (the literal words after a `udf` that ends a panic
    // handler decode as `bmi`), not an edge.
    let edges: Vec<Vec<usize>> = functions
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let mut callees: Vec<usize> = f
                .targets
                .iter()
                .filter_map(|&t| index_of(t).filter(|&k| functions[k].start == t))
                .filter(|&callee| callee != i)
                .collect();
            callees.sort_unstable();
            callees.dedup();
            callees
        })
        .collect();
    // core's panic entry points (`panic_bounds_check`, `unwrap_failed`, `len_mismatch_fail`, ...)
    // and the handler.
    let is_panic = |i: usize| {
        let name = short_name(&functions[i].name);
        name.contains("panic")
            || name.contains("rust_begin_unwind")
            || name.ends_with("_fail")
            || name.ends_with("_failed")
    };

    let mut roots: Vec<(String, usize)> = Vec::new();
    if let Some(main) = functions.iter().position(|f| f.name == "main") {
        roots.push(("main (init, then idle)".into(), main));
    }
    if let Some(idle) = functions.iter().position(|f| short_name(&f.name).ends_with("::idle")) {
        roots.push((format!("{} (from main)", short_name(&functions[idle].name)), idle));
    }
    let table = sections
        .iter()
        .find(|s| s.name == ".vector_table")
        .context("the ELF has no .vector_table")?;
    let from = table.file_offset as usize;
    let words =
        elf.get(from..from + table.size_bytes as usize).context("vector table truncated")?;
    for (number, word) in words.chunks_exact(4).enumerate().skip(2) {
        let address = u64::from(u32::from_le_bytes([word[0], word[1], word[2], word[3]]) & !1);
        if let Some(i) = index_of(address).filter(|&i| functions[i].start == address) {
            let name = &functions[i].name;
            let default = name.contains("DefaultHandler") || name.contains("HardFault");
            if !default && !roots.iter().any(|(_, r)| *r == i) {
                let irq = if number >= 16 {
                    format!("IRQ {}", number - 16)
                } else {
                    format!("exception {number}")
                };
                roots.push((format!("{} ({irq})", short_name(name)), i));
            }
        }
    }

    let mut out = format!(
        "\nworst-case stack per root (own code; add the exception frame, \
         {EXCEPTION_FRAME_FPU_BYTES} B with FPU context, per interrupt level):\n"
    );
    out.push_str("| root | stack, B | without the panic path, B | indirect calls reached | recursion | worst path |\n");
    out.push_str("|---|---:|---:|---:|---|---|\n");
    // `main`'s worst is `init`'s, before any interrupt is enabled; afterwards idle runs under
    // every interrupt, each level nested at most once (the worst every handler reaches, with its
    // exception frame).
    let (mut init_bytes, mut idle_bytes, mut handlers_bytes) = (0, 0, 0);
    for (label, root) in roots {
        let mut all = Search::new(&functions, &edges, |_| false);
        let worst = all.worst(root);
        let mut quiet = Search::new(&functions, &edges, is_panic);
        let no_panic = quiet.worst(root);
        let indirect: u32 = all.reached.iter().map(|&i| functions[i].indirect_calls).sum();
        let dynamic = all.reached.iter().any(|&i| functions[i].dynamic);
        let path: Vec<String> = no_panic
            .path
            .iter()
            .map(|&i| format!("{} ({})", short_name(&functions[i].name), functions[i].frame_bytes))
            .collect();
        if functions[root].name == "main" {
            init_bytes = worst.bytes;
        } else if label.ends_with("(from main)") {
            idle_bytes = worst.bytes;
        } else {
            handlers_bytes += worst.bytes + EXCEPTION_FRAME_FPU_BYTES;
        }
        out.push_str(&format!(
            "| {label} | {}{} | {} | {indirect} | {} | {} |\n",
            worst.bytes,
            if dynamic { " + dynamic" } else { "" },
            no_panic.bytes,
            match all.recursion {
                Some((caller, callee)) => format!(
                    "cut: {} → {}",
                    short_name(&functions[caller].name),
                    short_name(&functions[callee].name)
                ),
                None => "no".into(),
            },
            path.join(" → ")
        ));
    }
    let running_bytes = idle_bytes + handlers_bytes;
    out.push_str(&format!(
        "\nstack: init {init_bytes} B; idle under every handler nested {running_bytes} B; \
         {free_bytes} B free\n"
    ));
    check_stack(init_bytes, running_bytes, free_bytes)?;
    Ok(out)
}

/// Depth-first longest path over the call graph, memoised; back edges (recursion) are cut.
struct Search<'a, F: Fn(usize) -> bool> {
    functions: &'a [Function],
    edges: &'a [Vec<usize>],
    skip: F,
    memo: Vec<Option<StackPath>>,
    on_path: Vec<bool>,
    /// The first back edge found (caller, callee).
    recursion: Option<(usize, usize)>,
    reached: Vec<usize>,
}

impl<'a, F: Fn(usize) -> bool> Search<'a, F> {
    fn new(functions: &'a [Function], edges: &'a [Vec<usize>], skip: F) -> Self {
        let n = functions.len();
        Search {
            functions,
            edges,
            skip,
            memo: vec![None; n],
            on_path: vec![false; n],
            recursion: None,
            reached: Vec::new(),
        }
    }

    fn worst(&mut self, i: usize) -> StackPath {
        if let Some(known) = &self.memo[i] {
            return known.clone();
        }
        self.on_path[i] = true;
        self.reached.push(i);
        let mut deepest = StackPath::default();
        for &callee in &self.edges[i] {
            if (self.skip)(callee) {
                continue;
            }
            if self.on_path[callee] {
                self.recursion.get_or_insert((i, callee));
                continue;
            }
            let below = self.worst(callee);
            if below.bytes > deepest.bytes || deepest.path.is_empty() {
                deepest = below;
            }
        }
        self.on_path[i] = false;
        let mut path = vec![i];
        path.extend(deepest.path);
        let result = StackPath { bytes: self.functions[i].frame_bytes + deepest.bytes, path };
        self.memo[i] = Some(result.clone());
        result
    }
}

/// A demangled name without its hash suffix (`::h0123456789abcdef`).
fn short_name(name: &str) -> &str {
    match name.rfind("::h") {
        Some(at) if name.len() - at == 19 => &name[..at],
        _ => name,
    }
}

/// `llvm-objdump -d --demangle` of `elf`, with rustup's llvm-tools (or one on PATH).
fn llvm_objdump_disassembly(elf: &[u8]) -> Result<String> {
    let sysroot = Command::new("rustc").args(["--print", "sysroot"]).output().ok();
    let host = Command::new("rustc").arg("-vV").output().ok().and_then(|o| {
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .find_map(|l| l.strip_prefix("host: ").map(str::to_owned))
    });
    let bundled = match (sysroot, host) {
        (Some(sysroot), Some(host)) => {
            let root = PathBuf::from(String::from_utf8_lossy(&sysroot.stdout).trim());
            Some(root.join("lib/rustlib").join(host).join("bin/llvm-objdump"))
        }
        _ => None,
    };
    let objdump = match bundled {
        Some(path) if path.is_file() => path,
        _ if util::on_path("llvm-objdump") => PathBuf::from("llvm-objdump"),
        _ => bail!("the stack analysis needs llvm-objdump: `rustup component add llvm-tools`"),
    };
    let file = std::env::temp_dir().join(format!("xtask-stack-{}.elf", std::process::id()));
    std::fs::write(&file, elf).with_context(|| format!("writing {}", file.display()))?;
    let output = Command::new(&objdump)
        // The core named: without it an llvm-objdump that does not read the ELF's build
        // attributes (LLVM 14, a distribution's) decodes no floating-point instruction, loses
        // the instruction stream after each and missed frames (the in-flight fit's 45 KB).
        .args(["-d", "--no-show-raw-insn", "--demangle", "--mcpu=cortex-m7"])
        .arg(&file)
        .output()
        .with_context(|| format!("could not run {}", objdump.display()));
    let _ = std::fs::remove_file(&file);
    let output = output?;
    ensure!(
        output.status.success(),
        "{} failed: {}",
        objdump.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    Ok(String::from_utf8_lossy(&output.stdout).into_owned())
}

/// Parse `llvm-objdump -d --no-show-raw-insn` output (Thumb-2) into functions, sorted by
/// address.
fn disassembled_functions(text: &str) -> Vec<Function> {
    let mut functions: Vec<Function> = Vec::new();
    for line in text.lines() {
        // "08000298 <name>:" starts a function.
        if let Some((address, rest)) = line.split_once(" <") {
            if let (Ok(start), Some(name)) =
                (u64::from_str_radix(address, 16), rest.strip_suffix(">:"))
            {
                if !name.starts_with('$') {
                    functions.push(Function {
                        name: name.to_owned(),
                        start,
                        ..Function::default()
                    });
                }
                continue;
            }
        }
        // " 80002fc:      \tsub.w\tsp, sp, #0x500" is an instruction.
        let Some(function) = functions.last_mut() else { continue };
        let Some((_, instruction)) = line.trim_start().split_once(':') else { continue };
        let mut fields = instruction.split('\t').map(str::trim).filter(|f| !f.is_empty());
        let (Some(mnemonic), operands) = (fields.next(), fields.next().unwrap_or("")) else {
            continue;
        };
        let operands = operands.split(" @").next().unwrap_or("").trim();
        let base = mnemonic.trim_end_matches(".w");
        match base {
            "push" | "vpush" => function.frame_bytes += register_list_bytes(operands),
            "stmdb" | "stmfd" if operands.starts_with("sp!") => {
                function.frame_bytes += register_list_bytes(operands)
            }
            "sub" | "subw" if operands.starts_with("sp,") => match operands.rsplit_once('#') {
                Some((_, imm)) => function.frame_bytes += parse_imm(imm).unwrap_or(0),
                None => function.dynamic = true,
            },
            "bl" | "blx" | "b" | "bx" | "beq" | "bne" | "bhs" | "blo" | "bmi" | "bpl" | "bvs"
            | "bvc" | "bhi" | "bls" | "bge" | "blt" | "bgt" | "ble" | "bcs" | "bcc" => {
                if let Some(target) = operands.strip_prefix("0x").and_then(|t| {
                    u64::from_str_radix(t.split_whitespace().next().unwrap_or(""), 16).ok()
                }) {
                    // Branches within the function are dropped once its end is known.
                    function.targets.push(target);
                } else if (base == "blx" || base == "bx") && operands != "lr" {
                    function.indirect_calls += 1;
                }
            }
            _ if base.starts_with("str")
                && operands.contains("[sp, #-")
                && operands.ends_with("]!") =>
            {
                let imm = operands.rsplit_once("#-").map(|(_, v)| v.trim_end_matches("]!"));
                function.frame_bytes += imm.and_then(parse_imm).unwrap_or(0);
            }
            _ => {}
        }
    }
    functions.sort_by_key(|f| f.start);
    // Keep only branches that leave the function (calls and tail calls).
    let ends: Vec<u64> = functions.iter().skip(1).map(|f| f.start).chain([u64::MAX]).collect();
    for (function, end) in functions.iter_mut().zip(ends) {
        let start = function.start;
        function.targets.retain(|&t| t < start || t >= end);
    }
    functions
}

/// Bytes pushed by a register list such as `{r4, r5, r6, r7, lr}`, `{r4-r11}` or `{d8-d9}`.
fn register_list_bytes(operands: &str) -> u64 {
    let Some(list) = operands.split_once('{').and_then(|(_, l)| l.split_once('}')).map(|(l, _)| l)
    else {
        return 0;
    };
    list.split(',')
        .map(str::trim)
        .map(|register| {
            let width = if register.starts_with('d') { 8 } else { 4 };
            let count = match register.split_once('-') {
                Some((first, last)) => {
                    let number = |r: &str| {
                        r.trim_start_matches(|c: char| c.is_alphabetic()).parse::<u64>().ok()
                    };
                    match (number(first), number(last)) {
                        (Some(a), Some(b)) if b >= a => b - a + 1,
                        _ => 1,
                    }
                }
                None => 1,
            };
            width * count
        })
        .sum()
}

/// `0x18` or `24`.
fn parse_imm(text: &str) -> Option<u64> {
    let text = text.trim();
    match text.strip_prefix("0x") {
        Some(hex) => u64::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

/// One section header of an ELF32 file: the fields this tool needs.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Section {
    name: String,
    /// Virtual (run-time) address.
    address: u64,
    size_bytes: u64,
    /// Where its bytes are in the file (meaningless for `NOBITS` sections such as `.bss`).
    file_offset: u64,
    /// `SHF_ALLOC`: the section occupies memory on the target.
    allocated: bool,
}

/// One loadable segment (`PT_LOAD` program header) of an ELF32 file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Segment {
    /// Load (physical) address: where the bytes are stored in flash.
    physical_address: u32,
    file_offset: u32,
    file_bytes: u32,
}

/// Little-endian field reader over an ELF file with bounds checks.
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn u16(&self, offset: usize) -> Result<u16> {
        let bytes = self.0.get(offset..offset + 2).context("ELF truncated")?;
        Ok(u16::from_le_bytes([bytes[0], bytes[1]]))
    }
    fn u32(&self, offset: usize) -> Result<u32> {
        let bytes = self.0.get(offset..offset + 4).context("ELF truncated")?;
        Ok(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
    }
}

/// Check the ELF identification: 32-bit, little-endian (what every Cortex-M ELF is).
fn check_elf32_le(elf: &[u8]) -> Result<()> {
    ensure!(elf.len() >= 52 && elf[..4] == *b"\x7fELF", "not an ELF file");
    ensure!(elf[4] == 1, "not a 32-bit ELF (EI_CLASS = {})", elf[4]);
    ensure!(elf[5] == 1, "not a little-endian ELF (EI_DATA = {})", elf[5]);
    Ok(())
}

/// Read the section headers of a little-endian ELF32 file (System V ABI, "Sections").
fn elf32_sections(elf: &[u8]) -> Result<Vec<Section>> {
    check_elf32_le(elf)?;
    let r = Reader(elf);
    let table_offset = r.u32(0x20)? as usize; // e_shoff
    let entry_bytes = usize::from(r.u16(0x2E)?); // e_shentsize
    let count = usize::from(r.u16(0x30)?); // e_shnum
    let names_index = usize::from(r.u16(0x32)?); // e_shstrndx
    ensure!(entry_bytes >= 40, "section header entries of {entry_bytes} bytes");
    ensure!(names_index < count, "section-name table index {names_index} out of {count}");

    let header = |index: usize| table_offset + index * entry_bytes;
    let names_offset = r.u32(header(names_index) + 16)? as usize; // sh_offset
    let names_size = r.u32(header(names_index) + 20)? as usize; // sh_size
    let names =
        elf.get(names_offset..names_offset + names_size).context("section names truncated")?;

    let mut sections = Vec::with_capacity(count);
    for index in 0..count {
        let base = header(index);
        let name_offset = r.u32(base)? as usize; // sh_name
        let name_bytes = names.get(name_offset..).context("section name out of range")?;
        let name_end = name_bytes.iter().position(|&b| b == 0).unwrap_or(name_bytes.len());
        const SHF_ALLOC: u32 = 0x2;
        sections.push(Section {
            name: String::from_utf8_lossy(&name_bytes[..name_end]).into_owned(),
            allocated: r.u32(base + 8)? & SHF_ALLOC != 0, // sh_flags
            address: u64::from(r.u32(base + 12)?),        // sh_addr
            file_offset: u64::from(r.u32(base + 16)?),    // sh_offset
            size_bytes: u64::from(r.u32(base + 20)?),     // sh_size
        });
    }
    Ok(sections)
}

/// The names of the symbols in a little-endian ELF32 file's symbol table (`SHT_SYMTAB`, its
/// names in the string table its `sh_link` names; System V ABI, "Symbol Table"), mangled.
fn elf32_symbol_names(elf: &[u8]) -> Result<Vec<String>> {
    check_elf32_le(elf)?;
    let r = Reader(elf);
    let table_offset = r.u32(0x20)? as usize; // e_shoff
    let entry_bytes = usize::from(r.u16(0x2E)?); // e_shentsize
    let count = usize::from(r.u16(0x30)?); // e_shnum
    ensure!(entry_bytes >= 40, "section header entries of {entry_bytes} bytes");
    let header = |index: usize| table_offset + index * entry_bytes;
    const SHT_SYMTAB: u32 = 2;
    const SYMBOL_BYTES: usize = 16; // Elf32_Sym
    let mut names = Vec::new();
    for index in 0..count {
        if r.u32(header(index) + 4)? != SHT_SYMTAB {
            continue;
        }
        let symbols_offset = r.u32(header(index) + 16)? as usize; // sh_offset
        let symbols_size = r.u32(header(index) + 20)? as usize; // sh_size
        let strings_index = r.u32(header(index) + 24)? as usize; // sh_link
        ensure!(strings_index < count, "symbol-name table index {strings_index} out of {count}");
        let strings_offset = r.u32(header(strings_index) + 16)? as usize;
        let strings_size = r.u32(header(strings_index) + 20)? as usize;
        let strings = elf
            .get(strings_offset..strings_offset + strings_size)
            .context("symbol names truncated")?;
        for entry in (0..symbols_size / SYMBOL_BYTES).map(|i| symbols_offset + i * SYMBOL_BYTES) {
            let name_offset = r.u32(entry)? as usize; // st_name
            let bytes = strings.get(name_offset..).context("symbol name out of range")?;
            let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
            if end > 0 {
                names.push(String::from_utf8_lossy(&bytes[..end]).into_owned());
            }
        }
    }
    Ok(names)
}

/// Read the loadable segments of a little-endian ELF32 file (System V ABI, "Program Header").
fn elf32_load_segments(elf: &[u8]) -> Result<Vec<Segment>> {
    check_elf32_le(elf)?;
    let r = Reader(elf);
    let table_offset = r.u32(0x1C)? as usize; // e_phoff
    let entry_bytes = usize::from(r.u16(0x2A)?); // e_phentsize
    let count = usize::from(r.u16(0x2C)?); // e_phnum
    ensure!(count == 0 || entry_bytes >= 32, "program header entries of {entry_bytes} bytes");
    const PT_LOAD: u32 = 1;
    let mut segments = Vec::new();
    for index in 0..count {
        let base = table_offset + index * entry_bytes;
        if r.u32(base)? != PT_LOAD {
            continue;
        }
        let segment = Segment {
            file_offset: r.u32(base + 4)?,       // p_offset
            physical_address: r.u32(base + 12)?, // p_paddr
            file_bytes: r.u32(base + 16)?,       // p_filesz
        };
        if segment.file_bytes > 0 {
            segments.push(segment);
        }
    }
    Ok(segments)
}

/// A raw flash image, what `objcopy -O binary` produces: the loadable bytes at their load
/// addresses, gaps filled with 0xFF (erased flash).
struct FlashImage {
    load_address: u32,
    bytes: Vec<u8>,
}

/// Convert an ELF to a raw image for the DFU bootloader (equivalent to `rust-objcopy -O binary`,
/// without needing cargo-binutils and llvm-tools installed).
fn elf_to_flash_image(elf: &[u8]) -> Result<FlashImage> {
    let segments = elf32_load_segments(elf)?;
    let start =
        segments.iter().map(|s| s.physical_address).min().context("ELF has nothing to load")?;
    let end = segments
        .iter()
        .map(|s| u64::from(s.physical_address) + u64::from(s.file_bytes))
        .max()
        .unwrap_or(u64::from(start));
    let length = usize::try_from(end - u64::from(start))?;
    ensure!(length as u64 <= FLASH_BYTES, "image of {length} bytes does not fit in flash");
    let mut bytes = vec![0xFF; length];
    for segment in segments {
        let from = segment.file_offset as usize;
        let data =
            elf.get(from..from + segment.file_bytes as usize).context("segment truncated")?;
        let at = (segment.physical_address - start) as usize;
        bytes[at..at + data.len()].copy_from_slice(data);
    }
    Ok(FlashImage { load_address: start, bytes })
}

/// Flash and RAM use of a firmware ELF.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct MemoryUse {
    flash_bytes: u64,
    ram_static_bytes: u64,
    /// Space left for the stack: with flip-link the stack grows down from the top of the gap
    /// between the start of RAM and the lowest static, so this is the stack's hard limit.
    stack_bytes: u64,
    axisram_bytes: u64,
}

impl MemoryUse {
    fn of(sections: &[Section]) -> Self {
        let total = |names: &[&str]| -> u64 {
            sections
                .iter()
                .filter(|s| s.allocated && names.contains(&s.name.as_str()))
                .map(|s| s.size_bytes)
                .sum()
        };
        let lowest_static = sections
            .iter()
            .filter(|s| RAM_SECTIONS.contains(&s.name.as_str()) && s.size_bytes > 0)
            .map(|s| s.address)
            .min();
        let ram_static_bytes = total(RAM_SECTIONS);
        let stack_bytes = match lowest_static {
            // flip-link: statics at the top of RAM, stack below them.
            Some(address) if address > RAM_ORIGIN => address - RAM_ORIGIN,
            // Plain cortex-m-rt layout: statics at the bottom, stack takes the rest.
            _ => RAM_BYTES.saturating_sub(ram_static_bytes),
        };
        MemoryUse {
            flash_bytes: total(FLASH_SECTIONS),
            ram_static_bytes,
            stack_bytes,
            axisram_bytes: total(&[".axisram"]),
        }
    }

    fn report(&self, elf: &Path) -> String {
        let percent = |used: u64, of: u64| 100.0 * used as f64 / of as f64;
        format!(
            "firmware: {}\n\
             \x20 flash  {:>8} B of {:>8} B ({:5.2} %)  .vector_table + .text + .rodata + .data\n\
             \x20 RAM    {:>8} B of {:>8} B ({:5.2} %)  .data + .bss + .uninit (DTCM)\n\
             \x20 stack  {:>8} B of {:>8} B ({:5.2} %)  free for the stack (flip-link: below the statics)\n\
             \x20 AXI    {:>8} B of {:>8} B ({:5.2} %)  .axisram (DMA buffers)\n",
            elf.display(),
            self.flash_bytes,
            FLASH_BYTES,
            percent(self.flash_bytes, FLASH_BYTES),
            self.ram_static_bytes,
            RAM_BYTES,
            percent(self.ram_static_bytes, RAM_BYTES),
            self.stack_bytes,
            RAM_BYTES,
            percent(self.stack_bytes, RAM_BYTES),
            self.axisram_bytes,
            AXISRAM_BYTES,
            percent(self.axisram_bytes, AXISRAM_BYTES),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal ELF32 with the given (name, flags, address, size) sections and one PT_LOAD
    /// segment of `payload` at `load_address`.
    fn tiny_elf(sections: &[(&str, u32, u32, u32)], payload: &[u8], load_address: u32) -> Vec<u8> {
        let mut names = vec![0u8];
        let mut name_offsets = Vec::new();
        for (name, ..) in sections.iter().chain([&(".shstrtab", 0, 0, 0)]) {
            name_offsets.push(names.len() as u32);
            names.extend_from_slice(name.as_bytes());
            names.push(0);
        }
        let payload_offset = 52 + 32;
        let names_offset = payload_offset + payload.len();
        let table_offset = names_offset + names.len();
        let count = sections.len() + 2; // null section + ours + .shstrtab

        let mut elf = vec![0u8; 52];
        elf[..6].copy_from_slice(b"\x7fELF\x01\x01");
        elf[0x1C..0x20].copy_from_slice(&52u32.to_le_bytes());
        elf[0x20..0x24].copy_from_slice(&(table_offset as u32).to_le_bytes());
        elf[0x2A..0x2C].copy_from_slice(&32u16.to_le_bytes());
        elf[0x2C..0x2E].copy_from_slice(&1u16.to_le_bytes());
        elf[0x2E..0x30].copy_from_slice(&40u16.to_le_bytes());
        elf[0x30..0x32].copy_from_slice(&(count as u16).to_le_bytes());
        elf[0x32..0x34].copy_from_slice(&((count - 1) as u16).to_le_bytes());
        // Program header: PT_LOAD.
        for word in [1, payload_offset as u32, load_address, load_address, payload.len() as u32] {
            elf.extend_from_slice(&word.to_le_bytes());
        }
        elf.extend_from_slice(&[0; 12]);
        elf.extend_from_slice(payload);
        elf.extend_from_slice(&names);
        elf.extend_from_slice(&[0; 40]); // null section
        let section = |name: u32, flags: u32, address: u32, offset: u32, size: u32| {
            let mut header = Vec::new();
            for word in [name, 1, flags, address, offset, size, 0, 0, 1, 0] {
                header.extend_from_slice(&word.to_le_bytes());
            }
            header
        };
        for (index, &(_, flags, address, size)) in sections.iter().enumerate() {
            elf.extend(section(name_offsets[index], flags, address, 0, size));
        }
        elf.extend(section(
            name_offsets[sections.len()],
            0,
            0,
            names_offset as u32,
            names.len() as u32,
        ));
        elf
    }

    /// A minimal ELF32 with a symbol table of the given names (all in section 0, value 0) and
    /// its string table; no other sections.
    fn elf_with_symbols(names: &[&str]) -> Vec<u8> {
        let mut strings = vec![0u8];
        let mut symbols = vec![0u8; 16]; // the null symbol
        for name in names {
            symbols.extend_from_slice(&(strings.len() as u32).to_le_bytes()); // st_name
            symbols.extend_from_slice(&[0; 12]); // st_value, st_size, st_info..st_shndx
            strings.extend_from_slice(name.as_bytes());
            strings.push(0);
        }
        let symbols_offset = 52;
        let strings_offset = symbols_offset + symbols.len();
        let table_offset = strings_offset + strings.len();
        let mut elf = vec![0u8; 52];
        elf[..6].copy_from_slice(b"\x7fELF\x01\x01");
        elf[0x20..0x24].copy_from_slice(&(table_offset as u32).to_le_bytes());
        elf[0x2E..0x30].copy_from_slice(&40u16.to_le_bytes());
        elf[0x30..0x32].copy_from_slice(&3u16.to_le_bytes());
        elf.extend_from_slice(&symbols);
        elf.extend_from_slice(&strings);
        elf.extend_from_slice(&[0; 40]); // null section
                                         // .symtab (SHT_SYMTAB = 2), sh_link = 2: the string table below.
        for word in [0, 2, 0, 0, symbols_offset as u32, symbols.len() as u32, 2, 0, 4, 16] {
            elf.extend_from_slice(&word.to_le_bytes());
        }
        // .strtab (SHT_STRTAB = 3).
        for word in [0, 3, 0, 0, strings_offset as u32, strings.len() as u32, 0, 0, 1, 0] {
            elf.extend_from_slice(&word.to_le_bytes());
        }
        elf
    }

    #[test]
    fn finds_float_formatting_among_the_symbols() {
        let clean = elf_with_symbols(&["main", "_ZN6flight4math5clamp17h0123456789abcdefE"]);
        assert_eq!(elf32_symbol_names(&clean).unwrap().len(), 2);
        assert!(float_formatting_symbols(&clean).unwrap().is_empty());
        let grisu = "_ZN4core3num7flt2dec8strategy5grisu19format_shortest_opt17h0fE";
        let dragon = "_ZN4core3num7flt2dec8strategy6dragon15format_shortest17h1fE";
        let bloated = elf_with_symbols(&["main", dragon, grisu]);
        assert_eq!(float_formatting_symbols(&bloated).unwrap(), [grisu, dragon]);
        // sorted
    }

    #[test]
    fn flash_budget_is_three_sectors() {
        // 2026-12-02: the image for ESCs without speed telemetry before issue 56 made the two
        // images one, 290,896 B.
        assert!(check_budget(290_896, FLASH_BUDGET_BYTES).is_ok());
        assert!(check_budget(393_216, FLASH_BUDGET_BYTES).is_ok());
        let over = check_budget(393_217, FLASH_BUDGET_BYTES).unwrap_err().to_string();
        assert!(over.contains("393217 B") && over.contains("by 1 B"), "{over}");
        assert!(over.contains("384 KiB, 3 flash sectors"), "{over}");
    }

    #[test]
    fn a_stack_that_overflows_at_init_or_in_flight_is_refused() {
        // 2026-11-28: init needed 124,236 B with 80,984 B free (the IMU-offset calibration built
        // on the stack and moved); built in place, 78,180 B.
        assert!(check_stack(78_180, 30_000, 80_984).is_ok());
        assert!(check_stack(124_236, 30_000, 80_984).is_err());
        assert!(check_stack(78_180, 80_985, 80_984).is_err());
    }

    #[test]
    fn sums_flash_and_ram_sections() {
        let elf = tiny_elf(
            &[
                (".vector_table", 2, 0x0800_0000, 0x298),
                (".text", 6, 0x0800_0298, 10_000),
                (".rodata", 2, 0x0800_29A8, 2_000),
                (".data", 3, 0x2001_F000, 100),
                (".bss", 3, 0x2001_F064, 900),
                (".uninit", 3, 0x2001_F3E8, 24),
                (".defmt", 0, 0, 5_000),
                (".axisram", 3, 0x2400_0000, 64),
            ],
            &[],
            0x0800_0000,
        );
        let sections = elf32_sections(&elf).unwrap();
        assert_eq!(sections[1].name, ".vector_table");
        let used = MemoryUse::of(&sections);
        assert_eq!(used.flash_bytes, 0x298 + 10_000 + 2_000 + 100);
        assert_eq!(used.ram_static_bytes, 100 + 900 + 24);
        assert_eq!(used.stack_bytes, 0x1F000);
        assert_eq!(used.axisram_bytes, 64);
    }

    #[test]
    fn flash_image_is_the_loadable_bytes() {
        let elf = tiny_elf(&[], &[1, 2, 3, 4], 0x0800_0000);
        let image = elf_to_flash_image(&elf).unwrap();
        assert_eq!(image.load_address, 0x0800_0000);
        assert_eq!(image.bytes, [1, 2, 3, 4]);
    }

    #[test]
    fn rejects_what_is_not_an_elf32() {
        assert!(
            elf32_sections(b"not an elf at all, but long enough to have a header......").is_err()
        );
        assert!(elf32_sections(&[0x7f, b'E', b'L', b'F']).is_err());
    }
}
