//! Targets: the descriptions of the boards this firmware runs on (Betaflight's word for a board
//! definition) — which pin, timer channel, DMA stream and UART each function of the flight
//! controller uses, as plain data that builds and is tested on the host — and the chip's facts
//! ([`h743`]). The code that drives them on the chip is `crate::board` (target only).
//!
//! The STM32H743 board layer (`crate::board`, target only) has no per-board code: it reads the
//! [`BoardDescription`] selected by [`SELECTED`] and programs the GPIO, DMA, DMAMUX, timer, SPI and
//! UART registers from it, with the chip facts (register addresses, DMAMUX request numbers,
//! clock-enable bits, alternate functions) from [`h743`]. Porting to another H743 flight
//! controller is one new file beside [`matek_h743`] and a change of [`SELECTED`]; the host test
//! `firmware/tests/board_description.rs` then checks it with [`BoardDescription::check`]: no pin,
//! DMA stream or timer channel used twice, every motor on a timer channel with a burst DMA
//! stream, every alternate function one the chip really has, the configuration flash sectors
//! outside the firmware's.
//!
//! Two things are fixed by the firmware rather than the board, and checked here against it: the
//! microsecond time base is TIM2 and the 2 kHz control tick is TIM7 (`src/main.rs` binds their
//! interrupts), and the IMU's data-ready EXTI line and DMA completion interrupt are bound by name
//! in `src/main.rs` ([`FIRMWARE_IMU_EXTI_LINE`], [`FIRMWARE_IMU_RX_DMA`]), as are the motor
//! bursts' completion interrupts that switch the outputs to capture the ESCs' answers
//! ([`FIRMWARE_MOTOR_BURST_DMA`]).

pub mod h743;
pub mod matek_h743;

use h743::{Function, Timer};

/// The board this firmware is built for.
pub const SELECTED: &BoardDescription = &matek_h743::MATEK_H743_V3;

/// The EXTI line `src/main.rs` binds the IMU's data-ready task to (`EXTI2`).
pub const FIRMWARE_IMU_EXTI_LINE: u8 = 2;
/// The DMA stream whose completion interrupt `src/main.rs` binds the IMU's read task to
/// (`DMA1_STR0`).
pub const FIRMWARE_IMU_RX_DMA: DmaStream = DmaStream { controller: 1, stream: 0 };
/// The DMA streams whose completion interrupts `src/main.rs` binds to the motor-burst task
/// (`DMA1_STR2`, `DMA1_STR3`, `DMA1_STR4`), in the order of the board's motor timers: the task
/// switches that timer's outputs to capture the bidirectional DShot answer
/// (`board::motors`).
pub const FIRMWARE_MOTOR_BURST_DMA: [DmaStream; 3] = [
    DmaStream { controller: 1, stream: 2 },
    DmaStream { controller: 1, stream: 3 },
    DmaStream { controller: 1, stream: 4 },
];
/// The timer of the microsecond time base (`board::time`), 32 bits.
pub const FIRMWARE_TIME_BASE: Timer = Timer::Tim2;
/// The timer of the 2 kHz control tick (`src/main.rs` binds `TIM7`).
pub const FIRMWARE_CONTROL_TICK: Timer = Timer::Tim7;

/// A GPIO port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Port {
    A,
    B,
    C,
    D,
    E,
}

impl Port {
    /// 0 for A, 1 for B, …: the port's register block is `GPIOA + 0x400 · index` and its clock
    /// enable is bit `index` of RCC_AHB4ENR.
    pub const fn index(self) -> u8 {
        self as u8
    }
}

/// A pin: port and number 0..=15.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pin {
    pub port: Port,
    pub number: u8,
}

/// Shorthand for a [`Pin`].
pub const fn pin(port: Port, number: u8) -> Pin {
    Pin { port, number }
}

/// A pin in alternate-function mode: which function, through which AF number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AltPin {
    pub pin: Pin,
    pub function: Function,
    /// AF0..=AF15 (datasheet DS12110 "Alternate function" tables).
    pub af: u8,
}

