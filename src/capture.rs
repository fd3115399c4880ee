//! A triggered, fixed-capacity capture of the drive at full rate: what its estimator was
//! given (u_αβ, i_αβ, the commanded acceleration) and what it estimated (θ̂, v̂, ψ̂_αβ),
//! one [`CaptureSample`] per control step, filled from the control interrupt.
//!
//! # Trigger: the estimator's start
//! A trace replays bit for bit only from the estimator's initial state: the trace
//! format carries the estimator's inputs, not its state. So an armed capture
//! ([`Capture::arm`]) starts at the first step *with* an estimate after a step without
//! one, the step right after the drive reset its estimator on leaving calibration
//! (every enable, every clear of a fault, goes that way). It stops when full, when the
//! estimate stops (disabled, fault), or when the drive reacquires from `Running` or
//! `LowSpeed` (its [`crate::estimator::Estimator::reacquire`] changes the estimator's
//! state in a way no trace column records: samples up to that step are kept and
//! replayable). The catch on enable (`Reacquiring` straight out of calibration) does not
//! reacquire and is captured.
//!
//! # Cost in the interrupt
//! [`Capture::record`] is a state check and, while recording, a copy of nine words
//! into a fixed array: no allocation, no loop over data, no panic (every index is
//! checked), no conversion. Reading ([`Capture::sample`]) is meant for when recording
//! is over ([`CaptureState::Done`]), the only time a sample can no longer change.
//!
//! # Units: the drive's own working values, bit for bit
//! A sample holds each value as the raw bits of the drive's number type in its working
//! units ([`CaptureFormat`]): `f32` bits in SI for an `f32` drive, Q8.24 bits in the
//! motor's per-unit base ([`Base::for_motor`]) for a `Q24` drive; the angle as the
//! estimator's binary [`Angle`]. So nothing is rounded on the target, and a replay fed
//! the same words reproduces the drive's estimates exactly.
//!
//! On the host, [`CaptureFormat::to_si`] turns a word into SI as `f64` and
//! [`CaptureFormat::from_si`] back: for `Q24`, `bits · 2⁻²⁴ · scale` with the scale of
//! the quantity ([`Quantity::scale`], an `f64` product of the base's `f32` values, so
//! exact) is one rounding away from the exact value (relative error 2⁻⁵³), and the
//! inverse `round(si / scale · 2²⁴)` is then off by at most `2³¹ · 2⁻⁵² = 2⁻²¹` before
//! rounding: it gives back the same bits for every `i32` (tested over the extremes and
//! a million values per quantity). Written as `f64` in its shortest round-trip text (the
//! trace writer's number format), an SI value therefore carries the Q8.24 value exactly.

use crate::drive::{DriveState, StepOutput};
use crate::num::units::Base;
use crate::num::{Angle, Q24, Scalar};

/// How a [`CaptureSample`]'s words are to be read: the drive's number type and its
/// working units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CaptureFormat {
    /// IEEE-754 `f32` bits, SI units ([`Base::SI`]): the M4F images.
    #[default]
    F32,
    /// Q8.24 bits (`i32`, value · 2²⁴) in the per-unit base of the drive's motor
    /// ([`Base::for_motor`]): the M3 image's `Drive<Q24>`.
    Q24,
}

impl CaptureFormat {
    /// Wire code: 0 `f32`, 1 Q8.24.
    pub const fn code(self) -> u8 {
        match self {
            CaptureFormat::F32 => 0,
            CaptureFormat::Q24 => 1,
        }
    }

