//! A drive image on QEMU's MPS2 boards with the virtual motor in place of the power
//! stage: the drive runs closed loop in its control interrupt with no plant outside it,
//! operated from the host over UART0 with the board link (`dcfo board --qemu`).
//! - `thumbv7em-none-eabihf` on `mps2-an386` (Cortex-M4F): `Drive<f32>` in SI units, as
//!   the ESC1 drive image; its capture replays bit for bit on the host (`dcfo replay`).
//! - `thumbv7m-none-eabi` on `mps2-an385` (Cortex-M3): `Drive<Q24>` in the motor's
//!   per-unit base; the capture holds the drive's Q8.24 words (format `q24` in each
//!   chunk) and replays bit for bit through `Estimator<Q24>` (`dcfo replay --numeric
//!   q24`; `dcfo board --qemu --cpu m3 --demo` checks it).
//!
//! The motor and the drive come from a motor image, as on the ESC1 (which reads it from
//! flash): the command line `image <hex>` (QEMU's `-append`, read through semihosting;
//! `dcfo board --qemu --image FILE` or `--move-to X` passes it) holds the record, and the
//! drive is built from it by `dcfo_firmware::image_drive::drive_config`, the function
//! the ESC1 images use, without inverter compensation (the virtual inverter is ideal).
//! With an axis in the image (version 3) it is a positioning drive: it takes moves from
//! the commands and its telemetry carries the position report; without one (or a
//! version-1 or -2 image) a speed drive, which reports every move refused. Without a
//! command line: the paper motor's speed drive at the paper axis's bus, on the paper
//! axis's carriage (`PAPER_AXIS_PAYLOAD_KG`). The virtual motor (`dcfo::plant`)
//! derives everything from the same `MotorParams`, with the axis's payload.
//!
//! | context | priority | work | budget |
//! |---|---|---|---|
//! | SysTick, 10 kHz (the PWM period) | 0x00, highest | `ControlLoop::period` on the `VirtualBoard` (virtual motor: 8 sub-steps), `Capture::record`, `DriveStatus::update` | one period: 2,500 cycles at 25 MHz are not enough on a real MPS2; on QEMU with `-icount shift=0` a period is 100,000 instructions, of which the step takes a fraction (`bench_qemu`) |
//! | thread | — | UART0 polled: `BoardLinkServer` commands, one answer per command, command watchdog on the drive's periods and the host's clock | the rest of each period |
//!
//! Time: QEMU runs the image with `-icount shift=0,sleep=off` (`dcfo_host::qemu`): one
//! instruction is one nanosecond of the image's time and an idle core (`WFI` until the next
//! SysTick) jumps to the next timer deadline. So the control periods, and what the thread
//! gets done between them, follow the instructions executed, whatever the host's load:
//! the drive's simulated time is its count of periods, and a loaded host slows it down
//! without reordering anything in it. It also runs as fast as QEMU can execute, not at the
//! wall clock's pace.
//!
//! Command watchdog: no command for 5,000 control periods (0.5 s of the drive's time) *and*
//! 500 ms of the host's time (`HostClock`, semihosting `SYS_ELAPSED`) disables the drive
//! (`BoardLinkServer::with_host_clock`). The drive's periods run as fast as QEMU executes
//! them, faster or slower than the host's clock; a silence is one in both: a host merely
//! slower than QEMU, or a machine that stalled QEMU and the host together (no periods ran),
//! is not silent. The bytes that have arrived are taken before the watchdog looks, so a
//! command that waited while the thread did not run is not a silence either.
//! Every other interrupt vector lands in `DefaultHandler`, which masks it and disables the
//! drive. Nothing in the image can panic (`.ci/no-panic`).
//!
//! ```sh
//! cargo build -p dcfo-firmware --release --features mps2 --example qemu_drive --target thumbv7em-none-eabihf
//! dcfo board --qemu --demo --json      # or interactively: dcfo board --qemu
//! dcfo board --qemu --cpu m3 --demo --json   # the Q8.24 image (thumbv7m-none-eabi)
//! ```
//!
//! On the host this file builds to an empty `main`.
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!(
        "qemu_drive is firmware: build it with `--target thumbv7em-none-eabihf` or `thumbv7m-none-eabi`"
    );
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
    use dcfo_firmware::board::mps2::{CmsdkUart, HostClock, SYSCLK_HZ, halt};
    use dcfo_firmware::board::virtual_motor::VirtualBoard;
    use dcfo_firmware::board_link::{BoardLinkServer, LinkClock};
    use dcfo_firmware::control::{ControlLoop, Setpoints};
    use dcfo_firmware::image_drive::{Inverter, drive_config, motor_image_from_hex, virtual_axis};
    use dcfo_firmware::runtime::{
        BoardLinkState, CaptureCell, DriveOnBoard, Slot, capture_cell, install, slot, start_systick,
    };
    use dcfo_firmware::stack;
    use embedded_io::Write as _;

    /// The numeric type of the control code: f32 with an FPU, Q8.24 without.
    #[cfg(target_abi = "eabihf")]
    type Work = f32;
    #[cfg(not(target_abi = "eabihf"))]
    type Work = dcfo::num::Q24;

    /// Working units: SI for f32, per-unit of the motor for fixed point.
    fn working_base(motor: &MotorParams) -> Base {
        if cfg!(target_abi = "eabihf") { Base::SI } else { Base::for_motor(motor) }
    }

    /// Capture capacity, samples: 2.4 s at 10 kHz (864 KB of the board's 4 MiB), enough
    /// to hold the start-up and the hand-over to `Running` of the paper axis at 0.3 m/s
    /// (about 1.8 s after enable on the virtual motor).
    const CAPTURE_SAMPLES: usize = 24_000;
    /// Control (PWM) rate, Hz.
    const CONTROL_HZ: u32 = 10_000;
    /// Control periods without a command after which the drive is disabled (0.5 s of the
    /// drive's time)...
    const COMMAND_TIMEOUT_PERIODS: u32 = CONTROL_HZ / 2;
    /// ... if they also span this much of the host's time (ms).
    const COMMAND_TIMEOUT_HOST_MS: u32 = 500;
    /// SysTick (the control period) priority: the highest.
    const PRIORITY_CONTROL: u8 = 0x00;

    /// What the control interrupt owns.
    static CONTROL: Slot<&'static mut DriveOnBoard<Work, VirtualBoard>> = slot();
    /// The capture and the last step's status: filled by the control interrupt, read by
    /// the thread.
    static CAPTURE: CaptureCell<CAPTURE_SAMPLES> = capture_cell();
    static LINK: BoardLinkState<CAPTURE_SAMPLES> = BoardLinkState::new(&CAPTURE);
    static SETPOINTS: Setpoints = Setpoints::new();

    #[entry]
    fn main() -> ! {
        let Some(mut uart) = CmsdkUart::take_uart0() else { halt("UART0 already taken") };
        uart.init(115_200);
        let Some(mut cp) = cortex_m::Peripherals::take() else { halt("core peripherals taken twice") };
        let Some(host_clock) = HostClock::new() else { halt("no host clock (semihosting SYS_TICKFREQ)") };
        stack::paint();
        if !stack::guard(&mut cp.MPU) {
            halt("no MPU guard for the stack");
        }

        // The motor image from the command line (as the ESC1 reads it from flash), or
        // the paper motor's speed drive; the drive is the image's, built as on every
        // drive image (`image_drive::drive_config`): with an axis a positioning drive.
        let image = match image_from_cmdline() {
            Some(Ok(image)) => image,
            Some(Err(why)) => halt(why),
            None => match MotorImage::new(MotorParams::paper(), PAPER_AXIS_BUS_V) {
                Ok(image) => image,
                Err(_) => halt("paper motor refused"),
            },
        };
        let motor = image.motor;
        let period_s = 1.0 / CONTROL_HZ as f32;
        let config = match drive_config(&image, period_s, Inverter::Virtual) {
            Ok(c) => c,
            Err(e) => halt(e.field),
        };
        let positioning = config.motion.is_some();
        let base = working_base(&motor);
        let drive = match Drive::<Work>::new(&motor, &config, &base) {
            Ok(d) => d,
            Err(e) => halt(e.field),
        };
        let virtual_motor = match VirtualMotor::new(&motor, &virtual_axis(&image, period_s)) {
            Ok(m) => m,
            Err(_) => halt("virtual motor settings refused"),
        };
        // The 0x00 after the banner is a frame delimiter: the host drops the banner as one
        // bad frame.
        let kind = if positioning { "positioning drive" } else { "speed drive" };
        let _ = write!(
            uart,
            "dcfo-firmware qemu_drive: virtual motor, {kind}, capture {CAPTURE_SAMPLES} samples\r\n\0"
        );

        // The drive in a static of its own, in .bss (`Slot`); `None` only if this ran twice.
        let control = cortex_m::singleton!(
            : DriveOnBoard<Work, VirtualBoard> = DriveOnBoard {
                control: ControlLoop::new(drive, u16::MAX),
                board: VirtualBoard::new(virtual_motor),
            }
        );
        let Some(control) = control else { halt("control state taken twice") };
        if !install(&CONTROL, control) {
            halt("control state busy at start-up");
        }
        start_systick(
            &mut cp.SYST,
            &mut cp.SCB,
            PRIORITY_CONTROL,
            SystClkSource::Core,
            SYSCLK_HZ / CONTROL_HZ - 1,
        );

        let mut server = BoardLinkServer::with_host_clock(COMMAND_TIMEOUT_PERIODS, COMMAND_TIMEOUT_HOST_MS);
        let mut wire = [0u8; CaptureChunk::WIRE_LEN];
        loop {
            // (A host clock that cannot be read counts as time passed.)
            let now = LinkClock { periods: LINK.periods(), host_ms: host_clock.now_ms() };
            while let Some(byte) = uart.try_read_byte() {
                if let Some(bytes) = LINK.on_byte(&mut server, byte, &SETPOINTS, now, &mut wire) {
                    for &b in bytes {
                        uart.write_byte(b);
                    }
                }
            }
            server.watchdog(&SETPOINTS, now);
            // SysTick wakes the core every period; a byte that arrives meanwhile waits in
            // the UART (the host sends one command and waits for its answer).
            cortex_m::asm::wfi();
        }
    }

    /// The motor image from the command line (QEMU's `-append`, through semihosting)
    /// `... image <hex>`: `None` without the word `image`, an error saying what is wrong
    /// with the record. Not inlined: its line buffer is given back before the control
    /// loop runs.
    #[inline(never)]
    fn image_from_cmdline() -> Option<Result<MotorImage, &'static str>> {
        let mut line = [0u8; 512];
        let line = dcfo_firmware::board::mps2::semihosting_cmdline(&mut line)?;
        let mut words = line.split(|&b| b == b' ').filter(|w| !w.is_empty());
        words.by_ref().find(|w| *w == b"image")?;
        let Some(hex) = words.next() else { return Some(Err("image: no motor image after `image`")) };
        Some(motor_image_from_hex(hex))
    }

    /// The control period: the virtual board, one drive step, the capture and the status.
    /// The state is borrowed only in critical sections that never nest; were it busy the
    /// period is skipped (no panic), which the status's period count shows.
    #[exception]
    fn SysTick() {
        interrupt::free(|cs| {
            let Ok(mut control) = CONTROL.borrow(cs).try_borrow_mut() else { return };
            let Some(c) = control.as_mut() else { return };
            LINK.period(cs, c, &SETPOINTS);
        });
    }

    // SAFETY: cortex-m-rt requires the default handler to be declared `unsafe`; it only
    // masks the interrupt that has no handler and disables the drive.
    #[exception]
    unsafe fn DefaultHandler(irqn: i16) {
        dcfo_firmware::board::mps2::mask_irq(irqn);
        SETPOINTS.set_enable(false);
    }

    dcfo_firmware::mps2_fault_handlers!();
}