/// One stream of DMA1 or DMA2 (the DMAMUX1 channel is `8 · (controller − 1) + stream`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DmaStream {
    /// 1 or 2.
    pub controller: u8,
    /// 0..=7.
    pub stream: u8,
}

impl DmaStream {
    /// The DMAMUX1 channel routed to this stream (RM0433 §17.3.2: channels 0–7 → DMA1 streams
    /// 0–7, channels 8–15 → DMA2 streams 0–7).
    pub const fn dmamux_channel(self) -> u8 {
        8 * (self.controller - 1) + self.stream
    }
}

/// The ICM-42688-P: SPI pins, chip select, data-ready line and the two DMA streams.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImuWiring {
    pub spi: h743::Spi,
    pub sck: AltPin,
    pub miso: AltPin,
    pub mosi: AltPin,
    /// Chip select, active low, driven as a GPIO.
    pub cs: Pin,
    /// INT1 (data ready), rising edge through EXTI.
    pub data_ready: Pin,
    /// Peripheral → memory (the sample bytes).
    pub rx_dma: DmaStream,
    /// Memory → peripheral (the address byte and dummies).
    pub tx_dma: DmaStream,
    /// SPI clock for the start-up register sequence, Hz (slow and safe).
    pub init_clock_hz: u32,
    /// SPI clock for the sample reads, Hz (the ICM-42688-P allows 24 MHz).
    pub read_clock_hz: u32,
}

/// One motor output: its pin, the timer channel that drives it, and the DMA stream that
/// captures the ESC's bidirectional DShot answer on that channel (input capture of both edges).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MotorOutput {
    pub pin: AltPin,
    pub timer: Timer,
    /// 1..=4.
    pub channel: u8,
    pub capture_dma: DmaStream,
}

/// A timer that drives motor outputs with DShot: its update event requests a DMA burst that
/// writes the next bit's compare values of all its motor channels (TIMx_DCR/DMAR).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MotorTimer {
    pub timer: Timer,
    pub dma: DmaStream,
}

/// A UART: RX by a circular DMA, TX through its FIFO (`board::serial`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UartWiring {
    pub uart: h743::Uart,
    pub rx: AltPin,
    pub tx: AltPin,
    pub rx_dma: DmaStream,
}

/// The GNSS receiver's UART: received by interrupt (every DMA stream of the H743 has a job
/// already: `board::gnss`), sent through its FIFO, 8N1 at whatever rate the driver sets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GnssWiring {
    pub uart: h743::Uart,
    pub rx: AltPin,
    pub tx: AltPin,
}

/// An I²C bus (`board::i2c`): the peripheral and its clock and data pads (open drain).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct I2cWiring {
    pub i2c: h743::I2c,
    pub scl: AltPin,
    pub sda: AltPin,
}

/// The flight battery's sensing: the pack through a resistor divider and a current sensor's
/// output, each on an ADC1 input (`board::battery`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatterySensing {
    /// The divider's output.
    pub voltage_pin: Pin,
    /// The current sensor's output.
    pub current_pin: Pin,
    /// Pack volts per volt at `voltage_pin` (the divider's ratio).
    pub volts_per_volt: f32,
    /// Amperes per volt at `current_pin` above `current_offset_v`.
    pub amps_per_volt: f32,
    /// Volts at `current_pin` with no current.
    pub current_offset_v: f32,
    /// The ADC's reference (VREF+), V.
    pub reference_v: f32,
}

impl BatterySensing {
    /// The pack's voltage and current from the two conversions (`voltage_raw`, `current_raw`)
    /// of an ADC whose full scale is `full_scale` (65,535 at 16 bits).
    pub fn reading(
        &self,
        voltage_raw: u32,
        current_raw: u32,
        full_scale: u32,
    ) -> crate::app::hal::BatteryReading {
        let volts_per_count = self.reference_v / full_scale as f32;
        crate::app::hal::BatteryReading {
            voltage_v: voltage_raw as f32 * volts_per_count * self.volts_per_volt,
            current_a: (current_raw as f32 * volts_per_count - self.current_offset_v)
                * self.amps_per_volt,
        }
    }
}

