//! The ST B-G431B-ESC1's set-up arithmetic, without its registers: the values and the
//! decisions that [`b_g431b_esc1`](super) writes into TIM1, DAC3 and GPIOC, and the two
//! start-up procedures it runs on them (the over-current comparators' zero-current level,
//! the ADC trigger's alignment to the carrier valley), each behind a small trait that the
//! board implements on its registers and the tests implement on a model. Compiled on every
//! target, so that the host tests check what the board module computes; the board module
//! re-exports all of it.
//!
//! - **Dead time** ([`dead_time_setting`]): TIM1 inserts the only dead time on this board
//!   (the L6387E gate driver only blocks both inputs high at once and adds none of its own).
//!   A request below [`DEAD_TIME_FLOOR_NS`] or above what `BDTR.DTG` encodes is refused
//!   with [`Esc1InitError`], never rounded into range.
//! - **Over-current threshold** ([`measure_zero_current_codes`],
//!   [`over_current_thresholds`]): COMP1/2/4 compare each low-side shunt's op-amp *input*
//!   with a DAC3 threshold. The input's zero-current level depends on a bias network whose
//!   values no source pins down, so it is measured: with the bridge off, DAC3 sweeps up
//!   from 0 V and the first code at which a comparator reads low is that phase's
//!   zero-current level, in the comparator's own terms (its offset and the DAC's
//!   included). The trip code adds the trip current times the sensing gain, which the
//!   sources do agree on (`MCSDK` `AMPLIFICATION_GAIN` 9.14 over the PGA's 16). Cost: at
//!   most one DAC step per count up to the window's top ([`ZERO_CURRENT_WINDOW_CODES`], 310
//!   steps) of [`ZERO_CURRENT_SAMPLES`] reads and 5 µs of settling each, under 2 ms at
//!   start-up; resolution one DAC count, 0.47 A of trip current.
//! - **Valley alignment** ([`align_update_to_valley`]): TIM1's update event (which loads the
//!   duties and, as TRGO2, triggers the current conversions) must fall at the carrier
//!   valley, where the low-side switches conduct and the shunts carry the phase currents.
//!   Sampled at the peak instead, the shunts read about zero under load. The alignment is
//!   confirmed on [`VALLEY_CHECKS`] update events before initialisation goes on, and fails
//!   with [`Esc1InitError::TriggerNotAtValley`] after [`VALLEY_ALIGN_ATTEMPTS`] attempts.
//! - **Status LED** ([`led_bsrr`]): its polarity is a setting ([`LedPolarity`]), the
//!   default [`STATUS_LED_POLARITY`] (see there for the sources and how to confirm it).

use core::fmt;

/// System, AHB, APB1, APB2 and TIM1 kernel clock after the board's `init` (Hz).
pub const SYSCLK_HZ: u32 = 170_000_000;

// =================================================================================================
// Analog front end (sources: the board table in `b_g431b_esc1`).
// =================================================================================================

/// Low-side shunt resistance (ohm), one per phase. MCSDK RSHUNT 0.003; NuttX board README /
/// stm32_foc.c: 0.003; SimpleFOC ESC1 example `LowsideCurrentSense(0.003, ...)`.
pub const SHUNT_OHM: f32 = 0.003;
/// Internal PGA setting (V/V) for the non-inverting input: PGA_GAIN = 0b01011
/// ("gain 16 / -15 with VINM0"). NuttX stm32_foc.c, SimpleFOC (`OPAMP_PGA_GAIN_16_OR_MINUS_15`).
pub const PGA_GAIN: f32 = 16.0;
/// Net transfer of phase current times shunt resistance to OPAMP output (V/V), including the
/// board's input network and the PGA (16): -64/7 = -9.142857, negative because with
/// "positive into the motor" the current flows up through the low-side shunt and the amplified
/// voltage falls below the bias. MCSDK AMPLIFICATION_GAIN 9.14; SimpleFOC ESC1 example
/// `-64.0/7.0`; NuttX README "Current sense gain = -9.14 (inverted current)".
pub const CURRENT_SENSE_GAIN: f32 = -64.0 / 7.0;
/// Shunt voltage to op-amp input voltage (V/V), the input network's share of
/// [`CURRENT_SENSE_GAIN`]: 9.142857 / 16 = 4/7. The comparators see this node.
pub const SHUNT_INPUT_GAIN: f32 = -CURRENT_SENSE_GAIN / PGA_GAIN;
/// ADC and DAC reference / full-scale voltage (V): VDDA = VREF+ = 3.3 V on the board (its
/// 3.3 V regulator; UM2516).
pub const VREF_V: f32 = 3.3;
/// 12-bit converter codes per full scale (counts), ADC and DAC alike.
pub const CONVERTER_COUNTS: f32 = 4096.0;
/// DAC3 counts per ampere of shunt current at the comparator input (counts/A):
/// [`SHUNT_INPUT_GAIN`] · [`SHUNT_OHM`] / [`VREF_V`] · 4096 = 2.128 (one count is 0.47 A).
pub const DAC_COUNTS_PER_AMP: f32 = SHUNT_INPUT_GAIN * SHUNT_OHM / VREF_V * CONVERTER_COUNTS;

// =================================================================================================
// Dead time — TIMx_BDTR.DTG (RM0440, advanced-control timers, "Complementary outputs and
// dead-time insertion").
// =================================================================================================

/// Default dead time (ns). 800 ns = DTG 0x84 at 170 MHz: ST's MCSDK project for this board
/// (power_stage_parameters.h HW_DEAD_TIME_NS 800), as the pat92fr ESC1 CubeMX project
/// (DTG = 128 at 160 MHz).
pub const DEFAULT_DEAD_TIME_NS: u32 = 800;

