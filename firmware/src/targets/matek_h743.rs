//! Mateksys H743 V3 (H743-SLIM V3, H743-WING V3, H743-MINI V3): the board this firmware is built
//! for. A widely sold STM32H743VIT6 flight controller with an ICM-42688-P on SPI1, eight motor
//! outputs on TIM3/TIM5/TIM4, an 8 MHz crystal and USB on PA11/PA12.
//!
//! Pin map sources (cross-checked against each other):
//! - Betaflight unified target `src/config/MATEKH743/config.h` (pins, `TIMER_PIN_MAPPING`) and
//!   the older `src/main/target/MATEKH743/target.c` (timer channels: S1/S2 = TIM3 CH3/CH4,
//!   S3–S6 = TIM5 CH1–CH4, S7/S8 = TIM4 CH1/CH2); gyro 1 on SPI1 with CS PC15, EXTI PB2.
//! - ArduPilot `libraries/AP_HAL_ChibiOS/hwdef/MatekH743/hwdef.dat`: "H743-V3: ICM42688P
//!   (SPI1, IMU1_CS PC15), ICM42605 (SPI4)", 8 MHz HSE, USART6 the RC input (RX6 = PC7).
//!   microSD on SDMMC1: D0–D3 PC8–PC11, CK PC12, CMD PD2 (its "microSD support" lines).
//!   (ArduPilot drives S1/S2 from TIM8 CH2N/CH3N; this firmware uses Betaflight's TIM3 CH3/CH4,
//!   whose non-complementary channels can also capture the ESC's bidirectional answer.)
//!
//! DMA streams are this firmware's own choice (any stream can take any request through
//! DMAMUX1): DMA1 S0/S1 for the IMU, DMA1 S2–S4 for the three motor timers' bursts, DMA1 S5 for
//! the receiver, DMA1 S6/S7 and DMA2 S0–S5 to capture the ESCs' bidirectional answers on M1–M8,
//! DMA2 S7 for ECC-safe flash reads.

use super::h743::{Function, I2c, Spi, Timer, Uart};
use super::Port::{A, B, C, D};
use super::{
    pin, AltPin, BatterySensing, BoardDescription, DmaStream, FlashLayout, GnssWiring, I2cWiring,
    ImuWiring, MotorOutput, MotorTimer, Pin, SdCardWiring, UartWiring,
};

const fn alt(pin: Pin, function: Function, af: u8) -> AltPin {
    AltPin { pin, function, af }
}

const fn motor(pin: Pin, timer: Timer, channel: u8, capture_dma: DmaStream) -> MotorOutput {
    let pin = alt(pin, Function::TimerChannel(timer, channel), 2);
    MotorOutput { pin, timer, channel, capture_dma }
}

const fn dma(controller: u8, stream: u8) -> DmaStream {
    DmaStream { controller, stream }
}

/// The eight motor outputs, M1..M8 = the board's S1..S8 pads.
const MOTORS: [MotorOutput; 8] = [
    motor(pin(B, 0), Timer::Tim3, 3, dma(1, 6)),
    motor(pin(B, 1), Timer::Tim3, 4, dma(1, 7)),
    motor(pin(A, 0), Timer::Tim5, 1, dma(2, 0)),
    motor(pin(A, 1), Timer::Tim5, 2, dma(2, 1)),
    motor(pin(A, 2), Timer::Tim5, 3, dma(2, 2)),
    motor(pin(A, 3), Timer::Tim5, 4, dma(2, 3)),
    motor(pin(D, 12), Timer::Tim4, 1, dma(2, 4)),
    motor(pin(D, 13), Timer::Tim4, 2, dma(2, 5)),
];

const MOTOR_TIMERS: [MotorTimer; 3] = [
    MotorTimer { timer: Timer::Tim3, dma: dma(1, 2) },
    MotorTimer { timer: Timer::Tim5, dma: dma(1, 3) },
    MotorTimer { timer: Timer::Tim4, dma: dma(1, 4) },
];