/// The microSD card's slot on SDMMC1 (4-bit bus; the card's own pull-ups are not relied on).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdCardWiring {
    pub clock: AltPin,
    pub command: AltPin,
    /// D0..=D3.
    pub data: [AltPin; 4],
}

impl SdCardWiring {
    /// Every pin of the slot with the function its role needs.
    pub fn pins(&self) -> [(AltPin, h743::Function); 6] {
        use h743::Function::{SdmmcCk, SdmmcCmd, SdmmcData};
        let [d0, d1, d2, d3] = self.data;
        [
            (self.clock, SdmmcCk),
            (self.command, SdmmcCmd),
            (d0, SdmmcData(0)),
            (d1, SdmmcData(1)),
            (d2, SdmmcData(2)),
            (d3, SdmmcData(3)),
        ]
    }
}

/// Where the firmware and the configuration store live in the internal flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FlashLayout {
    /// Start of the firmware image (bank 1, sector 0), address.
    pub firmware_start: u32,
    /// Flash reserved for the firmware image, bytes (the `FLASH` region of `memory.x`).
    pub firmware_len: u32,
    /// First configuration sector, address (bank 2, so erasing never stalls code fetches from
    /// bank 1: the banks read while the other one writes).
    pub config_start: u32,
    /// Configuration sectors, bytes (whole sectors, at least two for sequential-storage).
    pub config_len: u32,
}

/// Everything that differs between H743 flight controllers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoardDescription {
    /// Reported in the handshake (at most 32 bytes).
    pub name: &'static str,
    /// Where the pin map comes from.
    pub source: &'static str,
    /// External crystal, Hz.
    pub hse_hz: u32,
    /// `true` when HSE is a clock signal (oscillator bypassed), not a crystal.
    pub hse_bypass: bool,
    pub imu: ImuWiring,
    /// Motor outputs in the order the application numbers its motors (M1 first).
    pub motors: &'static [MotorOutput],
    /// Motors the firmware drives: the first this many of `motors` (4..=8).
    pub motor_count: u8,
    /// One entry per timer in `motors`.
    pub motor_timers: &'static [MotorTimer],
    /// Motor pole pairs (14 poles = 7 pairs, the common 22xx/23xx motor), for eRPM → rad/s.
    pub motor_pole_pairs: u8,
    /// Whether the ESCs speak bidirectional DShot (BLHeli_32, Bluejay, AM32 do; BLHeli_S
    /// without Bluejay does not): inverted frames, each answered with the motor's eRPM.
    pub motor_bidirectional: bool,
    /// The CRSF receiver (RC in, handset telemetry out).
    pub receiver: UartWiring,
    /// The telemetry radio: the link protocol, when the `radio_baud` parameter is not 0.
    pub telemetry_radio: UartWiring,
    /// The GNSS receiver's port (`None`: the board has none).
    pub gnss: Option<GnssWiring>,
    /// The I²C bus of the GNSS mast's compass (`None`: the board has none).
    pub compass: Option<I2cWiring>,
    /// The flight battery's voltage and current.
    pub battery: BatterySensing,
    /// USB OTG2 full-speed pins (D−, D+).
    pub usb_dm: AltPin,
    pub usb_dp: AltPin,
    /// The microSD card slot, for the flight log (`None`: no slot).
    pub sdcard: Option<SdCardWiring>,
    /// The DMA stream the flash driver copies configuration words with (memory to memory, so a
    /// torn word's ECC error is a transfer error instead of a CPU bus fault).
    pub flash_read_dma: DmaStream,
    pub flash: FlashLayout,
}

