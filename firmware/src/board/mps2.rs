//! Arm MPS2/MPS2+ with the AN386 (Cortex-M4F) or AN385 (Cortex-M3) FPGA image, as
//! modelled by QEMU's `mps2-an386` and `mps2-an385` machines: the same memory map, UARTs
//! and interrupt numbers on both.
//!
//! Sources:
//! - Arm "Application Note AN386: ARM Cortex-M4 SMM on V2M-MPS2" and "AN385: ARM
//!   Cortex-M3 SMM on V2M-MPS2" (memory map: APB UART0 at `0x4000_4000`, UART1..4 at
//!   `0x4000_5000`, `0x4000_6000`, `0x4000_7000`, `0x4000_9000`; 25 MHz system clock).
//! - Arm "Cortex-M System Design Kit Technical Reference Manual" (ARM DDI 0479),
//!   section "APB UART" (register map below).
//! - QEMU `hw/char/cmsdk-apb-uart.c` and `hw/arm/mps2.c` (same map; UART0 is `-serial`
//!   number 0, i.e. `-serial stdio`).
//!
//! CMSDK APB UART registers (offsets from the base, 32-bit):
//!
//! | offset | name | bits used here |
//! |---|---|---|
//! | `0x000` | DATA | `[7:0]` received byte (read) / byte to send (write) |
//! | `0x004` | STATE | bit 0 TX buffer full, bit 1 RX buffer full, bit 2 TX overrun, bit 3 RX overrun (write 1 to clear) |
//! | `0x008` | CTRL | bit 0 TX enable, bit 1 RX enable, bit 3 RX interrupt enable (bits 2, 4, 5 stay 0) |
//! | `0x00C` | INTSTATUS / INTCLEAR | bit 1 RX interrupt (write 1 to clear) |
//! | `0x010` | BAUDDIV | `[19:0]` clock divider, at least 16 |
//!
//! The driver polls, with one byte of buffering each way. With
//! [`CmsdkUart::enable_rx_wakeup`] it sleeps (`WFI`) between received bytes instead of
//! spinning on STATE: the RX interrupt (AN386 interrupt map: UART0 RX is IRQ 0, TX is
//! IRQ 1) is enabled in the NVIC only to wake the core, while PRIMASK stays set so it is
//! never taken and no handler is needed. On QEMU 7.2 this raised the lock-step rate of
//! the HIL loop from 520-930 to 1050-1600 frames/s (measured; the polling vCPU
//! presumably contends with the I/O thread for QEMU's global lock on every register
//! read).

use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::NVIC;

/// Base address of APB UART0 (AN386 memory map).
pub const UART0_BASE: usize = 0x4000_4000;
/// System (APB) clock of the AN386 image, Hz.
pub const SYSCLK_HZ: u32 = 25_000_000;

const DATA: usize = 0x000;
const STATE: usize = 0x004;
const CTRL: usize = 0x008;
const INTCLEAR: usize = 0x00C;
const BAUDDIV: usize = 0x010;

const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const STATE_TX_OVERRUN: u32 = 1 << 2;
const STATE_RX_OVERRUN: u32 = 1 << 3;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_RX_INT_EN: u32 = 1 << 3;
const INT_RX: u32 = 1 << 1;

/// NVIC interrupt line of the UART0 receiver (AN385/AN386 interrupt map; QEMU `mps2.c`).
#[derive(Clone, Copy, Debug)]
pub struct Uart0RxIrq;

// SAFETY: 0 is the AN385/AN386 UART0 RX interrupt, a valid external interrupt number.
unsafe impl InterruptNumber for Uart0RxIrq {
    fn number(self) -> u16 {
        UART0_RX_IRQN
    }
}

/// The number of [`Uart0RxIrq`], as `DefaultHandler` receives it.
pub const UART0_RX_IRQN: u16 = 0;

static UART0_TAKEN: AtomicBool = AtomicBool::new(false);

/// A CMSDK APB UART, polled.
pub struct CmsdkUart {
    base: usize,
    /// Sleep between received bytes (see [`CmsdkUart::enable_rx_wakeup`]).
    rx_wakeup: bool,
}

impl CmsdkUart {
    /// UART0, once: `None` if it was already taken.
    pub fn take_uart0() -> Option<Self> {
        if UART0_TAKEN.swap(true, Ordering::AcqRel) {
            None
        } else {
            Some(CmsdkUart { base: UART0_BASE, rx_wakeup: false })
        }
    }