/// Shortest dead time a configuration may ask for (ns). The L6387E inserts none (its
/// interlock only forces both outputs low while both inputs are high: DocID13990, input
/// logic truth table), so this is all that separates one switch's turn-off from the other's
/// turn-on. 500 ns is NuttX's nominal figure for this board (`PWM_DEADTIME_NS`, marked
/// "REVISIT"; its driver programs `DTG` = 20, 118 ns at 170 MHz, which is not a reference)
/// and the least any source states; ST's own project for the board runs 800 ns
/// ([`DEFAULT_DEAD_TIME_NS`]). The STL180N6F7's turn-off behind the driver's sink current is
/// characterised in none of the sources, so a shorter dead time needs a measurement on the
/// board (the gate voltages of one leg on a scope, at the bus voltage and current of the
/// application) and a change of this constant, not a configuration.
pub const DEAD_TIME_FLOOR_NS: u32 = 500;

/// Longest dead time `BDTR.DTG` encodes with `CKD` = 0 (timer ticks): (32 + 31) · 16.
pub const DEAD_TIME_MAX_TICKS: u32 = 1008;

/// The dead time TIM1 inserts: the `BDTR.DTG` code and what it means.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeadTime {
    /// TIMx_BDTR.DTG code.
    pub dtg: u8,
    /// Dead time obtained (timer ticks of 1/[`SYSCLK_HZ`]).
    pub ticks: u32,
}

impl DeadTime {
    /// The dead time obtained (ns, rounded down).
    pub const fn ns(&self) -> u32 {
        self.ticks * 1000 / (SYSCLK_HZ / 1_000_000)
    }
}

/// Timer ticks needed for at least `ns` nanoseconds at `f_hz` (whole MHz; exact for
/// 170 MHz), `ns` taken up to 100 µs (beyond any encodable dead time). 32-bit math only.
const fn dead_time_ticks(ns: u32, f_hz: u32) -> u32 {
    let ns = if ns > 100_000 { 100_000 } else { ns };
    // ceil(ns * f_MHz / 1000); 100_000 * 4294 fits u32 for any f_hz.
    (ns * (f_hz / 1_000_000)).div_ceil(1000)
}

/// Encodes a dead time of at least `ns` nanoseconds at timer clock `f_hz` (tDTS = 1/f_hz,
/// CKD = 0) into TIMx_BDTR.DTG (RM0440 TIMx_BDTR `DTG[7:0]`); saturates at
/// [`DEAD_TIME_MAX_TICKS`]. [`dead_time_setting`] is what the board uses: it refuses what
/// this would saturate, and anything below the floor.
pub const fn dead_time_dtg(ns: u32, f_hz: u32) -> DeadTime {
    let t = dead_time_ticks(ns, f_hz);
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
        // 111xxxxx: (32 + DTG[4:0]) * 16, saturating at 63 * 16.
        let mut x = t.div_ceil(16);
        if x > 63 {
            x = 63;
        }
        let x = (x - 32) as u8;
        DeadTime { dtg: 0xE0 | x, ticks: (32 + x as u32) * 16 }
    }
}

/// The dead time for a configured `ns` at [`SYSCLK_HZ`]: at least `ns`, or refused —
/// below [`DEAD_TIME_FLOOR_NS`] ([`Esc1InitError::DeadTimeBelowFloor`]) or longer than
/// `BDTR.DTG` encodes ([`Esc1InitError::DeadTimeAboveMaximum`]).
pub const fn dead_time_setting(ns: u32) -> Result<DeadTime, Esc1InitError> {
    if ns < DEAD_TIME_FLOOR_NS {
        return Err(Esc1InitError::DeadTimeBelowFloor { requested_ns: ns });
    }
    if dead_time_ticks(ns, SYSCLK_HZ) > DEAD_TIME_MAX_TICKS {
        return Err(Esc1InitError::DeadTimeAboveMaximum { requested_ns: ns });
    }
    Ok(dead_time_dtg(ns, SYSCLK_HZ))
}

// =================================================================================================
// Carrier — TIM1 centre-aligned mode 1, the repetition counter and the update event
// (RM0440, advanced-control timers, "Repetition counter").
// =================================================================================================

/// Default PWM carrier frequency (Hz): 10 kHz, i.e. 100 us period.
pub const DEFAULT_PWM_HZ: u32 = 10_000;

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

/// What the valley alignment needs of the carrier timer. The board implements it on TIM1
/// (`CR1.CEN`, `RCR.REP`, `SR.UIF`, `CR1.DIR`, `CNT`), the tests on a model of the
/// centre-aligned counter and its repetition counter.
pub trait CarrierTimer {
    /// Starts the counter (it runs from then on).
    fn start(&mut self);
    /// Writes the repetition counter register (`RCR.REP`); it takes effect at the next
    /// update event.
    fn set_repetition(&mut self, rep: u8);
    /// Clears the update flag and waits for the next update event: `false` if none comes
    /// within a bound of several carrier periods (the timer does not count).
    fn wait_update(&mut self) -> bool;
    /// The counter counts down now (`CR1.DIR`, read right after the event).
    fn counting_down(&self) -> bool;
    /// The counter now (`CNT`, timer ticks).
    fn count(&self) -> u32;
}

/// Update events that must all fall at the valley before the alignment is accepted.
pub const VALLEY_CHECKS: u32 = 4;
/// Alignment attempts before initialisation fails.
pub const VALLEY_ALIGN_ATTEMPTS: u32 = 3;
/// Update events waited for, in one attempt, to find one at the peak.
const PEAK_SEARCH_EVENTS: u32 = 4;

