//! Board support for the ST **B-G431B-ESC1** (MCU STM32G431CBU6), written directly on the
//! `stm32g4` PAC (no HAL).
//!
//! What [`init`] brings up, in this order:
//! * TIM1 frozen while the core is halted by a debugger (DBGMCU), which also forces its
//!   outputs off: a breakpoint or a probe halt leaves the bridge off, not switching at the
//!   last duties;
//! * SYSCLK = HCLK = PCLK1 = PCLK2 = 170 MHz from the PLL (HSI16 by default, or the board's
//!   8 MHz HSE, then with the clock security system on), Range-1 boost mode and 4 flash wait
//!   states; the Cortex-M4 LOCKUP output wired to TIM1's break (a locked-up core cannot leave
//!   the bridge on); the UCPD dead-battery pull-down released from PB4 (USART2 RX);
//! * the hardware over-current trip: DAC3 sets a threshold from a trip current, COMP1/2/4
//!   compare the three shunt inputs with it and drive TIM1's break input, which clears MOE
//!   in hardware; the power stage latches it ([`PowerStage::hardware_trip`](crate::board::PowerStage::hardware_trip));
//! * TIM1: centre-aligned complementary PWM on the board's six gate-driver inputs, dead time,
//!   preloaded CCR1..3, one update event (and TRGO/TRGO2) per carrier period at the valley,
//!   break enabled, MOE clear; only then are the six gate pins handed to TIM1 (until then they
//!   are in their reset state, analog / Hi-Z, and the gate driver's input pull-downs hold
//!   them low);
//! * OPAMP1/2/3 in PGA mode (gain 16, VINM0 bias) on the three low-side shunts, read internally
//!   by ADC1/ADC2 as an injected group triggered by TIM1 TRGO2, plus the DC-bus divider on PA0;
//! * USART2 on the ST-LINK virtual COM port (PB3/PB4), 8N1;
//! * the green status LED on PC6.
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

pub use adc::*;
pub use clocks::*;
pub use led::*;
pub use motor_image::*;
pub use over_current::*;
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
// | Status LED (LD2)    | GPIO output           | PC6  | -   | NuttX b-g431b-esc1.h ("User LD2: green LED ... PC6") |
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
//   outputs off), V_il <= 1.5 V, and they sink 50-70 uA at 15 V (an input pull-down; L6387E
//   datasheet DocID13990 §5 Table 7 and the logic-input table). So: TIM1 polarity high on
//   CHx and CHxN (CCxP = CCxNP = 0, as NuttX requires and MCSDK sets), idle states low
//   (OISx = OISxN = 0, MCSDK: OCIdleState/OCNIdleState RESET), OSSI = OSSR = 1 (MCSDK), AOE = 0
//   (MCSDK). A gate pin left floating (reset state: analog, Hi-Z; none of the six is a debug
//   pin with a reset pull-up) reads low at the driver, i.e. switch off. The six pins: AF6
//   (PA8/9/10/12) and AF4 (PC13, PB15), push-pull, pull-down, speed "high" in MCSDK's
//   HAL_TIM_MspPostInit; the same here.
// * Current sense: shunt 3 mOhm per low-side leg (MCSDK RSHUNT 0.003; NuttX; SimpleFOC). Each
//   shunt reaches its op-amp's VINP through 1.5 kOhm, with 2.2 kOhm to ground and 22 kOhm to
//   3.3 V on that node (schematic values as worked out on the SimpleFOC forum, thread
//   "B-G431B-ESC1 Current Control"): VINP = 3.3 V * 3/77 + (4/7) * V_shunt = 0.1286 V +
//   0.571 * V_shunt. PGA gain 16 (PGA_GAIN 0b01011, VINM0 as the resistor ground; MCSDK
//   OPAMP_PGA_GAIN_16_OR_MINUS_15 with INVERTINGINPUT_IO0_BIAS; NuttX) gives 16 * 4/7 = 64/7 =
//   9.14 V/V (MCSDK AMPLIFICATION_GAIN 9.14; NuttX "-9.14 (inverted current)"). V_shunt is
//   positive when current flows down through the low-side switch into ground, which is current
//   flowing *out of* the motor's phase: with "positive into the motor" the gain is -64/7. The
//   zero-current output is not pinned down by these sources: 16 * 0.1286 V = 2.06 V (2553
//   counts) if the VINM0 pins (PA3/PA5/PB2, "OPAMPx_INT_GAIN" in MCSDK) sit at 0 V, ~1.65 V
//   by the SimpleFOC forum's measurement. It is measured at start-up, never assumed, and
//   checked against a window that holds both.
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
//   left-aligned = 255 of 4095 = 0.2056 V), i.e. 45 A with the network above.
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
    /// Dead time inserted between a leg's high- and low-side gate signals (ns), max ~6 us.
    pub dead_time_ns: u32,
    /// USART2 baud rate (bit/s), e.g. 115 200 or 921 600.
    pub baud: u32,
    /// PLL input clock.
    pub clock_source: ClockSource,
    /// Enable the USART2 RX-not-empty interrupt (vector [`UART_IRQ`]) at init.
    pub uart_rx_interrupt: bool,
    /// Hardware over-current trip (A, down any low-side shunt): DAC3 threshold of COMP1/2/4,
    /// which break TIM1. Clamped to [`OVER_CURRENT_TRIP_MIN_A`]..=[`OVER_CURRENT_TRIP_MAX_A`];
    /// can be lowered later with [`Esc1PowerStage::set_over_current_trip_a`].
    pub over_current_trip_a: f32,
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
}

