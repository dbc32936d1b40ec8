//! The STM32H743 firmware binary: an RTIC 1 application that runs the portable
//! [`firmware::app`] on the board.
//!
//! It is deliberately thin (in the manner of stabilizer's `dual-iir.rs`): it sets up clocks and
//! peripherals through [`firmware::board`], then gives each part of DESIGN.md's data flow a task:
//!
//! | task | bound to | priority | what |
//! |---|---|---|---|
//! | `control_tick` | TIM2 update, 2 kHz | 3 (highest) | one control step; pends `usb_service` at 1 kHz, spawns `background` when samples wait |
//! | `usb_service` | OTG2 (`OTG_FS`) interrupt, also pended | 2 | USB device, CDC bytes ↔ link server, telemetry |
//! | `background` | software task (dispatcher `DCMI`) | 1 | drains the learner-sample queue, publishes results |
//! | `idle` | — | 0 | reports the control step's longest duration over defmt, sleeps (`wfi`) |
//!
//! Shared resources are only handoffs: the control step's `Copy` status snapshot and the
//! background results, each written and read under a lock held for a copy. Everything else is a
//! task's `#[local]` state. Task bodies live outside the `#[app]` module (RTIC v1 book), in
//! [`tasks`].
//!
//! Clocks: 8 MHz HSE → PLL1 → sys_ck 400 MHz, hclk 200 MHz; USB from HSI48 (see
//! [`firmware::board::config`]). Time: TIM5 as a 1 MHz counter extended to 64-bit microseconds
//! ([`firmware::board::time`]), read by the control and USB tasks.
//!
//! On the host this file builds to a stub `main` so that `cargo build --workspace` works; the
//! simulator runs the same `firmware::app` code instead.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("the firmware binary only runs on the STM32H743; run the simulator instead: cargo run -p sim --bin sitl");
}

#[cfg(target_os = "none")]
use {defmt_rtt as _, panic_probe as _};

// The RTIC application: resources, initialisation and the task table.
#[cfg(target_os = "none")]
#[rtic::app(device = stm32h7xx_hal::pac, peripherals = true, dispatchers = [DCMI])]
mod app {
    use crate::tasks::{background, control_tick, usb_service};
    use firmware::app::hal::Motors;
    use firmware::app::{
        split_queue, Background, BackgroundCommand, BackgroundResults, BoardInfo, ControlCommand,
        ControlConfig, ControlLoop, ControlSnapshot, LinkServer, NoFlash, SampleQueue, Settings,
        StepConsumer, StepRing,
    };
    use firmware::board::config::{HCLK_HZ, SYS_CK_HZ, TIME_BASE_HZ};
    use firmware::board::identity::{uid_hex, UID_HEX_CHARS};
    use firmware::board::imu::BoardImu;
    use firmware::board::motors::BoardMotors;
    use firmware::board::time::MicrosClock;
    use firmware::board::timing::{step_stats, StepStats, StepTimer};
    use firmware::board::usb::{self, UsbSerial, UsbStorage, EP_MEMORY_WORDS};
    use firmware::board::BOARD;
    use protocol::Capabilities;
    use stm32h7xx_hal::pac;
    use stm32h7xx_hal::prelude::*;
    use stm32h7xx_hal::rcc::rec::UsbClkSel;
    use stm32h7xx_hal::rcc::PllConfigStrategy;
    use stm32h7xx_hal::timer::{Event, Timer};
    use stm32h7xx_hal::usb_hs::USB2;
    use usb_device::bus::UsbBusAllocator;

    /// Handoffs between tasks: small `Copy` values, locked only for the copy.
    #[shared]
    struct Shared {
        /// Written by `control_tick` every step, read by `usb_service`.
        control: ControlSnapshot,
        /// Written by `background` after each batch, read by `usb_service`.
        background: BackgroundResults,
        /// Commands from the link for the control step (arm, disarm, pose, settings, motor
        /// test): pushed by `usb_service`, taken by `control_tick` at the start of its next step.
        commands: heapless::Deque<ControlCommand, 4>,
        /// Commands from the link for the background task (calibration start and stop, new
        /// parameters): pushed by `usb_service`, taken by `background` when it next runs.
        background_commands: heapless::Deque<BackgroundWork, 4>,
    }

    /// What the link task hands the background task. The parameters travel whole (about
    /// 0.5 KiB, copied once per change into a 4-entry static queue: no allocation, no boxing).
    #[derive(Clone, Copy)]
    #[allow(clippy::large_enum_variant)]
    pub enum BackgroundWork {
        Command(BackgroundCommand),
        Configure(firmware::app::Params),
    }

