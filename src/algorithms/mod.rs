//! The algorithms: each block of the drive on its own, pure, knowing nothing of the
//! estimator that composes some of them or of the drive that runs them.
//!
//! This floor imports only the floors below it, [`crate::num`] and [`crate::motor`],
//! and its own modules; nothing here imports `estimator`, `drive` or anything above.
//!
//! | module | `docs/method.md` | contents |
//! |---|---|---|
//! | [`transforms`] | §5 | Clarke, Park and inverses |
//! | [`pi`] | §5 | PI controller with anti-windup |
//! | [`svpwm`] | §5 | space-vector modulation |
//! | [`dead_time`] | §8 | the inverter's dead-time and drop error with the PWM ripple at the switching edges, as the drive compensates it |
//! | [`observer`] | §2–3 | pure integrator, LPF (CFO) and DCFO flux observers |
//! | [`pll`] | §4 | angle and speed from the flux |
//! | [`fll`] | — | the frequency from the flux vector's rotation: tunes the DCFO's notch, acquires a moving mover |
//! | [`arc_fit`] | — | circle fits to the integrated back-EMF's arc: where the mover's flux was at a cold start, and the inputs' DC error |
//! | [`hfi`] | — | high-frequency injection: the angle of a salient motor at standstill and low speed, magnet polarity |
//! | [`load_observer`] | — | position, speed and load of the moving mass from a noisy position |
//! | [`motion`] | — | trapezoidal motion profiles on a finite stroke, from a fixed-capacity queue of moves |

pub mod arc_fit;
pub mod dead_time;
pub mod fll;
pub mod hfi;
pub mod load_observer;
pub mod motion;
pub mod observer;
pub mod pi;
pub mod pll;
pub mod svpwm;
pub mod transforms;