/// Why a [`BoardDescription`] is inconsistent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoardError {
    PinUsedTwice(Pin),
    DmaStreamUsedTwice(DmaStream),
    DmaStreamOutOfRange(DmaStream),
    TimerChannelUsedTwice {
        timer: Timer,
        channel: u8,
    },
    /// A motor's channel is not 1..=4.
    BadChannel {
        motor: u8,
    },
    /// A motor's timer has no [`MotorTimer`] entry (no DMA burst to drive it).
    MotorTimerMissing {
        motor: u8,
        timer: Timer,
    },
    /// A [`MotorTimer`] entry drives no motor, or a timer is listed twice.
    MotorTimerUnused(Timer),
    /// A timer drives motors and is also the firmware's time base or control tick.
    TimerReserved(Timer),
    /// The motors of one timer must use consecutive channels (one DMA burst writes them).
    ChannelsNotConsecutive(Timer),
    /// `motor_count` is outside 1..=8 or above the outputs listed.
    MotorCount,
    /// The chip has no such alternate function on that pin.
    NoSuchAlternateFunction(AltPin),
    /// The function on a pin is not the one its role needs (e.g. a TIM4 pin for a TIM3 motor).
    WrongFunction(AltPin),
    /// A battery pin is not an ADC1 input.
    NotAnAdcInput(Pin),
    /// The IMU's data-ready line or RX DMA stream differs from the interrupts `src/main.rs`
    /// binds.
    ImuInterruptBinding,
    /// The configuration sectors are not whole sectors of bank 2, fewer than two, or overlap
    /// the firmware.
    FlashLayout,
    /// The board asks for a timer the chip table does not know as a DShot-capable timer.
    NotAMotorTimer(Timer),
    /// A motor's timer channel has no DMA request to capture the ESC's answer with (TIM4 CH4).
    NoCaptureRequest {
        motor: u8,
    },
    /// A motor timer's burst stream is not one whose completion interrupt `src/main.rs` binds
    /// ([`FIRMWARE_MOTOR_BURST_DMA`]).
    MotorBurstInterruptBinding(DmaStream),
}

