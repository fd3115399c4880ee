//! Drive firmware for the ST B-G431B-ESC1 (STM32G431CB): the sensorless DCFO drive on the
//! board's power stage. **Not tried on hardware** (none here); it builds in CI.
//!
//! - The motor comes from the motor image in the last flash page (`dcfo motor-image`,
//!   or `dcfo identify --image` with the identified inverter compensation, which the
//!   drive then uses; see the README); without a valid one the bridge stays off and the
//!   LED blinks fast. The drive is built by `dcfo_firmware::image_drive::drive_config`,
//!   as in every drive image: with an axis in the image (`dcfo motor-image
//!   --stroke-min-m ...`) a positioning drive that takes moves over the board link,
//!   without one a speed drive (moves are reported refused).
//! - TIM1 runs centre-aligned complementary PWM at 10 kHz with 800 ns dead time; it
//!   triggers the injected ADC conversions of the three shunt currents and the bus
//!   voltage at the carrier valley; the end of conversion raises `ADC1_2`, the control
//!   interrupt. Pins and peripherals: `dcfo_firmware::board::b_g431b_esc1`.
//! - USART2 (the ST-LINK virtual COM port, 921600 8N1) speaks the board link
//!   (`dcfo::link::board`, `dcfo board --port`): each `BoardCommand` from the host sets
//!   enable, clear-faults and the speed reference, may arm the capture or carry a move
//!   (target, dwell), and is answered with a `BoardTelemetry` (state, faults, estimate,
//!   currents, bus; x̂ and the move queue of a positioning drive) or, for a finished
//!   capture, a `CaptureChunk`.
//! - A capture of [`CAPTURE_SAMPLES`] full-rate samples (u_αβ, i_αβ, the estimates) from
//!   the estimator's start, filled in the control interrupt (`dcfo::capture`): 12.8 ms,
//!   what keeps the static RAM within the 8 KiB goal.
//! - defmt over RTT logs state changes and faults (`probe-rs run` shows them).
//! - Nothing in the image can panic (`.ci/no-panic`). An initialisation that cannot
//!   complete, a HardFault (e.g. a stack overflow, which flip-link turns into one) and the
//!   panic handler that remains all switch the bridge off first (TIM1 MOE clear) and stop.
//!
//! | context | priority | work | budget |
//! |---|---|---|---|
//! | `ADC1_2` (end of injected conversions) | 0x00, highest | `ControlLoop::period`: sample, `Drive::step`, duties / bridge; `Capture::record`, `DriveStatus::update` | one PWM period, 100 µs = 17,000 cycles at 170 MHz; the step's instructions, mean and worst, are `bench_qemu`'s (`docs/cost-budget.md`) |
//! | SysTick, every 10 ms | 0x80 | stall check: control periods still counting, else bridge off | a load, a swap and a compare (not measured) |
//! | thread | — | board link (`BoardLinkServer`: commands in, one answer each), command watchdog, LED, defmt | — |
//!
//! Command watchdog: while enabled, if no valid command frame arrives for 0.5 s the
//! drive is disabled (bridge off). Stall check: if the control interrupt stops coming for
//! 10 to 20 ms (SysTick, priority 0x80), the bridge goes off and the image halts. Run (flashes through the on-board ST-LINK):
//! ```sh
//! cargo run -p dcfo-firmware --release --features esc1 --example b_g431b_esc1 --target thumbv7em-none-eabihf
//! ```
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!("b_g431b_esc1 is firmware: build it with `--target thumbv7em-none-eabihf`");
}

