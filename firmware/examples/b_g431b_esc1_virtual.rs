//! The ESC1 drive image with the virtual motor in place of the power stage: the drive of
//! the motor image (or, without one, the paper motor) runs closed loop on
//! `dcfo::plant` inside the STM32G431 while the bridge stays off (TIM1 MOE is
//! never set), operated from the host over the board link on USART2 (`dcfo board --port`),
//! as `qemu_drive` on QEMU. **Not tried on hardware** (none here); it builds in CI.
//!
//! The drive is the image's (`dcfo_firmware::image_drive::drive_config`, as every drive
//! image) without inverter compensation (the virtual inverter is ideal): with an axis in
//! the image a positioning drive moving the axis's payload, which takes moves over the
//! board link; without one a speed drive, and the virtual axis carries the paper axis's
//! 10 kg carriage (`PAPER_AXIS_PAYLOAD_KG`) besides the motor's own mass (a bare mover
//! trips after the I/f hand-over: docs/low-speed-operation.md).
//!
//! | context | priority | work | budget |
//! |---|---|---|---|
//! | SysTick, 10 kHz | 0x00, highest | `ControlLoop::period` on the `VirtualBoard`, `Capture::record`, `DriveStatus::update` | 100 µs = 17,000 cycles at 170 MHz; the step's instructions are `bench_qemu`'s (`docs/cost-budget.md`), the virtual motor's eight sub-steps are not measured |
//! | thread | — | board link on USART2, command watchdog (0.5 s), defmt | — |
//!
//! ```sh
//! cargo run -p dcfo-firmware --release --features esc1 --example b_g431b_esc1_virtual --target thumbv7em-none-eabihf
//! cargo run --release -p dcfo-host -- board --port /dev/ttyACM0 --demo --json
//! ```
//! (The demo asks for a finished capture with the drive `Running`; the 128 samples here
//! end long before the hand-over, so the demo's wait holds until the drive runs.)
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!("b_g431b_esc1_virtual is firmware: build it with `--target thumbv7em-none-eabihf`");
}

#[cfg(target_arch = "arm")]
mod firmware {
    use cortex_m::interrupt;
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m_rt::{entry, exception};
    use dcfo::drive::{Drive, PAPER_AXIS_BUS_V};
    use dcfo::link::board::CaptureChunk;
    use dcfo::motor::MotorParams;
    use dcfo::motor_image::MotorImage;
    use dcfo::num::units::Base;
    use dcfo::plant::VirtualMotor;
    use dcfo_firmware::board::b_g431b_esc1::{self as esc1, DEFAULT_PWM_HZ, Esc1Config, SYSCLK_HZ, stop};
    use dcfo_firmware::board::virtual_motor::VirtualBoard;
    use dcfo_firmware::board_link::{BoardLinkServer, LinkClock};
    use dcfo_firmware::control::{ControlLoop, Setpoints};
    use dcfo_firmware::image_drive::{Inverter, drive_config, virtual_axis};
    use dcfo_firmware::runtime::{
        BoardLinkState, CaptureCell, DriveOnBoard, Slot, capture_cell, install, slot, start_systick,
    };
    use dcfo_firmware::stack;
    use embedded_io::Write as _;
    use stm32g4::stm32g431 as pac;

    const BAUD: u32 = 921_600;
    /// Capture capacity, samples (4.6 KB), as the ESC1 drive image.
    const CAPTURE_SAMPLES: usize = 128;
    /// Control periods without a command after which the drive is disabled (0.5 s).
    const COMMAND_TIMEOUT_PERIODS: u32 = DEFAULT_PWM_HZ / 2;
    /// SysTick (the control period) priority: the highest.
    const PRIORITY_CONTROL: u8 = 0x00;

    /// What the control interrupt owns.
    static CONTROL: Slot<&'static mut DriveOnBoard<f32, VirtualBoard>> = slot();
    /// The capture and the last step's status.
    static CAPTURE: CaptureCell<CAPTURE_SAMPLES> = capture_cell();
    static LINK: BoardLinkState<CAPTURE_SAMPLES> = BoardLinkState::new(&CAPTURE);
    static SETPOINTS: Setpoints = Setpoints::new();

