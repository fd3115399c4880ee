//! The status LED on PC6: [`StatusLed`] (`embedded_hal::digital::OutputPin`).

use core::convert::Infallible;

use stm32g4::stm32g431 as pac;

use super::pins::PIN_LED;

// =================================================================================================
// Status LED — PC6 push-pull output, set/reset through GPIOC_BSRR (atomic).
// =================================================================================================

/// Green user LED LD2 on PC6 ("high" = LED on, polarity assumed).
pub struct StatusLed {
    gpioc: pac::GPIOC,
}

impl StatusLed {
    pub(super) fn new(gpioc: pac::GPIOC) -> Self {
        let n = PIN_LED.pin;
        gpioc.bsrr().write(|w| w.br(n).set_bit());
        gpioc.otyper().modify(|_, w| w.ot(n).clear_bit());
        gpioc.moder().modify(|_, w| w.moder(n).output());
        Self { gpioc }
    }

    /// Inverts the LED.
    pub fn toggle(&mut self) {
        let n = PIN_LED.pin;
        if self.gpioc.odr().read().odr(n).bit_is_set() {
            self.gpioc.bsrr().write(|w| w.br(n).set_bit());
        } else {
            self.gpioc.bsrr().write(|w| w.bs(n).set_bit());
        }
    }
}

impl embedded_hal::digital::ErrorType for StatusLed {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for StatusLed {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        self.gpioc.bsrr().write(|w| w.br(PIN_LED.pin).set_bit());
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Self::Error> {
        self.gpioc.bsrr().write(|w| w.bs(PIN_LED.pin).set_bit());
        Ok(())
    }
}

impl embedded_hal::digital::StatefulOutputPin for StatusLed {
    fn is_set_high(&mut self) -> Result<bool, Self::Error> {
        Ok(self.gpioc.odr().read().odr(PIN_LED.pin).bit_is_set())
    }

    fn is_set_low(&mut self) -> Result<bool, Self::Error> {
        Ok(self.gpioc.odr().read().odr(PIN_LED.pin).bit_is_clear())
    }
}
