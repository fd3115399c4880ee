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
//!   in hardware; the power stage latches it ([`PowerStage::hardware_trip`]);
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
//! Reference numbering used below: UM2516 = "B-G431B-ESC1 Discovery kit" user manual,
//! RM0440 = STM32G4 reference manual, DS12589 = STM32G431xx datasheet, MCSDK = the ST Motor
//! Control SDK project generated for this board ("ElectronicSpeedControl_ESC-G4", MCSDK 6.x:
//! its `main.c`, `mc_parameters.c`, `power_stage_parameters.h`; public copies e.g.
//! github.com/kennethsauers/B-G431B-ESC1), L6387E = the gate driver's datasheet (DocID13990).
//! Section numbers of RM0440 are given as chapter titles plus the number as recalled for RM0440
//! rev 7/8 and are not verified; register and bit names are (they are the PAC's, generated from
//! ST's SVD). The facts are collected, with their sources, in the board table below.

use core::convert::Infallible;

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
/// User/status LED LD2 (PC6, push-pull output), active high: UM2516 Table 4 via the pinout
/// extract ("PC6 STATUS LED"); a CubeMX project's notes for the board switch it on with the pin
/// set. Its colour is given as green (NuttX) and as red (those notes): not verified.
pub const PIN_LED: PinDef = pin(b'C', 6, 0);

/// ADC1 channel of the OPAMP1 output (VOPAMP1 = ADC1_IN13, internal; RM0440 ADC connectivity).
pub const ADC1_CH_I_U: u8 = 13;
/// ADC1 channel of the DC-bus divider (ADC1_IN1 = PA0).
pub const ADC1_CH_VBUS: u8 = 1;
/// ADC2 channel of the OPAMP2 output (VOPAMP2 = ADC2_IN16, internal).
pub const ADC2_CH_I_V: u8 = 16;
/// ADC2 channel of the OPAMP3 output (VOPAMP3 = ADC2_IN18, internal on ADC2).
pub const ADC2_CH_I_W: u8 = 18;

/// Interrupt that signals "injected sequence of ADC1 finished" = the control interrupt.
/// ADC1 and ADC2 share this vector (RM0440 vector table: `ADC1_2`, IRQ 18).
pub const CONTROL_IRQ: pac::Interrupt = pac::Interrupt::ADC1_2;
/// Interrupt of the UART (RX-not-empty when enabled with [`Esc1Uart::listen_rx`]).
pub const UART_IRQ: pac::Interrupt = pac::Interrupt::USART2;

// -------------------------------------------------------------------------------------------------
// Analog front-end constants (board facts; sources in the board table above).
// -------------------------------------------------------------------------------------------------

/// Low-side shunt resistance (ohm), one per phase. MCSDK RSHUNT 0.003; NuttX board README /
/// stm32_foc.c: 0.003; SimpleFOC ESC1 example `LowsideCurrentSense(0.003, ...)`.
pub const SHUNT_OHM: f32 = 0.003;
/// Internal PGA setting (V/V) for the non-inverting input: PGA_GAIN = 0b01011
/// ("gain 16 / -15 with VINM0"). NuttX stm32_foc.c, SimpleFOC (`OPAMP_PGA_GAIN_16_OR_MINUS_15`).
pub const PGA_GAIN: f32 = 16.0;
/// Net transfer of phase current times shunt resistance to OPAMP output (V/V), including the
/// board's input network (4/7) and the PGA (16): -64/7 = -9.142857, negative because with
/// "positive into the motor" the current flows up through the low-side shunt and the amplified
/// voltage falls below the bias. MCSDK AMPLIFICATION_GAIN 9.14; SimpleFOC ESC1 example
/// `-64.0/7.0`; NuttX README "Current sense gain = -9.14 (inverted current)".
pub const CURRENT_SENSE_GAIN: f32 = -64.0 / 7.0;
/// ADC reference / full-scale voltage (V). VDDA = VREF+ = 3.3 V on the board (assumed, 3.3 V LDO).
pub const VREF_V: f32 = 3.3;
/// ADC full-scale code count for 12-bit conversions (counts).
pub const ADC_FULL_SCALE_COUNTS: f32 = 4096.0;
/// Nominal zero-current ADC code of each current channel (counts). Mid-scale placeholder:
/// the real bias comes from the board's resistor network and differs per phase, so call
/// [`Esc1Sensors::calibrate_current_offsets`] with the bridge disabled before use.
pub const CURRENT_OFFSET_NOMINAL_COUNTS: f32 = 2048.0;
/// DC-bus divider ratio V_adc / V_bus (V/V) = 18 k / (18 k + 169 k) = 0.09626. NuttX README;
/// MCSDK VBUS_PARTITIONING_FACTOR 0.09625565501973242 (= 18/187 to 7 digits).
pub const VBUS_DIVIDER: f32 = 18.0 / (18.0 + 169.0);
/// Amperes per ADC count of a current channel (A/count) = VREF / 4096 / (R_shunt * gain) ≈ -0.02937.
pub const AMPS_PER_COUNT: f32 = VREF_V / ADC_FULL_SCALE_COUNTS / (SHUNT_OHM * CURRENT_SENSE_GAIN);
/// Bus volts per ADC count (V/count) = VREF / 4096 / divider ≈ 0.00837.
pub const VBUS_VOLTS_PER_COUNT: f32 = VREF_V / ADC_FULL_SCALE_COUNTS / VBUS_DIVIDER;
/// Window (counts) the measured zero-current code of every current channel must fall in for
/// [`Esc1Sensors::calibrate_current_offsets`] to accept it: mid-scale ± 1000 counts (± 0.8 V,
/// ± 29 A). The offset is expected between about 2048 and 2553 counts (board table); a code
/// near a rail means an op-amp, channel or bias fault, and the drive must not run on it.
pub const CURRENT_OFFSET_WINDOW_COUNTS: (f32, f32) = (1048.0, 3048.0);

/// Voltage at an op-amp's non-inverting input (PA1/PA7/PB0) with no shunt current (V):
/// 3.3 V * 3/77, from the board's input network (board table).
pub const SHUNT_INPUT_BIAS_V: f32 = 3.3 * 3.0 / 77.0;
/// Shunt voltage to op-amp input voltage (V/V): 4/7, from the same network.
pub const SHUNT_INPUT_GAIN: f32 = 4.0 / 7.0;
/// DAC3 full scale (V): its reference is VREF+ = 3.3 V on this board.
pub const DAC_FULL_SCALE_V: f32 = 3.3;
/// Default hardware over-current trip (A, down a low-side shunt): the board's rating,
/// "Iout max = 40A peak" (NuttX README). MCSDK's threshold for this board is 45 A.
pub const DEFAULT_OVER_CURRENT_TRIP_A: f32 = 40.0;
/// Lowest hardware trip accepted (A): 10 A is 17 mV (21 DAC counts) above the comparator
/// inputs' zero-current level; lower would trip on noise and offsets.
pub const OVER_CURRENT_TRIP_MIN_A: f32 = 10.0;
/// Highest hardware trip accepted (A): MCSDK's own threshold for the board (45 A).
pub const OVER_CURRENT_TRIP_MAX_A: f32 = 45.0;

