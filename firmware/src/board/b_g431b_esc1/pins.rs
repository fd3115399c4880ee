//! The board's pins (the board table in the module docs of [`super`]) and their GPIO
//! set-up: analog inputs and the six gate pins handed to TIM1.

use stm32g4::stm32g431 as pac;

/// Port letter / pin number / alternate function of one pin (AF is 0 for analog / GPIO pins).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PinDef {
    /// GPIO port letter (b'A', b'B', b'C').
    pub port: u8,
    /// Pin number 0..=15.
    pub pin: u8,
    /// Alternate-function number (RM0440 GPIOx_AFRL/AFRH), 0 when unused.
    pub af: u8,
}

const fn pin(port: u8, pin: u8, af: u8) -> PinDef {
    PinDef { port, pin, af }
}

/// TIM1_CH1 -> phase U high-side gate input (PA8, AF6). UM2516 Table 4.
pub const PIN_U_HIGH: PinDef = pin(b'A', 8, 6);
/// TIM1_CH1N -> phase U low-side gate input (PC13, AF4). UM2516 Table 4.
pub const PIN_U_LOW: PinDef = pin(b'C', 13, 4);
/// TIM1_CH2 -> phase V high-side gate input (PA9, AF6). UM2516 Table 4.
pub const PIN_V_HIGH: PinDef = pin(b'A', 9, 6);
/// TIM1_CH2N -> phase V low-side gate input (PA12, AF6). UM2516 Table 4.
pub const PIN_V_LOW: PinDef = pin(b'A', 12, 6);
/// TIM1_CH3 -> phase W high-side gate input (PA10, AF6). UM2516 Table 4.
pub const PIN_W_HIGH: PinDef = pin(b'A', 10, 6);
/// TIM1_CH3N -> phase W low-side gate input (PB15, AF4). UM2516 Table 4.
pub const PIN_W_LOW: PinDef = pin(b'B', 15, 4);
/// OPAMP1 non-inverting input VINP0 = shunt U "+" (PA1, analog).
pub const PIN_OPAMP1_VINP: PinDef = pin(b'A', 1, 0);
/// OPAMP1 inverting input VINM0 = shunt U "-" / bias network (PA3, analog).
pub const PIN_OPAMP1_VINM: PinDef = pin(b'A', 3, 0);
/// OPAMP2 non-inverting input VINP0 = shunt V "+" (PA7, analog).
pub const PIN_OPAMP2_VINP: PinDef = pin(b'A', 7, 0);
/// OPAMP2 inverting input VINM0 = shunt V "-" / bias network (PA5, analog).
pub const PIN_OPAMP2_VINM: PinDef = pin(b'A', 5, 0);
/// OPAMP3 non-inverting input VINP0 = shunt W "+" (PB0, analog).
pub const PIN_OPAMP3_VINP: PinDef = pin(b'B', 0, 0);
/// OPAMP3 inverting input VINM0 = shunt W "-" / bias network (PB2, analog).
pub const PIN_OPAMP3_VINM: PinDef = pin(b'B', 2, 0);
/// DC-bus divider output, ADC1_IN1 (PA0, analog).
pub const PIN_VBUS: PinDef = pin(b'A', 0, 0);
/// USART2_TX to the ST-LINK virtual COM port (PB3, AF7).
pub const PIN_UART_TX: PinDef = pin(b'B', 3, 7);
/// USART2_RX from the ST-LINK virtual COM port (PB4, AF7).
pub const PIN_UART_RX: PinDef = pin(b'B', 4, 7);
/// Status LED (PC6, push-pull output): UM2516 Table 4 via the pinout extract ("PC6 STATUS
/// LED"); red ("D4 LED RED STATUS" in Zephyr's board file, `LED_RED` in ST's Arduino variant).
/// Its polarity is a setting, [`Esc1Config::led_polarity`](super::Esc1Config::led_polarity):
/// the sources disagree (see [`STATUS_LED_POLARITY`](super::STATUS_LED_POLARITY)).
pub const PIN_LED: PinDef = pin(b'C', 6, 0);

