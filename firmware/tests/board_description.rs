//! Board-file consistency: the selected board description (pins, timers, DMA streams, flash
//! sectors) is checked on the host, so a porting mistake fails `cargo test` instead of a
//! flight.

use firmware::targets::h743::{self, Function, Spi, Timer};
use firmware::targets::{
    self, matek_h743::MATEK_H743_V3, pin, AltPin, BoardDescription, BoardError, DmaStream,
    MotorOutput, MotorTimer, Port,
};

#[test]
fn the_selected_board_is_consistent() {
    assert_eq!(targets::SELECTED.check(), Ok(()));
    assert_eq!(MATEK_H743_V3.check(), Ok(()));
}

#[test]
fn every_motor_has_a_timer_channel_and_a_burst_stream() {
    let board = targets::SELECTED;
    assert!((4..=8).contains(&board.motor_count));
    for motor in board.driven_motors() {
        let timer = board.motor_timers.iter().find(|t| t.timer == motor.timer).unwrap();
        let info = h743::timer(timer.timer).unwrap();
        assert!(info.update_request > 0);
        let (first, count) = board.burst_channels(motor.timer);
        assert!(first <= motor.channel && motor.channel < first + count);
    }
    // The Matek's bursts: TIM3 CH3..CH4, TIM5 CH1..CH4, TIM4 CH1..CH2.
    assert_eq!(MATEK_H743_V3.burst_channels(Timer::Tim3), (3, 2));
    assert_eq!(MATEK_H743_V3.burst_channels(Timer::Tim5), (1, 4));
    assert_eq!(MATEK_H743_V3.burst_channels(Timer::Tim4), (1, 2));
}

#[test]
fn the_firmware_region_of_memory_x_matches_the_flash_layout() {
    // memory.x: `FLASH : ORIGIN = 0x08000000, LENGTH = 1M`.
    let memory_x = include_str!("../memory.x");
    let line = memory_x.lines().find(|l| l.trim_start().starts_with("FLASH")).unwrap();
    let length = line.split("LENGTH =").nth(1).unwrap().trim();
    let bytes = match length.strip_suffix('M') {
        Some(m) => m.trim().parse::<u32>().unwrap() * 1024 * 1024,
        None => length.strip_suffix('K').unwrap().trim().parse::<u32>().unwrap() * 1024,
    };
    let flash = targets::SELECTED.flash;
    assert_eq!(bytes, flash.firmware_len);
    assert!(line.contains("0x08000000"));
    assert!(flash.firmware_start + flash.firmware_len <= flash.config_start);
    assert_eq!(targets::SELECTED.config_bank_offsets(), 0xC_0000..0x10_0000);
}

#[test]
fn dmamux_request_numbers_match_rm0433() {
    // RM0433 Table 121 (checked against the stm32h7 PAC's DMAREQ_ID enumeration).
    assert_eq!(h743::spi(Spi::Spi1).rx_request, 37);
    assert_eq!(h743::spi(Spi::Spi1).tx_request, 38);
    assert_eq!(h743::timer(Timer::Tim3).unwrap().update_request, 27);
    assert_eq!(h743::timer(Timer::Tim4).unwrap().update_request, 32);
    assert_eq!(h743::timer(Timer::Tim5).unwrap().update_request, 59);
    // The channels' capture requests (TIMx_CH1..4); TIM4 has none for CH4.
    assert_eq!(h743::timer(Timer::Tim3).unwrap().channel_requests, [23, 24, 25, 26]);
    assert_eq!(h743::timer(Timer::Tim4).unwrap().channel_requests, [29, 30, 31, 0]);
    assert_eq!(h743::timer(Timer::Tim5).unwrap().channel_requests, [55, 56, 57, 58]);
    assert_eq!(h743::timer(Timer::Tim8).unwrap().channel_requests, [47, 48, 49, 50]);
    assert_eq!(h743::uart(h743::Uart::Usart6).rx_request, 71);
    assert_eq!(DmaStream { controller: 2, stream: 7 }.dmamux_channel(), 15);
    assert_eq!(DmaStream { controller: 1, stream: 3 }.dmamux_channel(), 3);
}