impl BoardDescription {
    /// The motors the firmware drives.
    pub fn driven_motors(&self) -> &'static [MotorOutput] {
        let count = usize::from(self.motor_count).min(self.motors.len());
        &self.motors[..count]
    }

    /// Every alternate-function pin of the board, with its role's required function.
    fn alt_pins(&self) -> impl Iterator<Item = (AltPin, Function)> + '_ {
        let imu = &self.imu;
        let fixed = [
            (imu.sck, Function::SpiSck(imu.spi)),
            (imu.miso, Function::SpiMiso(imu.spi)),
            (imu.mosi, Function::SpiMosi(imu.spi)),
            (self.receiver.rx, Function::UartRx(self.receiver.uart)),
            (self.receiver.tx, Function::UartTx(self.receiver.uart)),
            (self.telemetry_radio.rx, Function::UartRx(self.telemetry_radio.uart)),
            (self.telemetry_radio.tx, Function::UartTx(self.telemetry_radio.uart)),
            (self.usb_dm, Function::UsbDm),
            (self.usb_dp, Function::UsbDp),
        ];
        let motors =
            self.motors.iter().map(|m| (m.pin, Function::TimerChannel(m.timer, m.channel)));
        let sdcard = self.sdcard.iter().flat_map(|card| card.pins());
        let gnss = self.gnss.iter().flat_map(|gnss| {
            [(gnss.rx, Function::UartRx(gnss.uart)), (gnss.tx, Function::UartTx(gnss.uart))]
        });
        let compass = self.compass.iter().flat_map(|bus| {
            [(bus.scl, Function::I2cScl(bus.i2c)), (bus.sda, Function::I2cSda(bus.i2c))]
        });
        fixed.into_iter().chain(motors).chain(sdcard).chain(gnss).chain(compass)
    }

    /// Every DMA stream the board uses.
    fn dma_streams(&self) -> impl Iterator<Item = DmaStream> + '_ {
        let uarts = [self.receiver.rx_dma, self.telemetry_radio.rx_dma];
        [self.imu.rx_dma, self.imu.tx_dma, self.flash_read_dma]
            .into_iter()
            .chain(uarts)
            .chain(self.motor_timers.iter().map(|t| t.dma))
            .chain(self.motors.iter().map(|m| m.capture_dma))
    }

    /// Check the description (see [`BoardError`]); the first problem found is returned.
    pub fn check(&self) -> Result<(), BoardError> {
        // Pins: alternate-function pins, chip select, data ready.
        let mut pins: heapless::Vec<Pin, 32> = heapless::Vec::new();
        let battery = [self.battery.voltage_pin, self.battery.current_pin];
        if let Some(&p) = battery.iter().find(|p| h743::adc1_input(**p).is_none()) {
            return Err(BoardError::NotAnAdcInput(p));
        }
        let plain = [self.imu.cs, self.imu.data_ready, battery[0], battery[1]];
        for p in self.alt_pins().map(|(a, _)| a.pin).chain(plain) {
            if pins.contains(&p) {
                return Err(BoardError::PinUsedTwice(p));
            }
            let _ = pins.push(p);
        }
        for (alt, needed) in self.alt_pins() {
            if alt.function != needed {
                return Err(BoardError::WrongFunction(alt));
            }
            if h743::alternate_function(alt.pin, alt.function) != Some(alt.af) {
                return Err(BoardError::NoSuchAlternateFunction(alt));
            }
        }
        // DMA streams.
        let mut streams: heapless::Vec<DmaStream, 24> = heapless::Vec::new();
        for s in self.dma_streams() {
            if !(1..=2).contains(&s.controller) || s.stream > 7 {
                return Err(BoardError::DmaStreamOutOfRange(s));
            }
            if streams.contains(&s) {
                return Err(BoardError::DmaStreamUsedTwice(s));
            }
            let _ = streams.push(s);
        }
        if self.imu.rx_dma != FIRMWARE_IMU_RX_DMA
            || self.imu.data_ready.number != FIRMWARE_IMU_EXTI_LINE
        {
            return Err(BoardError::ImuInterruptBinding);
        }
        // Motors and their timers.
        if self.motor_count == 0
            || usize::from(self.motor_count) > self.motors.len()
            || self.motors.len() > crate::app::hal::MAX_MOTORS
        {
            return Err(BoardError::MotorCount);
        }
        let mut channels: heapless::Vec<(Timer, u8), 8> = heapless::Vec::new();
        for (index, m) in self.motors.iter().enumerate() {
            let motor = index as u8;
            if !(1..=4).contains(&m.channel) {
                return Err(BoardError::BadChannel { motor });
            }
            if channels.contains(&(m.timer, m.channel)) {
                return Err(BoardError::TimerChannelUsedTwice {
                    timer: m.timer,
                    channel: m.channel,
                });
            }
            let _ = channels.push((m.timer, m.channel));
            if !self.motor_timers.iter().any(|t| t.timer == m.timer) {
                return Err(BoardError::MotorTimerMissing { motor, timer: m.timer });
            }
            let capture =
                h743::timer(m.timer).map(|t| t.channel_requests[usize::from(m.channel - 1)]);
            if self.motor_bidirectional && capture.unwrap_or(0) == 0 {
                return Err(BoardError::NoCaptureRequest { motor });
            }
        }
        for (i, t) in self.motor_timers.iter().enumerate() {
            if !self.motors.iter().any(|m| m.timer == t.timer)
                || self.motor_timers[..i].iter().any(|u| u.timer == t.timer)
            {
                return Err(BoardError::MotorTimerUnused(t.timer));
            }
            if t.timer == FIRMWARE_TIME_BASE || t.timer == FIRMWARE_CONTROL_TICK {
                return Err(BoardError::TimerReserved(t.timer));
            }
            if h743::timer(t.timer).is_none() {
                return Err(BoardError::NotAMotorTimer(t.timer));
            }
            if FIRMWARE_MOTOR_BURST_DMA.get(i) != Some(&t.dma) {
                return Err(BoardError::MotorBurstInterruptBinding(t.dma));
            }
            let (first, count) = self.burst_channels(t.timer);
            let used = self.motors.iter().filter(|m| m.timer == t.timer).count() as u8;
            if used != count || first == 0 {
                return Err(BoardError::ChannelsNotConsecutive(t.timer));
            }
        }
        self.check_flash()
    }

    fn check_flash(&self) -> Result<(), BoardError> {
        let f = &self.flash;
        let bank2 = h743::FLASH_BANK2_START..h743::FLASH_BANK2_START + h743::FLASH_BANK_LEN;
        let sector = h743::FLASH_SECTOR_LEN;
        let config_end = f.config_start + f.config_len;
        let firmware_end = f.firmware_start + f.firmware_len;
        let ok = f.config_start.is_multiple_of(sector)
            && f.config_len.is_multiple_of(sector)
            && f.config_len >= 2 * sector
            && bank2.contains(&f.config_start)
            && config_end <= bank2.end
            && (config_end <= f.firmware_start || f.config_start >= firmware_end)
            && f.firmware_start == h743::FLASH_BANK1_START;
        if ok {
            Ok(())
        } else {
            Err(BoardError::FlashLayout)
        }
    }

    /// The DMA burst of `timer`'s motors: (first channel, number of channels), i.e. the burst
    /// writes CCR`first` .. CCR`first + count − 1`. (0, 0) when the timer drives no motor.
    pub fn burst_channels(&self, timer: Timer) -> (u8, u8) {
        let mut low = u8::MAX;
        let mut high = 0u8;
        for m in self.motors.iter().filter(|m| m.timer == timer) {
            low = low.min(m.channel);
            high = high.max(m.channel);
        }
        if high == 0 {
            (0, 0)
        } else {
            (low, high - low + 1)
        }
    }

    /// The configuration sectors as offsets within flash bank 2 (what the HAL's bank driver
    /// takes).
    pub fn config_bank_offsets(&self) -> core::ops::Range<u32> {
        let start = self.flash.config_start - h743::FLASH_BANK2_START;
        start..start + self.flash.config_len
    }
}

