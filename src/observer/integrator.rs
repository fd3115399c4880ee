//! The pure-integrator flux observer: `psi = integral(u - Rs i) - Ls i`.

use super::voltage_model::VoltageModel;
use super::{FluxEstimate, FluxObserver, ObserverFault, ObserverInput, ObserverMotor, check_input};
use crate::num::Scalar;
use crate::transforms::AlphaBeta;

/// Pure-integrator flux observer. Exact for ideal inputs; any DC offset in `u` or `i`
/// (or a wrong `Rs`) makes it drift without bound, until the state overflows and the
/// observer reports [`ObserverFault::StateOverflow`]. A baseline, not for driving.
#[derive(Clone, Debug)]
pub struct PureIntegrator<T> {
    model: VoltageModel<T>,
    psi_stator: AlphaBeta<T>,
    faulted: bool,
}

impl<T: Scalar> PureIntegrator<T> {
    /// An integrator for `motor`, starting from zero flux.
    pub fn new(motor: ObserverMotor<T>) -> Self {
        PureIntegrator { model: VoltageModel::new(motor), psi_stator: AlphaBeta::default(), faulted: false }
    }

    /// Starts the integral at `psi_stator` (Wb), e.g. the known magnet flux at a known
    /// angle (the integrator cannot find its own initial condition).
    pub fn set_stator_flux(&mut self, psi_stator: AlphaBeta<T>) {
        self.psi_stator = psi_stator;
    }
}

impl<T: Scalar> FluxObserver<T> for PureIntegrator<T> {
    fn update(&mut self, input: &ObserverInput<T>) -> Result<FluxEstimate<T>, ObserverFault> {
        if self.faulted {
            return Err(ObserverFault::StateOverflow);
        }
        check_input(input)?;
        let de = self.model.emf_increment(input);
        let next =
            AlphaBeta { alpha: self.psi_stator.alpha + de.alpha, beta: self.psi_stator.beta + de.beta };
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