    /// The format with wire code `code`, `None` for an unknown code.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(CaptureFormat::F32),
            1 => Some(CaptureFormat::Q24),
            _ => None,
        }
    }

    /// Its name in traces and on the command line: `f32`, `q24`.
    pub const fn name(self) -> &'static str {
        match self {
            CaptureFormat::F32 => "f32",
            CaptureFormat::Q24 => "q24",
        }
    }

    /// The word of a working value of quantity `q` in SI units, as `f64`: exact for `f32`
    /// in [`Base::SI`]; for `Q24` one rounding from exact (see the module docs).
    pub fn to_si(self, word: u32, q: Quantity, base: &Base) -> f64 {
        match self {
            CaptureFormat::F32 => f64::from(f32::from_bits(word)) * q.scale(base),
            CaptureFormat::Q24 => f64::from(word as i32) * Q24_LSB * q.scale(base),
        }
    }

    /// The inverse of [`CaptureFormat::to_si`]: the word whose SI value is `si`, rounded
    /// to the nearest; `None` when `si` is not finite or beyond the type's range (|x|
    /// above 3.4e38 for `f32`, 128 working units for `Q24`).
    pub fn from_si(self, si: f64, q: Quantity, base: &Base) -> Option<u32> {
        if !si.is_finite() {
            return None;
        }
        let working = si / q.scale(base);
        match self {
            CaptureFormat::F32 => {
                let x = working as f32;
                x.is_finite().then_some(x.to_bits())
            }
            CaptureFormat::Q24 => {
                let bits = libm::round(working * Q24_SCALE);
                (bits >= f64::from(i32::MIN) && bits <= f64::from(i32::MAX)).then_some(bits as i32 as u32)
            }
        }
    }

    /// `true` when `word` is a usable value of this format (a finite `f32`; any `Q24`).
    pub fn word_ok(self, word: u32) -> bool {
        match self {
            CaptureFormat::F32 => f32::from_bits(word).is_finite(),
            CaptureFormat::Q24 => true,
        }
    }
}

/// 2²⁴: a Q8.24 value's bits per unit.
const Q24_SCALE: f64 = 16_777_216.0;
/// 2⁻²⁴.
const Q24_LSB: f64 = 1.0 / Q24_SCALE;

/// The physical quantity of a captured value, for its per-unit scale.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quantity {
    /// Voltage: SI V per working unit = [`Base::voltage_v`].
    Voltage,
    /// Current: A per working unit = [`Base::current_a`].
    Current,
    /// Flux linkage: Wb per working unit = [`Base::flux_wb`].
    Flux,
    /// Electrical acceleration: rad/s² per working unit = [`Base::omega_rad_s`]² (a rate
    /// of angular frequency per unit of time).
    Acceleration,
    /// Linear speed: m/s in every unit system, scale 1.
    Speed,
}

impl Quantity {
    /// SI units per working unit under `base`, as `f64`: the base's `f32` values widened,
    /// and for the acceleration the square of one, so exact (48 significant bits).
    pub fn scale(self, base: &Base) -> f64 {
        match self {
            Quantity::Voltage => f64::from(base.voltage_v),
            Quantity::Current => f64::from(base.current_a),
            Quantity::Flux => f64::from(base.flux_wb()),
            Quantity::Acceleration => f64::from(base.omega_rad_s) * f64::from(base.omega_rad_s),
            Quantity::Speed => 1.0,
        }
    }
}

/// A number type a drive can be captured in: its [`CaptureFormat`] and its bits.
pub trait CaptureScalar: Scalar {
    /// How this type's words read.
    const FORMAT: CaptureFormat;
    /// The raw bits of a value (`f32::to_bits`, [`Q24::to_bits`]).
    fn to_word(self) -> u32;
    /// The value of raw bits (the inverse of [`CaptureScalar::to_word`]).
    fn from_word(word: u32) -> Self;
}

impl CaptureScalar for f32 {
    const FORMAT: CaptureFormat = CaptureFormat::F32;
    fn to_word(self) -> u32 {
        self.to_bits()
    }
    fn from_word(word: u32) -> Self {
        f32::from_bits(word)
    }
}

impl CaptureScalar for Q24 {
    const FORMAT: CaptureFormat = CaptureFormat::Q24;
    fn to_word(self) -> u32 {
        self.to_bits() as u32
    }
    fn from_word(word: u32) -> Self {
        Q24::from_bits(word as i32)
    }
}

/// One control step of a capture: raw words of the drive's number type in its working
/// units (see [`CaptureFormat`]; SI after [`CaptureSample::to_si`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CaptureSample {
    /// Voltage applied during `[t_k, t_k + Ts)` as the observer sees it, α (voltage; the
    /// trace's `u_alpha`, V).
    pub u_alpha: u32,
    /// The same, β (`u_beta`).
    pub u_beta: u32,
    /// Current as the observer saw it at `t_k`, α (current; `i_alpha`, A).
    pub i_alpha: u32,
    /// The same, β (`i_beta`).
    pub i_beta: u32,
    /// Commanded electrical acceleration the estimator used (acceleration;
    /// `alpha_e_ref`, rad/s²).
    pub alpha_e_ref: u32,
    /// Estimated electrical angle.
    pub theta_hat: Angle,
    /// Estimated speed (speed, m/s).
    pub v_hat: u32,
    /// Estimated mover flux, α (flux, Wb).
    pub psi_alpha_hat: u32,
    /// Estimated mover flux, β (flux, Wb).
    pub psi_beta_hat: u32,
}

