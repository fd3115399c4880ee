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
//! checked). Reading ([`Capture::sample`]) is meant for when recording is over
//! ([`CaptureState::Done`]), the only time a sample can no longer change.
//!
//! # Units
//! SI, `f32`, as [`crate::link`] and the trace format: volts, amperes, rad/s², m/s,
//! webers; the angle as the estimator's binary [`Angle`], so that a host comparing it
//! with a replay converts it to radians exactly as the replay does.

use crate::drive::{DriveState, StepOutput};
use crate::num::{Angle, Scalar};
use crate::units::Base;

/// One control step of a capture (SI units).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CaptureSample {
    /// Voltage applied during `[t_k, t_k + Ts)` as the observer sees it, α, V (the trace's
    /// `u_alpha`).
    pub u_alpha: f32,
    /// The same, β, V (`u_beta`).
    pub u_beta: f32,
    /// Current as the observer saw it at `t_k`, α, A (`i_alpha`).
    pub i_alpha: f32,
    /// The same, β, A (`i_beta`).
    pub i_beta: f32,
    /// Commanded electrical acceleration the estimator used, rad/s² (`alpha_e_ref`).
    pub alpha_e_ref: f32,
    /// Estimated electrical angle.
    pub theta_hat: Angle,
    /// Estimated speed, m/s.
    pub v_hat: f32,
    /// Estimated mover flux, α, Wb.
    pub psi_alpha_hat: f32,
    /// Estimated mover flux, β, Wb.
    pub psi_beta_hat: f32,
}

impl CaptureSample {
    /// Bytes of a sample on the wire.
    pub const WIRE_LEN: usize = 36;

    /// The sample from one step's output, in SI; `None` without an estimate.
    pub fn from_step<T: Scalar>(out: &StepOutput<T>, base: &Base) -> Option<Self> {
        let e = out.estimate?;
        Some(CaptureSample {
            u_alpha: base.to_volts(out.u_applied.alpha),
            u_beta: base.to_volts(out.u_applied.beta),
            i_alpha: base.to_amperes(out.i_observer.alpha),
            i_beta: base.to_amperes(out.i_observer.beta),
            alpha_e_ref: base.to_rad_per_s(out.alpha_e_ref) / base.time_s(),
            theta_hat: e.theta_e,
            v_hat: e.speed_m_per_s.to_f32(),
            psi_alpha_hat: base.to_webers(e.psi_ab.alpha),
            psi_beta_hat: base.to_webers(e.psi_ab.beta),
        })
    }

    /// Little-endian wire form: the eight `f32` as IEEE bits and the angle as `i32`, in
    /// field order (u_α, u_β, i_α, i_β, alpha_e_ref, θ̂, v̂, ψ̂_α, ψ̂_β).
    pub fn to_le_bytes(&self) -> [u8; Self::WIRE_LEN] {
        let words = [
            self.u_alpha.to_bits(),
            self.u_beta.to_bits(),
            self.i_alpha.to_bits(),
            self.i_beta.to_bits(),
            self.alpha_e_ref.to_bits(),
            self.theta_hat.bits() as u32,
            self.v_hat.to_bits(),
            self.psi_alpha_hat.to_bits(),
            self.psi_beta_hat.to_bits(),
        ];
        let mut out = [0u8; Self::WIRE_LEN];
        for (chunk, w) in out.chunks_exact_mut(4).zip(words) {
            chunk.iter_mut().zip(w.to_le_bytes()).for_each(|(d, s)| *d = s);
        }
        out
    }