/// A copy of the selected board with one change, for the negative cases.
fn broken(change: impl FnOnce(&mut BoardDescription)) -> Result<(), BoardError> {
    let mut board = *targets::SELECTED;
    change(&mut board);
    board.check()
}

#[test]
fn a_dma_stream_used_twice_is_refused() {
    let imu_rx = targets::SELECTED.imu.rx_dma;
    assert_eq!(broken(|b| b.receiver.rx_dma = imu_rx), Err(BoardError::DmaStreamUsedTwice(imu_rx)));
    let stream = DmaStream { controller: 3, stream: 0 };
    assert_eq!(broken(|b| b.flash_read_dma = stream), Err(BoardError::DmaStreamOutOfRange(stream)));
}

static TWICE: [MotorOutput; 2] = [
    MotorOutput {
        pin: AltPin {
            pin: pin(Port::B, 0),
            function: Function::TimerChannel(Timer::Tim3, 3),
            af: 2,
        },
        timer: Timer::Tim3,
        channel: 3,
        capture_dma: DmaStream { controller: 1, stream: 6 },
    },
    MotorOutput {
        pin: AltPin {
            pin: pin(Port::B, 1),
            function: Function::TimerChannel(Timer::Tim3, 4),
            af: 2,
        },
        timer: Timer::Tim3,
        channel: 3,
        capture_dma: DmaStream { controller: 1, stream: 7 },
    },
];

static TIM3_ONLY: [MotorTimer; 1] =
    [MotorTimer { timer: Timer::Tim3, dma: DmaStream { controller: 1, stream: 2 } }];

#[test]
fn a_timer_channel_used_twice_or_a_wrong_function_is_refused() {
    let result = broken(|b| {
        b.motors = &TWICE;
        b.motor_count = 2;
        b.motor_timers = &TIM3_ONLY;
    });
    // The second motor's pin says CH4 but the motor says CH3: the function check sees it first.
    assert!(matches!(result, Err(BoardError::WrongFunction(_))), "{result:?}");
}

#[test]
fn pins_reserved_timers_and_missing_bursts_are_refused() {
    let cs = targets::SELECTED.imu.cs;
    assert_eq!(broken(|b| b.imu.data_ready = cs), Err(BoardError::PinUsedTwice(cs)));
    assert_eq!(
        broken(|b| b.motor_timers = &TIM3_ONLY),
        Err(BoardError::MotorTimerMissing { motor: 2, timer: Timer::Tim5 })
    );
    assert_eq!(broken(|b| b.motor_count = 9), Err(BoardError::MotorCount));
    assert_eq!(
        broken(|b| b.imu.data_ready = pin(Port::E, 15)),
        Err(BoardError::ImuInterruptBinding)
    );
    // The time base's timer (TIM2) as a motor timer.
    static ON_TIM2: [MotorOutput; 1] = [MotorOutput {
        pin: AltPin {
            pin: pin(Port::A, 0),
            function: Function::TimerChannel(Timer::Tim2, 1),
            af: 1,
        },
        timer: Timer::Tim2,
        channel: 1,
        capture_dma: DmaStream { controller: 1, stream: 6 },
    }];
    static TIM2: [MotorTimer; 1] =
        [MotorTimer { timer: Timer::Tim2, dma: DmaStream { controller: 1, stream: 2 } }];
    assert_eq!(
        broken(|b| {
            b.motors = &ON_TIM2;
            b.motor_count = 1;
            b.motor_timers = &TIM2;
        }),
        Err(BoardError::TimerReserved(Timer::Tim2))
    );
}

