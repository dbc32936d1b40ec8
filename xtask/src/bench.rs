//! `cargo xtask bench` (host, criterion) and `cargo xtask bench-m7` (QEMU Cortex-M7 counts).
//!
//! `bench-m7` builds the `bench-m7/` crate (outside the workspace) for `thumbv7em-none-eabihf`
//! with `-C target-cpu=cortex-m7`, runs it on QEMU's `mps2-an500` with one translation block per
//! instruction and an execution trace, and counts the trace lines between the two marker
//! functions `bench_region_start` / `bench_region_end` (addresses from the ELF symbol table).
//! The binary prints its region names over semihosting in the order it runs them; the first
//! region is empty and measures the marker overhead, which is subtracted from the others.
//! Counts are instructions, not cycles, and repeat exactly from run to run. Each region with a
//! target of issue 56 (`TARGETS`) is checked against it, and the command fails when one is
//! missed.

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
/// Issue 56 ("the speed back"): the thrust-axis solve at m = 4, every case (cold, warm),
/// instructions.
const SOLVE_M4_TARGET: u64 = 875;
/// Issue 56: the thrust-axis solve at m = 6, every case (planar and tilted 20°, cold and warm),
/// instructions.
const SOLVE_M6_TARGET: u64 = 1_500;
/// Issue 56: the thrust-axis solve at m = 8, every case (planar and tilted 20°, cold and warm),
/// instructions.
const SOLVE_M8_TARGET: u64 = 1_500;
/// Issue 56: one closed-loop control step of the quad, every `bench-m7` case (hover, pose fix,
/// recovery), instructions.
const STEP_QUAD_TARGET: u64 = 8_000;
/// Issue 56: one closed-loop control step of the octorotor, every `bench-m7` case, instructions.
const STEP_OCTO_TARGET: u64 = 12_000;
/// Issue 56: the quad's learner per sample, the worst sample of its cycle, instructions. The
/// learner without speed telemetry (its excitation and its catch-up after it) has the same budget.
const LEARNER_QUAD_TARGET: u64 = 12_000;
/// Issue 56: the octorotor's learner per sample, the worst sample, instructions; also the budget
/// of its catch-up without speed telemetry.
const LEARNER_OCTO_TARGET: u64 = 24_000;

/// Issue 56: the worst control period's load, percent of the period, at the planned cycles per
/// instruction on the slower silicon (docs/budget.md, "Time"): the octorotor's worst
/// closed-loop step, its DShot answers decoded and frames encoded, and the worst sample of its
/// learner (the background task, which runs beside the closed loop in the in-flight
/// refinement), with an IMU offset known.
const PERIOD_LOAD_TARGET_PERCENT: f64 = 25.0;
/// Cycles per instruction planned for: the worst case of docs/budget.md's band (dependent FPU
/// chains, branch mispredictions, instruction-cache misses to flash).
const PLANNED_CYCLES_PER_INSTRUCTION: f64 = 1.5;
/// sys_ck of the H743's older silicon (revision Y), Hz; revision V runs at 480 MHz.
const SLOWER_CLOCK_HZ: f64 = 400e6;
/// The control period, s (2 kHz).
const CONTROL_PERIOD_S: f64 = 1.0 / 2000.0;
/// Regions a part of a period takes the worst of: names that start with the first string and
/// contain the second.
type Pattern = (&'static str, &'static str);
/// A part of a control period: what, and the patterns whose worst regions it adds up.
type PeriodPart = (&'static str, &'static [Pattern]);
/// The worst control periods, each checked against [`PERIOD_LOAD_TARGET_PERCENT`]: with speed
/// telemetry (the answers decoded, the learner's samples in flight as in its excitation),
/// without (frames only; in flight a held sample every 4 ms begins a regression row and the
/// sample after it finishes its update: the samples after the model's publication), and with no
/// IMU offset known (the background task hands each sample to the in-flight fit, which runs in
/// `idle`: [`FIT_IDLE`]).
const PERIODS: [(&str, [PeriodPart; 3]); 3] = [
    (
        "with speed telemetry",
        [
            ("control step, octorotor", &[("closed-loop step m=8, ", "")]),
            ("DShot, 8 motors", &[("dshot: decode 8 ", ""), ("dshot: encode 8 ", "")]),
            ("learner, octorotor, per sample", &[("learner step m=8, ", "")]),
        ],
    ),
    (
        "without speed telemetry, in flight",
        [
            ("control step, octorotor", &[("closed-loop step m=8, ", "")]),
            ("DShot frames, 8 motors", &[("dshot: encode 8 ", "")]),
            (
                "learner without speeds, octorotor, per sample in flight",
                &[("learner m=8, no speed telemetry, ", ": after the publication")],
            ),
        ],
    ),
    (
        "with no IMU offset known",
        [
            ("control step, octorotor", &[("closed-loop step m=8, ", "")]),
            ("DShot, 8 motors", &[("dshot: decode 8 ", ""), ("dshot: encode 8 ", "")]),
            (
                "learner, octorotor, per sample, and the sample handed to the in-flight fit",
                &[("learner step m=8, ", ""), (FIT_HANDOFF_PREFIX, "")],
            ),
        ],
    ),
];

