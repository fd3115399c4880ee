//! Board support for the ST **B-G431B-ESC1** (MCU STM32G431CBU6), written directly on the
//! `stm32g4` PAC (no HAL).
//!
//! What [`init`] brings up, in this order (a configuration or a measurement it cannot accept
//! ends it with an [`Esc1InitError`] naming why, the bridge off: see the last paragraph):
//! * the configuration checked first: a dead time below [`DEAD_TIME_FLOOR_NS`] (or beyond
//!   what TIM1 encodes) is refused before anything is touched;
//! * TIM1 frozen while the core is halted by a debugger (DBGMCU), which also forces its
//!   outputs off: a breakpoint or a probe halt leaves the bridge off, not switching at the
//!   last duties;
//! * SYSCLK = HCLK = PCLK1 = PCLK2 = 170 MHz from the PLL (HSI16 by default, or the board's
//!   8 MHz HSE, then with the clock security system on), Range-1 boost mode and 4 flash wait
//!   states; the Cortex-M4 LOCKUP output wired to TIM1's break (a locked-up core cannot leave
//!   the bridge on); the UCPD dead-battery pull-down released from PB4 (USART2 RX);
//! * OPAMP1/2/3 in PGA mode (gain 16, VINM0 bias) on the three low-side shunts, read internally
//!   by ADC1/ADC2 as an injected group triggered by TIM1 TRGO2, plus the DC-bus divider on PA0;
//! * the hardware over-current trip: COMP1/2/4 compare the three shunt inputs with DAC3 and
//!   drive TIM1's break input, which clears MOE in hardware; the power stage latches it
//!   ([`PowerStage::hardware_trip`](crate::board::PowerStage::hardware_trip)). The threshold
//!   is set from what the board measures: with no current flowing, DAC3 sweeps up until each
//!   comparator switches ([`measure_zero_current_codes`]), and the trip current's share sits
//!   on top of that level ([`over_current_thresholds`]); the ADCs read the same three nodes as
//!   a second opinion ([`Esc1::shunt_inputs_adc_v`], for the log and the first power-up
//!   checklist);
//! * TIM1: centre-aligned complementary PWM on the board's six gate-driver inputs, dead time,
//!   preloaded CCR1..3, break enabled, MOE clear, started with one update event (and
//!   TRGO/TRGO2) per carrier period at the valley — confirmed on several update events
//!   ([`align_update_to_valley`]) and on the end of the current conversions, or
//!   initialisation fails; only then are the six gate pins handed to TIM1 (until then they are
//!   in their reset state, analog / Hi-Z, and the gate driver's input pull-downs hold them
//!   low);
//! * USART2 on the ST-LINK virtual COM port (PB3/PB4), 8N1;
//! * the red status LED on PC6, dark, with the configured polarity
//!   ([`Esc1Config::led_polarity`]).
//!
//! When [`init`] fails, the gate pins have not left their reset state and TIM1's main output
//! is off: the bridge cannot switch; the image says why and stops.
//!
//! The control interrupt is [`CONTROL_IRQ`] (`ADC1_2`, end of the injected sequence of ADC1).
//!
//! One file per peripheral (everything is re-exported here, so the paths are
//! `b_g431b_esc1::*`): this file has the board table, [`Esc1Config`] and [`init`];
//! `clocks` (PLL, flash wait states, peripheral clocks), `pins` (the pin table and GPIO
//! set-up), `pwm` (TIM1, [`Esc1PowerStage`]), `adc` (op-amps, ADCs, [`Esc1Sensors`]),
//! `over_current` (DAC3 and COMP1/2/4 on TIM1's break), `uart` ([`Esc1Uart`]), `led`
//! ([`StatusLed`]), `safe_state` (bridge off from anywhere, the fault vectors, the panic
//! handler) and `motor_image` (the motor image in the last flash page). What a new board
//! implements: `docs/new-board.md`.
//!
//! Reference numbering used below: UM2516 = "B-G431B-ESC1 Discovery kit" user manual,
//! RM0440 = STM32G4 reference manual, DS12589 = STM32G431xx datasheet, MCSDK = the ST Motor
//! Control SDK project generated for this board ("ElectronicSpeedControl_ESC-G4", MCSDK 6.x:
//! its `main.c`, `mc_parameters.c`, `power_stage_parameters.h`; public copies e.g.
//! github.com/kennethsauers/B-G431B-ESC1), L6387E = the gate driver's datasheet (DocID13990).
//! Section numbers of RM0440 are given as chapter titles plus the number as recalled for RM0440
//! rev 7/8 and are not verified; register and bit names are (they are the PAC's, generated from
//! ST's SVD). The facts are collected, with their sources, in the board table below.

