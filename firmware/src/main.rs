//! The STM32H743 firmware binary: an RTIC 1 application that runs the portable
//! [`firmware::app`] on the board.
//!
//! It is deliberately thin (in the manner of stabilizer's `dual-iir.rs`): it sets up clocks and
//! peripherals through [`firmware::board`], then gives each part of the data flow a task
//! (docs/architecture.md):
//!
//! | task | bound to | priority | what |
//! |---|---|---|---|
//! | `control_tick` | TIM7 update, 2 kHz | 3 (highest) | [`ControlTask::tick`](firmware::app::system::ControlTask::tick): the link's commands, the receiver's bytes → arm/disarm, one control step (IMU mean in, DShot frames out); pends `usb_service` at 1 kHz, spawns `background` when samples wait |
//! | `imu_data_ready` | EXTI2 (ICM-42688-P INT1), 8 kHz | 3 | starts the SPI DMA read of one sample (returns at once) |
//! | `imu_transfer_done` | DMA1 stream 0 complete | 3 | ends the read, adds the sample to the 8 kHz → 2 kHz mean |
//! | `motor_burst_0..2` | DMA1 streams 2–4 complete (the motor timers' DShot bursts) | 4 | switches the timer's outputs to capture the ESCs' bidirectional answers (a few dozen register writes, 28 µs after the step started the frame; the answer starts 30 µs after the frame, too soon to wait for the step to end) |
//! | `usb_service` | OTG2 (`OTG_FS`) interrupt, also pended | 2 | [`LinkTask::pass`](firmware::app::system::LinkTask::pass) on the USB CDC port and the telemetry radio's UART (`radio_baud`): requests routed, telemetry, configuration saves (flash erase); the GNSS receiver serviced ([`LinkTask::service_gnss`](firmware::app::system::LinkTask::service_gnss): its fixes to the control queue); the compass serviced ([`LinkTask::service_compass`](firmware::app::system::LinkTask::service_compass): a read every 10 ms on I2C1, about 0.2 ms, its samples to the control queue, a calibration's solve handed to `background`); then a restart if one was asked for |
//! | `gnss_received` | USART2 (the GNSS UART's receive FIFO) | 3 | moves the received bytes into the queue the link pass reads (`board::gnss`: no DMA stream is left for it) |
//! | `background` | software task (dispatcher `DCMI`) | 1 | [`run_background`](firmware::app::system::run_background): the link's work, the learner-sample queue drained, results published; then a compass calibration's solve, if one waits ([`run_compass_solve`](firmware::app::compass::run_compass_solve)) |
//! | `idle` | — | 0 | the in-flight IMU-offset fit (`app::offset_fit`), reports the control step's longest duration over defmt, sleeps (`wfi`) |
//!
//! What each task does, and in which order, is the portable application graph's
//! ([`firmware::app::system`], which the simulators run too); this file only binds its entry
//! points to interrupts and its handoffs ([`firmware::app::system::Handoffs`]) to RTIC shared
//! resources, each behind its own lock: the control step's snapshot, the background results,
//! the board's health (locked for a copy) and the two command queues; and the IMU, shared
//! lock-free by the three priority-3 tasks (equal priorities never preempt each other). Everything else is a task's `#[local]` state; the motor-burst tasks and the control
//! step touch the same motor timers at different times by construction (`board::motors`). Task bodies live outside the `#[app]` module (RTIC v1 book), in
//! [`tasks`].
//!
//! The board (pins, timers, DMA streams) is [`firmware::targets::SELECTED`], the Matek H743 V3.
//! Clocks: the silicon revision is read first (DBGMCU_IDCODE); 8 MHz HSE → PLL1 → sys_ck
//! 480 MHz at VOS0 on revision V, 400 MHz at VOS1 otherwise, hclk = sys_ck / 2; USB from HSI48
//! (see [`firmware::board::config`]). Time: TIM2 as a 1 MHz counter extended to 64-bit
//! microseconds ([`firmware::board::time`]), read by the control and USB tasks.
//!
//! On the host this file builds to a stub `main` so that `cargo build --workspace` works; the
//! simulator runs the same `firmware::app` code instead.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("the firmware binary only runs on the STM32H743; run the simulator instead: cargo run -p sim --bin sitl");
}

#[cfg(target_os = "none")]
use defmt_rtt as _;

/// On a panic: log where (file and line, over defmt), then stop the core with a permanent
/// undefined instruction (HardFault, which loops). The DShot bursts are started by the control
/// step only, so the ESCs stop receiving frames and stop the motors (their signal-loss timeout).
///
/// Our own handler rather than `panic-probe` with `print-defmt`: that one formats the panic
/// message, which links `core::fmt`'s machinery into the flash; the file and line lead to the
/// failed check in the source.
#[cfg(target_os = "none")]
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    match info.location() {
        Some(at) => defmt::error!("panic at {=str}:{=u32}", at.file(), at.line()),
        None => defmt::error!("panic"),
    }
    cortex_m::asm::udf()
}

/// `defmt::panic!` (start-up failures: no USB clock, a switch channel out of range) logs its
/// message itself; then the same stop as a panic.
#[cfg(target_os = "none")]
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    cortex_m::asm::udf()
}