/// The background task's part of a sample for the in-flight IMU-offset fit (`bench-m7`'s
/// region names).
const FIT_HANDOFF_PREFIX: &str = "in-flight fit hand-off, ";

/// The in-flight IMU-offset fit in `idle` (`firmware::app::offset_fit`): each estimate is taken
/// back [`FIT_HANDBACK_S`] after the sample that completed it, and the background task waits
/// for it beyond that, its samples held in their queue. The worst such wait: a solve and the
/// hand-back's sum intervals done in the idle time the worst period with no offset known leaves,
/// less the hand-back; a miss above [`FIT_WAIT_TARGET_S`].
const FIT_IDLE: (&str, &str) =
    ("imu-offset in-flight fit solve m=8", "imu-offset in-flight fit m=8, 4 samples");
/// `firmware::app::offset_fit::OFFSET_FIT_HANDBACK_S`, s.
const FIT_HANDBACK_S: f64 = 0.005;
/// `imu_offset::in_flight::SUM_INTERVAL_S`, s: a 2 ms interval's four samples are a region.
const FIT_SUM_INTERVAL_S: f64 = 0.002;
/// Longest wait of the background task for the fit, s: half of what its sample queue holds
/// (`firmware::app::SAMPLE_QUEUE_LEN`, 63 usable samples at 2 kHz), the rest for the USB link's
/// bursts and a board busier than planned.
const FIT_WAIT_TARGET_S: f64 = 0.5 * 63.0 * CONTROL_PERIOD_S;

/// Issue 53: what the pilot's sticks and the landing add to one control step, instructions
/// (the worst step: position mode's setpoint moved with the fly-away detector counting; a
/// landing's touchdown detector).
const PILOT_STEP_TARGET: u64 = 300;

/// A target: every region whose name (as `bench-m7/src/main.rs` announces it) starts with
/// `prefix` takes at most `limit` instructions.
#[derive(Debug)]
struct Target {
    /// What the target bounds, as the table prints it.
    what: &'static str,
    /// Region-name prefix; a region takes the first target whose prefix it starts with.
    prefix: &'static str,
    /// Instructions, at most.
    limit: u64,
    /// Where the target comes from.
    origin: &'static str,
}

/// Where most targets come from.
const ORIGIN: &str = "issue 56";

/// The targets (issue 56's, and issue 53's for the pilot), matched by region-name prefix in
/// this order.
static TARGETS: [Target; 11] = [
    Target {
        what: "thrust-axis solve, m = 4",
        prefix: "thrust-axis solve m=4 ",
        limit: SOLVE_M4_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "thrust-axis solve, m = 6",
        prefix: "thrust-axis solve m=6 ",
        limit: SOLVE_M6_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "thrust-axis solve, m = 8",
        prefix: "thrust-axis solve m=8 ",
        limit: SOLVE_M8_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "control step, quad",
        prefix: "closed-loop step m=4, ",
        limit: STEP_QUAD_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "control step, octorotor",
        prefix: "closed-loop step m=8, ",
        limit: STEP_OCTO_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "learner without speed telemetry, quad, per sample of the excitation",
        prefix: "learner step m=4, no speed telemetry, ",
        limit: LEARNER_QUAD_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "learner, quad, per sample",
        prefix: "learner step m=4, ",
        limit: LEARNER_QUAD_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "learner, octorotor, per sample",
        prefix: "learner step m=8, ",
        limit: LEARNER_OCTO_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "catch-up without speed telemetry, quad, per sample",
        prefix: "learner m=4, no speed telemetry, ",
        limit: LEARNER_QUAD_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "catch-up without speed telemetry, octorotor, per sample",
        prefix: "learner m=8, no speed telemetry, ",
        limit: LEARNER_OCTO_TARGET,
        origin: ORIGIN,
    },
    Target {
        what: "the sticks and the landing in a control step",
        prefix: "pilot step: ",
        limit: PILOT_STEP_TARGET,
        origin: "issue 53",
    },
];

