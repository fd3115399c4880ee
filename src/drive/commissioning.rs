//! Commissioning: the drive measures its motor and its inverter (issue 10).
//!
//! A pure state machine, stepped once per PWM period by [`super::Drive`] in its
//! `Commissioning` state: it gets the measured currents (offsets removed) and the bus, and
//! returns the stationary-frame voltage to apply. It reads no clock: time is the step
//! count times the PWM period. It is told only the rated current and voltage, the bus
//! and the pole pitch ([`CommissioningConfig`]); every level, voltage, duration and speed
//! below is derived from those.
//!
//! ## Sequence (about 4.1 s, bounded: every phase has a fixed or capped length)
//! 1. **Ramp and align** (mover free): the alpha voltage ramps from zero until the alpha
//!    current reaches half the rated peak current `I_p`. The current pulls the magnet's
//!    d axis onto alpha (the mover moves up to half a pole pitch). `U / I` at that point
//!    is a rough resistance that tunes the slow integral current controllers of the DC
//!    tests (crossover [`DC_LOOP_RAD_S`]), which then hold the current for 0.4 s while the
//!    mover settles. No current at the voltage limit, or a mean current at the end of the
//!    hold that is not on alpha: [`CommissioningError::OpenPhase`]; sample-to-sample jumps
//!    of a fifth of the held current (no winding inductance smoothing the PWM):
//!    [`CommissioningError::ShortedPhase`].
//! 2. **DC sweep** on the alpha (d) axis at [`SWEEP_LEVELS`] levels from `I_p` down to
//!    `0.005 I_p`.
//!    With the alpha current `I` the phase currents are `I, -I/2, -I/2`, and the voltage
//!    the controller needs is `U(I) = R_t I + 4/3 e(I)`, where `e(I)` is the per-phase
//!    voltage error of the inverter (dead time and device threshold, saturating with the
//!    current). A straight line through the levels at or above `0.3 I_p`, where `e` has
//!    saturated, gives the slope `R_t` (the difference between levels removes the drop)
//!    and the intercept `4/3 e_sat`; each level then gives a point `e(I) = 3/4 (U - R_t I)`
//!    of the voltage-error curve, whose half-amplitude current sets the compensation's
//!    band (or, if the error has not fallen to half at the lowest level, the current
//!    sensors' noise RMS). The drive's dead-time compensation ([`super::DeadTimeCompensation`]) is this
//!    curve's model: amplitude `e_sat`, band from the curve.
//! 3. **Ld, Lq at standstill** (mover free, held on d by a bias of `I_p / 2` on alpha): a
//!    sinusoidal voltage at `f_pwm / 10` on alpha (Ld) and then on beta (Lq), its amplitude
//!    raised per cycle until the current's reaches `I_p / 10` (below the bias, so no phase
//!    current changes sign and the dead-time error stays constant). The demodulated
//!    voltage and current phasors, with the one-period computation delay, fit the exact
//!    discrete model of an R-L winding over one period, `i(k+1) = a i(k) + b u(k)` with
//!    `a = exp(-R Ts / L)`: `b` from the quadrature part, `L = -R Ts / ln(1 - b R)`.
//!    The q-axis current shakes the free mover; its back-EMF reads as an inductance lower
//!    by `(pi/tau) psi_f K_f / (w_h^2 M)`: 0.8 % on the paper motor's bare 0.66 kg mover at
//!    1 kHz, less with any carriage. A locked mover removes it.
//! 4. **psi_f from an I/f run**: a current vector of `I_p / 2` (current loops on the
//!    identified R and L, inverter compensation on) turned at a frequency ramped to
//!    [`IF_FREQUENCY_HZ`]; the mover follows. In the open-loop frame `E = u - R i - j w Lq
//!    i` is `j w_m psi_a` with `w_m` the mover's own speed; the mover swings about the
//!    vector (end-effect ripple, friction), so the mean of `|E|` over whole electrical
//!    periods, divided by the vector's speed (the mover's mean), gives `psi_a`, the active flux
//!    `psi_a = psi_f + (Ld - Lq) i_d` along the rotor's d axis: `psi_f = |E| / w - (Ld -
//!    Lq) i_d`, with `i_d` the current's projection on `E / j`. Travel: about 20 pole
//!    pitches (0.3 m on the paper motor). Then the frequency ramps down and the bridge
//!    turns off.
//!
//! **Direction convention.** Positive speed is the direction the mover moves when the
//! current vector turns from phase a to b to c (alpha to beta): the I/f run turns that way
//! and checks that the back-EMF's flux lies on the mover's side of the current vector (the
//! mover follows); a mover that does not follow, or no back-EMF, is
//! [`CommissioningError::NoBackEmf`]. A swapped pair of phases just moves the mover the
//! other way: the convention is defined by the wiring, and positions and speeds in the
//! drive follow it.
//!
//! ## Resistance: terminal, not winding
//! Each conducting device drops `V0 + r |i|`: its slope `r` acts on each phase as a
//! resistance in series with the winding, in every conduction state (an IGBT or a diode
//! with equal slopes). From the terminals, with the commanded voltage as the only voltage
//! known, no test separates it from the winding: DC levels, the HF test and the back-EMF
//! all see `R_t = R_s + r`. The constant-amplitude compensation model `e sat(i / band)`
//! has no slope term, so it does not absorb `r` either. `R_t` is what the observer and the
//! current loops need (they see commanded voltage), so the result's `rs_ohm` is the
//! terminal resistance; the winding alone needs a device model or a voltage measurement.
//!
//! ## Dead time against device drop
//! The sweep measures their sum at the commissioning bus. The result expresses it as a
//! dead time (`e_sat Ts / V_dc`, no device drop), exact at that bus; at another bus the
//! device-drop share would be scaled wrongly (a clamped-leg test could separate them; not
//! done).
//!
//! ## Numbers
//! Runs in `f32` SI whatever the drive's scalar type: its accumulators (sums over
//! thousands of samples of products) exceed Q8.24's range. Bounded: a fixed number of
//! operations per step, no loops over samples; no indexing that can panic, no division by
//! an integer.