    /// The inverse of [`CaptureSample::to_le_bytes`]; `None` when a value is not finite.
    pub fn from_le_bytes(bytes: &[u8; Self::WIRE_LEN]) -> Option<Self> {
        let mut words = [0u32; 9];
        for (w, chunk) in words.iter_mut().zip(bytes.chunks_exact(4)) {
            *w = u32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
        }
        let f = f32::from_bits;
        let s = CaptureSample {
            u_alpha: f(words[0]),
            u_beta: f(words[1]),
            i_alpha: f(words[2]),
            i_beta: f(words[3]),
            alpha_e_ref: f(words[4]),
            theta_hat: Angle::from_bits(words[5] as i32),
            v_hat: f(words[6]),
            psi_alpha_hat: f(words[7]),
            psi_beta_hat: f(words[8]),
        };
        let floats = [
            s.u_alpha,
            s.u_beta,
            s.i_alpha,
            s.i_beta,
            s.alpha_e_ref,
            s.v_hat,
            s.psi_alpha_hat,
            s.psi_beta_hat,
        ];
        floats.iter().all(|x| x.is_finite()).then_some(s)
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
}

impl<const N: usize> Default for Capture<N> {
    fn default() -> Self {
        Self::new()
    }
}

const EMPTY: CaptureSample = CaptureSample {
    u_alpha: 0.0,
    u_beta: 0.0,
    i_alpha: 0.0,
    i_beta: 0.0,
    alpha_e_ref: 0.0,
    theta_hat: Angle::ZERO,
    v_hat: 0.0,
    psi_alpha_hat: 0.0,
    psi_beta_hat: 0.0,
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
    pub fn record<T: Scalar>(&mut self, out: &StepOutput<T>, base: &Base) {
        let sample = CaptureSample::from_step(out, base);
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
    use crate::drive::{Drive, DriveConfig, Measurements};
    use crate::motor::MotorParams;
    use crate::observer::ObserverKind;
    use crate::transforms::Abc;

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
            u_alpha: -12.5,
            u_beta: 1e-7,
            i_alpha: 3.0,
            i_beta: -0.0,
            alpha_e_ref: 251.3,
            theta_hat: Angle::from_bits(-123_456_789),
            v_hat: 0.3,
            psi_alpha_hat: 0.16,
            psi_beta_hat: -0.01,
        };
        let back = CaptureSample::from_le_bytes(&s.to_le_bytes()).unwrap();
        assert_eq!(back.to_le_bytes(), s.to_le_bytes());
        let mut bad = s.to_le_bytes();
        bad[24..28].copy_from_slice(&f32::NAN.to_bits().to_le_bytes());
        assert_eq!(CaptureSample::from_le_bytes(&bad), None);
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
            c.record(&out, &Base::SI);
            if first.is_none() && out.estimate.is_none() {
                // Until the estimator starts, the capture waits, empty.
                assert_eq!((c.state(), c.len()), (CaptureState::Armed, 0), "step {k}");
            }
            if out.estimate.is_some() && first.is_none() {
                first = Some(k);
                assert_eq!(c.state(), CaptureState::Recording);
                assert_eq!(c.sample(0), CaptureSample::from_step(&out, &Base::SI).as_ref());
            }
            if let Some(f) = first
                && k - f < 64
            {
                assert_eq!(c.sample(k - f), CaptureSample::from_step(&out, &Base::SI).as_ref());
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
            c.record(&out, &Base::SI);
            steps += 1;
            if out.estimate.is_some() || steps > 20_000 {
                break;
            }
        }
        c.arm();
        for _ in 0..10 {
            let out = d.step(&quiet());
            assert!(out.estimate.is_some());
            c.record(&out, &Base::SI);
        }
        assert_eq!((c.state(), c.len()), (CaptureState::Armed, 0));
        // Disabled and enabled again: the estimator's start records; a disable ends the
        // capture early with what it holds.
        d.disable();
        c.record(&d.step(&quiet()), &Base::SI);
        d.enable();
        let mut steps = 0;
        while c.state() != CaptureState::Recording && steps < 20_000 {
            c.record(&d.step(&quiet()), &Base::SI);
            steps += 1;
        }
        for _ in 0..9 {
            c.record(&d.step(&quiet()), &Base::SI);
        }
        d.disable();
        c.record(&d.step(&quiet()), &Base::SI);
        assert_eq!((c.state(), c.len()), (CaptureState::Done, 10));
    }
}