/// The background worker's storage (AXI SRAM, NOLOAD): `init` builds the worker in place
/// (`Background::build_in`), so it is never a temporary on `init`'s stack.
#[cfg(target_os = "none")]
#[link_section = ".axisram.background"]
static mut BACKGROUND: core::mem::MaybeUninit<firmware::app::Background<'static>> =
    core::mem::MaybeUninit::uninit();

/// The in-flight IMU-offset fit's task (AXI SRAM, NOLOAD): its rings, and the worker that
/// `init` builds in place (`OffsetFitWorker::build_in`, 40 KB) and `idle` runs.
#[cfg(target_os = "none")]
#[link_section = ".axisram.offset_fit"]
static mut OFFSET_FIT_HANDOFF: core::mem::MaybeUninit<firmware::app::offset_fit::FitHandoff> =
    core::mem::MaybeUninit::uninit();
#[cfg(target_os = "none")]
#[link_section = ".axisram.offset_fit"]
static mut OFFSET_FIT: core::mem::MaybeUninit<firmware::app::offset_fit::OffsetFitWorker<'static>> =
    core::mem::MaybeUninit::uninit();

/// The flight log's storage (AXI SRAM, NOLOAD; `init` writes it): the ring from the control
/// tick to the logger (78 KB), and the card's log when a card answered at start-up (else the
/// logger's files are refused as `NoCard`).
#[cfg(target_os = "none")]
struct LogStorage {
    ring: firmware::app::log::LogRing,
    card: Option<firmware::app::card::CardLog<firmware::board::sdcard::BoardCard>>,
    no_card: firmware::app::log::NoCard,
}

#[cfg(target_os = "none")]
#[link_section = ".axisram.log"]
static mut LOG: core::mem::MaybeUninit<LogStorage> = core::mem::MaybeUninit::uninit();

/// The GNSS UART's receive queue and the receiver's driver (AXI SRAM, NOLOAD; `init` writes
/// them when the board has a GNSS port).
#[cfg(target_os = "none")]
#[link_section = ".axisram.gnss"]
static mut GNSS_QUEUE: core::mem::MaybeUninit<firmware::board::gnss::GnssQueue> =
    core::mem::MaybeUninit::uninit();
#[cfg(target_os = "none")]
#[link_section = ".axisram.gnss"]
static mut GNSS_INPUT: core::mem::MaybeUninit<firmware::app::gnss::GnssInput> =
    core::mem::MaybeUninit::uninit();

/// The compass service, its calibration's handoff and the background task's solver (about 7 KB
/// each with a calibration's store; AXI SRAM, NOLOAD: `init` writes them).
#[cfg(target_os = "none")]
#[link_section = ".axisram.compass"]
static mut COMPASS_INPUT: core::mem::MaybeUninit<firmware::app::compass::CompassInput> =
    core::mem::MaybeUninit::uninit();
#[cfg(target_os = "none")]
#[link_section = ".axisram.compass"]
static mut COMPASS_SOLVE: core::mem::MaybeUninit<firmware::app::compass::CompassSolveSlot> =
    core::mem::MaybeUninit::uninit();
#[cfg(target_os = "none")]
#[link_section = ".axisram.compass"]
static mut COMPASS_SOLVER: core::mem::MaybeUninit<firmware::app::compass::CompassSolver> =
    core::mem::MaybeUninit::uninit();

/// The box beside the log's ring for the control loop's state at an arming (9 KB; AXI SRAM,
/// NOLOAD: `init` writes its state byte only, `Mailbox::init_in`).
#[cfg(target_os = "none")]
#[link_section = ".axisram.log"]
static mut ARMING: core::mem::MaybeUninit<firmware::app::log::ArmingBox> =
    core::mem::MaybeUninit::uninit();

/// The tasks' largest states, built where they lie by `init` rather than returned to RTIC by
/// value: RTIC 1 takes `init`'s resources by value, and at opt-level "z" each by-value move of a
/// 4-9 KB state kept its own copy in `init`'s frame (65 KB of it; docs/budget.md). The control
/// task stays in DTCM (the 2 kHz step's data, zero wait states); the links and the link task
/// too (serviced at 1 kHz). The log writer (2 KB) and the queues are still returned by value.
#[cfg(target_os = "none")]
static mut CONTROL: core::mem::MaybeUninit<firmware::app::system::ControlTask<'static>> =
    core::mem::MaybeUninit::uninit();
#[cfg(target_os = "none")]
static mut USB_LINK: core::mem::MaybeUninit<
    firmware::app::system::Link<firmware::board::usb::UsbSerial>,
> = core::mem::MaybeUninit::uninit();
#[cfg(target_os = "none")]
static mut RADIO_LINK: core::mem::MaybeUninit<
    Option<firmware::app::system::Link<firmware::board::radio::BoardRadio>>,
> = core::mem::MaybeUninit::uninit();
#[cfg(target_os = "none")]
static mut LINK_TASK: core::mem::MaybeUninit<
    firmware::app::system::LinkTask<'static, firmware::board::flash::ConfigSectors>,
> = core::mem::MaybeUninit::uninit();

