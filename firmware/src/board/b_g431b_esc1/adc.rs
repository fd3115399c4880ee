//! Current and bus-voltage sensing: OPAMP1/2/3 in PGA mode on the low-side shunts, ADC1/2
//! injected conversions triggered by TIM1 at the carrier valley, and [`Esc1Sensors`]
//! ([`PhaseSensors`]).

use stm32g4::stm32g431 as pac;

use crate::board::esc1_settings::{CURRENT_SENSE_GAIN, SHUNT_OHM, SYSCLK_HZ, VREF_V};
use crate::board::{PhaseSample, PhaseSensors};

/// ADC1 channel of the OPAMP1 output (VOPAMP1 = ADC1_IN13, internal; RM0440 ADC connectivity).
pub const ADC1_CH_I_U: u8 = 13;
/// ADC1 channel of the DC-bus divider (ADC1_IN1 = PA0).
pub const ADC1_CH_VBUS: u8 = 1;
/// ADC2 channel of the OPAMP2 output (VOPAMP2 = ADC2_IN16, internal).
pub const ADC2_CH_I_V: u8 = 16;
/// ADC2 channel of the OPAMP3 output (VOPAMP3 = ADC2_IN18, internal on ADC2).
pub const ADC2_CH_I_W: u8 = 18;
/// ADC1 channel of OPAMP1's input VINP0 = COMP1's input (PA1 = ADC1_IN2; NuttX board.h).
pub const ADC1_CH_SHUNT_INPUT_U: u8 = 2;
/// ADC2 channel of OPAMP2's input VINP0 = COMP2's input (PA7 = ADC2_IN4; NuttX STM32G4 pin map).
pub const ADC2_CH_SHUNT_INPUT_V: u8 = 4;
/// ADC1 channel of OPAMP3's input VINP0 = COMP4's input (PB0 = ADC1_IN15; NuttX board.h).
pub const ADC1_CH_SHUNT_INPUT_W: u8 = 15;

/// Interrupt that signals "injected sequence of ADC1 finished" = the control interrupt.
/// ADC1 and ADC2 share this vector (RM0440 vector table: `ADC1_2`, IRQ 18).
pub const CONTROL_IRQ: pac::Interrupt = pac::Interrupt::ADC1_2;

// -------------------------------------------------------------------------------------------------
// Analog front-end constants (board facts; sources in the board table above).
// -------------------------------------------------------------------------------------------------

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

// =================================================================================================
// OPAMP — RM0440 ch. 25 "Operational amplifiers (OPAMP)", §25.3.5 PGA mode with external
// bias on VINM0, OPAMPx_CSR.
// =================================================================================================

pub(super) fn init_opamps(opamp: &pac::OPAMP) {
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

pub(super) fn init_adcs(adc1: &pac::ADC1, adc2: &pac::ADC2, common: &pac::ADC12_COMMON) {
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

/// Sampling time of the shunt-input channels (code 4 = 47.5 cycles = 1.12 us): the network
/// behind the op-amp inputs is about a kiloohm.
const SMP_SHUNT_INPUT: u8 = 4;
/// Polls of `ISR.EOC` before a regular conversion counts as lost (a conversion takes well
/// under a microsecond; injected conversions may delay it by their own couple).
const REGULAR_CONVERSION_SPINS: u32 = 100_000;

/// One software-started regular conversion of `ch` (counts), `None` if it does not end.
/// Injected conversions keep their priority (RM0440: a regular conversion is interrupted
/// by an injected trigger and resumes after it). Never inlined: its caller runs it in
/// a loop at start-up, which inlined it unrolled 48 times (1.5 KB of flash).
#[inline(never)]
fn convert_regular(adc: &pac::adc1::RegisterBlock, ch: u8) -> Option<u16> {
    adc.isr().write(|w| w.eoc().clear().eos().clear().ovr().clear());
    // SAFETY: SQ1 is a 5-bit channel number; 2, 4 and 15 are existing ADC1/ADC2 channels.
    adc.sqr1().write(|w| unsafe { w.l().set(0).sq(0).bits(ch) });
    adc.cr().modify(|_, w| w.adstart().set_bit());
    let mut spins = 0u32;
    while adc.isr().read().eoc().bit_is_clear() {
        spins += 1;
        if spins > REGULAR_CONVERSION_SPINS {
            return None;
        }
    }
    Some(adc.dr().read().rdata().bits())
}

/// Conversions averaged per comparator input by [`measure_shunt_inputs_v`].
const SHUNT_INPUT_CONVERSIONS: u16 = 16;

/// The comparators' inputs (the op-amps' VINP0 pins) read by the ADCs, U, V, W (V),
/// averaged over 16 conversions each: an independent reading of the node whose
/// zero-current level the comparator sweep measured (for the start-up log and the first
/// power-up checklist; the two differ by the comparator's and the converters' offsets).
/// `None` if a conversion does not end.
pub(super) fn measure_shunt_inputs_v(adc1: &pac::ADC1, adc2: &pac::ADC2) -> Option<[f32; 3]> {
    adc_set_sampling(adc1, ADC1_CH_SHUNT_INPUT_U, SMP_SHUNT_INPUT);
    adc_set_sampling(adc2, ADC2_CH_SHUNT_INPUT_V, SMP_SHUNT_INPUT);
    adc_set_sampling(adc1, ADC1_CH_SHUNT_INPUT_W, SMP_SHUNT_INPUT);
    let channels: [(&pac::adc1::RegisterBlock, u8); 3] =
        [(adc1, ADC1_CH_SHUNT_INPUT_U), (adc2, ADC2_CH_SHUNT_INPUT_V), (adc1, ADC1_CH_SHUNT_INPUT_W)];
    let mut volts = [0.0f32; 3];
    for (v, (adc, ch)) in volts.iter_mut().zip(channels) {
        let mut sum = 0u32;
        for _ in 0..SHUNT_INPUT_CONVERSIONS {
            sum += u32::from(convert_regular(adc, ch)?);
        }
        *v = sum as f32 / f32::from(SHUNT_INPUT_CONVERSIONS) * VREF_V / ADC_FULL_SCALE_COUNTS;
    }
    Some(volts)
}

/// Polls of ADC1's `ISR.JEOS` before the injected sequence counts as not triggered: several
/// carrier periods.
const INJECTED_END_SPINS: u32 = 2_000_000;

/// Clears ADC1's injected end-of-sequence flag and waits for the next one (the control
/// interrupt's event, which stays masked in the NVIC): `false` if none comes.
pub(super) fn wait_injected_end(adc1: &pac::ADC1) -> bool {
    adc1.isr().write(|w| w.jeos().clear().jeoc().clear());
    let mut spins = 0u32;
    while adc1.isr().read().jeos().bit_is_clear() {
        spins += 1;
        if spins > INJECTED_END_SPINS {
            return false;
        }
    }
    true
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
    /// The sensing of the ADCs [`init_adcs`] has set up, with the nominal offsets until
    /// [`Esc1Sensors::calibrate_current_offsets`].
    pub(super) fn new(adc1: pac::ADC1, adc2: pac::ADC2) -> Self {
        Self {
            adc1,
            adc2,
            offset_counts: [CURRENT_OFFSET_NOMINAL_COUNTS; 3],
            last_calibration: [CURRENT_OFFSET_NOMINAL_COUNTS; 3],
        }
    }

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