    /// Each task's own state.
    #[local]
    struct Local {
        control_timer: Timer<pac::TIM2>,
        step_timer: StepTimer,
        control_clock: MicrosClock,
        control: ControlLoop<'static>,
        imu: BoardImu,
        motors: BoardMotors,
        usb_clock: MicrosClock,
        usb: UsbSerial,
        link: LinkServer,
        /// The link task's end of the telemetry ring (one record per control step).
        telemetry: StepConsumer<'static>,
        /// The parameters. No flash store yet: the H743's configuration sectors need a driver
        /// that reports ECC errors instead of faulting on a torn word (see `app::settings`).
        settings: Settings<NoFlash>,
        background: Background<'static>,
    }

    #[init(local = [
        samples: SampleQueue = SampleQueue::new(),
        step_ring: StepRing = StepRing::new(),
        ep_memory: [u32; EP_MEMORY_WORDS] = [0; EP_MEMORY_WORDS],
        usb_bus: Option<UsbBusAllocator<usb::Bus>> = None,
        uid_text: [u8; UID_HEX_CHARS] = [0; UID_HEX_CHARS],
    ])]
    fn init(cx: init::Context) -> (Shared, Local, init::Monotonics) {
        let dp = cx.device;
        let mut core = cx.core;

        // Keep the debug port alive while the core sleeps in `wfi`, so probe-rs and defmt-rtt
        // keep working (RM0433 §60.5.8, DBGMCU_CR).
        dp.DBGMCU
            .cr
            .modify(|_, w| w.dbgsleep_d1().set_bit().dbgstop_d1().set_bit().dbgstby_d1().set_bit());

        // Clocks: LDO supply at VOS1 (the HAL's default), HSE → PLL1 → 400 MHz (see
        // `board::config` for why not 480 MHz), USB from the 48 MHz internal RC (HSI48).
        let pwrcfg = dp.PWR.constrain().freeze();
        // PLL1 in the wide VCO range (the HAL's `Iterative` strategy): 8 MHz / M 1 × N 100 = an
        // 800 MHz VCO, / P 2 = 400 MHz, the textbook H743 setting (an even P divider; the
        // `Normal` strategy would run the VCO at 400 MHz with P = 1).
        let mut rcc = dp
            .RCC
            .constrain()
            .use_hse(BOARD.hse_hz.Hz())
            .sys_ck(SYS_CK_HZ.Hz())
            .hclk(HCLK_HZ.Hz())
            .pll1_strategy(PllConfigStrategy::Iterative);
        if BOARD.hse_bypass {
            rcc = rcc.bypass_hse();
        }
        let mut ccdr = rcc.freeze(pwrcfg, &dp.SYSCFG);
        if ccdr.clocks.hsi48_ck().is_none() {
            defmt::panic!("HSI48 is not running: USB has no clock");
        }
        ccdr.peripheral.kernel_usb_clk_mux(UsbClkSel::Hsi48);

        // Time base: TIM5 counting microseconds.
        let time_base = dp.TIM5.tick_timer(TIME_BASE_HZ.Hz(), ccdr.peripheral.TIM5, &ccdr.clocks);
        let clock = MicrosClock::new(time_base);

        // USB CDC on OTG2's internal full-speed PHY (PA11 = D−, PA12 = D+, AF10).
        let gpioa = dp.GPIOA.split(ccdr.peripheral.GPIOA);
        let usb_peripheral = USB2::new(
            dp.OTG2_HS_GLOBAL,
            dp.OTG2_HS_DEVICE,
            dp.OTG2_HS_PWRCLK,
            gpioa.pa11.into_alternate(),
            gpioa.pa12.into_alternate(),
            ccdr.peripheral.USB2OTG,
            &ccdr.clocks,
        );
        let uid_text: &'static str = uid_hex(cx.local.uid_text);
        let usb = UsbSerial::new(
            usb_peripheral,
            UsbStorage { ep_memory: cx.local.ep_memory, bus: cx.local.usb_bus },
            uid_text,
        );

        // The portable application: control loop → sample queue → background worker.
        let config = ControlConfig::default();
        let motors = BoardMotors::default();
        let (producer, consumer) = split_queue(cx.local.samples);
        let (ring_producer, telemetry) = split_queue(cx.local.step_ring);
        let control = ControlLoop::new(config, producer).with_telemetry(ring_producer);
        let background = Background::new(consumer, config.rate_hz);
        let mut serial = heapless::String::new();
        // The 24-character UID always fits the protocol's 32-byte field.
        let _ = serial.push_str(uid_text);
        let link = LinkServer::new(BoardInfo {
            board: BOARD.name,
            serial,
            // No IMU driver and no motor outputs yet: say so (see `board::imu`, `board::motors`).
            capabilities: Capabilities::TELEMETRY,
            control_rate_hz: config.rate_hz,
            motor_count: motors.count(),
        });
        let shared = Shared {
            control: control.snapshot(),
            background: background.results(),
            commands: heapless::Deque::new(),
            background_commands: heapless::Deque::new(),
        };

        // The control tick at the application's rate (2 kHz), started last so the first step
        // finds everything ready.
        let control_rate_hz = u32::from(config.rate_hz);
        let step_timer = StepTimer::new(&mut core.DCB, core.DWT, 1_000_000 / control_rate_hz);
        let mut control_timer =
            dp.TIM2.timer(control_rate_hz.Hz(), ccdr.peripheral.TIM2, &ccdr.clocks);
        control_timer.listen(Event::TimeOut);

        defmt::info!(
            "STM32H743 {=str} up: sys_ck {} Hz, hclk {} Hz, control {} Hz",
            uid_text,
            ccdr.clocks.sys_ck().raw(),
            ccdr.clocks.hclk().raw(),
            control_rate_hz
        );

        let local = Local {
            control_timer,
            step_timer,
            control_clock: clock,
            control,
            imu: BoardImu,
            motors,
            usb_clock: clock,
            usb,
            link,
            telemetry,
            settings: Settings::without_store(),
            background,
        };
        (shared, local, init::Monotonics())
    }

    /// Between interrupts: report the control step's timing over defmt when it changed, then
    /// sleep until the next interrupt. defmt-rtt writes with interrupts masked for the few µs a
    /// message takes and, built with `disable-blocking-mode`, drops messages rather than wait
    /// for the probe, so logging here delays the control interrupt by microseconds at most.
    #[idle(local = [reported: StepStats = StepStats { max_us: 0, overruns: 0 }])]
    fn idle(cx: idle::Context) -> ! {
        loop {
            let stats = step_stats();
            if stats != *cx.local.reported {
                defmt::info!(
                    "control step: longest {} us, {} over the deadline",
                    stats.max_us,
                    stats.overruns
                );
                *cx.local.reported = stats;
            }
            cortex_m::asm::wfi();
        }
    }

    extern "Rust" {
        #[task(
            binds = TIM2,
            priority = 3,
            local = [control_timer, step_timer, control_clock, control, imu, motors, ticks: u32 = 0],
            shared = [control, background, commands]
        )]
        fn control_tick(cx: control_tick::Context);

        #[task(binds = OTG_FS, priority = 2, local = [usb_clock, usb, link, telemetry, settings], shared = [control, background, commands, background_commands])]
        fn usb_service(cx: usb_service::Context);

        #[task(priority = 1, local = [background], shared = [background, background_commands])]
        fn background(cx: background::Context);
    }
}

