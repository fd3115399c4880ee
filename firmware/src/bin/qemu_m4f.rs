//! Lock-step HIL firmware for QEMU `mps2-an386` (Cortex-M4F), UART0 at 115200 8N1.
//!
//! Prints a one-line banner, then for every in-order `dcfo::link::SensorFrame` from the
//! host (phase currents, bus voltage, speed reference, enable) runs `Drive::<f32>::step`
//! once and answers with an `ActuationFrame` (duties, state, faults, estimate, link
//! counts) through the library's `dcfo::link::LinkServer`. The drive runs
//! `DriveConfig::paper_axis`, the settings of the host's simulated axis, so a HIL run
//! and an in-process run agree bit for bit. No interrupt handlers and no timers: the
//! host paces the loop (a board with a PWM interrupt calls `LinkServer::silent_period`
//! in periods without a frame). A panic prints `PANIC: <message>` on UART0 and stops the core.
//!
//! ```sh
//! cargo build -p dcfo-firmware --release --target thumbv7em-none-eabihf
//! qemu-system-arm -M mps2-an386 -cpu cortex-m4 -display none -monitor none \
//!     -semihosting-config enable=on,target=native -serial stdio \
//!     -kernel target/thumbv7em-none-eabihf/release/qemu_m4f
//! ```
//!
//! On the host this file builds to an empty `main`.
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!("qemu_m4f is firmware: build it with `--target thumbv7em-none-eabihf`");
}

#[cfg(target_arch = "arm")]
mod firmware {
    use cortex_m as _; // critical-section implementation (single core)
    use cortex_m_rt::entry;
    use dcfo::drive::{Drive, DriveConfig};
    use dcfo::link::{ActuationFrame, LinkServer};
    use dcfo::motor::MotorParams;
    use dcfo::observer::ObserverKind;
    use dcfo::units::Base;
    use dcfo_firmware::board::mps2_an386::CmsdkUart;
    use embedded_io::Write as _; // write_all and write! (write_fmt)

    #[entry]
    fn main() -> ! {
        let Some(mut uart) = CmsdkUart::take_uart0() else { panic!("UART0 already taken") };
        uart.init(115_200);
        uart.enable_rx_wakeup();

        let motor = MotorParams::paper();
        let config = DriveConfig::paper_axis(ObserverKind::Dcfo);
        let mut drive = match Drive::<f32>::new(&motor, &config, &Base::SI) {
            Ok(d) => d,
            Err(e) => panic!("{e}"),
        };

        // The banner states the FPU access mode (CPACR CP10/CP11) that cortex-m-rt set
        // before `main`; every f32 operation below runs on the FPU. The 0x00 after it is
        // a link frame delimiter: a host link receiver drops the banner as one bad frame
        // and starts clean on the first answer.
        #[cfg(target_abi = "eabihf")]
        let fpu = cortex_m::peripheral::SCB::fpu_access_mode();
        #[cfg(not(target_abi = "eabihf"))]
        let fpu = "soft-float";
        let _ = write!(uart, "dcfo-firmware qemu_m4f: drive ready, fpu {fpu:?}\r\n\0");

        let mut link = LinkServer::new();
        let mut reply = [0u8; ActuationFrame::WIRE_LEN];
        loop {
            let byte = uart.read_byte();
            if let Some(n) = link.on_byte(byte, &mut drive, &Base::SI, &mut reply) {
                let Ok(()) = uart.write_all(&reply[..n]);
            }
        }
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        cortex_m::interrupt::disable();
        // SAFETY: interrupts are off and the panic handler never returns, so the main
        // loop's UART0 handle is never used again; nothing else runs.
        let mut uart = unsafe { CmsdkUart::steal_uart0() };
        let _ = write!(uart, "\r\nPANIC: {info}\r\n");
        loop {
            cortex_m::asm::wfi();
        }
    }
}
