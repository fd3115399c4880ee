//! The pure-integrator flux observer: `psi = integral(u - Rs i) - Ls i`.

use super::voltage_model::StatorFlux;
use super::{FluxEstimate, FluxObserver, ObserverFault, ObserverInput, ObserverMotor};
use crate::algorithms::transforms::AlphaBeta;
use crate::num::Scalar;

/// Pure-integrator flux observer. Exact for ideal inputs; any DC offset in `u` or `i`
/// (or a wrong `Rs`) makes it drift without bound, until the state overflows and the
/// observer reports [`ObserverFault::StateOverflow`]. A baseline, not for driving.
#[derive(Clone, Debug)]
pub struct PureIntegrator<T> {
    flux: StatorFlux<T>,
}

impl<T: Scalar> PureIntegrator<T> {
    /// An integrator for `motor`, starting from zero flux.
    pub fn new(motor: ObserverMotor<T>) -> Self {
        PureIntegrator { flux: StatorFlux::new(motor) }
    }

    /// Starts the integral at `psi_stator` (Wb), e.g. the known magnet flux at a known
    /// angle (the integrator cannot find its own initial condition).
    pub fn set_stator_flux(&mut self, psi_stator: AlphaBeta<T>) {
        self.flux.set(psi_stator);
    }

    /// Starts from mover flux `psi_mover` (Wb) at current `i_ab` (A).
    pub fn seed(&mut self, psi_mover: AlphaBeta<T>, i_ab: AlphaBeta<T>) {
        self.flux.seed(psi_mover, i_ab);
    }
}

impl<T: Scalar> FluxObserver<T> for PureIntegrator<T> {
    fn update(&mut self, input: &ObserverInput<T>) -> Result<FluxEstimate<T>, ObserverFault> {
        // No leak: multiplying by one is exact in every Scalar type.
        self.flux.update(input, T::ONE, T::ONE)
    }

    fn reset(&mut self) {
        self.flux.reset();
    }
}
