//! flip-link's stack guard, shown on QEMU's MPS2 boards: the image recurses without
//! bound. Linked with flip-link (the thumb targets' linker, `.cargo/config.toml`), the
//! stack sits below the statics, so the recursion runs off the bottom of the stack and
//! faults (on QEMU, which ignores writes below RAM, in the MPU guard of
//! `dcfo_firmware::stack::guard`);
//! the HardFault handler ([`dcfo_firmware::hard_fault_entry!`]: stack pointer reset first)
//! then finds both statics as they were and prints
//! `STACK_GUARD fault after <n> frames, statics intact` on UART0. Linked the usual way
//! (stack at the top of RAM, growing down onto `.bss` and `.data`), it would overwrite
//! them first and print `statics overwritten` (or never print at all). The image exits
//! through semihosting `SYS_EXIT`: status 0 when the statics were intact.
//!
//! ```sh
//! cargo build -p dcfo-firmware --release --features mps2 --example stack_guard --target thumbv7em-none-eabihf
//! qemu-system-arm -M mps2-an386 -cpu cortex-m4 -display none -monitor none \
//!     -semihosting-config enable=on,target=native -serial stdio \
//!     -kernel target/thumbv7em-none-eabihf/release/examples/stack_guard
//! ```
//! `host/tests/qemu_hil.rs` runs it for both boards. On the host this file builds to an
//! empty `main`.
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!(
        "stack_guard is firmware: build it with `--target thumbv7em-none-eabihf` or `thumbv7m-none-eabi`"
    );
}

#[cfg(target_arch = "arm")]
mod firmware {
    use core::hint::black_box;
    use core::sync::atomic::{AtomicU32, Ordering};

    use cortex_m_rt::entry;
    use dcfo_firmware::board::mps2::{CmsdkUart, semihosting_exit as exit};
    use dcfo_firmware::stack;
    use embedded_io::Write as _;

    /// In `.data` (a non-zero initial value).
    static DATA_CANARY: AtomicU32 = AtomicU32::new(0x5AFE_DA7A);
    /// In `.bss` (zero at boot), set in `main`.
    static BSS_CANARY: AtomicU32 = AtomicU32::new(0);
    const BSS_VALUE: u32 = 0xB55C_A7A1;
    /// Frames entered so far.
    static FRAMES: AtomicU32 = AtomicU32::new(0);

    #[entry]
    fn main() -> ! {
        // SAFETY: the only UART0 handle until the fault handler, which runs when this
        // context can no longer use it.
        let mut uart = unsafe { CmsdkUart::steal_uart0() };
        uart.init(115_200);
        let guarded = cortex_m::Peripherals::take().is_some_and(|mut cp| stack::guard(&mut cp.MPU));
        let _ = write!(uart, "STACK_GUARD start, mpu guard {guarded}\r\n");
        BSS_CANARY.store(BSS_VALUE, Ordering::Relaxed);
        let n = recurse(black_box(1));
        // Not reached: the recursion has no end.
        let _ = write!(uart, "STACK_GUARD returned {n}\r\n");
        exit(false)
    }

    /// Far more frames than any RAM here holds (1 GiB of them).
    const FRAME_LIMIT: u32 = 1 << 22;

    /// 256 bytes of frame per call, each written, and a use of the callee's result after
    /// the call (no tail call).
    #[inline(never)]
    fn recurse(k: u32) -> u32 {
        if k >= FRAME_LIMIT {
            return k;
        }
        let mut frame = [k; 64];
        black_box(&mut frame);
        FRAMES.store(k, Ordering::Relaxed);
        let below = recurse(black_box(k + 1));
        below.wrapping_add(frame[black_box(5) % 64])
    }

    /// Runs on a fresh stack ([`dcfo_firmware::hard_fault_entry!`]).
    extern "C" fn on_hard_fault() -> ! {
        let intact = DATA_CANARY.load(Ordering::Relaxed) == 0x5AFE_DA7A
            && BSS_CANARY.load(Ordering::Relaxed) == BSS_VALUE;
        // SAFETY: the thread that used UART0 never runs again.
        let mut uart = unsafe { CmsdkUart::steal_uart0() };
        let frames = FRAMES.load(Ordering::Relaxed);
        let verdict = if intact { "statics intact" } else { "statics overwritten" };
        let _ = write!(uart, "STACK_GUARD fault after {frames} frames, {verdict}\r\n");
        exit(intact)
    }

    dcfo_firmware::hard_fault_entry!(on_hard_fault);

    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        exit(false)
    }
}
