//! The hardware over-current trip: DAC3 sets the threshold, COMP1/2/4 compare the shunt
//! inputs with it and drive TIM1's break input; and the same DAC and comparators as the
//! [`ShuntComparators`] that measure the inputs' zero-current levels at start-up
//! ([`measure_zero_current_codes`](crate::board::esc1_settings::measure_zero_current_codes)).

use stm32g4::stm32g431 as pac;

use crate::board::esc1_settings::{OverCurrentThresholds, SYSCLK_HZ, ShuntComparators};

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

/// Brings DAC3 (both channels at 0 V) and COMP1/2/4 up, not yet locked: the comparators
/// read high (every input above 0 V) until the zero-current sweep and
/// [`write_thresholds`] have set the thresholds.
pub(super) fn init_over_current(dac: &pac::DAC3, comp: &pac::COMP) {
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
    dac.dhr12r1().write(|w| w.daccdhr().set(0));
    dac.dhr12r2().write(|w| w.daccdhr().set(0));
    // Let the threshold settle before the comparators look at it (a few us).
    cortex_m::asm::delay(SYSCLK_HZ / 1_000_000 * 10);

    // COMP1 (INP0 = PA1, U), COMP2 (INP0 = PA7, V), COMP4 (INP0 = PB0, W) against DAC3: output
    // high while the shunt input is above the threshold; no hysteresis, no blanking, not
    // inverted (MCSDK MX_COMPx_Init). Locked once the thresholds are set (`lock_comparators`).
    for n in COMPARATORS {
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
    // Comparator start-up time (t_START, a few us in DS12589) before anything reads them.
    cortex_m::asm::delay(SYSCLK_HZ / 1_000_000 * 10);
}

/// COMP1, COMP2, COMP4 (phases U, V, W) as indices of `COMP::ccsr`.
const COMPARATORS: [usize; 3] = [0, 1, 3];

/// Locks COMP1/2/4's configuration until reset (MCSDK locks them too). The thresholds stay
/// writable: they are DAC3's.
pub(super) fn lock_comparators(comp: &pac::COMP) {
    for n in COMPARATORS {
        comp.ccsr(n).modify(|_, w| w.lock().set_bit());
    }
}

/// Writes the thresholds: DAC3_CH1 (COMP1, U) and DAC3_CH2 (COMP2 and COMP4, V and W).
pub(super) fn write_thresholds(dac: &pac::DAC3, t: &OverCurrentThresholds) {
    dac.dhr12r1().write(|w| w.daccdhr().set(t.dac_ch1));
    dac.dhr12r2().write(|w| w.daccdhr().set(t.dac_ch2));
}

/// DAC settling after a threshold step (us): the unbuffered internal output driving the
/// comparators' inputs settles in well under this (DS12589, DAC settling time).
const THRESHOLD_SETTLE_US: u32 = 5;

/// DAC3 and COMP1/2/4 as the [`ShuntComparators`] of the zero-current sweep.
pub(super) struct DacComparators<'a> {
    /// DAC3 (both channels).
    pub dac: &'a pac::DAC3,
    /// COMP1/2/4.
    pub comp: &'a pac::COMP,
}

impl ShuntComparators for DacComparators<'_> {
    fn set_threshold(&mut self, code: u16) {
        self.dac.dhr12r1().write(|w| w.daccdhr().set(code));
        self.dac.dhr12r2().write(|w| w.daccdhr().set(code));
        cortex_m::asm::delay(SYSCLK_HZ / 1_000_000 * THRESHOLD_SETTLE_US);
    }

    fn outputs(&mut self) -> [bool; 3] {
        COMPARATORS.map(|n| self.comp.ccsr(n).read().value().bit_is_set())
    }
}