    /// UART0 regardless of who else holds it: for the panic handler only.
    ///
    /// # Safety
    /// The caller must make sure no other user of UART0 runs again (e.g. it is the
    /// panic handler of a single-threaded program that never returns), since the two
    /// would interleave register accesses.
    pub unsafe fn steal_uart0() -> Self {
        CmsdkUart { base: UART0_BASE, rx_wakeup: false }
    }

    /// Sets the baud rate (divider `SYSCLK_HZ / baud`, at least 16), clears the overrun
    /// flags and enables the transmitter and the receiver. QEMU ignores the rate.
    pub fn init(&mut self, baud: u32) {
        let div = (SYSCLK_HZ / baud.max(1)).clamp(16, 0xF_FFFF);
        self.write_reg(CTRL, 0);
        self.write_reg(BAUDDIV, div);
        self.write_reg(STATE, STATE_TX_OVERRUN | STATE_RX_OVERRUN);
        self.write_reg(CTRL, CTRL_TX_EN | CTRL_RX_EN);
    }

    /// Makes [`CmsdkUart::read_byte`] sleep until a byte arrives. Masks interrupts
    /// (PRIMASK) for good: the UART0 RX interrupt is enabled in the NVIC only as a
    /// `WFI` wake-up event and is never taken. For a program without interrupt handlers.
    pub fn enable_rx_wakeup(&mut self) {
        cortex_m::interrupt::disable();
        self.write_reg(INTCLEAR, INT_RX);
        self.write_reg(CTRL, CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN);
        NVIC::unpend(Uart0RxIrq);
        // SAFETY: unmasking can break critical sections that rely on the NVIC mask;
        // there are none here, and with PRIMASK set the interrupt only pends (it wakes
        // `WFI`) and is never taken.
        unsafe { NVIC::unmask(Uart0RxIrq) };
        self.rx_wakeup = true;
    }

    /// Switches to interrupt-driven reception and splits the UART into its receiver (for
    /// the UART0 RX interrupt handler) and its transmitter (for a lower-priority
    /// context). Every received byte raises IRQ 0 ([`Uart0RxIrq`]), whose handler must
    /// call [`UartRx::try_read_byte`] until it returns `None`.
    ///
    /// The halves share only the read-only STATE register; the receiver writes INTCLEAR
    /// and the RX-overrun bit of STATE (write-1-to-clear, so it cannot touch the TX
    /// bits), the transmitter writes DATA.
    ///
    /// The interrupt stays masked in the NVIC until [`unmask_uart0_rx`]: call that once
    /// the handler's state is in place.
    pub fn into_interrupt_driven(mut self) -> (UartRx, UartTx) {
        self.write_reg(INTCLEAR, INT_RX);
        self.write_reg(CTRL, CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN);
        NVIC::unpend(Uart0RxIrq);
        (UartRx { uart: CmsdkUart { base: self.base, rx_wakeup: false } }, UartTx { uart: self })
    }

    /// The received byte, if one is waiting.
    pub fn try_read_byte(&mut self) -> Option<u8> {
        if self.read_reg(STATE) & STATE_RX_FULL == 0 {
            return None;
        }
        let byte = self.read_reg(DATA) as u8;
        if self.rx_wakeup {
            // Re-arm the wake-up: clear the UART's and then the NVIC's pending RX
            // interrupt. A byte arriving after this pends it again.
            self.write_reg(INTCLEAR, INT_RX);
            NVIC::unpend(Uart0RxIrq);
        }
        Some(byte)
    }

    /// Waits for a byte (sleeping between checks after
    /// [`CmsdkUart::enable_rx_wakeup`]).
    pub fn read_byte(&mut self) -> u8 {
        loop {
            if let Some(b) = self.try_read_byte() {
                return b;
            }
            if self.rx_wakeup {
                // A byte that arrived since the check above has pended the interrupt,
                // so this returns at once: no lost wake-up.
                cortex_m::asm::wfi();
            }
        }
    }

    /// Waits until the transmit buffer is free, then sends `byte`.
    pub fn write_byte(&mut self, byte: u8) {
        while self.read_reg(STATE) & STATE_TX_FULL != 0 {}
        self.write_reg(DATA, u32::from(byte));
    }