/// The silicon revision in DBGMCU_IDCODE.REV_ID (RM0433 rev 8 §61.5.8, errata ES0392).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SiliconRevision {
    /// REV_ID 0x1003: limited to 400 MHz (VOS1).
    Y,
    /// REV_ID 0x2003: 480 MHz with VOS0.
    V,
    /// Anything else: treated like revision Y (the rate every revision supports).
    Unknown(u16),
}

impl SiliconRevision {
    pub const fn from_rev_id(rev_id: u16) -> Self {
        match rev_id {
            0x1003 => Self::Y,
            0x2003 => Self::V,
            other => Self::Unknown(other),
        }
    }
}

/// The clock tree the firmware runs for a silicon revision.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClockPlan {
    /// Core clock (sys_ck), Hz.
    pub sys_ck_hz: u32,
    /// AHB/AXI clock (hclk), Hz: sys_ck / 2, the AHB maximum (240 MHz at VOS0, 200 MHz at VOS1).
    pub hclk_hz: u32,
    /// Voltage scale 0 (required above 400 MHz, revision V only; DS12110 table 23).
    pub vos0: bool,
}

impl ClockPlan {
    /// 480 MHz at VOS0 on revision V; 400 MHz at VOS1 otherwise (revision Y's maximum, and a
    /// safe choice for a revision this firmware does not know).
    pub const fn for_revision(revision: SiliconRevision) -> Self {
        match revision {
            SiliconRevision::V => Self { sys_ck_hz: 480_000_000, hclk_hz: 240_000_000, vos0: true },
            _ => Self { sys_ck_hz: 400_000_000, hclk_hz: 200_000_000, vos0: false },
        }
    }

    /// The APB1/APB2 timer kernel clock, Hz: the HAL runs pclk = hclk / 2 and the timers at
    /// twice their APB clock (RCC_CFGR.TIMPRE = 0, RM0433 §8.5.7), i.e. hclk.
    pub const fn timer_clock_hz(&self) -> u32 {
        self.hclk_hz
    }

    /// The APB2 peripheral clock (USART6's kernel clock by default), Hz: hclk / 2.
    pub const fn pclk2_hz(&self) -> u32 {
        self.hclk_hz / 2
    }
}

/// The value [`crate::targets`]' bootloader request leaves in RAM across a reset: "ROM DFU".
pub const BOOTLOADER_MAGIC: u32 = 0xB007_DF00;

/// Whether a reset should go to the ROM bootloader, given the word found in the reset-surviving
/// RAM location. Any other value (including RAM noise after a power cycle) boots the firmware.
pub const fn boot_to_bootloader(word: u32) -> bool {
    word == BOOTLOADER_MAGIC
}

/// A USART baud-rate divider: kernel clock / baud, rounded to nearest (oversampling by 16,
/// RM0433 §48.5.7).
pub const fn uart_brr(kernel_clock_hz: u32, baud: u32) -> u32 {
    (kernel_clock_hz + baud / 2) / baud
}