/// A [`CaptureSample`] in SI units, `f64` (see [`CaptureFormat::to_si`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SiSample {
    /// u_α, V.
    pub u_alpha: f64,
    /// u_β, V.
    pub u_beta: f64,
    /// i_α, A.
    pub i_alpha: f64,
    /// i_β, A.
    pub i_beta: f64,
    /// Commanded electrical acceleration, rad/s².
    pub alpha_e_ref: f64,
    /// Estimated electrical angle (binary; exact).
    pub theta_hat: Angle,
    /// Estimated speed, m/s.
    pub v_hat: f64,
    /// Estimated mover flux α, Wb.
    pub psi_alpha_hat: f64,
    /// Estimated mover flux β, Wb.
    pub psi_beta_hat: f64,
}

impl CaptureSample {
    /// Bytes of a sample on the wire.
    pub const WIRE_LEN: usize = 36;

    /// The sample from one step's output; `None` without an estimate.
    pub fn from_step<T: CaptureScalar>(out: &StepOutput<T>) -> Option<Self> {
        let e = out.estimate?;
        Some(CaptureSample {
            u_alpha: out.u_applied.alpha.to_word(),
            u_beta: out.u_applied.beta.to_word(),
            i_alpha: out.i_observer.alpha.to_word(),
            i_beta: out.i_observer.beta.to_word(),
            alpha_e_ref: out.alpha_e_ref.to_word(),
            theta_hat: e.theta_e,
            v_hat: e.speed_m_per_s.to_word(),
            psi_alpha_hat: e.psi_ab.alpha.to_word(),
            psi_beta_hat: e.psi_ab.beta.to_word(),
        })
    }

    /// The eight value words with their quantities, in field order (the angle apart).
    pub fn words(&self) -> [(u32, Quantity); 8] {
        [
            (self.u_alpha, Quantity::Voltage),
            (self.u_beta, Quantity::Voltage),
            (self.i_alpha, Quantity::Current),
            (self.i_beta, Quantity::Current),
            (self.alpha_e_ref, Quantity::Acceleration),
            (self.v_hat, Quantity::Speed),
            (self.psi_alpha_hat, Quantity::Flux),
            (self.psi_beta_hat, Quantity::Flux),
        ]
    }

    /// `true` when every word is a usable value of `format`.
    pub fn valid(&self, format: CaptureFormat) -> bool {
        self.words().iter().all(|(w, _)| format.word_ok(*w))
    }

    /// The sample in SI units, read as `format` in working units of `base`.
    pub fn to_si(&self, format: CaptureFormat, base: &Base) -> SiSample {
        let si = |w: u32, q: Quantity| format.to_si(w, q, base);
        SiSample {
            u_alpha: si(self.u_alpha, Quantity::Voltage),
            u_beta: si(self.u_beta, Quantity::Voltage),
            i_alpha: si(self.i_alpha, Quantity::Current),
            i_beta: si(self.i_beta, Quantity::Current),
            alpha_e_ref: si(self.alpha_e_ref, Quantity::Acceleration),
            theta_hat: self.theta_hat,
            v_hat: si(self.v_hat, Quantity::Speed),
            psi_alpha_hat: si(self.psi_alpha_hat, Quantity::Flux),
            psi_beta_hat: si(self.psi_beta_hat, Quantity::Flux),
        }
    }