/// Trip current actually used for a request of `trip_a` (A): clamped to
/// [`OVER_CURRENT_TRIP_MIN_A`]..=[`OVER_CURRENT_TRIP_MAX_A`], NaN -> the default.
pub const fn over_current_trip_clamped(trip_a: f32) -> f32 {
    if trip_a.is_nan() {
        DEFAULT_OVER_CURRENT_TRIP_A
    } else if trip_a < OVER_CURRENT_TRIP_MIN_A {
        OVER_CURRENT_TRIP_MIN_A
    } else if trip_a > OVER_CURRENT_TRIP_MAX_A {
        OVER_CURRENT_TRIP_MAX_A
    } else {
        trip_a
    }
}

/// DAC3 code (12-bit right-aligned, counts) of the comparator threshold for a trip at
/// `trip_a` amperes flowing down a low-side shunt (clamped as in
/// [`over_current_trip_clamped`]): (bias + 4/7 · R_shunt · I) / 3.3 V · 4096, rounded.
pub const fn over_current_dac_code(trip_a: f32) -> u16 {
    let i = over_current_trip_clamped(trip_a);
    let v = SHUNT_INPUT_BIAS_V + SHUNT_INPUT_GAIN * SHUNT_OHM * i;
    // In range by the clamp: 0.146 V .. 0.206 V -> 181 .. 255 counts.
    (v / DAC_FULL_SCALE_V * 4096.0 + 0.5) as u16
}

// -------------------------------------------------------------------------------------------------
// Clock constants.
// -------------------------------------------------------------------------------------------------

/// System, AHB, APB1, APB2 and TIM1 kernel clock after [`init`] (Hz).
pub const SYSCLK_HZ: u32 = 170_000_000;
/// HSE frequency of [`ClockSource::Hse8MHz`] (Hz): UM2516 Table 4 lists "OSC 8 MHz" on
/// PF0/PF1 and ST's MCSDK project for the board runs its PLL from an 8 MHz HSE (oscillator
/// mode, not bypass). HSI16 stays the default: it needs nothing from the board.
pub const HSE_HZ: u32 = 8_000_000;
/// ADC kernel clock: synchronous HCLK / 4 (Hz) = 42.5 MHz.
pub const ADC_CLOCK_HZ: u32 = SYSCLK_HZ / 4;

/// Default PWM carrier frequency (Hz): 10 kHz, i.e. 100 us period.
pub const DEFAULT_PWM_HZ: u32 = 10_000;
/// Default dead time (ns). 800 ns = DTG 0x84 at 170 MHz: MCSDK's value for this board
/// (power_stage_parameters.h HW_DEAD_TIME_NS 800), as the pat92fr ESC1 CubeMX project (DTG=128
/// at 160 MHz); NuttX uses 500 ns.
pub const DEFAULT_DEAD_TIME_NS: u32 = 800;
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

use super::{PhaseSample, PhaseSensors, PowerStage};

// =================================================================================================
// Everything init() hands back.
// =================================================================================================

/// The initialised board.
pub struct Esc1 {
    /// TIM1 three-phase PWM (implements [`PowerStage`]).
    pub power: Esc1PowerStage,
    /// OPAMP/ADC current and bus-voltage sensing (implements [`PhaseSensors`]).
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
    let sensors = Esc1Sensors {
        adc1: dp.ADC1,
        adc2: dp.ADC2,
        offset_counts: [CURRENT_OFFSET_NOMINAL_COUNTS; 3],
        last_calibration: [CURRENT_OFFSET_NOMINAL_COUNTS; 3],
    };
    Esc1 { power, sensors, uart, led, clock_source }
}

// =================================================================================================
// Clocks — RM0440 ch. 6 PWR §6.1.5 "Dynamic voltage scaling management" (boost sequence),
// ch. 7 RCC §7.2.4 "PLL", ch. 3 FLASH §3.3.3 "Read access latency" (Table 9: 4 WS @ 170 MHz
// in Range 1 boost mode).
// =================================================================================================

/// Busy-wait bound for oscillator/PLL ready flags (iterations, roughly 1 ms at 16 MHz).
const READY_SPINS: u32 = 20_000;

fn init_clocks(rcc: &pac::RCC, flash: &pac::FLASH, pwr: &pac::PWR, want: ClockSource) -> ClockSource {
    // PWR registers need the PWR APB clock.
    rcc.apb1enr1().modify(|_, w| w.pwren().set_bit());
    let _ = rcc.apb1enr1().read(); // RM0440 §7.2.17 (read back = 2-cycle delay after enable)

    // Source selection: try the HSE only if asked.
    let mut source = ClockSource::Hsi16;
    if want == ClockSource::Hse8MHz {
        rcc.cr().modify(|_, w| w.hseon().set_bit());
        let mut n = 0;
        while rcc.cr().read().hserdy().bit_is_clear() && n < READY_SPINS * 10 {
            n += 1;
        }
        if rcc.cr().read().hserdy().bit_is_set() {
            source = ClockSource::Hse8MHz;
            // Clock security system (MCSDK enables it too): an HSE failure switches to HSI16,
            // raises the NMI and is a system break of TIM1 (MOE cleared in hardware).
            rcc.cr().modify(|_, w| w.csson().set_bit());
        } else {
            rcc.cr().modify(|_, w| w.hseon().clear_bit());
        }
    }
    // HSI16 is on after reset; make sure anyway (it also clocks the flash interface at reset).
    rcc.cr().modify(|_, w| w.hsion().set_bit());
    while rcc.cr().read().hsirdy().bit_is_clear() {}

    // Boost step 1 (PWR §6.1.5): divide HCLK by 2 before raising SYSCLK above 150 MHz.
    rcc.cfgr().modify(|_, w| w.hpre().div2());
    // Boost step 2: Range 1 boost mode (R1MODE = 0 in PWR_CR5). VOS stays Range 1 (reset).
    pwr.cr5().modify(|_, w| w.r1mode().clear_bit());
    // Boost step 3: wait states for 170 MHz (FLASH Table 9: 4 WS), prefetch and caches on.
    flash.acr().modify(|_, w| {
        w.latency().variant(pac::flash::acr::LATENCY::Wait4);
        w.prften().set_bit();
        w.icen().set_bit();
        w.dcen().set_bit()
    });
    while flash.acr().read().latency().bits() != 4 {}

    // PLL: VCO in = 4 MHz (range 2.66..8 MHz), VCO = 4 MHz * 85 = 340 MHz (<= 344 MHz),
    // PLLR = /2 -> 170 MHz. RCC §7.2.4 and RCC_PLLCFGR.
    rcc.cr().modify(|_, w| w.pllon().clear_bit());
    while rcc.cr().read().pllrdy().bit_is_set() {}
    rcc.pllcfgr().modify(|_, w| {
        match source {
            ClockSource::Hsi16 => {
                w.pllsrc().hsi16();
                w.pllm().div4()
            }
            ClockSource::Hse8MHz => {
                w.pllsrc().hse();
                w.pllm().div2()
            }
        };
        w.plln().variant(pac::rcc::pllcfgr::PLLN::Div85);
        w.pllr().div2();
        w.pllren().set_bit()
    });
    rcc.cr().modify(|_, w| w.pllon().set_bit());
    while rcc.cr().read().pllrdy().bit_is_clear() {}

    // Boost step 4: switch SYSCLK to PLLR; APB1/APB2 undivided (so TIM1 clock = 170 MHz).
    rcc.cfgr().modify(|_, w| {
        w.ppre1().div1();
        w.ppre2().div1();
        w.sw().pll()
    });
    while !rcc.cfgr().read().sws().is_pll() {}
    // Boost step 5: wait >= 1 us at the new clock, then HCLK = SYSCLK.
    cortex_m::asm::delay(200);
    rcc.cfgr().modify(|_, w| w.hpre().div1());
    source
}