/// Brings the board up (clocks, PWM with the bridge disabled, analog front end, UART, LED).
///
/// On return: TIM1 counts, ADC1/ADC2 convert the injected group at every carrier valley and
/// ADC1 raises `JEOS` (interrupt [`CONTROL_IRQ`] is enabled in the ADC but *not* unmasked in the
/// NVIC: unmask it yourself once your handler is ready), the bridge is off (MOE = 0, all six
/// gate inputs driven low), the over-current comparators are armed on TIM1's break input.
/// Call [`Esc1Sensors::calibrate_current_offsets`] before enabling the bridge. Peripherals not
/// used here are dropped with `dp`.
///
/// Order matters for the board: the gate pins stay in their reset state (analog, Hi-Z: the
/// L6387E input pull-downs keep every switch off) until TIM1 is configured with MOE = 0,
/// OSSI = 1, idle levels low and the break armed; only then do they become TIM1 outputs, and
/// the first level TIM1 drives on them is low.
pub fn init(dp: pac::Peripherals, config: &Esc1Config) -> Esc1 {
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
    let trip_a = over_current_trip_clamped(config.over_current_trip_a);
    init_over_current(&dp.DAC3, &dp.COMP, over_current_dac_code(trip_a));
    let power = Esc1PowerStage::new(dp.TIM1, dp.DAC3, dp.COMP, config, trip_a);
    // Gate pins switch to TIM1 only now: TIM1 already drives them low (OSSI = 1, MOE = 0).
    init_pwm_pins(&dp.GPIOA, &dp.GPIOB, &dp.GPIOC);
    let uart = Esc1Uart::new(dp.USART2, &dp.GPIOB, config.baud, config.uart_rx_interrupt);
    let led = StatusLed::new(dp.GPIOC);
    let sensors = Esc1Sensors::new(dp.ADC1, dp.ADC2);
    Esc1 { power, sensors, uart, led, clock_source }
}

// =================================================================================================
// Compile-time checks of the arithmetic above.
// =================================================================================================

const _: () = {
    // 800 ns at 170 MHz = 136 ticks = (64 + 4) * 2 -> DTG 0x84.
    let d = dead_time_dtg(800, SYSCLK_HZ);
    assert!(d.dtg == 0x84 && d.ticks == 136);
    // 500 ns -> 85 ticks (DTG 85).
    assert!(dead_time_dtg(500, SYSCLK_HZ).dtg == 85);
    // 10 kHz centre-aligned -> ARR 8500 (period 17000 ticks = 100 us).
    assert!(pwm_arr(10_000, SYSCLK_HZ) == 8500);
    // The over-current threshold at MCSDK's 45 A is MCSDK's DAC value for this board
    // (DAC_OCP_Threshold 4083, 16-bit left-aligned = 255 in 12 bits); 40 A -> 0.197 V = 245.
    assert!(over_current_dac_code(45.0) == 255);
    assert!(over_current_dac_code(DEFAULT_OVER_CURRENT_TRIP_A) == 245);
    // Clamped at both ends, NaN -> the default; the lowest threshold is above the
    // zero-current level of the comparator inputs (0.1286 V = 159.6 counts).
    assert!(over_current_dac_code(1000.0) == 255 && over_current_dac_code(f32::NAN) == 245);
    assert!(over_current_dac_code(0.0) == 181 && over_current_dac_code(-5.0) == 181);
};