use super::DeadTimeCompensation;
use crate::motor::MotorParams;
use crate::num::{positive as pos, sin_cos, sqrt_rounded};

/// Crossover of the integral current controllers of the DC tests, rad/s (slow enough for
/// any electrical time constant up to 6 ms whatever the rough resistance's error).
pub const DC_LOOP_RAD_S: f32 = 30.0;
/// Number of DC sweep levels.
pub const SWEEP_LEVELS: usize = 12;
/// The DC sweep's levels as fractions of the rated peak current, descending (the lowest,
/// 0.5 %, is 15 mA on the paper motor: about one and a half noise sigmas of its sensors).
pub const SWEEP_FRACTIONS: [f32; SWEEP_LEVELS] =
    [1.0, 0.8, 0.6, 0.45, 0.3, 0.2, 0.12, 0.07, 0.04, 0.02, 0.01, 0.005];
/// Levels at or above this fraction of rated peak current are in the straight-line fit.
const FIT_FRACTION: f32 = 0.299;
/// Electrical frequency of the I/f run, Hz.
pub const IF_FREQUENCY_HZ: f32 = 10.0;
/// PWM periods per cycle of the HF injection.
const HF_PERIODS: u32 = 10;
/// Cycles demodulated for each inductance.
const HF_CYCLES: u32 = 40;
/// Cycles the HF amplitude may take to reach its target.
const HF_RAMP_CYCLES: u32 = 30;

const RAMP_S: f32 = 0.4;
const ALIGN_S: f32 = 0.4;
const SETTLE_S: f32 = 0.12;
const AVERAGE_S: f32 = 0.05;
const IF_ACCEL_S: f32 = 0.4;
const IF_DWELL_S: f32 = 0.3;
/// Whole electrical periods averaged in the I/f run.
const IF_MEASURE_PERIODS: f32 = 3.0;

/// What the drive is told before commissioning (SI).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommissioningConfig {
    /// Rated current, A RMS.
    pub rated_current_a: f32,
    /// Rated line voltage, V RMS.
    pub rated_voltage_v: f32,
    /// Nominal DC bus, V.
    pub bus_v: f32,
    /// Pole pitch, m.
    pub pole_pitch_m: f32,
}

impl CommissioningConfig {
    /// A motor record carrying only what commissioning is told (ratings, pole pitch) and
    /// neutral placeholders elsewhere (R, L, psi_f from the rated impedance, 1 kg, no
    /// friction): enough to build a [`super::Drive`] that will commission; the
    /// commissioning itself reads none of the placeholders.
    pub fn placeholder_motor(&self) -> MotorParams {
        let v_ph = self.rated_voltage_v * 0.816_496_6;
        let i_p = self.rated_current_a * core::f32::consts::SQRT_2;
        let z = v_ph / i_p;
        MotorParams {
            rs_ohm: 0.05 * z,
            ld_h: z * 1e-3,
            lq_h: z * 1e-3,
            psi_f_wb: v_ph / (2.0 * core::f32::consts::PI * 50.0),
            pole_pitch_m: self.pole_pitch_m,
            mass_kg: 1.0,
            viscous_n_s_per_m: 0.0,
            rated_current_a: self.rated_current_a,
            rated_voltage_v: self.rated_voltage_v,
        }
    }
}

/// Why commissioning stopped (the bridge is off, no result).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommissioningError {
    /// A setting is not a positive finite number (the field's name).
    BadSetting(&'static str),
    /// The bus is outside 80-120 % of the nominal bus it was told.
    BusOutOfRange,
    /// A measurement was NaN or infinite.
    NonFinite,
    /// No current at the voltage limit, or a current that does not follow the commanded
    /// direction: a phase is open (or a sensor is missing).
    OpenPhase,
    /// Resistance or inductance far below anything a motor of these ratings has, or a
    /// held current that jumps from one sample to the next (nothing smooths the PWM): a
    /// short.
    ShortedPhase,
    /// A phase current beyond 1.5 times the rated peak.
    RunawayCurrent,
    /// The I/f run saw no back-EMF, or a mover that did not follow the current vector.
    NoBackEmf,
    /// The response does not fit an R-L winding (e.g. the HF test needed more voltage than
    /// allowed, or the fit is not physical).
    NotAMotor,
    /// The drive latched a fault of its own (its bits) during commissioning.
    DriveFault(u16),
}