/// Which event of the carrier was checked against the valley.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(all(feature = "esc1", target_arch = "arm"), derive(defmt::Format))]
pub enum CarrierEvent {
    /// TIM1's update event (loads the duties, fires TRGO2).
    Update,
    /// The end of ADC1's injected conversions (the control interrupt's event).
    ConversionEnd,
}

/// Whether an event just seen (with the counter read right after it) followed the carrier
/// valley: the counter counts up and is in the first half of its rise. An event at the
/// peak reads counting down near `arr`.
pub const fn after_valley(counting_down: bool, count: u32, arr: u32) -> bool {
    !counting_down && count < arr / 2
}

/// Starts `timer` with its single update event per period at the valley, and confirms it.
///
/// In centre-aligned mode the repetition counter counts both over- and underflows and the
/// update event fires when it is 0, so with `REP` = 1 which extremum gets the event depends
/// on when `REP` was loaded. The counter starts with `REP` = 0 (an event at both ends); after
/// an event at the peak (counting down) `REP` = 1 is written, loaded at the coming event,
/// the valley, and from then on every event is at a valley. The next [`VALLEY_CHECKS`]
/// events are each checked with [`after_valley`]; a failed check restarts the procedure
/// (`REP` = 0 again), [`VALLEY_ALIGN_ATTEMPTS`] times at most.
///
/// # Errors
/// [`Esc1InitError::CarrierNotCounting`] when an update event does not come;
/// [`Esc1InitError::TriggerNotAtValley`] with the last event seen when no attempt
/// confirmed the alignment.
pub fn align_update_to_valley<T: CarrierTimer>(timer: &mut T, arr: u32) -> Result<(), Esc1InitError> {
    timer.start();
    let mut last = (false, 0);
    for _ in 0..VALLEY_ALIGN_ATTEMPTS {
        timer.set_repetition(0);
        let mut at_peak = false;
        for _ in 0..PEAK_SEARCH_EVENTS {
            if !timer.wait_update() {
                return Err(Esc1InitError::CarrierNotCounting);
            }
            if timer.counting_down() {
                at_peak = true;
                break;
            }
        }
        if !at_peak {
            last = (timer.counting_down(), timer.count());
            continue;
        }
        timer.set_repetition(1);
        let mut confirmed = true;
        for _ in 0..VALLEY_CHECKS {
            if !timer.wait_update() {
                return Err(Esc1InitError::CarrierNotCounting);
            }
            last = (timer.counting_down(), timer.count());
            if !after_valley(last.0, last.1, arr) {
                confirmed = false;
                break;
            }
        }
        if confirmed {
            return Ok(());
        }
    }
    Err(Esc1InitError::TriggerNotAtValley {
        event: CarrierEvent::Update,
        counting_down: last.0,
        count: last.1,
        arr,
    })
}

// =================================================================================================
// Hardware over-current trip — DAC3 thresholds for COMP1 (U, DAC3_CH1) and COMP2/COMP4 (V, W,
// both on DAC3_CH2), measured zero-current levels.
// =================================================================================================

/// One phase of the bridge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(all(feature = "esc1", target_arch = "arm"), derive(defmt::Format))]
pub enum Phase {
    /// Phase U: shunt 1, OPAMP1, COMP1, DAC3_CH1.
    U,
    /// Phase V: shunt 2, OPAMP2, COMP2, DAC3_CH2.
    V,
    /// Phase W: shunt 3, OPAMP3, COMP4, DAC3_CH2.
    W,
}

impl Phase {
    /// U, V, W in the order of every `[_; 3]` here.
    pub const ALL: [Phase; 3] = [Phase::U, Phase::V, Phase::W];
}

impl fmt::Display for Phase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Phase::U => "U",
            Phase::V => "V",
            Phase::W => "W",
        })
    }
}

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

/// DAC3 code (counts) of voltage `v` at the comparator inputs, rounded to nearest.
const fn dac_code(v: f32) -> u16 {
    (v / VREF_V * CONVERTER_COUNTS + 0.5) as u16
}

/// Window (DAC counts) the measured zero-current level of every comparator input must fall
/// in: 50 mV to 250 mV. The sources put it at 103 mV (the ~1.65 V zero-current output
/// measured on the SimpleFOC forum, over the PGA's 16, with VINM0 at 0 V) or 129 mV (the
/// forum's resistor values: 3.3 V · 3/77); outside the window the network is not what the
/// board was built with (an open or shorted resistor, an unpowered input) or the comparator
/// does not switch, and no threshold derived from it can be trusted.
pub const ZERO_CURRENT_WINDOW_CODES: (u16, u16) = (dac_code(0.05), dac_code(0.25));

/// Comparator reads per DAC code during the sweep: a phase's level is the first code at which
/// all of them read low (its input below the threshold).
pub const ZERO_CURRENT_SAMPLES: u32 = 8;

/// What the zero-current sweep needs of DAC3 and the comparators. The board implements it
/// on DAC3 (`DHR12R1/2`) and COMP1/2/4 (`CSR.VALUE`), the tests on a model of the inputs.
pub trait ShuntComparators {
    /// Sets both DAC3 channels (U's threshold, and V's and W's) to `code` and waits until
    /// the DAC and the comparators have settled.
    fn set_threshold(&mut self, code: u16);
    /// The comparator outputs of U, V, W now: `true` while that input is above its
    /// threshold.
    fn outputs(&mut self) -> [bool; 3];
}