/// Fast-mode I²C's timing (NXP UM10204 rev. 7, table 10), ns: SCL low at least 1,300 and high
/// at least 600 (we give 1,350 and 800, so that with the peripheral's synchronisation and a
/// 300 ns rise the clock stays at or below 400 kHz); the data set-up before SCL rises, at least
/// the 300 ns longest rise plus 100 ns; the data hold after SCL falls, past the 300 ns longest
/// fall less the peripheral's 50 ns analog filter (RM0433 §47.4.10, "I2C timings").
pub const I2C_FAST_LOW_NS: u32 = 1_350;
pub const I2C_FAST_HIGH_NS: u32 = 800;
pub const I2C_FAST_SETUP_NS: u32 = 400;
pub const I2C_FAST_HOLD_NS: u32 = 250;
/// The prescaled I²C clock's period aimed at, ns: fine enough for the hold, coarse enough that
/// SCL low fits its 8-bit field at every kernel clock up to 200 MHz.
const I2C_TICK_NS: u32 = 50;

/// I2C_TIMINGR for 400 kHz fast mode from the kernel clock `kernel_hz` (RM0433 §47.7.5: PRESC
/// bits 31:28, SCLDEL 23:20, SDADEL 19:16, SCLH 15:8, SCLL 7:0; each time is its field plus one
/// prescaled ticks, SDADEL's is its field).
pub const fn i2c_fast_timingr(kernel_hz: u32) -> u32 {
    const fn min(a: u32, b: u32) -> u32 {
        if a < b {
            a
        } else {
            b
        }
    }
    // Prescaled ticks for at least `ns`.
    const fn ticks(ns: u32, kernel_hz: u32, presc: u32) -> u32 {
        let tick_ps = (presc as u64 + 1) * 1_000_000_000_000 / kernel_hz as u64;
        (ns as u64 * 1_000).div_ceil(tick_ps) as u32
    }
    let per_tick = (kernel_hz as u64 * I2C_TICK_NS as u64).div_ceil(1_000_000_000) as u32;
    let presc = if per_tick == 0 {
        0
    } else if per_tick > 16 {
        15
    } else {
        per_tick - 1
    };
    let scll = min(ticks(I2C_FAST_LOW_NS, kernel_hz, presc).saturating_sub(1), 255);
    let sclh = min(ticks(I2C_FAST_HIGH_NS, kernel_hz, presc).saturating_sub(1), 255);
    let scldel = min(ticks(I2C_FAST_SETUP_NS, kernel_hz, presc).saturating_sub(1), 15);
    let sdadel = min(ticks(I2C_FAST_HOLD_NS, kernel_hz, presc), 15);
    (presc << 28) | (scldel << 20) | (sdadel << 16) | (sclh << 8) | scll
}

/// The SPI clock divider exponent (CFG1.MBR: divide by 2^(MBR+1)) for the fastest clock not
/// above `max_hz` from `kernel_hz`; 7 (÷256) at most.
pub const fn spi_mbr(kernel_hz: u32, max_hz: u32) -> u8 {
    let mut mbr = 0u8;
    while mbr < 7 && kernel_hz >> (mbr + 1) > max_hz {
        mbr += 1;
    }
    mbr
}