#[cfg(target_arch = "arm")]
mod firmware {
    use cortex_m::interrupt::free;
    use cortex_m::peripheral::NVIC;
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m_rt::{entry, exception};
    use dcfo::drive::{Drive, DriveState};
    use dcfo::link::board::CaptureChunk;
    use dcfo::num::units::Base;
    use dcfo_firmware::board::b_g431b_esc1::{
        self as esc1, CONTROL_IRQ, ClockSource, DEFAULT_DEAD_TIME_NS, DEFAULT_PWM_HZ, Esc1Config,
        Esc1PowerStage, Esc1Sensors, StatusLed, stop,
    };
    use dcfo_firmware::board::{Bridge, PhaseSensors, PowerStage};
    use dcfo_firmware::board_link::{BoardLinkServer, LinkClock};
    use dcfo_firmware::control::{ControlLoop, Setpoints};
    use dcfo_firmware::image_drive::{Inverter, drive_config};
    use dcfo_firmware::runtime::{
        BoardLinkState, CaptureCell, DriveOnBoard, Slot, StallCheck, capture_cell, install, slot,
        start_systick,
    };
    use dcfo_firmware::stack;
    use embedded_hal::digital::OutputPin;
    use embedded_io::Write as _;
    use stm32g4::stm32g431::{self as pac, interrupt};

    /// USART2 rate, bit/s (the host's `--baud` default).
    const BAUD: u32 = 921_600;
    /// Capture capacity, samples (36 B each: 4.6 KB), 12.8 ms at 10 kHz: what keeps the
    /// image's static RAM within the board's 8 KiB goal (`bench_qemu --check`).
    pub const CAPTURE_SAMPLES: usize = 128;
    /// Control periods without a command frame after which a running drive is disabled.
    const COMMAND_TIMEOUT_PERIODS: u32 = DEFAULT_PWM_HZ / 2;
    /// Rate of the stall check in SysTick (Hz): every 10 ms.
    const STALL_CHECK_HZ: u32 = 100;
    /// Stall checks in a row without a control period after which the bridge goes off for
    /// good (10 to 20 ms). The command watchdog counts control periods, so it cannot see the
    /// control interrupt stop; with TIM1 still running the bridge would go on switching at
    /// the last duties with nothing in control.
    const STALL_CHECKS: u32 = 2;
    /// NVIC priority of the control interrupt (`ADC1_2`): the highest.
    const PRIORITY_CONTROL: u8 = 0x00;
    /// SysTick (the stall check) priority: below the control interrupt.
    const PRIORITY_STALL_CHECK: u8 = 0x80;

    /// What the control interrupt owns: the drive on the board's sensors and power stage.
    static CONTROL: Slot<&'static mut DriveOnBoard<f32, Bridge<Esc1Sensors, Esc1PowerStage>>> = slot();
    /// The capture and the last step's status, filled by the control interrupt, read by
    /// the thread (both in critical sections); constant-initialised in place.
    static CAPTURE: CaptureCell<CAPTURE_SAMPLES> = capture_cell();
    static LINK: BoardLinkState<CAPTURE_SAMPLES> = BoardLinkState::new(&CAPTURE);
    static SETPOINTS: Setpoints = Setpoints::new();
    /// Control periods run (the thread's time base) and the stall check on them.
    static STALL: StallCheck = StallCheck::new(STALL_CHECKS);