/// Why a zero-current level was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(all(feature = "esc1", target_arch = "arm"), derive(defmt::Format))]
pub enum ZeroCurrentError {
    /// The comparator reads low with a 0 V threshold: its input is at 0 V or it cannot
    /// switch high (and so cannot trip).
    NeverHigh {
        /// The phase.
        phase: Phase,
    },
    /// The comparator still reads high at the top of [`ZERO_CURRENT_WINDOW_CODES`]: its
    /// input sits too high, or it cannot switch low (a trip that never releases).
    AboveWindow {
        /// The phase.
        phase: Phase,
    },
    /// The level is below [`ZERO_CURRENT_WINDOW_CODES`].
    BelowWindow {
        /// The phase.
        phase: Phase,
        /// The level measured (DAC counts).
        code: u16,
    },
}

impl fmt::Display for ZeroCurrentError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (lo, hi) = ZERO_CURRENT_WINDOW_CODES;
        match *self {
            ZeroCurrentError::NeverHigh { phase } => write!(
                f,
                "over-current comparator {phase} reads low at a 0 V threshold: its input is at 0 V or it cannot trip"
            ),
            ZeroCurrentError::AboveWindow { phase } => write!(
                f,
                "over-current comparator {phase} still reads high at {hi} counts: its input is above the window ({lo}..={hi} counts) or it cannot release"
            ),
            ZeroCurrentError::BelowWindow { phase, code } => write!(
                f,
                "over-current comparator {phase}'s zero-current level {code} counts is below the window ({lo}..={hi} counts)"
            ),
        }
    }
}

/// Measures each phase's zero-current level at the comparator (DAC counts): with the bridge
/// off and no current, the threshold starts at 0 V, where every comparator must read high,
/// and steps up one count at a time; a phase's level is the first code at which its
/// comparator reads low in all [`ZERO_CURRENT_SAMPLES`] reads. Leaves the threshold at the
/// last code swept. Preconditions: bridge off (no shunt current), nothing else driving DAC3.
///
/// # Errors
/// [`ZeroCurrentError`] naming the first phase whose comparator does not switch high at
/// 0 V, does not switch low inside the window, or switches below it.
pub fn measure_zero_current_codes<C: ShuntComparators>(c: &mut C) -> Result<[u16; 3], ZeroCurrentError> {
    let (lo, hi) = ZERO_CURRENT_WINDOW_CODES;
    c.set_threshold(0);
    let mut high = [true; 3];
    for _ in 0..ZERO_CURRENT_SAMPLES {
        let out = c.outputs();
        for (h, o) in high.iter_mut().zip(out) {
            *h &= o;
        }
    }
    if let Some(p) = high.iter().position(|h| !h) {
        return Err(ZeroCurrentError::NeverHigh { phase: Phase::ALL[p] });
    }
    let mut level: [Option<u16>; 3] = [None; 3];
    for code in 1..=hi {
        c.set_threshold(code);
        let mut low = [true; 3];
        for _ in 0..ZERO_CURRENT_SAMPLES {
            let out = c.outputs();
            for (l, o) in low.iter_mut().zip(out) {
                *l &= !o;
            }
        }
        for (lv, l) in level.iter_mut().zip(low) {
            if lv.is_none() && l {
                *lv = Some(code);
            }
        }
        if level.iter().all(Option::is_some) {
            break;
        }
    }
    let mut codes = [0u16; 3];
    for ((code, lv), phase) in codes.iter_mut().zip(level).zip(Phase::ALL) {
        match lv {
            None => return Err(ZeroCurrentError::AboveWindow { phase }),
            Some(c) if c < lo => return Err(ZeroCurrentError::BelowWindow { phase, code: c }),
            Some(c) => *code = c,
        }
    }
    Ok(codes)
}

/// The DAC3 thresholds of a trip current over measured zero-current levels, and the trip
/// each phase then gets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OverCurrentThresholds {
    /// DAC3_CH1 code (COMP1, phase U; counts).
    pub dac_ch1: u16,
    /// DAC3_CH2 code (COMP2 and COMP4, phases V and W; counts).
    pub dac_ch2: u16,
    /// The trip current each phase gets, U, V, W (A, down its low-side shunt): the request
    /// less up to one DAC count (0.47 A); V's or W's lower still by the difference of their
    /// zero-current levels, since they share a threshold.
    pub trip_a: [f32; 3],
}

/// The thresholds for a trip at `trip_a` amperes (clamped as [`over_current_trip_clamped`])
/// above the zero-current levels `zero` (U, V, W; DAC counts, from
/// [`measure_zero_current_codes`]): level + ⌊trip · [`DAC_COUNTS_PER_AMP`]⌋, rounded down so
/// that no phase trips above the request. V and W share DAC3_CH2, which is set from the
/// lower of their two levels: the other phase trips lower, never higher.
pub fn over_current_thresholds(trip_a: f32, zero: [u16; 3]) -> OverCurrentThresholds {
    let i = over_current_trip_clamped(trip_a);
    // In range by the clamp: 21..=95 counts (floor of 10 A .. 45 A times 2.128).
    let delta = (i * DAC_COUNTS_PER_AMP) as u16;
    let dac_ch1 = zero[0].saturating_add(delta);
    let dac_ch2 = zero[1].min(zero[2]).saturating_add(delta);
    let trip = |code: u16, level: u16| f32::from(code.saturating_sub(level)) / DAC_COUNTS_PER_AMP;
    OverCurrentThresholds {
        dac_ch1,
        dac_ch2,
        trip_a: [trip(dac_ch1, zero[0]), trip(dac_ch2, zero[1]), trip(dac_ch2, zero[2])],
    }
}

/// A DAC3 code (counts) as volts at the comparator inputs.
pub fn dac_code_volts(code: u16) -> f32 {
    f32::from(code) * VREF_V / CONVERTER_COUNTS
}

// =================================================================================================
// Status LED — PC6, set and reset atomically through GPIOC_BSRR.
// =================================================================================================