mod adc;
mod clocks;
mod led;
mod motor_image;
mod over_current;
#[macro_use]
mod pins;
mod pwm;
mod safe_state;
mod uart;

pub use crate::board::esc1_settings::*;
pub use adc::*;
pub use clocks::*;
pub use led::*;
pub use motor_image::*;
use over_current::*;
pub use pins::*;
pub use pwm::*;
pub use safe_state::*;
pub use uart::*;

use stm32g4::stm32g431 as pac;

// =================================================================================================
// BOARD TABLE: every pin and peripheral choice in one place.
// =================================================================================================
//
// | Function            | MCU resource          | Pin  | AF  | Source                                              |
// |---------------------|-----------------------|------|-----|-----------------------------------------------------|
// | Phase U high (HIN)  | TIM1_CH1              | PA8  | 6   | UM2516 Table 4 (via NuttX README, pat92fr CubeMX)   |
// | Phase U low  (LIN)  | TIM1_CH1N             | PC13 | 4   | idem; AF from ST Arduino PeripheralPins_B_G431B_ESC1 |
// | Phase V high        | TIM1_CH2              | PA9  | 6   | idem                                                |
// | Phase V low         | TIM1_CH2N             | PA12 | 6   | idem                                                |
// | Phase W high        | TIM1_CH3              | PA10 | 6   | idem                                                |
// | Phase W low         | TIM1_CH3N             | PB15 | 4   | idem                                                |
// | Shunt U +  / -      | OPAMP1 VINP0 / VINM0  | PA1 / PA3 | analog | NuttX board README, SimpleFOC b_g431_hal      |
// | Shunt V +  / -      | OPAMP2 VINP0 / VINM0  | PA7 / PA5 | analog | idem                                           |
// | Shunt W +  / -      | OPAMP3 VINP0 / VINM0  | PB0 / PB2 | analog | idem                                           |
// | I_U (amplified)     | VOPAMP1 -> ADC1_IN13  | internal  |   | RM0440 ADC1/2 connectivity table; stm32g4xx-hal     |
// | I_V (amplified)     | VOPAMP2 -> ADC2_IN16  | internal  |   | idem                                                |
// | I_W (amplified)     | VOPAMP3 -> ADC2_IN18  | internal  |   | idem                                                |
// | V_BUS divider       | ADC1_IN1              | PA0  | analog | UM2516 Table 4 via NuttX README (18k / (18k+169k)) |
// | ST-LINK VCP TX      | USART2_TX             | PB3  | 7   | NuttX board.h/README; Arduino PeripheralPins        |
// | ST-LINK VCP RX      | USART2_RX             | PB4  | 7   | idem                                                |
// | Status LED (D4, red)| GPIO output           | PC6  | -   | Zephyr b_g431b_esc1.dts ("D4 LED RED STATUS", active low); ST Arduino variant (LED_RED PC6); NuttX ("User LD2: green", active high): polarity a setting |
// | Shunt inputs to ADC | ADC1_IN2 / ADC2_IN4 / ADC1_IN15 | PA1 / PA7 / PB0 | analog | NuttX board.h (ADC1_IN2 = PA1, ADC1_IN15 = PB0), NuttX G4 pin map (ADC2_IN4 = PA7) |
// | OCP threshold U     | DAC3_CH1 (internal)   | -    | -   | MCSDK main.c MX_DAC3_Init, mc_parameters.c (DAC_Channel_OCPA) |
// | OCP threshold V, W  | DAC3_CH2 (internal)   | -    | -   | idem (DAC_Channel_OCPB/OCPC: one channel for V and W) |
// | OCP comparator U    | COMP1: INP = PA1, INM = DAC3_CH1 | - | - | MCSDK MX_COMP1_Init (INPUT_PLUS_IO1, INPUT_MINUS_DAC3_CH1) |
// | OCP comparator V    | COMP2: INP = PA7, INM = DAC3_CH2 | - | - | MCSDK MX_COMP2_Init |
// | OCP comparator W    | COMP4: INP = PB0, INM = DAC3_CH2 | - | - | MCSDK MX_COMP4_Init |
// | OCP -> bridge off   | TIM1 BRK (not BRK2) from COMP1/2/4, active high, filter 3 | - | - | MCSDK MX_TIM1_Init (TIM_BREAKINPUT_BRK, POLARITY_HIGH, BreakFilter 3, BRK2 disabled) |
// | HSE                 | 8 MHz on PF0/PF1      | PF0/PF1 | - | UM2516 Table 4 ("OSC 8 MHz"); MCSDK SystemClock_Config (HSE on, PLLM /2, N 85, R /2) |
//
// Power stage and analog facts (used below):
// * Gate driver: three L6387E (NuttX README/stm32_foc.c: "L6387" / "L6387ED"), MOSFETs
//   STL180N6F7. L6387E inputs HIN/LIN are active high, with an interlock (both high = both
//   outputs off) and no dead time of its own (TIM1's is the only one: floor
//   `DEAD_TIME_FLOOR_NS`), V_il <= 1.5 V, and they sink 50-70 uA at 15 V (an input pull-down; L6387E
//   datasheet DocID13990 §5 Table 7 and the logic-input table). So: TIM1 polarity high on
//   CHx and CHxN (CCxP = CCxNP = 0, as NuttX requires and MCSDK sets), idle states low
//   (OISx = OISxN = 0, MCSDK: OCIdleState/OCNIdleState RESET), OSSI = OSSR = 1 (MCSDK), AOE = 0
//   (MCSDK). A gate pin left floating (reset state: analog, Hi-Z; none of the six is a debug
//   pin with a reset pull-up) reads low at the driver, i.e. switch off. The six pins: AF6
//   (PA8/9/10/12) and AF4 (PC13, PB15), push-pull, pull-down, speed "high" in MCSDK's
//   HAL_TIM_MspPostInit; the same here.
// * Current sense: shunt 3 mOhm per low-side leg (MCSDK RSHUNT 0.003; NuttX; SimpleFOC). The
//   net gain from shunt voltage to op-amp output is 9.14 V/V (MCSDK AMPLIFICATION_GAIN 9.14;
//   NuttX "-9.14 (inverted current)"; SimpleFOC -64/7): PGA gain 16 (PGA_GAIN 0b01011, VINM0 as
//   the resistor ground; MCSDK OPAMP_PGA_GAIN_16_OR_MINUS_15 with INVERTINGINPUT_IO0_BIAS;
//   NuttX) times 4/7 from the input network, so VINP = bias + (4/7) * V_shunt. V_shunt is
//   positive when current flows down through the low-side switch into ground, which is current
//   flowing *out of* the motor's phase: with "positive into the motor" the gain is -64/7. The
//   bias is not pinned down by the sources: resistor values worked out on the SimpleFOC forum
//   (thread "B-G431B-ESC1 Current Control": 1.5 kOhm in series, 2.2 kOhm to ground, 22 kOhm to
//   3.3 V) give 3.3 V * 3/77 = 0.1286 V, while the zero-current output measured there, ~1.65 V,
//   gives 0.103 V over the PGA's 16 with VINM0 at 0 V. Both the bias at the comparators (DAC3
//   sweep) and the zero-current output at the ADC (offset calibration) are measured at
//   start-up, never assumed, and checked against windows that hold both readings.
// * Bus divider 18 kOhm / (18 + 169) kOhm = 0.09626 (NuttX README; MCSDK
//   VBUS_PARTITIONING_FACTOR 0.0962556..., the same ratio): 34.3 V at the ADC's full scale.
//   Bus range: 3S-6S LiPo (UM2516 via the pinout extract: J5/J6), NuttX "Vbus max = 25V",
//   "Iout max = 40A peak".
// * Hardware over-current trip (MCSDK): COMPx compares the op-amp's *input* VINP (not its
//   output) with DAC3, so it sees current flowing down a low-side shunt (out of the motor's
//   phase, and every shoot-through or phase-to-phase short); current into the motor lowers
//   VINP and does not trip that leg's comparator (in a balanced three-phase load a large
//   current always flows out of some phase). A short from a phase to ground bypasses the
//   shunts and is not seen. MCSDK's DAC_OCP_Threshold for this board is 4083 (16-bit
//   left-aligned = 255 of 4095 = 0.2056 V): 45 A over the forum network's 0.1286 V bias, but
//   55 A over a 0.103 V one. Here the threshold is the measured bias plus the trip current's
//   share, 4/7 * 3 mOhm per ampere (2.13 DAC counts/A).
//
// Not used here (for the record): PB14 temperature NTC (ADC1_IN5), PB12 potentiometer
// (ADC1_IN11), PA15 PWM input, PB6/7/8 encoder/Hall, PC10 button, PA11/PB9 FDCAN1, PA4/PC4/PB11
// BEMF dividers and PB5 (BEMF enable), PA2/PA6/PB1 op-amp outputs (MCSDK reads OPAMP1/2 there;
// here all three are read internally).