fn enable_peripheral_clocks(rcc: &pac::RCC) {
    rcc.ahb2enr().modify(|_, w| {
        w.gpioaen().set_bit();
        w.gpioben().set_bit();
        w.gpiocen().set_bit();
        w.adc12en().set_bit();
        w.dac3en().set_bit()
    });
    rcc.apb2enr().modify(|_, w| {
        w.syscfgen().set_bit(); // SYSCFG, COMP and OPAMP registers: the SYSCFG APB2 clock
        w.tim1en().set_bit()
    });
    rcc.apb1enr1().modify(|_, w| w.usart2en().set_bit());
    // USART2 kernel clock = PCLK1 (USART2SEL = 00) and ADC12 kernel clock = SYSCLK (only used
    // in asynchronous mode; we use the synchronous HCLK/4 clock, ADC12_CCR.CKMODE).
    rcc.ccipr().modify(|_, w| {
        // SAFETY: USART2SEL is a 2-bit field; 0b00 = PCLK is a documented value (RM0440 RCC_CCIPR).
        unsafe { w.usart2sel().bits(0) };
        w.adc12sel().variant(pac::rcc::ccipr::ADC12SEL::System)
    });
    let _ = rcc.ccipr().read();
}

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

fn init_analog_pins(gpioa: &pac::GPIOA, gpiob: &pac::GPIOB) {
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
fn init_pwm_pins(gpioa: &pac::GPIOA, gpiob: &pac::GPIOB, gpioc: &pac::GPIOC) {
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

// =================================================================================================
// OPAMP — RM0440 ch. 25 "Operational amplifiers (OPAMP)", §25.3.5 PGA mode with external
// bias on VINM0, OPAMPx_CSR.
// =================================================================================================

fn init_opamps(opamp: &pac::OPAMP) {
    // Identical settings for the three phases; written in two steps (configure, then enable) like
    // the NuttX board code. OPAINTOEN = 1 routes the output to the ADC internally (the output
    // pins PA2/PA6/PB1 stay free). OPAHSM = high-speed mode.
    macro_rules! cfg {
        ($csr:expr) => {{
            $csr.write(|w| {
                w.vp_sel().vinp0();
                w.vm_sel().pga();
                w.pga_gain().gain16_input_vinm0();
                w.opahsm().set_bit();
                w.opaintoen().set_bit()
            });
            $csr.modify(|_, w| w.opaen().set_bit());
        }};
    }
    cfg!(opamp.opamp1_csr());
    cfg!(opamp.opamp2_csr());
    cfg!(opamp.opamp3_csr());
}

// =================================================================================================
// ADC — RM0440 ch. 21 "Analog-to-digital converters (ADC)": §21.4.6 deep power-down / regulator,
// §21.4.8 calibration, §21.4.9 enable, §21.4.21 injected channels (JSQR, JEXTSEL), §21.4.12
// sampling time; ADC12_CCR.CKMODE clock.
// =================================================================================================

/// Sampling time of the current channels (ADC cycles, SMPx code 1 = 6.5 cycles = 153 ns), as
/// MCSDK (ADC_SAMPLETIME_6CYCLES_5 for its current channels).
const SMP_CURRENT: u8 = 1;
/// Sampling time of the bus-voltage channel (code 4 = 47.5 cycles = 1.12 us; source ~16 kohm),
/// as MCSDK (M1_VBUS_SAMPLING_TIME 47.5 cycles).
const SMP_VBUS: u8 = 4;
/// JEXTSEL code of TIM1_TRGO2 for ADC1/ADC2 injected triggers (RM0440 ADC1/2 injected trigger table).
const JEXTSEL_TIM1_TRGO2: u8 = 8;

fn init_adcs(adc1: &pac::ADC1, adc2: &pac::ADC2, common: &pac::ADC12_COMMON) {
    // Synchronous clock HCLK/4 = 42.5 MHz: deterministic trigger-to-sample latency.
    common.ccr().modify(|_, w| w.ckmode().sync_div4());
    adc_power_up_and_calibrate(adc1);
    adc_power_up_and_calibrate(adc2);

    // Sequences: ADC1 = [I_U, V_BUS], ADC2 = [I_V, I_W]. Both start on the same TIM1 TRGO2 edge,
    // so I_U and I_V are sampled simultaneously at the valley; I_W and V_BUS are sampled one
    // conversion later (6.5 + 12.5 = 19 ADC cycles ≈ 0.45 us after the valley).
    adc_set_sampling(adc1, ADC1_CH_I_U, SMP_CURRENT);
    adc_set_sampling(adc1, ADC1_CH_VBUS, SMP_VBUS);
    adc_set_sampling(adc2, ADC2_CH_I_V, SMP_CURRENT);
    adc_set_sampling(adc2, ADC2_CH_I_W, SMP_CURRENT);
    adc_set_injected(adc1, ADC1_CH_I_U, ADC1_CH_VBUS);
    adc_set_injected(adc2, ADC2_CH_I_V, ADC2_CH_I_W);

    // ADC1 ends last (its 2nd conversion has the longer sampling time): its JEOS is the
    // "all four results ready" event; ADC2's sequence is 38 ADC cycles vs 79 for ADC1.
    adc1.isr().write(|w| w.jeos().clear().jeoc().clear());
    adc2.isr().write(|w| w.jeos().clear().jeoc().clear());
    adc1.ier().modify(|_, w| w.jeosie().set_bit());
    // Arm: conversions start at each trigger edge from now on.
    adc1.cr().modify(|_, w| w.jadstart().set_bit());
    adc2.cr().modify(|_, w| w.jadstart().set_bit());
}

fn adc_power_up_and_calibrate(adc: &pac::adc1::RegisterBlock) {
    // Leave deep power-down, enable the voltage regulator, wait t_ADCVREG_STUP (20 us, DS12589).
    adc.cr().modify(|_, w| w.deeppwd().clear_bit());
    adc.cr().modify(|_, w| w.advregen().set_bit());
    cortex_m::asm::delay(SYSCLK_HZ / 1_000_000 * 25);
    // Single-ended calibration (ADEN must be 0).
    adc.cr().modify(|_, w| w.adcaldif().clear_bit());
    adc.cr().modify(|_, w| w.adcal().set_bit());
    while adc.cr().read().adcal().bit_is_set() {}
    // >= 4 ADC clock cycles between end of calibration and ADEN (RM0440 §21.4.8 note).
    cortex_m::asm::delay(64);
    // 12-bit, right-aligned, injected queue disabled (JQDIS = 1: JSQR is a plain register).
    adc.cfgr().modify(|_, w| {
        w.res().bits12();
        w.align().clear_bit();
        w.jqdis().set_bit()
    });
    adc.isr().write(|w| w.adrdy().clear());
    adc.cr().modify(|_, w| w.aden().set_bit());
    while adc.isr().read().adrdy().bit_is_clear() {}
    adc.isr().write(|w| w.adrdy().clear());
    // One dummy regular conversion (sequence length 1, SQ1 = channel 0 at reset, software
    // start), its result dropped, before the injected conversions start: MCSDK's ADC set-up
    // for the G4 does the same, citing the G431 errata sheet ES0431 ("ADC channel 0 converted
    // instead of the required ADC channel"); NuttX's FOC driver has its own workaround for it.
    adc.sqr1().modify(|_, w| w.l().set(0));
    adc.cr().modify(|_, w| w.adstart().set_bit());
    let mut spins = 0u32;
    while adc.isr().read().eoc().bit_is_clear() && spins < 100_000 {
        spins += 1;
    }
    let _ = adc.dr().read();
    adc.isr().write(|w| w.eoc().clear().eos().clear().ovr().clear());
}

fn adc_set_sampling(adc: &pac::adc1::RegisterBlock, ch: u8, smp: u8) {
    if ch < 10 {
        adc.smpr1().modify(|_, w| w.smp(ch).set(smp));
    } else {
        adc.smpr2().modify(|_, w| w.smp(ch - 10).set(smp));
    }
}

fn adc_set_injected(adc: &pac::adc1::RegisterBlock, first: u8, second: u8) {
    adc.jsqr().write(|w| {
        w.jl().set(1); // 2 conversions
        // SAFETY: JEXTSEL is 5 bits; 8 = TIM1_TRGO2 is a valid ADC1/ADC2 injected trigger code.
        unsafe { w.jextsel().bits(JEXTSEL_TIM1_TRGO2) };
        w.jexten().rising_edge();
        // SAFETY: JSQx are 5-bit channel numbers; 1, 13, 16, 18 are existing ADC1/ADC2 channels.
        unsafe {
            w.jsq1().bits(first);
            w.jsq2().bits(second)
        }
    });
}

// =================================================================================================
// Current / bus-voltage sensing.
// =================================================================================================

/// ADC1 + ADC2 injected results converted to SI units.
pub struct Esc1Sensors {
    adc1: pac::ADC1,
    adc2: pac::ADC2,
    /// Zero-current ADC code of phases U, V, W (counts).
    offset_counts: [f32; 3],
    /// What the last calibration measured (counts).
    last_calibration: [f32; 3],
}

impl Esc1Sensors {
    /// Raw injected results `[I_U, I_V, I_W, V_BUS]` (ADC counts, 0..4095), last conversion.
    pub fn raw(&self) -> [u16; 4] {
        [
            self.adc1.jdr(0).read().jdata().bits(),
            self.adc2.jdr(0).read().jdata().bits(),
            self.adc2.jdr(1).read().jdata().bits(),
            self.adc1.jdr(1).read().jdata().bits(),
        ]
    }

    /// Clears the injected end-of-sequence/-conversion flags of both ADCs (acknowledges the
    /// [`CONTROL_IRQ`]). [`PhaseSensors::sample`] does this itself.
    pub fn clear_flags(&mut self) {
        self.adc1.isr().write(|w| w.jeos().clear().jeoc().clear());
        self.adc2.isr().write(|w| w.jeos().clear().jeoc().clear());
    }

    /// Current zero offsets of phases U, V, W (ADC counts).
    pub fn current_offsets(&self) -> [f32; 3] {
        self.offset_counts
    }

    /// Sets the zero-current offsets of phases U, V, W (ADC counts).
    pub fn set_current_offsets(&mut self, counts: [f32; 3]) {
        self.offset_counts = counts;
    }

    /// Measures the zero-current offsets by averaging `n` valley samples (n = 1..=4096 periods;
    /// 64 takes 6.4 ms at 10 kHz). Preconditions: bridge disabled, motor at rest, and the control
    /// interrupt masked in the NVIC (this polls the same JEOS flag). Returns `false` (offsets
    /// unchanged) if conversions stop arriving or if any channel's average is outside
    /// [`CURRENT_OFFSET_WINDOW_COUNTS`] (an op-amp, channel or bias fault: the currents would be
    /// wrong by amperes); [`Esc1Sensors::last_calibration`] has what was measured either way.
    pub fn calibrate_current_offsets(&mut self, n: u16) -> bool {
        let n = n.clamp(1, 4096);
        let mut acc = [0u32; 3];
        let mut got = 0u16;
        while got < n {
            self.clear_flags();
            let mut spins = 0u32;
            while self.adc1.isr().read().jeos().bit_is_clear() {
                spins += 1;
                if spins > 2_000_000 {
                    return false;
                }
            }
            let r = self.raw();
            acc[0] += u32::from(r[0]);
            acc[1] += u32::from(r[1]);
            acc[2] += u32::from(r[2]);
            got += 1;
        }
        self.clear_flags();
        let nf = f32::from(n);
        let measured = [acc[0] as f32 / nf, acc[1] as f32 / nf, acc[2] as f32 / nf];
        self.last_calibration = measured;
        let (lo, hi) = CURRENT_OFFSET_WINDOW_COUNTS;
        if measured.iter().any(|&c| !(lo..=hi).contains(&c)) {
            return false;
        }
        self.offset_counts = measured;
        true
    }

    /// Averages of the last [`Esc1Sensors::calibrate_current_offsets`] (counts, U/V/W),
    /// accepted or not; the nominal mid-scale before any.
    pub fn last_calibration(&self) -> [f32; 3] {
        self.last_calibration
    }
}

impl PhaseSensors for Esc1Sensors {
    /// Reads ADC1/ADC2 JDR1/JDR2 and clears the flags. Sampling instants (valley = TIM1 underflow
    /// + trigger latency): I_U and I_V at the valley, I_W and V_BUS ≈ 0.45 us later.
    fn sample(&mut self) -> PhaseSample {
        let r = self.raw();
        self.clear_flags();
        let o = self.offset_counts;
        PhaseSample {
            i_abc_a: [
                (f32::from(r[0]) - o[0]) * AMPS_PER_COUNT,
                (f32::from(r[1]) - o[1]) * AMPS_PER_COUNT,
                (f32::from(r[2]) - o[2]) * AMPS_PER_COUNT,
            ],
            vdc_v: f32::from(r[3]) * VBUS_VOLTS_PER_COUNT,
        }
    }
}

// =================================================================================================
// Hardware over-current trip — DAC3 (RM0440 ch. 22 "DAC": DAC_MCR.MODEx / HFSEL, DAC_CR.ENx,
// DAC_SR.DACxRDY, DAC_DHR12Rx) and COMP1/2/4 (ch. 24 "COMP": COMPx_CSR), wired as in MCSDK's
// project for this board (board table). The comparators feed TIM1's break (TIM1_AF1, below).
// =================================================================================================

/// Busy-wait bound for the DAC3 channels' ready flags (iterations).
const DAC_READY_SPINS: u32 = 100_000;

/// COMPx_CSR.INMSEL code of "DAC3 channel" (DAC3_CH1 for COMP1, DAC3_CH2 for COMP2 and COMP4;
/// RM0440 COMPx_CSR, MCSDK COMP_INPUT_MINUS_DAC3_CH1/_CH2 = INMSEL bit 2).
const COMP_INMSEL_DAC3: u8 = 0b100;

fn init_over_current(dac: &pac::DAC3, comp: &pac::COMP, code: u16) {
    // DAC3: internal only (it has no pin), buffer off, as MCSDK configures it
    // (DAC_CHIPCONNECT_INTERNAL, OUTPUTBUFFER_DISABLE); the bus interface in its >160 MHz mode
    // for HCLK = 170 MHz. MODEx and HFSEL are written with the channels disabled.
    dac.cr().write(|w| w.en1().clear_bit().en2().clear_bit());
    dac.mcr().write(|w| {
        w.hfsel().variant(pac::dac1::mcr::HFSEL::More160mhz);
        w.mode1().normal_chip_no_buffer();
        w.mode2().normal_chip_no_buffer()
    });
    dac.cr().write(|w| w.en1().set_bit().en2().set_bit());
    let mut spins = 0;
    while !(dac.sr().read().dac1rdy().is_ready() && dac.sr().read().dac2rdy().is_ready())
        && spins < DAC_READY_SPINS
    {
        spins += 1;
    }
    // No trigger (TENx = 0): DHR goes to the output one clock after the write.
    dac.dhr12r1().write(|w| w.daccdhr().set(code));
    dac.dhr12r2().write(|w| w.daccdhr().set(code));
    // Let the threshold settle before the comparators look at it (a few us).
    cortex_m::asm::delay(SYSCLK_HZ / 1_000_000 * 10);

    // COMP1 (INP0 = PA1, U), COMP2 (INP0 = PA7, V), COMP4 (INP0 = PB0, W) against DAC3: output
    // high while the shunt input is above the threshold; no hysteresis, no blanking, not
    // inverted (MCSDK MX_COMPx_Init). Locked afterwards (MCSDK locks them too): their
    // configuration cannot change until reset.
    for n in [0usize, 1, 3] {
        let csr = comp.ccsr(n);
        csr.write(|w| {
            // SAFETY: INMSEL is 3 bits; 0b100 selects the DAC3 channel of this comparator
            // (RM0440 COMPx_CSR).
            unsafe { w.inmsel().bits(COMP_INMSEL_DAC3) };
            w.inpsel().clear_bit();
            w.pol().clear_bit();
            // SAFETY: HYST and BLANKSEL are 3 bits; 0 = none (RM0440 COMPx_CSR).
            unsafe {
                w.hyst().bits(0);
                w.blanksel().bits(0)
            }
        });
        csr.modify(|_, w| w.en().set_bit());
    }
    // Comparator start-up time (t_START, a few us in DS12589) before TIM1 reads them.
    cortex_m::asm::delay(SYSCLK_HZ / 1_000_000 * 10);
    for n in [0usize, 1, 3] {
        comp.ccsr(n).modify(|_, w| w.lock().set_bit());
    }
}

// =================================================================================================
// TIM1 PWM — RM0440 ch. 28 "Advanced-control timers (TIM1/TIM8/TIM20)": §28.3.3 repetition
// counter, §28.3.13 PWM mode (centre-aligned), §28.3.14 complementary outputs and dead-time,
// §28.3.16 break / MOE, TIMx_CR2.MMS2 (TRGO2), TIMx_BDTR.DTG encoding.
// =================================================================================================

/// TIM1 configured for three-phase complementary centre-aligned PWM.
///
/// Counter: centre-aligned mode 1, 0 -> ARR -> 0, period = 2·ARR timer ticks.
/// Channels use **PWM mode 2** (OCxREF active while CNT > CCRx), so the high side is on around
/// the counter *peak* and the low sides conduct around the *valley* (CNT = 0) — the instant at
/// which the update event, TRGO and TRGO2 (ADC trigger) fire once per period (RCR = 1, phase
/// verified at init). High-side on time = 2·(ARR − CCR) ticks, so CCR = ARR·(1 − duty).
///
/// Break: COMP1/2/4 (the hardware over-current trip) and the system break sources (core
/// LOCKUP, HSE clock failure when the HSE runs) clear MOE in hardware. The break inputs act on
/// level, but once the current has decayed the comparators release, and MOE could be set
/// again by software. So the stage latches any break it sees (`BIF`/`SBIF`) and
/// [`PowerStage::enable_bridge`] does nothing while latched, checking again right after it
/// sets MOE (a break between the check and the write is caught in the same call). Only
/// [`PowerStage::clear_hardware_trip`] re-arms it, and only once the break input is inactive.
pub struct Esc1PowerStage {
    tim: pac::TIM1,
    dac: pac::DAC3,
    comp: pac::COMP,
    arr: u32,
    dtg: u8,
    trip_a: f32,
    tripped: bool,
}

/// Result of the dead-time computation (for logging / tests).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeadTime {
    /// TIMx_BDTR.DTG code.
    pub dtg: u8,
    /// Dead time actually obtained (timer ticks of 1/170 MHz).
    pub ticks: u32,
}

/// Encodes a dead time of at least `ns` nanoseconds at timer clock `f_hz` (tDTS = 1/f_hz, CKD = 0)
/// into TIMx_BDTR.DTG (RM0440 TIMx_BDTR DTG[7:0]); saturates at the maximum (1008 ticks).
/// `f_hz` is used in whole MHz (exact for 170 MHz); 32-bit math only (no u64 division helper).
pub const fn dead_time_dtg(ns: u32, f_hz: u32) -> DeadTime {
    let ns = if ns > 100_000 { 100_000 } else { ns };
    let f_mhz = f_hz / 1_000_000;
    // ticks = ceil(ns * f_MHz / 1000); <= 100_000 * 4294 fits u32 for any f_hz.
    let t = (ns * f_mhz).div_ceil(1000);
    if t <= 127 {
        DeadTime { dtg: t as u8, ticks: t }
    } else if t <= 254 {
        // 10xxxxxx: (64 + DTG[5:0]) * 2
        let x = (t.div_ceil(2) - 64) as u8;
        DeadTime { dtg: 0x80 | x, ticks: (64 + x as u32) * 2 }
    } else if t <= 504 {
        // 110xxxxx: (32 + DTG[4:0]) * 8
        let x = (t.div_ceil(8) - 32) as u8;
        DeadTime { dtg: 0xC0 | x, ticks: (32 + x as u32) * 8 }
    } else {
        // 111xxxxx: (32 + DTG[4:0]) * 16, saturating at 63 * 16 = 1008 ticks.
        let mut x = t.div_ceil(16);
        if x > 63 {
            x = 63;
        }
        let x = (x - 32) as u8;
        DeadTime { dtg: 0xE0 | x, ticks: (32 + x as u32) * 16 }
    }
}

/// Half-period register value ARR for a centre-aligned carrier of `f_pwm_hz` (timer ticks),
/// clamped to 100..=65534 (so that CCR = ARR + 1 still fits the 16-bit compare register).
pub const fn pwm_arr(f_pwm_hz: u32, f_tim_hz: u32) -> u32 {
    let f = if f_pwm_hz == 0 { 1 } else { f_pwm_hz };
    let arr = f_tim_hz / (2 * f);
    if arr < 100 {
        100
    } else if arr > 65_534 {
        65_534
    } else {
        arr
    }
}

/// Highest high-side duty applied (fraction of the period). The phase currents are sampled at
/// the carrier valley, in the middle of the low-side on-time; above this duty that window is
/// too short for a valid low-side shunt sample: at 10 kHz, 0.95 leaves 2.5 us of low-side time
/// before the valley, 1.7 us after the 0.8 us dead time, against 1.3 us of settling measured
/// on this board after a switch turns off (github.com/diglet48/FOC-Stim, its ESC1 board
/// support). A current read as zero where it is not is what a current loop must never see.
/// NuttX's ESC1 board code uses the same 0.95 limit. Near full modulation (SVPWM peak duty
/// 0.5 + m/2, up to 0.975 at the drive's 0.95 modulation limit) this flattens the top of the
/// highest phase.
pub const MAX_DUTY: f32 = 0.95;

/// Duty fraction -> CCR for PWM mode 2 with half-period `arr`: clamped to 0..=[`MAX_DUTY`],
/// NaN -> 0.5, never panics.
#[inline]
pub fn duty_to_ccr(d: f32, arr: u32) -> u32 {
    // NaN -> 0.5; `clamp` with constant, ordered bounds cannot panic.
    let d = if d.is_nan() { 0.5 } else { d.clamp(0.0, MAX_DUTY) };
    // d in [0, 1] and arr <= 65534: the product is in [0, 65534.5], so the (saturating) `as`
    // conversion is exact-rounded and cannot overflow.
    let on = (d * arr as f32 + 0.5) as u32;
    let on = if on > arr { arr } else { on };
    if on == 0 {
        arr + 1 // CCR > ARR: OCxREF never active -> high side off, low side on all period.
    } else {
        arr - on
    }
}

impl Esc1PowerStage {
    fn new(tim: pac::TIM1, dac: pac::DAC3, comp: pac::COMP, config: &Esc1Config, trip_a: f32) -> Self {
        let arr = pwm_arr(config.pwm_frequency_hz, SYSCLK_HZ);
        let dt = dead_time_dtg(config.dead_time_ns, SYSCLK_HZ);

        tim.cr1().write(|w| {
            w.cms().center_aligned1();
            w.arpe().set_bit(); // ARR preloaded
            w.ckd().div1() // tDTS = tCK_INT (dead-time base)
        });
        tim.psc().write(|w| w.psc().set(0));
        tim.arr().write(|w| w.arr().set(arr));
        tim.rcr().write(|w| w.rep().set(0)); // first 0, set to 1 in `align_update_to_valley`

        // CH1..3: PWM mode 2, CCR preload; CH4 unused.
        tim.ccmr1_output().write(|w| {
            w.oc1m().pwm_mode2();
            w.oc1pe().set_bit();
            w.oc2m().pwm_mode2();
            w.oc2pe().set_bit()
        });
        tim.ccmr2_output().write(|w| {
            w.oc3m().pwm_mode2();
            w.oc3pe().set_bit()
        });
        let off = arr + 1;
        tim.ccr1().write(|w| w.ccr().set(off));
        tim.ccr2().write(|w| w.ccr().set(off));
        tim.ccr3().write(|w| w.ccr().set(off));

        // Idle states all low (both L6387 inputs active high: NuttX stm32_foc.c requires positive
        // polarity on CHx and CHxN), TRGO = TRGO2 = update event.
        tim.cr2().write(|w| {
            // SAFETY: MMS is 3 bits; 0b010 = "Update" (RM0440 TIMx_CR2).
            unsafe { w.mms().bits(0b010) };
            // SAFETY: MMS2 is 4 bits; 0b0010 = "Update" (RM0440 TIMx_CR2).
            unsafe { w.mms2().bits(0b0010) };
            w.ois1().clear_bit();
            w.ois1n().clear_bit();
            w.ois2().clear_bit();
            w.ois2n().clear_bit();
            w.ois3().clear_bit();
            w.ois3n().clear_bit()
        });
        // Outputs enabled at channel level, active-high, main output still off.
        tim.ccer().write(|w| {
            w.cc1e().set_bit();
            w.cc1ne().set_bit();
            w.cc2e().set_bit();
            w.cc2ne().set_bit();
            w.cc3e().set_bit();
            w.cc3ne().set_bit()
        });
        // Break sources (TIM1_AF1): COMP1, COMP2, COMP4, not inverted (BKCMPxP = 0); the BKIN
        // pin input off (BKINE resets to 1; no pin is in its alternate function, cleared anyway).
        // As MCSDK: TIM_BREAKINPUT_BRK from COMP1/2/4, POLARITY_HIGH.
        tim.af1().write(|w| {
            w.bkine().clear_bit();
            w.bkcmp1e().set_bit();
            w.bkcmp2e().set_bit();
            w.bkcmp4e().set_bit();
            w.bkcmp1p().clear_bit();
            w.bkcmp2p().clear_bit();
            w.bkcmp4p().clear_bit()
        });
        // Dead time; OSSI = OSSR = 1 so that with MOE = 0 the timer keeps *driving* all six pins
        // to their idle level (low = switch off) instead of releasing them (Hi-Z); break on,
        // active high, filtered over 8 samples of f_CK_INT (BKF = 3, 47 ns, as MCSDK); BRK2 off;
        // no automatic output enable (a break stays until software clears it); no lock.
        tim.bdtr().write(|w| {
            w.dtg().set(dt.dtg);
            w.ossi().set_bit();
            w.ossr().set_bit();
            w.bke().set_bit();
            w.bkp().set_bit();
            // SAFETY: BKF is 4 bits; 3 = f_CK_INT, N = 8 (RM0440 TIMx_BDTR).
            unsafe { w.bkf().bits(3) };
            w.bk2e().clear_bit();
            w.aoe().clear_bit();
            w.moe().clear_bit()
        });
        // Load ARR/PSC/CCR/RCR shadows.
        tim.egr().write(|w| w.ug().set_bit());
        tim.sr().write(|w| w.uif().clear());

        let mut s = Self { tim, dac, comp, arr, dtg: dt.dtg, trip_a, tripped: false };
        s.align_update_to_valley();
        // Break flags set while the comparators and the DAC came up (MOE was 0 throughout):
        // cleared; a break input that is *still* active stays latched (the drive then
        // reports it at its first step and never switches on).
        s.clear_hardware_trip();
        s
    }

    /// Whether a break (over-current comparators or a system break) has fired since the last
    /// re-arm: TIM1 `SR.BIF` / `SR.SBIF`.
    fn break_seen(&self) -> bool {
        let sr = self.tim.sr().read();
        sr.bif().bit_is_set() || sr.sbif().bit_is_set()
    }

    /// Comparator outputs of phases U, V, W now (`COMPx_CSR.VALUE`; `true` = that shunt's input
    /// is above the trip threshold). With no current all three must be `false`.
    pub fn comparators(&self) -> [bool; 3] {
        [
            self.comp.c1csr().read().value().bit_is_set(),
            self.comp.c2csr().read().value().bit_is_set(),
            self.comp.c4csr().read().value().bit_is_set(),
        ]
    }

    /// Hardware over-current trip in use (A, down a low-side shunt).
    pub fn over_current_trip_a(&self) -> f32 {
        self.trip_a
    }

    /// Sets the hardware over-current trip (A, clamped to [`OVER_CURRENT_TRIP_MIN_A`]..=
    /// [`OVER_CURRENT_TRIP_MAX_A`]) and returns the value in use: rewrites both DAC3 channels.
    /// Lower it to the motor's needs before enabling the bridge.
    pub fn set_over_current_trip_a(&mut self, trip_a: f32) -> f32 {
        self.trip_a = over_current_trip_clamped(trip_a);
        let code = over_current_dac_code(self.trip_a);
        self.dac.dhr12r1().write(|w| w.daccdhr().set(code));
        self.dac.dhr12r2().write(|w| w.daccdhr().set(code));
        self.trip_a
    }

    /// Starts the counter and arranges RCR = 1 so the single update event per period (which
    /// also loads the preloaded CCRs and fires TRGO/TRGO2) happens at the underflow (valley).
    ///
    /// Mechanism (RM0440 §28.3.3): in centre-aligned mode the repetition down-counter is
    /// decremented at every over- *and* underflow and UEV fires when it is 0, so with RCR = 1 the
    /// parity depends on the moment RCR is loaded. We start with RCR = 0 (UEV at both ends), wait
    /// for an overflow (counter now counting down, CR1.DIR = 1) and only then write RCR = 1: it is
    /// loaded at the next UEV (the coming underflow), after which UEV occurs at every underflow.
    fn align_update_to_valley(&mut self) {
        let tim = &self.tim;
        tim.cr1().modify(|_, w| w.cen().set_bit());
        // Up to a few periods; the bound avoids a hang if the timer were not clocked.
        let mut tries = 0u32;
        loop {
            tim.sr().write(|w| w.uif().clear()); // rc_w0: other flags are written 1 = untouched
            let mut spins = 0u32;
            while tim.sr().read().uif().bit_is_clear() && spins < 1_000_000 {
                spins += 1;
            }
            tries += 1;
            if tim.cr1().read().dir().bit_is_set() || tries > 8 {
                break; // just passed the peak (now counting down)
            }
        }
        tim.rcr().write(|w| w.rep().set(1));
        tim.sr().write(|w| w.uif().clear());
    }

    /// Half-period ARR (timer ticks). The carrier period is 2·ARR ticks of 1/170 MHz.
    pub fn arr(&self) -> u32 {
        self.arr
    }

    /// Carrier period (ns).
    pub fn period_ns(&self) -> u32 {
        // 2 * 65534 * 1000 < 2^32: plain 32-bit math.
        (2 * self.arr * 1000) / (SYSCLK_HZ / 1_000_000)
    }

    /// BDTR.DTG code in use (see [`dead_time_dtg`]).
    pub fn dtg(&self) -> u8 {
        self.dtg
    }

    /// Whether the main output enable is currently set (it is cleared by hardware on break).
    pub fn is_enabled(&self) -> bool {
        self.tim.bdtr().read().moe().bit_is_set()
    }
}

impl PowerStage for Esc1PowerStage {
    fn set_duties(&mut self, duties: [f32; 3]) {
        let arr = self.arr;
        let c1 = duty_to_ccr(duties[0], arr);
        let c2 = duty_to_ccr(duties[1], arr);
        let c3 = duty_to_ccr(duties[2], arr);
        // Preloaded: take effect together at the next valley update event.
        self.tim.ccr1().write(|w| w.ccr().set(c1));
        self.tim.ccr2().write(|w| w.ccr().set(c2));
        self.tim.ccr3().write(|w| w.ccr().set(c3));
    }

    fn enable_bridge(&mut self) {
        if self.hardware_trip() {
            return;
        }
        self.tim.bdtr().modify(|_, w| w.moe().set_bit());
        // A break between the check and the write: MOE may have been set after the hardware
        // cleared it; take it back and latch.
        if self.hardware_trip() {
            self.disable_bridge();
        }
    }

    fn disable_bridge(&mut self) {
        // MOE = 0 with OSSI = 1: all six outputs go to their idle level (low) at once.
        self.tim.bdtr().modify(|_, w| w.moe().clear_bit());
    }

    fn hardware_trip(&mut self) -> bool {
        if self.break_seen() {
            self.tripped = true;
        }
        self.tripped
    }

    fn clear_hardware_trip(&mut self) {
        // BIF/SBIF cannot be cleared while the break input is active: if they read set again
        // the cause is still there and the trip stays latched.
        self.tim.sr().write(|w| w.bif().clear().sbif().clear()); // rc_w0: others written 1
        self.tripped = self.break_seen();
    }
}

// =================================================================================================
// USART2 — RM0440 ch. 37 "USART": §37.5.7 baud rate (BRR = f_ck / baud, OVER8 = 0),
// USART_CR1/ISR/ICR/RDR/TDR. FIFO disabled.
// =================================================================================================

/// UART receive errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UartError {
    /// Receiver overrun (a byte was lost).
    Overrun,
    /// Framing error (stop bit missing; wrong baud?).
    Framing,
    /// Noise detected on a received bit.
    Noise,
    /// Parity error (cannot happen with 8N1, reported for completeness).
    Parity,
}

