//! Measurement chains: phase-current sensors and the DC-bus voltage divider, each
//! into an ADC, with a seeded noise generator.

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64;

use super::params::{CurrentSensing, SensorParams};

/// One set of sensor readings, taken at a PWM carrier valley (period start).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorReading {
    /// Sampling time, second.
    pub t_s: f64,
    /// Phase currents a, b, c as the firmware sees them, ampere. With
    /// [`CurrentSensing::TwoPhase`] the third is `-(i_a + i_b)` of the readings.
    pub i_abc_a: [f64; 3],
    /// Alpha current from the readings (amplitude-invariant Clarke), ampere.
    pub i_alpha_a: f64,
    /// Beta current from the readings (amplitude-invariant Clarke), ampere.
    pub i_beta_a: f64,
    /// DC-bus voltage reading, volt.
    pub vdc_v: f64,
    /// `true` if any current reading hit an end of its ADC range.
    pub current_saturated: bool,
}

/// Sensor chain state: parameters and the noise generator.
#[derive(Debug, Clone)]
pub(crate) struct Sensors {
    p: SensorParams,
    rng: Pcg64,
}

/// Rounds `x` to the nearest ADC code `round(x / lsb) + zero_code`, clamped to
/// `0..=max_code`, and returns the value it stands for and whether it clipped.
fn quantise(x: f64, lsb: f64, zero_code: f64, max_code: f64) -> (f64, bool) {
    let code = (x / lsb).round() + zero_code;
    let clipped = !(0.0..=max_code).contains(&code);
    let code = if code.is_nan() { zero_code } else { code.clamp(0.0, max_code) };
    ((code - zero_code) * lsb, clipped)
}

impl Sensors {
    pub(crate) fn new(p: SensorParams, seed: u64) -> Self {
        Sensors { p, rng: Pcg64::seed_from_u64(seed) }
    }

    fn noise(&mut self, rms: f64) -> f64 {
        if rms > 0.0 {
            let z: f64 = self.rng.sample(StandardNormal);
            rms * z
        } else {
            0.0
        }
    }

    fn current(&mut self, k: usize, i_true: f64) -> (f64, bool) {
        let x = (1.0 + self.p.current_gain_error[k]) * i_true
            + self.p.current_offset_a[k]
            + self.noise(self.p.current_noise_rms_a);
        match self.p.current_adc_bits {
            Some(bits) => {
                let codes = f64::from(1u32 << bits);
                let lsb = 2.0 * self.p.current_full_scale_a / codes;
                quantise(x, lsb, 0.5 * codes, codes - 1.0)
            }
            None => (x, false),
        }
    }

    /// Readings of true phase currents `i_abc` (A) and true bus voltage `vdc` (V) at `t_s`.
    pub(crate) fn read(&mut self, t_s: f64, i_abc: [f64; 3], vdc: f64) -> SensorReading {
        let (a, sa) = self.current(0, i_abc[0]);
        let (b, sb) = self.current(1, i_abc[1]);
        let (c, sc) = match self.p.current_sensing {
            CurrentSensing::TwoPhase => (-(a + b), false),
            CurrentSensing::ThreePhase => self.current(2, i_abc[2]),
        };
        let (i_alpha, i_beta) = match self.p.current_sensing {
            CurrentSensing::TwoPhase => (a, (a + 2.0 * b) / 3f64.sqrt()),
            CurrentSensing::ThreePhase => ((2.0 * a - b - c) / 3.0, (b - c) / 3f64.sqrt()),
        };
        let x =
            (1.0 + self.p.bus_gain_error) * vdc + self.p.bus_offset_v + self.noise(self.p.bus_noise_rms_v);
        let vdc_v = match self.p.bus_adc_bits {
            Some(bits) => {
                let codes = f64::from(1u32 << bits);
                quantise(x, self.p.bus_full_scale_v / codes, 0.0, codes - 1.0).0
            }
            None => x,
        };
        SensorReading {
            t_s,
            i_abc_a: [a, b, c],
            i_alpha_a: i_alpha,
            i_beta_a: i_beta,
            vdc_v,
            current_saturated: sa || sb || sc,
        }
    }
}
