//! Lock-step HIL firmware for QEMU's MPS2 boards, interrupt-driven, UART0 at 115200 8N1:
//! - `thumbv7em-none-eabihf` on `mps2-an386` (Cortex-M4F): `Drive<f32>` in SI units;
//! - `thumbv7m-none-eabi` on `mps2-an385` (Cortex-M3, no FPU): `Drive<Q24>` (Q8.24
//!   fixed point) in the per-unit base of the motor, the fixed-point path.
//!
//! The drive runs `DriveConfig::paper_axis` (DCFO), the settings of the host's
//! simulated axis, so a HIL run and an in-process run of the same numeric type agree bit
//! for bit. Started with the command line `stroke <motor image in hex>` (QEMU's
//! `-append`, read through semihosting; `dcfo stroke --qemu` passes it), it runs the
//! positioning drive of `dcfo stroke` instead: `DriveConfig::stroke_axis` of the image's
//! motor and bus, the function the host's in-process stroke builds its drive with. The
//! host queues moves through the sensor frames (`Drive::push_move`; a refused move is
//! counted in the answers, never acted on) and reads x̂ in the answers. Each in-order `dcfo::link::SensorFrame` from the host is one PWM period: its
//! arrival plays the part of the ADC's end-of-conversion interrupt on a drive board.
//!
//! | context | priority | work | budget |
//! |---|---|---|---|
//! | UART0 RX interrupt (IRQ 0) | 0x00, highest | per byte: `HilServer::on_byte`; per complete in-order frame: the link watchdog on its sequence number, one `Drive::step` and the encoded `ActuationFrame` into the TX queue | one control step (its instructions on either core: `bench_qemu`, `docs/cost-budget.md`), plus the per-byte COBS decoding (not measured separately) |
//! | thread | — | moves the TX queue into UART0, sleeps when it is empty | — |
//!
//! Between periods the host may send a `dcfo::link::CommissioningRequest`; it is answered
//! with a `CommissioningReport` in the same interrupt, and a start replaces the drive by
//! the one commissioning is told about (`LinkServer::on_byte`; `dcfo identify --qemu`).
//!
//! A silent link switches the bridge off (fault `EXTERNAL`) if the drive was active: a
//! frame whose sequence number skips 10 or more (the host sent no frame for 10 control
//! periods of its own) trips the drive before it steps on it, and that frame's answer
//! reports it (`LinkWatchdog::frame_after`, the periods the in-process fault campaign's
//! watchdog counts). The image has no timer and reads no clock: it steps once per frame,
//! and nothing it does follows QEMU's virtual clock or the host's wall clock. A host that
//! stops (a loaded machine, a debugger) stops the simulation with it, and picks it up where
//! it left it; the plant does not run meanwhile, so there is no silence to catch. Between
//! frames the core sleeps, and QEMU with it. Every other interrupt vector lands in
//! `DefaultHandler`, which masks that interrupt and trips the drive.
//!
//! Nothing in the image can panic (`.ci/no-panic` checks that the panic machinery is not
//! linked). Should that ever change, the panic handler stops the control interrupt
//! first, then prints `PANIC: <message>` on UART0 and stops the core; a HardFault (e.g.
//! a stack overflow, which flip-link turns into one) prints `HARDFAULT` and stops. A
//! stopped core answers no frame: the host's plant sees a silent link. An initialisation
//! that cannot complete prints `HALT: <why>` and stops the same way.
//!
//! ```sh
//! cargo build -p dcfo-firmware --release --features mps2 --example qemu_hil --target thumbv7em-none-eabihf
//! qemu-system-arm -M mps2-an386 -cpu cortex-m4 -display none -monitor none \
//!     -semihosting-config enable=on,target=native -serial stdio \
//!     -kernel target/thumbv7em-none-eabihf/release/examples/qemu_hil
//! ```
//! (`--target thumbv7m-none-eabi` and `-M mps2-an385 -cpu cortex-m3` for fixed point;
//! `dcfo hil --qemu [--cpu m3]` does all of this.)
//!
//! On the host this file builds to an empty `main`.
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!("qemu_hil is firmware: build it with `--target thumbv7em-none-eabihf` or `thumbv7m-none-eabi`");
}