impl core::fmt::Display for CommissioningError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CommissioningError::BadSetting(field) => {
                write!(f, "commissioning setting `{field}` is out of range")
            }
            CommissioningError::BusOutOfRange => {
                f.write_str("bus voltage out of range (80-120 % of nominal)")
            }
            CommissioningError::NonFinite => f.write_str("non-finite measurement"),
            CommissioningError::OpenPhase => {
                f.write_str("open phase: the current does not follow the voltage")
            }
            CommissioningError::ShortedPhase => {
                f.write_str("shorted phase: resistance or inductance too low")
            }
            CommissioningError::RunawayCurrent => f.write_str("runaway current (beyond 1.5x rated peak)"),
            CommissioningError::NoBackEmf => {
                f.write_str("no back-EMF: the mover does not follow the I/f vector")
            }
            CommissioningError::NotAMotor => f.write_str("the response does not fit an R-L winding"),
            CommissioningError::DriveFault(bits) => write!(f, "drive fault {bits:#06x}"),
        }
    }
}

/// One point of the inverter's voltage-error curve.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VoltageErrorPoint {
    /// Alpha current of the DC level (phase a carries it, b and c half of it), A.
    pub current_a: f32,
    /// Per-phase voltage error at that current, V (`3/4 (U - R_t I)`).
    pub error_v: f32,
}

/// What commissioning measured (SI).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommissioningResult {
    /// Terminal resistance per phase (winding plus device slope; module docs), ohm.
    pub rs_ohm: f32,
    /// d-axis inductance, H.
    pub ld_h: f32,
    /// q-axis inductance, H.
    pub lq_h: f32,
    /// Magnet flux linkage (amplitude-invariant), Wb.
    pub psi_f_wb: f32,
    /// Saturated per-phase voltage error of the inverter at `bus_v`, V.
    pub voltage_error_v: f32,
    /// Current over which the error's sign changes in the compensation model, A.
    pub current_band_a: f32,
    /// Mean bus measured during the sweep, V.
    pub bus_v: f32,
    /// The voltage-error curve, one point per sweep level (descending current).
    pub curve: [VoltageErrorPoint; SWEEP_LEVELS],
    /// +1: the mover moved in the positive direction as the vector turned a-b-c (the
    /// convention; module docs).
    pub direction: i8,
    /// Time commissioning took, s.
    pub duration_s: f32,
}

impl CommissioningResult {
    /// The inverter compensation for the drive: the whole error as a dead time at the
    /// commissioning bus (`e Ts / V_dc`), no separate device drop, the measured band.
    pub fn dead_time_compensation(&self, control_period_s: f32) -> DeadTimeCompensation {
        DeadTimeCompensation {
            dead_time_s: self.voltage_error_v * control_period_s / self.bus_v,
            device_drop_v: 0.0,
            current_band_a: self.current_band_a,
        }
    }

    /// The identified motor with the ratings and pole pitch commissioning was told and the
    /// given mechanics (not identified), validated.
    pub fn motor(
        &self,
        config: &CommissioningConfig,
        mass_kg: f32,
        viscous_n_s_per_m: f32,
    ) -> Result<MotorParams, crate::motor::ParamError> {
        MotorParams::new(MotorParams {
            rs_ohm: self.rs_ohm,
            ld_h: self.ld_h,
            lq_h: self.lq_h,
            psi_f_wb: self.psi_f_wb,
            pole_pitch_m: config.pole_pitch_m,
            mass_kg,
            viscous_n_s_per_m,
            rated_current_a: config.rated_current_a,
            rated_voltage_v: config.rated_voltage_v,
        })
    }
}

impl CommissioningResult {
    /// The identified motor as the board's flash record ([`crate::motor_image`]): the
    /// motor of [`Self::motor`], the nominal bus commissioning was told, and the
    /// identified inverter compensation ([`Self::dead_time_compensation`] at
    /// `control_period_s`, the PWM period commissioning ran at: the error as a dead time,
    /// which a drive at another period scales with its own).
    pub fn motor_image(
        &self,
        config: &CommissioningConfig,
        mass_kg: f32,
        viscous_n_s_per_m: f32,
        control_period_s: f32,
    ) -> Result<crate::motor_image::MotorImage, crate::motor_image::MotorImageError> {
        let motor = self
            .motor(config, mass_kg, viscous_n_s_per_m)
            .map_err(crate::motor_image::MotorImageError::Param)?;
        crate::motor_image::MotorImage::new(motor, config.bus_v)?
            .with_compensation(self.dead_time_compensation(control_period_s))
    }
}