    /// `true` if a received byte was lost since the last call (and clears the flag).
    pub fn take_rx_overrun(&mut self) -> bool {
        let overrun = self.read_reg(STATE) & STATE_RX_OVERRUN != 0;
        if overrun {
            self.write_reg(STATE, STATE_RX_OVERRUN);
        }
        overrun
    }

    fn read_reg(&self, offset: usize) -> u32 {
        let addr = (self.base + offset) as *const u32;
        // SAFETY: `base` is a CMSDK APB UART base from the AN386 memory map and `offset`
        // one of the register offsets above: a valid, aligned, 32-bit device register.
        // Volatile because the device changes it.
        unsafe { read_volatile(addr) }
    }

    fn write_reg(&mut self, offset: usize, value: u32) {
        let addr = (self.base + offset) as *mut u32;
        // SAFETY: as in `read_reg`; `&mut self` means this handle is the only writer
        // (UART0 is handed out once by `take_uart0`, or stolen by the panic handler).
        unsafe { write_volatile(addr, value) }
    }
}

impl embedded_io::ErrorType for CmsdkUart {
    type Error = Infallible;
}

impl embedded_io::Read for CmsdkUart {
    /// Blocks for the first byte, then takes whatever else is already waiting.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let Some((first, rest)) = buf.split_first_mut() else {
            return Ok(0);
        };
        *first = self.read_byte();
        let mut n = 1;
        for slot in rest {
            match self.try_read_byte() {
                Some(b) => {
                    *slot = b;
                    n += 1;
                }
                None => break,
            }
        }
        Ok(n)
    }
}

impl embedded_io::Write for CmsdkUart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        while self.read_reg(STATE) & STATE_TX_FULL != 0 {}
        Ok(())
    }
}

/// Unmasks the UART0 RX interrupt in the NVIC (after
/// [`CmsdkUart::into_interrupt_driven`], once its handler can run), and pends it once.
///
/// The pend is not optional: a byte that arrived after [`CmsdkUart::init`] enabled the
/// receiver but before the RX interrupt was enabled sits in the RX buffer without having
/// raised the interrupt (the CMSDK UART raises it on arrival only, as QEMU models it),
/// and the UART takes no further byte while its buffer is full. Nobody would ever read
/// it and the link would stall for good: a host that sends while the image boots hits
/// exactly this (it was a CI failure, "no answer to frame 0"). The handler drains the
/// buffer until it is empty, so a pend with nothing waiting costs one empty handler run.
pub fn unmask_uart0_rx() {
    // SAFETY: the critical sections of these images use PRIMASK
    // (`cortex_m::interrupt::free`), never the NVIC mask, so unmasking cannot break one.
    unsafe { NVIC::unmask(Uart0RxIrq) };
    NVIC::pend(Uart0RxIrq);
}

/// Masks an interrupt that has no handler (`irqn` from `DefaultHandler`), so that it
/// cannot fire again. Out-of-range numbers are ignored.
pub fn mask_irq(irqn: i16) {
    #[derive(Clone, Copy)]
    struct Irq(u16);
    // SAFETY: only numbers 0..240 are built below, the external interrupt lines of an
    // ARMv7-M NVIC.
    unsafe impl InterruptNumber for Irq {
        fn number(self) -> u16 {
            self.0
        }
    }
    if let Ok(n) = u16::try_from(irqn)
        && n < 240
    {
        NVIC::mask(Irq(n));
    }
}

/// The receiving half of an interrupt-driven UART (see
/// [`CmsdkUart::into_interrupt_driven`]).
pub struct UartRx {
    uart: CmsdkUart,
}

impl UartRx {
    /// The received byte, if one is waiting; acknowledges the RX interrupt when it
    /// takes a byte (a byte arriving later raises it again).
    pub fn try_read_byte(&mut self) -> Option<u8> {
        let byte = self.uart.try_read_byte()?;
        self.uart.write_reg(INTCLEAR, INT_RX);
        Some(byte)
    }

    /// `true` if a received byte was lost since the last call (and clears the flag).
    pub fn take_rx_overrun(&mut self) -> bool {
        self.uart.take_rx_overrun()
    }
}

/// The transmitting half of an interrupt-driven UART (polled writes).
pub struct UartTx {
    uart: CmsdkUart,
}

