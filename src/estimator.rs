//! The sensorless estimator: a flux observer and the PLL wired together, as the drive
//! runs them every control period and as trace replay runs them on recorded data.
//!
//! Per sample: the observer takes the voltage applied during the period that just
//! ended and the currents sampled now; its flux estimate feeds the PLL; the PLL's
//! frequency integrator tunes the DCFO's notch for the *next* sample (see
//! [`crate::pll`] for why the integrator and not the full speed estimate).
//! Having this composition in one place is what makes a replayed trace reproduce a
//! closed-loop run's estimates bit for bit.

use crate::fll::{Fll, FllConfig, FllConfigError};
use crate::motor::MotorParams;
use crate::num::{Angle, Scalar};
use crate::observer::{
    AnyObserver, Dcfo, DcfoConfig, DcfoConfigError, FluxObserver, LpfConfigError, LpfObserver, ObserverFault,
    ObserverInput, ObserverKind, ObserverMotor, PureIntegrator,
};
use crate::pll::{Pll, PllConfig, PllConfigError, PllFault};
use crate::transforms::{AlphaBeta, CosSin};
use crate::units::Base;

/// Estimator settings, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimatorConfig {
    /// Which flux observer.
    pub observer: ObserverKind,
    /// DCFO tuning (used when `observer` is [`ObserverKind::Dcfo`]).
    pub dcfo: DcfoConfig,
    /// CFO low-pass cut-off (rad/s; used when `observer` is [`ObserverKind::Cfo`]).
    pub cfo_cutoff_rad_s: f32,
    /// PLL tuning.
    pub pll: PllConfig,
    /// Frequency-locked loop that tunes the DCFO's notch and feeds the PLL forward
    /// (used when `observer` is [`ObserverKind::Dcfo`]); `None`: the notch follows the
    /// PLL's frequency integrator, as the paper's method does. Opt-in for now (see
    /// [`crate::fll`] for what it does better and worse).
    pub fll: Option<FllConfig>,
}

impl EstimatorConfig {
    /// Defaults for `motor` with the given observer: [`DcfoConfig::default`],
    /// [`PllConfig::for_flux`], and a CFO cut-off of `2 pi * 2.5 Hz` (15.7 rad/s). The
    /// paper gives no cut-off; this one makes the CFO's phase lead at 10 Hz the 14
    /// degrees of the paper's Fig. 17 (`atan(15.7 / 62.8)`). No FLL (see
    /// [`EstimatorConfig::with_fll`]).
    pub fn for_motor(motor: &MotorParams, observer: ObserverKind) -> Self {
        EstimatorConfig {
            observer,
            dcfo: DcfoConfig::default(),
            cfo_cutoff_rad_s: 2.0 * core::f32::consts::PI * 2.5,
            pll: PllConfig::for_flux(motor.psi_f_wb),
            fll: None,
        }
    }

    /// This configuration with the DCFO's notch tuned by an FLL:
    /// [`FllConfig::for_motor`] with the motor's rated phase peak voltage and the DCFO's
    /// notch floor.
    pub fn with_fll(mut self, motor: &MotorParams) -> Self {
        self.fll = Some(FllConfig::for_motor(
            motor.psi_f_wb,
            motor.rated_voltage_v * 0.816_496_6,
            self.dcfo.omega_floor_rad_s,
        ));
        self
    }
}

/// Why an estimator could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EstimatorConfigError {
    /// The DCFO settings were refused.
    Dcfo(DcfoConfigError),
    /// The CFO cut-off was refused.
    Cfo(LpfConfigError),
    /// The PLL settings were refused.
    Pll(PllConfigError),
    /// The FLL settings were refused.
    Fll(FllConfigError),
}

/// Why the estimator refused a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EstimatorFault {
    /// The observer refused the sample.
    Observer(ObserverFault),
    /// The PLL refused the observer's output.
    Pll(PllFault),
}

/// One sample of estimator output, in working units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate<T> {
    /// Estimated electrical angle at this sample.
    pub theta_e: Angle,
    /// Cosine and sine of `theta_e` (dimensionless), from the PLL.
    pub cos_sin: CosSin<T>,
    /// Estimated electrical speed (rad/s).
    pub omega_e: T,
    /// Estimated linear speed (m/s, SI in every unit system).
    pub speed_m_per_s: T,
    /// Estimated mover flux (Wb).
    pub psi_ab: AlphaBeta<T>,
    /// The observer's disturbance estimate (Wb), where it has one.
    pub disturbance_ab: Option<AlphaBeta<T>>,
    /// `true` while the PLL reports lock.
    pub locked: bool,
}