    /// Little-endian wire form: the nine words in field order (u_α, u_β, i_α, i_β,
    /// alpha_e_ref, θ̂ as `i32`, v̂, ψ̂_α, ψ̂_β).
    pub fn to_le_bytes(&self) -> [u8; Self::WIRE_LEN] {
        let words = [
            self.u_alpha,
            self.u_beta,
            self.i_alpha,
            self.i_beta,
            self.alpha_e_ref,
            self.theta_hat.bits() as u32,
            self.v_hat,
            self.psi_alpha_hat,
            self.psi_beta_hat,
        ];
        let mut out = [0u8; Self::WIRE_LEN];
        for (chunk, w) in out.chunks_exact_mut(4).zip(words) {
            chunk.iter_mut().zip(w.to_le_bytes()).for_each(|(d, s)| *d = s);
        }
        out
    }

    /// The inverse of [`CaptureSample::to_le_bytes`] (any bits; [`CaptureSample::valid`]
    /// checks them against a format).
    pub fn from_le_bytes(bytes: &[u8; Self::WIRE_LEN]) -> Self {
        let mut w = [0u32; 9];
        for (w, chunk) in w.iter_mut().zip(bytes.chunks_exact(4)) {
            *w = u32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
        }
        CaptureSample {
            u_alpha: w[0],
            u_beta: w[1],
            i_alpha: w[2],
            i_beta: w[3],
            alpha_e_ref: w[4],
            theta_hat: Angle::from_bits(w[5] as i32),
            v_hat: w[6],
            psi_alpha_hat: w[7],
            psi_beta_hat: w[8],
        }
    }
}

/// Where a capture stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CaptureState {
    /// Not armed; holds whatever the last capture left (nothing after power-on).
    #[default]
    Idle,
    /// Waiting for the estimator's start.
    Armed,
    /// Recording, one sample a step.
    Recording,
    /// Over: the samples held are final and can be read.
    Done,
}

impl CaptureState {
    /// Wire code: 0 idle, 1 armed, 2 recording, 3 done.
    pub const fn code(self) -> u8 {
        match self {
            CaptureState::Idle => 0,
            CaptureState::Armed => 1,
            CaptureState::Recording => 2,
            CaptureState::Done => 3,
        }
    }

    /// The state with wire code `code`, `None` for an unknown code.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(CaptureState::Idle),
            1 => Some(CaptureState::Armed),
            2 => Some(CaptureState::Recording),
            3 => Some(CaptureState::Done),
            _ => None,
        }
    }
}

/// A capture of up to `N` samples. See the module documentation.
#[derive(Clone, Debug)]
pub struct Capture<const N: usize> {
    samples: [CaptureSample; N],
    len: usize,
    state: CaptureState,
    /// Whether the previous step had an estimate, and its drive state.
    had_estimate: bool,
    last_state: DriveState,
    /// The number type of the samples (set by [`Capture::record`]).
    format: CaptureFormat,
}

impl<const N: usize> Default for Capture<N> {
    fn default() -> Self {
        Self::new()
    }
}

const EMPTY: CaptureSample = CaptureSample {
    u_alpha: 0,
    u_beta: 0,
    i_alpha: 0,
    i_beta: 0,
    alpha_e_ref: 0,
    theta_hat: Angle::ZERO,
    v_hat: 0,
    psi_alpha_hat: 0,
    psi_beta_hat: 0,
};

impl<const N: usize> Capture<N> {
    /// An idle, empty capture.
    pub const fn new() -> Self {
        Capture {
            samples: [EMPTY; N],
            len: 0,
            state: CaptureState::Idle,
            had_estimate: false,
            last_state: DriveState::Disabled,
            format: CaptureFormat::F32,
        }
    }

    /// Capacity, samples.
    pub const fn capacity(&self) -> usize {
        N
    }

    /// Forgets what was captured and waits for the estimator's next start.
    pub fn arm(&mut self) {
        self.len = 0;
        self.state = CaptureState::Armed;
    }

    /// Stops: `Done` with what was recorded (an armed capture that never started ends
    /// empty).
    pub fn stop(&mut self) {
        if self.state != CaptureState::Idle {
            self.state = CaptureState::Done;
        }
    }

