//! The motor image in the last flash page (`dcfo motor-image`).

// =================================================================================================
// Motor image — the last flash page (RM0440 §3.3.1: 64 pages of 2 KiB on category 2 devices),
// reserved by `firmware/memory/stm32g431cb.x`, written with `dcfo motor-image` + probe-rs.
// =================================================================================================

/// Flash address of the motor image page (page 63).
pub const MOTOR_IMAGE_ADDR: usize = 0x0801_F800;

/// The motor image as stored in flash, validated ([`dcfo::motor_image::MotorImage::decode`]):
/// an erased page, a corrupted record or unphysical values are an error, never a motor.
pub fn motor_image() -> Result<dcfo::motor_image::MotorImage, dcfo::motor_image::MotorImageError> {
    let ptr = MOTOR_IMAGE_ADDR as *const [u8; dcfo::motor_image::MotorImage::LEN];
    // SAFETY: MOTOR_IMAGE_ADDR is inside the STM32G431CB's 128 KiB of flash (RM0440
    // §2.2), always mapped and readable; the linker script keeps the firmware out of that
    // page, nothing in this firmware writes flash, and a byte array needs no alignment.
    // A plain read (a copy): the debug probe writes the page only with the core halted
    // and resets it after, so it cannot change while this program runs. (A volatile read
    // of the array was 88 single-byte loads and stores unrolled: 1.8 KB of flash.)
    let bytes = unsafe { core::ptr::read(ptr) };
    dcfo::motor_image::MotorImage::decode(&bytes)
}
