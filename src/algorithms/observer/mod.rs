//! Flux observers (docs/method.md §2–3): estimate the mover (magnet) flux vector `psi_f_ab`
//! from the stator voltage and current, behind one interface.
//!
//! All of them integrate the back-EMF side of the voltage equation, `u - Rs i`, and
//! remove the inductive part, `psi = integral(u - Rs i) - Ls i`; they differ in what
//! replaces the pure integral:
//! - [`PureIntegrator`]: exact in theory, drifts without bound on any DC offset;
//! - [`LpfObserver`]: the paper's conventional flux observer (CFO), `1/(s + wc)`:
//!   bounded, but with a phase lead `atan(wc/w)` and gain `w/sqrt(w^2+wc^2)`;
//! - [`Dcfo`]: the disturbance compensated flux observer, a notch filter at the
//!   fundamental acting as a disturbance observer fed back through a gain `h < 0`.
//!
//! ## Timing contract
//! Each call to [`FluxObserver::update`] takes the voltage that was applied during
//! the period that just ended and the currents sampled now, at its end, and returns the
//! estimate for now. The voltage is treated as held over the period (as a PWM inverter
//! applies it), so its integral is exact; the resistive drop is integrated with the
//! trapezoidal rule between the previous and the present current sample.
//!
//! ## Units
//! Working units of [`crate::num::units`]: V, A, rad/s, s, Wb (or per-unit).
//!
//! ## Saliency
//! With `Ld != Lq` the observers use `Ls = Lq` and so estimate the *active flux*
//! `psi_s - Lq i`, aligned with the rotor, of amplitude `psi_f + (Ld - Lq) i_d`.

mod dcfo;
mod integrator;
mod lpf;
mod voltage_model;

pub use dcfo::{Dcfo, DcfoConfig, DcfoConfigError};
pub use integrator::PureIntegrator;
pub use lpf::{LpfConfigError, LpfObserver};
pub use voltage_model::ObserverMotor;

use crate::algorithms::transforms::AlphaBeta;
use crate::num::Scalar;

/// One sample of observer input, in working units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ObserverInput<T> {
    /// Stator voltage applied during the period that just ended (V): in a drive, the
    /// commanded voltage of the previous control step.
    pub u_ab: AlphaBeta<T>,
    /// Stator current sampled now, at the end of that period (A).
    pub i_ab: AlphaBeta<T>,
    /// Electrical speed estimate (rad/s; sign ignored by the observers that use it).
    pub omega_e: T,
    /// Length of the period that just ended (s, > 0).
    pub dt: T,
}

/// One sample of observer output, in working units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FluxEstimate<T> {
    /// Estimated mover flux vector (Wb): `psi_f [cos theta, sin theta]`.
    pub psi_ab: AlphaBeta<T>,
    /// The observer's own disturbance estimate (Wb), where it has one: for the DCFO,
    /// the notch filter's output `d` (DC offset and harmonics of the integrator state).
    pub disturbance_ab: Option<AlphaBeta<T>>,
    /// The increment over this sample of the flux before the observer's output filter
    /// (Wb), where the observer has one: for the DCFO, of its integrator state `psi_i`
    /// (the back-EMF `e dt` plus the observer's DC correction). With `psi_ab` it gives
    /// the frequency discriminator of [`crate::algorithms::fll`].
    pub flux_increment_ab: Option<AlphaBeta<T>>,
    /// The increment over this sample of the model flux without any observer
    /// correction, `(u - Rs i) dt - Ls di` (Wb), where the observer has a correction to
    /// leave out: for the DCFO, `flux_increment_ab` less its feedback `(h/Ls) d dt`. It
    /// draws the arc [`crate::algorithms::arc_fit`] fits.
    pub emf_increment_ab: Option<AlphaBeta<T>>,
}

/// Why an observer refused a sample. The state is left as it was for input faults;
/// after [`ObserverFault::StateOverflow`] the observer refuses every sample until
/// [`FluxObserver::reset`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ObserverFault {
    /// A voltage, current or speed input was NaN, infinite or out of range.
    InvalidInput,
    /// The sample period was not a valid positive number.
    InvalidPeriod,
    /// The internal state left the representable range (overflow); latched.
    StateOverflow,
}

