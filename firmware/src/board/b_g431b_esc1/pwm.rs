//! TIM1: centre-aligned complementary PWM on the six gate-driver inputs, dead time, the
//! ADC trigger at the carrier valley and the latched break; [`Esc1PowerStage`]
//! ([`PowerStage`]).

use stm32g4::stm32g431 as pac;

use super::Esc1Config;
use super::over_current::write_thresholds;
use crate::board::PowerStage;
use crate::board::esc1_settings::{
    CarrierTimer, DeadTime, Esc1InitError, OverCurrentThresholds, SYSCLK_HZ, align_update_to_valley,
    over_current_thresholds, pwm_arr,
};

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
/// set and confirmed at init by [`align_update_to_valley`]: initialisation fails rather than
/// go on with the trigger at the peak). High-side on time = 2·(ARR − CCR) ticks, so
/// CCR = ARR·(1 − duty).
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
    /// The comparators' zero-current levels U, V, W (DAC counts), measured at init.
    zero_current_codes: [u16; 3],
    thresholds: OverCurrentThresholds,
    tripped: bool,
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
    /// TIM1 set up with the bridge off (MOE = 0, break armed on COMP1/2/4), started with its
    /// update event aligned to the carrier valley and confirmed there.
    ///
    /// # Errors
    /// [`Esc1InitError::CarrierNotCounting`] or [`Esc1InitError::TriggerNotAtValley`] from
    /// [`align_update_to_valley`]; TIM1 then runs with MOE = 0 and drives no pin.
    pub(super) fn new(
        tim: pac::TIM1,
        dac: pac::DAC3,
        comp: pac::COMP,
        config: &Esc1Config,
        dt: DeadTime,
        zero_current_codes: [u16; 3],
        thresholds: OverCurrentThresholds,
    ) -> Result<Self, Esc1InitError> {
        let arr = pwm_arr(config.pwm_frequency_hz, SYSCLK_HZ);

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

        align_update_to_valley(&mut Tim1Carrier(&tim), arr)?;
        let mut s = Self { tim, dac, comp, arr, dtg: dt.dtg, zero_current_codes, thresholds, tripped: false };
        // Break flags set while the comparators and the DAC came up (MOE was 0 throughout):
        // cleared; a break input that is *still* active stays latched (the drive then
        // reports it at its first step and never switches on).
        s.clear_hardware_trip();
        Ok(s)
    }

    /// `CR1.DIR` (`true`: counting down) and `CNT` now: where in the carrier period the
    /// caller is (the end-of-conversion check at init).
    pub(super) fn carrier_now(&self) -> (bool, u32) {
        (self.tim.cr1().read().dir().bit_is_set(), u32::from(self.tim.cnt().read().cnt().bits()))
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

    /// The hardware over-current thresholds in use: DAC3 codes and the trip each phase gets
    /// (A, down its low-side shunt).
    pub fn over_current_thresholds(&self) -> OverCurrentThresholds {
        self.thresholds
    }

    /// The comparators' zero-current levels U, V, W measured at init (DAC counts; volts:
    /// [`dac_code_volts`](super::dac_code_volts)).
    pub fn zero_current_codes(&self) -> [u16; 3] {
        self.zero_current_codes
    }

    /// Sets the hardware over-current trip (A, clamped to
    /// [`OVER_CURRENT_TRIP_MIN_A`](super::OVER_CURRENT_TRIP_MIN_A)..=[`OVER_CURRENT_TRIP_MAX_A`](super::OVER_CURRENT_TRIP_MAX_A))
    /// above the zero-current levels measured at init ([`over_current_thresholds`]), rewrites
    /// both DAC3 channels and returns the thresholds in use. Lower it to the motor's needs
    /// before enabling the bridge.
    pub fn set_over_current_trip_a(&mut self, trip_a: f32) -> OverCurrentThresholds {
        self.thresholds = over_current_thresholds(trip_a, self.zero_current_codes);
        write_thresholds(&self.dac, &self.thresholds);
        self.thresholds
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

    /// BDTR.DTG code in use (see [`dead_time_setting`](super::dead_time_setting)).
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

/// TIM1 as the [`CarrierTimer`] that [`align_update_to_valley`] runs on: `CR1.CEN`,
/// `RCR.REP`, `SR.UIF`, `CR1.DIR`, `CNT`.
struct Tim1Carrier<'a>(&'a pac::TIM1);

/// Polls of `SR.UIF` before an update event counts as missing: several periods of the
/// slowest carrier (65 534 · 2 ticks) at a few cycles per poll.
const UPDATE_SPINS: u32 = 1_000_000;

impl CarrierTimer for Tim1Carrier<'_> {
    fn start(&mut self) {
        self.0.cr1().modify(|_, w| w.cen().set_bit());
    }

    fn set_repetition(&mut self, rep: u8) {
        self.0.rcr().write(|w| w.rep().set(u16::from(rep)));
    }

    fn wait_update(&mut self) -> bool {
        // rc_w0: the other flags are written 1, i.e. left as they are.
        self.0.sr().write(|w| w.uif().clear());
        let mut spins = 0u32;
        while self.0.sr().read().uif().bit_is_clear() {
            spins += 1;
            if spins > UPDATE_SPINS {
                return false;
            }
        }
        true
    }

    fn counting_down(&self) -> bool {
        self.0.cr1().read().dir().bit_is_set()
    }

    fn count(&self) -> u32 {
        u32::from(self.0.cnt().read().cnt().bits())
    }
}