/// Which pin level lights the status LED.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LedPolarity {
    /// The LED lights with the pin high (LED and resistor from the pin to ground).
    ActiveHigh,
    /// The LED lights with the pin low (LED and resistor from 3.3 V to the pin).
    ActiveLow,
}

/// Polarity of the status LED on PC6 (the board's "D4", red) unless configured otherwise:
/// active low. The sources disagree: Zephyr's board file names it from the schematic,
/// "D4 LED RED STATUS", `GPIO_ACTIVE_LOW`; ST's own Arduino variant calls PC6 `LED_RED`
/// (no polarity); NuttX's board files call it a green "User LD2" and drive it active high,
/// in text that reads as copied from a Nucleo board. The first power-up checklist confirms
/// it: with the drive disabled the LED is dark, and the drive image lights it for its lamp
/// test at start-up; if it is lit while disabled, set the other polarity.
pub const STATUS_LED_POLARITY: LedPolarity = LedPolarity::ActiveLow;

/// The GPIOx_BSRR word that makes the LED on `pin` `lit` (or dark) with `polarity`: `BSn`
/// (bit n) drives the pin high, `BRn` (bit n + 16) low; every other pin is left alone.
/// `pin` is 0..=15.
pub const fn led_bsrr(lit: bool, polarity: LedPolarity, pin: u8) -> u32 {
    let high = match polarity {
        LedPolarity::ActiveHigh => lit,
        LedPolarity::ActiveLow => !lit,
    };
    let n = (pin & 0x0F) as u32;
    if high { 1 << n } else { 1 << (n + 16) }
}

/// Whether the LED is lit with the pin's output latch at `pin_high` (GPIOx_ODR).
pub const fn led_lit(pin_high: bool, polarity: LedPolarity) -> bool {
    match polarity {
        LedPolarity::ActiveHigh => pin_high,
        LedPolarity::ActiveLow => !pin_high,
    }
}

// =================================================================================================
// What initialisation refuses.
// =================================================================================================

/// Why the board's `init` refused to bring the board up. The bridge is off whichever: the
/// gate pins are still in their reset state (analog, the driver's pull-downs hold every
/// switch off) and TIM1's main output is disabled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(all(feature = "esc1", target_arch = "arm"), derive(defmt::Format))]
pub enum Esc1InitError {
    /// The configured dead time is below [`DEAD_TIME_FLOOR_NS`].
    DeadTimeBelowFloor {
        /// What was configured (ns).
        requested_ns: u32,
    },
    /// The configured dead time is longer than `BDTR.DTG` encodes
    /// ([`DEAD_TIME_MAX_TICKS`]).
    DeadTimeAboveMaximum {
        /// What was configured (ns).
        requested_ns: u32,
    },
    /// A comparator's zero-current level could not be measured or is implausible, so no
    /// over-current threshold can be set from it.
    ZeroCurrentLevel(ZeroCurrentError),
    /// TIM1 produced no update event: the carrier does not run.
    CarrierNotCounting,
    /// The ADC trigger is not at the carrier valley: the shunts would be sampled while the
    /// low-side switches are off.
    TriggerNotAtValley {
        /// The event checked.
        event: CarrierEvent,
        /// `CR1.DIR` right after it (`true`: counting down).
        counting_down: bool,
        /// `CNT` right after it (timer ticks).
        count: u32,
        /// The carrier's half period `ARR` (timer ticks).
        arr: u32,
    },
    /// The injected conversions (the control interrupt's event) did not end after the
    /// carrier valley within a few periods.
    NoConversion,
}

impl From<ZeroCurrentError> for Esc1InitError {
    fn from(e: ZeroCurrentError) -> Self {
        Esc1InitError::ZeroCurrentLevel(e)
    }
}