// The RTIC application: resources, initialisation and the task table.
#[cfg(target_os = "none")]
#[rtic::app(device = stm32h7xx_hal::pac, peripherals = true, dispatchers = [DCMI])]
mod app {
    use crate::tasks::{
        background, control_tick, gnss_received, imu_data_ready, imu_transfer_done, motor_burst_0,
        motor_burst_1, motor_burst_2, usb_service,
    };
    use firmware::app::card::CardLog;
    use firmware::app::compass::{CompassInput, CompassSolveSlot, CompassSolver};
    use firmware::app::gnss::GnssInput;
    use firmware::app::hal::Motors;
    use firmware::app::log::{LogRing, LogSink, Logger, NoCard};
    use firmware::app::offset_fit::{FitHandoff, OffsetFitWorker};
    use firmware::app::radio::Receiver;
    use firmware::app::system::{ControlQueue, ControlTask, Link, LinkTask, WorkQueue};
    use firmware::app::{
        split_queue, Background, BackgroundResults, BoardInfo, ControlConfig, ControlLoop,
        ControlSnapshot, LinkServer, SampleQueue, Settings, StepRing,
    };
    use firmware::board::battery::BoardBattery;
    use firmware::board::config::{clock_plan, silicon_revision, TIME_BASE_HZ};
    use firmware::board::flash::ConfigSectors;
    use firmware::board::gnss::{self, BoardGnss, GnssQueue, GnssRx};
    use firmware::board::i2c::BoardI2c;
    use firmware::board::identity::{uid_hex, UID_HEX_CHARS};
    use firmware::board::imu::{BoardImu, CycleDelay};
    use firmware::board::motors::{BoardMotors, BurstCompletion};
    use firmware::board::radio::BoardRadio;
    use firmware::board::receiver::BoardReceiver;
    use firmware::board::sdcard::{card_stats, BoardCard, CardStats};
    use firmware::board::time::MicrosClock;
    use firmware::board::timing::{step_stats, StepStats, StepTimer};
    use firmware::board::usb::{self, UsbSerial, UsbStorage, EP_MEMORY_WORDS};
    use firmware::board::{bootloader, BOARD};
    use firmware::drivers::crsf::RcLinkConfig;
    use protocol::{BoardHealth, Capabilities, ImuDriverState};
    use stm32h7xx_hal::flash::FlashExt;
    use stm32h7xx_hal::pac;
    use stm32h7xx_hal::prelude::*;
    use stm32h7xx_hal::rcc::rec::UsbClkSel;
    use stm32h7xx_hal::rcc::PllConfigStrategy;
    use stm32h7xx_hal::timer::{Event, Timer};
    use stm32h7xx_hal::usb_hs::USB2;
    use usb_device::bus::UsbBusAllocator;

    // The interrupts bound below must be the board's: EXTI line of the IMU's data-ready pin and
    // the IMU's RX DMA stream (`targets::FIRMWARE_IMU_*`, checked on the host too).
    const _: () = assert!(
        BOARD.imu.data_ready.number == 2
            && BOARD.imu.rx_dma.controller == 1
            && BOARD.imu.rx_dma.stream == 0
    );

    /// The application graph's handoffs ([`firmware::app::system::Handoffs`]), each behind its
    /// own lock.
    #[shared]
    struct Shared {
        /// Written by `control_tick` every step, read by `usb_service`.
        snapshot: ControlSnapshot,
        /// Written by `background` after each run, read by `control_tick` and `usb_service`.
        results: BackgroundResults,
        /// Clocks and drivers: written by `init` and (motors, receiver) by `control_tick` at
        /// 1 kHz, read by `usb_service` (`GetBoard`).
        board: BoardHealth,
        /// Commands for the control step (arm, disarm, pose, settings, motor test): pushed by
        /// `usb_service`, taken by `control_tick` at the start of its next step.
        commands: ControlQueue,
        /// Work for the background task (calibration start and stop, new parameters): pushed by
        /// `usb_service`, taken by `background` when it next runs.
        work: WorkQueue,
        /// The IMU: its data-ready and DMA tasks fill the 8 kHz mean, the control step takes it.
        /// All three run at priority 3, so no lock is needed.
        #[lock_free]
        imu: BoardImu,
        /// The flight log's writer and its card: `background` drains the control tick's entries
        /// into it (locked per entry), `usb_service` reads and deletes its files (locked per
        /// chunk).
        log: Logger<'static>,
        /// The compass calibration's solves: `usb_service` copies in what was gathered and
        /// takes the outcome, `background` solves (each locked for a copy).
        compass_solve: &'static mut CompassSolveSlot,
    }