/// One measured region: its name, its instructions (marker overhead subtracted) and its target.
#[derive(Debug)]
struct Row {
    name: String,
    instructions: u64,
    target: Option<&'static Target>,
}

impl Row {
    /// Over its target.
    fn over(&self) -> bool {
        self.target.is_some_and(|target| self.instructions > target.limit)
    }
}

/// The regions (names and raw counts, in run order, the marker overhead's own region left out)
/// with the overhead subtracted and each one's target.
fn verdicts(names: &[&str], counts: &[u64], overhead: u64) -> Vec<Row> {
    names
        .iter()
        .zip(counts)
        .map(|(name, count)| Row {
            name: name.to_string(),
            instructions: count.saturating_sub(overhead),
            target: TARGETS.iter().find(|target| name.starts_with(target.prefix)),
        })
        .collect()
}

/// Every target missed, one line each: a region over its limit, or a target no region measured
/// (every target's regions run: a renamed region must not pass unseen).
fn missed(rows: &[Row]) -> Vec<String> {
    let mut out: Vec<String> = rows
        .iter()
        .filter(|row| row.over())
        .filter_map(|row| {
            let target = row.target?;
            Some(format!(
                "{}: {} instructions > {} ({}, {})",
                row.name, row.instructions, target.limit, target.what, target.origin
            ))
        })
        .collect();
    for target in &TARGETS {
        let measured = rows.iter().any(|row| row.target.is_some_and(|t| std::ptr::eq(t, target)));
        if !measured {
            out.push(format!(
                "{} (≤ {}, {}): no region named `{}…` was measured",
                target.what, target.limit, target.origin, target.prefix
            ));
        }
    }
    out
}

/// The table of the targets: each one's worst region and its verdict.
fn print_targets(rows: &[Row]) {
    println!("\nTargets of issues 56 and 53 (instructions, every region of the target at most its limit):\n");
    println!("| target | worst region | instructions | target | verdict |");
    println!("|---|---|---:|---:|---|");
    for target in &TARGETS {
        let worst = rows
            .iter()
            .filter(|row| row.target.is_some_and(|t| std::ptr::eq(t, target)))
            .max_by_key(|row| row.instructions);
        match worst {
            Some(row) => println!(
                "| {} | {} | {} | ≤ {} | {} |",
                target.what,
                row.name,
                row.instructions,
                target.limit,
                if row.instructions > target.limit { "MISSED" } else { "met" }
            ),
            None => println!("| {} | — | — | ≤ {} | not measured |", target.what, target.limit),
        }
    }
}

/// The argument that adds the thrust-axis bounded search (the bench crate's feature of the same
/// name, which also compiles `flight` with it, unlike the firmware).
const BOUNDED_SEARCH_ARG: &str = "--bounded-search";
/// Debian package that provides `qemu-system-arm`.
const QEMU_PACKAGE: &str = "qemu-system-arm";

