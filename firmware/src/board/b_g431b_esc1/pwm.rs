//! TIM1: centre-aligned complementary PWM on the six gate-driver inputs, dead time, the
//! ADC trigger at the carrier valley and the latched break; [`Esc1PowerStage`]
//! ([`PowerStage`]).

use stm32g4::stm32g431 as pac;

use super::Esc1Config;
use super::clocks::SYSCLK_HZ;
use super::over_current::{over_current_dac_code, over_current_trip_clamped};
use crate::board::PowerStage;

/// Default PWM carrier frequency (Hz): 10 kHz, i.e. 100 us period.
pub const DEFAULT_PWM_HZ: u32 = 10_000;
/// Default dead time (ns). 800 ns = DTG 0x84 at 170 MHz: MCSDK's value for this board
/// (power_stage_parameters.h HW_DEAD_TIME_NS 800), as the pat92fr ESC1 CubeMX project (DTG=128
/// at 160 MHz); NuttX uses 500 ns.
pub const DEFAULT_DEAD_TIME_NS: u32 = 800;

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
/// into TIMx_BDTR.DTG (RM0440 TIMx_BDTR `DTG[7:0]`); saturates at the maximum (1008 ticks).
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
    pub(super) fn new(
        tim: pac::TIM1,
        dac: pac::DAC3,
        comp: pac::COMP,
        config: &Esc1Config,
        trip_a: f32,
    ) -> Self {
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

    /// Sets the hardware over-current trip (A, clamped to [`OVER_CURRENT_TRIP_MIN_A`](super::OVER_CURRENT_TRIP_MIN_A)..=
    /// [`OVER_CURRENT_TRIP_MAX_A`](super::OVER_CURRENT_TRIP_MAX_A)) and returns the value in use: rewrites both DAC3 channels.
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