/// Default UART baud rate (bit/s).
pub const DEFAULT_BAUD: u32 = 115_200;

// =================================================================================================
// Configuration
// =================================================================================================

/// PLL input clock choice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClockSource {
    /// Internal 16 MHz RC oscillator (always present). PLLM = /4.
    Hsi16,
    /// The board's 8 MHz HSE on PF0/PF1 (UM2516 Table 4, MCSDK), PLLM = /2. Falls back to
    /// HSI16 if the HSE does not become ready; once it runs, the clock security system is on:
    /// a failing HSE switches the clock to HSI16, breaks TIM1 (bridge off in hardware) and
    /// raises the NMI, which the images' default handler ends in with the bridge off.
    Hse8MHz,
}

/// Board configuration passed to [`init`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Esc1Config {
    /// PWM carrier frequency (Hz); clamped so that the TIM1 half-period fits 16 bits
    /// (about 1.3 kHz .. 850 kHz at 170 MHz).
    pub pwm_frequency_hz: u32,
    /// Dead time inserted between a leg's high- and low-side gate signals (ns):
    /// [`DEAD_TIME_FLOOR_NS`] to 5929 ns, anything else refused by [`init`]
    /// ([`dead_time_setting`]).
    pub dead_time_ns: u32,
    /// USART2 baud rate (bit/s), e.g. 115 200 or 921 600.
    pub baud: u32,
    /// PLL input clock.
    pub clock_source: ClockSource,
    /// Enable the USART2 RX-not-empty interrupt (vector [`UART_IRQ`]) at init.
    pub uart_rx_interrupt: bool,
    /// Hardware over-current trip (A, down any low-side shunt): DAC3 threshold of COMP1/2/4,
    /// which break TIM1. Clamped to [`OVER_CURRENT_TRIP_MIN_A`]..=[`OVER_CURRENT_TRIP_MAX_A`];
    /// can be lowered later with [`Esc1PowerStage::set_over_current_trip_a`]. Set above each
    /// comparator's zero-current level as measured at init ([`over_current_thresholds`]).
    pub over_current_trip_a: f32,
    /// Which pin level lights the status LED on PC6 ([`STATUS_LED_POLARITY`] unless the first
    /// power-up shows otherwise).
    pub led_polarity: LedPolarity,
}