impl embedded_io::Error for UartError {
    fn kind(&self) -> embedded_io::ErrorKind {
        match self {
            UartError::Overrun => embedded_io::ErrorKind::OutOfMemory,
            _ => embedded_io::ErrorKind::InvalidData,
        }
    }
}

/// USART2, 8 data bits, no parity, 1 stop bit, on PB3 (TX) / PB4 (RX).
pub struct Esc1Uart {
    usart: pac::USART2,
}

impl Esc1Uart {
    fn new(usart: pac::USART2, gpiob: &pac::GPIOB, baud: u32, rx_irq: bool) -> Self {
        pin_af!(gpiob, PIN_UART_TX, 3);
        pin_af!(gpiob, PIN_UART_RX, 3);
        gpiob.pupdr().modify(|_, w| w.pupdr(PIN_UART_RX.pin).pull_up());

        let baud = if baud == 0 { DEFAULT_BAUD } else { baud };
        // Rounded BRR, >= 16 required with OVER8 = 0 (max ~10.6 Mbit/s at 170 MHz).
        let brr = (SYSCLK_HZ + baud / 2) / baud;
        let brr = brr.clamp(16, 0xFFFF) as u16;
        usart.cr1().write(|w| w.ue().clear_bit());
        usart.brr().write(|w| w.brr().set(brr));
        usart.cr1().write(|w| {
            w.te().set_bit();
            w.re().set_bit();
            w.rxneie().bit(rx_irq);
            w.ue().set_bit()
        });
        Self { usart }
    }

