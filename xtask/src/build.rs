//! `cargo xtask build` and `cargo xtask flash`: the STM32H743 firmware.
//!
//! `build` installs what the cross build needs (the rustup target, flip-link), builds the release
//! ELF and prints its flash and RAM use, read from the ELF's section headers by a small reader
//! below (no binutils needed). `flash` programs a board through a debug probe (probe-rs) or
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

/// Build the release firmware ELF and print its flash and RAM use; returns the ELF's path.
///
/// Extra `args` are passed to `cargo build` (e.g. `--features ...`).
pub fn build(args: &[String]) -> Result<PathBuf> {
    ensure_target_installed()?;
    ensure_flip_link()?;

    let mut cargo = util::cargo();
    cargo.args(["build", "--release", "-p", "firmware", "--bin", "firmware", "--target", TARGET]);
    cargo.args(args);
    if std::env::var_os("DEFMT_LOG").is_none() {
        // defmt compiles out everything below `error` unless told otherwise.
        cargo.env("DEFMT_LOG", "info");
    }
    util::run(&mut cargo)?;

    let elf = target_dir().join(TARGET).join("release").join("firmware");
    ensure!(elf.is_file(), "the build succeeded but {} is missing", elf.display());
    let bytes = std::fs::read(&elf).with_context(|| format!("reading {}", elf.display()))?;
    let sections = elf32_sections(&bytes).with_context(|| format!("parsing {}", elf.display()))?;
    print!("{}", MemoryUse::of(&sections).report(&elf));
    Ok(elf)
}

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
            "install dfu-util (Debian/Ubuntu: `sudo apt-get install dfu-util`, macOS: `brew install dfu-util`)",
        )?;
        require_dfu_device()?;
    } else {
        require_tool(
            "probe-rs",
            "install probe-rs (`cargo install probe-rs-tools --locked`, see https://probe.rs), \
             or use the ROM bootloader: `cargo xtask flash --dfu`",
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

/// One section header of an ELF32 file: the fields this tool needs.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Section {
    name: String,
    /// Virtual (run-time) address.
    address: u64,
    size_bytes: u64,
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
            size_bytes: u64::from(r.u32(base + 20)?),     // sh_size
        });
    }
    Ok(sections)
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