    #[entry]
    fn main() -> ! {
        let Some(dp) = pac::Peripherals::take() else {
            stop(defmt::intern!("device peripherals taken twice"))
        };
        let Some(mut cp) = cortex_m::Peripherals::take() else {
            stop(defmt::intern!("core peripherals taken twice"))
        };
        // The stack (below the statics, flip-link): painted, so that a probe can read its
        // high-water mark, and its lowest bytes made a fault through the MPU, in case
        // the bus does not fault just below RAM.
        stack::paint();
        let guarded = stack::guard(&mut cp.MPU);
        let config = Esc1Config { baud: BAUD, ..Esc1Config::default() };
        // Refused (dead time below the floor, a comparator's zero-current level out of its
        // window, the ADC trigger off the valley): bridge off, the reason over defmt, stop.
        let board = match esc1::init(dp, &config) {
            Ok(board) => board,
            Err(e) => stop(e),
        };
        let (mut uart, mut led) = (board.uart, board.led);
        // Named here rather than through `Debug2Format`: that would link core::fmt (4.9 KB).
        let clock = match board.clock_source {
            ClockSource::Hsi16 => "HSI16",
            ClockSource::Hse8MHz => "HSE 8 MHz",
        };
        defmt::info!("B-G431B-ESC1 up, clock {}", clock);
        defmt::info!("stack: {} bytes, MPU guard {}", stack::bounds().1 - stack::bounds().0, guarded);
        // Lamp test: the status LED lit for half a second, then dark until the drive runs
        // (first power-up checklist: lit now and dark after, or the polarity is wrong).
        led.set_lit(true);
        cortex_m::asm::delay(esc1::SYSCLK_HZ / 2);
        led.set_lit(false);

        let image = match esc1::motor_image() {
            Ok(image) => image,
            Err(e) => halt(&mut led, e),
        };
        // The drive of the image (`image_drive::drive_config`, as every drive image):
        // positioning on the image's axis, or a speed drive without one; the inverter
        // compensation from the image (identified by commissioning: `dcfo identify
        // --image`), without one the programmed dead time alone.
        let bridge = Inverter::Bridge { dead_time_s: DEFAULT_DEAD_TIME_NS as f32 * 1e-9 };
        let drive_config = match drive_config(&image, 1.0 / DEFAULT_PWM_HZ as f32, bridge) {
            Ok(c) => c,
            Err(e) => halt(&mut led, e.field),
        };
        let drive = match Drive::<f32>::new(&image.motor, &drive_config, &Base::SI) {
            Ok(d) => d,
            Err(e) => halt(&mut led, e.field),
        };
        defmt::info!(
            "motor: {}, bus {} V, compensation {} (from the image: {}), axis {}",
            image.motor,
            image.bus_v,
            drive_config.dead_time_compensation,
            image.compensation.is_some(),
            image.axis
        );

        // The hardware trip a quarter above the drive's own over-current fault (which acts
        // first, in software), within the board's limits, over the comparators' zero-current
        // levels measured at init.
        let mut power = board.power;
        let zero = power.zero_current_codes();
        defmt::info!(
            "comparator inputs at zero current U/V/W: {} counts = {} V by the DAC3 sweep, {} V by the ADCs",
            zero,
            zero.map(esc1::dac_code_volts),
            board.shunt_inputs_adc_v
        );
        let thresholds = power.set_over_current_trip_a(1.25 * drive_config.faults.overcurrent_a);
        defmt::info!(
            "over-current trip U/V/W {} A (hardware: DAC3 {} / {} counts), {} A (drive); comparators U/V/W {}",
            thresholds.trip_a,
            thresholds.dac_ch1,
            thresholds.dac_ch2,
            drive_config.faults.overcurrent_a,
            power.comparators()
        );
        if power.hardware_trip() {
            halt(
                &mut led,
                defmt::intern!(
                    "TIM1 break active at start-up: an over-current comparator, lock-up or clock failure"
                ),
            );
        }

        let mut sensors = board.sensors;
        if !sensors.calibrate_current_offsets(64) {
            defmt::error!(
                "current offsets (counts): {} (window {})",
                sensors.last_calibration(),
                esc1::CURRENT_OFFSET_WINDOW_COUNTS
            );
            halt(
                &mut led,
                defmt::intern!(
                    "current offsets: no ADC conversions, or outside the window (op-amp, channel or bias fault)"
                ),
            );
        }
        defmt::info!("current offsets (counts): {}", sensors.current_offsets());
        defmt::info!("bus at rest: {} V", sensors.sample().vdc_v);

        // The drive in a static of its own, in .bss (`Slot`); `None` only if this ran twice.
        let control = cortex_m::singleton!(
            : DriveOnBoard<f32, Bridge<Esc1Sensors, Esc1PowerStage>> =
                DriveOnBoard { control: ControlLoop::new(drive, u16::MAX), board: Bridge { sensors, power } }
        );
        let Some(control) = control else { halt(&mut led, defmt::intern!("control state taken twice")) };
        if !install(&CONTROL, control) {
            halt(&mut led, defmt::intern!("control state busy at start-up"));
        }
        // SAFETY: set before the interrupt is unmasked; no critical section here relies on
        // priorities (they use PRIMASK).
        unsafe { cp.NVIC.set_priority(CONTROL_IRQ, PRIORITY_CONTROL) };
        NVIC::unpend(CONTROL_IRQ);
        // SAFETY: the handler's state is in place (above); critical sections use PRIMASK,
        // not the NVIC mask.
        unsafe { NVIC::unmask(CONTROL_IRQ) };
        // The stall check: SysTick at a priority below the control interrupt's.
        STALL.arm();
        // HCLK / 8.
        start_systick(
            &mut cp.SYST,
            &mut cp.SCB,
            PRIORITY_STALL_CHECK,
            SystClkSource::External,
            esc1::SYSCLK_HZ / 8 / STALL_CHECK_HZ - 1,
        );

        let mut server = BoardLinkServer::new(COMMAND_TIMEOUT_PERIODS);
        let mut last_state = DriveState::Disabled;
        let mut wire = [0u8; CaptureChunk::WIRE_LEN];
        loop {
            // Commands in, one answer each (telemetry, or capture samples).
            while let Ok(Some(byte)) = uart.try_read_byte() {
                let periods = STALL.periods();
                if let Some(bytes) =
                    LINK.on_byte(&mut server, byte, &SETPOINTS, LinkClock::periods(periods), &mut wire)
                {
                    let _ = uart.write_all(bytes);
                }
            }
            server.watchdog(&SETPOINTS, LinkClock::periods(STALL.periods()));
            // State changes logged.
            let (state, faults) =
                LINK.status().map(|s| (s.state, s.faults)).unwrap_or((last_state, Default::default()));
            if state != last_state {
                defmt::info!("state {} -> {}, faults {}", last_state, state, faults);
                last_state = state;
            }
            let _ = led.set_state((last_state == DriveState::Running).into());
            if STALL.stalled() {
                halt(
                    &mut led,
                    defmt::intern!("control interrupt stalled: no ADC end of conversion for 10-20 ms"),
                );
            }
        }
    }