    /// Enables or disables the RX-not-empty interrupt (vector [`UART_IRQ`]).
    pub fn listen_rx(&mut self, enable: bool) {
        self.usart.cr1().modify(|_, w| w.rxneie().bit(enable));
    }

    /// Non-blocking read: `Ok(Some(byte))`, `Ok(None)` if nothing arrived, or a receive error
    /// (the error flag is cleared; the pending byte, if any, stays readable).
    pub fn try_read_byte(&mut self) -> Result<Option<u8>, UartError> {
        let isr = self.usart.isr().read();
        if isr.ore().bit_is_set() {
            self.usart.icr().write(|w| w.orecf().clear());
            return Err(UartError::Overrun);
        }
        if isr.fe().bit_is_set() {
            self.usart.icr().write(|w| w.fecf().clear());
            return Err(UartError::Framing);
        }
        if isr.nf().bit_is_set() {
            self.usart.icr().write(|w| w.ncf().clear());
            return Err(UartError::Noise);
        }
        if isr.pe().bit_is_set() {
            self.usart.icr().write(|w| w.pecf().clear());
            return Err(UartError::Parity);
        }
        if isr.rxne().bit_is_set() { Ok(Some(self.usart.rdr().read().rdr().bits() as u8)) } else { Ok(None) }
    }