/// What one commissioning step asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CommissioningStep {
    /// Apply this stationary-frame voltage (alpha, beta; V) from the next period on.
    Apply(f32, f32),
    /// Finished: bridge off.
    Done(CommissioningResult),
    /// Aborted: bridge off.
    Failed(CommissioningError),
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    Ramp,
    Align,
    Sweep(usize),
    Hf(bool),
    IfRun,
}

/// A complex number (re, im) for the demodulation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct C(f32, f32);

impl C {
    fn mul(self, o: C) -> C {
        C(self.0 * o.0 - self.1 * o.1, self.0 * o.1 + self.1 * o.0)
    }
    fn div(self, o: C) -> C {
        let n = o.0 * o.0 + o.1 * o.1;
        C((self.0 * o.0 + self.1 * o.1) / n, (self.1 * o.0 - self.0 * o.1) / n)
    }
}

/// One PWM period of commissioning ([`Commissioning::step`]'s signature).
type StepFn = fn(&mut Commissioning, f32, f32, f32) -> CommissioningStep;

/// The commissioning state machine (module docs).
#[derive(Clone, Debug)]
pub struct Commissioning {
    /// The step's body, reached through this pointer, which only [`Commissioning::new`]
    /// sets: an image that never starts commissioning (every drive image: `Drive::step`
    /// holds an `Option<Commissioning>` that stays `None`) does not link the state
    /// machine (5.3 KB of the ESC1 drive image), as a direct call from `Drive::step` would.
    step_fn: StepFn,
    cfg: CommissioningConfig,
    ts: f32,
    i_peak: f32,
    v_limit: f32,
    /// Largest HF injection amplitude, V.
    hf_limit: f32,
    phase: Phase,
    /// Steps in the present phase.
    n: u32,
    /// Steps since the start.
    total: u32,
    /// Integral controllers' outputs (V).
    u_alpha: f32,
    u_beta: f32,
    ki: f32,
    i_ref: f32,
    r_rough: f32,
    /// Sweep sums and results.
    sum_u: f32,
    sum_i: f32,
    sum_vdc: f32,
    sum_i2: f32,
    count: u32,
    /// RMS noise of the alpha current, A (from the first sweep level).
    noise_a: f32,
    i_previous: f32,
    levels_u: [f32; SWEEP_LEVELS],
    levels_i: [f32; SWEEP_LEVELS],
    vdc_mean: f32,
    rs: f32,
    e_sat: f32,
    band: f32,
    curve: [VoltageErrorPoint; SWEEP_LEVELS],
    /// HF test.
    hf_amp_v: f32,
    hf_cycles: u32,
    hf_measuring: bool,
    hf_settle: u32,
    i_max: f32,
    i_min: f32,
    dft_u: C,
    dft_i: C,
    ld: f32,
    lq: f32,
    /// I/f run.
    theta: f32,
    omega: f32,
    int_d: f32,
    int_q: f32,
    e_filtered: C,
    e_abs_sum: f32,
    i_d_sum: f32,
    i_sum: C,
    e_sum: C,
    if_count: u32,
    psi_f: f32,
}

// Variable limits are applied with `max` and `min`, not `f32::clamp`: clamp panics when its
// bounds are NaN or crossed, which the optimiser cannot rule out (no image may link a panic).

/// The rated phase voltage (peak, line-to-neutral) of `config`, V.
fn phase_voltage(config: &CommissioningConfig) -> f32 {
    config.rated_voltage_v * 0.816_496_6
}

impl Commissioning {
    /// Starts commissioning with `config` at the PWM period `control_period_s` (s).
    pub fn new(config: CommissioningConfig, control_period_s: f32) -> Result<Self, CommissioningError> {
        let checks = [
            (config.rated_current_a, "rated_current_a"),
            (config.rated_voltage_v, "rated_voltage_v"),
            (config.bus_v, "bus_v"),
            (config.pole_pitch_m, "pole_pitch_m"),
            (control_period_s, "control_period_s"),
        ];
        for (x, field) in checks {
            if !pos(x) {
                return Err(CommissioningError::BadSetting(field));
            }
        }
        let i_peak = config.rated_current_a * core::f32::consts::SQRT_2;
        let v_phase = phase_voltage(&config);
        Ok(Commissioning {
            step_fn: Commissioning::step_body,
            cfg: config,
            ts: control_period_s,
            i_peak,
            // 30 % of the rated phase voltage, within linear modulation of the bus.
            v_limit: (0.3 * v_phase).min(0.5 * config.bus_v * 0.577_350_26),
            hf_limit: (0.6 * v_phase).min(0.5 * config.bus_v * 0.577_350_26),
            phase: Phase::Ramp,
            n: 0,
            total: 0,
            u_alpha: 0.0,
            u_beta: 0.0,
            ki: 0.0,
            i_ref: 0.5 * i_peak,
            r_rough: 0.0,
            sum_u: 0.0,
            sum_i: 0.0,
            sum_vdc: 0.0,
            sum_i2: 0.0,
            count: 0,
            noise_a: 0.0,
            i_previous: 0.0,
            levels_u: [0.0; SWEEP_LEVELS],
            levels_i: [0.0; SWEEP_LEVELS],
            vdc_mean: config.bus_v,
            rs: 0.0,
            e_sat: 0.0,
            band: 0.0,
            curve: [VoltageErrorPoint::default(); SWEEP_LEVELS],
            hf_amp_v: 0.0,
            hf_cycles: 0,
            hf_measuring: false,
            hf_settle: 0,
            i_max: f32::MIN,
            i_min: f32::MAX,
            dft_u: C::default(),
            dft_i: C::default(),
            ld: 0.0,
            lq: 0.0,
            theta: 0.0,
            omega: 0.0,
            int_d: 0.0,
            int_q: 0.0,
            e_filtered: C::default(),
            e_abs_sum: 0.0,
            i_d_sum: 0.0,
            i_sum: C::default(),
            e_sum: C::default(),
            if_count: 0,
            psi_f: 0.0,
        })
    }

