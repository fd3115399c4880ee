//! The hardware over-current trip: DAC3 sets the threshold, COMP1/2/4 compare the shunt
//! inputs with it and drive TIM1's break input.

use stm32g4::stm32g431 as pac;

use super::adc::SHUNT_OHM;
use super::clocks::SYSCLK_HZ;

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

pub(super) fn init_over_current(dac: &pac::DAC3, comp: &pac::COMP, code: u16) {
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