    /// Each task's own state.
    #[local]
    struct Local {
        control_timer: Timer<pac::TIM7>,
        step_timer: StepTimer,
        control_clock: MicrosClock,
        /// The control loop and the pilot's receiver policy.
        control: &'static mut ControlTask<'static>,
        motors: BoardMotors,
        /// Each motor timer's switch to capture, for its burst task (`None`: no such timer, or
        /// ESCs without bidirectional DShot).
        burst_0: Option<BurstCompletion>,
        burst_1: Option<BurstCompletion>,
        burst_2: Option<BurstCompletion>,
        /// The receiver's UART ring, read by the control tick.
        receiver: BoardReceiver,
        /// The battery's ADC, read by the control tick.
        battery: BoardBattery,
        usb_clock: MicrosClock,
        /// The USB CDC port and its protocol endpoint.
        usb: &'static mut Link<UsbSerial>,
        /// The telemetry radio's UART and its (untrusted) protocol endpoint, when configured.
        radio: &'static mut Option<Link<BoardRadio>>,
        /// The GNSS receiver's UART, serviced by the link pass (`None`: no GNSS port).
        gnss: Option<BoardGnss>,
        /// Its receive interrupt's end.
        gnss_rx: Option<GnssRx>,
        /// The compass's I²C bus, serviced by the link pass (`None`: no compass bus), and the
        /// busy wait of its sensor's initialisation.
        compass_bus: Option<BoardI2c>,
        compass_delay: CycleDelay,
        /// The compass calibration's solver (`background`).
        compass_solver: &'static mut CompassSolver,
        /// The parameters and their store in flash bank 2 (`board::flash`: ECC-safe reads), and
        /// the link task's end of the telemetry ring (one record per control step).
        link: &'static mut LinkTask<'static, ConfigSectors>,
        /// The learner, the thrust-axis solver and the IMU-offset estimator (with the drag
        /// model's store of a throw's blocks): 55 KB that only the lowest-priority task touches,
        /// in AXI SRAM so that DTCM keeps room for the stack, built there in place by `init`
        /// ([`BACKGROUND`]; docs/budget.md).
        background: &'static mut Background<'static>,
        /// The in-flight IMU-offset fit (`idle`): 40 KB in AXI SRAM like the background's,
        /// built there in place by `init` ([`OFFSET_FIT`]).
        offset_fit: &'static mut OffsetFitWorker<'static>,
    }