impl Default for Esc1Config {
    fn default() -> Self {
        Self {
            pwm_frequency_hz: DEFAULT_PWM_HZ,
            dead_time_ns: DEFAULT_DEAD_TIME_NS,
            baud: DEFAULT_BAUD,
            clock_source: ClockSource::Hsi16,
            uart_rx_interrupt: false,
            over_current_trip_a: DEFAULT_OVER_CURRENT_TRIP_A,
            led_polarity: STATUS_LED_POLARITY,
        }
    }
}

// =================================================================================================
// Everything init() hands back.
// =================================================================================================

/// The initialised board.
pub struct Esc1 {
    /// TIM1 three-phase PWM (implements [`PowerStage`](crate::board::PowerStage)).
    pub power: Esc1PowerStage,
    /// OPAMP/ADC current and bus-voltage sensing (implements [`PhaseSensors`](crate::board::PhaseSensors)).
    pub sensors: Esc1Sensors,
    /// USART2 on the ST-LINK virtual COM port (implements `embedded_io::{Read, Write}`).
    pub uart: Esc1Uart,
    /// Status LED on PC6 (implements `embedded_hal::digital::OutputPin`).
    pub led: StatusLed,
    /// PLL input actually in use (HSE request falls back to HSI16 on timeout).
    pub clock_source: ClockSource,
    /// The over-current comparators' inputs U, V, W with no current, as the ADCs read them
    /// (V; `None` if a conversion did not end): a second reading of the zero-current levels
    /// the comparator sweep set the thresholds from
    /// ([`Esc1PowerStage::zero_current_codes`]); the two differ by the comparator's, the
    /// DAC's and the ADC's offsets.
    pub shunt_inputs_adc_v: Option<[f32; 3]>,
}

