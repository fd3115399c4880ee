//! The safe state from anywhere (panic, faults, an interrupt that cannot reach its state):
//! bridge off without the power stage's handle, the images' fault vectors and the panic
//! handler.

use stm32g4::stm32g431 as pac;

// =================================================================================================
// Safe state from anywhere: panic, faults, an interrupt that cannot reach its state.
// =================================================================================================

/// Switches the bridge off without the [`Esc1PowerStage`](super::Esc1PowerStage) handle: clears TIM1 `BDTR.MOE`,
/// which with `OSSI = 1` drives all six gate inputs to their idle level (low, every
/// switch off) at once (RM0440 §28.3.16). For the panic handler, the fault handlers and
/// an interrupt that cannot reach its state; no allocation, a single register
/// read-modify-write. Before [`init`](super::init) has enabled TIM1's clock the write is ignored and
/// the gate pins are not yet connected to the timer, so the bridge is off anyway.
///
/// The owner of the bridge may set MOE again from an interrupt: call this with
/// interrupts masked, or again after masking them (as [`safe_state_and_stop`] does).
pub fn force_bridge_off() {
    // SAFETY: one read-modify-write of TIM1_BDTR, which only clears MOE (the safe
    // state). Taking the register block without its owner is sound for this: a
    // concurrent read-modify-write by the owner can at worst set MOE again, which the
    // callers cover by masking interrupts and clearing it once more.
    let tim1 = unsafe { &*pac::TIM1::ptr() };
    tim1.bdtr().modify(|_, w| w.moe().clear_bit());
}

/// Bridge off, interrupts masked, bridge off again (an interrupt between the first
/// write and the mask may have set MOE). After this nothing switches the bridge on.
pub fn safe_state_and_stop() {
    force_bridge_off();
    cortex_m::interrupt::disable();
    force_bridge_off();
}

/// Defines an ESC1 image's fault vectors, the same in every image: `HardFault` (a stack
/// overflow among others) on a fresh stack ([`crate::hard_fault_entry`]) and
/// `DefaultHandler` (an interrupt enabled without a handler, the NMI), each switching
/// the bridge off first ([`safe_state_and_stop`]) and then stopping. cortex-m-rt's own
/// default handler would spin at the interrupt's priority, possibly the control
/// interrupt's, with the bridge on. Expand once, at the image's top level.
#[macro_export]
macro_rules! esc1_fault_handlers {
    () => {
        /// HardFault, on a fresh stack: bridge off first, then stop.
        extern "C" fn on_hard_fault() -> ! {
            $crate::board::b_g431b_esc1::safe_state_and_stop();
            loop {
                cortex_m::asm::wfi();
            }
        }

        $crate::hard_fault_entry!(on_hard_fault);

        // SAFETY: cortex-m-rt requires the default handler to be declared `unsafe`; it
        // only switches the bridge off and stops.
        #[cortex_m_rt::exception]
        unsafe fn DefaultHandler(_irqn: i16) {
            $crate::board::b_g431b_esc1::safe_state_and_stop();
            loop {
                cortex_m::asm::wfi();
            }
        }
    };
}

/// Not linked while nothing in the images can panic (`.ci/no-panic` checks it); kept so
/// that a panic that creeps in switches the bridge off before anything else. Then it
/// logs the message over defmt (the logger drops it rather than wait or panic) and
/// raises a HardFault with `udf`, as panic-probe did: `probe-rs run` stops there and
/// shows the backtrace; without a probe the images' HardFault handler keeps the bridge
/// off and stops. (Replaces panic-probe, which logs first and never touches the bridge.)
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    safe_state_and_stop();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    cortex_m::asm::udf()
}

/// An image that cannot run before its control interrupt is on (an initialisation that
/// cannot complete, e.g. [`init`](super::init)'s [`Esc1InitError`](super::Esc1InitError),
/// logged by its derived `defmt::Format`, variant and fields, without `core::fmt`): bridge
/// off ([`safe_state_and_stop`]; it was never switched on), the reason over defmt, then
/// sleep for good.
pub fn stop(why: impl defmt::Format) -> ! {
    safe_state_and_stop();
    defmt::error!("cannot run: {}", why);
    loop {
        cortex_m::asm::wfi();
    }
}