#[test]
fn alternate_functions_and_flash_layout_are_checked() {
    let bad_af = AltPin { af: 6, ..targets::SELECTED.imu.sck };
    assert_eq!(broken(|b| b.imu.sck = bad_af), Err(BoardError::NoSuchAlternateFunction(bad_af)));
    assert_eq!(broken(|b| b.flash.config_len = 0x2_0000), Err(BoardError::FlashLayout));
    assert_eq!(broken(|b| b.flash.config_start = 0x080C_0000), Err(BoardError::FlashLayout));
    assert_eq!(broken(|b| b.flash.config_start = 0x081C_1000), Err(BoardError::FlashLayout));
}

/// Bidirectional DShot: every motor has its own capture stream (shared with nothing else), on a
/// channel with a capture DMA request, and the bursts' completions are the interrupts
/// `src/main.rs` binds.
#[test]
fn every_motor_can_capture_its_escs_answer() {
    let board = targets::SELECTED;
    assert!(board.motor_bidirectional);
    for (motor, output) in board.motors.iter().enumerate() {
        let requests = h743::timer(output.timer).unwrap().channel_requests;
        assert_ne!(requests[usize::from(output.channel - 1)], 0, "motor {motor}");
    }
    // M1's capture stream taken by the receiver: refused as a stream used twice.
    let m1 = board.motors[0].capture_dma;
    assert_eq!(broken(|b| b.receiver.rx_dma = m1), Err(BoardError::DmaStreamUsedTwice(m1)));
    // The telemetry radio on the receiver's stream, or on the receiver's pad: refused.
    let crsf = board.receiver.rx_dma;
    assert_eq!(
        broken(|b| b.telemetry_radio.rx_dma = crsf),
        Err(BoardError::DmaStreamUsedTwice(crsf))
    );
    let rx6 = board.receiver.rx.pin;
    assert_eq!(broken(|b| b.telemetry_radio.rx.pin = rx6), Err(BoardError::PinUsedTwice(rx6)));
    // A burst stream whose completion `src/main.rs` does not bind.
    static UNBOUND: [MotorTimer; 3] = [
        MotorTimer { timer: Timer::Tim3, dma: DmaStream { controller: 2, stream: 6 } },
        MotorTimer { timer: Timer::Tim5, dma: DmaStream { controller: 1, stream: 3 } },
        MotorTimer { timer: Timer::Tim4, dma: DmaStream { controller: 1, stream: 4 } },
    ];
    // (Every stream is taken: the radio gets the one the TIM3 burst gives up.)
    let stream = UNBOUND[0].dma;
    let freed = board.motor_timers[0].dma;
    assert_eq!(
        broken(|b| {
            b.motor_timers = &UNBOUND;
            b.telemetry_radio.rx_dma = freed;
        }),
        Err(BoardError::MotorBurstInterruptBinding(stream))
    );
    // TIM4 CH4 has no capture request: a motor there cannot answer.
    static ON_TIM4_CH4: [MotorOutput; 1] = [MotorOutput {
        pin: AltPin {
            pin: pin(Port::D, 15),
            function: Function::TimerChannel(Timer::Tim4, 4),
            af: 2,
        },
        timer: Timer::Tim4,
        channel: 4,
        capture_dma: DmaStream { controller: 1, stream: 6 },
    }];
    static TIM4: [MotorTimer; 1] =
        [MotorTimer { timer: Timer::Tim4, dma: DmaStream { controller: 1, stream: 2 } }];
    let result = broken(|b| {
        b.motors = &ON_TIM4_CH4;
        b.motor_count = 1;
        b.motor_timers = &TIM4;
    });
    assert_eq!(result, Err(BoardError::NoCaptureRequest { motor: 0 }));
    let without = broken(|b| {
        b.motors = &ON_TIM4_CH4;
        b.motor_count = 1;
        b.motor_timers = &TIM4;
        b.motor_bidirectional = false;
    });
    assert_eq!(without, Ok(()), "normal DShot needs no capture");
}