/// Instruction counts on QEMU's Cortex-M7; prints a table of every region with its target and
/// one of the issue 56 targets, and fails listing every target missed (`missed`). With
/// `BENCH_M7_PROFILE` set to region numbers (comma-separated, in run order, 0 the marker
/// overhead's), each of those regions' instructions are also listed by function.
/// `--bounded-search` adds the thrust-axis bounded-search regions (it compiles `flight` with its
/// feature, as the firmware does not). The learner without speed telemetry is in every run, as
/// in the firmware's one image (issue 56).
pub fn m7(args: &[String]) -> Result<()> {
    let mut features = Vec::new();
    for arg in args {
        match arg.as_str() {
            BOUNDED_SEARCH_ARG => features.push("bounded-search"),
            other => bail!(
                "bench-m7: unknown argument `{other}` (usage: cargo xtask bench-m7 \
                 [{BOUNDED_SEARCH_ARG}])"
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
    let profiled: Vec<usize> = std::env::var("BENCH_M7_PROFILE")
        .map(|v| v.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_default();
    let (counts, profiles) = count_regions(trace, start, end, &profiled)?;
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
    let rows = verdicts(&names[1..], &counts[1..], overhead);
    println!("| region | instructions | target |");
    println!("|---|---:|---:|");
    for row in &rows {
        let verdict = match row.target {
            Some(target) if row.over() => format!("≤ {} MISSED", target.limit),
            Some(target) => format!("≤ {} met", target.limit),
            None => "—".to_string(),
        };
        println!("| {} | {} | {verdict} |", row.name, row.instructions);
    }
    for line in stdout.lines().filter(|l| l.starts_with("bench-m7 check:")) {
        println!("{line}");
    }
    print_targets(&rows);
    if !profiles.is_empty() {
        let mut functions: Vec<(&String, &(u32, u32))> =
            symbols.iter().filter(|(_, s)| s.1 > 0).collect();
        functions.sort_by_key(|(_, s)| s.0);
        for (index, profile) in profiles {
            let mut by_function: HashMap<String, u64> = HashMap::new();
            for (pc, n) in profile {
                let name = functions
                    .iter()
                    .rev()
                    .find(|(_, s)| s.0 <= pc && pc < s.0 + s.1)
                    .map_or_else(|| format!("{pc:#x}"), |(name, _)| name.to_string());
                *by_function.entry(name).or_default() += n;
            }
            let mut list: Vec<_> = by_function.into_iter().collect();
            list.sort_by_key(|(_, n)| std::cmp::Reverse(*n));
            println!("profile of region {index} ({}):", names.get(index).unwrap_or(&"?"));
            for (name, n) in list {
                println!("  {n:6} {name}");
            }
        }
    }
    let mut missed = missed(&rows);
    let loads: Vec<PeriodLoad> =
        PERIODS.iter().map(|(_, parts)| period_load(&rows, parts)).collect();
    for ((which, _), load) in PERIODS.iter().zip(&loads) {
        print_period(which, load);
        missed.extend(load.missed());
    }
    let fit = fit_idle_wait(&rows, &loads[2]);
    print_fit_idle(&fit);
    missed.extend(fit.missed());
    if !missed.is_empty() {
        bail!("bench-m7: {} target(s) missed:\n  {}", missed.len(), missed.join("\n  "));
    }
    Ok(())
}

/// The in-flight fit's work within a hand-back, done in idle time ([`FIT_IDLE`]).
struct FitIdleWait {
    /// The solve's and a sum interval's instructions (`None`: not measured).
    solve: Option<u64>,
    interval: Option<u64>,
    /// The work within a hand-back, instructions; its time, and the fraction of the time left
    /// idle by the worst period.
    instructions: u64,
    work_s: f64,
    idle_fraction: f64,
}

impl FitIdleWait {
    /// How long the work takes in the idle time, s.
    fn done_after_s(&self) -> f64 {
        self.work_s / self.idle_fraction
    }

    /// The background task's longest wait for it, s.
    fn wait_s(&self) -> f64 {
        (self.done_after_s() - FIT_HANDBACK_S).max(0.0)
    }

    fn missed(&self) -> Option<String> {
        if self.solve.is_none() || self.interval.is_none() {
            return Some("in-flight fit in idle: its solve or sum interval not measured".into());
        }
        (self.wait_s() > FIT_WAIT_TARGET_S).then(|| {
            format!(
                "in-flight fit in idle: the background task waits {:.1} ms for it > {:.1} ms",
                self.wait_s() * 1e3,
                FIT_WAIT_TARGET_S * 1e3
            )
        })
    }
}

/// The fit's worst work within a hand-back (a solve and the hand-back's sum intervals) in the
/// idle time the worst period `worst` leaves, at the planned cycles per instruction.
fn fit_idle_wait(rows: &[Row], worst: &PeriodLoad) -> FitIdleWait {
    let find = |prefix: &str| {
        rows.iter().filter(|r| r.name.starts_with(prefix)).map(|r| r.instructions).max()
    };
    let (solve, interval) = (find(FIT_IDLE.0), find(FIT_IDLE.1));
    let intervals = (FIT_HANDBACK_S / FIT_SUM_INTERVAL_S).ceil() as u64;
    let instructions = solve.unwrap_or(0) + intervals * interval.unwrap_or(0);
    let work_s = instructions as f64 * PLANNED_CYCLES_PER_INSTRUCTION / SLOWER_CLOCK_HZ;
    FitIdleWait {
        solve,
        interval,
        instructions,
        work_s,
        idle_fraction: 1.0 - worst.percent / 100.0,
    }
}

/// Prints [`fit_idle_wait`].
fn print_fit_idle(fit: &FitIdleWait) {
    println!(
        "\nThe in-flight IMU-offset fit in idle (octorotor, CPI {PLANNED_CYCLES_PER_INSTRUCTION} at \
         {} MHz): a solve ({} instructions) and the sum intervals of its {:.1} ms hand-back ({} \
         each), {} instructions, {:.2} ms of work, done after {:.2} ms in the {:.0} % the worst \
         period with no offset known leaves idle: the background task waits {:.2} ms for it \
         (target ≤ {:.1} ms, half its sample queue)",
        SLOWER_CLOCK_HZ / 1e6,
        fit.solve.unwrap_or(0),
        FIT_HANDBACK_S * 1e3,
        fit.interval.unwrap_or(0),
        fit.instructions,
        fit.work_s * 1e3,
        fit.done_after_s() * 1e3,
        fit.idle_fraction * 100.0,
        fit.wait_s() * 1e3,
        FIT_WAIT_TARGET_S * 1e3
    );
}

/// A worst control period's work (one of [`PERIODS`]) and its load.
struct PeriodLoad {
    /// Each part: what, the region it took (the worst of its prefix, or the sum), instructions.
    parts: Vec<(&'static str, String, u64)>,
    instructions: u64,
    /// Percent of the control period at [`PLANNED_CYCLES_PER_INSTRUCTION`] and
    /// [`SLOWER_CLOCK_HZ`].
    percent: f64,
    /// Parts no region measured.
    unmeasured: Vec<&'static str>,
}

impl PeriodLoad {
    /// The miss, if any: over the target, or a part not measured.
    fn missed(&self) -> Option<String> {
        if !self.unmeasured.is_empty() {
            return Some(format!(
                "worst control-period load: no region measured {}",
                self.unmeasured.join(", ")
            ));
        }
        (self.percent > PERIOD_LOAD_TARGET_PERCENT).then(|| {
            format!(
                "worst control-period load: {:.1} % > {PERIOD_LOAD_TARGET_PERCENT} % ({} \
                 instructions; issue 56)",
                self.percent, self.instructions
            )
        })
    }
}

/// Prints a worst control period: its parts and its load.
fn print_period(which: &str, load: &PeriodLoad) {
    println!(
        "\nWorst control period {which} (octorotor, CPI {PLANNED_CYCLES_PER_INSTRUCTION} at {} MHz):",
        SLOWER_CLOCK_HZ / 1e6
    );
    for (what, region, instructions) in &load.parts {
        println!("  {what}: {instructions} ({region})");
    }
    println!(
        "  {} instructions, {:.1} µs, {:.1} % of the period (target ≤ {PERIOD_LOAD_TARGET_PERCENT} %)",
        load.instructions,
        load.percent * CONTROL_PERIOD_S * 1e4,
        load.percent
    );
}

/// The worst control period made of `parts` (one of [`PERIODS`]) from the measured `rows`.
fn period_load(rows: &[Row], parts: &[PeriodPart]) -> PeriodLoad {
    let mut load =
        PeriodLoad { parts: Vec::new(), instructions: 0, percent: 0.0, unmeasured: Vec::new() };
    for &(what, patterns) in parts {
        let mut sum = 0;
        let mut names = Vec::new();
        for (prefix, contains) in patterns {
            match rows
                .iter()
                .filter(|row| row.name.starts_with(prefix) && row.name.contains(contains))
                .max_by_key(|row| row.instructions)
            {
                Some(row) => {
                    sum += row.instructions;
                    names.push(row.name.clone());
                }
                None => load.unmeasured.push(what),
            }
        }
        load.instructions += sum;
        load.parts.push((what, names.join(" + "), sum));
    }
    load.percent = load_percent(load.instructions);
    load
}

/// What `instructions` take of the control period, percent, at
/// [`PLANNED_CYCLES_PER_INSTRUCTION`] and [`SLOWER_CLOCK_HZ`].
fn load_percent(instructions: u64) -> f64 {
    let seconds = instructions as f64 * PLANNED_CYCLES_PER_INSTRUCTION / SLOWER_CLOCK_HZ;
    100.0 * seconds / CONTROL_PERIOD_S
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
#[allow(clippy::type_complexity)]
fn count_regions(
    trace: impl BufRead,
    start: (u32, u32),
    end: (u32, u32),
    profiled: &[usize],
) -> Result<(Vec<u64>, Vec<(usize, HashMap<u32, u64>)>)> {
    let mut profiles: Vec<(usize, HashMap<u32, u64>)> = Vec::new();
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
                if profiled.contains(&counts.len()) {
                    if profiles.last().is_none_or(|(i, _)| *i != counts.len()) {
                        profiles.push((counts.len(), HashMap::new()));
                    }
                    if let Some((_, p)) = profiles.last_mut() {
                        *p.entry(pc).or_default() += 1;
                    }
                }
            }
        }
    }
    Ok((counts, profiles))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The marker overhead of the tests' runs (the real one is measured, 8 in the last runs).
    const OVERHEAD: u64 = 8;

    /// The rows of regions named `names` that took `instructions` each, net of the overhead.
    fn rows(names: &[&str], instructions: &[u64]) -> Vec<Row> {
        let counts: Vec<u64> = instructions.iter().map(|n| n + OVERHEAD).collect();
        verdicts(names, &counts, OVERHEAD)
    }

    /// One region of each target (every one runs without arguments), as `bench-m7/src/main.rs`
    /// names them, in the order of [`TARGETS`].
    const DEFAULT_REGIONS: [&str; 11] = [
        "thrust-axis solve m=4 warm",
        "thrust-axis solve m=6 tilted 20°, cold",
        "thrust-axis solve m=8 cold",
        "closed-loop step m=4, hover, position hold",
        "closed-loop step m=8, recovery 10 ms after a 60° tilt, position hold (allocation saturated)",
        "learner step m=4, no speed telemetry, sample 3",
        "learner step m=4, sample 4: force row y's turn ends, thrust-axis solve, model published",
        "learner step m=8, sample 7: rotational row x begun (its product P x and the parameters)",
        "learner m=4, no speed telemetry, sample 451 at the excitation's end",
        "learner m=8, no speed telemetry, sample 851 at the excitation's end",
        "pilot step: a landing, the touchdown detector (no fixes)",
    ];

    /// The limit of each of [`DEFAULT_REGIONS`], in order.
    const DEFAULT_LIMITS: [u64; 11] = [
        SOLVE_M4_TARGET,
        SOLVE_M6_TARGET,
        SOLVE_M8_TARGET,
        STEP_QUAD_TARGET,
        STEP_OCTO_TARGET,
        LEARNER_QUAD_TARGET,
        LEARNER_QUAD_TARGET,
        LEARNER_OCTO_TARGET,
        LEARNER_QUAD_TARGET,
        LEARNER_OCTO_TARGET,
        PILOT_STEP_TARGET,
    ];

    #[test]
    fn each_region_takes_its_target() {
        let limits: Vec<u64> = DEFAULT_REGIONS
            .iter()
            .map(|name| rows(&[name], &[0])[0].target.map(|t| t.limit).unwrap_or(0))
            .collect();
        assert_eq!(limits, DEFAULT_LIMITS);
        // Each region takes its own target, the one of the same place in the table.
        for (name, target) in DEFAULT_REGIONS.iter().zip(&TARGETS) {
            let row = &rows(&[name], &[0])[0];
            assert_eq!(row.target.map(|t| t.what), Some(target.what), "{name}");
        }
        // Regions without a target of their own.
        for name in [
            "learner cycle m=4: the same twelve samples in one region",
            "closed-loop part m=8: allocation solve, hover increment (warm start)",
            "thrust-axis bounded search m=8 (one motor capped)",
            "imu-offset RLS update",
        ] {
            let row = &rows(&[name], &[u64::MAX - OVERHEAD])[0];
            assert!(row.target.is_none() && !row.over(), "{name} has a target");
        }
    }

    #[test]
    fn a_figure_over_its_target_is_a_miss() {
        let limits = DEFAULT_LIMITS;
        // At the limit: no miss.
        let at = rows(&DEFAULT_REGIONS, &limits);
        assert_eq!(missed(&at), Vec::<String>::new());
        // One instruction over, one region at a time: that region alone is missed.
        for (k, name) in DEFAULT_REGIONS.iter().enumerate() {
            let mut figures = limits;
            figures[k] += 1;
            let missed = missed(&rows(&DEFAULT_REGIONS, &figures));
            assert_eq!(missed.len(), 1, "{missed:?}");
            assert!(missed[0].starts_with(name), "{missed:?}");
            assert!(
                missed[0].contains(&format!("{} instructions > {}", figures[k], limits[k])),
                "{missed:?}"
            );
        }
        // The last run's quad hover step, 9,638 instructions (docs/benchmarks.md).
        let mut figures = limits;
        figures[3] = 9_638;
        let missed = missed(&rows(&DEFAULT_REGIONS, &figures));
        assert_eq!(missed.len(), 1);
        assert!(missed[0].contains("9638 instructions > 8000"), "{missed:?}");
    }

    /// The worst period adds the octorotor's worst step, its DShot and its learner's worst
    /// sample: the figures of 2026-12-04 (the learner's rows whole in one sample) are a 30 %
    /// load and a miss; a learner sample that leaves the sum within 33,333 instructions (25 %
    /// of 500 µs at 400 MHz and 1.5 cycles an instruction) is not; a part unmeasured is.
    #[test]
    fn the_worst_control_period_over_a_quarter_is_a_miss() {
        let names = [
            "closed-loop step m=8, hover on GNSS, solution part 1 of 8",
            "closed-loop step m=8, hover, position hold",
            "dshot: decode 8 bidirectional answers",
            "dshot: encode 8 bidirectional throttle frames",
            "learner step m=8, sample 7: rotational row x begun (its product P x and the parameters)",
            "learner step m=8, sample 3: force row z",
            "learner step m=4, sample 4: rotational row x",
        ];
        let load = |learner: u64| {
            period_load(
                &rows(&names, &[11_784, 10_612, 4_035, 344, learner, 12_966, 30_000]),
                &PERIODS[0].1,
            )
        };
        let before = load(23_790);
        assert_eq!(before.instructions, 11_784 + 4_035 + 344 + 23_790);
        assert!((before.percent - 30.0).abs() < 0.1, "{}", before.percent);
        assert!(before.missed().is_some_and(|m| m.contains("30.0 % > 25 %")));
        let within = 33_333 - 11_784 - 4_035 - 344;
        assert_eq!(load(within).missed(), None);
        assert!(load(within + 1).missed().is_some());
        let no_dshot = period_load(&rows(&names[..2], &[11_784, 10_612]), &PERIODS[0].1);
        assert!(no_dshot.missed().is_some_and(|m| m.contains("DShot")), "unmeasured");
        // Without speed telemetry: the frames alone, and the learner's samples in flight only
        // (after the model's publication), not its catch-up before the engagement.
        let without = [
            "closed-loop step m=8, hover, position hold",
            "dshot: decode 8 bidirectional answers",
            "dshot: encode 8 bidirectional throttle frames",
            "learner m=8, no speed telemetry, sample 1100 at the excitation's end (…)",
            "learner m=8, no speed telemetry, sample 1190 at the excitation's end (…): after the \
             publication (as in flight)",
        ];
        let load =
            period_load(&rows(&without, &[11_000, 4_035, 344, 23_000, 15_000]), &PERIODS[1].1);
        assert_eq!(load.instructions, 11_000 + 344 + 15_000);
        assert_eq!(load.missed(), None);
    }

    /// With no IMU offset known the background task's hand-off joins the learner's worst
    /// sample in the worst period; the fit itself, in idle, may hold the background task up
    /// for at most half its sample queue.
    #[test]
    fn the_fit_in_idle_may_hold_the_background_task_up_for_half_its_queue() {
        let names = [
            "closed-loop step m=8, hover, position hold",
            "dshot: decode 8 bidirectional answers",
            "dshot: encode 8 bidirectional throttle frames",
            "learner step m=8, sample 7: rotational row x begun (its product P x and the parameters)",
            "in-flight fit hand-off, octorotor sample with an estimate due, taken back (…)",
            "in-flight fit hand-off, octorotor sample: checked, pushed, counted, none due (…)",
            "imu-offset in-flight fit m=8, 4 samples: one 2 ms sum interval",
            "imu-offset in-flight fit solve m=8",
        ];
        let figures = |solve: u64| [11_839, 4_035, 387, 15_646, 420, 180, 25_502, solve];
        let load = period_load(&rows(&names, &figures(1_070_000)), &PERIODS[2].1);
        assert_eq!(load.instructions, 11_839 + 4_035 + 387 + 15_646 + 420);
        assert_eq!(load.missed(), None);
        let fit = fit_idle_wait(&rows(&names, &figures(1_070_000)), &load);
        // A solve and three 2 ms intervals (5 ms): 1.15 M instructions, 4.3 ms at 1.5 cycles
        // and 400 MHz, done after 5.7 ms in the 76 % left idle: 0.7 ms of waiting.
        assert_eq!(fit.instructions, 1_070_000 + 3 * 25_502);
        assert!((fit.work_s - 4.3e-3).abs() < 0.01e-3, "{}", fit.work_s);
        assert!((fit.wait_s() - 0.66e-3).abs() < 0.05e-3, "{}", fit.wait_s());
        assert_eq!(fit.missed(), None);
        // A solve four times slower: 16 ms of waiting, over half the queue's 31.5 ms.
        let slow = fit_idle_wait(&rows(&names, &figures(4_300_000)), &load);
        assert!(slow.wait_s() > FIT_WAIT_TARGET_S, "{}", slow.wait_s());
        assert!(slow.missed().is_some_and(|m| m.contains("> 15.8 ms")), "{:?}", slow.missed());
        let unmeasured = fit_idle_wait(&rows(&names[..6], &figures(0)[..6]), &load);
        assert!(unmeasured.missed().is_some());
    }

    #[test]
    fn the_catch_up_over_the_learner_budget_is_a_miss() {
        // The octorotor's sample that publishes the model to engage on, as `bench-m7` names it,
        // one instruction over its budget.
        let over = "learner m=8, no speed telemetry, sample 1178 at the excitation's end (from \
                    853: …): the model published (caught up)";
        let mut all: Vec<&str> = DEFAULT_REGIONS.to_vec();
        all.push(over);
        let mut figures = DEFAULT_LIMITS.to_vec();
        figures.push(LEARNER_OCTO_TARGET);
        assert!(missed(&rows(&all, &figures)).is_empty());
        let last = figures.len() - 1;
        figures[last] = LEARNER_OCTO_TARGET + 1;
        let missed = missed(&rows(&all, &figures));
        assert_eq!(missed.len(), 1, "{missed:?}");
        assert!(missed[0].starts_with(over), "{missed:?}");
    }

    #[test]
    fn a_target_no_region_measured_is_a_miss() {
        let zeros = [0; DEFAULT_REGIONS.len()];
        assert!(missed(&rows(&DEFAULT_REGIONS, &zeros)).is_empty());
        // The catch-up's regions left out (as `--no-speed` once did): their two targets missed.
        let without: Vec<&str> =
            DEFAULT_REGIONS.into_iter().filter(|name| !name.starts_with("learner m=")).collect();
        assert_eq!(missed(&rows(&without, &zeros[..without.len()])).len(), 2);
        // A control-step region renamed away: its target is missed.
        let renamed = ["closed loop m=4 hover"];
        let mut names: Vec<&str> = DEFAULT_REGIONS.to_vec();
        names[3] = renamed[0];
        let missed = missed(&rows(&names, &zeros));
        assert_eq!(missed.len(), 1, "{missed:?}");
        assert!(missed[0].starts_with(TARGETS[3].what), "{missed:?}");
    }
}