/// Observer + PLL. See the module documentation.
#[derive(Clone, Debug)]
pub struct Estimator<T> {
    observer: AnyObserver<T>,
    pll: Pll<T>,
    /// The DCFO's frequency-locked loop (`None` for the other observers, which run the
    /// paper's plain PLL).
    fll: Option<Fll<T>>,
}

impl<T: Scalar> Estimator<T> {
    /// Builds the estimator for `motor` in the working units of `base`.
    pub fn new(
        motor: &MotorParams,
        config: &EstimatorConfig,
        base: &Base,
    ) -> Result<Self, EstimatorConfigError> {
        let m = ObserverMotor::new(motor, base);
        let observer = match config.observer {
            ObserverKind::PureIntegrator => AnyObserver::PureIntegrator(PureIntegrator::new(m)),
            ObserverKind::Cfo => AnyObserver::Cfo(
                LpfObserver::new(m, base.omega(config.cfo_cutoff_rad_s))
                    .map_err(EstimatorConfigError::Cfo)?,
            ),
            ObserverKind::Dcfo => {
                AnyObserver::Dcfo(Dcfo::new(m, &config.dcfo, base).map_err(EstimatorConfigError::Dcfo)?)
            }
        };
        let pll = Pll::new(&config.pll, motor.pole_pitch_m, base).map_err(EstimatorConfigError::Pll)?;
        let fll = match (config.observer, &config.fll) {
            (ObserverKind::Dcfo, Some(fll)) => Some(Fll::new(fll, base).map_err(EstimatorConfigError::Fll)?),
            _ => None,
        };
        Ok(Estimator { observer, pll, fll })
    }

    /// One sample: `u_applied` is the voltage applied during the period that just ended
    /// (V), `i` the currents sampled now (A), `dt` that period's length (s).
    pub fn update(
        &mut self,
        u_applied: AlphaBeta<T>,
        i: AlphaBeta<T>,
        dt: T,
    ) -> Result<Estimate<T>, EstimatorFault> {
        let notch = match &self.fll {
            Some(fll) => fll.notch_omega(),
            None => self.pll.omega_integral(),
        };
        let input = ObserverInput { u_ab: u_applied, i_ab: i, omega_e: notch, dt };
        let flux = self.observer.update(&input).map_err(EstimatorFault::Observer)?;
        let (out, settled) = match (&mut self.fll, flux.flux_increment_ab) {
            (Some(fll), Some(increment)) => {
                let f = fll.update(flux.psi_ab, increment, dt);
                let out = self
                    .pll
                    .update_with_feedforward(flux.psi_ab, f.omega_e, f.notch_omega, dt)
                    .map_err(EstimatorFault::Pll)?;
                (out, f.settled)
            }
            _ => (self.pll.update(flux.psi_ab, dt).map_err(EstimatorFault::Pll)?, true),
        };
        Ok(Estimate {
            theta_e: out.theta_e,
            cos_sin: out.cos_sin,
            omega_e: out.omega_e,
            speed_m_per_s: out.speed_m_per_s,
            psi_ab: flux.psi_ab,
            disturbance_ab: flux.disturbance_ab,
            locked: out.locked && settled,
        })
    }

    /// Sets the PLL's angle (for its next sample) and speed (rad/s, working units),
    /// e.g. from an open-loop start-up; the observer keeps its state.
    pub fn preset_pll(&mut self, theta_e: Angle, omega_e: T) {
        match &mut self.fll {
            Some(fll) => {
                fll.preset(omega_e);
                self.pll.preset(theta_e, T::ZERO);
            }
            None => self.pll.preset(theta_e, omega_e),
        }
    }

    /// Back to the initial state; clears latched faults.
    pub fn reset(&mut self) {
        self.observer.reset();
        self.pll.reset();
        if let Some(fll) = &mut self.fll {
            fll.reset();
        }
    }

    /// The frequency the observer's notch will be tuned to at the next sample (rad/s,
    /// working units): the FLL's for the DCFO, the PLL integrator's otherwise.
    pub fn notch_omega(&self) -> T {
        match &self.fll {
            Some(fll) => fll.notch_omega(),
            None => self.pll.omega_integral(),
        }
    }

    /// The FLL's signed frequency estimate (rad/s, working units), where it runs.
    pub fn fll_omega(&self) -> Option<T> {
        self.fll.as_ref().map(|f| f.omega())
    }

    /// Which observer runs.
    pub fn observer_kind(&self) -> ObserverKind {
        self.observer.kind()
    }
}