impl fmt::Display for Esc1InitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Esc1InitError::DeadTimeBelowFloor { requested_ns } => write!(
                f,
                "dead time {requested_ns} ns refused: below the floor of {DEAD_TIME_FLOOR_NS} ns (the L6387E adds no dead time of its own; a shorter one needs a measurement on the board)"
            ),
            Esc1InitError::DeadTimeAboveMaximum { requested_ns } => write!(
                f,
                "dead time {requested_ns} ns refused: TIM1 encodes at most {} ns",
                DeadTime { dtg: 0xFF, ticks: DEAD_TIME_MAX_TICKS }.ns()
            ),
            Esc1InitError::ZeroCurrentLevel(e) => write!(f, "{e}"),
            Esc1InitError::CarrierNotCounting => f.write_str("TIM1 does not count: no update event"),
            Esc1InitError::TriggerNotAtValley { event, counting_down, count, arr } => write!(
                f,
                "the {} is not at the carrier valley: counter {count} of {arr}, counting {} (the shunts would be sampled with the low-side switches off)",
                match event {
                    CarrierEvent::Update => "update event (ADC trigger)",
                    CarrierEvent::ConversionEnd => "end of the current conversions",
                },
                if counting_down { "down" } else { "up" }
            ),
            Esc1InitError::NoConversion => {
                f.write_str("no end of the current conversions: the ADC is not triggered by TIM1")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::format;

    // ---- Dead time.

    /// The DTG encoding against RM0440's four ranges at 170 MHz (tDTS = 5.88 ns), values
    /// worked out by hand from the register description.
    #[test]
    fn dead_time_codes_follow_the_reference_manual() {
        // 800 ns = 136 ticks = (64 + 4) * 2: range 10xxxxxx, x = 4.
        assert_eq!(dead_time_dtg(800, SYSCLK_HZ), DeadTime { dtg: 0x84, ticks: 136 });
        // 500 ns = 85 ticks: range 0xxxxxxx, DTG = 85.
        assert_eq!(dead_time_dtg(500, SYSCLK_HZ), DeadTime { dtg: 85, ticks: 85 });
        // 1 us = 170 ticks = (64 + 21) * 2.
        assert_eq!(dead_time_dtg(1000, SYSCLK_HZ), DeadTime { dtg: 0x80 | 21, ticks: 170 });
        // 2 us = 340 ticks -> ceil(340 / 8) = 43 = 32 + 11: 344 ticks.
        assert_eq!(dead_time_dtg(2000, SYSCLK_HZ), DeadTime { dtg: 0xC0 | 11, ticks: 344 });
        // 5 us = 850 ticks -> ceil(850 / 16) = 54 = 32 + 22: 864 ticks.
        assert_eq!(dead_time_dtg(5000, SYSCLK_HZ), DeadTime { dtg: 0xE0 | 22, ticks: 864 });
        // Never shorter than asked, one range's step at most longer.
        for ns in (DEAD_TIME_FLOOR_NS..=5929).step_by(7) {
            let d = dead_time_dtg(ns, SYSCLK_HZ);
            let exact = f64::from(ns) * 0.17;
            assert!(f64::from(d.ticks) >= exact - 1e-9, "{ns} ns -> {d:?}");
            assert!(f64::from(d.ticks) < exact + 16.0, "{ns} ns -> {d:?}");
        }
    }

    /// Below the floor or beyond what DTG encodes a configuration is refused, naming what
    /// was asked; the default and the floor itself are accepted.
    #[test]
    fn dead_times_below_the_floor_or_beyond_the_register_are_refused() {
        for ns in [0, 1, 100, 118, DEAD_TIME_FLOOR_NS - 1] {
            let e = dead_time_setting(ns).unwrap_err();
            assert_eq!(e, Esc1InitError::DeadTimeBelowFloor { requested_ns: ns });
            let text = format!("{e}");
            assert!(text.contains(&format!("{ns} ns refused")) && text.contains("floor of 500 ns"), "{text}");
        }
        assert_eq!(dead_time_setting(DEAD_TIME_FLOOR_NS), Ok(DeadTime { dtg: 85, ticks: 85 }));
        assert_eq!(dead_time_setting(DEFAULT_DEAD_TIME_NS), Ok(DeadTime { dtg: 0x84, ticks: 136 }));
        // 1008 ticks = 5929.4 ns: 5929 ns fits, 5930 ns does not.
        assert_eq!(dead_time_setting(5929), Ok(DeadTime { dtg: 0xFF, ticks: 1008 }));
        for ns in [5930, 10_000, u32::MAX] {
            let e = dead_time_setting(ns).unwrap_err();
            assert_eq!(e, Esc1InitError::DeadTimeAboveMaximum { requested_ns: ns });
            assert!(format!("{e}").contains("at most 5929 ns"), "{e}");
        }
    }

    #[test]
    fn the_carrier_half_period_is_the_timer_clock_over_twice_the_carrier() {
        // 10 kHz: 170 MHz / 20 kHz = 8500 ticks (100 us period).
        assert_eq!(pwm_arr(DEFAULT_PWM_HZ, SYSCLK_HZ), 8500);
        assert_eq!(pwm_arr(20_000, SYSCLK_HZ), 4250);
        assert_eq!((pwm_arr(0, SYSCLK_HZ), pwm_arr(10_000_000, SYSCLK_HZ)), (65_534, 100));
    }

    // ---- Valley alignment, on a model of TIM1's counter.

    /// TIM1 in centre-aligned mode 1 as RM0440 describes it, one tick at a time: the
    /// counter runs 0 -> ARR -> 0; at each over- and underflow the repetition counter is
    /// decremented, or, when it is 0, the update event fires and reloads it from `REP`.
    /// The CPU reads `DIR` and `CNT` `latency` ticks after the event it waited for.
    struct ModelTimer {
        arr: u32,
        cnt: u32,
        down: bool,
        rep: u8,
        rep_counter: u8,
        running: bool,
        latency: u32,
        /// Ticks from start to the CPU's write of `REP` (a write that comes late).
        rep_write_delay: u32,
        /// `REP` writes are lost (a timer that ignores them).
        rep_ignored: bool,
        updates: u32,
    }

    impl ModelTimer {
        fn new(arr: u32) -> Self {
            ModelTimer {
                arr,
                cnt: 0,
                down: false,
                rep: 0,
                rep_counter: 0,
                running: false,
                latency: 20,
                rep_write_delay: 0,
                rep_ignored: false,
                updates: 0,
            }
        }

        /// One timer tick; `true` if it ended with an update event.
        fn tick(&mut self) -> bool {
            if !self.running {
                return false;
            }
            let extremum = if self.down {
                self.cnt -= 1;
                if self.cnt == 0 {
                    self.down = false;
                    true
                } else {
                    false
                }
            } else {
                self.cnt += 1;
                if self.cnt == self.arr {
                    self.down = true;
                    true
                } else {
                    false
                }
            };
            if !extremum {
                return false;
            }
            if self.rep_counter == 0 {
                self.rep_counter = self.rep;
                self.updates += 1;
                true
            } else {
                self.rep_counter -= 1;
                false
            }
        }
    }

    impl CarrierTimer for ModelTimer {
        fn start(&mut self) {
            self.running = true;
        }
        fn set_repetition(&mut self, rep: u8) {
            for _ in 0..self.rep_write_delay {
                self.tick();
            }
            if !self.rep_ignored {
                self.rep = rep;
            }
        }
        fn wait_update(&mut self) -> bool {
            if !self.running {
                return false;
            }
            for _ in 0..4 * self.arr {
                if self.tick() {
                    for _ in 0..self.latency {
                        self.tick();
                    }
                    return true;
                }
            }
            false
        }
        fn counting_down(&self) -> bool {
            self.down
        }
        fn count(&self) -> u32 {
            self.cnt
        }
    }

    /// Run on the model, the procedure leaves exactly one update event per period, at
    /// every valley: the events that follow are each a full period (2 ARR ticks) apart and
    /// each finds the counter rising from 0.
    #[test]
    fn the_update_event_is_aligned_to_the_valley_and_stays_there() {
        let arr = pwm_arr(DEFAULT_PWM_HZ, SYSCLK_HZ);
        let mut t = ModelTimer::new(arr);
        assert_eq!(align_update_to_valley(&mut t, arr), Ok(()));
        assert_eq!(t.rep, 1);
        while !t.tick() {}
        for _ in 0..10 {
            let mut ticks = 0;
            while !t.tick() {
                ticks += 1;
            }
            assert_eq!((t.down, t.cnt), (false, 0), "an update event at the valley");
            assert_eq!(ticks + 1, 2 * arr, "one event per period");
        }
    }

    /// A `REP` write that lands after the valley it was meant for puts the event at the
    /// peak; the check sees it and the next attempt aligns it.
    #[test]
    fn a_late_repetition_write_is_seen_and_aligned_on_a_later_attempt() {
        let arr = 8500;
        let mut t = ModelTimer::new(arr);
        // More than half a period late: the event after the write is the peak's.
        t.rep_write_delay = arr + arr / 2;
        let first = align_update_to_valley(&mut t, arr);
        // Every attempt's write is late by the same amount, so every attempt fails: the
        // error names the event at the peak.
        match first {
            Err(Esc1InitError::TriggerNotAtValley {
                event: CarrierEvent::Update,
                counting_down,
                count,
                arr: a,
            }) => {
                assert!(counting_down && count > arr / 2 && a == arr, "{first:?}");
            }
            other => panic!("{other:?}"),
        }
        // A write late by less than the falling half-period still lands before the valley.
        let mut t = ModelTimer::new(arr);
        t.rep_write_delay = arr / 2;
        assert_eq!(align_update_to_valley(&mut t, arr), Ok(()));
    }

    /// A timer that ignores the repetition counter (an event at both ends) or does not
    /// count makes initialisation fail with the named error, never silently.
    #[test]
    fn a_timer_that_ignores_the_repetition_counter_or_does_not_count_fails_initialisation() {
        let arr = 8500;
        let mut t = ModelTimer::new(arr);
        t.rep_ignored = true;
        let e = align_update_to_valley(&mut t, arr).unwrap_err();
        assert!(
            matches!(e, Esc1InitError::TriggerNotAtValley { counting_down: true, .. }),
            "an event at the peak: {e:?}"
        );
        assert!(format!("{e}").contains("not at the carrier valley"), "{e}");
        struct Stopped;
        impl CarrierTimer for Stopped {
            fn start(&mut self) {}
            fn set_repetition(&mut self, _: u8) {}
            fn wait_update(&mut self) -> bool {
                false
            }
            fn counting_down(&self) -> bool {
                false
            }
            fn count(&self) -> u32 {
                0
            }
        }
        assert_eq!(align_update_to_valley(&mut Stopped, arr), Err(Esc1InitError::CarrierNotCounting));
    }

    #[test]
    fn events_after_the_valley_are_told_from_events_at_the_peak() {
        let arr = 8500;
        assert!(after_valley(false, 3, arr));
        // The injected sequence ends about 2 us (340 ticks) after the valley.
        assert!(after_valley(false, 340, arr));
        assert!(!after_valley(true, arr - 3, arr));
        assert!(!after_valley(false, arr - 3, arr));
        assert!(!after_valley(true, 3, arr));
    }

    // ---- Over-current thresholds, on a model of the comparator inputs.

    /// Three comparator inputs at `input_v` (V), with `noise_v` of peak-to-peak noise
    /// cycling through the reads, compared with DAC3 (both channels at one code, 12-bit
    /// over 3.3 V) plus `offset_v` (the comparator's and the DAC's offset together).
    struct ModelInputs {
        input_v: [f32; 3],
        offset_v: f32,
        noise_v: f32,
        code: u16,
        reads: u32,
        stuck: [Option<bool>; 3],
    }

    impl ModelInputs {
        fn new(input_v: [f32; 3]) -> Self {
            ModelInputs { input_v, offset_v: 0.0, noise_v: 0.0, code: 0, reads: 0, stuck: [None; 3] }
        }
    }

    impl ShuntComparators for ModelInputs {
        fn set_threshold(&mut self, code: u16) {
            self.code = code;
        }
        fn outputs(&mut self) -> [bool; 3] {
            self.reads += 1;
            let n = self.noise_v * ((self.reads % 4) as f32 / 3.0 - 0.5);
            let threshold = dac_code_volts(self.code) + self.offset_v;
            core::array::from_fn(|p| self.stuck[p].unwrap_or(self.input_v[p] + n > threshold))
        }
    }

    /// The sweep finds each input's level to the DAC count: the first code whose voltage
    /// reaches the input (plus the offset and the noise's positive peak).
    #[test]
    fn the_sweep_finds_each_zero_current_level_to_one_count() {
        // The two levels the sources imply (103 mV and 129 mV) and one in between: the
        // first code at or above each, ceil(v / 3.3 V * 4096).
        let inputs = [0.1031f32, 0.1286, 0.115];
        let mut m = ModelInputs::new(inputs);
        assert_eq!(measure_zero_current_codes(&mut m), Ok([128, 160, 143]));
        for (code, v) in [128u16, 160, 143].iter().zip(inputs) {
            assert!(dac_code_volts(*code) >= v && dac_code_volts(*code - 1) < v, "{v} V -> {code}");
        }
        // A comparator that switches 5 mV above the DAC's voltage (its offset and the
        // DAC's) and 2 mV of noise move the level with them: the threshold is set in the
        // comparator's own terms.
        let mut m = ModelInputs::new([0.1031; 3]);
        m.offset_v = -0.005;
        m.noise_v = 0.002;
        let codes = measure_zero_current_codes(&mut m).unwrap();
        let with = (0.1031f32 + 0.001 + 0.005) / 3.3 * 4096.0;
        for code in codes {
            assert!((f32::from(code) - with).abs() <= 1.0, "{code} vs {with}");
        }
    }

    /// An input at 0 V, a comparator stuck low or high, an input outside the window: each
    /// refused, naming the phase.
    #[test]
    fn implausible_zero_current_levels_are_refused_naming_the_phase() {
        let mut m = ModelInputs::new([0.103, 0.0, 0.103]);
        assert_eq!(measure_zero_current_codes(&mut m), Err(ZeroCurrentError::NeverHigh { phase: Phase::V }));
        let mut m = ModelInputs::new([0.103; 3]);
        m.stuck[2] = Some(false);
        assert_eq!(measure_zero_current_codes(&mut m), Err(ZeroCurrentError::NeverHigh { phase: Phase::W }));
        let mut m = ModelInputs::new([0.103; 3]);
        m.stuck[0] = Some(true);
        assert_eq!(
            measure_zero_current_codes(&mut m),
            Err(ZeroCurrentError::AboveWindow { phase: Phase::U })
        );
        let mut m = ModelInputs::new([0.103, 0.30, 0.103]);
        assert_eq!(
            measure_zero_current_codes(&mut m),
            Err(ZeroCurrentError::AboveWindow { phase: Phase::V })
        );
        let mut m = ModelInputs::new([0.103, 0.103, 0.02]);
        let e = measure_zero_current_codes(&mut m).unwrap_err();
        assert!(matches!(e, ZeroCurrentError::BelowWindow { phase: Phase::W, code } if code < 62), "{e:?}");
        assert!(format!("{}", Esc1InitError::from(e)).contains("comparator W"), "{e}");
        assert_eq!(ZERO_CURRENT_WINDOW_CODES, (62, 310));
    }

    /// The threshold codes from measured levels: 4/7 of 3 mOhm per ampere at the
    /// comparator (2.128 counts/A), rounded down; the trip each phase gets is the request
    /// within one count below it, and V/W share the lower level's threshold.
    #[test]
    fn thresholds_sit_the_trip_current_above_each_measured_level() {
        assert!((SHUNT_INPUT_GAIN - 4.0 / 7.0).abs() < 1e-6);
        assert!((DAC_COUNTS_PER_AMP - 4.0 / 7.0 * 0.003 / 3.3 * 4096.0).abs() < 1e-4);
        // Levels of the ~1.65 V reading (103 mV: 128 counts) on all three phases: 40 A is
        // 85.1 counts -> 85 above, 39.95 A.
        let t = over_current_thresholds(40.0, [128, 128, 128]);
        assert_eq!((t.dac_ch1, t.dac_ch2), (213, 213));
        for trip in t.trip_a {
            assert!(trip <= 40.0 && trip > 40.0 - 1.0 / DAC_COUNTS_PER_AMP, "{trip}");
        }
        // The guessed bias (129 mV, 160 counts) applied to a board at 103 mV trips 32
        // counts (15 A) high: the error the measurement removes.
        let guessed = over_current_thresholds(40.0, [160; 3]).dac_ch1;
        let actual_trip = f32::from(guessed - 128) / DAC_COUNTS_PER_AMP;
        assert!((actual_trip - 55.0).abs() < 0.5, "{actual_trip}");
        // V and W apart by 4 counts: one threshold from the lower, the other phase trips
        // 1.9 A lower, never above the request.
        let t = over_current_thresholds(30.0, [130, 126, 130]);
        assert_eq!((t.dac_ch1, t.dac_ch2), (130 + 63, 126 + 63));
        assert!(t.trip_a[1] <= 30.0 && t.trip_a[1] > 29.5);
        assert!((t.trip_a[1] - t.trip_a[2] - 4.0 / DAC_COUNTS_PER_AMP).abs() < 1e-4);
        // Clamped requests (and NaN -> the default).
        assert_eq!(over_current_thresholds(1000.0, [128; 3]).dac_ch1, 128 + 95);
        assert_eq!(over_current_thresholds(0.0, [128; 3]).dac_ch1, 128 + 21);
        assert_eq!(over_current_thresholds(f32::NAN, [128; 3]), over_current_thresholds(40.0, [128; 3]));
    }

    // ---- Status LED.

    /// PC6: BS6 is bit 6, BR6 bit 22; the polarity picks which lights the LED.
    #[test]
    fn the_led_word_sets_or_resets_only_its_pin_by_polarity() {
        assert_eq!(led_bsrr(true, LedPolarity::ActiveLow, 6), 0x0040_0000);
        assert_eq!(led_bsrr(false, LedPolarity::ActiveLow, 6), 0x0000_0040);
        assert_eq!(led_bsrr(true, LedPolarity::ActiveHigh, 6), 0x0000_0040);
        assert_eq!(led_bsrr(false, LedPolarity::ActiveHigh, 6), 0x0040_0000);
        for polarity in [LedPolarity::ActiveHigh, LedPolarity::ActiveLow] {
            for lit in [false, true] {
                let pin_high = led_bsrr(lit, polarity, 6) == 1 << 6;
                assert_eq!(led_lit(pin_high, polarity), lit);
            }
        }
        assert_eq!(STATUS_LED_POLARITY, LedPolarity::ActiveLow);
    }
}
