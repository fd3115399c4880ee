//! The paper's conventional flux observer (CFO): a first-order low-pass filter
//! `1/(s + wc)` in place of the integrator, uncompensated.
//!
//! Relative to the open-loop flux, the estimate is `s/(s + wc)` times it: at electrical
//! frequency `w` it leads by `atan(wc/w)` and is scaled by `w/sqrt(w^2 + wc^2)`; a DC
//! input `dc` (V) leaves an offset of `dc / wc` (Wb). Discretised with the trapezoidal
//! rule on the leak term (Tustin for `s/(s + wc)`), which keeps the phase exact to
//! `O((w dt)^2)`.

use super::voltage_model::VoltageModel;
use super::{FluxEstimate, FluxObserver, ObserverFault, ObserverInput, ObserverMotor, check_input};
use crate::num::Scalar;
use crate::transforms::AlphaBeta;

/// Why an LPF observer could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LpfConfigError {
    /// The cut-off frequency is not a valid positive number.
    BadCutoff,
}

/// LPF ("CFO") flux observer with a fixed cut-off. See the module docs.
#[derive(Clone, Debug)]
pub struct LpfObserver<T> {
    model: VoltageModel<T>,
    cutoff: T,
    psi_stator: AlphaBeta<T>,
    faulted: bool,
}

impl<T: Scalar> LpfObserver<T> {
    /// An observer for `motor` with cut-off `cutoff` (rad/s, working units, > 0).
    pub fn new(motor: ObserverMotor<T>, cutoff: T) -> Result<Self, LpfConfigError> {
        if !cutoff.is_valid() || cutoff <= T::ZERO {
            return Err(LpfConfigError::BadCutoff);
        }
        Ok(LpfObserver {
            model: VoltageModel::new(motor),
            cutoff,
            psi_stator: AlphaBeta::default(),
            faulted: false,
        })
    }

    /// The cut-off frequency (rad/s, working units).
    pub fn cutoff(&self) -> T {
        self.cutoff
    }
}

impl<T: Scalar> FluxObserver<T> for LpfObserver<T> {
    fn update(&mut self, input: &ObserverInput<T>) -> Result<FluxEstimate<T>, ObserverFault> {
        if self.faulted {
            return Err(ObserverFault::StateOverflow);
        }
        check_input(input)?;
        // y_k (1 + c) = y_{k-1} (1 - c) + increment, with c = wc dt / 2.
        let c = self.cutoff * input.dt * T::HALF;
        let Some(inv) = T::ONE.checked_div(T::ONE + c) else {
            return Err(ObserverFault::InvalidPeriod);
        };
        let keep = T::ONE - c;
        let de = self.model.emf_increment(input);
        let next = AlphaBeta {
            alpha: (self.psi_stator.alpha * keep + de.alpha) * inv,
            beta: (self.psi_stator.beta * keep + de.beta) * inv,
        };
        let psi_ab = self.model.mover_flux(next, input.i_ab);
        if !(next.is_valid() && psi_ab.is_valid()) {
            self.faulted = true;
            return Err(ObserverFault::StateOverflow);
        }
        self.psi_stator = next;
        Ok(FluxEstimate { psi_ab, disturbance_ab: None })
    }

    fn reset(&mut self) {
        self.model.reset();
        self.psi_stator = AlphaBeta::default();
        self.faulted = false;
    }
}