/// The task bodies (RTIC v1 "extern" tasks): what each task does, apart from the task table.
#[cfg(target_os = "none")]
mod tasks {
    use crate::app::{background, control_tick, usb_service, BackgroundWork};
    use firmware::app::{ControlCommand, ControlSettings, LinkRequest, StatusView};
    use firmware::board::config::USB_SERVICE_DIVIDER;
    use firmware::board::timing::step_stats;
    use protocol::StepTime;
    use rtic::mutex_prelude::*;
    use stm32h7xx_hal::pac::Interrupt;

    /// One control step, on every TIM2 update at 2 kHz, at the highest priority.
    ///
    /// Deadline: 500 µs (one period of the 2 kHz loop; the next IMU sample is due then). It
    /// never blocks and never allocates: the IMU and motor adapters return at once, the sample
    /// queue drops and counts when full, the snapshot lock is uncontended (no higher-priority
    /// task exists) and held for a copy, and the only interrupts-off sections are a few
    /// instructions long (the clock's 64-bit extension, RTIC's spawn queue). Its own duration is
    /// measured against the deadline (`board::timing`) and reported from `idle`.
    pub fn control_tick(mut cx: control_tick::Context) {
        let started = cx.local.step_timer.start();
        cx.local.control_timer.clear_irq();
        let now_us = cx.local.control_clock.now_us();
        let control = &mut *cx.local.control;
        cx.shared.commands.lock(|commands| {
            while let Some(command) = commands.pop_front() {
                control.command(command, now_us);
            }
        });
        // What the background task learned (copied only when it changed).
        cx.shared.background.lock(|results| control.receive(results));
        let samples_waiting = cx.local.control.step(now_us, cx.local.imu, cx.local.motors);
        let snapshot = cx.local.control.snapshot();
        cx.shared.control.lock(|control| *control = snapshot);

        if samples_waiting {
            // `Err` means a run is already queued; it drains everything, so nothing is lost.
            let _ = background::spawn();
        }
        *cx.local.ticks = cx.local.ticks.wrapping_add(1);
        if cx.local.ticks.is_multiple_of(USB_SERVICE_DIVIDER) {
            // Telemetry must flow even when the host sends nothing (no USB interrupt).
            rtic::pend(Interrupt::OTG_FS);
        }
        cx.local.step_timer.finish(started);
    }