    /// Blocking write of one byte (waits for TXE).
    pub fn write_byte(&mut self, b: u8) {
        while self.usart.isr().read().txe().bit_is_clear() {}
        self.usart.tdr().write(|w| w.tdr().set(u16::from(b)));
    }
}

impl embedded_io::ErrorType for Esc1Uart {
    type Error = UartError;
}

impl embedded_io::Write for Esc1Uart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        while self.usart.isr().read().tc().bit_is_clear() {}
        Ok(())
    }
}

impl embedded_io::Read for Esc1Uart {
    /// Blocks until at least one byte is available, then returns what is there (no further wait).
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let mut n = 0;
        for slot in buf.iter_mut() {
            let b = loop {
                match self.try_read_byte() {
                    Ok(Some(b)) => break Some(b),
                    Ok(None) if n == 0 => continue,
                    Ok(None) => break None,
                    // Bytes already taken are not lost: report them, the error shows next call.
                    Err(_) if n > 0 => break None,
                    Err(e) => return Err(e),
                }
            };
            match b {
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

impl embedded_io::ReadReady for Esc1Uart {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.usart.isr().read().rxne().bit_is_set())
    }
}

impl embedded_io::WriteReady for Esc1Uart {
    fn write_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.usart.isr().read().txe().bit_is_set())
    }
}

// =================================================================================================
// Status LED — PC6 push-pull output, set/reset through GPIOC_BSRR (atomic).
// =================================================================================================

/// Green user LED LD2 on PC6 ("high" = LED on, polarity assumed).
pub struct StatusLed {
    gpioc: pac::GPIOC,
}

impl StatusLed {
    fn new(gpioc: pac::GPIOC) -> Self {
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

// =================================================================================================
// Safe state from anywhere: panic, faults, an interrupt that cannot reach its state.
// =================================================================================================

/// Switches the bridge off without the [`Esc1PowerStage`] handle: clears TIM1 `BDTR.MOE`,
/// which with `OSSI = 1` drives all six gate inputs to their idle level (low, every
/// switch off) at once (RM0440 §28.3.16). For the panic handler, the fault handlers and
/// an interrupt that cannot reach its state; no allocation, a single register
/// read-modify-write. Before [`init`] has enabled TIM1's clock the write is ignored and
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
    // A volatile read: the page is changed by the debug probe, not by this program.
    let bytes = unsafe { core::ptr::read_volatile(ptr) };
    dcfo::motor_image::MotorImage::decode(&bytes)
}