    /// The base impedance, ohm: the rated phase voltage over the peak current. Computed
    /// rather than stored, so that the step's pointer (`step_fn`) leaves the state's size,
    /// and with it `Drive`'s, unchanged: 8 B more static RAM on the ESC1 drive image
    /// otherwise, and fields moved within `Drive` (6 instructions more in the Cortex-M4F
    /// running step, 13 on the M3).
    fn z_base(&self) -> f32 {
        phase_voltage(&self.cfg) / self.i_peak
    }

    fn steps(&self, seconds: f32) -> u32 {
        (seconds / self.ts) as u32
    }

    /// One PWM period: the measured stationary-frame currents (A, offsets removed) and
    /// the bus (V). Returns the voltage to apply, or the end.
    pub fn step(&mut self, i_alpha: f32, i_beta: f32, vdc: f32) -> CommissioningStep {
        (self.step_fn)(self, i_alpha, i_beta, vdc)
    }

    /// [`Commissioning::step`]'s body, reached through the `step_fn` field.
    fn step_body(&mut self, i_alpha: f32, i_beta: f32, vdc: f32) -> CommissioningStep {
        if !(i_alpha.is_finite() && i_beta.is_finite() && vdc.is_finite()) {
            return CommissioningStep::Failed(CommissioningError::NonFinite);
        }
        if vdc < 0.8 * self.cfg.bus_v || vdc > 1.2 * self.cfg.bus_v {
            return CommissioningStep::Failed(CommissioningError::BusOutOfRange);
        }
        // Largest phase current of the alpha-beta vector: |i| bounds all three.
        let limit = 1.5 * self.i_peak;
        if i_alpha * i_alpha + i_beta * i_beta > limit * limit {
            return CommissioningStep::Failed(CommissioningError::RunawayCurrent);
        }
        self.n = self.n.saturating_add(1);
        self.total = self.total.saturating_add(1);
        let r = match self.phase {
            Phase::Ramp => self.ramp(i_alpha, i_beta),
            Phase::Align => self.align(i_alpha, i_beta),
            Phase::Sweep(k) => self.sweep(k, i_alpha, i_beta, vdc),
            Phase::Hf(q) => self.hf(q, i_alpha, i_beta),
            Phase::IfRun => self.if_run(i_alpha, i_beta),
        };
        match r {
            Ok(step) => step,
            Err(e) => CommissioningStep::Failed(e),
        }
    }

    fn next(&mut self, phase: Phase) {
        self.phase = phase;
        self.n = 0;
        self.sum_u = 0.0;
        self.sum_i = 0.0;
        self.sum_vdc = 0.0;
        self.sum_i2 = 0.0;
        self.count = 0;
    }

    /// The DC integral controllers towards `(i_ref, 0)` on alpha-beta.
    fn dc_loops(&mut self, i_alpha: f32, i_beta: f32) {
        let k = self.ki * self.ts;
        self.u_alpha = within(self.u_alpha + k * (self.i_ref - i_alpha), self.v_limit);
        self.u_beta = within(self.u_beta + k * (0.0 - i_beta), self.v_limit);
    }

    fn ramp(&mut self, i_alpha: f32, _i_beta: f32) -> Result<CommissioningStep, CommissioningError> {
        if i_alpha >= self.i_ref {
            self.r_rough = self.u_alpha / i_alpha;
            self.ki = DC_LOOP_RAD_S * self.r_rough;
            self.next(Phase::Align);
            return Ok(CommissioningStep::Apply(self.u_alpha, 0.0));
        }
        self.u_alpha += self.v_limit * self.ts / RAMP_S;
        if self.u_alpha > self.v_limit {
            return Err(CommissioningError::OpenPhase);
        }
        Ok(CommissioningStep::Apply(self.u_alpha, 0.0))
    }