/// Interleave per-motor DShot compare values into one timer's DMA burst buffer: for each bit,
/// the compare values of the timer's channels in register order (`out[bit · n + k]` is channel
/// `first + k`'s value for `bit`). Channels without a motor get 0 (line idle). `values[k]` is
/// `None` for such a channel. `out` must hold `COMPARE_BUFFER_LEN · values.len()` words; extra
/// words are left untouched.
pub fn interleave_burst(
    values: &[Option<[u16; crate::drivers::dshot::COMPARE_BUFFER_LEN]>],
    out: &mut [u32],
) {
    let n = values.len();
    for (k, channel) in values.iter().enumerate() {
        for bit in 0..crate::drivers::dshot::COMPARE_BUFFER_LEN {
            if let Some(slot) = out.get_mut(bit * n + k) {
                *slot = channel.map_or(0, |v| u32::from(v[bit]));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn revisions_and_clock_plans() {
        assert_eq!(SiliconRevision::from_rev_id(0x1003), SiliconRevision::Y);
        assert_eq!(SiliconRevision::from_rev_id(0x2003), SiliconRevision::V);
        assert_eq!(SiliconRevision::from_rev_id(0x1001), SiliconRevision::Unknown(0x1001));
        let v = ClockPlan::for_revision(SiliconRevision::V);
        assert_eq!((v.sys_ck_hz, v.hclk_hz, v.vos0), (480_000_000, 240_000_000, true));
        let y = ClockPlan::for_revision(SiliconRevision::Y);
        assert_eq!((y.sys_ck_hz, y.hclk_hz, y.vos0), (400_000_000, 200_000_000, false));
        assert_eq!(ClockPlan::for_revision(SiliconRevision::Unknown(7)), y);
        assert_eq!(v.timer_clock_hz(), 240_000_000);
    }

    #[test]
    fn dividers() {
        // 420 kbaud CRSF from pclk2 = 120 MHz and 100 MHz.
        assert_eq!(uart_brr(120_000_000, 420_000), 286);
        assert_eq!(uart_brr(100_000_000, 420_000), 238);
        // 64 MHz per_ck: 16 MHz (÷4) for samples, 2 MHz (÷32) at start-up.
        assert_eq!(spi_mbr(64_000_000, 24_000_000), 1);
        assert_eq!(spi_mbr(64_000_000, 16_000_000), 1);
        assert_eq!(spi_mbr(64_000_000, 2_000_000), 4);
        assert_eq!(spi_mbr(64_000_000, 1), 7);
    }

    /// At the kernel clocks the board runs I2C1 from (pclk1: 100 and 120 MHz) and a slow one,
    /// the fields meet fast mode's minima and the clock's period (low + high + the peripheral's
    /// three-tick synchronisation + a 300 ns rise) is no faster than 400 kHz nor slower than
    /// 320 kHz.
    #[test]
    fn i2c_fast_mode_timing_meets_the_specification() {
        for kernel_hz in [100_000_000u32, 120_000_000, 64_000_000, 16_000_000] {
            let t = i2c_fast_timingr(kernel_hz);
            let presc = t >> 28;
            let tick_ns = f64::from(presc + 1) * 1e9 / f64::from(kernel_hz);
            let low_ns = f64::from((t & 0xFF) + 1) * tick_ns;
            let high_ns = f64::from(((t >> 8) & 0xFF) + 1) * tick_ns;
            let setup_ns = f64::from(((t >> 20) & 0xF) + 1) * tick_ns;
            let hold_ns = f64::from((t >> 16) & 0xF) * tick_ns;
            assert!(low_ns >= 1_300.0 && high_ns >= 600.0, "{kernel_hz}: {low_ns} {high_ns}");
            assert!(setup_ns >= 400.0 && (250.0..=600.0).contains(&hold_ns), "{kernel_hz}");
            let sync_ns = 3.0 * 1e9 / f64::from(kernel_hz);
            let period_ns = low_ns + high_ns + 2.0 * sync_ns + 300.0;
            let scl_khz = 1e6 / period_ns;
            assert!((320.0..=400.0).contains(&scl_khz), "{kernel_hz} Hz: {scl_khz} kHz");
        }
    }

    #[test]
    fn bootloader_magic_only_on_the_exact_word() {
        assert!(boot_to_bootloader(BOOTLOADER_MAGIC));
        assert!(!boot_to_bootloader(0));
        assert!(!boot_to_bootloader(!BOOTLOADER_MAGIC));
    }

    #[test]
    fn burst_interleaving() {
        let a = [1u16; 18];
        let mut b = [2u16; 18];
        b[17] = 0;
        let mut out = [9u32; 18 * 3];
        interleave_burst(&[Some(a), None, Some(b)], &mut out);
        assert_eq!(&out[..6], &[1, 0, 2, 1, 0, 2]);
        assert_eq!(&out[48..], &[1, 0, 2, 1, 0, 0]);
    }
}
