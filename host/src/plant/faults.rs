//! Fault injection that needs the plant's inside: the DC bus changing under a running
//! drive (sag, overvoltage, loss). Everything else `dcfo faults` injects (an open
//! phase, a short, sensor and link faults) is a wrapper around the plant's public
//! interface (`crate::commands::faults::inject`).

use super::{Plant, PlantError};

impl Plant {
    /// Sets the true DC-bus voltage (V, finite, >= 0) from the next period on: a sag, an
    /// overvoltage or, at 0 V, the loss of the bus. The bus ripple (if any) stays
    /// superimposed. Refuses a negative or non-finite voltage.
    pub fn set_dc_bus_v(&mut self, dc_bus_v: f64) -> Result<(), PlantError> {
        if !(dc_bus_v.is_finite() && dc_bus_v >= 0.0) {
            return Err(PlantError::NotFinite { what: "DC-bus voltage (finite, >= 0)" });
        }
        self.params.inverter.dc_bus_v = dc_bus_v;
        Ok(())
    }

    /// The nominal (ripple-free) DC-bus voltage in force, V.
    pub fn dc_bus_v(&self) -> f64 {
        self.params.inverter.dc_bus_v
    }
}

#[cfg(test)]
mod tests {
    use crate::plant::{Plant, SimParams};
    use dcfo::motor::MotorParams;

    #[test]
    fn the_bus_follows_the_setter_and_refuses_nonsense() {
        let mut p = Plant::new(&SimParams::ideal_from_motor(&MotorParams::paper())).unwrap();
        p.set_dc_bus_v(100.0).unwrap();
        assert_eq!(p.state().vdc_v, 100.0);
        p.step([0.5; 3], 0.0);
        assert_eq!(p.sample().vdc_v, 100.0);
        p.set_dc_bus_v(0.0).unwrap();
        assert_eq!(p.sample().vdc_v, 0.0);
        assert!(p.set_dc_bus_v(-1.0).is_err());
        assert!(p.set_dc_bus_v(f64::NAN).is_err());
        assert_eq!(p.dc_bus_v(), 0.0);
    }
}