    fn align(&mut self, i_alpha: f32, i_beta: f32) -> Result<CommissioningStep, CommissioningError> {
        self.dc_loops(i_alpha, i_beta);
        if self.n > self.steps(ALIGN_S - AVERAGE_S) {
            self.sum_i += i_alpha;
            self.sum_u += i_beta;
            let d = i_alpha - self.i_previous;
            self.sum_i2 += d * d;
            self.count += 1;
        }
        self.i_previous = i_alpha;
        if self.n >= self.steps(ALIGN_S) {
            // Settled on alpha: a mean current that cannot be steered there means a phase
            // is open (with a, b or c open the vector is confined to one axis).
            let c = 1.0 / self.count.max(1) as f32;
            let (ia, ib) = (self.sum_i * c, self.sum_u * c);
            // A winding smooths the PWM: from one valley sample to the next, a held DC
            // current changes by its sensors' noise. Jumps of a fifth of the current mean
            // an inductance far too small to be the motor's: a short.
            if sqrt_rounded(0.5 * self.sum_i2 * c) > 0.2 * self.i_ref {
                return Err(CommissioningError::ShortedPhase);
            }
            if (ia - self.i_ref).abs() > 0.3 * self.i_ref || ib.abs() > 0.3 * self.i_ref {
                return Err(CommissioningError::OpenPhase);
            }
            self.i_ref = self.level(0);
            self.next(Phase::Sweep(0));
        }
        Ok(CommissioningStep::Apply(self.u_alpha, self.u_beta))
    }

    fn level(&self, k: usize) -> f32 {
        SWEEP_FRACTIONS.get(k).copied().unwrap_or(0.0) * self.i_peak
    }

    fn sweep(
        &mut self,
        k: usize,
        i_alpha: f32,
        i_beta: f32,
        vdc: f32,
    ) -> Result<CommissioningStep, CommissioningError> {
        self.dc_loops(i_alpha, i_beta);
        if self.n > self.steps(SETTLE_S) {
            self.sum_u += self.u_alpha;
            self.sum_i += i_alpha;
            // Sample-to-sample differences: twice the white noise's variance, blind to
            // the loop's slow motion.
            let d = i_alpha - self.i_previous;
            self.sum_i2 += d * d;
            self.sum_vdc += vdc;
            self.count += 1;
        }
        if self.n >= self.steps(SETTLE_S + AVERAGE_S) {
            let c = self.count.max(1) as f32;
            if let (Some(u), Some(i)) = (self.levels_u.get_mut(k), self.levels_i.get_mut(k)) {
                *u = self.sum_u / c;
                *i = self.sum_i / c;
            }
            if k == 0 {
                self.vdc_mean = self.sum_vdc / c;
                self.noise_a = sqrt_rounded(0.5 * self.sum_i2 / c);
            }
            if k + 1 < SWEEP_LEVELS {
                self.i_ref = self.level(k + 1);
                self.next(Phase::Sweep(k + 1));
            } else {
                self.fit()?;
                self.i_ref = 0.5 * self.i_peak;
                self.next(Phase::Hf(false));
                self.start_hf();
            }
        }
        self.i_previous = i_alpha;
        Ok(CommissioningStep::Apply(self.u_alpha, self.u_beta))
    }

    /// Straight line through the saturated levels; the curve; the band.
    fn fit(&mut self) -> Result<(), CommissioningError> {
        let (mut n, mut sx, mut sy, mut sxx, mut sxy) = (0.0f32, 0.0, 0.0, 0.0, 0.0);
        for ((&u, &i), &f) in self.levels_u.iter().zip(&self.levels_i).zip(&SWEEP_FRACTIONS) {
            if f >= FIT_FRACTION {
                n += 1.0;
                sx += i;
                sy += u;
                sxx += i * i;
                sxy += i * u;
            }
        }
        let det = n * sxx - sx * sx;
        let slope = (n * sxy - sx * sy) / det;
        let intercept = (sy - slope * sx) / n;
        if !(slope.is_finite() && intercept.is_finite()) {
            return Err(CommissioningError::NotAMotor);
        }
        if slope < 0.01 * self.z_base() {
            return Err(CommissioningError::ShortedPhase);
        }
        self.rs = slope;
        self.e_sat = 0.75 * intercept;
        for ((p, &u), &i) in self.curve.iter_mut().zip(&self.levels_u).zip(&self.levels_i) {
            *p = VoltageErrorPoint { current_a: i, error_v: 0.75 * (u - slope * i) };
        }
        // Band: twice the current at which the error reaches half its saturated value
        // (interpolated between levels). If the error is above half at the lowest level
        // already, the switching is sharper than the sweep resolves (a DC current has no
        // ripple): the band is then the current sensors' noise (RMS, measured at the
        // first level from sample-to-sample differences),
        // below which the sign of a measured current is uncertain; a wider band would
        // leave the light-load currents of a running drive under-compensated.
        let half = 0.5 * self.e_sat;
        let mut band = self.noise_a;
        for w in self.curve.windows(2) {
            if let [hi, lo] = w
                && hi.error_v >= half
                && lo.error_v < half
            {
                let t = (half - lo.error_v) / (hi.error_v - lo.error_v);
                band = 2.0 * (lo.current_a + t * (hi.current_a - lo.current_a));
            }
        }
        self.band = band.max(0.001 * self.i_peak);
        Ok(())
    }