    /// One control step's output (call once per step, after [`crate::drive::Drive::step`]).
    pub fn record<T: CaptureScalar>(&mut self, out: &StepOutput<T>) {
        let sample = CaptureSample::from_step(out);
        self.format = T::FORMAT;
        let started = sample.is_some() && !self.had_estimate;
        let reacquired = out.state == DriveState::Reacquiring
            && matches!(self.last_state, DriveState::Running | DriveState::LowSpeed);
        self.had_estimate = sample.is_some();
        self.last_state = out.state;
        match self.state {
            CaptureState::Armed if started => self.state = CaptureState::Recording,
            CaptureState::Recording if sample.is_none() || reacquired => {
                self.state = CaptureState::Done;
                return;
            }
            CaptureState::Recording => {}
            _ => return,
        }
        let (Some(s), Some(slot)) = (sample, self.samples.get_mut(self.len)) else {
            self.state = CaptureState::Done;
            return;
        };
        *slot = s;
        self.len += 1;
        if self.len >= N {
            self.state = CaptureState::Done;
        }
    }

    /// Where the capture stands.
    pub fn state(&self) -> CaptureState {
        self.state
    }

    /// How the samples' words read: the number type of the drive recorded last.
    pub fn format(&self) -> CaptureFormat {
        self.format
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// `true` when no sample is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Sample `index` (0 is the estimator's first step), `None` past the end.
    pub fn sample(&self, index: usize) -> Option<&CaptureSample> {
        self.samples.get(..self.len)?.get(index)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::algorithms::observer::ObserverKind;
    use crate::algorithms::transforms::Abc;
    use crate::drive::{Drive, DriveConfig, Measurements};
    use crate::motor::MotorParams;

    fn drive() -> Drive<f32> {
        let m = MotorParams::paper();
        Drive::new(&m, &DriveConfig::for_motor(&m, 311.0, ObserverKind::Dcfo), &Base::SI).unwrap()
    }

    fn quiet() -> Measurements<f32> {
        Measurements { i_abc: Abc { a: 0.0, b: 0.0, c: 0.0 }, vdc: 311.0 }
    }

    #[test]
    fn samples_round_trip_through_their_wire_form() {
        let s = CaptureSample {
            u_alpha: (-12.5f32).to_bits(),
            u_beta: 1e-7f32.to_bits(),
            i_alpha: 3.0f32.to_bits(),
            i_beta: (-0.0f32).to_bits(),
            alpha_e_ref: 251.3f32.to_bits(),
            theta_hat: Angle::from_bits(-123_456_789),
            v_hat: 0.3f32.to_bits(),
            psi_alpha_hat: 0.16f32.to_bits(),
            psi_beta_hat: (-0.01f32).to_bits(),
        };
        let back = CaptureSample::from_le_bytes(&s.to_le_bytes());
        assert_eq!(back, s);
        assert!(back.valid(CaptureFormat::F32));
        let mut bad = s.to_le_bytes();
        bad[24..28].copy_from_slice(&f32::NAN.to_bits().to_le_bytes());
        let bad = CaptureSample::from_le_bytes(&bad);
        assert!(!bad.valid(CaptureFormat::F32), "a NaN speed is not an f32 value");
        assert!(bad.valid(CaptureFormat::Q24), "every word is a Q8.24 value");
        for f in [CaptureFormat::F32, CaptureFormat::Q24] {
            assert_eq!(CaptureFormat::from_code(f.code()), Some(f));
        }
        assert_eq!(CaptureFormat::from_code(2), None);
    }

    /// Q8.24 words to SI `f64` and back give the same bits, for every quantity, in the
    /// per-unit bases of the paper motor, of two awkward ones and in SI: the extremes,
    /// every power of two and its neighbours, and a million pseudo-random words per
    /// quantity and base. (The host's `capture_trace` tests add the trip through text.)
    #[test]
    fn q24_words_survive_si_f64_exactly() {
        let bases = [
            Base::SI,
            Base::for_motor(&MotorParams::paper()),
            // Scalings whose f32 values use all 24 significand bits, and small/large ones.
            Base { voltage_v: 179.629_36, current_a: 2.969_848_5, omega_rad_s: 1_122.683_5 },
            Base { voltage_v: 0.333_333_34, current_a: 1e-3, omega_rad_s: 3.0e4 },
        ];
        let quantities =
            [Quantity::Voltage, Quantity::Current, Quantity::Flux, Quantity::Acceleration, Quantity::Speed];
        for base in &bases {
            for q in quantities {
                let check = |w: i32| {
                    let si = CaptureFormat::Q24.to_si(w as u32, q, base);
                    assert_eq!(CaptureFormat::Q24.from_si(si, q, base), Some(w as u32), "{q:?} {base:?} {w}");
                };
                for w in [0, 1, -1, i32::MAX, i32::MIN, i32::MAX - 1, i32::MIN + 1] {
                    check(w);
                }
                for k in 0..31 {
                    for d in [-1i32, 0, 1] {
                        check((1i32 << k).wrapping_add(d));
                        check((-(1i32 << k)).wrapping_add(d));
                    }
                }
                let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
                for _ in 0..1_000_000 {
                    // xorshift64*
                    x ^= x >> 12;
                    x ^= x << 25;
                    x ^= x >> 27;
                    check((x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 32) as u32 as i32);
                }
            }
        }
        // f32 in SI: exact both ways.
        for v in [0.0f32, -0.0, 1e-45, -3.4e38, 0.3, 311.0] {
            let si = CaptureFormat::F32.to_si(v.to_bits(), Quantity::Voltage, &Base::SI);
            assert_eq!(si, f64::from(v));
            assert_eq!(CaptureFormat::F32.from_si(si, Quantity::Voltage, &Base::SI), Some(v.to_bits()));
        }
        // Out of range and not finite: refused.
        let b = Base::for_motor(&MotorParams::paper());
        let top = CaptureFormat::Q24.to_si(i32::MAX as u32, Quantity::Voltage, &b);
        assert_eq!(CaptureFormat::Q24.from_si(top * 1.001, Quantity::Voltage, &b), None);
        assert_eq!(CaptureFormat::Q24.from_si(f64::NAN, Quantity::Voltage, &b), None);
        assert_eq!(CaptureFormat::F32.from_si(1e39, Quantity::Voltage, &Base::SI), None);
    }

    /// Armed while disabled, the capture starts at the estimator's first step (the one
    /// that leaves calibration), holds exactly what the drive reported step by step,
    /// stops when full, and a disable ends a capture early.
    #[test]
    fn starts_at_the_estimators_first_step_and_stops_when_full() {
        let mut d = drive();
        let mut c = Capture::<64>::new();
        c.arm();
        d.set_speed_reference(d.omega_from_speed(0.3));
        d.enable();
        let mut first: Option<usize> = None;
        for k in 0..20_000 {
            let out = d.step(&quiet());
            c.record(&out);
            if first.is_none() && out.estimate.is_none() {
                // Until the estimator starts, the capture waits, empty.
                assert_eq!((c.state(), c.len()), (CaptureState::Armed, 0), "step {k}");
            }
            if out.estimate.is_some() && first.is_none() {
                first = Some(k);
                assert_eq!(c.state(), CaptureState::Recording);
                assert_eq!(c.sample(0), CaptureSample::from_step(&out).as_ref());
            }
            if let Some(f) = first
                && k - f < 64
            {
                assert_eq!(c.sample(k - f), CaptureSample::from_step(&out).as_ref());
            }
        }
        assert!(first.is_some());
        assert_eq!((c.state(), c.len()), (CaptureState::Done, 64));
        assert_eq!(c.sample(64), None);
        // Armed again while the estimator runs: waits for its next start, empty.
        let mut d = drive();
        d.set_speed_reference(d.omega_from_speed(0.3));
        d.enable();
        let mut steps = 0;
        loop {
            let out = d.step(&quiet());
            c.record(&out);
            steps += 1;
            if out.estimate.is_some() || steps > 20_000 {
                break;
            }
        }
        c.arm();
        for _ in 0..10 {
            let out = d.step(&quiet());
            assert!(out.estimate.is_some());
            c.record(&out);
        }
        assert_eq!((c.state(), c.len()), (CaptureState::Armed, 0));
        // Disabled and enabled again: the estimator's start records; a disable ends the
        // capture early with what it holds.
        d.disable();
        c.record(&d.step(&quiet()));
        d.enable();
        let mut steps = 0;
        while c.state() != CaptureState::Recording && steps < 20_000 {
            c.record(&d.step(&quiet()));
            steps += 1;
        }
        for _ in 0..9 {
            c.record(&d.step(&quiet()));
        }
        d.disable();
        c.record(&d.step(&quiet()));
        assert_eq!((c.state(), c.len()), (CaptureState::Done, 10));
    }
}