/// A flux observer: voltage and current in, mover flux out. See the module docs for the
/// timing contract and units.
pub trait FluxObserver<T: Scalar> {
    /// Processes one sample and returns the flux estimate for the present instant.
    fn update(&mut self, input: &ObserverInput<T>) -> Result<FluxEstimate<T>, ObserverFault>;
    /// Returns to the initial state (zero flux, no history) and clears a latched fault.
    fn reset(&mut self);
}

/// Which observer, for selection at run time (host tools, firmware configuration).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ObserverKind {
    /// [`PureIntegrator`].
    PureIntegrator,
    /// [`LpfObserver`], the paper's CFO.
    Cfo,
    /// [`Dcfo`].
    Dcfo,
}

/// Any of the observers, dispatched by `match` (no trait objects, no allocation).
#[derive(Clone, Debug)]
pub enum AnyObserver<T> {
    /// A pure integrator.
    PureIntegrator(PureIntegrator<T>),
    /// The paper's conventional LPF flux observer.
    Cfo(LpfObserver<T>),
    /// The disturbance compensated flux observer.
    Dcfo(Dcfo<T>),
}

impl<T: Scalar> AnyObserver<T> {
    /// Which observer this is.
    pub fn kind(&self) -> ObserverKind {
        match self {
            AnyObserver::PureIntegrator(_) => ObserverKind::PureIntegrator,
            AnyObserver::Cfo(_) => ObserverKind::Cfo,
            AnyObserver::Dcfo(_) => ObserverKind::Dcfo,
        }
    }

    /// Starts the observer from a known mover flux `psi_mover` (Wb) turning at `omega_e`
    /// (rad/s) at current `i_ab` (A), with a DC voltage error `dc_voltage` (V) in its
    /// inputs that the DCFO's disturbance estimate takes on at once (the others have no
    /// state for it and ignore it); see [`Dcfo::seed`].
    pub fn seed(
        &mut self,
        psi_mover: AlphaBeta<T>,
        i_ab: AlphaBeta<T>,
        omega_e: T,
        dc_voltage: AlphaBeta<T>,
    ) {
        match self {
            AnyObserver::PureIntegrator(o) => o.seed(psi_mover, i_ab),
            AnyObserver::Cfo(o) => o.seed(psi_mover, i_ab),
            AnyObserver::Dcfo(o) => o.seed(psi_mover, i_ab, omega_e, dc_voltage),
        }
    }
}

impl<T: Scalar> AnyObserver<T> {
    /// The frequency `w_l` (rad/s) by which the observer's estimate leads the flux in the
    /// steady state, by `atan(w_l / |w|)`: the CFO's low-pass cut-off; zero for the pure
    /// integrator and the DCFO, which have no such lead.
    pub fn steady_lead_cutoff(&self) -> T {
        match self {
            AnyObserver::Cfo(o) => o.cutoff(),
            AnyObserver::PureIntegrator(_) | AnyObserver::Dcfo(_) => T::ZERO,
        }
    }

    /// Arms the DCFO's radial feedback in the share `weight` (dimensionless, 0 to 1;
    /// [`Dcfo::set_magnitude_feedback`]); the other observers have none.
    pub fn set_magnitude_feedback(&mut self, weight: T) {
        if let AnyObserver::Dcfo(o) = self {
            o.set_magnitude_feedback(weight);
        }
    }
}

impl<T: Scalar> FluxObserver<T> for AnyObserver<T> {
    fn update(&mut self, input: &ObserverInput<T>) -> Result<FluxEstimate<T>, ObserverFault> {
        match self {
            AnyObserver::PureIntegrator(o) => o.update(input),
            AnyObserver::Cfo(o) => o.update(input),
            AnyObserver::Dcfo(o) => o.update(input),
        }
    }
    fn reset(&mut self) {
        match self {
            AnyObserver::PureIntegrator(o) => o.reset(),
            AnyObserver::Cfo(o) => o.reset(),
            AnyObserver::Dcfo(o) => o.reset(),
        }
    }
}

/// Checks the parts of an input every observer needs.
fn check_input<T: Scalar>(input: &ObserverInput<T>) -> Result<(), ObserverFault> {
    if !input.dt.is_valid() || input.dt <= T::ZERO {
        return Err(ObserverFault::InvalidPeriod);
    }
    if !(input.u_ab.is_valid() && input.i_ab.is_valid() && input.omega_e.is_valid()) {
        return Err(ObserverFault::InvalidInput);
    }
    Ok(())
}
