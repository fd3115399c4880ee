//! The stack: the HardFault entry every image uses, and painting for a high-water mark.
//!
//! The images link with flip-link (`.cargo/config.toml`): the stack sits at the bottom
//! of RAM, from `_stack_end` (the start of RAM) up to `_stack_start`, and `.data`/`.bss`
//! above it. A stack overflow therefore runs off the bottom of RAM and faults (a bus
//! error, taken as a HardFault) instead of overwriting statics.
//!
//! The HardFault handler then starts with the stack pointer below RAM: its first push
//! would fault again, inside the HardFault handler, and lock the core up — with a
//! drive's bridge as it was. [`hard_fault_entry!`] therefore defines the `HardFault`
//! vector as a naked function that first sets the stack pointer back to the top of the
//! stack, then branches to the image's handler, which never returns (what it overwrites
//! on the stack is never used again).
//!
//! That relies on a bus error below RAM, as on the STM32G431 (reserved addresses).
//! QEMU's MPS2 boards ignore writes there (an unimplemented region), so [`guard`] also
//! makes the lowest [`GUARD_BYTES`] of the stack inaccessible through the MPU: a stack
//! that reaches them faults on any board. They are not part of the usable stack.
//!
//! [`paint`] fills the free stack with [`PAINT`] at boot; the deepest word no longer
//! equal to it is the high-water mark ([`high_water_bytes`], or read from outside, as
//! the QEMU HIL test does through QEMU's monitor).

/// The pattern the free stack is painted with.
pub const PAINT: u32 = 0xA5C3_5A3C;

/// Bytes left unpainted below the caller's stack pointer (the painting loop's own use).
const PAINT_MARGIN: usize = 256;

/// Bytes at the bottom of the stack that [`guard`] forbids: a power of two, at least 32
/// (the MPU's smallest region), and larger than the images' largest frame so that no
/// frame steps over it without touching it.
pub const GUARD_BYTES: usize = 256;

unsafe extern "C" {
    /// The lowest address of the stack (cortex-m-rt's symbol; the start of RAM with
    /// flip-link).
    static _stack_end: u32;
    /// The initial stack pointer, the top of the stack (cortex-m-rt's symbol).
    static _stack_start: u32;
}

/// The usable stack's bounds `(lowest address, top)`: above the guard, below the
/// statics.
pub fn bounds() -> (usize, usize) {
    // Only the symbols' addresses are taken, never their contents.
    let end = core::ptr::addr_of!(_stack_end) as usize;
    (end + GUARD_BYTES, core::ptr::addr_of!(_stack_start) as usize)
}

/// Makes the lowest [`GUARD_BYTES`] of the stack inaccessible (MPU region 0: no access,
/// never executable; the default memory map everywhere else, and no MPU inside the
/// HardFault handler). A stack that grows into them raises a MemManage fault, taken as
/// a HardFault. Returns `false`, changing nothing, when the core has no MPU or the
/// stack's bottom is not aligned to the guard's size.
pub fn guard(mpu: &mut cortex_m::peripheral::MPU) -> bool {
    let end = core::ptr::addr_of!(_stack_end) as usize;
    let regions = (mpu._type.read() >> 8) & 0xFF;
    if regions == 0 || !end.is_multiple_of(GUARD_BYTES) {
        return false;
    }
    // RASR: XN (bit 28), AP = 0b000 no access (bits 24..26), SIZE = log2(bytes) - 1
    // (bits 1..5), ENABLE (bit 0). CTRL: PRIVDEFENA (bit 2), ENABLE (bit 0).
    const SIZE: u32 = GUARD_BYTES.trailing_zeros() - 1;
    const RASR: u32 = 1 << 28 | SIZE << 1 | 1;
    // SAFETY: region 0 covers only the guard, which holds no live data (below the
    // usable stack); every other address keeps the default map (PRIVDEFENA), so no
    // access of this program changes meaning. The barriers make it take effect before
    // the next access.
    unsafe {
        mpu.rnr.write(0);
        mpu.rbar.write(end as u32);
        mpu.rasr.write(RASR);
        mpu.ctrl.write(1 << 2 | 1);
    }
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
    true
}

/// Paints the usable stack from its lowest address up to [`PAINT_MARGIN`] bytes below the
/// current stack pointer with [`PAINT`]. Call it once at boot, before any interrupt is
/// enabled; its time is linear in the stack's size (a few ms for the 4 MiB of QEMU's
/// MPS2, where the stack is all the RAM that the statics leave).
#[inline(never)]
pub fn paint() {
    let (bottom, _) = bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let top = sp.saturating_sub(PAINT_MARGIN) & !3;
    let mut a = bottom;
    while a < top {
        // SAFETY: `a` is word-aligned (cortex-m-rt aligns `_stack_end` to 4) and lies in
        // the stack's region below every live frame (the margin covers this function's
        // own use, which is a leaf); nothing else lives there.
        unsafe { core::ptr::write_volatile(a as *mut u32, PAINT) };
        a += 4;
    }
}

/// Deepest stack use since [`paint`], in bytes below the top: the painted region is
/// scanned from the bottom to the first word no longer equal to [`PAINT`]. Time is
/// linear in the unused stack.
pub fn high_water_bytes() -> usize {
    let (bottom, top) = bounds();
    let mut a = bottom;
    while a < top {
        // SAFETY: word-aligned addresses inside the stack region, read only.
        if unsafe { core::ptr::read_volatile(a as *const u32) } != PAINT {
            break;
        }
        a += 4;
    }
    top - a
}

/// Defines the `HardFault` vector: the stack pointer back to the top of the stack
/// (`_stack_start`), then a branch to `$handler`, an `extern "C" fn() -> !` of the
/// image. See the [module documentation](self) for why.
#[macro_export]
macro_rules! hard_fault_entry {
    ($handler:path) => {
        /// HardFault: MSP to the top of the stack first (after a stack overflow it
        /// points below RAM), then the image's handler, which never returns.
        // SAFETY: naked, so nothing touches the stack before MSP is valid again; the
        // handler never returns, so the frames it overwrites are never used again.
        #[unsafe(naked)]
        #[unsafe(no_mangle)]
        unsafe extern "C" fn HardFault() -> ! {
            core::arch::naked_asm!(
                "movw r0, :lower16:_stack_start",
                "movt r0, :upper16:_stack_start",
                "msr msp, r0",
                "b {handler}",
                handler = sym $handler,
            )
        }
    };
}
