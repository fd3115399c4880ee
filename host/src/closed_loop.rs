//! The closed loop every simulated run steps: the plant, the drive's one-period
//! computation delay, and whatever controller the caller runs in between.
//!
//! One PWM period `k` (time `t_k`, a carrier valley) is two calls in this order:
//!
//! 1. [`ClosedLoop::sense`]: the plant's sensors are read at `t_k` (plain SI readings,
//!    [`SensorReading`]) together with the true state ([`TrueState`]).
//! 2. The caller's controller computes its answer from the readings: a drive in this
//!    process, a drive behind a link, the sensored current controller of a recording.
//! 3. [`ClosedLoop::actuate`]: the plant runs `[t_k, t_k + Ts)` with the bridge the
//!    controller asked for one period earlier (the computation delay: duties computed
//!    from the sample at `t_k` act from `t_{k+1}`), and the new answer is queued for
//!    the next period.
//!
//! [`ClosedLoop::actuate`] consumes the [`Sensed`] value of the same period, so a period
//! cannot be actuated without being sensed first, nor twice. The stepper knows no drive
//! and no wire format: the controller's answer reaches it as a [`Bridge`].

use crate::plant::{PeriodAverage, Plant, SensorReading, TrueState};

/// What the inverter bridge does over one PWM period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bridge {
    /// Every switch off ([`Plant::step_open`]): no current flows, the mover coasts.
    Off,
    /// Switching with these duties (upper-switch on-time fractions of legs a, b, c,
    /// [`Plant::step`]).
    On([f64; 3]),
}

impl Bridge {
    /// The bridge a drive's answer asks for: switching with `duties` when `enabled`,
    /// off otherwise.
    pub fn driven(enabled: bool, duties: [f64; 3]) -> Self {
        if enabled { Bridge::On(duties) } else { Bridge::Off }
    }

    /// `true` when the bridge switches.
    pub fn is_on(self) -> bool {
        matches!(self, Bridge::On(_))
    }
}

/// The plant's readings and true state at the start of a period (step 1 above); hand
/// it back to [`ClosedLoop::actuate`] to run the period.
#[derive(Debug)]
#[must_use = "a sensed period is run by ClosedLoop::actuate"]
pub struct Sensed {
    /// The sensors' readings at `t_k` (each [`ClosedLoop::sense`] draws fresh noise).
    pub reading: SensorReading,
    /// The true state at `t_k`.
    pub truth: TrueState,
    /// The plant's period index when it was sensed.
    period: u64,
}

/// One period run (step 3 above): what was sensed at its start and what the plant did.
#[derive(Clone, Copy, Debug)]
pub struct Stepped {
    /// The sensors' readings at `t_k`.
    pub reading: SensorReading,
    /// The true state at `t_k`.
    pub truth: TrueState,
    /// The bridge over `[t_k, t_k + Ts)`: the controller's answer of period `k - 1`.
    pub bridge: Bridge,
    /// The plant's averages over `[t_k, t_k + Ts)` (applied voltages, bus, load).
    pub applied: PeriodAverage,
}

/// The plant in closed loop with a controller one period late. See the module
/// documentation for the order of operations.
#[derive(Clone, Debug)]
pub struct ClosedLoop {
    plant: Plant,
    /// The bridge of the controller's last answer, applied during the next period.
    queued: Bridge,
    /// Periods run.
    periods: u64,
}

impl ClosedLoop {
    /// `plant` with the bridge off during the first period (a drive starts disabled).
    pub fn new(plant: Plant) -> Self {
        Self::starting_with(plant, Bridge::Off)
    }

    /// `plant` with `first` applied during the first period, before the controller's
    /// first answer takes effect.
    pub fn starting_with(plant: Plant, first: Bridge) -> Self {
        ClosedLoop { plant, queued: first, periods: 0 }
    }

    /// The plant.
    pub fn plant(&self) -> &Plant {
        &self.plant
    }

    /// The plant, to change it between periods (scenario events, injected faults).
    pub fn plant_mut(&mut self) -> &mut Plant {
        &mut self.plant
    }

    /// The bridge queued for the next period (the controller's last answer).
    pub fn queued(&self) -> Bridge {
        self.queued
    }

    /// Periods run so far.
    pub fn periods(&self) -> u64 {
        self.periods
    }

    /// Step 1 of a period: the sensors' readings and the true state now.
    pub fn sense(&mut self) -> Sensed {
        let reading = self.plant.sample();
        Sensed { reading, truth: self.plant.state(), period: self.periods }
    }

    /// Step 3 of the period `sensed` started: runs it with the queued bridge and the load
    /// force `load_n` (N, opposing positive motion), and queues `next` (the controller's
    /// answer to `sensed`) for the period after.
    ///
    /// # Panics
    /// When `sensed` is not this period's (a period sensed twice or skipped): a
    /// programming error.
    pub fn actuate(&mut self, sensed: Sensed, next: Bridge, load_n: f64) -> Stepped {
        assert_eq!(sensed.period, self.periods, "a period is actuated once, after it is sensed");
        let bridge = std::mem::replace(&mut self.queued, next);
        match bridge {
            Bridge::On(duties) => self.plant.step(duties, load_n),
            Bridge::Off => self.plant.step_open(load_n),
        }
        self.periods += 1;
        Stepped {
            reading: sensed.reading,
            truth: sensed.truth,
            bridge,
            applied: self.plant.state().last_period,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::SimParams;
    use dcfo::motor::MotorParams;

    fn paper_loop() -> ClosedLoop {
        ClosedLoop::new(Plant::new(&SimParams::from_motor(&MotorParams::paper())).expect("plant"))
    }

    /// The controller's answer acts one period late: the first period runs with the
    /// bridge the loop started with, each next one with the answer of the period before.
    #[test]
    fn an_answer_acts_during_the_next_period() {
        let mut cl = paper_loop();
        let answers = [Bridge::On([0.6, 0.5, 0.4]), Bridge::Off, Bridge::On([0.4, 0.5, 0.6])];
        let mut ran = Vec::new();
        for next in answers {
            let sensed = cl.sense();
            let stepped = cl.actuate(sensed, next, 0.0);
            if let Bridge::On(duties) = stepped.bridge {
                assert_eq!(stepped.applied.duties, duties);
            }
            ran.push(stepped.bridge);
        }
        assert_eq!(ran, [Bridge::Off, answers[0], answers[1]]);
        assert_eq!((cl.queued(), cl.periods()), (answers[2], 3));
        assert_eq!(cl.plant().time_s(), 3.0 * cl.plant().pwm_period_s());
    }

    /// A period is actuated once, with what was sensed at its start.
    #[test]
    #[should_panic(expected = "actuated once")]
    fn a_period_sensed_earlier_is_refused() {
        let mut cl = paper_loop();
        let first = cl.sense();
        let again = cl.sense();
        let _ = cl.actuate(first, Bridge::Off, 0.0);
        let _ = cl.actuate(again, Bridge::Off, 0.0);
    }
}