// =================================================================================================
// GPIO — RM0440 ch. 9 "General-purpose I/Os (GPIO)": MODER, OTYPER, OSPEEDR, PUPDR, AFRL/AFRH.
// =================================================================================================

/// Puts `$pin` of `$port` into alternate function `$af`, push-pull, with output speed
/// `$speed` (OSPEEDR code: 0 low .. 3 very high).
macro_rules! pin_af {
    ($port:expr, $p:expr, $speed:expr) => {{
        let n: u8 = $p.pin;
        let af: u8 = $p.af;
        $port.ospeedr().modify(|_, w| w.ospeedr(n).set($speed));
        $port.otyper().modify(|_, w| w.ot(n).clear_bit());
        if n < 8 {
            $port.afrl().modify(|_, w| w.afr(n).set(af));
        } else {
            $port.afrh().modify(|_, w| w.afr(n - 8).set(af));
        }
        $port.moder().modify(|_, w| w.moder(n).alternate());
    }};
}

/// Puts `$pin` of `$port` into analog mode (no pull), as needed by OPAMP/ADC inputs.
macro_rules! pin_analog {
    ($port:expr, $p:expr) => {{
        let n: u8 = $p.pin;
        $port.pupdr().modify(|_, w| w.pupdr(n).floating());
        $port.moder().modify(|_, w| w.moder(n).analog());
    }};
}

pub(super) fn init_analog_pins(gpioa: &pac::GPIOA, gpiob: &pac::GPIOB) {
    // Most pins already reset to analog on the G4 (RM0440 GPIOx_MODER reset values); explicit anyway.
    pin_analog!(gpioa, PIN_OPAMP1_VINP);
    pin_analog!(gpioa, PIN_OPAMP1_VINM);
    pin_analog!(gpioa, PIN_OPAMP2_VINP);
    pin_analog!(gpioa, PIN_OPAMP2_VINM);
    pin_analog!(gpiob, PIN_OPAMP3_VINP);
    pin_analog!(gpiob, PIN_OPAMP3_VINM);
    pin_analog!(gpioa, PIN_VBUS);
}

/// Output speed of the gate pins: "high" (OSPEEDR 2), as ST's MCSDK project for this board
/// (HAL_TIM_MspPostInit: GPIO_SPEED_FREQ_HIGH).
const GATE_PIN_SPEED: u8 = 2;

/// Hands the six gate pins to TIM1. Each gets its pull-down first (MCSDK: GPIO_PULLDOWN on all
/// six), so that from the moment it leaves analog mode (where pulls are off) a pin that TIM1
/// does not drive still reads low at the gate driver; TIM1 itself drives them low (MOE = 0,
/// OSSI = 1, OISx = OISxN = 0) before this is called.
pub(super) fn init_pwm_pins(gpioa: &pac::GPIOA, gpiob: &pac::GPIOB, gpioc: &pac::GPIOC) {
    for p in [PIN_U_HIGH, PIN_V_HIGH, PIN_V_LOW, PIN_W_HIGH] {
        gpioa.pupdr().modify(|_, w| w.pupdr(p.pin).pull_down());
        pin_af!(gpioa, p, GATE_PIN_SPEED);
    }
    // PC13 sits behind the backup-domain power switch (DS12589 limits it to 2 MHz and 30 pF
    // as an output); a 10 kHz signal into a driver input is inside that, and ST's project
    // drives TIM1_CH1N on it the same way.
    gpioc.pupdr().modify(|_, w| w.pupdr(PIN_U_LOW.pin).pull_down());
    pin_af!(gpioc, PIN_U_LOW, GATE_PIN_SPEED);
    gpiob.pupdr().modify(|_, w| w.pupdr(PIN_W_LOW.pin).pull_down());
    pin_af!(gpiob, PIN_W_LOW, GATE_PIN_SPEED);
}