    fn start_hf(&mut self) {
        self.hf_amp_v = 0.01 * self.v_limit;
        self.hf_cycles = 0;
        self.hf_measuring = false;
        self.hf_settle = 0;
        self.i_max = f32::MIN;
        self.i_min = f32::MAX;
        self.dft_u = C::default();
        self.dft_i = C::default();
    }

    fn hf(
        &mut self,
        q_axis: bool,
        i_alpha: f32,
        i_beta: f32,
    ) -> Result<CommissioningStep, CommissioningError> {
        self.dc_loops(i_alpha, i_beta);
        let k = (self.n - 1) % HF_PERIODS;
        let phase = 2.0 * core::f32::consts::PI * k as f32 / HF_PERIODS as f32;
        let (s, c) = sin_cos(phase);
        let i_axis = if q_axis { i_beta } else { i_alpha };
        // The command this step returns (applied over the period after next).
        let u_h = self.hf_amp_v * c;
        let u_axis = u_h + if q_axis { self.u_beta } else { self.u_alpha };
        if self.hf_measuring {
            let e = C(c, -s);
            self.dft_u = C(self.dft_u.0 + u_axis * e.0, self.dft_u.1 + u_axis * e.1);
            self.dft_i = C(self.dft_i.0 + i_axis * e.0, self.dft_i.1 + i_axis * e.1);
        }
        self.i_max = self.i_max.max(i_axis);
        self.i_min = self.i_min.min(i_axis);
        if k + 1 == HF_PERIODS {
            let amp = 0.5 * (self.i_max - self.i_min);
            self.i_max = f32::MIN;
            self.i_min = f32::MAX;
            self.hf_cycles += 1;
            let target = 0.1 * self.i_peak;
            if self.hf_measuring {
                if self.hf_cycles >= HF_CYCLES {
                    let l = self.inductance()?;
                    if q_axis {
                        self.lq = l;
                        self.start_if();
                    } else {
                        self.ld = l;
                        self.next(Phase::Hf(true));
                        self.start_hf();
                    }
                    let (ua, ub) = (self.u_alpha, self.u_beta);
                    return Ok(CommissioningStep::Apply(ua, ub));
                }
            } else if amp < target {
                if self.hf_cycles >= HF_RAMP_CYCLES || self.hf_amp_v >= self.hf_limit {
                    return Err(CommissioningError::NotAMotor);
                }
                self.hf_amp_v = (self.hf_amp_v * 1.25).min(self.hf_limit);
            } else {
                self.hf_settle += 1;
                if self.hf_settle >= 5 {
                    self.hf_measuring = true;
                    self.hf_cycles = 0;
                }
            }
        }
        Ok(if q_axis {
            CommissioningStep::Apply(self.u_alpha, u_axis)
        } else {
            CommissioningStep::Apply(u_axis, self.u_beta)
        })
    }

    /// L from the demodulated phasors (module docs).
    fn inductance(&self) -> Result<f32, CommissioningError> {
        let w_ts = 2.0 * core::f32::consts::PI / HF_PERIODS as f32;
        let (sin_w, cos_w) = sin_cos(w_ts);
        let z = C(cos_w, sin_w);
        // U / (I z) = (z - a) / b.
        let zp = self.dft_u.div(self.dft_i.mul(z));
        let b = sin_w / zp.1;
        let x = 1.0 - b * self.rs;
        if !(b.is_finite() && b > 0.0 && x > 0.0 && x < 1.0) {
            return Err(CommissioningError::NotAMotor);
        }
        let l = -self.rs * self.ts / libm::logf(x);
        if !l.is_finite() {
            return Err(CommissioningError::NotAMotor);
        }
        if l < 0.1 * self.z_base() * self.ts {
            return Err(CommissioningError::ShortedPhase);
        }
        Ok(l)
    }

    fn start_if(&mut self) {
        self.next(Phase::IfRun);
        self.theta = 0.0;
        self.omega = 0.0;
        self.int_d = self.u_alpha;
        self.int_q = self.u_beta;
        self.e_filtered = C::default();
        self.e_abs_sum = 0.0;
        self.i_d_sum = 0.0;
        self.i_sum = C::default();
        self.e_sum = C::default();
        self.if_count = 0;
    }