    #[init(local = [
        samples: SampleQueue = SampleQueue::new(),
        step_ring: StepRing = StepRing::new(),
        ep_memory: [u32; EP_MEMORY_WORDS] = [0; EP_MEMORY_WORDS],
        usb_bus: Option<UsbBusAllocator<usb::Bus>> = None,
        uid_text: heapless::String<UID_HEX_CHARS> = heapless::String::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local, init::Monotonics) {
        // First of all, before any clock or peripheral is touched: did the previous run ask for
        // the ROM bootloader?
        if bootloader::take_request() {
            // SAFETY: nothing is configured yet (see `jump_to_bootloader`).
            unsafe { bootloader::jump_to_bootloader() }
        }
        let dp = cx.device;
        let mut core = cx.core;

        // Keep the debug port alive while the core sleeps in `wfi`, so probe-rs and defmt-rtt
        // keep working (RM0433 §60.5.8, DBGMCU_CR).
        dp.DBGMCU
            .cr
            .modify(|_, w| w.dbgsleep_d1().set_bit().dbgstop_d1().set_bit().dbgstby_d1().set_bit());
        core.SCB.enable_icache();

        // Clocks: the silicon revision decides 480 MHz (VOS0) or 400 MHz (VOS1); LDO supply;
        // HSE → PLL1 (wide VCO, the HAL's `Iterative` strategy: 8 MHz / 1 × 120 = 960 MHz / 2 =
        // 480 MHz, or × 100 = 800 MHz / 2 = 400 MHz); USB from the 48 MHz internal RC (HSI48).
        let revision = silicon_revision();
        let plan = clock_plan(revision);
        let pwr = dp.PWR.constrain();
        let pwr = if plan.vos0 { pwr.vos0(&dp.SYSCFG) } else { pwr };
        let pwrcfg = pwr.freeze();
        let mut rcc = dp
            .RCC
            .constrain()
            .use_hse(BOARD.hse_hz.Hz())
            .sys_ck(plan.sys_ck_hz.Hz())
            .hclk(plan.hclk_hz.Hz())
            .pll1_strategy(PllConfigStrategy::Iterative)
            // SDMMC1's kernel clock (the microSD card; 96 or 100 MHz, divided down to 25 MHz).
            .pll1_q_ck(100.MHz());
        if BOARD.hse_bypass {
            rcc = rcc.bypass_hse();
        }
        let mut ccdr = rcc.freeze(pwrcfg, &dp.SYSCFG);
        if ccdr.clocks.hsi48_ck().is_none() {
            defmt::panic!("HSI48 is not running: USB has no clock");
        }
        ccdr.peripheral.kernel_usb_clk_mux(UsbClkSel::Hsi48);
        let sys_ck_hz = ccdr.clocks.sys_ck().raw();
        let cycles_per_us = sys_ck_hz / 1_000_000;

        // Time base: TIM2 counting microseconds.
        let time_base = dp.TIM2.tick_timer(TIME_BASE_HZ.Hz(), ccdr.peripheral.TIM2, &ccdr.clocks);
        let clock = MicrosClock::new(time_base);

        // USB CDC on OTG2's internal full-speed PHY (PA11 = D−, PA12 = D+, AF10). GPIOA is split
        // (enabled and reset by the HAL) before the board's other pins on port A are set up.
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

        // The configuration store: bank 2's configuration sectors, read through DMA.
        let (_bank1, bank2) = dp.FLASH.split();
        let mut settings = match bank2 {
            Some(bank2) => {
                let sectors =
                    ConfigSectors::new(bank2, BOARD.config_bank_offsets(), BOARD.flash_read_dma);
                let capacity = BOARD.flash.config_len;
                Settings::load(sectors, 0..capacity)
            }
            None => Settings::without_store(),
        };

        // The microSD card (identified now, at 400 kHz then 25 MHz) and the log's storage.
        let card = BOARD.sdcard.and_then(|wiring| {
            BoardCard::start(wiring, dp.SDMMC1, ccdr.peripheral.SDMMC1, &ccdr.clocks)
        });
        let card = card.and_then(|card| CardLog::mount(card).ok());
        if card.is_none() {
            defmt::warn!("no microSD card: the flight log is not kept");
        }
        // SAFETY: `init` runs once, before any task: this is the storage's only reference.
        let log_storage = unsafe {
            (*core::ptr::addr_of_mut!(crate::LOG)).write(crate::LogStorage {
                ring: LogRing::new(),
                card,
                no_card: NoCard,
            })
        };
        let sink: &'static mut dyn LogSink = match &mut log_storage.card {
            Some(card) => card,
            None => &mut log_storage.no_card,
        };
        // SAFETY: as above, the box's only reference; `init_in` makes it a valid empty box.
        let arming = unsafe {
            let arming = (*core::ptr::addr_of_mut!(crate::ARMING)).as_mut_ptr();
            firmware::app::log::ArmingBox::init_in(arming);
            &mut *arming
        };
        let (log_producer, log_consumer) =
            firmware::app::log::split_log(&mut log_storage.ring, arming);

        // The signing session of this start-up (`protocol::signing`): 64 bits from the RNG,
        // clocked by HSI48 (on: USB runs from it). Should the RNG fail its self-test, the
        // session is 0: frames signed before a restart would then pass after it (a weaker
        // replay guard, said in the log), never a refused flight.
        let session = {
            use stm32h7xx_hal::rng::{RngCore, RngExt};
            let mut rng = dp.RNG.constrain(ccdr.peripheral.RNG, &ccdr.clocks);
            RngCore::<u64>::gen(&mut rng).unwrap_or_else(|_| {
                defmt::warn!("the RNG failed: the signing session is 0");
                0
            })
        };
        settings.set_link_session(session);

        // The drivers.
        let imu = BoardImu::new(BOARD.imu, cycles_per_us);
        // Bidirectional DShot when the board can and the parameter says the ESCs answer.
        let bidirectional = BOARD.motor_bidirectional && settings.params().bidirectional_dshot();
        let motors = BoardMotors::new(BOARD, ccdr.clocks.timx_ker_ck().raw(), bidirectional);
        let receiver = BoardReceiver::new(BOARD.receiver, ccdr.clocks.pclk2().raw());
        let battery = BoardBattery::new(BOARD.battery, cycles_per_us);
        if !battery.is_running() {
            defmt::warn!("the battery ADC did not start: no battery reported");
        }
        // The default switches (channels 5, 6, 7) are valid by construction.
        let radio = match Receiver::new(RcLinkConfig::default()) {
            Ok(radio) => radio,
            Err(_) => defmt::panic!("RC switch channel out of range"),
        };
        let imu_state = imu.state();
        let board = BoardHealth {
            core_clock_hz: Some(sys_ck_hz),
            silicon_revision: Some(revision),
            imu: imu_state,
            motors: motors.health(),
            receiver: Some(radio.health(0)),
        };

        // The portable application: control loop → sample queue → background worker.
        let config = ControlConfig::default();
        let (producer, consumer) = split_queue(cx.local.samples);
        let (ring_producer, telemetry) = split_queue(cx.local.step_ring);
        // SAFETY: `init` runs once, before any task: this is the static's only reference.
        let control = unsafe {
            (*core::ptr::addr_of_mut!(crate::CONTROL))
                .write(ControlTask::new(ControlLoop::new(config, producer), Some(radio)))
        };
        control.set_log(log_producer);
        control.control_mut().set_telemetry(ring_producer);
        // SAFETY: `init` runs once, before any task: this is the storage's only reference.
        // SAFETY: as above, the static's only reference.
        let handoff = unsafe {
            (*core::ptr::addr_of_mut!(crate::OFFSET_FIT_HANDOFF)).write(FitHandoff::new())
        };
        let (fit_client, fit_ends) = handoff.split(f32::from(config.rate_hz));
        // SAFETY: as above.
        let offset_fit = OffsetFitWorker::build_in(
            unsafe { &mut *core::ptr::addr_of_mut!(crate::OFFSET_FIT) },
            fit_ends,
        );
        // SAFETY: as above.
        let storage = unsafe { &mut *core::ptr::addr_of_mut!(crate::BACKGROUND) };
        let background = Background::build_in(storage, consumer, fit_client, config.rate_hz);
        let mut serial = heapless::String::new();
        // The 24-character UID always fits the protocol's 32-byte field.
        let _ = serial.push_str(uid_text);
        let mut capabilities = Capabilities::TELEMETRY
            | Capabilities::MOTORS
            | Capabilities::RECEIVER
            | Capabilities::BOOTLOADER
            | Capabilities::ESC_COMMANDS;
        if imu_state == ImuDriverState::Running {
            capabilities |= Capabilities::IMU;
        }
        if bidirectional {
            // The ESCs answer every frame with their eRPM (`board::motors`).
            capabilities |= Capabilities::MOTOR_RPM;
        }
        // Every image identifies without speeds when told so (`motor_bidir_dshot` = 0, issue 56).
        capabilities |= Capabilities::IDENTIFIES_WITHOUT_SPEEDS;
        if settings.status().origin != protocol::ConfigOrigin::NoStore {
            capabilities |= Capabilities::PERSISTENT_STORE;
        }
        let board_info = BoardInfo {
            board: BOARD.name,
            serial,
            capabilities,
            control_rate_hz: config.rate_hz,
            motor_count: motors.count(),
        };
        // The telemetry radio (`radio_baud`, read at start-up as the ESCs' protocol is): the
        // same protocol as USB on an untrusted link with the radio's byte budget.
        // SAFETY: as above.
        let telemetry_radio = unsafe {
            (*core::ptr::addr_of_mut!(crate::RADIO_LINK)).write(settings.params().radio_baud().map(
                |baud| {
                    let port =
                        BoardRadio::new(BOARD.telemetry_radio, ccdr.clocks.pclk2().raw(), baud);
                    let server = LinkServer::new(board_info.clone())
                        .untrusted()
                        .with_byte_rate(firmware::board::radio::byte_rate(baud));
                    Link::new(server, port)
                },
            ))
        };
        // The GNSS receiver's port (pads TX2/RX2), searched for from start-up at every rate.
        let (gnss_rx, gnss, gnss_input) = match BOARD.gnss {
            Some(wiring) => {
                // SAFETY: `init` runs once, before any task: these are the statics' only
                // references from now on.
                let (queue, input) = unsafe {
                    let queue =
                        (*core::ptr::addr_of_mut!(crate::GNSS_QUEUE)).write(GnssQueue::new());
                    let input =
                        (*core::ptr::addr_of_mut!(crate::GNSS_INPUT)).write(GnssInput::new(
                            settings.params().gnss_config(),
                            settings.params().gnss_latency_s(),
                        ));
                    (queue, input)
                };
                let target_baud = settings.params().gnss_config().target_baud;
                let pclk1_hz = ccdr.clocks.pclk1().raw();
                let (rx, port) = gnss::start(wiring, pclk1_hz, target_baud, queue);
                (Some(rx), Some(port), Some(input))
            }
            None => (None, None, None),
        };
        // The compass's bus (the GNSS mast's SCL/SDA), probed for a sensor from the first pass.
        // SAFETY: `init` runs once, before any task: these are the statics' only references.
        // Built in place: 7 KB each, never on this stack.
        let (compass_input, compass_solve, compass_solver) = unsafe {
            (
                CompassInput::build_in(&mut *core::ptr::addr_of_mut!(crate::COMPASS_INPUT)),
                CompassSolveSlot::build_in(&mut *core::ptr::addr_of_mut!(crate::COMPASS_SOLVE)),
                CompassSolver::build_in(&mut *core::ptr::addr_of_mut!(crate::COMPASS_SOLVER)),
            )
        };
        let compass_bus = BOARD
            .compass
            .map(|wiring| BoardI2c::new(wiring, ccdr.clocks.pclk1().raw(), cycles_per_us));
        let link = LinkServer::new(board_info);
        let shared = Shared {
            snapshot: control.control().snapshot(),
            results: background.results(),
            board,
            commands: ControlQueue::new(),
            work: WorkQueue::new(),
            imu,
            log: Logger::new(log_consumer, sink, BOARD.name, config.rate_hz)
                .with_params(settings.params()),
            compass_solve,
        };

        // The control tick at the application's rate (2 kHz), started last so the first step
        // finds everything ready.
        let control_rate_hz = u32::from(config.rate_hz);
        let step_timer =
            StepTimer::new(&mut core.DCB, core.DWT, 1_000_000 / control_rate_hz, sys_ck_hz);
        let mut control_timer =
            dp.TIM7.timer(control_rate_hz.Hz(), ccdr.peripheral.TIM7, &ccdr.clocks);
        control_timer.listen(Event::TimeOut);

        defmt::info!(
            "{=str} {=str} up: REV_ID {=u16:#x}, sys_ck {} Hz, hclk {} Hz, control {} Hz",
            BOARD.name,
            uid_text,
            revision,
            sys_ck_hz,
            ccdr.clocks.hclk().raw(),
            control_rate_hz
        );

        let local = Local {
            control_timer,
            step_timer,
            control_clock: clock,
            control,
            burst_0: motors.completion(0),
            burst_1: motors.completion(1),
            burst_2: motors.completion(2),
            motors,
            receiver,
            battery,
            usb_clock: clock,
            // SAFETY: as above, the statics' only references.
            usb: unsafe { (*core::ptr::addr_of_mut!(crate::USB_LINK)).write(Link::new(link, usb)) },
            radio: telemetry_radio,
            link: unsafe {
                (*core::ptr::addr_of_mut!(crate::LINK_TASK)).write(match gnss_input {
                    Some(input) => LinkTask::new(settings, telemetry).with_gnss(input),
                    None => LinkTask::new(settings, telemetry),
                })
            },
            gnss,
            gnss_rx,
            compass_bus,
            compass_delay: CycleDelay { cycles_per_us },
            compass_solver,
            background,
            offset_fit,
        };
        // Attached where it lies (a `with_compass` on the task by value would add copies of
        // the whole link task, 4 KB each, to this frame).
        if local.compass_bus.is_some() {
            local.link.set_compass(compass_input);
        }
        (shared, local, init::Monotonics())
    }

    /// Between interrupts: the in-flight IMU-offset fit's waiting work
    /// (`firmware::app::offset_fit`: below every task, nothing waits for it but the estimate's
    /// hand-back 20 ms later), then report the control step's timing over defmt when it
    /// changed, then sleep until the next interrupt (work pushed after the fit's run waits for
    /// it: at most one control period). defmt-rtt writes with interrupts masked for the few µs a
    /// message takes and, built with `disable-blocking-mode`, drops messages rather than wait
    /// for the probe, so logging here delays the control interrupt by microseconds at most.
    ///
    /// Likewise the microSD card's write time (`board::sdcard::card_stats`): when its longest
    /// block write grows, and every 4,096 blocks (about 12 s of log).
    #[idle(local = [
        offset_fit,
        reported: StepStats = StepStats { max_us: 0, overruns: 0 },
        card_reported: CardStats = CardStats { write_max_us: 0, blocks: 0 },
    ])]
    fn idle(cx: idle::Context) -> ! {
        loop {
            cx.local.offset_fit.run_pending();
            let stats = step_stats();
            if stats != *cx.local.reported {
                defmt::info!(
                    "control step: longest {} us, {} over the deadline",
                    stats.max_us,
                    stats.overruns
                );
                *cx.local.reported = stats;
            }
            let card = card_stats();
            let reported = *cx.local.card_reported;
            if card.write_max_us != reported.write_max_us
                || card.blocks / 4096 != reported.blocks / 4096
            {
                defmt::info!(
                    "card: longest block write {} us, {} blocks",
                    card.write_max_us,
                    card.blocks
                );
                *cx.local.card_reported = card;
            }
            cortex_m::asm::wfi();
        }
    }

    extern "Rust" {
        #[task(
            binds = TIM7,
            priority = 3,
            local = [control_timer, step_timer, control_clock, control, motors, receiver, battery],
            shared = [snapshot, results, commands, board, imu]
        )]
        fn control_tick(cx: control_tick::Context);

        #[task(binds = EXTI2, priority = 3, shared = [imu])]
        fn imu_data_ready(cx: imu_data_ready::Context);

        #[task(binds = DMA1_STR0, priority = 3, shared = [imu])]
        fn imu_transfer_done(cx: imu_transfer_done::Context);

        // The motor timers' burst streams (`targets::FIRMWARE_MOTOR_BURST_DMA`), above the
        // control step: see `board::motors`.
        #[task(binds = DMA1_STR2, priority = 4, local = [burst_0])]
        fn motor_burst_0(cx: motor_burst_0::Context);

        #[task(binds = DMA1_STR3, priority = 4, local = [burst_1])]
        fn motor_burst_1(cx: motor_burst_1::Context);

        #[task(binds = DMA1_STR4, priority = 4, local = [burst_2])]
        fn motor_burst_2(cx: motor_burst_2::Context);

        #[task(binds = OTG_FS, priority = 2, local = [usb_clock, usb, radio, gnss, compass_bus, compass_delay, link], shared = [snapshot, results, board, commands, work, log, compass_solve])]
        fn usb_service(cx: usb_service::Context);

        #[task(binds = USART2, priority = 3, local = [gnss_rx])]
        fn gnss_received(cx: gnss_received::Context);

        #[task(priority = 1, local = [background, compass_solver], shared = [results, work, log, compass_solve])]
        fn background(cx: background::Context);
    }
}