    #[entry]
    fn main() -> ! {
        let Some(dp) = pac::Peripherals::take() else {
            stop(defmt::intern!("device peripherals taken twice"))
        };
        let Some(mut cp) = cortex_m::Peripherals::take() else {
            stop(defmt::intern!("core peripherals taken twice"))
        };
        stack::paint();
        let guarded = stack::guard(&mut cp.MPU);
        // The bridge stays off: init leaves MOE clear and nothing here enables it (the
        // virtual board has no register).
        let board = match esc1::init(dp, &Esc1Config { baud: BAUD, ..Esc1Config::default() }) {
            Ok(board) => board,
            Err(e) => stop(e),
        };
        let mut uart = board.uart;
        // The image's drive (`image_drive::drive_config`, as every drive image: with an
        // axis a positioning drive); without a valid image, the paper motor's speed drive.
        let image = match esc1::motor_image() {
            Ok(image) => image,
            Err(_) => match MotorImage::new(MotorParams::paper(), PAPER_AXIS_BUS_V) {
                Ok(image) => image,
                Err(_) => stop(defmt::intern!("paper motor refused")),
            },
        };
        let period_s = 1.0 / DEFAULT_PWM_HZ as f32;
        let config = match drive_config(&image, period_s, Inverter::Virtual) {
            Ok(c) => c,
            Err(e) => stop(e.field),
        };
        let drive = match Drive::<f32>::new(&image.motor, &config, &Base::SI) {
            Ok(d) => d,
            Err(e) => stop(e.field),
        };
        let Ok(virtual_motor) = VirtualMotor::new(&image.motor, &virtual_axis(&image, period_s)) else {
            stop(defmt::intern!("virtual motor settings refused"))
        };
        // The drive in a static of its own, in .bss (`Slot`); `None` only if this ran twice.
        let control = cortex_m::singleton!(
            : DriveOnBoard<f32, VirtualBoard> = DriveOnBoard {
                control: ControlLoop::new(drive, u16::MAX),
                board: VirtualBoard::new(virtual_motor),
            }
        );
        let Some(control) = control else { stop(defmt::intern!("control state taken twice")) };
        if !install(&CONTROL, control) {
            stop(defmt::intern!("control state busy at start-up"));
        }
        // HCLK / 8.
        start_systick(
            &mut cp.SYST,
            &mut cp.SCB,
            PRIORITY_CONTROL,
            SystClkSource::External,
            SYSCLK_HZ / 8 / DEFAULT_PWM_HZ - 1,
        );
        defmt::info!(
            "B-G431B-ESC1 virtual motor, bridge off; stack {} bytes, MPU guard {}",
            stack::bounds().1 - stack::bounds().0,
            guarded
        );

        let mut server = BoardLinkServer::new(COMMAND_TIMEOUT_PERIODS);
        let mut wire = [0u8; CaptureChunk::WIRE_LEN];
        loop {
            let periods = LINK.periods();
            while let Ok(Some(byte)) = uart.try_read_byte() {
                if let Some(bytes) =
                    LINK.on_byte(&mut server, byte, &SETPOINTS, LinkClock::periods(periods), &mut wire)
                {
                    let _ = uart.write_all(bytes);
                }
            }
            server.watchdog(&SETPOINTS, LinkClock::periods(periods));
        }
    }

    /// The control period on the virtual board; the state is borrowed only in critical
    /// sections that never nest: were it busy, the period is skipped (no panic).
    #[exception]
    fn SysTick() {
        interrupt::free(|cs| {
            let Ok(mut control) = CONTROL.borrow(cs).try_borrow_mut() else { return };
            let Some(c) = control.as_mut() else { return };
            LINK.period(cs, c, &SETPOINTS);
        });
    }

    dcfo_firmware::esc1_fault_handlers!();
}
