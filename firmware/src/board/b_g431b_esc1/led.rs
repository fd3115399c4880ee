//! The status LED on PC6: [`StatusLed`] (`embedded_hal::digital::OutputPin`).

use core::convert::Infallible;

use stm32g4::stm32g431 as pac;

use super::pins::PIN_LED;
use crate::board::esc1_settings::{LedPolarity, led_bsrr, led_lit};

// =================================================================================================
// Status LED — PC6 push-pull output, set/reset through GPIOC_BSRR (atomic).
// =================================================================================================

/// The status LED on PC6 (the board's red "D4"), with its polarity
/// ([`Esc1Config::led_polarity`](super::Esc1Config::led_polarity), by default
/// [`STATUS_LED_POLARITY`](super::STATUS_LED_POLARITY)). It is the LED, not the pin: "high"
/// in its `OutputPin` is lit, whatever the pin level that takes.
pub struct StatusLed {
    gpioc: pac::GPIOC,
    polarity: LedPolarity,
}

impl StatusLed {
    /// PC6 as a push-pull output with the LED dark: the dark level is latched before the pin
    /// leaves its reset state (analog), so it never flashes.
    pub(super) fn new(gpioc: pac::GPIOC, polarity: LedPolarity) -> Self {
        let n = PIN_LED.pin;
        let led = Self { gpioc, polarity };
        led.set_lit(false);
        led.gpioc.otyper().modify(|_, w| w.ot(n).clear_bit());
        led.gpioc.moder().modify(|_, w| w.moder(n).output());
        led
    }

    /// Lights the LED or darkens it (one GPIOC_BSRR write, [`led_bsrr`]).
    pub fn set_lit(&self, lit: bool) {
        let word = led_bsrr(lit, self.polarity, PIN_LED.pin);
        // SAFETY: BSRR is write-only set/reset bits of port C; the word has exactly one bit
        // set, PC6's BS6 or BR6, so no other pin of the port changes.
        self.gpioc.bsrr().write(|w| unsafe { w.bits(word) });
    }

    /// Whether the LED is lit (from the pin's output latch, GPIOC_ODR).
    pub fn is_lit(&self) -> bool {
        led_lit(self.gpioc.odr().read().odr(PIN_LED.pin).bit_is_set(), self.polarity)
    }

    /// Inverts the LED.
    pub fn toggle(&mut self) {
        self.set_lit(!self.is_lit());
    }
}

impl embedded_hal::digital::ErrorType for StatusLed {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for StatusLed {
    /// Darkens the LED.
    fn set_low(&mut self) -> Result<(), Self::Error> {
        self.set_lit(false);
        Ok(())
    }

    /// Lights the LED.
    fn set_high(&mut self) -> Result<(), Self::Error> {
        self.set_lit(true);
        Ok(())
    }
}

impl embedded_hal::digital::StatefulOutputPin for StatusLed {
    fn is_set_high(&mut self) -> Result<bool, Self::Error> {
        Ok(self.is_lit())
    }

    fn is_set_low(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.is_lit())
    }
}