/// Brings the board up (clocks, PWM with the bridge disabled, analog front end, UART, LED).
///
/// On return: TIM1 counts, ADC1/ADC2 convert the injected group at every carrier valley and
/// ADC1 raises `JEOS` (interrupt [`CONTROL_IRQ`] is enabled in the ADC but *not* unmasked in the
/// NVIC: unmask it yourself once your handler is ready), the bridge is off (MOE = 0, all six
/// gate inputs driven low), the over-current comparators are armed on TIM1's break input with
/// thresholds above their measured zero-current levels. Call
/// [`Esc1Sensors::calibrate_current_offsets`] before enabling the bridge. Peripherals not used
/// here are dropped with `dp`. Preconditions: the bridge has not switched since reset and the
/// motor is at rest (no current in the shunts while the comparators are measured).
///
/// Order matters for the board: the gate pins stay in their reset state (analog, Hi-Z: the
/// L6387E input pull-downs keep every switch off) until TIM1 is configured with MOE = 0,
/// OSSI = 1, idle levels low and the break armed, and its trigger is confirmed at the valley;
/// only then do they become TIM1 outputs, and the first level TIM1 drives on them is low.
///
/// # Errors
/// [`Esc1InitError`]: a dead time outside [`DEAD_TIME_FLOOR_NS`]..=5929 ns (before anything is
/// touched), an implausible zero-current level at a comparator, a carrier that does not count,
/// an ADC trigger or conversion not at the valley. The gate pins have then not left their reset
/// state and MOE is clear.
pub fn init(dp: pac::Peripherals, config: &Esc1Config) -> Result<Esc1, Esc1InitError> {
    let dead_time = dead_time_setting(config.dead_time_ns)?;
    // A debugger halt stops TIM1 and disables its outputs as if MOE were cleared (RM0440,
    // advanced-control timers, "Debug mode"; DBGMCU_APB2FZR.DBG_TIM1_STOP). MCSDK sets it too.
    dp.DBGMCU.apb2_fz().modify(|_, w| w.dbg_tim1_stop().set_bit());
    let clock_source = init_clocks(&dp.RCC, &dp.FLASH, &dp.PWR, config.clock_source);
    enable_peripheral_clocks(&dp.RCC);
    // SYSCFG_CFGR2.CLL: the core's LOCKUP output breaks TIM1 (RM0440 SYSCFG_CFGR2, TIM1 system
    // break): a core locked up in a double fault cannot leave the bridge switching. Write-once
    // until reset.
    dp.SYSCFG.cfgr2().modify(|_, w| w.cll().set_bit());
    // PWR_CR3.UCPD1_DBDIS: release the USB-C dead-battery resistors the G4 applies from reset
    // to the UCPD1 CC pins, PB6 and PB4 = USART2 RX (RM0440 PWR_CR3). MCSDK's HAL_MspInit does
    // the same (HAL_PWREx_DisableUCPDDeadBattery), NuttX's board code when it uses PB6..PB8.
    dp.PWR.cr3().modify(|_, w| w.ucpd1_dbdis().set_bit());
    init_analog_pins(&dp.GPIOA, &dp.GPIOB);
    init_opamps(&dp.OPAMP);
    init_adcs(&dp.ADC1, &dp.ADC2, &dp.ADC12_COMMON);
    // The over-current thresholds from the comparators' own zero-current levels (TIM1 is not
    // running and its break not armed yet: the sweep's high outputs break nothing).
    init_over_current(&dp.DAC3, &dp.COMP);
    let zero_current_codes =
        measure_zero_current_codes(&mut DacComparators { dac: &dp.DAC3, comp: &dp.COMP })?;
    lock_comparators(&dp.COMP);
    let thresholds = over_current_thresholds(config.over_current_trip_a, zero_current_codes);
    write_thresholds(&dp.DAC3, &thresholds);
    let shunt_inputs_adc_v = measure_shunt_inputs_v(&dp.ADC1, &dp.ADC2);
    let power =
        Esc1PowerStage::new(dp.TIM1, dp.DAC3, dp.COMP, config, dead_time, zero_current_codes, thresholds)?;
    // The update event is at the valley; the conversions it triggers must end just after it
    // (the injected sequence takes about 2 us of the carrier's rise).
    if !wait_injected_end(&dp.ADC1) {
        return Err(Esc1InitError::NoConversion);
    }
    let (counting_down, count) = power.carrier_now();
    if !after_valley(counting_down, count, power.arr()) {
        return Err(Esc1InitError::TriggerNotAtValley {
            event: CarrierEvent::ConversionEnd,
            counting_down,
            count,
            arr: power.arr(),
        });
    }
    // Gate pins switch to TIM1 only now: TIM1 already drives them low (OSSI = 1, MOE = 0).
    init_pwm_pins(&dp.GPIOA, &dp.GPIOB, &dp.GPIOC);
    let uart = Esc1Uart::new(dp.USART2, &dp.GPIOB, config.baud, config.uart_rx_interrupt);
    let led = StatusLed::new(dp.GPIOC, config.led_polarity);
    let sensors = Esc1Sensors::new(dp.ADC1, dp.ADC2);
    Ok(Esc1 { power, sensors, uart, led, clock_source, shunt_inputs_adc_v })
}