/// The Mateksys H743 V3.
pub const MATEK_H743_V3: BoardDescription = BoardDescription {
    name: "MATEKH743",
    source: "Betaflight MATEKH743 config.h/target.c; ArduPilot MatekH743 hwdef.dat",
    hse_hz: 8_000_000,
    hse_bypass: false,
    imu: ImuWiring {
        spi: Spi::Spi1,
        sck: alt(pin(A, 5), Function::SpiSck(Spi::Spi1), 5),
        miso: alt(pin(A, 6), Function::SpiMiso(Spi::Spi1), 5),
        mosi: alt(pin(D, 7), Function::SpiMosi(Spi::Spi1), 5),
        cs: pin(C, 15),
        data_ready: pin(B, 2),
        rx_dma: dma(1, 0),
        tx_dma: dma(1, 1),
        init_clock_hz: 2_000_000,
        read_clock_hz: 16_000_000,
    },
    motors: &MOTORS,
    // A quadcopter by default: S1–S4. The learner supports up to eight; raise this for more.
    motor_count: 4,
    motor_timers: &MOTOR_TIMERS,
    motor_pole_pairs: 7,
    motor_bidirectional: true,
    receiver: UartWiring {
        uart: Uart::Usart6,
        rx: alt(pin(C, 7), Function::UartRx(Uart::Usart6), 7),
        tx: alt(pin(C, 6), Function::UartTx(Uart::Usart6), 7),
        rx_dma: dma(1, 5),
    },
    // Pads TX1 and RX1; the last DMA stream free (DMA2 stream 6).
    telemetry_radio: UartWiring {
        uart: Uart::Usart1,
        rx: alt(pin(A, 10), Function::UartRx(Uart::Usart1), 7),
        tx: alt(pin(A, 9), Function::UartTx(Uart::Usart1), 7),
        rx_dma: dma(2, 6),
    },
    // Pads TX2 and RX2 (PD5/PD6, USART2 AF7): the GPS port of ArduPilot's MatekH743 hwdef.dat
    // (SERIAL2 = USART2, "GPS1"). Received by interrupt: no DMA stream is left.
    gnss: Some(GnssWiring {
        uart: Uart::Usart2,
        rx: alt(pin(D, 6), Function::UartRx(Uart::Usart2), 7),
        tx: alt(pin(D, 5), Function::UartTx(Uart::Usart2), 7),
    }),
    // The compass of a GNSS mast on I2C1, pads SCL/SDA = PB6/PB7 (AF4): Betaflight's
    // MATEKH743 config.h (I2C1_SCL_PIN PB6, I2C1_SDA_PIN PB7, MAG_I2C_INSTANCE I2C1); the
    // barometer is on I2C2 (PB10/PB11), which this firmware leaves alone.
    compass: Some(I2cWiring {
        i2c: I2c::I2c1,
        scl: alt(pin(B, 6), Function::I2cScl(I2c::I2c1), 4),
        sda: alt(pin(B, 7), Function::I2cSda(I2c::I2c1), 4),
    }),
    // The VBAT and CURR pads on PC0 (ADC1_INP10) and PC1 (ADC1_INP11): the board's divider
    // (11 V a volt) and 40 A a volt for the current sensor, as ArduPilot's MatekH743
    // hwdef.dat sets them (HAL_BATT_VOLT_SCALE 11.0, HAL_BATT_CURR_SCALE 40.0; Betaflight's
    // default current scale, 25 mV an ampere, is the same). A current sensor of another scale
    // needs its own value here.
    battery: BatterySensing {
        voltage_pin: pin(C, 0),
        current_pin: pin(C, 1),
        volts_per_volt: 11.0,
        amps_per_volt: 40.0,
        current_offset_v: 0.0,
        reference_v: 3.3,
    },
    usb_dm: alt(pin(A, 11), Function::UsbDm, 10),
    usb_dp: alt(pin(A, 12), Function::UsbDp, 10),
    // ArduPilot hwdef.dat "microSD support": PC8–PC11 SDMMC1_D0–D3, PC12 SDMMC1_CK, PD2
    // SDMMC1_CMD (AF12, DS12110 Table 9).
    sdcard: Some(SdCardWiring {
        clock: alt(pin(C, 12), Function::SdmmcCk, 12),
        command: alt(pin(D, 2), Function::SdmmcCmd, 12),
        data: [
            alt(pin(C, 8), Function::SdmmcData(0), 12),
            alt(pin(C, 9), Function::SdmmcData(1), 12),
            alt(pin(C, 10), Function::SdmmcData(2), 12),
            alt(pin(C, 11), Function::SdmmcData(3), 12),
        ],
    }),
    flash_read_dma: dma(2, 7),
    flash: FlashLayout {
        firmware_start: 0x0800_0000,
        firmware_len: 0x10_0000,
        // Bank 2, sectors 6 and 7 (the last 256 KiB), as ArduPilot's storage on this board.
        config_start: 0x081C_0000,
        config_len: 0x4_0000,
    },
};