#[cfg(target_arch = "arm")]
mod firmware {
    #[cfg(target_abi = "eabihf")]
    use cortex_m::peripheral::scb::FpuAccessMode;
    use cortex_m_rt::{entry, exception};
    use dcfo::algorithms::observer::ObserverKind;
    use dcfo::drive::{Drive, DriveConfig};
    use dcfo::motor::MotorParams;
    use dcfo::motor_image::MotorImage;
    use dcfo::num::units::Base;
    use dcfo_firmware::board::mps2::{self, CmsdkUart, UART0_RX_IRQN, Uart0RxIrq, UartRx, UartTx, halt};
    use dcfo_firmware::hil::HilServer;
    use dcfo_firmware::queue::{Producer, Queue};
    use dcfo_firmware::runtime::{Slot, install, slot, with_slot};
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

    /// NVIC priority of the control (UART0 RX) interrupt: the highest.
    const PRIORITY_CONTROL: u8 = 0x00;
    /// Bytes of transmit queue: four answers (or a commissioning report).
    const TX_QUEUE_BYTES: usize = dcfo_firmware::hil::tx_queue_bytes(4);

    /// What the control interrupt owns.
    struct Control {
        server: HilServer<Work>,
        rx: UartRx,
        tx: Producer<'static, u8, TX_QUEUE_BYTES>,
    }

    static CONTROL: Slot<&'static mut Control> = slot();

    #[entry]
    fn main() -> ! {
        let Some(mut uart) = CmsdkUart::take_uart0() else { halt("UART0 already taken") };
        uart.init(115_200);
        let Some(mut cp) = cortex_m::Peripherals::take() else { halt("core peripherals taken twice") };
        let Some(queue) = cortex_m::singleton!(: Queue<u8, TX_QUEUE_BYTES> = Queue::new()) else {
            halt("transmit queue taken twice")
        };
        let (producer, mut consumer) = queue.split();
        // The drive, for the axis the command line names, into the control state first:
        // the 512-byte line buffer, the axis's tuning, the drive's construction and its
        // moves into the state are one-offs at boot, done before the paint, so the
        // high-water mark measures the control path.
        let mut tx = match start(uart, producer) {
            Ok(tx) => tx,
            Err(why) => halt(why),
        };
        // The stack: paint it for the high-water mark (the host reads it through QEMU's
        // monitor), then the MPU guard at its bottom (QEMU ignores writes below RAM,
        // where flip-link's guard relies on a bus error).
        stack::paint();
        if !stack::guard(&mut cp.MPU) {
            halt("no MPU guard for the stack");
        }

        // SAFETY: set before the interrupt is unmasked; no critical section here relies on
        // priorities (they mask with PRIMASK).
        unsafe { cp.NVIC.set_priority(Uart0RxIrq, PRIORITY_CONTROL) };
        mps2::unmask_uart0_rx();

        loop {
            while let Some(byte) = consumer.dequeue() {
                tx.write_byte(byte);
            }
            // Sleep only if nothing arrived since the check: with PRIMASK set a pending
            // interrupt still ends WFI, and it is taken when `free` re-enables.
            cortex_m::interrupt::free(|_| {
                if !consumer.ready() {
                    cortex_m::asm::wfi();
                }
            });
        }
    }