impl UartTx {
    /// `true` when the transmit buffer can take a byte now.
    pub fn can_write(&self) -> bool {
        self.uart.read_reg(STATE) & STATE_TX_FULL == 0
    }

    /// Waits until the transmit buffer is free, then sends `byte`.
    pub fn write_byte(&mut self, byte: u8) {
        self.uart.write_byte(byte);
    }
}

impl embedded_io::ErrorType for UartTx {
    type Error = Infallible;
}

impl embedded_io::Write for UartTx {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.uart.write(buf)
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        embedded_io::Write::flush(&mut self.uart)
    }
}

/// An image that cannot run (an initialisation that cannot complete): `HALT: <why>` on
/// UART0, then as [`stop_with`]. Nothing is switched on yet when `main` calls it.
pub fn halt(why: &str) -> ! {
    stop_with(&["HALT: ", why])
}

/// Stops the image for good: masks every interrupt (the control step lives in one, so it
/// never runs again: no answer goes out and the drive's bridge flag is never set again),
/// prints the pieces of `what` on UART0 as one line and sleeps. For [`halt`] and the
/// HardFault ([`mps2_fault_handlers!`](crate::mps2_fault_handlers)). Pieces, not
/// `format_args!`: formatting would link core::fmt (3 to 5 KB of flash) into every image.
pub fn stop_with(what: &[&str]) -> ! {
    let mut uart = stop_uart();
    for part in [&["\r\n"], what, &["\r\n"]].into_iter().flatten() {
        let _ = embedded_io::Write::write_all(&mut uart, part.as_bytes());
    }
    sleep_forever()
}

/// [`stop_with`] for a formatted message: the panic handler's (not linked while nothing
/// can panic, `.ci/no-panic`).
pub fn stop(what: core::fmt::Arguments<'_>) -> ! {
    let mut uart = stop_uart();
    let _ = embedded_io::Write::write_fmt(&mut uart, format_args!("\r\n{what}\r\n"));
    sleep_forever()
}

/// Masks every interrupt and takes UART0 for a last message.
fn stop_uart() -> CmsdkUart {
    cortex_m::interrupt::disable();
    // SAFETY: interrupts are off and the callers never return, so no other user of UART0
    // runs again; a byte the thread was writing is at worst cut short.
    unsafe { CmsdkUart::steal_uart0() }
}

fn sleep_forever() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// The command line QEMU gives the image through ARM semihosting `SYS_GET_CMDLINE`
/// (QEMU runs with `-semihosting-config enable=on`; with `-kernel ELF -append LINE` it
/// is `ELF LINE`), copied into `buf`; `None` when the call fails, e.g. when the line
/// does not fit. Call it at start-up only: QEMU stops the core for the call. Only for
/// QEMU (a core without a debugger takes the breakpoint as a HardFault).
pub fn semihosting_cmdline(buf: &mut [u8]) -> Option<&[u8]> {
    const SYS_GET_CMDLINE: usize = 0x15;
    // The parameter block: the buffer's address and its length (in), the length of the
    // line without its terminating NUL (out).
    let mut block: [usize; 2] = [buf.as_mut_ptr() as usize, buf.len()];
    let status: isize;
    // SAFETY: a semihosting call (`bkpt 0xab`, operation in r0, the parameter block's
    // address in r1, the result in r0). QEMU writes at most `block[1]` bytes into `buf`,
    // which is exclusively borrowed and that long, and the new length into `block`, a
    // live local; nothing else in memory is touched.
    unsafe {
        core::arch::asm!(
            "bkpt #0xab",
            inout("r0") SYS_GET_CMDLINE => status,
            in("r1") block.as_mut_ptr(),
            options(nostack)
        );
    }
    if status != 0 {
        return None;
    }
    let len = block.get(1).copied().unwrap_or(0);
    buf.get(..len)
}

/// The host's clock, read through ARM semihosting `SYS_ELAPSED` and `SYS_TICKFREQ` (QEMU: the
/// host's monotonic clock in ns since QEMU started). On QEMU the drive image's own time
/// follows the instructions it executes (`-icount`, `dcfo_host::qemu`), faster or slower than
/// the host's; its command watchdog wants a silence in both clocks, and reads the host's
/// here. One semihosting call per reading (a trap into QEMU, no guest instructions). Only
/// for QEMU (a core without a debugger takes the breakpoint as a HardFault).
#[derive(Clone, Copy, Debug)]
pub struct HostClock {
    ticks_per_ms: core::num::NonZeroU64,
}

