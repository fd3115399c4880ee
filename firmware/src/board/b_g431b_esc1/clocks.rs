//! Clocks: SYSCLK = HCLK = PCLK1 = PCLK2 = 170 MHz from the PLL, Range-1 boost mode,
//! flash wait states, and the peripheral clocks the board uses.

use stm32g4::stm32g431 as pac;

use super::ClockSource;
use crate::board::esc1_settings::SYSCLK_HZ;

// Clock constants.
// -------------------------------------------------------------------------------------------------

/// HSE frequency of [`ClockSource::Hse8MHz`] (Hz): UM2516 Table 4 lists "OSC 8 MHz" on
/// PF0/PF1 and ST's MCSDK project for the board runs its PLL from an 8 MHz HSE (oscillator
/// mode, not bypass). HSI16 stays the default: it needs nothing from the board.
pub const HSE_HZ: u32 = 8_000_000;
/// ADC kernel clock: synchronous HCLK / 4 (Hz) = 42.5 MHz.
pub const ADC_CLOCK_HZ: u32 = SYSCLK_HZ / 4;

// =================================================================================================
// Clocks — RM0440 ch. 6 PWR §6.1.5 "Dynamic voltage scaling management" (boost sequence),
// ch. 7 RCC §7.2.4 "PLL", ch. 3 FLASH §3.3.3 "Read access latency" (Table 9: 4 WS @ 170 MHz
// in Range 1 boost mode).
// =================================================================================================

/// Busy-wait bound for oscillator/PLL ready flags (iterations, roughly 1 ms at 16 MHz).
const READY_SPINS: u32 = 20_000;

pub(super) fn init_clocks(
    rcc: &pac::RCC,
    flash: &pac::FLASH,
    pwr: &pac::PWR,
    want: ClockSource,
) -> ClockSource {
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

pub(super) fn enable_peripheral_clocks(rcc: &pac::RCC) {
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