    /// The stall check, every 10 ms: if no control period has run since the check before the
    /// last, the bridge goes off and the control interrupt is masked for good (the thread
    /// then halts and says why).
    #[exception]
    fn SysTick() {
        STALL.check(|| {
            NVIC::mask(CONTROL_IRQ);
            esc1::force_bridge_off();
        });
    }

    /// The control interrupt: end of the injected conversions at the carrier valley.
    /// The state is borrowed only in critical sections that never nest, so the borrow
    /// cannot fail; if it did, the drive could not step: bridge off and this interrupt
    /// masked for good (no panic).
    #[interrupt]
    fn ADC1_2() {
        let stepped = free(|cs| match CONTROL.borrow(cs).try_borrow_mut() {
            Ok(mut guard) => {
                if let Some(c) = guard.as_mut() {
                    LINK.period(cs, c, &SETPOINTS);
                    STALL.period();
                }
                true
            }
            Err(_) => false,
        });
        if !stepped {
            esc1::force_bridge_off();
            NVIC::mask(CONTROL_IRQ);
        }
    }

    dcfo_firmware::esc1_fault_handlers!();

    /// Cannot run: bridge off (init left MOE clear and the ADC interrupt masked; cleared
    /// again here), says why over defmt and blinks the LED fast.
    fn halt(led: &mut StatusLed, why: impl defmt::Format) -> ! {
        esc1::force_bridge_off();
        defmt::error!("cannot run: {}", why);
        loop {
            led.toggle();
            cortex_m::asm::delay(esc1::SYSCLK_HZ / 10);
        }
    }
}