/// The task bodies (RTIC v1 "extern" tasks): each binds its task's resources to an entry point of
/// the application graph ([`firmware::app::system`]) and does what only the board can (clear
/// the timer, measure the step, pend and spawn tasks, restart the chip).
#[cfg(target_os = "none")]
mod tasks {
    use crate::app::{
        background, control_tick, gnss_received, imu_data_ready, imu_transfer_done, motor_burst_0,
        motor_burst_1, motor_burst_2, usb_service,
    };
    use firmware::app::compass::{run_compass_solve, CompassSolveSlot};
    use firmware::app::system::{
        run_background, Mutex, PassShared, Restart, TickHardware, TickShared,
    };
    use firmware::board::bootloader;
    use firmware::board::timing::{cycles_per_us, step_stats};
    use protocol::StepTime;
    use stm32h7xx_hal::pac::Interrupt;

    /// One control step, on every TIM7 update at 2 kHz, at the highest priority.
    ///
    /// Deadline: 500 µs (one period of the 2 kHz loop; the next IMU mean is due then). It
    /// never blocks and never allocates: the receiver drains at most one DMA ring of bytes, the
    /// IMU hands over a mean already summed, the motor outputs restart three DMA streams, the
    /// sample queue drops and counts when full, the locks are uncontended (no higher-priority
    /// task shares them) and held for a copy or a queue operation, and the only interrupts-off
    /// sections are a few instructions long (the clock's 64-bit extension, RTIC's spawn queue).
    /// Its own duration is measured against the deadline (`board::timing`) and reported from
    /// `idle`. The order of its work is [`firmware::app::system::ControlTask::tick`]'s.
    pub fn control_tick(cx: control_tick::Context) {
        let started = cx.local.step_timer.start();
        cx.local.control_timer.clear_irq();
        let now_us = cx.local.control_clock.now_us();
        let mut shared = TickShared {
            commands: cx.shared.commands,
            results: cx.shared.results,
            snapshot: cx.shared.snapshot,
            board: cx.shared.board,
        };
        let hardware = TickHardware {
            imu: cx.shared.imu,
            motors: cx.local.motors,
            radio_bytes: cx.local.receiver,
            battery: cx.local.battery,
        };
        let outcome = cx.local.control.tick(now_us, hardware, &mut shared);
        if outcome.background_due {
            // `Err` means a run is already queued; it drains everything, so nothing is lost.
            let _ = background::spawn();
        }
        if outcome.link_due {
            // Telemetry must flow even when the host sends nothing (no USB interrupt).
            rtic::pend(Interrupt::OTG_FS);
        }
        cx.local.step_timer.finish(started);
    }