    /// The USB link, on every OTG2 interrupt and at 1 kHz from the control step: services the
    /// USB device, feeds received bytes to the link server, lets it queue due telemetry, and
    /// offers what it queued to the CDC buffer until it has nothing more or the buffer is full (the
    /// rest stays queued in the link server for the next service). Never blocks.
    pub fn usb_service(mut cx: usb_service::Context) {
        let now_us = cx.local.usb_clock.now_us();
        let step = step_stats();
        let view = StatusView {
            control: cx.shared.control.lock(|control| *control),
            background: cx.shared.background.lock(|background| *background),
            step_time: Some(StepTime { max_us: step.max_us, overruns: step.overruns }),
            board: protocol::BoardHealth::default(),
        };
        let link = cx.local.link;
        let settings = cx.local.settings;
        cx.local.usb.receive(|bytes| link.receive(bytes, now_us, &view, settings));
        let mut reboot = false;
        let mut work = heapless::Vec::<BackgroundWork, 4>::new();
        cx.shared.commands.lock(|commands| {
            while let Some(request) = link.take_request() {
                match request {
                    // A disarm always finds room: it replaces whatever still waits.
                    LinkRequest::Control(command) => {
                        if command == ControlCommand::Disarm {
                            commands.clear();
                        }
                        let _ = commands.push_back(command);
                    }
                    LinkRequest::Background(command) => {
                        let _ = work.push(BackgroundWork::Command(command));
                    }
                    LinkRequest::Reboot => reboot = true,
                    // Refused by the link until the board announces `Capabilities::BOOTLOADER`.
                    LinkRequest::RebootToBootloader => {}
                }
            }
            if let Some(params) = settings.service(&view) {
                let _ =
                    commands.push_back(ControlCommand::Configure(ControlSettings::from(&params)));
                let _ = work.push(BackgroundWork::Configure(params));
            }
        });
        if !work.is_empty() {
            cx.shared.background_commands.lock(|queue| {
                for item in work {
                    let _ = queue.push_back(item);
                }
            });
            let _ = background::spawn();
        }
        // Every control step's record, each offered to USB at once so the transmit buffer never
        // holds more than a few frames; what does not fit is dropped whole (a counted gap).
        let usb = cx.local.usb;
        while let Some(record) = cx.local.telemetry.pop() {
            link.stream(&record);
            while link.transmit_to(|bytes| usb.write(bytes)) > 0 {}
        }
        link.poll(now_us, &view);
        while link.transmit_to(|bytes| usb.write(bytes)) > 0 {}
        usb.flush();
        if reboot {
            // The reply is in the USB buffer; give the host a moment to take it.
            cortex_m::asm::delay(firmware::board::config::SYS_CK_HZ / 20);
            cortex_m::peripheral::SCB::sys_reset();
        }
    }

    /// Background work at the lowest priority: drain the learner-sample queue through the
    /// portable worker and publish its results (a copy under a short lock).
    pub fn background(mut cx: background::Context) {
        let worker = &mut *cx.local.background;
        while let Some(item) = cx.shared.background_commands.lock(|queue| queue.pop_front()) {
            match item {
                BackgroundWork::Command(command) => worker.command(command),
                BackgroundWork::Configure(params) => worker.configure(&params),
            }
        }
        cx.local.background.run_pending();
        let results = cx.local.background.results();
        cx.shared.background.lock(|shared| *shared = results);
    }
}