    /// Builds the drive (the stroke axis of the command line's motor image, or without
    /// one the paper axis), prints the banner, installs the control state with UART0's
    /// receiver and `producer`, and returns UART0's transmitter for the thread. Not
    /// inlined (see `main`).
    #[inline(never)]
    fn start(
        mut uart: CmsdkUart,
        producer: Producer<'static, u8, TX_QUEUE_BYTES>,
    ) -> Result<UartTx, &'static str> {
        let (motor, config, axis) = match stroke_axis() {
            Some(image) => {
                let image = image?;
                (image.motor, DriveConfig::stroke_axis(&image.motor, image.bus_v), "stroke axis")
            }
            None => (MotorParams::paper(), DriveConfig::paper_axis(ObserverKind::Dcfo), "paper axis"),
        };
        let drive = Drive::<Work>::new(&motor, &config, &working_base(&motor)).map_err(|e| e.field)?;

        // The banner states the numeric type and, with an FPU, the access mode
        // (CPACR CP10/CP11) cortex-m-rt set before `main`. The 0x00 after it is a link
        // frame delimiter: the host's receiver drops the banner as one bad frame.
        // Written piece by piece: `write!` would link core::fmt (3-5 KB of flash).
        #[cfg(target_abi = "eabihf")]
        let numbers = match cortex_m::peripheral::SCB::fpu_access_mode() {
            FpuAccessMode::Enabled => "f32, fpu Enabled",
            FpuAccessMode::Privileged => "f32, fpu Privileged",
            FpuAccessMode::Disabled => "f32, fpu Disabled",
        };
        #[cfg(not(target_abi = "eabihf"))]
        let numbers = "Q8.24 fixed point, no fpu";
        for part in ["dcfo-firmware qemu_hil: ", numbers, ", ", axis, "\r\n\0"] {
            let _ = uart.write_all(part.as_bytes());
        }

        let (rx, tx) = uart.into_interrupt_driven();
        // The state in a static of its own, in .bss (`Slot`); `None` only if this ran twice.
        let Some(control) =
            cortex_m::singleton!(: Control = Control { server: HilServer::new(drive), rx, tx: producer })
        else {
            return Err("control state taken twice");
        };
        if !install(&CONTROL, control) {
            return Err("control state busy at start-up");
        }
        Ok(tx)
    }

    /// The stroke axis's motor image from the command line `... stroke <hex>`: `None`
    /// without the word `stroke`, an error naming what is wrong with the image. Not
    /// inlined: its line buffer is given back before the control loop runs.
    #[inline(never)]
    fn stroke_axis() -> Option<Result<MotorImage, &'static str>> {
        let mut line = [0u8; 512];
        let line = mps2::semihosting_cmdline(&mut line)?;
        let mut words = line.split(|&b| b == b' ').filter(|w| !w.is_empty());
        words.by_ref().find(|w| *w == b"stroke")?;
        let Some(hex) = words.next() else { return Some(Err("stroke: no motor image after `stroke`")) };
        Some(dcfo_firmware::image_drive::motor_image_from_hex(hex))
    }

    /// UART0 RX: drain the receiver through the HIL server; an in-order frame runs one
    /// control step (after the link watchdog on its sequence number), whose answer goes to
    /// the transmit queue. Should the state be unreachable, the bytes are left in the UART
    /// and this interrupt is masked: a drive that cannot step answers nothing, and the
    /// host's watchdog sees a silent link.
    fn on_uart0_rx() {
        let ok = with_slot(&CONTROL, |c| {
            while let Some(byte) = c.rx.try_read_byte() {
                c.server.on_byte(byte, &mut c.tx);
            }
        });
        if !ok {
            mps2::mask_irq(UART0_RX_IRQN as i16);
        }
    }

    // SAFETY: cortex-m-rt requires the default handler to be declared `unsafe`; it runs
    // for every interrupt vector (no device crate is linked) and only dispatches on the
    // number and touches state through the critical section.
    #[exception]
    unsafe fn DefaultHandler(irqn: i16) {
        if irqn == UART0_RX_IRQN as i16 {
            on_uart0_rx();
            return;
        }
        // No handler for this interrupt: silence it and switch the bridge off.
        mps2::mask_irq(irqn);
        with_slot(&CONTROL, |c| c.server.trip());
    }

    dcfo_firmware::mps2_fault_handlers!();
}