    /// The IMU's data-ready line (8 kHz): start the DMA read of one sample.
    pub fn imu_data_ready(cx: imu_data_ready::Context) {
        cx.shared.imu.on_data_ready();
    }

    /// The IMU's RX DMA stream finished: add the sample to the mean.
    pub fn imu_transfer_done(cx: imu_transfer_done::Context) {
        cx.shared.imu.on_transfer_complete();
    }

    /// A motor timer's DShot burst has ended: its outputs capture the ESCs' answers.
    pub fn motor_burst_0(cx: motor_burst_0::Context) {
        if let Some(burst) = cx.local.burst_0 {
            burst.on_burst_complete();
        }
    }

    /// See [`motor_burst_0`].
    pub fn motor_burst_1(cx: motor_burst_1::Context) {
        if let Some(burst) = cx.local.burst_1 {
            burst.on_burst_complete();
        }
    }

    /// See [`motor_burst_0`].
    pub fn motor_burst_2(cx: motor_burst_2::Context) {
        if let Some(burst) = cx.local.burst_2 {
            burst.on_burst_complete();
        }
    }

    /// The USB link, on every OTG2 interrupt and at 1 kHz from the control step: one link pass
    /// ([`firmware::app::system::LinkTask::pass`]) on the CDC port. Never blocks, except for a
    /// configuration save, which erases a flash sector (up to seconds, at this priority: the
    /// control step preempts it), and a restart's 50 ms wait.
    pub fn usb_service(cx: usb_service::Context) {
        let now_us = cx.local.usb_clock.now_us();
        let step = step_stats();
        let mut shared = PassShared {
            snapshot: cx.shared.snapshot,
            results: cx.shared.results,
            board: cx.shared.board,
            commands: cx.shared.commands,
            work: cx.shared.work,
            logs: cx.shared.log,
        };
        let step_time = Some(StepTime { max_us: step.max_us, overruns: step.overruns });
        let mut links = (&mut *cx.local.usb, &mut *cx.local.radio);
        let outcome = cx.local.link.pass(now_us, &mut links, step_time, &mut shared);
        if let Some(gnss) = cx.local.gnss.as_mut() {
            cx.local.link.service_gnss(now_us, gnss, &mut shared.commands);
        }
        // The compass: a read when one is due (every 10 ms, about 0.2 ms of I²C), its sample to
        // the control queue, a calibration's solve handed to the background task.
        let mut solve_due = false;
        if let Some(bus) = cx.local.compass_bus.as_mut() {
            solve_due = cx.local.link.service_compass(
                now_us,
                bus,
                cx.local.compass_delay,
                &mut shared.commands,
                &mut shared.snapshot,
                &mut SlotLock(cx.shared.compass_solve),
            );
        }
        if outcome.background_due || solve_due {
            let _ = background::spawn();
        }
        if let Some(restart) = outcome.restart {
            // The reply is in the USB buffer; give the host 50 ms to take it. The motors are
            // stopped (the links refuse a restart while anything is armed), so the control step
            // may starve meanwhile.
            cortex_m::asm::delay(cycles_per_us().saturating_mul(50_000));
            if restart == Restart::Bootloader {
                bootloader::restart_into_bootloader();
            }
            cortex_m::peripheral::SCB::sys_reset();
        }
    }

    /// The GNSS UART's receive interrupt: its FIFO into the queue the link pass reads.
    pub fn gnss_received(cx: gnss_received::Context) {
        if let Some(rx) = cx.local.gnss_rx.as_mut() {
            rx.on_interrupt();
        }
    }

    /// Background work at the lowest priority ([`firmware::app::system::run_background`]).
    pub fn background(cx: background::Context) {
        let (mut work, mut results, mut log) = (cx.shared.work, cx.shared.results, cx.shared.log);
        run_background(cx.local.background, Some(&mut log), &mut work, &mut results);
        run_compass_solve(cx.local.compass_solver, &mut SlotLock(cx.shared.compass_solve));
    }

    /// An RTIC resource holding a `&'static mut` to a handoff, locked as the handoff itself.
    struct SlotLock<M>(M);

    impl<M: Mutex<T = &'static mut CompassSolveSlot>> Mutex for SlotLock<M> {
        type T = CompassSolveSlot;
        fn lock<R>(&mut self, f: impl FnOnce(&mut CompassSolveSlot) -> R) -> R {
            self.0.lock(|slot| f(slot))
        }
    }
}