    fn if_run(&mut self, i_alpha: f32, i_beta: f32) -> Result<CommissioningStep, CommissioningError> {
        let w_if = 2.0 * core::f32::consts::PI * IF_FREQUENCY_HZ;
        let accel = self.steps(IF_ACCEL_S);
        let dwell = accel + self.steps(IF_DWELL_S);
        let measure = dwell + self.steps(IF_MEASURE_PERIODS / IF_FREQUENCY_HZ);
        let stop = measure + accel;
        let n = self.n;
        self.omega = if n <= accel {
            w_if * n as f32 / accel.max(1) as f32
        } else if n <= measure {
            w_if
        } else {
            w_if * (stop.saturating_sub(n)) as f32 / accel.max(1) as f32
        };
        let (s, c) = sin_cos(self.theta);
        let i_d = c * i_alpha + s * i_beta;
        let i_q = -s * i_alpha + c * i_beta;
        // Current loops in the open-loop frame, on the identified R and L.
        let wc = 0.15 / self.ts;
        let l = 0.5 * (self.ld + self.lq);
        let (kp, ki_ts) = (l * wc, self.rs * wc * self.ts);
        let i_ref = 0.5 * self.i_peak;
        let (ed, eq) = (i_ref - i_d, -i_q);
        self.int_d = within(self.int_d + ki_ts * ed, self.v_limit);
        self.int_q = within(self.int_q + ki_ts * eq, self.v_limit);
        let u_d = within(self.int_d + kp * ed, self.v_limit);
        let u_q = within(self.int_q + kp * eq, self.v_limit);
        // E = u - R i - j w Lq i in the open-loop frame, low-passed over 1 ms.
        let w = self.omega;
        let e = C(u_d - self.rs * i_d + w * self.lq * i_q, u_q - self.rs * i_q - w * self.lq * i_d);
        let k_f = (self.ts / 1e-3).min(1.0);
        self.e_filtered = C(
            self.e_filtered.0 + k_f * (e.0 - self.e_filtered.0),
            self.e_filtered.1 + k_f * (e.1 - self.e_filtered.1),
        );
        if n > dwell && n <= measure {
            // The mover swings about the vector (end-effect ripple, friction): E turns
            // with it and its length follows the mover's own speed, whose mean over the
            // window is the vector's. So the mean of |E| over w is psi_a, where the
            // length of the mean vector would be short by the swing.
            let ef = self.e_filtered;
            let e_abs = sqrt_rounded(ef.0 * ef.0 + ef.1 * ef.1);
            self.e_abs_sum += e_abs;
            if e_abs > 0.0 {
                // psi's direction: E / j = (E_q, -E_d); the current's projection on it.
                self.i_d_sum += (ef.1 * i_d - ef.0 * i_q) / e_abs;
            }
            self.e_sum = C(self.e_sum.0 + ef.0, self.e_sum.1 + ef.1);
            self.i_sum = C(self.i_sum.0 + i_d, self.i_sum.1 + i_q);
            self.if_count += 1;
        }
        if n == measure {
            let k = 1.0 / self.if_count.max(1) as f32;
            let psi_a = self.e_abs_sum * k / w_if;
            let (e, i) = (self.e_sum, self.i_sum);
            // psi = E / (j w) = (E_q, -E_d) / w on the mover's side of the current.
            let follows = e.1 * i.0 - e.0 * i.1 > 0.0;
            let v_phase = phase_voltage(&self.cfg);
            if !follows || psi_a * w_if < 0.02 * v_phase {
                return Err(CommissioningError::NoBackEmf);
            }
            self.psi_f = psi_a - (self.ld - self.lq) * self.i_d_sum * k;
        }
        if n >= stop {
            return Ok(CommissioningStep::Done(CommissioningResult {
                rs_ohm: self.rs,
                ld_h: self.ld,
                lq_h: self.lq,
                psi_f_wb: self.psi_f,
                voltage_error_v: self.e_sat,
                current_band_a: self.band,
                bus_v: self.vdc_mean,
                curve: self.curve,
                direction: 1,
                duration_s: self.total as f32 * self.ts,
            }));
        }
        // Apply at the middle of the application window, 1.5 periods ahead, with the
        // identified inverter compensation from the current reference.
        let th = self.theta + 1.5 * self.omega * self.ts;
        let (sa, ca) = sin_cos(th);
        let u_alpha = ca * u_d - sa * u_q;
        let u_beta = sa * u_d + ca * u_q;
        let (ia, ib) = (ca * i_ref, sa * i_ref);
        let h = 0.866_025_4;
        let phases = [ia, -0.5 * ia + h * ib, -0.5 * ia - h * ib];
        let band = self.band;
        let sign = |i: f32| (i / band).clamp(-1.0, 1.0);
        let [sa_, sb_, sc_] = phases.map(|i| self.e_sat * sign(i));
        let comp_alpha = (2.0 * sa_ - sb_ - sc_) / 3.0;
        let comp_beta = (sb_ - sc_) / 1.732_050_8;
        self.theta += self.omega * self.ts;
        if self.theta > core::f32::consts::PI {
            self.theta -= 2.0 * core::f32::consts::PI;
        }
        Ok(CommissioningStep::Apply(u_alpha + comp_alpha, u_beta + comp_beta))
    }
}

/// `x` limited to `[-limit, limit]` (`limit >= 0`). `f32::clamp` with bounds that are
/// not constants asserts their order and links float formatting (a path to a panic in
/// the firmware images, `.ci/no-panic`); NaN passes through, as with `clamp`.
fn within(x: f32, limit: f32) -> f32 {
    if x > limit {
        limit
    } else if x < -limit {
        -limit
    } else {
        x
    }
}
