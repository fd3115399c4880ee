//! The part every voltage-model flux observer shares: the back-EMF increment
//! `integral(u - Rs i)` over one period, and the inductive correction `- Ls i`.

use super::{FluxEstimate, ObserverFault, ObserverInput, check_input};
use crate::algorithms::transforms::AlphaBeta;
use crate::motor::MotorParams;
use crate::num::Scalar;
use crate::num::units::Base;

/// The motor constants an observer needs, in working units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObserverMotor<T> {
    /// Stator resistance (ohm).
    pub rs: T,
    /// Inductance used to remove the inductive flux (H): `Lq`, so that a salient motor
    /// gives the active flux.
    pub ls: T,
    /// Saliency `Ld - Lq` (H): the active flux's magnitude is `psi_f + (Ld - Lq) i_d`.
    pub saliency: T,
}

impl<T: Scalar> ObserverMotor<T> {
    /// Takes `Rs`, `Lq` and `Ld - Lq` from `motor`, converted with `base`.
    pub fn new(motor: &MotorParams, base: &Base) -> Self {
        ObserverMotor {
            rs: base.resistance(motor.rs_ohm),
            ls: base.inductance(motor.lq_h),
            saliency: base.inductance(motor.ld_h - motor.lq_h),
        }
    }
}

/// Per-sample voltage-model arithmetic with the one sample of current history that the
/// trapezoidal resistive drop needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct VoltageModel<T> {
    pub(super) motor: ObserverMotor<T>,
    i_prev: Option<AlphaBeta<T>>,
}

impl<T: Scalar> VoltageModel<T> {
    pub(super) fn new(motor: ObserverMotor<T>) -> Self {
        VoltageModel { motor, i_prev: None }
    }

    /// `dt * (u - Rs * (i_prev + i) / 2)` per axis (Wb): the exact integral of a held
    /// voltage less the trapezoidal integral of the resistive drop. On the first sample
    /// after a reset the present current stands in for the previous one.
    pub(super) fn emf_increment(&mut self, input: &ObserverInput<T>) -> AlphaBeta<T> {
        let i = input.i_ab;
        let prev = self.i_prev.unwrap_or(i);
        self.i_prev = Some(i);
        let half_rs = self.motor.rs * T::HALF;
        AlphaBeta {
            alpha: input.dt * (input.u_ab.alpha - half_rs * (prev.alpha + i.alpha)),
            beta: input.dt * (input.u_ab.beta - half_rs * (prev.beta + i.beta)),
        }
    }

    /// `psi_stator - Ls i` (Wb): the mover flux from a stator-flux-like state.
    pub(super) fn mover_flux(&self, psi_stator: AlphaBeta<T>, i: AlphaBeta<T>) -> AlphaBeta<T> {
        AlphaBeta {
            alpha: psi_stator.alpha - self.motor.ls * i.alpha,
            beta: psi_stator.beta - self.motor.ls * i.beta,
        }
    }

    pub(super) fn reset(&mut self) {
        self.i_prev = None;
    }

    /// The previous sample's current (A; zero after a reset, before the first sample).
    pub(super) fn previous_current(&self) -> AlphaBeta<T> {
        self.i_prev.unwrap_or_default()
    }

    /// Takes `i` (A) as the previous sample's current (no start-up special case next).
    pub(super) fn set_previous_current(&mut self, i: AlphaBeta<T>) {
        self.i_prev = Some(i);
    }
}

/// The state the pure-integrator and LPF observers share: the stator-flux integral with
/// an optional leak, `psi_s <- (psi_s * keep + increment) * scale`, and the latched
/// overflow fault. `keep = scale = 1` is the pure integrator.
#[derive(Clone, Debug)]
pub(super) struct StatorFlux<T> {
    model: VoltageModel<T>,
    psi_stator: AlphaBeta<T>,
    faulted: bool,
}

impl<T: Scalar> StatorFlux<T> {
    pub(super) fn new(motor: ObserverMotor<T>) -> Self {
        StatorFlux { model: VoltageModel::new(motor), psi_stator: AlphaBeta::default(), faulted: false }
    }

    pub(super) fn set(&mut self, psi_stator: AlphaBeta<T>) {
        self.psi_stator = psi_stator;
    }

    /// Starts from mover flux `psi_mover` (Wb) at current `i` (A); clears a latched
    /// overflow.
    pub(super) fn seed(&mut self, psi_mover: AlphaBeta<T>, i: AlphaBeta<T>) {
        let ls = self.model.motor.ls;
        self.psi_stator = AlphaBeta::new(psi_mover.alpha + ls * i.alpha, psi_mover.beta + ls * i.beta);
        self.model.set_previous_current(i);
        self.faulted = false;
    }

    /// One sample (see the struct docs); refuses bad input without touching the state
    /// and latches an overflow until [`StatorFlux::reset`].
    pub(super) fn update(
        &mut self,
        input: &ObserverInput<T>,
        keep: T,
        scale: T,
    ) -> Result<FluxEstimate<T>, ObserverFault> {
        if self.faulted {
            return Err(ObserverFault::StateOverflow);
        }
        check_input(input)?;
        let de = self.model.emf_increment(input);
        let next = AlphaBeta {
            alpha: (self.psi_stator.alpha * keep + de.alpha) * scale,
            beta: (self.psi_stator.beta * keep + de.beta) * scale,
        };
        let psi_ab = self.model.mover_flux(next, input.i_ab);
        if !(next.is_valid() && psi_ab.is_valid()) {
            self.faulted = true;
            return Err(ObserverFault::StateOverflow);
        }
        self.psi_stator = next;
        Ok(FluxEstimate { psi_ab, disturbance_ab: None, flux_increment_ab: None, emf_increment_ab: None })
    }

    pub(super) fn reset(&mut self) {
        self.model.reset();
        self.psi_stator = AlphaBeta::default();
        self.faulted = false;
    }
}