impl HostClock {
    /// The clock, `None` if the host does not give its tick rate (semihosting off, or a
    /// rate under 1 kHz).
    pub fn new() -> Option<Self> {
        const SYS_TICKFREQ: usize = 0x31;
        let hz: isize;
        // SAFETY: a semihosting call (`bkpt 0xab`, operation in r0, r1 = 0: no parameter
        // block), the tick rate or -1 in r0; nothing in memory is read or written.
        unsafe {
            core::arch::asm!(
                "bkpt #0xab",
                inout("r0") SYS_TICKFREQ => hz,
                in("r1") 0usize,
                options(nostack)
            );
        }
        let hz = u64::try_from(hz).ok()?;
        Some(HostClock { ticks_per_ms: core::num::NonZeroU64::new(hz / 1000)? })
    }

    /// Milliseconds since QEMU started (wrapping after 49 days), `None` if the call fails.
    pub fn now_ms(&self) -> Option<u32> {
        const SYS_ELAPSED: usize = 0x30;
        // The parameter block: the 64-bit tick count, low word first (out).
        let mut block: [u32; 2] = [0; 2];
        let status: isize;
        // SAFETY: a semihosting call (`bkpt 0xab`, operation in r0, the parameter block's
        // address in r1, the status in r0). QEMU writes the two words of `block`, a live
        // local that long; nothing else in memory is touched.
        unsafe {
            core::arch::asm!(
                "bkpt #0xab",
                inout("r0") SYS_ELAPSED => status,
                in("r1") block.as_mut_ptr(),
                options(nostack)
            );
        }
        if status != 0 {
            return None;
        }
        let ticks = u64::from(block[0]) | (u64::from(block[1]) << 32);
        // Truncation to u32 is the wrap-around: the watchdogs subtract with wrapping.
        Some((ticks / self.ticks_per_ms) as u32)
    }
}

/// Ends the QEMU run through ARM semihosting `SYS_EXIT` (QEMU runs with
/// `-semihosting-config enable=on`): QEMU exits with status 0 when `ok`, 1 otherwise. For
/// the test images (`stack_guard`, `bench`); should no debugger or QEMU take the call, the
/// core sleeps for good.
pub fn semihosting_exit(ok: bool) -> ! {
    const SYS_EXIT: usize = 0x18;
    const ADP_STOPPED_APPLICATION_EXIT: usize = 0x2_0026;
    const ADP_STOPPED_RUNTIME_ERROR: usize = 0x2_0023;
    let reason = if ok { ADP_STOPPED_APPLICATION_EXIT } else { ADP_STOPPED_RUNTIME_ERROR };
    // SAFETY: a semihosting call (`bkpt 0xab`, operation in r0, argument in r1): SYS_EXIT
    // with the reason code in r1, a value; nothing in memory is read or written.
    unsafe {
        core::arch::asm!("bkpt #0xab", in("r0") SYS_EXIT, in("r1") reason, options(nostack));
    }
    loop {
        cortex_m::asm::wfi();
    }
}

/// Defines the fault exits of an MPS2 image that talks on UART0, the same in every such
/// image: `HardFault` (a stack overflow among others) on a fresh stack
/// ([`crate::hard_fault_entry!`]) prints `HARDFAULT`, and the panic handler (not linked
/// while nothing can panic, `.ci/no-panic`; kept so that a panic that creeps in still
/// stops the control step first) prints `PANIC: <message>`; through
/// [`stop_with`](crate::board::mps2::stop_with) and [`stop`](crate::board::mps2::stop). Expand once, at the image's top level; the
/// image's `DefaultHandler` is its own (it dispatches its interrupts).
#[macro_export]
macro_rules! mps2_fault_handlers {
    () => {
        /// HardFault (a stack overflow among others), on a fresh stack: stops the core.
        extern "C" fn on_hard_fault() -> ! {
            $crate::board::mps2::stop_with(&["HARDFAULT"])
        }

        $crate::hard_fault_entry!(on_hard_fault);

        /// Not linked while nothing can panic (`.ci/no-panic`).
        #[panic_handler]
        fn panic(info: &core::panic::PanicInfo) -> ! {
            $crate::board::mps2::stop(format_args!("PANIC: {info}"))
        }
    };
}
