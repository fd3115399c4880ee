//! The paper's conventional flux observer (CFO): a first-order low-pass filter
//! `1/(s + wc)` in place of the integrator, uncompensated.
//!
//! Relative to the open-loop flux, the estimate is `s/(s + wc)` times it: at electrical
//! frequency `w` it leads by `atan(wc/w)` and is scaled by `w/sqrt(w^2 + wc^2)`; a DC
//! input `dc` (V) leaves an offset of `dc / wc` (Wb). Discretised with the trapezoidal
//! rule on the leak term (Tustin for `s/(s + wc)`), which keeps the phase exact to
//! `O((w dt)^2)`.

use super::voltage_model::StatorFlux;
use super::{FluxEstimate, FluxObserver, ObserverFault, ObserverInput, ObserverMotor};
use crate::algorithms::transforms::AlphaBeta;
use crate::num::Scalar;

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
    flux: StatorFlux<T>,
    cutoff: T,
}

impl<T: Scalar> LpfObserver<T> {
    /// An observer for `motor` with cut-off `cutoff` (rad/s, working units, > 0).
    pub fn new(motor: ObserverMotor<T>, cutoff: T) -> Result<Self, LpfConfigError> {
        if !cutoff.is_valid() || cutoff <= T::ZERO {
            return Err(LpfConfigError::BadCutoff);
        }
        Ok(LpfObserver { flux: StatorFlux::new(motor), cutoff })
    }

    /// Starts from mover flux `psi_mover` (Wb) at current `i_ab` (A).
    pub fn seed(&mut self, psi_mover: AlphaBeta<T>, i_ab: AlphaBeta<T>) {
        self.flux.seed(psi_mover, i_ab);
    }

    /// The cut-off frequency (rad/s, working units).
    pub fn cutoff(&self) -> T {
        self.cutoff
    }
}

impl<T: Scalar> FluxObserver<T> for LpfObserver<T> {
    fn update(&mut self, input: &ObserverInput<T>) -> Result<FluxEstimate<T>, ObserverFault> {
        // y_k (1 + c) = y_{k-1} (1 - c) + increment, with c = wc dt / 2. A bad period
        // is refused by the shared update before these are used.
        let c = self.cutoff * input.dt * T::HALF;
        let Some(inv) = (T::ONE + c).recip() else {
            return Err(ObserverFault::InvalidPeriod);
        };
        self.flux.update(input, T::ONE - c, inv)
    }

    fn reset(&mut self) {
        self.flux.reset();
    }
}
